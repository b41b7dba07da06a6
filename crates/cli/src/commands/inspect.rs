//! `fishprobe inspect`: what is in trial files (any robofish.io file, or the lab's legacy
//! layout).

use anyhow::Result;
use clap::Args;
use fishprobe_io::{IoError, TrialFile};
use serde::Serialize;
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

/// Reads either layout, with the layout's name.
fn read_any(path: &Path) -> Result<(TrialFile, &'static str), IoError> {
    fishprobe_io::read_any_trial_layout(path).map(|(t, l)| (t, l.label()))
}

/// What `inspect` reports of one file (`--json` prints it; fields in alphabetical order).
#[derive(Debug, Serialize)]
struct FileSummary {
    attributes: std::collections::BTreeMap<String, Value>,
    duration_s: f32,
    entities: Vec<EntitySummary>,
    file: String,
    frame_rate_hz: f32,
    layout: &'static str,
    task: Option<TaskSummary>,
    world_size_cm: [f32; 2],
}

/// One entity of a file.
#[derive(Debug, Serialize)]
struct EntitySummary {
    category: String,
    frames: usize,
    mean_speed_cm_s: Option<f32>,
    name: String,
    nan_fraction: f32,
}

/// The task record fishprobe wrote, if any.
#[derive(Debug, Serialize)]
struct TaskSummary {
    commands: usize,
    control_start_frame: u64,
    fish_model: String,
    goal_radius_cm: f32,
    goals: Vec<[f32; 2]>,
    goals_reached: usize,
    kind: String,
    policy: String,
    policy_sha256: Option<String>,
    program_version: String,
    seed: u64,
}

/// A file that could not be read.
#[derive(Debug, Serialize)]
struct FileError {
    error: String,
    file: String,
}

/// One file's line in the report.
#[derive(Debug, Serialize)]
#[serde(untagged)]
enum Report {
    Read(Box<FileSummary>),
    Failed(FileError),
}

fn summary(path: &Path, t: &TrialFile, layout: &'static str) -> FileSummary {
    FileSummary {
        attributes: fishprobe_io::robofish::attributes_json(t),
        duration_s: t.duration_s(),
        entities: t
            .entities
            .iter()
            .map(|e| EntitySummary {
                category: e.category_label.clone(),
                frames: e.frames(),
                mean_speed_cm_s: e.mean_speed(t.frame_rate_hz),
                name: e.name.clone(),
                nan_fraction: e.nan_fraction(),
            })
            .collect(),
        file: path.display().to_string(),
        frame_rate_hz: t.frame_rate_hz,
        layout,
        task: t.task.as_ref().map(|r| TaskSummary {
            commands: r.command_frames.len(),
            control_start_frame: r.control_start_frame,
            fish_model: r.fish_model.clone(),
            goal_radius_cm: r.goal_radius_cm,
            goals: r.goals.clone(),
            goals_reached: r.goal_frames.len(),
            kind: r.kind.label().to_string(),
            policy: r.policy.clone(),
            policy_sha256: r.policy_sha256(),
            program_version: r.program_version.clone(),
            seed: r.seed,
        }),
        world_size_cm: t.world_size_cm,
    }
}

/// A number as JSON writes it (`100.0`, not `100`): the text report reads as `--json` does.
fn num<T: Serialize>(x: T) -> String {
    serde_json::to_string(&x).unwrap_or_default()
}

fn write_text(out: &mut String, v: &FileSummary) -> std::fmt::Result {
    writeln!(out, "{}", v.file)?;
    writeln!(
        out,
        "  {}; world {} x {} cm; {} Hz; {:.1} s",
        v.layout,
        num(v.world_size_cm[0]),
        num(v.world_size_cm[1]),
        num(v.frame_rate_hz),
        f64::from(v.duration_s)
    )?;
    for e in &v.entities {
        let speed = e
            .mean_speed_cm_s
            .map_or("-".to_string(), |s| format!("{:.1} cm/s", f64::from(s)));
        writeln!(
            out,
            "  {:<10} {:<8} {:>7} frames  {:>5.1} % untracked  mean speed {}",
            e.name,
            e.category,
            e.frames,
            100.0 * f64::from(e.nan_fraction),
            speed
        )?;
    }
    if let Some(t) = &v.task {
        writeln!(
            out,
            "  task: {} trial, policy {}{}, fish model {}, seed {}; {} goals reached; {} robot commands; control from frame {}",
            t.kind,
            t.policy,
            t.policy_sha256.as_deref().map_or_else(String::new, |s| {
                format!(" (weights sha256 {}…)", fishprobe_io::short_sha(s))
            }),
            t.fish_model,
            t.seed,
            t.goals_reached,
            t.commands,
            t.control_start_frame
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
                reports.push(Report::Read(Box::new(v)));
            }
            Err(e) => {
                failed += 1;
                say!("error: {e}");
                reports.push(Report::Failed(FileError {
                    error: e.to_string(),
                    file: path.display().to_string(),
                }));
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
