//! `fishprobe bench stats`: the study's analysis (statistics and metrics) on a study
//! directory, or on a synthetic one of the paper's size.

use super::{emit, machine, StudySizeArg};
use anyhow::{Context, Result};
use std::time::Instant;

pub(super) fn bench_stats(
    json: bool,
    dir: Option<std::path::PathBuf>,
    size: StudySizeArg,
    seed: u64,
) -> Result<()> {
    use fishprobe_analysis::synth::{generate, StudySize};
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
