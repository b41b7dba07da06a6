//! Every subcommand with hostile values: each ends in a clean error (exit 1, or clap's 2 for
//! what it parses), with a message naming the problem, quickly, without a panic or an abort.

#![allow(clippy::unwrap_used)] // a failure is a test failure

mod common;

use common::{fresh_dir, stderr};
use std::path::Path;
use std::process::{Command, Output, Stdio};
use std::time::{Duration, Instant};

/// Runs fishprobe with `args`; kills it and fails after `limit`.
fn run_within(args: &[&str], limit: Duration) -> Output {
    let mut child = Command::new(env!("CARGO_BIN_EXE_fishprobe"))
        .args(args)
        .stdin(Stdio::null())
        .stdout(Stdio::piped())
        .stderr(Stdio::piped())
        .spawn()
        .unwrap();
    let start = Instant::now();
    while child.try_wait().unwrap().is_none() {
        if start.elapsed() > limit {
            let _ = child.kill();
            panic!("fishprobe {args:?} still running after {limit:?}");
        }
        std::thread::sleep(Duration::from_millis(20));
    }
    child.wait_with_output().unwrap()
}

/// Asserts a clean refusal whose message contains `needle`.
fn refused(args: &[&str], needle: &str) {
    let o = run_within(args, Duration::from_secs(60));
    let err = stderr(&o);
    let code = o.status.code();
    assert!(
        matches!(code, Some(1 | 2)),
        "fishprobe {args:?}: exit {:?} (a panic is 101, a signal none)\n{err}",
        o.status
    );
    assert!(
        !err.contains("panicked"),
        "fishprobe {args:?} panicked:\n{err}"
    );
    assert!(
        err.contains(needle),
        "fishprobe {args:?}: `{needle}` not in:\n{err}"
    );
}

fn s(p: &Path) -> &str {
    p.to_str().unwrap()
}

#[test]
fn absurd_numbers_are_refused_before_any_work() {
    let d = fresh_dir("hostile-numbers");
    let trial = d.join("t.hdf5");
    let out = d.join("out");
    for m in ["1e9", "1e7", "NaN", "inf", "-1", "0", "1e-40", "0.01"] {
        let flag = format!("--minutes={m}");
        refused(
            &["simulate", "--model", "Zone", &flag, "--out", s(&trial)],
            "--minutes must lie in [1/60, 1440] minutes (one second to 24 hours)",
        );
    }
    // The value as given, not the f64 noise of the nearest f32.
    refused(
        &[
            "simulate",
            "--model",
            "Zone",
            "--minutes=1e-40",
            "--out",
            s(&trial),
        ],
        "got 1e-40",
    );
    refused(
        &[
            "evaluate",
            "--policy",
            "scripted:goal-seeker",
            "--model",
            "Zone",
            "--minutes",
            "1e9",
            "--out",
            s(&out),
        ],
        "--minutes must lie in",
    );
    refused(
        &[
            "evaluate",
            "--policy",
            "scripted:goal-seeker",
            "--model",
            "Zone",
            "--episodes",
            "0",
            "--out",
            s(&out),
        ],
        "--episodes must lie in",
    );
    refused(
        &[
            "evaluate",
            "--policy",
            "scripted:goal-seeker",
            "--model",
            "Zone",
            "--episodes",
            "1",
            "--jobs",
            "0",
            "--out",
            s(&out),
        ],
        "--jobs must be at least 1",
    );
    refused(
        &["models", "--measure", "--minutes", "1e9"],
        "--minutes must lie in",
    );
    refused(
        &[
            "lab",
            "--policy",
            "scripted:goal-seeker",
            "--minutes",
            "1e9",
            "--out",
            s(&out),
        ],
        "--minutes must lie in",
    );
    refused(
        &[
            "lab",
            "--policy",
            "scripted:goal-seeker",
            "--trials",
            "0",
            "--out",
            s(&out),
        ],
        "--trials must lie in",
    );
    refused(
        &["run", "--jobs", "0", "--out", s(&d.join("study"))],
        "--jobs must be at least 1",
    );
    refused(
        &["analyze", s(&d), "--jobs", "0"],
        "--jobs must be at least 1",
    );
    refused(
        &["bench", "sim", "--seconds", "1e12"],
        "--seconds must lie in (0, 3600], got 1e12",
    );
    // Physically absurd settings: refused by name, whether typed on the command line or
    // in a settings file.
    refused(
        &["collective", "--orientation", "1.8e19", "--out", s(&d.join("c"))],
        "Δr_o = 1.8e19, Δr_a = 4: invalid configuration: `orientation_zone_cm` = 1.8e19: must lie in [0, 1000]",
    );
    let robot = d.join("robot.toml");
    std::fs::write(&robot, "[env.robot]\nmax_speed_cm_s = 1e30\n").unwrap();
    refused(
        &[
            "simulate",
            "--model",
            "Zone",
            "--settings",
            s(&robot),
            "--out",
            s(&trial),
        ],
        "`robot.max_speed_cm_s` = 1e30: must lie in (0, 1000]",
    );
    // A report setting that made the report crash (an 800-TB histogram) is refused by name.
    let study = d.join("study");
    std::fs::create_dir_all(study.join("rollouts")).unwrap();
    let rcfg = d.join("report.toml");
    std::fs::write(&rcfg, "iid_bin_cm = 1e-12\n").unwrap();
    refused(
        &["report", s(&study), "--config", s(&rcfg)],
        "`report.iid_bin_cm` = 1e-12: makes 1e14 bins",
    );
    // An absurd number is named as typed, not in three hundred digits.
    refused(
        &["bench", "ood", "--seconds", "1e300"],
        "--seconds must lie in [0.1, 600], got 1e300",
    );
    refused(
        &["bench", "observer", "--seconds", "1e300"],
        "--seconds must lie in [1, 600], got 1e300",
    );
    refused(&["bench", "sim", "--envs", "0"], "--envs must lie in");
    refused(
        &["bench", "train", "--iterations", "1000000"],
        "--iterations must lie in",
    );
    refused(
        &[
            "train",
            "--model",
            "Zone",
            "--steps",
            "0",
            "--out",
            s(&d.join("t0")),
        ],
        "total_timesteps",
    );
    refused(
        &[
            "train",
            "--model",
            "Zone",
            "--steps",
            "99999999999999",
            "--out",
            s(&d.join("t1")),
        ],
        "total_timesteps",
    );
    // Values clap cannot parse are its errors (exit 2), not panics.
    refused(
        &[
            "train",
            "--model",
            "Zone",
            "--steps",
            "1e99",
            "--out",
            s(&d.join("t2")),
        ],
        "invalid value",
    );
    refused(&["run", "--jobs", "-3"], "unexpected argument");
    // A network of 100,000 x 100,000 units is refused, not allocated (40 GB).
    let ppo = d.join("huge.toml");
    std::fs::write(&ppo, "hidden = [100000, 100000]\n").unwrap();
    refused(
        &[
            "train",
            "--model",
            "Zone",
            "--preset",
            "smoke",
            "--ppo",
            s(&ppo),
            "--out",
            s(&d.join("t3")),
        ],
        "needs 1 to 8 layers of 1 to 4096 units",
    );
    let settings = d.join("settings.toml");
    std::fs::write(&settings, "frame_rate_hz = 1e30\n").unwrap();
    refused(&["config", "check", s(&settings)], "frame_rate_hz");
    refused(
        &[
            "live",
            "serve",
            "--policy",
            "scripted:goal-seeker",
            "--token",
            "",
            "--out",
            s(&out),
        ],
        "token",
    );
}

/// The subcommands not covered above: each with a value that cannot work.
#[test]
fn every_other_subcommand_refuses_cleanly() {
    let d = fresh_dir("hostile-rest");
    let nowhere = d.join("nowhere");
    let study = d.join("study");
    std::fs::create_dir_all(study.join("rollouts")).unwrap();
    refused(&["report", s(&nowhere)], "no such study directory");
    refused(&["report", s(&d)], "not a study directory");
    // An existing file where a directory belongs: as a study, and as (or on the way to) an
    // output directory. The file is named, and left as it was.
    let file = d.join("results.csv");
    std::fs::write(&file, "a,b\n").unwrap();
    for sub in ["analyze", "report"] {
        refused(&[sub, s(&file)], "a file, not a study directory");
    }
    for out in [file.clone(), file.join("sub")] {
        refused(
            &[
                "train",
                "--model",
                "Follow",
                "--preset",
                "smoke",
                "--out",
                s(&out),
            ],
            "results.csv: exists and is not a directory",
        );
    }
    assert_eq!(std::fs::read_to_string(&file).unwrap(), "a,b\n");
    refused(
        &["report", s(&study), "--jobs", "0"],
        "--jobs must be at least 1",
    );
    refused(
        &[
            "fit-convnet",
            "--data",
            s(&nowhere),
            "--validation",
            s(&nowhere),
            "--out",
            s(&d.join("w.safetensors")),
            "--max-epochs",
            "0",
        ],
        "max_epochs",
    );
    refused(
        &[
            "fit-convnet",
            "--data",
            s(&nowhere),
            "--validation",
            s(&nowhere),
            "--out",
            s(&d.join("w.safetensors")),
            "--max-epochs",
            "99999999999",
        ],
        "max_epochs",
    );
    refused(
        &[
            "compare-offline",
            "--data",
            s(&nowhere),
            "--out",
            s(&d.join("c")),
            "--reps",
            "99999999999",
        ],
        "bootstrap_reps",
    );
    refused(
        &[
            "compare-offline",
            "--data",
            s(&nowhere),
            "--out",
            s(&d.join("c")),
            "--jobs",
            "0",
        ],
        "no trial files",
    );
    refused(
        &["import-legacy", s(&nowhere), "--out", s(&d.join("i"))],
        "nowhere",
    );
    refused(
        &[
            "export",
            "--policy",
            s(&nowhere),
            "--onnx",
            s(&d.join("p.onnx")),
        ],
        "nowhere",
    );
    refused(
        &["live", "replay", s(&nowhere), "--connect", "127.0.0.1:9"],
        "nowhere",
    );
    refused(&["inspect", s(&nowhere)], "nowhere");
    refused(
        &["models", "--measure", "--episodes", "0"],
        "--episodes must lie in",
    );
    refused(&["config", "check", s(&nowhere)], "nowhere");
    refused(
        &["analyze", s(&study), "--sim-trials", "99999999999"],
        "sim_trials",
    );
}

/// A wrong file given as settings: a device that never ends, a large file, a minified one.
/// Each is refused without reading it all or printing it back.
#[test]
fn a_wrong_settings_file_is_refused_short() {
    let d = fresh_dir("hostile-settings");
    let big = d.join("big.toml");
    std::fs::write(&big, vec![b'#'; (17 << 20) as usize]).unwrap();
    // One line of 200,000 characters with a parse error at its end.
    let long = d.join("long.toml");
    let n = 50_000;
    std::fs::write(
        &long,
        format!("a = {}{}\n", "[".repeat(n), "]".repeat(n - 1)),
    )
    .unwrap();
    let out = d.join("t");
    for (flag, sub) in [("--settings", "train"), ("--config", "run")] {
        let mut args = vec![sub, flag];
        #[cfg(unix)]
        {
            args.push("/dev/zero");
            args.extend(["--out", s(&out)]);
            refused(&args, "larger than 16.0 MiB");
            args.truncate(2);
        }
        args.extend([s(&big), "--out", s(&out)]);
        refused(&args, "larger than 16.0 MiB");
    }
    for args in [
        vec!["train", "--settings", s(&long), "--out", s(&out)],
        vec!["run", "--config", s(&long), "--out", s(&out)],
        vec!["report", s(&d), "--config", s(&long)],
    ] {
        let o = run_within(&args, Duration::from_secs(60));
        let err = stderr(&o);
        assert_eq!(o.status.code(), Some(1), "{args:?}: {err}");
        assert!(err.contains("line 1, column"), "{args:?}: {err}");
        assert!(err.len() < 2_000, "{args:?} printed {} bytes", err.len());
    }
    refused(&["config", "check", "/dev/zero"], "larger than 16.0 MiB");
}

/// A weights, sidecar or support file that is a device that never ends (here /dev/zero
/// through a symbolic link) is refused at its limit, not read until memory runs out.
#[cfg(unix)]
#[test]
fn an_endless_model_file_is_refused_at_its_limit() {
    use std::os::unix::fs::symlink;
    let d = fresh_dir("hostile-weights");
    let assets = Path::new(env!("CARGO_MANIFEST_DIR")).join("../models/assets");
    // Real weights whose sidecar never ends.
    let w = d.join("w.safetensors");
    std::fs::copy(assets.join("convnet.safetensors"), &w).unwrap();
    symlink("/dev/zero", d.join("w.safetensors.json")).unwrap();
    // Real weights and sidecar whose support file never ends.
    let v = d.join("v.safetensors");
    std::fs::copy(assets.join("convnet.safetensors"), &v).unwrap();
    std::fs::copy(
        assets.join("convnet.safetensors.json"),
        d.join("v.safetensors.json"),
    )
    .unwrap();
    symlink("/dev/zero", d.join("v.safetensors.support.json")).unwrap();
    let out = d.join("t");
    let zero = "convnet:/dev/zero";
    let sidecar = format!("convnet:{}", s(&w));
    let support = format!("convnet:{}", s(&v));
    for (args, needle) in [
        (
            vec!["train", "--model", zero, "--out", s(&out)],
            "larger than 512.0 MiB",
        ),
        (vec!["support", "--model", zero], "larger than 512.0 MiB"),
        (
            vec!["train", "--model", &sidecar, "--out", s(&out)],
            "larger than 16.0 MiB",
        ),
        (
            vec![
                "train",
                "--model",
                &support,
                "--task",
                "ood",
                "--out",
                s(&out),
            ],
            "larger than 64.0 MiB",
        ),
        (
            vec!["train", "--model", "onnx:/dev/zero", "--out", s(&out)],
            "not a regular file",
        ),
    ] {
        refused(&args, needle);
    }
}

/// A bridge that answers with a line that never ends: the virtual lab (`lab --connect`) and
/// `live replay` refuse it once the line passes their limit, instead of reading it into memory.
#[test]
fn a_bridge_whose_line_never_ends_is_refused() {
    use std::io::Write;
    let listener = std::net::TcpListener::bind("127.0.0.1:0").unwrap();
    let addr = listener.local_addr().unwrap().to_string();
    std::thread::spawn(move || {
        for mut conn in listener.incoming().map_while(Result::ok) {
            std::thread::spawn(move || {
                let chunk = [b'x'; 65_536];
                // Until the client hangs up.
                while conn.write_all(&chunk).is_ok() {}
            });
        }
    });
    let d = fresh_dir("hostile-bridge");
    let trial = d.join("trial.hdf5");
    let o = run_within(
        &["simulate", "--minutes", "0.05", "--out", s(&trial)],
        Duration::from_secs(60),
    );
    assert!(o.status.success(), "{}", stderr(&o));
    let lab = d.join("lab");
    for args in [
        vec![
            "lab",
            "--policy",
            "scripted:goal-seeker",
            "--connect",
            &addr,
            "--out",
            s(&lab),
        ],
        vec!["live", "replay", s(&trial), "--connect", &addr],
    ] {
        refused(&args, "a line longer than 65536 bytes");
    }
}

/// A list option naming one value twice would count one run (a seed of the loop, a cell of
/// the sweep) or one row twice; each is refused before any work.
#[test]
fn a_value_named_twice_is_refused() {
    let d = fresh_dir("hostile-repeats");
    let out = d.join("o");
    for (args, needle) in [
        (
            vec!["ood-loop", "--out", s(&out), "--seeds", "0", "1", "0"],
            "--seeds names 0 twice",
        ),
        (
            vec![
                "fidelity",
                "--readings",
                "baseline,baseline",
                "--out",
                s(&out),
            ],
            "--readings names baseline twice",
        ),
        (
            vec!["fidelity", "--models", "Zone,Zone", "--out", s(&out)],
            "--models names Zone twice",
        ),
        (
            vec![
                "compare-offline",
                "--models",
                "Zone,Force,Zone",
                "--out",
                s(&out),
            ],
            "--models names Zone twice",
        ),
        (
            vec!["models", "--model", "Zone", "--model", "Zone"],
            "--model names Zone twice",
        ),
    ] {
        refused(&args, needle);
    }
    assert!(
        !out.exists(),
        "a refused command wrote its output directory"
    );
}

#[test]
fn too_many_jobs_are_capped_with_a_note() {
    let d = fresh_dir("hostile-jobs");
    let start = Instant::now();
    let o = run_within(
        &[
            "train",
            "--model",
            "Follow",
            "--preset",
            "smoke",
            "--jobs",
            "100000",
            "--out",
            s(&d.join("t")),
        ],
        Duration::from_secs(120),
    );
    let err = stderr(&o);
    assert!(o.status.success(), "{err}");
    assert!(err.contains("--jobs 100000 capped to"), "{err}");
    assert!(start.elapsed() < Duration::from_secs(120));
}

#[cfg(unix)]
#[test]
fn a_full_stdout_and_stderr_is_an_error_not_a_panic() {
    let Some(data) = fishprobe_io::shared_data_dir() else {
        eprintln!("skipping: FISHPROBE_DATA is not set and ../shared/data is absent");
        return;
    };
    let example = data.join("examples/example.hdf5");
    assert!(example.is_file(), "{} missing", example.display());
    let full = std::fs::OpenOptions::new()
        .write(true)
        .open("/dev/full")
        .unwrap();
    let o = Command::new(env!("CARGO_BIN_EXE_fishprobe"))
        .args(["inspect", s(&example)])
        .stdout(full.try_clone().unwrap())
        .stderr(full)
        .status()
        .unwrap();
    assert_eq!(o.code(), Some(1), "{o:?}");
}

/// A policy whose weights are NaN is refused by the bridge and the virtual lab before any
/// trial (the bridge would also stop the robot on its first non-finite turn).
#[test]
fn a_policy_with_nan_weights_is_refused_by_the_bridge() {
    let d = fresh_dir("hostile-nan-policy");
    let policy = d.join("p");
    let o = run_within(
        &[
            "train",
            "--model",
            "Follow",
            "--preset",
            "smoke",
            "--out",
            s(&policy),
        ],
        Duration::from_secs(120),
    );
    assert!(o.status.success(), "{}", stderr(&o));
    // safetensors: an 8-byte header length, the JSON header, then the raw floats.
    let file = policy.join("policy.safetensors");
    let mut bytes = std::fs::read(&file).unwrap();
    let header = u64::from_le_bytes(bytes[..8].try_into().unwrap()) as usize;
    bytes[8 + header..].fill(0xff);
    std::fs::write(&file, bytes).unwrap();
    refused(
        &["lab", "--policy", s(&policy), "--out", s(&d.join("lab"))],
        "non-finite weights",
    );
}

/// Model names that would share a directory with the study's own (the reality arms), with
/// each other on a case-insensitive file system, or split at the arm separator are refused
/// before any work starts, naming the clash; the output directory stays empty.
#[test]
fn model_names_that_collide_with_the_layout_are_refused_before_any_work() {
    let d = fresh_dir("hostile-names");
    let study = |name: &str, spec: &str| {
        format!(
            "preset = \"smoke\"\n[[extra_models]]\nname = \"{name}\"\nspec = {{ model = \"{spec}\" }}\n"
        )
    };
    let mut cases: Vec<(String, String, &str)> = Vec::new();
    for reserved in fishprobe_io::layout::RESERVED_NAMES {
        for n in [
            reserved.to_string(),
            reserved.to_lowercase(),
            reserved.to_uppercase(),
        ] {
            cases.push((n, "Zone".into(), "reserved"));
        }
    }
    cases.push(("zone".into(), "Zone".into(), "differ only in case"));
    cases.push(("Zone_".into(), "Zone".into(), "trailing '_'"));
    cases.push(("_Zone".into(), "Zone".into(), "leading or trailing"));
    cases.push(("a__b".into(), "Zone".into(), "separates policy and model"));
    for (i, (name, spec, needle)) in cases.iter().enumerate() {
        let file = d.join(format!("s{i}.toml"));
        std::fs::write(&file, study(name, spec)).unwrap();
        let out = d.join(format!("out{i}"));
        let o = run_within(
            &["run", "--config", s(&file), "--out", s(&out)],
            Duration::from_secs(60),
        );
        let err = stderr(&o);
        assert_eq!(o.status.code(), Some(1), "{name}: {err}");
        assert!(
            err.contains(needle) && err.contains(&format!("`{name}`")),
            "{name}: {err}"
        );
        let left = std::fs::read_dir(&out).map_or(0, |r| r.count());
        assert_eq!(left, 0, "{name}: the refused study wrote into {out:?}");
    }
}
