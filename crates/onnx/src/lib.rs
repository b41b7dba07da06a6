//! Models and policies brought as ONNX files, so a lab tests its own candidate model or its
//! own robot policy (trained in PyTorch, Stable-Baselines3, RLlib) without writing Rust. This
//! is the only crate that names the ONNX engine.
//!
//! **Engine: `tract-onnx` 0.23.9, pinned.** Pure Rust: nothing to download at build or run
//! time (onnxruntime would need its C++ library), memory-safe on hostile files, and fast on
//! the small networks these contracts describe. Pinned exactly because an engine's numerics
//! and operator coverage are part of a result.
//!
//! Every file is checked against its contract when it is loaded, before any work: a file that
//! is missing, not ONNX, has other input or output names, shapes or types, or uses an operator
//! the engine lacks is a one-line error naming the file, what was expected and what was found.
//! A file that declares tensors of gigabytes is refused with bounded memory (see
//! [`CappedAlloc`] and [`MemoryBound`]), one of more than [`MAX_NODES`] nodes before the
//! engine plans it.
//!
//! ```no_run
//! use fishprobe_onnx::OnnxPolicy;
//! use fishprobe_sim::{stream, AgentState, ControlInput, Controller};
//!
//! let mut policy = OnnxPolicy::load("sb3_policy.onnx".as_ref())?;
//! let obs = vec![0.0f32; 180];
//! let input = ControlInput { obs: &obs, robot: AgentState::at(0.0, 0.0, 0.0), fish: &[], goal: [0.0, 0.0] };
//! let turn = policy.act(&input, &mut stream(0, "doc", 0));
//! # Ok::<(), fishprobe_onnx::OnnxError>(())
//! ```

#![warn(missing_docs)]

mod guard;
mod net;
mod policy;

pub use guard::{
    CappedAlloc, MemoryBound, MAX_ALLOCATION_BYTES, MEMORY_ENV, SMALL_ALLOCATION_BYTES,
};
pub use net::{
    hex, node_limit, read_model_file, sha256_hex, Contract, OnnxNet, MAX_FILE_BYTES, MAX_NODES,
    NODES_ENV,
};

// The unit tests check the allocation cap, so their binary installs it as binaries do.
#[cfg(test)]
#[global_allocator]
static ALLOC: CappedAlloc = CappedAlloc;
pub use policy::OnnxPolicy;

use std::path::PathBuf;

/// The engine, as trial files and errors name it.
pub const ENGINE: &str = "tract-onnx 0.23.9";

/// Why an ONNX file cannot be used.
#[derive(Debug, thiserror::Error)]
pub enum OnnxError {
    /// A setting of fishprobe's ONNX limits (an environment variable) that is not one.
    #[error("{0}")]
    Setting(String),
    /// The file cannot be read.
    #[error("{}: cannot read: {reason}", path.display())]
    Read {
        /// The file.
        path: PathBuf,
        /// The OS error.
        reason: std::io::Error,
    },
    /// Not an ONNX model the engine can parse.
    #[error("{}: not an ONNX model: {what}", path.display())]
    NotOnnx {
        /// The file.
        path: PathBuf,
        /// The parser's words.
        what: String,
    },
    /// An ONNX model, but not of the contract.
    #[error("{}: expected {expected}, found {found}", path.display())]
    Contract {
        /// The file.
        path: PathBuf,
        /// What the contract asks for.
        expected: String,
        /// What the file has.
        found: String,
    },
    /// The engine cannot run it (an operator it lacks, or shapes it cannot resolve).
    #[error("{}: {ENGINE} cannot run this model: {what}", path.display())]
    Unsupported {
        /// The file.
        path: PathBuf,
        /// The engine's words.
        what: String,
    },
    /// Over one of the limits that bound the memory and time a file may take (the node
    /// count, the memory bound's setting).
    #[error("{}: refused: {what}", path.display())]
    Limit {
        /// The file.
        path: PathBuf,
        /// Which limit, the file's value and how to raise it.
        what: String,
    },
    /// Running it failed.
    #[error("{}: running the model failed: {what}", path.display())]
    Run {
        /// The file.
        path: PathBuf,
        /// What failed.
        what: String,
    },
}
