//! The figures of the paper, drawn from a [`StudyData`]. Each returns `None` when its inputs
//! are absent (the report then says what is missing).

use crate::config::ReportConfig;
use crate::data::{StudyData, Track};
use crate::svg::{
    ink_on, legend, series, viridis, Anchor, Axes, Key, Series, Svg, TextStyle, REAL, SIM,
};
use fishprobe_analysis::METRICS;

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

/// Metric labels with units, in [`METRICS`] order.
pub const METRIC_LABELS: [&str; 9] = [
    "IID (cm)",
    "IID change (cm/s)",
    "alignment (cos)",
    "fish speed (cm/s)",
    "fish turn (rad/s)",
    "fish-goal dist. (cm)",
    "fish faces robot (cos)",
    "wall distance (cm)",
    "wall alignment (|cos|)",
];

fn arm_label(d: &StudyData) -> &'static str {
    match d.arm.as_deref() {
        Some(fishprobe_io::layout::VIRTUAL_LAB) => "virtual lab",
        _ => "real",
    }
}

fn fmt(v: f64, digits: usize) -> String {
    if v.is_finite() {
        format!("{v:.digits$}")
    } else {
        "–".into()
    }
}

fn mean(v: &[f64]) -> f64 {
    if v.is_empty() {
        f64::NAN
    } else {
        v.iter().sum::<f64>() / v.len() as f64
    }
}

fn sd(v: &[f64]) -> f64 {
    if v.len() < 2 {
        return f64::NAN;
    }
    let m = mean(v);
    (v.iter().map(|x| (x - m).powi(2)).sum::<f64>() / (v.len() - 1) as f64).sqrt()
}

fn range(values: impl Iterator<Item = f64>) -> (f64, f64) {
    values
        .filter(|v| v.is_finite())
        .fold((f64::INFINITY, f64::NEG_INFINITY), |(a, b), v| {
            (a.min(v), b.max(v))
        })
}

/// A deterministic jitter in [-1, 1] for the i-th point (low-discrepancy, no RNG needed).
fn jitter(i: usize) -> f64 {
    ((i as f64 * 0.618_033_988_75).fract() - 0.5) * 2.0
}

/// Fig. 3: goals reached per trial, sim vs reality.
pub fn goals(d: &StudyData) -> Option<Figure> {
    let g = d.section(&["goals"])?;
    let policies: Vec<&String> = g.keys().collect();
    let arr = |p: &str, arm: &str| -> Vec<f64> {
        g.get(p)
            .and_then(|v| v.get(arm))
            .and_then(|v| v.as_array())
            .map(|a| a.iter().filter_map(|x| x.as_f64()).collect())
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

/// Fig. 4: sim-to-real gap heatmap, policies × (goals + nine metrics).
pub fn gap_heatmap(d: &StudyData) -> Option<Figure> {
    let mg = d.section(&["metric_gaps"]);
    let s2r = d.section(&["sim_to_real"]);
    if mg.is_none() && s2r.is_none() {
        return None;
    }
    let mut policies: Vec<String> = s2r.map(|m| m.keys().cloned().collect()).unwrap_or_default();
    if let Some(mg) = mg {
        for per in mg.values().filter_map(|v| v.as_object()) {
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
        .map(|p| d.num(&["sim_to_real", p, "w"]))
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
                        ci: [
                            d.num(&["sim_to_real", p, "ci", "0"]),
                            d.num(&["sim_to_real", p, "ci", "1"]),
                        ],
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
    for (m, label) in METRICS.iter().zip(METRIC_LABELS) {
        let Some(per) = mg.and_then(|x| x.get(*m)).and_then(|v| v.as_object()) else {
            continue;
        };
        let cells = policies
            .iter()
            .map(|p| {
                per.get(p).map(|c| {
                    let g = |k: &str| c.get(k).and_then(|v| v.as_f64()).unwrap_or(f64::NAN);
                    let ci = c.get("ci").and_then(|v| v.as_array());
                    let ci_at = |i: usize| {
                        ci.and_then(|a| a.get(i))
                            .and_then(|v| v.as_f64())
                            .unwrap_or(f64::NAN)
                    };
                    Cell {
                        value: g("median"),
                        ci: [ci_at(0), ci_at(1)],
                        norm: g("normalized"),
                        rank: g("rank"),
                    }
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
        svg.text(
            left - 8.0,
            y + ch / 2.0 + 4.0,
            &format!("π_{p}"),
            TextStyle::new(12.0, Anchor::End).bold(),
        );
        for (j, (_, cells)) in columns.iter().enumerate() {
            let x = left + cw * j as f64;
            match &cells[i] {
                Some(c) => {
                    let t = if c.norm.is_finite() { c.norm } else { 0.0 };
                    let fill = viridis(t);
                    svg.rect(x, y, cw, ch, &fill, Some(("#ffffff", 1.0)));
                    let ink = ink_on(t);
                    let digits = if c.value.abs() >= 10.0 { 1 } else { 2 };
                    svg.text(
                        x + cw / 2.0,
                        y + 20.0,
                        &fmt(c.value, digits),
                        TextStyle::new(12.0, Anchor::Middle).color(ink),
                    );
                    svg.text(
                        x + cw / 2.0,
                        y + 34.0,
                        &format!("[{}, {}]", fmt(c.ci[0], digits), fmt(c.ci[1], digits)),
                        TextStyle::new(9.0, Anchor::Middle).color(ink),
                    );
                    svg.text(
                        x + cw / 2.0,
                        y + 48.0,
                        &format!(
                            "rank {}",
                            fmt(c.rank, if c.rank.fract() == 0.0 { 0 } else { 1 })
                        ),
                        TextStyle::new(10.0, Anchor::Middle).bold().color(ink),
                    );
                }
                None => {
                    svg.rect(x, y, cw, ch, "#f2f2f2", Some(("#ffffff", 1.0)));
                    svg.text(
                        x + cw / 2.0,
                        y + ch / 2.0 + 4.0,
                        "n/a",
                        TextStyle::new(10.0, Anchor::Middle),
                    );
                }
            }
        }
        svg.text(
            left + cw * columns.len() as f64 + 55.0,
            y + ch / 2.0 + 5.0,
            &fmt(d.num(&["mean_ranks", p]), 2),
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
        caption: "Rows: policies (each trained on one candidate model). Columns: the gap in goals \
                  reached (1-Wasserstein W between sim and real goal counts) and in nine per-frame \
                  behaviour metrics (median of the per-trial W1 between sim and real distributions). \
                  Each cell shows the gap, its 95 % bootstrap interval below it and its rank within the \
                  column (1 = closest to reality, in bold). Colour: the gap min-max normalised within \
                  the column (dark = small). Right: mean rank over the nine metrics; the model with the \
                  smallest mean rank taught the policy that transfers best."
            .into(),
        svg: svg.finish(),
    })
}

/// A 200 px viridis bar at `at` with labels under its two ends.
fn colour_bar(svg: &mut Svg, at: (f64, f64), low: &str, high: &str) {
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

/// Fig. 5: sim-to-sim matrix, training model × rollout model.
pub fn sim_to_sim(d: &StudyData) -> Option<Figure> {
    let m = d.section(&["sim_to_sim"])?;
    let rows: Vec<&String> = m.keys().collect();
    let mut cols: Vec<String> = Vec::new();
    for per in m.values().filter_map(|v| v.as_object()) {
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
            .map(move |c| d.num(&["sim_to_sim", p, c, "median"]))
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
        svg.text(
            left - 8.0,
            y + ch / 2.0 + 4.0,
            &format!("π_{p}"),
            TextStyle::new(12.0, Anchor::End).bold(),
        );
        for (j, c) in cols.iter().enumerate() {
            let x = left + cw * j as f64;
            let med = d.num(&["sim_to_sim", p, c, "median"]);
            if !med.is_finite() {
                svg.rect(x, y, cw, ch, "#f2f2f2", Some(("#ffffff", 1.0)));
                continue;
            }
            let t = if hi > lo { (med - lo) / (hi - lo) } else { 0.0 };
            svg.rect(x, y, cw, ch, &viridis(t), Some(("#ffffff", 1.0)));
            let ink = ink_on(t);
            svg.text(
                x + cw / 2.0,
                y + 22.0,
                &fmt(med, 1),
                TextStyle::new(13.0, Anchor::Middle).color(ink),
            );
            svg.text(
                x + cw / 2.0,
                y + 38.0,
                &format!(
                    "[{}, {}]",
                    fmt(d.num(&["sim_to_sim", p, c, "ci", "0"]), 1),
                    fmt(d.num(&["sim_to_sim", p, c, "ci", "1"]), 1)
                ),
                TextStyle::new(9.0, Anchor::Middle).color(ink),
            );
            let ph = d.num(&["sim_to_sim", p, c, "p_holm"]);
            if ph.is_finite() {
                svg.text(
                    x + cw / 2.0,
                    y + 50.0,
                    &format!("p_Holm {}", p_text(ph)),
                    TextStyle::new(9.0, Anchor::Middle).color(ink),
                );
            }
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
        let (kh, kp) = (d.num(&["kruskal", p, "h"]), d.num(&["kruskal", p, "p"]));
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

/// Gaussian smoothing of a histogram into a density (per cm).
fn density(hist: &[f64], frames: usize, cfg: &ReportConfig) -> Vec<f64> {
    let bin = f64::from(cfg.iid_bin_cm);
    let sigma = f64::from(cfg.iid_kernel_cm) / bin;
    let reach = (3.0 * sigma).ceil() as isize;
    let kernel: Vec<f64> = (-reach..=reach)
        .map(|k| (-0.5 * (k as f64 / sigma).powi(2)).exp())
        .collect();
    let ksum: f64 = kernel.iter().sum();
    let norm = (frames.max(1) as f64) * bin * ksum;
    (0..hist.len() as isize)
        .map(|i| {
            kernel
                .iter()
                .enumerate()
                .filter_map(|(k, w)| {
                    let j = i + k as isize - reach;
                    (j >= 0 && (j as usize) < hist.len()).then(|| w * hist[j as usize])
                })
                .sum::<f64>()
                / norm
        })
        .collect()
}

/// (columns, rows) of a panel grid: one row up to three panels, else two columns.
fn panels(n: usize) -> (usize, usize) {
    let cols = if n <= 3 { n.max(1) } else { 2 };
    (cols, n.div_ceil(cols).max(1))
}

/// Fig. 6: inter-individual distance densities per policy.
pub fn iid_density(d: &StudyData, cfg: &ReportConfig) -> Option<Figure> {
    let pol: Vec<(&String, &crate::data::PolicyTrials)> = d
        .trials
        .iter()
        .filter(|(_, t)| !t.sim.is_empty() || !t.real.is_empty())
        .collect();
    if pol.is_empty() {
        return None;
    }
    let bin = f64::from(cfg.iid_bin_cm);
    let curves = |v: &[crate::data::TrialNumbers]| -> (Vec<Vec<f64>>, Vec<f64>) {
        let per: Vec<Vec<f64>> = v
            .iter()
            .map(|t| density(&t.iid_hist, t.iid_frames, cfg))
            .collect();
        let mut pooled = vec![0.0; v.first().map_or(0, |t| t.iid_hist.len())];
        for t in v {
            for (a, b) in pooled.iter_mut().zip(&t.iid_hist) {
                *a += b;
            }
        }
        let frames = v.iter().map(|t| t.iid_frames).sum();
        (per, density(&pooled, frames, cfg))
    };
    let all: Vec<_> = pol
        .iter()
        .map(|(p, t)| (*p, curves(&t.sim), curves(&t.real)))
        .collect();
    let ymax = all
        .iter()
        .flat_map(|(_, s, r)| s.0.iter().chain(r.0.iter()).flatten().copied())
        .fold(0.0, f64::max);
    let (nc, nr) = panels(all.len());
    let (pw, ph) = (320.0, 200.0);
    let mut svg = Svg::new(
        80.0 + nc as f64 * (pw + 50.0),
        40.0 + nr as f64 * (ph + 80.0),
    );
    let real_name = arm_label(d);
    for (k, (p, s, r)) in all.iter().enumerate() {
        let (ci, ri) = (k % nc, k / nc);
        let ax = Axes::new(
            (
                70.0 + ci as f64 * (pw + 50.0),
                35.0 + ri as f64 * (ph + 80.0),
                pw,
                ph,
            ),
            (0.0, f64::from(cfg.iid_max_cm)),
            (0.0, ymax * 1.05),
        );
        ax.draw(
            &mut svg,
            "robot-fish distance (cm)",
            if ci == 0 { "density (1/cm)" } else { "" },
            &format!("π_{p}"),
            None,
        );
        for ((per, pooled), look) in [(s, SIM), (r, REAL)] {
            for c in per {
                let pts: Vec<(f64, f64)> = c
                    .iter()
                    .enumerate()
                    .map(|(i, y)| ax.p((i as f64 + 0.5) * bin, *y))
                    .collect();
                svg.polyline(&pts, look.color, 0.8, None, 0.45);
            }
            if !per.is_empty() {
                let pts: Vec<(f64, f64)> = pooled
                    .iter()
                    .enumerate()
                    .map(|(i, y)| ax.p((i as f64 + 0.5) * bin, *y))
                    .collect();
                svg.polyline(&pts, "#ffffff", 4.0, None, 0.9);
                svg.polyline(&pts, look.color, 2.4, Some("2 3"), 1.0);
            }
        }
        if k == 0 {
            legend(
                &mut svg,
                ax.x + ax.w - 165.0,
                ax.y + 6.0,
                &[
                    (
                        Series { dash: None, ..SIM },
                        "simulation, one trial".into(),
                        Key::Line,
                    ),
                    (
                        Series { dash: None, ..REAL },
                        format!("{real_name}, one trial"),
                        Key::Line,
                    ),
                    (
                        Series {
                            dash: Some("2 3"),
                            ..SIM
                        },
                        "simulation, pooled".into(),
                        Key::Line,
                    ),
                    (
                        Series {
                            dash: Some("2 3"),
                            ..REAL
                        },
                        format!("{real_name}, pooled"),
                        Key::Line,
                    ),
                ],
            );
        }
    }
    Some(Figure {
        name: "iid_density",
        title: "Robot-fish distance".into(),
        caption: format!(
            "Distribution of the distance between robot and fish during control, one panel per \
             policy. Thin lines: one trial each (simulation dark blue, {real_name} light orange); \
             dotted thick lines: all trials of the arm pooled. Densities are {} cm histograms \
             smoothed with a Gaussian of s.d. {} cm. Where the simulated fish follows the robot \
             more closely than the real fish, the blue mass sits left of the orange.",
            cfg.iid_bin_cm, cfg.iid_kernel_cm
        ),
        svg: svg.finish(),
    })
}

fn tank(svg: &mut Svg, ax: &Axes) {
    svg.rect(
        ax.px(-50.0),
        ax.py(50.0),
        ax.w,
        ax.h,
        "#f7fbff",
        Some(("#000000", 1.5)),
    );
}

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
            let (b0, rr) = (
                d.num(&["temporal", arm, p, "first_minute"]),
                d.num(&["temporal", arm, p, "rate_ratio"]),
            );
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

fn track_panel(svg: &mut Svg, ax: &Axes, t: &Track, look: Series, title: &str) {
    tank(svg, ax);
    let p = |v: &[f32; 2]| ax.p(f64::from(v[0]), f64::from(v[1]));
    let s = ax.w / 100.0;
    for g in &t.goals {
        svg.circle(
            p(g),
            f64::from(t.goal_radius_cm) * s,
            Some("#b9e3d3"),
            "#009E73",
            1.5,
        );
    }
    let robot: Vec<(f64, f64)> = t.robot.iter().map(p).collect();
    let fish: Vec<(f64, f64)> = t.fish.iter().map(p).collect();
    svg.polyline(&robot, "#000000", 1.0, None, 0.55);
    svg.polyline(&fish, look.color, 1.3, look.dash, 0.9);
    for r in &t.reached {
        svg.circle(p(r), 4.0, Some("#ffffff"), "#D55E00", 2.0);
    }
    svg.text(
        ax.x + ax.w / 2.0,
        ax.y - 8.0,
        title,
        TextStyle::new(12.0, Anchor::Middle).bold(),
    );
}

/// Example trajectories, one sim and one real per policy.
pub fn trajectories(d: &StudyData, cfg: &ReportConfig) -> Option<Figure> {
    let rows: Vec<(&String, &crate::data::PolicyTrials)> = d
        .trials
        .iter()
        .filter(|(_, t)| t.sim_track.is_some() || t.real_track.is_some())
        .collect();
    if rows.is_empty() {
        return None;
    }
    let side = 220.0;
    let n = rows.len() as f64;
    // A reality row only when some policy has a reality-arm trial.
    let arms = if d.arm.is_some() { 2 } else { 1 };
    let mut svg = Svg::new(
        40.0 + n * (side + 30.0),
        40.0 + arms as f64 * (side + 50.0) + 20.0,
    );
    let real_name = arm_label(d);
    let mut files = Vec::new();
    for (i, (p, t)) in rows.iter().enumerate() {
        for (j, (tr, look, arm)) in [(&t.sim_track, SIM, "sim"), (&t.real_track, REAL, real_name)]
            .into_iter()
            .take(arms)
            .enumerate()
        {
            let ax = Axes::new(
                (
                    30.0 + i as f64 * (side + 30.0),
                    40.0 + j as f64 * (side + 50.0),
                    side,
                    side,
                ),
                (-50.0, 50.0),
                (-50.0, 50.0),
            );
            match tr {
                Some(tr) => {
                    track_panel(
                        &mut svg,
                        &ax,
                        tr,
                        look,
                        &format!(
                            "π_{p}, {arm}: {} goal{}",
                            tr.reached.len(),
                            if tr.reached.len() == 1 { "" } else { "s" }
                        ),
                    );
                    files.push(format!(
                        "π_{p} {arm}: {}",
                        tr.path
                            .file_name()
                            .map(|n| n.to_string_lossy().into_owned())
                            .unwrap_or_default()
                    ));
                }
                None => {
                    svg.rect(ax.x, ax.y, side, side, "#f2f2f2", None);
                    svg.text(
                        ax.x + side / 2.0,
                        ax.y + side / 2.0,
                        &format!("no {arm} trial"),
                        TextStyle::new(11.0, Anchor::Middle),
                    );
                }
            }
        }
    }
    let ly = 40.0 + arms as f64 * (side + 50.0) - 5.0;
    svg.line((40.0, ly), (62.0, ly), "#000000", 1.5, None);
    svg.text(66.0, ly + 4.0, "robot", TextStyle::new(11.0, Anchor::Start));
    svg.line((120.0, ly), (142.0, ly), SIM.color, 1.5, None);
    svg.line((142.0, ly), (164.0, ly), REAL.color, 1.5, REAL.dash);
    svg.text(
        168.0,
        ly + 4.0,
        "fish (sim / reality)",
        TextStyle::new(11.0, Anchor::Start),
    );
    svg.circle((300.0, ly), 6.0, Some("#b9e3d3"), "#009E73", 1.5);
    svg.text(310.0, ly + 4.0, "goal", TextStyle::new(11.0, Anchor::Start));
    svg.circle((360.0, ly), 4.0, Some("#ffffff"), "#D55E00", 2.0);
    svg.text(
        368.0,
        ly + 4.0,
        "goal reached",
        TextStyle::new(11.0, Anchor::Start),
    );
    Some(Figure {
        name: "trajectories",
        title: "Example trajectories".into(),
        caption: format!(
            "Top view of the 100 × 100 cm tank during the first {} s of control of one trial per \
             policy (columns) and arm (rows: simulation, reality), the first file of each \
             condition ({}). Black: robot; coloured: fish; green discs: the goals (radius = goal \
             radius); open red circles: where the fish was when it reached a goal. The goal counts \
             in the panel titles are those of the drawn window.",
            cfg.trajectory_seconds,
            files.join("; ")
        ),
        svg: svg.finish(),
    })
}

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

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn smoothing_preserves_the_mass_of_a_histogram() {
        let cfg = ReportConfig::default();
        let mut h = vec![0.0; 100];
        h[50] = 30.0;
        h[20] = 10.0;
        let dens = density(&h, 40, &cfg);
        let mass: f64 = dens.iter().sum::<f64>() * f64::from(cfg.iid_bin_cm);
        assert!((mass - 1.0).abs() < 1e-9, "{mass}");
        assert!(dens[50] > dens[45] && dens[45] > dens[40]);
    }

    #[test]
    fn jitter_stays_within_one() {
        assert!((0..1000).map(jitter).all(|j| (-1.0..=1.0).contains(&j)));
    }
}
