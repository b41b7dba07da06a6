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

/// The Markdown files a user reads: the READMEs and everything under `docs/`.
fn user_docs() -> Vec<std::path::PathBuf> {
    let root = Path::new(env!("CARGO_MANIFEST_DIR")).join("../..");
    let root = root.canonicalize().unwrap();
    let mut files = vec![root.join("README.md"), root.join("python/README.md")];
    let mut dirs = vec![root.join("docs")];
    while let Some(dir) = dirs.pop() {
        for entry in std::fs::read_dir(&dir).unwrap() {
            let path = entry.unwrap().path();
            if path.is_dir() {
                dirs.push(path);
            } else if path.extension().is_some_and(|e| e == "md") {
                files.push(path);
            }
        }
    }
    files.sort();
    files
}

/// The help text of a command path (`["assay", "approach"]`), cached.
fn help_of<'a>(
    cache: &'a mut std::collections::HashMap<Vec<String>, String>,
    path: &[String],
) -> &'a str {
    cache.entry(path.to_vec()).or_insert_with(|| {
        let mut args: Vec<&str> = path.iter().map(String::as_str).collect();
        args.push("--help");
        let o = fishprobe(&args);
        assert!(
            o.status.success(),
            "fishprobe {} --help failed",
            path.join(" ")
        );
        stdout(&o)
    })
}

/// The subcommands a help text lists under `Commands:`.
fn subcommands(help: &str) -> Vec<&str> {
    let Some((_, rest)) = help.split_once("Commands:\n") else {
        return Vec::new();
    };
    rest.lines()
        .take_while(|l| !l.trim().is_empty())
        .filter(|l| l.starts_with("  ") && !l.starts_with("   "))
        .filter_map(|l| l.split_whitespace().next())
        .collect()
}

/// The command lines a Markdown line holds: each `fishprobe` followed by a space, up to the
/// end of the code span or shell command (a backtick, a pipe, `;`, `)` or a comment).
fn command_lines(line: &str) -> Vec<&str> {
    let mut found = Vec::new();
    let mut from = 0;
    while let Some(at) = line[from..].find("fishprobe ") {
        let start = from + at;
        from = start + "fishprobe ".len();
        let before = line[..start].chars().next_back();
        if before.is_some_and(|c| !(c.is_whitespace() || "`;(".contains(c))) {
            continue;
        }
        let rest = &line[from..];
        let end = rest.find(['`', '|', ';', ')', '#']).unwrap_or(rest.len());
        found.push(&rest[..end]);
    }
    found
}

/// Every `fishprobe SUBCOMMAND --flag` the user documentation shows names a subcommand and
/// flags that exist: a renamed flag must not leave a guide or a validation table's command
/// behind.
#[test]
fn every_command_the_docs_show_has_its_flags() {
    let mut cache = std::collections::HashMap::new();
    let (mut checked, mut stale) = (0, Vec::new());
    for file in user_docs() {
        let text = std::fs::read_to_string(&file).unwrap();
        for (n, line) in text.lines().enumerate() {
            for command in command_lines(line) {
                let mut words = command.split_whitespace().peekable();
                let mut path: Vec<String> = Vec::new();
                while let Some(w) = words.peek() {
                    if !subcommands(help_of(&mut cache, &path)).contains(w) {
                        break;
                    }
                    path.push((*w).to_string());
                    words.next();
                }
                if path.is_empty() {
                    continue; // prose: "fishprobe itself", "fishprobe is fast"
                }
                let help = help_of(&mut cache, &path).to_string();
                for flag in words.filter(|w| w.starts_with("--") && w.len() > 2) {
                    let flag = flag.split('=').next().unwrap_or(flag);
                    let flag = flag.trim_end_matches(['.', ',', ':']);
                    checked += 1;
                    let listed = help.match_indices(flag).any(|(i, _)| {
                        help[i + flag.len()..]
                            .chars()
                            .next()
                            .is_some_and(|c| c.is_whitespace() || ",=<[".contains(c))
                    });
                    if !listed {
                        stale.push(format!(
                            "{}:{}: fishprobe {} has no {flag}",
                            file.display(),
                            n + 1,
                            path.join(" ")
                        ));
                    }
                }
            }
        }
    }
    assert!(
        stale.is_empty(),
        "stale commands in the docs:\n{}",
        stale.join("\n")
    );
    assert!(checked > 300, "only {checked} flags found in the docs");
}
