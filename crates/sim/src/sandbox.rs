//! A tank with model fish and scripted agents but no task: for model tests, calibration and
//! simulating pairs of model fish.

use crate::agent::AgentState;
use crate::error::SimError;
use crate::fish::{FishMind, FishModel, FishView};
use crate::geometry::Tank;
use crate::rng::{stream, SimRng};
use std::sync::Arc;

/// Model fish in a tank, stepped frame by frame; scripted agents (moved by the caller) are
/// seen by every fish before the other fish.
#[derive(Debug, Clone)]
pub struct Sandbox {
    tank: Tank,
    dt: f32,
    model: Arc<dyn FishModel>,
    fish: Vec<AgentState>,
    minds: Vec<FishMind>,
    rngs: Vec<SimRng>,
    scripted: Vec<AgentState>,
    views: Vec<FishView>,
    inferred: Vec<f32>,
    frame: u32,
    wall_contacts: u32,
}

impl Sandbox {
    /// Fish at the given poses (x, y, heading); randomness from `seed`.
    pub fn new(
        tank: Tank,
        frame_rate_hz: f32,
        model: Arc<dyn FishModel>,
        poses: &[[f32; 3]],
        seed: u64,
    ) -> Self {
        let fish: Vec<AgentState> = poses
            .iter()
            .map(|p| AgentState::at(p[0], p[1], p[2]))
            .collect();
        let mut rngs: Vec<SimRng> = (0..fish.len() as u64)
            .map(|i| stream(seed, "fish", i))
            .collect();
        let mut minds = vec![FishMind::default(); fish.len()];
        for ((f, m), r) in fish.iter().zip(&mut minds).zip(&mut rngs) {
            model.begin_episode(f, m, r);
        }
        let width = model.inference_width();
        Self {
            tank,
            dt: 1.0 / frame_rate_hz,
            views: vec![FishView::default(); fish.len()],
            inferred: vec![0.0; width * fish.len()],
            model,
            fish,
            minds,
            rngs,
            scripted: Vec::new(),
            frame: 0,
            wall_contacts: 0,
        }
    }

    /// Sets the scripted agents for the next frames.
    pub fn set_scripted(&mut self, agents: &[AgentState]) {
        self.scripted.clear();
        self.scripted.extend_from_slice(agents);
    }

    /// The fish.
    pub fn fish(&self) -> &[AgentState] {
        &self.fish
    }
    /// The fish's memories.
    pub fn minds(&self) -> &[FishMind] {
        &self.minds
    }
    /// Frames stepped.
    pub fn frame(&self) -> u32 {
        self.frame
    }
    /// Frames with a fish clipped at a wall (summed over fish).
    pub fn wall_contacts(&self) -> u32 {
        self.wall_contacts
    }

    /// Advances every fish by one frame.
    pub fn step(&mut self) -> Result<(), SimError> {
        let time_s = self.frame as f32 * self.dt;
        for i in 0..self.fish.len() {
            self.views[i].rebuild(i, &self.fish, &self.scripted, self.tank, self.dt, time_s);
            self.views[i].individual = self.minds[i].individual;
        }
        let width = self.model.inference_width();
        if width > 0 {
            self.model.infer_batch(&self.views, &mut self.inferred);
        }
        self.wall_contacts += crate::fish::step_fish(
            self.model.as_ref(),
            &self.views,
            &self.inferred,
            &mut self.minds,
            &mut self.rngs,
            &mut self.fish,
            &self.tank,
            self.dt,
            self.frame,
        )?;
        self.frame += 1;
        Ok(())
    }
}
