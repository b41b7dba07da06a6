//! `fishprobe bench`: throughput on this machine, printed with the machine's description so
//! numbers can be compared.

use anyhow::Result;
use clap::{Args, Subcommand};
use serde::Serialize;
use std::time::Instant;

use super::emit;

mod observer;
mod ood;
mod sim;
mod stats;
mod train;
use observer::bench_observer;
use ood::bench_ood;
use sim::bench_sim;
use stats::bench_stats;
use train::bench_train;

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
    /// preset (100 epochs per batch) and the `paper` preset (2 epochs, sixteen times the steps;
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
    /// The BioTracker observer component (`live biotracker`, its own process) as the tracker
    /// core sees it: `update` round trips (p50, p99, worst) and the component's CPU share of
    /// one core, at the lab's 25 Hz and as fast as answered.
    Observer {
        /// Print JSON instead of text.
        #[arg(long)]
        json: bool,
        /// Seconds of measurement per load.
        #[arg(long, default_value_t = 10.0)]
        seconds: f64,
        /// The policy in control (as `live serve --policy`).
        #[arg(long, default_value = "scripted:goal-seeker")]
        policy: String,
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
        /// Fish per tank (`fish_count`; groups).
        #[arg(long, default_value_t = 1)]
        fish: u32,
    },
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
        BenchWhat::Observer {
            json,
            seconds,
            policy,
        } => bench_observer(json, seconds, &policy),
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
