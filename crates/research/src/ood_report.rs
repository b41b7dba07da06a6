//! `fishprobe ood-report`: what an OOD policy drives the fish into. Runs the policy
//! and a lead-to-goal policy on the same episodes against the fish model (or reads recorded
//! trials of either, e.g. live ones), scores every view of the fish against the model's
//! training support, and writes the distributions, example episodes, and a ranked data
//! wishlist.

use crate::{ResearchError, Result, Runner};
use fishprobe_analysis::ood::{
    disagreement_of_trials, disagreement_of_views, distribution, quantile, score_recorded,
    score_views, share_at_least, share_beyond_interval, trial_views, wishlist, Distribution,
    SourceScores, WishItem,
};
use fishprobe_learn::bc::{load_pairs, CloneConfig};
use fishprobe_learn::yardstick::ScoredRun;
use fishprobe_learn::{Evaluation, Trainer};
use fishprobe_models::disagreement::Disagreement;
use fishprobe_models::support::{SupportError, SupportModel};
use fishprobe_models::{ModelError, ModelSpec};
use fishprobe_report::figures::{ood_scores, ood_trajectories, ScoredEpisode};
use fishprobe_sim::{Controller, EnvConfig};
use std::path::{Path, PathBuf};

mod text;
use text::{markdown, summary};

/// Which policies `fishprobe ood-report` runs or scores, against what, and where the report goes.
#[derive(Debug, Clone)]
pub struct OodReportSettings {
    /// The OOD policy: a directory from `fishprobe train --task ood` (or `onnx:FILE`). With
    /// `--trials`, only names the policy the trials were recorded with (and, as a training
    /// directory, the fish model and its yardstick).
    pub policy: Option<String>,
    /// Recorded trials of the OOD policy to score instead of simulating its episodes: trial
    /// files or directories of them (`*.hdf5`, `*.h5`), e.g. live trials (`fishprobe live`)
    /// or the virtual lab's (`fishprobe lab`): how far the fish in those recordings went
    /// outside the model's training support. At most 1000 files.
    pub trials: Vec<PathBuf>,
    /// Recorded trials of the lead-to-goal policy, scored instead of simulating `--compare`'s
    /// episodes (as `--trials`).
    pub compare_trials: Vec<PathBuf>,
    /// The lead-to-goal policy to compare with (a training directory, `onnx:FILE` or
    /// `scripted:NAME`). Default: `scripted:fetch-and-lead`.
    pub compare: String,
    /// The fish model (default: the one the OOD policy was trained against).
    pub model: Option<String>,
    /// The model's training recordings, for their score distribution (default: the shared
    /// guppy pairs when the model is the shipped ConvNet and they are found; else none).
    pub data: Vec<PathBuf>,
    /// Episodes per policy.
    pub episodes: usize,
    /// Minutes per episode (the evaluation task: random starts, corner goals).
    pub minutes: f32,
    /// Master seed of the episodes (both policies get the same ones).
    pub seed: u64,
    /// Report directory (report.md, ood.json, figures, the episodes' trial files).
    pub out: PathBuf,
    /// Print ood.json instead of the summary.
    pub json: bool,
}

/// The training run behind a policy argument, if it is one.
fn run_dir(policy: &str) -> Option<&Path> {
    let p = Path::new(policy);
    (!policy.contains(':') && fishprobe_learn::run::RunLayout::new(p).holds_run()).then_some(p)
}

/// The report's numbers (ood.json).
#[derive(Debug, serde::Serialize)]
struct OodReport {
    model: String,
    ood_policy: String,
    goal_policy: String,
    episodes: usize,
    minutes: f32,
    seed: u64,
    /// Recorded trials scored for each policy (OOD, lead-to-goal) instead of simulated
    /// episodes (`--trials`, `--compare-trials`); `None`: simulated.
    recorded_trials: [Option<usize>; 2],
    distributions: Vec<Distribution>,
    /// The goal policy's 95th-percentile score.
    goal_policy_p95: f64,
    /// Share of the OOD policy's views scoring at least that (the target: most of the time).
    ood_share_beyond_goal_p95: f64,
    /// Its 95 % percentile-bootstrap interval over the episodes (or recorded trials) of both
    /// policies, the yardstick measured again in each replicate (`SHARE_INTERVAL_REPS` of
    /// them, seeded by `--seed`); null with fewer than two of either.
    ood_share_interval: Option<[f64; 2]>,
    /// The score the OOD policy's reward counted time beyond (`train --ood-yardstick`), if
    /// it was trained so: its `yardstick.json`.
    trained_yardstick: Option<TrainedYardstick>,
    /// Goals per episode or recorded trial (null: recordings without fishprobe's task record).
    goals_per_episode: [f64; 2],
    wishlist: Vec<WishItem>,
    /// The same views scored by the disagreement of the model's ensemble, when it has one
    /// (`fit-convnet --members K`).
    #[serde(skip_serializing_if = "Option::is_none")]
    disagreement: Option<DisagreementPart>,
}

/// The views scored by the ensemble's disagreement.
#[derive(Debug, serde::Serialize)]
struct DisagreementPart {
    /// Networks of the ensemble, the model's own included.
    members: usize,
    distributions: Vec<Distribution>,
    goal_policy_p95: f64,
    ood_share_beyond_goal_p95: f64,
}

/// The ensemble of `model`, when it has one; an ensemble that is there but unusable (a
/// damaged member, another model's) is an error.
fn ensemble_of(model: &ModelSpec) -> Result<Option<Disagreement>> {
    match model.disagreement() {
        Ok(d) => Ok(Some(d)),
        Err(ModelError::Support(SupportError::MissingEnsemble { .. })) => Ok(None),
        Err(e) => Err(e).map_err(|e| ResearchError::within("the ensemble of the fish model", e)),
    }
}

/// What `train --ood-yardstick` measured for the OOD policy (its run's `yardstick.json`).
#[derive(Debug, serde::Serialize, serde::Deserialize)]
struct TrainedYardstick {
    policy: String,
    /// The score the yardstick was measured in (a record written before the disagreement
    /// had a yardstick is the support's).
    #[serde(default)]
    ood_score: fishprobe_sim::OodScore,
    score: f64,
}

/// The yardstick the OOD policy at `policy` was trained against, if any.
fn trained_yardstick(policy: &str) -> Result<Option<TrainedYardstick>> {
    let Some(file) = run_dir(policy).map(|d| d.join("yardstick.json")) else {
        return Ok(None);
    };
    if !file.exists() {
        return Ok(None);
    }
    let text = fishprobe_io::read_small_text(&file)
        .map_err(|e| ResearchError::within(format!("reading {}", file.display()), e))?;
    let y = serde_json::from_str(&text).map_err(|e| {
        ResearchError::within(
            format!("{}: not a yardstick record of `train`", file.display()),
            e,
        )
    })?;
    Ok(Some(y))
}

/// An example episode for the picture: the robot's path, the first fish's scored views (both
/// from the start of closed-loop control: a live trial's habituation is not the policy's).
fn scored_episode(support: &SupportModel, file: &Path, title: String) -> Result<ScoredEpisode> {
    let t = fishprobe_io::read_trial(file)?;
    let control = t.control_start();
    Ok(ScoredEpisode {
        title,
        robot: t
            .robot()
            .map(|r| r.positions.iter().skip(control).copied().collect())
            .unwrap_or_default(),
        fish: trial_views(support, &t)
            .into_iter()
            .filter(|v| v.fish == 0)
            .map(|v| (v.position, v.score))
            .collect(),
    })
}

/// Runs `c` on the episodes of `e` (their trial files in `e.out`) and scores every fish view
/// against `support` (`fishprobe_learn::yardstick::score_policy`, on `--jobs`' pool).
fn score_policy(
    c: &dyn Controller,
    e: &Evaluation,
    support: &SupportModel,
    label: &str,
    by: Runner,
) -> Result<ScoredRun> {
    by.note(&format!(
        "running {} episodes of {} ...",
        e.episodes,
        c.describe()
    ));
    Ok(fishprobe_learn::yardstick::score_policy(
        c, e, support, label,
    )?)
}

/// Bootstrap replicates of the headline share's interval (`ood.json`'s
/// `ood_share_interval`; choice: 2,000, the usual count for a 95 % percentile interval; on
/// the default 6 + 6 episodes of 5 minutes they add no measurable time to a 2.6-s report).
const SHARE_INTERVAL_REPS: usize = 2000;

/// The interval's coverage (choice: 95 %, as the report says).
const SHARE_INTERVAL_LEVEL: f64 = 0.95;

/// The lead-to-goal policy's quantile the OOD policy's time is measured beyond (the
/// yardstick: its 95th percentile).
const YARDSTICK_QUANTILE: f64 = 0.95;

/// Most recorded trials one source may hold (as many as `--episodes` allows).
const MAX_RECORDED: usize = 1000;

/// Where a policy's scored views come from.
enum Source {
    /// Episodes simulated now with this controller.
    Simulated(Box<dyn Controller>),
    /// Recorded trial files.
    Recorded(Vec<PathBuf>),
}

/// The trial files `paths` name (files, or directories of `*.hdf5` / `*.h5`), for `flag`.
fn recorded_files(paths: &[PathBuf], flag: &str) -> Result<Vec<PathBuf>> {
    let mut files = Vec::new();
    for p in paths {
        if p.is_dir() {
            let found = fishprobe_io::trial_files(p);
            if found.is_empty() {
                return Err(ResearchError::Refused(format!(
                    "{flag} {}: no trial files (*.hdf5, *.h5) in it",
                    p.display()
                )));
            }
            files.extend(found);
        } else {
            files.push(p.clone());
        }
        if files.len() > MAX_RECORDED {
            return Err(ResearchError::Refused(format!(
                "{flag}: more than {MAX_RECORDED} trial files; score a sample of them"
            )));
        }
    }
    Ok(files)
}

/// Recorded trials scored against `support`: their views and their goals per trial (NaN when
/// none of them has fishprobe's task record).
fn recorded_run(
    support: &SupportModel,
    label: &str,
    files: &[PathBuf],
    by: Runner,
) -> Result<ScoredRun> {
    by.note(&format!(
        "scoring {} recorded trials of the {label} ...",
        files.len()
    ));
    let (scores, goals) = score_recorded(support, label, files)?;
    if scores.scores.is_empty() {
        return Err(ResearchError::Refused(format!(
            "the {label}'s recorded trials hold no tracked fish with the robot"
        )));
    }
    let counted: Vec<f64> = goals.into_iter().flatten().map(|g| g as f64).collect();
    Ok(ScoredRun {
        scores,
        goals: counted.iter().sum::<f64>() / counted.len() as f64,
        files: files.to_vec(),
    })
}

/// Runs (or scores the recorded trials of) the OOD and the lead-to-goal policy, writes
/// `report.md`, `ood.json`, the figures and the episodes' trial files into `out`, and returns
/// the summary (or, with `json`, `ood.json`) to show; progress goes to `by`.
pub fn run(a: &OodReportSettings, by: Runner) -> Result<String> {
    if a.episodes == 0 || a.episodes > 1000 {
        return Err(ResearchError::Refused(format!(
            "episodes must lie in [1, 1000], got {}",
            a.episodes
        )));
    }
    fishprobe_learn::evaluate::check_minutes("minutes", a.minutes)?;
    let policy = a.policy.as_deref();
    let recorded = policy
        .and_then(run_dir)
        .map(Trainer::recorded_spec)
        .transpose()?;
    let model = match (&a.model, &recorded) {
        (Some(m), _) => ModelSpec::by_name(m)?,
        (None, Some(spec)) => spec.model.clone(),
        (None, None) => {
            return Err(ResearchError::Refused(
                "model is required unless policy is a training directory".to_string(),
            ))
        }
    };
    let support = model.support().map_err(|e| {
        ResearchError::within(format!("the support of fish model {}", model.name()), e)
    })?;
    let ensemble = ensemble_of(&model)?;
    let env = recorded
        .as_ref()
        .map(|s| s.env.clone())
        .unwrap_or_else(EnvConfig::default);
    let ood_src = match (a.trials.is_empty(), policy) {
        (false, _) => Source::Recorded(recorded_files(&a.trials, "trials")?),
        (true, Some(p)) => Source::Simulated(
            fishprobe_learn::controller(p, false)
                .map_err(|e| ResearchError::within(format!("loading the policy {p}"), e))?,
        ),
        (true, None) => {
            return Err(ResearchError::Refused(
                "policy or trials is required".to_string(),
            ))
        }
    };
    // Read before the episodes: a corrupt record fails at once, not after minutes.
    let trained = policy.map(trained_yardstick).transpose()?.flatten();
    let goal_src = if a.compare_trials.is_empty() {
        Source::Simulated(fishprobe_learn::controller(&a.compare, false).map_err(|e| {
            ResearchError::within(format!("loading the compared policy {}", a.compare), e)
        })?)
    } else {
        Source::Recorded(recorded_files(&a.compare_trials, "compare_trials")?)
    };
    let describe = |src: &Source, name: Option<&str>| match src {
        Source::Simulated(c) => format!("{} ({})", name.unwrap_or("?"), c.describe()),
        Source::Recorded(f) => match name {
            Some(n) => format!("{} recorded trials of {n}", f.len()),
            None => format!("{} recorded trials", f.len()),
        },
    };
    let compare_name = a.compare_trials.is_empty().then_some(a.compare.as_str());
    // The training recordings too: a bad --data fails before minutes of episodes.
    let (training, training_disagreement) =
        training_scores(&a.data, &model, &support, ensemble.as_ref(), by)?;
    // Locked (and so created) only now: a refused report leaves no empty --out behind.
    let _lock = fishprobe_io::DirLock::acquire(&a.out, "ood-report")?;
    let mut sources = Vec::new();
    let mut goals = [0.0; 2];
    let mut first_files = Vec::new();
    let mut all_files = Vec::new();
    let both = [
        (&ood_src, "ood", "OOD policy"),
        (&goal_src, "goal", "lead-to-goal policy"),
    ];
    // An earlier report's episodes would be overwritten in part and mixed with these.
    for (src, name, _) in &both {
        if matches!(src, Source::Simulated(_)) {
            fishprobe_learn::evaluate::check_fresh_output(
                &a.out.join("episodes").join(name),
                name,
            )?;
        }
    }
    for (k, (src, name, label)) in both.into_iter().enumerate() {
        let run = match src {
            Source::Recorded(files) => recorded_run(&support, label, files, by)?,
            Source::Simulated(c) => {
                // Each policy observes and acts as it was trained to (an opt-in block such
                // as `heading_bins`, or five actions a second, on one side only).
                let e = Evaluation {
                    model: model.clone(),
                    env: fishprobe_sim::controller_env(c.as_ref(), &env),
                    episodes: a.episodes,
                    minutes: a.minutes,
                    seed: a.seed,
                    start: None,
                    out: a.out.join("episodes").join(name),
                    prefix: name.into(),
                };
                score_policy(c.as_ref(), &e, &support, label, by)?
            }
        };
        goals[k] = run.goals;
        first_files.push(run.files[0].clone());
        all_files.push((label, run.files.clone()));
        sources.push(run.scores);
    }
    let cap = support_cap(&env.task);
    let goal_p95 = quantile(&sources[1].scores, YARDSTICK_QUANTILE);
    let count = |src: &Source| match src {
        Source::Recorded(f) => Some(f.len()),
        Source::Simulated(_) => None,
    };
    let disagreement = ensemble
        .as_ref()
        .map(|e| disagreement_part(e, training_disagreement.as_ref(), &all_files, by))
        .transpose()?;
    let report = OodReport {
        model: model.name().to_string(),
        ood_policy: describe(&ood_src, policy),
        goal_policy: describe(&goal_src, compare_name),
        episodes: a.episodes,
        minutes: a.minutes,
        seed: a.seed,
        recorded_trials: [count(&ood_src), count(&goal_src)],
        distributions: training.iter().chain(&sources).map(distribution).collect(),
        goal_policy_p95: goal_p95,
        ood_share_beyond_goal_p95: share_at_least(&sources[0].scores, goal_p95),
        ood_share_interval: share_beyond_interval(
            &sources[0],
            &sources[1],
            YARDSTICK_QUANTILE,
            SHARE_INTERVAL_REPS,
            SHARE_INTERVAL_LEVEL,
            &mut fishprobe_sim::stream(a.seed, "ood-report-share-interval", 0),
        ),
        trained_yardstick: trained,
        goals_per_episode: goals,
        wishlist: wishlist(
            &sources[0],
            training.as_ref().unwrap_or(&SourceScores::default()),
            Some(&sources[1]),
            cap,
            10,
        ),
        disagreement,
    };
    write_figures(
        &a.out,
        &support,
        training.iter().chain(&sources),
        &first_files,
        cap,
    )?;
    let json = serde_json::to_string_pretty(&report)? + "\n";
    fishprobe_io::write_atomically(&a.out.join("ood.json"), json.as_bytes())?;
    let md = markdown(&report, a);
    fishprobe_io::write_atomically(&a.out.join("report.md"), md.as_bytes())?;
    if a.json {
        Ok(json)
    } else {
        Ok(summary(&report, &a.out))
    }
}

/// The support scores (and, with an ensemble, the disagreements) of the views of the training
/// recordings: `data`, or for the shipped M_ConvNet its training recordings in the shared data;
/// none when neither is there.
fn training_scores(
    data: &[PathBuf],
    model: &ModelSpec,
    support: &SupportModel,
    ensemble: Option<&Disagreement>,
    by: Runner,
) -> Result<(Option<SourceScores>, Option<SourceScores>)> {
    let data = if !data.is_empty() {
        data.to_vec()
    } else {
        match (model, fishprobe_io::shared_data_dir()) {
            (ModelSpec::ConvNet(p), Some(d)) if p.weights.is_empty() => {
                vec![d.join("guppy-pairs/legacy/train")]
            }
            _ => Vec::new(),
        }
    };
    if data.is_empty() {
        by.note("note: no training recordings given (data): the report has no training-data row");
        return Ok((None, None));
    }
    let clone = CloneConfig {
        robot_as_partner: true,
        ..CloneConfig::default()
    };
    let d = load_pairs(&data, &support.arch(), &clone)
        .map_err(|e| ResearchError::within("loading the training recordings", e))?;
    let disagreement =
        ensemble.map(|e| disagreement_of_views(e, "training recordings", &d.x, 50_000));
    Ok((
        Some(score_views(support, "training recordings", &d.x, 50_000)),
        disagreement,
    ))
}

/// The report's disagreement part: every policy's trial files (`all_files`, the OOD policy's
/// first, then the lead-to-goal policy's) scored by the ensemble, beside the training views'.
fn disagreement_part(
    e: &Disagreement,
    training: Option<&SourceScores>,
    all_files: &[(&str, Vec<PathBuf>)],
    by: Runner,
) -> Result<DisagreementPart> {
    by.note("scoring the views by the ensemble's disagreement ...");
    let policies = all_files
        .iter()
        .map(|(label, files)| disagreement_of_trials(e, label, files))
        .collect::<Result<Vec<_>, _>>()
        .map_err(ResearchError::msg)?;
    let p95 = quantile(&policies[1].scores, YARDSTICK_QUANTILE);
    Ok(DisagreementPart {
        members: e.members(),
        distributions: training
            .into_iter()
            .chain(&policies)
            .map(distribution)
            .collect(),
        goal_policy_p95: p95,
        ood_share_beyond_goal_p95: share_at_least(&policies[0].scores, p95),
    })
}

/// The figures: the score distributions of `curves` and the first episode of each policy
/// (`first_files`: the OOD policy's, the lead-to-goal policy's) coloured by its scores.
fn write_figures<'s>(
    out: &Path,
    support: &SupportModel,
    curves: impl Iterator<Item = &'s SourceScores>,
    first_files: &[PathBuf],
    cap: f32,
) -> Result<()> {
    let curves: Vec<(String, Vec<f32>)> = curves
        .map(|s| (s.label.clone(), s.scores.clone()))
        .collect();
    fishprobe_report::write_figure(&ood_scores(&curves, cap), out, 2.0)?;
    let examples = [
        ("OOD policy", &first_files[0]),
        ("lead-to-goal policy", &first_files[1]),
    ]
    .into_iter()
    .map(|(title, file)| {
        let name = file.file_name().unwrap_or_default().to_string_lossy();
        scored_episode(support, file, format!("{title}, {name}"))
    })
    .collect::<Result<Vec<_>>>()?;
    fishprobe_report::write_figure(&ood_trajectories(&examples, cap), out, 2.0)?;
    Ok(())
}

/// The support score at which the figures' colour scale and the wishlist's weights saturate:
/// the OOD reward's cap when the reward paid support scores (what the policy was trained to
/// reach), else the support reward's default cap. A reward of the ensemble's disagreement has
/// its cap in the disagreement's scale (e.g. 1.14 from `--ood-yardstick`), which says nothing
/// about support scores; nor does a support cap at or within the support's edge (1), e.g.
/// 0.89 from `--ood-yardstick` under a short partner range: the wishlist lists views beyond
/// 1 only, and would weigh and show every one of them as scoring the cap.
fn support_cap(task: &fishprobe_sim::TaskParams) -> f32 {
    match task.ood_score {
        fishprobe_sim::OodScore::Support if task.ood_score_cap > 1.0 => task.ood_score_cap,
        _ => fishprobe_sim::TaskParams::default().ood_score_cap,
    }
}

#[cfg(test)]
mod tests {
    use super::support_cap;
    use fishprobe_sim::{OodScore, TaskParams};

    #[test]
    fn the_support_figures_take_the_reward_cap_only_when_the_reward_paid_support_scores() {
        let support = TaskParams {
            ood_score_cap: 1.43,
            ..TaskParams::default()
        };
        assert_eq!(support_cap(&support), 1.43);
        let within = TaskParams {
            ood_score_cap: 0.893,
            ..TaskParams::default()
        };
        assert_eq!(support_cap(&within), TaskParams::default().ood_score_cap);
        let disagreement = TaskParams {
            ood_score: OodScore::Disagreement,
            ood_score_cap: 1.14,
            ..TaskParams::default()
        };
        assert_eq!(
            support_cap(&disagreement),
            TaskParams::default().ood_score_cap
        );
    }
}
