//! `fishprobe fidelity`: the fidelity sweep, with a tiny budget.

#![allow(clippy::unwrap_used)] // a failure is a test failure

mod common;

use common::{fishprobe, fresh_dir, stderr, stdout};

#[test]
fn the_sweep_trains_scores_and_reads_finished_cells_back() {
    let d = fresh_dir("fidelity");
    let out = d.join("sweep");
    let args = [
        "fidelity",
        "--preset",
        "smoke",
        "--readings",
        "baseline,robot-reaches,zone-radii,robot-reaches+zone-radii",
        "--models",
        "Zone,Follow",
        "--episodes",
        "2",
        "--approach-episodes",
        "1",
        "--out",
        out.to_str().unwrap(),
    ];
    let o = fishprobe(&args);
    assert!(o.status.success(), "{}", stderr(&o));
    // zone-radii changes only M_Zone, so it (and a combination with it) runs only there:
    // 2 + 2 + 1 + 1 cells.
    let rows: Vec<serde_json::Value> =
        serde_json::from_str(&std::fs::read_to_string(out.join("scoreboard.json")).unwrap())
            .unwrap();
    assert_eq!(rows.len(), 6);
    let first_zone = rows
        .iter()
        .find(|r| r["reading"] == "baseline" && r["model"] == "Zone")
        .cloned()
        .unwrap();
    for r in &rows {
        assert!(
            r["goals"].is_number() && r["nearer_fish"].is_number(),
            "{r}"
        );
        assert!(r["best_scripted"].is_string(), "{r}");
        // How soon each reaches its fish: fetch-and-lead does within a 15-minute episode.
        assert!(r["reach_s"].is_number() || r["reach_s"].is_null(), "{r}");
        assert!(r["baselines_reach_s"]["fetch-and-lead"].is_number(), "{r}");
        // The competence's standard error, whenever the policy reached goals.
        if r["goals"].as_f64().unwrap() > 0.0 {
            assert!(r["competence_se"].as_f64().is_some_and(|x| x >= 0.0), "{r}");
        }
    }
    let robot = out.join("robot-reaches/Zone/policy/params.json");
    let params: serde_json::Value =
        serde_json::from_str(&std::fs::read_to_string(robot).unwrap()).unwrap();
    assert_eq!(params["env"]["task"]["training_goal_reached_by"], "robot");
    let radii = out.join("zone-radii/Zone/policy/params.json");
    let params: serde_json::Value =
        serde_json::from_str(&std::fs::read_to_string(radii).unwrap()).unwrap();
    assert_eq!(params["model"]["zone_convention"], "radii");
    let both = out.join("robot-reaches+zone-radii/Zone/policy/params.json");
    let params: serde_json::Value =
        serde_json::from_str(&std::fs::read_to_string(both).unwrap()).unwrap();
    assert_eq!(params["model"]["zone_convention"], "radii");
    assert_eq!(params["env"]["task"]["training_goal_reached_by"], "robot");
    let board = std::fs::read_to_string(out.join("scoreboard.md")).unwrap();
    assert!(
        board.contains("| robot-reaches | Zone |")
            && board.contains("(41 (x")
            && board.contains("reaches its fish"),
        "{board}"
    );
    // A cell made before the scoreboard gave the time to reach the fish gets it from its
    // trial files when read back: the same values as when it was made.
    let cell = out.join("baseline/Zone/cell.json");
    let mut v: serde_json::Value =
        serde_json::from_str(&std::fs::read_to_string(&cell).unwrap()).unwrap();
    let reach = (v["reach_s"].clone(), v["baselines_reach_s"].clone());
    let obj = v.as_object_mut().unwrap();
    obj.remove("reach_s");
    obj.remove("baselines_reach_s");
    std::fs::write(&cell, serde_json::to_string_pretty(&v).unwrap()).unwrap();
    // A second run reads every finished cell back: the same scoreboard.
    let o2 = fishprobe(&args);
    assert!(o2.status.success(), "{}", stderr(&o2));
    assert_eq!(stdout(&o), stdout(&o2));
    assert!(!stderr(&o2).contains("iteration"), "{}", stderr(&o2));
    let v: serde_json::Value =
        serde_json::from_str(&std::fs::read_to_string(&cell).unwrap()).unwrap();
    assert_eq!(
        (v["reach_s"].clone(), v["baselines_reach_s"].clone()),
        reach
    );
    // An older cell whose trial files were pruned is still read back, its time left out.
    let mut v = v;
    let obj = v.as_object_mut().unwrap();
    obj.remove("reach_s");
    obj.remove("baselines_reach_s");
    std::fs::write(&cell, serde_json::to_string_pretty(&v).unwrap()).unwrap();
    std::fs::remove_dir_all(out.join("baseline/Zone/eval")).unwrap();
    let o4 = fishprobe(&args);
    assert!(o4.status.success(), "{}", stderr(&o4));
    assert!(stderr(&o4).contains("older cell"), "{}", stderr(&o4));
    assert!(stdout(&o4).contains("| – (–, –) |"), "{}", stdout(&o4));
    // Other settings into the same directory: refused, naming the cell.
    let mut other = args.to_vec();
    other[8] = "3"; // --episodes
    let o3 = fishprobe(&other);
    assert!(!o3.status.success());
    assert!(
        stderr(&o3).contains("made with other settings"),
        "{}",
        stderr(&o3)
    );
    // A run of one reading prints its own row, and the files keep every finished cell of the
    // directory; cells of another seed say so.
    let o4 = fishprobe(&[
        "fidelity",
        "--preset",
        "smoke",
        "--readings",
        "time-limit-terminal",
        "--models",
        "Follow",
        "--episodes",
        "2",
        "--approach-episodes",
        "1",
        "--seed",
        "1",
        "--out",
        out.to_str().unwrap(),
    ]);
    assert!(o4.status.success(), "{}", stderr(&o4));
    assert_eq!(
        stdout(&o4).matches("| Follow |").count(),
        1,
        "{}",
        stdout(&o4)
    );
    let rows: Vec<serde_json::Value> =
        serde_json::from_str(&std::fs::read_to_string(out.join("scoreboard.json")).unwrap())
            .unwrap();
    assert_eq!(rows.len(), 7);
    assert_eq!(rows[0]["reading"], "time-limit-terminal");
    let board = std::fs::read_to_string(out.join("scoreboard.md")).unwrap();
    assert!(
        board.contains("| baseline (seed 0) | Zone |")
            && board.contains("| time-limit-terminal | Follow |"),
        "{board}"
    );
    // A cell stopped before it finished (no cell.json) is redone: its training resumes only
    // if it is this cell's, and its evaluation starts afresh (the time to reach the fish is
    // read from every trial file there, so a stale one would count).
    let zone = out.join("baseline/Zone");
    std::fs::remove_file(zone.join("cell.json")).unwrap();
    let one = |seed: &str| {
        fishprobe(&[
            "fidelity",
            "--preset",
            "smoke",
            "--readings",
            "baseline",
            "--models",
            "Zone",
            "--episodes",
            "2",
            "--approach-episodes",
            "1",
            "--seed",
            seed,
            "--out",
            out.to_str().unwrap(),
        ])
    };
    let o5 = one("1");
    assert!(
        !o5.status.success()
            && stderr(&o5).contains("already holds a training run, of other settings (seed "),
        "{}",
        stderr(&o5)
    );
    std::fs::create_dir_all(zone.join("eval")).unwrap();
    let stale = zone.join("eval/trial_099.hdf5");
    std::fs::copy(zone.join("baseline-goal-seeker/trial_000.hdf5"), &stale).unwrap();
    let o6 = one("0");
    assert!(o6.status.success(), "{}", stderr(&o6));
    assert!(!stale.exists(), "a stale trial file was kept");
    let redone: serde_json::Value =
        serde_json::from_str(&std::fs::read_to_string(zone.join("cell.json")).unwrap()).unwrap();
    for k in [
        "goals",
        "reach_s",
        "baselines_reach_s",
        "closest_cm",
        "competence",
    ] {
        assert_eq!(redone[k], first_zone[k], "{k}");
    }
}

#[test]
fn readings_are_listed_and_unknown_ones_refused() {
    let o = fishprobe(&["fidelity", "--list"]);
    assert!(o.status.success());
    for r in ["baseline", "robot-reaches", "zone-radii", "budget-4x"] {
        assert!(stdout(&o).contains(r), "{}", stdout(&o));
    }
    let d = fresh_dir("fidelity-bad");
    let o = fishprobe(&[
        "fidelity",
        "--readings",
        "moonlight",
        "--out",
        d.join("x").to_str().unwrap(),
    ]);
    assert!(!o.status.success());
    assert!(
        stderr(&o).contains("unknown reading `moonlight`"),
        "{}",
        stderr(&o)
    );
    let o = fishprobe(&[
        "fidelity",
        "--models",
        "Zonk",
        "--out",
        d.join("y").to_str().unwrap(),
    ]);
    assert!(stderr(&o).contains("Zonk"), "{}", stderr(&o));
}
