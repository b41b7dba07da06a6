//! The robot fish and its low-level controller (SPEC §3).
//!
//! The policy gives one relative turn angle per second. Within that second the controller
//! turns toward the new heading with a saturating proportional law, drives forward only when
//! it faces the new heading (a gate on the heading error), then stops driving and glides:
//! the burst-and-glide of a guppy. Both commands pass an actuator lag and acceleration limits.

use crate::agent::AgentState;
use crate::geometry::{wrap_angle, Tank};
use crate::params::{check, ConfigError};
use std::f32::consts::PI;

crate::documented_params! {
    /// Limits and gains of the robot's low-level controller. Reference values: the lab's own
    /// robot model in gym-guppy (2020).
    pub struct RobotParams {
        /// Maximum forward speed (paper: 15 cm/s).
        pub max_speed_cm_s: f32 = 15.0; "cm/s",
        /// Maximum turning rate (paper: 180°/s).
        pub max_turn_rate_rad_s: f32 = PI; "rad/s",
        /// Heading gain: commanded turn rate = max_turn_rate · tanh(gain · error / slope)
        /// (gym-guppy: 1.2).
        pub heading_gain: f32 = 1.2; "1",
        /// Heading error at which the turn command saturates (gym-guppy sigmoid slope 0.75).
        pub heading_slope_rad: f32 = 0.75; "rad",
        /// Forward gain: burst speed = forward_gain · max_speed · gate (gym-guppy: 1). gym-guppy's
        /// forward slope (0.5) acts on a distance to a target point, which a turn-angle action
        /// does not have; `burst_duration_s` takes its role.
        pub forward_gain: f32 = 1.0; "1",
        /// Heading gate: forward drive is scaled by max(0, cos error)^exponent, so the robot only
        /// drives when it faces where it wants to go (gym-guppy gate slope 3).
        pub heading_gate_exponent: f32 = 3.0; "1",
        /// First-order actuator lag of speed and turn rate (gym-guppy: about 160 ms).
        pub actuator_lag_s: f32 = 0.16; "s",
        /// Forward acceleration limit (choice: full speed in 0.25 s).
        pub acceleration_cm_s2: f32 = 60.0; "cm/s²",
        /// Braking limit while the gate closes during a turn (choice).
        pub braking_cm_s2: f32 = 60.0; "cm/s²",
        /// Deceleration while gliding after the burst (choice: from 15 cm/s to rest in 1.25 s).
        pub glide_deceleration_cm_s2: f32 = 12.0; "cm/s²",
        /// How long after each action the forward drive is on; the rest of the second is
        /// glide (choice).
        pub burst_duration_s: f32 = 0.6; "s",
    }
}

impl RobotParams {
    /// Checks the ranges; `prefix` is the field path of this struct.
    pub fn validate(&self, prefix: &str) -> Result<(), ConfigError> {
        check::positive_at_most(
            prefix,
            "max_speed_cm_s",
            self.max_speed_cm_s,
            check::MAX_SPEED_CM_S,
        )?;
        check::positive_at_most(
            prefix,
            "max_turn_rate_rad_s",
            self.max_turn_rate_rad_s,
            check::MAX_TURN_RATE_RAD_S,
        )?;
        check::positive_at_most(prefix, "heading_gain", self.heading_gain, check::MAX_WEIGHT)?;
        check::positive_at_most(
            prefix,
            "heading_slope_rad",
            self.heading_slope_rad,
            std::f32::consts::PI,
        )?;
        check::within(prefix, "forward_gain", self.forward_gain, 0.0, 1.0)?;
        check::within(
            prefix,
            "heading_gate_exponent",
            self.heading_gate_exponent,
            0.0,
            check::MAX_WEIGHT,
        )?;
        check::within(
            prefix,
            "actuator_lag_s",
            self.actuator_lag_s,
            0.0,
            check::MAX_DURATION_S,
        )?;
        for (f, v) in [
            ("acceleration_cm_s2", self.acceleration_cm_s2),
            ("braking_cm_s2", self.braking_cm_s2),
            ("glide_deceleration_cm_s2", self.glide_deceleration_cm_s2),
        ] {
            check::positive_at_most(prefix, f, v, check::MAX_ACCELERATION_CM_S2)?;
        }
        check::within(
            prefix,
            "burst_duration_s",
            self.burst_duration_s,
            0.0,
            check::MAX_DURATION_S,
        )
    }
}

/// The robot: its pose and its controller's memory.
#[derive(Debug, Clone, Copy, PartialEq, Default, serde::Serialize, serde::Deserialize)]
pub struct Robot {
    /// Pose and last-frame velocity.
    pub state: AgentState,
    /// Forward speed the actuators currently deliver (cm/s, >= 0).
    pub speed: f32,
    /// Turn rate the actuators currently deliver (rad/s).
    pub turn_rate: f32,
    /// Heading the controller steers to (rad).
    pub target_heading: f32,
    /// Time since the last action (s).
    pub time_in_action: f32,
}

impl Robot {
    /// A robot at rest at a pose, holding its heading.
    pub fn at(x: f32, y: f32, heading: f32) -> Self {
        Self {
            state: AgentState::at(x, y, heading),
            speed: 0.0,
            turn_rate: 0.0,
            target_heading: heading,
            time_in_action: 0.0,
        }
    }

    /// Starts a new action: turn by `turn` (rad, already clipped to [-π, π]) relative to the
    /// current heading.
    pub fn begin_action(&mut self, turn: f32) {
        self.target_heading = wrap_angle(self.state.heading + turn);
        self.time_in_action = 0.0;
    }

    /// Advances the robot by one frame of `dt` seconds. Returns true on a wall contact (the
    /// robot is stopped there).
    #[inline]
    pub fn advance(&mut self, p: &RobotParams, tank: &Tank, dt: f32) -> bool {
        let lag = if p.actuator_lag_s > 0.0 {
            (dt / p.actuator_lag_s).min(1.0)
        } else {
            1.0
        };
        let error = wrap_angle(self.target_heading - self.state.heading);

        let turn_cmd =
            p.max_turn_rate_rad_s * (p.heading_gain * error / p.heading_slope_rad).tanh();
        self.turn_rate += (turn_cmd - self.turn_rate) * lag;
        self.turn_rate = self
            .turn_rate
            .clamp(-p.max_turn_rate_rad_s, p.max_turn_rate_rad_s);

        let driving = self.time_in_action < p.burst_duration_s;
        let speed_cmd = if driving {
            let gate = error.cos().max(0.0).powf(p.heading_gate_exponent);
            p.forward_gain * p.max_speed_cm_s * gate
        } else {
            0.0
        };
        let wanted = (speed_cmd - self.speed) * lag;
        let dv = if wanted >= 0.0 {
            wanted.min(p.acceleration_cm_s2 * dt)
        } else if driving {
            wanted.max(-p.braking_cm_s2 * dt)
        } else {
            wanted.max(-p.glide_deceleration_cm_s2 * dt)
        };
        self.speed = (self.speed + dv).clamp(0.0, p.max_speed_cm_s);

        let s = &mut self.state;
        s.heading = wrap_angle(s.heading + self.turn_rate * dt);
        let (sin, cos) = s.heading.sin_cos();
        let (nx, ny, contact) = tank.clip(s.x + self.speed * cos * dt, s.y + self.speed * sin * dt);
        s.vx = (nx - s.x) / dt;
        s.vy = (ny - s.y) / dt;
        s.x = nx;
        s.y = ny;
        if contact {
            self.speed = 0.0;
        }
        self.time_in_action += dt;
        contact
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    const DT: f32 = 0.04;

    fn run_action(robot: &mut Robot, turn: f32, frames: usize) -> (f32, f32, f32) {
        let p = RobotParams::default();
        let tank = Tank::default();
        robot.begin_action(turn);
        let (mut max_v, mut max_w, mut max_acc) = (0.0f32, 0.0f32, 0.0f32);
        for _ in 0..frames {
            let v0 = robot.state.speed();
            let h0 = robot.state.heading;
            robot.advance(&p, &tank, DT);
            max_v = max_v.max(robot.state.speed());
            max_w = max_w.max((wrap_angle(robot.state.heading - h0) / DT).abs());
            max_acc = max_acc.max((robot.state.speed() - v0) / DT);
        }
        (max_v, max_w, max_acc)
    }

    #[test]
    fn durations_beyond_a_day_are_refused_by_name() {
        assert!(RobotParams::default().validate("robot").is_ok());
        for (field, p) in [
            (
                "robot.actuator_lag_s",
                RobotParams {
                    actuator_lag_s: 1e30,
                    ..RobotParams::default()
                },
            ),
            (
                "robot.burst_duration_s",
                RobotParams {
                    burst_duration_s: 86_401.0,
                    ..RobotParams::default()
                },
            ),
        ] {
            let e = p.validate("robot").unwrap_err().to_string();
            assert!(e.contains(field) && e.contains("[0, 86400]"), "{e}");
        }
    }

    #[test]
    fn turns_by_the_commanded_angle() {
        for &turn in &[-2.0f32, -1.0, -0.3, 0.0, 0.5, 1.2, 2.0] {
            let mut r = Robot::at(0.0, 0.0, 0.3);
            // One action second, then hold (a zero turn keeps the target only if it was
            // reached, so hold the same target for a second second instead).
            run_action(&mut r, turn, 25);
            let after_one = wrap_angle(r.state.heading - (0.3 + turn)).abs();
            for _ in 0..25 {
                r.advance(&RobotParams::default(), &Tank::default(), DT);
            }
            let after_two = wrap_angle(r.state.heading - (0.3 + turn)).abs();
            assert!(
                after_one < 0.2,
                "turn {turn}: error after 1 s {after_one} rad"
            );
            assert!(
                after_two < 0.02,
                "turn {turn}: error after 2 s {after_two} rad"
            );
        }
    }

    #[test]
    fn never_exceeds_limits() {
        let p = RobotParams::default();
        let mut r = Robot::at(0.0, 0.0, 0.0);
        let turns = [3.1f32, -3.1, 0.0, 0.0, 1.5, -2.5, 0.0, PI, 0.2, -0.2];
        for (i, t) in turns.iter().cycle().take(60).enumerate() {
            let (v, w, a) = run_action(&mut r, *t, 25);
            assert!(v <= p.max_speed_cm_s + 1e-3, "action {i}: speed {v}");
            assert!(
                w <= p.max_turn_rate_rad_s + 1e-3,
                "action {i}: turn rate {w}"
            );
            assert!(
                a <= p.acceleration_cm_s2 + 1e-2,
                "action {i}: acceleration {a}"
            );
        }
    }

    #[test]
    fn bursts_then_glides() {
        let p = RobotParams::default();
        let tank = Tank::default();
        let mut r = Robot::at(-40.0, 0.0, 0.0);
        r.begin_action(0.0);
        let mut speeds = Vec::new();
        for _ in 0..25 {
            r.advance(&p, &tank, DT);
            speeds.push(r.speed);
        }
        let peak = speeds.iter().cloned().fold(0.0, f32::max);
        assert!(peak > 0.9 * p.max_speed_cm_s, "peak {peak}");
        assert!(speeds[24] < peak && speeds[24] > 0.0, "glides: {speeds:?}");
        // A large turn first slows the robot: the gate closes while the heading error is big.
        let before = r.speed;
        r.begin_action(PI * 0.95);
        r.advance(&p, &tank, DT);
        r.advance(&p, &tank, DT);
        assert!(r.speed < before, "slows to turn: {before} -> {}", r.speed);
    }

    #[test]
    fn stops_at_walls() {
        let p = RobotParams::default();
        let tank = Tank::default();
        let mut r = Robot::at(40.0, 0.0, 0.0);
        let mut contacts = 0;
        for _ in 0..5 {
            r.begin_action(0.0);
            for _ in 0..25 {
                contacts += usize::from(r.advance(&p, &tank, DT));
            }
        }
        assert!(contacts > 0);
        assert!(r.state.x <= 49.0 + 1e-5);
        assert_eq!(r.speed, 0.0);
    }
}
