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
    #[error("listening on {addr} (not loopback) needs --allow-remote and a --token")]
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
    /// The pilot (policy) could not be made.
    #[error("pilot: {0}")]
    Pilot(String),
}
