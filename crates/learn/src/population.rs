//! Fitting a population of individuals to recordings (`fishprobe fit-population`): which of
//! a model's traits vary between individuals, and how (means, spreads and correlations), from
//! the per-recording statistics of real pairs.
//!
//! **Method: the method of simulated moments, solved by Levenberg–Marquardt with common random
//! numbers.** The target is the distribution of the per-recording statistics of the training
//! recordings ([`FitConfig::statistics`]: by default mean speed, paused fraction, median
//! inter-individual distance, median wall distance, mean alignment), summarised by the mean
//! and s.d. of each statistic across recordings and the correlation of every two. A population
//! is a normal distribution N(μ, Σ) of the traits on their log scale
//! ([`fishprobe_models::population`]); Σ = L Lᵀ with L lower triangular (its diagonal on the
//! log scale), so every parameter vector is a valid population and correlations are fitted
//! with the spreads. One evaluation simulates every training recording `replicates` times
//! (each from its first tracked poses, as long as it; every fish its own individual) and
//! returns the residuals: per statistic (m − m*)/s* and ln(s/s*), per pair of statistics the
//! difference of the Fisher-z of their correlations (with [`FitConfig::correlations`]). Its
//! seeds never change (common random numbers), so the residuals are a deterministic function
//! of the parameters and their finite differences are not buried in simulation noise. Each
//! iteration takes the Jacobian by forward differences and a Levenberg–Marquardt step, its
//! damping raised until the step lowers the objective J (the residuals' sum of squares).
//!
//! Why this and not approximate Bayesian computation or neural posterior estimation: those
//! infer one individual per recording, but a recording holds two fish whose traits its
//! statistics mix, and the population (not any one individual) is what the robot meets;
//! matching the moments of the per-recording statistics targets exactly the spread the
//! benchmark measures. The guide ("Model individuals") says more.
//!
//! The pause duration is not fitted: it is held at the training recordings' mean pause
//! (`pause_mean_s` of the result, a trait with no spread), so that the paused fraction
//! identifies the pause rate.

use crate::LearnError;
use fishprobe_analysis::offline::{
    recording_values, simulate_model, OfflineConfig, Recording, RecordingValues, RECORDING_STATS,
};
use fishprobe_models::population::{PopulationParams, Trait};
use fishprobe_models::ModelSpec;
use fishprobe_sim::params::{check, ConfigError};
use fishprobe_stats::linalg::invert;
use rayon::prelude::*;
use serde::{Deserialize, Serialize};

fishprobe_sim::documented_params! {
    /// How `fit-population` fits a population.
    pub struct FitConfig {
        /// The per-recording statistics whose distribution across recordings is matched
        /// (ids of `offline::RECORDING_STATS`; choice: the five of the benchmark's spread
        /// table).
        pub statistics: Vec<String> = vec![
            "mean_speed".into(),
            "paused_fraction".into(),
            "median_iid".into(),
            "median_wall_distance".into(),
            "mean_alignment".into(),
        ]; "-",
        /// The traits fitted (choice: the rule-based models' multipliers and the pause rate;
        /// the pause duration is held at the recordings' mean pause).
        pub traits: Vec<Trait> = vec![
            Trait::Speed,
            Trait::Social,
            Trait::Noise,
            Trait::Wall,
            Trait::PauseRate,
        ]; "-",
        /// Simulated recordings per training recording in each evaluation (choice: 8: the
        /// s.d. of a log-normal trait across simulated recordings is noisy, the more so for
        /// long-tailed statistics such as the median distance between the fish, and that noise
        /// is what the fit would otherwise match).
        pub replicates: usize = 8; "recordings",
        /// Simulations per recording when the fitted population is checked against the real
        /// recordings (the training and the validation ones; choice: 10).
        pub check_replicates: usize = 10; "simulations",
        /// Iterations at most (choice: 20; a fit stops earlier when no step lowers J).
        pub iterations: usize = 20; "iterations",
        /// Also match the correlations between the statistics across recordings (choice:
        /// true: a population is a joint distribution, and the recordings say which traits go
        /// together).
        pub correlations: bool = true; "-",
        /// Forward-difference step of every parameter (choice: 0.1 on the log scale: large
        /// enough to move the statistics past the simulation's chaos, small enough to stay
        /// local).
        pub difference_step: f64 = 0.1; "1",
        /// Levenberg–Marquardt damping of the first step (choice: 0.1; multiplied by 4 after a
        /// step that does not lower J, divided by 3 after one that does).
        pub damping: f64 = 0.1; "1",
        /// Largest spread of a trait between individuals (s.d. on the log scale; choice: 1.5,
        /// a factor of 4.5 either way for one s.d.).
        pub max_sd: f64 = 1.5; "1",
    }
}

impl FitConfig {
    /// Checks the settings.
    pub fn validate(&self) -> Result<(), ConfigError> {
        for s in &self.statistics {
            if !RECORDING_STATS.iter().any(|r| r.id == *s) {
                return Err(ConfigError::new(
                    "fit",
                    "statistics",
                    s,
                    &format!(
                        "not a per-recording statistic; known: {}",
                        RECORDING_STATS
                            .iter()
                            .map(|r| r.id)
                            .collect::<Vec<_>>()
                            .join(", ")
                    ),
                ));
            }
        }
        if self.statistics.is_empty() || self.traits.is_empty() {
            return Err(ConfigError::new(
                "fit",
                "statistics",
                self.statistics.len(),
                "name at least one statistic and one trait",
            ));
        }
        if self.traits.contains(&Trait::PauseMean) {
            return Err(ConfigError::new(
                "fit",
                "traits",
                "pause_mean",
                "the pause duration is held at the recordings' mean pause, not fitted",
            ));
        }
        for (f, v, hi) in [
            ("replicates", self.replicates, 100),
            ("check_replicates", self.check_replicates, 1000),
            ("iterations", self.iterations, 1000),
        ] {
            if !(1..=hi).contains(&v) {
                return Err(ConfigError::new(
                    "fit",
                    f,
                    v,
                    &format!("must lie in [1, {hi}]"),
                ));
            }
        }
        for (f, v, lo, hi) in [
            ("difference_step", self.difference_step, 0.001, 1.0),
            ("damping", self.damping, 1e-6, 1e6),
            ("max_sd", self.max_sd, 0.01, 5.0),
        ] {
            check::within("fit", f, v as f32, lo as f32, hi as f32)?;
        }
        Ok(())
    }
}

/// One iteration's record.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
pub struct IterationRecord {
    /// The iteration (0 first).
    pub iteration: usize,
    /// The objective J of the population evaluated in it.
    pub objective: f64,
    /// Per statistic: the simulated mean and s.d. across recordings.
    pub simulated: Vec<[f64; 2]>,
    /// The population's means then.
    pub mean: Vec<f64>,
    /// Its covariance then.
    pub cov: Vec<Vec<f64>>,
}

/// Where a fit stands: written after every iteration, so an interrupted fit resumes.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
pub struct FitState {
    /// What the fit is of: the base model, the settings, the data and the seed, as JSON; a
    /// state of another fit is not resumed.
    pub key: String,
    /// The next iteration.
    pub iteration: usize,
    /// The parameters now: the means, then the rows of L's lower triangle (its diagonal on the
    /// log scale), Σ = L Lᵀ.
    pub params: Vec<f64>,
    /// The Levenberg–Marquardt damping now.
    pub lambda: f64,
    /// Every iteration so far.
    pub history: Vec<IterationRecord>,
}

/// The real recordings' targets.
#[derive(Debug, Clone, PartialEq)]
pub struct Targets {
    /// Per statistic: the mean across recordings.
    pub mean: Vec<f64>,
    /// Per statistic: the s.d. across recordings.
    pub sd: Vec<f64>,
    /// Covariance across recordings (m x m, row-major).
    pub cov: Vec<f64>,
    /// The mean duration of the recordings' pauses (s).
    pub pause_mean_s: f64,
    /// Recordings with every statistic.
    pub n: usize,
}

fn stat_index(id: &str) -> usize {
    RECORDING_STATS
        .iter()
        .position(|s| s.id == id)
        .expect("validated statistic")
}

/// The statistics of one recording (`None` if one is undefined).
fn stats_of(v: &RecordingValues, ids: &[usize]) -> Option<Vec<f64>> {
    ids.iter()
        .map(|&i| (RECORDING_STATS[i].compute)(v).filter(|x| x.is_finite()))
        .collect()
}

fn moments(rows: &[Vec<f64>]) -> (Vec<f64>, Vec<f64>) {
    let m = rows.first().map_or(0, Vec::len);
    let n = rows.len() as f64;
    let mean: Vec<f64> = (0..m)
        .map(|j| rows.iter().map(|r| r[j]).sum::<f64>() / n)
        .collect();
    let mut cov = vec![0.0; m * m];
    for r in rows {
        for i in 0..m {
            for j in 0..m {
                cov[i * m + j] += (r[i] - mean[i]) * (r[j] - mean[j]) / (n - 1.0).max(1.0);
            }
        }
    }
    (mean, cov)
}

/// The targets of the real recordings.
pub fn targets(
    real: &[(String, Recording)],
    cfg: &FitConfig,
    offline: &OfflineConfig,
) -> Result<Targets, LearnError> {
    let ids: Vec<usize> = cfg.statistics.iter().map(|s| stat_index(s)).collect();
    let values: Vec<RecordingValues> = real
        .par_iter()
        .map(|(_, r)| recording_values(r, offline))
        .collect();
    let rows: Vec<Vec<f64>> = values.iter().filter_map(|v| stats_of(v, &ids)).collect();
    if rows.len() < 3 {
        return Err(LearnError::Run(format!(
            "{} recordings with every statistic: a population needs at least 3",
            rows.len()
        )));
    }
    let (mean, cov) = moments(&rows);
    let m = mean.len();
    let sd: Vec<f64> = (0..m).map(|j| cov[j * m + j].sqrt().max(1e-9)).collect();
    let pauses: Vec<f64> = values
        .iter()
        .flat_map(|v| v.pauses_s.iter().copied())
        .collect();
    let pause_mean_s = if pauses.is_empty() {
        0.04
    } else {
        pauses.iter().sum::<f64>() / pauses.len() as f64
    };
    Ok(Targets {
        mean,
        sd,
        cov,
        pause_mean_s,
        n: rows.len(),
    })
}

/// A bank of simulated recordings: per recording, its statistics.
struct Bank {
    stats: Vec<Vec<f64>>,
}

/// The population with the fitted traits at (μ, Σ) and the pause duration held.
fn population(
    base: &ModelSpec,
    name: &str,
    cfg: &FitConfig,
    t: &Targets,
    mean: &[f64],
    cov: &[Vec<f64>],
) -> PopulationParams {
    let k = cfg.traits.len();
    let mut traits = cfg.traits.clone();
    let mut mu = mean.to_vec();
    let mut c: Vec<Vec<f64>> = cov
        .iter()
        .map(|r| {
            let mut r = r.clone();
            r.push(0.0);
            r
        })
        .collect();
    traits.push(Trait::PauseMean);
    mu.push(t.pause_mean_s.max(0.04).ln());
    c.push(vec![0.0; k + 1]);
    PopulationParams {
        name: name.to_string(),
        base: Some(Box::new(base.clone())),
        traits,
        mean: mu,
        cov: c,
        ..PopulationParams::default()
    }
}

/// Simulates every recording `replicates` times with individuals of `pop`; the seeds depend
/// only on the recording and the replicate (common random numbers).
fn bank(
    pop: &PopulationParams,
    real: &[(String, Recording)],
    cfg: &FitConfig,
    offline: &OfflineConfig,
    seed: u64,
) -> Result<Bank, LearnError> {
    let model = ModelSpec::Population(pop.clone()).build()?;
    let ids: Vec<usize> = cfg.statistics.iter().map(|s| stat_index(s)).collect();
    let n = real.len();
    let out: Vec<Result<Option<Vec<f64>>, LearnError>> = (0..cfg.replicates * n)
        .into_par_iter()
        .map(|i| {
            let s = fishprobe_sim::derive_seed(seed, "fit/population", i as u64);
            let (sim, _) = simulate_model(&model, &real[i % n].1, offline, s)?;
            Ok(stats_of(&recording_values(&sim, offline), &ids))
        })
        .collect();
    let mut b = Bank { stats: Vec::new() };
    for o in out {
        b.stats.extend(o?);
    }
    if b.stats.len() < 3 {
        return Err(LearnError::Run(format!(
            "only {} simulated recordings have every statistic: too few to compare",
            b.stats.len()
        )));
    }
    Ok(b)
}

fn fisher_z(r: f64) -> f64 {
    r.clamp(-0.999, 0.999).atanh()
}

/// The residuals of a set of per-recording statistics against the targets: per statistic
/// (m − m*)/s* and ln(s/s*), then (with `correlations`) per pair the difference of the
/// Fisher-z of their correlations. Also the statistics' means and s.d.s.
fn residuals(rows: &[Vec<f64>], t: &Targets, correlations: bool) -> (Vec<f64>, Vec<[f64; 2]>) {
    let (mean, cov) = moments(rows);
    let m = mean.len();
    let sd: Vec<f64> = (0..m).map(|s| cov[s * m + s].max(0.0).sqrt()).collect();
    let mut r = Vec::with_capacity(2 * m + m * m / 2);
    for s in 0..m {
        r.push((mean[s] - t.mean[s]) / t.sd[s]);
        r.push((sd[s].max(1e-9 * t.sd[s]) / t.sd[s]).ln());
    }
    if correlations {
        for a in 0..m {
            for b in a + 1..m {
                let corr = |c: &[f64], sa: f64, sb: f64| c[a * m + b] / (sa * sb).max(1e-300);
                let sim = corr(&cov, sd[a], sd[b]);
                let real = corr(&t.cov, t.sd[a], t.sd[b]);
                r.push(fisher_z(sim) - fisher_z(real));
            }
        }
    }
    (r, (0..m).map(|s| [mean[s], sd[s]]).collect())
}

/// (μ, Σ) of a parameter vector: the means, then L's lower triangle by rows (diagonal on the
/// log scale); Σ = L Lᵀ, each trait's s.d. capped at `max_sd`.
pub fn to_population(params: &[f64], k: usize, max_sd: f64) -> (Vec<f64>, Vec<Vec<f64>>) {
    let mean = params[..k].to_vec();
    let mut l = vec![vec![0.0; k]; k];
    let mut p = k;
    for (i, row) in l.iter_mut().enumerate() {
        for (j, x) in row.iter_mut().enumerate().take(i + 1) {
            *x = if i == j { params[p].exp() } else { params[p] };
            p += 1;
        }
    }
    for row in &mut l {
        let norm = row.iter().map(|x| x * x).sum::<f64>().sqrt();
        if norm > max_sd {
            row.iter_mut().for_each(|x| *x *= max_sd / norm);
        }
    }
    let cov = (0..k)
        .map(|i| {
            (0..k)
                .map(|j| (0..k).map(|m| l[i][m] * l[j][m]).sum())
                .collect()
        })
        .collect();
    (mean, cov)
}

/// The parameter vector of (μ, Σ) (Σ positive definite).
pub fn from_population(mean: &[f64], cov: &[Vec<f64>]) -> Vec<f64> {
    let k = mean.len();
    let l = fishprobe_models::population::cholesky(cov).unwrap_or_else(|| {
        (0..k)
            .map(|i| (0..k).map(|j| if i == j { 0.1 } else { 0.0 }).collect())
            .collect()
    });
    let mut p = mean.to_vec();
    for (i, row) in l.iter().enumerate() {
        for (j, &x) in row.iter().enumerate().take(i + 1) {
            p.push(if i == j { x.max(1e-6).ln() } else { x });
        }
    }
    p
}

/// What a fit reports after each iteration.
#[derive(Debug, Clone, PartialEq)]
pub struct Progress<'a> {
    /// The iteration just done.
    pub iteration: usize,
    /// Of how many.
    pub of: usize,
    /// Its record.
    pub record: &'a IterationRecord,
    /// The best objective so far.
    pub best: f64,
}

/// The starting point: every multiplier neutral with a spread of 0.1 (s.d. on the log
/// scale); the pause rate where the recordings' paused fraction would put it with pauses of
/// their mean length.
pub fn start(cfg: &FitConfig, t: &Targets) -> Vec<f64> {
    let k = cfg.traits.len();
    let paused = cfg
        .statistics
        .iter()
        .position(|s| s == "paused_fraction")
        .map_or(0.05, |i| t.mean[i])
        .clamp(0.001, 0.9);
    let mean: Vec<f64> = cfg
        .traits
        .iter()
        .map(|tr| match tr {
            Trait::PauseRate => (paused / (t.pause_mean_s.max(0.04) * (1.0 - paused))).ln(),
            _ => 0.0,
        })
        .collect();
    let cov: Vec<Vec<f64>> = (0..k)
        .map(|i| (0..k).map(|j| if i == j { 0.01 } else { 0.0 }).collect())
        .collect();
    from_population(&mean, &cov)
}

/// Solves (A + λ diag(A)) x = b for a small dense symmetric A.
fn damped_solve(a: &[f64], b: &[f64], lambda: f64) -> Option<Vec<f64>> {
    let n = b.len();
    let mut m = a.to_vec();
    for i in 0..n {
        m[i * n + i] += lambda * a[i * n + i].max(1e-9);
    }
    let inv = invert(&m, n)?;
    Some(
        (0..n)
            .map(|i| (0..n).map(|j| inv[i * n + j] * b[j]).sum())
            .collect(),
    )
}

/// Fits a population of `base` to the recordings `real`, from `state` (a fresh one from
/// [`start`], or a resumed one), calling `save` with the state after every iteration and
/// `progress` with what it did. Returns the population of the iteration with the smallest
/// objective.
#[allow(clippy::too_many_arguments)]
pub fn fit(
    base: &ModelSpec,
    name: &str,
    real: &[(String, Recording)],
    cfg: &FitConfig,
    offline: &OfflineConfig,
    seed: u64,
    mut state: FitState,
    save: &mut dyn FnMut(&FitState) -> Result<(), LearnError>,
    progress: &mut dyn FnMut(Progress<'_>),
) -> Result<(PopulationParams, FitState), LearnError> {
    cfg.validate()?;
    let t = targets(real, cfg, offline)?;
    let k = cfg.traits.len();
    let n_params = k + k * (k + 1) / 2;
    if state.params.len() != n_params {
        return Err(LearnError::Run(format!(
            "the fit's state has {} parameters, {k} traits need {n_params}",
            state.params.len()
        )));
    }
    let evaluate = |params: &[f64]| -> Result<(Vec<f64>, Vec<[f64; 2]>), LearnError> {
        let (mean, cov) = to_population(params, k, cfg.max_sd);
        let pop = population(base, name, cfg, &t, &mean, &cov);
        let b = bank(&pop, real, cfg, offline, seed)?;
        Ok(residuals(&b.stats, &t, cfg.correlations))
    };
    let cost = |r: &[f64]| r.iter().map(|x| x * x).sum::<f64>();
    let (mut r0, mut sim0) = evaluate(&state.params)?;
    while state.iteration < cfg.iterations {
        let it = state.iteration;
        // The Jacobian by forward differences, a column per parameter.
        let h = cfg.difference_step;
        let mut jac = vec![0.0; r0.len() * n_params];
        for p in 0..n_params {
            let mut q = state.params.clone();
            q[p] += h;
            let (rp, _) = evaluate(&q)?;
            for (i, (a, b)) in rp.iter().zip(&r0).enumerate() {
                jac[i * n_params + p] = (a - b) / h;
            }
        }
        let mut jtj = vec![0.0; n_params * n_params];
        let mut jtr = vec![0.0; n_params];
        for i in 0..r0.len() {
            for a in 0..n_params {
                jtr[a] -= jac[i * n_params + a] * r0[i];
                for b in 0..n_params {
                    jtj[a * n_params + b] += jac[i * n_params + a] * jac[i * n_params + b];
                }
            }
        }
        let now = cost(&r0);
        let mut accepted = false;
        for _ in 0..4 {
            let Some(delta) = damped_solve(&jtj, &jtr, state.lambda) else {
                state.lambda *= 4.0;
                continue;
            };
            let q: Vec<f64> = state
                .params
                .iter()
                .zip(&delta)
                .map(|(p, d)| (p + d.clamp(-1.0, 1.0)).clamp(-8.0, 8.0))
                .collect();
            let (rq, simq) = evaluate(&q)?;
            if cost(&rq) < now {
                state.params = q;
                r0 = rq;
                sim0 = simq;
                state.lambda = (state.lambda / 3.0).max(1e-6);
                accepted = true;
                break;
            }
            state.lambda *= 4.0;
        }
        let (mean, cov) = to_population(&state.params, k, cfg.max_sd);
        state.history.push(IterationRecord {
            iteration: it,
            objective: cost(&r0),
            simulated: sim0.clone(),
            mean,
            cov,
        });
        state.iteration += 1;
        if !accepted && state.lambda > 1e4 {
            // No step lowers J however short: a minimum, as far as the simulations can tell.
            state.iteration = cfg.iterations;
        }
        save(&state)?;
        let best = state
            .history
            .iter()
            .map(|r| r.objective)
            .fold(f64::INFINITY, f64::min);
        progress(Progress {
            iteration: it,
            of: cfg.iterations,
            record: state.history.last().expect("just pushed"),
            best,
        });
    }
    let best = state
        .history
        .iter()
        .min_by(|a, b| a.objective.total_cmp(&b.objective))
        .ok_or_else(|| LearnError::Run("no iteration was run".into()))?;
    Ok((
        population(base, name, cfg, &t, &best.mean, &best.cov),
        state,
    ))
}

#[cfg(test)]
mod tests {
    #![allow(clippy::unwrap_used)]
    use super::*;

    #[test]
    fn parameters_and_populations_map_both_ways() {
        let mean = vec![0.1, -0.2, 0.3];
        let cov = vec![
            vec![0.09, 0.03, 0.0],
            vec![0.03, 0.25, -0.05],
            vec![0.0, -0.05, 0.16],
        ];
        let p = from_population(&mean, &cov);
        assert_eq!(p.len(), 3 + 6);
        let (m, c) = to_population(&p, 3, 5.0);
        assert_eq!(m, mean);
        for i in 0..3 {
            for j in 0..3 {
                assert!((c[i][j] - cov[i][j]).abs() < 1e-6, "{c:?}");
            }
        }
        // A spread over the cap is scaled down to it, keeping the correlations.
        let (_, c) = to_population(&p, 3, 0.45);
        assert!((c[1][1].sqrt() - 0.45).abs() < 1e-9 && (c[0][0] - 0.09).abs() < 1e-6);
    }

    #[test]
    fn residuals_are_zero_at_the_targets_and_say_which_way_they_miss() {
        let rows: Vec<Vec<f64>> = (0..40)
            .map(|i| {
                let x = f64::from(i);
                vec![x, 2.0 * x + (x * 7.0).sin()]
            })
            .collect();
        let (mean, cov) = moments(&rows);
        let t = Targets {
            sd: vec![cov[0].sqrt(), cov[3].sqrt()],
            mean,
            cov,
            pause_mean_s: 0.1,
            n: 40,
        };
        let (r, sim) = residuals(&rows, &t, true);
        assert_eq!(r.len(), 5);
        assert!(r.iter().all(|x| x.abs() < 1e-9), "{r:?}");
        assert!((sim[0][0] - 19.5).abs() < 1e-12);
        // Twice as spread and shifted up: positive residuals.
        let wide: Vec<Vec<f64>> = rows.iter().map(|r| vec![2.0 * r[0], r[1] + 5.0]).collect();
        let (r, _) = residuals(&wide, &t, false);
        assert!(r[0] > 0.0 && (r[1] - 2f64.ln()).abs() < 1e-9 && r[2] > 0.0 && r[3].abs() < 1e-9);
    }

    #[test]
    fn settings_out_of_range_are_refused_by_name() {
        let bad = |c: FitConfig, field: &str| {
            let e = c.validate().unwrap_err().to_string();
            assert!(e.contains(field), "{e}");
        };
        bad(
            FitConfig {
                statistics: vec!["mean_sped".into()],
                ..FitConfig::default()
            },
            "mean_sped",
        );
        bad(
            FitConfig {
                iterations: 0,
                ..FitConfig::default()
            },
            "iterations",
        );
        bad(
            FitConfig {
                traits: vec![Trait::PauseMean],
                ..FitConfig::default()
            },
            "pause_mean",
        );
        assert!(FitConfig::default().validate().is_ok());
    }
}
