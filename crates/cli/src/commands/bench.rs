//! `fishprobe bench`: throughput on this machine, printed with the machine's description so
//! numbers can be compared.

use anyhow::{Context, Result};
use clap::{Args, Subcommand};
use fishprobe_models::ModelSpec;
use fishprobe_sim::params::check::shown;
use fishprobe_sim::{stream, Env, EnvConfig, TankEnv, VecEnv};
use rand::RngExt;
use serde::Serialize;
use std::f32::consts::PI;
use std::fmt::Write;
use std::time::Instant;

use super::emit;

#[derive(Debug, Args)]
pub struct BenchArgs {
    #[command(subcommand)]
    what: BenchWhat,
}

#[derive(Debug, Clone, Copy, clap::ValueEnum)]
enum StudySizeArg {
    /// The paper's study: 4 policies x (50 sim + 18 real), 4 x 4 x 50 sim-to-sim, 6 x 4 x 50
    /// stability, 4 x 10 approach episodes; 15-minute trials (about 2,100 files).
    Paper,
    /// A small study for tests: 2 policies, 2-minute trials.
    Small,
}

#[derive(Debug, Subcommand)]
enum BenchWhat {
    /// The trainer: single-core matrix-multiply rate, PPO-update minibatch steps/s and GFLOP/s
    /// (paper network and minibatch), and end-to-end training steps/s with the `published`
    /// preset (100 epochs per batch) and the `paper` preset (2 epochs, eight times the steps;
    /// for an expensive fish the published steps at 10 epochs), each projected to a full run.
    Train {
        /// Print JSON instead of text.
        #[arg(long)]
        json: bool,
        /// Training iterations of each end-to-end measurement (8192 steps each).
        #[arg(long, default_value_t = 2)]
        iterations: u64,
        /// Fish model of the end-to-end measurement (e.g. ConvNet, to compare its batched
        /// inference with Zone).
        #[arg(long, default_value = "Zone")]
        model: String,
    },
    /// The whole analysis of a paper-sized study of synthetic trials (scripted robots), file
    /// reading included, with the paper's replicate counts.
    Stats {
        /// Print JSON instead of text.
        #[arg(long)]
        json: bool,
        /// Keep the generated study here (reused when it already holds one).
        #[arg(long)]
        dir: Option<std::path::PathBuf>,
        /// Study size.
        #[arg(long, value_enum, default_value = "paper")]
        size: StudySizeArg,
        /// Seed of the generated trials and of the resampling.
        #[arg(long, default_value_t = 0)]
        seed: u64,
    },
    /// The OOD task's scores, per fish view on one core: the shipped support (kNN), an
    /// ensemble's disagreement alone and in the batch the trainer scores (one per core's part
    /// of its 64 environments), next to the fish's own inference. The ensemble's further
    /// members are fresh networks of the shipped shape: they cost what fitted ones cost.
    Ood {
        /// Print JSON instead of text.
        #[arg(long)]
        json: bool,
        /// Members of the ensemble, the shipped network included (2 to 16).
        #[arg(long, default_value_t = 4)]
        members: usize,
        /// Seconds of measurement per row.
        #[arg(long, default_value_t = 2.0)]
        seconds: f64,
    },
    /// Simulation throughput per rule-based model: the robot under random 1 Hz commands,
    /// observation encoded once per action; one core, then all cores.
    Sim {
        /// Print JSON instead of text.
        #[arg(long)]
        json: bool,
        /// Seconds of measurement per model and mode.
        #[arg(long, default_value_t = 2.0)]
        seconds: f64,
        /// Environments in the all-cores run (default: 32 per core).
        #[arg(long)]
        envs: Option<usize>,
        /// Fish per tank (`fish_count`; groups, issue 22).
        #[arg(long, default_value_t = 1)]
        fish: u32,
    },
}

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

#[derive(Debug, Serialize)]
struct Machine {
    cores: usize,
    cpu: String,
    os: &'static str,
    arch: &'static str,
}

fn machine() -> Machine {
    let cpu = std::fs::read_to_string("/proc/cpuinfo")
        .ok()
        .and_then(|s| {
            s.lines()
                .find(|l| l.starts_with("model name"))
                .and_then(|l| l.split(':').nth(1))
                .map(|m| m.trim().to_string())
        })
        .unwrap_or_else(|| "unknown".into());
    Machine {
        cores: std::thread::available_parallelism().map_or(1, |n| n.get()),
        cpu,
        os: std::env::consts::OS,
        arch: std::env::consts::ARCH,
    }
}

pub fn run(a: BenchArgs) -> Result<()> {
    match a.what {
        BenchWhat::Sim {
            json,
            seconds,
            envs,
            fish,
        } => bench_sim(json, seconds, envs, fish),
        BenchWhat::Train {
            json,
            iterations,
            model,
        } => {
            if iterations == 0 || iterations > 1000 {
                anyhow::bail!("--iterations must lie in [1, 1000], got {iterations}");
            }
            bench_train(json, iterations, &model)
        }
        BenchWhat::Stats {
            json,
            dir,
            size,
            seed,
        } => bench_stats(json, dir, size, seed),
        BenchWhat::Ood {
            json,
            members,
            seconds,
        } => bench_ood(json, members, seconds),
    }
}

/// One row of `bench ood`.
#[derive(Debug, Serialize)]
struct OodBench {
    score: String,
    batch: usize,
    us_per_view: f64,
}

fn bench_ood(json: bool, members: usize, seconds: f64) -> Result<()> {
    use fishprobe_models::disagreement::{Disagreement, DisagreementFile, MAX_MEMBERS};
    use fishprobe_models::{ConvNet, ConvNetFish};
    use fishprobe_sim::{AgentState, FishModel, FishView, InputSupport, Tank};
    if !(2..=MAX_MEMBERS).contains(&members) {
        anyhow::bail!("--members must lie in [2, {MAX_MEMBERS}], got {members}");
    }
    if !(seconds.is_finite() && (0.1..=600.0).contains(&seconds)) {
        anyhow::bail!("--seconds must lie in [0.1, 600], got {}", shown(seconds));
    }
    // The batch one core scores in training: the trainer's 64 environments split across the
    // cores (at least 16 fish per part, as the vector environment splits them).
    let cores = std::thread::available_parallelism().map_or(1, |n| n.get());
    let batch = (64 / cores).max(16);
    let mut rng = stream(0, "bench-ood", 0);
    let tank = Tank::default();
    let mut pose = || {
        AgentState::at(
            rng.random_range(-45.0..45.0),
            rng.random_range(-45.0..45.0),
            rng.random_range(-PI..PI),
        )
    };
    let views: Vec<FishView> = (0..4096)
        .map(|_| FishView::build(0, &[pose()], &[pose()], tank, 0.04, 0.0))
        .collect();
    let shipped = ConvNet::shipped()?;
    let arch = shipped.arch.clone();
    let mut nets = vec![shipped.clone()];
    let mut net_rng = stream(0, "bench-ood-member", 0);
    nets.extend((1..members).map(|_| ConvNet::new(arch.clone(), &mut net_rng)));
    let len = arch.view_len();
    let mut encoded = vec![0.0; views.len() * len];
    for (v, row) in views.iter().zip(encoded.chunks_exact_mut(len)) {
        fishprobe_models::convnet::encode_view(&arch, &v.tank, &v.me, v.others(), row);
    }
    let refs = (1..members)
        .map(|i| fishprobe_models::disagreement::MemberRef {
            file: format!("member-{i}"),
            sha256: String::new(),
        })
        .collect();
    let file = DisagreementFile::new(
        "ConvNet".into(),
        String::new(),
        refs,
        serde_json::Value::Null,
    );
    let ensemble = Disagreement::fit(nets, file, &encoded, 256, &mut net_rng)?;
    let support = fishprobe_models::convnet::shipped_support()?;
    let fish = ConvNetFish::from_net(shipped);
    let mut out = vec![0.0; batch * arch.cells()];
    let mut measure = |name: &str, batch: usize, f: &mut dyn FnMut(&[FishView], &mut [f32])| {
        let mut done = 0usize;
        let mut pass = |done: &mut usize| {
            let at = (*done * batch) % (views.len() - batch);
            f(&views[at..at + batch], &mut out);
            *done += 1;
        };
        let warm = Instant::now();
        while warm.elapsed().as_secs_f64() < seconds * 0.1 {
            pass(&mut done);
        }
        done = 0;
        let start = Instant::now();
        while start.elapsed().as_secs_f64() < seconds {
            pass(&mut done);
        }
        OodBench {
            score: name.into(),
            batch,
            us_per_view: start.elapsed().as_secs_f64() * 1e6 / (done * batch) as f64,
        }
    };
    let rows = vec![
        measure("support (kNN, shipped)", 1, &mut |v, o| {
            support.score_batch(v, o)
        }),
        measure(&format!("disagreement of {members}"), 1, &mut |v, o| {
            ensemble.score_batch(v, o)
        }),
        measure(&format!("disagreement of {members}"), batch, &mut |v, o| {
            ensemble.score_batch(v, o)
        }),
        measure("the fish's inference (M_ConvNet)", batch, &mut |v, o| {
            fish.infer_batch(v, o)
        }),
    ];
    let m = machine();
    let text = if json {
        serde_json::to_string_pretty(&serde_json::json!({
            "bench": "ood", "machine": m, "members": members, "rows": rows,
            "command": format!("fishprobe bench ood --members {members} --json"),
        }))? + "\n"
    } else {
        let mut t = format!(
            "fishprobe bench ood — one core of {} ({}, {} {}); 4,096 random fish-robot views\n{:<36} {:>6} {:>12}\n",
            m.cores, m.cpu, m.os, m.arch, "score", "batch", "µs per view"
        );
        for r in &rows {
            writeln!(t, "{:<36} {:>6} {:>12.1}", r.score, r.batch, r.us_per_view)?;
        }
        t
    };
    emit(&text)
}

fn bench_stats(
    json: bool,
    dir: Option<std::path::PathBuf>,
    size: StudySizeArg,
    seed: u64,
) -> Result<()> {
    use super::synth::{generate, StudySize};
    let size = match size {
        StudySizeArg::Paper => StudySize::PAPER,
        StudySizeArg::Small => StudySize {
            policies: 2,
            own: 8,
            cross: 5,
            real: 6,
            stability: (3, 4),
            approach: 2,
            minutes: 2.0,
        },
    };
    let temporary = dir.is_none();
    let dir = dir.unwrap_or_else(|| {
        std::env::temp_dir().join(format!("fishprobe-bench-stats-{}", std::process::id()))
    });
    let scratch = temporary.then(|| fishprobe_io::ScratchDir::remove_on_drop(dir.clone()));
    let t0 = Instant::now();
    let layout = fishprobe_io::StudyLayout::new(&dir);
    let generated = if layout.rollouts().is_dir() {
        0
    } else {
        generate(&dir, size, seed)
            .with_context(|| format!("generating a study in {}", dir.display()))?
    };
    let generation_s = t0.elapsed().as_secs_f64();
    let t1 = Instant::now();
    let cfg = fishprobe_analysis::AnalysisConfig::default();
    let results = fishprobe_analysis::analyze_dir(&dir, &cfg, seed)?;
    fishprobe_analysis::write_results(&layout.analysis(), &results)?;
    let analysis_s = t1.elapsed().as_secs_f64();
    let files = walk_count(&dir);
    drop(scratch);
    let m = machine();
    let text = if json {
        serde_json::to_string_pretty(&serde_json::json!({
            "bench": "stats", "machine": m, "trial_files": files, "generated": generated,
            "generation_s": generation_s, "analysis_s": analysis_s,
            "skipped": results.skipped.len(), "command": "fishprobe bench stats --json",
        }))? + "\n"
    } else {
        format!(
            "fishprobe bench stats — {} cores, {} ({} {})\n{files} trial files ({} generated in {generation_s:.1} s)\nanalysis (reading, metrics, every test at the paper's replicate counts, writing): {analysis_s:.1} s\n",
            m.cores, m.cpu, m.os, m.arch, generated
        )
    };
    emit(&text)
}

/// Trial files under a directory (the analysis output excluded).
fn walk_count(dir: &std::path::Path) -> usize {
    let Ok(rd) = std::fs::read_dir(dir) else {
        return 0;
    };
    rd.filter_map(Result::ok)
        .map(|e| e.path())
        .map(|p| {
            if p.is_dir() {
                walk_count(&p)
            } else {
                usize::from(p.extension().is_some_and(|x| x == "hdf5"))
            }
        })
        .sum()
}

fn bench_sim(json: bool, seconds: f64, envs: Option<usize>, fish: u32) -> Result<()> {
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

/// Calls `chunk` (which returns the policy steps it made) after a short warm-up until
/// `seconds` have passed; returns (steps, elapsed seconds).
fn timed(
    seconds: f64,
    mut chunk: impl FnMut() -> Result<u64, fishprobe_sim::SimError>,
) -> Result<(u64, f64)> {
    let warm = Instant::now();
    while warm.elapsed().as_secs_f64() < seconds * 0.1 {
        chunk()?;
    }
    let start = Instant::now();
    let mut steps = 0;
    while start.elapsed().as_secs_f64() < seconds {
        steps += chunk()?;
    }
    Ok((steps, start.elapsed().as_secs_f64()))
}

/// FLOPs of one forward and backward pass of an MLP on `m` rows (dense layers only).
fn mlp_flops(sizes: &[usize], m: usize) -> f64 {
    let macs: Vec<f64> = sizes.windows(2).map(|w| (w[0] * w[1]) as f64).collect();
    let forward: f64 = macs.iter().sum::<f64>() * 2.0 * m as f64;
    // Backward: weight gradients for every layer, input gradients for all but the first.
    let backward = forward + (macs.iter().sum::<f64>() - macs[0]) * 2.0 * m as f64;
    forward + backward
}

fn bench_train(json: bool, iterations: u64, model_name: &str) -> Result<()> {
    use fishprobe_learn::ppo::{update, Rollout, Scratch};
    use fishprobe_learn::{GaussianPolicy, PpoConfig, RunSpec, Trainer};
    let m = machine();
    // 1. Single-core GEMM rate at the update's shapes (512 x 256 · 256 x 256).
    let (a, b) = (vec![0.5f32; 512 * 256], vec![0.25f32; 256 * 256]);
    let mut c = vec![0.0f32; 512 * 256];
    let per = 2.0 * 512.0 * 256.0 * 256.0;
    let (reps, secs) = timed(1.0, || {
        fishprobe_nn::gemm::gemm(
            1.0,
            fishprobe_nn::gemm::Mat::new(&a, 512, 256),
            fishprobe_nn::gemm::Mat::new(&b, 256, 256),
            0.0,
            &mut c,
            512,
            256,
        );
        Ok(1)
    })?;
    let gemm_gflops = per * reps as f64 / secs / 1e9;

    // 2. PPO update (paper network, minibatch and batch sizes) on one batch sampled from the
    // model's environment by the fresh policy: real observations are mostly zero, which the
    // first layer exploits, so a synthetic dense batch would misstate the update's speed.
    let cfg = PpoConfig {
        num_sgd_iter: 2,
        ..PpoConfig::default()
    };
    let mut rng = stream(0, "bench-train", 0);
    let mut venv = fishprobe_sim::VecEnv::new(
        fishprobe_sim::EnvConfig::default(),
        ModelSpec::by_name(model_name)?.build()?,
        cfg.num_envs,
    )?;
    venv.reset(0)?;
    let obs_dim = venv.obs_dim();
    let mut policy = GaussianPolicy::new(obs_dim, &cfg, &mut rng);
    let mut roll = Rollout::new(cfg.num_envs, cfg.train_batch_size / cfg.num_envs, obs_dim);
    let mut scratch = Scratch::default();
    fishprobe_learn::ppo::collect(&cfg, &mut venv, &policy, &mut roll, &mut rng, &mut scratch)?;
    let mut adam_pi = fishprobe_nn::Adam::new(policy.pi.num_params(), cfg.lr);
    let mut adam_vf = fishprobe_nn::Adam::new(policy.vf.num_params(), cfg.lr);
    let minibatches_per_call = cfg.num_sgd_iter * (cfg.train_batch_size / cfg.sgd_minibatch_size);
    let (calls, secs) = timed(3.0, || {
        update(
            &cfg,
            &mut policy,
            &mut adam_pi,
            &mut adam_vf,
            0.2,
            &mut roll,
            &mut rng,
            &mut scratch,
        )
        .map_err(|_| fishprobe_sim::SimError::NeedsReset)?;
        Ok(1)
    })?;
    let mb_per_s = (calls as usize * minibatches_per_call) as f64 / secs;
    let flops_mb = mlp_flops(&policy.pi.spec().sizes, cfg.sgd_minibatch_size)
        + mlp_flops(&policy.vf.spec().sizes, cfg.sgd_minibatch_size);
    let update_gflops = flops_mb * mb_per_s / 1e9;

    // 3. End to end: `iterations` iterations of the `published` preset (100 epochs per batch,
    // the speed target) and of the `paper` preset (for this model) against the model.
    let model = ModelSpec::by_name(model_name)?;
    let mut e2e = Vec::new();
    for preset in ["published", "paper"] {
        let dir = std::env::temp_dir().join(format!(
            "fishprobe-bench-train-{}-{preset}",
            std::process::id()
        ));
        let _ = std::fs::remove_dir_all(&dir);
        let scratch = fishprobe_io::ScratchDir::remove_on_drop(dir.clone());
        let spec = RunSpec {
            ppo: PpoConfig::preset_for(preset, model.is_expensive()).context("PPO preset")?,
            env: fishprobe_sim::EnvConfig::default(),
            model: model.clone(),
            seed: 0,
            preset: preset.into(),
            program_version: env!("CARGO_PKG_VERSION").into(),
        };
        let (total, epochs) = (spec.ppo.total_timesteps, spec.ppo.num_sgd_iter);
        let mut t = Trainer::create(&dir, spec)?;
        let start = Instant::now();
        for _ in 0..iterations.max(1) {
            t.iterate()?;
        }
        let e2e_secs = start.elapsed().as_secs_f64();
        drop(scratch);
        let steps_per_s = t.timesteps() as f64 / e2e_secs;
        e2e.push((
            preset,
            epochs,
            total,
            steps_per_s,
            total as f64 / steps_per_s / 60.0,
        ));
    }
    let text = if json {
        let runs: Vec<_> = e2e
            .iter()
            .map(|(preset, epochs, total, sps, min)| {
                serde_json::json!({"preset": preset, "epochs_per_batch": epochs,
                    "total_timesteps": total, "train_steps_per_s": sps, "run_minutes_projected": min})
            })
            .collect();
        serde_json::to_string_pretty(&serde_json::json!({
            "bench": "train", "machine": m, "gemm_gflops_single_core": gemm_gflops,
            "update_minibatches_per_s": mb_per_s, "update_gflops": update_gflops,
            "update_gflops_per_core": update_gflops / m.cores as f64,
            "model": model_name, "iterations": iterations.max(1), "end_to_end": runs,
            "command": "fishprobe bench train --json",
        }))? + "\n"
    } else {
        let mut s = format!(
            "fishprobe bench train — {} cores, {} ({} {})\n\
             matrix multiply, one core (512x256 · 256x256):  {gemm_gflops:.1} GFLOP/s\n\
             PPO update (2 x [180, 256, 256, out] MLPs, minibatch 512): {mb_per_s:.1} minibatches/s, {update_gflops:.1} GFLOP/s dense-equivalent ({:.1} per core, {:.0} % of the single-core GEMM rate)\n",
            m.cores, m.cpu, m.os, m.arch,
            update_gflops / m.cores as f64,
            100.0 * update_gflops / m.cores as f64 / gemm_gflops,
        );
        for (preset, epochs, total, sps, min) in &e2e {
            s += &format!(
                "end to end ({preset} preset, {epochs} epochs per batch, {} iterations, {model_name}): {sps:.0} steps/s -> a full {total}-step run takes {min:.1} min\n",
                iterations.max(1)
            );
        }
        s
    };
    emit(&text)
}
