//! The figures of the paper, drawn from a [`StudyData`], one file each. Each returns `None`
//! when its inputs are absent (the report then says what is missing).

mod approach;
mod collective;
mod gap_heatmap;
mod goals;
mod goals_over_time;
mod iid_density;
mod ood;
mod sim_to_sim;
mod spread;
mod training;
mod trajectories;

pub use approach::approach;
pub use collective::collective_phase;
pub use gap_heatmap::gap_heatmap;
pub use goals::goals;
pub use goals_over_time::goals_over_time;
pub use iid_density::iid_density;
pub use ood::{ood_scores, ood_trajectories, ScoredEpisode};
pub use sim_to_sim::sim_to_sim;
pub use spread::spread;
pub use training::training;
pub use trajectories::trajectories;

use crate::data::StudyData;
use crate::svg::{ink_on, viridis, Anchor, Axes, Svg, TextStyle};

/// What every figure file uses.
mod prelude {
    pub(super) use super::{
        arm_label, colour_bar, fmt, heat_cell, heat_row_label, jitter, range, tank, Figure,
        METRIC_LABELS,
    };
    pub(super) use crate::config::ReportConfig;
    pub(super) use crate::data::{StudyData, Track};
    pub(super) use crate::svg::{
        ink_on, legend, series, viridis, Anchor, Axes, Key, Series, Svg, TextStyle, REAL, SIM,
    };
    pub(super) use fishprobe_analysis::ALL_METRICS;
    pub(super) use fishprobe_stats::sample::{mean, sd};
}

/// One finished figure.
#[derive(Debug, Clone, PartialEq)]
pub struct Figure {
    /// File stem (`goals` → `goals.svg`, `goals.png`).
    pub name: &'static str,
    /// Heading.
    pub title: String,
    /// What it shows and how to read it (plain text).
    pub caption: String,
    /// The SVG (text as `<text>`, see [`crate::render`]).
    pub svg: String,
}

/// Metric labels with units, in [`fishprobe_analysis::ALL_METRICS`] order (from the analysis's
/// metric table): the pair metrics, then the group metrics (present only in studies with
/// groups).
pub use fishprobe_analysis::METRIC_LABELS;

pub(crate) fn arm_label(d: &StudyData) -> &'static str {
    match d.arm.as_deref() {
        Some(fishprobe_io::layout::VIRTUAL_LAB) => "virtual lab",
        _ => "real",
    }
}

pub(crate) fn fmt(v: f64, digits: usize) -> String {
    if v.is_finite() {
        format!("{v:.digits$}")
    } else {
        "–".into()
    }
}

pub(crate) fn range(values: impl Iterator<Item = f64>) -> (f64, f64) {
    values
        .filter(|v| v.is_finite())
        .fold((f64::INFINITY, f64::NEG_INFINITY), |(a, b), v| {
            (a.min(v), b.max(v))
        })
}

/// A deterministic jitter in [-1, 1] for the i-th point (low-discrepancy, no RNG needed).
pub(crate) fn jitter(i: usize) -> f64 {
    ((i as f64 * 0.618_033_988_75).fract() - 0.5) * 2.0
}

/// One cell of a heat grid (the gap heatmap, the sim-to-sim matrix): the rectangle
/// `(x, y, w, h)` filled by `shade` (viridis, 0 dark = small), its `lines` of text (height
/// below the cell's top, text, style) centred in the colour that reads on the fill; with no
/// `shade`, grey, with `missing` in its middle when given.
pub(crate) fn heat_cell(
    svg: &mut Svg,
    (x, y, w, h): (f64, f64, f64, f64),
    shade: Option<f64>,
    lines: &[(f64, String, TextStyle)],
    missing: Option<&str>,
) {
    let Some(t) = shade else {
        svg.rect(x, y, w, h, "#f2f2f2", Some(("#ffffff", 1.0)));
        if let Some(m) = missing {
            svg.text(
                x + w / 2.0,
                y + h / 2.0 + 4.0,
                m,
                TextStyle::new(10.0, Anchor::Middle),
            );
        }
        return;
    };
    svg.rect(x, y, w, h, &viridis(t), Some(("#ffffff", 1.0)));
    let ink = ink_on(t);
    for (dy, text, style) in lines {
        svg.text(x + w / 2.0, y + dy, text, style.color(ink));
    }
}

/// A heat grid's row label (`π_<policy>`), right-aligned left of the row at `y` of height `h`.
pub(crate) fn heat_row_label(svg: &mut Svg, right: f64, y: f64, h: f64, policy: &str) {
    svg.text(
        right - 8.0,
        y + h / 2.0 + 4.0,
        &format!("π_{policy}"),
        TextStyle::new(12.0, Anchor::End).bold(),
    );
}

/// A 200 px viridis bar at `at` with labels under its two ends.
pub(crate) fn colour_bar(svg: &mut Svg, at: (f64, f64), low: &str, high: &str) {
    let (x, y) = at;
    for k in 0..100 {
        let t = f64::from(k) / 99.0;
        svg.rect(x + 2.0 * f64::from(k), y, 2.2, 10.0, &viridis(t), None);
    }
    svg.text(x, y + 24.0, low, TextStyle::new(10.0, Anchor::Start));
    svg.text(
        x + 200.0,
        y + 24.0,
        high,
        TextStyle::new(10.0, Anchor::Start),
    );
}

pub(crate) fn tank(svg: &mut Svg, ax: &Axes) {
    svg.rect(
        ax.px(-50.0),
        ax.py(50.0),
        ax.w,
        ax.h,
        "#f7fbff",
        Some(("#000000", 1.5)),
    );
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn jitter_stays_within_one() {
        assert!((0..1000).map(jitter).all(|j| (-1.0..=1.0).contains(&j)));
    }
}
