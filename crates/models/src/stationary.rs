//! A fish that never moves: the stationary fish of the approach assay (SPEC §8).

use fishprobe_sim::params::ConfigError;
use fishprobe_sim::{FishMind, FishModel, FishMotion, FishView, SimRng};

fishprobe_sim::documented_params! {
    /// A stationary fish has no parameters.
    pub struct StationaryParams {}
}

impl StationaryParams {
    /// Nothing to check.
    pub fn validate(&self, _prefix: &str) -> Result<(), ConfigError> {
        Ok(())
    }
}

/// The stationary fish.
#[derive(Debug, Clone, Default)]
pub struct Stationary;

impl FishModel for Stationary {
    fn name(&self) -> &str {
        "Stationary"
    }

    fn decide(&self, v: &FishView, _: &[f32], _: &mut FishMind, _: &mut SimRng) -> FishMotion {
        FishMotion {
            heading: v.me.heading,
            speed: 0.0,
        }
    }
}

impl crate::ModelParams for StationaryParams {
    const NAME: &'static str = "Stationary";
    const SUMMARY: &'static str = "never moves (approach assay)";

    fn check(&self, prefix: &str) -> Result<(), fishprobe_sim::params::ConfigError> {
        self.validate(prefix)
    }

    fn build_model(
        &self,
    ) -> Result<std::sync::Arc<dyn fishprobe_sim::FishModel>, crate::ModelError> {
        use std::sync::Arc;
        Ok(Arc::new(Stationary))
    }
}
