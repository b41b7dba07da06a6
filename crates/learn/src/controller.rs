//! A trained policy as a [`Controller`], and the `--policy` argument every command reads.

use crate::error::LearnError;
use crate::policy::{to_env_action, GaussianPolicy};
use fishprobe_nn::MlpWorkspace;
use fishprobe_sim::{ControlInput, Controller, ObservationParams, SimRng};
use rand_distr::{Distribution, StandardNormal};
use std::path::Path;

/// A trained policy driving the robot: its mean action, or samples with `stochastic`.
#[derive(Debug, Clone)]
pub struct PolicyController {
    /// The policy.
    pub policy: Box<GaussianPolicy>,
    /// Sample instead of taking the mean.
    pub stochastic: bool,
    name: String,
    description: String,
    fingerprint: String,
    /// The observation settings it was trained with (its sidecar's `about.observation`;
    /// absent in policies trained before fishprobe recorded them).
    observation: Option<ObservationParams>,
    /// The frames per action it was trained at (`about.frames_per_action`; absent in policies
    /// trained before fishprobe recorded it).
    frames_per_action: Option<u32>,
    /// The simulator's frame rate it was trained at (`about.frame_rate_hz`; absent in
    /// policies trained before fishprobe recorded it).
    frame_rate_hz: Option<f32>,
    ws: MlpWorkspace,
}

impl PolicyController {
    /// A controller for `policy`, named `name` (the model it was trained on) and described in
    /// trial files as `description`.
    pub fn new(
        policy: GaussianPolicy,
        stochastic: bool,
        name: String,
        description: String,
    ) -> Self {
        Self {
            fingerprint: policy.fingerprint(),
            policy: Box::new(policy),
            stochastic,
            name,
            description,
            observation: None,
            frames_per_action: None,
            frame_rate_hz: None,
            ws: MlpWorkspace::default(),
        }
    }

    /// Loads a policy directory (`fishprobe train`'s output). Refuses a policy whose weights
    /// are not all finite: it could never drive a robot.
    pub fn load(dir: &Path, stochastic: bool) -> Result<Self, LearnError> {
        let (policy, meta) = GaussianPolicy::load(dir)?;
        if policy.pi.params().iter().any(|v| !v.is_finite()) {
            return Err(LearnError::Policy(format!(
                "{}: its network holds non-finite weights (NaN or infinity); it cannot drive a robot",
                dir.display()
            )));
        }
        let model = meta["about"]["model"].as_str();
        let name = model.map_or_else(|| dir.display().to_string(), str::to_string);
        let description = model.map_or_else(
            || dir.display().to_string(),
            |m| format!("{m} (seed {})", meta["about"]["seed"]),
        );
        let observation = match meta["about"].get("observation") {
            None => None,
            Some(o) => Some(serde_json::from_value(o.clone()).map_err(|e| {
                LearnError::Policy(format!(
                    "{}: its about.observation is not observation settings: {e}",
                    dir.display()
                ))
            })?),
        };
        let frames_per_action = match meta["about"].get("frames_per_action") {
            None => None,
            Some(f) => Some(
                f.as_u64()
                    .and_then(|f| u32::try_from(f).ok())
                    .filter(|&f| f > 0)
                    .ok_or_else(|| {
                        LearnError::Policy(format!(
                            "{}: its about.frames_per_action is not a positive whole number: {f}",
                            dir.display()
                        ))
                    })?,
            ),
        };
        let frame_rate_hz = match meta["about"].get("frame_rate_hz") {
            None => None,
            Some(f) => Some(
                f.as_f64()
                    .map(|f| f as f32)
                    .filter(|f| f.is_finite() && *f > 0.0)
                    .ok_or_else(|| {
                        LearnError::Policy(format!(
                            "{}: its about.frame_rate_hz is not a positive number: {f}",
                            dir.display()
                        ))
                    })?,
            ),
        };
        Ok(Self {
            observation,
            frames_per_action,
            frame_rate_hz,
            ..Self::new(policy, stochastic, name, description)
        })
    }
}

impl Controller for PolicyController {
    fn name(&self) -> String {
        self.name.clone()
    }

    fn describe(&self) -> String {
        self.description.clone()
    }

    fn fingerprint(&self) -> Option<String> {
        Some(self.fingerprint.clone())
    }

    fn check_observation(&self, dim: usize) -> Result<(), fishprobe_sim::SimError> {
        self.policy
            .check_obs_dim(dim)
            .map_err(|e| fishprobe_sim::SimError::Controller(e.to_string()))
    }

    fn trained_observation(&self) -> Option<ObservationParams> {
        self.observation.clone()
    }

    fn trained_frames_per_action(&self) -> Option<u32> {
        self.frames_per_action
    }

    fn trained_frame_rate_hz(&self) -> Option<f32> {
        self.frame_rate_hz
    }

    fn act(&mut self, input: &ControlInput<'_>, rng: &mut SimRng) -> f32 {
        let y = self.policy.pi.forward(input.obs, 1, &mut self.ws);
        let a = if self.stochastic {
            let z: f32 = StandardNormal.sample(rng);
            y[0] + self.policy.log_std(y[1]).exp() * z
        } else {
            y[0]
        };
        to_env_action(a)
    }
}

/// A `--policy` argument, parsed once: where a robot policy comes from. The one parser of
/// policy strings (the CLI's flags, study files, the Python package).
#[derive(Debug, Clone, PartialEq, Eq)]
pub enum PolicyArg {
    /// A policy directory (`fishprobe train`'s output).
    Dir(std::path::PathBuf),
    /// `onnx:PATH`: an ONNX file of the policy contract (`docs/onnx-models.md`).
    Onnx(std::path::PathBuf),
    /// `scripted:NAME`: a scripted baseline (`scripted:goal-seeker`, ...).
    Scripted(String),
}

impl PolicyArg {
    /// The prefix of an ONNX policy.
    pub const ONNX: &'static str = "onnx:";
    /// The prefix of a scripted controller.
    pub const SCRIPTED: &'static str = "scripted:";

    /// Parses a policy string.
    pub fn parse(arg: &str) -> Self {
        if let Some(name) = arg.strip_prefix(Self::SCRIPTED) {
            PolicyArg::Scripted(name.to_string())
        } else if let Some(path) = arg.strip_prefix(Self::ONNX) {
            PolicyArg::Onnx(path.into())
        } else {
            PolicyArg::Dir(arg.into())
        }
    }

    /// A relative path taken relative to `dir` (a study file's folder); scripted
    /// controllers and absolute paths stay as they are.
    pub fn relative_to(self, dir: &Path) -> Self {
        match self {
            PolicyArg::Dir(p) if p.is_relative() => PolicyArg::Dir(dir.join(p)),
            PolicyArg::Onnx(p) if p.is_relative() => PolicyArg::Onnx(dir.join(p)),
            other => other,
        }
    }

    /// Whether it gives one action per observation (ONNX, scripted) rather than a
    /// distribution to sample.
    pub fn is_deterministic(&self) -> bool {
        !matches!(self, PolicyArg::Dir(_))
    }

    /// The SHA-256 of the file whose weights decide the actions (the ONNX file; a directory's
    /// `policy.safetensors`); `None` for a scripted controller.
    pub fn sha256(&self) -> Result<Option<String>, LearnError> {
        match self {
            PolicyArg::Scripted(_) => Ok(None),
            PolicyArg::Onnx(p) => Ok(Some(fishprobe_models::onnx_sha256(p)?)),
            PolicyArg::Dir(d) => {
                let w = crate::run::RunLayout::new(d).policy();
                fishprobe_models::weights_sha256(&w)
                    .map(Some)
                    .map_err(|e| LearnError::Policy(format!("{}: {e}", w.display())))
            }
        }
    }
}

impl std::fmt::Display for PolicyArg {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        match self {
            PolicyArg::Dir(p) => write!(f, "{}", p.display()),
            PolicyArg::Onnx(p) => write!(f, "{}{}", Self::ONNX, p.display()),
            PolicyArg::Scripted(n) => write!(f, "{}{n}", Self::SCRIPTED),
        }
    }
}

/// A controller from a `--policy` argument ([`PolicyArg`]): a policy directory, an ONNX file
/// (its one deterministic output) or a scripted baseline. `stochastic` samples a policy
/// directory's Gaussian instead of taking its mean; for an ONNX file or a scripted
/// controller, which give one action per observation, it is refused rather than silently
/// ignored.
pub fn controller(arg: &str, stochastic: bool) -> Result<Box<dyn Controller>, LearnError> {
    let policy = PolicyArg::parse(arg);
    if stochastic && policy.is_deterministic() {
        return Err(LearnError::Policy(format!(
            "stochastic actions sample a policy directory's Gaussian; `{arg}` gives one \
             action per observation (an ONNX file holds only the mean action: sample from the \
             policy directory it was exported from, or run it without sampling)"
        )));
    }
    match policy {
        PolicyArg::Scripted(name) => fishprobe_sim::scripted(&name).ok_or_else(|| {
            LearnError::Policy(format!(
                "unknown scripted controller `{arg}`: use {}",
                fishprobe_sim::SCRIPTED_ALL
                    .map(|n| format!("{}{n}", PolicyArg::SCRIPTED))
                    .join(", ")
            ))
        }),
        PolicyArg::Onnx(path) => Ok(Box::new(fishprobe_onnx::OnnxPolicy::load(&path)?)),
        PolicyArg::Dir(dir) => Ok(Box::new(PolicyController::load(&dir, stochastic)?)),
    }
}

/// A robot pilot for live trials, from a `--policy` argument (as [`controller`]): loaded and
/// checked once, before any tracker connects, so that each trial runs a copy of it
/// (`boxed_clone`). Refused, by name: a policy whose weights are not finite (it would only
/// ever stop the robot), one trained with other observation blocks than `obs` (what the
/// live settings give), and one trained to act at another rate than `command_hz` (its
/// frames are the simulator's, at the frame rate it records; one from before fishprobe
/// recorded it: the tracking rate, 25 Hz).
pub fn pilot(
    arg: &str,
    obs: &ObservationParams,
    command_hz: f64,
) -> Result<Box<dyn Controller>, LearnError> {
    let c = controller(arg, false)?;
    fishprobe_sim::check_controller_observation(c.as_ref(), obs)
        .map_err(|e| LearnError::Policy(format!("the policy's observation: {e}")))?;
    let default_hz = fishprobe_sim::EnvConfig::default().frame_rate_hz;
    if let Some(hz) = fishprobe_sim::controller_actions_per_second(c.as_ref(), default_hz) {
        if (hz - command_hz).abs() > 1e-6 * hz {
            return Err(LearnError::Policy(format!(
                "the policy {arg} was trained to act every {} frames at {} Hz, {hz} times a \
                 second; the bridge commands {command_hz} times a second: set command_hz = \
                 {hz} in the bridge's settings",
                c.trained_frames_per_action().unwrap_or_default(),
                c.trained_frame_rate_hz().unwrap_or(default_hz),
            )));
        }
    }
    Ok(c)
}

/// `c` under another short name (a study's name for its model; the directory name of the
/// study layout), describing itself as before.
pub fn named(c: Box<dyn Controller>, name: String) -> Box<dyn Controller> {
    Box::new(Named { inner: c, name })
}

struct Named {
    inner: Box<dyn Controller>,
    name: String,
}

impl Clone for Named {
    fn clone(&self) -> Self {
        Self {
            inner: self.inner.boxed_clone(),
            name: self.name.clone(),
        }
    }
}

impl Controller for Named {
    fn name(&self) -> String {
        self.name.clone()
    }

    fn describe(&self) -> String {
        self.inner.describe()
    }

    fn fingerprint(&self) -> Option<String> {
        self.inner.fingerprint()
    }

    fn check_observation(&self, dim: usize) -> Result<(), fishprobe_sim::SimError> {
        self.inner.check_observation(dim)
    }

    fn trained_observation(&self) -> Option<ObservationParams> {
        self.inner.trained_observation()
    }

    fn trained_frames_per_action(&self) -> Option<u32> {
        self.inner.trained_frames_per_action()
    }

    fn trained_frame_rate_hz(&self) -> Option<f32> {
        self.inner.trained_frame_rate_hz()
    }

    fn act(&mut self, input: &ControlInput<'_>, rng: &mut SimRng) -> f32 {
        self.inner.act(input, rng)
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    /// Sampling is refused, before any file is read, for the controllers that give one action
    /// per observation: the CLI and the Python `Policy` share this refusal.
    #[test]
    fn stochastic_is_refused_where_there_is_nothing_to_sample() {
        for arg in ["scripted:goal-seeker", "onnx:/nonexistent/policy.onnx"] {
            let e = controller(arg, true).err().expect("refused");
            let msg = e.to_string();
            assert!(
                matches!(e, LearnError::Policy(_)) && msg.contains(arg) && msg.contains("Gaussian"),
                "{msg}"
            );
        }
        assert!(controller("scripted:goal-seeker", false).is_ok());
        // Without sampling, the ONNX path is read (and here found missing).
        assert!(!matches!(
            controller("onnx:/nonexistent/policy.onnx", false),
            Err(LearnError::Policy(_)) | Ok(_)
        ));
    }

    /// A policy's sidecar records what it reads; the checks tell two 216-float blocks apart,
    /// and a policy from before the record is taken not to observe headings.
    #[test]
    fn a_policy_knows_the_observation_it_was_trained_with() {
        use fishprobe_sim::{check_controller_observation, controller_observation};
        let dir = std::env::temp_dir().join(format!("fishprobe-ctl-obs-{}", std::process::id()));
        let headings = ObservationParams {
            heading_bins: true,
            ..ObservationParams::default()
        };
        let centroid = ObservationParams {
            centroid_bins: true,
            ..ObservationParams::default()
        };
        let mut rng = fishprobe_sim::stream(0, "t", 0);
        let p = GaussianPolicy::new(216, &crate::PpoConfig::default(), &mut rng);
        let save = |about: serde_json::Value| {
            p.save(&dir, about).unwrap();
            PolicyController::load(&dir, false)
        };
        let c = save(serde_json::json!({ "observation": headings })).unwrap();
        assert_eq!(c.trained_observation(), Some(headings.clone()));
        assert!(check_controller_observation(&c, &headings).is_ok());
        let e = check_controller_observation(&c, &centroid)
            .unwrap_err()
            .to_string();
        assert!(e.contains("heading_bins = true (216 floats)"), "{e}");
        assert_eq!(controller_observation(&c, &centroid), headings);
        // No record: the length alone, and a run's headings are not this policy's.
        let old = save(serde_json::json!({})).unwrap();
        assert_eq!(old.trained_observation(), None);
        assert!(check_controller_observation(&old, &centroid).is_ok());
        assert_eq!(
            controller_observation(&old, &headings),
            ObservationParams::default()
        );
        // A record from before the look-back was recorded looks one action back (SPEC §5);
        // one that looks five back is refused one, and a run that looks back five does not
        // lend that to a policy that records nothing.
        let before = serde_json::json!({ "observation": {
            "sectors": 36, "far_plane_cm": 141.42136, "centroid_bins": false, "heading_bins": true
        } });
        let c = save(before).unwrap();
        assert_eq!(c.trained_observation(), Some(headings.clone()));
        let back5 = ObservationParams {
            previous_block_actions: 5,
            ..headings.clone()
        };
        let e = check_controller_observation(&c, &back5)
            .unwrap_err()
            .to_string();
        assert!(e.contains("previous_block_actions = 1"), "{e}");
        let c = save(serde_json::json!({ "observation": back5 })).unwrap();
        assert!(check_controller_observation(&c, &back5).is_ok());
        assert!(check_controller_observation(&c, &headings).is_err());
        assert_eq!(
            controller_observation(&old, &back5),
            ObservationParams::default()
        );
        // A record that is not observation settings is refused by name.
        let e = save(serde_json::json!({ "observation": "216" })).unwrap_err();
        assert!(e.to_string().contains("about.observation"), "{e}");
        std::fs::remove_dir_all(&dir).unwrap();
    }

    /// A policy's sidecar records how often it acts; it is run at that rate in another run's
    /// settings, refused at another, and one from before the record takes the run's.
    #[test]
    fn a_policy_knows_the_rate_it_was_trained_at() {
        use fishprobe_sim::{check_controller_rate, controller_env, EnvConfig};
        let dir = std::env::temp_dir().join(format!("fishprobe-ctl-rate-{}", std::process::id()));
        let mut rng = fishprobe_sim::stream(0, "t", 0);
        let p = GaussianPolicy::new(180, &crate::PpoConfig::default(), &mut rng);
        let save = |about: serde_json::Value| {
            p.save(&dir, about).unwrap();
            PolicyController::load(&dir, false)
        };
        let run = EnvConfig {
            frames_per_action: 5,
            ..EnvConfig::default()
        };
        let paper = save(serde_json::json!({ "frames_per_action": 25 })).unwrap();
        let at = |frames_per_action, frame_rate_hz| EnvConfig {
            frames_per_action,
            frame_rate_hz,
            ..EnvConfig::default()
        };
        assert_eq!(paper.trained_frames_per_action(), Some(25));
        assert_eq!(controller_env(&paper, &run).frames_per_action, 25);
        assert!(check_controller_rate(&paper, &at(25, 25.0)).is_ok());
        let e = check_controller_rate(&paper, &at(5, 25.0))
            .unwrap_err()
            .to_string();
        assert!(
            e.contains("every 25 frames") && e.contains("run every 5"),
            "{e}"
        );
        let old = save(serde_json::json!({})).unwrap();
        assert_eq!(controller_env(&old, &run).frames_per_action, 5);
        assert!(check_controller_rate(&old, &at(5, 25.0)).is_ok());
        assert_eq!(
            fishprobe_sim::controller_actions_per_second(&old, 25.0),
            None
        );
        // A policy from before the frame rate was recorded acts at the run's frame rate.
        assert_eq!(paper.trained_frame_rate_hz(), None);
        assert!(check_controller_rate(&paper, &at(25, 50.0)).is_ok());
        assert_eq!(
            fishprobe_sim::controller_actions_per_second(&paper, 25.0),
            Some(1.0)
        );
        // One that records it is run at it, and refused at another: 25 frames at 50 Hz are
        // two actions a second, not one.
        let fast =
            save(serde_json::json!({ "frames_per_action": 25, "frame_rate_hz": 50.0 })).unwrap();
        assert_eq!(fast.trained_frame_rate_hz(), Some(50.0));
        assert_eq!(controller_env(&fast, &run).frame_rate_hz, 50.0);
        assert!(check_controller_rate(&fast, &at(25, 50.0)).is_ok());
        let e = check_controller_rate(&fast, &at(25, 25.0))
            .unwrap_err()
            .to_string();
        assert!(
            e.contains("frame_rate_hz = 50") && e.contains("run at 25"),
            "{e}"
        );
        assert_eq!(
            fishprobe_sim::controller_actions_per_second(&fast, 25.0),
            Some(2.0)
        );
        // An absurd record is shown as people write it, not in thirty digits.
        let absurd = save(serde_json::json!({ "frame_rate_hz": 1e30 })).unwrap();
        let e = check_controller_rate(&absurd, &at(25, 25.0))
            .unwrap_err()
            .to_string();
        assert!(e.contains("frame_rate_hz = 1e30"), "{e}");
        for bad in [
            serde_json::json!(0),
            serde_json::json!(-25.0),
            serde_json::json!("25"),
            serde_json::json!(null),
        ] {
            let e = save(serde_json::json!({ "frame_rate_hz": bad })).unwrap_err();
            assert!(e.to_string().contains("about.frame_rate_hz"), "{e}");
        }
        for bad in [
            serde_json::json!(0),
            serde_json::json!(-5),
            serde_json::json!("25"),
        ] {
            let e = save(serde_json::json!({ "frames_per_action": bad })).unwrap_err();
            assert!(e.to_string().contains("about.frames_per_action"), "{e}");
        }
        std::fs::remove_dir_all(&dir).unwrap();
    }
}

#[cfg(test)]
mod policy_arg_tests {
    use super::PolicyArg;
    use std::path::Path;

    #[test]
    fn policy_strings_parse_and_print_back() {
        for (arg, parsed) in [
            ("runs/zone", PolicyArg::Dir("runs/zone".into())),
            ("onnx:p.onnx", PolicyArg::Onnx("p.onnx".into())),
            (
                "scripted:goal-seeker",
                PolicyArg::Scripted("goal-seeker".into()),
            ),
        ] {
            assert_eq!(PolicyArg::parse(arg), parsed);
            assert_eq!(parsed.to_string(), arg);
        }
        let d = Path::new("/study");
        assert_eq!(
            PolicyArg::parse("onnx:p.onnx").relative_to(d).to_string(),
            "onnx:/study/p.onnx"
        );
        assert_eq!(
            PolicyArg::parse("/abs/run").relative_to(d).to_string(),
            "/abs/run"
        );
        assert_eq!(
            PolicyArg::parse("scripted:goal-seeker")
                .relative_to(d)
                .to_string(),
            "scripted:goal-seeker"
        );
    }
}
