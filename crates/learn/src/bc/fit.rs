//! The training loop: softmax cross-entropy, Adam, minibatches over two threads, early stopping
//! on the validation NLL.

use super::{CloneConfig, PairDataset};
use crate::error::LearnError;
use fishprobe_models::convnet::{ConvNet, ConvNetWorkspace};
use fishprobe_nn::Adam;
use fishprobe_sim::SimRng;
use rand::RngExt;
use rayon::prelude::*;

/// Mean NLL (nats per example) of the network on a dataset (a network with an individual's
/// latent: every example at the population's centre, zeros).
pub fn nll(net: &ConvNet, d: &PairDataset) -> f64 {
    nll_with(net, d, &Latent::Centre)
}

/// Which latent each example of a dataset is given.
#[derive(Debug, Clone, Copy)]
pub enum Latent<'a> {
    /// Zeros (the population's centre; and the only choice without a latent).
    Centre,
    /// The same vector for every example.
    Same(&'a [f32]),
    /// Per individual (`individuals x latent_dim`), by each example's `ind`.
    Own(&'a [f32]),
}

impl Latent<'_> {
    /// The latents of examples `ind` (`None`: zeros).
    fn rows(&self, ind: &[u32], d: usize) -> Option<Vec<f32>> {
        match *self {
            _ if d == 0 => None,
            Latent::Centre => None,
            Latent::Same(z) => Some(ind.iter().flat_map(|_| z[..d].iter().copied()).collect()),
            Latent::Own(z) => Some(
                ind.iter()
                    .flat_map(|&i| z[i as usize * d..(i as usize + 1) * d].iter().copied())
                    .collect(),
            ),
        }
    }
}

/// Mean NLL of the network on a dataset, each example with the latent `z` gives it.
pub fn nll_with(net: &ConvNet, d: &PairDataset, z: &Latent<'_>) -> f64 {
    let len = net.arch.view_len();
    let cells = net.arch.cells();
    let dim = net.arch.latent_dim;
    let chunk = 4096;
    let ind: &[u32] = if d.ind.len() == d.len() { &d.ind } else { &[] };
    let total: f64 =
        d.x.par_chunks(chunk * len)
            .zip(d.y.par_chunks(chunk))
            .enumerate()
            .map(|(c, (x, y))| {
                let mut ws = ConvNetWorkspace::default();
                let rows = if ind.is_empty() {
                    z.rows(&vec![0; y.len()], dim)
                } else {
                    z.rows(&ind[c * chunk..c * chunk + y.len()], dim)
                };
                let logits = net.forward_latent(x, rows.as_deref(), y.len(), &mut ws);
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

/// One thread's buffers: workspace, logit gradients, conv and dense parameter gradients, and
/// the gradients of its rows' latents.
type Worker = (ConvNetWorkspace, Vec<f32>, Vec<f32>, Vec<f32>, Vec<f32>);

/// The individuals' embeddings: `individuals x latent_dim`, learnt with the network.
pub type Embeddings = Vec<f32>;

/// The mean of the embeddings' rows (the population's centre the validation NLL is taken at
/// while fitting).
pub fn embedding_mean(e: &[f32], d: usize) -> Vec<f32> {
    let n = e.len() / d.max(1);
    (0..d)
        .map(|j| (0..n).map(|i| e[i * d + j]).sum::<f32>() / n.max(1) as f32)
        .collect()
}

/// Fits `net` on `train`, stopping early on `val`; keeps the best epoch's weights. Calls
/// `on_epoch` after each epoch and `on_batch(done, total)` during it. A network with an
/// individual's latent (`arch.latent_dim` > 0) learns one embedding per training individual
/// beside its weights, under a standard normal prior (`latent_prior`); they are returned
/// (empty without a latent), and the validation NLL is taken at their mean.
pub fn fit(
    net: &mut ConvNet,
    train: &PairDataset,
    val: &PairDataset,
    cfg: &CloneConfig,
    rng: &mut SimRng,
    mut on_epoch: impl FnMut(&EpochLog),
    on_batch: &(dyn Fn(usize, usize) + Sync),
) -> Result<(Vec<EpochLog>, Embeddings), LearnError> {
    cfg.validate()?;
    let len = net.arch.view_len();
    let cells = net.arch.cells();
    let dim = net.arch.latent_dim;
    if dim > 0 && train.ind.len() != train.len() {
        return Err(LearnError::Run(
            "a network with individuals needs each example's individual".into(),
        ));
    }
    let n_ind = if dim > 0 { train.individuals.len() } else { 0 };
    let mut emb: Embeddings = vec![0.0; n_ind * dim];
    let mut g_emb = vec![0.0f32; n_ind * dim];
    let mut adam_z = Adam::new(emb.len(), cfg.latent_learning_rate);
    let m = cfg.batch_size;
    let half = m.div_ceil(2);
    let mut adam_c = Adam::new(net.conv.params.len(), cfg.learning_rate);
    let mut adam_m = Adam::new(net.mlp.num_params(), cfg.learning_rate);
    let mut idx: Vec<usize> = (0..train.len()).collect();
    let (mut xb, mut yb) = (vec![0.0f32; m * len], vec![0usize; m]);
    // One chunk per worker even without a latent (then each holds one unused float per row).
    let mut zb = vec![0.0f32; m * dim.max(1)];
    let mut workers: Vec<Worker> = (0..2)
        .map(|_| {
            (
                ConvNetWorkspace::default(),
                vec![0.0; half * cells],
                vec![0.0; net.conv.params.len()],
                vec![0.0; net.mlp.num_params()],
                vec![0.0; half * dim],
            )
        })
        .collect();
    let started = std::time::Instant::now();
    let val_nll = |net: &ConvNet, emb: &[f32]| {
        let centre = embedding_mean(emb, dim);
        nll_with(net, val, &Latent::Same(&centre))
    };
    let mut best = (val_nll(net, &emb), net.clone(), emb.clone());
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
                if dim > 0 {
                    let i = train.ind[k] as usize;
                    zb[j * dim..(j + 1) * dim].copy_from_slice(&emb[i * dim..(i + 1) * dim]);
                }
            }
            let net_ref = &*net;
            let losses: Vec<f64> = workers
                .par_iter_mut()
                .zip(xb.par_chunks(half * len).zip(yb.par_chunks(half)))
                .zip(zb.par_chunks(half * dim.max(1)))
                .map(|(((ws, dl, gc, gm, gz), (x, y)), z)| {
                    let n = y.len();
                    let z = (dim > 0).then_some(z);
                    let logits = net_ref.forward_latent(x, z, n, ws);
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
                    let g_z = (dim > 0).then(|| &mut gz[..n * dim]);
                    net_ref.backward_latent(x, n, &dl[..n * cells], ws, gc, gm, g_z);
                    f64::from(l) * n as f64
                })
                .collect();
            if dim > 0 {
                // Each example's latent gradient to its individual's row, plus the prior's
                // share of this minibatch (the whole epoch adds the prior once per example).
                let prior = cfg.latent_prior * m as f32 / train.len() as f32;
                for (g, e) in g_emb.iter_mut().zip(&emb) {
                    *g = prior * e;
                }
                for (w, (_, part)) in workers.iter().zip(chunk.chunks(half).enumerate()) {
                    for (j, &k) in part.iter().enumerate() {
                        let i = train.ind[k] as usize;
                        for c in 0..dim {
                            g_emb[i * dim + c] += w.4[j * dim + c];
                        }
                    }
                }
                adam_z.step(&mut emb, &g_emb);
            }
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
        let val_nll = val_nll(net, &emb);
        let log = EpochLog {
            epoch,
            train_nll,
            val_nll,
            seconds: started.elapsed().as_secs_f64(),
        };
        on_epoch(&log);
        logs.push(log);
        if val_nll < best.0 {
            best = (val_nll, net.clone(), emb.clone());
            since_best = 0;
        } else {
            since_best += 1;
            if since_best >= cfg.patience {
                break;
            }
        }
    }
    *net = best.1;
    Ok((logs, best.2))
}

/// Mean NLL of `d` when each example's individual is unknown but drawn from a population:
/// per example, -ln of the mean over `draws` (latents drawn from the population) of the
/// probability of its cell. What the network predicts of a new fish before it has seen it.
pub fn nll_over_population(net: &ConvNet, d: &PairDataset, draws: &[Vec<f32>]) -> f64 {
    let len = net.arch.view_len();
    let cells = net.arch.cells();
    let dim = net.arch.latent_dim;
    let chunk = 2048;
    let total: f64 =
        d.x.par_chunks(chunk * len)
            .zip(d.y.par_chunks(chunk))
            .map(|(x, y)| {
                let n = y.len();
                let mut ws = ConvNetWorkspace::default();
                let mut p = vec![0.0f64; n];
                let mut probs = vec![0.0f32; n * cells];
                for z in draws {
                    let zb: Vec<f32> = (0..n).flat_map(|_| z[..dim].iter().copied()).collect();
                    let logits = net.forward_latent(x, Some(&zb), n, &mut ws);
                    fishprobe_nn::dist::softmax_rows(logits, &mut probs, cells);
                    for (j, &c) in y.iter().enumerate() {
                        p[j] += f64::from(probs[j * cells + c]);
                    }
                }
                p.iter()
                    .map(|&s| -(s / draws.len().max(1) as f64).max(1e-300).ln())
                    .sum::<f64>()
            })
            .sum();
    total / d.len().max(1) as f64
}

/// Fits the embeddings of `d`'s individuals to their examples with the network fixed (MAP
/// under the standard normal prior, `latent_fit_steps` Adam steps of `batch_size` examples
/// drawn from each individual's own): how a held-back fish's latent is found from its data.
/// Returns `individuals x latent_dim`.
pub fn fit_latents(
    net: &ConvNet,
    d: &PairDataset,
    cfg: &CloneConfig,
    rng: &mut SimRng,
) -> Embeddings {
    let dim = net.arch.latent_dim;
    let (len, cells) = (net.arch.view_len(), net.arch.cells());
    let n_ind = d.individuals.len();
    let mut out = vec![0.0f32; n_ind * dim];
    if dim == 0 || d.ind.len() != d.len() {
        return out;
    }
    let mut by_ind: Vec<Vec<usize>> = vec![Vec::new(); n_ind];
    for (k, &i) in d.ind.iter().enumerate() {
        by_ind[i as usize].push(k);
    }
    let seeds: Vec<u64> = (0..n_ind).map(|_| rng.random()).collect();
    let fitted: Vec<Vec<f32>> = by_ind
        .par_iter()
        .zip(seeds)
        .map(|(examples, seed)| {
            let mut z = vec![0.0f32; dim];
            if examples.is_empty() {
                return z;
            }
            let mut r = fishprobe_sim::stream(seed, "latent", 0);
            let m = cfg.batch_size.min(examples.len());
            let mut adam = Adam::new(dim, cfg.latent_learning_rate);
            let mut ws = ConvNetWorkspace::default();
            let (mut x, mut y) = (vec![0.0f32; m * len], vec![0usize; m]);
            // One chunk per worker even without a latent (then each holds one unused float per row).
            let mut zb = vec![0.0f32; m * dim.max(1)];
            let (mut dl, mut gz) = (vec![0.0f32; m * cells], vec![0.0f32; m * dim]);
            let (mut gc, mut gm) = (
                vec![0.0f32; net.conv.params.len()],
                vec![0.0f32; net.mlp.num_params()],
            );
            let prior = cfg.latent_prior / examples.len() as f32;
            for _ in 0..cfg.latent_fit_steps {
                for j in 0..m {
                    let k = examples[r.random_range(0..examples.len())];
                    x[j * len..(j + 1) * len].copy_from_slice(&d.x[k * len..(k + 1) * len]);
                    y[j] = d.y[k];
                    zb[j * dim..(j + 1) * dim].copy_from_slice(&z);
                }
                let logits = net.forward_latent(&x, Some(&zb), m, &mut ws);
                fishprobe_nn::dist::softmax_cross_entropy(logits, cells, &y, &mut dl);
                net.backward_latent(&x, m, &dl, &mut ws, &mut gc, &mut gm, Some(&mut gz));
                let mut g: Vec<f32> = z.iter().map(|v| prior * v).collect();
                for j in 0..m {
                    for c in 0..dim {
                        g[c] += gz[j * dim + c];
                    }
                }
                adam.step(&mut z, &g);
            }
            z
        })
        .collect();
    for (i, z) in fitted.into_iter().enumerate() {
        out[i * dim..(i + 1) * dim].copy_from_slice(&z);
    }
    out
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
    fn a_network_with_individuals_learns_how_two_fish_differ_and_finds_a_new_ones_latent() {
        // Two individuals that answer a neighbour ahead alike (cell 0) and one behind
        // differently (fish 0: cell 0, fish 1: cell 1): without an individual's latent the
        // second case stays a coin toss; with one the network tells them apart, and a
        // held-back fish like the second is recognised from its own examples.
        let arch = ConvNetArch {
            bins: 8,
            conv_channels: 2,
            kernel: 3,
            hidden: [8, 8],
            v_bins: 1,
            w_bins: 2,
            latent_dim: 1,
            ..ConvNetArch::default()
        };
        let mut r = fishprobe_sim::stream(3, "test", 0);
        let mut rv = fishprobe_sim::stream(3, "views", 0);
        let tank = Tank::new(&TankParams::default());
        let mut view = vec![0.0; arch.view_len()];
        let mut data = |who: &[u32]| {
            let mut d = PairDataset::default();
            for k in 0..1500 {
                let i = who[k % who.len()];
                let ahead = rv.random::<bool>();
                let me = AgentState::at(0.0, 0.0, 0.0);
                let o = AgentState::at(if ahead { 10.0 } else { -10.0 }, 1.0, 0.0);
                encode_view(&arch, &tank, &me, &[o], &mut view);
                d.x.extend_from_slice(&view);
                d.y.push(if ahead { 0 } else { i as usize % 2 });
                d.ind.push(i);
            }
            d.individuals = (0..who.iter().max().map_or(0, |m| m + 1))
                .map(|i| format!("fish {i}"))
                .collect();
            d
        };
        let train = data(&[0, 1]);
        let cfg = CloneConfig {
            batch_size: 64,
            learning_rate: 0.01,
            latent_learning_rate: 0.05,
            max_epochs: 15,
            patience: 15,
            latent_fit_steps: 150,
            ..CloneConfig::default()
        };
        let mut rng = rand_xoshiro::Xoshiro256PlusPlus::seed_from_u64(4);
        let mut net = ConvNet::new(arch.clone(), &mut rng);
        let (_, emb) =
            fit(&mut net, &train, &train, &cfg, &mut r, |_| {}, &|_, _| {}).expect("fits");
        assert_eq!(emb.len(), 2);
        assert!(
            (emb[0] - emb[1]).abs() > 0.1,
            "the two fish look alike: {emb:?}"
        );
        let own = nll_with(&net, &train, &Latent::Own(&emb));
        let centre = nll_with(&net, &train, &Latent::Same(&embedding_mean(&emb, 1)));
        // A coin toss in a quarter of the examples: 0.25 ln 2 = 0.17 at the centre.
        assert!(own < 0.08 && centre > 0.12, "own {own}, centre {centre}");
        // A new fish that behaves like fish 1: its latent fitted from its data.
        let mut new = data(&[1]);
        new.ind.iter_mut().for_each(|i| *i = 0);
        new.individuals = vec!["new".into()];
        let z = fit_latents(&net, &new, &cfg, &mut r);
        assert!(
            nll_with(&net, &new, &Latent::Own(&z)) < 0.2,
            "{z:?} vs {emb:?}"
        );
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
