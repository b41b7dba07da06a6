//! Errors of training, evaluation and export.

/// What can go wrong.
#[derive(Debug, thiserror::Error)]
pub enum LearnError {
    /// A configuration value is out of range.
    #[error(transparent)]
    Config(#[from] fishprobe_sim::ConfigError),
    /// The simulator refused.
    #[error(transparent)]
    Sim(#[from] fishprobe_sim::SimError),
    /// A fish model problem.
    #[error(transparent)]
    Model(#[from] fishprobe_models::ModelError),
    /// Weights files.
    #[error(transparent)]
    Nn(#[from] fishprobe_nn::NnError),
    /// Trial files.
    #[error(transparent)]
    Io(#[from] fishprobe_io::IoError),
    /// Trial data read for a measure (a yardstick's scores).
    #[error(transparent)]
    Analysis(#[from] fishprobe_analysis::AnalysisError),
    /// An ONNX model or policy that cannot be used.
    #[error(transparent)]
    Onnx(#[from] fishprobe_onnx::OnnxError),
    /// A policy directory or file that cannot be used.
    #[error("{0}")]
    Policy(String),
    /// A training run's directory that cannot be resumed or written.
    #[error("{0}")]
    Run(String),
    /// A PPO update's loss went non-finite (the trainer reports it as divergence).
    #[error("non-finite loss (surrogate {surrogate}, KL {kl}, value {value})")]
    NonFiniteLoss {
        /// The surrogate loss.
        surrogate: f64,
        /// The KL divergence.
        kl: f64,
        /// The value loss.
        value: f64,
    },
    /// Training diverged.
    #[error(
        "training diverged at iteration {iteration}: {what}; the last good checkpoint is kept"
    )]
    Diverged {
        /// Iteration.
        iteration: u64,
        /// What went non-finite.
        what: String,
    },
}
