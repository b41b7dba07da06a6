//! `fishprobe bench sim`: simulation throughput per rule-based model, on one core and on all.

use super::{emit, machine, timed};
use anyhow::{Context, Result};
use fishprobe_models::ModelSpec;
use fishprobe_sim::params::check::shown;
use fishprobe_sim::{stream, Env, EnvConfig, TankEnv, VecEnv};
use rand::RngExt;
use serde::Serialize;
use std::f32::consts::PI;
use std::fmt::Write;

/// One measured configuration.
#[derive(Debug, Serialize)]
struct SimBench {
    model: String,
    threads: usize,
    envs: usize,
    fish: u32,
    policy_steps_per_s: f64,
    frames_per_s: f64,
    frames_per_s_per_core: f64,
    fish_frames_per_s_per_core: f64,
}

pub(super) fn bench_sim(json: bool, seconds: f64, envs: Option<usize>, fish: u32) -> Result<()> {
    if !(seconds.is_finite() && seconds > 0.0 && seconds <= 3600.0) {
        anyhow::bail!("--seconds must lie in (0, 3600], got {}", shown(seconds));
    }
    if envs.is_some_and(|n| n == 0 || n > 65_536) {
        anyhow::bail!("--envs must lie in [1, 65536]");
    }
    let m = machine();
    let n_envs = envs.unwrap_or(32 * m.cores).max(1);
    let cfg = EnvConfig {
        fish_count: fish,
        ..EnvConfig::default()
    };
    cfg.validate().context("--fish")?;
    let frames_per_action = f64::from(cfg.frames_per_action);
    let mut rows = Vec::new();
    for name in ModelSpec::RULE_BASED {
        let model = ModelSpec::by_name(name)?.build()?;

        // One core: a single environment stepped in this thread.
        let mut env = TankEnv::new(cfg.clone(), model.clone())?;
        let mut obs = vec![0.0; env.observation_space().dim()];
        let mut rng = stream(0, "bench-actions", 0);
        env.reset(Some(1), &mut obs)?;
        let (steps, secs) = timed(seconds, || {
            for _ in 0..64 {
                let t = env.step(&[rng.random_range(-PI..=PI)], &mut obs)?;
                if t.truncated {
                    env.reset(None, &mut obs)?;
                }
            }
            Ok(64)
        })
        .with_context(|| format!("single-core run of {name}"))?;
        rows.push(row(name, 1, 1, steps, secs, frames_per_action, fish));

        // All cores: a vector environment on the global thread pool.
        let mut venv = VecEnv::new(cfg.clone(), model, n_envs)?;
        venv.reset(2)?;
        let mut actions = vec![0.0f32; n_envs];
        let (steps, secs) = timed(seconds, || {
            for a in actions.iter_mut() {
                *a = rng.random_range(-PI..=PI);
            }
            venv.step(&actions)?;
            Ok(n_envs as u64)
        })
        .with_context(|| format!("all-core run of {name}"))?;
        rows.push(row(
            name,
            rayon::current_num_threads(),
            n_envs,
            steps,
            secs,
            frames_per_action,
            fish,
        ));
    }
    let mut text = String::new();
    if json {
        let out = serde_json::json!({ "bench": "sim", "machine": m, "results": rows,
            "command": format!("fishprobe bench sim --fish {fish} --json") });
        text = serde_json::to_string_pretty(&out)? + "\n";
    } else {
        writeln!(
            text,
            "fishprobe bench sim --fish {fish} — {} cores, {} ({} {}); {:.1} s per measurement",
            m.cores, m.cpu, m.os, m.arch, seconds
        )?;
        writeln!(
            text,
            "{:<8} {:>7} {:>6} {:>16} {:>14} {:>18} {:>23}",
            "model",
            "threads",
            "envs",
            "policy steps/s",
            "frames/s",
            "frames/s per core",
            "fish-frames/s per core"
        )?;
        for r in &rows {
            writeln!(
                text,
                "{:<8} {:>7} {:>6} {:>16.0} {:>14.0} {:>18.0} {:>23.0}",
                r.model,
                r.threads,
                r.envs,
                r.policy_steps_per_s,
                r.frames_per_s,
                r.frames_per_s_per_core,
                r.fish_frames_per_s_per_core
            )?;
        }
    }
    emit(&text)
}

fn row(
    model: &str,
    threads: usize,
    envs: usize,
    steps: u64,
    secs: f64,
    fpa: f64,
    fish: u32,
) -> SimBench {
    let sps = steps as f64 / secs;
    SimBench {
        model: model.to_string(),
        threads,
        envs,
        fish,
        policy_steps_per_s: sps,
        frames_per_s: sps * fpa,
        frames_per_s_per_core: sps * fpa / threads as f64,
        fish_frames_per_s_per_core: sps * fpa * f64::from(fish) / threads as f64,
    }
}
