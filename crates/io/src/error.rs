//! Errors of the io crate: each names the file and the problem.

use std::path::PathBuf;

/// Everything that can go wrong reading or writing trial files.
#[derive(Debug, thiserror::Error)]
pub enum IoError {
    /// The file cannot be read at all.
    // The OS error is part of the message, not a chained source, so that `{:#}` in the CLI
    // does not print it twice.
    #[error("{}: cannot read: {reason}", path.display())]
    Read {
        /// The file.
        path: PathBuf,
        /// The OS error.
        reason: std::io::Error,
    },
    /// The file is not HDF5.
    #[error("{}: not an HDF5 file (no HDF5 signature)", path.display())]
    NotHdf5 {
        /// The file.
        path: PathBuf,
    },
    /// The file is HDF5 but damaged or not of the expected layout.
    #[error("{}: {what}", path.display())]
    Format {
        /// The file.
        path: PathBuf,
        /// What is wrong.
        what: String,
    },
    /// Writing failed.
    #[error("{}: cannot write: {what}", path.display())]
    Write {
        /// The file.
        path: PathBuf,
        /// What went wrong.
        what: String,
    },
    /// The data to write is inconsistent.
    #[error("cannot write trial: {0}")]
    Invalid(String),
}

impl IoError {
    /// A layout problem in `path`.
    pub fn format(path: &std::path::Path, what: impl Into<String>) -> Self {
        IoError::Format {
            path: path.to_path_buf(),
            what: what.into(),
        }
    }
}
