//! The approach assay: robot-fish distance over time with a still fish.

use super::prelude::*;

/// Fig. 7: the approach assay: set-up and robot-fish distance over time.
pub fn approach(d: &StudyData, cfg: &ReportConfig) -> Option<Figure> {
    if d.approach.is_empty() {
        return None;
    }
    let mut svg = Svg::new(820.0, 360.0);
    let side = 250.0;
    let t = Axes::new((40.0, 50.0, side, side), (-50.0, 50.0), (-50.0, 50.0));
    tank(&mut svg, &t);
    svg.text(
        t.x + side / 2.0,
        t.y - 10.0,
        "set-up (top view)",
        TextStyle::new(13.0, Anchor::Middle).bold(),
    );
    if let Some(s) = d.approach_setup {
        let p = |v: [f32; 2]| t.p(f64::from(v[0]), f64::from(v[1]));
        let r = side / 100.0;
        svg.circle(p(s.goal), 5.0 * r, None, "#009E73", 2.0);
        svg.text(
            p(s.goal).0,
            p(s.goal).1 + 5.0 * r + 14.0,
            "goal",
            TextStyle::new(11.0, Anchor::Middle),
        );
        svg.marker(p(s.fish), 6.0, REAL, 1.0);
        svg.text(
            p(s.fish).0,
            p(s.fish).1 - 12.0,
            "fish (still)",
            TextStyle::new(11.0, Anchor::Middle),
        );
        let rb = Series {
            color: "#000000",
            marker: crate::svg::Marker::Square,
            dash: None,
        };
        svg.marker(p(s.robot), 5.0, rb, 1.0);
        svg.text(
            p(s.robot).0 + 10.0,
            p(s.robot).1 - 8.0,
            "robot",
            TextStyle::new(11.0, Anchor::Start),
        );
    }
    let bin = f64::from(cfg.approach_bin_s);
    let len = d
        .approach
        .values()
        .flatten()
        .map(Vec::len)
        .max()
        .unwrap_or(1);
    let ymax = d
        .approach
        .values()
        .flatten()
        .flatten()
        .copied()
        .filter(|v| v.is_finite())
        .fold(0.0, f64::max);
    let ax = Axes::new(
        (380.0, 50.0, 400.0, side),
        (0.0, len as f64 * bin),
        (0.0, ymax * 1.05),
    );
    ax.draw(
        &mut svg,
        "time since start of control (s)",
        "robot-fish distance (cm)",
        "distance over time",
        None,
    );
    let mut rows = Vec::new();
    for (i, (p, eps)) in d.approach.iter().enumerate() {
        let look = series(i);
        for e in eps {
            let pts: Vec<(f64, f64)> = e
                .iter()
                .enumerate()
                .map(|(k, y)| ax.p((k as f64 + 0.5) * bin, *y))
                .collect();
            svg.polyline(&pts, look.color, 0.7, None, 0.3);
        }
        let mean_curve: Vec<(f64, f64)> = (0..len)
            .map(|k| {
                let v: Vec<f64> = eps
                    .iter()
                    .filter_map(|e| e.get(k).copied())
                    .filter(|x| x.is_finite())
                    .collect();
                ax.p((k as f64 + 0.5) * bin, mean(&v))
            })
            .collect();
        svg.polyline(&mean_curve, look.color, 2.4, look.dash, 1.0);
        rows.push((look, format!("π_{p} ({} episodes)", eps.len()), Key::Line));
    }
    legend(
        &mut svg,
        ax.x + ax.w - 190.0,
        ax.y + ax.h - 12.0 - 18.0 * rows.len() as f64,
        &rows,
    );
    Some(Figure {
        name: "approach",
        title: "Approach assay".into(),
        caption: "Left: the assay (robot in a corner, a motionless fish and the goal on either side). \
                  Right: distance between robot and fish over time, thin lines one episode each, thick \
                  lines the mean per policy. A policy that learned to fetch the fish first drives to it \
                  (the distance drops towards zero); one that ignores the fish keeps its distance."
            .into(),
        svg: svg.finish(),
    })
}
