//! `fishprobe fit-convnet` as a whole: the weights, the no-neighbour baseline, the support,
//! the ensemble and its disagreement file, each network saved when fitted and taken again by a
//! resumed run.

use super::{blind, fit, load_pairs, marginal_nll, nll, CloneConfig, EpochLog, PairDataset};
use crate::error::LearnError;
use fishprobe_models::convnet::{ConvNet, ConvNetArch};
use fishprobe_models::support::{SupportConfig, SupportModel};
use std::path::{Path, PathBuf};

/// What [`fit_convnet`] reports while it works.
#[derive(Debug, Clone)]
pub enum FitProgress<'a> {
    /// The datasets are loaded.
    Loaded {
        /// Training examples.
        train: &'a PairDataset,
        /// Validation examples.
        validation: &'a PairDataset,
    },
    /// Within an epoch of the network `label`: minibatch `done` of `total`.
    Batch {
        /// "ConvNet" or "no-neighbour baseline".
        label: &'static str,
        /// Minibatches done.
        done: usize,
        /// Minibatches per epoch.
        total: usize,
    },
    /// An epoch of the network `label` ended.
    Epoch {
        /// See `Batch`.
        label: &'static str,
        /// Its log line.
        log: EpochLog,
    },
    /// Resuming: the network `label` is taken from `file`, which an earlier run of the same
    /// data, settings and seed finished.
    Resumed {
        /// See `Batch`.
        label: &'static str,
        /// The weights file.
        file: &'a Path,
    },
    /// Resuming: `file` is there but cannot be taken (`why`), so the network `label` is fitted
    /// again and the file replaced.
    Refit {
        /// See `Batch`.
        label: &'static str,
        /// The weights file.
        file: &'a Path,
        /// Why it cannot be taken.
        why: &'a str,
    },
}

/// Sidecar key: the digest of what a fit saw ([`fit_inputs_sha256`]).
const FIT_INPUTS_KEY: &str = "fit_inputs_sha256";
/// Sidecar key: the digest of the fitted tensors ([`tensors_sha256`]).
const TENSORS_KEY: &str = "tensors_sha256";
/// Sidecar key: the fit's epoch log.
const LOG_KEY: &str = "log";
/// The sidecar's record of a network with individuals: the training individuals' names and
/// embeddings, their population, the held-back fish's fitted latents and NLLs.
const INDIVIDUALS_KEY: &str = "individuals";
/// Sidecar key: the fishprobe build that fitted the network (`fishprobe --version`: the
/// version and the git commit), so that a resumed run takes only networks its own code made.
const BUILD_KEY: &str = "program_build";

/// What a fit sees, digested: the training and validation examples as loaded (so the data and
/// every setting that shapes the examples), the architecture and the fit's own settings. The
/// ensemble's size, its calibration and the support's settings do not change a fit and are left
/// out, so a resumed run may ask for more members or another support.
fn fit_inputs_sha256(
    arch: &ConvNetArch,
    cfg: &CloneConfig,
    train: &PairDataset,
    val: &PairDataset,
) -> String {
    use sha2::Digest;
    let mut h = sha2::Sha256::new();
    h.update(b"fishprobe fit-convnet inputs, version 1\n");
    h.update(serde_json::to_vec(arch).unwrap_or_default());
    for n in [cfg.batch_size, cfg.max_epochs, cfg.patience] {
        h.update((n as u64).to_le_bytes());
    }
    h.update(cfg.learning_rate.to_le_bytes());
    let mut buf = Vec::with_capacity(8 * 4096);
    for d in [train, val] {
        h.update((d.len() as u64).to_le_bytes());
        for c in d.x.chunks(4096) {
            buf.clear();
            c.iter()
                .for_each(|v| buf.extend_from_slice(&v.to_le_bytes()));
            h.update(&buf);
        }
        for c in d.y.chunks(4096) {
            buf.clear();
            c.iter()
                .for_each(|&v| buf.extend_from_slice(&(v as u64).to_le_bytes()));
            h.update(&buf);
        }
    }
    fishprobe_onnx::hex(&h.finalize())
}

/// The SHA-256 of a network's tensors as a weights file stores them.
fn tensors_sha256(net: &ConvNet) -> Result<String, LearnError> {
    let bytes = fishprobe_nn::store::to_bytes(&net.to_tensors())?;
    Ok(fishprobe_models::sha256_hex(&bytes))
}

/// A fit an earlier run left in `file`, if a resumed run may take it: `None` when there is no
/// file; otherwise the network and its sidecar, or why not (another fit's inputs or seed,
/// another fishprobe build than `build`, a fishprobe that did not record them, or tensors
/// other than the sidecar describes: a write cut short).
fn earlier_fit(
    file: &Path,
    inputs: &str,
    seed: u64,
    build: &str,
) -> Option<Result<(ConvNet, serde_json::Value), String>> {
    if !file.exists() {
        return None;
    }
    let found = || -> Result<(ConvNet, serde_json::Value), String> {
        let (t, meta) = fishprobe_nn::store::load(file).map_err(|e| e.to_string())?;
        let text = |k: &str| meta.get(k).and_then(serde_json::Value::as_str);
        if text(FIT_INPUTS_KEY) != Some(inputs) {
            return Err(match text(FIT_INPUTS_KEY) {
                Some(_) => "it was fitted on other data or with other settings".into(),
                None => "its sidecar does not record what it was fitted on".into(),
            });
        }
        if meta.get("seed").and_then(serde_json::Value::as_u64) != Some(seed) {
            return Err("it was fitted with another seed".into());
        }
        match text(BUILD_KEY) {
            Some(b) if b == build => {}
            Some(b) => {
                return Err(format!(
                    "it was fitted by fishprobe {b}; this is {build}, whose fitting code may differ"
                ))
            }
            None => {
                return Err("its sidecar does not record the fishprobe build that fitted it".into())
            }
        }
        let net = ConvNet::from_parts(&t, &meta, &file.display().to_string())
            .map_err(|e| e.to_string())?;
        if text(TENSORS_KEY) != Some(tensors_sha256(&net).map_err(|e| e.to_string())?.as_str()) {
            return Err(
                "its weights are not those its sidecar describes (a write cut short)".into(),
            );
        }
        Ok((net, meta))
    };
    Some(found())
}

/// The validation NLL a sidecar records (of the validation examples its inputs digest covers).
fn recorded_nll(meta: &serde_json::Value) -> Option<f64> {
    meta.get("validation_nll")
        .and_then(serde_json::Value::as_f64)
}

/// The epoch log a sidecar records (empty when it records none).
fn logs_of(meta: &serde_json::Value) -> Vec<EpochLog> {
    meta.get(LOG_KEY)
        .and_then(|l| serde_json::from_value(l.clone()).ok())
        .unwrap_or_default()
}

/// The validation NLL (nats per frame) of existing weights on the pair files under
/// `validation`, their examples made with `cfg` (so two networks can be compared on the same
/// targets, e.g. with and without `heading_smoothing_frames`), and the number of examples.
pub fn score_weights(
    weights: &Path,
    validation: &[PathBuf],
    cfg: &CloneConfig,
) -> Result<(f64, usize), LearnError> {
    cfg.validate()?;
    let net = ConvNet::load(weights).map_err(|e| LearnError::Run(e.to_string()))?;
    let val = load_pairs(validation, &net.arch, cfg)?;
    Ok((nll(&net, &val), val.len()))
}

/// What [`fit_convnet`] produced.
#[derive(Debug, Clone, PartialEq)]
pub struct FitReport {
    /// Validation NLL of the fitted network.
    pub val_nll: f64,
    /// Validation NLL of the training data's marginal histogram.
    pub marginal_nll: f64,
    /// Validation NLL of the network without neighbour channels, when fitted.
    pub no_neighbour_nll: Option<f64>,
    /// Epoch logs of the fitted network.
    pub logs: Vec<EpochLog>,
    /// Files skipped, with the reason.
    pub skipped: Vec<(PathBuf, String)>,
    /// The weights file.
    pub weights: PathBuf,
    /// The support file of the training views beside it.
    pub support: PathBuf,
    /// The training log (CSV).
    pub log_file: PathBuf,
    /// The further members of the ensemble (`ensemble_members` > 1), with their validation
    /// NLLs.
    pub members: Vec<(PathBuf, f64)>,
    /// The ensemble's disagreement file, when it has further members.
    pub disagreement: Option<PathBuf>,
}

/// What [`fit_convnet`] is asked to do: one fit of M_ConvNet, with the names a sidecar records.
#[derive(Debug, Clone, Copy)]
pub struct FitRequest<'a> {
    /// The pair files (or directories of them) to fit on.
    pub data: &'a [PathBuf],
    /// The pair files to stop early on; no file may be in both.
    pub validation: &'a [PathBuf],
    /// The weights file to write (its sidecar, training log, support file and the ensemble's
    /// further members beside it).
    pub out: &'a Path,
    /// The fit's settings.
    pub cfg: &'a CloneConfig,
    /// The fit's seed (initialisation and shuffling; each further member derives its own).
    pub seed: u64,
    /// Also fit the same network without neighbour channels, for its NLL.
    pub baselines: bool,
    /// Take each network (the weights, the ensemble's members) that an earlier run of the same
    /// data, settings, seed and build finished beside `out`, and the baseline's NLL the
    /// weights' sidecar records; fit the rest.
    pub resume: bool,
    /// The command recorded in every sidecar.
    pub command: &'a str,
    /// The fishprobe build running, as `fishprobe --version` names it (recorded in each
    /// sidecar; a resumed run takes only networks this build fitted).
    pub build: &'a str,
}

/// Fits M_ConvNet as `req` says and writes the weights (`req.out`), their sidecar
/// (architecture, settings, data, NLLs, command, build) and the training log (`req.out` with
/// extension `training.csv`), the support file of the training views, and, with
/// `ensemble_members` > 1, the further members and their disagreement file. Each network is
/// saved as soon as it is fitted, so a resumed run (`req.resume`) writes what an uninterrupted
/// one writes (the fits are deterministic for their seed).
pub fn fit_convnet(
    req: &FitRequest<'_>,
    progress: &(dyn Fn(FitProgress<'_>) + Sync),
) -> Result<FitReport, LearnError> {
    req.cfg.validate()?;
    let arch = ConvNetArch {
        latent_dim: req.cfg.latent_dim,
        ..ConvNetArch::default()
    };
    let (train, val) = load_disjoint(req, &arch)?;
    progress(FitProgress::Loaded {
        train: &train,
        validation: &val,
    });
    let f = Fitting {
        inputs: fit_inputs_sha256(&arch, req.cfg, &train, &val),
        req,
        arch,
        train,
        val,
        progress,
    };
    if let Some(parent) = req.out.parent().filter(|p| !p.as_os_str().is_empty()) {
        std::fs::create_dir_all(parent)
            .map_err(|e| LearnError::Run(format!("creating {}: {e}", parent.display())))?;
    }
    let main = f.main_network()?;
    remove_stale_ensemble(req.out, req.cfg.ensemble_members)?;
    let weights_sha = sha256_of_file(req.out)?;
    let support = f.write_support(&weights_sha)?;
    let mut nets = vec![main.net];
    let members = f.ensemble(&mut nets)?;
    let disagreement = f.write_disagreement(&weights_sha, &members, nets)?;
    let log_file = write_training_log(req.out, &main.logs)?;
    let mut skipped = f.train.skipped.clone();
    skipped.extend(f.val.skipped.iter().cloned());
    Ok(FitReport {
        val_nll: main.val_nll,
        marginal_nll: main.marginal_nll,
        no_neighbour_nll: main.no_neighbour_nll,
        logs: main.logs,
        skipped,
        weights: req.out.to_path_buf(),
        support,
        log_file,
        members,
        disagreement,
    })
}

/// The training and validation examples of `req`, refused when a file is in both (by path
/// before loading, by the files each found after).
fn load_disjoint(
    req: &FitRequest<'_>,
    arch: &ConvNetArch,
) -> Result<(PairDataset, PairDataset), LearnError> {
    let canon = |v: &[PathBuf]| -> Vec<PathBuf> {
        v.iter()
            .map(|p| p.canonicalize().unwrap_or_else(|_| p.clone()))
            .collect()
    };
    let mix = |p: &Path| {
        LearnError::Run(format!(
            "{} is both training and validation data; they must not mix",
            p.display()
        ))
    };
    let (ct, cv) = (canon(req.data), canon(req.validation));
    if let Some(p) = ct.iter().find(|p| cv.contains(p)) {
        return Err(mix(p));
    }
    let train = load_pairs(req.data, arch, req.cfg)?;
    let val = load_pairs(req.validation, arch, req.cfg)?;
    if let Some(f) = train.files.iter().find(|f| val.files.contains(f)) {
        return Err(mix(f));
    }
    Ok((train, val))
}

/// The file names (without directories) of `files`, as sidecars and support files record
/// them.
pub fn file_names(files: &[PathBuf]) -> Vec<String> {
    files
        .iter()
        .filter_map(|f| f.file_name().map(|n| n.to_string_lossy().into_owned()))
        .collect()
}

/// The SHA-256 of a weights file just written, read back as every weights file is hashed
/// ([`fishprobe_models::weights_sha256`]).
fn sha256_of_file(file: &Path) -> Result<String, LearnError> {
    fishprobe_models::weights_sha256(file)
        .map_err(|e| LearnError::Run(format!("reading back {}: {e}", file.display())))
}

/// The epoch log as CSV beside the weights (`training.csv`).
fn write_training_log(out: &Path, logs: &[EpochLog]) -> Result<PathBuf, LearnError> {
    let log_file = out.with_extension("training.csv");
    let mut csv = String::from("epoch,train_nll,val_nll,seconds\n");
    for l in logs {
        csv += &format!(
            "{},{},{},{:.1}\n",
            l.epoch, l.train_nll, l.val_nll, l.seconds
        );
    }
    fishprobe_io::write_atomically(&log_file, csv.as_bytes())?;
    Ok(log_file)
}

/// The fitted (or taken) weights with what the report says of them.
struct MainFit {
    net: ConvNet,
    logs: Vec<EpochLog>,
    val_nll: f64,
    marginal_nll: f64,
    no_neighbour_nll: Option<f64>,
}

/// A fit under way: the request, its examples and the digest of what the fits see.
struct Fitting<'a> {
    req: &'a FitRequest<'a>,
    arch: ConvNetArch,
    train: PairDataset,
    val: PairDataset,
    inputs: String,
    progress: &'a (dyn Fn(FitProgress<'_>) + Sync),
}

impl Fitting<'_> {
    /// Fits `net` on `t`, stopping early on `v`, shuffled by `seed`, reporting as `label`.
    fn train_net(
        &self,
        label: &'static str,
        seed: u64,
        net: &mut ConvNet,
        t: &PairDataset,
        v: &PairDataset,
    ) -> Result<(Vec<EpochLog>, super::Embeddings), LearnError> {
        let progress = self.progress;
        let mut rng = fishprobe_sim::stream(seed, &format!("fit-convnet/{label}/shuffle"), 0);
        let on_batch =
            |done: usize, total: usize| progress(FitProgress::Batch { label, done, total });
        fit(
            net,
            t,
            v,
            self.req.cfg,
            &mut rng,
            |log| progress(FitProgress::Epoch { label, log: *log }),
            &on_batch,
        )
    }

    /// The network an earlier run of the same inputs, seed and build finished in `file`, when
    /// resuming; saying either way why.
    fn earlier(
        &self,
        label: &'static str,
        file: &Path,
        seed: u64,
    ) -> Option<(ConvNet, serde_json::Value)> {
        if !self.req.resume {
            return None;
        }
        match earlier_fit(file, &self.inputs, seed, self.req.build)? {
            Ok(found) => {
                (self.progress)(FitProgress::Resumed { label, file });
                Some(found)
            }
            Err(why) => {
                (self.progress)(FitProgress::Refit {
                    label,
                    file,
                    why: &why,
                });
                None
            }
        }
    }

    /// A new network from `seed`, fitted and saved to `file` at once (a resumed run starts
    /// after it), its sidecar the common record and `extra`'s fields.
    fn fit_new(
        &self,
        label: &'static str,
        seed: u64,
        file: &Path,
        extra: serde_json::Value,
    ) -> Result<(ConvNet, serde_json::Value), LearnError> {
        let mut init = fishprobe_sim::stream(seed, "fit-convnet/init", 0);
        let mut net = ConvNet::new(self.arch.clone(), &mut init);
        let (logs, emb) = self.train_net(label, seed, &mut net, &self.train, &self.val)?;
        let centre = super::embedding_mean(&emb, self.arch.latent_dim);
        let mut meta = serde_json::json!({
            "arch": self.arch,
            "seed": seed,
            "command": self.req.command,
            "validation_nll": super::nll_with(&net, &self.val, &super::Latent::Same(&centre)),
            "epochs": logs.len(),
            "program_version": env!("CARGO_PKG_VERSION"),
            BUILD_KEY: self.req.build,
            FIT_INPUTS_KEY: self.inputs,
            TENSORS_KEY: tensors_sha256(&net)?,
            LOG_KEY: logs,
        });
        if let (Some(m), serde_json::Value::Object(extra)) = (meta.as_object_mut(), extra) {
            m.extend(extra);
        }
        if self.arch.latent_dim > 0 {
            meta[INDIVIDUALS_KEY] = serde_json::json!({
                "names": self.train.individuals,
                "embeddings": emb,
            });
        }
        fishprobe_nn::store::save(file, &net.to_tensors(), &meta)?;
        Ok((net, meta))
    }

    /// The weights: taken or fitted, with the baselines' NLLs, saved again with this run's
    /// record (a resumed run's differs from the first only in what does not change a fit:
    /// flags, the ensemble's size, the support's settings).
    fn main_network(&self) -> Result<MainFit, LearnError> {
        let (req, train, val) = (self.req, &self.train, &self.val);
        let (net, mut meta) = match self.earlier("ConvNet", req.out, req.seed) {
            Some(found) => found,
            None => self.fit_new(
                "ConvNet",
                req.seed,
                req.out,
                serde_json::json!({
                    "clone_config": req.cfg,
                    "training_files": file_names(&train.files),
                    "validation_files": file_names(&val.files),
                    "training_examples": train.len(),
                    "validation_examples": val.len(),
                    "baselines": {"no_neighbour_nll": null},
                }),
            )?,
        };
        let logs = logs_of(&meta);
        let val_nll = recorded_nll(&meta).unwrap_or_else(|| nll(&net, val));
        let marginal_nll = marginal_nll(train, val, self.arch.cells());
        let recorded_baseline = meta
            .pointer("/baselines/no_neighbour_nll")
            .and_then(serde_json::Value::as_f64);
        let no_neighbour_nll = match recorded_baseline {
            Some(b) => Some(b),
            None if req.baselines => Some(self.no_neighbour_nll()?),
            None => None,
        };
        meta["baselines"] = serde_json::json!({
            "marginal_histogram_nll": marginal_nll,
            "no_neighbour_nll": no_neighbour_nll,
        });
        meta["command"] = req.command.into();
        meta["clone_config"] = serde_json::json!(req.cfg);
        meta["training_files"] = file_names(&train.files).into();
        meta["validation_files"] = file_names(&val.files).into();
        if self.arch.latent_dim > 0 {
            self.individuals(&net, &mut meta)?;
        }
        fishprobe_nn::store::save(req.out, &net.to_tensors(), &meta)?;
        Ok(MainFit {
            net,
            logs,
            val_nll,
            marginal_nll,
            no_neighbour_nll,
        })
    }

    /// For a network with individuals: the population of the training embeddings (their mean
    /// and covariance), the held-back fish's latents fitted to their data with the network
    /// fixed, the validation NLL with each fish's own latent against the population's centre,
    /// into the sidecar; and the population file beside the weights.
    fn individuals(&self, net: &ConvNet, meta: &mut serde_json::Value) -> Result<(), LearnError> {
        let d = self.arch.latent_dim;
        let emb: Vec<f32> = meta
            .pointer("/individuals/embeddings")
            .and_then(|v| serde_json::from_value(v.clone()).ok())
            .ok_or_else(|| {
                LearnError::Run("the sidecar holds no individuals' embeddings".into())
            })?;
        let n = emb.len() / d;
        let mean: Vec<f64> = (0..d)
            .map(|j| (0..n).map(|i| f64::from(emb[i * d + j])).sum::<f64>() / n as f64)
            .collect();
        let cov: Vec<Vec<f64>> = (0..d)
            .map(|a| {
                (0..d)
                    .map(|b| {
                        (0..n)
                            .map(|i| {
                                (f64::from(emb[i * d + a]) - mean[a])
                                    * (f64::from(emb[i * d + b]) - mean[b])
                            })
                            .sum::<f64>()
                            / (n as f64 - 1.0).max(1.0)
                    })
                    .collect()
            })
            .collect();
        // Each held-back fish's latent is fitted on the first half of its frames and scored,
        // against the population's centre, on the second half: the NLL is out of sample for
        // the latent too.
        let (first, second) = halves_by_individual(&self.val);
        let mut rng = fishprobe_sim::stream(self.req.seed, "fit-convnet/held-back-latents", 0);
        let own = super::fit_latents(net, &first, self.req.cfg, &mut rng);
        let centre: Vec<f32> = mean.iter().map(|&m| m as f32).collect();
        let nll_own = super::nll_with(net, &second, &super::Latent::Own(&own));
        let nll_centre = super::nll_with(net, &second, &super::Latent::Same(&centre));
        // The population's prediction of a fish it has not seen: its probability averaged
        // over individuals drawn from it (choice: 64 draws, seeded).
        let pop_model = fishprobe_models::population::cholesky(&cov)
            .ok_or_else(|| LearnError::Run("the embeddings' covariance is not one".into()))?;
        let mut draw_rng = fishprobe_sim::stream(self.req.seed, "fit-convnet/population-draws", 0);
        let draws: Vec<Vec<f32>> = (0..64)
            .map(|_| {
                let eps: Vec<f64> = (0..d)
                    .map(|_| {
                        rand_distr::Distribution::sample(&rand_distr::StandardNormal, &mut draw_rng)
                    })
                    .collect();
                (0..d)
                    .map(|i| {
                        (mean[i] + (0..=i).map(|j| pop_model[i][j] * eps[j]).sum::<f64>()) as f32
                    })
                    .collect()
            })
            .collect();
        let nll_pop = super::nll_over_population(net, &second, &draws);
        // For comparison, the shipped M_ConvNet without individuals on the same frames.
        let nll_shipped = fishprobe_models::ConvNet::shipped()
            .ok()
            .filter(|n| {
                n.arch.view_len() == net.arch.view_len() && n.arch.cells() == net.arch.cells()
            })
            .map(|n| nll(&n, &second));
        meta[INDIVIDUALS_KEY]["population"] = serde_json::json!({"mean": mean, "cov": cov});
        meta[INDIVIDUALS_KEY]["held_back"] = serde_json::json!({
            "names": self.val.individuals,
            "latents": own,
            "validation_nll_own_latent": nll_own,
            "validation_nll_population_centre": nll_centre,
            "validation_nll_population": nll_pop,
            "validation_nll_shipped_convnet": nll_shipped,
            "scored_on": "the second half of each held-back fish's frames; its latent fitted on the first half",
        });
        let traits = fishprobe_models::Trait::ALL[6..6 + d].to_vec();
        let pop = fishprobe_models::PopulationParams {
            name: "ConvNetPop".into(),
            source: String::new(),
            base: Some(Box::new(fishprobe_models::ModelSpec::ConvNet(
                fishprobe_models::ConvNetParams {
                    weights: self.req.out.display().to_string(),
                    ..fishprobe_models::ConvNetParams::default()
                },
            ))),
            traits,
            mean,
            cov,
            fit: serde_json::json!({
                "method": "behavioural cloning with a per-individual embedding under a standard normal prior; the population is the embeddings' normal distribution (fishprobe_learn::bc)",
                "command": self.req.command,
                "training_files": file_names(&self.train.files),
                "validation_files": file_names(&self.val.files),
                "validation_nll_own_latent": nll_own,
                "validation_nll_population": nll_pop,
                "validation_nll_population_centre": nll_centre,
            }),
        };
        let file = population_beside(self.req.out);
        let text =
            serde_json::to_string_pretty(&pop).map_err(|e| LearnError::Run(e.to_string()))?;
        fishprobe_io::write_atomically(&file, text.as_bytes())?;
        Ok(())
    }

    /// The validation NLL of the same network fitted without its neighbour channels.
    fn no_neighbour_nll(&self) -> Result<f64, LearnError> {
        let (mut tb, mut vb) = (self.train.clone(), self.val.clone());
        blind(&mut tb.x, &self.arch);
        blind(&mut vb.x, &self.arch);
        let mut init = fishprobe_sim::stream(self.req.seed, "fit-convnet/init-no-neighbour", 0);
        let mut net_b = ConvNet::new(self.arch.clone(), &mut init);
        let (_, emb) =
            self.train_net("no-neighbour baseline", self.req.seed, &mut net_b, &tb, &vb)?;
        let centre = super::embedding_mean(&emb, self.arch.latent_dim);
        Ok(super::nll_with(&net_b, &vb, &super::Latent::Same(&centre)))
    }

    /// The support file of the training views beside the weights (whose SHA-256 it records).
    fn write_support(&self, weights_sha: &str) -> Result<PathBuf, LearnError> {
        let req = self.req;
        let support = support_beside(req.out);
        let provenance = serde_json::json!({
            "command": req.command,
            "training_files": file_names(&self.train.files),
        });
        let s = build_support(
            &self.train,
            &self.arch,
            &SupportConfig {
                partner_range_cm: req.cfg.support_partner_range_cm,
                ..SupportConfig::default()
            },
            &req.out.display().to_string(),
            weights_sha,
            req.seed,
            provenance,
        )?;
        s.save(&support)
            .map_err(fishprobe_models::ModelError::from)?;
        Ok(support)
    }

    /// The ensemble's further members, each from its own seed (initialisation and shuffle),
    /// taken or fitted: their files with their validation NLLs, the networks appended to
    /// `nets`.
    fn ensemble(&self, nets: &mut Vec<ConvNet>) -> Result<Vec<(PathBuf, f64)>, LearnError> {
        let req = self.req;
        let mut members = Vec::new();
        for i in 2..=req.cfg.ensemble_members {
            let member_seed =
                fishprobe_sim::derive_seed(req.seed, "fit-convnet/ensemble-member", i as u64);
            let file = fishprobe_models::disagreement::member_beside(req.out, i);
            let (m, m_meta) = match self.earlier("ensemble member", &file, member_seed) {
                Some(found) => found,
                None => self.fit_new(
                    "ensemble member",
                    member_seed,
                    &file,
                    serde_json::json!({
                        "ensemble_member_of": req.out.file_name().map(|n| n.to_string_lossy().into_owned()),
                        "member": i,
                    }),
                )?,
            };
            let m_nll = recorded_nll(&m_meta).unwrap_or_else(|| nll(&m, &self.val));
            members.push((file, m_nll));
            nets.push(m);
        }
        Ok(members)
    }

    /// The ensemble's disagreement file beside the weights, when it has further `members`;
    /// calibrated on the training views.
    fn write_disagreement(
        &self,
        weights_sha: &str,
        members: &[(PathBuf, f64)],
        nets: Vec<ConvNet>,
    ) -> Result<Option<PathBuf>, LearnError> {
        use fishprobe_models::disagreement::{
            file_beside, Disagreement, DisagreementFile, MemberRef,
        };
        if members.is_empty() {
            return Ok(None);
        }
        let req = self.req;
        let refs = members
            .iter()
            .map(|(f, _)| {
                Ok(MemberRef {
                    file: f
                        .file_name()
                        .map(|n| n.to_string_lossy().into_owned())
                        .unwrap_or_default(),
                    sha256: sha256_of_file(f)?,
                })
            })
            .collect::<Result<Vec<_>, LearnError>>()?;
        let file = DisagreementFile::new(
            req.out.display().to_string(),
            weights_sha.to_string(),
            refs,
            serde_json::json!({
                "command": req.command,
                "training_files": file_names(&self.train.files),
            }),
        );
        let mut rng = fishprobe_sim::stream(req.seed, "disagreement", 0);
        let d = Disagreement::fit(
            nets,
            file,
            &self.train.x,
            req.cfg.ensemble_calibration_views,
            &mut rng,
        )
        .map_err(fishprobe_models::ModelError::from)?;
        let path = file_beside(req.out);
        d.save(&path).map_err(fishprobe_models::ModelError::from)?;
        Ok(Some(path))
    }
}

/// Removes what an earlier fit into `out` left of its ensemble that this fit, of `members`
/// members, will not write again: further members beyond `members` (with their sidecars) and
/// the disagreement file (rewritten when `members` > 1). They belonged to the old weights.
fn remove_stale_ensemble(out: &Path, members: usize) -> Result<(), LearnError> {
    use fishprobe_models::disagreement::{file_beside, member_beside, MAX_MEMBERS};
    let stale = (members.max(1) + 1..=MAX_MEMBERS)
        .map(|i| member_beside(out, i))
        .flat_map(|m| [fishprobe_nn::store::sidecar_path(&m), m])
        .chain(std::iter::once(file_beside(out)));
    for f in stale {
        match std::fs::remove_file(&f) {
            Err(e) if e.kind() != std::io::ErrorKind::NotFound => {
                return Err(LearnError::Run(format!(
                    "removing {} (of the ensemble an earlier fit left beside {}): {e}",
                    f.display(),
                    out.display()
                )))
            }
            _ => {}
        }
    }
    Ok(())
}

/// Each individual's examples split in time: the first half of its frames and the second.
fn halves_by_individual(d: &PairDataset) -> (PairDataset, PairDataset) {
    let len = d.x.len() / d.len().max(1);
    let mut count = vec![0usize; d.individuals.len()];
    for &i in &d.ind {
        count[i as usize] += 1;
    }
    let mut seen = vec![0usize; d.individuals.len()];
    let (mut a, mut b) = (PairDataset::default(), PairDataset::default());
    for (k, &i) in d.ind.iter().enumerate() {
        let i = i as usize;
        let part = if seen[i] < count[i] / 2 {
            &mut a
        } else {
            &mut b
        };
        seen[i] += 1;
        part.x.extend_from_slice(&d.x[k * len..(k + 1) * len]);
        part.y.push(d.y[k]);
        part.ind.push(i as u32);
    }
    a.individuals = d.individuals.clone();
    b.individuals = d.individuals.clone();
    (a, b)
}

/// The population file of a network with individuals: `WEIGHTS.population.json`.
pub fn population_beside(weights: &Path) -> PathBuf {
    let mut s = weights.as_os_str().to_owned();
    s.push(".population.json");
    PathBuf::from(s)
}

/// The support file of a weights (or ONNX) file: `FILE.support.json` beside it.
pub fn support_beside(weights: &Path) -> PathBuf {
    let mut s = weights.as_os_str().to_owned();
    s.push(".support.json");
    PathBuf::from(s)
}

/// The support model of a training dataset's views, for the model `model` whose
/// weights have SHA-256 `sha256`; seeded by `seed`.
pub fn build_support(
    train: &PairDataset,
    arch: &ConvNetArch,
    cfg: &SupportConfig,
    model: &str,
    sha256: &str,
    seed: u64,
    provenance: serde_json::Value,
) -> Result<SupportModel, LearnError> {
    let mut rng = fishprobe_sim::stream(seed, "support", 0);
    let mut s = SupportModel::fit(arch, &train.x, cfg, model, sha256, &mut rng)
        .map_err(fishprobe_models::ModelError::from)?;
    s.provenance = provenance;
    Ok(s)
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn a_fit_is_resumed_only_from_the_same_examples_and_fit_settings() {
        let arch = ConvNetArch::default();
        let set = |n: usize, v: f32| PairDataset {
            x: vec![v; n * arch.view_len()],
            y: vec![3; n],
            files: Vec::new(),
            skipped: Vec::new(),
            frames_left_out: 0,
            headings_from_motion: 0,
            ..PairDataset::default()
        };
        let cfg = CloneConfig::default();
        let (t, v) = (set(5, 0.5), set(3, 0.25));
        let base = fit_inputs_sha256(&arch, &cfg, &t, &v);
        assert_eq!(base.len(), 64);
        // What does not change a fit: the ensemble's size and calibration, the support.
        let same = CloneConfig {
            ensemble_members: 4,
            ensemble_calibration_views: 100,
            support_partner_range_cm: 15.0,
            ..cfg.clone()
        };
        assert_eq!(fit_inputs_sha256(&arch, &same, &t, &v), base);
        // What does: the fit's settings, a single example, the split.
        let lr = CloneConfig {
            learning_rate: 0.002,
            ..cfg.clone()
        };
        assert_ne!(fit_inputs_sha256(&arch, &lr, &t, &v), base);
        let mut t2 = t.clone();
        t2.x[7] = 0.5000001;
        assert_ne!(fit_inputs_sha256(&arch, &cfg, &t2, &v), base);
        let mut t3 = t.clone();
        t3.y[4] = 2;
        assert_ne!(fit_inputs_sha256(&arch, &cfg, &t3, &v), base);
        assert_ne!(fit_inputs_sha256(&arch, &cfg, &v, &t), base);
    }

    #[test]
    fn a_network_is_taken_only_from_the_same_inputs_seed_and_build_with_its_own_tensors() {
        let dir =
            std::env::temp_dir().join(format!("fishprobe-earlier-fit-{}", std::process::id()));
        std::fs::create_dir_all(&dir).unwrap();
        let file = dir.join("cn.safetensors");
        let arch = ConvNetArch::default();
        let net = ConvNet::new(arch.clone(), &mut fishprobe_sim::stream(1, "t", 0));
        let (inputs, build) = ("ab".repeat(32), "0.1.0 (commit 0123456789ab)");
        let save = |meta: serde_json::Value| {
            fishprobe_nn::store::save(&file, &net.to_tensors(), &meta).unwrap();
        };
        let meta = serde_json::json!({
            "arch": arch,
            "seed": 7,
            BUILD_KEY: build,
            FIT_INPUTS_KEY: inputs,
            TENSORS_KEY: tensors_sha256(&net).unwrap(),
        });
        assert!(earlier_fit(&dir.join("none.safetensors"), &inputs, 7, build).is_none());
        save(meta.clone());
        let why = |inputs: &str, seed: u64, build: &str| {
            earlier_fit(&file, inputs, seed, build).unwrap().err()
        };
        assert_eq!(why(&inputs, 7, build), None, "the same fit is taken");
        assert!(why(&"cd".repeat(32), 7, build)
            .unwrap()
            .contains("other data"));
        assert!(why(&inputs, 8, build).unwrap().contains("another seed"));
        let other = why(&inputs, 7, "0.1.0 (commit ba9876543210)").unwrap();
        assert!(
            other.contains("fitted by fishprobe 0.1.0 (commit 0123456789ab)")
                && other.contains("this is 0.1.0 (commit ba9876543210), whose fitting code"),
            "{other}"
        );
        let mut unrecorded = meta.clone();
        unrecorded.as_object_mut().unwrap().remove(BUILD_KEY);
        save(unrecorded);
        assert!(why(&inputs, 7, build)
            .unwrap()
            .contains("does not record the fishprobe build"));
        let mut cut = meta;
        cut[TENSORS_KEY] = serde_json::json!("00".repeat(32));
        save(cut);
        assert!(why(&inputs, 7, build)
            .unwrap()
            .contains("a write cut short"));
        std::fs::remove_dir_all(&dir).unwrap();
    }
}
