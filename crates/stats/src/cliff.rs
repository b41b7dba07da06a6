//! Cliff's δ = P(x > y) - P(x < y) over all pairs, with the usual magnitude labels (Romano et
//! al. 2006): negligible < 0.147 ≤ small < 0.33 ≤ medium < 0.474 ≤ large.

use crate::error::{check_sample, StatsError};

/// Cliff's δ of x against y. O((n + m) log m): y is sorted once and each x is located by
/// binary search (equal to a direct count over all n·m pairs; tested).
pub fn cliffs_delta(x: &[f64], y: &[f64]) -> Result<f64, StatsError> {
    check_sample("cliffs_delta x", x)?;
    check_sample("cliffs_delta y", y)?;
    let ys = crate::sample::sorted(y);
    let mut more = 0usize;
    let mut less = 0usize;
    for &xi in x {
        let below = ys.partition_point(|&v| v < xi);
        let not_above = ys.partition_point(|&v| v <= xi);
        more += below;
        less += ys.len() - not_above;
    }
    Ok((more as f64 - less as f64) / (x.len() * y.len()) as f64)
}

/// The magnitude label of |δ|.
pub fn magnitude(delta: f64) -> &'static str {
    let d = delta.abs();
    if d < 0.147 {
        "negligible"
    } else if d < 0.33 {
        "small"
    } else if d < 0.474 {
        "medium"
    } else {
        "large"
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    fn direct(x: &[f64], y: &[f64]) -> f64 {
        let mut s = 0i64;
        for a in x {
            for b in y {
                s += i64::from(a > b) - i64::from(a < b);
            }
        }
        s as f64 / (x.len() * y.len()) as f64
    }

    #[test]
    fn equals_the_direct_count() {
        let x = [1.0, 3.0, 3.0, 5.0, 8.0, 2.0];
        let y = [3.0, 4.0, 0.5, 3.0, 9.0];
        // By hand: pairs (x>y) - (x<y) = 12 - 14 over 30.
        assert!((cliffs_delta(&x, &y).unwrap() - direct(&x, &y)).abs() < 1e-15);
        assert!((direct(&x, &y) - (-2.0 / 30.0)).abs() < 1e-15);
        assert_eq!(cliffs_delta(&[5.0, 6.0], &[1.0, 2.0]).unwrap(), 1.0);
        assert_eq!(cliffs_delta(&[1.0], &[1.0]).unwrap(), 0.0);
        assert_eq!(magnitude(0.1), "negligible");
        assert_eq!(magnitude(-0.2), "small");
        assert_eq!(magnitude(0.33), "medium");
        assert_eq!(magnitude(0.474), "large");
    }
}
