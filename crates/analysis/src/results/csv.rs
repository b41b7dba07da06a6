//! The results as one CSV table per section.

use super::{MeanSd, Results};

fn csv_escape(s: &str) -> String {
    if s.contains([',', '"', '\n']) {
        format!("\"{}\"", s.replace('"', "\"\""))
    } else {
        s.to_string()
    }
}

pub(crate) fn table(header: &[&str], rows: Vec<Vec<String>>) -> String {
    let mut out = header.join(",") + "\n";
    for r in rows {
        out += &r
            .iter()
            .map(|c| csv_escape(c))
            .collect::<Vec<_>>()
            .join(",");
        out.push('\n');
    }
    out
}

pub(crate) fn f(x: f64) -> String {
    if x.is_finite() {
        format!("{x}")
    } else {
        String::new()
    }
}

impl Results {
    /// One CSV table per present section: (file name, contents).
    pub fn csv_tables(&self) -> Vec<(&'static str, String)> {
        let mut out = Vec::new();
        if !self.competence.is_empty() {
            let rows = self
                .competence
                .iter()
                .flat_map(|(p, c)| {
                    c.baselines.iter().map(move |(b, g)| {
                        let reach = |t: Option<&f64>| t.map_or(String::new(), f64::to_string);
                        vec![
                            p.clone(),
                            c.policy_goals.to_string(),
                            b.clone(),
                            g.to_string(),
                            (c.policy_goals / g).to_string(),
                            (b == &c.best).to_string(),
                            c.weak.to_string(),
                            reach(c.reach_s.as_ref()),
                            reach(c.baselines_reach_s.get(b)),
                            // The standard error belongs to the ratio to the best.
                            reach(c.ratio_se.as_ref().filter(|_| b == &c.best)),
                        ]
                    })
                })
                .collect();
            out.push((
                "competence.csv",
                table(
                    &[
                        "policy",
                        "policy_goals",
                        "baseline",
                        "baseline_goals",
                        "ratio",
                        "best",
                        "weak",
                        "policy_reach_s",
                        "baseline_reach_s",
                        "ratio_se",
                    ],
                    rows,
                ),
            ));
        }
        if !self.goals.is_empty() {
            let rows = self
                .goals
                .iter()
                .flat_map(|(p, g)| {
                    let sim = g.sim.iter().enumerate().map(move |(i, v)| {
                        vec![p.clone(), "sim".into(), i.to_string(), v.to_string()]
                    });
                    let real = g.real.iter().enumerate().map(move |(i, v)| {
                        vec![p.clone(), "real".into(), i.to_string(), v.to_string()]
                    });
                    sim.chain(real)
                })
                .collect();
            out.push((
                "goals.csv",
                table(&["policy", "arm", "trial", "goals_reached"], rows),
            ));
        }
        if !self.sim_to_real.is_empty() {
            let rows = self
                .sim_to_real
                .iter()
                .map(|(p, g)| {
                    vec![
                        p.clone(),
                        f(g.w),
                        f(g.ci[0]),
                        f(g.ci[1]),
                        f(g.p),
                        f(g.cliffs_delta),
                        g.magnitude.clone(),
                        g.n_sim.to_string(),
                        g.n_real.to_string(),
                    ]
                })
                .collect();
            out.push((
                "sim_to_real.csv",
                table(
                    &[
                        "policy",
                        "w",
                        "ci_low",
                        "ci_high",
                        "p",
                        "cliffs_delta",
                        "magnitude",
                        "n_sim",
                        "n_real",
                    ],
                    rows,
                ),
            ));
        }
        if !self.metric_gaps.is_empty() {
            let rows = self
                .metric_gaps
                .iter()
                .flat_map(|(m, per)| {
                    per.iter().map(move |(p, g)| {
                        vec![
                            m.clone(),
                            p.clone(),
                            f(g.median),
                            f(g.ci[0]),
                            f(g.ci[1]),
                            f(g.normalized),
                            f(g.rank),
                        ]
                    })
                })
                .collect();
            out.push((
                "metric_gaps.csv",
                table(
                    &[
                        "metric",
                        "policy",
                        "median_w",
                        "ci_low",
                        "ci_high",
                        "normalized",
                        "rank",
                    ],
                    rows,
                ),
            ));
            let rows = self
                .mean_ranks
                .iter()
                .map(|(p, r)| vec![p.clone(), f(*r)])
                .collect();
            out.push(("mean_ranks.csv", table(&["policy", "mean_rank"], rows)));
        }
        if !self.sim_to_sim.is_empty() {
            let rows = self
                .sim_to_sim
                .iter()
                .flat_map(|(p, per)| {
                    per.iter().map(move |(m, c)| {
                        vec![
                            p.clone(),
                            m.clone(),
                            f(c.median),
                            f(c.ci[0]),
                            f(c.ci[1]),
                            c.p_holm.map(f).unwrap_or_default(),
                        ]
                    })
                })
                .collect();
            out.push((
                "sim_to_sim.csv",
                table(
                    &[
                        "policy",
                        "rollout_model",
                        "median_w",
                        "ci_low",
                        "ci_high",
                        "p_holm",
                    ],
                    rows,
                ),
            ));
            let rows = self
                .kruskal
                .iter()
                .map(|(p, k)| vec![p.clone(), f(k.h), f(k.p)])
                .collect();
            out.push(("kruskal.csv", table(&["policy", "h", "p"], rows)));
        }
        if !self.temporal.is_empty() {
            let rows = self
                .temporal
                .iter()
                .flat_map(|(arm, per)| {
                    per.iter().map(move |(p, t)| {
                        vec![
                            arm.clone(),
                            p.clone(),
                            f(t.rate_ratio),
                            f(t.ci[0]),
                            f(t.ci[1]),
                            f(t.p),
                            f(t.alpha),
                            f(t.first_minute),
                        ]
                    })
                })
                .collect();
            out.push((
                "temporal.csv",
                table(
                    &[
                        "arm",
                        "policy",
                        "rate_ratio",
                        "ci_low",
                        "ci_high",
                        "p",
                        "alpha",
                        "first_minute",
                    ],
                    rows,
                ),
            ));
        }
        if !self.time_to_goal.is_empty() {
            let cell = |m: &Option<MeanSd>| {
                m.as_ref()
                    .map_or([String::new(), String::new(), "0".into()], |m| {
                        [f(m.mean), f(m.sd), m.n.to_string()]
                    })
            };
            let rows = self
                .time_to_goal
                .iter()
                .map(|(p, t)| {
                    let mut r = vec![p.clone()];
                    r.extend(cell(&t.sim));
                    r.extend(cell(&t.real));
                    r
                })
                .collect();
            out.push((
                "time_to_goal.csv",
                table(
                    &[
                        "policy",
                        "sim_mean_s",
                        "sim_sd_s",
                        "sim_n",
                        "real_mean_s",
                        "real_sd_s",
                        "real_n",
                    ],
                    rows,
                ),
            ));
        }
        if !self.approach.is_empty() {
            let rows = self
                .approach
                .iter()
                .map(|(p, a)| {
                    vec![
                        p.clone(),
                        f(a.min_iid),
                        f(a.mean_iid),
                        f(a.frac_closer_to_fish),
                        a.episodes.to_string(),
                    ]
                })
                .collect();
            out.push((
                "approach.csv",
                table(
                    &[
                        "policy",
                        "min_iid_cm",
                        "mean_iid_cm",
                        "frac_closer_to_fish",
                        "episodes",
                    ],
                    rows,
                ),
            ));
        }
        if !self.seeds.is_empty() {
            out.push(("seeds.csv", crate::seeds::csv(&self.seeds)));
        }
        if let Some(s) = &self.stability {
            out.push((
                "stability.csv",
                table(
                    &["r", "ci_low", "ci_high", "p"],
                    vec![vec![f(s.r), f(s.ci[0]), f(s.ci[1]), f(s.p)]],
                ),
            ));
        }
        out
    }
}
