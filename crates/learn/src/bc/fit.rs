//! The training loop: softmax cross-entropy, Adam, minibatches over two threads, early stopping
//! on the validation NLL.

use super::{CloneConfig, PairDataset};
use crate::error::LearnError;
use fishprobe_models::convnet::{ConvNet, ConvNetWorkspace};
use fishprobe_nn::Adam;
use fishprobe_sim::SimRng;
use rand::RngExt;
use rayon::prelude::*;

/// Mean NLL (nats per example) of the network on a dataset.
pub fn nll(net: &ConvNet, d: &PairDataset) -> f64 {
    let len = net.arch.view_len();
    let cells = net.arch.cells();
    let chunk = 4096;
    let total: f64 =
        d.x.par_chunks(chunk * len)
            .zip(d.y.par_chunks(chunk))
            .map(|(x, y)| {
                let mut ws = ConvNetWorkspace::default();
                let logits = net.forward(x, y.len(), &mut ws);
                let mut g = vec![0.0; logits.len()];
                f64::from(fishprobe_nn::dist::softmax_cross_entropy(
                    logits, cells, y, &mut g,
                )) * y.len() as f64
            })
            .sum();
    total / d.len().max(1) as f64
}

/// NLL of the training data's marginal cell histogram on `val` (add-½ smoothing: every cell
/// gets half a count, so unseen cells do not give infinite loss).
pub fn marginal_nll(train: &PairDataset, val: &PairDataset, cells: usize) -> f64 {
    let mut counts = vec![0.5f64; cells];
    for &c in &train.y {
        counts[c] += 1.0;
    }
    let total: f64 = counts.iter().sum();
    -val.y.iter().map(|&c| (counts[c] / total).ln()).sum::<f64>() / val.len().max(1) as f64
}

/// One epoch's log line.
#[derive(Debug, Clone, Copy, PartialEq, serde::Serialize, serde::Deserialize)]
pub struct EpochLog {
    /// Epoch (1-based).
    pub epoch: usize,
    /// Mean training NLL over the epoch's minibatches.
    pub train_nll: f64,
    /// Validation NLL after the epoch.
    pub val_nll: f64,
    /// Seconds since the start.
    pub seconds: f64,
}

/// One thread's buffers: workspace, logit gradients, conv and dense parameter gradients.
type Worker = (ConvNetWorkspace, Vec<f32>, Vec<f32>, Vec<f32>);

/// Fits `net` on `train`, stopping early on `val`; keeps the best epoch's weights. Calls
/// `on_epoch` after each epoch and `on_batch(done, total)` during it.
pub fn fit(
    net: &mut ConvNet,
    train: &PairDataset,
    val: &PairDataset,
    cfg: &CloneConfig,
    rng: &mut SimRng,
    mut on_epoch: impl FnMut(&EpochLog),
    on_batch: &(dyn Fn(usize, usize) + Sync),
) -> Result<Vec<EpochLog>, LearnError> {
    cfg.validate()?;
    let len = net.arch.view_len();
    let cells = net.arch.cells();
    let m = cfg.batch_size;
    let half = m.div_ceil(2);
    let mut adam_c = Adam::new(net.conv.params.len(), cfg.learning_rate);
    let mut adam_m = Adam::new(net.mlp.num_params(), cfg.learning_rate);
    let mut idx: Vec<usize> = (0..train.len()).collect();
    let (mut xb, mut yb) = (vec![0.0f32; m * len], vec![0usize; m]);
    let mut workers: Vec<Worker> = (0..2)
        .map(|_| {
            (
                ConvNetWorkspace::default(),
                vec![0.0; half * cells],
                vec![0.0; net.conv.params.len()],
                vec![0.0; net.mlp.num_params()],
            )
        })
        .collect();
    let started = std::time::Instant::now();
    let mut best = (nll(net, val), net.clone());
    let mut logs = Vec::new();
    let mut since_best = 0;
    for epoch in 1..=cfg.max_epochs {
        for i in (1..idx.len()).rev() {
            idx.swap(i, rng.random_range(0..=i));
        }
        let batches = idx.len() / m;
        let mut loss_sum = 0.0f64;
        for (b, chunk) in idx.chunks_exact(m).enumerate() {
            for (j, &k) in chunk.iter().enumerate() {
                xb[j * len..(j + 1) * len].copy_from_slice(&train.x[k * len..(k + 1) * len]);
                yb[j] = train.y[k];
            }
            let net_ref = &*net;
            let losses: Vec<f64> = workers
                .par_iter_mut()
                .zip(xb.par_chunks(half * len).zip(yb.par_chunks(half)))
                .map(|((ws, dl, gc, gm), (x, y))| {
                    let n = y.len();
                    let logits = net_ref.forward(x, n, ws);
                    let l = fishprobe_nn::dist::softmax_cross_entropy(
                        logits,
                        cells,
                        y,
                        &mut dl[..n * cells],
                    );
                    // Each half's gradient is a mean over its half: scale to the minibatch mean.
                    let scale = n as f32 / m as f32;
                    dl[..n * cells].iter_mut().for_each(|g| *g *= scale);
                    gc.fill(0.0);
                    gm.fill(0.0);
                    net_ref.backward(x, n, &dl[..n * cells], ws, gc, gm);
                    f64::from(l) * n as f64
                })
                .collect();
            loss_sum += losses.iter().sum::<f64>() / m as f64;
            let (w0, w1) = workers.split_at_mut(1);
            for (a, b) in w0[0].2.iter_mut().zip(&w1[0].2) {
                *a += b;
            }
            for (a, b) in w0[0].3.iter_mut().zip(&w1[0].3) {
                *a += b;
            }
            adam_c.step(&mut net.conv.params, &w0[0].2);
            adam_m.step(net.mlp.params_mut(), &w0[0].3);
            if b % 64 == 0 {
                on_batch(b, batches);
            }
        }
        let train_nll = loss_sum / batches.max(1) as f64;
        if !train_nll.is_finite() {
            return Err(LearnError::Diverged {
                iteration: epoch as u64,
                what: "training NLL is not finite".into(),
            });
        }
        let val_nll = nll(net, val);
        let log = EpochLog {
            epoch,
            train_nll,
            val_nll,
            seconds: started.elapsed().as_secs_f64(),
        };
        on_epoch(&log);
        logs.push(log);
        if val_nll < best.0 {
            best = (val_nll, net.clone());
            since_best = 0;
        } else {
            since_best += 1;
            if since_best >= cfg.patience {
                break;
            }
        }
    }
    *net = best.1;
    Ok(logs)
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::bc::blind;
    use fishprobe_models::convnet::{encode_view, ConvNetArch};
    use fishprobe_sim::{AgentState, Tank, TankParams};
    use rand::SeedableRng;

    #[test]
    fn marginal_baseline_is_the_entropy_of_the_histogram() {
        let train = PairDataset {
            y: vec![0, 0, 1, 1],
            ..PairDataset::default()
        };
        // Smoothed counts (2.5, 2.5, 0.5 ...) over 4 cells: p(0) = 2.5 / 6.
        let v = marginal_nll(&train, &train, 4);
        assert!((v - -(2.5f64 / 6.0).ln()).abs() < 1e-12, "{v}");
    }

    #[test]
    fn fitting_learns_a_neighbour_dependent_rule() {
        // Synthetic examples: the cell is 0 when the neighbour is ahead, 1 when behind. A
        // network that sees the neighbour learns it; the blind one cannot beat log 2.
        let arch = ConvNetArch {
            bins: 8,
            conv_channels: 2,
            kernel: 3,
            hidden: [8, 8],
            v_bins: 1,
            w_bins: 2,
            ..ConvNetArch::default()
        };
        let mut r = fishprobe_sim::stream(1, "test", 0);
        let mut d = PairDataset::default();
        let tank = Tank::new(&TankParams::default());
        let mut view = vec![0.0; arch.view_len()];
        for _ in 0..2000 {
            let ahead = r.random::<bool>();
            let me = AgentState::at(0.0, 0.0, 0.0);
            let o = AgentState::at(if ahead { 10.0 } else { -10.0 }, 1.0, 0.0);
            encode_view(&arch, &tank, &me, &[o], &mut view);
            d.x.extend_from_slice(&view);
            d.y.push(usize::from(!ahead));
        }
        let cfg = CloneConfig {
            batch_size: 64,
            learning_rate: 0.01,
            max_epochs: 15,
            ..CloneConfig::default()
        };
        let mut rng = rand_xoshiro::Xoshiro256PlusPlus::seed_from_u64(2);
        let mut net = ConvNet::new(arch.clone(), &mut rng);
        let before = nll(&net, &d);
        fit(&mut net, &d, &d, &cfg, &mut r, |_| {}, &|_, _| {}).expect("fits");
        let after = nll(&net, &d);
        assert!(before > 0.6 && after < 0.05, "{before} -> {after}");
        let mut blind_d = d.clone();
        blind(&mut blind_d.x, &arch);
        let mut net2 = ConvNet::new(arch, &mut rng);
        fit(
            &mut net2,
            &blind_d,
            &blind_d,
            &cfg,
            &mut r,
            |_| {},
            &|_, _| {},
        )
        .expect("fits");
        assert!(
            nll(&net2, &blind_d) > 0.65,
            "the blind network cannot see the rule"
        );
    }
}
