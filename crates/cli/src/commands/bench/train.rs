//! `fishprobe bench train`: the single-core matrix multiply, the PPO update and a training
//! run end to end.

use super::{emit, machine, timed};
use anyhow::{Context, Result};
use fishprobe_models::ModelSpec;
use fishprobe_sim::stream;
use std::time::Instant;

/// FLOPs of one forward and backward pass of an MLP on `m` rows (dense layers only).
fn mlp_flops(sizes: &[usize], m: usize) -> f64 {
    let macs: Vec<f64> = sizes.windows(2).map(|w| (w[0] * w[1]) as f64).collect();
    let forward: f64 = macs.iter().sum::<f64>() * 2.0 * m as f64;
    // Backward: weight gradients for every layer, input gradients for all but the first.
    let backward = forward + (macs.iter().sum::<f64>() - macs[0]) * 2.0 * m as f64;
    forward + backward
}

pub(super) fn bench_train(json: bool, iterations: u64, model_name: &str) -> Result<()> {
    use fishprobe_learn::ppo::{update, Rollout, Scratch};
    use fishprobe_learn::{GaussianPolicy, PpoConfig, RunSpec, Trainer};
    let m = machine();
    // 1. Single-core GEMM rate at the update's shapes (512 x 256 · 256 x 256).
    let (a, b) = (vec![0.5f32; 512 * 256], vec![0.25f32; 256 * 256]);
    let mut c = vec![0.0f32; 512 * 256];
    let per = 2.0 * 512.0 * 256.0 * 256.0;
    let (reps, secs) = timed(1.0, || {
        fishprobe_nn::gemm::gemm(
            1.0,
            fishprobe_nn::gemm::Mat::new(&a, 512, 256),
            fishprobe_nn::gemm::Mat::new(&b, 256, 256),
            0.0,
            &mut c,
            512,
            256,
        );
        Ok(1)
    })?;
    let gemm_gflops = per * reps as f64 / secs / 1e9;

    // 2. PPO update (paper network, minibatch and batch sizes) on one batch sampled from the
    // model's environment by the fresh policy: real observations are mostly zero, which the
    // first layer exploits, so a synthetic dense batch would misstate the update's speed.
    let cfg = PpoConfig {
        num_sgd_iter: 2,
        ..PpoConfig::default()
    };
    let mut rng = stream(0, "bench-train", 0);
    let mut venv = fishprobe_sim::VecEnv::new(
        fishprobe_sim::EnvConfig::default(),
        ModelSpec::by_name(model_name)?.build()?,
        cfg.num_envs,
    )?;
    venv.reset(0)?;
    let obs_dim = venv.obs_dim();
    let mut policy = GaussianPolicy::new(obs_dim, &cfg, &mut rng);
    let mut roll = Rollout::new(cfg.num_envs, cfg.train_batch_size / cfg.num_envs, obs_dim);
    let mut scratch = Scratch::default();
    fishprobe_learn::ppo::collect(&cfg, &mut venv, &policy, &mut roll, &mut rng, &mut scratch)?;
    let mut adam_pi = fishprobe_nn::Adam::new(policy.pi.num_params(), cfg.lr);
    let mut adam_vf = fishprobe_nn::Adam::new(policy.vf.num_params(), cfg.lr);
    let minibatches_per_call = cfg.num_sgd_iter * (cfg.train_batch_size / cfg.sgd_minibatch_size);
    let (calls, secs) = timed(3.0, || {
        update(
            &cfg,
            &mut policy,
            &mut adam_pi,
            &mut adam_vf,
            0.2,
            &mut roll,
            &mut rng,
            &mut scratch,
        )
        .map_err(|_| fishprobe_sim::SimError::NeedsReset)?;
        Ok(1)
    })?;
    let mb_per_s = (calls as usize * minibatches_per_call) as f64 / secs;
    let flops_mb = mlp_flops(&policy.pi.spec().sizes, cfg.sgd_minibatch_size)
        + mlp_flops(&policy.vf.spec().sizes, cfg.sgd_minibatch_size);
    let update_gflops = flops_mb * mb_per_s / 1e9;

    // 3. End to end: `iterations` iterations of the `published` preset (100 epochs per batch,
    // the speed target) and of the `paper` preset (for this model) against the model.
    let model = ModelSpec::by_name(model_name)?;
    let mut e2e = Vec::new();
    for preset in ["published", "paper"] {
        let dir = std::env::temp_dir().join(format!(
            "fishprobe-bench-train-{}-{preset}",
            std::process::id()
        ));
        let _ = std::fs::remove_dir_all(&dir);
        let scratch = fishprobe_io::ScratchDir::remove_on_drop(dir.clone());
        let spec = RunSpec::new(
            model.clone(),
            PpoConfig::preset_for(preset, model.is_expensive()).context("PPO preset")?,
            fishprobe_sim::EnvConfig::default(),
            0,
            preset,
            crate::commands::BUILD,
        );
        let (total, epochs) = (spec.ppo.total_timesteps, spec.ppo.num_sgd_iter);
        let mut t = Trainer::create(&dir, spec)?;
        let start = Instant::now();
        for _ in 0..iterations.max(1) {
            t.iterate()?;
        }
        let e2e_secs = start.elapsed().as_secs_f64();
        drop(scratch);
        let steps_per_s = t.timesteps() as f64 / e2e_secs;
        e2e.push((
            preset,
            epochs,
            total,
            steps_per_s,
            total as f64 / steps_per_s / 60.0,
        ));
    }
    let text = if json {
        let runs: Vec<_> = e2e
            .iter()
            .map(|(preset, epochs, total, sps, min)| {
                serde_json::json!({"preset": preset, "epochs_per_batch": epochs,
                    "total_timesteps": total, "train_steps_per_s": sps, "run_minutes_projected": min})
            })
            .collect();
        serde_json::to_string_pretty(&serde_json::json!({
            "bench": "train", "machine": m, "gemm_gflops_single_core": gemm_gflops,
            "update_minibatches_per_s": mb_per_s, "update_gflops": update_gflops,
            "update_gflops_per_core": update_gflops / m.cores as f64,
            "model": model_name, "iterations": iterations.max(1), "end_to_end": runs,
            "command": "fishprobe bench train --json",
        }))? + "\n"
    } else {
        let mut s = format!(
            "fishprobe bench train — {} cores, {} ({} {})\n\
             matrix multiply, one core (512x256 · 256x256):  {gemm_gflops:.1} GFLOP/s\n\
             PPO update (2 x [180, 256, 256, out] MLPs, minibatch 512): {mb_per_s:.1} minibatches/s, {update_gflops:.1} GFLOP/s dense-equivalent ({:.1} per core, {:.0} % of the single-core GEMM rate)\n",
            m.cores, m.cpu, m.os, m.arch,
            update_gflops / m.cores as f64,
            100.0 * update_gflops / m.cores as f64 / gemm_gflops,
        );
        for (preset, epochs, total, sps, min) in &e2e {
            s += &format!(
                "end to end ({preset} preset, {epochs} epochs per batch, {} iterations, {model_name}): {sps:.0} steps/s -> a full {total}-step run takes {min:.1} min\n",
                iterations.max(1)
            );
        }
        s
    };
    emit(&text)
}
