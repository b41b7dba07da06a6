//! M_ConvNet refitted on the study's pair recordings (`--convnet-data`).

use super::Ctx;
use crate::error::{StepError, StudyError};
use crate::store::staged;
use crate::Study;
use serde::Serialize;
use std::path::PathBuf;

/// What the refit reads.
#[derive(Debug, Clone, Serialize)]
pub struct Inputs {
    /// The recordings: `train/` is fitted, `validation/` stops the fit early.
    pub data: PathBuf,
    /// The study's master seed.
    pub seed: u64,
    /// How the network is fitted (the defaults, with the study's `convnet_max_epochs`).
    pub clone: fishprobe_learn::bc::CloneConfig,
}

pub(crate) fn inputs(study: &Study) -> Result<Inputs, StudyError> {
    let data = study.convnet_data.clone().ok_or_else(|| {
        StudyError::Input("no ConvNet fitting data (the study's convnet_data)".into())
    })?;
    Ok(Inputs {
        data,
        seed: study.cfg.seed,
        clone: fishprobe_learn::bc::CloneConfig {
            max_epochs: study.cfg.convnet_max_epochs,
            ..fishprobe_learn::bc::CloneConfig::default()
        },
    })
}

pub(crate) fn run(i: &Inputs, cx: &mut Ctx) -> Result<(), StepError> {
    let command = format!(
        "fishprobe fit-convnet --data {} --validation {} --seed {}",
        i.data.join("train").display(),
        i.data.join("validation").display(),
        i.seed
    );
    let say = &mut *cx.say;
    staged(&cx.out, |tmp| {
        let r = fishprobe_learn::bc::fit_convnet(
            &fishprobe_learn::bc::FitRequest {
                data: &[i.data.join("train")],
                validation: &[i.data.join("validation")],
                out: &tmp.join("convnet.safetensors"),
                cfg: &i.clone,
                seed: i.seed,
                baselines: false,
                resume: false,
                command: &command,
                build: cx.program_build,
            },
            &|_| {},
        )?;
        say(&format!(
            "refitted M_ConvNet: validation NLL {:.4} (marginal {:.4})",
            r.val_nll, r.marginal_nll
        ));
        Ok(())
    })
}
