//! The OOD objective: the reward is the capped mean support score of the fish's
//! views over the action's frames (above a floor), plus the goal reward's share, minus the wall penalty; an
//! OOD environment without a support model refuses to step.

#![allow(clippy::unwrap_used)] // a failure is a test failure

use fishprobe_sim::{Env, EnvConfig, FishView, InputSupport, Objective, SimError, TankEnv, VecEnv};
use std::sync::Arc;

mod common;
use common::{Still, Straight};

/// Scores a view by its fish's x coordinate (cm / 10): a known answer per frame.
#[derive(Debug)]
struct ByX;

impl InputSupport for ByX {
    fn score(&self, v: &FishView) -> f32 {
        v.me.x.abs() / 10.0
    }
}

fn env(objective: Objective) -> TankEnv {
    let mut cfg = EnvConfig::default();
    cfg.task.objective = objective;
    cfg.task.ood_score_cap = 2.5;
    cfg.task.ood_score_floor = 0.0;
    cfg.task.ood_score_every_frames = 1;
    TankEnv::new(cfg, Arc::new(Still)).unwrap()
}

#[test]
fn the_ood_reward_is_the_capped_mean_score_of_the_views() {
    let mut e = env(Objective::Ood);
    let mut obs = vec![0.0; e.observation_space().dim()];
    e.set_start_poses(Some(fishprobe_sim::StartPoses {
        robot: [0.0, 0.0, 0.0],
        fish: vec![[30.0, 0.0, 0.0]],
    }))
    .unwrap();
    e.reset(Some(1), &mut obs).unwrap();
    // Without a support model: refused, naming how to get one.
    let err = e.step(&[0.0], &mut obs).unwrap_err();
    assert!(matches!(err, SimError::NoSupport { .. }), "{err}");
    assert!(err.to_string().contains("fit-convnet"), "{err}");
    e.set_support(Some(Arc::new(ByX)));
    let t = e.step(&[0.0], &mut obs).unwrap();
    // The still fish at x = 30 scores 3 every frame, capped at 2.5; the robot is far from
    // the walls; no goal is reached by a fish that does not move (goals are drawn away from it).
    assert_eq!(t.info.goals_reached, 0);
    assert!((t.info.support_score - 3.0).abs() < 1e-6, "{:?}", t.info);
    assert!((t.reward - 2.5).abs() < 1e-6, "{}", t.reward);
}

#[test]
fn a_score_floor_rewards_only_how_far_a_view_lies_beyond_it() {
    // The still fish at x = 30 scores 3 (capped at 2.5); with the floor at 1 each view is
    // worth 2.5 - 1 = 1.5, at x = 5 (score 0.5, below the floor) nothing.
    for (x, want) in [(30.0, 1.5), (5.0, 0.0)] {
        let mut e = env(Objective::Ood);
        let mut cfg = e.config().clone();
        cfg.task.ood_score_floor = 1.0;
        e = TankEnv::new(cfg, Arc::new(Still)).unwrap();
        e.set_support(Some(Arc::new(ByX)));
        let mut obs = vec![0.0; e.observation_space().dim()];
        e.set_start_poses(Some(fishprobe_sim::StartPoses {
            robot: [0.0, 20.0, 0.0],
            fish: vec![[x, 0.0, 0.0]],
        }))
        .unwrap();
        e.reset(Some(1), &mut obs).unwrap();
        let t = e.step(&[0.0], &mut obs).unwrap();
        assert_eq!(t.info.goals_reached, 0);
        assert!(
            (t.info.support_score - x / 10.0).abs() < 1e-6,
            "{:?}",
            t.info
        );
        assert!((t.reward - want).abs() < 1e-6, "x = {x}: {}", t.reward);
    }
}

#[test]
fn the_goal_task_ignores_the_support_and_evaluation_counts_goals() {
    let mut e = env(Objective::Goal);
    e.set_support(Some(Arc::new(ByX)));
    let mut obs = vec![0.0; e.observation_space().dim()];
    e.reset(Some(1), &mut obs).unwrap();
    let t = e.step(&[0.0], &mut obs).unwrap();
    assert_eq!(t.info.support_score, 0.0);
    assert!(t.reward <= 0.0 || t.info.goals_reached > 0);
    // An OOD configuration evaluates as the lead-to-goal task (no support needed).
    let mut cfg = EnvConfig::default();
    cfg.task.objective = Objective::Ood;
    let eval = cfg.evaluation();
    assert_eq!(eval.task.objective, Objective::Goal);
    let mut e = TankEnv::new(eval, Arc::new(Still)).unwrap();
    e.reset(Some(1), &mut obs).unwrap();
    e.step(&[0.0], &mut obs).unwrap();
}

#[test]
fn the_vector_env_passes_the_support_on_and_settings_are_checked() {
    let mut cfg = EnvConfig::default();
    cfg.task.objective = Objective::Ood;
    let mut v = VecEnv::new(cfg.clone(), Arc::new(Still), 3).unwrap();
    v.reset(0).unwrap();
    assert!(v.step(&[0.0; 3]).is_err());
    v.set_support(Some(Arc::new(ByX)));
    v.reset(0).unwrap();
    v.step(&[0.0; 3]).unwrap();
    for (field, value) in [
        ("task.ood_weight", -1.0),
        ("task.ood_score_cap", 0.0),
        ("task.ood_goal_weight", 11.0),
        ("task.ood_score_every_frames", 0.0),
        ("task.ood_score_floor", 4.0),
        ("task.ood_score_floor", -0.5),
    ] {
        let mut c = cfg.clone();
        match field {
            "task.ood_weight" => c.task.ood_weight = value,
            "task.ood_score_cap" => c.task.ood_score_cap = value,
            "task.ood_score_every_frames" => c.task.ood_score_every_frames = value as u32,
            "task.ood_score_floor" => c.task.ood_score_floor = value,
            _ => c.task.ood_goal_weight = value,
        }
        let e = c.validate().unwrap_err();
        assert_eq!(e.field, field, "{e}");
    }
}

#[test]
fn the_views_are_scored_every_nth_frame() {
    for (every, want) in [(1u32, 1.2f32), (5, 1.0)] {
        let mut cfg = EnvConfig::default();
        cfg.task.objective = Objective::Ood;
        cfg.task.ood_score_every_frames = every;
        let mut e = TankEnv::new(cfg, Arc::new(Straight(25.0))).unwrap();
        e.set_support(Some(Arc::new(ByX)));
        e.set_start_poses(Some(fishprobe_sim::StartPoses {
            robot: [0.0, -30.0, 0.0],
            fish: vec![[0.0, 0.0, 0.0]],
        }))
        .unwrap();
        let mut obs = vec![0.0; e.observation_space().dim()];
        e.reset(Some(1), &mut obs).unwrap();
        let t = e.step(&[0.0], &mut obs).unwrap();
        // Frames 0..24 see the fish at x = 0..24 cm (score x / 10): every frame averages
        // 1.2; every 5th (x = 0, 5, 10, 15, 20) averages 1.0.
        assert!(
            (t.info.support_score - want).abs() < 1e-4,
            "every {every}: {}",
            t.info.support_score
        );
    }
}
