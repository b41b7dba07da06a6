//! A fish model written in Python, driving fish in the Rust simulator.
//!
//! The model is any object with `decide(views) -> (speed, turn_rate)` over a batch of fish.
//! It is called once per frame for all fish of an environment (of a part of a vector
//! environment), through [`FishModel::infer_batch`]: the views go out as numpy arrays, two
//! numbers per fish come back. The simulator cannot carry a Python exception through its
//! stepping, so the first error is kept here, the fish stand still for the rest of the action,
//! and the caller raises it when the step returns ([`PyFish::take_error`]).

use fishprobe_sim::{AgentState, FishMind, FishModel, FishMotion, FishView, SimRng, MAX_OTHERS};
use numpy::{PyArray1, PyArrayMethods, PyUntypedArrayMethods};
use pyo3::exceptions::{PyRuntimeError, PyTypeError, PyValueError};
use pyo3::prelude::*;
use pyo3::types::PyDict;
use std::sync::Mutex;

/// Floats per agent in the arrays a Python model sees: x, y (cm), heading (rad), vx, vy (cm/s).
pub const POSE: usize = 5;

/// A Python fish model as a [`FishModel`].
pub struct PyFish {
    decide: Py<PyAny>,
    namespace: Py<PyAny>,
    /// `numpy.asarray`, looked up once (it is called twice per frame).
    asarray: Py<PyAny>,
    name: String,
    class: String,
    error: Mutex<Option<PyErr>>,
}

impl std::fmt::Debug for PyFish {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        write!(f, "PyFish({})", self.class)
    }
}

impl PyFish {
    /// Wraps `obj`, which must have a callable `decide`.
    pub fn new(obj: &Bound<'_, PyAny>) -> PyResult<Self> {
        let py = obj.py();
        let decide = obj.getattr("decide").map_err(|_| {
            PyTypeError::new_err(format!(
                "model {} has no decide(views) method: a fish model is a name (\"Zone\"), a spec dict, \
                 \"onnx:PATH\", or an object with decide(views) -> (speed, turn_rate)",
                obj.repr().map_or_else(|_| "?".to_string(), |r| r.to_string())
            ))
        })?;
        if !decide.is_callable() {
            return Err(PyTypeError::new_err("the model's `decide` is not callable"));
        }
        let ty = obj.get_type();
        let qual = ty.qualname()?.to_string();
        let module = ty.module()?.to_string();
        let class = format!("{module}.{qual}");
        let name = match obj.getattr("name") {
            Ok(n) => n
                .extract::<String>()
                .map_err(|_| PyTypeError::new_err(format!("{class}.name must be a string")))?,
            Err(_) => qual.rsplit('.').next().unwrap_or(&qual).to_string(),
        };
        let namespace = py.import("types")?.getattr("SimpleNamespace")?.unbind();
        let asarray = py.import("numpy")?.getattr("asarray")?.unbind();
        Ok(Self {
            decide: decide.unbind(),
            namespace,
            asarray,
            name,
            class,
            error: Mutex::new(None),
        })
    }

    /// The model's class, `module.QualifiedName`.
    pub fn class(&self) -> &str {
        &self.class
    }

    /// The first error the model raised since the last call, if any.
    pub fn take_error(&self) -> Option<PyErr> {
        self.error.lock().map_or(None, |mut e| e.take())
    }

    fn call(&self, py: Python<'_>, views: &[FishView], out: &mut [f32]) -> PyResult<()> {
        let n = views.len();
        let mut me = Vec::with_capacity(n * POSE);
        let mut others = vec![f32::NAN; n * MAX_OTHERS * POSE];
        let mut n_others = Vec::with_capacity(n);
        let mut walls = Vec::with_capacity(n * 4);
        let mut time_s = Vec::with_capacity(n);
        let pose = |a: &AgentState| [a.x, a.y, a.heading, a.vx, a.vy];
        for (i, v) in views.iter().enumerate() {
            me.extend_from_slice(&pose(&v.me));
            for (j, o) in v.others().iter().enumerate() {
                let at = (i * MAX_OTHERS + j) * POSE;
                others[at..at + POSE].copy_from_slice(&pose(o));
            }
            n_others.push(i64::from(v.n_others));
            let h = v.tank.half;
            walls.extend_from_slice(&[v.me.x + h, h - v.me.x, v.me.y + h, h - v.me.y]);
            time_s.push(v.time_s);
        }
        let dt = views.first().map_or(0.0, |v| v.dt);
        let half = views.first().map_or(0.0, |v| v.tank.half);
        let kw = PyDict::new(py);
        kw.set_item("me", PyArray1::from_vec(py, me).reshape([n, POSE])?)?;
        kw.set_item(
            "others",
            PyArray1::from_vec(py, others).reshape([n, MAX_OTHERS, POSE])?,
        )?;
        kw.set_item("n_others", PyArray1::from_vec(py, n_others))?;
        kw.set_item("walls", PyArray1::from_vec(py, walls).reshape([n, 4])?)?;
        kw.set_item("time_s", PyArray1::from_vec(py, time_s))?;
        kw.set_item("dt", dt)?;
        kw.set_item("tank_half_size_cm", half)?;
        let views_obj = self.namespace.bind(py).call((), Some(&kw))?;
        let result = self.decide.bind(py).call1((views_obj,))?;
        let (speed, turn) = result
            .extract::<(Bound<'_, PyAny>, Bound<'_, PyAny>)>()
            .map_err(|_| {
                PyTypeError::new_err(format!(
                    "{}.decide must return (speed, turn_rate), two arrays of {n} numbers; it returned {}",
                    self.class,
                    result.get_type().name().map_or_else(|_| "?".into(), |s| s.to_string())
                ))
            })?;
        for (k, (what, arr)) in [("speed", speed), ("turn_rate", turn)]
            .into_iter()
            .enumerate()
        {
            let kw = PyDict::new(py);
            kw.set_item("dtype", "float32")?;
            let a = self.asarray.bind(py).call((arr,), Some(&kw)).map_err(|e| {
                PyTypeError::new_err(format!(
                    "{}.decide: `{what}` is not an array of numbers ({e})",
                    self.class
                ))
            })?;
            let a = a.cast_into::<numpy::PyArrayDyn<f32>>().map_err(|_| {
                PyTypeError::new_err(format!("{}.decide: `{what}` is not numeric", self.class))
            })?;
            let shape = a.shape().to_vec();
            if shape != [n] {
                return Err(PyValueError::new_err(format!(
                    "{}.decide returned `{what}` of shape {shape:?}; expected ({n},), one per fish",
                    self.class
                )));
            }
            let ro = a.readonly();
            let values = ro.as_slice()?;
            if let Some((i, v)) = values.iter().enumerate().find(|(_, v)| !v.is_finite()) {
                return Err(PyValueError::new_err(format!(
                    "{}.decide returned `{what}` = {v} for fish {i}: must be finite",
                    self.class
                )));
            }
            for (i, v) in values.iter().enumerate() {
                out[i * 2 + k] = *v;
            }
        }
        Ok(())
    }
}

impl FishModel for PyFish {
    fn name(&self) -> &str {
        &self.name
    }

    fn inference_width(&self) -> usize {
        2
    }

    /// Python runs one thread at a time (the GIL): one call per frame for all fish is fastest.
    fn concurrent_inference(&self) -> bool {
        false
    }

    fn infer_batch(&self, views: &[FishView], out: &mut [f32]) {
        out.fill(0.0);
        let failed = self.error.lock().map_or(true, |e| e.is_some());
        if failed || views.is_empty() {
            return;
        }
        let result = Python::attach(|py| {
            self.call(py, views, out).map_err(|e| {
                // Errors of the model's own code keep their type and traceback as the cause.
                let wrapped = PyRuntimeError::new_err(format!(
                    "fish model {} failed: {}",
                    self.class,
                    e.value(py)
                ));
                if e.is_instance_of::<PyTypeError>(py) || e.is_instance_of::<PyValueError>(py) {
                    e
                } else {
                    wrapped.set_cause(py, Some(e));
                    wrapped
                }
            })
        });
        if let Err(e) = result {
            out.fill(0.0);
            if let Ok(mut slot) = self.error.lock() {
                slot.get_or_insert(e);
            }
        }
    }

    fn decide(
        &self,
        view: &FishView,
        inferred: &[f32],
        mind: &mut FishMind,
        _rng: &mut SimRng,
    ) -> FishMotion {
        let (speed, turn) = match inferred {
            [s, t, ..] => (s.max(0.0), *t),
            _ => (0.0, 0.0),
        };
        mind.speed = speed;
        mind.turn_rate = turn;
        FishMotion {
            heading: view.me.heading + turn * view.dt,
            speed,
        }
    }
}
