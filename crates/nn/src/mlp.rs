//! Multi-layer perceptrons: dense layers `y = act(x · W + b)`, the last one linear.
//!
//! Shapes: inputs are `batch x in` row-major; `W` of layer l is `in_l x out_l` row-major (so
//! a forward pass is one GEMM per layer, and ONNX export is a `MatMul` with the same matrix).
//! All parameters live in one flat vector, so an optimiser sees a single slice.

use crate::act::Activation;
use crate::gemm::{fma_chain_gemm, gemm, Mat, PackedMatrix, SparseRows};
use rand::Rng;
use rand_distr::{Distribution, StandardNormal};
use serde::{Deserialize, Serialize};

/// Layer sizes and activation of an MLP.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
pub struct MlpSpec {
    /// Input, hidden and output sizes, e.g. [180, 256, 256, 2].
    pub sizes: Vec<usize>,
    /// Activation after every layer but the last.
    pub hidden: Activation,
}

/// An MLP's parameters.
#[derive(Debug, Clone, PartialEq)]
pub struct Mlp {
    spec: MlpSpec,
    /// All weights and biases: for each layer, W (in x out) then b (out).
    params: Vec<f32>,
    /// Offset of each layer's W in `params` (its b follows W).
    offsets: Vec<usize>,
}

/// Activations kept by a forward pass for the backward pass; reused across calls.
#[derive(Debug, Clone, Default)]
pub struct MlpWorkspace {
    batch: usize,
    /// Output of each layer (post-activation; the last is linear).
    outs: Vec<Vec<f32>>,
    /// Backpropagated deltas, one buffer per layer.
    deltas: Vec<Vec<f32>>,
    /// A narrow output layer's W transposed (out x in), then its weight gradient (out x in).
    narrow: Vec<f32>,
    /// The first layer's input nonzeros, when it is sparse (the policy's observations), and
    /// whether the last forward pass used them.
    sparse: SparseRows,
    sparse_used: bool,
}

impl MlpWorkspace {
    /// Makes room for `batch` rows of every layer.
    fn ensure(&mut self, sizes: &[usize], batch: usize) {
        if self.outs.len() != sizes.len() - 1 || self.batch < batch {
            self.outs = sizes[1..].iter().map(|&s| vec![0.0; s * batch]).collect();
            self.deltas = sizes[1..].iter().map(|&s| vec![0.0; s * batch]).collect();
            self.batch = batch;
        }
    }
}

/// Output layers at most this wide skip `sgemm`: its 16 x 16 register tile would compute 8 to
/// 16 times the useful work for the policy's 2 and the value's 1 outputs, and it packs the whole
/// 512 x 256 input for it. Plain loops over a transposed W do these layers in one pass each
/// (about 3 % of a PPO minibatch step; `fishprobe bench train`).
const NARROW_OUT: usize = 4;

/// Σ a·b with eight partial sums (so it vectorises), added in a fixed order.
#[inline]
fn dot(a: &[f32], b: &[f32]) -> f32 {
    let mut acc = [0.0f32; 8];
    let (ca, cb) = (a.chunks_exact(8), b.chunks_exact(8));
    let tail: f32 = ca
        .remainder()
        .iter()
        .zip(cb.remainder())
        .map(|(x, y)| x * y)
        .sum();
    for (x, y) in ca.zip(cb) {
        for l in 0..8 {
            acc[l] += x[l] * y[l];
        }
    }
    let [a0, a1, a2, a3, a4, a5, a6, a7] = acc;
    ((a0 + a4) + (a1 + a5)) + ((a2 + a6) + (a3 + a7)) + tail
}

/// `wt` (out x in) = `w` (in x out) transposed.
fn transpose_into(w: &[f32], inp: usize, out: usize, wt: &mut [f32]) {
    for (k, row) in w.chunks_exact(out).enumerate().take(inp) {
        for (o, v) in row.iter().enumerate() {
            wt[o * inp + k] = *v;
        }
    }
}

impl Mlp {
    /// A network initialised as RLlib's default torch model does: each column of W drawn from
    /// N(0, 1) and scaled to norm `std` ("normc"), biases 0; hidden layers with std 1 and the
    /// output layer with `out_std` (RLlib: 0.01 for policy outputs, 1.0 for values).
    pub fn new<R: Rng>(spec: MlpSpec, out_std: f32, rng: &mut R) -> Self {
        let mut offsets = Vec::new();
        let mut n = 0;
        for w in spec.sizes.windows(2) {
            offsets.push(n);
            n += w[0] * w[1] + w[1];
        }
        let mut params = vec![0.0f32; n];
        let layers = spec.sizes.len() - 1;
        for (l, w) in spec.sizes.windows(2).enumerate() {
            let (inp, out) = (w[0], w[1]);
            let std = if l + 1 == layers { out_std } else { 1.0 };
            let wm: &mut [f32] = &mut params[offsets[l]..offsets[l] + inp * out];
            for v in wm.iter_mut() {
                *v = StandardNormal.sample(rng);
            }
            for j in 0..out {
                let norm = (0..inp)
                    .map(|i| wm[i * out + j].powi(2))
                    .sum::<f32>()
                    .sqrt()
                    .max(1e-12);
                for i in 0..inp {
                    wm[i * out + j] *= std / norm;
                }
            }
        }
        Self {
            spec,
            params,
            offsets,
        }
    }

    /// From a spec and a flat parameter vector (checked by length).
    pub fn from_params(spec: MlpSpec, params: Vec<f32>) -> Option<Self> {
        let mut m = Self {
            spec,
            params: Vec::new(),
            offsets: Vec::new(),
        };
        let mut n = 0;
        for w in m.spec.sizes.windows(2) {
            m.offsets.push(n);
            n += w[0] * w[1] + w[1];
        }
        (params.len() == n).then(|| {
            m.params = params;
            m
        })
    }

    /// The architecture.
    pub fn spec(&self) -> &MlpSpec {
        &self.spec
    }
    /// Input size.
    pub fn input_size(&self) -> usize {
        self.spec.sizes[0]
    }
    /// Output size.
    pub fn output_size(&self) -> usize {
        *self.spec.sizes.last().unwrap_or(&0)
    }
    /// Number of parameters.
    pub fn num_params(&self) -> usize {
        self.params.len()
    }
    /// All parameters.
    pub fn params(&self) -> &[f32] {
        &self.params
    }
    /// All parameters, mutable (for the optimiser).
    pub fn params_mut(&mut self) -> &mut [f32] {
        &mut self.params
    }
    /// Layer `l`'s weight (in x out) and bias.
    pub fn layer(&self, l: usize) -> (&[f32], &[f32]) {
        let (inp, out) = (self.spec.sizes[l], self.spec.sizes[l + 1]);
        let o = self.offsets[l];
        (
            &self.params[o..o + inp * out],
            &self.params[o + inp * out..o + inp * out + out],
        )
    }

    /// Forward pass for `batch` rows of `x`; returns the output (`batch x out`), kept in `ws`.
    #[allow(unsafe_code)]
    pub fn forward<'w>(&self, x: &[f32], batch: usize, ws: &'w mut MlpWorkspace) -> &'w [f32] {
        #[cfg(target_arch = "x86_64")]
        if crate::gemm::avx2_fma_supported() {
            // SAFETY: the CPU has AVX2 and FMA, checked just above.
            return unsafe { self.forward_avx2(x, batch, ws) };
        }
        self.forward_any(x, batch, ws)
    }

    /// [`Mlp::forward`] compiled for AVX2 and FMA, so that its bias, activation and
    /// narrow-layer loops run 8 floats wide instead of the default target's 4. The code is
    /// the same and Rust never fuses a multiply and an add by itself, so the results are the
    /// same bits.
    #[cfg(target_arch = "x86_64")]
    #[target_feature(enable = "avx2,fma")]
    fn forward_avx2<'w>(&self, x: &[f32], batch: usize, ws: &'w mut MlpWorkspace) -> &'w [f32] {
        self.forward_any(x, batch, ws)
    }

    #[inline(always)]
    fn forward_any<'w>(&self, x: &[f32], batch: usize, ws: &'w mut MlpWorkspace) -> &'w [f32] {
        let sizes = &self.spec.sizes;
        let layers = sizes.len() - 1;
        ws.ensure(sizes, batch);
        ws.sparse_used = false;
        for l in 0..layers {
            let (inp, out) = (sizes[l], sizes[l + 1]);
            let (w, b) = self.layer(l);
            let (input, y) = layer_io(&mut ws.outs, x, l, batch, (inp, out));
            if l + 1 == layers && out <= NARROW_OUT {
                ws.narrow.resize(2 * inp * out, 0.0);
                let wt = &mut ws.narrow[..inp * out];
                transpose_into(w, inp, out, wt);
                for (x, yr) in input.chunks_exact(inp).zip(y.chunks_exact_mut(out)) {
                    for (o, v) in yr.iter_mut().enumerate() {
                        *v = b[o] + dot(x, &wt[o * inp..(o + 1) * inp]);
                    }
                }
                break;
            }
            // A sparse input (the observations' mostly empty bins) skips its zeros.
            if l == 0 {
                ws.sparse_used = ws.sparse.build(input, batch, inp);
            }
            if l == 0 && ws.sparse_used {
                ws.sparse.mul(w, out, y);
            } else {
                gemm(
                    1.0,
                    Mat::new(input, batch, inp),
                    Mat::new(w, inp, out),
                    0.0,
                    y,
                    batch,
                    out,
                );
            }
            // x·W + b rounds as sgemm's `beta = 1` epilogue did with b preloaded (one
            // rounding of the product's f32 sum plus b), in one pass with the activation.
            finish_layer(self.spec.hidden, y, b, l + 1 == layers);
        }
        &ws.outs[layers - 1][..batch * sizes[layers]]
    }

    /// Backward pass after `forward` on the same `x`: adds the parameter gradients of
    /// `sum(dy · output)` into `grads` (length `num_params`). With `dx`, also writes the
    /// gradient with respect to the input.
    #[allow(unsafe_code)]
    pub fn backward(
        &self,
        x: &[f32],
        batch: usize,
        dy: &[f32],
        ws: &mut MlpWorkspace,
        grads: &mut [f32],
        dx: Option<&mut [f32]>,
    ) {
        #[cfg(target_arch = "x86_64")]
        if crate::gemm::avx2_fma_supported() {
            // SAFETY: the CPU has AVX2 and FMA, checked just above.
            return unsafe { self.backward_avx2(x, batch, dy, ws, grads, dx) };
        }
        self.backward_any(x, batch, dy, ws, grads, dx)
    }

    /// [`Mlp::backward`] compiled for AVX2 and FMA (see [`Mlp::forward`]'s counterpart).
    #[cfg(target_arch = "x86_64")]
    #[target_feature(enable = "avx2,fma")]
    fn backward_avx2(
        &self,
        x: &[f32],
        batch: usize,
        dy: &[f32],
        ws: &mut MlpWorkspace,
        grads: &mut [f32],
        dx: Option<&mut [f32]>,
    ) {
        self.backward_any(x, batch, dy, ws, grads, dx)
    }

    #[inline(always)]
    fn backward_any(
        &self,
        x: &[f32],
        batch: usize,
        dy: &[f32],
        ws: &mut MlpWorkspace,
        grads: &mut [f32],
        dx: Option<&mut [f32]>,
    ) {
        let sizes = &self.spec.sizes;
        let layers = sizes.len() - 1;
        ws.deltas[layers - 1][..batch * sizes[layers]]
            .copy_from_slice(&dy[..batch * sizes[layers]]);
        let mut dx = dx;
        for l in (0..layers).rev() {
            let (inp, out) = (sizes[l], sizes[l + 1]);
            let o = self.offsets[l];
            let (w, _) = self.layer(l);
            let (d_before, d_after) = ws.deltas.split_at_mut(l);
            let delta = &d_after[0][..batch * out];
            let input: &[f32] = if l == 0 {
                &x[..batch * inp]
            } else {
                &ws.outs[l - 1][..batch * inp]
            };
            let (gw, gb) = grads[o..o + inp * out + out].split_at_mut(inp * out);
            let narrow = l + 1 == layers && out <= NARROW_OUT;
            if narrow {
                // The forward pass left W transposed in the first half of `narrow`.
                let gwt = &mut ws.narrow[inp * out..2 * inp * out];
                gwt.fill(0.0);
                for (xr, dr) in input.chunks_exact(inp).zip(delta.chunks_exact(out)) {
                    for (o, d) in dr.iter().enumerate() {
                        let g = &mut gwt[o * inp..(o + 1) * inp];
                        g.iter_mut().zip(xr).for_each(|(g, x)| *g += d * x);
                    }
                }
                for (k, row) in gw.chunks_exact_mut(out).enumerate() {
                    for (o, g) in row.iter_mut().enumerate() {
                        *g += gwt[o * inp + k];
                    }
                }
            } else if l == 0 && ws.sparse_used {
                ws.sparse.t_mul_acc(delta, out, gw);
            } else {
                gemm(
                    1.0,
                    Mat::new(input, batch, inp).t(),
                    Mat::new(delta, batch, out),
                    1.0,
                    gw,
                    inp,
                    out,
                );
            }
            for row in delta.chunks_exact(out) {
                gb.iter_mut().zip(row).for_each(|(g, d)| *g += d);
            }
            // The gradient with respect to this layer's input: the previous layer's delta, or
            // `dx` at the first layer when asked for.
            let target: Option<&mut [f32]> = if l > 0 {
                Some(&mut d_before[l - 1][..batch * inp])
            } else {
                dx.as_deref_mut().map(|d| &mut d[..batch * inp])
            };
            let Some(target) = target else { continue };
            if narrow {
                let wt = &ws.narrow[..inp * out];
                for (tr, dr) in target.chunks_exact_mut(inp).zip(delta.chunks_exact(out)) {
                    tr.iter_mut()
                        .zip(&wt[..inp])
                        .for_each(|(v, w)| *v = dr[0] * w);
                    for (o, d) in dr.iter().enumerate().skip(1) {
                        let wo = &wt[o * inp..(o + 1) * inp];
                        tr.iter_mut().zip(wo).for_each(|(v, w)| *v += d * w);
                    }
                }
            } else {
                gemm(
                    1.0,
                    Mat::new(delta, batch, out),
                    Mat::new(w, inp, out).t(),
                    0.0,
                    target,
                    batch,
                    inp,
                );
            }
            if l > 0 {
                self.spec
                    .hidden
                    .backprop(&ws.outs[l - 1][..batch * inp], target);
            }
        }
    }
}

/// Layer `l`'s input (`x` for the first layer, else the previous layer's output) and output
/// buffer, `batch` rows each of `inp` and `out` floats.
#[inline(always)]
fn layer_io<'a>(
    outs: &'a mut [Vec<f32>],
    x: &'a [f32],
    l: usize,
    batch: usize,
    (inp, out): (usize, usize),
) -> (&'a [f32], &'a mut [f32]) {
    let (before, after) = outs.split_at_mut(l);
    let input = if l == 0 {
        &x[..batch * inp]
    } else {
        &before[l - 1][..batch * inp]
    };
    (input, &mut after[0][..batch * out])
}

/// Adds the bias `b` to each row of a layer's product `y`, and applies the hidden activation
/// unless it is the last (linear) layer.
#[inline(always)]
fn finish_layer(hidden: Activation, y: &mut [f32], b: &[f32], last: bool) {
    if last {
        for row in y.chunks_exact_mut(b.len()) {
            row.iter_mut().zip(b).for_each(|(v, b)| *v += b);
        }
    } else {
        hidden.apply_with_bias(y, b);
    }
}

/// An [`Mlp`] laid out for inference on a few rows at a time (the ConvNet fish: one frame's
/// fish per call): each layer's weights packed once ([`PackedMatrix`]) and multiplied by
/// [`fma_chain_gemm`], so that no weight is repacked per call and a row's output is the same
/// bits whatever the batch it comes in (one fish stepped alone or 64 in a vector
/// environment). On CPUs without AVX2 and FMA it is [`Mlp::forward`]. Inference only: a
/// changed `Mlp` needs a new `PackedMlp`.
#[derive(Debug, Clone, PartialEq)]
pub struct PackedMlp {
    mlp: Mlp,
    weights: Vec<PackedMatrix>,
}

impl PackedMlp {
    /// Packs `mlp`'s weights.
    pub fn new(mlp: &Mlp) -> Self {
        let sizes = &mlp.spec.sizes;
        let weights = (0..sizes.len() - 1)
            .map(|l| PackedMatrix::new(mlp.layer(l).0, sizes[l], sizes[l + 1]))
            .collect();
        Self {
            mlp: mlp.clone(),
            weights,
        }
    }

    /// Forward pass for `batch` rows of `x`; returns the output (`batch x out`), kept in `ws`.
    #[allow(unsafe_code)]
    pub fn forward<'w>(&self, x: &[f32], batch: usize, ws: &'w mut MlpWorkspace) -> &'w [f32] {
        #[cfg(target_arch = "x86_64")]
        if crate::gemm::avx2_fma_supported() {
            // SAFETY: the CPU has AVX2 and FMA, checked just above.
            return unsafe { self.forward_avx2(x, batch, ws) };
        }
        self.mlp.forward(x, batch, ws)
    }

    #[cfg(target_arch = "x86_64")]
    #[target_feature(enable = "avx2,fma")]
    fn forward_avx2<'w>(&self, x: &[f32], batch: usize, ws: &'w mut MlpWorkspace) -> &'w [f32] {
        let spec = &self.mlp.spec;
        let sizes = &spec.sizes;
        let layers = sizes.len() - 1;
        ws.ensure(sizes, batch);
        ws.sparse_used = false;
        for (l, w) in self.weights.iter().enumerate() {
            let (inp, out) = (sizes[l], sizes[l + 1]);
            let b = self.mlp.layer(l).1;
            let (input, y) = layer_io(&mut ws.outs, x, l, batch, (inp, out));
            fma_chain_gemm(input, w, y, batch);
            finish_layer(spec.hidden, y, b, l + 1 == layers);
        }
        &ws.outs[layers - 1][..batch * sizes[layers]]
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use rand::SeedableRng;

    #[test]
    fn packed_forward_is_the_forward_pass_and_independent_of_the_batch() {
        let mut rng = rand_xoshiro::Xoshiro256PlusPlus::seed_from_u64(3);
        let net = Mlp::new(
            MlpSpec {
                sizes: vec![40, 32, 24, 37],
                hidden: Activation::LeakyRelu(0.01),
            },
            1.0,
            &mut rng,
        );
        let batch = 9;
        let x: Vec<f32> = (0..batch * 40)
            .map(|i| ((i * 29) % 83) as f32 / 40.0 - 1.0)
            .collect();
        let mut ws = MlpWorkspace::default();
        let reference = net.forward(&x, batch, &mut ws).to_vec();
        let packed = PackedMlp::new(&net);
        let rows = packed.forward(&x, batch, &mut ws).to_vec();
        for (a, b) in reference.iter().zip(&rows) {
            assert!((a - b).abs() < 1e-5 * (1.0 + a.abs()), "{a} vs {b}");
        }
        for i in 0..batch {
            let one = packed.forward(&x[i * 40..(i + 1) * 40], 1, &mut ws);
            assert!(
                one.iter()
                    .zip(&rows[i * 37..(i + 1) * 37])
                    .all(|(a, b)| a.to_bits() == b.to_bits()),
                "row {i}"
            );
        }
    }
}
