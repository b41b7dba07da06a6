//! Episodes of a policy on a model: the evaluation cells (policy `p` on model `m`) and the
//! stability episodes of each training run.

use super::{Ctx, PolicySource};
use crate::error::StepError;
use crate::store::staged;
use crate::Study;
use fishprobe_learn::Evaluation;
use serde::Serialize;

/// What a set of episodes reads.
#[derive(Debug, Clone, Serialize)]
pub struct Inputs {
    /// The policy that drives the robot.
    pub policy: PolicySource,
    /// The fish model, environment, episodes, their length and seed.
    pub evaluation: Evaluation,
}

/// The evaluation episodes of policy `p` on model `m` (the scripted baselines of model `m`
/// run on those of `m`'s own policy: the same starts and fish).
pub(crate) fn evaluation(study: &Study, p: usize, m: usize) -> Evaluation {
    let c = &study.cfg;
    Evaluation {
        model: c.models[m].spec.clone(),
        env: study.env.clone(),
        episodes: study.eval_episodes(p, m),
        minutes: c.episode_minutes,
        seed: fishprobe_sim::derive_seed(
            c.seed,
            &format!("eval/{}/{}", c.models[p].name, c.models[m].name),
            0,
        ),
        start: None,
        out: Default::default(),
        prefix: "trial".into(),
    }
}

pub(crate) fn eval_inputs(study: &Study, p: usize, m: usize) -> Inputs {
    Inputs {
        policy: PolicySource::of(study, p, 0),
        evaluation: evaluation(study, p, m),
    }
}

pub(crate) fn stability_inputs(study: &Study, m: usize, k: usize) -> Inputs {
    let c = &study.cfg;
    Inputs {
        policy: PolicySource::of(study, m, k),
        evaluation: Evaluation {
            model: c.models[m].spec.clone(),
            env: study.env.clone(),
            episodes: c.stability_episodes,
            minutes: c.episode_minutes,
            seed: fishprobe_sim::derive_seed(
                c.seed,
                &format!("stability/{}/{k}", c.models[m].name),
                0,
            ),
            start: None,
            out: Default::default(),
            prefix: "episode".into(),
        },
    }
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
