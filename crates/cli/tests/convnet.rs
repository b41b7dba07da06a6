//! End-to-end tests of `fishprobe fit-convnet` and `fishprobe compare-offline` on the shared
//! recordings of live guppy pairs.

#![allow(clippy::unwrap_used)] // a failure is a test failure

mod common;

use common::{fishprobe, fresh_dir as dir, pairs, stderr, stdout};
use fishprobe_io::{write_trial, Category, Entity, TrialFile};
use std::collections::BTreeMap;
use std::path::{Path, PathBuf};

fn first_file(dir: &Path) -> PathBuf {
    let mut v: Vec<PathBuf> = std::fs::read_dir(dir)
        .unwrap()
        .map(|e| e.unwrap().path())
        .collect();
    v.sort();
    v[0].clone()
}

fn fish(name: &str, frames: usize, world: f32) -> Entity {
    Entity {
        name: name.into(),
        category: Category::Fish,
        category_label: "organism".into(),
        positions: (0..frames)
            .map(|t| [(t as f32 * 0.1) % (world / 2.0 - 2.0), 1.0])
            .collect(),
        orientations: vec![[1.0, 0.0]; frames],
        attributes: BTreeMap::new(),
    }
}

/// `world` NaN: a 100 x 100 cm file whose tracks are all NaN.
fn write_pair(path: &Path, n_fish: usize, frames: usize, world: f32) {
    let mut entities: Vec<Entity> = (0..n_fish)
        .map(|i| fish(&format!("fish_{i}"), frames, world))
        .collect();
    let world = if world.is_nan() { 100.0 } else { world };
    let t = TrialFile {
        world_size_cm: [world, world],
        frame_rate_hz: 25.0,
        entities: std::mem::take(&mut entities),
        attributes: BTreeMap::new(),
        task: None,
    };
    write_trial(path, &t).unwrap();
}

#[test]
fn fit_convnet_writes_weights_a_sidecar_and_a_log_that_the_fish_model_uses() {
    let Some(p) = pairs() else { return };
    let d = dir("fit-convnet");
    let out = d.join("w/convnet.safetensors");
    let train = first_file(&p.join("train"));
    let val = first_file(&p.join("validation"));
    let o = fishprobe(&[
        "fit-convnet",
        "--data",
        train.to_str().unwrap(),
        "--validation",
        val.to_str().unwrap(),
        "--out",
        out.to_str().unwrap(),
        "--max-epochs",
        "2",
    ]);
    assert!(o.status.success(), "{}", stderr(&o));
    let text = stdout(&o);
    for needle in ["ConvNet", "marginal histogram", "no-neighbour ConvNet"] {
        assert!(text.contains(needle), "{text}");
    }
    let meta: serde_json::Value = serde_json::from_str(
        &std::fs::read_to_string(d.join("w/convnet.safetensors.json")).unwrap(),
    )
    .unwrap();
    let nll = meta["validation_nll"].as_f64().unwrap();
    let marginal = meta["baselines"]["marginal_histogram_nll"]
        .as_f64()
        .unwrap();
    assert!(nll.is_finite() && nll < (1025f64).ln(), "{nll}");
    assert!(marginal.is_finite());
    assert_eq!(meta["validation_files"].as_array().unwrap().len(), 1);
    assert!(meta["command"]
        .as_str()
        .unwrap()
        .starts_with("fishprobe fit-convnet"));
    let log = std::fs::read_to_string(d.join("w/convnet.training.csv")).unwrap();
    assert!(
        log.starts_with("epoch,train_nll,val_nll") && log.lines().count() >= 2,
        "{log}"
    );
    // The weights drive the fish model (here in the offline comparison).
    let o = fishprobe(&[
        "compare-offline",
        "--data",
        val.to_str().unwrap(),
        "--models",
        "ConvNet",
        "--convnet-weights",
        out.to_str().unwrap(),
        "--reps",
        "20",
        "--out",
        d.join("off").to_str().unwrap(),
    ]);
    assert!(o.status.success(), "{}", stderr(&o));
}

#[test]
fn bad_pair_files_are_skipped_by_name_and_an_empty_dataset_is_an_error() {
    let d = dir("convnet-bad");
    let bad = d.join("bad");
    std::fs::create_dir_all(&bad).unwrap();
    write_pair(&bad.join("one_fish.hdf5"), 1, 400, 100.0);
    write_pair(&bad.join("three_fish.hdf5"), 3, 400, 100.0);
    write_pair(&bad.join("short.hdf5"), 2, 20, 100.0);
    write_pair(&bad.join("big_tank.hdf5"), 2, 400, 200.0);
    write_pair(&bad.join("all_nan.hdf5"), 2, 400, f32::NAN);
    std::fs::write(bad.join("garbage.hdf5"), b"not hdf5 at all").unwrap();
    let good = d.join("good");
    std::fs::create_dir_all(&good).unwrap();
    write_pair(&good.join("pair.hdf5"), 2, 400, 100.0);
    let o = fishprobe(&[
        "fit-convnet",
        "--data",
        bad.to_str().unwrap(),
        "--validation",
        good.to_str().unwrap(),
        "--out",
        d.join("w.safetensors").to_str().unwrap(),
    ]);
    assert!(!o.status.success());
    let e = stderr(&o);
    assert!(e.contains("no training examples"), "{e}");
    // With one usable file, the others are skipped with warnings that name file and reason.
    std::fs::copy(good.join("pair.hdf5"), bad.join("pair.hdf5")).unwrap();
    let o = fishprobe(&[
        "fit-convnet",
        "--data",
        bad.to_str().unwrap(),
        "--validation",
        good.to_str().unwrap(),
        "--out",
        d.join("w.safetensors").to_str().unwrap(),
        "--max-epochs",
        "1",
        "--no-baselines",
    ]);
    assert!(o.status.success(), "{}", stderr(&o));
    let e = stderr(&o);
    for (file, why) in [
        ("one_fish.hdf5", "1 fish"),
        ("three_fish.hdf5", "3 fish"),
        ("short.hdf5", "shorter than"),
        ("big_tank.hdf5", "200 x 200"),
        ("all_nan.hdf5", "NaN"),
        ("garbage.hdf5", "garbage"),
    ] {
        assert!(
            e.lines().any(|l| l.contains(file) && l.contains(why)),
            "no warning for {file} ({why}): {e}"
        );
    }
    // An ensemble, then one network into the same file: the first fit's further member and
    // disagreement file go (they belong to the old weights).
    let w3 = d.join("w3.safetensors");
    let fit = |members: &str| {
        fishprobe(&[
            "fit-convnet",
            "--data",
            good.to_str().unwrap(),
            "--validation",
            bad.to_str().unwrap(),
            "--out",
            w3.to_str().unwrap(),
            "--max-epochs",
            "1",
            "--no-baselines",
            "--members",
            members,
        ])
    };
    let ensemble = [
        "w3.safetensors.member-2.safetensors",
        "w3.safetensors.member-2.safetensors.json",
        "w3.safetensors.disagreement.json",
    ];
    let o = fit("2");
    assert!(o.status.success(), "{}", stderr(&o));
    for f in ensemble {
        assert!(d.join(f).is_file(), "{f}");
    }
    let o = fit("1");
    assert!(o.status.success(), "{}", stderr(&o));
    for f in ensemble {
        assert!(!d.join(f).exists(), "{f} left behind");
    }
    assert!(w3.is_file() && d.join("w3.safetensors.support.json").is_file());
    // Training and validation must not mix.
    let o = fishprobe(&[
        "fit-convnet",
        "--data",
        good.to_str().unwrap(),
        "--validation",
        good.to_str().unwrap(),
        "--out",
        d.join("w2.safetensors").to_str().unwrap(),
    ]);
    assert!(!o.status.success());
    assert!(stderr(&o).contains("must not mix"), "{}", stderr(&o));
    // Weights that do not match the architecture: a clear error.
    let meta = d.join("w.safetensors.json");
    let text = std::fs::read_to_string(&meta)
        .unwrap()
        .replace("\"conv_channels\": 8", "\"conv_channels\": 9");
    std::fs::write(&meta, text).unwrap();
    let o = fishprobe(&[
        "compare-offline",
        "--data",
        good.to_str().unwrap(),
        "--models",
        "ConvNet",
        "--convnet-weights",
        d.join("w.safetensors").to_str().unwrap(),
        "--out",
        d.join("off").to_str().unwrap(),
    ]);
    assert!(!o.status.success());
    let e = stderr(&o);
    assert!(
        e.contains("w.safetensors") && e.contains("architecture"),
        "{e}"
    );
}

#[test]
fn an_interrupted_ensemble_fit_resumes_to_the_networks_of_an_uninterrupted_one() {
    let d = dir("convnet-resume");
    let (train, val) = (d.join("train"), d.join("val"));
    for (dir, frames) in [(&train, 600), (&val, 400)] {
        std::fs::create_dir_all(dir).unwrap();
        write_pair(&dir.join("pair.hdf5"), 2, frames, 100.0);
    }
    let fit = |out: &str, extra: &[&str]| {
        let mut args = vec![
            "fit-convnet",
            "--data",
            train.to_str().unwrap(),
            "--validation",
            val.to_str().unwrap(),
            "--max-epochs",
            "2",
        ];
        let out = d.join(out);
        args.extend(["--out", out.to_str().unwrap()]);
        args.extend(extra);
        let o = fishprobe(&args);
        assert!(o.status.success(), "{}", stderr(&o));
        stderr(&o)
    };
    let nets = |stem: &str| -> Vec<Vec<u8>> {
        ["", ".member-2.safetensors", ".member-3.safetensors"]
            .iter()
            .map(|m| std::fs::read(d.join(format!("{stem}.safetensors{m}"))).unwrap())
            .collect()
    };
    let baseline = |stem: &str| -> serde_json::Value {
        let text = std::fs::read_to_string(d.join(format!("{stem}.safetensors.json"))).unwrap();
        let meta: serde_json::Value = serde_json::from_str(&text).unwrap();
        meta["baselines"]["no_neighbour_nll"].clone()
    };
    // One run of three networks, uninterrupted.
    fit("a.safetensors", &["--members", "3"]);
    let whole = nets("a");
    assert!(baseline("a").is_number());
    // A run stopped after its second network (as a run of two, without the baseline), then
    // resumed for three with the baseline: the two finished networks are taken, the rest is
    // fitted, and every network is the uninterrupted run's, byte for byte.
    let first = fit("b.safetensors", &["--members", "2", "--no-baselines"]);
    assert!(!first.contains("kept"), "{first}");
    assert!(baseline("b").is_null());
    let e = fit("b.safetensors", &["--members", "3", "--resume"]);
    assert!(
        e.contains("ConvNet: kept")
            && e.contains("ensemble member: kept")
            && e.contains("b.safetensors.member-2.safetensors, fitted by an earlier run")
            && e.contains("ensemble member: epoch 1")
            && e.contains("no-neighbour baseline: epoch 1")
            && !e.contains("ConvNet: epoch"),
        "{e}"
    );
    assert_eq!(nets("b"), whole);
    assert_eq!(baseline("b"), baseline("a"));
    assert!(d.join("b.safetensors.disagreement.json").is_file());
    // Resumed again with everything finished: nothing is fitted.
    let e = fit("b.safetensors", &["--members", "3", "--resume"]);
    assert!(!e.contains("epoch"), "{e}");
    assert_eq!(nets("b"), whole);
    // A member whose tensors are not those its sidecar describes (a write cut short between
    // the two files), and a member of another seed: fitted again, and right again.
    let m2 = d.join("b.safetensors.member-2.safetensors");
    std::fs::copy(d.join("b.safetensors.member-3.safetensors"), &m2).unwrap();
    let m3 = d.join("b.safetensors.member-3.safetensors.json");
    let text = std::fs::read_to_string(&m3).unwrap();
    let mut meta: serde_json::Value = serde_json::from_str(&text).unwrap();
    meta["seed"] = 7.into();
    std::fs::write(&m3, meta.to_string()).unwrap();
    let e = fit("b.safetensors", &["--members", "3", "--resume"]);
    assert!(
        e.contains(
            "member-2.safetensors cannot be taken (its weights are not those its sidecar describes"
        ) && e.contains("member-3.safetensors cannot be taken (it was fitted with another seed)"),
        "{e}"
    );
    assert_eq!(nets("b"), whole);
    // Other settings (here the learning rate): the network is fitted again, not taken.
    let settings = d.join("lr.toml");
    std::fs::write(&settings, "learning_rate = 0.01\n").unwrap();
    let settings = settings.to_str().unwrap();
    let e = fit(
        "b.safetensors",
        &["--members", "3", "--resume", "--config", settings],
    );
    assert!(
        e.contains("ConvNet: fitted again")
            && e.contains("it was fitted on other data or with other settings"),
        "{e}"
    );
    assert_ne!(nets("b")[0], whole[0]);
}

#[test]
fn offline_comparison_on_the_validation_pairs_ranks_the_shipped_convnet_closest() {
    let Some(p) = pairs() else { return };
    let d = dir("offline");
    let o = fishprobe(&[
        "compare-offline",
        "--data",
        p.join("validation").to_str().unwrap(),
        "--reps",
        "200",
        "--out",
        d.to_str().unwrap(),
    ]);
    assert!(o.status.success(), "{}", stderr(&o));
    let csv = std::fs::read_to_string(d.join("offline.csv")).unwrap();
    assert_eq!(csv.lines().count(), 1 + 4 * 7, "{csv}");
    assert!(d.join("offline_histograms.png").is_file());
    assert!(d.join("offline_histograms.svg").is_file());
    let r: serde_json::Value =
        serde_json::from_str(&std::fs::read_to_string(d.join("offline.json")).unwrap()).unwrap();
    assert_eq!(r["recordings"].as_array().unwrap().len(), 5);
    let w = |m: &str, k: &str| r["gaps"][m][k]["w"].as_f64().unwrap();
    let metrics = [
        "speed",
        "turn_rate",
        "wall_distance",
        "iid",
        "alignment",
        "paused",
    ];
    let closer = |other: &str| {
        metrics
            .iter()
            .filter(|k| w("ConvNet", k) < w(other, k))
            .count()
    };
    assert!(
        closer("Zone") >= 4,
        "ConvNet closer than Zone on only {} of 6",
        closer("Zone")
    );
    // Against M_Force the turn rate, alignment and inter-individual distance go to M_Force:
    // the recordings' per-frame turn rate holds the tracker's frame-to-frame jitter, which
    // M_ConvNet, fitted on headings smoothed over 0.2 s, does not imitate (docs/validation.md,
    // "M_ConvNet and the virtual guppy against held-back real pairs"). Where a fish is in the tank and how fast it swims are
    // M_ConvNet's, against every model.
    assert!(
        closer("Force") >= 3,
        "ConvNet closer than Force on only {} of 6",
        closer("Force")
    );
    for k in ["speed", "wall_distance", "paused"] {
        for other in ["Zone", "Force", "Follow"] {
            assert!(
                w("ConvNet", k) < w(other, k),
                "{k}: ConvNet {} vs {other} {}",
                w("ConvNet", k),
                w(other, k)
            );
        }
    }
}

/// The spread across recordings, against values computed from the files with h5py and numpy
/// (per recording over both fish: the mean of the speeds from consecutive tracked positions
/// at 25 Hz, the fraction below 0.5 cm/s, the median distance between the fish), and the
/// robot-fish recordings compared open loop.
#[test]
fn recordings_spread_and_the_robot_recordings_open_loop() {
    let Some(p) = pairs() else { return };
    let robot = p.join("../../robot-fish");
    assert!(robot.is_dir(), "{} is missing", robot.display());
    let d = dir("offline-spread");
    let o = fishprobe(&[
        "compare-offline",
        "--data",
        p.join("validation").to_str().unwrap(),
        robot.to_str().unwrap(),
        "--models",
        "Zone,ConvNet",
        "--reps",
        "200",
        "--out",
        d.to_str().unwrap(),
    ]);
    assert!(o.status.success(), "{}", stderr(&o));
    let r: serde_json::Value =
        serde_json::from_str(&std::fs::read_to_string(d.join("offline.json")).unwrap()).unwrap();
    let names: Vec<&str> = r["recordings"]
        .as_array()
        .unwrap()
        .iter()
        .map(|v| v.as_str().unwrap())
        .collect();
    assert!(
        names[0].ends_with("2019-05-03T14_58_30_8108-sub_0.hdf5"),
        "{names:?}"
    );
    let real = |stat: &str| -> Vec<f64> {
        r["spread"]["values"]["real"][stat]
            .as_array()
            .unwrap()
            .iter()
            .map(|v| v.as_f64().unwrap())
            .collect()
    };
    let close = |got: &[f64], want: &[f64], tol: f64| {
        assert_eq!(got.len(), want.len());
        for (g, w) in got.iter().zip(want) {
            assert!((g - w).abs() <= tol * w.abs(), "{got:?} vs {want:?}");
        }
    };
    close(
        &real("mean_speed"),
        &[6.265_466_7, 3.173_974_8, 5.779_738, 9.087_251, 6.228_023_5],
        1e-5,
    );
    close(
        &real("paused_fraction"),
        &[
            0.021_526_31,
            0.095_505_62,
            0.029_146_735,
            0.019_412_615,
            0.025_253_087,
        ],
        // A speed within f32 rounding of the threshold counts either way: the legacy files'
        // positions are converted to the tank's frame in f32 (one frame of 17,978 here).
        4e-3,
    );
    close(
        &real("median_iid"),
        &[5.747_818, 21.373_531, 6.290_469, 3.606_642_7, 4.165_882],
        1e-5,
    );
    let e = &r["spread"]["models"]["ConvNet"]["mean_speed"];
    assert!(
        (e["sd_real"].as_f64().unwrap() - 2.099_487_3).abs() < 1e-5,
        "{e}"
    );
    let ratio = e["ratio"].as_f64().unwrap();
    assert!(
        ratio > 0.0 && ratio < 1.0,
        "M_ConvNet's pairs vary less than live ones: {e}"
    );
    assert_eq!(
        r["spread"]["values"]["ConvNet"]["mean_speed"]
            .as_array()
            .unwrap()
            .len(),
        5
    );
    // M_Zone swims at one speed: its pairs hardly differ.
    assert!(
        r["spread"]["models"]["Zone"]["mean_speed"]["ratio"]
            .as_f64()
            .unwrap()
            < 0.05
    );
    assert!(r["spread"]["split_half"]["mean_speed"].as_f64().unwrap() > 0.0);
    assert_eq!(
        r["spread"]["correlations"]["real"]
            .as_array()
            .unwrap()
            .len(),
        28
    );
    // The robot recordings, open loop: the live fish's values (h5py: mean speed at 20 Hz,
    // median robot-fish distance) and every model's fish beside the replayed robot.
    let o = &r["open_loop"];
    assert_eq!(o["recordings"].as_array().unwrap().len(), 2);
    let v = &o["spread"]["values"]["real"];
    for (stat, want) in [
        ("mean_speed", [8.325_03, 11.379_752]),
        ("median_iid", [25.535_713, 18.386_68]),
    ] {
        let got: Vec<f64> = v[stat]
            .as_array()
            .unwrap()
            .iter()
            .map(|x| x.as_f64().unwrap())
            .collect();
        close(&got, &want, 1e-5);
    }
    for m in ["Zone", "ConvNet"] {
        assert!(o["gaps"][m]["iid"]["w"].as_f64().unwrap() > 0.0);
        assert_eq!(
            o["spread"]["values"][m]["median_iid"]
                .as_array()
                .unwrap()
                .len(),
            2
        );
    }
    for f in [
        "offline_spread.csv",
        "offline_recordings.csv",
        "offline_correlations.csv",
        "offline_spread.png",
        "open_loop_histograms.png",
        "open_loop_spread.svg",
    ] {
        assert!(d.join(f).is_file(), "{f} missing");
    }
    let md = std::fs::read_to_string(d.join("offline.md")).unwrap();
    assert!(
        md.contains("robot-fish distance") && md.contains("How much recordings differ"),
        "{md}"
    );
    let rows = std::fs::read_to_string(d.join("offline_recordings.csv")).unwrap();
    // 8 statistics x 5 recordings x 3 sources + 8 x 2 x 3, and the header.
    assert_eq!(rows.lines().count(), 1 + 8 * 5 * 3 + 8 * 2 * 3, "{rows}");
}

#[test]
fn the_virtual_guppy_matches_validation_pairs_better_than_zone_and_force() {
    // Calibrated on the training pairs only; checked here on the validation pairs.
    let Some(p) = pairs() else { return };
    let d = dir("guppy-offline");
    let o = fishprobe(&[
        "compare-offline",
        "--data",
        p.join("validation").to_str().unwrap(),
        "--models",
        "Zone,Force,Guppy",
        "--reps",
        "100",
        "--out",
        d.to_str().unwrap(),
    ]);
    assert!(o.status.success(), "{}", stderr(&o));
    let r: serde_json::Value =
        serde_json::from_str(&std::fs::read_to_string(d.join("offline.json")).unwrap()).unwrap();
    let w = |m: &str, k: &str| r["gaps"][m][k]["w"].as_f64().unwrap();
    for k in ["speed", "turn_rate", "wall_distance", "paused"] {
        for other in ["Zone", "Force"] {
            assert!(
                w("Guppy", k) < w(other, k),
                "{k}: virtual guppy {} vs {other} {}",
                w("Guppy", k),
                w(other, k)
            );
        }
    }
}

/// `compare-offline` on a directory a hostile or careless hand made: a link looping back to
/// the directory, 10,000 tiny files named `*.hdf5`, a pair recorded at 50 Hz beside one at
/// 25 Hz, and a file rewritten in place (torn) while it reads. Documented behaviour
/// (docs/guide/analyse.md): entries that are no usable pair are skipped with a warning naming
/// them, each recording is read at its own frame rate, and the rest is compared; nothing
/// panics or hangs.
#[cfg(unix)]
#[test]
fn compare_offline_takes_hostile_directories_as_documented() {
    let d = dir("offline-hostile");
    let data = d.join("data");
    std::fs::create_dir_all(&data).unwrap();
    write_pair(&data.join("a_pair.hdf5"), 2, 400, 100.0);
    let mut t = fishprobe_io::read_trial(&data.join("a_pair.hdf5")).unwrap();
    t.frame_rate_hz = 50.0;
    write_trial(&data.join("b_pair_50hz.hdf5"), &t).unwrap();
    std::os::unix::fs::symlink(&data, data.join("loop.hdf5")).unwrap();
    for i in 0..10_000 {
        std::fs::write(data.join(format!("tiny_{i:05}.hdf5")), b"x").unwrap();
    }
    let good = std::fs::read(data.join("a_pair.hdf5")).unwrap();
    let torn = common::TornFile::start(&data.join("c_torn.hdf5"), good);
    let start = std::time::Instant::now();
    let o = fishprobe(&[
        "compare-offline",
        "--data",
        data.to_str().unwrap(),
        "--models",
        "Zone",
        "--reps",
        "10",
        "--out",
        d.join("off").to_str().unwrap(),
    ]);
    drop(torn);
    let e = stderr(&o);
    assert!(o.status.success(), "{e}");
    assert!(
        start.elapsed().as_secs() < 300,
        "took {:?}",
        start.elapsed()
    );
    for name in ["loop.hdf5", "tiny_00000.hdf5", "tiny_09999.hdf5"] {
        assert!(
            e.contains(name),
            "{name} not named: {}",
            &e[..e.len().min(2000)]
        );
    }
    let r: serde_json::Value =
        serde_json::from_str(&std::fs::read_to_string(d.join("off/offline.json")).unwrap())
            .unwrap();
    let used = r["recordings"].to_string();
    assert!(
        used.contains("a_pair.hdf5") && used.contains("b_pair_50hz.hdf5"),
        "{used}"
    );
}
