//! Figures and the HTML report of a fishprobe study (`fishprobe report STUDY`).
//!
//! Reads what the other steps left in the study directory — `analysis/results.json` from
//! `fishprobe analyze`, the trial files under `rollouts/` and `approach_test/`, the training
//! logs under `policies/` — and writes
//!
//! ```text
//! STUDY/report/index.html          one self-contained page (figures inlined, no network)
//! STUDY/report/summary.md          for terminals and lab notebooks
//! STUDY/report/figures/NAME.svg    for papers (text converted to outlines)
//! STUDY/report/figures/NAME.png    for slides
//! ```
//!
//! The figures follow the paper (goals reached; sim-to-real gap heatmap; sim-to-sim matrix;
//! robot-fish distance densities; approach assay; goals per minute with the negative-binomial
//! trend; example trajectories; training curves). Drawing is done by a small SVG kit
//! ([`svg`]) and rendered by `resvg` with a compiled-in font ([`render`]), so the output is
//! the same on every machine and needs no installed font. Colours are the Okabe-Ito palette
//! and viridis, every series is also told apart by marker or dash, so figures survive
//! greyscale printing and colour-vision deficiencies.
//!
//! Parts whose inputs are absent are listed in the report with the command that would
//! produce them; only a missing study directory is an error.
//!
//! ```no_run
//! use fishprobe_report::{build_report, ReportConfig};
//! let out = build_report("study".as_ref(), None, None, &ReportConfig::default())?;
//! println!("{} figures in {}", out.figures.len(), out.index.display());
//! # Ok::<(), fishprobe_report::ReportError>(())
//! ```

#![warn(missing_docs)]

pub mod config;
pub mod data;
pub mod error;
pub mod figures;
pub mod html;
pub mod offline;
pub mod render;
pub mod svg;

pub use config::ReportConfig;
pub use data::{gather, Missing, StudyData};
pub use error::ReportError;

use rayon::prelude::*;
use std::path::{Path, PathBuf};

/// What [`build_report`] wrote.
#[derive(Debug, Clone)]
pub struct ReportOutcome {
    /// `index.html`.
    pub index: PathBuf,
    /// `summary.md`.
    pub summary: PathBuf,
    /// Figure names made.
    pub figures: Vec<&'static str>,
    /// What the report could not show.
    pub missing: Vec<Missing>,
    /// Files that could not be read.
    pub unreadable: Vec<(PathBuf, String)>,
}

fn write(path: &Path, bytes: &[u8]) -> Result<(), ReportError> {
    fishprobe_io::write_atomically(path, bytes).map_err(|e| ReportError::Write {
        path: path.to_path_buf(),
        what: e.to_string(),
    })
}

/// Writes `dir/NAME.svg` (text as outlines) and `dir/NAME.png` (`png_scale` device pixels per
/// SVG pixel); returns the outlined SVG.
pub fn write_figure(
    f: &figures::Figure,
    dir: &Path,
    png_scale: f32,
) -> Result<String, ReportError> {
    let portable = render::portable_svg(&f.svg, f.name)?;
    let png = render::png(&f.svg, f.name, png_scale)?;
    write(&dir.join(format!("{}.svg", f.name)), portable.as_bytes())?;
    write(&dir.join(format!("{}.png", f.name)), &png)?;
    Ok(portable)
}

/// Every figure a study report can draw (which it draws depends on what the study holds).
pub const STUDY_FIGURES: [&str; 9] = [
    "goals",
    "gap_heatmap",
    "spread",
    "sim_to_sim",
    "goals_over_time",
    "approach",
    "iid_density",
    "trajectories",
    "training",
];

/// Removes the figures of an earlier report into the same directory that this one does not
/// draw (it no longer has their data), so that `figures/` shows only what `index.html` does.
/// Files of other names are left alone.
fn remove_stale_figures(
    fig_dir: &Path,
    rendered: &[(figures::Figure, String)],
) -> Result<(), ReportError> {
    for name in STUDY_FIGURES {
        if rendered.iter().any(|(f, _)| f.name == name) {
            continue;
        }
        for ext in ["svg", "png"] {
            let path = fig_dir.join(format!("{name}.{ext}"));
            match std::fs::remove_file(&path) {
                Err(e) if e.kind() != std::io::ErrorKind::NotFound => {
                    return Err(ReportError::Write {
                        path,
                        what: format!("removing an earlier report's figure: {e}"),
                    })
                }
                _ => {}
            }
        }
    }
    Ok(())
}

/// Makes the report of the study at `root` into `out` (default `root/report`), reading the
/// analysis from `analysis` (default `root/analysis`).
pub fn build_report(
    root: &Path,
    out: Option<&Path>,
    analysis: Option<&Path>,
    cfg: &ReportConfig,
) -> Result<ReportOutcome, ReportError> {
    cfg.validate()?;
    let layout = fishprobe_io::StudyLayout::new(root);
    let out = out.map_or_else(|| layout.report(), Path::to_path_buf);
    let analysis = analysis.map_or_else(|| layout.analysis(), Path::to_path_buf);
    let data = gather(root, &analysis, cfg)?;
    let figs: Vec<figures::Figure> = [
        figures::goals(&data),
        figures::gap_heatmap(&data),
        figures::spread(&data),
        figures::sim_to_sim(&data),
        figures::goals_over_time(&data),
        figures::approach(&data, cfg),
        figures::iid_density(&data, cfg),
        figures::trajectories(&data, cfg),
        figures::training(&data),
    ]
    .into_iter()
    .flatten()
    .collect();
    debug_assert!(figs.iter().all(|f| STUDY_FIGURES.contains(&f.name)));
    let fig_dir = out.join("figures");
    std::fs::create_dir_all(&fig_dir).map_err(|e| ReportError::Write {
        path: fig_dir.clone(),
        what: e.to_string(),
    })?;
    let rendered: Vec<(figures::Figure, String)> = figs
        .into_par_iter()
        .map(|f| {
            let portable = write_figure(&f, &fig_dir, cfg.png_scale)?;
            Ok((f, portable))
        })
        .collect::<Result<_, ReportError>>()?;
    remove_stale_figures(&fig_dir, &rendered)?;
    let page = html::Page {
        data: &data,
        figures: rendered,
        report_dir: &out,
        version: env!("CARGO_PKG_VERSION"),
    };
    let index = out.join("index.html");
    let summary = out.join("summary.md");
    write(&index, page.html().as_bytes())?;
    write(&summary, page.markdown().as_bytes())?;
    Ok(ReportOutcome {
        index,
        summary,
        figures: page.figures.iter().map(|(f, _)| f.name).collect(),
        missing: data.missing.clone(),
        unreadable: data.unreadable.clone(),
    })
}
