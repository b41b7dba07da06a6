//! How much a sample spreads, and whether two samples spread alike: the Brown–Forsythe test
//! (`scipy.stats.levene(..., center="median")`), a percentile bootstrap of the ratio of two
//! standard deviations, ranks (`scipy.stats.rankdata`) and Spearman's rank correlation
//! (`scipy.stats.spearmanr`). For the between-trial spread of the analysis: do simulated
//! trials differ from one another as much as live ones?

use crate::error::{check_sample, StatsError};
use crate::sample::{median, sd};
use rand::{Rng, RngExt};
use statrs::distribution::{ContinuousCDF, FisherSnedecor, StudentsT};

/// A test statistic and its p-value.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct TestResult {
    /// The statistic (Brown–Forsythe: W; Spearman: ρ).
    pub statistic: f64,
    /// Its p-value.
    pub p: f64,
}

/// The Brown–Forsythe test of equal spread across `groups` (at least two, each with at least
/// two values): Levene's W on the absolute deviations from each group's median, p from the
/// F(k - 1, N - k) distribution, like `scipy.stats.levene(*groups, center="median")`.
/// Undefined (an error) when every group's deviations are constant within the group, where
/// scipy returns NaN or infinity.
pub fn brown_forsythe(groups: &[&[f64]]) -> Result<TestResult, StatsError> {
    if groups.len() < 2 {
        return Err(StatsError::Undefined(
            "Brown–Forsythe needs at least two groups".into(),
        ));
    }
    let mut z: Vec<Vec<f64>> = Vec::with_capacity(groups.len());
    for g in groups {
        check_sample("Brown–Forsythe group", g)?;
        if g.len() < 2 {
            return Err(StatsError::Undefined(
                "Brown–Forsythe needs at least two values per group".into(),
            ));
        }
        let m = median(g);
        z.push(g.iter().map(|v| (v - m).abs()).collect());
    }
    let n: usize = z.iter().map(Vec::len).sum();
    let k = z.len();
    let means: Vec<f64> = z.iter().map(|g| crate::sample::mean(g)).collect();
    let grand = z.iter().flatten().sum::<f64>() / n as f64;
    let between: f64 = z
        .iter()
        .zip(&means)
        .map(|(g, m)| g.len() as f64 * (m - grand).powi(2))
        .sum();
    let within: f64 = z
        .iter()
        .zip(&means)
        .map(|(g, m)| g.iter().map(|v| (v - m).powi(2)).sum::<f64>())
        .sum();
    let (df1, df2) = ((k - 1) as f64, (n - k) as f64);
    if within <= 0.0 || df2 <= 0.0 {
        return Err(StatsError::Undefined(
            "Brown–Forsythe: no spread of the deviations within any group".into(),
        ));
    }
    let w = df2 / df1 * between / within;
    let f = FisherSnedecor::new(df1, df2)
        .map_err(|e| StatsError::Undefined(format!("Brown–Forsythe: {e}")))?;
    Ok(TestResult {
        statistic: w,
        p: f.sf(w),
    })
}

/// Average ranks (1 = smallest), ties sharing the mean of their positions, like
/// `scipy.stats.rankdata(x, method="average")`.
pub fn rankdata(x: &[f64]) -> Vec<f64> {
    let mut idx: Vec<usize> = (0..x.len()).collect();
    idx.sort_by(|&a, &b| x[a].total_cmp(&x[b]));
    let mut ranks = vec![0.0; x.len()];
    let mut i = 0;
    while i < idx.len() {
        let mut j = i;
        while j + 1 < idx.len() && x[idx[j + 1]] == x[idx[i]] {
            j += 1;
        }
        let r = (i + j) as f64 / 2.0 + 1.0;
        for &k in &idx[i..=j] {
            ranks[k] = r;
        }
        i = j + 1;
    }
    ranks
}

fn pearson(a: &[f64], b: &[f64]) -> f64 {
    let (ma, mb) = (crate::sample::mean(a), crate::sample::mean(b));
    let (mut sab, mut saa, mut sbb) = (0.0, 0.0, 0.0);
    for (x, y) in a.iter().zip(b) {
        sab += (x - ma) * (y - mb);
        saa += (x - ma).powi(2);
        sbb += (y - mb).powi(2);
    }
    sab / (saa * sbb).sqrt()
}

/// Spearman's rank correlation ρ of paired samples and its two-sided p-value from Student's t
/// with n - 2 degrees of freedom, like `scipy.stats.spearmanr(x, y)`. Undefined (an error)
/// below three pairs or when either sample is constant (scipy: NaN).
pub fn spearman(x: &[f64], y: &[f64]) -> Result<TestResult, StatsError> {
    check_sample("spearman x", x)?;
    check_sample("spearman y", y)?;
    if x.len() != y.len() {
        return Err(StatsError::Undefined(format!(
            "spearman: {} values against {}: the samples must be paired",
            x.len(),
            y.len()
        )));
    }
    if x.len() < 3 {
        return Err(StatsError::Undefined(
            "spearman needs at least three pairs".into(),
        ));
    }
    let rho = pearson(&rankdata(x), &rankdata(y));
    if !rho.is_finite() {
        return Err(StatsError::Undefined(
            "spearman: a sample is constant".into(),
        ));
    }
    let rho = rho.clamp(-1.0, 1.0);
    let df = (x.len() - 2) as f64;
    let p = if rho.abs() >= 1.0 {
        0.0
    } else {
        let t = rho * (df / ((1.0 + rho) * (1.0 - rho))).sqrt();
        let dist = StudentsT::new(0.0, 1.0, df)
            .map_err(|e| StatsError::Undefined(format!("spearman: {e}")))?;
        2.0 * dist.sf(t.abs())
    };
    Ok(TestResult { statistic: rho, p })
}

/// The sample s.d. (n - 1), exactly 0 when every value is the same (the plain formula leaves
/// a rounding residue of about 1e-15 of the value there, which would make a ratio of two
/// constant samples a number instead of undefined).
pub fn sd_exact(x: &[f64]) -> f64 {
    match x.first() {
        Some(&first) if x.len() >= 2 && x.iter().all(|&v| v == first) => 0.0,
        _ => sd(x),
    }
}

/// Bootstrap distribution of sd(a) / sd(b) (sample s.d., n - 1): each of `reps` replicates
/// resamples both samples with replacement, independently, at their own sizes. A replicate in
/// which `b`'s resample has no spread gives +∞ (or NaN when `a`'s has none either; those are
/// left out). Both samples need at least two values.
pub fn bootstrap_sd_ratio<R: Rng>(
    a: &[f64],
    b: &[f64],
    reps: usize,
    rng: &mut R,
) -> Result<Vec<f64>, StatsError> {
    check_sample("sd ratio a", a)?;
    check_sample("sd ratio b", b)?;
    if a.len() < 2 || b.len() < 2 {
        return Err(StatsError::Undefined(
            "an s.d. ratio needs at least two values a side".into(),
        ));
    }
    let (mut ra, mut rb) = (vec![0.0; a.len()], vec![0.0; b.len()]);
    let mut out = Vec::with_capacity(reps);
    for _ in 0..reps {
        ra.iter_mut()
            .for_each(|v| *v = a[rng.random_range(0..a.len())]);
        rb.iter_mut()
            .for_each(|v| *v = b[rng.random_range(0..b.len())]);
        let r = sd_exact(&ra) / sd_exact(&rb);
        if !r.is_nan() {
            out.push(r);
        }
    }
    Ok(out)
}

#[cfg(test)]
mod tests {
    #![allow(clippy::unwrap_used)]
    use super::*;
    use rand::SeedableRng;
    use rand_xoshiro::Xoshiro256PlusPlus;

    const A: [f64; 8] = [3.1, 4.7, 2.2, 5.9, 4.4, 3.8, 6.1, 2.9];
    const B: [f64; 6] = [4.0, 4.2, 3.9, 4.1, 4.3, 4.0];
    const C: [f64; 5] = [1.0, 9.0, 5.5, 7.2, 0.4];

    fn close(a: f64, b: f64, tol: f64) {
        assert!((a - b).abs() <= tol * b.abs().max(1e-300), "{a} vs {b}");
    }

    #[test]
    fn brown_forsythe_matches_scipy_levene_with_median_centre() {
        // scipy.stats.levene(A, B, center="median")
        let t = brown_forsythe(&[&A, &B]).unwrap();
        close(t.statistic, 12.207_853_837_940_458, 1e-12);
        close(t.p, 0.004_430_784_872_783_466, 1e-9);
        // three groups
        let t = brown_forsythe(&[&A, &B, &C]).unwrap();
        close(t.statistic, 8.487_604_980_411_415, 1e-12);
        close(t.p, 0.003_072_269_471_582_850_8, 1e-9);
        // ties and an even group: levene([1, 1, 1, 2], [5, 9, 3, 3, 7], center="median")
        let t = brown_forsythe(&[&[1.0, 1.0, 1.0, 2.0], &[5.0, 9.0, 3.0, 3.0, 7.0]]).unwrap();
        close(t.statistic, 5.444_444_444_444_444, 1e-12);
        close(t.p, 0.052_356_306_554_902_324, 1e-9);
    }

    #[test]
    fn brown_forsythe_refuses_what_it_cannot_test() {
        assert!(brown_forsythe(&[&A]).is_err());
        assert!(brown_forsythe(&[&A, &[1.0]]).is_err());
        assert!(brown_forsythe(&[&[1.0, 1.0], &[2.0, 2.0]]).is_err());
        assert!(brown_forsythe(&[&A, &[1.0, f64::NAN]]).is_err());
    }

    #[test]
    fn brown_forsythe_rejects_at_scipys_rates_under_equal_spread() {
        // With 18 trials a side the test is known to be conservative; scipy's levene on the
        // same design (two normal samples of 18, other means, 40,000 repetitions) rejects at
        // 0.039, 0.083 and 0.482 at α = 0.05, 0.1 and 0.5.
        let mut rng = Xoshiro256PlusPlus::seed_from_u64(5);
        let normal = |rng: &mut Xoshiro256PlusPlus| {
            let (u1, u2): (f64, f64) = (rng.random::<f64>().max(1e-300), rng.random());
            (-2.0 * u1.ln()).sqrt() * (std::f64::consts::TAU * u2).cos()
        };
        let mut ps = Vec::new();
        for _ in 0..4000 {
            let a: Vec<f64> = (0..18).map(|_| normal(&mut rng)).collect();
            let b: Vec<f64> = (0..18).map(|_| 3.0 + normal(&mut rng)).collect();
            ps.push(brown_forsythe(&[&a, &b]).unwrap().p);
        }
        for (alpha, scipy) in [(0.05, 0.039), (0.1, 0.083), (0.5, 0.482)] {
            let frac = ps.iter().filter(|&&p| p <= alpha).count() as f64 / ps.len() as f64;
            assert!((frac - scipy).abs() < 0.02, "P(p <= {alpha}) = {frac}");
        }
    }

    #[test]
    fn ranks_and_spearman_match_scipy() {
        let x = [2.0, 3.5, 1.0, 4.0, 4.0, 6.5, 7.0, 2.0];
        assert_eq!(rankdata(&x), vec![2.5, 4.0, 1.0, 5.5, 5.5, 7.0, 8.0, 2.5]);
        // scipy.stats.spearmanr(x, y)
        let y = [1.2, 3.0, 0.5, 5.0, 4.5, 6.0, 8.0, 2.5];
        let s = spearman(&x, &y).unwrap();
        close(s.statistic, 0.988_023_520_059_353_8, 1e-12);
        close(s.p, 4.256_164_416_841_797e-6, 1e-7);
        let y = [5.0, 3.0, 6.0, 1.0, 2.0, 0.5, 4.0, 7.0];
        let s = spearman(&x, &y).unwrap();
        close(s.statistic, -0.710_894_971_750_023, 1e-12);
        close(s.p, 0.048_068_540_310_284_6, 1e-9);
        let s = spearman(&[1.0, 2.0, 3.0], &[3.0, 2.0, 1.0]).unwrap();
        assert_eq!((s.statistic, s.p), (-1.0, 0.0));
        assert!(spearman(&[1.0, 1.0, 1.0], &[1.0, 2.0, 3.0]).is_err());
        assert!(spearman(&[1.0, 2.0], &[1.0, 2.0]).is_err());
        assert!(spearman(&[1.0, 2.0, 3.0], &[1.0, 2.0]).is_err());
    }

    #[test]
    fn sd_ratio_interval_covers_the_true_ratio_about_95_percent() {
        // Normal samples whose s.d. ratio is 0.5. The percentile interval of a ratio of s.d.s
        // is known to undercover at small n; at 60 a side it is near its level.
        let mut rng = Xoshiro256PlusPlus::seed_from_u64(13);
        let normal = |rng: &mut Xoshiro256PlusPlus| {
            let (u1, u2): (f64, f64) = (rng.random::<f64>().max(1e-300), rng.random());
            (-2.0 * u1.ln()).sqrt() * (std::f64::consts::TAU * u2).cos()
        };
        let trials = 300;
        let mut covered = 0;
        for _ in 0..trials {
            let a: Vec<f64> = (0..60).map(|_| 0.5 * normal(&mut rng)).collect();
            let b: Vec<f64> = (0..60).map(|_| normal(&mut rng) + 4.0).collect();
            let mut boot = bootstrap_sd_ratio(&a, &b, 400, &mut rng).unwrap();
            let [lo, hi] = crate::sample::percentile_ci(&mut boot, 0.95);
            covered += usize::from(lo <= 0.5 && 0.5 <= hi);
        }
        let rate = covered as f64 / trials as f64;
        assert!((0.88..=0.99).contains(&rate), "coverage {rate}");
    }

    #[test]
    fn the_sd_of_equal_values_is_exactly_zero() {
        assert_eq!(sd_exact(&[0.04; 7]), 0.0);
        assert_eq!(sd_exact(&[1.0, 3.0]), sd(&[1.0, 3.0]));
        assert!(sd_exact(&[1.0]).is_nan());
    }

    #[test]
    fn sd_ratio_of_a_constant_denominator_is_infinite_and_0_over_0_is_left_out() {
        let mut rng = Xoshiro256PlusPlus::seed_from_u64(1);
        let b = bootstrap_sd_ratio(&[1.0, 2.0], &[3.0, 3.0], 100, &mut rng).unwrap();
        // Half the resamples of `a` have spread (+∞), the others none (0/0, left out).
        assert!(b.iter().all(|&r| r == f64::INFINITY) && (25..75).contains(&b.len()));
        let b = bootstrap_sd_ratio(&[1.0, 1.0], &[3.0, 3.0], 100, &mut rng).unwrap();
        assert!(b.is_empty());
        assert!(bootstrap_sd_ratio(&[1.0], &[3.0, 4.0], 10, &mut rng).is_err());
    }
}
