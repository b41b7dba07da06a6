//! End-to-end tests of `fishprobe run` with the smoke preset.

#![allow(clippy::unwrap_used)] // a failure is a test failure

mod common;

use common::{fishprobe, fresh_dir as dir, stderr, stdout, train_smoke};
use std::path::Path;
use std::process::{Command, Stdio};
use std::time::{Duration, Instant};

fn results(study: &Path) -> String {
    // Paths differ between studies; everything else must not.
    std::fs::read_to_string(study.join("analysis/results.json"))
        .unwrap()
        .replace(study.to_str().unwrap(), "STUDY")
}

#[test]
fn a_smoke_study_runs_end_to_end_resumes_after_kill_9_and_reruns_to_nothing() {
    let base = dir("run");
    let a = base.join("a");
    let start = Instant::now();
    let o = fishprobe(&["run", "--preset", "smoke", "--out", a.to_str().unwrap()]);
    assert!(o.status.success(), "{}", stderr(&o));
    eprintln!("smoke study: {:.1} s", start.elapsed().as_secs_f64());
    assert!(stdout(&o).contains("Study complete"), "{}", stdout(&o));
    for p in [
        "study.json",
        "policies/Zone/params.json",
        "policies/ConvNet/progress.csv",
        "policies_stability/Force/seed1/policy.safetensors",
        "rollouts/Zone__Force",
        "rollouts/Follow__VirtualLab",
        "approach_test/ConvNet",
        "approach_stability/Zone/seed1",
        "stability/Follow/seed1",
        "analysis/results.json",
        "report/index.html",
        "logs/train-Zone-0.log",
    ] {
        assert!(a.join(p).exists(), "{p} missing");
    }
    let r: serde_json::Value = serde_json::from_str(&results(&a)).unwrap();
    assert_eq!(r["reality"], "VirtualLab");
    assert_eq!(r["sim_to_sim"].as_object().unwrap().len(), 4);
    assert!(r["stability"]["r"].is_number());
    // Every policy's competence: its goals next to both scripted controllers' on its episodes.
    for p in ["Follow", "Zone", "Force", "ConvNet"] {
        let c = &r["competence"][p];
        assert_eq!(c["baselines"].as_object().unwrap().len(), 2, "{c}");
        assert!(
            c["policy_goals"].is_number() && c["weak"].is_boolean(),
            "{c}"
        );
        assert!(a.join(format!("baselines/{p}/FetchAndLead")).is_dir());
        // The ratio's standard error, whenever both sides have goals over two episodes.
        let se = &c["ratio_se"];
        if c["policy_goals"].as_f64().unwrap() > 0.0 && c["trials"].as_u64().unwrap() >= 2 {
            assert!(se.as_f64().is_some_and(|x| x >= 0.0), "{c}");
        } else {
            assert!(se.is_null(), "{c}");
        }
        // How soon each reaches its fish: fetch-and-lead does within any episode.
        assert!(c["reach_s"].is_number() || c["reach_s"].is_null(), "{c}");
        assert!(
            c["baselines_reach_s"]["FetchAndLead"]
                .as_f64()
                .is_some_and(|t| t >= 0.0),
            "{c}"
        );
    }
    let csv = std::fs::read_to_string(a.join("analysis/competence.csv")).unwrap();
    assert!(csv.lines().next().unwrap().ends_with(",ratio_se"), "{csv}");
    // Every training seed of every policy: its competence and its approach assay.
    for p in ["Follow", "Zone", "Force", "ConvNet"] {
        let seeds = r["seeds"][p].as_array().unwrap();
        let names: Vec<&str> = seeds.iter().map(|s| s["seed"].as_str().unwrap()).collect();
        assert_eq!(names, ["seed0", "seed1"], "{p}");
        for s in seeds {
            assert!(
                s["ratio"].is_number() && s["goes_to_fish"].is_boolean(),
                "{s}"
            );
            assert_eq!(s["approach"]["episodes"], 2, "{s}");
        }
        assert_eq!(
            seeds[0]["approach"], r["approach"][p],
            "seed 0's assay is the policy's"
        );
    }
    assert!(a.join("analysis/seeds.csv").is_file());
    let html = std::fs::read_to_string(a.join("report/index.html")).unwrap();
    assert!(html.contains("id=\"virtual\""));
    assert!(html.contains("id=\"competence\"") && html.contains("reaches its fish"));
    assert!(html.contains("id=\"seeds\"") && html.contains("seeds.csv"));
    // A rerun finds everything complete and changes nothing.
    let before = results(&a);
    let o = fishprobe(&["run", "--preset", "smoke", "--out", a.to_str().unwrap()]);
    assert!(o.status.success(), "{}", stderr(&o));
    assert!(
        stderr(&o).contains("50 steps, 50 complete"),
        "{}",
        stderr(&o)
    );
    assert!(results(&a) == before, "a rerun changed the results");

    // Steps recorded by an older fishprobe (markers without this version's schema) are
    // recomputed once, and the run says so; the results come out as before.
    let done = a.join(".fishprobe/done");
    for e in std::fs::read_dir(&done).unwrap() {
        let p = e.unwrap().path();
        let mut m: serde_json::Value =
            serde_json::from_str(&std::fs::read_to_string(&p).unwrap()).unwrap();
        m.as_object_mut().unwrap().remove("schema");
        std::fs::write(&p, m.to_string()).unwrap();
    }
    let o = fishprobe(&["run", "--preset", "smoke", "--out", a.to_str().unwrap()]);
    assert!(o.status.success(), "{}", stderr(&o));
    assert!(
        stderr(&o).contains("50 steps, 0 complete")
            && stderr(&o).contains("50 recorded by an older fishprobe"),
        "{}",
        stderr(&o)
    );
    assert!(results(&a) == before, "recomputing changed the results");

    // Outputs that no longer match their markers (a trial lost, a stranger added, a trial
    // swapped for another, as when two processes wrote one study) are
    // redone, and the results come out as before.
    let lost = fishprobe_io::trial_files(&a.join("rollouts/Zone__Force"))[0].clone();
    std::fs::remove_file(&lost).unwrap();
    let stranger = a.join("rollouts/Force__Force/trial_999.hdf5");
    let follow = fishprobe_io::trial_files(&a.join("rollouts/Follow__Follow"));
    std::fs::copy(&follow[0], &stranger).unwrap();
    let zone = fishprobe_io::trial_files(&a.join("rollouts/Zone__Zone"));
    let (swapped, original) = (zone[0].clone(), std::fs::read(&zone[0]).unwrap());
    std::fs::copy(&zone[1], &swapped).unwrap();
    let o = fishprobe(&["run", "--preset", "smoke", "--out", a.to_str().unwrap()]);
    assert!(o.status.success(), "{}", stderr(&o));
    let err = stderr(&o);
    assert!(!err.contains("50 steps, 50 complete"), "{err}");
    assert!(lost.is_file(), "the lost trial was not redone");
    assert!(!stranger.exists(), "the stranger is still there");
    assert_eq!(
        std::fs::read(&swapped).unwrap(),
        original,
        "the swap was kept"
    );
    assert!(
        results(&a) == before,
        "redoing the damaged steps changed the results"
    );

    // A training run whose spec cannot be read (not text) is kept, not deleted as stale:
    // the study stops naming it, and runs on once the spec is back.
    let params = a.join("policies/Zone/params.json");
    let spec = std::fs::read(&params).unwrap();
    let mut damaged = vec![0xff];
    damaged.extend_from_slice(&spec);
    std::fs::write(&params, &damaged).unwrap();
    let o = fishprobe(&["run", "--preset", "smoke", "--out", a.to_str().unwrap()]);
    assert!(!o.status.success());
    assert!(
        stderr(&o).contains("cannot tell whether the folder holds this run (it is kept"),
        "{}",
        stderr(&o)
    );
    assert!(a.join("policies/Zone/policy.safetensors").is_file());
    assert_eq!(std::fs::read(&params).unwrap(), damaged);
    std::fs::write(&params, &spec).unwrap();
    let o = fishprobe(&["run", "--preset", "smoke", "--out", a.to_str().unwrap()]);
    assert!(o.status.success(), "{}", stderr(&o));
    assert!(results(&a) == before, "the kept run changed the results");

    // A run that another trainer revision started (its marker gone, as when a raised revision
    // changes the step's hash) is stale: trained again from the start, not continued.
    let mut old: serde_json::Value = serde_json::from_slice(&spec).unwrap();
    assert_eq!(old["trainer_revision"], fishprobe_learn::TRAINER_REVISION);
    old["trainer_revision"] = 1.into();
    std::fs::write(&params, old.to_string()).unwrap();
    std::fs::remove_file(a.join(".fishprobe/done/train-Zone-0.json")).unwrap();
    let o = fishprobe(&["run", "--preset", "smoke", "--out", a.to_str().unwrap()]);
    assert!(o.status.success(), "{}", stderr(&o));
    let log = std::fs::read_to_string(a.join("logs/train-Zone-0.log")).unwrap();
    let last = &log[log.rfind("step train-Zone-0").unwrap()..];
    assert!(!last.contains("resuming"), "{last}");
    assert_eq!(std::fs::read(&params).unwrap(), spec, "not trained again");
    assert!(
        results(&a) == before,
        "the retrained run changed the results"
    );

    // Live trials as the reality arm (here the virtual lab's, which record the weights that
    // drove them): taken when they are the study's policies'; refused, naming the trial, when
    // one was driven by other weights under the same name; taken with a warning when one
    // does not say.
    let real = base.join("real");
    for p in ["Follow", "Zone", "Force", "ConvNet"] {
        let to = real.join(format!("{p}__Real"));
        std::fs::create_dir_all(&to).unwrap();
        for f in fishprobe_io::trial_files(&a.join(format!("rollouts/{p}__VirtualLab"))) {
            std::fs::copy(&f, to.join(f.file_name().unwrap())).unwrap();
        }
    }
    let with_real = |dir: &Path| {
        fishprobe(&[
            "run",
            "--preset",
            "smoke",
            "--out",
            a.to_str().unwrap(),
            "--real",
            dir.to_str().unwrap(),
        ])
    };
    let o = with_real(&real);
    assert!(o.status.success(), "{}", stderr(&o));
    assert!(!stderr(&o).contains("do not record"), "{}", stderr(&o));
    let retrained = base.join("real-retrained");
    std::fs::rename(&real, &retrained).unwrap();
    let trial = retrained.join("Zone__Real/trial_001.hdf5");
    let mut t = fishprobe_io::read_trial(&trial).unwrap();
    let task = t.task.as_mut().unwrap();
    let sha = task.policy_sha256().unwrap();
    assert_eq!(sha.len(), 64);
    task.config_json = task.config_json.replace(&sha, &"0".repeat(64));
    fishprobe_io::write_trial(&trial, &t).unwrap();
    let o = with_real(&retrained);
    assert!(!o.status.success());
    assert!(
        stderr(&o).contains("trial_001.hdf5")
            && stderr(&o).contains("another policy under the same name")
            && stderr(&o).contains("policies/Zone"),
        "{}",
        stderr(&o)
    );
    let unsaid = base.join("real-unsaid");
    std::fs::rename(&retrained, &unsaid).unwrap();
    let task = t.task.as_mut().unwrap();
    task.config_json = "{}".into();
    fishprobe_io::write_trial(&unsaid.join("Zone__Real/trial_001.hdf5"), &t).unwrap();
    std::fs::write(unsaid.join("Zone__Real/trial_009.hdf5"), b"garbage").unwrap();
    let o = with_real(&unsaid);
    assert!(o.status.success(), "{}", stderr(&o));
    assert!(
        stderr(&o).contains("1 of the live trials")
            && stderr(&o).contains("do not record")
            && stderr(&o).contains("trial_009.hdf5 cannot be read"),
        "{}",
        stderr(&o)
    );

    // Killed (SIGKILL) once some steps are done, then rerun: the same results.
    let b = base.join("b");
    let mut child = Command::new(env!("CARGO_BIN_EXE_fishprobe"))
        .args(["run", "--preset", "smoke", "--out", b.to_str().unwrap()])
        .stdout(Stdio::null())
        .stderr(Stdio::null())
        .spawn()
        .unwrap();
    let t0 = Instant::now();
    loop {
        let markers = std::fs::read_dir(b.join(".fishprobe/done"))
            .map(|d| d.count())
            .unwrap_or(0);
        if markers >= 12 || t0.elapsed() > Duration::from_secs(60) {
            break;
        }
        std::thread::sleep(Duration::from_millis(10));
    }
    child.kill().unwrap();
    child.wait().unwrap();
    assert!(
        !b.join("report/index.html").exists(),
        "killed too late to test resuming"
    );
    let o = fishprobe(&["run", "--preset", "smoke", "--out", b.to_str().unwrap()]);
    assert!(o.status.success(), "{}", stderr(&o));
    assert_eq!(
        results(&b),
        before,
        "a resumed study differs from an uninterrupted one"
    );

    // A setting the trainings read, added to the finished study's file: the policies are
    // trained again with it (and everything after them runs again), not passed off as new.
    let file = base.join("centroid.toml");
    std::fs::write(&file, "centroid_bins = true\n").unwrap();
    let o = fishprobe(&[
        "run",
        "--preset",
        "smoke",
        "--config",
        file.to_str().unwrap(),
        "--out",
        b.to_str().unwrap(),
    ]);
    assert!(o.status.success(), "{}", stderr(&o));
    assert!(
        stderr(&o).contains("50 steps, 0 complete"),
        "{}",
        stderr(&o)
    );
    let params: serde_json::Value = serde_json::from_str(
        &std::fs::read_to_string(b.join("policies/Zone/params.json")).unwrap(),
    )
    .unwrap();
    assert_eq!(
        params.pointer("/env/observation/centroid_bins"),
        Some(&serde_json::Value::Bool(true)),
        "{params}"
    );
}

#[test]
fn bad_study_inputs_fail_before_any_work() {
    let d = dir("run-bad");
    let cfg = d.join("study.toml");
    std::fs::write(
        &cfg,
        "[[extra_models]]\nname = \"Mystery\"\nspec = { model = \"Couzin\" }\n",
    )
    .unwrap();
    let out = d.join("s");
    let run_config = || {
        fishprobe(&[
            "run",
            "--preset",
            "smoke",
            "--config",
            cfg.to_str().unwrap(),
            "--out",
            out.to_str().unwrap(),
        ])
    };
    let o = run_config();
    assert!(!o.status.success());
    assert!(stderr(&o).contains("Couzin"), "{}", stderr(&o));
    assert!(!out.exists(), "work started despite a bad config");
    // `--real`: missing, a file where the directory belongs (named as what it is, not as
    // missing), and a directory without every policy's trials. Each refused before any work.
    let run_real = |real: &str| {
        fishprobe(&[
            "run",
            "--preset",
            "smoke",
            "--real",
            d.join(real).to_str().unwrap(),
            "--out",
            out.to_str().unwrap(),
        ])
    };
    std::fs::write(d.join("trial.hdf5"), b"").unwrap();
    std::fs::create_dir_all(d.join("real/Zone__Real")).unwrap();
    for (real, says) in [
        ("nope", "does not exist"),
        ("trial.hdf5", "trial.hdf5 is not a directory"),
        ("real", "Follow"),
    ] {
        let o = run_real(real);
        assert!(!o.status.success());
        assert!(stderr(&o).contains(says), "{}", stderr(&o));
        assert!(!out.exists());
    }
    let o = fishprobe(&["run", "--preset", "huge", "--out", out.to_str().unwrap()]);
    assert!(!o.status.success());
    assert!(stderr(&o).contains("huge"), "{}", stderr(&o));
    // An analysis setting that does not exist, in the study file's [analysis] table.
    std::fs::write(&cfg, "[analysis]\napproach_closest = 4.0\n").unwrap();
    let o = run_config();
    assert!(!o.status.success());
    assert!(
        stderr(&o).contains("`analysis.approach_closest`")
            && stderr(&o).contains("is not among the [analysis] settings"),
        "{}",
        stderr(&o)
    );
    assert!(!out.exists());
    // A task setting of the wrong kind, in the study file's [task] table.
    std::fs::write(&cfg, "[task]\ntraining_start = \"corner\"\n").unwrap();
    let o = run_config();
    assert!(!o.status.success());
    assert!(
        stderr(&o).contains("`task.training_start`"),
        "{}",
        stderr(&o)
    );
    assert!(!out.exists());
}

#[test]
fn convnet_can_be_refitted_for_the_study() {
    let Some(data) = fishprobe_io::shared_data_dir() else {
        eprintln!("skipping: FISHPROBE_DATA is not set and ../shared/data is absent");
        return;
    };
    let legacy = data.join("guppy-pairs/legacy");
    let d = dir("run-convnet");
    let pairs = d.join("pairs");
    for (sub, n) in [("train", 2), ("validation", 1)] {
        std::fs::create_dir_all(pairs.join(sub)).unwrap();
        let mut files: Vec<_> = std::fs::read_dir(legacy.join(sub))
            .unwrap()
            .map(|e| e.unwrap().path())
            .collect();
        files.sort();
        for f in files.into_iter().take(n) {
            std::fs::copy(&f, pairs.join(sub).join(f.file_name().unwrap())).unwrap();
        }
    }
    let cfg = d.join("study.toml");
    // With a [task] table: every training runs under it.
    std::fs::write(&cfg, "preset = \"smoke\"\nmodels = [{ name = \"ConvNet\", spec = { model = \"ConvNet\" } }, { name = \"Follow\", spec = { model = \"Follow\" } }]\n[task]\ntraining_episode_actions = 30\n").unwrap();
    let out = d.join("study");
    let o = fishprobe(&[
        "run",
        "--config",
        cfg.to_str().unwrap(),
        "--convnet-data",
        pairs.to_str().unwrap(),
        "--out",
        out.to_str().unwrap(),
    ]);
    assert!(o.status.success(), "{}", stderr(&o));
    assert!(out.join("convnet/convnet.safetensors").is_file());
    let params = std::fs::read_to_string(out.join("policies/ConvNet/params.json")).unwrap();
    assert!(
        params.contains("convnet/convnet.safetensors"),
        "the policy did not train against the refitted fish"
    );
    let params: serde_json::Value = serde_json::from_str(&params).unwrap();
    assert_eq!(params["env"]["task"]["training_episode_actions"], 30);
    let o = fishprobe(&[
        "run",
        "--convnet-data",
        d.join("nope").to_str().unwrap(),
        "--out",
        out.to_str().unwrap(),
    ]);
    assert!(!o.status.success());
    assert!(stderr(&o).contains("train/"), "{}", stderr(&o));
}

/// A study file naming a policy trained elsewhere (here: exported to ONNX): its model's first
/// training run is skipped and the ONNX file is evaluated, assayed and analysed in its place.
#[test]
fn a_study_evaluates_a_policy_trained_elsewhere_without_training_it() {
    let base = dir("run-external");
    let p = base.join("trained_elsewhere");
    train_smoke("Zone", &p, &["--seed", "9"]);
    let onnx = base.join("zone.onnx");
    let o = fishprobe(&[
        "export",
        "--policy",
        p.to_str().unwrap(),
        "--onnx",
        onnx.to_str().unwrap(),
    ]);
    assert!(o.status.success(), "{}", stderr(&o));
    // The path is relative to the study file.
    let cfg = base.join("study.toml");
    std::fs::write(
        &cfg,
        "[[policies]]\nmodel = \"Zone\"\npolicy = \"onnx:zone.onnx\"\n",
    )
    .unwrap();
    let s = base.join("s");
    let o = fishprobe(&[
        "run",
        "--preset",
        "smoke",
        "--config",
        cfg.to_str().unwrap(),
        "--out",
        s.to_str().unwrap(),
    ]);
    assert!(o.status.success(), "{}", stderr(&o));
    assert!(!s.join("policies/Zone").exists(), "π_Zone was trained");
    assert!(s.join("policies/Follow/policy.safetensors").is_file());
    let files = fishprobe_io::trial_files(&s.join("rollouts/Zone__Force"));
    assert!(!files.is_empty());
    let t = fishprobe_io::read_trial(&files[0]).unwrap();
    let policy = &t.task.unwrap().policy;
    assert!(
        policy.starts_with("onnx:") && policy.contains("zone.onnx"),
        "{policy}"
    );
    let virt = fishprobe_io::trial_files(&s.join("rollouts/Zone__VirtualLab"));
    assert!(
        !virt.is_empty(),
        "no virtual-lab trials for the ONNX policy"
    );
    let r: serde_json::Value = serde_json::from_str(&results(&s)).unwrap();
    assert!(
        r["sim_to_real"]["Zone"]["w"].is_number(),
        "{}",
        r["sim_to_real"]
    );
    // A policy for a model the study does not have, or a file that does not load: refused
    // before any work.
    for (k, (model, file, needle)) in [
        ("Nope", "zone.onnx", "not one of the study's models"),
        ("Zone", "missing.onnx", "missing.onnx"),
    ]
    .into_iter()
    .enumerate()
    {
        let toml = format!("[[policies]]\nmodel = \"{model}\"\npolicy = \"onnx:{file}\"\n");
        std::fs::write(&cfg, toml).unwrap();
        let out = base.join(format!("refused{k}"));
        let o = fishprobe(&[
            "run",
            "--preset",
            "smoke",
            "--config",
            cfg.to_str().unwrap(),
            "--out",
            out.to_str().unwrap(),
        ]);
        assert!(
            !o.status.success() && stderr(&o).contains(needle),
            "{}",
            stderr(&o)
        );
        assert!(
            !out.join("policies").exists(),
            "work started before the check"
        );
    }
}
