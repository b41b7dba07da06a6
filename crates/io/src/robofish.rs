//! Reading and writing the robofish.io track format 1.0 (as described from real files in
//! `../shared/data/README.md`) with fishprobe's `/fishprobe` task group.
//!
//! Reading is tolerant where the format allows (unknown groups, datasets and attributes are
//! ignored; entities may differ in length; NaN frames are kept; any sampling rate) and strict
//! where a wrong value would silently corrupt an analysis (world size, sampling rate, dataset
//! shapes): those are errors that name the file and the problem.

use crate::attr::Attr;
use crate::backend::{self, AttrOut, Data, GroupSpec, H5Group};
use crate::error::IoError;
use crate::trial::{Category, Entity, TaskRecord, TrialFile, TrialKind};
use std::collections::BTreeMap;
use std::io::Write;
use std::path::{Path, PathBuf};

/// `format_url` written into every file.
pub const FORMAT_URL: &str =
    "https://git.imp.fu-berlin.de/bioroboticslab/robofish/track_format/-/releases/1.0";

/// Root attributes the reader interprets (all others are kept in `TrialFile::attributes`).
const MODELLED_ROOT_ATTRS: [&str; 3] = ["format_version", "format_url", "world_size_cm"];

/// Reads a robofish.io 1.0 file. Entities come in name order.
pub fn read_trial(path: &Path) -> Result<TrialFile, IoError> {
    let root = backend::open(path)?;
    let attrs = root.attrs()?;
    let Some(entities_group) = root.group("entities")? else {
        let hint = if attrs.contains_key("world") && attrs.contains_key("time_step") {
            " (this looks like the lab's pre-2020 layout: convert it with `fishprobe import-legacy`)"
        } else {
            ""
        };
        return Err(IoError::format(
            path,
            format!("no /entities group: not a robofish.io track file{hint}"),
        ));
    };
    if let Some(v) = attrs.get("format_version") {
        let major = v.as_numbers().and_then(|n| n.first().copied());
        if major != Some(1.0) {
            return Err(IoError::format(
                path,
                format!("format_version {v:?} is not 1.x"),
            ));
        }
    }
    let world_size_cm = world_size(path, attrs.get("world_size_cm"))?;
    let frame_rate_hz = sampling_rate(path, &root)?;
    let mut entities = Vec::new();
    for name in entities_group.groups()? {
        let Some(g) = entities_group.group(&name)? else {
            continue;
        };
        entities.push(read_entity(path, &name, &g)?);
    }
    let task = match root.group("fishprobe")? {
        Some(g) => Some(read_task(path, &g)?),
        None => None,
    };
    let attributes = attrs
        .into_iter()
        .filter(|(k, _)| !MODELLED_ROOT_ATTRS.contains(&k.as_str()))
        .collect();
    Ok(TrialFile {
        world_size_cm,
        frame_rate_hz,
        entities,
        attributes,
        task,
    })
}

fn world_size(path: &Path, a: Option<&Attr>) -> Result<[f32; 2], IoError> {
    let Some(a) = a else {
        return Err(IoError::format(
            path,
            "missing root attribute world_size_cm",
        ));
    };
    match a.as_numbers().as_deref() {
        Some([w, h]) if w.is_finite() && h.is_finite() && *w > 0.0 && *h > 0.0 => {
            Ok([*w as f32, *h as f32])
        }
        _ => Err(IoError::format(
            path,
            format!("world_size_cm is not 2 positive numbers: {a:?}"),
        )),
    }
}

fn sampling_rate(path: &Path, root: &H5Group) -> Result<f32, IoError> {
    let Some(s) = root.group("samplings")? else {
        return Err(IoError::format(
            path,
            "no /samplings group: the frame rate is unknown",
        ));
    };
    let subgroups = s.groups()?;
    let name = match s.attrs()?.get("default").and_then(Attr::as_text) {
        Some(d) => d.to_string(),
        None if subgroups.len() == 1 => subgroups[0].clone(),
        None => {
            return Err(IoError::format(
                path,
                format!(
                    "/samplings has no `default` attribute and {} samplings",
                    subgroups.len()
                ),
            ))
        }
    };
    let Some(g) = s.group(&name)? else {
        return Err(IoError::format(
            path,
            format!("default sampling `{name}` is not a group under /samplings"),
        ));
    };
    match g.attrs()?.get("frequency_hz").and_then(Attr::as_number) {
        Some(f) if f.is_finite() && f > 0.0 => Ok(f as f32),
        Some(f) => Err(IoError::format(
            path,
            format!("sampling `{name}` has frequency_hz {f}, not a positive rate"),
        )),
        None => Err(IoError::format(
            path,
            format!("sampling `{name}` has no frequency_hz"),
        )),
    }
}

/// Reads an (T, 2) numeric dataset.
fn read_pairs(path: &Path, g: &H5Group, name: &str) -> Result<Option<Vec<[f32; 2]>>, IoError> {
    let Some(d) = g.dataset(name)? else {
        return Ok(None);
    };
    let shape = d.shape()?;
    if shape.len() != 2 || shape[1] != 2 {
        return Err(IoError::format(
            path,
            format!(
                "dataset {} has shape {shape:?}, expected (frames, 2)",
                d.name()
            ),
        ));
    }
    let v = d.read_f32()?;
    if v.len() as u64 != shape[0] * 2 {
        return Err(IoError::format(
            path,
            format!(
                "dataset {} holds {} values for shape {shape:?}",
                d.name(),
                v.len()
            ),
        ));
    }
    Ok(Some(v.chunks_exact(2).map(|c| [c[0], c[1]]).collect()))
}

fn read_entity(path: &Path, name: &str, g: &H5Group) -> Result<Entity, IoError> {
    let mut attributes = g.attrs()?;
    let category_label = attributes
        .remove("category")
        .and_then(|a| a.as_text().map(str::to_string))
        .unwrap_or_default();
    let Some(positions) = read_pairs(path, g, "positions")? else {
        return Err(IoError::format(
            path,
            format!("entity {name} has no positions dataset"),
        ));
    };
    let orientations = match read_pairs(path, g, "orientations")? {
        Some(o) if o.len() != positions.len() => {
            return Err(IoError::format(
                path,
                format!(
                    "entity {name}: {} orientations for {} positions",
                    o.len(),
                    positions.len()
                ),
            ))
        }
        Some(o) => o,
        None => vec![[f32::NAN; 2]; positions.len()],
    };
    Ok(Entity {
        name: name.to_string(),
        category: Category::from_label(&category_label),
        category_label,
        positions,
        orientations,
        attributes,
    })
}

fn read_task(path: &Path, g: &H5Group) -> Result<TaskRecord, IoError> {
    let attrs = g.attrs()?;
    let text = |k: &str| -> Result<String, IoError> {
        attrs
            .get(k)
            .and_then(Attr::as_text)
            .map(str::to_string)
            .ok_or_else(|| {
                IoError::format(
                    path,
                    format!("/fishprobe is missing the text attribute {k}"),
                )
            })
    };
    let number = |k: &str| -> Result<f64, IoError> {
        attrs.get(k).and_then(Attr::as_number).ok_or_else(|| {
            IoError::format(
                path,
                format!("/fishprobe is missing the number attribute {k}"),
            )
        })
    };
    let ints = |k: &str| -> Result<Vec<i64>, IoError> {
        match g.dataset(k)? {
            Some(d) => d.read_i64(),
            None => Err(IoError::format(
                path,
                format!("/fishprobe is missing the dataset {k}"),
            )),
        }
    };
    let unsigned = |k: &str| -> Result<Vec<u64>, IoError> {
        ints(k)?
            .into_iter()
            .map(|v| {
                u64::try_from(v).map_err(|_| {
                    IoError::format(path, format!("/fishprobe/{k} holds the negative frame {v}"))
                })
            })
            .collect()
    };
    let kind_label = text("kind")?;
    let kind = TrialKind::from_label(&kind_label).ok_or_else(|| {
        IoError::format(
            path,
            format!("/fishprobe kind `{kind_label}` is not sim, virtual or real"),
        )
    })?;
    let goals = read_pairs(path, g, "goals")?
        .ok_or_else(|| IoError::format(path, "/fishprobe is missing the dataset goals"))?;
    let command_turns = match g.dataset("command_turns")? {
        Some(d) => d.read_f32()?,
        None => {
            return Err(IoError::format(
                path,
                "/fishprobe is missing the dataset command_turns",
            ))
        }
    };
    let config_json = match g.dataset("config_json")? {
        Some(d) => d.read_strings()?.into_iter().next().unwrap_or_default(),
        None => String::new(),
    };
    let active_goal: Vec<i32> = ints("active_goal")?
        .into_iter()
        .map(|v| v.clamp(-1, i64::from(i32::MAX)) as i32)
        .collect();
    if let Some(bad) = active_goal.iter().find(|&&i| i >= goals.len() as i32) {
        return Err(IoError::format(
            path,
            format!(
                "/fishprobe/active_goal refers to goal {bad} of {}",
                goals.len()
            ),
        ));
    }
    let record = TaskRecord {
        kind,
        policy: text("policy")?,
        fish_model: text("fish_model")?,
        seed: number("seed")? as i64 as u64,
        goal_radius_cm: number("goal_radius_cm")? as f32,
        goals,
        active_goal,
        goal_frames: unsigned("goal_frames")?,
        command_frames: unsigned("command_frames")?,
        command_turns,
        control_start_frame: number("control_start_frame")?.max(0.0) as u64,
        config_json,
        program_version: text("program_version").unwrap_or_default(),
    };
    if record.command_frames.len() != record.command_turns.len() {
        return Err(IoError::format(
            path,
            "/fishprobe command_frames and command_turns differ in length",
        ));
    }
    Ok(record)
}

/// Seeds are stored as int64 (h5py and robofish.io read that natively); values above
/// i64::MAX keep their bits.
fn seed_attr(seed: u64) -> AttrOut {
    AttrOut::I64(seed as i64)
}

fn attr_out(a: &Attr) -> AttrOut {
    match a {
        Attr::Int(i) => AttrOut::I64(*i),
        Attr::Float(f) => AttrOut::F64(*f),
        Attr::Text(s) => AttrOut::Text(s.clone()),
        Attr::Ints(v) => AttrOut::I64s(v.clone()),
        Attr::Floats(v) => AttrOut::F64s(v.clone()),
        Attr::Texts(v) => AttrOut::Texts(v.clone()),
    }
}

fn pairs(v: &[[f32; 2]]) -> Data {
    Data::F32(
        v.iter().flatten().copied().collect(),
        vec![v.len() as u64, 2],
    )
}

/// The name of a sampling: "25 hz", "20 hz", "12.5 hz".
pub fn sampling_name(rate: f32) -> String {
    format!("{rate} hz")
}

/// Builds the HDF5 layout of a trial.
pub fn trial_spec(t: &TrialFile) -> Result<GroupSpec, IoError> {
    if !(t.frame_rate_hz.is_finite() && t.frame_rate_hz > 0.0) {
        return Err(IoError::Invalid(format!(
            "frame rate {} is not positive",
            t.frame_rate_hz
        )));
    }
    let mut root = GroupSpec::default();
    root.attrs
        .push(("format_version".into(), AttrOut::I32s(vec![1, 0])));
    root.attrs
        .push(("format_url".into(), AttrOut::Text(FORMAT_URL.into())));
    root.attrs.push((
        "world_size_cm".into(),
        AttrOut::F32s(t.world_size_cm.to_vec()),
    ));
    for (k, a) in &t.attributes {
        if !MODELLED_ROOT_ATTRS.contains(&k.as_str()) {
            root.attrs.push((k.clone(), attr_out(a)));
        }
    }
    let mut entities = GroupSpec::default();
    for e in &t.entities {
        if e.positions.len() != e.orientations.len() {
            return Err(IoError::Invalid(format!(
                "entity {}: positions and orientations differ in length",
                e.name
            )));
        }
        let mut g = GroupSpec::default();
        g.attrs
            .push(("category".into(), AttrOut::Text(e.category_label.clone())));
        for (k, a) in &e.attributes {
            g.attrs.push((k.clone(), attr_out(a)));
        }
        g.datasets
            .push(("orientations".into(), pairs(&e.orientations)));
        g.datasets.push(("positions".into(), pairs(&e.positions)));
        entities.groups.push((e.name.clone(), g));
    }
    root.groups.push(("entities".into(), entities));
    let name = sampling_name(t.frame_rate_hz);
    let mut rate = GroupSpec::default();
    rate.attrs
        .push(("frequency_hz".into(), AttrOut::F32(t.frame_rate_hz)));
    let mut samplings = GroupSpec::default();
    samplings
        .attrs
        .push(("default".into(), AttrOut::Text(name.clone())));
    samplings.groups.push((name, rate));
    root.groups.push(("samplings".into(), samplings));
    if let Some(task) = &t.task {
        root.groups.push(("fishprobe".into(), task_spec(task)?));
    }
    Ok(root)
}

fn task_spec(r: &TaskRecord) -> Result<GroupSpec, IoError> {
    if r.command_frames.len() != r.command_turns.len() {
        return Err(IoError::Invalid(
            "command_frames and command_turns differ in length".into(),
        ));
    }
    let frames = |v: &[u64]| Data::I64(v.iter().map(|&x| x as i64).collect());
    let mut g = GroupSpec::default();
    g.attrs
        .push(("kind".into(), AttrOut::Text(r.kind.label().into())));
    g.attrs
        .push(("policy".into(), AttrOut::Text(r.policy.clone())));
    g.attrs
        .push(("fish_model".into(), AttrOut::Text(r.fish_model.clone())));
    g.attrs.push(("seed".into(), seed_attr(r.seed)));
    g.attrs
        .push(("goal_radius_cm".into(), AttrOut::F32(r.goal_radius_cm)));
    g.attrs.push((
        "control_start_frame".into(),
        AttrOut::I64(r.control_start_frame as i64),
    ));
    g.attrs.push((
        "program_version".into(),
        AttrOut::Text(r.program_version.clone()),
    ));
    g.datasets.push(("goals".into(), pairs(&r.goals)));
    g.datasets
        .push(("active_goal".into(), Data::I32(r.active_goal.clone())));
    g.datasets
        .push(("goal_frames".into(), frames(&r.goal_frames)));
    g.datasets
        .push(("command_frames".into(), frames(&r.command_frames)));
    g.datasets.push((
        "command_turns".into(),
        Data::F32(r.command_turns.clone(), vec![r.command_turns.len() as u64]),
    ));
    g.datasets.push((
        "config_json".into(),
        Data::Strings(vec![r.config_json.clone()]),
    ));
    Ok(g)
}

/// Writes a trial file crash-safely: the bytes go to a hidden temporary file in the same
/// directory, are synced, and the file is renamed into place, so an interrupted run never
/// leaves a half-written file under the final name.
pub fn write_trial(path: &Path, t: &TrialFile) -> Result<(), IoError> {
    let bytes = backend::to_bytes(&trial_spec(t)?).map_err(|e| match e {
        IoError::Write { what, .. } => IoError::Write {
            path: path.to_path_buf(),
            what,
        },
        other => other,
    })?;
    write_atomically(path, &bytes)
}

/// Writes `bytes` to `path` via a synced temporary file and a rename.
pub fn write_atomically(path: &Path, bytes: &[u8]) -> Result<(), IoError> {
    let werr = |what: String| IoError::Write {
        path: path.to_path_buf(),
        what,
    };
    let dir = match path.parent() {
        Some(d) if !d.as_os_str().is_empty() => d.to_path_buf(),
        _ => PathBuf::from("."),
    };
    std::fs::create_dir_all(&dir)
        .map_err(|e| werr(format!("cannot create {}: {e}", dir.display())))?;
    let file_name = path
        .file_name()
        .ok_or_else(|| werr("not a file path".into()))?
        .to_string_lossy()
        .into_owned();
    let tmp = dir.join(format!(".{file_name}.{}.partial", std::process::id()));
    let result = (|| -> std::io::Result<()> {
        let mut f = std::fs::File::create(&tmp)?;
        f.write_all(bytes)?;
        f.sync_all()?;
        std::fs::rename(&tmp, path)
    })();
    if let Err(e) = result {
        let _ = std::fs::remove_file(&tmp);
        return Err(werr(e.to_string()));
    }
    Ok(())
}

/// Root attributes of a trial as a plain map (for `inspect`).
pub fn attributes_json(t: &TrialFile) -> BTreeMap<String, serde_json::Value> {
    t.attributes
        .iter()
        .filter_map(|(k, v)| serde_json::to_value(v).ok().map(|j| (k.clone(), j)))
        .collect()
}
