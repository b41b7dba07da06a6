//! The support of a data-driven fish model's training data (issue 23): how well the
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

use crate::convnet::{encode_view, ConvNetArch, CHANNELS};
use fishprobe_sim::params::{check, ConfigError};
use fishprobe_sim::{wrap_angle, AgentState, FishView, InputSupport, SimRng, Tank};
use rand::RngExt;
use serde::{Deserialize, Serialize};
use std::f32::consts::PI;
use std::path::{Path, PathBuf};

/// Features of the embedding.
pub const FEATURES: usize = 9;

/// Names of the features, in order.
pub const FEATURE_NAMES: [&str; FEATURES] = [
    "ln(1 + partner distance / cm)",
    "cos partner bearing",
    "sin partner bearing",
    "cos relative heading",
    "sin relative heading",
    "ln(1 + wall distance / cm)",
    "cos wall bearing",
    "sin wall bearing",
    "ln(1 + second wall distance / cm)",
];

/// The second wall is the nearest one at least this far in bearing from the nearest wall
/// (choice: 80°): at a straight wall it lies 1/cos 80° ≈ 5.8 times further than the first,
/// in a corner about as near.
pub const SECOND_WALL_MIN_ANGLE_RAD: f32 = 80.0 * PI / 180.0;

/// Format name written into support files.
const FORMAT: &str = "fishprobe-support";
/// Format version.
const VERSION: u32 = 1;
/// Largest support file read (a file declaring more is refused before it is read).
pub const MAX_FILE_BYTES: u64 = 64 << 20;

/// What a view shows, in plain terms. Angles are egocentric (0 = straight ahead, positive
/// to the left), in radians in [-π, π).
#[derive(Debug, Clone, Copy, PartialEq, Default, Serialize, Deserialize)]
pub struct Situation {
    /// Whether the view shows another agent at all.
    pub partner_seen: bool,
    /// Distance to the nearest other agent (cm; the far plane when none is seen).
    pub partner_distance_cm: f32,
    /// Bearing of that agent (0 when none is seen).
    pub partner_bearing_rad: f32,
    /// Its heading relative to the fish's (π: head-on when ahead; 0 when none is seen).
    pub relative_heading_rad: f32,
    /// Distance to the nearest wall along the view's rays (cm).
    pub wall_distance_cm: f32,
    /// Bearing of that wall.
    pub wall_bearing_rad: f32,
    /// Distance to the nearest wall at least [`SECOND_WALL_MIN_ANGLE_RAD`] in bearing from
    /// the nearest one (cm): near in a corner, far along a straight wall.
    pub second_wall_cm: f32,
}

impl Situation {
    /// The situation a view (`3 x bins`, channel-major, as [`encode_view`] writes it) shows.
    pub fn of_view(arch: &ConvNetArch, view: &[f32]) -> Self {
        let n = arch.bins;
        let width = std::f32::consts::TAU / n as f32;
        let centre = |i: usize| -PI + (i as f32 + 0.5) * width;
        let argmax = |c: &[f32]| {
            c.iter()
                .enumerate()
                .fold((0usize, f32::NEG_INFINITY), |(bi, bv), (i, &v)| {
                    if v > bv {
                        (i, v)
                    } else {
                        (bi, bv)
                    }
                })
        };
        let (wi, wv) = argmax(&view[..n]);
        let (pi, pv) = argmax(&view[n..2 * n]);
        let far = arch.far_plane_cm;
        // Bins at least the second wall's angle away from the nearest wall's bin (circularly).
        let min_bins = (SECOND_WALL_MIN_ANGLE_RAD / width).ceil() as usize;
        let second = view[..n]
            .iter()
            .enumerate()
            .filter(|(i, _)| {
                let d = i.abs_diff(wi);
                d.min(n - d) >= min_bins
            })
            .fold(0.0f32, |m, (_, &v)| m.max(v));
        let mut s = Situation {
            second_wall_cm: far * (1.0 - second.max(0.0)),
            partner_distance_cm: far,
            wall_distance_cm: far * (1.0 - wv.max(0.0)),
            wall_bearing_rad: centre(wi),
            ..Situation::default()
        };
        if pv > 0.0 {
            s.partner_seen = true;
            s.partner_distance_cm = far * (1.0 - pv);
            s.partner_bearing_rad = centre(pi);
            s.relative_heading_rad = wrap_angle(view[2 * n + pi] * PI);
        }
        s
    }

    /// The embedding's features (see [`FEATURE_NAMES`]), every partner the view shows.
    pub fn features(&self) -> [f32; FEATURES] {
        self.features_within(0.0)
    }

    /// The embedding's features with partners farther than `partner_range_cm` embedded as
    /// not seen, at that distance (0: no range, every partner the view shows).
    pub fn features_within(&self, partner_range_cm: f32) -> [f32; FEATURES] {
        let (bs, bc) = self.partner_bearing_rad.sin_cos();
        let (hs, hc) = self.relative_heading_rad.sin_cos();
        let (ws, wc) = self.wall_bearing_rad.sin_cos();
        let beyond = partner_range_cm > 0.0 && self.partner_distance_cm > partner_range_cm;
        let g = if self.partner_seen && !beyond {
            1.0
        } else {
            0.0
        };
        let partner = if beyond {
            partner_range_cm
        } else {
            self.partner_distance_cm
        };
        [
            partner.max(0.0).ln_1p(),
            g * bc,
            g * bs,
            g * hc,
            g * hs,
            self.wall_distance_cm.max(0.0).ln_1p(),
            wc,
            ws,
            self.second_wall_cm.max(0.0).ln_1p(),
        ]
    }

    /// One line in plain terms.
    pub fn describe(&self) -> String {
        let side = |a: f32| {
            let d = a.to_degrees();
            if d.abs() <= 30.0 {
                "ahead".to_string()
            } else if d.abs() >= 150.0 {
                "behind".to_string()
            } else if d > 0.0 {
                format!("{:.0}° to the left", d)
            } else {
                format!("{:.0}° to the right", -d)
            }
        };
        let h = self.relative_heading_rad.to_degrees().abs();
        let heading = if h >= 135.0 {
            "head-on"
        } else if h <= 45.0 {
            "swimming the same way"
        } else {
            "crossing"
        };
        let corner = if self.second_wall_cm < 5.0 {
            format!(" (in a corner: another wall {:.1} cm)", self.second_wall_cm)
        } else {
            String::new()
        };
        format!(
            "partner {:.1} cm {}, {}; wall {:.1} cm {}{corner}",
            self.partner_distance_cm,
            side(self.partner_bearing_rad),
            heading,
            self.wall_distance_cm,
            side(self.wall_bearing_rad)
        )
    }
}

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
        /// seek close interactions; docs/validation.md, "A partner range for the support"). In
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
            1000.0,
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

/// A diagonal Gaussian mixture over the embedding.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
pub struct Mixture {
    /// Log mixing weights.
    pub log_weights: Vec<f32>,
    /// Means, one row per component.
    pub means: Vec<[f32; FEATURES]>,
    /// Variances, one row per component.
    pub variances: Vec<[f32; FEATURES]>,
}

/// Variance floor of the mixture (standardised units): a component on a few identical
/// points must not collapse.
const VAR_FLOOR: f32 = 1e-3;

impl Mixture {
    /// Log-density of each component at `z` (without the weights) into `out`.
    fn component_logs(&self, z: &[f32; FEATURES], out: &mut [f32]) {
        let c = (FEATURES as f32) * (2.0 * PI).ln();
        for (o, (m, v)) in out.iter_mut().zip(self.means.iter().zip(&self.variances)) {
            let mut q = 0.0;
            let mut logdet = 0.0;
            for d in 0..FEATURES {
                let e = z[d] - m[d];
                q += e * e / v[d];
                logdet += v[d].ln();
            }
            *o = -0.5 * (c + logdet + q);
        }
    }

    /// Negative log-density at `z`.
    fn nll(&self, z: &[f32; FEATURES]) -> f32 {
        let mut best = f32::NEG_INFINITY;
        let mut logs = [0.0f32; 256];
        let k = self.means.len().min(256);
        self.component_logs(z, &mut logs[..k]);
        for (l, w) in logs[..k].iter_mut().zip(&self.log_weights) {
            *l += w;
            best = best.max(*l);
        }
        let s: f32 = logs[..k].iter().map(|l| (l - best).exp()).sum();
        -(best + s.ln())
    }

    /// EM from `k` points drawn as initial means.
    fn fit(points: &[[f32; FEATURES]], k: usize, iterations: usize, rng: &mut SimRng) -> Self {
        let n = points.len();
        let k = k.min(n);
        let mut m = Mixture {
            log_weights: vec![-(k as f32).ln(); k],
            means: (0..k).map(|_| points[rng.random_range(0..n)]).collect(),
            variances: vec![[1.0; FEATURES]; k],
        };
        let mut resp = vec![0.0f32; n * k];
        for _ in 0..iterations {
            // E step.
            for (z, r) in points.iter().zip(resp.chunks_exact_mut(k)) {
                m.component_logs(z, r);
                let mut best = f32::NEG_INFINITY;
                for (l, w) in r.iter_mut().zip(&m.log_weights) {
                    *l += w;
                    best = best.max(*l);
                }
                let mut s = 0.0;
                for l in r.iter_mut() {
                    *l = (*l - best).exp();
                    s += *l;
                }
                r.iter_mut().for_each(|l| *l /= s);
            }
            // M step.
            for j in 0..k {
                let mut w = 0.0f64;
                let mut mean = [0.0f64; FEATURES];
                for (z, r) in points.iter().zip(resp.chunks_exact(k)) {
                    w += f64::from(r[j]);
                    for d in 0..FEATURES {
                        mean[d] += f64::from(r[j] * z[d]);
                    }
                }
                if w < 1e-6 {
                    // An empty component restarts on a random point.
                    m.means[j] = points[rng.random_range(0..n)];
                    m.variances[j] = [1.0; FEATURES];
                    m.log_weights[j] = (1.0 / n as f32).ln();
                    continue;
                }
                let mean: [f64; FEATURES] = std::array::from_fn(|d| mean[d] / w);
                let mut var = [0.0f64; FEATURES];
                for (z, r) in points.iter().zip(resp.chunks_exact(k)) {
                    for d in 0..FEATURES {
                        let e = f64::from(z[d]) - mean[d];
                        var[d] += f64::from(r[j]) * e * e;
                    }
                }
                m.means[j] = std::array::from_fn(|d| mean[d] as f32);
                m.variances[j] = std::array::from_fn(|d| ((var[d] / w) as f32).max(VAR_FLOOR));
                m.log_weights[j] = (w / n as f64).ln() as f32;
            }
        }
        m
    }
}

/// A support model: embedding, estimator and calibration, as saved in a support file.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct SupportModel {
    /// Always "fishprobe-support".
    pub format: String,
    /// Format version (1).
    pub version: u32,
    /// The model the support belongs to (name or file).
    pub model: String,
    /// SHA-256 of the model's weights (or ONNX) file; empty: not checked.
    pub model_sha256: String,
    /// Bins of the view.
    pub bins: usize,
    /// Far plane of the view (cm).
    pub far_plane_cm: f32,
    /// How it was built.
    pub config: SupportConfig,
    /// Mean of each feature over the reference views.
    pub mean: [f32; FEATURES],
    /// Standard deviation of each feature over the reference views.
    pub std: [f32; FEATURES],
    /// Median of the raw estimator values of the calibration views.
    pub raw_median: f32,
    /// Their 95th percentile.
    pub raw_p95: f32,
    /// Reference views, standardised (`knn`; empty for `gmm`).
    pub points: Vec<[f32; FEATURES]>,
    /// The mixture (`gmm`).
    pub mixture: Option<Mixture>,
    /// Training views the references were drawn from.
    pub training_views: usize,
    /// Free notes: the command, the training files.
    #[serde(default)]
    pub provenance: serde_json::Value,
    /// `points` feature-major (feature d of point i at `d * n + i`), so that the distances
    /// to a block of points vectorise; built from `points` by fit and load.
    #[serde(skip)]
    columns: Vec<f32>,
}

/// A raw value as a score: 0 at the calibration views' `median` (and below), 1 at their `p95`,
/// linear beyond. A NaN input (never from a simulated view) counts as far outside (1000).
pub(crate) fn calibrated(raw: f32, median: f32, p95: f32) -> f32 {
    let s = (raw - median) / (p95 - median);
    if s.is_finite() {
        s.max(0.0)
    } else {
        1e3
    }
}

/// `k` distinct indices of `0..n`, drawn uniformly (partial Fisher-Yates).
pub(crate) fn draw(n: usize, k: usize, rng: &mut SimRng) -> Vec<usize> {
    let mut idx: Vec<usize> = (0..n).collect();
    for i in 0..k.min(n) {
        let j = rng.random_range(i..n);
        idx.swap(i, j);
    }
    idx.truncate(k.min(n));
    idx
}

/// The `q`-quantile (linear interpolation) of `v`, which it sorts.
pub(crate) fn quantile(v: &mut [f32], q: f32) -> f32 {
    v.sort_by(f32::total_cmp);
    if v.is_empty() {
        return f32::NAN;
    }
    let pos = q * (v.len() - 1) as f32;
    let (lo, hi) = (pos.floor() as usize, pos.ceil() as usize);
    v[lo] + (v[hi] - v[lo]) * (pos - lo as f32)
}

impl SupportModel {
    /// Builds the support of the training views `views` (`n x view_len`) of a model whose
    /// view is `arch`'s; `model` and `model_sha256` name what it belongs to.
    pub fn fit(
        arch: &ConvNetArch,
        views: &[f32],
        cfg: &SupportConfig,
        model: &str,
        model_sha256: &str,
        rng: &mut SimRng,
    ) -> Result<Self, SupportError> {
        cfg.validate()?;
        let len = arch.view_len();
        let n = views.len() / len;
        // With less data than asked for, a third calibrates and the rest is the reference.
        let n_cal = cfg.calibration_views.min(n / 3);
        let n_ref = cfg.reference_views.min(n - n_cal);
        if n_cal < 20 || n_ref <= cfg.neighbours {
            return Err(SupportError::TooFewViews {
                got: n,
                need: 60.max(3 * (cfg.neighbours + 1)),
            });
        }
        let idx = draw(n, n_ref + n_cal, rng);
        let feats = |i: usize| {
            Situation::of_view(arch, &views[i * len..(i + 1) * len])
                .features_within(cfg.partner_range_cm)
        };
        let reference: Vec<[f32; FEATURES]> = idx[..n_ref].iter().map(|&i| feats(i)).collect();
        let calibration: Vec<[f32; FEATURES]> = idx[n_ref..].iter().map(|&i| feats(i)).collect();
        let mut mean = [0.0f32; FEATURES];
        let mut std = [0.0f32; FEATURES];
        for d in 0..FEATURES {
            let m = reference.iter().map(|f| f64::from(f[d])).sum::<f64>() / n_ref as f64;
            let v = reference
                .iter()
                .map(|f| (f64::from(f[d]) - m).powi(2))
                .sum::<f64>()
                / n_ref as f64;
            mean[d] = m as f32;
            // A feature constant in the data still separates what differs from it.
            std[d] = (v.sqrt() as f32).max(0.05);
        }
        let mut s = SupportModel {
            format: FORMAT.into(),
            version: VERSION,
            model: model.into(),
            model_sha256: model_sha256.into(),
            bins: arch.bins,
            far_plane_cm: arch.far_plane_cm,
            config: cfg.clone(),
            mean,
            std,
            raw_median: 0.0,
            raw_p95: 1.0,
            points: Vec::new(),
            mixture: None,
            training_views: n,
            provenance: serde_json::Value::Null,
            columns: Vec::new(),
        };
        let z: Vec<[f32; FEATURES]> = reference.iter().map(|f| s.standardise(f)).collect();
        match cfg.estimator {
            Estimator::Knn => {
                s.points = z;
                s.index();
            }
            Estimator::Gmm => {
                s.mixture = Some(Mixture::fit(&z, cfg.components, cfg.em_iterations, rng))
            }
        }
        let mut raw: Vec<f32> = calibration
            .iter()
            .map(|f| s.raw(&s.standardise(f)))
            .collect();
        s.raw_median = quantile(&mut raw, 0.5);
        s.raw_p95 = quantile(&mut raw, 0.95);
        if s.raw_p95.partial_cmp(&s.raw_median) != Some(std::cmp::Ordering::Greater) {
            // Degenerate data (all views alike): any spread above the median is "out".
            s.raw_p95 = s.raw_median + 1e-3;
        }
        Ok(s)
    }

    /// The view layout the support was built for.
    pub fn arch(&self) -> ConvNetArch {
        ConvNetArch {
            bins: self.bins,
            far_plane_cm: self.far_plane_cm,
            ..ConvNetArch::default()
        }
    }

    /// Builds the feature-major copy of the reference points.
    fn index(&mut self) {
        let n = self.points.len();
        self.columns = vec![0.0; n * FEATURES];
        for (i, p) in self.points.iter().enumerate() {
            for (d, &v) in p.iter().enumerate() {
                self.columns[d * n + i] = v;
            }
        }
    }

    fn standardise(&self, f: &[f32; FEATURES]) -> [f32; FEATURES] {
        std::array::from_fn(|d| (f[d] - self.mean[d]) / self.std[d])
    }

    /// The estimator's raw value at a standardised point (larger: less supported).
    fn raw(&self, z: &[f32; FEATURES]) -> f32 {
        match &self.mixture {
            Some(m) => m.nll(z),
            None => {
                let k = self.config.neighbours.min(64);
                let mut best = [f32::INFINITY; 64];
                // Distances a block at a time over the feature-major columns (vectorised),
                // then the few that beat the k-th best go into the sorted k best.
                const BLOCK: usize = 256;
                let n = self.points.len();
                let mut d2s = [0.0f32; BLOCK];
                let mut start = 0;
                while start < n {
                    let len = BLOCK.min(n - start);
                    let d2s = &mut d2s[..len];
                    d2s.fill(0.0);
                    for (d, zd) in z.iter().enumerate() {
                        let col = &self.columns[d * n + start..d * n + start + len];
                        for (o, p) in d2s.iter_mut().zip(col) {
                            let e = zd - p;
                            *o += e * e;
                        }
                    }
                    for &d2 in d2s.iter() {
                        if d2 < best[k - 1] {
                            let mut i = k - 1;
                            while i > 0 && best[i - 1] > d2 {
                                best[i] = best[i - 1];
                                i -= 1;
                            }
                            best[i] = d2;
                        }
                    }
                    start += len;
                }
                best[..k].iter().map(|d2| d2.sqrt()).sum::<f32>() / k as f32
            }
        }
    }

    /// The support score of a situation's features.
    pub fn score_features(&self, f: &[f32; FEATURES]) -> f32 {
        calibrated(
            self.raw(&self.standardise(f)),
            self.raw_median,
            self.raw_p95,
        )
    }

    /// The support score of a situation, embedded as the support was built.
    pub fn score_situation(&self, s: &Situation) -> f32 {
        self.score_features(&s.features_within(self.config.partner_range_cm))
    }

    /// The support score of a view (`3 x bins`).
    pub fn score_view(&self, view: &[f32]) -> f32 {
        self.score_situation(&Situation::of_view(&self.arch(), view))
    }

    /// The situation fish `me` is in among `others`, as the model sees it.
    pub fn situation(&self, tank: &Tank, me: &AgentState, others: &[AgentState]) -> Situation {
        let arch = self.arch();
        let mut buf = [0.0f32; CHANNELS * 720];
        let view = &mut buf[..arch.view_len()];
        encode_view(&arch, tank, me, others, view);
        Situation::of_view(&arch, view)
    }

    /// Writes the support file (atomically: a temporary file renamed into place).
    pub fn save(&self, path: &Path) -> Result<(), SupportError> {
        let err = |e: String| SupportError::Write {
            path: path.to_path_buf(),
            what: e,
        };
        let text = serde_json::to_string(self).map_err(|e| err(e.to_string()))?;
        let tmp = path.with_extension("support.json.tmp");
        std::fs::write(&tmp, text).map_err(|e| err(e.to_string()))?;
        std::fs::rename(&tmp, path).map_err(|e| err(e.to_string()))
    }

    /// Reads a support file and checks it: format, sizes, finite numbers, and, when
    /// `expected_sha256` is not empty, that it belongs to that model.
    pub fn load(path: &Path, model: &str, expected_sha256: &str) -> Result<Self, SupportError> {
        let invalid = |what: String| SupportError::Invalid {
            path: path.display().to_string(),
            what,
        };
        let text = read_file_beside(
            path,
            (MAX_FILE_BYTES, "fishprobe_models::support::MAX_FILE_BYTES"),
            || SupportError::Missing {
                model: model.into(),
                path: path.to_path_buf(),
            },
        )?;
        let s = Self::from_json(&text).map_err(invalid)?;
        if !expected_sha256.is_empty() && s.model_sha256 != expected_sha256 {
            return Err(SupportError::OtherModel {
                path: path.to_path_buf(),
                model: model.into(),
                expected: expected_sha256.into(),
                found: s.model_sha256.clone(),
            });
        }
        Ok(s)
    }

    /// Parses and checks a support file's text.
    pub fn from_json(text: &str) -> Result<Self, String> {
        let mut s: SupportModel =
            serde_json::from_str(text).map_err(|e| format!("not a fishprobe support file: {e}"))?;
        if s.format != FORMAT || s.version != VERSION {
            return Err(format!(
                "format {} version {}, not {FORMAT} version {VERSION}",
                s.format, s.version
            ));
        }
        s.config.validate().map_err(|e| e.to_string())?;
        s.arch().validate().map_err(|e| e.to_string())?;
        let finite = |v: &[f32]| v.iter().all(|x| x.is_finite());
        let ok = finite(&s.mean)
            && finite(&s.std)
            && s.std.iter().all(|&x| x > 0.0)
            && s.raw_median.is_finite()
            && s.raw_p95.is_finite()
            && s.raw_p95 > s.raw_median;
        if !ok {
            return Err("non-finite or degenerate calibration".into());
        }
        match (&s.mixture, s.config.estimator) {
            (None, Estimator::Knn) => {
                if s.points.len() <= s.config.neighbours || !s.points.iter().all(|p| finite(p)) {
                    return Err(format!(
                        "{} reference views for {} neighbours, or non-finite ones",
                        s.points.len(),
                        s.config.neighbours
                    ));
                }
            }
            (Some(m), Estimator::Gmm) => {
                let k = m.means.len();
                if k == 0
                    || k > 256
                    || m.variances.len() != k
                    || m.log_weights.len() != k
                    || !m.means.iter().chain(&m.variances).all(|p| finite(p))
                    || !m.variances.iter().all(|v| v.iter().all(|&x| x > 0.0))
                    || !finite(&m.log_weights)
                {
                    return Err("a malformed mixture".into());
                }
            }
            _ => return Err("estimator and stored parameters disagree".into()),
        }
        s.index();
        Ok(s)
    }
}

impl InputSupport for SupportModel {
    fn score(&self, view: &FishView) -> f32 {
        self.score_situation(&self.situation(&view.tank, &view.me, view.others()))
    }
}

/// Kinds of views the guppy-pair data lacks, for checking a support model.
pub const SYNTHETIC_KINDS: [&str; 2] = ["pressed into a corner", "head-on approach"];

/// `n` views of each [`SYNTHETIC_KINDS`] situation, built from poses: a fish within 2 cm of
/// both walls of a corner with its partner 2-5 cm away on the open side; a fish away from the
/// walls with its partner 2-6 cm straight ahead (±15°), heading at it (±20°).
pub fn synthetic_views(
    arch: &ConvNetArch,
    tank: &Tank,
    n: usize,
    rng: &mut SimRng,
) -> Vec<(&'static str, Vec<f32>)> {
    let len = arch.view_len();
    let mut out = Vec::new();
    let mut view = vec![0.0; len];
    let lim = tank.half - tank.margin;
    let mut corner = Vec::with_capacity(n * len);
    for _ in 0..n {
        let (sx, sy) = (
            if rng.random_bool(0.5) { 1.0 } else { -1.0 },
            if rng.random_bool(0.5) { 1.0 } else { -1.0 },
        );
        let x = sx * (lim - rng.random_range(0.0..2.0));
        let y = sy * (lim - rng.random_range(0.0..2.0));
        let me = AgentState::at(x, y, rng.random_range(-PI..PI));
        // The partner sits towards the centre.
        let a = (-sy).atan2(-sx) + rng.random_range(-0.5..0.5);
        let d = rng.random_range(2.0..5.0);
        let other = AgentState::at(x + d * a.cos(), y + d * a.sin(), rng.random_range(-PI..PI));
        encode_view(arch, tank, &me, &[other], &mut view);
        corner.extend_from_slice(&view);
    }
    out.push((SYNTHETIC_KINDS[0], corner));
    let mut head_on = Vec::with_capacity(n * len);
    for _ in 0..n {
        let inner = lim - 15.0;
        let me = AgentState::at(
            rng.random_range(-inner..inner),
            rng.random_range(-inner..inner),
            rng.random_range(-PI..PI),
        );
        let b = me.heading + rng.random_range(-0.26..0.26);
        let d = rng.random_range(2.0..6.0);
        let h = me.heading + PI + rng.random_range(-0.35..0.35);
        let other = AgentState::at(me.x + d * b.cos(), me.y + d * b.sin(), h);
        encode_view(arch, tank, &me, &[other], &mut view);
        head_on.extend_from_slice(&view);
    }
    out.push((SYNTHETIC_KINDS[1], head_on));
    out
}

/// Area under the ROC curve for separating `outside` (positive) from `inside` by score: the
/// probability that a random outside view scores higher than a random inside one (ties half).
pub fn auc(inside: &[f32], outside: &[f32]) -> f64 {
    let mut all: Vec<(f32, bool)> = inside
        .iter()
        .map(|&s| (s, false))
        .chain(outside.iter().map(|&s| (s, true)))
        .collect();
    all.sort_by(|a, b| a.0.total_cmp(&b.0));
    // Mann-Whitney U from mid-ranks.
    let mut rank_sum = 0.0f64;
    let mut i = 0;
    while i < all.len() {
        let mut j = i;
        while j < all.len() && all[j].0 == all[i].0 {
            j += 1;
        }
        let mid = (i + j + 1) as f64 / 2.0;
        rank_sum += all[i..j].iter().filter(|x| x.1).count() as f64 * mid;
        i = j;
    }
    let (n1, n0) = (outside.len() as f64, inside.len() as f64);
    (rank_sum - n1 * (n1 + 1.0) / 2.0) / (n1 * n0)
}

/// The text of a file kept beside a model's weights (a support or disagreement file):
/// `missing()` when there is none; refused, as [`SupportError::Invalid`], when it is larger
/// than `limit` (the bytes and the constant's name), by its stated size or, for a device or
/// a pipe whose stated size is 0, by reading.
pub(crate) fn read_file_beside(
    path: &Path,
    (max, limit_name): (u64, &str),
    missing: impl FnOnce() -> SupportError,
) -> Result<String, SupportError> {
    let invalid = |what: String| SupportError::Invalid {
        path: path.display().to_string(),
        what,
    };
    match std::fs::metadata(path) {
        Err(_) => return Err(missing()),
        Ok(m) if m.len() > max => {
            return Err(invalid(format!(
                "{} bytes, more than the {max} accepted ({limit_name})",
                m.len()
            )))
        }
        Ok(_) => {}
    }
    let bytes = fishprobe_nn::store::read_at_most(path, max, limit_name)
        .map_err(|e| invalid(e.to_string()))?;
    String::from_utf8(bytes).map_err(|e| {
        invalid(format!(
            "not UTF-8 text (invalid byte at offset {})",
            e.utf8_error().valid_up_to()
        ))
    })
}

#[cfg(test)]
mod tests {
    use super::*;
    use fishprobe_sim::{stream, TankParams};

    fn views_of(pairs: &[(AgentState, AgentState)], arch: &ConvNetArch, tank: &Tank) -> Vec<f32> {
        let mut out = Vec::new();
        let mut v = vec![0.0; arch.view_len()];
        for (a, b) in pairs {
            encode_view(arch, tank, a, &[*b], &mut v);
            out.extend_from_slice(&v);
        }
        out
    }

    /// Followers: a partner 3-10 cm behind-left, swimming the same way, in the tank's middle.
    fn follower_views(n: usize, rng: &mut SimRng) -> Vec<(AgentState, AgentState)> {
        (0..n)
            .map(|_| {
                let me = AgentState::at(
                    rng.random_range(-25.0..25.0),
                    rng.random_range(-25.0..25.0),
                    rng.random_range(-PI..PI),
                );
                let b = me.heading + 2.5 + rng.random_range(-0.3..0.3);
                let d = rng.random_range(3.0..10.0);
                let o = AgentState::at(me.x + d * b.cos(), me.y + d * b.sin(), me.heading);
                (me, o)
            })
            .collect()
    }

    #[test]
    fn a_view_shows_its_situation() {
        let arch = ConvNetArch::default();
        let tank = Tank::new(&TankParams::default());
        // Facing +x at (40, 0): the wall 9.5 cm ahead (50 - 0.5 margin? raycast to the wall).
        let me = AgentState::at(40.0, 0.0, 0.0);
        let other = AgentState::at(30.0, 0.0, 0.0); // 10 cm behind, same heading
        let mut v = vec![0.0; arch.view_len()];
        encode_view(&arch, &tank, &me, &[other], &mut v);
        let s = Situation::of_view(&arch, &v);
        assert!((s.partner_distance_cm - 10.0).abs() < 0.01, "{s:?}");
        // Behind: the bin centred 2.5° from ±180°.
        assert!(s.partner_bearing_rad.abs() > PI - 0.05, "{s:?}");
        assert!(s.relative_heading_rad.abs() < 1e-6, "{s:?}");
        let wall_ahead = tank.raycast(40.0, 0.0, 1.0, 0.0);
        // The nearest ray is one of the two bins either side of straight ahead.
        assert!(
            (s.wall_distance_cm - wall_ahead).abs() < 0.05,
            "{s:?} vs {wall_ahead}"
        );
        assert!(s.wall_bearing_rad.abs() < 0.05, "{s:?}");
        // Along the right wall the second wall (≥ 80° away) is 10 cm / cos 80°, or the
        // top/bottom wall's 49.5 cm: whichever ray of those bins is shortest.
        assert!(s.second_wall_cm > 40.0, "{s:?}");
        // In the corner (48, 48) facing +x: the top wall is 90° away, about as near.
        encode_view(
            &arch,
            &tank,
            &AgentState::at(48.0, 48.0, 0.0),
            &[other],
            &mut v,
        );
        let c = Situation::of_view(&arch, &v);
        assert!(c.second_wall_cm < 2.5, "{c:?}");
        assert!(c.describe().contains("in a corner"), "{}", c.describe());
        assert!(s.describe().contains("behind"), "{}", s.describe());
        assert!(s.describe().contains("same way"), "{}", s.describe());
    }

    #[test]
    fn both_estimators_score_training_like_views_low_and_unseen_situations_high() {
        let arch = ConvNetArch::default();
        let tank = Tank::new(&TankParams::default());
        let mut rng = stream(3, "support-test", 0);
        let train = views_of(&follower_views(3000, &mut rng), &arch, &tank);
        let held_out = views_of(&follower_views(500, &mut rng), &arch, &tank);
        let synthetic = synthetic_views(&arch, &tank, 300, &mut rng);
        for est in [Estimator::Knn, Estimator::Gmm] {
            let cfg = SupportConfig {
                estimator: est,
                reference_views: 1500,
                calibration_views: 1000,
                components: 8,
                em_iterations: 40,
                ..Default::default()
            };
            let s = SupportModel::fit(&arch, &train, &cfg, "test", "", &mut rng).unwrap();
            let scores = |v: &[f32]| -> Vec<f32> {
                v.chunks_exact(arch.view_len())
                    .map(|x| s.score_view(x))
                    .collect()
            };
            let inside = scores(&held_out);
            let within = inside.iter().filter(|&&x| x <= 1.0).count() as f32 / 500.0;
            assert!((0.88..=0.99).contains(&within), "{est:?}: {within}");
            for (kind, v) in &synthetic {
                let out = scores(v);
                let a = auc(&inside, &out);
                assert!(a > 0.95, "{est:?} {kind}: AUC {a}");
                let beyond = out.iter().filter(|&&x| x > 1.0).count() as f32 / 300.0;
                assert!(beyond > 0.8, "{est:?} {kind}: {beyond}");
            }
            // The file round-trips, and checks what it belongs to.
            let dir =
                std::env::temp_dir().join(format!("fp-support-{}-{est:?}", std::process::id()));
            std::fs::create_dir_all(&dir).unwrap();
            let mut named = s.clone();
            named.model_sha256 = "abc".into();
            let p = dir.join("m.support.json");
            named.save(&p).unwrap();
            let back = SupportModel::load(&p, "m", "abc").unwrap();
            assert_eq!(back, named);
            let e = SupportModel::load(&p, "m", "def").unwrap_err();
            assert!(matches!(e, SupportError::OtherModel { .. }), "{e}");
            let e = SupportModel::load(&dir.join("none.json"), "m", "").unwrap_err();
            assert!(e.to_string().contains("fit-convnet"), "{e}");
            std::fs::write(&p, "{\"format\": 3}").unwrap();
            let e = SupportModel::load(&p, "m", "").unwrap_err();
            assert!(
                e.to_string().contains("not a fishprobe support file"),
                "{e}"
            );
            std::fs::remove_dir_all(&dir).ok();
        }
    }

    #[test]
    fn the_shipped_convnet_has_its_support_and_other_models_have_none() {
        let s = crate::ModelSpec::by_name("ConvNet")
            .unwrap()
            .support()
            .unwrap();
        assert_eq!(s.model_sha256, crate::convnet::shipped_sha256());
        assert_eq!(s.config.estimator, Estimator::Knn);
        assert!(s.points.len() >= 1000, "{}", s.points.len());
        let e = crate::ModelSpec::by_name("Zone")
            .unwrap()
            .support()
            .unwrap_err();
        assert!(e.to_string().contains("not data-driven"), "{e}");
        let e = crate::ModelSpec::by_name("convnet:/nonexistent/w.safetensors")
            .unwrap()
            .support()
            .unwrap_err();
        assert!(e.to_string().contains("/nonexistent/w.safetensors"), "{e}");
    }

    #[test]
    fn a_partner_range_embeds_far_partners_as_not_seen() {
        let arch = ConvNetArch::default();
        let tank = Tank::new(&TankParams::default());
        let me = AgentState::at(0.0, 0.0, 0.0);
        let mut v = vec![0.0; arch.view_len()];
        let sit = |d: f32, v: &mut Vec<f32>| {
            encode_view(&arch, &tank, &me, &[AgentState::at(0.0, d, PI)], v);
            Situation::of_view(&arch, v)
        };
        let near = sit(8.0, &mut v);
        let far = sit(40.0, &mut v);
        // Within range, and with no range, nothing changes.
        assert_eq!(near.features_within(20.0), near.features());
        assert_eq!(far.features_within(0.0), far.features());
        // Beyond it: at the range, no bearing, no heading; the walls as they are.
        let f = far.features_within(20.0);
        assert!((f[0] - 20.0f32.ln_1p()).abs() < 1e-6, "{f:?}");
        assert_eq!(&f[1..5], &[0.0; 4]);
        assert_eq!(&f[5..], &far.features()[5..]);
        // Training data with the partner 3-10 cm away but now and then 30-45 cm, anywhere:
        // with no range every far partner in a new direction scores far out; with a range of
        // 20 cm the far partners all look alike and lie within the data.
        let mut rng = stream(5, "support-range", 0);
        let mut pairs = follower_views(2700, &mut rng);
        let far_pair = |rng: &mut SimRng| {
            let me = AgentState::at(
                rng.random_range(-5.0..5.0),
                rng.random_range(-5.0..5.0),
                rng.random_range(-PI..PI),
            );
            let b = rng.random_range(-PI..PI);
            let d = rng.random_range(30.0..42.0);
            let o = AgentState::at(
                me.x + d * b.cos(),
                me.y + d * b.sin(),
                rng.random_range(-PI..PI),
            );
            (me, o)
        };
        pairs.extend((0..300).map(|_| far_pair(&mut rng)));
        let train = views_of(&pairs, &arch, &tank);
        // Far partners ahead, heading at the fish: rare among 300 random far partners.
        let probe: Vec<(AgentState, AgentState)> = (0..200)
            .map(|_| {
                let me = AgentState::at(0.0, 0.0, rng.random_range(-PI..PI));
                let d = rng.random_range(30.0..42.0);
                let o = AgentState::at(d * me.heading.cos(), d * me.heading.sin(), me.heading + PI);
                (me, o)
            })
            .collect();
        let probe = views_of(&probe, &arch, &tank);
        let mean_score = |range: f32, rng: &mut SimRng| {
            let cfg = SupportConfig {
                reference_views: 1500,
                calibration_views: 1000,
                partner_range_cm: range,
                ..Default::default()
            };
            let s = SupportModel::fit(&arch, &train, &cfg, "test", "", rng).unwrap();
            let sc: Vec<f32> = probe
                .chunks_exact(arch.view_len())
                .map(|x| s.score_view(x))
                .collect();
            sc.iter().sum::<f32>() / sc.len() as f32
        };
        let open = mean_score(0.0, &mut rng);
        let ranged = mean_score(20.0, &mut rng);
        assert!(
            open > 1.0 && ranged < 0.5,
            "no range {open}, range 20 cm {ranged}"
        );
        let bad = SupportConfig {
            partner_range_cm: f32::NAN,
            ..Default::default()
        };
        let e = bad.validate().unwrap_err();
        assert!(e.to_string().contains("support.partner_range_cm"), "{e}");
        let absurd = SupportConfig {
            partner_range_cm: 1e30,
            ..Default::default()
        };
        let e = absurd.validate().unwrap_err();
        assert!(e.to_string().contains("[0, 1000]"), "{e}");
    }

    #[test]
    fn the_auc_matches_hand_counts() {
        // Pairs (out > in): 3 > 1, 3 > 2, 2 = 2 (half), 1 = 1 (half) ... out {3, 2}, in {1, 2}:
        // (3>1) + (3>2) + (2>1) + 0.5 (2=2) = 3.5 of 4.
        assert!((auc(&[1.0, 2.0], &[3.0, 2.0]) - 0.875).abs() < 1e-12);
        assert!((auc(&[1.0, 1.0], &[1.0]) - 0.5).abs() < 1e-12);
        assert!((auc(&[5.0], &[1.0, 2.0]) - 0.0).abs() < 1e-12);
    }

    #[test]
    fn bad_settings_and_too_little_data_are_refused() {
        let arch = ConvNetArch::default();
        let mut rng = stream(1, "t", 0);
        let cfg = SupportConfig {
            neighbours: 0,
            ..Default::default()
        };
        let e = SupportModel::fit(&arch, &[], &cfg, "m", "", &mut rng).unwrap_err();
        assert!(e.to_string().contains("support.neighbours"), "{e}");
        let e = SupportModel::fit(
            &arch,
            &vec![0.0; arch.view_len() * 10],
            &SupportConfig::default(),
            "m",
            "",
            &mut rng,
        )
        .unwrap_err();
        assert!(
            matches!(e, SupportError::TooFewViews { got: 10, .. }),
            "{e}"
        );
    }
}
