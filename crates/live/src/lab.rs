//! The virtual lab (SPEC §9): tank, tracker, robot and a virtual guppy played over the live
//! protocol, so that the bridge runs exactly as with the real lab, faster than real time.
//!
//! Each frame (25 Hz) the lab moves the robot by its low-level controller under the last
//! command (holding still while stopped), moves the fish (kept in its container in a corner
//! until the release), adds tracking noise and occasional dropouts, and sends the frame. When a
//! frame it waits for the bridge's answer (lockstep, `sync` in the hello), so the run is
//! deterministic for a seed and as fast as the bridge answers.

use crate::error::LiveError;
use crate::protocol::{to_line, ClientMsg, ServerMsg, PROTOCOL_VERSION};
use crate::track::{Command, FishPose, Pose};
use fishprobe_models::ModelSpec;
use fishprobe_sim::params::{check, ConfigError};
use fishprobe_sim::{
    step_fish, stream, wrap_angle, AgentState, FishMind, FishModel, FishView, Robot, RobotParams,
    SimRng, Tank, TankParams,
};
use rand::RngExt;
use rand_distr::{Distribution, StandardNormal};
use std::io::{BufReader, Write};
use std::net::{SocketAddr, TcpStream};
use std::sync::mpsc;
use std::time::Duration;

fishprobe_sim::documented_params! {
    /// The virtual lab's tracker and set-up (choices).
    pub struct LabConfig {
        /// Tracking rate (the real set-up: 25 Hz).
        pub tracking_hz: f32 = 25.0; "Hz",
        /// Tracking noise on positions (s.d.).
        pub position_noise_cm: f32 = 0.1; "cm",
        /// Tracking noise on headings (s.d.).
        pub heading_noise_rad: f32 = 0.05; "rad",
        /// Fish dropouts start at this rate.
        pub dropouts_per_min: f32 = 2.0; "1/min",
        /// A dropout lasts uniformly between this and `dropout_max_s`.
        pub dropout_min_s: f32 = 0.1; "s",
        /// See `dropout_min_s`.
        pub dropout_max_s: f32 = 1.2; "s",
        /// Where the fish waits in its container until the release (a corner).
        pub container: [f32; 2] = [-40.0, -40.0]; "cm",
        /// Seconds to wait for a due command before giving up (the bridge is gone).
        pub command_timeout_s: f32 = 10.0; "s",
        /// The virtual fish (a model name, `population:FILE`, ...). Choice: `GuppyPop`, the
        /// virtual guppy as a population whose individuals' spread was fitted to the training
        /// recordings (`fishprobe fit-population --model Guppy`); `Guppy` is the virtual guppy
        /// with its hand-set individual traits only.
        pub fish_model: String = "GuppyPop".into(); "-",
        /// Send the frames at the tracker's own pace (`tracking_hz` frames a second, a trial
        /// taking its real 17 minutes) instead of as fast as the bridge answers, so a person
        /// can watch a virtual trial as a live one unfolds (demonstrations, training an
        /// operator). The trial is the same either way: it is a function of its seed. Choice:
        /// off.
        pub real_time: bool = false; "-",
    }
}

impl LabConfig {
    /// Checks the ranges.
    pub fn validate(&self) -> Result<(), ConfigError> {
        check::positive("lab", "tracking_hz", self.tracking_hz)?;
        check::within(
            "lab",
            "position_noise_cm",
            self.position_noise_cm,
            0.0,
            check::MAX_LENGTH_CM,
        )?;
        check::non_negative("lab", "heading_noise_rad", self.heading_noise_rad)?;
        check::non_negative("lab", "dropouts_per_min", self.dropouts_per_min)?;
        check::non_negative("lab", "dropout_min_s", self.dropout_min_s)?;
        check::positive("lab", "command_timeout_s", self.command_timeout_s)?;
        if self.dropout_max_s < self.dropout_min_s {
            return Err(ConfigError::new(
                "lab",
                "dropout_max_s",
                self.dropout_max_s,
                "must be at least dropout_min_s",
            ));
        }
        Ok(())
    }
}

/// What one virtual trial did.
#[derive(Debug, Clone, PartialEq)]
pub struct LabTrial {
    /// The trial file the bridge wrote.
    pub file: String,
    /// Goals reached (the bridge's count).
    pub goals_reached: u32,
    /// Frames sent.
    pub frames_sent: u64,
    /// Frames in which a fish was reported lost (summed over the fish of a group).
    pub frames_lost: u64,
    /// Stop commands received.
    pub stops: u64,
    /// The SHA-256 of the weights the bridge flew, as its welcome named them (none for a
    /// scripted pilot, or a bridge of an earlier version).
    pub policy_sha256: Option<String>,
    /// What the bridge reported going wrong (a trial file written elsewhere, or kept in its
    /// memory, because the disk was full).
    pub warnings: Vec<String>,
}

fn normal(rng: &mut SimRng) -> f32 {
    StandardNormal.sample(rng)
}

fn reader_thread(stream: TcpStream) -> mpsc::Receiver<Result<ServerMsg, String>> {
    let (tx, rx) = mpsc::channel();
    std::thread::spawn(move || {
        let mut r = BufReader::new(stream);
        loop {
            let m = match crate::read_line_at_most(&mut r, crate::MAX_BRIDGE_LINE_BYTES) {
                Ok(Some(l)) => serde_json::from_str::<ServerMsg>(&l)
                    .map_err(|e| format!("bad message from the bridge: {e}")),
                Ok(None) => break,
                Err(e) if e.kind() == std::io::ErrorKind::InvalidData => {
                    // Reported once; the trial ends on it.
                    let _ = tx.send(Err(format!("bad message from the bridge: {e}")));
                    break;
                }
                Err(_) => break,
            };
            if tx.send(m).is_err() {
                break;
            }
        }
    });
    rx
}

/// What the bridge's welcome sets for a trial.
struct Terms {
    habituation_s: f64,
    release_s: f64,
    control_s: f64,
    fish_count: usize,
    policy_sha256: Option<String>,
}

/// Says hello to the bridge and reads its welcome.
fn handshake(
    conn: &mut TcpStream,
    rx: &mpsc::Receiver<Result<ServerMsg, String>>,
    cfg: &LabConfig,
    net: impl Fn(std::io::Error) -> LiveError,
) -> Result<Terms, LiveError> {
    let hello = ClientMsg::Hello {
        protocol: PROTOCOL_VERSION,
        world_size_cm: [crate::TANK_CM; 2],
        tracking_hz: cfg.tracking_hz,
        source: "virtual_lab".into(),
        token: None,
        sync: true,
    };
    conn.write_all(to_line(&hello).as_bytes()).map_err(net)?;
    match rx.recv_timeout(Duration::from_secs_f32(cfg.command_timeout_s)) {
        Ok(Ok(ServerMsg::Welcome {
            habituation_s,
            release_s,
            control_s,
            fish_count,
            policy_sha256,
            ..
        })) => {
            if !(1..=fishprobe_sim::MAX_FISH as u32).contains(&fish_count) {
                return Err(LiveError::Net(format!(
                    "the bridge asks for {fish_count} fish; the virtual lab holds 1 to {}",
                    fishprobe_sim::MAX_FISH
                )));
            }
            Ok(Terms {
                habituation_s,
                release_s,
                control_s,
                fish_count: fish_count as usize,
                policy_sha256,
            })
        }
        Ok(Ok(ServerMsg::Error { reason })) => Err(LiveError::Refused(reason)),
        Ok(Ok(other)) => Err(LiveError::Net(format!("expected welcome, got {other:?}"))),
        Ok(Err(e)) => Err(LiveError::Net(e)),
        Err(_) => Err(LiveError::Net("no welcome from the bridge".into())),
    }
}

/// The tank's contents as the lab simulates them: the robot under the bridge's commands, the
/// virtual guppies, and the tracker's noise and dropouts, each with its random stream.
struct VirtualTank<'a> {
    cfg: &'a LabConfig,
    tank: Tank,
    robot_params: RobotParams,
    dt: f32,
    model: std::sync::Arc<dyn FishModel>,
    views: Vec<FishView>,
    inferred: Vec<f32>,
    robot: Robot,
    stopped: bool,
    fish: Vec<AgentState>,
    minds: Vec<FishMind>,
    rng_fish: Vec<SimRng>,
    rng_track: SimRng,
    dropout_left: Vec<f32>,
}

impl<'a> VirtualTank<'a> {
    /// The robot in the centre, the fish waiting in their container.
    fn new(cfg: &'a LabConfig, seed: u64, n_fish: usize) -> Result<Self, LiveError> {
        // One stream per fish: fish 0 draws what the one fish of a pair trial drew.
        let mut rng_fish: Vec<SimRng> = (0..n_fish as u64)
            .map(|i| stream(seed, "lab/fish", i))
            .collect();
        let mut rng_track = stream(seed, "lab/tracking", 0);
        let robot = Robot::at(
            0.0,
            0.0,
            rng_track.random_range(-std::f32::consts::PI..std::f32::consts::PI),
        );
        // The fish wait in the container, a group in a small cluster (choice: 2 cm apart along
        // the corner's diagonal and across it), each its own individual.
        let fish: Vec<AgentState> = (0..n_fish)
            .map(|i| {
                let (along, across) = ((i / 2) as f32 * 2.0, (i % 2) as f32 * 2.0);
                let dir = [
                    -cfg.container[0].signum() * std::f32::consts::FRAC_1_SQRT_2,
                    -cfg.container[1].signum() * std::f32::consts::FRAC_1_SQRT_2,
                ];
                AgentState::at(
                    cfg.container[0] + along * dir[0] - across * dir[1],
                    cfg.container[1] + along * dir[1] + across * dir[0],
                    std::f32::consts::FRAC_PI_4,
                )
            })
            .collect();
        let model = ModelSpec::by_name(&cfg.fish_model)
            .and_then(|s| s.build())
            .map_err(|e| LiveError::Settings(format!("lab.fish_model: {e}")))?;
        let mut minds = vec![FishMind::default(); n_fish];
        for ((f, m), r) in fish.iter().zip(&mut minds).zip(&mut rng_fish) {
            model.begin_episode(f, m, r);
        }
        Ok(Self {
            cfg,
            tank: Tank::new(&TankParams::default()),
            robot_params: RobotParams::default(),
            dt: 1.0 / cfg.tracking_hz,
            views: vec![FishView::default(); n_fish],
            inferred: vec![0.0; n_fish * model.inference_width()],
            model,
            robot,
            stopped: false,
            fish,
            minds,
            rng_fish,
            rng_track,
            dropout_left: vec![0.0; n_fish],
        })
    }

    /// One frame on, to time `t`: the robot (unless stopped) and, from `release_s` on, the
    /// fish, every fish deciding from the same snapshot before any moves.
    fn advance(&mut self, t: f64, release_s: f64) -> Result<(), LiveError> {
        let dt = self.dt;
        if !self.stopped {
            self.robot.advance(&self.robot_params, &self.tank, dt);
        }
        if t >= release_s {
            for (i, view) in self.views.iter_mut().enumerate() {
                *view = FishView::build(
                    i,
                    &self.fish,
                    &[self.robot.state],
                    self.tank,
                    dt,
                    (t - release_s) as f32,
                );
                view.individual = self.minds[i].individual;
            }
            if self.model.inference_width() > 0 {
                self.model.infer_batch(&self.views, &mut self.inferred);
            }
            let frame = ((t - release_s) / f64::from(dt)).round() as u32;
            step_fish(
                self.model.as_ref(),
                &self.views,
                &self.inferred,
                &mut self.minds,
                &mut self.rng_fish,
                &mut self.fish,
                &self.tank,
                dt,
                frame,
            )
            .map_err(|e| LiveError::Settings(format!("lab.fish_model: {e}")))?;
        }
        Ok(())
    }

    /// The tracker's frame at time `t`: every pose with noise, fish in a dropout without one
    /// (counted in `out`).
    fn track(&mut self, t: f64, out: &mut LabTrial) -> ClientMsg {
        let (cfg, dt) = (self.cfg, self.dt);
        for left in &mut self.dropout_left {
            if *left > 0.0 {
                *left -= dt;
            } else if self.rng_track.random::<f32>() < cfg.dropouts_per_min / 60.0 * dt {
                *left = cfg.dropout_min_s
                    + (cfg.dropout_max_s - cfg.dropout_min_s) * self.rng_track.random::<f32>();
            }
        }
        let noisy = |s: &AgentState, r: &mut SimRng| Pose {
            x: s.x + cfg.position_noise_cm * normal(r),
            y: s.y + cfg.position_noise_cm * normal(r),
            heading: wrap_angle(s.heading + cfg.heading_noise_rad * normal(r)),
        };
        let robot_pose = noisy(&self.robot.state, &mut self.rng_track);
        let mut poses = Vec::with_capacity(self.fish.len());
        for (i, (f, left)) in self.fish.iter().zip(&self.dropout_left).enumerate() {
            let pose = noisy(f, &mut self.rng_track);
            let lost = *left > 0.0;
            if lost {
                out.frames_lost += 1;
            }
            poses.push(FishPose {
                id: format!("fish_{}", i + 1),
                pose: (!lost).then_some(pose),
            });
        }
        ClientMsg::Frame {
            t,
            robot: Some(robot_pose),
            fish: poses,
        }
    }

    /// Applies what the bridge said: a command to the robot, the trial's end or a warning to
    /// `out`. Whether the trial is done.
    fn apply(&mut self, m: ServerMsg, out: &mut LabTrial) -> bool {
        match m {
            ServerMsg::Command(Command {
                seq, turn, stop, ..
            }) => {
                if stop {
                    if !self.stopped {
                        out.stops += 1;
                    }
                    self.stopped = true;
                    self.robot.speed = 0.0;
                    self.robot.turn_rate = 0.0;
                } else {
                    self.stopped = false;
                    if seq.is_some() {
                        self.robot.begin_action(turn);
                    }
                }
                false
            }
            ServerMsg::Done {
                file,
                goals_reached,
            } => {
                out.file = file;
                out.goals_reached = goals_reached;
                true
            }
            ServerMsg::Error { reason } => {
                out.warnings.push(reason);
                false
            }
            _ => false,
        }
    }
}

/// " (it last said: …)" with the bridge's last warning, or nothing.
fn last_said(out: &LabTrial) -> String {
    out.warnings
        .last()
        .map_or_else(String::new, |w| format!(" (it last said: {w})"))
}

/// Runs one virtual trial against the bridge at `addr`.
pub fn run_trial(addr: SocketAddr, cfg: &LabConfig, seed: u64) -> Result<LabTrial, LiveError> {
    cfg.validate()?;
    let net = |e: std::io::Error| LiveError::Net(format!("{addr}: {e}"));
    let mut conn = TcpStream::connect(addr).map_err(net)?;
    let _ = conn.set_nodelay(true);
    let rx = reader_thread(conn.try_clone().map_err(net)?);
    let terms = handshake(&mut conn, &rx, cfg, net)?;
    let wait = Duration::from_secs_f32(cfg.command_timeout_s);
    let mut lab = VirtualTank::new(cfg, seed, terms.fish_count)?;
    let mut out = LabTrial {
        file: String::new(),
        goals_reached: 0,
        frames_sent: 0,
        frames_lost: 0,
        stops: 0,
        policy_sha256: terms.policy_sha256,
        warnings: Vec::new(),
    };
    let total =
        ((terms.habituation_s + terms.control_s) * f64::from(cfg.tracking_hz)).ceil() as u64 + 2;
    let started = std::time::Instant::now();
    for k in 0..total + 50 {
        let t = k as f64 / f64::from(cfg.tracking_hz);
        if k > 0 {
            lab.advance(t, terms.release_s)?;
        }
        if cfg.real_time {
            let due = started + Duration::from_secs_f64(t);
            std::thread::sleep(due.saturating_duration_since(std::time::Instant::now()));
        }
        let frame = lab.track(t, &mut out);
        if conn.write_all(to_line(&frame).as_bytes()).is_err() {
            break;
        }
        out.frames_sent += 1;
        // Lockstep: apply everything the bridge says about this frame, up to its ack.
        loop {
            let m = match rx.recv_timeout(wait) {
                Ok(m) => m.map_err(LiveError::Net)?,
                Err(_) => {
                    return Err(LiveError::Net(format!(
                        "no answer from the bridge for {:.0} s{}",
                        cfg.command_timeout_s,
                        last_said(&out)
                    )));
                }
            };
            if matches!(m, ServerMsg::Ack { .. }) {
                break;
            }
            if lab.apply(m, &mut out) {
                let _ = conn.shutdown(std::net::Shutdown::Both);
                return Ok(out);
            }
        }
    }
    // The bridge never said done (it was killed, or the trial ran past its end).
    loop {
        match rx.recv_timeout(wait) {
            Ok(Ok(ServerMsg::Done {
                file,
                goals_reached,
            })) => {
                out.file = file;
                out.goals_reached = goals_reached;
                return Ok(out);
            }
            Ok(Ok(ServerMsg::Error { reason })) => out.warnings.push(reason),
            Ok(Ok(_)) => {}
            _ => {
                return Err(LiveError::Net(format!(
                    "the bridge did not finish the trial{}",
                    last_said(&out)
                )))
            }
        }
    }
}
