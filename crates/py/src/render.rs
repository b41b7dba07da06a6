//! A top-down picture of the tank for Gymnasium's `rgb_array` render mode: the tank floor,
//! the active goal, the robot (red) and the fish (blue), each with a line along its heading.

use fishprobe_sim::{AgentState, TankEnv};

const FLOOR: [u8; 3] = [236, 240, 244];
const WALL: [u8; 3] = [60, 60, 60];
const GOAL: [u8; 3] = [120, 200, 120];
const ROBOT: [u8; 3] = [214, 39, 40];
const FISH: [u8; 3] = [31, 119, 180];

/// Body radius drawn for an agent (cm): about a guppy's half length.
const BODY_CM: f32 = 2.0;

struct Canvas {
    size: usize,
    px: Vec<u8>,
    /// Pixels per cm, and the half side (cm) of the drawn area.
    scale: f32,
    half: f32,
}

impl Canvas {
    fn to_px(&self, x: f32, y: f32) -> (f32, f32) {
        // y up in the tank, down in the image.
        ((x + self.half) * self.scale, (self.half - y) * self.scale)
    }

    fn put(&mut self, i: isize, j: isize, c: [u8; 3]) {
        if i < 0 || j < 0 || i as usize >= self.size || j as usize >= self.size {
            return;
        }
        let at = (j as usize * self.size + i as usize) * 3;
        self.px[at..at + 3].copy_from_slice(&c);
    }

    fn disc(&mut self, x: f32, y: f32, r_cm: f32, c: [u8; 3]) {
        let (cx, cy) = self.to_px(x, y);
        let r = (r_cm * self.scale).max(1.5);
        let (lo_i, hi_i) = ((cx - r).floor() as isize, (cx + r).ceil() as isize);
        let (lo_j, hi_j) = ((cy - r).floor() as isize, (cy + r).ceil() as isize);
        for j in lo_j..=hi_j {
            for i in lo_i..=hi_i {
                let (dx, dy) = (i as f32 + 0.5 - cx, j as f32 + 0.5 - cy);
                if dx * dx + dy * dy <= r * r {
                    self.put(i, j, c);
                }
            }
        }
    }

    fn line(&mut self, a: (f32, f32), b: (f32, f32), c: [u8; 3]) {
        let (pa, pb) = (self.to_px(a.0, a.1), self.to_px(b.0, b.1));
        let n = ((pb.0 - pa.0).abs().max((pb.1 - pa.1).abs()).ceil() as usize).max(1);
        for k in 0..=n {
            let t = k as f32 / n as f32;
            let (x, y) = (pa.0 + t * (pb.0 - pa.0), pa.1 + t * (pb.1 - pa.1));
            self.put(x as isize, y as isize, c);
        }
    }

    fn agent(&mut self, a: &AgentState, c: [u8; 3]) {
        if !(a.x.is_finite() && a.y.is_finite() && a.heading.is_finite()) {
            return;
        }
        self.disc(a.x, a.y, BODY_CM, c);
        let (s, co) = a.heading.sin_cos();
        let tip = (a.x + 2.5 * BODY_CM * co, a.y + 2.5 * BODY_CM * s);
        self.line((a.x, a.y), tip, c);
    }
}

/// The picture of `env`, `size` x `size` RGB pixels, row-major.
pub fn tank(env: &TankEnv, size: usize) -> Vec<u8> {
    let half = env.tank().half;
    let mut c = Canvas {
        size,
        px: FLOOR
            .iter()
            .copied()
            .cycle()
            .take(size * size * 3)
            .collect(),
        scale: size as f32 / (2.0 * half),
        half,
    };
    let edge = (size as f32 / 200.0).ceil().max(1.0) as usize;
    for j in 0..size {
        for i in 0..size {
            if i < edge || j < edge || i >= size - edge || j >= size - edge {
                c.put(i as isize, j as isize, WALL);
            }
        }
    }
    let [gx, gy] = env.active_goal();
    c.disc(gx, gy, env.config().task.goal_radius_cm, GOAL);
    for f in env.fish() {
        c.agent(f, FISH);
    }
    c.agent(&env.robot().state, ROBOT);
    c.px
}
