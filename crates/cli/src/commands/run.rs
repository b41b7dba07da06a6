//! `fishprobe run`: the whole study in one command.

use anyhow::{bail, Context, Result};
use clap::Args;
use fishprobe_study::{Event, Study, StudyConfig, StudyFile};
use indicatif::{ProgressBar, ProgressStyle};
use std::collections::BTreeSet;
use std::path::PathBuf;
use std::sync::Mutex;
use std::time::Instant;

use super::emit;

#[derive(Debug, Args)]
pub struct RunArgs {
    /// Budget: `quick` (a complete study in minutes), `paper` (the published protocol with
    /// PPO's `paper` preset, see `fishprobe train --help`; about 50 minutes on 2 cores on a
    /// fast day), `published` (the same with the published PPO settings, hours) or `smoke`
    /// (tiny, for tests).
    #[arg(long, default_value = "quick")]
    preset: String,
    /// Study file (TOML): overrides of the preset and extra models, e.g.
    /// `[[extra_models]] name = "Zone-radii"` with `spec = { model = "Zone", zone_convention = "radii" }`,
    /// and policies trained elsewhere: `[[policies]] model = "Zone"`, `policy = "onnx:zone.onnx"`.
    #[arg(long)]
    config: Option<PathBuf>,
    /// The study directory (rerunning the same command resumes it).
    #[arg(long, default_value = "study")]
    out: PathBuf,
    /// Steps run at once (default: the number of cores).
    #[arg(long)]
    jobs: Option<usize>,
    /// Where steps run: `local`, or `slurm` (training and evaluation as SLURM job arrays with
    /// dependencies; the study directory and the fishprobe binary must be visible to the nodes).
    #[arg(long, default_value = "local")]
    executor: String,
    /// Extra sbatch arguments for `--executor slurm` (repeat: `--sbatch-arg=--partition=cpu`).
    #[arg(long, allow_hyphen_values = true)]
    sbatch_arg: Vec<String>,
    /// Run only this step of the plan (what a SLURM array task runs).
    #[arg(long, hide = true)]
    step: Option<String>,
    /// Live trials: a directory of `<Policy>__Real/` trial directories (default: the virtual lab).
    #[arg(long)]
    real: Option<PathBuf>,
    /// Master seed (overrides the study file's).
    #[arg(long)]
    seed: Option<u64>,
    /// Refit M_ConvNet on these pair recordings (`DIR/train/`, `DIR/validation/`) instead of
    /// using the shipped weights.
    #[arg(long)]
    convnet_data: Option<PathBuf>,
}

pub fn run(a: RunArgs) -> Result<()> {
    if a.executor != "local" && a.executor != "slurm" {
        bail!("--executor {}: use local or slurm", a.executor);
    }
    let mut cfg: StudyConfig = match &a.config {
        Some(p) => {
            let f: StudyFile = super::read_toml(p, "study file")?;
            let dir = p.parent().unwrap_or_else(|| std::path::Path::new("."));
            f.apply_in(&a.preset, dir)
                .with_context(|| format!("study file {}", p.display()))?
        }
        None => StudyConfig::preset(&a.preset).with_context(|| {
            format!(
                "unknown --preset `{}`: use smoke, quick, paper or published",
                a.preset
            )
        })?,
    };
    if let Some(s) = a.seed {
        cfg.seed = s;
    }
    let jobs = super::resolve_jobs(a.jobs)?
        .unwrap_or_else(|| std::thread::available_parallelism().map_or(1, |n| n.get()));
    let mut study =
        Study::with_convnet_data(a.out.clone(), cfg, a.real.clone(), a.convnet_data.clone())?;
    study.program_build = super::BUILD.into();
    if let Some(id) = &a.step {
        // A SLURM array task: steps run concurrently in one study, so each locks only itself
        // (the submitting `run` holds the study's lock meanwhile).
        let lock = study.layout().step_locks().join(format!("{id}.lock"));
        let _lock =
            fishprobe_io::DirLock::acquire_file(&a.out, &lock, &format!("run --step {id}"))?;
        study.run_one(id)?;
        return emit(&format!("step {id} complete\n"));
    }
    // One writer per study: a second `run` on it is refused at once.
    let _lock = super::lock_out(&a.out, "run")?;
    let bar = ProgressBar::new(0);
    bar.set_style(
        ProgressStyle::with_template(
            "{spinner} [{elapsed_precise}] {bar:30} {pos}/{len} steps  {msg}",
        )
        .unwrap_or_else(|_| ProgressStyle::default_bar()),
    );
    let running: Mutex<BTreeSet<String>> = Mutex::new(BTreeSet::new());
    let started = Instant::now();
    let on_event = |e: Event| {
        let mut r = running.lock().unwrap_or_else(|p| p.into_inner());
        let line = match &e {
            Event::Planned {
                total,
                complete,
                older,
            } => {
                bar.set_length(*total as u64);
                bar.set_position(*complete as u64);
                let mut line = format!("{total} steps, {complete} complete from an earlier run");
                if *older > 0 {
                    line.push_str(&format!(
                        "; {older} recorded by an older fishprobe, whose records held less of \
                         what each step reads, are recomputed once"
                    ));
                }
                line
            }
            Event::Started(id) => {
                r.insert(id.clone());
                format!("started {id}")
            }
            Event::Finished(id, secs) => {
                r.remove(id);
                bar.inc(1);
                format!("finished {id} in {secs:.1} s")
            }
            Event::Warning(id, w) => {
                // Shown whether or not the progress bar is.
                bar.suspend(|| say!("warning: {id}: {w}"));
                return;
            }
        };
        bar.set_message(r.iter().cloned().collect::<Vec<_>>().join(", "));
        if bar.is_hidden() {
            say!("[{:7.1} s] {line}", started.elapsed().as_secs_f64());
        }
    };
    let result = if a.executor == "slurm" {
        let abs = |p: &PathBuf| {
            p.canonicalize()
                .unwrap_or_else(|_| p.clone())
                .display()
                .to_string()
        };
        let mut study_args = vec!["--preset".to_string(), a.preset.clone()];
        if let Some(c) = &a.config {
            study_args.extend(["--config".into(), abs(c)]);
        }
        if let Some(r) = &a.real {
            study_args.extend(["--real".into(), abs(r)]);
        }
        if let Some(s) = a.seed {
            study_args.extend(["--seed".into(), s.to_string()]);
        }
        if let Some(d) = &a.convnet_data {
            study_args.extend(["--convnet-data".into(), abs(d)]);
        }
        let o = fishprobe_study::slurm::SlurmOptions {
            fishprobe: std::env::current_exe().context("locating the fishprobe binary")?,
            study_args,
            sbatch_args: a.sbatch_arg.clone(),
            poll_s: 2.0,
            timeout_s: None,
        };
        study.run_slurm(&o, &on_event)
    } else {
        study.run(jobs, &on_event)
    };
    bar.finish_and_clear();
    result.with_context(|| format!("running the study in {}", a.out.display()))?;
    let summary =
        fishprobe_io::read_small_text(&a.out.join("analysis/summary.md")).unwrap_or_default();
    emit(&format!(
        "{summary}\nStudy complete in {}: {}/report/index.html\n",
        took(started.elapsed().as_secs_f64()),
        a.out.display()
    ))
}

/// A run's duration for people: seconds under a minute (a smoke study said "0.0 min"), else
/// minutes to a tenth.
fn took(seconds: f64) -> String {
    if seconds < 59.95 {
        format!("{seconds:.1} s")
    } else {
        format!("{:.1} min", seconds / 60.0)
    }
}

#[cfg(test)]
mod tests {
    use super::took;

    #[test]
    fn durations_read_in_seconds_under_a_minute_and_minutes_above() {
        assert_eq!(took(2.94), "2.9 s");
        assert_eq!(took(59.9), "59.9 s");
        assert_eq!(took(59.97), "1.0 min");
        assert_eq!(took(1786.0), "29.8 min");
    }
}
