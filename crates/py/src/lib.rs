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

mod env;
mod files;
mod fish;
mod policy;
mod render;

// A user's ONNX file cannot make the engine allocate gigabytes (fishprobe_onnx::CappedAlloc).
#[global_allocator]
static ALLOC: fishprobe_onnx::CappedAlloc = fishprobe_onnx::CappedAlloc;

use fish::PyFish;
use fishprobe_io::{IoError, TrialFile};
use fishprobe_learn::run::{train_to_end, Begin, TrainHooks};
use fishprobe_learn::yardstick::OodYardstickConfig;
use fishprobe_learn::{IterationStats, LearnError, PpoConfig, RunSpec, Trainer};
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

use env::{env_config, Env, Model, VecEnv};
use files::{read_trial, support_scores};
use policy::Policy;

/// The names of the built-in fish models.
#[pyfunction]
fn model_names() -> Vec<&'static str> {
    ModelSpec::listed_names()
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
    let resuming = || resume && fishprobe_learn::run::RunLayout::new(&out).holds_run();
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
    let mut hooks = PyTrain {
        model: resolved.model.clone(),
        measure: None,
        callback: callback
            .filter(|c| !c.is_none())
            .map(|c| c.clone().unbind()),
        python: resolved.python.clone(),
        raised: None,
    };
    let begin = if resuming() {
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
        if resolved.python.is_none() {
            hooks.model = recorded.model.build().map_err(model_err)?;
        }
        // `steps` raises a resumed run's budget (a finished run trains on), as `train
        // --resume --steps` does.
        if let Some(steps) = steps {
            Trainer::raise_budget(&out, steps).map_err(learn_err)?;
        }
        Begin::Resume
    } else {
        // (Checked above unless the run's params.json vanished since.)
        let (spec, measure) = match fresh.take() {
            Some(s) => s,
            None => fresh_spec()?,
        };
        hooks.measure = measure;
        Begin::Start(spec, "pass resume=True to continue it")
    };
    // Python is released while training; the hooks take it back for the callback.
    let trained = py.detach(|| train_to_end(&out, begin, PY_BUILD, &mut hooks));
    resolved.check()?;
    if let Some(e) = hooks.raised.take() {
        return Err(e);
    }
    let (_, path) = trained.map_err(learn_err)?;
    Ok(path.display().to_string())
}

/// What Python's `train` adds to training: its fish model (a Python fish only it can build),
/// a new run's yardstick, and the callback with each iteration's statistics; Ctrl+C between
/// iterations stops the run, which resumes from its last checkpoint.
struct PyTrain {
    model: Arc<dyn FishModel>,
    measure: Option<(String, OodYardstickConfig)>,
    callback: Option<Py<PyAny>>,
    python: Option<Arc<PyFish>>,
    /// What Python raised in the callback or on a signal (training stops at once).
    raised: Option<PyErr>,
}

impl TrainHooks for PyTrain {
    fn create(&mut self, dir: &std::path::Path, spec: RunSpec) -> Result<Trainer, LearnError> {
        let measure = self.measure.as_ref().map(|(p, c)| (p.as_str(), c));
        fishprobe_learn::yardstick::start_run(dir, spec, self.model.clone(), measure)
            .map(|(t, _)| t)
    }

    fn resume(&mut self, dir: &std::path::Path, build: &str) -> Result<Trainer, LearnError> {
        Trainer::resume_with_model(dir, self.model.clone(), build)
    }

    fn iterated(&mut self, _t: &Trainer, s: &IterationStats) -> Result<(), LearnError> {
        // A Python fish that raised stops the run; `train` raises what it raised.
        if let Some(e) = self.python.as_ref().and_then(|f| f.take_error()) {
            self.raised = Some(e);
            return Err(LearnError::Run("the Python fish model raised".into()));
        }
        let r = Python::attach(|py| -> PyResult<()> {
            if let Some(cb) = &self.callback {
                let text =
                    serde_json::to_string(s).map_err(|e| PyRuntimeError::new_err(e.to_string()))?;
                let d = py.import("json")?.call_method1("loads", (text,))?;
                cb.call1(py, (d,))?;
            }
            py.check_signals()
        });
        match r {
            Ok(()) => Ok(()),
            Err(e) => {
                self.raised = Some(e);
                Err(LearnError::Run("stopped from Python".into()))
            }
        }
    }
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
    let spec = RunSpec::new(
        model.clone(),
        cfg,
        env_config(settings, "training", None)?,
        seed,
        preset.to_string(),
        PY_BUILD,
    );
    // The OOD reward needs the model's support: a missing or foreign file is refused here.
    spec.check().map_err(learn_err)?;
    Ok(spec)
}

/// The build a run records when this package starts or continues it (`params.json`'s
/// `program_build`, `result.json`'s `build`).
const PY_BUILD: &str = concat!(env!("CARGO_PKG_VERSION"), ", Python package");

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
