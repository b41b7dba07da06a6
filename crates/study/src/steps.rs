//! What each step does.

use crate::error::StepError;
use crate::store::{commit_dir, fresh, staged, tmp_of};
use crate::{Step, StepKind, Study};
use fishprobe_io::{Arm, StudyLayout};
use fishprobe_learn::{Evaluation, PolicyController, RunSpec, Trainer};
use fishprobe_live::lab::{run_trial, LabConfig};
use fishprobe_live::server::{serve, BridgeGuard, ServeOptions};
use fishprobe_live::session::LiveConfig;
use fishprobe_sim::{derive_seed, Controller};
use std::io::Write;
use std::path::{Path, PathBuf};

/// Prefix of a step's log lines that the user must see (they are passed on as
/// [`crate::Event::Warning`]).
const WARNING: &str = "warning: ";

/// A step's log: each line goes to its log file; warnings are also kept in `warnings`.
fn log<'a>(
    study: &Study,
    s: &Step,
    warnings: &'a std::cell::RefCell<Vec<String>>,
) -> impl FnMut(&str) + 'a {
    let path = study.log_path(s);
    let mut f = std::fs::OpenOptions::new()
        .create(true)
        .append(true)
        .open(path)
        .ok();
    move |line: &str| {
        if let Some(f) = f.as_mut() {
            let _ = writeln!(f, "{line}");
        }
        if let Some(w) = line.strip_prefix(WARNING) {
            warnings.borrow_mut().push(w.to_string());
        }
    }
}

/// The evaluation episodes of policy `p` on model `m`, written to `out` (the scripted baselines
/// of model `m` run on those of `m`'s own policy: the same starts and fish).
fn eval_episodes(study: &Study, p: usize, m: usize, out: PathBuf) -> Evaluation {
    let c = &study.cfg;
    Evaluation {
        model: c.models[m].spec.clone(),
        env: study.env.clone(),
        episodes: study.eval_episodes(p, m),
        minutes: c.episode_minutes,
        seed: derive_seed(
            c.seed,
            &format!("eval/{}/{}", c.models[p].name, c.models[m].name),
            0,
        ),
        start: None,
        out,
        prefix: "trial".into(),
    }
}

fn train_dir(study: &Study, m: usize, k: usize) -> PathBuf {
    study.output(&StepKind::Train { m, k })
}

/// The policy of model `m`'s training run `k`: fishprobe's own, or for `k` = 0 the one the
/// study file names, under the study's name for the model.
fn policy_of(study: &Study, m: usize, k: usize) -> Result<Box<dyn Controller>, StepError> {
    match study.external_policy(m).filter(|_| k == 0) {
        Some(arg) => Ok(fishprobe_learn::named(
            fishprobe_learn::controller(arg, false)?,
            study.cfg.models[m].name.clone(),
        )),
        None => Ok(Box::new(PolicyController::load(
            &train_dir(study, m, k),
            false,
        )?)),
    }
}

/// Runs one step; its warnings on success.
pub(crate) fn run_step(study: &Study, s: &Step) -> Result<Vec<String>, StepError> {
    let warnings = std::cell::RefCell::new(Vec::new());
    let mut say = log(study, s, &warnings);
    say(&format!("step {} (inputs hash {:016x})", s.id, s.hash));
    let c = &study.cfg;
    let seed = |label: &str| derive_seed(c.seed, label, 0);
    let out = study.output(&s.kind);
    let r = match &s.kind {
        StepKind::FitConvnet => fit_convnet_step(study, &out, &mut say),
        StepKind::Train { m, k } => train_step(study, *m, *k, &out, &mut say),
        StepKind::Eval { p, m } => staged(&out, |tmp| {
            let e = eval_episodes(study, *p, *m, tmp.to_path_buf());
            fishprobe_learn::evaluate(policy_of(study, *p, 0)?.as_ref(), &e)?;
            Ok(())
        }),
        StepKind::Baseline { m } => staged(&out, |tmp| {
            for name in fishprobe_sim::SCRIPTED {
                let b = fishprobe_sim::scripted(name)
                    .ok_or_else(|| StepError::Missing(format!("scripted controller `{name}`")))?;
                let e = eval_episodes(study, *m, *m, tmp.join(b.name()));
                let r = fishprobe_learn::evaluate(b.as_ref(), &e)?;
                let (mean, _) = fishprobe_learn::goals_mean_sd(&r);
                say(&format!(
                    "{} on {}: {mean:.1} goals per episode",
                    b.name(),
                    c.models[*m].name
                ));
            }
            Ok(())
        }),
        // SPEC §8: the robot in a corner, a motionless fish and the goal on either side.
        StepKind::Approach { p, k } => staged(&out, |tmp| {
            let mut e = fishprobe_learn::approach_assay(
                c.approach_episodes,
                c.approach_minutes,
                seed(&format!("approach/{}", c.models[*p].name)),
                tmp.to_path_buf(),
            )?;
            // One still fish, observed as the study's policies observe.
            e.env.observation.centroid_bins = c.centroid_bins;
            fishprobe_learn::evaluate(policy_of(study, *p, *k)?.as_ref(), &e)?;
            Ok(())
        }),
        StepKind::Stability { m, k } => staged(&out, |tmp| {
            let e = Evaluation {
                model: c.models[*m].spec.clone(),
                env: study.env.clone(),
                episodes: c.stability_episodes,
                minutes: c.episode_minutes,
                seed: seed(&format!("stability/{}/{k}", c.models[*m].name)),
                start: None,
                out: tmp.to_path_buf(),
                prefix: "episode".into(),
            };
            fishprobe_learn::evaluate(policy_of(study, *m, *k)?.as_ref(), &e)?;
            Ok(())
        }),
        StepKind::Reality { p } => reality(study, *p, &out, &mut say),
        StepKind::Analyze => staged(&out, |tmp| {
            let cfg = c
                .analysis_config()
                .map_err(|e| StepError::Settings(e.to_string()))?;
            let r = fishprobe_analysis::analyze_dir(&study.root, &cfg, c.seed)?;
            fishprobe_analysis::write_results(tmp, &r)?;
            Ok(())
        }),
        StepKind::Report => staged(&out, |tmp| {
            fishprobe_report::build_report(
                &study.root,
                Some(tmp),
                Some(&study.output(&StepKind::Analyze)),
                &fishprobe_report::ReportConfig::default(),
            )?;
            Ok(())
        }),
    };
    say(match &r {
        Ok(()) => "done".to_string(),
        Err(e) => format!("failed: {e}"),
    }
    .as_str());
    drop(say);
    r.map(|()| warnings.into_inner())
}

/// Refits M_ConvNet on the study's `--convnet-data` into `out`.
fn fit_convnet_step(
    study: &Study,
    out: &Path,
    say: &mut impl FnMut(&str),
) -> Result<(), StepError> {
    let c = &study.cfg;
    let data = study.convnet_data.as_ref().ok_or_else(|| {
        StepError::Missing("no ConvNet fitting data (the study's convnet_data)".into())
    })?;
    let command = format!(
        "fishprobe fit-convnet --data {} --validation {} --seed {}",
        data.join("train").display(),
        data.join("validation").display(),
        c.seed
    );
    staged(out, |tmp| {
        let r = fishprobe_learn::bc::fit_convnet(
            &fishprobe_learn::bc::FitRequest {
                data: &[data.join("train")],
                validation: &[data.join("validation")],
                out: &tmp.join("convnet.safetensors"),
                cfg: &fishprobe_learn::bc::CloneConfig {
                    max_epochs: c.convnet_max_epochs,
                    ..fishprobe_learn::bc::CloneConfig::default()
                },
                seed: c.seed,
                baselines: false,
                resume: false,
                command: &command,
                build: &study.program_build,
            },
            &|_| {},
        )?;
        say(&format!(
            "refitted M_ConvNet: validation NLL {:.4} (marginal {:.4})",
            r.val_nll, r.marginal_nll
        ));
        Ok(())
    })
}

/// Trains policy `k` of model `m` into `out`: resumes a run of the same spec, starts a run of
/// another spec (or another trainer revision's) over.
fn train_step(
    study: &Study,
    m: usize,
    k: usize,
    out: &Path,
    say: &mut impl FnMut(&str),
) -> Result<(), StepError> {
    let c = &study.cfg;
    let ppo = c
        .ppo(&c.models[m].spec)
        .ok_or_else(|| StepError::Missing(format!("unknown PPO preset `{}`", c.ppo_preset)))?;
    let spec = RunSpec::new(
        c.models[m].spec.clone(),
        ppo,
        study.env.clone(),
        derive_seed(c.seed, &format!("train/{}", c.models[m].name), k as u64),
        c.ppo_preset.clone(),
        study.program_build.clone(),
    );
    // Resume a run of the same spec; a run of another spec, or one another trainer
    // revision started, is stale and starts over.
    use fishprobe_learn::run::{open, OnOther, Opening};
    let mut t = match open(out, &spec, OnOther::Restart)? {
        Opening::Resume => {
            say("resuming from the last checkpoint");
            Trainer::resume(out, &spec.program_build)?
        }
        Opening::Start | Opening::Restarted { .. } => {
            // A folder without a run's record holds nothing to keep.
            if out.exists() {
                std::fs::remove_dir_all(out).map_err(|e| StepError::io("removing", out, e))?;
            }
            Trainer::create(out, spec)?
        }
    };
    while !t.done() {
        let i = t.iterate()?;
        say(&format!(
            "iteration {} steps {} return {:.3} goals/episode {:.3}",
            i.iteration, i.timesteps, i.episode_return_mean, i.goals_per_episode
        ));
    }
    t.finish()?;
    Ok(())
}

fn reality(
    study: &Study,
    p: usize,
    out: &Path,
    say: &mut impl FnMut(&str),
) -> Result<(), StepError> {
    let c = &study.cfg;
    let name = c.models[p].name.clone();
    let tmp = tmp_of(out);
    fresh(&tmp)?;
    if let Some(real) = &study.real {
        let src = real.join(StudyLayout::arm_dir_name(&name, &Arm::Real));
        // The live trials must be of the policy this study trained (not of one trained
        // under the same name before a retraining).
        if let Some(sha) = policy_of(study, p, 0)?.fingerprint() {
            let prov = fishprobe_io::Provenance::of_dir(&src, &sha);
            if let Some(why) = prov.describe_other(&src, &sha) {
                return Err(StepError::Missing(format!(
                    "{why}. The study's {name} policy ({}) did not drive them: record \
                     its live trials with that policy (`fishprobe live serve --policy` it), \
                     and keep other policies' trials out of the study's real trials",
                    study.external_policy(p).map_or_else(
                        || train_dir(study, p, 0).display().to_string(),
                        str::to_string
                    )
                )));
            }
            if !prov.unrecorded.is_empty() {
                say(&format!(
                    "{WARNING}{} of the live trials in {} do not record which weights drove \
                     them (written before fishprobe recorded it, or by another tool): they \
                     are taken as the study's {name} policy's",
                    prov.unrecorded.len(),
                    src.display()
                ));
            }
            for (f, e) in &prov.unreadable {
                say(&format!(
                    "{WARNING}{} cannot be read ({e}); the analysis will leave it out",
                    f.display()
                ));
            }
        }
        let mut n = 0;
        for f in fishprobe_io::trial_files(&src) {
            let to = tmp.join(f.file_name().unwrap_or_default());
            std::fs::copy(&f, &to).map_err(|e| StepError::io("copying", &f, e))?;
            n += 1;
        }
        if n == 0 {
            return Err(StepError::Missing(format!(
                "no trial files in {}",
                src.display()
            )));
        }
        say(&format!("{n} live trials copied from {}", src.display()));
        return commit_dir(&tmp, out);
    }
    // The virtual lab against an in-process bridge on a loopback port.
    let loopback = Path::new("127.0.0.1:0");
    let listener = std::net::TcpListener::bind("127.0.0.1:0")
        .map_err(|e| StepError::io("listening on", loopback, e))?;
    let addr = listener
        .local_addr()
        .map_err(|e| StepError::io("listening on", loopback, e))?;
    let ctl = policy_of(study, p, 0)?;
    let live = LiveConfig {
        control_s: c.virtual_minutes * 60.0,
        fish_count: c.fish_count,
        centroid_bins: c.centroid_bins,
        ..LiveConfig::default()
    };
    let opts = ServeOptions {
        live,
        task: study.env.task.clone(),
        out: tmp.clone(),
        token: None,
        max_trials: Some(c.virtual_trials),
        fish_label: "virtual guppy".into(),
        guard: BridgeGuard::default(),
    };
    let pilot_name = name.clone();
    let bridge = std::thread::spawn(move || {
        let mut make = || {
            Ok(fishprobe_learn::named(
                ctl.boxed_clone(),
                pilot_name.clone(),
            ))
        };
        serve(&listener, &opts, &mut make, |_| {})
    });
    for k in 0..c.virtual_trials {
        let s = derive_seed(c.seed, &format!("virtual/{name}"), k as u64);
        let t = run_trial(addr, &LabConfig::default(), s)?;
        say(&format!("virtual trial {k}: {} goals", t.goals_reached));
        for w in &t.warnings {
            say(&format!("{WARNING}the bridge says: {w}"));
        }
    }
    bridge
        .join()
        .map_err(|_| StepError::Panicked("the bridge thread"))??;
    let made = tmp.join(StudyLayout::arm_dir_name(&name, &Arm::VirtualLab));
    commit_dir(&made, out)?;
    std::fs::remove_dir_all(&tmp).map_err(|e| StepError::io("removing", &tmp, e))
}
