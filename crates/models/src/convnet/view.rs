//! What the network sees and what it answers in: its shape, the (v, ω) grid of its output,
//! and the egocentric view it is given ([`encode_view`]).

use fishprobe_sim::params::ConfigError;
use fishprobe_sim::{AgentState, FishView, Tank};
use serde::{Deserialize, Serialize};

/// The network's shape and the (v, ω) grid; saved in the weights' sidecar, so a weights file
/// always says what it was trained as.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct ConvNetArch {
    /// Angular bins of the view over 360° (SPEC choice: 72 of 5°).
    pub bins: usize,
    /// Far plane of the intensity 1 - d/D (cm; SPEC choice: the tank diagonal).
    pub far_plane_cm: f32,
    /// Output channels of the convolution (choice).
    pub conv_channels: usize,
    /// Kernel width of the convolution, in bins (choice; odd).
    pub kernel: usize,
    /// Widths of the two fully connected hidden layers (choice).
    pub hidden: [usize; 2],
    /// Negative slope of the Leaky-ReLUs (choice: PyTorch's default).
    pub leaky_slope: f32,
    /// Speed cells over [0, v_max) (SPEC choice: 25).
    pub v_bins: usize,
    /// Upper end of the speed grid (cm/s; SPEC choice: 25).
    pub v_max_cm_s: f32,
    /// Turn-rate cells over [-w_max, w_max) (SPEC choice: 41).
    pub w_bins: usize,
    /// Half-width of the turn-rate grid (rad/s; SPEC choice: 10).
    pub w_max_rad_s: f32,
    /// Length of the individual's latent vector fed to the dense layers beside the
    /// convolution's output (0: M_ConvNet as the paper has it, one average fish; at most
    /// `fishprobe_sim::LATENT_DIM`). Written only when not 0, so the sidecars of networks
    /// without one read and write as before.
    #[serde(default, skip_serializing_if = "is_zero")]
    pub latent_dim: usize,
}

fn is_zero(n: &usize) -> bool {
    *n == 0
}

impl Default for ConvNetArch {
    fn default() -> Self {
        Self {
            bins: 72,
            far_plane_cm: 141.421_36,
            conv_channels: 8,
            kernel: 5,
            hidden: [128, 128],
            leaky_slope: 0.01,
            v_bins: 25,
            v_max_cm_s: 25.0,
            w_bins: 41,
            w_max_rad_s: 10.0,
            latent_dim: 0,
        }
    }
}

/// View channels.
pub const CHANNELS: usize = 3;

impl ConvNetArch {
    /// Floats of one view.
    pub fn view_len(&self) -> usize {
        CHANNELS * self.bins
    }

    /// Cells of the (v, ω) grid.
    pub fn cells(&self) -> usize {
        self.v_bins * self.w_bins
    }

    /// Checks the shape.
    pub fn validate(&self) -> Result<(), ConfigError> {
        let bad = |field: &str, v: String, why: &str| {
            Err(ConfigError::new("ConvNet.arch", field, v, why))
        };
        if !(8..=720).contains(&self.bins) {
            return bad("bins", self.bins.to_string(), "must lie in [8, 720]");
        }
        if self.kernel.is_multiple_of(2) || self.kernel > self.bins {
            return bad(
                "kernel",
                self.kernel.to_string(),
                "must be odd and at most `bins`",
            );
        }
        if self.conv_channels == 0
            || self.hidden.contains(&0)
            || self.v_bins == 0
            || self.w_bins == 0
        {
            return bad(
                "conv_channels/hidden/v_bins/w_bins",
                "0".into(),
                "must be at least 1",
            );
        }
        if self.latent_dim > fishprobe_sim::LATENT_DIM {
            return bad(
                "latent_dim",
                self.latent_dim.to_string(),
                &format!("must be at most {}", fishprobe_sim::LATENT_DIM),
            );
        }
        for (f, v) in [
            ("far_plane_cm", self.far_plane_cm),
            ("v_max_cm_s", self.v_max_cm_s),
            ("w_max_rad_s", self.w_max_rad_s),
        ] {
            if !(v.is_finite() && v > 0.0) {
                return bad(f, v.to_string(), "must be finite and greater than 0");
            }
        }
        Ok(())
    }

    /// The grid cell of a (speed, turn rate) pair (values outside the grid go to its edge).
    pub fn cell_of(&self, v: f32, w: f32) -> usize {
        let vi = ((v / self.v_max_cm_s) * self.v_bins as f32).floor();
        let wi = ((w + self.w_max_rad_s) / (2.0 * self.w_max_rad_s) * self.w_bins as f32).floor();
        let vi = (vi.max(0.0) as usize).min(self.v_bins - 1);
        let wi = (wi.max(0.0) as usize).min(self.w_bins - 1);
        vi * self.w_bins + wi
    }

    /// The lower corner and size of a cell: ((v0, dv), (w0, dw)).
    pub fn cell_bounds(&self, cell: usize) -> ((f32, f32), (f32, f32)) {
        let (vi, wi) = (cell / self.w_bins, cell % self.w_bins);
        let dv = self.v_max_cm_s / self.v_bins as f32;
        let dw = 2.0 * self.w_max_rad_s / self.w_bins as f32;
        (
            (vi as f32 * dv, dv),
            (-self.w_max_rad_s + wi as f32 * dw, dw),
        )
    }
}

/// The egocentric view of a fish at `me`, with the other agents `others` (position and
/// heading; none, the pair partner, or a group of up to `MAX_OTHERS`, as a view holds) into
/// `out` (`3 x bins`, channel-major). Each bin holds the nearest agent whose bearing falls in
/// it (ties: the first listed), so a group is seen as the nearest agent per sector and one
/// partner exactly as in the pair recordings.
pub fn encode_view(
    arch: &ConvNetArch,
    tank: &Tank,
    me: &AgentState,
    others: &[AgentState],
    out: &mut [f32],
) {
    let n = arch.bins;
    let width = std::f32::consts::TAU / n as f32;
    let (walls, rest) = out[..CHANNELS * n].split_at_mut(n);
    let (near, rel) = rest.split_at_mut(n);
    for (i, w) in walls.iter_mut().enumerate() {
        let phi = me.heading - std::f32::consts::PI + (i as f32 + 0.5) * width;
        let (s, c) = phi.sin_cos();
        let d = tank.raycast(me.x, me.y, c, s);
        *w = (1.0 - d / arch.far_plane_cm).max(0.0);
    }
    near.fill(0.0);
    rel.fill(0.0);
    // Bin and distance of each agent, once (None when its position is not finite). A view
    // holds at most MAX_OTHERS agents; so does this (no allocation per fish and frame).
    let mut placed = [None::<(usize, f32)>; fishprobe_sim::MAX_OTHERS];
    for (slot, o) in placed.iter_mut().zip(others) {
        let (dx, dy) = (o.x - me.x, o.y - me.y);
        let d = (dx * dx + dy * dy).sqrt();
        *slot = d.is_finite().then(|| {
            let bearing = fishprobe_sim::wrap_angle(dy.atan2(dx) - me.heading);
            let i = (((bearing + std::f32::consts::PI) / width) as usize).min(n - 1);
            (i, d)
        });
    }
    let placed = &placed[..others.len().min(fishprobe_sim::MAX_OTHERS)];
    for (j, (o, p)) in others.iter().zip(placed).enumerate() {
        let Some((i, d)) = *p else { continue };
        // A nearer agent in the same bin (or an equally near one listed earlier) wins it.
        let beaten = placed
            .iter()
            .enumerate()
            .any(|(l, q)| l != j && q.is_some_and(|(k, e)| k == i && (e < d || (e == d && l < j))));
        if !beaten {
            near[i] = (1.0 - d / arch.far_plane_cm).max(0.0);
            rel[i] = fishprobe_sim::wrap_angle(o.heading - me.heading) / std::f32::consts::PI;
        }
    }
}

/// The views of `views`' fish, one row of `arch.view_len()` each, into `x` (sized already).
pub(crate) fn encode_views(arch: &ConvNetArch, views: &[FishView], x: &mut [f32]) {
    for (v, row) in views.iter().zip(x.chunks_exact_mut(arch.view_len())) {
        encode_view(arch, &v.tank, &v.me, v.others(), row);
    }
}
