//! The lab's pre-2020 layout (`guppy-pairs/legacy/` in the shared data): root attributes
//! `world` = [w, h] (cm) and `time_step` (ms), one dataset per fish named "1", "2", ... of
//! float32 (T, 4) = x, y, ori_x, ori_y with the origin at the top-left corner and y pointing
//! down; a dataset attribute `interp_frames` lists interpolated frames.
//!
//! Conversion to robofish.io: x' = x - w/2, y' = h/2 - y, orientation (ori_x, -ori_y), the
//! frame rate 1000 / time_step. This reproduces the lab's own converted files exactly (tested
//! against `guppy-pairs/robofish-io/`). `interp_frames` is kept as an entity attribute with its
//! original (video) frame numbers; `num_frames`, `tracking_interval` and `video` stay root
//! attributes.

use crate::attr::Attr;
use crate::backend;
use crate::error::IoError;
use crate::trial::{Category, Entity, TrialFile};
use std::collections::BTreeMap;
use std::path::Path;

/// Reads a legacy file as a robofish.io trial (no task record).
pub fn read_legacy(path: &Path) -> Result<TrialFile, IoError> {
    let root = backend::open(path)?;
    let mut attrs = root.attrs()?;
    let world = match attrs.remove("world").and_then(|a| a.as_numbers()) {
        Some(v) if v.len() == 2 && v.iter().all(|x| x.is_finite() && *x > 0.0) => {
            [v[0] as f32, v[1] as f32]
        }
        Some(v) => {
            return Err(IoError::format(
                path,
                format!("legacy `world` is not 2 positive numbers: {v:?}"),
            ))
        }
        None => {
            let hint = if root.group("entities")?.is_some() {
                " (it looks like a robofish.io file already)"
            } else {
                ""
            };
            return Err(IoError::format(
                path,
                format!("no root attribute `world`: not a legacy file{hint}"),
            ));
        }
    };
    let time_step_ms = match attrs.remove("time_step").and_then(|a| a.as_number()) {
        Some(t) if t.is_finite() && t > 0.0 => t,
        Some(t) => {
            return Err(IoError::format(
                path,
                format!("legacy `time_step` is {t} ms, not a positive duration"),
            ))
        }
        None => return Err(IoError::format(path, "no root attribute `time_step` (ms)")),
    };
    let mut names = root.datasets()?;
    // "1", "2", ..., "10" in numeric order; other names after them.
    names.sort_by_key(|n| (n.parse::<u64>().unwrap_or(u64::MAX), n.clone()));
    let (half_w, half_h) = (world[0] / 2.0, world[1] / 2.0);
    let mut entities = Vec::new();
    for name in names {
        let Some(d) = root.dataset(&name)? else {
            continue;
        };
        let shape = d.shape()?;
        if shape.len() != 2 || shape[1] != 4 {
            return Err(IoError::format(
                path,
                format!(
                    "legacy dataset {} has shape {shape:?}, expected (frames, 4)",
                    d.name()
                ),
            ));
        }
        let v = d.read_f32()?;
        if v.len() as u64 != shape[0] * 4 {
            return Err(IoError::format(
                path,
                format!(
                    "legacy dataset {} holds {} values for shape {shape:?}",
                    d.name(),
                    v.len()
                ),
            ));
        }
        let mut attributes: BTreeMap<String, Attr> = d.attrs()?;
        attributes.retain(|k, _| k == "interp_frames");
        entities.push(Entity {
            name: name.clone(),
            category: Category::Fish,
            category_label: "fish".into(),
            positions: v
                .chunks_exact(4)
                .map(|r| [r[0] - half_w, half_h - r[1]])
                .collect(),
            orientations: v.chunks_exact(4).map(|r| [r[2], -r[3]]).collect(),
            attributes,
        });
    }
    if entities.is_empty() {
        return Err(IoError::format(path, "legacy file without fish datasets"));
    }
    Ok(TrialFile {
        world_size_cm: world,
        frame_rate_hz: (1000.0 / time_step_ms) as f32,
        entities,
        attributes: attrs,
        task: None,
    })
}
