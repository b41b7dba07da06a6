//! The whole study in one command (`fishprobe run`): train one policy per model (and more
//! seeds for the stability analysis), evaluate every policy on every model, run the approach
//! assay and the stability episodes, collect the reality arm (live trials from a directory, or
//! the virtual lab through the live bridge), analyse and report — resumably and in parallel.
//!
//! The study directory has the layout of the paper's public archive, which `fishprobe analyze`
//! and `fishprobe report` read:
//!
//! ```text
//! STUDY/study.json                      the resolved configuration
//! STUDY/policies/<Model>/               training runs (params.json, progress.csv, checkpoints, policy)
//! STUDY/policies_stability/<Model>/seed<k>/   the extra seeds
//! STUDY/rollouts/<Policy>__<Model>/     evaluation episodes; <Policy>__Real or __VirtualLab
//! STUDY/approach_test/<Policy>/         approach-assay episodes
//! STUDY/stability/<Model>/seed<k>/      stability episodes
//! STUDY/analysis/, STUDY/report/        results and report
//! STUDY/logs/<step>.log                 one log per step
//! STUDY/.fishprobe/done/<step>.json     completion markers
//! ```
//!
//! **Resumable.** Every step writes its outputs into a temporary directory renamed into place,
//! then records a marker holding the hash of everything the step depends on (its settings and
//! the hashes of the steps it uses). A rerun skips steps whose marker matches and whose output
//! exists, redoes the others, and so never mixes results of different configurations: a changed
//! setting invalidates exactly the steps downstream of it. Training runs resume from their last
//! checkpoint and end byte-identical to an uninterrupted run (`fishprobe_learn::Trainer`).
//!
//! **Parallel.** Independent steps run concurrently, up to `jobs` at once, each on its own
//! thread pool.

pub mod config;
mod manifest;
pub mod slurm;
mod steps;

pub use config::{NamedModel, StudyConfig, StudyFile};

use fishprobe_io::{Arm, StudyLayout};
use std::path::{Path, PathBuf};
use std::sync::mpsc;
use std::time::Instant;

/// What went wrong.
#[derive(Debug, thiserror::Error)]
pub enum StudyError {
    /// The configuration or the inputs cannot work (reported before any expensive work).
    #[error("{0}")]
    Input(String),
    /// A step failed.
    #[error("step {step} failed: {what} (log: {log})")]
    Step {
        /// The step.
        step: String,
        /// Why.
        what: String,
        /// Its log.
        log: PathBuf,
    },
    /// File system.
    #[error("{path}: {what}")]
    Io {
        /// Where.
        path: PathBuf,
        /// What.
        what: String,
    },
}

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
    /// The approach assay of policy `p`.
    Approach {
        /// Policy index.
        p: usize,
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

/// Events for a progress display.
#[derive(Debug, Clone, PartialEq)]
pub enum Event {
    /// The plan: how many steps, how many already complete.
    Planned {
        /// Steps.
        total: usize,
        /// Complete and valid from an earlier run.
        complete: usize,
    },
    /// A step started.
    Started(String),
    /// A step finished after this many seconds.
    Finished(String, f64),
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

/// The study: its directory, configuration and reality arm.
#[derive(Debug, Clone)]
pub struct Study {
    /// The study directory.
    pub root: PathBuf,
    /// The configuration.
    pub cfg: StudyConfig,
    /// Live trials (`<Policy>__Real/` directories), if any.
    pub real: Option<PathBuf>,
    /// Pair recordings (`train/` and `validation/`) to refit M_ConvNet on, if any.
    pub convnet_data: Option<PathBuf>,
}

impl Study {
    /// Checks everything that can be checked before expensive work: the configuration, and the
    /// real-trials directory (it exists, and holds `<Policy>__Real/` for exactly the study's
    /// policies).
    pub fn new(root: PathBuf, cfg: StudyConfig, real: Option<PathBuf>) -> Result<Self, StudyError> {
        Self::with_convnet_data(root, cfg, real, None)
    }

    /// Like [`Study::new`], with M_ConvNet refitted on `convnet_data` (which must hold
    /// `train/` and `validation/` pair recordings) instead of the shipped weights.
    pub fn with_convnet_data(
        root: PathBuf,
        mut cfg: StudyConfig,
        real: Option<PathBuf>,
        convnet_data: Option<PathBuf>,
    ) -> Result<Self, StudyError> {
        cfg.validate().map_err(StudyError::Input)?;
        if let Some(d) = &convnet_data {
            for sub in ["train", "validation"] {
                if !d.join(sub).is_dir() {
                    return Err(StudyError::Input(format!(
                        "--convnet-data {}: needs {sub}/ with pair recordings",
                        d.display()
                    )));
                }
            }
            // Every ConvNet model without weights of its own uses the refitted ones.
            let weights = StudyLayout::new(&root)
                .convnet()
                .join("convnet.safetensors");
            for m in &mut cfg.models {
                if let fishprobe_models::ModelSpec::ConvNet(p) = &mut m.spec {
                    if p.weights.is_empty() {
                        p.weights = weights.display().to_string();
                    }
                }
            }
        }
        if let Some(r) = &real {
            if !r.is_dir() {
                return Err(StudyError::Input(format!(
                    "real-trials directory {} does not exist",
                    r.display()
                )));
            }
            let mut found: Vec<String> = std::fs::read_dir(r)
                .map_err(|e| StudyError::Input(format!("{}: {e}", r.display())))?
                .filter_map(|e| e.ok())
                .filter(|e| e.path().is_dir())
                .filter_map(
                    |e| match StudyLayout::parse_arm(&e.file_name().to_string_lossy()) {
                        Some((policy, Arm::Real)) => Some(policy),
                        _ => None,
                    },
                )
                .collect();
            found.sort();
            let mut want: Vec<String> = cfg.models.iter().map(|m| m.name.clone()).collect();
            want.sort();
            if found != want {
                return Err(StudyError::Input(format!(
                    "the real trials in {} are for policies [{}], the study trains [{}]: each policy needs a <Policy>__Real/ directory and nothing else",
                    r.display(),
                    found.join(", "),
                    want.join(", ")
                )));
            }
        }
        Ok(Self {
            root,
            cfg,
            real,
            convnet_data,
        })
    }

    fn name(&self, i: usize) -> &str {
        &self.cfg.models[i].name
    }

    /// The study directory's paths.
    pub fn layout(&self) -> StudyLayout {
        StudyLayout::new(&self.root)
    }

    /// The reality arm this study collects: live trials with `--real`, else the virtual lab.
    pub fn reality_arm(&self) -> Arm {
        if self.real.is_some() {
            Arm::Real
        } else {
            Arm::VirtualLab
        }
    }

    /// Where a step writes.
    pub fn output(&self, kind: &StepKind) -> PathBuf {
        let l = self.layout();
        let sim = |m: usize| Arm::Sim(self.name(m).to_string());
        match kind {
            StepKind::FitConvnet => l.convnet(),
            StepKind::Train { m, k } => l.policy(self.name(*m), *k),
            StepKind::Eval { p, m } => l.arm(self.name(*p), &sim(*m)),
            StepKind::Approach { p } => l.approach(self.name(*p)),
            StepKind::Stability { m, k } => l.stability(self.name(*m), *k),
            StepKind::Reality { p } => l.arm(self.name(*p), &self.reality_arm()),
            StepKind::Analyze => l.analysis(),
            StepKind::Report => l.report(),
        }
    }

    /// The settings a step depends on, as JSON (hashed into its marker).
    fn inputs(&self, kind: &StepKind) -> serde_json::Value {
        let c = &self.cfg;
        let model = |i: usize| serde_json::json!({"name": self.name(i), "spec": c.models[i].spec});
        match kind {
            StepKind::FitConvnet => {
                serde_json::json!({"fit_convnet": self.convnet_data, "seed": c.seed,
                    "epochs": c.convnet_max_epochs})
            }
            // The resolved PPO settings, not the preset's name: a preset whose values change
            // (the `paper` preset's epochs went from 100 to 10) must not pass for the old one.
            StepKind::Train { m, k } => {
                serde_json::json!({"train": model(*m), "k": k, "seed": c.seed, "ppo": c.ppo()})
            }
            StepKind::Eval { p, m } => {
                serde_json::json!({"eval": [self.name(*p), model(*m)], "seed": c.seed,
                "episodes": self.eval_episodes(*p, *m), "minutes": c.episode_minutes})
            }
            StepKind::Approach { p } => {
                serde_json::json!({"approach": self.name(*p), "seed": c.seed,
                "episodes": c.approach_episodes, "minutes": c.approach_minutes})
            }
            StepKind::Stability { m, k } => {
                serde_json::json!({"stability": model(*m), "k": k, "seed": c.seed,
                "episodes": c.stability_episodes, "minutes": c.episode_minutes})
            }
            StepKind::Reality { p } => match &self.real {
                Some(r) => {
                    serde_json::json!({"real": r.join(StudyLayout::arm_dir_name(self.name(*p), &Arm::Real))})
                }
                None => serde_json::json!({"virtual": self.name(*p), "seed": c.seed,
                    "trials": c.virtual_trials, "minutes": c.virtual_minutes}),
            },
            StepKind::Analyze => {
                serde_json::json!({"analyze": c.analysis_quick, "seed": c.seed, "sim_trials": c.sim_trials})
            }
            StepKind::Report => serde_json::json!({"report": 1}),
        }
    }

    /// Episodes of a sim cell: the own-model cell also serves sim-to-real.
    pub fn eval_episodes(&self, p: usize, m: usize) -> usize {
        if p == m {
            self.cfg.cross_episodes.max(self.cfg.sim_trials)
        } else {
            self.cfg.cross_episodes
        }
    }

    /// The plan, in an order where every step comes after its dependencies.
    pub fn plan(&self) -> Vec<Step> {
        let n = self.cfg.models.len();
        let seeds = self.cfg.extra_seeds + 1;
        let mut steps: Vec<Step> = Vec::new();
        let add = |kind: StepKind, deps: Vec<usize>, steps: &mut Vec<Step>| -> usize {
            let mut bytes = serde_json::to_vec(&self.inputs(&kind)).unwrap_or_default();
            for d in &deps {
                bytes.extend_from_slice(&steps[*d].hash.to_le_bytes());
            }
            let id = match &kind {
                StepKind::FitConvnet => "fit-convnet".into(),
                StepKind::Train { m, k } => format!("train-{}-{k}", self.name(*m)),
                StepKind::Eval { p, m } => format!("eval-{}__{}", self.name(*p), self.name(*m)),
                StepKind::Approach { p } => format!("approach-{}", self.name(*p)),
                StepKind::Stability { m, k } => format!("stability-{}-{k}", self.name(*m)),
                StepKind::Reality { p } => format!("reality-{}", self.name(*p)),
                StepKind::Analyze => "analyze".into(),
                StepKind::Report => "report".into(),
            };
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
        let mut train = vec![vec![0usize; seeds]; n];
        for (m, row) in train.iter_mut().enumerate() {
            for (k, slot) in row.iter_mut().enumerate() {
                *slot = add(StepKind::Train { m, k }, needs_fit(m), &mut steps);
            }
        }
        let mut for_analysis = Vec::new();
        for (p, row) in train.iter().enumerate() {
            let policy = row[0];
            for m in 0..n {
                let mut deps = vec![policy];
                deps.extend(needs_fit(m));
                for_analysis.push(add(StepKind::Eval { p, m }, deps, &mut steps));
            }
            for_analysis.push(add(StepKind::Approach { p }, vec![policy], &mut steps));
            for_analysis.push(add(StepKind::Reality { p }, vec![policy], &mut steps));
        }
        for (m, row) in train.iter().enumerate() {
            for (k, &t) in row.iter().enumerate() {
                for_analysis.push(add(StepKind::Stability { m, k }, vec![t], &mut steps));
            }
        }
        let analyze = add(StepKind::Analyze, for_analysis, &mut steps);
        let mut report_deps = vec![analyze];
        report_deps.extend(train.iter().map(|row| row[0]));
        add(StepKind::Report, report_deps, &mut steps);
        steps
    }

    fn marker(&self, s: &Step) -> PathBuf {
        self.layout().markers().join(format!("{}.json", s.id))
    }

    /// Whether a step is complete and valid: its marker's hash matches the step's inputs, its
    /// output is there, and the output holds exactly the files (names and sizes) the marker
    /// recorded when the step finished.
    pub fn is_complete(&self, s: &Step) -> bool {
        let Some(marker) = std::fs::read_to_string(self.marker(s))
            .ok()
            .and_then(|t| serde_json::from_str::<serde_json::Value>(&t).ok())
        else {
            return false;
        };
        let hash_ok = marker["hash"].as_str() == Some(format!("{:016x}", s.hash).as_str());
        hash_ok
            && steps::output_valid(self, s)
            && manifest::matches(&marker, &manifest::manifest(&self.output(&s.kind)))
    }

    fn mark(&self, s: &Step, secs: f64) -> Result<(), StudyError> {
        let p = self.marker(s);
        let outputs = manifest::manifest(&self.output(&s.kind));
        let text =
            serde_json::json!({"step": s.id, "hash": format!("{:016x}", s.hash), "seconds": secs,
            "inputs": self.inputs(&s.kind), "outputs": outputs})
            .to_string();
        if let Some(d) = p.parent() {
            std::fs::create_dir_all(d).map_err(|e| StudyError::Io {
                path: d.to_path_buf(),
                what: e.to_string(),
            })?;
        }
        fishprobe_io::write_atomically(&p, text.as_bytes()).map_err(|e| StudyError::Io {
            path: p,
            what: e.to_string(),
        })
    }

    /// Writes `study.json`, the log directory, and moves stale outputs aside: what every run
    /// does before its first step.
    pub fn prepare(&self) -> Result<Vec<Step>, StudyError> {
        let steps = self.plan();
        let l = self.layout();
        std::fs::create_dir_all(l.logs()).map_err(|e| StudyError::Io {
            path: l.logs(),
            what: e.to_string(),
        })?;
        let cfg_text = serde_json::to_string_pretty(&self.cfg).unwrap_or_default();
        fishprobe_io::write_atomically(&l.config(), cfg_text.as_bytes()).map_err(|e| {
            StudyError::Io {
                path: l.config(),
                what: e.to_string(),
            }
        })?;
        self.sweep_stale(&steps)?;
        Ok(steps)
    }

    /// Runs the one step `id` (its dependencies must be complete): what a SLURM array task
    /// does. A complete step is left alone.
    pub fn run_one(&self, id: &str) -> Result<(), StudyError> {
        let steps = self.plan();
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
        steps::run_step(self, s).map_err(|what| StudyError::Step {
            step: s.id.clone(),
            what,
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
        });
        let jobs = jobs.max(1);
        let threads = (std::thread::available_parallelism().map_or(1, |n| n.get()) / jobs).max(1);
        let mut running = vec![false; steps.len()];
        let (tx, rx) = mpsc::channel::<(usize, Result<f64, String>)>();
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
                            .map_err(|e| e.to_string())
                            .and_then(|pool| pool.install(|| steps::run_step(self, step)))
                            .map(|()| start.elapsed().as_secs_f64());
                        let _ = tx.send((i, r));
                    });
                }
            }
            if !running.iter().any(|r| *r) {
                break;
            }
            let Ok((i, r)) = rx.recv() else { break };
            running[i] = false;
            match r.and_then(|secs| {
                self.mark(&steps[i], secs)
                    .map(|()| secs)
                    .map_err(|e| e.to_string())
            }) {
                Ok(secs) => {
                    done[i] = true;
                    on_event(Event::Finished(steps[i].id.clone(), secs));
                }
                Err(what) => {
                    failure.get_or_insert(StudyError::Step {
                        step: steps[i].id.clone(),
                        what,
                        log: self.log_path(&steps[i]),
                    });
                }
            }
        });
        match failure {
            Some(e) => Err(e),
            None => Ok(()),
        }
    }

    /// Moves outputs that no step of the current plan produces (another configuration's, or a
    /// killed step's `.partial` directory) out of the analysed tree, into `.fishprobe/stale/`,
    /// so that results of different configurations never mix.
    fn sweep_stale(&self, steps: &[Step]) -> Result<(), StudyError> {
        let wanted: std::collections::BTreeSet<PathBuf> =
            steps.iter().map(|s| self.output(&s.kind)).collect();
        let stale_root = self.layout().stale();
        let io = |path: &Path, e: std::io::Error| StudyError::Io {
            path: path.to_path_buf(),
            what: e.to_string(),
        };
        let mut candidates = Vec::new();
        for top in fishprobe_io::layout::STEP_OUTPUT_DIRS {
            let d = self.root.join(top);
            let Ok(rd) = std::fs::read_dir(&d) else {
                continue;
            };
            for e in rd.filter_map(|e| e.ok()) {
                let p = e.path();
                if !p.is_dir() {
                    continue;
                }
                if fishprobe_io::layout::SEEDED_DIRS.contains(&top) {
                    // Two levels: <Model>/seed<k>.
                    let Ok(inner) = std::fs::read_dir(&p) else {
                        continue;
                    };
                    let kids: Vec<PathBuf> = inner
                        .filter_map(|e| e.ok())
                        .map(|e| e.path())
                        .filter(|q| q.is_dir())
                        .collect();
                    candidates.extend(kids);
                } else {
                    candidates.push(p);
                }
            }
        }
        let l = self.layout();
        for p in [l.analysis(), l.report()] {
            candidates.push(steps::tmp_of(&p));
        }
        for p in candidates
            .into_iter()
            .filter(|p| p.exists() && !wanted.contains(p))
        {
            let rel = p
                .strip_prefix(&self.root)
                .unwrap_or(&p)
                .display()
                .to_string()
                .replace(['/', '\\'], "--");
            std::fs::create_dir_all(&stale_root).map_err(|e| io(&stale_root, e))?;
            let mut to = stale_root.join(&rel);
            let mut n = 1;
            while to.exists() {
                to = stale_root.join(format!("{rel}.{n}"));
                n += 1;
            }
            std::fs::rename(&p, &to).map_err(|e| io(&p, e))?;
        }
        Ok(())
    }

    /// A step's log file.
    pub fn log_path(&self, s: &Step) -> PathBuf {
        self.layout().logs().join(format!("{}.log", s.id))
    }
}

/// Moves a finished temporary directory into place (replacing an older output).
fn commit_dir(tmp: &Path, out: &Path) -> Result<(), String> {
    if out.exists() {
        std::fs::remove_dir_all(out).map_err(|e| format!("removing {}: {e}", out.display()))?;
    }
    if let Some(p) = out.parent() {
        std::fs::create_dir_all(p).map_err(|e| format!("{}: {e}", p.display()))?;
    }
    std::fs::rename(tmp, out)
        .map_err(|e| format!("moving {} to {}: {e}", tmp.display(), out.display()))
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn the_plan_orders_dependencies_and_a_changed_setting_changes_only_its_downstream() {
        let cfg = StudyConfig::preset("smoke").unwrap();
        let s = Study::new("/tmp/x".into(), cfg.clone(), None).unwrap();
        let plan = s.plan();
        // 4 models x 2 seeds trainings, 16 evals, 4 approach, 4 reality, 8 stability, analyze, report.
        assert_eq!(plan.len(), 8 + 16 + 4 + 4 + 8 + 2);
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
        // Setting the epochs the preset already has changes nothing.
        let mut same = paper.clone();
        same.ppo_epochs = Some(10);
        for (a, b) in base.iter().zip(&plan(same)) {
            assert_eq!(a.hash, b.hash, "{}", a.id);
        }
        // The published epochs, by override or by preset, change the training and all that
        // follows it, and nothing else; the override keeps the `paper` preset's log-s.d. bound
        // and the preset does not, so the two trainings differ.
        let mut hundred = paper.clone();
        hundred.ppo_epochs = Some(100);
        let published = StudyConfig::preset("published").unwrap();
        for (a, (b, c)) in base.iter().zip(plan(hundred).iter().zip(&plan(published))) {
            let downstream = !a.id.starts_with("fit-convnet");
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
    }

    #[test]
    fn real_trials_must_match_the_policies() {
        let d = std::env::temp_dir().join(format!("fishprobe-study-real-{}", std::process::id()));
        let _ = std::fs::remove_dir_all(&d);
        std::fs::create_dir_all(d.join("Zone__Real")).unwrap();
        let e = Study::new(
            "/tmp/x".into(),
            StudyConfig::preset("smoke").unwrap(),
            Some(d.clone()),
        )
        .unwrap_err();
        assert!(e.to_string().contains("Follow"), "{e}");
        let e = Study::new(
            "/tmp/x".into(),
            StudyConfig::preset("smoke").unwrap(),
            Some(d.join("nope")),
        )
        .unwrap_err();
        assert!(e.to_string().contains("does not exist"), "{e}");
        let _ = std::fs::remove_dir_all(&d);
    }
}
