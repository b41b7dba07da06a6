//! Negative-binomial (NB2) regression with a log link, fitted by maximum likelihood for the
//! coefficients β and the dispersion α jointly, with cluster-robust standard errors. Matches
//! `statsmodels.discrete.discrete_model.NegativeBinomial(y, X, loglike_method="nb2")
//! .fit(cov_type="cluster", cov_kwds={"groups": g})`: the sandwich H⁻¹ (Σ_g s_g s_gᵀ) H⁻¹
//! over the full parameter vector (β, α) with the small-sample factor
//! G/(G-1) · (N-1)/(N-K), K = number of parameters including α; Wald intervals and p-values
//! from the normal distribution.
//!
//! When the dispersion's maximum-likelihood estimate lies on its boundary α = 0 (counts no
//! more variable than Poisson), NB2 reduces to the Poisson model: that is fitted instead and
//! α is reported as 0 with an undefined standard error (statsmodels ends at α ≈ 1e-8 with the
//! same coefficients).
//!
//! Per observation, with μ = exp(xβ) and r = 1/α:
//! ℓ = lnΓ(y+r) - lnΓ(r) - lnΓ(y+1) + r ln(r/(r+μ)) + y ln(μ/(r+μ)).

use crate::error::StatsError;
use crate::linalg::{invert, matmul};
use crate::special::{digamma, ln_gamma, normal_cdf, normal_ppf, trigamma};

/// A fitted NB2 model.
#[derive(Debug, Clone, PartialEq)]
pub struct Nb2Fit {
    /// Coefficients β followed by the dispersion α.
    pub params: Vec<f64>,
    /// Their covariance (row-major, (k+1) x (k+1)); cluster-robust when clusters were given.
    pub cov: Vec<f64>,
    /// Standard errors of `params`.
    pub se: Vec<f64>,
    /// Log-likelihood at the optimum.
    pub llf: f64,
    /// Newton iterations used.
    pub iterations: usize,
}

/// A Wald summary of one parameter.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct Wald {
    /// Estimate.
    pub estimate: f64,
    /// Standard error.
    pub se: f64,
    /// Two-sided p-value (normal).
    pub p: f64,
    /// 95 % interval (normal).
    pub ci: [f64; 2],
}

impl Nb2Fit {
    /// Wald summary of parameter `j`.
    pub fn wald(&self, j: usize) -> Wald {
        let (b, s) = (self.params[j], self.se[j]);
        let z = normal_ppf(0.975);
        Wald {
            estimate: b,
            se: s,
            p: 2.0 * normal_cdf(-(b / s).abs()),
            ci: [b - z * s, b + z * s],
        }
    }
}

/// Per-observation log-likelihood, score (β.., α) and Hessian contributions.
struct Obs {
    ll: f64,
}

fn obs_terms(
    y: f64,
    xrow: &[f64],
    beta: &[f64],
    alpha: f64,
    grad: &mut [f64],
    hess: &mut [f64],
    want_hess: bool,
) -> Obs {
    let k = beta.len();
    let p = k + 1;
    let eta: f64 = xrow.iter().zip(beta).map(|(x, b)| x * b).sum();
    let mu = eta.exp();
    let r = 1.0 / alpha;
    let ll = ln_gamma(y + r) - ln_gamma(r) - ln_gamma(y + 1.0)
        + r * (r / (r + mu)).ln()
        + y * (mu / (r + mu)).ln();
    let am = 1.0 + alpha * mu;
    // dℓ/dβ = (y - μ)/(1 + αμ) x
    let gb = (y - mu) / am;
    // dℓ/dr = ψ(y+r) - ψ(r) + ln(r/(r+μ)) + (μ - y)/(r+μ); dℓ/dα = -r² dℓ/dr
    let g_r = digamma(y + r) - digamma(r) + (r / (r + mu)).ln() + (mu - y) / (r + mu);
    let ga = -r * r * g_r;
    for j in 0..k {
        grad[j] = gb * xrow[j];
    }
    grad[k] = ga;
    if want_hess {
        // d²ℓ/dβdβ' = -μ(1 + αy)/(1 + αμ)² x x'
        let hbb = -mu * (1.0 + alpha * y) / (am * am);
        // d²ℓ/dβdα = -(y - μ) μ /(1 + αμ)² x
        let hba = -(y - mu) * mu / (am * am);
        // d²ℓ/dα² = 2r³ g_r + r⁴ g_r'
        let gpr = trigamma(y + r) - trigamma(r) + 1.0 / r
            - 1.0 / (r + mu)
            - (mu - y) / ((r + mu) * (r + mu));
        let haa = 2.0 * r * r * r * g_r + r * r * r * r * gpr;
        for i in 0..k {
            for j in 0..k {
                hess[i * p + j] = hbb * xrow[i] * xrow[j];
            }
            hess[i * p + k] = hba * xrow[i];
            hess[k * p + i] = hba * xrow[i];
        }
        hess[k * p + k] = haa;
    }
    Obs { ll }
}

/// Total log-likelihood, gradient and Hessian at (β, α).
fn totals(y: &[f64], x: &[f64], beta: &[f64], alpha: f64) -> (f64, Vec<f64>, Vec<f64>) {
    let k = beta.len();
    let p = k + 1;
    let (mut ll, mut g, mut h) = (0.0, vec![0.0; p], vec![0.0; p * p]);
    let (mut gi, mut hi) = (vec![0.0; p], vec![0.0; p * p]);
    for (i, &yi) in y.iter().enumerate() {
        ll += obs_terms(
            yi,
            &x[i * k..(i + 1) * k],
            beta,
            alpha,
            &mut gi,
            &mut hi,
            true,
        )
        .ll;
        g.iter_mut().zip(&gi).for_each(|(a, b)| *a += b);
        h.iter_mut().zip(&hi).for_each(|(a, b)| *a += b);
    }
    (ll, g, h)
}

/// Below this the dispersion is taken to be at its boundary, 0.
const ALPHA_BOUNDARY: f64 = 1e-6;

/// Poisson regression (NB2 at α = 0), same covariance conventions (K = number of β).
fn fit_poisson(
    y: &[f64],
    x: &[f64],
    k: usize,
    clusters: Option<&[usize]>,
) -> Result<Nb2Fit, StatsError> {
    let n = y.len();
    let ybar = y.iter().sum::<f64>() / n as f64;
    let mut beta = vec![0.0; k];
    if x.chunks(k).all(|r| r[0] == x[0]) {
        beta[0] = ybar.ln() / x[0];
    }
    let eval = |beta: &[f64]| {
        let (mut ll, mut g, mut h) = (0.0, vec![0.0; k], vec![0.0; k * k]);
        for (i, &yi) in y.iter().enumerate() {
            let row = &x[i * k..(i + 1) * k];
            let mu = row.iter().zip(beta).map(|(a, b)| a * b).sum::<f64>().exp();
            ll += yi * mu.ln() - mu - ln_gamma(yi + 1.0);
            for a in 0..k {
                g[a] += (yi - mu) * row[a];
                for b in 0..k {
                    h[a * k + b] -= mu * row[a] * row[b];
                }
            }
        }
        (ll, g, h)
    };
    let (mut ll, mut g, mut h) = eval(&beta);
    let mut iterations = 0;
    for it in 0..100 {
        iterations = it + 1;
        let inv = invert(&h, k)
            .ok_or_else(|| StatsError::NoConvergence("poisson: singular Hessian".into()))?;
        let step: Vec<f64> = (0..k)
            .map(|i| -(0..k).map(|j| inv[i * k + j] * g[j]).sum::<f64>())
            .collect();
        let mut t = 1.0;
        let mut accepted = false;
        for _ in 0..40 {
            let nb: Vec<f64> = beta.iter().zip(&step).map(|(b, s)| b + t * s).collect();
            let (nl, ng, nh) = eval(&nb);
            if nl.is_finite() && nl >= ll - 1e-12 * ll.abs() {
                (beta, ll, g, h) = (nb, nl, ng, nh);
                accepted = true;
                break;
            }
            t *= 0.5;
        }
        if !accepted || step.iter().all(|s| (t * s).abs() < 1e-12) {
            break;
        }
    }
    let h_inv = invert(&h, k).ok_or_else(|| {
        StatsError::NoConvergence("poisson: singular Hessian at the optimum".into())
    })?;
    let cov_b: Vec<f64> = match clusters {
        None => h_inv.iter().map(|v| -v).collect(),
        Some(c) => {
            let n_groups = c.iter().max().map_or(0, |m| m + 1);
            let mut sums = vec![0.0; n_groups * k];
            for i in 0..n {
                let row = &x[i * k..(i + 1) * k];
                let mu = row.iter().zip(&beta).map(|(a, b)| a * b).sum::<f64>().exp();
                for a in 0..k {
                    sums[c[i] * k + a] += (y[i] - mu) * row[a];
                }
            }
            let used: Vec<usize> = (0..n_groups).filter(|g| c.contains(g)).collect();
            let gn = used.len() as f64;
            if gn < 2.0 {
                return Err(StatsError::Undefined(
                    "clustered errors need at least two clusters".into(),
                ));
            }
            let mut meat = vec![0.0; k * k];
            for &gi in &used {
                let sg = &sums[gi * k..(gi + 1) * k];
                for a in 0..k {
                    for b in 0..k {
                        meat[a * k + b] += sg[a] * sg[b];
                    }
                }
            }
            let factor = gn / (gn - 1.0) * ((n as f64 - 1.0) / (n as f64 - k as f64));
            matmul(&matmul(&h_inv, &meat, k), &h_inv, k)
                .into_iter()
                .map(|v| v * factor)
                .collect()
        }
    };
    let p = k + 1;
    let mut cov = vec![f64::NAN; p * p];
    for a in 0..k {
        for b in 0..k {
            cov[a * p + b] = cov_b[a * k + b];
        }
    }
    let mut params = beta;
    params.push(0.0);
    let se = (0..p).map(|i| cov[i * p + i].sqrt()).collect();
    Ok(Nb2Fit {
        params,
        cov,
        se,
        llf: ll,
        iterations,
    })
}

/// Fits NB2 to counts `y` with design matrix `x` (row-major, n x k, include the intercept
/// column yourself). `clusters[i]` is observation i's cluster id for robust standard errors
/// (`None`: the usual inverse-Hessian covariance).
pub fn fit_nb2(
    y: &[f64],
    x: &[f64],
    k: usize,
    clusters: Option<&[usize]>,
) -> Result<Nb2Fit, StatsError> {
    let n = y.len();
    if n == 0 || k == 0 || x.len() != n * k {
        return Err(StatsError::Undefined(format!(
            "nb2: {} values of x for {n} observations of {k} columns",
            x.len()
        )));
    }
    if y.iter()
        .any(|v| !v.is_finite() || *v < 0.0 || v.fract() != 0.0)
        || x.iter().any(|v| !v.is_finite())
    {
        return Err(StatsError::Undefined(
            "nb2: y must be non-negative integer counts and x finite".into(),
        ));
    }
    let ybar = y.iter().sum::<f64>() / n as f64;
    if ybar <= 0.0 {
        return Err(StatsError::Undefined("nb2: all counts are zero".into()));
    }
    let p = k + 1;
    // Start: intercept at ln(mean y) if the first column is constant, else 0; α by moments.
    let mut beta = vec![0.0; k];
    if x.chunks(k).all(|r| r[0] == x[0]) {
        beta[0] = ybar.ln() / x[0];
    }
    let var = y.iter().map(|v| (v - ybar).powi(2)).sum::<f64>() / (n as f64 - 1.0).max(1.0);
    let mut alpha = ((var - ybar) / (ybar * ybar)).clamp(0.05, 10.0);
    // Newton in θ = (β, ln α), which keeps α > 0; step halving keeps ℓ increasing.
    let (mut ll, mut g, mut h) = totals(y, x, &beta, alpha);
    let mut iterations = 0;
    for it in 0..200 {
        iterations = it + 1;
        let mut gt = g.clone();
        gt[k] *= alpha;
        let mut ht = h.clone();
        for i in 0..k {
            ht[i * p + k] *= alpha;
            ht[k * p + i] *= alpha;
        }
        ht[k * p + k] = alpha * alpha * h[k * p + k] + alpha * g[k];
        let Some(inv) = invert(&ht, p) else {
            return Err(StatsError::NoConvergence(
                "nb2: singular Hessian (collinear design?)".into(),
            ));
        };
        let step: Vec<f64> = (0..p)
            .map(|i| -(0..p).map(|j| inv[i * p + j] * gt[j]).sum::<f64>())
            .collect();
        let mut t = 1.0;
        let mut accepted = false;
        for _ in 0..40 {
            let nb: Vec<f64> = (0..k).map(|j| beta[j] + t * step[j]).collect();
            let na = (alpha.ln() + t * step[k]).exp();
            let (nl, ng, nh) = totals(y, x, &nb, na);
            if nl.is_finite() && nl >= ll - 1e-12 * ll.abs() {
                beta = nb;
                alpha = na;
                ll = nl;
                g = ng;
                h = nh;
                accepted = true;
                break;
            }
            t *= 0.5;
        }
        let max_step = step.iter().fold(0.0f64, |m, s| m.max((t * s).abs()));
        if !accepted || max_step < 1e-10 || alpha < ALPHA_BOUNDARY {
            break;
        }
    }
    if alpha < ALPHA_BOUNDARY {
        return fit_poisson(y, x, k, clusters);
    }
    let gmax = g.iter().fold(0.0f64, |m, v| m.max(v.abs()));
    if gmax.is_nan() || gmax >= 1e-4 * n as f64 {
        return Err(StatsError::NoConvergence(format!(
            "nb2: no convergence (gradient {gmax:e}); the maximum-likelihood estimate may not exist, e.g. when one covariate value has only zero counts"
        )));
    }
    let Some(h_inv) = invert(&h, p) else {
        return Err(StatsError::NoConvergence(
            "nb2: singular Hessian at the optimum".into(),
        ));
    };
    let cov = match clusters {
        None => h_inv.iter().map(|v| -v).collect(),
        Some(c) => robust_cov(y, x, &beta, alpha, &h_inv, c)?,
    };
    let mut params = beta;
    params.push(alpha);
    let se = (0..p).map(|i| cov[i * p + i].sqrt()).collect();
    Ok(Nb2Fit {
        params,
        cov,
        se,
        llf: ll,
        iterations,
    })
}

fn robust_cov(
    y: &[f64],
    x: &[f64],
    beta: &[f64],
    alpha: f64,
    h_inv: &[f64],
    clusters: &[usize],
) -> Result<Vec<f64>, StatsError> {
    let (n, k) = (y.len(), beta.len());
    let p = k + 1;
    if clusters.len() != n {
        return Err(StatsError::Undefined(format!(
            "nb2: {} cluster ids for {n} observations",
            clusters.len()
        )));
    }
    let n_groups = clusters.iter().max().map_or(0, |m| m + 1);
    let mut sums = vec![0.0; n_groups * p];
    let (mut gi, mut unused) = (vec![0.0; p], vec![]);
    for i in 0..n {
        obs_terms(
            y[i],
            &x[i * k..(i + 1) * k],
            beta,
            alpha,
            &mut gi,
            &mut unused,
            false,
        );
        let c = clusters[i];
        for j in 0..p {
            sums[c * p + j] += gi[j];
        }
    }
    let used: Vec<usize> = (0..n_groups).filter(|c| clusters.contains(c)).collect();
    let g = used.len() as f64;
    if g < 2.0 {
        return Err(StatsError::Undefined(
            "nb2: clustered errors need at least two clusters".into(),
        ));
    }
    let mut meat = vec![0.0; p * p];
    for &c in &used {
        let s = &sums[c * p..(c + 1) * p];
        for i in 0..p {
            for j in 0..p {
                meat[i * p + j] += s[i] * s[j];
            }
        }
    }
    let factor = g / (g - 1.0) * ((n as f64 - 1.0) / (n as f64 - p as f64));
    let sandwich = matmul(&matmul(h_inv, &meat, p), h_inv, p);
    Ok(sandwich.into_iter().map(|v| v * factor).collect())
}
