//! Multi-layer perceptrons: dense layers `y = act(x · W + b)`, the last one linear.
//!
//! Shapes: inputs are `batch x in` row-major; `W` of layer l is `in_l x out_l` row-major (so
//! a forward pass is one GEMM per layer, and ONNX export is a `MatMul` with the same matrix).
//! All parameters live in one flat vector, so an optimiser sees a single slice.

use crate::act::Activation;
use crate::gemm::{gemm, Mat};
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
    pub fn forward<'w>(&self, x: &[f32], batch: usize, ws: &'w mut MlpWorkspace) -> &'w [f32] {
        let sizes = &self.spec.sizes;
        let layers = sizes.len() - 1;
        if ws.outs.len() != layers || ws.batch < batch {
            ws.outs = sizes[1..].iter().map(|&s| vec![0.0; s * batch]).collect();
            ws.deltas = sizes[1..].iter().map(|&s| vec![0.0; s * batch]).collect();
            ws.batch = batch;
        }
        for l in 0..layers {
            let (inp, out) = (sizes[l], sizes[l + 1]);
            let (w, b) = self.layer(l);
            let (before, after) = ws.outs.split_at_mut(l);
            let input: &[f32] = if l == 0 {
                &x[..batch * inp]
            } else {
                &before[l - 1][..batch * inp]
            };
            let y = &mut after[0][..batch * out];
            for row in y.chunks_exact_mut(out) {
                row.copy_from_slice(b);
            }
            gemm(
                1.0,
                Mat::new(input, batch, inp),
                Mat::new(w, inp, out),
                1.0,
                y,
                batch,
                out,
            );
            if l + 1 < layers {
                self.spec.hidden.apply(y);
            }
        }
        &ws.outs[layers - 1][..batch * sizes[layers]]
    }

    /// Backward pass after `forward` on the same `x`: adds the parameter gradients of
    /// `sum(dy · output)` into `grads` (length `num_params`). With `dx`, also writes the
    /// gradient with respect to the input.
    pub fn backward(
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
            gemm(
                1.0,
                Mat::new(input, batch, inp).t(),
                Mat::new(delta, batch, out),
                1.0,
                gw,
                inp,
                out,
            );
            for row in delta.chunks_exact(out) {
                gb.iter_mut().zip(row).for_each(|(g, d)| *g += d);
            }
            if l > 0 {
                let prev = &mut d_before[l - 1][..batch * inp];
                gemm(
                    1.0,
                    Mat::new(delta, batch, out),
                    Mat::new(w, inp, out).t(),
                    0.0,
                    prev,
                    batch,
                    inp,
                );
                self.spec
                    .hidden
                    .backprop(&ws.outs[l - 1][..batch * inp], prev);
            } else if let Some(dx) = dx.as_deref_mut() {
                gemm(
                    1.0,
                    Mat::new(delta, batch, out),
                    Mat::new(w, inp, out).t(),
                    0.0,
                    &mut dx[..batch * inp],
                    batch,
                    inp,
                );
            }
        }
    }
}
