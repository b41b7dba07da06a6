//! `fishprobe ood-report`: what an OOD policy (issue 23) drives the fish into. Runs the policy
//! and a lead-to-goal policy on the same episodes against the fish model, scores every view
//! of the fish against the model's training support, and writes the distributions, example
//! episodes, and a ranked data wishlist.

use anyhow::{bail, Context, Result};
use clap::Args;
use fishprobe_analysis::ood::{
    distribution, quantile, score_trials, score_views, share_at_least, trial_views, wishlist,
    Distribution, SourceScores, WishItem,
};
use fishprobe_learn::bc::{load_pairs, CloneConfig};
use fishprobe_learn::{Evaluation, Trainer};
use fishprobe_models::support::SupportModel;
use fishprobe_models::ModelSpec;
use fishprobe_report::figures::{ood_scores, ood_trajectories, ScoredEpisode};
use fishprobe_sim::{Controller, EnvConfig};
use std::path::{Path, PathBuf};

use super::emit;

#[derive(Debug, Args)]
pub struct OodReportArgs {
    /// The OOD policy: a directory from `fishprobe train --task ood` (or `onnx:FILE`).
    #[arg(long)]
    policy: String,
    /// The lead-to-goal policy to compare with (a training directory, `onnx:FILE` or
    /// `scripted:NAME`). Default: `scripted:fetch-and-lead`.
    #[arg(long, default_value = "scripted:fetch-and-lead")]
    compare: String,
    /// The fish model (default: the one the OOD policy was trained against).
    #[arg(long)]
    model: Option<String>,
    /// The model's training recordings, for their score distribution (default: the shared
    /// guppy pairs when the model is the shipped ConvNet and they are found; else none).
    #[arg(long, num_args = 1..)]
    data: Vec<PathBuf>,
    /// Episodes per policy.
    #[arg(long, default_value_t = 6)]
    episodes: usize,
    /// Minutes per episode (the evaluation task: random starts, corner goals).
    #[arg(long, default_value_t = 5.0)]
    minutes: f32,
    /// Master seed of the episodes (both policies get the same ones).
    #[arg(long, default_value_t = 0)]
    seed: u64,
    /// Report directory (report.md, ood.json, figures, the episodes' trial files).
    #[arg(long)]
    out: PathBuf,
    /// Print ood.json instead of the summary.
    #[arg(long)]
    json: bool,
}

/// The training run behind a policy argument, if it is one.
fn run_dir(policy: &str) -> Option<&Path> {
    let p = Path::new(policy);
    (!policy.contains(':') && p.join("params.json").exists()).then_some(p)
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
    distributions: Vec<Distribution>,
    /// The goal policy's 95th-percentile score.
    goal_policy_p95: f64,
    /// Share of the OOD policy's views scoring at least that (the target: most).
    ood_share_beyond_goal_p95: f64,
    /// The score the OOD policy's reward counted time beyond (`train --ood-yardstick`), if
    /// it was trained so: its `yardstick.json`.
    trained_yardstick: Option<TrainedYardstick>,
    goals_per_episode: [f64; 2],
    wishlist: Vec<WishItem>,
}

/// What `train --ood-yardstick` measured for the OOD policy (its run's `yardstick.json`).
#[derive(Debug, serde::Serialize, serde::Deserialize)]
struct TrainedYardstick {
    policy: String,
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
    let text =
        std::fs::read_to_string(&file).with_context(|| format!("reading {}", file.display()))?;
    let y = serde_json::from_str(&text)
        .with_context(|| format!("{}: not a yardstick record of `train`", file.display()))?;
    Ok(Some(y))
}

/// An example episode for the picture: the robot's path, the first fish's scored views.
fn scored_episode(support: &SupportModel, file: &Path, title: String) -> Result<ScoredEpisode> {
    let t = fishprobe_io::read_trial(file)?;
    Ok(ScoredEpisode {
        title,
        robot: t.robot().map(|r| r.positions.clone()).unwrap_or_default(),
        fish: trial_views(support, &t)
            .into_iter()
            .filter(|v| v.fish == 0)
            .map(|v| (v.position, v.score))
            .collect(),
    })
}

/// A policy's episodes, every fish view scored against the support.
pub(crate) struct ScoredRun {
    /// The scored views.
    pub scores: SourceScores,
    /// Goals per episode (mean).
    pub goals: f64,
    /// The episodes' trial files.
    pub files: Vec<PathBuf>,
}

/// Runs `c` on the episodes of `e` (their trial files in `e.out`) and scores every fish view
/// against `support`: what `ood-report` compares, and what `train --ood-yardstick` takes its
/// yardstick from.
pub(crate) fn score_policy(
    c: &dyn Controller,
    e: &Evaluation,
    support: &SupportModel,
    label: &str,
) -> Result<ScoredRun> {
    std::fs::create_dir_all(&e.out).with_context(|| format!("creating {}", e.out.display()))?;
    say!("running {} episodes of {} ...", e.episodes, c.describe());
    let results = super::with_jobs(None, || fishprobe_learn::evaluate(c, e))??;
    let files: Vec<PathBuf> = results.iter().map(|r| r.file.clone()).collect();
    Ok(ScoredRun {
        scores: score_trials(support, label, &files).map_err(anyhow::Error::msg)?,
        goals: fishprobe_learn::goals_mean_sd(&results).0,
        files,
    })
}

pub fn run(a: OodReportArgs) -> Result<()> {
    if a.episodes == 0 || a.episodes > 1000 {
        bail!("--episodes must lie in [1, 1000], got {}", a.episodes);
    }
    super::check_minutes("--minutes", f64::from(a.minutes))?;
    let _lock = super::lock_out(&a.out, "ood-report")?;
    let recorded = run_dir(&a.policy).map(Trainer::recorded_spec).transpose()?;
    let model = match (&a.model, &recorded) {
        (Some(m), _) => ModelSpec::by_name(m)?,
        (None, Some(spec)) => spec.model.clone(),
        (None, None) => bail!("--model is required when --policy is not a training directory"),
    };
    let support = model
        .support()
        .with_context(|| format!("the support of fish model {}", model.name()))?;
    let env = recorded
        .as_ref()
        .map(|s| s.env.clone())
        .unwrap_or_else(EnvConfig::default);
    let ood_c = fishprobe_learn::controller(&a.policy, false)
        .with_context(|| format!("loading --policy {}", a.policy))?;
    // Read before the episodes: a corrupt record fails at once, not after minutes.
    let trained = trained_yardstick(&a.policy)?;
    let goal_c = fishprobe_learn::controller(&a.compare, false)
        .with_context(|| format!("loading --compare {}", a.compare))?;
    // The training recordings too: a bad --data fails before minutes of episodes.
    let data = if !a.data.is_empty() {
        a.data.clone()
    } else {
        match (&model, fishprobe_io::shared_data_dir()) {
            (ModelSpec::ConvNet(p), Some(d)) if p.weights.is_empty() => {
                vec![d.join("guppy-pairs/legacy/train")]
            }
            _ => Vec::new(),
        }
    };
    let training = if data.is_empty() {
        say!("note: no training recordings given (--data): the report has no training-data row");
        None
    } else {
        let clone = CloneConfig {
            robot_as_partner: true,
            ..CloneConfig::default()
        };
        let d = load_pairs(&data, &support.arch(), &clone).context("loading --data")?;
        Some(score_views(&support, "training recordings", &d.x, 50_000))
    };
    let mut sources = Vec::new();
    let mut goals = [0.0; 2];
    let mut first_files = Vec::new();
    for (k, (c, name)) in [(&ood_c, "ood"), (&goal_c, "goal")].into_iter().enumerate() {
        let e = Evaluation {
            model: model.clone(),
            env: env.clone(),
            episodes: a.episodes,
            minutes: a.minutes,
            seed: a.seed,
            start: None,
            out: a.out.join("episodes").join(name),
            prefix: name.into(),
        };
        let label = if k == 0 {
            "OOD policy"
        } else {
            "lead-to-goal policy"
        };
        let run = score_policy(c.as_ref(), &e, &support, label)?;
        goals[k] = run.goals;
        first_files.push(run.files[0].clone());
        sources.push(run.scores);
    }
    let cap = env.task.ood_score_cap;
    let goal_p95 = quantile(&sources[1].scores, 0.95);
    let report = OodReport {
        model: model.name().to_string(),
        ood_policy: format!("{} ({})", a.policy, ood_c.describe()),
        goal_policy: format!("{} ({})", a.compare, goal_c.describe()),
        episodes: a.episodes,
        minutes: a.minutes,
        seed: a.seed,
        distributions: training.iter().chain(&sources).map(distribution).collect(),
        goal_policy_p95: goal_p95,
        ood_share_beyond_goal_p95: share_at_least(&sources[0].scores, goal_p95),
        trained_yardstick: trained,
        goals_per_episode: goals,
        wishlist: wishlist(
            &sources[0],
            training.as_ref().unwrap_or(&SourceScores::default()),
            Some(&sources[1]),
            cap,
            10,
        ),
    };
    // Figures.
    let curves: Vec<(String, Vec<f32>)> = training
        .iter()
        .chain(&sources)
        .map(|s| (s.label.clone(), s.scores.clone()))
        .collect();
    fishprobe_report::write_figure(&ood_scores(&curves, cap), &a.out, 2.0)?;
    let examples = [
        ("OOD policy", &first_files[0]),
        ("lead-to-goal policy", &first_files[1]),
    ]
    .into_iter()
    .map(|(title, file)| scored_episode(&support, file, format!("{title}, episode 0")))
    .collect::<Result<Vec<_>>>()?;
    fishprobe_report::write_figure(&ood_trajectories(&examples, cap), &a.out, 2.0)?;
    let json = serde_json::to_string_pretty(&report)? + "\n";
    fishprobe_io::write_atomically(&a.out.join("ood.json"), json.as_bytes())?;
    let md = markdown(&report, &a);
    fishprobe_io::write_atomically(&a.out.join("report.md"), md.as_bytes())?;
    if a.json {
        emit(&json)
    } else {
        emit(&summary(&report, &a.out))
    }
}

fn pct(v: f64) -> String {
    format!("{:.1} %", 100.0 * v)
}

fn distributions_table(r: &OodReport) -> String {
    let mut t = String::from(
        "| views of | scored | median score | 95th percentile | beyond the support (> 1) |\n|---|---|---|---|---|\n",
    );
    for d in &r.distributions {
        t += &format!(
            "| {} | {} | {:.2} | {:.2} | {} |\n",
            d.label,
            d.views,
            d.median,
            d.p95,
            pct(d.beyond_support)
        );
    }
    t
}

fn wishlist_table(r: &OodReport) -> String {
    let mut t = String::from(
        "| rank | situation | OOD policy's time there, beyond the support | mean score | share of training views | share of lead-to-goal views |\n|---|---|---|---|---|---|\n",
    );
    for w in &r.wishlist {
        t += &format!(
            "| {} | {} | {} | {:.2} | {} | {} |\n",
            w.rank,
            w.situation,
            pct(w.ood_policy_share_beyond),
            w.mean_score,
            pct(w.training_share),
            w.goal_policy_share.map(pct).unwrap_or_else(|| "–".into())
        );
    }
    t
}

/// A note when the OOD policy was trained to count time beyond another score than this
/// report's yardstick (empty when it was not, or the two agree).
fn yardstick_note(r: &OodReport) -> String {
    match &r.trained_yardstick {
        Some(y) if (y.score - r.goal_policy_p95).abs() > 1e-9 => format!(
            " Note: the OOD policy's reward counted time beyond {:.3} (the 95th percentile of \
             {}, `train --ood-yardstick`), not this report's yardstick.",
            y.score, y.policy
        ),
        _ => String::new(),
    }
}

fn summary(r: &OodReport, out: &Path) -> String {
    format!(
        "{}\nThe OOD policy's fish spent {} of their time at or beyond the lead-to-goal \
         policy's 95th-percentile score ({:.2}).{} Goals per episode: OOD {:.1}, lead-to-goal \
         {:.1}.\n\nData wishlist (record these next):\n{}\nwrote {}\n",
        distributions_table(r),
        pct(r.ood_share_beyond_goal_p95),
        r.goal_policy_p95,
        yardstick_note(r),
        r.goals_per_episode[0],
        r.goals_per_episode[1],
        r.wishlist
            .iter()
            .take(5)
            .map(|w| format!(
                "  {}. {} ({} of the OOD policy's time)\n",
                w.rank,
                w.situation,
                pct(w.ood_policy_share_beyond)
            ))
            .collect::<String>(),
        out.join("report.md").display()
    )
}

fn markdown(r: &OodReport, a: &OodReportArgs) -> String {
    format!(
        "# What the OOD policy finds\n\n\
         Fish model: {}. OOD policy: {}. Lead-to-goal policy: {}. {} episodes of {} min each \
         per policy (seed {}; the evaluation task's random starts and corner goals), every \
         fish view scored against the model's training support (0: the training views' \
         median, 1: their 95th percentile).\n\n\
         ## Support scores\n\n{}\n\
         The OOD policy's fish spent **{}** of their time at or beyond the lead-to-goal \
         policy's 95th-percentile score ({:.2}).{} Goals per episode: OOD policy {:.1}, \
         lead-to-goal policy {:.1}.\n\n\
         ![score distributions](ood-scores.png)\n\n\
         ![example episodes](ood-trajectories.png)\n\n\
         ## Data wishlist\n\n\
         The situations beyond the support where the OOD policy drove the fish, ranked by \
         its time there weighted by score: what the lab should record next.\n\n{}\n\
         Made by `fishprobe ood-report --policy {} --compare {} --episodes {} --minutes {} \
         --seed {}`.\n",
        r.model,
        r.ood_policy,
        r.goal_policy,
        r.episodes,
        r.minutes,
        r.seed,
        distributions_table(r),
        pct(r.ood_share_beyond_goal_p95),
        r.goal_policy_p95,
        yardstick_note(r),
        r.goals_per_episode[0],
        r.goals_per_episode[1],
        wishlist_table(r),
        a.policy,
        a.compare,
        a.episodes,
        a.minutes,
        a.seed
    )
}
