//! The study's comparisons (SPEC §8), each with its own random stream derived from the master
//! seed by a label naming the section and the policy, so results do not depend on the number of
//! threads or on which other sections run.

use crate::config::AnalysisConfig;
use crate::results::*;
use crate::study::{StudyFiles, REALITY_ARMS};
use crate::trial::{load_trial, Loaded, TrialData, ALL_METRICS, METRICS};
use fishprobe_sim::{stream, SimRng};
use fishprobe_stats as st;
use rayon::prelude::*;
use st::rankdata as average_ranks;
use std::collections::BTreeMap;
use std::path::PathBuf;

use crate::conditions::{fish_counts, groups_check, mixed_policies, other_weights, weights_of};

fn rng(seed: u64, label: &str) -> SimRng {
    stream(seed, label, 0)
}

/// Everything the analysis reads, loaded in parallel. `true`: with per-frame metrics.
fn load_all(jobs: BTreeMap<PathBuf, bool>, cfg: &AnalysisConfig) -> Loaded {
    jobs.into_par_iter()
        .map(|(p, metrics)| {
            let r = load_trial(&p, cfg, metrics).map_err(|e| e.to_string());
            (p, r)
        })
        .collect()
}

/// The valid trials of a list of files; failures go to `skipped`.
fn valid<'a>(
    files: &[PathBuf],
    loaded: &'a Loaded,
    skipped: &mut Vec<Skipped>,
) -> Vec<&'a TrialData> {
    files
        .iter()
        .filter_map(|f| match loaded.get(f) {
            Some(Ok(t)) => Some(t),
            Some(Err(reason)) => {
                if !skipped.iter().any(|s| s.what == f.display().to_string()) {
                    skipped.push(Skipped {
                        what: f.display().to_string(),
                        reason: reason.clone(),
                    });
                }
                None
            }
            None => None,
        })
        .collect()
}

fn goals_of(trials: &[&TrialData]) -> Vec<f64> {
    trials.iter().map(|t| f64::from(t.goals_reached)).collect()
}

fn mean_sd(v: &[f64]) -> Option<MeanSd> {
    (!v.is_empty()).then(|| MeanSd {
        mean: st::mean(v),
        sd: st::sd(v),
        n: v.len(),
    })
}

/// Runs the whole analysis.
pub fn analyze(study: &StudyFiles, cfg: &AnalysisConfig, seed: u64) -> Results {
    let mut res = Results {
        seed,
        config: cfg.clone(),
        ..Results::default()
    };
    let policies = study.policies();
    let arm = study.reality();
    res.reality = arm.map(str::to_string);

    // What to read.
    let mut jobs: BTreeMap<PathBuf, bool> = BTreeMap::new();
    for ((p, m), files) in &study.rollouts {
        let own = p == m;
        let reality = REALITY_ARMS.contains(&m.as_str());
        for (i, f) in files.iter().enumerate() {
            let metrics = reality || (own && i < cfg.sim_trials);
            let e = jobs.entry(f.clone()).or_insert(false);
            *e |= metrics;
        }
    }
    for seeds in study.stability.values().chain(study.baselines.values()) {
        for f in seeds.values().flatten() {
            jobs.entry(f.clone()).or_insert(false);
        }
    }
    let loaded = load_all(jobs, cfg);
    let mut skipped = Vec::new();

    // Conditions: sim (first N of P__P) and real per policy.
    let mut sim: BTreeMap<String, Vec<&TrialData>> = BTreeMap::new();
    let mut real: BTreeMap<String, Vec<&TrialData>> = BTreeMap::new();
    for p in &policies {
        let files = &study.rollouts[&(p.clone(), p.clone())];
        let first: Vec<PathBuf> = files.iter().take(cfg.sim_trials).cloned().collect();
        let s = valid(&first, &loaded, &mut skipped);
        if s.is_empty() {
            skipped.push(Skipped {
                what: format!("{p}__{p}"),
                reason: "no valid sim trials".into(),
            });
            continue;
        }
        if let Some(why) = mixed_policies(&s) {
            skipped.push(Skipped {
                what: format!("{p}__{p}"),
                reason: why,
            });
            continue;
        }
        let own = weights_of(&s);
        if let Some(w) = own {
            res.weights.insert(p.clone(), w.to_string());
        }
        sim.insert(p.clone(), s);
        if let Some(a) = arm {
            match study.rollouts.get(&(p.clone(), a.to_string())) {
                Some(files) => {
                    let r = crate::conditions::one_protocol(
                        &format!("{p}__{a}"),
                        valid(files, &loaded, &mut skipped),
                        cfg.control_length_tolerance_s,
                        &mut skipped,
                    );
                    if r.is_empty() {
                        skipped.push(Skipped {
                            what: format!("{p}__{a}"),
                            reason: "no valid trials".into(),
                        });
                    } else if let Some(why) = other_weights(own, &r) {
                        skipped.push(Skipped {
                            what: format!("{p}__{a}"),
                            reason: why,
                        });
                    } else {
                        real.insert(p.clone(), r);
                    }
                }
                None => skipped.push(Skipped {
                    what: format!("{p}__{a}"),
                    reason: format!("policy {p} has sim trials but no {a} trials"),
                }),
            }
        }
    }
    for (p, m) in study.rollouts.keys() {
        if REALITY_ARMS.contains(&m.as_str()) && !sim.contains_key(p) {
            skipped.push(Skipped {
                what: format!("{p}__{m}"),
                reason: format!("no {p}__{p} sim trials to compare with"),
            });
        }
    }

    groups_check(&sim, &real, &mut skipped);
    goals_and_gaps(&mut res, &sim, &real, cfg, seed);
    metric_gaps(&mut res, &sim, &real, cfg, seed);
    crate::spread::spread(&mut res, &sim, &real, &mut skipped, cfg, seed);
    temporal(&mut res, &sim, &real, &mut skipped);
    sim_to_sim(&mut res, study, &policies, &loaded, &mut skipped, cfg, seed);
    stability(&mut res, study, &loaded, &mut skipped, cfg, seed);
    crate::approach::approach(&mut res, study, &mut skipped, cfg);
    crate::competence::competence(&mut res, study, &policies, &loaded, &mut skipped, cfg);
    crate::seeds::seeds(&mut res, study, &loaded, &mut skipped, cfg);
    skipped.sort_by(|a, b| a.what.cmp(&b.what));
    skipped.dedup();
    res.skipped = skipped;
    res
}

fn goals_and_gaps(
    res: &mut Results,
    sim: &BTreeMap<String, Vec<&TrialData>>,
    real: &BTreeMap<String, Vec<&TrialData>>,
    cfg: &AnalysisConfig,
    seed: u64,
) {
    let gaps: Vec<(String, GoalsPair, Option<GoalGap>, TimeToGoal)> = sim
        .par_iter()
        .map(|(p, s)| {
            let r = real.get(p).cloned().unwrap_or_default();
            let (gs, gr) = (goals_of(s), goals_of(&r));
            let ttg = |v: &[&TrialData]| {
                mean_sd(
                    &v.iter()
                        .filter_map(|t| t.time_to_goal_s)
                        .collect::<Vec<_>>(),
                )
            };
            let times = TimeToGoal {
                sim: ttg(s),
                real: ttg(&r),
            };
            let pair = GoalsPair {
                sim: s.iter().map(|t| t.goals_reached).collect(),
                real: r.iter().map(|t| t.goals_reached).collect(),
            };
            let gap = (!gr.is_empty()).then(|| {
                let mut rb = rng(seed, &format!("sim_to_real/bootstrap/{p}"));
                let mut rp = rng(seed, &format!("sim_to_real/permutation/{p}"));
                let mut boot = st::bootstrap_wasserstein(&gs, &gr, cfg.bootstrap_reps, &mut rb)
                    .unwrap_or_default();
                let perm = st::permutation_test_wasserstein(&gs, &gr, cfg.permutations, &mut rp);
                let delta = st::cliffs_delta(&gs, &gr).unwrap_or(f64::NAN);
                GoalGap {
                    w: st::wasserstein(&gs, &gr).unwrap_or(f64::NAN),
                    ci: st::percentile_ci(&mut boot, cfg.ci_level),
                    p: perm.map_or(f64::NAN, |t| t.p),
                    cliffs_delta: delta,
                    magnitude: st::magnitude(delta).to_string(),
                    n_sim: gs.len(),
                    n_real: gr.len(),
                }
            });
            (p.clone(), pair, gap, times)
        })
        .collect();
    for (p, pair, gap, times) in gaps {
        res.goals.insert(p.clone(), pair);
        if let Some(g) = gap {
            res.sim_to_real.insert(p.clone(), g);
        }
        res.time_to_goal.insert(p, times);
    }
}

fn metric_gaps(
    res: &mut Results,
    sim: &BTreeMap<String, Vec<&TrialData>>,
    real: &BTreeMap<String, Vec<&TrialData>>,
    cfg: &AnalysisConfig,
    seed: u64,
) {
    let policies: Vec<&String> = sim.keys().filter(|p| real.contains_key(*p)).collect();
    if policies.is_empty() {
        return;
    }
    // The nine pair metrics, and the six group metrics where both arms have groups.
    let cells: Vec<(usize, &String)> = (0..ALL_METRICS.len())
        .flat_map(|m| policies.iter().map(move |p| (m, *p)))
        .collect();
    let gaps: Vec<Option<(f64, [f64; 2])>> = cells
        .par_iter()
        .map(|&(m, p)| {
            fn samples<'a>(v: &[&'a TrialData], m: usize) -> Vec<&'a [f64]> {
                v.iter()
                    .filter_map(|t| t.metrics.as_ref().and_then(|x| x.get(m)))
                    .map(Vec::as_slice)
                    .filter(|x| !x.is_empty())
                    .collect()
            }
            let (s, r) = (samples(&sim[p], m), samples(&real[p], m));
            if s.is_empty() || r.is_empty() {
                return None;
            }
            // Group metrics only between arms of the same group size (see `groups_check`).
            if m >= METRICS.len() && fish_counts(&sim[p]) != fish_counts(&real[p]) {
                return None;
            }
            let matrix: Vec<f64> = s
                .iter()
                .flat_map(|a| r.iter().map(move |b| st::wasserstein_sorted(a, b)))
                .collect();
            let median = st::median(&matrix);
            let mut g = rng(seed, &format!("metric_gaps/{}/{p}", ALL_METRICS[m]));
            let mut boot = st::cluster_bootstrap_median(
                &matrix,
                s.len(),
                r.len(),
                cfg.cluster_bootstrap_reps,
                &mut g,
            )
            .ok()?;
            Some((median, st::percentile_ci(&mut boot, cfg.ci_level)))
        })
        .collect();
    let mut rank_sums: BTreeMap<String, (f64, usize)> = BTreeMap::new();
    for (m, name) in ALL_METRICS.iter().enumerate() {
        let row: Vec<(&String, (f64, [f64; 2]))> = policies
            .iter()
            .enumerate()
            .filter_map(|(i, p)| gaps[m * policies.len() + i].map(|g| (*p, g)))
            .collect();
        if row.is_empty() {
            continue;
        }
        let medians: Vec<f64> = row.iter().map(|(_, g)| g.0).collect();
        let (lo, hi) = medians
            .iter()
            .fold((f64::INFINITY, f64::NEG_INFINITY), |(a, b), &v| {
                (a.min(v), b.max(v))
            });
        let ranks = average_ranks(&medians);
        let per: BTreeMap<String, MetricGap> = row
            .iter()
            .zip(&ranks)
            .map(|((p, (median, ci)), &rank)| {
                let normalized = if hi > lo {
                    (median - lo) / (hi - lo)
                } else {
                    0.0
                };
                let e = rank_sums.entry((*p).clone()).or_insert((0.0, 0));
                e.0 += rank;
                e.1 += 1;
                (
                    (*p).clone(),
                    MetricGap {
                        median: *median,
                        ci: *ci,
                        normalized,
                        rank,
                    },
                )
            })
            .collect();
        res.metric_gaps.insert((*name).to_string(), per);
    }
    res.mean_ranks = rank_sums
        .into_iter()
        .map(|(p, (s, n))| (p, s / n as f64))
        .collect();
}

/// NB2 of goals per minute on the minute index (0, 1, ...), clustered by trial.
fn trend(trials: &[&TrialData]) -> Result<Trend, String> {
    let (mut y, mut x, mut clusters) = (Vec::new(), Vec::new(), Vec::new());
    for (i, t) in trials.iter().enumerate() {
        for (m, &v) in t.goals_per_minute.iter().enumerate() {
            y.push(f64::from(v));
            x.extend([1.0, m as f64]);
            clusters.push(i);
        }
    }
    if y.is_empty() {
        return Err("no complete minute of control".into());
    }
    let fit = st::fit_nb2(&y, &x, 2, Some(&clusters)).map_err(|e| e.to_string())?;
    let w = fit.wald(1);
    Ok(Trend {
        rate_ratio: w.estimate.exp(),
        ci: [w.ci[0].exp(), w.ci[1].exp()],
        p: w.p,
        alpha: fit.params[2],
        first_minute: fit.params[0].exp(),
    })
}

fn temporal(
    res: &mut Results,
    sim: &BTreeMap<String, Vec<&TrialData>>,
    real: &BTreeMap<String, Vec<&TrialData>>,
    skipped: &mut Vec<Skipped>,
) {
    for (arm, set) in [("sim", sim), ("real", real)] {
        let all: Vec<&TrialData> = set.values().flatten().copied().collect();
        let mut jobs: Vec<(String, Vec<&TrialData>)> =
            set.iter().map(|(p, t)| (p.clone(), t.clone())).collect();
        if !all.is_empty() {
            jobs.push(("total".into(), all));
        }
        let fits: Vec<(String, Result<Trend, String>)> =
            jobs.into_par_iter().map(|(p, t)| (p, trend(&t))).collect();
        let mut per = BTreeMap::new();
        for (p, fit) in fits {
            match fit {
                Ok(t) => {
                    per.insert(p, t);
                }
                Err(reason) => skipped.push(Skipped {
                    what: format!("temporal trend {arm}/{p}"),
                    reason,
                }),
            }
        }
        if !per.is_empty() {
            res.temporal.insert(arm.into(), per);
        }
    }
}

fn sim_to_sim(
    res: &mut Results,
    study: &StudyFiles,
    policies: &[String],
    loaded: &Loaded,
    skipped: &mut Vec<Skipped>,
    cfg: &AnalysisConfig,
    seed: u64,
) {
    for p in policies {
        let models: Vec<&String> = study
            .rollouts
            .keys()
            .filter(|(q, m)| q == p && !REALITY_ARMS.contains(&m.as_str()))
            .map(|(_, m)| m)
            .collect();
        if models.len() < 2 {
            continue;
        }
        let mut samples: Vec<(String, Vec<f64>)> = Vec::new();
        let own = res.weights.get(p).map(String::as_str);
        for m in models {
            let trials = valid(&study.rollouts[&(p.clone(), m.clone())], loaded, skipped);
            if trials.is_empty() {
                skipped.push(Skipped {
                    what: format!("{p}__{m}"),
                    reason: "no valid trials".into(),
                });
            } else if let Some(why) = other_weights(own, &trials) {
                skipped.push(Skipped {
                    what: format!("{p}__{m}"),
                    reason: why,
                });
            } else {
                samples.push((m.clone(), goals_of(&trials)));
            }
        }
        let Some(diag) = samples.iter().find(|(m, _)| m == p).map(|(_, g)| g.clone()) else {
            continue;
        };
        let cells: Vec<(String, f64, [f64; 2], Option<f64>)> = samples
            .par_iter()
            .map(|(m, g)| {
                let mut rb = rng(seed, &format!("sim_to_sim/bootstrap/{p}/{m}"));
                let mut boot = st::bootstrap_wasserstein(&diag, g, cfg.sim_to_sim_reps, &mut rb)
                    .unwrap_or_default();
                let median = st::median(&boot);
                let ci = st::percentile_ci(&mut boot, cfg.ci_level);
                let p_raw = (m != p).then(|| {
                    let mut rp = rng(seed, &format!("sim_to_sim/permutation/{p}/{m}"));
                    st::permutation_test_wasserstein(&diag, g, cfg.permutations, &mut rp)
                        .map_or(f64::NAN, |t| t.p)
                });
                (m.clone(), median, ci, p_raw)
            })
            .collect();
        let raw: Vec<f64> = cells.iter().filter_map(|c| c.3).collect();
        let mut adjusted = st::holm(&raw).into_iter();
        let row = cells
            .into_iter()
            .map(|(m, median, ci, p_raw)| {
                (
                    m,
                    SimToSimCell {
                        median,
                        ci,
                        p_holm: p_raw.and_then(|_| adjusted.next()),
                    },
                )
            })
            .collect();
        res.sim_to_sim.insert(p.clone(), row);
        let groups: Vec<&[f64]> = samples.iter().map(|(_, g)| g.as_slice()).collect();
        match st::kruskal(&groups) {
            Ok(k) => {
                res.kruskal.insert(p.clone(), KruskalOut { h: k.h, p: k.p });
            }
            Err(e) => skipped.push(Skipped {
                what: format!("kruskal {p}"),
                reason: e.to_string(),
            }),
        }
    }
}

fn stability(
    res: &mut Results,
    study: &StudyFiles,
    loaded: &Loaded,
    skipped: &mut Vec<Skipped>,
    cfg: &AnalysisConfig,
    seed: u64,
) {
    if study.stability.is_empty() {
        return;
    }
    let episodes: Vec<Vec<Vec<f64>>> = study
        .stability
        .values()
        .map(|seeds| {
            seeds
                .values()
                .map(|files| goals_of(&valid(files, loaded, skipped)))
                .filter(|g| !g.is_empty())
                .collect::<Vec<_>>()
        })
        .collect();
    let mut g = rng(seed, "stability");
    match st::stability(
        &episodes,
        cfg.stability_bootstrap_reps,
        cfg.stability_permutations,
        &mut g,
    ) {
        Ok(s) => {
            res.stability = Some(StabilityOut {
                r: s.r,
                ci: s.ci,
                p: s.p,
            })
        }
        Err(e) => skipped.push(Skipped {
            what: "stability".into(),
            reason: e.to_string(),
        }),
    }
}
