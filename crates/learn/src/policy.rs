//! The robot's policy: a diagonal Gaussian over the turn command whose mean and log-s.d. come
//! from one MLP, and a separate MLP for the value (RLlib's default continuous model with
//! `vf_share_layers = false`). Actions are "normalised" as in RLlib: the network acts in
//! [-1, 1], which maps linearly onto the action space [-π, π] (samples are clipped to it).
//! The log-s.d. may be bounded above ([`PpoConfig::log_std_max`]); the bound belongs to the
//! policy and is saved with it, so that sampling after training uses the training distribution.

use crate::config::PpoConfig;
use crate::error::LearnError;
use fishprobe_nn::store::{load, save, Tensors};
use fishprobe_nn::{Mlp, MlpSpec, MlpWorkspace};
use rand::Rng;
use serde_json::json;
use std::f32::consts::PI;
use std::path::{Path, PathBuf};

/// Name of the weights file in a policy directory.
pub const POLICY_FILE: &str = fishprobe_io::RunLayout::POLICY;
/// Format version of policy files.
pub const POLICY_VERSION: u64 = 1;

/// Policy and value networks.
#[derive(Debug, Clone, PartialEq)]
pub struct GaussianPolicy {
    /// Policy network: observation → (mean, log-s.d.) of the normalised action.
    pub pi: Mlp,
    /// Value network: observation → V.
    pub vf: Mlp,
    /// Upper bound on the log-s.d. (`None`: unbounded); see [`PpoConfig::log_std_max`].
    pub log_std_max: Option<f32>,
}

/// `raw` limited to `max` (`None`: unlimited). Above the bound the log-s.d. is constant; the
/// PPO update still lets through a gradient that lowers `raw`, so the bound is a cap the
/// policy can leave, not a trap (`ppo::above_bound_gradient`).
#[inline]
pub fn bounded_log_std(raw: f32, max: Option<f32>) -> f32 {
    match max {
        Some(m) => raw.min(m),
        None => raw,
    }
}

/// The normalised action's scale: env action = clip(a, -1, 1) · π.
pub fn to_env_action(normalised: f32) -> f32 {
    normalised.clamp(-1.0, 1.0) * PI
}

impl GaussianPolicy {
    /// Fresh networks for `obs_dim` inputs (RLlib's normc initialisation: 0.01 on the policy
    /// output, 1.0 on the value output).
    pub fn new<R: Rng>(obs_dim: usize, cfg: &PpoConfig, rng: &mut R) -> Self {
        let sizes = |out: usize| {
            let mut s = vec![obs_dim];
            s.extend(&cfg.hidden);
            s.push(out);
            s
        };
        Self {
            pi: Mlp::new(
                MlpSpec {
                    sizes: sizes(2),
                    hidden: cfg.activation,
                },
                0.01,
                rng,
            ),
            vf: Mlp::new(
                MlpSpec {
                    sizes: sizes(1),
                    hidden: cfg.activation,
                },
                1.0,
                rng,
            ),
            log_std_max: cfg.log_std_max,
        }
    }

    /// The log-s.d. of the action distribution for the network's raw log-s.d. output.
    #[inline]
    pub fn log_std(&self, raw: f32) -> f32 {
        bounded_log_std(raw, self.log_std_max)
    }

    /// Observation length it expects.
    pub fn obs_dim(&self) -> usize {
        self.pi.input_size()
    }

    /// The deterministic (mean) normalised actions for a batch of observations.
    pub fn mean_actions(&self, obs: &[f32], batch: usize, ws: &mut MlpWorkspace, out: &mut [f32]) {
        let y = self.pi.forward(obs, batch, ws);
        for (o, row) in out.iter_mut().zip(y.chunks_exact(2)) {
            *o = row[0];
        }
    }

    /// Writes `dir/policy.safetensors` and its JSON sidecar (architecture, format version,
    /// and `about`: what it was trained on).
    pub fn save(&self, dir: &Path, about: serde_json::Value) -> Result<PathBuf, LearnError> {
        let mut t = Tensors::new();
        for (prefix, net) in [("pi", &self.pi), ("vf", &self.vf)] {
            let sizes = &net.spec().sizes;
            for l in 0..sizes.len() - 1 {
                let (w, b) = net.layer(l);
                t.insert(
                    format!("{prefix}.{l}.weight"),
                    (vec![sizes[l], sizes[l + 1]], w.to_vec()),
                );
                t.insert(
                    format!("{prefix}.{l}.bias"),
                    (vec![sizes[l + 1]], b.to_vec()),
                );
            }
        }
        let meta = json!({
            "format": "fishprobe-policy",
            "version": POLICY_VERSION,
            "obs_dim": self.obs_dim(),
            "pi": self.pi.spec(),
            "vf": self.vf.spec(),
            "action": "normalised; env action = clip(a, -1, 1) * pi rad",
            "log_std_max": self.log_std_max,
            "about": about,
        });
        let path = dir.join(POLICY_FILE);
        save(&path, &t, &meta)?;
        Ok(path)
    }

    /// Reads a policy directory (or a `policy.safetensors` file), checking format, version
    /// and shapes.
    pub fn load(path: &Path) -> Result<(Self, serde_json::Value), LearnError> {
        let file = if path.is_dir() {
            path.join(POLICY_FILE)
        } else {
            path.to_path_buf()
        };
        let bad = |what: String| LearnError::Policy(format!("{}: {what}", file.display()));
        if !file.is_file() {
            // Missing, or something else than a file (a device, a link that leads nowhere):
            // say which.
            let what = match fishprobe_io::limits::not_regular(&file) {
                Some(_) if std::fs::symlink_metadata(&file).is_err() => "missing:".to_string(),
                Some(kind) => format!("{kind}, so"),
                None => "not a file, so".to_string(),
            };
            return Err(bad(format!(
                "{what} not a policy directory (train one with `fishprobe train`)"
            )));
        }
        let (tensors, meta) = load(&file)?;
        if meta["format"] != "fishprobe-policy" {
            return Err(bad(format!(
                "not a fishprobe policy (format {})",
                meta["format"]
            )));
        }
        if meta["version"].as_u64() != Some(POLICY_VERSION) {
            return Err(bad(format!("policy format version {} is not {POLICY_VERSION} (written by another fishprobe version)", meta["version"])));
        }
        let net = |prefix: &str| -> Result<Mlp, LearnError> {
            let spec: MlpSpec = serde_json::from_value(meta[prefix].clone())
                .map_err(|e| bad(format!("{prefix} architecture: {e}")))?;
            let mut params = Vec::new();
            for l in 0..spec.sizes.len().saturating_sub(1) {
                for (part, shape) in [
                    ("weight", vec![spec.sizes[l], spec.sizes[l + 1]]),
                    ("bias", vec![spec.sizes[l + 1]]),
                ] {
                    let name = format!("{prefix}.{l}.{part}");
                    match tensors.get(&name) {
                        Some((s, d)) if *s == shape => params.extend_from_slice(d),
                        Some((s, _)) => {
                            return Err(bad(format!(
                                "tensor {name} has shape {s:?}, the architecture says {shape:?}"
                            )))
                        }
                        None => return Err(bad(format!("tensor {name} is missing"))),
                    }
                }
            }
            Mlp::from_params(spec, params)
                .ok_or_else(|| bad(format!("{prefix}: parameter count does not match")))
        };
        // Absent in files written before the bound existed: those policies were unbounded.
        let log_std_max = match &meta["log_std_max"] {
            serde_json::Value::Null => None,
            v => Some(
                v.as_f64()
                    .filter(|m| m.is_finite())
                    .ok_or_else(|| bad(format!("log_std_max {v} is not a number")))?
                    as f32,
            ),
        };
        let policy = Self {
            pi: net("pi")?,
            vf: net("vf")?,
            log_std_max,
        };
        if policy.pi.output_size() != 2
            || policy.vf.output_size() != 1
            || policy.vf.input_size() != policy.obs_dim()
        {
            return Err(bad(
                "networks do not have the policy's shape (pi: 2 outputs, vf: 1)".into(),
            ));
        }
        Ok((policy, meta))
    }

    /// SHA-256 (hex) of what decides the policy's actions: the policy network's layer sizes
    /// and weights (little-endian f32) and its log-s.d. bound. The value network is left
    /// out: two policies that differ only there drive the robot alike. Trial files record it
    /// ([`fishprobe_sim::Controller::fingerprint`]).
    pub fn fingerprint(&self) -> String {
        let sizes = &self.pi.spec().sizes;
        let params = self.pi.params();
        let mut bytes = Vec::with_capacity(8 * (sizes.len() + 1) + 4 * params.len());
        for &n in sizes {
            bytes.extend_from_slice(&(n as u64).to_le_bytes());
        }
        for v in params {
            bytes.extend_from_slice(&v.to_le_bytes());
        }
        match self.log_std_max {
            Some(m) => bytes.extend_from_slice(&m.to_le_bytes()),
            None => bytes.extend_from_slice(b"unbounded"),
        }
        fishprobe_onnx::sha256_hex(&bytes)
    }

    /// Checks the policy fits an environment's observation size.
    pub fn check_obs_dim(&self, env_obs: usize) -> Result<(), LearnError> {
        if self.obs_dim() == env_obs {
            Ok(())
        } else {
            Err(LearnError::Policy(format!(
                "the policy was built for observations of {} floats, the environment gives {env_obs}",
                self.obs_dim()
            )))
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use rand::SeedableRng;

    #[test]
    fn a_path_that_is_no_policy_says_what_it_is() {
        let e = |p: &str| {
            GaussianPolicy::load(Path::new(p))
                .err()
                .unwrap()
                .to_string()
        };
        let missing = e("/nonexistent/policy");
        assert!(
            missing.contains("missing: not a policy directory"),
            "{missing}"
        );
        let device = e("/dev/zero");
        assert!(
            device.contains("/dev/zero: a device, not a regular file, so not a policy directory"),
            "{device}"
        );
    }

    #[test]
    fn the_log_std_bound_caps_and_travels_with_the_policy() {
        assert_eq!(bounded_log_std(0.7, Some(0.0)), 0.0);
        assert_eq!(bounded_log_std(-0.7, Some(0.0)), -0.7);
        assert_eq!(bounded_log_std(3.0, None), 3.0);

        let dir = std::env::temp_dir().join(format!("fishprobe-policy-{}", std::process::id()));
        std::fs::create_dir_all(&dir).unwrap();
        let mut rng = rand_xoshiro::Xoshiro256PlusPlus::seed_from_u64(1);
        let cfg = PpoConfig::preset("smoke").unwrap();
        let p = GaussianPolicy::new(6, &cfg, &mut rng);
        assert_eq!(p.log_std_max, Some(0.0));
        p.save(&dir, json!({})).unwrap();
        assert_eq!(GaussianPolicy::load(&dir).unwrap().0, p);

        // A sidecar from before the bound existed: an unbounded policy.
        let sidecar = dir.join(format!("{POLICY_FILE}.json"));
        let mut meta: serde_json::Value =
            serde_json::from_str(&std::fs::read_to_string(&sidecar).unwrap()).unwrap();
        meta.as_object_mut().unwrap().remove("log_std_max");
        std::fs::write(&sidecar, meta.to_string()).unwrap();
        assert_eq!(GaussianPolicy::load(&dir).unwrap().0.log_std_max, None);

        // The fingerprint: the same after a save and a load, another for other policy
        // weights or bound, the same for another value network.
        let loaded = GaussianPolicy::load(&dir).unwrap().0;
        let mut q = p.clone();
        q.log_std_max = None;
        assert_eq!(loaded.fingerprint(), q.fingerprint());
        assert_ne!(p.fingerprint(), q.fingerprint());
        assert_eq!(p.fingerprint().len(), 64);
        q.vf.params_mut()[0] += 1.0;
        assert_eq!(loaded.fingerprint(), q.fingerprint());
        q.pi.params_mut()[0] += 1.0;
        assert_ne!(loaded.fingerprint(), q.fingerprint());

        meta["log_std_max"] = json!("wide");
        std::fs::write(&sidecar, meta.to_string()).unwrap();
        let e = GaussianPolicy::load(&dir).unwrap_err().to_string();
        assert!(e.contains("log_std_max"), "{e}");
        std::fs::remove_dir_all(&dir).unwrap();
    }
}
