//! The classic offline evaluation that the paper's method is contrasted with: simulate pairs
//! of two model fish and compare their motion with recorded pairs of live fish.
//!
//! For every real recording, each model simulates one pair in the tank, as long as the
//! recording, starting from the recording's first tracked poses (seeded per file and model).
//! Six distributions are compared: speed, absolute turn rate, distance to the nearest wall (per
//! fish and frame), inter-individual distance and alignment cos(θ1 - θ2) (per frame), and the
//! fraction of time paused (speed below `pause_cm_s`, per fish). Real headings are checked
//! against motion as in the ConvNet's dataset. For each model and metric: the 1-Wasserstein
//! distance between the pooled real and model values, and a percentile interval from a
//! bootstrap that resamples recordings (and simulated pairs) with replacement — the recording is
//! the unit that varies, frames within it are not independent. The bootstrap works on fine
//! histograms (`hist_bins` per metric), so each replicate costs O(bins).

use fishprobe_io::{Entity, TrialFile};
use fishprobe_models::ModelSpec;
use fishprobe_sim::params::{check, ConfigError};
use fishprobe_sim::{stream, wrap_angle, Sandbox, SimRng, Tank, TankParams};
use rand::RngExt;
use rayon::prelude::*;
use serde::Serialize;
use std::path::PathBuf;

/// The compared metrics, in order, with units.
pub const OFFLINE_METRICS: [(&str, &str); 6] = [
    ("speed", "cm/s"),
    ("turn_rate", "rad/s"),
    ("wall_distance", "cm"),
    ("iid", "cm"),
    ("alignment", "cos"),
    ("paused", "fraction"),
];

/// Histogram range of each metric (values outside go to the edge bins).
const RANGES: [(f64, f64); 6] = [
    (0.0, 40.0),
    // |Δθ| at 25 Hz is at most π per frame: 78.5 rad/s.
    (0.0, 80.0),
    (0.0, 50.0),
    (0.0, 142.0),
    (-1.0, 1.0),
    (0.0, 1.0),
];

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
    }
}

impl OfflineConfig {
    /// Checks the ranges.
    pub fn validate(&self) -> Result<(), ConfigError> {
        for (f, v, lo, hi) in [
            ("bootstrap_reps", self.bootstrap_reps, 1, 10_000_000),
            ("hist_bins", self.hist_bins, 10, 100_000),
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

/// One pair's values of the six metrics.
#[derive(Debug, Clone, Default, PartialEq)]
pub struct PairValues {
    /// Per metric, the values (per fish-frame, per frame, or per fish for `paused`).
    pub values: [Vec<f64>; 6],
}

/// Poses of a pair: per fish, positions and headings.
#[derive(Debug, Clone, PartialEq)]
pub struct PairTrack {
    /// Positions per fish.
    pub pos: [Vec<[f32; 2]>; 2],
    /// Headings per fish.
    pub heading: [Vec<f32>; 2],
    /// Frame rate.
    pub rate: f32,
}

/// The six metrics of a pair.
pub fn pair_values(p: &PairTrack, cfg: &OfflineConfig) -> PairValues {
    let tank = Tank::new(&TankParams::default());
    let rate = f64::from(p.rate);
    let mut v = PairValues::default();
    let frames = p.pos[0].len().min(p.pos[1].len());
    let ok = |q: [f32; 2]| q[0].is_finite() && q[1].is_finite();
    for f in 0..2 {
        let (mut slow, mut n) = (0usize, 0usize);
        for t in 0..frames {
            let a = p.pos[f][t];
            if !ok(a) {
                continue;
            }
            v.values[2].push(f64::from(tank.wall_distance(a[0], a[1])));
            if t + 1 < frames && ok(p.pos[f][t + 1]) {
                let b = p.pos[f][t + 1];
                let s = f64::from(((b[0] - a[0]).powi(2) + (b[1] - a[1]).powi(2)).sqrt()) * rate;
                v.values[0].push(s);
                n += 1;
                if s < f64::from(cfg.pause_cm_s) {
                    slow += 1;
                }
                let (h0, h1) = (p.heading[f][t], p.heading[f][t + 1]);
                if h0.is_finite() && h1.is_finite() {
                    v.values[1].push(f64::from(wrap_angle(h1 - h0).abs()) * rate);
                }
            }
        }
        if n > 0 {
            v.values[5].push(slow as f64 / n as f64);
        }
    }
    for t in 0..frames {
        let (a, b) = (p.pos[0][t], p.pos[1][t]);
        if ok(a) && ok(b) {
            v.values[3].push(f64::from(
                ((a[0] - b[0]).powi(2) + (a[1] - b[1]).powi(2)).sqrt(),
            ));
        }
        let (h0, h1) = (p.heading[0][t], p.heading[1][t]);
        if h0.is_finite() && h1.is_finite() {
            v.values[4].push(f64::from((h0 - h1).cos()));
        }
    }
    v
}

/// A real pair from a trial file (exactly two fish, 100 x 100 cm), or why not.
pub fn real_pair(t: &TrialFile, cfg: &OfflineConfig) -> Result<PairTrack, crate::AnalysisError> {
    if (t.world_size_cm[0] - 100.0).abs() > 0.5 || (t.world_size_cm[1] - 100.0).abs() > 0.5 {
        return Err(format!(
            "world size {} x {} cm, not the 100 x 100 cm tank",
            t.world_size_cm[0], t.world_size_cm[1]
        )
        .into());
    }
    let fish: Vec<&Entity> = t.fish().collect();
    if fish.len() != 2 {
        return Err(format!("{} fish, not a pair", fish.len()).into());
    }
    if fish.iter().any(|f| f.nan_fraction() >= 1.0) {
        return Err("a fish track is all NaN".into());
    }
    let h = |e: &Entity| {
        e.headings_checked(cfg.motion_min_step_cm, cfg.heading_disagreement_rad)
            .0
    };
    Ok(PairTrack {
        pos: [fish[0].positions.clone(), fish[1].positions.clone()],
        heading: [h(fish[0]), h(fish[1])],
        rate: t.frame_rate_hz,
    })
}

/// A model pair as long as `real`, from its first tracked poses.
pub fn simulate_pair(
    model: &ModelSpec,
    real: &PairTrack,
    seed: u64,
) -> Result<PairTrack, crate::AnalysisError> {
    let frames = real.pos[0].len().min(real.pos[1].len());
    let start = |f: usize| -> [f32; 3] {
        (0..frames)
            .find(|&t| real.pos[f][t][0].is_finite() && real.heading[f][t].is_finite())
            .map_or([0.0, 0.0, 0.0], |t| {
                [real.pos[f][t][0], real.pos[f][t][1], real.heading[f][t]]
            })
    };
    let m = model.build().map_err(|e| e.to_string())?;
    let tank = Tank::new(&TankParams::default());
    let mut sb = Sandbox::new(tank, real.rate, m, &[start(0), start(1)], seed);
    let mut out = PairTrack {
        pos: [Vec::with_capacity(frames), Vec::with_capacity(frames)],
        heading: [Vec::with_capacity(frames), Vec::with_capacity(frames)],
        rate: real.rate,
    };
    for t in 0..frames {
        if t > 0 {
            sb.step().map_err(|e| e.to_string())?;
        }
        for (f, s) in sb.fish().iter().enumerate() {
            out.pos[f].push([s.x, s.y]);
            out.heading[f].push(s.heading);
        }
    }
    Ok(out)
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

/// The comparison's results.
#[derive(Debug, Clone, PartialEq, Serialize)]
pub struct OfflineResults {
    /// Real recordings used.
    pub recordings: Vec<String>,
    /// Recordings skipped, with the reason.
    pub skipped: Vec<(String, String)>,
    /// model → metric → gap.
    pub gaps: std::collections::BTreeMap<String, std::collections::BTreeMap<String, OfflineGap>>,
    /// Per model (and "real"), per metric, a normalised histogram for the figures
    /// (`hist_bins` / 40 bins over the metric's range).
    pub histograms: std::collections::BTreeMap<String, Vec<Vec<f64>>>,
    /// The settings.
    pub config: OfflineConfig,
    /// Master seed.
    pub seed: u64,
}

fn hist(values: &[f64], m: usize, bins: usize) -> Vec<f64> {
    let (lo, hi) = RANGES[m];
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
    let (lo, hi) = RANGES[m];
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

fn pooled(v: &[PairValues], m: usize) -> Vec<f64> {
    v.iter().flat_map(|p| p.values[m].iter().copied()).collect()
}

/// Compares each model with the real pairs. `real`: (name, pair) per recording.
pub fn compare_offline(
    real: &[(String, PairTrack)],
    skipped: Vec<(String, String)>,
    models: &[(String, ModelSpec)],
    cfg: &OfflineConfig,
    seed: u64,
) -> Result<OfflineResults, crate::AnalysisError> {
    cfg.validate().map_err(|e| e.to_string())?;
    if real.is_empty() {
        return Err("no usable real pair recordings".into());
    }
    let real_vals: Vec<PairValues> = real.par_iter().map(|(_, p)| pair_values(p, cfg)).collect();
    let fig_bins = (cfg.hist_bins / 40).max(10);
    let mut res = OfflineResults {
        recordings: real.iter().map(|(n, _)| n.clone()).collect(),
        skipped,
        gaps: Default::default(),
        histograms: Default::default(),
        config: cfg.clone(),
        seed,
    };
    res.histograms.insert(
        "real".into(),
        (0..6)
            .map(|m| normalise(hist(&pooled(&real_vals, m), m, fig_bins)))
            .collect(),
    );
    for (name, spec) in models {
        let sims: Vec<Result<PairValues, crate::AnalysisError>> = real
            .par_iter()
            .enumerate()
            .map(|(i, (_, p))| {
                let s = fishprobe_sim::derive_seed(seed, &format!("offline/{name}"), i as u64);
                simulate_pair(spec, p, s).map(|t| pair_values(&t, cfg))
            })
            .collect();
        let sims: Vec<PairValues> = sims
            .into_iter()
            .collect::<Result<_, _>>()
            .map_err(|e| format!("{name}: {e}"))?;
        let mut per = std::collections::BTreeMap::new();
        for (m, (metric, _)) in OFFLINE_METRICS.iter().enumerate() {
            let (a, b) = (pooled(&real_vals, m), pooled(&sims, m));
            let w = fishprobe_stats::wasserstein(&a, &b).unwrap_or(f64::NAN);
            let mut rng: SimRng = stream(seed, &format!("offline/bootstrap/{name}/{metric}"), 0);
            let ha: Vec<Vec<f64>> = real_vals
                .iter()
                .map(|p| hist(&p.values[m], m, cfg.hist_bins))
                .collect();
            let hb: Vec<Vec<f64>> = sims
                .iter()
                .map(|p| hist(&p.values[m], m, cfg.hist_bins))
                .collect();
            let mut boot: Vec<f64> = (0..cfg.bootstrap_reps)
                .map(|_| {
                    let mut sa = vec![0.0; cfg.hist_bins];
                    let mut sb = vec![0.0; cfg.hist_bins];
                    for _ in 0..ha.len() {
                        let k = rng.random_range(0..ha.len());
                        sa.iter_mut().zip(&ha[k]).for_each(|(x, y)| *x += y);
                        let k = rng.random_range(0..hb.len());
                        sb.iter_mut().zip(&hb[k]).for_each(|(x, y)| *x += y);
                    }
                    hist_w1(&sa, &sb, m)
                })
                .filter(|x| x.is_finite())
                .collect();
            per.insert(
                (*metric).to_string(),
                OfflineGap {
                    w,
                    ci: fishprobe_stats::percentile_ci(&mut boot, cfg.ci_level),
                    n_real: a.len(),
                    n_model: b.len(),
                },
            );
        }
        res.gaps.insert(name.clone(), per);
        res.histograms.insert(
            name.clone(),
            (0..6)
                .map(|m| normalise(hist(&pooled(&sims, m), m, fig_bins)))
                .collect(),
        );
    }
    Ok(res)
}

fn normalise(mut h: Vec<f64>) -> Vec<f64> {
    let s: f64 = h.iter().sum();
    if s > 0.0 {
        h.iter_mut().for_each(|x| *x /= s);
    }
    h
}

/// The metric's histogram range (for figures).
pub fn metric_range(m: usize) -> (f64, f64) {
    RANGES[m]
}

impl OfflineResults {
    /// `offline.csv`: model, metric, unit, w, ci_low, ci_high, n_real, n_model.
    pub fn csv(&self) -> String {
        let mut s = String::from("model,metric,unit,w,ci_low,ci_high,n_real,n_model\n");
        for (model, per) in &self.gaps {
            for (metric, unit) in OFFLINE_METRICS {
                if let Some(g) = per.get(metric) {
                    s += &format!(
                        "{model},{metric},{unit},{},{},{},{},{}\n",
                        g.w, g.ci[0], g.ci[1], g.n_real, g.n_model
                    );
                }
            }
        }
        s
    }

    /// A Markdown table: metrics as rows, models as columns, W \[CI\]; the smallest per row in bold.
    pub fn markdown(&self) -> String {
        let models: Vec<&String> = self.gaps.keys().collect();
        let mut s = String::from("| metric |");
        for m in &models {
            s += &format!(" M_{m} |");
        }
        s += "\n|---|";
        s += &"---|".repeat(models.len());
        s.push('\n');
        for (metric, unit) in OFFLINE_METRICS {
            let ws: Vec<f64> = models.iter().map(|m| self.gaps[*m][metric].w).collect();
            let best = ws
                .iter()
                .copied()
                .filter(|w| w.is_finite())
                .fold(f64::INFINITY, f64::min);
            s += &format!("| {metric} ({unit}) |");
            for (m, w) in models.iter().zip(&ws) {
                let g = &self.gaps[*m][metric];
                let cell = format!("{w:.3} [{:.3}, {:.3}]", g.ci[0], g.ci[1]);
                s += &if *w == best {
                    format!(" **{cell}** |")
                } else {
                    format!(" {cell} |")
                };
            }
            s.push('\n');
        }
        s
    }
}

/// Files left out, with the reason.
pub type Skips = Vec<(String, String)>;

/// The pairs of `files` (read with `read`), and the files skipped with the reason.
pub fn read_pairs<E: std::fmt::Display>(
    files: &[PathBuf],
    read: impl Fn(&std::path::Path) -> Result<TrialFile, E> + Sync,
    cfg: &OfflineConfig,
) -> (Vec<(String, PairTrack)>, Skips) {
    let r: Vec<(String, Result<PairTrack, String>)> = files
        .par_iter()
        .map(|f| {
            (
                f.display().to_string(),
                read(f)
                    .map_err(|e| e.to_string())
                    .and_then(|t| real_pair(&t, cfg).map_err(|e| e.to_string())),
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
    fn pair_values_by_hand() {
        // Fish 0 moves 1 cm per frame along +x at 25 Hz; fish 1 sits still facing +y.
        let p = PairTrack {
            pos: [
                vec![[0.0, 0.0], [1.0, 0.0], [2.0, 0.0]],
                vec![[0.0, 10.0], [0.0, 10.0], [0.0, 10.0]],
            ],
            heading: [vec![0.0; 3], vec![std::f32::consts::FRAC_PI_2; 3]],
            rate: 25.0,
        };
        let v = pair_values(&p, &OfflineConfig::default());
        assert_eq!(v.values[0][..2], [25.0, 25.0]);
        assert_eq!(v.values[0][2..], [0.0, 0.0]);
        assert_eq!(v.values[5], vec![0.0, 1.0], "fish 1 is always paused");
        assert!((v.values[3][2] - (4.0f64 + 100.0).sqrt()).abs() < 1e-5);
        assert!(v.values[4].iter().all(|c| c.abs() < 1e-6), "perpendicular");
        assert_eq!(v.values[2][0], 50.0);
    }

    #[test]
    fn histogram_w1_matches_the_exact_distance() {
        let a: Vec<f64> = (0..1000).map(|i| f64::from(i) * 0.01).collect();
        let b: Vec<f64> = a.iter().map(|x| x + 2.0).collect();
        let w = hist_w1(&hist(&a, 0, 4000), &hist(&b, 0, 4000), 0);
        assert!((w - 2.0).abs() < 0.02, "{w}");
    }
}
