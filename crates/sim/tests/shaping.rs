//! The progress shaping of training episodes (the fidelity sweep, reading
//! `progress-shaping`): each action adds w · (d − γ_s · d′) / L, d and d′ the distance of the
//! fish nearest the goal before and after the action, d′ = 0 when a goal was reached, L the
//! tank's side. Known answers with fish whose motion is known.

#![allow(clippy::unwrap_used)] // a failure is a test failure

use fishprobe_sim::{Env, EnvConfig, FishModel, StartPoses, TankEnv, TaskMode};
use std::sync::Arc;

mod common;
use common::{Still, Straight};

fn env(model: Arc<dyn FishModel>, mode: TaskMode, w: f32, gamma: f32) -> TankEnv {
    let mut cfg = EnvConfig {
        mode,
        ..EnvConfig::default()
    };
    cfg.task.progress_shaping = w;
    cfg.task.progress_shaping_gamma = gamma;
    TankEnv::new(cfg, model).unwrap()
}

fn distance(e: &TankEnv) -> f32 {
    let [gx, gy] = e.active_goal();
    let f = e.fish()[0];
    (f.x - gx).hypot(f.y - gy)
}

/// Robot in the centre (no wall penalty), the fish where given.
fn start(e: &mut TankEnv, fish: [f32; 3], seed: u64) -> Vec<f32> {
    let mut obs = vec![0.0; e.observation_space().dim()];
    e.set_start_poses(Some(StartPoses {
        robot: [0.0, 0.0, 0.0],
        fish: vec![fish],
    }))
    .unwrap();
    e.reset(Some(seed), &mut obs).unwrap();
    obs
}

#[test]
fn a_still_fish_pays_its_discounted_distance() {
    // d′ = d: the shaping is w · d · (1 − γ) / 100 cm, every action.
    let mut e = env(Arc::new(Still), TaskMode::Training, 2.0, 0.5);
    let mut obs = start(&mut e, [30.0, 0.0, 0.0], 3);
    let d = distance(&e);
    for _ in 0..3 {
        let t = e.step(&[0.0], &mut obs).unwrap();
        assert_eq!(t.info.goals_reached, 0);
        assert!(!t.info.robot_near_wall);
        let want = 2.0 * (d - 0.5 * d) / 100.0;
        assert!((t.reward - want).abs() < 1e-5, "{} vs {want}", t.reward);
    }
}

#[test]
fn a_moving_fish_pays_its_progress() {
    // γ = 1: the shaping is the fish's progress toward the goal, w · (d − d′) / 100 cm.
    let mut e = env(Arc::new(Straight(10.0)), TaskMode::Training, 1.5, 1.0);
    let mut obs = start(&mut e, [-40.0, 0.0, 0.0], 5);
    let mut total = 0.0;
    let d_start = distance(&e);
    for _ in 0..2 {
        let d = distance(&e);
        let t = e.step(&[0.0], &mut obs).unwrap();
        assert_eq!(
            t.info.goals_reached, 0,
            "the test needs a goal off the fish's path"
        );
        let want = 1.5 * (d - distance(&e)) / 100.0;
        assert!((t.reward - want).abs() < 1e-5, "{} vs {want}", t.reward);
        total += t.reward;
    }
    // The shaping telescopes: the sum is the whole progress.
    let whole = 1.5 * (d_start - distance(&e)) / 100.0;
    assert!((total - whole).abs() < 1e-5);
}

#[test]
fn a_reached_goal_ends_the_potential_at_zero() {
    // Find the seed's first goal, then start the fish 8 cm before it, swimming at it: the goal
    // is reached within the first action, which pays +1 and w · 8 / 100 cm (d′ = 0), not the
    // distance to the next goal.
    let mut e = env(Arc::new(Straight(10.0)), TaskMode::Training, 1.0, 0.9);
    start(&mut e, [45.0, 45.0, 0.0], 11);
    let [gx, gy] = e.active_goal();
    let mut obs = start(&mut e, [gx - 8.0, gy, 0.0], 11);
    assert_eq!(e.active_goal(), [gx, gy], "same seed, same first goal");
    let t = e.step(&[0.0], &mut obs).unwrap();
    assert_eq!(t.info.goals_reached, 1);
    let want = 1.0 + 8.0 / 100.0 - if t.info.robot_near_wall { 0.1 } else { 0.0 };
    assert!((t.reward - want).abs() < 1e-4, "{} vs {want}", t.reward);
}

#[test]
fn evaluation_and_the_default_have_no_shaping() {
    for (mode, w) in [(TaskMode::Evaluation, 1.0), (TaskMode::Training, 0.0)] {
        let mut e = env(Arc::new(Straight(10.0)), mode, w, 0.9);
        let mut obs = start(&mut e, [-40.0, 0.0, 0.0], 5);
        let t = e.step(&[0.0], &mut obs).unwrap();
        assert_eq!(t.reward, t.info.goals_reached as f32, "{mode:?}");
    }
}

#[test]
fn shaping_settings_out_of_range_are_refused() {
    for (w, g, field) in [
        (-0.1, 0.9, "progress_shaping"),
        (11.0, 0.9, "progress_shaping"),
        (1.0, 0.0, "progress_shaping_gamma"),
        (1.0, 1.5, "progress_shaping_gamma"),
        (f32::NAN, 0.9, "progress_shaping"),
    ] {
        let mut cfg = EnvConfig::default();
        cfg.task.progress_shaping = w;
        cfg.task.progress_shaping_gamma = g;
        let err = cfg.validate().unwrap_err().to_string();
        assert!(err.contains(field), "{err}");
    }
}
