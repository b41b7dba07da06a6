//! The results of an analysis: `results.json` (shape documented in docs/guide/analyse.md), one CSV per
//! section, and a Markdown summary.

use crate::config::AnalysisConfig;
use serde::{Deserialize, Deserializer, Serialize};
use std::collections::BTreeMap;

mod csv;
pub mod seeds_table;
mod summary;

pub(crate) use csv::{f, table};

/// ` ± 0.03`: a ratio's standard error as the tables append it (empty without one).
pub fn plus_minus(se: Option<f64>) -> String {
    se.map_or(String::new(), |se| format!(" ± {se:.2}"))
}

/// Reading `results.json` back: serde_json writes NaN as `null`, so numbers read `null` (and
/// an absent field, from an older or partial analysis) as NaN. With these, the report reads the
/// same structs the analysis writes.
pub mod nan {
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
pub const OUTPUT_FILES: [&str; 15] = [
    fishprobe_io::layout::RESULTS_FILE,
    "summary.md",
    "competence.csv",
    "seeds.csv",
    "goals.csv",
    "sim_to_real.csv",
    "metric_gaps.csv",
    "mean_ranks.csv",
    "spread.csv",
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

/// The between-trial spread of one quantity for one policy (`spread`, see
/// [`crate::spread`]): do its simulated trials differ from one another as much as the real
/// ones?
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
pub struct SpreadEntry {
    /// Between-trial s.d. (n - 1) of the sim trials' values.
    #[serde(default = "nan::nan", deserialize_with = "nan::f64")]
    pub sd_sim: f64,
    /// Between-trial s.d. (n - 1) of the real trials' values.
    #[serde(default = "nan::nan", deserialize_with = "nan::f64")]
    pub sd_real: f64,
    /// `sd_sim / sd_real`: the share of the real spread the model reproduces (1: as varied
    /// as reality; 0.2: a fifth of it).
    #[serde(default = "nan::nan", deserialize_with = "nan::f64")]
    pub ratio: f64,
    /// Percentile-bootstrap interval of `ratio`, trials resampled within each side.
    #[serde(default = "nan::nan2", deserialize_with = "nan::pair")]
    pub ci: [f64; 2],
    /// 1-Wasserstein distance between the sim and the real per-trial values.
    #[serde(default = "nan::nan", deserialize_with = "nan::f64")]
    pub w1_trials: f64,
    /// Brown–Forsythe statistic (`scipy.stats.levene(sim, real, center="median")`).
    #[serde(default = "nan::nan", deserialize_with = "nan::f64")]
    pub bf_stat: f64,
    /// Its p-value.
    #[serde(default = "nan::nan", deserialize_with = "nan::f64")]
    pub bf_p: f64,
    /// Its p-value Holm-adjusted across the policies of this quantity.
    #[serde(default = "nan::nan", deserialize_with = "nan::f64")]
    pub bf_p_holm: f64,
    /// The sim trials' values, in file order.
    #[serde(default)]
    pub sim: Vec<f64>,
    /// The real trials' values, in file order.
    #[serde(default)]
    pub real: Vec<f64>,
}

impl Default for SpreadEntry {
    fn default() -> Self {
        Self {
            sd_sim: f64::NAN,
            sd_real: f64::NAN,
            ratio: f64::NAN,
            ci: [f64::NAN; 2],
            w1_trials: f64::NAN,
            bf_stat: f64::NAN,
            bf_p: f64::NAN,
            bf_p_holm: f64::NAN,
            sim: Vec::new(),
            real: Vec::new(),
        }
    }
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
/// evaluation episodes.
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
    /// `competence::ratio_se`); `None` with fewer than two episodes a side (results
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
/// to the still fish of the approach assay (`seeds`).
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
    /// The between-trial spread: quantity → policy → entry (see [`crate::spread`]).
    #[serde(skip_serializing_if = "BTreeMap::is_empty")]
    pub spread: BTreeMap<String, BTreeMap<String, SpreadEntry>>,
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
