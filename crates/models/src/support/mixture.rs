//! The `gmm` estimator: a diagonal Gaussian mixture fitted by EM.

use super::FEATURES;
use fishprobe_sim::SimRng;
use rand::RngExt;
use serde::{Deserialize, Serialize};
use std::f32::consts::PI;

/// A diagonal Gaussian mixture over the embedding.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
pub struct Mixture {
    /// Log mixing weights.
    pub log_weights: Vec<f32>,
    /// Means, one row per component.
    pub means: Vec<[f32; FEATURES]>,
    /// Variances, one row per component.
    pub variances: Vec<[f32; FEATURES]>,
}

/// Variance floor of the mixture (standardised units): a component on a few identical
/// points must not collapse.
const VAR_FLOOR: f32 = 1e-3;

impl Mixture {
    /// Log-density of each component at `z` (without the weights) into `out`.
    fn component_logs(&self, z: &[f32; FEATURES], out: &mut [f32]) {
        let c = (FEATURES as f32) * (2.0 * PI).ln();
        for (o, (m, v)) in out.iter_mut().zip(self.means.iter().zip(&self.variances)) {
            let mut q = 0.0;
            let mut logdet = 0.0;
            for d in 0..FEATURES {
                let e = z[d] - m[d];
                q += e * e / v[d];
                logdet += v[d].ln();
            }
            *o = -0.5 * (c + logdet + q);
        }
    }

    /// Negative log-density at `z`.
    pub(super) fn nll(&self, z: &[f32; FEATURES]) -> f32 {
        let mut best = f32::NEG_INFINITY;
        let mut logs = [0.0f32; 256];
        let k = self.means.len().min(256);
        self.component_logs(z, &mut logs[..k]);
        for (l, w) in logs[..k].iter_mut().zip(&self.log_weights) {
            *l += w;
            best = best.max(*l);
        }
        let s: f32 = logs[..k].iter().map(|l| (l - best).exp()).sum();
        -(best + s.ln())
    }

    /// EM from `k` points drawn as initial means.
    pub(super) fn fit(
        points: &[[f32; FEATURES]],
        k: usize,
        iterations: usize,
        rng: &mut SimRng,
    ) -> Self {
        let n = points.len();
        let k = k.min(n);
        let mut m = Mixture {
            log_weights: vec![-(k as f32).ln(); k],
            means: (0..k).map(|_| points[rng.random_range(0..n)]).collect(),
            variances: vec![[1.0; FEATURES]; k],
        };
        let mut resp = vec![0.0f32; n * k];
        for _ in 0..iterations {
            // E step.
            for (z, r) in points.iter().zip(resp.chunks_exact_mut(k)) {
                m.component_logs(z, r);
                let mut best = f32::NEG_INFINITY;
                for (l, w) in r.iter_mut().zip(&m.log_weights) {
                    *l += w;
                    best = best.max(*l);
                }
                let mut s = 0.0;
                for l in r.iter_mut() {
                    *l = (*l - best).exp();
                    s += *l;
                }
                r.iter_mut().for_each(|l| *l /= s);
            }
            // M step.
            for j in 0..k {
                let mut w = 0.0f64;
                let mut mean = [0.0f64; FEATURES];
                for (z, r) in points.iter().zip(resp.chunks_exact(k)) {
                    w += f64::from(r[j]);
                    for d in 0..FEATURES {
                        mean[d] += f64::from(r[j] * z[d]);
                    }
                }
                if w < 1e-6 {
                    // An empty component restarts on a random point.
                    m.means[j] = points[rng.random_range(0..n)];
                    m.variances[j] = [1.0; FEATURES];
                    m.log_weights[j] = (1.0 / n as f32).ln();
                    continue;
                }
                let mean: [f64; FEATURES] = std::array::from_fn(|d| mean[d] / w);
                let mut var = [0.0f64; FEATURES];
                for (z, r) in points.iter().zip(resp.chunks_exact(k)) {
                    for d in 0..FEATURES {
                        let e = f64::from(z[d]) - mean[d];
                        var[d] += f64::from(r[j]) * e * e;
                    }
                }
                m.means[j] = std::array::from_fn(|d| mean[d] as f32);
                m.variances[j] = std::array::from_fn(|d| ((var[d] / w) as f32).max(VAR_FLOOR));
                m.log_weights[j] = (w / n as f64).ln() as f32;
            }
        }
        m
    }
}
