//! Which fish is which: a frame's fish entries matched to the trial's fish by the tracker's
//! ids, so fish that come in a different order from frame to frame are not swapped.
//!
//! The rules (also in `docs/live-protocol.md`):
//!
//! 1. An entry whose id is a fish's id is that fish.
//! 2. A new id takes the first fish that has no id yet (in the trial's first frames the
//!    ids are handed out in the order they first appear).
//! 3. A new id when every fish has one: a tracker that lost a fish and found it again under
//!    another id. It takes the fish that is missing from this frame and was seen longest ago;
//!    the change is recorded (frame, fish, old and new id). If no fish is missing, the entry
//!    is a fish too many and is ignored (counted).
//! 4. An id given twice in one frame: the second entry is ignored (counted).
//! 5. A frame whose entries all have an empty id (a client without ids) is matched by order.

use crate::protocol::{FishPose, Pose};

/// One change of a fish's id.
#[derive(Debug, Clone, PartialEq, serde::Serialize)]
pub struct IdChange {
    /// The frame (index in the trial file) where the new id first appeared.
    pub frame: u64,
    /// The fish (0-based: 0 is `fish_1`).
    pub fish: usize,
    /// Its id until then.
    pub old: String,
    /// Its id from then on.
    pub new: String,
}

/// The matching state of one trial.
#[derive(Debug, Clone)]
pub struct FishIds {
    /// Per fish, its current id (None until one is given).
    ids: Vec<Option<String>>,
    /// Per fish, its first id (what the trial file records as the fish's id).
    first: Vec<Option<String>>,
    /// Per fish, the last frame it was in (for rule 3).
    seen: Vec<Option<u64>>,
    changes: Vec<IdChange>,
    ignored: u64,
    by_order: u64,
}

impl FishIds {
    /// For `n` fish.
    pub fn new(n: usize) -> Self {
        Self {
            ids: vec![None; n],
            first: vec![None; n],
            seen: vec![None; n],
            changes: Vec::new(),
            ignored: 0,
            by_order: 0,
        }
    }

    /// Per fish, its valid pose in this frame (`frame`: the index it is stored at).
    pub fn assign(&mut self, frame: u64, entries: &[FishPose]) -> Vec<Option<Pose>> {
        let n = self.ids.len();
        let mut poses: Vec<Option<Pose>> = vec![None; n];
        let mut present = vec![false; n];
        if !entries.is_empty() && entries.iter().all(|e| e.id.is_empty()) {
            self.by_order += 1;
            for (i, e) in entries.iter().enumerate() {
                if i < n {
                    present[i] = true;
                    poses[i] = e.pose.filter(Pose::is_valid);
                } else {
                    self.ignored += 1;
                }
            }
        } else {
            // Known ids first, so a new id never takes a fish that is in this frame.
            let mut pending = Vec::new();
            for e in entries {
                if e.id.is_empty() {
                    self.ignored += 1;
                    continue;
                }
                match self.ids.iter().position(|i| i.as_deref() == Some(&e.id)) {
                    Some(k) if present[k] => self.ignored += 1,
                    Some(k) => {
                        present[k] = true;
                        poses[k] = e.pose.filter(Pose::is_valid);
                    }
                    None => pending.push(e),
                }
            }
            for e in pending {
                // A new id given twice in this frame: the first took a fish.
                if self.ids.iter().any(|i| i.as_deref() == Some(&e.id)) {
                    self.ignored += 1;
                    continue;
                }
                let slot = self.ids.iter().position(Option::is_none).or_else(|| {
                    (0..n)
                        .filter(|&k| !present[k])
                        .min_by_key(|&k| (self.seen[k], k))
                });
                let Some(k) = slot else {
                    self.ignored += 1;
                    continue;
                };
                if let Some(old) = self.ids[k].replace(e.id.clone()) {
                    self.changes.push(IdChange {
                        frame,
                        fish: k,
                        old,
                        new: e.id.clone(),
                    });
                }
                if self.first[k].is_none() {
                    self.first[k] = Some(e.id.clone());
                }
                present[k] = true;
                poses[k] = e.pose.filter(Pose::is_valid);
            }
        }
        for (k, p) in poses.iter().enumerate() {
            if p.is_some() {
                self.seen[k] = Some(frame);
            }
        }
        poses
    }

    /// Per fish, the first id it had (None: never in a frame with an id).
    pub fn first_ids(&self) -> &[Option<String>] {
        &self.first
    }

    /// The recorded changes of id.
    pub fn changes(&self) -> &[IdChange] {
        &self.changes
    }

    /// Entries ignored (a fish too many, an id twice in a frame, an empty id among others).
    pub fn ignored(&self) -> u64 {
        self.ignored
    }

    /// Frames matched by order (every entry without an id).
    pub fn by_order(&self) -> u64 {
        self.by_order
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    fn e(id: &str, x: f32) -> FishPose {
        FishPose {
            id: id.into(),
            pose: Some(Pose {
                x,
                y: 0.0,
                heading: 0.0,
            }),
        }
    }

    fn xs(p: &[Option<Pose>]) -> Vec<Option<f32>> {
        p.iter().map(|p| p.map(|p| p.x)).collect()
    }

    #[test]
    fn a_swapped_order_is_followed_by_id() {
        let mut m = FishIds::new(2);
        assert_eq!(
            xs(&m.assign(0, &[e("a", 1.0), e("b", 2.0)])),
            [Some(1.0), Some(2.0)]
        );
        assert_eq!(
            xs(&m.assign(1, &[e("b", 2.5), e("a", 1.5)])),
            [Some(1.5), Some(2.5)]
        );
        assert_eq!(m.first_ids(), [Some("a".into()), Some("b".into())]);
        assert!(m.changes().is_empty());
    }

    #[test]
    fn a_lost_fish_found_under_a_new_id_keeps_its_place_and_the_change_is_recorded() {
        let mut m = FishIds::new(2);
        m.assign(0, &[e("a", 1.0), e("b", 2.0)]);
        m.assign(1, &[e("b", 2.0)]); // a lost
        let p = m.assign(2, &[e("c", 1.2), e("b", 2.1)]);
        assert_eq!(xs(&p), [Some(1.2), Some(2.1)]);
        assert_eq!(
            m.changes(),
            [IdChange {
                frame: 2,
                fish: 0,
                old: "a".into(),
                new: "c".into()
            }]
        );
        // A fish too many and a repeated id are ignored.
        let p = m.assign(3, &[e("c", 1.3), e("b", 2.2), e("d", 9.0), e("b", 7.0)]);
        assert_eq!(xs(&p), [Some(1.3), Some(2.2)]);
        assert_eq!(m.ignored(), 2);
    }

    #[test]
    fn entries_without_ids_are_taken_in_order() {
        let mut m = FishIds::new(2);
        let p = m.assign(0, &[e("", 1.0), e("", 2.0), e("", 3.0)]);
        assert_eq!(xs(&p), [Some(1.0), Some(2.0)]);
        assert_eq!((m.by_order(), m.ignored()), (1, 1));
    }
}
