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

    /// The scores of `views` into `out` (same length), each as [`InputSupport::score`] gives
    /// it, whatever the batch: a support whose score is cheaper per view in a batch (the
    /// ensemble's networks) overrides this. Called with a frame's fish, or with the fish of
    /// many environments at once (the vector environment): must not allocate.
    fn score_batch(&self, views: &[FishView], out: &mut [f32]) {
        for (v, o) in views.iter().zip(out) {
            *o = self.score(v);
        }
    }
}
