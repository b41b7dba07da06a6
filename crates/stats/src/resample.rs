//! Resampling: percentile bootstrap, one-sided permutation tests and the two-way cluster
//! bootstrap. Each function takes its RNG; none allocates per replicate.

use crate::error::{check_sample, StatsError};
use crate::sample::median_in_place;
use crate::wasserstein::wasserstein_sorted;
use rand::{Rng, RngExt};

/// Fills `out` with a resample (with replacement) of `x`, sorted.
fn resample_sorted<R: Rng>(x: &[f64], out: &mut [f64], rng: &mut R) {
    for o in out.iter_mut() {
        *o = x[rng.random_range(0..x.len())];
    }
    out.sort_unstable_by(f64::total_cmp);
}

/// Bootstrap distribution of W1 between `a` and `b`: each of `reps` replicates resamples both
/// samples with replacement, independently, at their own sizes.
pub fn bootstrap_wasserstein<R: Rng>(
    a: &[f64],
    b: &[f64],
    reps: usize,
    rng: &mut R,
) -> Result<Vec<f64>, StatsError> {
    check_sample("bootstrap a", a)?;
    check_sample("bootstrap b", b)?;
    let (mut ra, mut rb) = (vec![0.0; a.len()], vec![0.0; b.len()]);
    Ok((0..reps)
        .map(|_| {
            resample_sorted(a, &mut ra, rng);
            resample_sorted(b, &mut rb, rng);
            wasserstein_sorted(&ra, &rb)
        })
        .collect())
}

/// Result of a permutation test.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct PermutationTest {
    /// The observed statistic.
    pub observed: f64,
    /// p = (1 + #{W_perm ≥ W_obs}) / (1 + n).
    pub p: f64,
    /// Permutations drawn.
    pub permutations: usize,
}

/// One-sided permutation test of W1 between `a` and `b`: the pooled labels are shuffled
/// `n` times; p = (1 + #{W_perm ≥ W_obs}) / (1 + n). Ties are counted with a relative
/// tolerance of 1e-12 so that float round-off in equal arrangements does not lower p.
pub fn permutation_test_wasserstein<R: Rng>(
    a: &[f64],
    b: &[f64],
    n: usize,
    rng: &mut R,
) -> Result<PermutationTest, StatsError> {
    check_sample("permutation a", a)?;
    check_sample("permutation b", b)?;
    let (sa, sb) = (crate::sample::sorted(a), crate::sample::sorted(b));
    let observed = wasserstein_sorted(&sa, &sb);
    let threshold = observed - 1e-12 * observed.abs().max(1.0);
    let mut pooled: Vec<f64> = a.iter().chain(b).copied().collect();
    let (mut pa, mut pb) = (vec![0.0; a.len()], vec![0.0; b.len()]);
    let mut count = 0usize;
    for _ in 0..n {
        // Partial Fisher-Yates: the first |a| slots become a uniformly random subset.
        for i in 0..a.len() {
            let j = rng.random_range(i..pooled.len());
            pooled.swap(i, j);
        }
        pa.copy_from_slice(&pooled[..a.len()]);
        pb.copy_from_slice(&pooled[a.len()..]);
        pa.sort_unstable_by(f64::total_cmp);
        pb.sort_unstable_by(f64::total_cmp);
        if wasserstein_sorted(&pa, &pb) >= threshold {
            count += 1;
        }
    }
    Ok(PermutationTest {
        observed,
        p: (1 + count) as f64 / (1 + n) as f64,
        permutations: n,
    })
}

/// Two-way cluster bootstrap of the median of a `rows x cols` matrix (row-major): each
/// replicate resamples rows and columns with replacement and takes the median of the
/// resampled matrix (every chosen row crossed with every chosen column).
pub fn cluster_bootstrap_median<R: Rng>(
    matrix: &[f64],
    rows: usize,
    cols: usize,
    reps: usize,
    rng: &mut R,
) -> Result<Vec<f64>, StatsError> {
    if rows == 0 || cols == 0 || matrix.len() != rows * cols {
        return Err(StatsError::Undefined(format!(
            "cluster bootstrap: {} values for a {rows} x {cols} matrix",
            matrix.len()
        )));
    }
    check_sample("cluster bootstrap matrix", matrix)?;
    let (mut ri, mut ci) = (vec![0usize; rows], vec![0usize; cols]);
    let mut cells = vec![0.0; rows * cols];
    Ok((0..reps)
        .map(|_| {
            ri.iter_mut().for_each(|r| *r = rng.random_range(0..rows));
            ci.iter_mut().for_each(|c| *c = rng.random_range(0..cols));
            let mut k = 0;
            for &r in &ri {
                for &c in &ci {
                    cells[k] = matrix[r * cols + c];
                    k += 1;
                }
            }
            median_in_place(&mut cells)
        })
        .collect())
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::wasserstein::wasserstein;
    use rand::SeedableRng;
    use rand_xoshiro::Xoshiro256PlusPlus;

    #[test]
    fn permutation_p_matches_exact_enumeration_on_tiny_samples() {
        // a = 3 values, b = 3 values: 20 equally likely splits. Exact p = #{W ≥ W_obs} / 20.
        let a = [1.0, 2.0, 6.0];
        let b = [3.0, 7.0, 8.0];
        let pooled: Vec<f64> = a.iter().chain(&b).copied().collect();
        let obs = wasserstein(&a, &b).unwrap();
        let mut ge = 0;
        let mut total = 0;
        for i in 0..6 {
            for j in i + 1..6 {
                for k in j + 1..6 {
                    let x: Vec<f64> = [i, j, k].iter().map(|&t| pooled[t]).collect();
                    let y: Vec<f64> = (0..6)
                        .filter(|t| ![i, j, k].contains(t))
                        .map(|t| pooled[t])
                        .collect();
                    total += 1;
                    if wasserstein(&x, &y).unwrap() >= obs - 1e-12 {
                        ge += 1;
                    }
                }
            }
        }
        let exact = f64::from(ge) / f64::from(total);
        let mut rng = Xoshiro256PlusPlus::seed_from_u64(1);
        let t = permutation_test_wasserstein(&a, &b, 200_000, &mut rng).unwrap();
        assert!((t.p - exact).abs() < 0.005, "{} vs exact {exact}", t.p);
    }

    #[test]
    fn permutation_p_values_are_uniform_under_the_null() {
        let mut rng = Xoshiro256PlusPlus::seed_from_u64(7);
        let mut ps = Vec::new();
        for _ in 0..400 {
            let a: Vec<f64> = (0..12).map(|_| rng.random::<f64>()).collect();
            let b: Vec<f64> = (0..12).map(|_| rng.random::<f64>()).collect();
            ps.push(
                permutation_test_wasserstein(&a, &b, 199, &mut rng)
                    .unwrap()
                    .p,
            );
        }
        // Under the null, P(p ≤ α) ≈ α; binomial s.d. at n = 400 is about 0.015 at α = 0.1.
        for alpha in [0.05, 0.1, 0.25, 0.5] {
            let frac = ps.iter().filter(|&&p| p <= alpha).count() as f64 / ps.len() as f64;
            assert!((frac - alpha).abs() < 0.06, "P(p <= {alpha}) = {frac}");
        }
    }

    #[test]
    fn bootstrap_ci_covers_the_true_distance_about_95_percent() {
        // Two normal samples whose true W1 is the shift, 1.0. Percentile intervals for W are
        // biased upward near 0, so test where the distance is clearly positive.
        let mut rng = Xoshiro256PlusPlus::seed_from_u64(11);
        let normal = |rng: &mut Xoshiro256PlusPlus| {
            let (u1, u2): (f64, f64) = (rng.random::<f64>().max(1e-300), rng.random());
            (-2.0 * u1.ln()).sqrt() * (std::f64::consts::TAU * u2).cos()
        };
        let trials = 300;
        let mut covered = 0;
        for _ in 0..trials {
            let a: Vec<f64> = (0..60).map(|_| normal(&mut rng)).collect();
            let b: Vec<f64> = (0..60).map(|_| normal(&mut rng) + 1.0).collect();
            let mut boot = bootstrap_wasserstein(&a, &b, 400, &mut rng).unwrap();
            let [lo, hi] = crate::sample::percentile_ci(&mut boot, 0.95);
            covered += usize::from(lo <= 1.0 && 1.0 <= hi);
        }
        let rate = covered as f64 / trials as f64;
        assert!((0.88..=0.99).contains(&rate), "coverage {rate}");
    }

    #[test]
    fn cluster_bootstrap_of_a_constant_matrix_is_constant() {
        let mut rng = Xoshiro256PlusPlus::seed_from_u64(3);
        let b = cluster_bootstrap_median(&[2.0; 12], 3, 4, 50, &mut rng).unwrap();
        assert!(b.iter().all(|&v| v == 2.0));
        // Rows 0..3 hold 1, 2, 3: the median of a resample is one of them.
        let m: Vec<f64> = (0..3).flat_map(|r| [f64::from(r + 1); 4]).collect();
        let b = cluster_bootstrap_median(&m, 3, 4, 500, &mut rng).unwrap();
        assert!(b.iter().all(|v| [1.0, 2.0, 3.0].contains(v)));
        assert!(b.contains(&1.0) && b.contains(&3.0));
        assert!(cluster_bootstrap_median(&m, 4, 4, 1, &mut rng).is_err());
    }
}
