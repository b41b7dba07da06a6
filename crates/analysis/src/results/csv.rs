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

/// A CSV table: its file name, whether the results have its section, and what writes it.
type CsvTable = (&'static str, bool, fn(&Results) -> String);

impl Results {
    /// One CSV table per present section: (file name, contents).
    pub fn csv_tables(&self) -> Vec<(&'static str, String)> {
        let tables: [CsvTable; 13] = [
            (
                "competence.csv",
                !self.competence.is_empty(),
                Self::competence_csv,
            ),
            ("goals.csv", !self.goals.is_empty(), Self::goals_csv),
            (
                "sim_to_real.csv",
                !self.sim_to_real.is_empty(),
                Self::sim_to_real_csv,
            ),
            (
                "metric_gaps.csv",
                !self.metric_gaps.is_empty(),
                Self::metric_gaps_csv,
            ),
            (
                "mean_ranks.csv",
                !self.metric_gaps.is_empty(),
                Self::mean_ranks_csv,
            ),
            ("spread.csv", !self.spread.is_empty(), Self::spread_csv),
            (
                "sim_to_sim.csv",
                !self.sim_to_sim.is_empty(),
                Self::sim_to_sim_csv,
            ),
            (
                "kruskal.csv",
                !self.sim_to_sim.is_empty(),
                Self::kruskal_csv,
            ),
            (
                "temporal.csv",
                !self.temporal.is_empty(),
                Self::temporal_csv,
            ),
            (
                "time_to_goal.csv",
                !self.time_to_goal.is_empty(),
                Self::time_to_goal_csv,
            ),
            (
                "approach.csv",
                !self.approach.is_empty(),
                Self::approach_csv,
            ),
            ("seeds.csv", !self.seeds.is_empty(), Self::seeds_csv),
            (
                "stability.csv",
                self.stability.is_some(),
                Self::stability_csv,
            ),
        ];
        tables
            .into_iter()
            .filter(|(_, present, _)| *present)
            .map(|(name, _, make)| (name, make(self)))
            .collect()
    }

    /// `spread.csv`: per quantity (in table order) and policy, the between-trial spread.
    fn spread_csv(&self) -> String {
        let rows = crate::spread::quantities()
            .into_iter()
            .filter_map(|q| self.spread.get(q.id()).map(|per| (q, per)))
            .flat_map(|(q, per)| {
                per.iter().map(move |(p, e)| {
                    vec![
                        q.id().to_string(),
                        p.clone(),
                        e.sim.len().to_string(),
                        e.real.len().to_string(),
                        f(e.sd_sim),
                        f(e.sd_real),
                        f(e.ratio),
                        f(e.ci[0]),
                        f(e.ci[1]),
                        f(e.w1_trials),
                        f(e.bf_stat),
                        f(e.bf_p),
                        f(e.bf_p_holm),
                    ]
                })
            })
            .collect();
        table(
            &[
                "quantity",
                "policy",
                "n_sim",
                "n_real",
                "sd_sim",
                "sd_real",
                "ratio",
                "ci_low",
                "ci_high",
                "w1_trials",
                "bf_stat",
                "bf_p",
                "bf_p_holm",
            ],
            rows,
        )
    }

    /// `competence.csv`: each policy's goals beside each scripted controller's on the same
    /// episodes: the ratio, whether that controller is the best, the times to reach the fish.
    fn competence_csv(&self) -> String {
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
        )
    }

    /// `goals.csv`: goals reached per trial, each policy's simulated and reality arm.
    fn goals_csv(&self) -> String {
        let rows =
            self.goals
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
        table(&["policy", "arm", "trial", "goals_reached"], rows)
    }

    /// `sim_to_real.csv`: the sim-to-real gap of each policy's goals: Wasserstein distance with its
    /// interval, p, Cliff's delta.
    fn sim_to_real_csv(&self) -> String {
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
        )
    }

    /// `metric_gaps.csv`: each behavioural metric's gap per policy: median Wasserstein distance
    /// with its interval, normalised, and its rank.
    fn metric_gaps_csv(&self) -> String {
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
        )
    }

    /// `mean_ranks.csv`: each policy's mean rank over the metrics.
    fn mean_ranks_csv(&self) -> String {
        let rows = self
            .mean_ranks
            .iter()
            .map(|(p, r)| vec![p.clone(), f(*r)])
            .collect();
        table(&["policy", "mean_rank"], rows)
    }

    /// `sim_to_sim.csv`: each policy's sim-to-sim cells, one per rollout model: the median
    /// Wasserstein distance with its interval and the Holm-adjusted p.
    fn sim_to_sim_csv(&self) -> String {
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
        )
    }

    /// `kruskal.csv`: Kruskal-Wallis across each policy's rollout models.
    fn kruskal_csv(&self) -> String {
        let rows = self
            .kruskal
            .iter()
            .map(|(p, k)| vec![p.clone(), f(k.h), f(k.p)])
            .collect();
        table(&["policy", "h", "p"], rows)
    }

    /// `temporal.csv`: goals over time per arm and policy: the negative-binomial rate ratio with
    /// its interval, p, α and the first minute.
    fn temporal_csv(&self) -> String {
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
        )
    }

    /// `time_to_goal.csv`: mean and s.d. of the time to goal, simulated and real.
    fn time_to_goal_csv(&self) -> String {
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
        )
    }

    /// `approach.csv`: the approach assay per policy: closest and mean distance to the fish, the
    /// share of frames nearer the fish than the goal.
    fn approach_csv(&self) -> String {
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
        table(
            &[
                "policy",
                "min_iid_cm",
                "mean_iid_cm",
                "frac_closer_to_fish",
                "episodes",
            ],
            rows,
        )
    }

    /// `seeds.csv`: every training seed's competence and approach assay.
    fn seeds_csv(&self) -> String {
        super::seeds_table::csv(&self.seeds)
    }

    /// `stability.csv`: retraining stability, σ²_between / σ²_within over the training seeds, with
    /// its bootstrap interval and permutation p.
    fn stability_csv(&self) -> String {
        let Some(s) = &self.stability else {
            return String::new();
        };
        table(
            &["r", "ci_low", "ci_high", "p"],
            vec![vec![f(s.r), f(s.ci[0]), f(s.ci[1]), f(s.p)]],
        )
    }
}
