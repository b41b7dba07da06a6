//! An environment checker in the spirit of Gymnasium's `check_env`: every environment and
//! every fish model must pass it (see the contract tests of `fishprobe-models`).

use crate::env::{BoxSpace, Env};
use crate::error::SimError;
use crate::rng::stream;
use rand::RngExt;

/// A violated part of the environment contract.
#[derive(Debug, Clone, PartialEq, thiserror::Error)]
#[error("environment check failed: {0}")]
pub struct CheckFailure(pub String);

impl From<SimError> for CheckFailure {
    fn from(e: SimError) -> Self {
        CheckFailure(format!("unexpected error: {e}"))
    }
}

/// What the checker ran.
#[derive(Debug, Clone, PartialEq, Default)]
pub struct CheckReport {
    /// Steps taken in total.
    pub steps: u64,
}

fn ensure(cond: bool, what: impl FnOnce() -> String) -> Result<(), CheckFailure> {
    if cond {
        Ok(())
    } else {
        Err(CheckFailure(what()))
    }
}

fn check_space(name: &str, s: &BoxSpace) -> Result<(), CheckFailure> {
    ensure(s.dim() > 0 && s.low.len() == s.high.len(), || {
        format!("{name} space has no dimensions or mismatched bounds")
    })?;
    ensure(
        s.low
            .iter()
            .zip(&s.high)
            .all(|(l, h)| l.is_finite() && h.is_finite() && l <= h),
        || format!("{name} space bounds are not finite with low <= high"),
    )
}

/// A uniform random action in the space.
fn random_action(rng: &mut crate::rng::SimRng, space: &BoxSpace) -> Vec<f32> {
    space
        .low
        .iter()
        .zip(&space.high)
        .map(|(l, h)| rng.random_range(*l..=*h))
        .collect()
}

/// One episode with seeded random actions: (observations, rewards) concatenated.
fn rollout<E: Env>(
    env: &mut E,
    seed: u64,
    steps: u32,
) -> Result<(Vec<f32>, Vec<f32>), CheckFailure> {
    let obs_space = env.observation_space().clone();
    let act = env.action_space().clone();
    let mut obs = vec![0.0; obs_space.dim()];
    let mut all_obs = Vec::new();
    let mut rewards = Vec::new();
    env.reset(Some(seed), &mut obs)?;
    ensure(obs_space.contains(&obs), || {
        format!("reset observation outside the space: {obs:?}")
    })?;
    all_obs.extend_from_slice(&obs);
    let mut rng = stream(seed, "checker-actions", 0);
    let max = env.max_episode_steps();
    for t in 0..steps.min(max) {
        let tr = env.step(&random_action(&mut rng, &act), &mut obs)?;
        ensure(obs_space.contains(&obs), || {
            format!("step {t}: observation outside the space")
        })?;
        ensure(tr.reward.is_finite(), || {
            format!("step {t}: reward {} is not finite", tr.reward)
        })?;
        ensure(!tr.terminated, || {
            format!("step {t}: this task never terminates")
        })?;
        let last = t + 1 == max;
        ensure(tr.truncated == last, || {
            format!(
                "step {t}: truncated = {} but the time limit is {max}",
                tr.truncated
            )
        })?;
        all_obs.extend_from_slice(&obs);
        rewards.push(tr.reward);
    }
    Ok((all_obs, rewards))
}

/// Checks spaces, value ranges, the time limit, seeded determinism, that reset really resets,
/// and that bad actions and buffers are rejected without changing the state. Runs at most
/// `max_steps` steps per episode (a full episode when it is at least the time limit).
pub fn check_env<E: Env>(
    env: &mut E,
    seed: u64,
    max_steps: u32,
) -> Result<CheckReport, CheckFailure> {
    check_space("observation", env.observation_space())?;
    check_space("action", env.action_space())?;
    ensure(env.max_episode_steps() > 0, || "time limit is 0".into())?;
    let dim = env.observation_space().dim();
    let adim = env.action_space().dim();
    let mut report = CheckReport::default();

    // Seeded determinism, and reset after play really resets.
    let (o1, r1) = rollout(env, seed, max_steps)?;
    let (o2, r2) = rollout(env, seed, max_steps)?;
    report.steps += 2 * r1.len() as u64;
    ensure(o1 == o2 && r1 == r2, || {
        "same seed, same actions, different episode".into()
    })?;

    // The end of an episode: stepping on must ask for a reset.
    if max_steps >= env.max_episode_steps() {
        let mut obs = vec![0.0; dim];
        let a = vec![0.0; adim];
        ensure(
            matches!(env.step(&a, &mut obs), Err(SimError::NeedsReset)),
            || "step after the time limit did not ask for a reset".into(),
        )?;
    }
    let (o3, _) = rollout(env, seed.wrapping_add(1), 1)?;
    ensure(o3[..dim] != o1[..dim], || {
        "different seeds gave the same start".into()
    })?;

    // Bad input is rejected and leaves the state alone.
    let mut obs = vec![0.0; dim];
    env.reset(Some(seed), &mut obs)?;
    let mut bad = vec![0.0; adim];
    bad[0] = f32::NAN;
    ensure(
        matches!(
            env.step(&bad, &mut obs),
            Err(SimError::NonFiniteAction { .. })
        ),
        || "a NaN action was not rejected".into(),
    )?;
    bad[0] = f32::INFINITY;
    ensure(env.step(&bad, &mut obs).is_err(), || {
        "an infinite action was not rejected".into()
    })?;
    ensure(env.step(&vec![0.0; adim + 1], &mut obs).is_err(), || {
        "an action of the wrong length was not rejected".into()
    })?;
    ensure(
        env.step(&vec![0.0; adim], &mut vec![0.0; dim + 1]).is_err(),
        || "an observation buffer of the wrong length was not rejected".into(),
    )?;
    let (o4, r4) = {
        // Continue the episode as the clean rollout did; must match it step for step.
        let mut rng = stream(seed, "checker-actions", 0);
        let act = env.action_space().clone();
        let mut all = obs.clone();
        let mut rewards = Vec::new();
        for _ in 0..r1.len().min(3) {
            rewards.push(env.step(&random_action(&mut rng, &act), &mut obs)?.reward);
            all.extend_from_slice(&obs);
        }
        (all, rewards)
    };
    report.steps += r4.len() as u64;
    ensure(o4[..] == o1[..o4.len()] && r4[..] == r1[..r4.len()], || {
        "rejected input changed the state".into()
    })?;
    Ok(report)
}
