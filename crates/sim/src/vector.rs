//! Many environments stepped together, in parallel across cores.
//!
//! Autoreset: [`AutoresetMode::SameStep`] (Gymnasium's `SAME_STEP`): when an episode ends in
//! `step`, the environment is reset at once; the returned observation row is the first of the
//! new episode, the last observation of the old one is in [`VecEnv::final_observations`], and
//! its totals in [`VecEnv::finished_episodes`]. Environment `i` is seeded from the master seed
//! by label, and consumes only its own random streams, so results do not depend on the number
//! of threads.

use crate::env::{Env, EnvConfig, EpisodeSummary, TankEnv, Transition};
use crate::error::SimError;
use crate::fish::{FishModel, FishView};
use crate::rng::derive_seed;
use rayon::prelude::*;
use std::sync::Arc;

/// How a vector environment starts new episodes.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum AutoresetMode {
    /// Reset inside the `step` that ended the episode (Gymnasium `SAME_STEP`).
    SameStep,
}

/// `n` copies of [`TankEnv`] with contiguous observation buffers.
#[derive(Debug)]
pub struct VecEnv {
    envs: Vec<TankEnv>,
    obs_dim: usize,
    obs: Vec<f32>,
    final_obs: Vec<f32>,
    transitions: Vec<Transition>,
    finished: Vec<Option<EpisodeSummary>>,
    errors: Vec<Option<SimError>>,
    views: Vec<FishView>,
    inferred: Vec<f32>,
    /// The OOD objective's support scores of `views`, one per fish.
    scores: Vec<f32>,
}

impl VecEnv {
    /// The autoreset behaviour.
    pub const AUTORESET: AutoresetMode = AutoresetMode::SameStep;

    /// `n` environments sharing one model.
    pub fn new(cfg: EnvConfig, model: Arc<dyn FishModel>, n: usize) -> Result<Self, SimError> {
        if n == 0 {
            return Err(SimError::Config(crate::params::ConfigError::new(
                "",
                "num_envs",
                0,
                "must be at least 1",
            )));
        }
        let first = TankEnv::new(cfg, model.clone())?;
        let obs_dim = first.observation_space().dim();
        let fish = first.fish().len();
        let width = model.inference_width();
        let mut envs = Vec::with_capacity(n);
        envs.push(first);
        while envs.len() < n {
            envs.push(envs[0].clone());
        }
        Ok(Self {
            envs,
            obs_dim,
            obs: vec![0.0; n * obs_dim],
            final_obs: vec![0.0; n * obs_dim],
            transitions: vec![Transition::default(); n],
            finished: vec![None; n],
            errors: vec![None; n],
            views: vec![FishView::default(); n * fish],
            inferred: vec![0.0; n * fish * width],
            scores: vec![0.0; n * fish],
        })
    }

    /// Gives every environment the fish model's support model (see
    /// [`TankEnv::set_support`]).
    pub fn set_support(&mut self, support: Option<Arc<dyn crate::InputSupport>>) {
        for e in &mut self.envs {
            e.set_support(support.clone());
        }
    }

    /// Number of environments.
    pub fn num_envs(&self) -> usize {
        self.envs.len()
    }
    /// Observation length of one environment.
    pub fn obs_dim(&self) -> usize {
        self.obs_dim
    }
    /// The environments.
    pub fn envs(&self) -> &[TankEnv] {
        &self.envs
    }
    /// Mutable access, e.g. to switch on recording.
    pub fn envs_mut(&mut self) -> &mut [TankEnv] {
        &mut self.envs
    }
    /// Current observations, `num_envs x obs_dim`, row-major.
    pub fn observations(&self) -> &[f32] {
        &self.obs
    }
    /// For environments whose episode ended in the last step: its last observation.
    pub fn final_observations(&self) -> &[f32] {
        &self.final_obs
    }
    /// The last step's transitions.
    pub fn transitions(&self) -> &[Transition] {
        &self.transitions
    }
    /// Totals of the episodes that ended in the last step (`None` elsewhere).
    pub fn finished_episodes(&self) -> &[Option<EpisodeSummary>] {
        &self.finished
    }

    /// Snapshots of every environment plus the current observations.
    pub fn snapshot(&self) -> (Vec<crate::env::EnvSnapshot>, Vec<f32>) {
        (
            self.envs.iter().map(TankEnv::snapshot).collect(),
            self.obs.clone(),
        )
    }

    /// Continues from [`VecEnv::snapshot`] taken of a vector environment of the same shape.
    pub fn restore(
        &mut self,
        envs: &[crate::env::EnvSnapshot],
        obs: &[f32],
    ) -> Result<(), SimError> {
        if envs.len() != self.envs.len() || obs.len() != self.obs.len() {
            return Err(SimError::StartPoses(format!(
                "snapshot of {} environments does not fit {}",
                envs.len(),
                self.envs.len()
            )));
        }
        for (e, s) in self.envs.iter_mut().zip(envs) {
            e.restore(s)?;
        }
        self.obs.copy_from_slice(obs);
        Ok(())
    }

    /// Resets every environment; environment `i` gets seed `derive_seed(seed, "env", i)`.
    pub fn reset(&mut self, seed: u64) -> Result<&[f32], SimError> {
        let d = self.obs_dim;
        self.envs
            .par_iter_mut()
            .zip(self.obs.par_chunks_mut(d))
            .enumerate()
            .try_for_each(|(i, (env, o))| env.reset(Some(derive_seed(seed, "env", i as u64)), o))?;
        self.finished.iter_mut().for_each(|f| *f = None);
        Ok(&self.obs)
    }

    /// One action per environment (`actions.len() == num_envs`). All actions are checked
    /// before any environment moves, so a bad action leaves every environment untouched.
    pub fn step(&mut self, actions: &[f32]) -> Result<(), SimError> {
        let n = self.envs.len();
        if actions.len() != n {
            return Err(SimError::ActionShape {
                expected: n,
                got: actions.len(),
            });
        }
        if let Some((index, &value)) = actions.iter().enumerate().find(|(_, a)| !a.is_finite()) {
            return Err(SimError::NonFiniteAction { index, value });
        }
        let batched = self.envs[0].model().inference_width() > 0;
        if batched {
            self.step_lockstep(actions)?;
        } else {
            self.step_independent(actions);
        }
        // Every slot is cleared: an error left behind would fail the next, good step.
        let mut first = None;
        for e in &mut self.errors {
            if let Some(e) = e.take() {
                first.get_or_insert(e);
            }
        }
        first.map_or(Ok(()), Err)
    }

    /// Rule-based models: every environment runs its whole action on one core.
    fn step_independent(&mut self, actions: &[f32]) {
        let d = self.obs_dim;
        self.envs
            .par_iter_mut()
            .zip(self.obs.par_chunks_mut(d))
            .zip(self.final_obs.par_chunks_mut(d))
            .zip(actions.par_chunks(1))
            .zip(self.transitions.par_iter_mut())
            .zip(self.finished.par_iter_mut())
            .zip(self.errors.par_iter_mut())
            .for_each(|((((((env, o), fo), a), tr), fin), err)| {
                *fin = None;
                match env.step(a, o) {
                    Ok(t) => {
                        *tr = t;
                        if let Err(e) = Self::autoreset(env, t, o, fo, fin) {
                            *err = Some(e);
                        }
                    }
                    Err(e) => *err = Some(e),
                }
            });
    }

    /// Batched models: the environments are split into one part per core (each of at least
    /// [`MIN_FISH_PER_INFERENCE`] fish), and each part advances its environments frame by
    /// frame together, the model's inference running once per frame over the part's fish. The
    /// parts meet only at the end of the action, not at every frame. A model without
    /// [`FishModel::concurrent_inference`] gets one part.
    fn step_lockstep(&mut self, actions: &[f32]) -> Result<(), SimError> {
        let d = self.obs_dim;
        self.envs
            .par_iter_mut()
            .zip(actions.par_chunks(1))
            .try_for_each(|(env, a)| env.begin_action(a))?;
        let model = self.envs[0].model().clone();
        let lockstep = Lockstep {
            frames: self.envs[0].config().frames_per_action,
            fish: self.envs[0].fish().len(),
            width: model.inference_width(),
            model: &*model,
        };
        let parts = if model.concurrent_inference() {
            rayon::current_num_threads()
        } else {
            1
        };
        let bufs = Buffers {
            views: &mut self.views,
            inferred: &mut self.inferred,
            scores: &mut self.scores,
        };
        lockstep.run(&mut self.envs, bufs, parts)?;
        self.envs
            .par_iter_mut()
            .zip(self.obs.par_chunks_mut(d))
            .zip(self.final_obs.par_chunks_mut(d))
            .zip(self.transitions.par_iter_mut())
            .zip(self.finished.par_iter_mut())
            .try_for_each(|((((env, o), fo), tr), fin)| {
                *fin = None;
                let t = env.end_action(o);
                *tr = t;
                Self::autoreset(env, t, o, fo, fin)
            })
    }

    fn autoreset(
        env: &mut TankEnv,
        t: Transition,
        obs: &mut [f32],
        final_obs: &mut [f32],
        finished: &mut Option<EpisodeSummary>,
    ) -> Result<(), SimError> {
        if t.terminated || t.truncated {
            final_obs.copy_from_slice(obs);
            *finished = Some(env.summary().clone());
            env.reset(None, obs)?;
        }
        Ok(())
    }
}

/// Fewest fish per inference call when the vector environment splits its environments across
/// cores. A fish's inference gives the same bits in any batch where the CPU has AVX2 and FMA
/// (`fishprobe_nn::gemm::fma_chain_gemm`), and elsewhere in any batch of more than 4 fish
/// (sgemm), so with parts this large the split, which follows the number of threads, never
/// changes results.
const MIN_FISH_PER_INFERENCE: usize = 16;

/// One action of a batched model's environments, frame by frame.
struct Lockstep<'m> {
    frames: u32,
    fish: usize,
    width: usize,
    model: &'m dyn FishModel,
}

/// The per-fish buffers of a part of the environments: views, inference outputs
/// (`width` each) and support scores.
struct Buffers<'b> {
    views: &'b mut [FishView],
    inferred: &'b mut [f32],
    scores: &'b mut [f32],
}

impl Lockstep<'_> {
    /// Runs `envs` (with their views, inference and score buffers) through the action's
    /// frames, halved recursively into at most `parts` parts (one per core) that run in
    /// parallel, each of at least [`MIN_FISH_PER_INFERENCE`] fish.
    fn run(&self, envs: &mut [TankEnv], b: Buffers<'_>, parts: usize) -> Result<(), SimError> {
        if parts >= 2 && envs.len() >= 2 && b.views.len() >= 2 * MIN_FISH_PER_INFERENCE {
            let mid = envs.len() / 2;
            let (ea, eb) = envs.split_at_mut(mid);
            let (va, vb) = b.views.split_at_mut(mid * self.fish);
            let (ia, ib) = b.inferred.split_at_mut(mid * self.fish * self.width);
            let (sa, sb) = b.scores.split_at_mut(mid * self.fish);
            let (a, b) = rayon::join(
                || {
                    let bufs = Buffers {
                        views: va,
                        inferred: ia,
                        scores: sa,
                    };
                    self.run(ea, bufs, parts / 2)
                },
                || {
                    let bufs = Buffers {
                        views: vb,
                        inferred: ib,
                        scores: sb,
                    };
                    self.run(eb, bufs, parts - parts / 2)
                },
            );
            return a.and(b);
        }
        for _ in 0..self.frames {
            for (env, v) in envs.iter_mut().zip(b.views.chunks_mut(self.fish)) {
                env.prepare_views();
                v.copy_from_slice(env.views());
            }
            self.model.infer_batch(b.views, b.inferred);
            // The OOD objective: every environment's views scored in one batch when all score
            // this frame with one support (they do: they share it and step in lockstep);
            // otherwise each environment scores its own.
            let shared = envs.first().and_then(|e| e.frame_support()).filter(|s| {
                envs.iter()
                    .all(|e| e.frame_support().is_some_and(|t| Arc::ptr_eq(s, t)))
            });
            let scored = match shared {
                Some(s) => {
                    s.score_batch(b.views, b.scores);
                    for (env, sc) in envs.iter_mut().zip(b.scores.chunks(self.fish)) {
                        env.add_view_scores(sc);
                    }
                    true
                }
                None => false,
            };
            for (env, inf) in envs
                .iter_mut()
                .zip(b.inferred.chunks(self.fish * self.width))
            {
                env.advance_frame(Some(inf), scored)?;
            }
        }
        Ok(())
    }
}
