//! Helpers shared by the end-to-end tests.

#![allow(dead_code)] // each test file uses a subset

use std::path::Path;
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

pub use fishprobe_io::ScratchDir as Scratch;

/// A fresh, empty directory for one test (the end-to-end tests' studies and trainings fill
/// hundreds of megabytes; none is left behind by a test that passes).
pub fn fresh_dir(tag: &str) -> Scratch {
    Scratch::for_test(&format!("e2e-{tag}"))
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
