//! The Gymnasium contract: spaces, what a step returns, and the [`Env`] trait.

use super::*;

/// A box of real vectors: per-dimension lower and upper bounds.
#[derive(Debug, Clone, PartialEq)]
pub struct BoxSpace {
    /// Lower bounds.
    pub low: Vec<f32>,
    /// Upper bounds.
    pub high: Vec<f32>,
}

impl BoxSpace {
    /// `n` dimensions with the same bounds.
    pub fn uniform(n: usize, low: f32, high: f32) -> Self {
        Self {
            low: vec![low; n],
            high: vec![high; n],
        }
    }

    /// Number of dimensions.
    pub fn dim(&self) -> usize {
        self.low.len()
    }

    /// Whether `x` has the right length and every value is finite and in bounds.
    pub fn contains(&self, x: &[f32]) -> bool {
        x.len() == self.dim()
            && x.iter()
                .zip(self.low.iter().zip(&self.high))
                .all(|(v, (l, h))| v.is_finite() && v >= l && v <= h)
    }
}

/// What happened during one action.
#[derive(Debug, Clone, Copy, PartialEq, Default)]
pub struct StepInfo {
    /// Goals reached during the action's frames.
    pub goals_reached: u32,
    /// Frames in which the robot was clipped at a wall.
    pub robot_wall_contacts: u32,
    /// Frames in which a fish was clipped at a wall (summed over fish).
    pub fish_wall_contacts: u32,
    /// Whether the robot came within the wall-penalty distance.
    pub robot_near_wall: bool,
    /// Frame count since the episode start, at the end of the action.
    pub frame: u32,
    /// With the OOD objective: the mean support score of the fish's views over the action's
    /// frames and fish, before the cap (0 otherwise).
    pub support_score: f32,
}

/// The result of one `step`.
#[derive(Debug, Clone, Copy, PartialEq, Default)]
pub struct Transition {
    /// Reward of the action.
    pub reward: f32,
    /// The episode reached a terminal state (never, in this task).
    pub terminated: bool,
    /// The episode hit its time limit.
    pub truncated: bool,
    /// Details.
    pub info: StepInfo,
}

/// The Gymnasium contract, allocation-free: observations go into caller buffers.
pub trait Env {
    /// Observation bounds.
    fn observation_space(&self) -> &BoxSpace;
    /// Action bounds.
    fn action_space(&self) -> &BoxSpace;
    /// Actions per episode (time limit).
    fn max_episode_steps(&self) -> u32;
    /// Starts an episode. `Some(seed)` re-seeds the environment; `None` continues its stream.
    fn reset(&mut self, seed: Option<u64>, obs: &mut [f32]) -> Result<(), SimError>;
    /// Applies one action. NaN or infinite actions are rejected without touching the state;
    /// finite ones are clipped to the action space.
    fn step(&mut self, action: &[f32], obs: &mut [f32]) -> Result<Transition, SimError>;
}
