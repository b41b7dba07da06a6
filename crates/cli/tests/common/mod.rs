//! Helpers shared by the end-to-end tests.

#![allow(dead_code)] // each test file uses a subset

use std::path::{Path, PathBuf};
use std::process::{Command, Output};

/// Runs the `fishprobe` binary.
pub fn fishprobe(args: &[&str]) -> Output {
    Command::new(env!("CARGO_BIN_EXE_fishprobe"))
        .args(args)
        .output()
        .expect("the fishprobe binary runs")
}

/// Its standard output as text.
pub fn stdout(o: &Output) -> String {
    String::from_utf8_lossy(&o.stdout).into_owned()
}

/// Its standard error as text.
pub fn stderr(o: &Output) -> String {
    String::from_utf8_lossy(&o.stderr).into_owned()
}

/// A test's scratch directory: removed when the test ends, kept (and named on stderr) when
/// it fails, for a look at what the commands left there. Derefs to its path.
#[derive(Debug)]
pub struct Scratch(PathBuf);

impl Scratch {
    /// The path, and the directory left in place: for a fixture that lives as long as its
    /// test binary (a `static`, which is never dropped) and that the next run's `fresh_dir`
    /// of the same tag replaces.
    pub fn keep(self) -> PathBuf {
        let p = self.0.clone();
        std::mem::forget(self);
        p
    }
}

impl std::ops::Deref for Scratch {
    type Target = Path;
    fn deref(&self) -> &Path {
        &self.0
    }
}

impl AsRef<Path> for Scratch {
    fn as_ref(&self) -> &Path {
        &self.0
    }
}

impl Drop for Scratch {
    fn drop(&mut self) {
        if std::thread::panicking() {
            eprintln!("kept for a look: {}", self.0.display());
        } else {
            let _ = std::fs::remove_dir_all(&self.0);
        }
    }
}

/// A fresh, empty directory for one test (the end-to-end tests' studies and trainings fill
/// hundreds of megabytes; none is left behind by a test that passes).
pub fn fresh_dir(tag: &str) -> Scratch {
    let d = std::env::temp_dir().join(format!("fishprobe-e2e-{tag}-{}", std::process::id()));
    let _ = std::fs::remove_dir_all(&d);
    std::fs::create_dir_all(&d).expect("the temp dir is writable");
    Scratch(d)
}

/// Trains a `smoke`-preset policy of `model` into `out` (`extra`: more `train` arguments) and
/// checks that the run succeeded.
pub fn train_smoke(model: &str, out: &Path, extra: &[&str]) {
    let out = out.to_str().expect("a UTF-8 temp path");
    let args = [
        &["train", "--model", model, "--preset", "smoke", "--out", out][..],
        extra,
    ]
    .concat();
    let o = fishprobe(&args);
    assert!(o.status.success(), "{}", stderr(&o));
}
