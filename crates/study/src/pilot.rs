//! A trained policy (or the scripted goal-seeker) as the live bridge's pilot.

use fishprobe_learn::{to_env_action, Controller};
use fishprobe_live::session::Pilot;
use fishprobe_nn::MlpWorkspace;

/// The bridge's pilot for a [`Controller`].
#[derive(Debug)]
pub struct PolicyPilot {
    c: Controller,
    name: String,
    ws: MlpWorkspace,
}

impl PolicyPilot {
    /// A pilot named `name` (the policy's directory name in the study layout).
    pub fn new(c: Controller, name: String) -> Self {
        Self {
            c,
            name,
            ws: MlpWorkspace::default(),
        }
    }
}

impl Pilot for PolicyPilot {
    fn name(&self) -> String {
        self.name.clone()
    }

    fn turn(&mut self, obs: &[f32]) -> f32 {
        match &self.c {
            Controller::Policy { policy, .. } => {
                to_env_action(policy.pi.forward(obs, 1, &mut self.ws)[0])
            }
            Controller::GoalSeeker => {
                // The active goal lights one sector of the third block of 36.
                let goal = &obs[72..108];
                let (i, _) =
                    goal.iter()
                        .enumerate()
                        .fold((0, -1.0f32), |b, (i, &v)| if v > b.1 { (i, v) } else { b });
                -std::f32::consts::PI + (i as f32 + 0.5) * std::f32::consts::TAU / 36.0
            }
        }
    }
}
