//! The support model: embedding, estimator and calibration, as saved in a support file.

use super::{
    Estimator, Mixture, Situation, SupportConfig, SupportError, FEATURES, FORMAT, MAX_FILE_BYTES,
    VERSION,
};
use crate::convnet::{encode_view, ConvNetArch, CHANNELS};
use fishprobe_sim::{AgentState, FishView, InputSupport, SimRng, Tank};
use rand::RngExt;
use serde::{Deserialize, Serialize};
use std::path::Path;

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
        let s = Self::from_json(&text).map_err(|e| invalid(e.to_string()))?;
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
    pub fn from_json(text: &str) -> Result<Self, SupportError> {
        let mut s: SupportModel = serde_json::from_str(text).map_err(|e| {
            SupportError::NotASupportFile(format!("not a fishprobe support file: {e}"))
        })?;
        if s.format != FORMAT || s.version != VERSION {
            return Err(SupportError::NotASupportFile(format!(
                "format {} version {}, not {FORMAT} version {VERSION}",
                s.format, s.version
            )));
        }
        let not_one = |e: &dyn std::fmt::Display| SupportError::NotASupportFile(e.to_string());
        s.config.validate().map_err(|e| not_one(&e))?;
        s.arch().validate().map_err(|e| not_one(&e))?;
        let finite = |v: &[f32]| v.iter().all(|x| x.is_finite());
        let ok = finite(&s.mean)
            && finite(&s.std)
            && s.std.iter().all(|&x| x > 0.0)
            && s.raw_median.is_finite()
            && s.raw_p95.is_finite()
            && s.raw_p95 > s.raw_median;
        if !ok {
            return Err(SupportError::NotASupportFile(
                "non-finite or degenerate calibration".into(),
            ));
        }
        match (&s.mixture, s.config.estimator) {
            (None, Estimator::Knn) => {
                if s.points.len() <= s.config.neighbours || !s.points.iter().all(|p| finite(p)) {
                    return Err(SupportError::NotASupportFile(format!(
                        "{} reference views for {} neighbours, or non-finite ones",
                        s.points.len(),
                        s.config.neighbours
                    )));
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
                    return Err(SupportError::NotASupportFile("a malformed mixture".into()));
                }
            }
            _ => {
                return Err(SupportError::NotASupportFile(
                    "estimator and stored parameters disagree".into(),
                ))
            }
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
