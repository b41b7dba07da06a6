//! Does PPO learn, and are the probes competent? The `paper` preset trains policies per
//! rule-based model (seeds 0 and 1) and each is evaluated on its own model against fishprobe's
//! scripted controllers (18 episodes of 15 minutes, evaluation seed 0), as in
//! docs/validation.md, "Does PPO learn?" and "Departures from the paper".
//!
//! Opt-in, 13 minutes on 2 cores in a release build on a fast day (792 s on 2026-11-29; longer
//! on slower days or while other work shares the cores):
//! `cargo test --release -p fishprobe --test learns -- --ignored --nocapture`.
//!
//! Each probe's goals, averaged over its two seeds, must reach at least 80 % of the best
//! scripted controller's (the competence bar; the goal-seeker alone is no bar for π_Follow,
//! since against M_Follow at 4 cm/s it is all but optimal), π_Follow must never be nearer the
//! approach assay's still fish than the goal (the paper's π_Follow), and π_Zone and π_Force
//! must go to it in every seed: closest at most 10 cm and nearer it than the goal at least
//! 10 % of the time (the paper's pattern). π_Zone's `train` seeds 0 and 1 reach 79.9 and 85.1
//! goals (0.96 and 1.02 of fetch-and-lead's 83.6) and go to the still fish (1.2 cm, 45.1 %;
//! 1.5 cm, 39.1 %; docs/validation.md, "Are the probes competent?"). One seed's ratio is not
//! enough: π_Zone's seeds range from 0.78 to 0.95 over nine, hence two seeds.

#![allow(clippy::unwrap_used)] // a failure is a test failure

mod common;

use common::{fishprobe, fresh_dir, stderr};
use std::path::Path;

/// The training seeds each probe is judged over: one seed's ratio to the best script carries
/// about ±0.04 from the episodes alone, and seeds of one probe differ by more (π_Zone without
/// M_Zone's wall pull: 0.78 in seed 0, 0.95 in seed 1, 0.78-0.95 over nine).
const SEEDS: [u64; 2] = [0, 1];

/// Mean goals per episode of an evaluation's summary.csv.
fn mean_goals(dir: &Path) -> f64 {
    let text = std::fs::read_to_string(dir.join("summary.csv")).unwrap();
    let mut lines = text.lines();
    let header: Vec<_> = lines.next().unwrap().split(',').collect();
    let col = header.iter().position(|h| *h == "goals_reached").unwrap();
    let goals: Vec<f64> = lines
        .map(|l| l.split(',').nth(col).unwrap().parse().unwrap())
        .collect();
    assert_eq!(goals.len(), 18);
    goals.iter().sum::<f64>() / goals.len() as f64
}

/// Closest robot-fish distance (cm) and share of frames nearer the fish than the goal in
/// the approach assay (`fishprobe assay approach --json`).
fn approach(policy: &str) -> (f64, f64) {
    let o = fishprobe(&["assay", "approach", "--policy", policy, "--json"]);
    assert!(o.status.success(), "assay {policy}: {}", stderr(&o));
    let j: serde_json::Value = serde_json::from_slice(&o.stdout).unwrap();
    (
        j["closest_cm"].as_f64().unwrap(),
        j["fraction_nearer_fish_than_goal"].as_f64().unwrap(),
    )
}

fn evaluate(policy: &str, model: &str, out: &Path) -> f64 {
    let o = fishprobe(&[
        "evaluate",
        "--policy",
        policy,
        "--model",
        model,
        "--episodes",
        "18",
        "--minutes",
        "15",
        "--out",
        out.to_str().unwrap(),
    ]);
    assert!(o.status.success(), "evaluate {policy}: {}", stderr(&o));
    mean_goals(out)
}

#[test]
#[ignore = "trains six paper-preset policies (13 minutes or more in a release build); run with --ignored"]
fn paper_preset_policies_learn_their_models() {
    let d = fresh_dir("learns");
    let mut failures = Vec::new();
    for model in ["Follow", "Zone", "Force"] {
        let (best, baseline) = ["goal-seeker", "fetch-and-lead"]
            .into_iter()
            .map(|c| {
                let goals = evaluate(
                    &format!("scripted:{c}"),
                    model,
                    &d.join(format!("base-{model}-{c}")),
                );
                (c, goals)
            })
            .fold(("", 0.0), |a, b| if b.1 > a.1 { b } else { a });
        let mut goals = Vec::new();
        for seed in SEEDS {
            let run = d.join(format!("run-{model}-{seed}"));
            let o = fishprobe(&[
                "train",
                "--model",
                model,
                "--seed",
                &seed.to_string(),
                "--out",
                run.to_str().unwrap(),
            ]);
            assert!(o.status.success(), "train {model}: {}", stderr(&o));
            let policy = evaluate(
                run.to_str().unwrap(),
                model,
                &d.join(format!("eval-{model}-{seed}")),
            );
            let (closest, nearer) = approach(run.to_str().unwrap());
            println!(
                "π_{model} seed {seed}: {policy:.1} goals per 15 min ({:.2} of {best}'s {baseline:.1}); approach assay: closest {closest:.1} cm, nearer the fish than the goal {:.1} %",
                policy / baseline,
                100.0 * nearer
            );
            if model == "Follow" && nearer > 0.0 {
                failures.push(format!(
                    "π_Follow seed {seed} nearer the still fish than the goal {:.1} % of the time",
                    100.0 * nearer
                ));
            }
            if model != "Follow" && (closest > 10.0 || nearer < 0.1) {
                failures.push(format!(
                    "π_{model} seed {seed} does not go to the still fish (closest {closest:.1} cm, nearer it than the goal {:.1} % of the time)",
                    100.0 * nearer
                ));
            }
            goals.push(policy);
        }
        let mean = goals.iter().sum::<f64>() / goals.len() as f64;
        if mean < 0.8 * baseline {
            failures.push(format!(
                "π_{model} {mean:.1} goals over seeds {SEEDS:?}, under 80 % of {best}'s {baseline:.1}"
            ));
        }
    }
    let _ = std::fs::remove_dir_all(&d);
    assert!(failures.is_empty(), "{failures:?}");
}
