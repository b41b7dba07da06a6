//! How much does the shipped M_ConvNet's motion depend on its partner, by the partner's
//! distance? The evidence for the support model's partner range (docs/validation.md,
//! "Probes that seek what the data lacks").
//!
//! ```sh
//! cargo run --release -p fishprobe-models --example partner_influence -- [POSES]
//! ```
//!
//! For each distance, POSES fish poses (default 400; master seed 0, label
//! "partner-influence") are drawn with the fish at least that distance from every wall less
//! 2 cm, so that the partner fits in the tank in any direction. For each pose the partner is
//! put at 8 bearings (every 45°), heading as the fish does, and the network's (v, ω)
//! distribution is computed. Printed per distance:
//! - the generalised Jensen-Shannon divergence of the 8 distributions (nats; 0: the partner's
//!   bearing does not matter), averaged over poses;
//! - the turn toward the partner: half the difference of the mean turn rate with the partner
//!   90° to the left and 90° to the right (rad/s; positive: toward it);
//! - the speed-up behind: the mean speed with the partner behind less with it ahead (cm/s).

use fishprobe_models::convnet::{encode_view, ConvNet, ConvNetWorkspace};
use fishprobe_nn::dist::softmax_rows;
use fishprobe_sim::{stream, AgentState, Tank, TankParams};
use rand::RngExt;
use std::f32::consts::PI;

fn main() -> Result<(), Box<dyn std::error::Error>> {
    let poses: usize = std::env::args().nth(1).map_or(Ok(400), |s| s.parse())?;
    let net = ConvNet::shipped()?;
    let arch = net.arch.clone();
    let tank = Tank::new(&TankParams::default());
    let half = TankParams::default().half_size_cm;
    let cells = arch.cells();
    let len = arch.view_len();
    let mut ws = ConvNetWorkspace::default();
    let mut x = vec![0.0f32; 8 * len];
    let mut p = vec![0.0f32; 8 * cells];
    let cell_mean = |p: &[f32], f: &dyn Fn(usize) -> f32| -> f32 {
        p.iter().enumerate().map(|(c, &q)| q * f(c)).sum()
    };
    let w_of = |c: usize| {
        let (_, (w0, dw)) = arch.cell_bounds(c);
        w0 + dw / 2.0
    };
    let v_of = |c: usize| {
        let ((v0, dv), _) = arch.cell_bounds(c);
        v0 + dv / 2.0
    };
    let entropy = |p: &[f32]| -> f32 { p.iter().filter(|&&q| q > 0.0).map(|&q| -q * q.ln()).sum() };
    println!("| partner distance (cm) | JS divergence over bearings (nats) | turn toward it (rad/s) | speed-up with it behind (cm/s) |");
    println!("|---|---|---|---|");
    for d in [
        2.0f32, 4.0, 6.0, 8.0, 10.0, 12.0, 15.0, 20.0, 25.0, 30.0, 40.0,
    ] {
        let mut rng = stream(0, "partner-influence", d.to_bits() as u64);
        let box_ = (half - d - 2.0).max(2.0);
        let (mut js, mut turn, mut speed) = (0.0f64, 0.0f64, 0.0f64);
        for _ in 0..poses {
            let me = AgentState::at(
                rng.random_range(-box_..box_),
                rng.random_range(-box_..box_),
                rng.random_range(-PI..PI),
            );
            for k in 0..8 {
                let b = me.heading + k as f32 * PI / 4.0;
                let o = AgentState::at(me.x + d * b.cos(), me.y + d * b.sin(), me.heading);
                encode_view(&arch, &tank, &me, &[o], &mut x[k * len..(k + 1) * len]);
            }
            let logits = net.forward(&x, 8, &mut ws);
            softmax_rows(logits, &mut p, cells);
            let rows: Vec<&[f32]> = p.chunks_exact(cells).collect();
            let mix: Vec<f32> = (0..cells)
                .map(|c| rows.iter().map(|r| r[c]).sum::<f32>() / 8.0)
                .collect();
            let mean_h = rows.iter().map(|r| entropy(r)).sum::<f32>() / 8.0;
            js += f64::from(entropy(&mix) - mean_h);
            // Bearing k: 0 ahead, 2 left (+90°), 4 behind, 6 right.
            turn += f64::from(cell_mean(rows[2], &w_of) - cell_mean(rows[6], &w_of)) / 2.0;
            speed += f64::from(cell_mean(rows[4], &v_of) - cell_mean(rows[0], &v_of));
        }
        let n = poses as f64;
        println!(
            "| {d:.0} | {:.3} | {:.2} | {:.2} |",
            js / n,
            turn / n,
            speed / n
        );
    }
    Ok(())
}
