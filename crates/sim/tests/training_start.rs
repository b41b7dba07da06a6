//! Where training episodes start (the fidelity sweep): `lab` puts the robot near the
//! centre and each fish in a corner, as a live trial after habituation; evaluation episodes
//! start at random poses whatever the setting.

#![allow(clippy::unwrap_used)] // a failure is a test failure

use fishprobe_sim::{Env, EnvConfig, TankEnv, TaskMode, TrainingStart};
use std::sync::Arc;

mod common;
use common::Still;

fn starts(mode: TaskMode, start: TrainingStart, fish: u32) -> Vec<([f32; 2], Vec<[f32; 2]>)> {
    let mut cfg = EnvConfig {
        mode,
        fish_count: fish,
        ..EnvConfig::default()
    };
    cfg.task.training_start = start;
    let mut e = TankEnv::new(cfg, Arc::new(Still)).unwrap();
    let mut obs = vec![0.0; e.observation_space().dim()];
    (0..200)
        .map(|i| {
            e.reset(if i == 0 { Some(7) } else { None }, &mut obs)
                .unwrap();
            let r = e.robot().state;
            let f = e.fish().iter().map(|f| [f.x, f.y]).collect();
            ([r.x, r.y], f)
        })
        .collect()
}

#[test]
fn lab_starts_put_the_robot_in_the_centre_and_the_fish_in_corners() {
    // Defaults: spread 10 cm, start clearance 5 cm, so a fish lies 35-45 cm out on both axes.
    let s = starts(TaskMode::Training, TrainingStart::Lab, 3);
    let mut corners = std::collections::BTreeSet::new();
    for (robot, fish) in &s {
        assert!(
            robot[0].abs() <= 5.0 && robot[1].abs() <= 5.0,
            "robot {robot:?}"
        );
        for f in fish {
            for c in f {
                assert!((35.0..=45.0).contains(&c.abs()), "fish {f:?}");
            }
            corners.insert((f[0] > 0.0, f[1] > 0.0));
        }
    }
    assert_eq!(corners.len(), 4, "every corner is used");
}

#[test]
fn evaluation_and_the_default_start_anywhere() {
    for (mode, start) in [
        (TaskMode::Evaluation, TrainingStart::Lab),
        (TaskMode::Training, TrainingStart::Random),
    ] {
        let s = starts(mode, start, 1);
        let central = s.iter().filter(|(_, f)| f[0][0].abs() < 30.0).count();
        assert!(
            central > 80,
            "{mode:?}/{start:?}: {central} of 200 fish starts central"
        );
    }
}

#[test]
fn mixed_starts_draw_lab_starts_at_the_set_share() {
    // A lab start has the robot within 5 cm of the centre on both axes and the fish 35-45 cm
    // out on both; a random start does both with probability (10/90)^2 x (20/90)^2 < 0.1 %.
    let lab_like = |share: f32| {
        let mut cfg = EnvConfig::default();
        cfg.task.training_start = TrainingStart::Mixed;
        cfg.task.lab_start_share = share;
        let mut e = TankEnv::new(cfg, Arc::new(Still)).unwrap();
        let mut obs = vec![0.0; e.observation_space().dim()];
        (0..400)
            .filter(|&i| {
                e.reset(if i == 0 { Some(3) } else { None }, &mut obs)
                    .unwrap();
                let r = e.robot().state;
                let f = e.fish()[0];
                r.x.abs() <= 5.0
                    && r.y.abs() <= 5.0
                    && (35.0..=45.0).contains(&f.x.abs())
                    && (35.0..=45.0).contains(&f.y.abs())
            })
            .count()
    };
    assert_eq!(lab_like(0.0), 0);
    assert_eq!(lab_like(1.0), 400);
    // Binomial(400, 0.25): mean 100, s.d. 8.7.
    let n = lab_like(0.25);
    assert!(
        (70..=130).contains(&n),
        "{n} of 400 lab starts at share 0.25"
    );
    let mut cfg = EnvConfig::default();
    cfg.task.lab_start_share = 1.5;
    assert_eq!(cfg.validate().unwrap_err().field, "task.lab_start_share");
}
