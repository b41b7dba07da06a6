//! Scripted robots: kinematic robots that follow a fixed plan instead of the policy's turn
//! commands (`fishprobe simulate --robot still|circle|goals`). They move directly, not through
//! the low-level controller, so that they can stand still and wait.

use crate::geometry::{wrap_angle, Tank};
use crate::params::{check, ConfigError};
use crate::robot::Robot;
use serde::{Deserialize, Serialize};

/// A scripted robot's plan.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Serialize, Deserialize)]
#[serde(rename_all = "snake_case")]
pub enum RobotScript {
    /// Stands still where it starts.
    Still,
    /// Drives a circle around the tank centre.
    Circle,
    /// Drives to the active goal of the task, waits there until the fish reaches it, then
    /// drives to the next one.
    Goals,
}

impl RobotScript {
    /// From its name.
    pub fn parse(s: &str) -> Option<Self> {
        match s {
            "still" => Some(Self::Still),
            "circle" => Some(Self::Circle),
            "goals" => Some(Self::Goals),
            _ => None,
        }
    }

    /// Its name.
    pub fn name(self) -> &'static str {
        match self {
            Self::Still => "still",
            Self::Circle => "circle",
            Self::Goals => "goals",
        }
    }
}

crate::documented_params! {
    /// How scripted robots move (all choices).
    pub struct ScriptParams {
        /// Driving speed of the circle and goals robots.
        pub speed_cm_s: f32 = 10.0; "cm/s",
        /// Radius of the circle robot's circle around the tank centre (a 30 cm circle).
        pub circle_radius_cm: f32 = 15.0; "cm",
    }
}

impl ScriptParams {
    /// Checks the ranges; `prefix` is the field path of this struct.
    pub fn validate(&self, prefix: &str) -> Result<(), ConfigError> {
        check::positive_at_most(prefix, "speed_cm_s", self.speed_cm_s, check::MAX_SPEED_CM_S)?;
        check::positive_at_most(
            prefix,
            "circle_radius_cm",
            self.circle_radius_cm,
            check::MAX_LENGTH_CM,
        )
    }
}

/// Moves the robot one frame along its plan. Returns true on a wall contact.
pub fn advance_scripted(
    robot: &mut Robot,
    script: RobotScript,
    p: &ScriptParams,
    goal: [f32; 2],
    tank: &Tank,
    dt: f32,
) -> bool {
    let s = robot.state;
    let step = p.speed_cm_s * dt;
    let target = match script {
        RobotScript::Still => None,
        RobotScript::Goals => Some(goal),
        RobotScript::Circle => {
            // Aim at the point one step further along the circle than our own angle: robots
            // off the circle spiral onto it, robots on it follow it counter-clockwise.
            let phi = s.y.atan2(s.x) + step / p.circle_radius_cm;
            Some([
                p.circle_radius_cm * phi.cos(),
                p.circle_radius_cm * phi.sin(),
            ])
        }
    };
    let (mut nx, mut ny, mut heading) = (s.x, s.y, s.heading);
    if let Some([tx, ty]) = target {
        let (dx, dy) = (tx - s.x, ty - s.y);
        let d = (dx * dx + dy * dy).sqrt();
        if d > 1e-6 {
            let k = step.min(d) / d;
            nx += dx * k;
            ny += dy * k;
            heading = wrap_angle(dy.atan2(dx));
        }
    }
    let (cx, cy, contact) = tank.clip(nx, ny);
    let st = &mut robot.state;
    st.vx = (cx - st.x) / dt;
    st.vy = (cy - st.y) / dt;
    st.x = cx;
    st.y = cy;
    st.heading = heading;
    robot.speed = st.speed();
    robot.turn_rate = 0.0;
    robot.target_heading = heading;
    contact
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn circle_robot_settles_on_the_circle() {
        let p = ScriptParams::default();
        let tank = Tank::default();
        let mut r = Robot::at(-30.0, 25.0, 0.0);
        for _ in 0..2000 {
            advance_scripted(&mut r, RobotScript::Circle, &p, [0.0, 0.0], &tank, 0.04);
        }
        let radius = (r.state.x.powi(2) + r.state.y.powi(2)).sqrt();
        assert!((radius - 15.0).abs() < 0.2, "{radius}");
        assert!((r.state.speed() - 10.0).abs() < 0.1);
    }

    #[test]
    fn goals_robot_arrives_and_waits() {
        let p = ScriptParams::default();
        let tank = Tank::default();
        let mut r = Robot::at(0.0, 0.0, 0.0);
        for _ in 0..200 {
            advance_scripted(&mut r, RobotScript::Goals, &p, [20.0, 20.0], &tank, 0.04);
        }
        assert_eq!((r.state.x, r.state.y), (20.0, 20.0));
        assert_eq!(r.state.speed(), 0.0);
        let mut still = Robot::at(3.0, 4.0, 1.0);
        advance_scripted(
            &mut still,
            RobotScript::Still,
            &p,
            [20.0, 20.0],
            &tank,
            0.04,
        );
        assert_eq!(
            (still.state.x, still.state.y, still.state.heading),
            (3.0, 4.0, 1.0)
        );
    }
}
