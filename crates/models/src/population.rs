//! A population of individuals of any model: each fish, each episode, draws an
//! [`Individual`] from a joint (multivariate normal) distribution of traits, correlations
//! included, and behaves as that individual.
//!
//! The traits ([`Trait`]) are multipliers on groups of the base model's parameters (speed,
//! social terms, noise, wall range; see [`Individual`]), a pause state any model can be given
//! (pauses begin at an individual rate and last an individual mean time; a paused fish keeps
//! its heading and does not move), and the coordinates of an individual's latent vector for a
//! model that takes one (M_ConvNet with individuals). Multipliers and pause rates and
//! durations are log-normal (their logarithms are normal); latent coordinates normal. A model
//! that does not read its individual's multipliers (an ONNX or Python fish) has its output
//! speed scaled by the speed multiplier.
//!
//! A population is fitted to recordings by `fishprobe fit-population` and kept in a
//! population file (JSON: [`PopulationParams`]); the populations fitted to the shared training
//! recordings ship with fishprobe under their own names (`fishprobe models`).
//!
//! ```
//! use fishprobe_models::{population::{PopulationParams, Trait}, ModelSpec};
//! use fishprobe_sim::{Sandbox, Tank, TankParams};
//!
//! let p = PopulationParams {
//!     name: "FastZone".into(),
//!     base: Some(Box::new(ModelSpec::by_name("Zone")?)),
//!     traits: vec![Trait::Speed],
//!     mean: vec![0.3_f64],                 // speed x e^0.3 = 1.35 on average
//!     cov: vec![vec![0.04]],               // s.d. 0.2 on the log scale
//!     ..PopulationParams::default()
//! };
//! let model = ModelSpec::Population(p).build()?;
//! let sb = Sandbox::new(Tank::new(&TankParams::default()), 25.0, model, &[[0.0, 0.0, 0.0]], 7);
//! assert!(sb.minds()[0].individual.speed > 0.5);
//! # Ok::<(), fishprobe_models::ModelError>(())
//! ```

use crate::{ModelError, ModelSpec};
use fishprobe_sim::params::ConfigError;
use fishprobe_sim::{
    AgentState, FishMind, FishModel, FishMotion, FishView, Individual, SimRng, LATENT_DIM,
};
use rand::RngExt;
use rand_distr::{Distribution, StandardNormal};
use serde::{Deserialize, Serialize};
use std::sync::Arc;

/// One trait that varies between individuals.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Serialize, Deserialize)]
#[serde(rename_all = "snake_case")]
pub enum Trait {
    /// [`Individual::speed`] (log-normal).
    Speed,
    /// [`Individual::social`] (log-normal).
    Social,
    /// [`Individual::noise`] (log-normal).
    Noise,
    /// [`Individual::wall`] (log-normal).
    Wall,
    /// [`Individual::pause_rate_hz`] (log-normal).
    PauseRate,
    /// [`Individual::pause_mean_s`] (log-normal).
    PauseMean,
    /// [`Individual::latent`]`[0]` (normal), and so on.
    Latent0,
    /// See [`Trait::Latent0`].
    Latent1,
    /// See [`Trait::Latent0`].
    Latent2,
    /// See [`Trait::Latent0`].
    Latent3,
}

impl Trait {
    /// Every trait.
    pub const ALL: [Trait; 10] = [
        Trait::Speed,
        Trait::Social,
        Trait::Noise,
        Trait::Wall,
        Trait::PauseRate,
        Trait::PauseMean,
        Trait::Latent0,
        Trait::Latent1,
        Trait::Latent2,
        Trait::Latent3,
    ];

    /// The traits of the rule-based models' populations: the multipliers and the pause state.
    pub const RULES: [Trait; 6] = [
        Trait::Speed,
        Trait::Social,
        Trait::Noise,
        Trait::Wall,
        Trait::PauseRate,
        Trait::PauseMean,
    ];

    /// Its name in population files.
    pub fn name(self) -> &'static str {
        match self {
            Trait::Speed => "speed",
            Trait::Social => "social",
            Trait::Noise => "noise",
            Trait::Wall => "wall",
            Trait::PauseRate => "pause_rate",
            Trait::PauseMean => "pause_mean",
            Trait::Latent0 => "latent0",
            Trait::Latent1 => "latent1",
            Trait::Latent2 => "latent2",
            Trait::Latent3 => "latent3",
        }
    }

    /// Whether the trait is drawn on the log scale (multipliers, pause rate and duration).
    pub fn is_log(self) -> bool {
        !matches!(
            self,
            Trait::Latent0 | Trait::Latent1 | Trait::Latent2 | Trait::Latent3
        )
    }

    /// The range a drawn value is held to (on the trait's own scale, not the log): multipliers
    /// within a factor of 20 either way, pauses at most 5 per second and at most a minute
    /// long, latent coordinates within ±10 (choice: bounds far outside any fitted spread,
    /// which keep a wide tail from drawing a fish that cannot move or a model outside the
    /// range it was validated for).
    pub fn bounds(self) -> (f32, f32) {
        match self {
            Trait::Speed | Trait::Social | Trait::Noise | Trait::Wall => (0.05, 20.0),
            Trait::PauseRate => (0.0, 5.0),
            Trait::PauseMean => (0.04, 60.0),
            _ => (-10.0, 10.0),
        }
    }

    /// Sets this trait of `ind` from its value `z` on the trait's normal scale.
    pub fn set(self, ind: &mut Individual, z: f64) {
        let (lo, hi) = self.bounds();
        let v = if self.is_log() { z.exp() } else { z } as f32;
        let v = if v.is_nan() {
            lo.max(0.0)
        } else {
            v.clamp(lo, hi)
        };
        match self {
            Trait::Speed => ind.speed = v,
            Trait::Social => ind.social = v,
            Trait::Noise => ind.noise = v,
            Trait::Wall => ind.wall = v,
            Trait::PauseRate => ind.pause_rate_hz = v,
            Trait::PauseMean => ind.pause_mean_s = v,
            Trait::Latent0 => ind.latent[0] = v,
            Trait::Latent1 => ind.latent[1] = v,
            Trait::Latent2 => ind.latent[2] = v,
            Trait::Latent3 => ind.latent[3] = v,
        }
    }

    /// This trait of `ind` on the trait's normal scale.
    pub fn get(self, ind: &Individual) -> f64 {
        let v = f64::from(match self {
            Trait::Speed => ind.speed,
            Trait::Social => ind.social,
            Trait::Noise => ind.noise,
            Trait::Wall => ind.wall,
            Trait::PauseRate => ind.pause_rate_hz,
            Trait::PauseMean => ind.pause_mean_s,
            Trait::Latent0 => ind.latent[0],
            Trait::Latent1 => ind.latent[1],
            Trait::Latent2 => ind.latent[2],
            Trait::Latent3 => ind.latent[3],
        });
        if self.is_log() {
            v.max(1e-12).ln()
        } else {
            v
        }
    }
}

const _: () = assert!(LATENT_DIM == 4, "Trait names four latent coordinates");

fishprobe_sim::documented_params! {
    /// A population of individuals of a model: the model, the traits that vary between its
    /// individuals and their joint normal distribution (on the traits' scale: the logarithm of
    /// multipliers and of pause rate and duration, latent coordinates as they are). What a
    /// population file holds.
    pub struct PopulationParams {
        /// The population's name (listings, trial files).
        pub name: String = String::new(); "-",
        /// Where it comes from: a shipped population's name or a population file's path. When
        /// `traits` is empty (a study file naming only the source), the population is read
        /// from there.
        pub source: String = String::new(); "-",
        /// The model whose individuals these are.
        pub base: Option<Box<ModelSpec>> = None; "-",
        /// The traits that vary, in the order of `mean` and `cov`; the others stay neutral.
        pub traits: Vec<Trait> = Vec::new(); "-",
        /// Mean of the traits on their scale.
        pub mean: Vec<f64> = Vec::new(); "-",
        /// Covariance of the traits on their scale (k x k, symmetric, positive semi-definite).
        pub cov: Vec<Vec<f64>> = Vec::new(); "-",
        /// How the population was fitted (written by `fit-population`: the data, the method,
        /// the fit's quality on recordings it did not use). Not used to simulate.
        pub fit: serde_json::Value = serde_json::Value::Null; "-",
    }
}

impl PopulationParams {
    /// This population with its content read from `source` (a shipped population's name or
    /// a population file) when it names only its source, as a study file may; the name given
    /// here is kept.
    pub fn resolved(&self) -> Result<Self, ModelError> {
        if !self.traits.is_empty() || self.source.is_empty() {
            return Ok(self.clone());
        }
        let mut p = match shipped(&self.source) {
            Some(p) => p?,
            None => read_file(std::path::Path::new(&self.source))?,
        };
        if !self.name.is_empty() {
            p.name = self.name.clone();
        }
        Ok(p)
    }

    /// The base model.
    pub fn base(&self) -> Result<&ModelSpec, ConfigError> {
        self.base.as_deref().ok_or_else(|| {
            ConfigError::new(
                &self.name,
                "base",
                "none",
                "a population needs its base model",
            )
        })
    }

    /// Checks the shape and the covariance (it must have a Cholesky factor, after a jitter of
    /// 1e-9 on the diagonal).
    pub fn validate(&self, prefix: &str) -> Result<(), ConfigError> {
        let base = self.base()?;
        if matches!(base, ModelSpec::Population(_)) {
            return Err(ConfigError::new(
                prefix,
                "base",
                "Population",
                "a population's base must be a model, not another population",
            ));
        }
        base.validate()?;
        let k = self.traits.len();
        if k == 0 {
            return Err(ConfigError::new(
                prefix,
                "traits",
                "[]",
                "name at least one trait that varies (a population file, or `source`)",
            ));
        }
        let mut seen = self.traits.clone();
        seen.sort_by_key(|t| t.name());
        seen.dedup();
        if seen.len() != k {
            return Err(ConfigError::new(
                prefix,
                "traits",
                k,
                "a trait is named twice",
            ));
        }
        if self.mean.len() != k || self.mean.iter().any(|m| !m.is_finite() || m.abs() > 50.0) {
            return Err(ConfigError::new(
                prefix,
                "mean",
                self.mean.len(),
                &format!("must hold {k} finite values within ±50, one per trait"),
            ));
        }
        if self.cov.len() != k
            || self
                .cov
                .iter()
                .any(|r| r.len() != k || r.iter().any(|v| !v.is_finite() || v.abs() > 100.0))
        {
            return Err(ConfigError::new(
                prefix,
                "cov",
                self.cov.len(),
                &format!("must be a {k} x {k} matrix of finite values within ±100"),
            ));
        }
        for i in 0..k {
            for j in 0..i {
                if (self.cov[i][j] - self.cov[j][i]).abs() > 1e-9 * (1.0 + self.cov[i][j].abs()) {
                    return Err(ConfigError::new(prefix, "cov", "", "must be symmetric"));
                }
            }
        }
        if cholesky(&self.cov).is_none() {
            return Err(ConfigError::new(
                prefix,
                "cov",
                "",
                "must be positive semi-definite (a covariance matrix)",
            ));
        }
        Ok(())
    }

    /// The population's standard deviation of each trait (on its scale).
    pub fn sd(&self) -> Vec<f64> {
        (0..self.traits.len())
            .map(|i| self.cov[i][i].max(0.0).sqrt())
            .collect()
    }

    /// The individual at the population's centre (every trait at its mean).
    pub fn centre(&self) -> Individual {
        let mut ind = Individual::NEUTRAL;
        for (t, &m) in self.traits.iter().zip(&self.mean) {
            t.set(&mut ind, m);
        }
        ind
    }
}

/// The largest population file read (bytes): a population is a few kilobytes; a wrong path
/// (`/dev/zero`, a video) is refused, never read whole.
pub const MAX_FILE_BYTES: u64 = 4 << 20;

/// A population file (`fishprobe fit-population` writes them), read and checked.
pub fn read_file(path: &std::path::Path) -> Result<PopulationParams, ModelError> {
    let err = |what: String| {
        ModelError::Config(ConfigError::new(
            "population",
            "file",
            path.display(),
            &what,
        ))
    };
    let bytes = fishprobe_nn::store::read_at_most(path, MAX_FILE_BYTES, "MAX_FILE_BYTES")
        .map_err(|e| err(e.to_string()))?;
    let mut p: PopulationParams =
        serde_json::from_slice(&bytes).map_err(|e| err(format!("not a population file: {e}")))?;
    if p.source.is_empty() {
        p.source = path.display().to_string();
    }
    p.validate(&p.name)?;
    Ok(p)
}

/// The populations fitted to the shared training recordings (`guppy-pairs/legacy/train` only)
/// that ship with fishprobe: name and file contents (`fishprobe fit-population` wrote them;
/// each records its command and its check on the validation recordings under `fit`).
pub const SHIPPED: [(&str, &str); 5] = [
    (
        "FollowPop",
        include_str!("../assets/populations/FollowPop.json"),
    ),
    (
        "ZonePop",
        include_str!("../assets/populations/ZonePop.json"),
    ),
    (
        "ForcePop",
        include_str!("../assets/populations/ForcePop.json"),
    ),
    (
        "ConvNetPop",
        include_str!("../assets/populations/ConvNetPop.json"),
    ),
    (
        "GuppyPop",
        include_str!("../assets/populations/GuppyPop.json"),
    ),
];

/// A shipped population by name (case-insensitive), if there is one of that name.
pub fn shipped(name: &str) -> Option<Result<PopulationParams, ModelError>> {
    let (n, text) = SHIPPED.iter().find(|(n, _)| n.eq_ignore_ascii_case(name))?;
    Some(
        serde_json::from_str::<PopulationParams>(text)
            .map_err(|e| {
                ModelError::Config(ConfigError::new(
                    "population",
                    n,
                    "shipped",
                    &format!("the shipped file does not read: {e}"),
                ))
            })
            .map(|mut p| {
                p.source = (*n).to_string();
                p
            }),
    )
}

/// The lower Cholesky factor of a symmetric positive semi-definite matrix (row-major rows),
/// with a jitter of 1e-9 on the diagonal; `None` when it is not one.
pub fn cholesky(a: &[Vec<f64>]) -> Option<Vec<Vec<f64>>> {
    let k = a.len();
    let mut l = vec![vec![0.0; k]; k];
    for i in 0..k {
        for j in 0..=i {
            let s = a[i][j] - (0..j).map(|m| l[i][m] * l[j][m]).sum::<f64>();
            if i == j {
                let d = s + 1e-9;
                if d.is_nan() || d <= 0.0 {
                    return None;
                }
                l[i][i] = d.sqrt();
            } else {
                l[i][j] = s / l[j][j];
            }
        }
    }
    Some(l)
}

/// A population of a model's individuals, as a fish model.
#[derive(Debug)]
pub struct Population {
    name: String,
    inner: Arc<dyn FishModel>,
    traits: Vec<Trait>,
    mean: Vec<f64>,
    chol: Vec<Vec<f64>>,
}

impl Population {
    /// The population of `p` (checked; one that names only its source is read from it).
    pub fn new(p: &PopulationParams) -> Result<Self, ModelError> {
        let p = &p.resolved()?;
        p.validate(&p.name)?;
        let chol = cholesky(&p.cov).ok_or_else(|| {
            ConfigError::new(&p.name, "cov", "", "must be positive semi-definite")
        })?;
        Ok(Self {
            name: if p.name.is_empty() {
                format!("{}Pop", p.base()?.name())
            } else {
                p.name.clone()
            },
            inner: p.base()?.build()?,
            traits: p.traits.clone(),
            mean: p.mean.clone(),
            chol,
        })
    }

    /// An individual drawn from the population with `rng`.
    pub fn draw(&self, rng: &mut SimRng) -> Individual {
        let k = self.traits.len();
        let mut eps = [0.0f64; Trait::ALL.len()];
        for e in eps.iter_mut().take(k) {
            *e = StandardNormal.sample(rng);
        }
        let mut ind = Individual::NEUTRAL;
        for i in 0..k {
            let z = self.mean[i] + (0..=i).map(|j| self.chol[i][j] * eps[j]).sum::<f64>();
            self.traits[i].set(&mut ind, z);
        }
        ind
    }
}

impl FishModel for Population {
    fn name(&self) -> &str {
        &self.name
    }

    fn begin_episode(&self, me: &AgentState, mind: &mut FishMind, rng: &mut SimRng) {
        self.inner.begin_episode(me, mind, rng);
        mind.individual = self.draw(rng);
        mind.pause_left_s = 0.0;
    }

    fn reads_individual(&self) -> bool {
        true
    }

    fn inference_width(&self) -> usize {
        self.inner.inference_width()
    }

    fn infer_batch(&self, views: &[FishView], out: &mut [f32]) {
        self.inner.infer_batch(views, out);
    }

    fn concurrent_inference(&self) -> bool {
        self.inner.concurrent_inference()
    }

    fn decide(
        &self,
        view: &FishView,
        inferred: &[f32],
        mind: &mut FishMind,
        rng: &mut SimRng,
    ) -> FishMotion {
        let ind = mind.individual;
        let still = FishMotion {
            heading: view.me.heading,
            speed: 0.0,
        };
        if mind.pause_left_s > 0.0 {
            mind.pause_left_s -= view.dt;
            return still;
        }
        if ind.pause_rate_hz > 0.0 && rng.random::<f32>() < ind.pause_rate_hz * view.dt {
            let u: f32 = rng.random::<f32>().max(1e-6);
            mind.pause_left_s = -ind.pause_mean_s * u.ln() - view.dt;
            return still;
        }
        let mut m = self.inner.decide(view, inferred, mind, rng);
        if !self.inner.reads_individual() {
            m.speed *= ind.speed;
        }
        m
    }
}

impl crate::ModelParams for PopulationParams {
    const NAME: &'static str = "Population";
    const SUMMARY: &'static str =
        "a model's individuals drawn from a fitted joint distribution of traits";

    fn check(&self, prefix: &str) -> Result<(), ConfigError> {
        if self.traits.is_empty() && !self.source.is_empty() {
            // Read at build time (`resolved`), checked there.
            return Ok(());
        }
        self.validate(prefix)
    }

    fn build_model(&self) -> Result<Arc<dyn FishModel>, ModelError> {
        Ok(Arc::new(Population::new(self)?))
    }
}

#[cfg(test)]
mod tests {
    #![allow(clippy::unwrap_used)]
    use super::*;
    use rand::SeedableRng;

    fn zone_pop(traits: Vec<Trait>, mean: Vec<f64>, cov: Vec<Vec<f64>>) -> PopulationParams {
        PopulationParams {
            name: "ZoneTest".into(),
            base: Some(Box::new(ModelSpec::by_name("Zone").unwrap())),
            traits,
            mean,
            cov,
            ..PopulationParams::default()
        }
    }

    #[test]
    fn draws_follow_the_joint_distribution_with_its_correlation() {
        let p = zone_pop(
            vec![Trait::Speed, Trait::Noise],
            vec![0.2, -0.1],
            vec![vec![0.09, 0.06], vec![0.06, 0.16]],
        );
        let pop = Population::new(&p).unwrap();
        let mut rng = SimRng::seed_from_u64(3);
        let n = 20_000;
        let (mut a, mut b) = (Vec::new(), Vec::new());
        for _ in 0..n {
            let i = pop.draw(&mut rng);
            a.push(f64::from(i.speed).ln());
            b.push(f64::from(i.noise).ln());
            assert_eq!((i.social, i.wall, i.pause_rate_hz), (1.0, 1.0, 0.0));
        }
        let mean = |v: &[f64]| v.iter().sum::<f64>() / v.len() as f64;
        let (ma, mb) = (mean(&a), mean(&b));
        let cov = a
            .iter()
            .zip(&b)
            .map(|(x, y)| (x - ma) * (y - mb))
            .sum::<f64>()
            / n as f64;
        let var = |v: &[f64], m: f64| v.iter().map(|x| (x - m).powi(2)).sum::<f64>() / n as f64;
        assert!(
            (ma - 0.2).abs() < 0.01 && (mb + 0.1).abs() < 0.01,
            "{ma} {mb}"
        );
        assert!((var(&a, ma) - 0.09).abs() < 0.005, "{}", var(&a, ma));
        assert!((cov - 0.06).abs() < 0.005, "{cov}");
    }

    #[test]
    fn bad_populations_are_refused_by_field() {
        let cases = [
            (zone_pop(vec![], vec![], vec![]), "traits"),
            (
                zone_pop(vec![Trait::Speed], vec![0.0, 1.0], vec![vec![0.1]]),
                "mean",
            ),
            (
                zone_pop(vec![Trait::Speed], vec![f64::NAN], vec![vec![0.1]]),
                "mean",
            ),
            (
                zone_pop(vec![Trait::Speed], vec![0.0], vec![vec![-0.1]]),
                "cov",
            ),
            (
                zone_pop(
                    vec![Trait::Speed, Trait::Speed],
                    vec![0.0, 0.0],
                    vec![vec![0.1, 0.0], vec![0.0, 0.1]],
                ),
                "traits",
            ),
            (
                zone_pop(
                    vec![Trait::Speed, Trait::Noise],
                    vec![0.0, 0.0],
                    vec![vec![0.1, 0.5], vec![0.5, 0.1]],
                ),
                "cov",
            ),
            (
                PopulationParams {
                    base: None,
                    ..zone_pop(vec![Trait::Speed], vec![0.0], vec![vec![0.1]])
                },
                "base",
            ),
        ];
        for (p, field) in cases {
            let e = ModelSpec::Population(p).build().unwrap_err().to_string();
            assert!(e.contains(field), "{field}: {e}");
        }
    }

    #[test]
    fn a_paused_individual_stands_still_for_its_pause() {
        let p = zone_pop(
            vec![Trait::PauseRate, Trait::PauseMean],
            vec![(2.0f64).ln(), (1.0f64).ln()],
            vec![vec![0.0, 0.0], vec![0.0, 0.0]],
        );
        let model = ModelSpec::Population(p).build().unwrap();
        let tank = fishprobe_sim::Tank::new(&fishprobe_sim::TankParams::default());
        let mut sb = fishprobe_sim::Sandbox::new(tank, 25.0, model, &[[0.0, 0.0, 0.0]], 1);
        let (mut still, frames) = (0, 25 * 60);
        let mut last = sb.fish()[0];
        for _ in 0..frames {
            sb.step().unwrap();
            let now = sb.fish()[0];
            if now.x == last.x && now.y == last.y {
                still += 1;
            }
            last = now;
        }
        // Pauses begin at 2 per second of swimming and last 1 s: about two thirds still.
        let frac = f64::from(still) / f64::from(frames);
        assert!((0.55..0.8).contains(&frac), "{frac}");
    }

    #[test]
    fn the_neutral_population_changes_nothing_but_the_draws() {
        // A population whose traits never move from neutral (zero mean, zero spread) drives
        // the same fish as the model itself, given the same stream after the draw.
        let p = zone_pop(vec![Trait::Speed], vec![0.0], vec![vec![0.0]]);
        let pop = Population::new(&p).unwrap();
        let mut r = SimRng::seed_from_u64(9);
        let i = pop.draw(&mut r);
        assert!((i.speed - 1.0).abs() < 1e-4, "{i:?}");
    }
}
