//! The figure of the offline comparison (`fishprobe compare-offline`).

use crate::figures::Figure;
use crate::svg::{legend, series, Axes, Key, Series, Svg};

/// The offline comparison: per metric, the real pairs' histogram (grey, filled) and each
/// model's (coloured lines).
pub fn offline_histograms(r: &fishprobe_analysis::offline::OfflineResults) -> Option<Figure> {
    use fishprobe_analysis::offline::{metric_range, OFFLINE_METRICS};
    let real = r.histograms.get("real")?;
    let models: Vec<(&String, &Vec<Vec<f64>>)> =
        r.histograms.iter().filter(|(k, _)| *k != "real").collect();
    let (pw, ph) = (300.0, 190.0);
    let mut svg = Svg::new(90.0 + 3.0 * (pw + 60.0) + 120.0, 60.0 + 2.0 * (ph + 80.0));
    for (m, (metric, unit)) in OFFLINE_METRICS.iter().enumerate() {
        let (c, row) = (m % 3, m / 3);
        let (lo, hi) = metric_range(m);
        // A model concentrated in one bin would flatten everything else: the axis stops at 3x
        // the real histogram's peak and taller lines are cut at the top.
        let real_peak = real[m].iter().copied().fold(0.0, f64::max);
        let ymax = std::iter::once(&real[m])
            .chain(models.iter().map(|(_, h)| &h[m]))
            .flatten()
            .copied()
            .fold(0.0, f64::max)
            .min(3.0 * real_peak.max(1e-9));
        let ax = Axes::new(
            (
                75.0 + c as f64 * (pw + 60.0),
                40.0 + row as f64 * (ph + 80.0),
                pw,
                ph,
            ),
            (lo, hi),
            (0.0, ymax * 1.05),
        );
        ax.draw(
            &mut svg,
            &format!("{} ({unit})", metric.replace('_', " ")),
            if c == 0 { "fraction per bin" } else { "" },
            "",
            None,
        );
        let bins = real[m].len();
        let x = |i: usize| lo + (i as f64 + 0.5) * (hi - lo) / bins as f64;
        let mut area: Vec<(f64, f64)> = vec![ax.p(lo, 0.0)];
        area.extend(real[m].iter().enumerate().map(|(i, y)| ax.p(x(i), *y)));
        area.push(ax.p(hi, 0.0));
        svg.polygon(&area, "#999999", 0.45);
        for (k, (_, h)) in models.iter().enumerate() {
            let look = series(k);
            let pts: Vec<(f64, f64)> = h[m]
                .iter()
                .enumerate()
                .map(|(i, y)| ax.p(x(i), y.min(ymax * 1.05)))
                .collect();
            svg.polyline(&pts, look.color, 1.6, look.dash, 1.0);
        }
    }
    let mut rows = vec![(
        Series {
            color: "#999999",
            marker: crate::svg::Marker::Square,
            dash: None,
        },
        "real pairs".to_string(),
        Key::Marker,
    )];
    rows.extend(
        models
            .iter()
            .enumerate()
            .map(|(k, (n, _))| (series(k), format!("M_{n}"), Key::Line)),
    );
    legend(&mut svg, 75.0 + 3.0 * (pw + 60.0) - 20.0, 40.0, &rows);
    Some(Figure {
        name: "offline_histograms",
        title: "Offline comparison: model pairs vs real pairs".into(),
        caption: format!(
            "Distributions of six motion metrics of pairs of live guppies (grey area, {} recordings) \
             and of pairs of model fish simulated as many and as long as the recordings, from the \
             same start poses (lines; a peak taller than three times the real one is cut at the top). Speed, turn rate and wall distance per fish and frame; \
             inter-individual distance and alignment per frame; paused = fraction of frames slower \
             than {} cm/s, per fish. The closer a line follows the grey area, the more realistic the \
             model by this classic criterion.",
            r.recordings.len(),
            r.config.pause_cm_s
        ),
        svg: svg.finish(),
    })
}
