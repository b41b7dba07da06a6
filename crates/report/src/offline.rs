//! The figures of the offline comparison (`fishprobe compare-offline`): per comparison (pairs,
//! or the robot recordings open loop), the pooled distributions and the per-recording values.

use crate::figures::{jitter, Figure};
use crate::svg::{legend, series, Axes, Key, Series, Svg};
use fishprobe_analysis::offline::{Comparison, OfflineResults, OFFLINE_METRICS, RECORDING_STATS};

const GREY: Series = Series {
    color: "#999999",
    marker: crate::svg::Marker::Square,
    dash: None,
};

/// Every figure of the offline comparison.
pub fn offline_figures(r: &OfflineResults) -> Vec<Figure> {
    let mut out = Vec::new();
    if !r.pairs.recordings.is_empty() {
        out.extend(offline_histograms(r));
        out.extend(recording_spread(&r.pairs, false, "offline_spread"));
    }
    if let Some(o) = &r.open_loop {
        out.extend(histograms(
            o,
            true,
            "open_loop_histograms",
            r.config.pause_cm_s,
        ));
        out.extend(recording_spread(o, true, "open_loop_spread"));
    }
    out
}

/// The pair comparison: per measure, the real pairs' histogram (grey, filled) and each
/// model's (coloured lines).
pub fn offline_histograms(r: &OfflineResults) -> Option<Figure> {
    histograms(&r.pairs, false, "offline_histograms", r.config.pause_cm_s)
}

fn grid(n: usize, cols: usize, pw: f64, ph: f64, extra_w: f64) -> (Svg, usize) {
    let rows = n.div_ceil(cols);
    (
        Svg::new(
            90.0 + cols as f64 * (pw + 60.0) + extra_w,
            60.0 + rows as f64 * (ph + 80.0),
        ),
        rows,
    )
}

fn histograms(c: &Comparison, robot: bool, name: &'static str, pause: f32) -> Option<Figure> {
    let real = c.histograms.get("real")?;
    let models: Vec<(&String, &Vec<Vec<f64>>)> =
        c.histograms.iter().filter(|(k, _)| *k != "real").collect();
    let (pw, ph) = (300.0, 190.0);
    let (mut svg, _) = grid(OFFLINE_METRICS.len(), 3, pw, ph, 210.0);
    for (m, metric) in OFFLINE_METRICS.iter().enumerate() {
        let (col, row) = (m % 3, m / 3);
        let (lo, hi) = metric.range;
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
                75.0 + col as f64 * (pw + 60.0),
                40.0 + row as f64 * (ph + 80.0),
                pw,
                ph,
            ),
            (lo, hi),
            (0.0, ymax * 1.05),
        );
        ax.draw(
            &mut svg,
            &format!("{} ({})", metric.label_for(robot), metric.unit),
            if col == 0 { "fraction per bin" } else { "" },
            "",
            None,
        );
        let bins = real[m].len();
        let x = |i: usize| lo + (i as f64 + 0.5) * (hi - lo) / bins as f64;
        let mut area: Vec<(f64, f64)> = vec![ax.p(lo, 0.0)];
        area.extend(real[m].iter().enumerate().map(|(i, y)| ax.p(x(i), *y)));
        area.push(ax.p(hi, 0.0));
        svg.polygon(&area, GREY.color, 0.45);
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
    let real_name = if robot {
        "live fish beside the robot"
    } else {
        "real pairs"
    };
    let mut rows = vec![(GREY, real_name.to_string(), Key::Marker)];
    rows.extend(
        models
            .iter()
            .enumerate()
            .map(|(k, (n, _))| (series(k), format!("M_{n}"), Key::Line)),
    );
    legend(&mut svg, 75.0 + 3.0 * (pw + 60.0) - 20.0, 40.0, &rows);
    let caption = if robot {
        format!(
            "Open loop: distributions of the motion of one live guppy beside the robot (grey area, {} \
             recordings) and of each model's fish beside the robot's recorded path replayed as it was, \
             from the live fish's first pose (lines; a peak taller than three times the real one is cut \
             at the top). The robot never reacts to the model fish: this is the fixed-rollout \
             evaluation the paper contrasts its closed loop with. Paused = fraction of frames slower \
             than {pause} cm/s, per fish.",
            c.recordings.len()
        )
    } else {
        format!(
            "Distributions of the motion of pairs of live guppies (grey area, {} recordings) \
             and of pairs of model fish simulated as many and as long as the recordings, from the \
             same start poses (lines; a peak taller than three times the real one is cut at the top). \
             Speed, turn rate, wall distance and facing the other fish per fish and frame; \
             inter-individual distance and alignment per frame; paused = fraction of frames slower \
             than {pause} cm/s, per fish. The closer a line follows the grey area, the more realistic the \
             model by this classic criterion.",
            c.recordings.len()
        )
    };
    Some(Figure {
        name,
        title: if robot {
            "Open loop: model fish beside the recorded robot vs live fish".into()
        } else {
            "Offline comparison: model pairs vs real pairs".into()
        },
        caption,
        svg: svg.finish(),
    })
}

/// Per statistic, one point per recording: the real recordings (grey) beside each model's.
fn recording_spread(c: &Comparison, robot: bool, name: &'static str) -> Option<Figure> {
    let sp = &c.spread;
    let sources: Vec<&String> = std::iter::once(sp.values.get_key_value("real")?.0)
        .chain(sp.values.keys().filter(|k| *k != "real"))
        .collect();
    let (pw, ph) = (70.0 + 55.0 * sources.len() as f64, 190.0);
    let cols = 3;
    let (mut svg, _) = grid(RECORDING_STATS.len(), cols, pw, ph, 0.0);
    let mut headline = Vec::new();
    for (k, st) in RECORDING_STATS.iter().enumerate() {
        let (col, row) = (k % cols, k / cols);
        let column = |src: &String| -> Vec<f64> {
            sp.values
                .get(src)
                .and_then(|m| m.get(st.id))
                .map(|v| v.iter().flatten().copied().collect())
                .unwrap_or_default()
        };
        let all: Vec<f64> = sources.iter().flat_map(|s| column(s)).collect();
        let (lo, hi) = crate::figures::range(all.iter().copied());
        if !lo.is_finite() {
            continue;
        }
        let pad = ((hi - lo) * 0.06).max(1e-6);
        let ax = Axes::new(
            (
                75.0 + col as f64 * (pw + 60.0),
                40.0 + row as f64 * (ph + 80.0),
                pw,
                ph,
            ),
            (-0.6, sources.len() as f64 - 0.4),
            (lo - pad, hi + pad),
        );
        let labels: Vec<(f64, String)> = sources
            .iter()
            .enumerate()
            .map(|(i, s)| {
                let l = if *s == "real" {
                    "real".to_string()
                } else {
                    format!("M_{s}")
                };
                (i as f64, l)
            })
            .collect();
        ax.draw(&mut svg, "", st.label_for(robot), "", Some(&labels));
        for (i, src) in sources.iter().enumerate() {
            let look = if *src == "real" { GREY } else { series(i - 1) };
            let v = column(src);
            for (j, y) in v.iter().enumerate() {
                svg.marker(ax.p(i as f64 + 0.22 * jitter(j), *y), 3.0, look, 0.7);
            }
        }
        if let Some((m, e)) = sp
            .models
            .iter()
            .filter_map(|(m, per)| per.get(st.id).map(|e| (m, e)))
            .max_by(|a, b| a.1.ratio.total_cmp(&b.1.ratio))
        {
            headline.push(format!(
                "{}: real s.d. {:.3}, the most varied model M_{m} {:.2} of it",
                st.label_for(robot),
                e.sd_real,
                e.ratio
            ));
        }
    }
    let what = if robot {
        "robot recording (one live fish beside the robot; models open loop)"
    } else {
        "recording of a pair (real pairs; each model simulates one pair per recording from its first poses)"
    };
    Some(Figure {
        name,
        title: if robot {
            "Open loop: how much recordings differ, live fish vs models".into()
        } else {
            "How much pairs differ: real recordings vs model pairs".into()
        },
        caption: format!(
            "Each point is one {what}; its value of the statistic named on the axis. \
             Live fish differ from one another far more than any model's fish when the models' \
             points bunch where the real ones spread. {}.",
            headline.join("; ")
        ),
        svg: svg.finish(),
    })
}
