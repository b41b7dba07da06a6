//! The approach assay of a training run (SPEC §8): the robot in a corner, a motionless fish
//! and the goal on either side.

use super::{Ctx, PolicySource};
use crate::error::{StepError, StudyError};
use crate::store::staged;
use crate::Study;
use fishprobe_learn::Evaluation;
use serde::Serialize;

/// What the assay reads.
#[derive(Debug, Clone, Serialize)]
pub struct Inputs {
    /// The policy assayed.
    pub policy: PolicySource,
    /// The assay's episodes: its own set-up, observed as the study's policies observe.
    pub evaluation: Evaluation,
}

/// Every seed of a policy meets the same episodes.
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

pub(crate) fn run(i: &Inputs, cx: &mut Ctx) -> Result<(), StepError> {
    staged(&cx.out, |tmp| {
        let e = Evaluation {
            out: tmp.to_path_buf(),
            ..i.evaluation.clone()
        };
        fishprobe_learn::evaluate(i.policy.load(&cx.layout)?.as_ref(), &e)?;
        Ok(())
    })
}
