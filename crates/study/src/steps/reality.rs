//! The reality arm of a policy: its live trials copied from the study's real-trials
//! directory (checked to be of the study's policy), or the virtual lab's trials against an
//! in-process bridge.

use super::{Ctx, PolicySource, WARNING};
use crate::error::StepError;
use crate::store::{commit_dir, fresh, tmp_of};
use crate::Study;
use fishprobe_io::{Arm, StudyLayout};
use fishprobe_live::lab::{run_trial, LabConfig};
use fishprobe_live::server::{serve, BridgeGuard, ServeOptions};
use fishprobe_live::session::LiveConfig;
use serde::Serialize;
use std::collections::BTreeMap;
use std::path::{Path, PathBuf};

/// What a reality arm reads.
// One value per step of a plan: the size of the virtual lab's settings does not matter.
#[allow(clippy::large_enum_variant)]
#[derive(Debug, Clone, Serialize)]
#[serde(tag = "arm", rename_all = "snake_case")]
pub enum Inputs {
    /// Live trials.
    Real {
        /// The policy that must have driven them.
        policy: PolicySource,
        /// The directory of the policy's live trials (`<Policy>__Real/`).
        dir: PathBuf,
        /// Its files, by name and size: a trial added or replaced reruns the arm.
        trials: BTreeMap<String, String>,
    },
    /// The virtual lab.
    Virtual {
        /// The policy run.
        policy: PolicySource,
        /// The bridge's protocol (the study's trial length, fish per tank, observation).
        live: LiveConfig,
        /// The task (goals, radius).
        task: fishprobe_sim::TaskParams,
        /// The virtual lab's tracker and fish.
        lab: LabConfig,
        /// One seed per trial (derived from the master seed by policy and trial).
        seeds: Vec<u64>,
    },
}

pub(crate) fn inputs(study: &Study, p: usize) -> Inputs {
    let c = &study.cfg;
    let name = &c.models[p].name;
    let policy = PolicySource::of(study, p, 0);
    match &study.real {
        Some(r) => {
            let dir = r.join(StudyLayout::arm_dir_name(name, &Arm::Real));
            Inputs::Real {
                policy,
                trials: crate::manifest::manifest(&dir),
                dir,
            }
        }
        None => Inputs::Virtual {
            policy,
            live: LiveConfig {
                control_s: c.virtual_minutes * 60.0,
                fish_count: c.fish_count,
                centroid_bins: study.env.observation.centroid_bins,
                heading_bins: study.env.observation.heading_bins,
                ..LiveConfig::default()
            },
            task: study.env.task.clone(),
            lab: LabConfig::default(),
            seeds: (0..c.virtual_trials)
                .map(|k| fishprobe_sim::derive_seed(c.seed, &format!("virtual/{name}"), k as u64))
                .collect(),
        },
    }
}

pub(crate) fn run(i: &Inputs, cx: &mut Ctx) -> Result<(), StepError> {
    let out = cx.out.clone();
    let tmp = tmp_of(&out);
    fresh(&tmp)?;
    match i {
        Inputs::Real { policy, dir, .. } => real(policy, dir, &tmp, &out, cx),
        Inputs::Virtual {
            policy,
            live,
            task,
            lab,
            seeds,
        } => {
            // The virtual lab against an in-process bridge on a loopback port.
            let loopback = Path::new("127.0.0.1:0");
            let listener = std::net::TcpListener::bind("127.0.0.1:0")
                .map_err(|e| StepError::io("listening on", loopback, e))?;
            let addr = listener
                .local_addr()
                .map_err(|e| StepError::io("listening on", loopback, e))?;
            // The pilot under the study's name for its model, which names the arm.
            let name = policy.model().to_string();
            let ctl = fishprobe_learn::named(policy.load(&cx.layout)?, name.clone());
            let opts = ServeOptions {
                live: live.clone(),
                task: task.clone(),
                out: tmp.clone(),
                token: None,
                max_trials: Some(seeds.len()),
                fish_label: "virtual guppy".into(),
                guard: BridgeGuard::default(),
            };
            let bridge = std::thread::spawn(move || {
                let mut make = || Ok(ctl.boxed_clone());
                serve(&listener, &opts, &mut make, |_| {})
            });
            for (k, s) in seeds.iter().enumerate() {
                let t = run_trial(addr, lab, *s)?;
                (cx.say)(&format!("virtual trial {k}: {} goals", t.goals_reached));
                for w in &t.warnings {
                    (cx.say)(&format!("{WARNING}the bridge says: {w}"));
                }
            }
            bridge
                .join()
                .map_err(|_| StepError::Panicked("the bridge thread"))??;
            let made = tmp.join(StudyLayout::arm_dir_name(&name, &Arm::VirtualLab));
            commit_dir(&made, &out)?;
            std::fs::remove_dir_all(&tmp).map_err(|e| StepError::io("removing", &tmp, e))
        }
    }
}

/// Copies the live trials of `src`, which must be of the study's policy (not of one trained
/// under the same name before a retraining).
fn real(
    policy: &PolicySource,
    src: &Path,
    tmp: &Path,
    out: &Path,
    cx: &mut Ctx,
) -> Result<(), StepError> {
    let ctl = policy.load(&cx.layout)?;
    let name = policy.model();
    if let Some(sha) = ctl.fingerprint() {
        let prov = fishprobe_io::Provenance::of_dir(src, &sha);
        if let Some(why) = prov.describe_other(src, &sha) {
            return Err(StepError::Missing(format!(
                "{why}. The study's {name} policy ({}) did not drive them: record \
                 its live trials with that policy (`fishprobe live serve --policy` it), \
                 and keep other policies' trials out of the study's real trials",
                policy.shown(&cx.layout)
            )));
        }
        if !prov.unrecorded.is_empty() {
            (cx.say)(&format!(
                "{WARNING}{} of the live trials in {} do not record which weights drove \
                 them (written before fishprobe recorded it, or by another tool): they \
                 are taken as the study's {name} policy's",
                prov.unrecorded.len(),
                src.display()
            ));
        }
        for (f, e) in &prov.unreadable {
            (cx.say)(&format!(
                "{WARNING}{} cannot be read ({e}); the analysis will leave it out",
                f.display()
            ));
        }
    }
    let mut n = 0;
    for f in fishprobe_io::trial_files(src) {
        let to = tmp.join(f.file_name().unwrap_or_default());
        std::fs::copy(&f, &to).map_err(|e| StepError::io("copying", &f, e))?;
        n += 1;
    }
    if n == 0 {
        return Err(StepError::Missing(format!(
            "no trial files in {}",
            src.display()
        )));
    }
    (cx.say)(&format!("{n} live trials copied from {}", src.display()));
    commit_dir(tmp, out)
}
