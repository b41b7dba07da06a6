//! Probe competence: how well each policy leads the fish of its own model, next to
//! fishprobe's scripted controllers on the same evaluation episodes. A probe that reaches far
//! fewer goals than a simple script has not found what its model allows, so its behaviour
//! (the approach assay, the sim-to-sim matrix) says as much about the optimiser as about the
//! model; the study flags it.

use crate::config::AnalysisConfig;
use crate::results::{Competence, Results, Skipped};
use crate::study::StudyFiles;
pub(crate) use crate::trial::Loaded;
use std::collections::BTreeMap;
use std::path::PathBuf;

pub use crate::results::plus_minus;

/// Goals per episode of a set of episodes: what a competence ratio and its standard error
/// are made of.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct GoalStats {
    /// Mean goals per episode.
    pub mean: f64,
    /// Their sample standard deviation (n - 1; NaN for one episode).
    pub sd: f64,
    /// Episodes.
    pub n: usize,
}

impl GoalStats {
    /// Of the goals of each episode (`None` without any).
    pub fn of(goals: &[f64]) -> Option<Self> {
        let n = goals.len();
        if n == 0 {
            return None;
        }
        let mean = goals.iter().sum::<f64>() / n as f64;
        let sd = if n > 1 {
            (goals.iter().map(|g| (g - mean).powi(2)).sum::<f64>() / (n - 1) as f64).sqrt()
        } else {
            f64::NAN
        };
        Some(Self { mean, sd, n })
    }
}

/// Goals per valid trial of `files` (none without any).
pub(crate) fn goal_stats(files: &[PathBuf], loaded: &Loaded) -> Option<GoalStats> {
    let goals: Vec<f64> = files
        .iter()
        .filter_map(|f| loaded.get(f)?.as_ref().ok())
        .map(|t| f64::from(t.goals_reached))
        .collect();
    GoalStats::of(&goals)
}

/// The standard error of the competence ratio `policy.mean / best.mean`, the two means from
/// independent episodes, by the delta method: R · sqrt(s_p² / (n_p m_p²) + s_b² / (n_b m_b²)).
/// With 50 episodes of about 24 ± 4 goals against 30 ± 4 it is about 0.02, so a ratio within
/// about 0.05 of the competence bar is not clearly on either side. `None` when either mean is
/// not positive or either side has fewer than two episodes.
pub fn ratio_se(policy: &GoalStats, best: &GoalStats) -> Option<f64> {
    if policy.n < 2 || best.n < 2 || !(policy.mean > 0.0 && best.mean > 0.0) {
        return None;
    }
    let rel = |g: &GoalStats| g.sd.powi(2) / (g.n as f64 * g.mean.powi(2));
    let se = policy.mean / best.mean * (rel(policy) + rel(best)).sqrt();
    se.is_finite().then_some(se)
}

/// Median seconds to reach the fish over the valid trials of `files` (a trial that never
/// reached it counts as later than any that did); `None` without trials or when the median
/// trial never reached it.
pub(crate) fn median_reach(files: &[PathBuf], loaded: &Loaded) -> Option<f64> {
    let mut t: Vec<f64> = files
        .iter()
        .filter_map(|f| loaded.get(f)?.as_ref().ok())
        .map(|t| t.time_to_reach_s.unwrap_or(f64::INFINITY))
        .collect();
    if t.is_empty() {
        return None;
    }
    t.sort_by(f64::total_cmp);
    let n = t.len();
    let m = if n % 2 == 1 {
        t[n / 2]
    } else {
        0.5 * (t[n / 2 - 1] + t[n / 2])
    };
    m.is_finite().then_some(m)
}

/// The median seconds to reach the fish (as a study's competence gives them: a trial that
/// never reached it counts as latest; `None` without trials or when the median trial never
/// did) of trial files read here, for a command that has just written them: the first file
/// that cannot be read is an error naming it.
pub fn median_reach_of(
    files: &[PathBuf],
    cfg: &AnalysisConfig,
) -> Result<Option<f64>, crate::AnalysisError> {
    let mut loaded = Loaded::new();
    for f in files {
        let t =
            crate::trial::load_trial(f, cfg, false).map_err(|e| format!("{}: {e}", f.display()))?;
        loaded.insert(f.clone(), Ok(t));
    }
    Ok(median_reach(files, &loaded))
}

/// One policy's competence from its mean goals and its baselines' (controller → mean goals).
/// The times to reach the fish are left empty for the caller to fill from its trial files
/// ([`median_reach_of`]; a study fills them from its own).
pub fn competence_of(
    policy_goals: f64,
    trials: usize,
    baselines: BTreeMap<String, f64>,
    threshold: f64,
) -> Option<Competence> {
    let (best, best_goals) = baselines
        .iter()
        .max_by(|a, b| a.1.total_cmp(b.1))
        .map(|(c, g)| (c.clone(), *g))?;
    let ratio = if best_goals > 0.0 {
        policy_goals / best_goals
    } else {
        f64::NAN
    };
    Some(Competence {
        policy_goals,
        trials,
        baselines,
        best,
        best_goals,
        ratio,
        weak: ratio < threshold,
        reach_s: None,
        baselines_reach_s: BTreeMap::new(),
        ratio_se: None,
    })
}

/// Fills `res.competence` for every policy with baselines on its own model.
pub(crate) fn competence(
    res: &mut Results,
    study: &StudyFiles,
    policies: &[String],
    loaded: &Loaded,
    skipped: &mut Vec<Skipped>,
    cfg: &AnalysisConfig,
) {
    for p in policies {
        let Some(by) = study.baselines.get(p) else {
            continue;
        };
        let Some(own) = study
            .rollouts
            .get(&(p.clone(), p.clone()))
            .and_then(|f| goal_stats(f, loaded))
        else {
            continue;
        };
        let mut baselines = BTreeMap::new();
        let mut stats = BTreeMap::new();
        let mut baselines_reach_s = BTreeMap::new();
        for (c, files) in by {
            match goal_stats(files, loaded) {
                Some(g) => {
                    baselines.insert(c.clone(), g.mean);
                    stats.insert(c.clone(), g);
                    if let Some(t) = median_reach(files, loaded) {
                        baselines_reach_s.insert(c.clone(), t);
                    }
                }
                None => skipped.push(Skipped {
                    what: format!("baselines/{p}/{c}"),
                    reason: "no valid trials".into(),
                }),
            }
        }
        if let Some(mut c) = competence_of(own.mean, own.n, baselines, cfg.competence_threshold) {
            c.ratio_se = stats.get(&c.best).and_then(|b| ratio_se(&own, b));
            c.reach_s = study
                .rollouts
                .get(&(p.clone(), p.clone()))
                .and_then(|f| median_reach(f, loaded));
            c.baselines_reach_s = baselines_reach_s;
            res.competence.insert(p.clone(), c);
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn the_ratio_is_to_the_best_baseline_and_weak_below_the_threshold() {
        let b = BTreeMap::from([
            ("GoalSeeker".to_string(), 10.2),
            ("FetchAndLead".into(), 83.7),
        ]);
        let c = competence_of(35.0, 18, b.clone(), 0.8).unwrap();
        assert_eq!(c.best, "FetchAndLead");
        assert!((c.ratio - 35.0 / 83.7).abs() < 1e-12);
        assert!(c.weak);
        let strong = competence_of(83.7 * 0.8, 18, b, 0.8).unwrap();
        assert!(!strong.weak, "exactly at the threshold is not weak");
        // Baselines that reach nothing give no ratio, and no verdict.
        let zero =
            competence_of(3.0, 18, BTreeMap::from([("GoalSeeker".into(), 0.0)]), 0.8).unwrap();
        assert!(zero.ratio.is_nan() && !zero.weak);
        assert!(competence_of(3.0, 18, BTreeMap::new(), 0.8).is_none());
    }

    #[test]
    fn the_ratio_s_standard_error_is_the_delta_method_s() {
        // Policy 20, 22, 24 (mean 22, s.d. 2); best 28, 30, 32 (mean 30, s.d. 2):
        // R = 22/30, se = R·sqrt(4/(3·22²) + 4/(3·30²)) = 0.0477304 (by hand, to 7 digits).
        let p = GoalStats::of(&[20.0, 22.0, 24.0]).unwrap();
        let b = GoalStats::of(&[28.0, 30.0, 32.0]).unwrap();
        assert_eq!((p.mean, p.sd, p.n), (22.0, 2.0, 3));
        let se = ratio_se(&p, &b).unwrap();
        assert!((se - 0.047_730_4).abs() < 1e-7, "{se}");
        // Identical episodes on both sides: no spread, no error.
        let same = GoalStats::of(&[5.0, 5.0]).unwrap();
        assert_eq!(ratio_se(&same, &same), Some(0.0));
        // Too few episodes, or a side without goals: none.
        let one = GoalStats::of(&[5.0]).unwrap();
        assert!(one.sd.is_nan());
        assert_eq!(ratio_se(&one, &b), None);
        let none = GoalStats::of(&[0.0, 0.0]).unwrap();
        assert_eq!(ratio_se(&p, &none), None);
        assert_eq!(ratio_se(&none, &b), None);
        assert!(GoalStats::of(&[]).is_none());
    }

    #[test]
    fn the_median_time_to_reach_counts_never_as_latest() {
        use crate::trial::TrialData;
        let trial = |t: Option<f64>| TrialData {
            time_to_reach_s: t,
            ..TrialData::blank("t.hdf5", 1)
        };
        let load = |times: &[Option<f64>]| -> (Vec<PathBuf>, Loaded) {
            let files: Vec<PathBuf> = (0..times.len())
                .map(|i| PathBuf::from(format!("t{i}.hdf5")))
                .collect();
            let mut loaded: Loaded = times
                .iter()
                .zip(&files)
                .map(|(t, f)| (f.clone(), Ok(trial(*t))))
                .collect();
            // An unreadable trial does not count.
            loaded.insert("bad.hdf5".into(), Err("corrupt".into()));
            let mut files = files;
            files.push("bad.hdf5".into());
            (files, loaded)
        };
        let (f, l) = load(&[Some(9.0), None, Some(1.0)]);
        assert_eq!(median_reach(&f, &l), Some(9.0));
        let (f, l) = load(&[Some(4.0), Some(2.0), None, Some(8.0)]);
        assert_eq!(median_reach(&f, &l), Some(6.0));
        let (f, l) = load(&[Some(4.0), None, None]);
        assert_eq!(
            median_reach(&f, &l),
            None,
            "the median trial never reached the fish"
        );
        let (f, l) = load(&[]);
        assert_eq!(median_reach(&f, &l), None);
    }
}
