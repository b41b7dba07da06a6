//! The virtual guppy (SPEC §9): the fish of the virtual lab, meant to stand in for a live
//! guppy better than the four candidate models — not a candidate itself.
//!
//! It swims in bursts and glides: at each kick it picks a new direction (persistence, walls,
//! the other agents, noise) and a speed, then glides with exponentially decaying speed
//! until the next kick. It sometimes pauses. Near a wall it turns along it (thigmotaxis); away
//! from walls it drifts back toward the nearest one. Its attraction to the other agents
//! (the robot in the lab; in a group, averaged over the agents within its social range, with
//! repulsion from any too close taking priority) differs between individuals and declines
//! over a long trial. Each
//! episode draws an individual — sociability, boldness, speed — from population distributions
//! (`begin_episode`). The defaults were calibrated against the real pair recordings of the
//! training split (docs/validation.md, "M_ConvNet and the virtual guppy against held-back real pairs").

use fishprobe_sim::params::{check, ConfigError};
use fishprobe_sim::{wrap_angle, AgentState, FishMind, FishModel, FishMotion, FishView, SimRng};
use rand::RngExt;
use rand_distr::{Distribution, StandardNormal};

fishprobe_sim::documented_params! {
    /// Parameters of the virtual guppy (all choices, calibrated on the training pairs).
    pub struct GuppyParams {
        /// Population median of an individual's mean kick speed.
        pub kick_speed_cm_s: f32 = 9.3; "cm/s",
        /// Between-individual spread of the kick speed (s.d. of its logarithm).
        pub speed_spread: f32 = 0.25; "1",
        /// Within-individual variability of each kick's speed (coefficient of variation).
        pub kick_cv: f32 = 0.45; "1",
        /// Glide time constant: speed decays as exp(-t / τ) between kicks.
        pub glide_tau_s: f32 = 0.45; "s",
        /// Mean interval between kicks (exponential, plus a minimum of 0.12 s).
        pub kick_interval_s: f32 = 0.35; "s",
        /// Largest turn rate while steering toward a kick's direction.
        pub max_turn_rad_s: f32 = 8.0; "rad/s",
        /// Turn noise at each kick (s.d.).
        pub kick_noise_rad: f32 = 0.45; "rad",
        /// Heading jitter every frame (s.d.): the wobble of a swimming fish's body axis.
        pub frame_noise_rad: f32 = 0.04; "rad",
        /// Weight of keeping the current heading at a kick.
        pub persistence: f32 = 1.0; "1",
        /// Probability per kick of a pause for the shyest individual (boldness 0); a bold one
        /// (boldness 1) pauses `pause_bold_factor` times as often.
        pub pause_probability: f32 = 0.026; "1",
        /// See `pause_probability`.
        pub pause_bold_factor: f32 = 0.05; "1",
        /// Mean pause duration (exponential).
        pub pause_mean_s: f32 = 2.0; "s",
        /// Walls closer than this deflect the kick direction along the wall.
        pub wall_range_cm: f32 = 5.0; "cm",
        /// Weight of the pull back toward the nearest wall when farther than `wall_range_cm`,
        /// for the shyest individual (scaled by 1 - boldness / 2).
        pub thigmotaxis: f32 = 0.15; "1",
        /// Other agents within this distance attract.
        pub social_range_cm: f32 = 35.0; "cm",
        /// Closer than this, the other agent repels.
        pub repulsion_cm: f32 = 3.0; "cm",
        /// Weight of the attraction for the most sociable individual (sociability 1).
        pub attraction: f32 = 1.0; "1",
        /// Weight of matching the other agent's heading, for the most sociable individual.
        pub alignment: f32 = 1.2; "1",
        /// Sociability of individuals is uniform in [min, max].
        pub sociability_min: f32 = 0.2; "1",
        /// See `sociability_min`.
        pub sociability_max: f32 = 1.0; "1",
        /// Engagement declines as floor + (1 - floor) · exp(-t / τ) over a trial.
        pub engagement_tau_s: f32 = 900.0; "s",
        /// See `engagement_tau_s`.
        pub engagement_floor: f32 = 0.4; "1",
    }
}

impl GuppyParams {
    /// Checks the ranges; `prefix` is the field path of this struct.
    pub fn validate(&self, prefix: &str) -> Result<(), ConfigError> {
        for (f, v) in [
            ("kick_speed_cm_s", self.kick_speed_cm_s),
            ("max_turn_rad_s", self.max_turn_rad_s),
            ("wall_range_cm", self.wall_range_cm),
            ("social_range_cm", self.social_range_cm),
        ] {
            check::positive(prefix, f, v)?;
        }
        for (f, v) in [
            ("glide_tau_s", self.glide_tau_s),
            ("kick_interval_s", self.kick_interval_s),
            ("pause_mean_s", self.pause_mean_s),
            ("engagement_tau_s", self.engagement_tau_s),
        ] {
            check::positive_at_most(prefix, f, v, check::MAX_DURATION_S)?;
        }
        for (f, v, hi) in [
            (
                "kick_speed_cm_s",
                self.kick_speed_cm_s,
                check::MAX_SPEED_CM_S,
            ),
            (
                "max_turn_rad_s",
                self.max_turn_rad_s,
                check::MAX_TURN_RATE_RAD_S,
            ),
            ("wall_range_cm", self.wall_range_cm, check::MAX_LENGTH_CM),
            (
                "social_range_cm",
                self.social_range_cm,
                check::MAX_LENGTH_CM,
            ),
            ("repulsion_cm", self.repulsion_cm, check::MAX_LENGTH_CM),
        ] {
            check::within(prefix, f, v, 0.0, hi)?;
        }
        for (f, v, hi) in [
            ("speed_spread", self.speed_spread, check::MAX_WEIGHT),
            ("kick_cv", self.kick_cv, check::MAX_WEIGHT),
            (
                "kick_noise_rad",
                self.kick_noise_rad,
                check::MAX_ANGLE_NOISE_RAD,
            ),
            (
                "frame_noise_rad",
                self.frame_noise_rad,
                check::MAX_ANGLE_NOISE_RAD,
            ),
            ("persistence", self.persistence, check::MAX_WEIGHT),
            ("thigmotaxis", self.thigmotaxis, check::MAX_WEIGHT),
            ("attraction", self.attraction, check::MAX_WEIGHT),
            ("alignment", self.alignment, check::MAX_WEIGHT),
        ] {
            check::within(prefix, f, v, 0.0, hi)?;
        }
        for (f, v) in [
            ("pause_probability", self.pause_probability),
            ("pause_bold_factor", self.pause_bold_factor),
            ("sociability_min", self.sociability_min),
            ("sociability_max", self.sociability_max),
            ("engagement_floor", self.engagement_floor),
        ] {
            check::within(prefix, f, v, 0.0, 1.0)?;
        }
        if self.sociability_min > self.sociability_max {
            return Err(ConfigError::new(
                prefix,
                "sociability_min",
                check::shown(self.sociability_min),
                "must not exceed sociability_max",
            ));
        }
        Ok(())
    }
}

/// The virtual guppy.
#[derive(Debug, Clone)]
pub struct Guppy {
    p: GuppyParams,
}

// FishMind slots.
const SPEED_SCALE: usize = 0;
const SOCIABILITY: usize = 1;
const BOLDNESS: usize = 2;
const NEXT_KICK: usize = 0;
const PAUSE_LEFT: usize = 1;
const TARGET: usize = 2;

impl Guppy {
    /// A virtual guppy with checked parameters.
    pub fn new(p: GuppyParams) -> Result<Self, ConfigError> {
        p.validate("Guppy")?;
        Ok(Self { p })
    }

    fn normal(rng: &mut SimRng) -> f32 {
        StandardNormal.sample(rng)
    }

    /// The direction of the next kick.
    fn kick_direction(&self, v: &FishView, mind: &FishMind, rng: &mut SimRng) -> f32 {
        let p = &self.p;
        let me = &v.me;
        let (s, c) = me.heading.sin_cos();
        let (mut dx, mut dy) = (p.persistence * c, p.persistence * s);
        // Walls: closer than the range and heading into it → along the wall; farther → a pull
        // toward the nearest wall for shy fish.
        let bold = mind.traits[BOLDNESS];
        let mut nearest = (f32::INFINITY, 0.0f32, 0.0f32);
        for w in v.tank.walls(me.x, me.y) {
            let (nx, ny) = (w.inward[0], w.inward[1]);
            if w.distance < nearest.0 {
                nearest = (w.distance, nx, ny);
            }
            if w.distance < p.wall_range_cm {
                let into = -(c * nx + s * ny);
                if into > -0.2 {
                    // Remove the component into the wall, push off it a little.
                    let k = (1.0 - w.distance / p.wall_range_cm) * 2.0;
                    dx += nx * (into.max(0.0) + k * 0.5);
                    dy += ny * (into.max(0.0) + k * 0.5);
                }
            }
        }
        if nearest.0 >= p.wall_range_cm && nearest.0.is_finite() {
            let w = p.thigmotaxis * (1.0 - 0.5 * bold);
            dx -= nearest.1 * w;
            dy -= nearest.2 * w;
        }
        // The other agents within the social range: repulsion from those too close has
        // priority; otherwise attraction and alignment, averaged over the agents in range (in a
        // group; with one other agent this is the pair model the defaults were calibrated on).
        let (mut rep, mut att, mut ali) = ([0.0f32; 2], [0.0f32; 2], [0.0f32; 2]);
        let (mut n_rep, mut n_att) = (0u32, 0u32);
        for o in v.others() {
            let d = me.distance_to(o);
            if !(d > 1e-3 && d < p.social_range_cm) {
                continue;
            }
            let (ux, uy) = ((o.x - me.x) / d, (o.y - me.y) / d);
            if d < p.repulsion_cm {
                rep[0] += ux;
                rep[1] += uy;
                n_rep += 1;
            } else {
                let (os, oc) = o.heading.sin_cos();
                att[0] += ux;
                att[1] += uy;
                ali[0] += oc;
                ali[1] += os;
                n_att += 1;
            }
        }
        let mean = |v: [f32; 2], n: u32| {
            if n > 1 {
                [v[0] / n as f32, v[1] / n as f32]
            } else {
                v
            }
        };
        if n_rep > 0 {
            let r = mean(rep, n_rep);
            dx -= r[0];
            dy -= r[1];
        } else if n_att > 0 {
            let (u, o) = (mean(att, n_att), mean(ali, n_att));
            let engagement = p.engagement_floor
                + (1.0 - p.engagement_floor) * (-v.time_s / p.engagement_tau_s).exp();
            let a = p.attraction * mind.traits[SOCIABILITY] * engagement;
            dx += u[0] * a;
            dy += u[1] * a;
            let al = p.alignment * mind.traits[SOCIABILITY] * engagement;
            dx += o[0] * al;
            dy += o[1] * al;
        }
        let base = if dx * dx + dy * dy > 1e-12 {
            dy.atan2(dx)
        } else {
            me.heading
        };
        wrap_angle(base + p.kick_noise_rad * Self::normal(rng))
    }
}

impl FishModel for Guppy {
    fn name(&self) -> &str {
        "Guppy"
    }

    fn begin_episode(&self, me: &AgentState, mind: &mut FishMind, rng: &mut SimRng) {
        let p = &self.p;
        *mind = FishMind::default();
        mind.traits[SPEED_SCALE] = (p.speed_spread * Self::normal(rng)).exp();
        mind.traits[SOCIABILITY] =
            p.sociability_min + (p.sociability_max - p.sociability_min) * rng.random::<f32>();
        mind.traits[BOLDNESS] = rng.random::<f32>();
        mind.speed = me.speed();
        mind.memory[NEXT_KICK] = 0.0;
        mind.memory[TARGET] = me.heading;
    }

    fn reads_individual(&self) -> bool {
        true
    }

    fn decide(
        &self,
        v: &FishView,
        _inferred: &[f32],
        mind: &mut FishMind,
        rng: &mut SimRng,
    ) -> FishMotion {
        if mind.individual.is_neutral() {
            self.step(v, mind, rng)
        } else {
            self.individual(&mind.individual).step(v, mind, rng)
        }
    }
}

impl Guppy {
    /// This virtual guppy as one individual of a population: kick speed, kick and frame
    /// noise, attraction and alignment (the social terms) and the wall range scaled by the
    /// individual's multipliers, on top of the traits it draws itself.
    pub fn individual(&self, ind: &fishprobe_sim::Individual) -> Self {
        let mut g = self.clone();
        g.p.kick_speed_cm_s *= ind.speed;
        g.p.kick_noise_rad *= ind.noise;
        g.p.frame_noise_rad *= ind.noise;
        g.p.attraction *= ind.social;
        g.p.alignment *= ind.social;
        g.p.wall_range_cm *= ind.wall;
        g
    }

    /// One frame of the virtual guppy.
    fn step(&self, v: &FishView, mind: &mut FishMind, rng: &mut SimRng) -> FishMotion {
        let p = &self.p;
        let dt = v.dt;
        if mind.memory[PAUSE_LEFT] > 0.0 {
            mind.memory[PAUSE_LEFT] -= dt;
            mind.speed *= (-dt / 0.1).exp();
            return FishMotion {
                heading: v.me.heading,
                speed: mind.speed,
            };
        }
        mind.memory[NEXT_KICK] -= dt;
        if mind.memory[NEXT_KICK] <= 0.0 {
            let bold = mind.traits[BOLDNESS];
            let pause_p = p.pause_probability * (1.0 - bold * (1.0 - p.pause_bold_factor));
            if rng.random::<f32>() < pause_p {
                let u: f32 = rng.random::<f32>().max(1e-6);
                mind.memory[PAUSE_LEFT] = -p.pause_mean_s * u.ln();
                mind.memory[NEXT_KICK] = 0.0;
                return FishMotion {
                    heading: v.me.heading,
                    speed: mind.speed * (-dt / 0.1).exp(),
                };
            }
            mind.memory[TARGET] = self.kick_direction(v, mind, rng);
            let mean = p.kick_speed_cm_s * mind.traits[SPEED_SCALE];
            mind.speed = (mean * (1.0 + p.kick_cv * Self::normal(rng)))
                .max(0.5 * mean)
                .min(40.0);
            let u: f32 = rng.random::<f32>().max(1e-6);
            mind.memory[NEXT_KICK] = 0.12 - (p.kick_interval_s - 0.12).max(0.01) * u.ln();
        } else {
            mind.speed *= (-dt / p.glide_tau_s).exp();
        }
        let err = wrap_angle(mind.memory[TARGET] - v.me.heading);
        let step = err.clamp(-p.max_turn_rad_s * dt, p.max_turn_rad_s * dt)
            + p.frame_noise_rad * Self::normal(rng);
        mind.turn_rate = step / dt;
        FishMotion {
            heading: v.me.heading + step,
            speed: mind.speed,
        }
    }
}

impl crate::ModelParams for GuppyParams {
    const NAME: &'static str = "Guppy";
    const ALIASES: &'static [&'static str] = &["virtualguppy"];
    const SUMMARY: &'static str =
        "the virtual lab's guppy: burst and glide, pauses, thigmotaxis, individual sociability";

    fn check(&self, prefix: &str) -> Result<(), fishprobe_sim::params::ConfigError> {
        self.validate(prefix)
    }

    fn build_model(
        &self,
    ) -> Result<std::sync::Arc<dyn fishprobe_sim::FishModel>, crate::ModelError> {
        use std::sync::Arc;
        Ok(Arc::new(Guppy::new(self.clone())?))
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use fishprobe_sim::{stream, Sandbox, Tank, TankParams};
    use std::sync::Arc;

    fn run(p: GuppyParams, seconds: f32, seed: u64) -> (Vec<f32>, Vec<f32>) {
        let tank = Tank::new(&TankParams::default());
        let mut sb = Sandbox::new(
            tank,
            25.0,
            Arc::new(Guppy::new(p).unwrap()),
            &[[0.0, 0.0, 0.0]],
            seed,
        );
        let (mut speeds, mut walls) = (Vec::new(), Vec::new());
        let mut last = sb.fish()[0];
        for _ in 0..(seconds * 25.0) as usize {
            sb.step().unwrap();
            let f = sb.fish()[0];
            speeds.push(((f.x - last.x).powi(2) + (f.y - last.y).powi(2)).sqrt() * 25.0);
            walls.push(tank.wall_distance(f.x, f.y));
            last = f;
        }
        (speeds, walls)
    }

    #[test]
    fn bursts_glides_and_follows_walls_without_contacts() {
        let (speeds, walls) = run(GuppyParams::default(), 300.0, 3);
        let mean = speeds.iter().sum::<f32>() / speeds.len() as f32;
        assert!((3.0..10.0).contains(&mean), "mean speed {mean}");
        // Burst and glide: speed varies a lot within seconds.
        let max = speeds.iter().copied().fold(0.0, f32::max);
        assert!(max > 2.0 * mean, "no bursts: max {max}, mean {mean}");
        let mean_wall = walls.iter().sum::<f32>() / walls.len() as f32;
        assert!(
            mean_wall < 16.7,
            "no thigmotaxis: mean wall distance {mean_wall}"
        );
        let contacts = walls.iter().filter(|w| **w <= 1.0 + 1e-3).count();
        assert!(
            contacts < walls.len() / 100,
            "{contacts} frames at the wall"
        );
    }

    #[test]
    fn individuals_differ_and_the_draw_is_seeded() {
        let g = Guppy::new(GuppyParams::default()).unwrap();
        let me = AgentState::at(0.0, 0.0, 0.0);
        let draw = |seed| {
            let mut m = FishMind::default();
            g.begin_episode(&me, &mut m, &mut stream(seed, "fish", 0));
            m.traits
        };
        assert_eq!(draw(1), draw(1));
        assert_ne!(draw(1), draw(2));
    }

    #[test]
    fn engagement_declines_so_attraction_weakens() {
        let g = Guppy::new(GuppyParams {
            kick_noise_rad: 0.0,
            alignment: 0.0,
            thigmotaxis: 0.0,
            ..GuppyParams::default()
        })
        .unwrap();
        let mut mind = FishMind::default();
        mind.traits[SOCIABILITY] = 1.0;
        let tank = Tank::new(&TankParams::default());
        // Heading +y, the robot 10 cm along +x: the kick bends toward the robot, less so late
        // in a long trial.
        let robot = AgentState::at(10.0, 0.0, 0.0);
        let me = [AgentState::at(0.0, 0.0, std::f32::consts::FRAC_PI_2)];
        let mut rng = stream(0, "t", 0);
        let at = |t: f32, rng: &mut SimRng| {
            let v = FishView::build(0, &me, &[robot], tank, 0.04, t);
            g.kick_direction(&v, &mind, rng)
        };
        let (early, late) = (at(0.0, &mut rng), at(3600.0, &mut rng));
        assert!(
            (early - std::f32::consts::FRAC_PI_4).abs() < 1e-3,
            "{early}"
        );
        assert!(late > early + 0.3, "early {early}, late {late}");
        let p = GuppyParams::default();
        assert!(GuppyParams {
            sociability_min: 0.9,
            sociability_max: 0.1,
            ..p
        }
        .validate("G")
        .is_err());
    }
}
