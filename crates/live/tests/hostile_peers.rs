//! The bridge against peers that try to blind or block it, and against a disk that fails:
//! one test per way found to defeat it (all over loopback, bounded in time).

#![allow(clippy::unwrap_used)] // a failure is a test failure

use fishprobe_io::read_trial;
use fishprobe_live::host::TrialOutcome;
use fishprobe_live::protocol::{to_line, ClientMsg, FishPose, Pose};
use fishprobe_live::server::{serve, BridgeGuard, ServeOptions};
use fishprobe_live::session::LiveConfig;
use fishprobe_live::LiveError;
use fishprobe_sim::{ControlInput, Controller, SimRng, TaskParams};
use std::io::{BufRead, BufReader, Write};
use std::net::{SocketAddr, TcpListener, TcpStream};
use std::path::Path;
use std::sync::mpsc;
use std::thread::JoinHandle;
use std::time::{Duration, Instant};

/// A controller with a name and a fixed turn (NaN for a broken policy).
#[derive(Clone)]
struct Fixed(&'static str, f32);
impl Controller for Fixed {
    fn name(&self) -> String {
        self.0.into()
    }
    fn act(&mut self, _input: &ControlInput<'_>, _rng: &mut SimRng) -> f32 {
        self.1
    }
}

fn tmp(tag: &str) -> fishprobe_io::ScratchDir {
    fishprobe_io::ScratchDir::for_test(&format!("peers-{tag}"))
}

fn short() -> LiveConfig {
    LiveConfig {
        habituation_s: 2.0,
        release_s: 1.0,
        control_s: 20.0,
        ..LiveConfig::default()
    }
}

fn options(out: &Path, trials: usize) -> ServeOptions {
    ServeOptions {
        live: short(),
        task: TaskParams::default(),
        out: out.to_path_buf(),
        token: None,
        max_trials: Some(trials),
        fish_label: "live guppy".into(),
        guard: BridgeGuard::default(),
    }
}

type Bridge = JoinHandle<Result<Vec<TrialOutcome>, LiveError>>;

fn start(opts: ServeOptions, name: &'static str, turn: f32) -> (SocketAddr, Bridge) {
    let listener = TcpListener::bind("127.0.0.1:0").unwrap();
    let addr = listener.local_addr().unwrap();
    let h = std::thread::spawn(move || {
        serve(
            &listener,
            &opts,
            &mut || Ok(Box::new(Fixed(name, turn)) as Box<dyn Controller>),
            |_| {},
        )
    });
    (addr, h)
}

fn hello(source: &str, sync: bool, token: Option<&str>) -> String {
    to_line(&ClientMsg::Hello {
        protocol: 1,
        world_size_cm: [100.0, 100.0],
        tracking_hz: 25.0,
        source: source.into(),
        token: token.map(Into::into),
        sync,
    })
}

fn frame(t: f64) -> String {
    let pose = |x: f32| Pose {
        x,
        y: 0.0,
        heading: 0.0,
    };
    to_line(&ClientMsg::Frame {
        t,
        robot: Some(pose(0.0)),
        fish: vec![FishPose {
            id: "f".into(),
            pose: Some(pose(10.0)),
        }],
    })
}

/// A lab client: the connection and the lines it receives, with their arrival times.
struct Client {
    s: TcpStream,
    rx: mpsc::Receiver<(Instant, String)>,
}

impl Client {
    fn connect(addr: SocketAddr) -> Self {
        let s = TcpStream::connect(addr).unwrap();
        let r = BufReader::new(s.try_clone().unwrap());
        let (tx, rx) = mpsc::channel();
        std::thread::spawn(move || {
            for l in r.lines() {
                let Ok(l) = l else { break };
                if tx.send((Instant::now(), l)).is_err() {
                    break;
                }
            }
        });
        Self { s, rx }
    }

    fn send(&mut self, text: &str) {
        self.s.write_all(text.as_bytes()).unwrap();
    }

    /// The next line within `limit`.
    fn line(&self, limit: Duration) -> Option<String> {
        self.rx.recv_timeout(limit).ok().map(|(_, l)| l)
    }

    /// Lines until one contains `needle`, within `limit`; the time it arrived.
    fn until(&self, needle: &str, limit: Duration) -> (Instant, String) {
        let end = Instant::now() + limit;
        loop {
            let left = end.saturating_duration_since(Instant::now());
            match self.rx.recv_timeout(left) {
                Ok((at, l)) if l.contains(needle) => return (at, l),
                Ok(_) => {}
                Err(_) => panic!("no line with `{needle}` within {limit:?}"),
            }
        }
    }

    fn welcomed(addr: SocketAddr) -> Self {
        let mut c = Self::connect(addr);
        c.send(&hello("lab", false, None));
        c.until("welcome", Duration::from_secs(3));
        c
    }
}

#[test]
fn blank_lines_and_partial_lines_do_not_defeat_the_silence_stop() {
    for keepalive in ["\n", "   \n", "x"] {
        let out = tmp("silence");
        let (addr, h) = start(options(&out, 1), "Seeker", 0.1);
        let mut c = Client::welcomed(addr);
        for k in 0..10 {
            c.send(&frame(f64::from(k) * 0.04));
        }
        // Then only keep-alive noise, every 0.1 s for 2 s: the stop must come as for silence
        // (stale_s = 0.5 s after the last frame), not never.
        let last_frame = Instant::now();
        for _ in 0..20 {
            std::thread::sleep(Duration::from_millis(100));
            c.send(keepalive);
        }
        let (at, line) = c.until("no tracking frame", Duration::from_secs(1));
        let after = at.duration_since(last_frame).as_secs_f64();
        assert!(line.contains("\"stop\":true"), "{line}");
        assert!(
            (0.45..1.0).contains(&after),
            "{keepalive:?}: stop {after:.2} s after the last frame"
        );
        c.send("\n");
        c.send(&to_line(&ClientMsg::End));
        h.join().unwrap().unwrap();
    }
}

#[test]
fn an_overlong_or_binary_line_mid_trial_stops_the_robot_and_the_trial_goes_on() {
    let out = tmp("overlong");
    let (addr, h) = start(options(&out, 1), "Seeker", 0.1);
    let mut c = Client::welcomed(addr);
    for k in 0..5 {
        c.send(&frame(f64::from(k) * 0.04));
    }
    // A line past the limit (65,536 bytes by default): dropped, named, the robot stopped.
    let limit = LiveConfig::default().max_message_bytes;
    c.send(&format!("{}\n", "x".repeat(limit + 10)));
    let (_, line) = c.until("malformed input", Duration::from_secs(3));
    assert!(
        line.contains(&format!(
            "message of more than {limit} bytes ({} read) dropped",
            limit + 10
        )) && line.contains("\"stop\":true"),
        "{line}"
    );
    // A good frame lifts the stop; then bytes that are not UTF-8: stopped again.
    c.send(&frame(0.2));
    c.s.write_all(b"\xff\xfe\n").unwrap();
    let (_, line) = c.until("not UTF-8", Duration::from_secs(3));
    assert!(line.contains("\"stop\":true"), "{line}");
    // The next good frame is taken and the trial ends as usual, keeping its frames.
    c.send(&frame(0.24));
    c.send(&to_line(&ClientMsg::End));
    let outcomes = h.join().unwrap().unwrap();
    assert_eq!(outcomes.len(), 1);
    assert_eq!(outcomes[0].frames, 7, "{:?}", outcomes[0]);
}

#[test]
fn lockstep_is_refused_for_a_live_lab() {
    let (addr, _h) = start(options(&tmp("sync"), 1), "Seeker", 0.1);
    let mut c = Client::connect(addr);
    c.send(&hello("lab", true, None));
    let l = c.line(Duration::from_secs(3)).unwrap();
    assert!(l.contains("error") && l.contains("virtual lab only"), "{l}");
}

#[test]
fn idle_and_trickling_peers_cannot_hold_the_bridge_and_a_busy_bridge_says_so() {
    let out = tmp("block");
    let (addr, h) = start(options(&out, 1), "Seeker", 0.1);
    // 130 connections that never say anything, and one that trickles a byte every 0.1 s.
    let idle: Vec<TcpStream> = (0..130)
        .map(|_| TcpStream::connect(addr).unwrap())
        .collect();
    let mut trickler = TcpStream::connect(addr).unwrap();
    let stop = std::sync::Arc::new(std::sync::atomic::AtomicBool::new(false));
    let stop2 = stop.clone();
    let trickle = std::thread::spawn(move || {
        while !stop2.load(std::sync::atomic::Ordering::SeqCst) {
            if trickler.write_all(b"{").is_err() {
                break;
            }
            std::thread::sleep(Duration::from_millis(100));
        }
    });
    std::thread::sleep(Duration::from_millis(300));
    // A real lab client is welcomed at once.
    let start = Instant::now();
    let mut lab = Client::welcomed(addr);
    assert!(
        start.elapsed() < Duration::from_secs(2),
        "welcome took {:?}",
        start.elapsed()
    );
    // While its trial runs, a second client is refused at once with "busy".
    let start = Instant::now();
    let mut second = Client::connect(addr);
    second.send(&hello("lab", false, None));
    let l = second.line(Duration::from_secs(2)).unwrap();
    assert!(l.contains("busy"), "{l}");
    assert!(start.elapsed() < Duration::from_secs(1));
    for k in 0..50 {
        lab.send(&frame(f64::from(k) * 0.04));
    }
    lab.send(&to_line(&ClientMsg::End));
    let outcomes = h.join().unwrap().unwrap();
    assert_eq!(outcomes.len(), 1);
    assert_eq!(outcomes[0].frames, 50);
    stop.store(true, std::sync::atomic::Ordering::SeqCst);
    trickle.join().unwrap();
    drop(idle);
}

#[test]
fn empty_tokens_are_refused() {
    let out = tmp("token");
    let mut opts = options(&out, 1);
    opts.token = Some(String::new());
    let (_, h) = start(opts, "Seeker", 0.1);
    let e = h.join().unwrap().unwrap_err().to_string();
    assert!(e.contains("token"), "{e}");
    // A bridge with a token refuses an empty one in the hello.
    let mut opts = options(&out, 1);
    opts.token = Some("s3cret".into());
    let (addr, _h) = start(opts, "Seeker", 0.1);
    let mut c = Client::connect(addr);
    c.send(&hello("lab", false, Some("")));
    let l = c.line(Duration::from_secs(3)).unwrap();
    assert!(l.contains("wrong token"), "{l}");
    let mut c = Client::connect(addr);
    c.send(&hello("lab", false, Some("s3cret")));
    assert!(c.line(Duration::from_secs(3)).unwrap().contains("welcome"));
}

#[test]
fn a_policy_name_cannot_put_a_trial_outside_out() {
    let base = tmp("traversal");
    let out = base.join("out");
    for name in ["../../escape", "/tmp/fishprobe-abs-escape"] {
        let (addr, h) = start(options(&out, 1), name, 0.1);
        let mut c = Client::welcomed(addr);
        c.send(&frame(0.0));
        c.send(&to_line(&ClientMsg::End));
        let o = h.join().unwrap().unwrap();
        let file = o[0].file.clone().unwrap();
        assert!(file.starts_with(&out), "{}", file.display());
        assert_eq!(file.parent().unwrap().parent().unwrap(), out);
    }
    assert!(!base.join("escape__Real").exists());
    assert!(!Path::new("/tmp/fishprobe-abs-escape__Real").exists());
}

#[test]
fn a_burst_of_frames_then_a_reset_loses_no_frame() {
    let out = tmp("reset");
    let trials = 20;
    let (addr, h) = start(options(&out, trials), "Seeker", 0.1);
    for _ in 0..trials {
        // The bridge may still be reading the last burst: a client retries on "busy".
        let start = Instant::now();
        let (mut s, r) = loop {
            let mut s = TcpStream::connect(addr).unwrap();
            s.write_all(hello("lab", false, None).as_bytes()).unwrap();
            let mut r = BufReader::new(s.try_clone().unwrap());
            let mut welcome = String::new();
            r.read_line(&mut welcome).unwrap();
            if welcome.contains("welcome") {
                break (s, r);
            }
            assert!(welcome.contains("busy"), "{welcome}");
            assert!(start.elapsed() < Duration::from_secs(5), "busy for 5 s");
            std::thread::sleep(Duration::from_millis(20));
        };
        let burst: String = (0..250).map(|k| frame(f64::from(k) * 0.04)).collect();
        s.write_all(burst.as_bytes()).unwrap();
        // Commands pile up unread; closing with unread data sends a TCP reset.
        std::thread::sleep(Duration::from_millis(30));
        drop(r);
        drop(s);
    }
    let outcomes = h.join().unwrap().unwrap();
    for o in &outcomes {
        let f = read_trial(o.file.as_ref().unwrap()).unwrap();
        let stored = f.fish().next().unwrap().positions.len();
        assert_eq!(stored, 250, "{}", o.file.as_ref().unwrap().display());
    }
}

#[test]
fn a_policy_that_outputs_nan_never_drives_the_robot() {
    let out = tmp("nan");
    let (addr, h) = start(options(&out, 1), "Broken", f32::NAN);
    let mut c = Client::welcomed(addr);
    // Habituation (2 s) and 3 s of control at 25 Hz.
    for k in 0..125 {
        c.send(&frame(f64::from(k) * 0.04));
    }
    c.send(&to_line(&ClientMsg::End));
    let o = h.join().unwrap().unwrap();
    let mut control = 0;
    while let Some(l) = c.line(Duration::from_millis(500)) {
        if l.contains("\"phase\":\"control\"") {
            control += 1;
            assert!(
                l.contains("\"stop\":true") && l.contains("\"turn\":0.0"),
                "{l}"
            );
        }
    }
    assert!(control >= 3, "{control} control commands");
    let f = read_trial(o[0].file.as_ref().unwrap()).unwrap();
    let cfg = &f.task.unwrap().config_json;
    assert!(cfg.contains("non-finite turn"), "{cfg}");
}

#[test]
fn a_write_failure_keeps_the_bridge_alive_and_the_trial() {
    let base = tmp("fulldisk");
    let out = base.join("out");
    std::fs::create_dir_all(&out).unwrap();
    // The trial directory cannot be made (a file stands in its place), as on a full disk.
    std::fs::write(out.join("Seeker__Real"), b"in the way").unwrap();
    let fallback = base.join("fallback");
    let mut opts = options(&out, 3);
    opts.guard.fallback_dir = Some(fallback.clone());
    let (addr, h) = start(opts, "Seeker", 0.1);
    let run = |expect: &str| {
        let mut c = Client::welcomed(addr);
        for k in 0..10 {
            c.send(&frame(f64::from(k) * 0.04));
        }
        c.send(&to_line(&ClientMsg::End));
        let (_, warning) = c.until(expect, Duration::from_secs(5));
        let (_, done) = c.until("done", Duration::from_secs(5));
        (warning, done)
    };
    // 1: written to the fallback, and the client is told where.
    let (w, done) = run("instead");
    assert!(
        w.contains("cannot write") && w.contains(&fallback.display().to_string()),
        "{w}"
    );
    assert!(done.contains(&fallback.display().to_string()), "{done}");
    // 2: the fallback fails too: kept in memory, and the client is told.
    std::fs::remove_dir_all(&fallback).unwrap();
    std::fs::write(&fallback, b"in the way too").unwrap();
    let (w, _) = run("kept in the bridge's memory");
    assert!(w.contains("fallback"), "{w}");
    // 3: the disk is back; the next trial's end writes both.
    std::fs::remove_file(out.join("Seeker__Real")).unwrap();
    let mut c = Client::welcomed(addr);
    c.send(&frame(0.0));
    c.send(&to_line(&ClientMsg::End));
    c.until("done", Duration::from_secs(5));
    let outcomes = h.join().unwrap().unwrap();
    assert_eq!(outcomes.len(), 3);
    assert!(outcomes[1].file.is_none() && outcomes[1].warning.is_some());
    let written = fishprobe_io::trial_files(&out.join("Seeker__Real"));
    assert_eq!(written.len(), 2, "{written:?}");
    for f in written {
        read_trial(&f).unwrap();
    }
}

/// A group bridge (3 fish) fed frames whose fish lists disagree with it and with each other:
/// more fish than it tracks, fewer, none, and one id given to every fish. Documented
/// behaviour (docs/live-protocol.md, "How fish are matched"): fish are matched by id, a missing
/// entry is that fish untracked, a fish too many is ignored, an id given twice counts once.
/// Every frame is stored (3 fish each), the robot stops when no fish is tracked for
/// `stale_s`, nothing panics and the trial file is written with what was matched how.
#[test]
fn a_group_bridge_takes_inconsistent_fish_lists_as_documented() {
    let out = tmp("group");
    let mut opts = options(&out, 1);
    opts.live.fish_count = 3;
    let (addr, h) = start(opts, "Seeker", 0.1);
    let mut c = Client::welcomed(addr);
    let fish = |ids: &[&str], x: f32| -> Vec<FishPose> {
        ids.iter()
            .enumerate()
            .map(|(k, id)| FishPose {
                id: (*id).into(),
                pose: Some(Pose {
                    x: x + 3.0 * k as f32,
                    y: 5.0,
                    heading: 0.0,
                }),
            })
            .collect()
    };
    let lists: [&[&str]; 5] = [
        &["a", "b", "c"],
        &["a"],
        &["a", "b", "c", "d", "e"],
        &["same", "same", "same"],
        &[],
    ];
    let frames = 250;
    let mut text = String::new();
    for k in 0..frames {
        // Each list in turn for 10 frames; the last stretch (frames 200-249) has no fish at
        // all, so the robot must stop there.
        let ids = if k >= 200 {
            lists[4]
        } else {
            lists[(k / 10) % 4]
        };
        text.push_str(&to_line(&ClientMsg::Frame {
            t: f64::from(k as u32) * 0.04,
            robot: Some(Pose {
                x: 0.0,
                y: 0.0,
                heading: 0.0,
            }),
            fish: fish(ids, 10.0),
        }));
    }
    c.send(&text);
    // No fish from 8.0 s on; with stale_s = 0.5 the robot stops by 8.5 s (tracking time).
    let (_, stop) = c.until("fish not tracked", Duration::from_secs(10));
    assert!(stop.contains("\"stop\":true"), "{stop}");
    c.send(&to_line(&ClientMsg::End));
    let outcomes = h.join().unwrap().unwrap();
    let o = &outcomes[0];
    assert_eq!(o.frames, frames);
    let f = read_trial(o.file.as_ref().unwrap()).unwrap();
    let stored: Vec<_> = f.fish().collect();
    assert_eq!(
        stored.len(),
        3,
        "the bridge's fish count, whatever the lists held"
    );
    for e in &stored {
        assert_eq!(e.positions.len(), frames);
    }
    // Frame 10 held only "a": fish 2 and 3 untracked there (NaN), fish 1 tracked.
    assert!(stored[0].positions[10][0].is_finite());
    assert!(stored[1].positions[10][0].is_nan() && stored[2].positions[10][0].is_nan());
    // Frame 20 held five: the three known ids were taken, "d" and "e" are fish too many.
    assert!((stored[2].positions[20][0] - 16.0).abs() < 1e-4);
    // Frame 30 gave every fish the same new id: a fish found again under a new id, once; the
    // two repeats are ignored.
    assert!((stored[0].positions[30][0] - 10.0).abs() < 1e-4);
    assert!(stored[1].positions[30][0].is_nan() && stored[2].positions[30][0].is_nan());
    let record: serde_json::Value =
        serde_json::from_str(&f.task.as_ref().unwrap().config_json).unwrap();
    let m = &record["fish_matching"];
    assert_eq!(m["id_changes"][0]["new"], "same", "{m}");
    assert!(m["entries_ignored"].as_u64().unwrap() > 0, "{m}");
}

/// Two fish whose entries come as `[a, b]` in one frame and `[b, a]` in the next: each fish
/// is followed by its id, never swapped, and the ids are in the trial file.
#[test]
fn fish_that_change_places_in_the_frame_are_followed_by_id() {
    let dir = tmp("swap");
    let mut opts = options(&dir, 1);
    opts.live.fish_count = 2;
    opts.live.control_s = 2.0;
    let (addr, bridge) = start(opts, "Swap", 0.1);
    let mut c = Client::connect(addr);
    c.send(&hello("lab", false, None));
    c.until("welcome", Duration::from_secs(5));
    let pose = |x: f32| Pose {
        x,
        y: 0.0,
        heading: 0.0,
    };
    let fish = |id: &str, x: f32| FishPose {
        id: id.into(),
        pose: Some(pose(x)),
    };
    for k in 0..120u32 {
        let t = f64::from(k) / 25.0;
        let (a, b) = (fish("7", -20.0), fish("12", 30.0));
        let entries = if k % 2 == 0 { vec![a, b] } else { vec![b, a] };
        c.send(&to_line(&ClientMsg::Frame {
            t,
            robot: Some(pose(0.0)),
            fish: entries,
        }));
    }
    c.send(&to_line(&ClientMsg::End));
    let outcomes = bridge.join().unwrap().unwrap();
    let t = read_trial(outcomes[0].file.as_ref().unwrap()).unwrap();
    let fish: Vec<_> = t.fish().collect();
    assert_eq!(fish.len(), 2);
    assert!(fish[0].positions.iter().all(|p| p[0] == -20.0));
    assert!(fish[1].positions.iter().all(|p| p[0] == 30.0));
    let id = |e: &fishprobe_io::Entity| {
        e.attributes
            .get(fishprobe_io::TRACKER_ID_ATTRIBUTE)
            .cloned()
    };
    assert_eq!(id(fish[0]), Some(fishprobe_io::Attr::Text("7".into())));
    assert_eq!(id(fish[1]), Some(fishprobe_io::Attr::Text("12".into())));
}
