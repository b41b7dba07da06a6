//! M_Force: the variable-speed social force model of Klamser et al. (2021) with noise and a
//! wall module (SPEC §6). The time unit of its parameters is one simulation frame (25 Hz):
//! speeds in cm per frame, forces in cm per frame per frame.

use fishprobe_sim::params::{check, ConfigError};
use fishprobe_sim::{AgentState, FishMind, FishModel, FishMotion, FishView, SimRng, Tank};
use rand_distr::{Distribution, StandardNormal};
use serde::{Deserialize, Serialize};

/// How the noise intensities D are turned into per-frame standard deviations σ.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Serialize, Deserialize)]
#[serde(rename_all = "snake_case")]
pub enum NoiseConvention {
    /// σ = sqrt(2 D dt) with dt the frame duration in seconds: Euler-Maruyama with D per
    /// second (choice).
    PerSecond,
    /// σ = sqrt(2 D): D per frame.
    PerFrame,
    /// σ = D: D read as the per-frame standard deviation.
    StdDev,
}

/// Frames per second of the parameters' time unit: speeds are in cm per frame and forces in
/// cm per frame² at the paper's 25 Hz.
pub const UNIT_FRAMES_PER_S: f32 = 25.0;

/// Largest alignment strength μ_alg (per frame). The alignment pulls the fish's velocity
/// toward its partner's by μ_alg of the difference each frame; beyond 2 that frame-by-frame
/// step overshoots by more than the difference and diverges (with the paper's other values,
/// 50 fish in open water stay a polarised school up to 1.9 and scatter at 2.5:
/// `fishprobe collective --model force --alignment 1.9,2.5`).
pub const MAX_ALIGNMENT: f32 = 2.0;

/// Largest preferred speed (cm per frame): [`check::MAX_SPEED_CM_S`] at 25 Hz.
pub const MAX_SPEED: f32 = check::MAX_SPEED_CM_S / UNIT_FRAMES_PER_S;

/// Largest force strength (cm per frame²): [`check::MAX_ACCELERATION_CM_S2`] at 25 Hz.
pub const MAX_FORCE: f32 = check::MAX_ACCELERATION_CM_S2 / (UNIT_FRAMES_PER_S * UNIT_FRAMES_PER_S);

fishprobe_sim::documented_params! {
    /// Parameters of M_Force. Defaults: the published values (SPEC §6).
    pub struct ForceParams {
        /// Agents within this distance interact (paper: 15 cm).
        pub interaction_range_cm: f32 = 15.0; "cm",
        /// Preferred distance r_d to the other agent (paper: 5 cm).
        pub preferred_distance_cm: f32 = 5.0; "cm",
        /// Alignment strength μ_alg (paper: 0.1).
        pub alignment: f32 = 0.1; "1/frame",
        /// Distance-regulation strength μ_d (paper: 0.3).
        pub distance_regulation: f32 = 0.3; "cm/frame²",
        /// Slope m_d of the distance regulation's tanh (paper: 0.2).
        pub distance_slope: f32 = 0.2; "1/cm",
        /// Preferred speed v0 (paper: 0.2 cm per time step = 5 cm/s at 25 Hz).
        pub preferred_speed: f32 = 0.2; "cm/frame",
        /// Speed relaxation β toward v0 (paper: 0.5).
        pub speed_relaxation: f32 = 0.5; "1/frame",
        /// Rotational friction α: turning is divided by (v + α) (paper: 1.0).
        pub rotational_friction: f32 = 1.0; "cm/frame",
        /// Angular noise intensity D_φ (paper: 0.3).
        pub angular_noise: f32 = 0.3; "see noise_convention",
        /// Speed noise intensity D_v (paper: 0.2).
        pub speed_noise: f32 = 0.2; "see noise_convention",
        /// How D becomes a per-frame σ (choice: per second, Euler-Maruyama).
        pub noise_convention: NoiseConvention = NoiseConvention::PerSecond; "-",
        /// Wall attraction's outward-angle factor (paper: -0.7).
        pub wall_outward_angle_factor: f32 = -0.7; "1",
        /// Weight of the wall tangent in the repulsion direction (paper: 0.3).
        pub wall_perpendicular_factor: f32 = 0.3; "1",
        /// Wall attraction strength (paper: 0.3).
        pub wall_attraction: f32 = 0.3; "cm/frame²",
        /// Walls closer than this repel when the fish heads into them (paper: 11).
        pub wall_repulsion_range_cm: f32 = 11.0; "cm",
        /// Wall repulsion strength at the wall, falling linearly to 0 at the range (paper: 0.7).
        pub wall_repulsion_strength: f32 = 0.7; "cm/frame²",
        /// Heading away from a wall within this multiple of the range attracts (choice: 2,
        /// i.e. 22 cm).
        pub wall_attraction_band: f32 = 2.0; "1",
    }
}

impl ForceParams {
    /// Checks the ranges; `prefix` is the field path of this struct.
    pub fn validate(&self, prefix: &str) -> Result<(), ConfigError> {
        for (f, v) in [
            ("interaction_range_cm", self.interaction_range_cm),
            ("preferred_distance_cm", self.preferred_distance_cm),
        ] {
            check::within(prefix, f, v, 0.0, check::MAX_LENGTH_CM)?;
        }
        check::within(prefix, "alignment", self.alignment, 0.0, MAX_ALIGNMENT)?;
        check::within(
            prefix,
            "distance_regulation",
            self.distance_regulation,
            0.0,
            MAX_FORCE,
        )?;
        check::within(
            prefix,
            "distance_slope",
            self.distance_slope,
            0.0,
            check::MAX_WEIGHT,
        )?;
        check::positive_at_most(prefix, "preferred_speed", self.preferred_speed, MAX_SPEED)?;
        check::within(prefix, "speed_relaxation", self.speed_relaxation, 0.0, 1.0)?;
        check::positive_at_most(
            prefix,
            "rotational_friction",
            self.rotational_friction,
            MAX_SPEED,
        )?;
        check::non_negative(prefix, "angular_noise", self.angular_noise)?;
        check::non_negative(prefix, "speed_noise", self.speed_noise)?;
        // Each noise is a speed or an angle once its convention turns it into a per-frame σ.
        let (sigma_v, sigma_phi) = self.noise_sigmas(1.0 / UNIT_FRAMES_PER_S);
        for (field, d, sigma, what, unit, max, max_name) in [
            (
                "speed_noise",
                self.speed_noise,
                sigma_v,
                "a speed noise",
                "cm",
                MAX_SPEED,
                "fishprobe_models::force::MAX_SPEED",
            ),
            (
                "angular_noise",
                self.angular_noise,
                sigma_phi,
                "a heading noise",
                "rad",
                check::MAX_ANGLE_NOISE_RAD,
                "a full turn, fishprobe_sim::params::check::MAX_ANGLE_NOISE_RAD",
            ),
        ] {
            if sigma > max {
                return Err(ConfigError::new(
                    prefix,
                    field,
                    check::shown(d),
                    &format!(
                        "gives {what} σ of {} {unit} per frame (noise_convention = {}); it must \
                         be at most {} ({max_name})",
                        check::shown(sigma),
                        // The name a settings file uses, quoted, as serde spells it.
                        serde_json::to_string(&self.noise_convention).unwrap_or_default(),
                        check::shown(max)
                    ),
                ));
            }
        }
        for (f, v) in [
            ("wall_outward_angle_factor", self.wall_outward_angle_factor),
            ("wall_perpendicular_factor", self.wall_perpendicular_factor),
        ] {
            check::within(prefix, f, v, -check::MAX_WEIGHT, check::MAX_WEIGHT)?;
        }
        check::within(
            prefix,
            "wall_attraction",
            self.wall_attraction,
            0.0,
            MAX_FORCE,
        )?;
        check::positive_at_most(
            prefix,
            "wall_repulsion_range_cm",
            self.wall_repulsion_range_cm,
            check::MAX_LENGTH_CM,
        )?;
        check::within(
            prefix,
            "wall_repulsion_strength",
            self.wall_repulsion_strength,
            0.0,
            MAX_FORCE,
        )?;
        check::within(
            prefix,
            "wall_attraction_band",
            self.wall_attraction_band,
            0.0,
            check::MAX_WEIGHT,
        )
    }

    /// Per-frame noise standard deviations (speed, angle) for a frame of `dt` seconds.
    pub fn noise_sigmas(&self, dt: f32) -> (f32, f32) {
        let sigma = |d: f32| match self.noise_convention {
            NoiseConvention::PerSecond => (2.0 * d * dt).sqrt(),
            NoiseConvention::PerFrame => (2.0 * d).sqrt(),
            NoiseConvention::StdDev => d,
        };
        (sigma(self.speed_noise), sigma(self.angular_noise))
    }
}

/// The Force model.
#[derive(Debug, Clone)]
pub struct Force {
    p: ForceParams,
}

impl Force {
    /// The parameters.
    pub fn params(&self) -> &ForceParams {
        &self.p
    }

    /// From parameters (validated here).
    pub fn new(p: ForceParams) -> Result<Self, ConfigError> {
        p.validate("")?;
        Ok(Self { p })
    }

    /// Social force on the fish (cm/frame²); `vf` its speed in cm/frame, `dt` the frame
    /// duration (s). The force is averaged over the partners within the interaction range
    /// (Klamser et al. 2021), so a group pulls no harder than one partner.
    fn social(
        &self,
        me: &AgentState,
        others: &[AgentState],
        dt: f32,
        e: [f32; 2],
        vf: f32,
    ) -> [f32; 2] {
        let p = &self.p;
        let mut f = [0.0f32; 2];
        let mut n = 0u32;
        for o in others {
            let (dx, dy) = (o.x - me.x, o.y - me.y);
            let d = (dx * dx + dy * dy).sqrt();
            if d >= p.interaction_range_cm || d < 1e-6 {
                continue;
            }
            let k =
                p.distance_regulation * (p.distance_slope * (d - p.preferred_distance_cm)).tanh();
            // The other's velocity in cm per frame.
            let (ux, uy) = (o.vx * dt, o.vy * dt);
            f[0] += k * dx / d + p.alignment * (ux - vf * e[0]);
            f[1] += k * dy / d + p.alignment * (uy - vf * e[1]);
            n += 1;
        }
        if n > 1 {
            let n = n as f32;
            f = [f[0] / n, f[1] / n];
        }
        f
    }

    /// Wall forces: (repulsion, entering speed and heading; attraction, heading only).
    fn walls(&self, tank: &Tank, me: &AgentState, e: [f32; 2]) -> ([f32; 2], [f32; 2]) {
        let p = &self.p;
        let (mut rep, mut att) = ([0.0f32; 2], [0.0f32; 2]);
        let band = p.wall_attraction_band * p.wall_repulsion_range_cm;
        for wall in tank.walls(me.x, me.y) {
            let n = wall.inward;
            let en = e[0] * n[0] + e[1] * n[1];
            if en < 0.0 && wall.distance < p.wall_repulsion_range_cm {
                // Tangent in the direction of travel.
                let t0 = [-n[1], n[0]];
                let sign = if e[0] * t0[0] + e[1] * t0[1] >= 0.0 {
                    1.0
                } else {
                    -1.0
                };
                let k =
                    p.wall_repulsion_strength * (1.0 - wall.distance / p.wall_repulsion_range_cm);
                rep[0] += k * (n[0] + p.wall_perpendicular_factor * sign * t0[0]);
                rep[1] += k * (n[1] + p.wall_perpendicular_factor * sign * t0[1]);
            } else if en > 0.0 && wall.distance < band {
                let k = p.wall_attraction * p.wall_outward_angle_factor * en;
                att[0] += k * n[0];
                att[1] += k * n[1];
            }
        }
        (rep, att)
    }
}

impl FishModel for Force {
    fn name(&self) -> &str {
        "Force"
    }

    fn begin_episode(&self, _: &AgentState, mind: &mut FishMind, _: &mut SimRng) {
        // Start at the preferred speed (cm/s at 25 Hz; rescaled by dt in decide).
        *mind = FishMind {
            speed: self.p.preferred_speed * UNIT_FRAMES_PER_S,
            ..FishMind::default()
        };
    }

    fn reads_individual(&self) -> bool {
        true
    }

    fn decide(&self, v: &FishView, _: &[f32], mind: &mut FishMind, rng: &mut SimRng) -> FishMotion {
        if mind.individual.is_neutral() {
            self.step_among(&v.me, v.others(), Some(&v.tank), v.dt, mind, rng)
        } else {
            self.individual(&mind.individual).step_among(
                &v.me,
                v.others(),
                Some(&v.tank),
                v.dt,
                mind,
                rng,
            )
        }
    }
}

impl Force {
    /// This model as one individual: preferred speed, speed and angular noise, distance
    /// regulation and alignment (the social terms) and the wall repulsion range scaled by the
    /// individual's multipliers (noise as a standard deviation: its intensity by the square).
    pub fn individual(&self, ind: &fishprobe_sim::Individual) -> Self {
        let mut f = self.clone();
        f.p.preferred_speed *= ind.speed;
        f.p.speed_noise *= ind.noise * ind.noise;
        f.p.angular_noise *= ind.noise * ind.noise;
        f.p.distance_regulation *= ind.social;
        f.p.alignment *= ind.social;
        f.p.wall_repulsion_range_cm *= ind.wall;
        f
    }

    /// One frame of a fish at `me` among `others` (any number), with the tank's walls or, with
    /// `tank = None`, in open water: what [`FishModel::decide`] does with a view, for groups
    /// larger than a view holds (the collective-state validation, [`crate::collective`]).
    pub fn step_among(
        &self,
        me: &AgentState,
        others: &[AgentState],
        tank: Option<&Tank>,
        dt: f32,
        mind: &mut FishMind,
        rng: &mut SimRng,
    ) -> FishMotion {
        let p = &self.p;
        let (s, c) = me.heading.sin_cos();
        let e = [c, s];
        let vf = mind.speed * dt;
        let social = self.social(me, others, dt, e, vf);
        let (rep, att) = match tank {
            Some(t) => self.walls(t, me, e),
            None => ([0.0; 2], [0.0; 2]),
        };
        let f = [social[0] + rep[0], social[1] + rep[1]];
        let (sigma_v, sigma_phi) = p.noise_sigmas(dt);
        let xi: f32 = StandardNormal.sample(rng);
        let xi2: f32 = StandardNormal.sample(rng);
        let v_new = (vf
            + p.speed_relaxation * (p.preferred_speed - vf)
            + f[0] * c
            + f[1] * s
            + sigma_v * xi)
            .max(0.0);
        // ê⊥ = (-sin θ, cos θ); attraction enters the heading only.
        let lateral = -(f[0] + att[0]) * s + (f[1] + att[1]) * c;
        let dtheta = (lateral + sigma_phi * xi2) / (v_new + p.rotational_friction);
        mind.speed = v_new / dt;
        mind.turn_rate = dtheta / dt;
        FishMotion {
            heading: me.heading + dtheta,
            speed: v_new / dt,
        }
    }
}

impl crate::ModelParams for ForceParams {
    const NAME: &'static str = "Force";
    const SUMMARY: &'static str =
        "Klamser et al. 2021 variable-speed force model with noise and a wall module";

    fn check(&self, prefix: &str) -> Result<(), fishprobe_sim::params::ConfigError> {
        self.validate(prefix)
    }

    fn build_model(
        &self,
    ) -> Result<std::sync::Arc<dyn fishprobe_sim::FishModel>, crate::ModelError> {
        use std::sync::Arc;
        Ok(Arc::new(Force::new(self.clone())?))
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use fishprobe_sim::Sandbox;
    use std::sync::Arc;

    /// The default parameters with one change.
    fn with(change: impl FnOnce(&mut ForceParams)) -> ForceParams {
        let mut p = ForceParams::default();
        change(&mut p);
        p
    }

    #[test]
    fn absurd_strengths_and_speeds_are_refused_by_name() {
        // The bounds themselves are allowed; 20,000 per second is a speed noise σ of 40 cm/frame.
        for ok in [
            with(|p| p.alignment = MAX_ALIGNMENT),
            with(|p| p.preferred_speed = MAX_SPEED),
            with(|p| p.distance_regulation = MAX_FORCE),
            with(|p| p.speed_noise = 20_000.0),
        ] {
            ok.validate("fish").unwrap();
        }
        for (field, bad, says) in [
            ("alignment", with(|p| p.alignment = 2.5), "[0, 2]"),
            (
                "preferred_speed",
                with(|p| p.preferred_speed = 1e20),
                "(0, 40]",
            ),
            (
                "distance_regulation",
                with(|p| p.distance_regulation = 17.0),
                "[0, 16]",
            ),
            (
                "wall_attraction",
                with(|p| p.wall_attraction = 1e9),
                "[0, 16]",
            ),
            (
                "wall_repulsion_strength",
                with(|p| p.wall_repulsion_strength = 1e9),
                "[0, 16]",
            ),
            (
                "rotational_friction",
                with(|p| p.rotational_friction = 1e30),
                "(0, 40]",
            ),
            ("speed_noise", with(|p| p.speed_noise = 1e30), "at most 40"),
            (
                "speed_noise",
                with(|p| {
                    p.speed_noise = 41.0;
                    p.noise_convention = NoiseConvention::StdDev;
                }),
                "σ of 41 cm per frame (noise_convention = \"std_dev\"); it must be at most 40",
            ),
            (
                "angular_noise",
                with(|p| {
                    p.angular_noise = 7.0;
                    p.noise_convention = NoiseConvention::StdDev;
                }),
                "a heading noise σ of 7 rad per frame (noise_convention = \"std_dev\"); it must \
                 be at most 6.2831855 (a full turn",
            ),
        ] {
            let e = bad.validate("fish").unwrap_err().to_string();
            assert!(
                e.contains(&format!("fish.{field}")) && e.contains(says),
                "{e}"
            );
        }
    }

    #[test]
    fn noise_conventions() {
        let p = ForceParams::default();
        let (sv, sp) = p.noise_sigmas(0.04);
        assert!((sv - (2.0f32 * 0.2 * 0.04).sqrt()).abs() < 1e-7);
        assert!((sp - (2.0f32 * 0.3 * 0.04).sqrt()).abs() < 1e-7);
        let q = ForceParams {
            noise_convention: NoiseConvention::PerFrame,
            ..p.clone()
        };
        assert!((q.noise_sigmas(0.04).1 - 0.6f32.sqrt()).abs() < 1e-7);
        let r = ForceParams {
            noise_convention: NoiseConvention::StdDev,
            ..p
        };
        assert_eq!(r.noise_sigmas(0.04), (0.2, 0.3));
    }

    /// Mean distance to a robot driving straight at 5 cm/s, over the second half of the run.
    fn trailing_distance(p: ForceParams, seed: u64) -> f32 {
        let model = Arc::new(Force::new(p).unwrap());
        let mut sb = Sandbox::new(Tank::default(), 25.0, model, &[[-45.0, 0.0, 0.0]], seed);
        let mut sum = 0.0;
        let mut n = 0;
        for k in 0..400 {
            // Robot from x = -40 to x = 40 at 5 cm/s (16 s).
            let mut robot = AgentState::at(-40.0 + 5.0 * 0.04 * k as f32, 0.0, 0.0);
            robot.vx = 5.0;
            sb.set_scripted(&[robot]);
            sb.step().unwrap();
            if k >= 200 {
                sum += sb.fish()[0].distance_to(&robot);
                n += 1;
            }
        }
        sum / n as f32
    }

    #[test]
    fn holds_the_preferred_distance_behind_a_moving_robot() {
        let quiet = ForceParams {
            angular_noise: 0.0,
            speed_noise: 0.0,
            ..ForceParams::default()
        };
        let d = trailing_distance(quiet, 0);
        assert!((d - 5.0).abs() < 0.5, "noise-free distance {d} cm");
        let noisy: f32 = (0..8)
            .map(|s| trailing_distance(ForceParams::default(), s))
            .sum::<f32>()
            / 8.0;
        assert!(
            (3.5..7.0).contains(&noisy),
            "noisy mean distance {noisy} cm"
        );
    }
}
