//! `fishprobe inspect`: what is in trial files (any robofish.io file, or the lab's legacy
//! layout).

use anyhow::Result;
use clap::Args;
use fishprobe_io::{read_legacy, read_trial, IoError, TrialFile};
use serde_json::{json, Value};
use std::fmt::Write;
use std::path::{Path, PathBuf};

use super::emit;

#[derive(Debug, Args)]
pub struct InspectArgs {
    /// Trial files (HDF5).
    #[arg(required = true)]
    files: Vec<PathBuf>,
    /// Print JSON (one object with a list of files) instead of text.
    #[arg(long)]
    json: bool,
}

/// Reads robofish.io, falling back to the legacy layout when the file says it is one.
fn read_any(path: &Path) -> Result<(TrialFile, &'static str), IoError> {
    match read_trial(path) {
        Ok(t) => Ok((t, "robofish.io 1.0")),
        Err(e) if e.to_string().contains("import-legacy") => {
            Ok((read_legacy(path)?, "legacy (pre-2020)"))
        }
        Err(e) => Err(e),
    }
}

fn summary(path: &Path, t: &TrialFile, layout: &str) -> Value {
    let entities: Vec<Value> = t
        .entities
        .iter()
        .map(|e| {
            json!({
                "name": e.name,
                "category": e.category_label,
                "frames": e.frames(),
                "nan_fraction": e.nan_fraction(),
                "mean_speed_cm_s": e.mean_speed(t.frame_rate_hz),
            })
        })
        .collect();
    let task = t.task.as_ref().map(|r| {
        json!({
            "kind": r.kind.label(),
            "policy": r.policy,
            "policy_sha256": r.policy_sha256(),
            "fish_model": r.fish_model,
            "seed": r.seed,
            "goal_radius_cm": r.goal_radius_cm,
            "goals": r.goals,
            "goals_reached": r.goal_frames.len(),
            "commands": r.command_frames.len(),
            "control_start_frame": r.control_start_frame,
            "program_version": r.program_version,
        })
    });
    json!({
        "file": path.display().to_string(),
        "layout": layout,
        "world_size_cm": t.world_size_cm,
        "frame_rate_hz": t.frame_rate_hz,
        "duration_s": t.duration_s(),
        "entities": entities,
        "task": task,
        "attributes": fishprobe_io::robofish::attributes_json(t),
    })
}

fn write_text(out: &mut String, v: &Value) -> std::fmt::Result {
    writeln!(out, "{}", v["file"].as_str().unwrap_or_default())?;
    writeln!(
        out,
        "  {}; world {} x {} cm; {} Hz; {:.1} s",
        v["layout"].as_str().unwrap_or_default(),
        v["world_size_cm"][0],
        v["world_size_cm"][1],
        v["frame_rate_hz"],
        v["duration_s"].as_f64().unwrap_or(0.0)
    )?;
    for e in v["entities"].as_array().into_iter().flatten() {
        let speed = e["mean_speed_cm_s"]
            .as_f64()
            .map_or("-".to_string(), |s| format!("{s:.1} cm/s"));
        writeln!(
            out,
            "  {:<10} {:<8} {:>7} frames  {:>5.1} % untracked  mean speed {}",
            e["name"].as_str().unwrap_or_default(),
            e["category"].as_str().unwrap_or_default(),
            e["frames"],
            100.0 * e["nan_fraction"].as_f64().unwrap_or(0.0),
            speed
        )?;
    }
    if let Some(t) = v["task"].as_object() {
        writeln!(
            out,
            "  task: {} trial, policy {}{}, fish model {}, seed {}; {} goals reached; {} robot commands; control from frame {}",
            t["kind"].as_str().unwrap_or_default(),
            t["policy"].as_str().unwrap_or_default(),
            t["policy_sha256"]
                .as_str()
                .map_or_else(String::new, |s| {
                    format!(" (weights sha256 {}…)", fishprobe_io::short_sha(s))
                }),
            t["fish_model"].as_str().unwrap_or_default(),
            t["seed"],
            t["goals_reached"],
            t["commands"],
            t["control_start_frame"]
        )?;
    } else {
        writeln!(out, "  task: none recorded (not written by fishprobe)")?;
    }
    Ok(())
}

pub fn run(a: InspectArgs) -> Result<()> {
    let mut reports = Vec::new();
    let mut failed = 0;
    let mut text = String::new();
    for path in &a.files {
        match read_any(path) {
            Ok((t, layout)) => {
                let v = summary(path, &t, layout);
                if !a.json {
                    write_text(&mut text, &v)?;
                }
                reports.push(v);
            }
            Err(e) => {
                failed += 1;
                say!("error: {e}");
                reports.push(json!({ "file": path.display().to_string(), "error": e.to_string() }));
            }
        }
    }
    if a.json {
        text = serde_json::to_string_pretty(&json!({ "files": reports }))? + "\n";
    }
    emit(&text)?;
    if failed > 0 {
        anyhow::bail!("{failed} of {} files could not be read", a.files.len());
    }
    Ok(())
}
