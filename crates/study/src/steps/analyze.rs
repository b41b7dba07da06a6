//! The analysis of the study's trials (every arm, the assay, the stability episodes).

use super::Ctx;
use crate::error::{StepError, StudyError};
use crate::store::staged;
use crate::Study;
use serde::Serialize;
use std::path::Path;

/// What the analysis reads besides the trials (its dependencies).
#[derive(Debug, Clone, Serialize)]
pub struct Inputs {
    /// The analysis settings, resolved: the preset's, the study's `sim_trials`, its
    /// `[analysis]` table.
    pub config: fishprobe_analysis::AnalysisConfig,
    /// The study's master seed (the resampling streams derive from it).
    pub seed: u64,
}

pub(crate) fn inputs(study: &Study) -> Result<Inputs, StudyError> {
    Ok(Inputs {
        config: study.cfg.analysis_config()?,
        seed: study.cfg.seed,
    })
}

pub(crate) fn run(i: &Inputs, root: &Path, cx: &mut Ctx) -> Result<(), StepError> {
    staged(&cx.out, |tmp| {
        let r = fishprobe_analysis::analyze_dir(root, &i.config, i.seed)?;
        fishprobe_analysis::write_results(tmp, &r)?;
        Ok(())
    })
}
