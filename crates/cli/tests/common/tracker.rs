//! Helpers of the tests that put fishprobe beside a BioTracker v4 core (a fake one, or the
//! real one in the opt-in test): a recorded trial's poses, a robot program on the sink.

#![allow(clippy::unwrap_used)] // a failure is a test failure

use super::{fishprobe, stderr};
use std::io::{BufRead, BufReader};
use std::net::{SocketAddr, TcpListener, TcpStream};
use std::path::{Path, PathBuf};
use std::process::Child;
use std::sync::{Arc, Mutex};
use std::time::{Duration, Instant};

/// The short protocol of these tests: 2 s of habituation, 6 s of control.
pub const PROTOCOL: &str = "habituation_s = 2.0\nrelease_s = 1.0\ncontrol_s = 6.0\n";
pub const FPS: f32 = 25.0;

pub fn free_addr() -> SocketAddr {
    TcpListener::bind("127.0.0.1:0")
        .unwrap()
        .local_addr()
        .unwrap()
}

pub fn runtime() -> tokio::runtime::Runtime {
    tokio::runtime::Builder::new_current_thread()
        .enable_all()
        .build()
        .unwrap()
}

pub fn config_json(out: &Path, protocol: &Path, sink: SocketAddr, core: SocketAddr) -> String {
    serde_json::json!({
        "policy": "scripted:goal-seeker",
        "out": out,
        "robot_id": 1,
        "fish_ids": [2],
        "robot_sink": sink.to_string(),
        "core": core.to_string(),
        "config": protocol,
    })
    .to_string()
}

/// Robot and fish poses (x, y, heading) per frame of a recorded trial, with the headings
/// `fishprobe live replay` sends.
pub fn recorded_poses(file: &Path) -> Vec<([f32; 3], [f32; 3])> {
    let t = fishprobe_io::read_trial(file).unwrap();
    let robot = t.robot().unwrap();
    let fish = t.fish().next().unwrap();
    let rh = robot.headings_from_motion(0.1);
    let fh = fish.headings_checked(0.1, std::f32::consts::FRAC_PI_2).0;
    (0..robot.frames().min(fish.frames()))
        .map(|k| {
            let r = robot.positions[k];
            let f = fish.positions[k];
            ([r[0], r[1], rh[k]], [f[0], f[1], fh[k]])
        })
        .collect()
}

/// Lines the robot program read from the sink, collected on a thread.
pub fn robot_program(sink: SocketAddr) -> Arc<Mutex<Vec<String>>> {
    let lines = Arc::new(Mutex::new(Vec::new()));
    let keep = Arc::clone(&lines);
    std::thread::spawn(move || {
        let start = Instant::now();
        let s = loop {
            match TcpStream::connect(sink) {
                Ok(s) => break s,
                Err(_) if start.elapsed() < Duration::from_secs(20) => {
                    std::thread::sleep(Duration::from_millis(20));
                }
                Err(e) => panic!("the robot sink never listened: {e}"),
            }
        };
        for l in BufReader::new(s).lines() {
            let Ok(l) = l else { break };
            keep.lock().unwrap().push(l);
        }
    });
    lines
}

pub fn wait_exit(child: &mut Child, within: Duration) -> Option<std::process::ExitStatus> {
    let start = Instant::now();
    while start.elapsed() < within {
        if let Some(s) = child.try_wait().unwrap() {
            return Some(s);
        }
        std::thread::sleep(Duration::from_millis(20));
    }
    None
}

/// A bridge for one trial of `protocol` into `out`.
pub fn one_trial_bridge(out: &Path, port: u16, protocol: &Path) -> Child {
    super::bridge(
        out,
        port,
        &["--trials", "1", "--config", protocol.to_str().unwrap()],
    )
}

/// A recorded trial of the short protocol (the virtual lab through a bridge with it).
pub fn record_trial(d: &Path, protocol: &Path) -> PathBuf {
    let port = free_addr().port();
    let out = d.join("recorded");
    let mut bridge = one_trial_bridge(&out, port, protocol);
    let o = fishprobe(&[
        "lab",
        "--policy",
        "scripted:goal-seeker",
        "--connect",
        &format!("127.0.0.1:{port}"),
        "--out",
        out.to_str().unwrap(),
    ]);
    assert!(o.status.success(), "{}", stderr(&o));
    assert!(wait_exit(&mut bridge, Duration::from_secs(20)).is_some());
    out.join("GoalSeeker__VirtualLab/trial_000.hdf5")
}
