//! A training run's folder: its names ([`RunLayout`]) and the header of its record
//! ([`RunRecord`], the part of `params.json` that says who trained what with which seed), for
//! the readers below the trainer (the report) that must not depend on it.
//!
//! ```text
//! RUN/params.json          the run's settings (fishprobe_learn::RunSpec); its header: RunRecord
//! RUN/progress.csv         one row per iteration
//! RUN/result.json          one JSON line per iteration
//! RUN/checkpoints/         ckpt_<iteration>/ and latest
//! RUN/policy.safetensors   the trained policy, when the run finished
//! ```

use serde::Deserialize;
use std::path::{Path, PathBuf};

/// Paths of a training run's folder.
#[derive(Debug, Clone, PartialEq, Eq)]
pub struct RunLayout {
    dir: PathBuf,
}

impl RunLayout {
    /// `params.json`: the run's settings.
    pub const PARAMS: &'static str = "params.json";
    /// `progress.csv`: one row per iteration.
    pub const PROGRESS: &'static str = "progress.csv";
    /// `result.json`: one JSON line per iteration.
    pub const RESULT: &'static str = "result.json";
    /// `checkpoints/`.
    pub const CHECKPOINTS: &'static str = "checkpoints";
    /// `policy.safetensors`: the trained policy.
    pub const POLICY: &'static str = "policy.safetensors";

    /// The layout of the run in `dir`.
    pub fn new(dir: impl Into<PathBuf>) -> Self {
        Self { dir: dir.into() }
    }

    /// The run's folder.
    pub fn dir(&self) -> &Path {
        &self.dir
    }

    /// `params.json`.
    pub fn params(&self) -> PathBuf {
        self.dir.join(Self::PARAMS)
    }

    /// `progress.csv`.
    pub fn progress(&self) -> PathBuf {
        self.dir.join(Self::PROGRESS)
    }

    /// `result.json`.
    pub fn result(&self) -> PathBuf {
        self.dir.join(Self::RESULT)
    }

    /// `checkpoints/`.
    pub fn checkpoints(&self) -> PathBuf {
        self.dir.join(Self::CHECKPOINTS)
    }

    /// `policy.safetensors`.
    pub fn policy(&self) -> PathBuf {
        self.dir.join(Self::POLICY)
    }

    /// Whether the folder holds a run (its `params.json`).
    pub fn holds_run(&self) -> bool {
        self.params().exists()
    }

    /// The header of the run's record, read (bounded) from `params.json`.
    pub fn record(&self) -> Result<RunRecord, crate::IoError> {
        let path = self.params();
        let text = crate::read_small_text(&path).map_err(|reason| crate::IoError::Read {
            path: path.clone(),
            reason,
        })?;
        serde_json::from_str(&text).map_err(|e| crate::IoError::Format {
            path,
            what: format!("not a training run's params.json: {e}"),
        })
    }
}

/// Who trained a run, from what and with which seed: the header of its `params.json` (whose
/// other fields, the PPO, environment and fish-model settings, only the trainer reads).
#[derive(Debug, Clone, PartialEq, Eq, Deserialize)]
pub struct RunRecord {
    /// The master seed (absent in other trainers' records, e.g. the RLlib `params.json` of the
    /// paper's archive, whose other fields are left out as unknown).
    #[serde(default)]
    pub seed: Option<u64>,
    /// The PPO preset the run started from.
    #[serde(default)]
    pub preset: String,
    /// The fishprobe version that started the run.
    #[serde(default)]
    pub program_version: String,
    /// The build that started the run (`fishprobe --version`; empty before builds were
    /// recorded).
    #[serde(default)]
    pub program_build: String,
    /// The trainer revision that started the run (0 before revisions were recorded).
    #[serde(default)]
    pub trainer_revision: u32,
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn the_record_is_read_from_params_json_and_other_files_are_refused() {
        let d = crate::ScratchDir::for_test("run-layout");
        let run = RunLayout::new(d.to_path_buf());
        assert!(!run.holds_run());
        std::fs::write(
            run.params(),
            r#"{"seed": 7, "preset": "paper", "program_version": "0.1.0", "ppo": {"lr": 1}}"#,
        )
        .unwrap();
        let r = run.record().unwrap();
        assert_eq!((r.seed, r.preset.as_str()), (Some(7), "paper"));
        assert_eq!((r.program_build.as_str(), r.trainer_revision), ("", 0));
        std::fs::write(run.params(), "[1, 2]").unwrap();
        let e = run.record().unwrap_err().to_string();
        assert!(
            e.contains("params.json") && e.contains("not a training run"),
            "{e}"
        );
        assert_eq!(run.policy(), d.join("policy.safetensors"));
    }
}
