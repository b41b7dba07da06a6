//! Reinforcement learning for the robot: PPO with the paper's settings (SPEC §7), evaluation
//! of trained policies on the 15-minute task, ONNX export for the robot PC, and the OOD
//! reward's yardstick measured from a lead-to-goal policy's episodes ([`yardstick`]).
//!
//! ```no_run
//! use fishprobe_learn::{PpoConfig, RunSpec, Trainer};
//! use fishprobe_models::ModelSpec;
//! use fishprobe_sim::EnvConfig;
//!
//! let spec = RunSpec::new(
//!     ModelSpec::by_name("Zone")?,
//!     PpoConfig::preset("quick").unwrap(),
//!     EnvConfig::default(),
//!     1,
//!     "quick",
//!     env!("CARGO_PKG_VERSION"),
//! );
//! let mut run = Trainer::create("runs/zone".as_ref(), spec)?;
//! while !run.done() {
//!     let s = run.iterate()?;
//!     println!("{}: {:.1} goals per episode", s.timesteps, s.goals_per_episode);
//! }
//! run.finish()?;
//! # Ok::<(), Box<dyn std::error::Error>>(())
//! ```

#![warn(missing_docs)]

pub mod bc;
pub mod config;
pub mod controller;
pub mod error;
pub mod evaluate;
pub mod gae;
pub mod onnx;
pub mod policy;
pub mod population;
pub mod ppo;
pub mod run;
pub mod trainer;
pub mod yardstick;

pub use config::PpoConfig;
pub use controller::{controller, named, pilot, PolicyArg, PolicyController};
pub use error::LearnError;
pub use evaluate::{
    approach_assay, evaluate, evaluate_with_model, goals_mean_sd, run_episode, EpisodeResult,
    Evaluation,
};
pub use policy::{to_env_action, GaussianPolicy};
pub use trainer::{shaping_matches, IterationStats, RunSpec, Trainer};

/// The trainer's revision: raised when a fix makes runs of earlier revisions wrong with the
/// same settings, so that a study retrains the policies it made before (its training steps
/// hash this number with their settings, and a partly trained run of another revision starts
/// over), and `train --resume` refuses to continue a run another revision started
/// ([`RunSpec::trainer_revision`]). 2: above the log-s.d. bound a gradient that lowers
/// the log-s.d. passes (`ppo`); under revision 1 a run could stay at the widest Gaussian for
/// good (docs/validation.md, "What did not work").
pub const TRAINER_REVISION: u32 = 2;
