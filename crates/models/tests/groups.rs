//! Groups: every model drives a group of fish in the tank and in a vector
//! environment, the group size is checked, and a school of M_Zone fish stays together.

use fishprobe_models::ModelSpec;
use fishprobe_sim::{group_order, Env, EnvConfig, TankEnv, TaskMode, VecEnv, MAX_FISH};

#[test]
fn every_model_drives_a_group_in_the_tank() {
    for name in ModelSpec::NAMES {
        for mode in [TaskMode::Training, TaskMode::Evaluation] {
            let model = ModelSpec::by_name(name).unwrap().build().unwrap();
            let cfg = EnvConfig {
                fish_count: 8,
                mode,
                ..EnvConfig::default()
            };
            let mut env = TankEnv::new(cfg, model).unwrap();
            let mut obs = vec![0.0; 180];
            env.reset(Some(3), &mut obs).unwrap();
            for t in 0..120 {
                let tr = env.step(&[((t % 5) as f32 - 2.0) * 0.7], &mut obs).unwrap();
                assert!(tr.reward.is_finite(), "{name}");
                assert!(obs.iter().all(|x| (0.0..=1.0).contains(x)), "{name}");
                if tr.truncated {
                    env.reset(None, &mut obs).unwrap();
                }
            }
            let fish = env.fish();
            assert_eq!(fish.len(), 8);
            for f in fish {
                assert!(f.x.abs() <= 50.0 && f.y.abs() <= 50.0, "{name}: {f:?}");
            }
        }
    }
}

#[test]
fn a_vector_environment_of_groups_batches_every_fish() {
    // ConvNet batches its inference over all fish of all environments.
    for name in ["ConvNet", "Zone"] {
        let model = ModelSpec::by_name(name).unwrap().build().unwrap();
        let cfg = EnvConfig {
            fish_count: 4,
            ..EnvConfig::default()
        };
        let mut v = VecEnv::new(cfg, model, 6).unwrap();
        v.reset(1).unwrap();
        for _ in 0..30 {
            v.step(&[0.3; 6]).unwrap();
        }
        assert!(v.observations().iter().all(|x| x.is_finite()), "{name}");
    }
}

#[test]
fn group_size_out_of_range_is_refused_naming_the_setting() {
    let model = ModelSpec::by_name("Zone").unwrap().build().unwrap();
    for n in [0, MAX_FISH as u32 + 1, u32::MAX] {
        let cfg = EnvConfig {
            fish_count: n,
            ..EnvConfig::default()
        };
        let e = TankEnv::new(cfg, model.clone()).unwrap_err().to_string();
        assert!(e.contains("fish_count") && e.contains("16"), "{e}");
    }
}

#[test]
fn a_school_of_zone_fish_stays_together() {
    // Eight M_Zone fish (published zones) hold together in the tank; the order parameters are
    // finite and in range for every model.
    let nnd = |name: &str| {
        let model = ModelSpec::by_name(name).unwrap().build().unwrap();
        let cfg = EnvConfig {
            fish_count: 8,
            mode: TaskMode::Evaluation,
            ..EnvConfig::default()
        };
        let mut env = TankEnv::new(cfg, model).unwrap();
        let mut obs = vec![0.0; 180];
        env.reset(Some(5), &mut obs).unwrap();
        let mut sum = 0.0;
        let mut k = 0;
        for t in 0..120 {
            env.step(&[0.0], &mut obs).unwrap();
            if t >= 30 {
                let g = group_order(env.fish()).unwrap();
                assert!((0.0..=1.0).contains(&g.polarisation), "{name}: {g:?}");
                assert!((0.0..=1.0 + 1e-6).contains(&g.milling), "{name}: {g:?}");
                sum += g.mean_nnd_cm;
                k += 1;
            }
        }
        sum / k as f32
    };
    let zone = nnd("Zone");
    let still = nnd("Stationary");
    assert!(zone < 10.0, "Zone school: mean NND {zone} cm");
    assert!(zone < 0.5 * still, "Zone {zone} vs motionless fish {still}");
}
