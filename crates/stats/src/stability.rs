//! Retraining stability (SPEC §8): is the variation between models large against the
//! variation between policies retrained on the same model?
//!
//! R = σ²_between / σ²_within over per-policy mean goals: σ²_within is the mean over models of
//! the variance of that model's policy means; σ²_between the variance of the model means
//! (each the mean of its policy means); sample variances (n - 1).

use crate::error::StatsError;
use crate::sample::{mean, percentile_ci, variance};
use rand::{Rng, RngExt};

/// R with its bootstrap interval and permutation p-value.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct Stability {
    /// The observed ratio.
    pub r: f64,
    /// 95 % percentile interval from resampling episodes within each policy.
    pub ci: [f64; 2],
    /// p = (1 + #{R_perm ≥ R_obs}) / (1 + n), shuffling policy means across models.
    pub p: f64,
}

/// R from policy means grouped by model (`means[model][policy]`).
pub fn ratio(means: &[Vec<f64>]) -> f64 {
    let within = mean(&means.iter().map(|m| variance(m)).collect::<Vec<_>>());
    let between = variance(&means.iter().map(|m| mean(m)).collect::<Vec<_>>());
    between / within
}

/// R, its bootstrap CI (`boot` replicates resampling each policy's episodes) and its
/// permutation p (`perms` shuffles of policy means across models, group sizes kept).
/// `episodes[model][policy]` holds that policy's per-episode values.
pub fn stability<R: Rng>(
    episodes: &[Vec<Vec<f64>>],
    boot: usize,
    perms: usize,
    rng: &mut R,
) -> Result<Stability, StatsError> {
    if episodes.len() < 2
        || episodes
            .iter()
            .any(|m| m.len() < 2 || m.iter().any(Vec::is_empty))
    {
        return Err(StatsError::Undefined(
            "stability needs at least 2 models with at least 2 policies of at least 1 episode each"
                .into(),
        ));
    }
    let means: Vec<Vec<f64>> = episodes
        .iter()
        .map(|m| m.iter().map(|e| mean(e)).collect())
        .collect();
    let r = ratio(&means);
    if !r.is_finite() {
        return Err(StatsError::Undefined(
            "stability: policies of every model have identical means".into(),
        ));
    }
    let mut boot_r = Vec::with_capacity(boot);
    let mut scratch = means.clone();
    for _ in 0..boot {
        for (m, model) in episodes.iter().enumerate() {
            for (q, e) in model.iter().enumerate() {
                scratch[m][q] = (0..e.len())
                    .map(|_| e[rng.random_range(0..e.len())])
                    .sum::<f64>()
                    / e.len() as f64;
            }
        }
        boot_r.push(ratio(&scratch));
    }
    boot_r.retain(|v| v.is_finite());
    let ci = percentile_ci(&mut boot_r, 0.95);
    let mut flat: Vec<f64> = means.iter().flatten().copied().collect();
    let sizes: Vec<usize> = means.iter().map(Vec::len).collect();
    let mut count = 0usize;
    for _ in 0..perms {
        for i in (1..flat.len()).rev() {
            flat.swap(i, rng.random_range(0..=i));
        }
        let mut start = 0;
        for (m, &s) in sizes.iter().enumerate() {
            scratch[m].copy_from_slice(&flat[start..start + s]);
            start += s;
        }
        if ratio(&scratch) >= r - 1e-12 * r.abs().max(1.0) {
            count += 1;
        }
    }
    Ok(Stability {
        r,
        ci,
        p: (1 + count) as f64 / (1 + perms) as f64,
    })
}

#[cfg(test)]
mod tests {
    use super::*;
    use rand::SeedableRng;

    #[test]
    fn ratio_by_hand() {
        // Model means 2 and 4 (variance 2); within variances 1 and 1 (mean 1): R = 2.
        let means = vec![vec![1.0, 2.0, 3.0], vec![3.0, 4.0, 5.0]];
        assert!((ratio(&means) - 2.0).abs() < 1e-12);
    }

    #[test]
    fn separated_models_are_significant() {
        let mut rng = rand_xoshiro::Xoshiro256PlusPlus::seed_from_u64(5);
        let eps = |base: f64| -> Vec<Vec<f64>> {
            (0..6)
                .map(|q| {
                    (0..20)
                        .map(|e| base + f64::from(q) * 0.1 + f64::from(e % 5) * 0.2)
                        .collect()
                })
                .collect()
        };
        let episodes = vec![eps(10.0), eps(20.0), eps(30.0), eps(40.0)];
        let s = stability(&episodes, 300, 999, &mut rng).unwrap();
        assert!(s.r > 100.0, "{s:?}");
        assert!(s.p < 0.01, "{s:?}");
        assert!(s.ci[0] <= s.r && s.r <= s.ci[1] * 1.5);
        assert!(stability(&episodes[..1], 10, 10, &mut rng).is_err());
    }
}
