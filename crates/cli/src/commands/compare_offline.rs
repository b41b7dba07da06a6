//! `fishprobe compare-offline`: model pairs vs recorded pairs of live guppies, and model fish
//! beside a recorded robot's path (open loop) vs the live fish of robot recordings.

use anyhow::{bail, Context, Result};
use clap::Args;
use fishprobe_analysis::offline::{compare_offline, read_recordings, OfflineConfig};
use fishprobe_io::read_any_trial;
use fishprobe_learn::bc::list_files;
use fishprobe_models::ModelSpec;
use fishprobe_report::offline::offline_figures;
use std::path::PathBuf;

use super::emit;

#[derive(Debug, Args)]
pub struct CompareOfflineArgs {
    /// Real recordings: directories or files (robofish.io or legacy) of pairs of live fish,
    /// or of one live fish beside the robot (compared open loop: the robot's recorded path
    /// replayed, each model's fish reacting to it). Default:
    /// guppy-pairs/legacy/validation of the shared data ($FISHPROBE_DATA).
    #[arg(long, num_args = 1..)]
    data: Vec<PathBuf>,
    /// Output directory: offline.json, offline.md, the CSV tables (offline.csv,
    /// offline_spread.csv, offline_recordings.csv, offline_correlations.csv) and the figures.
    #[arg(long)]
    out: PathBuf,
    /// Models to compare (names, comma-separated).
    #[arg(
        long,
        value_delimiter = ',',
        default_value = "Follow,Zone,Force,ConvNet"
    )]
    models: Vec<String>,
    /// Weights for M_ConvNet (default: the shipped weights).
    #[arg(long)]
    convnet_weights: Option<PathBuf>,
    /// Master seed (simulations and bootstrap).
    #[arg(long, default_value_t = 0)]
    seed: u64,
    /// Bootstrap replicates.
    #[arg(long)]
    reps: Option<usize>,
    /// Simulations of each recording per model (default 1): more make a model's side less a
    /// matter of its random draws.
    #[arg(long)]
    replicates: Option<usize>,
    /// Threads (default: all cores). Results do not depend on it.
    #[arg(long)]
    jobs: Option<usize>,
}

pub fn run(a: CompareOfflineArgs) -> Result<()> {
    super::no_repeats("--models", &a.models)?;
    let mut cfg = OfflineConfig::default();
    if let Some(r) = a.reps {
        cfg.bootstrap_reps = r;
    }
    if let Some(r) = a.replicates {
        cfg.replicates = r;
    }
    cfg.validate()?;
    let data = if a.data.is_empty() {
        let d = fishprobe_io::shared_data_dir()
            .context("no --data given and no shared data found (set FISHPROBE_DATA)")?;
        vec![d.join("guppy-pairs/legacy/validation")]
    } else {
        a.data.clone()
    };
    let mut models = Vec::new();
    for name in &a.models {
        let mut spec = ModelSpec::by_name(name)?;
        if let (ModelSpec::ConvNet(p), Some(w)) = (&mut spec, &a.convnet_weights) {
            p.weights = w.display().to_string();
        }
        spec.build().with_context(|| format!("model {name}"))?;
        models.push((spec.label(), spec));
    }
    let files = list_files(&data);
    if files.is_empty() {
        bail!(
            "no trial files in {}",
            data.iter()
                .map(|p| p.display().to_string())
                .collect::<Vec<_>>()
                .join(", ")
        );
    }
    let res = super::with_jobs(a.jobs, || -> Result<_> {
        let (real, skipped) = read_recordings(&files, read_any_trial, &cfg);
        for (f, why) in &skipped {
            say!("warning: skipped {f}: {why}");
        }
        compare_offline(&real, skipped, &models, &cfg, a.seed).map_err(anyhow::Error::from)
    })??;
    std::fs::create_dir_all(&a.out).with_context(|| format!("creating {}", a.out.display()))?;
    let _lock = super::lock_out(&a.out, "compare-offline")?;
    let put = |name: &str, text: &str| -> Result<()> {
        let p = a.out.join(name);
        fishprobe_io::write_atomically(&p, text.as_bytes())
            .with_context(|| format!("writing {}", p.display()))
    };
    put("offline.json", &serde_json::to_string_pretty(&res)?)?;
    let mut written = vec!["offline.json".to_string(), "offline.md".to_string()];
    for (name, text) in res.csv_tables() {
        put(name, &text)?;
        written.push(name.to_string());
    }
    let tables = res.markdown();
    let n = res.pairs.recordings.len() + res.open_loop.as_ref().map_or(0, |o| o.recordings.len());
    put(
        "offline.md",
        &format!("# Offline comparison: models against {n} real recordings\n\n{tables}"),
    )?;
    for f in offline_figures(&res) {
        fishprobe_report::write_figure(&f, &a.out, 2.0)?;
        written.push(format!("{}.svg/.png", f.name));
    }
    emit(&format!(
        "{n} real recordings ({} pairs, {} with the robot):\n\n{tables}wrote {}: {}\n",
        res.pairs.recordings.len(),
        res.open_loop.as_ref().map_or(0, |o| o.recordings.len()),
        a.out.display(),
        written.join(", ")
    ))
}
