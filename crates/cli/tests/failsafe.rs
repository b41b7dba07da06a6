//! The live stack fails safe: a robot never runs on stale tracking, a stalled peer is dropped,
//! a trial file is never lost. Each test is an attack that the live stack once failed,
//! against `fishprobe live biotracker` with a stand-in BioTracker core, a robot program on its
//! sink, or `fishprobe live serve` with a client.

#![allow(clippy::unwrap_used)] // a failure is a test failure

mod common;

use common::fresh_dir as dir;
use common::tracker::{
    config_json, connect, experiment, free_addr, observer, runtime, timed_robot_program, wait_exit,
    FakeCore, FPS, PROTOCOL,
};
use fishprobe_live::biotracker::grpc;
use fishprobe_live::biotracker::schema::{ComponentConfig, Empty, Experiment, RecordingState};
use std::time::{Duration, Instant};

/// A tracker whose frame counter sticks in the control phase: the repeated frames are no sign
/// of life, so the robot is stopped within the stale time and its watchdog gets no ticks.
#[test]
fn a_stuck_frame_counter_stops_the_robot_within_the_stale_time_and_feeds_no_watchdog() {
    let d = dir("failsafe-stuck");
    let protocol = d.join("protocol.toml");
    std::fs::write(&protocol, PROTOCOL).unwrap();
    let core = FakeCore::start();
    let (address, sink) = (free_addr(), free_addr());
    let log = d.join("observer.log");
    let mut child = observer(address, core.addr, &log, false);
    let out = d.join("trials");
    let rt = runtime();
    let mut client = rt.block_on(connect(address));
    rt.block_on(client.call::<ComponentConfig, Empty>(
        grpc::SET_CONFIG_PATH,
        ComponentConfig {
            config_json: config_json(&out, &protocol, sink, core.addr),
            id: "fishprobe".into(),
        },
    ))
    .unwrap();
    let robot = timed_robot_program(sink);
    let (r, f) = ([-10.0f32, 0.0, 0.0], [10.0f32, 5.0, 1.0]);
    let mut send = |e: Experiment| {
        rt.block_on(client.call::<Experiment, Empty>(grpc::UPDATE_PATH, e))
            .unwrap();
    };
    let start = Instant::now();
    // 3 s of good frames (control begins at 2 s), then frame 75 repeated for 2 s at 25 Hz.
    let mut stuck_at = None;
    for k in 0..125u32 {
        let due = start + Duration::from_secs_f64(f64::from(k) / f64::from(FPS));
        std::thread::sleep(due.saturating_duration_since(Instant::now()));
        let frame = k.min(75);
        if k == 76 {
            stuck_at = Some(Instant::now());
        }
        send(experiment(RecordingState::Recording, frame, r, f));
    }
    let stuck_at = stuck_at.unwrap();
    let lines = robot.lock().unwrap().clone();
    let stop = lines
        .iter()
        .find(|(at, l)| *at >= stuck_at && l.contains("\"stop\":true"))
        .unwrap_or_else(|| {
            let tail: Vec<&String> = lines.iter().rev().take(8).map(|(_, l)| l).collect();
            panic!("no stop after the counter stuck; the last lines: {tail:?}")
        });
    assert!(
        stop.1.contains("no tracking frame for"),
        "the stop says why: {}",
        stop.1
    );
    let after = stop.0.duration_since(stuck_at);
    assert!(
        after <= Duration::from_millis(650),
        "stopped {after:?} after the counter stuck (stale time 0.5 s)"
    );
    let late_ticks = lines
        .iter()
        .filter(|(at, l)| *at > stuck_at + Duration::from_millis(50) && l.contains("\"tick\""))
        .count();
    assert_eq!(late_ticks, 0, "repeated frames fed the watchdog");
    let _ = child.kill();
    let _ = child.wait();
    let _ = wait_exit(&mut child, Duration::from_secs(1));
}

/// Front and centre nodes swapped mid-trial: the frames are not of the trial's layout, so the
/// trial ends, with the reason, instead of storing them as if they were.
#[test]
fn a_skeleton_change_mid_trial_ends_the_trial_with_the_reason() {
    let d = dir("failsafe-skeleton");
    let protocol = d.join("protocol.toml");
    std::fs::write(&protocol, PROTOCOL).unwrap();
    let core = FakeCore::start();
    let (address, sink) = (free_addr(), free_addr());
    let log = d.join("observer.log");
    let mut child = observer(address, core.addr, &log, false);
    let out = d.join("trials");
    let rt = runtime();
    let mut client = rt.block_on(connect(address));
    rt.block_on(client.call::<ComponentConfig, Empty>(
        grpc::SET_CONFIG_PATH,
        ComponentConfig {
            config_json: config_json(&out, &protocol, sink, core.addr),
            id: "fishprobe".into(),
        },
    ))
    .unwrap();
    let robot = timed_robot_program(sink);
    let (r, f) = ([-10.0f32, 0.0, 0.0], [10.0f32, 5.0, 1.0]);
    for k in 0..60u32 {
        let mut e = experiment(RecordingState::Recording, k, r, f);
        if k >= 40 {
            let s = e.skeleton.as_mut().unwrap();
            std::mem::swap(&mut s.front_index, &mut s.center_index);
        }
        rt.block_on(client.call::<Experiment, Empty>(grpc::UPDATE_PATH, e))
            .unwrap();
        std::thread::sleep(Duration::from_millis(5));
    }
    let file = out.join("GoalSeeker__Real/2026-12-07_fake.hdf5");
    let start = Instant::now();
    while !file.exists() && start.elapsed() < Duration::from_secs(10) {
        std::thread::sleep(Duration::from_millis(20));
    }
    std::thread::sleep(Duration::from_millis(200));
    let t = fishprobe_io::read_trial(&file).unwrap();
    let record: serde_json::Value = serde_json::from_str(&t.task.unwrap().config_json).unwrap();
    let why = record["front_end"]["ended_because"]
        .as_str()
        .unwrap()
        .to_string();
    assert!(why.contains("the skeleton changed"), "{why}");
    assert_eq!(
        t.entities[0].positions.len(),
        40,
        "no frame of the new layout stored"
    );
    let lines = robot.lock().unwrap().clone();
    assert!(
        lines
            .iter()
            .any(|(_, l)| l.contains("\"stop\":true") && l.contains("skeleton changed")),
        "the robot program was not told why it stops"
    );
    let _ = child.kill();
    let _ = child.wait();
}
