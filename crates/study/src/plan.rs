//! The plan: the steps of a study, what each does, needs, writes and depends on.

use crate::Study;
use fishprobe_io::{Arm, StudyLayout};
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
    /// Hash of its inputs (settings and the dependencies' hashes).
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

    /// The settings this step depends on, as JSON (hashed into its marker). A step that runs
    /// a policy trained elsewhere also depends on that file's identity (its path and SHA-256);
    /// for fishprobe's own policies the inputs are as they always were, so existing studies
    /// resume.
    pub fn inputs(&self, study: &Study) -> serde_json::Value {
        let mut v = self.own_inputs(study);
        let runs = match self {
            StepKind::Eval { p, .. } | StepKind::Approach { p, k: 0 } | StepKind::Reality { p } => {
                Some(*p)
            }
            StepKind::Stability { m, k: 0 } => Some(*m),
            _ => None,
        };
        // Groups: only a study with groups records them, so pair studies resume.
        let c = &study.cfg;
        if (c.fish_count, c.group_goal) != (1, fishprobe_sim::GroupGoal::Any) {
            v["groups"] =
                serde_json::json!({"fish_count": c.fish_count, "group_goal": c.group_goal});
        }
        // The `[task]` table, resolved: only a study whose task differs from the default
        // records it, so other studies resume (and writing out a default value changes
        // nothing).
        let default_task = fishprobe_sim::TaskParams {
            group_goal: c.group_goal,
            ..fishprobe_sim::TaskParams::default()
        };
        if study.env.task != default_task {
            v["task"] = serde_json::to_value(&study.env.task).unwrap_or_default();
        }
        if let Some(ext) = runs.and_then(|p| study.external_policy(p)) {
            v["external_policy"] = serde_json::json!({
                "policy": ext,
                "sha256": crate::external_policy_sha256(ext),
            });
        }
        v
    }

    fn own_inputs(&self, study: &Study) -> serde_json::Value {
        let c = &study.cfg;
        let model = |i: usize| serde_json::json!({"name": study.name(i), "spec": c.models[i].spec});
        match self {
            StepKind::FitConvnet => {
                serde_json::json!({"fit_convnet": study.convnet_data, "seed": c.seed,
                    "epochs": c.convnet_max_epochs})
            }
            // The resolved PPO settings, not the preset's name: a preset whose values change
            // (the `paper` preset's epochs went from 100 to 10) must not pass for the old one.
            // And the trainer's revision: a fixed trainer retrains what the broken one made.
            StepKind::Train { m, k } => {
                serde_json::json!({"train": model(*m), "k": k, "seed": c.seed,
                    "ppo": c.ppo(&c.models[*m].spec),
                    "trainer": fishprobe_learn::TRAINER_REVISION})
            }
            StepKind::Eval { p, m } => {
                serde_json::json!({"eval": [study.name(*p), model(*m)], "seed": c.seed,
                "episodes": study.eval_episodes(*p, *m), "minutes": c.episode_minutes})
            }
            // Same seed and episodes as the model's own evaluation, so that policy and
            // baselines face the same fish starts.
            StepKind::Baseline { m } => {
                serde_json::json!({"baseline": model(*m), "controllers": fishprobe_sim::SCRIPTED,
                "fetch": fishprobe_sim::FetchParams::default(), "seed": c.seed,
                "episodes": study.eval_episodes(*m, *m), "minutes": c.episode_minutes})
            }
            // Every seed meets the same episodes; seed 0's inputs are as they always were.
            StepKind::Approach { p, k } => {
                let mut v = serde_json::json!({"approach": study.name(*p), "seed": c.seed,
                "episodes": c.approach_episodes, "minutes": c.approach_minutes});
                if *k > 0 {
                    v["k"] = serde_json::json!(k);
                }
                v
            }
            StepKind::Stability { m, k } => {
                serde_json::json!({"stability": model(*m), "k": k, "seed": c.seed,
                "episodes": c.stability_episodes, "minutes": c.episode_minutes})
            }
            StepKind::Reality { p } => match &study.real {
                Some(r) => {
                    serde_json::json!({"real": r.join(StudyLayout::arm_dir_name(study.name(*p), &Arm::Real))})
                }
                None => serde_json::json!({"virtual": study.name(*p), "seed": c.seed,
                    "trials": c.virtual_trials, "minutes": c.virtual_minutes}),
            },
            // The `[analysis]` table only when a study file has one, so existing studies resume.
            StepKind::Analyze => {
                let mut v = serde_json::json!({"analyze": c.analysis_quick, "seed": c.seed,
                    "sim_trials": c.sim_trials});
                if !c.analysis.is_empty() {
                    v["analysis"] = serde_json::Value::Object(c.analysis.clone());
                }
                v
            }
            StepKind::Report => serde_json::json!({"report": 1}),
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

    /// The plan, in an order where every step comes after its dependencies.
    pub fn plan(&self) -> Vec<Step> {
        let n = self.cfg.models.len();
        let seeds = self.cfg.extra_seeds + 1;
        let mut steps: Vec<Step> = Vec::new();
        let add = |kind: StepKind, deps: Vec<usize>, steps: &mut Vec<Step>| -> usize {
            let mut bytes = serde_json::to_vec(&kind.inputs(self)).unwrap_or_default();
            for d in &deps {
                bytes.extend_from_slice(&steps[*d].hash.to_le_bytes());
            }
            let id = kind.id(self);
            steps.push(Step {
                id,
                kind,
                deps,
                hash: fnv(&bytes),
            });
            steps.len() - 1
        };
        let fit = self
            .convnet_data
            .is_some()
            .then(|| add(StepKind::FitConvnet, vec![], &mut steps));
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
                *slot = Some(add(StepKind::Train { m, k }, needs_fit(m), &mut steps));
            }
        }
        let mut for_analysis = Vec::new();
        for (p, row) in train.iter().enumerate() {
            let policy: Vec<usize> = row[0].into_iter().collect();
            for m in 0..n {
                let mut deps = policy.clone();
                deps.extend(needs_fit(m));
                for_analysis.push(add(StepKind::Eval { p, m }, deps, &mut steps));
            }
            for_analysis.push(add(StepKind::Baseline { m: p }, needs_fit(p), &mut steps));
            for_analysis.push(add(
                StepKind::Approach { p, k: 0 },
                policy.clone(),
                &mut steps,
            ));
            for_analysis.push(add(StepKind::Reality { p }, policy, &mut steps));
        }
        for (m, row) in train.iter().enumerate() {
            for (k, t) in row.iter().enumerate() {
                let deps: Vec<usize> = t.iter().copied().collect();
                if k > 0 {
                    let approach = StepKind::Approach { p: m, k };
                    for_analysis.push(add(approach, deps.clone(), &mut steps));
                }
                for_analysis.push(add(StepKind::Stability { m, k }, deps, &mut steps));
            }
        }
        let analyze = add(StepKind::Analyze, for_analysis, &mut steps);
        let mut report_deps = vec![analyze];
        report_deps.extend(train.iter().filter_map(|row| row[0]));
        add(StepKind::Report, report_deps, &mut steps);
        steps
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::StudyConfig;

    #[test]
    fn the_plan_orders_dependencies_and_a_changed_setting_changes_only_its_downstream() {
        let cfg = StudyConfig::preset("smoke").unwrap();
        let s = Study::new("/tmp/x".into(), cfg.clone(), None).unwrap();
        let plan = s.plan();
        // 4 models x 2 seeds trainings, 16 evals, 4 baselines, 4 x 2 approach, 4 reality, 8
        // stability, analyze, report.
        assert_eq!(plan.len(), 8 + 16 + 4 + 8 + 4 + 8 + 2);
        // Seed 0's assay keeps the id and inputs it always had (existing studies resume); a
        // stability seed's assay runs its own policy on the same episodes.
        let ids: Vec<&str> = plan.iter().map(|st| st.id.as_str()).collect();
        assert!(ids.contains(&"approach-Zone") && ids.contains(&"approach-Zone-1"));
        let zero = StepKind::Approach { p: 0, k: 0 }.inputs(&s);
        assert!(zero.get("k").is_none());
        assert_eq!(StepKind::Approach { p: 0, k: 1 }.inputs(&s)["k"], 1);
        assert_eq!(
            s.output(&StepKind::Approach { p: 1, k: 1 }),
            PathBuf::from(format!("/tmp/x/approach_stability/{}/seed1", s.name(1)))
        );
        for (i, st) in plan.iter().enumerate() {
            assert!(st.deps.iter().all(|&d| d < i), "{} before its deps", st.id);
        }
        let mut cfg2 = cfg;
        cfg2.stability_episodes += 1;
        let plan2 = Study::new("/tmp/x".into(), cfg2, None).unwrap().plan();
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
        let plan = |cfg: StudyConfig| Study::new("/tmp/x".into(), cfg, None).unwrap().plan();
        let paper = StudyConfig::preset("paper").unwrap();
        let base = plan(paper.clone());
        // Setting the epochs the preset already has, and the expensive fish's budget the preset
        // already gives them, changes nothing.
        let mut same = paper.clone();
        same.ppo_epochs = Some(2);
        same.expensive_fish_budget = Some(crate::config::Budget {
            train_steps: 832_300,
            ppo_epochs: 10,
        });
        for (a, b) in base.iter().zip(&plan(same)) {
            assert_eq!(a.hash, b.hash, "{}", a.id);
        }
        // The published epochs, by override or by preset, change the training and all that
        // follows it, and nothing else; the override keeps the `paper` preset's log-s.d. bound
        // and the preset does not, so the two trainings differ.
        // The discount: the preset's own changes nothing, another changes every training and
        // what follows it; the settings record it only when it is set.
        let mut own_gamma = paper.clone();
        own_gamma.ppo_gamma = Some(0.99);
        let mut published_gamma = paper.clone();
        published_gamma.ppo_gamma = Some(0.9453);
        for (a, (b, c)) in base
            .iter()
            .zip(plan(own_gamma).iter().zip(&plan(published_gamma)))
        {
            assert_eq!(a.hash, b.hash, "{}", a.id);
            let downstream = !a.id.starts_with("fit-convnet") && !a.id.starts_with("baseline-");
            assert_eq!(a.hash != c.hash, downstream, "{}", a.id);
        }
        assert!(!serde_json::to_string(&paper).unwrap().contains("ppo_gamma"));
        let mut hundred = paper.clone();
        hundred.ppo_epochs = Some(100);
        let published = StudyConfig::preset("published").unwrap();
        for (a, (b, c)) in base.iter().zip(plan(hundred).iter().zip(&plan(published))) {
            // Baselines run no policy: the PPO settings do not touch them.
            let downstream = !a.id.starts_with("fit-convnet") && !a.id.starts_with("baseline-");
            assert_eq!(a.hash != b.hash, downstream, "{}", a.id);
            assert_eq!(a.hash != c.hash, downstream, "{}", a.id);
            if a.id.starts_with("train-") {
                assert_ne!(b.hash, c.hash, "{}", a.id);
            }
        }
        // A marker written by fishprobe 0.1.0, when the `paper` preset meant 100 epochs and the
        // hash held only the preset's name, no longer passes for a `paper` training.
        let follow = base.iter().find(|s| s.id == "train-Follow-0").unwrap();
        assert_ne!(format!("{:016x}", follow.hash), "7b2a1ef96103b6b1");
        // The trainer's revision is hashed too: policies of a broken trainer are retrained.
        let s = Study::new("/tmp/x".into(), paper, None).unwrap();
        let train = StepKind::Train { m: 0, k: 0 }.inputs(&s);
        assert_eq!(train["trainer"], fishprobe_learn::TRAINER_REVISION);
        assert!(StepKind::Baseline { m: 0 }
            .inputs(&s)
            .get("trainer")
            .is_none());
    }

    #[test]
    fn a_task_table_changes_every_step_and_its_absence_none() {
        let plan = |cfg: StudyConfig| Study::new("/tmp/x".into(), cfg, None).unwrap().plan();
        let quick = StudyConfig::preset("quick").unwrap();
        let base = plan(quick.clone());
        // A task other than the default is hashed: every step is redone with it (trainings
        // and trials use the task; the rest follows them); studies without one resume.
        let mut mixed = quick;
        mixed
            .task
            .insert("training_start".into(), serde_json::json!("mixed"));
        let with = plan(mixed);
        assert_eq!(base.len(), with.len());
        for (a, b) in base.iter().zip(&with) {
            assert_ne!(a.hash, b.hash, "{}", a.id);
        }
        let s = Study::new("/tmp/x".into(), StudyConfig::preset("quick").unwrap(), None).unwrap();
        assert!(StepKind::Train { m: 0, k: 0 }
            .inputs(&s)
            .get("task")
            .is_none());
        // A default written out is no change.
        let mut explicit = StudyConfig::preset("quick").unwrap();
        explicit
            .task
            .insert("training_start".into(), serde_json::json!("random"));
        for (a, b) in base.iter().zip(&plan(explicit)) {
            assert_eq!(a.hash, b.hash, "{}", a.id);
        }
    }
}
