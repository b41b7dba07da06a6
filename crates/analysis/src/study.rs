//! The trial files of a study directory, found through its layout
//! ([`fishprobe_io::StudyLayout`], the paper's public archive):
//!
//! ```text
//! STUDY/rollouts/<Policy>__<RolloutModel>/*.hdf5   e.g. Zone__Zone, Zone__Force, Zone__Real
//! STUDY/approach_test/<Policy>/*.hdf5             (or files naming their policy)
//! STUDY/approach_stability/<Model>/<seed>/*.hdf5   the assay of the extra seeds
//! STUDY/stability/<Model>/<seed>/*.hdf5
//! ```
//!
//! `Real` marks live trials; `VirtualLab` marks virtual-lab trials, used as the reality arm
//! when a policy has no `Real` trials. A bare rollouts directory (holding the condition
//! directories itself) is accepted too.

use crate::error::AnalysisError;
use fishprobe_io::{trial_files, StudyLayout};
use std::collections::BTreeMap;
use std::path::{Path, PathBuf};

pub use fishprobe_io::layout::REALITY_ARMS;

/// The trial files of a study, by condition.
#[derive(Debug, Clone, Default, PartialEq)]
pub struct StudyFiles {
    /// (policy, rollout model) → trial files, sorted by name.
    pub rollouts: BTreeMap<(String, String), Vec<PathBuf>>,
    /// Approach-assay files: policy (from the directory; empty when it must come from the
    /// file) → files.
    pub approach: BTreeMap<String, Vec<PathBuf>>,
    /// Approach-assay files of the extra training seeds: model → seed → files.
    pub approach_seeds: BTreeMap<String, BTreeMap<String, Vec<PathBuf>>>,
    /// Retraining stability: model → seed → files.
    pub stability: BTreeMap<String, BTreeMap<String, Vec<PathBuf>>>,
    /// Scripted baselines: model → controller → files (on the model's own evaluation episodes).
    pub baselines: BTreeMap<String, BTreeMap<String, Vec<PathBuf>>>,
}

fn subdirs(dir: &Path) -> Vec<PathBuf> {
    let mut v: Vec<PathBuf> = std::fs::read_dir(dir)
        .into_iter()
        .flatten()
        .filter_map(|e| e.ok().map(|e| e.path()))
        .filter(|p| p.is_dir())
        .collect();
    v.sort();
    v
}

/// `dir/<a>/<b>/*.hdf5` as a → b → files (none when `dir` is missing).
fn two_levels(dir: &Path) -> BTreeMap<String, BTreeMap<String, Vec<PathBuf>>> {
    subdirs(dir)
        .into_iter()
        .map(|a| {
            let inner = subdirs(&a)
                .into_iter()
                .map(|b| (name_of(&b), trial_files(&b)))
                .collect();
            (name_of(&a), inner)
        })
        .collect()
}

fn name_of(p: &Path) -> String {
    p.file_name()
        .map(|n| n.to_string_lossy().into_owned())
        .unwrap_or_default()
}

impl StudyFiles {
    /// Discovers the layout under `root`.
    pub fn discover(root: &Path) -> Result<Self, AnalysisError> {
        if !root.is_dir() {
            return Err(AnalysisError::Layout {
                path: root.to_path_buf(),
                what: "is not a directory".into(),
            });
        }
        let layout = StudyLayout::new(root);
        let rollouts_dir = if layout.rollouts().is_dir() {
            layout.rollouts()
        } else {
            root.to_path_buf()
        };
        let mut s = StudyFiles::default();
        for d in subdirs(&rollouts_dir) {
            if let Some((policy, arm)) = StudyLayout::parse_arm(&name_of(&d)) {
                s.rollouts
                    .insert((policy, arm.label().to_string()), trial_files(&d));
            }
        }
        let approach = layout.approach_root();
        if approach.is_dir() {
            let loose = trial_files(&approach);
            if !loose.is_empty() {
                s.approach.insert(String::new(), loose);
            }
            for d in subdirs(&approach) {
                s.approach.insert(name_of(&d), trial_files(&d));
            }
        }
        s.approach_seeds = two_levels(&layout.approach_stability_root());
        s.stability = two_levels(&layout.stability_root());
        s.baselines = two_levels(&layout.baselines_root());
        if s.rollouts.is_empty() && s.approach.is_empty() && s.stability.is_empty() {
            return Err(AnalysisError::Layout {
                path: root.to_path_buf(),
                what: "no rollouts/<Policy>__<Model>/ directories (nor approach_test/ or stability/) found".into(),
            });
        }
        Ok(s)
    }

    /// Policies with a sim condition on their own model, sorted.
    pub fn policies(&self) -> Vec<String> {
        let mut v: Vec<String> = self
            .rollouts
            .keys()
            .filter(|(p, m)| p == m)
            .map(|(p, _)| p.clone())
            .collect();
        v.dedup();
        v
    }

    /// The reality arm of the study: "Real" if any policy has real trials, else "VirtualLab"
    /// if any has virtual-lab trials.
    pub fn reality(&self) -> Option<&'static str> {
        REALITY_ARMS.into_iter().find(|arm| {
            self.rollouts
                .iter()
                .any(|((_, m), files)| m == arm && !files.is_empty())
        })
    }
}
