//! The steps of a study, one file per kind of work: what the step reads (its `Inputs`,
//! serialisable, hashed whole into its completion marker) and the work it does with exactly
//! that. The work is given its inputs and a [`Ctx`] (where it writes, the study's layout to
//! find the policies it runs, the build that runs it) and no study settings, so a setting a
//! step reads cannot be left out of its hash: to read a setting, a step must put it in its
//! inputs.

pub mod analyze;
pub mod approach;
pub mod baseline;
pub mod episodes;
pub mod fit_convnet;
pub mod reality;
pub mod report;
pub mod train;

use crate::error::{StepError, StudyError};
use crate::{Step, StepKind, Study};
use fishprobe_io::StudyLayout;
use fishprobe_sim::Controller;
use serde::Serialize;
use std::io::Write;
use std::path::PathBuf;

/// Version of what a completion marker holds. A marker of another version (or of none: those
/// written before the version was recorded) is not trusted: its step is recomputed once.
pub const MARKER_SCHEMA: u32 = 2;

/// Prefix of a step's log lines that the user must see (they are passed on as
/// [`crate::Event::Warning`]).
const WARNING: &str = "warning: ";

/// Everything one step reads, by kind.
#[derive(Debug, Clone, Serialize)]
#[serde(tag = "kind", rename_all = "snake_case")]
pub enum StepInputs {
    /// M_ConvNet refitted on the study's recordings.
    FitConvnet(fit_convnet::Inputs),
    /// A training run.
    Train(train::Inputs),
    /// A policy's evaluation episodes on a model.
    Eval(episodes::Inputs),
    /// The scripted baselines on a model's evaluation episodes.
    Baseline(baseline::Inputs),
    /// The approach assay of a training run (its episodes: the assay's set-up).
    Approach(episodes::Inputs),
    /// The stability episodes of a training run.
    Stability(episodes::Inputs),
    /// The reality arm of a policy.
    Reality(reality::Inputs),
    /// The analysis.
    Analyze(analyze::Inputs),
    /// The report.
    Report(report::Inputs),
}

impl StepKind {
    /// What this step reads, resolved from the study's configuration.
    pub fn inputs(&self, study: &Study) -> Result<StepInputs, StudyError> {
        Ok(match *self {
            StepKind::FitConvnet => StepInputs::FitConvnet(fit_convnet::inputs(study)?),
            StepKind::Train { m, k } => StepInputs::Train(train::inputs(study, m, k)?),
            StepKind::Eval { p, m } => StepInputs::Eval(episodes::eval_inputs(study, p, m)),
            StepKind::Baseline { m } => StepInputs::Baseline(baseline::inputs(study, m)),
            StepKind::Approach { p, k } => StepInputs::Approach(approach::inputs(study, p, k)?),
            StepKind::Stability { m, k } => {
                StepInputs::Stability(episodes::stability_inputs(study, m, k))
            }
            StepKind::Reality { p } => StepInputs::Reality(reality::inputs(study, p)),
            StepKind::Analyze => StepInputs::Analyze(analyze::inputs(study)?),
            StepKind::Report => StepInputs::Report(report::inputs(study)),
        })
    }
}

/// Which policy a step runs.
#[derive(Debug, Clone, Serialize)]
#[serde(rename_all = "snake_case")]
pub enum PolicySource {
    /// Training run `k` of `model`, trained by the study (its identity is that training
    /// step's hash, a dependency of the step that runs it).
    Trained {
        /// The model's name in the study.
        model: String,
        /// The training run (0: the policy; more: stability seeds).
        k: usize,
    },
    /// A policy trained elsewhere, which the study file names for `model`.
    External {
        /// The model's name in the study (the policy runs under it).
        model: String,
        /// `onnx:PATH` or a `fishprobe train` directory.
        policy: String,
        /// Its file's SHA-256, so that a replaced file reruns every step that ran it.
        sha256: String,
    },
}

impl PolicySource {
    /// Model `m`'s training run `k`: fishprobe's own, or for `k` = 0 the one the study file
    /// names.
    pub(crate) fn of(study: &Study, m: usize, k: usize) -> Self {
        let model = study.cfg.models[m].name.clone();
        match study.external_policy(m).filter(|_| k == 0) {
            Some(arg) => PolicySource::External {
                model,
                policy: arg.to_string(),
                sha256: crate::external_policy_sha256(arg),
            },
            None => PolicySource::Trained { model, k },
        }
    }

    /// The policy, loaded (under the study's name for its model).
    fn load(&self, layout: &StudyLayout) -> Result<Box<dyn Controller>, StepError> {
        match self {
            PolicySource::External { model, policy, .. } => Ok(fishprobe_learn::named(
                fishprobe_learn::controller(policy, false)?,
                model.clone(),
            )),
            PolicySource::Trained { model, k } => Ok(Box::new(
                fishprobe_learn::PolicyController::load(&layout.policy(model, *k), false)?,
            )),
        }
    }

    /// The model's name in the study.
    fn model(&self) -> &str {
        match self {
            PolicySource::External { model, .. } | PolicySource::Trained { model, .. } => model,
        }
    }

    /// Where the policy is, for messages.
    fn shown(&self, layout: &StudyLayout) -> String {
        match self {
            PolicySource::External { policy, .. } => policy.clone(),
            PolicySource::Trained { model, k } => layout.policy(model, *k).display().to_string(),
        }
    }
}

/// What a step's work is given besides its inputs: never a setting.
pub struct Ctx<'a> {
    /// The study directory's paths (to find the policies a step runs).
    pub layout: StudyLayout,
    /// Where the step writes.
    pub out: PathBuf,
    /// The fishprobe build running the study, recorded with what it fits.
    pub program_build: &'a str,
    /// The step's log.
    pub say: &'a mut dyn FnMut(&str),
}

/// A step's log: each line goes to its log file; warnings are also kept in `warnings`.
fn log<'a>(
    study: &Study,
    s: &Step,
    warnings: &'a std::cell::RefCell<Vec<String>>,
) -> impl FnMut(&str) + 'a {
    let path = study.log_path(s);
    let mut f = std::fs::OpenOptions::new()
        .create(true)
        .append(true)
        .open(path)
        .ok();
    move |line: &str| {
        if let Some(f) = f.as_mut() {
            let _ = writeln!(f, "{line}");
        }
        if let Some(w) = line.strip_prefix(WARNING) {
            warnings.borrow_mut().push(w.to_string());
        }
    }
}

/// Runs one step; its warnings on success.
pub(crate) fn run_step(study: &Study, s: &Step) -> Result<Vec<String>, StepError> {
    let warnings = std::cell::RefCell::new(Vec::new());
    let mut say = log(study, s, &warnings);
    say(&format!("step {} (inputs hash {:016x})", s.id, s.hash));
    let mut cx = Ctx {
        layout: study.layout(),
        out: study.output(&s.kind),
        program_build: &study.program_build,
        say: &mut say,
    };
    let r = match &s.inputs {
        StepInputs::FitConvnet(i) => fit_convnet::run(i, &mut cx),
        StepInputs::Train(i) => train::run(i, &mut cx),
        StepInputs::Eval(i) | StepInputs::Stability(i) | StepInputs::Approach(i) => {
            episodes::run(i, &mut cx)
        }
        StepInputs::Baseline(i) => baseline::run(i, &mut cx),
        StepInputs::Reality(i) => reality::run(i, &mut cx),
        StepInputs::Analyze(i) => analyze::run(i, &study.root, &mut cx),
        StepInputs::Report(i) => report::run(i, &study.root, &mut cx),
    };
    say(match &r {
        Ok(()) => "done".to_string(),
        Err(e) => format!("failed: {e}"),
    }
    .as_str());
    drop(say);
    r.map(|()| warnings.into_inner())
}
