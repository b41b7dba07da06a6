//! Which policy drove a trial. A trial file names its policy (`Zone`), but a policy retrained
//! under the same name keeps the name: trials of the old and the new one would land in one
//! `<Policy>__Real/` directory and be counted as one policy's. So fishprobe records, in the
//! task's `config_json`, the SHA-256 of what decided the robot's actions (a trained policy's
//! weights, an ONNX file: `Controller::fingerprint`), and checks it where trials are added to
//! a directory (the live bridge) or taken into a study (its reality step).

use crate::{read_trial, trial_files, TaskRecord};
use std::path::{Path, PathBuf};

/// The key of `config_json` under which a trial records its policy's fingerprint.
pub const POLICY_SHA256_KEY: &str = "policy_sha256";

impl TaskRecord {
    /// The recorded fingerprint of the policy that drove this trial (`None`: not recorded,
    /// e.g. a scripted controller, or a file written before fishprobe recorded it).
    pub fn policy_sha256(&self) -> Option<String> {
        let v: serde_json::Value = serde_json::from_str(&self.config_json).ok()?;
        v.get(POLICY_SHA256_KEY)?.as_str().map(str::to_string)
    }
}

/// The trial files of a directory sorted by the policy that drove them, against one
/// fingerprint.
#[derive(Debug, Default, Clone, PartialEq, Eq)]
pub struct Provenance {
    /// Trials recorded with the fingerprint.
    pub same: Vec<PathBuf>,
    /// Trials recording no fingerprint.
    pub unrecorded: Vec<PathBuf>,
    /// Trials of another policy, with the fingerprint they record.
    pub other: Vec<(PathBuf, String)>,
    /// Files that cannot be read as trial files, with the reason: which policy drove them
    /// cannot be told.
    pub unreadable: Vec<(PathBuf, String)>,
}

impl Provenance {
    /// Sorts the trial files of `dir` (none if it does not exist) by whether they were
    /// driven by the policy with fingerprint `sha256`.
    pub fn of_dir(dir: &Path, sha256: &str) -> Self {
        let mut p = Self::default();
        for f in trial_files(dir) {
            match read_trial(&f).map(|t| t.task.and_then(|t| t.policy_sha256())) {
                Ok(Some(s)) if s == sha256 => p.same.push(f),
                Ok(Some(s)) => p.other.push((f, s)),
                Ok(None) => p.unrecorded.push(f),
                Err(e) => p.unreadable.push((f, e.to_string())),
            }
        }
        p
    }

    /// A sentence naming the trials of another policy (at most three by name), or `None`
    /// if there are none.
    pub fn describe_other(&self, dir: &Path, sha256: &str) -> Option<String> {
        let ((first, theirs), rest) = self.other.split_first()?;
        let names: Vec<String> = std::iter::once(first)
            .chain(rest.iter().map(|(f, _)| f))
            .take(3)
            .map(|f| {
                f.file_name()
                    .map_or_else(|| f.display().to_string(), |n| n.to_string_lossy().into())
            })
            .collect();
        let more = if self.other.len() > 3 {
            format!(" and {} more", self.other.len() - 3)
        } else {
            String::new()
        };
        Some(format!(
            "{} holds {} trial(s) of another policy under the same name ({}{more}: weights \
             sha256 {}…, this policy's {}…): a policy retrained since, or another one",
            dir.display(),
            self.other.len(),
            names.join(", "),
            short_sha(theirs),
            short_sha(sha256),
        ))
    }
}

/// A fingerprint's first twelve digits, as messages show it (followed by `…`).
pub fn short_sha(sha: &str) -> &str {
    sha.get(..12).unwrap_or(sha)
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::{Category, Entity, TrialFile, TrialKind};
    use std::collections::BTreeMap;

    fn trial(config_json: Option<&str>) -> TrialFile {
        TrialFile {
            world_size_cm: [100.0, 100.0],
            frame_rate_hz: 25.0,
            entities: vec![Entity {
                name: "robot".into(),
                category: Category::Robot,
                category_label: "robot".into(),
                positions: vec![[50.0, 50.0]; 4],
                orientations: vec![[1.0, 0.0]; 4],
                attributes: BTreeMap::new(),
            }],
            attributes: BTreeMap::new(),
            task: config_json.map(|c| TaskRecord {
                kind: TrialKind::Real,
                policy: "Zone".into(),
                fish_model: "live".into(),
                seed: 0,
                goal_radius_cm: 10.0,
                goals: vec![],
                active_goal: vec![-1; 4],
                goal_frames: vec![],
                command_frames: vec![],
                command_turns: vec![],
                control_start_frame: 0,
                config_json: c.into(),
                program_version: "test".into(),
            }),
        }
    }

    #[test]
    fn trials_are_sorted_by_the_weights_that_drove_them() {
        let d = crate::ScratchDir::for_test("provenance");
        let dir: &Path = &d;
        // A missing directory holds nothing.
        assert_eq!(
            Provenance::of_dir(&dir.join("none"), "aa"),
            Provenance::default()
        );
        let files = [
            ("trial_000.hdf5", Some(r#"{"policy_sha256": "aa"}"#)),
            (
                "trial_001.hdf5",
                Some(r#"{"policy_sha256": "bb0123456789abcdef"}"#),
            ),
            ("trial_002.hdf5", Some(r#"{"live": {}}"#)),
            ("trial_003.hdf5", Some("not json")),
            ("trial_004.hdf5", None),
        ];
        for (name, c) in files {
            crate::write_trial(&dir.join(name), &trial(c)).unwrap();
        }
        let p = Provenance::of_dir(dir, "aa");
        assert_eq!(p.same, vec![dir.join("trial_000.hdf5")]);
        assert_eq!(
            p.other,
            vec![(dir.join("trial_001.hdf5"), "bb0123456789abcdef".to_string())]
        );
        assert_eq!(p.unrecorded.len(), 3);
        let msg = p.describe_other(dir, "aa").unwrap();
        assert!(
            msg.contains("1 trial(s) of another policy")
                && msg.contains("trial_001.hdf5")
                && msg.contains("bb0123456789…")
                && !msg.contains("bb0123456789a"),
            "{msg}"
        );
        assert!(Provenance::of_dir(dir, "bb0123456789abcdef")
            .describe_other(dir, "x")
            .is_some());
        // An unreadable trial file is listed with its reason, not taken for either.
        std::fs::write(dir.join("trial_005.hdf5"), b"not hdf5").unwrap();
        let p = Provenance::of_dir(dir, "aa");
        assert_eq!(p.unreadable.len(), 1);
        assert_eq!(p.unreadable[0].0, dir.join("trial_005.hdf5"));
        assert_eq!((p.same.len(), p.other.len(), p.unrecorded.len()), (1, 1, 3));
    }
}
