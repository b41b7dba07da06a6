//! Couzin's phase picture for a free group of model fish: polarisation and milling
//! over the orientation and attraction widths, each cell marked with its collective state.

use super::prelude::*;
use fishprobe_models::collective::{CollectiveState, PhaseGrid};

/// One order parameter of a state.
type Measure = fn(&CollectiveState) -> f32;

/// The phase picture of `grid`: two heatmaps (polarisation, milling) over Δr_o × Δr_a.
pub fn collective_phase(grid: &PhaseGrid) -> Figure {
    let (cols, rows) = (grid.orientation_cm.len(), grid.attraction_cm.len());
    let cell = (300.0 / cols.max(1) as f64).min(48.0);
    let (pw, ph) = (cell * cols as f64, cell * rows as f64);
    let (left, top, gap) = (70.0, 60.0, 90.0);
    let mut svg = Svg::new(left + 2.0 * pw + gap + 30.0, top + ph + 110.0);
    let panels: [(&str, Measure); 2] = [
        ("polarisation", |c| c.polarisation),
        ("milling (group rotation)", |c| c.milling),
    ];
    for (k, (name, value)) in panels.iter().enumerate() {
        let x0 = left + k as f64 * (pw + gap);
        svg.text(
            x0 + pw / 2.0,
            top - 14.0,
            name,
            TextStyle::new(13.0, Anchor::Middle).bold(),
        );
        for a in 0..rows {
            for o in 0..cols {
                let t = f64::from(value(&grid.mean(a, o))).clamp(0.0, 1.0);
                // Largest attraction width at the top.
                let (x, y) = (x0 + o as f64 * cell, top + (rows - 1 - a) as f64 * cell);
                svg.rect(x, y, cell, cell, &viridis(t), Some(("#ffffff", 0.5)));
                let mark = match grid.label(a, o) {
                    "torus" => "T",
                    "highly parallel" => "H",
                    "dynamic parallel" => "D",
                    "fragmented" => "F",
                    _ => "S",
                };
                svg.text(
                    x + cell / 2.0,
                    y + cell / 2.0 + 4.0,
                    mark,
                    TextStyle::new(11.0, Anchor::Middle).color(ink_on(t)),
                );
            }
        }
        for (o, w) in grid.orientation_cm.iter().enumerate() {
            svg.text(
                x0 + (o as f64 + 0.5) * cell,
                top + ph + 14.0,
                &fmt(f64::from(*w), 0),
                TextStyle::new(10.0, Anchor::Middle),
            );
        }
        svg.text(
            x0 + pw / 2.0,
            top + ph + 32.0,
            "orientation width Δr_o (cm)",
            TextStyle::new(11.0, Anchor::Middle),
        );
        for (a, w) in grid.attraction_cm.iter().enumerate() {
            svg.text(
                x0 - 6.0,
                top + (rows - 1 - a) as f64 * cell + cell / 2.0 + 4.0,
                &fmt(f64::from(*w), 0),
                TextStyle::new(10.0, Anchor::End),
            );
        }
        svg.text(
            x0 - 38.0,
            top + ph / 2.0,
            "attraction width Δr_a (cm)",
            TextStyle::new(11.0, Anchor::Middle).rotated(-90.0),
        );
    }
    colour_bar(&mut svg, (left, top + ph + 50.0), "0", "1");
    svg.text(
        left + 230.0,
        top + ph + 60.0,
        "S swarm · T torus · D dynamic parallel · H highly parallel · F fell apart",
        TextStyle::new(11.0, Anchor::Start),
    );
    let seeds = grid.cells.first().map_or(0, Vec::len);
    Figure {
        name: "collective-phase",
        title: "Collective states of M_Zone groups (Couzin et al. 2002, Fig. 2)".into(),
        caption: format!(
            "{} fish in open water, repulsion radius {} cm, maximum turning rate {:.2} rad/s; \
             each cell the mean over {seeds} seeds of the order parameters after the burn-in, \
             marked with the most frequent state (F: the largest cluster held less than {:.0} % \
             of the fish).",
            grid.fish,
            fmt(f64::from(grid.repulsion_cm), 1),
            grid.max_turn_rate_rad_s,
            100.0 * grid.cohesive_share
        ),
        svg: svg.finish(),
    }
}
