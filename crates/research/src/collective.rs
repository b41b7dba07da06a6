//! Groups in open water (`fishprobe collective`): Couzin's phase picture for free groups of
//! M_Zone fish, the validation that the group version of the model shows his four collective
//! states, and for M_Force the polarisation over its alignment strength (Klamser et al. 2021).

use crate::{ResearchError, Result};
use fishprobe_models::collective::{
    couzin_zone, run as run_group, CollectiveParams, CollectiveState, PhaseGrid, Swimmer,
    COUZIN_TURN_RATE_RAD_S,
};
use fishprobe_models::{ForceParams, ZoneParams};
use fishprobe_sim::params::check::shown;
use rayon::prelude::*;
use std::fmt::Write as _;
use std::path::PathBuf;

/// The model whose groups are swept.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum GroupModel {
    /// M_Zone over Couzin's orientation and attraction widths.
    Zone,
    /// M_Force over its alignment strength.
    Force,
}

/// What `fishprobe collective` sweeps, and where its output goes.
#[derive(Debug, Clone, PartialEq)]
pub struct CollectiveSettings {
    /// The model.
    pub model: GroupModel,
    /// Fish per group.
    pub fish: u32,
    /// Seeds per cell.
    pub seeds: u64,
    /// Simulated seconds per run (the first half is left out as burn-in).
    pub seconds: f32,
    // The sweeps are unset by default, so that a value of the other model's sweep is refused
    // instead of ignored; their defaults are the constants below.
    /// M_Zone: orientation widths Δr_o (cm), comma-separated [default: 0,1,2,4,8,12,16,20,30]
    pub orientation: Option<Vec<f32>>,
    /// M_Zone: attraction widths Δr_a (cm), comma-separated [default: 4,8,14,20,28,40]
    pub attraction: Option<Vec<f32>>,
    /// M_Zone: maximum turning rate in rad/s, or `couzin` (40°/s) or `paper` (10 rad/s)
    /// [default: couzin]
    pub turn_rate: Option<String>,
    /// M_Force: alignment strengths μ_alg, comma-separated [default: 0,0.05,0.1,0.2,0.3,0.6]
    pub alignment: Option<Vec<f32>>,
    /// Master seed.
    pub seed: u64,
    /// Write the picture (collective-phase.svg/.png) and the numbers (collective.json) here.
    pub out: Option<PathBuf>,
    /// Print JSON instead of a table.
    pub json: bool,
}

impl Default for CollectiveSettings {
    /// The command's defaults (`fishprobe collective` without flags).
    fn default() -> Self {
        Self {
            model: GroupModel::Zone,
            fish: 50,
            seeds: 3,
            seconds: 150.0,
            orientation: None,
            attraction: None,
            turn_rate: None,
            alignment: None,
            seed: 0,
            out: None,
            json: false,
        }
    }
}

/// Most runs one invocation may ask for (cells x seeds).
const MAX_RUNS: usize = 10_000;

/// M_Zone's default orientation widths Δr_o (cm): Couzin et al. 2002's range, from none to
/// wider than the attraction zones.
pub const ORIENTATION_CM: &[f32] = &[0.0, 1.0, 2.0, 4.0, 8.0, 12.0, 16.0, 20.0, 30.0];
/// M_Zone's default attraction widths Δr_a (cm).
pub const ATTRACTION_CM: &[f32] = &[4.0, 8.0, 14.0, 20.0, 28.0, 40.0];
/// M_Force's default alignment strengths μ_alg (per frame), around the published 0.1.
pub const ALIGNMENT: &[f32] = &[0.0, 0.05, 0.1, 0.2, 0.3, 0.6];

/// The sweep's values: the flags given, else the defaults.
struct Sweep {
    orientation_cm: Vec<f32>,
    attraction_cm: Vec<f32>,
    alignment: Vec<f32>,
}

impl Sweep {
    /// Refuses a flag of the other model's sweep, which would otherwise be ignored
    /// (`collective --alignment 0.5` without `--model force` swept M_Zone).
    fn of(a: &CollectiveSettings) -> Result<Self> {
        let zone_flags = [
            ("orientation", a.orientation.is_some()),
            ("attraction", a.attraction.is_some()),
            ("turn_rate", a.turn_rate.is_some()),
        ];
        match a.model {
            GroupModel::Zone if a.alignment.is_some() => {
                return Err(ResearchError::Refused(
                    "alignment sweeps M_Force: set model to force (this run sweeps M_Zone)"
                        .to_string(),
                ))
            }
            GroupModel::Force => {
                if let Some((flag, _)) = zone_flags.iter().find(|(_, given)| *given) {
                    return Err(ResearchError::Refused(format!(
                        "{flag} sweeps M_Zone: set model to zone (this run sweeps M_Force)"
                    )));
                }
            }
            GroupModel::Zone => {}
        }
        let or = |v: &Option<Vec<f32>>, d: &[f32]| v.clone().unwrap_or_else(|| d.to_vec());
        Ok(Self {
            orientation_cm: or(&a.orientation, ORIENTATION_CM),
            attraction_cm: or(&a.attraction, ATTRACTION_CM),
            alignment: or(&a.alignment, ALIGNMENT),
        })
    }
}

/// Runs the sweep, writes the picture and numbers into `--out` when given, and returns the
/// table (or JSON) to show. `progress(done, total)` is called after each run, from any thread.
pub fn run(a: &CollectiveSettings, progress: &(dyn Fn(u64, u64) + Sync)) -> Result<String> {
    if a.seeds == 0 || a.seeds > 100 {
        return Err(ResearchError::Refused(format!(
            "seeds must lie in [1, 100], got {}",
            a.seeds
        )));
    }
    let p = CollectiveParams {
        fish: a.fish,
        seconds: a.seconds,
        burn_in_s: a.seconds / 2.0,
        ..CollectiveParams::default()
    };
    p.validate("")
        .map_err(ResearchError::msg)
        .map_err(|e| ResearchError::within("fish, seconds", e))?;
    let sweep = Sweep::of(a)?;
    let turn = match a.turn_rate.as_deref().unwrap_or("couzin") {
        "couzin" => COUZIN_TURN_RATE_RAD_S,
        "paper" => ZoneParams::default().max_turn_rate_rad_s,
        x => x
            .parse::<f32>()
            .ok()
            .filter(|v| v.is_finite() && *v > 0.0)
            .ok_or_else(|| {
                ResearchError::Refused(format!(
                    "turn_rate must be `couzin`, `paper` or a positive number, got `{x}`"
                ))
            })?,
    };
    let swimmers = swimmers(a, &sweep, turn)?;
    let runs = swimmers.len() * a.seeds as usize;
    if swimmers.is_empty() || runs > MAX_RUNS {
        return Err(ResearchError::Refused(format!(
            "the sweep has {runs} runs; it must have 1 to {MAX_RUNS}"
        )));
    }
    let done = std::sync::atomic::AtomicU64::new(0);
    let jobs: Vec<(usize, u64)> = (0..swimmers.len())
        .flat_map(|c| (0..a.seeds).map(move |s| (c, s)))
        .collect();
    let results: Vec<CollectiveState> = jobs
        .par_iter()
        .map(|&(c, s)| {
            let r = run_group(&swimmers[c].1, &p, a.seed.wrapping_add(s));
            let d = done.fetch_add(1, std::sync::atomic::Ordering::Relaxed) + 1;
            progress(d, runs as u64);
            r.map_err(ResearchError::msg)
        })
        .collect::<Result<_>>()?;
    let cells: Vec<Vec<CollectiveState>> = results
        .chunks(a.seeds as usize)
        .map(<[CollectiveState]>::to_vec)
        .collect();
    match a.model {
        GroupModel::Zone => zone_output(a, &sweep, &p, turn, cells),
        GroupModel::Force => force_output(a, &swimmers, &cells),
    }
}

/// The swimmers of the sweep, each with its parameter values: M_Zone over the grid of
/// orientation and attraction widths (turning at `turn` rad/s), or M_Force over the alignments.
fn swimmers(a: &CollectiveSettings, sweep: &Sweep, turn: f32) -> Result<Vec<(Vec<f32>, Swimmer)>> {
    Ok(match a.model {
        GroupModel::Zone => {
            let mut v = Vec::new();
            for &ra in &sweep.attraction_cm {
                for &ro in &sweep.orientation_cm {
                    let zp = ZoneParams {
                        max_turn_rate_rad_s: turn,
                        ..couzin_zone(ro, ra)
                    };
                    let s = Swimmer::zone(zp).map_err(ResearchError::msg).map_err(|e| {
                        ResearchError::within(
                            format!("Δr_o = {}, Δr_a = {}", shown(ro), shown(ra)),
                            e,
                        )
                    })?;
                    v.push((vec![ro, ra], s));
                }
            }
            v
        }
        GroupModel::Force => sweep
            .alignment
            .iter()
            .map(|&al| {
                let s = Swimmer::force(ForceParams {
                    alignment: al,
                    ..ForceParams::default()
                })
                .map_err(ResearchError::msg)
                .map_err(|e| ResearchError::within(format!("alignment {al}"), e))?;
                Ok((vec![al], s))
            })
            .collect::<Result<_>>()?,
    })
}

/// M_Zone's phase grid: the picture and numbers into `--out`, the table (or JSON) printed.
fn zone_output(
    a: &CollectiveSettings,
    sweep: &Sweep,
    p: &CollectiveParams,
    turn: f32,
    cells: Vec<Vec<CollectiveState>>,
) -> Result<String> {
    let grid = PhaseGrid {
        orientation_cm: sweep.orientation_cm.clone(),
        attraction_cm: sweep.attraction_cm.clone(),
        cells,
        repulsion_cm: ZoneParams::default().repulsion_zone_cm,
        fish: a.fish,
        max_turn_rate_rad_s: turn,
        cohesive_share: p.cohesive_share,
    };
    if let Some(dir) = &a.out {
        std::fs::create_dir_all(dir)
            .map_err(|e| ResearchError::within(format!("creating {}", dir.display()), e))?;
        let fig = fishprobe_report::figures::collective_phase(&grid);
        fishprobe_report::write_figure(&fig, dir, 2.0).map_err(|e| {
            ResearchError::within(format!("writing the picture into {}", dir.display()), e)
        })?;
        fishprobe_io::write_atomically(
            &dir.join("collective.json"),
            serde_json::to_string_pretty(&grid)?.as_bytes(),
        )
        .map_err(|e| {
            ResearchError::within(
                format!("writing {}", dir.join("collective.json").display()),
                e,
            )
        })?;
    }
    if a.json {
        return Ok(serde_json::to_string_pretty(&grid)? + "\n");
    }
    let mut t = format!(
        "M_Zone, {} fish in open water, turning rate {:.2} rad/s, {} seeds per cell \
         (mean polarisation / milling / share in the largest cluster, state)\n\
         {:>8} {:>8}  {:>6} {:>6} {:>8}  state\n",
        a.fish, grid.max_turn_rate_rad_s, a.seeds, "Δr_o cm", "Δr_a cm", "P", "M", "cluster"
    );
    for (ai, ra) in grid.attraction_cm.iter().enumerate() {
        for (oi, ro) in grid.orientation_cm.iter().enumerate() {
            let m = grid.mean(ai, oi);
            let _ = writeln!(
                t,
                "{ro:>8} {ra:>8}  {:>6.2} {:>6.2} {:>8.2}  {}",
                m.polarisation,
                m.milling,
                m.cohesion,
                grid.label(ai, oi)
            );
        }
    }
    if let Some(dir) = &a.out {
        let _ = writeln!(t, "picture and numbers in {}", dir.display());
    }
    Ok(t)
}

/// M_Force's order over alignment: the numbers into `--out`, the table (or JSON) printed.
fn force_output(
    a: &CollectiveSettings,
    swimmers: &[(Vec<f32>, Swimmer)],
    cells: &[Vec<CollectiveState>],
) -> Result<String> {
    let rows: Vec<serde_json::Value> = swimmers
        .iter()
        .zip(cells)
        .map(|((k, _), c)| serde_json::json!({"alignment": k[0], "runs": c}))
        .collect();
    if let Some(dir) = &a.out {
        std::fs::create_dir_all(dir)
            .map_err(|e| ResearchError::within(format!("creating {}", dir.display()), e))?;
        fishprobe_io::write_atomically(
            &dir.join("collective-force.json"),
            serde_json::to_string_pretty(&rows)?.as_bytes(),
        )?;
    }
    if a.json {
        return Ok(serde_json::to_string_pretty(&rows)? + "\n");
    }
    let mut t = format!(
        "M_Force, {} fish in open water, {} seeds (mean polarisation / milling / \
         nearest-neighbour distance / share in the largest cluster)\n\
         {:>9}  {:>6} {:>6} {:>8} {:>8}\n",
        a.fish, a.seeds, "μ_alg", "P", "M", "NND cm", "cluster"
    );
    for ((k, _), c) in swimmers.iter().zip(cells) {
        let n = c.len() as f32;
        let f = |g: fn(&CollectiveState) -> f32| c.iter().map(g).sum::<f32>() / n;
        let _ = writeln!(
            t,
            "{:>9}  {:>6.2} {:>6.2} {:>8.1} {:>8.2}",
            k[0],
            f(|s| s.polarisation),
            f(|s| s.milling),
            f(|s| s.mean_nnd_cm),
            f(|s| s.cohesion)
        );
    }
    Ok(t)
}
