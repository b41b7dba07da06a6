//! `fishprobe analyze`: every measure and test of SPEC §8 from a study directory.

use anyhow::{Context, Result};
use clap::Args;
use fishprobe_analysis::{analyze_dir, write_results, AnalysisConfig};
use std::path::PathBuf;
use std::time::Instant;

use super::emit;

#[derive(Debug, Args)]
pub struct AnalyzeArgs {
    /// The study directory (`rollouts/<Policy>__<Model>/`, optional `approach_test/` and
    /// `stability/<Model>/<seed>/`), or a bare rollouts directory.
    study: PathBuf,
    /// Output directory (default: STUDY/analysis).
    #[arg(long)]
    out: Option<PathBuf>,
    /// Master seed of the resampling.
    #[arg(long, default_value_t = 0)]
    seed: u64,
    /// Threads (default: all cores). Results do not depend on it.
    #[arg(long)]
    jobs: Option<usize>,
    /// Sim trials per policy for the sim-to-real comparison (first N files by name).
    #[arg(long)]
    sim_trials: Option<usize>,
    /// Fewer bootstrap replicates and permutations (for a quick look; same statistics).
    #[arg(long)]
    quick: bool,
    /// A TOML file whose `[analysis]` table replaces analysis settings by name (e.g.
    /// `competence_threshold = 0.9`, `approach_closest_cm = 4`; the list is in
    /// docs/settings.md). A study file works: its other keys are ignored.
    #[arg(long)]
    settings: Option<PathBuf>,
}

pub fn run(a: AnalyzeArgs) -> Result<()> {
    let mut cfg = if a.quick {
        AnalysisConfig::quick()
    } else {
        AnalysisConfig::default()
    };
    if let Some(n) = a.sim_trials {
        cfg.sim_trials = n;
    }
    if let Some(p) = &a.settings {
        cfg = super::analysis_settings(&cfg, p)?;
    }
    super::check_study_dir(&a.study)?;
    let out = a
        .out
        .clone()
        .unwrap_or_else(|| fishprobe_io::StudyLayout::new(&a.study).analysis());
    let _lock = super::lock_out(&out, "analyze")?;
    let started = Instant::now();
    let results = super::with_jobs(a.jobs, || analyze_dir(&a.study, &cfg, a.seed))?
        .with_context(|| format!("analysing {}", a.study.display()))?;
    write_results(&out, &results)?;
    let mut text = results.summary_markdown();
    text += &format!(
        "\nWrote {}/results.json, CSV tables and summary.md in {:.1} s.\n",
        out.display(),
        started.elapsed().as_secs_f64()
    );
    emit(&text)
}
