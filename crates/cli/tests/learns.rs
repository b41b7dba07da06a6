//! Does PPO learn, and are the probes competent? The `paper` preset trains one policy per
//! rule-based model (seed 0) and each is evaluated on its own model against fishprobe's
//! scripted controllers (18 episodes of 15 minutes, evaluation seed 0), as in
//! docs/validation.md, "Does it learn?" and "The fidelity sweep".
//!
//! Opt-in, about 8 minutes on 2 cores in a release build (longer while other work shares them):
//! `cargo test --release -p fishprobe --test learns -- --ignored --nocapture`.
//!
//! Each policy must reach at least 80 % of the best scripted controller's goals (issue 20's
//! bar; issue 4's was to beat the goal-seeker, which π_Follow can no longer do clearly since
//! M_Follow swims at 4 cm/s: the goal-seeker is then all but optimal). With the `paper`
//! preset's eight times the published steps at 2 epochs, the fidelity sweep measured π_Follow
//! 0.96, π_Zone 0.85 and 0.74 (seeds 0 and 1 of `fishprobe fidelity`, whose seeds differ from
//! `train --seed`), π_Force 1.18 and 1.17. **Known to fail** for π_Zone, whose competence
//! varies with the training seed: this test's seed gave 24.1 goals against fetch-and-lead's
//! 83.7 (0.29; π_Follow 63.3 against 63.9, π_Force 137.4 against 121.9; commit 0c4894a), and
//! π_Zone fell short in five of the nine seeds measured, the open part of issue 20
//! (docs/validation.md, "The fidelity sweep").

#![allow(clippy::unwrap_used)] // a failure is a test failure

mod common;

use common::{fishprobe, fresh_dir, stderr};
use std::path::Path;

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
#[ignore = "trains three paper-preset policies (about 8 minutes in a release build); run with --ignored"]
fn paper_preset_policies_learn_their_models() {
    let d = fresh_dir("learns");
    let mut failures = Vec::new();
    for model in ["Follow", "Zone", "Force"] {
        let run = d.join(format!("run-{model}"));
        let o = fishprobe(&[
            "train",
            "--model",
            model,
            "--seed",
            "0",
            "--out",
            run.to_str().unwrap(),
        ]);
        assert!(o.status.success(), "train {model}: {}", stderr(&o));
        let policy = evaluate(
            run.to_str().unwrap(),
            model,
            &d.join(format!("eval-{model}")),
        );
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
        println!("π_{model}: {policy:.1} goals per 15 min; best scripted ({best}) {baseline:.1}");
        if policy < 0.8 * baseline {
            failures.push(format!(
                "π_{model} {policy:.1} goals, under 80 % of {best}'s {baseline:.1}"
            ));
        }
    }
    let _ = std::fs::remove_dir_all(&d);
    assert!(failures.is_empty(), "{failures:?}");
}
