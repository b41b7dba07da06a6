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
        let text = std::fs::read_to_string(path)
            .with_context(|| format!("cannot read settings file {}", path.display()))?;
        let is_toml = path
            .extension()
            .is_some_and(|e| e.eq_ignore_ascii_case("toml"));
        let s: SimSettings = if is_toml {
            toml::from_str(&text)
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
    /// a word). A flag naming another model, or a file (`convnet:PATH`, `onnx:PATH`), replaces
    /// the fish, with a note when that drops parameters the file set.
    pub fn apply_model_flag(&mut self, flag: &str) -> Result<()> {
        let named = ModelSpec::by_name(flag)?;
        if !flag.contains(':') && named.name() == self.fish.name() {
            return Ok(());
        }
        if self.fish != default_fish() && self.fish != named {
            say!(
                "note: --model {flag} replaces the settings file's fish ({}) and the parameters it sets",
                self.fish.name()
            );
        }
        self.fish = named;
        Ok(())
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
        ConfigWhat::Reference => emit(&super::reference::reference()),
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
