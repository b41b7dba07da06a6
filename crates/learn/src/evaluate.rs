//! Running a controller on the evaluation task: one trial file per episode and a summary.

use crate::error::LearnError;
use fishprobe_io::{write_trial, TrialFile, TrialKind, TrialMeta};
use fishprobe_models::ModelSpec;
use fishprobe_sim::{
    derive_seed, stream, ControlInput, Controller, Env, EnvConfig, FishModel, StartPoses, TankEnv,
};
use rayon::prelude::*;
use std::path::{Path, PathBuf};
use std::sync::Arc;

/// Longest evaluation episode, in minutes (24 hours): the simulator reserves an episode's
/// trajectory up front (`--minutes 1e9` asked for 1.2 TB), and trial files of up to 48 hours
/// are read back (`fishprobe_io::ReadLimits::max_frames`).
pub const MAX_MINUTES: f32 = 24.0 * 60.0;

/// Shortest evaluation episode, in minutes: one second, the paper's control period. A shorter
/// one still runs one whole action, and its rates ("goals per 0.000001 min") would describe a
/// time that was never simulated.
pub const MIN_MINUTES: f32 = 1.0 / 60.0;

/// The range of episode lengths, as error messages show it.
pub const MINUTES_RANGE: &str = "[1/60, 1440] minutes (one second to 24 hours)";

/// Whether `minutes` is an episode length fishprobe accepts: finite, from [`MIN_MINUTES`] to
/// [`MAX_MINUTES`]. One second written with six decimals (`0.016667`) counts as one second.
pub fn minutes_in_range(minutes: f64) -> bool {
    minutes.is_finite()
        && minutes >= f64::from(MIN_MINUTES) * (1.0 - 1e-4)
        && minutes <= f64::from(MAX_MINUTES)
}

/// Checks the minutes setting `setting` (an episode length): one second to 24 hours
/// ([`minutes_in_range`]), the value shown as it was given.
pub fn check_minutes<T>(setting: &str, minutes: T) -> Result<(), fishprobe_sim::ConfigError>
where
    T: Copy + Into<f64> + std::fmt::Display + std::fmt::LowerExp,
{
    if minutes_in_range(minutes.into()) {
        return Ok(());
    }
    Err(fishprobe_sim::ConfigError::new(
        "",
        setting,
        fishprobe_sim::params::check::shown(minutes),
        &format!("must lie in {MINUTES_RANGE}"),
    ))
}

/// Refuses an output directory that already holds an evaluation (trial files
/// `<prefix>_*.hdf5` or a `summary.csv`): writing into it would overwrite some of the earlier
/// trials and leave the others beside the new ones, so that a later analysis would count both
/// as one evaluation. A missing directory is fresh; one that cannot be listed is left to the
/// writing to report. `fishprobe evaluate` and Python's `fishprobe.evaluate` check this; a
/// study evaluates into fresh staging directories of its own.
pub fn check_fresh_output(out: &Path, prefix: &str) -> Result<(), LearnError> {
    let Ok(entries) = std::fs::read_dir(out) else {
        return Ok(());
    };
    let (mut trials, mut summary) = (0usize, false);
    let trial_start = format!("{prefix}_");
    for e in entries.flatten() {
        let name = e.file_name();
        let name = name.to_string_lossy();
        if name == "summary.csv" {
            summary = true;
        } else if name.starts_with(&trial_start) && name.ends_with(".hdf5") {
            trials += 1;
        }
    }
    if trials > 0 || summary {
        return Err(LearnError::Run(format!(
            "{}: already holds an evaluation ({trials} trial files{}); choose another output \
             directory, or remove them to evaluate again",
            out.display(),
            if summary { " and summary.csv" } else { "" }
        )));
    }
    Ok(())
}

/// Most episodes one evaluation runs (each is one trial file).
pub const MAX_EPISODES: usize = 100_000;

/// One evaluation episode's outcome.
#[derive(Debug, Clone, PartialEq, serde::Serialize)]
pub struct EpisodeResult {
    /// Episode index.
    pub episode: usize,
    /// Its seed.
    pub seed: u64,
    /// Goals reached.
    pub goals: usize,
    /// Mean time to goal (s), if any goal.
    pub mean_time_to_goal_s: Option<f64>,
    /// Frames with the robot clipped at a wall.
    pub wall_contacts: u32,
    /// Its trial file.
    pub file: PathBuf,
}

/// An evaluation: which episodes, how long, where to. Serialised (without `out`), it is
/// everything the episodes depend on besides the controller.
#[derive(Debug, Clone, serde::Serialize)]
pub struct Evaluation {
    /// Fish model.
    pub model: ModelSpec,
    /// Environment settings (forced to evaluation mode).
    pub env: EnvConfig,
    /// Episodes.
    pub episodes: usize,
    /// Minutes per episode.
    pub minutes: f32,
    /// Master seed.
    pub seed: u64,
    /// Fixed start poses (approach assay) instead of random ones.
    pub start: Option<StartPoses>,
    /// Output directory; files are `<prefix>_<k>.hdf5`.
    #[serde(skip)]
    pub out: PathBuf,
    /// File name prefix.
    pub prefix: String,
}

/// Runs episode `k` of an evaluation and writes its trial file to `file`.
pub fn run_episode(
    c: &dyn Controller,
    e: &Evaluation,
    k: usize,
    file: &Path,
) -> Result<EpisodeResult, LearnError> {
    run_episode_with(c, e, k, file, e.model.build()?)
}

/// [`run_episode`] with the fish model given rather than built from `e.model`, which then
/// only records what it is (a fish model written in Python, `ModelSpec::Python`).
pub fn run_episode_with(
    c: &dyn Controller,
    e: &Evaluation,
    k: usize,
    file: &Path,
    fish: Arc<dyn FishModel>,
) -> Result<EpisodeResult, LearnError> {
    // The lead-to-goal task, whatever the policy was trained for (an OOD policy too).
    let mut cfg = e.env.clone().evaluation();
    let seconds_per_action = cfg.frames_per_action as f32 / cfg.frame_rate_hz;
    cfg.task.evaluation_episode_actions =
        ((e.minutes * 60.0 / seconds_per_action).ceil() as u32).max(1);
    let mut env = TankEnv::new(cfg.clone(), fish)?;
    fishprobe_sim::check_controller_observation(c, &cfg.observation)?;
    fishprobe_sim::check_controller_rate(c, &cfg)?;
    let mut c = c.boxed_clone();
    env.set_start_poses(e.start.clone())?;
    env.set_recording(true);
    let seed = derive_seed(e.seed, "evaluate", k as u64);
    let mut obs = vec![0.0; env.observation_space().dim()];
    env.reset(Some(seed), &mut obs)?;
    let mut rng = stream(seed, "evaluate-actions", 0);
    let mut out = [0.0f32];
    loop {
        let input = ControlInput {
            obs: &obs,
            robot: env.robot().state,
            fish: env.fish(),
            goal: env.active_goal(),
        };
        let action = c.act(&input, &mut rng);
        if !action.is_finite() {
            return Err(LearnError::Policy(format!(
                "{} produced a non-finite turn ({action}) in episode {k} at second {}",
                c.describe(),
                env.summary().actions
            )));
        }
        out[0] = action;
        let step = env
            .step(&out, &mut obs)
            .map_err(|e| LearnError::Run(format!("episode {k}: {e}")))?;
        if step.truncated {
            break;
        }
    }
    let t = env
        .trajectory()
        .ok_or_else(|| LearnError::Run("recording was on".into()))?;
    let meta = TrialMeta {
        kind: TrialKind::Sim,
        policy: c.describe(),
        fish_model: e.model.label(),
        seed,
        goal_radius_cm: cfg.task.goal_radius_cm,
        config_json: serde_json::json!({
            "env": cfg,
            "fish": e.model,
            fishprobe_io::POLICY_SHA256_KEY: c.fingerprint(),
        })
        .to_string(),
        experiment_setup: format!(
            "fishprobe evaluate: {} against {}",
            c.describe(),
            e.model.label()
        ),
    };
    let half = cfg.tank.half_size_cm;
    let trial = TrialFile::from_trajectory(t, env.summary(), &meta, [2.0 * half, 2.0 * half]);
    write_trial(file, &trial)?;
    let s = env.summary();
    let mut prev = 0u32;
    let waits: Vec<f64> = s
        .goal_events
        .iter()
        .map(|g| {
            let w = f64::from(g.frame - prev) / f64::from(cfg.frame_rate_hz);
            prev = g.frame;
            w
        })
        .collect();
    Ok(EpisodeResult {
        episode: k,
        seed,
        goals: s.goal_events.len(),
        mean_time_to_goal_s: (!waits.is_empty())
            .then(|| waits.iter().sum::<f64>() / waits.len() as f64),
        wall_contacts: s.robot_wall_contacts,
        file: file.to_path_buf(),
    })
}

/// The approach assay of SPEC §8 as an evaluation: the robot in a corner (-45, -45) facing the
/// centre, a motionless fish at (-20, 20) and the goal at (20, -20), 30 cm from the walls on
/// either side of it; `episodes` of `minutes`, files `approach_<k>.hdf5` in `out`.
pub fn approach_assay(
    episodes: usize,
    minutes: f32,
    seed: u64,
    out: PathBuf,
) -> Result<Evaluation, LearnError> {
    let mut env = EnvConfig::default();
    env.task.evaluation_goals = [[20.0, -20.0], [20.0, -20.0]];
    Ok(Evaluation {
        model: ModelSpec::by_name("Stationary")?,
        env,
        episodes,
        minutes,
        seed,
        start: Some(StartPoses {
            robot: [-45.0, -45.0, std::f32::consts::FRAC_PI_4],
            fish: vec![[-20.0, 20.0, 0.0]],
        }),
        out,
        prefix: "approach".into(),
    })
}

/// Runs the episodes in parallel; writes the trial files and `summary.csv` into `e.out`.
pub fn evaluate(c: &dyn Controller, e: &Evaluation) -> Result<Vec<EpisodeResult>, LearnError> {
    evaluate_with_model(c, e, None)
}

/// [`evaluate`] with the fish model given (`Some`) rather than built from `e.model` for each
/// episode: a model that only its caller can build (a fish model written in Python). A model
/// without [`FishModel::concurrent_inference`] runs its episodes one after another.
pub fn evaluate_with_model(
    c: &dyn Controller,
    e: &Evaluation,
    fish: Option<Arc<dyn FishModel>>,
) -> Result<Vec<EpisodeResult>, LearnError> {
    let run = |k: usize| {
        let file = e.out.join(format!("{}_{k:03}.hdf5", e.prefix));
        match &fish {
            Some(f) => run_episode_with(c, e, k, &file, f.clone()),
            None => run_episode(c, e, k, &file),
        }
    };
    // A fish behind a lock runs fastest on one thread (`FishModel::concurrent_inference`).
    let results: Result<Vec<EpisodeResult>, LearnError> = match &fish {
        Some(f) if !f.concurrent_inference() => (0..e.episodes).map(run).collect(),
        _ => (0..e.episodes).into_par_iter().map(run).collect(),
    };
    let results = results?;
    let mut csv =
        String::from("episode,seed,goals_reached,mean_time_to_goal_s,wall_contacts,file\n");
    for r in &results {
        csv += &format!(
            "{},{},{},{},{},{}\n",
            r.episode,
            r.seed,
            r.goals,
            r.mean_time_to_goal_s
                .map(|v| format!("{v:.3}"))
                .unwrap_or_default(),
            r.wall_contacts,
            r.file
                .file_name()
                .map(|f| f.to_string_lossy().into_owned())
                .unwrap_or_default()
        );
    }
    fishprobe_io::write_atomically(&e.out.join("summary.csv"), csv.as_bytes())?;
    Ok(results)
}

/// Mean and sample s.d. of goals per episode.
pub fn goals_mean_sd(r: &[EpisodeResult]) -> (f64, f64) {
    let n = r.len() as f64;
    let mean = r.iter().map(|x| x.goals as f64).sum::<f64>() / n;
    let var = r
        .iter()
        .map(|x| (x.goals as f64 - mean).powi(2))
        .sum::<f64>()
        / (n - 1.0).max(1.0);
    (mean, var.sqrt())
}

#[cfg(test)]
mod tests {
    #[test]
    fn an_episode_lasts_from_one_second_to_one_day() {
        use super::minutes_in_range as ok;
        for m in [1.0 / 60.0, 0.016667, 0.0166667, 0.05, 15.0, 1440.0] {
            assert!(ok(m), "{m} minutes refused");
        }
        for m in [
            0.0,
            -1.0,
            1e-40,
            0.0166,
            0.01,
            1440.01,
            1e9,
            f64::NAN,
            f64::INFINITY,
        ] {
            assert!(!ok(m), "{m} minutes accepted");
        }
    }

    use super::*;
    use fishprobe_sim::{FishMind, FishMotion, FishView, SimRng};
    use std::sync::Mutex;
    use std::thread::ThreadId;

    /// M_Follow, answering `false` to `concurrent_inference`, noting the thread of every call.
    #[derive(Debug)]
    struct Locked {
        inner: Arc<dyn FishModel>,
        threads: Mutex<Vec<ThreadId>>,
    }

    impl FishModel for Locked {
        fn name(&self) -> &str {
            "Locked"
        }
        fn concurrent_inference(&self) -> bool {
            false
        }
        fn decide(&self, v: &FishView, i: &[f32], m: &mut FishMind, r: &mut SimRng) -> FishMotion {
            if let Ok(mut t) = self.threads.lock() {
                t.push(std::thread::current().id());
            }
            self.inner.decide(v, i, m, r)
        }
    }

    #[test]
    fn a_fish_behind_a_lock_runs_its_episodes_on_the_callers_thread_with_the_same_goals() {
        let dir = std::env::temp_dir().join(format!("fishprobe-locked-{}", std::process::id()));
        let e = |out: &str| Evaluation {
            model: ModelSpec::by_name("Follow").unwrap(),
            env: EnvConfig::default(),
            episodes: 4,
            minutes: 2.0,
            seed: 7,
            start: None,
            out: dir.join(out),
            prefix: "trial".into(),
        };
        let c = crate::controller("scripted:goal-seeker", false).unwrap();
        let locked = Arc::new(Locked {
            inner: ModelSpec::by_name("Follow").unwrap().build().unwrap(),
            threads: Mutex::new(Vec::new()),
        });
        for out in ["a", "b"] {
            std::fs::create_dir_all(dir.join(out)).unwrap();
        }
        let serial = evaluate_with_model(c.as_ref(), &e("a"), Some(locked.clone())).unwrap();
        let parallel = evaluate(c.as_ref(), &e("b")).unwrap();
        let threads = locked.threads.lock().unwrap();
        assert_eq!(threads.len(), 4 * 120 * 25);
        assert!(threads.iter().all(|t| *t == std::thread::current().id()));
        let goals = |r: &[EpisodeResult]| r.iter().map(|x| x.goals).collect::<Vec<_>>();
        assert!(goals(&serial).iter().sum::<usize>() > 0);
        assert_eq!(goals(&serial), goals(&parallel));
        let _ = std::fs::remove_dir_all(&dir);
    }
}
