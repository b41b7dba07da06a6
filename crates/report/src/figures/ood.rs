//! What an OOD policy finds: the support scores of the fish's views per source,
//! and example episodes with the fish's path coloured by score.

use super::prelude::*;

/// The empirical distribution (ECDF) of each source's support scores, on [0, `cap`] (higher
/// scores drawn at `cap`), with the training data's 95th percentile (score 1) marked.
pub fn ood_scores(sources: &[(String, Vec<f32>)], cap: f32) -> Figure {
    let mut svg = Svg::new(700.0, 400.0);
    let ax = Axes::new(
        (70.0, 40.0, 380.0, 290.0),
        (0.0, f64::from(cap)),
        (0.0, 1.0),
    );
    ax.draw(
        &mut svg,
        "support score of the fish's view (1 = 95th percentile of the training views)",
        "share of views with a lower score",
        "",
        None,
    );
    let x1 = ax.px(1.0);
    svg.line((x1, ax.y), (x1, ax.y + ax.h), "#888888", 1.0, Some("4 3"));
    let mut rows = Vec::new();
    for (i, (label, scores)) in sources.iter().enumerate() {
        let mut v: Vec<f64> = scores
            .iter()
            .map(|&s| f64::from(s.min(cap)))
            .filter(|s| s.is_finite())
            .collect();
        if v.is_empty() {
            continue;
        }
        v.sort_by(f64::total_cmp);
        // At most ~400 steps: every k-th order statistic.
        let k = v.len().div_ceil(400).max(1);
        let n = v.len() as f64;
        let mut pts = vec![ax.p(0.0, 0.0)];
        for (j, x) in v.iter().enumerate().step_by(k) {
            pts.push(ax.p(*x, j as f64 / n));
        }
        pts.push(ax.p(v[v.len() - 1], 1.0));
        pts.push(ax.p(f64::from(cap), 1.0));
        let look = series(i);
        svg.polyline(&pts, look.color, 2.0, look.dash, 0.95);
        rows.push((look, label.clone(), Key::Line));
    }
    legend(&mut svg, 462.0, 50.0, &rows);
    Figure {
        name: "ood-scores",
        title: "How far out of the model's training support the fish's views were".into(),
        caption: format!(
            "Empirical distribution of the support score of every fish view (each frame), per \
             source. 0: at or below the training views' median; 1 (dashed): their 95th \
             percentile, so 95 % of the training views lie left of it; scores above {cap:.2} are \
             drawn at {cap:.2}. A curve further right spends more time where the data is thin."
        ),
        svg: svg.finish(),
    }
}

/// One example episode: robot path, fish path(s) as dots coloured by support score.
#[derive(Debug, Clone, PartialEq, Default)]
pub struct ScoredEpisode {
    /// Panel title.
    pub title: String,
    /// Robot positions (cm), per frame.
    pub robot: Vec<[f32; 2]>,
    /// Fish positions (cm) with the score of the view there.
    pub fish: Vec<([f32; 2], f32)>,
}

/// Example episodes side by side, fish paths coloured by support score (viridis over
/// [0, `cap`]).
pub fn ood_trajectories(episodes: &[ScoredEpisode], cap: f32) -> Figure {
    let side = 240.0;
    let n = episodes.len().max(1) as f64;
    let mut svg = Svg::new((40.0 + n * (side + 30.0)).max(560.0), side + 140.0);
    for (i, e) in episodes.iter().enumerate() {
        let ax = Axes::new(
            (30.0 + i as f64 * (side + 30.0), 40.0, side, side),
            (-50.0, 50.0),
            (-50.0, 50.0),
        );
        tank(&mut svg, &ax);
        let p = |v: &[f32; 2]| ax.p(f64::from(v[0]), f64::from(v[1]));
        let robot: Vec<(f64, f64)> = e
            .robot
            .iter()
            .filter(|v| v[0].is_finite() && v[1].is_finite())
            .map(p)
            .collect();
        svg.polyline(&robot, "#555555", 1.0, None, 0.6);
        // Every 5th frame is dense enough at 25 Hz and keeps the file small.
        for (pos, s) in e.fish.iter().step_by(5) {
            if pos[0].is_finite() && pos[1].is_finite() {
                let t = (f64::from(*s) / f64::from(cap)).clamp(0.0, 1.0);
                svg.circle(p(pos), 1.6, Some(&viridis(t)), "none", 0.0);
            }
        }
        svg.text(
            ax.x + ax.w / 2.0,
            ax.y - 8.0,
            &e.title,
            TextStyle::new(12.0, Anchor::Middle).bold(),
        );
    }
    colour_bar(
        &mut svg,
        (30.0, side + 70.0),
        "score 0",
        &format!("{cap:.2}+"),
    );
    svg.text(
        30.0,
        side + 120.0,
        "fish path coloured by the support score of its view; robot in grey",
        TextStyle::new(11.0, Anchor::Start),
    );
    Figure {
        name: "ood-trajectories",
        title: "Example episodes: where the fish's views left the data".into(),
        caption: "Each panel one episode; the fish's positions (every 5th frame) coloured by \
                  how far its view lay outside the model's training data (bright: far out), \
                  the robot's path in grey."
            .into(),
        svg: svg.finish(),
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn both_figures_render() {
        let f = ood_scores(
            &[
                ("training data".into(), vec![0.0, 0.2, 0.5, 1.2]),
                ("OOD policy".into(), vec![1.0, 2.0, 9.0]),
                ("empty".into(), vec![]),
            ],
            4.0,
        );
        assert!(f.svg.contains("OOD policy"));
        crate::render::png(&f.svg, f.name, 1.0).unwrap();
        let e = ScoredEpisode {
            title: "ep".into(),
            robot: vec![[0.0, 0.0], [1.0, 1.0]],
            fish: vec![([2.0, 2.0], 0.5), ([f32::NAN, 0.0], 1.0)],
        };
        let f = ood_trajectories(&[e.clone(), e], 4.0);
        crate::render::png(&f.svg, f.name, 1.0).unwrap();
    }
}
