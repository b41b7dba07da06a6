//! `fishprobe fit-convnet`: behavioural cloning of live guppy pairs into M_ConvNet weights.

use anyhow::{bail, Context, Result};
use clap::Args;
use fishprobe_learn::bc::{blind, fit, load_pairs, marginal_nll, nll, CloneConfig, EpochLog};
use fishprobe_models::{ConvNet, ConvNetArch};
use fishprobe_sim::stream;
use indicatif::{ProgressBar, ProgressStyle};
use std::path::{Path, PathBuf};

use super::emit;

#[derive(Debug, Args)]
pub struct FitConvnetArgs {
    /// Training recordings: directories of pair files (robofish.io or legacy) or files.
    /// Default: guppy-pairs/legacy/train of the shared data ($FISHPROBE_DATA).
    #[arg(long, num_args = 1..)]
    data: Vec<PathBuf>,
    /// Validation recordings, never mixed with the training ones. Default:
    /// guppy-pairs/legacy/validation of the shared data.
    #[arg(long, num_args = 1..)]
    validation: Vec<PathBuf>,
    /// Weights file to write (safetensors; the sidecar FILE.json and the log FILE.training.csv
    /// go beside it).
    #[arg(long)]
    out: PathBuf,
    /// Master seed (initialisation and shuffling).
    #[arg(long, default_value_t = 0)]
    seed: u64,
    /// Training settings (TOML, the fields of CloneConfig).
    #[arg(long)]
    config: Option<PathBuf>,
    /// Most epochs (overrides the settings).
    #[arg(long)]
    max_epochs: Option<usize>,
    /// Skip the "no neighbour" baseline network (halves the time).
    #[arg(long)]
    no_baselines: bool,
    /// Threads (default: all cores).
    #[arg(long)]
    jobs: Option<usize>,
}

fn shared(sub: &str) -> Result<Vec<PathBuf>> {
    let d = fishprobe_io::shared_data_dir()
        .context("no --data given and no shared data found (set FISHPROBE_DATA)")?;
    Ok(vec![d.join("guppy-pairs/legacy").join(sub)])
}

fn fit_one(
    label: &str,
    net: &mut ConvNet,
    train: &fishprobe_learn::bc::PairDataset,
    val: &fishprobe_learn::bc::PairDataset,
    cfg: &CloneConfig,
    seed: u64,
) -> Result<Vec<EpochLog>> {
    let bar = ProgressBar::new(cfg.max_epochs as u64);
    bar.set_style(
        ProgressStyle::with_template(
            "{spinner} [{elapsed_precise}] {bar:30} epoch {pos}/{len}  {msg}",
        )
        .unwrap_or_else(|_| ProgressStyle::default_bar()),
    );
    bar.set_message(label.to_string());
    let mut rng = stream(seed, &format!("fit-convnet/{label}/shuffle"), 0);
    let on_batch = |b: usize, n: usize| bar.set_message(format!("{label}: batch {b}/{n}"));
    let logs = fit(
        net,
        train,
        val,
        cfg,
        &mut rng,
        |l| {
            bar.inc(1);
            let line = format!(
                "{label}: epoch {} train NLL {:.4} validation NLL {:.4} ({:.0} s)",
                l.epoch, l.train_nll, l.val_nll, l.seconds
            );
            if bar.is_hidden() {
                eprintln!("{line}");
            } else {
                bar.println(line);
            }
        },
        &on_batch,
    )?;
    bar.finish_and_clear();
    Ok(logs)
}

fn write_log(path: &Path, logs: &[EpochLog]) -> Result<()> {
    let mut s = String::from("epoch,train_nll,val_nll,seconds\n");
    for l in logs {
        s += &format!(
            "{},{},{},{:.1}\n",
            l.epoch, l.train_nll, l.val_nll, l.seconds
        );
    }
    fishprobe_io::write_atomically(path, s.as_bytes())
        .with_context(|| format!("writing {}", path.display()))
}

pub fn run(a: FitConvnetArgs) -> Result<()> {
    let mut cfg: CloneConfig = match &a.config {
        Some(p) => toml::from_str(
            &std::fs::read_to_string(p).with_context(|| format!("reading {}", p.display()))?,
        )
        .with_context(|| format!("settings {}", p.display()))?,
        None => CloneConfig::default(),
    };
    if let Some(n) = a.max_epochs {
        cfg.max_epochs = n;
    }
    cfg.validate()?;
    let data = if a.data.is_empty() {
        shared("train")?
    } else {
        a.data.clone()
    };
    let validation = if a.validation.is_empty() {
        shared("validation")?
    } else {
        a.validation.clone()
    };
    let canon = |v: &[PathBuf]| -> Vec<PathBuf> {
        v.iter()
            .map(|p| p.canonicalize().unwrap_or_else(|_| p.clone()))
            .collect()
    };
    let (ct, cv) = (canon(&data), canon(&validation));
    if let Some(p) = ct.iter().find(|p| cv.contains(p)) {
        bail!(
            "{} is both training and validation data; they must not mix",
            p.display()
        );
    }
    super::with_jobs(a.jobs, || -> Result<()> {
        let arch = ConvNetArch::default();
        let train = load_pairs(&data, &arch, &cfg).context("training data")?;
        let val = load_pairs(&validation, &arch, &cfg).context("validation data")?;
        for (f, why) in train.skipped.iter().chain(&val.skipped) {
            eprintln!("warning: skipped {}: {why}", f.display());
        }
        let shared_files: Vec<&PathBuf> = train
            .files
            .iter()
            .filter(|f| val.files.contains(f))
            .collect();
        if let Some(f) = shared_files.first() {
            bail!(
                "{} is both training and validation data; they must not mix",
                f.display()
            );
        }
        eprintln!(
            "{} training examples from {} files, {} validation examples from {} files \
             ({} frames left out: NaN or interpolated; {} headings taken from motion)",
            train.len(),
            train.files.len(),
            val.len(),
            val.files.len(),
            train.frames_left_out + val.frames_left_out,
            train.headings_from_motion + val.headings_from_motion
        );
        let mut init = stream(a.seed, "fit-convnet/init", 0);
        let mut net = ConvNet::new(arch.clone(), &mut init);
        let logs = fit_one("ConvNet", &mut net, &train, &val, &cfg, a.seed)?;
        let val_nll = nll(&net, &val);
        let marginal = marginal_nll(&train, &val, arch.cells());
        let no_neighbour = if a.no_baselines {
            None
        } else {
            let (mut tb, mut vb) = (train.clone(), val.clone());
            blind(&mut tb.x, &arch);
            blind(&mut vb.x, &arch);
            let mut init = stream(a.seed, "fit-convnet/init-no-neighbour", 0);
            let mut net_b = ConvNet::new(arch.clone(), &mut init);
            fit_one("no-neighbour baseline", &mut net_b, &tb, &vb, &cfg, a.seed)?;
            Some(nll(&net_b, &vb))
        };
        // The command as a user types it (the binary's own path says nothing).
        let command: Vec<String> = std::iter::once("fishprobe".to_string())
            .chain(std::env::args().skip(1))
            .collect();
        let names = |v: &[PathBuf]| -> Vec<String> {
            v.iter()
                .filter_map(|f| f.file_name().map(|n| n.to_string_lossy().into_owned()))
                .collect()
        };
        let meta = serde_json::json!({
            "arch": arch,
            "clone_config": cfg,
            "seed": a.seed,
            "command": command.join(" "),
            "training_files": names(&train.files),
            "validation_files": names(&val.files),
            "training_examples": train.len(),
            "validation_examples": val.len(),
            "validation_nll": val_nll,
            "baselines": {"marginal_histogram_nll": marginal, "no_neighbour_nll": no_neighbour},
            "epochs": logs.len(),
            "program_version": env!("CARGO_PKG_VERSION"),
        });
        if let Some(parent) = a.out.parent().filter(|p| !p.as_os_str().is_empty()) {
            std::fs::create_dir_all(parent)
                .with_context(|| format!("creating {}", parent.display()))?;
        }
        fishprobe_nn::store::save(&a.out, &net.to_tensors(), &meta)
            .with_context(|| format!("writing {}", a.out.display()))?;
        let log = a.out.with_extension("training.csv");
        write_log(&log, &logs)?;
        let mut text = format!(
            "validation NLL (nats per frame, {} cells):\n  ConvNet                 {val_nll:.4}\n  marginal histogram      {marginal:.4}\n",
            arch.cells()
        );
        if let Some(b) = no_neighbour {
            text += &format!("  no-neighbour ConvNet    {b:.4}\n");
        }
        text += &format!(
            "wrote {} (+ {}, {})\n",
            a.out.display(),
            fishprobe_nn::store::sidecar_path(&a.out).display(),
            log.display()
        );
        emit(&text)
    })?
}
