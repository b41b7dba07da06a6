//! `fishprobe fit-population`: a population of a model's individuals fitted to the spread of
//! real recordings, checked on recordings it did not use.

use anyhow::{bail, Context, Result};
use clap::Args;
use fishprobe_analysis::offline::{
    compare_offline, read_recordings, recording_values, simulate_model, OfflineConfig, Recording,
    RecordingValues,
};
use fishprobe_io::read_any_trial;
use fishprobe_learn::bc::{list_files, pairs_or_shared};
use fishprobe_learn::population::{fit, start, FitConfig, FitState, Progress};
use fishprobe_models::{ModelSpec, PopulationParams};
use serde_json::json;
use std::path::{Path, PathBuf};

use super::emit;

#[derive(Debug, Args)]
pub struct FitPopulationArgs {
    /// The model whose individuals vary (a name, `onnx:FILE`, `convnet:FILE`).
    #[arg(long)]
    model: String,
    /// Training recordings (pairs, or one fish beside the robot): directories or files.
    /// Default: guppy-pairs/legacy/train of the shared data ($FISHPROBE_DATA).
    #[arg(long, num_args = 1..)]
    data: Vec<PathBuf>,
    /// Recordings the fit is checked on, never fitted. Default: guppy-pairs/legacy/validation
    /// of the shared data.
    #[arg(long, num_args = 1..)]
    validation: Vec<PathBuf>,
    /// The population file to write (JSON; FILE.progress.json beside it lets an interrupted
    /// fit resume, FILE.md holds the report).
    #[arg(long)]
    out: PathBuf,
    /// The population's name (default: the model's name and "Pop").
    #[arg(long)]
    name: Option<String>,
    /// Master seed (simulations and the check's bootstrap).
    #[arg(long, default_value_t = 0)]
    seed: u64,
    /// Fit settings (TOML, the fields of FitConfig).
    #[arg(long)]
    config: Option<PathBuf>,
    /// Iterations (overrides the settings).
    #[arg(long)]
    iterations: Option<usize>,
    /// Also cross-validate on the training recordings: K folds, each fitted on the others and
    /// checked on itself (K fits more; the report's cross-validation table).
    #[arg(long)]
    cv: Option<usize>,
    /// Threads (default: all cores). Results do not depend on it.
    #[arg(long)]
    jobs: Option<usize>,
}

fn recordings(
    dirs: &[PathBuf],
    what: &str,
    cfg: &OfflineConfig,
) -> Result<Vec<(String, Recording)>> {
    let files = list_files(dirs);
    let (real, skipped) = read_recordings(&files, read_any_trial, cfg);
    for (f, why) in &skipped {
        say!("warning: skipped {f}: {why}");
    }
    if real.is_empty() {
        bail!(
            "no usable {what} recordings in {}",
            dirs.iter()
                .map(|d| d.display().to_string())
                .collect::<Vec<_>>()
                .join(", ")
        );
    }
    Ok(real)
}

fn with_suffix(p: &Path, suffix: &str) -> PathBuf {
    let mut s = p.as_os_str().to_owned();
    s.push(suffix);
    PathBuf::from(s)
}

/// Fits one population, resuming from `state_file` when it holds a fit of the same key.
#[allow(clippy::too_many_arguments)]
fn fit_one(
    base: &ModelSpec,
    name: &str,
    train: &[(String, Recording)],
    cfg: &FitConfig,
    offline: &OfflineConfig,
    seed: u64,
    state_file: &Path,
    label: &str,
) -> Result<(PopulationParams, FitState)> {
    let key = serde_json::to_string(&json!({
        "base": base, "name": name, "config": cfg, "seed": seed,
        "data": train.iter().map(|(n, _)| n).collect::<Vec<_>>(),
    }))?;
    let fresh = || -> Result<FitState> {
        let t = fishprobe_learn::population::targets(train, cfg, offline)?;
        Ok(FitState {
            key: key.clone(),
            iteration: 0,
            params: start(cfg, &t),
            lambda: cfg.damping,
            history: Vec::new(),
        })
    };
    let state = match fishprobe_io::read_small_text(state_file) {
        Ok(text) => match serde_json::from_str::<FitState>(&text) {
            Ok(s) if s.key == key => {
                if s.iteration >= cfg.iterations {
                    say!(
                        "{label}: {} holds this fit, complete ({} iterations)",
                        state_file.display(),
                        s.history.len()
                    );
                } else {
                    say!(
                        "{label}: resuming at iteration {} of {}",
                        s.iteration + 1,
                        cfg.iterations
                    );
                }
                s
            }
            _ => {
                say!(
                    "{label}: {} holds another fit (other data, settings or seed): starting over",
                    state_file.display()
                );
                fresh()?
            }
        },
        Err(_) => fresh()?,
    };
    let started = std::time::Instant::now();
    let mut save = |s: &FitState| -> Result<(), fishprobe_learn::LearnError> {
        let text = serde_json::to_string_pretty(s)
            .map_err(|e| fishprobe_learn::LearnError::Run(e.to_string()))?;
        fishprobe_io::write_atomically(state_file, text.as_bytes())?;
        Ok(())
    };
    let mut progress = |p: Progress<'_>| {
        say!(
            "{label}: iteration {}/{}: objective {:.3} (best {:.3}) [{:.0} s]",
            p.iteration + 1,
            p.of,
            p.record.objective,
            p.best,
            started.elapsed().as_secs_f64()
        );
    };
    Ok(fit(
        base,
        name,
        train,
        cfg,
        offline,
        seed,
        state,
        &mut save,
        &mut progress,
    )?)
}

pub fn run(a: FitPopulationArgs) -> Result<()> {
    let mut cfg: FitConfig = match &a.config {
        Some(p) => super::read_toml(p, "settings")?,
        None => FitConfig::default(),
    };
    if let Some(n) = a.iterations {
        cfg.iterations = n;
    }
    cfg.validate()?;
    if let Some(k) = a.cv {
        if !(2..=20).contains(&k) {
            bail!("--cv must lie in [2, 20] folds, got {k}");
        }
    }
    let base = ModelSpec::by_name(&a.model)?;
    if matches!(base, ModelSpec::Population(_)) {
        bail!("--model names a population: fit a population of its base model instead");
    }
    base.build().with_context(|| format!("model {}", a.model))?;
    let name = a
        .name
        .clone()
        .unwrap_or_else(|| format!("{}Pop", base.label()));
    let _lock = super::lock_out_file(&a.out, "fit-population")?;
    let offline = OfflineConfig::default();
    let train_dirs = pairs_or_shared(&a.data, "train")?;
    let val_dirs = pairs_or_shared(&a.validation, "validation")?;
    let command: Vec<String> = std::iter::once("fishprobe".to_string())
        .chain(std::env::args().skip(1))
        .collect();
    let report = super::with_jobs(a.jobs, || -> Result<String> {
        let train = recordings(&train_dirs, "training", &offline)?;
        let validation = recordings(&val_dirs, "validation", &offline)?;
        let overlap: Vec<&String> = train
            .iter()
            .filter(|(n, _)| validation.iter().any(|(m, _)| file_name(m) == file_name(n)))
            .map(|(n, _)| n)
            .collect();
        if !overlap.is_empty() {
            bail!(
                "{} is both a training and a validation recording: a fit is checked on recordings it did not use",
                overlap[0]
            );
        }
        say!(
            "fitting {name}: a population of {} on {} recordings, checked on {}",
            base.label(),
            train.len(),
            validation.len()
        );
        let started = std::time::Instant::now();
        let state_file = with_suffix(&a.out, ".progress.json");
        let (mut pop, state) = fit_one(
            &base,
            &name,
            &train,
            &cfg,
            &offline,
            a.seed,
            &state_file,
            "fit",
        )?;
        let fit_s = started.elapsed().as_secs_f64();
        let check = |recs: &[(String, Recording)], what: &str| -> Result<serde_json::Value> {
            check_on(&base, &pop, recs, &cfg, &offline, a.seed, what)
        };
        let on_train = check(&train, "training")?;
        let on_validation = check(&validation, "validation")?;
        let cv = match a.cv {
            Some(k) => Some(cross_validate(
                &base, &name, &train, &cfg, &offline, a.seed, k, &a.out,
            )?),
            None => None,
        };
        let best = state
            .history
            .iter()
            .map(|r| r.objective)
            .fold(f64::INFINITY, f64::min);
        pop.source = a.out.display().to_string();
        pop.fit = json!({
            "method": "the method of simulated moments on per-recording statistics (means, s.d.s, correlations), Levenberg-Marquardt with common random numbers (fishprobe_learn::population)",
            "command": command.join(" "),
            "seed": a.seed,
            "settings": cfg,
            "training_files": train.iter().map(|(n, _)| file_name(n)).collect::<Vec<_>>(),
            "validation_files": validation.iter().map(|(n, _)| file_name(n)).collect::<Vec<_>>(),
            "iterations": state.history.len(),
            "objective": best,
            "history": state.history.iter().map(|r| r.objective).collect::<Vec<_>>(),
            "seconds": fit_s,
            "training": on_train,
            "validation": on_validation,
            "cross_validation": cv,
        });
        let text = serde_json::to_string_pretty(&pop)?;
        fishprobe_io::write_atomically(&a.out, text.as_bytes())
            .with_context(|| format!("writing {}", a.out.display()))?;
        let md = report_markdown(&pop);
        fishprobe_io::write_atomically(&with_suffix(&a.out, ".md"), md.as_bytes())?;
        Ok(md)
    })??;
    emit(&format!("{report}\nwrote {}\n", a.out.display()))
}

fn file_name(p: &str) -> String {
    Path::new(p)
        .file_name()
        .map_or_else(|| p.to_string(), |n| n.to_string_lossy().into_owned())
}

/// The base model and the population on `recs` (the offline comparison): per statistic of the
/// fit, the s.d. ratio and W1 against the real recordings' floor, and the pooled gaps.
fn check_on(
    base: &ModelSpec,
    pop: &PopulationParams,
    recs: &[(String, Recording)],
    cfg: &FitConfig,
    offline: &OfflineConfig,
    seed: u64,
    what: &str,
) -> Result<serde_json::Value> {
    let models = vec![
        (base.label(), base.clone()),
        (pop.name.clone(), ModelSpec::Population(pop.clone())),
    ];
    let offline = OfflineConfig {
        replicates: cfg.check_replicates,
        ..offline.clone()
    };
    let r = compare_offline(recs, Vec::new(), &models, &offline, seed)
        .with_context(|| format!("checking on the {what} recordings"))?;
    let c = if r.pairs.recordings.is_empty() {
        r.open_loop.unwrap_or_default()
    } else {
        r.pairs
    };
    Ok(spread_json(
        &c.spread,
        &c.gaps,
        &cfg.statistics,
        c.recordings.len(),
    ))
}

fn spread_json(
    sp: &fishprobe_analysis::offline::OfflineSpread,
    gaps: &std::collections::BTreeMap<
        String,
        std::collections::BTreeMap<String, fishprobe_analysis::offline::OfflineGap>,
    >,
    stats: &[String],
    n: usize,
) -> serde_json::Value {
    let per_model = |m: &String| {
        let per = &sp.models[m];
        json!({
            "spread": stats.iter().filter_map(|s| per.get(s).map(|e| (s.clone(), json!({
                "ratio": e.ratio, "ci": e.ci, "w1": e.w1_trials, "sd_real": e.sd_real,
            })))).collect::<serde_json::Map<_, _>>(),
            "pooled_w": gaps.get(m).map(|g| g.iter().map(|(k, v)| (k.clone(), json!(v.w))).collect::<serde_json::Map<_, _>>()),
        })
    };
    json!({
        "recordings": n,
        "split_half": stats.iter().filter_map(|s| sp.split_half.get(s).map(|v| (s.clone(), json!(v)))).collect::<serde_json::Map<_, _>>(),
        "floor": stats.iter().filter_map(|s| sp.floor.get(s).map(|v| (s.clone(), json!(v)))).collect::<serde_json::Map<_, _>>(),
        "models": sp.models.keys().map(|m| (m.clone(), per_model(m))).collect::<serde_json::Map<_, _>>(),
    })
}

/// K-fold cross-validation on the training recordings: each fold's recordings are simulated
/// by the population fitted on the other folds (and by the base model), and the pooled
/// held-out simulations are compared with the real recordings.
#[allow(clippy::too_many_arguments)]
fn cross_validate(
    base: &ModelSpec,
    name: &str,
    train: &[(String, Recording)],
    cfg: &FitConfig,
    offline: &OfflineConfig,
    seed: u64,
    k: usize,
    out: &Path,
) -> Result<serde_json::Value> {
    let n = train.len();
    if n < 2 * k {
        bail!("{n} training recordings are too few for {k} folds (at least two per fold)");
    }
    // Folds by a seeded shuffle of the recordings.
    let mut order: Vec<usize> = (0..n).collect();
    order.sort_by_key(|&i| fishprobe_sim::derive_seed(seed, "fit/cv/order", i as u64));
    let fold_of = |i: usize| order.iter().position(|&j| j == i).unwrap_or(0) % k;
    let mut pop_vals: Vec<Option<RecordingValues>> = vec![None; n];
    let mut base_vals: Vec<Option<RecordingValues>> = vec![None; n];
    let base_model = base.build()?;
    for f in 0..k {
        let fit_set: Vec<(String, Recording)> = (0..n)
            .filter(|&i| fold_of(i) != f)
            .map(|i| train[i].clone())
            .collect();
        let state_file = with_suffix(out, &format!(".cv{}of{k}.progress.json", f + 1));
        let (pop, _) = fit_one(
            base,
            name,
            &fit_set,
            cfg,
            offline,
            seed,
            &state_file,
            &format!("cross-validation fold {}/{k}", f + 1),
        )?;
        let pop_model = ModelSpec::Population(pop).build()?;
        for i in (0..n).filter(|&i| fold_of(i) == f) {
            let s = fishprobe_sim::derive_seed(seed, "fit/cv/simulate", i as u64);
            let (sim, _) = simulate_model(&pop_model, &train[i].1, offline, s)?;
            pop_vals[i] = Some(recording_values(&sim, offline));
            let (sim, _) = simulate_model(&base_model, &train[i].1, offline, s)?;
            base_vals[i] = Some(recording_values(&sim, offline));
        }
    }
    let real: Vec<RecordingValues> = train
        .iter()
        .map(|(_, r)| recording_values(r, offline))
        .collect();
    let models = vec![
        (base.label(), base_vals.into_iter().flatten().collect()),
        (name.to_string(), pop_vals.into_iter().flatten().collect()),
    ];
    let sp = fishprobe_analysis::offline::spread::offline_spread(
        &real, &models, offline, seed, "fit/cv",
    );
    Ok(json!({"folds": k, "result": spread_json(&sp, &Default::default(), &cfg.statistics, n)}))
}

/// The report: per check (training, validation, cross-validation), per statistic, the s.d.
/// ratio and W1 of the base model and the population, beside the floor.
fn report_markdown(pop: &PopulationParams) -> String {
    let base = pop.base.as_deref().map_or("?".into(), ModelSpec::label);
    let f = &pop.fit;
    let mut s = format!(
        "# {}: a population of {base}\n\nFitted in {:.0} s ({} iterations, objective {:.3}) on {} training recordings.\n\n",
        pop.name,
        f["seconds"].as_f64().unwrap_or(f64::NAN),
        f["iterations"],
        f["objective"].as_f64().unwrap_or(f64::NAN),
        f["training_files"].as_array().map_or(0, Vec::len),
    );
    s += "| trait | mean (population scale) | s.d. |\n|---|---|---|\n";
    for (i, t) in pop.traits.iter().enumerate() {
        s += &format!(
            "| {} | {:.3} | {:.3} |\n",
            t.name(),
            pop.mean[i],
            pop.cov[i][i].max(0.0).sqrt()
        );
    }
    let table = |title: &str, v: &serde_json::Value| -> String {
        if v.is_null() {
            return String::new();
        }
        let mut t = format!(
            "\n## {title} ({} recordings)\n\n| statistic | floor W1 | M_{base} ratio | M_{base} W1 | {} ratio | {} W1 |\n|---|---|---|---|---|---|\n",
            v["recordings"], pop.name, pop.name
        );
        let stats: Vec<&String> = v["floor"]
            .as_object()
            .map(|o| o.keys().collect())
            .unwrap_or_default();
        for st in stats {
            let cell = |m: &str, k: &str| {
                v["models"][m]["spread"][st.as_str()][k]
                    .as_f64()
                    .map_or("–".into(), |x| format!("{x:.3}"))
            };
            t += &format!(
                "| {st} | {} | {} | {} | {} | {} |\n",
                v["floor"][st.as_str()]
                    .as_f64()
                    .map_or("–".into(), |x| format!("{x:.3}")),
                cell(&base, "ratio"),
                cell(&base, "w1"),
                cell(&pop.name, "ratio"),
                cell(&pop.name, "w1"),
            );
        }
        t
    };
    s += &table("On the training recordings", &f["training"]);
    s += &table(
        "On recordings it did not use (validation)",
        &f["validation"],
    );
    if !f["cross_validation"].is_null() {
        s += &table(
            &format!(
                "{}-fold cross-validation on the training recordings",
                f["cross_validation"]["folds"]
            ),
            &f["cross_validation"]["result"],
        );
    }
    s
}
