//! How far out of M_ConvNet's training support can a *scripted* robot drive the fish?
//! A ceiling check for the OOD objective: if no simple strategy keeps the fish's views beyond a
//! score, a trained OOD policy that does not either may be limited by the fish, not by PPO.
//! docs/validation.md, "Probes that seek what the data lacks", cites it.
//!
//! ```sh
//! cargo run --release -p fishprobe-learn --example ood_scripted -- EPISODES THRESHOLD [MODEL [PREFIX [FRAMES_PER_ACTION]]]
//! ```
//!
//! Every strategy meets the same training-task episodes (41 s, random starts; master seed 0,
//! label "ood-scripted"), against MODEL (default: the shipped M_ConvNet; `convnet:FILE` for
//! weights with their own support file beside them), every frame scored against its support.
//! Prints, per strategy, the mean, median and 95th percentile of the per-second mean score,
//! the share of seconds whose mean score is at least THRESHOLD (default 1.23, the lead-to-goal
//! policy's 95th percentile per view in validation.md) and the share of single views at least
//! THRESHOLD (what `ood-report` counts for a policy). Each second the robot turns toward:
//! - `seek`: the active goal (the goal-seeker baseline);
//! - `chase`: the fish;
//! - `aheadD`: the point D cm ahead of the fish along its heading (D = 5, 10, 20);
//! - `behind10`: the point 10 cm behind it; `side8`: 8 cm to its left;
//! - `flee`: away from the fish;
//! - `corner`: the corner nearest the fish (45 cm out on both axes);
//! - `random`: a uniform turn in [-3, 3] rad;
//! - `pinD`: the point D cm from the fish toward the tank's centre (D = 4, 8), so that the fish
//!   is between the robot and the walls;
//! - `wallpin`: 5 cm from the fish along the normal of the fish's nearest wall;
//! - `orbit-cw-R-A` / `orbit-ccw-R-A`: around the fish at R cm (R = 5, 8, 12, 16), clockwise /
//!   counter-clockwise: the point on that circle A rad (0.5, 0.8, 1.2, 1.6) beyond the robot's
//!   present bearing from the fish. Clockwise, the robot passes the fish's right heading the
//!   opposite way, the OOD policies' first wish (docs/validation.md, "Probes that seek what the data lacks").
//! - `weave-D-L`: across the fish's path in front of it: the point D cm ahead of the fish and
//!   L cm to the side of its path opposite the robot's (D = 5, 10, 20; L = 5, 10, 15), so the
//!   robot keeps crossing the fish's heading instead of swimming alongside it.
//! - `pass-O-D`: repeated passes down the fish's right side heading the opposite way, the
//!   orbits' best situation without the rest of the turn: while the robot is ahead of the fish
//!   it turns toward the point O cm to the fish's right (O = 3, 6, 10), once behind it toward
//!   the point D cm ahead of the fish and O cm to its right (D = 15, 25), to come round again.
//!
//! A fourth argument keeps only the strategies whose names start with it (`weave`); a fifth sets
//! the frames per action (default 25, the paper's 1 Hz; the episode stays 41 s): a robot that
//! re-aims more often, to see whether the policy's action rate limits the OOD objective.

use fishprobe_models::ModelSpec;
use fishprobe_sim::{
    derive_seed, stream, wrap_angle, Env, EnvConfig, InputSupport, Objective, TankEnv,
};
use rand::RngExt;
use std::sync::Arc;

#[path = "common/counting.rs"]
mod counting;
use counting::Counting;

fn main() -> Result<(), Box<dyn std::error::Error>> {
    let args: Vec<String> = std::env::args().skip(1).collect();
    let episodes: u64 = args.first().map_or(Ok(40), |s| s.parse())?;
    let thr: f32 = args.get(1).map_or(Ok(1.23), |s| s.parse())?;
    let model = ModelSpec::by_name(args.get(2).map_or("ConvNet", String::as_str))?;
    let support: Arc<dyn InputSupport> = Arc::new(model.support()?);
    let mut cfg = EnvConfig::default();
    cfg.task.objective = Objective::Ood;
    cfg.task.ood_score_every_frames = 1;
    cfg.task.ood_score_cap = 100.0;
    if let Some(f) = args.get(4) {
        cfg.frames_per_action = f.parse()?;
        let seconds = cfg.task.training_episode_actions as f32;
        cfg.task.training_episode_actions =
            (seconds * cfg.frame_rate_hz / cfg.frames_per_action as f32).round() as _;
        cfg.validate()?;
    }
    let mut pilots: Vec<String> = [
        "seek", "chase", "ahead5", "ahead10", "ahead20", "behind10", "side8", "flee", "corner",
        "random", "pin4", "pin8", "wallpin",
    ]
    .map(String::from)
    .to_vec();
    for dir in ["cw", "ccw"] {
        for rad in ["5", "8", "12", "16"] {
            for step in ["0.5", "0.8", "1.2", "1.6"] {
                pilots.push(format!("orbit-{dir}-{rad}-{step}"));
            }
        }
    }
    for ahead in ["5", "10", "20"] {
        for side in ["5", "10", "15"] {
            pilots.push(format!("weave-{ahead}-{side}"));
        }
    }
    for off in ["3", "6", "10"] {
        for ahead in ["15", "25"] {
            pilots.push(format!("pass-{off}-{ahead}"));
        }
    }
    let only = args.get(3).map_or("", String::as_str);
    for name in pilots
        .iter()
        .map(String::as_str)
        .filter(|n| n.starts_with(only))
    {
        // orbit-DIR-R-A: (clockwise, R, A)
        let orbit: Option<(bool, f32, f32)> = name.strip_prefix("orbit-").and_then(|o| {
            let p: Vec<&str> = o.split('-').collect();
            Some((p[0] == "cw", p[1].parse().ok()?, p[2].parse().ok()?))
        });
        // weave-D-L: (D, L)
        let pair = |prefix: &str| -> Option<(f32, f32)> {
            let (a, b) = name.strip_prefix(prefix)?.split_once('-')?;
            Some((a.parse().ok()?, b.parse().ok()?))
        };
        let weave = pair("weave-");
        // pass-O-D: (O, D)
        let pass = pair("pass-");
        let (mut n, mut hi, mut sum) = (0u64, 0u64, 0.0f64);
        let mut scores = Vec::new();
        let counting = Arc::new(Counting::new(support.clone(), thr));
        for ep in 0..episodes {
            let mut env = TankEnv::new(cfg.clone(), model.build()?)?;
            env.set_support(Some(counting.clone()));
            let mut obs = vec![0.0; env.observation_space().dim()];
            env.reset(Some(derive_seed(0, "ood-scripted", ep)), &mut obs)?;
            let mut rng = stream(0, "ood-scripted-actions", ep);
            loop {
                let r = env.robot().state;
                let f = env.fish()[0];
                let g = env.active_goal();
                let toward = |t: [f32; 2]| wrap_angle((t[1] - r.y).atan2(t[0] - r.x) - r.heading);
                let (c, s) = (f.heading.cos(), f.heading.sin());
                let action = if let Some((ahead, side)) = weave {
                    // The robot's side of the fish's path (left: +), and the point opposite.
                    let left = c * (r.y - f.y) - s * (r.x - f.x) > 0.0;
                    let l = if left { -side } else { side };
                    toward([f.x + ahead * c - l * s, f.y + ahead * s + l * c])
                } else if let Some((off, ahead)) = pass {
                    // The fish's right: (s, -c). Ahead of the fish: pass down its right side.
                    let in_front = c * (r.x - f.x) + s * (r.y - f.y) > 0.0;
                    let d = if in_front { 0.0 } else { ahead };
                    toward([f.x + d * c + off * s, f.y + d * s - off * c])
                } else if let Some((cw, rad, step)) = orbit {
                    let b = (r.y - f.y).atan2(r.x - f.x) + if cw { -step } else { step };
                    toward([f.x + rad * b.cos(), f.y + rad * b.sin()])
                } else {
                    match name {
                        "seek" => toward(g),
                        "chase" => toward([f.x, f.y]),
                        "ahead5" => toward([f.x + 5.0 * c, f.y + 5.0 * s]),
                        "ahead10" => toward([f.x + 10.0 * c, f.y + 10.0 * s]),
                        "ahead20" => toward([f.x + 20.0 * c, f.y + 20.0 * s]),
                        "behind10" => toward([f.x - 10.0 * c, f.y - 10.0 * s]),
                        "side8" => toward([f.x - 8.0 * s, f.y + 8.0 * c]),
                        "flee" => toward([2.0 * r.x - f.x, 2.0 * r.y - f.y]),
                        "corner" => toward([45.0 * f.x.signum(), 45.0 * f.y.signum()]),
                        "pin4" | "pin8" => {
                            let d = if name == "pin4" { 4.0 } else { 8.0 };
                            let n = f.x.hypot(f.y).max(1e-3);
                            toward([f.x - d * f.x / n, f.y - d * f.y / n])
                        }
                        "wallpin" => {
                            // between the fish and the tank's centre along the nearest wall's normal
                            let (nx, ny) = if f.x.abs() > f.y.abs() {
                                (f.x.signum(), 0.0)
                            } else {
                                (0.0, f.y.signum())
                            };
                            toward([f.x - 5.0 * nx, f.y - 5.0 * ny])
                        }
                        _ => rng.random_range(-3.0..3.0),
                    }
                };
                let t = env.step(&[action], &mut obs)?;
                let sc = t.info.support_score;
                n += 1;
                hi += u64::from(sc >= thr);
                sum += f64::from(sc);
                scores.push(sc);
                if t.truncated {
                    break;
                }
            }
        }
        scores.sort_by(f32::total_cmp);
        let (views, beyond) = counting.counts();
        let views = views.max(1);
        println!(
            "{name:>16}: mean {:.2} median {:.2} p95 {:.2} seconds >= {thr}: {:.1} %, views >= {thr}: {:.1} %",
            sum / n as f64,
            scores[scores.len() / 2],
            scores[scores.len() * 95 / 100],
            100.0 * hi as f64 / n as f64,
            100.0 * beyond as f64 / views as f64
        );
    }
    Ok(())
}
