//! The scheduler: runs the plan's incomplete steps, up to `jobs` at once, each on its own
//! thread pool, in dependency order; or one step alone (a SLURM array task).

use crate::error::{StepError, StudyError};
use crate::{steps, Study};
use std::sync::mpsc;
use std::time::Instant;

/// Events for a progress display.
#[derive(Debug, Clone, PartialEq)]
pub enum Event {
    /// The plan: how many steps, how many already complete.
    Planned {
        /// Steps.
        total: usize,
        /// Complete and valid from an earlier run.
        complete: usize,
        /// Recorded by an older fishprobe, whose completion markers held something else:
        /// recomputed once.
        older: usize,
    },
    /// A step started.
    Started(String),
    /// A step finished after this many seconds.
    Finished(String, f64),
    /// A finished step's warning (also in its log): what the user should know about its
    /// result.
    Warning(String, String),
}

impl Study {
    /// Runs the one step `id` (its dependencies must be complete): what a SLURM array task
    /// does. A complete step is left alone.
    pub fn run_one(&self, id: &str) -> Result<(), StudyError> {
        let steps = self.plan()?;
        let s = steps
            .iter()
            .find(|s| s.id == id)
            .ok_or_else(|| StudyError::Input(format!("no step `{id}` in this study's plan")))?;
        if self.is_complete(s) {
            return Ok(());
        }
        if let Some(d) = s.deps.iter().find(|&&d| !self.is_complete(&steps[d])) {
            return Err(StudyError::Input(format!(
                "step `{id}` needs `{}`, which is not complete",
                steps[*d].id
            )));
        }
        let start = Instant::now();
        // A SLURM task's warnings stay in the step's log.
        steps::run_step(self, s).map_err(|source| StudyError::Step {
            step: s.id.clone(),
            source: Box::new(source),
            log: self.log_path(s),
        })?;
        self.mark(s, start.elapsed().as_secs_f64())
    }

    /// Runs every incomplete step, up to `jobs` at once, reporting progress to `on_event`.
    pub fn run(&self, jobs: usize, on_event: &(dyn Fn(Event) + Sync)) -> Result<(), StudyError> {
        let steps = self.prepare()?;
        let mut done: Vec<bool> = steps.iter().map(|s| self.is_complete(s)).collect();
        on_event(Event::Planned {
            total: steps.len(),
            complete: done.iter().filter(|d| **d).count(),
            older: steps.iter().filter(|s| self.marked_by_older(s)).count(),
        });
        let jobs = jobs.max(1);
        let threads = (std::thread::available_parallelism().map_or(1, |n| n.get()) / jobs).max(1);
        let mut running = vec![false; steps.len()];
        let (tx, rx) = mpsc::channel::<(usize, Result<(f64, Vec<String>), StepError>)>();
        let mut failure: Option<StudyError> = None;
        std::thread::scope(|scope| loop {
            let active = running.iter().filter(|r| **r).count();
            if failure.is_none() {
                let ready: Vec<usize> = (0..steps.len())
                    .filter(|&i| !done[i] && !running[i] && steps[i].deps.iter().all(|&d| done[d]))
                    .take(jobs.saturating_sub(active))
                    .collect();
                for i in ready {
                    running[i] = true;
                    on_event(Event::Started(steps[i].id.clone()));
                    let tx = tx.clone();
                    let step = &steps[i];
                    scope.spawn(move || {
                        let start = Instant::now();
                        let r = rayon::ThreadPoolBuilder::new()
                            .num_threads(threads)
                            .build()
                            .map_err(StepError::from)
                            .and_then(|pool| pool.install(|| steps::run_step(self, step)))
                            .map(|w| (start.elapsed().as_secs_f64(), w));
                        let _ = tx.send((i, r));
                    });
                }
            }
            if !running.iter().any(|r| *r) {
                break;
            }
            let Ok((i, r)) = rx.recv() else { break };
            running[i] = false;
            let outcome = match r {
                Ok((secs, warnings)) => self.mark(&steps[i], secs).map(|()| (secs, warnings)),
                Err(source) => Err(StudyError::Step {
                    step: steps[i].id.clone(),
                    source: Box::new(source),
                    log: self.log_path(&steps[i]),
                }),
            };
            match outcome {
                Ok((secs, warnings)) => {
                    done[i] = true;
                    for w in warnings {
                        on_event(Event::Warning(steps[i].id.clone(), w));
                    }
                    on_event(Event::Finished(steps[i].id.clone(), secs));
                }
                Err(e) => {
                    failure.get_or_insert(e);
                }
            }
        });
        match failure {
            Some(e) => Err(e),
            None => Ok(()),
        }
    }
}
