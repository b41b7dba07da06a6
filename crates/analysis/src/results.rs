//! The results of an analysis: `results.json` (shape documented in docs/guide/analyse.md), one CSV per
//! section, and a Markdown summary.

use crate::config::AnalysisConfig;
use serde::{Deserialize, Deserializer, Serialize};
use std::collections::BTreeMap;

/// Reading `results.json` back: serde_json writes NaN as `null`, so numbers read `null` (and
/// an absent field, from an older or partial analysis) as NaN. With these, the report reads the
/// same structs the analysis writes.
mod nan {
    use super::*;

    /// NaN: the default of numbers an older `results.json` lacks.
    pub fn nan() -> f64 {
        f64::NAN
    }

    /// A pair of NaNs.
    pub fn nan2() -> [f64; 2] {
        [f64::NAN; 2]
    }

    /// A number, `null` read as NaN.
    pub fn f64<'de, D: Deserializer<'de>>(d: D) -> Result<f64, D::Error> {
        Ok(Option::<f64>::deserialize(d)?.unwrap_or(f64::NAN))
    }

    /// An interval, `null` ends read as NaN.
    pub fn pair<'de, D: Deserializer<'de>>(d: D) -> Result<[f64; 2], D::Error> {
        let v = <[Option<f64>; 2]>::deserialize(d)?;
        Ok(v.map(|x| x.unwrap_or(f64::NAN)))
    }

    /// A map of numbers, `null` values read as NaN.
    pub fn map<'de, D: Deserializer<'de>>(d: D) -> Result<BTreeMap<String, f64>, D::Error> {
        let m = BTreeMap::<String, Option<f64>>::deserialize(d)?;
        Ok(m.into_iter()
            .map(|(k, v)| (k, v.unwrap_or(f64::NAN)))
            .collect())
    }
}

/// Every file `write_results` can write, in the order a reader meets them.
pub const OUTPUT_FILES: [&str; 14] = [
    fishprobe_io::layout::RESULTS_FILE,
    "summary.md",
    "competence.csv",
    "seeds.csv",
    "goals.csv",
    "sim_to_real.csv",
    "metric_gaps.csv",
    "mean_ranks.csv",
    "sim_to_sim.csv",
    "kruskal.csv",
    "temporal.csv",
    "time_to_goal.csv",
    "approach.csv",
    "stability.csv",
];

/// Per-trial goals of one policy.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
pub struct GoalsPair {
    /// Sim trials (the first `sim_trials` files of `<P>__<P>`).
    #[serde(default)]
    pub sim: Vec<u32>,
    /// Reality-arm trials.
    #[serde(default)]
    pub real: Vec<u32>,
}

/// The sim-to-real gap in goals reached.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
pub struct GoalGap {
    /// 1-Wasserstein distance between sim and real goals.
    #[serde(default = "nan::nan", deserialize_with = "nan::f64")]
    pub w: f64,
    /// Percentile-bootstrap interval.
    #[serde(default = "nan::nan2", deserialize_with = "nan::pair")]
    pub ci: [f64; 2],
    /// One-sided permutation p.
    #[serde(default = "nan::nan", deserialize_with = "nan::f64")]
    pub p: f64,
    /// Cliff's δ = P(sim > real) - P(sim < real).
    #[serde(default = "nan::nan", deserialize_with = "nan::f64")]
    pub cliffs_delta: f64,
    /// Its magnitude label.
    #[serde(default)]
    pub magnitude: String,
    /// Sim trials.
    #[serde(default)]
    pub n_sim: usize,
    /// Real trials.
    #[serde(default)]
    pub n_real: usize,
}

/// The sim-to-real gap in one per-frame metric.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
pub struct MetricGap {
    /// Median of the sim x real matrix of per-trial W1.
    #[serde(default = "nan::nan", deserialize_with = "nan::f64")]
    pub median: f64,
    /// Two-way cluster-bootstrap interval.
    #[serde(default = "nan::nan2", deserialize_with = "nan::pair")]
    pub ci: [f64; 2],
    /// Min-max normalised across policies within the metric.
    #[serde(default = "nan::nan", deserialize_with = "nan::f64")]
    pub normalized: f64,
    /// Rank within the metric (1 = smallest gap; ties share the average rank).
    #[serde(default = "nan::nan", deserialize_with = "nan::f64")]
    pub rank: f64,
}

/// One sim-to-sim cell.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
pub struct SimToSimCell {
    /// Median of the bootstrap distribution of W1.
    #[serde(default = "nan::nan", deserialize_with = "nan::f64")]
    pub median: f64,
    /// Its percentile interval.
    #[serde(default = "nan::nan2", deserialize_with = "nan::pair")]
    pub ci: [f64; 2],
    /// Holm-adjusted permutation p against the diagonal (`null` on the diagonal).
    pub p_holm: Option<f64>,
}

/// Kruskal-Wallis across rollout models.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
pub struct KruskalOut {
    /// Tie-corrected H.
    #[serde(default = "nan::nan", deserialize_with = "nan::f64")]
    pub h: f64,
    /// χ² p-value.
    #[serde(default = "nan::nan", deserialize_with = "nan::f64")]
    pub p: f64,
}

/// A negative-binomial trend of goals per minute.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
pub struct Trend {
    /// exp(β) per minute.
    #[serde(default = "nan::nan", deserialize_with = "nan::f64")]
    pub rate_ratio: f64,
    /// Wald interval of exp(β).
    #[serde(default = "nan::nan2", deserialize_with = "nan::pair")]
    pub ci: [f64; 2],
    /// Wald p of β.
    #[serde(default = "nan::nan", deserialize_with = "nan::f64")]
    pub p: f64,
    /// NB2 dispersion α.
    #[serde(default = "nan::nan", deserialize_with = "nan::f64")]
    pub alpha: f64,
    /// exp(intercept): the fitted goals in the first minute (with `rate_ratio`, the dashed
    /// trend line of the report's figure).
    #[serde(default = "nan::nan", deserialize_with = "nan::f64")]
    pub first_minute: f64,
}

/// Mean and sample s.d.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
pub struct MeanSd {
    /// Mean.
    #[serde(default = "nan::nan", deserialize_with = "nan::f64")]
    pub mean: f64,
    /// Sample standard deviation (n - 1); null below two values.
    #[serde(default = "nan::nan", deserialize_with = "nan::f64")]
    pub sd: f64,
    /// Trials with a value.
    #[serde(default)]
    pub n: usize,
}

/// Time to goal, sim and real.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
pub struct TimeToGoal {
    /// Sim trials.
    pub sim: Option<MeanSd>,
    /// Reality-arm trials.
    pub real: Option<MeanSd>,
}

/// How well a policy leads its own model's fish, next to the scripted controllers on the same
/// evaluation episodes (issue 20).
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
pub struct Competence {
    /// Mean goals per evaluation episode of the policy on its own model.
    pub policy_goals: f64,
    /// Episodes behind that mean.
    pub trials: usize,
    /// Mean goals of each scripted controller on the same episodes.
    pub baselines: BTreeMap<String, f64>,
    /// The best scripted controller.
    pub best: String,
    /// Its mean goals.
    pub best_goals: f64,
    /// `policy_goals / best_goals` (NaN, written null, when the best reaches none).
    #[serde(default = "nan::nan", deserialize_with = "nan::f64")]
    pub ratio: f64,
    /// Below `AnalysisConfig::competence_threshold`: a weak probe.
    pub weak: bool,
    /// Median seconds the policy took to reach its fish (within
    /// `AnalysisConfig::robot_reach_cm`) in those episodes; `None` without trials or when the
    /// median episode never reached it (results of versions before this measure too).
    #[serde(default)]
    pub reach_s: Option<f64>,
    /// The same median for each scripted controller on the same episodes (those with one). A
    /// probe that reaches its fish no sooner than the goal-seeker waits for it at the goal; one
    /// near fetch-and-lead's fetches it. The goal count alone hides the difference when the
    /// probe holds the fish once it has it.
    #[serde(default)]
    pub baselines_reach_s: BTreeMap<String, f64>,
    /// Standard error of `ratio` over the episodes (delta method,
    /// [`crate::competence::ratio_se`]); `None` with fewer than two episodes a side (results
    /// of versions before this measure too).
    #[serde(default)]
    pub ratio_se: Option<f64>,
}

/// The approach assay of one policy.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
pub struct Approach {
    /// Minimum robot-fish distance over all frames of all episodes (cm).
    #[serde(default = "nan::nan", deserialize_with = "nan::f64")]
    pub min_iid: f64,
    /// Mean robot-fish distance over all frames (cm).
    #[serde(default = "nan::nan", deserialize_with = "nan::f64")]
    pub mean_iid: f64,
    /// Fraction of frames in which the robot is closer to the fish than to the goal.
    #[serde(default = "nan::nan", deserialize_with = "nan::f64")]
    pub frac_closer_to_fish: f64,
    /// Episodes.
    #[serde(default)]
    pub episodes: usize,
}

/// One training seed of a policy: how well it leads its own model's fish and whether it goes
/// to the still fish of the approach assay (`crate::seeds`).
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
pub struct SeedProbe {
    /// The seed's name in the study (`seed0` is the policy itself).
    #[serde(default)]
    pub seed: String,
    /// Mean goals per stability episode on its own model (NaN, written null, without them).
    #[serde(default = "nan::nan", deserialize_with = "nan::f64")]
    pub goals: f64,
    /// Stability episodes behind `goals`.
    #[serde(default)]
    pub episodes: usize,
    /// Median seconds to reach its fish in those episodes ([`Competence::reach_s`]).
    #[serde(default)]
    pub reach_s: Option<f64>,
    /// `goals` over the best scripted controller's mean goals on the model's evaluation
    /// episodes (the same kind of episode, not the same ones; NaN without baselines).
    #[serde(default = "nan::nan", deserialize_with = "nan::f64")]
    pub ratio: f64,
    /// Standard error of `ratio` ([`Competence::ratio_se`]; the best controller's episodes are
    /// the evaluation's).
    #[serde(default)]
    pub ratio_se: Option<f64>,
    /// Its approach assay, when the study ran one for this seed.
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub approach: Option<Approach>,
    /// It goes to the still fish: closest at most `approach_closest_cm` and nearer the fish
    /// than the goal at least `approach_nearer_share` of the frames (false without an assay).
    #[serde(default)]
    pub goes_to_fish: bool,
}

/// Retraining stability.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
pub struct StabilityOut {
    /// σ²_between / σ²_within.
    #[serde(default = "nan::nan", deserialize_with = "nan::f64")]
    pub r: f64,
    /// Bootstrap interval.
    #[serde(default = "nan::nan2", deserialize_with = "nan::pair")]
    pub ci: [f64; 2],
    /// Permutation p.
    #[serde(default = "nan::nan", deserialize_with = "nan::f64")]
    pub p: f64,
}

/// Something left out, and why.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
pub struct Skipped {
    /// A file or a condition.
    #[serde(default)]
    pub what: String,
    /// Why.
    #[serde(default)]
    pub reason: String,
}

/// Everything `fishprobe analyze` computes. Sections whose inputs are absent are left out;
/// read back, an absent section is empty (so an older or partial `results.json` still reads).
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize, Default)]
#[serde(default)]
pub struct Results {
    /// "Real" or "VirtualLab" (virtual-lab results are never real).
    #[serde(skip_serializing_if = "Option::is_none")]
    pub reality: Option<String>,
    /// Per-trial goals.
    #[serde(skip_serializing_if = "BTreeMap::is_empty")]
    pub goals: BTreeMap<String, GoalsPair>,
    /// Sim-to-real gap in goals.
    #[serde(skip_serializing_if = "BTreeMap::is_empty")]
    pub sim_to_real: BTreeMap<String, GoalGap>,
    /// Per-metric gaps: metric → policy → gap.
    #[serde(skip_serializing_if = "BTreeMap::is_empty")]
    pub metric_gaps: BTreeMap<String, BTreeMap<String, MetricGap>>,
    /// Mean rank over the nine metrics.
    #[serde(
        skip_serializing_if = "BTreeMap::is_empty",
        deserialize_with = "nan::map"
    )]
    pub mean_ranks: BTreeMap<String, f64>,
    /// Policy → rollout model → cell.
    #[serde(skip_serializing_if = "BTreeMap::is_empty")]
    pub sim_to_sim: BTreeMap<String, BTreeMap<String, SimToSimCell>>,
    /// Policy → Kruskal-Wallis across rollout models.
    #[serde(skip_serializing_if = "BTreeMap::is_empty")]
    pub kruskal: BTreeMap<String, KruskalOut>,
    /// "sim" | "real" → policy | "total" → trend.
    #[serde(skip_serializing_if = "BTreeMap::is_empty")]
    pub temporal: BTreeMap<String, BTreeMap<String, Trend>>,
    /// Policy → time to goal.
    #[serde(skip_serializing_if = "BTreeMap::is_empty")]
    pub time_to_goal: BTreeMap<String, TimeToGoal>,
    /// Policy → approach assay.
    #[serde(skip_serializing_if = "BTreeMap::is_empty")]
    pub approach: BTreeMap<String, Approach>,
    /// Policy → probe competence (its goals next to the scripted controllers').
    #[serde(default, skip_serializing_if = "BTreeMap::is_empty")]
    pub competence: BTreeMap<String, Competence>,
    /// Policy → its training seeds in order (seed 0 first): competence and approach assay of
    /// each, for studies with more than one seed.
    #[serde(default, skip_serializing_if = "BTreeMap::is_empty")]
    pub seeds: BTreeMap<String, Vec<SeedProbe>>,
    /// Policy → the SHA-256 of the weights its own-model trials record (`policy_sha256`;
    /// absent for a scripted policy or trials that record none). Its other conditions were
    /// driven by the same weights, or left out (`skipped`).
    #[serde(default, skip_serializing_if = "BTreeMap::is_empty")]
    pub weights: BTreeMap<String, String>,
    /// Retraining stability.
    #[serde(skip_serializing_if = "Option::is_none")]
    pub stability: Option<StabilityOut>,
    /// What was left out.
    pub skipped: Vec<Skipped>,
    /// Master seed of the resampling.
    pub seed: u64,
    /// The settings used.
    pub config: AnalysisConfig,
}

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

    /// A short Markdown summary for terminals and lab notebooks.
    pub fn summary_markdown(&self) -> String {
        let mut s = String::from("# fishprobe analysis\n\n");
        match self.reality.as_deref() {
            Some(fishprobe_io::layout::VIRTUAL_LAB) => {
                s += "**Reality arm: VIRTUAL LAB.** These are not live-fish results.\n\n"
            }
            Some(r) => s += &format!("Reality arm: {r}.\n\n"),
            None => s += "No reality arm (no `<P>__Real` or `<P>__VirtualLab` trials).\n\n",
        }
        if !self.weights.is_empty() {
            let each: Vec<String> = self
                .weights
                .iter()
                .map(|(p, w)| format!("{p} `{}…`", fishprobe_io::short_sha(w)))
                .collect();
            s += &format!(
                "Weights that drove the trials (SHA-256): {}.\n\n",
                each.join(", ")
            );
        }
        if !self.sim_to_real.is_empty() {
            s += "## Sim-to-real gap, goals reached\n\n| policy | sim mean | real mean | W | 95 % CI | p | Cliff's δ |\n|---|---|---|---|---|---|---|\n";
            for (p, g) in &self.sim_to_real {
                let mean = |v: &[u32]| {
                    v.iter().map(|&x| f64::from(x)).sum::<f64>() / v.len().max(1) as f64
                };
                let pair = &self.goals[p];
                s += &format!(
                    "| {p} | {:.1} | {:.1} | {:.2} | [{:.2}, {:.2}] | {:.4} | {:.2} ({}) |\n",
                    mean(&pair.sim),
                    mean(&pair.real),
                    g.w,
                    g.ci[0],
                    g.ci[1],
                    g.p,
                    g.cliffs_delta,
                    g.magnitude
                );
            }
            s.push('\n');
        }
        if !self.competence.is_empty() {
            s += "## Probe competence: goals on the own model, next to the best scripted controller\n\n| policy | goals | best scripted | its goals | ratio | reaches its fish (median s) | scripted controllers reach it (median s) |\n|---|---|---|---|---|---|---|\n";
            for (p, c) in &self.competence {
                let scripted: Vec<String> = c
                    .baselines_reach_s
                    .iter()
                    .map(|(b, t)| format!("{b} {t:.1}"))
                    .collect();
                s += &format!(
                    "| {p} | {:.1} | {} | {:.1} | {:.2}{}{} | {} | {} |\n",
                    c.policy_goals,
                    c.best,
                    c.best_goals,
                    c.ratio,
                    crate::competence::plus_minus(c.ratio_se),
                    if c.weak { " **weak**" } else { "" },
                    c.reach_s.map_or("–".into(), |t| format!("{t:.1}")),
                    if scripted.is_empty() {
                        "–".into()
                    } else {
                        scripted.join(", ")
                    },
                );
            }
            s += &format!(
                "\nThe ratio's ± is its standard error over the episodes (delta method): a ratio \
                 within about two of them of the bar is not clearly on either side. \
                 Reaching the fish: the first moment a fish is within {} cm of the robot. A probe \
                 that takes as long as GoalSeeker waits at the goal for its fish to come by; one \
                 near FetchAndLead fetches it. The goal count hides the difference when the probe \
                 holds the fish once it has it.\n",
                self.config.robot_reach_cm
            );
            let weak: Vec<&str> = self
                .competence
                .iter()
                .filter(|(_, c)| c.weak)
                .map(|(p, _)| p.as_str())
                .collect();
            if !weak.is_empty() {
                s += &format!(
                    "\n**Warning:** {} reach{} less than {:.0} % of the best scripted controller's goals on \
                     {} own model: {} strateg{} reflect{} the optimiser, not only the model.\n",
                    weak.join(", "),
                    if weak.len() == 1 { "es" } else { "" },
                    100.0 * self.config.competence_threshold,
                    if weak.len() == 1 { "its" } else { "their" },
                    if weak.len() == 1 { "its" } else { "their" },
                    if weak.len() == 1 { "y" } else { "ies" },
                    if weak.len() == 1 { "s" } else { "" },
                );
                // Weak by less than two standard errors: the measurement cannot tell.
                let near: Vec<String> = self
                    .competence
                    .iter()
                    .filter(|(_, c)| c.weak)
                    .filter_map(|(p, c)| {
                        let se = c.ratio_se?;
                        (c.ratio + 2.0 * se >= self.config.competence_threshold)
                            .then(|| format!("{p} ({:.2} ± {se:.2})", c.ratio))
                    })
                    .collect();
                if !near.is_empty() {
                    s += &format!(
                        "Within two standard errors of the bar, so not clearly below it: {}; more evaluation episodes would tell.\n",
                        near.join(", ")
                    );
                }
            }
            s.push('\n');
        }
        if !self.seeds.is_empty() {
            s += &crate::seeds::summary_markdown(&self.seeds, &self.config);
        }
        if !self.mean_ranks.is_empty() {
            let over = if self.metric_gaps.len() > crate::METRICS.len() {
                "the nine pair and the group metrics"
            } else {
                "the nine metrics"
            };
            s += &format!("## Per-metric gaps: mean rank over {over} (1 = closest to reality)\n\n| policy | mean rank |\n|---|---|\n");
            for (p, r) in &self.mean_ranks {
                s += &format!("| {p} | {r:.2} |\n");
            }
            s.push('\n');
        }
        if !self.kruskal.is_empty() {
            s += "## Sim-to-sim: Kruskal-Wallis across rollout models\n\n| policy | H | p |\n|---|---|---|\n";
            for (p, k) in &self.kruskal {
                s += &format!("| {p} | {:.2} | {:.2e} |\n", k.h, k.p);
            }
            s.push('\n');
        }
        if let Some(st) = &self.stability {
            s += &format!(
                "## Retraining stability\n\nR = {:.2} [{:.2}, {:.2}], p = {:.4}\n\n",
                st.r, st.ci[0], st.ci[1], st.p
            );
        }
        if !self.skipped.is_empty() {
            s += &format!("## Skipped ({})\n\n", self.skipped.len());
            for k in &self.skipped {
                s += &format!("- {}: {}\n", k.what, k.reason);
            }
        }
        s
    }
}

#[cfg(test)]
mod tests {
    #![allow(clippy::unwrap_used)]
    use super::*;

    #[test]
    fn a_weak_probe_is_flagged_and_one_within_two_standard_errors_is_called_unclear() {
        let mut r = Results::default();
        let probe = |ratio: f64, se: Option<f64>| {
            let mut c = crate::competence::competence_of(
                ratio * 30.0,
                50,
                BTreeMap::from([("FetchAndLead".into(), 30.0)]),
                0.8,
            )
            .unwrap();
            c.ratio_se = se;
            c
        };
        r.competence
            .insert("ConvNet".into(), probe(0.78, Some(0.02)));
        r.competence.insert("Zone".into(), probe(0.7, Some(0.02)));
        r.competence.insert("Force".into(), probe(1.1, Some(0.01)));
        r.competence.insert("Follow".into(), probe(0.79, None));
        let md = r.summary_markdown();
        assert!(
            md.contains("| ConvNet | 23.4 | FetchAndLead | 30.0 | 0.78 ± 0.02 **weak** |"),
            "{md}"
        );
        assert!(
            md.contains("| Follow | 23.7 | FetchAndLead | 30.0 | 0.79 **weak** |"),
            "{md}"
        );
        assert!(
            md.contains("**Warning:** ConvNet, Follow, Zone reach less than 80 %"),
            "{md}"
        );
        // 0.78 + 2 · 0.02 reaches the bar; 0.70 does not, and without an error nothing is said.
        assert!(
            md.contains("not clearly below it: ConvNet (0.78 ± 0.02); more evaluation"),
            "{md}"
        );
        assert!(
            !md.contains("Zone (0.70") && !md.contains("Follow (0.79"),
            "{md}"
        );
    }

    #[test]
    fn results_read_back_as_written_with_nan_and_from_older_partial_files() {
        let mut r = Results {
            reality: Some("VirtualLab".into()),
            ..Results::default()
        };
        r.sim_to_real.insert(
            "Zone".into(),
            GoalGap {
                w: 1.5,
                ci: [f64::NAN, 2.0],
                p: f64::NAN,
                cliffs_delta: -0.25,
                magnitude: "small".into(),
                n_sim: 18,
                n_real: 17,
            },
        );
        r.mean_ranks.insert("Zone".into(), f64::NAN);
        let text = serde_json::to_string(&r).unwrap();
        let back: Results = serde_json::from_str(&text).unwrap();
        assert_eq!(serde_json::to_string(&back).unwrap(), text);
        assert!(back.sim_to_real["Zone"].p.is_nan() && back.mean_ranks["Zone"].is_nan());
        // An older analysis without `first_minute` in its trends, and without most sections.
        let old: Results = serde_json::from_str(
            r#"{"temporal": {"sim": {"Zone": {"rate_ratio": 0.98, "ci": [0.9, 1.1], "p": 0.5, "alpha": 0.1}}}}"#,
        )
        .unwrap();
        let t = &old.temporal["sim"]["Zone"];
        assert_eq!(t.rate_ratio, 0.98);
        assert!(t.first_minute.is_nan());
        assert!(old.goals.is_empty() && old.stability.is_none());
    }
}
