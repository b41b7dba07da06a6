//! `fishprobe bench observer`: the BioTracker observer component as the core sees it. The
//! component runs as its own process (`fishprobe live biotracker`, with a stand-in core's
//! heartbeat in this process); a client plays the core: `update` calls of a trial in
//! recording, at the tracker's rate and then as fast as they are answered. Reported: each
//! call's round trip (p50, p99, worst) and the component's CPU time as a share of one core.

use super::{emit, machine};
use anyhow::{bail, Context, Result};
use fishprobe_live::biotracker::grpc::{self, Client};
use fishprobe_live::biotracker::schema::{
    ComponentConfig, Empty, Experiment, Feature, RecordingState, SkeletonDescriptor, SkeletonNode,
};
use fishprobe_sim::params::check::shown;
use serde::Serialize;
use std::fmt::Write;
use std::net::{SocketAddr, TcpListener};
use std::process::{Command, Stdio};
use std::time::{Duration, Instant};

/// One row of `bench observer`.
#[derive(Debug, Serialize)]
struct ObserverBench {
    load: String,
    updates: usize,
    updates_per_s: f64,
    p50_us: f64,
    p99_us: f64,
    max_us: f64,
    cpu_share_of_one_core: f64,
}

/// The process's CPU time (user + system, s) from `/proc/PID/stat`.
fn cpu_seconds(pid: u32) -> Option<f64> {
    let stat = std::fs::read_to_string(format!("/proc/{pid}/stat")).ok()?;
    // Fields after the command name (which may hold spaces) start after the last ')'.
    let rest = &stat[stat.rfind(')')? + 2..];
    let f: Vec<&str> = rest.split_whitespace().collect();
    let ticks: f64 = f.get(11)?.parse::<f64>().ok()? + f.get(12)?.parse::<f64>().ok()?;
    // The kernel's clock ticks per second: 100 on every Linux fishprobe runs on.
    Some(ticks / 100.0)
}

fn free_addr() -> Result<SocketAddr> {
    Ok(TcpListener::bind("127.0.0.1:0")?.local_addr()?)
}

/// Frame `k` of a robot circling the tank and a fish trailing it.
fn update(k: u32, fps: f32) -> Experiment {
    let a = k as f32 * 0.01;
    let node = |x: f32, y: f32| SkeletonNode { x, y, score: 1.0 };
    let feature = |id: u32, r: f32, phase: f32| {
        let (x, y) = (r * (a - phase).cos(), r * (a - phase).sin());
        Feature {
            score: 1.0,
            out_of_bounds: None,
            id: Some(id),
            world_nodes: vec![node(x - y * 0.05, y + x * 0.05), node(x, y)],
        }
    };
    let skeleton = SkeletonDescriptor {
        front_index: 0,
        center_index: 1,
    };
    let features = vec![feature(1, 20.0, 0.0), feature(2, 25.0, 0.3)];
    let state = RecordingState::Recording;
    Experiment::update(
        fps,
        "bench/observer",
        state,
        k,
        features,
        vec![1, 2],
        skeleton,
    )
}

pub(super) fn bench_observer(json: bool, seconds: f64, policy: &str) -> Result<()> {
    if !(seconds.is_finite() && (1.0..=600.0).contains(&seconds)) {
        bail!("--seconds must lie in [1, 600], got {}", shown(seconds));
    }
    let dir = fishprobe_io::ScratchDir::remove_on_drop(
        std::env::temp_dir().join(format!("fishprobe-bench-observer-{}", std::process::id())),
    );
    std::fs::create_dir_all(&*dir).with_context(|| format!("creating {}", dir.display()))?;
    // A protocol that reaches the policy's control at once and lasts longer than the bench.
    let protocol = dir.join("protocol.toml");
    std::fs::write(
        &protocol,
        "habituation_s = 1.0\nrelease_s = 0.5\ncontrol_s = 3600.0\n",
    )?;
    let rt = tokio::runtime::Builder::new_current_thread()
        .enable_all()
        .build()?;
    let core_listener = TcpListener::bind("127.0.0.1:0")?;
    let core = core_listener.local_addr()?;
    rt.spawn(grpc::serve(
        core_listener,
        grpc::heartbeat_service(),
        std::future::pending(),
    ));
    let (address, sink) = (free_addr()?, free_addr()?);
    let mut child = Command::new(std::env::current_exe()?)
        .args(["live", "biotracker", "--address", &address.to_string()])
        .args(["--core", &core.to_string(), "--log"])
        .arg(dir.join("observer.log"))
        .stdout(Stdio::null())
        .stderr(Stdio::null())
        .spawn()
        .context("starting the observer")?;
    let result = rt.block_on(async {
        let mut client = Client::lazy(address, Duration::from_secs(2))?;
        let start = Instant::now();
        while client
            .call::<Experiment, Empty>(grpc::UPDATE_PATH, Experiment::default())
            .await
            .is_err()
        {
            if start.elapsed() > Duration::from_secs(20) {
                bail!("the observer did not start within 20 s");
            }
            tokio::time::sleep(Duration::from_millis(50)).await;
        }
        let config = serde_json::json!({
            "policy": policy, "out": dir.join("trials"), "robot_id": 1, "fish_ids": [2],
            "robot_sink": sink.to_string(), "core": core.to_string(), "config": protocol,
        });
        client
            .call::<ComponentConfig, Empty>(
                grpc::SET_CONFIG_PATH,
                ComponentConfig {
                    config_json: config.to_string(),
                    id: "bench".into(),
                },
            )
            .await
            .map_err(|s| anyhow::anyhow!("set_config: {}", s.message()))?;
        let fps = 25.0f32;
        let mut frame = 0u32;
        let mut rows = Vec::new();
        for (load, period) in [
            (
                "25 Hz (the lab's tracking rate)",
                Some(1.0 / f64::from(fps)),
            ),
            ("as fast as answered", None),
        ] {
            let mut times = Vec::new();
            let cpu0 = cpu_seconds(child.id()).unwrap_or(f64::NAN);
            let t0 = Instant::now();
            while t0.elapsed().as_secs_f64() < seconds {
                if let Some(p) = period {
                    let due = t0 + Duration::from_secs_f64(times.len() as f64 * p);
                    tokio::time::sleep_until(due.into()).await;
                }
                let t = Instant::now();
                client
                    .call::<Experiment, Empty>(grpc::UPDATE_PATH, update(frame, fps))
                    .await
                    .map_err(|s| anyhow::anyhow!("update: {}", s.message()))?;
                times.push(t.elapsed().as_secs_f64() * 1e6);
                frame += 1;
            }
            let wall = t0.elapsed().as_secs_f64();
            let cpu = cpu_seconds(child.id()).unwrap_or(f64::NAN) - cpu0;
            times.sort_by(f64::total_cmp);
            let at = |q: f64| times[((times.len() - 1) as f64 * q).round() as usize];
            rows.push(ObserverBench {
                load: load.into(),
                updates: times.len(),
                updates_per_s: times.len() as f64 / wall,
                p50_us: at(0.5),
                p99_us: at(0.99),
                max_us: at(1.0),
                cpu_share_of_one_core: cpu / wall,
            });
        }
        Ok(rows)
    });
    let _ = child.kill();
    let _ = child.wait();
    let rows = result?;
    let m = machine();
    let command = format!(
        "fishprobe bench observer --seconds {} --policy {policy}",
        shown(seconds)
    );
    let text = if json {
        serde_json::to_string_pretty(&serde_json::json!({
            "bench": "observer", "machine": m, "policy": policy, "rows": rows,
            "command": command,
        }))? + "\n"
    } else {
        let mut t = format!(
            "fishprobe bench observer — {} cores ({}, {} {}); policy {policy}; `update` round trips on loopback, the component's CPU share of one core\n{:<34} {:>8} {:>10} {:>9} {:>9} {:>9} {:>6}\n",
            m.cores, m.cpu, m.os, m.arch, "load", "updates", "updates/s", "p50 µs", "p99 µs", "max µs", "CPU"
        );
        for r in &rows {
            writeln!(
                t,
                "{:<34} {:>8} {:>10.1} {:>9.0} {:>9.0} {:>9.0} {:>5.1}%",
                r.load,
                r.updates,
                r.updates_per_s,
                r.p50_us,
                r.p99_us,
                r.max_us,
                100.0 * r.cpu_share_of_one_core
            )?;
        }
        writeln!(t, "({command})")?;
        t
    };
    emit(&text)
}
