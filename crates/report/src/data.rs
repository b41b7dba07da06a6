//! Everything the report reads from a study directory: the analysis results
//! (`analysis/results.json`), the trial files behind them, the approach-assay episodes and the
//! training logs (`policies/<Model>/progress.csv`, `params.json`). Whatever is missing is
//! recorded with the command that would produce it; nothing missing is an error, except a
//! study directory that does not exist.

use crate::config::ReportConfig;
use crate::error::ReportError;
use fishprobe_analysis::{load_trial, AnalysisConfig, Results, StudyFiles};
use fishprobe_io::layout::StudyLayout;
use fishprobe_io::{read_trial, TrialFile};
use rayon::prelude::*;
use serde_json::Value;
use std::collections::BTreeMap;
use std::path::{Path, PathBuf};

/// Something the report could not show, why, and what would produce it.
#[derive(Debug, Clone, PartialEq, Eq)]
pub struct Missing {
    /// What is missing (a section, a file).
    pub what: String,
    /// Why / what was found instead.
    pub why: String,
    /// The command or step that would produce it.
    pub remedy: String,
}

/// One trial's numbers for the figures.
#[derive(Debug, Clone, PartialEq)]
pub struct TrialNumbers {
    /// Goals per complete minute of control.
    pub goals_per_minute: Vec<u32>,
    /// Histogram of the robot-fish distance over the control phase (counts per
    /// `ReportConfig::iid_bin_cm` bin from 0 to `iid_max_cm`; beyond it not counted).
    pub iid_hist: Vec<f64>,
    /// Frames with a finite distance (the denominator of the density, including those
    /// beyond the axis).
    pub iid_frames: usize,
}

/// The paths of one example trial, from the start of control.
#[derive(Debug, Clone, PartialEq)]
pub struct Track {
    /// The file.
    pub path: PathBuf,
    /// Robot positions (cm).
    pub robot: Vec<[f32; 2]>,
    /// Fish positions (cm), per fish (one for a pair, several for a group).
    pub fish: Vec<Vec<[f32; 2]>>,
    /// The goals of the trial.
    pub goals: Vec<[f32; 2]>,
    /// Goal radius (cm).
    pub goal_radius_cm: f32,
    /// Fish positions (a group's centroid) at the frames a goal was reached.
    pub reached: Vec<[f32; 2]>,
    /// Frame rate.
    pub rate_hz: f32,
}

/// Trials of one policy.
#[derive(Debug, Clone, Default, PartialEq)]
pub struct PolicyTrials {
    /// Sim trials on the policy's own model (the analysis' first N).
    pub sim: Vec<TrialNumbers>,
    /// Reality-arm trials.
    pub real: Vec<TrialNumbers>,
    /// Example sim trial.
    pub sim_track: Option<Track>,
    /// Example reality-arm trial.
    pub real_track: Option<Track>,
}

/// The approach assay's set-up (from the first episode found).
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct ApproachSetup {
    /// Robot position at the start of control.
    pub robot: [f32; 2],
    /// Fish position at the start of control.
    pub fish: [f32; 2],
    /// The goal.
    pub goal: [f32; 2],
}

/// A training run's log.
#[derive(Debug, Clone, PartialEq)]
pub struct TrainingLog {
    /// (environment steps, mean return, goals per episode) per iteration.
    pub rows: Vec<(f64, f64, f64)>,
    /// The header of `params.json`, when present and readable.
    pub params: Option<fishprobe_io::RunRecord>,
}

/// One condition directory of the study.
#[derive(Debug, Clone, PartialEq)]
pub struct Condition {
    /// Policy.
    pub policy: String,
    /// Rollout model or reality arm.
    pub model: String,
    /// Trial files.
    pub files: usize,
    /// The kind (sim, virtual, real) and set-up the first file records, when it has them.
    pub recorded: Option<String>,
}

/// All the report's inputs.
#[derive(Debug, Clone, Default)]
pub struct StudyData {
    /// The study directory.
    pub root: PathBuf,
    /// The analysis directory.
    pub analysis_dir: PathBuf,
    /// `results.json`, when present and readable: the structs `fishprobe analyze` wrote.
    pub results: Option<Results>,
    /// Reality arm ("Real", "VirtualLab") found in the rollouts.
    pub arm: Option<String>,
    /// Policies with sim trials on their own model.
    pub policies: Vec<String>,
    /// Conditions and their file counts.
    pub conditions: Vec<Condition>,
    /// Per-policy trials.
    pub trials: BTreeMap<String, PolicyTrials>,
    /// Approach assay: policy → per episode the robot-fish distance per time bin.
    pub approach: BTreeMap<String, Vec<Vec<f64>>>,
    /// Approach set-up.
    pub approach_setup: Option<ApproachSetup>,
    /// Training logs by model.
    pub training: BTreeMap<String, TrainingLog>,
    /// Trial files that could not be read, with the reason.
    pub unreadable: Vec<(PathBuf, String)>,
    /// What is missing.
    pub missing: Vec<Missing>,
    /// The study's candidate models from its `study.json`: (name, model, origin).
    pub candidates: Vec<(String, String, String)>,
}

/// The candidates `fishprobe run` recorded in `study.json`, with their origin (built in,
/// changed parameters, or an ONNX file with its SHA-256); none for a study made otherwise.
fn candidates(root: &Path) -> Vec<(String, String, String)> {
    let Ok(text) = fishprobe_io::read_small_text(&StudyLayout::new(root).config()) else {
        return Vec::new();
    };
    let Ok(v) = serde_json::from_str::<Value>(&text) else {
        return Vec::new();
    };
    v["models"]
        .as_array()
        .into_iter()
        .flatten()
        .filter_map(|m| {
            let name = m["name"].as_str()?.to_string();
            let spec: fishprobe_models::ModelSpec =
                serde_json::from_value(m["spec"].clone()).ok()?;
            Some((name, spec.name().to_string(), spec.origin()))
        })
        .collect()
}

/// Loads the report's inputs. `analysis_dir`: where `fishprobe analyze` wrote (default
/// `STUDY/analysis`).
pub fn gather(
    root: &Path,
    analysis_dir: &Path,
    cfg: &ReportConfig,
) -> Result<StudyData, ReportError> {
    if !root.is_dir() {
        return Err(ReportError::Study {
            path: root.to_path_buf(),
            what: "does not exist or is not a directory".into(),
        });
    }
    let root_s = root.display().to_string();
    let mut d = StudyData {
        root: root.to_path_buf(),
        analysis_dir: analysis_dir.to_path_buf(),
        ..StudyData::default()
    };
    let acfg = read_results(analysis_dir, &root_s, &mut d);

    d.candidates = candidates(root);
    let study = StudyFiles::discover(root).ok();
    let training = training_logs(root, &mut d);
    d.training = training;
    let Some(study) = study else {
        d.missing.push(Missing {
            what: "trial files".into(),
            why: "no rollouts/<Policy>__<Model>/, approach_test/ or stability/ directory".into(),
            remedy: "fishprobe evaluate --policy DIR --model M --out STUDY/rollouts/<M>__<M> (or fishprobe run)".into(),
        });
        return Ok(d);
    };
    d.arm = study.reality().map(str::to_string);
    d.policies = study.policies();
    if !d.training.is_empty() {
        for p in &d.policies {
            if !d.training.contains_key(p) {
                d.missing.push(Missing {
                    what: format!("training log of π_{p}"),
                    why: format!("no policies/{p}/progress.csv"),
                    remedy: format!("fishprobe train --model {p} --out {root_s}/policies/{p}"),
                });
            }
        }
    }
    d.conditions = study
        .rollouts
        .iter()
        .map(|((p, m), f)| Condition {
            policy: p.clone(),
            model: m.clone(),
            files: f.len(),
            recorded: f.first().and_then(|f| recorded(f)),
        })
        .collect();
    if d.arm.is_none() {
        d.missing.push(Missing {
            what: "reality arm".into(),
            why: "no rollouts/<Policy>__Real/ or <Policy>__VirtualLab/ trials".into(),
            remedy: "copy live trials into rollouts/<Policy>__Real/, or run the virtual lab (fishprobe lab)".into(),
        });
    }

    load_trials(&study, cfg, &acfg, &mut d);
    // Example tracks: the first readable file of each arm.
    for p in d.policies.clone() {
        let first = |m: &str| -> Option<Track> {
            study
                .rollouts
                .get(&(p.clone(), m.to_string()))?
                .iter()
                .find_map(|f| track(f, cfg).ok())
        };
        let sim_track = first(&p);
        let real_track = d.arm.clone().and_then(|a| first(&a));
        let e = d.trials.entry(p).or_default();
        e.sim_track = sim_track;
        e.real_track = real_track;
    }

    approach(&study, cfg, &acfg, &mut d);
    if d.approach.is_empty() {
        d.missing.push(Missing {
            what: "approach assay".into(),
            why: "no readable approach_test/<Policy>/ episodes".into(),
            remedy:
                "the approach-assay step of fishprobe run (episodes in approach_test/<Policy>/)"
                    .into(),
        });
    }
    Ok(d)
}

/// The analysis results into `d.results` (or what is missing into `d.missing`); the analysis
/// settings they were made with (the defaults without them).
fn read_results(analysis_dir: &Path, root_s: &str, d: &mut StudyData) -> AnalysisConfig {
    let results_path = StudyLayout::results_in(analysis_dir);
    let mut acfg = AnalysisConfig::default();
    match fishprobe_io::read_small_text(&results_path) {
        Ok(text) => match serde_json::from_str::<Value>(&text) {
            Ok(v) if v.is_object() => match serde_json::from_value::<Results>(v) {
                Ok(r) => {
                    acfg = r.config.clone();
                    d.results = Some(r);
                }
                Err(e) => d.missing.push(Missing {
                    what: "analysis results".into(),
                    why: format!(
                        "{} does not hold what fishprobe analyze writes: {e}",
                        results_path.display()
                    ),
                    remedy: format!("fishprobe analyze {root_s}"),
                }),
            },
            Ok(_) | Err(_) => d.missing.push(Missing {
                what: "analysis results".into(),
                why: format!("{} is not a JSON object", results_path.display()),
                remedy: format!("fishprobe analyze {root_s}"),
            }),
        },
        Err(e) => d.missing.push(Missing {
            what: "analysis results (tables, sim-to-real and sim-to-sim figures)".into(),
            why: if e.kind() == std::io::ErrorKind::NotFound {
                format!("{} not found", results_path.display())
            } else {
                format!("{}: {e}", results_path.display())
            },
            remedy: format!("fishprobe analyze {root_s}"),
        }),
    }
    acfg
}

/// Every trial's numbers for the figures: each policy's own-model trials (the analysis's
/// `sim_trials` first) and its reality-arm trials, loaded in parallel; unreadable files into
/// `d.unreadable`.
fn load_trials(study: &StudyFiles, cfg: &ReportConfig, acfg: &AnalysisConfig, d: &mut StudyData) {
    let iid_bins = (cfg.iid_max_cm / cfg.iid_bin_cm).ceil() as usize;
    let mut jobs: Vec<(String, bool, PathBuf)> = Vec::new();
    for p in &d.policies {
        if let Some(files) = study.rollouts.get(&(p.clone(), p.clone())) {
            for f in files.iter().take(acfg.sim_trials) {
                jobs.push((p.clone(), false, f.clone()));
            }
        }
        if let Some(arm) = &d.arm {
            if let Some(files) = study.rollouts.get(&(p.clone(), arm.clone())) {
                for f in files {
                    jobs.push((p.clone(), true, f.clone()));
                }
            }
        }
    }
    let loaded: Vec<(String, bool, PathBuf, Result<TrialNumbers, String>)> = jobs
        .into_par_iter()
        .map(|(p, real, f)| {
            let r = load_trial(&f, acfg, true)
                .map_err(|e| e.to_string())
                .map(|t| {
                    let iid = t
                        .metrics
                        .as_ref()
                        .and_then(|m| m.get(fishprobe_analysis::metric::IID))
                        .cloned()
                        .unwrap_or_default();
                    let mut hist = vec![0.0; iid_bins];
                    for v in &iid {
                        let b = (v / f64::from(cfg.iid_bin_cm)) as usize;
                        if let Some(h) = hist.get_mut(b) {
                            *h += 1.0;
                        }
                    }
                    TrialNumbers {
                        goals_per_minute: t.goals_per_minute,
                        iid_hist: hist,
                        iid_frames: iid.len(),
                    }
                });
            (p, real, f, r)
        })
        .collect();
    for (p, real, f, r) in loaded {
        let e = d.trials.entry(p).or_default();
        match r {
            Ok(t) if real => e.real.push(t),
            Ok(t) => e.sim.push(t),
            Err(why) => d.unreadable.push((f, why)),
        }
    }
}

/// "kind, set-up" as the file records them.
fn recorded(path: &Path) -> Option<String> {
    let t = read_trial(path).ok()?;
    let kind = t.task.as_ref().map(|k| k.kind.label().to_string());
    let setup = match t.attributes.get("experiment_setup") {
        Some(fishprobe_io::Attr::Text(s)) if !s.is_empty() => Some(s.clone()),
        _ => None,
    };
    let parts: Vec<String> = [kind, setup].into_iter().flatten().collect();
    (!parts.is_empty()).then(|| parts.join("; "))
}

/// The example track of a file (first `trajectory_seconds` of control).
fn track(path: &Path, cfg: &ReportConfig) -> Result<Track, String> {
    let t: TrialFile = read_trial(path).map_err(|e| e.to_string())?;
    let robot = t.robot().ok_or("no robot")?;
    let fish: Vec<&fishprobe_io::Entity> = t.fish().collect();
    if fish.is_empty() {
        return Err("no fish".into());
    }
    let start = t.control_start();
    let frames = fish
        .iter()
        .map(|f| f.frames())
        .fold(robot.frames(), usize::min);
    let end = start
        .saturating_add((f64::from(cfg.trajectory_seconds) * f64::from(t.frame_rate_hz)) as usize)
        .min(frames);
    if start >= end {
        return Err("no frame of control".into());
    }
    // Where the fish were when a goal was reached: one fish, or a group's tracked centroid.
    let centroid = |g: usize| {
        let tracked: Vec<[f32; 2]> = fish
            .iter()
            .map(|f| f.positions[g])
            .filter(|p| p[0].is_finite() && p[1].is_finite())
            .collect();
        let n = tracked.len().max(1) as f32;
        let (x, y) = tracked
            .iter()
            .fold((0.0, 0.0), |(x, y), p| (x + p[0], y + p[1]));
        [x / n, y / n]
    };
    let (goals, radius, reached) = match &t.task {
        Some(k) => (
            k.goals.clone(),
            k.goal_radius_cm,
            k.goal_frames
                .iter()
                .filter_map(|&g| usize::try_from(g).ok())
                .filter(|&g| g >= start && g < end)
                .map(centroid)
                .collect(),
        ),
        None => (Vec::new(), 5.0, Vec::new()),
    };
    Ok(Track {
        path: path.to_path_buf(),
        robot: robot.positions[start..end].to_vec(),
        fish: fish
            .iter()
            .map(|f| f.positions[start..end].to_vec())
            .collect(),
        goals,
        goal_radius_cm: radius,
        reached,
        rate_hz: t.frame_rate_hz,
    })
}

type ApproachEpisode = (Option<String>, Vec<f64>, ApproachSetup);

fn approach_episode(
    path: &Path,
    cfg: &ReportConfig,
    acfg: &AnalysisConfig,
) -> Result<ApproachEpisode, String> {
    let t = read_trial(path).map_err(|e| e.to_string())?;
    let robot = t.robot().ok_or("no robot")?;
    let fish = t.fish().next().ok_or("no fish")?;
    let start = t.control_start();
    let frames = robot.frames().min(fish.frames());
    if start >= frames {
        return Err("no frame of control".into());
    }
    let goal = t
        .task
        .as_ref()
        .and_then(|k| k.goals.first().copied())
        .unwrap_or(acfg.approach_goal);
    let per_bin =
        ((f64::from(cfg.approach_bin_s) * f64::from(t.frame_rate_hz)).round() as usize).max(1);
    let series = (start..frames)
        .collect::<Vec<_>>()
        .chunks(per_bin)
        .map(|c| {
            let v: Vec<f64> = c
                .iter()
                .map(|&i| {
                    let (r, f) = (robot.positions[i], fish.positions[i]);
                    f64::from(((r[0] - f[0]).powi(2) + (r[1] - f[1]).powi(2)).sqrt())
                })
                .filter(|x| x.is_finite())
                .collect();
            if v.is_empty() {
                f64::NAN
            } else {
                v.iter().sum::<f64>() / v.len() as f64
            }
        })
        .collect();
    let setup = ApproachSetup {
        robot: robot.positions[start],
        fish: fish.positions[start],
        goal,
    };
    Ok((t.task.as_ref().map(|k| k.policy.clone()), series, setup))
}

fn approach(study: &StudyFiles, cfg: &ReportConfig, acfg: &AnalysisConfig, d: &mut StudyData) {
    let jobs: Vec<(String, PathBuf)> = study
        .approach
        .iter()
        .flat_map(|(p, files)| files.iter().map(move |f| (p.clone(), f.clone())))
        .collect();
    let eps: Vec<(String, PathBuf, Result<ApproachEpisode, String>)> = jobs
        .into_par_iter()
        .map(|(p, f)| {
            let r = approach_episode(&f, cfg, acfg);
            (p, f, r)
        })
        .collect();
    for (dir_policy, f, r) in eps {
        match r {
            Ok((file_policy, series, setup)) => {
                let p = if dir_policy.is_empty() {
                    file_policy.unwrap_or_default()
                } else {
                    dir_policy
                };
                if p.is_empty() {
                    d.unreadable
                        .push((f, "approach file names no policy".into()));
                    continue;
                }
                d.approach_setup.get_or_insert(setup);
                d.approach.entry(p).or_default().push(series);
            }
            Err(why) => d.unreadable.push((f, why)),
        }
    }
}

/// Largest training log (`progress.csv`) the report reads. A `paper`-preset run logs about
/// 810 iterations of some 170 bytes (0.14 MB); 256 MiB holds over a million and a half, and
/// stops a log that is not one (a link to a device, a file that never ends) before it fills
/// memory.
pub const MAX_TRAINING_LOG_BYTES: u64 = 256 << 20;

/// Reads `policies/<Model>/progress.csv` (+ `params.json`). Column names: fishprobe's
/// (`timesteps`, `episode_return_mean`, `goals_per_episode`) or RLlib's (`timesteps_total`,
/// `episode_reward_mean`), as in the paper's archive.
fn training_logs(root: &Path, d: &mut StudyData) -> BTreeMap<String, TrainingLog> {
    let mut out = BTreeMap::new();
    let dir = StudyLayout::new(root).policies_root();
    let Ok(entries) = std::fs::read_dir(&dir) else {
        d.missing.push(Missing {
            what: "training curves".into(),
            why: format!("{} not found", dir.display()),
            remedy: "fishprobe train --model M --out STUDY/policies/M (or fishprobe run)".into(),
        });
        return out;
    };
    let mut models: Vec<PathBuf> = entries
        .filter_map(|e| e.ok().map(|e| e.path()))
        .filter(|p| p.is_dir())
        .collect();
    models.sort();
    for m in models {
        let name = m
            .file_name()
            .map(|n| n.to_string_lossy().into_owned())
            .unwrap_or_default();
        let run = fishprobe_io::RunLayout::new(&m);
        let csv = run.progress();
        let params = run.record().ok();
        match fishprobe_io::read_text_at_most(
            &csv,
            MAX_TRAINING_LOG_BYTES,
            "not a training log fishprobe wrote",
            "fishprobe_report::data::MAX_TRAINING_LOG_BYTES",
        ) {
            Ok(text) => match parse_progress(&text) {
                Ok(rows) => {
                    out.insert(name, TrainingLog { rows, params });
                }
                Err(why) => d.unreadable.push((csv, why.to_string())),
            },
            Err(e) if e.kind() != std::io::ErrorKind::NotFound => {
                d.unreadable.push((csv, e.to_string()))
            }
            Err(_) => d.missing.push(Missing {
                what: format!("training log of {name}"),
                why: format!("{} not found", csv.display()),
                remedy: format!("fishprobe train --model {name} --out {}", m.display()),
            }),
        }
    }
    out
}

/// Parses a progress CSV into (steps, mean return, goals per episode).
pub fn parse_progress(text: &str) -> Result<Vec<(f64, f64, f64)>, crate::ReportError> {
    progress_rows(text).map_err(crate::ReportError::Progress)
}

fn progress_rows(text: &str) -> Result<Vec<(f64, f64, f64)>, String> {
    let mut lines = text.lines();
    let header: Vec<&str> = lines.next().ok_or("empty file")?.split(',').collect();
    let col = |names: &[&str]| header.iter().position(|h| names.contains(&h.trim()));
    let steps = col(&["timesteps", "timesteps_total"]).ok_or("no `timesteps` column")?;
    let ret = col(&["episode_return_mean", "episode_reward_mean"])
        .ok_or("no `episode_return_mean` column")?;
    let goals = col(&["goals_per_episode", "custom_metrics/goals_reached_mean"]);
    let mut rows = Vec::new();
    for (i, line) in lines.enumerate() {
        if line.trim().is_empty() {
            continue;
        }
        let cells: Vec<&str> = line.split(',').collect();
        let get = |c: usize| {
            cells
                .get(c)
                .and_then(|s| s.trim().parse::<f64>().ok())
                .unwrap_or(f64::NAN)
        };
        let s = get(steps);
        if !s.is_finite() {
            return Err(format!("line {}: no step count", i + 2));
        }
        rows.push((s, get(ret), goals.map_or(f64::NAN, get)));
    }
    Ok(rows)
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn progress_csv_by_column_name() {
        let rows = parse_progress(
            "iteration,timesteps,episode_return_mean,goals_per_episode\n1,100,2.5,1\n2,200,nan,0.5\n",
        )
        .expect("parses");
        assert_eq!(rows.len(), 2);
        assert_eq!(rows[0], (100.0, 2.5, 1.0));
        assert!(rows[1].1.is_nan());
        let rllib = parse_progress("episode_reward_mean,timesteps_total\n3,4000\n").expect("rllib");
        assert_eq!(rows.len(), 2);
        assert_eq!(rllib[0].0, 4000.0);
        assert!(rllib[0].2.is_nan());
        assert!(parse_progress("a,b\n1,2\n")
            .unwrap_err()
            .to_string()
            .contains("timesteps"));
        assert!(parse_progress("timesteps,episode_return_mean\nx,1\n")
            .unwrap_err()
            .to_string()
            .contains("line 2"));
    }

    #[test]
    fn a_missing_study_is_an_error_and_an_empty_one_says_what_is_missing() {
        let cfg = ReportConfig::default();
        let e = gather(Path::new("/nonexistent/study"), Path::new("/x"), &cfg).unwrap_err();
        assert!(e.to_string().contains("/nonexistent/study"));
        let dir =
            std::env::temp_dir().join(format!("fishprobe-report-empty-{}", std::process::id()));
        std::fs::create_dir_all(&dir).expect("tmp");
        let d = gather(&dir, &dir.join("analysis"), &cfg).expect("gathers");
        let whats: Vec<&str> = d.missing.iter().map(|m| m.what.as_str()).collect();
        assert!(
            whats.iter().any(|w| w.starts_with("analysis results")),
            "{whats:?}"
        );
        assert!(whats.contains(&"trial files"), "{whats:?}");
        assert!(d
            .missing
            .iter()
            .any(|m| m.remedy.contains("fishprobe analyze")));
        let _ = std::fs::remove_dir_all(&dir);
    }
}
