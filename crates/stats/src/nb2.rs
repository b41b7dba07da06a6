//! Negative-binomial (NB2) regression with a log link, fitted by maximum likelihood for the
//! coefficients β and the dispersion α jointly, with cluster-robust standard errors. Matches
//! `statsmodels.discrete.discrete_model.NegativeBinomial(y, X, loglike_method="nb2")
//! .fit(cov_type="cluster", cov_kwds={"groups": g})`: the sandwich H⁻¹ (Σ_g s_g s_gᵀ) H⁻¹
//! over the full parameter vector (β, α) with the small-sample factor
//! G/(G-1) · (N-1)/(N-K), K = number of parameters including α; Wald intervals and p-values
//! from the normal distribution.
//!
//! Near the boundary α = 0 the fit decides by the score of α there. At the Poisson fit β̂,
//! dℓ/dα at α = 0⁺ is ½ Σ [(y - μ)² - y] (Cameron and Trivedi's overdispersion score):
//! - **Not positive:** the likelihood falls as α leaves 0, so the maximum is on the boundary
//!   and NB2 reduces to the Poisson model. That is fitted instead, and α is reported as 0 with
//!   an undefined standard error. statsmodels' `NegativeBinomial` keeps α among the parameters,
//!   so its small-sample factor has K = k + 1; fishprobe follows that convention (the Poisson
//!   sandwich over β, with K = k + 1 in (N-1)/(N-K)). statsmodels itself does not converge
//!   there: its BFGS stops at some tiny α (1e-8 to 1e-5, `converged = False`) where the score
//!   of α is far from zero, and its p-values move by several per cent from run to run; the
//!   known-answer tests compare with statsmodels' converged `Poisson` fit instead.
//! - **Positive:** the maximum is inside, at a small α (1e-5 is typical of counts barely more
//!   variable than Poisson). When the first Newton path heads for the boundary, or stalls on
//!   the way (far from the maximum its direction in (β, ln α) need not rise), Newton's method
//!   starts again from β̂ and the moment estimate α = Σ [(y - μ)² - y] / Σ μ², which lies near
//!   that maximum.
//!
//! At α below 1e-4 the count's terms lnΓ(y + 1/α) - lnΓ(1/α) and its digamma and trigamma
//! differences are summed over the count (Σ ln(1/α + j), ...) instead of taken as differences,
//! whose rounding reaches the few 1e-8 by which the likelihood changes there. The known-answer
//! tests hold fits at α = 1.1e-5 and 0.0054 to values computed in 50-digit arithmetic
//! (`tests/nb2_reference.py`) to 1e-6, and to statsmodels' own fit to 2e-3 in p.
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
    /// A fit from its coefficients, dispersion, covariance of (β, α) and log-likelihood.
    fn assemble(beta: Vec<f64>, alpha: f64, cov: Vec<f64>, llf: f64, iterations: usize) -> Self {
        let p = beta.len() + 1;
        let mut params = beta;
        params.push(alpha);
        let se = (0..p).map(|i| cov[i * p + i].sqrt()).collect();
        Self {
            params,
            cov,
            se,
            llf,
            iterations,
        }
    }

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

/// Above this r = 1/α (α below 1e-4) the count's terms lnΓ(y + r) - lnΓ(r), ψ(y + r) - ψ(r) and
/// ψ'(y + r) - ψ'(r) are summed over the count instead of taken as differences: lnΓ(r) is about
/// r ln r, and its rounding (r ln r · 2e-16 per observation) reaches the few 1e-8 by which the
/// likelihood changes over a tiny α. Below it the differences are exact enough and cheaper.
const SUMMED_ABOVE_R: f64 = 1e4;

/// The largest count whose terms are summed (a longer sum costs more than it saves).
const SUMMED_UP_TO_Y: f64 = 1e4;

/// The mean μ = exp(xβ) of the observation with covariates `row`.
fn mean_at(row: &[f64], beta: &[f64]) -> f64 {
    row.iter().zip(beta).map(|(x, b)| x * b).sum::<f64>().exp()
}

/// The terms of one count `y` at r = 1/α: lnΓ(y + r) - lnΓ(r), ψ(y + r) - ψ(r),
/// ψ'(y + r) - ψ'(r), ln(r / (r + μ)) and 1/r - 1/(r + μ).
fn count_terms(y: f64, r: f64, mu: f64) -> [f64; 5] {
    if r >= SUMMED_ABOVE_R && y <= SUMMED_UP_TO_Y {
        let (mut lg, mut dg, mut tg) = (0.0, 0.0, 0.0);
        let mut j = 0.0;
        while j < y {
            lg += (r + j).ln();
            dg += 1.0 / (r + j);
            tg -= 1.0 / ((r + j) * (r + j));
            j += 1.0;
        }
        [lg, dg, tg, -(mu / r).ln_1p(), mu / (r * (r + mu))]
    } else {
        [
            ln_gamma(y + r) - ln_gamma(r),
            digamma(y + r) - digamma(r),
            trigamma(y + r) - trigamma(r),
            (r / (r + mu)).ln(),
            1.0 / r - 1.0 / (r + mu),
        ]
    }
}

fn obs_terms(
    y: f64,
    xrow: &[f64],
    beta: &[f64],
    alpha: f64,
    grad: &mut [f64],
    hess: &mut [f64],
    want_hess: bool,
) -> f64 {
    let k = beta.len();
    let p = k + 1;
    let mu = mean_at(xrow, beta);
    let r = 1.0 / alpha;
    let [lg, dg, tg, ln_q, inv_diff] = count_terms(y, r, mu);
    let ll = lg - ln_gamma(y + 1.0) + r * ln_q + y * (mu / (r + mu)).ln();
    let am = 1.0 + alpha * mu;
    // dℓ/dβ = (y - μ)/(1 + αμ) x
    let gb = (y - mu) / am;
    // dℓ/dr = ψ(y+r) - ψ(r) + ln(r/(r+μ)) + (μ - y)/(r+μ); dℓ/dα = -r² dℓ/dr
    let g_r = dg + ln_q + (mu - y) / (r + mu);
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
        let gpr = tg + inv_diff - (mu - y) / ((r + mu) * (r + mu));
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
    ll
}

/// Log-likelihood, gradient and Hessian of a parameter vector.
type Objective = (f64, Vec<f64>, Vec<f64>);

/// Total log-likelihood, gradient and Hessian of NB2 at (β, α).
fn nb2_totals(y: &[f64], x: &[f64], beta: &[f64], alpha: f64) -> Objective {
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
        );
        g.iter_mut().zip(&gi).for_each(|(a, b)| *a += b);
        h.iter_mut().zip(&hi).for_each(|(a, b)| *a += b);
    }
    (ll, g, h)
}

/// Poisson log-likelihood, gradient and Hessian at β (NB2 at α = 0).
fn poisson_totals(y: &[f64], x: &[f64], beta: &[f64]) -> Objective {
    let k = beta.len();
    let (mut ll, mut g, mut h) = (0.0, vec![0.0; k], vec![0.0; k * k]);
    for (i, &yi) in y.iter().enumerate() {
        let row = &x[i * k..(i + 1) * k];
        let mu = mean_at(row, beta);
        ll += yi * mu.ln() - mu - ln_gamma(yi + 1.0);
        for a in 0..k {
            g[a] += (yi - mu) * row[a];
            for b in 0..k {
                h[a * k + b] -= mu * row[a] * row[b];
            }
        }
    }
    (ll, g, h)
}

/// Newton's method with step halving (the objective never decreases), from `theta` until the
/// step is negligible, no step improves, or `stop` says so; where `flat(θ)` holds, also once an
/// accepted step did not raise the objective (near a maximum as flat in one direction as ln α
/// at a tiny α, Newton's step there is rounding noise and never gets small). Returns θ, the
/// objective there and the iterations used.
fn maximize(
    mut theta: Vec<f64>,
    eval: impl Fn(&[f64]) -> Objective,
    stop: impl Fn(&[f64]) -> bool,
    flat: impl Fn(&[f64]) -> bool,
) -> Result<(Vec<f64>, Objective, usize), StatsError> {
    let p = theta.len();
    let mut cur = eval(&theta);
    let mut iterations = 0;
    for it in 0..200 {
        iterations = it + 1;
        let Some(inv) = invert(&cur.2, p) else {
            return Err(StatsError::NoConvergence(
                "singular Hessian (collinear design?)".into(),
            ));
        };
        let step: Vec<f64> = (0..p)
            .map(|i| -(0..p).map(|j| inv[i * p + j] * cur.1[j]).sum::<f64>())
            .collect();
        let mut t = 1.0;
        let mut accepted = false;
        let mut gained = false;
        for _ in 0..40 {
            let next: Vec<f64> = theta.iter().zip(&step).map(|(a, s)| a + t * s).collect();
            let cand = eval(&next);
            if cand.0.is_finite() && cand.0 >= cur.0 - 1e-12 * cur.0.abs() {
                gained = cand.0 > cur.0;
                theta = next;
                cur = cand;
                accepted = true;
                break;
            }
            t *= 0.5;
        }
        let max_step = step.iter().fold(0.0f64, |m, s| m.max((t * s).abs()));
        if !accepted || (!gained && flat(&theta)) || max_step < 1e-10 || stop(&theta) {
            break;
        }
    }
    Ok((theta, cur, iterations))
}

/// The cluster-robust sandwich H⁻¹ (Σ_g s_g s_gᵀ) H⁻¹ · G/(G-1) · (N-1)/(N-K) over `p`
/// parameters, with `score(i, out)` writing observation i's score (p values) and K =
/// `k_factor` the parameter count of the small-sample factor (p, or p + 1 for a Poisson fit
/// standing in for NB2 at α = 0).
fn clustered_cov(
    h_inv: &[f64],
    p: usize,
    k_factor: usize,
    n: usize,
    clusters: &[usize],
    score: impl Fn(usize, &mut [f64]),
) -> Result<Vec<f64>, StatsError> {
    if clusters.len() != n {
        return Err(StatsError::Undefined(format!(
            "{} cluster ids for {n} observations",
            clusters.len()
        )));
    }
    let n_groups = clusters.iter().max().map_or(0, |m| m + 1);
    let mut sums = vec![0.0; n_groups * p];
    let mut si = vec![0.0; p];
    for (i, &c) in clusters.iter().enumerate() {
        score(i, &mut si);
        sums[c * p..(c + 1) * p]
            .iter_mut()
            .zip(&si)
            .for_each(|(a, b)| *a += b);
    }
    let used: Vec<usize> = (0..n_groups).filter(|c| clusters.contains(c)).collect();
    let g = used.len() as f64;
    if g < 2.0 {
        return Err(StatsError::Undefined(
            "clustered errors need at least two clusters".into(),
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
    let factor = g / (g - 1.0) * ((n as f64 - 1.0) / (n as f64 - k_factor as f64));
    Ok(matmul(&matmul(h_inv, &meat, p), h_inv, p)
        .into_iter()
        .map(|v| v * factor)
        .collect())
}

/// Covariance of an optimum: -H⁻¹, or the clustered sandwich (small-sample factor with K =
/// `k_factor` parameters).
fn covariance(
    h: &[f64],
    p: usize,
    k_factor: usize,
    n: usize,
    clusters: Option<&[usize]>,
    score: impl Fn(usize, &mut [f64]),
) -> Result<Vec<f64>, StatsError> {
    let h_inv = invert(h, p)
        .ok_or_else(|| StatsError::NoConvergence("singular Hessian at the optimum".into()))?;
    match clusters {
        None => Ok(h_inv.iter().map(|v| -v).collect()),
        Some(c) => clustered_cov(&h_inv, p, k_factor, n, c, score),
    }
}

/// Below this the first Newton path is taken to be heading for the boundary α = 0, where the
/// score at α = 0 decides (module docs).
const ALPHA_BOUNDARY: f64 = 1e-6;

/// Below this a search for an interior maximum has found none: the dispersion is 0 to within
/// what lnΓ(1/α) resolves in double precision (its cancellation error reaches the likelihood's
/// differences there).
const ALPHA_FLOOR: f64 = 1e-10;

/// Starting coefficients: the intercept at ln(mean y) when the first column is constant.
fn start_beta(x: &[f64], k: usize, ybar: f64) -> Vec<f64> {
    let mut beta = vec![0.0; k];
    if x.chunks(k).all(|r| r[0] == x[0]) {
        beta[0] = ybar.ln() / x[0];
    }
    beta
}

/// Poisson regression (NB2 at α = 0); α is reported as 0 with an undefined standard error.
fn fit_poisson(
    y: &[f64],
    x: &[f64],
    k: usize,
    clusters: Option<&[usize]>,
) -> Result<Nb2Fit, StatsError> {
    let ybar = y.iter().sum::<f64>() / y.len() as f64;
    let (beta, (llf, _, h), iterations) = maximize(
        start_beta(x, k, ybar),
        |b| poisson_totals(y, x, b),
        |_| false,
        |_| false,
    )?;
    // K = k + 1: α stays a parameter, as in statsmodels' NegativeBinomial (module docs).
    let cov_b = covariance(&h, k, k + 1, y.len(), clusters, |i, out| {
        let row = &x[i * k..(i + 1) * k];
        let mu = mean_at(row, &beta);
        out.iter_mut()
            .zip(row)
            .for_each(|(o, r)| *o = (y[i] - mu) * r);
    })?;
    let p = k + 1;
    let mut cov = vec![f64::NAN; p * p];
    for a in 0..k {
        cov[a * p..a * p + k].copy_from_slice(&cov_b[a * k..(a + 1) * k]);
    }
    Ok(Nb2Fit::assemble(beta, 0.0, cov, llf, iterations))
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
    // Start: α by the method of moments; optimise θ = (β, ln α), which keeps α > 0.
    let var = y.iter().map(|v| (v - ybar).powi(2)).sum::<f64>() / (n as f64 - 1.0).max(1.0);
    let alpha0 = ((var - ybar) / (ybar * ybar)).clamp(0.05, 10.0);
    let mut theta0 = start_beta(x, k, ybar);
    theta0.push(alpha0.ln());
    let in_log_alpha = |theta: &[f64]| -> Objective {
        let alpha = theta[k].exp();
        let (ll, mut g, mut h) = nb2_totals(y, x, &theta[..k], alpha);
        // Chain rule for ln α: g' = α g, H' = α² H + α g on the diagonal, α H off it.
        let ga = g[k];
        g[k] *= alpha;
        for i in 0..k {
            h[i * p + k] *= alpha;
            h[k * p + i] *= alpha;
        }
        h[k * p + k] = alpha * alpha * h[k * p + k] + alpha * ga;
        (ll, g, h)
    };
    let (theta, _, iterations) = maximize(
        theta0,
        in_log_alpha,
        |t| t[k].exp() < ALPHA_BOUNDARY,
        |t| t[k].exp() * SUMMED_ABOVE_R <= 1.0,
    )
    .map_err(|e| StatsError::NoConvergence(format!("nb2: {e}")))?;
    let first = (theta[k].exp() >= ALPHA_BOUNDARY)
        .then(|| interior_fit(y, x, k, clusters, &theta, iterations));
    let stalled = match first {
        Some(Ok(fit)) => return Ok(fit),
        Some(Err(e)) => Some(e),
        None => None,
    };
    // The path went for the boundary, or stalled on the way (far from the maximum Newton's
    // direction in (β, ln α) need not rise): the score of α at 0 says where the maximum is, and
    // the moment estimate at the Poisson fit starts near it.
    let poisson = match fit_poisson(y, x, k, clusters) {
        Ok(poisson) => poisson,
        Err(e) => return Err(stalled.unwrap_or(e)),
    };
    let Some(alpha_small) = overdispersion_moment(y, x, &poisson.params[..k]) else {
        // The maximum is on the boundary; a path that stalled inside found no other.
        return match stalled {
            Some(e) => Err(e),
            None => Ok(poisson),
        };
    };
    let mut start = poisson.params[..k].to_vec();
    start.push(alpha_small.ln());
    let (theta, _, more) = maximize(start, in_log_alpha, |t| t[k].exp() < ALPHA_FLOOR, |_| true)
        .map_err(|e| StatsError::NoConvergence(format!("nb2: {e}")))?;
    if theta[k].exp() < ALPHA_FLOOR {
        return Ok(poisson);
    }
    interior_fit(y, x, k, clusters, &theta, iterations + more)
}

/// The moment estimate Σ [(y - μ)² - y] / Σ μ² of α at the Poisson fit `beta`, when the score
/// of α at 0, ½ Σ [(y - μ)² - y], is positive (the maximum is inside); `None` when it is not
/// (the maximum is on the boundary).
fn overdispersion_moment(y: &[f64], x: &[f64], beta: &[f64]) -> Option<f64> {
    let k = beta.len();
    let (mut excess, mut mu2) = (0.0, 0.0);
    for (i, &yi) in y.iter().enumerate() {
        let row = &x[i * k..(i + 1) * k];
        let mu = mean_at(row, beta);
        excess += (yi - mu) * (yi - mu) - yi;
        mu2 += mu * mu;
    }
    (excess > 0.0 && mu2 > 0.0).then(|| (excess / mu2).max(ALPHA_FLOOR))
}

/// The NB2 fit at an interior optimum `theta` = (β, ln α): checks that the gradient vanishes in
/// (β, α) and computes the covariance there.
fn interior_fit(
    y: &[f64],
    x: &[f64],
    k: usize,
    clusters: Option<&[usize]>,
    theta: &[f64],
    iterations: usize,
) -> Result<Nb2Fit, StatsError> {
    let (n, p) = (y.len(), k + 1);
    let (beta, alpha) = (&theta[..k], theta[k].exp());
    let (llf, g, h) = nb2_totals(y, x, beta, alpha);
    let gmax = g.iter().fold(0.0f64, |m, v| m.max(v.abs()));
    if gmax.is_nan() || gmax >= 1e-4 * n as f64 {
        return Err(StatsError::NoConvergence(format!(
            "nb2: no convergence (gradient {gmax:e}); the maximum-likelihood estimate may not exist, e.g. when one covariate value has only zero counts"
        )));
    }
    let cov = covariance(&h, p, p, n, clusters, |i, out| {
        obs_terms(
            y[i],
            &x[i * k..(i + 1) * k],
            beta,
            alpha,
            out,
            &mut [],
            false,
        );
    })
    .map_err(|e| StatsError::NoConvergence(format!("nb2: {e}")))?;
    Ok(Nb2Fit::assemble(beta.to_vec(), alpha, cov, llf, iterations))
}
