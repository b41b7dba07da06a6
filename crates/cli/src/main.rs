//! The `fishprobe` command line: one subcommand per job. `main` only parses, runs and maps
//! errors to an exit code; the work is in `commands/`.
//!
//! **Reading the API** (`cargo doc --workspace --open`): start with [`fishprobe_sim`] (the tank,
//! the robot, the task, the `Env`, `FishModel` and `Controller` traits), then
//! [`fishprobe_models`] (the candidate fish models and how one is added), [`fishprobe_io`] (trial
//! files, the study layout, locks), [`fishprobe_learn`] (PPO, evaluation, behavioural cloning),
//! `fishprobe_stats` and [`fishprobe_analysis`] (the statistics and the study's comparisons),
//! [`fishprobe_report`], [`fishprobe_live`] (the bridge and the virtual lab), `fishprobe_onnx`
//! (files users bring) and [`fishprobe_study`] (`fishprobe run`); `fishprobe_py` is the native
//! half of the Python package (`python/`, documented for Python users in `python/README.md`).
//! ARCHITECTURE.md draws how they depend on each other. Every public item is documented
//! (`#![warn(missing_docs)]` in each library, and CI denies warnings).

mod commands;

use std::process::ExitCode;

// A user's ONNX file cannot make the engine allocate gigabytes (fishprobe_onnx::CappedAlloc).
#[global_allocator]
static ALLOC: fishprobe_onnx::CappedAlloc = fishprobe_onnx::CappedAlloc;

fn main() -> ExitCode {
    let cli = commands::parse();
    match commands::run(cli) {
        Ok(()) => ExitCode::SUCCESS,
        Err(e) => {
            // Not `eprintln!`: it panics when stderr is closed or full (`2>/dev/full`).
            commands::note(&format!("error: {e:#}"));
            ExitCode::FAILURE
        }
    }
}
