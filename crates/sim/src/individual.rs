//! Who a fish is: the traits an individual draws at the start of an episode from a
//! population, which a model reads to behave as that individual.
//!
//! Live fish differ from one another far more than any model's fish; a model of a population
//! of individuals draws, per fish and episode, an [`Individual`] (its parameters are spread
//! over a fitted joint distribution) and the environment keeps it in the fish's [`FishMind`]
//! and shows it in its [`FishView`]. The traits are multipliers on groups of a model's
//! parameters, so that one population machinery fits every rule-based model, plus a pause
//! state any model can be given, and a latent vector for models that take an individual's
//! embedding (M_ConvNet with individuals, an ONNX model of that contract). The neutral
//! individual ([`Individual::NEUTRAL`], the default) changes nothing: a model without a
//! population behaves exactly as before, bit for bit.
//!
//! [`FishMind`]: crate::FishMind
//! [`FishView`]: crate::FishView

/// Length of an individual's latent vector ([`Individual::latent`]).
pub const LATENT_DIM: usize = 4;

/// An individual fish's traits.
#[derive(Debug, Clone, Copy, PartialEq, serde::Serialize, serde::Deserialize)]
pub struct Individual {
    /// Multiplier on the model's swimming speed (M_Zone's speed, M_Force's preferred speed,
    /// M_Follow's speed, the virtual guppy's kick speed; any other model's output speed).
    pub speed: f32,
    /// Multiplier on the model's social terms (M_Zone's orientation and attraction zones,
    /// M_Force's distance regulation and alignment, the virtual guppy's attraction and
    /// alignment).
    pub social: f32,
    /// Multiplier on the model's noise (turn and speed noise).
    pub noise: f32,
    /// Multiplier on the range of the model's wall terms (how far from a wall it reacts).
    pub wall: f32,
    /// Pauses begin at this rate while swimming (per second; 0: the population adds no
    /// pauses). A paused fish keeps its heading and does not move.
    pub pause_rate_hz: f32,
    /// Mean duration of those pauses (s; exponential).
    pub pause_mean_s: f32,
    /// The individual's embedding, for models that take one (zeros: the population's
    /// centre for M_ConvNet with individuals).
    pub latent: [f32; LATENT_DIM],
}

impl Individual {
    /// The individual that changes nothing: multipliers 1, no pauses, a zero latent.
    pub const NEUTRAL: Self = Self {
        speed: 1.0,
        social: 1.0,
        noise: 1.0,
        wall: 1.0,
        pause_rate_hz: 0.0,
        pause_mean_s: 0.0,
        latent: [0.0; LATENT_DIM],
    };

    /// Whether this is the neutral individual.
    pub fn is_neutral(&self) -> bool {
        *self == Self::NEUTRAL
    }
}

impl Default for Individual {
    fn default() -> Self {
        Self::NEUTRAL
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn the_default_individual_is_neutral() {
        assert!(Individual::default().is_neutral());
        let i = Individual {
            speed: 1.2,
            ..Individual::NEUTRAL
        };
        assert!(!i.is_neutral());
        let back: Individual = serde_json::from_str(&serde_json::to_string(&i).unwrap()).unwrap();
        assert_eq!(back, i);
    }
}
