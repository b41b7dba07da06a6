//! Finished trials are never lost: a trial that cannot be written where it belongs (a full
//! disk, a vanished directory) goes to a fallback directory; if that fails too it stays in
//! memory and every later trial's end tries again. The bridge keeps serving either way, and
//! the client is told where its trial went.
//!
//! The descriptors the write needs are secured when a trial starts ([`Keeper::reserve`]) and
//! given back just before it is written, so a process whose descriptor table filled up during
//! the trial (a flood of connections, say) still writes the trial. A running trial is written
//! now and then as a checkpoint ([`Keeper::checkpoint`]), so even a kill that cannot be caught
//! leaves a readable file of the frames so far.

use fishprobe_io::TrialFile;
use std::path::{Path, PathBuf};

/// Where a trial ended up.
#[derive(Debug, Clone, PartialEq)]
pub enum Kept {
    /// Written where it belongs.
    Written(PathBuf),
    /// Written to the fallback directory; why the proper place failed.
    Fallback {
        /// Where it is.
        file: PathBuf,
        /// Where it should have gone, and why it could not.
        why: String,
    },
    /// Held in memory, to be written at the next chance; why nothing worked.
    InMemory {
        /// Where it should go.
        file: PathBuf,
        /// What failed.
        why: String,
    },
}

impl Kept {
    /// The file, if one was written.
    pub fn written(&self) -> Option<&Path> {
        match self {
            Kept::Written(f) | Kept::Fallback { file: f, .. } => Some(f),
            Kept::InMemory { .. } => None,
        }
    }

    /// What the client (and the operator) should be told, if anything went wrong.
    pub fn warning(&self) -> Option<String> {
        match self {
            Kept::Written(_) => None,
            Kept::Fallback { file, why } => Some(format!(
                "{why}; the trial was written to {} instead",
                file.display()
            )),
            Kept::InMemory { file, why } => Some(format!(
                "{why}; the trial is kept in the bridge's memory and written to {} as soon as \
                 that works (at the end of a later trial, or when the bridge stops)",
                file.display()
            )),
        }
    }
}

/// Descriptors held for a trial's write (its temporary file, and the fallback's).
const RESERVED_DESCRIPTORS: usize = 2;

/// What a checkpoint's `ended_because` says until the trial's real end replaces the file.
pub const CHECKPOINT_NOTE: &str =
    "still running: a checkpoint written during the trial (fishprobe ended before the trial did)";

/// Trials waiting to be written.
#[derive(Debug, Default)]
pub struct Keeper {
    unsaved: Vec<(PathBuf, TrialFile)>,
    fallback: Option<PathBuf>,
    /// Descriptors held for the next write.
    reserved: Vec<std::fs::File>,
    /// Checkpoints written where a trial belongs (removed if the trial goes elsewhere).
    checkpoints: Vec<PathBuf>,
    /// The checkpoint being written.
    checkpointing: Option<std::thread::JoinHandle<Result<(), String>>>,
}

impl Keeper {
    /// A keeper whose fallback directory is `fallback` (none: the system's temporary
    /// directory, `fishprobe-unsaved/`).
    pub fn new(fallback: Option<PathBuf>) -> Self {
        Self {
            unsaved: Vec::new(),
            fallback,
            reserved: Vec::new(),
            checkpoints: Vec::new(),
            checkpointing: None,
        }
    }

    /// Secures the descriptors a trial's write needs (call when the trial starts); whether
    /// they are held. They are given back when the trial is kept.
    pub fn reserve(&mut self) -> bool {
        while self.reserved.len() < RESERVED_DESCRIPTORS {
            match spare_descriptor() {
                Ok(f) => self.reserved.push(f),
                Err(_) => return false,
            }
        }
        true
    }

    /// Writes a running trial where it belongs, on a thread of its own (a slow disk never
    /// delays a frame or a command), replacing the last checkpoint at once, so the file there
    /// is always readable; the trial's end replaces it. While the previous checkpoint is still
    /// being written this one is skipped. Returns why the previous one failed, if it did: a
    /// failed checkpoint changes nothing, the trial is still kept at its end.
    pub fn checkpoint(&mut self, file: &Path, trial: TrialFile) -> Option<String> {
        if self
            .checkpointing
            .as_ref()
            .is_some_and(|h| !h.is_finished())
        {
            return None;
        }
        let failed = self.settle();
        let target = file.to_path_buf();
        self.checkpointing = std::thread::Builder::new()
            .name("trial-checkpoint".into())
            .spawn(move || write(&target, &trial))
            .ok();
        if !self.checkpoints.iter().any(|c| c == file) {
            self.checkpoints.push(file.to_path_buf());
        }
        failed
    }

    /// Waits for a checkpoint being written; why it failed, if it did.
    fn settle(&mut self) -> Option<String> {
        let h = self.checkpointing.take()?;
        match h.join() {
            Ok(Ok(())) => None,
            Ok(Err(e)) => Some(e),
            Err(_) => Some("the checkpoint's writer failed".into()),
        }
    }

    fn fallback_dir(&self) -> PathBuf {
        self.fallback
            .clone()
            .unwrap_or_else(|| std::env::temp_dir().join("fishprobe-unsaved"))
    }

    /// Writes `trial` to `file`, else to the fallback directory, else keeps it.
    pub fn keep(&mut self, file: &Path, trial: TrialFile) -> Kept {
        // A checkpoint still being written must not land after the trial's file.
        let _ = self.settle();
        // The descriptors held since the trial started are what this write uses.
        self.reserved.clear();
        let had_checkpoint = self.checkpoints.iter().any(|c| c == file);
        self.checkpoints.retain(|c| c != file);
        let first = match write(file, &trial) {
            Ok(()) => return Kept::Written(file.to_path_buf()),
            Err(e) => format!("cannot write {}: {e}", file.display()),
        };
        let name = file
            .file_name()
            .map_or_else(|| "trial.hdf5".into(), |n| n.to_string_lossy().into_owned());
        let arm = file
            .parent()
            .and_then(Path::file_name)
            .map_or_else(String::new, |n| n.to_string_lossy().into_owned());
        let stamp = std::time::SystemTime::now()
            .duration_since(std::time::UNIX_EPOCH)
            .map_or(0, |d| d.as_millis());
        let alt = self
            .fallback_dir()
            .join(arm)
            .join(format!("{stamp}-{}-{name}", std::process::id()));
        match write(&alt, &trial) {
            Ok(()) => {
                if had_checkpoint {
                    // The whole trial is in the fallback: no half of it where it belongs.
                    let _ = std::fs::remove_file(file);
                }
                Kept::Fallback {
                    file: alt,
                    why: first,
                }
            }
            Err(e) => {
                self.unsaved.push((file.to_path_buf(), trial));
                Kept::InMemory {
                    file: file.to_path_buf(),
                    why: format!("{first}; the fallback {} failed too: {e}", alt.display()),
                }
            }
        }
    }

    /// Tries again to write the trials held in memory; returns those written.
    pub fn retry(&mut self) -> Vec<PathBuf> {
        let mut done = Vec::new();
        self.unsaved
            .retain(|(file, trial)| match write(file, trial) {
                Ok(()) => {
                    done.push(file.clone());
                    false
                }
                Err(_) => true,
            });
        done
    }

    /// Trials still held in memory.
    pub fn unsaved(&self) -> Vec<&Path> {
        self.unsaved.iter().map(|(f, _)| f.as_path()).collect()
    }
}

/// A descriptor to hold: the null device, which any process may open.
fn spare_descriptor() -> std::io::Result<std::fs::File> {
    std::fs::File::open(if cfg!(windows) { "NUL" } else { "/dev/null" })
}

fn write(file: &Path, trial: &TrialFile) -> Result<(), String> {
    if let Some(d) = file.parent() {
        std::fs::create_dir_all(d).map_err(|e| format!("{}: {e}", d.display()))?;
    }
    fishprobe_io::write_trial(file, trial).map_err(|e| e.to_string())
}
