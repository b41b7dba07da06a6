//! End-to-end tests of the `fishprobe` binary with tiny budgets.

mod common;

use common::{fishprobe, fresh_dir, stderr, stdout, train_smoke, Scratch};
use std::path::PathBuf;
use std::sync::OnceLock;

/// A small input file in this test binary's shared directory (the next run removes it).
fn temp_file(name: &str, text: &str) -> PathBuf {
    static DIR: OnceLock<PathBuf> = OnceLock::new();
    let p = DIR.get_or_init(|| Scratch::for_process("cli")).join(name);
    std::fs::write(&p, text).expect("the temp dir is writable");
    p
}

#[test]
fn help_lists_the_subcommands() {
    let o = fishprobe(&["--help"]);
    assert!(o.status.success());
    for cmd in ["models", "bench", "config"] {
        assert!(stdout(&o).contains(cmd), "{}", stdout(&o));
    }
}

#[test]
fn models_lists_every_model_with_published_defaults() {
    let o = fishprobe(&["models"]);
    assert!(o.status.success(), "{}", stderr(&o));
    let text = stdout(&o);
    for needle in [
        "Follow",
        "Zone",
        "Force",
        "Stationary",
        "wall_repulsion_strength",
        "40.51",
        "8.39",
    ] {
        assert!(text.contains(needle), "missing {needle}");
    }
    let o = fishprobe(&["models", "--json"]);
    let v: serde_json::Value = serde_json::from_slice(&o.stdout).unwrap();
    let zone = &v["models"][1];
    assert_eq!(zone["name"], "Zone");
    assert_eq!(zone["params"]["speed_cm_s"], 6.3);
    assert_eq!(zone["params"]["zone_convention"], "widths");
    let force = &v["models"][2];
    assert_eq!(force["params"]["wall_outward_angle_factor"], -0.7);
    assert_eq!(force["params"]["noise_convention"], "per_second");
    assert!(force["fields"]
        .as_array()
        .unwrap()
        .iter()
        .all(|f| !f["doc"].as_str().unwrap().is_empty()));
}

#[test]
fn models_measure_reports_distributions() {
    let o = fishprobe(&[
        "models",
        "--measure",
        "--json",
        "--episodes",
        "1",
        "--minutes",
        "0.5",
    ]);
    assert!(o.status.success(), "{}", stderr(&o));
    let v: serde_json::Value = serde_json::from_slice(&o.stdout).unwrap();
    let ms = v["measurements"].as_array().unwrap();
    let names: Vec<&str> = v["models"]
        .as_array()
        .unwrap()
        .iter()
        .map(|m| m["candidate"].as_str().unwrap())
        .filter(|n| *n != "Stationary")
        .collect();
    // The paper's four, the virtual guppy and the fitted populations, each in 2 conditions,
    // under the name it is listed by.
    assert!(names.len() >= 5 && names.contains(&"ZonePop"), "{names:?}");
    assert_eq!(ms.len(), 2 * names.len());
    for n in &names {
        assert_eq!(ms.iter().filter(|m| m["model"] == *n).count(), 2, "{n}");
    }
    let zone_alone = ms
        .iter()
        .find(|m| m["model"] == "Zone" && m["condition"] == "solitary")
        .unwrap();
    let mean_speed = zone_alone["speed"]["mean"].as_f64().unwrap();
    assert!((mean_speed - 6.3).abs() < 0.3, "{mean_speed}");
    let bad = fishprobe(&["models", "--measure", "--minutes=-1"]);
    assert!(!bad.status.success());
    assert!(stderr(&bad).contains("--minutes"), "{}", stderr(&bad));
}

#[test]
fn bench_sim_prints_throughput_and_machine() {
    let o = fishprobe(&["bench", "sim", "--json", "--seconds", "0.05", "--envs", "4"]);
    assert!(o.status.success(), "{}", stderr(&o));
    let v: serde_json::Value = serde_json::from_slice(&o.stdout).unwrap();
    assert!(v["machine"]["cores"].as_u64().unwrap() >= 1);
    let rows = v["results"].as_array().unwrap();
    assert_eq!(rows.len(), 6);
    for r in rows {
        assert!(r["frames_per_s"].as_f64().unwrap() > 1000.0, "{r}");
        let ratio = r["frames_per_s"].as_f64().unwrap() / r["policy_steps_per_s"].as_f64().unwrap();
        assert!((ratio - 25.0).abs() < 1e-6);
    }
    let text = fishprobe(&["bench", "sim", "--seconds", "0.05", "--envs", "2"]);
    assert!(stdout(&text).contains("frames/s per core"));
}

#[test]
fn bench_observer_measures_update_round_trips_and_the_components_cpu() {
    let o = fishprobe(&["bench", "observer", "--json", "--seconds", "1"]);
    assert!(o.status.success(), "{}", stderr(&o));
    let v: serde_json::Value = serde_json::from_slice(&o.stdout).unwrap();
    let rows = v["rows"].as_array().unwrap();
    assert_eq!(rows.len(), 2);
    // At 25 Hz for a second: about 25 updates, each answered, the slowest no faster than the
    // median; the component used CPU, less than the whole machine.
    let paced = &rows[0];
    let n = paced["updates"].as_u64().unwrap();
    assert!((20..=30).contains(&n), "{paced}");
    let (p50, p99) = (
        paced["p50_us"].as_f64().unwrap(),
        paced["p99_us"].as_f64().unwrap(),
    );
    assert!(p50 > 0.0 && p99 >= p50, "{paced}");
    // The kernel counts CPU time in 10 ms ticks: a second at 25 Hz may show none.
    let cpu = paced["cpu_share_of_one_core"].as_f64().unwrap();
    assert!((0.0..2.0).contains(&cpu), "{paced}");
    let flooded = rows[1]["cpu_share_of_one_core"].as_f64().unwrap();
    assert!(flooded > 0.0 && flooded < 2.0, "{}", rows[1]);
    // Unpaced, the core's calls come far faster than the tracker's rate.
    assert!(
        rows[1]["updates_per_s"].as_f64().unwrap() > 100.0,
        "{}",
        rows[1]
    );
    assert!(v["command"]
        .as_str()
        .unwrap()
        .starts_with("fishprobe bench observer"));
}

#[test]
fn config_show_round_trips_through_check() {
    for (flag, ext) in [("--toml", "toml"), ("--json", "json")] {
        let args: Vec<&str> = if flag == "--toml" {
            vec!["config", "show", "--toml"]
        } else {
            vec!["config", "show"]
        };
        let shown = fishprobe(&args);
        assert!(shown.status.success());
        let p = temp_file(&format!("default.{ext}"), &stdout(&shown));
        let checked = fishprobe(&["config", "check", p.to_str().unwrap()]);
        assert!(checked.status.success(), "{}", stderr(&checked));
        assert!(stdout(&checked).contains("valid (Zone fish, training mode)"));
    }
}

#[test]
fn bad_settings_name_the_field_and_value() {
    let cases = [
        (
            "zero.toml",
            "[env.robot]\nmax_speed_cm_s = 0.0\n",
            "robot.max_speed_cm_s` = 0",
        ),
        (
            "nan.toml",
            "[env.task]\ngoal_radius_cm = nan\n",
            "task.goal_radius_cm` = NaN",
        ),
        (
            "neg.toml",
            "[fish]\nmodel = \"Zone\"\nrepulsion_zone_cm = -2\n",
            "Zone.repulsion_zone_cm` = -2",
        ),
        (
            "unknown.json",
            r#"{"env": {"robot": {"max_sped": 3}}}"#,
            "unknown field `max_sped`",
        ),
        ("model.toml", "[fish]\nmodel = \"Couzin\"\n", "Couzin"),
        ("garbage.json", "not json", "not valid settings JSON"),
    ];
    for (name, text, needle) in cases {
        let p = temp_file(name, text);
        let o = fishprobe(&["config", "check", p.to_str().unwrap()]);
        assert!(!o.status.success(), "{name} was accepted");
        assert!(stderr(&o).contains(needle), "{name}: {}", stderr(&o));
        assert!(!stderr(&o).contains("panicked"), "{name}: {}", stderr(&o));
    }
    let missing = fishprobe(&["config", "check", "/nonexistent/settings.toml"]);
    assert!(
        stderr(&missing).contains("cannot read settings file"),
        "{}",
        stderr(&missing)
    );
}

#[test]
fn simulate_writes_a_trial_that_inspect_reads() {
    let d = fresh_dir("sim");
    let f = d.join("follow.hdf5");
    let o = fishprobe(&[
        "simulate",
        "--model",
        "Follow",
        "--robot",
        "goals",
        "--minutes",
        "2",
        "--seed",
        "3",
        "--out",
        f.to_str().unwrap(),
    ]);
    assert!(o.status.success(), "{}", stderr(&o));
    assert!(stdout(&o).contains("3001 frames"), "{}", stdout(&o));
    let o = fishprobe(&["inspect", "--json", f.to_str().unwrap()]);
    assert!(o.status.success(), "{}", stderr(&o));
    let v: serde_json::Value = serde_json::from_slice(&o.stdout).unwrap();
    let file = &v["files"][0];
    assert_eq!(file["frame_rate_hz"], 25.0);
    assert_eq!(file["entities"].as_array().unwrap().len(), 2);
    let task = &file["task"];
    assert_eq!(task["kind"], "sim");
    assert_eq!(task["policy"], "scripted:goals");
    assert_eq!(task["fish_model"], "Follow");
    // A Follow fish trails the goal-to-goal robot into the goals.
    assert!(task["goals_reached"].as_u64().unwrap() >= 5, "{task}");
}

#[test]
fn simulate_is_deterministic_per_seed() {
    let d = fresh_dir("det");
    let run = |name: &str, seed: &str| {
        let p = d.join(name);
        let o = fishprobe(&[
            "simulate",
            "--model",
            "Force",
            "--robot",
            "circle",
            "--minutes",
            "1",
            "--seed",
            seed,
            "--out",
            p.to_str().unwrap(),
        ]);
        assert!(o.status.success(), "{}", stderr(&o));
        std::fs::read(p).unwrap()
    };
    let a = run("a.hdf5", "9");
    assert_eq!(a, run("b.hdf5", "9"), "same seed, different file");
    assert_ne!(a, run("c.hdf5", "10"), "different seed, same file");
}

#[test]
fn simulate_rejects_bad_arguments_before_work() {
    let d = fresh_dir("bad");
    let f = d.join("x.hdf5");
    let f = f.to_str().unwrap();
    for (args, needle) in [
        (vec!["--robot", "fly"], "unknown --robot `fly`"),
        (vec!["--model", "Couzin"], "unknown fish model `Couzin`"),
        (
            vec!["--minutes", "0"],
            "--minutes must lie in [1/60, 1440] minutes (one second to 24 hours)",
        ),
    ] {
        let mut all = vec!["simulate", "--out", f];
        all.extend(args);
        let o = fishprobe(&all);
        assert!(!o.status.success());
        assert!(stderr(&o).contains(needle), "{}", stderr(&o));
    }
    assert!(!std::path::Path::new(f).exists());
}

#[test]
fn inspect_reports_bad_files_and_continues() {
    let d = fresh_dir("insp");
    let good = d.join("good.hdf5");
    assert!(fishprobe(&[
        "simulate",
        "--minutes",
        "0.1",
        "--out",
        good.to_str().unwrap()
    ])
    .status
    .success());
    let bad = temp_file("bad.hdf5", "not hdf5 at all");
    let o = fishprobe(&["inspect", bad.to_str().unwrap(), good.to_str().unwrap()]);
    assert!(
        !o.status.success(),
        "a failed file makes the exit code non-zero"
    );
    assert!(
        stderr(&o).contains("bad.hdf5: not an HDF5 file"),
        "{}",
        stderr(&o)
    );
    assert!(
        stdout(&o).contains("good.hdf5"),
        "continued with the next file: {}",
        stdout(&o)
    );
}

#[test]
fn import_legacy_converts_the_validation_split() {
    let Some(data) = fishprobe_io::shared_data_dir() else {
        eprintln!("skipping: FISHPROBE_DATA is not set and ../shared/data is absent");
        return;
    };
    let d = fresh_dir("legacy");
    let input = data.join("guppy-pairs/legacy/validation");
    let o = fishprobe(&[
        "import-legacy",
        input.to_str().unwrap(),
        "--out",
        d.to_str().unwrap(),
    ]);
    assert!(o.status.success(), "{}", stderr(&o));
    assert!(stdout(&o).contains("converted 5 of 5"), "{}", stdout(&o));
    // The trial files (the directory also holds the hidden one-writer lock).
    let converted = fishprobe_io::trial_files(&d);
    assert_eq!(converted.len(), 5);
    for p in converted {
        let ours = fishprobe_io::read_trial(&p).unwrap();
        let theirs = fishprobe_io::read_trial(
            &data
                .join("guppy-pairs/robofish-io")
                .join(p.file_name().unwrap()),
        )
        .unwrap();
        for (a, b) in ours.entities.iter().zip(&theirs.entities) {
            assert!(a
                .positions
                .iter()
                .flatten()
                .zip(b.positions.iter().flatten())
                .all(|(x, y)| x.to_bits() == y.to_bits()));
        }
    }
    let o = fishprobe(&[
        "import-legacy",
        "/nonexistent/file.hdf5",
        "--out",
        d.to_str().unwrap(),
    ]);
    assert!(!o.status.success());
    assert!(
        stderr(&o).contains("/nonexistent/file.hdf5"),
        "{}",
        stderr(&o)
    );
}

/// `fishprobe assay approach` for one policy: the goal-seeker ignores the fish, so it is never
/// nearer the fish than the goal, and the JSON carries every measure.
#[test]
fn the_approach_assay_of_one_policy() {
    let o = fishprobe(&[
        "assay",
        "approach",
        "--policy",
        "scripted:goal-seeker",
        "--episodes",
        "3",
        "--json",
    ]);
    assert!(o.status.success(), "{}", stderr(&o));
    let v: serde_json::Value = serde_json::from_str(&stdout(&o)).unwrap();
    assert_eq!(v["episodes"], 3);
    assert_eq!(v["fraction_nearer_fish_than_goal"], 0.0);
    let closest = v["closest_cm"].as_f64().unwrap();
    let mean = v["mean_distance_cm"].as_f64().unwrap();
    assert!(closest > 20.0 && mean >= closest, "{v}");
    assert_eq!(v["goes_to_fish"], false, "{v}");
    // Fetch-and-lead swims to the still fish and waits 12 cm ahead of it, nearer it than the
    // goal all the time: not the paper's pattern by the study's thresholds (closest at most
    // 10 cm), but by a settings file's wider one.
    let fetch = [
        "assay",
        "approach",
        "--policy",
        "scripted:fetch-and-lead",
        "--episodes",
        "3",
    ];
    // The assay with an `[analysis]` table (none: the study's thresholds).
    let assay = |table: Option<(&str, &str)>| match table {
        None => fishprobe(&fetch),
        Some((name, text)) => {
            let file = temp_file(name, &format!("[analysis]\n{text}\n"));
            fishprobe(&[&fetch[..], &["--settings", file.to_str().unwrap()]].concat())
        }
    };
    let says = |o: &std::process::Output, verdict: &str| {
        assert!(o.status.success(), "{}", stderr(o));
        assert!(stdout(o).contains(verdict), "{}", stdout(o));
    };
    says(&assay(None), "does not go to the still fish");
    says(
        &assay(Some(("wide.toml", "approach_closest_cm = 15.0"))),
        "\ngoes to the still fish",
    );
    let o = assay(Some(("nan.toml", "approach_nearer_share = nan")));
    assert!(
        !o.status.success() && stderr(&o).contains("analysis.approach_nearer_share"),
        "{}",
        stderr(&o)
    );
    let o = fishprobe(&[
        "assay",
        "approach",
        "--policy",
        "scripted:goal-seeker",
        "--episodes",
        "0",
    ]);
    assert!(!o.status.success() && stderr(&o).contains("--episodes"));
    // A scripted robot has no Gaussian to sample.
    let o = fishprobe(&[
        "assay",
        "approach",
        "--policy",
        "scripted:goal-seeker",
        "--stochastic",
    ]);
    assert!(
        !o.status.success() && stderr(&o).contains("--stochastic"),
        "{}",
        stderr(&o)
    );
    // With --out the episodes stay; a second assay into the same directory is refused, not
    // mixed with them.
    let out = fresh_dir("assay-out");
    let with_out = |policy: &str| {
        fishprobe(&[
            "assay",
            "approach",
            "--policy",
            policy,
            "--episodes",
            "2",
            "--minutes",
            "0.2",
            "--out",
            out.to_str().unwrap(),
        ])
    };
    let o = with_out("scripted:goal-seeker");
    assert!(o.status.success(), "{}", stderr(&o));
    assert!(out.join("approach_001.hdf5").is_file());
    let o = with_out("scripted:fetch-and-lead");
    assert!(
        !o.status.success() && stderr(&o).contains("already holds an evaluation (2 trial files"),
        "{}",
        stderr(&o)
    );
}

/// `--stochastic` runs the assay with the policy's sampled actions (RLlib's default when a
/// policy is deployed): other paths than its mean action's, and the JSON says which.
#[test]
fn the_approach_assay_samples_a_policy_on_request() {
    let dir = fresh_dir("assay-stochastic");
    let pol = dir.join("pol");
    train_smoke("Zone", &pol, &["--steps", "2048"]);
    let assay = |extra: &[&str]| {
        let args = [
            &["assay", "approach", "--policy", pol.to_str().unwrap()][..],
            &["--episodes", "2", "--minutes", "0.2", "--json"],
            extra,
        ]
        .concat();
        let o = fishprobe(&args);
        assert!(o.status.success(), "{}", stderr(&o));
        serde_json::from_str::<serde_json::Value>(&stdout(&o)).unwrap()
    };
    let (mean, sampled) = (assay(&[]), assay(&["--stochastic"]));
    assert_eq!(mean["stochastic"], false);
    assert_eq!(sampled["stochastic"], true);
    assert_ne!(
        mean["mean_distance_cm"], sampled["mean_distance_cm"],
        "{mean} {sampled}"
    );
    // The same seed samples the same actions.
    assert_eq!(sampled, assay(&["--stochastic"]));
}
