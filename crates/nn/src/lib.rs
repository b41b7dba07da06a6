//! A small neural-network kit, written for the network sizes of this project (MLPs of a few
//! hundred units, a small 1-D convolution): dense layers on `matrixmultiply`'s GEMM, a fast
//! tanh, Leaky-ReLU, circular 1-D convolution, softmax cross-entropy, diagonal-Gaussian
//! log-probability, entropy and KL with gradients, Adam, and safetensors files with a JSON
//! sidecar. Every layer's gradient is checked against finite differences in the tests.
//!
//! Why hand-written: for 2 x 256 MLPs with minibatches of 512, a framework's per-op overhead
//! dominates; a GEMM crate plus hand-written backward passes keeps the work in the matrix
//! kernels (the project measured about 4x over candle or burn at these sizes). `fishprobe bench
//! train` reports GFLOP/s next to the machine's single-core GEMM rate. Narrow output layers (at
//! most 4 units) use plain loops, and a first layer with a mostly-zero input (the policy's
//! observations) visits only the nonzeros, bit-identical to the dense product
//! ([`gemm::SparseRows`]). For inference on a few rows at a time (the ConvNet fish, at every
//! frame) [`PackedMlp`] packs the weights once and computes every output as one FMA chain, so
//! a row's result does not depend on its batch; the fish's softmax uses a vectorised exp
//! ([`dist::softmax_rows`]).
//!
//! ```
//! use fishprobe_nn::{Activation, Adam, Mlp, MlpSpec, MlpWorkspace};
//! use rand::SeedableRng;
//!
//! let mut rng = rand_xoshiro::Xoshiro256PlusPlus::seed_from_u64(0);
//! let mut net = Mlp::new(MlpSpec { sizes: vec![2, 16, 1], hidden: Activation::Tanh }, 1.0, &mut rng);
//! let mut adam = Adam::new(net.num_params(), 0.01);
//! let mut ws = MlpWorkspace::default();
//! let x = [0.5f32, -1.0];
//! for _ in 0..200 {
//!     // Fit y = 0.3 at x: squared error, gradient 2 (y - 0.3).
//!     let y = net.forward(&x, 1, &mut ws)[0];
//!     let mut grads = vec![0.0; net.num_params()];
//!     net.backward(&x, 1, &[2.0 * (y - 0.3)], &mut ws, &mut grads, None);
//!     adam.step(net.params_mut(), &grads);
//! }
//! assert!((net.forward(&x, 1, &mut ws)[0] - 0.3).abs() < 1e-3);
//! ```

#![warn(missing_docs)]

pub mod act;
pub mod adam;
pub mod conv1d;
pub mod dist;
pub mod error;
pub mod gemm;
pub mod mlp;
pub mod store;

pub use act::{tanh_fast, Activation};
pub use adam::Adam;
pub use conv1d::Conv1d;
pub use error::NnError;
pub use mlp::{Mlp, MlpSpec, MlpWorkspace, PackedMlp};
