//! What one seed of the loop found, and the Markdown tables of `loop.md`.

use fishprobe_sim::OodScore;

use super::OodLoopConfig;

/// One model's gap to the virtual guppy.
#[derive(Debug, Clone, Copy, serde::Serialize, serde::Deserialize)]
pub(super) struct Gap {
    /// Mean over the nine metrics of W1(model, guppy) / s.d.(guppy).
    pub(super) metrics: f64,
    /// |goals(model) - goals(guppy)| / goals(guppy), goals per episode of the probe.
    pub(super) goals: f64,
    /// Goals per episode of the probe against the model.
    pub(super) goals_per_episode: f64,
}

/// The gaps one further probe measured (`more_gap_probes`).
#[derive(Debug, Clone, serde::Serialize, serde::Deserialize)]
pub(super) struct ProbeGaps {
    pub(super) probe: String,
    pub(super) guppy_goals_per_episode: f64,
    pub(super) narrow: Gap,
    pub(super) after_goal_data: Gap,
    pub(super) after_ood_data: Gap,
}

/// One seed's outcome.
#[derive(Debug, Clone, serde::Serialize, serde::Deserialize)]
pub(super) struct SeedResult {
    pub(super) seed: u64,
    pub(super) guppy_goals_per_episode: f64,
    pub(super) narrow: Gap,
    pub(super) after_goal_data: Gap,
    pub(super) after_ood_data: Gap,
    /// Share of the guppy's views under the OOD policy at or beyond the lead-to-goal
    /// policy's 95th-percentile support score (narrow model's support).
    pub(super) ood_share_beyond_goal_p95: f64,
    /// From the second round on (`rounds` > 1): the same share, each round's policies scored
    /// under the support of the model the OOD policy was trained against.
    #[serde(default)]
    pub(super) later_rounds_ood_share: Vec<f64>,
    /// Goals per episode of each policy with the guppy.
    pub(super) ood_policy_goals: f64,
    pub(super) goal_policy_goals: f64,
    /// The further probes' gaps (absent in loops recorded before them).
    #[serde(default)]
    pub(super) more_probes: Vec<ProbeGaps>,
}

pub(super) fn markdown(cfg: &OodLoopConfig, r: &[SeedResult]) -> String {
    let mut t = String::from(
        "| seed | metric gap: narrow model | + lead-to-goal data | + OOD data | goal gap: narrow | + lead-to-goal data | + OOD data | OOD views beyond lead-to-goal p95 |\n|---|---|---|---|---|---|---|---|\n",
    );
    for s in r {
        t += &format!(
            "| {} | {:.3} | {:.3} | {:.3} | {:.2} | {:.2} | {:.2} | {:.1} % |\n",
            s.seed,
            s.narrow.metrics,
            s.after_goal_data.metrics,
            s.after_ood_data.metrics,
            s.narrow.goals,
            s.after_goal_data.goals,
            s.after_ood_data.goals,
            100.0 * s.ood_share_beyond_goal_p95
        );
    }
    let n = r.len().max(1) as f64;
    let mean = |f: fn(&SeedResult) -> f64| r.iter().map(f).sum::<f64>() / n;
    let better = r
        .iter()
        .filter(|s| s.after_ood_data.metrics < s.after_goal_data.metrics)
        .count();
    t += &format!(
        "| mean | {:.3} | {:.3} | {:.3} | {:.2} | {:.2} | {:.2} | {:.1} % |\n\n\
         Metric gap: the nine metrics' Wasserstein distances between the model's and the \
         virtual guppy's trials with the gap probe, each in units of the guppy's s.d., \
         averaged. Goal gap: |goals(model) - goals(guppy)| / goals(guppy). The OOD data left \
         a smaller metric gap than the lead-to-goal data in {better} of {} seeds{}.\n",
        mean(|s| s.narrow.metrics),
        mean(|s| s.after_goal_data.metrics),
        mean(|s| s.after_ood_data.metrics),
        mean(|s| s.narrow.goals),
        mean(|s| s.after_goal_data.goals),
        mean(|s| s.after_ood_data.goals),
        100.0 * mean(|s| s.ood_share_beyond_goal_p95),
        r.len(),
        paired_difference(
            &r.iter()
                .map(|s| s.after_ood_data.metrics)
                .collect::<Vec<_>>(),
            &r.iter()
                .map(|s| s.after_goal_data.metrics)
                .collect::<Vec<_>>(),
        )
        .map_or_else(String::new, |d| format!(
            "; the mean difference over the seeds, OOD minus lead-to-goal data, is {d} (paired t)"
        ))
    );
    if cfg.ood_score == OodScore::Disagreement {
        t += &format!(
            "\nThe OOD policy was rewarded by the disagreement of an ensemble of {} fits of its \
             model (`ood_score = \"disagreement\"`); the last column still measures support \
             scores.\n",
            cfg.ensemble_members
        );
    }
    if cfg.rounds > 1 {
        t += &format!(
            "\n{} rounds: the gaps are those of each chain's model after its last round; the \
             last column is the first round's. OOD views beyond the lead-to-goal p95 by round: {}.\n",
            cfg.rounds,
            r.iter()
                .map(|s| {
                    let by_round: Vec<String> = std::iter::once(s.ood_share_beyond_goal_p95)
                        .chain(s.later_rounds_ood_share.iter().copied())
                        .map(|x| format!("{:.1} %", 100.0 * x))
                        .collect();
                    format!("seed {}: {}", s.seed, by_round.join(", "))
                })
                .collect::<Vec<_>>()
                .join("; ")
        );
    }
    t + "\n" + &probe_table(&cfg.gap_probe, r)
}

/// Per probe, the mean metric gaps over the seeds and in how many seeds the OOD data left the
/// smaller one; then the same for each seed's mean over all probes.
fn probe_table(first_probe: &str, r: &[SeedResult]) -> String {
    let Some(s0) = r.first() else {
        return String::new();
    };
    if s0.more_probes.is_empty() {
        return String::new();
    }
    // Per seed, per probe: (narrow, after lead-to-goal data, after OOD data).
    let per_seed: Vec<Vec<[f64; 3]>> = r
        .iter()
        .map(|s| {
            std::iter::once([
                s.narrow.metrics,
                s.after_goal_data.metrics,
                s.after_ood_data.metrics,
            ])
            .chain(s.more_probes.iter().map(|p| {
                [
                    p.narrow.metrics,
                    p.after_goal_data.metrics,
                    p.after_ood_data.metrics,
                ]
            }))
            .collect()
        })
        .collect();
    let names: Vec<&str> = std::iter::once(first_probe)
        .chain(s0.more_probes.iter().map(|p| p.probe.as_str()))
        .collect();
    let n = r.len() as f64;
    let mut t = String::from(
        "| gap probe | metric gap: narrow model | + lead-to-goal data | + OOD data | seeds where the OOD data left the smaller gap | OOD minus lead-to-goal data, paired over the seeds |\n|---|---|---|---|---|---|\n",
    );
    let mut row = |name: &str, gaps: Vec<[f64; 3]>| {
        let m = |k: usize| gaps.iter().map(|g| g[k]).sum::<f64>() / n;
        let better = gaps.iter().filter(|g| g[2] < g[1]).count();
        let column = |k: usize| gaps.iter().map(|g| g[k]).collect::<Vec<_>>();
        t += &format!(
            "| {name} | {:.3} | {:.3} | {:.3} | {better} of {} | {} |\n",
            m(0),
            m(1),
            m(2),
            gaps.len(),
            paired_difference(&column(2), &column(1)).unwrap_or_else(|| "(one seed)".into())
        );
    };
    for (k, name) in names.iter().enumerate() {
        row(name, per_seed.iter().map(|s| s[k]).collect());
    }
    let over_all = per_seed
        .iter()
        .map(|s| {
            let p = s.len() as f64;
            [0, 1, 2].map(|k| s.iter().map(|g| g[k]).sum::<f64>() / p)
        })
        .collect();
    row("mean over the probes", over_all);
    t + "\nEach probe's metric gap averaged over the seeds (the first probe's is the table above); \
         the last column: the mean over the seeds of (gap after OOD data) - (gap after \
         lead-to-goal data), negative where the OOD data did better, with its 95 % interval \
         (paired t: each seed refits one narrow model once with each kind of data).\n"
}

/// Level of the interval for the paired difference of the gaps (the study's 95 %).
const PAIRED_LEVEL: f64 = 0.95;

/// The mean paired difference `ood - goal` over the seeds with its 95 % t interval and p value
/// ("+0.016 (95 % interval -0.020 to +0.052, p = 0.31)"); `None` with fewer than two seeds (no
/// spread to judge it by); a gap that is not a number says so.
fn paired_difference(ood: &[f64], goal: &[f64]) -> Option<String> {
    if ood.len() < 2 {
        return None;
    }
    let d = match fishprobe_stats::paired_t(ood, goal, PAIRED_LEVEL) {
        Ok(d) => d,
        Err(e) => return Some(format!("undefined ({e})")),
    };
    let p = if d.p.is_nan() {
        "no seed differs".to_string()
    } else if d.p >= 0.01 {
        format!("p = {:.2}", d.p)
    } else if d.p >= 0.001 {
        format!("p = {:.3}", d.p)
    } else {
        format!("p = {:.1e}", d.p)
    };
    Some(format!(
        "{} (95 % interval {} to {}, {p})",
        signed(d.mean_difference),
        signed(d.ci[0]),
        signed(d.ci[1])
    ))
}

/// A signed number to three decimals; one that would print as "+0.000" or "-0.000" without being
/// zero keeps its first two significant digits instead ("-2.1e-4"), so that an interval which
/// only just holds zero reads so and does not end at a negative zero.
fn signed(x: f64) -> String {
    if x != 0.0 && x.abs() < 0.0005 {
        format!("{x:+.1e}")
    } else {
        format!("{x:+.3}")
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    fn gap(metrics: f64) -> Gap {
        Gap {
            metrics,
            goals: 0.5,
            goals_per_episode: 10.0,
        }
    }

    fn seed(seed: u64, goal: f64, ood: f64) -> SeedResult {
        SeedResult {
            seed,
            guppy_goals_per_episode: 20.0,
            narrow: gap(0.5),
            after_goal_data: gap(goal),
            after_ood_data: gap(ood),
            ood_share_beyond_goal_p95: 0.5,
            later_rounds_ood_share: Vec::new(),
            ood_policy_goals: 1.0,
            goal_policy_goals: 2.0,
            more_probes: vec![ProbeGaps {
                probe: "scripted:random".into(),
                guppy_goals_per_episode: 20.0,
                narrow: gap(0.4),
                after_goal_data: gap(ood),
                after_ood_data: gap(goal),
            }],
        }
    }

    #[test]
    fn the_verdict_carries_the_paired_difference_over_the_seeds() {
        // The first scipy case of fishprobe_stats::paired: ttest_rel(ood, goal) gives a mean
        // difference of 0.042, interval -0.059 to 0.143, p = 0.31.
        let goal = [0.440, 0.276, 0.363, 0.5, 0.2];
        let ood = [0.430, 0.419, 0.380, 0.45, 0.31];
        let r: Vec<SeedResult> = (0..5)
            .map(|k| seed(k, goal[k as usize], ood[k as usize]))
            .collect();
        let md = markdown(&OodLoopConfig::default(), &r);
        assert!(
            md.contains(
                "in 2 of 5 seeds; the mean difference over the seeds, OOD minus lead-to-goal \
                 data, is +0.042 (95 % interval -0.059 to +0.143, p = 0.31) (paired t)."
            ),
            "{md}"
        );
        // The further probe swapped the two kinds of data: the difference turns sign.
        assert!(
            md.contains("| scripted:random | 0.400 | 0.398 | 0.356 | 3 of 5 | -0.042 (95 % interval -0.143 to +0.059, p = 0.31) |"),
            "{md}"
        );
    }

    #[test]
    fn a_gap_that_is_not_a_number_leaves_the_difference_undefined() {
        let r = [seed(0, 0.3, f64::NAN), seed(1, 0.3, 0.4)];
        let md = markdown(&OodLoopConfig::default(), &r);
        assert!(
            md.contains("is undefined (paired_t x: sample holds a non-finite value) (paired t)."),
            "{md}"
        );
    }

    #[test]
    fn a_small_p_keeps_its_first_digit() {
        // scipy.stats.ttest_rel(x, y).pvalue: 1.036e-4, 0.002105, 0.01478
        let d = paired_difference(&[1.0, 2.1, 3.0, 4.2], &[0.0, 1.0, 2.05, 3.1]).unwrap();
        assert!(d.ends_with(", p = 1.0e-4)"), "{d}");
        let d = paired_difference(&[0.5, 0.9, 0.6, 1.0, 0.8], &[0.1, 0.2, 0.3, 0.4, 0.2]).unwrap();
        assert!(d.ends_with(", p = 0.002)"), "{d}");
        let d = paired_difference(&[0.5, 0.9, 0.4, 1.2, 0.8], &[0.1, 0.2, 0.3, 0.4, 0.0]).unwrap();
        assert!(d.ends_with(", p = 0.01)"), "{d}");
    }

    #[test]
    fn an_interval_that_only_just_holds_zero_does_not_end_at_negative_zero() {
        // scipy.stats.ttest_rel([1.0, 0.85405], [0, 0]).confidence_interval(): -2.103e-4 to
        // 1.85426, p = 0.050011
        let d = paired_difference(&[1.0, 0.85405], &[0.0, 0.0]).unwrap();
        assert_eq!(d, "+0.927 (95 % interval -2.1e-4 to +1.854, p = 0.05)");
        assert_eq!(signed(0.0), "+0.000");
        assert_eq!(signed(-0.0123), "-0.012");
    }

    #[test]
    fn one_seed_has_no_interval() {
        let md = markdown(&OodLoopConfig::default(), &[seed(0, 0.3, 0.4)]);
        assert!(md.contains("in 0 of 1 seeds.\n"), "{md}");
        assert!(md.contains("| 0 of 1 | (one seed) |"), "{md}");
    }
}
