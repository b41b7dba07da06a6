//! M_Follow, the baseline: swims at constant speed straight at the closest other agent, never
//! overshooting it.

use fishprobe_sim::params::{check, ConfigError};
use fishprobe_sim::{FishMind, FishModel, FishMotion, FishView, SimRng};

fishprobe_sim::documented_params! {
    /// Parameters of M_Follow (SPEC §6).
    pub struct FollowParams {
        /// Constant swimming speed. The paper does not publish it; choice from the fidelity
        /// sweep (docs/validation.md "Departures from the paper"): at 4 cm/s the paper-preset
        /// π_Follow reaches 61.4 goals per 15 min in 14.5 s per goal, the paper's about 60 and
        /// about 15 s; at the earlier choice, M_Zone's 6.3 cm/s, it reached 85.2 in 10.5 s
        /// (`fishprobe fidelity --readings baseline,follow-6.3cm-s --models Follow`).
        pub speed_cm_s: f32 = 4.0; "cm/s",
    }
}

impl FollowParams {
    /// Checks the ranges.
    pub fn validate(&self, prefix: &str) -> Result<(), ConfigError> {
        check::positive_at_most(prefix, "speed_cm_s", self.speed_cm_s, check::MAX_SPEED_CM_S)
    }
}

/// The Follow model.
#[derive(Debug, Clone)]
pub struct Follow {
    p: FollowParams,
}

impl Follow {
    /// From validated parameters.
    pub fn new(p: FollowParams) -> Result<Self, ConfigError> {
        p.validate("")?;
        Ok(Self { p })
    }
}

impl FishModel for Follow {
    fn name(&self) -> &str {
        "Follow"
    }

    fn reads_individual(&self) -> bool {
        true
    }

    /// An individual's speed multiplier scales the speed; M_Follow has no noise, social or
    /// wall terms to vary.
    fn decide(&self, v: &FishView, _: &[f32], mind: &mut FishMind, _: &mut SimRng) -> FishMotion {
        let speed = self.p.speed_cm_s * mind.individual.speed;
        match v.closest_other() {
            // Nobody to follow, or already there: stay put.
            None => FishMotion {
                heading: v.me.heading,
                speed: 0.0,
            },
            Some((_, d)) if d < 1e-4 => FishMotion {
                heading: v.me.heading,
                speed: 0.0,
            },
            Some((o, d)) => FishMotion {
                heading: (o.y - v.me.y).atan2(o.x - v.me.x),
                speed: speed.min(d / v.dt),
            },
        }
    }
}

impl crate::ModelParams for FollowParams {
    const NAME: &'static str = "Follow";
    const SUMMARY: &'static str =
        "baseline: constant speed straight at the closest other agent, no overshoot";

    fn check(&self, prefix: &str) -> Result<(), fishprobe_sim::params::ConfigError> {
        self.validate(prefix)
    }

    fn build_model(
        &self,
    ) -> Result<std::sync::Arc<dyn fishprobe_sim::FishModel>, crate::ModelError> {
        use std::sync::Arc;
        Ok(Arc::new(Follow::new(self.clone())?))
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use fishprobe_sim::{AgentState, Sandbox, Tank};
    use std::sync::Arc;

    #[test]
    fn reaches_a_still_robot_without_overshooting() {
        let model = Arc::new(Follow::new(FollowParams::default()).unwrap());
        let mut sb = Sandbox::new(Tank::default(), 25.0, model, &[[-30.0, -10.0, 2.0]], 1);
        let robot = AgentState::at(10.0, 20.0, 0.0);
        sb.set_scripted(&[robot]);
        let start = sb.fish()[0].distance_to(&robot); // 50 cm
        let mut prev = start;
        for frame in 1..=400 {
            sb.step().unwrap();
            let d = sb.fish()[0].distance_to(&robot);
            assert!(d <= prev + 1e-4, "frame {frame}: moved away");
            // Constant speed: 4 cm/s · 0.04 s per frame until arrival.
            let expected = (start - 4.0 * 0.04 * frame as f32).max(0.0);
            assert!(
                (d - expected).abs() < 1e-3,
                "frame {frame}: {d} vs {expected}"
            );
            prev = d;
        }
        assert!(prev < 1e-3, "arrived: {prev}");
    }
}
