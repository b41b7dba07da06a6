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

/// e^x to within 2 units in the last place, in a form the compiler vectorises (the standard
/// library's `exp` is a call per element): x = n ln 2 + r with |r| ≤ ln 2 / 2, e^r by Cephes'
/// `expf` polynomial, 2^n put into the exponent bits. Inputs are clamped to [-87, 88], so the
/// result is always a positive normal float (e^-87 ≈ 1.6e-38 stands for anything smaller).
#[inline(always)]
pub fn exp_fast(x: f32) -> f32 {
    // ln 2 split into a part exact in few bits and the rest (Cody-Waite), so n · LN2_HI is exact.
    const LN2_HI: f32 = 0.693_359_4;
    const LN2_LO: f32 = -2.121_944_4e-4;
    // Adding and subtracting 1.5 · 2^23 rounds to the nearest integer (ties to even).
    const ROUND: f32 = 12_582_912.0;
    let x = x.clamp(-87.0, 88.0);
    let t = x * std::f32::consts::LOG2_E + ROUND;
    let n = t - ROUND;
    // n as an integer: the low bits of t's mantissa (integer operations only, so that the
    // loop stays vectorised; `as i32` would saturate element by element).
    let k = t.to_bits().wrapping_sub(ROUND.to_bits());
    let r = (x - n * LN2_HI) - n * LN2_LO;
    let p = 1.987_569_1e-4;
    let p = p * r + 1.398_199_9e-3;
    let p = p * r + 8.333_452e-3;
    let p = p * r + 4.166_579_6e-2;
    let p = p * r + 1.666_666_5e-1;
    let p = p * r + 0.5;
    let e = p * r * r + r + 1.0;
    e * f32::from_bits(k.wrapping_add(127) << 23)
}

/// Softmax of each `cells`-long row of `logits`, written to the same row of `out` (the
/// ConvNet fish's distribution over its (v, ω) grid, at every frame for every fish: the hot
/// loop of training against M_ConvNet). Uses [`exp_fast`] and eight partial sums and maxima,
/// so that it runs 8 floats wide (AVX2 where the CPU has it); the probabilities agree with an
/// exact softmax to a few units in the last place.
///
/// # Panics
/// When `out` is shorter than `logits` (a programming error).
#[allow(unsafe_code)]
pub fn softmax_rows(logits: &[f32], out: &mut [f32], cells: usize) {
    assert!(out.len() >= logits.len(), "softmax output too short");
    #[cfg(target_arch = "x86_64")]
    if crate::gemm::avx2_fma_supported() {
        // SAFETY: the CPU has AVX2 and FMA, checked just above.
        return unsafe { softmax_rows_avx2(logits, out, cells) };
    }
    softmax_rows_any(logits, out, cells)
}

/// [`softmax_rows`] compiled for AVX2 and FMA.
#[cfg(target_arch = "x86_64")]
#[target_feature(enable = "avx2,fma")]
fn softmax_rows_avx2(logits: &[f32], out: &mut [f32], cells: usize) {
    softmax_rows_any(logits, out, cells)
}

#[inline(always)]
fn softmax_rows_any(logits: &[f32], out: &mut [f32], cells: usize) {
    const LANES: usize = 8;
    for (row, p) in logits.chunks_exact(cells).zip(out.chunks_exact_mut(cells)) {
        let mut top = [f32::NEG_INFINITY; LANES];
        let mut chunks = row.chunks_exact(LANES);
        for c in &mut chunks {
            for (t, &z) in top.iter_mut().zip(c) {
                *t = if z > *t { z } else { *t };
            }
        }
        let max = chunks
            .remainder()
            .iter()
            .chain(&top)
            .copied()
            .fold(f32::NEG_INFINITY, f32::max);
        let mut sums = [0.0f32; LANES];
        let mut zs = row.chunks_exact(LANES);
        let mut ps = p.chunks_exact_mut(LANES);
        for (c, q) in (&mut zs).zip(&mut ps) {
            for ((s, y), &z) in sums.iter_mut().zip(q).zip(c) {
                *y = exp_fast(z - max);
                *s += *y;
            }
        }
        let mut sum: f32 = sums.iter().sum();
        for (y, &z) in ps.into_remainder().iter_mut().zip(zs.remainder()) {
            *y = exp_fast(z - max);
            sum += *y;
        }
        let inv = 1.0 / sum;
        p.iter_mut().for_each(|y| *y *= inv);
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    fn fd(f: impl Fn(f64) -> f64, x: f64) -> f64 {
        let h = 1e-3;
        (f(x + h) - f(x - h)) / (2.0 * h)
    }

    #[test]
    fn fast_exp_is_within_two_ulp() {
        let mut worst = 0.0f64;
        let mut x = -87.0f32;
        while x <= 88.0 {
            let exact = f64::from(x).exp();
            worst = worst.max((f64::from(exp_fast(x)) - exact).abs() / exact);
            x += 0.000_37;
        }
        // two units in the last place of an f32 are 2^-22 ≈ 2.4e-7 relative at worst
        assert!(worst < 2.4e-7, "max relative error {worst}");
        assert_eq!(exp_fast(0.0), 1.0);
        assert!(exp_fast(-1e9) > 0.0 && exp_fast(-1e9) < 2e-38);
        assert!(exp_fast(1e9).is_finite());
    }

    #[test]
    fn fast_softmax_matches_the_exact_one() {
        let cells = 1025; // the ConvNet grid: not a multiple of 8
        let rows: Vec<f32> = (0..3 * cells)
            .map(|i| ((i * 7919) % 1000) as f32 * 0.03 - 20.0)
            .collect();
        let mut fast = vec![f32::NAN; rows.len()];
        softmax_rows(&rows, &mut fast, cells);
        for (row, p) in rows.chunks_exact(cells).zip(fast.chunks_exact(cells)) {
            let max = row.iter().copied().fold(f32::NEG_INFINITY, f32::max);
            let sum: f64 = row.iter().map(|&z| f64::from(z - max).exp()).sum();
            for (&z, &q) in row.iter().zip(p) {
                let exact = f64::from(z - max).exp() / sum;
                assert!(
                    (f64::from(q) - exact).abs() <= 1e-6 * exact,
                    "{q} vs {exact}"
                );
            }
            let total: f32 = p.iter().sum();
            assert!((total - 1.0).abs() < 1e-5);
        }
        // the portable and the AVX2 copy compute the same bits
        let mut any = vec![f32::NAN; rows.len()];
        softmax_rows_any(&rows, &mut any, cells);
        assert_eq!(any, fast);
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
