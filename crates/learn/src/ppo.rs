//! One PPO iteration, top to bottom: collect a batch from the vector environment, compute
//! advantages, then `num_sgd_iter` epochs of minibatch updates.
//!
//! The loss is RLlib 2.0.1's PPO loss (torch), averaged over the minibatch:
//!
//! ```text
//! -min(r·A, clip(r, 1-ε, 1+ε)·A) + vf_coeff·clamp((V - R)², 0, vf_clip) - ent_coeff·H + kl_coeff·KL(old ‖ new)
//! ```
//!
//! with r the probability ratio, A the standardised GAE advantage and R the GAE value target.
//! The policy and value networks are separate, so each sees only its own terms; they are
//! updated side by side on two threads.

use crate::config::PpoConfig;
use crate::gae::gae;
use crate::policy::{bounded_log_std, to_env_action, GaussianPolicy};
use fishprobe_nn::dist::{
    gaussian_entropy, gaussian_kl, gaussian_kl_grad, gaussian_log_prob, gaussian_log_prob_grad,
};
use fishprobe_nn::{Adam, MlpWorkspace};
use fishprobe_sim::{SimError, SimRng, VecEnv};
use rand::RngExt;
use rand_distr::{Distribution, StandardNormal};

/// A collected batch, time-major (`index = t · n_envs + env`).
#[derive(Debug, Clone, Default)]
pub struct Rollout {
    /// Environments.
    pub n_envs: usize,
    /// Steps per environment.
    pub steps: usize,
    /// Observation length.
    pub obs_dim: usize,
    /// Observations.
    pub obs: Vec<f32>,
    /// Sampled normalised actions.
    pub actions: Vec<f32>,
    /// Their log-probabilities under the sampling policy.
    pub logp: Vec<f32>,
    /// The sampling policy's means.
    pub mean: Vec<f32>,
    /// The sampling policy's log-s.d.
    pub log_std: Vec<f32>,
    /// V of each observation.
    pub values: Vec<f32>,
    /// Rewards (plus γ·V(last observation) at a truncation when bootstrapping).
    pub rewards: Vec<f32>,
    /// Whether the episode ended at this step.
    pub dones: Vec<bool>,
    /// V of the observations after the last step.
    pub last_values: Vec<f32>,
    /// GAE advantages.
    pub advantages: Vec<f32>,
    /// GAE value targets.
    pub returns: Vec<f32>,
}

/// Episodes that ended during collection: (return, goals reached).
pub type Finished = Vec<(f32, u32)>;

impl Rollout {
    /// Buffers for `steps x n_envs` transitions.
    pub fn new(n_envs: usize, steps: usize, obs_dim: usize) -> Self {
        let n = n_envs * steps;
        Self {
            n_envs,
            steps,
            obs_dim,
            obs: vec![0.0; n * obs_dim],
            actions: vec![0.0; n],
            logp: vec![0.0; n],
            mean: vec![0.0; n],
            log_std: vec![0.0; n],
            values: vec![0.0; n],
            rewards: vec![0.0; n],
            dones: vec![false; n],
            last_values: vec![0.0; n_envs],
            advantages: vec![0.0; n],
            returns: vec![0.0; n],
        }
    }

    /// Number of transitions.
    pub fn len(&self) -> usize {
        self.n_envs * self.steps
    }

    /// Whether it holds no transitions.
    pub fn is_empty(&self) -> bool {
        self.len() == 0
    }
}

/// Scratch space reused across iterations.
#[derive(Debug, Default)]
pub struct Scratch {
    ws_pi: MlpWorkspace,
    ws_vf: MlpWorkspace,
    env_actions: Vec<f32>,
    final_rows: Vec<f32>,
    truncated: Vec<usize>,
    idx: Vec<usize>,
    /// The minibatch's observations, one copy per network: each thread gathers its own, so
    /// the gather runs in parallel instead of before the two threads start.
    mb_obs_pi: Vec<f32>,
    mb_obs_vf: Vec<f32>,
    grads_pi: Vec<f32>,
    grads_vf: Vec<f32>,
    dy_pi: Vec<f32>,
    dy_vf: Vec<f32>,
}

/// Fills `roll` with one batch; returns the episodes that ended.
pub fn collect(
    cfg: &PpoConfig,
    venv: &mut VecEnv,
    policy: &GaussianPolicy,
    roll: &mut Rollout,
    rng: &mut SimRng,
    s: &mut Scratch,
) -> Result<Finished, SimError> {
    let (n, d) = (roll.n_envs, roll.obs_dim);
    s.env_actions.resize(n, 0.0);
    let mut finished = Vec::new();
    for t in 0..roll.steps {
        let base = t * n;
        roll.obs[base * d..(base + n) * d].copy_from_slice(venv.observations());
        let obs = &roll.obs[base * d..(base + n) * d];
        let (pi, vf) = (&policy.pi, &policy.vf);
        let (ws_pi, ws_vf) = (&mut s.ws_pi, &mut s.ws_vf);
        let (out, v) = rayon::join(|| pi.forward(obs, n, ws_pi), || vf.forward(obs, n, ws_vf));
        roll.values[base..base + n].copy_from_slice(v);
        for i in 0..n {
            let (mean, log_std) = (out[2 * i], policy.log_std(out[2 * i + 1]));
            let z: f32 = StandardNormal.sample(rng);
            let a = mean + log_std.exp() * z;
            roll.mean[base + i] = mean;
            roll.log_std[base + i] = log_std;
            roll.actions[base + i] = a;
            roll.logp[base + i] = gaussian_log_prob(a, mean, log_std);
            s.env_actions[i] = to_env_action(a);
        }
        venv.step(&s.env_actions)?;
        for (i, tr) in venv.transitions().iter().enumerate() {
            roll.rewards[base + i] = tr.reward;
            roll.dones[base + i] = tr.terminated || tr.truncated;
        }
        for e in venv.finished_episodes().iter().flatten() {
            finished.push((e.episode_return, e.goal_events.len() as u32));
        }
        if cfg.bootstrap_truncated {
            bootstrap_truncations(cfg, venv, policy, roll, base, s);
        }
    }
    let last = policy.vf.forward(venv.observations(), n, &mut s.ws_vf);
    roll.last_values.copy_from_slice(last);
    gae(
        &roll.rewards,
        &roll.values,
        &roll.dones,
        &roll.last_values,
        n,
        cfg.gamma,
        cfg.lambda,
        &mut roll.advantages,
        &mut roll.returns,
    );
    Ok(finished)
}

/// At a time limit the episode is cut, not ended: add γ·V(its last observation).
fn bootstrap_truncations(
    cfg: &PpoConfig,
    venv: &VecEnv,
    policy: &GaussianPolicy,
    roll: &mut Rollout,
    base: usize,
    s: &mut Scratch,
) {
    let d = roll.obs_dim;
    s.truncated.clear();
    s.truncated.extend(
        venv.transitions()
            .iter()
            .enumerate()
            .filter(|(_, t)| t.truncated && !t.terminated)
            .map(|(i, _)| i),
    );
    if s.truncated.is_empty() {
        return;
    }
    s.final_rows.clear();
    for &i in &s.truncated {
        s.final_rows
            .extend_from_slice(&venv.final_observations()[i * d..(i + 1) * d]);
    }
    let v = policy
        .vf
        .forward(&s.final_rows, s.truncated.len(), &mut s.ws_vf);
    for (k, &i) in s.truncated.iter().enumerate() {
        roll.rewards[base + i] += cfg.gamma * v[k];
    }
}

/// Averages over an update.
#[derive(Debug, Clone, Copy, Default, PartialEq, serde::Serialize)]
pub struct UpdateStats {
    /// Mean surrogate loss term (-min(r·A, clip(r)·A)).
    pub policy_loss: f32,
    /// Mean clamped squared value error.
    pub vf_loss: f32,
    /// Mean KL(old ‖ new) over the last epoch.
    pub kl: f32,
    /// Mean policy entropy.
    pub entropy: f32,
    /// Fraction of samples whose probability ratio left [1-ε, 1+ε] in the last epoch.
    pub clip_frac: f32,
    /// Fraction of the batch's sampled actions outside [-1, 1] (clipped to ±π in the tank).
    pub action_clip_frac: f32,
    /// Explained variance of the value targets by the value predictions made while sampling
    /// (RLlib's `vf_explained_var`: 1 - Var(R - V) / Var(R), at least -1).
    pub vf_explained_var: f32,
    /// The same on the batch it was trained on, during the last epoch: 1 - mean (V - R)² /
    /// Var(R), at least -1. Far above `vf_explained_var` (of the next batch), the value
    /// network fits each batch more closely than it generalises.
    pub vf_explained_var_fit: f32,
}

/// Sums of one minibatch's policy terms: (surrogate loss, KL, entropy, ratios outside the clip
/// range).
type PiSums = (f64, f64, f64, usize);

/// RLlib's explained variance: max(-1, 1 - Var(y - pred) / Var(y)); 0 when y is constant.
pub fn explained_variance(y: &[f32], pred: &[f32]) -> f32 {
    let (_, var_y) = mean_var(y);
    if var_y <= 0.0 {
        return 0.0;
    }
    let n = y.len().max(1) as f64;
    let diff = |(&a, &b): (&f32, &f32)| f64::from(a) - f64::from(b);
    let mean_d = y.iter().zip(pred).map(diff).sum::<f64>() / n;
    let var_d = y
        .iter()
        .zip(pred)
        .map(|p| (diff(p) - mean_d).powi(2))
        .sum::<f64>()
        / n;
    (1.0 - var_d / var_y).max(-1.0) as f32
}

/// Mean and population variance (divisor n), in f64.
fn mean_var(y: &[f32]) -> (f64, f64) {
    let n = y.len().max(1) as f64;
    let mean = y.iter().map(|&v| f64::from(v)).sum::<f64>() / n;
    let var = y
        .iter()
        .map(|&v| (f64::from(v) - mean).powi(2))
        .sum::<f64>()
        / n;
    (mean, var)
}

/// `num_sgd_iter` epochs of minibatch updates over `roll`.
#[allow(clippy::too_many_arguments)]
pub fn update(
    cfg: &PpoConfig,
    policy: &mut GaussianPolicy,
    adam_pi: &mut Adam,
    adam_vf: &mut Adam,
    kl_coeff: f32,
    roll: &mut Rollout,
    rng: &mut SimRng,
    s: &mut Scratch,
) -> Result<UpdateStats, crate::LearnError> {
    let (n, d, m) = (roll.len(), roll.obs_dim, cfg.sgd_minibatch_size);
    let vf_explained_var = explained_variance(&roll.returns, &roll.values);
    let action_clip_frac =
        roll.actions.iter().filter(|a| a.abs() > 1.0).count() as f32 / n.max(1) as f32;
    if cfg.standardize_advantages {
        let (mean, var) = mean_var(&roll.advantages);
        let sd = var.sqrt().max(1e-8);
        roll.advantages
            .iter_mut()
            .for_each(|a| *a = ((f64::from(*a) - mean) / sd) as f32);
    }
    s.idx.clear();
    s.idx.extend(0..n);
    s.mb_obs_pi.resize(m * d, 0.0);
    s.mb_obs_vf.resize(m * d, 0.0);
    s.grads_pi.resize(policy.pi.num_params(), 0.0);
    s.grads_vf.resize(policy.vf.num_params(), 0.0);
    s.dy_pi.resize(2 * m, 0.0);
    s.dy_vf.resize(m, 0.0);
    let (mut stats, mut batches) = (UpdateStats::default(), 0usize);
    let (mut last_kl, mut last_batches, mut last_clipped) = (0.0f64, 0usize, 0usize);
    let mut last_sq_err = 0.0f64;
    let log_std_max = policy.log_std_max;
    for epoch in 0..cfg.num_sgd_iter {
        // Shuffle (Fisher-Yates), then full minibatches; a remainder smaller than a minibatch
        // is dropped this epoch (it is shuffled into others).
        for i in (1..n).rev() {
            s.idx.swap(i, rng.random_range(0..=i));
        }
        for chunk in s.idx.chunks_exact(m) {
            let (pi_part, vf_part) = (
                (
                    &mut policy.pi,
                    &mut *adam_pi,
                    &mut s.ws_pi,
                    &mut s.mb_obs_pi,
                    &mut s.grads_pi,
                    &mut s.dy_pi,
                ),
                (
                    &mut policy.vf,
                    &mut *adam_vf,
                    &mut s.ws_vf,
                    &mut s.mb_obs_vf,
                    &mut s.grads_vf,
                    &mut s.dy_vf,
                ),
            );
            let roll_ref = &*roll;
            let (pi_sums, (vf_sum, vf_sq_err)) = rayon::join(
                || policy_step(cfg, kl_coeff, log_std_max, roll_ref, chunk, pi_part),
                || value_step(cfg, roll_ref, chunk, vf_part),
            );
            let (surr, kl, ent, clipped) = pi_sums;
            if !(surr.is_finite() && kl.is_finite() && vf_sum.is_finite()) {
                return Err(crate::LearnError::NonFiniteLoss {
                    surrogate: surr,
                    kl,
                    value: vf_sum,
                });
            }
            stats.policy_loss += (surr / m as f64) as f32;
            stats.vf_loss += (vf_sum / m as f64) as f32;
            stats.entropy += (ent / m as f64) as f32;
            batches += 1;
            if epoch + 1 == cfg.num_sgd_iter {
                last_kl += kl / m as f64;
                last_batches += 1;
                last_clipped += clipped;
                last_sq_err += vf_sq_err;
            }
        }
    }
    let b = batches.max(1) as f32;
    stats.policy_loss /= b;
    stats.vf_loss /= b;
    stats.entropy /= b;
    stats.kl = (last_kl / last_batches.max(1) as f64) as f32;
    stats.clip_frac = last_clipped as f32 / (last_batches * m).max(1) as f32;
    stats.action_clip_frac = action_clip_frac;
    stats.vf_explained_var = vf_explained_var;
    let (_, ret_var) = mean_var(&roll.returns);
    stats.vf_explained_var_fit = if ret_var > 0.0 {
        (1.0 - last_sq_err / (last_batches * m).max(1) as f64 / ret_var).max(-1.0) as f32
    } else {
        0.0
    };
    Ok(stats)
}

type NetPart<'a> = (
    &'a mut fishprobe_nn::Mlp,
    &'a mut Adam,
    &'a mut MlpWorkspace,
    &'a mut Vec<f32>,
    &'a mut Vec<f32>,
    &'a mut Vec<f32>,
);

/// Copies the rows' observations into `obs` (the minibatch, in row order).
fn gather(roll: &Rollout, rows: &[usize], obs: &mut [f32]) {
    let d = roll.obs_dim;
    for (row, &k) in obs.chunks_exact_mut(d).zip(rows) {
        row.copy_from_slice(&roll.obs[k * d..(k + 1) * d]);
    }
}

/// Policy-network step on one minibatch; returns the sums of its terms.
fn policy_step(
    cfg: &PpoConfig,
    kl_coeff: f32,
    log_std_max: Option<f32>,
    roll: &Rollout,
    rows: &[usize],
    part: NetPart<'_>,
) -> PiSums {
    let (net, adam, ws, obs, grads, dy) = part;
    let m = rows.len();
    gather(roll, rows, obs);
    let inv_m = 1.0 / m as f32;
    let (lo, hi) = (1.0 - cfg.clip_param, 1.0 + cfg.clip_param);
    let out = net.forward(obs, m, ws);
    let (mut surr_sum, mut kl_sum, mut ent_sum, mut clipped) = (0.0f64, 0.0f64, 0.0f64, 0usize);
    for (j, &k) in rows.iter().enumerate() {
        let (mean, raw_log_std) = (out[2 * j], out[2 * j + 1]);
        let log_std = bounded_log_std(raw_log_std, log_std_max);
        let a = roll.actions[k];
        let adv = roll.advantages[k];
        let ratio = (gaussian_log_prob(a, mean, log_std) - roll.logp[k]).exp();
        let (s1, s2) = (ratio * adv, ratio.clamp(lo, hi) * adv);
        clipped += usize::from(!(lo..=hi).contains(&ratio));
        surr_sum -= f64::from(s1.min(s2));
        let kl = gaussian_kl(roll.mean[k], roll.log_std[k], mean, log_std);
        kl_sum += f64::from(kl);
        ent_sum += f64::from(gaussian_entropy(log_std));
        // d(-min)/d logp: the unclipped term carries the gradient when it is the minimum
        // (inside the clip range both are equal).
        let d_logp = if s1 <= s2 { -adv * ratio } else { 0.0 };
        let (lp_m, lp_s) = gaussian_log_prob_grad(a, mean, log_std);
        let (kl_m, kl_s) = gaussian_kl_grad(roll.mean[k], roll.log_std[k], mean, log_std);
        dy[2 * j] = (d_logp * lp_m + kl_coeff * kl_m) * inv_m;
        let d_log_std = (d_logp * lp_s + kl_coeff * kl_s - cfg.entropy_coeff) * inv_m;
        dy[2 * j + 1] = above_bound_gradient(raw_log_std, log_std, d_log_std);
    }
    grads.fill(0.0);
    net.backward(obs, m, &dy[..2 * m], ws, grads, None);
    adam.step(net.params_mut(), grads);
    (surr_sum, kl_sum, ent_sum, clipped)
}

/// The gradient that reaches the network's raw log-s.d. output, given the gradient `d` of the
/// loss with respect to the bounded log-s.d. Below the bound they are the same. Above it the
/// bounded log-s.d. is constant, and a plain clamp would pass nothing: a raw output that crossed
/// the bound could never come back, and the policy would keep its widest Gaussian for the rest
/// of training (it happened: `fishprobe train --model Zone --seed 0` spent all 813 iterations at
/// entropy 1.4189, σ = π rad, and reached 0.2 goals per training episode; docs/validation.md,
/// "What did not work"). So a gradient that would lower the log-s.d. passes
/// (gradient descent lowers the output when `d > 0`), one that would raise it further does not:
/// the bound caps the Gaussian's width and never holds it there.
#[inline]
fn above_bound_gradient(raw_log_std: f32, log_std: f32, d: f32) -> f32 {
    if raw_log_std > log_std {
        d.max(0.0)
    } else {
        d
    }
}

/// Value-network step on one minibatch; returns the sums of the clamped (loss) and of the
/// plain squared errors.
fn value_step(cfg: &PpoConfig, roll: &Rollout, rows: &[usize], part: NetPart<'_>) -> (f64, f64) {
    let (net, adam, ws, obs, grads, dy) = part;
    let m = rows.len();
    gather(roll, rows, obs);
    let out = net.forward(obs, m, ws);
    let (mut sum, mut sum_sq) = (0.0f64, 0.0f64);
    for (j, &k) in rows.iter().enumerate() {
        let err = out[j] - roll.returns[k];
        let sq = err * err;
        sum += f64::from(sq.min(cfg.vf_clip_param));
        sum_sq += f64::from(sq);
        // The clamp is flat above vf_clip_param: no gradient there.
        dy[j] = if sq < cfg.vf_clip_param {
            2.0 * err * cfg.vf_loss_coeff / m as f32
        } else {
            0.0
        };
    }
    grads.fill(0.0);
    net.backward(obs, m, &dy[..m], ws, grads, None);
    adam.step(net.params_mut(), grads);
    (sum * f64::from(cfg.vf_loss_coeff), sum_sq)
}

/// RLlib's adaptive KL coefficient.
pub fn adapt_kl(kl_coeff: f32, kl: f32, target: f32) -> f32 {
    if kl > 2.0 * target {
        kl_coeff * 1.5
    } else if kl < 0.5 * target {
        kl_coeff * 0.5
    } else {
        kl_coeff
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn explained_variance_known_answers() {
        let y = [1.0, 2.0, 3.0, 4.0];
        // Var(y) = 1.25; residuals (0, 0, 0, -1) have variance 0.1875: 1 - 0.15.
        assert!((explained_variance(&y, &[1.0, 2.0, 3.0, 5.0]) - 0.85).abs() < 1e-6);
        assert_eq!(explained_variance(&y, &y), 1.0);
        // A constant prediction explains nothing; a wild one is floored at -1 as in RLlib.
        assert!(explained_variance(&y, &[7.0; 4]).abs() < 1e-6);
        assert_eq!(explained_variance(&y, &[40.0, -40.0, 40.0, -40.0]), -1.0);
        assert_eq!(explained_variance(&[2.0; 3], &[1.0, 2.0, 3.0]), 0.0);
    }

    /// With the log-s.d. above its bound the policy step passes only the gradient that lowers
    /// it (never one that would widen the Gaussian further), and the bounded distribution is
    /// the one the rollout sampled from (ratio 1 before any step).
    #[test]
    fn above_the_bound_only_a_gradient_that_lowers_the_log_std_passes() {
        use fishprobe_nn::{Activation, Mlp, MlpSpec};
        let spec = MlpSpec {
            sizes: vec![3, 4, 2],
            hidden: Activation::Tanh,
        };
        let mut params: Vec<f32> = (0..spec.sizes.windows(2).map(|w| w[0] * w[1] + w[1]).sum())
            .map(|i| ((i * 37 % 11) as f32 - 5.0) / 10.0)
            .collect();
        // Output layer: the log-s.d. column's weights 0 and its bias 0.5, above a bound of 0.
        let n = params.len();
        for i in 0..4 {
            params[n - 10 + 2 * i + 1] = 0.0;
        }
        params[n - 1] = 0.5;
        let rows = 8;
        for (bound, sd) in [(Some(0.0f32), 1.0f32), (None, 0.5f32.exp())] {
            let mut net = Mlp::from_params(spec.clone(), params.clone()).unwrap();
            let mut roll = Rollout::new(rows, 1, 3);
            let mut ws = MlpWorkspace::default();
            roll.obs
                .iter_mut()
                .enumerate()
                .for_each(|(i, o)| *o = (i as f32 * 0.7).sin());
            let out = net.forward(&roll.obs, rows, &mut ws).to_vec();
            for k in 0..rows {
                let (mean, ls) = (out[2 * k], bounded_log_std(out[2 * k + 1], bound));
                assert!((ls.exp() - sd).abs() < 1e-6);
                roll.actions[k] = mean + sd * if k % 2 == 0 { 0.8 } else { -1.3 };
                roll.mean[k] = mean;
                roll.log_std[k] = ls;
                roll.logp[k] = gaussian_log_prob(roll.actions[k], mean, ls);
                roll.advantages[k] = k as f32 - 2.0;
            }
            let mut adam = Adam::new(net.num_params(), 1e-3);
            let (mut obs, mut grads, mut dy) =
                (vec![0.0; rows * 3], vec![0.0; n], vec![0.0; 2 * rows]);
            let idx: Vec<usize> = (0..rows).collect();
            let cfg = PpoConfig::default();
            let (surr, kl, _, clipped) = policy_step(
                &cfg,
                0.2,
                bound,
                &roll,
                &idx,
                (&mut net, &mut adam, &mut ws, &mut obs, &mut grads, &mut dy),
            );
            // Ratio 1 everywhere: the surrogate is minus the sum of the advantages (12).
            assert!(
                (surr + 12.0).abs() < 1e-4 && kl.abs() < 1e-9 && clipped == 0,
                "{surr} {kl} {clipped}"
            );
            // By hand: ratio 1 and equal distributions (KL gradient 0), so the loss's gradient
            // in the log-s.d. is -adv · (z² - 1) / rows with z the action's standard score.
            for (k, g) in dy.iter().skip(1).step_by(2).enumerate() {
                let z: f32 = if k % 2 == 0 { 0.8 } else { -1.3 };
                let d = -(k as f32 - 2.0) * (z * z - 1.0) / rows as f32;
                let want = if bound.is_some() { d.max(0.0) } else { d };
                assert!((g - want).abs() < 1e-5, "row {k}: {g} vs {want}");
            }
            // Above the bound both kinds occur here: rows whose gradient would widen the
            // Gaussian (blocked) and rows whose gradient narrows it (passed).
            let passed = dy.iter().skip(1).step_by(2).filter(|g| **g > 1e-4).count();
            assert!(passed > 0 && passed < rows, "{passed}");
            assert!(dy.iter().step_by(2).any(|&g| g.abs() > 1e-4));
        }
    }

    #[test]
    fn adaptive_kl_follows_rllib() {
        let close = |a: f32, b: f32| (a - b).abs() < 1e-6;
        assert!(close(adapt_kl(0.2, 0.03, 0.01), 0.3));
        assert!(close(adapt_kl(0.2, 0.004, 0.01), 0.1));
        assert!(close(adapt_kl(0.2, 0.01, 0.01), 0.2));
    }
}
