//! `fishprobe models`: every fish model with its parameters, and optionally its measured
//! motion statistics beside the real guppies'.

use anyhow::{Context, Result};
use clap::Args;
use fishprobe_models::measure::{measure, Condition, Measurement};
use fishprobe_models::ModelSpec;
use rayon::prelude::*;
use serde_json::{json, Value};
use std::fmt::Write;

use super::{emit, params_json};

#[derive(Debug, Args)]
pub struct ModelsArgs {
    /// Print JSON instead of text.
    #[arg(long)]
    json: bool,
    /// Also simulate each model and report its speed, turn-rate and wall-distance
    /// distributions (solitary, and with a randomly driven robot).
    #[arg(long)]
    measure: bool,
    /// Episodes per model and condition for --measure.
    #[arg(long, default_value_t = 8, requires = "measure")]
    episodes: u32,
    /// Minutes per episode for --measure.
    #[arg(long, default_value_t = 6.0, requires = "measure")]
    minutes: f32,
    /// Master seed for --measure.
    #[arg(long, default_value_t = 0, requires = "measure")]
    seed: u64,
    /// List (and measure) these models instead of the built-in ones: names, or `onnx:FILE`
    /// for a model brought as an ONNX file (repeat the option).
    #[arg(long)]
    model: Vec<String>,
    /// List the candidate models of a study (its `study.json`), each with its origin.
    #[arg(long, conflicts_with = "model")]
    study: Option<std::path::PathBuf>,
}

/// Real guppy pairs, 48 training recordings (../shared/data/README.md).
const REAL_GUPPIES: &str =
    "real guppy pairs (data README): speed mean 6.0, median 5.3, p90 11.9 cm/s; \
paused (<0.5 cm/s) 0-45 % per fish; wall distance mean 13.1, median 11.1 cm; IID median 5.3 cm";

pub fn run(a: ModelsArgs) -> Result<()> {
    super::no_repeats("--model", &a.model)?;
    // (the name each model carries, its spec)
    let named: Vec<(String, ModelSpec)> = if let Some(dir) = &a.study {
        let file = fishprobe_io::StudyLayout::new(dir).config();
        let text = fishprobe_io::read_small_text(&file)
            .with_context(|| format!("reading {} (made by fishprobe run)", file.display()))?;
        let cfg: fishprobe_study::StudyConfig =
            serde_json::from_str(&text).with_context(|| format!("{}", file.display()))?;
        cfg.models.into_iter().map(|m| (m.name, m.spec)).collect()
    } else if a.model.is_empty() {
        ModelSpec::listed_names()
            .iter()
            .map(|n| ModelSpec::by_name(n).map(|s| (n.to_string(), s)))
            .collect::<Result<_, _>>()?
    } else {
        a.model
            .iter()
            .map(|n| {
                let s = ModelSpec::by_name(n)?;
                s.build().with_context(|| format!("model {n}"))?;
                Ok((n.clone(), s))
            })
            .collect::<Result<_>>()?
    };
    let measurements = if a.measure {
        super::check_minutes("--minutes", a.minutes)?;
        if a.episodes == 0 || a.episodes > 10_000 {
            anyhow::bail!("--episodes must lie in [1, 10000], got {}", a.episodes);
        }
        // Each measurement under the name the model is listed by (a population's own name,
        // not its spec's kind).
        let jobs: Vec<(&str, &ModelSpec, Condition)> = named
            .iter()
            .filter(|(_, s)| s.name() != "Stationary")
            .flat_map(|(n, s)| {
                [Condition::Solitary, Condition::RandomRobot].map(|c| (n.as_str(), s, c))
            })
            .collect();
        jobs.par_iter()
            .map(|(n, s, c)| {
                let mut m = measure(s, *c, a.episodes, a.minutes, a.seed)
                    .with_context(|| format!("measuring {n}"))?;
                m.model = n.to_string();
                Ok(m)
            })
            .collect::<Result<Vec<_>>>()?
    } else {
        Vec::new()
    };
    let mut text = String::new();
    if a.json {
        let models: Vec<Value> = named
            .iter()
            .map(|(n, s)| {
                let mut v = model_json(s)?;
                v["candidate"] = json!(n);
                Ok(v)
            })
            .collect::<Result<_>>()?;
        let out = json!({ "models": models, "measurements": params_json(&measurements)? });
        text = serde_json::to_string_pretty(&out)? + "\n";
    } else {
        for (n, s) in &named {
            if n != s.name() {
                writeln!(text, "candidate {n}:")?;
            }
            write_model(&mut text, s)?;
        }
        if !measurements.is_empty() {
            write_measurements(&mut text, &measurements, &a)?;
        }
    }
    emit(&text)
}

fn model_json(s: &ModelSpec) -> Result<Value> {
    let mut params = params_json(s)?;
    if let Some(m) = params.as_object_mut() {
        m.remove("model");
    }
    Ok(json!({
        "name": s.name(),
        "origin": s.origin(),
        "summary": s.summary(),
        "params": params,
        "fields": s.field_docs().iter()
            .map(|f| json!({ "name": f.name, "unit": f.unit, "doc": f.text() }))
            .collect::<Vec<_>>(),
    }))
}

fn write_model(out: &mut String, s: &ModelSpec) -> Result<()> {
    if let ModelSpec::Population(p) = s {
        return write_population(out, p);
    }
    writeln!(out, "{} — {} [{}]", s.name(), s.summary(), s.origin())?;
    let values = params_json(s)?;
    for f in s.field_docs() {
        let v = values.get(f.name).map(Value::to_string).unwrap_or_default();
        writeln!(out, "  {:<26} {:>9} {:<10} {}", f.name, v, f.unit, f.text())?;
    }
    if s.field_docs().is_empty() {
        writeln!(out, "  (no parameters)")?;
    }
    writeln!(out)?;
    Ok(())
}

/// A population as a table of its traits (mean, spread, the value at the mean on the trait's
/// own scale) and one line of its fit; the whole record is in its file (`--json`).
fn write_population(out: &mut String, p: &fishprobe_models::PopulationParams) -> Result<()> {
    let base = p.base.as_deref().map_or("?".into(), ModelSpec::label);
    writeln!(
        out,
        "{} — a population of {base}: each fish an individual drawn from a fitted joint distribution of traits",
        p.name
    )?;
    writeln!(
        out,
        "  {:<12} {:>8} {:>8} {:>12}",
        "trait", "mean", "s.d.", "at the mean"
    )?;
    for (i, t) in p.traits.iter().enumerate() {
        let at = if t.is_log() {
            p.mean[i].exp()
        } else {
            p.mean[i]
        };
        writeln!(
            out,
            "  {:<12} {:>8.3} {:>8.3} {:>12.3}",
            t.name(),
            p.mean[i],
            p.cov[i][i].max(0.0).sqrt(),
            at
        )?;
    }
    writeln!(
        out,
        "  (mean and s.d. on the trait's scale: the logarithm of multipliers, pause rate and duration; latent coordinates as they are)"
    )?;
    if let Some(c) = p.fit.get("command").and_then(Value::as_str) {
        writeln!(out, "  fitted by: {c}")?;
    }
    writeln!(out)?;
    Ok(())
}

fn write_measurements(out: &mut String, ms: &[Measurement], a: &ModelsArgs) -> Result<()> {
    writeln!(
        out,
        "Measured: {} episodes x {} min per model and condition, seed {} (25 Hz; speed and turn rate from consecutive frames)",
        a.episodes, a.minutes, a.seed
    )?;
    writeln!(
        out,
        "{:<8} {:<13} {:>27} {:>7} {:>17} {:>17} {:>10} {:>8}",
        "model",
        "condition",
        "speed mean/median/p90 cm/s",
        "paused",
        "|turn| med/p90",
        "wall dist mean/med",
        "IID median",
        "contacts"
    )?;
    for m in ms {
        let cond = match m.condition {
            Condition::Solitary => "solitary",
            Condition::RandomRobot => "random robot",
        };
        writeln!(
            out,
            "{:<8} {:<13} {:>9.1} {:>8.1} {:>8.1} {:>6.0}% {:>8.2} {:>8.2} {:>8.1} {:>8.1} {:>10} {:>8.2}",
            m.model,
            cond,
            m.speed.mean,
            m.speed.median,
            m.speed.p90,
            100.0 * m.pause_fraction,
            m.turn_rate.median,
            m.turn_rate.p90,
            m.wall_distance.mean,
            m.wall_distance.median,
            m.robot_distance.map(|d| format!("{:.1}", d.median)).unwrap_or_else(|| "-".into()),
            m.wall_contacts_per_min,
        )?;
    }
    writeln!(
        out,
        "(contacts: wall-clipped frames per minute; rad/s for turn rates)"
    )?;
    writeln!(out, "Reference, {REAL_GUPPIES}")?;
    Ok(())
}
