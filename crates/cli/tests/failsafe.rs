//! The live stack fails safe: a robot never runs on stale tracking, a stalled peer is dropped,
//! a trial file is never lost. Each test is an attack that the live stack once failed,
//! against `fishprobe live biotracker` with a stand-in BioTracker core, a robot program on its
//! sink, or `fishprobe live serve` with a client.

#![allow(clippy::unwrap_used)] // a failure is a test failure

mod common;

use common::fresh_dir as dir;
use common::tracker::{
    config_json, configured, connect, experiment, final_trial, free_addr, observer, observer_with,
    runtime, timed_robot_program, wait_exit, Configured, FakeCore, FPS, PROTOCOL,
};
use fishprobe_live::biotracker::grpc;
use fishprobe_live::biotracker::schema::{ComponentConfig, Empty, Experiment, RecordingState};
use std::time::{Duration, Instant};

/// A tracker whose frame counter sticks in the control phase: the repeated frames are no sign
/// of life, so the robot is stopped within the stale time and its watchdog gets no ticks.
#[test]
fn a_stuck_frame_counter_stops_the_robot_within_the_stale_time_and_feeds_no_watchdog() {
    let Configured {
        d: _d,
        core: _core,
        address: _address,
        sink,
        log: _log,
        mut child,
        out: _out,
        rt,
        mut client,
        protocol: _protocol,
    } = configured("failsafe-stuck");
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
    let Configured {
        d: _d,
        core: _core,
        address: _address,
        sink,
        log,
        mut child,
        out,
        rt,
        mut client,
        protocol: _protocol,
    } = configured("failsafe-skeleton");
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
    let t = final_trial(&file, &log, Duration::from_secs(10));
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

fn call_config(
    rt: &tokio::runtime::Runtime,
    client: &grpc::Client,
    json: String,
) -> Result<(), tonic::Status> {
    rt.block_on(client.clone().call::<ComponentConfig, Empty>(
        grpc::SET_CONFIG_PATH,
        ComponentConfig {
            config_json: json,
            id: "fishprobe".into(),
        },
    ))
    .map(|_| ())
}

/// A mistaken first configuration does not cost a BioTracker restart: it is answered (the
/// core keeps the component), every problem is logged at once, the robot stays stopped, and
/// the corrected entry is taken. A later refusal names its reasons, a huge value cut short.
#[test]
fn a_refused_first_config_lists_every_problem_and_a_corrected_one_is_taken() {
    let d = dir("failsafe-config");
    let protocol = d.join("protocol.toml");
    std::fs::write(&protocol, PROTOCOL).unwrap();
    let core = FakeCore::start();
    let (address, sink) = (free_addr(), free_addr());
    let log = d.join("observer.log");
    let mut child = observer(address, core.addr, &log, false);
    let out = d.join("trials");
    let rt = runtime();
    let client = rt.block_on(connect(address));
    let good = config_json(&out, &protocol, sink, core.addr);
    // Three problems: the fish id is the robot's, a misspelt key, the core's port 0.
    let mut wrong: serde_json::Value = serde_json::from_str(&good).unwrap();
    wrong["fish_ids"] = serde_json::json!([1]);
    wrong["folow_recording"] = serde_json::json!(true);
    wrong["core"] = serde_json::json!("127.0.0.1:0");
    call_config(&rt, &client, wrong.to_string()).unwrap();
    let text = std::fs::read_to_string(&log).unwrap();
    for needle in [
        "first configuration is refused",
        "entity id 1 is given twice",
        "unknown key `folow_recording`",
    ] {
        assert!(text.contains(needle), "{needle} not in the log:\n{text}");
    }
    // A misspelt key is reported before the values are checked; once fixed, the port.
    wrong.as_object_mut().unwrap().remove("folow_recording");
    let e = call_config(&rt, &client, wrong.to_string()).unwrap_err();
    assert!(
        e.message().contains("entity id 1 is given twice") && e.message().contains("port 0"),
        "{e:?}"
    );
    // Nothing configured: no robot sink yet, so nothing drives a robot.
    assert!(std::net::TcpStream::connect(sink).is_err());
    // The corrected entry is taken and runs trials.
    call_config(&rt, &client, good.clone()).unwrap();
    let robot = timed_robot_program(sink);
    // Connected when it has read the robot's current state (a stop).
    let start = Instant::now();
    while robot.lock().unwrap().is_empty() {
        assert!(start.elapsed() < Duration::from_secs(5), "never connected");
        std::thread::sleep(Duration::from_millis(20));
    }
    let mut c = client.clone();
    for k in 0..30u32 {
        rt.block_on(c.call::<Experiment, Empty>(
            grpc::UPDATE_PATH,
            experiment(
                RecordingState::Recording,
                k,
                [0.0, 0.0, 0.0],
                [5.0, 5.0, 0.0],
            ),
        ))
        .unwrap();
    }
    let start = Instant::now();
    while !robot
        .lock()
        .unwrap()
        .iter()
        .any(|(_, l)| l.contains("\"tick\""))
    {
        assert!(start.elapsed() < Duration::from_secs(5), "no ticks");
        std::thread::sleep(Duration::from_millis(20));
    }
    // A later refusal (a trial is not running; the policy names a 900 kB path): the reason is
    // cut short, the log line too.
    rt.block_on(c.call::<Experiment, Empty>(
        grpc::UPDATE_PATH,
        experiment(
            RecordingState::Finished,
            31,
            [0.0, 0.0, 0.0],
            [5.0, 5.0, 0.0],
        ),
    ))
    .unwrap();
    let huge = good.replace("scripted:goal-seeker", &"x".repeat(900_000));
    let e = call_config(&rt, &client, huge).unwrap_err();
    assert!(e.message().len() < 4_000, "{} bytes", e.message().len());
    assert!(
        e.message().contains("more bytes)"),
        "{}",
        &e.message()[..200]
    );
    let longest = std::fs::read_to_string(&log)
        .unwrap()
        .lines()
        .map(str::len)
        .max()
        .unwrap();
    assert!(longest < 20_000, "a log line of {longest} bytes");
    let _ = child.kill();
    let _ = child.wait();
}

/// A `set_config` whose settings file is a FIFO (a hung disk) loads beside tracking: every
/// update is answered promptly meanwhile, the heartbeat keeps the component alive.
#[test]
fn updates_are_answered_while_a_set_config_loads() {
    let d = dir("failsafe-slow-config");
    let fifo = d.join("protocol.toml");
    let status = std::process::Command::new("mkfifo")
        .arg(&fifo)
        .status()
        .unwrap();
    assert!(status.success());
    let protocol = d.join("good.toml");
    std::fs::write(&protocol, PROTOCOL).unwrap();
    let core = FakeCore::start();
    let (address, sink) = (free_addr(), free_addr());
    let log = d.join("observer.log");
    let mut child = observer(address, core.addr, &log, false);
    let rt = runtime();
    let client = rt.block_on(connect(address));
    // A good configuration first, so that the slow one is a later edit.
    call_config(
        &rt,
        &client,
        config_json(&d.join("t"), &protocol, sink, core.addr),
    )
    .unwrap();
    let slow = config_json(&d.join("t"), &fifo, sink, core.addr);
    // The slow call has its own runtime and connection: a channel's timers and connection
    // task run on the runtime that made it, which this thread stops driving at `join`.
    let pending = std::thread::spawn(move || {
        let rt = runtime();
        let client = rt.block_on(connect(address));
        call_config(&rt, &client, slow)
    });
    std::thread::sleep(Duration::from_millis(300));
    let mut c = client.clone();
    let mut slowest = Duration::ZERO;
    for k in 0..50u32 {
        let t = Instant::now();
        rt.block_on(c.call::<Experiment, Empty>(
            grpc::UPDATE_PATH,
            experiment(
                RecordingState::Initial,
                1000 + k,
                [0.0, 0.0, 0.0],
                [5.0, 5.0, 0.0],
            ),
        ))
        .unwrap();
        slowest = slowest.max(t.elapsed());
        std::thread::sleep(Duration::from_millis(40));
    }
    assert!(
        slowest < Duration::from_millis(200),
        "an update waited {slowest:?} for the loading config"
    );
    // (The test's client gives up on its call after 2 s; the component is still loading.)
    let _ = pending.join();
    assert_eq!(
        std::fs::read_to_string(&log)
            .unwrap()
            .matches("configured (")
            .count(),
        1
    );
    // The writer comes and goes: the loader reads an empty file, and the configuration (the
    // protocol's defaults) is taken.
    drop(std::fs::OpenOptions::new().write(true).open(&fifo).unwrap());
    let start = Instant::now();
    while std::fs::read_to_string(&log)
        .unwrap()
        .matches("configured (")
        .count()
        < 2
    {
        assert!(start.elapsed() < Duration::from_secs(5), "never taken");
        std::thread::sleep(Duration::from_millis(20));
    }
    assert!(child.try_wait().unwrap().is_none(), "the component died");
    let text = std::fs::read_to_string(&log).unwrap();
    assert!(!text.contains("tracker core gone"), "{text}");
    let _ = child.kill();
    let _ = child.wait();
}

/// Hundreds of idle connections to the gRPC port, more than the observer's descriptor limit:
/// they are capped and the quietest closed, tracking goes on, and the trial file is written.
#[test]
fn idle_connections_cannot_exhaust_descriptors_and_the_trial_is_written() {
    let d = dir("failsafe-descriptors");
    let protocol = d.join("protocol.toml");
    std::fs::write(&protocol, PROTOCOL).unwrap();
    let core = FakeCore::start();
    let (address, sink) = (free_addr(), free_addr());
    let log = d.join("observer.log");
    let mut child = observer_with(address, core.addr, &log, false, Some(128));
    let out = d.join("trials");
    let rt = runtime();
    let mut client = rt.block_on(connect(address));
    call_config(&rt, &client, config_json(&out, &protocol, sink, core.addr)).unwrap();
    let (r, f) = ([-10.0f32, 0.0, 0.0], [10.0f32, 5.0, 1.0]);
    let mut send = |e: Experiment| {
        rt.block_on(client.call::<Experiment, Empty>(grpc::UPDATE_PATH, e))
            .map(|_| ())
    };
    for k in 0..25u32 {
        send(experiment(RecordingState::Recording, k, r, f)).unwrap();
        std::thread::sleep(Duration::from_millis(40));
    }
    // 400 idle connections (the limit is 128), a few at a time between frames.
    let mut idle = Vec::new();
    for k in 25..125u32 {
        for _ in 0..4 {
            if let Ok(s) = std::net::TcpStream::connect(address) {
                idle.push(s);
            }
        }
        send(experiment(RecordingState::Recording, k, r, f))
            .unwrap_or_else(|e| panic!("frame {k} not answered: {e:?}"));
        std::thread::sleep(Duration::from_millis(10));
    }
    let fds = std::fs::read_dir(format!("/proc/{}/fd", child.id()))
        .unwrap()
        .count();
    assert!(fds < 100, "the observer holds {fds} descriptors");
    send(experiment(RecordingState::Finished, 125, r, f)).unwrap();
    let file = out.join("GoalSeeker__Real/2026-12-07_fake.hdf5");
    let t = final_trial(&file, &log, Duration::from_secs(10));
    assert_eq!(t.entities[0].positions.len(), 125);
    drop(idle);
    let _ = child.kill();
    let _ = child.wait();
}

/// Sends `signal` (a name for `kill -s`) to the process `pid`.
fn signal(pid: u32, signal: &str) {
    let s = std::process::Command::new("kill")
        .args(["-s", signal, &pid.to_string()])
        .status()
        .unwrap();
    assert!(s.success(), "kill -s {signal} {pid}");
}

/// The observer's process, the robot program's timed lines and the trial file's path.
type MidTrial = (
    std::process::Child,
    std::sync::Arc<std::sync::Mutex<Vec<(Instant, String)>>>,
    std::path::PathBuf,
);

/// An observer in a trial of 150 frames, with a robot program on its sink: returns the child,
/// the robot program's lines and the trial file's path.
fn observer_mid_trial(d: &std::path::Path, core: &FakeCore) -> MidTrial {
    let protocol = d.join("protocol.toml");
    std::fs::write(&protocol, PROTOCOL).unwrap();
    let (address, sink) = (free_addr(), free_addr());
    let child = observer(address, core.addr, &d.join("observer.log"), false);
    let out = d.join("trials");
    let rt = runtime();
    let mut client = rt.block_on(connect(address));
    call_config(&rt, &client, config_json(&out, &protocol, sink, core.addr)).unwrap();
    let robot = timed_robot_program(sink);
    let start = Instant::now();
    while robot.lock().unwrap().is_empty() {
        assert!(start.elapsed() < Duration::from_secs(5), "never connected");
        std::thread::sleep(Duration::from_millis(20));
    }
    let (r, f) = ([-10.0f32, 0.0, 0.0], [10.0f32, 5.0, 1.0]);
    for k in 0..150u32 {
        rt.block_on(client.call::<Experiment, Empty>(
            grpc::UPDATE_PATH,
            experiment(RecordingState::Recording, k, r, f),
        ))
        .unwrap();
        std::thread::sleep(Duration::from_millis(4));
    }
    // The session has taken the frames (its queue drains within milliseconds).
    std::thread::sleep(Duration::from_millis(200));
    (
        child,
        robot,
        out.join("GoalSeeker__Real/2026-12-07_fake.hdf5"),
    )
}

/// SIGTERM, SIGINT or SIGHUP mid-trial (as BioTracker's shutdown or a closed terminal sends):
/// the robot program's last line is a stop saying why, the trial file is complete with that
/// reason, and the status is 128 + the signal.
#[test]
fn a_polite_signal_mid_trial_stops_the_robot_and_writes_the_trial() {
    for (name, number) in [("TERM", 15), ("INT", 2), ("HUP", 1)] {
        let d = dir(&format!("failsafe-sig{name}"));
        let core = FakeCore::start();
        let (mut child, robot, file) = observer_mid_trial(&d, &core);
        signal(child.id(), name);
        let status = wait_exit(&mut child, Duration::from_secs(5))
            .unwrap_or_else(|| panic!("SIG{name}: still running after 5 s"));
        assert_eq!(status.code(), Some(128 + number), "SIG{name}");
        std::thread::sleep(Duration::from_millis(100));
        let lines = robot.lock().unwrap().clone();
        let last = &lines.last().unwrap().1;
        assert!(
            last.contains("\"stop\":true") && last.contains(&format!("received SIG{name}")),
            "SIG{name}: the robot program's last line: {last}"
        );
        let t = fishprobe_io::read_trial(&file).unwrap();
        assert_eq!(t.entities[0].positions.len(), 150, "SIG{name}");
        let record: serde_json::Value = serde_json::from_str(&t.task.unwrap().config_json).unwrap();
        assert_eq!(
            record["front_end"]["ended_because"],
            format!("fishprobe received SIG{name}")
        );
    }
}

/// SIGKILL cannot be caught: the trial's last checkpoint (every 2 s of frames) is a readable
/// file of the frames so far, saying it is one.
#[test]
fn a_kill_mid_trial_leaves_a_readable_checkpoint() {
    let d = dir("failsafe-sigkill");
    let core = FakeCore::start();
    let (mut child, _robot, file) = observer_mid_trial(&d, &core);
    signal(child.id(), "KILL");
    let _ = child.wait();
    let t = fishprobe_io::read_trial(&file).unwrap();
    let frames = t.entities[0].positions.len();
    assert!((100..=150).contains(&frames), "{frames} frames");
    let record: serde_json::Value = serde_json::from_str(&t.task.unwrap().config_json).unwrap();
    assert!(record["front_end"]["ended_because"]
        .as_str()
        .unwrap()
        .contains("checkpoint"));
}

/// `fishprobe live serve` asked to stop mid-trial: the client hears a stop with the reason and
/// `done`, the trial file is complete with that reason, the status is 143.
#[test]
fn live_serve_on_sigterm_stops_the_robot_and_writes_the_trial() {
    use fishprobe_live::protocol::{to_line, ClientMsg, FishPose, Pose};
    use std::io::{BufRead, BufReader, Write};
    let d = dir("failsafe-serve-sigterm");
    let protocol = d.join("protocol.toml");
    std::fs::write(&protocol, PROTOCOL).unwrap();
    let listen = free_addr();
    let out = d.join("trials");
    let mut child = std::process::Command::new(env!("CARGO_BIN_EXE_fishprobe"))
        .args(["live", "serve", "--policy", "scripted:goal-seeker"])
        .args(["--listen", &listen.to_string(), "--out"])
        .arg(&out)
        .arg("--config")
        .arg(&protocol)
        .stdout(std::process::Stdio::piped())
        .stderr(std::process::Stdio::piped())
        .spawn()
        .unwrap();
    let start = Instant::now();
    let s = loop {
        match std::net::TcpStream::connect(listen) {
            Ok(s) => break s,
            Err(_) if start.elapsed() < Duration::from_secs(20) => {
                std::thread::sleep(Duration::from_millis(20));
            }
            Err(e) => panic!("the bridge never listened: {e}"),
        }
    };
    let mut w = s.try_clone().unwrap();
    let mut r = BufReader::new(s);
    let hello = ClientMsg::Hello {
        protocol: 1,
        world_size_cm: [100.0, 100.0],
        tracking_hz: FPS,
        source: "lab".into(),
        token: None,
        sync: false,
    };
    w.write_all(to_line(&hello).as_bytes()).unwrap();
    let mut line = String::new();
    r.read_line(&mut line).unwrap();
    assert!(line.contains("welcome"), "{line}");
    let pose = |x: f32, y: f32| Some(Pose { x, y, heading: 0.0 });
    for k in 0..150u32 {
        let frame = ClientMsg::Frame {
            t: f64::from(k) / f64::from(FPS),
            robot: pose(-10.0, 0.0),
            fish: vec![FishPose {
                id: "f".into(),
                pose: pose(10.0, 5.0),
            }],
        };
        w.write_all(to_line(&frame).as_bytes()).unwrap();
        std::thread::sleep(Duration::from_millis(4));
    }
    std::thread::sleep(Duration::from_millis(200));
    signal(child.id(), "TERM");
    let mut tail = Vec::new();
    r.get_ref()
        .set_read_timeout(Some(Duration::from_secs(5)))
        .unwrap();
    for l in r.lines() {
        let Ok(l) = l else { break };
        tail.push(l);
    }
    let status = wait_exit(&mut child, Duration::from_secs(5)).expect("exits");
    assert_eq!(status.code(), Some(143));
    let n = tail.len();
    assert!(n >= 2, "{tail:?}");
    assert!(
        tail[n - 2].contains("\"stop\":true") && tail[n - 2].contains("received SIGTERM"),
        "{tail:?}"
    );
    assert!(tail[n - 1].contains("done"), "{tail:?}");
    let t = fishprobe_io::read_trial(&out.join("GoalSeeker__Real/trial_000.hdf5")).unwrap();
    assert_eq!(t.entities[0].positions.len(), 150);
    let record: serde_json::Value = serde_json::from_str(&t.task.unwrap().config_json).unwrap();
    assert_eq!(
        record["front_end"]["ended_because"],
        "fishprobe received SIGTERM"
    );
}
