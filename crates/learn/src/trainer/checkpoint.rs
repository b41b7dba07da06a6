//! A run's checkpoints: the networks, Adam's moments and `state.json` (the KL coefficient,
//! the sampling RNG and every environment's state mid-episode), written atomically, the two
//! newest kept, and `checkpoints/latest` naming the one to resume from.

use super::{run_err, Trainer};
use crate::error::LearnError;
use crate::policy::GaussianPolicy;
use fishprobe_io::RunLayout;
use fishprobe_nn::store::{load, save, write_atomic, Tensors};
use fishprobe_sim::{EnvSnapshot, SimRng};
use serde::{Deserialize, Serialize};
use std::path::{Path, PathBuf};

/// Largest `state.json` a resumed run reads. It holds every environment's state and
/// observation: at the limits (4,096 environments of 16 fish) some tens of megabytes.
pub const MAX_STATE_BYTES: u64 = 1 << 30;

/// Trainer state that is not networks: `state.json` of a checkpoint.
#[derive(Debug, Clone, Serialize, Deserialize)]
struct State {
    iteration: u64,
    timesteps: u64,
    episodes: u64,
    kl_coeff: f32,
    adam_t: (u64, u64),
    rng: SimRng,
    envs: Vec<EnvSnapshot>,
    obs: Vec<f32>,
}

impl Trainer {
    pub(super) fn about(&self) -> serde_json::Value {
        serde_json::json!({
            "model": self.spec.model.label(),
            "seed": self.spec.seed,
            "preset": self.spec.preset,
            "iteration": self.iteration,
            "timesteps": self.timesteps,
            // What the policy reads: evaluation, the yardstick and the live bridge check it.
            "observation": self.spec.env.observation,
            // and how often it acts: a policy of five actions a second is run at five.
            "frames_per_action": self.spec.env.frames_per_action,
            // at this frame rate: 25 frames at 50 Hz are half a second.
            "frame_rate_hz": self.spec.env.frame_rate_hz,
            "program_version": env!("CARGO_PKG_VERSION"),
        })
    }

    pub(super) fn save_checkpoint(&self) -> Result<(), LearnError> {
        let name = format!("ckpt_{:06}", self.iteration);
        let dir = self.dir.join(RunLayout::CHECKPOINTS).join(&name);
        self.policy.save(&dir, self.about())?;
        let mut optim = Tensors::new();
        for (k, adam) in [("pi", &self.adam_pi), ("vf", &self.adam_vf)] {
            optim.insert(format!("{k}.m"), (vec![adam.m.len()], adam.m.clone()));
            optim.insert(format!("{k}.v"), (vec![adam.v.len()], adam.v.clone()));
        }
        save(
            &dir.join("optim.safetensors"),
            &optim,
            &serde_json::json!({"format": "fishprobe-adam", "version": 1}),
        )?;
        let (envs, obs) = self.venv.snapshot();
        let state = State {
            iteration: self.iteration,
            timesteps: self.timesteps,
            episodes: self.episodes,
            kl_coeff: self.kl_coeff,
            adam_t: (self.adam_pi.t, self.adam_vf.t),
            rng: self.rng.clone(),
            envs,
            obs,
        };
        let text = serde_json::to_string(&state).map_err(|e| run_err(&dir, e))?;
        write_atomic(&dir.join("state.json"), text.as_bytes())?;
        // The pointer moves last: a crash before this line leaves the previous checkpoint.
        write_atomic(&self.dir.join("checkpoints/latest"), name.as_bytes())?;
        // Keep the two newest checkpoints.
        let mut all: Vec<PathBuf> = std::fs::read_dir(self.dir.join(RunLayout::CHECKPOINTS))
            .map_err(|e| run_err(&self.dir, e))?
            .filter_map(|e| e.ok().map(|e| e.path()))
            .filter(|p| p.is_dir())
            .collect();
        all.sort();
        for old in all.iter().rev().skip(2) {
            let _ = std::fs::remove_dir_all(old);
        }
        Ok(())
    }

    pub(super) fn load_checkpoint(&mut self, dir: &Path) -> Result<(), LearnError> {
        let (policy, _) = GaussianPolicy::load(dir)?;
        if policy.pi.spec() != self.policy.pi.spec() || policy.vf.spec() != self.policy.vf.spec() {
            return Err(run_err(dir, "checkpoint networks do not match params.json"));
        }
        // A checkpoint written before the bound existed holds an unbounded policy; continuing it
        // under params.json's (default) bound would change the run half-way.
        if policy.log_std_max != self.policy.log_std_max {
            let show = |b: Option<f32>| b.map_or_else(|| "none".to_string(), |m| m.to_string());
            return Err(run_err(
                dir,
                format!(
                    "the checkpoint's log-s.d. bound ({}) is not params.json's ({}): the run \
                     was started by another fishprobe version; finish it with that version or \
                     start it again",
                    show(policy.log_std_max),
                    show(self.policy.log_std_max)
                ),
            ));
        }
        self.policy = policy;
        let (optim, _) = load(&dir.join("optim.safetensors"))?;
        for (k, adam) in [("pi", &mut self.adam_pi), ("vf", &mut self.adam_vf)] {
            for (part, buf) in [("m", &mut adam.m), ("v", &mut adam.v)] {
                match optim.get(&format!("{k}.{part}")) {
                    Some((_, d)) if d.len() == buf.len() => buf.copy_from_slice(d),
                    _ => {
                        return Err(run_err(
                            dir,
                            format!("optimiser state {k}.{part} missing or of the wrong size"),
                        ))
                    }
                }
            }
        }
        let p = dir.join("state.json");
        let text = fishprobe_io::read_text_at_most(
            &p,
            MAX_STATE_BYTES,
            "not a checkpoint's state",
            "fishprobe_learn::trainer::MAX_STATE_BYTES",
        )
        .map_err(|e| run_err(&p, e))?;
        let s: State = serde_json::from_str(&text).map_err(|e| run_err(&p, e))?;
        self.venv.restore(&s.envs, &s.obs)?;
        self.iteration = s.iteration;
        self.timesteps = s.timesteps;
        self.episodes = s.episodes;
        self.kl_coeff = s.kl_coeff;
        self.adam_pi.t = s.adam_t.0;
        self.adam_vf.t = s.adam_t.1;
        self.rng = s.rng;
        Ok(())
    }
}

/// The checkpoint a resumed run continues from: the one `checkpoints/latest` names, or `None`
/// when the run was stopped before its first checkpoint was complete. `latest` is written after
/// each checkpoint and only ever replaced, so it is missing beside at most one (the first, cut
/// short); beside two or more it was lost, and a `latest` that cannot be read is refused too,
/// since starting the run over would overwrite its checkpoints and erase its logs.
pub(super) fn latest_checkpoint(dir: &Path) -> Result<Option<PathBuf>, LearnError> {
    let checkpoints = dir.join(RunLayout::CHECKPOINTS);
    let latest = checkpoints.join("latest");
    let name = match fishprobe_io::read_small_text(&latest) {
        Ok(name) => name,
        Err(e) if e.kind() == std::io::ErrorKind::NotFound => {
            let mut held: Vec<String> = std::fs::read_dir(&checkpoints)
                .map(|entries| {
                    entries
                        .filter_map(|e| e.ok())
                        .map(|e| e.file_name().to_string_lossy().into_owned())
                        .filter(|n| is_checkpoint_name(n))
                        .collect()
                })
                .unwrap_or_default();
            held.sort();
            return match held.last() {
                Some(newest) if held.len() >= 2 => Err(run_err(
                    &latest,
                    format!(
                        "missing, but checkpoints/ holds {} checkpoint(s), the newest {newest}: \
                         write the name of the one to resume from into this file (the newest \
                         may be incomplete if the run was stopped while writing it), or start \
                         the run over in another directory",
                        held.len()
                    ),
                )),
                _ => Ok(None),
            };
        }
        Err(e) => return Err(run_err(&latest, format!("cannot read: {e}"))),
    };
    let name = name.trim();
    if !is_checkpoint_name(name) {
        return Err(run_err(
            &latest,
            format!(
                "names {name:?}, not a checkpoint of this run (ckpt_ and the iteration, as \
                 ckpt_000012)"
            ),
        ));
    }
    Ok(Some(checkpoints.join(name)))
}

/// `ckpt_` and digits: the names [`Trainer`] gives its checkpoints.
fn is_checkpoint_name(name: &str) -> bool {
    name.strip_prefix("ckpt_")
        .is_some_and(|d| !d.is_empty() && d.bytes().all(|b| b.is_ascii_digit()))
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn checkpoint_names_are_the_trainers_own() {
        for good in ["ckpt_000001", "ckpt_1", "ckpt_123456789"] {
            assert!(is_checkpoint_name(good), "{good}");
        }
        for bad in [
            "",
            "ckpt_",
            "ckpt_-1",
            "ckpt_1/../..",
            "/etc",
            "../ckpt_1",
            "latest",
        ] {
            assert!(!is_checkpoint_name(bad), "{bad}");
        }
    }
}
