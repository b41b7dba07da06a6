//! M_ConvNet (SPEC §6): a fish whose next speed and turn rate are sampled from a network
//! trained by behavioural cloning on pairs of live guppies (`fishprobe fit-convnet`).
//!
//! The fish sees an egocentric view of 72 bins of 5° around its heading with three channels:
//! wall intensity along the bin's ray, the other agent's intensity in the bin holding
//! it, and that agent's heading relative to the fish's (divided by π) in the same bin
//! ([`encode_view`]; in a group, the nearest agent per bin). The network is a circular 1-D convolution, two fully connected Leaky-ReLU
//! layers and a linear layer giving the logits of a 2-D grid of (speed, turn rate) cells
//! ([`ConvNet`]). The fish samples a cell, then a value uniformly inside it. Inference is
//! batched over all fish of a vector environment ([`FishModel::infer_batch`]).
//!
//! The weights shipped with fishprobe (`assets/convnet.safetensors` and its sidecar `assets/convnet.safetensors.json`)
//! were trained by `fishprobe fit-convnet` on the shared pair recordings; the command, the data
//! split and the validation loss are in the sidecar and in docs/validation.md.

use fishprobe_nn::{Activation, Conv1d, Mlp, MlpSpec, MlpWorkspace, PackedMlp};
use fishprobe_sim::{FishMind, FishModel, FishMotion, FishView, SimRng};
use rand::{Rng, RngExt};
use std::path::Path;
use std::sync::Mutex;

mod view;
pub(crate) use view::encode_views;
pub use view::{encode_view, ConvNetArch, CHANNELS};

static SHIPPED_WEIGHTS: &[u8] = include_bytes!("../assets/convnet.safetensors");
static SHIPPED_META: &str = include_str!("../assets/convnet.safetensors.json");
static SHIPPED_INDIVIDUALS: &[u8] = include_bytes!("../assets/convnet_individuals.safetensors");
static SHIPPED_INDIVIDUALS_META: &str =
    include_str!("../assets/convnet_individuals.safetensors.json");

/// The `weights` that name the shipped M_ConvNet with individuals (`fit-convnet --latent-dim
/// 4` on the training recordings; the population of its individuals ships as `ConvNetPop`).
pub const SHIPPED_INDIVIDUALS_WEIGHTS: &str = "shipped:individuals";

/// SHA-256 of the shipped weights file (what its support file names).
pub fn shipped_sha256() -> String {
    fishprobe_onnx::sha256_hex(SHIPPED_WEIGHTS)
}

/// Buffers of a forward/backward pass, reused across calls.
#[derive(Debug, Clone, Default)]
pub struct ConvNetWorkspace {
    pub(crate) conv_out: Vec<f32>,
    conv_delta: Vec<f32>,
    /// The dense layers' input with an individual's latent (the convolution's output and the
    /// latent, per row), and its delta.
    pub(crate) mlp_in: Vec<f32>,
    mlp_in_delta: Vec<f32>,
    /// The rows' latents, gathered from the fish's views for batched inference.
    latent: Vec<f32>,
    pub(crate) mlp: MlpWorkspace,
}

/// The network: circular Conv1d → Leaky-ReLU → dense Leaky-ReLU x 2 → linear logits.
#[derive(Debug, Clone, PartialEq)]
pub struct ConvNet {
    /// Shape.
    pub arch: ConvNetArch,
    /// The convolution.
    pub conv: Conv1d,
    /// The dense layers (input: the flattened convolution output).
    pub mlp: Mlp,
}

/// Why a weights file cannot be used.
#[derive(Debug, Clone, PartialEq, thiserror::Error)]
#[error("ConvNet weights {source_name}: {what}")]
pub struct WeightsError {
    /// The file (or "shipped weights").
    pub source_name: String,
    /// What is wrong.
    pub what: String,
}

fn mlp_spec(arch: &ConvNetArch) -> MlpSpec {
    MlpSpec {
        sizes: vec![
            arch.conv_channels * arch.bins + arch.latent_dim,
            arch.hidden[0],
            arch.hidden[1],
            arch.cells(),
        ],
        hidden: Activation::LeakyRelu(arch.leaky_slope),
    }
}

impl ConvNet {
    /// A freshly initialised network (He-initialised convolution; normc dense layers, the
    /// output layer at 0.01 so the initial distribution is near uniform).
    pub fn new<R: Rng>(arch: ConvNetArch, rng: &mut R) -> Self {
        let conv = Conv1d::new(CHANNELS, arch.conv_channels, arch.kernel, rng);
        let mlp = Mlp::new(mlp_spec(&arch), 0.01, rng);
        Self { arch, conv, mlp }
    }

    /// Logits (`batch x cells`) of `batch` views (a network with a latent is given the
    /// population's centre, zeros; [`ConvNet::forward_latent`] gives each row its own).
    pub fn forward<'w>(&self, x: &[f32], batch: usize, ws: &'w mut ConvNetWorkspace) -> &'w [f32] {
        self.forward_latent(x, None, batch, ws)
    }

    /// Logits of `batch` views, each with its individual's latent (`batch x latent_dim`;
    /// `None`: zeros).
    pub fn forward_latent<'w>(
        &self,
        x: &[f32],
        z: Option<&[f32]>,
        batch: usize,
        ws: &'w mut ConvNetWorkspace,
    ) -> &'w [f32] {
        self.features(x, batch, ws);
        if self.arch.latent_dim == 0 {
            return self.mlp.forward(&ws.conv_out, batch, &mut ws.mlp);
        }
        self.join_latent(z, batch, ws);
        self.mlp.forward(&ws.mlp_in, batch, &mut ws.mlp)
    }

    /// The dense layers' input: each row's convolution output followed by its latent.
    pub(crate) fn join_latent(&self, z: Option<&[f32]>, batch: usize, ws: &mut ConvNetWorkspace) {
        let (c, d) = (
            self.arch.conv_channels * self.arch.bins,
            self.arch.latent_dim,
        );
        ws.mlp_in.resize(batch * (c + d), 0.0);
        for r in 0..batch {
            let row = &mut ws.mlp_in[r * (c + d)..(r + 1) * (c + d)];
            row[..c].copy_from_slice(&ws.conv_out[r * c..(r + 1) * c]);
            match z {
                Some(z) => row[c..].copy_from_slice(&z[r * d..(r + 1) * d]),
                None => row[c..].fill(0.0),
            }
        }
    }

    /// The convolution's activated output, the dense layers' input, into `ws.conv_out`.
    pub(crate) fn features(&self, x: &[f32], batch: usize, ws: &mut ConvNetWorkspace) {
        let len = self.arch.bins;
        ws.conv_out
            .resize(batch * self.arch.conv_channels * len, 0.0);
        let act = Activation::LeakyRelu(self.arch.leaky_slope);
        self.conv
            .forward_activated(x, batch, len, &mut ws.conv_out, Some(act));
    }

    /// After [`ConvNet::forward`] on the same `x`: adds the gradients of `sum(dlogits ·
    /// logits)` into `g_conv` and `g_mlp`.
    pub fn backward(
        &self,
        x: &[f32],
        batch: usize,
        dlogits: &[f32],
        ws: &mut ConvNetWorkspace,
        g_conv: &mut [f32],
        g_mlp: &mut [f32],
    ) {
        self.backward_latent(x, batch, dlogits, ws, g_conv, g_mlp, None);
    }

    /// [`ConvNet::backward`] after [`ConvNet::forward_latent`], also writing the gradient
    /// with respect to each row's latent into `g_z` (`batch x latent_dim`, overwritten).
    #[allow(clippy::too_many_arguments)]
    pub fn backward_latent(
        &self,
        x: &[f32],
        batch: usize,
        dlogits: &[f32],
        ws: &mut ConvNetWorkspace,
        g_conv: &mut [f32],
        g_mlp: &mut [f32],
        g_z: Option<&mut [f32]>,
    ) {
        let len = self.arch.bins;
        let c = self.arch.conv_channels * len;
        let d = self.arch.latent_dim;
        ws.conv_delta.resize(batch * c, 0.0);
        let ConvNetWorkspace {
            conv_out,
            conv_delta,
            mlp_in,
            mlp_in_delta,
            mlp,
            ..
        } = ws;
        if d == 0 {
            self.mlp
                .backward(conv_out, batch, dlogits, mlp, g_mlp, Some(conv_delta));
        } else {
            mlp_in_delta.resize(batch * (c + d), 0.0);
            self.mlp
                .backward(mlp_in, batch, dlogits, mlp, g_mlp, Some(mlp_in_delta));
            for r in 0..batch {
                let row = &mlp_in_delta[r * (c + d)..(r + 1) * (c + d)];
                conv_delta[r * c..(r + 1) * c].copy_from_slice(&row[..c]);
            }
            if let Some(g_z) = g_z {
                for r in 0..batch {
                    g_z[r * d..(r + 1) * d]
                        .copy_from_slice(&mlp_in_delta[r * (c + d) + c..(r + 1) * (c + d)]);
                }
            }
        }
        Activation::LeakyRelu(self.arch.leaky_slope).backprop(conv_out, conv_delta);
        self.conv.backward(x, batch, len, conv_delta, g_conv, None);
    }

    /// The tensors and sidecar of a weights file.
    pub fn to_tensors(&self) -> fishprobe_nn::store::Tensors {
        let mut t = fishprobe_nn::store::Tensors::new();
        t.insert(
            "conv".into(),
            (vec![self.conv.params.len()], self.conv.params.clone()),
        );
        t.insert(
            "mlp".into(),
            (vec![self.mlp.num_params()], self.mlp.params().to_vec()),
        );
        t
    }

    /// Rebuilds a network from a weights file's tensors and sidecar (which holds `arch`).
    pub fn from_parts(
        tensors: &fishprobe_nn::store::Tensors,
        meta: &serde_json::Value,
        source_name: &str,
    ) -> Result<Self, WeightsError> {
        let err = |what: String| WeightsError {
            source_name: source_name.to_string(),
            what,
        };
        let arch: ConvNetArch = meta
            .get("arch")
            .ok_or_else(|| err("the sidecar has no `arch` (not a ConvNet weights file?)".into()))
            .and_then(|a| {
                serde_json::from_value(a.clone()).map_err(|e| err(format!("`arch`: {e}")))
            })?;
        arch.validate().map_err(|e| err(e.to_string()))?;
        let get = |name: &str, want: usize| -> Result<Vec<f32>, WeightsError> {
            let (_, v) = tensors
                .get(name)
                .ok_or_else(|| err(format!("no tensor `{name}`")))?;
            if v.len() != want {
                return Err(err(format!(
                    "tensor `{name}` has {} values, the architecture in the sidecar needs {want}",
                    v.len()
                )));
            }
            Ok(v.clone())
        };
        let mut conv = Conv1d {
            c_in: CHANNELS,
            c_out: arch.conv_channels,
            k: arch.kernel,
            params: Vec::new(),
        };
        conv.params = get(
            "conv",
            CHANNELS * arch.conv_channels * arch.kernel + arch.conv_channels,
        )?;
        let spec = mlp_spec(&arch);
        let n_mlp: usize = spec.sizes.windows(2).map(|w| w[0] * w[1] + w[1]).sum();
        let mlp = Mlp::from_params(spec, get("mlp", n_mlp)?)
            .ok_or_else(|| err("dense layers do not match the architecture".into()))?;
        if conv
            .params
            .iter()
            .chain(mlp.params())
            .any(|v| !v.is_finite())
        {
            return Err(err("non-finite weights".into()));
        }
        Ok(Self { arch, conv, mlp })
    }

    /// Loads a weights file written by `fishprobe fit-convnet`.
    pub fn load(path: &Path) -> Result<Self, WeightsError> {
        let name = path.display().to_string();
        let (t, meta) = fishprobe_nn::store::load(path).map_err(|e| {
            // The store's error names the file it could not read (the weights or their
            // sidecar); the weights' own name is said once, by `source_name`.
            let what = e.to_string();
            let what = what
                .strip_prefix(&format!("{name}: "))
                .map(str::to_string)
                .unwrap_or(what);
            WeightsError {
                source_name: name.clone(),
                what,
            }
        })?;
        Self::from_parts(&t, &meta, &name)
    }

    /// The weights shipped with fishprobe.
    pub fn shipped() -> Result<Self, WeightsError> {
        let name = "shipped with fishprobe";
        let err = |what: String| WeightsError {
            source_name: name.into(),
            what,
        };
        let t = fishprobe_nn::store::from_bytes(SHIPPED_WEIGHTS).map_err(|e| err(e.to_string()))?;
        let meta: serde_json::Value =
            serde_json::from_str(SHIPPED_META).map_err(|e| err(e.to_string()))?;
        Self::from_parts(&t, &meta, name)
    }

    /// The shipped M_ConvNet with individuals ([`SHIPPED_INDIVIDUALS_WEIGHTS`]).
    pub fn shipped_individuals() -> Result<Self, WeightsError> {
        let name = "shipped with fishprobe (individuals)";
        let err = |what: String| WeightsError {
            source_name: name.into(),
            what,
        };
        let t =
            fishprobe_nn::store::from_bytes(SHIPPED_INDIVIDUALS).map_err(|e| err(e.to_string()))?;
        let meta: serde_json::Value =
            serde_json::from_str(SHIPPED_INDIVIDUALS_META).map_err(|e| err(e.to_string()))?;
        Self::from_parts(&t, &meta, name)
    }

    /// The sidecar of the shipped weights (training command, data split, validation NLL).
    pub fn shipped_meta() -> serde_json::Value {
        serde_json::from_str(SHIPPED_META).unwrap_or(serde_json::Value::Null)
    }
}

fishprobe_sim::documented_params! {
    /// M_ConvNet's settings: which weights to use.
    pub struct ConvNetParams {
        /// Weights file written by `fishprobe fit-convnet` (safetensors with its `.json`
        /// sidecar); empty: the weights shipped with fishprobe; `shipped:individuals`: the
        /// shipped M_ConvNet with individuals (an individual's latent as input; its population
        /// is `ConvNetPop`).
        pub weights: String = String::new(); "-",
        /// A drawn (v, ω) whose step would cross the wall margin is drawn again, up to this
        /// many times; when none stays in the water, the glass turns the fish along it (it
        /// takes the part of its step along the wall and heads where it moved; nose straight
        /// in, it turns on the spot). 0: the plain sampling of SPEC §6, the step clipped at
        /// the wall (a wall contact). **Decision: 16, a documented
        /// extension of SPEC §6's sampling**: the fish samples from the learned distribution
        /// conditioned on a step that stays in the water, as every recorded step of a live
        /// guppy did. Without it (0: the plain sampling) the fish, memoryless, swam into a
        /// wall, and there, nose to the glass at the margin (a view the recordings hardly
        /// hold), its network answered with slow, small turns that kept it there for up to
        /// 16 s: 12 % of its frames alone were clipped, where live guppies are within 1 cm of
        /// a wall in 0.4 % of frames. The redraws leave the network and
        /// its likelihood as they are. The measurements: docs/validation.md, "M_ConvNet and the virtual guppy against held-back real pairs".
        pub wall_redraws: u32 = 16; "draws",
    }
}

impl ConvNetParams {
    /// Most redraws accepted (a redraw costs one scan of the grid).
    pub const MAX_WALL_REDRAWS: u32 = 1000;
}

/// The ConvNet fish.
#[derive(Debug)]
pub struct ConvNetFish {
    net: ConvNet,
    /// [`ConvNetParams::wall_redraws`].
    wall_redraws: u32,
    /// The dense layers packed for inference on one frame's fish: no repacking per frame, and
    /// a fish's logits do not depend on the batch it is stepped in (alone in evaluation and
    /// the virtual lab, 64 at a time in training).
    dense: PackedMlp,
    /// Input and workspace buffers, one set per concurrent `infer_batch` call (the vector
    /// environment calls it from every core at once); a call takes the first free set.
    scratch: Vec<Mutex<(Vec<f32>, ConvNetWorkspace)>>,
}

impl ConvNetFish {
    /// The fish with the weights `p` names.
    pub fn new(p: &ConvNetParams) -> Result<Self, WeightsError> {
        let net = if p.weights.is_empty() {
            ConvNet::shipped()?
        } else if p.weights == SHIPPED_INDIVIDUALS_WEIGHTS {
            ConvNet::shipped_individuals()?
        } else {
            ConvNet::load(Path::new(&p.weights))?
        };
        Ok(Self {
            wall_redraws: p.wall_redraws,
            ..Self::from_net(net)
        })
    }

    /// The fish with a given network (and the default [`ConvNetParams::wall_redraws`]).
    pub fn from_net(net: ConvNet) -> Self {
        Self {
            wall_redraws: ConvNetParams::default().wall_redraws,
            dense: PackedMlp::new(&net.mlp),
            net,
            scratch: slots(|| (Vec::new(), ConvNetWorkspace::default())),
        }
    }

    /// The network.
    pub fn net(&self) -> &ConvNet {
        &self.net
    }
}

impl FishModel for ConvNetFish {
    fn name(&self) -> &str {
        "ConvNet"
    }

    fn inference_width(&self) -> usize {
        self.net.arch.cells()
    }

    fn infer_batch(&self, views: &[FishView], out: &mut [f32]) {
        let arch = &self.net.arch;
        let len = arch.view_len();
        let mut guard = free_slot(&self.scratch);
        let (x, ws) = &mut *guard;
        x.resize(views.len() * len, 0.0);
        encode_views(arch, views, x);
        self.net.features(x, views.len(), ws);
        if arch.latent_dim > 0 {
            // Each fish's own latent, from its individual.
            let d = arch.latent_dim;
            let mut z = std::mem::take(&mut ws.latent);
            z.clear();
            z.extend(
                views
                    .iter()
                    .flat_map(|v| v.individual.latent[..d].iter().copied()),
            );
            self.net.join_latent(Some(&z), views.len(), ws);
            ws.latent = z;
        }
        let (dense_in, mlp) = if arch.latent_dim == 0 {
            (&ws.conv_out, &mut ws.mlp)
        } else {
            (&ws.mlp_in, &mut ws.mlp)
        };
        let logits = self.dense.forward(dense_in, views.len(), mlp);
        fishprobe_nn::dist::softmax_rows(logits, out, arch.cells());
    }

    fn decide(
        &self,
        view: &FishView,
        inferred: &[f32],
        mind: &mut FishMind,
        rng: &mut SimRng,
    ) -> FishMotion {
        sample_motion(&self.net.arch, view, inferred, self.wall_redraws, mind, rng)
    }
}

/// One set of scratch buffers per core, for a batched model's concurrent `infer_batch` calls.
pub(crate) fn slots<T>(make: impl Fn() -> T) -> Vec<Mutex<T>> {
    (0..std::thread::available_parallelism().map_or(1, |n| n.get()))
        .map(|_| Mutex::new(make()))
        .collect()
}

/// The first free set of scratch buffers of a batched model, one set per concurrent
/// `infer_batch` call (the vector environment calls from every core at once). A poisoned lock
/// only means another thread panicked mid-inference; the buffers are overwritten by the
/// caller, so they are still usable. When every set is busy (more callers than cores), waits
/// for the first. `slots` must not be empty.
pub(crate) fn free_slot<T>(slots: &[Mutex<T>]) -> std::sync::MutexGuard<'_, T> {
    slots
        .iter()
        .find_map(|m| match m.try_lock() {
            Ok(g) => Some(g),
            Err(std::sync::TryLockError::Poisoned(p)) => Some(p.into_inner()),
            Err(std::sync::TryLockError::WouldBlock) => None,
        })
        .unwrap_or_else(|| slots[0].lock().unwrap_or_else(|p| p.into_inner()))
}

/// SPEC §6: a cell of the (v, ω) grid drawn from the probabilities `inferred`, then a value
/// uniformly inside it. Shared by every model of the grid contract (M_ConvNet, ONNX models).
/// A draw whose step would cross the tank's wall margin is drawn again, up to `wall_redraws`
/// times ([`ConvNetParams::wall_redraws`]); when none stays in the water, the fish slides:
/// it takes the part of its last draw's step along the wall and turns to where it moved
/// (`wall_redraws` 0: the plain sampling, the step clipped as the simulator does).
pub fn sample_motion(
    arch: &ConvNetArch,
    view: &FishView,
    inferred: &[f32],
    wall_redraws: u32,
    mind: &mut FishMind,
    rng: &mut SimRng,
) -> FishMotion {
    let mut draw = || {
        let u: f32 = rng.random();
        let mut acc = 0.0;
        let mut cell = inferred.len().saturating_sub(1);
        for (i, p) in inferred.iter().enumerate() {
            acc += p;
            if u < acc {
                cell = i;
                break;
            }
        }
        let ((v0, dv), (w0, dw)) = arch.cell_bounds(cell);
        (v0 + dv * rng.random::<f32>(), w0 + dw * rng.random::<f32>())
    };
    let me = &view.me;
    let mut attempt = 0;
    loop {
        let (v, w) = draw();
        let heading = me.heading + w * view.dt;
        let (s, c) = heading.sin_cos();
        let step = v.max(0.0) * view.dt;
        let (x, y, contact) = view.tank.clip(me.x + step * c, me.y + step * s);
        if !contact || wall_redraws == 0 {
            mind.speed = v;
            mind.turn_rate = w;
            return FishMotion { heading, speed: v };
        }
        if attempt >= wall_redraws {
            // No draw stays in the water: the glass turns the fish along it. It takes the step
            // the wall allows (the part of its step along the wall) and heads where it moved;
            // nose straight in (or in a corner) it turns on the spot.
            let (dx, dy) = (x - me.x, y - me.y);
            let moved = (dx * dx + dy * dy).sqrt();
            let (heading, speed) = if moved > 1e-4 {
                (dy.atan2(dx), moved / view.dt)
            } else {
                (heading, 0.0)
            };
            mind.speed = speed;
            mind.turn_rate = fishprobe_sim::wrap_angle(heading - me.heading) / view.dt;
            return FishMotion { heading, speed };
        }
        attempt += 1;
    }
}

/// [`ConvNetParams::wall_redraws`] (and the ONNX models' copy of it) within its range.
pub(crate) fn check_wall_redraws(
    prefix: &str,
    n: u32,
) -> Result<(), fishprobe_sim::params::ConfigError> {
    if n > ConvNetParams::MAX_WALL_REDRAWS {
        return Err(fishprobe_sim::params::ConfigError::new(
            prefix,
            "wall_redraws",
            n,
            &format!("must be at most {}", ConvNetParams::MAX_WALL_REDRAWS),
        ));
    }
    Ok(())
}

impl crate::ModelParams for ConvNetParams {
    const NAME: &'static str = "ConvNet";
    const SUMMARY: &'static str =
        "behavioural cloning of live guppy pairs: (speed, turn) sampled from a ConvNet";

    fn check(&self, prefix: &str) -> Result<(), fishprobe_sim::params::ConfigError> {
        check_wall_redraws(prefix, self.wall_redraws)
    }

    fn build_model(
        &self,
    ) -> Result<std::sync::Arc<dyn fishprobe_sim::FishModel>, crate::ModelError> {
        use std::sync::Arc;
        Ok(Arc::new(ConvNetFish::new(self)?))
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use fishprobe_sim::{AgentState, Tank};
    use rand::SeedableRng;

    /// One draw of `sample_motion` for a fish at `(x, y, heading)` whose distribution puts all
    /// its mass on the cell of (v, ω).
    fn sample_at(
        pose: [f32; 3],
        v: f32,
        w: f32,
        redraws: u32,
        seed: u64,
    ) -> (FishMotion, AgentState) {
        let arch = ConvNetArch::default();
        let mut p = vec![0.0; arch.cells()];
        p[arch.cell_of(v, w)] = 1.0;
        let me = AgentState::at(pose[0], pose[1], pose[2]);
        let robot = AgentState::at(0.0, 0.0, 0.0);
        let view = FishView::build(0, &[me], &[robot], Tank::default(), 0.04, 0.0);
        let mut rng = fishprobe_sim::stream(seed, "test", 0);
        let m = sample_motion(
            &arch,
            &view,
            &p,
            redraws,
            &mut FishMind::default(),
            &mut rng,
        );
        (m, me)
    }

    #[test]
    fn a_fish_at_the_glass_slides_along_it_instead_of_swimming_into_it() {
        use std::f32::consts::FRAC_PI_4;
        let tank = Tank::default();
        let lim = tank.half - tank.margin; // 49 cm: the margin line
                                           // At the bottom margin line, heading 45° into the wall (down and right), all mass on
                                           // 10 cm/s straight on: every draw crosses the margin.
        let pose = [0.0, -lim, -FRAC_PI_4];
        let (m, me) = sample_at(pose, 10.2, 0.0, 0, 1);
        let step = m.speed * 0.04;
        assert!(
            tank.clip(me.x + step * m.heading.cos(), me.y + step * m.heading.sin())
                .2
        );
        // With redraws it slides: along the wall (heading 0, rightwards), at the part of its
        // speed along the wall (cos 45° of a speed in the cell [10, 11) cm/s; ω in the cell
        // around 0 turns it by at most 0.01 rad), and the step stays in the water.
        let (m, me) = sample_at(pose, 10.2, 0.0, 16, 1);
        assert!(m.heading.abs() < 0.05, "heading {}", m.heading);
        let along = FRAC_PI_4.cos();
        assert!(m.speed > 9.9 * along && m.speed < 11.1 * along, "{m:?}");
        let step = m.speed * 0.04;
        assert!(
            !tank
                .clip(me.x + step * m.heading.cos(), me.y + step * m.heading.sin())
                .2
        );
        // Nose straight in: next to nothing to slide on (the drawn turn, at most 0.01 rad
        // here, leaves a sliver along the wall), it turns nearly on the spot.
        let (m, _) = sample_at([0.0, -lim, -std::f32::consts::FRAC_PI_2], 10.2, 0.0, 16, 1);
        assert!(m.speed < 11.0 * 0.01, "{m:?}");
        // A turn away is kept when it is drawn: mass on a hard left turn at speed 2 cm/s,
        // heading 5° into the wall at the margin, stays as drawn (no redraw needed).
        let (m, _) = sample_at([0.0, -lim, -0.087], 2.2, 9.8, 16, 1);
        assert!(m.heading > -0.087 + 0.3, "turned {}", m.heading);
    }

    #[test]
    fn in_open_water_the_redraws_change_nothing() {
        for seed in 0..20 {
            let a = sample_at([5.0, 3.0, 0.7], 6.1, -1.3, 0, seed).0;
            let b = sample_at([5.0, 3.0, 0.7], 6.1, -1.3, 16, seed).0;
            assert_eq!((a.heading, a.speed), (b.heading, b.speed));
        }
        let bad = ConvNetParams {
            wall_redraws: ConvNetParams::MAX_WALL_REDRAWS + 1,
            ..ConvNetParams::default()
        };
        use crate::ModelParams;
        assert!(bad
            .check("ConvNet")
            .unwrap_err()
            .to_string()
            .contains("wall_redraws"));
    }

    #[test]
    fn grid_cells_round_trip_and_clamp() {
        let a = ConvNetArch::default();
        let c = a.cell_of(5.5, 0.3);
        let ((v0, dv), (w0, dw)) = a.cell_bounds(c);
        assert!(v0 <= 5.5 && 5.5 < v0 + dv && w0 <= 0.3 && 0.3 < w0 + dw);
        assert_eq!(a.cell_of(-3.0, -50.0), 0);
        assert_eq!(a.cell_of(99.0, 50.0), a.cells() - 1);
    }

    #[test]
    fn a_fish_inference_does_not_depend_on_its_batch() {
        // The vector environment splits a frame's batch across cores; evaluation and the
        // virtual lab step one fish at a time. All must give the same bits.
        let fish = ConvNetFish::from_net(ConvNet::shipped().unwrap());
        let tank = Tank::new(&fishprobe_sim::TankParams::default());
        let views: Vec<FishView> = (0..40)
            .map(|i| {
                let f = i as f32;
                let me = AgentState::at(-40.0 + 2.0 * f, 30.0 - 1.5 * f, 0.3 * f - 3.0);
                let robot = AgentState::at(10.0 - f, 5.0 + 0.5 * f, 1.0);
                FishView::build(0, &[me], &[robot], tank, 0.04, f)
            })
            .collect();
        let w = fish.inference_width();
        let mut whole = vec![0.0; views.len() * w];
        fish.infer_batch(&views, &mut whole);
        for cut in [1, 2, 5, 16, 20, 33, 39] {
            let mut parts = vec![0.0; views.len() * w];
            let (a, b) = parts.split_at_mut(cut * w);
            fish.infer_batch(&views[..cut], a);
            fish.infer_batch(&views[cut..], b);
            assert!(
                whole
                    .iter()
                    .zip(&parts)
                    .all(|(x, y)| x.to_bits() == y.to_bits()),
                "split at {cut}"
            );
        }
        for (k, v) in views.iter().enumerate() {
            let mut one = vec![0.0; w];
            fish.infer_batch(std::slice::from_ref(v), &mut one);
            assert!(
                one.iter()
                    .zip(&whole[k * w..(k + 1) * w])
                    .all(|(x, y)| x.to_bits() == y.to_bits()),
                "fish {k} alone"
            );
        }
    }

    #[test]
    fn view_puts_the_neighbour_in_the_right_bin() {
        let a = ConvNetArch::default();
        let tank = Tank::new(&fishprobe_sim::TankParams::default());
        let me = AgentState::at(0.0, 0.0, 0.0);
        // Straight ahead (bearing 0): bin 36 of 72 covers [0°, 5°).
        let other = AgentState::at(10.0, 0.1, std::f32::consts::FRAC_PI_2);
        let mut v = vec![0.0; a.view_len()];
        encode_view(&a, &tank, &me, &[other], &mut v);
        let near = &v[72..144];
        let (i, _) = near
            .iter()
            .enumerate()
            .fold((0, 0.0), |b, (i, &x)| if x > b.1 { (i, x) } else { b });
        assert_eq!(i, 36);
        assert!((near[36] - (1.0 - 10.0 / 141.421_36)).abs() < 1e-3);
        assert!(
            (v[144 + 36] - 0.5).abs() < 1e-5,
            "relative heading π/2 → 0.5"
        );
        // The wall straight ahead is 50 cm away; behind too.
        assert!((v[36] - (1.0 - 50.0 / 141.421_36)).abs() < 2e-2);
        assert!(v[..72].iter().all(|w| (0.0..=1.0).contains(w)));
    }

    #[test]
    fn a_group_is_seen_as_the_nearest_agent_per_bin() {
        let a = ConvNetArch::default();
        let tank = Tank::new(&fishprobe_sim::TankParams::default());
        let me = AgentState::at(0.0, 0.0, 0.0);
        let ahead_far = AgentState::at(20.0, 0.1, 0.0);
        let ahead_near = AgentState::at(10.0, 0.05, std::f32::consts::FRAC_PI_2);
        let left = AgentState::at(-0.5, 15.0, std::f32::consts::PI / 4.0);
        let view = |others: &[AgentState]| {
            let mut v = vec![0.0; a.view_len()];
            encode_view(&a, &tank, &me, others, &mut v);
            v
        };
        // The nearer of two agents in the same bin wins it, in either order.
        let both = view(&[ahead_far, ahead_near, left]);
        assert_eq!(both, view(&[left, ahead_near, ahead_far]));
        assert_eq!(both[72 + 36], view(&[ahead_near])[72 + 36]);
        assert!((both[144 + 36] - 0.5).abs() < 1e-6);
        // An agent in another bin (90° left: bin 54) is marked too.
        assert!((both[72 + 54] - (1.0 - 15.008_33 / 141.421_36)).abs() < 1e-4);
        assert!((both[144 + 54] - 0.25).abs() < 1e-6);
        // Exactly two bins are occupied; no agents, none.
        assert_eq!(both[72..144].iter().filter(|&&x| x > 0.0).count(), 2);
        assert!(view(&[])[72..].iter().all(|&x| x == 0.0));
        // An untracked (NaN) agent marks nothing and takes no bin from a tracked one.
        let nan = AgentState::at(f32::NAN, f32::NAN, 0.0);
        assert_eq!(view(&[nan, ahead_near]), view(&[ahead_near]));
    }

    /// A small network for gradient checks (`latent_dim`, seeded), its output weights made
    /// larger so that a check is not dominated by rounding, and a batch of two inputs.
    fn tiny_net(latent_dim: usize, seed: u64) -> (ConvNetArch, ConvNet, usize, Vec<f32>) {
        let arch = ConvNetArch {
            bins: 12,
            conv_channels: 2,
            kernel: 3,
            hidden: [5, 4],
            v_bins: 2,
            w_bins: 3,
            latent_dim,
            ..ConvNetArch::default()
        };
        let mut rng = rand_xoshiro::Xoshiro256PlusPlus::seed_from_u64(seed);
        let mut net = ConvNet::new(arch.clone(), &mut rng);
        for p in net.mlp.params_mut() {
            *p *= 3.0;
        }
        let batch = 2;
        let x: Vec<f32> = (0..batch * arch.view_len())
            .map(|i| ((i * 37 % 11) as f32 / 11.0) - 0.3)
            .collect();
        (arch, net, batch, x)
    }

    #[test]
    fn backward_matches_finite_differences() {
        let (arch, mut net, batch, x) = tiny_net(0, 3);
        let targets = [1usize, 4];
        let loss = |n: &ConvNet| {
            let mut ws = ConvNetWorkspace::default();
            let l = n.forward(&x, batch, &mut ws).to_vec();
            let mut g = vec![0.0; l.len()];
            f64::from(fishprobe_nn::dist::softmax_cross_entropy(
                &l,
                arch.cells(),
                &targets,
                &mut g,
            ))
        };
        let mut ws = ConvNetWorkspace::default();
        let logits = net.forward(&x, batch, &mut ws).to_vec();
        let mut dl = vec![0.0; logits.len()];
        fishprobe_nn::dist::softmax_cross_entropy(&logits, arch.cells(), &targets, &mut dl);
        let mut gc = vec![0.0; net.conv.params.len()];
        let mut gm = vec![0.0; net.mlp.num_params()];
        net.backward(&x, batch, &dl, &mut ws, &mut gc, &mut gm);
        let h = 1e-2f32;
        for k in (0..gc.len()).step_by(3) {
            let mut a = net.clone();
            a.conv.params[k] += h;
            let mut b = net.clone();
            b.conv.params[k] -= h;
            let fd = (loss(&a) - loss(&b)) / (2.0 * f64::from(h));
            assert!(
                (fd - f64::from(gc[k])).abs() < 2e-3 + 2e-2 * fd.abs(),
                "conv {k}: {fd} vs {}",
                gc[k]
            );
        }
        for k in (0..gm.len()).step_by(7) {
            let mut a = net.clone();
            a.mlp.params_mut()[k] += h;
            let mut b = net.clone();
            b.mlp.params_mut()[k] -= h;
            let fd = (loss(&a) - loss(&b)) / (2.0 * f64::from(h));
            assert!(
                (fd - f64::from(gm[k])).abs() < 2e-3 + 2e-2 * fd.abs(),
                "mlp {k}: {fd} vs {}",
                gm[k]
            );
        }
        let _ = &mut net;
    }

    #[test]
    fn the_latent_gradient_matches_finite_differences_and_the_latent_matters() {
        let (arch, mut net, batch, x) = tiny_net(2, 5);
        let z = vec![0.4f32, -0.7, 1.1, 0.2];
        let targets = [2usize, 5];
        let loss = |z: &[f32]| {
            let mut ws = ConvNetWorkspace::default();
            let l = net.forward_latent(&x, Some(z), batch, &mut ws).to_vec();
            let mut g = vec![0.0; l.len()];
            f64::from(fishprobe_nn::dist::softmax_cross_entropy(
                &l,
                arch.cells(),
                &targets,
                &mut g,
            ))
        };
        let mut ws = ConvNetWorkspace::default();
        let logits = net.forward_latent(&x, Some(&z), batch, &mut ws).to_vec();
        let mut dl = vec![0.0; logits.len()];
        fishprobe_nn::dist::softmax_cross_entropy(&logits, arch.cells(), &targets, &mut dl);
        let mut gc = vec![0.0; net.conv.params.len()];
        let mut gm = vec![0.0; net.mlp.num_params()];
        let mut gz = vec![0.0; z.len()];
        net.backward_latent(&x, batch, &dl, &mut ws, &mut gc, &mut gm, Some(&mut gz));
        let h = 1e-2f32;
        for k in 0..z.len() {
            let (mut a, mut b) = (z.clone(), z.clone());
            a[k] += h;
            b[k] -= h;
            let fd = (loss(&a) - loss(&b)) / (2.0 * f64::from(h));
            assert!(
                (fd - f64::from(gz[k])).abs() < 2e-3 + 2e-2 * fd.abs(),
                "latent {k}: {fd} vs {}",
                gz[k]
            );
        }
        // Another individual, other logits; no latent at all is the centre (zeros).
        assert!((loss(&z) - loss(&[0.0; 4])).abs() > 1e-6);
        let mut ws = ConvNetWorkspace::default();
        let centre = net.forward(&x, batch, &mut ws).to_vec();
        let zeros = net
            .forward_latent(&x, Some(&[0.0; 4]), batch, &mut ws)
            .to_vec();
        assert_eq!(centre, zeros);
        let _ = &mut net;
    }

    #[test]
    fn the_shipped_network_with_individuals_loads_and_its_fish_differ_by_latent() {
        let net = ConvNet::shipped_individuals().expect("the shipped individuals load");
        assert_eq!(net.arch.latent_dim, 4);
        let fish = ConvNetFish::new(&ConvNetParams {
            weights: SHIPPED_INDIVIDUALS_WEIGHTS.into(),
            ..ConvNetParams::default()
        })
        .unwrap();
        let tank = fishprobe_sim::Tank::default();
        let me = fishprobe_sim::AgentState::at(0.0, 0.0, 0.0);
        let mut a = FishView::build(0, &[me], &[], tank, 0.04, 0.0);
        let mut b = a;
        a.individual.latent = [1.5, -1.0, 0.5, 0.0];
        b.individual.latent = [-1.5, 1.0, -0.5, 0.0];
        let w = fish.inference_width();
        let (mut pa, mut pb) = (vec![0.0; w], vec![0.0; w]);
        fish.infer_batch(&[a], &mut pa);
        fish.infer_batch(&[b], &mut pb);
        let diff: f32 = pa.iter().zip(&pb).map(|(x, y)| (x - y).abs()).sum();
        assert!(
            diff > 0.05,
            "two individuals, the same distribution: {diff}"
        );
    }

    #[test]
    fn shipped_weights_load_and_a_mismatch_is_a_clear_error() {
        let net = ConvNet::shipped().expect("the shipped weights load");
        assert_eq!(net.arch, ConvNetArch::default());
        let mut t = net.to_tensors();
        t.insert("conv".into(), (vec![3], vec![0.0; 3]));
        let meta = ConvNet::shipped_meta();
        let e = ConvNet::from_parts(&t, &meta, "x.safetensors")
            .unwrap_err()
            .to_string();
        assert!(e.contains("x.safetensors") && e.contains("conv"), "{e}");
        let e = ConvNet::from_parts(&net.to_tensors(), &serde_json::json!({}), "y").unwrap_err();
        assert!(e.to_string().contains("arch"), "{e}");
    }

    #[test]
    fn a_missing_weights_file_is_named_once_and_a_missing_sidecar_by_its_own_name() {
        let dir =
            std::env::temp_dir().join(format!("fishprobe-convnet-load-{}", std::process::id()));
        std::fs::create_dir_all(&dir).unwrap();
        let path = dir.join("none.safetensors");
        let e = ConvNet::load(&path).unwrap_err().to_string();
        let name = path.display().to_string();
        assert_eq!(e.matches(name.as_str()).count(), 1, "{e}");
        // Weights without their sidecar: the sidecar's path says which file is missing.
        let net = ConvNet::shipped().unwrap();
        std::fs::write(
            &path,
            fishprobe_nn::store::to_bytes(&net.to_tensors()).unwrap(),
        )
        .unwrap();
        let e = ConvNet::load(&path).unwrap_err().to_string();
        assert!(e.contains(&format!("{name}.json")), "{e}");
        std::fs::remove_dir_all(&dir).unwrap();
    }
}
