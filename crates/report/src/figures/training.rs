//! Training curves: goals per episode over environment steps.

use super::prelude::*;

/// Training curves from the policies' progress logs.
pub fn training(d: &StudyData) -> Option<Figure> {
    if d.training.is_empty() {
        return None;
    }
    let (_, xmax) = range(d.training.values().flat_map(|l| l.rows.iter().map(|r| r.0)));
    type Column = fn(&(f64, f64, f64)) -> f64;
    let panels_def: [(&str, Column); 2] = [
        ("goals per episode", |r| r.2),
        ("mean episode return", |r| r.1),
    ];
    let (pw, ph) = (380.0, 250.0);
    let mut svg = Svg::new(90.0 + 2.0 * (pw + 60.0) + 100.0, 350.0);
    for (k, (label, get)) in panels_def.iter().enumerate() {
        let (lo, hi) = range(d.training.values().flat_map(|l| l.rows.iter().map(get)));
        let ax = Axes::new(
            (80.0 + k as f64 * (pw + 60.0), 35.0, pw, ph),
            (0.0, xmax.max(1.0)),
            (lo.min(0.0), hi.max(lo + 1e-9) * 1.05),
        );
        ax.draw(&mut svg, "environment steps", label, "", None);
        let mut leg = Vec::new();
        for (i, (m, log)) in d.training.iter().enumerate() {
            let look = series(i);
            let pts: Vec<(f64, f64)> = log.rows.iter().map(|r| ax.p(r.0, get(r))).collect();
            svg.polyline(&pts, look.color, 1.8, look.dash, 1.0);
            leg.push((look, format!("π_{m}"), Key::Line));
        }
        if k == 1 {
            legend(&mut svg, ax.x + ax.w + 10.0, ax.y, &leg);
        }
    }
    Some(Figure {
        name: "training",
        title: "Training curves".into(),
        caption: "Goals reached per training episode (left) and mean episode return (right) over \
                  environment steps, one line per policy, from policies/<Model>/progress.csv. Training \
                  episodes are shorter than evaluation trials, so their goal counts are not comparable \
                  with the other figures."
            .into(),
        svg: svg.finish(),
    })
}
