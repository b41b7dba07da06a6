//! A corpus of damaged files made from the real ones (truncations, flipped bits, overwritten
//! bytes, wrong shapes): every read ends in a value or an error naming the file, never a
//! panic or a hang.

#![allow(clippy::unwrap_used)] // test helpers may unwrap: a failure is a test failure

use fishprobe_io::backend::{to_bytes, AttrOut, Data, GroupSpec};
use fishprobe_io::{read_legacy, read_trial, shared_data_dir};
use std::path::{Path, PathBuf};
use std::sync::mpsc;
use std::time::Duration;

/// xorshift64: the corpus is the same on every run.
struct Xs(u64);
impl Xs {
    fn next(&mut self) -> u64 {
        self.0 ^= self.0 << 13;
        self.0 ^= self.0 >> 7;
        self.0 ^= self.0 << 17;
        self.0
    }
    fn below(&mut self, n: usize) -> usize {
        (self.next() % n.max(1) as u64) as usize
    }
}

fn damage(orig: &[u8], variant: usize, rng: &mut Xs) -> Vec<u8> {
    let mut b = orig.to_vec();
    match variant % 4 {
        0 => b.truncate(rng.below(b.len())),
        1 => {
            // Metadata lives near the start and end of small files: flip bits there.
            for _ in 0..1 + rng.below(8) {
                let i = if rng.below(2) == 0 {
                    rng.below(b.len().min(4096))
                } else {
                    b.len() - 1 - rng.below(b.len().min(4096))
                };
                b[i] ^= 1 << rng.below(8);
            }
        }
        2 => {
            for _ in 0..1 + rng.below(4) {
                let i = rng.below(b.len());
                b[i] = rng.next() as u8;
            }
        }
        _ => {
            let i = rng.below(b.len().min(8192));
            let len = rng.below(64).min(b.len() - i);
            b[i..i + len].fill(0xff);
        }
    }
    b
}

/// Reads `path` in a thread; fails the test on a panic or after 20 s.
fn read_within_time_limit(path: PathBuf) -> Result<(), String> {
    let (tx, rx) = mpsc::channel();
    let p = path.clone();
    std::thread::spawn(move || {
        let r = std::panic::catch_unwind(|| {
            let a = read_trial(&p).map(|_| ()).map_err(|e| e.to_string());
            let b = read_legacy(&p).map(|_| ()).map_err(|e| e.to_string());
            (a, b)
        });
        let _ = tx.send(r);
    });
    match rx.recv_timeout(Duration::from_secs(20)) {
        Ok(Ok((a, b))) => {
            for e in [a, b].into_iter().filter_map(Result::err) {
                assert!(
                    e.contains(path.file_name().unwrap().to_str().unwrap()),
                    "error does not name the file: {e}"
                );
            }
            Ok(())
        }
        Ok(Err(_)) => Err(format!("{}: reading panicked", path.display())),
        Err(_) => Err(format!("{}: reading hung", path.display())),
    }
}

fn corpus_sources(d: &Path) -> Vec<PathBuf> {
    vec![
        d.join("examples/example.hdf5"),
        d.join("examples/second_example.hdf5"),
        d.join("robot-fish/Q12I_Fri_Dec__6_11_59_34_2019_Robotracker.hdf5"),
        d.join("guppy-pairs/robofish-io/CameraCapture2019-05-03T11_22_33_8108-sub_0.hdf5"),
        d.join("guppy-pairs/legacy/validation/CameraCapture2019-05-03T14_58_30_8108-sub_0.hdf5"),
    ]
}

#[test]
fn damaged_real_files_give_errors_not_panics() {
    let Some(d) = shared_data_dir() else {
        eprintln!("skipping: FISHPROBE_DATA is not set and ../shared/data is absent");
        return;
    };
    // 50 MB of damaged copies, kept only when the test fails.
    let out = fishprobe_io::ScratchDir::for_test("damaged");
    let mut rng = Xs(0x5eed_f15b_0000_0001);
    let mut failures = Vec::new();
    let mut n = 0;
    for src in corpus_sources(&d) {
        let orig = std::fs::read(&src).unwrap_or_else(|e| panic!("{}: {e}", src.display()));
        for v in 0..50 {
            let p = out.join(format!("damaged-{n:03}.hdf5"));
            std::fs::write(&p, damage(&orig, v, &mut rng)).unwrap();
            if let Err(e) = read_within_time_limit(p) {
                failures.push(e);
            }
            n += 1;
        }
    }
    assert!(n >= 250);
    assert!(failures.is_empty(), "{failures:#?}");
}

#[test]
fn structurally_wrong_files_are_named_errors() {
    let dir = fishprobe_io::ScratchDir::for_test("wrong");
    let text = |s: &str| AttrOut::Text(s.into());
    let base = |world: AttrOut, rate: Option<f32>, positions: Data| {
        let mut fish = GroupSpec::default();
        fish.attrs.push(("category".into(), text("fish")));
        fish.datasets.push(("positions".into(), positions));
        let mut entities = GroupSpec::default();
        entities.groups.push(("fish_1".into(), fish));
        let mut hz = GroupSpec::default();
        if let Some(r) = rate {
            hz.attrs.push(("frequency_hz".into(), AttrOut::F32(r)));
        }
        let mut samplings = GroupSpec::default();
        samplings.attrs.push(("default".into(), text("25 hz")));
        samplings.groups.push(("25 hz".into(), hz));
        let mut root = GroupSpec::default();
        root.attrs.push(("world_size_cm".into(), world));
        root.groups.push(("entities".into(), entities));
        root.groups.push(("samplings".into(), samplings));
        root
    };
    let good_pos = || Data::F32(vec![0.0; 20], vec![10, 2]);
    let cases: Vec<(&str, GroupSpec, &str)> = vec![
        (
            "world3.hdf5",
            base(
                AttrOut::F32s(vec![100.0, 100.0, 1.0]),
                Some(25.0),
                good_pos(),
            ),
            "world_size_cm is not 2",
        ),
        (
            "worldtext.hdf5",
            base(text("big"), Some(25.0), good_pos()),
            "world_size_cm is not 2",
        ),
        (
            "norate.hdf5",
            base(AttrOut::F32s(vec![100.0, 100.0]), None, good_pos()),
            "has no frequency_hz",
        ),
        (
            "zerorate.hdf5",
            base(AttrOut::F32s(vec![100.0, 100.0]), Some(0.0), good_pos()),
            "not a positive rate",
        ),
        (
            "shape3.hdf5",
            base(
                AttrOut::F32s(vec![100.0, 100.0]),
                Some(25.0),
                Data::F32(vec![0.0; 30], vec![10, 3]),
            ),
            "expected (frames, 2)",
        ),
        (
            "strings.hdf5",
            base(
                AttrOut::F32s(vec![100.0, 100.0]),
                Some(25.0),
                Data::Strings(vec!["a".into()]),
            ),
            "positions",
        ),
        (
            "noentities.hdf5",
            GroupSpec::default(),
            "no /entities group",
        ),
    ];
    for (name, spec, needle) in cases {
        let p = dir.join(name);
        std::fs::write(&p, to_bytes(&spec).unwrap()).unwrap();
        let e = read_trial(&p).expect_err(name).to_string();
        assert!(e.contains(needle) && e.contains(name), "{name}: {e}");
    }
    // A good one of the same construction reads.
    let p = dir.join("good.hdf5");
    std::fs::write(
        &p,
        to_bytes(&base(
            AttrOut::F32s(vec![100.0, 100.0]),
            Some(25.0),
            good_pos(),
        ))
        .unwrap(),
    )
    .unwrap();
    let t = read_trial(&p).unwrap();
    assert!(
        t.fish().next().unwrap().orientations[0][0].is_nan(),
        "missing orientations are NaN"
    );
    // Not HDF5 at all, and a missing file.
    let txt = dir.join("notes.hdf5");
    std::fs::write(&txt, "just text").unwrap();
    assert!(read_trial(&txt)
        .unwrap_err()
        .to_string()
        .contains("not an HDF5 file"));
    assert!(read_trial(&dir.join("absent.hdf5"))
        .unwrap_err()
        .to_string()
        .contains("cannot read"));
}
