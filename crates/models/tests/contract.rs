//! Every fish model in every task mode passes the environment checker.

use fishprobe_models::ModelSpec;
use fishprobe_sim::{check_env, EnvConfig, TankEnv, TaskMode, VecEnv};

#[test]
fn every_model_passes_the_checker_in_both_modes() {
    for name in ModelSpec::NAMES {
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
    // Force steps each environment on one core; ConvNet runs its batched inference split
    // into one call per core, so 1, 2 and 3 threads give it batches of 6, 3 and 2 fish.
    for (name, steps) in [("Force", 100), ("ConvNet", 30)] {
        let run = |threads: usize| {
            let pool = rayon::ThreadPoolBuilder::new()
                .num_threads(threads)
                .build()
                .unwrap();
            pool.install(|| {
                let model = ModelSpec::by_name(name).unwrap().build().unwrap();
                let mut v = VecEnv::new(EnvConfig::default(), model, 6).unwrap();
                v.reset(99).unwrap();
                let mut trace = Vec::new();
                let mut goals = 0;
                for t in 0..steps {
                    let actions: Vec<f32> = (0..6)
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
                (trace, goals)
            })
        };
        let (one, goals) = run(1);
        let (two, _) = run(2);
        let (three, _) = run(3);
        assert!(
            one == two && one == three,
            "{name}: thread count changed the results"
        );
        // 100 steps of 41-step episodes: two full autoresets per environment.
        assert!(goals < 1000, "{name}: {goals}");
    }
}
