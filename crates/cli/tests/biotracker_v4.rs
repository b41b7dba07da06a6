//! Opt-in: fishprobe beside a real BioTracker v4 build.
//!
//! Needs a biotracker_v4 checkout that the user built (`cargo build`), named by
//! `BIOTRACKER_V4_DIR` (its binary is looked for in `target/release` then `target/debug`, or
//! named by `BIOTRACKER_V4_BIN`), `protoc` on the PATH, and `python3` with the `venv` module.
//! Run with
//!
//! ```text
//! BIOTRACKER_V4_DIR=/path/to/biotracker_v4 cargo test -p fishprobe --test biotracker_v4 -- --ignored
//! ```
//!
//! Two tests:
//! - fishprobe's schema against the upstream protocol files, compiled at test time by `protoc`:
//!   every message, field, number, label and type fishprobe states is the same upstream, and so
//!   are the methods it calls and serves;
//! - a headless core (`--video fake:///`, a blank image stream) with three components: its own
//!   Hungarian matcher, a replay feature detector written here that serves a recorded trial's
//!   poses by frame number, and fishprobe as observer, started through the Python launcher the
//!   lab's config names. A robot program reads the robot sink. The test records through the
//!   core's own commands and checks the trial file, the stop at a tracking gap, and the stop
//!   when the core dies.

#![allow(clippy::unwrap_used)] // a failure is a test failure

mod common;

use common::fresh_dir as dir;
use common::tracker::{
    config_json, free_addr, record_trial, recorded_poses, robot_program, runtime, FPS, PROTOCOL,
};
use fishprobe_live::biotracker::grpc::{self, Client, Methods};
use fishprobe_live::biotracker::schema::{
    Arena, ComponentConfig, Empty, Experiment, Feature, Features, RecordingConfig, RecordingState,
    SkeletonDescriptor, SkeletonNode,
};
use prost::Message;
use std::collections::HashMap;
use std::net::TcpListener;
use std::path::{Path, PathBuf};
use std::process::{Child, Command, Stdio};
use std::sync::atomic::{AtomicBool, Ordering};
use std::sync::{Arc, Mutex};
use std::time::{Duration, Instant};

/// The checkout, or a panic that says how to name it.
fn upstream_dir() -> PathBuf {
    let dir = std::env::var_os("BIOTRACKER_V4_DIR")
        .map(PathBuf::from)
        .expect(
            "BIOTRACKER_V4_DIR names a biotracker_v4 checkout (built with cargo build) for this \
         opt-in test",
        );
    assert!(
        dir.join("protocol").is_dir(),
        "{} has no protocol/ folder: not a biotracker_v4 checkout",
        dir.display()
    );
    dir
}

// ---------------------------------------------------------------------------------------------
// The schema, against the upstream protocol files.
// ---------------------------------------------------------------------------------------------

/// The parts of `google/protobuf/descriptor.proto` this check reads (protoc's output format).
mod descriptor {
    #[derive(Clone, PartialEq, prost::Message)]
    pub struct FileDescriptorSet {
        #[prost(message, repeated, tag = "1")]
        pub file: Vec<FileDescriptorProto>,
    }
    #[derive(Clone, PartialEq, prost::Message)]
    pub struct FileDescriptorProto {
        #[prost(string, optional, tag = "1")]
        pub name: Option<String>,
        #[prost(string, optional, tag = "2")]
        pub package: Option<String>,
        #[prost(message, repeated, tag = "4")]
        pub message_type: Vec<DescriptorProto>,
        #[prost(message, repeated, tag = "5")]
        pub enum_type: Vec<EnumDescriptorProto>,
        #[prost(message, repeated, tag = "6")]
        pub service: Vec<ServiceDescriptorProto>,
    }
    #[derive(Clone, PartialEq, prost::Message)]
    pub struct DescriptorProto {
        #[prost(string, optional, tag = "1")]
        pub name: Option<String>,
        #[prost(message, repeated, tag = "2")]
        pub field: Vec<FieldDescriptorProto>,
    }
    #[derive(Clone, PartialEq, prost::Message)]
    pub struct FieldDescriptorProto {
        #[prost(string, optional, tag = "1")]
        pub name: Option<String>,
        #[prost(int32, optional, tag = "3")]
        pub number: Option<i32>,
        #[prost(int32, optional, tag = "4")]
        pub label: Option<i32>,
        #[prost(int32, optional, tag = "5")]
        pub r#type: Option<i32>,
        #[prost(string, optional, tag = "6")]
        pub type_name: Option<String>,
        #[prost(int32, optional, tag = "9")]
        pub oneof_index: Option<i32>,
        #[prost(bool, optional, tag = "17")]
        pub proto3_optional: Option<bool>,
    }
    #[derive(Clone, PartialEq, prost::Message)]
    pub struct EnumDescriptorProto {
        #[prost(string, optional, tag = "1")]
        pub name: Option<String>,
        #[prost(message, repeated, tag = "2")]
        pub value: Vec<EnumValueDescriptorProto>,
    }
    #[derive(Clone, PartialEq, prost::Message)]
    pub struct EnumValueDescriptorProto {
        #[prost(string, optional, tag = "1")]
        pub name: Option<String>,
        #[prost(int32, optional, tag = "2")]
        pub number: Option<i32>,
    }
    #[derive(Clone, PartialEq, prost::Message)]
    pub struct ServiceDescriptorProto {
        #[prost(string, optional, tag = "1")]
        pub name: Option<String>,
        #[prost(message, repeated, tag = "2")]
        pub method: Vec<MethodDescriptorProto>,
    }
    #[derive(Clone, PartialEq, prost::Message)]
    pub struct MethodDescriptorProto {
        #[prost(string, optional, tag = "1")]
        pub name: Option<String>,
        #[prost(string, optional, tag = "2")]
        pub input_type: Option<String>,
        #[prost(string, optional, tag = "3")]
        pub output_type: Option<String>,
    }

    // FieldDescriptorProto.Type and .Label.
    pub const TYPE_DOUBLE: i32 = 1;
    pub const TYPE_FLOAT: i32 = 2;
    pub const TYPE_INT64: i32 = 3;
    pub const TYPE_UINT64: i32 = 4;
    pub const TYPE_INT32: i32 = 5;
    pub const TYPE_FIXED64: i32 = 6;
    pub const TYPE_FIXED32: i32 = 7;
    pub const TYPE_BOOL: i32 = 8;
    pub const TYPE_STRING: i32 = 9;
    pub const TYPE_MESSAGE: i32 = 11;
    pub const TYPE_BYTES: i32 = 12;
    pub const TYPE_UINT32: i32 = 13;
    pub const TYPE_ENUM: i32 = 14;
    pub const TYPE_SFIXED32: i32 = 15;
    pub const TYPE_SFIXED64: i32 = 16;
    pub const TYPE_SINT32: i32 = 17;
    pub const TYPE_SINT64: i32 = 18;
    pub const LABEL_REPEATED: i32 = 3;
}

use descriptor::{DescriptorProto, EnumDescriptorProto, FieldDescriptorProto};

/// The upstream protocol of the checkout, compiled by `protoc` now.
struct Upstream {
    package: String,
    messages: HashMap<String, DescriptorProto>,
    enums: HashMap<String, EnumDescriptorProto>,
    /// `/package.Service/method` -> (input, output) type names without the package.
    methods: HashMap<String, (String, String)>,
}

fn compile_upstream(dir: &Path, out: &Path) -> Upstream {
    let protos: Vec<PathBuf> = std::fs::read_dir(dir.join("protocol"))
        .unwrap()
        .map(|e| e.unwrap().path())
        .filter(|p| p.extension().is_some_and(|x| x == "proto"))
        .collect();
    assert!(!protos.is_empty(), "no .proto files in {}", dir.display());
    let set = out.join("upstream.pb");
    let status = Command::new("protoc")
        .arg(format!("-I{}", dir.join("protocol").display()))
        .arg("--include_imports")
        .arg(format!("--descriptor_set_out={}", set.display()))
        .args(protos.iter().map(|p| p.file_name().unwrap()))
        .status()
        .expect("protoc runs (Debian: protobuf-compiler)");
    assert!(status.success(), "protoc failed on the upstream protocol");
    let set = descriptor::FileDescriptorSet::decode(std::fs::read(set).unwrap().as_slice())
        .expect("protoc's descriptor set decodes");
    let mut up = Upstream {
        package: String::new(),
        messages: HashMap::new(),
        enums: HashMap::new(),
        methods: HashMap::new(),
    };
    let strip = |t: &Option<String>| {
        t.clone()
            .unwrap_or_default()
            .rsplit('.')
            .next()
            .unwrap_or_default()
            .to_string()
    };
    for f in set.file {
        let package = f.package.clone().unwrap_or_default();
        if package != "biotracker" {
            continue; // imported well-known types
        }
        up.package = package.clone();
        for m in f.message_type {
            up.messages.insert(m.name.clone().unwrap(), m);
        }
        for e in f.enum_type {
            up.enums.insert(e.name.clone().unwrap(), e);
        }
        for s in f.service {
            for m in s.method {
                let path = format!(
                    "/{package}.{}/{}",
                    s.name.clone().unwrap(),
                    m.name.clone().unwrap()
                );
                up.methods
                    .insert(path, (strip(&m.input_type), strip(&m.output_type)));
            }
        }
    }
    assert_eq!(up.package, "biotracker", "no package biotracker upstream");
    up
}

/// The top-level `name: value` pairs of a derived `Debug` text `Name { a: 1, b: Some(X { .. }) }`.
fn debug_fields(text: &str) -> Vec<(String, String)> {
    let Some(open) = text.find(" { ") else {
        return Vec::new(); // a message without fields prints its bare name
    };
    let inner = &text[open + 3..text.len() - 2];
    let (mut out, mut depth, mut quoted, mut start) = (Vec::new(), 0i32, false, 0);
    let bytes = inner.as_bytes();
    let mut push = |piece: &str| {
        let (name, value) = piece.split_once(": ").unwrap();
        out.push((name.trim().to_string(), value.trim().to_string()));
    };
    let mut i = 0;
    while i < bytes.len() {
        match bytes[i] {
            b'\\' if quoted => i += 1,
            b'"' => quoted = !quoted,
            b'(' | b'[' | b'{' if !quoted => depth += 1,
            b')' | b']' | b'}' if !quoted => depth -= 1,
            b',' if !quoted && depth == 0 => {
                push(&inner[start..i]);
                start = i + 1;
            }
            _ => {}
        }
        i += 1;
    }
    push(&inner[start..]);
    out
}

fn varint(mut v: u64, out: &mut Vec<u8>) {
    while v >= 0x80 {
        out.push((v as u8) | 0x80);
        v >>= 7;
    }
    out.push(v as u8);
}

/// One field of the given upstream description on the wire, with a value no default has, and
/// the `Debug` text a schema with the same name, label and type prints for it.
fn probe(field: &FieldDescriptorProto, up: &Upstream) -> (Vec<u8>, String) {
    use descriptor::*;
    let number = u64::try_from(field.number.unwrap()).unwrap();
    let ty = field.r#type.unwrap();
    let repeated = field.label == Some(LABEL_REPEATED);
    let type_name = field
        .type_name
        .clone()
        .unwrap_or_default()
        .rsplit('.')
        .next()
        .unwrap()
        .to_string();
    // (wire type, payload, the value's Debug text)
    let (wire, payload, shown): (u64, Vec<u8>, String) = match ty {
        TYPE_FLOAT => (5, 12.5f32.to_le_bytes().to_vec(), "12.5".into()),
        TYPE_DOUBLE => (1, 12.5f64.to_le_bytes().to_vec(), "12.5".into()),
        TYPE_FIXED32 | TYPE_SFIXED32 => (5, 7u32.to_le_bytes().to_vec(), "7".into()),
        TYPE_FIXED64 | TYPE_SFIXED64 => (1, 7u64.to_le_bytes().to_vec(), "7".into()),
        TYPE_INT32 | TYPE_INT64 | TYPE_UINT32 | TYPE_UINT64 => (0, vec![7], "7".into()),
        TYPE_SINT32 | TYPE_SINT64 => (0, vec![14], "7".into()), // zigzag
        TYPE_BOOL => (0, vec![1], "true".into()),
        TYPE_STRING => (2, b"s".to_vec(), "\"s\"".into()),
        TYPE_BYTES => (2, b"s".to_vec(), "[115]".into()),
        TYPE_ENUM => {
            let e = &up.enums[&type_name];
            let v = e
                .value
                .iter()
                .find(|v| v.number != Some(0))
                .expect("an enum with a non-zero value");
            // prost names variants in UpperCamelCase: RECORDING -> Recording.
            let camel: String = v
                .name
                .clone()
                .unwrap()
                .split('_')
                .map(|w| {
                    let w = w.to_ascii_lowercase();
                    let mut c = w.chars();
                    c.next()
                        .map(|f| f.to_ascii_uppercase().to_string() + c.as_str())
                        .unwrap_or_default()
                })
                .collect();
            let mut p = Vec::new();
            varint(u64::try_from(v.number.unwrap()).unwrap(), &mut p);
            (0, p, camel)
        }
        TYPE_MESSAGE => (2, Vec::new(), type_name.clone()),
        other => panic!("upstream field type {other} is not one this check knows"),
    };
    let mut bytes = Vec::new();
    if repeated && wire != 2 {
        // proto3 packs repeated scalars.
        varint(number << 3 | 2, &mut bytes);
        varint(payload.len() as u64, &mut bytes);
    } else {
        varint(number << 3 | wire, &mut bytes);
        if wire == 2 {
            varint(payload.len() as u64, &mut bytes);
        }
    }
    bytes.extend(payload);
    let shown = if repeated {
        format!("[{shown}")
    } else if ty == TYPE_MESSAGE
        || field.proto3_optional == Some(true)
        || field.oneof_index.is_some()
    {
        format!("Some({shown}")
    } else {
        shown
    };
    (bytes, shown)
}

/// Every field fishprobe's `M` states is upstream's field of the same name, number, label and
/// type: one upstream-shaped field on the wire decodes into `M` as that field with that value,
/// and `M` encodes it back to the same bytes. Returns the fields checked.
fn check_message<M: Message + Default + std::fmt::Debug>(up: &Upstream) -> Vec<String> {
    let name = std::any::type_name::<M>().rsplit("::").next().unwrap();
    let upstream = up
        .messages
        .get(name)
        .unwrap_or_else(|| panic!("fishprobe's message {name} is not upstream"));
    let mut checked = Vec::new();
    for (field, _) in debug_fields(&format!("{:?}", M::default())) {
        let theirs = upstream
            .field
            .iter()
            .find(|f| f.name.as_deref() == Some(field.as_str()))
            .unwrap_or_else(|| panic!("fishprobe's {name}.{field} is not upstream"));
        let (bytes, shown) = probe(theirs, up);
        let decoded = M::decode(bytes.as_slice()).unwrap_or_else(|e| {
            panic!("upstream's {name}.{field} does not decode as fishprobe's: {e}")
        });
        let text = format!("{decoded:?}");
        let changed: Vec<(String, String)> = debug_fields(&text)
            .into_iter()
            .filter(|(n, v)| {
                debug_fields(&format!("{:?}", M::default()))
                    .iter()
                    .any(|(m, w)| m == n && w != v)
            })
            .collect();
        assert_eq!(
            changed.len(),
            1,
            "upstream's {name}.{field} (number {:?}) set {changed:?} in fishprobe's: {text}",
            theirs.number
        );
        assert_eq!(changed[0].0, field, "number {:?} in {name}", theirs.number);
        assert!(
            changed[0].1.starts_with(&shown),
            "{name}.{field}: upstream's type reads as {} in fishprobe's, wanted {shown}…",
            changed[0].1
        );
        assert_eq!(
            decoded.encode_to_vec(),
            bytes,
            "{name}.{field} encodes differently from upstream's type"
        );
        checked.push(format!("{name}.{field}"));
    }
    checked
}

#[test]
#[ignore = "needs a biotracker_v4 checkout (BIOTRACKER_V4_DIR) and protoc"]
fn fishprobes_schema_is_upstreams_schema() {
    let d = dir("biotracker-v4-schema");
    let up = compile_upstream(&upstream_dir(), &d);
    let mut checked = Vec::new();
    checked.extend(check_message::<Empty>(&up));
    checked.extend(check_message::<SkeletonNode>(&up));
    checked.extend(check_message::<Feature>(&up));
    checked.extend(check_message::<Features>(&up));
    checked.extend(check_message::<SkeletonDescriptor>(&up));
    checked.extend(check_message::<Arena>(&up));
    checked.extend(check_message::<RecordingConfig>(&up));
    checked.extend(check_message::<Experiment>(&up));
    checked.extend(check_message::<ComponentConfig>(&up));
    // Every message of the schema file is in the list above.
    let source = include_str!("../../live/src/biotracker/schema.rs");
    for line in source.lines() {
        if let Some(rest) = line.trim().strip_prefix("pub struct ") {
            let name = rest.split([' ', '{']).next().unwrap();
            assert!(
                checked.iter().any(|c| c.starts_with(&format!("{name}."))) || name == "Empty",
                "fishprobe's message {name} is not checked here"
            );
        }
    }
    assert_eq!(checked.len(), 24, "{checked:?}");

    // The enum: every variant fishprobe knows has upstream's number.
    let states = &up.enums["RecordingState"];
    for n in 0..=16 {
        if let Ok(v) = RecordingState::try_from(n) {
            let theirs = states
                .value
                .iter()
                .find(|u| u.number == Some(n))
                .unwrap_or_else(|| panic!("RecordingState {n} is not upstream"));
            assert_eq!(
                format!("{v:?}").to_ascii_uppercase(),
                theirs.name.clone().unwrap(),
                "RecordingState {n}"
            );
        }
    }

    // The methods fishprobe serves and calls, with their message types.
    for (path, input, output) in [
        (grpc::SET_CONFIG_PATH, "ComponentConfig", "Empty"),
        (grpc::UPDATE_PATH, "Experiment", "Empty"),
        (grpc::HEARTBEAT_PATH, "Empty", "Empty"),
        (DETECT_FEATURES_PATH, "Image", "DetectorResponse"),
        (DETECTOR_SET_CONFIG_PATH, "ComponentConfig", "Empty"),
        (COMMAND_PATH, "BioTrackerCommand", "Empty"),
        (GET_STATE_PATH, "Empty", "Experiment"),
    ] {
        let (i, o) = up
            .methods
            .get(path)
            .unwrap_or_else(|| panic!("{path} is not upstream"));
        assert_eq!((i.as_str(), o.as_str()), (input, output), "{path}");
    }
    // And the messages this file adds to drive the core and serve features.
    check_message::<theirs::Image>(&up);
    check_message::<theirs::DetectorResponse>(&up);
    check_message::<theirs::Features>(&up);
    check_message::<theirs::Feature>(&up);
    check_message::<theirs::SkeletonDescriptor>(&up);
    check_message::<theirs::BioTrackerCommand>(&up);
    check_message::<theirs::RecordingConfig>(&up);
    check_message::<theirs::EntityIDSwitch>(&up);
    println!("{} fields of fishprobe's schema checked", checked.len());
}

// ---------------------------------------------------------------------------------------------
// The core, a replay detector and fishprobe.
// ---------------------------------------------------------------------------------------------

const DETECT_FEATURES_PATH: &str = "/biotracker.FeatureDetector/detect_features";
const DETECTOR_SET_CONFIG_PATH: &str = "/biotracker.FeatureDetector/set_config";
const COMMAND_PATH: &str = "/biotracker.BioTracker/command";
const GET_STATE_PATH: &str = "/biotracker.BioTracker/get_state";

/// The messages a detector answers with and a client commands the core with, named as upstream
/// names them (the schema test checks them as it checks fishprobe's). Only the fields used here.
mod theirs {
    use super::{RecordingState, SkeletonNode};

    /// `biotracker.Image` (the frame a detector is asked about; pixels are in shared memory).
    #[derive(Clone, PartialEq, prost::Message)]
    pub struct Image {
        #[prost(uint32, tag = "2")]
        pub frame_number: u32,
        #[prost(uint32, tag = "4")]
        pub width: u32,
        #[prost(uint32, tag = "5")]
        pub height: u32,
    }

    /// `biotracker.DetectorResponse`.
    #[derive(Clone, PartialEq, prost::Message)]
    pub struct DetectorResponse {
        #[prost(message, optional, tag = "1")]
        pub features: Option<Features>,
        #[prost(message, optional, tag = "2")]
        pub skeleton: Option<SkeletonDescriptor>,
    }

    /// `biotracker.Features` as a detector fills it.
    #[derive(Clone, PartialEq, prost::Message)]
    pub struct Features {
        #[prost(message, repeated, tag = "1")]
        pub features: Vec<Feature>,
    }

    /// `biotracker.Feature` as a detector fills it: image nodes (pixels), not world nodes.
    #[derive(Clone, PartialEq, prost::Message)]
    pub struct Feature {
        #[prost(message, repeated, tag = "1")]
        pub image_nodes: Vec<SkeletonNode>,
        #[prost(float, tag = "2")]
        pub score: f32,
    }

    /// `biotracker.SkeletonDescriptor` with the node names a detector declares.
    #[derive(Clone, PartialEq, prost::Message)]
    pub struct SkeletonDescriptor {
        #[prost(string, repeated, tag = "2")]
        pub node_names: Vec<String>,
        #[prost(uint32, tag = "3")]
        pub front_index: u32,
        #[prost(uint32, tag = "4")]
        pub center_index: u32,
    }

    /// `biotracker.BioTrackerCommand` (a oneof upstream): the commands this test sends.
    #[derive(Clone, PartialEq, prost::Message)]
    pub struct BioTrackerCommand {
        #[prost(enumeration = "RecordingState", optional, tag = "2")]
        pub recording_state: Option<i32>,
        #[prost(message, optional, tag = "7")]
        pub initialize_recording: Option<RecordingConfig>,
        #[prost(message, optional, tag = "10")]
        pub switch_entities: Option<EntityIDSwitch>,
        #[prost(float, optional, tag = "12")]
        pub target_fps: Option<f32>,
    }

    /// `biotracker.EntityIDSwitch`: what the GUI sends when the user swaps two entities' ids.
    #[derive(Clone, PartialEq, prost::Message)]
    pub struct EntityIDSwitch {
        #[prost(uint32, tag = "1")]
        pub id1: u32,
        #[prost(uint32, tag = "2")]
        pub id2: u32,
    }

    /// `biotracker.RecordingConfig` with the video size the core's encoder needs.
    #[derive(Clone, PartialEq, prost::Message)]
    pub struct RecordingConfig {
        #[prost(string, tag = "1")]
        pub base_path: String,
        #[prost(double, tag = "2")]
        pub fps: f64,
        #[prost(uint32, tag = "3")]
        pub width: u32,
        #[prost(uint32, tag = "4")]
        pub height: u32,
    }
}

use theirs::BioTrackerCommand;

/// cm (tank centre origin, y up) to pixels of a `width` x `height` frame (top-left origin, y
/// down) whose corners the arena's rectification corners are (the config below gives them
/// relative to the frame: the whole frame is the 100 x 100 cm tank).
fn px(x_cm: f32, y_cm: f32, width: u32, height: u32) -> SkeletonNode {
    SkeletonNode {
        x: (x_cm + 50.0) / 100.0 * width as f32,
        y: (50.0 - y_cm) / 100.0 * height as f32,
        score: 1.0,
    }
}

/// The served poses' indices in which the robot is not detected: 0.8 s, past the 0.5 s after
/// which the bridge's rule stops the robot.
const GAP: std::ops::Range<usize> = 100..120;

/// The replay detector. The core asks about frames by its own running frame number (its
/// recording's numbers, which restart at 0, reach only the observers), so the detector serves
/// the first pose until `start` is set, then from the first frame it sees after that,
/// `base`, the pose `frame - base`; the robot is left out of the poses in [`GAP`].
fn replay_detector(
    poses: Arc<Vec<([f32; 3], [f32; 3])>>,
    start: Arc<AtomicBool>,
    base: Arc<Mutex<Option<u32>>>,
) -> Methods {
    let feature = |p: [f32; 3], image: &theirs::Image| theirs::Feature {
        // Front node 1 cm ahead of the centre, along the heading.
        image_nodes: vec![
            px(
                p[0] + p[2].cos(),
                p[1] + p[2].sin(),
                image.width,
                image.height,
            ),
            px(p[0], p[1], image.width, image.height),
        ],
        score: 1.0,
    };
    Methods::new("the replay detector")
        .unary(DETECTOR_SET_CONFIG_PATH, 1 << 20, |_: ComponentConfig| {
            Ok(Empty {})
        })
        .unary(
            DETECT_FEATURES_PATH,
            1 << 20,
            move |image: theirs::Image| {
                let k = if start.load(Ordering::SeqCst) {
                    let b = *base.lock().unwrap().get_or_insert(image.frame_number);
                    image.frame_number.saturating_sub(b) as usize
                } else {
                    0
                };
                let (robot, fish) = poses[k.min(poses.len() - 1)];
                let mut features = Vec::new();
                if !GAP.contains(&k) {
                    features.push(feature(robot, &image));
                }
                features.push(feature(fish, &image));
                Ok(theirs::DetectorResponse {
                    features: Some(theirs::Features { features }),
                    skeleton: Some(theirs::SkeletonDescriptor {
                        node_names: vec!["head".into(), "center".into()],
                        front_index: 0,
                        center_index: 1,
                    }),
                })
            },
        )
}

/// A stdlib Python component that only forwards its port to the detector served by this
/// test (the core starts components only as Python programs).
const FORWARDER: &str = r#"
import os, socket, threading
host, port = os.environ["BIOTRACKER_COMPONENT_ADDRESS"].rsplit(":", 1)
to_host, to_port = os.environ["FISHPROBE_TEST_DETECTOR"].rsplit(":", 1)
server = socket.create_server((host, int(port)))
def pipe(a, b):
    try:
        while True:
            data = a.recv(65536)
            if not data:
                break
            b.sendall(data)
    except OSError:
        pass
    for s in (a, b):
        try:
            s.shutdown(socket.SHUT_RDWR)
        except OSError:
            pass
while True:
    client, _ = server.accept()
    upstream = socket.create_connection((to_host, int(to_port)))
    threading.Thread(target=pipe, args=(client, upstream), daemon=True).start()
    threading.Thread(target=pipe, args=(upstream, client), daemon=True).start()
"#;

fn biotracker_bin(dir: &Path) -> PathBuf {
    if let Some(bin) = std::env::var_os("BIOTRACKER_V4_BIN") {
        return PathBuf::from(bin);
    }
    ["release", "debug"]
        .iter()
        .map(|p| dir.join("target").join(p).join("biotracker4"))
        .find(|p| p.exists())
        .unwrap_or_else(|| {
            panic!(
                "no target/release/biotracker4 or target/debug/biotracker4 in {}: build it \
                 (cargo build) or name it with BIOTRACKER_V4_BIN",
                dir.display()
            )
        })
}

/// Kills the core (and with it nothing else: its components are left to notice) when the test
/// ends, passing or not.
struct Core(Child);

impl Drop for Core {
    fn drop(&mut self) {
        let _ = self.0.kill();
        let _ = self.0.wait();
    }
}

async fn command(core: &mut Client, c: BioTrackerCommand) {
    core.call::<BioTrackerCommand, Empty>(COMMAND_PATH, c)
        .await
        .unwrap_or_else(|e| panic!("the core refused a command: {e}"));
}

/// Waits until `done`; else fails with `what` (made at the failure, so logs are current).
fn wait_for<W: std::fmt::Display>(
    what: impl Fn() -> W,
    within: Duration,
    mut done: impl FnMut() -> bool,
) {
    let start = Instant::now();
    while !done() {
        if start.elapsed() >= within {
            // A little longer, to tell "late" from "never" in the message.
            std::thread::sleep(within);
            panic!(
                "{} not within {within:?} (done a while later: {})",
                what(),
                done()
            );
        }
        std::thread::sleep(Duration::from_millis(50));
    }
}

#[test]
#[ignore = "needs a biotracker_v4 build (BIOTRACKER_V4_DIR), python3 with venv"]
fn a_real_biotracker_v4_core_drives_fishprobe_through_a_recording() {
    let upstream = upstream_dir();
    let bin = biotracker_bin(&upstream);
    let d = dir("biotracker-v4-core");
    let protocol = d.join("protocol.toml");
    std::fs::write(&protocol, PROTOCOL).unwrap();
    let poses = Arc::new(recorded_poses(&record_trial(&d, &protocol)));
    assert!(poses.len() > GAP.end + 50, "{}", poses.len());

    // The replay detector, served here on a thread of its own.
    let (start, base) = (Arc::new(AtomicBool::new(false)), Arc::new(Mutex::new(None)));
    let listener = TcpListener::bind("127.0.0.1:0").unwrap();
    let detector_addr = listener.local_addr().unwrap();
    let detector = replay_detector(Arc::clone(&poses), Arc::clone(&start), Arc::clone(&base));
    std::thread::spawn(move || {
        runtime()
            .block_on(grpc::serve(listener, detector, std::future::pending()))
            .unwrap();
    });

    // The core's config folder: a venv (the core sources its activate script), the forwarder,
    // and the config with the three components.
    let venv = d.join("venv");
    let st = Command::new("python3")
        .args(["-m", "venv", "--without-pip"])
        .arg(&venv)
        .status()
        .unwrap();
    assert!(st.success(), "python3 -m venv failed");
    std::fs::write(d.join("forward.py"), FORWARDER).unwrap();
    let core_addr = free_addr();
    let sink = free_addr();
    let out = d.join("trials");
    let log = d.join("observer.log");
    let launcher = Path::new(env!("CARGO_MANIFEST_DIR"))
        .join("../../lab/biotracker/fishprobe_biotracker.py")
        .canonicalize()
        .unwrap();
    let ours: serde_json::Value =
        serde_json::from_str(&config_json(&out, &protocol, sink, core_addr)).unwrap();
    let unit = serde_json::json!([
        {"x": 0.0, "y": 0.0}, {"x": 1.0, "y": 0.0}, {"x": 1.0, "y": 1.0}, {"x": 0.0, "y": 1.0}
    ]);
    let config = serde_json::json!({
        "components": [
            {"id": "HungarianMatcher", "services": ["MATCHER"],
             "config_json": {"ignore_nan": true, "ignore_out_of_bounds": false,
                             "confidence_threshold_feature": 0.0,
                             "confidence_threshold_node": 0.0}},
            {"id": "ReplayDetector", "services": ["FEATURE_DETECTOR"], "config_json": {},
             "python_config": {"venv": venv, "cmd": "forward.py"}},
            {"id": "fishprobe", "services": ["OBSERVER"], "config_json": ours,
             "python_config": {"venv": venv,
                               "cmd": format!("{} --log {}", launcher.display(), log.display())}}
        ],
        "cameras": [],
        "arena": {"width_cm": 100, "height_cm": 100,
                  "rectification_corners": unit, "tracking_area_corners": unit}
    });
    let config_file = d.join("biotracker.json");
    std::fs::write(&config_file, config.to_string()).unwrap();
    let core_log = std::fs::File::create(d.join("core.log")).unwrap();
    let core_process = Core(
        Command::new(&bin)
            .arg("--config")
            .arg(&config_file)
            .args([
                "--headless",
                "--video",
                "fake:///replay",
                "--entity-count",
                "2",
            ])
            .args(["--port", &core_addr.port().to_string()])
            .env("FISHPROBE_BIN", env!("CARGO_BIN_EXE_fishprobe"))
            .env("FISHPROBE_TEST_DETECTOR", detector_addr.to_string())
            .current_dir(&d)
            .stdout(Stdio::null())
            .stderr(core_log)
            .spawn()
            .unwrap(),
    );
    let core_log = || std::fs::read_to_string(d.join("core.log")).unwrap_or_default();
    let observer_log = || std::fs::read_to_string(&log).unwrap_or_default();

    let rt = runtime();
    let mut core = rt.block_on(async { Client::lazy(core_addr, Duration::from_secs(2)).unwrap() });
    wait_for(
        || "the core's heartbeat",
        Duration::from_secs(20),
        || rt.block_on(core.heartbeat()).is_ok(),
    );
    // The lab's rate: fishprobe refuses the core's default 30 Hz for a 25 Hz policy.
    rt.block_on(command(
        &mut core,
        BioTrackerCommand {
            target_fps: Some(FPS),
            ..Default::default()
        },
    ));
    // The observer configured (its robot sink listens) and fed (ticks arrive).
    let robot = robot_program(sink);
    wait_for(
        || {
            format!(
                "ticks on the robot sink; core log:\n{}\nobserver log:\n{}",
                core_log(),
                observer_log()
            )
        },
        Duration::from_secs(30),
        || robot.lock().unwrap().iter().any(|l| l.contains("\"tick\"")),
    );

    // The matcher numbers the entities as it likes on the first frame; the lab then swaps ids in
    // the GUI until the robot has the id its config names (1). So does this test.
    let (robot0, fish0) = poses[0];
    let near = |f: &Feature, p: [f32; 3]| {
        f.world_nodes
            .get(1)
            .is_some_and(|n| (n.x - p[0]).hypot(n.y - p[1]) < 1.0)
    };
    let mut swapped = false;
    wait_for(
        || "the robot as entity 1",
        Duration::from_secs(10),
        || {
            let state: Experiment = rt
                .block_on(core.call::<Empty, Experiment>(GET_STATE_PATH, Empty {}))
                .unwrap();
            let features = state.last_features.unwrap_or_default().features;
            let one = features.iter().find(|f| f.id == Some(1));
            if one.is_some_and(|f| near(f, robot0)) {
                return true;
            }
            if one.is_some_and(|f| near(f, fish0)) && !swapped {
                rt.block_on(command(
                    &mut core,
                    BioTrackerCommand {
                        switch_entities: Some(theirs::EntityIDSwitch { id1: 1, id2: 2 }),
                        ..Default::default()
                    },
                ));
                swapped = true;
            }
            false
        },
    );

    // A recording, as the GUI's record button makes one.
    let stem = "2026-12-07_biotracker";
    std::fs::create_dir_all(d.join("recordings")).unwrap();
    let base_path = d.join("recordings").join(stem);
    rt.block_on(command(
        &mut core,
        BioTrackerCommand {
            initialize_recording: Some(theirs::RecordingConfig {
                base_path: base_path.to_str().unwrap().into(),
                fps: f64::from(FPS),
                width: 128,
                height: 128,
            }),
            ..Default::default()
        },
    ));
    start.store(true, Ordering::SeqCst);
    rt.block_on(command(
        &mut core,
        BioTrackerCommand {
            recording_state: Some(RecordingState::Recording as i32),
            ..Default::default()
        },
    ));
    // The protocol's 8 s, and 2 s more.
    std::thread::sleep(Duration::from_secs(10));
    rt.block_on(command(
        &mut core,
        BioTrackerCommand {
            recording_state: Some(RecordingState::Finished as i32),
            ..Default::default()
        },
    ));

    // The trial, named after the recording, its track beside it.
    let file = out.join(format!("GoalSeeker__Real/{stem}.hdf5"));
    wait_for(
        || {
            format!(
                "the trial file; observer log:\n{}\ncore log:\n{}",
                observer_log(),
                core_log()
            )
        },
        Duration::from_secs(10),
        || file.exists(),
    );
    wait_for(
        || "BioTracker's track",
        Duration::from_secs(10),
        || base_path.with_extension("json").exists(),
    );
    std::thread::sleep(Duration::from_millis(300));
    let t = fishprobe_io::read_trial(&file).unwrap();
    let record: serde_json::Value =
        serde_json::from_str(&t.task.as_ref().unwrap().config_json).unwrap();
    println!("trial record: {record:#}");
    let frames = t.robot().unwrap().positions.len();
    assert!(frames >= 8 * 25 * 3 / 4, "only {frames} frames in 8 s");
    // Which pose the recording's frame 0 is: the core's track says at which of its frames the
    // recording started, the detector at which it started serving the poses.
    let track: serde_json::Value =
        serde_json::from_str(&std::fs::read_to_string(base_path.with_extension("json")).unwrap())
            .unwrap();
    let started = track["original_track_start"].as_i64().unwrap();
    let served_from = i64::from(base.lock().unwrap().unwrap());
    // The pose served at the recording's frame k (the first when the detector started later).
    let served = |k: usize| usize::try_from(started + k as i64 - served_from).unwrap_or(0);
    // The robot where the detector put it: through pixels, the core's homography, the matcher
    // and the observer, to within a millimetre.
    let robot_track = &t.robot().unwrap().positions;
    let mut compared = 0;
    for (k, p) in robot_track.iter().enumerate() {
        let Some(&(want, _)) = poses.get(served(k)) else {
            break;
        };
        if p[0].is_nan() {
            continue;
        }
        assert!(
            (p[0] - want[0]).abs() < 0.1 && (p[1] - want[1]).abs() < 0.1,
            "frame {k} (pose {}): robot at {p:?}, served at {want:?}",
            served(k)
        );
        compared += 1;
    }
    assert!(
        compared > frames / 2,
        "only {compared} robot poses compared"
    );
    // Frame for frame the core's own track: its frame k is the trial file's frame k.
    let mut same = 0;
    for (k, f) in track["features"].as_object().unwrap() {
        let k: usize = k.parse().unwrap();
        let robot = f["features"]
            .as_array()
            .unwrap()
            .iter()
            .find(|x| x["id"] == 1);
        let (Some(robot), Some(p)) = (robot, robot_track.get(k)) else {
            continue;
        };
        let node = &robot["world_nodes"][1];
        let (x, y) = (node["x"].as_f64().unwrap(), node["y"].as_f64().unwrap());
        assert!(
            (f64::from(p[0]) - x).abs() < 1e-3 && (f64::from(p[1]) - y).abs() < 1e-3,
            "frame {k}: the trial has the robot at {p:?}, the core's track at ({x}, {y})"
        );
        same += 1;
    }
    assert!(
        same > frames / 2,
        "only {same} frames of the core's track compared"
    );
    // The policy drove: commands in the control phase.
    assert!(!t.task.as_ref().unwrap().command_frames.is_empty());
    // The stop at the gap: the robot undetected from frame 100.
    let stops = record["stops"].as_array().unwrap();
    assert!(
        stops.iter().any(|s| {
            s["reason"]
                .as_str()
                .unwrap_or("")
                .contains("robot not tracked")
                && s["frame"].as_u64().is_some_and(|f| {
                    // Stopped when the gap reached 0.5 s: 13 frames after the last seen.
                    let last_seen = (0..frames).rev().find(|&k| served(k) < GAP.start).unwrap();
                    let last_seen = last_seen as u64;
                    (last_seen + 13..=last_seen + 15).contains(&f)
                })
        }),
        "no stop at the tracking gap: {stops:?}"
    );
    assert_eq!(record["front_end"]["tracker_target_fps"], 25.0);

    // The core dies: the robot program is told to stop within 3 s.
    drop(core_process);
    let died = Instant::now();
    println!(
        "core killed at {:.3}",
        std::time::SystemTime::now()
            .duration_since(std::time::UNIX_EPOCH)
            .unwrap()
            .as_secs_f64()
    );
    wait_for(
        || {
            format!(
                "the stop after the core died; the robot program's last lines:\n{:?}\nlog:\n{}",
                robot
                    .lock()
                    .unwrap()
                    .iter()
                    .rev()
                    .take(3)
                    .collect::<Vec<_>>(),
                observer_log()
            )
        },
        Duration::from_secs(3),
        || {
            robot
                .lock()
                .unwrap()
                .last()
                .is_some_and(|l| l.contains("\"stop\":true") && l.contains("tracker core gone"))
        },
    );
    println!(
        "{frames} frames (the recording's frame 0 is pose {}), {compared} robot poses as \
         served, {same} frames as in the core's track; stops {stops:?}, tracking gaps {}; \
         stop {:?} after the core died",
        served(0),
        record["tracking_gaps_frames"],
        died.elapsed()
    );
}
