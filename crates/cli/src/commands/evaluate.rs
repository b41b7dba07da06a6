//! `fishprobe evaluate`: a trained policy (or the scripted baseline) on the 15-minute
//! evaluation task, one trial file per episode.

use anyhow::{bail, Result};
use clap::Args;
use fishprobe_learn::evaluate::MAX_EPISODES;
use fishprobe_learn::{evaluate, goals_mean_sd, Evaluation};
use std::path::PathBuf;

use super::config::SimSettings;
use super::emit;

#[derive(Debug, Args)]
pub struct EvaluateArgs {
    /// A policy directory from `fishprobe train`, `onnx:FILE` (a policy trained elsewhere, e.g.
    /// Stable-Baselines3; docs/onnx-models.md), or a scripted baseline: `scripted:goal-seeker`
    /// (turns toward the active goal every second, ignoring the fish) or
    /// `scripted:fetch-and-lead` (goes to the fish, then keeps 15 cm ahead of it on its line
    /// to the goal), or the random robot `scripted:random` (turns by a uniform random angle
    /// every second: what a robot does by chance).
    #[arg(long)]
    policy: String,
    /// Fish model to evaluate against.
    #[arg(long)]
    model: String,
    /// Episodes.
    #[arg(long, default_value_t = 18)]
    episodes: usize,
    /// Minutes per episode (paper: 15).
    #[arg(long, default_value_t = 15.0)]
    minutes: f32,
    /// Output directory: `trial_<k>.hdf5` per episode and `summary.csv`.
    #[arg(long)]
    out: PathBuf,
    /// Sample actions instead of taking the policy's mean.
    #[arg(long)]
    stochastic: bool,
    /// Master seed of the episodes.
    #[arg(long, default_value_t = 0)]
    seed: u64,
    /// Settings file for the environment and the fish (see `fishprobe config show`); a fish it
    /// describes keeps its parameters when --model names the same model.
    #[arg(long)]
    settings: Option<PathBuf>,
    /// Threads (default: all cores).
    #[arg(long)]
    jobs: Option<usize>,
}

pub fn run(a: EvaluateArgs) -> Result<()> {
    if a.episodes == 0 || a.episodes > MAX_EPISODES {
        bail!(
            "--episodes must lie in [1, {MAX_EPISODES}], got {}",
            a.episodes
        );
    }
    super::check_minutes("--minutes", a.minutes)?;
    let mut settings = match &a.settings {
        Some(p) => SimSettings::load(p)?,
        None => SimSettings::default(),
    };
    settings.apply_model_flag(&a.model)?;
    let c = super::policy_controller(&a.policy, a.stochastic)?;
    let e = Evaluation {
        model: settings.fish,
        env: settings.env,
        episodes: a.episodes,
        minutes: a.minutes,
        seed: a.seed,
        start: None,
        out: a.out.clone(),
        prefix: "trial".into(),
    };
    let _lock = super::lock_out(&a.out, "evaluate")?;
    fishprobe_learn::evaluate::check_fresh_output(&a.out, &e.prefix)?;
    let results = super::with_jobs(a.jobs, || evaluate(c.as_ref(), &e))??;
    let (mean, sd) = goals_mean_sd(&results);
    emit(&format!(
        "{} against {}: {:.1} ± {:.1} goals per {} min over {} episodes (mean ± s.d.); trial files and summary.csv in {}\n",
        c.name(),
        a.model,
        mean,
        sd,
        a.minutes,
        results.len(),
        a.out.display()
    ))
}
