//! End-to-end tests of populations of individuals: `fishprobe fit-population` (fit, report,
//! resume, refusals), a population wherever a model goes (`simulate`, `compare-offline`,
//! `models`), and the drawn individual recorded in the trial file.

#![allow(clippy::unwrap_used)] // a failure is a test failure

mod common;

use common::{fishprobe, fresh_dir as dir, pairs, stderr, stdout};

/// Settings for a fit in seconds: one simulation per recording, two iterations, no
/// correlations.
const QUICK: &str = "replicates = 1\ncheck_replicates = 1\niterations = 2\ncorrelations = false\n";

#[test]
fn a_population_is_fitted_checked_resumed_and_used_wherever_a_model_goes() {
    let Some(p) = pairs() else { return };
    let d = dir("population-fit");
    let settings = d.join("quick.toml");
    std::fs::write(&settings, QUICK).unwrap();
    let out = d.join("zone.population.json");
    // Fitted on the five validation recordings, checked on the robot-fish recordings (open
    // loop): small and disjoint.
    let robot = p.join("../../robot-fish");
    let args = |extra: &[&str]| {
        let mut v: Vec<String> = [
            "fit-population",
            "--model",
            "Zone",
            "--data",
            p.join("validation").to_str().unwrap(),
            "--validation",
            robot.to_str().unwrap(),
            "--config",
            settings.to_str().unwrap(),
            "--out",
            out.to_str().unwrap(),
        ]
        .iter()
        .map(|s| s.to_string())
        .collect();
        v.extend(extra.iter().map(|s| s.to_string()));
        v
    };
    let run = |extra: &[&str]| {
        let a = args(extra);
        let a: Vec<&str> = a.iter().map(String::as_str).collect();
        fishprobe(&a)
    };
    let o = run(&[]);
    assert!(o.status.success(), "{}", stderr(&o));
    let e = stderr(&o);
    assert!(
        e.contains("iteration 1/2") && e.contains("iteration 2/2"),
        "{e}"
    );
    let text = stdout(&o);
    assert!(
        text.contains("ZonePop") && text.contains("recordings it did not use"),
        "{text}"
    );
    let pop: serde_json::Value =
        serde_json::from_str(&std::fs::read_to_string(&out).unwrap()).unwrap();
    assert_eq!(pop["name"], "ZonePop");
    assert_eq!(pop["base"]["model"], "Zone");
    assert_eq!(pop["traits"].as_array().unwrap().len(), 6, "{pop}");
    assert_eq!(pop["fit"]["training_files"].as_array().unwrap().len(), 5);
    assert!(
        pop["fit"]["validation"]["models"]["ZonePop"]["spread"]["mean_speed"]["ratio"].is_number()
    );
    assert!(d.join("zone.population.json.md").is_file());
    // Run again: the progress file holds the whole fit; nothing is simulated again.
    let o = run(&[]);
    assert!(o.status.success(), "{}", stderr(&o));
    assert!(
        stderr(&o).contains("holds this fit, complete"),
        "{}",
        stderr(&o)
    );
    // Another seed is another fit: it starts over and says so.
    let o = run(&["--seed", "1"]);
    assert!(o.status.success(), "{}", stderr(&o));
    assert!(stderr(&o).contains("holds another fit"), "{}", stderr(&o));

    // The population as a model: simulate records each fish's individual.
    let spec = format!("population:{}", out.display());
    let trial = d.join("pop.hdf5");
    let o = fishprobe(&[
        "simulate",
        "--model",
        &spec,
        "--minutes",
        "0.1",
        "--out",
        trial.to_str().unwrap(),
    ]);
    assert!(o.status.success(), "{}", stderr(&o));
    let t = fishprobe_io::read_trial(&trial).unwrap();
    let fish = t.fish().next().unwrap();
    let ind = match fish.attributes.get(fishprobe_io::INDIVIDUAL_ATTRIBUTE) {
        Some(fishprobe_io::Attr::Text(j)) => j.clone(),
        other => panic!("no individual recorded: {other:?}"),
    };
    let ind: fishprobe_sim::Individual = serde_json::from_str(&ind).unwrap();
    assert!(ind.speed > 0.0 && !ind.is_neutral(), "{ind:?}");
    assert_eq!(t.task.unwrap().fish_model, "ZonePop");
}

#[test]
fn shipped_populations_are_listed_and_bad_fits_are_refused_by_name() {
    let o = fishprobe(&["models"]);
    assert!(o.status.success(), "{}", stderr(&o));
    let text = stdout(&o);
    for name in ["ZonePop", "ForcePop", "GuppyPop", "ConvNetPop"] {
        assert!(text.contains(name), "{name} not listed");
    }
    let d = dir("population-bad");
    let out = d.join("p.json");
    for (args, why) in [
        (vec!["--model", "ZonePop"], "names a population"),
        (vec!["--model", "Couzin"], "unknown fish model"),
        (
            vec!["--model", "Zone", "--cv", "1"],
            "--cv must lie in [2, 20]",
        ),
        (
            vec!["--model", "Zone", "--iterations", "0"],
            "fit.iterations",
        ),
    ] {
        let mut a = vec!["fit-population", "--out", out.to_str().unwrap()];
        a.extend(args);
        let o = fishprobe(&a);
        assert!(!o.status.success(), "{a:?} was accepted");
        assert!(stderr(&o).contains(why), "{a:?}: {}", stderr(&o));
    }
    // A damaged population file is refused naming the file.
    std::fs::write(&out, b"{\"model\": \"Population\", \"traits\": [\"spee\"]}").unwrap();
    let spec = format!("population:{}", out.display());
    let o = fishprobe(&[
        "simulate",
        "--model",
        &spec,
        "--out",
        d.join("x.hdf5").to_str().unwrap(),
    ]);
    assert!(!o.status.success());
    assert!(
        stderr(&o).contains("p.json") && stderr(&o).contains("not a population file"),
        "{}",
        stderr(&o)
    );
}
