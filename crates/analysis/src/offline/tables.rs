//! The offline comparison's tables: CSV files and the Markdown of `offline.md`.

use super::{Comparison, OfflineResults, OFFLINE_METRICS, RECORDING_STATS};
use crate::results::{f, table};

/// The comparisons present, each with its name in the tables and whether it has a robot.
fn present(r: &OfflineResults) -> Vec<(&'static str, bool, &Comparison)> {
    let mut v = Vec::new();
    if !r.pairs.recordings.is_empty() {
        v.push(("pairs", false, &r.pairs));
    }
    if let Some(o) = &r.open_loop {
        v.push(("open_loop", true, o));
    }
    v
}

impl OfflineResults {
    /// Every CSV table: (file name, contents).
    pub fn csv_tables(&self) -> Vec<(&'static str, String)> {
        vec![
            ("offline.csv", self.csv()),
            ("offline_spread.csv", self.spread_csv()),
            ("offline_recordings.csv", self.recordings_csv()),
            ("offline_correlations.csv", self.correlations_csv()),
        ]
    }

    /// `offline.csv`: the pooled gaps, a row per comparison, model and measure.
    pub fn csv(&self) -> String {
        let mut rows = Vec::new();
        for (kind, _, c) in present(self) {
            for (model, per) in &c.gaps {
                for m in OFFLINE_METRICS {
                    if let Some(g) = per.get(m.id) {
                        rows.push(vec![
                            kind.to_string(),
                            model.clone(),
                            m.id.into(),
                            m.unit.into(),
                            f(g.w),
                            f(g.ci[0]),
                            f(g.ci[1]),
                            g.n_real.to_string(),
                            g.n_model.to_string(),
                        ]);
                    }
                }
            }
        }
        table(
            &[
                "recordings",
                "model",
                "metric",
                "unit",
                "w",
                "ci_low",
                "ci_high",
                "n_real",
                "n_model",
            ],
            rows,
        )
    }

    /// `offline_spread.csv`: per comparison, statistic and model, how much the model's
    /// recordings differ from one another against the real ones.
    fn spread_csv(&self) -> String {
        let mut rows = Vec::new();
        for (kind, _, c) in present(self) {
            let sp = &c.spread;
            for s in RECORDING_STATS {
                for (model, per) in &sp.models {
                    let Some(e) = per.get(s.id) else { continue };
                    rows.push(vec![
                        kind.to_string(),
                        s.id.into(),
                        model.clone(),
                        e.real.len().to_string(),
                        e.sim.len().to_string(),
                        f(e.sd_real),
                        f(e.sd_sim),
                        f(e.ratio),
                        f(e.ci[0]),
                        f(e.ci[1]),
                        f(e.w1_trials),
                        f(sp.split_half.get(s.id).copied().unwrap_or(f64::NAN)),
                        f(sp.floor.get(s.id).copied().unwrap_or(f64::NAN)),
                        f(e.bf_stat),
                        f(e.bf_p),
                    ]);
                }
            }
        }
        table(
            &[
                "recordings",
                "statistic",
                "model",
                "n_real",
                "n_model",
                "sd_real",
                "sd_model",
                "ratio",
                "ci_low",
                "ci_high",
                "w1_recordings",
                "split_half_w1",
                "floor_w1",
                "bf_stat",
                "bf_p",
            ],
            rows,
        )
    }

    /// `offline_recordings.csv`: every recording's value of every statistic, real and per
    /// model (long format).
    fn recordings_csv(&self) -> String {
        let mut rows = Vec::new();
        for (kind, _, c) in present(self) {
            for s in RECORDING_STATS {
                for (source, per) in &c.spread.values {
                    let Some(values) = per.get(s.id) else {
                        continue;
                    };
                    // A model's simulation i is of recording i mod n (`replicates`).
                    let n = c.recordings.len().max(1);
                    for (i, v) in values.iter().enumerate() {
                        rows.push(vec![
                            kind.to_string(),
                            c.recordings[i % n].clone(),
                            (i / n).to_string(),
                            source.clone(),
                            s.id.into(),
                            v.map_or(String::new(), f),
                        ]);
                    }
                }
            }
        }
        table(
            &[
                "recordings",
                "recording",
                "replicate",
                "source",
                "statistic",
                "value",
            ],
            rows,
        )
    }

    /// `offline_correlations.csv`: Spearman's ρ between every two statistics across
    /// recordings, real and per model.
    fn correlations_csv(&self) -> String {
        let mut rows = Vec::new();
        for (kind, _, c) in present(self) {
            for (source, list) in &c.spread.correlations {
                for k in list {
                    rows.push(vec![
                        kind.to_string(),
                        source.clone(),
                        k.a.clone(),
                        k.b.clone(),
                        f(k.rho),
                        f(k.p),
                        k.n.to_string(),
                    ]);
                }
            }
        }
        table(&["recordings", "source", "a", "b", "rho", "p", "n"], rows)
    }

    /// `offline.md`: per comparison, the pooled gaps, the spread across recordings and the
    /// correlations between the statistics.
    pub fn markdown(&self) -> String {
        let mut s = String::new();
        for (kind, robot, c) in present(self) {
            s += &match kind {
                "pairs" => format!(
                    "## Model pairs against {} recorded pairs of live fish\n\n",
                    c.recordings.len()
                ),
                _ => format!(
                    "## Open loop: model fish beside the robot's recorded path, against {} robot recordings with a live fish\n\n",
                    c.recordings.len()
                ),
            };
            s += "1-Wasserstein distance between the pooled values [95 % bootstrap CI over recordings]; smallest per measure in bold.\n\n";
            s += &gaps_markdown(c, robot);
            s += &spread_markdown(c, robot);
            s += &correlations_markdown(c, robot);
        }
        s
    }
}

fn gaps_markdown(c: &Comparison, robot: bool) -> String {
    let models: Vec<&String> = c.gaps.keys().collect();
    let mut s = String::from("| measure |");
    for m in &models {
        s += &format!(" M_{m} |");
    }
    s += "\n|---|";
    s += &"---|".repeat(models.len());
    s.push('\n');
    for metric in OFFLINE_METRICS {
        let ws: Vec<f64> = models
            .iter()
            .map(|m| c.gaps[*m].get(metric.id).map_or(f64::NAN, |g| g.w))
            .collect();
        let best = ws
            .iter()
            .copied()
            .filter(|w| w.is_finite())
            .fold(f64::INFINITY, f64::min);
        s += &format!("| {} ({}) |", metric.label_for(robot), metric.unit);
        for (m, w) in models.iter().zip(&ws) {
            let Some(g) = c.gaps[*m].get(metric.id) else {
                s += " – |";
                continue;
            };
            let cell = format!("{w:.3} [{:.3}, {:.3}]", g.ci[0], g.ci[1]);
            s += &if *w == best {
                format!(" **{cell}** |")
            } else {
                format!(" {cell} |")
            };
        }
        s.push('\n');
    }
    s.push('\n');
    s
}

fn spread_markdown(c: &Comparison, robot: bool) -> String {
    let sp = &c.spread;
    let models: Vec<&String> = sp.models.keys().collect();
    let unit = if robot { "recording" } else { "pair" };
    let mut s = format!(
        "### How much recordings differ: s.d. across recordings, model / real\n\n\
         Per {unit}, one value of each statistic; the ratio is the s.d. of the model's values \
         over the s.d. of the real ones (1: as varied as the live fish) [95 % bootstrap CI]; \
         W1: the distance between the per-recording values, beside the floor that sampling \
         alone gives (the real recordings' split-half distance scaled to these sample sizes).\n\n\
         | statistic | real s.d. | floor W1 |"
    );
    for m in &models {
        s += &format!(" M_{m} ratio | M_{m} W1 |");
    }
    s += "\n|---|---|---|";
    s += &"---|---|".repeat(models.len());
    s.push('\n');
    for st in RECORDING_STATS {
        let sd_real = sp
            .models
            .values()
            .find_map(|m| m.get(st.id))
            .map_or(f64::NAN, |e| e.sd_real);
        s += &format!(
            "| {} | {} | {} |",
            st.label_for(robot).replace('|', "\\|"),
            num(sd_real),
            num(sp.floor.get(st.id).copied().unwrap_or(f64::NAN))
        );
        for m in &models {
            match sp.models[*m].get(st.id) {
                Some(e) => {
                    s += &format!(
                        " {} [{}, {}] | {} |",
                        num(e.ratio),
                        num(e.ci[0]),
                        num(e.ci[1]),
                        num(e.w1_trials)
                    )
                }
                None => s += " – | – |",
            }
        }
        s.push('\n');
    }
    s.push('\n');
    s
}

fn correlations_markdown(c: &Comparison, robot: bool) -> String {
    let sp = &c.spread;
    let Some(real) = sp.correlations.get("real") else {
        return String::new();
    };
    if real.iter().all(|k| !k.rho.is_finite()) {
        return "Too few recordings for correlations between the statistics.\n\n".into();
    }
    let models: Vec<&String> = sp.models.keys().collect();
    let label = |id: &str| -> String {
        RECORDING_STATS
            .iter()
            .find(|s| s.id == id)
            .map_or(id, |s| s.label_for(robot))
            .to_string()
    };
    let mut s = String::from(
        "### Do the statistics go together across recordings? Spearman's ρ, real beside each model\n\n\
         (\\* real ρ with p < 0.05)\n\n| statistics | real |",
    );
    for m in &models {
        s += &format!(" M_{m} |");
    }
    s += "\n|---|---|";
    s += &"---|".repeat(models.len());
    s.push('\n');
    for (i, k) in real.iter().enumerate() {
        s += &format!(
            "| {} ~ {} | {}{} |",
            label(&k.a).replace('|', "\\|"),
            label(&k.b).replace('|', "\\|"),
            num(k.rho),
            if k.p < 0.05 { " \\*" } else { "" }
        );
        for m in &models {
            let rho = sp
                .correlations
                .get(*m)
                .and_then(|l| l.get(i))
                .map_or(f64::NAN, |k| k.rho);
            s += &format!(" {} |", num(rho));
        }
        s.push('\n');
    }
    s.push('\n');
    s
}

/// A number for the tables: three significant digits, "–" when undefined.
fn num(x: f64) -> String {
    if !x.is_finite() {
        return "–".into();
    }
    if x == 0.0 {
        return "0".into();
    }
    if x.abs() < 1e-3 {
        return format!("{x:.1e}");
    }
    let digits = (2 - x.abs().log10().floor() as i32).clamp(0, 6) as usize;
    format!("{x:.digits$}")
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn numbers_keep_three_significant_digits() {
        assert_eq!(num(2.4812), "2.48");
        assert_eq!(num(0.07134), "0.0713");
        assert_eq!(num(11.14), "11.1");
        assert_eq!(num(123.4), "123");
        assert_eq!(num(f64::NAN), "–");
        assert_eq!(num(0.0), "0");
        assert_eq!(num(3.2e-17), "3.2e-17");
    }
}
