//! Fish behaviour models for fishprobe (SPEC §6): M_Follow, M_Zone (Couzin et al. 2002 with
//! noise and a wall module), M_Force (Klamser et al. 2021 with noise and a wall module), and a
//! stationary fish for the approach assay. Each is a [`FishModel`] built from a [`ModelSpec`],
//! the serialisable choice of model plus its documented parameters.
//!
//! ```
//! use fishprobe_models::ModelSpec;
//! use fishprobe_sim::{Env, EnvConfig, TankEnv};
//!
//! let spec = ModelSpec::by_name("zone")?;           // the published parameters
//! let mut env = TankEnv::new(EnvConfig::default(), spec.build()?)?;
//! let mut obs = vec![0.0; 180];
//! env.reset(Some(1), &mut obs)?;
//! let t = env.step(&[0.0], &mut obs)?;
//! assert!(t.reward.is_finite());
//! # Ok::<(), Box<dyn std::error::Error>>(())
//! ```

pub mod convnet;
pub mod follow;
pub mod force;
pub mod guppy;
pub mod measure;
pub mod stationary;
pub mod zone;

pub use convnet::{ConvNet, ConvNetArch, ConvNetFish, ConvNetParams, WeightsError};
pub use follow::{Follow, FollowParams};
pub use force::{Force, ForceParams, NoiseConvention};
pub use guppy::{Guppy, GuppyParams};
pub use stationary::{Stationary, StationaryParams};
pub use zone::{Zone, ZoneConvention, ZoneParams};

use fishprobe_sim::params::{ConfigError, DocumentedParams, FieldDoc};
use fishprobe_sim::FishModel;
use serde::{Deserialize, Serialize};
use std::sync::Arc;

/// Errors of the model registry.
#[derive(Debug, Clone, PartialEq, thiserror::Error)]
pub enum ModelError {
    /// No model of that name.
    #[error("unknown fish model `{name}`; known models: {known}")]
    Unknown {
        /// The name asked for.
        name: String,
        /// The names there are.
        known: String,
    },
    /// Parameters out of range.
    #[error(transparent)]
    Config(#[from] ConfigError),
    /// A simulation error while measuring.
    #[error(transparent)]
    Sim(#[from] fishprobe_sim::SimError),
    /// ConvNet weights that cannot be used.
    #[error(transparent)]
    Weights(#[from] WeightsError),
}

/// A fish model and its parameters, as written in config files: `{"model": "Zone", ...}`.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
#[serde(tag = "model")]
pub enum ModelSpec {
    /// M_Follow.
    Follow(FollowParams),
    /// M_Zone.
    Zone(ZoneParams),
    /// M_Force.
    Force(ForceParams),
    /// A fish that never moves (approach assay).
    Stationary(StationaryParams),
    /// M_ConvNet: behavioural cloning of live guppy pairs.
    ConvNet(ConvNetParams),
    /// The virtual guppy of the virtual lab (not a candidate model).
    Guppy(GuppyParams),
}

impl ModelSpec {
    /// Names of every model, in the paper's order (candidate models first).
    pub const NAMES: [&'static str; 6] =
        ["Follow", "Zone", "Force", "Stationary", "ConvNet", "Guppy"];

    /// The rule-based candidate models of the paper.
    pub const RULE_BASED: [&'static str; 3] = ["Follow", "Zone", "Force"];

    /// A model with its default (published) parameters, by name (case-insensitive).
    pub fn by_name(name: &str) -> Result<Self, ModelError> {
        match name.to_ascii_lowercase().as_str() {
            "follow" => Ok(Self::Follow(FollowParams::default())),
            "zone" => Ok(Self::Zone(ZoneParams::default())),
            "force" => Ok(Self::Force(ForceParams::default())),
            "stationary" => Ok(Self::Stationary(StationaryParams::default())),
            "convnet" => Ok(Self::ConvNet(ConvNetParams::default())),
            "guppy" | "virtualguppy" => Ok(Self::Guppy(GuppyParams::default())),
            _ => Err(ModelError::Unknown {
                name: name.to_string(),
                known: Self::NAMES.join(", "),
            }),
        }
    }

    /// The model's name.
    pub fn name(&self) -> &'static str {
        match self {
            Self::Follow(_) => "Follow",
            Self::Zone(_) => "Zone",
            Self::Force(_) => "Force",
            Self::Stationary(_) => "Stationary",
            Self::ConvNet(_) => "ConvNet",
            Self::Guppy(_) => "Guppy",
        }
    }

    /// One line on what the model is.
    pub fn summary(&self) -> &'static str {
        match self {
            Self::Follow(_) => {
                "baseline: constant speed straight at the closest other agent, no overshoot"
            }
            Self::Zone(_) => "Couzin et al. 2002 zonal model with turn noise and a wall module",
            Self::Force(_) => {
                "Klamser et al. 2021 variable-speed force model with noise and a wall module"
            }
            Self::Stationary(_) => "never moves (approach assay)",
            Self::ConvNet(_) => {
                "behavioural cloning of live guppy pairs: (speed, turn) sampled from a ConvNet"
            }
            Self::Guppy(_) => {
                "the virtual lab's guppy: burst and glide, pauses, thigmotaxis, individual sociability"
            }
        }
    }

    /// The documented fields of this model's parameters.
    pub fn field_docs(&self) -> &'static [FieldDoc] {
        match self {
            Self::Follow(_) => FollowParams::field_docs(),
            Self::Zone(_) => ZoneParams::field_docs(),
            Self::Force(_) => ForceParams::field_docs(),
            Self::Stationary(_) => StationaryParams::field_docs(),
            Self::ConvNet(_) => ConvNetParams::field_docs(),
            Self::Guppy(_) => GuppyParams::field_docs(),
        }
    }

    /// Checks the parameters; errors name the field.
    pub fn validate(&self) -> Result<(), ConfigError> {
        let prefix = self.name();
        match self {
            Self::Follow(p) => p.validate(prefix),
            Self::Zone(p) => p.validate(prefix),
            Self::Force(p) => p.validate(prefix),
            Self::Stationary(p) => p.validate(prefix),
            Self::ConvNet(_) => Ok(()),
            Self::Guppy(p) => p.validate(prefix),
        }
    }

    /// The model, ready to drive fish.
    pub fn build(&self) -> Result<Arc<dyn FishModel>, ModelError> {
        self.validate()?;
        Ok(match self {
            Self::Follow(p) => Arc::new(Follow::new(p.clone())?),
            Self::Zone(p) => Arc::new(Zone::new(p.clone())?),
            Self::Force(p) => Arc::new(Force::new(p.clone())?),
            Self::Stationary(_) => Arc::new(Stationary),
            Self::ConvNet(p) => Arc::new(ConvNetFish::new(p)?),
            Self::Guppy(p) => Arc::new(Guppy::new(p.clone())?),
        })
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn names_round_trip_and_unknown_is_clear() {
        for n in ModelSpec::NAMES {
            let s = ModelSpec::by_name(n).unwrap();
            assert_eq!(s.name(), n);
            assert_eq!(s.build().unwrap().name(), n);
            let json = serde_json::to_string(&s).unwrap();
            let back: ModelSpec = serde_json::from_str(&json).unwrap();
            assert_eq!(back, s);
        }
        let e = ModelSpec::by_name("Couzin").unwrap_err().to_string();
        assert!(e.contains("Couzin") && e.contains("Zone"), "{e}");
    }

    #[test]
    fn bad_parameters_name_field_and_value() {
        let bad = ModelSpec::Zone(ZoneParams {
            repulsion_zone_cm: -1.0,
            ..ZoneParams::default()
        });
        let e = bad.build().unwrap_err().to_string();
        assert!(
            e.contains("Zone.repulsion_zone_cm") && e.contains("-1"),
            "{e}"
        );
        let nan = ModelSpec::Force(ForceParams {
            preferred_speed: f32::NAN,
            ..ForceParams::default()
        });
        assert!(nan
            .build()
            .unwrap_err()
            .to_string()
            .contains("Force.preferred_speed"));
        let unknown = serde_json::from_str::<ModelSpec>(r#"{"model": "Zone", "speeed_cm_s": 3}"#);
        assert!(unknown.unwrap_err().to_string().contains("speeed_cm_s"));
        let partial: ModelSpec =
            serde_json::from_str(r#"{"model": "Zone", "speed_cm_s": 3}"#).unwrap();
        match partial {
            ModelSpec::Zone(p) => assert_eq!((p.speed_cm_s, p.turn_noise_rad), (3.0, 0.2)),
            other => panic!("{other:?}"),
        }
    }
}
