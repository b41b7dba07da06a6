//! fishprobe's own protobuf schema for the BioTracker v4 messages an observer reads.
//!
//! Package `biotracker`, proto3. Names, field numbers and types are interface facts of
//! BioTracker v4 (its tracker core and components talk gRPC over loopback); this file states
//! only the subset an observer needs, written for fishprobe. Fields it leaves out are skipped by
//! the decoder, as proto3 requires, so the subset reads the full messages unchanged.
//!
//! The structs are written with `prost`'s derive macros directly (no `.proto` file, no
//! `protoc`): the derive is the schema.

/// `biotracker.Empty`.
#[derive(Clone, Copy, PartialEq, Eq, ::prost::Message)]
pub struct Empty {}

/// `biotracker.SkeletonNode`: one node of a tracked skeleton, in cm (world nodes).
#[derive(Clone, Copy, PartialEq, ::prost::Message)]
pub struct SkeletonNode {
    /// x (cm, tank centre origin, x right); may be NaN.
    #[prost(float, tag = "1")]
    pub x: f32,
    /// y (cm, y up); may be NaN.
    #[prost(float, tag = "2")]
    pub y: f32,
    /// The detector's confidence in the node.
    #[prost(float, tag = "3")]
    pub score: f32,
}

/// `biotracker.Feature`: one detected animal (or robot) in a frame.
#[derive(Clone, PartialEq, ::prost::Message)]
pub struct Feature {
    /// The detection's score.
    #[prost(float, tag = "2")]
    pub score: f32,
    /// Set when the tracker found it outside the arena.
    #[prost(bool, optional, tag = "3")]
    pub out_of_bounds: Option<bool>,
    /// The entity id the tracker matched it to (absent: unmatched).
    #[prost(uint32, optional, tag = "4")]
    pub id: Option<u32>,
    /// The skeleton's nodes in world coordinates (cm).
    #[prost(message, repeated, tag = "5")]
    pub world_nodes: Vec<SkeletonNode>,
}

/// `biotracker.Features`: the features of one frame.
#[derive(Clone, PartialEq, ::prost::Message)]
pub struct Features {
    /// The detections.
    #[prost(message, repeated, tag = "1")]
    pub features: Vec<Feature>,
    /// The frame's number (restarts at 0 when a recording starts).
    #[prost(uint32, tag = "3")]
    pub frame_number: u32,
}

/// `biotracker.SkeletonDescriptor`: which skeleton nodes are the front and the centre.
#[derive(Clone, Copy, PartialEq, Eq, ::prost::Message)]
pub struct SkeletonDescriptor {
    /// Index of the front node (head).
    #[prost(uint32, tag = "3")]
    pub front_index: u32,
    /// Index of the centre node (the pose).
    #[prost(uint32, tag = "4")]
    pub center_index: u32,
}

/// `biotracker.Arena`: the tank's size.
#[derive(Clone, Copy, PartialEq, Eq, ::prost::Message)]
pub struct Arena {
    /// Width (cm).
    #[prost(uint32, tag = "3")]
    pub width_cm: u32,
    /// Height (cm).
    #[prost(uint32, tag = "4")]
    pub height_cm: u32,
}

/// `biotracker.RecordingState`.
#[derive(Clone, Copy, Debug, PartialEq, Eq, Hash, PartialOrd, Ord, ::prost::Enumeration)]
#[repr(i32)]
pub enum RecordingState {
    /// Not recording yet.
    Initial = 0,
    /// Recording: a trial runs.
    Recording = 2,
    /// The recording ended.
    Finished = 3,
}

/// `biotracker.RecordingConfig`: where the recording goes.
#[derive(Clone, PartialEq, ::prost::Message)]
pub struct RecordingConfig {
    /// The recording's path without extension (`<folder>/<date-time>`); BioTracker writes its
    /// track and its robofish.io file beside it.
    #[prost(string, tag = "1")]
    pub base_path: String,
    /// The recording's frame rate.
    #[prost(double, tag = "2")]
    pub fps: f64,
}

/// `biotracker.Experiment`: the tracker's state, sent to every observer on each frame.
#[derive(Clone, PartialEq, ::prost::Message)]
pub struct Experiment {
    /// The tracking rate (frames per second); time is `frame_number / target_fps`.
    #[prost(float, tag = "3")]
    pub target_fps: f32,
    /// The current recording's settings.
    #[prost(message, optional, tag = "5")]
    pub recording_config: Option<RecordingConfig>,
    /// The tank.
    #[prost(message, optional, tag = "6")]
    pub arena: Option<Arena>,
    /// Recording state ([`RecordingState`]; other values read as not recording).
    #[prost(enumeration = "RecordingState", tag = "8")]
    pub recording_state: i32,
    /// This frame's features.
    #[prost(message, optional, tag = "11")]
    pub last_features: Option<Features>,
    /// The ids of the entities being tracked.
    #[prost(uint32, repeated, tag = "13")]
    pub entity_ids: Vec<u32>,
    /// The skeleton's layout.
    #[prost(message, optional, tag = "18")]
    pub skeleton: Option<SkeletonDescriptor>,
}

impl Experiment {
    /// One update as BioTracker v4 sends it for the 100 x 100 cm tank: the rate `fps`, the
    /// recording at `base_path` in `state`, frame `frame` with its `features`, the tracked
    /// `entity_ids` and the skeleton's layout. What a stand-in core sends (tests, the
    /// benchmark).
    pub fn update(
        fps: f32,
        base_path: &str,
        state: RecordingState,
        frame: u32,
        features: Vec<Feature>,
        entity_ids: Vec<u32>,
        skeleton: SkeletonDescriptor,
    ) -> Self {
        Self {
            target_fps: fps,
            recording_config: Some(RecordingConfig {
                base_path: base_path.into(),
                fps: f64::from(fps),
            }),
            arena: Some(Arena {
                width_cm: 100,
                height_cm: 100,
            }),
            recording_state: state as i32,
            last_features: Some(Features {
                features,
                frame_number: frame,
            }),
            entity_ids,
            skeleton: Some(skeleton),
        }
    }
}

/// `biotracker.ComponentConfig`: a component's configuration from the core's config file.
#[derive(Clone, PartialEq, Eq, ::prost::Message)]
pub struct ComponentConfig {
    /// The entry's `config_json`, as a JSON string.
    #[prost(string, tag = "1")]
    pub config_json: String,
    /// The entry's id.
    #[prost(string, tag = "2")]
    pub id: String,
}

#[cfg(test)]
mod tests {
    use super::*;
    use prost::Message;

    /// Hand-encoded wire bytes (tag = field << 3 | wire type) prove the numbers, not just a
    /// round trip through the same derive.
    #[test]
    fn the_wire_numbers_are_the_trackers() {
        // SkeletonNode{x: 1.0, y: -2.0, score: 0.5}: fields 1, 2, 3 as 32-bit floats (type 5).
        let mut want = vec![0x0d];
        want.extend(1.0f32.to_le_bytes());
        want.push(0x15);
        want.extend((-2.0f32).to_le_bytes());
        want.push(0x1d);
        want.extend(0.5f32.to_le_bytes());
        let node = SkeletonNode {
            x: 1.0,
            y: -2.0,
            score: 0.5,
        };
        assert_eq!(node.encode_to_vec(), want);

        // Experiment with target_fps (3, float), recording_state (8, varint), entity_ids (13,
        // packed), arena (6) and skeleton (18, a two-byte tag).
        let e = Experiment {
            target_fps: 25.0,
            recording_state: RecordingState::Recording as i32,
            entity_ids: vec![1, 2],
            arena: Some(Arena {
                width_cm: 100,
                height_cm: 100,
            }),
            skeleton: Some(SkeletonDescriptor {
                front_index: 0,
                center_index: 1,
            }),
            ..Experiment::default()
        };
        let bytes = e.encode_to_vec();
        let mut want = vec![0x1d];
        want.extend(25.0f32.to_le_bytes());
        want.extend([0x32, 4, 0x18, 100, 0x20, 100]); // arena: field 6, length 4
        want.extend([0x40, 2]); // recording_state: field 8
        want.extend([0x6a, 2, 1, 2]); // entity_ids: field 13, packed
        want.extend([0x92, 0x01, 2, 0x20, 1]); // skeleton: field 18; front 0 is the default
        assert_eq!(bytes, want);
        assert_eq!(Experiment::decode(bytes.as_slice()).ok(), Some(e));
    }

    #[test]
    fn fields_it_does_not_know_are_skipped() {
        // Field 99 (a string) and field 7 (a varint) in front of a known field.
        let mut bytes = vec![0x9a, 0x06, 3, b'a', b'b', b'c', 0x38, 5];
        bytes.extend([0x0a, 4, b'p', b'a', b't', b'h']);
        let c = RecordingConfig::decode(bytes.as_slice()).expect("decodes");
        assert_eq!(c.base_path, "path");
        // A recording state fishprobe does not know stays a number.
        let e = Experiment::decode([0x40, 1].as_slice()).expect("decodes");
        assert!(RecordingState::try_from(e.recording_state).is_err());
    }
}
