//! The bridge against the virtual lab and against hostile clients, over loopback.

#![allow(clippy::unwrap_used)] // a failure is a test failure

use fishprobe_io::{read_trial, TrialKind};
use fishprobe_live::host::TrialOutcome;
use fishprobe_live::lab::{run_trial, LabConfig};
use fishprobe_live::protocol::{to_line, ClientMsg, FishPose, Pose};
use fishprobe_live::server::{serve, BridgeGuard, ServeOptions};
use fishprobe_live::session::LiveConfig;
use fishprobe_sim::{ControlInput, Controller, SimRng, TaskParams};
use rand::{RngExt, SeedableRng};
use std::io::{BufRead, BufReader, Write};
use std::net::{SocketAddr, TcpListener, TcpStream};
use std::path::PathBuf;
use std::thread::JoinHandle;

/// Turns toward the goal sector of the observation (a stand-in for a trained policy).
#[derive(Clone)]
struct GoalSeeker;
impl Controller for GoalSeeker {
    fn name(&self) -> String {
        "Seeker".into()
    }
    fn act(&mut self, input: &ControlInput<'_>, _rng: &mut SimRng) -> f32 {
        let goal = &input.obs[72..108];
        let (i, _) = goal
            .iter()
            .enumerate()
            .fold((0, -1.0f32), |b, (i, &v)| if v > b.1 { (i, v) } else { b });
        -std::f32::consts::PI + (i as f32 + 0.5) * std::f32::consts::PI / 18.0
    }
}

fn tmp(tag: &str) -> fishprobe_io::ScratchDir {
    fishprobe_io::ScratchDir::for_test(&format!("live-{tag}"))
}

fn short() -> LiveConfig {
    LiveConfig {
        habituation_s: 6.0,
        release_s: 3.0,
        control_s: 60.0,
        ..LiveConfig::default()
    }
}

type Served = Result<Vec<TrialOutcome>, fishprobe_live::LiveError>;

/// A bridge for `trials` trials into `out`, flown by `pilot`'s copies, on its own thread.
fn bridge_with(
    out: PathBuf,
    trials: usize,
    live: LiveConfig,
    pilot: impl Controller + Clone + 'static,
) -> (SocketAddr, JoinHandle<Served>) {
    let listener = TcpListener::bind("127.0.0.1:0").unwrap();
    let addr = listener.local_addr().unwrap();
    let opts = ServeOptions {
        live,
        task: TaskParams::default(),
        out,
        token: None,
        max_trials: Some(trials),
        fish_label: "live guppy".into(),
        guard: BridgeGuard::default(),
    };
    let h = std::thread::spawn(move || {
        serve(
            &listener,
            &opts,
            &mut || Ok(Box::new(pilot.clone()) as Box<dyn Controller>),
            |_| {},
        )
    });
    (addr, h)
}

fn bridge(
    out: PathBuf,
    trials: usize,
    live: LiveConfig,
) -> (SocketAddr, JoinHandle<Vec<TrialOutcome>>) {
    let (addr, h) = bridge_with(out, trials, live, GoalSeeker);
    (addr, std::thread::spawn(move || h.join().unwrap().unwrap()))
}

#[test]
fn a_virtual_trial_through_the_bridge_gives_a_valid_trial_file_with_goals() {
    let out = tmp("lab");
    let (addr, h) = bridge(out.to_path_buf(), 1, short());
    let lab = LabConfig {
        dropouts_per_min: 0.0,
        ..LabConfig::default()
    };
    let t = run_trial(addr, &lab, 3).unwrap();
    let outcomes = h.join().unwrap();
    assert!(outcomes[0].complete);
    assert!(t.file.contains("Seeker__VirtualLab"), "{}", t.file);
    let f = read_trial(std::path::Path::new(&t.file)).unwrap();
    let task = f.task.as_ref().unwrap();
    assert_eq!(task.kind, TrialKind::Virtual);
    assert_eq!(task.control_start_frame, 150);
    assert_eq!(
        f.robot().unwrap().positions.len(),
        66 * 25,
        "every frame stored"
    );
    assert_eq!(
        task.command_frames.len(),
        60,
        "one command per second of control"
    );
    assert_eq!(task.goal_frames.len() as u32, t.goals_reached);
    assert_eq!(
        t.policy_sha256, None,
        "a scripted pilot has no weights to name"
    );
    assert!(
        t.goals_reached >= 1,
        "a goal-seeking robot leads a virtual guppy to a goal in a minute"
    );
    // Deterministic for a seed.
    let scratch = tmp("lab2");
    let (addr, h) = bridge(scratch.to_path_buf(), 1, short());
    let t2 = run_trial(addr, &lab, 3).unwrap();
    h.join().unwrap();
    assert_eq!(t2.goals_reached, t.goals_reached);
    let f2 = read_trial(std::path::Path::new(&t2.file)).unwrap();
    assert_eq!(
        f2.fish().next().unwrap().positions,
        f.fish().next().unwrap().positions
    );
}

/// At the tracker's pace a trial takes its real time, and is the same trial.
#[test]
fn a_virtual_trial_at_the_trackers_pace_takes_its_time_and_is_the_same() {
    let brief = LiveConfig {
        habituation_s: 1.0,
        release_s: 0.5,
        control_s: 1.0,
        ..LiveConfig::default()
    };
    let mut files = Vec::new();
    for real_time in [false, true] {
        let out = tmp(&format!("pace-{real_time}"));
        let (addr, h) = bridge(out.to_path_buf(), 1, brief.clone());
        let lab = LabConfig {
            real_time,
            ..LabConfig::default()
        };
        let start = std::time::Instant::now();
        let t = run_trial(addr, &lab, 9).unwrap();
        let took = start.elapsed().as_secs_f64();
        h.join().unwrap();
        if real_time {
            // 2 s of protocol, at 25 frames a second.
            assert!(took >= 1.9, "a real-time trial took {took:.2} s");
        }
        let f = read_trial(std::path::Path::new(&t.file)).unwrap();
        files.push((f.fish().next().unwrap().positions.clone(), t.goals_reached));
        drop(out);
    }
    assert_eq!(files[0], files[1]);
}

#[test]
fn dropouts_stop_the_robot_within_one_frame_of_the_timeout() {
    let out = tmp("dropouts");
    let (addr, h) = bridge(out.to_path_buf(), 1, short());
    let lab = LabConfig {
        dropouts_per_min: 20.0,
        dropout_min_s: 0.6,
        dropout_max_s: 1.5,
        ..LabConfig::default()
    };
    let t = run_trial(addr, &lab, 5).unwrap();
    h.join().unwrap();
    assert!(t.stops > 0, "no stop despite dropouts");
    let f = read_trial(std::path::Path::new(&t.file)).unwrap();
    let fish = &f.fish().next().unwrap().positions;
    let cfg: serde_json::Value =
        serde_json::from_str(&f.task.as_ref().unwrap().config_json).unwrap();
    let stale_frames = (0.5f64 * 25.0).round() as i64;
    let mut checked = 0;
    for s in cfg["stops"].as_array().unwrap() {
        let frame = s["frame"].as_i64().unwrap();
        if !s["reason"].as_str().unwrap().contains("fish not tracked") {
            continue;
        }
        // Before the release (frame 75) the fish is in its container and not required.
        let release_frame = 75;
        let last_tracked = (0..frame)
            .rev()
            .find(|&k| fish[k as usize][0].is_finite())
            .unwrap_or(0);
        let last_good = last_tracked.max(release_frame - 1);
        let late = frame - (last_good + stale_frames);
        assert!(
            (0..=1).contains(&late),
            "stop at {frame}, last good {last_good}: {late} frames late"
        );
        checked += 1;
    }
    assert!(checked > 0);
    assert!(cfg["tracking_gaps_frames"].as_array().unwrap().len() as u64 >= 1);
}

fn hello() -> String {
    to_line(&ClientMsg::Hello {
        protocol: 1,
        world_size_cm: [100.0, 100.0],
        tracking_hz: 25.0,
        source: "lab".into(),
        token: None,
        sync: false,
    })
}

fn frame(t: f64) -> String {
    to_line(&ClientMsg::Frame {
        t,
        robot: Some(Pose {
            x: 0.0,
            y: 0.0,
            heading: 0.0,
        }),
        fish: vec![FishPose {
            id: "f".into(),
            pose: Some(Pose {
                x: 10.0,
                y: 10.0,
                heading: 1.0,
            }),
        }],
    })
}

#[test]
fn hostile_clients_never_crash_the_bridge_nor_lose_frames() {
    let out = tmp("fuzz");
    let clients = 12;
    let (addr, h) = bridge(out.to_path_buf(), clients, short());
    let mut rng = rand_xoshiro::Xoshiro256PlusPlus::seed_from_u64(11);
    let mut sent_frames = Vec::new();
    for c in 0..clients {
        let mut s = TcpStream::connect(addr).unwrap();
        s.write_all(hello().as_bytes()).unwrap();
        let mut r = BufReader::new(s.try_clone().unwrap());
        let mut welcome = String::new();
        r.read_line(&mut welcome).unwrap();
        assert!(welcome.contains("welcome"), "{welcome}");
        let mut good = 0u64;
        let n = rng.random_range(10..400);
        for k in 0..n {
            let t = f64::from(k) * 0.04;
            let garbage: Vec<u8> = match rng.random_range(0..10) {
                0 => (0..rng.random_range(1..200))
                    .map(|_| rng.random::<u8>())
                    .filter(|b| *b != b'\n')
                    .chain([b'\n'])
                    .collect(),
                1 => {
                    let mut v = vec![b'x'; 70_000 + rng.random_range(0..100_000)];
                    v.push(b'\n');
                    v
                }
                2 => b"{\"type\":\"frame\",\"t\":\"soon\"}\n".to_vec(),
                _ => Vec::new(),
            };
            if !garbage.is_empty() && s.write_all(&garbage).is_err() {
                break;
            }
            if s.write_all(frame(t).as_bytes()).is_err() {
                break;
            }
            good += 1;
        }
        // Half the clients leave without a word, half say end.
        if c % 2 == 0 {
            let _ = s.write_all(to_line(&ClientMsg::End).as_bytes());
        }
        let _ = s.shutdown(std::net::Shutdown::Write);
        // Wait until the bridge has finished with this client (it closes the connection).
        let mut rest = String::new();
        while r.read_line(&mut rest).map(|n| n > 0).unwrap_or(false) {}
        sent_frames.push(good);
    }
    let outcomes = h.join().unwrap();
    assert_eq!(outcomes.len(), clients);
    for (o, sent) in outcomes.iter().zip(&sent_frames) {
        let f = read_trial(o.file.as_ref().unwrap()).unwrap();
        let recorded = f
            .fish()
            .next()
            .unwrap()
            .positions
            .iter()
            .filter(|p| p[0].is_finite())
            .count() as u64;
        assert_eq!(
            recorded,
            *sent,
            "{}: frames lost",
            o.file.as_ref().unwrap().display()
        );
    }
}

#[test]
fn a_wrong_handshake_is_refused_with_a_reason() {
    let scratch = tmp("refuse");
    let (addr, _h) = bridge(scratch.to_path_buf(), 1, short());
    let mut s = TcpStream::connect(addr).unwrap();
    let bad = to_line(&ClientMsg::Hello {
        protocol: 1,
        world_size_cm: [200.0, 100.0],
        tracking_hz: 25.0,
        source: "lab".into(),
        token: None,
        sync: false,
    });
    s.write_all(bad.as_bytes()).unwrap();
    let mut line = String::new();
    BufReader::new(s).read_line(&mut line).unwrap();
    assert!(
        line.contains("error") && line.contains("100 x 100"),
        "{line}"
    );
}

#[test]
fn a_bridge_with_a_token_refuses_a_hello_without_it() {
    let listener = TcpListener::bind("127.0.0.1:0").unwrap();
    let addr = listener.local_addr().unwrap();
    let scratch = tmp("token");
    let opts = ServeOptions {
        live: short(),
        task: TaskParams::default(),
        out: scratch.to_path_buf(),
        token: Some("s3cret".into()),
        max_trials: Some(1),
        fish_label: "live guppy".into(),
        guard: BridgeGuard::default(),
    };
    std::thread::spawn(move || {
        let _ = serve(
            &listener,
            &opts,
            &mut || Ok(Box::new(GoalSeeker) as Box<dyn Controller>),
            |_| {},
        );
    });
    let mut s = TcpStream::connect(addr).unwrap();
    s.write_all(hello().as_bytes()).unwrap();
    let mut line = String::new();
    BufReader::new(s).read_line(&mut line).unwrap();
    assert!(line.contains("token"), "{line}");
}

/// The goal-seeker standing in for a trained policy with weights of fingerprint `.0`.
#[derive(Clone)]
struct Weighted(&'static str);
impl Controller for Weighted {
    fn name(&self) -> String {
        "Zone".into()
    }
    fn fingerprint(&self) -> Option<String> {
        Some(self.0.into())
    }
    fn act(&mut self, input: &ControlInput<'_>, rng: &mut SimRng) -> f32 {
        GoalSeeker.act(input, rng)
    }
}

fn serve_weighted(out: &std::path::Path, sha: &'static str) -> (SocketAddr, JoinHandle<Served>) {
    bridge_with(out.to_path_buf(), 1, short(), Weighted(sha))
}

/// A policy retrained under the same name does not add its trials to the old one's: each
/// trial records the weights' fingerprint, and the bridge refuses, before it listens, an
/// output directory holding trials of other weights under the pilot's name.
#[test]
fn trials_of_a_retrained_policy_are_not_mixed_with_the_old_ones() {
    let out = tmp("provenance");
    let lab = LabConfig::default();
    let (addr, h) = serve_weighted(&out, "aaaa");
    let t = run_trial(addr, &lab, 1).unwrap();
    h.join().unwrap().unwrap();
    let task = read_trial(std::path::Path::new(&t.file))
        .unwrap()
        .task
        .unwrap();
    assert_eq!(task.policy_sha256().as_deref(), Some("aaaa"));
    // The welcome named the same weights to the lab side.
    assert_eq!(t.policy_sha256.as_deref(), Some("aaaa"));
    // Other weights under the same name: refused, naming the directory and the trial.
    let (_, h) = serve_weighted(&out, "bbbb");
    let e = h.join().unwrap().expect_err("refused");
    let msg = e.to_string();
    assert!(
        matches!(e, fishprobe_live::LiveError::Mixed(_))
            && msg.contains("Zone__VirtualLab")
            && msg.contains("trial_000.hdf5")
            && msg.contains("aaaa")
            && msg.contains("another output directory"),
        "{msg}"
    );
    // The same weights go on numbering their trials.
    let (addr, h) = serve_weighted(&out, "aaaa");
    let t = run_trial(addr, &lab, 2).unwrap();
    h.join().unwrap().unwrap();
    assert!(t.file.ends_with("trial_001.hdf5"), "{}", t.file);
    // A file there that is no trial: which policy drove it cannot be told, so refused too.
    std::fs::write(out.join("Zone__VirtualLab/trial_009.hdf5"), b"garbage").unwrap();
    let (_, h) = serve_weighted(&out, "aaaa");
    let msg = h.join().unwrap().expect_err("refused").to_string();
    assert!(
        msg.contains("trial_009.hdf5 cannot be read") && msg.contains("cannot be told"),
        "{msg}"
    );
}
