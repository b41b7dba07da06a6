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
    let mut files = vec![
        root.join("README.md"),
        root.join("python/README.md"),
        root.join("ARCHITECTURE.md"),
    ];
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

/// The subcommands a help text lists under `Commands:` and, at the top, under the research
/// commands' heading.
fn subcommands(help: &str) -> Vec<&str> {
    let listed = |heading: &str| -> Vec<&str> {
        let Some((_, rest)) = help.split_once(heading) else {
            return Vec::new();
        };
        rest.lines()
            .take_while(|l| !l.trim().is_empty())
            .filter(|l| l.starts_with("  ") && !l.starts_with("   "))
            .filter_map(|l| l.split_whitespace().next())
            .collect()
    };
    let mut all = listed("Commands:\n");
    all.extend(listed(
        "Research commands (checks of the method and the paper's outlook):\n",
    ));
    all
}

/// Every command path of the binary (the top level included), found through `--help`.
fn every_command(cache: &mut std::collections::HashMap<Vec<String>, String>) -> Vec<Vec<String>> {
    let (mut found, mut todo) = (Vec::new(), vec![Vec::new()]);
    while let Some(path) = todo.pop() {
        for sub in subcommands(help_of(cache, &path)) {
            if sub != "help" {
                let mut next = path.clone();
                next.push(sub.to_string());
                todo.push(next);
            }
        }
        found.push(path);
    }
    found
}

/// Where a text speaks of the work's own bookkeeping ("issue 20"), which a user cannot see.
fn development_vocabulary(text: &str) -> Vec<String> {
    let lower = text.to_lowercase();
    lower
        .match_indices("issue ")
        .filter(|(i, m)| {
            lower[i + m.len()..]
                .chars()
                .next()
                .is_some_and(|c| c.is_ascii_digit())
        })
        .map(|(i, _)| {
            let line = lower[..i].matches('\n').count() + 1;
            let end = (i + 20).min(text.len());
            format!("line {line}: {}", text.get(i..end).unwrap_or("?"))
        })
        .collect()
}

/// The README is a newcomer's path, not a manual: at most 200 lines.
#[test]
fn the_readme_is_short() {
    let path = Path::new(env!("CARGO_MANIFEST_DIR")).join("../../README.md");
    let lines = std::fs::read_to_string(path).unwrap().lines().count();
    assert!(
        lines <= 200,
        "README.md has {lines} lines; move detail into docs/"
    );
}

/// No help text, no generated reference and no page a user reads names an issue: say what the
/// thing is instead.
#[test]
fn no_help_text_or_user_doc_names_an_issue() {
    assert_eq!(
        development_vocabulary("see Issue 20."),
        ["line 1: Issue 20."]
    );
    assert!(development_vocabulary("no issue here; issues 2").is_empty());
    let mut cache = std::collections::HashMap::new();
    let commands = every_command(&mut cache);
    assert!(
        commands.len() > 25,
        "only {} commands found",
        commands.len()
    );
    assert!(
        commands.iter().any(|c| c == &["ood-loop"]),
        "the research commands are listed"
    );
    let mut found = Vec::new();
    for path in &commands {
        for hit in development_vocabulary(help_of(&mut cache, path)) {
            found.push(format!("fishprobe {} --help, {hit}", path.join(" ")));
        }
    }
    for file in user_docs() {
        for hit in development_vocabulary(&std::fs::read_to_string(&file).unwrap()) {
            found.push(format!("{}, {hit}", file.display()));
        }
    }
    assert!(
        found.is_empty(),
        "issue numbers shown to users:\n{}",
        found.join("\n")
    );
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

/// The crates of ours a manifest (`crates/DIR/Cargo.toml`) depends on, by directory name
/// (`fishprobe-sim` is `sim`), from its `[dependencies]` table.
fn manifest_dependencies(manifest: &str) -> std::collections::BTreeSet<String> {
    let mut in_deps = false;
    let mut deps = std::collections::BTreeSet::new();
    for line in manifest.lines() {
        let line = line.trim();
        if line.starts_with('[') {
            in_deps = line == "[dependencies]";
        } else if in_deps {
            if let Some(name) = line.strip_prefix("fishprobe-") {
                let name: String = name
                    .chars()
                    .take_while(|c| c.is_ascii_alphanumeric())
                    .collect();
                deps.insert(name);
            }
        }
    }
    deps
}

/// ARCHITECTURE.md's picture names, for every crate, exactly the crates of ours its manifest
/// depends on.
#[test]
fn the_architecture_picture_matches_the_manifests() {
    let root = Path::new(env!("CARGO_MANIFEST_DIR")).join("../..");
    let text = std::fs::read_to_string(root.join("ARCHITECTURE.md")).unwrap();
    let picture = text
        .split("```")
        .nth(1)
        .expect("ARCHITECTURE.md opens with the dependency picture");
    let mut drawn = std::collections::BTreeMap::new();
    for line in picture.lines().filter(|l| l.contains('►')) {
        let (name, deps) = line.split_once('►').unwrap();
        let name = name.trim_end_matches(['─', ' ']).trim().to_string();
        // "(nothing of ours)" and other remarks in parentheses name no crate.
        let deps = deps.split('(').next().unwrap_or_default();
        let deps: std::collections::BTreeSet<String> = deps
            .split_whitespace()
            .filter(|w| w.chars().all(|c| c.is_ascii_lowercase()))
            .map(str::to_string)
            .collect();
        drawn.insert(name, deps);
    }
    let mut crates = Vec::new();
    for entry in std::fs::read_dir(root.join("crates")).unwrap() {
        let dir = entry.unwrap().path();
        let manifest = std::fs::read_to_string(dir.join("Cargo.toml")).unwrap();
        let name = dir.file_name().unwrap().to_string_lossy().to_string();
        let Some(deps) = drawn.get(&name) else {
            panic!("crates/{name} is not in ARCHITECTURE.md's picture");
        };
        assert_eq!(
            deps,
            &manifest_dependencies(&manifest),
            "ARCHITECTURE.md's line for {name} against crates/{name}/Cargo.toml"
        );
        crates.push(name);
    }
    assert_eq!(
        crates.len(),
        drawn.len(),
        "the picture names crates that do not exist"
    );
}

/// The counts of metrics the prose names ("the nine per-frame metrics", "six group metrics")
/// are the metric table's: a metric added to the table fails this test until the docs say so.
#[test]
fn the_docs_count_the_metrics_the_table_holds() {
    let pairs = fishprobe_analysis::count_word(fishprobe_analysis::METRICS.len());
    let groups = fishprobe_analysis::count_word(fishprobe_analysis::GROUP_METRICS.len());
    let words = [
        "two", "three", "four", "five", "six", "seven", "eight", "nine", "ten", "eleven", "twelve",
    ];
    let mut wrong = Vec::new();
    for file in user_docs() {
        // Lines are joined: a phrase may wrap.
        let text = std::fs::read_to_string(&file)
            .unwrap()
            .split_whitespace()
            .collect::<Vec<_>>()
            .join(" ")
            .to_lowercase();
        let tokens: Vec<&str> = text.split(' ').collect();
        for (i, w) in tokens.iter().enumerate() {
            let w = w.trim_start_matches(['(', '*', '"']);
            if !words.contains(&w) {
                continue;
            }
            let next = |k: usize| tokens.get(i + k).copied().unwrap_or("");
            let want = match (next(1), next(2)) {
                ("group", m) if m.starts_with("metric") => &groups,
                ("pair" | "per-frame", m) if m.starts_with("metric") => &pairs,
                ("per-frame", "behaviour") if next(3).starts_with("metric") => &pairs,
                (m, _) if m.starts_with("metric") => &pairs,
                _ => continue,
            };
            if w != want {
                wrong.push(format!(
                    "{}: \"{w} {} {}\" (the table holds {pairs} pair and {groups} group metrics)",
                    file.display(),
                    next(1),
                    next(2)
                ));
            }
        }
    }
    assert!(wrong.is_empty(), "{}", wrong.join("\n"));
}
