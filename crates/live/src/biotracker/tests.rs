//! The observer against synthetic BioTracker updates: it must make the trial the bridge makes
//! of the same frames, and keep the robot stopped whenever the tracker's state is unusable.

use super::frames::Expected;
use super::schema::{Arena, Experiment, Feature, RecordingState, SkeletonDescriptor, SkeletonNode};
use super::*;
use crate::host::TrialOutcome;
use crate::session::{LiveConfig, Session};
use crate::track::{Command, FishPose, Frame, Pose};
use fishprobe_io::ScratchDir;
use fishprobe_io::TrialKind;
use fishprobe_sim::{Controller, GoalSeeker, TaskParams};

const FPS: f32 = 25.0;

fn live() -> LiveConfig {
    LiveConfig {
        habituation_s: 2.0,
        release_s: 1.0,
        control_s: 6.0,
        ..LiveConfig::default()
    }
}

fn expected() -> Expected {
    Expected {
        tank_cm: 100,
        fps: FPS,
        accept_other_fps: false,
    }
}

/// Frame `k`'s robot and fish: the robot circles, the fish trails it.
fn poses(k: u32) -> (Pose, Pose) {
    let a = k as f32 * 0.02;
    let robot = Pose {
        x: 20.0 * a.cos(),
        y: 20.0 * a.sin(),
        heading: a + std::f32::consts::FRAC_PI_2,
    };
    let fish = Pose {
        x: 25.0 * (a - 0.3).cos(),
        y: 25.0 * (a - 0.3).sin(),
        heading: a - 0.3 + std::f32::consts::FRAC_PI_2,
    };
    (robot, fish)
}

/// A feature whose centre node is the pose and whose front node lies 2 cm ahead; its
/// skeleton has the front at index 0 and the centre at 2, a tail node between.
fn feature(id: u32, p: Pose) -> Feature {
    let node = |x: f32, y: f32| SkeletonNode { x, y, score: 0.9 };
    Feature {
        score: 0.9,
        out_of_bounds: None,
        id: Some(id),
        world_nodes: vec![
            node(p.x + 2.0 * p.heading.cos(), p.y + 2.0 * p.heading.sin()),
            node(f32::NAN, f32::NAN),
            node(p.x, p.y),
        ],
    }
}

fn update(state: RecordingState, frame: u32, features: Vec<Feature>) -> Experiment {
    let skeleton = SkeletonDescriptor {
        front_index: 0,
        center_index: 2,
    };
    let base = "/lab/recordings/2026-12-07_10-00-00";
    Experiment::update(FPS, base, state, frame, features, vec![7, 3], skeleton)
}

fn tracked(state: RecordingState, k: u32) -> Experiment {
    let (r, f) = poses(k);
    update(state, k, vec![feature(3, f), feature(7, r)])
}

/// Makes the test's pilot.
type Pilot = fn() -> Result<Box<dyn Controller>, crate::LiveError>;

fn observer(out: &std::path::Path) -> Observer<Pilot> {
    Observer::new(
        live(),
        TaskParams::default(),
        out.to_path_buf(),
        EntityIds {
            robot: 7,
            fish: vec![3],
        },
        expected(),
        true,
        Some(out.join("fallback")),
        goal_seeker as Pilot,
    )
    .expect("valid settings")
}

fn goal_seeker() -> Result<Box<dyn Controller>, crate::LiveError> {
    Ok(Box::new(GoalSeeker))
}

fn run(obs: &mut Observer<Pilot>, updates: impl IntoIterator<Item = Experiment>) -> Vec<Event> {
    let mut out = Vec::new();
    for e in updates {
        obs.on_update(&e, &mut out);
    }
    out
}

fn ended(events: &[Event]) -> Vec<TrialOutcome> {
    events
        .iter()
        .filter_map(|e| match e {
            Event::Ended(o) => Some(o.clone()),
            _ => None,
        })
        .collect()
}

fn stops(events: &[Event]) -> Vec<(f64, String)> {
    events
        .iter()
        .filter_map(|e| match e {
            Event::Command(Command {
                t,
                stop: true,
                reason,
                ..
            }) => Some((*t, reason.clone().unwrap_or_default())),
            _ => None,
        })
        .collect()
}

#[test]
fn the_observer_makes_the_trial_the_bridge_makes_of_the_same_frames() {
    let dir = ScratchDir::for_test("observer-same-trial");
    let mut obs = observer(&dir);
    // Frames the tracker skipped (every 9th) and frames it delivered twice or late.
    let kept: Vec<u32> = (0..=8 * FPS as u32).filter(|k| k % 9 != 4).collect();
    let mut updates = vec![tracked(RecordingState::Initial, 500)];
    for (i, &k) in kept.iter().enumerate() {
        updates.push(tracked(RecordingState::Recording, k));
        if i % 10 == 5 {
            updates.push(tracked(RecordingState::Recording, k));
            updates.push(tracked(RecordingState::Recording, k.saturating_sub(1)));
        }
    }
    let events = run(&mut obs, updates);
    let outcomes = ended(&events);
    assert_eq!(outcomes.len(), 1, "{events:?}");
    assert!(outcomes[0].complete);
    let file = outcomes[0].file.clone().expect("written");
    assert_eq!(
        file.file_name().and_then(|n| n.to_str()),
        Some("2026-12-07_10-00-00.hdf5")
    );
    let got = fishprobe_io::read_trial(&file).expect("a readable trial file");

    // The bridge, fed the same frames as JSON would give them.
    let mut bridge = Session::new(
        live(),
        TaskParams::default(),
        Box::new(GoalSeeker),
        TrialKind::Real,
    )
    .expect("valid");
    let mut commands = Vec::new();
    for &k in &kept {
        let (r, f) = poses(k);
        commands.extend(bridge.on_frame(&Frame {
            t: f64::from(k) / f64::from(FPS),
            robot: Some(r),
            fish: vec![FishPose {
                id: "3".into(),
                pose: Some(f),
            }],
        }));
        if bridge.is_done() {
            break;
        }
    }
    let want = bridge.trial_file("live guppy");
    let (g, w) = (
        got.task.as_ref().expect("task"),
        want.task.as_ref().expect("task"),
    );
    assert_eq!(g.command_frames, w.command_frames);
    assert_eq!(g.goal_frames, w.goal_frames);
    assert_eq!(g.active_goal, w.active_goal);
    assert_eq!(g.command_turns.len(), w.command_turns.len());
    // Headings come from two nodes here and as numbers there: equal to rounding.
    for (a, b) in g.command_turns.iter().zip(&w.command_turns) {
        assert!((a - b).abs() < 1e-4, "{a} vs {b}");
    }
    assert_eq!(got.entities.len(), want.entities.len());
    for b in &want.entities {
        let a = got
            .entities
            .iter()
            .find(|a| a.name == b.name)
            .expect("the same entities");
        assert_eq!(a.positions.len(), b.positions.len());
        for (p, q) in a.positions.iter().zip(&b.positions) {
            assert!(
                (p[0].is_nan() && q[0].is_nan()) || (p[0] - q[0]).abs() < 1e-5,
                "{p:?} vs {q:?}"
            );
        }
        for (p, q) in a.orientations.iter().zip(&b.orientations) {
            assert!(
                (p[0].is_nan() && q[0].is_nan()) || (p[0] - q[0]).abs() < 1e-4,
                "{p:?} vs {q:?}"
            );
        }
    }
    // What only the observer knows is in the file.
    let record: serde_json::Value = serde_json::from_str(&g.config_json).expect("json");
    // Two late updates after every tenth frame, 18 times before the trial's end.
    assert_eq!(obs.stale_updates(), 36);
    assert_eq!(record["front_end"]["stale_updates_dropped"], 36);
    assert_eq!(record["front_end"]["tracker_target_fps"], 25.0);
    assert_eq!(
        record["front_end"]["ended_because"],
        "the protocol's control time is over"
    );
    // The robot is stopped when the trial is over.
    assert_eq!(
        stops(&events).last().map(|s| s.1.as_str()),
        Some("the protocol's control time is over")
    );
}

#[test]
fn the_robot_stops_at_the_first_frame_a_tracking_gap_reaches_the_stale_time() {
    let dir = ScratchDir::for_test("observer-gap");
    let mut obs = observer(&dir);
    let mut updates = vec![tracked(RecordingState::Initial, 0)];
    updates.extend((0..=50).map(|k| tracked(RecordingState::Recording, k)));
    let before = run(&mut obs, updates);
    assert!(stops(&before).is_empty(), "{before:?}");
    // The robot vanishes from frame 51 on: 0.5 s later (frame 63.5) it must be stopped, on
    // the first frame at or past that time.
    let mut out = Vec::new();
    let mut stopped_at = None;
    for k in 51..=80 {
        let (_, f) = poses(k);
        obs.on_update(
            &update(RecordingState::Recording, k, vec![feature(3, f)]),
            &mut out,
        );
        if stopped_at.is_none() && !stops(&out).is_empty() {
            stopped_at = Some(k);
        }
    }
    assert_eq!(stopped_at, Some(63));
    assert!(stops(&out)[0].1.contains("robot not tracked"), "{out:?}");
}

#[test]
fn a_tank_or_rate_the_policy_does_not_know_keeps_the_robot_stopped_and_says_why_once() {
    let dir = ScratchDir::for_test("observer-refuse");
    let mut obs = observer(&dir);
    let mut wrong = tracked(RecordingState::Recording, 0);
    wrong.target_fps = 30.0;
    let events = run(&mut obs, [wrong.clone(), wrong.clone(), wrong]);
    let logs: Vec<&Event> = events
        .iter()
        .filter(|e| matches!(e, Event::Log(l) if l.contains("refused")))
        .collect();
    assert_eq!(logs.len(), 1, "{events:?}");
    assert_eq!(stops(&events).len(), 1);
    assert!(stops(&events)[0].1.contains("target_fps = 30"));
    assert!(!obs.in_trial());
    assert!(obs.refusal().is_some());
    // Mended: the next recording starts a trial.
    let events = run(
        &mut obs,
        [
            tracked(RecordingState::Initial, 10),
            tracked(RecordingState::Recording, 0),
        ],
    );
    assert!(events
        .iter()
        .any(|e| matches!(e, Event::Log(l) if l.contains("accepted now"))));
    assert!(obs.in_trial());
    // An arena that changes mid-trial ends the trial, which is kept.
    let mut big = tracked(RecordingState::Recording, 1);
    big.arena = Some(Arena {
        width_cm: 200,
        height_cm: 200,
    });
    let events = run(&mut obs, [big]);
    let outcomes = ended(&events);
    assert_eq!(outcomes.len(), 1);
    assert!(outcomes[0].file.as_ref().is_some_and(|f| f.exists()));
    assert!(!outcomes[0].complete);
    assert!(stops(&events).iter().any(|s| s.1.contains("200 x 200")));
}

#[test]
fn recording_starts_and_finishing_ends_each_trial_beside_the_recording() {
    let dir = ScratchDir::for_test("observer-recording");
    let mut obs = observer(&dir);
    let mut updates = vec![tracked(RecordingState::Initial, 900)];
    updates.extend((0..30).map(|k| tracked(RecordingState::Recording, k)));
    updates.push(tracked(RecordingState::Finished, 30));
    updates.push(tracked(RecordingState::Finished, 31));
    // The same recording path again (the user pressed record twice within a second).
    updates.extend((0..5).map(|k| tracked(RecordingState::Recording, k)));
    updates.push(tracked(RecordingState::Finished, 5));
    let events = run(&mut obs, updates);
    let outcomes = ended(&events);
    assert_eq!(outcomes.len(), 2, "{events:?}");
    let names: Vec<String> = outcomes
        .iter()
        .map(|o| {
            o.file
                .as_ref()
                .and_then(|f| f.file_name())
                .map(|n| n.to_string_lossy().into_owned())
                .unwrap_or_default()
        })
        .collect();
    assert_eq!(
        names,
        ["2026-12-07_10-00-00.hdf5", "2026-12-07_10-00-00_2.hdf5"]
    );
    assert!(outcomes.iter().all(|o| !o.complete));
    assert_eq!(outcomes[0].frames, 30);
    let trial = fishprobe_io::read_trial(outcomes[0].file.as_ref().expect("file")).expect("reads");
    let record: serde_json::Value =
        serde_json::from_str(&trial.task.expect("task").config_json).expect("json");
    assert_eq!(
        record["front_end"]["ended_because"],
        "the recording finished"
    );
    assert_eq!(
        record["front_end"]["recording_base_path"],
        "/lab/recordings/2026-12-07_10-00-00"
    );
}

#[test]
fn the_core_going_away_ends_the_trial_and_keeps_it() {
    let dir = ScratchDir::for_test("observer-core-gone");
    let mut obs = observer(&dir);
    let mut updates = vec![tracked(RecordingState::Initial, 0)];
    updates.extend((0..10).map(|k| tracked(RecordingState::Recording, k)));
    run(&mut obs, updates);
    // The robot program is away from frame 10 to 15 and from 20 on.
    for (k, connected) in [
        (10, false),
        (12, false),
        (15, true),
        (20, false),
        (25, false),
    ] {
        obs.set_robot_connected(connected);
        run(&mut obs, [tracked(RecordingState::Recording, k)]);
    }
    let mut out = Vec::new();
    obs.finish("tracker core gone", &mut out);
    assert_eq!(stops(&out).len(), 1);
    let o = ended(&out);
    assert_eq!(o.len(), 1);
    let trial = fishprobe_io::read_trial(o[0].file.as_ref().expect("written")).expect("reads");
    let record: serde_json::Value =
        serde_json::from_str(&trial.task.expect("task").config_json).expect("json");
    assert_eq!(record["front_end"]["ended_because"], "tracker core gone");
    assert_eq!(
        record["front_end"]["robot_program_absent_s"],
        serde_json::json!([[0.4, 0.6], [0.8, 1.0]])
    );
    // Nothing more to end.
    let mut again = Vec::new();
    obs.finish("tracker core gone", &mut again);
    assert!(again.is_empty());
}

#[test]
fn settings_come_from_the_config_entry_and_mistakes_are_named() {
    let s = ObserverSettings::from_json(
        r#"{"policy": "runs/zone", "out": "trials", "robot_id": 1, "fish_ids": [2]}"#,
    )
    .expect("valid");
    assert!(s.follow_recording && !s.accept_other_fps);
    assert_eq!(s.core.to_string(), "127.0.0.1:27342");
    assert!(s.robot_sink.ip().is_loopback());
    let err = |j: &str| ObserverSettings::from_json(j).unwrap_err().to_string();
    assert!(
        err(r#"{"policy": "p", "out": "o", "robot_id": 1, "fish_ids": [2], "fishids": [3]}"#)
            .contains("unknown key `fishids`")
    );
    // Every problem at once: a misspelt key, a mistyped value, a duplicate id.
    let all = err(
        r#"{"policy": "p", "out": "o", "robot_id": 1, "fish_ids": [1], "fishids": [3], "follow_recording": "yes"}"#,
    );
    for needle in ["unknown key `fishids`", "`follow_recording`", "given twice"] {
        assert!(all.contains(needle), "{needle}: {all}");
    }
    assert!(
        err(r#"{"policy": "p", "out": "o", "robot_id": 1, "fish_ids": [1]}"#).contains("distinct")
    );
    assert!(
        err(r#"{"policy": "p", "out": "o", "robot_id": 1, "fish_ids": []}"#)
            .contains("at least one")
    );
    assert!(err(
        r#"{"policy": "p", "out": "o", "robot_id": 1, "fish_ids": [2], "robot_sink": "0.0.0.0:9000"}"#
    )
    .contains("robot_sink_token"));
    assert!(
        err(r#"{"policy": " ", "out": "o", "robot_id": 1, "fish_ids": [2]}"#).contains("policy")
    );
    // A protocol for two fish with one id is refused when the observer is made.
    let two = LiveConfig {
        fish_count: 2,
        ..live()
    };
    assert!(Observer::new(
        two,
        TaskParams::default(),
        "o".into(),
        s.ids(),
        expected(),
        true,
        None,
        goal_seeker as Pilot,
    )
    .is_err());
}
