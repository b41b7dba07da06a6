//! Errors of the analysis.

use std::path::PathBuf;

/// What stops an analysis (problems with single files or conditions do not: they are listed
/// as skipped).
#[derive(Debug, thiserror::Error)]
pub enum AnalysisError {
    /// The study directory has no rollouts.
    #[error("{}: {what}", path.display())]
    Layout {
        /// The directory.
        path: PathBuf,
        /// What is missing.
        what: String,
    },
    /// A configuration value is out of range.
    #[error(transparent)]
    Config(#[from] fishprobe_sim::ConfigError),
    /// The trial data cannot give what was asked (a file that is not a pair, a trial without
    /// the fish, too few frames for a measure), with the file and the reason.
    #[error("{0}")]
    Data(String),
    /// A fish model of a synthetic study.
    #[error(transparent)]
    Model(#[from] fishprobe_models::ModelError),
    /// The simulation of a synthetic study.
    #[error(transparent)]
    Sim(#[from] fishprobe_sim::SimError),
    /// Writing a synthetic study's trial file.
    #[error(transparent)]
    Trial(#[from] fishprobe_io::IoError),
    /// Writing results failed.
    #[error("{}: cannot write: {what}", path.display())]
    Write {
        /// The file.
        path: PathBuf,
        /// Why.
        what: String,
    },
}

/// A message about the data, made where it is read ([`AnalysisError::Data`]).
impl From<String> for AnalysisError {
    fn from(what: String) -> Self {
        AnalysisError::Data(what)
    }
}

impl From<&str> for AnalysisError {
    fn from(what: &str) -> Self {
        AnalysisError::Data(what.to_string())
    }
}
