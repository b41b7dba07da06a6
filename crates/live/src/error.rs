//! Errors of the live crate.

use std::path::PathBuf;

/// What can go wrong on the bridge or in the virtual lab.
#[derive(Debug, thiserror::Error)]
pub enum LiveError {
    /// A setting is out of range.
    #[error(transparent)]
    Config(#[from] fishprobe_sim::params::ConfigError),
    /// The network.
    #[error("connection: {0}")]
    Net(String),
    /// The bridge refused the handshake.
    #[error("the bridge refused the trial: {0}")]
    Refused(String),
    /// Listening beyond loopback without a token.
    #[error("listening on {addr} (not loopback) needs a token")]
    Unsafe {
        /// The address.
        addr: String,
    },
    /// Writing a trial file.
    #[error("writing {path}: {what}")]
    Write {
        /// The file.
        path: PathBuf,
        /// Why.
        what: String,
    },
    /// The BioTracker observer's settings do not fit together.
    #[error("observer settings: {0}")]
    Observer(String),
    /// A component's configuration or entity ids that cannot be used.
    #[error("{0}")]
    Settings(String),
    /// The tracker's state that a trial cannot run on (tank size, rate, ids, skeleton).
    #[error("{0}")]
    TrackerState(String),
    /// A line that is not a message of the live protocol.
    #[error("{0}")]
    Malformed(String),
    /// The pilot (policy) could not be made.
    #[error("pilot: {0}")]
    Pilot(String),
    /// The output directory holds trials of another policy under the pilot's name (or a
    /// file there cannot be read, so this cannot be told).
    #[error(
        "{0}; trials of two policies in one directory would be counted as one policy's: serve \
         into another output directory, or move those trials out"
    )]
    Mixed(String),
}
