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
use crate::observation::ObservationParams;
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
    /// The SHA-256 (hex) of what decides this controller's actions, if it has more than
    /// code: a trained policy's weights, an ONNX file. Trial files record it, so trials of a
    /// policy retrained under the same name are told apart from the old one's. `None` for
    /// scripted controllers (their name says it all).
    fn fingerprint(&self) -> Option<String> {
        None
    }
    /// Checks that the controller can read observations of `dim` floats.
    fn check_observation(&self, dim: usize) -> Result<(), crate::SimError> {
        let _ = dim;
        Ok(())
    }
    /// The observation settings the controller was trained with, where it knows them (a
    /// policy trained by fishprobe records them); `None`: only the length can be checked.
    /// Two opt-in blocks of the same length (`centroid_bins`, `heading_bins`) are told apart
    /// only by these.
    fn trained_observation(&self) -> Option<ObservationParams> {
        None
    }
    /// The frames per action (`frames_per_action`) the controller was trained at, where it
    /// knows them (a policy trained by fishprobe records them); `None`: it is run at the run's.
    /// A policy that learnt to act five times a second is not the same robot once a second.
    fn trained_frames_per_action(&self) -> Option<u32> {
        None
    }
    /// The simulator's frame rate (`frame_rate_hz`) the controller was trained at, where it
    /// records one (policies trained by fishprobe since it recorded the rate); `None`: it is
    /// run at the run's. With `trained_frames_per_action` it fixes how often the robot acts:
    /// 25 frames at 50 Hz are half a second, not one.
    fn trained_frame_rate_hz(&self) -> Option<f32> {
        None
    }
    /// The turn for this second. `rng` is the episode's action stream, for controllers that
    /// sample.
    fn act(&mut self, input: &ControlInput<'_>, rng: &mut SimRng) -> f32;
}

/// Checks that `c` reads the observation `obs` encodes: its length, and the opt-in blocks where
/// `c` knows what it was trained with (a 216-float policy trained with the fish's headings must
/// not be given the group's centroid).
pub fn check_controller_observation(
    c: &dyn Controller,
    obs: &ObservationParams,
) -> Result<(), crate::SimError> {
    match c.trained_observation() {
        Some(t) if (t.centroid_bins, t.heading_bins) != (obs.centroid_bins, obs.heading_bins) => {
            Err(crate::SimError::Controller(format!(
                "{} was trained with observation.centroid_bins = {} and heading_bins = {} \
                 ({} floats); it is given centroid_bins = {} and heading_bins = {} ({} floats): \
                 run it with the observation settings it was trained with",
                c.describe(),
                t.centroid_bins,
                t.heading_bins,
                t.size(),
                obs.centroid_bins,
                obs.heading_bins,
                obs.size()
            )))
        }
        Some(t) if t.previous_block_actions != obs.previous_block_actions => {
            Err(crate::SimError::Controller(format!(
                "{} was trained with observation.previous_block_actions = {} (its motion blocks \
             look back {} actions); it is given {}: run it with the observation settings it \
             was trained with",
                c.describe(),
                t.previous_block_actions,
                t.previous_block_actions,
                obs.previous_block_actions
            )))
        }
        _ => c.check_observation(obs.size()),
    }
}

/// What `c` observes in a run whose policy observes `run`: the settings `c` was trained with
/// where it records them, else `run` without the fish's headings and with SPEC §5's previous
/// step (a controller that records nothing, an ONNX or Python policy or one trained before
/// fishprobe recorded its settings, cannot have been trained with that block or that look
/// back). A lead-to-goal yardstick or comparison policy of an OOD run that observes headings,
/// or looks back further, is run as it was trained.
pub fn controller_observation(c: &dyn Controller, run: &ObservationParams) -> ObservationParams {
    c.trained_observation()
        .unwrap_or_else(|| ObservationParams {
            heading_bins: false,
            previous_block_actions: 1,
            ..run.clone()
        })
}

/// Checks that `c` is run at the action rate it was trained at, where it records one: the same
/// frames per action at the same frame rate.
pub fn check_controller_rate(
    c: &dyn Controller,
    run: &crate::EnvConfig,
) -> Result<(), crate::SimError> {
    let frames_per_action = run.frames_per_action;
    match (c.trained_frames_per_action(), c.trained_frame_rate_hz()) {
        (Some(t), _) if t != frames_per_action => Err(crate::SimError::Controller(format!(
            "{} was trained to act every {t} frames (frames_per_action = {t}); it is run every \
             {frames_per_action}: run it at the rate it was trained at",
            c.describe()
        ))),
        (_, Some(hz)) if hz != run.frame_rate_hz => Err(crate::SimError::Controller(format!(
            "{} was trained at frame_rate_hz = {}; it is run at {}: run it at the frame rate \
             it was trained at",
            c.describe(),
            crate::params::check::shown(hz),
            crate::params::check::shown(run.frame_rate_hz)
        ))),
        _ => Ok(()),
    }
}

/// How many times a second `c` acts where it records its rate: its frame rate (the run's
/// `default_hz` for a policy that records only its frames per action) over its frames per
/// action; `None` for a controller that records neither.
pub fn controller_actions_per_second(c: &dyn Controller, default_hz: f32) -> Option<f64> {
    let frames = c.trained_frames_per_action()?;
    let hz = c.trained_frame_rate_hz().unwrap_or(default_hz);
    Some(f64::from(hz) / f64::from(frames))
}

/// The settings under which `c` runs in a run of settings `run`: its own observation
/// ([`controller_observation`]) and its own action rate (frames per action and frame rate)
/// where it records one. A lead-to-goal yardstick or comparison policy of an OOD run that
/// observes headings, or acts five times a second, is run as it was trained.
pub fn controller_env(c: &dyn Controller, run: &crate::EnvConfig) -> crate::EnvConfig {
    crate::EnvConfig {
        observation: controller_observation(c, &run.observation),
        frames_per_action: c
            .trained_frames_per_action()
            .unwrap_or(run.frames_per_action),
        frame_rate_hz: c.trained_frame_rate_hz().unwrap_or(run.frame_rate_hz),
        ..run.clone()
    }
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

crate::documented_params! {
    /// The fetch-and-lead baseline's settings: go to the fish, then keep ahead of it on its
    /// line to the goal, so that a fish that follows the robot is led there.
    pub struct FetchParams {
        /// Beyond this robot-fish distance the robot goes to fetch the fish (choice: 25 cm,
        /// about where M_Zone's and M_Force's attraction fades).
        pub fetch_radius_cm: f32 = 25.0; "cm",
        /// Within it, the robot heads for the point this far ahead of the fish on the fish's
        /// line to the goal (choice: 15 cm, the middle of the 10-20 cm that led M_Zone and
        /// M_Force best in a scan).
        pub lead_distance_cm: f32 = 15.0; "cm",
    }
}

impl FetchParams {
    /// Checks both distances.
    pub fn validate(&self, prefix: &str) -> Result<(), crate::params::ConfigError> {
        use crate::params::check;
        check::positive_at_most(
            prefix,
            "fetch_radius_cm",
            self.fetch_radius_cm,
            check::MAX_LENGTH_CM,
        )?;
        check::positive_at_most(
            prefix,
            "lead_distance_cm",
            self.lead_distance_cm,
            check::MAX_LENGTH_CM,
        )
    }
}

/// The scripted baseline that leads: each second, if the fish (the centroid of the fish) is
/// farther than `fetch_radius_cm`, turn toward it; otherwise turn toward the point
/// `lead_distance_cm` ahead of it on its line to the active goal. A probe policy that leads its
/// model's fish worse than this has not found what its model allows.
#[derive(Debug, Clone, Default, PartialEq)]
pub struct FetchAndLead {
    /// Its settings.
    pub params: FetchParams,
}

impl Controller for FetchAndLead {
    fn name(&self) -> String {
        "FetchAndLead".into()
    }

    fn describe(&self) -> String {
        "scripted:fetch-and-lead".into()
    }

    fn act(&mut self, input: &ControlInput<'_>, _rng: &mut SimRng) -> f32 {
        let r = input.robot;
        let n = input.fish.len();
        if n == 0 {
            return GoalSeeker.act(input, _rng);
        }
        let (fx, fy) = input
            .fish
            .iter()
            .fold((0.0, 0.0), |(x, y), f| (x + f.x, y + f.y));
        let (fx, fy) = (fx / n as f32, fy / n as f32);
        let p = &self.params;
        let (tx, ty) = if (fx - r.x).hypot(fy - r.y) > p.fetch_radius_cm {
            (fx, fy)
        } else {
            let (gx, gy) = (input.goal[0] - fx, input.goal[1] - fy);
            let d = gx.hypot(gy).max(1e-6);
            (
                fx + p.lead_distance_cm * gx / d,
                fy + p.lead_distance_cm * gy / d,
            )
        };
        wrap_angle((ty - r.y).atan2(tx - r.x) - r.heading)
    }
}

/// A robot that neither seeks the goal nor the fish: each second it turns by an angle drawn
/// uniformly from [-π, π] (the episode's action stream), the random robot of `fishprobe models
/// --measure`. Not a baseline a policy must beat: a probe whose situations no policy chose
/// (`ood-loop`'s gap probes), and a floor for what a robot does by chance.
#[derive(Debug, Clone, Copy, Default, PartialEq, Eq)]
pub struct RandomTurns;

impl Controller for RandomTurns {
    fn name(&self) -> String {
        "RandomTurns".into()
    }

    fn describe(&self) -> String {
        "scripted:random".into()
    }

    fn act(&mut self, _input: &ControlInput<'_>, rng: &mut SimRng) -> f32 {
        use rand::RngExt;
        rng.random_range(-std::f32::consts::PI..=std::f32::consts::PI)
    }
}

/// The scripted controllers every study runs as baselines, by their `scripted:` names.
pub const SCRIPTED: [&str; 2] = ["goal-seeker", "fetch-and-lead"];

/// Every scripted controller by its `scripted:` name: the baselines and the random robot.
pub const SCRIPTED_ALL: [&str; 3] = ["goal-seeker", "fetch-and-lead", "random"];

/// A scripted controller by its name after `scripted:` (`goal-seeker`, `fetch-and-lead`,
/// `random`).
pub fn scripted(name: &str) -> Option<Box<dyn Controller>> {
    match name {
        "goal-seeker" => Some(Box::new(GoalSeeker)),
        "fetch-and-lead" => Some(Box::new(FetchAndLead::default())),
        "random" => Some(Box::new(RandomTurns)),
        _ => None,
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::rng::stream;

    #[test]
    fn fetch_and_lead_fetches_a_far_fish_then_leads_it_toward_the_goal() {
        let mut rng = stream(0, "t", 0);
        let mut c = FetchAndLead::default();
        let pi = std::f32::consts::PI;
        let fish = [AgentState::at(0.0, 40.0, 0.0)];
        // Far (40 cm): straight at the fish, which is to the robot's left.
        let input = ControlInput {
            obs: &[],
            robot: AgentState::at(0.0, 0.0, 0.0),
            fish: &fish,
            goal: [30.0, 40.0],
        };
        assert!((c.act(&input, &mut rng) - pi / 2.0).abs() < 1e-6);
        // Near (10 cm): toward the point 15 cm beyond the fish on its line to the goal,
        // (15, 40) from the robot at (0, 25): 45° to the left.
        let input = ControlInput {
            robot: AgentState::at(0.0, 25.0, 0.0),
            ..input
        };
        assert!((c.act(&input, &mut rng) - pi / 4.0).abs() < 1e-5);
        // Without fish it seeks the goal; its names are the scripted ones.
        let alone = ControlInput { fish: &[], ..input };
        assert_eq!(c.act(&alone, &mut rng), GoalSeeker.act(&alone, &mut rng));
        assert_eq!(c.describe(), "scripted:fetch-and-lead");
        for name in SCRIPTED_ALL {
            assert_eq!(
                scripted(name).unwrap().describe(),
                format!("scripted:{name}")
            );
        }
        assert!(scripted("dance").is_none());
        let bad = FetchParams {
            lead_distance_cm: 0.0,
            ..FetchParams::default()
        };
        assert!(bad
            .validate("fetch")
            .unwrap_err()
            .to_string()
            .contains("lead_distance_cm"));
    }

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

    #[test]
    fn the_random_robot_turns_uniformly_and_reproducibly() {
        let input = ControlInput {
            obs: &[],
            robot: AgentState::at(0.0, 0.0, 0.0),
            fish: &[],
            goal: [20.0, 20.0],
        };
        let draw = |seed| {
            let mut rng = stream(seed, "t", 0);
            (0..4000)
                .map(|_| RandomTurns.act(&input, &mut rng))
                .collect::<Vec<_>>()
        };
        let a = draw(1);
        assert_eq!(a, draw(1), "same stream, same turns");
        assert_ne!(a, draw(2));
        let pi = std::f32::consts::PI;
        assert!(a.iter().all(|t| (-pi..=pi).contains(t)));
        // Uniform on [-π, π]: mean 0 (s.e. π/√3/√4000 ≈ 0.029), a quarter in each quarter.
        let mean = a.iter().sum::<f32>() / a.len() as f32;
        assert!(mean.abs() < 0.1, "{mean}");
        let left_half = a.iter().filter(|t| **t > pi / 2.0).count() as f32 / a.len() as f32;
        assert!((left_half - 0.25).abs() < 0.03, "{left_half}");
        assert!(!SCRIPTED.contains(&"random"), "not a baseline");
    }
}
