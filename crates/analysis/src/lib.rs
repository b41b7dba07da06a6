//! The study's analysis (SPEC §8): from a directory of trial files, every measure and test of
//! the paper, as machine-readable results.
//!
//! ```no_run
//! use fishprobe_analysis::{analyze_dir, AnalysisConfig};
//!
//! let results = analyze_dir("study".as_ref(), &AnalysisConfig::default(), 0)?;
//! for (policy, gap) in &results.sim_to_real {
//!     println!("{policy}: W = {:.2}, p = {:.4}", gap.w, gap.p);
//! }
//! fishprobe_analysis::write_results("study/analysis".as_ref(), &results)?;
//! # Ok::<(), fishprobe_analysis::AnalysisError>(())
//! ```

#![warn(missing_docs)]

pub mod approach;
pub mod compare;
pub mod competence;
mod conditions;
pub mod config;
pub mod error;
pub mod metric;
pub mod offline;
pub mod ood;
pub mod results;
pub mod seeds;
pub mod spread;
pub mod study;
pub mod synth;
pub mod trial;

pub use compare::analyze;
pub use config::AnalysisConfig;
pub use error::AnalysisError;
pub use metric::{count_word, Metric, METRIC_LABELS, METRIC_TABLE};
pub use results::Results;
pub use study::StudyFiles;
pub use trial::{load_trial, TrialData, ALL_METRICS, GROUP_METRICS, METRICS};

use std::path::Path;

/// Discovers the study under `root` and analyses it.
pub fn analyze_dir(root: &Path, cfg: &AnalysisConfig, seed: u64) -> Result<Results, AnalysisError> {
    cfg.validate()?;
    let study = StudyFiles::discover(root)?;
    Ok(analyze(&study, cfg, seed))
}

/// Writes `results.json`, the CSV tables and `summary.md` into `dir` (each atomically).
pub fn write_results(dir: &Path, r: &Results) -> Result<(), AnalysisError> {
    let werr = |path: &Path, e: &dyn std::fmt::Display| AnalysisError::Write {
        path: path.to_path_buf(),
        what: e.to_string(),
    };
    let put = |name: &str, text: &str| -> Result<(), AnalysisError> {
        let p = dir.join(name);
        fishprobe_io::write_atomically(&p, text.as_bytes()).map_err(|e| werr(&p, &e))
    };
    let results = fishprobe_io::layout::RESULTS_FILE;
    let json = serde_json::to_string_pretty(r).map_err(|e| werr(&dir.join(results), &e))?;
    put(results, &json)?;
    for (name, text) in r.csv_tables() {
        put(name, &text)?;
    }
    put("summary.md", &r.summary_markdown())
}
