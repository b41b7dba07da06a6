//! End-to-end tests of `fishprobe report`: a complete small study, a partial one, a
//! virtual-lab one, and the page rendered in headless Chromium.

#![allow(clippy::unwrap_used)] // a failure is a test failure

mod common;

use common::{fishprobe, fresh_dir as dir, stderr, stdout, Scratch};
use std::path::{Path, PathBuf};
use std::process::Command;
use std::sync::OnceLock;

use fishprobe_report::STUDY_FIGURES as FIGURES;

fn ok(args: &[&str]) -> String {
    let o = fishprobe(args);
    assert!(o.status.success(), "{args:?}: {}", stderr(&o));
    stdout(&o)
}

/// A small synthetic study (2 policies, 2-minute trials), analysed, with a real (smoke)
/// training run of each policy under `policies/`, and its report. Made once per test binary;
/// the tests only read it.
fn full_study() -> &'static Path {
    static STUDY: OnceLock<PathBuf> = OnceLock::new();
    STUDY.get_or_init(|| {
        let d = Scratch::for_process("e2e-report-full");
        let s = d.to_str().unwrap();
        ok(&["bench", "stats", "--size", "small", "--dir", s, "--json"]);
        ok(&["analyze", s, "--quick", "--sim-trials", "6"]);
        for m in ["Follow", "Zone"] {
            let out = d.join("policies").join(m);
            ok(&[
                "train",
                "--model",
                m,
                "--preset",
                "smoke",
                "--steps",
                "8192",
                "--out",
                out.to_str().unwrap(),
            ]);
        }
        let text = ok(&["report", s]);
        assert!(
            text.contains(&format!("{} figures", FIGURES.len())),
            "{text}"
        );
        d
    })
}

fn read(p: &Path) -> String {
    std::fs::read_to_string(p).unwrap_or_else(|e| panic!("{}: {e}", p.display()))
}

#[test]
fn a_complete_study_gets_every_figure_table_and_link() {
    let r = full_study().join("report");
    for f in FIGURES {
        let svg = read(&r.join("figures").join(format!("{f}.svg")));
        assert!(svg.starts_with("<svg"), "{f}");
        assert!(!svg.contains("<text"), "{f}.svg still needs a font");
        let png = std::fs::read(r.join("figures").join(format!("{f}.png"))).unwrap();
        assert_eq!(&png[1..4], b"PNG", "{f}");
        assert!(png.len() > 5_000, "{f}.png is nearly empty");
    }
    let html = read(&r.join("index.html"));
    // Figures are inlined; nothing is fetched from a network.
    assert_eq!(
        html.matches("data:image/svg+xml;base64,").count(),
        FIGURES.len()
    );
    assert!(!html.contains("http://") && !html.contains("https://"));
    for section in [
        "Sim-to-real gap in goals reached",
        "Per-metric sim-to-real gaps and ranks",
        "How much trials differ",
        "simulated trials differ from one another in goals",
        "Kruskal-Wallis",
        "rate ratio per minute",
        "Time to goal",
        "fraction closer to fish than goal",
        "Retraining stability",
        "training seed",
    ] {
        assert!(html.contains(section), "the report lacks `{section}`");
    }
    // Links to the analysis files resolve from the report directory.
    for link in ["../analysis/results.json", "../analysis/metric_gaps.csv"] {
        assert!(html.contains(link), "{link}");
        assert!(r.join(link).is_file(), "{link} does not resolve");
    }
    assert!(!html.contains("VIRTUAL LAB"));
    // The synthetic study's reality arm is scripted simulation: the report must say so.
    assert!(
        html.contains("id=\"not-real\""),
        "no warning about non-real files in __Real"
    );
    let md = read(&r.join("summary.md"));
    assert!(
        md.contains("## Analysis") && md.contains("figures/goals.svg"),
        "{md}"
    );
    // Training parameters come from params.json.
    assert!(html.contains("smoke"), "preset missing from the run table");
}

#[test]
fn a_directory_with_nothing_of_a_study_is_refused_and_left_alone() {
    let d = dir("report-nothing");
    std::fs::write(d.join("notes.txt"), "not a study").unwrap();
    let o = fishprobe(&["report", d.to_str().unwrap()]);
    assert_eq!(o.status.code(), Some(1));
    let err = stderr(&o);
    assert!(err.contains("not a study directory"), "{err}");
    assert!(err.contains("fishprobe run --out"), "{err}");
    let left: Vec<_> = std::fs::read_dir(&d)
        .unwrap()
        .map(|e| e.unwrap().file_name())
        .collect();
    assert_eq!(left, ["notes.txt"], "the refusal wrote into the directory");
}

#[test]
fn a_study_file_that_never_ends_is_reported_not_read_to_the_end() {
    use std::os::unix::fs::symlink;
    let d = dir("report-endless");
    for sub in ["analysis", "policies/Zone"] {
        std::fs::create_dir_all(d.join(sub)).unwrap();
    }
    for f in [
        "study.json",
        "analysis/results.json",
        "analysis/summary.md",
        "policies/Zone/params.json",
        "policies/Zone/progress.csv",
    ] {
        symlink("/dev/zero", d.join(f)).unwrap();
    }
    let o = fishprobe(&["report", d.to_str().unwrap()]);
    assert!(o.status.success(), "{}", stderr(&o));
    let html = read(&d.join("report/index.html"));
    for needle in [
        "results.json: larger than 16.0 MiB",
        "progress.csv</code>: larger than 256.0 MiB: not a training log fishprobe wrote",
    ] {
        assert!(html.contains(needle), "missing `{needle}`");
    }
}

#[test]
fn a_partial_study_says_what_is_missing_and_how_to_make_it() {
    let d = dir("report-partial");
    let s = d.to_str().unwrap();
    ok(&["bench", "stats", "--size", "small", "--dir", s, "--json"]);
    ok(&["report", s]);
    assert!(d.join("report/figures/gap_heatmap.svg").is_file());
    // No analysis, no policies, no approach assay, no reality arm. The report made again
    // into the same directory keeps none of the first one's figures it no longer draws.
    let _ = std::fs::remove_dir_all(d.join("analysis"));
    let _ = std::fs::remove_dir_all(d.join("approach_test"));
    for e in std::fs::read_dir(d.join("rollouts")).unwrap() {
        let p = e.unwrap().path();
        if p.to_string_lossy().ends_with("__Real") {
            std::fs::remove_dir_all(p).unwrap();
        }
    }
    let text = ok(&["report", s]);
    assert!(text.contains(&format!("fishprobe analyze {s}")), "{text}");
    let html = read(&d.join("report/index.html"));
    for needle in [
        "fishprobe analyze",
        "reality arm",
        "approach assay",
        "training curves",
        "No reality arm",
    ] {
        assert!(html.contains(needle), "missing note `{needle}`");
    }
    // What the trial files alone allow is still drawn.
    for f in ["goals_over_time", "iid_density", "trajectories"] {
        assert!(d.join(format!("report/figures/{f}.svg")).is_file(), "{f}");
    }
    for f in [
        "gap_heatmap.svg",
        "gap_heatmap.png",
        "approach.svg",
        "approach.png",
    ] {
        assert!(
            !d.join("report/figures").join(f).exists(),
            "{f} left behind"
        );
    }
}

#[test]
fn a_virtual_lab_study_is_labelled_virtual_everywhere() {
    let d = dir("report-virtual");
    let s = d.to_str().unwrap();
    ok(&["bench", "stats", "--size", "small", "--dir", s, "--json"]);
    for e in std::fs::read_dir(d.join("rollouts")).unwrap() {
        let p = e.unwrap().path();
        let name = p.file_name().unwrap().to_string_lossy().into_owned();
        if let Some(policy) = name.strip_suffix("__Real") {
            std::fs::rename(&p, d.join("rollouts").join(format!("{policy}__VirtualLab"))).unwrap();
        }
    }
    ok(&["analyze", s, "--quick", "--sim-trials", "6"]);
    ok(&["report", s]);
    let html = read(&d.join("report/index.html"));
    assert!(html.contains("id=\"virtual\""), "no virtual-lab banner");
    assert!(html.contains("not live fish"));
    let md = read(&d.join("report/summary.md"));
    assert!(md.contains("VIRTUAL LAB"), "{md}");
}

#[test]
fn bad_input_gets_a_clear_error() {
    let o = fishprobe(&["report", "/nonexistent/fishprobe-study"]);
    assert!(!o.status.success());
    assert!(
        stderr(&o).contains("/nonexistent/fishprobe-study"),
        "{}",
        stderr(&o)
    );
    // A corrupt results.json is reported as missing analysis, not a crash.
    let d = dir("report-corrupt");
    let s = d.to_str().unwrap();
    ok(&["bench", "stats", "--size", "small", "--dir", s, "--json"]);
    std::fs::create_dir_all(d.join("analysis")).unwrap();
    std::fs::write(d.join("analysis/results.json"), b"{\"goals\": [1, 2").unwrap();
    let text = ok(&["report", s]);
    assert!(text.contains("not a JSON object"), "{text}");
    // A wrong setting names the field.
    let cfg = d.join("bad.toml");
    std::fs::write(&cfg, "png_scale = 0\n").unwrap();
    let o = fishprobe(&["report", s, "--config", cfg.to_str().unwrap()]);
    assert!(!o.status.success());
    assert!(stderr(&o).contains("png_scale"), "{}", stderr(&o));
}

/// Installs Debian's Chromium when it is missing (CI runs as root with the Debian registry).
/// Two tests need it; one installs while the other waits (apt refuses a second apt at once).
fn chromium() -> String {
    static INSTALL: std::sync::Mutex<()> = std::sync::Mutex::new(());
    let _one_at_a_time = INSTALL.lock().unwrap_or_else(|p| p.into_inner());
    for c in ["chromium", "chromium-browser"] {
        if Command::new("which")
            .arg(c)
            .output()
            .is_ok_and(|o| o.status.success())
        {
            return c.to_string();
        }
    }
    let install = Command::new("sh")
        .args([
            "-c",
            "apt-get update -qq && DEBIAN_FRONTEND=noninteractive apt-get install -y -qq chromium",
        ])
        .output()
        .expect("sh runs");
    assert!(
        install.status.success(),
        "installing chromium failed: {}",
        String::from_utf8_lossy(&install.stderr)
    );
    "chromium".into()
}

#[test]
fn the_report_renders_in_headless_chromium_without_errors() {
    let index = full_study().join("report/index.html");
    let url = format!("file://{}", index.display());
    let browser = chromium();
    let shots = PathBuf::from(env!("CARGO_TARGET_TMPDIR")).join("report-screenshots");
    std::fs::create_dir_all(&shots).unwrap();
    let shot = shots.join("index.png");
    let _ = std::fs::remove_file(&shot);
    let common_args = [
        "--headless",
        "--no-sandbox",
        "--disable-gpu",
        "--hide-scrollbars",
        "--enable-logging=stderr",
        "--v=0",
        "--virtual-time-budget=10000",
    ];
    let o = Command::new(&browser)
        .args(common_args)
        .arg("--window-size=1280,4000")
        .arg(format!("--screenshot={}", shot.display()))
        .arg(&url)
        .output()
        .unwrap();
    let log = String::from_utf8_lossy(&o.stderr).into_owned();
    assert!(o.status.success(), "{log}");
    let console: Vec<&str> = log.lines().filter(|l| l.contains(":CONSOLE")).collect();
    assert!(console.is_empty(), "console messages: {console:#?}");
    let png = std::fs::read(&shot).unwrap();
    assert!(png.len() > 50_000, "the screenshot is nearly empty");
    eprintln!("screenshot: {}", shot.display());
    // The page's own check: every image decoded.
    let o = Command::new(&browser)
        .args(common_args)
        .arg("--dump-dom")
        .arg(&url)
        .output()
        .unwrap();
    let dom = String::from_utf8_lossy(&o.stdout);
    assert!(
        dom.contains(&format!(
            "data-images=\"{}\" data-broken-images=\"0\"",
            FIGURES.len()
        )),
        "images not all displayed: {}",
        dom.lines()
            .find(|l| l.contains("<body"))
            .unwrap_or("no <body>")
    );
    let log = String::from_utf8_lossy(&o.stderr);
    assert!(!log.contains(":CONSOLE"), "{log}");
}

#[test]
fn a_broken_image_fails_the_page_check() {
    // The check above must be able to fail: a page with one undecodable figure.
    let d = dir("report-broken");
    let index = d.join("index.html");
    let html = read(&full_study().join("report/index.html")).replacen(
        "data:image/svg+xml;base64,",
        "data:image/svg+xml;base64,AAAA",
        1,
    );
    std::fs::write(&index, html).unwrap();
    let o = Command::new(chromium())
        .args([
            "--headless",
            "--no-sandbox",
            "--disable-gpu",
            "--enable-logging=stderr",
            "--v=0",
            "--virtual-time-budget=10000",
            "--dump-dom",
        ])
        .arg(format!("file://{}", index.display()))
        .output()
        .unwrap();
    let dom = String::from_utf8_lossy(&o.stdout);
    assert!(
        dom.contains("data-broken-images=\"1\""),
        "{}",
        dom.lines().find(|l| l.contains("<body")).unwrap_or("")
    );
    assert!(String::from_utf8_lossy(&o.stderr).contains("broken image"));
}
