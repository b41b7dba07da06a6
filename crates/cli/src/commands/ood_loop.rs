//! `fishprobe ood-loop`: the OOD idea tested in silico with a known truth (issue 23, item 4).
//!
//! The virtual guppy plays the real fish. Per seed: record it with a robot in a narrow set of
//! situations (a scripted robot shuttling between two goals); fit M_ConvNet on that (with its
//! support); train an OOD policy and a lead-to-goal policy against that model with the same
//! budget; record the virtual guppy under each policy (the same episodes and minutes); refit
//! M_ConvNet on the narrow data plus each policy's data; and measure each model's sim-to-real
//! gap to the virtual guppy with a probe neither policy is (the nine metrics' Wasserstein
//! distances in units of the guppy's spread, and the goals a scripted fetch-and-lead robot
//! reaches; the same with further probes, `more_gap_probes`). With `rounds` > 1 each chain
//! trains, records and refits again against its own model (iterative retraining). The
//! virtual guppy is recorded in-process, by the same simulation the virtual lab (`fishprobe
//! lab`) serves over the bridge: the bridge adds transport, not behaviour.
//!
//! Every stage leaves its files in the output directory and is skipped when they are there, so
//! an interrupted loop resumes.

use anyhow::{bail, Context, Result};
use clap::Args;
use fishprobe_analysis::ood::{metric_gap, pooled_metrics, quantile, score_trials, share_at_least};
use fishprobe_analysis::{load_trial, AnalysisConfig};
use fishprobe_learn::bc::{fit_convnet, CloneConfig, FitProgress};
use fishprobe_learn::{Evaluation, PpoConfig, RunSpec, Trainer};
use fishprobe_models::ModelSpec;
use fishprobe_sim::params::check;
use fishprobe_sim::{EnvConfig, Objective, OodScore};
use std::path::{Path, PathBuf};

use super::emit;

fishprobe_sim::documented_params! {
    /// The closed loop's budget and design (defaults: the run in docs/validation.md).
    pub struct OodLoopConfig {
        /// The robot of the narrow recordings (choice: the goal-seeker, which shuttles between
        /// the two evaluation goals and ignores the fish, so the data holds a robot on one
        /// diagonal and a fish that comes and goes).
        pub narrow_controller: String = "scripted:goal-seeker".into(); "-",
        /// Narrow episodes the first model is fitted on (choice: 12).
        pub narrow_episodes: usize = 12; "episodes",
        /// Held-out narrow episodes for early stopping of every fit (choice: 3).
        pub validation_episodes: usize = 3; "episodes",
        /// Episodes recorded under each policy and added to the data (choice: 6: half the
        /// narrow data again).
        pub new_episodes: usize = 6; "episodes",
        /// Rounds of policy training, recording and refitting (choice: 1, the loop).
        /// In round k > 1 each chain trains a new policy against its own model of round k - 1
        /// (the OOD chain against the model refitted with OOD data, the lead-to-goal chain
        /// against its own), records `new_episodes` more and refits on the narrow data plus
        /// all its chain's recordings: the paper's "iterative model and policy retraining".
        /// The gaps are those of each chain's last model.
        pub rounds: usize = 1; "rounds",
        /// Minutes per recorded episode (choice: 3).
        pub episode_minutes: f32 = 3.0; "min",
        /// PPO preset of both policies (choice: `quick`).
        pub ppo_preset: String = "quick".into(); "-",
        /// Environment steps of each policy (choice: 200,000, the quick preset's).
        pub train_steps: u64 = 200_000; "steps",
        /// Most epochs of each M_ConvNet fit (choice: 15).
        pub fit_max_epochs: usize = 15; "epochs",
        /// The probe that measures each model's gap (choice: `scripted:fetch-and-lead`,
        /// which neither policy is and which interacts with the fish closely).
        pub gap_probe: String = "scripted:fetch-and-lead".into(); "-",
        /// Further probes whose gaps are measured the same way and reported beside the first
        /// (choice: the goal-seeker, whose situations the narrow data holds, and the random
        /// robot, whose situations no policy chose: data where a model is least supported
        /// need not be where one probe looks). The verdict of `loop.md` is given per probe
        /// and over all of them.
        pub more_gap_probes: Vec<String> = vec!["scripted:goal-seeker".into(), "scripted:random".into()]; "-",
        /// Gap episodes per model and for the virtual guppy (choice: 6).
        pub gap_episodes: usize = 6; "episodes",
        /// Minutes per gap episode (choice: 5).
        pub gap_minutes: f32 = 5.0; "min",
        /// Partner range of every fitted model's support (`support.partner_range_cm`; choice:
        /// 0, every partner counts, as the shipped support; 15 makes the OOD policy seek
        /// close interactions, docs/validation.md, "A partner range for the support").
        pub support_partner_range_cm: f32 = 0.0; "cm",
        /// What the OOD policy is rewarded by (`task.ood_score`): `support` (choice: the rarity
        /// of the fish's views in the model's training data) or `disagreement` (how much an
        /// ensemble of `ensemble_members` fits of the model disagrees on them; every model
        /// the OOD chain trains against is then fitted as an ensemble). The share of the OOD
        /// policy's views beyond the lead-to-goal policy's p95 is measured in support scores
        /// either way.
        pub ood_score: OodScore = OodScore::Support; "-",
        /// Networks of each ensemble with `ood_score = "disagreement"`, in [2, 16] (choice: 4:
        /// enough for a stable disagreement, each member one more fit).
        pub ensemble_members: usize = 4; "networks",
    }
}

impl OodLoopConfig {
    fn validate(&self) -> Result<()> {
        for (f, v, hi) in [
            ("narrow_episodes", self.narrow_episodes, 1000),
            ("validation_episodes", self.validation_episodes, 1000),
            ("new_episodes", self.new_episodes, 1000),
            ("rounds", self.rounds, 20),
            ("gap_episodes", self.gap_episodes, 1000),
            ("fit_max_epochs", self.fit_max_epochs, 1000),
        ] {
            if !(1..=hi).contains(&v) {
                bail!("ood-loop setting `{f}` = {v}: must lie in [1, {hi}]");
            }
        }
        if !(1..=1_000_000_000).contains(&self.train_steps) {
            bail!(
                "ood-loop setting `train_steps` = {}: must lie in [1, 1e9]",
                self.train_steps
            );
        }
        super::check_minutes("episode_minutes", self.episode_minutes)?;
        super::check_minutes("gap_minutes", self.gap_minutes)?;
        check::non_negative(
            "",
            "support_partner_range_cm",
            self.support_partner_range_cm,
        )
        .context("ood-loop settings")?;
        if !(2..=fishprobe_models::disagreement::MAX_MEMBERS).contains(&self.ensemble_members) {
            bail!(
                "ood-loop setting `ensemble_members` = {}: must lie in [2, {}]",
                self.ensemble_members,
                fishprobe_models::disagreement::MAX_MEMBERS
            );
        }
        if self.more_gap_probes.len() > 8 {
            bail!(
                "ood-loop setting `more_gap_probes`: at most 8 probes, got {}",
                self.more_gap_probes.len()
            );
        }
        let mut dirs = vec![probe_dir_name(&self.gap_probe)];
        for p in &self.more_gap_probes {
            let d = probe_dir_name(p);
            if dirs.contains(&d) {
                bail!(
                    "ood-loop setting `more_gap_probes`: `{p}` is listed twice (or as `gap_probe`)"
                );
            }
            dirs.push(d);
        }
        for p in std::iter::once(&self.gap_probe).chain(&self.more_gap_probes) {
            fishprobe_learn::controller(p, false)
                .with_context(|| format!("ood-loop settings: gap probe `{p}`"))?;
        }
        if PpoConfig::preset(&self.ppo_preset).is_none() {
            bail!(
                "ood-loop setting `ppo_preset` = {}: not a preset",
                self.ppo_preset
            );
        }
        Ok(())
    }
}

#[derive(Debug, Args)]
pub struct OodLoopArgs {
    /// Output directory (one subdirectory per seed; loop.json and loop.md at the end).
    #[arg(long)]
    out: PathBuf,
    /// Seeds (each a whole loop).
    #[arg(long, num_args = 1.., default_values_t = [0u64, 1, 2])]
    seeds: Vec<u64>,
    /// Settings (TOML, the fields of OodLoopConfig).
    #[arg(long)]
    config: Option<PathBuf>,
}

/// One model's gap to the virtual guppy.
#[derive(Debug, Clone, Copy, serde::Serialize, serde::Deserialize)]
struct Gap {
    /// Mean over the nine metrics of W1(model, guppy) / s.d.(guppy).
    metrics: f64,
    /// |goals(model) - goals(guppy)| / goals(guppy), goals per episode of the probe.
    goals: f64,
    /// Goals per episode of the probe against the model.
    goals_per_episode: f64,
}

/// The gaps one further probe measured (`more_gap_probes`).
#[derive(Debug, Clone, serde::Serialize, serde::Deserialize)]
struct ProbeGaps {
    probe: String,
    guppy_goals_per_episode: f64,
    narrow: Gap,
    after_goal_data: Gap,
    after_ood_data: Gap,
}

/// The directory of a further probe's gap trials under `gap/`: `probe-` and its name with
/// every character but letters, digits and `-` made a `-` (so a policy directory's path makes
/// a name too, and none is the first probe's `guppy`, `narrow`, ...).
fn probe_dir_name(probe: &str) -> String {
    let s: String = probe
        .chars()
        .take(80)
        .map(|c| {
            if c.is_ascii_alphanumeric() || c == '-' {
                c
            } else {
                '-'
            }
        })
        .collect();
    format!("probe-{s}")
}

/// One seed's outcome.
#[derive(Debug, Clone, serde::Serialize, serde::Deserialize)]
struct SeedResult {
    seed: u64,
    guppy_goals_per_episode: f64,
    narrow: Gap,
    after_goal_data: Gap,
    after_ood_data: Gap,
    /// Share of the guppy's views under the OOD policy at or beyond the lead-to-goal
    /// policy's 95th-percentile support score (narrow model's support).
    ood_share_beyond_goal_p95: f64,
    /// From the second round on (`rounds` > 1): the same share, each round's policies scored
    /// under the support of the model the OOD policy was trained against.
    #[serde(default)]
    later_rounds_ood_share: Vec<f64>,
    /// Goals per episode of each policy with the guppy.
    ood_policy_goals: f64,
    goal_policy_goals: f64,
    /// The further probes' gaps (absent in loops recorded before them).
    #[serde(default)]
    more_probes: Vec<ProbeGaps>,
}

fn trial_files(dir: &Path) -> Vec<PathBuf> {
    fishprobe_io::trial_files(dir)
}

/// Records `episodes` of `controller` with `model` into `dir` (skipped when done).
fn record(
    controller: &str,
    model: &ModelSpec,
    episodes: usize,
    minutes: f32,
    seed: u64,
    dir: &Path,
) -> Result<(Vec<PathBuf>, f64)> {
    let c = fishprobe_learn::controller(controller, false)
        .with_context(|| format!("loading {controller}"))?;
    let done = dir.join("summary.csv").exists();
    let e = Evaluation {
        model: model.clone(),
        env: EnvConfig::default(),
        episodes,
        minutes,
        seed,
        start: None,
        out: dir.to_path_buf(),
        prefix: "trial".into(),
    };
    if !done {
        std::fs::create_dir_all(dir).with_context(|| format!("creating {}", dir.display()))?;
        fishprobe_learn::evaluate(c.as_ref(), &e)?;
    }
    let files = trial_files(dir);
    let cfg = AnalysisConfig::default();
    let goals: Vec<f64> = files
        .iter()
        .map(|f| load_trial(f, &cfg, false).map(|t| f64::from(t.goals_reached)))
        .collect::<Result<_, _>>()
        .map_err(anyhow::Error::msg)?;
    Ok((files, goals.iter().sum::<f64>() / goals.len().max(1) as f64))
}

/// Fits M_ConvNet on `data` into `dir/convnet.safetensors` (skipped when done), as an
/// ensemble when an OOD policy will be trained against it with `ood_score = "disagreement"`.
fn fit(
    data: &[PathBuf],
    validation: &Path,
    dir: &Path,
    loop_cfg: &OodLoopConfig,
    seed: u64,
    ood_target: bool,
) -> Result<ModelSpec> {
    let weights = dir.join("convnet.safetensors");
    let ensemble = ood_target && loop_cfg.ood_score == OodScore::Disagreement;
    // The support is written after the weights, the disagreement file after the members.
    let done = fishprobe_learn::bc::support_beside(&weights).exists()
        && (!ensemble || fishprobe_models::disagreement::file_beside(&weights).exists());
    if !done {
        std::fs::create_dir_all(dir)?;
        let cfg = CloneConfig {
            robot_as_partner: true,
            max_epochs: loop_cfg.fit_max_epochs,
            support_partner_range_cm: loop_cfg.support_partner_range_cm,
            ensemble_members: if ensemble {
                loop_cfg.ensemble_members
            } else {
                1
            },
            ..CloneConfig::default()
        };
        let quiet = |_: FitProgress<'_>| {};
        fit_convnet(
            data,
            &[validation.to_path_buf()],
            &weights,
            &cfg,
            seed,
            false,
            // A stage stopped inside its fit keeps the networks it finished (an ensemble is
            // several fits); the loop's resume is the stage's, this is the fit's.
            true,
            "fishprobe ood-loop",
            &quiet,
        )
        .with_context(|| format!("fitting {}", weights.display()))?;
    }
    Ok(ModelSpec::by_name(&format!(
        "convnet:{}",
        weights.display()
    ))?)
}

/// Trains a policy against `model` in `dir` (resumed or skipped when done).
fn train(
    model: &ModelSpec,
    objective: Objective,
    cfg: &OodLoopConfig,
    seed: u64,
    dir: &Path,
) -> Result<String> {
    let policy = dir.join("policy.safetensors");
    if !policy.exists() {
        let mut t = if dir.join("params.json").exists() {
            Trainer::resume(dir)?
        } else {
            let mut ppo = PpoConfig::preset(&cfg.ppo_preset).context("preset checked")?;
            ppo.total_timesteps = cfg.train_steps;
            let mut env = EnvConfig::default();
            env.task.objective = objective;
            env.task.ood_score = cfg.ood_score;
            Trainer::create(
                dir,
                RunSpec {
                    ppo,
                    env,
                    model: model.clone(),
                    seed,
                    preset: cfg.ppo_preset.clone(),
                    program_version: env!("CARGO_PKG_VERSION").into(),
                },
            )?
        };
        while !t.done() {
            t.iterate()?;
        }
        t.finish()?;
    }
    Ok(dir.display().to_string())
}

fn gap(model: &[Vec<f64>], guppy: &[Vec<f64>], goals: f64, guppy_goals: f64) -> Gap {
    Gap {
        metrics: metric_gap(model, guppy),
        goals: (goals - guppy_goals).abs() / guppy_goals.max(1e-9),
        goals_per_episode: goals,
    }
}

fn metric_values(files: &[PathBuf]) -> Result<Vec<Vec<f64>>> {
    pooled_metrics(files, &AnalysisConfig::default()).map_err(anyhow::Error::msg)
}

fn one_seed(cfg: &OodLoopConfig, seed: u64, root: &Path) -> Result<SeedResult> {
    let dir = root.join(format!("seed-{seed}"));
    let guppy = ModelSpec::by_name("Guppy")?;
    let step = |what: &str| say!("seed {seed}: {what}");
    step("recording the virtual guppy in narrow situations");
    let (narrow, _) = record(
        &cfg.narrow_controller,
        &guppy,
        cfg.narrow_episodes,
        cfg.episode_minutes,
        seed,
        &dir.join("data/narrow"),
    )?;
    let validation = dir.join("data/validation");
    record(
        &cfg.narrow_controller,
        &guppy,
        cfg.validation_episodes,
        cfg.episode_minutes,
        seed.wrapping_add(1_000_003),
        &validation,
    )?;
    step("fitting M_ConvNet on the narrow data");
    let m0 = fit(
        &narrow,
        &validation,
        &dir.join("model-narrow"),
        cfg,
        seed,
        true,
    )?;
    let with = |extra: &[PathBuf]| narrow.iter().chain(extra).cloned().collect::<Vec<_>>();
    // Each chain: its current model and everything it has recorded.
    let (mut m_ood, mut m_goal) = (m0.clone(), m0.clone());
    let (mut ood_all, mut goal_all) = (Vec::new(), Vec::new());
    let (mut shares, mut ood_goals, mut goal_goals) = (Vec::new(), 0.0, 0.0);
    for round in 1..=cfg.rounds {
        // Round 1 keeps the layout of loops made before rounds existed.
        let sfx = if round == 1 {
            String::new()
        } else {
            format!("-r{round}")
        };
        let in_round = |what: &str| {
            if cfg.rounds == 1 {
                step(what)
            } else {
                step(&format!("round {round}: {what}"))
            }
        };
        in_round("training the OOD and the lead-to-goal policy against their models");
        let p_ood = train(
            &m_ood,
            Objective::Ood,
            cfg,
            seed,
            &dir.join(format!("policy-ood{sfx}")),
        )?;
        let p_goal = train(
            &m_goal,
            Objective::Goal,
            cfg,
            seed,
            &dir.join(format!("policy-goal{sfx}")),
        )?;
        in_round("recording the virtual guppy under each policy");
        let new_seed = seed
            .wrapping_add(2_000_003)
            .wrapping_add(7_919 * (round as u64 - 1));
        let ood_data;
        let goal_data;
        (ood_data, ood_goals) = record(
            &p_ood,
            &guppy,
            cfg.new_episodes,
            cfg.episode_minutes,
            new_seed,
            &dir.join(format!("data/under-ood{sfx}")),
        )?;
        (goal_data, goal_goals) = record(
            &p_goal,
            &guppy,
            cfg.new_episodes,
            cfg.episode_minutes,
            new_seed,
            &dir.join(format!("data/under-goal{sfx}")),
        )?;
        let support = m_ood.support()?;
        let ood_scores = score_trials(&support, "ood", &ood_data).map_err(anyhow::Error::msg)?;
        let goal_scores = score_trials(&support, "goal", &goal_data).map_err(anyhow::Error::msg)?;
        shares.push(share_at_least(
            &ood_scores.scores,
            quantile(&goal_scores.scores, 0.95),
        ));
        ood_all.extend(ood_data);
        goal_all.extend(goal_data);
        in_round("refitting M_ConvNet with each policy's data");
        m_ood = fit(
            &with(&ood_all),
            &validation,
            &dir.join(format!("model-ood{sfx}")),
            cfg,
            seed,
            round < cfg.rounds,
        )?;
        m_goal = fit(
            &with(&goal_all),
            &validation,
            &dir.join(format!("model-goal{sfx}")),
            cfg,
            seed,
            false,
        )?;
    }
    step("measuring each model's gap to the virtual guppy");
    let gap_seed = seed.wrapping_add(3_000_017);
    let models = [&m0, &m_goal, &m_ood];
    // The first probe's trials lie in gap/ itself, as before further probes existed.
    let first = probe_gaps(
        cfg,
        &cfg.gap_probe,
        &guppy,
        models,
        gap_seed,
        &dir.join("gap"),
    )?;
    let mut more_probes = Vec::new();
    for p in &cfg.more_gap_probes {
        let at = dir.join("gap").join(probe_dir_name(p));
        more_probes.push(probe_gaps(cfg, p, &guppy, models, gap_seed, &at)?);
    }
    Ok(SeedResult {
        seed,
        guppy_goals_per_episode: first.guppy_goals_per_episode,
        narrow: first.narrow,
        after_goal_data: first.after_goal_data,
        after_ood_data: first.after_ood_data,
        ood_share_beyond_goal_p95: shares.first().copied().unwrap_or(f64::NAN),
        later_rounds_ood_share: shares.iter().skip(1).copied().collect(),
        ood_policy_goals: ood_goals,
        goal_policy_goals: goal_goals,
        more_probes,
    })
}

/// The gaps of the narrow, the after-lead-to-goal and the after-OOD model (`models`, in that
/// order) to the virtual guppy, measured with `probe` (trials in `dir`, skipped when there).
fn probe_gaps(
    cfg: &OodLoopConfig,
    probe: &str,
    guppy: &ModelSpec,
    models: [&ModelSpec; 3],
    seed: u64,
    dir: &Path,
) -> Result<ProbeGaps> {
    let run = |model: &ModelSpec, name: &str| {
        record(
            probe,
            model,
            cfg.gap_episodes,
            cfg.gap_minutes,
            seed,
            &dir.join(name),
        )
    };
    let (g_files, g_goals) = run(guppy, "guppy")?;
    let g_metrics = metric_values(&g_files)?;
    let mut gaps = Vec::new();
    for (m, name) in models
        .into_iter()
        .zip(["narrow", "after-goal", "after-ood"])
    {
        let (files, goals) = run(m, name)?;
        gaps.push(gap(&metric_values(&files)?, &g_metrics, goals, g_goals));
    }
    Ok(ProbeGaps {
        probe: probe.to_string(),
        guppy_goals_per_episode: g_goals,
        narrow: gaps[0],
        after_goal_data: gaps[1],
        after_ood_data: gaps[2],
    })
}

pub fn run(a: OodLoopArgs) -> Result<()> {
    let cfg: OodLoopConfig = match &a.config {
        Some(p) => super::read_toml(p, "settings")?,
        None => OodLoopConfig::default(),
    };
    cfg.validate()?;
    if a.seeds.is_empty() || a.seeds.len() > 100 {
        bail!("--seeds takes 1 to 100 seeds, got {}", a.seeds.len());
    }
    super::no_repeats("--seeds", &a.seeds)?;
    let _lock = super::lock_out(&a.out, "ood-loop")?;
    let settings = serde_json::to_string_pretty(&cfg)? + "\n";
    let recorded = a.out.join("settings.json");
    match fishprobe_io::read_small_text(&recorded) {
        // Compared as settings, not as text: a loop recorded before a setting existed has
        // that setting's default, and resumes when the new run keeps it.
        Ok(old) => {
            let old: OodLoopConfig = serde_json::from_str(&old).with_context(|| {
                format!(
                    "{} is not the settings of a loop this fishprobe can resume; use another --out",
                    recorded.display()
                )
            })?;
            if old != cfg {
                bail!(
                    "{} holds a loop with other settings ({}); use another --out",
                    a.out.display(),
                    recorded.display()
                );
            }
        }
        Err(e) if e.kind() == std::io::ErrorKind::NotFound => {
            fishprobe_io::write_atomically(&recorded, settings.as_bytes())?
        }
        Err(e) => return Err(e).with_context(|| format!("reading {}", recorded.display())),
    }
    let mut results = Vec::new();
    for &seed in &a.seeds {
        let r = one_seed(&cfg, seed, &a.out).with_context(|| format!("seed {seed}"))?;
        say!(
            "seed {seed}: metric gap narrow {:.3}, after lead-to-goal data {:.3}, after OOD data {:.3}",
            r.narrow.metrics,
            r.after_goal_data.metrics,
            r.after_ood_data.metrics
        );
        results.push(r);
    }
    let json = serde_json::to_string_pretty(&serde_json::json!({
        "settings": cfg,
        "seeds": results,
    }))? + "\n";
    fishprobe_io::write_atomically(&a.out.join("loop.json"), json.as_bytes())?;
    let md = markdown(&cfg, &results);
    fishprobe_io::write_atomically(&a.out.join("loop.md"), md.as_bytes())?;
    emit(&md)
}

fn markdown(cfg: &OodLoopConfig, r: &[SeedResult]) -> String {
    let mut t = String::from(
        "| seed | metric gap: narrow model | + lead-to-goal data | + OOD data | goal gap: narrow | + lead-to-goal data | + OOD data | OOD views beyond lead-to-goal p95 |\n|---|---|---|---|---|---|---|---|\n",
    );
    for s in r {
        t += &format!(
            "| {} | {:.3} | {:.3} | {:.3} | {:.2} | {:.2} | {:.2} | {:.1} % |\n",
            s.seed,
            s.narrow.metrics,
            s.after_goal_data.metrics,
            s.after_ood_data.metrics,
            s.narrow.goals,
            s.after_goal_data.goals,
            s.after_ood_data.goals,
            100.0 * s.ood_share_beyond_goal_p95
        );
    }
    let n = r.len().max(1) as f64;
    let mean = |f: fn(&SeedResult) -> f64| r.iter().map(f).sum::<f64>() / n;
    let better = r
        .iter()
        .filter(|s| s.after_ood_data.metrics < s.after_goal_data.metrics)
        .count();
    t += &format!(
        "| mean | {:.3} | {:.3} | {:.3} | {:.2} | {:.2} | {:.2} | {:.1} % |\n\n\
         Metric gap: the nine metrics' Wasserstein distances between the model's and the \
         virtual guppy's trials with the gap probe, each in units of the guppy's s.d., \
         averaged. Goal gap: |goals(model) - goals(guppy)| / goals(guppy). The OOD data left \
         a smaller metric gap than the lead-to-goal data in {better} of {} seeds.\n",
        mean(|s| s.narrow.metrics),
        mean(|s| s.after_goal_data.metrics),
        mean(|s| s.after_ood_data.metrics),
        mean(|s| s.narrow.goals),
        mean(|s| s.after_goal_data.goals),
        mean(|s| s.after_ood_data.goals),
        100.0 * mean(|s| s.ood_share_beyond_goal_p95),
        r.len()
    );
    if cfg.ood_score == OodScore::Disagreement {
        t += &format!(
            "\nThe OOD policy was rewarded by the disagreement of an ensemble of {} fits of its \
             model (`ood_score = \"disagreement\"`); the last column still measures support \
             scores.\n",
            cfg.ensemble_members
        );
    }
    if cfg.rounds > 1 {
        t += &format!(
            "\n{} rounds: the gaps are those of each chain's model after its last round; the \
             last column is the first round's. OOD views beyond the lead-to-goal p95 by round: {}.\n",
            cfg.rounds,
            r.iter()
                .map(|s| {
                    let by_round: Vec<String> = std::iter::once(s.ood_share_beyond_goal_p95)
                        .chain(s.later_rounds_ood_share.iter().copied())
                        .map(|x| format!("{:.1} %", 100.0 * x))
                        .collect();
                    format!("seed {}: {}", s.seed, by_round.join(", "))
                })
                .collect::<Vec<_>>()
                .join("; ")
        );
    }
    t + "\n" + &probe_table(&cfg.gap_probe, r)
}

/// Per probe, the mean metric gaps over the seeds and in how many seeds the OOD data left the
/// smaller one; then the same for each seed's mean over all probes.
fn probe_table(first_probe: &str, r: &[SeedResult]) -> String {
    let Some(s0) = r.first() else {
        return String::new();
    };
    if s0.more_probes.is_empty() {
        return String::new();
    }
    // Per seed, per probe: (narrow, after lead-to-goal data, after OOD data).
    let per_seed: Vec<Vec<[f64; 3]>> = r
        .iter()
        .map(|s| {
            std::iter::once([
                s.narrow.metrics,
                s.after_goal_data.metrics,
                s.after_ood_data.metrics,
            ])
            .chain(s.more_probes.iter().map(|p| {
                [
                    p.narrow.metrics,
                    p.after_goal_data.metrics,
                    p.after_ood_data.metrics,
                ]
            }))
            .collect()
        })
        .collect();
    let names: Vec<&str> = std::iter::once(first_probe)
        .chain(s0.more_probes.iter().map(|p| p.probe.as_str()))
        .collect();
    let n = r.len() as f64;
    let mut t = String::from(
        "| gap probe | metric gap: narrow model | + lead-to-goal data | + OOD data | seeds where the OOD data left the smaller gap |\n|---|---|---|---|---|\n",
    );
    let mut row = |name: &str, gaps: Vec<[f64; 3]>| {
        let m = |k: usize| gaps.iter().map(|g| g[k]).sum::<f64>() / n;
        let better = gaps.iter().filter(|g| g[2] < g[1]).count();
        t += &format!(
            "| {name} | {:.3} | {:.3} | {:.3} | {better} of {} |\n",
            m(0),
            m(1),
            m(2),
            gaps.len()
        );
    };
    for (k, name) in names.iter().enumerate() {
        row(name, per_seed.iter().map(|s| s[k]).collect());
    }
    let over_all = per_seed
        .iter()
        .map(|s| {
            let p = s.len() as f64;
            [0, 1, 2].map(|k| s.iter().map(|g| g[k]).sum::<f64>() / p)
        })
        .collect();
    row("mean over the probes", over_all);
    t + "\nEach probe's metric gap averaged over the seeds (the first probe's is the table above).\n"
}
