//! Whatever drives the robot, one action per second: a trained policy, a scripted baseline, an
//! ONNX or Python policy, on the simulator or on the live bridge. One trait, so that each of
//! them runs everywhere a robot is driven (`evaluate`, `simulate --robot policy:`, the study,
//! the virtual lab, live trials).
//!
//! ```
//! use fishprobe_sim::{stream, AgentState, ControlInput, Controller, GoalSeeker};
//!
//! let mut seeker = GoalSeeker;
//! let obs = vec![0.0; 180];
//! let input = ControlInput {
//!     obs: &obs,
//!     robot: AgentState::at(0.0, 0.0, 0.0),
//!     fish: &[],
//!     goal: [0.0, 20.0],
//! };
//! let turn = seeker.act(&input, &mut stream(0, "doc", 0));
//! assert!((turn - std::f32::consts::FRAC_PI_2).abs() < 1e-6); // the goal is to its left
//! ```
//!
//! Not a controller: the scripted robots of `fishprobe simulate --robot still|circle|goals`
//! ([`crate::RobotScript`]) replace the robot's *body* (they move kinematically, can stand and
//! wait), not its decisions; a controller commands the real robot's turn, as a policy does.

use crate::agent::AgentState;
use crate::geometry::wrap_angle;
use crate::rng::SimRng;

/// What a controller is given each second.
#[derive(Debug, Clone, Copy)]
pub struct ControlInput<'a> {
    /// The observation a policy sees (SPEC §5: 180 floats, relative to the robot).
    pub obs: &'a [f32],
    /// The robot's pose, as the simulator or the tracker knows it. Privileged: a learned
    /// policy must decide from `obs` alone; scripted baselines may use it.
    pub robot: AgentState,
    /// The fish's poses (privileged, as `robot`).
    pub fish: &'a [AgentState],
    /// The active goal's centre (cm; privileged, as `robot`).
    pub goal: [f32; 2],
}

/// Drives the robot: an observation in, a relative turn (rad) out, once per action. fishprobe
/// clips the turn to [-π, π]; a non-finite turn never drives a robot (evaluation stops with an
/// error naming the episode, the live bridge stops the robot).
pub trait Controller: Send + Sync + ControllerClone {
    /// Short name, used in directory names of the study layout (`Zone`, `GoalSeeker`).
    fn name(&self) -> String;
    /// What trial files record as the policy (`Zone (seed 0)`, `scripted:goal-seeker`).
    fn describe(&self) -> String {
        self.name()
    }
    /// Checks that the controller can read observations of `dim` floats.
    fn check_observation(&self, dim: usize) -> Result<(), String> {
        let _ = dim;
        Ok(())
    }
    /// The turn for this second. `rng` is the episode's action stream, for controllers that
    /// sample.
    fn act(&mut self, input: &ControlInput<'_>, rng: &mut SimRng) -> f32;
}

/// A fresh copy of a controller for another episode or thread (implemented for every
/// `Controller + Clone`).
pub trait ControllerClone {
    /// The copy.
    fn boxed_clone(&self) -> Box<dyn Controller>;
}

impl<T: Controller + Clone + 'static> ControllerClone for T {
    fn boxed_clone(&self) -> Box<dyn Controller> {
        Box::new(self.clone())
    }
}

/// The scripted baseline every policy must beat: each second, turn toward the active goal's
/// centre, ignoring the fish. It steers at the goal itself (from the robot's pose), not at the
/// centre of the goal's 10° observation sector: the stronger of the two baselines fishprobe had,
/// and the one its evaluation numbers always used (the live bridge's copy steered by sector).
#[derive(Debug, Clone, Copy, Default, PartialEq, Eq)]
pub struct GoalSeeker;

impl Controller for GoalSeeker {
    fn name(&self) -> String {
        "GoalSeeker".into()
    }

    fn describe(&self) -> String {
        "scripted:goal-seeker".into()
    }

    fn act(&mut self, input: &ControlInput<'_>, _rng: &mut SimRng) -> f32 {
        let (r, g) = (input.robot, input.goal);
        wrap_angle((g[1] - r.y).atan2(g[0] - r.x) - r.heading)
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::rng::stream;

    #[test]
    fn the_goal_seeker_turns_toward_the_goal_from_any_heading() {
        let mut rng = stream(0, "t", 0);
        let mut at = |x, y, h, goal| {
            let input = ControlInput {
                obs: &[],
                robot: AgentState::at(x, y, h),
                fish: &[],
                goal,
            };
            GoalSeeker.act(&input, &mut rng)
        };
        let pi = std::f32::consts::PI;
        assert!((at(0.0, 0.0, 0.0, [10.0, 0.0])).abs() < 1e-6);
        assert!((at(0.0, 0.0, 0.0, [0.0, -10.0]) + pi / 2.0).abs() < 1e-6);
        assert!((at(0.0, 0.0, pi / 2.0, [-10.0, 0.0]) - pi / 2.0).abs() < 1e-6);
        // Behind: the turn is wrapped into [-π, π).
        let back = at(5.0, 5.0, 0.0, [-5.0, 5.0]);
        assert!((back.abs() - pi).abs() < 1e-5, "{back}");
        let copy = GoalSeeker.boxed_clone();
        assert_eq!(copy.describe(), "scripted:goal-seeker");
        assert_eq!(copy.name(), "GoalSeeker");
    }
}
