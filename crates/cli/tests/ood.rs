//! The OOD objective from the command line: the in-silico loop with tiny budgets
//! (narrow virtual-guppy data, M_ConvNet and its support, an OOD and a lead-to-goal policy,
//! refits, gaps), in one and two rounds and with an ensemble's disagreement; the report of what
//! the OOD policy finds; a reward measured against a lead-to-goal policy's yardstick; the
//! support command; and the refusals: a model that is not data-driven, a missing support
//! file, a support file of other weights, settings out of range.
//!
//! The one-round loop is made once per test binary ([`one_round`]) and only read by the tests
//! that use it; a test that changes a loop's files runs its own.

#![allow(clippy::unwrap_used)] // a failure is a test failure

mod common;

use common::{fishprobe, fresh_dir, stderr, stdout, Scratch};
use std::path::{Path, PathBuf};
use std::sync::OnceLock;

const TINY: &str = r#"
narrow_episodes = 2
validation_episodes = 1
new_episodes = 1
episode_minutes = 0.5
ppo_preset = "smoke"
train_steps = 1500
fit_max_epochs = 1
gap_episodes = 1
gap_minutes = 0.5
support_partner_range_cm = 15.0
"#;

fn s(p: &Path) -> &str {
    p.to_str().unwrap()
}

/// `fishprobe support` for the weights `weights` fitted in the loop's `seed_dir`, on its narrow
/// and validation recordings, with 50 synthetic views per situation, written to `out`.
fn support_command(
    weights: &Path,
    seed_dir: &Path,
    out: &Path,
    extra: &[&str],
) -> std::process::Output {
    let model = format!("convnet:{}", s(weights));
    let (data, validation) = (
        seed_dir.join("data/narrow"),
        seed_dir.join("data/validation"),
    );
    let mut args = vec![
        "support",
        "--model",
        &model,
        "--data",
        s(&data),
        "--validation",
        s(&validation),
        "--robot-as-partner",
        "--synthetic",
        "50",
        "--out",
        s(out),
    ];
    args.extend_from_slice(extra);
    fishprobe(&args)
}

/// `fishprobe ood-loop` of seed 5 into `out` with the settings file `cfg`.
fn loop_args<'a>(out: &'a Path, cfg: &'a Path) -> [&'a str; 7] {
    [
        "ood-loop",
        "--out",
        s(out),
        "--seeds",
        "5",
        "--config",
        s(cfg),
    ]
}

/// A finished one-round loop of [`TINY`]: its directory, the table it printed, its
/// `loop.json`.
struct Loop {
    out: PathBuf,
    table: String,
    json: serde_json::Value,
}

impl Loop {
    /// Runs the loop of `settings` into `dir/loop` (`dir/loop.toml` its settings file).
    fn run(dir: &Path, settings: &str) -> Self {
        let cfg = dir.join("loop.toml");
        std::fs::write(&cfg, settings).unwrap();
        let out = dir.join("loop");
        let o = fishprobe(&loop_args(&out, &cfg));
        assert!(o.status.success(), "{}", stderr(&o));
        let json = serde_json::from_slice(&std::fs::read(out.join("loop.json")).unwrap()).unwrap();
        Self {
            out,
            table: stdout(&o),
            json,
        }
    }

    /// The seed's directory: its data, models and policies.
    fn seed_dir(&self) -> PathBuf {
        self.out.join("seed-5")
    }

    /// The narrow model's weights (its support file beside them).
    fn weights(&self) -> PathBuf {
        self.seed_dir().join("model-narrow/convnet.safetensors")
    }

    /// The seed's row of `loop.json`.
    fn seed(&self) -> &serde_json::Value {
        &self.json["seeds"][0]
    }
}

/// The one-round loop of [`TINY`], made once per test binary; the tests only read it.
fn one_round() -> &'static Loop {
    static LOOP: OnceLock<Loop> = OnceLock::new();
    LOOP.get_or_init(|| Loop::run(&Scratch::for_process("e2e-ood-loop"), TINY))
}

#[test]
fn the_loop_measures_every_gap_resumes_and_refuses_other_settings() {
    // Its own loop: this test changes the loop's files.
    let dir = fresh_dir("ood-loop-own");
    let lp = Loop::run(&dir, TINY);
    let (out, cfg, text, seed) = (&lp.out, dir.join("loop.toml"), lp.table.as_str(), lp.seed());
    let loop_args = loop_args(out, &cfg);
    assert!(text.contains("| 5 |") && text.contains("seeds"), "{text}");
    // One seed gives no spread to judge the paired difference by, and the table says so.
    assert!(
        text.contains("| (one seed) |") && !text.contains("p = "),
        "{text}"
    );
    for k in ["narrow", "after_goal_data", "after_ood_data"] {
        let g = seed[k]["metrics"].as_f64().unwrap();
        assert!(g.is_finite() && g >= 0.0, "{k}: {g}");
    }
    // The further gap probes (the default two): measured, in the JSON and in the table.
    let more = seed["more_probes"].as_array().unwrap();
    let names: Vec<&str> = more.iter().map(|p| p["probe"].as_str().unwrap()).collect();
    assert_eq!(names, ["scripted:goal-seeker", "scripted:random"]);
    for p in more {
        let g = p["after_ood_data"]["metrics"].as_f64().unwrap();
        assert!(g.is_finite() && g >= 0.0, "{p}");
    }
    assert!(text.contains("| scripted:random |") && text.contains("mean over the probes"));
    let seed_dir = out.join("seed-5");
    for name in ["guppy", "narrow", "after-goal", "after-ood"] {
        assert!(seed_dir
            .join("gap/probe-scripted-random")
            .join(name)
            .join("summary.csv")
            .is_file());
    }
    let support = seed_dir.join("model-narrow/convnet.safetensors.support.json");
    assert!(
        support.is_file(),
        "fit-convnet writes the support beside the weights"
    );
    let f: serde_json::Value = serde_json::from_slice(&std::fs::read(&support).unwrap()).unwrap();
    assert_eq!(
        f["config"]["partner_range_cm"], 15.0,
        "the loop's partner range"
    );
    // The loop resumes: a second call finds every stage done and prints the same table.
    let o2 = fishprobe(&loop_args);
    assert!(o2.status.success(), "{}", stderr(&o2));
    assert_eq!(stdout(&o2), text);
    // A loop recorded before a setting existed (its settings.json lacks the field) resumes
    // when the run keeps that setting's default.
    let recorded = out.join("settings.json");
    let mut old: serde_json::Value =
        serde_json::from_slice(&std::fs::read(&recorded).unwrap()).unwrap();
    for field in ["gap_probe", "more_gap_probes"] {
        assert!(old.as_object_mut().unwrap().remove(field).is_some());
    }
    std::fs::write(&recorded, serde_json::to_string_pretty(&old).unwrap()).unwrap();
    let o3 = fishprobe(&loop_args);
    assert!(o3.status.success(), "{}", stderr(&o3));
    assert_eq!(stdout(&o3), text);
    // A policy that another trainer revision trained is not compared with this one's.
    let params = seed_dir.join("policy-ood/params.json");
    let kept = std::fs::read(&params).unwrap();
    let mut p: serde_json::Value = serde_json::from_slice(&kept).unwrap();
    p["trainer_revision"] = 1.into();
    std::fs::write(&params, p.to_string()).unwrap();
    let o = fishprobe(&loop_args);
    assert!(!o.status.success());
    assert!(
        stderr(&o)
            .contains("the loop was begun by another fishprobe; use another output directory")
            && stderr(&o).contains("started by trainer revision 1"),
        "{}",
        stderr(&o)
    );
    std::fs::write(&params, kept).unwrap();
    // Other settings into the same directory: refused.
    std::fs::write(&cfg, TINY.replace("new_episodes = 1", "new_episodes = 2")).unwrap();
    let o = fishprobe(&loop_args);
    assert!(!o.status.success());
    assert!(stderr(&o).contains("other settings"), "{}", stderr(&o));
    // A gap probe that is not one, one listed twice, a partner range out of range: each
    // refused by name before anything runs.
    for (settings, says) in [
        (format!("{TINY}ensemble_members = 1\n"), "ensemble_members"),
        (
            format!("{TINY}more_gap_probes = [\"scripted:dance\"]\n"),
            "scripted:dance",
        ),
        (
            format!("{TINY}more_gap_probes = [\"scripted:random\", \"scripted:random\"]\n"),
            "listed twice",
        ),
        (
            format!("{TINY}more_gap_probes = [\"scripted:fetch-and-lead\"]\n"),
            "listed twice",
        ),
        (TINY.replace("= 15.0", "= -1.0"), "support_partner_range_cm"),
        (TINY.replace("= 15.0", "= 1e30"), "support_partner_range_cm"),
    ] {
        std::fs::write(&cfg, &settings).unwrap();
        let o = fishprobe(&[
            "ood-loop",
            "--out",
            s(&dir.join("never")),
            "--config",
            s(&cfg),
        ]);
        assert!(!o.status.success());
        assert!(stderr(&o).contains(says), "{settings}: {}", stderr(&o));
    }
    assert!(!dir.join("never").exists());
}

#[test]
fn two_rounds_train_and_refit_again_on_both_rounds() {
    let dir = fresh_dir("ood-rounds");
    let seed = one_round().seed();
    // Two rounds: each chain trains again against its own refitted model, records as much
    // again and refits on the narrow data plus both rounds' recordings.
    let cfg2 = dir.join("rounds.toml");
    std::fs::write(&cfg2, format!("{TINY}rounds = 2\n")).unwrap();
    let out2 = dir.join("loop2");
    let o = fishprobe(&[
        "ood-loop",
        "--out",
        s(&out2),
        "--seeds",
        "5",
        "--config",
        s(&cfg2),
    ]);
    assert!(o.status.success(), "{}", stderr(&o));
    assert!(stdout(&o).contains("2 rounds"), "{}", stdout(&o));
    let j2: serde_json::Value =
        serde_json::from_slice(&std::fs::read(out2.join("loop.json")).unwrap()).unwrap();
    assert_eq!(
        j2["seeds"][0]["later_rounds_ood_share"]
            .as_array()
            .unwrap()
            .len(),
        1
    );
    for chain in ["ood", "goal"] {
        let fit = out2.join(format!("seed-5/model-{chain}-r2/convnet.safetensors.json"));
        let fit: serde_json::Value = serde_json::from_slice(&std::fs::read(fit).unwrap()).unwrap();
        // 2 narrow episodes and 1 per round.
        assert_eq!(
            fit["training_files"].as_array().unwrap().len(),
            4,
            "{chain}"
        );
        assert!(out2
            .join(format!("seed-5/policy-{chain}-r2/policy.safetensors"))
            .is_file());
    }
    // The narrow model is the same data and fit: its gap is the one-round loop's.
    assert_eq!(j2["seeds"][0]["narrow"], seed["narrow"]);
}

#[test]
fn an_ensembles_disagreement_rewards_the_policy_and_is_reported() {
    let dir = fresh_dir("ood-disagreement");
    let (seed, weights) = (one_round().seed(), one_round().weights());
    // The OOD policy rewarded by an ensemble's disagreement: the narrow model is fitted as an
    // ensemble (its own network unchanged, so the narrow gap is the one above), the policy
    // trains against it, and the table says so.
    let cfg3 = dir.join("disagreement.toml");
    std::fs::write(
        &cfg3,
        format!("{TINY}ood_score = \"disagreement\"\nensemble_members = 2\n"),
    )
    .unwrap();
    let out3 = dir.join("loop3");
    let loop3 = [
        "ood-loop",
        "--out",
        s(&out3),
        "--seeds",
        "5",
        "--config",
        s(&cfg3),
    ];
    let o = fishprobe(&loop3);
    assert!(o.status.success(), "{}", stderr(&o));
    assert!(stdout(&o).contains("disagreement of an ensemble of 2"));
    let narrow3 = out3.join("seed-5/model-narrow/convnet.safetensors");
    let d: serde_json::Value = serde_json::from_slice(
        &std::fs::read(out3.join("seed-5/model-narrow/convnet.safetensors.disagreement.json"))
            .unwrap(),
    )
    .unwrap();
    assert_eq!(d["members"].as_array().unwrap().len(), 1);
    assert!(out3
        .join("seed-5/model-narrow/convnet.safetensors.member-2.safetensors")
        .is_file());
    let p: serde_json::Value =
        serde_json::from_slice(&std::fs::read(out3.join("seed-5/policy-ood/params.json")).unwrap())
            .unwrap();
    assert_eq!(p["env"]["task"]["ood_score"], "disagreement");
    let j3: serde_json::Value =
        serde_json::from_slice(&std::fs::read(out3.join("loop.json")).unwrap()).unwrap();
    assert_eq!(j3["seeds"][0]["narrow"], seed["narrow"]);
    // A loop stopped inside an ensemble's fit (its disagreement file not yet written) fits it
    // again keeping the finished networks: the same bytes, the same tables.
    let member = out3.join("seed-5/model-narrow/convnet.safetensors.member-2.safetensors");
    let nets = || {
        (
            std::fs::read(&narrow3).unwrap(),
            std::fs::read(&member).unwrap(),
        )
    };
    let before = nets();
    let written = || std::fs::metadata(&member).unwrap().modified().unwrap();
    let member_written = written();
    let dis = out3.join("seed-5/model-narrow/convnet.safetensors.disagreement.json");
    std::fs::remove_file(&dis).unwrap();
    let again = fishprobe(&loop3);
    assert!(again.status.success(), "{}", stderr(&again));
    assert!(dis.is_file());
    assert!(nets() == before);
    assert_eq!(
        written(),
        member_written,
        "the finished member was fitted again"
    );
    assert_eq!(stdout(&again), stdout(&o));
    // The lead-to-goal chain's model is no ensemble.
    assert!(!out3
        .join("seed-5/model-goal/convnet.safetensors.disagreement.json")
        .exists());
    // The support command checks the ensemble's disagreement beside the two estimators.
    let o = support_command(
        &narrow3,
        &out3.join("seed-5"),
        &dir.join("support3.json"),
        &["--json"],
    );
    assert!(o.status.success(), "{}", stderr(&o));
    let c: serde_json::Value = serde_json::from_str(&stdout(&o)).unwrap();
    let names: Vec<&str> = c["checks"]
        .as_array()
        .unwrap()
        .iter()
        .map(|c| c["estimator"].as_str().unwrap())
        .collect();
    assert_eq!(names, ["knn", "gmm", "disagreement"]);
    // ood-report scores the views by the ensemble's disagreement too.
    let rep3 = dir.join("report3");
    let o = fishprobe(&[
        "ood-report",
        "--policy",
        s(&out3.join("seed-5/policy-ood")),
        "--data",
        s(&out3.join("seed-5/data/narrow")),
        "--episodes",
        "1",
        "--minutes",
        "0.5",
        "--out",
        s(&rep3),
        "--json",
    ]);
    assert!(o.status.success(), "{}", stderr(&o));
    let r3: serde_json::Value = serde_json::from_str(&stdout(&o)).unwrap();
    assert_eq!(r3["disagreement"]["members"], 2);
    let dists = r3["disagreement"]["distributions"].as_array().unwrap();
    // The training recordings and both policies, as many views as the support scored.
    assert_eq!(dists.len(), 3);
    for (a, b) in dists.iter().zip(r3["distributions"].as_array().unwrap()) {
        assert_eq!(a["views"], b["views"], "{a} {b}");
    }
    let share = r3["disagreement"]["ood_share_beyond_goal_p95"]
        .as_f64()
        .unwrap();
    assert!((0.0..=1.0).contains(&share), "{share}");
    let md = std::fs::read_to_string(rep3.join("report.md")).unwrap();
    assert!(md.contains("## The ensemble's disagreement"), "{md}");
    // A yardstick in the disagreement's own scale: measured by the ensemble on the yardstick
    // episodes, it is the reward's floor and the report's disagreement yardstick.
    let ds = dir.join("ds.toml");
    std::fs::write(&ds, "[env.task]\nood_score = \"disagreement\"\n").unwrap();
    let model = format!("convnet:{}", s(&narrow3));
    let yard_dis = dir.join("yard-dis");
    let o = fishprobe(&[
        "train",
        "--model",
        &model,
        "--task",
        "ood",
        "--preset",
        "smoke",
        "--steps",
        "500",
        "--settings",
        s(&ds),
        "--ood-yardstick",
        "scripted:goal-seeker",
        "--ood-yardstick-episodes",
        "1",
        "--ood-yardstick-minutes",
        "0.5",
        "--out",
        s(&yard_dis),
    ]);
    assert!(o.status.success(), "{}", stderr(&o));
    assert!(
        stderr(&o).contains("disagreement score is"),
        "{}",
        stderr(&o)
    );
    let y: serde_json::Value =
        serde_json::from_slice(&std::fs::read(yard_dis.join("yardstick.json")).unwrap()).unwrap();
    assert_eq!(y["ood_score"], "disagreement");
    let t = y["score"].as_f64().unwrap();
    let p: serde_json::Value =
        serde_json::from_slice(&std::fs::read(yard_dis.join("params.json")).unwrap()).unwrap();
    let floor = p["env"]["task"]["ood_score_floor"].as_f64().unwrap();
    assert!(
        (floor - t.max(0.0)).abs() < 1e-6,
        "floor {floor}, score {t}"
    );
    let o = fishprobe(&[
        "ood-report",
        "--policy",
        s(&yard_dis),
        "--compare",
        "scripted:goal-seeker",
        "--data",
        s(&out3.join("seed-5/data/narrow")),
        "--episodes",
        "1",
        "--minutes",
        "0.5",
        "--out",
        s(&dir.join("yard-dis-report")),
        "--json",
    ]);
    assert!(o.status.success(), "{}", stderr(&o));
    let r: serde_json::Value = serde_json::from_str(&stdout(&o)).unwrap();
    let ours = r["disagreement"]["goal_policy_p95"].as_f64().unwrap();
    assert!(
        (ours - t).abs() < 1e-9,
        "the report's {ours}, the reward's {t}"
    );
    let md = std::fs::read_to_string(dir.join("yard-dis-report/report.md")).unwrap();
    assert!(!md.contains("counted time beyond"), "{md}");
    // A member that is not the file it was fitted as: refused by name when a policy would
    // train against the ensemble.
    let member = out3.join("seed-5/model-narrow/convnet.safetensors.member-2.safetensors");
    let mut bytes = std::fs::read(&member).unwrap();
    let last = bytes.len() - 1;
    bytes[last] ^= 1;
    std::fs::write(&member, bytes).unwrap();
    let o = fishprobe(&[
        "train",
        "--model",
        &model,
        "--task",
        "ood",
        "--preset",
        "smoke",
        "--settings",
        s(&ds),
        "--out",
        s(&dir.join("never-ds")),
    ]);
    assert!(!o.status.success());
    assert!(
        stderr(&o).contains("member-2") && stderr(&o).contains("SHA-256"),
        "{}",
        stderr(&o)
    );
    // Weights with no ensemble: the error says how to make one.
    let o = fishprobe(&[
        "train",
        "--model",
        &format!("convnet:{}", s(&weights)),
        "--task",
        "ood",
        "--preset",
        "smoke",
        "--settings",
        s(&ds),
        "--out",
        s(&dir.join("never-ds")),
    ]);
    assert!(!o.status.success());
    assert!(stderr(&o).contains("--members"), "{}", stderr(&o));
    assert!(!dir.join("never-ds").exists());
}

#[test]
fn the_report_finds_what_the_policy_does_and_scores_recorded_trials_the_same() {
    let dir = fresh_dir("ood-report");
    let seed_dir = one_round().seed_dir();
    // What the OOD policy finds.
    let report = dir.join("report");
    let report_of = |episodes: &str| {
        fishprobe(&[
            "ood-report",
            "--policy",
            s(&seed_dir.join("policy-ood")),
            "--compare",
            s(&seed_dir.join("policy-goal")),
            "--data",
            s(&seed_dir.join("data/narrow")),
            "--episodes",
            episodes,
            "--minutes",
            "0.5",
            "--out",
            s(&report),
        ])
    };
    let o = report_of("2");
    assert!(o.status.success(), "{}", stderr(&o));
    assert!(stdout(&o).contains("Data wishlist"), "{}", stdout(&o));
    for f in [
        "report.md",
        "ood.json",
        "ood-scores.png",
        "ood-trajectories.png",
    ] {
        assert!(report.join(f).is_file(), "{f} missing");
    }
    let r: serde_json::Value =
        serde_json::from_slice(&std::fs::read(report.join("ood.json")).unwrap()).unwrap();
    // Training recordings, the OOD policy, the lead-to-goal policy.
    assert_eq!(r["distributions"].as_array().unwrap().len(), 3);
    let share = r["ood_share_beyond_goal_p95"].as_f64().unwrap();
    assert!((0.0..=1.0).contains(&share), "{share}");
    // Its interval over the (two) episodes of each policy holds it.
    let interval: Vec<f64> = serde_json::from_value(r["ood_share_interval"].clone()).unwrap();
    assert!(
        interval.len() == 2 && interval[0] <= share && share <= interval[1],
        "{interval:?} {share}"
    );
    assert_eq!(r["recorded_trials"], serde_json::json!([null, null]));
    assert!(
        r.get("disagreement").is_none(),
        "no ensemble, no disagreement: {r}"
    );

    // A second report into the same --out would overwrite some of these episodes and leave
    // the rest beside its own: refused.
    let o = report_of("1");
    assert!(
        !o.status.success()
            && stderr(&o).contains("episodes/ood: already holds an evaluation (2 trial files"),
        "{}",
        stderr(&o)
    );

    // Recorded trials (here: the report's own episodes, as live trials would be given) are
    // scored exactly as the episodes were when simulated.
    let rescored = dir.join("report-recorded");
    let o = fishprobe(&[
        "ood-report",
        "--trials",
        s(&report.join("episodes/ood")),
        "--compare-trials",
        s(&report.join("episodes/goal/goal_000.hdf5")),
        s(&report.join("episodes/goal/goal_001.hdf5")),
        "--policy",
        s(&seed_dir.join("policy-ood")),
        "--data",
        s(&seed_dir.join("data/narrow")),
        "--out",
        s(&rescored),
    ]);
    assert!(o.status.success(), "{}", stderr(&o));
    let rr: serde_json::Value =
        serde_json::from_slice(&std::fs::read(rescored.join("ood.json")).unwrap()).unwrap();
    assert_eq!(rr["recorded_trials"], serde_json::json!([2, 2]));
    for k in [
        "goal_policy_p95",
        "ood_share_beyond_goal_p95",
        "ood_share_interval",
        "goals_per_episode",
        "wishlist",
    ] {
        assert_eq!(rr[k], r[k], "{k}");
    }
    for (a, b) in rr["distributions"]
        .as_array()
        .unwrap()
        .iter()
        .zip(r["distributions"].as_array().unwrap())
    {
        for k in ["views", "median", "p95", "beyond_support"] {
            assert_eq!(a[k], b[k], "{k}");
        }
    }
    let md = std::fs::read_to_string(rescored.join("report.md")).unwrap();
    assert!(
        md.contains("2 recorded trials of") && md.contains("--trials"),
        "{md}"
    );
    let empty = dir.join("no-trials");
    std::fs::create_dir_all(&empty).unwrap();
    let o = fishprobe(&[
        "ood-report",
        "--trials",
        s(&empty),
        "--model",
        "ConvNet",
        "--out",
        s(&dir.join("never-report")),
    ]);
    assert!(
        !o.status.success() && stderr(&o).contains("no trial files"),
        "{}",
        stderr(&o)
    );
    assert!(
        !dir.join("never-report").exists(),
        "a refused report leaves no --out behind"
    );
}

#[test]
fn a_yardstick_from_a_lead_to_goal_policy_sets_the_reward_and_the_report() {
    let dir = fresh_dir("ood-yardstick");
    let (seed_dir, weights) = (one_round().seed_dir(), one_round().weights());
    // A reward that counts time beyond a lead-to-goal policy's 95th percentile: measured before
    // training on `ood-report`'s episodes, so the report's yardstick is the reward's floor.
    let good = format!("convnet:{}", s(&weights));
    let goal_policy = seed_dir.join("policy-goal");
    let yard_run = dir.join("yard-run");
    let yard_args = |out: &Path, extra: &[&str]| {
        let mut args: Vec<String> = [
            "train",
            "--model",
            &good,
            "--task",
            "ood",
            "--preset",
            "smoke",
            "--steps",
            "500",
            "--ood-yardstick",
            s(&goal_policy),
            "--ood-yardstick-episodes",
            "2",
            "--ood-yardstick-minutes",
            "0.5",
            "--out",
            s(out),
        ]
        .map(String::from)
        .to_vec();
        args.extend(extra.iter().map(|a| a.to_string()));
        args
    };
    let run_with =
        |args: Vec<String>| fishprobe(&args.iter().map(String::as_str).collect::<Vec<_>>());
    let o = run_with(yard_args(&yard_run, &["--ood-yardstick-band", "0.2"]));
    assert!(o.status.success(), "{}", stderr(&o));
    let y: serde_json::Value =
        serde_json::from_slice(&std::fs::read(yard_run.join("yardstick.json")).unwrap()).unwrap();
    let t = y["score"].as_f64().unwrap();
    let p: serde_json::Value =
        serde_json::from_slice(&std::fs::read(yard_run.join("params.json")).unwrap()).unwrap();
    let task = &p["env"]["task"];
    let floor = task["ood_score_floor"].as_f64().unwrap();
    assert!(
        (floor - t.max(0.0)).abs() < 1e-6,
        "floor {floor}, score {t}"
    );
    assert!((task["ood_score_cap"].as_f64().unwrap() - (floor + 0.2)).abs() < 1e-5);
    assert!((task["ood_weight"].as_f64().unwrap() - 5.0).abs() < 1e-5);
    assert!(yard_run.join("yardstick/yardstick_000.hdf5").is_file());
    let yard_report = dir.join("yard-report");
    let o = fishprobe(&[
        "ood-report",
        "--policy",
        s(&yard_run),
        "--compare",
        s(&goal_policy),
        "--episodes",
        "2",
        "--minutes",
        "0.5",
        "--out",
        s(&yard_report),
    ]);
    assert!(o.status.success(), "{}", stderr(&o));
    let r: serde_json::Value =
        serde_json::from_slice(&std::fs::read(yard_report.join("ood.json")).unwrap()).unwrap();
    assert!(
        (r["goal_policy_p95"].as_f64().unwrap() - t).abs() < 1e-9,
        "the report's yardstick {} is the reward's {t}",
        r["goal_policy_p95"]
    );
    assert!(
        !stdout(&o).contains("counted time beyond"),
        "{}",
        stdout(&o)
    );
    // Measured against another yardstick, the report says what the reward counted.
    let o = fishprobe(&[
        "ood-report",
        "--policy",
        s(&yard_run),
        "--compare",
        "scripted:goal-seeker",
        "--episodes",
        "1",
        "--minutes",
        "0.5",
        "--out",
        s(&dir.join("yard-report-2")),
    ]);
    assert!(o.status.success(), "{}", stderr(&o));
    assert!(
        stdout(&o).contains(&format!("counted time beyond a support score of {t:.3}")),
        "{}",
        stdout(&o)
    );
    // Refused before anything runs: a band out of range, the goal task, a used directory.
    let o = run_with(yard_args(
        &dir.join("yard-bad"),
        &["--ood-yardstick-band", "0"],
    ));
    assert!(
        !o.status.success() && stderr(&o).contains("band"),
        "{}",
        stderr(&o)
    );
    // Refused before its directory is made: nothing left behind.
    assert!(!dir.join("yard-bad").exists());
    let mut missing = yard_args(&dir.join("yard-missing"), &[]);
    missing[10] = s(&dir.join("no-such-policy")).to_string();
    let o = run_with(missing);
    assert!(
        !o.status.success() && stderr(&o).contains("no-such-policy"),
        "{}",
        stderr(&o)
    );
    assert!(!dir.join("yard-missing").exists());
    let mut goal_task = yard_args(&dir.join("yard-goal"), &[]);
    goal_task[4] = "goal".into();
    let o = run_with(goal_task);
    assert!(stderr(&o).contains("--task ood only"), "{}", stderr(&o));
    assert!(!dir.join("yard-goal").exists());
    let o = run_with(yard_args(&yard_run, &[]));
    assert!(
        stderr(&o).contains("already holds a training run"),
        "{}",
        stderr(&o)
    );
    // A corrupt yardstick record is refused by name before any episode runs.
    std::fs::write(yard_run.join("yardstick.json"), b"{\"score\": \"high\"}").unwrap();
    let bad_report = dir.join("yard-report-bad");
    let o = fishprobe(&[
        "ood-report",
        "--policy",
        s(&yard_run),
        "--episodes",
        "1",
        "--minutes",
        "0.5",
        "--out",
        s(&bad_report),
    ]);
    assert!(
        !o.status.success() && stderr(&o).contains("yardstick.json"),
        "{}",
        stderr(&o)
    );
    assert!(!bad_report.join("episodes").exists());
}

/// An OOD run of the smoke preset under the settings `settings` (a settings file's text), its
/// reward's yardstick the one-round loop's lead-to-goal policy; it must succeed. Returns the
/// run and that policy.
fn ood_run(dir: &Path, settings: &str) -> (PathBuf, PathBuf) {
    let (seed_dir, weights) = (one_round().seed_dir(), one_round().weights());
    let good = format!("convnet:{}", s(&weights));
    let goal_policy = seed_dir.join("policy-goal");
    let file = dir.join("settings.toml");
    std::fs::write(&file, settings).unwrap();
    let run = dir.join("run");
    let o = fishprobe(&[
        "train",
        "--model",
        &good,
        "--task",
        "ood",
        "--preset",
        "smoke",
        "--steps",
        "500",
        "--settings",
        s(&file),
        "--ood-yardstick",
        s(&goal_policy),
        "--ood-yardstick-episodes",
        "1",
        "--ood-yardstick-minutes",
        "0.5",
        "--out",
        s(&run),
    ]);
    assert!(o.status.success(), "{}", stderr(&o));
    (run, goal_policy)
}

/// `ood-report` of `run` against `goal_policy`, one short episode; it must succeed.
fn ood_report(dir: &Path, run: &Path, goal_policy: &Path) {
    let o = fishprobe(&[
        "ood-report",
        "--policy",
        s(run),
        "--compare",
        s(goal_policy),
        "--episodes",
        "1",
        "--minutes",
        "0.5",
        "--out",
        s(&dir.join("report")),
    ]);
    assert!(o.status.success(), "{}", stderr(&o));
}

/// `evaluate` of `run` on M_Zone under the default settings.
fn evaluate_on_zone(dir: &Path, run: &Path) -> std::process::Output {
    fishprobe(&[
        "evaluate",
        "--policy",
        s(run),
        "--model",
        "Zone",
        "--episodes",
        "1",
        "--minutes",
        "0.1",
        "--out",
        s(&dir.join("eval")),
    ])
}

/// The `about` record beside a trained policy's weights.
fn policy_about(policy: &Path) -> serde_json::Value {
    let meta: serde_json::Value =
        serde_json::from_slice(&std::fs::read(policy.join("policy.safetensors.json")).unwrap())
            .unwrap();
    meta["about"].clone()
}

/// One short virtual-lab trial of `policy` into `dir/out`, with `extra` arguments.
fn lab_trial(dir: &Path, policy: &Path, out: &str, extra: &[&str]) -> std::process::Output {
    let out = dir.join(out);
    let mut args = vec![
        "lab",
        "--policy",
        s(policy),
        "--trials",
        "1",
        "--minutes",
        "0.1",
        "--out",
        s(&out),
    ];
    args.extend(extra);
    fishprobe(&args)
}

/// Asserts that a command failed with a message that holds `needle`.
fn assert_refused(o: &std::process::Output, needle: &str) {
    assert!(
        !o.status.success() && stderr(o).contains(needle),
        "expected a refusal naming {needle:?}: {}",
        stderr(o)
    );
}

#[test]
fn an_ood_policy_that_observes_headings_is_measured_against_a_yardstick_that_does_not() {
    let dir = fresh_dir("ood-heading");
    // The yardstick policy reads the paper's 180 values, the OOD policy 216: each observes as
    // it was trained to.
    let (run, goal_policy) = ood_run(&dir, "[env.observation]\nheading_bins = true\n");
    let meta: serde_json::Value =
        serde_json::from_slice(&std::fs::read(run.join("policy.safetensors.json")).unwrap())
            .unwrap();
    assert_eq!(meta["obs_dim"], 216);
    assert_eq!(policy_about(&run)["observation"]["heading_bins"], true);
    ood_report(&dir, &run, &goal_policy);
    // The approach assay observes its still fish as the policy records.
    let o = fishprobe(&[
        "assay",
        "approach",
        "--policy",
        s(&run),
        "--episodes",
        "1",
        "--minutes",
        "0.2",
        "--json",
    ]);
    assert!(o.status.success(), "{}", stderr(&o));
    // Elsewhere a policy runs only with the settings it was trained with: evaluation names
    // them, and the virtual lab refuses it unless its settings give the headings.
    assert_refused(
        &evaluate_on_zone(&dir, &run),
        "heading_bins = true (216 floats)",
    );
    assert_refused(
        &lab_trial(&dir, &run, "lab-refused", &[]),
        "heading_bins = true",
    );
    // The bridge observes the tracked headings when its settings say so.
    let o = lab_trial(&dir, &run, "lab", &["--heading-bins"]);
    assert!(o.status.success(), "{}", stderr(&o));
}

#[test]
fn an_ood_policy_that_acts_five_times_a_second_is_measured_against_a_yardstick_that_acts_once() {
    let dir = fresh_dir("ood-rate");
    // The yardstick policy was trained at the paper's 1 Hz: run every 5 frames it would be
    // refused, so the run's success says it acted at its own rate.
    let (run, goal_policy) = ood_run(
        &dir,
        "[env]\nframes_per_action = 5\n[env.task]\ntraining_episode_actions = 205\n",
    );
    assert_eq!(policy_about(&run)["frames_per_action"], 5);
    assert_eq!(policy_about(&goal_policy)["frames_per_action"], 25);
    assert_eq!(policy_about(&run)["frame_rate_hz"], 25.0);
    ood_report(&dir, &run, &goal_policy);
    // Elsewhere it runs only at its rate: evaluation and the bridge name it.
    assert_refused(&evaluate_on_zone(&dir, &run), "act every 5 frames");
    assert_refused(&lab_trial(&dir, &run, "lab", &[]), "set command_hz = 5");
    // The same policy had it been trained at 50 Hz acts ten times a second, and the bridge
    // asks for that rate: its frames are the frame rate it records, not SPEC's 25 Hz.
    let fast = dir.join("fast");
    std::fs::create_dir_all(&fast).unwrap();
    std::fs::copy(
        run.join("policy.safetensors"),
        fast.join("policy.safetensors"),
    )
    .unwrap();
    let mut meta: serde_json::Value =
        serde_json::from_slice(&std::fs::read(run.join("policy.safetensors.json")).unwrap())
            .unwrap();
    meta["about"]["frame_rate_hz"] = serde_json::json!(50.0);
    std::fs::write(
        fast.join("policy.safetensors.json"),
        serde_json::to_vec(&meta).unwrap(),
    )
    .unwrap();
    assert_refused(
        &lab_trial(&dir, &fast, "lab-fast", &[]),
        "set command_hz = 10",
    );
}

#[test]
fn an_ood_policy_that_looks_further_back_is_measured_against_a_yardstick_that_looks_one_back() {
    let dir = fresh_dir("ood-back");
    let (run, goal_policy) = ood_run(&dir, "[env.observation]\nprevious_block_actions = 3\n");
    let back = |p: &Path| policy_about(p)["observation"]["previous_block_actions"].clone();
    assert_eq!((back(&run), back(&goal_policy)), (3.into(), 1.into()));
    // Both observations are 180 floats: only the record tells them apart, and the yardstick
    // and the comparison policy look back as they were trained.
    ood_report(&dir, &run, &goal_policy);
    // Elsewhere it runs only as it was trained: evaluation names the setting, and the bridge,
    // which looks one action back, refuses it.
    assert_refused(&evaluate_on_zone(&dir, &run), "previous_block_actions = 3");
    assert_refused(
        &lab_trial(&dir, &run, "lab", &[]),
        "previous_block_actions = 3",
    );
}

#[test]
fn the_support_command_checks_its_estimators_and_bad_input_is_refused() {
    let dir = fresh_dir("ood-support");
    let (seed_dir, weights) = (one_round().seed_dir(), one_round().weights());
    let good = format!("convnet:{}", s(&weights));
    // The support command: both estimators checked, the chosen one written.
    let other = dir.join("support.json");
    let o = support_command(
        &weights,
        &seed_dir,
        &other,
        &["--estimator", "gmm", "--partner-range-cm", "15"],
    );
    assert!(o.status.success(), "{}", stderr(&o));
    let t = stdout(&o);
    assert!(t.contains("| knn |") && t.contains("| gmm |"), "{t}");
    assert!(!t.contains("| disagreement |"), "no ensemble: {t}");
    assert!(t.contains("pressed into a corner"), "{t}");
    let f: serde_json::Value = serde_json::from_slice(&std::fs::read(&other).unwrap()).unwrap();
    assert_eq!(f["config"]["estimator"], "gmm");
    assert_eq!(f["config"]["partner_range_cm"], 15.0);

    // Refusals.
    let train = |model: &str, extra: &[&str]| {
        let mut args = vec![
            "train", "--model", model, "--task", "ood", "--preset", "smoke", "--steps", "500",
        ];
        args.extend_from_slice(extra);
        let run = dir.join(format!("run-{}", extra.len()));
        let run = run.to_str().unwrap().to_string();
        args.extend_from_slice(&["--out", &run]);
        fishprobe(&args)
    };
    // A command that fails, saying `why`.
    let refused = |o: std::process::Output, why: &str| {
        assert!(!o.status.success(), "{why}: it ran");
        assert!(stderr(&o).contains(why), "{}", stderr(&o));
    };
    refused(train("Zone", &[]), "not data-driven");
    // Refused before its run directory is made.
    assert!(!dir.join("run-0").exists());
    refused(
        fishprobe(&[
            "support",
            "--model",
            &format!("convnet:{}", s(&weights)),
            "--partner-range-cm=-3",
            "--out",
            s(&dir.join("never.json")),
        ]),
        "support.partner_range_cm",
    );
    // Weights without a support file beside them.
    let bare = dir.join("bare.safetensors");
    std::fs::copy(&weights, &bare).unwrap();
    std::fs::copy(
        seed_dir.join("model-narrow/convnet.safetensors.json"),
        dir.join("bare.safetensors.json"),
    )
    .unwrap();
    let bare_model = format!("convnet:{}", s(&bare));
    let o = train(&bare_model, &[]);
    assert!(stderr(&o).contains("fit-convnet"), "{}", stderr(&o));
    refused(o, "no support file");
    // Another model's support file: refused by hash.
    std::fs::copy(
        seed_dir.join("model-ood/convnet.safetensors.support.json"),
        dir.join("bare.safetensors.support.json"),
    )
    .unwrap();
    refused(
        train(&bare_model, &[]),
        "was built for the model with SHA-256",
    );
    assert!(!dir.join("run-0").exists());
    // Settings out of range.
    refused(
        train(&good, &["--ood-goal-weight", "20"]),
        "task.ood_goal_weight",
    );
    let x = dir.join("x");
    refused(
        fishprobe(&[
            "train",
            "--model",
            "Zone",
            "--ood-goal-weight",
            "1",
            "--out",
            s(&x),
        ]),
        "--task ood only",
    );
    refused(
        fishprobe(&[
            "ood-report",
            "--policy",
            "scripted:goal-seeker",
            "--out",
            s(&x),
        ]),
        "model is required unless policy is a training directory",
    );
    refused(
        fishprobe(&[
            "ood-report",
            "--policy",
            "scripted:goal-seeker",
            "--model",
            "Follow",
            "--out",
            s(&x),
        ]),
        "not data-driven",
    );
}
