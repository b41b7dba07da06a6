//! `fishprobe live biotracker` against a fake BioTracker core on loopback: a heartbeat server
//! and a client that configures the observer and sends it updates at 25 Hz, built from a
//! recorded trial, while a robot program reads the robot sink. No BioTracker needed.

#![allow(clippy::unwrap_used)] // a failure is a test failure

mod common;

use common::tracker::{
    config_json, configured, connect, experiment, final_trial, free_addr, observer,
    one_trial_bridge, record_trial, recorded_poses, robot_program, runtime, wait_exit, Configured,
    FakeCore, FPS, PROTOCOL,
};
use common::{fishprobe, fresh_dir as dir, stderr};
use fishprobe_live::biotracker::grpc::{self, Client};
use fishprobe_live::biotracker::schema::{ComponentConfig, Empty, Experiment, RecordingState};
use std::net::TcpListener;
use std::path::Path;
use std::time::{Duration, Instant};
use tonic::Code;

/// What `live replay` makes of a trial file with the same protocol.
fn replayed(d: &Path, file: &Path, protocol: &Path) -> fishprobe_io::TrialFile {
    let port = free_addr().port();
    let out = d.join("replayed");
    let mut bridge = one_trial_bridge(&out, port, protocol);
    let o = fishprobe(&[
        "live",
        "replay",
        file.to_str().unwrap(),
        "--connect",
        &format!("127.0.0.1:{port}"),
    ]);
    assert!(o.status.success(), "{}", stderr(&o));
    assert!(wait_exit(&mut bridge, Duration::from_secs(20)).is_some());
    fishprobe_io::read_trial(&out.join("GoalSeeker__Real/trial_000.hdf5")).unwrap()
}

#[test]
fn a_recording_through_the_observer_makes_the_trial_replay_makes_and_the_core_gone_stops_all() {
    let d = dir("biotracker-e2e");
    let protocol = d.join("protocol.toml");
    std::fs::write(&protocol, PROTOCOL).unwrap();
    let recorded = record_trial(&d, &protocol);
    let poses = recorded_poses(&recorded);
    assert!(poses.len() >= 200, "{}", poses.len());
    let want = replayed(&d, &recorded, &protocol);

    let mut core = FakeCore::start();
    let (address, sink) = (free_addr(), free_addr());
    let log = d.join("observer.log");
    let mut child = observer(address, core.addr, &log, false);
    let out = d.join("trials");
    let rt = runtime();
    let mut client = rt.block_on(connect(address));
    let cfg = ComponentConfig {
        config_json: config_json(&out, &protocol, sink, core.addr),
        id: "fishprobe".into(),
    };
    rt.block_on(client.call::<ComponentConfig, Empty>(grpc::SET_CONFIG_PATH, cfg.clone()))
        .unwrap();
    let robot = robot_program(sink);

    // Idle frames, then the recording at 25 Hz, then FINISHED after the protocol's end.
    let (r0, f0) = poses[0];
    let mut answers = Vec::new();
    let mut send = |client: &mut Client, e: Experiment| {
        let t = Instant::now();
        rt.block_on(client.call::<Experiment, Empty>(grpc::UPDATE_PATH, e))
            .unwrap();
        answers.push(t.elapsed());
    };
    for frame in 900..905 {
        send(
            &mut client,
            experiment(RecordingState::Initial, frame, r0, f0),
        );
    }
    let mut changed = None;
    let start = Instant::now();
    for (k, (r, f)) in poses.iter().enumerate() {
        // On the 25 Hz clock.
        let due = start + Duration::from_secs_f64(k as f64 / f64::from(FPS));
        std::thread::sleep(due.saturating_duration_since(Instant::now()));
        send(
            &mut client,
            experiment(RecordingState::Recording, k as u32, *r, *f),
        );
        if k == 100 {
            // Mid-trial: the same config is accepted, another refused with the reason.
            rt.block_on(client.call::<ComponentConfig, Empty>(grpc::SET_CONFIG_PATH, cfg.clone()))
                .unwrap();
            let mut other = cfg.clone();
            other.config_json = other
                .config_json
                .replace("\"fish_ids\":[2]", "\"fish_ids\":[3]");
            changed = Some(
                rt.block_on(client.call::<ComponentConfig, Empty>(grpc::SET_CONFIG_PATH, other))
                    .unwrap_err(),
            );
        }
    }
    let changed = changed.unwrap();
    assert_eq!(changed.code(), Code::FailedPrecondition);
    assert!(
        changed.message().contains("a trial is running"),
        "{changed:?}"
    );
    send(
        &mut client,
        experiment(RecordingState::Finished, poses.len() as u32, r0, f0),
    );
    // Every update answered at once (the core never waits for the trial's work).
    answers.sort();
    let p99 = answers[answers.len() * 99 / 100];
    assert!(p99 < Duration::from_millis(100), "p99 {p99:?}");

    // The trial lies beside the recording's files, named after them.
    let file = out.join("GoalSeeker__Real/2026-12-07_fake.hdf5");
    let got = final_trial(&file, &log, Duration::from_secs(10));
    let (g, w) = (got.task.as_ref().unwrap(), want.task.as_ref().unwrap());
    // The same commands at the same frames, the same goals: one engine behind both.
    assert_eq!(g.command_frames, w.command_frames);
    assert_eq!(g.goal_frames, w.goal_frames);
    assert_eq!(g.command_turns.len(), w.command_turns.len());
    for (a, b) in g.command_turns.iter().zip(&w.command_turns) {
        assert!((a - b).abs() < 1e-3, "turn {a} vs {b}");
    }
    assert_eq!(g.policy_sha256(), w.policy_sha256());
    // The robot program got the commands and a tick per frame.
    let lines = robot.lock().unwrap().clone();
    let ticks = lines.iter().filter(|l| l.contains("\"tick\"")).count();
    let commands = lines.iter().filter(|l| l.contains("\"command\"")).count();
    assert!(ticks >= poses.len(), "{ticks} ticks");
    assert!(commands >= w.command_frames.len(), "{commands} commands");

    // The core dies: the robot is stopped and the observer exits non-zero within 3 s.
    core.kill();
    let died = Instant::now();
    let status = wait_exit(&mut child, Duration::from_secs(3));
    let Some(status) = status else {
        let _ = child.kill();
        panic!(
            "still running 3 s after the core died; log:\n{}",
            std::fs::read_to_string(&log).unwrap_or_default()
        );
    };
    assert!(!status.success());
    assert!(died.elapsed() <= Duration::from_secs(3));
    let log_text = std::fs::read_to_string(&log).unwrap();
    assert!(log_text.contains("tracker core gone"), "{log_text}");
    // Between trials too, the robot program hears why fishprobe goes.
    let last = robot.lock().unwrap().last().cloned().unwrap_or_default();
    assert!(
        last.contains("\"stop\":true") && last.contains("tracker core gone"),
        "{last}"
    );
}

/// A message with a field of the given number holding raw bytes: garbage where the observer
/// expects an Experiment, or a huge one.
#[derive(Clone, PartialEq, prost::Message)]
struct Raw {
    #[prost(bytes = "vec", tag = "11")]
    features: Vec<u8>,
    #[prost(bytes = "vec", tag = "99")]
    padding: Vec<u8>,
}

#[test]
fn garbage_a_huge_message_and_a_flood_get_errors_or_drops_and_no_crash() {
    let d = dir("biotracker-hostile");
    let protocol = d.join("protocol.toml");
    std::fs::write(&protocol, PROTOCOL).unwrap();
    let core = FakeCore::start();
    let (address, sink) = (free_addr(), free_addr());
    let log = d.join("observer.log");
    let mut child = observer(address, core.addr, &log, true);
    let rt = runtime();
    let mut client = rt.block_on(connect(address));

    // A config that is not ours, and one that names a missing policy: refused with reasons.
    let probe = client.clone();
    let bad = |json: String| {
        rt.block_on(probe.clone().call::<ComponentConfig, Empty>(
            grpc::SET_CONFIG_PATH,
            ComponentConfig {
                config_json: json,
                id: "x".into(),
            },
        ))
        .unwrap_err()
    };
    // The first configuration is answered with success even when refused (the core would
    // drop the component for good otherwise); its problems go to the log. Later ones are
    // refused with the reasons.
    rt.block_on(probe.clone().call::<ComponentConfig, Empty>(
        grpc::SET_CONFIG_PATH,
        ComponentConfig {
            config_json: "{\"policy\": 3}".into(),
            id: "x".into(),
        },
    ))
    .unwrap();
    let e = bad("{\"policy\": 3}".into());
    assert_eq!(e.code(), Code::InvalidArgument);
    let e = bad(config_json(&d.join("t"), &protocol, sink, core.addr)
        .replace("scripted:goal-seeker", "/nonexistent/policy"));
    assert!(e.message().contains("/nonexistent/policy"), "{e:?}");
    // An output directory another command writes into (a bridge serving there): refused.
    let taken = d.join("taken");
    let mut other = common::bridge(&taken, free_addr().port(), &[]);
    let e = bad(config_json(&taken, &protocol, sink, core.addr));
    let _ = other.kill();
    let _ = other.wait();
    assert!(
        e.message().contains("in use by") && e.message().contains("live serve"),
        "{e:?}"
    );
    rt.block_on(client.call::<ComponentConfig, Empty>(
        grpc::SET_CONFIG_PATH,
        ComponentConfig {
            config_json: config_json(&d.join("t"), &protocol, sink, core.addr),
            id: "x".into(),
        },
    ))
    .unwrap();

    // A new config whose robot-sink port is taken: refused, and the one before stays.
    let taken_port = TcpListener::bind("127.0.0.1:0").unwrap();
    let e = bad(config_json(
        &d.join("t"),
        &protocol,
        taken_port.local_addr().unwrap(),
        core.addr,
    ));
    assert!(e.message().contains("robot sink on"), "{e:?}");

    // Garbage where the features should be: an error, not a crash.
    let garbage = Raw {
        features: vec![0xff; 64],
        padding: Vec::new(),
    };
    let e = rt
        .block_on(client.call::<Raw, Empty>(grpc::UPDATE_PATH, garbage))
        .unwrap_err();
    assert_ne!(e.code(), Code::Ok);
    // Two MiB: refused before it is decoded.
    let huge = Raw {
        features: Vec::new(),
        padding: vec![7; 2 << 20],
    };
    let e = rt
        .block_on(client.call::<Raw, Empty>(grpc::UPDATE_PATH, huge))
        .unwrap_err();
    assert_eq!(e.code(), Code::OutOfRange, "{e:?}");

    // A flood: 1,000 updates a second for 10 s, each answered promptly, memory bounded.
    let rss_kb = |pid: u32| -> u64 {
        std::fs::read_to_string(format!("/proc/{pid}/status"))
            .ok()
            .and_then(|s| {
                s.lines()
                    .find_map(|l| l.strip_prefix("VmRSS:"))
                    .and_then(|v| v.trim().trim_end_matches("kB").trim().parse().ok())
            })
            .unwrap_or(0)
    };
    let before = rss_kb(child.id());
    let p = [0.0f32, 0.0, 0.0];
    let start = Instant::now();
    let mut slowest = Duration::ZERO;
    let mut k = 0u32;
    while start.elapsed() < Duration::from_secs(10) {
        let due = start + Duration::from_micros(u64::from(k) * 1000);
        std::thread::sleep(due.saturating_duration_since(Instant::now()));
        let t = Instant::now();
        rt.block_on(client.call::<Experiment, Empty>(
            grpc::UPDATE_PATH,
            experiment(RecordingState::Recording, k, p, p),
        ))
        .unwrap();
        slowest = slowest.max(t.elapsed());
        k += 1;
    }
    let after = rss_kb(child.id());
    assert!(k >= 5_000, "only {k} updates in 10 s");
    assert!(
        slowest < Duration::from_millis(500),
        "slowest answer {slowest:?}"
    );
    assert!(
        after < before + 50_000,
        "memory grew from {before} kB to {after} kB"
    );
    assert!(child.try_wait().unwrap().is_none(), "the observer died");
    let _ = child.kill();
    let _ = child.wait();
    // The flood's frames made a trial under the config that stayed.
    assert!(
        d.join("t/GoalSeeker__Real/2026-12-07_fake.hdf5").exists(),
        "no trial under the kept config"
    );
    let text = std::fs::read_to_string(&log).unwrap();
    assert!(!text.contains("panicked"), "{text}");
}

#[test]
fn the_core_dying_mid_trial_stops_the_robot_and_keeps_the_trial_with_the_reason() {
    let Configured {
        d: _d,
        mut core,
        address: _address,
        sink,
        log,
        mut child,
        out,
        rt,
        mut client,
        protocol: _protocol,
    } = configured("biotracker-core-dies");
    let robot = robot_program(sink);
    let (r, f) = ([-10.0f32, 0.0, 0.0], [10.0f32, 5.0, 1.0]);
    let lost = [f32::NAN; 3];
    let start = Instant::now();
    let mut stale_sent = 0;
    for k in 0..70u32 {
        let due = start + Duration::from_secs_f64(f64::from(k) / f64::from(FPS));
        std::thread::sleep(due.saturating_duration_since(Instant::now()));
        // The robot is not tracked from frame 30 to 49 (0.8 s, past the 0.5 s stale time).
        let robot = if (30..50).contains(&k) { lost } else { r };
        rt.block_on(client.call::<Experiment, Empty>(
            grpc::UPDATE_PATH,
            experiment(RecordingState::Recording, k, robot, f),
        ))
        .unwrap();
        // Late and repeated frames, as overlapping updates arrive.
        if k % 10 == 5 {
            for late in [k, k - 1] {
                rt.block_on(client.call::<Experiment, Empty>(
                    grpc::UPDATE_PATH,
                    experiment(RecordingState::Recording, late, r, f),
                ))
                .unwrap();
                stale_sent += 1;
            }
        }
    }
    core.kill();
    let status = wait_exit(&mut child, Duration::from_secs(3));
    if status.is_none() {
        let _ = child.kill();
    }
    assert!(
        status.is_some_and(|s| !s.success()),
        "{status:?}; log:\n{}",
        std::fs::read_to_string(&log).unwrap_or_default()
    );
    let t = fishprobe_io::read_trial(&out.join("GoalSeeker__Real/2026-12-07_fake.hdf5")).unwrap();
    let record: serde_json::Value = serde_json::from_str(&t.task.unwrap().config_json).unwrap();
    assert_eq!(record["front_end"]["ended_because"], "tracker core gone");
    assert_eq!(t.entities[0].positions.len(), 70);
    // Every late or repeated frame dropped and counted.
    assert_eq!(record["front_end"]["stale_updates_dropped"], stale_sent);
    // The robot was stopped at the first frame its gap reached 0.5 s: last seen at frame 29,
    // stopped at frame 42 (1.68 s - 1.16 s = 0.52 s), and the gap recorded.
    let stops = record["stops"].as_array().unwrap();
    assert!(
        stops.iter().any(
            |s| s["frame"] == 42 && s["reason"].as_str().unwrap().contains("robot not tracked")
        ),
        "{stops:?}"
    );
    assert_eq!(
        record["tracking_gaps_frames"],
        serde_json::json!([[29, 50]])
    );
    let last = robot.lock().unwrap().last().cloned().unwrap_or_default();
    assert!(
        last.contains("\"stop\":true") && last.contains("tracker core gone"),
        "{last}"
    );
}
