//! What can go wrong in a research command, typed, with what was being done when it did.

use std::fmt::Display;

/// What went wrong in a research command.
#[derive(Debug, thiserror::Error)]
pub enum ResearchError {
    /// What was asked cannot be done: an option out of range, a file of the wrong kind, a
    /// directory that holds another run.
    #[error("{0}")]
    Refused(String),
    /// What was being done when `source` happened ("loading --policy runs/zone", "seed 3").
    #[error("{context}")]
    Context {
        /// What was being done.
        context: String,
        /// What went wrong.
        #[source]
        source: Box<ResearchError>,
    },
    /// Training, evaluation, a policy, behavioural cloning.
    #[error(transparent)]
    Learn(#[from] fishprobe_learn::LearnError),
    /// A fish model.
    #[error(transparent)]
    Model(#[from] fishprobe_models::ModelError),
    /// A support model.
    #[error(transparent)]
    Support(#[from] fishprobe_models::support::SupportError),
    /// The analysis of trial files.
    #[error(transparent)]
    Analysis(#[from] fishprobe_analysis::AnalysisError),
    /// A figure.
    #[error(transparent)]
    Report(#[from] fishprobe_report::ReportError),
    /// A trial file or another file fishprobe reads and writes.
    #[error(transparent)]
    Files(#[from] fishprobe_io::IoError),
    /// The one-writer lock of the output.
    #[error(transparent)]
    Lock(#[from] fishprobe_io::LockError),
    /// The simulation's settings.
    #[error(transparent)]
    Sim(#[from] fishprobe_sim::SimError),
    /// A setting out of its range.
    #[error(transparent)]
    Config(#[from] fishprobe_sim::ConfigError),
    /// A network file.
    #[error(transparent)]
    Nn(#[from] fishprobe_nn::NnError),
    /// An ONNX file.
    #[error(transparent)]
    Onnx(#[from] fishprobe_onnx::OnnxError),
    /// The file system.
    #[error(transparent)]
    Io(#[from] std::io::Error),
    /// JSON written or read back.
    #[error(transparent)]
    Json(#[from] serde_json::Error),
}

/// The result of a research command's work.
pub type Result<T, E = ResearchError> = std::result::Result<T, E>;

impl ResearchError {
    /// A refusal or failure described by a message.
    pub fn msg(message: impl Display) -> Self {
        ResearchError::Refused(message.to_string())
    }

    /// `source`, with what was being done when it happened (`context`) in front of it.
    pub fn within(context: impl Display, source: impl Into<ResearchError>) -> Self {
        ResearchError::Context {
            context: context.to_string(),
            source: Box::new(source.into()),
        }
    }

    /// The error and its causes, joined by ": " (as the command line shows them).
    pub fn chain(&self) -> String {
        let mut text = self.to_string();
        let mut source = std::error::Error::source(self);
        while let Some(s) = source {
            text.push_str(": ");
            text.push_str(&s.to_string());
            source = s.source();
        }
        text
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    /// The chain reads as anyhow's would: each context, then the cause.
    #[test]
    fn contexts_chain_to_their_cause() {
        let io = std::io::Error::new(std::io::ErrorKind::NotFound, "no such file");
        let e = ResearchError::within("seed 3", ResearchError::within("reading a.json", io));
        assert_eq!(e.chain(), "seed 3: reading a.json: no such file");
    }
}
