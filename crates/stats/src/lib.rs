//! The statistics of the study (SPEC §8), as pure functions on slices with an explicit RNG and
//! no I/O. Each names the scipy or statsmodels function it matches; the tests hold values
//! computed by those libraries.
//!
//! ```
//! use fishprobe_stats::{wasserstein, cliffs_delta, magnitude, permutation_test_wasserstein};
//! use rand::SeedableRng;
//!
//! let sim = [61.0, 58.0, 64.0, 60.0, 57.0];
//! let real = [41.0, 39.0, 52.0, 45.0, 47.0];
//! let w = wasserstein(&sim, &real)?;               // scipy.stats.wasserstein_distance
//! let d = cliffs_delta(&sim, &real)?;              // P(sim > real) - P(sim < real)
//! let mut rng = rand_xoshiro::Xoshiro256PlusPlus::seed_from_u64(1);
//! let t = permutation_test_wasserstein(&sim, &real, 9_999, &mut rng)?;
//! assert!(w > 10.0 && d == 1.0 && magnitude(d) == "large" && t.p < 0.05);
//! # Ok::<(), fishprobe_stats::StatsError>(())
//! ```

#![warn(missing_docs)]

pub mod cliff;
pub mod error;
pub mod holm;
pub mod kruskal;
pub mod linalg;
pub mod nb2;
pub mod paired;
pub mod resample;
pub mod sample;
pub mod special;
pub mod spread;
pub mod stability;
pub mod wasserstein;

pub use cliff::{cliffs_delta, magnitude};
pub use error::StatsError;
pub use holm::holm;
pub use kruskal::{kruskal, Kruskal};
pub use nb2::{fit_nb2, Nb2Fit, Wald};
pub use paired::{paired_t, PairedT};
pub use resample::{
    bootstrap_wasserstein, cluster_bootstrap_median, permutation_test_wasserstein, PermutationTest,
};
pub use sample::{mean, median, percentile_ci, quantile_sorted, sd, variance};
pub use spread::{bootstrap_sd_ratio, brown_forsythe, rankdata, sd_exact, spearman, TestResult};
pub use stability::{stability, Stability};
pub use wasserstein::{wasserstein, wasserstein_sorted};
