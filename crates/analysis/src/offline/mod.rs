//! The classic offline evaluation that the paper's method is contrasted with: simulate the
//! recordings with a model and compare the model fish's motion with the live fish's.
//!
//! Two kinds of recording are taken. **Pairs of live fish**: for every recording, each model
//! simulates one pair in the tank, as long as the recording, starting from the recording's
//! first tracked poses (seeded per file and model). **One live fish beside the robot** (the
//! lab's robot-fish recordings; open loop): the robot's recorded path is replayed as it was and
//! each model's fish starts from the live fish's first pose; the model fish reacts to the
//! robot, the robot never to the fish. This is the fixed-rollout evaluation the paper contrasts
//! its closed loop with.
//!
//! Pooled over recordings, the distributions of [`OFFLINE_METRICS`] are compared (speed,
//! absolute turn rate, distance to the nearest wall, distance to and alignment with the other
//! agent, the fish facing it, the fraction of time paused); real headings are checked against
//! motion as in the ConvNet's dataset. For each model and measure: the 1-Wasserstein distance
//! between the pooled real and model values, and a percentile interval from a bootstrap that
//! resamples recordings (and simulated recordings) with replacement — the recording is the
//! unit that varies, frames within it are not independent. The bootstrap works on fine
//! histograms (`hist_bins` per measure), so each replicate costs O(bins). Per recording, the
//! statistics of [`RECORDING_STATS`] measure how much individuals differ ([`spread`]).

mod metrics;
mod recording;
pub mod spread;
mod tables;

pub use metrics::{
    recording_values, OfflineMetric, RecordingStat, RecordingValues, OFFLINE_METRICS,
    RECORDING_STATS,
};
pub use recording::{real_recording, resample, simulate, simulate_model, Recording, Track};
pub use spread::{Correlation, OfflineSpread};

use fishprobe_io::TrialFile;
use fishprobe_models::ModelSpec;
use fishprobe_sim::params::{check, ConfigError};
use fishprobe_sim::{stream, SimRng};
use rand::RngExt;
use rayon::prelude::*;
use serde::Serialize;
use std::collections::BTreeMap;
use std::path::PathBuf;

fishprobe_sim::documented_params! {
    /// Settings of the offline comparison.
    pub struct OfflineConfig {
        /// A fish slower than this is paused (the data README's threshold: 0.5 cm/s).
        pub pause_cm_s: f32 = 0.5; "cm/s",
        /// Bootstrap replicates of each interval (choice).
        pub bootstrap_reps: usize = 1000; "replicates",
        /// Interval level (choice: 95 %).
        pub ci_level: f64 = 0.95; "1",
        /// Histogram bins per metric for the bootstrap (choice; the point estimate is exact).
        pub hist_bins: usize = 2000; "bins",
        /// Minimum step (cm per frame) that shows the direction of motion when checking real
        /// headings (as for the ConvNet dataset).
        pub motion_min_step_cm: f32 = 0.1; "cm",
        /// Recorded heading and motion further apart than this: use the motion (rad).
        pub heading_disagreement_rad: f32 = std::f32::consts::FRAC_PI_2; "rad",
        /// The frame rate (Hz) at which models simulate every recording (choice: the
        /// simulator's 25 Hz, SPEC §2, at which the models' parameters were published; a
        /// recording at another rate, such as the 20 Hz robot-fish files, is simulated for as
        /// many seconds, its robot path resampled to this rate).
        pub model_rate_hz: f32 = 25.0; "Hz",
        /// In a robot recording, take the robot's headings from its motion instead of its
        /// recorded orientations (choice: true; the shared robot-fish files record the robot's
        /// orientation with the wrong sign of the angle, see the data README).
        pub robot_heading_from_motion: bool = true; "",
        /// Random splits of the real recordings into halves for the split-half distance of the
        /// spread section (choice).
        pub split_half_reps: usize = 1000; "splits",
        /// Simulations of each recording per model (choice: 1). More make a model's side of the
        /// comparison (its pooled distributions, the s.d. of its per-recording values) less a
        /// matter of its random draws; the real side stays what it is.
        pub replicates: usize = 1; "simulations",
    }
}

impl OfflineConfig {
    /// Checks the ranges.
    pub fn validate(&self) -> Result<(), ConfigError> {
        for (f, v, lo, hi) in [
            ("bootstrap_reps", self.bootstrap_reps, 1, 10_000_000),
            ("hist_bins", self.hist_bins, 10, 100_000),
            ("split_half_reps", self.split_half_reps, 1, 10_000_000),
            ("replicates", self.replicates, 1, 1000),
        ] {
            if !(lo..=hi).contains(&v) {
                return Err(ConfigError::new(
                    "offline",
                    f,
                    v,
                    &format!("must lie in [{lo}, {hi}]"),
                ));
            }
        }
        check::within(
            "offline",
            "pause_cm_s",
            self.pause_cm_s,
            0.0,
            check::MAX_SPEED_CM_S,
        )?;
        check::positive_at_most("offline", "model_rate_hz", self.model_rate_hz, 1000.0)?;
        check::positive_at_most(
            "offline",
            "motion_min_step_cm",
            self.motion_min_step_cm,
            check::MAX_LENGTH_CM,
        )?;
        check::positive_at_most(
            "offline",
            "heading_disagreement_rad",
            self.heading_disagreement_rad,
            std::f32::consts::PI,
        )?;
        if !(self.ci_level > 0.0 && self.ci_level < 1.0) {
            return Err(ConfigError::new(
                "offline",
                "ci_level",
                self.ci_level,
                "must lie in (0, 1)",
            ));
        }
        Ok(())
    }
}

/// One model's distance to reality in one metric.
#[derive(Debug, Clone, PartialEq, Serialize)]
pub struct OfflineGap {
    /// 1-Wasserstein distance between pooled real and model values.
    pub w: f64,
    /// Bootstrap interval (recordings resampled).
    pub ci: [f64; 2],
    /// Real values.
    pub n_real: usize,
    /// Model values.
    pub n_model: usize,
}

/// One comparison: the pair recordings, or the robot recordings (open loop).
#[derive(Debug, Clone, PartialEq, Serialize, Default)]
pub struct Comparison {
    /// Real recordings used.
    pub recordings: Vec<String>,
    /// model → measure → gap.
    pub gaps: BTreeMap<String, BTreeMap<String, OfflineGap>>,
    /// Per model (and "real"), per measure, a normalised histogram for the figures
    /// (`hist_bins` / 40 bins over the measure's range).
    pub histograms: BTreeMap<String, Vec<Vec<f64>>>,
    /// How much recordings differ from one another, real against each model.
    pub spread: OfflineSpread,
}

/// The comparison's results.
#[derive(Debug, Clone, PartialEq, Serialize)]
pub struct OfflineResults {
    /// Pairs of live fish against model pairs (its fields at the top level of
    /// `offline.json`; empty without pair recordings).
    #[serde(flatten)]
    pub pairs: Comparison,
    /// Robot recordings against model fish beside the replayed robot (open loop), when there
    /// are any.
    #[serde(skip_serializing_if = "Option::is_none")]
    pub open_loop: Option<Comparison>,
    /// Recordings skipped, with the reason.
    pub skipped: Vec<(String, String)>,
    /// The settings.
    pub config: OfflineConfig,
    /// Master seed.
    pub seed: u64,
}

fn hist(values: &[f64], m: usize, bins: usize) -> Vec<f64> {
    let (lo, hi) = OFFLINE_METRICS[m].range;
    let mut h = vec![0.0; bins];
    for &x in values {
        let i = (((x - lo) / (hi - lo)) * bins as f64)
            .floor()
            .clamp(0.0, (bins - 1) as f64) as usize;
        h[i] += 1.0;
    }
    h
}

/// W1 between two histograms on the same bins of metric `m`.
fn hist_w1(a: &[f64], b: &[f64], m: usize) -> f64 {
    let (lo, hi) = OFFLINE_METRICS[m].range;
    let dx = (hi - lo) / a.len() as f64;
    let (sa, sb) = (a.iter().sum::<f64>(), b.iter().sum::<f64>());
    if sa == 0.0 || sb == 0.0 {
        return f64::NAN;
    }
    let (mut ca, mut cb, mut w) = (0.0, 0.0, 0.0);
    for (x, y) in a.iter().zip(b) {
        ca += x / sa;
        cb += y / sb;
        w += (ca - cb).abs() * dx;
    }
    w
}

fn pooled(v: &[RecordingValues], m: usize) -> Vec<f64> {
    v.iter().flat_map(|p| p.values[m].iter().copied()).collect()
}

/// Compares each model with the real recordings. `real`: (name, recording) per recording,
/// pairs and robot recordings in any order.
pub fn compare_offline(
    real: &[(String, Recording)],
    skipped: Vec<(String, String)>,
    models: &[(String, ModelSpec)],
    cfg: &OfflineConfig,
    seed: u64,
) -> Result<OfflineResults, crate::AnalysisError> {
    cfg.validate().map_err(|e| e.to_string())?;
    if real.is_empty() {
        return Err("no usable real recordings (pairs, or one fish beside the robot)".into());
    }
    type Named<'a> = Vec<&'a (String, Recording)>;
    let (robot, pairs): (Named, Named) = real.iter().partition(|(_, r)| r.has_robot());
    let pairs = if pairs.is_empty() {
        Comparison::default()
    } else {
        comparison(&pairs, models, cfg, seed, "offline")?
    };
    let open_loop = if robot.is_empty() {
        None
    } else {
        Some(comparison(&robot, models, cfg, seed, "offline/open_loop")?)
    };
    Ok(OfflineResults {
        pairs,
        open_loop,
        skipped,
        config: cfg.clone(),
        seed,
    })
}

/// One comparison of recordings of one kind; `label` roots its random streams.
fn comparison(
    real: &[&(String, Recording)],
    models: &[(String, ModelSpec)],
    cfg: &OfflineConfig,
    seed: u64,
    label: &str,
) -> Result<Comparison, crate::AnalysisError> {
    let real_vals: Vec<RecordingValues> = real
        .par_iter()
        .map(|(_, r)| recording_values(r, cfg))
        .collect();
    let fig_bins = (cfg.hist_bins / 40).max(10);
    let mut res = Comparison {
        recordings: real.iter().map(|(n, _)| n.clone()).collect(),
        ..Comparison::default()
    };
    res.histograms.insert(
        "real".into(),
        (0..OFFLINE_METRICS.len())
            .map(|m| normalise(hist(&pooled(&real_vals, m), m, fig_bins)))
            .collect(),
    );
    let mut simulated = Vec::with_capacity(models.len());
    for (name, spec) in models {
        let built = spec.build().map_err(|e| format!("{name}: {e}"))?;
        // Simulation i is of recording i mod n (with one replicate, simulation i of recording i).
        let sims: Vec<Result<RecordingValues, crate::AnalysisError>> = (0..real.len()
            * cfg.replicates)
            .into_par_iter()
            .map(|i| {
                let r = &real[i % real.len()].1;
                let s = fishprobe_sim::derive_seed(seed, &format!("{label}/{name}"), i as u64);
                simulate_model(&built, r, cfg, s).map(|(t, _)| recording_values(&t, cfg))
            })
            .collect();
        let sims: Vec<RecordingValues> = sims
            .into_iter()
            .collect::<Result<_, _>>()
            .map_err(|e| format!("{name}: {e}"))?;
        let per = (0..OFFLINE_METRICS.len())
            .into_par_iter()
            .map(|m| {
                let g = pooled_gap(
                    &real_vals,
                    &sims,
                    m,
                    cfg,
                    seed,
                    &format!("{label}/bootstrap/{name}"),
                );
                (OFFLINE_METRICS[m].id.to_string(), g)
            })
            .collect();
        res.gaps.insert(name.clone(), per);
        res.histograms.insert(
            name.clone(),
            (0..OFFLINE_METRICS.len())
                .map(|m| normalise(hist(&pooled(&sims, m), m, fig_bins)))
                .collect(),
        );
        simulated.push((name.clone(), sims));
    }
    res.spread = spread::offline_spread(&real_vals, &simulated, cfg, seed, label);
    Ok(res)
}

/// The gap in pooled measure `m` between the real and a model's recordings, with its
/// recording bootstrap from the stream `{label}/{measure}`.
fn pooled_gap(
    real: &[RecordingValues],
    sims: &[RecordingValues],
    m: usize,
    cfg: &OfflineConfig,
    seed: u64,
    label: &str,
) -> OfflineGap {
    let metric = OFFLINE_METRICS[m].id;
    let (a, b) = (pooled(real, m), pooled(sims, m));
    let w = fishprobe_stats::wasserstein(&a, &b).unwrap_or(f64::NAN);
    let mut rng: SimRng = stream(seed, &format!("{label}/{metric}"), 0);
    let ha: Vec<Vec<f64>> = real
        .iter()
        .map(|p| hist(&p.values[m], m, cfg.hist_bins))
        .collect();
    let hb: Vec<Vec<f64>> = sims
        .iter()
        .map(|p| hist(&p.values[m], m, cfg.hist_bins))
        .collect();
    let (mut sa, mut sb) = (vec![0.0; cfg.hist_bins], vec![0.0; cfg.hist_bins]);
    let mut boot: Vec<f64> = (0..cfg.bootstrap_reps)
        .map(|_| {
            sa.iter_mut().for_each(|x| *x = 0.0);
            sb.iter_mut().for_each(|x| *x = 0.0);
            // Each side resampled at its own size (drawn alternately while both have draws
            // left, so one replicate per recording draws as it always did).
            for i in 0..ha.len().max(hb.len()) {
                if i < ha.len() {
                    let k = rng.random_range(0..ha.len());
                    sa.iter_mut().zip(&ha[k]).for_each(|(x, y)| *x += y);
                }
                if i < hb.len() {
                    let k = rng.random_range(0..hb.len());
                    sb.iter_mut().zip(&hb[k]).for_each(|(x, y)| *x += y);
                }
            }
            hist_w1(&sa, &sb, m)
        })
        .filter(|x| x.is_finite())
        .collect();
    OfflineGap {
        w,
        ci: fishprobe_stats::percentile_ci(&mut boot, cfg.ci_level),
        n_real: a.len(),
        n_model: b.len(),
    }
}

fn normalise(mut h: Vec<f64>) -> Vec<f64> {
    let s: f64 = h.iter().sum();
    if s > 0.0 {
        h.iter_mut().for_each(|x| *x /= s);
    }
    h
}

/// Files left out, with the reason.
pub type Skips = Vec<(String, String)>;

/// The recordings of `files` (read with `read`): pairs, and one fish beside the robot; and
/// the files skipped with the reason.
pub fn read_recordings<E: std::fmt::Display>(
    files: &[PathBuf],
    read: impl Fn(&std::path::Path) -> Result<TrialFile, E> + Sync,
    cfg: &OfflineConfig,
) -> (Vec<(String, Recording)>, Skips) {
    let r: Vec<(String, Result<Recording, String>)> = files
        .par_iter()
        .map(|f| {
            (
                f.display().to_string(),
                read(f)
                    .map_err(|e| e.to_string())
                    .and_then(|t| real_recording(&t, cfg).map_err(|e| e.to_string())),
            )
        })
        .collect();
    let mut ok = Vec::new();
    let mut bad = Vec::new();
    for (n, p) in r {
        match p {
            Ok(p) => ok.push((n, p)),
            Err(e) => bad.push((n, e)),
        }
    }
    (ok, bad)
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn histogram_w1_matches_the_exact_distance() {
        let a: Vec<f64> = (0..1000).map(|i| f64::from(i) * 0.01).collect();
        let b: Vec<f64> = a.iter().map(|x| x + 2.0).collect();
        let w = hist_w1(&hist(&a, 0, 4000), &hist(&b, 0, 4000), 0);
        assert!((w - 2.0).abs() < 0.02, "{w}");
    }
}
