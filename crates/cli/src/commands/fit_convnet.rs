//! `fishprobe fit-convnet`: behavioural cloning of live guppy pairs into M_ConvNet weights.

use anyhow::{Context, Result};
use clap::Args;
use fishprobe_learn::bc::{fit_convnet, CloneConfig, FitProgress, FitRequest};
use fishprobe_models::ConvNetArch;
use indicatif::{ProgressBar, ProgressStyle};
use std::path::PathBuf;

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
    #[arg(long, required_unless_present = "score")]
    out: Option<PathBuf>,
    /// Fit nothing: print the validation NLL of these weights on the validation recordings,
    /// with the examples made by these settings (compares networks on the same targets).
    #[arg(long, conflicts_with = "out")]
    score: Option<PathBuf>,
    /// Master seed (initialisation and shuffling).
    #[arg(long, default_value_t = 0)]
    seed: u64,
    /// Training settings (TOML, the fields of CloneConfig).
    #[arg(long)]
    config: Option<PathBuf>,
    /// Most epochs (overrides the settings).
    #[arg(long)]
    max_epochs: Option<usize>,
    /// Networks of an ensemble fitted on the same data, these weights included (overrides the
    /// settings' `ensemble_members`; 1: none). With K > 1 the K - 1 further members and the
    /// ensemble's disagreement file go beside the weights, for the OOD score `disagreement`.
    #[arg(long)]
    members: Option<usize>,
    /// M_ConvNet with individuals: every training fish gets an embedding of this many floats
    /// (at most 4), learnt with the network; their normal distribution is written beside the
    /// weights as a population file (WEIGHTS.population.json), and each held-back fish's
    /// latent is fitted to its data. Overrides the settings' `latent_dim` (0: none).
    #[arg(long)]
    latent_dim: Option<usize>,
    /// Skip the "no neighbour" baseline network (halves the time).
    #[arg(long)]
    no_baselines: bool,
    /// Take the networks an interrupted (or earlier) run of the same data, settings and seed
    /// finished beside --out (the weights, the baseline, ensemble members) and fit only the
    /// rest; the result is what one uninterrupted run writes. A network fitted on other data
    /// or settings is fitted again.
    #[arg(long, conflicts_with = "score")]
    resume: bool,
    /// Threads (default: all cores).
    #[arg(long)]
    jobs: Option<usize>,
}

pub fn run(a: FitConvnetArgs) -> Result<()> {
    let mut cfg: CloneConfig = match &a.config {
        Some(p) => super::read_toml(p, "settings")?,
        None => CloneConfig::default(),
    };
    if let Some(n) = a.max_epochs {
        cfg.max_epochs = n;
    }
    if let Some(k) = a.members {
        cfg.ensemble_members = k;
    }
    if let Some(d) = a.latent_dim {
        cfg.latent_dim = d;
    }
    cfg.validate()?;
    let validation = fishprobe_learn::bc::pairs_or_shared(&a.validation, "validation")?;
    if let Some(w) = &a.score {
        let (nll, n) = fishprobe_learn::bc::score_weights(w, &validation, &cfg)
            .with_context(|| format!("scoring {}", w.display()))?;
        emit(&format!(
            "{}: validation NLL {nll:.4} nats per frame over {n} examples\n",
            w.display()
        ))?;
        return Ok(());
    }
    let out = a
        .out
        .clone()
        .context("--out names the weights file to write")?;
    let _lock = super::lock_out_file(&out, "fit-convnet")?;
    let data = fishprobe_learn::bc::pairs_or_shared(&a.data, "train")?;
    // The command as a user types it (the binary's own path says nothing).
    let command: Vec<String> = std::iter::once("fishprobe".to_string())
        .chain(std::env::args().skip(1))
        .collect();
    let bar = ProgressBar::new(cfg.max_epochs as u64);
    bar.set_style(
        ProgressStyle::with_template(
            "{spinner} [{elapsed_precise}] {bar:30} epoch {pos}/{len}  {msg}",
        )
        .unwrap_or_else(|_| ProgressStyle::default_bar()),
    );
    let current = std::sync::Mutex::new("");
    let progress = |p: FitProgress<'_>| match p {
        FitProgress::Loaded { train, validation } => {
            for (f, why) in train.skipped.iter().chain(&validation.skipped) {
                // Warnings go to stderr whether or not a bar is drawn.
                bar.suspend(|| say!("warning: skipped {}: {why}", f.display()));
            }
            let line = format!(
                "{} training examples from {} files, {} validation examples from {} files \
                 ({} frames left out: NaN or interpolated; {} headings taken from motion)",
                train.len(),
                train.files.len(),
                validation.len(),
                validation.files.len(),
                train.frames_left_out + validation.frames_left_out,
                train.headings_from_motion + validation.headings_from_motion
            );
            if bar.is_hidden() {
                say!("{line}");
            } else {
                bar.println(line);
            }
        }
        FitProgress::Batch { label, done, total } => {
            let mut c = current.lock().unwrap_or_else(|e| e.into_inner());
            if *c != label {
                *c = label;
                bar.set_position(0);
            }
            bar.set_message(format!("{label}: batch {done}/{total}"));
        }
        FitProgress::Resumed { label, file } => {
            let line = format!(
                "{label}: kept {}, fitted by an earlier run (--resume)",
                file.display()
            );
            bar.suspend(|| say!("{line}"));
        }
        FitProgress::Refit { label, file, why } => {
            let line = format!(
                "{label}: fitted again: {} cannot be taken ({why})",
                file.display()
            );
            bar.suspend(|| say!("{line}"));
        }
        FitProgress::Epoch { label, log: l } => {
            bar.inc(1);
            let line = format!(
                "{label}: epoch {} train NLL {:.4} validation NLL {:.4} ({:.0} s)",
                l.epoch, l.train_nll, l.val_nll, l.seconds
            );
            if bar.is_hidden() {
                say!("{line}");
            } else {
                bar.println(line);
            }
        }
    };
    let r = super::with_jobs(a.jobs, || {
        fit_convnet(
            &FitRequest {
                data: &data,
                validation: &validation,
                out: &out,
                cfg: &cfg,
                seed: a.seed,
                baselines: !a.no_baselines,
                resume: a.resume,
                command: &command.join(" "),
                build: super::BUILD,
            },
            &progress,
        )
    })?;
    bar.finish_and_clear();
    let r = r?;
    let mut text = format!(
        "validation NLL (nats per frame, {} cells):\n  ConvNet                 {:.4}\n  marginal histogram      {:.4}\n",
        ConvNetArch::default().cells(),
        r.val_nll,
        r.marginal_nll
    );
    if let Some(b) = r.no_neighbour_nll {
        text += &format!("  no-neighbour ConvNet    {b:.4}\n");
    }
    for (f, nll) in &r.members {
        let name = f.file_name().map(|n| n.to_string_lossy().into_owned());
        text += &format!(
            "  ensemble member        {nll:.4}  ({})\n",
            name.unwrap_or_default()
        );
    }
    let meta = fishprobe_nn::store::load(&r.weights).ok().map(|(_, m)| m);
    if let Some(h) = meta
        .as_ref()
        .and_then(|m| m.pointer("/individuals/held_back"))
    {
        let get = |k: &str| {
            h.get(k)
                .and_then(serde_json::Value::as_f64)
                .unwrap_or(f64::NAN)
        };
        text += &format!(
            "held-back fish, the second half of each one's frames:\n  \
             with its own latent (fitted on the first half)       {:.4}\n  \
             over the population (its latent unknown)            {:.4}\n  \
             at the population's centre                           {:.4}\n  \
             the shipped M_ConvNet (no individuals)               {:.4}\n\
             wrote the population of the training individuals {}\n",
            get("validation_nll_own_latent"),
            get("validation_nll_population"),
            get("validation_nll_population_centre"),
            get("validation_nll_shipped_convnet"),
            fishprobe_learn::bc::population_beside(&r.weights).display()
        );
    }
    if let Some(d) = &r.disagreement {
        text += &format!("wrote the ensemble's disagreement file {}\n", d.display());
    }
    text += &format!(
        "wrote {} (+ {}, {})\n",
        r.weights.display(),
        fishprobe_nn::store::sidecar_path(&r.weights).display(),
        r.log_file.display()
    );
    emit(&text)
}
