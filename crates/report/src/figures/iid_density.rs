//! The robot-fish distance (IID) densities, simulation vs reality.

use super::prelude::*;

/// Gaussian smoothing of a histogram into a density (per cm).
pub(super) fn density(hist: &[f64], frames: usize, cfg: &ReportConfig) -> Vec<f64> {
    let bin = f64::from(cfg.iid_bin_cm);
    let sigma = f64::from(cfg.iid_kernel_cm) / bin;
    // Beyond the histogram's length the kernel meets no bin.
    let reach = ((3.0 * sigma).ceil() as isize).min(hist.len() as isize);
    let kernel: Vec<f64> = (-reach..=reach)
        .map(|k| (-0.5 * (k as f64 / sigma).powi(2)).exp())
        .collect();
    let ksum: f64 = kernel.iter().sum();
    let norm = (frames.max(1) as f64) * bin * ksum;
    (0..hist.len() as isize)
        .map(|i| {
            kernel
                .iter()
                .enumerate()
                .filter_map(|(k, w)| {
                    let j = i + k as isize - reach;
                    (j >= 0 && (j as usize) < hist.len()).then(|| w * hist[j as usize])
                })
                .sum::<f64>()
                / norm
        })
        .collect()
}

/// (columns, rows) of a panel grid: one row up to three panels, else two columns.
fn panels(n: usize) -> (usize, usize) {
    let cols = if n <= 3 { n.max(1) } else { 2 };
    (cols, n.div_ceil(cols).max(1))
}

/// Fig. 6: inter-individual distance densities per policy.
pub fn iid_density(d: &StudyData, cfg: &ReportConfig) -> Option<Figure> {
    let pol: Vec<(&String, &crate::data::PolicyTrials)> = d
        .trials
        .iter()
        .filter(|(_, t)| !t.sim.is_empty() || !t.real.is_empty())
        .collect();
    if pol.is_empty() {
        return None;
    }
    let bin = f64::from(cfg.iid_bin_cm);
    let curves = |v: &[crate::data::TrialNumbers]| -> (Vec<Vec<f64>>, Vec<f64>) {
        let per: Vec<Vec<f64>> = v
            .iter()
            .map(|t| density(&t.iid_hist, t.iid_frames, cfg))
            .collect();
        let mut pooled = vec![0.0; v.first().map_or(0, |t| t.iid_hist.len())];
        for t in v {
            for (a, b) in pooled.iter_mut().zip(&t.iid_hist) {
                *a += b;
            }
        }
        let frames = v.iter().map(|t| t.iid_frames).sum();
        (per, density(&pooled, frames, cfg))
    };
    let all: Vec<_> = pol
        .iter()
        .map(|(p, t)| (*p, curves(&t.sim), curves(&t.real)))
        .collect();
    let ymax = all
        .iter()
        .flat_map(|(_, s, r)| s.0.iter().chain(r.0.iter()).flatten().copied())
        .fold(0.0, f64::max);
    let (nc, nr) = panels(all.len());
    let (pw, ph) = (320.0, 200.0);
    let mut svg = Svg::new(
        80.0 + nc as f64 * (pw + 50.0),
        40.0 + nr as f64 * (ph + 80.0),
    );
    let real_name = arm_label(d);
    for (k, (p, s, r)) in all.iter().enumerate() {
        let (ci, ri) = (k % nc, k / nc);
        let ax = Axes::new(
            (
                70.0 + ci as f64 * (pw + 50.0),
                35.0 + ri as f64 * (ph + 80.0),
                pw,
                ph,
            ),
            (0.0, f64::from(cfg.iid_max_cm)),
            (0.0, ymax * 1.05),
        );
        ax.draw(
            &mut svg,
            "robot-fish distance (cm)",
            if ci == 0 { "density (1/cm)" } else { "" },
            &format!("π_{p}"),
            None,
        );
        for ((per, pooled), look) in [(s, SIM), (r, REAL)] {
            for c in per {
                let pts: Vec<(f64, f64)> = c
                    .iter()
                    .enumerate()
                    .map(|(i, y)| ax.p((i as f64 + 0.5) * bin, *y))
                    .collect();
                svg.polyline(&pts, look.color, 0.8, None, 0.45);
            }
            if !per.is_empty() {
                let pts: Vec<(f64, f64)> = pooled
                    .iter()
                    .enumerate()
                    .map(|(i, y)| ax.p((i as f64 + 0.5) * bin, *y))
                    .collect();
                svg.polyline(&pts, "#ffffff", 4.0, None, 0.9);
                svg.polyline(&pts, look.color, 2.4, Some("2 3"), 1.0);
            }
        }
        if k == 0 {
            legend(
                &mut svg,
                ax.x + ax.w - 165.0,
                ax.y + 6.0,
                &[
                    (
                        Series { dash: None, ..SIM },
                        "simulation, one trial".into(),
                        Key::Line,
                    ),
                    (
                        Series { dash: None, ..REAL },
                        format!("{real_name}, one trial"),
                        Key::Line,
                    ),
                    (
                        Series {
                            dash: Some("2 3"),
                            ..SIM
                        },
                        "simulation, pooled".into(),
                        Key::Line,
                    ),
                    (
                        Series {
                            dash: Some("2 3"),
                            ..REAL
                        },
                        format!("{real_name}, pooled"),
                        Key::Line,
                    ),
                ],
            );
        }
    }
    Some(Figure {
        name: "iid_density",
        title: "Robot-fish distance".into(),
        caption: format!(
            "Distribution of the distance between robot and fish during control, one panel per \
             policy. Thin lines: one trial each (simulation dark blue, {real_name} light orange); \
             dotted thick lines: all trials of the arm pooled. Densities are {} cm histograms \
             smoothed with a Gaussian of s.d. {} cm. Where the simulated fish follows the robot \
             more closely than the real fish, the blue mass sits left of the orange.",
            cfg.iid_bin_cm, cfg.iid_kernel_cm
        ),
        svg: svg.finish(),
    })
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn smoothing_preserves_the_mass_of_a_histogram() {
        let cfg = ReportConfig::default();
        let mut h = vec![0.0; 100];
        h[50] = 30.0;
        h[20] = 10.0;
        let dens = density(&h, 40, &cfg);
        let mass: f64 = dens.iter().sum::<f64>() * f64::from(cfg.iid_bin_cm);
        assert!((mass - 1.0).abs() < 1e-9, "{mass}");
        assert!(dens[50] > dens[45] && dens[45] > dens[40]);
    }
}
