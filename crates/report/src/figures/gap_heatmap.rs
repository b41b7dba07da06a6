//! Fig. 4: the sim-to-real gap heatmap, policies x (goals + the metrics).

use super::prelude::*;

/// The pair metrics (a study with groups has more columns).
const METRICS_IN_PAIRS: usize = fishprobe_analysis::METRICS.len();

/// Fig. 4: sim-to-real gap heatmap, policies × (goals + the per-frame metrics).
pub fn gap_heatmap(d: &StudyData) -> Option<Figure> {
    let r = d.results.as_ref()?;
    let mg = (!r.metric_gaps.is_empty()).then_some(&r.metric_gaps);
    let s2r = (!r.sim_to_real.is_empty()).then_some(&r.sim_to_real);
    if mg.is_none() && s2r.is_none() {
        return None;
    }
    let mut policies: Vec<String> = s2r.map(|m| m.keys().cloned().collect()).unwrap_or_default();
    if let Some(mg) = mg {
        for per in mg.values() {
            for p in per.keys() {
                if !policies.contains(p) {
                    policies.push(p.clone());
                }
            }
        }
    }
    policies.sort();
    // Columns: goals, then the metrics present.
    struct Cell {
        value: f64,
        ci: [f64; 2],
        norm: f64,
        rank: f64,
    }
    let goal_ws: Vec<f64> = policies
        .iter()
        .map(|p| r.sim_to_real.get(p).map_or(f64::NAN, |g| g.w))
        .collect();
    let (glo, ghi) = range(goal_ws.iter().copied());
    let mut columns: Vec<(String, Vec<Option<Cell>>)> = Vec::new();
    if s2r.is_some() {
        let mut sorted: Vec<f64> = goal_ws.iter().copied().filter(|v| v.is_finite()).collect();
        sorted.sort_by(f64::total_cmp);
        let cells = policies
            .iter()
            .zip(&goal_ws)
            .map(|(p, &w)| {
                w.is_finite().then(|| {
                    let below = sorted.iter().filter(|&&x| x < w).count() as f64;
                    let equal = sorted.iter().filter(|&&x| x == w).count() as f64;
                    Cell {
                        value: w,
                        ci: r
                            .sim_to_real
                            .get(p.as_str())
                            .map_or([f64::NAN; 2], |g| g.ci),
                        norm: if ghi > glo {
                            (w - glo) / (ghi - glo)
                        } else {
                            0.0
                        },
                        rank: below + (equal + 1.0) / 2.0,
                    }
                })
            })
            .collect();
        columns.push(("goals (W)".into(), cells));
    }
    for (m, label) in ALL_METRICS.iter().zip(METRIC_LABELS) {
        let Some(per) = mg.and_then(|x| x.get(*m)) else {
            continue;
        };
        let cells = policies
            .iter()
            .map(|p| {
                per.get(p).map(|c| Cell {
                    value: c.median,
                    ci: c.ci,
                    norm: c.normalized,
                    rank: c.rank,
                })
            })
            .collect();
        columns.push((label.to_string(), cells));
    }
    // The CI of the paper's per-metric table, "ci": [lo, hi], is an array; for goals too.
    let (cw, ch, left, top) = (96.0, 54.0, 120.0, 110.0);
    let w = left + cw * columns.len() as f64 + 110.0;
    let h = top + ch * policies.len() as f64 + 60.0;
    let mut svg = Svg::new(w, h);
    for (j, (label, _)) in columns.iter().enumerate() {
        let x = left + cw * (j as f64 + 0.5);
        svg.text(
            x,
            top - 8.0,
            label,
            TextStyle::new(11.0, Anchor::Start).rotated(-35.0),
        );
    }
    svg.text(
        left + cw * columns.len() as f64 + 55.0,
        top - 8.0,
        "mean rank",
        TextStyle::new(11.0, Anchor::Middle).bold(),
    );
    for (i, p) in policies.iter().enumerate() {
        let y = top + ch * i as f64;
        heat_row_label(&mut svg, left, y, ch, p);
        for (j, (_, cells)) in columns.iter().enumerate() {
            let x = left + cw * j as f64;
            let (shade, lines) = match &cells[i] {
                Some(c) => {
                    let digits = if c.value.abs() >= 10.0 { 1 } else { 2 };
                    let rank = fmt(c.rank, if c.rank.fract() == 0.0 { 0 } else { 1 });
                    let lines = vec![
                        (
                            20.0,
                            fmt(c.value, digits),
                            TextStyle::new(12.0, Anchor::Middle),
                        ),
                        (
                            34.0,
                            format!("[{}, {}]", fmt(c.ci[0], digits), fmt(c.ci[1], digits)),
                            TextStyle::new(9.0, Anchor::Middle),
                        ),
                        (
                            48.0,
                            format!("rank {rank}"),
                            TextStyle::new(10.0, Anchor::Middle).bold(),
                        ),
                    ];
                    (Some(if c.norm.is_finite() { c.norm } else { 0.0 }), lines)
                }
                None => (None, Vec::new()),
            };
            heat_cell(&mut svg, (x, y, cw, ch), shade, &lines, Some("n/a"));
        }
        svg.text(
            left + cw * columns.len() as f64 + 55.0,
            y + ch / 2.0 + 5.0,
            &fmt(r.mean_ranks.get(p).copied().unwrap_or(f64::NAN), 2),
            TextStyle::new(13.0, Anchor::Middle).bold(),
        );
    }
    colour_bar(
        &mut svg,
        (left, top + ch * policies.len() as f64 + 22.0),
        "smallest gap",
        "largest gap (within column)",
    );
    Some(Figure {
        name: "gap_heatmap",
        title: "Sim-to-real gap per policy and metric".into(),
        caption: {
            let pairs = fishprobe_analysis::count_word(METRICS_IN_PAIRS);
            let (metrics, over) = if columns.len() > METRICS_IN_PAIRS + 1 {
                (
                    format!(
                        "the {pairs} per-frame behaviour metrics and the {} group metrics",
                        fishprobe_analysis::count_word(fishprobe_analysis::GROUP_METRICS.len())
                    ),
                    "all metrics".to_string(),
                )
            } else {
                (
                    format!("{pairs} per-frame behaviour metrics"),
                    format!("the {pairs} metrics"),
                )
            };
            format!(
                "Rows: policies (each trained on one candidate model). Columns: the gap in goals \
                 reached (1-Wasserstein W between sim and real goal counts) and in {metrics} \
                 (median of the per-trial W1 between sim and real distributions). \
                 Each cell shows the gap, its 95 % bootstrap interval below it and its rank within the \
                 column (1 = closest to reality, in bold). Colour: the gap min-max normalised within \
                 the column (dark = small). Right: mean rank over {over}; the model with the \
                 smallest mean rank taught the policy that transfers best."
            )
        },
        svg: svg.finish(),
    })
}

#[cfg(test)]
mod tests {
    use super::*;
    use fishprobe_analysis::results::{MetricGap, Results};
    use fishprobe_analysis::{ALL_METRICS, METRIC_LABELS};

    /// A study with a gap for every metric of the table: the heatmap and the page's gap table
    /// show each one under its label. A metric added to the table but dropped by a figure or a
    /// table fails here.
    #[test]
    fn every_metric_of_the_table_is_in_the_heatmap_and_the_gap_table() {
        let gap = |m: usize| MetricGap {
            median: m as f64,
            ci: [0.0, m as f64 + 1.0],
            normalized: 0.5,
            rank: 1.0,
        };
        let mut results = Results::default();
        for (m, id) in ALL_METRICS.iter().enumerate() {
            for p in ["Zone", "Force"] {
                results
                    .metric_gaps
                    .entry((*id).to_string())
                    .or_default()
                    .insert(p.to_string(), gap(m));
            }
        }
        let d = StudyData {
            results: Some(results),
            ..StudyData::default()
        };
        let fig = gap_heatmap(&d).expect("a heatmap");
        let page = crate::html::Page {
            data: &d,
            figures: Vec::new(),
            report_dir: std::path::Path::new("."),
            version: "test",
        };
        let mut table = String::new();
        page.metric_gaps(&mut table);
        for label in METRIC_LABELS {
            let esc = label.replace('&', "&amp;");
            assert!(fig.svg.contains(&esc), "the heatmap lacks {label}");
            assert!(table.contains(&esc), "the gap table lacks {label}");
        }
        assert!(fig
            .caption
            .contains("the nine per-frame behaviour metrics and the six group metrics"));
    }
}
