//! End-to-end tests of train, evaluate, export and simulate --robot policy:DIR.

#![allow(clippy::unwrap_used)] // a failure is a test failure

mod common;

use common::{fishprobe, fresh_dir, stderr, stdout, train_smoke};
use std::path::Path;
use std::process::Command;
use std::time::{Duration, Instant};

/// progress.csv without the wall-time columns (time_s, steps_per_s: the last two).
fn progress_without_times(dir: &Path) -> Vec<String> {
    std::fs::read_to_string(dir.join("progress.csv"))
        .unwrap()
        .lines()
        .map(|l| {
            let cols: Vec<_> = l.split(',').collect();
            assert_eq!(cols.len(), 19, "progress.csv columns: {l}");
            cols[..cols.len() - 2].join(",")
        })
        .collect()
}

#[test]
fn a_killed_run_resumes_to_the_same_result() {
    let d = fresh_dir("resume");
    let (a, b) = (d.join("a"), d.join("b"));
    let args = |out: &Path| {
        vec![
            "train",
            "--model",
            "Zone",
            "--preset",
            "smoke",
            "--steps",
            "24576",
            "--seed",
            "4",
            "--out",
            out.to_str().unwrap().to_string().leak(),
        ]
    };
    let o = fishprobe(&args(&a));
    assert!(o.status.success(), "{}", stderr(&o));
    // The same run, killed (SIGKILL) once some iterations are logged, then resumed.
    let mut child = Command::new(env!("CARGO_BIN_EXE_fishprobe"))
        .args(args(&b))
        .stderr(std::process::Stdio::null())
        .spawn()
        .unwrap();
    let start = Instant::now();
    loop {
        let lines = std::fs::read_to_string(b.join("progress.csv"))
            .map(|t| t.lines().count())
            .unwrap_or(0);
        if lines >= 6 || start.elapsed() > Duration::from_secs(60) {
            break;
        }
        std::thread::sleep(Duration::from_millis(5));
    }
    child.kill().unwrap();
    child.wait().unwrap();
    // The killed run is continued as if by another build than the one that started it: each
    // line of result.json names the build that made it, params.json the one that started it.
    let version = stdout(&fishprobe(&["--version"]));
    let build = version.trim().trim_start_matches("fishprobe ");
    let b_params = b.join("params.json");
    let mut started: serde_json::Value =
        serde_json::from_str(&std::fs::read_to_string(&b_params).unwrap()).unwrap();
    started["program_build"] = "0.1.0 (commit 0123456789ab)".into();
    std::fs::write(&b_params, started.to_string()).unwrap();
    let mut resume = args(&b);
    resume.push("--resume");
    let o = fishprobe(&resume);
    assert!(o.status.success(), "{}", stderr(&o));
    let b_builds: Vec<serde_json::Value> = std::fs::read_to_string(b.join("result.json"))
        .unwrap()
        .lines()
        .map(|l| serde_json::from_str::<serde_json::Value>(l).unwrap()["build"].clone())
        .collect();
    assert_eq!(b_builds, vec![serde_json::Value::from(build); 24]);
    assert!(std::fs::read_to_string(&b_params)
        .unwrap()
        .contains("0123456789ab"));
    assert_eq!(
        std::fs::read(a.join("policy.safetensors")).unwrap(),
        std::fs::read(b.join("policy.safetensors")).unwrap(),
        "resumed policy differs"
    );
    assert_eq!(progress_without_times(&a), progress_without_times(&b));
    assert_eq!(progress_without_times(&a).len(), 1 + 24);
    // result.json: one JSON object per iteration.
    let lines: Vec<serde_json::Value> = std::fs::read_to_string(a.join("result.json"))
        .unwrap()
        .lines()
        .map(|l| serde_json::from_str(l).unwrap())
        .collect();
    assert_eq!(lines.len(), 24);
    for k in [
        "timesteps",
        "episode_return_mean",
        "goals_per_episode",
        "policy_loss",
        "value_loss",
        "kl",
        "entropy",
        "time_s",
    ] {
        assert!(lines[23].get(k).is_some(), "{k}");
    }
    let params: serde_json::Value =
        serde_json::from_str(&std::fs::read_to_string(a.join("params.json")).unwrap()).unwrap();
    assert_eq!(params["ppo"]["clip_param"].as_f64().unwrap() as f32, 0.1112);
    assert_eq!(params["model"]["model"], "Zone");
    // Starting over in a used directory is refused.
    let o = fishprobe(&args(&a));
    assert!(
        stderr(&o).contains("already holds a training run"),
        "{}",
        stderr(&o)
    );
    // A finished run resumed without its flags continues with its own seed and preset, and
    // says so (with them, it says nothing).
    let o = fishprobe(&["train", "--resume", "--out", a.to_str().unwrap()]);
    assert!(o.status.success(), "{}", stderr(&o));
    assert!(
        stderr(&o).contains("resuming with the run's own seed 4 and preset `smoke` (params.json), not --seed 0 --preset paper"),
        "{}",
        stderr(&o)
    );
    assert!(!stderr(&fishprobe(&resume)).contains("run's own seed"));

    // The run records the build and the trainer revision that started it. Another build of the
    // same revision continues it and says so; a run of another revision, or one that does not
    // record its revision (started before fishprobe recorded it), is refused, naming both.
    assert_eq!(params["program_build"], build, "{version}");
    assert_eq!(
        params["trainer_revision"],
        fishprobe_learn::TRAINER_REVISION
    );
    let mut resume_a = args(&a);
    resume_a.push("--resume");
    assert!(!stderr(&fishprobe(&resume_a)).contains("started by fishprobe"));
    let params_file = a.join("params.json");
    let original = std::fs::read_to_string(&params_file).unwrap();
    let policy = std::fs::read(a.join("policy.safetensors")).unwrap();
    let with = |key: &str, value: serde_json::Value| {
        let mut p = params.clone();
        match value {
            serde_json::Value::Null => p.as_object_mut().unwrap().remove(key),
            v => p.as_object_mut().unwrap().insert(key.into(), v),
        };
        std::fs::write(&params_file, p.to_string()).unwrap();
    };
    with("program_build", "0.1.0 (commit 0123456789ab)".into());
    let o = fishprobe(&resume_a);
    assert!(o.status.success(), "{}", stderr(&o));
    assert!(
        stderr(&o).contains(
            "the run was started by fishprobe 0.1.0 (commit 0123456789ab); continuing it with"
        ),
        "{}",
        stderr(&o)
    );
    with("trainer_revision", 1.into());
    let o = fishprobe(&resume_a);
    assert!(!o.status.success());
    assert!(
        stderr(&o).contains(&format!(
            "params.json: the run was started by trainer revision 1 (fishprobe {build}); this \
             fishprobe's trainer is revision {}",
            fishprobe_learn::TRAINER_REVISION
        )) && stderr(&o).contains("train it again"),
        "{}",
        stderr(&o)
    );
    with("trainer_revision", serde_json::Value::Null);
    let o = fishprobe(&resume_a);
    assert!(!o.status.success());
    assert!(
        stderr(&o).contains("a fishprobe that did not record its trainer's revision"),
        "{}",
        stderr(&o)
    );
    assert_eq!(
        std::fs::read(a.join("policy.safetensors")).unwrap(),
        policy,
        "a refused resume changed the policy"
    );
    std::fs::write(&params_file, original).unwrap();
}

#[test]
fn a_finished_run_resumed_with_more_steps_trains_on_to_the_longer_runs_policy() {
    let d = fresh_dir("raise");
    let (long, short) = (d.join("long"), d.join("short"));
    let train = |out: &Path, steps: &str, more: &[&str]| {
        let mut a = vec![
            "train", "--model", "Zone", "--preset", "smoke", "--seed", "5",
        ];
        a.extend(["--steps", steps, "--out", out.to_str().unwrap()]);
        a.extend(more);
        fishprobe(&a)
    };
    for (out, steps) in [(&long, "8192"), (&short, "4096")] {
        let o = train(out, steps, &[]);
        assert!(o.status.success(), "{}", stderr(&o));
    }
    let o = train(&short, "8192", &["--resume"]);
    assert!(o.status.success(), "{}", stderr(&o));
    assert!(
        stderr(&o).contains("raising the run's budget from 4096 to 8192 steps (params.json)")
            && stdout(&o).contains("for 8192 steps (8 iterations)"),
        "{}{}",
        stderr(&o),
        stdout(&o)
    );
    assert_eq!(
        std::fs::read(long.join("policy.safetensors")).unwrap(),
        std::fs::read(short.join("policy.safetensors")).unwrap(),
        "4096 steps raised to 8192 differ from 8192 steps"
    );
    assert_eq!(
        progress_without_times(&long),
        progress_without_times(&short)
    );
    // A lower budget is refused, naming both, and leaves the run as it was.
    let policy = std::fs::read(short.join("policy.safetensors")).unwrap();
    let o = train(&short, "4096", &["--resume"]);
    assert!(!o.status.success());
    assert!(
        stderr(&o).contains(
            "the run's budget is 8192 steps, and resuming can only raise it, not lower it to 4096"
        ),
        "{}",
        stderr(&o)
    );
    let o = train(&short, "99999999999999", &["--resume"]);
    assert!(
        !o.status.success() && stderr(&o).contains("total_timesteps"),
        "{}",
        stderr(&o)
    );
    assert_eq!(
        std::fs::read(short.join("policy.safetensors")).unwrap(),
        policy
    );
    let params = std::fs::read_to_string(short.join("params.json")).unwrap();
    assert!(params.contains("\"total_timesteps\": 8192"), "{params}");
}

#[test]
fn evaluate_export_and_simulate_a_trained_policy() {
    let d = fresh_dir("eval");
    let run = d.join("run");
    train_smoke("Follow", &run, &[]);
    let ev = d.join("ev");
    let o = fishprobe(&[
        "evaluate",
        "--policy",
        run.to_str().unwrap(),
        "--model",
        "Follow",
        "--episodes",
        "3",
        "--minutes",
        "0.5",
        "--out",
        ev.to_str().unwrap(),
    ]);
    assert!(o.status.success(), "{}", stderr(&o));
    assert!(
        stdout(&o).contains("goals per 0.5 min over 3 episodes"),
        "{}",
        stdout(&o)
    );
    let summary = std::fs::read_to_string(ev.join("summary.csv")).unwrap();
    assert_eq!(summary.lines().count(), 4);
    // A second evaluation into the same directory would overwrite trial_000 and leave the
    // first one's trial_001 and trial_002 beside it: refused, with nothing touched.
    let first = std::fs::read(ev.join("trial_000.hdf5")).unwrap();
    let o = fishprobe(&[
        "evaluate",
        "--policy",
        "scripted:goal-seeker",
        "--model",
        "Zone",
        "--episodes",
        "1",
        "--minutes",
        "0.5",
        "--out",
        ev.to_str().unwrap(),
    ]);
    assert!(!o.status.success());
    assert!(
        stderr(&o).contains("already holds an evaluation (3 trial files and summary.csv)"),
        "{}",
        stderr(&o)
    );
    assert_eq!(std::fs::read(ev.join("trial_000.hdf5")).unwrap(), first);
    assert_eq!(
        std::fs::read_to_string(ev.join("summary.csv")).unwrap(),
        summary
    );
    let t = fishprobe_io::read_trial(&ev.join("trial_000.hdf5")).unwrap();
    let task = t.task.unwrap();
    assert_eq!(task.fish_model, "Follow");
    assert!(task.policy.starts_with("Follow"), "{}", task.policy);
    assert_eq!(task.command_frames.len(), 30, "one command per second");
    // Which weights drove it: the policy's fingerprint, as `inspect` shows it.
    let sha = task.policy_sha256().unwrap();
    assert!(
        sha.len() == 64 && sha.bytes().all(|b| b.is_ascii_hexdigit()),
        "{sha}"
    );
    let o = fishprobe(&["inspect", ev.join("trial_000.hdf5").to_str().unwrap()]);
    assert!(
        stdout(&o).contains(&format!("(weights sha256 {}…)", &sha[..12])),
        "{}",
        stdout(&o)
    );
    // The virtual lab into a directory with another Follow policy's trials: the bridge's
    // refusal is what the user reads (not the client's lost connection).
    let lab = |policy: &Path| {
        fishprobe(&[
            "lab",
            "--policy",
            policy.to_str().unwrap(),
            "--trials",
            "1",
            "--minutes",
            "0.1",
            "--out",
            d.join("lab").to_str().unwrap(),
        ])
    };
    let o = lab(&run);
    assert!(o.status.success(), "{}", stderr(&o));
    // The welcome names the weights the bridge flies, and the lab says which.
    assert!(
        stderr(&o).contains(&format!("the bridge flew weights sha256 {}…", &sha[..12])),
        "{}",
        stderr(&o)
    );
    let retrained = d.join("run-seed1");
    train_smoke("Follow", &retrained, &["--seed", "1"]);
    let o = lab(&retrained);
    assert!(!o.status.success());
    assert!(
        stderr(&o).contains("the in-process bridge")
            && stderr(&o).contains("Follow__VirtualLab holds 1 trial(s) of another policy"),
        "{}",
        stderr(&o)
    );
    let base = fishprobe(&[
        "evaluate",
        "--policy",
        "scripted:goal-seeker",
        "--model",
        "Follow",
        "--episodes",
        "2",
        "--minutes",
        "0.5",
        "--out",
        d.join("base").to_str().unwrap(),
    ]);
    assert!(base.status.success(), "{}", stderr(&base));
    let one = d.join("one.hdf5");
    let o = fishprobe(&[
        "simulate",
        "--robot",
        &format!("policy:{}", run.display()),
        "--model",
        "Follow",
        "--minutes",
        "0.5",
        "--out",
        one.to_str().unwrap(),
    ]);
    assert!(o.status.success(), "{}", stderr(&o));
    assert!(fishprobe_io::read_trial(&one).is_ok());
    onnx_matches_onnxruntime(&run, &d);
}

/// The exported ONNX model gives the same turn angles as fishprobe (fast tanh vs exact tanh:
/// within 1e-3 rad), checked with onnxruntime from PyPI.
fn onnx_matches_onnxruntime(run: &Path, d: &Path) {
    let onnx = d.join("policy.onnx");
    let o = fishprobe(&[
        "export",
        "--policy",
        run.to_str().unwrap(),
        "--onnx",
        onnx.to_str().unwrap(),
    ]);
    assert!(o.status.success(), "{}", stderr(&o));
    let (policy, _) = fishprobe_learn::GaussianPolicy::load(run).unwrap();
    let obs: Vec<f32> = (0..5 * 180)
        .map(|i| ((i * 37 % 101) as f32) / 100.0)
        .collect();
    let mut mean = vec![0.0; 5];
    policy.mean_actions(
        &obs,
        5,
        &mut fishprobe_nn::MlpWorkspace::default(),
        &mut mean,
    );
    let expected: Vec<f32> = mean
        .iter()
        .map(|&m| fishprobe_learn::to_env_action(m))
        .collect();
    let case = d.join("case.json");
    std::fs::write(
        &case,
        serde_json::json!({"obs": obs, "expected": expected}).to_string(),
    )
    .unwrap();
    let ok = |py: &str| {
        Command::new(py)
            .args(["-c", "import onnxruntime, numpy"])
            .status()
            .is_ok_and(|s| s.success())
    };
    if !ok("python3") {
        let st = Command::new("python3")
            .args(["-m", "pip", "install", "--quiet", "onnxruntime", "numpy"])
            .status();
        assert!(
            st.is_ok_and(|s| s.success()) && ok("python3"),
            "onnxruntime is required for this test"
        );
    }
    let script = r#"
import sys, json, numpy as np, onnxruntime as ort
c = json.load(open(sys.argv[2]))
s = ort.InferenceSession(sys.argv[1])
out = s.run(["turn"], {"obs": np.array(c["obs"], dtype=np.float32).reshape(5, 180)})[0].ravel()
err = np.max(np.abs(out - np.array(c["expected"], dtype=np.float32)))
assert err < 1e-3, (out, c["expected"], err)
print("max error", err)
"#;
    let o = Command::new("python3")
        .args(["-c", script, onnx.to_str().unwrap(), case.to_str().unwrap()])
        .output()
        .unwrap();
    assert!(o.status.success(), "{}{}", stdout(&o), stderr(&o));
}

#[test]
fn unusable_policies_are_clear_errors() {
    let d = fresh_dir("badpol");
    let o = fishprobe(&[
        "evaluate",
        "--policy",
        d.join("none").to_str().unwrap(),
        "--model",
        "Zone",
        "--out",
        d.join("x").to_str().unwrap(),
    ]);
    assert!(
        stderr(&o).contains("not a policy directory"),
        "{}",
        stderr(&o)
    );
    let run = d.join("run");
    assert!(fishprobe(&[
        "train",
        "--model",
        "Zone",
        "--preset",
        "smoke",
        "--steps",
        "1024",
        "--out",
        run.to_str().unwrap()
    ])
    .status
    .success());
    // Built for 180 observations; an environment with 18 sectors gives 90.
    let settings = d.join("s.toml");
    std::fs::write(&settings, "[env.observation]\nsectors = 18\n").unwrap();
    let o = fishprobe(&[
        "evaluate",
        "--policy",
        run.to_str().unwrap(),
        "--model",
        "Zone",
        "--episodes",
        "1",
        "--minutes",
        "0.1",
        "--settings",
        settings.to_str().unwrap(),
        "--out",
        d.join("y").to_str().unwrap(),
    ]);
    assert!(
        stderr(&o).contains("built for observations of 180 floats, the environment gives 90"),
        "{}",
        stderr(&o)
    );
    // Another format version.
    let sidecar = run.join("policy.safetensors.json");
    let text = std::fs::read_to_string(&sidecar)
        .unwrap()
        .replace("\"version\": 1", "\"version\": 99");
    std::fs::write(&sidecar, text).unwrap();
    let o = fishprobe(&[
        "export",
        "--policy",
        run.to_str().unwrap(),
        "--onnx",
        d.join("p.onnx").to_str().unwrap(),
    ]);
    assert!(stderr(&o).contains("version 99"), "{}", stderr(&o));
    // Missing weights.
    std::fs::remove_file(run.join("policy.safetensors")).unwrap();
    let o = fishprobe(&[
        "export",
        "--policy",
        run.to_str().unwrap(),
        "--onnx",
        d.join("p.onnx").to_str().unwrap(),
    ]);
    assert!(stderr(&o).contains("missing"), "{}", stderr(&o));
    let o = fishprobe(&[
        "train",
        "--model",
        "Zone",
        "--preset",
        "huge",
        "--out",
        d.join("z").to_str().unwrap(),
    ]);
    assert!(
        stderr(&o).contains("unknown --preset `huge`"),
        "{}",
        stderr(&o)
    );
    // A refused new run leaves no directory behind (it is made only once the run is checked).
    assert!(!d.join("z").exists());
    let o = fishprobe(&[
        "train",
        "--model",
        "onnx:/nonexistent/fish.onnx",
        "--out",
        d.join("z").to_str().unwrap(),
    ]);
    assert!(stderr(&o).contains("fish.onnx"), "{}", stderr(&o));
    assert!(!d.join("z").exists());
}

#[test]
fn a_ppo_file_overrides_the_preset_field_by_field() {
    let d = fresh_dir("ppo-file");
    let train = |settings: &str, run: &str| {
        let file = d.join("ppo.toml");
        std::fs::write(&file, settings).unwrap();
        let out = d.join(run);
        let args = ["train", "--model", "Follow", "--preset", "smoke", "--ppo"];
        let o = fishprobe(
            &[
                &args[..],
                &[file.to_str().unwrap(), "--out", out.to_str().unwrap()],
            ]
            .concat(),
        );
        (o, out)
    };
    let (o, out) = train("num_sgd_iter = 3\nlr = 0.001\n", "run");
    assert!(o.status.success(), "{}", stderr(&o));
    let params: serde_json::Value =
        serde_json::from_str(&std::fs::read_to_string(out.join("params.json")).unwrap()).unwrap();
    let ppo = &params["ppo"];
    assert_eq!(ppo["num_sgd_iter"], 3);
    assert!((ppo["lr"].as_f64().unwrap() - 0.001).abs() < 1e-9);
    // The rest is the smoke preset's.
    assert_eq!(ppo["train_batch_size"], 1024);
    // The diagnostics are logged.
    let head = std::fs::read_to_string(out.join("progress.csv")).unwrap();
    assert!(head.contains(",clip_frac,action_clip_frac,vf_explained_var,vf_explained_var_fit,"));
    // The paper's log-s.d. bound is on unless the file lifts it (TOML inf: no bound), and the
    // policy carries it.
    assert_eq!(ppo["log_std_max"], 0.0);
    let (o, out) = train("log_std_max = inf\n", "unbounded");
    assert!(o.status.success(), "{}", stderr(&o));
    let sidecar: serde_json::Value = serde_json::from_str(
        &std::fs::read_to_string(out.join("policy.safetensors.json")).unwrap(),
    )
    .unwrap();
    assert!(sidecar["log_std_max"].is_null(), "{sidecar}");

    for (text, needle) in [
        ("num_sgd_iters = 3\n", "num_sgd_iters"),
        ("num_sgd_iter = 0\n", "num_sgd_iter"),
        ("lr = \"fast\"\n", "lr"),
        ("lr = nan\n", "`lr`: not a finite number"),
        ("log_std_max = 20.0\n", "log_std_max"),
        ("log_std_max = nan\n", "`log_std_max`: nan is not a bound"),
    ] {
        let (o, _) = train(text, "bad-run");
        assert!(!o.status.success());
        let e = stderr(&o);
        assert!(e.contains("ppo.toml") && e.contains(needle), "{e}");
        assert!(!e.contains("panicked"), "{e}");
    }
}

#[test]
fn the_paper_preset_trains_an_expensive_fish_at_the_published_budget() {
    // A tiny network and batch, so that one iteration against M_ConvNet is quick; the steps
    // and epochs the preset chose for each fish are what params.json records.
    let d = fresh_dir("paper-budget");
    let file = d.join("tiny.toml");
    std::fs::write(
        &file,
        "train_batch_size = 64\nnum_envs = 16\nsgd_minibatch_size = 32\nhidden = [8]\n",
    )
    .unwrap();
    // The steps are set here to keep the run short; `PpoConfig::preset_for`'s own test checks
    // the preset's steps for both kinds of fish.
    for (model, epochs) in [("Zone", 2), ("ConvNet", 10)] {
        let out = d.join(model);
        let o = fishprobe(&[
            "train",
            "--model",
            model,
            "--preset",
            "paper",
            "--ppo",
            file.to_str().unwrap(),
            "--out",
            out.to_str().unwrap(),
            "--steps",
            "64",
        ]);
        assert!(o.status.success(), "{model}: {}", stderr(&o));
        let params: serde_json::Value =
            serde_json::from_str(&std::fs::read_to_string(out.join("params.json")).unwrap())
                .unwrap();
        assert_eq!(params["ppo"]["num_sgd_iter"], epochs, "{model}");
        assert_eq!(params["ppo"]["total_timesteps"], 64, "{model}");
        assert_eq!(params["ppo"]["hidden"], serde_json::json!([8]), "{model}");
    }
}

#[test]
fn a_settings_files_fish_keeps_its_parameters_under_a_model_flag_of_the_same_model() {
    let d = fresh_dir("model-flag");
    let file = d.join("zone.toml");
    std::fs::write(
        &file,
        "[fish]\nmodel = \"Zone\"\nwall_attraction_strength = 1.0\n",
    )
    .unwrap();
    let train = |model: &str, run: &str| {
        let out = d.join(run);
        let o = fishprobe(&[
            "train",
            "--model",
            model,
            "--preset",
            "smoke",
            "--steps",
            "64",
            "--settings",
            file.to_str().unwrap(),
            "--out",
            out.to_str().unwrap(),
        ]);
        assert!(o.status.success(), "{}", stderr(&o));
        let params: serde_json::Value =
            serde_json::from_str(&std::fs::read_to_string(out.join("params.json")).unwrap())
                .unwrap();
        (params["model"].clone(), stderr(&o))
    };
    // The same model (any spelling): the file's fish, parameters and all.
    let (model, err) = train("zone", "same");
    assert_eq!(model["model"], "Zone");
    assert_eq!(model["wall_attraction_strength"], 1.0);
    assert!(!err.contains("replaces"), "{err}");
    // Another model replaces the fish, and says that the file's parameters are dropped.
    let (model, err) = train("Follow", "other");
    assert_eq!(model["model"], "Follow");
    assert!(
        err.contains("--model Follow replaces the settings file's fish (Zone)"),
        "{err}"
    );

    // `evaluate` reads the file's fish too: the scripted fetch-and-lead meets the file's fish,
    // so its trial files differ from those with the default M_Zone.
    let eval = |settings: bool, run: &str| {
        let out = d.join(run);
        let mut args = vec![
            "evaluate",
            "--policy",
            "scripted:fetch-and-lead",
            "--model",
            "Zone",
            "--episodes",
            "1",
            "--minutes",
            "1",
            "--out",
            out.to_str().unwrap(),
        ];
        if settings {
            args.extend(["--settings", file.to_str().unwrap()]);
        }
        let o = fishprobe(&args);
        assert!(o.status.success(), "{}", stderr(&o));
        std::fs::read(out.join("trial_000.hdf5")).unwrap()
    };
    let default = eval(false, "ev-default");
    assert_eq!(
        default,
        eval(false, "ev-default-again"),
        "trial files are reproducible"
    );
    assert_ne!(eval(true, "ev-file"), default);
}
