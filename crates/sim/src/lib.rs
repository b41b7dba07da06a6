//! The RoboFish tank, simulated: a 100 x 100 cm tank at 25 Hz with a robot fish whose
//! low-level controller executes one turn command per second, fish driven by a
//! [`FishModel`], the lead-to-goal task, and the policy's 180-float observation
//! (Hocke et al. 2026; see `SPEC.md` §2-§5).
//!
//! ```
//! use fishprobe_sim::{EnvConfig, Env, TankEnv, FishModel, FishView, FishMind, FishMotion, SimRng};
//! use std::sync::Arc;
//!
//! /// A fish that swims straight at 5 cm/s.
//! #[derive(Debug)]
//! struct Straight;
//! impl FishModel for Straight {
//!     fn name(&self) -> &str { "Straight" }
//!     fn decide(&self, v: &FishView, _: &[f32], _: &mut FishMind, _: &mut SimRng) -> FishMotion {
//!         FishMotion { heading: v.me.heading, speed: 5.0 }
//!     }
//! }
//!
//! let mut env = TankEnv::new(EnvConfig::default(), Arc::new(Straight))?;
//! let mut obs = vec![0.0; 180];
//! env.reset(Some(7), &mut obs)?;
//! let step = env.step(&[0.5], &mut obs)?; // turn 0.5 rad left within the next second
//! assert_eq!(step.info.frame, 25);
//! # Ok::<(), fishprobe_sim::SimError>(())
//! ```
//!
//! Models live in `fishprobe-models`; this crate depends on nothing of ours.

#![warn(missing_docs)]

pub mod agent;
pub mod checker;
pub mod controller;
pub mod env;
pub mod error;
pub mod fish;
pub mod geometry;
pub mod group;
pub mod individual;
pub mod observation;
pub mod params;
pub mod rng;
pub mod robot;
pub mod sandbox;
pub mod script;
pub mod support;
pub mod task;
pub mod vector;

pub use agent::AgentState;
pub use checker::{check_env, CheckFailure, CheckReport};
pub use controller::{
    check_controller_observation, check_controller_rate, controller_actions_per_second,
    controller_env, controller_observation, scripted, ControlInput, Controller, ControllerClone,
    FetchAndLead, FetchParams, GoalSeeker, RandomTurns, SCRIPTED, SCRIPTED_ALL,
};
pub use env::{
    BoxSpace, Env, EnvConfig, EnvSnapshot, EpisodeSummary, RecordedCommand, StartPoses, StepInfo,
    TankEnv, Trajectory, Transition,
};
pub use error::SimError;
pub use fish::{
    apply_motion, step_fish, FishMind, FishModel, FishMotion, FishView, MAX_FISH, MAX_OTHERS,
};
pub use geometry::{wrap_angle, Tank, TankParams};
pub use group::{group_order, robot_to_group, GroupOrder};
pub use individual::{Individual, LATENT_DIM};
pub use observation::{ObservationEncoder, ObservationParams, Scene};
pub use params::{ConfigError, DocumentedParams, FieldDoc};
pub use rng::{derive_seed, stream, SimRng};
pub use robot::{Robot, RobotParams};
pub use sandbox::Sandbox;
pub use script::{RobotScript, ScriptParams};
pub use support::InputSupport;
pub use task::{
    GoalEvent, GoalReacher, GoalTracker, GroupGoal, Objective, OodScore, TaskMode, TaskParams,
    TrainingGoals, TrainingStart,
};
pub use vector::{AutoresetMode, VecEnv};
