//! The [`FishModel`] trait: what a fish perceives and how a model turns that into motion.
//!
//! A model is stateless and shared (`Arc<dyn FishModel>`) by every environment; what a fish
//! remembers between frames (its speed, last turn rate, individual traits drawn per episode)
//! lives in a [`FishMind`] owned by the environment, and its randomness comes from the fish's
//! own RNG stream. Models that profit from batched inference (a neural network) declare an
//! `inference_width`: the vector environment then gathers the views of all its environments
//! each frame, calls [`FishModel::infer_batch`] once, and hands each fish its slice.

use crate::agent::AgentState;
use crate::geometry::Tank;
use crate::rng::SimRng;

/// The largest number of fish in one tank (`EnvConfig::fish_count`; groups of
/// at least 8 must fit). A fish's view is a fixed array (no allocation per frame, and views are copied
/// into batches for batched inference), so this bounds its size.
pub const MAX_FISH: usize = 16;

/// The largest number of other agents one fish perceives: the robot and the other
/// [`MAX_FISH`]` - 1` fish. Beyond it (only in a [`crate::Sandbox`] with scripted agents) a fish
/// perceives the leading agents and then the nearest fish.
pub const MAX_OTHERS: usize = MAX_FISH;

/// Everything a fish perceives at the start of a frame.
#[derive(Debug, Clone, Copy, PartialEq, Default)]
pub struct FishView {
    /// The fish itself.
    pub me: AgentState,
    /// The other agents (robot first, then the other fish); only `n_others` are valid.
    pub others: [AgentState; MAX_OTHERS],
    /// How many entries of `others` are valid.
    pub n_others: u8,
    /// The tank's geometry.
    pub tank: Tank,
    /// Frame duration (s).
    pub dt: f32,
    /// Time since the episode started (s).
    pub time_s: f32,
    /// The fish's individual (a copy of its mind's, set by the environment each frame), for
    /// models whose batched inference takes it (an individual's latent vector).
    pub individual: crate::Individual,
}

impl FishView {
    /// The valid other agents.
    #[inline]
    pub fn others(&self) -> &[AgentState] {
        &self.others[..usize::from(self.n_others)]
    }

    /// The view of fish `i` of `fish`, seeing first the `leading` agents (the robot, or
    /// scripted agents), then the other fish, up to [`MAX_OTHERS`] agents in all; when there
    /// are more (only possible in a [`crate::Sandbox`] with scripted agents), the nearest fish.
    #[inline]
    pub fn build(
        i: usize,
        fish: &[AgentState],
        leading: &[AgentState],
        tank: Tank,
        dt: f32,
        time_s: f32,
    ) -> Self {
        let mut v = FishView::default();
        v.rebuild(i, fish, leading, tank, dt, time_s);
        v
    }

    /// [`FishView::build`] in place: the same valid entries, written into an existing view
    /// (entries of `others` past `n_others` keep whatever they held). The environment's
    /// views are rebuilt every frame; building a fresh view and moving it in cost a sixth of
    /// a frame's time in copies.
    #[inline]
    pub fn rebuild(
        &mut self,
        i: usize,
        fish: &[AgentState],
        leading: &[AgentState],
        tank: Tank,
        dt: f32,
        time_s: f32,
    ) {
        let me = fish[i];
        let v = self;
        v.me = me;
        v.tank = tank;
        v.dt = dt;
        v.time_s = time_s;
        let lead = leading.len().min(MAX_OTHERS);
        v.others[..lead].copy_from_slice(&leading[..lead]);
        let room = MAX_OTHERS - lead;
        let mut n = lead;
        if fish.len() - 1 <= room {
            for (j, f) in fish.iter().enumerate() {
                if j != i {
                    v.others[n] = *f;
                    n += 1;
                }
            }
        } else {
            // Keep the `room` nearest fish, sorted by distance (insertion into the tail).
            let mut dist = [f32::INFINITY; MAX_OTHERS];
            for (j, f) in fish.iter().enumerate() {
                if j == i {
                    continue;
                }
                let d = me.distance_to(f);
                let mut k = n.min(lead + room);
                if k == lead + room {
                    if d >= dist[k - 1] {
                        continue;
                    }
                    k -= 1;
                } else {
                    n += 1;
                }
                while k > lead && dist[k - 1] > d {
                    dist[k] = dist[k - 1];
                    v.others[k] = v.others[k - 1];
                    k -= 1;
                }
                dist[k] = d;
                v.others[k] = *f;
            }
        }
        v.n_others = n as u8;
    }

    /// The closest other agent and its distance, if any.
    #[inline]
    pub fn closest_other(&self) -> Option<(&AgentState, f32)> {
        self.others()
            .iter()
            .map(|o| (o, self.me.distance_to(o)))
            .min_by(|a, b| a.1.total_cmp(&b.1))
    }
}

/// A fish's motion for one frame: it turns to `heading`, then moves `speed · dt` along it.
#[derive(Debug, Clone, Copy, PartialEq, Default)]
pub struct FishMotion {
    /// New heading (rad).
    pub heading: f32,
    /// Speed over this frame (cm/s, >= 0).
    pub speed: f32,
}

/// What a fish carries from frame to frame, owned by the environment and reset each episode.
#[derive(Debug, Clone, Copy, PartialEq, Default, serde::Serialize, serde::Deserialize)]
pub struct FishMind {
    /// The model's internal speed (cm/s): may differ from the realised one at walls.
    pub speed: f32,
    /// The model's last turn rate (rad/s).
    pub turn_rate: f32,
    /// Individual traits drawn at the start of an episode (meaning defined by the model).
    pub traits: [f32; 4],
    /// Further per-fish memory (meaning defined by the model).
    pub memory: [f32; 4],
    /// Who this fish is: drawn from a population at the start of the episode, neutral for a
    /// model without one ([`crate::Individual`]). Models read it here; the environment also
    /// shows it in the fish's view each frame (for batched inference).
    #[serde(default)]
    pub individual: crate::Individual,
    /// Seconds left of a pause a population imposes (0: swimming).
    #[serde(default)]
    pub pause_left_s: f32,
}

/// A behaviour model of a fish. Implementations live in the `fishprobe-models` crate; a new
/// model needs nothing from the simulator but this trait.
pub trait FishModel: Send + Sync + std::fmt::Debug {
    /// Short name ("Zone", "Force", ...).
    fn name(&self) -> &str;

    /// Prepares a fish for a new episode (draw individual traits, reset memory).
    fn begin_episode(&self, me: &AgentState, mind: &mut FishMind, rng: &mut SimRng) {
        let _ = rng;
        *mind = FishMind::default();
        mind.speed = me.speed();
    }

    /// Whether the model reads its fish's [`crate::Individual`] (`mind.individual`): its speed,
    /// social, noise and wall multipliers. A population of a model that does not (an ONNX or
    /// Python fish) scales the model's output speed by the individual's instead.
    fn reads_individual(&self) -> bool {
        false
    }

    /// Floats of batched, deterministic inference per fish and frame (0: none).
    fn inference_width(&self) -> usize {
        0
    }

    /// Batched inference for `views.len()` fish into `out` (`inference_width` floats each).
    /// Must be a pure function of each fish's own view: a fish's output may not depend on the
    /// other fish in the batch, because the vector environment splits the batch across cores
    /// (calling this concurrently from several threads).
    fn infer_batch(&self, views: &[FishView], out: &mut [f32]) {
        let _ = (views, out);
    }

    /// Whether concurrent [`FishModel::infer_batch`] calls run in parallel. A model serialised
    /// by a global lock answers `false` (a fish written in Python, behind the GIL): the vector
    /// environment then asks it once per frame for all its fish, on one thread, and evaluation
    /// runs its episodes one after another, because threads taking turns at a lock run slower
    /// than one thread alone (two threads ran a Python fish at about a third of one thread's
    /// speed: docs/validation.md, "Speed"). Results do not depend on it.
    fn concurrent_inference(&self) -> bool {
        true
    }

    /// The fish's motion for this frame. `inferred` is this fish's slice of `infer_batch`'s
    /// output (empty when `inference_width` is 0).
    fn decide(
        &self,
        view: &FishView,
        inferred: &[f32],
        mind: &mut FishMind,
        rng: &mut SimRng,
    ) -> FishMotion;
}

/// The fish's part of one frame, the one place it is written (the environment, the sandbox,
/// the virtual lab): each fish decides from its view (all built from the same snapshot
/// before this call) and its slice of the batched inference `inferred`, then moves. A motion
/// that is not finite is refused with [`crate::SimError::NonFiniteModelOutput`] (at `frame`)
/// before that fish moves. Returns the wall contacts.
#[allow(clippy::too_many_arguments)]
pub fn step_fish(
    model: &dyn FishModel,
    views: &[FishView],
    inferred: &[f32],
    minds: &mut [FishMind],
    rngs: &mut [SimRng],
    fish: &mut [AgentState],
    tank: &Tank,
    dt: f32,
    frame: u32,
) -> Result<u32, crate::SimError> {
    let width = model.inference_width();
    let mut contacts = 0;
    for (i, f) in fish.iter_mut().enumerate() {
        let m = model.decide(
            &views[i],
            &inferred[i * width..(i + 1) * width],
            &mut minds[i],
            &mut rngs[i],
        );
        if !(m.heading.is_finite() && m.speed.is_finite()) {
            return Err(crate::SimError::NonFiniteModelOutput {
                model: model.name().to_string(),
                frame,
            });
        }
        if apply_motion(tank, f, m, dt) {
            contacts += 1;
        }
    }
    Ok(contacts)
}

/// Moves an agent by a fish motion, keeping it inside the tank. Returns whether the move was
/// clipped (a wall contact).
#[inline]
pub fn apply_motion(tank: &Tank, s: &mut AgentState, m: FishMotion, dt: f32) -> bool {
    s.heading = crate::geometry::wrap_angle(m.heading);
    let step = m.speed.max(0.0) * dt;
    let (sin, cos) = s.heading.sin_cos();
    let (nx, ny, contact) = tank.clip(s.x + step * cos, s.y + step * sin);
    s.vx = (nx - s.x) / dt;
    s.vy = (ny - s.y) / dt;
    s.x = nx;
    s.y = ny;
    contact
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn a_view_rebuilt_in_place_holds_what_a_fresh_one_holds() {
        let tank = Tank::default();
        let robot = AgentState::at(-40.0, -40.0, 0.0);
        let fish: Vec<AgentState> = (0..20)
            .map(|i| AgentState::at(i as f32 * 2.0 - 20.0, (i % 3) as f32, 0.1 * i as f32))
            .collect();
        // A view that last held many agents, rebuilt for fewer and for more (the nearest).
        let mut v = FishView::build(0, &fish, &[robot], tank, 0.04, 1.0);
        for (i, n, lead) in [(1, 3, 1), (2, 20, 1), (0, 2, 0), (5, 17, 1)] {
            let leading = &[robot][..lead];
            v.rebuild(i, &fish[..n], leading, tank, 0.02, 2.0);
            let fresh = FishView::build(i, &fish[..n], leading, tank, 0.02, 2.0);
            assert_eq!(v.others(), fresh.others(), "fish {i} of {n}");
            assert_eq!(
                (v.me, v.tank, v.dt, v.time_s),
                (fresh.me, fresh.tank, 0.02, 2.0)
            );
        }
    }

    #[test]
    fn a_view_holds_the_leading_agents_then_the_other_fish_or_the_nearest_of_them() {
        let tank = Tank::default();
        let robot = AgentState::at(-40.0, -40.0, 0.0);
        let fish: Vec<AgentState> = (0..4)
            .map(|i| AgentState::at(i as f32 * 3.0, 0.0, 0.0))
            .collect();
        let v = FishView::build(1, &fish, &[robot], tank, 0.04, 0.0);
        assert_eq!(v.others(), &[robot, fish[0], fish[2], fish[3]]);
        assert_eq!(v.me, fish[1]);
        // More fish than a view holds: the leading agents, then the nearest fish by distance.
        let many: Vec<AgentState> = (0..40)
            .map(|i| AgentState::at(40.0 - 2.0 * i as f32, 1.0, 0.0))
            .collect();
        let me = 20; // at x = 0
        let v = FishView::build(me, &many, &[robot], tank, 0.04, 0.0);
        assert_eq!(usize::from(v.n_others), MAX_OTHERS);
        assert_eq!(v.others()[0], robot);
        let d: Vec<f32> = v.others()[1..]
            .iter()
            .map(|o| o.distance_to(&many[me]))
            .collect();
        assert!(d.windows(2).all(|w| w[0] <= w[1]), "{d:?}");
        // The 15 nearest of fish 2 cm apart on a line: up to 8 ahead or behind, 16 cm.
        assert!(d.iter().all(|&x| x <= 16.0 + 1e-4), "{d:?}");
        assert!(!v.others()[1..].contains(&many[me]));
    }
}
