//! Errors of the simulator.

use crate::params::ConfigError;

/// Everything that can go wrong in the simulator.
#[derive(Debug, Clone, PartialEq, thiserror::Error)]
pub enum SimError {
    /// A configuration value is out of range.
    #[error(transparent)]
    Config(#[from] ConfigError),
    /// An action contained NaN or infinity; the state was not touched.
    #[error("action {index} is {value}: actions must be finite numbers")]
    NonFiniteAction {
        /// Position in the action vector.
        index: usize,
        /// The value received.
        value: f32,
    },
    /// An action vector of the wrong length.
    #[error("action has {got} values, the action space has {expected}")]
    ActionShape {
        /// Expected length.
        expected: usize,
        /// Received length.
        got: usize,
    },
    /// An output buffer of the wrong length.
    #[error("observation buffer has {got} floats, the observation has {expected}")]
    ObservationShape {
        /// Expected length.
        expected: usize,
        /// Received length.
        got: usize,
    },
    /// `step` was called before `reset`, or after the episode ended.
    #[error("the episode has ended (or never started): call reset before step")]
    NeedsReset,
    /// The OOD objective needs the fish model's support model, and none was given.
    #[error(
        "the OOD objective (task.objective = \"ood\") needs the support model of fish model \
         `{model}`'s training data, and the environment has none (fit-convnet writes one \
         beside the weights)"
    )]
    NoSupport {
        /// The model's name.
        model: String,
    },
    /// A fish model produced NaN or infinite motion.
    #[error("fish model `{model}` produced a non-finite motion at frame {frame}")]
    NonFiniteModelOutput {
        /// The model's name.
        model: String,
        /// The frame.
        frame: u32,
    },
    /// Start poses that do not fit the environment.
    #[error("start poses: {0}")]
    StartPoses(String),
    /// A controller that cannot drive this run: it reads observations of another length or
    /// layout, or was trained at another action rate.
    #[error("{0}")]
    Controller(String),
}
