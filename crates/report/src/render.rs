//! From the plotting kit's SVG to the files people use: PNG (slides) rendered with `resvg`,
//! and SVG (papers) whose text has been converted to outlines, so that neither depends on
//! fonts installed where it is opened.
//!
//! The only font is DejaVu Sans (regular and bold), compiled into the program
//! (`assets/`, licence in `assets/DejaVu-LICENSE.txt`); system fonts are never consulted,
//! so a figure looks the same on every machine.

use crate::error::ReportError;
use resvg::{tiny_skia, usvg};
use std::sync::{Arc, OnceLock};

static REGULAR: &[u8] = include_bytes!("../assets/DejaVuSans.ttf");
static BOLD: &[u8] = include_bytes!("../assets/DejaVuSans-Bold.ttf");

fn fonts() -> Arc<usvg::fontdb::Database> {
    static DB: OnceLock<Arc<usvg::fontdb::Database>> = OnceLock::new();
    DB.get_or_init(|| {
        let mut db = usvg::fontdb::Database::new();
        db.load_font_data(REGULAR.to_vec());
        db.load_font_data(BOLD.to_vec());
        db.set_sans_serif_family(crate::svg::FONT);
        Arc::new(db)
    })
    .clone()
}

fn tree(svg: &str, name: &str) -> Result<usvg::Tree, ReportError> {
    let opt = usvg::Options {
        font_family: crate::svg::FONT.to_string(),
        fontdb: fonts(),
        ..usvg::Options::default()
    };
    usvg::Tree::from_str(svg, &opt).map_err(|e| ReportError::Render {
        figure: name.to_string(),
        what: e.to_string(),
    })
}

/// The figure as PNG, `scale` device pixels per SVG px.
pub fn png(svg: &str, name: &str, scale: f32) -> Result<Vec<u8>, ReportError> {
    let t = tree(svg, name)?;
    let size = t
        .size()
        .to_int_size()
        .scale_by(scale)
        .ok_or_else(|| ReportError::Render {
            figure: name.to_string(),
            what: format!("cannot scale a {:?} figure by {scale}", t.size()),
        })?;
    let mut pixmap =
        tiny_skia::Pixmap::new(size.width(), size.height()).ok_or_else(|| ReportError::Render {
            figure: name.to_string(),
            what: format!("empty canvas {}x{}", size.width(), size.height()),
        })?;
    pixmap.fill(tiny_skia::Color::WHITE);
    resvg::render(
        &t,
        tiny_skia::Transform::from_scale(scale, scale),
        &mut pixmap.as_mut(),
    );
    pixmap.encode_png().map_err(|e| ReportError::Render {
        figure: name.to_string(),
        what: e.to_string(),
    })
}

/// The figure as self-contained SVG: text converted to outlines in the embedded font.
pub fn portable_svg(svg: &str, name: &str) -> Result<String, ReportError> {
    let t = tree(svg, name)?;
    let opt = usvg::WriteOptions {
        coordinates_precision: 3,
        transforms_precision: 4,
        ..usvg::WriteOptions::default()
    };
    Ok(t.to_string(&opt))
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::svg::{Anchor, Svg, TextStyle};

    fn sample() -> String {
        let mut s = Svg::new(120.0, 40.0);
        s.text(
            10.0,
            25.0,
            "goals / 15 min",
            TextStyle::new(14.0, Anchor::Start).bold(),
        );
        s.finish()
    }

    #[test]
    fn text_renders_without_system_fonts() {
        let png = png(&sample(), "t", 2.0).expect("renders");
        assert_eq!(&png[1..4], b"PNG");
        // Decode is not available without another crate; render again and count ink.
        let t = tree(&sample(), "t").expect("parses");
        let mut pm = tiny_skia::Pixmap::new(120, 40).expect("canvas");
        pm.fill(tiny_skia::Color::WHITE);
        resvg::render(&t, tiny_skia::Transform::identity(), &mut pm.as_mut());
        let dark = pm.pixels().iter().filter(|p| p.red() < 128).count();
        assert!(
            dark > 50,
            "the text drew {dark} dark pixels: font not found?"
        );
    }

    #[test]
    fn portable_svg_has_no_text_elements_left() {
        let out = portable_svg(&sample(), "t").expect("writes");
        assert!(!out.contains("<text"), "{out}");
        assert!(out.contains("<path"), "{out}");
    }

    #[test]
    fn malformed_svg_is_an_error_naming_the_figure() {
        let e = png("<svg", "goals", 1.0).unwrap_err().to_string();
        assert!(e.contains("goals"), "{e}");
    }
}
