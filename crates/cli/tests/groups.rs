//! Groups from the command line: Couzin's phase picture, M_Force's order over
//! alignment, the simulation benchmark with a group, and their refusals.

#![allow(clippy::unwrap_used)] // a failure is a test failure

mod common;

use common::{fishprobe, fresh_dir, stderr, stdout};

#[test]
fn collective_draws_the_phase_picture_and_writes_its_numbers() {
    let dir = fresh_dir("collective");
    let out = dir.join("phase");
    let o = fishprobe(&[
        "collective",
        "--fish",
        "20",
        "--seconds",
        "20",
        "--seeds",
        "1",
        "--orientation",
        "0,30",
        "--attraction",
        "4,28",
        "--out",
        out.to_str().unwrap(),
    ]);
    assert!(o.status.success(), "{}", stderr(&o));
    let text = stdout(&o);
    assert!(text.contains("highly parallel"), "{text}");
    // Δr_o = 0 with a 4-cm attraction zone cannot hold the group: it falls apart, and is
    // called so rather than by its fragments' order parameters.
    assert!(text.contains("fragmented"), "{text}");
    for f in [
        "collective-phase.svg",
        "collective-phase.png",
        "collective.json",
    ] {
        assert!(out.join(f).is_file(), "{f} missing");
    }
    let grid: serde_json::Value =
        serde_json::from_slice(&std::fs::read(out.join("collective.json")).unwrap()).unwrap();
    assert_eq!(grid["cells"].as_array().unwrap().len(), 4);
    // Δr_o = 30 cm: everyone aligns with everyone: polarised, together.
    let p = grid["cells"][3][0]["polarisation"].as_f64().unwrap();
    assert!(p > 0.9, "{p}");
    assert!(grid["cells"][3][0]["cohesion"].as_f64().unwrap() > 0.9);
    assert!(grid["cells"][0][0]["cohesion"].as_f64().unwrap() < 0.5);
    assert_eq!(grid["cohesive_share"].as_f64(), Some(0.9));

    let o = fishprobe(&[
        "collective",
        "--model",
        "force",
        "--fish",
        "10",
        "--seconds",
        "10",
        "--seeds",
        "1",
        "--alignment",
        "0,0.6",
        "--json",
    ]);
    assert!(o.status.success(), "{}", stderr(&o));
    let rows: serde_json::Value = serde_json::from_str(&stdout(&o)).unwrap();
    assert_eq!(rows.as_array().unwrap().len(), 2);
}

#[test]
fn collective_and_bench_refuse_bad_groups() {
    for (args, needle) in [
        (vec!["collective", "--fish", "1"], "fish"),
        (vec!["collective", "--fish", "100000"], "fish"),
        (vec!["collective", "--turn-rate", "fast"], "turn_rate"),
        (vec!["collective", "--seeds", "0"], "seeds must lie in"),
        (
            vec!["collective", "--orientation=-1", "--seconds", "1"],
            "orientation_zone_cm",
        ),
        (vec!["collective", "--seconds", "nan"], "seconds"),
        // A flag of the other model's sweep would be ignored: refused.
        (
            vec!["collective", "--alignment", "0.5"],
            "set model to force",
        ),
        (
            vec!["collective", "--model", "force", "--orientation", "1"],
            "orientation sweeps M_Zone",
        ),
        (
            vec!["collective", "--model", "force", "--alignment", "2.5"],
            "must lie in [0, 2]",
        ),
        (
            vec!["bench", "sim", "--fish", "17", "--seconds", "0.1"],
            "fish_count",
        ),
        (
            vec!["bench", "sim", "--fish", "0", "--seconds", "0.1"],
            "fish_count",
        ),
    ] {
        let o = fishprobe(&args);
        assert!(!o.status.success(), "{args:?} succeeded");
        let e = stderr(&o);
        assert!(e.contains(needle), "{args:?}: {e}");
        assert!(!e.contains("panicked"), "{args:?}: {e}");
    }
}

#[test]
fn a_study_with_groups_runs_end_to_end_through_the_virtual_lab() {
    let dir = fresh_dir("group-study");
    let cfg = dir.join("groups.toml");
    std::fs::write(
        &cfg,
        "fish_count = 3\ngroup_goal = \"centroid\"\ncentroid_bins = true\nepisode_minutes = 1.5\nextra_seeds = 0\n\
         models = [{ name = \"Zone\", spec = { model = \"Zone\" } }, \
         { name = \"Follow\", spec = { model = \"Follow\" } }]\n",
    )
    .unwrap();
    let out = dir.join("study");
    let start = std::time::Instant::now();
    let o = fishprobe(&[
        "run",
        "--preset",
        "smoke",
        "--config",
        cfg.to_str().unwrap(),
        "--out",
        out.to_str().unwrap(),
    ]);
    eprintln!("group study: {:.1} s", start.elapsed().as_secs_f64());
    assert!(o.status.success(), "{}", stderr(&o));
    // Trial files of the simulation and of the virtual lab hold three fish.
    for arm in [
        "rollouts/Zone__Zone/trial_000.hdf5",
        "rollouts/Zone__VirtualLab/trial_000.hdf5",
    ] {
        let o = fishprobe(&["inspect", out.join(arm).to_str().unwrap()]);
        let text = stdout(&o);
        assert!(
            text.contains("fish_3") && !text.contains("fish_4"),
            "{arm}: {text}"
        );
    }
    // The analysis has the group metrics' sim-to-real gaps; the report draws every fish.
    let r: serde_json::Value =
        serde_json::from_slice(&std::fs::read(out.join("analysis/results.json")).unwrap()).unwrap();
    for m in [
        "polarisation",
        "milling",
        "mean_nnd",
        "fish_near_robot",
        "iid",
    ] {
        assert!(r["metric_gaps"][m]["Zone"]["median"].is_number(), "{m}");
    }
    assert!(out.join("report/index.html").is_file());

    // A group size the tank does not take is refused before any work.
    std::fs::write(&cfg, "fish_count = 17\n").unwrap();
    let bad = dir.join("bad");
    let o = fishprobe(&[
        "run",
        "--preset",
        "smoke",
        "--config",
        cfg.to_str().unwrap(),
        "--out",
        bad.to_str().unwrap(),
    ]);
    assert!(!o.status.success());
    assert!(stderr(&o).contains("fish_count"), "{}", stderr(&o));
    assert!(!bad.exists(), "work started despite a bad group size");
}

#[test]
fn a_policy_with_centroid_bins_trains_and_evaluates_with_its_settings_only() {
    let dir = fresh_dir("centroid-bins");
    let settings = dir.join("group.toml");
    std::fs::write(
        &settings,
        "[env]\nfish_count = 4\n\n[env.task]\ngroup_goal = \"centroid\"\n\n\
         [env.observation]\ncentroid_bins = true\n",
    )
    .unwrap();
    let (pol, s) = (dir.join("pol"), settings.to_str().unwrap());
    let o = fishprobe(&[
        "train",
        "--model",
        "Zone",
        "--preset",
        "smoke",
        "--steps",
        "2048",
        "--settings",
        s,
        "--out",
        pol.to_str().unwrap(),
    ]);
    assert!(o.status.success(), "{}", stderr(&o));
    let eval = |with: bool, out: &str| {
        let out = dir.join(out);
        let mut args = vec![
            "evaluate",
            "--policy",
            pol.to_str().unwrap(),
            "--model",
            "Zone",
            "--episodes",
            "1",
            "--minutes",
            "0.2",
            "--out",
            out.to_str().unwrap(),
        ];
        if with {
            args.extend(["--settings", s]);
        }
        fishprobe(&args)
    };
    let o = eval(true, "ok");
    assert!(o.status.success(), "{}", stderr(&o));
    let o = eval(false, "bad");
    assert!(!o.status.success());
    assert!(
        stderr(&o).contains("216") && stderr(&o).contains("180"),
        "{}",
        stderr(&o)
    );
    // The approach assay observes the still fish as the policy was trained to.
    let o = fishprobe(&[
        "assay",
        "approach",
        "--policy",
        pol.to_str().unwrap(),
        "--episodes",
        "1",
        "--minutes",
        "0.2",
        "--json",
    ]);
    assert!(o.status.success(), "{}", stderr(&o));
    assert!(stdout(&o).contains("\"goes_to_fish\""), "{}", stdout(&o));
}

#[test]
fn the_virtual_lab_runs_a_group_through_its_bridge() {
    let dir = fresh_dir("lab-group");
    let out = dir.join("lab");
    let o = fishprobe(&[
        "lab",
        "--policy",
        "scripted:fetch-and-lead",
        "--fish",
        "3",
        "--group-goal",
        "centroid",
        "--minutes",
        "0.3",
        "--out",
        out.to_str().unwrap(),
    ]);
    assert!(o.status.success(), "{}", stderr(&o));
    assert!(
        stdout(&o).contains("fish-frames with a fish lost"),
        "{}",
        stdout(&o)
    );
    let file = out.join("FetchAndLead__VirtualLab/trial_000.hdf5");
    let o = fishprobe(&["inspect", file.to_str().unwrap()]);
    let text = stdout(&o);
    assert!(
        text.contains("fish_3") && !text.contains("fish_4"),
        "{text}"
    );
    let o = fishprobe(&[
        "lab",
        "--policy",
        "scripted:goal-seeker",
        "--fish",
        "17",
        "--out",
        out.to_str().unwrap(),
    ]);
    assert!(!o.status.success());
    assert!(stderr(&o).contains("fish_count"), "{}", stderr(&o));
}

#[test]
fn simulate_writes_a_group_trial() {
    let dir = fresh_dir("simulate-group");
    let settings = dir.join("group.toml");
    std::fs::write(&settings, "[env]\nfish_count = 5\n").unwrap();
    let file = dir.join("group.hdf5");
    let o = fishprobe(&[
        "simulate",
        "--model",
        "Zone",
        "--settings",
        settings.to_str().unwrap(),
        "--minutes",
        "1.2",
        "--out",
        file.to_str().unwrap(),
    ]);
    assert!(o.status.success(), "{}", stderr(&o));
    let o = fishprobe(&["inspect", file.to_str().unwrap()]);
    assert!(stdout(&o).contains("fish_5"), "{}", stdout(&o));
    std::fs::write(&settings, "[env]\nfish_count = 0\n").unwrap();
    let o = fishprobe(&[
        "simulate",
        "--settings",
        settings.to_str().unwrap(),
        "--out",
        dir.join("x.hdf5").to_str().unwrap(),
    ]);
    assert!(!o.status.success());
    assert!(stderr(&o).contains("fish_count"), "{}", stderr(&o));
}
