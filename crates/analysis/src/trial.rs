//! One trial's numbers: goal events, time to goal, goals per minute, and the nine per-frame
//! metrics of SPEC §8 over the control phase.
//!
//! A trial with a group of fish gives the nine pair metrics of every fish with the
//! robot, pooled (so "per fish" distributions), plus the six group metrics of
//! [`GROUP_METRICS`] per frame; a fish not tracked in a frame is left out of that frame's
//! values (and a frame with fewer than two tracked fish has no group values).
//!
//! Goal events come from the file's `/fishprobe` group when present; otherwise they are
//! recomputed from the fish track and the evaluation task (first goal active at the start of
//! control, a goal reached when the fish is inside its radius, the next one active from that
//! frame). Files at other frame rates (the 20 Hz robot-fish recordings) are analysed at their
//! own rate: differences are multiplied by the file's rate, so speeds and turn rates keep
//! their units, and goals per minute are binned in seconds.

use crate::config::AnalysisConfig;
use fishprobe_io::{read_trial, Entity, TrialFile, TrialKind};
use std::path::{Path, PathBuf};

use crate::metric::{Compute, GroupFrame, PairFrame, METRIC_TABLE};
pub use crate::metric::{ALL_METRICS, GROUP_METRICS, METRICS};

/// Trials by file, as the analysis loads them once for all its comparisons; a failed load
/// carries the reason.
pub(crate) type Loaded = std::collections::HashMap<PathBuf, Result<TrialData, String>>;

/// What the analysis needs of one trial.
#[derive(Debug, Clone, PartialEq)]
pub struct TrialData {
    /// The file.
    pub path: PathBuf,
    /// Kind recorded in the file, if any.
    pub kind: Option<TrialKind>,
    /// Policy recorded in the file, if any.
    pub policy: Option<String>,
    /// SHA-256 of the weights that drove the robot, if recorded
    /// (`fishprobe_io::TaskRecord::policy_sha256`).
    pub policy_sha256: Option<String>,
    /// Goals reached during control.
    pub goals_reached: u32,
    /// Mean time from a goal becoming active to reaching it (s); `None` without goals.
    pub time_to_goal_s: Option<f64>,
    /// Goals per minute of control: one bin per complete minute of control the trial has, at
    /// most `AnalysisConfig::minutes` (a shorter trial is not padded with empty minutes).
    pub goals_per_minute: Vec<u32>,
    /// The metrics' per-frame values (finite, sorted ascending), when requested: the nine of
    /// [`METRICS`] (pooled over the fish of a group), then for a group the six of
    /// [`GROUP_METRICS`] ([`ALL_METRICS`] names them all).
    pub metrics: Option<Vec<Vec<f64>>>,
    /// Seconds of control until a fish first came within `AnalysisConfig::robot_reach_cm` of
    /// the robot (0 when one starts there); `None` when none ever did. How fast a probe gets to
    /// its fish: a policy that waits at the goal for the fish to come by reaches it no sooner
    /// than the scripted goal-seeker, one that fetches it as soon as fetch-and-lead.
    pub time_to_reach_s: Option<f64>,
    /// Fish in the trial.
    pub fish: usize,
    /// In a group trial, fish-frames of control in which a fish was untracked (left out of
    /// that frame's metrics); 0 for a pair.
    pub untracked_fish_frames: usize,
    /// What protocol the trial was recorded under, to tell a mixed reality arm.
    pub protocol: TrialProtocol,
}

/// The recording conditions of a trial: what must agree across the trials of one arm.
#[derive(Debug, Clone, PartialEq, Default)]
pub struct TrialProtocol {
    /// Frames per second.
    pub frame_rate_hz: f32,
    /// The tank (cm).
    pub world_size_cm: [f32; 2],
    /// Whether the file records fishprobe's task (goals, policy); a foreign recording does
    /// not, and its goals are recomputed.
    pub has_task: bool,
    /// The file's `experiment_setup` attribute, if any.
    pub setup: Option<String>,
    /// Seconds of control the trial holds.
    pub control_s: f64,
}

#[cfg(test)]
impl TrialData {
    /// A trial of `fish` fish with nothing in it, for tests to fill in.
    pub(crate) fn blank(path: &str, fish: usize) -> Self {
        Self {
            path: path.into(),
            kind: None,
            policy: None,
            policy_sha256: None,
            goals_reached: 0,
            time_to_goal_s: None,
            goals_per_minute: Vec::new(),
            metrics: None,
            time_to_reach_s: None,
            fish,
            untracked_fish_frames: 0,
            protocol: TrialProtocol::default(),
        }
    }
}

/// Robot and fish of a trial, checked: every entity must be tracked in some frame.
fn agents(t: &TrialFile) -> Result<(&Entity, Vec<&Entity>), String> {
    let robot = t.robot().ok_or("trial without a robot entity")?;
    let fish: Vec<&Entity> = t.fish().collect();
    if fish.is_empty() {
        return Err("trial without a fish entity".into());
    }
    for f in &fish {
        if f.positions
            .iter()
            .all(|p| !(p[0].is_finite() && p[1].is_finite()))
        {
            return Err(format!("fish track `{}` is all NaN", f.name));
        }
    }
    if robot
        .positions
        .iter()
        .all(|p| !(p[0].is_finite() && p[1].is_finite()))
    {
        return Err(format!("robot track `{}` is all NaN", robot.name));
    }
    Ok((robot, fish))
}

/// The goal active during each frame and the frames at which goals were reached (both from
/// `control_start` on).
fn goal_timeline(
    t: &TrialFile,
    fish: &[&Entity],
    control_start: usize,
    frames: usize,
    cfg: &AnalysisConfig,
) -> (Vec<[f32; 2]>, Vec<usize>) {
    if let Some(task) = &t.task {
        if !task.goals.is_empty() && task.active_goal.len() >= frames.min(1) {
            let goal_at = |i: usize| -> [f32; 2] {
                let idx = task.active_goal.get(i).copied().unwrap_or(-1);
                usize::try_from(idx)
                    .ok()
                    .and_then(|k| task.goals.get(k).copied())
                    .unwrap_or(task.goals[0])
            };
            // active_goal[t] is the goal at the end of frame t; during frame t it is t - 1's.
            let active = (0..frames).map(|i| goal_at(i.saturating_sub(1))).collect();
            let events = task
                .goal_frames
                .iter()
                .filter_map(|&f| usize::try_from(f).ok())
                .filter(|&f| f >= control_start && f < frames)
                .collect();
            return (active, events);
        }
    }
    let radius = t
        .task
        .as_ref()
        .map_or(cfg.goal_radius_cm, |k| k.goal_radius_cm);
    let r2 = radius * radius;
    let mut k = 0usize;
    let mut active = vec![cfg.goals[0]; frames];
    let mut events = Vec::new();
    for (i, slot) in active.iter_mut().enumerate().skip(control_start) {
        let g = cfg.goals[k % cfg.goals.len()];
        *slot = g;
        // Without a recorded task a group reaches a goal when any fish does (the default of
        // `task.group_goal`); a recorded task's goal frames say what its setting counted.
        let inside = |f: &&Entity| {
            let p = f.positions[i];
            (p[0] - g[0]).powi(2) + (p[1] - g[1]).powi(2) < r2
        };
        if fish.iter().any(inside) {
            events.push(i);
            k += 1;
        }
    }
    (active, events)
}

/// Loads a trial and computes its numbers (`with_metrics`: also the per-frame metrics).
pub fn load_trial(
    path: &Path,
    cfg: &AnalysisConfig,
    with_metrics: bool,
) -> Result<TrialData, crate::AnalysisError> {
    let t = read_trial(path)?;
    let (robot, fish) = agents(&t).map_err(crate::AnalysisError::Data)?;
    let frames = fish
        .iter()
        .map(|f| f.frames())
        .fold(robot.frames(), usize::min);
    let rate = f64::from(t.frame_rate_hz);
    let control_start = t.control_start().min(frames);
    let (active, events) = goal_timeline(&t, &fish, control_start, frames, cfg);

    let control_minutes = ((frames - control_start) as f64 / rate / 60.0 + 1e-9).floor() as usize;
    let mut goals_per_minute = vec![0u32; cfg.minutes.min(control_minutes)];
    let mut waits = Vec::with_capacity(events.len());
    let mut activated = control_start;
    for &e in &events {
        let minute = ((e - control_start) as f64 / rate / 60.0) as usize;
        if let Some(b) = goals_per_minute.get_mut(minute) {
            *b += 1;
        }
        waits.push((e - activated) as f64 / rate);
        activated = e;
    }
    let untracked_fish_frames = if fish.len() >= 2 {
        fish.iter()
            .map(|f| {
                f.positions[control_start..frames]
                    .iter()
                    .filter(|p| !(p[0].is_finite() && p[1].is_finite()))
                    .count()
            })
            .sum()
    } else {
        0
    };
    let reach2 = f64::from(cfg.robot_reach_cm).powi(2);
    let time_to_reach_s = (control_start..frames)
        .find(|&i| {
            let r = robot.positions[i];
            fish.iter().any(|f| {
                let p = f.positions[i];
                let d2 = f64::from(p[0] - r[0]).powi(2) + f64::from(p[1] - r[1]).powi(2);
                d2 <= reach2 // NaN (untracked) compares false
            })
        })
        .map(|i| (i - control_start) as f64 / rate);
    let metrics = with_metrics.then(|| {
        // Each fish's headings once, for the pair and the group metrics.
        let hf: Vec<Vec<f32>> = fish.iter().map(|f| headings(f)).collect();
        let mut m = per_frame_metrics(&t, robot, &fish, &hf, &active, control_start, frames);
        if fish.len() >= 2 {
            m.extend(group_metrics(robot, &fish, &hf, control_start, frames, cfg));
        }
        m
    });
    Ok(TrialData {
        path: path.to_path_buf(),
        kind: t.task.as_ref().map(|k| k.kind),
        policy: t.task.as_ref().map(|k| k.policy.clone()),
        policy_sha256: t.task.as_ref().and_then(|k| k.policy_sha256()),
        goals_reached: events.len() as u32,
        time_to_goal_s: (!waits.is_empty()).then(|| waits.iter().sum::<f64>() / waits.len() as f64),
        goals_per_minute,
        metrics,
        time_to_reach_s,
        fish: fish.len(),
        untracked_fish_frames,
        protocol: TrialProtocol {
            frame_rate_hz: t.frame_rate_hz,
            world_size_cm: t.world_size_cm,
            has_task: t.task.is_some(),
            setup: match t.attributes.get("experiment_setup") {
                Some(fishprobe_io::Attr::Text(s)) => Some(s.clone()),
                _ => None,
            },
            control_s: (frames - control_start) as f64 / rate,
        },
    })
}

/// Recorded headings, falling back to heading from motion for an entity whose orientations
/// are all missing.
fn headings(e: &Entity) -> Vec<f32> {
    let h = e.headings();
    if h.iter().all(|v| v.is_nan()) {
        e.headings_from_motion(0.1)
    } else {
        h
    }
}

fn per_frame_metrics(
    t: &TrialFile,
    robot: &Entity,
    fish: &[&Entity],
    fish_headings: &[Vec<f32>],
    active: &[[f32; 2]],
    start: usize,
    frames: usize,
) -> Vec<Vec<f64>> {
    let rate = f64::from(t.frame_rate_hz);
    let (hx, hy) = (
        f64::from(t.world_size_cm[0]) / 2.0,
        f64::from(t.world_size_cm[1]) / 2.0,
    );
    let hr = headings(robot);
    let p = |e: &Entity, i: usize| [f64::from(e.positions[i][0]), f64::from(e.positions[i][1])];
    let n = frames.saturating_sub(start) * fish.len();
    let pair: Vec<fn(&PairFrame) -> Option<f64>> = METRIC_TABLE
        .iter()
        .filter_map(|m| match m.compute {
            Compute::Pair(f) => Some(f),
            Compute::Group(_) => None,
        })
        .collect();
    let mut m: Vec<Vec<f64>> = pair.iter().map(|_| Vec::with_capacity(n)).collect();
    for (&fish, hf) in fish.iter().zip(fish_headings) {
        for i in start..frames {
            let frame = PairFrame {
                robot: p(robot, i),
                fish: p(fish, i),
                robot_heading: f64::from(hr[i]),
                fish_heading: hf[i],
                next: (i + 1 < frames).then(|| (p(robot, i + 1), p(fish, i + 1), hf[i + 1])),
                goal: active[i],
                half: [hx, hy],
                rate,
            };
            for (values, compute) in m.iter_mut().zip(&pair) {
                if let Some(v) = compute(&frame) {
                    values.push(v);
                }
            }
        }
    }
    for v in &mut m {
        v.retain(|x| x.is_finite());
        v.sort_unstable_by(f64::total_cmp);
    }
    m
}

/// The six group metrics per frame of a group trial (sorted, finite): frames with fewer than
/// two tracked fish have none; an untracked fish is left out of its frame.
fn group_metrics(
    robot: &Entity,
    fish: &[&Entity],
    headings: &[Vec<f32>],
    start: usize,
    frames: usize,
    cfg: &AnalysisConfig,
) -> Vec<Vec<f64>> {
    use fishprobe_sim::{group_order, robot_to_group, AgentState};
    let group: Vec<fn(&GroupFrame) -> Option<f64>> = METRIC_TABLE
        .iter()
        .filter_map(|m| match m.compute {
            Compute::Group(f) => Some(f),
            Compute::Pair(_) => None,
        })
        .collect();
    let mut m: Vec<Vec<f64>> = group
        .iter()
        .map(|_| Vec::with_capacity(frames.saturating_sub(start)))
        .collect();
    let mut now = vec![AgentState::default(); fish.len()];
    for i in start..frames {
        for ((a, f), h) in now.iter_mut().zip(fish).zip(headings) {
            let [x, y] = f.positions[i];
            *a = AgentState::at(x, y, h[i]);
        }
        if let Some(order) = group_order(&now) {
            let [x, y] = robot.positions[i];
            let frame = GroupFrame {
                order,
                robot: robot_to_group(&AgentState::at(x, y, 0.0), &now, cfg.robot_reach_cm),
            };
            for (values, compute) in m.iter_mut().zip(&group) {
                if let Some(v) = compute(&frame) {
                    values.push(v);
                }
            }
        }
    }
    for v in &mut m {
        v.retain(|x| x.is_finite());
        v.sort_unstable_by(f64::total_cmp);
    }
    m
}
