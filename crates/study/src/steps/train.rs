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
    let out = cx.out.as_path();
    let spec = RunSpec::new(
        i.spec.clone(),
        i.ppo.clone(),
        i.env.clone(),
        i.seed,
        i.preset.clone(),
        cx.program_build.to_string(),
    );
    use fishprobe_learn::run::{open, OnOther, Opening};
    let mut t = match open(out, &spec, OnOther::Restart)? {
        Opening::Resume => {
            (cx.say)("resuming from the last checkpoint");
            Trainer::resume(out, &spec.program_build)?
        }
        Opening::Start | Opening::Restarted { .. } => {
            // A folder without a run's record holds nothing to keep.
            if out.exists() {
                std::fs::remove_dir_all(out).map_err(|e| StepError::io("removing", out, e))?;
            }
            Trainer::create(out, spec)?
        }
    };
    while !t.done() {
        let s = t.iterate()?;
        (cx.say)(&format!(
            "iteration {} steps {} return {:.3} goals/episode {:.3}",
            s.iteration, s.timesteps, s.episode_return_mean, s.goals_per_episode
        ));
    }
    t.finish()?;
    Ok(())
}
