//! Live trials (SPEC §9): the bridge between a trained policy and the lab's tracker and robot,
//! and the virtual lab that stands in for tank, tracker, robot and fish through exactly the
//! same code path.
//!
//! The bridge ([`server::serve`]) speaks newline-delimited JSON over TCP
//! (`docs/live-protocol.md`): the lab sends a hello and then tracking frames; the bridge answers
//! with robot commands once per second of tracking time, runs the trial protocol (habituation
//! with a milling robot and the fish's release, then 15 minutes of policy control with the goal
//! logic), stops the robot when tracking is lost or input is malformed, and writes every trial
//! as a trial file. [`lab::run_trial`] plays the virtual lab against it.
//!
//! ```no_run
//! use fishprobe_live::{lab, server, session::LiveConfig};
//! use fishprobe_sim::{ControlInput, Controller, SimRng};
//! #[derive(Clone)]
//! struct Straight;
//! impl Controller for Straight {
//!     fn name(&self) -> String { "Straight".into() }
//!     fn act(&mut self, _input: &ControlInput<'_>, _rng: &mut SimRng) -> f32 { 0.0 }
//! }
//! let listener = std::net::TcpListener::bind("127.0.0.1:0")?;
//! let addr = listener.local_addr()?;
//! let opts = server::ServeOptions {
//!     live: LiveConfig::default(),
//!     task: fishprobe_sim::TaskParams::default(),
//!     out: "trials".into(),
//!     token: None,
//!     max_trials: Some(1),
//!     fish_label: "live guppy".into(),
//!     guard: server::BridgeGuard::default(),
//! };
//! let bridge = std::thread::spawn(move || {
//!     server::serve(&listener, &opts, &mut || Ok(Box::new(Straight) as Box<dyn Controller>), |_| {})
//! });
//! let trial = lab::run_trial(addr, &lab::LabConfig::default(), 7)?;
//! println!("{} goals, written to {}", trial.goals_reached, trial.file);
//! # let _ = bridge.join();
//! # Ok::<(), Box<dyn std::error::Error>>(())
//! ```

#![warn(missing_docs)]

pub mod biotracker;
pub mod error;
pub mod keep;
pub mod lab;
mod lines;
pub mod protocol;
pub mod server;
pub mod session;
pub mod sink;

pub use error::LiveError;
pub use lines::{read_line_at_most, MAX_BRIDGE_LINE_BYTES};

/// Side (cm) of the square tank of the bridge and the virtual lab: the 1 x 1 m tank every
/// policy is trained for. A hello with another tank is refused.
pub const TANK_CM: f32 = 100.0;
