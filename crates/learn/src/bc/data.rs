//! The dataset: pair recordings become views and target cells (the module docs of
//! [`crate::bc`] say how).

use super::CloneConfig;
use crate::error::LearnError;
use fishprobe_io::Attr;
use fishprobe_models::convnet::{encode_view, ConvNetArch, CHANNELS};
use fishprobe_sim::{wrap_angle, AgentState, Tank, TankParams};
use rayon::prelude::*;
use std::path::{Path, PathBuf};

/// Examples: views and target cells.
#[derive(Debug, Clone, Default)]
pub struct PairDataset {
    /// Views, `n x view_len`.
    pub x: Vec<f32>,
    /// Target cells.
    pub y: Vec<usize>,
    /// The individual of each example: an index into `individuals`.
    pub ind: Vec<u32>,
    /// The individuals: every learning fish of every file, as `FILE#fish_k`.
    pub individuals: Vec<String>,
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
    let t = fishprobe_io::read_any_trial(path).map_err(|e| e.to_string())?;
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
            d.ind.push(me as u32);
        }
    }
    let stem = path.file_name().map_or_else(
        || path.display().to_string(),
        |n| n.to_string_lossy().into_owned(),
    );
    d.individuals = (0..pairs.len())
        .map(|k| format!("{stem}#fish_{}", k + 1))
        .collect();
    Ok(())
}

/// The recordings `given`, or when none are given the shared data's
/// `guppy-pairs/legacy/SUB` (`sub`: "train" or "validation", the lab's split).
pub fn pairs_or_shared(given: &[PathBuf], sub: &str) -> Result<Vec<PathBuf>, LearnError> {
    if !given.is_empty() {
        return Ok(given.to_vec());
    }
    let d = fishprobe_io::shared_data_dir().ok_or_else(|| {
        LearnError::Run("no recordings given and no shared data found (set FISHPROBE_DATA)".into())
    })?;
    Ok(vec![d.join("guppy-pairs/legacy").join(sub)])
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
                let offset = d.individuals.len() as u32;
                d.x.extend(p.x);
                d.y.extend(p.y);
                d.ind.extend(p.ind.iter().map(|i| i + offset));
                d.individuals.extend(p.individuals);
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

#[cfg(test)]
mod tests {
    use super::*;

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
            (
                CloneConfig {
                    batch_size: 3_000_000_000,
                    ..CloneConfig::default()
                },
                "`clone.batch_size` = 3000000000: must be at most 1048576",
            ),
            (
                CloneConfig {
                    motion_min_step_cm: 1e30,
                    ..CloneConfig::default()
                },
                "`clone.motion_min_step_cm` = 1e30",
            ),
            // The support's bound, before the fit: a range beyond any tank.
            (
                CloneConfig {
                    support_partner_range_cm: 1e30,
                    ..CloneConfig::default()
                },
                "clone.support_partner_range_cm",
            ),
        ] {
            let e = cfg.validate().unwrap_err().to_string();
            assert!(e.contains(field), "{e}");
        }
    }
}
