//! `fishprobe._native`: the Rust half of the `fishprobe` Python package (`python/`).
//!
//! The Python half (`python/fishprobe/`) wraps these classes into Gymnasium's interfaces; this
//! module only moves numbers between numpy and the simulator, trainer and file reader, and
//! turns every error into a Python exception (`ValueError` for bad input, `TypeError` for
//! wrong kinds of objects, `OSError` for files, `RuntimeError` for the rest). The GIL is
//! released while Rust steps many environments or trains, so the work uses every core.

// PyO3's macros expand to FFI glue that needs `unsafe`; this crate writes none itself.
#![allow(unsafe_code)]
#![warn(missing_docs)]

mod fish;
mod render;

// A user's ONNX file cannot make the engine allocate gigabytes (fishprobe_onnx::CappedAlloc).
#[global_allocator]
static ALLOC: fishprobe_onnx::CappedAlloc = fishprobe_onnx::CappedAlloc;

use fish::PyFish;
use fishprobe_io::{IoError, TrialFile};
use fishprobe_learn::yardstick::OodYardstickConfig;
use fishprobe_learn::{LearnError, PpoConfig, RunSpec, Trainer};
use fishprobe_models::{ModelError, ModelSpec, PythonParams};
use fishprobe_sim::{
    AgentState, ControlInput, Controller, Env as _, EnvConfig, FishModel, InputSupport, Objective,
    SimError, SimRng, TankEnv, TaskMode,
};
use numpy::{PyArray1, PyArrayMethods, PyReadonlyArray1, PyReadonlyArray2, PyUntypedArrayMethods};
use pyo3::exceptions::{PyOSError, PyRuntimeError, PyTypeError, PyValueError};
use pyo3::prelude::*;
use pyo3::types::{PyDict, PyList};
use std::sync::Arc;

/// Most environments one vector environment may hold: each is a few kilobytes, but a typo
/// (`num_envs=10**9`) must be refused, not allocated.
const MAX_NUM_ENVS: usize = 65_536;

fn sim_err(e: SimError) -> PyErr {
    match e {
        SimError::NeedsReset => PyRuntimeError::new_err(e.to_string()),
        SimError::Config(_)
        | SimError::NonFiniteAction { .. }
        | SimError::ActionShape { .. }
        | SimError::ObservationShape { .. }
        | SimError::StartPoses(_) => PyValueError::new_err(e.to_string()),
        other => PyRuntimeError::new_err(other.to_string()),
    }
}

fn model_err(e: ModelError) -> PyErr {
    PyValueError::new_err(e.to_string())
}

fn learn_err(e: LearnError) -> PyErr {
    match e {
        // A fish model that cannot be used is a bad argument, as everywhere (`model_err`).
        LearnError::Config(_) | LearnError::Model(_) => PyValueError::new_err(e.to_string()),
        LearnError::Io(_) => PyOSError::new_err(e.to_string()),
        other => PyRuntimeError::new_err(other.to_string()),
    }
}

fn io_err(e: IoError) -> PyErr {
    match e {
        IoError::Read { .. } | IoError::Write { .. } | IoError::NotRegular { .. } => {
            PyOSError::new_err(e.to_string())
        }
        other => PyValueError::new_err(other.to_string()),
    }
}

/// A Python value as JSON text (dicts of settings and model specs).
/// `what` names the argument in errors. NaN and infinities are refused here (Python's `json`
/// would write them as `NaN`, which is not JSON, and serde's error would only give a column).
fn to_json(obj: &Bound<'_, PyAny>, what: &str) -> PyResult<String> {
    let py = obj.py();
    let kwargs = PyDict::new(py);
    kwargs.set_item("allow_nan", false)?;
    py.import("json")?
        .call_method("dumps", (obj,), Some(&kwargs))
        .and_then(|t| t.extract())
        .map_err(|e: PyErr| {
            if e.is_instance_of::<pyo3::exceptions::PyValueError>(py) {
                PyValueError::new_err(format!("{what}: numbers must be finite: {e}"))
            } else {
                PyTypeError::new_err(format!(
                    "{what}: not JSON-like (dicts, lists, strings, finite numbers): {e}"
                ))
            }
        })
}

/// A resolved `model=` argument.
struct Model {
    spec: ModelSpec,
    model: Arc<dyn FishModel>,
    python: Option<Arc<PyFish>>,
}

impl Model {
    /// A name (`"Zone"`, `"onnx:PATH"`), a spec dict (`{"model": "Zone", "speed_cm_s": 5}`), or
    /// a Python object with `decide(views)`.
    fn resolve(obj: &Bound<'_, PyAny>) -> PyResult<Self> {
        if let Some(spec) = Self::spec_of(obj)? {
            return Self::from_spec(spec);
        }
        let fish = Arc::new(PyFish::new(obj)?);
        let spec = ModelSpec::Python(PythonParams {
            class: fish.class().to_string(),
            name: fish.name().to_string(),
        });
        Ok(Self {
            spec,
            model: fish.clone(),
            python: Some(fish),
        })
    }

    /// The spec a name or a spec dict stands for, without building the model; `None` for a
    /// Python fish model object.
    fn spec_of(obj: &Bound<'_, PyAny>) -> PyResult<Option<ModelSpec>> {
        if let Ok(name) = obj.extract::<String>() {
            return ModelSpec::by_name(&name).map(Some).map_err(model_err);
        }
        if obj.cast::<PyDict>().is_ok() {
            let text = to_json(obj, "model")?;
            let spec: ModelSpec = serde_json::from_str(&text).map_err(|e| {
                PyValueError::new_err(format!(
                    "model spec {text}: {e} (a spec is {{\"model\": NAME, field: value, ...}}; fields: \
                     `fishprobe models --model NAME`)"
                ))
            })?;
            return Ok(Some(spec));
        }
        Ok(None)
    }

    fn from_spec(spec: ModelSpec) -> PyResult<Self> {
        let model = spec.build().map_err(model_err)?;
        Ok(Self {
            spec,
            model,
            python: None,
        })
    }

    /// Raises what the Python model raised during the last step, if anything.
    fn check(&self) -> PyResult<()> {
        match self.python.as_ref().and_then(|f| f.take_error()) {
            Some(e) => Err(e),
            None => Ok(()),
        }
    }
}

/// The environment settings: `settings` (a dict of `EnvConfig` fields, as in a settings
/// file's `env` table; missing fields keep their defaults), then `mode` and `fish_count`.
fn env_config(
    settings: Option<&Bound<'_, PyAny>>,
    mode: &str,
    fish_count: Option<u32>,
) -> PyResult<EnvConfig> {
    let mut cfg = match settings {
        Some(s) if !s.is_none() => {
            let text = to_json(s, "settings")?;
            serde_json::from_str::<EnvConfig>(&text)
                .map_err(|e| PyValueError::new_err(format!("settings: {e}")))?
        }
        _ => EnvConfig::default(),
    };
    cfg.mode = match mode {
        "training" => TaskMode::Training,
        "evaluation" => TaskMode::Evaluation,
        other => {
            return Err(PyValueError::new_err(format!(
                "mode `{other}`: use \"training\" or \"evaluation\""
            )))
        }
    };
    if let Some(n) = fish_count {
        cfg.fish_count = n;
    }
    cfg.validate()
        .map_err(|e| PyValueError::new_err(format!("settings: {e}")))?;
    Ok(cfg)
}

/// The support the OOD task (`task.objective = "ood"`) scores the fish's views against: the
/// model's own (or its ensemble's disagreement, `task.ood_score`), as `fishprobe train --task
/// ood` uses; none for the lead-to-goal task.
fn ood_support(model: &Model, cfg: &EnvConfig) -> PyResult<Option<Arc<dyn InputSupport>>> {
    if cfg.task.objective != Objective::Ood {
        return Ok(None);
    }
    let scorer = model
        .spec
        .ood_scorer(cfg.task.ood_score)
        .map_err(model_err)?;
    Ok(Some(scorer))
}

fn pose(a: &AgentState) -> [f32; 3] {
    [a.x, a.y, a.heading]
}

/// Poses of the robot and the fish, and the active goal, of `env`.
fn state_info<'py>(py: Python<'py>, env: &TankEnv, info: &Bound<'py, PyDict>) -> PyResult<()> {
    info.set_item(
        "robot_pose",
        PyArray1::from_slice(py, &pose(&env.robot().state)),
    )?;
    let fish: Vec<f32> = env.fish().iter().flat_map(pose).collect();
    let n = env.fish().len();
    info.set_item("fish_poses", PyArray1::from_vec(py, fish).reshape([n, 3])?)?;
    info.set_item("goal", PyArray1::from_slice(py, &env.active_goal()))?;
    info.set_item("frame", env.frame())?;
    info.set_item("goals_total", env.summary().goal_events.len())?;
    Ok(())
}

/// The top-down picture of `env` as a (size, size, 3) uint8 array.
fn picture<'py>(py: Python<'py>, env: &TankEnv, size: usize) -> PyResult<Bound<'py, PyAny>> {
    if !(16..=4096).contains(&size) {
        return Err(PyValueError::new_err(format!(
            "render size {size}: must lie in [16, 4096] pixels"
        )));
    }
    Ok(PyArray1::from_vec(py, render::tank(env, size))
        .reshape([size, size, 3])?
        .into_any())
}

/// One environment: the tank, a robot, `fish_count` fish and the lead-to-goal task.
#[pyclass(module = "fishprobe._native")]
struct Env {
    env: TankEnv,
    obs: Vec<f32>,
    model: Model,
    spoiled: bool,
}

#[pymethods]
impl Env {
    #[new]
    #[pyo3(signature = (model, mode="training", fish_count=None, settings=None))]
    fn new(
        model: &Bound<'_, PyAny>,
        mode: &str,
        fish_count: Option<u32>,
        settings: Option<&Bound<'_, PyAny>>,
    ) -> PyResult<Self> {
        let cfg = env_config(settings, mode, fish_count)?;
        let model = Model::resolve(model)?;
        let support = ood_support(&model, &cfg)?;
        let mut env = TankEnv::new(cfg, model.model.clone()).map_err(sim_err)?;
        env.set_support(support);
        let obs = vec![0.0; env.observation_space().dim()];
        Ok(Self {
            env,
            obs,
            model,
            spoiled: false,
        })
    }

    /// Observation length.
    #[getter]
    fn obs_dim(&self) -> usize {
        self.obs.len()
    }

    /// Actions per episode (the time limit).
    #[getter]
    fn max_episode_steps(&self) -> u32 {
        self.env.max_episode_steps()
    }

    /// The fish model's name.
    #[getter]
    fn model_name(&self) -> String {
        self.model.spec.label()
    }

    /// The model spec, as JSON.
    #[getter]
    fn model_spec(&self) -> PyResult<String> {
        serde_json::to_string(&self.model.spec).map_err(|e| PyRuntimeError::new_err(e.to_string()))
    }

    /// The resolved environment settings, as JSON.
    #[getter]
    fn settings(&self) -> PyResult<String> {
        serde_json::to_string(self.env.config()).map_err(|e| PyRuntimeError::new_err(e.to_string()))
    }

    /// Frame rate (Hz).
    #[getter]
    fn frame_rate_hz(&self) -> f32 {
        self.env.config().frame_rate_hz
    }

    /// Starts an episode: `seed` re-seeds, `None` continues the environment's streams.
    /// Returns the observation and the info dict.
    #[pyo3(signature = (seed=None))]
    fn reset<'py>(
        &mut self,
        py: Python<'py>,
        seed: Option<u64>,
    ) -> PyResult<(Bound<'py, PyArray1<f32>>, Bound<'py, PyDict>)> {
        self.env.reset(seed, &mut self.obs).map_err(sim_err)?;
        self.spoiled = false;
        let info = PyDict::new(py);
        state_info(py, &self.env, &info)?;
        Ok((PyArray1::from_slice(py, &self.obs), info))
    }

    /// One action (a relative turn, rad). Returns (obs, reward, terminated, truncated, info).
    #[allow(clippy::type_complexity)]
    fn step<'py>(
        &mut self,
        py: Python<'py>,
        action: f32,
    ) -> PyResult<(
        Bound<'py, PyArray1<f32>>,
        f32,
        bool,
        bool,
        Bound<'py, PyDict>,
    )> {
        if self.spoiled {
            return Err(PyRuntimeError::new_err(
                "the fish model failed during this episode: call reset() before step()",
            ));
        }
        let t = self.env.step(&[action], &mut self.obs).map_err(sim_err);
        if let Err(e) = self.model.check() {
            self.spoiled = true;
            return Err(e);
        }
        let t = t?;
        let info = PyDict::new(py);
        info.set_item("goals_reached", t.info.goals_reached)?;
        info.set_item("robot_wall_contacts", t.info.robot_wall_contacts)?;
        info.set_item("fish_wall_contacts", t.info.fish_wall_contacts)?;
        info.set_item("robot_near_wall", t.info.robot_near_wall)?;
        if self.env.config().task.objective == Objective::Ood {
            info.set_item("support_score", t.info.support_score)?;
        }
        state_info(py, &self.env, &info)?;
        Ok((
            PyArray1::from_slice(py, &self.obs),
            t.reward,
            t.terminated,
            t.truncated,
            info,
        ))
    }

    /// A top-down picture of the tank, `size` x `size` pixels, RGB (uint8).
    #[pyo3(signature = (size=400))]
    fn render<'py>(&self, py: Python<'py>, size: usize) -> PyResult<Bound<'py, PyAny>> {
        picture(py, &self.env, size)
    }
}

/// Many environments stepped together on all cores (autoreset in the same step).
#[pyclass(module = "fishprobe._native")]
struct VecEnv {
    venv: fishprobe_sim::VecEnv,
    model: Model,
    spoiled: bool,
    actions: Vec<f32>,
}

#[pymethods]
impl VecEnv {
    #[new]
    #[pyo3(signature = (num_envs, model, mode="training", fish_count=None, settings=None))]
    fn new(
        num_envs: usize,
        model: &Bound<'_, PyAny>,
        mode: &str,
        fish_count: Option<u32>,
        settings: Option<&Bound<'_, PyAny>>,
    ) -> PyResult<Self> {
        if !(1..=MAX_NUM_ENVS).contains(&num_envs) {
            return Err(PyValueError::new_err(format!(
                "num_envs = {num_envs}: must lie in [1, {MAX_NUM_ENVS}]"
            )));
        }
        let cfg = env_config(settings, mode, fish_count)?;
        let model = Model::resolve(model)?;
        let support = ood_support(&model, &cfg)?;
        let mut venv =
            fishprobe_sim::VecEnv::new(cfg, model.model.clone(), num_envs).map_err(sim_err)?;
        venv.set_support(support);
        Ok(Self {
            venv,
            model,
            spoiled: false,
            actions: vec![0.0; num_envs],
        })
    }

    #[getter]
    fn num_envs(&self) -> usize {
        self.venv.num_envs()
    }

    #[getter]
    fn obs_dim(&self) -> usize {
        self.venv.obs_dim()
    }

    #[getter]
    fn max_episode_steps(&self) -> u32 {
        self.venv.envs()[0].max_episode_steps()
    }

    #[getter]
    fn model_name(&self) -> String {
        self.model.spec.label()
    }

    /// Resets every environment; environment `i` is seeded from `seed` and `i`.
    fn reset<'py>(&mut self, py: Python<'py>, seed: u64) -> PyResult<Bound<'py, PyAny>> {
        let venv = &mut self.venv;
        py.detach(|| venv.reset(seed).map(|_| ()))
            .map_err(sim_err)?;
        self.spoiled = false;
        let (n, d) = (self.venv.num_envs(), self.venv.obs_dim());
        Ok(PyArray1::from_slice(py, self.venv.observations())
            .reshape([n, d])?
            .into_any())
    }

    /// One action per environment. Returns (obs, rewards, terminated, truncated, final_obs,
    /// ended, goals_reached): `ended[i]` marks environments whose episode ended in this step
    /// (their row of `obs` is the next episode's first, `final_obs` holds the last).
    #[allow(clippy::type_complexity)]
    fn step<'py>(
        &mut self,
        py: Python<'py>,
        actions: PyReadonlyArray1<'py, f32>,
    ) -> PyResult<Bound<'py, pyo3::types::PyTuple>> {
        if self.spoiled {
            return Err(PyRuntimeError::new_err(
                "the fish model failed during this step: call reset() before step()",
            ));
        }
        let a = actions.as_slice()?;
        if a.len() != self.actions.len() {
            return Err(PyValueError::new_err(format!(
                "{} actions for {} environments",
                a.len(),
                self.actions.len()
            )));
        }
        self.actions.copy_from_slice(a);
        let (venv, acts) = (&mut self.venv, &self.actions);
        let r = py.detach(|| venv.step(acts));
        if let Err(e) = self.model.check() {
            self.spoiled = true;
            return Err(e);
        }
        r.map_err(sim_err)?;
        let (n, d) = (self.venv.num_envs(), self.venv.obs_dim());
        let tr = self.venv.transitions();
        let rewards: Vec<f32> = tr.iter().map(|t| t.reward).collect();
        let term: Vec<bool> = tr.iter().map(|t| t.terminated).collect();
        let trunc: Vec<bool> = tr.iter().map(|t| t.truncated).collect();
        let goals: Vec<u32> = tr.iter().map(|t| t.info.goals_reached).collect();
        let ended: Vec<bool> = self
            .venv
            .finished_episodes()
            .iter()
            .map(Option::is_some)
            .collect();
        let obs = PyArray1::from_slice(py, self.venv.observations()).reshape([n, d])?;
        let fin = PyArray1::from_slice(py, self.venv.final_observations()).reshape([n, d])?;
        pyo3::types::PyTuple::new(
            py,
            [
                obs.into_any(),
                PyArray1::from_vec(py, rewards).into_any(),
                PyArray1::from_vec(py, term).into_any(),
                PyArray1::from_vec(py, trunc).into_any(),
                fin.into_any(),
                PyArray1::from_vec(py, ended).into_any(),
                PyArray1::from_vec(py, goals).into_any(),
            ],
        )
    }

    /// With the OOD task: each environment's mean support score of the fish's views over
    /// the last step (0 with the lead-to-goal task).
    fn support_scores<'py>(&self, py: Python<'py>) -> Bound<'py, PyArray1<f32>> {
        let scores: Vec<f32> = self
            .venv
            .transitions()
            .iter()
            .map(|t| t.info.support_score)
            .collect();
        PyArray1::from_vec(py, scores)
    }

    /// Goals and returns of the episodes that ended in the last step: a list with, for each
    /// environment, `None` or `(episode_return, goals, actions)`.
    fn finished<'py>(&self, py: Python<'py>) -> PyResult<Bound<'py, PyList>> {
        let items: Vec<Option<(f32, usize, u32)>> = self
            .venv
            .finished_episodes()
            .iter()
            .map(|f| {
                f.as_ref()
                    .map(|s| (s.episode_return, s.goal_events.len(), s.actions))
            })
            .collect();
        PyList::new(py, items)
    }

    /// A picture of environment `index`, as `Env.render`.
    #[pyo3(signature = (index=0, size=400))]
    fn render<'py>(
        &self,
        py: Python<'py>,
        index: usize,
        size: usize,
    ) -> PyResult<Bound<'py, PyAny>> {
        let Some(env) = self.venv.envs().get(index) else {
            return Err(PyValueError::new_err(format!(
                "environment {index} of {}",
                self.venv.num_envs()
            )));
        };
        picture(py, env, size)
    }
}

/// A trained robot policy: a policy directory (`fishprobe train`'s output) or `onnx:PATH`.
#[pyclass(module = "fishprobe._native")]
struct Policy {
    ctrl: Box<dyn Controller>,
    rng: SimRng,
}

#[pymethods]
impl Policy {
    #[new]
    #[pyo3(signature = (path, stochastic=false, seed=0))]
    fn new(path: &str, stochastic: bool, seed: u64) -> PyResult<Self> {
        if path.starts_with("scripted:") {
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
            .map_err(PyValueError::new_err)?;
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

/// Reads a trial file (robofish.io 1.0, or the lab's pre-2020 layout) into plain Python
/// values and numpy arrays.
#[pyfunction]
fn read_trial<'py>(py: Python<'py>, path: std::path::PathBuf) -> PyResult<Bound<'py, PyDict>> {
    trial_dict(py, &read_any_trial(&path)?)
}

/// A trial file in robofish.io 1.0 or, failing that, the lab's pre-2020 layout (the first
/// format's error when neither reads).
fn read_any_trial(path: &std::path::Path) -> PyResult<TrialFile> {
    match fishprobe_io::read_trial(path) {
        Ok(t) => Ok(t),
        Err(first) => fishprobe_io::read_legacy(path).map_err(|_| io_err(first)),
    }
}

/// The support scores of the fish's views in a trial file against `model`'s training support
/// (issue 23), from the start of closed-loop control, one entry per fish and tracked frame:
/// `frame`, `fish` (int64), `score` (float32), `position` ((n, 2) cm). The views `fishprobe
/// ood-report --trials` scores.
#[pyfunction]
#[pyo3(signature = (path, model=None))]
fn support_scores<'py>(
    py: Python<'py>,
    path: std::path::PathBuf,
    model: Option<&Bound<'_, PyAny>>,
) -> PyResult<Bound<'py, PyDict>> {
    let spec = match model.filter(|m| !m.is_none()) {
        Some(m) => Model::spec_of(m)?.ok_or_else(|| {
            PyValueError::new_err(
                "a fish model written in Python is not data-driven: it has no training support \
                 (give a data-driven model's name or spec, e.g. \"ConvNet\")",
            )
        })?,
        None => ModelSpec::by_name("ConvNet").map_err(model_err)?,
    };
    let support = spec.support().map_err(model_err)?;
    let trial = read_any_trial(&path)?;
    let views = py.detach(|| fishprobe_analysis::ood::trial_views(&support, &trial));
    let d = PyDict::new(py);
    let frames: Vec<i64> = views.iter().map(|v| v.frame as i64).collect();
    let fish: Vec<i64> = views.iter().map(|v| v.fish as i64).collect();
    let scores: Vec<f32> = views.iter().map(|v| v.score).collect();
    let positions: Vec<f32> = views.iter().flat_map(|v| v.position).collect();
    d.set_item("frame", PyArray1::from_vec(py, frames))?;
    d.set_item("fish", PyArray1::from_vec(py, fish))?;
    d.set_item("score", PyArray1::from_vec(py, scores))?;
    d.set_item(
        "position",
        PyArray1::from_vec(py, positions).reshape([views.len(), 2])?,
    )?;
    Ok(d)
}

fn attrs_dict<'py>(
    py: Python<'py>,
    attrs: &std::collections::BTreeMap<String, fishprobe_io::Attr>,
) -> PyResult<Bound<'py, PyAny>> {
    let text = serde_json::to_string(attrs).map_err(|e| PyRuntimeError::new_err(e.to_string()))?;
    py.import("json")?.call_method1("loads", (text,))
}

fn trial_dict<'py>(py: Python<'py>, t: &TrialFile) -> PyResult<Bound<'py, PyDict>> {
    let d = PyDict::new(py);
    d.set_item("frame_rate_hz", t.frame_rate_hz)?;
    d.set_item("world_size_cm", t.world_size_cm.to_vec())?;
    let frames = t.entities.iter().map(|e| e.frames()).max().unwrap_or(0);
    let n = t.entities.len();
    let mut poses = vec![f32::NAN; n * frames * 3];
    let entities = PyList::empty(py);
    for (i, e) in t.entities.iter().enumerate() {
        let headings = e.headings();
        for (f, (p, h)) in e.positions.iter().zip(&headings).enumerate() {
            let at = (i * frames + f) * 3;
            poses[at..at + 3].copy_from_slice(&[p[0], p[1], *h]);
        }
        let ed = PyDict::new(py);
        ed.set_item("name", &e.name)?;
        ed.set_item("category", &e.category_label)?;
        let pos: Vec<f32> = e.positions.iter().flatten().copied().collect();
        ed.set_item(
            "positions",
            PyArray1::from_vec(py, pos).reshape([e.frames(), 2])?,
        )?;
        let ori: Vec<f32> = e.orientations.iter().flatten().copied().collect();
        ed.set_item(
            "orientations",
            PyArray1::from_vec(py, ori).reshape([e.orientations.len(), 2])?,
        )?;
        ed.set_item("attributes", attrs_dict(py, &e.attributes)?)?;
        entities.append(ed)?;
    }
    d.set_item("entities", entities)?;
    d.set_item(
        "names",
        t.entities
            .iter()
            .map(|e| e.name.clone())
            .collect::<Vec<_>>(),
    )?;
    d.set_item(
        "categories",
        t.entities
            .iter()
            .map(|e| e.category_label.clone())
            .collect::<Vec<_>>(),
    )?;
    d.set_item(
        "poses",
        PyArray1::from_vec(py, poses).reshape([n, frames, 3])?,
    )?;
    d.set_item("attributes", attrs_dict(py, &t.attributes)?)?;
    match &t.task {
        None => {
            d.set_item("goals", numpy::PyArray2::<f32>::zeros(py, [0, 2], false))?;
            d.set_item("fishprobe", py.None())?;
        }
        Some(task) => {
            let g: Vec<f32> = task.goals.iter().flatten().copied().collect();
            d.set_item(
                "goals",
                PyArray1::from_vec(py, g).reshape([task.goals.len(), 2])?,
            )?;
            let m = PyDict::new(py);
            m.set_item("kind", task.kind.label())?;
            m.set_item("policy", &task.policy)?;
            m.set_item("fish_model", &task.fish_model)?;
            m.set_item("seed", task.seed)?;
            m.set_item("goal_radius_cm", task.goal_radius_cm)?;
            m.set_item("active_goal", PyArray1::from_slice(py, &task.active_goal))?;
            m.set_item("goal_frames", PyArray1::from_slice(py, &task.goal_frames))?;
            m.set_item(
                "command_frames",
                PyArray1::from_slice(py, &task.command_frames),
            )?;
            m.set_item(
                "command_turns",
                PyArray1::from_slice(py, &task.command_turns),
            )?;
            m.set_item("control_start_frame", task.control_start_frame)?;
            let config = if task.config_json.trim().is_empty() {
                py.None().into_bound(py)
            } else {
                py.import("json")?
                    .call_method1("loads", (task.config_json.as_str(),))
                    .unwrap_or_else(|_| {
                        task.config_json
                            .clone()
                            .into_pyobject(py)
                            .map_or_else(|_| py.None().into_bound(py), |s| s.into_any())
                    })
            };
            m.set_item("config", config)?;
            m.set_item("program_version", &task.program_version)?;
            d.set_item("fishprobe", m)?;
        }
    }
    Ok(d)
}

/// The names of the built-in fish models.
#[pyfunction]
fn model_names() -> Vec<&'static str> {
    ModelSpec::NAMES.to_vec()
}

/// Trains a PPO policy (fishprobe's own trainer) against `model` into `out`; `callback` gets
/// each iteration's statistics as a dict. Returns the policy file's path.
#[pyfunction]
#[pyo3(signature = (model, out, preset="paper", seed=0, steps=None, settings=None, ppo=None, resume=false, callback=None, ood_yardstick=None, yardstick=None))]
#[allow(clippy::too_many_arguments)]
fn train(
    py: Python<'_>,
    model: &Bound<'_, PyAny>,
    out: std::path::PathBuf,
    preset: &str,
    seed: u64,
    steps: Option<u64>,
    settings: Option<&Bound<'_, PyAny>>,
    ppo: Option<&Bound<'_, PyAny>>,
    resume: bool,
    callback: Option<&Bound<'_, PyAny>>,
    ood_yardstick: Option<String>,
    yardstick: Option<&Bound<'_, PyAny>>,
) -> PyResult<String> {
    let resolved = Model::resolve(model)?;
    let resuming = || resume && out.join("params.json").exists();
    // A new run is checked before its directory is created: a refused `train` leaves none.
    let fresh_spec = || {
        let spec = fresh_run(&resolved.spec, preset, seed, steps, settings, ppo)?;
        let measure = match &ood_yardstick {
            None if yardstick.is_some_and(|y| !y.is_none()) => {
                return Err(PyValueError::new_err(
                    "yardstick: settings of a yardstick need ood_yardstick (the policy to measure)",
                ))
            }
            None => None,
            Some(policy) => {
                let config: OodYardstickConfig =
                    overrides(OodYardstickConfig::default(), yardstick, "yardstick")?;
                fishprobe_learn::yardstick::check(policy, &config, &spec.env).map_err(learn_err)?;
                Some((policy.clone(), config))
            }
        };
        Ok((spec, measure))
    };
    let mut fresh = if resuming() {
        None
    } else {
        Some(fresh_spec()?)
    };
    let _lock = fishprobe_io::DirLock::acquire(&out, "fishprobe.train")
        .map_err(|e| PyRuntimeError::new_err(e.to_string()))?;
    let mut trainer = if resuming() {
        let recorded = Trainer::recorded_spec(&out).map_err(learn_err)?;
        if recorded.model.name() != resolved.spec.name()
            || (resolved.python.is_some() && recorded.model != resolved.spec)
        {
            return Err(PyValueError::new_err(format!(
                "{}: the run was begun with the fish model {} ({}); resume it with that model, not {}",
                out.display(),
                recorded.model.label(),
                recorded.model.origin(),
                resolved.spec.origin()
            )));
        }
        let model = match resolved.python {
            Some(_) => resolved.model.clone(),
            None => recorded.model.build().map_err(model_err)?,
        };
        Trainer::resume_with_model(&out, model).map_err(learn_err)?
    } else {
        // (Checked above unless the run's params.json vanished since.)
        let (spec, measure) = match fresh.take() {
            Some(s) => s,
            None => fresh_spec()?,
        };
        let model = resolved.model.clone();
        let measure = measure.as_ref().map(|(p, c)| (p.as_str(), c));
        py.detach(|| fishprobe_learn::yardstick::start_run(&out, spec, model, measure))
            .map_err(learn_err)?
            .0
    };
    while !trainer.done() {
        let t = &mut trainer;
        let r = py.detach(|| t.iterate());
        resolved.check()?;
        let stats = r.map_err(learn_err)?;
        if let Some(cb) = callback.filter(|c| !c.is_none()) {
            let text = serde_json::to_string(&stats)
                .map_err(|e| PyRuntimeError::new_err(e.to_string()))?;
            let d = py.import("json")?.call_method1("loads", (text,))?;
            cb.call1((d,))?;
        }
        // Ctrl+C between iterations: the run resumes from its last checkpoint.
        py.check_signals()?;
    }
    let path = trainer.finish().map_err(learn_err)?;
    Ok(path.display().to_string())
}

/// Runs `policy` on the evaluation task against `model`, one trial file per episode and
/// `summary.csv` in `out`, exactly as `fishprobe evaluate` does (a fish model written in Python
/// too). Returns the per-episode results as a dict.
#[pyfunction]
#[pyo3(signature = (policy, model, out, episodes=18, minutes=15.0, seed=0, settings=None))]
#[allow(clippy::too_many_arguments)]
fn evaluate<'py>(
    py: Python<'py>,
    policy: &str,
    model: &Bound<'_, PyAny>,
    out: std::path::PathBuf,
    episodes: usize,
    minutes: f32,
    seed: u64,
    settings: Option<&Bound<'_, PyAny>>,
) -> PyResult<Bound<'py, PyDict>> {
    use fishprobe_learn::evaluate::{minutes_in_range, MAX_EPISODES, MINUTES_RANGE};
    if !(1..=MAX_EPISODES).contains(&episodes) {
        return Err(PyValueError::new_err(format!(
            "episodes = {episodes}: must lie in [1, {MAX_EPISODES}]"
        )));
    }
    if !minutes_in_range(f64::from(minutes)) {
        return Err(PyValueError::new_err(format!(
            "minutes = {minutes}: must lie in {MINUTES_RANGE}"
        )));
    }
    let resolved = Model::resolve(model)?;
    let c = fishprobe_learn::controller(policy, false).map_err(learn_err)?;
    let e = fishprobe_learn::Evaluation {
        model: resolved.spec.clone(),
        env: env_config(settings, "evaluation", None)?,
        episodes,
        minutes,
        seed,
        start: None,
        out: out.clone(),
        prefix: "trial".into(),
    };
    // Checked before the directory exists: a refused evaluation leaves none.
    let _lock = fishprobe_io::DirLock::acquire(&out, "fishprobe.evaluate")
        .map_err(|e| PyRuntimeError::new_err(e.to_string()))?;
    fishprobe_learn::evaluate::check_fresh_output(&out, &e.prefix)
        .map_err(|e| pyo3::exceptions::PyFileExistsError::new_err(e.to_string()))?;
    // A Python fish is shared by the episodes; every other model is built as the CLI builds it.
    let fish = resolved.python.is_some().then(|| resolved.model.clone());
    let r = py.detach(|| fishprobe_learn::evaluate_with_model(c.as_ref(), &e, fish));
    resolved.check()?;
    let results = r.map_err(learn_err)?;
    let (mean, sd) = fishprobe_learn::goals_mean_sd(&results);
    let d = PyDict::new(py);
    let goals: Vec<i64> = results.iter().map(|r| r.goals as i64).collect();
    let waits: Vec<f64> = results
        .iter()
        .map(|r| r.mean_time_to_goal_s.unwrap_or(f64::NAN))
        .collect();
    let walls: Vec<i64> = results.iter().map(|r| i64::from(r.wall_contacts)).collect();
    let files: Vec<String> = results
        .iter()
        .map(|r| r.file.display().to_string())
        .collect();
    d.set_item("policy", c.describe())?;
    d.set_item("model", resolved.spec.label())?;
    d.set_item("goals", PyArray1::from_vec(py, goals))?;
    d.set_item("mean_time_to_goal_s", PyArray1::from_vec(py, waits))?;
    d.set_item("wall_contacts", PyArray1::from_vec(py, walls))?;
    d.set_item("files", PyList::new(py, files)?)?;
    d.set_item("goals_mean", mean)?;
    d.set_item("goals_sd", sd)?;
    Ok(d)
}

/// The spec of a new training run, every setting checked.
fn fresh_run(
    model: &ModelSpec,
    preset: &str,
    seed: u64,
    steps: Option<u64>,
    settings: Option<&Bound<'_, PyAny>>,
    ppo: Option<&Bound<'_, PyAny>>,
) -> PyResult<RunSpec> {
    let Some(mut cfg) = PpoConfig::preset_for(preset, model.is_expensive()) else {
        return Err(PyValueError::new_err(format!(
            "unknown preset `{preset}`: use paper, published, quick or smoke"
        )));
    };
    cfg = overrides(cfg, ppo, "ppo")?;
    if let Some(s) = steps {
        cfg.total_timesteps = s;
    }
    cfg.validate()
        .map_err(|e| PyValueError::new_err(format!("ppo: {e}")))?;
    let spec = RunSpec {
        ppo: cfg,
        env: env_config(settings, "training", None)?,
        model: model.clone(),
        seed,
        preset: preset.to_string(),
        program_version: env!("CARGO_PKG_VERSION").into(),
    };
    // The OOD reward needs the model's support: a missing or foreign file is refused here.
    spec.check().map_err(learn_err)?;
    Ok(spec)
}

/// `base` with the fields of the dict `over` (if given) replaced, for the argument `what`.
fn overrides<T: serde::Serialize + serde::de::DeserializeOwned>(
    base: T,
    over: Option<&Bound<'_, PyAny>>,
    what: &str,
) -> PyResult<T> {
    let Some(over) = over.filter(|p| !p.is_none()) else {
        return Ok(base);
    };
    let mut merged =
        serde_json::to_value(&base).map_err(|e| PyRuntimeError::new_err(e.to_string()))?;
    let fields: serde_json::Value = serde_json::from_str(&to_json(over, what)?)
        .map_err(|e| PyValueError::new_err(format!("{what}: {e}")))?;
    let (Some(m), serde_json::Value::Object(o)) = (merged.as_object_mut(), fields) else {
        return Err(PyTypeError::new_err(format!(
            "{what} must be a dict of settings"
        )));
    };
    let too_large = integer_too_large(&o);
    m.extend(o);
    serde_json::from_value(merged).map_err(|e| {
        // JSON has no integer type: an integer past u64 arrives as a float, and serde's own
        // message ("invalid type: floating point, expected u64") names neither field nor cause.
        let msg = match too_large.filter(|_| e.to_string().contains("floating point")) {
            Some((key, v)) => format!(
                "{what}: {key} = {v:.0} is too large for a whole number (at most {})",
                u64::MAX
            ),
            None => format!("{what}: {e}"),
        };
        PyValueError::new_err(msg)
    })
}

/// The first top-level field of `fields` holding a whole number beyond the range of u64 (JSON
/// turns a Python integer such as `2**70` into a float).
fn integer_too_large(fields: &serde_json::Map<String, serde_json::Value>) -> Option<(String, f64)> {
    fields.iter().find_map(|(k, v)| {
        let x = v.as_f64().filter(|_| v.is_f64())?;
        (x.fract() == 0.0 && x.abs() >= u64::MAX as f64).then(|| (k.clone(), x))
    })
}

/// Whether `path` names a directory holding a study's results.
#[pyfunction]
fn results_path(study: std::path::PathBuf) -> std::path::PathBuf {
    if study.is_dir() {
        fishprobe_io::StudyLayout::new(&study).results()
    } else {
        study
    }
}

#[pymodule]
fn _native(m: &Bound<'_, PyModule>) -> PyResult<()> {
    m.add_class::<Env>()?;
    m.add_class::<VecEnv>()?;
    m.add_class::<Policy>()?;
    m.add_function(wrap_pyfunction!(read_trial, m)?)?;
    m.add_function(wrap_pyfunction!(support_scores, m)?)?;
    m.add_function(wrap_pyfunction!(model_names, m)?)?;
    m.add_function(wrap_pyfunction!(train, m)?)?;
    m.add_function(wrap_pyfunction!(evaluate, m)?)?;
    m.add_function(wrap_pyfunction!(results_path, m)?)?;
    m.add("__version__", env!("CARGO_PKG_VERSION"))?;
    m.add("MAX_NUM_ENVS", MAX_NUM_ENVS)?;
    Ok(())
}
