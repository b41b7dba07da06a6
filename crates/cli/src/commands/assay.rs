//! `fishprobe assay approach`: the approach assay of SPEC §8 for one policy, so a single
//! policy's strategy can be checked without a study: does it go to the fish first?

use anyhow::{bail, Result};
use clap::{Args, Subcommand};
use fishprobe_analysis::approach::assay_files;
use fishprobe_analysis::seeds::goes_to_fish;
use fishprobe_analysis::AnalysisConfig;
use std::path::PathBuf;

use super::emit;

#[derive(Debug, Args)]
pub struct AssayArgs {
    #[command(subcommand)]
    what: AssayWhat,
}

#[derive(Debug, Subcommand)]
enum AssayWhat {
    /// The robot in a corner, a motionless fish and the goal 30 cm from the walls on either
    /// side: the closest and mean robot-fish distance and the fraction of frames the robot is
    /// nearer the fish than the goal (the paper: π_Zone and π_Force approach the fish,
    /// π_Follow does not).
    Approach(ApproachArgs),
}

#[derive(Debug, Args)]
struct ApproachArgs {
    /// The policy: a directory from `fishprobe train`, `onnx:FILE`, `scripted:goal-seeker`
    /// or `scripted:fetch-and-lead`.
    #[arg(long)]
    policy: String,
    /// Episodes (SPEC choice: 10).
    #[arg(long, default_value_t = 10)]
    episodes: usize,
    /// Minutes per episode (SPEC choice: 2).
    #[arg(long, default_value_t = 2.0)]
    minutes: f32,
    /// Master seed of the episodes.
    #[arg(long, default_value_t = 0)]
    seed: u64,
    /// Keep the episodes' trial files here (default: a temporary directory, removed after).
    #[arg(long)]
    out: Option<PathBuf>,
    /// Sample the policy's actions instead of taking its mean (RLlib's default when a policy
    /// is deployed with `compute_single_action`; a policy directory only).
    #[arg(long)]
    stochastic: bool,
    /// Print JSON instead of text.
    #[arg(long)]
    json: bool,
    /// A TOML file whose `[analysis]` table sets the verdict's thresholds
    /// (`approach_closest_cm`, `approach_nearer_share`; a study file works).
    #[arg(long)]
    settings: Option<PathBuf>,
}

pub fn run(a: AssayArgs) -> Result<()> {
    let AssayWhat::Approach(a) = a.what;
    if a.episodes == 0 || a.episodes > 10_000 {
        bail!("--episodes must lie in [1, 10000], got {}", a.episodes);
    }
    super::check_minutes("--minutes", a.minutes)?;
    let cfg = match &a.settings {
        Some(p) => super::analysis_settings(&AnalysisConfig::default(), p)?,
        None => AnalysisConfig::default(),
    };
    let c = super::policy_controller(&a.policy, a.stochastic)?;
    // The still fish is observed as the policy was trained to observe: with the group's
    // centroid bins when it takes those, as a study's approach step does.
    // A policy that records its observation settings is given them; for one that records
    // none (ONNX, or trained before fishprobe recorded them) the length tells.
    let obs = match c.trained_observation() {
        Some(t) => t,
        None => {
            let mut obs = fishprobe_sim::ObservationParams::default();
            if let Err(why) = c.check_observation(obs.size()) {
                obs.centroid_bins = true;
                if c.check_observation(obs.size()).is_err() {
                    bail!("--policy {}: {why}", a.policy);
                }
            }
            obs
        }
    };
    let temporary = a.out.is_none();
    let out = a.out.clone().unwrap_or_else(|| {
        std::env::temp_dir().join(format!("fishprobe-assay-{}", std::process::id()))
    });
    // Without --out the trial files are scratch: removed however the assay ends, an error
    // included (declared before the lock, so the lock is released first).
    let _scratch = temporary.then(|| fishprobe_io::ScratchDir::remove_on_drop(out.clone()));
    let _lock = super::lock_out(&out, "assay approach")?;
    let mut e = fishprobe_learn::approach_assay(a.episodes, a.minutes, a.seed, out.clone())?;
    if !temporary {
        // Another assay's episodes there would be overwritten in part and mixed with these.
        fishprobe_learn::evaluate::check_fresh_output(&out, &e.prefix)?;
    }
    e.env.observation = obs;
    let results = super::with_jobs(None, || fishprobe_learn::evaluate(c.as_ref(), &e))??;
    let files: Vec<PathBuf> = results.iter().map(|r| r.file.clone()).collect();
    let r = assay_files(&files, &cfg)?;
    let goes = goes_to_fish(&r, &cfg);
    let text = if a.json {
        serde_json::to_string_pretty(&serde_json::json!({
            "policy": c.describe(),
            "episodes": r.episodes,
            "minutes": a.minutes,
            "seed": a.seed,
            "stochastic": a.stochastic,
            "closest_cm": r.min_iid,
            "mean_distance_cm": r.mean_iid,
            "fraction_nearer_fish_than_goal": r.frac_closer_to_fish,
            "goes_to_fish": goes,
            "thresholds": {
                "closest_cm": cfg.approach_closest_cm,
                "nearer_share": cfg.approach_nearer_share,
            },
        }))? + "\n"
    } else {
        format!(
            "approach assay of {}{}: closest {:.1} cm, mean {:.1} cm from the fish; nearer the fish than the goal in {:.1} % of frames ({} episode{} of {} min, seed {})\n{} (the paper's pattern: closest at most {} cm and nearer the fish in at least {:.0} % of frames)\n",
            c.describe(),
            if a.stochastic { " (sampled actions)" } else { "" },
            r.min_iid,
            r.mean_iid,
            100.0 * r.frac_closer_to_fish,
            r.episodes,
            if r.episodes == 1 { "" } else { "s" },
            a.minutes,
            a.seed,
            if goes {
                "goes to the still fish"
            } else {
                "does not go to the still fish"
            },
            cfg.approach_closest_cm,
            100.0 * cfg.approach_nearer_share,
        )
    };
    emit(&text)
}
