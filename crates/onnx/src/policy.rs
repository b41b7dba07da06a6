//! A robot policy brought as an ONNX file (`--policy onnx:PATH`), driving the robot like any
//! [`Controller`]: the observation in, the turn angle in radians out (fishprobe clips it to
//! [-π, π]; a non-finite turn never drives a robot).

use crate::net::{Contract, OnnxNet};
use crate::OnnxError;
use fishprobe_sim::{ControlInput, Controller, SimRng};
use std::path::Path;

/// An ONNX policy of [`Contract::policy`], run one observation at a time.
#[derive(Debug, Clone)]
pub struct OnnxPolicy {
    net: OnnxNet,
    name: String,
    out: [f32; 1],
}

impl OnnxPolicy {
    /// Loads and checks `path`. Its name in the study layout is the file's stem.
    pub fn load(path: &Path) -> Result<Self, OnnxError> {
        let net = OnnxNet::load(path, &Contract::policy(), 1)?;
        let name = path
            .file_stem()
            .map_or_else(|| "onnx".to_string(), |s| s.to_string_lossy().into_owned());
        Ok(Self {
            net,
            name,
            out: [0.0],
        })
    }

    /// The network.
    pub fn net(&self) -> &OnnxNet {
        &self.net
    }
}

impl Controller for OnnxPolicy {
    fn name(&self) -> String {
        self.name.clone()
    }

    /// `onnx:PATH (sha256 …)`: the exact file that drove the robot.
    fn describe(&self) -> String {
        format!(
            "onnx:{} (sha256 {})",
            self.net.path().display(),
            self.net.sha256()
        )
    }

    /// The file's SHA-256.
    fn fingerprint(&self) -> Option<String> {
        Some(self.net.sha256().to_string())
    }

    fn check_observation(&self, dim: usize) -> Result<(), fishprobe_sim::SimError> {
        match &Contract::policy().input_dims[..] {
            [d] if *d == dim => Ok(()),
            d => Err(fishprobe_sim::SimError::Controller(format!(
                "{}: the policy reads observations of {d:?} floats, the environment gives {dim}",
                self.net.path().display()
            ))),
        }
    }

    /// A failing run gives NaN, which evaluation refuses (naming the episode) and the live
    /// bridge answers with a stop.
    fn act(&mut self, input: &ControlInput<'_>, _rng: &mut SimRng) -> f32 {
        if self.net.run(input.obs, &mut self.out).is_err() {
            return f32::NAN;
        }
        self.out[0]
    }
}
