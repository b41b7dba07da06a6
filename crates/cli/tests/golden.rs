//! The smoke study's outputs, bit for bit: every trial file and `results.json`, and the report
//! (figures, HTML, summary), digested and compared with the digests recorded when they were
//! last changed on purpose. Refactoring
//! (issue 25: one controller trait, one study layout, ...) must leave them as they are.
//!
//! If a change alters results on purpose, run this test, take the digest it prints, replace
//! `GOLDEN` and say in the commit message why the results changed. The digest depends on the
//! machine's floating-point paths (the ConvNet fish's inference uses AVX2 and FMA where the
//! CPU has them), so it is checked only on x86-64 with both; elsewhere the test says so and
//! checks that two runs agree with each other.

#![allow(clippy::unwrap_used)] // a failure is a test failure

mod common;

use common::{fishprobe, fresh_dir, stderr};
use std::path::{Path, PathBuf};

/// Digest of the smoke study (fishprobe 0.1.0, x86-64 with AVX2 and FMA). History: 28e3bb4d…
/// from commit 6638720 through issues 21 and 25 (refactors, bit-identical); then changed on
/// purpose when NB2 trends at the dispersion boundary (α = 0) took statsmodels' small-sample
/// factor (K counts α): only `temporal` entries with α = 0 changed (their CI and p); then
/// b4735a37… until the scripted baselines joined every study (issue 20: `baselines/` trial
/// files and `competence` in results.json; every rollout file unchanged, checked by sha256);
/// then f4786dd4… until `task.training_goal_reached_by` joined the settings that every trial
/// file records in its config JSON (positions of all 84 trial files compared: identical); then
/// 76290e50… until M_Follow's default speed became 4 cm/s (the fidelity sweep, issue 20);
/// then bdb51e1a… until `task.group_goal` and `task.group_goal_fraction` joined the recorded
/// settings (issue 22: groups). With those two keys left out of the config JSON the digest was
/// bdb51e1a… again: the models' group versions leave one fish bit-identical. Then a3cadde9…
/// until `analysis.robot_reach_cm` joined the config in results.json and `live.fish_count`
/// the config of virtual-lab trial files (groups in analyze, the bridge and the virtual lab);
/// with those two keys removed from the text the digest was a3cadde9… again. Then 6c6986d8…
/// until `observation.centroid_bins` joined the recorded settings (with it cut from the config
/// JSON: 6c6986d8… again). Then 094b9e0e… until `live.centroid_bins` joined the config of
/// virtual-lab trial files (with it cut from the text: 094b9e0e… again). Then 49ecd88a… until
/// the OOD objective's five `task` settings (`objective`, `ood_weight`, `ood_score_cap`,
/// `ood_goal_weight`, `ood_score_every_frames`) joined the recorded environment (with them cut
/// from the config JSON: 49ecd88a… again). Then c5c37960… until M_ConvNet stayed off the walls
/// (issue 20, item 4: weights refitted on headings smoothed over 5 frames, and the sampler's
/// wall redraws; every trial with an M_ConvNet fish or policy changed, and so results.json),
/// with `task.training_start` and `task.lab_start_spread_cm` joining the recorded settings.
/// Then 725e6c5b… until `task.ood_score_floor` and `task.lab_start_share` joined the recorded
/// settings (issues 23 and 20; both inert at their defaults: the report's digest, over every
/// figure, stayed 5f7b3f96…). Then 77988c30… until `task.ood_score_floor`'s default became 1
/// (recorded in every trial's settings; no study trains an OOD policy, and the report's
/// digest stayed 5f7b3f96…). Then 98759d7a… until the log-s.d. bound stopped trapping the
/// policy (issue 20: above the bound a gradient that lowers the log-s.d. passes; the smoke
/// policies start with about half their states above it, so every policy's trials changed).
/// Then babfa8ca… until every training seed's policy got its approach assay (issue 20:
/// `approach_stability/` trial files joined the digest, `seeds` and two analysis settings
/// joined results.json). Then db63f14e… until `task.progress_shaping` and
/// `task.progress_shaping_gamma` joined the recorded settings (issue 20's fidelity sweep;
/// inert at their default: the report's digest, over every figure, stayed ccd1f03b…).
/// Then 09ddfedb… until M_Zone lost SPEC's wall pull by default (issue 20: every trial with an
/// M_Zone fish or π_Zone changed, and so results.json). Then 8b2a1083… until
/// `task.training_goals` joined the recorded settings (issue 20's reading `evaluation-goals`;
/// inert at its default, which draws as before: the report's digest, over every figure,
/// stayed dd4c923b…). Then 6e425b02… until probe competence gave each probe's time to reach
/// its fish (issue 20: `reach_s` and `baselines_reach_s` in `competence`, `reach_s` in
/// `seeds`; with those keys cut from results.json the digest was 6e425b02… again). Then
/// fff5bf7c… until the competence ratio got its standard error (`ratio_se` in `competence` and
/// `seeds`; with those keys cut from results.json the digest was fff5bf7c… again). Then
/// 2873f78c… until the OOD task got the `ood_score` setting (issue 23; inert at its default:
/// every trial file's datasets and attributes equal the previous run's, compared with h5py,
/// the `config_json` dataset once `"ood_score":"support"` is cut from it; results.json and
/// the report unchanged). Then 30151bb4… until every trial file recorded the SHA-256 of the
/// policy that drove it (`policy_sha256` in its config JSON; with that key left out of the
/// text the digest, and the report's, were 30151bb4… and 189f187b… again). Then ddf97a88…
/// until results.json named each policy's weights (`weights`; with that key cut from the text
/// the digest was ddf97a88… again). Then fbbf8f3f… until `task.progress_shaping_gamma`'s
/// default became 0.99, the `paper` PPO preset's new discount, which every trial file records
/// (issue 20; the smoke preset keeps the published γ, so no trial's motion changed: the
/// report's digest, over every figure, stayed d6deac52…). Then 931be0a2… until
/// `observation.heading_bins` joined the recorded settings (issue 23; inert at its default:
/// with the key left out of the config JSON the digest was 931be0a2… again, and the report's
/// stayed d6deac52…). Then 4bccb0c8… until `live.heading_bins` joined the config of
/// virtual-lab trial files (with the key left out of the text: 4bccb0c8… again). Then
/// 58b5dd6c… until `observation.previous_block_actions` joined the recorded settings (issue
/// 23; inert at its default, SPEC §5's previous step: with the key not serialised the digest
/// was 58b5dd6c… again, and the report's stayed d6deac52…).
const GOLDEN: &str = "70a961c2393164f4";

/// Digest of the smoke study's report (every figure, `index.html` and `summary.md` with the
/// study's path replaced by `STUDY`). History: 535e3f1d… at the session start; cd7735f1…
/// after the NB2 change (the temporal table's intervals and p-values); then the table of
/// candidate models with their origin was added to "What was run" (issue 18); dc5c7f10… until
/// the "Probe competence" section and summary table (issue 20); dcd6df67… until M_Follow's
/// default speed became 4 cm/s (its trials, and so the figures, changed); 1f452965… until
/// M_ConvNet stayed off the walls (issue 20, item 4: its trials, and so the figures, changed);
/// 5f7b3f96… until the log-s.d. bound stopped trapping the policy (every policy's trials
/// changed); e6019e8e… until the "Every training seed" table joined the report and summary;
/// ccd1f03b… until M_Zone lost SPEC's wall pull by default (its trials, and so the figures);
/// dd4c923b… until the competence and seed tables gave the time to reach the fish;
/// 4d32c1a0… until they gave the competence ratio's standard error; 189f187b… until "What
/// was run" and the summary named each policy's weights (with the column and the line cut from
/// the two documents: 189f187b… again).
const GOLDEN_REPORT: &str = "d6deac523576f83a";

/// FNV-1a over byte strings.
fn fnv(parts: &[Vec<u8>]) -> String {
    let mut h: u64 = 0xcbf2_9ce4_8422_2325;
    for p in parts {
        for &b in p {
            h = (h ^ u64::from(b)).wrapping_mul(0x0000_0100_0000_01b3);
        }
    }
    format!("{h:016x}")
}

/// The report's digest: figures by name, then the two documents with the study path replaced.
fn report_digest(study: &Path) -> String {
    let report = study.join("report");
    let mut figs: Vec<PathBuf> = std::fs::read_dir(report.join("figures"))
        .unwrap()
        .map(|e| e.unwrap().path())
        .collect();
    figs.sort();
    let mut parts = Vec::new();
    for f in &figs {
        parts.push(f.file_name().unwrap().to_string_lossy().as_bytes().to_vec());
        parts.push(std::fs::read(f).unwrap());
    }
    let root = study.to_str().unwrap();
    for doc in ["index.html", "summary.md"] {
        let text = std::fs::read_to_string(report.join(doc)).unwrap();
        parts.push(text.replace(root, "STUDY").into_bytes());
    }
    fnv(&parts)
}

/// FNV-1a over the relative paths and contents of every trial file and of `results.json`.
fn digest(study: &Path) -> (String, usize) {
    fn walk(d: &Path, out: &mut Vec<PathBuf>) {
        for e in std::fs::read_dir(d).unwrap() {
            let p = e.unwrap().path();
            if p.is_dir() {
                walk(&p, out);
            } else if p.extension().is_some_and(|x| x == "hdf5") {
                out.push(p);
            }
        }
    }
    let mut files = Vec::new();
    for top in [
        "rollouts",
        "approach_test",
        "approach_stability",
        "stability",
    ] {
        walk(&study.join(top), &mut files);
    }
    files.sort();
    files.push(study.join("analysis/results.json"));
    let mut h: u64 = 0xcbf2_9ce4_8422_2325;
    let mut eat = |bytes: &[u8]| {
        for &b in bytes {
            h = (h ^ u64::from(b)).wrapping_mul(0x0000_0100_0000_01b3);
        }
    };
    for f in &files {
        eat(f.strip_prefix(study).unwrap().to_string_lossy().as_bytes());
        eat(&std::fs::read(f).unwrap());
    }
    (format!("{h:016x}"), files.len())
}

fn has_avx2_fma() -> bool {
    #[cfg(target_arch = "x86_64")]
    {
        std::arch::is_x86_feature_detected!("avx2") && std::arch::is_x86_feature_detected!("fma")
    }
    #[cfg(not(target_arch = "x86_64"))]
    {
        false
    }
}

#[test]
fn the_smoke_study_is_bit_identical_to_the_recorded_one() {
    let d = fresh_dir("golden");
    let study = d.join("s");
    let o = fishprobe(&["run", "--preset", "smoke", "--out", study.to_str().unwrap()]);
    assert!(o.status.success(), "{}", stderr(&o));
    let (got, n) = digest(&study);
    let report = report_digest(&study);
    println!("smoke study digest: {got} over {n} files; report digest: {report}");
    assert!(n > 50, "only {n} files");
    if has_avx2_fma() {
        assert_eq!(
            got, GOLDEN,
            "the smoke study's trial files or results.json changed (see this file's docs)"
        );
        assert_eq!(
            report, GOLDEN_REPORT,
            "the smoke study's report changed (see this file's docs)"
        );
    } else {
        println!("not x86-64 with AVX2 and FMA: checking only that a second run agrees");
        let again = d.join("t");
        let o = fishprobe(&["run", "--preset", "smoke", "--out", again.to_str().unwrap()]);
        assert!(o.status.success(), "{}", stderr(&o));
        assert_eq!(digest(&again).0, got);
        assert_eq!(report_digest(&again), report);
    }
}
