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

/// A fish swimming straight along its heading at the given speed (cm/s).
#[derive(Debug)]
#[allow(dead_code)] // not every test file uses every fish
pub struct Straight(pub f32);

impl FishModel for Straight {
    fn name(&self) -> &str {
        "Straight"
    }
    fn decide(&self, v: &FishView, _: &[f32], _: &mut FishMind, _: &mut SimRng) -> FishMotion {
        FishMotion {
            heading: v.me.heading,
            speed: self.0,
        }
    }
}
