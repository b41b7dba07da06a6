//! From BioTracker's `Experiment` updates to the live session's tracking frames: who is the
//! robot and who the fish, their poses, the trial's time, and which updates to drop.

use super::schema::{Experiment, Feature, RecordingState, SkeletonDescriptor};
use crate::track::{FishPose, Frame, Pose};

/// The entities an observer follows, by BioTracker entity id.
#[derive(Debug, Clone, PartialEq, Eq)]
pub struct EntityIds {
    /// The robot's entity id.
    pub robot: u32,
    /// The fish's entity ids, in the order the policy's observation lists them.
    pub fish: Vec<u32>,
}

impl EntityIds {
    /// Checks that the ids are distinct and that there is at least one fish.
    pub fn validate(&self) -> Result<(), crate::LiveError> {
        if self.fish.is_empty() {
            return Err(crate::LiveError::Settings(
                "no fish entity id: list at least one".into(),
            ));
        }
        let mut all = self.fish.clone();
        all.push(self.robot);
        all.sort_unstable();
        if let Some(w) = all.windows(2).find(|w| w[0] == w[1]) {
            return Err(crate::LiveError::Settings(format!(
                "entity id {} is given twice (robot and fish ids must be distinct)",
                w[0]
            )));
        }
        Ok(())
    }
}

/// An entity's pose from its feature: the skeleton's centre node, heading from the centre to
/// the front node, `atan2(front.y - centre.y, front.x - centre.x)` (BioTracker's own pose
/// helper returns pi minus that). `None` (untracked) when the feature is out of bounds, when
/// either node is missing or not finite, or when the two nodes coincide (no heading).
pub fn pose_of(f: &Feature, skeleton: &SkeletonDescriptor) -> Option<Pose> {
    if f.out_of_bounds == Some(true) {
        return None;
    }
    let node = |i: u32| {
        f.world_nodes
            .get(i as usize)
            .filter(|n| n.x.is_finite() && n.y.is_finite())
    };
    let front = node(skeleton.front_index)?;
    let centre = node(skeleton.center_index)?;
    let (dx, dy) = (front.x - centre.x, front.y - centre.y);
    if dx == 0.0 && dy == 0.0 {
        return None;
    }
    Some(Pose {
        x: centre.x,
        y: centre.y,
        heading: dy.atan2(dx),
    })
}

/// The pose of entity `id` in the update's features: untracked when no feature carries the id,
/// or when two do (the tracker could not tell them apart).
fn pose_of_id(e: &Experiment, skeleton: &SkeletonDescriptor, id: u32) -> Option<Pose> {
    let features = e.last_features.as_ref()?;
    let mut found = features.features.iter().filter(|f| f.id == Some(id));
    let f = found.next()?;
    if found.next().is_some() {
        return None;
    }
    pose_of(f, skeleton)
}

/// The tracking frame of an update at time `t` (s): the robot and the fish by id.
pub fn frame_of(e: &Experiment, skeleton: &SkeletonDescriptor, ids: &EntityIds, t: f64) -> Frame {
    Frame {
        t,
        robot: pose_of_id(e, skeleton, ids.robot),
        fish: ids
            .fish
            .iter()
            .map(|&id| FishPose {
                id: id.to_string(),
                pose: pose_of_id(e, skeleton, id),
            })
            .collect(),
    }
}

/// What the tank and the tracking must be for a trial, checked on the first update.
#[derive(Debug, Clone, PartialEq)]
pub struct Expected {
    /// The tank's side (cm); the policy was trained for a square tank of this side.
    pub tank_cm: u32,
    /// The tracking rate the policy was trained at (Hz).
    pub fps: f32,
    /// Accept another `target_fps` (recorded in the trial file).
    pub accept_other_fps: bool,
}

/// Checks an update against what the trial needs: the tank's size, the tracking rate, the
/// entities and the skeleton. Returns the skeleton to read poses with, or why not.
pub fn check_experiment(
    e: &Experiment,
    ids: &EntityIds,
    want: &Expected,
) -> Result<SkeletonDescriptor, crate::LiveError> {
    match e.arena {
        Some(a) if a.width_cm == want.tank_cm && a.height_cm == want.tank_cm => {}
        Some(a) => {
            return Err(crate::LiveError::TrackerState(format!(
                "the arena is {} x {} cm; the policy was trained for a {t} x {t} cm tank",
                a.width_cm,
                a.height_cm,
                t = want.tank_cm
            )))
        }
        None => {
            return Err(crate::LiveError::TrackerState(
                "the tracker sent no arena (tank size)".into(),
            ))
        }
    }
    if !(e.target_fps.is_finite() && e.target_fps > 0.0) {
        return Err(crate::LiveError::TrackerState(format!(
            "the tracker's target_fps is {}, not a rate",
            e.target_fps
        )));
    }
    if e.target_fps != want.fps && !want.accept_other_fps {
        return Err(crate::LiveError::TrackerState(format!(
            "the tracker runs at target_fps = {} Hz; the policy was trained at {} Hz (set \
             accept_other_fps to run anyway; the trial file records it)",
            e.target_fps, want.fps
        )));
    }
    let Some(skeleton) = e.skeleton else {
        return Err(crate::LiveError::TrackerState(
            "the tracker sent no skeleton (front and centre nodes)".into(),
        ));
    };
    if skeleton.front_index == skeleton.center_index {
        return Err(crate::LiveError::TrackerState(format!(
            "the skeleton's front and centre are the same node ({}): no heading",
            skeleton.front_index
        )));
    }
    let missing: Vec<String> = std::iter::once(ids.robot)
        .chain(ids.fish.iter().copied())
        .filter(|id| !e.entity_ids.contains(id))
        .map(|id| id.to_string())
        .collect();
    if !missing.is_empty() {
        return Err(crate::LiveError::TrackerState(format!(
            "entity id(s) {} are not among the tracker's entities {:?}",
            missing.join(", "),
            e.entity_ids
        )));
    }
    Ok(skeleton)
}

/// What one update means for the trial.
#[derive(Debug, Clone, PartialEq)]
pub enum Step {
    /// Not in a trial (no recording yet, or the last one ended): nothing to do.
    Idle,
    /// A recording started: a trial begins, named after the recording's file stem (when it
    /// has one); the update is also the trial's first frame, at `t`.
    Start {
        /// The recording's `base_path` stem.
        stem: Option<String>,
        /// The trial's time zero (s): the recording's frame 0 when following the recording
        /// (the core's first tracked frame of a recording is often frame 1 or later; counted
        /// from frame 0, the trial file's frame k is the recording's frame k, as in the
        /// tracker's own track and video), else the first frame's time.
        origin: f64,
        /// The frame's time (s).
        t: f64,
    },
    /// A frame of the running trial at time `t` (s).
    Frame {
        /// The frame's time.
        t: f64,
    },
    /// The recording ended: the trial ends.
    End,
    /// A frame number not newer than the last of the same recording (the core's updates may
    /// overlap and arrive out of order): dropped.
    Stale,
}

/// Frame numbers from here up, during a recording, are frames tracked before it started. The
/// core numbers a recording's frames as `frame - start` in 32 bits, `start` being the frame it
/// showed when recording began; a frame whose tracking was still running then is older, and
/// its number wraps to just below 2^32 (a release build; a debug build of the core panics).
/// A real recording reaches 2^31 frames after 2.7 years at 25 Hz.
pub const WRAPPED_FRAME: u32 = 1 << 31;

/// Follows BioTracker's recording and frame numbers: which update starts a trial, which ends
/// it, which frames are stale, and each frame's time (`frame_number / target_fps`; the frame
/// number restarts at 0 when a recording starts).
///
/// With `follow_recording` off, a trial starts at the first update and time runs on through
/// recordings: when the frame number restarts, the time continues from the last frame.
#[derive(Debug, Clone)]
pub struct RecordingGate {
    follow_recording: bool,
    in_trial: bool,
    state: i32,
    last_frame: Option<u32>,
    /// Added to `frame_number / target_fps` (only without `follow_recording`).
    offset_s: f64,
    last_t: f64,
    stale: u64,
}

impl RecordingGate {
    /// A gate; see the type's docs.
    pub fn new(follow_recording: bool) -> Self {
        Self {
            follow_recording,
            in_trial: false,
            state: RecordingState::Initial as i32,
            last_frame: None,
            offset_s: 0.0,
            last_t: f64::NEG_INFINITY,
            stale: 0,
        }
    }

    /// Updates dropped as stale so far.
    pub fn stale(&self) -> u64 {
        self.stale
    }

    /// Whether a trial is running.
    pub fn in_trial(&self) -> bool {
        self.in_trial
    }

    /// Ends the running trial from outside (the protocol's time ran out, or a fault): the
    /// gate stays idle until the next recording starts (with `follow_recording` off, for
    /// good).
    pub fn close(&mut self) {
        self.in_trial = false;
    }

    /// The meaning of one update (`target_fps` checked positive beforehand).
    pub fn step(&mut self, e: &Experiment) -> Step {
        let recording = e.recording_state == RecordingState::Recording as i32;
        let frame = e.last_features.as_ref().map_or(0, |f| f.frame_number);
        if recording && frame >= WRAPPED_FRAME {
            // Tracked before the recording started: not a frame of it (nor its start).
            self.stale += 1;
            return Step::Stale;
        }
        let fps = f64::from(e.target_fps);
        let changed = e.recording_state != self.state;
        self.state = e.recording_state;
        if changed {
            // Frame numbers restart with a recording: the old numbers say nothing any more.
            self.last_frame = None;
            if !self.follow_recording {
                self.offset_s = if self.last_t.is_finite() {
                    self.last_t + 1.0 / fps - f64::from(frame) / fps
                } else {
                    0.0
                };
            }
        }
        if self.last_frame.is_some_and(|last| frame <= last) {
            self.stale += 1;
            return Step::Stale;
        }
        self.last_frame = Some(frame);
        let t = f64::from(frame) / fps + self.offset_s;
        if self.follow_recording {
            if changed && recording && !self.in_trial {
                self.in_trial = true;
                self.last_t = t;
                let stem = e
                    .recording_config
                    .as_ref()
                    .and_then(|c| stem_of(&c.base_path));
                return Step::Start {
                    stem,
                    origin: 0.0,
                    t,
                };
            }
            if self.in_trial && !recording {
                self.in_trial = false;
                return Step::End;
            }
        } else if !self.in_trial && !self.last_t.is_finite() {
            self.in_trial = true;
            self.last_t = t;
            return Step::Start {
                stem: None,
                origin: t,
                t,
            };
        }
        if !self.in_trial {
            return Step::Idle;
        }
        self.last_t = t;
        Step::Frame { t }
    }
}

/// The file stem of a recording's `base_path` (`<folder>/<date-time>`): its last component,
/// made safe as a file name ([`fishprobe_io::StudyLayout::safe_name`]); `None` when the path
/// names no file.
pub fn stem_of(base_path: &str) -> Option<String> {
    let last = base_path
        .rsplit(['/', '\\'])
        .find(|s| !s.is_empty() && *s != "." && *s != "..")?;
    Some(fishprobe_io::StudyLayout::safe_name(last))
}

#[cfg(test)]
mod tests {
    use super::super::schema::{Arena, SkeletonNode};
    use super::*;

    const SK: SkeletonDescriptor = SkeletonDescriptor {
        front_index: 0,
        center_index: 1,
    };

    fn feature(id: Option<u32>, front: (f32, f32), centre: (f32, f32)) -> Feature {
        let node = |(x, y): (f32, f32)| SkeletonNode { x, y, score: 1.0 };
        Feature {
            score: 1.0,
            out_of_bounds: None,
            id,
            world_nodes: vec![node(front), node(centre)],
        }
    }

    fn update(state: RecordingState, frame: u32, features: Vec<Feature>) -> Experiment {
        let base = "/data/rec/2026-12-07_10-00-00";
        Experiment::update(25.0, base, state, frame, features, vec![1, 2], SK)
    }

    fn ids() -> EntityIds {
        EntityIds {
            robot: 1,
            fish: vec![2],
        }
    }

    #[test]
    fn the_pose_is_the_centre_and_the_heading_points_to_the_front() {
        let p = pose_of(&feature(Some(1), (3.0, 4.0), (2.0, 3.0)), &SK).expect("tracked");
        assert_eq!((p.x, p.y), (2.0, 3.0));
        assert!((p.heading - std::f32::consts::FRAC_PI_4).abs() < 1e-6);
        // Front to the left of the centre: heading pi, where BioTracker's helper says 0.
        let p = pose_of(&feature(Some(1), (-1.0, 0.0), (0.0, 0.0)), &SK).expect("tracked");
        assert!((p.heading - std::f32::consts::PI).abs() < 1e-6);
        // Untracked: NaN node, a node missing, both nodes on one point, out of bounds.
        assert!(pose_of(&feature(Some(1), (f32::NAN, 0.0), (0.0, 0.0)), &SK).is_none());
        let mut one_node = feature(Some(1), (1.0, 0.0), (0.0, 0.0));
        one_node.world_nodes.truncate(1);
        assert!(pose_of(&one_node, &SK).is_none());
        assert!(pose_of(&feature(Some(1), (1.0, 1.0), (1.0, 1.0)), &SK).is_none());
        let mut out = feature(Some(1), (1.0, 0.0), (0.0, 0.0));
        out.out_of_bounds = Some(true);
        assert!(pose_of(&out, &SK).is_none());
    }

    #[test]
    fn robot_and_fish_are_found_by_id_and_untracked_when_absent_or_ambiguous() {
        let e = update(
            RecordingState::Recording,
            5,
            vec![
                feature(None, (9.0, 9.0), (8.0, 8.0)),
                feature(Some(2), (1.0, 0.0), (0.0, 0.0)),
                feature(Some(1), (11.0, 10.0), (10.0, 10.0)),
            ],
        );
        let Frame { t, robot, fish } = frame_of(&e, &SK, &ids(), 0.2);
        assert_eq!(t, 0.2);
        assert_eq!(robot.map(|p| p.x), Some(10.0));
        assert_eq!(fish.len(), 1);
        assert_eq!(fish[0].id, "2");
        assert_eq!(fish[0].pose.map(|p| p.x), Some(0.0));
        // Two features claim the robot's id; the fish's is missing.
        let e = update(
            RecordingState::Recording,
            6,
            vec![
                feature(Some(1), (1.0, 0.0), (0.0, 0.0)),
                feature(Some(1), (3.0, 0.0), (2.0, 0.0)),
            ],
        );
        let Frame { robot, fish, .. } = frame_of(&e, &SK, &ids(), 0.24);
        assert!(robot.is_none());
        assert!(fish[0].pose.is_none());
    }

    #[test]
    fn the_first_update_is_checked_for_tank_rate_ids_and_skeleton() {
        let want = Expected {
            tank_cm: 100,
            fps: 25.0,
            accept_other_fps: false,
        };
        let good = update(RecordingState::Initial, 0, vec![]);
        assert_eq!(check_experiment(&good, &ids(), &want).ok(), Some(SK));
        let mut e = good.clone();
        e.arena = Some(Arena {
            width_cm: 200,
            height_cm: 100,
        });
        assert!(check_experiment(&e, &ids(), &want)
            .unwrap_err()
            .to_string()
            .contains("200 x 100"));
        let mut e = good.clone();
        e.target_fps = 30.0;
        let err = check_experiment(&e, &ids(), &want).unwrap_err().to_string();
        assert!(
            err.contains("30") && err.contains("accept_other_fps"),
            "{err}"
        );
        assert!(check_experiment(
            &e,
            &ids(),
            &Expected {
                accept_other_fps: true,
                ..want.clone()
            }
        )
        .is_ok());
        let mut e = good.clone();
        e.skeleton = None;
        assert!(check_experiment(&e, &ids(), &want)
            .unwrap_err()
            .to_string()
            .contains("skeleton"));
        let mut e = good.clone();
        e.entity_ids = vec![1];
        assert!(check_experiment(&e, &ids(), &want)
            .unwrap_err()
            .to_string()
            .contains("entity id(s) 2"));
        assert!(EntityIds {
            robot: 3,
            fish: vec![4, 3]
        }
        .validate()
        .unwrap_err()
        .to_string()
        .contains("id 3"));
    }

    #[test]
    fn recording_starts_and_ends_the_trial_and_stale_frames_are_dropped() {
        let mut g = RecordingGate::new(true);
        assert_eq!(
            g.step(&update(RecordingState::Initial, 100, vec![])),
            Step::Idle
        );
        assert_eq!(
            g.step(&update(RecordingState::Initial, 101, vec![])),
            Step::Idle
        );
        // Recording: frame numbers restart at 0, and the trial's time zero is frame 0 even
        // when the first frame tracked is a later one.
        assert_eq!(
            g.step(&update(RecordingState::Recording, 1, vec![])),
            Step::Start {
                stem: Some("2026-12-07_10-00-00".into()),
                origin: 0.0,
                t: 0.04
            }
        );
        assert_eq!(
            g.step(&update(RecordingState::Recording, 2, vec![])),
            Step::Frame { t: 0.08 }
        );
        // An overlapping update that arrives late, and a repeat: dropped and counted.
        assert_eq!(
            g.step(&update(RecordingState::Recording, 1, vec![])),
            Step::Stale
        );
        assert_eq!(
            g.step(&update(RecordingState::Recording, 2, vec![])),
            Step::Stale
        );
        assert_eq!(g.stale(), 2);
        assert_eq!(
            g.step(&update(RecordingState::Recording, 3, vec![])),
            Step::Frame { t: 0.12 }
        );
        assert_eq!(
            g.step(&update(RecordingState::Finished, 4, vec![])),
            Step::End
        );
        assert_eq!(
            g.step(&update(RecordingState::Finished, 5, vec![])),
            Step::Idle
        );
        // A frame tracked before the next recording, numbered by the core's wrapped
        // subtraction: dropped, and the recording still starts at its first real frame.
        assert_eq!(
            g.step(&update(RecordingState::Recording, u32::MAX, vec![])),
            Step::Stale
        );
        assert_eq!(g.stale(), 3);
        // The next recording starts the next trial; one closed from outside waits for it.
        assert!(matches!(
            g.step(&update(RecordingState::Recording, 0, vec![])),
            Step::Start { .. }
        ));
        g.close();
        assert_eq!(
            g.step(&update(RecordingState::Recording, 1, vec![])),
            Step::Idle
        );
    }

    #[test]
    fn without_following_recording_time_runs_on_when_frame_numbers_restart() {
        let mut g = RecordingGate::new(false);
        assert_eq!(
            g.step(&update(RecordingState::Initial, 50, vec![])),
            Step::Start {
                stem: None,
                origin: 2.0,
                t: 2.0
            }
        );
        assert_eq!(
            g.step(&update(RecordingState::Initial, 51, vec![])),
            Step::Frame { t: 2.04 }
        );
        // Recording starts: frame 0 comes one frame after frame 51.
        match g.step(&update(RecordingState::Recording, 0, vec![])) {
            Step::Frame { t } => assert!((t - 2.08).abs() < 1e-9, "{t}"),
            other => panic!("{other:?}"),
        }
        match g.step(&update(RecordingState::Recording, 1, vec![])) {
            Step::Frame { t } => assert!((t - 2.12).abs() < 1e-9, "{t}"),
            other => panic!("{other:?}"),
        }
    }

    #[test]
    fn a_stem_is_the_last_path_component_made_safe() {
        assert_eq!(
            stem_of("/a/b/2026-12-07 10:00").as_deref(),
            Some("2026-12-07_10_00")
        );
        assert_eq!(stem_of("C:\\rec\\trial_1").as_deref(), Some("trial_1"));
        assert_eq!(stem_of("/rec/").as_deref(), Some("rec"));
        assert_eq!(stem_of(""), None);
        assert_eq!(stem_of("/../"), None);
        assert_eq!(stem_of("/data/.hidden").as_deref(), Some("_hidden"));
    }
}
