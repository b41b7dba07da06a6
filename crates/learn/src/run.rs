//! The training-run contract: the folder's names ([`RunLayout`]), its record (`params.json`,
//! [`RunSpec`]; its header [`fishprobe_io::RunRecord`] for readers below the trainer), and
//! [`open`], which decides for every caller (the study's steps, the research commands,
//! `fishprobe train`, the Python package) what a folder means for the run it asks for: start,
//! resume, restart or refuse, with one message per outcome.
//!
//! Every caller trains through one function, [`train_to_end`]: open the folder (start,
//! resume or restart, as its [`Begin`] says), iterate with the caller's progress
//! ([`TrainHooks`]), finish.
//!
//! ```no_run
//! use fishprobe_learn::run::{train_to_end, Begin, OnOther};
//! # fn spec() -> fishprobe_learn::RunSpec { unimplemented!() }
//! let dir = std::path::Path::new("runs/zone");
//! let (trainer, policy) =
//!     train_to_end(dir, Begin::StartOrResume(spec(), OnOther::Refuse), "0.1.0", &mut ())?;
//! # Ok::<(), fishprobe_learn::LearnError>(())
//! ```

use crate::{IterationStats, LearnError, RunSpec, Trainer};
pub use fishprobe_io::{RunLayout, RunRecord};
use std::path::{Path, PathBuf};

/// What [`train_to_end`] is asked to do with a folder.
#[derive(Debug)]
pub enum Begin {
    /// This run: resumed when the folder holds it, started when it holds none; a folder of
    /// another run as [`OnOther`] says (the study's steps, fidelity, the OOD loop).
    StartOrResume(RunSpec, OnOther),
    /// A new run: a folder that already holds this very run is refused, the message ending
    /// with how to continue it; one of another run is refused (`fishprobe train`, Python).
    Start(RunSpec, &'static str),
    /// The run the folder holds, continued as its record says (`train --resume`, Python's
    /// `resume=True`).
    Resume,
}

/// How [`train_to_end`] opened the run.
#[derive(Debug, Clone, PartialEq, Eq)]
pub enum Opened {
    /// Started in a folder without a run.
    Started,
    /// Continued from its last checkpoint (a finished run is done at once).
    Resumed,
    /// Another run was there and is deleted ([`OnOther::Restart`]); this one started.
    Restarted {
        /// What differed.
        was: String,
    },
}

/// What a caller adds to [`train_to_end`]; every method has the plain default, and `()`
/// takes them all.
pub trait TrainHooks {
    /// Creates the new run (default: [`Trainer::create`]; a caller with a yardstick to measure
    /// first, or a fish model only it can build, brings its own).
    fn create(&mut self, dir: &Path, spec: RunSpec) -> Result<Trainer, LearnError> {
        Trainer::create(dir, spec)
    }
    /// Reopens the recorded run (default: [`Trainer::resume`] under `build`).
    fn resume(&mut self, dir: &Path, build: &str) -> Result<Trainer, LearnError> {
        Trainer::resume(dir, build)
    }
    /// Once the run is open, before it trains on (notes for the user, a progress bar).
    fn opened(&mut self, _t: &Trainer, _how: &Opened) -> Result<(), LearnError> {
        Ok(())
    }
    /// After each iteration (progress, a log line, a Python callback); an error stops the
    /// training, which resumes from its last checkpoint.
    fn iterated(&mut self, _t: &Trainer, _s: &IterationStats) -> Result<(), LearnError> {
        Ok(())
    }
}

impl TrainHooks for () {}

/// Trains a run to its end: opens `dir` as `begin` says, iterates until the run's budget is
/// spent, telling `hooks`, and writes the policy. The one way every caller trains (the
/// study, `fishprobe train`, Python, fidelity, the OOD loop). Returns the trainer and the
/// policy file.
pub fn train_to_end(
    dir: &Path,
    begin: Begin,
    build: &str,
    hooks: &mut dyn TrainHooks,
) -> Result<(Trainer, PathBuf), LearnError> {
    let (mut t, how) = match begin {
        Begin::Resume => (hooks.resume(dir, build)?, Opened::Resumed),
        Begin::Start(spec, hint) => match open(dir, &spec, OnOther::Refuse)? {
            Opening::Resume => {
                return Err(LearnError::Run(format!(
                    "{}: already holds a training run of these settings: {hint}",
                    dir.display()
                )))
            }
            Opening::Start | Opening::Restarted { .. } => {
                (hooks.create(dir, spec)?, Opened::Started)
            }
        },
        Begin::StartOrResume(spec, on_other) => match open(dir, &spec, on_other)? {
            Opening::Resume => (hooks.resume(dir, build)?, Opened::Resumed),
            Opening::Start => (hooks.create(dir, spec)?, Opened::Started),
            Opening::Restarted { was } => (hooks.create(dir, spec)?, Opened::Restarted { was }),
        },
    };
    hooks.opened(&t, &how)?;
    // A run that was finished before keeps its policy file as it is (another build would
    // write other metadata, and so other bytes, into the same weights).
    let written = RunLayout::new(dir).policy();
    if t.done() && how == Opened::Resumed && written.is_file() {
        return Ok((t, written));
    }
    while !t.done() {
        let s = t.iterate()?;
        hooks.iterated(&t, &s)?;
    }
    let policy = t.finish()?;
    Ok((t, policy))
}

/// What [`open`] does with a folder that holds another run (other settings, or begun by
/// another trainer revision).
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum OnOther {
    /// Delete it and start this run: a study step, whose changed settings make the old run
    /// stale (the study's markers already say so).
    Restart,
    /// Refuse, saying what differs: a user's folder (`train`, the research commands), whose
    /// run is not fishprobe's to delete.
    Refuse,
}

/// What a run folder means for the run asked for.
#[derive(Debug, Clone, PartialEq, Eq)]
pub enum Opening {
    /// No run there yet: start it ([`crate::Trainer::create`]).
    Start,
    /// This very run, begun (or finished) before: continue it from its last checkpoint
    /// ([`crate::Trainer::resume`]; a finished run is done at once).
    Resume,
    /// Another run was there ([`OnOther::Restart`]); it is deleted: start this one.
    Restarted {
        /// What differed.
        was: String,
    },
}

/// Decides what `dir` means for a run of `spec`; see [`Opening`] and [`OnOther`]. A
/// `params.json` that cannot be read is an error under either rule (whether the run is this
/// one is unknown, so it is kept); one that is not a run's record counts as another run.
pub fn open(dir: &Path, spec: &RunSpec, on_other: OnOther) -> Result<Opening, LearnError> {
    let run = RunLayout::new(dir);
    let params = run.params();
    let text = match fishprobe_io::read_small_text(&params) {
        Ok(t) => t,
        Err(e) if e.kind() == std::io::ErrorKind::NotFound => return Ok(Opening::Start),
        Err(e) => {
            return Err(LearnError::Run(format!(
                "{}: cannot tell whether the folder holds this run (it is kept; delete the \
                 folder to train anew): {e}",
                params.display()
            )))
        }
    };
    let was = match serde_json::from_str::<RunSpec>(&text) {
        Ok(old) if old.same_run(spec) => return Ok(Opening::Resume),
        Ok(old) => {
            if on_other == OnOther::Refuse {
                // Begun by another trainer: its own message says why it is not continued.
                old.check_revision(dir)?;
            }
            difference(&old, spec)
        }
        Err(e) => format!("not a run's record ({e})"),
    };
    match on_other {
        OnOther::Restart => {
            std::fs::remove_dir_all(dir).map_err(|e| {
                LearnError::Run(format!("{}: removing the other run: {e}", dir.display()))
            })?;
            Ok(Opening::Restarted { was })
        }
        OnOther::Refuse => Err(LearnError::Run(format!(
            "{}: already holds a training run, of other settings ({was}): train in another \
             folder, or delete this one",
            dir.display()
        ))),
    }
}

/// What differs between the recorded run `old` and the run `new` asked for, in words.
fn difference(old: &RunSpec, new: &RunSpec) -> String {
    let mut parts = Vec::new();
    if old.trainer_revision != new.trainer_revision {
        parts.push(format!("trainer revision {}", old.trainer_revision));
    }
    if old.model != new.model {
        parts.push(format!("fish model {}", old.model.label()));
    }
    if old.seed != new.seed {
        parts.push(format!("seed {}", old.seed));
    }
    if old.preset != new.preset {
        parts.push(format!("preset `{}`", old.preset));
    }
    if old.ppo != new.ppo {
        parts.push("other PPO settings".into());
    }
    if old.env != new.env {
        parts.push("other environment settings".into());
    }
    if old.program_version != new.program_version {
        parts.push(format!("fishprobe {}", old.program_version));
    }
    if parts.is_empty() {
        "other settings".into()
    } else {
        parts.join(", ")
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::PpoConfig;
    use fishprobe_models::ModelSpec;
    use fishprobe_sim::EnvConfig;

    fn spec(seed: u64) -> RunSpec {
        RunSpec::new(
            ModelSpec::by_name("Zone").expect("a model"),
            PpoConfig::preset("smoke").expect("a preset"),
            EnvConfig::default(),
            seed,
            "smoke",
            "test",
        )
    }

    fn record(dir: &Path, s: &RunSpec) {
        std::fs::create_dir_all(dir).expect("dir");
        let text = serde_json::to_string(s).expect("json");
        std::fs::write(RunLayout::new(dir).params(), text).expect("write");
    }

    #[test]
    fn each_folder_gets_one_outcome_under_each_rule() {
        let d = fishprobe_io::ScratchDir::for_test("run-open");
        let dir = d.join("run");
        // Nothing there.
        assert_eq!(
            open(&dir, &spec(1), OnOther::Refuse).ok(),
            Some(Opening::Start)
        );
        // This run (another build of this trainer continues it).
        let mut mine = spec(1);
        mine.program_build = "another build".into();
        record(&dir, &mine);
        for rule in [OnOther::Refuse, OnOther::Restart] {
            assert_eq!(open(&dir, &spec(1), rule).ok(), Some(Opening::Resume));
        }
        // Another run: refused, naming what differs, and kept.
        let e = open(&dir, &spec(2), OnOther::Refuse)
            .unwrap_err()
            .to_string();
        assert!(
            e.contains("already holds a training run, of other settings (seed 1)")
                && e.contains("train in another folder"),
            "{e}"
        );
        assert!(dir.join("params.json").exists());
        // Begun by another trainer revision: its own message.
        let mut old = spec(2);
        old.trainer_revision = 0;
        record(&dir, &old);
        let e = open(&dir, &spec(2), OnOther::Refuse)
            .unwrap_err()
            .to_string();
        assert!(e.contains("did not record its trainer's revision"), "{e}");
        // Under the study's rule, another run is deleted.
        assert_eq!(
            open(&dir, &spec(2), OnOther::Restart).ok(),
            Some(Opening::Restarted {
                was: "trainer revision 0".into()
            })
        );
        assert!(!dir.exists());
        // A record that is not one: another run; one that cannot be read: kept, an error.
        std::fs::create_dir_all(&dir).expect("dir");
        std::fs::write(dir.join("params.json"), "{}").expect("write");
        let e = open(&dir, &spec(1), OnOther::Refuse)
            .unwrap_err()
            .to_string();
        assert!(e.contains("not a run's record"), "{e}");
        std::fs::write(dir.join("params.json"), [0xff, 0xfe]).expect("write");
        for rule in [OnOther::Refuse, OnOther::Restart] {
            let e = open(&dir, &spec(1), rule).unwrap_err().to_string();
            assert!(
                e.contains("cannot tell whether the folder holds this run"),
                "{e}"
            );
        }
        assert!(dir.join("params.json").exists());
    }

    /// Counts what train_to_end tells its hooks.
    #[derive(Default)]
    struct Count {
        opened: Vec<Opened>,
        iterations: usize,
    }

    impl TrainHooks for Count {
        fn opened(&mut self, _t: &Trainer, how: &Opened) -> Result<(), LearnError> {
            self.opened.push(how.clone());
            Ok(())
        }
        fn iterated(&mut self, _t: &Trainer, _s: &IterationStats) -> Result<(), LearnError> {
            self.iterations += 1;
            Ok(())
        }
    }

    #[test]
    fn train_to_end_starts_resumes_and_refuses_as_asked() {
        let d = fishprobe_io::ScratchDir::for_test("run-train-to-end");
        let dir = d.join("run");
        let mut small = spec(3);
        small.ppo.total_timesteps = small.ppo.train_batch_size as u64;
        let mut c = Count::default();
        let (t, policy) = train_to_end(
            &dir,
            Begin::Start(small.clone(), "resume it"),
            "test",
            &mut c,
        )
        .expect("trains");
        assert!(t.done() && policy.is_file());
        assert_eq!(
            (c.opened.as_slice(), c.iterations),
            (&[Opened::Started][..], 1)
        );
        // The same run again as new: refused with how to continue it.
        let Err(e) = train_to_end(
            &dir,
            Begin::Start(small.clone(), "resume it"),
            "test",
            &mut (),
        ) else {
            panic!("a second start of the same run was taken");
        };
        let e = e.to_string();
        assert!(
            e.ends_with("already holds a training run of these settings: resume it"),
            "{e}"
        );
        // Started or resumed: a finished run is done at once, its policy file untouched.
        let before = std::fs::read(&policy).expect("policy");
        std::fs::write(&policy, b"kept as it was").expect("write");
        let mut c = Count::default();
        train_to_end(
            &dir,
            Begin::StartOrResume(small, OnOther::Refuse),
            "test",
            &mut c,
        )
        .expect("resumes");
        assert_eq!(
            (c.opened.as_slice(), c.iterations),
            (&[Opened::Resumed][..], 0)
        );
        assert_eq!(std::fs::read(&policy).expect("policy"), b"kept as it was");
        std::fs::write(&policy, before).expect("write");
        // Another run under the study's rule: deleted and started.
        let mut c = Count::default();
        let mut other = spec(4);
        other.ppo.total_timesteps = other.ppo.train_batch_size as u64;
        train_to_end(
            &dir,
            Begin::StartOrResume(other, OnOther::Restart),
            "test",
            &mut c,
        )
        .expect("restarts");
        assert!(
            matches!(c.opened[0], Opened::Restarted { .. }),
            "{:?}",
            c.opened
        );
    }
}
