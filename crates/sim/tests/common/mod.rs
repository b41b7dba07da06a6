//! Fish models shared by the simulator's integration tests.

use fishprobe_sim::{FishMind, FishModel, FishMotion, FishView, SimRng};

/// A fish that stays where it is.
#[derive(Debug)]
pub struct Still;

impl FishModel for Still {
    fn name(&self) -> &str {
        "Still"
    }
    fn decide(&self, v: &FishView, _: &[f32], _: &mut FishMind, _: &mut SimRng) -> FishMotion {
        FishMotion {
            heading: v.me.heading,
            speed: 0.0,
        }
    }
}
