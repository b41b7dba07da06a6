//! A trial's file is written even when the process's descriptor table filled up during the
//! trial: the keeper secured what the write needs when the trial started. Alone in its test
//! binary, because it lowers the process's descriptor limit and fills the table.

#![allow(clippy::unwrap_used)] // a failure is a test failure

use fishprobe_io::read_trial;
use fishprobe_live::keep::{Keeper, Kept};
use fishprobe_live::session::{LiveConfig, Session};
use fishprobe_sim::{ControlInput, Controller, SimRng, TaskParams};

#[derive(Clone)]
struct Straight;
impl Controller for Straight {
    fn name(&self) -> String {
        "Straight".into()
    }
    fn act(&mut self, _input: &ControlInput<'_>, _rng: &mut SimRng) -> f32 {
        0.0
    }
}

#[test]
fn a_trial_is_written_under_an_exhausted_descriptor_table() {
    let dir = fishprobe_io::ScratchDir::for_test("live-descriptors");
    let session = Session::new(
        LiveConfig::default(),
        TaskParams::default(),
        Box::new(Straight),
        fishprobe_io::TrialKind::Real,
    )
    .unwrap();
    let trial = session.trial_file("live guppy");
    let file = dir.join("Straight__Real").join("trial_000.hdf5");
    std::fs::create_dir_all(file.parent().unwrap()).unwrap();

    // A low limit, so filling the table is quick.
    let limit = rustix::process::getrlimit(rustix::process::Resource::Nofile);
    rustix::process::setrlimit(
        rustix::process::Resource::Nofile,
        rustix::process::Rlimit {
            current: Some(256),
            maximum: limit.maximum,
        },
    )
    .unwrap();

    let mut keeper = Keeper::new(Some(dir.join("fallback")));
    assert!(keeper.reserve(), "descriptors secured as the trial starts");
    // During the trial something takes every descriptor left.
    let mut hog = Vec::new();
    let full = loop {
        match std::fs::File::open("/dev/null") {
            Ok(f) => hog.push(f),
            Err(e) => break e,
        }
        assert!(hog.len() < 100_000, "the limit did not hold");
    };
    assert_eq!(full.raw_os_error(), Some(24), "{full}"); // EMFILE
    assert!(std::fs::File::create(dir.join("probe")).is_err());

    let kept = keeper.keep(&file, trial);
    let written = matches!(&kept, Kept::Written(f) if *f == file);
    drop(hog);
    assert!(written, "{kept:?}");
    let back = read_trial(&file).unwrap();
    assert_eq!(back.task.unwrap().policy, "Straight");
}
