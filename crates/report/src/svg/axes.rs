//! Axes: "nice" ticks and their labels, the mapping from data to pixels with its frame and
//! labels, and the legend.

use super::{Anchor, Series, Svg, TextStyle};

/// "Nice" tick positions covering [lo, hi], about `target` of them.
pub fn ticks(lo: f64, hi: f64, target: usize) -> Vec<f64> {
    if !(lo.is_finite() && hi.is_finite()) || hi <= lo {
        return vec![lo];
    }
    let raw = (hi - lo) / target.max(1) as f64;
    let mag = 10f64.powf(raw.log10().floor());
    let step = [1.0, 2.0, 2.5, 5.0, 10.0]
        .into_iter()
        .map(|m| m * mag)
        .find(|&s| s >= raw)
        .unwrap_or(10.0 * mag);
    let first = (lo / step).ceil() as i64;
    let last = (hi / step + 1e-9).floor() as i64;
    (first..=last).map(|k| k as f64 * step).collect()
}

/// A tick label without float noise.
pub fn tick_label(v: f64) -> String {
    let r = (v * 1e6).round() / 1e6;
    if r == 0.0 {
        return "0".into();
    }
    for (unit, from, suffix) in [(1e6, 1e6, "M"), (1e3, 1e4, "k")] {
        if r.abs() >= from && (r / unit * 10.0).fract() == 0.0 {
            return format!("{}{suffix}", r / unit);
        }
    }
    let s = format!("{r}");
    if s.len() > 8 {
        format!("{r:.3e}")
    } else {
        s
    }
}

/// A plotting area in px with data ranges.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct Axes {
    /// Left edge (px).
    pub x: f64,
    /// Top edge (px).
    pub y: f64,
    /// Width (px).
    pub w: f64,
    /// Height (px).
    pub h: f64,
    /// Data x range.
    pub xr: (f64, f64),
    /// Data y range.
    pub yr: (f64, f64),
}

impl Axes {
    /// An area with data ranges (degenerate ranges are widened).
    pub fn new(rect: (f64, f64, f64, f64), xr: (f64, f64), yr: (f64, f64)) -> Self {
        let widen = |r: (f64, f64)| {
            if !(r.0.is_finite() && r.1.is_finite()) {
                (0.0, 1.0)
            } else if r.1 > r.0 {
                r
            } else {
                (r.0 - 0.5, r.0 + 0.5)
            }
        };
        Self {
            x: rect.0,
            y: rect.1,
            w: rect.2,
            h: rect.3,
            xr: widen(xr),
            yr: widen(yr),
        }
    }

    /// Data x → px.
    pub fn px(&self, x: f64) -> f64 {
        self.x + (x - self.xr.0) / (self.xr.1 - self.xr.0) * self.w
    }

    /// Data y → px (up is up).
    pub fn py(&self, y: f64) -> f64 {
        self.y + self.h - (y - self.yr.0) / (self.yr.1 - self.yr.0) * self.h
    }

    /// Data point → px.
    pub fn p(&self, x: f64, y: f64) -> (f64, f64) {
        (self.px(x), self.py(y))
    }

    /// Frame, grid, numeric ticks and labels. `xticks` `None`: numeric x ticks; `Some`:
    /// categorical labels at the given data positions.
    pub fn draw(
        &self,
        svg: &mut Svg,
        xlabel: &str,
        ylabel: &str,
        title: &str,
        xticks: Option<&[(f64, String)]>,
    ) {
        let grid = "#e4e4e4";
        let tick_style = TextStyle::new(11.0, Anchor::End);
        for v in ticks(self.yr.0, self.yr.1, 5) {
            let y = self.py(v);
            svg.line((self.x, y), (self.x + self.w, y), grid, 0.8, None);
            svg.line((self.x - 4.0, y), (self.x, y), "#000000", 1.0, None);
            svg.text(self.x - 6.0, y + 4.0, &tick_label(v), tick_style);
        }
        let xt: Vec<(f64, String)> = match xticks {
            Some(t) => t.to_vec(),
            None => ticks(self.xr.0, self.xr.1, 6)
                .into_iter()
                .map(|v| (v, tick_label(v)))
                .collect(),
        };
        for (v, label) in &xt {
            let x = self.px(*v);
            if xticks.is_none() {
                svg.line((x, self.y), (x, self.y + self.h), grid, 0.8, None);
            }
            svg.line(
                (x, self.y + self.h),
                (x, self.y + self.h + 4.0),
                "#000000",
                1.0,
                None,
            );
            svg.text(
                x,
                self.y + self.h + 17.0,
                label,
                TextStyle::new(11.0, Anchor::Middle),
            );
        }
        svg.rect(
            self.x,
            self.y,
            self.w,
            self.h,
            "none",
            Some(("#000000", 1.0)),
        );
        if !xlabel.is_empty() {
            svg.text(
                self.x + self.w / 2.0,
                self.y + self.h + 36.0,
                xlabel,
                TextStyle::new(12.0, Anchor::Middle),
            );
        }
        if !ylabel.is_empty() {
            let (x, y) = (self.x - 44.0, self.y + self.h / 2.0);
            svg.text(
                x,
                y,
                ylabel,
                TextStyle::new(12.0, Anchor::Middle).rotated(-90.0),
            );
        }
        if !title.is_empty() {
            svg.text(
                self.x + self.w / 2.0,
                self.y - 8.0,
                title,
                TextStyle::new(13.0, Anchor::Middle).bold(),
            );
        }
    }
}

/// How a legend row shows its series.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum Key {
    /// The marker alone (scatter).
    Marker,
    /// The line (with the series' dash) alone.
    Line,
    /// Line and marker.
    Both,
}

/// A legend box at (x, y): one row per (series, label, key).
pub fn legend(svg: &mut Svg, x: f64, y: f64, rows: &[(Series, String, Key)]) {
    let h = 18.0;
    let w = 28.0
        + rows
            .iter()
            .map(|r| r.1.chars().count() as f64 * 6.6)
            .fold(0.0, f64::max);
    svg.rect(
        x,
        y,
        w + 10.0,
        h * rows.len() as f64 + 6.0,
        "#ffffff",
        Some(("#999999", 0.8)),
    );
    for (i, (s, label, key)) in rows.iter().enumerate() {
        let cy = y + 3.0 + h * (i as f64 + 0.5);
        if *key != Key::Marker {
            svg.line((x + 5.0, cy), (x + 27.0, cy), s.color, 2.0, s.dash);
        }
        if *key != Key::Line {
            svg.marker((x + 16.0, cy), 4.0, *s, 1.0);
        }
        svg.text(
            x + 32.0,
            cy + 4.0,
            label,
            TextStyle::new(11.0, Anchor::Start),
        );
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn ticks_are_nice_and_cover_the_range() {
        assert_eq!(ticks(0.0, 10.0, 5), vec![0.0, 2.0, 4.0, 6.0, 8.0, 10.0]);
        assert_eq!(ticks(0.0, 1.0, 4), vec![0.0, 0.25, 0.5, 0.75, 1.0]);
        let t = ticks(-3.2, 47.0, 5);
        assert_eq!(t.first(), Some(&0.0));
        assert_eq!(t.last(), Some(&40.0));
        assert_eq!(ticks(1.0, 1.0, 5), vec![1.0]);
        assert_eq!(tick_label(200_000.0), "200k");
        assert_eq!(tick_label(2_500_000.0), "2.5M");
        assert_eq!(tick_label(7_500.0), "7500");
        assert_eq!(tick_label(0.30000000000000004), "0.3");
    }

    #[test]
    fn axes_map_data_to_pixels_with_y_up() {
        let a = Axes::new((10.0, 20.0, 100.0, 50.0), (0.0, 10.0), (0.0, 5.0));
        assert_eq!(a.p(0.0, 0.0), (10.0, 70.0));
        assert_eq!(a.p(10.0, 5.0), (110.0, 20.0));
        let d = Axes::new((0.0, 0.0, 1.0, 1.0), (3.0, 3.0), (f64::NAN, 1.0));
        assert!(d.xr.1 > d.xr.0 && d.yr == (0.0, 1.0));
    }
}
