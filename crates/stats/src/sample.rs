//! Descriptive statistics.

/// Arithmetic mean (NaN for an empty slice).
pub fn mean(x: &[f64]) -> f64 {
    x.iter().sum::<f64>() / x.len() as f64
}

/// Sample variance with n - 1 in the denominator (NaN below 2 values), like
/// `numpy.var(x, ddof=1)`.
pub fn variance(x: &[f64]) -> f64 {
    if x.len() < 2 {
        return f64::NAN;
    }
    let m = mean(x);
    x.iter().map(|v| (v - m) * (v - m)).sum::<f64>() / (x.len() - 1) as f64
}

/// Sample standard deviation (n - 1).
pub fn sd(x: &[f64]) -> f64 {
    variance(x).sqrt()
}

/// Quantile `p` in [0, 1] of a sorted sample by linear interpolation between order
/// statistics, like `numpy.quantile(x, p)` (method "linear").
pub fn quantile_sorted(sorted: &[f64], p: f64) -> f64 {
    if sorted.is_empty() {
        return f64::NAN;
    }
    let h = p.clamp(0.0, 1.0) * (sorted.len() - 1) as f64;
    let lo = h.floor() as usize;
    let hi = (lo + 1).min(sorted.len() - 1);
    // On an order statistic, or between equal ones, the value itself: also when it is
    // infinite (a bootstrap of a ratio whose denominator can be 0), where interpolating would
    // give NaN.
    if h == lo as f64 || sorted[lo] == sorted[hi] {
        return sorted[lo];
    }
    sorted[lo] + (h - lo as f64) * (sorted[hi] - sorted[lo])
}

/// [`quantile_sorted`] of `x` in any order, by selection (O(n); `x` is reordered): for a
/// quantile of a sample drawn again in every replicate of a bootstrap.
pub fn quantile_in_place(x: &mut [f64], p: f64) -> f64 {
    if x.is_empty() {
        return f64::NAN;
    }
    let h = p.clamp(0.0, 1.0) * (x.len() - 1) as f64;
    let lo = h.floor() as usize;
    let (_, &mut at, above) = x.select_nth_unstable_by(lo, f64::total_cmp);
    match above.iter().copied().min_by(f64::total_cmp) {
        Some(next) if h > lo as f64 => at + (h - lo as f64) * (next - at),
        _ => at,
    }
}

/// Sorts a copy (NaN last).
pub fn sorted(x: &[f64]) -> Vec<f64> {
    let mut v = x.to_vec();
    v.sort_by(f64::total_cmp);
    v
}

/// Median, like `numpy.median` (mean of the two middle values for even n). Reorders `x`.
pub fn median_in_place(x: &mut [f64]) -> f64 {
    let n = x.len();
    if n == 0 {
        return f64::NAN;
    }
    let (_, m, _) = x.select_nth_unstable_by(n / 2, f64::total_cmp);
    let upper = *m;
    if n % 2 == 1 {
        return upper;
    }
    let lower = x[..n / 2].iter().copied().fold(f64::NEG_INFINITY, f64::max);
    0.5 * (lower + upper)
}

/// Median of a slice (copies).
pub fn median(x: &[f64]) -> f64 {
    median_in_place(&mut x.to_vec())
}

/// The 95 % percentile interval [2.5 %, 97.5 %] of a bootstrap distribution (sorted in
/// place), like `numpy.percentile(b, [2.5, 97.5])`.
pub fn percentile_ci(boot: &mut [f64], level: f64) -> [f64; 2] {
    boot.sort_by(f64::total_cmp);
    let a = (1.0 - level) / 2.0;
    [quantile_sorted(boot, a), quantile_sorted(boot, 1.0 - a)]
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn quantiles_reach_infinity_without_nan() {
        let x = [1.0, 2.0, f64::INFINITY, f64::INFINITY];
        assert_eq!(quantile_sorted(&x, 1.0), f64::INFINITY);
        assert_eq!(quantile_sorted(&x, 0.9), f64::INFINITY);
        assert_eq!(quantile_sorted(&x, 0.5), f64::INFINITY);
        assert_eq!(quantile_sorted(&x, 0.25), 1.75);
    }

    #[test]
    fn a_quantile_by_selection_is_the_sorted_ones() {
        // numpy.quantile([4, 1, 3, 2, 10], [0, .25, .5, .95, 1]) = 1, 2, 3, 8.8, 10
        let x = [4.0, 1.0, 3.0, 2.0, 10.0];
        for (p, want) in [
            (0.0, 1.0),
            (0.25, 2.0),
            (0.5, 3.0),
            (0.95, 8.8),
            (1.0, 10.0),
        ] {
            let got = quantile_in_place(&mut x.clone(), p);
            assert!((got - want).abs() < 1e-12, "{p}: {got}");
            assert_eq!(got, quantile_sorted(&sorted(&x), p));
        }
        assert!(quantile_in_place(&mut [], 0.5).is_nan());
        assert_eq!(quantile_in_place(&mut [7.0], 0.95), 7.0);
    }

    #[test]
    fn match_numpy() {
        let x = [4.0, 1.0, 3.0, 2.0, 10.0];
        assert_eq!(mean(&x), 4.0);
        // numpy.var(x, ddof=1) = 12.5
        assert!((variance(&x) - 12.5).abs() < 1e-12);
        assert_eq!(median(&x), 3.0);
        assert_eq!(median(&[4.0, 1.0, 3.0, 2.0]), 2.5);
        // numpy.quantile([1,2,3,4,10], 0.9) = 7.6
        assert!((quantile_sorted(&sorted(&x), 0.9) - 7.6).abs() < 1e-12);
        let mut b: Vec<f64> = (0..=100).map(f64::from).collect();
        let ci = percentile_ci(&mut b, 0.95);
        assert!((ci[0] - 2.5).abs() < 1e-12 && (ci[1] - 97.5).abs() < 1e-12);
        assert!(variance(&[1.0]).is_nan());
    }
}
