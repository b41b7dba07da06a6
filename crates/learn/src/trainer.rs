//! A training run on disk (its names: [`crate::run::RunLayout`]): `params.json` (the resolved
//! configuration), `progress.csv` and `result.json` (one JSON object per iteration),
//! `checkpoints/` and, at the end,
//! `policy.safetensors`. A run interrupted at any moment resumes from its last checkpoint and
//! ends exactly where an uninterrupted run with the same seed ends: a checkpoint holds the
//! networks, Adam's moments, the KL coefficient, the sampling RNG and every environment's
//! state mid-episode.

use crate::config::PpoConfig;
use crate::error::LearnError;
use crate::policy::GaussianPolicy;
use crate::ppo::{adapt_kl, collect, update, Rollout, Scratch, UpdateStats};
use fishprobe_io::RunLayout;
use fishprobe_models::ModelSpec;
use fishprobe_nn::store::write_atomic;
use fishprobe_nn::Adam;
use fishprobe_sim::{
    derive_seed, stream, EnvConfig, FishModel, Objective, SimRng, TaskMode, VecEnv,
};
use serde::{Deserialize, Serialize};
use std::path::{Path, PathBuf};
use std::sync::Arc;
use std::time::Instant;

mod checkpoint;
mod log;
use checkpoint::latest_checkpoint;
pub use checkpoint::MAX_STATE_BYTES;
use log::CSV_HEADER;
pub use log::{IterationStats, MAX_LOG_LINE_BYTES};

/// What a run is: everything `params.json` records.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct RunSpec {
    /// PPO settings.
    pub ppo: PpoConfig,
    /// The environment (training mode).
    pub env: EnvConfig,
    /// The fish model the policy is trained against.
    pub model: ModelSpec,
    /// Master seed.
    pub seed: u64,
    /// The preset the settings came from.
    pub preset: String,
    /// fishprobe version that started the run.
    pub program_version: String,
    /// The build that started the run, as `fishprobe --version` prints it (the version and the
    /// git commit); empty in runs started before it was recorded. Provenance only: a resumed
    /// run continues under the trainer's revision, not the build.
    #[serde(default)]
    pub program_build: String,
    /// The trainer's revision ([`crate::TRAINER_REVISION`]) that started the run; 0 in runs
    /// started before it was recorded (revisions 1 and 2). A run of another revision is not
    /// resumed: its updates so far were made by a trainer whose fixes the current one has.
    #[serde(default)]
    pub trainer_revision: u32,
}

impl RunSpec {
    /// A run of `model` with these settings, seed and preset, started by the program build
    /// `build` (what `fishprobe --version` prints) with this fishprobe's version and trainer
    /// revision.
    pub fn new(
        model: ModelSpec,
        ppo: PpoConfig,
        env: EnvConfig,
        seed: u64,
        preset: impl Into<String>,
        build: impl Into<String>,
    ) -> Self {
        Self {
            ppo,
            env,
            model,
            seed,
            preset: preset.into(),
            program_version: env!("CARGO_PKG_VERSION").into(),
            program_build: build.into(),
            trainer_revision: crate::TRAINER_REVISION,
        }
    }

    /// Checks the run before anything is written: the PPO and environment settings, and, for
    /// the OOD task, that the fish model's support file exists and belongs to its weights (the
    /// reward scores the fish's views against it). `Trainer::create` checks the same; callers
    /// check first so that a refused run leaves no directory behind.
    pub fn check(&self) -> Result<(), LearnError> {
        self.check_settings()?;
        if self.env.task.objective == Objective::Ood {
            self.model.ood_scorer(self.env.task.ood_score)?;
        }
        Ok(())
    }

    /// The settings alone (PPO, environment, and the shaping's discount against PPO's), what
    /// [`RunSpec::check`] and [`Trainer::create`] both check.
    fn check_settings(&self) -> Result<(), LearnError> {
        self.ppo.validate()?;
        self.env.validate()?;
        shaping_matches(&self.ppo, &self.env)?;
        Ok(())
    }

    /// Whether `self` and `other` describe the same run: equal in everything but the program
    /// version and build that started them (a run started by one build and finished by another
    /// of the same trainer revision is one run; the revision is compared).
    pub fn same_run(&self, other: &RunSpec) -> bool {
        RunSpec {
            program_version: other.program_version.clone(),
            program_build: other.program_build.clone(),
            ..self.clone()
        } == *other
    }

    /// An error when the run was started by another trainer revision than this fishprobe's:
    /// continuing it would mix two trainers' updates in one policy.
    pub fn check_revision(&self, dir: &Path) -> Result<(), LearnError> {
        if self.trainer_revision == crate::TRAINER_REVISION {
            return Ok(());
        }
        let started = match self.trainer_revision {
            0 => "a fishprobe that did not record its trainer's revision (1 or 2)".to_string(),
            r => format!("trainer revision {r}"),
        };
        let build = match self.program_build.as_str() {
            "" => String::new(),
            b => format!(" (fishprobe {b})"),
        };
        Err(run_err(
            &dir.join(RunLayout::PARAMS),
            format!(
                "the run was started by {started}{build}; this fishprobe's trainer is revision \
                 {}, whose fixes make the earlier updates wrong, so it does not continue them: \
                 finish the run with the fishprobe that started it, or train it again (in \
                 another folder, or delete this one)",
                crate::TRAINER_REVISION
            ),
        ))
    }
}

/// A PPO run in progress.
pub struct Trainer {
    dir: PathBuf,
    spec: RunSpec,
    venv: VecEnv,
    policy: GaussianPolicy,
    adam_pi: Adam,
    adam_vf: Adam,
    kl_coeff: f32,
    rng: SimRng,
    iteration: u64,
    timesteps: u64,
    episodes: u64,
    roll: Rollout,
    scratch: Scratch,
    /// The build that makes the iterations from now on: the run's own when created, the
    /// resuming one when resumed ([`Trainer::resume`]).
    build: String,
}

fn run_err(path: &Path, what: impl std::fmt::Display) -> LearnError {
    LearnError::Run(format!("{}: {what}", path.display()))
}

/// Refuses progress shaping (`task.progress_shaping` > 0, lead-to-goal task) whose discount
/// is not the learner's: potential-based shaping leaves the goal reward's optimal policies
/// unchanged only when its potential is discounted as the learner discounts (Ng et al. 1999).
pub fn shaping_matches(ppo: &PpoConfig, env: &EnvConfig) -> Result<(), fishprobe_sim::ConfigError> {
    let t = &env.task;
    if t.progress_shaping > 0.0
        && t.objective == Objective::Goal
        && t.progress_shaping_gamma != ppo.gamma
    {
        return Err(fishprobe_sim::ConfigError::new(
            "env.task",
            "progress_shaping_gamma",
            t.progress_shaping_gamma,
            &format!(
                "differs from the PPO discount gamma = {}: the progress shaping leaves the \
                 optimal policies unchanged only when they match; set \
                 `progress_shaping_gamma = {}` where the shaping is turned on",
                ppo.gamma, ppo.gamma
            ),
        ));
    }
    Ok(())
}

impl Trainer {
    /// Starts a new run in `dir` (which must not hold one).
    pub fn create(dir: &Path, spec: RunSpec) -> Result<Self, LearnError> {
        let model = spec.model.build()?;
        Self::create_with_model(dir, spec, model)
    }

    /// [`Trainer::create`] with the fish model given rather than built from `spec.model`,
    /// which then only records what it is: a model that only its caller can build (a fish
    /// model written in Python, `ModelSpec::Python`).
    pub fn create_with_model(
        dir: &Path,
        mut spec: RunSpec,
        model: Arc<dyn FishModel>,
    ) -> Result<Self, LearnError> {
        // A new run is always this trainer's.
        spec.trainer_revision = crate::TRAINER_REVISION;
        spec.env.mode = TaskMode::Training;
        spec.check_settings()?;
        Self::ensure_new(dir)?;
        let mut t = Self::build(dir, spec, model)?;
        t.venv.reset(derive_seed(t.spec.seed, "envs", 0))?;
        let params = serde_json::to_string_pretty(&t.spec).map_err(|e| run_err(dir, e))?;
        write_atomic(&dir.join(RunLayout::PARAMS), params.as_bytes())?;
        write_atomic(
            &dir.join(RunLayout::PROGRESS),
            format!("{CSV_HEADER}\n").as_bytes(),
        )?;
        write_atomic(&dir.join(RunLayout::RESULT), b"")?;
        Ok(t)
    }

    /// An error when `dir` already holds a training run: what [`Trainer::create`] refuses, for
    /// a caller that must know before work of its own (e.g. measuring an OOD yardstick).
    pub fn ensure_new(dir: &Path) -> Result<(), LearnError> {
        if dir.join(RunLayout::PARAMS).exists() {
            return Err(run_err(
                dir,
                "already holds a training run: resume it, or train in another folder",
            ));
        }
        Ok(())
    }

    fn build(dir: &Path, spec: RunSpec, model: Arc<dyn FishModel>) -> Result<Self, LearnError> {
        let mut venv = VecEnv::new(spec.env.clone(), model, spec.ppo.num_envs)?;
        if spec.env.task.objective == Objective::Ood {
            // The OOD reward scores the fish's views against the model's training support
            // (or its ensemble's disagreement).
            venv.set_support(Some(spec.model.ood_scorer(spec.env.task.ood_score)?));
        }
        let obs_dim = venv.obs_dim();
        let policy =
            GaussianPolicy::new(obs_dim, &spec.ppo, &mut stream(spec.seed, "policy-init", 0));
        let adam_pi = Adam::new(policy.pi.num_params(), spec.ppo.lr);
        let adam_vf = Adam::new(policy.vf.num_params(), spec.ppo.lr);
        let steps = spec.ppo.train_batch_size / spec.ppo.num_envs;
        Ok(Self {
            dir: dir.to_path_buf(),
            roll: Rollout::new(spec.ppo.num_envs, steps, obs_dim),
            kl_coeff: spec.ppo.kl_coeff,
            rng: stream(spec.seed, "ppo-sampling", 0),
            build: spec.program_build.clone(),
            spec,
            venv,
            policy,
            adam_pi,
            adam_vf,
            iteration: 0,
            timesteps: 0,
            episodes: 0,
            scratch: Scratch::default(),
        })
    }

    /// Continues the run in `dir` from its last checkpoint (from the start when it has none),
    /// with the program build `build` (what `fishprobe --version` prints) making the
    /// iterations from now on: each line of `result.json` names the build that made it, while
    /// `params.json` keeps the one that started the run.
    pub fn resume(dir: &Path, build: &str) -> Result<Self, LearnError> {
        let spec = Self::recorded_spec(dir)?;
        let model = spec.model.build()?;
        Self::resume_spec(dir, spec, model, build)
    }

    /// [`Trainer::resume`] with the fish model given (see [`Trainer::create_with_model`]).
    pub fn resume_with_model(
        dir: &Path,
        model: Arc<dyn FishModel>,
        build: &str,
    ) -> Result<Self, LearnError> {
        Self::resume_spec(dir, Self::recorded_spec(dir)?, model, build)
    }

    /// Raises the step budget of the run in `dir` to `total_timesteps`, in its `params.json`,
    /// so that the next [`Trainer::resume`] trains on to it: how a finished run is given more
    /// steps. Returns the budget it had.
    ///
    /// At a constant learning rate nothing a run computes depends on its budget but when it
    /// stops, so a run raised from N to M steps ends exactly where a run of M steps from the
    /// start ends, and `params.json`, recording M, stays true. What makes that false is
    /// refused: a lower budget (the run may have trained past it; start a new run), a run
    /// of another trainer revision ([`RunSpec::check_revision`]), and a learning-rate
    /// schedule (`lr_final`), which anneals over the budget and so would have taken other
    /// rates for the steps already done. The caller holds the directory's lock.
    pub fn raise_budget(dir: &Path, total_timesteps: u64) -> Result<u64, LearnError> {
        let mut spec = Self::recorded_spec(dir)?;
        spec.check_revision(dir)?;
        let params = dir.join(RunLayout::PARAMS);
        let had = spec.ppo.total_timesteps;
        if total_timesteps == had {
            return Ok(had);
        }
        // A budget no run may have (0, or past the cap) is refused as such first, so the
        // advice below never names a command that would itself be refused.
        let mut raised = spec.ppo.clone();
        raised.total_timesteps = total_timesteps;
        raised.validate()?;
        if total_timesteps < had {
            return Err(run_err(
                &params,
                format!(
                    "the run's budget is {had} steps, and resuming can only raise it, not lower \
                     it to {total_timesteps} (the run may have trained past that): train a new \
                     run of {total_timesteps} steps instead"
                ),
            ));
        }
        if let Some(end) = spec.ppo.lr_final {
            return Err(run_err(
                &params,
                format!(
                    "the run anneals its learning rate from {} to {end} over its {had} steps \
                     (`lr_final`), so a budget of {total_timesteps} would have given the steps \
                     already taken other rates: train a new run of {total_timesteps} steps \
                     instead",
                    spec.ppo.lr
                ),
            ));
        }
        spec.ppo = raised;
        let text = serde_json::to_string_pretty(&spec).map_err(|e| run_err(&params, e))?;
        write_atomic(&params, text.as_bytes())?;
        Ok(had)
    }

    /// The settings `dir`'s `params.json` records.
    pub fn recorded_spec(dir: &Path) -> Result<RunSpec, LearnError> {
        let params = dir.join(RunLayout::PARAMS);
        // Bounded: `ood-report --policy P` reads the params.json of a directory a user names.
        let text = fishprobe_io::read_small_text(&params)
            .map_err(|e| run_err(&params, format!("cannot resume: {e}")))?;
        serde_json::from_str(&text)
            .map_err(|e| run_err(&params, format!("not a run's parameters: {e}")))
    }

    fn resume_spec(
        dir: &Path,
        spec: RunSpec,
        model: Arc<dyn FishModel>,
        build: &str,
    ) -> Result<Self, LearnError> {
        spec.check_revision(dir)?;
        spec.ppo.validate()?;
        let mut t = Self::build(dir, spec, model)?;
        build.clone_into(&mut t.build);
        match latest_checkpoint(dir)? {
            Some(ckpt) => t.load_checkpoint(&ckpt)?,
            None => t
                .venv
                .reset(derive_seed(t.spec.seed, "envs", 0))
                .map(|_| ())?,
        }
        t.truncate_logs()?;
        Ok(t)
    }

    /// The run's settings.
    pub fn spec(&self) -> &RunSpec {
        &self.spec
    }
    /// Iterations done.
    pub fn iteration(&self) -> u64 {
        self.iteration
    }
    /// Steps done.
    pub fn timesteps(&self) -> u64 {
        self.timesteps
    }
    /// Whether the step budget is reached.
    pub fn done(&self) -> bool {
        self.timesteps >= self.spec.ppo.total_timesteps
    }
    /// The current policy.
    pub fn policy(&self) -> &GaussianPolicy {
        &self.policy
    }

    /// One iteration: collect, update, log; checkpoints on schedule and at the end.
    pub fn iterate(&mut self) -> Result<IterationStats, LearnError> {
        let started = Instant::now();
        let iteration = self.iteration + 1;
        let finished = collect(
            &self.spec.ppo,
            &mut self.venv,
            &self.policy,
            &mut self.roll,
            &mut self.rng,
            &mut self.scratch,
        )
        .map_err(|e| match e {
            // A finite policy never proposes a NaN action: the networks have diverged.
            fishprobe_sim::SimError::NonFiniteAction { .. } => LearnError::Diverged {
                iteration,
                what: format!("the policy proposed a non-finite action ({e})"),
            },
            other => other.into(),
        })?;
        let lr = self.spec.ppo.lr_at(self.timesteps);
        (self.adam_pi.lr, self.adam_vf.lr) = (lr, lr);
        let u: UpdateStats = update(
            &self.spec.ppo,
            &mut self.policy,
            &mut self.adam_pi,
            &mut self.adam_vf,
            self.kl_coeff,
            &mut self.roll,
            &mut self.rng,
            &mut self.scratch,
        )
        .map_err(|e| LearnError::Diverged {
            iteration,
            what: e.to_string(),
        })?;
        if self
            .policy
            .pi
            .params()
            .iter()
            .chain(self.policy.vf.params())
            .any(|v| !v.is_finite())
        {
            return Err(LearnError::Diverged {
                iteration,
                what: "non-finite network weights".into(),
            });
        }
        self.kl_coeff = adapt_kl(self.kl_coeff, u.kl, self.spec.ppo.kl_target);
        self.iteration = iteration;
        self.timesteps += self.roll.len() as u64;
        self.episodes += finished.len() as u64;
        let returns: Vec<f32> = finished.iter().map(|f| f.0).collect();
        let n = returns.len().max(1) as f32;
        let time_s = started.elapsed().as_secs_f64();
        let stats = IterationStats {
            iteration,
            timesteps: self.timesteps,
            episodes_total: self.episodes,
            episodes: finished.len() as u64,
            episode_return_mean: if returns.is_empty() {
                f32::NAN
            } else {
                returns.iter().sum::<f32>() / n
            },
            episode_return_min: returns.iter().copied().fold(f32::NAN, f32::min),
            episode_return_max: returns.iter().copied().fold(f32::NAN, f32::max),
            goals_per_episode: if finished.is_empty() {
                f32::NAN
            } else {
                finished.iter().map(|f| f.1 as f32).sum::<f32>() / n
            },
            policy_loss: u.policy_loss,
            value_loss: u.vf_loss,
            kl: u.kl,
            kl_coeff: self.kl_coeff,
            entropy: u.entropy,
            clip_frac: u.clip_frac,
            action_clip_frac: u.action_clip_frac,
            vf_explained_var: u.vf_explained_var,
            vf_explained_var_fit: u.vf_explained_var_fit,
            time_s,
            steps_per_s: self.roll.len() as f64 / time_s.max(1e-9),
            build: self.build.clone(),
        };
        self.append_logs(&stats)?;
        if iteration.is_multiple_of(self.spec.ppo.checkpoint_every as u64) || self.done() {
            self.save_checkpoint()?;
        }
        Ok(stats)
    }

    /// Writes the final policy to `dir/policy.safetensors`.
    pub fn finish(&self) -> Result<PathBuf, LearnError> {
        self.policy.save(&self.dir, self.about())
    }
}

/// Observation length of an environment configuration (for checking policies).
pub fn obs_dim(env: &EnvConfig) -> usize {
    env.observation.size()
}

#[cfg(test)]
mod tests {
    use super::*;

    /// A smoke run of `iterations` iterations (a checkpoint after each) in a fresh `dir`.
    fn smoke_run(dir: &Path, iterations: usize) -> Trainer {
        smoke_run_with(dir, iterations, |_| {})
    }

    /// [`smoke_run`] with the smoke preset's PPO settings changed by `adjust`.
    fn smoke_run_with(dir: &Path, iterations: usize, adjust: impl Fn(&mut PpoConfig)) -> Trainer {
        let _ = std::fs::remove_dir_all(dir);
        let mut ppo = PpoConfig::preset("smoke").unwrap();
        ppo.total_timesteps = 1_000_000;
        adjust(&mut ppo);
        let spec = RunSpec {
            ppo,
            env: EnvConfig::default(),
            model: ModelSpec::by_name("Zone").unwrap(),
            seed: 0,
            preset: "smoke".into(),
            program_version: "test".into(),
            program_build: "test".into(),
            trainer_revision: crate::TRAINER_REVISION,
        };
        let mut t = Trainer::create(dir, spec).unwrap();
        for _ in 0..iterations {
            t.iterate().unwrap();
        }
        t
    }

    #[test]
    fn progress_shaping_must_discount_as_the_learner_does() {
        let mut spec = RunSpec {
            ppo: PpoConfig::preset("quick").unwrap(),
            env: EnvConfig::default(),
            model: ModelSpec::by_name("Zone").unwrap(),
            seed: 0,
            preset: "quick".into(),
            program_version: "test".into(),
            program_build: "test".into(),
            trainer_revision: crate::TRAINER_REVISION,
        };
        // Shaping off: the shaping's discount is inert, whatever it is.
        assert!(spec.check().is_ok());
        spec.env.task.progress_shaping = 1.0;
        let e = spec.check().unwrap_err().to_string();
        assert!(
            e.contains("`env.task.progress_shaping_gamma` = 0.99: differs from the PPO discount gamma = 0.9453")
                && e.contains("progress_shaping_gamma = 0.9453`"),
            "{e}"
        );
        // Every way of starting a run refuses it, not only callers that check first.
        let dir = std::env::temp_dir().join(format!("fishprobe-shaping-{}", std::process::id()));
        let _ = std::fs::remove_dir_all(&dir);
        let e = Trainer::create(&dir, spec.clone())
            .err()
            .map(|e| e.to_string());
        assert!(
            e.as_deref()
                .is_some_and(|e| e.contains("progress_shaping_gamma")),
            "{e:?}"
        );
        assert!(!dir.exists(), "a refused run leaves no directory");
        spec.env.task.progress_shaping_gamma = spec.ppo.gamma;
        assert!(spec.check().is_ok());
        spec.ppo = PpoConfig::preset("paper").unwrap();
        assert!(spec.check().is_err());
    }

    #[test]
    fn one_run_across_builds_but_not_across_trainer_revisions() {
        let dir = std::env::temp_dir().join(format!("fishprobe-revision-{}", std::process::id()));
        let spec = smoke_run(&dir, 0).spec().clone();
        assert_eq!(spec.trainer_revision, crate::TRAINER_REVISION);
        let other_build = RunSpec {
            program_version: "9.9.9".into(),
            program_build: "9.9.9 (commit abc)".into(),
            ..spec.clone()
        };
        assert!(spec.same_run(&other_build) && other_build.same_run(&spec));
        assert!(other_build.check_revision(&dir).is_ok());
        let other_revision = RunSpec {
            trainer_revision: 1,
            ..spec.clone()
        };
        assert!(!spec.same_run(&other_revision));
        let e = other_revision.check_revision(&dir).unwrap_err().to_string();
        assert!(
            e.contains("started by trainer revision 1 (fishprobe test)"),
            "{e}"
        );
        let mut seed = spec.clone();
        seed.seed += 1;
        assert!(!spec.same_run(&seed));
        // params.json of a run started before the revision was recorded reads as revision 0.
        let mut json = serde_json::to_value(&spec).unwrap();
        json.as_object_mut().unwrap().remove("trainer_revision");
        json.as_object_mut().unwrap().remove("program_build");
        let old: RunSpec = serde_json::from_value(json).unwrap();
        assert_eq!((old.trainer_revision, old.program_build.as_str()), (0, ""));
        let e = old.check_revision(&dir).unwrap_err().to_string();
        assert!(e.contains("did not record its trainer's revision"), "{e}");
        let _ = std::fs::remove_dir_all(&dir);
    }

    #[test]
    fn a_learning_rate_schedule_takes_effect_and_resumes_exactly() {
        let dir = |tag: &str| {
            std::env::temp_dir().join(format!("fishprobe-lr-{tag}-{}", std::process::id()))
        };
        let anneal = |p: &mut PpoConfig| {
            p.total_timesteps = 4 * p.train_batch_size as u64;
            p.lr = 0.003;
            p.lr_final = Some(0.0);
        };
        let whole = smoke_run_with(&dir("whole"), 4, anneal);
        assert!(whole.done());
        drop(smoke_run_with(&dir("cut"), 2, anneal));
        let mut cut = Trainer::resume(&dir("cut"), "test").unwrap();
        while !cut.done() {
            cut.iterate().unwrap();
        }
        assert_eq!(cut.policy().pi.params(), whole.policy().pi.params());
        assert_eq!(cut.policy().vf.params(), whole.policy().vf.params());
        let params = std::fs::read_to_string(dir("whole").join("params.json")).unwrap();
        assert!(params.contains("\"lr_final\": 0.0"), "{params}");
        // The same run at a constant rate ends elsewhere, and its params.json has no schedule.
        let constant = smoke_run_with(&dir("constant"), 4, |p| {
            anneal(p);
            p.lr_final = None;
        });
        assert_ne!(constant.policy().pi.params(), whole.policy().pi.params());
        let params = std::fs::read_to_string(dir("constant").join("params.json")).unwrap();
        assert!(!params.contains("lr_final"), "{params}");
        for tag in ["whole", "cut", "constant"] {
            let _ = std::fs::remove_dir_all(dir(tag));
        }
    }

    #[test]
    fn a_finished_run_given_more_steps_ends_where_the_longer_run_ends() {
        let dir = |tag: &str| {
            std::env::temp_dir().join(format!("fishprobe-raise-{tag}-{}", std::process::id()))
        };
        let budget =
            |n: u64| move |p: &mut PpoConfig| p.total_timesteps = n * p.train_batch_size as u64;
        let whole = smoke_run_with(&dir("whole"), 4, budget(4));
        assert!(whole.done());
        let short = smoke_run_with(&dir("short"), 2, budget(2));
        assert!(short.done());
        let (had, four) = (
            short.spec().ppo.total_timesteps,
            whole.spec().ppo.total_timesteps,
        );
        drop(short);
        assert_eq!(Trainer::raise_budget(&dir("short"), four).unwrap(), had);
        let mut raised = Trainer::resume(&dir("short"), "test").unwrap();
        assert_eq!(
            (raised.iteration(), raised.spec().ppo.total_timesteps),
            (2, four)
        );
        while !raised.done() {
            raised.iterate().unwrap();
        }
        assert_eq!(raised.policy().pi.params(), whole.policy().pi.params());
        assert_eq!(raised.policy().vf.params(), whole.policy().vf.params());
        assert!(raised.spec().same_run(whole.spec()));
        drop(raised);
        // The same budget again changes nothing; a lower one is refused and leaves the file.
        let before = std::fs::read(dir("short").join("params.json")).unwrap();
        assert_eq!(Trainer::raise_budget(&dir("short"), four).unwrap(), four);
        let e = Trainer::raise_budget(&dir("short"), had)
            .unwrap_err()
            .to_string();
        assert!(
            e.contains(&format!("the run's budget is {four} steps"))
                && e.contains(&format!("a new run of {had} steps instead")),
            "{e}"
        );
        let e = Trainer::raise_budget(&dir("short"), u64::MAX)
            .unwrap_err()
            .to_string();
        assert!(e.contains("total_timesteps"), "{e}");
        // No budget at all is refused as such, not met with advice to train a run of 0 steps.
        let e = Trainer::raise_budget(&dir("short"), 0)
            .unwrap_err()
            .to_string();
        assert!(
            e.contains("total_timesteps") && e.contains("at least 1") && !e.contains("run of 0"),
            "{e}"
        );
        assert_eq!(
            std::fs::read(dir("short").join("params.json")).unwrap(),
            before
        );
        // A schedule over the budget is refused: the steps taken would have had other rates.
        drop(smoke_run_with(&dir("anneal"), 1, |p| {
            budget(1)(p);
            p.lr_final = Some(0.0);
        }));
        let e = Trainer::raise_budget(&dir("anneal"), four)
            .unwrap_err()
            .to_string();
        assert!(
            e.contains("anneals its learning rate") && e.contains("lr_final"),
            "{e}"
        );
        // So is a run of another trainer revision, as resuming it is.
        let params = dir("whole").join("params.json");
        let text = std::fs::read_to_string(&params).unwrap().replace(
            &format!("\"trainer_revision\": {}", crate::TRAINER_REVISION),
            "\"trainer_revision\": 1",
        );
        std::fs::write(&params, text).unwrap();
        let e = Trainer::raise_budget(&dir("whole"), 2 * four)
            .unwrap_err()
            .to_string();
        assert!(e.contains("started by trainer revision 1"), "{e}");
        for tag in ["whole", "short", "anneal"] {
            let _ = std::fs::remove_dir_all(dir(tag));
        }
    }

    #[test]
    fn each_iteration_names_the_build_that_made_it() {
        let dir = std::env::temp_dir().join(format!("fishprobe-builds-{}", std::process::id()));
        drop(smoke_run(&dir, 2));
        let mut t = Trainer::resume(&dir, "9.9.9 (commit abc)").unwrap();
        t.iterate().unwrap();
        drop(t);
        // A resume by the starting build again: its iterations say so.
        let mut t = Trainer::resume(&dir, "test").unwrap();
        assert_eq!(t.iterate().unwrap().build, "test");
        let builds: Vec<String> = std::fs::read_to_string(dir.join("result.json"))
            .unwrap()
            .lines()
            .map(|l| serde_json::from_str::<IterationStats>(l).unwrap().build)
            .collect();
        assert_eq!(builds, ["test", "test", "9.9.9 (commit abc)", "test"]);
        // params.json keeps the build that started the run.
        assert_eq!(Trainer::recorded_spec(&dir).unwrap().program_build, "test");
        // A log line written before the build was recorded still reads.
        let mut old = serde_json::to_value(t.iterate().unwrap()).unwrap();
        old.as_object_mut().unwrap().remove("build");
        let old: IterationStats = serde_json::from_value(old).unwrap();
        assert_eq!(old.build, "");
        let _ = std::fs::remove_dir_all(&dir);
    }

    #[test]
    fn a_resume_never_erases_finished_iterations() {
        let dir = std::env::temp_dir().join(format!("fishprobe-keeplogs-{}", std::process::id()));
        drop(smoke_run(&dir, 3));
        let (csv, latest) = (dir.join("progress.csv"), dir.join("checkpoints/latest"));
        // A damaged byte (not UTF-8) in iteration 2's row: the row is kept as it was.
        let mut bytes = std::fs::read(&csv).unwrap();
        let row2 = bytes.windows(3).position(|w| w == b"\n2,").unwrap() + 1;
        let end = row2 + bytes[row2..].iter().position(|&b| b == b'\n').unwrap();
        bytes[end - 1] = 0xff;
        std::fs::write(&csv, &bytes).unwrap();
        let r = Trainer::resume(&dir, "test").unwrap();
        assert_eq!(r.iteration(), 3);
        drop(r);
        assert_eq!(
            std::fs::read(&csv).unwrap(),
            bytes,
            "the log changed on resume"
        );

        // A line longer than any fishprobe writes (a file that is not the run's log): refused,
        // with the log left as it was and no temporary file behind.
        let result = dir.join("result.json");
        let kept = std::fs::read(&result).unwrap();
        let mut long = kept.clone();
        long.extend(std::iter::repeat_n(b'x', MAX_LOG_LINE_BYTES as usize + 2));
        std::fs::write(&result, &long).unwrap();
        let e = Trainer::resume(&dir, "test").err().unwrap().to_string();
        assert!(e.contains("a line longer than 1048576 bytes"), "{e}");
        assert_eq!(std::fs::read(&result).unwrap(), long);
        std::fs::write(&result, &kept).unwrap();
        // A log that is not a file (here a directory): refused.
        let aside = dir.join("progress.aside");
        std::fs::rename(&csv, &aside).unwrap();
        std::fs::create_dir(&csv).unwrap();
        let e = Trainer::resume(&dir, "test").err().unwrap().to_string();
        assert!(
            e.contains("progress.csv: cannot rewrite the run's log: not a regular file"),
            "{e}"
        );
        std::fs::remove_dir(&csv).unwrap();
        std::fs::rename(&aside, &csv).unwrap();
        let partial = std::fs::read_dir(&dir)
            .unwrap()
            .filter_map(|e| e.ok())
            .find(|e| e.file_name().to_string_lossy().ends_with(".partial"));
        assert!(partial.is_none(), "{partial:?} left behind");

        // `latest` unreadable (here a directory): refused, not started over.
        std::fs::remove_file(&latest).unwrap();
        std::fs::create_dir(&latest).unwrap();
        let e = Trainer::resume(&dir, "test").err().unwrap().to_string();
        assert!(e.contains("checkpoints/latest: cannot read"), "{e}");
        std::fs::remove_dir(&latest).unwrap();
        // `latest` lost beside the two checkpoints kept: refused, naming the newest.
        let e = Trainer::resume(&dir, "test").err().unwrap().to_string();
        assert!(
            e.contains("missing, but checkpoints/ holds 2 checkpoint(s), the newest ckpt_000003"),
            "{e}"
        );
        // `latest` naming something else than a checkpoint.
        std::fs::write(&latest, "../../elsewhere").unwrap();
        let e = Trainer::resume(&dir, "test").err().unwrap().to_string();
        assert!(e.contains("not a checkpoint of this run"), "{e}");
        // Every refusal left the logs as they were.
        assert_eq!(std::fs::read(&csv).unwrap(), bytes);
        assert_eq!(
            std::fs::read_to_string(dir.join("result.json"))
                .unwrap()
                .lines()
                .count(),
            3
        );
        // A run stopped while writing its first checkpoint (one, no `latest`) starts over.
        drop(smoke_run(&dir, 1));
        std::fs::remove_file(&latest).unwrap();
        let r = Trainer::resume(&dir, "test").unwrap();
        assert_eq!(r.iteration(), 0);
        let _ = std::fs::remove_dir_all(&dir);
    }

    #[test]
    fn divergence_stops_with_an_error_and_keeps_the_last_good_checkpoint() {
        let dir = std::env::temp_dir().join(format!("fishprobe-diverge-{}", std::process::id()));
        let mut t = smoke_run(&dir, 1);
        let good = std::fs::read(dir.join("checkpoints/ckpt_000001/policy.safetensors")).unwrap();
        // Poison the policy: the next update meets non-finite values.
        t.policy.pi.params_mut()[0] = f32::NAN;
        match t.iterate() {
            Err(LearnError::Diverged { iteration, .. }) => assert_eq!(iteration, 2),
            Err(other) => panic!("unexpected error {other}"),
            Ok(_) => panic!("a NaN weight went unnoticed"),
        }
        assert_eq!(
            std::fs::read_to_string(dir.join("checkpoints/latest")).unwrap(),
            "ckpt_000001"
        );
        assert_eq!(
            std::fs::read(dir.join("checkpoints/ckpt_000001/policy.safetensors")).unwrap(),
            good
        );
        // And the run resumes from it.
        let r = Trainer::resume(&dir, "test").unwrap();
        assert_eq!(r.iteration(), 1);
        // But not when its policy's log-s.d. bound disagrees with params.json (a checkpoint from
        // before the bound existed).
        let sidecar = dir.join("checkpoints/ckpt_000001/policy.safetensors.json");
        let mut meta: serde_json::Value =
            serde_json::from_str(&std::fs::read_to_string(&sidecar).unwrap()).unwrap();
        meta.as_object_mut().unwrap().remove("log_std_max");
        std::fs::write(&sidecar, meta.to_string()).unwrap();
        let e = Trainer::resume(&dir, "test").err().unwrap().to_string();
        assert!(
            e.contains("log-s.d. bound (none) is not params.json's (0)"),
            "{e}"
        );
        let _ = std::fs::remove_dir_all(&dir);
    }
}
