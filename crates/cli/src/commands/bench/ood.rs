//! `fishprobe bench ood`: the cost of scoring a view against the support or the ensemble's
//! disagreement, per view, at the batch sizes the trainer uses.

use super::{emit, machine};
use anyhow::Result;
use fishprobe_sim::params::check::shown;
use fishprobe_sim::stream;
use rand::RngExt;
use serde::Serialize;
use std::f32::consts::PI;
use std::fmt::Write;
use std::time::Instant;

/// One row of `bench ood`.
#[derive(Debug, Serialize)]
struct OodBench {
    score: String,
    batch: usize,
    us_per_view: f64,
}

pub(super) fn bench_ood(json: bool, members: usize, seconds: f64) -> Result<()> {
    use fishprobe_models::disagreement::{Disagreement, DisagreementFile, MAX_MEMBERS};
    use fishprobe_models::{ConvNet, ConvNetFish};
    use fishprobe_sim::{AgentState, FishModel, FishView, InputSupport, Tank};
    if !(2..=MAX_MEMBERS).contains(&members) {
        anyhow::bail!("--members must lie in [2, {MAX_MEMBERS}], got {members}");
    }
    if !(seconds.is_finite() && (0.1..=600.0).contains(&seconds)) {
        anyhow::bail!("--seconds must lie in [0.1, 600], got {}", shown(seconds));
    }
    // The batch one core scores in training: the trainer's 64 environments split across the
    // cores (at least 16 fish per part, as the vector environment splits them).
    let cores = std::thread::available_parallelism().map_or(1, |n| n.get());
    let batch = (64 / cores).max(16);
    let mut rng = stream(0, "bench-ood", 0);
    let tank = Tank::default();
    let mut pose = || {
        AgentState::at(
            rng.random_range(-45.0..45.0),
            rng.random_range(-45.0..45.0),
            rng.random_range(-PI..PI),
        )
    };
    let views: Vec<FishView> = (0..4096)
        .map(|_| FishView::build(0, &[pose()], &[pose()], tank, 0.04, 0.0))
        .collect();
    let shipped = ConvNet::shipped()?;
    let arch = shipped.arch.clone();
    let mut nets = vec![shipped.clone()];
    let mut net_rng = stream(0, "bench-ood-member", 0);
    nets.extend((1..members).map(|_| ConvNet::new(arch.clone(), &mut net_rng)));
    let len = arch.view_len();
    let mut encoded = vec![0.0; views.len() * len];
    for (v, row) in views.iter().zip(encoded.chunks_exact_mut(len)) {
        fishprobe_models::convnet::encode_view(&arch, &v.tank, &v.me, v.others(), row);
    }
    let refs = (1..members)
        .map(|i| fishprobe_models::disagreement::MemberRef {
            file: format!("member-{i}"),
            sha256: String::new(),
        })
        .collect();
    let file = DisagreementFile::new(
        "ConvNet".into(),
        String::new(),
        refs,
        serde_json::Value::Null,
    );
    let ensemble = Disagreement::fit(nets, file, &encoded, 256, &mut net_rng)?;
    let support = fishprobe_models::support::shipped_convnet()?;
    let fish = ConvNetFish::from_net(shipped);
    let mut out = vec![0.0; batch * arch.cells()];
    let mut measure = |name: &str, batch: usize, f: &mut dyn FnMut(&[FishView], &mut [f32])| {
        let mut done = 0usize;
        let mut pass = |done: &mut usize| {
            let at = (*done * batch) % (views.len() - batch);
            f(&views[at..at + batch], &mut out);
            *done += 1;
        };
        let warm = Instant::now();
        while warm.elapsed().as_secs_f64() < seconds * 0.1 {
            pass(&mut done);
        }
        done = 0;
        let start = Instant::now();
        while start.elapsed().as_secs_f64() < seconds {
            pass(&mut done);
        }
        OodBench {
            score: name.into(),
            batch,
            us_per_view: start.elapsed().as_secs_f64() * 1e6 / (done * batch) as f64,
        }
    };
    let rows = vec![
        measure("support (kNN, shipped)", 1, &mut |v, o| {
            support.score_batch(v, o)
        }),
        measure(&format!("disagreement of {members}"), 1, &mut |v, o| {
            ensemble.score_batch(v, o)
        }),
        measure(&format!("disagreement of {members}"), batch, &mut |v, o| {
            ensemble.score_batch(v, o)
        }),
        measure("the fish's inference (M_ConvNet)", batch, &mut |v, o| {
            fish.infer_batch(v, o)
        }),
    ];
    let m = machine();
    let text = if json {
        serde_json::to_string_pretty(&serde_json::json!({
            "bench": "ood", "machine": m, "members": members, "rows": rows,
            "command": format!("fishprobe bench ood --members {members} --json"),
        }))? + "\n"
    } else {
        let mut t = format!(
            "fishprobe bench ood — one core of {} ({}, {} {}); 4,096 random fish-robot views\n{:<36} {:>6} {:>12}\n",
            m.cores, m.cpu, m.os, m.arch, "score", "batch", "µs per view"
        );
        for r in &rows {
            writeln!(t, "{:<36} {:>6} {:>12.1}", r.score, r.batch, r.us_per_view)?;
        }
        t
    };
    emit(&text)
}
