//! One-dimensional convolution with circular padding, for inputs whose positions are angular
//! bins around the animal (the last bin neighbours the first).
//!
//! Shapes: input `batch x c_in x len`, kernel `c_out x c_in x k` (k odd), bias `c_out`,
//! output `batch x c_out x len`; `out[o][t] = b[o] + Σ_i Σ_j w[o][i][j] · in[i][(t + j - k/2) mod len]`.

use crate::act::Activation;
use rand::Rng;
use rand_distr::{Distribution, StandardNormal};

/// Kernel tap j of a kernel centred on `half` reads the input `shift_of(j, half, len)`
/// positions ahead, wrapped: (j - half) mod len.
fn shift_of(j: usize, half: usize, len: usize) -> usize {
    (j + len - half % len) % len
}

/// A circular 1-D convolution's parameters.
#[derive(Debug, Clone, PartialEq)]
pub struct Conv1d {
    /// Input channels.
    pub c_in: usize,
    /// Output channels.
    pub c_out: usize,
    /// Kernel width (odd).
    pub k: usize,
    /// Weights (`c_out x c_in x k`) then biases (`c_out`).
    pub params: Vec<f32>,
}

impl Conv1d {
    /// He-style initialisation: N(0, 2 / (c_in · k)), zero bias.
    pub fn new<R: Rng>(c_in: usize, c_out: usize, k: usize, rng: &mut R) -> Self {
        assert!(k % 2 == 1, "kernel width must be odd");
        let std = (2.0 / (c_in * k) as f32).sqrt();
        let mut params: Vec<f32> = (0..c_out * c_in * k)
            .map(|_| {
                let z: f32 = StandardNormal.sample(rng);
                std * z
            })
            .collect();
        params.extend(std::iter::repeat_n(0.0, c_out));
        Self {
            c_in,
            c_out,
            k,
            params,
        }
    }

    fn split(&self) -> (&[f32], &[f32]) {
        self.params.split_at(self.c_out * self.c_in * self.k)
    }

    /// Forward pass into `out` (`batch x c_out x len`).
    pub fn forward(&self, x: &[f32], batch: usize, len: usize, out: &mut [f32]) {
        self.forward_activated(x, batch, len, out, None);
    }

    /// Forward pass into `out`, then `activation` applied to it, in one AVX2-compiled pass
    /// where the CPU has AVX2 (the loops run 8 floats wide instead of 4; Rust never fuses a
    /// multiply and an add by itself, so the results are the same bits as the portable code's).
    #[allow(unsafe_code)]
    pub fn forward_activated(
        &self,
        x: &[f32],
        batch: usize,
        len: usize,
        out: &mut [f32],
        activation: Option<Activation>,
    ) {
        #[cfg(target_arch = "x86_64")]
        if crate::gemm::avx2_fma_supported() {
            // SAFETY: the CPU has AVX2 and FMA, checked just above.
            return unsafe { self.forward_avx2(x, batch, len, out, activation) };
        }
        self.forward_any(x, batch, len, out, activation)
    }

    #[cfg(target_arch = "x86_64")]
    #[target_feature(enable = "avx2,fma")]
    fn forward_avx2(
        &self,
        x: &[f32],
        batch: usize,
        len: usize,
        out: &mut [f32],
        activation: Option<Activation>,
    ) {
        self.forward_any(x, batch, len, out, activation)
    }

    #[inline(always)]
    fn forward_any(
        &self,
        x: &[f32],
        batch: usize,
        len: usize,
        out: &mut [f32],
        activation: Option<Activation>,
    ) {
        let (w, b) = self.split();
        let half = self.k / 2;
        for n in 0..batch {
            let xin = &x[n * self.c_in * len..(n + 1) * self.c_in * len];
            let y = &mut out[n * self.c_out * len..(n + 1) * self.c_out * len];
            for o in 0..self.c_out {
                let yo = &mut y[o * len..(o + 1) * len];
                yo.fill(b[o]);
                for i in 0..self.c_in {
                    let xi = &xin[i * len..(i + 1) * len];
                    for j in 0..self.k {
                        let wv = w[(o * self.c_in + i) * self.k + j];
                        // Source index t + j - half, wrapped: the output's first len - shift
                        // positions read xi[shift..], the rest xi[..shift] (no division per
                        // element, so the loops vectorise; same operations in the same order).
                        let (head, tail) = yo.split_at_mut(len - shift_of(j, half, len));
                        let (x_tail, x_head) = xi.split_at(len - head.len());
                        for (yt, xv) in head.iter_mut().zip(x_head) {
                            *yt += wv * xv;
                        }
                        for (yt, xv) in tail.iter_mut().zip(x_tail) {
                            *yt += wv * xv;
                        }
                    }
                }
            }
        }
        if let Some(a) = activation {
            a.apply(&mut out[..batch * self.c_out * len]);
        }
    }

    /// Adds the parameter gradients of `sum(dy · out)` into `grads`, and writes the input
    /// gradient into `dx` when given.
    pub fn backward(
        &self,
        x: &[f32],
        batch: usize,
        len: usize,
        dy: &[f32],
        grads: &mut [f32],
        mut dx: Option<&mut [f32]>,
    ) {
        let (w, _) = self.split();
        let nw = self.c_out * self.c_in * self.k;
        let half = self.k / 2;
        if let Some(d) = dx.as_deref_mut() {
            d[..batch * self.c_in * len].fill(0.0);
        }
        for n in 0..batch {
            let xin = &x[n * self.c_in * len..(n + 1) * self.c_in * len];
            let dyn_ = &dy[n * self.c_out * len..(n + 1) * self.c_out * len];
            for o in 0..self.c_out {
                let d = &dyn_[o * len..(o + 1) * len];
                grads[nw + o] += d.iter().sum::<f32>();
                for i in 0..self.c_in {
                    let xi = &xin[i * len..(i + 1) * len];
                    for j in 0..self.k {
                        let shift = shift_of(j, half, len);
                        let idx = (o * self.c_in + i) * self.k + j;
                        // As in `forward`: position t reads (t + shift) mod len.
                        let (d_head, d_tail) = d.split_at(len - shift);
                        let (x_tail, x_head) = xi.split_at(shift);
                        grads[idx] += d_head
                            .iter()
                            .zip(x_head)
                            .chain(d_tail.iter().zip(x_tail))
                            .map(|(dv, xv)| dv * xv)
                            .sum::<f32>();
                        if let Some(dxv) = dx.as_deref_mut() {
                            let dxi =
                                &mut dxv[(n * self.c_in + i) * len..(n * self.c_in + i + 1) * len];
                            let (dx_tail, dx_head) = dxi.split_at_mut(shift);
                            for (dxt, dv) in dx_head
                                .iter_mut()
                                .zip(d_head)
                                .chain(dx_tail.iter_mut().zip(d_tail))
                            {
                                *dxt += w[idx] * dv;
                            }
                        }
                    }
                }
            }
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use rand::SeedableRng;

    #[test]
    fn the_avx2_copy_gives_the_same_bits() {
        let mut rng = rand_xoshiro::Xoshiro256PlusPlus::seed_from_u64(5);
        let conv = Conv1d::new(3, 8, 5, &mut rng);
        let (batch, len) = (3, 72);
        let x: Vec<f32> = (0..batch * 3 * len)
            .map(|i| ((i * 31) % 89) as f32 / 44.0 - 1.0)
            .collect();
        let mut fast = vec![0.0; batch * 8 * len];
        let mut plain = fast.clone();
        let act = Some(Activation::LeakyRelu(0.01));
        conv.forward_activated(&x, batch, len, &mut fast, act);
        conv.forward_any(&x, batch, len, &mut plain, None);
        Activation::LeakyRelu(0.01).apply(&mut plain);
        assert!(fast
            .iter()
            .zip(&plain)
            .all(|(a, b)| a.to_bits() == b.to_bits()));
    }
}
