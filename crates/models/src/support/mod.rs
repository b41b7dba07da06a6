//! The support of a data-driven fish model's training data: how well the
//! recordings a model was fitted on cover an input the fish sees.
//!
//! A view (M_ConvNet's 3 x 72 egocentric input, also the ONNX contract's) is reduced to the
//! [`Situation`] it shows: the nearest partner's distance, bearing and relative heading, the
//! nearest wall's distance and bearing, and a second wall's distance (near in a corner). Their
//! 9 [`features`](Situation::features) (log
//! distances, cosines and sines of the angles), standardised by the training views' means and
//! spreads, are the embedding in which the support is estimated, by one of two estimators
//! ([`Estimator`]):
//!
//! - `knn`: the mean distance to the `neighbours` nearest of `reference_views` training views;
//! - `gmm`: the negative log-density of a diagonal Gaussian mixture fitted to them by EM.
//!
//! Each raw value is calibrated on `calibration_views` other training views into a **support
//! score**: 0 at their median, 1 at their 95th percentile (so about 5 % of the training views
//! score above 1), larger further out; never negative. `fishprobe fit-convnet` writes the
//! support file beside the weights (`WEIGHTS.support.json`, with the weights' SHA-256), and
//! `fishprobe support` builds one for any model of the view contract and compares the two
//! estimators on held-out recordings and on situations the data lacks
//! ([`synthetic_views`]).
//!
//! ```
//! use fishprobe_models::support::{SupportConfig, SupportModel};
//! use fishprobe_models::convnet::{encode_view, ConvNetArch};
//! use fishprobe_sim::{stream, AgentState, Tank, TankParams};
//! use rand::RngExt;
//!
//! let arch = ConvNetArch::default();
//! let tank = Tank::new(&TankParams::default());
//! // Training views: two fish in the middle of the tank, 3 to 10 cm apart.
//! let mut rng = stream(1, "doc", 0);
//! let mut views = Vec::new();
//! let mut view = vec![0.0; arch.view_len()];
//! for _ in 0..600 {
//!     let me = AgentState::at(rng.random_range(-20.0..20.0), rng.random_range(-20.0..20.0), 0.0);
//!     let d = rng.random_range(3.0..10.0);
//!     let other = AgentState::at(me.x + d, me.y, 0.0);
//!     encode_view(&arch, &tank, &me, &[other], &mut view);
//!     views.extend_from_slice(&view);
//! }
//! let cfg = SupportConfig { reference_views: 300, calibration_views: 200, ..Default::default() };
//! let support = SupportModel::fit(&arch, &views, &cfg, "example", "", &mut rng).unwrap();
//! // A fish pressed into a corner by a partner right behind it: far outside this data.
//! let me = AgentState::at(49.0, 49.0, 0.0);
//! encode_view(&arch, &tank, &me, &[AgentState::at(46.0, 49.0, 0.0)], &mut view);
//! assert!(support.score_view(&view) > 1.0);
//! ```

use fishprobe_sim::params::{check, ConfigError};
use serde::{Deserialize, Serialize};
use std::path::PathBuf;

mod mixture;
mod model;
mod situation;
mod synthetic;
#[cfg(test)]
mod tests;

pub use mixture::Mixture;
pub use model::*;
pub use situation::*;
pub use synthetic::*;

/// The shipped M_ConvNet's support file (`assets/convnet.support.json`, made by `fishprobe
/// support`; see docs/validation.md).
static SHIPPED_CONVNET: &str = include_str!("../../assets/convnet.support.json");

/// The support model of the shipped M_ConvNet's training views.
pub fn shipped_convnet() -> Result<SupportModel, SupportError> {
    let invalid = |what: String| SupportError::Invalid {
        path: "shipped with fishprobe (convnet.support.json)".into(),
        what,
    };
    let s = SupportModel::from_json(SHIPPED_CONVNET).map_err(|e| invalid(e.to_string()))?;
    if s.model_sha256 != crate::convnet::shipped_sha256() {
        return Err(invalid(
            "built for other weights than the shipped ones".into(),
        ));
    }
    Ok(s)
}

/// Format name written into support files.
const FORMAT: &str = "fishprobe-support";
/// Format version.
const VERSION: u32 = 1;
/// Largest support file read (a file declaring more is refused before it is read).
pub const MAX_FILE_BYTES: u64 = 64 << 20;

/// How the support is estimated.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Default, Serialize, Deserialize)]
#[serde(rename_all = "snake_case")]
pub enum Estimator {
    /// Mean distance to the k nearest reference views.
    #[default]
    Knn,
    /// Negative log-density of a diagonal Gaussian mixture.
    Gmm,
}

impl std::str::FromStr for Estimator {
    type Err = String;
    fn from_str(s: &str) -> Result<Self, String> {
        match s {
            "knn" => Ok(Self::Knn),
            "gmm" => Ok(Self::Gmm),
            _ => Err(format!("unknown estimator `{s}` (knn or gmm)")),
        }
    }
}

fishprobe_sim::documented_params! {
    /// How a support model is built from a model's training views.
    pub struct SupportConfig {
        /// `knn` (choice: the comparison in docs/validation.md favours it) or `gmm`.
        pub estimator: Estimator = Estimator::Knn; "-",
        /// Neighbours averaged by `knn` (choice: 10).
        pub neighbours: usize = 10; "views",
        /// Training views kept as the reference (`knn`) or fitted (`gmm`), drawn uniformly
        /// (choice: 4096; the cost per scored view grows with it).
        pub reference_views: usize = 4096; "views",
        /// Other training views that calibrate the score (choice: 2048).
        pub calibration_views: usize = 2048; "views",
        /// Components of the `gmm` (choice: 16).
        pub components: usize = 16; "1",
        /// EM iterations of the `gmm` (choice: 100).
        pub em_iterations: usize = 100; "1",
        /// Partners farther than this are embedded as not seen, at this distance, in the
        /// training views and in every scored view alike (choice: 0, no range: every partner
        /// the view shows counts, up to the far plane, since M_ConvNet still turns toward a
        /// partner 40 cm away at two thirds of its close-range rate; 15 makes the OOD task
        /// seek close interactions; docs/validation.md, "Probes that seek what the data lacks"). In
        /// [0, 1000].
        pub partner_range_cm: f32 = 0.0; "cm",
    }
}

impl SupportConfig {
    /// Checks the ranges.
    pub fn validate(&self) -> Result<(), ConfigError> {
        let bad = |f: &str, v: usize, why: &str| Err(ConfigError::new("support", f, v, why));
        if !(1..=64).contains(&self.neighbours) {
            return bad("neighbours", self.neighbours, "must lie in [1, 64]");
        }
        if !(16..=1 << 20).contains(&self.reference_views) {
            return bad(
                "reference_views",
                self.reference_views,
                "must lie in [16, 1048576]",
            );
        }
        if self.neighbours >= self.reference_views {
            return bad(
                "neighbours",
                self.neighbours,
                "must be fewer than reference_views",
            );
        }
        if !(20..=1 << 20).contains(&self.calibration_views) {
            return bad(
                "calibration_views",
                self.calibration_views,
                "must lie in [20, 1048576]",
            );
        }
        if !(1..=256).contains(&self.components) {
            return bad("components", self.components, "must lie in [1, 256]");
        }
        // Beyond any tank (10 m) a range means what 0 does; a typo like 1e30 is refused.
        check::within(
            "support",
            "partner_range_cm",
            self.partner_range_cm,
            0.0,
            check::MAX_LENGTH_CM,
        )?;
        if !(1..=10_000).contains(&self.em_iterations) {
            return bad(
                "em_iterations",
                self.em_iterations,
                "must lie in [1, 10000]",
            );
        }
        Ok(())
    }
}

/// Why a support model cannot be built or used.
#[derive(Debug, Clone, PartialEq, thiserror::Error)]
pub enum SupportError {
    /// A support file's text that is not one (with why).
    #[error("{0}")]
    NotASupportFile(String),
    /// Settings out of range.
    #[error(transparent)]
    Config(#[from] ConfigError),
    /// Too few training views.
    #[error("{got} training views, but a support model needs at least {need}")]
    TooFewViews {
        /// Views given.
        got: usize,
        /// Views needed.
        need: usize,
    },
    /// No support file beside the model.
    #[error(
        "no support file for {model} at {path}: the OOD objective needs one; `fishprobe \
         fit-convnet` writes it beside the weights, `fishprobe support --model ...` builds it \
         for a model's training recordings"
    )]
    Missing {
        /// The model.
        model: String,
        /// Where it was looked for.
        path: PathBuf,
    },
    /// No ensemble beside the model (the `disagreement` OOD score).
    #[error(
        "no ensemble for {model} at {path}: the OOD score `disagreement` needs one; `fishprobe \
         fit-convnet --members K` fits K - 1 further members beside the weights and writes it"
    )]
    MissingEnsemble {
        /// The model.
        model: String,
        /// Where it was looked for.
        path: PathBuf,
    },
    /// A support file that belongs to other weights.
    #[error(
        "support file {path} was built for the model with SHA-256 {found}, not for {model} \
         (SHA-256 {expected}): rebuild it with `fishprobe support --model ...`"
    )]
    OtherModel {
        /// The file.
        path: PathBuf,
        /// The model.
        model: String,
        /// The model's hash.
        expected: String,
        /// The hash the file names.
        found: String,
    },
    /// A file that is not a usable support file.
    #[error("support file {path}: {what}")]
    Invalid {
        /// The file.
        path: String,
        /// What is wrong.
        what: String,
    },
    /// Writing failed.
    #[error("writing {path}: {what}")]
    Write {
        /// The file.
        path: PathBuf,
        /// The OS error.
        what: String,
    },
}
