//! A small SVG plotting kit: a canvas, axes with "nice" ticks, and the colour scheme.
//!
//! Figures are written as SVG with `<text>` elements in the embedded font (DejaVu Sans);
//! `render` turns them into PNG and into SVG whose text is converted to paths, so
//! neither needs a font on the reader's machine.

use std::fmt::Write as _;

mod axes;
pub use axes::{legend, tick_label, ticks, Axes, Key};

/// The font every figure names (embedded: the `render` module).
pub const FONT: &str = "DejaVu Sans";

/// Okabe-Ito colours (colour-blind safe), ordered so that neighbours also differ in
/// lightness: series are further told apart by marker and dash (see [`Series`]).
pub const PALETTE: [&str; 7] = [
    "#0072B2", "#E69F00", "#009E73", "#CC79A7", "#56B4E9", "#D55E00", "#000000",
];

/// Sim is drawn dark blue with filled circles and solid lines; reality light orange with
/// open triangles and dashed lines: distinguishable in colour, in greyscale and by shape.
pub const SIM: Series = Series {
    color: "#0072B2",
    marker: Marker::Circle,
    dash: None,
};
/// See [`SIM`].
pub const REAL: Series = Series {
    color: "#E69F00",
    marker: Marker::Triangle,
    dash: Some("6 3"),
};

/// Marker shapes.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum Marker {
    /// Filled circle.
    Circle,
    /// Open triangle.
    Triangle,
    /// Filled square.
    Square,
    /// Open diamond.
    Diamond,
}

/// How one data series looks.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct Series {
    /// Stroke and fill colour.
    pub color: &'static str,
    /// Marker shape.
    pub marker: Marker,
    /// SVG dash array, `None` for solid.
    pub dash: Option<&'static str>,
}

/// The look of the `i`-th policy (colour, marker and dash cycle with different periods).
pub fn series(i: usize) -> Series {
    const MARKERS: [Marker; 4] = [
        Marker::Circle,
        Marker::Triangle,
        Marker::Square,
        Marker::Diamond,
    ];
    const DASHES: [Option<&str>; 3] = [None, Some("7 3"), Some("2 2")];
    Series {
        color: PALETTE[i % PALETTE.len()],
        marker: MARKERS[i % MARKERS.len()],
        dash: DASHES[i % DASHES.len()],
    }
}

/// Viridis (perceptually uniform, monotone in lightness, so it survives greyscale printing) at
/// `t` in [0, 1], as `#rrggbb`.
pub fn viridis(t: f64) -> String {
    const STOPS: [[f64; 3]; 9] = [
        [68.0, 1.0, 84.0],
        [71.0, 44.0, 122.0],
        [59.0, 81.0, 139.0],
        [44.0, 113.0, 142.0],
        [33.0, 144.0, 141.0],
        [39.0, 173.0, 129.0],
        [92.0, 200.0, 99.0],
        [170.0, 220.0, 50.0],
        [253.0, 231.0, 37.0],
    ];
    let t = if t.is_finite() {
        t.clamp(0.0, 1.0)
    } else {
        0.0
    };
    let x = t * (STOPS.len() - 1) as f64;
    let i = (x.floor() as usize).min(STOPS.len() - 2);
    let f = x - i as f64;
    let c: Vec<u8> = (0..3)
        .map(|k| (STOPS[i][k] + (STOPS[i + 1][k] - STOPS[i][k]) * f).round() as u8)
        .collect();
    format!("#{:02x}{:02x}{:02x}", c[0], c[1], c[2])
}

/// Text on a viridis cell of value `t`: white on the dark half, black on the light half.
pub fn ink_on(t: f64) -> &'static str {
    if t < 0.55 {
        "#ffffff"
    } else {
        "#000000"
    }
}

/// Escapes text for XML.
pub fn esc(s: &str) -> String {
    s.replace('&', "&amp;")
        .replace('<', "&lt;")
        .replace('>', "&gt;")
        .replace('"', "&quot;")
}

/// Text alignment.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum Anchor {
    /// Left-aligned.
    Start,
    /// Centred.
    Middle,
    /// Right-aligned.
    End,
}

impl Anchor {
    fn svg(self) -> &'static str {
        match self {
            Anchor::Start => "start",
            Anchor::Middle => "middle",
            Anchor::End => "end",
        }
    }
}

/// A text element's style.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct TextStyle {
    /// Size in px.
    pub size: f64,
    /// Alignment.
    pub anchor: Anchor,
    /// Bold.
    pub bold: bool,
    /// Rotation in degrees about the anchor point.
    pub rotate: f64,
    /// Colour.
    pub color: &'static str,
}

impl TextStyle {
    /// Regular text of `size` px with `anchor`.
    pub const fn new(size: f64, anchor: Anchor) -> Self {
        Self {
            size,
            anchor,
            bold: false,
            rotate: 0.0,
            color: "#000000",
        }
    }
    /// Bold.
    pub const fn bold(mut self) -> Self {
        self.bold = true;
        self
    }
    /// Rotated.
    pub const fn rotated(mut self, deg: f64) -> Self {
        self.rotate = deg;
        self
    }
    /// Coloured.
    pub const fn color(mut self, c: &'static str) -> Self {
        self.color = c;
        self
    }
}

/// An SVG canvas in px.
#[derive(Debug, Clone)]
pub struct Svg {
    w: f64,
    h: f64,
    body: String,
}

fn n(x: f64) -> String {
    let r = (x * 100.0).round() / 100.0;
    if r == 0.0 {
        "0".into()
    } else {
        format!("{r}")
    }
}

impl Svg {
    /// A white canvas.
    pub fn new(w: f64, h: f64) -> Self {
        let mut s = Self {
            w,
            h,
            body: String::new(),
        };
        s.rect(0.0, 0.0, w, h, "#ffffff", None);
        s
    }

    /// Width and height.
    pub fn size(&self) -> (f64, f64) {
        (self.w, self.h)
    }

    /// A raw element (already escaped).
    pub fn raw(&mut self, element: &str) {
        self.body += element;
        self.body.push('\n');
    }

    /// A line.
    pub fn line(
        &mut self,
        a: (f64, f64),
        b: (f64, f64),
        color: &str,
        width: f64,
        dash: Option<&str>,
    ) {
        let d = dash.map_or(String::new(), |d| format!(r#" stroke-dasharray="{d}""#));
        let _ = writeln!(
            self.body,
            r#"<line x1="{}" y1="{}" x2="{}" y2="{}" stroke="{color}" stroke-width="{}"{d}/>"#,
            n(a.0),
            n(a.1),
            n(b.0),
            n(b.1),
            n(width)
        );
    }

    /// A polyline through `pts` (non-finite points split it into pieces).
    pub fn polyline(
        &mut self,
        pts: &[(f64, f64)],
        color: &str,
        width: f64,
        dash: Option<&str>,
        opacity: f64,
    ) {
        let d = dash.map_or(String::new(), |d| format!(r#" stroke-dasharray="{d}""#));
        for piece in pts.split(|p| !(p.0.is_finite() && p.1.is_finite())) {
            if piece.len() < 2 {
                continue;
            }
            let mut path = String::with_capacity(piece.len() * 14);
            for (i, p) in piece.iter().enumerate() {
                let _ = write!(
                    path,
                    "{}{} {} ",
                    if i == 0 { 'M' } else { 'L' },
                    n(p.0),
                    n(p.1)
                );
            }
            let _ = writeln!(
                self.body,
                r#"<path d="{}" fill="none" stroke="{color}" stroke-width="{}" stroke-opacity="{}" stroke-linejoin="round"{d}/>"#,
                path.trim_end(),
                n(width),
                n(opacity)
            );
        }
    }

    /// A filled polygon.
    pub fn polygon(&mut self, pts: &[(f64, f64)], fill: &str, opacity: f64) {
        let p: Vec<String> = pts
            .iter()
            .filter(|p| p.0.is_finite() && p.1.is_finite())
            .map(|p| format!("{},{}", n(p.0), n(p.1)))
            .collect();
        if p.len() < 3 {
            return;
        }
        let _ = writeln!(
            self.body,
            r#"<polygon points="{}" fill="{fill}" fill-opacity="{}" stroke="none"/>"#,
            p.join(" "),
            n(opacity)
        );
    }

    /// A rectangle; `stroke` = (colour, width).
    pub fn rect(
        &mut self,
        x: f64,
        y: f64,
        w: f64,
        h: f64,
        fill: &str,
        stroke: Option<(&str, f64)>,
    ) {
        let s = stroke.map_or(String::new(), |(c, sw)| {
            format!(r#" stroke="{c}" stroke-width="{}""#, n(sw))
        });
        let _ = writeln!(
            self.body,
            r#"<rect x="{}" y="{}" width="{}" height="{}" fill="{fill}"{s}/>"#,
            n(x),
            n(y),
            n(w.max(0.0)),
            n(h.max(0.0))
        );
    }

    /// A circle; `fill` `None` draws it open.
    pub fn circle(&mut self, c: (f64, f64), r: f64, fill: Option<&str>, stroke: &str, width: f64) {
        let _ = writeln!(
            self.body,
            r#"<circle cx="{}" cy="{}" r="{}" fill="{}" stroke="{stroke}" stroke-width="{}"/>"#,
            n(c.0),
            n(c.1),
            n(r),
            fill.unwrap_or("none"),
            n(width)
        );
    }

    /// A marker of `size` px (radius-like) in the series' colour.
    pub fn marker(&mut self, c: (f64, f64), size: f64, s: Series, opacity: f64) {
        let (x, y) = c;
        let op = n(opacity);
        let el = match s.marker {
            Marker::Circle => format!(
                r#"<circle cx="{}" cy="{}" r="{}" fill="{}" fill-opacity="{op}" stroke="{}" stroke-width="0.8"/>"#,
                n(x),
                n(y),
                n(size),
                s.color,
                s.color
            ),
            Marker::Square => format!(
                r#"<rect x="{}" y="{}" width="{}" height="{}" fill="{}" fill-opacity="{op}" stroke="{}" stroke-width="0.8"/>"#,
                n(x - size * 0.85),
                n(y - size * 0.85),
                n(size * 1.7),
                n(size * 1.7),
                s.color,
                s.color
            ),
            Marker::Triangle => format!(
                r##"<polygon points="{},{} {},{} {},{}" fill="#ffffff" fill-opacity="{op}" stroke="{}" stroke-width="1.6"/>"##,
                n(x),
                n(y - size * 1.15),
                n(x - size),
                n(y + size * 0.7),
                n(x + size),
                n(y + size * 0.7),
                s.color
            ),
            Marker::Diamond => format!(
                r##"<polygon points="{},{} {},{} {},{} {},{}" fill="#ffffff" fill-opacity="{op}" stroke="{}" stroke-width="1.6"/>"##,
                n(x),
                n(y - size * 1.2),
                n(x + size),
                n(y),
                n(x),
                n(y + size * 1.2),
                n(x - size),
                n(y),
                s.color
            ),
        };
        self.raw(&el);
    }

    /// Text at (x, y) (baseline).
    pub fn text(&mut self, x: f64, y: f64, s: &str, st: TextStyle) {
        let rot = if st.rotate == 0.0 {
            String::new()
        } else {
            format!(r#" transform="rotate({} {} {})""#, n(st.rotate), n(x), n(y))
        };
        let _ = writeln!(
            self.body,
            r#"<text x="{}" y="{}" font-family="{FONT}" font-size="{}" text-anchor="{}"{} fill="{}"{rot}>{}</text>"#,
            n(x),
            n(y),
            n(st.size),
            st.anchor.svg(),
            if st.bold {
                r#" font-weight="bold""#
            } else {
                ""
            },
            st.color,
            esc(s)
        );
    }

    /// The finished document.
    pub fn finish(&self) -> String {
        format!(
            "<svg xmlns=\"http://www.w3.org/2000/svg\" width=\"{w}\" height=\"{h}\" viewBox=\"0 0 {w} {h}\">\n{}</svg>\n",
            self.body,
            w = n(self.w),
            h = n(self.h)
        )
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn viridis_is_monotone_in_lightness() {
        let lum = |c: &str| {
            let v = |i: usize| f64::from(u8::from_str_radix(&c[i..i + 2], 16).unwrap_or(0));
            0.299 * v(1) + 0.587 * v(3) + 0.114 * v(5)
        };
        let l: Vec<f64> = (0..=20)
            .map(|i| lum(&viridis(f64::from(i) / 20.0)))
            .collect();
        assert!(l.windows(2).all(|w| w[1] > w[0]), "{l:?}");
    }

    #[test]
    fn text_is_escaped_and_polylines_split_at_gaps() {
        let mut s = Svg::new(10.0, 10.0);
        s.text(1.0, 1.0, "a<b & c", TextStyle::new(10.0, Anchor::Start));
        s.polyline(
            &[
                (0.0, 0.0),
                (1.0, 1.0),
                (f64::NAN, 0.0),
                (2.0, 2.0),
                (3.0, 3.0),
            ],
            "#000000",
            1.0,
            None,
            1.0,
        );
        let out = s.finish();
        assert!(out.contains("a&lt;b &amp; c"));
        assert_eq!(out.matches("<path").count(), 2);
    }
}
