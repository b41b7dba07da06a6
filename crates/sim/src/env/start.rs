//! How an episode starts: fixed start poses, random poses, the lab's start (milling in the
//! centre, the fish released from a corner), the reset itself, and the snapshot a checkpoint
//! keeps mid-episode and restores.

use super::{EnvSnapshot, EpisodeSummary, StartPoses, TankEnv};
use crate::agent::AgentState;
use crate::error::SimError;
use crate::rng::stream;
use crate::robot::Robot;
use crate::task::{GoalTracker, TaskMode, TrainingStart};
use rand::{Rng, RngExt};
use std::f32::consts::PI;

impl TankEnv {
    /// Uses fixed start poses for the following resets (`None`: random again).
    pub fn set_start_poses(&mut self, poses: Option<StartPoses>) -> Result<(), SimError> {
        if let Some(p) = &poses {
            if p.fish.len() != self.fish.len() {
                return Err(SimError::StartPoses(format!(
                    "{} fish poses for {} fish",
                    p.fish.len(),
                    self.fish.len()
                )));
            }
            let lim = self.tank.half - self.tank.margin;
            for pose in std::iter::once(&p.robot).chain(&p.fish) {
                if !pose.iter().all(|v| v.is_finite()) || pose[0].abs() > lim || pose[1].abs() > lim
                {
                    return Err(SimError::StartPoses(format!(
                        "pose {pose:?} is not a finite pose inside the tank"
                    )));
                }
            }
        }
        self.start_poses = poses;
        Ok(())
    }

    /// The environment's changing state.
    pub fn snapshot(&self) -> EnvSnapshot {
        EnvSnapshot {
            robot: self.robot,
            fish: self.fish.clone(),
            minds: self.minds.clone(),
            fish_rngs: self.fish_rngs.clone(),
            task_rng: self.task_rng.clone(),
            reset_rng: self.reset_rng.clone(),
            goals: self.goals.clone(),
            frame: self.frame,
            prev_bins: self.prev_bins.clone(),
            summary: self.summary.clone(),
            live: self.live,
        }
    }

    /// Continues from a snapshot taken of an environment with the same configuration.
    pub fn restore(&mut self, s: &EnvSnapshot) -> Result<(), SimError> {
        if s.fish.len() != self.fish.len() || s.prev_bins.len() != self.prev_bins.len() {
            return Err(SimError::StartPoses(format!(
                "snapshot of {} fish and {} bins does not fit this environment ({} fish, {} bins)",
                s.fish.len(),
                s.prev_bins.len(),
                self.fish.len(),
                self.prev_bins.len()
            )));
        }
        self.robot = s.robot;
        self.fish.clone_from(&s.fish);
        self.minds.clone_from(&s.minds);
        self.fish_rngs.clone_from(&s.fish_rngs);
        self.task_rng = s.task_rng.clone();
        self.reset_rng = s.reset_rng.clone();
        self.goals = s.goals.clone();
        self.frame = s.frame;
        self.prev_bins.clone_from(&s.prev_bins);
        self.summary = s.summary.clone();
        self.live = s.live;
        Ok(())
    }

    fn random_pose(&mut self) -> AgentState {
        let lim = self.tank.half - self.cfg.task.start_wall_clearance_cm;
        let x = self.task_rng.random_range(-lim..=lim);
        let y = self.task_rng.random_range(-lim..=lim);
        let h = self.task_rng.random_range(-PI..PI);
        AgentState::at(x, y, h)
    }

    /// `training_start = lab`: the robot near the centre, each fish in a corner drawn for it,
    /// headings uniform (as a live trial after habituation).
    fn lab_start(&mut self) {
        let spread = self.cfg.task.lab_start_spread_cm;
        let lim = self.tank.half - self.cfg.task.start_wall_clearance_cm;
        let r = &mut self.task_rng;
        let (x, y) = (
            r.random_range(-0.5..=0.5) * spread,
            r.random_range(-0.5..=0.5) * spread,
        );
        self.robot = Robot::at(x, y, r.random_range(-PI..PI));
        for f in &mut self.fish {
            let (sx, sy) = (
                if r.random::<bool>() { 1.0 } else { -1.0 },
                if r.random::<bool>() { 1.0 } else { -1.0 },
            );
            let x = sx * (lim - r.random_range(0.0..=spread));
            let y = sy * (lim - r.random_range(0.0..=spread));
            *f = AgentState::at(x, y, r.random_range(-PI..PI));
        }
    }

    /// Whether this training episode starts lab-style (`training_start`; with `mixed`, one
    /// draw from the episode's task stream).
    fn lab_start_drawn(&mut self) -> bool {
        match self.cfg.task.training_start {
            TrainingStart::Random => false,
            TrainingStart::Lab => true,
            TrainingStart::Mixed => {
                let share = f64::from(self.cfg.task.lab_start_share);
                self.task_rng.random_bool(share.clamp(0.0, 1.0))
            }
        }
    }

    pub(super) fn reset_state(&mut self, seed: Option<u64>) {
        if let Some(s) = seed {
            self.reset_rng = stream(s, "episodes", 0);
        }
        let episode_seed = self.reset_rng.next_u64();
        self.task_rng = stream(episode_seed, "task", 0);
        for (i, r) in self.fish_rngs.iter_mut().enumerate() {
            *r = stream(episode_seed, "fish", i as u64);
        }
        if let Some(p) = self.start_poses.clone() {
            self.robot = Robot::at(p.robot[0], p.robot[1], p.robot[2]);
            for (f, q) in self.fish.iter_mut().zip(&p.fish) {
                *f = AgentState::at(q[0], q[1], q[2]);
            }
        } else if self.cfg.mode == TaskMode::Training && self.lab_start_drawn() {
            self.lab_start();
        } else {
            let r = self.random_pose();
            self.robot = Robot::at(r.x, r.y, r.heading);
            for i in 0..self.fish.len() {
                self.fish[i] = self.random_pose();
            }
        }
        for ((f, m), r) in self
            .fish
            .iter()
            .zip(&mut self.minds)
            .zip(&mut self.fish_rngs)
        {
            self.model.begin_episode(f, m, r);
        }
        self.goals = GoalTracker::start(
            self.cfg.mode,
            &self.cfg.task,
            &self.tank,
            &self.fish,
            &mut self.task_rng,
        );
        self.frame = 0;
        self.summary = EpisodeSummary::default();
        self.summary.goal_events.reserve(64);
        if self.recording {
            let actions = self.episode_actions() as usize;
            let frames = actions * self.cfg.frames_per_action as usize + 1;
            let t = &mut self.trajectory;
            t.frame_rate_hz = self.cfg.frame_rate_hz;
            t.robot.clear();
            t.robot.reserve(frames);
            t.fish.resize_with(self.fish.len(), Vec::new);
            for f in &mut t.fish {
                f.clear();
                f.reserve(frames);
            }
            t.active_goal.clear();
            t.active_goal.reserve(frames);
            t.commands.clear();
            t.commands.reserve(actions);
            t.individuals.clear();
            t.individuals
                .extend(self.minds.iter().map(|m| m.individual));
            self.record_frame();
        }
        self.live = true;
    }
}
