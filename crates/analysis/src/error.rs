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
    /// Writing results failed.
    #[error("{}: cannot write: {what}", path.display())]
    Write {
        /// The file.
        path: PathBuf,
        /// Why.
        what: String,
    },
}
