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
