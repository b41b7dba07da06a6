//! The readings of the fidelity sweep: each a set of overrides (environment, fish model, PPO)
//! merged field by field into the defaults, alone or combined (`a+b`), and the paper's
//! simulation results the scoreboard compares a cell with.

use crate::{ResearchError, Result};
use fishprobe_learn::PpoConfig;
use serde_json::{json, Value};

/// One reading: overrides merged field by field into the defaults.
pub(super) struct Reading {
    pub(super) name: &'static str,
    pub(super) what: &'static str,
    /// Only these models (empty: all).
    pub(super) models: &'static [&'static str],
    pub(super) env: fn() -> Value,
    pub(super) model: fn() -> Value,
    pub(super) ppo: fn() -> Value,
}

fn none() -> Value {
    json!({})
}

/// The paper's training steps per policy; the budget readings are multiples of it.
const PUBLISHED: u64 = PpoConfig::PUBLISHED_TIMESTEPS;

/// The fidelity sweep's readings of what the paper leaves open (one departure from the defaults each).
pub(super) const READINGS: &[Reading] = &[
    Reading {
        name: "baseline",
        what: "fishprobe's defaults",
        models: &[],
        env: none,
        model: none,
        ppo: none,
    },
    Reading {
        name: "robot-reaches",
        what: "a training goal counts (and is re-drawn) when the robot reaches it, as the paper's methods say",
        models: &[],
        env: || json!({"task": {"training_goal_reached_by": "robot"}}),
        model: none,
        ppo: none,
    },
    Reading {
        name: "either-reaches",
        what: "a training goal counts when the robot or the fish reaches it",
        models: &[],
        env: || json!({"task": {"training_goal_reached_by": "either"}}),
        model: none,
        ppo: none,
    },
    Reading {
        name: "zone-radii",
        what: "M_Zone's zone sizes read as radii, not widths",
        models: &["Zone"],
        env: none,
        model: || json!({"zone_convention": "radii"}),
        ppo: none,
    },
    Reading {
        name: "zone-no-wall-pull",
        what: "M_Zone with wall repulsion only, the paper's published wall parameters (the default since this sweep)",
        models: &["Zone"],
        env: none,
        model: || json!({"wall_attraction_strength": 0.0}),
        ppo: none,
    },
    Reading {
        name: "zone-wall-pull",
        what: "M_Zone pulled back to a wall it heads away from, SPEC's wall-following choice (the default before this sweep)",
        models: &["Zone"],
        env: none,
        model: || json!({"wall_attraction_strength": 1.0}),
        ppo: none,
    },
    Reading {
        name: "force-noise-per-frame",
        what: "M_Force's noise amplitudes read per frame",
        models: &["Force"],
        env: none,
        model: || json!({"noise_convention": "per_frame"}),
        ppo: none,
    },
    Reading {
        name: "force-noise-std-dev",
        what: "M_Force's noise amplitudes read as standard deviations",
        models: &["Force"],
        env: none,
        model: || json!({"noise_convention": "std_dev"}),
        ppo: none,
    },
    Reading {
        name: "follow-4cm-s",
        what: "M_Follow at 4 cm/s (the default since this sweep: the paper's ~15 s per goal)",
        models: &["Follow"],
        env: none,
        model: || json!({"speed_cm_s": 4.0}),
        ppo: none,
    },
    Reading {
        name: "follow-6.3cm-s",
        what: "M_Follow at 6.3 cm/s, M_Zone's speed (the default before this sweep)",
        models: &["Follow"],
        env: none,
        model: || json!({"speed_cm_s": 6.3}),
        ppo: none,
    },
    Reading {
        name: "lab-start",
        what: "training episodes start as a live trial after habituation: the robot in the centre, the fish in a corner",
        models: &[],
        env: || json!({"task": {"training_start": "lab"}}),
        model: none,
        ppo: none,
    },
    Reading {
        name: "random-start",
        what: "training episodes start at random poses (the default, spelt out)",
        models: &[],
        env: || json!({"task": {"training_start": "random"}}),
        model: none,
        ppo: none,
    },
    Reading {
        name: "mixed-start",
        what: "half the training episodes start as `lab-start`, half at random poses (to learn fetching and leading)",
        models: &[],
        env: || json!({"task": {"training_start": "mixed", "lab_start_share": 0.5}}),
        model: none,
        ppo: none,
    },
    Reading {
        name: "time-limit-terminal",
        what: "the 41-s time limit ends an episode (RLlib 2.0.1 with gym's done flag), no bootstrap from V",
        models: &[],
        env: none,
        model: none,
        ppo: || json!({"bootstrap_truncated": false}),
    },
    Reading {
        name: "std-unbounded",
        what: "the policy's log-s.d. unbounded, as in RLlib 2.0.1 (the published preset's; 10 epochs kept)",
        models: &[],
        env: none,
        model: none,
        ppo: || json!({"log_std_max": null}),
    },
    Reading {
        name: "value-clip-off",
        what: "no clamp of the squared value error (RLlib's vf_clip_param 10 lifted)",
        models: &[],
        env: none,
        model: none,
        ppo: || json!({"vf_clip_param": 1.0e9}),
    },
    Reading {
        name: "lr-anneal",
        what: "the learning rate falls linearly to 0 over the run (RLlib's lr_schedule, SB3's linear schedule; the paper lists one rate)",
        models: &[],
        env: none,
        model: none,
        ppo: || json!({"lr_final": 0.0}),
    },
    Reading {
        name: "gamma-0.99",
        what: "a discount of 0.99 per 1-s action, a 100-s horizon (the paper's 0.9453 is 18 s, less than a fetch and a lead; the `paper` preset's since `budget-16x`)",
        models: &[],
        env: none,
        model: none,
        ppo: || json!({"gamma": 0.99}),
    },
    Reading {
        name: "gamma-published",
        what: "the paper's discount of 0.9453 per 1-s action, an 18-s horizon (the `paper` preset's before `gamma-0.99+budget-16x`)",
        models: &[],
        env: none,
        model: none,
        ppo: || json!({"gamma": PpoConfig::PUBLISHED_GAMMA}),
    },
    Reading {
        name: "evaluation-goals",
        what: "training goals are the evaluation's two corner goals, alternating, not random ones (not in the paper)",
        models: &[],
        env: || json!({"task": {"training_goals": "evaluation"}}),
        model: none,
        ppo: none,
    },
    Reading {
        name: "progress-shaping",
        what: "training rewards the fish's progress toward the goal too (potential-based shaping, weight 1; not in the paper)",
        models: &[],
        env: || json!({"task": {"progress_shaping": 1.0}}),
        model: none,
        ppo: none,
    },
    Reading {
        name: "budget-4x",
        what: "four times the paper's 832,300 training steps",
        models: &[],
        env: none,
        model: none,
        ppo: || json!({"total_timesteps": 4 * PUBLISHED}),
    },
    Reading {
        name: "epochs-3",
        what: "3 epochs per batch (with `budget-4x`: four times the data for 1.2 times the update work of `budget-1x+epochs-10`)",
        models: &[],
        env: none,
        model: none,
        ppo: || json!({"num_sgd_iter": 3}),
    },
    Reading {
        name: "epochs-5",
        what: "5 epochs per batch (with `budget-2x`: twice the data for the update work of `budget-1x+epochs-10`)",
        models: &[],
        env: none,
        model: none,
        ppo: || json!({"num_sgd_iter": 5}),
    },
    Reading {
        name: "budget-1x",
        what: "the paper's 832,300 training steps (the `paper` preset's before this sweep, with `epochs-10`)",
        models: &[],
        env: none,
        model: none,
        ppo: || json!({"total_timesteps": PUBLISHED}),
    },
    Reading {
        name: "epochs-10",
        what: "10 epochs per batch (the `paper` preset's before this sweep, with `budget-1x`)",
        models: &[],
        env: none,
        model: none,
        ppo: || json!({"num_sgd_iter": 10}),
    },
    Reading {
        name: "budget-2x",
        what: "twice the paper's 832,300 training steps",
        models: &[],
        env: none,
        model: none,
        ppo: || json!({"total_timesteps": 2 * PUBLISHED}),
    },
    Reading {
        name: "budget-16x",
        what: "sixteen times the paper's 832,300 training steps (the `paper` preset's since this reading with `gamma-0.99`, whose longer horizon learns to lead more slowly)",
        models: &[],
        env: none,
        model: none,
        ppo: || json!({"total_timesteps": 16 * PUBLISHED}),
    },
    Reading {
        name: "budget-8x",
        what: "eight times the paper's 832,300 training steps (the `paper` preset's from the first sweep to `gamma-0.99+budget-16x`)",
        models: &[],
        env: none,
        model: none,
        ppo: || json!({"total_timesteps": 8 * PUBLISHED}),
    },
    Reading {
        name: "epochs-2",
        what: "2 epochs per batch (the `paper` preset's since this sweep; with `budget-8x`: eight times the data for 1.6 times the update work of `budget-1x+epochs-10`)",
        models: &[],
        env: none,
        model: none,
        ppo: || json!({"num_sgd_iter": 2}),
    },
    Reading {
        name: "epochs-30",
        what: "30 epochs per batch (between 10 and the published 100)",
        models: &[],
        env: none,
        model: none,
        ppo: || json!({"num_sgd_iter": 30}),
    },
];

/// One cell's reading: one reading, or several combined (`a+b`).
pub(super) struct Combo {
    pub(super) name: String,
    pub(super) parts: Vec<&'static Reading>,
}

impl Combo {
    pub(super) fn parse(name: &str) -> Result<Self> {
        let parts = name
            .split('+')
            .map(|n| {
                READINGS.iter().find(|r| r.name == n.trim()).ok_or_else(|| {
                    ResearchError::msg(format!(
                        "unknown reading `{n}` (see `fishprobe fidelity --list`)"
                    ))
                })
            })
            .collect::<Result<Vec<_>>>()?;
        Ok(Self {
            name: name.to_string(),
            parts,
        })
    }

    pub(super) fn what(&self) -> String {
        let w: Vec<&str> = self.parts.iter().map(|r| r.what).collect();
        w.join("; ")
    }

    /// Whether every part that is specific to some models includes `model`.
    pub(super) fn applies_to(&self, model: &str) -> bool {
        self.parts
            .iter()
            .all(|r| r.models.is_empty() || r.models.contains(&model))
    }

    pub(super) fn merged(&self, part: impl Fn(&Reading) -> Value) -> Value {
        let mut v = json!({});
        for r in &self.parts {
            merge(&mut v, &part(r));
        }
        v
    }
}

/// The paper's simulation results per policy on its own model (approximate, read off its
/// Fig. 3 and Fig. 7 and text): goals per 15 min, closest approach (cm) and fraction of time
/// nearer the fish than the goal in the approach assay. `None`: not reported.
pub(super) fn paper(model: &str) -> (Option<f64>, Option<f64>, Option<f64>) {
    match model {
        "Follow" => (Some(60.0), None, Some(0.0)),
        "Zone" => (Some(41.0), Some(4.0), Some(0.223)),
        "Force" => (Some(51.0), Some(0.35), Some(0.561)),
        "ConvNet" => (None, None, Some(0.046)),
        _ => (None, None, None),
    }
}

fn merge(base: &mut Value, over: &Value) {
    match (base, over) {
        (Value::Object(b), Value::Object(o)) => {
            for (k, v) in o {
                merge(b.entry(k.clone()).or_insert(Value::Null), v);
            }
        }
        (b, o) => *b = o.clone(),
    }
}

pub(super) fn with<T: serde::Serialize + serde::de::DeserializeOwned>(
    base: &T,
    over: &Value,
) -> Result<T> {
    let mut v = serde_json::to_value(base)?;
    merge(&mut v, over);
    Ok(serde_json::from_value(v)?)
}

#[cfg(test)]
mod tests {
    use super::*;
    use fishprobe_models::ModelSpec;
    use fishprobe_sim::EnvConfig;

    /// Every reading's overrides name real fields: merged into the defaults of each model it
    /// runs on, they give valid settings that differ from the defaults where the reading says
    /// it changes something (a misspelt field would otherwise be a silent no-op, or fail only
    /// after the cells before it had trained).
    #[test]
    fn every_reading_changes_valid_settings() {
        let models = ["Follow", "Zone", "Force", "ConvNet"];
        for r in READINGS {
            let mut changed = false;
            for m in models
                .iter()
                .filter(|m| r.models.is_empty() || r.models.contains(m))
            {
                let base = ModelSpec::by_name(m).unwrap_or_else(|e| panic!("{m}: {e}"));
                let spec: ModelSpec =
                    with(&base, &(r.model)()).unwrap_or_else(|e| panic!("{}: {m}: {e}", r.name));
                assert!(spec.validate().is_ok(), "{}: {m}", r.name);
                changed |= spec != base;
            }
            let env: EnvConfig = with(&EnvConfig::default(), &(r.env)())
                .unwrap_or_else(|e| panic!("{}: {e}", r.name));
            assert!(env.validate().is_ok(), "{}", r.name);
            changed |= env != EnvConfig::default();
            let ppo = PpoConfig::preset("paper").unwrap_or_else(|| panic!("paper preset"));
            let over: PpoConfig =
                with(&ppo, &(r.ppo)()).unwrap_or_else(|e| panic!("{}: {e}", r.name));
            changed |= serde_json::to_value(&over).ok() != serde_json::to_value(&ppo).ok();
            // The readings that spell out a default change nothing, by design.
            let spelt_out = [
                "baseline",
                "random-start",
                "follow-4cm-s",
                "zone-no-wall-pull",
                "budget-16x",
                "gamma-0.99",
                "epochs-2",
            ];
            assert_eq!(changed, !spelt_out.contains(&r.name), "{}", r.name);
        }
    }

    #[test]
    fn the_wall_pull_readings_change_only_the_pull() {
        let zone = |name: &str| {
            let r = READINGS
                .iter()
                .find(|r| r.name == name)
                .unwrap_or_else(|| panic!("{name} listed"));
            assert_eq!(r.models, ["Zone"]);
            let base = ModelSpec::by_name("Zone").unwrap_or_else(|e| panic!("{e}"));
            match with(&base, &(r.model)()).unwrap_or_else(|e| panic!("{e}")) {
                ModelSpec::Zone(p) => p,
                other => panic!("a Zone spec, not {other:?}"),
            }
        };
        let d = fishprobe_models::ZoneParams::default();
        assert_eq!(zone("zone-no-wall-pull"), d, "the default since the sweep");
        let pulled = zone("zone-wall-pull");
        assert_eq!(pulled.wall_attraction_strength, 1.0);
        assert_eq!(
            fishprobe_models::ZoneParams {
                wall_attraction_strength: d.wall_attraction_strength,
                ..pulled
            },
            d
        );
    }
}
