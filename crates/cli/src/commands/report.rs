//! `fishprobe report`: the figures and the self-contained HTML report of a study.

use anyhow::{Context, Result};
use clap::Args;
use fishprobe_report::{build_report, ReportConfig};
use std::path::PathBuf;
use std::time::Instant;

use super::emit;

#[derive(Debug, Args)]
pub struct ReportArgs {
    /// The study directory (`rollouts/`, `analysis/` from `fishprobe analyze`, optional
    /// `approach_test/` and `policies/`).
    study: PathBuf,
    /// Output directory (default: STUDY/report).
    #[arg(long)]
    out: Option<PathBuf>,
    /// Where `fishprobe analyze` wrote its results (default: STUDY/analysis).
    #[arg(long)]
    analysis: Option<PathBuf>,
    /// Report settings (TOML; the fields of `ReportConfig`, e.g. `trajectory_seconds = 60`).
    #[arg(long)]
    config: Option<PathBuf>,
    /// Threads (default: all cores).
    #[arg(long)]
    jobs: Option<usize>,
}

pub fn run(a: ReportArgs) -> Result<()> {
    let cfg: ReportConfig = match &a.config {
        Some(p) => super::read_toml(p, "report settings")?,
        None => ReportConfig::default(),
    };
    super::check_study_dir(&a.study)?;
    // A partial study gets a partial report; a directory with nothing of a study in it (a
    // mistyped path) gets an error, not a report of 0 figures written into it.
    let layout = fishprobe_io::StudyLayout::new(&a.study);
    let study_parts = [
        layout.config(),
        layout.results(),
        layout.policies_root(),
        layout.rollouts(),
        layout.approach_root(),
        layout.approach_stability_root(),
        layout.stability_root(),
        layout.baselines_root(),
    ];
    if a.analysis.is_none() && !study_parts.iter().any(|p| p.exists()) {
        anyhow::bail!(
            "{}: not a study directory (it holds none of study.json, analysis/results.json, \
             policies/, rollouts/, approach_test/, stability/); name the directory `fishprobe \
             run --out` wrote, or make one with `fishprobe run --out {}`",
            a.study.display(),
            a.study.display()
        );
    }
    let out_dir = a
        .out
        .clone()
        .unwrap_or_else(|| fishprobe_io::StudyLayout::new(&a.study).report());
    let _lock = super::lock_out(&out_dir, "report")?;
    let started = Instant::now();
    let out = super::with_jobs(a.jobs, || {
        build_report(&a.study, a.out.as_deref(), a.analysis.as_deref(), &cfg)
    })?
    .with_context(|| format!("making the report of {}", a.study.display()))?;
    let mut text = format!(
        "Wrote {} ({} figures, SVG and PNG in {}/figures) and {} in {:.1} s.\n",
        out.index.display(),
        out.figures.len(),
        out.index
            .parent()
            .map_or_else(String::new, |p| p.display().to_string()),
        out.summary.display(),
        started.elapsed().as_secs_f64()
    );
    if !out.missing.is_empty() {
        text += "\nNot in the report (inputs missing):\n";
        for m in &out.missing {
            text += &format!("  - {}: {}. To produce it: {}\n", m.what, m.why, m.remedy);
        }
    }
    for (p, why) in &out.unreadable {
        text += &format!("  - unreadable {}: {why}\n", p.display());
    }
    emit(&text)
}
