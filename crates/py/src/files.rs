//! Trial files as dicts of numpy arrays, and the support scores of their fish's views.

use super::*;

/// Reads a trial file (robofish.io 1.0, or the lab's pre-2020 layout) into plain Python
/// values and numpy arrays.
#[pyfunction]
pub(crate) fn read_trial<'py>(
    py: Python<'py>,
    path: std::path::PathBuf,
) -> PyResult<Bound<'py, PyDict>> {
    trial_dict(py, &read_any_trial(&path)?)
}

/// A trial file in robofish.io 1.0 or the lab's pre-2020 layout.
fn read_any_trial(path: &std::path::Path) -> PyResult<TrialFile> {
    fishprobe_io::read_any_trial(path).map_err(io_err)
}

/// The support scores of the fish's views in a trial file against `model`'s training support, from the start of closed-loop control, one entry per fish and tracked frame:
/// `frame`, `fish` (int64), `score` (float32), `position` ((n, 2) cm). The views `fishprobe
/// ood-report --trials` scores.
#[pyfunction]
#[pyo3(signature = (path, model=None))]
pub(crate) fn support_scores<'py>(
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
