//! Behavioural cloning of live guppy pairs for M_ConvNet (SPEC §6): the dataset and the
//! training loop behind `fishprobe fit-convnet`.
//!
//! **Dataset.** Every file of two fish (robofish.io or the lab's legacy layout) gives, for each
//! fish and frame t, its egocentric view at t (with the other fish as the neighbour) and the
//! grid cell of its next (v, ω): v = |p(t+1) - p(t)| · rate, ω = wrap(θ(t+1) - θ(t)) · rate.
//! Frames are left out when a position needed (own at t, t+1, t+2; the other's at t) is NaN, or
//! when the tracker interpolated the fish's own frame t or t+1 (`interp_frames` of legacy files,
//! counted from the start of `tracking_interval`). The heading θ(t) is the recorded orientation,
//! except where the fish moves (a step of at least `motion_min_step_cm`) in a direction more
//! than `heading_disagreement_rad` away from it: there the tracker confused head and tail, and
//! the direction of motion is used. Headings are then smoothed over `heading_smoothing_frames`
//! (centred circular mean), which removes the tracker's frame-to-frame jitter from views and
//! turn targets. Files that are not 100 x 100 cm, do not hold exactly two
//! fish, are shorter than `min_frames` or all NaN are skipped with the reason.
//!
//! **Training.** Softmax cross-entropy (the negative log-likelihood of the recorded cell),
//! Adam, minibatches split over two threads, early stopping on the validation NLL (the best
//! epoch's weights are kept), all seeded.

use crate::error::LearnError;
use fishprobe_io::{read_legacy, read_trial, Attr, TrialFile};
use fishprobe_models::convnet::{encode_view, ConvNet, ConvNetArch, ConvNetWorkspace, CHANNELS};
use fishprobe_models::support::{SupportConfig, SupportModel};
use fishprobe_nn::Adam;
use fishprobe_sim::params::{check, ConfigError};
use fishprobe_sim::{wrap_angle, AgentState, SimRng, Tank, TankParams};
use rand::RngExt;
use rayon::prelude::*;
use std::path::{Path, PathBuf};

fishprobe_sim::documented_params! {
    /// How pair recordings become training examples, and how the network is fitted.
    pub struct CloneConfig {
        /// A step at least this long (cm per frame) shows the direction of motion (choice:
        /// 0.1 cm per frame = 2.5 cm/s).
        pub motion_min_step_cm: f32 = 0.1; "cm",
        /// Recorded orientation and direction of motion further apart than this: use the
        /// direction of motion (choice: 90°).
        pub heading_disagreement_rad: f32 = std::f32::consts::FRAC_PI_2; "rad",
        /// Headings are smoothed over this many frames, centred (circular mean; odd; 1: none),
        /// before views and turn targets are taken from them. **Choice: 5 (0.2 s at 25 Hz).**
        /// The recorded orientation jitters from frame to frame (median |Δθ| 0.053 rad in the
        /// training pairs) without the jitter adding up (0.072 over 5 frames): tracking noise.
        /// A fish that samples each frame's turn independently (SPEC §6) adds it up as real
        /// turning, and unsmoothed its course wandered twice as fast as a guppy's over 0.2-1 s
        /// and into the walls (issue 20, item 4). Five frames remove the jitter (0.014 per
        /// frame) and leave the course over 1 s and 3 s as recorded (median 0.235 and 0.605
        /// rad, against 0.243 and 0.612). The measurements: docs/validation.md, "M_ConvNet
        /// at the walls".
        pub heading_smoothing_frames: usize = 5; "frames",
        /// Files with fewer frames are skipped (choice: 10 s at 25 Hz).
        pub min_frames: usize = 250; "frames",
        /// Minibatch size (choice).
        pub batch_size: usize = 512; "examples",
        /// Adam learning rate (choice).
        pub learning_rate: f32 = 0.001; "1",
        /// Most epochs (choice).
        pub max_epochs: usize = 30; "epochs",
        /// Stop after this many epochs without a better validation NLL (choice).
        pub patience: usize = 3; "epochs",
        /// Also learn from files of one fish with the robot (`lab`, `evaluate`, live trials):
        /// the fish's frames, with the robot as its neighbour (the robot's own motion is not a
        /// fish's). Choice: off, the paper fits fish pairs only; the OOD loop (issue 23) turns
        /// it on to add what the fish did under a policy.
        pub robot_as_partner: bool = false; "-",
        /// The partner range of the support written beside the weights
        /// (`support.partner_range_cm`; choice: 0, every partner counts).
        pub support_partner_range_cm: f32 = 0.0; "cm",
        /// Networks of the ensemble fitted on the same data, the weights included, in
        /// [1, 16] (choice: 1, no ensemble). With K > 1 the K - 1 further members (each from its
        /// own initialisation and shuffle, seeds derived by label) are written beside the
        /// weights with the ensemble's disagreement file, which the OOD score `disagreement`
        /// needs (issue 23). Each member costs a fit.
        pub ensemble_members: usize = 1; "networks",
        /// Training views the disagreement is calibrated on (choice: 2048, as the support).
        pub ensemble_calibration_views: usize = 2048; "views",
    }
}

impl CloneConfig {
    /// Checks the ranges.
    pub fn validate(&self) -> Result<(), ConfigError> {
        check::positive("clone", "motion_min_step_cm", self.motion_min_step_cm)?;
        check::positive(
            "clone",
            "heading_disagreement_rad",
            self.heading_disagreement_rad,
        )?;
        check::positive("clone", "learning_rate", self.learning_rate)?;
        check::non_negative(
            "clone",
            "support_partner_range_cm",
            self.support_partner_range_cm,
        )?;
        if self.heading_smoothing_frames.is_multiple_of(2) || self.heading_smoothing_frames > 251 {
            return Err(ConfigError::new(
                "clone",
                "heading_smoothing_frames",
                self.heading_smoothing_frames,
                "must be odd and at most 251 (1: no smoothing)",
            ));
        }
        for (f, v) in [
            ("batch_size", self.batch_size),
            ("max_epochs", self.max_epochs),
            ("patience", self.patience),
            ("min_frames", self.min_frames),
        ] {
            if v == 0 {
                return Err(ConfigError::new("clone", f, 0, "must be at least 1"));
            }
        }
        if !(1..=fishprobe_models::disagreement::MAX_MEMBERS).contains(&self.ensemble_members) {
            return Err(ConfigError::new(
                "clone",
                "ensemble_members",
                self.ensemble_members,
                &format!(
                    "must lie in [1, {}]",
                    fishprobe_models::disagreement::MAX_MEMBERS
                ),
            ));
        }
        if !(20..=1 << 20).contains(&self.ensemble_calibration_views) {
            return Err(ConfigError::new(
                "clone",
                "ensemble_calibration_views",
                self.ensemble_calibration_views,
                "must lie in [20, 1048576]",
            ));
        }
        // Upper bounds, checked before anything is allocated: a batch is held in memory, and
        // the paper's fit takes well under 1,000 epochs.
        if self.batch_size > 1 << 20 || self.max_epochs > 1_000_000 {
            return Err(ConfigError::new(
                "clone",
                "max_epochs",
                self.max_epochs,
                &format!(
                    "at most 1,000,000 epochs of batches of at most 1,048,576 (batch_size = {})",
                    self.batch_size
                ),
            ));
        }
        Ok(())
    }
}

/// Examples: views and target cells.
#[derive(Debug, Clone, Default)]
pub struct PairDataset {
    /// Views, `n x view_len`.
    pub x: Vec<f32>,
    /// Target cells.
    pub y: Vec<usize>,
    /// Files used.
    pub files: Vec<PathBuf>,
    /// Files skipped, with the reason.
    pub skipped: Vec<(PathBuf, String)>,
    /// Frames left out (NaN or interpolated).
    pub frames_left_out: usize,
    /// Frames whose heading came from motion.
    pub headings_from_motion: usize,
}

impl PairDataset {
    /// Number of examples.
    pub fn len(&self) -> usize {
        self.y.len()
    }
    /// Whether there are none.
    pub fn is_empty(&self) -> bool {
        self.y.is_empty()
    }
}

/// Reads robofish.io, or else the legacy layout.
pub fn read_any(path: &Path) -> Result<TrialFile, String> {
    match read_trial(path) {
        Ok(t) => Ok(t),
        Err(e1) => read_legacy(path).map_err(|e2| format!("{e1}; as a legacy file: {e2}")),
    }
}

/// Trial files under `dirs` (files given directly are taken as they are), sorted.
pub fn list_files(dirs: &[PathBuf]) -> Vec<PathBuf> {
    let mut out = Vec::new();
    for d in dirs {
        if d.is_file() {
            out.push(d.clone());
            continue;
        }
        out.extend(fishprobe_io::trial_files(d));
    }
    out
}

/// Per-frame poses of one fish with corrected headings; NaN where unknown.
struct Track {
    pos: Vec<[f32; 2]>,
    heading: Vec<f32>,
    interpolated: Vec<bool>,
    from_motion: usize,
}

fn track(e: &fishprobe_io::Entity, offset: i64, cfg: &CloneConfig) -> Track {
    let n = e.positions.len();
    let (heading, from_motion) =
        e.headings_checked(cfg.motion_min_step_cm, cfg.heading_disagreement_rad);
    let heading = smooth_headings(&heading, cfg.heading_smoothing_frames);
    let mut interpolated = vec![false; n];
    if let Some(Attr::Ints(frames)) = e.attributes.get("interp_frames") {
        for &f in frames {
            if let Ok(i) = usize::try_from(f - offset) {
                if let Some(s) = interpolated.get_mut(i) {
                    *s = true;
                }
            }
        }
    }
    Track {
        pos: e.positions.clone(),
        heading,
        interpolated,
        from_motion,
    }
}

/// Circular mean of each heading's centred window of `window` frames (odd), over the finite
/// headings in it; an unknown (NaN) heading stays unknown. `window` 1 returns the input.
pub fn smooth_headings(heading: &[f32], window: usize) -> Vec<f32> {
    let half = window / 2;
    (0..heading.len())
        .map(|t| {
            if window <= 1 || !heading[t].is_finite() {
                return heading[t];
            }
            let lo = t.saturating_sub(half);
            let hi = (t + half + 1).min(heading.len());
            let (mut c, mut s) = (0.0f64, 0.0f64);
            for &h in heading[lo..hi].iter().filter(|h| h.is_finite()) {
                c += f64::from(h.cos());
                s += f64::from(h.sin());
            }
            s.atan2(c) as f32
        })
        .collect()
}

/// Examples of one pair file appended to `d`, or why the file is skipped.
fn add_file(
    path: &Path,
    arch: &ConvNetArch,
    cfg: &CloneConfig,
    d: &mut PairDataset,
) -> Result<(), String> {
    let t = read_any(path)?;
    if (t.world_size_cm[0] - 100.0).abs() > 0.5 || (t.world_size_cm[1] - 100.0).abs() > 0.5 {
        return Err(format!(
            "world size {} x {} cm, not the 100 x 100 cm tank",
            t.world_size_cm[0], t.world_size_cm[1]
        ));
    }
    let mut fish: Vec<&fishprobe_io::Entity> = t.fish().collect();
    // (learner, neighbour) indices into `fish`.
    let pairs: &[(usize, usize)] = match (fish.len(), t.robot()) {
        (2, _) => &[(0, 1), (1, 0)],
        (1, Some(robot)) if cfg.robot_as_partner => {
            fish.push(robot);
            &[(0, 1)]
        }
        (1, Some(_)) => {
            return Err("1 fish with the robot, not a pair (clone.robot_as_partner is off)".into())
        }
        (n, _) => return Err(format!("{n} fish, not a pair")),
    };
    let frames = fish[0].frames().min(fish[1].frames());
    if frames < cfg.min_frames {
        return Err(format!("{frames} frames, shorter than {}", cfg.min_frames));
    }
    if fish.iter().any(|f| f.nan_fraction() >= 1.0) {
        return Err("a fish track is all NaN".into());
    }
    let offset = match t.attributes.get("tracking_interval") {
        Some(Attr::Ints(v)) if !v.is_empty() => v[0],
        Some(Attr::Floats(v)) if !v.is_empty() => v[0] as i64,
        _ => 0,
    };
    let rate = t.frame_rate_hz;
    let tracks: Vec<Track> = fish.iter().map(|f| track(f, offset, cfg)).collect();
    let tank = Tank::new(&TankParams::default());
    let len = arch.view_len();
    let mut view = vec![0.0; len];
    let ok = |p: [f32; 2]| p[0].is_finite() && p[1].is_finite();
    for &(me, other) in pairs {
        let (a, b) = (&tracks[me], &tracks[other]);
        d.headings_from_motion += a.from_motion;
        for i in 0..frames.saturating_sub(2) {
            let usable = ok(a.pos[i])
                && ok(a.pos[i + 1])
                && ok(a.pos[i + 2])
                && ok(b.pos[i])
                && a.heading[i].is_finite()
                && a.heading[i + 1].is_finite()
                && b.heading[i].is_finite()
                && !a.interpolated[i]
                && !a.interpolated[i + 1];
            if !usable {
                d.frames_left_out += 1;
                continue;
            }
            let s_me = AgentState::at(a.pos[i][0], a.pos[i][1], a.heading[i]);
            let s_other = AgentState::at(b.pos[i][0], b.pos[i][1], b.heading[i]);
            encode_view(arch, &tank, &s_me, &[s_other], &mut view);
            let (dx, dy) = (a.pos[i + 1][0] - a.pos[i][0], a.pos[i + 1][1] - a.pos[i][1]);
            let v = (dx * dx + dy * dy).sqrt() * rate;
            let w = wrap_angle(a.heading[i + 1] - a.heading[i]) * rate;
            d.x.extend_from_slice(&view);
            d.y.push(arch.cell_of(v, w));
        }
    }
    Ok(())
}

/// Builds the dataset of the pair files under `dirs`. An empty result is an error naming what
/// was skipped.
pub fn load_pairs(
    dirs: &[PathBuf],
    arch: &ConvNetArch,
    cfg: &CloneConfig,
) -> Result<PairDataset, LearnError> {
    let files = list_files(dirs);
    let parts: Vec<(PathBuf, Result<PairDataset, String>)> = files
        .par_iter()
        .map(|f| {
            let mut d = PairDataset::default();
            let r = add_file(f, arch, cfg, &mut d).map(|()| d);
            (f.clone(), r)
        })
        .collect();
    let mut d = PairDataset::default();
    for (f, r) in parts {
        match r {
            Ok(p) => {
                d.x.extend(p.x);
                d.y.extend(p.y);
                d.frames_left_out += p.frames_left_out;
                d.headings_from_motion += p.headings_from_motion;
                d.files.push(f);
            }
            Err(why) => d.skipped.push((f, why)),
        }
    }
    if d.is_empty() {
        let given = dirs;
        let dirs: Vec<String> = dirs.iter().map(|p| p.display().to_string()).collect();
        let why: Vec<String> = d
            .skipped
            .iter()
            .take(5)
            .map(|(f, w)| format!("{}: {w}", f.display()))
            .collect();
        return Err(LearnError::Run(format!(
            "no training examples in {} ({} files; {})",
            dirs.join(", "),
            files.len(),
            if why.is_empty() {
                dirs_without_files(given)
            } else {
                why.join("; ")
            }
        )));
    }
    Ok(d)
}

/// Why `dirs` gave no trial file, each path in a few words (missing, a device, an empty
/// directory).
fn dirs_without_files(dirs: &[PathBuf]) -> String {
    dirs.iter()
        .map(|d| {
            let what = if std::fs::symlink_metadata(d).is_err() {
                "does not exist".to_string()
            } else if d.is_dir() {
                "holds no trial files (*.hdf5, *.h5)".to_string()
            } else {
                fishprobe_io::limits::not_regular(d).unwrap_or_else(|| "not a trial file".into())
            };
            format!("{}: {what}", d.display())
        })
        .collect::<Vec<_>>()
        .join("; ")
}

/// Zeroes the neighbour channels (the "no neighbour" baseline network sees walls only).
pub fn blind(x: &mut [f32], arch: &ConvNetArch) {
    for row in x.chunks_exact_mut(arch.view_len()) {
        row[arch.bins..CHANNELS * arch.bins].fill(0.0);
    }
}

/// Mean NLL (nats per example) of the network on a dataset.
pub fn nll(net: &ConvNet, d: &PairDataset) -> f64 {
    let len = net.arch.view_len();
    let cells = net.arch.cells();
    let chunk = 4096;
    let total: f64 =
        d.x.par_chunks(chunk * len)
            .zip(d.y.par_chunks(chunk))
            .map(|(x, y)| {
                let mut ws = ConvNetWorkspace::default();
                let logits = net.forward(x, y.len(), &mut ws);
                let mut g = vec![0.0; logits.len()];
                f64::from(fishprobe_nn::dist::softmax_cross_entropy(
                    logits, cells, y, &mut g,
                )) * y.len() as f64
            })
            .sum();
    total / d.len().max(1) as f64
}

/// NLL of the training data's marginal cell histogram on `val` (add-½ smoothing: every cell
/// gets half a count, so unseen cells do not give infinite loss).
pub fn marginal_nll(train: &PairDataset, val: &PairDataset, cells: usize) -> f64 {
    let mut counts = vec![0.5f64; cells];
    for &c in &train.y {
        counts[c] += 1.0;
    }
    let total: f64 = counts.iter().sum();
    -val.y.iter().map(|&c| (counts[c] / total).ln()).sum::<f64>() / val.len().max(1) as f64
}

/// One epoch's log line.
#[derive(Debug, Clone, Copy, PartialEq, serde::Serialize, serde::Deserialize)]
pub struct EpochLog {
    /// Epoch (1-based).
    pub epoch: usize,
    /// Mean training NLL over the epoch's minibatches.
    pub train_nll: f64,
    /// Validation NLL after the epoch.
    pub val_nll: f64,
    /// Seconds since the start.
    pub seconds: f64,
}

/// One thread's buffers: workspace, logit gradients, conv and dense parameter gradients.
type Worker = (ConvNetWorkspace, Vec<f32>, Vec<f32>, Vec<f32>);

/// Fits `net` on `train`, stopping early on `val`; keeps the best epoch's weights. Calls
/// `on_epoch` after each epoch and `on_batch(done, total)` during it.
pub fn fit(
    net: &mut ConvNet,
    train: &PairDataset,
    val: &PairDataset,
    cfg: &CloneConfig,
    rng: &mut SimRng,
    mut on_epoch: impl FnMut(&EpochLog),
    on_batch: &(dyn Fn(usize, usize) + Sync),
) -> Result<Vec<EpochLog>, LearnError> {
    cfg.validate()?;
    let len = net.arch.view_len();
    let cells = net.arch.cells();
    let m = cfg.batch_size;
    let half = m.div_ceil(2);
    let mut adam_c = Adam::new(net.conv.params.len(), cfg.learning_rate);
    let mut adam_m = Adam::new(net.mlp.num_params(), cfg.learning_rate);
    let mut idx: Vec<usize> = (0..train.len()).collect();
    let (mut xb, mut yb) = (vec![0.0f32; m * len], vec![0usize; m]);
    let mut workers: Vec<Worker> = (0..2)
        .map(|_| {
            (
                ConvNetWorkspace::default(),
                vec![0.0; half * cells],
                vec![0.0; net.conv.params.len()],
                vec![0.0; net.mlp.num_params()],
            )
        })
        .collect();
    let started = std::time::Instant::now();
    let mut best = (nll(net, val), net.clone());
    let mut logs = Vec::new();
    let mut since_best = 0;
    for epoch in 1..=cfg.max_epochs {
        for i in (1..idx.len()).rev() {
            idx.swap(i, rng.random_range(0..=i));
        }
        let batches = idx.len() / m;
        let mut loss_sum = 0.0f64;
        for (b, chunk) in idx.chunks_exact(m).enumerate() {
            for (j, &k) in chunk.iter().enumerate() {
                xb[j * len..(j + 1) * len].copy_from_slice(&train.x[k * len..(k + 1) * len]);
                yb[j] = train.y[k];
            }
            let net_ref = &*net;
            let losses: Vec<f64> = workers
                .par_iter_mut()
                .zip(xb.par_chunks(half * len).zip(yb.par_chunks(half)))
                .map(|((ws, dl, gc, gm), (x, y))| {
                    let n = y.len();
                    let logits = net_ref.forward(x, n, ws);
                    let l = fishprobe_nn::dist::softmax_cross_entropy(
                        logits,
                        cells,
                        y,
                        &mut dl[..n * cells],
                    );
                    // Each half's gradient is a mean over its half: scale to the minibatch mean.
                    let scale = n as f32 / m as f32;
                    dl[..n * cells].iter_mut().for_each(|g| *g *= scale);
                    gc.fill(0.0);
                    gm.fill(0.0);
                    net_ref.backward(x, n, &dl[..n * cells], ws, gc, gm);
                    f64::from(l) * n as f64
                })
                .collect();
            loss_sum += losses.iter().sum::<f64>() / m as f64;
            let (w0, w1) = workers.split_at_mut(1);
            for (a, b) in w0[0].2.iter_mut().zip(&w1[0].2) {
                *a += b;
            }
            for (a, b) in w0[0].3.iter_mut().zip(&w1[0].3) {
                *a += b;
            }
            adam_c.step(&mut net.conv.params, &w0[0].2);
            adam_m.step(net.mlp.params_mut(), &w0[0].3);
            if b % 64 == 0 {
                on_batch(b, batches);
            }
        }
        let train_nll = loss_sum / batches.max(1) as f64;
        if !train_nll.is_finite() {
            return Err(LearnError::Diverged {
                iteration: epoch as u64,
                what: "training NLL is not finite".into(),
            });
        }
        let val_nll = nll(net, val);
        let log = EpochLog {
            epoch,
            train_nll,
            val_nll,
            seconds: started.elapsed().as_secs_f64(),
        };
        on_epoch(&log);
        logs.push(log);
        if val_nll < best.0 {
            best = (val_nll, net.clone());
            since_best = 0;
        } else {
            since_best += 1;
            if since_best >= cfg.patience {
                break;
            }
        }
    }
    *net = best.1;
    Ok(logs)
}

#[cfg(test)]
mod tests {
    use super::*;
    use rand::SeedableRng;

    #[test]
    fn data_without_trial_files_says_why_per_path() {
        let empty = std::env::temp_dir().join(format!("fishprobe-bc-empty-{}", std::process::id()));
        std::fs::create_dir_all(&empty).unwrap();
        let dirs = [
            empty.clone(),
            PathBuf::from("/nonexistent/pairs"),
            PathBuf::from("/dev/zero"),
        ];
        let e = load_pairs(&dirs, &ConvNetArch::default(), &CloneConfig::default())
            .err()
            .unwrap()
            .to_string();
        for part in [
            format!("{}: holds no trial files", empty.display()),
            "/nonexistent/pairs: does not exist".into(),
            "/dev/zero: a device, not a regular file".into(),
        ] {
            assert!(e.contains(&part), "{part} not in: {e}");
        }
        let _ = std::fs::remove_dir_all(&empty);
    }

    #[test]
    fn a_fit_is_resumed_only_from_the_same_examples_and_fit_settings() {
        let arch = ConvNetArch::default();
        let set = |n: usize, v: f32| PairDataset {
            x: vec![v; n * arch.view_len()],
            y: vec![3; n],
            files: Vec::new(),
            skipped: Vec::new(),
            frames_left_out: 0,
            headings_from_motion: 0,
        };
        let cfg = CloneConfig::default();
        let (t, v) = (set(5, 0.5), set(3, 0.25));
        let base = fit_inputs_sha256(&arch, &cfg, &t, &v);
        assert_eq!(base.len(), 64);
        // What does not change a fit: the ensemble's size and calibration, the support.
        let same = CloneConfig {
            ensemble_members: 4,
            ensemble_calibration_views: 100,
            support_partner_range_cm: 15.0,
            ..cfg.clone()
        };
        assert_eq!(fit_inputs_sha256(&arch, &same, &t, &v), base);
        // What does: the fit's settings, a single example, the split.
        let lr = CloneConfig {
            learning_rate: 0.002,
            ..cfg.clone()
        };
        assert_ne!(fit_inputs_sha256(&arch, &lr, &t, &v), base);
        let mut t2 = t.clone();
        t2.x[7] = 0.5000001;
        assert_ne!(fit_inputs_sha256(&arch, &cfg, &t2, &v), base);
        let mut t3 = t.clone();
        t3.y[4] = 2;
        assert_ne!(fit_inputs_sha256(&arch, &cfg, &t3, &v), base);
        assert_ne!(fit_inputs_sha256(&arch, &cfg, &v, &t), base);
    }

    #[test]
    fn smoothing_removes_jitter_keeps_turns_and_wraps_at_pi() {
        use std::f32::consts::PI;
        // A steady heading with one frame of jitter: the spike is spread over its window.
        let h = [0.0, 0.0, 0.5, 0.0, 0.0];
        let s = smooth_headings(&h, 3);
        // Centre: atan2(sin 0.5, 2 + cos 0.5) = 0.1648 (by hand).
        assert!((s[2] - 0.1648).abs() < 1e-3, "{s:?}");
        assert!((s[1] - s[2]).abs() < 1e-6 && s[0] == 0.0 && s[4] == 0.0);
        // A steady turn keeps its rate inside the track (the window is centred).
        let turn: Vec<f32> = (0..9).map(|i| 0.1 * i as f32).collect();
        let st = smooth_headings(&turn, 5);
        for t in 2..7 {
            assert!((st[t] - turn[t]).abs() < 1e-5, "{t}: {}", st[t]);
        }
        // Across ±π the mean is taken on the circle, not over the numbers.
        let w = smooth_headings(&[PI - 0.1, -PI + 0.1, PI - 0.1], 3);
        assert!(w[1].abs() > PI - 0.05, "{w:?}");
        // NaN stays NaN and does not spoil its neighbours; window 1 is the identity.
        let n = smooth_headings(&[0.2, f32::NAN, 0.4], 3);
        assert!(n[1].is_nan() && (n[0] - 0.2).abs() < 1e-6 && (n[2] - 0.4).abs() < 1e-6);
        assert_eq!(smooth_headings(&h, 1), h.to_vec());
        let even = CloneConfig {
            heading_smoothing_frames: 4,
            ..CloneConfig::default()
        };
        assert!(even
            .validate()
            .unwrap_err()
            .to_string()
            .contains("heading_smoothing_frames"));
        let ranged = CloneConfig {
            support_partner_range_cm: f32::INFINITY,
            ..CloneConfig::default()
        };
        assert!(ranged
            .validate()
            .unwrap_err()
            .to_string()
            .contains("clone.support_partner_range_cm"));
        // An ensemble of none or of more networks than a score may evaluate; a calibration on
        // too few views.
        for (cfg, field) in [
            (
                CloneConfig {
                    ensemble_members: 0,
                    ..CloneConfig::default()
                },
                "clone.ensemble_members",
            ),
            (
                CloneConfig {
                    ensemble_members: 17,
                    ..CloneConfig::default()
                },
                "clone.ensemble_members",
            ),
            (
                CloneConfig {
                    ensemble_calibration_views: 5,
                    ..CloneConfig::default()
                },
                "clone.ensemble_calibration_views",
            ),
        ] {
            let e = cfg.validate().unwrap_err().to_string();
            assert!(e.contains(field), "{e}");
        }
    }

    #[test]
    fn marginal_baseline_is_the_entropy_of_the_histogram() {
        let train = PairDataset {
            y: vec![0, 0, 1, 1],
            ..PairDataset::default()
        };
        // Smoothed counts (2.5, 2.5, 0.5 ...) over 4 cells: p(0) = 2.5 / 6.
        let v = marginal_nll(&train, &train, 4);
        assert!((v - -(2.5f64 / 6.0).ln()).abs() < 1e-12, "{v}");
    }

    #[test]
    fn fitting_learns_a_neighbour_dependent_rule() {
        // Synthetic examples: the cell is 0 when the neighbour is ahead, 1 when behind. A
        // network that sees the neighbour learns it; the blind one cannot beat log 2.
        let arch = ConvNetArch {
            bins: 8,
            conv_channels: 2,
            kernel: 3,
            hidden: [8, 8],
            v_bins: 1,
            w_bins: 2,
            ..ConvNetArch::default()
        };
        let mut r = fishprobe_sim::stream(1, "test", 0);
        let mut d = PairDataset::default();
        let tank = Tank::new(&TankParams::default());
        let mut view = vec![0.0; arch.view_len()];
        for _ in 0..2000 {
            let ahead = r.random::<bool>();
            let me = AgentState::at(0.0, 0.0, 0.0);
            let o = AgentState::at(if ahead { 10.0 } else { -10.0 }, 1.0, 0.0);
            encode_view(&arch, &tank, &me, &[o], &mut view);
            d.x.extend_from_slice(&view);
            d.y.push(usize::from(!ahead));
        }
        let cfg = CloneConfig {
            batch_size: 64,
            learning_rate: 0.01,
            max_epochs: 15,
            ..CloneConfig::default()
        };
        let mut rng = rand_xoshiro::Xoshiro256PlusPlus::seed_from_u64(2);
        let mut net = ConvNet::new(arch.clone(), &mut rng);
        let before = nll(&net, &d);
        fit(&mut net, &d, &d, &cfg, &mut r, |_| {}, &|_, _| {}).expect("fits");
        let after = nll(&net, &d);
        assert!(before > 0.6 && after < 0.05, "{before} -> {after}");
        let mut blind_d = d.clone();
        blind(&mut blind_d.x, &arch);
        let mut net2 = ConvNet::new(arch, &mut rng);
        fit(
            &mut net2,
            &blind_d,
            &blind_d,
            &cfg,
            &mut r,
            |_| {},
            &|_, _| {},
        )
        .expect("fits");
        assert!(
            nll(&net2, &blind_d) > 0.65,
            "the blind network cannot see the rule"
        );
    }
}

/// What [`fit_convnet`] reports while it works.
#[derive(Debug, Clone)]
pub enum FitProgress<'a> {
    /// The datasets are loaded.
    Loaded {
        /// Training examples.
        train: &'a PairDataset,
        /// Validation examples.
        validation: &'a PairDataset,
    },
    /// Within an epoch of the network `label`: minibatch `done` of `total`.
    Batch {
        /// "ConvNet" or "no-neighbour baseline".
        label: &'static str,
        /// Minibatches done.
        done: usize,
        /// Minibatches per epoch.
        total: usize,
    },
    /// An epoch of the network `label` ended.
    Epoch {
        /// See `Batch`.
        label: &'static str,
        /// Its log line.
        log: EpochLog,
    },
    /// Resuming: the network `label` is taken from `file`, which an earlier run of the same
    /// data, settings and seed finished.
    Resumed {
        /// See `Batch`.
        label: &'static str,
        /// The weights file.
        file: &'a Path,
    },
    /// Resuming: `file` is there but cannot be taken (`why`), so the network `label` is fitted
    /// again and the file replaced.
    Refit {
        /// See `Batch`.
        label: &'static str,
        /// The weights file.
        file: &'a Path,
        /// Why it cannot be taken.
        why: &'a str,
    },
}

/// Sidecar key: the digest of what a fit saw ([`fit_inputs_sha256`]).
const FIT_INPUTS_KEY: &str = "fit_inputs_sha256";
/// Sidecar key: the digest of the fitted tensors ([`tensors_sha256`]).
const TENSORS_KEY: &str = "tensors_sha256";
/// Sidecar key: the fit's epoch log.
const LOG_KEY: &str = "log";

/// What a fit sees, digested: the training and validation examples as loaded (so the data and
/// every setting that shapes the examples), the architecture and the fit's own settings. The
/// ensemble's size, its calibration and the support's settings do not change a fit and are left
/// out, so a resumed run may ask for more members or another support.
fn fit_inputs_sha256(
    arch: &ConvNetArch,
    cfg: &CloneConfig,
    train: &PairDataset,
    val: &PairDataset,
) -> String {
    use sha2::Digest;
    let mut h = sha2::Sha256::new();
    h.update(b"fishprobe fit-convnet inputs, version 1\n");
    h.update(serde_json::to_vec(arch).unwrap_or_default());
    for n in [cfg.batch_size, cfg.max_epochs, cfg.patience] {
        h.update((n as u64).to_le_bytes());
    }
    h.update(cfg.learning_rate.to_le_bytes());
    let mut buf = Vec::with_capacity(8 * 4096);
    for d in [train, val] {
        h.update((d.len() as u64).to_le_bytes());
        for c in d.x.chunks(4096) {
            buf.clear();
            c.iter()
                .for_each(|v| buf.extend_from_slice(&v.to_le_bytes()));
            h.update(&buf);
        }
        for c in d.y.chunks(4096) {
            buf.clear();
            c.iter()
                .for_each(|&v| buf.extend_from_slice(&(v as u64).to_le_bytes()));
            h.update(&buf);
        }
    }
    h.finalize().iter().map(|b| format!("{b:02x}")).collect()
}

/// The SHA-256 of a network's tensors as a weights file stores them.
fn tensors_sha256(net: &ConvNet) -> Result<String, LearnError> {
    let bytes = fishprobe_nn::store::to_bytes(&net.to_tensors())?;
    Ok(fishprobe_models::sha256_hex(&bytes))
}

/// A fit an earlier run left in `file`, if a resumed run may take it: `None` when there is no
/// file; otherwise the network and its sidecar, or why not (another fit's inputs or seed, a
/// fishprobe that did not record them, or tensors other than the sidecar describes: a write
/// cut short).
fn earlier_fit(
    file: &Path,
    inputs: &str,
    seed: u64,
) -> Option<Result<(ConvNet, serde_json::Value), String>> {
    if !file.exists() {
        return None;
    }
    let found = || -> Result<(ConvNet, serde_json::Value), String> {
        let (t, meta) = fishprobe_nn::store::load(file).map_err(|e| e.to_string())?;
        let text = |k: &str| meta.get(k).and_then(serde_json::Value::as_str);
        if text(FIT_INPUTS_KEY) != Some(inputs) {
            return Err(match text(FIT_INPUTS_KEY) {
                Some(_) => "it was fitted on other data or with other settings".into(),
                None => "its sidecar does not record what it was fitted on".into(),
            });
        }
        if meta.get("seed").and_then(serde_json::Value::as_u64) != Some(seed) {
            return Err("it was fitted with another seed".into());
        }
        let net = ConvNet::from_parts(&t, &meta, &file.display().to_string())
            .map_err(|e| e.to_string())?;
        if text(TENSORS_KEY) != Some(tensors_sha256(&net).map_err(|e| e.to_string())?.as_str()) {
            return Err(
                "its weights are not those its sidecar describes (a write cut short)".into(),
            );
        }
        Ok((net, meta))
    };
    Some(found())
}

/// The validation NLL a sidecar records (of the validation examples its inputs digest covers).
fn recorded_nll(meta: &serde_json::Value) -> Option<f64> {
    meta.get("validation_nll")
        .and_then(serde_json::Value::as_f64)
}

/// The epoch log a sidecar records (empty when it records none).
fn logs_of(meta: &serde_json::Value) -> Vec<EpochLog> {
    meta.get(LOG_KEY)
        .and_then(|l| serde_json::from_value(l.clone()).ok())
        .unwrap_or_default()
}

/// The validation NLL (nats per frame) of existing weights on the pair files under
/// `validation`, their examples made with `cfg` (so two networks can be compared on the same
/// targets, e.g. with and without `heading_smoothing_frames`), and the number of examples.
pub fn score_weights(
    weights: &Path,
    validation: &[PathBuf],
    cfg: &CloneConfig,
) -> Result<(f64, usize), LearnError> {
    cfg.validate()?;
    let net = ConvNet::load(weights).map_err(|e| LearnError::Run(e.to_string()))?;
    let val = load_pairs(validation, &net.arch, cfg)?;
    Ok((nll(&net, &val), val.len()))
}

/// What [`fit_convnet`] produced.
#[derive(Debug, Clone, PartialEq)]
pub struct FitReport {
    /// Validation NLL of the fitted network.
    pub val_nll: f64,
    /// Validation NLL of the training data's marginal histogram.
    pub marginal_nll: f64,
    /// Validation NLL of the network without neighbour channels, when fitted.
    pub no_neighbour_nll: Option<f64>,
    /// Epoch logs of the fitted network.
    pub logs: Vec<EpochLog>,
    /// Files skipped, with the reason.
    pub skipped: Vec<(PathBuf, String)>,
    /// The weights file.
    pub weights: PathBuf,
    /// The support file of the training views beside it (issue 23).
    pub support: PathBuf,
    /// The training log (CSV).
    pub log_file: PathBuf,
    /// The further members of the ensemble (`ensemble_members` > 1), with their validation
    /// NLLs.
    pub members: Vec<(PathBuf, f64)>,
    /// The ensemble's disagreement file, when it has further members.
    pub disagreement: Option<PathBuf>,
}

/// Fits M_ConvNet on the pair files under `data`, stopping early on `validation`, and writes
/// the weights (`out`), their sidecar (architecture, settings, data, NLLs, `command`) and the
/// training log (`out` with extension `training.csv`). Training and validation files must not
/// overlap. With `baselines`, also fits the same network without neighbour channels. With
/// `resume`, each network (the weights, the ensemble's members) that an earlier run of the same
/// data, settings and seed finished beside `out` is taken as it is, and so is the baseline's
/// NLL the weights' sidecar records; the rest is fitted. A resumed run writes what an
/// uninterrupted one writes (the fits are deterministic for their seed).
#[allow(clippy::too_many_arguments)]
pub fn fit_convnet(
    data: &[PathBuf],
    validation: &[PathBuf],
    out: &Path,
    cfg: &CloneConfig,
    seed: u64,
    baselines: bool,
    resume: bool,
    command: &str,
    progress: &(dyn Fn(FitProgress<'_>) + Sync),
) -> Result<FitReport, LearnError> {
    cfg.validate()?;
    let canon = |v: &[PathBuf]| -> Vec<PathBuf> {
        v.iter()
            .map(|p| p.canonicalize().unwrap_or_else(|_| p.clone()))
            .collect()
    };
    let (ct, cv) = (canon(data), canon(validation));
    let mix = |p: &Path| {
        LearnError::Run(format!(
            "{} is both training and validation data; they must not mix",
            p.display()
        ))
    };
    if let Some(p) = ct.iter().find(|p| cv.contains(p)) {
        return Err(mix(p));
    }
    let arch = ConvNetArch::default();
    let train = load_pairs(data, &arch, cfg)?;
    let val = load_pairs(validation, &arch, cfg)?;
    if let Some(f) = train.files.iter().find(|f| val.files.contains(f)) {
        return Err(mix(f));
    }
    progress(FitProgress::Loaded {
        train: &train,
        validation: &val,
    });
    let run =
        |label: &'static str, seed: u64, net: &mut ConvNet, t: &PairDataset, v: &PairDataset| {
            let mut rng = fishprobe_sim::stream(seed, &format!("fit-convnet/{label}/shuffle"), 0);
            let on_batch =
                |done: usize, total: usize| progress(FitProgress::Batch { label, done, total });
            fit(
                net,
                t,
                v,
                cfg,
                &mut rng,
                |log| progress(FitProgress::Epoch { label, log: *log }),
                &on_batch,
            )
        };
    let inputs = fit_inputs_sha256(&arch, cfg, &train, &val);
    let names = |v: &[PathBuf]| -> Vec<String> {
        v.iter()
            .filter_map(|f| f.file_name().map(|n| n.to_string_lossy().into_owned()))
            .collect()
    };
    if let Some(parent) = out.parent().filter(|p| !p.as_os_str().is_empty()) {
        std::fs::create_dir_all(parent)
            .map_err(|e| LearnError::Run(format!("creating {}: {e}", parent.display())))?;
    }
    // A fit an earlier run of the same inputs and seed finished, when resuming.
    let earlier = |label: &'static str, file: &Path, seed: u64| {
        if !resume {
            return None;
        }
        match earlier_fit(file, &inputs, seed)? {
            Ok(found) => {
                progress(FitProgress::Resumed { label, file });
                Some(found)
            }
            Err(why) => {
                progress(FitProgress::Refit {
                    label,
                    file,
                    why: &why,
                });
                None
            }
        }
    };
    let (net, logs, mut meta) = match earlier("ConvNet", out, seed) {
        Some((net, meta)) => {
            let logs = logs_of(&meta);
            (net, logs, meta)
        }
        None => {
            let mut init = fishprobe_sim::stream(seed, "fit-convnet/init", 0);
            let mut net = ConvNet::new(arch.clone(), &mut init);
            let logs = run("ConvNet", seed, &mut net, &train, &val)?;
            let meta = serde_json::json!({
                "arch": arch,
                "clone_config": cfg,
                "seed": seed,
                "command": command,
                "training_files": names(&train.files),
                "validation_files": names(&val.files),
                "training_examples": train.len(),
                "validation_examples": val.len(),
                "validation_nll": nll(&net, &val),
                "baselines": {"no_neighbour_nll": null},
                "epochs": logs.len(),
                "program_version": env!("CARGO_PKG_VERSION"),
                FIT_INPUTS_KEY: inputs,
                TENSORS_KEY: tensors_sha256(&net)?,
                LOG_KEY: logs,
            });
            // Saved before the baseline and the members: a resumed run starts after it.
            fishprobe_nn::store::save(out, &net.to_tensors(), &meta)?;
            (net, logs, meta)
        }
    };
    let val_nll = recorded_nll(&meta).unwrap_or_else(|| nll(&net, &val));
    let marginal = marginal_nll(&train, &val, arch.cells());
    let recorded_baseline = meta
        .pointer("/baselines/no_neighbour_nll")
        .and_then(serde_json::Value::as_f64);
    let no_neighbour = match recorded_baseline {
        Some(b) => Some(b),
        None if baselines => {
            let (mut tb, mut vb) = (train.clone(), val.clone());
            blind(&mut tb.x, &arch);
            blind(&mut vb.x, &arch);
            let mut init = fishprobe_sim::stream(seed, "fit-convnet/init-no-neighbour", 0);
            let mut net_b = ConvNet::new(arch.clone(), &mut init);
            run("no-neighbour baseline", seed, &mut net_b, &tb, &vb)?;
            Some(nll(&net_b, &vb))
        }
        None => None,
    };
    meta["baselines"] = serde_json::json!({
        "marginal_histogram_nll": marginal,
        "no_neighbour_nll": no_neighbour,
    });
    // This run's command, settings and data names (a resumed run's differ from the first
    // only in what does not change a fit: flags, the ensemble's size, the support's settings).
    meta["command"] = command.into();
    meta["clone_config"] = serde_json::json!(cfg);
    meta["training_files"] = names(&train.files).into();
    meta["validation_files"] = names(&val.files).into();
    fishprobe_nn::store::save(out, &net.to_tensors(), &meta)?;
    remove_stale_ensemble(out, cfg.ensemble_members)?;
    let support = support_beside(out);
    let bytes = std::fs::read(out)
        .map_err(|e| LearnError::Run(format!("reading back {}: {e}", out.display())))?;
    let provenance = serde_json::json!({
        "command": command,
        "training_files": names(&train.files),
    });
    let s = build_support(
        &train,
        &arch,
        &SupportConfig {
            partner_range_cm: cfg.support_partner_range_cm,
            ..SupportConfig::default()
        },
        &out.display().to_string(),
        &fishprobe_models::sha256_hex(&bytes),
        seed,
        provenance,
    )?;
    s.save(&support)
        .map_err(fishprobe_models::ModelError::from)?;
    // The ensemble: each further member from its own seed (initialisation and shuffle).
    let mut members = Vec::new();
    let mut nets = vec![net];
    for i in 2..=cfg.ensemble_members {
        let member_seed = fishprobe_sim::derive_seed(seed, "fit-convnet/ensemble-member", i as u64);
        let file = fishprobe_models::disagreement::member_beside(out, i);
        let (m, m_nll) = match earlier("ensemble member", &file, member_seed) {
            Some((m, meta)) => {
                let m_nll = recorded_nll(&meta).unwrap_or_else(|| nll(&m, &val));
                (m, m_nll)
            }
            None => {
                let mut init = fishprobe_sim::stream(member_seed, "fit-convnet/init", 0);
                let mut m = ConvNet::new(arch.clone(), &mut init);
                let m_logs = run("ensemble member", member_seed, &mut m, &train, &val)?;
                let m_nll = nll(&m, &val);
                let m_meta = serde_json::json!({
                    "arch": arch,
                    "ensemble_member_of": out.file_name().map(|n| n.to_string_lossy().into_owned()),
                    "member": i,
                    "seed": member_seed,
                    "command": command,
                    "validation_nll": m_nll,
                    "epochs": m_logs.len(),
                    "program_version": env!("CARGO_PKG_VERSION"),
                    FIT_INPUTS_KEY: inputs,
                    TENSORS_KEY: tensors_sha256(&m)?,
                    LOG_KEY: m_logs,
                });
                fishprobe_nn::store::save(&file, &m.to_tensors(), &m_meta)?;
                (m, m_nll)
            }
        };
        members.push((file, m_nll));
        nets.push(m);
    }
    let disagreement = if members.is_empty() {
        None
    } else {
        let refs = members
            .iter()
            .map(|(f, _)| {
                let bytes = std::fs::read(f)
                    .map_err(|e| LearnError::Run(format!("reading back {}: {e}", f.display())))?;
                Ok(fishprobe_models::disagreement::MemberRef {
                    file: f
                        .file_name()
                        .map(|n| n.to_string_lossy().into_owned())
                        .unwrap_or_default(),
                    sha256: fishprobe_models::sha256_hex(&bytes),
                })
            })
            .collect::<Result<Vec<_>, LearnError>>()?;
        let file = fishprobe_models::disagreement::DisagreementFile::new(
            out.display().to_string(),
            fishprobe_models::sha256_hex(&bytes),
            refs,
            serde_json::json!({
                "command": command,
                "training_files": names(&train.files),
            }),
        );
        let mut rng = fishprobe_sim::stream(seed, "disagreement", 0);
        let d = fishprobe_models::disagreement::Disagreement::fit(
            nets,
            file,
            &train.x,
            cfg.ensemble_calibration_views,
            &mut rng,
        )
        .map_err(fishprobe_models::ModelError::from)?;
        let path = fishprobe_models::disagreement::file_beside(out);
        d.save(&path).map_err(fishprobe_models::ModelError::from)?;
        Some(path)
    };
    let log_file = out.with_extension("training.csv");
    let mut csv = String::from("epoch,train_nll,val_nll,seconds\n");
    for l in &logs {
        csv += &format!(
            "{},{},{},{:.1}\n",
            l.epoch, l.train_nll, l.val_nll, l.seconds
        );
    }
    fishprobe_io::write_atomically(&log_file, csv.as_bytes())?;
    let mut skipped = train.skipped.clone();
    skipped.extend(val.skipped.iter().cloned());
    Ok(FitReport {
        val_nll,
        marginal_nll: marginal,
        no_neighbour_nll: no_neighbour,
        logs,
        skipped,
        weights: out.to_path_buf(),
        support,
        log_file,
        members,
        disagreement,
    })
}

/// Removes what an earlier fit into `out` left of its ensemble that this fit, of `members`
/// members, will not write again: further members beyond `members` (with their sidecars) and
/// the disagreement file (rewritten when `members` > 1). They belonged to the old weights.
fn remove_stale_ensemble(out: &Path, members: usize) -> Result<(), LearnError> {
    use fishprobe_models::disagreement::{file_beside, member_beside, MAX_MEMBERS};
    let stale = (members.max(1) + 1..=MAX_MEMBERS)
        .map(|i| member_beside(out, i))
        .flat_map(|m| [fishprobe_nn::store::sidecar_path(&m), m])
        .chain(std::iter::once(file_beside(out)));
    for f in stale {
        match std::fs::remove_file(&f) {
            Err(e) if e.kind() != std::io::ErrorKind::NotFound => {
                return Err(LearnError::Run(format!(
                    "removing {} (of the ensemble an earlier fit left beside {}): {e}",
                    f.display(),
                    out.display()
                )))
            }
            _ => {}
        }
    }
    Ok(())
}

/// The support file of a weights (or ONNX) file: `FILE.support.json` beside it.
pub fn support_beside(weights: &Path) -> PathBuf {
    let mut s = weights.as_os_str().to_owned();
    s.push(".support.json");
    PathBuf::from(s)
}

/// The support model of a training dataset's views (issue 23), for the model `model` whose
/// weights have SHA-256 `sha256`; seeded by `seed`.
pub fn build_support(
    train: &PairDataset,
    arch: &ConvNetArch,
    cfg: &SupportConfig,
    model: &str,
    sha256: &str,
    seed: u64,
    provenance: serde_json::Value,
) -> Result<SupportModel, LearnError> {
    let mut rng = fishprobe_sim::stream(seed, "support", 0);
    let mut s = SupportModel::fit(arch, &train.x, cfg, model, sha256, &mut rng)
        .map_err(fishprobe_models::ModelError::from)?;
    s.provenance = provenance;
    Ok(s)
}
