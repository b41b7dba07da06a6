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
pub mod fish_ids;
pub mod host;
pub mod keep;
pub mod lab;
mod lines;
pub mod protocol;
pub mod server;
pub mod session;
pub mod shutdown;
pub mod sink;
pub mod track;

pub use error::LiveError;
pub use lines::{read_line_at_most, MAX_BRIDGE_LINE_BYTES};

/// Side (cm) of the square tank of the bridge and the virtual lab: the 1 x 1 m tank every
/// policy is trained for. A hello with another tank is refused.
pub const TANK_CM: f32 = 100.0;

/// A moment as a log line's stamp, readable and sortable: `2026-12-07 23:59:01.123Z` (UTC;
/// the proleptic Gregorian calendar of the Unix epoch's days).
pub fn utc_stamp(t: std::time::SystemTime) -> String {
    let d = t.duration_since(std::time::UNIX_EPOCH).unwrap_or_default();
    let secs = d.as_secs();
    let (days, rem) = (secs / 86_400, secs % 86_400);
    // Days since 1970-01-01 to a civil date (Howard Hinnant's algorithm).
    let z = days as i64 + 719_468;
    let era = z.div_euclid(146_097);
    let doe = z.rem_euclid(146_097);
    let yoe = (doe - doe / 1460 + doe / 36_524 - doe / 146_096) / 365;
    let doy = doe - (365 * yoe + yoe / 4 - yoe / 100);
    let mp = (5 * doy + 2) / 153;
    let day = doy - (153 * mp + 2) / 5 + 1;
    let month = if mp < 10 { mp + 3 } else { mp - 9 };
    let year = yoe + era * 400 + i64::from(month <= 2);
    format!(
        "{year:04}-{month:02}-{day:02} {:02}:{:02}:{:02}.{:03}Z",
        rem / 3600,
        rem % 3600 / 60,
        rem % 60,
        d.subsec_millis()
    )
}

#[cfg(test)]
mod stamp_tests {
    #[test]
    fn stamps_are_utc_calendar_dates() {
        let at = |s: u64, ms: u32| {
            super::utc_stamp(std::time::UNIX_EPOCH + std::time::Duration::new(s, ms * 1_000_000))
        };
        assert_eq!(at(0, 0), "1970-01-01 00:00:00.000Z");
        // date -u -d @1796774341 → 2026-12-08 23:59:01
        assert_eq!(at(1_796_774_341, 123), "2026-12-08 23:59:01.123Z");
        assert_eq!(at(951_782_400, 0), "2000-02-29 00:00:00.000Z");
    }
}
