//! Known answers computed with scipy 1.17.1 and statsmodels 0.15.0 (the script is in this
//! file's doc below), stored here so the tests need no Python.
//!
//! ```python
//! import numpy as np, scipy.stats as st
//! from statsmodels.discrete.discrete_model import NegativeBinomial
//! rng = np.random.default_rng(7)
//! a = np.round(rng.normal(3, 2, 40), 2); b = np.round(rng.gamma(2, 2, 33), 2)
//! st.wasserstein_distance(a, b)
//! rng = np.random.default_rng(2026)      # 18 trials x 15 minutes, declining rate
//! for g in range(18):
//!     eff = rng.normal(0, 0.3)
//!     for k in range(15):
//!         mu = np.exp(1.2 + eff - 0.04 * k); r = 1 / 0.35
//!         y.append(rng.negative_binomial(r, r / (r + mu))); minute.append(k); trial.append(g)
//! X = np.column_stack([np.ones(len(y)), minute])
//! res = NegativeBinomial(y, X, loglike_method="nb2").fit(
//!     cov_type="cluster", cov_kwds={"groups": trial}, disp=0, maxiter=200)
//! res.params, res.bse, res.pvalues, res.conf_int(), res.llf
//! ```

#![allow(clippy::unwrap_used)] // a failure is a test failure

use fishprobe_stats::{fit_nb2, wasserstein};

const A: [f64; 40] = [
    3.0, 3.6, 2.45, 1.22, 2.09, 1.02, 3.12, 5.68, 2.02, 1.76, 3.98, 3.71, 3.21, 1.14, 2.94, 4.39,
    0.31, 2.08, -0.8, 0.42, -0.68, 2.53, 0.47, 3.54, 3.31, 2.63, -2.03, 1.92, 2.9, 3.23, -0.06,
    2.04, 1.04, 1.38, 5.12, 1.38, 2.93, 4.77, 1.83, 2.78,
];
const B: [f64; 33] = [
    3.63, 1.07, 8.22, 6.08, 1.94, 5.71, 3.53, 2.87, 3.16, 8.6, 3.89, 3.67, 2.05, 6.23, 0.95, 5.3,
    2.27, 7.75, 2.56, 2.73, 2.35, 4.33, 2.85, 3.3, 7.34, 3.27, 2.53, 3.32, 0.99, 2.61, 3.78, 1.61,
    3.89,
];
const Y: [u32; 270] = [
    4, 6, 2, 1, 1, 2, 4, 1, 4, 3, 1, 2, 0, 3, 4, 12, 1, 5, 1, 5, 8, 3, 2, 0, 2, 2, 1, 0, 1, 3, 8,
    7, 6, 1, 1, 5, 5, 2, 3, 0, 1, 10, 1, 0, 2, 1, 3, 3, 2, 1, 1, 0, 3, 2, 5, 2, 4, 1, 2, 0, 1, 5,
    1, 4, 2, 0, 0, 2, 4, 0, 1, 2, 2, 0, 2, 1, 3, 4, 0, 2, 2, 3, 0, 0, 0, 3, 1, 1, 0, 5, 3, 1, 2, 3,
    10, 1, 1, 2, 3, 3, 2, 0, 5, 0, 1, 3, 2, 2, 3, 3, 5, 6, 5, 5, 0, 1, 7, 5, 1, 0, 5, 0, 1, 2, 3,
    1, 0, 4, 11, 0, 0, 1, 2, 2, 9, 3, 8, 2, 1, 1, 2, 7, 2, 1, 1, 2, 0, 0, 1, 2, 2, 4, 1, 1, 3, 0,
    5, 5, 9, 1, 5, 7, 1, 1, 3, 0, 2, 1, 2, 1, 1, 1, 0, 1, 2, 0, 2, 1, 0, 1, 0, 1, 5, 0, 1, 0, 2, 2,
    7, 0, 1, 3, 5, 4, 0, 1, 1, 3, 2, 5, 3, 2, 1, 1, 1, 3, 5, 0, 2, 1, 2, 0, 3, 2, 0, 1, 4, 1, 1, 0,
    1, 1, 2, 0, 1, 3, 2, 0, 3, 3, 5, 3, 0, 4, 2, 4, 1, 0, 0, 1, 6, 6, 3, 1, 7, 1, 5, 0, 2, 3, 1, 8,
    4, 3, 2, 4, 0, 1, 4, 1, 2, 1, 0, 0, 0, 1, 3, 1, 2, 1,
];

fn rel(a: f64, b: f64) -> f64 {
    ((a - b) / b).abs()
}

#[test]
fn wasserstein_matches_scipy() {
    let w = wasserstein(&A, &B).unwrap();
    assert!(rel(w, 1.5598409090909091) < 1e-12, "{w}");
}

#[test]
fn nb2_with_trial_clustered_errors_matches_statsmodels() {
    let y: Vec<f64> = Y.iter().map(|&v| f64::from(v)).collect();
    let x: Vec<f64> = (0..270).flat_map(|i| [1.0, f64::from(i % 15)]).collect();
    let clusters: Vec<usize> = (0..270).map(|i| i / 15).collect();
    let fit = fit_nb2(&y, &x, 2, Some(&clusters)).unwrap();
    let params = [
        1.0569723984324528,
        -0.03275516296774897,
        0.43252126029880794,
    ];
    let bse = [
        0.12067470673718095,
        0.013555699940109443,
        0.07433366431729371,
    ];
    let pvalues = [
        1.972416207304156e-18,
        0.015677468722756088,
        5.932631452707673e-09,
    ];
    let ci = [
        [0.8204543193826451, 1.2934904774822604],
        [-0.05932384663559524, -0.006186479299902695],
        [0.28682995539802214, 0.5782125651995937],
    ];
    for j in 0..3 {
        assert!(
            rel(fit.params[j], params[j]) < 1e-4,
            "param {j}: {} vs {}",
            fit.params[j],
            params[j]
        );
        assert!(
            rel(fit.se[j], bse[j]) < 1e-4,
            "se {j}: {} vs {}",
            fit.se[j],
            bse[j]
        );
        let w = fit.wald(j);
        assert!(
            rel(w.p, pvalues[j]) < 1e-3,
            "p {j}: {} vs {}",
            w.p,
            pvalues[j]
        );
        assert!(
            rel(w.ci[0], ci[j][0]) < 1e-4 && rel(w.ci[1], ci[j][1]) < 1e-4,
            "ci {j}"
        );
    }
    assert!(rel(fit.llf, -532.4980422854927) < 1e-8, "llf {}", fit.llf);
}

#[test]
fn nb2_rejects_bad_input() {
    assert!(fit_nb2(&[1.0, -1.0], &[1.0, 1.0], 1, None).is_err());
    assert!(fit_nb2(&[0.0, 0.0], &[1.0, 1.0], 1, None).is_err());
    assert!(fit_nb2(&[1.5, 2.0], &[1.0, 1.0], 1, None).is_err());
    assert!(fit_nb2(&[1.0, 2.0, 3.0], &[1.0, 1.0], 1, None).is_err());
}

/// Under-dispersed counts: the dispersion MLE is at α = 0 and the fit is Poisson. statsmodels'
/// `NegativeBinomial(...).fit(cov_type="cluster")` ends at α = 2.3e-8 with the same
/// coefficients and counts α among the parameters in the small-sample factor (K = 3), which
/// fishprobe follows; statsmodels' `Poisson` would give standard errors smaller by
/// sqrt((N-3)/(N-2)) (here 0.0254 and 0.0372).
#[test]
fn nb2_at_the_dispersion_boundary_is_poisson_with_statsmodels_nb_errors() {
    let y = [
        7.0, 7.0, 6.0, 7.0, 8.0, 7.0, 7.0, 6.0, 7.0, 7.0, 8.0, 6.0, 7.0, 7.0, 7.0, 6.0, 7.0, 8.0,
        7.0, 7.0, 6.0, 6.0, 7.0, 7.0,
    ];
    let x: Vec<f64> = (0..24).flat_map(|i| [1.0, f64::from(i % 2)]).collect();
    let clusters: Vec<usize> = (0..24).map(|i| i / 2).collect();
    let fit = fit_nb2(&y, &x, 2, Some(&clusters)).unwrap();
    // statsmodels 0.15.0 NegativeBinomial, cluster covariance.
    let params = [1.9459097714449969, -0.03636694136081434];
    let bse = [0.026025520534903923, 0.038095704754343734];
    for j in 0..2 {
        assert!(
            rel(fit.params[j], params[j]) < 1e-4,
            "param {j}: {}",
            fit.params[j]
        );
        assert!(rel(fit.se[j], bse[j]) < 1e-4, "se {j}: {}", fit.se[j]);
    }
    assert!(
        rel(fit.wald(1).p, 0.3397696378840317) < 1e-3,
        "p {}",
        fit.wald(1).p
    );
    assert_eq!(fit.params[2], 0.0);
    assert!(fit.se[2].is_nan());
}

/// Goals per minute as under-dispersed as a good policy's (variance 0.61 at mean 4.28), with a
/// decline: 6 trials x 15 minutes. Known answers from statsmodels 0.15.0:
///
/// ```python
/// m = NegativeBinomial(y, sm.add_constant(minute), loglike_method="nb2")
/// r = m.fit(cov_type="cluster", cov_kwds={"groups": trial}, disp=0, maxiter=200)
/// ```
///
/// Before fishprobe counted α in K at the boundary, its standard errors were 0.57 % smaller
/// and the slope's p-value was off by a factor of three (z = -19).
#[test]
fn nb2_temporal_fit_of_an_under_dispersed_policy_matches_statsmodels() {
    let y: [f64; 90] = [
        5., 5., 4., 5., 5., 4., 4., 5., 4., 4., 4., 4., 3., 4., 4., 6., 5., 5., 5., 6., 5., 5., 4.,
        5., 5., 4., 5., 4., 4., 4., 4., 4., 4., 4., 3., 4., 4., 4., 3., 4., 3., 3., 4., 3., 3., 5.,
        5., 5., 4., 5., 5., 4., 4., 5., 4., 4., 4., 4., 4., 3., 6., 6., 5., 6., 5., 5., 5., 5., 5.,
        4., 5., 4., 5., 4., 4., 4., 5., 4., 4., 4., 4., 4., 3., 4., 4., 3., 4., 3., 3., 3.,
    ];
    let x: Vec<f64> = (0..90).flat_map(|i| [1.0, f64::from(i % 15)]).collect();
    let clusters: Vec<usize> = (0..90).map(|i| i / 15).collect();
    let fit = fit_nb2(&y, &x, 2, Some(&clusters)).unwrap();
    let params = [1.6104470699667255, -0.023144160586165027];
    let bse = [0.056619728930776485, 0.0012064484798776584];
    let ci_slope = [-0.025508756155928333, -0.02077956501640172];
    for j in 0..2 {
        assert!(
            rel(fit.params[j], params[j]) < 1e-4,
            "param {j}: {}",
            fit.params[j]
        );
        assert!(
            rel(fit.se[j], bse[j]) < 1e-4,
            "se {j}: {} vs {}",
            fit.se[j],
            bse[j]
        );
    }
    let w = fit.wald(1);
    assert!(rel(w.ci[0], ci_slope[0]) < 1e-4 && rel(w.ci[1], ci_slope[1]) < 1e-4);
    // z = -19.2: p is 5.06e-82; a relative error of 1e-5 in the s.e. moves it by about 0.4 %.
    assert!(rel(w.p, 5.063288174501792e-82) < 2e-2, "p {}", w.p);
    assert_eq!(fit.params[2], 0.0);
}
