//! The SLURM executor: for studies that outgrow one machine, the training steps go to the
//! cluster as one job array, the evaluation steps (sim cells, approach, stability, reality arm)
//! as a second array that starts after the first succeeded (`--dependency=afterok`); the
//! executor waits for both, then analyses and reports locally. Each array task runs
//! `fishprobe run --step ID` with the same study arguments, so steps are exactly the local
//! executor's (markers, atomic outputs, resumable).

use crate::{Event, Step, StepError, StepKind, Study, StudyError};
use std::path::PathBuf;
use std::process::Command;
use std::time::{Duration, Instant};

/// How to reach SLURM and how to call fishprobe on the nodes.
#[derive(Debug, Clone)]
pub struct SlurmOptions {
    /// The fishprobe binary the tasks run (a path the nodes can see).
    pub fishprobe: PathBuf,
    /// The study arguments to repeat on the nodes (`--preset`, `--config`, `--real`, `--seed`).
    pub study_args: Vec<String>,
    /// Extra `sbatch` arguments (e.g. `--partition=cpu`, `--time=04:00:00`).
    pub sbatch_args: Vec<String>,
    /// Seconds between `squeue` polls.
    pub poll_s: f64,
    /// Give up after this long (None: never).
    pub timeout_s: Option<f64>,
}

fn io(path: &std::path::Path, e: impl std::fmt::Display) -> StudyError {
    StudyError::Io {
        path: path.to_path_buf(),
        what: e.to_string(),
    }
}

fn sh_quote(s: &str) -> String {
    format!("'{}'", s.replace('\'', r"'\''"))
}

/// Submits one array over `ids` (after `after`, if any); returns the job id.
fn submit(
    study: &Study,
    o: &SlurmOptions,
    name: &str,
    ids: &[String],
    after: Option<&str>,
) -> Result<String, StudyError> {
    let dir = study.layout().slurm();
    std::fs::create_dir_all(&dir).map_err(|e| io(&dir, e))?;
    let list = dir.join(format!("{name}.txt"));
    std::fs::write(&list, ids.join("\n") + "\n").map_err(|e| io(&list, e))?;
    let script = dir.join(format!("{name}.sh"));
    let root = study
        .root
        .canonicalize()
        .unwrap_or_else(|_| study.root.clone());
    let args: Vec<String> = o.study_args.iter().map(|a| sh_quote(a)).collect();
    let text = format!(
        "#!/bin/bash\n# fishprobe study step, one per array task (written by fishprobe run --executor slurm)\nset -euo pipefail\nID=$(sed -n \"$((SLURM_ARRAY_TASK_ID + 1))p\" {list})\nexec {exe} run --out {root} {args} --step \"$ID\"\n",
        list = sh_quote(&list.display().to_string()),
        exe = sh_quote(&o.fishprobe.display().to_string()),
        root = sh_quote(&root.display().to_string()),
        args = args.join(" "),
    );
    std::fs::write(&script, text).map_err(|e| io(&script, e))?;
    let logs = root.join("logs");
    let mut cmd = Command::new("sbatch");
    cmd.arg("--parsable")
        .arg(format!("--job-name=fishprobe-{name}"))
        .arg(format!("--array=0-{}", ids.len() - 1))
        .arg(format!("--output={}/slurm-%A_%a.out", logs.display()));
    if let Some(j) = after {
        cmd.arg(format!("--dependency=afterok:{j}"));
    }
    cmd.args(&o.sbatch_args).arg(&script);
    let out = cmd
        .output()
        .map_err(|e| StudyError::Input(format!("running sbatch: {e} (is SLURM installed?)")))?;
    if !out.status.success() {
        return Err(StudyError::Input(format!(
            "sbatch refused the {name} array: {}",
            String::from_utf8_lossy(&out.stderr).trim()
        )));
    }
    let id = String::from_utf8_lossy(&out.stdout)
        .trim()
        .split(';')
        .next()
        .unwrap_or("")
        .to_string();
    if id.is_empty() {
        return Err(StudyError::Input("sbatch printed no job id".into()));
    }
    Ok(id)
}

fn queued(jobs: &[String]) -> Result<bool, StudyError> {
    let out = Command::new("squeue")
        .args(["-h", "-o", "%i", "-j", &jobs.join(",")])
        .output()
        .map_err(|e| StudyError::Input(format!("running squeue: {e}")))?;
    // squeue fails for job ids it no longer knows: then they are gone.
    Ok(out.status.success() && !String::from_utf8_lossy(&out.stdout).trim().is_empty())
}

impl Study {
    /// Runs the study with SLURM job arrays for training and evaluation, then analyses and
    /// reports locally.
    pub fn run_slurm(
        &self,
        o: &SlurmOptions,
        on_event: &(dyn Fn(Event) + Sync),
    ) -> Result<(), StudyError> {
        let steps = self.prepare()?;
        // Refitting M_ConvNet comes before any training: done here, on this machine.
        if let Some(s) = steps.iter().find(|s| s.kind == StepKind::FitConvnet) {
            self.run_one(&s.id)?;
        }
        let todo = |pred: &dyn Fn(&Step) -> bool| -> Vec<String> {
            steps
                .iter()
                .filter(|s| pred(s) && !self.is_complete(s))
                .map(|s| s.id.clone())
                .collect()
        };
        let train = todo(&|s| matches!(s.kind, StepKind::Train { .. }));
        let eval = todo(&|s| {
            !matches!(
                s.kind,
                StepKind::Train { .. } | StepKind::Analyze | StepKind::Report
            )
        });
        on_event(Event::Planned {
            total: steps.len(),
            complete: steps.len() - train.len() - eval.len() - 2,
            older: steps.iter().filter(|s| self.marked_by_older(s)).count(),
        });
        let mut jobs = Vec::new();
        let train_job = if train.is_empty() {
            None
        } else {
            let j = submit(self, o, "train", &train, None)?;
            on_event(Event::Started(format!(
                "SLURM job {j}: {} training steps",
                train.len()
            )));
            jobs.push(j.clone());
            Some(j)
        };
        if !eval.is_empty() {
            let j = submit(self, o, "evaluate", &eval, train_job.as_deref())?;
            on_event(Event::Started(format!(
                "SLURM job {j}: {} evaluation steps",
                eval.len()
            )));
            jobs.push(j);
        }
        let start = Instant::now();
        while !jobs.is_empty() && queued(&jobs)? {
            if o.timeout_s
                .is_some_and(|t| start.elapsed().as_secs_f64() > t)
            {
                return Err(StudyError::Input(format!(
                    "SLURM jobs {} still queued after the timeout",
                    jobs.join(",")
                )));
            }
            std::thread::sleep(Duration::from_secs_f64(o.poll_s));
        }
        let missing: Vec<&Step> = steps
            .iter()
            .filter(|s| {
                !matches!(s.kind, StepKind::Analyze | StepKind::Report) && !self.is_complete(s)
            })
            .collect();
        if let Some(s) = missing.first() {
            return Err(StudyError::Step {
                step: s.id.clone(),
                source: Box::new(StepError::Missing(format!(
                    "{} step(s) did not complete on the cluster (see logs/slurm-*.out)",
                    missing.len()
                ))),
                log: self.log_path(s),
            });
        }
        for id in train.iter().chain(&eval) {
            on_event(Event::Finished(id.clone(), 0.0));
        }
        // Analysis and report locally: everything else is complete now.
        self.run(1, on_event)
    }
}
