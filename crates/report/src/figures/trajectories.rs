//! Example trajectories of robot and fish.

use super::prelude::*;

fn track_panel(svg: &mut Svg, ax: &Axes, t: &Track, look: Series, title: &str) {
    tank(svg, ax);
    let p = |v: &[f32; 2]| ax.p(f64::from(v[0]), f64::from(v[1]));
    let s = ax.w / 100.0;
    for g in &t.goals {
        svg.circle(
            p(g),
            f64::from(t.goal_radius_cm) * s,
            Some("#b9e3d3"),
            "#009E73",
            1.5,
        );
    }
    let robot: Vec<(f64, f64)> = t.robot.iter().map(p).collect();
    svg.polyline(&robot, "#000000", 1.0, None, 0.55);
    // A group: every fish, the first drawn as a pair's fish, the others thinner and lighter.
    for (k, f) in t.fish.iter().enumerate() {
        let fish: Vec<(f64, f64)> = f.iter().map(p).collect();
        let (width, opacity) = if k == 0 { (1.3, 0.9) } else { (0.9, 0.55) };
        svg.polyline(&fish, look.color, width, look.dash, opacity);
    }
    for r in &t.reached {
        svg.circle(p(r), 4.0, Some("#ffffff"), "#D55E00", 2.0);
    }
    svg.text(
        ax.x + ax.w / 2.0,
        ax.y - 8.0,
        title,
        TextStyle::new(12.0, Anchor::Middle).bold(),
    );
}

/// Example trajectories, one sim and one real per policy.
pub fn trajectories(d: &StudyData, cfg: &ReportConfig) -> Option<Figure> {
    let rows: Vec<(&String, &crate::data::PolicyTrials)> = d
        .trials
        .iter()
        .filter(|(_, t)| t.sim_track.is_some() || t.real_track.is_some())
        .collect();
    if rows.is_empty() {
        return None;
    }
    let side = 220.0;
    let n = rows.len() as f64;
    // A reality row only when some policy has a reality-arm trial.
    let arms = if d.arm.is_some() { 2 } else { 1 };
    let mut svg = Svg::new(
        40.0 + n * (side + 30.0),
        40.0 + arms as f64 * (side + 50.0) + 20.0,
    );
    let real_name = arm_label(d);
    let mut files = Vec::new();
    for (i, (p, t)) in rows.iter().enumerate() {
        for (j, (tr, look, arm)) in [(&t.sim_track, SIM, "sim"), (&t.real_track, REAL, real_name)]
            .into_iter()
            .take(arms)
            .enumerate()
        {
            let ax = Axes::new(
                (
                    30.0 + i as f64 * (side + 30.0),
                    40.0 + j as f64 * (side + 50.0),
                    side,
                    side,
                ),
                (-50.0, 50.0),
                (-50.0, 50.0),
            );
            match tr {
                Some(tr) => {
                    track_panel(
                        &mut svg,
                        &ax,
                        tr,
                        look,
                        &format!(
                            "π_{p}, {arm}: {} goal{}",
                            tr.reached.len(),
                            if tr.reached.len() == 1 { "" } else { "s" }
                        ),
                    );
                    files.push(format!(
                        "π_{p} {arm}: {}",
                        tr.path
                            .file_name()
                            .map(|n| n.to_string_lossy().into_owned())
                            .unwrap_or_default()
                    ));
                }
                None => {
                    svg.rect(ax.x, ax.y, side, side, "#f2f2f2", None);
                    svg.text(
                        ax.x + side / 2.0,
                        ax.y + side / 2.0,
                        &format!("no {arm} trial"),
                        TextStyle::new(11.0, Anchor::Middle),
                    );
                }
            }
        }
    }
    let ly = 40.0 + arms as f64 * (side + 50.0) - 5.0;
    svg.line((40.0, ly), (62.0, ly), "#000000", 1.5, None);
    svg.text(66.0, ly + 4.0, "robot", TextStyle::new(11.0, Anchor::Start));
    svg.line((120.0, ly), (142.0, ly), SIM.color, 1.5, None);
    svg.line((142.0, ly), (164.0, ly), REAL.color, 1.5, REAL.dash);
    svg.text(
        168.0,
        ly + 4.0,
        "fish (sim / reality)",
        TextStyle::new(11.0, Anchor::Start),
    );
    svg.circle((300.0, ly), 6.0, Some("#b9e3d3"), "#009E73", 1.5);
    svg.text(310.0, ly + 4.0, "goal", TextStyle::new(11.0, Anchor::Start));
    svg.circle((360.0, ly), 4.0, Some("#ffffff"), "#D55E00", 2.0);
    svg.text(
        368.0,
        ly + 4.0,
        "goal reached",
        TextStyle::new(11.0, Anchor::Start),
    );
    Some(Figure {
        name: "trajectories",
        title: "Example trajectories".into(),
        caption: format!(
            "Top view of the 100 × 100 cm tank during the first {} s of control of one trial per \
             policy (columns) and arm (rows: simulation, reality), the first file of each \
             condition ({}). Black: robot; coloured: fish; green discs: the goals (radius = goal \
             radius); open red circles: where the fish was when it reached a goal. The goal counts \
             in the panel titles are those of the drawn window.",
            cfg.trajectory_seconds,
            files.join("; ")
        ),
        svg: svg.finish(),
    })
}
