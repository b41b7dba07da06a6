//! The square tank: walls, distances, raycasts and clipping. Coordinates in cm, origin at the
//! tank centre, x right, y up; headings in radians counter-clockwise from +x.

use crate::params::{check, ConfigError};
use std::f32::consts::{PI, TAU};

crate::documented_params! {
    /// The tank (SPEC §2).
    pub struct TankParams {
        /// Half the side of the square tank: walls at x, y = ±half_size_cm (paper: 100 x 100 cm).
        /// At most [`MAX_HALF_SIZE_CM`] (a 100 m tank): farther from the centre an `f32`
        /// position no longer resolves a fish's step, and the fish would silently stand still.
        pub half_size_cm: f32 = 50.0; "cm",
        /// Agents are kept this far inside the walls; a step that would cross the line is clipped
        /// onto it and counted as a wall contact (SPEC choice).
        pub wall_margin_cm: f32 = 1.0; "cm",
    }
}

/// The largest `half_size_cm` accepted (choice): at 5,000 cm an `f32` position resolves about
/// 0.5 mm, a tenth of a slow fish's step at 25 Hz; a tank of 1e30 cm would freeze every agent
/// in place without an error.
pub const MAX_HALF_SIZE_CM: f32 = 5_000.0;

impl TankParams {
    /// Checks the ranges; `prefix` is the field path of this struct.
    pub fn validate(&self, prefix: &str) -> Result<(), ConfigError> {
        check::positive(prefix, "half_size_cm", self.half_size_cm)?;
        check::within(
            prefix,
            "half_size_cm",
            self.half_size_cm,
            0.0,
            MAX_HALF_SIZE_CM,
        )?;
        check::within(
            prefix,
            "wall_margin_cm",
            self.wall_margin_cm,
            0.0,
            self.half_size_cm * 0.5,
        )
    }
}

/// Wraps an angle to [-π, π).
#[inline]
pub fn wrap_angle(a: f32) -> f32 {
    if (-PI..PI).contains(&a) {
        return a;
    }
    let w = a - TAU * ((a + PI) / TAU).floor();
    // Rounding can land exactly on +π; keep the half-open interval.
    if w >= PI {
        w - TAU
    } else {
        w
    }
}

/// One wall as seen from a point.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct WallSight {
    /// Distance from the point to the wall (cm).
    pub distance: f32,
    /// Unit normal pointing from the wall into the tank.
    pub inward: [f32; 2],
}

/// Validated tank geometry, cheap to copy.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct Tank {
    /// Half side (cm).
    pub half: f32,
    /// Clipping margin (cm).
    pub margin: f32,
}

impl Default for Tank {
    fn default() -> Self {
        Self::new(&TankParams::default())
    }
}

impl Tank {
    /// From (already validated) parameters.
    pub fn new(p: &TankParams) -> Self {
        Self {
            half: p.half_size_cm,
            margin: p.wall_margin_cm,
        }
    }

    /// Length of the tank diagonal (cm): the far plane of all intensity encodings.
    pub fn diagonal(&self) -> f32 {
        2.0 * self.half * std::f32::consts::SQRT_2
    }

    /// Distance from a point inside the tank to the nearest wall (cm).
    #[inline]
    pub fn wall_distance(&self, x: f32, y: f32) -> f32 {
        self.half - x.abs().max(y.abs())
    }

    /// The four walls as seen from (x, y): right, left, top, bottom.
    #[inline]
    pub fn walls(&self, x: f32, y: f32) -> [WallSight; 4] {
        [
            WallSight {
                distance: self.half - x,
                inward: [-1.0, 0.0],
            },
            WallSight {
                distance: self.half + x,
                inward: [1.0, 0.0],
            },
            WallSight {
                distance: self.half - y,
                inward: [0.0, -1.0],
            },
            WallSight {
                distance: self.half + y,
                inward: [0.0, 1.0],
            },
        ]
    }

    /// The nearest wall as seen from (x, y).
    #[inline]
    pub fn nearest_wall(&self, x: f32, y: f32) -> WallSight {
        let walls = self.walls(x, y);
        let mut best = walls[0];
        for w in &walls[1..] {
            if w.distance < best.distance {
                best = *w;
            }
        }
        best
    }

    /// Distance from (x, y) along the unit direction (c, s) to the wall it hits (cm).
    #[inline]
    pub fn raycast(&self, x: f32, y: f32, c: f32, s: f32) -> f32 {
        let tx = if c > 1e-9 {
            (self.half - x) / c
        } else if c < -1e-9 {
            (-self.half - x) / c
        } else {
            f32::INFINITY
        };
        let ty = if s > 1e-9 {
            (self.half - y) / s
        } else if s < -1e-9 {
            (-self.half - y) / s
        } else {
            f32::INFINITY
        };
        tx.min(ty).max(0.0)
    }

    /// Keeps a point inside the walls less the margin. Returns the clipped point and whether
    /// clipping happened (a wall contact).
    #[inline]
    pub fn clip(&self, x: f32, y: f32) -> (f32, f32, bool) {
        let lim = self.half - self.margin;
        let cx = x.clamp(-lim, lim);
        let cy = y.clamp(-lim, lim);
        (cx, cy, cx != x || cy != y)
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn a_tank_too_large_for_f32_positions_is_refused() {
        let ok = TankParams {
            half_size_cm: MAX_HALF_SIZE_CM,
            ..TankParams::default()
        };
        assert!(ok.validate("tank").is_ok());
        let e = TankParams {
            half_size_cm: 1e30,
            ..TankParams::default()
        }
        .validate("tank")
        .unwrap_err();
        assert_eq!(e.field, "tank.half_size_cm");
        assert!(e.to_string().contains("5000"), "{e}");
    }

    #[test]
    fn wrap_is_half_open() {
        assert_eq!(wrap_angle(0.5), 0.5);
        assert!((wrap_angle(PI) + PI).abs() < 1e-6);
        assert!((wrap_angle(3.0 * PI) + PI).abs() < 1e-5);
        assert!((wrap_angle(-PI) + PI).abs() < 1e-6);
        assert!((wrap_angle(7.0) - (7.0 - TAU)).abs() < 1e-6);
        for i in -1000..1000 {
            let w = wrap_angle(i as f32 * 0.0371);
            assert!((-PI..PI).contains(&w));
        }
    }

    #[test]
    fn distances_and_rays() {
        let t = Tank::default();
        assert_eq!(t.wall_distance(0.0, 0.0), 50.0);
        assert_eq!(t.wall_distance(40.0, -10.0), 10.0);
        let n = t.nearest_wall(40.0, -10.0);
        assert_eq!(n.inward, [-1.0, 0.0]);
        assert!((t.raycast(0.0, 0.0, 1.0, 0.0) - 50.0).abs() < 1e-6);
        let d = std::f32::consts::FRAC_1_SQRT_2;
        assert!((t.raycast(0.0, 0.0, d, d) - 50.0 * std::f32::consts::SQRT_2).abs() < 1e-4);
        assert!((t.raycast(10.0, 20.0, 0.0, -1.0) - 70.0).abs() < 1e-6);
        assert!((t.diagonal() - 141.42136).abs() < 1e-3);
    }

    #[test]
    fn clipping_keeps_margin() {
        let t = Tank::default();
        assert_eq!(t.clip(10.0, 10.0), (10.0, 10.0, false));
        assert_eq!(t.clip(60.0, -70.0), (49.0, -49.0, true));
    }
}
