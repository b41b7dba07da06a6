//! The wire format (docs/live-protocol.md): newline-delimited JSON over TCP. The client is the
//! lab side (tracker and robot, or the virtual lab); the server is the bridge running the
//! policy.

use serde::{Deserialize, Serialize};

/// Protocol version spoken by this build.
pub const PROTOCOL_VERSION: u32 = 1;

pub use crate::track::{Command, FishPose, Phase, Pose};

/// Messages from the lab side.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
#[serde(tag = "type", rename_all = "snake_case", deny_unknown_fields)]
pub enum ClientMsg {
    /// First message: who is talking and what the tank is.
    Hello {
        /// Protocol version.
        protocol: u32,
        /// Tank size (cm).
        world_size_cm: [f32; 2],
        /// Tracking rate (Hz).
        tracking_hz: f32,
        /// "lab" (live fish) or "virtual_lab".
        source: String,
        /// Shared secret, required when the bridge listens beyond loopback.
        #[serde(default)]
        token: Option<String>,
        /// Lockstep (the virtual lab): the bridge ends its answer to every frame with an
        /// `ack`, and the peer waits for it, so a simulated trial is deterministic. Time is
        /// then the peer's alone: the wall-clock silence rule does not apply.
        #[serde(default)]
        sync: bool,
    },
    /// One tracking frame.
    Frame {
        /// Tracking time stamp (s, monotonic within a trial).
        t: f64,
        /// The robot's pose, `null` when lost.
        robot: Option<Pose>,
        /// The fish.
        #[serde(default)]
        fish: Vec<FishPose>,
    },
    /// The lab ends the trial early.
    End,
}

/// Messages from the bridge.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
#[serde(tag = "type", rename_all = "snake_case")]
pub enum ServerMsg {
    /// Handshake accepted.
    Welcome {
        /// Protocol version.
        protocol: u32,
        /// The policy in control.
        policy: String,
        /// Habituation length (s).
        habituation_s: f64,
        /// When the fish is released, from the start (s).
        release_s: f64,
        /// Control length (s).
        control_s: f64,
        /// Commands per second of tracking time.
        command_hz: f64,
        /// Fish the bridge expects in each frame, in a fixed order (absent: 1, as before
        /// groups; sent only when more than one).
        #[serde(default = "one_fish", skip_serializing_if = "is_one_fish")]
        fish_count: u32,
        /// The SHA-256 of the weights in control (the `policy_sha256` its trial files record);
        /// absent for a scripted pilot, which has no weights. Added within version 1: a client
        /// that does not know the field ignores it.
        #[serde(default, skip_serializing_if = "Option::is_none")]
        policy_sha256: Option<String>,
    },
    /// A robot command (see [`Command`]).
    Command(Command),
    /// The trial is over; where it was written.
    Done {
        /// The trial file.
        file: String,
        /// Goals reached.
        goals_reached: u32,
    },
    /// In lockstep mode: everything the bridge has to say about frame `t` has been said.
    Ack {
        /// The frame's time stamp.
        t: f64,
    },
    /// A refused handshake or a fatal problem.
    Error {
        /// What is wrong.
        reason: String,
    },
}

impl From<Command> for ServerMsg {
    fn from(c: Command) -> Self {
        ServerMsg::Command(c)
    }
}

/// Parses one line from the lab side.
pub fn parse_client(line: &str) -> Result<ClientMsg, crate::LiveError> {
    serde_json::from_str(line.trim()).map_err(|e| {
        let head: String = line.chars().take(80).collect();
        crate::LiveError::Malformed(format!("malformed message ({e}): {head}"))
    })
}

/// One line of JSON (with the newline) for the wire.
pub fn to_line<T: Serialize>(m: &T) -> String {
    let mut s = serde_json::to_string(m).unwrap_or_else(|e| {
        format!("{{\"type\":\"error\",\"reason\":\"cannot encode message: {e}\"}}")
    });
    s.push('\n');
    s
}

fn one_fish() -> u32 {
    1
}

#[allow(clippy::trivially_copy_pass_by_ref)] // serde's skip_serializing_if passes a reference
fn is_one_fish(n: &u32) -> bool {
    *n == 1
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn frames_parse_with_lost_agents_and_unknown_messages_are_refused() {
        let m = parse_client(
            r#"{"type":"frame","t":1.04,"robot":{"x":1,"y":2,"heading":0.5},"fish":[{"id":"f1","x":3,"y":4,"heading":1},{"id":"f2"}]}"#,
        )
        .expect("parses");
        match m {
            ClientMsg::Frame { t, robot, fish } => {
                assert_eq!(t, 1.04);
                assert!(robot.is_some_and(|p| p.is_valid()));
                assert_eq!(fish.len(), 2);
                assert!(fish[1].pose.is_none());
            }
            other => panic!("{other:?}"),
        }
        let lost = parse_client(r#"{"type":"frame","t":2,"robot":null}"#).expect("parses");
        assert!(matches!(lost, ClientMsg::Frame { robot: None, .. }));
        assert!(parse_client(r#"{"type":"dance"}"#)
            .unwrap_err()
            .to_string()
            .contains("malformed"));
        assert!(parse_client("{not json").is_err());
        assert!(!Pose {
            x: f32::NAN,
            y: 0.0,
            heading: 0.0
        }
        .is_valid());
        assert!(!Pose {
            x: 90.0,
            y: 0.0,
            heading: 0.0
        }
        .is_valid());
    }

    #[test]
    fn commands_round_trip() {
        let c = ServerMsg::Command(Command {
            t: 3.0,
            seq: Some(3),
            turn: 0.5,
            stop: false,
            reason: None,
            phase: Phase::Control,
            released: true,
            active_goal: Some([-20.0, -20.0]),
            goals_reached: 2,
        });
        let line = to_line(&c);
        assert!(line.ends_with('\n') && line.contains("\"type\":\"command\""));
        let back: ServerMsg = serde_json::from_str(&line).expect("parses");
        assert_eq!(back, c);
    }

    #[test]
    fn a_welcome_names_weights_only_when_there_are_some() {
        let w = |policy_sha256: Option<String>| ServerMsg::Welcome {
            protocol: 1,
            policy: "Zone".into(),
            habituation_s: 120.0,
            release_s: 60.0,
            control_s: 900.0,
            command_hz: 1.0,
            fish_count: 1,
            policy_sha256,
        };
        let with = to_line(&w(Some("ab12".into())));
        assert!(with.contains(r#""policy_sha256":"ab12""#), "{with}");
        assert_eq!(
            serde_json::from_str::<ServerMsg>(&with).ok(),
            Some(w(Some("ab12".into())))
        );
        // A scripted pilot's welcome is the welcome of earlier builds, byte for byte, and an
        // earlier bridge's welcome (no field) reads as one without weights.
        let without = to_line(&w(None));
        assert_eq!(
            without,
            "{\"type\":\"welcome\",\"protocol\":1,\"policy\":\"Zone\",\"habituation_s\":120.0,\
             \"release_s\":60.0,\"control_s\":900.0,\"command_hz\":1.0}\n"
        );
        assert_eq!(
            serde_json::from_str::<ServerMsg>(&without).ok(),
            Some(w(None))
        );
    }
}
