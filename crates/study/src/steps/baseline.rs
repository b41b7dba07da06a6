//! The scripted baselines on the evaluation episodes of a model's own policy (probe
//! competence): the same seed and episodes, so policy and baselines face the same fish starts.

use super::Ctx;
use crate::error::StepError;
use crate::store::staged;
use crate::Study;
use fishprobe_learn::Evaluation;
use serde::Serialize;

/// What the baselines read.
#[derive(Debug, Clone, Serialize)]
pub struct Inputs {
    /// The model's name in the study.
    pub model: String,
    /// The scripted controllers run, by name.
    pub controllers: Vec<String>,
    /// The fetch-and-lead controller's settings (the defaults it is built with).
    pub fetch: fishprobe_sim::FetchParams,
    /// The model's own evaluation episodes.
    pub evaluation: Evaluation,
}

pub(crate) fn inputs(study: &Study, m: usize) -> Inputs {
    Inputs {
        model: study.cfg.models[m].name.clone(),
        controllers: fishprobe_sim::SCRIPTED.map(str::to_string).to_vec(),
        fetch: fishprobe_sim::FetchParams::default(),
        evaluation: super::episodes::evaluation(study, m, m),
    }
}

pub(crate) fn run(i: &Inputs, cx: &mut Ctx) -> Result<(), StepError> {
    let say = &mut *cx.say;
    staged(&cx.out, |tmp| {
        for name in &i.controllers {
            let b = fishprobe_sim::scripted(name)
                .ok_or_else(|| StepError::Missing(format!("scripted controller `{name}`")))?;
            let e = Evaluation {
                out: tmp.join(b.name()),
                ..i.evaluation.clone()
            };
            let r = fishprobe_learn::evaluate(b.as_ref(), &e)?;
            let (mean, _) = fishprobe_learn::goals_mean_sd(&r);
            say(&format!(
                "{} on {}: {mean:.1} goals per episode",
                b.name(),
                i.model
            ));
        }
        Ok(())
    })
}
