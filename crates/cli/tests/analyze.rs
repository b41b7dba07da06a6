//! End-to-end tests of `fishprobe analyze` on small synthetic studies.

#![allow(clippy::unwrap_used)] // a failure is a test failure

mod common;

use common::{fishprobe, fresh_dir as dir};
use fishprobe_io::{read_trial, write_trial};
use std::path::Path;

/// A small synthetic study (2 policies, 2-minute trials).
fn small_study(tag: &str) -> common::Scratch {
    let d = dir(tag);
    let o = fishprobe(&[
        "bench",
        "stats",
        "--size",
        "small",
        "--dir",
        d.to_str().unwrap(),
        "--json",
    ]);
    assert!(o.status.success(), "{}", String::from_utf8_lossy(&o.stderr));
    d
}

fn analyze(study: &Path, out: &Path, jobs: &str) -> serde_json::Value {
    let o = fishprobe(&[
        "analyze",
        study.to_str().unwrap(),
        "--out",
        out.to_str().unwrap(),
        "--quick",
        "--jobs",
        jobs,
        "--sim-trials",
        "6",
    ]);
    assert!(o.status.success(), "{}", String::from_utf8_lossy(&o.stderr));
    serde_json::from_str(&std::fs::read_to_string(out.join("results.json")).unwrap()).unwrap()
}

#[test]
fn every_section_is_computed_and_threads_do_not_matter() {
    let s = small_study("full");
    let r1 = analyze(&s, &s.join("a1"), "1");
    analyze(&s, &s.join("a2"), "2");
    let bytes = |p: &str| std::fs::read(s.join(p).join("results.json")).unwrap();
    assert_eq!(
        bytes("a1"),
        bytes("a2"),
        "results depend on the number of threads"
    );
    assert_eq!(r1["reality"], "Real");
    for p in ["Follow", "Zone"] {
        assert_eq!(r1["goals"][p]["sim"].as_array().unwrap().len(), 6);
        assert_eq!(r1["goals"][p]["real"].as_array().unwrap().len(), 6);
        let g = &r1["sim_to_real"][p];
        for k in ["w", "p", "cliffs_delta"] {
            assert!(g[k].is_number(), "{p} {k}: {g}");
        }
        assert!(g["ci"][0].as_f64().unwrap() <= g["ci"][1].as_f64().unwrap());
        assert!(r1["sim_to_sim"][p][p]["p_holm"].is_null());
        assert!(r1["kruskal"][p]["h"].is_number());
        assert!(r1["approach"][p]["min_iid"].is_number());
        assert!(r1["time_to_goal"][p]["sim"].is_object() || r1["time_to_goal"][p]["sim"].is_null());
    }
    assert_eq!(r1["metric_gaps"].as_object().unwrap().len(), 9);
    // The between-trial spread: goals, time to goal, paused fraction and the nine metrics.
    let spread = r1["spread"].as_object().unwrap();
    assert!(spread.len() >= 11, "{spread:?}");
    for p in ["Follow", "Zone"] {
        let e = &r1["spread"]["goals"][p];
        for k in [
            "sd_sim",
            "sd_real",
            "ratio",
            "w1_trials",
            "bf_stat",
            "bf_p",
            "bf_p_holm",
        ] {
            assert!(e[k].is_number() || e[k].is_null(), "{p} {k}: {e}");
        }
        assert_eq!(e["sim"].as_array().unwrap().len(), 6);
        let (sd_sim, sd_real) = (
            e["sd_sim"].as_f64().unwrap(),
            e["sd_real"].as_f64().unwrap(),
        );
        if sd_real > 0.0 {
            assert!((e["ratio"].as_f64().unwrap() - sd_sim / sd_real).abs() < 1e-12);
        }
        assert_eq!(e["ci"].as_array().unwrap().len(), 2);
        assert!(r1["spread"]["fish_speed"][p]["ratio"].as_f64().unwrap() > 0.0);
    }
    assert!(r1["temporal"]["sim"]["total"]["rate_ratio"].is_number());
    assert!(r1["stability"]["r"].is_number());
    // Only trends that do not exist are skipped: in 2-minute trials the scripted robot may
    // lead no Zone fish to a goal in some minute, and then the rate ratio has no MLE.
    for s in r1["skipped"].as_array().unwrap() {
        // And the spread of time to goal where too few trials reach a goal.
        let what = s["what"].as_str().unwrap();
        let reason = s["reason"].as_str().unwrap();
        if what.starts_with("spread time_to_goal/") {
            assert!(reason.contains("at least two a side"), "{s}");
            continue;
        }
        assert!(what.starts_with("temporal trend"), "{s}");
        assert!(
            reason.contains("all counts are zero") || reason.contains("may not exist"),
            "{s}"
        );
    }
    for f in [
        "goals.csv",
        "sim_to_real.csv",
        "metric_gaps.csv",
        "mean_ranks.csv",
        "spread.csv",
        "sim_to_sim.csv",
        "kruskal.csv",
        "temporal.csv",
        "time_to_goal.csv",
        "approach.csv",
        "stability.csv",
        "summary.md",
    ] {
        assert!(s.join("a1").join(f).is_file(), "{f} missing");
    }
}

#[test]
fn bad_input_is_skipped_with_reasons_and_the_rest_analysed() {
    let s = small_study("bad");
    let roll = s.join("rollouts");
    // A trial without a fish: the robot only.
    let good = roll.join("Follow__Follow/Follow__Follow_000.hdf5");
    let mut t = read_trial(&good).unwrap();
    t.entities.retain(|e| e.name == "robot");
    write_trial(&roll.join("Follow__Follow/zz_nofish.hdf5"), &t).unwrap();
    // A NaN-only fish in a real trial.
    let mut t = read_trial(&roll.join("Zone__Real/Zone__Real_000.hdf5")).unwrap();
    for e in &mut t.entities {
        if e.name == "fish_1" {
            e.positions.iter_mut().for_each(|p| *p = [f32::NAN; 2]);
        }
    }
    write_trial(&roll.join("Zone__Real/zz_nan.hdf5"), &t).unwrap();
    // An empty condition, and a policy with sim trials but no real ones.
    std::fs::create_dir_all(roll.join("Zone__Empty")).unwrap();
    std::fs::create_dir_all(roll.join("Extra__Extra")).unwrap();
    std::fs::copy(&good, roll.join("Extra__Extra/e.hdf5")).unwrap();
    // Not HDF5 at all.
    std::fs::write(roll.join("Follow__Real/broken.hdf5"), "garbage").unwrap();
    let r = analyze(&s, &s.join("out"), "2");
    let skipped = r["skipped"].to_string();
    for needle in [
        "zz_nofish.hdf5",
        "without a fish",
        "zz_nan.hdf5",
        "all NaN",
        "Zone__Empty",
        "Extra__Real",
        "no Real trials",
        "broken.hdf5",
        "not an HDF5 file",
    ] {
        assert!(skipped.contains(needle), "{needle} not in {skipped}");
    }
    // The valid trials are still analysed: 6 real trials of Zone remain (zz_nan sorts last).
    assert_eq!(r["goals"]["Zone"]["real"].as_array().unwrap().len(), 6);
    assert!(r["sim_to_real"]["Follow"]["w"].is_number());
}

/// Entries named `*.hdf5` that are no regular files are listed in `skipped` with the reason,
/// not silently dropped (which made n = 6 where 7 trials were meant).
#[cfg(unix)]
#[test]
fn entries_that_are_not_files_are_skipped_by_name() {
    use std::os::unix::fs::symlink;
    let s = small_study("notfiles");
    let real = s.join("rollouts/Follow__Real");
    symlink(real.join("nowhere.hdf5"), real.join("zz_dangling.hdf5")).unwrap();
    symlink(real.join("zz_loop_b.hdf5"), real.join("zz_loop_a.hdf5")).unwrap();
    symlink(real.join("zz_loop_a.hdf5"), real.join("zz_loop_b.hdf5")).unwrap();
    std::fs::create_dir_all(real.join("zz_directory.hdf5")).unwrap();
    symlink("/dev/zero", real.join("zz_zero.hdf5")).unwrap();
    let ok = std::process::Command::new("mkfifo")
        .arg(real.join("zz_fifo.hdf5"))
        .status()
        .unwrap()
        .success();
    assert!(ok);
    let r = analyze(&s, &s.join("out"), "2");
    let skipped = r["skipped"].to_string();
    for needle in [
        "zz_dangling.hdf5",
        "zz_loop_a.hdf5",
        "zz_loop_b.hdf5",
        "cannot be followed",
        "zz_directory.hdf5",
        "a directory, not a regular file",
        "zz_zero.hdf5",
        "a symbolic link to a device",
        "zz_fifo.hdf5",
        "FIFO",
    ] {
        assert!(skipped.contains(needle), "{needle} not in {skipped}");
    }
    assert_eq!(r["goals"]["Follow"]["real"].as_array().unwrap().len(), 6);
}

#[test]
fn a_virtual_lab_arm_is_labelled_virtual() {
    let s = small_study("virtual");
    for p in ["Follow", "Zone"] {
        std::fs::rename(
            s.join(format!("rollouts/{p}__Real")),
            s.join(format!("rollouts/{p}__VirtualLab")),
        )
        .unwrap();
    }
    let r = analyze(&s, &s.join("out"), "2");
    assert_eq!(r["reality"], "VirtualLab");
    let summary = std::fs::read_to_string(s.join("out/summary.md")).unwrap();
    assert!(
        summary.contains("VIRTUAL LAB") && summary.contains("not live-fish results"),
        "{summary}"
    );
}

#[test]
fn real_robot_fish_recordings_serve_as_the_reality_arm() {
    let Some(data) = fishprobe_io::shared_data_dir() else {
        eprintln!("skipping: FISHPROBE_DATA is not set and ../shared/data is absent");
        return;
    };
    let s = small_study("real");
    let real = s.join("rollouts/Follow__Real");
    std::fs::remove_dir_all(&real).unwrap();
    std::fs::create_dir_all(&real).unwrap();
    for f in std::fs::read_dir(data.join("robot-fish")).unwrap() {
        let f = f.unwrap().path();
        std::fs::copy(&f, real.join(f.file_name().unwrap())).unwrap();
    }
    let r = analyze(&s, &s.join("out"), "2");
    // 20 Hz, no /fishprobe group: goals recomputed from the fish track, metrics at 20 Hz.
    assert_eq!(r["goals"]["Follow"]["real"].as_array().unwrap().len(), 2);
    assert!(r["metric_gaps"]["fish_speed"]["Follow"]["median"].is_number());
    assert!(
        !r["skipped"].to_string().contains("Robotracker"),
        "{}",
        r["skipped"]
    );
}

/// A foreign recording (20 Hz, 11 minutes, no task, another set-up) dropped among a policy's
/// live trials is not counted as one more trial: it is left out and named, in results.json
/// and the summary, with how it differs.
#[test]
fn a_foreign_recording_in_a_reality_arm_is_left_out_and_named() {
    let Some(data) = fishprobe_io::shared_data_dir() else {
        eprintln!("skipping: FISHPROBE_DATA is not set and ../shared/data is absent");
        return;
    };
    let s = small_study("mixed-real");
    let real = s.join("rollouts/Follow__Real");
    let before = fishprobe_io::trial_files(&real).len();
    let foreign = std::fs::read_dir(data.join("robot-fish"))
        .unwrap()
        .map(|f| f.unwrap().path())
        .find(|p| p.extension().is_some_and(|e| e == "hdf5"))
        .unwrap();
    std::fs::copy(&foreign, real.join(foreign.file_name().unwrap())).unwrap();
    let r = analyze(&s, &s.join("out"), "2");
    assert_eq!(
        r["goals"]["Follow"]["real"].as_array().unwrap().len(),
        before,
        "the foreign recording counted as a trial"
    );
    let skipped = r["skipped"].to_string();
    assert!(
        skipped.contains("Robotracker") && skipped.contains("20 Hz") && skipped.contains("foreign"),
        "{skipped}"
    );
    let summary = std::fs::read_to_string(s.join("out/summary.md")).unwrap();
    assert!(summary.contains("must hold one protocol"), "{summary}");
}

#[test]
fn a_directory_without_a_study_is_an_error() {
    let d = dir("nostudy");
    let o = fishprobe(&["analyze", d.to_str().unwrap()]);
    assert!(!o.status.success());
    assert!(
        String::from_utf8_lossy(&o.stderr).contains("no rollouts/<Policy>__<Model>/"),
        "{}",
        String::from_utf8_lossy(&o.stderr)
    );
}

#[test]
fn a_settings_file_replaces_analysis_settings_by_name() {
    let s = small_study("settings");
    let good = s.join("analysis.toml");
    std::fs::write(
        &good,
        "preset = \"quick\"\n[analysis]\ncompetence_threshold = 0.5\nci_level = 0.9\n",
    )
    .unwrap();
    let out = s.join("out");
    let o = fishprobe(&[
        "analyze",
        s.to_str().unwrap(),
        "--out",
        out.to_str().unwrap(),
        "--quick",
        "--sim-trials",
        "6",
        "--settings",
        good.to_str().unwrap(),
    ]);
    assert!(o.status.success(), "{}", String::from_utf8_lossy(&o.stderr));
    let r: serde_json::Value =
        serde_json::from_str(&std::fs::read_to_string(out.join("results.json")).unwrap()).unwrap();
    assert_eq!(r["config"]["competence_threshold"], 0.5);
    assert_eq!(r["config"]["ci_level"], 0.9);
    // The rest is --quick's.
    assert_eq!(r["config"]["permutations"], 2000);
    for (text, want) in [
        (
            "[analysis]\ncompetence_treshold = 0.5\n",
            "competence_treshold",
        ),
        ("[analysis]\nci_level = \"high\"\n", "ci_level"),
        ("competence_threshold = 0.5\n", "no [analysis] table"),
        ("[analysis\n", "analysis settings"),
    ] {
        let bad = s.join("bad.toml");
        std::fs::write(&bad, text).unwrap();
        let o = fishprobe(&[
            "analyze",
            s.to_str().unwrap(),
            "--out",
            s.join("out_bad").to_str().unwrap(),
            "--settings",
            bad.to_str().unwrap(),
        ]);
        let err = String::from_utf8_lossy(&o.stderr);
        assert!(!o.status.success() && err.contains(want), "{text}: {err}");
        assert!(!s.join("out_bad").join("results.json").exists());
    }
}

/// Live trials of two sets of weights under one policy name (a policy retrained while its
/// trials were recorded) are not one condition: the analysis leaves the condition out and
/// says why, naming both.
/// Stamps the trials in `dir` as driven by the weights `sha(i)` (the i-th file).
fn stamp_weights(dir: &Path, sha: impl Fn(usize) -> String) {
    for (i, f) in fishprobe_io::trial_files(dir).iter().enumerate() {
        let mut t = read_trial(f).unwrap();
        let task = t.task.as_mut().unwrap();
        let mut c: serde_json::Value = serde_json::from_str(&task.config_json).unwrap();
        c[fishprobe_io::POLICY_SHA256_KEY] = sha(i).into();
        task.config_json = c.to_string();
        write_trial(f, &t).unwrap();
    }
}

#[test]
fn trials_of_two_weights_under_one_name_are_left_out_and_named() {
    let s = small_study("mixed");
    stamp_weights(&s.join("rollouts/Zone__Real"), |i| {
        if i < 2 { "a" } else { "b" }.repeat(64)
    });
    let r = analyze(&s, &s.join("out"), "2");
    let skipped = r["skipped"].to_string();
    assert!(
        skipped.contains("Zone__Real")
            && skipped.contains("2 different policies")
            && skipped.contains("aaaaaaaaaaaa… in 2"),
        "{skipped}"
    );
    assert!(
        r["sim_to_real"].get("Zone").is_none(),
        "{}",
        r["sim_to_real"]
    );
    assert!(r["sim_to_real"]["Follow"]["w"].is_number());

    // One set of weights in each condition, but live trials of other weights than the
    // simulated ones (a policy retrained between them): not a sim-to-real gap of one policy.
    stamp_weights(&s.join("rollouts/Zone__Real"), |_| "b".repeat(64));
    stamp_weights(&s.join("rollouts/Zone__Zone"), |_| "a".repeat(64));
    stamp_weights(&s.join("rollouts/Zone__Follow"), |_| "c".repeat(64));
    stamp_weights(&s.join("approach_test/Zone"), |i| {
        if i == 0 { "a" } else { "d" }.repeat(64)
    });
    let episodes = fishprobe_io::trial_files(&s.join("approach_test/Zone")).len();
    assert!(episodes >= 2);
    let r = analyze(&s, &s.join("out2"), "2");
    let skipped = r["skipped"].to_string();
    assert!(
        skipped.contains("Zone__Real")
            && skipped.contains("driven by weights sha256 bbbbbbbbbbbb…")
            && skipped.contains("own-model trials by aaaaaaaaaaaa…")
            && skipped.contains("Zone__Follow")
            && skipped.contains("driven by weights sha256 cccccccccccc…"),
        "{skipped}"
    );
    assert!(r["sim_to_real"].get("Zone").is_none());
    assert!(r["sim_to_sim"]["Zone"].get("Follow").is_none());
    // The approach assay counts only the episodes of the policy's own weights.
    assert_eq!(r["approach"]["Zone"]["episodes"], 1);
    assert!(
        skipped.contains("not counted in Zone's approach assay")
            && skipped.contains("driven by weights sha256 dddddddddddd…"),
        "{skipped}"
    );
    assert!(r["sim_to_sim"]["Follow"].get("Zone").is_some());
    assert_eq!(r["weights"]["Zone"], "a".repeat(64));
    assert!(r["weights"].get("Follow").is_none(), "{}", r["weights"]);
    let summary = std::fs::read_to_string(s.join("out2/summary.md")).unwrap();
    assert!(
        summary.contains("Weights that drove the trials (SHA-256): Zone `aaaaaaaaaaaa…`."),
        "{summary}"
    );
}

/// A study directory a hostile or careless hand made: a directory link looping back to its
/// parent inside an arm and an arm that is a link to `rollouts/` itself, 10,000 tiny files
/// named `*.hdf5`, a trial recorded at another frame rate, and a trial rewritten in place
/// (torn) while `analyze` reads. Documented behaviour (docs/guide/analyse.md): every entry
/// that is not a readable trial is named in `skipped`, a trial is read at its own frame rate,
/// and the rest is analysed; nothing panics or hangs.
#[cfg(unix)]
#[test]
fn hostile_study_directories_are_analysed_or_skipped_by_name() {
    use std::os::unix::fs::symlink;
    let s = small_study("hostile-dirs");
    let roll = s.join("rollouts");
    let real = roll.join("Follow__Real");
    symlink(&real, real.join("zz_loop.hdf5")).unwrap();
    symlink(&roll, roll.join("Loop__Real")).unwrap();
    let tiny = roll.join("Zone__Real");
    for i in 0..10_000 {
        std::fs::write(tiny.join(format!("tiny_{i:05}.hdf5")), b"x").unwrap();
    }
    // The same motion recorded at 50 Hz: as many frames, half the time.
    let mut t = read_trial(&roll.join("Follow__Real/Follow__Real_000.hdf5")).unwrap();
    t.frame_rate_hz = 50.0;
    write_trial(&roll.join("Follow__Real/zz_50hz.hdf5"), &t).unwrap();
    // A trial rewritten in place, alternately whole and cut in half, until analyze ends.
    let good = std::fs::read(roll.join("Zone__Zone/Zone__Zone_000.hdf5")).unwrap();
    let torn = common::TornFile::start(&roll.join("Zone__Zone/zz_torn.hdf5"), good);
    let start = std::time::Instant::now();
    let r = analyze(&s, &s.join("out"), "2");
    drop(torn);
    assert!(
        start.elapsed() < std::time::Duration::from_secs(300),
        "analyze took {:?}",
        start.elapsed()
    );
    let skipped = r["skipped"].to_string();
    for needle in ["zz_loop.hdf5", "tiny_00000.hdf5", "tiny_09999.hdf5", "Loop"] {
        assert!(skipped.contains(needle), "{needle} not in skipped");
    }
    // The 10,000 tiny files cost Zone none of its real trials; the 50-Hz trial is another
    // protocol than Follow's 25-Hz trials: left out and named, the others analysed.
    assert_eq!(r["goals"]["Zone"]["real"].as_array().unwrap().len(), 6);
    assert_eq!(r["goals"]["Follow"]["real"].as_array().unwrap().len(), 6);
    assert!(skipped.contains("zz_50hz.hdf5"), "{skipped}");
}
