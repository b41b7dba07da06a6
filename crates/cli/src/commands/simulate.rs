//! `fishprobe simulate`: one evaluation-task trial with a scripted robot, written as a trial
//! file.

use anyhow::{bail, Context, Result};
use clap::Args;
use fishprobe_io::{write_trial, TrialFile, TrialKind, TrialMeta};
use fishprobe_sim::{Env, RobotScript, ScriptParams, TankEnv, TaskMode};
use serde_json::json;
use std::path::PathBuf;

use super::config::SimSettings;
use super::emit;

#[derive(Debug, Args)]
pub struct SimulateArgs {
    /// Fish model (Follow, Zone, Force, ConvNet, Stationary, Guppy). Replaces the settings
    /// file's fish unless it names the same model, whose parameters from the file are kept.
    #[arg(long)]
    model: Option<String>,
    /// Scripted robot: `still` (stands where it starts), `circle` (drives a 30 cm circle
    /// around the centre) or `goals` (drives to the active goal and waits until the fish
    /// reaches it); or `policy:DIR` (a trained policy's mean action) or `policy:onnx:FILE`
    /// (an ONNX policy, docs/onnx-models.md).
    #[arg(long, default_value = "goals")]
    robot: String,
    /// Trial length in minutes (paper: 15).
    #[arg(long, default_value_t = 15.0)]
    minutes: f32,
    /// Master seed (start poses, fish noise).
    #[arg(long, default_value_t = 0)]
    seed: u64,
    /// Settings file (see `fishprobe config show`); defaults to the paper's settings.
    #[arg(long)]
    settings: Option<PathBuf>,
    /// The trial file to write.
    #[arg(long)]
    out: PathBuf,
}

pub fn run(a: SimulateArgs) -> Result<()> {
    let mut settings = match &a.settings {
        Some(p) => SimSettings::load(p)?,
        None => SimSettings::default(),
    };
    if let Some(m) = &a.model {
        settings.apply_model_flag(m)?;
    }
    super::check_minutes("--minutes", a.minutes)?;
    if let Some(dir) = a.robot.strip_prefix("policy:") {
        return simulate_policy(dir, &settings, &a);
    }
    let Some(script) = RobotScript::parse(&a.robot) else {
        bail!(
            "unknown --robot `{}`: use still, circle, goals, policy:DIR or policy:onnx:FILE",
            a.robot
        );
    };
    let script_params = ScriptParams::default();
    let mut env_cfg = settings.env.clone();
    env_cfg.mode = TaskMode::Evaluation;
    let seconds_per_action = env_cfg.frames_per_action as f32 / env_cfg.frame_rate_hz;
    let actions = (a.minutes * 60.0 / seconds_per_action).ceil() as u32;
    env_cfg.task.evaluation_episode_actions = actions.max(1);

    let model = settings.fish.build()?;
    let mut env = TankEnv::new(env_cfg.clone(), model).context("building the environment")?;
    env.set_recording(true);
    let mut obs = vec![0.0; fishprobe_sim::Env::observation_space(&env).dim()];
    env.reset(Some(a.seed), &mut obs)?;
    for _ in 0..env_cfg.task.evaluation_episode_actions {
        env.step_scripted(script, &script_params, &mut obs)?;
    }
    let trajectory = env.trajectory().context("recording was switched on")?;
    let config_json = serde_json::to_string(&json!({
        "env": env_cfg,
        "fish": settings.fish,
        "robot_script": script,
        "script": script_params,
    }))?;
    let meta = TrialMeta {
        kind: TrialKind::Sim,
        policy: format!("scripted:{}", script.name()),
        fish_model: settings.fish.label(),
        seed: a.seed,
        goal_radius_cm: env_cfg.task.goal_radius_cm,
        config_json,
        experiment_setup: format!(
            "fishprobe simulate: {} fish, scripted robot `{}`, {} min, seed {}",
            settings.fish.label(),
            script.name(),
            a.minutes,
            a.seed
        ),
    };
    let half = env_cfg.tank.half_size_cm;
    let trial =
        TrialFile::from_trajectory(trajectory, env.summary(), &meta, [2.0 * half, 2.0 * half]);
    write_trial(&a.out, &trial)?;
    let s = env.summary();
    emit(&format!(
        "{}: {} frames ({:.1} min) of {} fish with the `{}` robot; {} goals reached, {} fish wall contacts\n",
        a.out.display(),
        trajectory.robot.len(),
        trial.duration_s() / 60.0,
        settings.fish.label(),
        script.name(),
        s.goal_events.len(),
        s.fish_wall_contacts
    ))
}

/// One evaluation episode driven by a trained policy (its mean action).
fn simulate_policy(dir: &str, settings: &SimSettings, a: &SimulateArgs) -> Result<()> {
    let c =
        fishprobe_learn::controller(dir, false).with_context(|| format!("loading policy {dir}"))?;
    let e = fishprobe_learn::Evaluation {
        model: settings.fish.clone(),
        env: settings.env.clone(),
        episodes: 1,
        minutes: a.minutes,
        seed: a.seed,
        start: None,
        out: a.out.parent().map(PathBuf::from).unwrap_or_default(),
        prefix: String::new(),
    };
    let r = fishprobe_learn::run_episode(c.as_ref(), &e, 0, &a.out)?;
    emit(&format!(
        "{}: {:.1} min of {} fish with policy {}; {} goals reached\n",
        a.out.display(),
        a.minutes,
        settings.fish.label(),
        c.name(),
        r.goals
    ))
}
