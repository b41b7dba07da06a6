//! The environment's settings ([`EnvConfig`]) and their bounds.

use super::*;

crate::documented_params! {
    /// Everything that defines an environment except the fish model.
    pub struct EnvConfig {
        /// Simulation (and tracking) frame rate (paper: 25 Hz). A policy records the frame
        /// rate it was trained at, as it records `frames_per_action`, and is run only at it:
        /// 25 frames at 50 Hz are half a second (policies trained before fishprobe recorded
        /// it run at the run's).
        pub frame_rate_hz: f32 = 25.0; "Hz",
        /// Frames per policy action (paper: the policy acts at 1 Hz, so 25). A policy
        /// records the rate it was trained at and is run only at it: `evaluate` refuses
        /// another by name, an OOD run's yardstick and `ood-report`'s comparison policy act
        /// at their own, and the live bridge asks for `command_hz` = `frame_rate_hz` / this.
        /// `training_episode_actions` and `evaluation_episode_actions` count actions, so a
        /// faster policy's 41-s episode is 41 · 25 / this of them.
        pub frames_per_action: u32 = 25; "frames",
        /// Number of fish, 1 to `MAX_FISH` = 16, the robot not counted (paper: 1). With
        /// more than one, `task.group_goal` says when the group has reached a goal.
        pub fish_count: u32 = 1; "1",
        /// Training or evaluation task.
        pub mode: TaskMode = TaskMode::Training; "-",
        /// The tank.
        pub tank: TankParams = TankParams::default(); "-",
        /// The robot's controller.
        pub robot: RobotParams = RobotParams::default(); "-",
        /// The task.
        pub task: TaskParams = TaskParams::default(); "-",
        /// The observation.
        pub observation: ObservationParams = ObservationParams::default(); "-",
    }
}

/// Most frames one episode may last: 24 hours at 25 Hz. An environment reserves its
/// episode's trajectory up front (no allocation per frame), so an absurd length must be
/// refused before anything is allocated (`--minutes 1e9` asked for 1.2 TB).
pub const MAX_EPISODE_FRAMES: u64 = 24 * 3600 * 25;

/// Highest frame rate accepted, in Hz (the tracking systems in use run at 20-100 Hz).
pub const MAX_FRAME_RATE_HZ: f32 = 1000.0;

impl EnvConfig {
    /// Checks every field; errors name the dotted field path and the value.
    pub fn validate(&self) -> Result<(), ConfigError> {
        check::positive("", "frame_rate_hz", self.frame_rate_hz)?;
        if self.frame_rate_hz > MAX_FRAME_RATE_HZ {
            return Err(ConfigError::new(
                "",
                "frame_rate_hz",
                check::shown(self.frame_rate_hz),
                &format!("must be at most {MAX_FRAME_RATE_HZ} Hz"),
            ));
        }
        if self.frames_per_action == 0 {
            return Err(ConfigError::new(
                "",
                "frames_per_action",
                0,
                "must be at least 1",
            ));
        }
        for (f, actions) in [
            (
                "task.training_episode_actions",
                self.task.training_episode_actions,
            ),
            (
                "task.evaluation_episode_actions",
                self.task.evaluation_episode_actions,
            ),
        ] {
            if u64::from(actions) * u64::from(self.frames_per_action) > MAX_EPISODE_FRAMES {
                return Err(ConfigError::new(
                    "",
                    f,
                    actions,
                    &format!(
                        "with {} frames per action an episode would exceed \
                         {MAX_EPISODE_FRAMES} frames (24 hours at 25 Hz)",
                        self.frames_per_action
                    ),
                ));
            }
        }
        if !(1..=MAX_FISH as u32).contains(&self.fish_count) {
            return Err(ConfigError::new(
                "",
                "fish_count",
                self.fish_count,
                &format!("must lie in [1, {MAX_FISH}]"),
            ));
        }
        self.tank.validate("tank")?;
        self.robot.validate("robot")?;
        self.task.validate("task", &Tank::new(&self.tank))?;
        self.observation.validate("observation")
    }

    /// The same configuration in evaluation mode: the lead-to-goal task, whatever objective
    /// a policy was trained for (an OOD policy is evaluated by the goals it reaches; what it
    /// finds is measured by `fishprobe ood-report`).
    pub fn evaluation(mut self) -> Self {
        self.mode = TaskMode::Evaluation;
        self.task.objective = Objective::Goal;
        self
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn an_episode_longer_than_a_day_names_the_task_field_at_fault() {
        let mut c = EnvConfig::default();
        assert!(c.validate().is_ok());
        c.task.training_episode_actions = u32::MAX;
        let e = c.validate().unwrap_err().to_string();
        assert!(
            e.contains("`task.training_episode_actions` = 4294967295") && e.contains("2160000"),
            "{e}"
        );
        let mut c = EnvConfig::default();
        c.task.evaluation_episode_actions = 86_401;
        let e = c.validate().unwrap_err().to_string();
        assert!(
            e.contains("`task.evaluation_episode_actions` = 86401"),
            "{e}"
        );
    }
}
