//! Trial files: every rollout, simulated or live, is one robofish.io 1.0 HDF5 file that the
//! lab's Python tools open, plus a `/fishprobe` group with the task (SPEC §10). Also reads the
//! lab's pre-2020 layout and converts it.
//!
//! ```no_run
//! use fishprobe_io::{read_trial, write_trial};
//!
//! let trial = read_trial("Q12I_Robotracker.hdf5".as_ref())?;
//! println!("{} Hz, {:.0} s", trial.frame_rate_hz, trial.duration_s());
//! for fish in trial.fish() {
//!     println!("{}: {:.1} % untracked", fish.name, 100.0 * fish.nan_fraction());
//! }
//! write_trial("copy.hdf5".as_ref(), &trial)?;
//! # Ok::<(), fishprobe_io::IoError>(())
//! ```
//!
//! This is the only crate of fishprobe that touches HDF5, and inside it only the `backend`
//! module names the HDF5 implementation. **Choice: `hdf5-pure`**, a pure-Rust HDF5 reader and
//! writer, over the reference C library built from bundled source (`hdf5-metno` with
//! `static`): it needs nothing on a user's machine beyond cargo (the C build needs cmake), and
//! as memory-safe code it turns damaged files into errors (250 damaged copies of the real files
//! in `tests/damaged_files.rs`) where a C parser can crash the process. Its files open in h5py
//! (`tests/write_read.rs`). To swap it, rewrite `backend.rs`; nothing else names it.

#![warn(missing_docs)]

pub mod any;
pub mod attr;
pub mod backend;
pub mod error;
pub mod layout;
pub mod legacy;
pub mod limits;
pub mod lock;
pub mod provenance;
pub mod robofish;
pub mod run;
pub mod scratch;
pub mod trial;

pub use any::{read_any_trial, read_any_trial_layout, TrialLayout};
pub use attr::Attr;
pub use error::IoError;
pub use layout::{Arm, StudyLayout};
pub use legacy::read_legacy;
pub use limits::{read_small_text, read_text_at_most, ReadLimits};
pub use lock::{DirLock, LockError};
pub use provenance::{short_sha, Provenance, POLICY_SHA256_KEY};
pub use robofish::{read_trial, write_atomically, write_trial};
pub use run::{RunLayout, RunRecord};
pub use scratch::ScratchDir;
pub use trial::{
    heading_from_motion, Category, Entity, TaskRecord, TrialFile, TrialKind, TrialMeta,
    INDIVIDUAL_ATTRIBUTE, TRACKER_ID_ATTRIBUTE,
};

/// Every entry directly in `dir` named `*.hdf5` or `*.h5`, sorted by name; none when `dir`
/// cannot be read. Entries that are not regular files (directories, FIFOs, dangling or looping
/// symbolic links) are listed too, so that a reader refuses them with a reason and an
/// analysis reports them as skipped instead of silently counting fewer trials.
pub fn trial_files(dir: &std::path::Path) -> Vec<std::path::PathBuf> {
    let mut v: Vec<std::path::PathBuf> = std::fs::read_dir(dir)
        .into_iter()
        .flatten()
        .filter_map(|e| e.ok().map(|e| e.path()))
        .filter(|p| p.extension().is_some_and(|x| x == "hdf5" || x == "h5"))
        .collect();
    v.sort();
    v
}

/// The shared real tracking data, for tests and examples: `$FISHPROBE_DATA` when set (whether
/// or not it exists, so that a test finding it missing fails), else `../shared/data` beside
/// the workspace when present, else `None`.
pub fn shared_data_dir() -> Option<std::path::PathBuf> {
    if let Some(d) = std::env::var_os("FISHPROBE_DATA") {
        return Some(std::path::PathBuf::from(d));
    }
    let beside = std::path::Path::new(env!("CARGO_MANIFEST_DIR")).join("../../../shared/data");
    beside.is_dir().then_some(beside)
}
