//! `fishprobe config reference`: every documented setting, generated from the parameter structs
//! themselves (their field docs, units and defaults), so the settings reference in
//! `docs/settings.md` cannot drift: a test regenerates it and fails when the file is stale.

use fishprobe_sim::params::DocumentedParams;
use std::fmt::Write;

/// One section: its heading, where it is used, and its fields with their defaults.
fn section<T: DocumentedParams>(out: &mut String, title: &str, used: &str) {
    let defaults = serde_json::to_value(T::default()).unwrap_or(serde_json::Value::Null);
    let _ = writeln!(out, "### {title}\n\n{used}\n");
    out.push_str("| field | default | unit | meaning |\n|---|---|---|---|\n");
    for f in T::field_docs() {
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
    section::<m::FollowParams>(&mut o, "`model = \"Follow\"`", "M_Follow.");
    section::<m::ZoneParams>(&mut o, "`model = \"Zone\"`", "M_Zone (Couzin et al. 2002).");
    section::<m::ForceParams>(
        &mut o,
        "`model = \"Force\"`",
        "M_Force (Klamser et al. 2021).",
    );
    section::<m::ConvNetParams>(&mut o, "`model = \"ConvNet\"`", "M_ConvNet.");
    section::<m::OnnxParams>(
        &mut o,
        "`model = \"Onnx\"`",
        "A model brought as an ONNX file (docs/onnx-models.md).",
    );
    section::<m::StationaryParams>(
        &mut o,
        "`model = \"Stationary\"`",
        "The approach assay's fish.",
    );
    section::<m::GuppyParams>(&mut o, "`model = \"Guppy\"`", "The virtual lab's guppy.");
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
    section::<super::ood_loop::OodLoopConfig>(
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
