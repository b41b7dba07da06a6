//! One writer per output directory: a second `run` or `train` into a directory in use is
//! refused at once, naming the directory and the holder's PID; a holder killed with SIGKILL
//! never blocks the next command (the lock is the operating system's).

#![allow(clippy::unwrap_used)] // a failure is a test failure

mod common;

use common::{fishprobe, fresh_dir, stderr};
use std::path::Path;
use std::process::{Child, Command, Stdio};
use std::time::{Duration, Instant};

fn spawn(args: &[&str]) -> Child {
    Command::new(env!("CARGO_BIN_EXE_fishprobe"))
        .args(args)
        .stdin(Stdio::null())
        .stdout(Stdio::null())
        .stderr(Stdio::null())
        .spawn()
        .unwrap()
}

/// Waits until `dir`'s lock names the process `pid`.
fn wait_for_lock(dir: &Path, pid: u32) {
    let start = Instant::now();
    let want = format!("PID {pid}");
    while !std::fs::read_to_string(dir.join(".fishprobe.lock")).is_ok_and(|t| t.contains(&want)) {
        assert!(
            start.elapsed() < Duration::from_secs(30),
            "no lock by {pid} in {}",
            dir.display()
        );
        std::thread::sleep(Duration::from_millis(10));
    }
}

fn assert_refused(args: &[&str], dir: &Path, holder: &str) {
    let start = Instant::now();
    let o = fishprobe(args);
    let err = stderr(&o);
    assert_eq!(o.status.code(), Some(1), "{args:?} was not refused:\n{err}");
    assert!(
        err.contains(&dir.display().to_string()) && err.contains(holder),
        "{args:?}: the refusal does not name the directory and `{holder}`:\n{err}"
    );
    assert!(
        start.elapsed() < Duration::from_secs(10),
        "refusal not at once"
    );
}

#[test]
fn a_second_run_on_one_study_is_refused_and_a_killed_run_blocks_nothing() {
    let d = fresh_dir("one-writer-run");
    let study = d.join("S");
    let args = ["run", "--preset", "smoke", "--out", study.to_str().unwrap()];
    let mut first = spawn(&args);
    wait_for_lock(&study, first.id());
    let holder = format!("fishprobe run, PID {}", first.id());
    assert_refused(&args, &study, &holder);
    first.kill().unwrap();
    first.wait().unwrap();
    // SIGKILL released the lock: the next run takes it at once.
    let mut second = spawn(&args);
    wait_for_lock(&study, second.id());
    second.kill().unwrap();
    second.wait().unwrap();
}

#[test]
fn a_second_train_or_resume_into_one_directory_is_refused() {
    let d = fresh_dir("one-writer-train");
    let out = d.join("T");
    let o = out.to_str().unwrap();
    let mut first = spawn(&[
        "train", "--model", "Follow", "--preset", "quick", "--seed", "5", "--out", o,
    ]);
    wait_for_lock(&out, first.id());
    let holder = format!("fishprobe train, PID {}", first.id());
    assert_refused(
        &[
            "train", "--model", "Follow", "--preset", "smoke", "--seed", "6", "--out", o,
        ],
        &out,
        &holder,
    );
    assert_refused(&["train", "--resume", "--out", o], &out, &holder);
    first.kill().unwrap();
    first.wait().unwrap();
    // params.json, if written, is the first run's (seed 5), never the refused one's.
    if let Ok(p) = std::fs::read_to_string(out.join("params.json")) {
        let v: serde_json::Value = serde_json::from_str(&p).unwrap();
        assert_eq!(v["seed"], 5, "{p}");
    }
}

/// The race CI once lost: a `--resume` into a directory whose holder has locked it but not
/// yet written params.json is refused by the lock, naming the holder, not asked for --model.
#[test]
fn a_resume_into_a_directory_locked_before_its_params_exist_names_the_holder() {
    use std::io::Write;
    let d = fresh_dir("one-writer-early-resume");
    let out = d.join("T");
    std::fs::create_dir_all(&out).unwrap();
    let mut lock = std::fs::OpenOptions::new()
        .read(true)
        .write(true)
        .create(true)
        .truncate(true)
        .open(out.join(".fishprobe.lock"))
        .unwrap();
    lock.try_lock().unwrap();
    lock.write_all(b"fishprobe train, PID 4242").unwrap();
    lock.flush().unwrap();
    assert!(!out.join("params.json").exists());
    assert_refused(
        &["train", "--resume", "--out", out.to_str().unwrap()],
        &out,
        "fishprobe train, PID 4242",
    );
    drop(lock);
}
