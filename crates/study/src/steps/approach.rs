//! The approach assay of a training run (SPEC §8): the robot in a corner, a motionless fish
//! and the goal on either side.

use super::episodes::Inputs;
use super::PolicySource;
use crate::error::StudyError;
use crate::Study;

/// The assay's episodes (its own set-up, observed as the study's policies observe) with the
/// policy assayed: every seed of a policy meets the same episodes, which run as any others.
pub(crate) fn inputs(study: &Study, p: usize, k: usize) -> Result<Inputs, StudyError> {
    let c = &study.cfg;
    let mut e = fishprobe_learn::approach_assay(
        c.approach_episodes,
        c.approach_minutes,
        fishprobe_sim::derive_seed(c.seed, &format!("approach/{}", c.models[p].name), 0),
        Default::default(),
    )
    .map_err(|e| StudyError::Input(format!("the approach assay: {e}")))?;
    // One still fish, observed as the study's policies observe.
    e.env.observation = study.env.observation.clone();
    Ok(Inputs {
        policy: PolicySource::of(study, p, k),
        evaluation: e,
    })
}
