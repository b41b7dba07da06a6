//! Errors of the network kit.

/// What can go wrong with networks and their files.
#[derive(Debug, Clone, PartialEq, thiserror::Error)]
pub enum NnError {
    /// A file cannot be read or written.
    #[error("{0}")]
    Io(String),
    /// A file is not what it should be (format, version, architecture, shapes).
    #[error("{0}")]
    Format(String),
}
