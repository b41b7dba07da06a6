//! A ceiling check for the OOD objective with a planner: how much of the time can a
//! robot that *knows* the fish hold its views at or beyond a score? `ood_scripted` asks this of
//! simple strategies; this asks it of a planner that, each second, imagines the next seconds
//! with the fish model itself.
//!
//! ```sh
//! cargo run --release -p fishprobe-learn --example ood_planner -- EPISODES THRESHOLD MODEL [HORIZON [TURNS [FUTURES [SECONDS [FRAMES [LEAD]]]]]]
//! ```
//!
//! FRAMES is the frames per decision (default 25, the paper's 1 Hz; 5 re-plans five times a
//! second); HORIZON and SECONDS stay in seconds. LEAD is the base robot's orbit lead angle
//! (default 1.2 rad, the best orbit at 1 Hz; at 5 Hz `ood_scripted`'s best is 0.5).
//!
//! The episodes are `ood_scripted`'s (41-s training-task episodes, random starts; master seed 0,
//! label "ood-scripted"; SECONDS sets another length, e.g. 300 as `ood-report`'s), against MODEL (`convnet:FILE` with its support file beside it), every
//! frame scored. Each second the planner tries TURNS turns evenly spread over [-π, π) (default
//! 12) and the base robot's own turn; for each it steps FUTURES clones of the episode
//! (default 2) through HORIZON seconds (default 4: the tried turn, then the base robot), each
//! clone with its own fish noise (`TankEnv::reseed_fish_noise`; the same FUTURES seeds for every
//! turn, so the turns are compared on the same futures), and counts the clones' views at or
//! beyond THRESHOLD (the task's wall penalty included). The turn with the most is taken in the
//! episode, whose noise the planner never sees. FUTURES = 0 is a clairvoyant planner instead: one
//! clone with the episode's own noise, so it sees exactly what each turn will bring over the
//! horizon (an upper bound for planners of this horizon and base robot). The base robot is `ood_scripted`'s best, the
//! clockwise orbit at 12 cm, 1.2 rad ahead: so the planner is one step of policy improvement on
//! it, given the fish model, the fish's state and everything but its future noise: more than
//! a policy's observation holds (the fish's heading, its exact position, its model).
//!
//! Prints the share of the episodes' views at or beyond THRESHOLD for the base robot alone and
//! for the planner. docs/validation.md, "Probes that seek what the data lacks", cites it.

use fishprobe_models::ModelSpec;
use fishprobe_sim::{derive_seed, wrap_angle, Env, EnvConfig, InputSupport, Objective, TankEnv};
use rayon::prelude::*;
use std::sync::Arc;

#[path = "common/counting.rs"]
mod counting;
use counting::Counting;

/// The base robot: toward the point 12 cm from the fish, `lead` rad clockwise beyond the
/// robot's bearing from it (`ood_scripted`'s `orbit-cw-12-LEAD`; 1.2 is its best at 1 Hz).
fn orbit(env: &TankEnv, lead: f32) -> f32 {
    let r = env.robot().state;
    let f = env.fish()[0];
    let b = (r.y - f.y).atan2(r.x - f.x) - lead;
    let (tx, ty) = (f.x + 12.0 * b.cos(), f.y + 12.0 * b.sin());
    wrap_angle((ty - r.y).atan2(tx - r.x) - r.heading)
}

/// Settings of one run.
struct Plan {
    /// The base robot's orbit lead angle (rad).
    lead: f32,
    horizon: usize,
    turns: usize,
    futures: u64,
}

/// The imagined count of views at or beyond the threshold after `first`, then the base robot,
/// over the horizon, summed over the futures.
fn imagine(env: &TankEnv, first: f32, plan: &Plan, second: u64, obs: &mut [f32]) -> f32 {
    let mut total = 0.0;
    for k in 0..plan.futures.max(1) {
        let mut e = env.clone();
        if plan.futures > 0 {
            e.reseed_fish_noise(derive_seed(second, "ood-planner-future", k));
        }
        for h in 0..plan.horizon {
            let a = if h == 0 { first } else { orbit(&e, plan.lead) };
            match e.step(&[a], obs) {
                Ok(t) => {
                    total += t.reward;
                    if t.truncated {
                        break;
                    }
                }
                Err(_) => break,
            }
        }
    }
    total
}

/// Replicates of [`interval_over_episodes`]' bootstrap, as `ood-report`'s.
const INTERVAL_REPS: usize = 2000;

/// The 95 % percentile-bootstrap interval of the share of views at or beyond the threshold,
/// drawing whole episodes again (`(views, beyond)` each), as `ood-report` draws its episodes:
/// so the planner's share compares with a policy's on the same footing.
fn interval_over_episodes(per_episode: &[(u64, u64)]) -> [f64; 2] {
    use rand::RngExt;
    let n = per_episode.len();
    if n == 0 {
        return [f64::NAN; 2];
    }
    let mut rng = fishprobe_sim::stream(0, "ood-planner-interval", 0);
    let mut shares: Vec<f64> = (0..INTERVAL_REPS)
        .map(|_| {
            let (mut v, mut b) = (0u64, 0u64);
            for _ in 0..n {
                let (ev, eb) = per_episode[rng.random_range(0..n)];
                (v, b) = (v + ev, b + eb);
            }
            b as f64 / v.max(1) as f64
        })
        .collect();
    fishprobe_stats::sample::percentile_ci(&mut shares, 0.95)
}

fn main() -> Result<(), Box<dyn std::error::Error>> {
    let args: Vec<String> = std::env::args().skip(1).collect();
    let episodes: u64 = args.first().map_or(Ok(20), |s| s.parse())?;
    let thr: f32 = args.get(1).map_or(Ok(1.28), |s| s.parse())?;
    let model = ModelSpec::by_name(args.get(2).map_or("ConvNet", String::as_str))?;
    let frames: u32 = args.get(7).map_or(Ok(25), |s| s.parse())?;
    let mut cfg = EnvConfig {
        frames_per_action: frames,
        ..EnvConfig::default()
    };
    // Decisions per second: the horizon and the episode are given in seconds.
    let per_second = cfg.frame_rate_hz / frames as f32;
    let in_decisions = |seconds: u32| ((seconds as f32 * per_second).round() as u32).max(1);
    let plan = Plan {
        horizon: in_decisions(args.get(3).map_or(Ok(4), |s| s.parse())?) as usize,
        turns: args.get(4).map_or(Ok(12), |s| s.parse())?,
        futures: args.get(5).map_or(Ok(2), |s| s.parse())?,
        lead: args.get(8).map_or(Ok(1.2), |s| s.parse())?,
    };
    let support: Arc<dyn InputSupport> = Arc::new(model.support()?);
    let seconds: u32 = args
        .get(6)
        .map_or(Ok(cfg.task.training_episode_actions), |s| s.parse())?;
    cfg.task.training_episode_actions = in_decisions(seconds);
    cfg.task.objective = Objective::Ood;
    cfg.task.ood_score_every_frames = 1;
    // The imagined reward counts views at or beyond the threshold: 1 per view (as a share of
    // the second's views), a view 0.01 short of it a part.
    cfg.task.ood_score_cap = thr;
    cfg.task.ood_score_floor = (thr - 0.01).max(0.0);
    cfg.task.ood_weight = 100.0;
    cfg.validate()?;
    let candidates: Vec<f32> = (0..plan.turns)
        .map(|i| -std::f32::consts::PI + i as f32 * std::f32::consts::TAU / plan.turns as f32)
        .collect();
    for planner in [false, true] {
        let started = std::time::Instant::now();
        let per_episode = (0..episodes)
            .into_par_iter()
            .map(|ep| -> Result<(u64, u64), String> {
                // Each episode counts its own views, for the interval over episodes.
                let counting = Arc::new(Counting::new(support.clone(), thr));
                let mut env = TankEnv::new(cfg.clone(), model.build().map_err(|e| e.to_string())?)
                    .map_err(|e| e.to_string())?;
                env.set_support(Some(support.clone()));
                let mut obs = vec![0.0; env.observation_space().dim()];
                let mut scratch = obs.clone();
                env.reset(Some(derive_seed(0, "ood-scripted", ep)), &mut obs)
                    .map_err(|e| e.to_string())?;
                for second in 0u64.. {
                    let base = orbit(&env, plan.lead);
                    let action = if planner {
                        let seed = derive_seed(ep, "ood-planner", second);
                        let mut best = (imagine(&env, base, &plan, seed, &mut scratch), base);
                        for &c in &candidates {
                            let v = imagine(&env, c, &plan, seed, &mut scratch);
                            if v > best.0 {
                                best = (v, c);
                            }
                        }
                        best.1
                    } else {
                        base
                    };
                    // Only the episode's own steps are counted.
                    env.set_support(Some(counting.clone()));
                    let t = env.step(&[action], &mut obs).map_err(|e| e.to_string())?;
                    env.set_support(Some(support.clone()));
                    if t.truncated {
                        break;
                    }
                }
                Ok(counting.counts())
            })
            .collect::<Result<Vec<_>, String>>()?;
        let (views, beyond) = per_episode
            .iter()
            .fold((0, 0), |(v, b), &(ev, eb)| (v + ev, b + eb));
        let views = views.max(1);
        let [lo, hi] = interval_over_episodes(&per_episode);
        println!(
            "{:>36}: views >= {thr}: {:.1} % (95 % interval over the {} episodes: {:.1}-{:.1} %; \
             {views} views, {:.0} s)",
            if planner {
                format!(
                    "planner (horizon {} decisions, {} turns, {} futures, {frames} frames each)",
                    plan.horizon, plan.turns, plan.futures
                )
            } else {
                format!("base robot (orbit-cw-12-{})", plan.lead)
            },
            100.0 * beyond as f64 / views as f64,
            per_episode.len(),
            100.0 * lo,
            100.0 * hi,
            started.elapsed().as_secs_f64()
        );
        let each: Vec<String> = per_episode
            .iter()
            .map(|&(v, b)| format!("{:.1}", 100.0 * b as f64 / v.max(1) as f64))
            .collect();
        println!("{:>36}  per episode (%): {}", "", each.join(" "));
    }
    Ok(())
}
