//! The kinematic state every agent (robot or fish) shares.

/// Position, heading and motion of one agent. Plain data: the simulation state is a set of
/// these plus the controllers' and models' memories.
#[derive(Debug, Clone, Copy, PartialEq, Default, serde::Serialize, serde::Deserialize)]
pub struct AgentState {
    /// Position x (cm).
    pub x: f32,
    /// Position y (cm).
    pub y: f32,
    /// Heading (rad, counter-clockwise from +x, in [-π, π)).
    pub heading: f32,
    /// Velocity over the last frame, x component (cm/s).
    pub vx: f32,
    /// Velocity over the last frame, y component (cm/s).
    pub vy: f32,
}

impl AgentState {
    /// An agent at rest.
    pub fn at(x: f32, y: f32, heading: f32) -> Self {
        Self {
            x,
            y,
            heading,
            vx: 0.0,
            vy: 0.0,
        }
    }

    /// Speed over the last frame (cm/s).
    #[inline]
    pub fn speed(&self) -> f32 {
        (self.vx * self.vx + self.vy * self.vy).sqrt()
    }

    /// Distance to another agent (cm).
    #[inline]
    pub fn distance_to(&self, other: &AgentState) -> f32 {
        ((other.x - self.x).powi(2) + (other.y - self.y).powi(2)).sqrt()
    }
}
