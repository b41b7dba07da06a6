//! End-to-end tests of the live bridge, the virtual lab and the replay client.

#![allow(clippy::unwrap_used)] // a failure is a test failure

mod common;

use common::{fishprobe, fresh_dir as dir, stderr, stdout};
use std::net::TcpListener;
use std::path::{Path, PathBuf};
use std::process::{Child, Command};

fn free_port() -> u16 {
    TcpListener::bind("127.0.0.1:0")
        .unwrap()
        .local_addr()
        .unwrap()
        .port()
}

/// The bridge for `trials` trials into `out`.
fn bridge(out: &Path, trials: usize, port: u16) -> Child {
    common::bridge(out, port, &["--trials", &trials.to_string()])
}

fn trials_in(d: &Path) -> Vec<PathBuf> {
    let mut v: Vec<PathBuf> = std::fs::read_dir(d)
        .map(|r| r.map(|e| e.unwrap().path()).collect())
        .unwrap_or_default();
    v.sort();
    v
}

#[test]
fn the_virtual_lab_feeds_analyze_and_report_labelled_virtual() {
    let d = dir("lab");
    let rollouts = d.join("rollouts");
    let o = fishprobe(&[
        "lab",
        "--policy",
        "scripted:goal-seeker",
        "--trials",
        "3",
        "--minutes",
        "1",
        "--seed",
        "4",
        "--out",
        rollouts.to_str().unwrap(),
    ]);
    assert!(o.status.success(), "{}", stderr(&o));
    assert!(stdout(&o).starts_with("VIRTUAL LAB"), "{}", stdout(&o));
    let files = trials_in(&rollouts.join("GoalSeeker__VirtualLab"));
    assert_eq!(files.len(), 3);
    let t = fishprobe_io::read_trial(&files[0]).unwrap();
    let task = t.task.unwrap();
    assert_eq!(task.kind, fishprobe_io::TrialKind::Virtual);
    assert_eq!(task.control_start_frame, 3000);
    // The sim arm of the same controller, then the study's analysis and report.
    let o = fishprobe(&[
        "evaluate",
        "--policy",
        "scripted:goal-seeker",
        "--model",
        "Force",
        "--episodes",
        "3",
        "--minutes",
        "1",
        "--out",
        rollouts.join("GoalSeeker__GoalSeeker").to_str().unwrap(),
    ]);
    assert!(o.status.success(), "{}", stderr(&o));
    let o = fishprobe(&["analyze", d.to_str().unwrap(), "--quick"]);
    assert!(o.status.success(), "{}", stderr(&o));
    assert!(stdout(&o).contains("VIRTUAL LAB"), "{}", stdout(&o));
    let r: serde_json::Value =
        serde_json::from_str(&std::fs::read_to_string(d.join("analysis/results.json")).unwrap())
            .unwrap();
    assert_eq!(r["reality"], "VirtualLab");
    assert_eq!(
        r["goals"]["GoalSeeker"]["real"].as_array().unwrap().len(),
        3
    );
    let o = fishprobe(&["report", d.to_str().unwrap()]);
    assert!(o.status.success(), "{}", stderr(&o));
    let html = std::fs::read_to_string(d.join("report/index.html")).unwrap();
    assert!(html.contains("id=\"virtual\""));
}

#[test]
fn the_python_example_client_of_the_protocol_doc_talks_to_the_bridge() {
    let doc = std::fs::read_to_string(
        Path::new(env!("CARGO_MANIFEST_DIR")).join("../../docs/live-protocol.md"),
    )
    .unwrap();
    let start = doc.find("```python\n").unwrap() + "```python\n".len();
    let code = &doc[start..start + doc[start..].find("```").unwrap()];
    let d = dir("pyclient");
    let script = d.join("client.py");
    std::fs::write(&script, code).unwrap();
    let port = free_port();
    let mut b = bridge(&d.join("trials"), 1, port);
    let py = Command::new("python3")
        .args([
            script.to_str().unwrap(),
            "127.0.0.1",
            &port.to_string(),
            "3",
        ])
        .output()
        .expect("python3 runs");
    let out = String::from_utf8_lossy(&py.stdout).into_owned();
    assert!(
        py.status.success(),
        "{out}{}",
        String::from_utf8_lossy(&py.stderr)
    );
    assert!(out.contains("policy GoalSeeker"), "{out}");
    assert_eq!(out.matches("habituation turn").count(), 3, "{out}");
    assert!(b.wait().unwrap().success());
    let files = trials_in(&d.join("trials/GoalSeeker__Real"));
    assert_eq!(files.len(), 1);
    let t = fishprobe_io::read_trial(&files[0]).unwrap();
    assert_eq!(t.task.as_ref().unwrap().kind, fishprobe_io::TrialKind::Real);
    assert_eq!(t.robot().unwrap().positions.len(), 75);
}

#[test]
fn a_recorded_robot_fish_trial_replays_through_the_bridge() {
    let Some(data) = fishprobe_io::shared_data_dir() else {
        eprintln!("skipping: FISHPROBE_DATA is not set and ../shared/data is absent");
        return;
    };
    let rf = data.join("robot-fish");
    let file = trials_in(&rf)
        .into_iter()
        .next()
        .unwrap_or_else(|| panic!("no files in {}", rf.display()));
    let d = dir("replay");
    let port = free_port();
    let mut b = bridge(&d, 1, port);
    let o = fishprobe(&[
        "live",
        "replay",
        file.to_str().unwrap(),
        "--connect",
        &format!("127.0.0.1:{port}"),
    ]);
    assert!(o.status.success(), "{}", stderr(&o));
    assert!(stdout(&o).contains("replayed"), "{}", stdout(&o));
    assert!(b.wait().unwrap().success());
    let files = trials_in(&d.join("GoalSeeker__Real"));
    let t = fishprobe_io::read_trial(&files[0]).unwrap();
    // 20 Hz recording stored at 25 Hz: about 1.25 x its frames, the whole recording.
    let n = t.robot().unwrap().positions.len();
    assert!(n > 13_000, "{n} frames");
    assert!(t.task.unwrap().command_frames.len() > 100);
}

#[test]
fn listening_beyond_loopback_needs_a_flag_and_a_token() {
    let o = fishprobe(&[
        "live",
        "serve",
        "--policy",
        "scripted:goal-seeker",
        "--listen",
        "0.0.0.0:4599",
        "--trials",
        "1",
    ]);
    assert!(!o.status.success());
    let e = stderr(&o);
    assert!(e.contains("--allow-remote") && e.contains("--token"), "{e}");
    let o = fishprobe(&[
        "live",
        "serve",
        "--policy",
        "/nonexistent/policy",
        "--trials",
        "1",
    ]);
    assert!(!o.status.success());
    assert!(stderr(&o).contains("/nonexistent/policy"), "{}", stderr(&o));
}

/// The RoboTracker behaviour turns a command's turn into a target point `L` ahead of the robot;
/// its default `L` is the distance the simulated robot covers in one action when it keeps its
/// heading (steady state, the robot settings' defaults). This simulates that and reads the
/// number the behaviour file states.
#[test]
fn the_robotracker_step_is_what_the_simulated_robot_covers_in_one_action() {
    use fishprobe_sim::{EnvConfig, Robot, Tank};
    let cfg = EnvConfig::default();
    let tank = Tank::default();
    let dt = 1.0 / cfg.frame_rate_hz;
    // Far from every wall: a run of straight actions along +x from the left wall's side.
    let mut robot = Robot::at(-45.0, 0.0, 0.0);
    let mut per_action = Vec::new();
    for _ in 0..6 {
        let x0 = robot.state.x;
        robot.begin_action(0.0);
        for _ in 0..cfg.frames_per_action {
            assert!(
                !robot.advance(&cfg.robot, &tank, dt),
                "the robot reached a wall"
            );
        }
        per_action.push(robot.state.x - x0);
    }
    // From rest the first action is shorter; from the third on it repeats.
    let steady = per_action[5];
    assert!((per_action[4] - steady).abs() < 1e-3, "{per_action:?}");

    let shim = Path::new(env!("CARGO_MANIFEST_DIR"))
        .join("../../lab/robotracker/fishprobe_robotracker.py");
    let text = std::fs::read_to_string(&shim).unwrap();
    let stated: f32 = text
        .lines()
        .find_map(|l| l.strip_prefix("SIMULATED_STEP_CM = "))
        .expect("the behaviour states SIMULATED_STEP_CM")
        .trim()
        .parse()
        .unwrap();
    assert!(
        (stated - steady).abs() <= 0.05,
        "{} states SIMULATED_STEP_CM = {stated} cm, the simulated robot covers {steady:.3} cm \
         per action (per action from rest: {per_action:?})",
        shim.display()
    );
}
