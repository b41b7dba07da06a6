//! The paired t test on the differences of matched samples, like `scipy.stats.ttest_rel`
//! (two-sided) with its `confidence_interval`: for replicates that each yield both arms of a
//! comparison (e.g. one seed of the OOD loop, refitted once with each kind of new data).

use crate::error::{check_sample, StatsError};
use statrs::distribution::{ContinuousCDF, StudentsT};

/// A paired t test of `x - y`.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct PairedT {
    /// Mean of the differences `x[i] - y[i]`.
    pub mean_difference: f64,
    /// The t statistic: the mean difference over its standard error (±∞ when every difference
    /// is the same non-zero value, NaN when every difference is zero, as scipy's).
    pub t: f64,
    /// Degrees of freedom, n - 1.
    pub df: f64,
    /// Two-sided p value (NaN with a NaN statistic).
    pub p: f64,
    /// The interval for the mean difference at the requested level, Student's t quantile.
    pub ci: [f64; 2],
}

/// Paired t test of `x` against `y` (same length, at least 2 pairs) with a two-sided interval
/// at `level` (e.g. 0.95) for the mean of `x - y`.
pub fn paired_t(x: &[f64], y: &[f64], level: f64) -> Result<PairedT, StatsError> {
    check_sample("paired_t x", x)?;
    check_sample("paired_t y", y)?;
    if x.len() != y.len() {
        return Err(StatsError::Undefined(format!(
            "paired_t: {} values against {}: the samples must be paired",
            x.len(),
            y.len()
        )));
    }
    if x.len() < 2 {
        return Err(StatsError::Undefined(
            "paired_t: one pair has no spread; at least 2 are needed".into(),
        ));
    }
    if !(level > 0.0 && level < 1.0) {
        return Err(StatsError::Undefined(format!(
            "paired_t: confidence level {level} outside (0, 1)"
        )));
    }
    let d: Vec<f64> = x.iter().zip(y).map(|(a, b)| a - b).collect();
    let mean = crate::sample::mean(&d);
    let se = crate::sample::sd(&d) / (d.len() as f64).sqrt();
    let df = (d.len() - 1) as f64;
    let dist = StudentsT::new(0.0, 1.0, df)
        .map_err(|e| StatsError::Undefined(format!("paired_t: Student's t with {df} df: {e}")))?;
    let q = dist.inverse_cdf(0.5 + level / 2.0);
    let t = mean / se;
    let p = if t.is_nan() {
        f64::NAN
    } else {
        (2.0 * dist.sf(t.abs())).min(1.0)
    };
    Ok(PairedT {
        mean_difference: mean,
        t,
        df,
        p,
        ci: [mean - q * se, mean + q * se],
    })
}

#[cfg(test)]
mod tests {
    use super::*;

    fn close(a: f64, b: f64, tol: f64) -> bool {
        (a - b).abs() <= tol * b.abs().max(1.0)
    }

    #[test]
    fn agrees_with_scipy_ttest_rel() {
        // scipy 1.17.1, for each (x, y) below:
        //   r = scipy.stats.ttest_rel(x, y); ci = r.confidence_interval(0.95)
        //   d.mean(), r.statistic, r.pvalue, ci.low, ci.high   (d = x - y)
        let cases: [(&[f64], &[f64], [f64; 5]); 3] = [
            (
                &[0.430, 0.419, 0.380, 0.45, 0.31],
                &[0.440, 0.276, 0.363, 0.5, 0.2],
                [
                    0.041_999_999_999_999_996,
                    1.151_268_382_903_521_3,
                    0.313_756_284_543_947_5,
                    -0.059_288_888_108_099_4,
                    0.143_288_888_108_099_4,
                ],
            ),
            (
                &[1.0, 2.0, 3.0],
                &[1.5, 2.1, 3.9],
                [
                    -0.5,
                    -2.165_063_509_461_097_3,
                    0.162_781_641_721_078_56,
                    -1.493_655_084_700_131_8,
                    0.493_655_084_700_131_75,
                ],
            ),
            (
                &[0.401, 0.33, 0.41, 0.42, 0.44],
                &[0.337, 0.30, 0.35, 0.36, 0.33],
                [
                    0.0648,
                    5.044_061_793_787_263,
                    0.007_261_308_247_251_19,
                    0.029_131_594_224_635_5,
                    0.100_468_405_775_364_49,
                ],
            ),
        ];
        for (x, y, [m, t, p, lo, hi]) in cases {
            let r = paired_t(x, y, 0.95).unwrap();
            assert!(close(r.mean_difference, m, 1e-12), "{r:?}");
            assert!(close(r.t, t, 1e-10), "{r:?}");
            assert!(close(r.p, p, 1e-8), "{r:?}");
            assert!(
                close(r.ci[0], lo, 1e-8) && close(r.ci[1], hi, 1e-8),
                "{r:?}"
            );
            assert_eq!(r.df, (x.len() - 1) as f64);
        }
    }

    #[test]
    fn degenerate_and_bad_input() {
        // Every difference the same: no spread, as scipy (t = inf, p = 0).
        let r = paired_t(&[2.0, 3.0, 4.0], &[1.0, 2.0, 3.0], 0.95).unwrap();
        assert!(r.t.is_infinite() && r.p == 0.0 && r.ci == [1.0, 1.0]);
        let r = paired_t(&[1.0, 2.0], &[1.0, 2.0], 0.95).unwrap();
        assert!(r.t.is_nan() && r.p.is_nan());
        assert!(paired_t(&[1.0], &[2.0], 0.95).is_err());
        assert!(paired_t(&[1.0, 2.0], &[2.0], 0.95).is_err());
        assert!(paired_t(&[1.0, f64::NAN], &[2.0, 1.0], 0.95).is_err());
        assert!(paired_t(&[1.0, 2.0], &[2.0, 1.0], 1.0).is_err());
        assert!(paired_t(&[], &[], 0.95).is_err());
    }
}
