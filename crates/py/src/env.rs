//! The environments: one (`Env`) and many stepped together on all cores (`VecEnv`), and
//! the `model=` and `settings=` arguments they take.

use super::*;

/// A resolved `model=` argument.
pub(crate) struct Model {
    pub(crate) spec: ModelSpec,
    pub(crate) model: Arc<dyn FishModel>,
    pub(crate) python: Option<Arc<PyFish>>,
}

impl Model {
    /// A name (`"Zone"`, `"onnx:PATH"`), a spec dict (`{"model": "Zone", "speed_cm_s": 5}`), or
    /// a Python object with `decide(views)`.
    pub(crate) fn resolve(obj: &Bound<'_, PyAny>) -> PyResult<Self> {
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
    pub(crate) fn spec_of(obj: &Bound<'_, PyAny>) -> PyResult<Option<ModelSpec>> {
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
    pub(crate) fn check(&self) -> PyResult<()> {
        match self.python.as_ref().and_then(|f| f.take_error()) {
            Some(e) => Err(e),
            None => Ok(()),
        }
    }
}

/// The environment settings: `settings` (a dict of `EnvConfig` fields, as in a settings
/// file's `env` table; missing fields keep their defaults), then `mode` and `fish_count`.
pub(crate) fn env_config(
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
pub(crate) struct Env {
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
pub(crate) struct VecEnv {
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
