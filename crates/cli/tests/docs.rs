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
