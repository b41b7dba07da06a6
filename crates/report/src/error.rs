//! What can go wrong while making a report.

use std::path::PathBuf;

/// An error of the report crate.
#[derive(Debug, thiserror::Error)]
pub enum ReportError {
    /// A training log (`progress.csv`) that is not one (with why).
    #[error("{0}")]
    Progress(String),
    /// The study directory is missing or not a directory.
    #[error("study directory {path}: {what}")]
    Study {
        /// The path given.
        path: PathBuf,
        /// What is wrong with it.
        what: String,
    },
    /// A file of the study exists but cannot be used.
    #[error("{path}: {what}")]
    Input {
        /// The file.
        path: PathBuf,
        /// What is wrong with it.
        what: String,
    },
    /// A figure could not be rendered.
    #[error("figure `{figure}`: {what}")]
    Render {
        /// The figure's name.
        figure: String,
        /// Why.
        what: String,
    },
    /// Writing an output failed.
    #[error("writing {path}: {what}")]
    Write {
        /// The file.
        path: PathBuf,
        /// Why.
        what: String,
    },
    /// A setting is out of range.
    #[error(transparent)]
    Config(#[from] fishprobe_sim::params::ConfigError),
}
