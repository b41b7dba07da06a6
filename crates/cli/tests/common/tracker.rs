//! Helpers of the tests that put fishprobe beside a BioTracker v4 core (a fake one, or the
//! real one in the opt-in test): a recorded trial's poses, a robot program on the sink.

#![allow(clippy::unwrap_used)] // a failure is a test failure

use super::{fishprobe, stderr};
use fishprobe_live::biotracker::grpc::{self, Client};
use fishprobe_live::biotracker::schema::{
    Empty, Experiment, Feature, RecordingState, SkeletonDescriptor, SkeletonNode,
};
use std::io::{BufRead, BufReader, Write};
use std::net::{SocketAddr, TcpListener, TcpStream};
use std::path::{Path, PathBuf};
use std::process::{Child, Command, Stdio};
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
/// A robot program on the sink, as the protocol asks: it reads every line and acknowledges
/// each tick. Keeps each line.
pub fn robot_program(sink: SocketAddr) -> Arc<Mutex<Vec<String>>> {
    let lines = Arc::new(Mutex::new(Vec::new()));
    let keep = Arc::clone(&lines);
    acking_program(sink, move |l| keep.lock().unwrap().push(l));
    lines
}

/// Connects to the robot sink (retrying while it is not yet listening) and hands each line
/// to `keep`, acknowledging ticks.
fn acking_program(sink: SocketAddr, mut keep: impl FnMut(String) + Send + 'static) {
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
        let mut ack = s.try_clone().unwrap();
        for l in BufReader::new(s).lines() {
            let Ok(l) = l else { break };
            if let Some(t) = serde_json::from_str::<serde_json::Value>(&l)
                .ok()
                .filter(|v| v["type"] == "tick")
                .map(|v| v["t"].clone())
            {
                let line = serde_json::json!({"type": "ack", "t": t}).to_string() + "\n";
                if ack.write_all(line.as_bytes()).is_err() {
                    break;
                }
            }
            keep(l);
        }
    });
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

/// The core's heartbeat on a thread of its own; `kill` (or dropping the value) ends it as a
/// dying process would.
pub struct FakeCore {
    pub addr: SocketAddr,
    stop: Option<tokio::sync::oneshot::Sender<()>>,
    thread: Option<std::thread::JoinHandle<()>>,
}

impl FakeCore {
    pub fn start() -> Self {
        let listener = TcpListener::bind("127.0.0.1:0").unwrap();
        let addr = listener.local_addr().unwrap();
        let (tx, rx) = tokio::sync::oneshot::channel::<()>();
        let thread = std::thread::spawn(move || {
            // Serving on the runtime until told to die; dropping the runtime then drops every
            // connection, as a core that exits does (a graceful shutdown would keep them).
            let rt = runtime();
            rt.spawn(grpc::serve(
                listener,
                grpc::heartbeat_service(),
                std::future::pending(),
            ));
            let _ = rt.block_on(rx);
        });
        Self {
            addr,
            stop: Some(tx),
            thread: Some(thread),
        }
    }

    pub fn kill(&mut self) {
        if let Some(tx) = self.stop.take() {
            let _ = tx.send(());
        }
        if let Some(t) = self.thread.take() {
            let _ = t.join();
        }
    }
}

impl Drop for FakeCore {
    fn drop(&mut self) {
        self.kill();
    }
}

/// The observer as BioTracker starts it: the address in the environment, and (with
/// `launcher`) through the Python launcher the core's config names, which must `exec`
/// fishprobe (the process keeps its id).
pub fn observer(address: SocketAddr, core: SocketAddr, log: &Path, launcher: bool) -> Child {
    observer_with(address, core, log, launcher, None)
}

/// [`observer`], optionally with the process's descriptor limit lowered to `nofile`.
pub fn observer_with(
    address: SocketAddr,
    core: SocketAddr,
    log: &Path,
    launcher: bool,
    nofile: Option<u32>,
) -> Child {
    let exe = env!("CARGO_BIN_EXE_fishprobe");
    let args = [
        "--core".to_string(),
        core.to_string(),
        "--log".into(),
        log.to_str().unwrap().into(),
    ];
    let mut cmd = if launcher {
        let script = Path::new(env!("CARGO_MANIFEST_DIR"))
            .join("../../lab/biotracker/fishprobe_biotracker.py");
        let mut c = Command::new("python3");
        c.arg(script).env("FISHPROBE_BIN", exe);
        c
    } else if let Some(n) = nofile {
        let mut c = Command::new("sh");
        c.args(["-c", &format!("ulimit -n {n} && exec \"$0\" \"$@\"")])
            .args([exe, "live", "biotracker"]);
        c
    } else {
        let mut c = Command::new(exe);
        c.args(["live", "biotracker"]);
        c
    };
    cmd.args(args)
        .env("BIOTRACKER_COMPONENT_ADDRESS", address.to_string())
        .stdout(Stdio::null())
        .stderr(Stdio::piped())
        .spawn()
        .unwrap()
}

/// A connected client, retried until the observer serves (it starts in well under 20 s).
pub async fn connect(addr: SocketAddr) -> Client {
    let start = Instant::now();
    loop {
        let mut c = Client::lazy(addr, Duration::from_secs(2)).unwrap();
        // An empty update is a call like any other; before set_config it is dropped.
        if c.call::<Experiment, Empty>(grpc::UPDATE_PATH, Experiment::default())
            .await
            .is_ok()
        {
            return c;
        }
        assert!(
            start.elapsed() < Duration::from_secs(20),
            "the observer did not start"
        );
        tokio::time::sleep(Duration::from_millis(50)).await;
    }
}

pub fn feature(id: u32, p: [f32; 3]) -> Feature {
    let node = |x: f32, y: f32| SkeletonNode { x, y, score: 1.0 };
    Feature {
        score: 1.0,
        out_of_bounds: None,
        id: Some(id),
        // Front node 1 cm ahead of the centre, the heading's direction.
        world_nodes: vec![node(p[0] + p[2].cos(), p[1] + p[2].sin()), node(p[0], p[1])],
    }
}

pub fn experiment(
    state: RecordingState,
    frame: u32,
    robot: [f32; 3],
    fish: [f32; 3],
) -> Experiment {
    let tracked = |p: [f32; 3]| p.iter().all(|v| v.is_finite());
    let mut features = Vec::new();
    if tracked(robot) {
        features.push(feature(1, robot));
    }
    if tracked(fish) {
        features.push(feature(2, fish));
    }
    let skeleton = SkeletonDescriptor {
        front_index: 0,
        center_index: 1,
    };
    let base = "/recordings/2026-12-07_fake";
    Experiment::update(FPS, base, state, frame, features, vec![1, 2], skeleton)
}

/// Lines the robot program read from the sink, each with when it arrived, collected on a
/// thread.
pub fn timed_robot_program(sink: SocketAddr) -> Arc<Mutex<Vec<(Instant, String)>>> {
    let lines = Arc::new(Mutex::new(Vec::new()));
    let keep = Arc::clone(&lines);
    acking_program(sink, move |l| {
        keep.lock().unwrap().push((Instant::now(), l))
    });
    lines
}

/// The trial at `file` once its end has written it (not a checkpoint of the running trial),
/// within `within`; the observer's `log` in the failure message.
pub fn final_trial(file: &Path, log: &Path, within: Duration) -> fishprobe_io::TrialFile {
    let start = Instant::now();
    loop {
        if let Ok(t) = fishprobe_io::read_trial(file) {
            let checkpoint = t.task.as_ref().is_some_and(|k| {
                k.config_json
                    .contains(fishprobe_live::keep::CHECKPOINT_NOTE)
            });
            if !checkpoint {
                return t;
            }
        }
        assert!(
            start.elapsed() < within,
            "no finished trial at {}; log:\n{}",
            file.display(),
            std::fs::read_to_string(log).unwrap_or_default()
        );
        std::thread::sleep(Duration::from_millis(20));
    }
}

/// An observer configured for a trial of [`PROTOCOL`] against a fake core, as most tests begin.
pub struct Configured {
    /// The test's directory.
    pub d: super::Scratch,
    /// The protocol file.
    pub protocol: PathBuf,
    /// The fake core.
    pub core: FakeCore,
    /// The observer's gRPC address.
    pub address: SocketAddr,
    /// The robot sink's address.
    pub sink: SocketAddr,
    /// The observer's log.
    pub log: PathBuf,
    /// The observer process.
    pub child: Child,
    /// Where trials are written.
    pub out: PathBuf,
    /// The test's runtime.
    pub rt: tokio::runtime::Runtime,
    /// A client, its configuration taken.
    pub client: Client,
}

/// Starts an observer beside a fake core and configures it (trials into `trials/`).
pub fn configured(tag: &str) -> Configured {
    let d = super::fresh_dir(tag);
    let protocol = d.join("protocol.toml");
    std::fs::write(&protocol, PROTOCOL).unwrap();
    let core = FakeCore::start();
    let (address, sink) = (free_addr(), free_addr());
    let log = d.join("observer.log");
    let child = observer(address, core.addr, &log, false);
    let out = d.join("trials");
    let rt = runtime();
    let mut client = rt.block_on(connect(address));
    rt.block_on(
        client.call::<fishprobe_live::biotracker::schema::ComponentConfig, Empty>(
            grpc::SET_CONFIG_PATH,
            fishprobe_live::biotracker::schema::ComponentConfig {
                config_json: config_json(&out, &protocol, sink, core.addr),
                id: "fishprobe".into(),
            },
        ),
    )
    .unwrap();
    Configured {
        d,
        protocol,
        core,
        address,
        sink,
        log,
        child,
        out,
        rt,
        client,
    }
}
