//! Groups from the command line (issue 22): Couzin's phase picture, M_Force's order over
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
        "28",
        "--out",
        out.to_str().unwrap(),
    ]);
    assert!(o.status.success(), "{}", stderr(&o));
    let text = stdout(&o);
    assert!(text.contains("highly parallel"), "{text}");
    for f in [
        "collective-phase.svg",
        "collective-phase.png",
        "collective.json",
    ] {
        assert!(out.join(f).is_file(), "{f} missing");
    }
    let grid: serde_json::Value =
        serde_json::from_slice(&std::fs::read(out.join("collective.json")).unwrap()).unwrap();
    assert_eq!(grid["cells"].as_array().unwrap().len(), 2);
    // Δr_o = 30 cm: everyone aligns with everyone: polarised.
    let p = grid["cells"][1][0]["polarisation"].as_f64().unwrap();
    assert!(p > 0.9, "{p}");

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
        (vec!["collective", "--turn-rate", "fast"], "--turn-rate"),
        (vec!["collective", "--seeds", "0"], "--seeds"),
        (
            vec!["collective", "--orientation=-1", "--seconds", "1"],
            "orientation_zone_cm",
        ),
        (vec!["collective", "--seconds", "nan"], "seconds"),
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
