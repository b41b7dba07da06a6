//! A run's logs: one line per iteration in `progress.csv` and `result.json`, appended as the
//! run goes and cut back to the checkpoint when it resumes.

use super::{run_err, Trainer};
use crate::error::LearnError;
use fishprobe_io::RunLayout;
use serde::{Deserialize, Serialize};
use std::path::Path;

/// One iteration's log line.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
pub struct IterationStats {
    /// Iteration (1-based).
    pub iteration: u64,
    /// Environment steps so far.
    pub timesteps: u64,
    /// Episodes finished so far.
    pub episodes_total: u64,
    /// Episodes finished in this iteration.
    pub episodes: u64,
    /// Mean return of those episodes (NaN when none).
    pub episode_return_mean: f32,
    /// Their minimum return.
    pub episode_return_min: f32,
    /// Their maximum return.
    pub episode_return_max: f32,
    /// Mean goals reached per episode.
    pub goals_per_episode: f32,
    /// Mean surrogate loss.
    pub policy_loss: f32,
    /// Mean clamped value loss.
    pub value_loss: f32,
    /// Mean KL of the last epoch.
    pub kl: f32,
    /// KL coefficient after this iteration's adaptation.
    pub kl_coeff: f32,
    /// Mean policy entropy.
    pub entropy: f32,
    /// Fraction of probability ratios outside the clip range in the last epoch.
    #[serde(default)]
    pub clip_frac: f32,
    /// Fraction of sampled (normalised) actions outside [-1, 1], i.e. turns clipped to ±π.
    #[serde(default)]
    pub action_clip_frac: f32,
    /// Explained variance of the value targets by the sampled value predictions.
    #[serde(default)]
    pub vf_explained_var: f32,
    /// The same on the training batch during the last epoch (in-sample fit).
    #[serde(default)]
    pub vf_explained_var_fit: f32,
    /// Wall time of the iteration (s).
    pub time_s: f64,
    /// Environment steps per second in this iteration.
    pub steps_per_s: f64,
    /// The program build that made this iteration (what `fishprobe --version` prints; the
    /// run's `params.json` records the one that started it, and a run resumed by another
    /// build says here which iterations which build made). `result.json` only: the CSV's
    /// columns are numbers. Empty in logs written before it was recorded.
    #[serde(default)]
    pub build: String,
}

pub(super) const CSV_HEADER: &str = "iteration,timesteps,episodes_total,episodes,episode_return_mean,episode_return_min,episode_return_max,goals_per_episode,policy_loss,value_loss,kl,kl_coeff,entropy,clip_frac,action_clip_frac,vf_explained_var,vf_explained_var_fit,time_s,steps_per_s";

impl IterationStats {
    fn csv_row(&self) -> String {
        format!(
            "{},{},{},{},{},{},{},{},{},{},{},{},{},{},{},{},{},{:.3},{:.1}",
            self.iteration,
            self.timesteps,
            self.episodes_total,
            self.episodes,
            self.episode_return_mean,
            self.episode_return_min,
            self.episode_return_max,
            self.goals_per_episode,
            self.policy_loss,
            self.value_loss,
            self.kl,
            self.kl_coeff,
            self.entropy,
            self.clip_frac,
            self.action_clip_frac,
            self.vf_explained_var,
            self.vf_explained_var_fit,
            self.time_s,
            self.steps_per_s
        )
    }
}

/// Longest line a run's log may have (1 MiB): fishprobe writes lines of some hundred bytes
/// (`progress.csv`) to a few kilobytes (`result.json`), so a longer one means the file is not
/// the run's log, and reading on would fill memory with it.
pub const MAX_LOG_LINE_BYTES: u64 = 1 << 20;

/// Rewrites a run's log `path`, keeping the lines `keep` accepts (blank lines go), through a
/// temporary file and a rename. The log is streamed, so memory stays at one line however long
/// the run. A log that cannot be read is an error, never an empty log: rewriting it from
/// nothing would erase the finished iterations. Lines are kept as bytes, so a damaged line
/// (not UTF-8, say) stays as it was. A missing log becomes empty (`progress.csv`: its header).
fn filter_log(path: &Path, is_csv: bool, keep: impl Fn(&str) -> bool) -> Result<(), LearnError> {
    use std::io::{BufRead, Read, Write};
    let refuse = |what: String| run_err(path, format!("cannot rewrite the run's log: {what}"));
    let reader = match std::fs::File::open(path) {
        Ok(f) => {
            match f.metadata() {
                Ok(m) if m.is_file() => {}
                Ok(_) => return Err(refuse("not a regular file".into())),
                Err(e) => return Err(refuse(e.to_string())),
            }
            Some(std::io::BufReader::new(f))
        }
        Err(e) if e.kind() == std::io::ErrorKind::NotFound => None,
        Err(e) => return Err(refuse(e.to_string())),
    };
    let name = path
        .file_name()
        .map(|n| n.to_string_lossy().into_owned())
        .unwrap_or_default();
    let tmp = path.with_file_name(format!(".{name}.{}.partial", std::process::id()));
    let result = (|| -> Result<(), LearnError> {
        let file = std::fs::File::create(&tmp).map_err(|e| refuse(e.to_string()))?;
        let mut out = std::io::BufWriter::new(file);
        let mut wrote = false;
        if let Some(mut reader) = reader {
            let mut line = Vec::new();
            loop {
                line.clear();
                let n = (&mut reader)
                    .take(MAX_LOG_LINE_BYTES + 1)
                    .read_until(b'\n', &mut line)
                    .map_err(|e| refuse(e.to_string()))?;
                if n == 0 {
                    break;
                }
                if line.last() == Some(&b'\n') {
                    line.pop();
                } else if n as u64 > MAX_LOG_LINE_BYTES {
                    return Err(refuse(format!(
                        "a line longer than {MAX_LOG_LINE_BYTES} bytes, so not a log fishprobe \
                         wrote (fishprobe_learn::trainer::MAX_LOG_LINE_BYTES)"
                    )));
                }
                let text = String::from_utf8_lossy(&line);
                if !text.trim().is_empty() && keep(&text) {
                    out.write_all(&line).map_err(|e| refuse(e.to_string()))?;
                    out.write_all(b"\n").map_err(|e| refuse(e.to_string()))?;
                    wrote = true;
                }
            }
        }
        if is_csv && !wrote {
            writeln!(out, "{CSV_HEADER}").map_err(|e| refuse(e.to_string()))?;
        }
        let file = out
            .into_inner()
            .map_err(|e| refuse(e.error().to_string()))?;
        file.sync_all().map_err(|e| refuse(e.to_string()))?;
        std::fs::rename(&tmp, path).map_err(|e| refuse(e.to_string()))
    })();
    if result.is_err() {
        let _ = std::fs::remove_file(&tmp);
    }
    result
}

impl Trainer {
    pub(super) fn append_logs(&self, s: &IterationStats) -> Result<(), LearnError> {
        use std::io::Write;
        let append = |name: &str, line: String| -> Result<(), LearnError> {
            let p = self.dir.join(name);
            let mut f = std::fs::OpenOptions::new()
                .append(true)
                .create(true)
                .open(&p)
                .map_err(|e| run_err(&p, e))?;
            f.write_all(line.as_bytes()).map_err(|e| run_err(&p, e))
        };
        append(RunLayout::PROGRESS, s.csv_row() + "\n")?;
        let json = serde_json::to_string(s).map_err(|e| run_err(&self.dir, e))?;
        append(RunLayout::RESULT, json + "\n")
    }

    /// Drops log lines of iterations after the checkpoint (they will be redone).
    pub(super) fn truncate_logs(&self) -> Result<(), LearnError> {
        let keep = |line: &str, first_field: &dyn Fn(&str) -> Option<u64>| {
            first_field(line).is_none_or(|it| it <= self.iteration)
        };
        for (name, field) in [
            (
                RunLayout::PROGRESS,
                &(|l: &str| l.split(',').next().and_then(|v| v.parse::<u64>().ok()))
                    as &dyn Fn(&str) -> Option<u64>,
            ),
            (RunLayout::RESULT, &|l: &str| {
                serde_json::from_str::<serde_json::Value>(l)
                    .ok()
                    .and_then(|v| v["iteration"].as_u64())
            }),
        ] {
            let p = self.dir.join(name);
            filter_log(&p, name == RunLayout::PROGRESS, |line| keep(line, field))?;
        }
        Ok(())
    }
}
