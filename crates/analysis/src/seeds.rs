//! Every training seed of a probe. A study trains each model's policy with several
//! seeds (the policy and the retraining-stability seeds); the report's competence and approach
//! sections show the policy, seed 0, and a strategy one seed happens to find (or miss) is that
//! seed's, not its model's. Per seed: how well it leads its own model's fish (its stability
//! episodes against the best scripted controller on the model's evaluation episodes) and the
//! approach assay (`STUDY/approach_test/<P>/` for seed 0, `approach_stability/<P>/seed<k>/`
//! for the others), with a verdict on whether it goes to the still fish.
//!
//! ```
//! use fishprobe_analysis::results::{Approach, SeedProbe};
//! use fishprobe_analysis::seeds::goes_to_fish;
//! use fishprobe_analysis::AnalysisConfig;
//!
//! let near = Approach { min_iid: 0.4, mean_iid: 32.6, frac_closer_to_fish: 0.49, episodes: 10 };
//! assert!(goes_to_fish(&near, &AnalysisConfig::default()));
//! ```

use crate::approach::assay_files;
use crate::competence::{goal_stats, median_reach, ratio_se, Loaded};
use crate::config::AnalysisConfig;
pub use crate::results::seeds_table::{approach_count, csv, summary_markdown};
use crate::results::{Approach, Results, SeedProbe, Skipped};
use crate::study::StudyFiles;
use std::collections::{BTreeMap, BTreeSet};

/// Whether an assay shows the paper's approach pattern: closest at most
/// `approach_closest_cm` and nearer the fish than the goal in at least `approach_nearer_share`
/// of the frames.
pub fn goes_to_fish(a: &Approach, cfg: &AnalysisConfig) -> bool {
    a.min_iid <= cfg.approach_closest_cm && a.frac_closer_to_fish >= cfg.approach_nearer_share
}

/// `seed<k>` → k; other names sort after every numbered seed.
fn order(name: &str) -> (usize, String) {
    let k = name.strip_prefix("seed").and_then(|k| k.parse().ok());
    (k.unwrap_or(usize::MAX), name.to_string())
}

/// Fills `res.seeds` for every policy with more than one seed; needs `res.approach` and
/// `res.competence` filled.
pub(crate) fn seeds(
    res: &mut Results,
    study: &StudyFiles,
    loaded: &Loaded,
    skipped: &mut Vec<Skipped>,
    cfg: &AnalysisConfig,
) {
    let none = BTreeMap::new();
    let models: BTreeSet<&String> = study
        .stability
        .keys()
        .chain(study.approach_seeds.keys())
        .collect();
    for p in models {
        let stability = study.stability.get(p).unwrap_or(&none);
        let approach = study.approach_seeds.get(p).unwrap_or(&none);
        let mut names: Vec<&String> = stability.keys().chain(approach.keys()).collect();
        let seed0 = "seed0".to_string();
        if res.approach.contains_key(p) {
            names.push(&seed0);
        }
        names.sort_by_key(|n| order(n));
        names.dedup();
        if names.len() < 2 {
            continue;
        }
        let best = res.competence.get(p).map_or(f64::NAN, |c| c.best_goals);
        // The best controller's episodes, for the ratios' standard errors.
        let best_stats = res.competence.get(p).and_then(|c| {
            let files = study.baselines.get(p)?.get(&c.best)?;
            goal_stats(files, loaded)
        });
        let rows = names
            .into_iter()
            .map(|name| {
                let own = stability
                    .get(name)
                    .and_then(|files| goal_stats(files, loaded));
                let (goals, episodes) = own.map_or((f64::NAN, 0), |g| (g.mean, g.n));
                let reach_s = stability
                    .get(name)
                    .and_then(|files| median_reach(files, loaded));
                let assay = match (name.as_str(), approach.get(name)) {
                    ("seed0", None) => res.approach.get(p).cloned(),
                    (_, Some(files)) => assay_files(files, cfg)
                        .map_err(|reason| {
                            skipped.push(Skipped {
                                what: format!("approach_stability/{p}/{name}"),
                                reason: reason.to_string(),
                            })
                        })
                        .ok(),
                    _ => None,
                };
                SeedProbe {
                    seed: name.clone(),
                    goals,
                    episodes,
                    reach_s,
                    ratio: if best > 0.0 { goals / best } else { f64::NAN },
                    ratio_se: own
                        .zip(best_stats.as_ref())
                        .and_then(|(o, b)| ratio_se(&o, b)),
                    goes_to_fish: assay.as_ref().is_some_and(|a| goes_to_fish(a, cfg)),
                    approach: assay,
                }
            })
            .collect();
        res.seeds.insert(p.clone(), rows);
    }
}

#[cfg(test)]
mod tests {
    #![allow(clippy::unwrap_used)]
    use super::*;
    use crate::results::Competence;

    fn assay(min_iid: f64, frac: f64) -> Approach {
        Approach {
            min_iid,
            mean_iid: 40.0,
            frac_closer_to_fish: frac,
            episodes: 10,
        }
    }

    #[test]
    fn the_verdict_needs_both_closeness_and_time_near_the_fish() {
        let c = AnalysisConfig::default();
        assert!(goes_to_fish(&assay(10.0, 0.1), &c), "at both thresholds");
        assert!(!goes_to_fish(&assay(10.5, 0.5), &c), "never close enough");
        assert!(
            !goes_to_fish(&assay(0.3, 0.09), &c),
            "close once, but not for long"
        );
        assert!(!goes_to_fish(&assay(f64::NAN, 0.5), &c));
    }

    #[test]
    fn seeds_are_ordered_numerically_and_rated_against_the_best_script() {
        let mut res = Results::default();
        res.approach.insert("Zone".into(), assay(47.7, 0.0));
        res.competence.insert(
            "Zone".into(),
            Competence {
                policy_goals: 70.0,
                trials: 18,
                baselines: BTreeMap::from([("FetchAndLead".into(), 80.0)]),
                best: "FetchAndLead".into(),
                best_goals: 80.0,
                ratio: 0.875,
                weak: false,
                reach_s: None,
                baselines_reach_s: BTreeMap::new(),
                ratio_se: None,
            },
        );
        // Stability seeds with no readable trial files: goals unknown, but the seeds are
        // listed, in numeric order (seed10 after seed2).
        let mut study = StudyFiles::default();
        study.stability.insert(
            "Zone".into(),
            ["seed0", "seed10", "seed2"]
                .iter()
                .map(|s| (s.to_string(), vec![]))
                .collect(),
        );
        let mut skipped = Vec::new();
        let cfg = AnalysisConfig::default();
        seeds(&mut res, &study, &Loaded::new(), &mut skipped, &cfg);
        let rows = &res.seeds["Zone"];
        let names: Vec<&str> = rows.iter().map(|r| r.seed.as_str()).collect();
        assert_eq!(names, ["seed0", "seed2", "seed10"]);
        // Seed 0's assay is the policy's; the others have none.
        assert_eq!(rows[0].approach, Some(assay(47.7, 0.0)));
        assert!(!rows[0].goes_to_fish && rows[1].approach.is_none());
        assert!(rows.iter().all(|r| r.goals.is_nan() && r.ratio.is_nan()));
        assert_eq!(approach_count(rows), (0, 1));
        let csv = csv(&res.seeds);
        assert_eq!(csv.lines().count(), 4, "{csv}");
        assert!(csv
            .lines()
            .nth(1)
            .unwrap()
            .starts_with("Zone,seed0,,0,,,47.7,40,0,false"));
        let md = summary_markdown(&res.seeds, &cfg);
        assert!(
            md.contains("| Zone | seed0 | – | – | – | 47.7 | 0.0 % | no |"),
            "{md}"
        );
        assert!(md.contains("Zone in 0 of 1"), "{md}");
        // A single seed adds nothing to the competence and approach sections: no rows.
        let mut one = Results::default();
        one.approach.insert("Force".into(), assay(0.2, 0.5));
        seeds(
            &mut one,
            &StudyFiles::default(),
            &Loaded::new(),
            &mut skipped,
            &cfg,
        );
        assert!(one.seeds.is_empty());
    }
}
