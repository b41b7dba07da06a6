//! Stepping an environment allocates nothing after reset, for every model: the per-frame
//! path (robot controller, fish models, goal logic, observation, and the OOD task's scoring
//! of the fish's views against the model's support) works in place.

// A counting GlobalAlloc cannot be written without unsafe; it only forwards to System.
#![allow(unsafe_code)]
#![allow(clippy::unwrap_used)] // a failure is a test failure

use fishprobe_models::ModelSpec;
use fishprobe_sim::{Env, EnvConfig, Objective, TankEnv, TaskMode};
use std::alloc::{GlobalAlloc, Layout, System};
use std::cell::Cell;
use std::sync::Arc;

struct Counting;

thread_local! {
    static COUNTING: Cell<bool> = const { Cell::new(false) };
    static COUNT: Cell<u64> = const { Cell::new(0) };
}

unsafe impl GlobalAlloc for Counting {
    unsafe fn alloc(&self, layout: Layout) -> *mut u8 {
        if COUNTING.with(Cell::get) {
            COUNT.with(|c| c.set(c.get() + 1));
        }
        unsafe { System.alloc(layout) }
    }
    unsafe fn dealloc(&self, ptr: *mut u8, layout: Layout) {
        unsafe { System.dealloc(ptr, layout) }
    }
}

#[global_allocator]
static GLOBAL: Counting = Counting;

/// Allocations while `env` takes 600 steps, after one step first: a network model sizes its
/// buffers on its first inference.
fn allocations_in_600_steps(env: &mut TankEnv) -> u64 {
    let mut obs = vec![0.0; 180];
    env.reset(Some(1), &mut obs).unwrap();
    env.step(&[0.0], &mut obs).unwrap();
    COUNT.with(|c| c.set(0));
    COUNTING.with(|c| c.set(true));
    for t in 0..600 {
        env.step(&[((t % 7) as f32 - 3.0) * 0.9], &mut obs).unwrap();
    }
    COUNTING.with(|c| c.set(false));
    COUNT.with(Cell::get)
}

#[test]
fn the_ood_task_scores_views_without_allocating() {
    let spec = ModelSpec::by_name("ConvNet").unwrap();
    let n = ood_allocations(Arc::new(spec.support().unwrap()));
    assert_eq!(n, 0, "the OOD task: {n} allocations in 600 steps");
}

/// [`allocations_in_600_steps`] of the OOD task against the shipped M_ConvNet, every frame's
/// views scored by `score`.
fn ood_allocations(score: Arc<dyn fishprobe_sim::InputSupport>) -> u64 {
    let spec = ModelSpec::by_name("ConvNet").unwrap();
    let mut cfg = EnvConfig {
        mode: TaskMode::Evaluation,
        ..EnvConfig::default()
    };
    cfg.task.objective = Objective::Ood;
    cfg.task.ood_score_every_frames = 1;
    let mut env = TankEnv::new(cfg, spec.build().unwrap()).unwrap();
    env.set_support(Some(score));
    allocations_in_600_steps(&mut env)
}

#[test]
fn the_ensembles_disagreement_scores_views_without_allocating() {
    use fishprobe_models::disagreement::{Disagreement, DisagreementFile, MemberRef};
    use fishprobe_models::ConvNet;
    use rand::RngExt;
    // The shipped network and a fresh one: an ensemble that disagrees everywhere.
    let shipped = ConvNet::shipped().unwrap();
    let mut rng = fishprobe_sim::stream(3, "no-alloc", 0);
    let fresh = ConvNet::new(shipped.arch.clone(), &mut rng);
    let views: Vec<f32> = (0..100 * shipped.arch.view_len())
        .map(|_| rng.random_range(0.0..1.0))
        .collect();
    let member = MemberRef {
        file: "fresh".into(),
        sha256: String::new(),
    };
    let file = DisagreementFile::new("t".into(), String::new(), vec![member], Default::default());
    let d = Disagreement::fit(vec![shipped, fresh], file, &views, 50, &mut rng).unwrap();
    let n = ood_allocations(Arc::new(d));
    assert_eq!(n, 0, "the disagreement score: {n} allocations in 600 steps");
}

#[test]
fn stepping_does_not_allocate() {
    // One fish (the paper) and a group of eight.
    for (name, fish_count) in ModelSpec::listed_names()
        .into_iter()
        .flat_map(|n| [(n, 1), (n, 8)])
    {
        let model = ModelSpec::by_name(name).unwrap().build().unwrap();
        let cfg = EnvConfig {
            mode: TaskMode::Evaluation,
            fish_count,
            ..EnvConfig::default()
        };
        let mut env = TankEnv::new(cfg, model).unwrap();
        let n = allocations_in_600_steps(&mut env);
        assert_eq!(
            n, 0,
            "{name} with {fish_count} fish: {n} allocations in 600 steps (15,000 frames)"
        );
    }
}
