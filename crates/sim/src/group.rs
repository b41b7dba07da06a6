//! Order parameters of a group of fish: polarisation and milling (Couzin et al.
//! 2002), nearest-neighbour distance and spread, and the robot's relation to the group.
//!
//! Every function takes one frame's poses and skips fish whose pose is not finite (untracked
//! in a recording); fewer than two finite fish give `None` where a group is needed.

use crate::agent::AgentState;

/// One frame's group measures.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct GroupOrder {
    /// Fish that entered the measures (finite poses).
    pub fish: usize,
    /// |mean heading unit vector|, in [0, 1]: 1 when all fish swim the same way.
    pub polarisation: f32,
    /// Couzin's group angular momentum |mean (r_ic × v_i)| with r_ic the unit vector from the
    /// centroid to fish i and v_i its heading, in [0, 1]: 1 when all circle the centroid the
    /// same way (a torus, or milling).
    pub milling: f32,
    /// Mean over fish of the distance to the nearest other fish (cm).
    pub mean_nnd_cm: f32,
    /// Mean distance of the fish from the centroid (cm).
    pub spread_cm: f32,
    /// The centroid (cm).
    pub centroid: [f32; 2],
}

#[inline]
fn finite(a: &AgentState) -> bool {
    a.x.is_finite() && a.y.is_finite() && a.heading.is_finite()
}

/// The group measures of `fish` (poses with headings); `None` with fewer than two finite fish.
/// No allocation: the nearest-neighbour search is the direct O(n²) one (n ≤ a few hundred).
pub fn group_order(fish: &[AgentState]) -> Option<GroupOrder> {
    let (mut n, mut cx, mut cy, mut hx, mut hy) = (0usize, 0.0f64, 0.0f64, 0.0f64, 0.0f64);
    for a in fish.iter().filter(|a| finite(a)) {
        n += 1;
        cx += f64::from(a.x);
        cy += f64::from(a.y);
        let (s, c) = a.heading.sin_cos();
        hx += f64::from(c);
        hy += f64::from(s);
    }
    if n < 2 {
        return None;
    }
    let nf = n as f64;
    let (cx, cy) = (cx / nf, cy / nf);
    let (mut m, mut spread, mut nnd) = (0.0f64, 0.0f64, 0.0f64);
    for (i, a) in fish.iter().enumerate().filter(|(_, a)| finite(a)) {
        let (rx, ry) = (f64::from(a.x) - cx, f64::from(a.y) - cy);
        let r = (rx * rx + ry * ry).sqrt();
        spread += r;
        if r > 1e-9 {
            let (s, c) = a.heading.sin_cos();
            m += (rx * f64::from(s) - ry * f64::from(c)) / r;
        }
        let nearest = fish
            .iter()
            .enumerate()
            .filter(|(j, b)| *j != i && finite(b))
            .map(|(_, b)| f64::from(a.distance_to(b)))
            .fold(f64::INFINITY, f64::min);
        nnd += nearest;
    }
    Some(GroupOrder {
        fish: n,
        polarisation: ((hx * hx + hy * hy).sqrt() / nf) as f32,
        milling: (m.abs() / nf) as f32,
        mean_nnd_cm: (nnd / nf) as f32,
        spread_cm: (spread / nf) as f32,
        centroid: [cx as f32, cy as f32],
    })
}

/// The robot's relation to a group: its distance to the centroid (cm) and the fraction of the
/// finite fish within `range_cm` of it. `None` without a finite fish or robot.
pub fn robot_to_group(
    robot: &AgentState,
    fish: &[AgentState],
    range_cm: f32,
) -> Option<(f32, f32)> {
    if !(robot.x.is_finite() && robot.y.is_finite()) {
        return None;
    }
    let (mut n, mut near, mut cx, mut cy) = (0usize, 0usize, 0.0f64, 0.0f64);
    for a in fish.iter().filter(|a| a.x.is_finite() && a.y.is_finite()) {
        n += 1;
        cx += f64::from(a.x);
        cy += f64::from(a.y);
        if robot.distance_to(a) < range_cm {
            near += 1;
        }
    }
    if n == 0 {
        return None;
    }
    let (cx, cy) = (cx / n as f64, cy / n as f64);
    let d = ((f64::from(robot.x) - cx).powi(2) + (f64::from(robot.y) - cy).powi(2)).sqrt();
    Some((d as f32, near as f32 / n as f32))
}

#[cfg(test)]
mod tests {
    use super::*;
    use std::f32::consts::{FRAC_PI_2, PI};

    fn ring(n: usize, r: f32, heading_offset: f32) -> Vec<AgentState> {
        (0..n)
            .map(|i| {
                let a = i as f32 / n as f32 * std::f32::consts::TAU;
                AgentState::at(r * a.cos(), r * a.sin(), a + heading_offset)
            })
            .collect()
    }

    #[test]
    fn known_answers_for_a_torus_a_parallel_group_and_a_burst() {
        // Eight fish on a ring of 10 cm, each heading tangentially (counter-clockwise): a torus.
        let torus = group_order(&ring(8, 10.0, FRAC_PI_2)).unwrap();
        assert!(torus.polarisation < 1e-6, "{torus:?}");
        assert!((torus.milling - 1.0).abs() < 1e-6, "{torus:?}");
        assert!((torus.spread_cm - 10.0).abs() < 1e-4);
        // Neighbours on a regular octagon of radius 10: side 2 r sin(π/8).
        let side = 2.0 * 10.0 * (PI / 8.0).sin();
        assert!((torus.mean_nnd_cm - side).abs() < 1e-4, "{torus:?}");
        assert!(torus.centroid[0].abs() < 1e-5 && torus.centroid[1].abs() < 1e-5);
        // Clockwise: the same milling magnitude.
        let cw = group_order(&ring(8, 10.0, -FRAC_PI_2)).unwrap();
        assert!((cw.milling - 1.0).abs() < 1e-6);
        // Heading outward (a burst): no polarisation, no rotation.
        let burst = group_order(&ring(8, 10.0, 0.0)).unwrap();
        assert!(
            burst.polarisation < 1e-6 && burst.milling < 1e-6,
            "{burst:?}"
        );
        // All heading +x on a line 3 cm apart: polarised, NND 3, spread (3+0+3)/3 = 2.
        let line: Vec<AgentState> = (0..3)
            .map(|i| AgentState::at(3.0 * i as f32, 0.0, 0.0))
            .collect();
        let p = group_order(&line).unwrap();
        assert!((p.polarisation - 1.0).abs() < 1e-6 && p.milling < 1e-6);
        assert!((p.mean_nnd_cm - 3.0).abs() < 1e-5 && (p.spread_cm - 2.0).abs() < 1e-5);
    }

    #[test]
    fn untracked_fish_are_left_out_and_one_fish_is_no_group() {
        let mut fish = ring(8, 10.0, FRAC_PI_2);
        fish.push(AgentState::at(f32::NAN, f32::NAN, 0.0));
        let g = group_order(&fish).unwrap();
        assert_eq!(g.fish, 8);
        assert!((g.milling - 1.0).abs() < 1e-6);
        assert!(group_order(&fish[..1]).is_none());
        assert!(group_order(&[]).is_none());
        let robot = AgentState::at(0.0, 0.0, 0.0);
        let (d, frac) = robot_to_group(&robot, &fish, 10.5).unwrap();
        assert!(d < 1e-5 && (frac - 1.0).abs() < 1e-6);
        let (_, frac) = robot_to_group(&AgentState::at(10.0, 0.0, 0.0), &fish, 1.0).unwrap();
        assert!((frac - 1.0 / 8.0).abs() < 1e-6);
        assert!(robot_to_group(&robot, &fish[8..], 1.0).is_none());
    }
}
