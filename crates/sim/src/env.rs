//! The Gymnasium-style environment: one robot, `fish_count` fish driven by a [`FishModel`],
//! the lead-to-goal task, and the 180-float observation.
//!
//! `reset(seed)` then `step(action)` until `truncated` (the time limit; the task never
//! `terminated`s). Observations are written into caller-owned buffers so that stepping never
//! allocates.

use crate::agent::AgentState;
use crate::error::SimError;
use crate::fish::{FishMind, FishModel, FishView, MAX_FISH};
use crate::geometry::{Tank, TankParams};
use crate::observation::{ObservationEncoder, ObservationParams, Scene};
use crate::params::{check, ConfigError};
use crate::rng::{stream, SimRng};
use crate::robot::{Robot, RobotParams};
use crate::script::{advance_scripted, RobotScript, ScriptParams};
use crate::support::InputSupport;
use crate::task::{GoalEvent, GoalTracker, Objective, TaskMode, TaskParams};
use std::f32::consts::PI;
use std::sync::Arc;

mod config;
mod contract;
mod records;
mod start;

pub use config::*;
pub use contract::*;
pub use records::*;

/// Everything that changes while an environment runs (not its configuration or model): enough
/// to continue an interrupted run exactly (checkpoints).
#[derive(Debug, Clone, PartialEq, serde::Serialize, serde::Deserialize)]
pub struct EnvSnapshot {
    robot: Robot,
    fish: Vec<AgentState>,
    minds: Vec<FishMind>,
    fish_rngs: Vec<SimRng>,
    task_rng: SimRng,
    reset_rng: SimRng,
    goals: GoalTracker,
    frame: u32,
    prev_bins: Vec<f32>,
    summary: EpisodeSummary,
    live: bool,
}

/// The RoboFish tank as a reinforcement-learning environment.
#[derive(Debug, Clone)]
pub struct TankEnv {
    cfg: EnvConfig,
    tank: Tank,
    dt: f32,
    model: Arc<dyn FishModel>,
    encoder: ObservationEncoder,
    obs_space: BoxSpace,
    act_space: BoxSpace,
    robot: Robot,
    fish: Vec<AgentState>,
    minds: Vec<FishMind>,
    fish_rngs: Vec<SimRng>,
    task_rng: SimRng,
    reset_rng: SimRng,
    goals: GoalTracker,
    frame: u32,
    prev_bins: Vec<f32>,
    views: Vec<FishView>,
    inferred: Vec<f32>,
    acc: StepInfo,
    /// The fish model's support, scored every frame with the OOD objective.
    support: Option<Arc<dyn InputSupport>>,
    /// Sums over the current action: capped scores, uncapped scores, samples.
    support_acc: (f32, f32, u32),
    /// Distance of the fish nearest the active goal when the current action began (cm), for
    /// the progress shaping ([`crate::TaskParams::progress_shaping`]).
    shaping_from_cm: f32,
    summary: EpisodeSummary,
    start_poses: Option<StartPoses>,
    recording: bool,
    trajectory: Trajectory,
    live: bool,
}

impl TankEnv {
    /// A new environment; validates the configuration. Call `reset` before `step`.
    pub fn new(cfg: EnvConfig, model: Arc<dyn FishModel>) -> Result<Self, SimError> {
        cfg.validate()?;
        let n_fish = cfg.fish_count as usize;
        let encoder = ObservationEncoder::new(&cfg.observation);
        let width = model.inference_width();
        Ok(Self {
            tank: Tank::new(&cfg.tank),
            dt: 1.0 / cfg.frame_rate_hz,
            obs_space: BoxSpace::uniform(encoder.size(), 0.0, 1.0),
            act_space: BoxSpace::uniform(1, -PI, PI),
            prev_bins: vec![0.0; encoder.history_len()],
            encoder,
            model,
            robot: Robot::default(),
            fish: vec![AgentState::default(); n_fish],
            minds: vec![FishMind::default(); n_fish],
            fish_rngs: (0..n_fish as u64).map(|i| stream(0, "fish", i)).collect(),
            task_rng: stream(0, "task", 0),
            reset_rng: stream(0, "episodes", 0),
            goals: GoalTracker {
                active: [0.0, 0.0],
                index: 0,
            },
            frame: 0,
            views: vec![FishView::default(); n_fish],
            inferred: vec![0.0; width * n_fish],
            acc: StepInfo::default(),
            support: None,
            support_acc: (0.0, 0.0, 0),
            shaping_from_cm: 0.0,
            summary: EpisodeSummary::default(),
            start_poses: None,
            recording: false,
            trajectory: Trajectory::default(),
            live: false,
            cfg,
        })
    }

    /// Gives the environment the fish model's support model, which the OOD objective
    /// (`task.objective = ood`) scores every frame with; without one, stepping an OOD
    /// environment is an error.
    pub fn set_support(&mut self, support: Option<Arc<dyn InputSupport>>) {
        self.support = support;
    }

    /// Draws the fish's noise from now on from streams of `seed` (label `"fish"`, one per fish)
    /// instead of the episode's: for a planner that steps a clone of the environment to
    /// imagine futures, so that it knows the fish's state and model but not the noise the real
    /// episode will draw (`fishprobe-learn`'s `ood_planner` example).
    pub fn reseed_fish_noise(&mut self, seed: u64) {
        for (i, r) in self.fish_rngs.iter_mut().enumerate() {
            *r = stream(seed, "fish", i as u64);
        }
    }

    /// The validated configuration.
    pub fn config(&self) -> &EnvConfig {
        &self.cfg
    }
    /// The fish model.
    pub fn model(&self) -> &Arc<dyn FishModel> {
        &self.model
    }
    /// The tank geometry.
    pub fn tank(&self) -> &Tank {
        &self.tank
    }
    /// The robot.
    pub fn robot(&self) -> &Robot {
        &self.robot
    }
    /// The fish.
    pub fn fish(&self) -> &[AgentState] {
        &self.fish
    }
    /// Centre of the active goal.
    pub fn active_goal(&self) -> [f32; 2] {
        self.goals.active
    }
    /// Frames since the episode start.
    pub fn frame(&self) -> u32 {
        self.frame
    }
    /// Totals of the current episode.
    pub fn summary(&self) -> &EpisodeSummary {
        &self.summary
    }
    /// Records every frame of the following episodes (memory is reserved at reset).
    pub fn set_recording(&mut self, on: bool) {
        self.recording = on;
    }
    /// The recorded current episode, if recording is on.
    pub fn trajectory(&self) -> Option<&Trajectory> {
        self.recording.then_some(&self.trajectory)
    }
    /// Actions per episode.
    pub fn episode_actions(&self) -> u32 {
        self.cfg.task.episode_actions(self.cfg.mode)
    }

    fn record_frame(&mut self) {
        let r = &self.robot.state;
        self.trajectory.robot.push([r.x, r.y, r.heading]);
        for (track, f) in self.trajectory.fish.iter_mut().zip(&self.fish) {
            track.push([f.x, f.y, f.heading]);
        }
        self.trajectory.active_goal.push(self.goals.active);
    }

    fn encode(&mut self, first: bool, obs: &mut [f32]) {
        let scene = Scene {
            tank: &self.tank,
            robot: &self.robot.state,
            fish: &self.fish,
            goal: self.goals.active,
        };
        self.encoder.encode(scene, &mut self.prev_bins, first, obs);
    }

    fn check_obs(&self, obs: &[f32]) -> Result<(), SimError> {
        if obs.len() == self.encoder.size() {
            Ok(())
        } else {
            Err(SimError::ObservationShape {
                expected: self.encoder.size(),
                got: obs.len(),
            })
        }
    }

    /// First part of a step: validates and applies the action to the robot's controller.
    pub(crate) fn begin_action(&mut self, action: &[f32]) -> Result<(), SimError> {
        if !self.live {
            return Err(SimError::NeedsReset);
        }
        if action.len() != 1 {
            return Err(SimError::ActionShape {
                expected: 1,
                got: action.len(),
            });
        }
        let a = action[0];
        if !a.is_finite() {
            return Err(SimError::NonFiniteAction { index: 0, value: a });
        }
        if self.cfg.task.objective == Objective::Ood && self.support.is_none() {
            return Err(SimError::NoSupport {
                model: self.model.name().to_string(),
            });
        }
        let turn = a.clamp(-PI, PI);
        self.robot.begin_action(turn);
        if self.recording {
            self.trajectory.commands.push(RecordedCommand {
                frame: self.frame,
                turn,
            });
        }
        self.acc = StepInfo::default();
        self.support_acc = (0.0, 0.0, 0);
        if self.shaping() {
            self.shaping_from_cm = self.fish_to_goal_cm();
        }
        Ok(())
    }

    /// Whether this episode's reward has the progress shaping (training, lead-to-goal task).
    fn shaping(&self) -> bool {
        let t = &self.cfg.task;
        t.progress_shaping > 0.0
            && t.objective == Objective::Goal
            && self.cfg.mode == TaskMode::Training
    }

    /// Distance of the fish nearest the active goal (cm).
    fn fish_to_goal_cm(&self) -> f32 {
        let [gx, gy] = self.goals.active;
        self.fish
            .iter()
            .map(|f| (f.x - gx).hypot(f.y - gy))
            .fold(f32::INFINITY, f32::min)
    }

    /// What each fish perceives at the start of the coming frame (into the env's buffer).
    pub(crate) fn prepare_views(&mut self) {
        let time_s = self.frame as f32 * self.dt;
        let leading = [self.robot.state];
        for i in 0..self.fish.len() {
            self.views[i].rebuild(i, &self.fish, &leading, self.tank, self.dt, time_s);
            self.views[i].individual = self.minds[i].individual;
        }
    }

    /// The views prepared for the coming frame.
    pub(crate) fn views(&self) -> &[FishView] {
        &self.views
    }

    /// One frame, with the views already prepared and (for batched models) `inferred` holding
    /// `inference_width` floats per fish. `scored`: the frame's views were scored by the
    /// caller ([`TankEnv::add_view_scores`]), so the frame does not score them again.
    pub(crate) fn advance_frame(
        &mut self,
        inferred: Option<&[f32]>,
        scored: bool,
    ) -> Result<(), SimError> {
        self.advance_frame_with(inferred, None, scored)
    }

    /// The support that scores the coming frame's views, if the frame is scored (the OOD
    /// objective, on every `ood_score_every_frames`-th frame).
    pub(crate) fn frame_support(&self) -> Option<&Arc<dyn InputSupport>> {
        let t = &self.cfg.task;
        let scored =
            t.objective == Objective::Ood && self.frame.is_multiple_of(t.ood_score_every_frames);
        self.support.as_ref().filter(|_| scored)
    }

    /// Adds the support scores of the coming frame's views (one per fish, in order) to the
    /// action's OOD reward.
    pub(crate) fn add_view_scores(&mut self, scores: &[f32]) {
        let t = &self.cfg.task;
        for &score in scores {
            self.support_acc.0 += (score.min(t.ood_score_cap) - t.ood_score_floor).max(0.0);
            self.support_acc.1 += score;
            self.support_acc.2 += 1;
        }
    }

    /// One frame; the robot follows `script` instead of its controller when given.
    fn advance_frame_with(
        &mut self,
        inferred: Option<&[f32]>,
        script: Option<(RobotScript, &ScriptParams)>,
        scored: bool,
    ) -> Result<(), SimError> {
        if !scored {
            if let Some(s) = self.frame_support().cloned() {
                // What the fish see at the start of this frame (the inputs the model acts on),
                // scored in one batch (a stack buffer: no allocation per frame).
                let mut scores = [0.0f32; MAX_FISH];
                let n = self.views.len();
                s.score_batch(&self.views, &mut scores[..n]);
                self.add_view_scores(&scores[..n]);
            }
        }
        let p = &self.cfg;
        let contact = match script {
            None => self.robot.advance(&p.robot, &self.tank, self.dt),
            Some((s, sp)) => advance_scripted(
                &mut self.robot,
                s,
                sp,
                self.goals.active,
                &self.tank,
                self.dt,
            ),
        };
        if contact {
            self.acc.robot_wall_contacts += 1;
        }
        let inferred = inferred.unwrap_or(&self.inferred);
        match crate::fish::step_fish(
            self.model.as_ref(),
            &self.views,
            inferred,
            &mut self.minds,
            &mut self.fish_rngs,
            &mut self.fish,
            &self.tank,
            self.dt,
            self.frame,
        ) {
            Ok(contacts) => self.acc.fish_wall_contacts += contacts,
            Err(e) => {
                self.live = false;
                return Err(e);
            }
        }
        self.frame += 1;
        if let Some(goal) = self.goals.check_with_robot(
            p.mode,
            &p.task,
            &self.tank,
            &self.fish,
            Some(&self.robot.state),
            &mut self.task_rng,
        ) {
            self.acc.goals_reached += 1;
            self.summary.goal_events.push(GoalEvent {
                frame: self.frame,
                goal,
            });
        }
        let r = &self.robot.state;
        if self.tank.wall_distance(r.x, r.y) < p.task.wall_penalty_distance_cm {
            self.acc.robot_near_wall = true;
        }
        if self.recording {
            self.record_frame();
        }
        Ok(())
    }

    /// Last part of a step: reward, observation, time limit.
    pub(crate) fn end_action(&mut self, obs: &mut [f32]) -> Transition {
        let t = &self.cfg.task;
        let goals = t.goal_reward * self.acc.goals_reached as f32;
        let mut reward = match t.objective {
            Objective::Goal => goals,
            Objective::Ood => {
                let (capped, raw, n) = self.support_acc;
                let n = n.max(1) as f32;
                self.acc.support_score = raw / n;
                t.ood_weight * capped / n + t.ood_goal_weight * goals
            }
        };
        if self.shaping() {
            // Potential Φ = -d / L (L the tank's side); a reached goal ends its potential at 0.
            let to = if self.acc.goals_reached > 0 {
                0.0
            } else {
                self.fish_to_goal_cm()
            };
            let side = 2.0 * self.cfg.tank.half_size_cm;
            reward +=
                t.progress_shaping * (self.shaping_from_cm - t.progress_shaping_gamma * to) / side;
        }
        if self.acc.robot_near_wall {
            reward -= t.wall_penalty;
        }
        self.acc.frame = self.frame;
        self.summary.actions += 1;
        self.summary.episode_return += reward;
        self.summary.robot_wall_contacts += self.acc.robot_wall_contacts;
        self.summary.fish_wall_contacts += self.acc.fish_wall_contacts;
        self.encode(false, obs);
        let truncated = self.summary.actions >= self.episode_actions();
        if truncated {
            self.live = false;
        }
        Transition {
            reward,
            terminated: false,
            truncated,
            info: self.acc,
        }
    }

    /// Runs the frames of one action sequentially (the non-batched path).
    fn run_frames(&mut self, script: Option<(RobotScript, &ScriptParams)>) -> Result<(), SimError> {
        let width = self.model.inference_width();
        for _ in 0..self.cfg.frames_per_action {
            self.prepare_views();
            if width > 0 {
                self.model.infer_batch(&self.views, &mut self.inferred);
            }
            self.advance_frame_with(None, script, false)?;
        }
        Ok(())
    }

    /// One action period (`frames_per_action` frames) with a scripted robot instead of the
    /// controller; reward and observation as in `step`. No command is recorded.
    pub fn step_scripted(
        &mut self,
        script: RobotScript,
        params: &ScriptParams,
        obs: &mut [f32],
    ) -> Result<Transition, SimError> {
        self.check_obs(obs)?;
        if !self.live {
            return Err(SimError::NeedsReset);
        }
        params.validate("script")?;
        if self.cfg.task.objective == Objective::Ood && self.support.is_none() {
            return Err(SimError::NoSupport {
                model: self.model.name().to_string(),
            });
        }
        self.acc = StepInfo::default();
        self.support_acc = (0.0, 0.0, 0);
        self.run_frames(Some((script, params)))?;
        Ok(self.end_action(obs))
    }
}

impl Env for TankEnv {
    fn observation_space(&self) -> &BoxSpace {
        &self.obs_space
    }

    fn action_space(&self) -> &BoxSpace {
        &self.act_space
    }

    fn max_episode_steps(&self) -> u32 {
        self.episode_actions()
    }

    fn reset(&mut self, seed: Option<u64>, obs: &mut [f32]) -> Result<(), SimError> {
        self.check_obs(obs)?;
        self.reset_state(seed);
        self.encode(true, obs);
        Ok(())
    }

    fn step(&mut self, action: &[f32], obs: &mut [f32]) -> Result<Transition, SimError> {
        self.check_obs(obs)?;
        self.begin_action(action)?;
        self.run_frames(None)?;
        Ok(self.end_action(obs))
    }
}
