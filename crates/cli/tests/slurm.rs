//! The SLURM executor against a real single-node SLURM (Debian's slurmctld, slurmd and munge on
//! loopback). Opt-in: `cargo test -p fishprobe --test slurm -- --ignored` (as root; it installs
//! the packages when missing and starts the daemons with scripts/slurm-single-node.sh).

#![allow(clippy::unwrap_used)] // a failure is a test failure

mod common;

use common::{fishprobe, fresh_dir as dir, stderr};
use std::path::Path;
use std::process::Command;

fn sh(cmd: &str) -> bool {
    Command::new("sh")
        .args(["-c", cmd])
        .status()
        .is_ok_and(|s| s.success())
}

#[test]
#[ignore = "needs root, Debian's SLURM packages and a few minutes; run with --ignored"]
fn slurm_executor_runs_a_smoke_study_identical_to_the_local_executor() {
    if !sh("command -v sbatch && command -v slurmctld && command -v munged") {
        assert!(
            sh("apt-get update -qq && DEBIAN_FRONTEND=noninteractive apt-get install -y -qq slurmctld slurmd slurm-client munge"),
            "installing SLURM failed"
        );
    }
    let script = Path::new(env!("CARGO_MANIFEST_DIR")).join("../../scripts/slurm-single-node.sh");
    assert!(
        sh(&format!("bash {}", script.display())),
        "SLURM did not start"
    );
    let d = dir("slurm");
    let (local, cluster) = (d.join("local"), d.join("cluster"));
    let o = fishprobe(&["run", "--preset", "smoke", "--out", local.to_str().unwrap()]);
    assert!(o.status.success(), "{}", stderr(&o));
    let o = fishprobe(&[
        "run",
        "--preset",
        "smoke",
        "--executor",
        "slurm",
        "--out",
        cluster.to_str().unwrap(),
    ]);
    assert!(o.status.success(), "{}", stderr(&o));
    // The steps ran as array tasks.
    let slurm_logs = std::fs::read_dir(cluster.join("logs"))
        .unwrap()
        .filter(|e| {
            e.as_ref()
                .unwrap()
                .file_name()
                .to_string_lossy()
                .starts_with("slurm-")
        })
        .count();
    assert!(slurm_logs >= 8, "{slurm_logs} array-task logs");
    let read = |p: &Path| {
        std::fs::read_to_string(p.join("analysis/results.json"))
            .unwrap()
            .replace(p.to_str().unwrap(), "STUDY")
    };
    assert!(
        read(&local) == read(&cluster),
        "the cluster's results differ from the local ones"
    );
}
