//! The research commands (`fidelity`, `collective`, `support`, `ood-report`, `ood-loop`):
//! their work is [`fishprobe_study::research`]; here they are parsed, called and printed.

use super::{emit, note, resolve_jobs, BUILD};
use anyhow::Result;
use clap::Args;
use fishprobe_study::research::{self, ood_loop::OodLoopConfig, Runner};
use std::path::PathBuf;

/// The command line as typed, recorded with what a command writes.
fn command_line() -> String {
    std::iter::once("fishprobe".to_string())
        .chain(std::env::args().skip(1))
        .collect::<Vec<_>>()
        .join(" ")
}

/// Runs `work` with this build, this command line and stderr for its progress lines.
fn with_runner<T>(work: impl FnOnce(Runner) -> T) -> T {
    let command = command_line();
    let notes = |line: &str| note(line);
    work(Runner {
        build: BUILD,
        command: &command,
        notes: &notes,
    })
}

/// `fishprobe fidelity`.
pub fn fidelity(mut a: research::fidelity::FidelityArgs) -> Result<()> {
    a.jobs = resolve_jobs(a.jobs)?;
    emit(&with_runner(|by| research::fidelity::run(&a, by))?)
}

/// `fishprobe collective`, with a progress bar over its runs.
pub fn collective(a: research::collective::CollectiveArgs) -> Result<()> {
    use indicatif::{ProgressBar, ProgressStyle};
    let bar = ProgressBar::new(0);
    bar.set_style(
        ProgressStyle::with_template("{spinner} [{elapsed_precise}] {bar:30} run {pos}/{len}")
            .unwrap_or_else(|_| ProgressStyle::default_bar()),
    );
    let progress = |done: u64, total: u64| {
        bar.set_length(total);
        bar.set_position(done);
    };
    let text = research::collective::run(&a, &progress);
    bar.finish_and_clear();
    emit(&text?)
}

/// `fishprobe support`.
pub fn support(a: research::support::SupportArgs) -> Result<()> {
    emit(&with_runner(|by| research::support::run(&a, by))?)
}

/// `fishprobe ood-report`.
pub fn ood_report(a: research::ood_report::OodReportArgs) -> Result<()> {
    emit(&with_runner(|by| research::ood_report::run(&a, by))?)
}

/// The flags of `fishprobe ood-loop`.
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

/// `fishprobe ood-loop`.
pub fn ood_loop(a: OodLoopArgs) -> Result<()> {
    let cfg: OodLoopConfig = match &a.config {
        Some(p) => super::read_toml(p, "settings")?,
        None => OodLoopConfig::default(),
    };
    emit(&with_runner(|by| {
        research::ood_loop::run(&a.out, &a.seeds, &cfg, by)
    })?)
}
