//! The fidelity sweep (`fishprobe fidelity`). The paper leaves details open that decide what
//! PPO can find; each reading of them is a set of overrides (environment, fish model, PPO),
//! and for each reading and model this trains a probe, evaluates it on its own model, runs the
//! approach assay and the scripted baselines, and prints a scoreboard against the paper.
//! Resumable: a finished cell is read back, an interrupted training resumes.

use crate::{ResearchError, Result, Runner};
use fishprobe_analysis::competence::{plus_minus, ratio_se, GoalStats};
use fishprobe_analysis::results::nan;
use fishprobe_analysis::{approach::assay_files, AnalysisConfig};
use fishprobe_learn::{Evaluation, PolicyController, PpoConfig, RunSpec, Trainer};
use fishprobe_models::ModelSpec;
use fishprobe_sim::{derive_seed, EnvConfig};
use serde::{Deserialize, Serialize};
use serde_json::{json, Value};
use std::collections::BTreeMap;
use std::path::{Path, PathBuf};

mod readings;
use readings::{paper, with, Combo, READINGS};

/// Which readings and models the sweep runs, with what budget, and where.
#[derive(Debug, Clone, PartialEq)]
pub struct FidelitySettings {
    /// Readings to run, comma-separated (default: all; `--list` names them); `a+b` combines
    /// readings (their overrides merged, on the models both apply to).
    pub readings: Vec<String>,
    /// Models, comma-separated (a reading that changes one model runs only on it).
    pub models: Vec<String>,
    /// PPO preset every reading starts from.
    pub preset: String,
    /// Evaluation episodes of 15 minutes per cell (paper: 18).
    pub episodes: usize,
    /// Approach-assay episodes of 2 minutes per cell (SPEC choice: 10).
    pub approach_episodes: usize,
    /// Master seed.
    pub seed: u64,
    /// Where the runs and `scoreboard.md` / `scoreboard.json` go.
    pub out: PathBuf,
    /// List the readings and exit.
    pub list: bool,
}

impl Default for FidelitySettings {
    /// The command's defaults (`fishprobe fidelity` without flags).
    fn default() -> Self {
        Self {
            readings: Vec::new(),
            models: ["Follow", "Zone", "Force"].map(String::from).to_vec(),
            preset: "paper".into(),
            episodes: 18,
            approach_episodes: 10,
            seed: 0,
            out: PathBuf::from("fidelity"),
            list: false,
        }
    }
}

/// One cell of the sweep: a reading's probe of one model, scored (its `cell.json`, a row of
/// the scoreboard). Fields in the file's (alphabetical) order; NaN is written as `null`.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
pub struct CellRow {
    /// Seconds each scripted robot takes to reach its fish, by script.
    #[serde(default)]
    pub baselines_reach_s: BTreeMap<String, Option<f64>>,
    /// The scripted robot that leads best.
    pub best_scripted: String,
    /// Its goals per 15 minutes.
    #[serde(deserialize_with = "nan::f64")]
    pub best_scripted_goals: f64,
    /// The approach assay's closest distance to the fish (cm).
    #[serde(deserialize_with = "nan::f64")]
    pub closest_cm: f64,
    /// The probe's goals over the best script's.
    #[serde(deserialize_with = "nan::f64")]
    pub competence: f64,
    /// Its standard error.
    pub competence_se: Option<f64>,
    /// Goals per 15 minutes.
    #[serde(deserialize_with = "nan::f64")]
    pub goals: f64,
    /// Their standard deviation over episodes.
    #[serde(deserialize_with = "nan::f64")]
    pub goals_sd: f64,
    /// The approach assay's mean distance to the fish (cm).
    #[serde(deserialize_with = "nan::f64")]
    pub mean_distance_cm: f64,
    /// The candidate model.
    pub model: String,
    /// Share of the assay's frames the robot is nearer the fish than the wall.
    #[serde(deserialize_with = "nan::f64")]
    pub nearer_fish: f64,
    /// Seconds the probe takes to reach its fish.
    #[serde(default)]
    pub reach_s: Option<f64>,
    /// The reading (with a note when made with another seed or episode count).
    pub reading: String,
    /// What the cell was made with, as the file holds it: a finished cell is read back only
    /// when this is the same JSON (a changed default makes it another cell).
    pub settings: Value,
    /// Training steps.
    pub steps: u64,
    /// Mean time to a goal (s).
    pub time_to_goal_s: Option<f64>,
}

/// The fish model, PPO and environment settings of reading `r` for `model` under `preset`.
fn cell_settings(
    preset: &str,
    r: &Combo,
    model: &str,
) -> Result<(ModelSpec, PpoConfig, EnvConfig)> {
    let spec: ModelSpec = with(&ModelSpec::by_name(model)?, &r.merged(|p| (p.model)()))?;
    spec.validate()?;
    let Some(base_ppo) = PpoConfig::preset_for(preset, spec.is_expensive()) else {
        return Err(ResearchError::Refused(format!("unknown preset `{preset}`")));
    };
    let ppo: PpoConfig = with(&base_ppo, &r.merged(|p| (p.ppo)()))?;
    ppo.validate()?;
    let mut env: EnvConfig = with(&EnvConfig::default(), &r.merged(|p| (p.env)()))?;
    // No reading sets the shaping's discount: it follows the reading's PPO discount, as it
    // must to leave the optimal policies unchanged (`gamma-published` with `progress-shaping`).
    if env.task.progress_shaping > 0.0 {
        env.task.progress_shaping_gamma = ppo.gamma;
    }
    env.validate()?;
    Ok((spec, ppo, env))
}

/// Trains (or resumes, or reads back) the probe of one cell, evaluates it and returns its row.
fn cell(a: &FidelitySettings, r: &Combo, model: &str, dir: &Path, by: Runner) -> Result<CellRow> {
    let (spec, ppo, env) = cell_settings(&a.preset, r, model)?;
    // A finished cell is read back only if it was made with these settings (a default that
    // changed since, or another --preset, must not pass for this reading).
    let settings = json!({"ppo": ppo, "env": env, "model": spec, "episodes": a.episodes,
        "approach_episodes": a.approach_episodes, "seed": a.seed,
        "trainer": fishprobe_learn::TRAINER_REVISION});
    // As the file will hold it (an f32 becomes its shortest decimal there).
    let settings: Value = serde_json::from_str(&serde_json::to_string(&settings)?)?;
    let done = dir.join("cell.json");
    if let Some(v) = finished_cell(dir, &settings, by)? {
        return Ok(v);
    }
    let train_dir = dir.join("policy");
    let t = train_cell(a, r, model, &train_dir, (&spec, ppo, &env), by)?;
    let policy = PolicyController::load(&train_dir, false)?;
    // The cell is not finished (it has no cell.json), so its episodes, if any, are from a run
    // that stopped, perhaps with another --episodes: they go, or the times to reach the fish
    // (read from every trial file there) would count them with the new ones.
    for sub in std::iter::once("eval".to_string())
        .chain(std::iter::once("approach".to_string()))
        .chain(
            fishprobe_sim::SCRIPTED
                .iter()
                .map(|n| format!("baseline-{n}")),
        )
    {
        let d = dir.join(&sub);
        if d.exists() {
            std::fs::remove_dir_all(&d)
                .map_err(|e| ResearchError::within(format!("removing {}", d.display()), e))?;
        }
    }
    // Evaluation on the 15-minute task (evaluation goals always count the fish).
    let e = Evaluation {
        model: spec.clone(),
        env: env.clone(),
        episodes: a.episodes,
        minutes: 15.0,
        seed: derive_seed(a.seed, &format!("fidelity-eval/{model}"), 0),
        start: None,
        out: dir.join("eval"),
        prefix: "trial".into(),
    };
    let res = fishprobe_learn::evaluate(&policy, &e)?;
    let (goals, sd) = fishprobe_learn::goals_mean_sd(&res);
    let ttg: Vec<f64> = res.iter().filter_map(|x| x.mean_time_to_goal_s).collect();
    let ttg = (!ttg.is_empty()).then(|| ttg.iter().sum::<f64>() / ttg.len() as f64);
    let stats = |r: &[fishprobe_learn::EpisodeResult]| {
        GoalStats::of(&r.iter().map(|x| x.goals as f64).collect::<Vec<_>>())
    };
    let own = stats(&res);
    let mut baselines = std::collections::BTreeMap::new();
    let mut baseline_stats = std::collections::BTreeMap::new();
    for name in fishprobe_sim::SCRIPTED {
        let Some(b) = fishprobe_sim::scripted(name) else {
            continue;
        };
        let be = Evaluation {
            out: dir.join(format!("baseline-{name}")),
            ..e.clone()
        };
        let br = fishprobe_learn::evaluate(b.as_ref(), &be)?;
        let g = stats(&br);
        baselines.insert(name.to_string(), g.map_or(f64::NAN, |g| g.mean));
        baseline_stats.insert(name.to_string(), g);
    }
    let (reach_s, baselines_reach_s) = reach_columns(dir)?;
    // The study's own measure of competence, on the scripts' `scripted:` names.
    let competence = fishprobe_analysis::competence::competence_of(
        goals,
        res.len(),
        baselines,
        AnalysisConfig::default().competence_threshold,
    )
    .ok_or_else(|| ResearchError::msg("no scripted baseline ran"))?;
    let competence_se = match (own, baseline_stats.get(&competence.best)) {
        (Some(o), Some(Some(b))) => ratio_se(&o, b),
        _ => None,
    };
    let ae = fishprobe_learn::approach_assay(
        a.approach_episodes,
        2.0,
        derive_seed(a.seed, "fidelity-approach", 0),
        dir.join("approach"),
    )?;
    let files: Vec<PathBuf> = fishprobe_learn::evaluate(&policy, &ae)?
        .into_iter()
        .map(|x| x.file)
        .collect();
    let ap = assay_files(&files, &AnalysisConfig::default())?;
    let row = CellRow {
        reading: r.name.clone(),
        model: model.to_string(),
        goals,
        goals_sd: sd,
        time_to_goal_s: ttg,
        closest_cm: ap.min_iid,
        mean_distance_cm: ap.mean_iid,
        nearer_fish: ap.frac_closer_to_fish,
        best_scripted: competence.best,
        best_scripted_goals: competence.best_goals,
        competence: competence.ratio,
        competence_se,
        reach_s,
        baselines_reach_s,
        steps: t.timesteps(),
        settings,
    };
    fishprobe_nn::store::write_atomic(&done, serde_json::to_string_pretty(&row)?.as_bytes())?;
    Ok(row)
}

/// The row of the finished cell in `dir` (its `cell.json`) when it was made with `settings`;
/// `None` when there is none; an error when it was made with others.
fn finished_cell(dir: &Path, settings: &Value, by: Runner) -> Result<Option<CellRow>> {
    let done = dir.join("cell.json");
    let Some((mut row, has_reach)) = read_cell(&done) else {
        return Ok(None);
    };
    if row.settings != *settings {
        return Err(ResearchError::Refused(format!(
            "{} holds a cell made with other settings (another preset, episodes or seed, or \
             fishprobe's defaults or trainer changed since): use another output directory or \
             remove it",
            dir.display()
        )));
    }
    // Cells made before the scoreboard gave the time to reach the fish get it from their own
    // trial files, once; a cell whose trial files are gone keeps "–".
    if !has_reach {
        match reach_columns(dir) {
            Ok((reach_s, baselines_reach_s)) => {
                row.reach_s = reach_s;
                row.baselines_reach_s = baselines_reach_s;
                fishprobe_nn::store::write_atomic(
                    &done,
                    serde_json::to_string_pretty(&row)?.as_bytes(),
                )?;
            }
            Err(e) => by.note(&format!(
                "  {}: no time to reach the fish for this older cell ({})",
                dir.display(),
                e.chain()
            )),
        }
    }
    Ok(Some(row))
}

/// The row in a `cell.json`, and whether it has the time to reach the fish (older cells do
/// not); `None` when there is no readable cell.
fn read_cell(file: &Path) -> Option<(CellRow, bool)> {
    let text = fishprobe_io::read_small_text(file).ok()?;
    let v: Value = serde_json::from_str(&text).ok()?;
    let has_reach = v.get("reach_s").is_some();
    Some((serde_json::from_value(v).ok()?, has_reach))
}

/// Trains the cell's probe in `train_dir` (resuming a run of this cell's settings: the fish
/// model, PPO and environment of [`cell_settings`]).
fn train_cell(
    a: &FidelitySettings,
    r: &Combo,
    model: &str,
    train_dir: &Path,
    (spec, ppo, env): (&ModelSpec, PpoConfig, &EnvConfig),
    by: Runner,
) -> Result<Trainer> {
    let seed = derive_seed(a.seed, &format!("fidelity/{model}"), 0);
    let run_spec = RunSpec::new(
        spec.clone(),
        ppo,
        env.clone(),
        seed,
        a.preset.clone(),
        by.build,
    );
    // A cell stopped before it finished resumes its training only if that training is this
    // cell's: resumed with other settings, it would be scored as this reading.
    use fishprobe_learn::run::{train_to_end, Begin, OnOther, TrainHooks};
    struct Note<'a>(&'a dyn Fn(&str));
    impl TrainHooks for Note<'_> {
        fn iterated(
            &mut self,
            _t: &Trainer,
            s: &fishprobe_learn::IterationStats,
        ) -> Result<(), fishprobe_learn::LearnError> {
            (self.0)(&format!(
                "iteration {} steps {} goals/episode {:.2}",
                s.iteration, s.timesteps, s.goals_per_episode
            ));
            Ok(())
        }
    }
    let cell = format!("  {} / {model}: ", r.name);
    let note = |line: &str| by.note(&format!("{cell}{line}"));
    let (t, _) = train_to_end(
        train_dir,
        Begin::StartOrResume(run_spec, OnOther::Refuse),
        by.build,
        &mut Note(&note),
    )?;
    Ok(t)
}

/// Median seconds to reach the fish, per scripted controller (`None`: its median episode never did).
type ScriptedReach = std::collections::BTreeMap<String, Option<f64>>;

/// How soon the cell's probe and each scripted controller reach the fish (the study's
/// measure, median seconds; waiting at the goal or fetching), from the trial files of its
/// evaluation (`eval/`) and baselines (`baseline-<name>/`).
fn reach_columns(dir: &Path) -> Result<(Option<f64>, ScriptedReach)> {
    let acfg = AnalysisConfig::default();
    let reach = |sub: &str| -> Result<Option<f64>> {
        let mut files: Vec<PathBuf> = std::fs::read_dir(dir.join(sub))
            .map_err(|e| ResearchError::within(format!("reading {}", dir.join(sub).display()), e))?
            .filter_map(|e| e.ok().map(|e| e.path()))
            .filter(|p| p.extension().is_some_and(|x| x == "hdf5"))
            .collect();
        files.sort();
        fishprobe_analysis::competence::median_reach_of(&files, &acfg).map_err(ResearchError::from)
    };
    let mut baselines = std::collections::BTreeMap::new();
    for name in fishprobe_sim::SCRIPTED {
        baselines.insert(name.to_string(), reach(&format!("baseline-{name}"))?);
    }
    Ok((reach("eval")?, baselines))
}

fn factor(ours: f64, paper: Option<f64>) -> String {
    match paper {
        Some(p) if p > 0.0 && ours.is_finite() => format!(" (x{:.2})", ours / p),
        _ => String::new(),
    }
}

fn scoreboard(rows: &[CellRow]) -> String {
    let mut s = String::from(
        "| reading | model | goals / 15 min (paper, factor) | time to goal (s) | closest (cm; paper) | nearer the fish (paper) | best scripted | competence | reaches its fish (s; fetch-and-lead, goal-seeker) |\n|---|---|---|---|---|---|---|---|---|\n",
    );
    for r in rows {
        let m = r.model.as_str();
        let (pg, pc, pf) = paper(m);
        let (g, c, f) = (r.goals, r.closest_cm, r.nearer_fish);
        let opt = |v: Option<f64>, d: usize| v.map_or("–".to_string(), |x| format!("{x:.d$}"));
        let baseline = |name: &str| r.baselines_reach_s.get(name).copied().flatten();
        s += &format!(
            "| {} | {m} | {g:.1} ± {:.1} ({}{}) | {} | {c:.1} ({}) | {:.1} % ({}) | {} {:.1} | {:.2}{} | {} ({}, {}) |\n",
            r.reading,
            r.goals_sd,
            opt(pg, 0),
            factor(g, pg),
            opt(r.time_to_goal_s, 1),
            opt(pc, 2),
            100.0 * f,
            pf.map_or("–".into(), |x| format!("{:.1} %", 100.0 * x)),
            r.best_scripted,
            r.best_scripted_goals,
            r.competence,
            plus_minus(r.competence_se),
            opt(r.reach_s, 1),
            opt(baseline("fetch-and-lead"), 1),
            opt(baseline("goal-seeker"), 1),
        );
    }
    s
}

/// Runs the sweep (or, with `list`, lists the readings), writing every cell and the
/// scoreboard files under `out`, and returns this run's scoreboard; progress goes to `by`.
pub fn run(a: &FidelitySettings, by: Runner) -> Result<String> {
    if a.list {
        let mut s = String::new();
        for r in READINGS {
            let only = if r.models.is_empty() {
                String::new()
            } else {
                format!(" [{}]", r.models.join(", "))
            };
            s += &format!("{:<24} {}{only}\n", r.name, r.what);
        }
        return Ok(s);
    }
    if !(1..=1000).contains(&a.episodes) || !(1..=1000).contains(&a.approach_episodes) {
        return Err(ResearchError::Refused(
            "episodes and approach_episodes must lie in [1, 1000]".to_string(),
        ));
    }
    for m in &a.models {
        ModelSpec::by_name(m).map_err(|e| ResearchError::within(format!("models: {m}"), e))?;
    }
    super::no_repeats("models", &a.models)?;
    super::no_repeats("readings", &a.readings)?;
    let chosen: Vec<Combo> = if a.readings.is_empty() {
        READINGS
            .iter()
            .map(|r| Combo::parse(r.name))
            .collect::<Result<_>>()?
    } else {
        a.readings
            .iter()
            .map(|n| Combo::parse(n))
            .collect::<Result<_>>()?
    };
    let _lock = fishprobe_io::DirLock::acquire(&a.out, "fidelity")?;
    let mut rows = Vec::new();
    for r in &chosen {
        for m in &a.models {
            let name = ModelSpec::by_name(m)?.name().to_string();
            if !r.applies_to(&name) {
                continue;
            }
            by.note(&format!("{} / {name}: {}", r.name, r.what()));
            let dir = a.out.join(&r.name).join(&name);
            let row = cell(a, r, &name, &dir, by)?;
            rows.push(row);
            let all = with_finished_cells(a, &rows);
            let board = scoreboard(&all);
            fishprobe_nn::store::write_atomic(
                &a.out.join("scoreboard.md"),
                format!(
                    "# fishprobe fidelity sweep\n\nEvery finished cell in this directory; the last \
                     run: `fishprobe fidelity --preset {} --episodes {} --seed {}` (fishprobe {}). \
                     A cell made with another seed or episode count says so after its reading.\n\n{board}",
                    a.preset,
                    a.episodes,
                    a.seed,
                    env!("CARGO_PKG_VERSION")
                )
                .as_bytes(),
            )?;
            fishprobe_nn::store::write_atomic(
                &a.out.join("scoreboard.json"),
                serde_json::to_string_pretty(&all)?.as_bytes(),
            )?;
        }
    }
    Ok(scoreboard(&rows))
}

/// This run's rows, then every other finished cell under `--out` (`READING/MODEL/cell.json`,
/// from earlier runs with other readings or models), sorted by reading and model, so that the
/// scoreboard files hold the whole directory. A cell made with another seed or episode count
/// gets it appended to its reading's name.
fn with_finished_cells(a: &FidelitySettings, rows: &[CellRow]) -> Vec<CellRow> {
    let key = |v: &CellRow| (v.reading.clone(), v.model.clone());
    let ours: std::collections::BTreeSet<_> = rows.iter().map(key).collect();
    let mut others = Vec::new();
    for reading in std::fs::read_dir(&a.out).into_iter().flatten().flatten() {
        for model in std::fs::read_dir(reading.path())
            .into_iter()
            .flatten()
            .flatten()
        {
            let Some((mut v, _)) = read_cell(&model.path().join("cell.json")) else {
                continue;
            };
            if ours.contains(&key(&v)) {
                continue;
            }
            let settings = &v.settings;
            let seed = settings["seed"].as_u64().filter(|&s| s != a.seed);
            let episodes = settings["episodes"]
                .as_u64()
                .filter(|&e| e != a.episodes as u64);
            let notes: Vec<String> = seed
                .map(|s| format!("seed {s}"))
                .into_iter()
                .chain(episodes.map(|e| format!("{e} episodes")))
                .collect();
            if !notes.is_empty() {
                v.reading = format!("{} ({})", v.reading, notes.join(", "));
            }
            others.push(v);
        }
    }
    others.sort_by_key(key);
    rows.iter().cloned().chain(others).collect()
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn the_shaping_reading_discounts_as_its_learner_does() {
        for (readings, gamma) in [
            ("progress-shaping", 0.99),
            (
                "progress-shaping+gamma-published",
                PpoConfig::PUBLISHED_GAMMA,
            ),
        ] {
            let r = Combo::parse(readings).unwrap();
            let (spec, ppo, env) = cell_settings("paper", &r, "Zone").unwrap();
            assert_eq!(ppo.gamma, gamma, "{readings}");
            assert_eq!(env.task.progress_shaping_gamma, gamma, "{readings}");
            let run = fishprobe_learn::RunSpec::new(spec, ppo, env, 0, "paper", "test");
            run.check().unwrap();
        }
        // Without the reading the shaping is off and its discount stays the default.
        let r = Combo::parse("gamma-published").unwrap();
        let (_, _, env) = cell_settings("paper", &r, "Zone").unwrap();
        assert_eq!(env.task.progress_shaping_gamma, 0.99);
    }
}
