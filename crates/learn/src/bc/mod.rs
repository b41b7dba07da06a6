//! Behavioural cloning of live guppy pairs for M_ConvNet (SPEC §6): the dataset and the
//! training loop behind `fishprobe fit-convnet`.
//!
//! **Dataset.** Every file of two fish (robofish.io or the lab's legacy layout) gives, for each
//! fish and frame t, its egocentric view at t (with the other fish as the neighbour) and the
//! grid cell of its next (v, ω): v = |p(t+1) - p(t)| · rate, ω = wrap(θ(t+1) - θ(t)) · rate.
//! Frames are left out when a position needed (own at t, t+1, t+2; the other's at t) is NaN, or
//! when the tracker interpolated the fish's own frame t or t+1 (`interp_frames` of legacy files,
//! counted from the start of `tracking_interval`). The heading θ(t) is the recorded orientation,
//! except where the fish moves (a step of at least `motion_min_step_cm`) in a direction more
//! than `heading_disagreement_rad` away from it: there the tracker confused head and tail, and
//! the direction of motion is used. Headings are then smoothed over `heading_smoothing_frames`
//! (centred circular mean), which removes the tracker's frame-to-frame jitter from views and
//! turn targets. Files that are not 100 x 100 cm, do not hold exactly two
//! fish, are shorter than `min_frames` or all NaN are skipped with the reason.
//!
//! **Training.** Softmax cross-entropy (the negative log-likelihood of the recorded cell),
//! Adam, minibatches split over two threads, early stopping on the validation NLL (the best
//! epoch's weights are kept), all seeded.

use fishprobe_sim::params::{check, ConfigError};

mod data;
mod fit;
mod run;

pub use data::*;
pub use fit::*;
pub use run::*;

fishprobe_sim::documented_params! {
    /// How pair recordings become training examples, and how the network is fitted.
    pub struct CloneConfig {
        /// A step at least this long (cm per frame) shows the direction of motion (choice:
        /// 0.1 cm per frame = 2.5 cm/s).
        pub motion_min_step_cm: f32 = 0.1; "cm",
        /// Recorded orientation and direction of motion further apart than this: use the
        /// direction of motion (choice: 90°).
        pub heading_disagreement_rad: f32 = std::f32::consts::FRAC_PI_2; "rad",
        /// Headings are smoothed over this many frames, centred (circular mean; odd; 1: none),
        /// before views and turn targets are taken from them. **Choice: 5 (0.2 s at 25 Hz).**
        /// The recorded orientation jitters from frame to frame (median |Δθ| 0.053 rad in the
        /// training pairs) without the jitter adding up (0.072 over 5 frames): tracking noise.
        /// A fish that samples each frame's turn independently (SPEC §6) adds it up as real
        /// turning, and unsmoothed its course wandered twice as fast as a guppy's over 0.2-1 s
        /// and into the walls. Five frames remove the jitter (0.014 per
        /// frame) and leave the course over 1 s and 3 s as recorded (median 0.235 and 0.605
        /// rad, against 0.243 and 0.612). The measurements: docs/validation.md, "M_ConvNet and the virtual guppy against held-back real pairs".
        pub heading_smoothing_frames: usize = 5; "frames",
        /// Files with fewer frames are skipped (choice: 10 s at 25 Hz).
        pub min_frames: usize = 250; "frames",
        /// Minibatch size (choice).
        pub batch_size: usize = 512; "examples",
        /// Adam learning rate (choice).
        pub learning_rate: f32 = 0.001; "1",
        /// Most epochs (choice).
        pub max_epochs: usize = 30; "epochs",
        /// Stop after this many epochs without a better validation NLL (choice).
        pub patience: usize = 3; "epochs",
        /// Also learn from files of one fish with the robot (`lab`, `evaluate`, live trials):
        /// the fish's frames, with the robot as its neighbour (the robot's own motion is not a
        /// fish's). Choice: off, the paper fits fish pairs only; the OOD loop turns
        /// it on to add what the fish did under a policy.
        pub robot_as_partner: bool = false; "-",
        /// The partner range of the support written beside the weights
        /// (`support.partner_range_cm`; choice: 0, every partner counts).
        pub support_partner_range_cm: f32 = 0.0; "cm",
        /// Networks of the ensemble fitted on the same data, the weights included, in
        /// [1, 16] (choice: 1, no ensemble). With K > 1 the K - 1 further members (each from its
        /// own initialisation and shuffle, seeds derived by label) are written beside the
        /// weights with the ensemble's disagreement file, which the OOD score `disagreement`
        /// needs. Each member costs a fit.
        pub ensemble_members: usize = 1; "networks",
        /// Training views the disagreement is calibrated on (choice: 2048, as the support).
        pub ensemble_calibration_views: usize = 2048; "views",
        /// Length of each individual's latent vector (0: M_ConvNet as the paper has it; at most
        /// 4). With more, every fish of every training recording is an individual with its own
        /// embedding, learnt with the network; the embeddings' normal distribution is the
        /// population new fish are drawn from (choice for M_ConvNet with individuals: 4).
        pub latent_dim: usize = 0; "floats",
        /// Weight of the embeddings' standard normal prior, per individual, against the
        /// training examples' mean NLL (choice: 1: the embeddings are MAP estimates under
        /// N(0, I)).
        pub latent_prior: f32 = 1.0; "1",
        /// Gradient steps when a held-back fish's embedding is fitted to its data with the
        /// network fixed (choice: 200 minibatches of `batch_size`).
        pub latent_fit_steps: usize = 200; "steps",
        /// Adam learning rate of the embeddings (choice: 0.01).
        pub latent_learning_rate: f32 = 0.01; "1",
    }
}

impl CloneConfig {
    /// Largest batch (examples) accepted: a batch is held in memory.
    pub const MAX_BATCH: usize = 1 << 20;
    /// Most epochs accepted (the paper's fit takes well under 1,000).
    pub const MAX_EPOCHS: usize = 1_000_000;

    /// Checks the ranges.
    pub fn validate(&self) -> Result<(), ConfigError> {
        check::positive_at_most(
            "clone",
            "motion_min_step_cm",
            self.motion_min_step_cm,
            check::MAX_LENGTH_CM,
        )?;
        // Two headings disagree by at most a half turn.
        check::positive_at_most(
            "clone",
            "heading_disagreement_rad",
            self.heading_disagreement_rad,
            std::f32::consts::PI,
        )?;
        check::positive("clone", "learning_rate", self.learning_rate)?;
        check::positive_at_most(
            "clone",
            "latent_learning_rate",
            self.latent_learning_rate,
            10.0,
        )?;
        check::within(
            "clone",
            "latent_prior",
            self.latent_prior,
            0.0,
            check::MAX_WEIGHT,
        )?;
        if self.latent_dim > fishprobe_sim::LATENT_DIM || self.latent_fit_steps > 1_000_000 {
            return Err(ConfigError::new(
                "clone",
                "latent_dim",
                self.latent_dim,
                &format!(
                    "must be at most {} (and latent_fit_steps at most 1000000)",
                    fishprobe_sim::LATENT_DIM
                ),
            ));
        }
        // The support's own bound, checked before the fit rather than after it.
        check::within(
            "clone",
            "support_partner_range_cm",
            self.support_partner_range_cm,
            0.0,
            check::MAX_LENGTH_CM,
        )?;
        if self.heading_smoothing_frames.is_multiple_of(2) || self.heading_smoothing_frames > 251 {
            return Err(ConfigError::new(
                "clone",
                "heading_smoothing_frames",
                self.heading_smoothing_frames,
                "must be odd and at most 251 (1: no smoothing)",
            ));
        }
        for (f, v) in [
            ("batch_size", self.batch_size),
            ("max_epochs", self.max_epochs),
            ("patience", self.patience),
            ("min_frames", self.min_frames),
        ] {
            if v == 0 {
                return Err(ConfigError::new("clone", f, 0, "must be at least 1"));
            }
        }
        if !(1..=fishprobe_models::disagreement::MAX_MEMBERS).contains(&self.ensemble_members) {
            return Err(ConfigError::new(
                "clone",
                "ensemble_members",
                self.ensemble_members,
                &format!(
                    "must lie in [1, {}]",
                    fishprobe_models::disagreement::MAX_MEMBERS
                ),
            ));
        }
        if !(20..=1 << 20).contains(&self.ensemble_calibration_views) {
            return Err(ConfigError::new(
                "clone",
                "ensemble_calibration_views",
                self.ensemble_calibration_views,
                "must lie in [20, 1048576]",
            ));
        }
        // Upper bounds, checked before anything is allocated: a batch is held in memory, and
        // the paper's fit takes well under 1,000 epochs.
        for (f, v, hi) in [
            ("batch_size", self.batch_size, Self::MAX_BATCH),
            ("max_epochs", self.max_epochs, Self::MAX_EPOCHS),
        ] {
            if v > hi {
                return Err(ConfigError::new(
                    "clone",
                    f,
                    v,
                    &format!("must be at most {hi}"),
                ));
            }
        }
        Ok(())
    }
}
