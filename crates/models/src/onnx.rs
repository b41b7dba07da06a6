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

/// The grid of `metadata_props`, on M_ConvNet's defaults.
fn arch_from(meta: &BTreeMap<String, String>) -> Result<ConvNetArch, String> {
    let mut a = ConvNetArch::default();
    let num = |k: &str| -> Result<Option<f64>, String> {
        meta.get(k)
            .map(|v| {
                v.trim()
                    .parse::<f64>()
                    .map_err(|_| format!("metadata {k} = `{v}`, not a number"))
            })
            .transpose()
    };
    if let Some(v) = num("v_max_cm_s")? {
        a.v_max_cm_s = v as f32;
    }
    if let Some(v) = num("omega_max_rad_s")? {
        a.w_max_rad_s = v as f32;
    }
    let count = |v: f64, k: &str| -> Result<usize, String> {
        if v.fract() == 0.0 && (1.0..=10_000.0).contains(&v) {
            Ok(v as usize)
        } else {
            Err(format!("metadata {k} = {v}, not a count of 1 to 10,000"))
        }
    };
    if let Some(v) = num("v_bins")? {
        a.v_bins = count(v, "v_bins")?;
    }
    if let Some(v) = num("omega_bins")? {
        a.w_bins = count(v, "omega_bins")?;
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
            Ok(contract)
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
