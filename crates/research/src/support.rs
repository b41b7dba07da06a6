//! The support model of a data-driven fish model's training recordings (`fishprobe support`),
//! validated on held-out recordings and on situations the data lacks, with the two estimators
//! compared.

use crate::{ResearchError, Result, Runner};
use fishprobe_learn::bc::{
    build_support, file_names, load_pairs, pairs_or_shared, CloneConfig, PairDataset,
};
use fishprobe_models::convnet::{shipped_sha256, ConvNetArch};
use fishprobe_models::support::{auc, synthetic_views, Estimator, SupportConfig};
use fishprobe_models::ModelSpec;
use fishprobe_sim::{Tank, TankParams};
use rayon::prelude::*;
use std::path::PathBuf;
use std::time::Instant;

/// Which model's support `fishprobe support` builds, from which recordings, and how it is checked.
#[derive(Debug, Clone, PartialEq)]
pub struct SupportSettings {
    /// The model: `ConvNet` (shipped weights), a ConvNet weights file (`--model
    /// convnet:FILE`) or `onnx:FILE` (a model of the view contract).
    pub model: String,
    /// The model's training recordings (pair files; with --robot-as-partner also files of
    /// one fish with the robot). Default: guppy-pairs/legacy/train of the shared data.
    pub data: Vec<PathBuf>,
    /// Held-out recordings for the check. Default: guppy-pairs/legacy/validation.
    pub validation: Vec<PathBuf>,
    /// Estimator written to the file (`knn` or `gmm`); both are compared.
    pub estimator: Estimator,
    /// Learn from files of one fish with the robot too (the fish's frames, the robot as
    /// its neighbour).
    pub robot_as_partner: bool,
    /// The support file to write. Default: beside the weights (`FILE.support.json`); the
    /// shipped ConvNet needs an explicit path.
    pub out: Option<PathBuf>,
    /// Partners farther than this (cm) are embedded as not seen (0: every partner the view
    /// shows; see `support.partner_range_cm` in docs/settings.md).
    pub partner_range_cm: f32,
    /// Seed of the reference and calibration draws.
    pub seed: u64,
    /// Synthetic views per kind of unseen situation in the check.
    pub synthetic: usize,
    /// Print the check as JSON.
    pub json: bool,
}

impl Default for SupportSettings {
    /// The command's defaults (`fishprobe support` without flags).
    fn default() -> Self {
        Self {
            model: "ConvNet".into(),
            data: Vec::new(),
            validation: Vec::new(),
            estimator: Estimator::Knn,
            robot_as_partner: false,
            out: None,
            partner_range_cm: SupportConfig::default().partner_range_cm,
            seed: 0,
            synthetic: 2000,
            json: false,
        }
    }
}

/// The model spec a `--model` names, and the SHA-256 of its weights.
fn model_of(name: &str) -> Result<(ModelSpec, String)> {
    let spec = ModelSpec::by_name(name)?;
    let hash = match &spec {
        ModelSpec::ConvNet(p) if p.weights.is_empty() => shipped_sha256(),
        ModelSpec::ConvNet(p) => fishprobe_models::weights_sha256(p.weights.as_ref())
            .map_err(|e| ResearchError::within(format!("reading {}", p.weights), e))?,
        ModelSpec::Onnx(p) => fishprobe_models::onnx_sha256(p.path.as_ref())
            .map_err(|e| ResearchError::within(format!("reading {}", p.path), e))?,
        other => {
            return Err(ResearchError::Refused(format!(
                "`{}` is not data-driven: a support model belongs to a model fitted on recordings \
             (ConvNet, convnet:FILE, onnx:FILE)",
                other.name()
            )))
        }
    };
    // The model must load: a support for a file that is no model helps no one.
    spec.build()?;
    Ok((spec, hash))
}

/// One estimator's check.
#[derive(Debug, serde::Serialize)]
struct Check {
    /// `knn`, `gmm`, or `disagreement` (the model's ensemble, when it has one).
    estimator: String,
    build_s: f64,
    score_us_per_view: f64,
    held_out_views: usize,
    held_out_within_1: f64,
    held_out_median_score: f32,
    unseen: Vec<Unseen>,
}

#[derive(Debug, serde::Serialize)]
struct Unseen {
    kind: &'static str,
    views: usize,
    beyond_1: f64,
    median_score: f32,
    auc: f64,
}

/// Scores a view (`3 x bins`).
type ViewScore<'a> = &'a (dyn Fn(&[f32]) -> f32 + Sync);

fn scores(s: ViewScore<'_>, views: &[f32], len: usize) -> Vec<f32> {
    views
        .par_chunks(len * 1024)
        .flat_map_iter(|c| c.chunks_exact(len).map(s).collect::<Vec<_>>())
        .collect()
}

fn median(v: &[f32]) -> f32 {
    let mut v = v.to_vec();
    v.sort_by(f32::total_cmp);
    v.get(v.len() / 2).copied().unwrap_or(f32::NAN)
}

fn check(
    estimator: String,
    s: ViewScore<'_>,
    build_s: f64,
    val: &PairDataset,
    unseen: &[(&'static str, Vec<f32>)],
    len: usize,
) -> Check {
    let t = Instant::now();
    let inside = scores(s, &val.x, len);
    let per_view = t.elapsed().as_secs_f64() * 1e6 / inside.len().max(1) as f64
        * rayon::current_num_threads() as f64;
    let frac = |v: &[f32]| v.iter().filter(|&&x| x > 1.0).count() as f64 / v.len().max(1) as f64;
    Check {
        estimator,
        build_s,
        score_us_per_view: per_view,
        held_out_views: inside.len(),
        held_out_within_1: 1.0 - frac(&inside),
        held_out_median_score: median(&inside),
        unseen: unseen
            .iter()
            .map(|(kind, v)| {
                let out = scores(s, v, len);
                Unseen {
                    kind,
                    views: out.len(),
                    beyond_1: frac(&out),
                    median_score: median(&out),
                    auc: auc(&inside, &out),
                }
            })
            .collect(),
    }
}

/// Builds the support file, checks both estimators, and returns the check to show (a table,
/// or JSON with `json`); skipped recordings go to `by` as warnings.
pub fn run(a: &SupportSettings, by: Runner) -> Result<String> {
    if a.synthetic == 0 || a.synthetic > 1_000_000 {
        return Err(ResearchError::Refused(format!(
            "synthetic must lie in [1, 1000000], got {}",
            a.synthetic
        )));
    }
    SupportConfig {
        partner_range_cm: a.partner_range_cm,
        ..SupportConfig::default()
    }
    .validate()
    .map_err(|e| ResearchError::within("partner_range_cm", e))?;
    let (spec, hash) = model_of(&a.model)?;
    let out = match (&a.out, spec.support_path()?) {
        (Some(p), _) => p.clone(),
        (None, Some(p)) => p,
        (None, None) => return Err(ResearchError::Refused("the shipped ConvNet's support is shipped with it; name an output file to build another \
             (e.g. crates/models/assets/convnet.support.json)".to_string())),
    };
    let _lock = fishprobe_io::DirLock::for_file(&out, "support")?;
    let data = pairs_or_shared(&a.data, "train")?;
    let validation = pairs_or_shared(&a.validation, "validation")?;
    let arch = ConvNetArch::default();
    let clone = CloneConfig {
        robot_as_partner: a.robot_as_partner,
        ..CloneConfig::default()
    };
    let train = load_pairs(&data, &arch, &clone)
        .map_err(|e| ResearchError::within("loading the training recordings", e))?;
    let val = load_pairs(&validation, &arch, &clone)
        .map_err(|e| ResearchError::within("loading the held-out recordings", e))?;
    if let Some(f) = train.files.iter().find(|f| val.files.contains(f)) {
        return Err(ResearchError::Refused(format!(
            "{} is both training and held-out data",
            f.display()
        )));
    }
    for (f, why) in train.skipped.iter().chain(&val.skipped) {
        by.note(&format!("warning: skipped {}: {why}", f.display()));
    }
    let provenance = serde_json::json!({
        "command": by.command,
        "training_files": file_names(&train.files),
        "validation_files": file_names(&val.files),
    });
    let tank = Tank::new(&TankParams::default());
    let mut rng = fishprobe_sim::stream(a.seed, "support/synthetic", 0);
    let unseen = synthetic_views(&arch, &tank, a.synthetic, &mut rng);
    let mut checks = Vec::new();
    let mut chosen = None;
    for est in [Estimator::Knn, Estimator::Gmm] {
        let cfg = SupportConfig {
            estimator: est,
            partner_range_cm: a.partner_range_cm,
            ..SupportConfig::default()
        };
        let t = Instant::now();
        let s = build_support(
            &train,
            &arch,
            &cfg,
            &spec_label(&spec),
            &hash,
            a.seed,
            provenance.clone(),
        )?;
        let c = check(
            serde_json::to_value(est)?
                .as_str()
                .unwrap_or_default()
                .to_string(),
            &|v| s.score_view(v),
            t.elapsed().as_secs_f64(),
            &val,
            &unseen,
            arch.view_len(),
        );
        if est == a.estimator {
            chosen = Some(s);
        }
        checks.push(c);
    }
    // The model's own uncertainty, when it was fitted as an ensemble (`--members`): checked
    // the same way, not written (its file is fit-convnet's).
    if let Ok(d) = spec.disagreement() {
        let c = check(
            "disagreement".into(),
            &|v| d.score_view(v),
            0.0,
            &val,
            &unseen,
            arch.view_len(),
        );
        checks.push(c);
    }
    let mut s = chosen.ok_or_else(|| ResearchError::msg("the chosen estimator was built"))?;
    let chosen_name = serde_json::to_value(a.estimator)?;
    let chosen_check = checks.iter().find(|c| chosen_name == c.estimator.as_str());
    if let serde_json::Value::Object(m) = &mut s.provenance {
        m.insert("check".into(), serde_json::to_value(chosen_check)?);
    }
    s.save(&out)?;
    let text = if a.json {
        serde_json::to_string_pretty(&serde_json::json!({
            "model": spec_label(&spec),
            "training_views": train.len(),
            "support_file": out,
            "estimator": a.estimator,
            "checks": checks,
        }))? + "\n"
    } else {
        let head = format!(
            "support of {} from {} training views ({} files); checked on {} held-out views \
             ({} files) and {} synthetic views per unseen situation\n\n",
            spec_label(&spec),
            train.len(),
            train.files.len(),
            val.len(),
            val.files.len(),
            a.synthetic
        );
        let kinds: Vec<&str> = unseen.iter().map(|(kind, _)| *kind).collect();
        head + &checks_table(&kinds, &checks)
            + &format!(
                "\nwrote {} ({})\n",
                out.display(),
                chosen_name.as_str().unwrap_or_default()
            )
    };
    Ok(text)
}

/// The checks as a Markdown table, a column per unseen situation (`kinds`).
fn checks_table(kinds: &[&str], checks: &[Check]) -> String {
    let mut t =
        "| estimator | held-out views with score <= 1 | held-out median score |".to_string();
    for kind in kinds {
        t += &format!(" {kind}: AUC / share > 1 |");
    }
    t += " build (s) | score (µs per view and core) |\n|---|---|---|";
    t += &"---|".repeat(kinds.len());
    t += "---|---|\n";
    for c in checks {
        t += &format!(
            "| {} | {:.1} % | {:.2} |",
            c.estimator,
            100.0 * c.held_out_within_1,
            c.held_out_median_score
        );
        for u in &c.unseen {
            t += &format!(" {:.3} / {:.1} % |", u.auc, 100.0 * u.beyond_1);
        }
        t += &format!(" {:.1} | {:.1} |\n", c.build_s, c.score_us_per_view);
    }
    t
}

fn spec_label(spec: &ModelSpec) -> String {
    match spec {
        ModelSpec::ConvNet(p) if p.weights.is_empty() => "ConvNet (shipped weights)".into(),
        ModelSpec::ConvNet(p) => format!("convnet:{}", p.weights),
        ModelSpec::Onnx(p) => format!("onnx:{}", p.path),
        other => other.name().to_string(),
    }
}
