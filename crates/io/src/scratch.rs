//! Scratch directories that do not outlive their use.
//!
//! A command that needs files only for a moment (`assay approach` without `--out`, the
//! benchmarks) and every test that writes files takes a [`ScratchDir`]: the directory is
//! removed when the value is dropped, however the work ends, an error included. A test's
//! directory is kept when the test fails (the drop runs while a panic unwinds), and its path
//! printed, for a look at what was left there. A fixture that all tests of one test binary
//! share lives in [`ScratchDir::for_process`], which the next run removes.

use crate::DirLock;
use std::path::{Path, PathBuf};

/// A directory removed when dropped. Derefs to its path.
#[derive(Debug)]
pub struct ScratchDir {
    path: PathBuf,
    keep_on_panic: bool,
}

impl ScratchDir {
    /// `path` (made or not by the caller), removed when the value is dropped.
    pub fn remove_on_drop(path: PathBuf) -> Self {
        Self {
            path,
            keep_on_panic: false,
        }
    }

    /// A fresh, empty `fishprobe-{tag}-{process id}` in the temp directory, for one test:
    /// removed when the test passes, kept (and named on stderr) when it panics.
    ///
    /// # Panics
    /// When the temp directory is not writable (a test cannot run without it).
    pub fn for_test(tag: &str) -> Self {
        let path = std::env::temp_dir().join(format!("fishprobe-{tag}-{}", std::process::id()));
        let _ = std::fs::remove_dir_all(&path);
        std::fs::create_dir_all(&path).expect("the temp directory is writable");
        Self {
            path,
            keep_on_panic: true,
        }
    }

    /// A fresh, empty `fishprobe-{tag}-{process id}` in the temp directory for a fixture that
    /// lives as long as its test binary (a `static`, never dropped): a lock beside it
    /// (`….lock`, a [`DirLock`] file, so that the commands a test runs in the directory take
    /// their own) is held until the process ends, and the directories that earlier processes
    /// left under the same tag, whose locks the operating system released when they ended, are
    /// removed first. So a run leaves at most one such directory per tag behind, and a
    /// process running the same tests beside it keeps its own.
    ///
    /// # Panics
    /// When the temp directory is not writable (a test cannot run without it).
    pub fn for_process(tag: &str) -> PathBuf {
        let prefix = format!("fishprobe-{tag}-");
        let temp = std::env::temp_dir();
        let lock_of = |dir: &Path| dir.with_extension("lock");
        let own = temp.join(format!("{prefix}{}", std::process::id()));
        let held = DirLock::acquire_file(&own, &lock_of(&own), "a test fixture")
            .expect("the temp directory is writable");
        // Held until the process ends: the OS releases the lock then, not a destructor.
        std::mem::forget(held);
        let _ = std::fs::remove_dir_all(&own);
        std::fs::create_dir_all(&own).expect("the temp directory is writable");
        for entry in std::fs::read_dir(&temp).into_iter().flatten().flatten() {
            let name = entry.file_name();
            // `{prefix}{pid}` (a fixture) or `{prefix}{pid}.lock` (its lock, maybe alone).
            let Some(pid) = name.to_str().and_then(|n| n.strip_prefix(&prefix)) else {
                continue;
            };
            let pid = pid.strip_suffix(".lock").unwrap_or(pid);
            if pid.is_empty() || !pid.bytes().all(|b| b.is_ascii_digit()) {
                continue;
            }
            let path = temp.join(format!("{prefix}{pid}"));
            if path == own {
                continue;
            }
            // Locked: its process still runs. Unlocked: left behind, and ours to remove.
            let lock = lock_of(&path);
            if let Ok(gone) = DirLock::acquire_file(&path, &lock, "a left-behind test fixture") {
                let _ = std::fs::remove_dir_all(&path);
                let _ = std::fs::remove_file(&lock);
                drop(gone);
            }
        }
        own
    }
}

impl std::ops::Deref for ScratchDir {
    type Target = Path;
    fn deref(&self) -> &Path {
        &self.path
    }
}

impl AsRef<Path> for ScratchDir {
    fn as_ref(&self) -> &Path {
        &self.path
    }
}

impl Drop for ScratchDir {
    fn drop(&mut self) {
        if self.keep_on_panic && std::thread::panicking() {
            eprintln!("kept for a look: {}", self.path.display());
        } else {
            let _ = std::fs::remove_dir_all(&self.path);
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn a_scratch_directory_goes_when_dropped() {
        let d = ScratchDir::for_test("scratch-drop");
        std::fs::write(d.join("f"), b"x").unwrap();
        let p = d.to_path_buf();
        drop(d);
        assert!(!p.exists());
    }

    #[test]
    fn a_process_fixture_stays_and_sweeps_what_dead_processes_left() {
        let temp = std::env::temp_dir();
        // What a finished run left (no process holds its lock) and a look-alike that is not
        // a fixture of this tag.
        let left = temp.join("fishprobe-scratch-proc-4000000001");
        let other = temp.join(format!("fishprobe-scratch-proc-x{}", std::process::id()));
        for d in [&left, &other] {
            std::fs::create_dir_all(d).unwrap();
            std::fs::write(d.join("f"), b"x").unwrap();
        }
        // A lock file whose directory is gone.
        let orphan = temp.join("fishprobe-scratch-proc-4000000003.lock");
        std::fs::write(&orphan, b"").unwrap();
        // A fixture of a process that still runs: its lock is held (here by this process).
        let alive = temp.join("fishprobe-scratch-proc-4000000002");
        std::fs::create_dir_all(&alive).unwrap();
        let _held =
            DirLock::acquire_file(&alive, &alive.with_extension("lock"), "a live one").unwrap();
        let own = ScratchDir::for_process("scratch-proc");
        assert!(
            own.is_dir() && std::fs::read_dir(&own).unwrap().count() == 0,
            "fresh"
        );
        assert!(!left.exists(), "a dead process's fixture is removed");
        assert!(!left.with_extension("lock").exists(), "with its lock file");
        assert!(
            !orphan.exists(),
            "a lock file without its directory is removed"
        );
        assert!(alive.is_dir(), "a live process's fixture stays");
        assert!(other.is_dir(), "a name that is not tag-pid is left alone");
        // Its own lock is held: another process's sweep would leave it. A command run in the
        // directory takes the directory's own lock.
        assert!(DirLock::acquire_file(&own, &own.with_extension("lock"), "sweep").is_err());
        drop(DirLock::acquire(&own, "a command in the fixture").unwrap());
        for d in [&own, &alive, &other] {
            std::fs::remove_dir_all(d).unwrap();
            let _ = std::fs::remove_file(d.with_extension("lock"));
        }
    }

    #[test]
    fn a_failing_test_keeps_its_directory() {
        let path = std::thread::spawn(|| {
            let d = ScratchDir::for_test("scratch-panic");
            let p = d.to_path_buf();
            std::panic::panic_any(p);
        })
        .join()
        .unwrap_err()
        .downcast::<PathBuf>()
        .unwrap();
        assert!(path.is_dir(), "{}", path.display());
        std::fs::remove_dir_all(&*path).unwrap();
        let p = {
            let d = ScratchDir::remove_on_drop(
                std::env::temp_dir().join(format!("fishprobe-scratch-cmd-{}", std::process::id())),
            );
            std::fs::create_dir_all(&*d).unwrap();
            d.to_path_buf()
        };
        assert!(!p.exists());
    }
}
