//! A training run: policy `k` of a model, resumed from its last checkpoint when its run
//! records the same spec.

use super::Ctx;
use crate::error::{StepError, StudyError};
use crate::Study;
use fishprobe_learn::{RunSpec, Trainer};
use serde::Serialize;

/// What a training run reads.
#[derive(Debug, Clone, Serialize)]
pub struct Inputs {
    /// The model's name in the study.
    pub model: String,
    /// The fish model trained against.
    pub spec: fishprobe_models::ModelSpec,
    /// The PPO preset's name, as the run records it.
    pub preset: String,
    /// The resolved PPO settings (not the preset's name: a preset whose values change must
    /// not pass for the old one).
    pub ppo: fishprobe_learn::PpoConfig,
    /// The whole environment: tank, task, observation, fish per tank.
    pub env: fishprobe_sim::EnvConfig,
    /// The run's seed (derived from the master seed by model and run).
    pub seed: u64,
    /// The trainer's revision: a fixed trainer retrains what the broken one made.
    pub trainer: u32,
}

pub(crate) fn inputs(study: &Study, m: usize, k: usize) -> Result<Inputs, StudyError> {
    let c = &study.cfg;
    let model = c.models[m].name.clone();
    let ppo = c
        .ppo(&c.models[m].spec)
        .ok_or_else(|| StudyError::Input(format!("unknown PPO preset `{}`", c.ppo_preset)))?;
    Ok(Inputs {
        seed: fishprobe_sim::derive_seed(c.seed, &format!("train/{model}"), k as u64),
        model,
        spec: c.models[m].spec.clone(),
        preset: c.ppo_preset.clone(),
        ppo,
        env: study.env.clone(),
        trainer: fishprobe_learn::TRAINER_REVISION,
    })
}

/// Trains into the step's output: resumes a run of the same spec, starts a run of another
/// spec (or another trainer revision's) over.
pub(crate) fn run(i: &Inputs, cx: &mut Ctx) -> Result<(), StepError> {
    let spec = RunSpec::new(
        i.spec.clone(),
        i.ppo.clone(),
        i.env.clone(),
        i.seed,
        i.preset.clone(),
        cx.program_build.to_string(),
    );
    use fishprobe_learn::run::{train_to_end, Begin, OnOther};
    let build = cx.program_build;
    let out = cx.out.clone();
    train_to_end(
        &out,
        Begin::StartOrResume(spec, OnOther::Restart),
        build,
        &mut StepLog(&mut *cx.say),
    )?;
    Ok(())
}

/// A training step's log: resumption and every iteration.
struct StepLog<'a>(&'a mut dyn FnMut(&str));

impl fishprobe_learn::run::TrainHooks for StepLog<'_> {
    fn create(
        &mut self,
        dir: &std::path::Path,
        spec: RunSpec,
    ) -> Result<Trainer, fishprobe_learn::LearnError> {
        // A folder without a run's record holds nothing to keep.
        if dir.exists() {
            std::fs::remove_dir_all(dir).map_err(|e| {
                fishprobe_learn::LearnError::Run(format!("{}: removing: {e}", dir.display()))
            })?;
        }
        Trainer::create(dir, spec)
    }

    fn opened(
        &mut self,
        _t: &Trainer,
        how: &fishprobe_learn::run::Opened,
    ) -> Result<(), fishprobe_learn::LearnError> {
        if *how == fishprobe_learn::run::Opened::Resumed {
            (self.0)("resuming from the last checkpoint");
        }
        Ok(())
    }

    fn iterated(
        &mut self,
        _t: &Trainer,
        s: &fishprobe_learn::IterationStats,
    ) -> Result<(), fishprobe_learn::LearnError> {
        (self.0)(&format!(
            "iteration {} steps {} return {:.3} goals/episode {:.3}",
            s.iteration, s.timesteps, s.episode_return_mean, s.goals_per_episode
        ));
        Ok(())
    }
}
