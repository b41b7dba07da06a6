//! A fish model's support that counts the views it scores: shared by the OOD ceiling checks
//! (`ood_scripted`, `ood_planner`).

use fishprobe_sim::{FishView, InputSupport};
use std::sync::atomic::{AtomicU64, Ordering};
use std::sync::Arc;

/// The model's support, counting the views it scores and those at or beyond a threshold.
#[derive(Debug)]
pub struct Counting {
    inner: Arc<dyn InputSupport>,
    threshold: f32,
    /// (views, views at or beyond the threshold)
    counts: (AtomicU64, AtomicU64),
}

impl Counting {
    /// Counts the views `inner` scores against `threshold`.
    pub fn new(inner: Arc<dyn InputSupport>, threshold: f32) -> Self {
        Self {
            inner,
            threshold,
            counts: (AtomicU64::new(0), AtomicU64::new(0)),
        }
    }

    /// (views scored, views at or beyond the threshold).
    pub fn counts(&self) -> (u64, u64) {
        (
            self.counts.0.load(Ordering::Relaxed),
            self.counts.1.load(Ordering::Relaxed),
        )
    }
}

impl InputSupport for Counting {
    fn score(&self, view: &FishView) -> f32 {
        let s = self.inner.score(view);
        self.counts.0.fetch_add(1, Ordering::Relaxed);
        if s >= self.threshold {
            self.counts.1.fetch_add(1, Ordering::Relaxed);
        }
        s
    }
}
