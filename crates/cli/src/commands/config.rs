//! `fishprobe config`: the simulation settings (environment and fish model) as a file, and a
//! check of a user's file.
//!
//! A settings file (JSON, or TOML by extension) has two optional sections: `env` (an
//! `EnvConfig`: tank, robot, task, observation) and `fish` (a model and its parameters,
//! `model = "Zone"` plus any parameters to change). Missing fields take the paper's defaults;
//! unknown fields and out-of-range values are errors that name the field.

use anyhow::{Context, Result};
use clap::{Args, Subcommand};
use fishprobe_models::ModelSpec;
use fishprobe_sim::EnvConfig;
use serde::{Deserialize, Serialize};
use std::path::{Path, PathBuf};

use super::emit;

/// Environment and fish model: what one simulation needs.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct SimSettings {
    /// The environment.
    #[serde(default)]
    pub env: EnvConfig,
    /// The fish model (default: M_Zone with the published parameters).
    #[serde(default = "default_fish")]
    pub fish: ModelSpec,
}

fn default_fish() -> ModelSpec {
    ModelSpec::Zone(fishprobe_models::ZoneParams::default())
}

impl Default for SimSettings {
    fn default() -> Self {
        Self {
            env: EnvConfig::default(),
            fish: default_fish(),
        }
    }
}

impl SimSettings {
    /// Reads and validates a settings file.
    pub fn load(path: &Path) -> Result<Self> {
        let text = fishprobe_io::read_small_text(path)
            .with_context(|| format!("cannot read settings file {}", path.display()))?;
        let is_toml = path
            .extension()
            .is_some_and(|e| e.eq_ignore_ascii_case("toml"));
        let s: SimSettings = if is_toml {
            super::parse_toml(&text)
                .with_context(|| format!("{} is not valid settings TOML", path.display()))?
        } else {
            serde_json::from_str(&text)
                .with_context(|| format!("{} is not valid settings JSON", path.display()))?
        };
        s.env
            .validate()
            .with_context(|| format!("in {} (section env)", path.display()))?;
        s.fish
            .validate()
            .with_context(|| format!("in {} (section fish)", path.display()))?;
        Ok(s)
    }

    /// Applies a `--model` flag to the fish. A flag naming the model the settings already
    /// describe keeps their parameters: `--model Zone --settings zone.toml` runs the Zone fish
    /// the file sets up, not the default one (before, the file's parameters were dropped without
    /// a word). A file flag (`convnet:PATH`, `onnx:PATH`) on a file describing the same kind of
    /// model replaces only the weights or network file and keeps the file's other parameters
    /// (`wall_redraws`), with a note when the file named other weights. A flag naming another
    /// model replaces the fish, with a note when that drops parameters the file set.
    pub fn apply_model_flag(&mut self, flag: &str) -> Result<()> {
        let by_file = flag.contains(':');
        match (&mut self.fish, ModelSpec::by_name(flag)?) {
            // A built-in model by its name: the file's parameters stand.
            (fish, named) if !by_file && fish.name() == named.name() => {}
            (ModelSpec::ConvNet(p), ModelSpec::ConvNet(n)) => {
                swap_file(&mut p.weights, n.weights, flag)
            }
            (ModelSpec::Onnx(p), ModelSpec::Onnx(n)) => {
                p.sha256 = n.sha256;
                swap_file(&mut p.path, n.path, flag)
            }
            (fish, named) => {
                if *fish != default_fish() && *fish != named {
                    say!(
                        "note: --model {flag} replaces the settings file's fish ({}) and the parameters it sets",
                        fish.name()
                    );
                }
                *fish = named;
            }
        }
        Ok(())
    }
}

/// Puts the file of a `--model convnet:PATH` / `onnx:PATH` flag in place of the one a settings
/// file named, saying so when it named another.
fn swap_file(slot: &mut String, new: String, flag: &str) {
    let old = std::mem::replace(slot, new);
    if !old.is_empty() && old != *slot {
        say!("note: --model {flag} replaces the settings file's {old}; its other parameters stand");
    }
}

#[derive(Debug, Args)]
pub struct ConfigArgs {
    #[command(subcommand)]
    what: ConfigWhat,
}

#[derive(Debug, Subcommand)]
enum ConfigWhat {
    /// Print the default settings (the paper's values) as a file to start from.
    Show {
        /// TOML instead of JSON.
        #[arg(long)]
        toml: bool,
        /// Fish model to show (default: Zone).
        #[arg(long)]
        model: Option<String>,
    },
    /// Print the settings reference (Markdown, every documented setting with its default,
    /// unit and meaning): what docs/settings.md holds.
    Reference,
    /// Check a settings file (.json or .toml) and print it resolved, with every default.
    Check {
        /// The file.
        file: PathBuf,
    },
}

pub fn run(a: ConfigArgs) -> Result<()> {
    match a.what {
        ConfigWhat::Show { toml, model } => {
            let mut s = SimSettings::default();
            if let Some(m) = model {
                s.fish = ModelSpec::by_name(&m)?;
            }
            let text = if toml {
                toml::to_string_pretty(&s)?
            } else {
                serde_json::to_string_pretty(&s)? + "\n"
            };
            emit(&text)
        }
        ConfigWhat::Reference => emit(&fishprobe_research::reference::reference()),
        ConfigWhat::Check { file } => {
            let s = SimSettings::load(&file)?;
            emit(&format!(
                "{}: valid ({} fish, {} mode)\n{}\n",
                file.display(),
                s.fish.name(),
                serde_json::to_value(s.env.mode)?.as_str().unwrap_or("?"),
                serde_json::to_string_pretty(&s)?
            ))
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use fishprobe_models::{ConvNetParams, OnnxParams, ZoneParams};

    fn with_fish(fish: ModelSpec) -> SimSettings {
        SimSettings {
            fish,
            ..SimSettings::default()
        }
    }

    #[test]
    fn a_weights_flag_keeps_the_files_other_convnet_parameters() {
        let mut s = with_fish(ModelSpec::ConvNet(ConvNetParams {
            weights: "old.safetensors".into(),
            wall_redraws: 0,
        }));
        s.apply_model_flag("convnet:new.safetensors").unwrap();
        assert_eq!(
            s.fish,
            ModelSpec::ConvNet(ConvNetParams {
                weights: "new.safetensors".into(),
                wall_redraws: 0,
            })
        );
        // The model's name alone keeps the file's weights too.
        s.apply_model_flag("ConvNet").unwrap();
        assert_eq!(
            s.fish,
            ModelSpec::ConvNet(ConvNetParams {
                weights: "new.safetensors".into(),
                wall_redraws: 0,
            })
        );
    }

    #[test]
    fn a_network_flag_keeps_the_files_other_onnx_parameters() {
        let mut s = with_fish(ModelSpec::Onnx(OnnxParams {
            path: "old.onnx".into(),
            sha256: "ab".repeat(32),
            wall_redraws: 3,
        }));
        s.apply_model_flag("onnx:no-such-file.onnx").unwrap();
        // The hash is the new file's (none here: the file does not exist, and loading it
        // later says so), never the old file's, which would refuse the new one.
        assert_eq!(
            s.fish,
            ModelSpec::Onnx(OnnxParams {
                path: "no-such-file.onnx".into(),
                sha256: String::new(),
                wall_redraws: 3,
            })
        );
    }

    #[test]
    fn another_model_replaces_the_fish_and_the_same_one_keeps_it() {
        let zone = ModelSpec::Zone(ZoneParams {
            wall_attraction_strength: 1.0,
            ..ZoneParams::default()
        });
        let mut s = with_fish(zone.clone());
        s.apply_model_flag("zone").unwrap();
        assert_eq!(s.fish, zone);
        s.apply_model_flag("convnet:w.safetensors").unwrap();
        assert_eq!(s.fish, ModelSpec::by_name("convnet:w.safetensors").unwrap());
        assert!(s.apply_model_flag("Zonk").is_err());
    }
}
