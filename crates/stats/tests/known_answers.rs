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

/// The NB2 trend of 6 trials x 15 minutes of counts: intercept and minute, clustered by trial.
fn per_minute_trend(y: &[f64; 90]) -> fishprobe_stats::Nb2Fit {
    let x: Vec<f64> = (0..90).flat_map(|i| [1.0, f64::from(i % 15)]).collect();
    let clusters: Vec<usize> = (0..90).map(|i| i / 15).collect();
    fit_nb2(y, &x, 2, Some(&clusters)).unwrap()
}

/// Each of `fit`'s first `params.len()` parameters and standard errors within `tol` (relative).
fn assert_estimates(fit: &fishprobe_stats::Nb2Fit, params: &[f64], bse: &[f64], tol: f64) {
    for (j, (p, se)) in params.iter().zip(bse).enumerate() {
        assert!(
            rel(fit.params[j], *p) < tol,
            "param {j}: {} vs {p}",
            fit.params[j]
        );
        assert!(rel(fit.se[j], *se) < tol, "se {j}: {} vs {se}", fit.se[j]);
    }
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
    assert_estimates(&fit, &params, &bse, 1e-4);
    for j in 0..3 {
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
/// decline: 6 trials x 15 minutes. The score of α at 0 is ½ Σ [(y - μ)² - y] = -173.6, so the
/// maximum is on the boundary α = 0 and the fit is Poisson's.
///
/// statsmodels 0.15.0's `NegativeBinomial(y, X, loglike_method="nb2").fit(cov_type="cluster",
/// cov_kwds={"groups": trial}, disp=0, maxiter=200)` does not converge here: it reports
/// `converged = False` and stops at α = 9.6e-9 (another run of the same version stopped at
/// 2.3e-8), where the score of α is -97, not 0; its lnΓ(y + 1/α) - lnΓ(1/α) loses about 1e-6 of
/// the likelihood per observation to cancellation, more than the differences its BFGS compares.
/// Its slope's p-value was 5.06e-82 in one run and 4.80e-82 in the other. The exact answer is
/// statsmodels' converged Poisson fit with α counted in the small-sample factor:
///
/// ```python
/// r = Poisson(y, sm.add_constant(minute)).fit(cov_type="cluster", cov_kwds={"groups": trial},
///                                            method="newton", tol=1e-14, disp=0)
/// se = r.bse * np.sqrt((90 - 2) / (90 - 3)); p = 2 * scipy.stats.norm.sf(abs(r.params / se))
/// ```
#[test]
fn nb2_temporal_fit_of_an_under_dispersed_policy_is_the_converged_poisson_fit() {
    let y: [f64; 90] = [
        5., 5., 4., 5., 5., 4., 4., 5., 4., 4., 4., 4., 3., 4., 4., 6., 5., 5., 5., 6., 5., 5., 4.,
        5., 5., 4., 5., 4., 4., 4., 4., 4., 4., 4., 3., 4., 4., 4., 3., 4., 3., 3., 4., 3., 3., 5.,
        5., 5., 4., 5., 5., 4., 4., 5., 4., 4., 4., 4., 4., 3., 6., 6., 5., 6., 5., 5., 5., 5., 5.,
        4., 5., 4., 5., 4., 4., 4., 5., 4., 4., 4., 4., 4., 3., 4., 4., 3., 4., 3., 3., 3.,
    ];
    let fit = per_minute_trend(&y);
    let params = [1.610453240856613, -0.02314489727595962];
    let bse = [0.05661939465208497, 0.00120642778848474];
    let pvalues = [5.865654986998659e-178, 4.972590106197667e-82];
    assert_estimates(&fit, &params, &bse, 1e-6);
    for (j, want) in pvalues.iter().enumerate() {
        // z = -19.2 for the slope: p moves by 19.2² times the s.e.'s relative error.
        let p = fit.wald(j).p;
        assert!(rel(p, *want) < 2e-3, "p {j}: {p} vs {want}");
    }
    assert_eq!(fit.params[2], 0.0);
    // statsmodels' non-converged NegativeBinomial fit (above) ends lower.
    assert!(fit.llf > -153.5823, "llf {}", fit.llf);
}

/// Counts barely more variable than Poisson (6 trials x 15 minutes, drawn with
/// `numpy.random.default_rng(1525).poisson(exp(1.5 - 0.02 * minute))`): the score of α at 0
/// is +0.0085, so the maximum is inside, at α = 1.1e-5. Known answers in 50-digit arithmetic
/// (`nb2_reference.py` beside this file: the maximum and statsmodels' cluster sandwich there),
/// and statsmodels 0.15.0's own fit, `NegativeBinomial(y, X, loglike_method="nb2").fit(
/// cov_type="cluster", cov_kwds={"groups": trial}, disp=0, maxiter=200)`, which stops at
/// α = 8.2e-5 with the slope's p = 0.024032219. The Poisson fit (α = 0) would give p = 0.02347,
/// 2.4 % off; lnΓ(y + 1/α) - lnΓ(1/α) taken as a difference in double precision left α at
/// 1.05e-5 and p 0.3 % off.
#[test]
fn nb2_with_a_tiny_interior_dispersion_matches_the_50_digit_maximum_and_statsmodels() {
    let y: [f64; 90] = [
        3., 3., 5., 3., 3., 6., 2., 9., 5., 1., 4., 2., 4., 3., 5., 2., 5., 1., 3., 8., 5., 6., 6.,
        4., 4., 1., 6., 4., 5., 2., 3., 2., 5., 9., 7., 3., 3., 2., 5., 8., 5., 2., 4., 3., 1., 2.,
        1., 9., 4., 2., 7., 5., 2., 3., 5., 4., 4., 1., 3., 3., 4., 1., 5., 4., 4., 3., 4., 8., 4.,
        2., 2., 5., 5., 4., 1., 7., 4., 6., 7., 2., 3., 9., 4., 3., 6., 5., 5., 2., 3., 4.,
    ];
    let fit = per_minute_trend(&y);
    let params = [
        1.5019117711586394,
        -0.01565797319211985,
        1.1076301593496772e-05,
    ];
    let bse = [
        0.07451188503424423,
        0.006938718990952817,
        0.017076285565583067,
    ];
    let pvalues = [2.3516874195569803e-90, 0.024032540316973473];
    let ci_slope = [-0.02925761251323148, -0.0020583338710082207];
    assert_estimates(&fit, &params, &bse, 1e-6);
    for (j, want) in pvalues.iter().enumerate() {
        let p = fit.wald(j).p;
        assert!(rel(p, *want) < 1e-5, "p {j}: {p} vs {want}");
    }
    let w = fit.wald(1);
    assert!(rel(w.ci[0], ci_slope[0]) < 1e-6 && rel(w.ci[1], ci_slope[1]) < 1e-6);
    assert!(rel(fit.llf, -186.49927591778347) < 1e-12, "llf {}", fit.llf);
    // statsmodels' own fit: its slope and p agree to 2e-3 and better.
    assert!(rel(fit.params[1], -0.01565842458713857) < 1e-4);
    assert!(rel(w.p, 0.024032219235493212) < 2e-3, "p {}", w.p);
}

/// Counts with a small interior dispersion (α = 0.0054; drawn with
/// `numpy.random.default_rng(1299).poisson(exp(1.0 - 0.02 * minute))`, 6 trials x 15 minutes)
/// on which Newton's method from the usual start (α = 0.05) stalls: far from the maximum its
/// direction in (β, ln α) need not rise. The fit then starts again from the Poisson fit and the
/// moment estimate of α. Known answers: the 50-digit maximum (`nb2_reference.py`) and
/// statsmodels 0.15.0's fit (converged, α = 0.00553).
#[test]
fn nb2_whose_first_newton_path_stalls_finds_the_maximum() {
    let y: [f64; 90] = [
        4., 2., 5., 2., 4., 0., 5., 2., 3., 2., 3., 0., 1., 1., 0., 0., 6., 1., 1., 1., 3., 4., 0.,
        2., 2., 3., 1., 2., 1., 2., 2., 3., 4., 3., 1., 2., 1., 1., 1., 5., 1., 2., 3., 0., 1., 3.,
        5., 2., 1., 2., 2., 2., 1., 1., 1., 1., 0., 1., 1., 0., 3., 1., 3., 2., 3., 3., 1., 2., 1.,
        2., 5., 4., 2., 3., 2., 5., 2., 2., 1., 0., 0., 5., 0., 5., 4., 1., 0., 2., 0., 2.,
    ];
    let fit = per_minute_trend(&y);
    let params = [
        1.0414871046992018,
        -0.05173472930856267,
        0.005449833649374451,
    ];
    let bse = [
        0.11637320118442385,
        0.02370805398247987,
        0.08516793072730706,
    ];
    assert_estimates(&fit, &params, &bse, 1e-6);
    let w = fit.wald(1);
    assert!(rel(w.p, 0.02909784381665266) < 1e-6, "p {}", w.p);
    // statsmodels' fit, which stops a little short of the maximum (α 1.5 % off).
    assert!(rel(w.p, 0.029100618754995297) < 2e-3, "p {}", w.p);
    assert!(rel(w.ci[0], -0.09820132967528451) < 1e-4 && rel(w.ci[1], -0.00526693572473849) < 1e-3);
    assert!(rel(fit.llf, -153.2313445288132) < 1e-12, "llf {}", fit.llf);
}
