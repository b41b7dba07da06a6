//! The OOD idea tested in silico with a known truth (`fishprobe ood-loop`).
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

use crate::{ResearchError, Result, Runner};
use fishprobe_analysis::ood::{metric_gap, pooled_metrics, quantile, score_trials, share_at_least};
use fishprobe_analysis::{load_trial, AnalysisConfig};
use fishprobe_learn::bc::{fit_convnet, CloneConfig, FitProgress, FitRequest};
use fishprobe_learn::{Evaluation, PpoConfig, RunSpec};
use fishprobe_models::ModelSpec;
use fishprobe_sim::{EnvConfig, Objective, OodScore};
use std::path::{Path, PathBuf};

mod config;
mod results;
use config::probe_dir_name;
pub use config::OodLoopConfig;
use results::{markdown, Gap, ProbeGaps, SeedResult};

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
        .map_err(|e| ResearchError::within(format!("loading {controller}"), e))?;
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
        std::fs::create_dir_all(dir)
            .map_err(|e| ResearchError::within(format!("creating {}", dir.display()), e))?;
        fishprobe_learn::evaluate(c.as_ref(), &e)?;
    }
    let files = trial_files(dir);
    let cfg = AnalysisConfig::default();
    let goals: Vec<f64> = files
        .iter()
        .map(|f| load_trial(f, &cfg, false).map(|t| f64::from(t.goals_reached)))
        .collect::<Result<_, _>>()
        .map_err(ResearchError::msg)?;
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
    build: &str,
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
            &FitRequest {
                data,
                validation: &[validation.to_path_buf()],
                out: &weights,
                cfg: &cfg,
                seed,
                baselines: false,
                // A stage stopped inside its fit keeps the networks it finished (an ensemble
                // is several fits); the loop's resume is the stage's, this is the fit's.
                resume: true,
                command: "fishprobe ood-loop",
                build,
            },
            &quiet,
        )
        .map_err(|e| ResearchError::within(format!("fitting {}", weights.display()), e))?;
    }
    Ok(ModelSpec::by_name(&format!(
        "convnet:{}",
        weights.display()
    ))?)
}

/// Trains a policy against `model` in `dir` (resumed or skipped when done; a policy that
/// another trainer revision trained or began is refused, so a loop never compares policies of
/// two trainers).
fn train(
    model: &ModelSpec,
    objective: Objective,
    cfg: &OodLoopConfig,
    seed: u64,
    dir: &Path,
    build: &str,
) -> Result<String> {
    let mut ppo =
        PpoConfig::preset(&cfg.ppo_preset).ok_or_else(|| ResearchError::msg("preset checked"))?;
    ppo.total_timesteps = cfg.train_steps;
    let mut env = EnvConfig::default();
    env.task.objective = objective;
    env.task.ood_score = cfg.ood_score;
    let spec = RunSpec::new(model.clone(), ppo, env, seed, cfg.ppo_preset.clone(), build);
    use fishprobe_learn::run::{open, train_to_end, Begin, OnOther};
    // Another fishprobe's run in the folder is named as such before any work.
    open(dir, &spec, OnOther::Refuse).map_err(|e| {
        ResearchError::within(
            "the loop was begun by another fishprobe; use another output directory",
            e,
        )
    })?;
    // A run trained in an earlier run of the loop is done at once.
    train_to_end(
        dir,
        Begin::StartOrResume(spec, OnOther::Refuse),
        build,
        &mut (),
    )?;
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
    pooled_metrics(files, &AnalysisConfig::default()).map_err(ResearchError::from)
}

fn one_seed(cfg: &OodLoopConfig, seed: u64, root: &Path, by: Runner) -> Result<SeedResult> {
    let build = by.build;
    let dir = root.join(format!("seed-{seed}"));
    let guppy = ModelSpec::by_name("Guppy")?;
    let step = |what: &str| by.note(&format!("seed {seed}: {what}"));
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
        build,
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
            build,
        )?;
        let p_goal = train(
            &m_goal,
            Objective::Goal,
            cfg,
            seed,
            &dir.join(format!("policy-goal{sfx}")),
            build,
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
        let ood_scores = score_trials(&support, "ood", &ood_data)?;
        let goal_scores = score_trials(&support, "goal", &goal_data)?;
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
            build,
        )?;
        m_goal = fit(
            &with(&goal_all),
            &validation,
            &dir.join(format!("model-goal{sfx}")),
            cfg,
            seed,
            false,
            build,
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

/// Runs the loop for each of `seeds` into `out` (resuming what is there), writes `loop.json`
/// and `loop.md`, and returns `loop.md`; a line per stage goes to `by`.
pub fn run(out: &Path, seeds: &[u64], cfg: &OodLoopConfig, by: Runner) -> Result<String> {
    cfg.validate()?;
    if seeds.is_empty() || seeds.len() > 100 {
        return Err(ResearchError::Refused(format!(
            "seeds: 1 to 100 seeds, got {}",
            seeds.len()
        )));
    }
    super::no_repeats("seeds", seeds)?;
    let _lock = fishprobe_io::DirLock::acquire(out, "ood-loop")?;
    let settings = serde_json::to_string_pretty(cfg)? + "\n";
    let recorded = out.join("settings.json");
    match fishprobe_io::read_small_text(&recorded) {
        // Compared as settings, not as text: a loop recorded before a setting existed has
        // that setting's default, and resumes when the new run keeps it.
        Ok(old) => {
            let old: OodLoopConfig = serde_json::from_str(&old).map_err(|e| ResearchError::within({
                format!(
                    "{} is not the settings of a loop this fishprobe can resume; use another output directory",
                    recorded.display()
                )
            }, e))?;
            if old != *cfg {
                return Err(ResearchError::Refused(format!(
                    "{} holds a loop with other settings ({}); use another output directory",
                    out.display(),
                    recorded.display()
                )));
            }
        }
        Err(e) if e.kind() == std::io::ErrorKind::NotFound => {
            fishprobe_io::write_atomically(&recorded, settings.as_bytes())?
        }
        Err(e) => {
            return Err(e)
                .map_err(|e| ResearchError::within(format!("reading {}", recorded.display()), e))
        }
    }
    let mut results = Vec::new();
    for &seed in seeds {
        let r = one_seed(cfg, seed, out, by)
            .map_err(|e| ResearchError::within(format!("seed {seed}"), e))?;
        by.note(&format!(
            "seed {seed}: metric gap narrow {:.3}, after lead-to-goal data {:.3}, after OOD data {:.3}",
            r.narrow.metrics,
            r.after_goal_data.metrics,
            r.after_ood_data.metrics
        ));
        results.push(r);
    }
    let json = serde_json::to_string_pretty(&serde_json::json!({
        "settings": cfg,
        "seeds": results,
    }))? + "\n";
    fishprobe_io::write_atomically(&out.join("loop.json"), json.as_bytes())?;
    let md = markdown(cfg, &results);
    fishprobe_io::write_atomically(&out.join("loop.md"), md.as_bytes())?;
    Ok(md)
}
