//! How well a fish model's training data covers what a fish sees: the seam between the
//! environment's OOD objective ([`crate::task::Objective::Ood`]) and the support models of
//! data-driven fish (built in `fishprobe-models`, from the recordings the model was fitted on).

use crate::fish::FishView;

/// A support model of a fish model's training inputs.
pub trait InputSupport: Send + Sync + std::fmt::Debug {
    /// How far outside the training data the input `view` lies: 0 at or below the median of
    /// the training views' own scores, 1 at their 95th percentile, larger further out. Finite
    /// and not negative. Called for every fish and frame: must not allocate.
    fn score(&self, view: &FishView) -> f32;
}
