//! The embedding: what a view shows ([`Situation`]) and its features.

use crate::convnet::ConvNetArch;
use fishprobe_sim::wrap_angle;
use serde::{Deserialize, Serialize};
use std::f32::consts::PI;

/// Features of the embedding.
pub const FEATURES: usize = 9;

/// Names of the features, in order.
pub const FEATURE_NAMES: [&str; FEATURES] = [
    "ln(1 + partner distance / cm)",
    "cos partner bearing",
    "sin partner bearing",
    "cos relative heading",
    "sin relative heading",
    "ln(1 + wall distance / cm)",
    "cos wall bearing",
    "sin wall bearing",
    "ln(1 + second wall distance / cm)",
];

/// The second wall is the nearest one at least this far in bearing from the nearest wall
/// (choice: 80°): at a straight wall it lies 1/cos 80° ≈ 5.8 times further than the first,
/// in a corner about as near.
pub const SECOND_WALL_MIN_ANGLE_RAD: f32 = 80.0 * PI / 180.0;

/// What a view shows, in plain terms. Angles are egocentric (0 = straight ahead, positive
/// to the left), in radians in [-π, π).
#[derive(Debug, Clone, Copy, PartialEq, Default, Serialize, Deserialize)]
pub struct Situation {
    /// Whether the view shows another agent at all.
    pub partner_seen: bool,
    /// Distance to the nearest other agent (cm; the far plane when none is seen).
    pub partner_distance_cm: f32,
    /// Bearing of that agent (0 when none is seen).
    pub partner_bearing_rad: f32,
    /// Its heading relative to the fish's (π: head-on when ahead; 0 when none is seen).
    pub relative_heading_rad: f32,
    /// Distance to the nearest wall along the view's rays (cm).
    pub wall_distance_cm: f32,
    /// Bearing of that wall.
    pub wall_bearing_rad: f32,
    /// Distance to the nearest wall at least [`SECOND_WALL_MIN_ANGLE_RAD`] in bearing from
    /// the nearest one (cm): near in a corner, far along a straight wall.
    pub second_wall_cm: f32,
}

impl Situation {
    /// The situation a view (`3 x bins`, channel-major, as [`encode_view`](crate::convnet::encode_view) writes it) shows.
    pub fn of_view(arch: &ConvNetArch, view: &[f32]) -> Self {
        let n = arch.bins;
        let width = std::f32::consts::TAU / n as f32;
        let centre = |i: usize| -PI + (i as f32 + 0.5) * width;
        let argmax = |c: &[f32]| {
            c.iter()
                .enumerate()
                .fold((0usize, f32::NEG_INFINITY), |(bi, bv), (i, &v)| {
                    if v > bv {
                        (i, v)
                    } else {
                        (bi, bv)
                    }
                })
        };
        let (wi, wv) = argmax(&view[..n]);
        let (pi, pv) = argmax(&view[n..2 * n]);
        let far = arch.far_plane_cm;
        // Bins at least the second wall's angle away from the nearest wall's bin (circularly).
        let min_bins = (SECOND_WALL_MIN_ANGLE_RAD / width).ceil() as usize;
        let second = view[..n]
            .iter()
            .enumerate()
            .filter(|(i, _)| {
                let d = i.abs_diff(wi);
                d.min(n - d) >= min_bins
            })
            .fold(0.0f32, |m, (_, &v)| m.max(v));
        let mut s = Situation {
            second_wall_cm: far * (1.0 - second.max(0.0)),
            partner_distance_cm: far,
            wall_distance_cm: far * (1.0 - wv.max(0.0)),
            wall_bearing_rad: centre(wi),
            ..Situation::default()
        };
        if pv > 0.0 {
            s.partner_seen = true;
            s.partner_distance_cm = far * (1.0 - pv);
            s.partner_bearing_rad = centre(pi);
            s.relative_heading_rad = wrap_angle(view[2 * n + pi] * PI);
        }
        s
    }

    /// The embedding's features (see [`FEATURE_NAMES`]), every partner the view shows.
    pub fn features(&self) -> [f32; FEATURES] {
        self.features_within(0.0)
    }

    /// The embedding's features with partners farther than `partner_range_cm` embedded as
    /// not seen, at that distance (0: no range, every partner the view shows).
    pub fn features_within(&self, partner_range_cm: f32) -> [f32; FEATURES] {
        let (bs, bc) = self.partner_bearing_rad.sin_cos();
        let (hs, hc) = self.relative_heading_rad.sin_cos();
        let (ws, wc) = self.wall_bearing_rad.sin_cos();
        let beyond = partner_range_cm > 0.0 && self.partner_distance_cm > partner_range_cm;
        let g = if self.partner_seen && !beyond {
            1.0
        } else {
            0.0
        };
        let partner = if beyond {
            partner_range_cm
        } else {
            self.partner_distance_cm
        };
        [
            partner.max(0.0).ln_1p(),
            g * bc,
            g * bs,
            g * hc,
            g * hs,
            self.wall_distance_cm.max(0.0).ln_1p(),
            wc,
            ws,
            self.second_wall_cm.max(0.0).ln_1p(),
        ]
    }

    /// One line in plain terms.
    pub fn describe(&self) -> String {
        let side = |a: f32| {
            let d = a.to_degrees();
            if d.abs() <= 30.0 {
                "ahead".to_string()
            } else if d.abs() >= 150.0 {
                "behind".to_string()
            } else if d > 0.0 {
                format!("{:.0}° to the left", d)
            } else {
                format!("{:.0}° to the right", -d)
            }
        };
        let h = self.relative_heading_rad.to_degrees().abs();
        let heading = if h >= 135.0 {
            "head-on"
        } else if h <= 45.0 {
            "swimming the same way"
        } else {
            "crossing"
        };
        let corner = if self.second_wall_cm < 5.0 {
            format!(" (in a corner: another wall {:.1} cm)", self.second_wall_cm)
        } else {
            String::new()
        };
        format!(
            "partner {:.1} cm {}, {}; wall {:.1} cm {}{corner}",
            self.partner_distance_cm,
            side(self.partner_bearing_rad),
            heading,
            self.wall_distance_cm,
            side(self.wall_bearing_rad)
        )
    }
}
