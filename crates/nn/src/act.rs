//! Activations.

use serde::{Deserialize, Serialize};

/// A hidden-layer activation.
#[derive(Debug, Clone, Copy, PartialEq, Serialize, Deserialize)]
#[serde(rename_all = "snake_case")]
pub enum Activation {
    /// Hyperbolic tangent (fast rational approximation, see [`tanh_fast`]).
    Tanh,
    /// Leaky ReLU with the given negative slope.
    LeakyRelu(f32),
}

/// tanh by a rational (continued-fraction) approximation, clamped to [-1, 1]: the standard
/// library's `tanh` is the bottleneck of small MLPs, while this one is a few multiplies and a
/// division that the compiler vectorises. Absolute error below 2e-4 everywhere (tested).
#[inline]
pub fn tanh_fast(x: f32) -> f32 {
    let x = x.clamp(-5.0, 5.0);
    let x2 = x * x;
    let p = x * (135_135.0 + x2 * (17_325.0 + x2 * (378.0 + x2)));
    let q = 135_135.0 + x2 * (62_370.0 + x2 * (3_150.0 + 28.0 * x2));
    (p / q).clamp(-1.0, 1.0)
}

impl Activation {
    /// Applies the activation in place.
    #[inline]
    pub fn apply(self, v: &mut [f32]) {
        match self {
            Activation::Tanh => v.iter_mut().for_each(|x| *x = tanh_fast(*x)),
            Activation::LeakyRelu(a) => v.iter_mut().for_each(|x| {
                if *x < 0.0 {
                    *x *= a
                }
            }),
        }
    }

    /// Adds `bias` to each row of `v` (rows as long as `bias`) and applies the activation, in
    /// one pass.
    #[inline]
    pub fn apply_with_bias(self, v: &mut [f32], bias: &[f32]) {
        for row in v.chunks_exact_mut(bias.len()) {
            row.iter_mut().zip(bias).for_each(|(x, b)| *x += b);
            self.apply(row);
        }
    }

    /// Multiplies `delta` by the derivative, given the activation's outputs `y`.
    #[inline]
    pub fn backprop(self, y: &[f32], delta: &mut [f32]) {
        match self {
            Activation::Tanh => delta.iter_mut().zip(y).for_each(|(d, y)| *d *= 1.0 - y * y),
            Activation::LeakyRelu(a) => delta.iter_mut().zip(y).for_each(|(d, y)| {
                if *y < 0.0 {
                    *d *= a
                }
            }),
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn fast_tanh_is_accurate() {
        let mut worst = 0.0f32;
        for i in -20_000..=20_000 {
            let x = i as f32 * 0.0005;
            worst = worst.max((tanh_fast(x) - x.tanh()).abs());
        }
        assert!(worst < 2e-4, "max error {worst}");
        assert_eq!(tanh_fast(100.0), 1.0);
        assert_eq!(tanh_fast(-100.0), -1.0);
        assert_eq!(tanh_fast(0.0), 0.0);
    }
}
