//! What can go wrong in a study, typed: the engine's errors and each step's.

use std::path::PathBuf;

/// What went wrong.
#[derive(Debug, thiserror::Error)]
pub enum StudyError {
    /// The configuration or the inputs cannot work (reported before any expensive work).
    #[error("{0}")]
    Input(String),
    /// A step failed.
    #[error("step {step} failed: {source} (log: {log})")]
    Step {
        /// The step.
        step: String,
        /// Why.
        source: Box<StepError>,
        /// Its log.
        log: PathBuf,
    },
    /// File system.
    #[error("{path}: {what}")]
    Io {
        /// Where.
        path: PathBuf,
        /// What.
        what: String,
    },
}

/// Why one step failed.
#[derive(Debug, thiserror::Error)]
pub enum StepError {
    /// A file or directory operation.
    #[error("{what} {path}: {source}")]
    Io {
        /// What was being done ("removing", "moving ... to", ...).
        what: String,
        /// The path.
        path: PathBuf,
        /// The OS error.
        source: std::io::Error,
    },
    /// Something the step needs is not there.
    #[error("{0}")]
    Missing(String),
    /// The study's settings (refused by `StudyConfig::validate` before any step runs).
    #[error("settings: {0}")]
    Settings(String),
    /// Training or evaluation.
    #[error(transparent)]
    Learn(#[from] fishprobe_learn::LearnError),
    /// A fish model.
    #[error(transparent)]
    Model(#[from] fishprobe_models::ModelError),
    /// The virtual lab or the bridge.
    #[error(transparent)]
    Live(#[from] fishprobe_live::LiveError),
    /// The analysis.
    #[error(transparent)]
    Analysis(#[from] fishprobe_analysis::AnalysisError),
    /// The report.
    #[error(transparent)]
    Report(#[from] fishprobe_report::ReportError),
    /// A thread pool for the step.
    #[error("thread pool: {0}")]
    ThreadPool(#[from] rayon::ThreadPoolBuildError),
    /// A thread of the step panicked.
    #[error("{0} panicked")]
    Panicked(&'static str),
}

impl StepError {
    /// An I/O error while `what`-ing `path`.
    pub fn io(what: &str, path: &std::path::Path, source: std::io::Error) -> Self {
        StepError::Io {
            what: what.to_string(),
            path: path.to_path_buf(),
            source,
        }
    }
}
