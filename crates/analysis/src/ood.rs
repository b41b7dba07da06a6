//! What an OOD policy finds: the support scores of the fish's views in trial
//! files, their distribution next to the training data's and a lead-to-goal policy's, and a
//! ranked "data wishlist" of the situations the data lacks that the policy drove the fish into.

use fishprobe_io::{read_trial, TrialFile};
use fishprobe_models::disagreement::Disagreement;
use fishprobe_models::support::{Situation, SupportModel};
use fishprobe_sim::{AgentState, Tank, TankParams};
use rand::{Rng, RngExt};
use rayon::prelude::*;
use serde::Serialize;
use std::path::PathBuf;

/// Support scores and situations of the fish's views in one source (a policy's trials, or
/// the training recordings), one entry per fish and frame.
#[derive(Debug, Clone, Default)]
pub struct SourceScores {
    /// What the views come from.
    pub label: String,
    /// Support scores.
    pub scores: Vec<f32>,
    /// Situations.
    pub situations: Vec<Situation>,
    /// Where each trial's views end in `scores` (exclusive), one entry per trial file, in
    /// the files' order; empty for views that are not from trials (training recordings).
    pub episode_ends: Vec<usize>,
}

/// One scored view of a fish in a trial.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct ScoredView {
    /// Frame.
    pub frame: usize,
    /// Which fish (0-based, in the file's order of fish).
    pub fish: usize,
    /// Its position (cm).
    pub position: [f32; 2],
    /// Support score.
    pub score: f32,
    /// What it saw.
    pub situation: Situation,
}

/// The fish's views of a trial file: for each frame with the fish tracked, its situation
/// among the robot and the other fish (agents not tracked in that frame are left out). A live
/// trial's frames before closed-loop control began (habituation, the robot idle) are left
/// out: they are not the policy's.
pub fn trial_views(support: &SupportModel, t: &TrialFile) -> Vec<ScoredView> {
    let mut out = Vec::new();
    for_each_view(t, |tank, frame, fish, s, others| {
        let sit = support.situation(tank, s, others);
        out.push(ScoredView {
            frame,
            fish,
            position: [s.x, s.y],
            score: support.score_situation(&sit),
            situation: sit,
        });
    });
    out
}

/// Hands each fish view of a trial file, as [`trial_views`] takes them, to `f`: the tank,
/// the frame, which fish, its state and the other agents' states.
fn for_each_view(
    t: &TrialFile,
    mut f: impl FnMut(&Tank, usize, usize, &AgentState, &[AgentState]),
) {
    let tank = Tank::new(&TankParams {
        half_size_cm: t.world_size_cm[0] / 2.0,
        ..TankParams::default()
    });
    let mut agents: Vec<(Vec<[f32; 2]>, Vec<f32>)> = Vec::new();
    if let Some(r) = t.robot() {
        agents.push((r.positions.clone(), r.headings()));
    }
    let first_fish = agents.len();
    agents.extend(t.fish().map(|f| (f.positions.clone(), f.headings())));
    let frames = agents.iter().map(|a| a.0.len()).min().unwrap_or(0);
    let mut others = Vec::with_capacity(agents.len());
    let state = |a: &(Vec<[f32; 2]>, Vec<f32>), i: usize| {
        let (p, h) = (a.0[i], a.1[i]);
        (p[0].is_finite() && p[1].is_finite() && h.is_finite())
            .then(|| AgentState::at(p[0], p[1], h))
    };
    let control = t.control_start();
    for i in control..frames {
        for me in first_fish..agents.len() {
            let Some(s) = state(&agents[me], i) else {
                continue;
            };
            others.clear();
            others.extend(
                (0..agents.len())
                    .filter(|&j| j != me)
                    .filter_map(|j| state(&agents[j], i)),
            );
            f(&tank, i, me - first_fish, &s, &others);
        }
    }
}

/// The disagreement scores of the model's ensemble on the fish's views in `files` (the views
/// [`trial_views`] takes), as one source (no situations).
pub fn disagreement_of_trials(
    d: &Disagreement,
    label: &str,
    files: &[PathBuf],
) -> Result<SourceScores, crate::AnalysisError> {
    let parts: Vec<Vec<f32>> = files
        .par_iter()
        .map(|f| {
            read_trial(f)
                .map(|t| {
                    let mut v = Vec::new();
                    for_each_view(&t, |tank, _, _, s, others| {
                        v.push(d.score_agents(tank, s, others))
                    });
                    v
                })
                .map_err(|e| format!("{}: {e}", f.display()))
        })
        .collect::<Result<_, _>>()?;
    Ok(SourceScores {
        label: label.into(),
        episode_ends: ends(parts.iter().map(Vec::len)),
        scores: parts.concat(),
        situations: Vec::new(),
    })
}

/// The disagreement scores of views given as M_ConvNet inputs (`n x view_len`), at most `max`
/// of them taken evenly spaced (as [`score_views`] takes them).
pub fn disagreement_of_views(
    d: &Disagreement,
    label: &str,
    views: &[f32],
    max: usize,
) -> SourceScores {
    let len = d.arch().view_len();
    let n = views.len() / len;
    let step = n.div_ceil(max.max(1)).max(1);
    SourceScores {
        label: label.into(),
        scores: (0..n)
            .into_par_iter()
            .step_by(step)
            .map(|i| d.score_view(&views[i * len..(i + 1) * len]))
            .collect(),
        situations: Vec::new(),
        episode_ends: Vec::new(),
    }
}

/// The views of every trial file in `files`, as one source.
pub fn score_trials(
    support: &SupportModel,
    label: &str,
    files: &[PathBuf],
) -> Result<SourceScores, crate::AnalysisError> {
    score_recorded(support, label, files).map(|(s, _)| s)
}

/// [`score_trials`], and each file's goals reached (`None` for a file without fishprobe's
/// task record, e.g. a recording made by other tools): for recordings that no evaluation
/// of fishprobe's counted, such as live trials.
pub fn score_recorded(
    support: &SupportModel,
    label: &str,
    files: &[PathBuf],
) -> Result<(SourceScores, Vec<Option<usize>>), crate::AnalysisError> {
    let parts: Vec<(Vec<ScoredView>, Option<usize>)> = files
        .par_iter()
        .map(|f| {
            read_trial(f)
                .map(|t| {
                    let goals = t.task.as_ref().map(|k| k.goal_frames.len());
                    (trial_views(support, &t), goals)
                })
                .map_err(|e| format!("{}: {e}", f.display()))
        })
        .collect::<Result<_, _>>()?;
    let mut s = SourceScores {
        label: label.into(),
        ..SourceScores::default()
    };
    let mut goals = Vec::with_capacity(parts.len());
    for (views, g) in parts {
        goals.push(g);
        for v in views {
            s.scores.push(v.score);
            s.situations.push(v.situation);
        }
        s.episode_ends.push(s.scores.len());
    }
    Ok((s, goals))
}

/// Running sums of `lens`: where each part ends when the parts are concatenated.
fn ends(lens: impl Iterator<Item = usize>) -> Vec<usize> {
    lens.scan(0, |end, n| {
        *end += n;
        Some(*end)
    })
    .collect()
}

/// Views given as M_ConvNet inputs (`n x view_len`, e.g. a training dataset), at most `max`
/// of them taken evenly spaced.
pub fn score_views(support: &SupportModel, label: &str, views: &[f32], max: usize) -> SourceScores {
    let arch = support.arch();
    let len = arch.view_len();
    let n = views.len() / len;
    let step = n.div_ceil(max.max(1)).max(1);
    let picked: Vec<(f32, Situation)> = (0..n)
        .into_par_iter()
        .step_by(step)
        .map(|i| {
            let s = Situation::of_view(&arch, &views[i * len..(i + 1) * len]);
            (support.score_situation(&s), s)
        })
        .collect();
    let (scores, situations) = picked.into_iter().unzip();
    SourceScores {
        label: label.into(),
        scores,
        situations,
        episode_ends: Vec::new(),
    }
}

/// The `q`-quantile (linear interpolation, like `numpy.quantile`) of `v` (NaN when empty).
pub fn quantile(v: &[f32], q: f64) -> f64 {
    let v: Vec<f64> = v.iter().map(|&x| f64::from(x)).collect();
    fishprobe_stats::sample::quantile_sorted(&fishprobe_stats::sample::sorted(&v), q)
}

/// Share of `v` at or above `threshold`.
pub fn share_at_least(v: &[f32], threshold: f64) -> f64 {
    v.iter().filter(|&&x| f64::from(x) >= threshold).count() as f64 / v.len().max(1) as f64
}

/// How sure a share beyond a yardstick is: the percentile-bootstrap interval, at `level`
/// (e.g. 0.95), of [`share_at_least`]`(ood, quantile(goal, q))` over episodes. Each of `reps`
/// replicates draws, with replacement, as many episodes of each source as it has, measures
/// the yardstick (the `q`-quantile) on the drawn lead-to-goal episodes and the share on the
/// drawn OOD ones: episodes are the independent units, not views (a view is much like the
/// next, 25 of them a second), and the yardstick is as uncertain as the share. `None` when a
/// source has fewer than two episodes ([`SourceScores::episode_ends`]) or `reps` is 0.
pub fn share_beyond_interval<R: Rng>(
    ood: &SourceScores,
    goal: &SourceScores,
    q: f64,
    reps: usize,
    level: f64,
    rng: &mut R,
) -> Option<[f64; 2]> {
    let episodes = |s: &SourceScores| -> Vec<Vec<f64>> {
        let mut start = 0;
        s.episode_ends
            .iter()
            .map(|&end| {
                let mut e: Vec<f64> = s.scores[start..end].iter().map(|&x| f64::from(x)).collect();
                e.sort_unstable_by(f64::total_cmp);
                start = end;
                e
            })
            .collect()
    };
    let (ood, goal) = (episodes(ood), episodes(goal));
    if ood.len() < 2 || goal.len() < 2 || reps == 0 {
        return None;
    }
    let longest = goal.iter().map(Vec::len).max().unwrap_or(0);
    let mut pooled = Vec::with_capacity(longest * goal.len());
    let mut shares = Vec::with_capacity(reps);
    for _ in 0..reps {
        pooled.clear();
        for _ in 0..goal.len() {
            pooled.extend_from_slice(&goal[rng.random_range(0..goal.len())]);
        }
        let yardstick = fishprobe_stats::sample::quantile_in_place(&mut pooled, q);
        let (mut at_least, mut views) = (0, 0);
        for _ in 0..ood.len() {
            let e = &ood[rng.random_range(0..ood.len())];
            at_least += e.len() - e.partition_point(|&x| x < yardstick);
            views += e.len();
        }
        shares.push(at_least as f64 / views.max(1) as f64);
    }
    Some(fishprobe_stats::sample::percentile_ci(&mut shares, level))
}

/// One source's score distribution.
#[derive(Debug, Clone, PartialEq, Serialize)]
pub struct Distribution {
    /// The source.
    pub label: String,
    /// Views scored.
    pub views: usize,
    /// Median score.
    pub median: f64,
    /// 95th percentile.
    pub p95: f64,
    /// Share of views scoring above 1 (beyond the training data's 95th percentile).
    pub beyond_support: f64,
}

/// The distribution of a source's scores.
pub fn distribution(s: &SourceScores) -> Distribution {
    Distribution {
        label: s.label.clone(),
        views: s.scores.len(),
        median: quantile(&s.scores, 0.5),
        p95: quantile(&s.scores, 0.95),
        beyond_support: s.scores.iter().filter(|&&x| x > 1.0).count() as f64
            / s.scores.len().max(1) as f64,
    }
}

/// Coarse classes of a situation, in plain terms: the cells of the wishlist.
pub fn situation_cell(s: &Situation) -> [&'static str; 4] {
    let d = s.partner_distance_cm;
    let partner = if !s.partner_seen {
        "no partner seen"
    } else if d < 3.0 {
        "partner within 3 cm"
    } else if d < 8.0 {
        "partner 3-8 cm away"
    } else if d < 20.0 {
        "partner 8-20 cm away"
    } else {
        "partner over 20 cm away"
    };
    let b = s.partner_bearing_rad.to_degrees();
    let bearing = if !s.partner_seen {
        "-"
    } else if b.abs() <= 45.0 {
        "ahead"
    } else if b.abs() >= 135.0 {
        "behind"
    } else if b > 0.0 {
        "to the left"
    } else {
        "to the right"
    };
    let h = s.relative_heading_rad.to_degrees().abs();
    let heading = if !s.partner_seen {
        "-"
    } else if h <= 45.0 {
        "swimming the same way"
    } else if h >= 135.0 {
        "heading the opposite way"
    } else {
        "crossing"
    };
    let w = s.wall_distance_cm;
    let wall = if w < 5.0 && s.second_wall_cm < 5.0 {
        "in a corner (two walls within 5 cm)"
    } else if w < 2.0 {
        "wall within 2 cm"
    } else if w < 5.0 {
        "wall 2-5 cm away"
    } else if w < 15.0 {
        "wall 5-15 cm away"
    } else {
        "wall over 15 cm away"
    };
    [partner, bearing, heading, wall]
}

/// One entry of the data wishlist.
#[derive(Debug, Clone, PartialEq, Serialize)]
pub struct WishItem {
    /// Rank (1 = record first).
    pub rank: usize,
    /// The situation, in plain terms.
    pub situation: String,
    /// Share of the OOD policy's views in this situation and beyond the support (score > 1).
    pub ood_policy_share_beyond: f64,
    /// Their mean score (uncapped: the views' own scores; only the ranking caps them).
    pub mean_score: f64,
    /// Share of the training views in this situation (any score).
    pub training_share: f64,
    /// Share of the lead-to-goal policy's views in this situation (any score), if compared.
    pub goal_policy_share: Option<f64>,
    /// The ranking value: the OOD policy's share beyond the support times its mean score.
    pub priority: f64,
}

/// The situations the OOD policy drove the fish into beyond the support, ranked by how much
/// out-of-support time (weighted by score, each capped at `cap`) the policy spent in them:
/// what the lab should record next. At most `n` entries.
pub fn wishlist(
    ood: &SourceScores,
    training: &SourceScores,
    goal: Option<&SourceScores>,
    cap: f32,
    n: usize,
) -> Vec<WishItem> {
    use std::collections::BTreeMap;
    // Per cell: views beyond the support, their capped sum (the ranking) and their sum.
    let mut cells: BTreeMap<[&str; 4], (usize, f64, f64)> = BTreeMap::new();
    for (score, sit) in ood.scores.iter().zip(&ood.situations) {
        if *score > 1.0 {
            let e = cells.entry(situation_cell(sit)).or_default();
            e.0 += 1;
            e.1 += f64::from(score.min(cap));
            e.2 += f64::from(*score);
        }
    }
    let share = |src: &SourceScores, cell: &[&str; 4]| {
        src.situations
            .iter()
            .filter(|s| &situation_cell(s) == cell)
            .count() as f64
            / src.situations.len().max(1) as f64
    };
    let total = ood.scores.len().max(1) as f64;
    let mut items: Vec<WishItem> = cells
        .into_iter()
        .map(|(cell, (count, capped, sum))| {
            let describe = cell
                .iter()
                .filter(|c| **c != "-")
                .copied()
                .collect::<Vec<_>>()
                .join(", ");
            WishItem {
                rank: 0,
                situation: describe,
                ood_policy_share_beyond: count as f64 / total,
                mean_score: sum / count as f64,
                training_share: share(training, &cell),
                goal_policy_share: goal.map(|g| share(g, &cell)),
                priority: capped / total,
            }
        })
        .collect();
    items.sort_by(|a, b| b.priority.total_cmp(&a.priority));
    items.truncate(n);
    for (i, it) in items.iter_mut().enumerate() {
        it.rank = i + 1;
    }
    items
}

/// The nine metrics' per-frame values pooled over trial files.
pub fn pooled_metrics(
    files: &[PathBuf],
    cfg: &crate::AnalysisConfig,
) -> Result<Vec<Vec<f64>>, crate::AnalysisError> {
    let mut pooled = vec![Vec::new(); crate::METRICS.len()];
    for f in files {
        let t = crate::load_trial(f, cfg, true)?;
        for (p, v) in pooled.iter_mut().zip(t.metrics.unwrap_or_default()) {
            p.extend(v);
        }
    }
    for p in &mut pooled {
        p.sort_by(f64::total_cmp);
    }
    Ok(pooled)
}

/// A model's distance to the real fish over the metrics: the mean over metrics of the
/// Wasserstein distance between the model's and the real values, each in units of the real
/// values' standard deviation (metrics without values or spread are left out; NaN if none).
pub fn metric_gap(model: &[Vec<f64>], real: &[Vec<f64>]) -> f64 {
    let mut sum = 0.0;
    let mut n = 0u32;
    for (m, r) in model.iter().zip(real) {
        let sd = fishprobe_stats::sample::sd(r);
        if let (Ok(w), true) = (fishprobe_stats::wasserstein::wasserstein(m, r), sd > 0.0) {
            sum += w / sd;
            n += 1;
        }
    }
    if n > 0 {
        sum / f64::from(n)
    } else {
        f64::NAN
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    fn sit(d: f32, b: f32, h: f32, w: f32) -> Situation {
        Situation {
            partner_seen: true,
            partner_distance_cm: d,
            partner_bearing_rad: b.to_radians(),
            relative_heading_rad: h.to_radians(),
            wall_distance_cm: w,
            wall_bearing_rad: 0.0,
            second_wall_cm: 60.0,
        }
    }

    #[test]
    fn a_live_trials_views_begin_with_control() {
        use fishprobe_io::{Category, Entity, TaskRecord, TrialKind};
        let entity = |name: &str, category: Category, x0: f32| Entity {
            name: name.into(),
            category_label: name.into(),
            category,
            positions: (0..10).map(|i| [x0 + i as f32, 0.0]).collect(),
            orientations: vec![[1.0, 0.0]; 10],
            attributes: Default::default(),
        };
        let record = |control_start_frame| TaskRecord {
            kind: TrialKind::Real,
            policy: "p".into(),
            fish_model: "live".into(),
            seed: 0,
            goal_radius_cm: 5.0,
            goals: vec![],
            active_goal: vec![-1; 10],
            goal_frames: vec![],
            command_frames: vec![],
            command_turns: vec![],
            control_start_frame,
            config_json: String::new(),
            program_version: String::new(),
        };
        let mut t = TrialFile {
            world_size_cm: [100.0, 100.0],
            frame_rate_hz: 25.0,
            entities: vec![
                entity("robot", Category::Robot, -20.0),
                entity("fish", Category::Fish, 0.0),
            ],
            attributes: Default::default(),
            task: None,
        };
        let support = fishprobe_models::support::shipped_convnet().unwrap();
        assert_eq!(trial_views(&support, &t).len(), 10);
        t.task = Some(record(0));
        assert_eq!(trial_views(&support, &t).len(), 10);
        t.task = Some(record(4));
        let v = trial_views(&support, &t);
        assert_eq!((v.len(), v[0].frame), (6, 4));
    }

    #[test]
    fn the_metric_gap_is_wasserstein_in_real_sds() {
        // Real {0, 2}: s.d. (n - 1) = sqrt(2); model {1, 3}: W1 = 1. A metric without spread
        // is left out.
        let g = metric_gap(
            &[vec![1.0, 3.0], vec![5.0]],
            &[vec![0.0, 2.0], vec![4.0, 4.0]],
        );
        assert!((g - 1.0 / 2f64.sqrt()).abs() < 1e-12, "{g}");
        assert!(metric_gap(&[vec![]], &[vec![1.0, 2.0]]).is_nan());
    }

    #[test]
    fn quantiles_and_shares_by_hand() {
        let v = [4.0, 1.0, 3.0, 2.0];
        assert_eq!(quantile(&v, 0.5), 2.5);
        assert_eq!(quantile(&v, 0.0), 1.0);
        assert!((quantile(&v, 0.95) - 3.85).abs() < 1e-12);
        assert_eq!(share_at_least(&v, 3.0), 0.5);
        let d = distribution(&SourceScores {
            label: "x".into(),
            scores: v.to_vec(),
            situations: vec![Situation::default(); 4],
            episode_ends: vec![4],
        });
        assert_eq!(d.beyond_support, 0.75);
    }

    #[test]
    fn cells_read_in_plain_terms() {
        assert_eq!(
            situation_cell(&sit(2.0, 170.0, 180.0, 1.0)),
            [
                "partner within 3 cm",
                "behind",
                "heading the opposite way",
                "wall within 2 cm"
            ]
        );
        let mut corner = sit(2.0, 170.0, 180.0, 1.0);
        corner.second_wall_cm = 3.0;
        assert_eq!(
            situation_cell(&corner)[3],
            "in a corner (two walls within 5 cm)"
        );
        assert_eq!(
            situation_cell(&sit(10.0, 90.0, 90.0, 30.0)),
            [
                "partner 8-20 cm away",
                "to the left",
                "crossing",
                "wall over 15 cm away"
            ]
        );
    }

    #[test]
    fn the_wishlist_ranks_out_of_support_time_weighted_by_score() {
        let corner = sit(2.0, 170.0, 180.0, 1.0);
        let open = sit(10.0, 0.0, 0.0, 30.0);
        let ood = SourceScores {
            label: "ood".into(),
            // Corner: 3 views at 2 (one capped from 9 to 3); open: 1 view at 1.5, 1 in support.
            scores: vec![2.0, 2.0, 9.0, 1.5, 0.5],
            situations: vec![corner, corner, corner, open, open],
            episode_ends: vec![5],
        };
        let training = SourceScores {
            label: "train".into(),
            scores: vec![0.0; 4],
            situations: vec![open, open, open, corner],
            episode_ends: Vec::new(),
        };
        let w = wishlist(&ood, &training, None, 3.0, 10);
        assert_eq!(w.len(), 2);
        assert_eq!(w[0].rank, 1);
        assert!(w[0].situation.contains("partner within 3 cm"), "{w:?}");
        assert!((w[0].ood_policy_share_beyond - 0.6).abs() < 1e-12);
        // The mean is the views' own (13 / 3); only the ranking caps the 9.
        assert!((w[0].mean_score - 13.0 / 3.0).abs() < 1e-12);
        assert!((w[0].priority - 7.0 / 5.0).abs() < 1e-12);
        assert!((w[0].training_share - 0.25).abs() < 1e-12);
        assert!((w[1].priority - 0.3).abs() < 1e-12);
        assert_eq!(w[1].goal_policy_share, None);
    }

    #[test]
    fn the_share_interval_resamples_episodes_and_knows_a_binomial() {
        let source = |episodes: &[Vec<f32>]| SourceScores {
            label: "x".into(),
            scores: episodes.concat(),
            situations: Vec::new(),
            episode_ends: ends(episodes.iter().map(Vec::len)),
        };
        let mut rng = fishprobe_sim::stream(7, "interval-test", 0);
        // The yardstick is 1 in every replicate; three OOD episodes lie wholly beyond it,
        // three wholly within, so a replicate's share is Binomial(6, 1/2) / 6: its 2.5 % and
        // 97.5 % quantiles are 1/6 and 5/6 (P(0) = 1/64 < 0.025 < P(<= 1) = 7/64).
        let goal = source(&vec![vec![1.0_f32; 50]; 6]);
        let mut ood: Vec<Vec<f32>> = vec![vec![2.0; 40]; 3];
        ood.extend(vec![vec![0.0; 40]; 3]);
        let ood = source(&ood);
        let [lo, hi] = share_beyond_interval(&ood, &goal, 0.95, 4000, 0.95, &mut rng).unwrap();
        assert!(
            (lo - 1.0 / 6.0).abs() < 1e-12 && (hi - 5.0 / 6.0).abs() < 1e-12,
            "{lo} {hi}"
        );
        assert_eq!(
            share_at_least(&ood.scores, quantile(&goal.scores, 0.95)),
            0.5
        );
        // Episodes all alike: no uncertainty, the interval is the point.
        let same = source(&vec![vec![0.5, 1.5, 2.5, 3.5]; 4]);
        let alike = source(&vec![(0..20).map(|i| i as f32 / 10.0).collect(); 3]);
        let point = share_at_least(&same.scores, quantile(&alike.scores, 0.95));
        let i = share_beyond_interval(&same, &alike, 0.95, 500, 0.95, &mut rng).unwrap();
        assert_eq!(i, [point, point]);
        // The yardstick varies with the drawn lead-to-goal episodes too: two that disagree.
        let split = source(&[vec![0.0; 10], vec![3.0; 10]]);
        let [lo, hi] = share_beyond_interval(&same, &split, 0.95, 2000, 0.95, &mut rng).unwrap();
        // (Drawn twice the low episode: yardstick 0, share 1; else 3, share 1/4.)
        assert_eq!([lo, hi], [0.25, 1.0]);
        // One episode (or no replicate) gives no interval; the same seed, the same interval.
        let one = source(&[vec![1.0; 10]]);
        assert!(share_beyond_interval(&one, &goal, 0.95, 100, 0.95, &mut rng).is_none());
        assert!(share_beyond_interval(&ood, &one, 0.95, 100, 0.95, &mut rng).is_none());
        assert!(share_beyond_interval(&ood, &goal, 0.95, 0, 0.95, &mut rng).is_none());
        let again = |seed| {
            let mut r = fishprobe_sim::stream(seed, "interval-test", 0);
            share_beyond_interval(&same, &split, 0.95, 300, 0.95, &mut r)
        };
        assert_eq!(again(1), again(1));
    }
}
