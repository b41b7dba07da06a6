//! A candidate fish model brought as an ONNX file (`--model onnx:PATH`,
//! `docs/onnx-models.md`): M_ConvNet's egocentric view in (`view`, float32 `[batch, 3, 72]`),
//! logits over a (v, ω) grid out (`logits`, float32 `[batch, cells]`); the fish samples a cell,
//! then a value inside it, exactly as M_ConvNet does. The grid is M_ConvNet's (25 speed cells
//! of 1 cm/s, 41 turn cells over ±10 rad/s) unless the file's `metadata_props` set
//! `v_max_cm_s`, `v_bins`, `omega_max_rad_s`, `omega_bins`. Inference is batched over the fish
//! of a vector environment like M_ConvNet's.

use crate::convnet::{encode_views, sample_motion, ConvNetArch};
use fishprobe_onnx::{Contract, OnnxError, OnnxNet};
use fishprobe_sim::params::ConfigError;
use fishprobe_sim::{FishMind, FishModel, FishMotion, FishView, SimRng};
use std::collections::{BTreeMap, HashMap};
use std::path::Path;
use std::sync::{Arc, Mutex, RwLock};

fishprobe_sim::documented_params! {
    /// A candidate fish model brought as an ONNX file of fishprobe's fish-model contract.
    pub struct OnnxParams {
        /// The ONNX file.
        pub path: String = String::new(); "-",
        /// The file's SHA-256, recorded when the model is named (`--model onnx:PATH`) so that
        /// every trial file traces its fish to the exact file; a file that no longer matches is
        /// refused. Empty: not checked.
        pub sha256: String = String::new(); "-",
        /// Redraws of a (v, ω) whose step would cross the wall margin, as
        /// [`crate::ConvNetParams::wall_redraws`] (the same decision: 16; 0 for the plain
        /// sampling).
        pub wall_redraws: u32 = 16; "draws",
    }
}

impl OnnxParams {
    /// The model in `path`, with the file's current SHA-256 (empty if it cannot be read: the
    /// model's construction then says why).
    pub fn for_file(path: &str) -> Self {
        let sha256 = crate::onnx_sha256(std::path::Path::new(path)).unwrap_or_default();
        Self {
            path: path.to_string(),
            sha256,
            ..Self::default()
        }
    }
}

/// The allowed range of each `metadata_props` value of the fish-model contract; a value
/// outside it is refused naming the key, the value and the range.
///
/// - `v_max_cm_s` in (0, 100] cm/s: a tank width a second, about twice a guppy's fastest
///   burst (M_ConvNet: 25).
/// - `omega_max_rad_s` in (0, 25π] rad/s: at the tank's 25 frames a second a larger turn
///   rate turns more than π in one frame, which is no longer a turn (M_ConvNet: 10).
/// - `v_bins` and `omega_bins` whole numbers in [1, 1,000] (M_ConvNet: 25 and 41), with at
///   most [`MAX_GRID_CELLS`] cells in all: the network outputs a logit per cell, per fish
///   and frame.
pub const METADATA_RANGES: [(&str, f64, f64); 4] = [
    ("v_max_cm_s", 0.0, 100.0),
    ("omega_max_rad_s", 0.0, 25.0 * std::f64::consts::PI),
    ("v_bins", 1.0, 1000.0),
    ("omega_bins", 1.0, 1000.0),
];

/// Most cells the (v, ω) grid of an ONNX fish may have (M_ConvNet: 1,025).
pub const MAX_GRID_CELLS: usize = 100_000;

/// The grid of `metadata_props`, on M_ConvNet's defaults, each value checked against
/// [`METADATA_RANGES`].
fn arch_from(meta: &BTreeMap<String, String>) -> Result<ConvNetArch, String> {
    let mut a = ConvNetArch::default();
    let value = |k: &str| -> Result<Option<f64>, String> {
        let Some(v) = meta.get(k) else {
            return Ok(None);
        };
        let &(_, lo, hi) = METADATA_RANGES
            .iter()
            .find(|(key, ..)| *key == k)
            .ok_or_else(|| format!("metadata {k}: no range defined"))?;
        let count = lo >= 1.0;
        let range = if count {
            format!("a whole number in [{lo}, {hi}]")
        } else {
            let hi = if hi.fract() == 0.0 {
                format!("{hi}")
            } else {
                format!("{hi:.4}")
            };
            format!("a number in ({lo}, {hi}]")
        };
        let x = v
            .trim()
            .parse::<f64>()
            .map_err(|_| format!("metadata {k} = `{v}`, not a number (allowed: {range})"))?;
        let inside = if count {
            x.fract() == 0.0 && (lo..=hi).contains(&x)
        } else {
            x > lo && x <= hi
        };
        if !inside {
            return Err(format!(
                "metadata {k} = {}, outside the allowed range: {range}",
                fishprobe_sim::params::check::shown(x)
            ));
        }
        Ok(Some(x))
    };
    if let Some(v) = value("v_max_cm_s")? {
        a.v_max_cm_s = v as f32;
    }
    if let Some(v) = value("omega_max_rad_s")? {
        a.w_max_rad_s = v as f32;
    }
    if let Some(v) = value("v_bins")? {
        a.v_bins = v as usize;
    }
    if let Some(v) = value("omega_bins")? {
        a.w_bins = v as usize;
    }
    if a.cells() > MAX_GRID_CELLS {
        return Err(format!(
            "metadata v_bins x omega_bins = {} x {} = {} cells, more than the {MAX_GRID_CELLS} allowed",
            a.v_bins,
            a.w_bins,
            a.cells()
        ));
    }
    a.validate().map_err(|e| e.to_string())?;
    Ok(a)
}

/// The ONNX fish.
#[derive(Debug)]
pub struct OnnxFish {
    arch: ConvNetArch,
    /// [`OnnxParams::wall_redraws`].
    wall_redraws: u32,
    /// The network planned for each batch size met so far (planning is done once per size).
    nets: RwLock<HashMap<usize, Arc<OnnxNet>>>,
    base: OnnxNet,
    /// Views and logits, one set per concurrent `infer_batch` call.
    scratch: Vec<Mutex<(Vec<f32>, Vec<f32>)>>,
}

impl OnnxFish {
    /// Loads and checks the file of `p`.
    pub fn load(p: &OnnxParams) -> Result<Self, OnnxError> {
        let path = Path::new(&p.path);
        let mut grid = None;
        let base = OnnxNet::load_with(path, 1, |meta| {
            let a = arch_from(meta)?;
            let contract = Contract::fish(a.bins, a.cells());
            grid = Some(a);
            Ok::<_, String>(contract)
        })?;
        if !p.sha256.is_empty() && base.sha256() != p.sha256 {
            return Err(OnnxError::Contract {
                path: path.to_path_buf(),
                expected: format!("the file with SHA-256 {}", p.sha256),
                found: format!(
                    "SHA-256 {} (the file changed since it was named)",
                    base.sha256()
                ),
            });
        }
        let arch = grid.expect("load_with calls contract_of before it succeeds");
        let mut nets = HashMap::new();
        nets.insert(1, Arc::new(base.clone()));
        Ok(Self {
            arch,
            wall_redraws: p.wall_redraws,
            nets: RwLock::new(nets),
            base,
            scratch: crate::convnet::slots(|| (Vec::new(), Vec::new())),
        })
    }

    /// The grid and view the model uses.
    pub fn arch(&self) -> &ConvNetArch {
        &self.arch
    }

    /// The network planned for `batch` rows (planned on first use).
    fn net_for(&self, batch: usize) -> Result<Arc<OnnxNet>, OnnxError> {
        if let Some(n) = self.nets.read().ok().and_then(|m| m.get(&batch).cloned()) {
            return Ok(n);
        }
        let net = Arc::new(self.base.with_batch(batch)?);
        if let Ok(mut m) = self.nets.write() {
            m.insert(batch, net.clone());
        }
        Ok(net)
    }

    /// Logits of `views` (one row each) into `logits`.
    pub fn logits(&self, views: &[f32], batch: usize, logits: &mut [f32]) -> Result<(), OnnxError> {
        self.net_for(batch)?.run(views, logits)
    }
}

impl FishModel for OnnxFish {
    fn name(&self) -> &str {
        "Onnx"
    }

    fn inference_width(&self) -> usize {
        self.arch.cells()
    }

    /// A failing run leaves NaN, which `decide` turns into a non-finite motion: the simulator
    /// stops with an error naming the model and the frame.
    fn infer_batch(&self, views: &[FishView], out: &mut [f32]) {
        let arch = &self.arch;
        let (len, cells) = (arch.view_len(), arch.cells());
        let mut guard = crate::convnet::free_slot(&self.scratch);
        let (x, logits) = &mut *guard;
        x.resize(views.len() * len, 0.0);
        logits.resize(views.len() * cells, 0.0);
        encode_views(arch, views, x);
        if self.logits(x, views.len(), logits).is_err() {
            out[..views.len() * cells].fill(f32::NAN);
            return;
        }
        fishprobe_nn::dist::softmax_rows(logits, out, cells);
    }

    fn decide(
        &self,
        view: &FishView,
        inferred: &[f32],
        mind: &mut FishMind,
        rng: &mut SimRng,
    ) -> FishMotion {
        if !inferred.iter().all(|p| p.is_finite()) {
            return FishMotion {
                heading: f32::NAN,
                speed: f32::NAN,
            };
        }
        sample_motion(&self.arch, view, inferred, self.wall_redraws, mind, rng)
    }
}

impl crate::ModelParams for OnnxParams {
    const NAME: &'static str = "Onnx";
    const SUMMARY: &'static str =
        "a candidate model brought as an ONNX file: M_ConvNet's view in, (v, ω) grid logits out";

    fn check(&self, prefix: &str) -> Result<(), ConfigError> {
        if self.path.is_empty() {
            return Err(ConfigError::new(
                prefix,
                "path",
                "\"\"",
                "names the ONNX file",
            ));
        }
        crate::convnet::check_wall_redraws(prefix, self.wall_redraws)
    }

    fn build_model(&self) -> Result<Arc<dyn FishModel>, crate::ModelError> {
        Ok(Arc::new(OnnxFish::load(self)?))
    }
}

#[cfg(test)]
mod tests {
    #![allow(clippy::unwrap_used)]
    use super::*;

    fn grid(pairs: &[(&str, &str)]) -> Result<ConvNetArch, String> {
        arch_from(
            &pairs
                .iter()
                .map(|(k, v)| ((*k).to_string(), (*v).to_string()))
                .collect(),
        )
    }

    #[test]
    fn every_contract_value_is_checked_against_its_range() {
        // No metadata: M_ConvNet's grid; values inside their ranges are taken.
        assert_eq!(grid(&[]).unwrap().cells(), 1025);
        let a = grid(&[
            ("v_max_cm_s", "100"),
            ("omega_max_rad_s", "78.5"),
            ("v_bins", "1000"),
            ("omega_bins", "100"),
        ])
        .unwrap();
        assert_eq!((a.v_max_cm_s, a.v_bins, a.w_bins), (100.0, 1000, 100));
        // Outside: refused naming the key, the value and the range.
        for (k, v, range) in [
            ("v_max_cm_s", "1e30", "(0, 100]"),
            ("v_max_cm_s", "0", "(0, 100]"),
            ("v_max_cm_s", "-3", "(0, 100]"),
            ("v_max_cm_s", "NaN", "(0, 100]"),
            ("v_max_cm_s", "inf", "(0, 100]"),
            ("omega_max_rad_s", "1e30", "(0, 78.5398]"),
            ("omega_max_rad_s", "78.6", "(0, 78.5398]"),
            ("v_bins", "0", "[1, 1000]"),
            ("v_bins", "2.5", "[1, 1000]"),
            ("omega_bins", "1001", "[1, 1000]"),
            ("omega_bins", "lots", "[1, 1000]"),
        ] {
            let e = grid(&[(k, v)]).unwrap_err();
            assert!(
                e.contains(k) && e.contains(range) && e.contains("allowed"),
                "{k} = {v}: {e}"
            );
            assert!(e.len() < 200, "{e}");
        }
        assert!(grid(&[("v_max_cm_s", "1e30")])
            .unwrap_err()
            .contains("1e30"));
        let e = grid(&[("v_bins", "1000"), ("omega_bins", "1000")]).unwrap_err();
        assert!(e.contains("1000000 cells") && e.contains("100000"), "{e}");
    }
}
