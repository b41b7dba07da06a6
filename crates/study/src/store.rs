//! The store: completion markers (what a step depended on and what its output held), the one
//! way a step's output comes into place (a temporary directory renamed over the old output),
//! and the sweep that sets aside outputs no step of the current plan produces.

use crate::error::{StepError, StudyError};
use crate::plan::{Step, StepKind};
use crate::steps::MARKER_SCHEMA;
use crate::{manifest, Study};
use fishprobe_io::StudyLayout;
use std::path::{Path, PathBuf};

fn files_in(d: &Path) -> usize {
    fishprobe_io::trial_files(d).len()
}

/// Whether a step's output is there (a marker alone is not enough).
fn output_valid(study: &Study, s: &Step) -> bool {
    let out = study.output(&s.kind);
    let c = &study.cfg;
    match &s.kind {
        StepKind::FitConvnet => out.join("convnet.safetensors").is_file(),
        StepKind::Train { .. } => fishprobe_learn::run::RunLayout::new(out).policy().is_file(),
        StepKind::Eval { p, m } => files_in(&out) == study.eval_episodes(*p, *m),
        StepKind::Approach { .. } => files_in(&out) == c.approach_episodes,
        StepKind::Baseline { m } => fishprobe_sim::SCRIPTED.iter().all(|name| {
            fishprobe_sim::scripted(name)
                .is_some_and(|b| files_in(&out.join(b.name())) == study.eval_episodes(*m, *m))
        }),
        StepKind::Stability { .. } => files_in(&out) == c.stability_episodes,
        StepKind::Reality { .. } => files_in(&out) > 0,
        StepKind::Analyze => StudyLayout::results_in(&out).is_file(),
        StepKind::Report => out.join("index.html").is_file(),
    }
}

impl Study {
    fn marker(&self, s: &Step) -> PathBuf {
        self.layout().markers().join(format!("{}.json", s.id))
    }

    /// Whether a step is complete and valid: its marker's hash matches the step's inputs, its
    /// output is there, and the output holds exactly the files (names and sizes) the marker
    /// recorded when the step finished.
    pub fn is_complete(&self, s: &Step) -> bool {
        let Some(marker) = fishprobe_io::read_small_text(&self.marker(s))
            .ok()
            .and_then(|t| serde_json::from_str::<serde_json::Value>(&t).ok())
        else {
            return false;
        };
        let schema_ok = marker["schema"].as_u64() == Some(u64::from(MARKER_SCHEMA));
        let hash_ok = marker["hash"].as_str() == Some(format!("{:016x}", s.hash).as_str());
        schema_ok
            && hash_ok
            && output_valid(self, s)
            && manifest::matches(&marker, &manifest::manifest(&self.output(&s.kind)))
    }

    /// Whether a step's marker was written by an older fishprobe, whose markers held
    /// something else (another [`MARKER_SCHEMA`]): such a step is recomputed once.
    pub fn marked_by_older(&self, s: &Step) -> bool {
        fishprobe_io::read_small_text(&self.marker(s))
            .ok()
            .and_then(|t| serde_json::from_str::<serde_json::Value>(&t).ok())
            .is_some_and(|m| m["schema"].as_u64() != Some(u64::from(MARKER_SCHEMA)))
    }

    pub(crate) fn mark(&self, s: &Step, secs: f64) -> Result<(), StudyError> {
        let p = self.marker(s);
        let outputs = manifest::manifest(&self.output(&s.kind));
        let text = serde_json::json!({"schema": MARKER_SCHEMA, "step": s.id,
            "hash": format!("{:016x}", s.hash), "seconds": secs, "inputs": s.inputs,
            "outputs": outputs})
        .to_string();
        if let Some(d) = p.parent() {
            std::fs::create_dir_all(d).map_err(|e| StudyError::Io {
                path: d.to_path_buf(),
                what: e.to_string(),
            })?;
        }
        fishprobe_io::write_atomically(&p, text.as_bytes()).map_err(|e| StudyError::Io {
            path: p,
            what: e.to_string(),
        })
    }

    /// Writes `study.json`, the log directory, and moves stale outputs aside: what every run
    /// does before its first step.
    pub fn prepare(&self) -> Result<Vec<Step>, StudyError> {
        let steps = self.plan()?;
        let l = self.layout();
        std::fs::create_dir_all(l.logs()).map_err(|e| StudyError::Io {
            path: l.logs(),
            what: e.to_string(),
        })?;
        let cfg_text = serde_json::to_string_pretty(&self.cfg).unwrap_or_default();
        fishprobe_io::write_atomically(&l.config(), cfg_text.as_bytes()).map_err(|e| {
            StudyError::Io {
                path: l.config(),
                what: e.to_string(),
            }
        })?;
        self.sweep_stale(&steps)?;
        Ok(steps)
    }

    /// Moves outputs that no step of the current plan produces (another configuration's, or a
    /// killed step's `.partial` directory) out of the analysed tree, into `.fishprobe/stale/`,
    /// so that results of different configurations never mix.
    pub(crate) fn sweep_stale(&self, steps: &[Step]) -> Result<(), StudyError> {
        let wanted: std::collections::BTreeSet<PathBuf> =
            steps.iter().map(|s| self.output(&s.kind)).collect();
        let stale_root = self.layout().stale();
        let io = |path: &Path, e: std::io::Error| StudyError::Io {
            path: path.to_path_buf(),
            what: e.to_string(),
        };
        let mut candidates = Vec::new();
        for top in fishprobe_io::layout::STEP_OUTPUT_DIRS {
            let d = self.root.join(top);
            let Ok(rd) = std::fs::read_dir(&d) else {
                continue;
            };
            for e in rd.filter_map(|e| e.ok()) {
                let p = e.path();
                if !p.is_dir() {
                    continue;
                }
                if fishprobe_io::layout::SEEDED_DIRS.contains(&top) {
                    // Two levels: <Model>/seed<k>.
                    let Ok(inner) = std::fs::read_dir(&p) else {
                        continue;
                    };
                    let kids: Vec<PathBuf> = inner
                        .filter_map(|e| e.ok())
                        .map(|e| e.path())
                        .filter(|q| q.is_dir())
                        .collect();
                    candidates.extend(kids);
                } else {
                    candidates.push(p);
                }
            }
        }
        let l = self.layout();
        for p in [l.analysis(), l.report()] {
            candidates.push(tmp_of(&p));
        }
        for p in candidates
            .into_iter()
            .filter(|p| p.exists() && !wanted.contains(p))
        {
            let rel = p
                .strip_prefix(&self.root)
                .unwrap_or(&p)
                .display()
                .to_string()
                .replace(['/', '\\'], "--");
            std::fs::create_dir_all(&stale_root).map_err(|e| io(&stale_root, e))?;
            let mut to = stale_root.join(&rel);
            let mut n = 1;
            while to.exists() {
                to = stale_root.join(format!("{rel}.{n}"));
                n += 1;
            }
            std::fs::rename(&p, &to).map_err(|e| io(&p, e))?;
        }
        Ok(())
    }

    /// A step's log file.
    pub fn log_path(&self, s: &Step) -> PathBuf {
        self.layout().logs().join(format!("{}.log", s.id))
    }
}

/// The temporary directory a step writes into before its output is committed: `<out>.partial`.
pub(crate) fn tmp_of(out: &Path) -> PathBuf {
    let mut s = out.as_os_str().to_owned();
    s.push(".partial");
    PathBuf::from(s)
}

/// Makes `dir` a fresh, empty directory.
pub(crate) fn fresh(dir: &Path) -> Result<(), StepError> {
    if dir.exists() {
        std::fs::remove_dir_all(dir).map_err(|e| StepError::io("removing", dir, e))?;
    }
    std::fs::create_dir_all(dir).map_err(|e| StepError::io("creating", dir, e))
}

/// Moves a finished temporary directory into place (replacing an older output).
pub(crate) fn commit_dir(tmp: &Path, out: &Path) -> Result<(), StepError> {
    if out.exists() {
        std::fs::remove_dir_all(out).map_err(|e| StepError::io("removing", out, e))?;
    }
    if let Some(p) = out.parent() {
        std::fs::create_dir_all(p).map_err(|e| StepError::io("creating", p, e))?;
    }
    std::fs::rename(tmp, out)
        .map_err(|e| StepError::io(&format!("moving {} to", tmp.display()), out, e))
}

/// Runs `work` on a fresh `<out>.partial` directory and, if it succeeds, renames that over
/// `out`: a step's output is never seen half-written, and a killed step leaves only a
/// `.partial` directory, which the next run's sweep sets aside.
pub(crate) fn staged(
    out: &Path,
    work: impl FnOnce(&Path) -> Result<(), StepError>,
) -> Result<(), StepError> {
    let tmp = tmp_of(out);
    fresh(&tmp)?;
    work(&tmp)?;
    commit_dir(&tmp, out)
}
