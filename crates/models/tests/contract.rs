//! Every fish model in every task mode passes the environment checker.

use fishprobe_models::ModelSpec;
use fishprobe_sim::{
    check_env, AgentState, EnvConfig, FishMind, FishModel, FishMotion, FishView, SimRng, TankEnv,
    TaskMode, VecEnv,
};
use std::sync::atomic::{AtomicU64, Ordering};
use std::sync::Arc;

/// A model that delegates to another and sums a hash of every fish's inferred row, so that a
/// test sees inference bits that a sampled trajectory would rarely show.
#[derive(Debug)]
struct Recording {
    inner: Arc<dyn FishModel>,
    sum: AtomicU64,
}

impl FishModel for Recording {
    fn name(&self) -> &str {
        self.inner.name()
    }
    fn begin_episode(&self, me: &AgentState, mind: &mut FishMind, rng: &mut SimRng) {
        self.inner.begin_episode(me, mind, rng)
    }
    fn inference_width(&self) -> usize {
        self.inner.inference_width()
    }
    fn infer_batch(&self, views: &[FishView], out: &mut [f32]) {
        self.inner.infer_batch(views, out);
        for row in out.chunks_exact(self.inference_width()) {
            let h = row.iter().fold(0xcbf2_9ce4_8422_2325u64, |h, v| {
                (h ^ u64::from(v.to_bits())).wrapping_mul(0x0100_0000_01b3)
            });
            self.sum.fetch_add(h, Ordering::Relaxed);
        }
    }
    fn decide(
        &self,
        view: &FishView,
        inferred: &[f32],
        mind: &mut FishMind,
        rng: &mut SimRng,
    ) -> FishMotion {
        self.inner.decide(view, inferred, mind, rng)
    }
}

#[test]
fn every_model_passes_the_checker_in_both_modes() {
    for name in ModelSpec::listed_names() {
        let model = ModelSpec::by_name(name).unwrap().build().unwrap();
        let mut train = TankEnv::new(EnvConfig::default(), model.clone()).unwrap();
        let r =
            check_env(&mut train, 3, u32::MAX).unwrap_or_else(|e| panic!("{name} training: {e}"));
        assert!(r.steps >= 82, "{name}: {r:?}");
        let eval_cfg = EnvConfig {
            mode: TaskMode::Evaluation,
            ..EnvConfig::default()
        };
        let mut eval = TankEnv::new(eval_cfg, model).unwrap();
        check_env(&mut eval, 4, 120).unwrap_or_else(|e| panic!("{name} evaluation: {e}"));
    }
}

#[test]
fn vector_env_is_deterministic_whatever_the_thread_count() {
    // Force steps each environment on one core. ConvNet's batched inference is split into one
    // call per core: with 64 environments, 1, 2 and 4 threads give calls of 64, 32 and 16 fish,
    // and every inferred bit must be the same.
    for (name, envs, steps, threads) in
        [("Force", 6, 100, [1, 2, 3]), ("ConvNet", 64, 8, [1, 2, 4])]
    {
        let run = |threads: usize| {
            let pool = rayon::ThreadPoolBuilder::new()
                .num_threads(threads)
                .build()
                .unwrap();
            pool.install(|| {
                let model = Arc::new(Recording {
                    inner: ModelSpec::by_name(name).unwrap().build().unwrap(),
                    sum: AtomicU64::new(0),
                });
                let mut v = VecEnv::new(EnvConfig::default(), model.clone(), envs).unwrap();
                v.reset(99).unwrap();
                let mut trace = Vec::new();
                let mut goals = 0;
                for t in 0..steps {
                    let actions: Vec<f32> = (0..envs)
                        .map(|i| ((t * 7 + i * 3) % 13) as f32 * 0.4 - 2.4)
                        .collect();
                    v.step(&actions).unwrap();
                    trace.extend_from_slice(v.observations());
                    trace.extend(v.transitions().iter().map(|t| t.reward));
                    goals += v
                        .finished_episodes()
                        .iter()
                        .flatten()
                        .map(|e| e.goal_events.len())
                        .sum::<usize>();
                }
                (trace, model.sum.load(Ordering::Relaxed), goals)
            })
        };
        let (one, sum_one, goals) = run(threads[0]);
        for t in &threads[1..] {
            let (other, sum, _) = run(*t);
            assert!(
                one == other && sum_one == sum,
                "{name}: {t} threads changed the results"
            );
        }
        // 100 steps of 41-step episodes: two full autoresets per environment.
        assert!(goals < 1000, "{name}: {goals}");
    }
}
