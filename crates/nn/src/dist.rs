//! Losses and distributions with their gradients.

/// ln(2π) / 2.
const HALF_LN_2PI: f32 = 0.918_938_5;

/// Log-density of x under N(mean, exp(log_std)²), one dimension.
#[inline]
pub fn gaussian_log_prob(x: f32, mean: f32, log_std: f32) -> f32 {
    let z = (x - mean) * (-log_std).exp();
    -0.5 * z * z - log_std - HALF_LN_2PI
}

/// Gradients of [`gaussian_log_prob`] with respect to (mean, log_std).
#[inline]
pub fn gaussian_log_prob_grad(x: f32, mean: f32, log_std: f32) -> (f32, f32) {
    let inv_var = (-2.0 * log_std).exp();
    let d = x - mean;
    (d * inv_var, d * d * inv_var - 1.0)
}

/// Entropy of N(·, exp(log_std)²), one dimension; its gradient with respect to log_std is 1.
#[inline]
pub fn gaussian_entropy(log_std: f32) -> f32 {
    log_std + 0.5 + HALF_LN_2PI
}

/// KL(old ‖ new) between one-dimensional Gaussians.
#[inline]
pub fn gaussian_kl(mean_old: f32, log_std_old: f32, mean_new: f32, log_std_new: f32) -> f32 {
    let var_old = (2.0 * log_std_old).exp();
    let var_new = (2.0 * log_std_new).exp();
    log_std_new - log_std_old + (var_old + (mean_old - mean_new).powi(2)) / (2.0 * var_new) - 0.5
}

/// Gradients of [`gaussian_kl`] with respect to (mean_new, log_std_new).
#[inline]
pub fn gaussian_kl_grad(
    mean_old: f32,
    log_std_old: f32,
    mean_new: f32,
    log_std_new: f32,
) -> (f32, f32) {
    let var_old = (2.0 * log_std_old).exp();
    let inv_var_new = (-2.0 * log_std_new).exp();
    let d = mean_new - mean_old;
    (d * inv_var_new, 1.0 - (var_old + d * d) * inv_var_new)
}

/// Mean softmax cross-entropy of `logits` (`batch x classes`) against class `targets`; writes
/// the gradient with respect to the logits into `grad` (already divided by the batch).
pub fn softmax_cross_entropy(
    logits: &[f32],
    classes: usize,
    targets: &[usize],
    grad: &mut [f32],
) -> f32 {
    let batch = targets.len();
    let mut loss = 0.0f64;
    for ((row, g), &t) in logits
        .chunks_exact(classes)
        .zip(grad.chunks_exact_mut(classes))
        .zip(targets)
    {
        let max = row.iter().copied().fold(f32::NEG_INFINITY, f32::max);
        let mut sum = 0.0f32;
        for (gi, &z) in g.iter_mut().zip(row) {
            *gi = (z - max).exp();
            sum += *gi;
        }
        loss += f64::from(sum.ln() + max - row[t]);
        for gi in g.iter_mut() {
            *gi /= sum * batch as f32;
        }
        g[t] -= 1.0 / batch as f32;
    }
    (loss / batch as f64) as f32
}

/// Softmax of one row in place.
pub fn softmax_in_place(row: &mut [f32]) {
    let max = row.iter().copied().fold(f32::NEG_INFINITY, f32::max);
    let mut sum = 0.0;
    for z in row.iter_mut() {
        *z = (*z - max).exp();
        sum += *z;
    }
    row.iter_mut().for_each(|z| *z /= sum);
}

#[cfg(test)]
mod tests {
    use super::*;

    fn fd(f: impl Fn(f64) -> f64, x: f64) -> f64 {
        let h = 1e-3;
        (f(x + h) - f(x - h)) / (2.0 * h)
    }

    #[test]
    fn gaussian_known_values_and_gradients() {
        // scipy.stats.norm(0.5, 2).logpdf(1.5) = -1.7370857137646178
        assert!((gaussian_log_prob(1.5, 0.5, 2f32.ln()) - (-1.737_085_7)).abs() < 1e-5);
        // entropy of N(., 2²) = 0.5 ln(2πe·4) = 2.1120857137646178
        assert!((gaussian_entropy(2f32.ln()) - 2.112_085_7).abs() < 1e-5);
        let (x, m, s) = (0.3f32, -0.2f32, 0.4f32);
        let (gm, gs) = gaussian_log_prob_grad(x, m, s);
        let num_m = fd(
            |v| f64::from(gaussian_log_prob(x, v as f32, s)),
            f64::from(m),
        );
        let num_s = fd(
            |v| f64::from(gaussian_log_prob(x, m, v as f32)),
            f64::from(s),
        );
        assert!((f64::from(gm) - num_m).abs() < 1e-3 && (f64::from(gs) - num_s).abs() < 1e-3);
        let (km, ks) = gaussian_kl_grad(0.1, -0.3, 0.4, 0.2);
        let num_km = fd(|v| f64::from(gaussian_kl(0.1, -0.3, v as f32, 0.2)), 0.4);
        let num_ks = fd(|v| f64::from(gaussian_kl(0.1, -0.3, 0.4, v as f32)), 0.2);
        assert!((f64::from(km) - num_km).abs() < 1e-3 && (f64::from(ks) - num_ks).abs() < 1e-3);
        assert!(gaussian_kl(0.3, 0.1, 0.3, 0.1).abs() < 1e-7);
    }

    #[test]
    fn cross_entropy_value_and_gradient() {
        let logits = [1.0f32, 2.0, 0.5, -1.0, 0.0, 3.0];
        let mut g = [0.0f32; 6];
        let loss = softmax_cross_entropy(&logits, 3, &[1, 2], &mut g);
        // Row 0: ln(e + e² + e^0.5) - 2 = 0.4643688; row 1: ln(e^-1 + 1 + e³) - 3 = 0.0658838.
        assert!(
            (loss - (0.464_368_8 + 0.065_883_8) / 2.0).abs() < 1e-5,
            "{loss}"
        );
        for i in 0..6 {
            let num = fd(
                |v| {
                    let mut l = logits;
                    l[i] = v as f32;
                    f64::from(softmax_cross_entropy(&l, 3, &[1, 2], &mut [0.0; 6]))
                },
                f64::from(logits[i]),
            );
            assert!((f64::from(g[i]) - num).abs() < 1e-3, "logit {i}");
        }
    }
}
