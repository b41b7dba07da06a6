//! A trial in memory: the robofish.io track (world, rate, entities) and, for fishprobe's own
//! files, the task record of the `/fishprobe` group.

use crate::attr::Attr;
use fishprobe_sim::{wrap_angle, EpisodeSummary, Trajectory};
use serde::{Deserialize, Serialize};
use std::collections::BTreeMap;

/// What an entity is.
#[derive(Debug, Clone, PartialEq, Eq, Serialize)]
pub enum Category {
    /// The robot ("robot").
    Robot,
    /// An animal ("fish", or "organism" in newer writers).
    Fish,
    /// Anything else ("obstacle", ...), kept with its label.
    Other(String),
}

impl Category {
    /// From the `category` attribute.
    pub fn from_label(label: &str) -> Self {
        match label.trim().to_ascii_lowercase().as_str() {
            "robot" => Category::Robot,
            "fish" | "organism" => Category::Fish,
            other => Category::Other(other.to_string()),
        }
    }
}

/// One tracked agent.
#[derive(Debug, Clone, PartialEq)]
pub struct Entity {
    /// Its name under `/entities`.
    pub name: String,
    /// Its category.
    pub category: Category,
    /// The `category` attribute as written.
    pub category_label: String,
    /// Positions (x, y) in cm per frame, centre origin, y up; NaN where untracked.
    pub positions: Vec<[f32; 2]>,
    /// Orientation vectors per frame as stored (live data is not always unit length; use
    /// [`Entity::headings`] or [`Entity::unit_orientations`]); NaN where untracked.
    pub orientations: Vec<[f32; 2]>,
    /// Other attributes (species, sex, interp_frames, ...).
    pub attributes: BTreeMap<String, Attr>,
}

impl Entity {
    /// Number of frames.
    pub fn frames(&self) -> usize {
        self.positions.len()
    }

    /// Headings (rad, in [-π, π)) from the orientation vectors; NaN where the vector is
    /// missing or zero.
    pub fn headings(&self) -> Vec<f32> {
        self.orientations
            .iter()
            .map(|[c, s]| {
                if c.is_finite() && s.is_finite() && (c * c + s * s) > 1e-12 {
                    wrap_angle(s.atan2(*c))
                } else {
                    f32::NAN
                }
            })
            .collect()
    }

    /// Orientation vectors normalised to unit length (NaN where missing or zero).
    pub fn unit_orientations(&self) -> Vec<[f32; 2]> {
        self.headings()
            .into_iter()
            .map(|h| {
                if h.is_nan() {
                    [f32::NAN; 2]
                } else {
                    [h.cos(), h.sin()]
                }
            })
            .collect()
    }

    /// Headings checked against motion: the recorded heading, except where the entity moves at
    /// least `min_step_cm` to the next frame in a direction more than `max_disagreement_rad`
    /// away from it (the tracker confused head and tail) or has no recorded heading: there the
    /// direction of motion. NaN where neither is known. Also returns how many frames took the
    /// direction of motion.
    pub fn headings_checked(
        &self,
        min_step_cm: f32,
        max_disagreement_rad: f32,
    ) -> (Vec<f32>, usize) {
        let recorded = self.headings();
        let mut replaced = 0;
        let out = (0..self.positions.len())
            .map(|t| {
                let p = self.positions[t];
                let motion = self.positions.get(t + 1).and_then(|q| {
                    let (dx, dy) = (q[0] - p[0], q[1] - p[1]);
                    ((dx * dx + dy * dy).sqrt() >= min_step_cm).then(|| dy.atan2(dx))
                });
                match (recorded[t].is_finite(), motion) {
                    (true, Some(m)) if wrap_angle(recorded[t] - m).abs() > max_disagreement_rad => {
                        replaced += 1;
                        m
                    }
                    (true, _) => recorded[t],
                    (false, Some(m)) => {
                        replaced += 1;
                        m
                    }
                    (false, None) => f32::NAN,
                }
            })
            .collect();
        (out, replaced)
    }

    /// Headings from motion: the direction of the displacement to the next frame when it is at
    /// least `min_step_cm` long, else the last such direction (the first ones take the first
    /// available). NaN only when the entity never moves that far. Use it where recorded
    /// orientations are unreliable (e.g. the robot in the robot-fish files).
    pub fn headings_from_motion(&self, min_step_cm: f32) -> Vec<f32> {
        heading_from_motion(&self.positions, min_step_cm)
    }

    /// Fraction of frames whose position is NaN.
    pub fn nan_fraction(&self) -> f32 {
        if self.positions.is_empty() {
            return 0.0;
        }
        let n = self
            .positions
            .iter()
            .filter(|p| !(p[0].is_finite() && p[1].is_finite()))
            .count();
        n as f32 / self.positions.len() as f32
    }

    /// Mean speed (cm/s) over pairs of consecutive tracked frames; `None` if there are none.
    pub fn mean_speed(&self, frame_rate_hz: f32) -> Option<f32> {
        let (mut sum, mut n) = (0.0f64, 0usize);
        for w in self.positions.windows(2) {
            let (a, b) = (w[0], w[1]);
            if a.iter().chain(&b).all(|v| v.is_finite()) {
                sum += f64::from(((b[0] - a[0]).powi(2) + (b[1] - a[1]).powi(2)).sqrt());
                n += 1;
            }
        }
        (n > 0).then(|| (sum / n as f64) as f32 * frame_rate_hz)
    }
}

/// See [`Entity::headings_from_motion`].
pub fn heading_from_motion(positions: &[[f32; 2]], min_step_cm: f32) -> Vec<f32> {
    let mut out = vec![f32::NAN; positions.len()];
    let mut last = f32::NAN;
    for (t, w) in positions.windows(2).enumerate() {
        let (dx, dy) = (w[1][0] - w[0][0], w[1][1] - w[0][1]);
        if dx.is_finite() && dy.is_finite() && (dx * dx + dy * dy).sqrt() >= min_step_cm {
            last = dy.atan2(dx);
        }
        out[t] = last;
    }
    if let Some(l) = out.len().checked_sub(1) {
        out[l] = last;
    }
    // Frames before the first real move take the first known direction.
    if let Some(first) = out.iter().copied().find(|h| h.is_finite()) {
        for h in out.iter_mut().take_while(|h| h.is_nan()) {
            *h = first;
        }
    }
    out
}

/// Where a trial comes from.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Serialize, Deserialize)]
#[serde(rename_all = "snake_case")]
pub enum TrialKind {
    /// Simulated.
    Sim,
    /// The virtual lab (never to be reported as real).
    Virtual,
    /// Live fish.
    Real,
}

impl TrialKind {
    /// As written in files.
    pub fn label(self) -> &'static str {
        match self {
            TrialKind::Sim => "sim",
            TrialKind::Virtual => "virtual",
            TrialKind::Real => "real",
        }
    }

    /// From a file's label.
    pub fn from_label(s: &str) -> Option<Self> {
        match s {
            "sim" => Some(TrialKind::Sim),
            "virtual" => Some(TrialKind::Virtual),
            "real" => Some(TrialKind::Real),
            _ => None,
        }
    }
}

/// The fish entity attribute that holds the individual a fish of a population was drawn as
/// (JSON of `fishprobe_sim::Individual`: its multipliers, pause rate and duration, latent).
pub const INDIVIDUAL_ATTRIBUTE: &str = "fishprobe_individual";

/// The fish entity attribute that holds the id the live tracker gave the fish (the first one,
/// when the tracker changed it; the changes are in the trial's record).
pub const TRACKER_ID_ATTRIBUTE: &str = "tracker_id";

/// The task of a trial: what robofish.io does not hold (SPEC §10), in `/fishprobe`.
#[derive(Debug, Clone, PartialEq)]
pub struct TaskRecord {
    /// Simulated, virtual lab, or live.
    pub kind: TrialKind,
    /// The policy (a name, a directory, or `scripted:<name>`).
    pub policy: String,
    /// The fish model (`live` for real fish).
    pub fish_model: String,
    /// Master seed of the trial (stored as int64 bits).
    pub seed: u64,
    /// Goal radius (cm).
    pub goal_radius_cm: f32,
    /// The goals of the trial, in order of first activation (cm).
    pub goals: Vec<[f32; 2]>,
    /// Index into `goals` of the active goal at the end of each frame (-1: none). A goal
    /// reached in frame t switches it, so at a frame in `goal_frames` this is already the
    /// next goal; the goal reached is the one active at frame t - 1.
    pub active_goal: Vec<i32>,
    /// Frames at which a goal was reached.
    pub goal_frames: Vec<u64>,
    /// Frames at which robot commands began.
    pub command_frames: Vec<u64>,
    /// The commands' turn angles (rad).
    pub command_turns: Vec<f32>,
    /// First frame of closed-loop control (after habituation; 0 in simulation).
    pub control_start_frame: u64,
    /// The resolved configuration, JSON.
    pub config_json: String,
    /// fishprobe's version that wrote the file.
    pub program_version: String,
}

/// One trial file's contents.
#[derive(Debug, Clone, PartialEq)]
pub struct TrialFile {
    /// Tank size (cm).
    pub world_size_cm: [f32; 2],
    /// Frame rate (Hz) of the default sampling.
    pub frame_rate_hz: f32,
    /// The tracked agents.
    pub entities: Vec<Entity>,
    /// Other root attributes (experiment_setup, video, ...).
    pub attributes: BTreeMap<String, Attr>,
    /// The task, for files fishprobe wrote.
    pub task: Option<TaskRecord>,
}

/// What a simulated trial is, besides its trajectory.
#[derive(Debug, Clone, PartialEq)]
pub struct TrialMeta {
    /// Simulated or virtual.
    pub kind: TrialKind,
    /// Policy name.
    pub policy: String,
    /// Fish model name.
    pub fish_model: String,
    /// Seed.
    pub seed: u64,
    /// Goal radius (cm).
    pub goal_radius_cm: f32,
    /// Resolved configuration, JSON.
    pub config_json: String,
    /// Free text for the `experiment_setup` attribute.
    pub experiment_setup: String,
}

impl TrialFile {
    /// The first robot entity.
    pub fn robot(&self) -> Option<&Entity> {
        self.entities.iter().find(|e| e.category == Category::Robot)
    }

    /// The animal entities.
    pub fn fish(&self) -> impl Iterator<Item = &Entity> {
        self.entities
            .iter()
            .filter(|e| e.category == Category::Fish)
    }

    /// The first frame of closed-loop control (0 without fishprobe's task record, and in
    /// simulation): a live trial's frames before it are habituation, not the policy's.
    pub fn control_start(&self) -> usize {
        self.task
            .as_ref()
            .map_or(0, |k| k.control_start_frame as usize)
    }

    /// Duration (s) of the longest entity.
    pub fn duration_s(&self) -> f32 {
        let frames = self.entities.iter().map(Entity::frames).max().unwrap_or(0);
        frames as f32 / self.frame_rate_hz
    }

    /// A trial file from a recorded simulation episode.
    pub fn from_trajectory(
        t: &Trajectory,
        summary: &EpisodeSummary,
        meta: &TrialMeta,
        world_size_cm: [f32; 2],
    ) -> Self {
        let entity = |name: &str, cat: Category, label: &str, poses: &[[f32; 3]]| Entity {
            name: name.to_string(),
            category: cat,
            category_label: label.to_string(),
            positions: poses.iter().map(|p| [p[0], p[1]]).collect(),
            orientations: poses.iter().map(|p| [p[2].cos(), p[2].sin()]).collect(),
            attributes: BTreeMap::new(),
        };
        let mut entities = vec![entity("robot", Category::Robot, "robot", &t.robot)];
        for (i, f) in t.fish.iter().enumerate() {
            let mut e = entity(&format!("fish_{}", i + 1), Category::Fish, "fish", f);
            // A fish drawn from a population: who it was, beside its track.
            if let Some(ind) = t.individuals.get(i).filter(|ind| !ind.is_neutral()) {
                if let Ok(json) = serde_json::to_string(ind) {
                    e.attributes
                        .insert(INDIVIDUAL_ATTRIBUTE.to_string(), Attr::Text(json));
                }
            }
            entities.push(e);
        }
        let mut goals: Vec<[f32; 2]> = Vec::new();
        let active_goal = t
            .active_goal
            .iter()
            .map(|g| match goals.iter().position(|x| x == g) {
                Some(i) => i as i32,
                None => {
                    goals.push(*g);
                    (goals.len() - 1) as i32
                }
            })
            .collect();
        let mut attributes = BTreeMap::new();
        attributes.insert(
            "experiment_setup".to_string(),
            Attr::Text(meta.experiment_setup.clone()),
        );
        TrialFile {
            world_size_cm,
            frame_rate_hz: t.frame_rate_hz,
            entities,
            attributes,
            task: Some(TaskRecord {
                kind: meta.kind,
                policy: meta.policy.clone(),
                fish_model: meta.fish_model.clone(),
                seed: meta.seed,
                goal_radius_cm: meta.goal_radius_cm,
                goals,
                active_goal,
                goal_frames: summary
                    .goal_events
                    .iter()
                    .map(|e| u64::from(e.frame))
                    .collect(),
                command_frames: t.commands.iter().map(|c| u64::from(c.frame)).collect(),
                command_turns: t.commands.iter().map(|c| c.turn).collect(),
                control_start_frame: 0,
                config_json: meta.config_json.clone(),
                program_version: env!("CARGO_PKG_VERSION").to_string(),
            }),
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn heading_from_motion_carries_and_backfills() {
        let p = [
            [0.0, 0.0],
            [0.0, 0.0],
            [1.0, 0.0],
            [1.0, 0.01],
            [1.0, 1.0],
            [1.0, 1.0],
        ];
        let h = heading_from_motion(&p, 0.1);
        // Frame 0 does not move: backfilled with frame 1's direction (+x).
        assert_eq!(h[0], 0.0);
        assert_eq!(h[1], 0.0);
        // Frame 2 moves 0.01 < 0.1: carries +x; frame 3 moves up.
        assert_eq!(h[2], 0.0);
        assert!((h[3] - std::f32::consts::FRAC_PI_2).abs() < 1e-6);
        assert!((h[5] - std::f32::consts::FRAC_PI_2).abs() < 1e-6);
        assert!(heading_from_motion(&[[0.0, 0.0]; 3], 0.1)
            .iter()
            .all(|h| h.is_nan()));
    }

    #[test]
    fn entity_statistics() {
        let e = Entity {
            name: "f".into(),
            category: Category::from_label("Organism"),
            category_label: "organism".into(),
            positions: vec![
                [0.0, 0.0],
                [0.3, 0.4],
                [f32::NAN, f32::NAN],
                [1.0, 1.0],
                [1.3, 1.4],
            ],
            orientations: vec![
                [2.0, 0.0],
                [0.0, 0.0],
                [f32::NAN; 2],
                [0.0, -0.5],
                [1.0, 1.0],
            ],
            attributes: BTreeMap::new(),
        };
        assert_eq!(e.category, Category::Fish);
        assert!((e.nan_fraction() - 0.2).abs() < 1e-6);
        // Two valid steps of 0.5 cm at 25 Hz = 12.5 cm/s.
        assert!((e.mean_speed(25.0).unwrap() - 12.5).abs() < 1e-4);
        let h = e.headings();
        assert_eq!(h[0], 0.0);
        assert!(h[1].is_nan() && h[2].is_nan());
        assert!((h[3] + std::f32::consts::FRAC_PI_2).abs() < 1e-6);
        let u = e.unit_orientations();
        assert!((u[4][0] - std::f32::consts::FRAC_1_SQRT_2).abs() < 1e-6);
        assert_eq!(
            Category::from_label("obstacle"),
            Category::Other("obstacle".into())
        );
    }
}
