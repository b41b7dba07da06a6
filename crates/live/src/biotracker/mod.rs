//! fishprobe as a BioTracker v4 observer: the lab's tracker sends every tracked frame to
//! fishprobe, which runs the live trial protocol on it and drives the robot.
//!
//! BioTracker v4's core starts its components and calls them over gRPC on loopback
//! (`biotracker.Observer/set_config` once, then `update` per frame). This module holds what
//! does not depend on the transport: the messages ([`schema`]), reading robot and fish out of
//! an update and following the recording ([`frames`]), and the trial logic on top of the
//! bridge's [`crate::session::Session`] ([`observer`]). The component's settings are the
//! `config_json` of its entry in BioTracker's config file ([`ObserverSettings`]).

pub mod component;
pub mod frames;
pub mod grpc;
pub mod observer;
pub mod schema;

pub use frames::{EntityIds, Expected};
pub use observer::{Event, Observer};

use serde::{Deserialize, Serialize};
use std::net::SocketAddr;
use std::path::PathBuf;

/// The observer component's settings: the `config_json` of its entry in BioTracker's config
/// file. Unknown keys are refused (a misspelt key would otherwise be silently ignored).
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct ObserverSettings {
    /// The policy that drives the robot, as `live serve --policy` takes it: a training run's
    /// folder, a policy file (`.fpnn`, `.onnx`), or `scripted:<name>`.
    pub policy: String,
    /// Where trial files go (`<out>/<Policy>__Real/`); relative to BioTracker's config file's
    /// folder, where the core starts its components.
    pub out: PathBuf,
    /// The robot's entity id in BioTracker.
    pub robot_id: u32,
    /// The fish's entity ids, in the order of the policy's observation (one for the paper's
    /// single fish).
    pub fish_ids: Vec<u32>,
    /// Where the robot sink listens for the lab's robot program (default `127.0.0.1:27350`,
    /// loopback).
    #[serde(default = "default_sink")]
    pub robot_sink: SocketAddr,
    /// Shared secret a robot program must send to the sink; required when `robot_sink` is
    /// not on loopback.
    #[serde(default)]
    pub robot_sink_token: Option<String>,
    /// The tracker core's address, for the heartbeat (default `127.0.0.1:27342`, the core's
    /// default `--port`).
    #[serde(default = "default_core")]
    pub core: SocketAddr,
    /// Trials follow BioTracker's recording: one starts when recording starts and ends when
    /// it stops (default). Off: a trial starts at the first update.
    #[serde(default = "yes")]
    pub follow_recording: bool,
    /// Run even when the tracker's `target_fps` differs from the rate the policy was trained
    /// at (the trial file records the tracker's rate). Off by default: the policy's sense of
    /// time comes from that rate.
    #[serde(default)]
    pub accept_other_fps: bool,
    /// A settings file for the trial protocol (TOML, the settings of `fishprobe live serve
    /// --config`); absent: the paper's protocol. Its `fish_count` follows `fish_ids`.
    #[serde(default)]
    pub config: Option<PathBuf>,
}

fn default_sink() -> SocketAddr {
    SocketAddr::from(([127, 0, 0, 1], 27350))
}

fn default_core() -> SocketAddr {
    SocketAddr::from(([127, 0, 0, 1], 27342))
}

fn yes() -> bool {
    true
}

/// The keys of a component's `config_json`, as [`ObserverSettings`] names them.
pub const SETTINGS_KEYS: [&str; 10] = [
    "policy",
    "out",
    "robot_id",
    "fish_ids",
    "robot_sink",
    "robot_sink_token",
    "core",
    "follow_recording",
    "accept_other_fps",
    "config",
];

/// The keys a `config_json` must have.
const REQUIRED_KEYS: [&str; 4] = ["policy", "out", "robot_id", "fish_ids"];

impl ObserverSettings {
    /// Reads the settings from a component's `config_json`; a refusal lists every problem
    /// found, not only the first (each key is checked on its own), so one edit of the entry
    /// can fix them all.
    pub fn from_json(config_json: &str) -> Result<Self, crate::LiveError> {
        let problems = |p: Vec<String>| {
            crate::LiveError::Settings(format!("the component's config_json: {}", p.join("; ")))
        };
        let value: serde_json::Value = serde_json::from_str(config_json)
            .map_err(|e| problems(vec![format!("not JSON: {e}")]))?;
        let Some(map) = value.as_object() else {
            return Err(problems(vec!["not a JSON object".into()]));
        };
        let mut p = Vec::new();
        for k in map.keys() {
            if !SETTINGS_KEYS.contains(&k.as_str()) {
                p.push(format!(
                    "unknown key `{k}` (the keys: {})",
                    SETTINGS_KEYS.join(", ")
                ));
            }
        }
        for k in REQUIRED_KEYS {
            if !map.contains_key(k) {
                p.push(format!("`{k}` is missing"));
            }
        }
        // Each known key on its own, so that every mistyped one is named.
        for (k, v) in map {
            if SETTINGS_KEYS.contains(&k.as_str()) {
                let mut one = serde_json::Map::new();
                one.insert(k.clone(), v.clone());
                if let Err(e) = serde_json::from_value::<KeyCheck>(serde_json::Value::Object(one)) {
                    p.push(format!("`{k}`: {e}"));
                }
            }
        }
        // The keys that read, checked together too, so that one look finds every problem.
        let bad: Vec<String> = map
            .keys()
            .filter(|k| p.iter().any(|q| q.contains(&format!("`{k}`"))))
            .cloned()
            .collect();
        let mut usable = map.clone();
        usable.retain(|k, _| !bad.contains(k));
        match serde_json::from_value::<Self>(serde_json::Value::Object(usable)) {
            Ok(s) => {
                p.extend(s.problems());
                if p.is_empty() {
                    Ok(s)
                } else {
                    Err(problems(p))
                }
            }
            Err(e) if p.is_empty() => Err(problems(vec![e.to_string()])),
            Err(_) => Err(problems(p)),
        }
    }

    /// The entity ids.
    pub fn ids(&self) -> EntityIds {
        EntityIds {
            robot: self.robot_id,
            fish: self.fish_ids.clone(),
        }
    }

    /// Checks what can be checked without loading anything.
    pub fn validate(&self) -> Result<(), crate::LiveError> {
        let p = self.problems();
        if p.is_empty() {
            Ok(())
        } else {
            Err(crate::LiveError::Settings(p.join("; ")))
        }
    }

    /// Every problem that can be found without loading anything.
    fn problems(&self) -> Vec<String> {
        let mut p = Vec::new();
        if self.policy.trim().is_empty() {
            p.push(
                "`policy` is empty: name a training run, a policy file or scripted:<name>".into(),
            );
        }
        if self.fish_ids.len() > fishprobe_sim::MAX_FISH {
            p.push(format!(
                "{} fish entity ids; at most {} fish",
                self.fish_ids.len(),
                fishprobe_sim::MAX_FISH
            ));
        }
        if let Err(e) = self.ids().validate() {
            p.push(e.to_string());
        }
        if self
            .robot_sink_token
            .as_deref()
            .is_some_and(|t| t.trim().is_empty())
        {
            p.push("`robot_sink_token` is empty".into());
        }
        if !self.robot_sink.ip().is_loopback() && self.robot_sink_token.is_none() {
            p.push(format!(
                "the robot sink listens on {} (not loopback): set `robot_sink_token`",
                self.robot_sink
            ));
        }
        // Port 0 asks the system for any free port: the robot program could not know the
        // sink's, and no core listens there.
        if self.robot_sink.port() == 0 {
            p.push("`robot_sink` has port 0: name the port the robot program connects to".into());
        }
        if self.core.port() == 0 {
            p.push("`core` has port 0: name the core's port (its --port, 27342 by default)".into());
        }
        p
    }
}

/// One key of the settings at a time, to name each mistyped key (see
/// [`ObserverSettings::from_json`]).
#[derive(Deserialize)]
#[allow(dead_code)]
struct KeyCheck {
    policy: Option<String>,
    out: Option<PathBuf>,
    robot_id: Option<u32>,
    fish_ids: Option<Vec<u32>>,
    robot_sink: Option<SocketAddr>,
    robot_sink_token: Option<Option<String>>,
    core: Option<SocketAddr>,
    follow_recording: Option<bool>,
    accept_other_fps: Option<bool>,
    config: Option<Option<PathBuf>>,
}

#[cfg(test)]
mod tests;
