//! Scratch directories that do not outlive their use.
//!
//! A command that needs files only for a moment (`assay approach` without `--out`, the
//! benchmarks) and every test that writes files takes a [`ScratchDir`]: the directory is
//! removed when the value is dropped, however the work ends, an error included. A test's
//! directory is kept when the test fails (the drop runs while a panic unwinds), and its path
//! printed, for a look at what was left there.

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

    /// The path, and the directory left in place: for a fixture that lives as long as its
    /// test binary (a `static` is never dropped); the next run's [`ScratchDir::for_test`] of
    /// the same tag and process id replaces it.
    pub fn keep(self) -> PathBuf {
        let path = self.path.clone();
        std::mem::forget(self);
        path
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
    fn a_scratch_directory_goes_when_dropped_and_stays_when_kept() {
        let d = ScratchDir::for_test("scratch-drop");
        std::fs::write(d.join("f"), b"x").unwrap();
        let p = d.to_path_buf();
        drop(d);
        assert!(!p.exists());
        let k = ScratchDir::for_test("scratch-keep").keep();
        assert!(k.is_dir());
        std::fs::remove_dir_all(&k).unwrap();
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
