//! The policy's observation (SPEC §5): wall raycasts and fish and goal sectors around the
//! robot, plus the previous action's fish and goal sectors.

use crate::agent::AgentState;
use crate::geometry::{wrap_angle, Tank};
use crate::params::{check, ConfigError};
use std::f32::consts::{PI, TAU};

/// Upper bound of `previous_block_actions`: a second at one action per frame.
pub const MAX_PREVIOUS_BLOCK_ACTIONS: u32 = 25;

crate::documented_params! {
    /// Observation encoding.
    pub struct ObservationParams {
        /// Sectors (and wall rays) evenly spaced over 360°, sector i covering
        /// [-π + i·w, -π + (i+1)·w) relative to the robot's heading; rays point at sector
        /// centres (paper: 36).
        pub sectors: u32 = 36; "1",
        /// Far plane D of the intensity 1 - d/D (choice, the lab's convention: the tank
        /// diagonal, 141.42 cm).
        pub far_plane_cm: f32 = 141.421_36; "cm",
        /// Groups (a documented extension; choice: off, the paper's 180 values): a
        /// sixth block of `sectors` bins holding the centroid of the fish (its intensity in the
        /// sector that holds it), after the five blocks of SPEC §5. The fish bins already hold
        /// the nearest fish per sector; with the centroid a policy sees where the group is, and
        /// one architecture serves 1 to 16 fish (with one fish the block repeats the fish's
        /// bin). A policy trained with it must be evaluated with it (a study file and the live
        /// bridge's settings have the same switch).
        pub centroid_bins: bool = false; "-",
        /// The fish's headings (a documented extension for the OOD task; choice: off,
        /// the paper's observation): a further block of `sectors` bins, after the centroid's if
        /// that is on, in which each fish marks the sector its heading points to, relative to
        /// the robot's heading, with its intensity (the nearest fish per sector wins). The
        /// paper's observation shows where the fish is, now and a second ago, not where it is
        /// going, which a robot needs to pass the fish in ways its model has not seen (the OOD
        /// task: docs/guide/ood.md). A policy records its observation settings and is run
        /// only with them: `evaluate` refuses others by name, an OOD run's yardstick and
        /// `ood-report`'s comparison policy observe as they were trained, and the live bridge
        /// runs such a policy only with its own `heading_bins` (`fishprobe lab --heading-bins`).
        pub heading_bins: bool = false; "-",
        /// How many actions back the fourth and fifth blocks look (choice: 1, SPEC §5's
        /// "previous step"; at the paper's one action a second, a second ago). At five actions
        /// a second (`frames_per_action = 5`) one action back is a fifth of a second, in which
        /// a guppy moves about a centimetre, less than a 10° sector at most distances; 5 keeps
        /// the paper's second. Measured on the OOD task at 5 Hz it did not help (docs/validation.md,
        /// "Probes that seek what the data lacks"). The observation's
        /// length and layout do not change. A policy records it and is run only with it:
        /// `evaluate` refuses others by name, an OOD run's yardstick and `ood-report`'s
        /// comparison policy look back as they were trained, and the live bridge, which looks
        /// one action back, refuses a policy trained otherwise.
        pub previous_block_actions: u32 = 1; "actions",
    }
}

impl ObservationParams {
    /// Checks the ranges; `prefix` is the field path of this struct.
    pub fn validate(&self, prefix: &str) -> Result<(), ConfigError> {
        if !(4..=720).contains(&self.sectors) {
            return Err(ConfigError::new(
                prefix,
                "sectors",
                self.sectors,
                "must lie in [4, 720]",
            ));
        }
        if !(1..=MAX_PREVIOUS_BLOCK_ACTIONS).contains(&self.previous_block_actions) {
            return Err(ConfigError::new(
                prefix,
                "previous_block_actions",
                self.previous_block_actions,
                &format!("must lie in [1, {MAX_PREVIOUS_BLOCK_ACTIONS}]"),
            ));
        }
        check::positive_at_most(
            prefix,
            "far_plane_cm",
            self.far_plane_cm,
            check::MAX_LENGTH_CM,
        )
    }

    /// Length of the history `ObservationEncoder::encode` keeps between calls: the fish and
    /// goal bins of the last `previous_block_actions` actions.
    pub fn history_len(&self) -> usize {
        2 * self.sectors as usize * self.previous_block_actions as usize
    }

    /// Length of the observation vector: 5 blocks of `sectors`, one more with
    /// `centroid_bins` and one more with `heading_bins`.
    pub fn size(&self) -> usize {
        (5 + usize::from(self.centroid_bins) + usize::from(self.heading_bins))
            * self.sectors as usize
    }
}

/// What the robot observes: the tank, itself, the fish and the active goal.
#[derive(Debug, Clone, Copy)]
pub struct Scene<'a> {
    /// Tank geometry.
    pub tank: &'a Tank,
    /// The robot.
    pub robot: &'a AgentState,
    /// The fish.
    pub fish: &'a [AgentState],
    /// Centre of the active goal (cm).
    pub goal: [f32; 2],
}

/// Encodes observations; holds precomputed ray directions.
#[derive(Debug, Clone)]
pub struct ObservationEncoder {
    n: usize,
    width: f32,
    far: f32,
    /// (cos, sin) of each ray's offset from the heading.
    rays: Vec<[f32; 2]>,
    /// Whether a sixth block holds the fish's centroid.
    centroid: bool,
    /// Whether a further block holds the fish's headings.
    heading: bool,
    /// Length of the history `encode` keeps (fish and goal bins of the last actions).
    history: usize,
}

impl ObservationEncoder {
    /// From validated parameters.
    pub fn new(p: &ObservationParams) -> Self {
        let n = p.sectors as usize;
        let width = TAU / n as f32;
        let rays = (0..n)
            .map(|i| {
                let a = -PI + (i as f32 + 0.5) * width;
                [a.cos(), a.sin()]
            })
            .collect();
        Self {
            n,
            width,
            far: p.far_plane_cm,
            rays,
            centroid: p.centroid_bins,
            heading: p.heading_bins,
            history: p.history_len(),
        }
    }

    /// Length of the history buffer `encode` takes (zeros to start with).
    pub fn history_len(&self) -> usize {
        self.history
    }

    /// Observation length.
    pub fn size(&self) -> usize {
        (5 + usize::from(self.centroid) + usize::from(self.heading)) * self.n
    }

    /// Sectors per block.
    pub fn sectors(&self) -> usize {
        self.n
    }

    /// Sector of a direction given relative to the heading (rad).
    #[inline]
    pub fn sector_of(&self, relative: f32) -> usize {
        let i = ((wrap_angle(relative) + PI) / self.width) as usize;
        i.min(self.n - 1)
    }

    #[inline]
    fn intensity(&self, d: f32) -> f32 {
        (1.0 - d / self.far).clamp(0.0, 1.0)
    }

    /// Writes the observation into `out` (length `size()`). `prev` (length `history_len()`)
    /// holds the fish and goal bins of the last `previous_block_actions` actions, oldest
    /// first; the oldest go into the fourth and fifth blocks and the current ones join the
    /// history. With `first` the history is filled with the current bins (no motion seen at an
    /// episode start).
    pub fn encode(&self, scene: Scene<'_>, prev: &mut [f32], first: bool, out: &mut [f32]) {
        let Scene {
            tank,
            robot,
            fish,
            goal,
        } = scene;
        let n = self.n;
        debug_assert_eq!(out.len(), self.size());
        let (out, extra) = out.split_at_mut(5 * n);
        let (centroid_block, heading_block) = extra.split_at_mut(n * usize::from(self.centroid));
        debug_assert_eq!(prev.len(), self.history);
        let (sin_h, cos_h) = robot.heading.sin_cos();
        let (walls, rest) = out.split_at_mut(n);
        for (w, r) in walls.iter_mut().zip(&self.rays) {
            let c = cos_h * r[0] - sin_h * r[1];
            let s = sin_h * r[0] + cos_h * r[1];
            *w = self.intensity(tank.raycast(robot.x, robot.y, c, s));
        }
        let (current, previous) = rest.split_at_mut(2 * n);
        current.fill(0.0);
        for f in fish {
            self.mark(robot, f.x, f.y, sin_h, cos_h, &mut current[..n]);
        }
        self.mark(robot, goal[0], goal[1], sin_h, cos_h, &mut current[n..]);
        if first {
            for slot in prev.chunks_exact_mut(2 * n) {
                slot.copy_from_slice(current);
            }
        }
        previous.copy_from_slice(&prev[..2 * n]);
        prev.copy_within(2 * n.., 0);
        let newest = prev.len() - 2 * n;
        prev[newest..].copy_from_slice(current);
        if self.centroid {
            centroid_block.fill(0.0);
            if !fish.is_empty() {
                let k = fish.len() as f32;
                let (sx, sy) = fish.iter().fold((0.0, 0.0), |(x, y), f| (x + f.x, y + f.y));
                self.mark(robot, sx / k, sy / k, sin_h, cos_h, centroid_block);
            }
        }
        if self.heading {
            heading_block.fill(0.0);
            for f in fish {
                let i = self.sector_of(f.heading - robot.heading);
                let v = self.intensity((f.x - robot.x).hypot(f.y - robot.y));
                if v > heading_block[i] {
                    heading_block[i] = v;
                }
            }
        }
    }

    #[inline]
    fn mark(&self, robot: &AgentState, x: f32, y: f32, sin_h: f32, cos_h: f32, bins: &mut [f32]) {
        let (dx, dy) = (x - robot.x, y - robot.y);
        // Into the robot's frame: one atan2 instead of atan2 minus heading.
        let fx = cos_h * dx + sin_h * dy;
        let fy = -sin_h * dx + cos_h * dy;
        let i = self.sector_of(fy.atan2(fx));
        let v = self.intensity((dx * dx + dy * dy).sqrt());
        if v > bins[i] {
            bins[i] = v;
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn hand_computed_observation() {
        let enc = ObservationEncoder::new(&ObservationParams::default());
        let tank = Tank::default();
        // Robot at the centre facing +x; fish 10 cm straight ahead; goal just past 90° left.
        let robot = AgentState::at(0.0, 0.0, 0.0);
        let fish = [AgentState::at(10.0, 0.0, 0.0)];
        let goal = [-2.0, 20.0];
        let mut prev = vec![0.0; 72];
        let mut out = vec![0.0; 180];
        let scene = |robot| Scene {
            tank: &tank,
            robot,
            fish: &fish,
            goal,
        };
        enc.encode(scene(&robot), &mut prev, true, &mut out);
        let d = 141.421_36f32;
        // Straight ahead is relative angle 0 → sector 18 ([0°, 10°)).
        assert!((out[36 + 18] - (1.0 - 10.0 / d)).abs() < 1e-6);
        assert_eq!(out[36..72].iter().filter(|v| **v > 0.0).count(), 1);
        // Goal at +95.7° → sector 27 ([90°, 100°)).
        assert!((out[72 + 27] - (1.0 - 404f32.sqrt() / d)).abs() < 1e-6);
        // Previous bins equal current at an episode start.
        assert_eq!(&out[108..180], &out[36..108]);
        // Ray 18 points at +5°: distance to the right wall 50 / cos 5°.
        let ray = 50.0 / 5f32.to_radians().cos();
        assert!((out[18] - (1.0 - ray / d)).abs() < 1e-5);
        // Rays at ±45° ± 5° etc. all within [0, 1].
        assert!(out.iter().all(|v| (0.0..=1.0).contains(v)));

        // Turn the robot by 90° left: the fish is now at -90° → sector 9.
        let robot = AgentState::at(0.0, 0.0, PI / 2.0);
        let before: Vec<f32> = out[36..108].to_vec();
        enc.encode(scene(&robot), &mut prev, false, &mut out);
        assert!(out[36 + 9] > 0.0);
        assert_eq!(&out[108..180], &before[..]);
    }

    #[test]
    fn the_previous_blocks_look_back_as_many_actions_as_set() {
        let tank = Tank::default();
        let robot = AgentState::at(0.0, 0.0, 0.0);
        let p = ObservationParams {
            previous_block_actions: 3,
            ..ObservationParams::default()
        };
        p.validate("observation").unwrap();
        let enc = ObservationEncoder::new(&p);
        assert_eq!((enc.size(), enc.history_len()), (180, 3 * 72));
        let mut prev = vec![0.0; enc.history_len()];
        let mut out = vec![0.0; 180];
        // The fish swims round the robot at 20 cm, 30° further each action.
        let mut current = Vec::new();
        for k in 0..6_usize {
            let a = (k as f32 * 30.0).to_radians();
            let fish = [AgentState::at(20.0 * a.cos(), 20.0 * a.sin(), 0.0)];
            let scene = Scene {
                tank: &tank,
                robot: &robot,
                fish: &fish,
                goal: [0.0, 30.0],
            };
            enc.encode(scene, &mut prev, k == 0, &mut out);
            current.push(out[36..108].to_vec());
            // The first three actions see the start (no motion seen at an episode start), then
            // the bins of three actions before.
            assert_eq!(
                out[108..180],
                current[k.saturating_sub(3)][..],
                "action {k}"
            );
        }
        // A new episode forgets the old one.
        let fish = [AgentState::at(0.0, -20.0, 0.0)];
        let scene = Scene {
            tank: &tank,
            robot: &robot,
            fish: &fish,
            goal: [0.0, 30.0],
        };
        enc.encode(scene, &mut prev, true, &mut out);
        assert_eq!(out[108..180], out[36..108]);
        for bad in [0, MAX_PREVIOUS_BLOCK_ACTIONS + 1] {
            let e = ObservationParams {
                previous_block_actions: bad,
                ..ObservationParams::default()
            }
            .validate("observation")
            .unwrap_err()
            .to_string();
            assert!(e.contains("observation.previous_block_actions"), "{e}");
        }
    }

    #[test]
    fn the_centroid_block_marks_the_groups_centre_and_is_off_by_default() {
        let tank = Tank::default();
        let robot = AgentState::at(0.0, 0.0, 0.0);
        let goal = [0.0, 30.0];
        // Two fish 10 cm ahead-left and ahead-right: the nearest per sector in the fish bins,
        // their centroid straight ahead at 10 cm in the sixth block.
        let fish = [
            AgentState::at(10.0, 10.0, 0.0),
            AgentState::at(10.0, -10.0, 0.0),
        ];
        let p = ObservationParams {
            centroid_bins: true,
            ..ObservationParams::default()
        };
        assert_eq!((ObservationParams::default().size(), p.size()), (180, 216));
        let enc = ObservationEncoder::new(&p);
        let mut prev = vec![0.0; 72];
        let mut out = vec![0.0; 216];
        let scene = Scene {
            tank: &tank,
            robot: &robot,
            fish: &fish,
            goal,
        };
        enc.encode(scene, &mut prev, true, &mut out);
        let centroid = &out[180..];
        assert_eq!(centroid.iter().filter(|&&v| v > 0.0).count(), 1);
        assert!(
            (centroid[18] - (1.0 - 10.0 / 141.421_36)).abs() < 1e-5,
            "{centroid:?}"
        );
        // The first 180 values are the paper's observation, unchanged by the extension.
        let plain = ObservationEncoder::new(&ObservationParams::default());
        let mut prev2 = vec![0.0; 72];
        let mut out2 = vec![0.0; 180];
        plain.encode(scene, &mut prev2, true, &mut out2);
        assert_eq!(&out[..180], &out2[..]);
    }

    #[test]
    fn the_heading_block_marks_where_each_fish_points_and_follows_the_centroid() {
        let tank = Tank::default();
        // The robot faces +y; a fish 10 cm to its right heads 5° left of the robot's heading
        // (sector 18, [0°, 10°)), one 30 cm ahead 95° left (sector 27), and one farther away
        // heads as the first: the nearer fish's intensity wins.
        let robot = AgentState::at(0.0, 0.0, PI / 2.0);
        let deg = |d: f32| d.to_radians();
        let fish = [
            AgentState::at(10.0, 0.0, deg(95.0)),
            AgentState::at(0.0, 30.0, deg(185.0)),
            AgentState::at(-40.0, 0.0, deg(95.0)),
        ];
        let scene = Scene {
            tank: &tank,
            robot: &robot,
            fish: &fish,
            goal: [0.0, -30.0],
        };
        let d = 141.421_36f32;
        for centroid_bins in [false, true] {
            let p = ObservationParams {
                centroid_bins,
                heading_bins: true,
                ..ObservationParams::default()
            };
            let size = if centroid_bins { 252 } else { 216 };
            assert_eq!(p.size(), size);
            let enc = ObservationEncoder::new(&p);
            assert_eq!(enc.size(), size);
            let mut prev = vec![0.0; 72];
            let mut out = vec![0.0; size];
            enc.encode(scene, &mut prev, true, &mut out);
            let heading = &out[size - 36..];
            assert_eq!(heading.iter().filter(|&&v| v > 0.0).count(), 2);
            assert!((heading[18] - (1.0 - 10.0 / d)).abs() < 1e-6, "{heading:?}");
            assert!((heading[27] - (1.0 - 30.0 / d)).abs() < 1e-6, "{heading:?}");
            // The paper's 180 values and the centroid block are unchanged by the extension.
            let q = ObservationParams {
                heading_bins: false,
                ..p
            };
            let mut prev2 = vec![0.0; 72];
            let mut out2 = vec![0.0; q.size()];
            ObservationEncoder::new(&q).encode(scene, &mut prev2, true, &mut out2);
            assert_eq!(&out[..size - 36], &out2[..]);
        }
    }

    #[test]
    fn sectors_cover_the_circle() {
        let enc = ObservationEncoder::new(&ObservationParams::default());
        assert_eq!(enc.sector_of(-PI), 0);
        assert_eq!(enc.sector_of(PI - 1e-4), 35);
        assert_eq!(enc.sector_of(0.0), 18);
        assert_eq!(enc.sector_of(-1e-4), 17);
    }
}
