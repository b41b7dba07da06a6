//! Fig. 5: sim-to-sim, each policy on each model.

use super::prelude::*;

/// Fig. 5: sim-to-sim matrix, training model × rollout model.
pub fn sim_to_sim(d: &StudyData) -> Option<Figure> {
    let r = d.results.as_ref()?;
    let m = &r.sim_to_sim;
    let cell = |p: &str, c: &str| m.get(p).and_then(|per| per.get(c));
    let rows: Vec<&String> = m.keys().collect();
    let mut cols: Vec<String> = Vec::new();
    for per in m.values() {
        for k in per.keys() {
            if !cols.contains(k) {
                cols.push(k.clone());
            }
        }
    }
    cols.sort();
    if rows.is_empty() || cols.is_empty() {
        return None;
    }
    let (lo, hi) = range(rows.iter().flat_map(|p| {
        cols.iter()
            .map(move |c| cell(p, c).map_or(f64::NAN, |x| x.median))
    }));
    let (cw, ch, left, top) = (104.0, 54.0, 130.0, 60.0);
    let w = (left + cw * cols.len() as f64 + 150.0).max(left + 500.0);
    let h = top + ch * rows.len() as f64 + 70.0;
    let mut svg = Svg::new(w, h);
    svg.text(
        left + cw * cols.len() as f64 / 2.0,
        20.0,
        "rollout model (fish the policy is tested against)",
        TextStyle::new(12.0, Anchor::Middle),
    );
    for (j, c) in cols.iter().enumerate() {
        svg.text(
            left + cw * (j as f64 + 0.5),
            top - 10.0,
            &format!("M_{c}"),
            TextStyle::new(12.0, Anchor::Middle).bold(),
        );
    }
    svg.text(
        left + cw * cols.len() as f64 + 75.0,
        top - 10.0,
        "Kruskal-Wallis",
        TextStyle::new(11.0, Anchor::Middle).bold(),
    );
    for (i, p) in rows.iter().enumerate() {
        let y = top + ch * i as f64;
        heat_row_label(&mut svg, left, y, ch, p);
        for (j, c) in cols.iter().enumerate() {
            let x = left + cw * j as f64;
            let med = cell(p, c).map_or(f64::NAN, |x| x.median);
            if !med.is_finite() {
                heat_cell(&mut svg, (x, y, cw, ch), None, &[], None);
                continue;
            }
            let t = if hi > lo { (med - lo) / (hi - lo) } else { 0.0 };
            let mut lines = vec![
                (22.0, fmt(med, 1), TextStyle::new(13.0, Anchor::Middle)),
                (
                    38.0,
                    format!(
                        "[{}, {}]",
                        fmt(cell(p, c).map_or(f64::NAN, |x| x.ci[0]), 1),
                        fmt(cell(p, c).map_or(f64::NAN, |x| x.ci[1]), 1)
                    ),
                    TextStyle::new(9.0, Anchor::Middle),
                ),
            ];
            let ph = cell(p, c).and_then(|x| x.p_holm).unwrap_or(f64::NAN);
            if ph.is_finite() {
                lines.push((
                    50.0,
                    format!("p_Holm {}", p_text(ph)),
                    TextStyle::new(9.0, Anchor::Middle),
                ));
            }
            heat_cell(&mut svg, (x, y, cw, ch), Some(t), &lines, None);
            if *p == c {
                svg.rect(
                    x + 1.5,
                    y + 1.5,
                    cw - 3.0,
                    ch - 3.0,
                    "none",
                    Some(("#D55E00", 3.0)),
                );
            }
        }
        let (kh, kp) = r
            .kruskal
            .get(*p)
            .map_or((f64::NAN, f64::NAN), |k| (k.h, k.p));
        svg.text(
            left + cw * cols.len() as f64 + 75.0,
            y + ch / 2.0,
            &format!("H = {}", fmt(kh, 1)),
            TextStyle::new(11.0, Anchor::Middle),
        );
        svg.text(
            left + cw * cols.len() as f64 + 75.0,
            y + ch / 2.0 + 14.0,
            &format!("p = {}", p_text(kp)),
            TextStyle::new(11.0, Anchor::Middle),
        );
    }
    svg.text(
        30.0,
        top + ch * rows.len() as f64 / 2.0,
        "training model (policy)",
        TextStyle::new(12.0, Anchor::Middle).rotated(-90.0),
    );
    let by = top + ch * rows.len() as f64 + 22.0;
    colour_bar(
        &mut svg,
        (left, by),
        &fmt(lo, 1),
        &format!("{} (W, goals)", fmt(hi, 1)),
    );
    svg.rect(
        left + 330.0,
        by - 2.0,
        26.0,
        14.0,
        "none",
        Some(("#D55E00", 3.0)),
    );
    svg.text(
        left + 362.0,
        by + 9.0,
        "own model (diagonal)",
        TextStyle::new(10.0, Anchor::Start),
    );
    Some(Figure {
        name: "sim_to_sim",
        title: "Sim-to-sim transfer between models".into(),
        caption: "Each policy (row) is run against every candidate model (column). A cell is the \
                  median 1-Wasserstein distance between the goals the policy reaches on that model and \
                  on its own model (bootstrap median, 95 % interval below; p_Holm: one-sided \
                  permutation test against the diagonal, Holm-adjusted within the row). The diagonal \
                  (own model, outlined) is small by construction; large off-diagonal cells mean the \
                  models teach different strategies, so the method can tell them apart. Right: \
                  Kruskal-Wallis across rollout models."
            .into(),
        svg: svg.finish(),
    })
}

fn p_text(p: f64) -> String {
    if !p.is_finite() {
        "–".into()
    } else if p < 0.001 {
        format!("{p:.1e}")
    } else {
        format!("{p:.3}")
    }
}
