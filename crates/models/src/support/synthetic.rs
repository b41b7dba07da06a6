//! Checking a support model: views of situations the guppy-pair data lacks, and the AUC.

use crate::convnet::{encode_view, ConvNetArch};
use fishprobe_sim::{AgentState, SimRng, Tank};
use rand::RngExt;
use std::f32::consts::PI;

/// Kinds of views the guppy-pair data lacks, for checking a support model.
pub const SYNTHETIC_KINDS: [&str; 2] = ["pressed into a corner", "head-on approach"];

/// `n` views of each [`SYNTHETIC_KINDS`] situation, built from poses: a fish within 2 cm of
/// both walls of a corner with its partner 2-5 cm away on the open side; a fish away from the
/// walls with its partner 2-6 cm straight ahead (±15°), heading at it (±20°).
pub fn synthetic_views(
    arch: &ConvNetArch,
    tank: &Tank,
    n: usize,
    rng: &mut SimRng,
) -> Vec<(&'static str, Vec<f32>)> {
    let len = arch.view_len();
    let mut out = Vec::new();
    let mut view = vec![0.0; len];
    let lim = tank.half - tank.margin;
    let mut corner = Vec::with_capacity(n * len);
    for _ in 0..n {
        let (sx, sy) = (
            if rng.random_bool(0.5) { 1.0 } else { -1.0 },
            if rng.random_bool(0.5) { 1.0 } else { -1.0 },
        );
        let x = sx * (lim - rng.random_range(0.0..2.0));
        let y = sy * (lim - rng.random_range(0.0..2.0));
        let me = AgentState::at(x, y, rng.random_range(-PI..PI));
        // The partner sits towards the centre.
        let a = (-sy).atan2(-sx) + rng.random_range(-0.5..0.5);
        let d = rng.random_range(2.0..5.0);
        let other = AgentState::at(x + d * a.cos(), y + d * a.sin(), rng.random_range(-PI..PI));
        encode_view(arch, tank, &me, &[other], &mut view);
        corner.extend_from_slice(&view);
    }
    out.push((SYNTHETIC_KINDS[0], corner));
    let mut head_on = Vec::with_capacity(n * len);
    for _ in 0..n {
        let inner = lim - 15.0;
        let me = AgentState::at(
            rng.random_range(-inner..inner),
            rng.random_range(-inner..inner),
            rng.random_range(-PI..PI),
        );
        let b = me.heading + rng.random_range(-0.26..0.26);
        let d = rng.random_range(2.0..6.0);
        let h = me.heading + PI + rng.random_range(-0.35..0.35);
        let other = AgentState::at(me.x + d * b.cos(), me.y + d * b.sin(), h);
        encode_view(arch, tank, &me, &[other], &mut view);
        head_on.extend_from_slice(&view);
    }
    out.push((SYNTHETIC_KINDS[1], head_on));
    out
}

/// Area under the ROC curve for separating `outside` (positive) from `inside` by score: the
/// probability that a random outside view scores higher than a random inside one (ties half).
pub fn auc(inside: &[f32], outside: &[f32]) -> f64 {
    let mut all: Vec<(f32, bool)> = inside
        .iter()
        .map(|&s| (s, false))
        .chain(outside.iter().map(|&s| (s, true)))
        .collect();
    all.sort_by(|a, b| a.0.total_cmp(&b.0));
    // Mann-Whitney U from mid-ranks.
    let mut rank_sum = 0.0f64;
    let mut i = 0;
    while i < all.len() {
        let mut j = i;
        while j < all.len() && all[j].0 == all[i].0 {
            j += 1;
        }
        let mid = (i + j + 1) as f64 / 2.0;
        rank_sum += all[i..j].iter().filter(|x| x.1).count() as f64 * mid;
        i = j;
    }
    let (n1, n0) = (outside.len() as f64, inside.len() as f64);
    (rank_sum - n1 * (n1 + 1.0) / 2.0) / (n1 * n0)
}
