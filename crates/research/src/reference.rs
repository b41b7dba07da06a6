//! The settings reference (`fishprobe config reference`): every documented setting, generated from the parameter structs
//! themselves (their field docs, units and defaults), so the settings reference in
//! `docs/settings.md` cannot drift: a test regenerates it and fails when the file is stale.

use fishprobe_sim::params::DocumentedParams;
use std::fmt::Write;

/// One section: its heading, where it is used, and its fields with their defaults.
fn section<T: DocumentedParams>(out: &mut String, title: &str, used: &str) {
    let defaults = serde_json::to_value(T::default()).unwrap_or(serde_json::Value::Null);
    rows(out, title, used, T::field_docs(), &defaults);
}

/// A section: its title, where it is used, and a row per field with its default.
fn rows(
    out: &mut String,
    title: &str,
    used: &str,
    docs: &[fishprobe_sim::params::FieldDoc],
    defaults: &serde_json::Value,
) {
    let _ = writeln!(out, "### {title}\n\n{used}\n");
    out.push_str("| field | default | unit | meaning |\n|---|---|---|---|\n");
    for f in docs {
        let d = match defaults.get(f.name) {
            Some(serde_json::Value::Object(_)) => "(section below)".to_string(),
            Some(v) => format!("`{}`", compact(v)),
            None => "–".into(),
        };
        let _ = writeln!(
            out,
            "| `{}` | {d} | {} | {} |",
            f.name,
            f.unit,
            f.text().replace('|', "\\|")
        );
    }
    out.push('\n');
}

/// A default as written in a file; floats as the shortest text that reads back (6.3, not
/// 6.300000190734863).
fn compact(v: &serde_json::Value) -> String {
    match v {
        serde_json::Value::Number(n) => match n.as_f64() {
            Some(x) if n.is_f64() => {
                let f = x as f32;
                if f64::from(f) == x || format!("{f}").parse::<f32>().ok() == Some(f) {
                    format!("{f}")
                } else {
                    format!("{x}")
                }
            }
            _ => n.to_string(),
        },
        serde_json::Value::String(s) if s.is_empty() => "\"\"".into(),
        other => other.to_string(),
    }
}

/// The reference, as Markdown.
pub fn reference() -> String {
    use fishprobe_models as m;
    use fishprobe_sim as s;
    let mut o = String::from(
        "# Settings reference\n\n\
         Every setting fishprobe reads from a file, with its default (the paper's value where the \
         paper gives one), its unit and its meaning. Generated from the parameter structs by \
         `fishprobe config reference > docs/settings.md`; a test fails when this file is stale. \
         Every struct refuses unknown fields and checks its ranges when read, naming the field.\n\n\
         ## Simulation (`--settings FILE`, `fishprobe config show`)\n\n\
         A settings file has two sections, `env` and `fish` (`model = \"Zone\"` plus the \
         parameters to change).\n\n",
    );
    section::<s::EnvConfig>(&mut o, "`env`", "The environment.");
    section::<s::TankParams>(&mut o, "`env.tank`", "The tank.");
    section::<s::RobotParams>(
        &mut o,
        "`env.robot`",
        "The robot and its low-level controller.",
    );
    section::<s::TaskParams>(
        &mut o,
        "`env.task`",
        "The lead-to-goal task, or the OOD objective (`fishprobe train --task ood`). A study file's `[task]` table sets these by name for the whole study (not `group_goal`, `objective`, `evaluation_episode_actions`).",
    );
    section::<s::ObservationParams>(&mut o, "`env.observation`", "The policy's observation.");
    o.push_str("## Fish models (`fish` section, study files' `spec`)\n\n");
    // Every built-in model of the registry, with its defaults and its one-line summary.
    for name in m::ModelSpec::NAMES {
        if let Ok(spec) = m::ModelSpec::by_name(name) {
            let defaults = serde_json::to_value(&spec).unwrap_or(serde_json::Value::Null);
            rows(
                &mut o,
                &format!("`model = \"{name}\"`"),
                spec.summary(),
                spec.field_docs(),
                &defaults,
            );
        }
    }
    section::<m::OnnxParams>(
        &mut o,
        "`model = \"Onnx\"`",
        "A model brought as an ONNX file (docs/onnx-models.md).",
    );
    section::<m::PopulationParams>(
        &mut o,
        "`model = \"Population\"`",
        "A population of a model's individuals (`population:FILE`, or a shipped population's name: FollowPop, ZonePop, ForcePop, ConvNetPop, GuppyPop; docs/guide/individuals.md).",
    );
    o.push_str("## Training and fitting\n\n");
    section::<fishprobe_learn::PpoConfig>(
        &mut o,
        "PPO (`fishprobe train --ppo FILE`)",
        "Fields override the preset's (`paper` shown).",
    );
    section::<fishprobe_learn::bc::CloneConfig>(
        &mut o,
        "M_ConvNet fitting (`fishprobe fit-convnet --config FILE`)",
        "Behavioural cloning of the pair recordings.",
    );
    section::<fishprobe_learn::population::FitConfig>(
        &mut o,
        "Population fitting (`fishprobe fit-population --config FILE`)",
        "How a population of a model's individuals is fitted to the per-recording statistics of real recordings.",
    );
    section::<fishprobe_models::support::SupportConfig>(
        &mut o,
        "Support model (`fishprobe support`; `fit-convnet` writes one with these defaults)",
        "How the OOD objective's support of a model's training views is estimated.",
    );
    section::<fishprobe_learn::yardstick::OodYardstickConfig>(
        &mut o,
        "The OOD reward's yardstick (`fishprobe train --task ood --ood-yardstick POLICY`)",
        "How the lead-to-goal policy's percentile is measured and the reward shaped from it; \
         each field has a `--ood-yardstick-*` flag except `seed`.",
    );
    section::<crate::ood_loop::OodLoopConfig>(
        &mut o,
        "The in-silico OOD loop (`fishprobe ood-loop --config FILE`)",
        "Budget and design of the closed loop with the virtual guppy as the real fish.",
    );
    o.push_str("## Analysis and report\n\n");
    section::<fishprobe_analysis::AnalysisConfig>(
        &mut o,
        "Analysis (`fishprobe_analysis::AnalysisConfig`)",
        "Every measure and test of SPEC §8 (`fishprobe analyze --quick` lowers the resampling counts; any of these can be set by name in an `[analysis]` table of a study file or of `fishprobe analyze --settings FILE`).",
    );
    section::<fishprobe_analysis::offline::OfflineConfig>(
        &mut o,
        "Offline comparison (`fishprobe compare-offline`)",
        "Model pairs against real pairs.",
    );
    section::<fishprobe_report::ReportConfig>(
        &mut o,
        "Report (`fishprobe report --config FILE`)",
        "Figures and the HTML page.",
    );
    o.push_str("## Live trials and the virtual lab\n\n");
    section::<fishprobe_live::session::LiveConfig>(
        &mut o,
        "Live trials (`fishprobe live serve --config FILE`)",
        "The trial protocol and the bridge's safety settings (docs/live-protocol.md, docs/safety.md).",
    );
    section::<fishprobe_live::lab::LabConfig>(
        &mut o,
        "Virtual lab (`fishprobe_live::lab::LabConfig`)",
        "Tank, tracker and robot of the virtual lab.",
    );
    section::<s::ScriptParams>(
        &mut o,
        "Scripted robots (`fishprobe simulate --robot still|circle|goals`)",
        "How the scripted robots move.",
    );
    o.trim_end().to_string() + "\n"
}

#[cfg(test)]
mod tests {
    //! Every number a settings file can hold, set to ±1e30 (or the largest integer): refused,
    //! or named below with the reason its effect stays bounded. A new field without a bound
    //! fails here until it gets one or a reason; a new settings section of [`reference`]
    //! fails here until the test's list has it too (the virtual lab's `LabConfig` is not read
    //! from a file).
    use serde::{de::DeserializeOwned, Serialize};
    use serde_json::{json, Map, Value};

    /// The fields of `base` set one at a time to absurd numbers, each checked by `check`
    /// (deserialising is part of the check: an integer field refuses a float). Returns
    /// `section.field = value` for every absurd number accepted.
    fn accepted(
        section: &str,
        base: &Map<String, Value>,
        check: &dyn Fn(Map<String, Value>) -> bool,
    ) -> Vec<String> {
        let mut out = Vec::new();
        for (k, v) in base {
            let absurd: Vec<Value> = if v.is_u64() {
                vec![json!(u64::MAX), json!(u32::MAX)]
            } else if v.is_number() {
                vec![json!(1e30), json!(-1e30)]
            } else {
                continue;
            };
            for a in absurd {
                let mut m = base.clone();
                m.insert(k.clone(), a.clone());
                if check(m) {
                    out.push(format!("{section}.{k} = {a}"));
                }
            }
        }
        out
    }

    /// Whether a map of a section's fields deserialises and validates.
    type Check = Box<dyn Fn(Map<String, Value>) -> bool>;

    /// A settings section: its name, its struct's default fields, and its [`Check`].
    fn plain<T: Serialize + DeserializeOwned + Default>(
        name: &'static str,
        validate: impl Fn(&T) -> bool + 'static,
    ) -> (&'static str, Map<String, Value>, Check) {
        let base = match serde_json::to_value(T::default()) {
            Ok(Value::Object(m)) => m,
            other => panic!("not a struct: {other:?}"),
        };
        let check = move |m: Map<String, Value>| {
            serde_json::from_value::<T>(Value::Object(m)).is_ok_and(|t| validate(&t))
        };
        (name, base, Box::new(check))
    }

    /// Fields whose absurd values are accepted, each with why that is harmless.
    const BOUNDED_EFFECT: &[(&str, &str)] = &[
        (
            "ppo.lr = 1e+30",
            "training stops at the first update with `training diverged`, the last good \
             checkpoint kept",
        ),
        (
            "ppo.entropy_coeff = 1e+30",
            "Adam's steps do not scale with the loss; `log_std_max` bounds the s.d.",
        ),
        (
            "ppo.vf_loss_coeff = 1e+30",
            "Adam's steps do not scale with the loss (measured: finite losses and policy)",
        ),
        (
            "ppo.kl_coeff = 1e+30",
            "the adaptive coefficient halves each iteration the KL stays under target",
        ),
        ("ppo.kl_target = 1e+30", "the KL penalty then never grows"),
        (
            "ppo.vf_clip_param = 1e+30",
            "no value clipping, RLlib's own behaviour without it",
        ),
        (
            "clone.learning_rate = 1e+30",
            "the fit stops with `training NLL is not finite`, the last good checkpoint kept",
        ),
        (
            "ppo.checkpoint_every = 18446744073709551615",
            "no checkpoint but the final policy",
        ),
        (
            "ppo.checkpoint_every = 4294967295",
            "no checkpoint but the final policy",
        ),
        (
            "ppo.total_timesteps = 4294967295",
            "within `MAX_TOTAL_TIMESTEPS` (10^10): a long run, shown with its ETA, resumable",
        ),
        (
            "clone.min_frames = 18446744073709551615",
            "every file is skipped as too short, then the fit refuses: no training data",
        ),
        (
            "clone.min_frames = 4294967295",
            "every file is skipped as too short, then the fit refuses: no training data",
        ),
        (
            "clone.patience = 18446744073709551615",
            "no early stopping; `max_epochs` bounds the fit",
        ),
        (
            "clone.patience = 4294967295",
            "no early stopping; `max_epochs` bounds the fit",
        ),
        (
            "yardstick.seed = 18446744073709551615",
            "a seed like any other",
        ),
        ("yardstick.seed = 4294967295", "a seed like any other"),
        (
            "analysis.competence_threshold = 1e+30",
            "every probe is reported below the bar, as asked",
        ),
    ];

    #[test]
    fn every_number_in_a_settings_file_is_bounded_or_its_effect_is() {
        use fishprobe_models::ModelSpec;
        let mut found: Vec<String> = Vec::new();
        let mut sections: Vec<(&str, Map<String, Value>, Check)> = Vec::new();
        let tank = fishprobe_sim::Tank::default();
        // The environment's own numbers (its sub-sections are checked one by one below).
        sections.push(plain::<fishprobe_sim::EnvConfig>("env", |p| {
            p.validate().is_ok()
        }));
        sections.push(plain::<fishprobe_sim::TankParams>("tank", |p| {
            p.validate("tank").is_ok()
        }));
        sections.push(plain::<fishprobe_sim::RobotParams>("robot", |p| {
            p.validate("robot").is_ok()
        }));
        // The episode's length is checked with the frames per action, by the environment.
        sections.push(plain::<fishprobe_sim::TaskParams>("task", move |p| {
            p.validate("task", &tank).is_ok()
                && fishprobe_sim::EnvConfig {
                    task: p.clone(),
                    ..fishprobe_sim::EnvConfig::default()
                }
                .validate()
                .is_ok()
        }));
        sections.push(plain::<fishprobe_sim::ObservationParams>(
            "observation",
            |p| p.validate("observation").is_ok(),
        ));
        sections.push(plain::<fishprobe_sim::script::ScriptParams>(
            "script",
            |p| p.validate("script").is_ok(),
        ));
        sections.push(plain::<fishprobe_learn::PpoConfig>("ppo", |p| {
            p.validate().is_ok()
        }));
        sections.push(plain::<fishprobe_learn::bc::CloneConfig>("clone", |p| {
            p.validate().is_ok()
        }));
        sections.push(plain::<fishprobe_models::support::SupportConfig>(
            "support",
            |p| p.validate().is_ok(),
        ));
        sections.push(plain::<fishprobe_learn::yardstick::OodYardstickConfig>(
            "yardstick",
            |p| p.validate().is_ok(),
        ));
        sections.push(plain::<crate::ood_loop::OodLoopConfig>("ood_loop", |p| {
            p.validate().is_ok()
        }));
        sections.push(plain::<fishprobe_learn::population::FitConfig>(
            "fit",
            |p| p.validate().is_ok(),
        ));
        sections.push(plain::<fishprobe_analysis::AnalysisConfig>(
            "analysis",
            |p| p.validate().is_ok(),
        ));
        sections.push(plain::<fishprobe_analysis::offline::OfflineConfig>(
            "offline",
            |p| p.validate().is_ok(),
        ));
        sections.push(plain::<fishprobe_report::ReportConfig>("report", |p| {
            p.validate().is_ok()
        }));
        sections.push(plain::<fishprobe_live::session::LiveConfig>("live", |p| {
            p.validate().is_ok()
        }));
        let models = ModelSpec::NAMES.iter().chain(&["Onnx", "Population"]);
        for &model in models {
            // An ONNX model names its file (validation does not open it); a population its
            // source (read when it is built).
            let spec = match model {
                "Onnx" => json!({ "model": model, "path": "model.onnx" }),
                "Population" => json!({ "model": model, "source": "ZonePop" }),
                _ => json!({ "model": model }),
            };
            let base =
                match serde_json::to_value(serde_json::from_value::<ModelSpec>(spec).unwrap()) {
                    Ok(Value::Object(m)) => m,
                    other => panic!("{other:?}"),
                };
            let check = |m: Map<String, Value>| {
                serde_json::from_value::<ModelSpec>(Value::Object(m))
                    .is_ok_and(|s| s.validate().is_ok())
            };
            sections.push((model, base, Box::new(check)));
        }
        // Every section of the reference is here, but the virtual lab's (not read from a file).
        let documented = super::reference().matches("\n### ").count();
        assert_eq!(
            sections.len() + 1,
            documented,
            "the reference has a settings section this test does not check"
        );
        for (name, base, check) in &sections {
            assert!(check(base.clone()), "{name}: the defaults are refused");
            found.extend(accepted(name, base, check.as_ref()));
        }
        // A listed field that is now bounded leaves the list.
        for (k, _) in BOUNDED_EFFECT {
            assert!(
                found.iter().any(|f| f == k),
                "{k} is refused now: unlist it"
            );
        }
        let unexplained: Vec<&String> = found
            .iter()
            .filter(|f| !BOUNDED_EFFECT.iter().any(|(k, _)| k == f))
            .collect();
        assert!(
            unexplained.is_empty(),
            "absurd numbers accepted with no bound and no reason:\n{}",
            unexplained
                .iter()
                .map(|s| s.as_str())
                .collect::<Vec<_>>()
                .join("\n")
        );
    }
}
