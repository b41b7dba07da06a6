//! `fishprobe live serve | replay` and `fishprobe lab`: live trials through the bridge, and the
//! virtual lab.

use anyhow::{bail, Context, Result};
use clap::{Args, Subcommand};
use fishprobe_live::host::TrialOutcome;
use fishprobe_live::lab::{run_trial, LabConfig};
use fishprobe_live::protocol::{to_line, ClientMsg, FishPose, Pose, PROTOCOL_VERSION};
use fishprobe_live::server::{is_loopback, serve, BridgeGuard, ServeOptions};
use fishprobe_live::session::LiveConfig;
use std::io::{BufReader, Write};
use std::net::{SocketAddr, TcpListener, TcpStream};
use std::path::PathBuf;
use std::time::{Duration, Instant};

use super::emit;

/// Most virtual trials one `lab` runs (each is a trial file of up to 24 hours).
const MAX_LAB_TRIALS: usize = 10_000;

#[derive(Debug, Args)]
pub struct LiveArgs {
    #[command(subcommand)]
    what: LiveWhat,
}

#[derive(Debug, Subcommand)]
enum LiveWhat {
    /// Run the bridge: a trained policy controls the robot from the lab's tracking frames
    /// (protocol: docs/live-protocol.md).
    Serve(ServeArgs),
    /// Play a recorded trial file as tracking input to a bridge (test and demo tool).
    Replay(ReplayArgs),
    /// Run as a BioTracker v4 observer component: BioTracker's core starts it through
    /// `lab/biotracker/fishprobe_biotracker.py` and sends it every tracked frame; the lab's
    /// robot program reads the robot sink (docs/guide/live-trials.md).
    Biotracker(super::observer::BiotrackerArgs),
}

#[derive(Debug, Args)]
struct ServeArgs {
    /// The policy: a directory from `fishprobe train`, `onnx:FILE` (docs/onnx-models.md) or
    /// `scripted:goal-seeker` / `scripted:fetch-and-lead`.
    #[arg(long)]
    policy: String,
    /// Address to listen on (loopback by default).
    #[arg(long, default_value = "127.0.0.1:4500")]
    listen: SocketAddr,
    /// Allow a non-loopback address (then --token is required).
    #[arg(long)]
    allow_remote: bool,
    /// Shared secret the lab must send in its hello.
    #[arg(long)]
    token: Option<String>,
    /// Where trial files go (`OUT/<Policy>__Real/` or `OUT/<Policy>__VirtualLab/`).
    #[arg(long, default_value = "live_trials")]
    out: PathBuf,
    /// Stop after this many trials (default: serve until interrupted).
    #[arg(long)]
    trials: Option<usize>,
    /// Trial protocol and safety settings (TOML: the fields of LiveConfig; `fish_count = 4`
    /// for a group).
    #[arg(long)]
    config: Option<PathBuf>,
    /// With a group: when it has reached a goal (`any` fish, its `centroid`, or a `fraction`
    /// of one half).
    #[arg(long, value_enum, default_value_t = GroupGoalArg::Any)]
    group_goal: GroupGoalArg,
}

/// `task.group_goal` on the command line.
#[derive(Debug, Clone, Copy, PartialEq, Eq, clap::ValueEnum)]
enum GroupGoalArg {
    Any,
    Centroid,
    Fraction,
}

/// The task with a group-goal rule.
fn task_with(g: GroupGoalArg) -> fishprobe_sim::TaskParams {
    fishprobe_sim::TaskParams {
        group_goal: match g {
            GroupGoalArg::Any => fishprobe_sim::GroupGoal::Any,
            GroupGoalArg::Centroid => fishprobe_sim::GroupGoal::Centroid,
            GroupGoalArg::Fraction => fishprobe_sim::GroupGoal::Fraction,
        },
        ..fishprobe_sim::TaskParams::default()
    }
}

#[derive(Debug, Args)]
struct ReplayArgs {
    /// The trial file to play.
    file: PathBuf,
    /// The bridge's address.
    #[arg(long, default_value = "127.0.0.1:4500")]
    connect: SocketAddr,
    /// Say `virtual_lab` instead of `lab` in the hello (the replayed fish is not live).
    #[arg(long)]
    as_virtual: bool,
}

#[derive(Debug, Args)]
pub struct LabArgs {
    /// The policy: a directory from `fishprobe train`, `onnx:FILE` (docs/onnx-models.md) or
    /// `scripted:goal-seeker` / `scripted:fetch-and-lead`.
    #[arg(long)]
    policy: String,
    /// Trials to run.
    #[arg(long, default_value_t = 1)]
    trials: usize,
    /// Output directory: trials land in `OUT/<Policy>__VirtualLab/`.
    #[arg(long)]
    out: PathBuf,
    /// Master seed (one virtual guppy per trial, drawn from the population).
    #[arg(long, default_value_t = 0)]
    seed: u64,
    /// Connect to a running bridge instead of starting one in-process.
    #[arg(long)]
    connect: Option<SocketAddr>,
    /// Minutes of control per trial (paper: 15).
    #[arg(long)]
    minutes: Option<f64>,
    /// Virtual guppies per trial, each its own individual (1 to 16; the in-process bridge
    /// tracks them all; with --connect the bridge's own `fish_count` decides).
    #[arg(long, default_value_t = 1)]
    fish: u32,
    /// The virtual fish's model: `GuppyPop` (the virtual guppy whose individuals' spread was
    /// fitted to the training recordings), `Guppy` (its hand-set traits only), or any model
    /// name or `population:FILE` (`fishprobe models`).
    #[arg(long, default_value = "GuppyPop")]
    fish_model: String,
    /// With a group: when it has reached a goal (in-process bridge only).
    #[arg(long, value_enum, default_value_t = GroupGoalArg::Any)]
    group_goal: GroupGoalArg,
    /// The policy was trained with `observation.centroid_bins` (216 values; in-process
    /// bridge only).
    #[arg(long)]
    centroid_bins: bool,
    /// The policy was trained with `observation.heading_bins`, the fish's headings (216
    /// values, 252 with the centroid; in-process bridge only).
    #[arg(long)]
    heading_bins: bool,
    /// Send frames at the tracker's pace (25 a second: a trial takes its real 17 minutes)
    /// rather than as fast as the bridge answers, to watch a virtual trial unfold. The trial
    /// is the same either way.
    #[arg(long)]
    real_time: bool,
}

fn report(o: &TrialOutcome) {
    if let Some(w) = &o.warning {
        say!("warning: {w}");
    }
    if let Some(f) = &o.file {
        say!(
            "trial {}: {} frames, {} goals{}",
            f.display(),
            o.frames,
            o.goals_reached,
            if o.complete {
                ""
            } else {
                " (the lab left early; the file holds what was recorded)"
            }
        );
    }
}

fn serve_cmd(a: ServeArgs) -> Result<()> {
    if a.token.as_deref().is_some_and(|t| t.trim().is_empty()) {
        bail!("--token is empty: a token must be a non-empty secret (or leave --token out on loopback)");
    }
    let remote_ok = a.allow_remote && a.token.is_some();
    if !(is_loopback(&a.listen) || remote_ok) {
        bail!(
            "listening on {} (not loopback) needs --allow-remote and a --token",
            a.listen
        );
    }
    let opts = ServeOptions {
        live: super::live_settings(a.config.as_deref())?,
        task: task_with(a.group_goal),
        out: a.out.clone(),
        token: a.token.clone(),
        max_trials: a.trials,
        fish_label: "live guppy".into(),
        guard: BridgeGuard::default(),
    };
    let mut make = super::pilot(&a.policy, &opts.live)?;
    // One bridge per output directory (taken once the inputs are known to be good).
    let _lock = super::lock_out(&a.out, "live serve")?;
    let listener =
        TcpListener::bind(a.listen).with_context(|| format!("listening on {}", a.listen))?;
    let weights = make()
        .ok()
        .and_then(|c| c.fingerprint())
        .map_or_else(String::new, |s| {
            format!(" (weights sha256 {}…)", fishprobe_io::short_sha(&s))
        });
    // The address actually bound: with port 0 the system chose one, and a client needs it.
    let bound = listener.local_addr().unwrap_or(a.listen);
    say!(
        "bridge for {}{weights} listening on {bound} (trials go to {})",
        a.policy,
        a.out.display()
    );
    fishprobe_live::shutdown::install()?;
    let done = serve(&listener, &opts, &mut make, report)?;
    emit(&format!("{} trials served\n", done.len()))?;
    exit_if_signalled()
}

/// After a stop that SIGTERM, SIGINT or SIGHUP asked for (the trial was ended and written):
/// says so and exits with 128 + the signal's number, the shell's convention.
fn exit_if_signalled() -> Result<()> {
    if let (Some(why), Some(code)) = (
        fishprobe_live::shutdown::requested(),
        fishprobe_live::shutdown::exit_status(),
    ) {
        say!("stopped: {why}; the running trial was ended and written");
        std::process::exit(code);
    }
    Ok(())
}

fn replay_cmd(a: ReplayArgs) -> Result<()> {
    let t = fishprobe_io::read_any_trial(&a.file)?;
    let robot = t.robot().context("the file has no robot")?;
    let fish = t.fish().next().context("the file has no fish")?;
    let rh = robot.headings_from_motion(0.1);
    let fh = fish.headings_checked(0.1, std::f32::consts::FRAC_PI_2).0;
    let mut s =
        TcpStream::connect(a.connect).with_context(|| format!("connecting to {}", a.connect))?;
    let hello = ClientMsg::Hello {
        protocol: PROTOCOL_VERSION,
        world_size_cm: t.world_size_cm,
        tracking_hz: t.frame_rate_hz,
        source: if a.as_virtual { "virtual_lab" } else { "lab" }.into(),
        token: None,
        sync: false,
    };
    s.write_all(to_line(&hello).as_bytes())?;
    let mut r = BufReader::new(s.try_clone()?);
    let line = fishprobe_live::read_line_at_most(&mut r, fishprobe_live::MAX_BRIDGE_LINE_BYTES)
        .with_context(|| format!("reading the bridge's answer from {}", a.connect))?
        .unwrap_or_default();
    if !line.contains("welcome") {
        bail!("the bridge refused: {}", line.trim());
    }
    let pose = |p: [f32; 2], h: f32| {
        (p[0].is_finite() && p[1].is_finite() && h.is_finite()).then_some(Pose {
            x: p[0],
            y: p[1],
            heading: h,
        })
    };
    let frames = robot.frames().min(fish.frames());
    for k in 0..frames {
        let m = ClientMsg::Frame {
            t: k as f64 / f64::from(t.frame_rate_hz),
            robot: pose(robot.positions[k], rh[k]),
            fish: vec![FishPose {
                id: fish.name.clone(),
                pose: pose(fish.positions[k], fh[k]),
            }],
        };
        if s.write_all(to_line(&m).as_bytes()).is_err() {
            break;
        }
    }
    let _ = s.write_all(to_line(&ClientMsg::End).as_bytes());
    let _ = s.shutdown(std::net::Shutdown::Write);
    let mut last = String::new();
    while let Ok(Some(l)) =
        fishprobe_live::read_line_at_most(&mut r, fishprobe_live::MAX_BRIDGE_LINE_BYTES)
    {
        if l.contains("\"done\"") {
            last = l;
        }
    }
    emit(&format!(
        "replayed {frames} frames of {}; bridge: {}\n",
        a.file.display(),
        if last.is_empty() {
            "closed".into()
        } else {
            last
        }
    ))
}

pub fn run_live(a: LiveArgs) -> Result<()> {
    match a.what {
        LiveWhat::Serve(s) => serve_cmd(s),
        LiveWhat::Replay(r) => replay_cmd(r),
        LiveWhat::Biotracker(b) => super::observer::run(b),
    }
}

pub fn run_lab(a: LabArgs) -> Result<()> {
    let lab = LabConfig {
        fish_model: a.fish_model.clone(),
        real_time: a.real_time,
        ..LabConfig::default()
    };
    let mut live = LiveConfig::default();
    if let Some(m) = a.minutes {
        super::check_minutes("--minutes", m)?;
        live.control_s = m * 60.0;
    }
    live.fish_count = a.fish;
    live.centroid_bins = a.centroid_bins;
    live.heading_bins = a.heading_bins;
    live.validate()?;
    if a.trials == 0 || a.trials > MAX_LAB_TRIALS {
        bail!(
            "--trials must lie in [1, {MAX_LAB_TRIALS}], got {}",
            a.trials
        );
    }
    // The in-process bridge writes --out; with --connect the remote bridge writes its own.
    let mut _lock = None;
    let (addr, bridge) = match a.connect {
        Some(addr) => (addr, None),
        None => {
            let listener = TcpListener::bind("127.0.0.1:0").context("binding a loopback port")?;
            let addr = listener.local_addr()?;
            let opts = ServeOptions {
                live,
                task: task_with(a.group_goal),
                out: a.out.clone(),
                token: None,
                max_trials: Some(a.trials),
                fish_label: "virtual guppy".into(),
                guard: BridgeGuard::default(),
            };
            let mut make = super::pilot(&a.policy, &opts.live)?;
            _lock = Some(super::lock_out(&a.out, "lab")?);
            let h = std::thread::spawn(move || serve(&listener, &opts, &mut make, |_| {}));
            (addr, Some(h))
        }
    };
    fishprobe_live::shutdown::install()?;
    let mut text = String::from("VIRTUAL LAB (virtual guppies, not live fish)\n");
    let mut bridge = bridge;
    for k in 0..a.trials {
        if fishprobe_live::shutdown::requested().is_some() {
            break;
        }
        let seed = fishprobe_sim::derive_seed(a.seed, "lab/trial", k as u64);
        let t = match run_trial(addr, &lab, seed) {
            Ok(t) => t,
            Err(e) => {
                // A bridge that stopped (refusing its --out, say) tells why; the client only
                // saw the connection end.
                if let Some(h) = bridge.take() {
                    let stopped = Instant::now();
                    while !h.is_finished() && stopped.elapsed() < Duration::from_secs(1) {
                        std::thread::sleep(Duration::from_millis(10));
                    }
                    if h.is_finished() {
                        if let Ok(Err(b)) = h.join() {
                            return Err(b).context("the in-process bridge");
                        }
                    }
                }
                return Err(e).with_context(|| format!("virtual trial {k}"));
            }
        };
        if k == 0 {
            if let Some(sha) = &t.policy_sha256 {
                say!(
                    "the bridge flew weights sha256 {}…\n",
                    fishprobe_io::short_sha(sha)
                );
            }
        }
        let lost = if a.fish > 1 {
            format!("{} fish-frames with a fish lost", t.frames_lost)
        } else {
            format!("{} with the fish lost", t.frames_lost)
        };
        let line = format!(
            "trial {k}: {} goals, {} frames ({lost}), {} stops -> {}\n",
            t.goals_reached, t.frames_sent, t.stops, t.file
        );
        say!("{line}");
        for w in &t.warnings {
            say!("warning: the bridge says: {w}");
        }
        text += &line;
    }
    if let Some(h) = bridge {
        h.join()
            .map_err(|_| anyhow::anyhow!("the bridge thread panicked"))?
            .context("the in-process bridge")?;
    }
    emit(&text)?;
    exit_if_signalled()
}
