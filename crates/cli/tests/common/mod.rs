//! Helpers shared by the end-to-end tests.

#![allow(dead_code)] // each test file uses a subset

use std::path::Path;
use std::process::{Child, Command, Output, Stdio};
use std::time::{Duration, Instant};

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

/// A file rewritten in place, alternately whole (`bytes`) and cut in half, by a thread that
/// runs until this value is dropped (at most 100,000 writes): a file torn while a command
/// reads it.
pub struct TornFile {
    done: std::sync::Arc<std::sync::atomic::AtomicBool>,
    writer: Option<std::thread::JoinHandle<()>>,
}

impl TornFile {
    /// Writes `bytes` to `path`, then starts tearing it.
    pub fn start(path: &Path, bytes: Vec<u8>) -> Self {
        use std::sync::atomic::{AtomicBool, Ordering};
        std::fs::write(path, &bytes).expect("the torn file can be written");
        let done = std::sync::Arc::new(AtomicBool::new(false));
        let (stop, path) = (done.clone(), path.to_path_buf());
        let writer = std::thread::spawn(move || {
            for k in 0..100_000usize {
                if stop.load(Ordering::Relaxed) {
                    break;
                }
                let n = if k.is_multiple_of(2) {
                    bytes.len()
                } else {
                    bytes.len() / 2
                };
                let _ = std::fs::write(&path, &bytes[..n]);
            }
        });
        Self {
            done,
            writer: Some(writer),
        }
    }
}

impl Drop for TornFile {
    fn drop(&mut self) {
        self.done.store(true, std::sync::atomic::Ordering::Relaxed);
        if let Some(w) = self.writer.take() {
            let _ = w.join();
        }
    }
}

/// `fishprobe live serve --policy scripted:goal-seeker --out OUT` on `127.0.0.1:PORT` in the
/// background (`extra`: more arguments), waited for until it accepts connections.
pub fn bridge(out: &Path, port: u16, extra: &[&str]) -> Child {
    let child = Command::new(env!("CARGO_BIN_EXE_fishprobe"))
        .args([
            "live",
            "serve",
            "--policy",
            "scripted:goal-seeker",
            "--listen",
        ])
        .arg(format!("127.0.0.1:{port}"))
        .arg("--out")
        .arg(out)
        .args(extra)
        .stdout(Stdio::piped())
        .stderr(Stdio::piped())
        .spawn()
        .expect("the fishprobe binary runs");
    let start = Instant::now();
    // A probe connection that never says hello is not a trial.
    while std::net::TcpStream::connect(("127.0.0.1", port)).is_err() {
        assert!(
            start.elapsed() < Duration::from_secs(20),
            "the bridge did not start"
        );
        std::thread::sleep(Duration::from_millis(20));
    }
    child
}

/// The shared pair recordings, `guppy-pairs/legacy` (`None`: the data is not configured, skip;
/// configured but missing: fail).
pub fn pairs() -> Option<std::path::PathBuf> {
    let Some(d) = fishprobe_io::shared_data_dir() else {
        eprintln!("skipping: FISHPROBE_DATA is not set and ../shared/data is absent");
        return None;
    };
    let p = d.join("guppy-pairs/legacy");
    assert!(p.join("train").is_dir(), "{} is missing", p.display());
    Some(p)
}

pub mod tracker;
