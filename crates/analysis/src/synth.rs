//! Synthetic studies in the paper's layout, made of scripted-robot trials: the input of
//! `fishprobe bench stats` and of the end-to-end tests of `analyze`. They exercise every
//! section of the analysis; their numbers mean nothing about real fish.

use crate::AnalysisError;
use fishprobe_io::{write_trial, TrialFile, TrialKind, TrialMeta};
use fishprobe_models::{ForceParams, ModelSpec, ZoneConvention, ZoneParams};
use fishprobe_sim::{
    derive_seed, Env, EnvConfig, RobotScript, ScriptParams, StartPoses, TankEnv, TaskMode,
};
use rayon::prelude::*;
use std::path::{Path, PathBuf};

/// How big a synthetic study is.
#[derive(Debug, Clone, Copy)]
pub struct StudySize {
    /// Policies (each named after a model).
    pub policies: usize,
    /// Sim trials per policy on its own model (the first `real` of them feed sim-to-real).
    pub own: usize,
    /// Episodes per policy on each other model.
    pub cross: usize,
    /// Reality-arm trials per policy.
    pub real: usize,
    /// Stability: seeds per model and episodes per seed.
    pub stability: (usize, usize),
    /// Approach episodes per policy.
    pub approach: usize,
    /// Minutes per trial (approach episodes: 2 min at most).
    pub minutes: f32,
}

impl StudySize {
    /// The paper's study: 4 policies, 50 episodes per sim cell, 18 real trials, 6 x 50
    /// stability episodes per model, 10 approach episodes, 15 minutes.
    pub const PAPER: StudySize = StudySize {
        policies: 4,
        own: 50,
        cross: 50,
        real: 18,
        stability: (6, 50),
        approach: 10,
        minutes: 15.0,
    };
}

/// The synthetic models: the three rule-based ones and a radii-convention Zone.
fn models() -> Vec<(&'static str, ModelSpec)> {
    vec![
        (
            "Follow",
            ModelSpec::by_name("Follow").unwrap_or_else(|_| unreachable!()),
        ),
        ("Zone", ModelSpec::Zone(ZoneParams::default())),
        ("Force", ModelSpec::Force(ForceParams::default())),
        (
            "ZoneRadii",
            ModelSpec::Zone(ZoneParams {
                zone_convention: ZoneConvention::Radii,
                ..ZoneParams::default()
            }),
        ),
    ]
}

/// The stand-in for live fish: a noisier, slower Force fish.
fn reality_model() -> ModelSpec {
    ModelSpec::Force(ForceParams {
        angular_noise: 0.6,
        preferred_speed: 0.16,
        ..ForceParams::default()
    })
}

struct Job {
    path: PathBuf,
    policy: String,
    model: ModelSpec,
    kind: TrialKind,
    seed: u64,
    minutes: f32,
    approach: bool,
}

fn run_job(j: &Job) -> Result<(), AnalysisError> {
    let mut cfg = EnvConfig {
        mode: TaskMode::Evaluation,
        ..EnvConfig::default()
    };
    let actions = (j.minutes * 60.0).ceil() as u32;
    cfg.task.evaluation_episode_actions = actions.max(1);
    if j.approach {
        cfg.task.evaluation_goals = [[20.0, -20.0], [20.0, -20.0]];
    }
    let model = if j.approach {
        ModelSpec::by_name("Stationary")?
    } else {
        j.model.clone()
    };
    let mut env = TankEnv::new(cfg.clone(), model.build()?)?;
    if j.approach {
        env.set_start_poses(Some(StartPoses {
            robot: [-45.0, -45.0, std::f32::consts::FRAC_PI_4],
            fish: vec![[-20.0, 20.0, 0.0]],
        }))?;
    }
    env.set_recording(true);
    let mut obs = vec![0.0; env.observation_space().dim()];
    env.reset(Some(j.seed), &mut obs)?;
    let script = ScriptParams::default();
    for _ in 0..actions {
        env.step_scripted(RobotScript::Goals, &script, &mut obs)?;
    }
    let meta = TrialMeta {
        kind: j.kind,
        policy: j.policy.clone(),
        fish_model: model.name().to_string(),
        seed: j.seed,
        goal_radius_cm: cfg.task.goal_radius_cm,
        config_json: String::from("{\"synthetic\": true}"),
        experiment_setup: "fishprobe synthetic study (scripted robot; not a real experiment)"
            .into(),
    };
    let t = env
        .trajectory()
        .expect("recording was switched on before the episode");
    write_trial(
        &j.path,
        &TrialFile::from_trajectory(t, env.summary(), &meta, [100.0, 100.0]),
    )?;
    Ok(())
}

/// Writes a synthetic study under `dir`; returns the number of trial files.
pub fn generate(dir: &Path, size: StudySize, seed: u64) -> Result<usize, AnalysisError> {
    let all = models();
    let used = &all[..size.policies.clamp(1, all.len())];
    let mut jobs = Vec::new();
    // Seeds come from the path inside the study, so a study is the same wherever it is made:
    // these relative paths stay literal (a change would change every synthetic trial). They
    // follow the paper's public archive, whose stability seeds are plain numbers
    // (`stability/<Model>/<seed>/`), which `analyze` reads like `fishprobe run`'s `seed<k>`.
    let mut add = |rel: String, policy: &str, model: ModelSpec, kind, minutes, approach| {
        let s = derive_seed(seed, &rel, 0);
        jobs.push(Job {
            path: dir.join(rel),
            policy: policy.into(),
            model,
            kind,
            seed: s,
            minutes,
            approach,
        });
    };
    for (p, _) in used {
        for (m, spec) in used {
            let n = if p == m { size.own } else { size.cross };
            for e in 0..n {
                add(
                    format!("rollouts/{p}__{m}/{p}__{m}_{e:03}.hdf5"),
                    p,
                    spec.clone(),
                    TrialKind::Sim,
                    size.minutes,
                    false,
                );
            }
        }
        for e in 0..size.real {
            add(
                format!("rollouts/{p}__Real/{p}__Real_{e:03}.hdf5"),
                p,
                reality_model(),
                TrialKind::Sim,
                size.minutes,
                false,
            );
        }
        for e in 0..size.approach {
            add(
                format!("approach_test/{p}/{p}_{e:03}.hdf5"),
                p,
                ModelSpec::by_name("Stationary")?,
                TrialKind::Sim,
                size.minutes.min(2.0),
                true,
            );
        }
    }
    for (m, spec) in used {
        for s in 0..size.stability.0 {
            for e in 0..size.stability.1 {
                add(
                    format!("stability/{m}/{s}/{m}_{s}_{e:03}.hdf5"),
                    m,
                    spec.clone(),
                    TrialKind::Sim,
                    size.minutes,
                    false,
                );
            }
        }
    }
    jobs.par_iter().try_for_each(run_job)?;
    Ok(jobs.len())
}
