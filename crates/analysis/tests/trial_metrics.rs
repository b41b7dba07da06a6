//! Hand-computed goal events, times and per-frame metrics on tiny constructed trials.

#![allow(clippy::unwrap_used)] // a failure is a test failure

use fishprobe_analysis::{load_trial, AnalysisConfig, METRICS};
use fishprobe_io::{write_trial, Category, Entity, TrialFile};
use std::collections::BTreeMap;
use std::f32::consts::PI;
use std::path::{Path, PathBuf};
use std::sync::OnceLock;

fn entity(name: &str, label: &str, poses: &[[f32; 3]]) -> Entity {
    Entity {
        name: name.into(),
        category: Category::from_label(label),
        category_label: label.into(),
        positions: poses.iter().map(|p| [p[0], p[1]]).collect(),
        orientations: poses.iter().map(|p| [p[2].cos(), p[2].sin()]).collect(),
        attributes: BTreeMap::new(),
    }
}

/// This test binary's directory for its trial files (the next run removes it).
fn scratch() -> &'static Path {
    static DIR: OnceLock<PathBuf> = OnceLock::new();
    DIR.get_or_init(|| fishprobe_io::ScratchDir::for_process("analysis"))
}

fn write(name: &str, robot: &[[f32; 3]], fish: &[[f32; 3]], rate: f32) -> PathBuf {
    let p = scratch().join(name);
    let t = TrialFile {
        world_size_cm: [100.0, 100.0],
        frame_rate_hz: rate,
        entities: vec![
            entity("robot", "robot", robot),
            entity("fish_1", "fish", fish),
        ],
        attributes: BTreeMap::new(),
        task: None,
    };
    write_trial(&p, &t).unwrap();
    p
}

#[test]
fn per_frame_metrics_by_hand() {
    // Robot still at the centre facing +x; fish from (10, 0) swimming +x at 1 cm per frame.
    let robot = vec![[0.0, 0.0, 0.0]; 5];
    let fish: Vec<[f32; 3]> = (0..5).map(|k| [10.0 + k as f32, 0.0, 0.0]).collect();
    let p = write("line.hdf5", &robot, &fish, 25.0);
    let t = load_trial(&p, &AnalysisConfig::default(), true).unwrap();
    let m = t.metrics.unwrap();
    let get = |name: &str| &m[METRICS.iter().position(|x| *x == name).unwrap()];
    assert_eq!(get("iid"), &vec![10.0, 11.0, 12.0, 13.0, 14.0]);
    // Forward differences: T - 1 values, times the rate.
    assert_eq!(get("iid_change"), &vec![25.0; 4]);
    assert_eq!(get("fish_speed"), &vec![25.0; 4]);
    assert_eq!(get("fish_turn"), &vec![0.0; 4]);
    assert_eq!(get("alignment"), &vec![1.0; 5]);
    // The fish faces away from the robot.
    assert_eq!(get("fish_faces_robot"), &vec![-1.0; 5]);
    // Nearest wall is the right one, 50 - x; swimming along x is perpendicular to it.
    assert_eq!(get("wall_distance"), &vec![36.0, 37.0, 38.0, 39.0, 40.0]);
    assert!(get("wall_alignment").iter().all(|v| v.abs() < 1e-6));
    // Distance to the first goal (-20, -20) from (10, 0): sqrt(900 + 400).
    assert!((get("fish_goal_distance")[0] - 1300f64.sqrt()).abs() < 1e-4);
}

#[test]
fn goal_events_are_recomputed_without_a_task() {
    // At 25 Hz: the fish waits 1 s, is at the first goal at frame 25, then at the second at
    // frame 100, and stays there. Times to goal: 1 s and 3 s; both in minute 0, the trial's one
    // complete minute (61 s).
    let mut fish = vec![[0.0f32, 0.0, 0.0]; 1525];
    for f in fish.iter_mut().take(100).skip(25) {
        *f = [-19.0, -21.0, 0.0];
    }
    for f in fish.iter_mut().skip(100) {
        *f = [22.0, 19.0, 0.0];
    }
    let robot = vec![[0.0, 10.0, 0.0]; 1525];
    let p = write("goals.hdf5", &robot, &fish, 25.0);
    let t = load_trial(&p, &AnalysisConfig::default(), false).unwrap();
    assert_eq!(t.goals_reached, 2);
    assert!((t.time_to_goal_s.unwrap() - 2.0).abs() < 1e-9);
    assert_eq!(t.goals_per_minute, vec![2]);
    assert!(t.metrics.is_none());
    // At 20 Hz the same frames are later in seconds: 1.25 s and 3.75 s.
    let p20 = write("goals20.hdf5", &robot, &fish, 20.0);
    let t20 = load_trial(&p20, &AnalysisConfig::default(), false).unwrap();
    assert!((t20.time_to_goal_s.unwrap() - 2.5).abs() < 1e-9);
    // 1525 frames at 20 Hz are 76 s: still one complete minute. A 5-s trial has none.
    assert_eq!(t20.goals_per_minute, vec![2]);
    let short = write("short.hdf5", &robot[..125], &fish[..125], 25.0);
    assert!(load_trial(&short, &AnalysisConfig::default(), false)
        .unwrap()
        .goals_per_minute
        .is_empty());
}

#[test]
fn unusable_trials_say_why() {
    let robot = vec![[0.0, 0.0, 0.0]; 5];
    let nan = vec![[f32::NAN, f32::NAN, 0.0]; 5];
    let p = write("nan.hdf5", &robot, &nan, 25.0);
    let e = load_trial(&p, &AnalysisConfig::default(), true).unwrap_err();
    assert!(
        matches!(e, fishprobe_analysis::AnalysisError::Data(_))
            && e.to_string().contains("all NaN"),
        "{e}"
    );
}

/// A trial file of a robot and a group of fish (25 Hz, no task).
fn write_group(name: &str, robot: &[[f32; 3]], fish: &[Vec<[f32; 3]>]) -> PathBuf {
    let p = scratch().join(name);
    let mut entities = vec![entity("robot", "robot", robot)];
    for (k, f) in fish.iter().enumerate() {
        entities.push(entity(&format!("fish_{}", k + 1), "fish", f));
    }
    let t = TrialFile {
        world_size_cm: [100.0, 100.0],
        frame_rate_hz: 25.0,
        entities,
        attributes: BTreeMap::new(),
        task: None,
    };
    write_trial(&p, &t).unwrap();
    p
}

#[test]
fn a_group_trial_gives_per_fish_pair_metrics_and_the_group_metrics() {
    use fishprobe_analysis::{ALL_METRICS, GROUP_METRICS};
    // Robot still at the centre; four fish on a ring of 10 cm around (20, 0), each heading
    // tangentially (a torus); fish 4 is untracked in frame 1.
    let robot = vec![[0.0, 0.0, 0.0]; 3];
    let ring = |k: usize| {
        let a = k as f32 * std::f32::consts::FRAC_PI_2;
        [
            20.0 + 10.0 * a.cos(),
            10.0 * a.sin(),
            a + std::f32::consts::FRAC_PI_2,
        ]
    };
    let mut fish: Vec<Vec<[f32; 3]>> = (0..4).map(|k| vec![ring(k); 3]).collect();
    fish[3][1] = [f32::NAN; 3];
    let p = write_group("group.hdf5", &robot, &fish);
    let cfg = AnalysisConfig::default();
    let t = load_trial(&p, &cfg, true).unwrap();
    assert_eq!(t.fish, 4);
    let m = t.metrics.unwrap();
    assert_eq!(m.len(), ALL_METRICS.len());
    let get = |name: &str| &m[ALL_METRICS.iter().position(|x| *x == name).unwrap()];
    // Pair metrics pooled over the fish: 3 frames x 4 fish less the untracked one.
    assert_eq!(get("iid").len(), 11);
    assert!((get("iid")[0] - 10.0).abs() < 1e-4); // fish 3 at (10, 0)
                                                  // Group metrics per frame; frame 1 has three fish (the fourth untracked).
    assert_eq!(get("polarisation").len(), 3);
    assert!(
        get("milling")[1..].iter().all(|&v| (v - 1.0).abs() < 1e-5),
        "{m:?}"
    );
    assert!(get("group_spread")[1..]
        .iter()
        .all(|&v| (v - 10.0).abs() < 1e-4));
    // The robot is 20 cm from the centroid; only fish 3 (10 cm away) is within 15 cm.
    assert!(get("robot_centroid_distance")[..2]
        .iter()
        .all(|&v| (v - 20.0).abs() < 1e-4));
    let near = get("fish_near_robot");
    assert!(
        (near[0] - 0.25).abs() < 1e-6 && (near[2] - 1.0 / 3.0).abs() < 1e-6,
        "{near:?}"
    );
    assert_eq!(GROUP_METRICS.len(), 6);

    // A pair trial has the nine metrics only, as before.
    let pair = write("pair.hdf5", &robot, &fish[0], 25.0);
    let t = load_trial(&pair, &cfg, true).unwrap();
    assert_eq!((t.fish, t.metrics.unwrap().len()), (1, 9));

    // A fish never tracked is refused by name.
    let mut lost = fish.clone();
    lost[2] = vec![[f32::NAN; 3]; 3];
    let q = write_group("lost.hdf5", &robot, &lost);
    let e = load_trial(&q, &cfg, true).unwrap_err().to_string();
    assert!(e.contains("fish_3") && e.contains("NaN"), "{e}");
}

#[test]
fn time_to_reach_the_fish_by_hand() {
    // Robot still at the centre; the fish comes in along x from 40 cm at 1 cm per frame, with
    // a tracking gap (NaN) at the frames where it would first be within 15 cm.
    let robot = vec![[0.0, 0.0, 0.0]; 40];
    let mut fish: Vec<[f32; 3]> = (0..40).map(|k| [40.0 - k as f32, 0.0, PI]).collect();
    // Frame 25 is at 15 cm, the first within reach (at most 15 cm); 25 and 26 untracked.
    fish[25] = [f32::NAN, f32::NAN, PI];
    fish[26] = [f32::NAN, f32::NAN, PI];
    let p = write("reach.hdf5", &robot, &fish, 25.0);
    let t = load_trial(&p, &AnalysisConfig::default(), false).unwrap();
    assert_eq!(t.time_to_reach_s, Some(27.0 / 25.0));
    // A reach of 30 cm is met at frame 10; one of 0.5 cm never.
    let cfg = |r: f32| AnalysisConfig {
        robot_reach_cm: r,
        ..AnalysisConfig::default()
    };
    let t = load_trial(&p, &cfg(30.0), false).unwrap();
    assert_eq!(t.time_to_reach_s, Some(10.0 / 25.0));
    assert_eq!(
        load_trial(&p, &cfg(0.5), false).unwrap().time_to_reach_s,
        None
    );
}
