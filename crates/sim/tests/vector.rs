//! The vector environment: autoreset, the batched (lockstep) path, bad actions.

use fishprobe_sim::{
    Env, EnvConfig, FishMind, FishModel, FishMotion, FishView, SimError, SimRng, TankEnv, VecEnv,
};
use rand_distr::{Distribution, StandardNormal};
use std::sync::Arc;

/// Swims toward the robot with noise; the direction comes from "inference" when batched.
#[derive(Debug)]
struct Chaser {
    batched: bool,
}

impl FishModel for Chaser {
    fn name(&self) -> &str {
        "Chaser"
    }
    fn inference_width(&self) -> usize {
        if self.batched {
            1
        } else {
            0
        }
    }
    fn infer_batch(&self, views: &[FishView], out: &mut [f32]) {
        for (v, o) in views.iter().zip(out) {
            *o = direction(v);
        }
    }
    fn decide(
        &self,
        v: &FishView,
        inferred: &[f32],
        _: &mut FishMind,
        rng: &mut SimRng,
    ) -> FishMotion {
        let dir = if self.batched {
            inferred[0]
        } else {
            direction(v)
        };
        let noise: f32 = StandardNormal.sample(rng);
        FishMotion {
            heading: dir + 0.3 * noise,
            speed: 6.0,
        }
    }
}

fn direction(v: &FishView) -> f32 {
    let r = v.others()[0];
    (r.y - v.me.y).atan2(r.x - v.me.x)
}

fn actions(t: usize, n: usize) -> Vec<f32> {
    (0..n)
        .map(|i| ((t * 5 + i * 11) % 17) as f32 * 0.35 - 2.8)
        .collect()
}

#[test]
fn lockstep_batched_path_equals_sequential_envs() {
    let n = 4;
    let mut vec = VecEnv::new(EnvConfig::default(), Arc::new(Chaser { batched: true }), n).unwrap();
    vec.reset(5).unwrap();
    let mut singles: Vec<TankEnv> = (0..n)
        .map(|_| TankEnv::new(EnvConfig::default(), Arc::new(Chaser { batched: false })).unwrap())
        .collect();
    let mut obs = vec![vec![0.0; 180]; n];
    for (i, (e, o)) in singles.iter_mut().zip(&mut obs).enumerate() {
        e.reset(Some(fishprobe_sim::derive_seed(5, "env", i as u64)), o)
            .unwrap();
    }
    for t in 0..90 {
        let a = actions(t, n);
        vec.step(&a).unwrap();
        for i in 0..n {
            let tr = singles[i].step(&a[i..i + 1], &mut obs[i]).unwrap();
            assert_eq!(tr, vec.transitions()[i], "step {t} env {i}");
            if tr.truncated {
                assert_eq!(
                    &vec.final_observations()[i * 180..(i + 1) * 180],
                    &obs[i][..]
                );
                singles[i].reset(None, &mut obs[i]).unwrap();
            }
            assert_eq!(
                &vec.observations()[i * 180..(i + 1) * 180],
                &obs[i][..],
                "step {t} env {i}"
            );
        }
    }
}

#[test]
fn autoreset_reports_finished_episodes() {
    let mut vec =
        VecEnv::new(EnvConfig::default(), Arc::new(Chaser { batched: false }), 3).unwrap();
    vec.reset(1).unwrap();
    for t in 0..41 {
        vec.step(&actions(t, 3)).unwrap();
        let done = vec.transitions().iter().all(|tr| tr.truncated);
        assert_eq!(done, t == 40);
        assert_eq!(vec.finished_episodes().iter().all(Option::is_some), t == 40);
    }
    for f in vec.finished_episodes().iter().flatten() {
        assert_eq!(f.actions, 41);
    }
    // The new episodes have begun: a further step is fine.
    vec.step(&actions(0, 3)).unwrap();
    assert!(vec.finished_episodes().iter().all(Option::is_none));
}

#[test]
fn bad_actions_are_rejected_before_anything_moves() {
    let mut vec =
        VecEnv::new(EnvConfig::default(), Arc::new(Chaser { batched: false }), 3).unwrap();
    vec.reset(1).unwrap();
    let before = vec.observations().to_vec();
    let err = vec.step(&[0.0, f32::NAN, 0.0]).unwrap_err();
    assert!(
        matches!(err, SimError::NonFiniteAction { index: 1, value } if value.is_nan()),
        "{err}"
    );
    assert_eq!(vec.observations(), &before[..]);
    assert!(matches!(
        vec.step(&[0.0; 2]),
        Err(SimError::ActionShape {
            expected: 3,
            got: 2
        })
    ));
    assert!(VecEnv::new(EnvConfig::default(), Arc::new(Chaser { batched: false }), 0).is_err());
}

#[test]
fn snapshot_and_restore_continue_exactly() {
    let mut a = VecEnv::new(EnvConfig::default(), Arc::new(Chaser { batched: false }), 3).unwrap();
    a.reset(8).unwrap();
    for t in 0..30 {
        a.step(&actions(t, 3)).unwrap();
    }
    let (snap, obs) = a.snapshot();
    let json = serde_json::to_string(&snap).unwrap();
    let mut b = VecEnv::new(EnvConfig::default(), Arc::new(Chaser { batched: false }), 3).unwrap();
    b.reset(999).unwrap();
    b.restore(
        &serde_json::from_str::<Vec<fishprobe_sim::EnvSnapshot>>(&json).unwrap(),
        &obs,
    )
    .unwrap();
    for t in 30..100 {
        a.step(&actions(t, 3)).unwrap();
        b.step(&actions(t, 3)).unwrap();
        assert_eq!(a.observations(), b.observations(), "step {t}");
        assert_eq!(a.transitions(), b.transitions(), "step {t}");
    }
    let small = VecEnv::new(EnvConfig::default(), Arc::new(Chaser { batched: false }), 2).unwrap();
    let mut small = small;
    assert!(small.restore(&snap, &obs).is_err());
}

/// [`Chaser`]'s batched path, recording the size of every inference batch; `concurrent` is
/// what it answers to `concurrent_inference`.
#[derive(Debug)]
struct Locked {
    concurrent: bool,
    batches: std::sync::Mutex<Vec<usize>>,
}

impl FishModel for Locked {
    fn name(&self) -> &str {
        "Locked"
    }
    fn inference_width(&self) -> usize {
        1
    }
    fn concurrent_inference(&self) -> bool {
        self.concurrent
    }
    fn infer_batch(&self, views: &[FishView], out: &mut [f32]) {
        if let Ok(mut b) = self.batches.lock() {
            b.push(views.len());
        }
        Chaser { batched: true }.infer_batch(views, out);
    }
    fn decide(&self, v: &FishView, i: &[f32], m: &mut FishMind, rng: &mut SimRng) -> FishMotion {
        Chaser { batched: true }.decide(v, i, m, rng)
    }
}

#[test]
fn a_fish_behind_a_lock_is_asked_once_per_frame_for_every_fish_with_the_same_results() {
    let pool = rayon::ThreadPoolBuilder::new()
        .num_threads(2)
        .build()
        .unwrap();
    let n = 64;
    let run = |concurrent: bool| {
        let model = Arc::new(Locked {
            concurrent,
            batches: Default::default(),
        });
        let mut vec = VecEnv::new(EnvConfig::default(), model.clone(), n).unwrap();
        vec.reset(3).unwrap();
        let mut seen = Vec::new();
        pool.install(|| {
            for t in 0..45 {
                vec.step(&actions(t, n)).unwrap();
                seen.push((vec.observations().to_vec(), vec.transitions().to_vec()));
            }
        });
        let batches = model.batches.lock().unwrap().clone();
        (seen, batches)
    };
    let (locked, locked_batches) = run(false);
    let (free, free_batches) = run(true);
    // One call per frame, all 64 fish in it; split in two parts (one per thread) otherwise.
    assert_eq!(locked_batches.len(), 45 * 25);
    assert!(locked_batches.iter().all(|&b| b == n));
    assert_eq!(free_batches.len(), 2 * 45 * 25);
    assert!(free_batches.iter().all(|&b| b == n / 2));
    assert_eq!(locked, free);
}

/// Scores a view by its fish's distance from the tank's centre, and remembers the largest
/// batch it was asked to score.
#[derive(Debug, Default)]
struct Radius {
    largest_batch: std::sync::atomic::AtomicUsize,
}

impl fishprobe_sim::InputSupport for Radius {
    fn score(&self, v: &FishView) -> f32 {
        v.me.x.hypot(v.me.y) / 20.0
    }
    fn score_batch(&self, views: &[FishView], out: &mut [f32]) {
        self.largest_batch
            .fetch_max(views.len(), std::sync::atomic::Ordering::Relaxed);
        for (v, o) in views.iter().zip(out) {
            *o = self.score(v);
        }
    }
}

#[test]
fn the_lockstep_path_scores_all_environments_views_in_one_batch_with_the_same_rewards() {
    let n = 4;
    let mut cfg = EnvConfig::default();
    cfg.task.objective = fishprobe_sim::Objective::Ood;
    let batched = Arc::new(Radius::default());
    let mut vec = VecEnv::new(cfg.clone(), Arc::new(Chaser { batched: true }), n).unwrap();
    vec.set_support(Some(batched.clone()));
    vec.reset(5).unwrap();
    let alone = Arc::new(Radius::default());
    let mut singles: Vec<TankEnv> = (0..n)
        .map(|_| TankEnv::new(cfg.clone(), Arc::new(Chaser { batched: false })).unwrap())
        .collect();
    let mut obs = vec![vec![0.0; 180]; n];
    for (i, (e, o)) in singles.iter_mut().zip(&mut obs).enumerate() {
        e.set_support(Some(alone.clone()));
        e.reset(Some(fishprobe_sim::derive_seed(5, "env", i as u64)), o)
            .unwrap();
    }
    for t in 0..50 {
        let a = actions(t, n);
        vec.step(&a).unwrap();
        for i in 0..n {
            let tr = singles[i].step(&a[i..i + 1], &mut obs[i]).unwrap();
            assert!(tr.info.support_score > 0.0);
            assert_eq!(tr, vec.transitions()[i], "step {t} env {i}");
            if tr.truncated {
                singles[i].reset(None, &mut obs[i]).unwrap();
            }
        }
    }
    use std::sync::atomic::Ordering::Relaxed;
    assert_eq!(
        batched.largest_batch.load(Relaxed),
        n,
        "one batch per frame"
    );
    assert_eq!(
        alone.largest_batch.load(Relaxed),
        1,
        "a pair's frame: one fish"
    );
}
