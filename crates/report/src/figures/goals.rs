//! Fig. 3: goals reached per trial, simulation vs reality.

use super::prelude::*;

/// Fig. 3: goals reached per trial, sim vs reality.
pub fn goals(d: &StudyData) -> Option<Figure> {
    let g = &d.results.as_ref()?.goals;
    if g.is_empty() {
        return None;
    }
    let policies: Vec<&String> = g.keys().collect();
    let arr = |p: &str, arm: &str| -> Vec<f64> {
        g.get(p)
            .map(|v| if arm == "sim" { &v.sim } else { &v.real })
            .map(|a| a.iter().map(|&x| f64::from(x)).collect())
            .unwrap_or_default()
    };
    let (_, hi) = range(
        policies
            .iter()
            .flat_map(|p| arr(p, "sim").into_iter().chain(arr(p, "real"))),
    );
    let w = 120.0 + 150.0 * policies.len() as f64;
    let mut svg = Svg::new(w.max(420.0) + 120.0, 380.0);
    let ax = Axes::new(
        (70.0, 30.0, w.max(420.0) - 100.0, 290.0),
        (-0.5, policies.len() as f64 - 0.5),
        (0.0, (hi * 1.08).max(1.0)),
    );
    let labels: Vec<(f64, String)> = policies
        .iter()
        .enumerate()
        .map(|(i, p)| (i as f64, format!("π_{p}")))
        .collect();
    ax.draw(
        &mut svg,
        "policy",
        "goals reached per trial",
        "",
        Some(&labels),
    );
    let real_name = arm_label(d);
    let mut totals = Vec::new();
    for (i, p) in policies.iter().enumerate() {
        for (arm, look, off) in [("sim", SIM, -0.2), ("real", REAL, 0.2)] {
            let v = arr(p, arm);
            if v.is_empty() {
                continue;
            }
            let x0 = i as f64 + off;
            for (k, y) in v.iter().enumerate() {
                svg.marker(ax.p(x0 + 0.08 * jitter(k), *y), 3.5, look, 0.75);
            }
            let m = mean(&v);
            svg.line(
                (ax.px(x0 - 0.14), ax.py(m)),
                (ax.px(x0 + 0.14), ax.py(m)),
                "#000000",
                2.5,
                None,
            );
            totals.push(format!(
                "π_{p} {}: {} goals in {} trials",
                if arm == "sim" { "sim" } else { real_name },
                v.iter().sum::<f64>(),
                v.len()
            ));
        }
    }
    legend(
        &mut svg,
        ax.x + ax.w + 10.0,
        ax.y + 6.0,
        &[
            (SIM, "simulation".into(), Key::Marker),
            (REAL, real_name.into(), Key::Marker),
        ],
    );
    Some(Figure {
        name: "goals",
        title: "Goals reached, simulation vs reality".into(),
        caption: format!(
            "Each point is one trial (goals reached in its control phase); the black bar is the mean. \
             Filled circles: simulation on the policy's own model; open triangles: {real_name} trials. \
             A model that predicts reality well puts both clouds at the same height. Totals: {}.",
            totals.join("; ")
        ),
        svg: svg.finish(),
    })
}
