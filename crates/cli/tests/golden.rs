//! The smoke study's outputs, bit for bit: every trial file and `results.json`, and the report
//! (figures, HTML, summary), digested and compared with the digests recorded when they were
//! last changed on purpose. A refactoring (moving work between crates, one controller trait
//! for everything that drives the robot, ...) must leave them as they are.
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

/// Digest of the smoke study (fishprobe 0.1.0, x86-64 with AVX2 and FMA): every trial file
/// and `results.json`. A setting that joins the recorded ones changes it even when it is inert
/// at its default; each change on purpose is explained in the commit that made it (`git log
/// crates/cli/tests/golden.rs`), usually with the check that nothing else moved (the digest
/// recomputed with the new key cut from the text).
const GOLDEN: &str = "267ed146caf2d317";

/// Digest of the smoke study's report (every figure, `index.html` and `summary.md` with the
/// study's path replaced by `STUDY`); its changes, too, are explained in their commits.
const GOLDEN_REPORT: &str = "c71a538e4a8e8bbb";

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

/// The same digests from a release build (what `cargo install` builds, with its own profile):
/// the build's settings change how long it takes, never the bits. Opt-in, since it needs that
/// build: `cargo build --release --locked -p fishprobe` first, or set `FISHPROBE_RELEASE_BIN`
/// to an installed binary.
#[test]
#[ignore = "needs a release build: cargo build --release --locked -p fishprobe"]
fn the_release_build_gives_the_recorded_digests() {
    let bin = std::env::var_os("FISHPROBE_RELEASE_BIN").map_or_else(
        || Path::new(env!("CARGO_MANIFEST_DIR")).join("../../target/release/fishprobe"),
        PathBuf::from,
    );
    assert!(bin.is_file(), "no release build at {}", bin.display());
    let d = fresh_dir("golden-release");
    let study = d.join("s");
    let o = std::process::Command::new(&bin)
        .args(["run", "--preset", "smoke", "--out", study.to_str().unwrap()])
        .output()
        .unwrap();
    assert!(o.status.success(), "{}", stderr(&o));
    let (got, n) = digest(&study);
    let report = report_digest(&study);
    println!(
        "release build {}: digest {got} over {n} files; report {report}",
        bin.display()
    );
    assert!(
        has_avx2_fma(),
        "the recorded digests hold on x86-64 with AVX2 and FMA only"
    );
    assert_eq!((got.as_str(), report.as_str()), (GOLDEN, GOLDEN_REPORT));
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
