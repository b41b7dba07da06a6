//! The report of the analysed study.

use super::Ctx;
use crate::error::StepError;
use crate::store::staged;
use crate::{NamedModel, Study};
use serde::Serialize;
use std::path::Path;

/// What the report reads besides the analysis and the policies (its dependencies).
#[derive(Debug, Clone, Serialize)]
pub struct Inputs {
    /// The report's settings.
    pub config: fishprobe_report::ReportConfig,
    /// The candidates it presents (read from `study.json`: names, models, origins).
    pub models: Vec<NamedModel>,
}

pub(crate) fn inputs(study: &Study) -> Inputs {
    Inputs {
        config: fishprobe_report::ReportConfig::default(),
        models: study.cfg.models.clone(),
    }
}

pub(crate) fn run(i: &Inputs, root: &Path, cx: &mut Ctx) -> Result<(), StepError> {
    let analysis = cx.layout.analysis();
    staged(&cx.out, |tmp| {
        fishprobe_report::build_report(root, Some(tmp), Some(&analysis), &i.config)?;
        Ok(())
    })
}
