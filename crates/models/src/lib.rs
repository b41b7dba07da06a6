//! Fish behaviour models for fishprobe (SPEC §6): M_Follow, M_Zone (Couzin et al. 2002 with
//! noise and a wall module), M_Force (Klamser et al. 2021 with noise and a wall module), and a
//! stationary fish for the approach assay. Each is a [`FishModel`] built from a [`ModelSpec`],
//! the serialisable choice of model plus its documented parameters.
//!
//! **Adding a model** is one file and one line: the file (`src/name.rs`) holds the model (a
//! [`FishModel`]), its `…Params` (declared with `fishprobe_sim::documented_params!`) and
//! `impl ModelParams for …Params` (name, one-line summary, checks, construction); the line
//! adds `name::Name(NameParams),` to the `model_registry!` list in this file, which declares
//! the module and generates [`ModelSpec`] and every lookup (`by_name`, `NAMES`, `summary`,
//! `field_docs`, `validate`, `build`). Everything else that lists models (`fishprobe models`,
//! the settings reference, the Python package) reads the registry.
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

#![warn(missing_docs)]

// The models' own modules are declared by their line in `model_registry!` below.
pub mod collective;
pub mod disagreement;
pub mod measure;
pub mod support;

pub use convnet::{ConvNet, ConvNetArch, ConvNetFish, WeightsError};
pub use fishprobe_onnx::sha256_hex;
pub use follow::Follow;
pub use force::{Force, NoiseConvention};
pub use guppy::Guppy;
pub use onnx::OnnxFish;
pub use population::Trait;
pub use stationary::Stationary;
pub use zone::{Zone, ZoneConvention};

use fishprobe_sim::params::{ConfigError, DocumentedParams, FieldDoc};
use fishprobe_sim::FishModel;
use serde::{Deserialize, Serialize};
use std::sync::Arc;

/// The SHA-256 of a weights file (`convnet:FILE`, a policy's `policy.safetensors`), read at
/// most [`fishprobe_nn::store::MAX_WEIGHTS_BYTES`]: a wrong path (`/dev/zero`) is refused,
/// never read into memory whole.
pub fn weights_sha256(path: &std::path::Path) -> std::io::Result<String> {
    fishprobe_nn::store::read_at_most(
        path,
        fishprobe_nn::store::MAX_WEIGHTS_BYTES,
        "fishprobe_nn::store::MAX_WEIGHTS_BYTES",
    )
    .map(|b| sha256_hex(&b))
}

/// A weights or model file that cannot be read (or hashed), as a [`ModelError`].
fn weights_error(path: &str, e: std::io::Error) -> ModelError {
    ModelError::Weights(WeightsError {
        source_name: path.to_string(),
        what: e.to_string(),
    })
}

/// The SHA-256 of an ONNX file, read as the ONNX loader reads it
/// ([`fishprobe_onnx::read_model_file`]: a regular file of at most
/// [`fishprobe_onnx::MAX_FILE_BYTES`]), so both refuse a file with the same words.
pub fn onnx_sha256(path: &std::path::Path) -> Result<String, fishprobe_onnx::OnnxError> {
    fishprobe_onnx::read_model_file(path).map(|b| sha256_hex(&b))
}

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
    /// An ONNX model that cannot be used (the engine's error, as text: it holds OS errors,
    /// which cannot be cloned).
    #[error("{0}")]
    Onnx(String),
    /// A fish model written in Python, asked for where there is no Python: only the Python
    /// package (which holds the model object) can run it.
    #[error(
        "the fish model `{class}` is written in Python: only the fishprobe Python package can run it \
         (pass the model object again, e.g. fishprobe.train(model=..., resume=True))"
    )]
    NeedsPython {
        /// The model's class.
        class: String,
    },
    /// A support model that cannot be used.
    #[error(transparent)]
    Support(#[from] support::SupportError),
    /// The OOD objective asked of a model without training data.
    #[error(
        "fish model `{model}` is not data-driven: the OOD objective needs a model fitted on \
         recordings (ConvNet, or an ONNX model of the view contract) and its support file"
    )]
    NotDataDriven {
        /// The model's name.
        model: String,
    },
}

impl From<fishprobe_onnx::OnnxError> for ModelError {
    fn from(e: fishprobe_onnx::OnnxError) -> Self {
        ModelError::Onnx(e.to_string())
    }
}

/// What a model's parameter struct says about its model: the one place a model is described.
/// A new model is its file (the model, its `…Params` and this impl) plus one line in
/// [`ModelSpec`]'s registry below.
pub trait ModelParams: DocumentedParams + Clone {
    /// Its name in config files (`{"model": NAME, ...}`) and on the command line; the
    /// registry's variant has the same name.
    const NAME: &'static str;
    /// Other names accepted by [`ModelSpec::by_name`] (lower case).
    const ALIASES: &'static [&'static str] = &[];
    /// One line on what the model is.
    const SUMMARY: &'static str;
    /// Checks the parameters; errors name `prefix.field` and the value.
    fn check(&self, prefix: &str) -> Result<(), ConfigError>;
    /// The model, ready to drive fish (parameters already checked).
    fn build_model(&self) -> Result<Arc<dyn FishModel>, ModelError>;
}

/// Declares [`ModelSpec`] from one line per model: `Variant(Params)`, with `Params:
/// ModelParams` and `Params::NAME` = the variant's name. Built-in models come first (they have
/// defaults and are listed in `NAMES`); models read from a file follow a `;`.
macro_rules! model_registry {
    (
        $( $(#[$doc:meta])* $module:ident :: $variant:ident($params:ident), )*
        ;
        $( $(#[$fdoc:meta])* $fmodule:ident :: $fvariant:ident($fparams:ident), )*
    ) => {
        $( pub mod $module; pub use $module::$params; )*
        $( pub mod $fmodule; pub use $fmodule::$fparams; )*

        /// A fish model and its parameters, as written in config files: `{"model": "Zone", ...}`.
        #[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
        #[serde(tag = "model")]
        pub enum ModelSpec {
            $( $(#[$doc])* $variant($params), )*
            $( $(#[$fdoc])* $fvariant($fparams), )*
        }

        impl ModelSpec {
            /// Names of every model, in the paper's order (candidate models first).
            pub const NAMES: &'static [&'static str] = &[$(<$params as ModelParams>::NAME),*];

            /// A model with its default (published) parameters, by name or alias
            /// (case-insensitive), `onnx:PATH` for a model brought as an ONNX file, or
            /// `convnet:PATH` for M_ConvNet with weights written by `fit-convnet`.
            pub fn by_name(name: &str) -> Result<Self, ModelError> {
                if let Some(path) = name.strip_prefix("onnx:") {
                    return Ok(Self::Onnx(OnnxParams::for_file(path)));
                }
                if let Some(path) = name.strip_prefix("population:") {
                    return population::read_file(std::path::Path::new(path)).map(Self::Population);
                }
                if let Some(p) = population::shipped(name) {
                    return p.map(Self::Population);
                }
                if let Some(path) = name.strip_prefix("convnet:") {
                    // M_ConvNet with weights from `fit-convnet` instead of the shipped ones.
                    return Ok(Self::ConvNet(ConvNetParams {
                        weights: path.to_string(),
                        ..ConvNetParams::default()
                    }));
                }
                let lower = name.to_ascii_lowercase();
                $(
                    if lower == <$params as ModelParams>::NAME.to_ascii_lowercase()
                        || <$params as ModelParams>::ALIASES.contains(&lower.as_str())
                    {
                        return Ok(Self::$variant(<$params>::default()));
                    }
                )*
                Err(ModelError::Unknown {
                    name: name.to_string(),
                    known: Self::NAMES.join(", "),
                })
            }

            /// The model's name.
            pub fn name(&self) -> &'static str {
                match self {
                    $( Self::$variant(_) => <$params as ModelParams>::NAME, )*
                    $( Self::$fvariant(_) => <$fparams as ModelParams>::NAME, )*
                }
            }

            /// One line on what the model is.
            pub fn summary(&self) -> &'static str {
                match self {
                    $( Self::$variant(_) => <$params as ModelParams>::SUMMARY, )*
                    $( Self::$fvariant(_) => <$fparams as ModelParams>::SUMMARY, )*
                }
            }

            /// The documented fields of this model's parameters.
            pub fn field_docs(&self) -> &'static [FieldDoc] {
                match self {
                    $( Self::$variant(_) => <$params as DocumentedParams>::field_docs(), )*
                    $( Self::$fvariant(_) => <$fparams as DocumentedParams>::field_docs(), )*
                }
            }

            /// Checks the parameters; errors name the field.
            pub fn validate(&self) -> Result<(), ConfigError> {
                let prefix = self.name();
                match self {
                    $( Self::$variant(p) => p.check(prefix), )*
                    $( Self::$fvariant(p) => p.check(prefix), )*
                }
            }

            /// The model, ready to drive fish.
            pub fn build(&self) -> Result<Arc<dyn FishModel>, ModelError> {
                self.validate()?;
                match self {
                    $( Self::$variant(p) => p.build_model(), )*
                    $( Self::$fvariant(p) => p.build_model(), )*
                }
            }
        }
    };
}

impl ModelSpec {
    /// Whether a step of this fish costs far more than a rule-based fish's: a network learned
    /// from recordings that runs every frame (M_ConvNet, an ONNX model; about twenty times the
    /// cost) or Python code called every frame. It decides training budgets (`PpoConfig::preset_for`,
    /// a study's `expensive_fish_budget`).
    pub fn is_expensive(&self) -> bool {
        match self {
            Self::Population(p) => p.base.as_deref().is_some_and(Self::is_expensive),
            _ => matches!(self, Self::ConvNet(_) | Self::Onnx(_) | Self::Python(_)),
        }
    }

    /// Where the support file of this model lives (`WEIGHTS.support.json` beside a weights or
    /// ONNX file; `None` for the shipped ConvNet weights, whose support is shipped with them).
    pub fn support_path(&self) -> Result<Option<std::path::PathBuf>, ModelError> {
        let beside = |p: &str| {
            let mut s = std::ffi::OsString::from(p);
            s.push(".support.json");
            std::path::PathBuf::from(s)
        };
        match self {
            Self::ConvNet(p) if p.weights.is_empty() => Ok(None),
            Self::ConvNet(p) => Ok(Some(beside(&p.weights))),
            Self::Onnx(p) => Ok(Some(beside(&p.path))),
            _ => Err(ModelError::NotDataDriven {
                model: self.name().to_string(),
            }),
        }
    }

    /// The support model of this model's training data, checked to belong to its weights
    /// (by SHA-256). Data-driven models only.
    pub fn support(&self) -> Result<support::SupportModel, ModelError> {
        match (self, self.support_path()?) {
            (_, None) => Ok(support::shipped_convnet()?),
            (Self::ConvNet(p), Some(file)) => {
                let hash =
                    weights_sha256(p.weights.as_ref()).map_err(|e| weights_error(&p.weights, e))?;
                Ok(support::SupportModel::load(&file, &p.weights, &hash)?)
            }
            (Self::Onnx(p), Some(file)) => {
                let hash = onnx_sha256(p.path.as_ref())?;
                Ok(support::SupportModel::load(&file, &p.path, &hash)?)
            }
            _ => Err(ModelError::NotDataDriven {
                model: self.name().to_string(),
            }),
        }
    }
}

impl ModelSpec {
    /// The ensemble of this model's fits (the `disagreement` OOD score), checked to belong to
    /// its weights. M_ConvNet with a weights file only: the shipped weights come without one,
    /// and an ONNX model's ensemble would need ONNX members (not supported).
    pub fn disagreement(&self) -> Result<disagreement::Disagreement, ModelError> {
        match self {
            Self::ConvNet(p) if !p.weights.is_empty() => {
                let sha =
                    weights_sha256(p.weights.as_ref()).map_err(|e| weights_error(&p.weights, e))?;
                Ok(disagreement::Disagreement::load(
                    p.weights.as_ref(),
                    &p.weights,
                    &sha,
                )?)
            }
            _ => Err(ModelError::Support(
                support::SupportError::MissingEnsemble {
                    model: self.name().to_string(),
                    path: "(only M_ConvNet fitted with `fit-convnet --members K` has one)".into(),
                },
            )),
        }
    }

    /// What scores the fish's views in the OOD task: the support of the training data or the
    /// disagreement of the model's ensemble ([`fishprobe_sim::OodScore`]).
    pub fn ood_scorer(
        &self,
        kind: fishprobe_sim::OodScore,
    ) -> Result<std::sync::Arc<dyn fishprobe_sim::InputSupport>, ModelError> {
        Ok(match kind {
            fishprobe_sim::OodScore::Support => std::sync::Arc::new(self.support()?),
            fishprobe_sim::OodScore::Disagreement => std::sync::Arc::new(self.disagreement()?),
        })
    }
}

model_registry! {
    /// M_Follow.
    follow::Follow(FollowParams),
    /// M_Zone.
    zone::Zone(ZoneParams),
    /// M_Force.
    force::Force(ForceParams),
    /// A fish that never moves (approach assay).
    stationary::Stationary(StationaryParams),
    /// M_ConvNet: behavioural cloning of live guppy pairs.
    convnet::ConvNet(ConvNetParams),
    /// The virtual guppy of the virtual lab (not a candidate model).
    guppy::Guppy(GuppyParams),
    ; // Models read from a file (no defaults; not in NAMES):
    /// A candidate model brought as an ONNX file (`onnx:PATH`).
    onnx::Onnx(OnnxParams),
    /// A fish model written in Python (run by the Python package only).
    python::Python(PythonParams),
    /// A population of a model's individuals (`population:FILE`, or a shipped population's
    /// name).
    population::Population(PopulationParams),
}

impl ModelSpec {
    /// Where the model comes from, for listings and reports: `built in`, `built in, changed:
    /// speed_cm_s, zone_convention` (parameters that differ from the published ones), or
    /// `ONNX file PATH (sha256 …)`.
    pub fn origin(&self) -> String {
        if let Self::Onnx(p) = self {
            let sha = if p.sha256.is_empty() {
                "not recorded"
            } else {
                p.sha256.as_str()
            };
            return format!("ONNX file {} (sha256 {sha})", p.path);
        }
        if let Self::Python(p) = self {
            return format!("Python class {}", p.class);
        }
        if let Self::Population(p) = self {
            let base = p.base.as_deref().map_or("?", Self::name);
            let traits: Vec<&str> = p.traits.iter().map(|t| t.name()).collect();
            let from = if p.source.is_empty() {
                String::new()
            } else {
                format!(", from {}", p.source)
            };
            return format!(
                "a population of {base} ({} varying{from})",
                traits.join(", ")
            );
        }
        let (Ok(mine), Ok(Ok(default))) = (
            serde_json::to_value(self),
            Self::by_name(self.name()).map(|d| serde_json::to_value(&d)),
        ) else {
            return "built in".into();
        };
        let changed: Vec<&String> = mine
            .as_object()
            .into_iter()
            .flatten()
            .filter(|(k, v)| default.get(k.as_str()) != Some(v))
            .map(|(k, _)| k)
            .collect();
        if changed.is_empty() {
            "built in".into()
        } else {
            let names: Vec<&str> = changed.iter().map(|k| k.as_str()).collect();
            format!("built in, changed: {}", names.join(", "))
        }
    }

    /// What to call the model in listings and policy files: its name, or for a Python model
    /// the name it gave itself.
    pub fn label(&self) -> String {
        match self {
            Self::Python(p) if !p.name.is_empty() => p.name.clone(),
            Self::Population(p) if !p.name.is_empty() => p.name.clone(),
            _ => self.name().to_string(),
        }
    }

    /// Every model a name alone selects, as listings show them: the built-in models, then the
    /// populations fitted to the shared training recordings that ship with fishprobe.
    pub fn listed_names() -> Vec<&'static str> {
        Self::NAMES
            .iter()
            .copied()
            .chain(population::SHIPPED.iter().map(|(n, _)| *n))
            .collect()
    }

    /// The rule-based candidate models of the paper.
    pub const RULE_BASED: [&'static str; 3] = ["Follow", "Zone", "Force"];
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn an_onnx_file_is_hashed_as_the_loader_reads_it() {
        let dir = std::env::temp_dir().join(format!("fishprobe-onnx-sha-{}", std::process::id()));
        std::fs::create_dir_all(&dir).unwrap();
        // A directory, a device and a file over the limit: refused in the loader's words,
        // never as "ConvNet weights".
        let big = dir.join("big.onnx");
        std::fs::File::create(&big)
            .unwrap()
            .set_len(fishprobe_onnx::MAX_FILE_BYTES + 1)
            .unwrap();
        for (path, why) in [
            (dir.clone(), "not an ONNX model: not a regular file"),
            (std::path::PathBuf::from("/dev/zero"), "not a regular file"),
            (big, "more than the 536870912 accepted"),
        ] {
            let e = onnx_sha256(&path).unwrap_err().to_string();
            assert!(e.contains(why) && !e.contains("ConvNet"), "{e}");
        }
        let small = dir.join("small.onnx");
        std::fs::write(&small, b"abc").unwrap();
        assert_eq!(
            onnx_sha256(&small).unwrap(),
            "ba7816bf8f01cfea414140de5dae2223b00361a396177a9cb410ff61f20015ad"
        );
        let _ = std::fs::remove_dir_all(&dir);
    }

    #[test]
    fn names_round_trip_and_unknown_is_clear() {
        for &n in ModelSpec::NAMES {
            let s = ModelSpec::by_name(n).unwrap();
            assert_eq!(s.name(), n);
            // The serde tag (the variant) is the model's NAME.
            let tagged = serde_json::to_value(&s).unwrap();
            assert_eq!(tagged["model"], n);
            assert_eq!(s.build().unwrap().name(), n);
            let json = serde_json::to_string(&s).unwrap();
            let back: ModelSpec = serde_json::from_str(&json).unwrap();
            assert_eq!(back, s);
        }
        assert_eq!(ModelSpec::by_name("virtualguppy").unwrap().name(), "Guppy");
        assert_eq!(ModelSpec::by_name("Zone").unwrap().origin(), "built in");
        let z = ZoneParams {
            speed_cm_s: 5.0,
            ..ZoneParams::default()
        };
        assert_eq!(ModelSpec::Zone(z).origin(), "built in, changed: speed_cm_s");
        let o = ModelSpec::by_name("onnx:/nonexistent/m.onnx").unwrap();
        assert_eq!(o.name(), "Onnx");
        assert_eq!(
            o.origin(),
            "ONNX file /nonexistent/m.onnx (sha256 not recorded)"
        );
        assert_eq!(ModelSpec::by_name("ZONE").unwrap().name(), "Zone");
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
