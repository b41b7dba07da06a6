//! What a trial is made of, whatever the tracker and the wire: the poses of one tracked frame
//! in, the robot's command out. A tracker source turns its own messages into [`Frame`]s; the
//! live protocol (`protocol.rs`) and the robot sink carry [`Command`]s as JSON of the same
//! shape.

use serde::{Deserialize, Serialize};

/// A pose as the tracker reports it (cm, rad); absent or `null` when lost.
#[derive(Debug, Clone, Copy, PartialEq, Serialize, Deserialize)]
pub struct Pose {
    /// x (cm, tank centre origin, x right).
    pub x: f32,
    /// y (cm, y up).
    pub y: f32,
    /// Heading (rad, counter-clockwise from +x).
    pub heading: f32,
}

impl Pose {
    /// All three values finite and inside a 100 x 100 cm tank (with 5 cm of slack).
    pub fn is_valid(&self) -> bool {
        self.x.is_finite()
            && self.y.is_finite()
            && self.heading.is_finite()
            && self.x.abs() <= 55.0
            && self.y.abs() <= 55.0
    }
}

/// A tracked fish: the tracker's id and its pose (`None` when lost).
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
pub struct FishPose {
    /// The tracker's id of the fish (see `fish_ids` for how ids are matched).
    pub id: String,
    /// Its pose, or `null` when lost.
    #[serde(flatten)]
    pub pose: Option<Pose>,
}

/// One tracked frame.
#[derive(Debug, Clone, PartialEq)]
pub struct Frame {
    /// Tracking time stamp (s, increasing within a trial).
    pub t: f64,
    /// The robot, `None` when lost.
    pub robot: Option<Pose>,
    /// The fish, in any order.
    pub fish: Vec<FishPose>,
}

/// Trial phases.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Serialize, Deserialize)]
#[serde(rename_all = "snake_case")]
pub enum Phase {
    /// Robot mills in the centre; the fish is released after `release_s`.
    Habituation,
    /// The policy leads.
    Control,
    /// The trial is over.
    Done,
}

/// What the robot should do now. Scheduled commands (`seq` = the second of the trial) come
/// once per 1 / command_hz of tracking time; unscheduled ones (`seq` none) stop the robot at
/// once.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
pub struct Command {
    /// Tracking time of the frame that triggered it.
    pub t: f64,
    /// Schedule index, or none for an immediate stop.
    pub seq: Option<u64>,
    /// Relative turn (rad) to execute within the next second.
    pub turn: f32,
    /// Stop the robot (tracking lost or input malformed) and hold still.
    pub stop: bool,
    /// Why it stops.
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub reason: Option<String>,
    /// Current phase.
    pub phase: Phase,
    /// Whether the fish has been released.
    pub released: bool,
    /// The active goal during control.
    pub active_goal: Option<[f32; 2]>,
    /// Goals reached so far.
    pub goals_reached: u32,
}

impl Command {
    /// A stop outside a trial's schedule (before a trial, at its end, on a refusal): the robot
    /// holds still, and `reason` says why.
    pub fn stop_outside_trial(t: f64, reason: &str, goals_reached: u32) -> Self {
        Command {
            t,
            seq: None,
            turn: 0.0,
            stop: true,
            reason: Some(reason.to_string()),
            phase: Phase::Done,
            released: false,
            active_goal: None,
            goals_reached,
        }
    }
}
