//! The plan: the steps of a study, what each does, needs, writes and depends on.

use crate::steps::{StepInputs, MARKER_SCHEMA};
use crate::{Study, StudyError};
use fishprobe_io::Arm;
use std::path::PathBuf;

/// One unit of work.
#[derive(Debug, Clone, PartialEq)]
pub enum StepKind {
    /// M_ConvNet refitted on `--convnet-data`.
    FitConvnet,
    /// Training run `k` (0: the policy; more: stability seeds) of model `m`.
    Train {
        /// Model index.
        m: usize,
        /// Seed index.
        k: usize,
    },
    /// Policy `p` on model `m`.
    Eval {
        /// Policy (model) index.
        p: usize,
        /// Rollout model index.
        m: usize,
    },
    /// The scripted baselines on the evaluation episodes of model `m`'s own policy (probe
    /// competence).
    Baseline {
        /// Model index.
        m: usize,
    },
    /// The approach assay of model `p`'s training run `k` (0: the policy; more: stability
    /// seeds, so that a strategy one seed happens to find is told from the model's).
    Approach {
        /// Policy (model) index.
        p: usize,
        /// Seed index.
        k: usize,
    },
    /// Stability episodes of training run `k` of model `m`.
    Stability {
        /// Model index.
        m: usize,
        /// Seed index.
        k: usize,
    },
    /// The reality arm of policy `p`.
    Reality {
        /// Policy index.
        p: usize,
    },
    /// The analysis.
    Analyze,
    /// The report.
    Report,
}

/// A step of the plan.
#[derive(Debug, Clone)]
pub struct Step {
    /// Unique, file-name-safe id ("train-Zone-0").
    pub id: String,
    /// What it does.
    pub kind: StepKind,
    /// Steps it needs (indices).
    pub deps: Vec<usize>,
    /// What it reads ([`StepKind::inputs`]): the only settings its work is given.
    pub inputs: StepInputs,
    /// Hash of its inputs, the marker schema and the dependencies' hashes.
    pub hash: u64,
}

impl StepKind {
    /// Its unique, file-name-safe id ("train-Zone-0").
    pub fn id(&self, study: &Study) -> String {
        match self {
            StepKind::FitConvnet => "fit-convnet".into(),
            StepKind::Train { m, k } => format!("train-{}-{k}", study.name(*m)),
            StepKind::Eval { p, m } => format!("eval-{}__{}", study.name(*p), study.name(*m)),
            StepKind::Approach { p, k: 0 } => format!("approach-{}", study.name(*p)),
            StepKind::Approach { p, k } => format!("approach-{}-{k}", study.name(*p)),
            StepKind::Baseline { m } => format!("baseline-{}", study.name(*m)),
            StepKind::Stability { m, k } => format!("stability-{}-{k}", study.name(*m)),
            StepKind::Reality { p } => format!("reality-{}", study.name(*p)),
            StepKind::Analyze => "analyze".into(),
            StepKind::Report => "report".into(),
        }
    }

    /// Where this step writes.
    pub fn output(&self, study: &Study) -> PathBuf {
        let l = study.layout();
        let sim = |m: usize| Arm::Sim(study.name(m).to_string());
        match self {
            StepKind::FitConvnet => l.convnet(),
            StepKind::Train { m, k } => l.policy(study.name(*m), *k),
            StepKind::Eval { p, m } => l.arm(study.name(*p), &sim(*m)),
            StepKind::Approach { p, k } => l.approach_seed(study.name(*p), *k),
            StepKind::Baseline { m } => l.baselines(study.name(*m)),
            StepKind::Stability { m, k } => l.stability(study.name(*m), *k),
            StepKind::Reality { p } => l.arm(study.name(*p), &study.reality_arm()),
            StepKind::Analyze => l.analysis(),
            StepKind::Report => l.report(),
        }
    }
}

/// FNV-1a: a hash that is the same on every build, for completion markers.
fn fnv(bytes: &[u8]) -> u64 {
    let mut h: u64 = 0xcbf2_9ce4_8422_2325;
    for b in bytes {
        h ^= u64::from(*b);
        h = h.wrapping_mul(0x0100_0000_01b3);
    }
    h
}

impl Study {
    /// Where a step writes.
    pub fn output(&self, kind: &StepKind) -> PathBuf {
        kind.output(self)
    }

    /// The plan, in an order where every step comes after its dependencies. Each step's hash
    /// is that of everything it reads and of the steps it uses: this function only wires the
    /// dependencies.
    pub fn plan(&self) -> Result<Vec<Step>, StudyError> {
        let n = self.cfg.models.len();
        let seeds = self.cfg.extra_seeds + 1;
        let mut steps: Vec<Step> = Vec::new();
        let add = |kind: StepKind,
                   deps: Vec<usize>,
                   steps: &mut Vec<Step>|
         -> Result<usize, StudyError> {
            let inputs = kind.inputs(self)?;
            let mut bytes = MARKER_SCHEMA.to_le_bytes().to_vec();
            bytes.extend(serde_json::to_vec(&inputs).map_err(|e| {
                StudyError::Input(format!("the inputs of step {}: {e}", kind.id(self)))
            })?);
            for d in &deps {
                bytes.extend_from_slice(&steps[*d].hash.to_le_bytes());
            }
            let id = kind.id(self);
            steps.push(Step {
                id,
                kind,
                deps,
                inputs,
                hash: fnv(&bytes),
            });
            Ok(steps.len() - 1)
        };
        let fit = match self.convnet_data {
            Some(_) => Some(add(StepKind::FitConvnet, vec![], &mut steps)?),
            None => None,
        };
        // Steps that simulate a refitted ConvNet need its weights.
        let needs_fit = |m: usize| -> Vec<usize> {
            match (&self.cfg.models[m].spec, fit) {
                (fishprobe_models::ModelSpec::ConvNet(_), Some(f)) => vec![f],
                _ => vec![],
            }
        };
        // A policy trained elsewhere replaces its model's first training run (no step).
        let mut train: Vec<Vec<Option<usize>>> = vec![vec![None; seeds]; n];
        for (m, row) in train.iter_mut().enumerate() {
            for (k, slot) in row.iter_mut().enumerate() {
                if k == 0 && self.external_policy(m).is_some() {
                    continue;
                }
                *slot = Some(add(StepKind::Train { m, k }, needs_fit(m), &mut steps)?);
            }
        }
        let mut for_analysis = Vec::new();
        for (p, row) in train.iter().enumerate() {
            let policy: Vec<usize> = row[0].into_iter().collect();
            for m in 0..n {
                let mut deps = policy.clone();
                deps.extend(needs_fit(m));
                for_analysis.push(add(StepKind::Eval { p, m }, deps, &mut steps)?);
            }
            for_analysis.push(add(StepKind::Baseline { m: p }, needs_fit(p), &mut steps)?);
            for_analysis.push(add(
                StepKind::Approach { p, k: 0 },
                policy.clone(),
                &mut steps,
            )?);
            for_analysis.push(add(StepKind::Reality { p }, policy, &mut steps)?);
        }
        for (m, row) in train.iter().enumerate() {
            for (k, t) in row.iter().enumerate() {
                let deps: Vec<usize> = t.iter().copied().collect();
                if k > 0 {
                    let approach = StepKind::Approach { p: m, k };
                    for_analysis.push(add(approach, deps.clone(), &mut steps)?);
                }
                for_analysis.push(add(StepKind::Stability { m, k }, deps, &mut steps)?);
            }
        }
        let analyze = add(StepKind::Analyze, for_analysis, &mut steps)?;
        let mut report_deps = vec![analyze];
        report_deps.extend(train.iter().filter_map(|row| row[0]));
        add(StepKind::Report, report_deps, &mut steps)?;
        Ok(steps)
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::StudyConfig;
    use std::collections::{BTreeMap, BTreeSet};

    fn plan_of(cfg: StudyConfig) -> Vec<Step> {
        Study::new("/tmp/x".into(), cfg, None)
            .unwrap()
            .plan()
            .unwrap()
    }

    fn json(i: &StepInputs) -> serde_json::Value {
        serde_json::to_value(i).unwrap()
    }

    #[test]
    fn the_plan_orders_dependencies_and_a_changed_setting_changes_only_its_downstream() {
        let cfg = StudyConfig::preset("smoke").unwrap();
        let s = Study::new("/tmp/x".into(), cfg.clone(), None).unwrap();
        let plan = s.plan().unwrap();
        // 4 models x 2 seeds trainings, 16 evals, 4 baselines, 4 x 2 approach, 4 reality, 8
        // stability, analyze, report.
        assert_eq!(plan.len(), 8 + 16 + 4 + 8 + 4 + 8 + 2);
        // A stability seed's assay runs its own policy on the same episodes as seed 0's.
        let ids: Vec<&str> = plan.iter().map(|st| st.id.as_str()).collect();
        assert!(ids.contains(&"approach-Zone") && ids.contains(&"approach-Zone-1"));
        let zero = json(&StepKind::Approach { p: 0, k: 0 }.inputs(&s).unwrap());
        let one = json(&StepKind::Approach { p: 0, k: 1 }.inputs(&s).unwrap());
        assert_eq!(zero["evaluation"], one["evaluation"]);
        assert_eq!(one["policy"]["trained"]["k"], 1);
        assert_eq!(
            s.output(&StepKind::Approach { p: 1, k: 1 }),
            PathBuf::from(format!("/tmp/x/approach_stability/{}/seed1", s.name(1)))
        );
        for (i, st) in plan.iter().enumerate() {
            assert!(st.deps.iter().all(|&d| d < i), "{} before its deps", st.id);
        }
        let mut cfg2 = cfg;
        cfg2.stability_episodes += 1;
        let plan2 = plan_of(cfg2);
        let changed: Vec<&str> = plan
            .iter()
            .zip(&plan2)
            .filter(|(a, b)| a.hash != b.hash)
            .map(|(a, _)| a.id.as_str())
            .collect();
        assert!(
            changed
                .iter()
                .all(|id| id.starts_with("stability") || *id == "analyze" || *id == "report"),
            "{changed:?}"
        );
        assert!(changed.len() == 8 + 2, "{changed:?}");
        assert_eq!(fnv(b"fishprobe"), fnv(b"fishprobe"));
    }

    #[test]
    fn training_hashes_follow_the_resolved_ppo_settings_not_the_preset_name() {
        let paper = StudyConfig::preset("paper").unwrap();
        let base = plan_of(paper.clone());
        // Setting the epochs the preset already has, and the expensive fish's budget the preset
        // already gives them, changes nothing.
        let mut same = paper.clone();
        same.ppo_epochs = Some(2);
        same.expensive_fish_budget = Some(crate::config::Budget {
            train_steps: 832_300,
            ppo_epochs: 10,
        });
        for (a, b) in base.iter().zip(&plan_of(same)) {
            assert_eq!(a.hash, b.hash, "{}", a.id);
        }
        // The discount: the preset's own changes nothing, another changes every training and
        // what follows it; the settings record it only when it is set.
        let mut own_gamma = paper.clone();
        own_gamma.ppo_gamma = Some(0.99);
        let mut published_gamma = paper.clone();
        published_gamma.ppo_gamma = Some(0.9453);
        for (a, (b, c)) in base
            .iter()
            .zip(plan_of(own_gamma).iter().zip(&plan_of(published_gamma)))
        {
            assert_eq!(a.hash, b.hash, "{}", a.id);
            let downstream = !a.id.starts_with("fit-convnet") && !a.id.starts_with("baseline-");
            assert_eq!(a.hash != c.hash, downstream, "{}", a.id);
        }
        assert!(!serde_json::to_string(&paper).unwrap().contains("ppo_gamma"));
        // The published epochs, by override or by preset, change the training and all that
        // follows it, and nothing else; the override keeps the `paper` preset's log-s.d. bound
        // and the preset does not, so the two trainings differ.
        let mut hundred = paper.clone();
        hundred.ppo_epochs = Some(100);
        let published = StudyConfig::preset("published").unwrap();
        for (a, (b, c)) in base
            .iter()
            .zip(plan_of(hundred).iter().zip(&plan_of(published)))
        {
            // Baselines run no policy: the PPO settings do not touch them.
            let downstream = !a.id.starts_with("fit-convnet") && !a.id.starts_with("baseline-");
            assert_eq!(a.hash != b.hash, downstream, "{}", a.id);
            assert_eq!(a.hash != c.hash, downstream, "{}", a.id);
            if a.id.starts_with("train-") {
                assert_ne!(b.hash, c.hash, "{}", a.id);
            }
        }
        // The trainer's revision is read, so hashed: policies of a broken trainer are
        // retrained.
        let s = Study::new("/tmp/x".into(), paper, None).unwrap();
        let train = json(&StepKind::Train { m: 0, k: 0 }.inputs(&s).unwrap());
        assert_eq!(train["trainer"], fishprobe_learn::TRAINER_REVISION);
        let baseline = json(&StepKind::Baseline { m: 0 }.inputs(&s).unwrap());
        assert!(baseline.get("trainer").is_none());
    }

    #[test]
    fn a_task_table_changes_every_step_and_a_default_written_out_none() {
        let quick = StudyConfig::preset("quick").unwrap();
        let base = plan_of(quick.clone());
        // Trainings and trials use the task; the rest follows them.
        let mut mixed = quick;
        mixed
            .task
            .insert("training_start".into(), serde_json::json!("mixed"));
        let with = plan_of(mixed);
        assert_eq!(base.len(), with.len());
        for (a, b) in base.iter().zip(&with) {
            assert_ne!(a.hash, b.hash, "{}", a.id);
        }
        let mut explicit = StudyConfig::preset("quick").unwrap();
        explicit
            .task
            .insert("training_start".into(), serde_json::json!("random"));
        for (a, b) in base.iter().zip(&plan_of(explicit)) {
            assert_eq!(a.hash, b.hash, "{}", a.id);
        }
    }

    /// The steps a changed configuration runs (again): those whose hash changed and those
    /// new to the plan.
    fn reruns(before: &[Step], after: &[Step]) -> BTreeSet<String> {
        let old: BTreeMap<&str, u64> = before.iter().map(|s| (s.id.as_str(), s.hash)).collect();
        after
            .iter()
            .filter(|s| old.get(s.id.as_str()) != Some(&s.hash))
            .map(|s| s.id.clone())
            .collect()
    }

    /// The steps that read a changed setting themselves: those whose own inputs changed (not
    /// only a dependency's) and those new to the plan.
    fn readers(before: &[Step], after: &[Step]) -> BTreeSet<String> {
        let old: BTreeMap<&str, serde_json::Value> = before
            .iter()
            .map(|s| (s.id.as_str(), json(&s.inputs)))
            .collect();
        after
            .iter()
            .filter(|s| old.get(s.id.as_str()) != Some(&json(&s.inputs)))
            .map(|s| s.id.clone())
            .collect()
    }

    /// Every setting of a study (a smoke study with M_ConvNet refitted, so that every kind of
    /// step is planned), changed one at a time: each reruns the steps that read it, or is one
    /// of the presentation-only settings. A setting added to the study configuration without
    /// a line here fails the test.
    #[test]
    fn every_setting_reruns_the_steps_that_read_it() {
        use serde_json::json;
        let root = std::env::temp_dir().join(format!("fishprobe-flip-{}", std::process::id()));
        let data = root.join("data");
        for sub in ["train", "validation"] {
            std::fs::create_dir_all(data.join(sub)).unwrap();
        }
        let smoke = StudyConfig::preset("smoke").unwrap();
        let plan = |cfg: serde_json::Value| {
            let cfg: StudyConfig = serde_json::from_value(cfg).unwrap();
            Study::with_convnet_data(root.join("study"), cfg, None, Some(data.clone()))
                .unwrap()
                .plan()
                .unwrap()
        };
        let base_json = serde_json::to_value(&smoke).unwrap();
        let base = plan(base_json.clone());
        let models = base_json["models"].clone();
        let mut other_models = models.clone();
        other_models[0]["spec"] = models[1]["spec"].clone();
        // (setting, a changed value, steps that read it, by id prefix: their own inputs
        // change, and they and everything after them rerun)
        let cases: Vec<(&str, serde_json::Value, &[&str])> = vec![
            (
                "seed",
                json!(7),
                &[
                    "fit-convnet",
                    "train-",
                    "eval-",
                    "baseline-",
                    "approach-",
                    "stability-",
                    "reality-",
                    "analyze",
                ],
            ),
            (
                "models",
                other_models,
                &["train-Follow", "eval-Follow__Follow", "baseline-Follow"],
            ),
            ("ppo_preset", json!("quick"), &["train-"]),
            ("train_steps", json!(2048), &["train-"]),
            ("ppo_epochs", json!(3), &["train-"]),
            ("ppo_gamma", json!(0.9), &["train-"]),
            (
                "expensive_fish_budget",
                json!({"train_steps": 2048, "ppo_epochs": 3}),
                &["train-ConvNet"],
            ),
            (
                "extra_seeds",
                json!(2),
                &["train-Zone-2", "stability-Zone-2", "approach-Zone-2"],
            ),
            (
                "episode_minutes",
                json!(3.0),
                &["eval-", "baseline-", "stability-"],
            ),
            (
                "sim_trials",
                json!(5),
                &["eval-Zone__Zone", "baseline-Zone", "analyze"],
            ),
            (
                "cross_episodes",
                json!(5),
                &["eval-Zone__Follow", "eval-Zone__Zone"],
            ),
            ("approach_episodes", json!(3), &["approach-"]),
            ("approach_minutes", json!(1.5), &["approach-"]),
            ("stability_episodes", json!(4), &["stability-"]),
            ("virtual_trials", json!(4), &["reality-"]),
            ("virtual_minutes", json!(3.0), &["reality-"]),
            ("analysis_quick", json!(false), &["analyze"]),
            ("convnet_max_epochs", json!(2), &["fit-convnet"]),
            (
                "policies",
                json!({"Zone": "scripted:goal-seeker"}),
                &["eval-Zone__", "approach-Zone", "reality-Zone"],
            ),
            (
                "fish_count",
                json!(2),
                &["train-", "eval-", "baseline-", "stability-", "reality-"],
            ),
            (
                "group_goal",
                json!("centroid"),
                &["train-", "eval-", "stability-", "reality-"],
            ),
            (
                "centroid_bins",
                json!(true),
                &["train-", "eval-", "approach-", "stability-", "reality-"],
            ),
            (
                "analysis",
                json!({"competence_threshold": 0.5}),
                &["analyze"],
            ),
            (
                "task",
                json!({"training_start": "mixed"}),
                &["train-", "eval-", "reality-"],
            ),
        ];
        let presentation: Vec<&str> = crate::config::PRESENTATION_ONLY
            .iter()
            .map(|(k, _)| *k)
            .collect();
        let mut covered: BTreeSet<&str> = cases.iter().map(|c| c.0).collect();
        covered.extend(&presentation);
        // Every field the configuration can hold (optional ones written out when set).
        let mut all = base_json.as_object().unwrap().clone();
        all.insert("ppo_gamma".into(), json!(0.9));
        for key in all.keys() {
            assert!(covered.contains(key.as_str()), "no flip case for `{key}`");
        }
        for (key, value, expected) in &cases {
            let mut cfg = base_json.clone();
            cfg[*key] = value.clone();
            let after = plan(cfg);
            let read = readers(&base, &after);
            for prefix in *expected {
                assert!(
                    read.iter().any(|id| id.starts_with(prefix)),
                    "`{key}` changed, but no `{prefix}` step reads it: {read:?}"
                );
            }
            // Whatever reads it reruns, and what follows (the report follows everything).
            let changed = reruns(&base, &after);
            assert!(read.is_subset(&changed), "{key}");
            assert!(changed.contains("report"), "{key}: {changed:?}");
        }
        for key in presentation {
            let mut cfg = base_json.clone();
            cfg[key] = json!("renamed");
            assert!(reruns(&base, &plan(cfg)).is_empty(), "{key}");
        }
        let _ = std::fs::remove_dir_all(&root);
    }
}
