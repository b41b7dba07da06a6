//! Goals per minute over the trial, with the negative-binomial trend.

use super::prelude::*;

/// Fig. 8: goals per minute over time, sim and real panels, with the NB2 trend.
pub fn goals_over_time(d: &StudyData) -> Option<Figure> {
    let arms: Vec<(&str, String)> = [
        ("sim", "simulation".to_string()),
        ("real", arm_label(d).to_string()),
    ]
    .into_iter()
    .filter(|(arm, _)| {
        d.trials.values().any(|t| {
            if *arm == "sim" {
                !t.sim.is_empty()
            } else {
                !t.real.is_empty()
            }
        })
    })
    .collect();
    if arms.is_empty() {
        return None;
    }
    let stats = |v: &[crate::data::TrialNumbers]| -> Vec<(f64, f64)> {
        let len = v
            .iter()
            .map(|t| t.goals_per_minute.len())
            .max()
            .unwrap_or(0);
        (0..len)
            .map(|m| {
                let x: Vec<f64> = v
                    .iter()
                    .filter_map(|t| t.goals_per_minute.get(m))
                    .map(|&g| f64::from(g))
                    .collect();
                (mean(&x), sd(&x))
            })
            .collect()
    };
    /// Per arm: (policy index, policy, (mean, s.d.) per minute).
    type ArmCurves<'a> = (&'a str, Vec<(usize, &'a String, Vec<(f64, f64)>)>);
    let per: Vec<ArmCurves> = arms
        .iter()
        .map(|(arm, _)| {
            (
                *arm,
                d.trials
                    .iter()
                    .enumerate()
                    .map(|(i, (p, t))| (i, p, stats(if *arm == "sim" { &t.sim } else { &t.real })))
                    .filter(|(_, _, s)| !s.is_empty())
                    .collect(),
            )
        })
        .collect();
    let minutes = per
        .iter()
        .flat_map(|(_, v)| v.iter().map(|x| x.2.len()))
        .max()
        .unwrap_or(1);
    let ymax = per
        .iter()
        .flat_map(|(_, v)| {
            v.iter().flat_map(|x| {
                x.2.iter()
                    .map(|(m, s)| m + if s.is_finite() { *s } else { 0.0 })
            })
        })
        .fold(0.0, f64::max);
    let (pw, ph) = (380.0, 260.0);
    let mut svg = Svg::new(90.0 + arms.len() as f64 * (pw + 40.0) + 130.0, 360.0);
    let minute_ticks: Vec<(f64, String)> = (1..=minutes)
        .filter(|m| minutes <= 8 || m % 2 == 1)
        .map(|m| (m as f64, m.to_string()))
        .collect();
    for (k, ((arm, label), (_, rows))) in arms.iter().zip(&per).enumerate() {
        let ax = Axes::new(
            (75.0 + k as f64 * (pw + 40.0), 40.0, pw, ph),
            (0.5, minutes as f64 + 0.5),
            (0.0, (ymax * 1.05).max(0.5)),
        );
        ax.draw(
            &mut svg,
            "minute of control",
            if k == 0 { "goals per minute" } else { "" },
            label,
            Some(&minute_ticks),
        );
        let mut leg = Vec::new();
        for (i, p, st) in rows {
            let look = series(*i);
            let upper: Vec<(f64, f64)> = st
                .iter()
                .enumerate()
                .map(|(m, (mu, s))| ax.p(m as f64 + 1.0, mu + if s.is_finite() { *s } else { 0.0 }))
                .collect();
            let lower: Vec<(f64, f64)> = st
                .iter()
                .enumerate()
                .rev()
                .map(|(m, (mu, s))| {
                    ax.p(
                        m as f64 + 1.0,
                        (mu - if s.is_finite() { *s } else { 0.0 }).max(0.0),
                    )
                })
                .collect();
            svg.polygon(&[upper, lower].concat(), look.color, 0.08);
            let pts: Vec<(f64, f64)> = st
                .iter()
                .enumerate()
                .map(|(m, (mu, _))| ax.p(m as f64 + 1.0, *mu))
                .collect();
            svg.polyline(&pts, look.color, 1.8, None, 1.0);
            for q in &pts {
                svg.marker(*q, 3.2, look, 1.0);
            }
            let (b0, rr) = d
                .results
                .as_ref()
                .and_then(|r| r.temporal.get(*arm))
                .and_then(|per| per.get(p.as_str()))
                .map_or((f64::NAN, f64::NAN), |t| (t.first_minute, t.rate_ratio));
            if b0.is_finite() && rr.is_finite() {
                let fit: Vec<(f64, f64)> = (0..st.len())
                    .map(|m| ax.p(m as f64 + 1.0, b0 * rr.powi(m as i32)))
                    .collect();
                svg.polyline(&fit, look.color, 2.0, Some("8 4"), 1.0);
            }
            leg.push((Series { dash: None, ..look }, format!("π_{p}"), Key::Both));
        }
        if k + 1 == arms.len() {
            leg.push((
                Series {
                    color: "#555555",
                    dash: Some("8 4"),
                    ..SIM
                },
                "NB2 trend".into(),
                Key::Line,
            ));
            legend(&mut svg, ax.x + ax.w + 12.0, ax.y, &leg);
        }
    }
    Some(Figure {
        name: "goals_over_time",
        title: "Goals per minute over the trial".into(),
        caption: "Mean goals reached in each minute of control (line with markers) with a band of ±1 \
                  s.d. across trials, per policy; simulation left, reality right. Dashed: the fitted \
                  negative-binomial trend (goals per minute = first-minute rate × rate ratio^minute), \
                  whose rate ratio and p are in the temporal-trend table. Real fish that lose interest \
                  show a declining trend the simulated fish do not."
            .into(),
        svg: svg.finish(),
    })
}
