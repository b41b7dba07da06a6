//! What an episode leaves: its totals, a recorded trajectory, and the start poses it may be given.

use super::*;

/// Totals of the current episode.
#[derive(Debug, Clone, PartialEq, Default, serde::Serialize, serde::Deserialize)]
pub struct EpisodeSummary {
    /// Actions taken.
    pub actions: u32,
    /// Sum of rewards.
    pub episode_return: f32,
    /// Goals reached, with frames.
    pub goal_events: Vec<GoalEvent>,
    /// Frames with the robot clipped at a wall.
    pub robot_wall_contacts: u32,
    /// Frames with a fish clipped at a wall.
    pub fish_wall_contacts: u32,
}

/// A robot command as recorded: the frame at which the action began and the turn applied
/// (after clipping).
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct RecordedCommand {
    /// Frame at which the action began.
    pub frame: u32,
    /// Turn angle (rad).
    pub turn: f32,
}

/// A recorded episode: poses of every agent at every frame (frame 0 = the start).
#[derive(Debug, Clone, PartialEq, Default)]
pub struct Trajectory {
    /// Frame rate (Hz).
    pub frame_rate_hz: f32,
    /// Robot (x, y, heading) per frame.
    pub robot: Vec<[f32; 3]>,
    /// Per fish: (x, y, heading) per frame.
    pub fish: Vec<Vec<[f32; 3]>>,
    /// Active goal centre per frame.
    pub active_goal: Vec<[f32; 2]>,
    /// Robot commands.
    pub commands: Vec<RecordedCommand>,
    /// Per fish: the individual it was this episode (neutral without a population).
    pub individuals: Vec<crate::Individual>,
}

/// Explicit start poses (x, y, heading) instead of random ones, e.g. for the approach assay.
#[derive(Debug, Clone, PartialEq, serde::Serialize)]
pub struct StartPoses {
    /// Robot pose.
    pub robot: [f32; 3],
    /// One pose per fish.
    pub fish: Vec<[f32; 3]>,
}
