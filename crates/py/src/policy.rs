//! A trained robot policy, for Python to call.

use super::*;

/// A trained robot policy: a policy directory (`fishprobe train`'s output) or `onnx:PATH`.
#[pyclass(module = "fishprobe._native")]
pub(crate) struct Policy {
    ctrl: Box<dyn Controller>,
    rng: SimRng,
}

#[pymethods]
impl Policy {
    #[new]
    #[pyo3(signature = (path, stochastic=false, seed=0))]
    fn new(path: &str, stochastic: bool, seed: u64) -> PyResult<Self> {
        if matches!(
            fishprobe_learn::PolicyArg::parse(path),
            fishprobe_learn::PolicyArg::Scripted(_)
        ) {
            return Err(PyValueError::new_err(format!(
                "{path}: scripted controllers use privileged state, not observations; \
                 Policy runs a trained policy (a directory or onnx:PATH)"
            )));
        }
        let ctrl = fishprobe_learn::controller(path, stochastic).map_err(|e| match e {
            LearnError::Io(_) => PyOSError::new_err(e.to_string()),
            other => PyValueError::new_err(other.to_string()),
        })?;
        Ok(Self {
            ctrl,
            rng: fishprobe_sim::stream(seed, "policy", 0),
        })
    }

    /// The policy's name (the model it was trained against).
    #[getter]
    fn name(&self) -> String {
        self.ctrl.name()
    }

    /// SHA-256 of the weights that decide its actions, as trial files record it
    /// (`policy_sha256` in their config).
    #[getter]
    fn sha256(&self) -> Option<String> {
        self.ctrl.fingerprint()
    }

    /// The environment settings the policy was trained with, where it records them, as JSON:
    /// `frames_per_action`, `frame_rate_hz` and `observation` (an ONNX policy, or one trained before fishprobe
    /// recorded them, records neither: `None`).
    #[getter]
    fn trained_settings(&self) -> PyResult<Option<String>> {
        let mut table = serde_json::Map::new();
        if let Some(f) = self.ctrl.trained_frames_per_action() {
            table.insert("frames_per_action".into(), f.into());
        }
        if let Some(hz) = self.ctrl.trained_frame_rate_hz() {
            table.insert("frame_rate_hz".into(), hz.into());
        }
        if let Some(o) = self.ctrl.trained_observation() {
            let o = serde_json::to_value(o).map_err(|e| PyValueError::new_err(e.to_string()))?;
            table.insert("observation".into(), o);
        }
        Ok((!table.is_empty()).then(|| serde_json::Value::Object(table).to_string()))
    }

    /// Turns (rad) for a batch of observations, shape (n, obs_dim) -> (n,).
    fn act<'py>(
        &mut self,
        py: Python<'py>,
        obs: PyReadonlyArray2<'py, f32>,
    ) -> PyResult<Bound<'py, PyArray1<f32>>> {
        let shape = obs.shape().to_vec();
        let (n, d) = (shape[0], shape[1]);
        self.ctrl
            .check_observation(d)
            .map_err(|e| PyValueError::new_err(e.to_string()))?;
        let obs = obs.as_slice()?;
        if let Some(i) = obs.iter().position(|v| !v.is_finite()) {
            return Err(PyValueError::new_err(format!(
                "observation {} holds a non-finite value at index {}",
                i / d.max(1),
                i % d.max(1)
            )));
        }
        let mut out = Vec::with_capacity(n);
        for row in obs.chunks(d.max(1)).take(n) {
            let input = ControlInput {
                obs: row,
                robot: AgentState::default(),
                fish: &[],
                goal: [0.0, 0.0],
            };
            out.push(self.ctrl.act(&input, &mut self.rng));
        }
        Ok(PyArray1::from_vec(py, out))
    }
}
