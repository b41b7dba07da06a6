//! The between-trial spread (SPEC §11): do simulated trials differ from one another as much
//! as live ones? The paper's main residual finding is that simulated distributions are
//! narrower than real ones; this section measures it per policy and quantity.
//!
//! Each trial gives one value per quantity: goals reached, mean time to goal, the fraction of
//! frames in which the fish was paused (slower than `pause_cm_s`), and for every metric of the
//! metric table its per-trial summary ([`crate::metric::PerTrial`]: the median for distances,
//! the mean of |·| for signed rates, the mean otherwise). Per policy and quantity, over the sim
//! and the real trials: the between-trial s.d. (n - 1) of each side; their ratio sim / real,
//! the share of the real spread the model reproduces, with a percentile-bootstrap interval
//! (trials resampled within each side); the 1-Wasserstein distance between the two sets of
//! per-trial values; and the Brown–Forsythe test of equal spread
//! (`scipy.stats.levene(sim, real, center="median")`), Holm-adjusted across policies per
//! quantity.

use crate::config::AnalysisConfig;
use crate::metric::{METRIC_TABLE, PAIR_METRIC_COUNT};
use crate::results::{Results, Skipped, SpreadEntry};
use crate::trial::TrialData;
use fishprobe_sim::stream;
use fishprobe_stats as st;
use rayon::prelude::*;
use std::collections::BTreeMap;

/// One quantity whose between-trial spread is measured.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum Quantity {
    /// Goals reached in the trial's control phase.
    Goals,
    /// The trial's mean time to goal (trials without a goal have none).
    TimeToGoal,
    /// The fraction of the fish's frames slower than `AnalysisConfig::pause_cm_s`.
    PausedFraction,
    /// A metric of [`METRIC_TABLE`] (its index), summarised per trial as the table says.
    Metric(usize),
}

/// Every quantity, in the order tables show them.
pub fn quantities() -> Vec<Quantity> {
    let mut q = vec![
        Quantity::Goals,
        Quantity::TimeToGoal,
        Quantity::PausedFraction,
    ];
    q.extend((0..METRIC_TABLE.len()).map(Quantity::Metric));
    q
}

impl Quantity {
    /// Its id: the key in `results.json` and the CSV.
    pub fn id(self) -> &'static str {
        match self {
            Self::Goals => "goals",
            Self::TimeToGoal => "time_to_goal",
            Self::PausedFraction => "paused_fraction",
            Self::Metric(m) => METRIC_TABLE[m].id,
        }
    }

    /// The quantity by its id.
    pub fn by_id(id: &str) -> Option<Self> {
        quantities().into_iter().find(|q| q.id() == id)
    }

    /// Its label with unit and, for a metric, how a trial's frames are summarised.
    pub fn label(self) -> String {
        match self {
            Self::Goals => "goals per trial".into(),
            Self::TimeToGoal => "time to goal (s)".into(),
            Self::PausedFraction => "paused fraction".into(),
            Self::Metric(m) => {
                let (how, label) = (METRIC_TABLE[m].per_trial, METRIC_TABLE[m].label);
                match (how, label.rsplit_once(" (")) {
                    (crate::metric::PerTrial::MeanAbsolute, Some((name, unit))) => {
                        format!("mean |{name}| ({unit}")
                    }
                    _ => format!("{} {label}", how.word()),
                }
            }
        }
    }

    fn is_group(self) -> bool {
        matches!(self, Self::Metric(m) if m >= PAIR_METRIC_COUNT)
    }

    /// The trial's value, if it has one.
    pub fn of(self, t: &TrialData, cfg: &AnalysisConfig) -> Option<f64> {
        let metric = |m: usize| {
            t.metrics
                .as_ref()
                .and_then(|x| x.get(m))
                .filter(|v| !v.is_empty())
        };
        let v = match self {
            Self::Goals => Some(f64::from(t.goals_reached)),
            Self::TimeToGoal => t.time_to_goal_s,
            Self::PausedFraction => {
                let speed = metric(fish_speed_index())?;
                // Sorted ascending: the paused frames are a prefix.
                let slow = speed.partition_point(|&s| s < f64::from(cfg.pause_cm_s));
                Some(slow as f64 / speed.len() as f64)
            }
            Self::Metric(m) => metric(m).map(|v| METRIC_TABLE[m].per_trial.of_sorted(v)),
        };
        v.filter(|x| x.is_finite())
    }
}

fn fish_speed_index() -> usize {
    METRIC_TABLE
        .iter()
        .position(|m| m.id == "fish_speed")
        .expect("the metric table has the fish's speed")
}

/// The spread entry of one policy and quantity from the per-trial values of each side (at
/// least two a side), with the bootstrap drawn from `rng`; `bf_p_holm` is left to the caller.
pub fn spread_entry(
    sim: Vec<f64>,
    real: Vec<f64>,
    reps: usize,
    level: f64,
    rng: &mut fishprobe_sim::SimRng,
) -> Result<SpreadEntry, st::StatsError> {
    let mut boot = st::bootstrap_sd_ratio(&sim, &real, reps, rng)?;
    let (sd_sim, sd_real) = (st::sd_exact(&sim), st::sd_exact(&real));
    let bf = st::brown_forsythe(&[&sim, &real]).ok();
    Ok(SpreadEntry {
        sd_sim,
        sd_real,
        ratio: sd_sim / sd_real,
        ci: if boot.is_empty() {
            [f64::NAN; 2]
        } else {
            st::percentile_ci(&mut boot, level)
        },
        w1_trials: st::wasserstein(&sim, &real)?,
        bf_stat: bf.map_or(f64::NAN, |t| t.statistic),
        bf_p: bf.map_or(f64::NAN, |t| t.p),
        bf_p_holm: f64::NAN,
        sim,
        real,
    })
}

/// Fills `res.spread` for the policies with both sim and real trials.
pub(crate) fn spread(
    res: &mut Results,
    sim: &BTreeMap<String, Vec<&TrialData>>,
    real: &BTreeMap<String, Vec<&TrialData>>,
    skipped: &mut Vec<Skipped>,
    cfg: &AnalysisConfig,
    seed: u64,
) {
    let policies: Vec<&String> = sim.keys().filter(|p| real.contains_key(*p)).collect();
    let cells: Vec<(Quantity, &String)> = quantities()
        .into_iter()
        .flat_map(|q| policies.iter().map(move |p| (q, *p)))
        .collect();
    type Cell<'a> = (Quantity, &'a String, Result<SpreadEntry, String>);
    let done: Vec<Cell> = cells
        .par_iter()
        .filter(|(q, p)| {
            // Group metrics only between arms of the same group size (as the metric gaps).
            !q.is_group()
                || crate::conditions::fish_counts(&sim[*p])
                    == crate::conditions::fish_counts(&real[*p])
        })
        .map(|&(q, p)| {
            let values =
                |v: &[&TrialData]| -> Vec<f64> { v.iter().filter_map(|t| q.of(t, cfg)).collect() };
            let (s, r) = (values(&sim[p]), values(&real[p]));
            let entry = if s.is_empty() && r.is_empty() {
                Err(String::new())
            } else if s.len() < 2 || r.len() < 2 {
                Err(format!(
                    "{} sim and {} real trials with a value: at least two a side are needed",
                    s.len(),
                    r.len()
                ))
            } else {
                let mut g = stream(seed, &format!("spread/bootstrap/{}/{p}", q.id()), 0);
                spread_entry(s, r, cfg.bootstrap_reps, cfg.ci_level, &mut g)
                    .map_err(|e| e.to_string())
            };
            (q, p, entry)
        })
        .collect();
    for (q, p, entry) in done {
        match entry {
            Ok(e) => {
                res.spread
                    .entry(q.id().to_string())
                    .or_default()
                    .insert(p.clone(), e);
            }
            Err(why) if why.is_empty() => {} // e.g. a group metric in a pair study
            Err(why) => skipped.push(Skipped {
                what: format!("spread {}/{p}", q.id()),
                reason: why,
            }),
        }
    }
    for per in res.spread.values_mut() {
        holm_within(per);
    }
}

/// A ratio of spreads as a biologist says it: "a fifth as much", "half as much", "about as
/// much", "2.5 times as much" (for "simulated trials differ from one another … as live ones").
pub fn ratio_in_words(r: f64) -> String {
    if !r.is_finite() {
        return if r == f64::INFINITY {
            "infinitely more (live trials do not differ at all)".into()
        } else {
            "an unknown share".into()
        };
    }
    if r < 0.005 {
        return "hardly at all".into();
    }
    if (0.8..=1.25).contains(&r) {
        return "about as much".into();
    }
    if r > 1.25 {
        return format!("{r:.1} times as much");
    }
    // The nearest simple fraction 1/k (k = 2..=20), else a percentage.
    let k = (1.0 / r).round();
    if (2.0..=20.0).contains(&k) && ((1.0 / k) - r).abs() <= 0.15 * r {
        const NAMES: [&str; 19] = [
            "half",
            "a third",
            "a quarter",
            "a fifth",
            "a sixth",
            "a seventh",
            "an eighth",
            "a ninth",
            "a tenth",
            "an eleventh",
            "a twelfth",
            "a thirteenth",
            "a fourteenth",
            "a fifteenth",
            "a sixteenth",
            "a seventeenth",
            "an eighteenth",
            "a nineteenth",
            "a twentieth",
        ];
        return format!("{} as much", NAMES[k as usize - 2]);
    }
    format!("{:.0} % as much", 100.0 * r)
}

/// One sentence on a policy's spread in a quantity, as a biologist reads it: "simulated
/// trials differ from one another in goals a fifth as much as live ones (s.d. 1.2 vs 6.0)".
/// `what`: the quantity in words ("in goals"); `arm`: the reality arm's trials ("live",
/// "virtual-lab").
pub fn spread_sentence(e: &SpreadEntry, what: &str, arm: &str) -> String {
    let (a, b) = (e.sd_sim, e.sd_real);
    if a == 0.0 && b == 0.0 {
        format!("neither the simulated nor the {arm} trials differ from one another {what}")
    } else if b == 0.0 {
        format!("the {arm} trials do not differ from one another {what}; the simulated ones do (s.d. {a:.2})")
    } else {
        format!(
            "simulated trials differ from one another {what} {} as {arm} ones (s.d. {a:.2} vs {b:.2})",
            ratio_in_words(e.ratio)
        )
    }
}

/// Holm-adjusts the Brown–Forsythe p-values of one quantity across policies (those with a
/// test; the others keep NaN).
fn holm_within(per: &mut BTreeMap<String, SpreadEntry>) {
    let tested: Vec<String> = per
        .iter()
        .filter(|(_, e)| e.bf_p.is_finite())
        .map(|(p, _)| p.clone())
        .collect();
    let raw: Vec<f64> = tested.iter().map(|p| per[p].bf_p).collect();
    for (p, adjusted) in tested.iter().zip(st::holm(&raw)) {
        if let Some(e) = per.get_mut(p) {
            e.bf_p_holm = adjusted;
        }
    }
}

#[cfg(test)]
mod tests {
    #![allow(clippy::unwrap_used)]
    use super::*;
    use rand::SeedableRng;

    #[test]
    fn an_entry_holds_the_spread_of_each_side_and_scipys_test() {
        // sim = A, real = B of the stats crate's Brown–Forsythe known answers.
        let sim = vec![3.1, 4.7, 2.2, 5.9, 4.4, 3.8, 6.1, 2.9];
        let real = vec![4.0, 4.2, 3.9, 4.1, 4.3, 4.0];
        let mut g = fishprobe_sim::SimRng::seed_from_u64(1);
        let e = spread_entry(sim.clone(), real.clone(), 2000, 0.95, &mut g).unwrap();
        // numpy.std(sim, ddof=1), numpy.std(real, ddof=1)
        assert!(
            (e.sd_sim - 1.405_029_232_029_406_2).abs() < 1e-12,
            "{}",
            e.sd_sim
        );
        assert!(
            (e.sd_real - 0.147_196_014_438_797_43).abs() < 1e-12,
            "{}",
            e.sd_real
        );
        assert!((e.ratio - e.sd_sim / e.sd_real).abs() < 1e-12);
        assert!(e.ci[0] < e.ratio && e.ratio < e.ci[1], "{:?}", e.ci);
        // scipy.stats.levene(sim, real, center="median"); scipy.stats.wasserstein_distance
        assert!((e.bf_stat - 12.207_853_837_940_458).abs() < 1e-10);
        assert!((e.bf_p - 0.004_430_784_872_783_466).abs() < 1e-9);
        assert!(
            (e.w1_trials - 1.020_833_333_333_333_5).abs() < 1e-12,
            "{}",
            e.w1_trials
        );
        assert_eq!((e.sim, e.real), (sim, real));
    }

    #[test]
    fn holm_adjusts_across_policies_and_leaves_untested_ones_alone() {
        let entry = |p: f64| SpreadEntry {
            bf_p: p,
            ..SpreadEntry::default()
        };
        let mut per: BTreeMap<String, SpreadEntry> = [
            ("A".to_string(), entry(0.01)),
            ("B".to_string(), entry(0.04)),
            ("C".to_string(), entry(f64::NAN)),
            ("D".to_string(), entry(0.03)),
        ]
        .into();
        holm_within(&mut per);
        // statsmodels multipletests([0.01, 0.04, 0.03], method="holm") = [0.03, 0.06, 0.06]
        assert!((per["A"].bf_p_holm - 0.03).abs() < 1e-12);
        assert!((per["B"].bf_p_holm - 0.06).abs() < 1e-12);
        assert!((per["D"].bf_p_holm - 0.06).abs() < 1e-12);
        assert!(per["C"].bf_p_holm.is_nan());
    }

    #[test]
    fn ratios_read_as_words() {
        for (r, w) in [
            (0.2, "a fifth as much"),
            (0.19, "a fifth as much"),
            (0.5, "half as much"),
            (0.33, "a third as much"),
            (0.9, "about as much"),
            (1.2, "about as much"),
            (2.5, "2.5 times as much"),
            (0.001, "hardly at all"),
            (0.7, "70 % as much"),
        ] {
            assert_eq!(ratio_in_words(r), w, "{r}");
        }
    }

    #[test]
    fn quantities_have_unique_ids_and_come_back_by_them() {
        let q = quantities();
        let mut ids: Vec<&str> = q.iter().map(|q| q.id()).collect();
        ids.sort_unstable();
        ids.dedup();
        assert_eq!(ids.len(), q.len());
        for x in q {
            assert_eq!(Quantity::by_id(x.id()), Some(x));
        }
        assert_eq!(Quantity::Metric(0).label(), "median IID (cm)");
        assert_eq!(Quantity::Metric(1).label(), "mean |IID change| (cm/s)");
    }

    #[test]
    fn a_trials_values_are_its_summaries() {
        let mut t = TrialData::blank("t.hdf5", 1);
        t.goals_reached = 7;
        t.time_to_goal_s = Some(12.5);
        let mut m: Vec<Vec<f64>> = vec![Vec::new(); crate::METRICS.len()];
        m[0] = vec![1.0, 2.0, 10.0]; // iid: median 2
        m[fish_speed_index()] = vec![0.1, 0.2, 3.0, 5.0]; // two of four below 0.5 cm/s
        m[4] = vec![-3.0, 1.0]; // fish turn: mean |·| 2
        t.metrics = Some(m);
        let cfg = AnalysisConfig::default();
        assert_eq!(Quantity::Goals.of(&t, &cfg), Some(7.0));
        assert_eq!(Quantity::TimeToGoal.of(&t, &cfg), Some(12.5));
        assert_eq!(Quantity::PausedFraction.of(&t, &cfg), Some(0.5));
        assert_eq!(Quantity::Metric(0).of(&t, &cfg), Some(2.0));
        assert_eq!(Quantity::Metric(4).of(&t, &cfg), Some(2.0));
        assert_eq!(
            Quantity::Metric(fish_speed_index()).of(&t, &cfg),
            Some(2.075)
        );
        assert_eq!(
            Quantity::Metric(1).of(&t, &cfg),
            None,
            "no frames, no value"
        );
    }
}
