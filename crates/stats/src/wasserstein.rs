//! The 1-Wasserstein distance between two one-dimensional samples: the area between their
//! empirical CDFs, as `scipy.stats.wasserstein_distance(u, v)` (no weights) computes it.

use crate::error::{check_sample, StatsError};

/// W1 between two samples.
pub fn wasserstein(u: &[f64], v: &[f64]) -> Result<f64, StatsError> {
    check_sample("wasserstein u", u)?;
    check_sample("wasserstein v", v)?;
    Ok(wasserstein_sorted(
        &crate::sample::sorted(u),
        &crate::sample::sorted(v),
    ))
}

/// W1 between two samples that are already sorted ascending (finite, non-empty). One merge
/// pass: O(n + m), no allocation.
pub fn wasserstein_sorted(u: &[f64], v: &[f64]) -> f64 {
    let (n, m) = (u.len(), v.len());
    let (inv_n, inv_m) = (1.0 / n as f64, 1.0 / m as f64);
    let (mut i, mut j) = (0usize, 0usize);
    let mut area = 0.0;
    let mut x = u[0].min(v[0]);
    while i < n || j < m {
        // Next breakpoint; the CDFs are constant on [x, next).
        let next = match (u.get(i), v.get(j)) {
            (Some(a), Some(b)) => a.min(*b),
            (Some(a), None) => *a,
            (None, Some(b)) => *b,
            (None, None) => break,
        };
        area += (i as f64 * inv_n - j as f64 * inv_m).abs() * (next - x);
        x = next;
        while i < n && u[i] <= x {
            i += 1;
        }
        while j < m && v[j] <= x {
            j += 1;
        }
    }
    area
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn matches_scipy() {
        // scipy.stats.wasserstein_distance([0, 1, 3, 3, 7.5], [2, 2, 4.5, 10]) = 1.925
        let w = wasserstein(&[0.0, 1.0, 3.0, 3.0, 7.5], &[2.0, 2.0, 4.5, 10.0]).unwrap();
        assert!((w - 1.925).abs() < 1e-12, "{w}");
        // A shift by c gives c; identical samples give 0.
        let a = [1.0, 5.0, 2.0, 9.0];
        let b: Vec<f64> = a.iter().map(|x| x + 2.5).collect();
        assert!((wasserstein(&a, &b).unwrap() - 2.5).abs() < 1e-12);
        assert_eq!(wasserstein(&a, &a).unwrap(), 0.0);
        assert!(wasserstein(&[], &a).is_err());
        assert!(wasserstein(&[f64::NAN], &a).is_err());
    }
}
