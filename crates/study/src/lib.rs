//! The whole study in one command (`fishprobe run`): train one policy per model (and more
//! seeds for the stability analysis), evaluate every policy on every model, run the approach
//! assay and the stability episodes, collect the reality arm (live trials from a directory, or
//! the virtual lab through the live bridge), analyse and report — resumably and in parallel.
//!
//! The study directory has the layout of the paper's public archive, which `fishprobe analyze`
//! and `fishprobe report` read:
//!
//! ```text
//! STUDY/study.json                      the resolved configuration
//! STUDY/policies/<Model>/               training runs (params.json, progress.csv, checkpoints, policy)
//! STUDY/policies_stability/<Model>/seed<k>/   the extra seeds
//! STUDY/rollouts/<Policy>__<Model>/     evaluation episodes; <Policy>__Real or __VirtualLab
//! STUDY/approach_test/<Policy>/         approach-assay episodes
//! STUDY/stability/<Model>/seed<k>/      stability episodes
//! STUDY/analysis/, STUDY/report/        results and report
//! STUDY/logs/<step>.log                 one log per step
//! STUDY/.fishprobe/done/<step>.json     completion markers
//! ```
//!
//! **Resumable.** Every step writes its outputs into a temporary directory renamed into place,
//! then records a marker holding the hash of everything the step depends on (its settings and
//! the hashes of the steps it uses) and what its output holds. A rerun skips steps whose marker
//! matches and whose output is as recorded, redoes the others, and so never mixes results of different configurations: a changed
//! setting invalidates exactly the steps downstream of it. Training runs resume from their last
//! checkpoint and end byte-identical to an uninterrupted run (`fishprobe_learn::Trainer`).
//!
//! **Parallel.** Independent steps run concurrently, up to `jobs` at once, each on its own
//! thread pool.
//!
//! The engine in rooms: [`plan`] (the step kinds, their ids and outputs, and the wiring of
//! dependencies), [`steps`] (one file per kind: the typed inputs it reads, hashed whole, and
//! its work, which gets nothing else), `store` (markers, staged outputs, the stale sweep),
//! `scheduler` (local runs), [`slurm`] (SLURM job arrays); errors are typed
//! ([`StudyError`], [`StepError`]). The directory's names come from
//! [`fishprobe_io::StudyLayout`].

#![warn(missing_docs)]

pub mod config;
mod error;
mod manifest;
pub mod plan;
mod scheduler;
pub mod slurm;
pub mod steps;
mod store;

pub use config::{Budget, NamedModel, StudyConfig, StudyFile};
pub use error::{StepError, StudyError};
pub use plan::{Step, StepKind};
pub use scheduler::Event;
pub use steps::{StepInputs, MARKER_SCHEMA};

use fishprobe_io::{Arm, StudyLayout};
use std::path::PathBuf;

/// The study: its directory, configuration and reality arm.
#[derive(Debug, Clone)]
pub struct Study {
    /// The study directory.
    pub root: PathBuf,
    /// The configuration.
    pub cfg: StudyConfig,
    /// Live trials (`<Policy>__Real/` directories), if any.
    pub real: Option<PathBuf>,
    /// Pair recordings (`train/` and `validation/`) to refit M_ConvNet on, if any.
    pub convnet_data: Option<PathBuf>,
    /// The environment of the study's trainings and trials ([`StudyConfig::env`], resolved
    /// and checked once).
    pub env: fishprobe_sim::EnvConfig,
    /// The fishprobe build running the study, recorded with what it fits (the CLI sets its
    /// `--version`; default: the version alone).
    pub program_build: String,
}

impl Study {
    /// Checks everything that can be checked before expensive work: the configuration, and the
    /// real-trials directory (it exists, and holds `<Policy>__Real/` for exactly the study's
    /// policies).
    pub fn new(root: PathBuf, cfg: StudyConfig, real: Option<PathBuf>) -> Result<Self, StudyError> {
        Self::with_convnet_data(root, cfg, real, None)
    }

    /// Like [`Study::new`], with M_ConvNet refitted on `convnet_data` (which must hold
    /// `train/` and `validation/` pair recordings) instead of the shipped weights.
    pub fn with_convnet_data(
        root: PathBuf,
        mut cfg: StudyConfig,
        real: Option<PathBuf>,
        convnet_data: Option<PathBuf>,
    ) -> Result<Self, StudyError> {
        cfg.validate()?;
        let env = cfg.env()?;
        if let Some(d) = &convnet_data {
            for sub in ["train", "validation"] {
                if !d.join(sub).is_dir() {
                    return Err(StudyError::Input(format!(
                        "the ConvNet fitting data {}: needs {sub}/ with pair recordings",
                        d.display()
                    )));
                }
            }
            // Every ConvNet model without weights of its own uses the refitted ones.
            let weights = StudyLayout::new(&root)
                .convnet()
                .join("convnet.safetensors");
            for m in &mut cfg.models {
                if let fishprobe_models::ModelSpec::ConvNet(p) = &mut m.spec {
                    if p.weights.is_empty() {
                        p.weights = weights.display().to_string();
                    }
                }
            }
        }
        // Policies trained elsewhere must load (and read the study's observations) now, not
        // hours into the study.
        for (model, arg) in &cfg.policies {
            let c = fishprobe_learn::controller(arg, false)
                .map_err(|e| StudyError::Input(format!("the policy for `{model}` ({arg}): {e}")))?;
            c.check_observation(env.observation.size())
                .map_err(|e| StudyError::Input(format!("the policy for `{model}`: {e}")))?;
        }
        if let Some(r) = &real {
            if !r.is_dir() {
                let what = if r.exists() {
                    "is not a directory (it holds <Policy>__Real/ with the live trials)"
                } else {
                    "does not exist"
                };
                return Err(StudyError::Input(format!(
                    "real-trials directory {} {what}",
                    r.display()
                )));
            }
            let mut found: Vec<String> = std::fs::read_dir(r)
                .map_err(|e| StudyError::Input(format!("{}: {e}", r.display())))?
                .filter_map(|e| e.ok())
                .filter(|e| e.path().is_dir())
                .filter_map(
                    |e| match StudyLayout::parse_arm(&e.file_name().to_string_lossy()) {
                        Some((policy, Arm::Real)) => Some(policy),
                        _ => None,
                    },
                )
                .collect();
            found.sort();
            let mut want: Vec<String> = cfg.models.iter().map(|m| m.name.clone()).collect();
            want.sort();
            if found != want {
                return Err(StudyError::Input(format!(
                    "the real trials in {} are for policies [{}], the study trains [{}]: each policy needs a <Policy>__Real/ directory and nothing else",
                    r.display(),
                    found.join(", "),
                    want.join(", ")
                )));
            }
        }
        Ok(Self {
            root,
            cfg,
            real,
            convnet_data,
            env,
            program_build: env!("CARGO_PKG_VERSION").into(),
        })
    }

    fn name(&self, i: usize) -> &str {
        &self.cfg.models[i].name
    }

    /// The policy trained elsewhere for model `m`, if the study file names one.
    pub fn external_policy(&self, m: usize) -> Option<&str> {
        self.cfg.policies.get(self.name(m)).map(String::as_str)
    }

    /// The study directory's paths.
    pub fn layout(&self) -> StudyLayout {
        StudyLayout::new(&self.root)
    }

    /// The reality arm this study collects: live trials with `--real`, else the virtual lab.
    pub fn reality_arm(&self) -> Arm {
        if self.real.is_some() {
            Arm::Real
        } else {
            Arm::VirtualLab
        }
    }

    /// Episodes of a sim cell: the own-model cell also serves sim-to-real.
    pub fn eval_episodes(&self, p: usize, m: usize) -> usize {
        if p == m {
            self.cfg.cross_episodes.max(self.cfg.sim_trials)
        } else {
            self.cfg.cross_episodes
        }
    }
}

/// The SHA-256 of a policy trained elsewhere (`onnx:PATH`: the file; a directory: its
/// `policy.safetensors`), so that a changed file invalidates every step that ran it.
pub(crate) fn external_policy_sha256(arg: &str) -> String {
    match fishprobe_learn::PolicyArg::parse(arg).sha256() {
        Ok(sha) => sha.unwrap_or_else(|| "scripted".into()),
        Err(e) => format!("unreadable: {e}"),
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn real_trials_must_match_the_policies() {
        let d = std::env::temp_dir().join(format!("fishprobe-study-real-{}", std::process::id()));
        let _ = std::fs::remove_dir_all(&d);
        std::fs::create_dir_all(d.join("Zone__Real")).unwrap();
        let e = Study::new(
            "/tmp/x".into(),
            StudyConfig::preset("smoke").unwrap(),
            Some(d.clone()),
        )
        .unwrap_err();
        assert!(e.to_string().contains("Follow"), "{e}");
        let e = Study::new(
            "/tmp/x".into(),
            StudyConfig::preset("smoke").unwrap(),
            Some(d.join("nope")),
        )
        .unwrap_err();
        assert!(e.to_string().contains("does not exist"), "{e}");
        let _ = std::fs::remove_dir_all(&d);
    }
}
