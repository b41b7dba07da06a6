//! How close does a trained policy come to scripted controllers on the task it was trained on
//! (random goals, 41-second episodes; SPEC §4)? docs/validation.md, "Does PPO learn?", cites this for
//! π_Follow. Every controller meets the same episodes: start poses, goal sequence and fish noise
//! come from seeds derived from master seed 0 (label "training-task"), one per episode.
//!
//! ```sh
//! cargo run --release -p fishprobe-learn --example training_task -- MODEL EPISODES [POLICY_DIR...]
//! cargo run --release -p fishprobe-learn --example training_task -- --evaluation MODEL EPISODES [POLICY_DIR...]
//! ```
//!
//! With `--evaluation` the same controllers meet evaluation episodes instead (15 minutes, the
//! two corner goals; SPEC §4), where a study measures probe competence against the goal-seeker
//! and fetch-and-lead (docs/validation.md, "Are the probes competent?").
//!
//! Prints, per controller, goals per episode (mean ± standard error), the mean return (goals
//! minus the wall penalties) and the robot's wall-contact frames per episode. For a policy's
//! mean action it adds what the policy does in the seconds when the goal lies more than 120°
//! off its heading: its s.d. there and how often its mean action turns by less than 90°, i.e.
//! drives on instead of turning toward the goal (docs/validation.md, "Does PPO learn?", the log-s.d. bound). The scripted
//! controllers, each turning every second toward a target point:
//! - `goal-seeker`: the goal's centre (the baseline of `fishprobe evaluate`);
//! - `goal-seeker, 10° sectors`: the centre of the goal's observation sector, i.e. only what
//!   the policy sees of the goal's direction;
//! - `near edge`: 2 cm inside the goal's edge on the fish's side, so the fish stops there
//!   instead of following the robot through the goal;
//! - `lead L cm`: L cm ahead of the fish on its line to the goal (never past the near edge),
//!   so that a fish that swims at the robot swims straight to the goal;
//! - `fetch D cm`: the fish while it is farther than D cm from the robot, else the lead point
//!   10 cm ahead of it: fetch the fish, then lead it (for fish that perceive the robot only
//!   nearby, like M_Zone's 18 cm and M_Force's 15 cm).
//! - `fetch-and-lead`: fishprobe's scripted baseline of that name, with its settings (the
//!   one a study's probe competence compares with).
//!
//! For M_Follow it first prints a limit no controller can pass: a fish that swims straight to
//! every goal at M_Follow's constant speed, from each episode's start position and first goal
//! (later goals drawn by the task's rule from a stream of their own).

use fishprobe_learn::{to_env_action, GaussianPolicy};
use fishprobe_models::{FollowParams, ModelSpec};
use fishprobe_nn::MlpWorkspace;
use fishprobe_sim::{
    derive_seed, stream, wrap_angle, ControlInput, Controller, Env, EnvConfig, FetchAndLead,
    GoalSeeker, TankEnv, TaskMode,
};
use rand::RngExt;
use rand_distr::{Distribution, StandardNormal};
use std::io::Write;
use std::path::Path;

/// What turns the robot.
enum Pilot {
    Seek,
    SeekSectors(usize),
    NearEdge(f32),
    Lead(f32),
    Fetch(f32),
    FetchAndLead(FetchAndLead),
    Policy(Box<GaussianPolicy>, bool),
}

fn unit(v: [f32; 2]) -> [f32; 2] {
    let n = v[0].hypot(v[1]).max(1e-6);
    [v[0] / n, v[1] / n]
}

/// Goals per episode (mean, standard error) of a fish that swims straight to every goal at
/// `speed` cm/s.
fn straight_fish(
    cfg: &EnvConfig,
    model: &ModelSpec,
    speed: f32,
    episodes: u64,
) -> Result<(f64, f64), Box<dyn std::error::Error>> {
    let (r, step) = (cfg.task.goal_radius_cm, speed / cfg.frame_rate_hz);
    let lim = cfg.tank.half_size_cm - cfg.task.goal_wall_clearance_cm;
    let frames = cfg.task.training_episode_actions * cfg.frames_per_action;
    let (mut sum, mut sum2) = (0.0f64, 0.0f64);
    for ep in 0..episodes {
        let mut env = TankEnv::new(cfg.clone(), model.build()?)?;
        let mut obs = vec![0.0; env.observation_space().dim()];
        env.reset(Some(derive_seed(0, "training-task", ep)), &mut obs)?;
        let (f, mut g) = (env.fish()[0], env.active_goal());
        let mut p = [f.x, f.y];
        let mut rng = stream(0, "training-task-limit", ep);
        let mut n = 0.0;
        for _ in 0..frames {
            let d = (g[0] - p[0]).hypot(g[1] - p[1]);
            let s = step.min(d) / d.max(1e-6);
            p = [p[0] + s * (g[0] - p[0]), p[1] + s * (g[1] - p[1])];
            if (g[0] - p[0]).hypot(g[1] - p[1]) < r {
                n += 1.0;
                for _ in 0..64 {
                    g = [rng.random_range(-lim..=lim), rng.random_range(-lim..=lim)];
                    if (g[0] - p[0]).hypot(g[1] - p[1]) >= r {
                        break;
                    }
                }
            }
        }
        sum += n;
        sum2 += n * n;
    }
    let n = episodes as f64;
    let mean = sum / n;
    Ok((
        mean,
        ((sum2 - n * mean * mean) / (n - 1.0)).max(0.0).sqrt() / n.sqrt(),
    ))
}

fn main() {
    if let Err(e) = run() {
        // A closed pipe (`| head`) is the reader's choice, not an error.
        let closed = e
            .downcast_ref::<std::io::Error>()
            .is_some_and(|e| e.kind() == std::io::ErrorKind::BrokenPipe);
        if !closed {
            eprintln!("training_task: {e}");
            std::process::exit(2);
        }
    }
}

fn run() -> Result<(), Box<dyn std::error::Error>> {
    let mut args: Vec<String> = std::env::args().skip(1).collect();
    let evaluation = args.first().is_some_and(|a| a == "--evaluation");
    if evaluation {
        args.remove(0);
    }
    let usage = "usage: training_task [--evaluation] MODEL EPISODES [POLICY_DIR...]";
    let model = ModelSpec::by_name(args.first().ok_or(usage)?)?;
    let episodes: u64 = args
        .get(1)
        .ok_or(usage)?
        .parse()
        .ok()
        .filter(|&n| n > 0)
        .ok_or("EPISODES must be a whole number of at least 1")?;
    let mut pilots: Vec<(String, Pilot)> = vec![
        ("goal-seeker".into(), Pilot::Seek),
        ("goal-seeker, 10° sectors".into(), Pilot::SeekSectors(36)),
        ("near edge".into(), Pilot::NearEdge(2.0)),
    ];
    for l in [10.0, 20.0, 30.0] {
        pilots.push((format!("lead {l} cm"), Pilot::Lead(l)));
    }
    for d in [8.0, 12.0, 16.0] {
        pilots.push((format!("fetch {d} cm"), Pilot::Fetch(d)));
    }
    pilots.push((
        "fetch-and-lead".into(),
        Pilot::FetchAndLead(FetchAndLead::default()),
    ));
    for dir in &args[2..] {
        let (p, _) = GaussianPolicy::load(Path::new(dir))?;
        pilots.push((
            format!("{dir}, mean action"),
            Pilot::Policy(Box::new(p.clone()), false),
        ));
        pilots.push((format!("{dir}, sampled"), Pilot::Policy(Box::new(p), true)));
    }
    let cfg = EnvConfig {
        mode: if evaluation {
            TaskMode::Evaluation
        } else {
            TaskMode::Training
        },
        ..EnvConfig::default()
    };
    let radius = cfg.task.goal_radius_cm;
    let mut stdout = std::io::stdout().lock();
    let kind = if evaluation { "evaluation" } else { "training" };
    writeln!(stdout, "{}, {episodes} {kind} episodes", model.name())?;
    if model.name() == "Follow" && !evaluation {
        let speed = FollowParams::default().speed_cm_s;
        let (mean, se) = straight_fish(&cfg, &model, speed, episodes)?;
        writeln!(
            stdout,
            "{:>40}: {mean:.2} ± {se:.2} goals per episode",
            format!("limit: straight to each goal, {speed} cm/s")
        )?;
    }
    for (name, pilot) in &pilots {
        let (mut goals, mut goals2, mut ret, mut walls) = (0.0f64, 0.0f64, 0.0f64, 0u64);
        // Seconds with the goal behind: count, sum of the policy's s.d., mean turns < 90°.
        let (mut behind, mut behind_sd, mut behind_on) = (0u64, 0.0f64, 0u64);
        let mut ws = MlpWorkspace::default();
        for ep in 0..episodes {
            let mut env = TankEnv::new(cfg.clone(), model.build()?)?;
            let mut obs = vec![0.0; env.observation_space().dim()];
            env.reset(Some(derive_seed(0, "training-task", ep)), &mut obs)?;
            let mut rng = stream(0, "training-task-actions", ep);
            loop {
                let r = env.robot().state;
                let f = env.fish()[0];
                let g = env.active_goal();
                let toward = |t: [f32; 2]| wrap_angle((t[1] - r.y).atan2(t[0] - r.x) - r.heading);
                let to_goal = unit([g[0] - f.x, g[1] - f.y]);
                let fish_goal = (g[0] - f.x).hypot(g[1] - f.y);
                let input = ControlInput {
                    obs: &obs,
                    robot: r,
                    fish: env.fish(),
                    goal: g,
                };
                let action = match pilot {
                    // fishprobe's one goal-seeker, the baseline of `evaluate` and the bridge.
                    Pilot::Seek => GoalSeeker.act(&input, &mut rng),
                    Pilot::SeekSectors(n) => {
                        let w = std::f32::consts::TAU / *n as f32;
                        let i = ((toward(g) + std::f32::consts::PI) / w).floor();
                        -std::f32::consts::PI + (i + 0.5) * w
                    }
                    Pilot::NearEdge(d) => {
                        let at = radius - d;
                        toward([g[0] - at * to_goal[0], g[1] - at * to_goal[1]])
                    }
                    Pilot::Lead(l) => {
                        let ahead = l.min((fish_goal - radius + 2.0).max(0.0));
                        toward([f.x + ahead * to_goal[0], f.y + ahead * to_goal[1]])
                    }
                    Pilot::Fetch(d) => {
                        if (f.x - r.x).hypot(f.y - r.y) > *d {
                            toward([f.x, f.y])
                        } else {
                            let ahead = 10f32.min((fish_goal - radius + 2.0).max(0.0));
                            toward([f.x + ahead * to_goal[0], f.y + ahead * to_goal[1]])
                        }
                    }
                    Pilot::FetchAndLead(c) => c.clone().act(&input, &mut rng),
                    Pilot::Policy(p, sampled) => {
                        let y = p.pi.forward(&obs, 1, &mut ws);
                        let z: f32 = if *sampled {
                            StandardNormal.sample(&mut rng)
                        } else {
                            0.0
                        };
                        let sd = p.log_std(y[1]).exp();
                        let turn = to_env_action(y[0] + sd * z);
                        if !*sampled && toward(g).abs() > 2.0 * std::f32::consts::FRAC_PI_3 {
                            behind += 1;
                            behind_sd += f64::from(sd);
                            behind_on += u64::from(turn.abs() < std::f32::consts::FRAC_PI_2);
                        }
                        turn
                    }
                };
                if env.step(&[action], &mut obs)?.truncated {
                    break;
                }
            }
            let s = env.summary();
            let n = s.goal_events.len() as f64;
            goals += n;
            goals2 += n * n;
            ret += f64::from(s.episode_return);
            walls += u64::from(s.robot_wall_contacts);
        }
        let n = episodes as f64;
        let mean = goals / n;
        let se = ((goals2 - n * mean * mean) / (n - 1.0)).max(0.0).sqrt() / n.sqrt();
        writeln!(
            stdout,
            "{name:>40}: {mean:.2} ± {se:.2} goals per episode, return {:.2}, wall-contact frames {:.1}",
            ret / n,
            walls as f64 / n
        )?;
        if behind > 0 {
            let b = behind as f64;
            writeln!(
                stdout,
                "{:>40}  goal > 120° off: s.d. {:.2} (normalised; 1 = π rad), turns < 90° in {:.0} % of {behind} s",
                "",
                behind_sd / b,
                100.0 * behind_on as f64 / b
            )?;
        }
    }
    Ok(())
}
