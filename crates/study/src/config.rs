//! What a study runs: the models, the presets' budgets, and a study file (TOML) that can add
//! parameter variants of any model under new names.

use crate::StudyError;
use fishprobe_models::ModelSpec;
use serde::{Deserialize, Serialize};

/// Most episodes, trials or trials per comparison a study may ask for in one setting (the paper's
/// largest is 50 episodes per cell); checked before any work, since every one is simulated.
pub const MAX_COUNT: usize = 100_000;

/// A candidate model under the name its policy and directories carry.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct NamedModel {
    /// Directory-safe name ("Zone", "ZoneRadii").
    pub name: String,
    /// The model and its parameters (`{ model = "Zone", zone_convention = "radii" }`).
    pub spec: ModelSpec,
}

/// The study's settings. Presets fill every field; a study file overrides any of them.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct StudyConfig {
    /// Preset the budgets came from: smoke, quick, paper or published.
    pub preset: String,
    /// Master seed of the whole study.
    pub seed: u64,
    /// Candidate models (paper: Follow, Zone, Force, ConvNet).
    pub models: Vec<NamedModel>,
    /// PPO preset of the training runs (paper, published, quick, smoke).
    pub ppo_preset: String,
    /// Environment steps per training run (None: the PPO preset's).
    pub train_steps: Option<u64>,
    /// PPO epochs per batch (None: the PPO preset's: 2 for `paper`, the published 100 for
    /// `published`; see `fishprobe_learn::PpoConfig::num_sgd_iter` for why they differ).
    #[serde(default)]
    pub ppo_epochs: Option<usize>,
    /// PPO discount γ per 1-s action for every model (None: the PPO preset's, 0.99 for
    /// `paper`, the published 0.9453 for the others; see
    /// `fishprobe_learn::PpoConfig::gamma` for why they differ). `ppo_gamma = 0.9453` trains
    /// the `paper` preset's budget at the paper's discount, under which π_Zone waits at the
    /// goal for its fish in most seeds (docs/validation.md, "The approach pattern over seeds").
    /// Written to the study's settings only when set.
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub ppo_gamma: Option<f32>,
    /// Steps and epochs of the policies of expensive fish (M_ConvNet, ONNX and Python models,
    /// `ModelSpec::is_expensive`), in place of
    /// the budget above (None, every preset: the PPO preset's for such a fish, which for
    /// `paper` is 832,300 steps at 10 epochs, see `fishprobe_learn::PpoConfig::preset_for`,
    /// with the study's `train_steps` and `ppo_epochs`).
    #[serde(default)]
    pub expensive_fish_budget: Option<Budget>,
    /// Training seeds per model beyond the first, for the stability analysis (paper: 5).
    pub extra_seeds: usize,
    /// Minutes per evaluation episode (paper: 15).
    pub episode_minutes: f32,
    /// Sim trials per policy on its own model for the sim-to-real comparison (paper: 18).
    pub sim_trials: usize,
    /// Episodes per sim-to-sim cell (paper: 50; the own-model cell holds max(this, sim_trials)).
    pub cross_episodes: usize,
    /// Approach-assay episodes per policy (paper: 10).
    pub approach_episodes: usize,
    /// Minutes per approach episode (choice: 2).
    pub approach_minutes: f32,
    /// Stability episodes per training seed (paper: 50).
    pub stability_episodes: usize,
    /// Virtual-lab trials per policy when there are no real trials (paper: 18 live trials).
    pub virtual_trials: usize,
    /// Minutes of control per virtual-lab trial (paper: 15).
    pub virtual_minutes: f64,
    /// Fewer resampling replicates in the analysis.
    pub analysis_quick: bool,
    /// Most epochs when M_ConvNet is refitted (`--convnet-data`; early stopping decides
    /// before that).
    pub convnet_max_epochs: usize,
    /// Policies trained elsewhere, by the name of the model they were trained on: `onnx:PATH`
    /// (docs/onnx-models.md) or a `fishprobe train` directory, absolute paths. Such a model's
    /// first training run is skipped and this policy is evaluated, assayed and analysed in
    /// its place (the extra stability seeds are still trained by fishprobe).
    #[serde(default)]
    pub policies: std::collections::BTreeMap<String, String>,
    /// Fish per tank in training, evaluation, stability, baselines and the virtual lab (paper:
    /// 1; groups: 1 to 16). The approach assay keeps its one motionless fish.
    #[serde(default = "one_fish")]
    pub fish_count: u32,
    /// When a group has reached a goal (`task.group_goal`: any, centroid or fraction, with
    /// the environment's default fraction of 0.5).
    #[serde(default)]
    pub group_goal: fishprobe_sim::GroupGoal,
    /// The policies observe the group's centroid too (`observation.centroid_bins`: 216 values
    /// instead of the paper's 180; groups).
    #[serde(default)]
    pub centroid_bins: bool,
    /// Analysis settings replaced by the study file's `[analysis]` table, by field name of
    /// `fishprobe_analysis::AnalysisConfig` (e.g. `competence_threshold`,
    /// `approach_closest_cm`), applied over the preset's (`analysis_quick`) and `sim_trials`.
    #[serde(default, skip_serializing_if = "serde_json::Map::is_empty")]
    pub analysis: serde_json::Map<String, serde_json::Value>,
    /// Task settings replaced by the study file's `[task]` table, by field name of
    /// `fishprobe_sim::TaskParams` (e.g. `training_start = "mixed"`,
    /// `training_goal_reached_by = "robot"`, the fidelity sweep's readings), for
    /// every training and trial of the study. Refused: `group_goal` (set at the top),
    /// `objective` (a study measures the lead-to-goal task; `fishprobe train --task ood`) and
    /// `evaluation_episode_actions` (set `episode_minutes`). The approach assay keeps its own
    /// set-up (SPEC §8).
    #[serde(default, skip_serializing_if = "serde_json::Map::is_empty")]
    pub task: serde_json::Map<String, serde_json::Value>,
}

fn one_fish() -> u32 {
    1
}

/// A training budget that replaces the PPO preset's for some models
/// ([`StudyConfig::expensive_fish_budget`]).
#[derive(Debug, Clone, Copy, PartialEq, Eq, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct Budget {
    /// Environment steps per training run.
    pub train_steps: u64,
    /// PPO epochs per batch.
    pub ppo_epochs: usize,
}

/// A policy trained elsewhere, named in a study file:
/// `[[policies]] model = "Zone", policy = "onnx:sb3_zone.onnx"`.
#[derive(Debug, Clone, PartialEq, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct ExternalPolicy {
    /// The study's model the policy was trained on (a name in `models`).
    pub model: String,
    /// `onnx:PATH` or a `fishprobe train` directory; relative paths are relative to the study
    /// file.
    pub policy: String,
}

fn paper_models() -> Vec<NamedModel> {
    ["Follow", "Zone", "Force", "ConvNet"]
        .into_iter()
        .filter_map(|n| {
            ModelSpec::by_name(n).ok().map(|spec| NamedModel {
                name: n.to_string(),
                spec,
            })
        })
        .collect()
}

/// Settings of a study that no step reads: changed, they rerun nothing (`study.json` records
/// them), with why.
pub const PRESENTATION_ONLY: &[(&str, &str)] = &[(
    "preset",
    "the name of the preset the budgets came from; the budgets themselves are settings",
)];

impl StudyConfig {
    /// A preset: `paper` (the published protocol, with PPO's `paper` preset: sixteen times the
    /// published steps at 2 epochs per batch, γ = 0.99, bounded log-s.d.; an expensive fish's
    /// policy the published steps at 10 epochs), `published` (the same with the published PPO
    /// settings, 100 epochs, γ = 0.9453 and RLlib's unbounded log-s.d., whose π_Zone and
    /// π_Force do not learn in this simulator), `quick` (the README's main command: a complete study in
    /// minutes) or `smoke` (tiny, for tests).
    pub fn preset(name: &str) -> Option<Self> {
        let paper = Self {
            preset: "paper".into(),
            seed: 0,
            models: paper_models(),
            ppo_preset: "paper".into(),
            train_steps: None,
            ppo_epochs: None,
            ppo_gamma: None,
            expensive_fish_budget: None,
            extra_seeds: 5,
            episode_minutes: 15.0,
            sim_trials: 18,
            cross_episodes: 50,
            approach_episodes: 10,
            approach_minutes: 2.0,
            stability_episodes: 50,
            virtual_trials: 18,
            virtual_minutes: 15.0,
            analysis_quick: false,
            convnet_max_epochs: 30,
            policies: std::collections::BTreeMap::new(),
            fish_count: 1,
            group_goal: fishprobe_sim::GroupGoal::Any,
            centroid_bins: false,
            analysis: serde_json::Map::new(),
            task: serde_json::Map::new(),
        };
        match name {
            "published" => Some(Self {
                preset: "published".into(),
                ppo_preset: "published".into(),
                ..paper
            }),
            "paper" => Some(paper),
            "quick" => Some(Self {
                preset: "quick".into(),
                ppo_preset: "quick".into(),
                extra_seeds: 2,
                cross_episodes: 18,
                approach_episodes: 5,
                stability_episodes: 10,
                analysis_quick: true,
                ..paper
            }),
            "smoke" => Some(Self {
                preset: "smoke".into(),
                ppo_preset: "smoke".into(),
                train_steps: Some(4096),
                extra_seeds: 1,
                // Two minutes: the goals-per-minute trend needs more than one minute.
                episode_minutes: 2.0,
                sim_trials: 3,
                cross_episodes: 3,
                approach_episodes: 2,
                approach_minutes: 1.0,
                stability_episodes: 3,
                virtual_trials: 3,
                virtual_minutes: 2.0,
                analysis_quick: true,
                convnet_max_epochs: 1,
                ..paper
            }),
            _ => None,
        }
    }

    /// The PPO settings of the training runs of `model`: the PPO preset for that model with the
    /// study's overrides of steps and epochs, and for an expensive fish its
    /// [`StudyConfig::expensive_fish_budget`] if set (None: an unknown PPO preset).
    pub fn ppo(&self, model: &ModelSpec) -> Option<fishprobe_learn::PpoConfig> {
        let mut ppo =
            fishprobe_learn::PpoConfig::preset_for(&self.ppo_preset, model.is_expensive())?;
        if let Some(n) = self.train_steps {
            ppo.total_timesteps = n;
        }
        if let Some(e) = self.ppo_epochs {
            ppo.num_sgd_iter = e;
        }
        if let Some(g) = self.ppo_gamma {
            ppo.gamma = g;
        }
        if let Some(b) = self.expensive_fish_budget.filter(|_| model.is_expensive()) {
            ppo.total_timesteps = b.train_steps;
            ppo.num_sgd_iter = b.ppo_epochs;
        }
        Some(ppo)
    }

    /// The environment of the study's trials: the defaults with its group settings and its
    /// `[task]` table (refused by name if a setting is unknown, mistyped, out of range or one
    /// the study sets elsewhere).
    pub fn env(&self) -> Result<fishprobe_sim::EnvConfig, StudyError> {
        let bad = |e: String| StudyError::Input(format!("[task] {e}"));
        for (key, instead) in [
            ("group_goal", "set `group_goal` at the top of the study file"),
            (
                "objective",
                "a study measures the lead-to-goal task; train an OOD policy with `fishprobe train --task ood`",
            ),
            (
                "evaluation_episode_actions",
                "set `episode_minutes` at the top of the study file",
            ),
        ] {
            if self.task.contains_key(key) {
                return Err(bad(format!("{key}: {instead}")));
            }
        }
        let mut env = fishprobe_sim::EnvConfig {
            fish_count: self.fish_count,
            ..fishprobe_sim::EnvConfig::default()
        };
        env.task = fishprobe_sim::params::replace_by_name(&env.task, "task", &self.task)
            .map_err(|e| bad(e.to_string()))?;
        env.task.group_goal = self.group_goal;
        env.observation.centroid_bins = self.centroid_bins;
        env.validate()
            .map_err(|e| StudyError::Input(format!("fish_count / group_goal / [task]: {e}")))?;
        Ok(env)
    }

    /// The analysis settings: the preset's (quick or full resampling), the study's
    /// `sim_trials`, then the study file's `[analysis]` table.
    pub fn analysis_config(&self) -> Result<fishprobe_analysis::AnalysisConfig, StudyError> {
        let base = if self.analysis_quick {
            fishprobe_analysis::AnalysisConfig::quick()
        } else {
            fishprobe_analysis::AnalysisConfig::default()
        };
        if self.analysis.contains_key("sim_trials") {
            return Err(StudyError::Input(
                "[analysis] sim_trials: set `sim_trials` at the top of the study file, it decides the trials run too"
                    .into(),
            ));
        }
        let base = fishprobe_analysis::AnalysisConfig {
            sim_trials: self.sim_trials,
            ..base
        };
        base.with_overrides(&self.analysis)
            .map_err(|e| StudyError::Input(format!("[analysis] {e}")))
    }

    /// Checks the settings before any work starts.
    pub fn validate(&self) -> Result<(), StudyError> {
        let bad = |what: String| Err(StudyError::Input(what));
        if self.models.is_empty() {
            return bad("no models".into());
        }
        self.analysis_config()?;
        let env = self.env()?;
        for model in self.policies.keys() {
            if !self.models.iter().any(|m| &m.name == model) {
                return bad(format!(
                    "a policy for `{model}`, which is not one of the study's models"
                ));
            }
        }
        let mut seen = std::collections::BTreeSet::new();
        for m in &self.models {
            if let Some(why) = fishprobe_io::layout::name_problem(&m.name) {
                return bad(format!("model name `{}`: {why}", m.name));
            }
            if !seen.insert(m.name.clone()) {
                return bad(format!("model name `{}` twice", m.name));
            }
        }
        if let Some((a, b)) =
            fishprobe_io::layout::case_clash(self.models.iter().map(|m| m.name.as_str()))
        {
            return bad(format!(
                "model names `{a}` and `{b}` differ only in case: on a case-insensitive file \
                 system (macOS's default) they would share one directory"
            ));
        }
        for m in &self.models {
            m.spec
                .build()
                .map_err(|e| StudyError::Input(format!("model `{}`: {e}", m.name)))?;
            let base = match &m.spec {
                ModelSpec::Population(p) => p.base.as_deref().unwrap_or(&m.spec),
                other => other,
            };
            if matches!(base, ModelSpec::Stationary(_) | ModelSpec::Guppy(_)) {
                return bad(format!(
                    "model `{}`: {} is not a candidate model (it serves the approach assay or the virtual lab)",
                    m.name,
                    m.spec.label()
                ));
            }
        }
        if fishprobe_learn::PpoConfig::preset(&self.ppo_preset).is_none() {
            return bad(format!(
                "ppo_preset `{}`: use paper, published, quick or smoke",
                self.ppo_preset
            ));
        }
        for m in &self.models {
            let Some(ppo) = self.ppo(&m.spec) else {
                continue;
            };
            if let Err(e) = ppo.validate() {
                return bad(format!("the PPO settings of model `{}`: {e}", m.name));
            }
            if let Err(e) = fishprobe_learn::shaping_matches(&ppo, &env) {
                return bad(format!("[task] for model `{}`: {e}", m.name));
            }
        }
        for (f, v) in [
            ("ppo_epochs", self.ppo_epochs.unwrap_or(1)),
            ("sim_trials", self.sim_trials),
            ("cross_episodes", self.cross_episodes),
            ("approach_episodes", self.approach_episodes),
            ("stability_episodes", self.stability_episodes),
            ("virtual_trials", self.virtual_trials),
        ] {
            if v == 0 {
                return bad(format!("{f} must be at least 1"));
            }
            if v > MAX_COUNT {
                return bad(format!("{f} = {v}: at most {MAX_COUNT}"));
            }
        }
        if self.extra_seeds > 100 {
            return bad(format!("extra_seeds = {}: at most 100", self.extra_seeds));
        }
        for (f, v) in [
            ("episode_minutes", f64::from(self.episode_minutes)),
            ("approach_minutes", f64::from(self.approach_minutes)),
            ("virtual_minutes", self.virtual_minutes),
        ] {
            if !fishprobe_learn::evaluate::minutes_in_range(v) {
                return bad(format!(
                    "{f} must lie in {}, got {}",
                    fishprobe_learn::evaluate::MINUTES_RANGE,
                    fishprobe_sim::params::check::shown(v)
                ));
            }
        }
        Ok(())
    }
}

/// A study file: a preset plus overrides, and extra models.
#[derive(Debug, Clone, Default, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct StudyFile {
    /// Preset to start from (default: the command line's).
    pub preset: Option<String>,
    /// Master seed.
    pub seed: Option<u64>,
    /// Replace the models (default: the paper's four).
    pub models: Option<Vec<NamedModel>>,
    /// Models added to the defaults (e.g. a "Zone-radii" variant).
    #[serde(default)]
    pub extra_models: Vec<NamedModel>,
    /// Overrides of the budgets.
    pub train_steps: Option<u64>,
    /// See [`StudyConfig::ppo_epochs`].
    pub ppo_epochs: Option<usize>,
    /// See [`StudyConfig::ppo_gamma`].
    pub ppo_gamma: Option<f32>,
    /// See [`StudyConfig::expensive_fish_budget`].
    pub expensive_fish_budget: Option<Budget>,
    /// See [`StudyConfig::extra_seeds`].
    pub extra_seeds: Option<usize>,
    /// See [`StudyConfig::episode_minutes`].
    pub episode_minutes: Option<f32>,
    /// See [`StudyConfig::sim_trials`].
    pub sim_trials: Option<usize>,
    /// See [`StudyConfig::cross_episodes`].
    pub cross_episodes: Option<usize>,
    /// See [`StudyConfig::virtual_trials`].
    pub virtual_trials: Option<usize>,
    /// Policies trained elsewhere ([`ExternalPolicy`]).
    #[serde(default)]
    pub policies: Vec<ExternalPolicy>,
    /// See [`StudyConfig::fish_count`] (groups).
    pub fish_count: Option<u32>,
    /// See [`StudyConfig::group_goal`].
    pub group_goal: Option<fishprobe_sim::GroupGoal>,
    /// See [`StudyConfig::centroid_bins`].
    pub centroid_bins: Option<bool>,
    /// See [`StudyConfig::analysis`]: `[analysis]` with any of the analysis settings.
    #[serde(default)]
    pub analysis: serde_json::Map<String, serde_json::Value>,
    /// See [`StudyConfig::task`]: `[task]` with task settings of the trainings and trials.
    #[serde(default)]
    pub task: serde_json::Map<String, serde_json::Value>,
}

impl StudyFile {
    /// Applies the file, read from the directory `dir`, on top of a preset: relative policy
    /// paths are taken relative to `dir`.
    pub fn apply_in(
        mut self,
        preset: &str,
        dir: &std::path::Path,
    ) -> Result<StudyConfig, StudyError> {
        for p in &mut self.policies {
            p.policy = fishprobe_learn::PolicyArg::parse(&p.policy)
                .relative_to(dir)
                .to_string();
        }
        // ONNX candidate models: the path relative to the study file, and the file's SHA-256
        // recorded (so every trial traces its fish to the exact file, and a file replaced
        // later is refused rather than mixed in).
        let models = self
            .models
            .iter_mut()
            .flatten()
            .chain(&mut self.extra_models);
        for m in models {
            if let ModelSpec::Onnx(p) = &mut m.spec {
                let path = std::path::Path::new(&p.path);
                if path.is_relative() {
                    p.path = dir.join(path).display().to_string();
                }
                if p.sha256.is_empty() {
                    p.sha256 = fishprobe_models::OnnxParams::for_file(&p.path).sha256;
                }
            }
            // A population named by its source (a shipped population or a population file,
            // relative to the study file): its content written into the study's settings, so
            // the steps that use it hash what they simulate.
            if let ModelSpec::Population(p) = &mut m.spec {
                if p.traits.is_empty() && !p.source.is_empty() {
                    let shipped = fishprobe_models::population::shipped(&p.source).is_some();
                    let path = std::path::Path::new(&p.source);
                    if !shipped && path.is_relative() {
                        p.source = dir.join(path).display().to_string();
                    }
                    let name = if p.name.is_empty() {
                        m.name.clone()
                    } else {
                        p.name.clone()
                    };
                    *p = p.resolved().map_err(|e| {
                        StudyError::Input(format!("candidate model {}: {e}", m.name))
                    })?;
                    p.name = name;
                }
            }
        }
        self.apply(preset)
    }

    /// Applies the file on top of a preset.
    pub fn apply(self, preset: &str) -> Result<StudyConfig, StudyError> {
        let name = self.preset.as_deref().unwrap_or(preset);
        let mut c = StudyConfig::preset(name).ok_or_else(|| {
            StudyError::Input(format!(
                "unknown preset `{name}`: use smoke, quick, paper or published"
            ))
        })?;
        if let Some(s) = self.seed {
            c.seed = s;
        }
        if let Some(m) = self.models {
            c.models = m;
        }
        c.models.extend(self.extra_models);
        if self.train_steps.is_some() {
            c.train_steps = self.train_steps;
        }
        if self.ppo_epochs.is_some() {
            c.ppo_epochs = self.ppo_epochs;
        }
        if self.ppo_gamma.is_some() {
            c.ppo_gamma = self.ppo_gamma;
        }
        if self.expensive_fish_budget.is_some() {
            c.expensive_fish_budget = self.expensive_fish_budget;
        }
        if let Some(v) = self.extra_seeds {
            c.extra_seeds = v;
        }
        if let Some(v) = self.episode_minutes {
            c.episode_minutes = v;
        }
        if let Some(v) = self.sim_trials {
            c.sim_trials = v;
        }
        if let Some(v) = self.cross_episodes {
            c.cross_episodes = v;
        }
        if let Some(v) = self.virtual_trials {
            c.virtual_trials = v;
        }
        if let Some(v) = self.fish_count {
            c.fish_count = v;
        }
        if let Some(v) = self.group_goal {
            c.group_goal = v;
        }
        if let Some(v) = self.centroid_bins {
            c.centroid_bins = v;
        }
        c.analysis.extend(self.analysis);
        c.task.extend(self.task);
        for p in self.policies {
            if c.policies.insert(p.model.clone(), p.policy).is_some() {
                return Err(StudyError::Input(format!(
                    "two policies for model `{}`",
                    p.model
                )));
            }
        }
        Ok(c)
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn presets_are_valid_and_a_study_file_adds_variants() {
        for p in ["smoke", "quick", "paper", "published"] {
            StudyConfig::preset(p).unwrap().validate().unwrap();
        }
        let f: StudyFile = toml_like(
            r#"{"preset": "smoke", "extra_models": [{"name": "Zone-radii", "spec": {"model": "Zone", "zone_convention": "radii"}}]}"#,
        );
        let c = f.apply("quick").unwrap();
        assert_eq!(c.preset, "smoke");
        assert_eq!(c.models.len(), 5);
        c.validate().unwrap();
        let bad: Result<StudyFile, _> = serde_json::from_str(
            r#"{"extra_models": [{"name": "X", "spec": {"model": "Couzin"}}]}"#,
        );
        assert!(bad.is_err());
        let mut c2 = c.clone();
        c2.models.push(c.models[0].clone());
        assert!(c2.validate().unwrap_err().to_string().contains("twice"));
        c2.models.pop();
        c2.models[0].name = "a__b".into();
        assert!(c2.validate().is_err());
    }

    #[test]
    fn expensive_fish_train_at_their_own_budget_in_the_paper_preset() {
        let paper = StudyConfig::preset("paper").unwrap();
        let spec = |n: &str| ModelSpec::by_name(n).unwrap();
        let zone = paper.ppo(&spec("Zone")).unwrap();
        assert_eq!((zone.total_timesteps, zone.num_sgd_iter), (13_316_800, 2));
        let convnet = paper.ppo(&spec("ConvNet")).unwrap();
        assert_eq!(
            (convnet.total_timesteps, convnet.num_sgd_iter),
            (832_300, 10)
        );
        // Everything else of the expensive fish's PPO is the preset's.
        assert_eq!(
            fishprobe_learn::PpoConfig {
                total_timesteps: zone.total_timesteps,
                num_sgd_iter: zone.num_sgd_iter,
                ..convnet
            },
            zone
        );
        // A file's budget reaches every model; its expensive-fish budget only those.
        let c = toml_like(r#"{"train_steps": 9000}"#)
            .apply("paper")
            .unwrap();
        assert_eq!(c.ppo(&spec("ConvNet")).unwrap().total_timesteps, 9000);
        let c = toml_like(
            r#"{"train_steps": 9000, "expensive_fish_budget": {"train_steps": 5000, "ppo_epochs": 4}}"#,
        )
        .apply("paper")
        .unwrap();
        let (z, cn) = (
            c.ppo(&spec("Zone")).unwrap(),
            c.ppo(&spec("ConvNet")).unwrap(),
        );
        assert_eq!(
            (z.total_timesteps, cn.total_timesteps, cn.num_sgd_iter),
            (9000, 5000, 4)
        );
        // The preset's discount, and a file's, reach every model, expensive fish too.
        let gammas = |c: &StudyConfig| {
            (
                c.ppo(&spec("Zone")).unwrap().gamma,
                c.ppo(&spec("ConvNet")).unwrap().gamma,
            )
        };
        assert_eq!(gammas(&paper), (0.99, 0.99));
        let c = toml_like(r#"{"ppo_gamma": 0.9453}"#)
            .apply("paper")
            .unwrap();
        assert_eq!(gammas(&c), (0.9453, 0.9453));
        let published = StudyConfig::preset("published").unwrap();
        assert_eq!(gammas(&published), (0.9453, 0.9453));
        // Other presets train every model alike; `expensive_fish_budget` is a file's choice.
        for p in ["published", "quick", "smoke"] {
            let c = StudyConfig::preset(p).unwrap();
            assert_eq!(c.ppo(&spec("ConvNet")), c.ppo(&spec("Follow")), "{p}");
        }
        // Budgets out of range are refused before any work, naming the field.
        for (json, field) in [
            (
                r#"{"expensive_fish_budget": {"train_steps": 5000, "ppo_epochs": 0}}"#,
                "model `ConvNet`: invalid configuration: `ppo.num_sgd_iter` = 0",
            ),
            (
                r#"{"expensive_fish_budget": {"train_steps": 0, "ppo_epochs": 2}}"#,
                "model `ConvNet`: invalid configuration: `ppo.total_timesteps` = 0",
            ),
            (
                r#"{"train_steps": 99000000000000}"#,
                "model `Follow`: invalid configuration: `ppo.total_timesteps`",
            ),
            (
                r#"{"ppo_gamma": 1.5}"#,
                "model `Follow`: invalid configuration: `ppo.gamma`",
            ),
        ] {
            let e = toml_like(json)
                .apply("paper")
                .unwrap()
                .validate()
                .unwrap_err()
                .to_string();
            assert!(e.contains(field), "{json}: {e}");
        }
        let bad: Result<StudyFile, _> =
            serde_json::from_str(r#"{"expensive_fish_budget": {"train_steps": 5000}}"#);
        assert!(bad.is_err());
    }

    #[test]
    fn progress_shaping_discounted_otherwise_than_the_ppo_is_refused_before_any_work() {
        let e = validate_quick(r#"{"task": {"progress_shaping": 1.0}}"#).unwrap_err();
        assert!(
            e.contains("[task] for model `Follow`")
                && e.contains("`env.task.progress_shaping_gamma` = 0.99: differs from the PPO discount gamma = 0.9453"),
            "{e}"
        );
        validate_quick(r#"{"task": {"progress_shaping": 1.0, "progress_shaping_gamma": 0.9453}}"#)
            .unwrap();
        // Off, the shaping's discount is inert.
        validate_quick(r#"{"task": {"progress_shaping_gamma": 0.5}}"#).unwrap();
    }

    #[test]
    fn an_analysis_table_replaces_named_settings_over_the_preset() {
        let c = toml_like(r#"{"analysis": {"approach_closest_cm": 4.0}}"#)
            .apply("quick")
            .unwrap();
        let a = c.analysis_config().unwrap();
        assert_eq!(a.approach_closest_cm, 4.0);
        // The quick preset's resampling and the study's trials stay.
        let quick = fishprobe_analysis::AnalysisConfig::quick();
        assert_eq!((a.permutations, a.sim_trials), (quick.permutations, 18));
        // The quick preset has no table of its own.
        assert_eq!(StudyConfig::preset("quick").unwrap().analysis.len(), 0);
        for (json, want) in [
            (
                r#"{"analysis": {"approach_closest": 4.0}}"#,
                "approach_closest",
            ),
            (r#"{"analysis": {"competence_threshold": 0.9}}"#, ""),
            (
                r#"{"analysis": {"competence_threshold": -0.5}}"#,
                "competence_threshold",
            ),
            (r#"{"analysis": {"ci_level": 1.0}}"#, "ci_level"),
            (
                r#"{"analysis": {"sim_trials": 4}}"#,
                "top of the study file",
            ),
        ] {
            let e = validate_quick(json);
            match (want, e) {
                ("", e) => assert!(e.is_ok(), "{json}: {e:?}"),
                (want, Err(e)) => assert!(e.contains(want) && e.contains("[analysis]"), "{e}"),
                (_, Ok(())) => panic!("{json} was accepted"),
            }
        }
    }

    #[test]
    fn a_task_table_replaces_named_task_settings_of_every_trial() {
        let c =
            toml_like(r#"{"task": {"training_start": "mixed", "training_episode_actions": 120}}"#)
                .apply("quick")
                .unwrap();
        let env = c.env().unwrap();
        assert_eq!(env.task.training_start, fishprobe_sim::TrainingStart::Mixed);
        assert_eq!(env.task.training_episode_actions, 120);
        // The rest is the default, and the study's own group settings still apply.
        let default = fishprobe_sim::TaskParams::default();
        assert_eq!(env.task.goal_radius_cm, default.goal_radius_cm);
        assert_eq!(
            StudyConfig::preset("quick").unwrap().env().unwrap().task,
            default
        );
        for (json, want) in [
            (r#"{"task": {"training_begin": "lab"}}"#, "training_begin"),
            (
                r#"{"task": {"training_start": "corner"}}"#,
                "training_start",
            ),
            (r#"{"task": {"goal_radius_cm": -1.0}}"#, "goal_radius_cm"),
            (r#"{"task": {"lab_start_share": null}}"#, "finite"),
            (
                r#"{"task": {"group_goal": "centroid"}}"#,
                "top of the study file",
            ),
            (r#"{"task": {"objective": "ood"}}"#, "--task ood"),
            (
                r#"{"task": {"evaluation_episode_actions": 60}}"#,
                "episode_minutes",
            ),
        ] {
            let e = validate_quick(json);
            match e {
                Err(e) => assert!(e.contains(want) && e.contains("task"), "{json}: {e}"),
                Ok(()) => panic!("{json} was accepted"),
            }
        }
    }

    fn toml_like(json: &str) -> StudyFile {
        serde_json::from_str(json).unwrap()
    }

    /// The study file `json` over the quick preset, checked.
    fn validate_quick(json: &str) -> Result<(), String> {
        toml_like(json)
            .apply("quick")
            .unwrap()
            .validate()
            .map_err(|e| e.to_string())
    }
}
