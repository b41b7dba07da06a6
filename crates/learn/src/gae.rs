//! Generalised advantage estimation (Schulman et al. 2016) over a time-major rollout
//! (`index = t * n_envs + env`).

/// Advantages and value targets (returns). `dones[t·n + i]`: the episode of env i ended at
/// step t (no bootstrapping across it); `last_values[i]`: V of env i's observation after the
/// last step.
#[allow(clippy::too_many_arguments)]
pub fn gae(
    rewards: &[f32],
    values: &[f32],
    dones: &[bool],
    last_values: &[f32],
    n_envs: usize,
    gamma: f32,
    lambda: f32,
    advantages: &mut [f32],
    returns: &mut [f32],
) {
    let steps = rewards.len() / n_envs;
    for (i, &last) in last_values.iter().enumerate().take(n_envs) {
        let mut running = 0.0f32;
        for t in (0..steps).rev() {
            let k = t * n_envs + i;
            let next_value = if t + 1 == steps {
                last
            } else {
                values[k + n_envs]
            };
            let nonterminal = if dones[k] { 0.0 } else { 1.0 };
            let delta = rewards[k] + gamma * next_value * nonterminal - values[k];
            running = delta + gamma * lambda * nonterminal * running;
            advantages[k] = running;
            returns[k] = running + values[k];
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn known_answer() {
        // One env, 3 steps, γ = 0.5, λ = 0.5; the episode ends after step 1.
        // r = [1, 0, 2], V = [0.5, 1.0, 0.0], V(after) = 4.
        // δ2 = 2 + 0.5·4 - 0 = 4;               A2 = 4
        // δ1 = 0 + 0 - 1 = -1 (done);            A1 = -1
        // δ0 = 1 + 0.5·1 - 0.5 = 1;              A0 = 1 + 0.25·(-1) = 0.75
        let (mut a, mut r) = ([0.0; 3], [0.0; 3]);
        gae(
            &[1.0, 0.0, 2.0],
            &[0.5, 1.0, 0.0],
            &[false, true, false],
            &[4.0],
            1,
            0.5,
            0.5,
            &mut a,
            &mut r,
        );
        assert_eq!(a, [0.75, -1.0, 4.0]);
        assert_eq!(r, [1.25, 0.0, 4.0]);
        // Two interleaved envs give each env's own answer.
        let (mut a2, mut r2) = ([0.0; 6], [0.0; 6]);
        gae(
            &[1.0, 9.0, 0.0, 9.0, 2.0, 9.0],
            &[0.5, 0.0, 1.0, 0.0, 0.0, 0.0],
            &[false, false, true, false, false, false],
            &[4.0, 0.0],
            2,
            0.5,
            0.5,
            &mut a2,
            &mut r2,
        );
        assert_eq!([a2[0], a2[2], a2[4]], [0.75, -1.0, 4.0]);
        // Env 1: r = 9 each step, V = 0, never done, V(after) = 0, γλ = 0.25:
        // A2 = 9, A1 = 9 + 0.25·9 = 11.25, A0 = 9 + 0.25·11.25 = 11.8125
        assert_eq!([a2[1], a2[3], a2[5]], [11.8125, 11.25, 9.0]);
        // λ = 1, γ = 1: advantages are returns-to-go minus values.
        let (mut a3, mut r3) = ([0.0; 3], [0.0; 3]);
        gae(
            &[1.0, 1.0, 1.0],
            &[0.0; 3],
            &[false; 3],
            &[0.0],
            1,
            1.0,
            1.0,
            &mut a3,
            &mut r3,
        );
        assert_eq!(r3, [3.0, 2.0, 1.0]);
    }
}
