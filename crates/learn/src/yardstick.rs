//! The OOD reward's yardstick: a lead-to-goal policy's percentile of the OOD score
//! (the support score, or the ensemble's disagreement with `ood_score = "disagreement"`),
//! measured on its episodes before training, so that the OOD reward counts the time beyond it
//! instead of a threshold copied by hand from an `ood-report`.
//!
//! The yardstick policy runs the episodes `ood-report` runs by default (6 of 5 minutes, seed 0,
//! the evaluation task) against the fish model; its views' `quantile` score `T` (in the run's
//! `ood_score`)
//! becomes the reward's floor, `T + band` its cap and `1 / band` its weight, so a view at or
//! beyond `T + band` earns 1 per second and the return counts time beyond the yardstick
//! (docs/guide/ood.md, "A reward that counts time beyond a score"). `fishprobe train
//! --ood-yardstick POLICY` and the Python package's `train(..., ood_yardstick=POLICY)` both
//! start their runs through [`start_run`].

use crate::evaluate::{minutes_in_range, MINUTES_RANGE};
use crate::{Evaluation, LearnError, RunSpec, Trainer};
use fishprobe_analysis::ood::{disagreement_of_trials, quantile, score_trials, SourceScores};
use fishprobe_models::support::SupportModel;
use fishprobe_models::ModelSpec;
use fishprobe_sim::params::{check, ConfigError};
use fishprobe_sim::{Controller, EnvConfig, FishModel, Objective, OodScore};
use std::path::{Path, PathBuf};
use std::sync::Arc;

fishprobe_sim::documented_params! {
    /// How `train --ood-yardstick` measures its yardstick and shapes the reward from it.
    pub struct OodYardstickConfig {
        /// The percentile of the yardstick policy's scores that the reward counts time
        /// beyond (choice: 0.95, the OOD target: "at least as far out as the 95th percentile
        /// of the lead-to-goal policy's").
        pub quantile: f64 = 0.95; "1",
        /// Width of the reward's ramp above the yardstick: floor `T`, cap `T + band`, weight
        /// `1 / band` (choice: 0.15, the near-count of docs/validation.md, "Probes that seek what the data lacks": 26.9, 32.7 and 28.8 % of the time beyond the yardstick with
        /// 4x the paper's steps, against 21.9, 25.1 and 24.8 % with the default reward, seeds
        /// 0-2). In [0.01, 10].
        pub band: f32 = 0.15; "1",
        /// Episodes of the yardstick policy (choice: 6, `ood-report`'s default, so that its
        /// report measures the policy against the same yardstick).
        pub episodes: usize = 6; "episodes",
        /// Minutes per episode (choice: 5, `ood-report`'s default). From one second (1/60) to 1440.
        pub minutes: f32 = 5.0; "min",
        /// Master seed of the episodes (choice: 0, `ood-report`'s default).
        pub seed: u64 = 0; "-",
    }
}

impl OodYardstickConfig {
    /// Checks the ranges.
    pub fn validate(&self) -> Result<(), ConfigError> {
        let p = "ood_yardstick";
        if !(self.quantile > 0.0 && self.quantile < 1.0) {
            return Err(ConfigError::new(
                p,
                "quantile",
                check::shown(self.quantile),
                "must lie in (0, 1), e.g. 0.95",
            ));
        }
        check::within(p, "band", self.band, 0.01, 10.0)?;
        if !(1..=1000).contains(&self.episodes) {
            return Err(ConfigError::new(
                p,
                "episodes",
                self.episodes,
                "must lie in [1, 1000]",
            ));
        }
        if !minutes_in_range(f64::from(self.minutes)) {
            return Err(ConfigError::new(
                p,
                "minutes",
                self.minutes,
                &format!("must lie in {MINUTES_RANGE}"),
            ));
        }
        Ok(())
    }
}

/// What the yardstick measured and what the reward became (`yardstick.json` in the run).
#[derive(Debug, Clone, serde::Serialize)]
pub struct Yardstick {
    /// The yardstick policy as given.
    pub policy: String,
    /// How it was measured.
    pub config: OodYardstickConfig,
    /// The score it was measured in: the run's `ood_score`.
    pub ood_score: OodScore,
    /// Views scored.
    pub views: usize,
    /// Its views' `quantile` score: the reward's floor.
    pub score: f64,
    /// The reward's cap (`score + band`).
    pub cap: f32,
    /// The reward's weight (`1 / band`).
    pub weight: f32,
}

/// A policy's episodes with every fish view scored against a support model.
#[derive(Debug, Clone)]
pub struct ScoredRun {
    /// The scored views.
    pub scores: SourceScores,
    /// Goals per episode (mean).
    pub goals: f64,
    /// The episodes' trial files.
    pub files: Vec<PathBuf>,
}

/// What a yardstick is measured in.
enum Scorer {
    Support(SupportModel),
    Ensemble(fishprobe_models::disagreement::Disagreement),
}

/// Runs `c` on the episodes of `e` (their trial files in `e.out`, on rayon's current pool);
/// returns the files and the evaluation's results.
fn run_episodes(
    c: &dyn Controller,
    e: &Evaluation,
) -> Result<(Vec<PathBuf>, Vec<crate::EpisodeResult>), LearnError> {
    std::fs::create_dir_all(&e.out)
        .map_err(|err| LearnError::Run(format!("creating {}: {err}", e.out.display())))?;
    let results = crate::evaluate(c, e)?;
    let files = results.iter().map(|r| r.file.clone()).collect();
    Ok((files, results))
}

/// Runs `c` on the episodes of `e` (their trial files in `e.out`, on rayon's current pool) and
/// scores every fish view against `support` as `label`: what `ood-report` compares, and what
/// the yardstick is measured from.
pub fn score_policy(
    c: &dyn Controller,
    e: &Evaluation,
    support: &SupportModel,
    label: &str,
) -> Result<ScoredRun, LearnError> {
    let (files, results) = run_episodes(c, e)?;
    Ok(ScoredRun {
        scores: score_trials(support, label, &files)?,
        goals: crate::goals_mean_sd(&results).0,
        files,
    })
}

/// Checks a yardstick before anything runs: that the run's task in `env` is the OOD task
/// (whose reward it shapes), its settings, and that `policy` loads.
pub fn check(policy: &str, config: &OodYardstickConfig, env: &EnvConfig) -> Result<(), LearnError> {
    check_settings(config, env)?;
    load(policy).map(|_| ())
}

fn check_settings(config: &OodYardstickConfig, env: &EnvConfig) -> Result<(), LearnError> {
    if env.task.objective != Objective::Ood {
        return Err(ConfigError::new(
            "task",
            "objective",
            "goal",
            "a yardstick shapes the OOD reward: it applies to the OOD task only (objective = ood)",
        )
        .into());
    }
    Ok(config.validate()?)
}

fn load(policy: &str) -> Result<Box<dyn Controller>, LearnError> {
    crate::controller(policy, false)
        .map_err(|e| LearnError::Policy(format!("the yardstick policy {policy}: {e}")))
}

/// Runs `policy` (a training directory, `onnx:FILE` or `scripted:NAME`) on the yardstick
/// episodes against `model` in `env` (trial files in `dir`) and sets `env`'s OOD reward to count
/// the time beyond its `quantile` score, in `env`'s `ood_score`: the support score, or the
/// disagreement of the model's ensemble.
pub fn measure(
    policy: &str,
    config: &OodYardstickConfig,
    model: &ModelSpec,
    env: &mut EnvConfig,
    dir: &Path,
) -> Result<Yardstick, LearnError> {
    check_settings(config, env)?;
    let ood_score = env.task.ood_score;
    // The scorer first: a missing support file or ensemble fails before any episode runs.
    let scorer = match ood_score {
        OodScore::Support => Scorer::Support(model.support()?),
        OodScore::Disagreement => Scorer::Ensemble(model.disagreement()?),
    };
    let c = load(policy)?;
    // The yardstick policy observes and acts as it was trained to (the OOD run may observe
    // headings, or act more often).
    let e = Evaluation {
        model: model.clone(),
        env: fishprobe_sim::controller_env(c.as_ref(), env),
        episodes: config.episodes,
        minutes: config.minutes,
        seed: config.seed,
        start: None,
        out: dir.to_path_buf(),
        prefix: "yardstick".into(),
    };
    let label = "yardstick policy";
    let scores = match &scorer {
        Scorer::Support(support) => score_policy(c.as_ref(), &e, support, label)?.scores,
        Scorer::Ensemble(d) => {
            let (files, _) = run_episodes(c.as_ref(), &e)?;
            disagreement_of_trials(d, label, &files)?
        }
    };
    let score = quantile(&scores.scores, config.quantile);
    if !score.is_finite() {
        return Err(LearnError::Policy(format!(
            "the yardstick policy {policy}: its episodes gave no scored fish view"
        )));
    }
    // A yardstick inside the data's bulk (a score below 0, the training views' median) still
    // counts from 0: the floor cannot be negative.
    let floor = (score as f32).max(0.0);
    let (cap, weight) = (floor + config.band, 1.0 / config.band);
    env.task.ood_score_floor = floor;
    env.task.ood_score_cap = cap;
    env.task.ood_weight = weight;
    env.validate()?;
    Ok(Yardstick {
        policy: policy.to_string(),
        config: config.clone(),
        ood_score,
        views: scores.scores.len(),
        score,
        cap,
        weight,
    })
}

/// Starts the new run `spec` in `dir` (locked by the caller) with the fish `model`: first, with
/// a yardstick `(policy, config)`, measures it (its episodes in `dir/yardstick/`) and sets the
/// OOD reward from it, then writes the run's files, and `yardstick.json` with what was measured.
/// A directory that already holds a run is refused before anything runs.
pub fn start_run(
    dir: &Path,
    mut spec: RunSpec,
    model: Arc<dyn FishModel>,
    yardstick: Option<(&str, &OodYardstickConfig)>,
) -> Result<(Trainer, Option<Yardstick>), LearnError> {
    Trainer::ensure_new(dir)?;
    let measured = match yardstick {
        None => None,
        Some((policy, config)) => Some(measure(
            policy,
            config,
            &spec.model,
            &mut spec.env,
            &dir.join("yardstick"),
        )?),
    };
    let trainer = Trainer::create_with_model(dir, spec, model)?;
    if let Some(y) = &measured {
        let json = serde_json::to_string_pretty(y)
            .map_err(|e| LearnError::Run(format!("yardstick.json: {e}")))?
            + "\n";
        fishprobe_io::write_atomically(&dir.join("yardstick.json"), json.as_bytes())?;
    }
    Ok((trainer, measured))
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn config_ranges_are_checked_by_name() {
        let d = OodYardstickConfig::default();
        assert!(d.validate().is_ok());
        let bad = [
            OodYardstickConfig {
                quantile: 1.0,
                ..d.clone()
            },
            OodYardstickConfig {
                quantile: f64::NAN,
                ..d.clone()
            },
            OodYardstickConfig {
                band: 0.0,
                ..d.clone()
            },
            OodYardstickConfig {
                episodes: 0,
                ..d.clone()
            },
            OodYardstickConfig {
                minutes: 1e9,
                ..d.clone()
            },
            OodYardstickConfig {
                minutes: f32::NAN,
                ..d.clone()
            },
        ];
        let fields = [
            "quantile", "quantile", "band", "episodes", "minutes", "minutes",
        ];
        for (c, f) in bad.iter().zip(fields) {
            let e = c.validate().unwrap_err();
            assert_eq!(e.field, format!("ood_yardstick.{f}"), "{c:?}");
        }
        // A yardstick on the lead-to-goal task is refused by name, before its policy loads.
        let goal_task = EnvConfig::default();
        match check("no-such-policy", &d, &goal_task) {
            Err(LearnError::Config(e)) => assert_eq!(e.field, "task.objective"),
            other => panic!("{other:?}"),
        }
        let mut ood = goal_task;
        ood.task.objective = Objective::Ood;
        assert!(matches!(
            check("no-such-policy", &d, &ood),
            Err(LearnError::Policy(_))
        ));
        assert!(check("scripted:goal-seeker", &d, &ood).is_ok());
        // The disagreement score has its yardstick too (measured in its own scale).
        ood.task.ood_score = OodScore::Disagreement;
        assert!(check("scripted:goal-seeker", &d, &ood).is_ok());
    }
}
