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
    /// The path is not a regular file (a directory, FIFO, device, or a dangling symbolic
    /// link): refused before opening, since reading it could block or never end.
    #[error("{}: {what}", path.display())]
    NotRegular {
        /// The path.
        path: PathBuf,
        /// What it is instead.
        what: String,
    },
    /// The file is larger than [`crate::ReadLimits::max_file_bytes`].
    #[error("{}: {bytes} bytes, more than the limit of {limit} bytes for a trial file (fishprobe_io::ReadLimits::max_file_bytes)", path.display())]
    TooLarge {
        /// The file.
        path: PathBuf,
        /// Its size.
        bytes: u64,
        /// The limit.
        limit: u64,
    },
    /// An HDF5 file of neither trial layout ([`crate::read_any_trial`]): why, as each.
    #[error("{robofish}; as a legacy file: {legacy}")]
    NeitherLayout {
        /// Why it is not robofish.io.
        robofish: Box<IoError>,
        /// Why it is not the lab's pre-2020 layout.
        legacy: Box<IoError>,
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
