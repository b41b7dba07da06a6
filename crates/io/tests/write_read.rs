//! Our files round-trip, are written crash-safely, and h5py reads them with the exact layout.

#![allow(clippy::unwrap_used)] // test helpers may unwrap: a failure is a test failure

use fishprobe_io::{
    read_trial, write_trial, Attr, Category, Entity, TaskRecord, TrialFile, TrialKind,
};
use std::collections::BTreeMap;
use std::process::Command;

fn temp_dir(tag: &str) -> fishprobe_io::ScratchDir {
    fishprobe_io::ScratchDir::for_test(&format!("io-{tag}"))
}

fn sample(frames: usize) -> TrialFile {
    let pose = |k: usize, phase: f32| {
        let a = k as f32 * 0.05 + phase;
        ([20.0 * a.cos(), 20.0 * a.sin()], [(-a.sin()), a.cos()])
    };
    let entity = |name: &str, label: &str, phase: f32| Entity {
        name: name.into(),
        category: Category::from_label(label),
        category_label: label.into(),
        positions: (0..frames).map(|k| pose(k, phase).0).collect(),
        orientations: (0..frames).map(|k| pose(k, phase).1).collect(),
        attributes: BTreeMap::new(),
    };
    let mut fish = entity("fish_1", "fish", 1.0);
    fish.attributes
        .insert("species".into(), Attr::Text("guppy".into()));
    fish.attributes
        .insert("fish_standard_length_cm".into(), Attr::Int(3));
    let mut attributes = BTreeMap::new();
    attributes.insert(
        "experiment_setup".into(),
        Attr::Text("fishprobe test".into()),
    );
    TrialFile {
        world_size_cm: [100.0, 100.0],
        frame_rate_hz: 25.0,
        entities: vec![entity("robot", "robot", 0.0), fish],
        attributes,
        task: Some(TaskRecord {
            kind: TrialKind::Sim,
            policy: "scripted:goals".into(),
            fish_model: "Zone".into(),
            seed: 42,
            goal_radius_cm: 5.0,
            goals: vec![[-20.0, -20.0], [20.0, 20.0]],
            active_goal: (0..frames).map(|k| i32::from(k >= frames / 2)).collect(),
            goal_frames: vec![(frames / 2) as u64],
            command_frames: (0..frames as u64).step_by(25).collect(),
            command_turns: (0..frames).step_by(25).map(|k| k as f32 * 0.001).collect(),
            control_start_frame: 0,
            config_json: r#"{"env": {"frame_rate_hz": 25.0}}"#.into(),
            program_version: "0.1.0".into(),
        }),
    }
}

#[test]
fn round_trip_is_exact_and_nan_survives() {
    let dir = temp_dir("rt");
    let p = dir.join("t.hdf5");
    let mut t = sample(100);
    write_trial(&p, &t).unwrap();
    let back = read_trial(&p).unwrap();
    // Entities come back in name order.
    t.entities.sort_by(|a, b| a.name.cmp(&b.name));
    assert!(back == t, "round trip changed the trial");
    // Untracked frames are NaN and stay NaN; entities may differ in length.
    // entities[0] is fish_1, entities[1] the robot.
    t.entities[0].positions[3] = [f32::NAN, f32::NAN];
    t.entities[1].positions.truncate(50);
    t.entities[1].orientations.truncate(50);
    write_trial(&p, &t).unwrap();
    let back = read_trial(&p).unwrap();
    assert!(back.entities[0].positions[3][0].is_nan());
    assert_eq!(back.robot().unwrap().frames(), 50);
    assert_eq!(back.fish().next().unwrap().frames(), 100);
    // No temporary file is left behind.
    let leftovers: Vec<_> = std::fs::read_dir(&dir)
        .unwrap()
        .map(|e| e.unwrap().file_name())
        .collect();
    assert_eq!(leftovers.len(), 1, "{leftovers:?}");
}

#[test]
fn failed_writes_leave_nothing_under_the_final_name() {
    let dir = temp_dir("fail");
    // The target is a directory: the rename fails, and the temporary file is removed.
    let target = dir.join("occupied.hdf5");
    std::fs::create_dir_all(target.join("x")).unwrap();
    let err = write_trial(&target, &sample(10)).unwrap_err().to_string();
    assert!(err.contains("occupied.hdf5"), "{err}");
    let names: Vec<_> = std::fs::read_dir(&dir)
        .unwrap()
        .map(|e| e.unwrap().file_name())
        .collect();
    assert_eq!(names.len(), 1, "{names:?}");
    // Inconsistent data is refused before anything is written.
    let mut bad = sample(10);
    bad.entities[0].orientations.pop();
    assert!(write_trial(&dir.join("bad.hdf5"), &bad).is_err());
    assert!(!dir.join("bad.hdf5").exists());
}

/// h5py is needed; install it if missing (CI installs it in .ci/run too).
fn python_with_h5py() -> &'static str {
    let ok = |py: &str| {
        Command::new(py)
            .args(["-c", "import h5py, numpy"])
            .status()
            .is_ok_and(|s| s.success())
    };
    if !ok("python3") {
        let status = Command::new("python3")
            .args(["-m", "pip", "install", "--quiet", "h5py"])
            .status();
        assert!(
            status.is_ok_and(|s| s.success()),
            "python3 with h5py is required for this test"
        );
        assert!(ok("python3"), "h5py still not importable after pip install");
    }
    "python3"
}

#[test]
fn python_reads_our_files() {
    let dir = temp_dir("py");
    let p = dir.join("trial.hdf5");
    write_trial(&p, &sample(60)).unwrap();
    let script = r#"
import sys, json, h5py, numpy as np
f = h5py.File(sys.argv[1], "r")
assert list(f.attrs["format_version"]) == [1, 0] and f.attrs["format_version"].dtype == np.int32
assert list(f.attrs["world_size_cm"]) == [100.0, 100.0] and f.attrs["world_size_cm"].dtype == np.float32
assert h5py.check_string_dtype(f.attrs.get_id("format_url").dtype).length is None  # variable length
assert f.attrs["experiment_setup"] == "fishprobe test"
assert sorted(f["entities"].keys()) == ["fish_1", "robot"]
for name in ["robot", "fish_1"]:
    e = f["entities"][name]
    for ds in ["positions", "orientations"]:
        d = e[ds]
        assert d.dtype == np.float32 and d.shape == (60, 2) and d.chunks is None and d.compression is None, (name, ds)
assert f["entities/robot"].attrs["category"] == "robot"
assert f["entities/fish_1"].attrs["category"] == "fish"
assert f["entities/fish_1"].attrs["species"] == "guppy"
p = f["entities/robot/positions"][:]
assert np.allclose(p[1], [20 * np.cos(0.05), 20 * np.sin(0.05)], atol=1e-5)
assert f["samplings"].attrs["default"] == "25 hz"
assert f["samplings/25 hz"].attrs["frequency_hz"] == np.float32(25.0)
t = f["fishprobe"]
assert t.attrs["kind"] == "sim" and t.attrs["policy"] == "scripted:goals" and t.attrs["fish_model"] == "Zone"
assert t.attrs["seed"] == 42 and t.attrs["control_start_frame"] == 0
assert t["goals"].shape == (2, 2) and list(t["goals"][1]) == [20.0, 20.0]
assert t["active_goal"].shape == (60,) and t["active_goal"][59] == 1
assert list(t["goal_frames"][:]) == [30]
assert t["command_frames"].shape == t["command_turns"].shape == (3,)
assert json.loads(t["config_json"][0])["env"]["frame_rate_hz"] == 25.0
print("h5py ok")
"#;
    let out = Command::new(python_with_h5py())
        .args(["-c", script, p.to_str().unwrap()])
        .output()
        .unwrap();
    assert!(
        out.status.success(),
        "h5py check failed:\n{}\n{}",
        String::from_utf8_lossy(&out.stdout),
        String::from_utf8_lossy(&out.stderr)
    );
}
