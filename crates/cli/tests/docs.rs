//! Documentation that is generated must be current.

#![allow(clippy::unwrap_used)] // a failure is a test failure

mod common;

use common::{fishprobe, stdout};
use std::path::Path;

#[test]
fn the_settings_reference_is_current() {
    let o = fishprobe(&["config", "reference"]);
    assert!(o.status.success());
    let want = stdout(&o);
    let path = Path::new(env!("CARGO_MANIFEST_DIR")).join("../../docs/settings.md");
    let have = std::fs::read_to_string(&path).unwrap_or_default();
    assert!(
        have == want,
        "docs/settings.md is stale: regenerate it with `fishprobe config reference > docs/settings.md`"
    );
}

#[test]
fn the_version_names_the_commit() {
    let o = fishprobe(&["--version"]);
    let v = stdout(&o);
    assert!(
        v.starts_with(&format!("fishprobe {} (", env!("CARGO_PKG_VERSION"))),
        "{v}"
    );
    // A checkout gives a commit hash; a source tree without git says so.
    assert!(v.contains("commit ") || v.contains("commit unknown"), "{v}");
}

/// The README's shell blocks marked `<!-- runnable -->` run as written (in a scratch
/// directory): a newcomer's first commands must work.
#[test]
fn the_readmes_runnable_blocks_run_as_written() {
    let readme =
        std::fs::read_to_string(Path::new(env!("CARGO_MANIFEST_DIR")).join("../../README.md"))
            .unwrap();
    let dir = common::fresh_dir("readme");
    let mut lines = readme.lines();
    let mut ran = 0;
    while let Some(l) = lines.next() {
        if l.trim() != "<!-- runnable -->" {
            continue;
        }
        assert_eq!(
            lines.next().map(str::trim),
            Some("```sh"),
            "a runnable block is ```sh"
        );
        for cmd in lines.by_ref().take_while(|l| l.trim() != "```") {
            let cmd = cmd.split(" #").next().unwrap_or("").trim();
            if cmd.is_empty() || cmd.starts_with('#') {
                continue;
            }
            let mut words = cmd.split_whitespace();
            assert_eq!(
                words.next(),
                Some("fishprobe"),
                "not a fishprobe command: {cmd}"
            );
            let args: Vec<&str> = words.collect();
            let o = std::process::Command::new(env!("CARGO_BIN_EXE_fishprobe"))
                .args(&args)
                .current_dir(&dir)
                .output()
                .unwrap();
            assert!(
                o.status.success(),
                "README command failed: {cmd}\n{}",
                String::from_utf8_lossy(&o.stderr)
            );
            ran += 1;
        }
    }
    assert!(ran >= 3, "only {ran} runnable commands in the README");
}
