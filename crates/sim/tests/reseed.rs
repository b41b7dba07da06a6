//! A planner's imagined futures (`TankEnv::reseed_fish_noise`): a clone of the environment
//! steps as the original does until its fish noise is reseeded, and then draws other noise,
//! the same for the same seed.

#![allow(clippy::unwrap_used)] // a failure is a test failure

use fishprobe_sim::{Env, EnvConfig, FishMind, FishModel, FishMotion, FishView, SimRng, TankEnv};
use rand::RngExt;
use std::sync::Arc;

/// A fish turning by a random angle every frame.
#[derive(Debug)]
struct Wanderer;

impl FishModel for Wanderer {
    fn name(&self) -> &str {
        "Wanderer"
    }
    fn decide(&self, v: &FishView, _: &[f32], _: &mut FishMind, rng: &mut SimRng) -> FishMotion {
        FishMotion {
            heading: v.me.heading + rng.random_range(-0.5..0.5),
            speed: 5.0,
        }
    }
}

/// The fish's path over `seconds` 1-s actions of a zero turn.
fn path(env: &mut TankEnv, seconds: usize) -> Vec<[f32; 2]> {
    let mut obs = vec![0.0; env.observation_space().dim()];
    (0..seconds)
        .map(|_| {
            env.step(&[0.0], &mut obs).unwrap();
            [env.fish()[0].x, env.fish()[0].y]
        })
        .collect()
}

#[test]
fn a_reseeded_clone_draws_its_own_noise() {
    let mut env = TankEnv::new(EnvConfig::default(), Arc::new(Wanderer)).unwrap();
    let mut obs = vec![0.0; env.observation_space().dim()];
    env.reset(Some(3), &mut obs).unwrap();
    path(&mut env, 2);
    let (mut same, mut other, mut again) = (env.clone(), env.clone(), env.clone());
    other.reseed_fish_noise(11);
    again.reseed_fish_noise(11);
    let real = path(&mut env, 5);
    assert_eq!(
        path(&mut same, 5),
        real,
        "a clone replays the episode's noise"
    );
    let imagined = path(&mut other, 5);
    assert_ne!(imagined, real, "a reseeded clone draws other noise");
    assert_eq!(
        path(&mut again, 5),
        imagined,
        "the same seed, the same future"
    );
}
