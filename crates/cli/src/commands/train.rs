//! `fishprobe train`: a PPO robot policy against one fish model.

use anyhow::{bail, Context, Result};
use clap::Args;
use fishprobe_learn::run::{train_to_end, Begin, Opened, TrainHooks};
use fishprobe_learn::yardstick::{self, OodYardstickConfig};
use fishprobe_learn::{IterationStats, LearnError, PpoConfig, RunSpec, Trainer};
use fishprobe_sim::FishModel;
use fishprobe_sim::Objective;
use indicatif::{ProgressBar, ProgressStyle};
use std::path::{Path, PathBuf};
use std::sync::Arc;

use super::config::SimSettings;
use super::emit;

#[derive(Debug, Args)]
pub struct TrainArgs {
    /// Fish model to train against (Follow, Zone, Force, ...). Replaces the settings file's
    /// fish unless it names the same model, whose parameters from the file are then kept.
    #[arg(long)]
    model: Option<String>,
    /// Master seed.
    #[arg(long, default_value_t = 0)]
    seed: u64,
    /// Run directory (params.json, progress.csv, result.json, checkpoints/, policy.safetensors).
    #[arg(long)]
    out: PathBuf,
    /// `paper` (the published settings with sixteen times the steps at 2 epochs per batch
    /// instead of 100, a discount of 0.99 instead of 0.9453, the policy's log-s.d. bounded at
    /// 0; an expensive fish's policy, e.g. M_ConvNet's, 832,300 steps at 10 epochs: see
    /// docs/validation.md, "Departures from the paper" and "The `paper` preset's discount and
    /// budget"), `published` (exactly the published settings, 100 epochs, γ = 0.9453, RLlib's
    /// unbounded log-s.d.),
    /// `quick` (200,000 steps at 10 epochs) or `smoke` (a few thousand steps of a small
    /// network).
    #[arg(long, default_value = "paper")]
    preset: String,
    /// Override the number of environment steps. With --resume: raise the run's budget to
    /// this many, so that a finished run trains on (it then ends where a run of this many
    /// steps from the start ends; a lower budget is refused).
    #[arg(long)]
    steps: Option<u64>,
    /// Continue the run in --out from its last checkpoint (with --steps, past its budget).
    #[arg(long)]
    resume: bool,
    /// Settings file for the environment and fish (see `fishprobe config show`).
    #[arg(long)]
    settings: Option<PathBuf>,
    /// PPO settings (.json or .toml) overriding the preset's, field by field (names as in
    /// params.json's `ppo`, e.g. `num_sgd_iter = 10`).
    #[arg(long)]
    ppo: Option<PathBuf>,
    /// What the robot is rewarded for: `goal` (lead the fish to goals, the paper's task) or
    /// `ood` (drive the fish's views out of its model's training support; needs a
    /// data-driven model and its support file). Default: the settings file's
    /// `env.task.objective` (goal).
    #[arg(long, value_parser = ["goal", "ood"])]
    task: Option<String>,
    /// With `--task ood`: weight of the goal reward added to the OOD reward (0 to 10;
    /// default 0, or the settings file's `env.task.ood_goal_weight`).
    #[arg(long)]
    ood_goal_weight: Option<f32>,
    /// With `--task ood`: reward the time beyond this lead-to-goal policy's 95th-percentile
    /// score, in the run's `ood_score` (support or disagreement; a training directory,
    /// `onnx:FILE` or `scripted:NAME`). Before training,
    /// the policy runs `ood-report`'s default episodes against the fish (trial files in
    /// OUT/yardstick/); its percentile becomes the reward's floor, floor + band its cap and
    /// 1 / band its weight (replacing the settings file's `ood_score_floor`, `ood_score_cap`
    /// and `ood_weight`; what was measured: OUT/yardstick.json). docs/guide/ood.md.
    #[arg(long, value_name = "POLICY")]
    ood_yardstick: Option<String>,
    /// With `--ood-yardstick`: the percentile, in (0, 1) (default 0.95: at least as far out as
    /// the 95th percentile of a lead-to-goal policy's scores).
    #[arg(long, requires = "ood_yardstick")]
    ood_yardstick_quantile: Option<f64>,
    /// With `--ood-yardstick`: width of the reward's ramp above the yardstick, in [0.01, 10]
    /// (default 0.15).
    #[arg(long, requires = "ood_yardstick")]
    ood_yardstick_band: Option<f32>,
    /// With `--ood-yardstick`: episodes of the yardstick policy (default 6, `ood-report`'s).
    #[arg(long, requires = "ood_yardstick")]
    ood_yardstick_episodes: Option<usize>,
    /// With `--ood-yardstick`: minutes per episode (default 5, `ood-report`'s).
    #[arg(long, requires = "ood_yardstick")]
    ood_yardstick_minutes: Option<f32>,
    /// Threads (default: all cores). Results do not depend on it.
    #[arg(long)]
    jobs: Option<usize>,
}

/// A new run, checked as far as it can be before its directory exists.
struct Fresh {
    spec: RunSpec,
    model: Arc<dyn FishModel>,
    /// The yardstick policy and how to measure it (`--ood-yardstick`).
    yardstick: Option<Yardstick>,
}

/// A yardstick policy and how to measure it.
type Yardstick = (String, OodYardstickConfig);

/// The new run the flags ask for: settings, model, task, PPO, all checked and the fish built,
/// so that a refused `train` refuses before it creates (and locks) its run directory.
fn fresh_run(a: &TrainArgs) -> Result<Fresh> {
    if PpoConfig::preset(&a.preset).is_none() {
        bail!(
            "unknown --preset `{}`: use paper, published, quick or smoke",
            a.preset
        );
    }
    let mut settings = match &a.settings {
        Some(p) => SimSettings::load(p)?,
        None => SimSettings::default(),
    };
    match &a.model {
        Some(m) => settings.apply_model_flag(m)?,
        None if a.settings.is_none() => {
            bail!("--model is required (or a --settings file naming the fish)")
        }
        None => {}
    }
    if let Some(t) = &a.task {
        settings.env.task.objective = match t.as_str() {
            "ood" => Objective::Ood,
            _ => Objective::Goal,
        };
    }
    if let Some(w) = a.ood_goal_weight {
        if settings.env.task.objective != Objective::Ood {
            bail!("--ood-goal-weight applies to --task ood only");
        }
        settings.env.task.ood_goal_weight = w;
    }
    let yardstick = match &a.ood_yardstick {
        None => None,
        Some(_) if settings.env.task.objective != Objective::Ood => {
            bail!("--ood-yardstick applies to --task ood only")
        }
        Some(policy) => {
            let d = OodYardstickConfig::default();
            let config = OodYardstickConfig {
                quantile: a.ood_yardstick_quantile.unwrap_or(d.quantile),
                band: a.ood_yardstick_band.unwrap_or(d.band),
                episodes: a.ood_yardstick_episodes.unwrap_or(d.episodes),
                minutes: a.ood_yardstick_minutes.unwrap_or(d.minutes),
                ..d
            };
            yardstick::check(policy, &config, &settings.env)?;
            Some((policy.clone(), config))
        }
    };
    settings
        .env
        .validate()
        .context("the environment settings")?;
    // The preset for this fish (the `paper` preset trains an expensive fish's policy at the
    // published budget), then the overrides.
    let mut ppo =
        PpoConfig::preset_for(&a.preset, settings.fish.is_expensive()).context("preset checked")?;
    if let Some(p) = &a.ppo {
        ppo = ppo_overrides(ppo, p)?;
    }
    if let Some(s) = a.steps {
        ppo.total_timesteps = s;
    }
    ppo.validate().context("the PPO settings")?;
    let spec = RunSpec::new(
        settings.fish,
        ppo,
        settings.env,
        a.seed,
        a.preset.clone(),
        super::BUILD,
    );
    // The OOD reward needs the model's support: a missing or foreign file is refused here.
    spec.check()
        .with_context(|| format!("the run against fish model {}", spec.model.label()))?;
    let model = spec
        .model
        .build()
        .with_context(|| format!("building fish model {}", spec.model.label()))?;
    Ok(Fresh {
        spec,
        model,
        yardstick,
    })
}

pub fn run(a: TrainArgs) -> Result<()> {
    let resuming =
        |a: &TrainArgs| a.resume && fishprobe_learn::run::RunLayout::new(&a.out).holds_run();
    // A new run is checked before its directory is created: a refused `train` leaves none.
    // A `--resume` into an existing directory takes the lock first: the directory's holder
    // may not have written params.json yet, and the refusal must name the holder, not the
    // flags a fresh run would need.
    let mut fresh = if resuming(&a) || (a.resume && a.out.is_dir()) {
        None
    } else {
        Some(fresh_run(&a)?)
    };
    // One writer per run directory: a second `train` (or a `--resume`) into it is refused.
    let _lock = super::lock_out(&a.out, "train")?;
    let mut hooks = Progress {
        args: &a,
        fresh: None,
        bar: None,
    };
    let begin = if resuming(&a) {
        if a.model.is_some()
            || a.settings.is_some()
            || a.ppo.is_some()
            || a.task.is_some()
            || a.ood_goal_weight.is_some()
            || a.ood_yardstick.is_some()
        {
            say!("note: --resume continues the run as params.json records it; --model, --settings, --ppo, --task, --ood-goal-weight and --ood-yardstick are ignored");
        }
        if let Some(steps) = a.steps {
            let had = Trainer::raise_budget(&a.out, steps)
                .with_context(|| format!("raising the budget of {}", a.out.display()))?;
            if had != steps {
                say!("raising the run's budget from {had} to {steps} steps (params.json)");
            }
        }
        Begin::Resume
    } else {
        // (Checked above unless the run's params.json vanished since.)
        let f = match fresh.take() {
            Some(f) => f,
            None => fresh_run(&a)?,
        };
        hooks.fresh = Some((f.model, f.yardstick));
        Begin::Start(f.spec, "add --resume to continue it")
    };
    let trained = super::with_jobs(a.jobs, || {
        train_to_end(&a.out, begin, super::BUILD, &mut hooks)
    })?;
    if let Some(bar) = &hooks.bar {
        bar.finish_and_clear();
    }
    let (trainer, path) = trained.with_context(|| format!("training in {}", a.out.display()))?;
    emit(&format!(
        "trained {} policy for {} steps ({} iterations): {}\n",
        trainer.spec().model.label(),
        trainer.timesteps(),
        trainer.iteration(),
        path.display()
    ))
}

/// What `train` adds to training: a new run's fish and yardstick, notes on a resumed run,
/// and the progress bar (a line per iteration without a terminal).
struct Progress<'a> {
    args: &'a TrainArgs,
    /// A new run's fish model and yardstick.
    fresh: Option<(Arc<dyn FishModel>, Option<Yardstick>)>,
    bar: Option<ProgressBar>,
}

impl TrainHooks for Progress<'_> {
    /// Measures the yardstick, if any, then writes the run's files.
    fn create(&mut self, dir: &Path, spec: RunSpec) -> Result<Trainer, LearnError> {
        let (model, yardstick) = match self.fresh.take() {
            Some(f) => f,
            None => (spec.model.build()?, None),
        };
        let yardstick = yardstick.as_ref().map(|(p, c)| (p.as_str(), c));
        if let Some((policy, config)) = yardstick {
            Trainer::ensure_new(dir)?;
            say!(
                "yardstick: running {} episodes of {policy} ...",
                config.episodes
            );
        }
        let (trainer, measured) = yardstick::start_run(dir, spec, model, yardstick)?;
        if let Some(y) = &measured {
            let task = &trainer.spec().env.task;
            say!(
                "yardstick: {}'s {}th-percentile {} score is {:.3}; the reward counts views from it (floor {:.3}, cap {:.3}, weight {:.2})",
                y.policy,
                (100.0 * y.config.quantile).round(),
                match y.ood_score {
                    fishprobe_sim::OodScore::Support => "support",
                    fishprobe_sim::OodScore::Disagreement => "disagreement",
                },
                y.score,
                task.ood_score_floor,
                y.cap,
                y.weight
            );
        }
        Ok(trainer)
    }

    fn opened(&mut self, t: &Trainer, how: &Opened) -> Result<(), LearnError> {
        if *how == Opened::Resumed {
            let a = self.args;
            // The seed and the preset have defaults, so they are always "given": say only
            // when the run's own differ from them.
            let (seed, preset) = (t.spec().seed, &t.spec().preset);
            if seed != a.seed || *preset != a.preset {
                say!(
                    "note: resuming with the run's own seed {seed} and preset `{preset}` (params.json), \
                     not --seed {} --preset {}",
                    a.seed,
                    a.preset
                );
            }
            // Another build of the same trainer revision continues the run (the revision is
            // what decides whether earlier updates are still right); say so, for the record.
            let build = &t.spec().program_build;
            if build != super::BUILD {
                say!(
                    "note: the run was started by fishprobe {}; continuing it with {} (same \
                     trainer revision, {})",
                    if build.is_empty() {
                        "(build not recorded)"
                    } else {
                        build
                    },
                    super::BUILD,
                    fishprobe_learn::TRAINER_REVISION
                );
            }
        }
        let total = t.spec().ppo.total_timesteps;
        let bar = ProgressBar::new(total);
        bar.set_style(
            ProgressStyle::with_template(
                "{spinner} [{elapsed_precise}] {bar:30} {pos}/{len} steps  {msg}  ETA {eta}",
            )
            .unwrap_or_else(|_| ProgressStyle::default_bar()),
        );
        bar.set_position(t.timesteps().min(total));
        self.bar = Some(bar);
        Ok(())
    }

    fn iterated(&mut self, t: &Trainer, s: &IterationStats) -> Result<(), LearnError> {
        let Some(bar) = &self.bar else { return Ok(()) };
        let total = t.spec().ppo.total_timesteps;
        bar.set_position(s.timesteps.min(total));
        bar.set_message(format!(
            "it {} | {} episodes | return {:.2} | goals/ep {:.2} | {:.0} steps/s",
            s.iteration,
            s.episodes_total,
            s.episode_return_mean,
            s.goals_per_episode,
            s.steps_per_s
        ));
        if !bar.is_hidden() {
            return Ok(());
        }
        // Without a terminal (CI, logs), a line per iteration instead of the bar.
        say!(
            "iteration {} steps {} return {:.3} goals/episode {:.3} kl {:.4} {:.0} steps/s",
            s.iteration,
            s.timesteps,
            s.episode_return_mean,
            s.goals_per_episode,
            s.kl,
            s.steps_per_s
        );
        Ok(())
    }
}

/// `base` with the fields that the file at `path` sets replaced; unknown fields and values out
/// of range are errors naming the file.
pub fn ppo_overrides(base: PpoConfig, path: &std::path::Path) -> Result<PpoConfig> {
    let text = fishprobe_io::read_small_text(path)
        .with_context(|| format!("cannot read PPO settings file {}", path.display()))?;
    let is_toml = path
        .extension()
        .is_some_and(|e| e.eq_ignore_ascii_case("toml"));
    let over: serde_json::Value = if is_toml {
        let table: toml::Table = super::parse_toml(&text)
            .with_context(|| format!("{} is not valid PPO settings TOML", path.display()))?;
        // Converted to JSON, TOML's inf and nan both become null; only inf lifts the bound.
        if let Some(toml::Value::Float(f)) = table.get("log_std_max") {
            if f.is_nan() {
                bail!(
                    "in PPO settings file {}, field `log_std_max`: nan is not a bound (inf: none)",
                    path.display()
                );
            }
        }
        serde_json::to_value(table)?
    } else {
        serde_json::from_str(&text)
            .with_context(|| format!("{} is not valid PPO settings JSON", path.display()))?
    };
    let serde_json::Value::Object(over) = over else {
        bail!("{}: PPO settings must be a table of fields", path.display());
    };
    let base = serde_json::to_value(&base)?;
    let with = |fields: &mut dyn Iterator<Item = (&String, &serde_json::Value)>| {
        let mut merged = base.clone();
        if let serde_json::Value::Object(m) = &mut merged {
            m.extend(fields.map(|(k, v)| (k.clone(), v.clone())));
        }
        serde_json::from_value::<PpoConfig>(merged)
    };
    // serde names unknown fields but not the field of a wrong value: try them one by one.
    for (k, v) in &over {
        // TOML's nan and inf arrive here as null (JSON has no such numbers). Only the log-s.d.
        // bound takes null (JSON) or inf (TOML): no bound.
        if v.is_null() && k != "log_std_max" {
            bail!(
                "in PPO settings file {}, field `{k}`: not a finite number",
                path.display()
            );
        }
        with(&mut std::iter::once((k, v)))
            .with_context(|| format!("in PPO settings file {}, field `{k}`", path.display()))?;
    }
    let ppo = with(&mut over.iter())
        .with_context(|| format!("in PPO settings file {}", path.display()))?;
    ppo.validate()
        .with_context(|| format!("in PPO settings file {}", path.display()))?;
    Ok(ppo)
}
