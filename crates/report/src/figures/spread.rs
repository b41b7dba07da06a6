//! How much trials differ from one another, simulation beside reality: per quantity (goals,
//! time to goal, robot-fish distance, fish speed, paused fraction), every trial's value, per
//! policy.

use super::prelude::*;
use fishprobe_analysis::spread::{spread_sentence, Quantity};

/// The quantities drawn, by id, in order.
const DRAWN: [&str; 5] = [
    "goals",
    "time_to_goal",
    "iid",
    "fish_speed",
    "paused_fraction",
];

/// Per-trial values, sim beside real, one panel per quantity.
pub fn spread(d: &StudyData) -> Option<Figure> {
    let sp = &d.results.as_ref()?.spread;
    let panels: Vec<(Quantity, &std::collections::BTreeMap<String, _>)> = DRAWN
        .iter()
        .filter_map(|id| Some((Quantity::by_id(id)?, sp.get(*id)?)))
        .collect();
    if panels.is_empty() {
        return None;
    }
    let mut policies: Vec<&String> = panels.iter().flat_map(|(_, m)| m.keys()).collect();
    policies.sort();
    policies.dedup();
    let pw = (90.0 * policies.len() as f64).max(200.0);
    let ph = 200.0;
    let cols = panels.len().min(3);
    let rows = panels.len().div_ceil(cols);
    let mut svg = Svg::new(
        80.0 + cols as f64 * (pw + 75.0) + 130.0,
        40.0 + rows as f64 * (ph + 75.0),
    );
    let real_name = arm_label(d);
    for (k, (q, per)) in panels.iter().enumerate() {
        let (c, r) = (k % cols, k / cols);
        let values = per
            .values()
            .flat_map(|e| e.sim.iter().chain(&e.real).copied());
        let (lo, hi) = range(values);
        if !lo.is_finite() {
            continue;
        }
        let pad = ((hi - lo) * 0.06).max(1e-6);
        let ax = Axes::new(
            (
                75.0 + c as f64 * (pw + 75.0),
                25.0 + r as f64 * (ph + 75.0),
                pw,
                ph,
            ),
            (-0.5, policies.len() as f64 - 0.5),
            (if lo >= 0.0 { 0.0 } else { lo - pad }, hi + pad),
        );
        let labels: Vec<(f64, String)> = policies
            .iter()
            .enumerate()
            .map(|(i, p)| (i as f64, format!("π_{p}")))
            .collect();
        ax.draw(&mut svg, "", &q.label(), "", Some(&labels));
        for (i, p) in policies.iter().enumerate() {
            let Some(e) = per.get(*p) else { continue };
            for (side, look, off) in [(&e.sim, SIM, -0.2), (&e.real, REAL, 0.2)] {
                let x0 = i as f64 + off;
                for (j, y) in side.iter().enumerate() {
                    svg.marker(ax.p(x0 + 0.08 * jitter(j), *y), 3.0, look, 0.7);
                }
            }
        }
    }
    legend(
        &mut svg,
        80.0 + cols as f64 * (pw + 75.0) - 10.0,
        30.0,
        &[
            (SIM, "simulation".into(), Key::Marker),
            (REAL, real_name.into(), Key::Marker),
        ],
    );
    let headline: Vec<String> = sp
        .get("goals")
        .map(|per| {
            per.iter()
                .map(|(p, e)| {
                    format!(
                        "π_{p}: {}",
                        spread_sentence(
                            e,
                            "in goals",
                            if real_name == "real" {
                                "live"
                            } else {
                                "virtual-lab"
                            }
                        )
                    )
                })
                .collect()
        })
        .unwrap_or_default();
    Some(Figure {
        name: "spread",
        title: format!("How much trials differ: simulation vs {real_name}"),
        caption: format!(
            "Each point is one trial: its goals, mean time to goal, median robot-fish distance, mean \
             fish speed and fraction of time paused (slower than {} cm/s). Filled circles: simulation \
             on the policy's own model; open triangles: {real_name} trials. A model that captures how \
             individuals differ spreads its trials as widely as reality does; one that simulates an \
             average fish bunches them. {}.",
            d.results
                .as_ref()
                .map_or(0.5, |r| r.config.pause_cm_s),
            if headline.is_empty() {
                "no policy has trials on both sides".to_string()
            } else {
                headline.join("; ")
            }
        ),
        svg: svg.finish(),
    })
}
