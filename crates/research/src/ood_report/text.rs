//! The report's text: `ood.md` (the distributions, the wishlist, the yardstick and the
//! command that remakes it) and the summary printed at the end.

use fishprobe_analysis::ood::Distribution;
use std::path::{Path, PathBuf};

use super::{OodReport, OodReportSettings};

fn pct(v: f64) -> String {
    format!("{:.1} %", 100.0 * v)
}

/// The headline share with its interval over episodes, when there is one.
fn share_text(r: &OodReport) -> String {
    match r.ood_share_interval {
        Some([lo, hi]) => format!(
            "{} (95 % interval over the episodes: {:.1}-{:.1} %)",
            pct(r.ood_share_beyond_goal_p95),
            100.0 * lo,
            100.0 * hi
        ),
        None => pct(r.ood_share_beyond_goal_p95),
    }
}

/// A note when the headline share's `interval` holds one half: the episodes then do not
/// settle whether the OOD policy held the fish beyond the yardstick most of the time (issue
/// 23's target), and the note says how to narrow it: more simulated episodes (`episodes`, the
/// count of them; `None` when recorded trials were scored) or more trials. Empty otherwise.
fn half_note(interval: Option<[f64; 2]>, episodes: Option<usize>) -> String {
    match interval {
        Some([lo, hi]) if lo <= 0.5 && hi >= 0.5 => {
            let more = episodes.map_or("more trials narrow it".into(), |n| {
                format!("more episodes (`--episodes`, here {n}) narrow it")
            });
            format!(
                " The interval holds one half, so these episodes do not settle whether the \
                 fish were beyond that score most of the time: {more}."
            )
        }
        _ => String::new(),
    }
}

/// [`half_note`] of a report.
fn report_half_note(r: &OodReport) -> String {
    let simulated = r.recorded_trials == [None, None];
    half_note(r.ood_share_interval, simulated.then_some(r.episodes))
}

/// Goals per episode or trial; "–" for recordings that do not say.
fn goals_text(v: f64) -> String {
    if v.is_finite() {
        format!("{v:.1}")
    } else {
        "–".into()
    }
}

/// Where each policy's views came from, in words.
fn sources_text(r: &OodReport) -> String {
    let simulated = format!(
        "{} episodes of {} min (seed {}; the evaluation task's random starts and corner goals)",
        r.episodes, r.minutes, r.seed
    );
    match r.recorded_trials {
        [None, None] => format!("{simulated} per policy"),
        [ood, goal] => {
            let one =
                |n: Option<usize>| n.map_or(simulated.clone(), |n| format!("{n} recorded trials"));
            format!(
                "OOD policy: {}; lead-to-goal policy: {}",
                one(ood),
                one(goal)
            )
        }
    }
}

/// The command that makes this report again.
fn command_line(a: &OodReportSettings) -> String {
    let paths = |v: &[PathBuf]| {
        v.iter()
            .map(|p| p.display().to_string())
            .collect::<Vec<_>>()
            .join(" ")
    };
    let mut c = String::from("fishprobe ood-report");
    if let Some(p) = &a.policy {
        c += &format!(" --policy {p}");
    }
    if !a.trials.is_empty() {
        c += &format!(" --trials {}", paths(&a.trials));
    }
    if a.compare_trials.is_empty() {
        c += &format!(" --compare {}", a.compare);
    } else {
        c += &format!(" --compare-trials {}", paths(&a.compare_trials));
    }
    if let Some(m) = &a.model {
        c += &format!(" --model {m}");
    }
    if !a.data.is_empty() {
        c += &format!(" --data {}", paths(&a.data));
    }
    if a.trials.is_empty() || a.compare_trials.is_empty() {
        c += &format!(
            " --episodes {} --minutes {} --seed {}",
            a.episodes, a.minutes, a.seed
        );
    }
    c
}

fn distributions_table(r: &OodReport) -> String {
    score_table(&r.distributions, "beyond the support (> 1)")
}

/// The distributions as a table; `beyond` heads the column of the share above 1.
fn score_table(distributions: &[Distribution], beyond: &str) -> String {
    let mut t = format!(
        "| views of | scored | median score | 95th percentile | {beyond} |\n|---|---|---|---|---|\n",
    );
    for d in distributions {
        t += &format!(
            "| {} | {} | {:.2} | {:.2} | {} |\n",
            d.label,
            d.views,
            d.median,
            d.p95,
            pct(d.beyond_support)
        );
    }
    t
}

fn wishlist_table(r: &OodReport) -> String {
    let mut t = String::from(
        "| rank | situation | OOD policy's time there, beyond the support | mean score | share of training views | share of lead-to-goal views |\n|---|---|---|---|---|---|\n",
    );
    for w in &r.wishlist {
        t += &format!(
            "| {} | {} | {} | {:.2} | {} | {} |\n",
            w.rank,
            w.situation,
            pct(w.ood_policy_share_beyond),
            w.mean_score,
            pct(w.training_share),
            w.goal_policy_share.map(pct).unwrap_or_else(|| "–".into())
        );
    }
    t
}

/// A note when the OOD policy was trained to count time beyond another score than this
/// report's yardstick (empty when it was not, or the two agree).
fn yardstick_note(r: &OodReport) -> String {
    let Some(y) = &r.trained_yardstick else {
        return String::new();
    };
    // The report's yardstick in the score the reward counted (none without an ensemble).
    let (kind, ours) = match y.ood_score {
        fishprobe_sim::OodScore::Support => ("support score", Some(r.goal_policy_p95)),
        fishprobe_sim::OodScore::Disagreement => (
            "disagreement",
            r.disagreement.as_ref().map(|d| d.goal_policy_p95),
        ),
    };
    match ours {
        Some(p) if (y.score - p).abs() <= 1e-9 => String::new(),
        _ => format!(
            " Note: the OOD policy's reward counted time beyond a {kind} of {:.3} (the 95th \
             percentile of {}, `train --ood-yardstick`), not this report's yardstick.",
            y.score, y.policy
        ),
    }
}

/// A note when the lead-to-goal policy's 95th percentile lies within the support (at most 1,
/// e.g. 0.74 under an 8-cm partner range): time beyond it is then not yet time beyond the
/// training data (docs/validation.md, "Probes that seek what the data lacks").
fn within_support_note(goal_p95: f64) -> &'static str {
    if goal_p95 <= 1.0 {
        " That yardstick lies within the support (at most 1): time beyond it is time in \
         situations rarer than the lead-to-goal policy's, not yet beyond the training data \
         (the share beyond the support counts those)."
    } else {
        ""
    }
}

pub(super) fn summary(r: &OodReport, out: &Path) -> String {
    format!(
        "{}\nThe OOD policy's fish spent {} of their time at or beyond the lead-to-goal \
         policy's 95th-percentile score ({:.2}).{}{}{} Goals per episode or trial: OOD {}, \
         lead-to-goal {}.{}\n\nData wishlist (record these next):\n{}\nwrote {}\n",
        distributions_table(r),
        share_text(r),
        r.goal_policy_p95,
        report_half_note(r),
        within_support_note(r.goal_policy_p95),
        yardstick_note(r),
        goals_text(r.goals_per_episode[0]),
        goals_text(r.goals_per_episode[1]),
        r.disagreement
            .as_ref()
            .map(|d| format!(
                " By the disagreement of the model's ensemble of {}: {} of the time at or \
                 beyond the lead-to-goal policy's 95th percentile ({:.2}).",
                d.members,
                pct(d.ood_share_beyond_goal_p95),
                d.goal_policy_p95
            ))
            .unwrap_or_default(),
        r.wishlist
            .iter()
            .take(5)
            .map(|w| format!(
                "  {}. {} ({} of the OOD policy's time)\n",
                w.rank,
                w.situation,
                pct(w.ood_policy_share_beyond)
            ))
            .collect::<String>(),
        out.join("report.md").display()
    )
}

/// The report's section on the ensemble's disagreement (empty without an ensemble).
fn disagreement_section(r: &OodReport) -> String {
    let Some(d) = &r.disagreement else {
        return String::new();
    };
    format!(
        "## The ensemble's disagreement\n\n\
         The model has an ensemble of {} fits (`fit-convnet --members`). The same views, scored \
         by how much the fits disagree on them (the mutual information of their predictions; 0: \
         the training views' median, 1: their 95th percentile), the OOD score \
         `ood_score = \"disagreement\"` rewards:\n\n{}\n\
         The OOD policy's fish spent **{}** of their time at or beyond the lead-to-goal \
         policy's 95th-percentile disagreement ({:.2}).\n\n",
        d.members,
        score_table(&d.distributions, "beyond the training p95 (> 1)"),
        pct(d.ood_share_beyond_goal_p95),
        d.goal_policy_p95
    )
}

pub(super) fn markdown(r: &OodReport, a: &OodReportSettings) -> String {
    format!(
        "# What the OOD policy finds\n\n\
         Fish model: {}. OOD policy: {}. Lead-to-goal policy: {}. {}, every fish view scored \
         against the model's training support (0: the training views' median, 1: their 95th \
         percentile).\n\n\
         ## Support scores\n\n{}\n\
         The OOD policy's fish spent **{}** of their time at or beyond the lead-to-goal \
         policy's 95th-percentile score ({:.2}).{}{}{} Goals per episode or trial: OOD policy \
         {}, lead-to-goal policy {}.\n\n\
         ![score distributions](ood-scores.png)\n\n\
         ![example episodes](ood-trajectories.png)\n\n\
         {}## Data wishlist\n\n\
         The situations beyond the support where the OOD policy drove the fish, ranked by \
         its time there weighted by score: what the lab should record next.\n\n{}\n\
         Made by `{}`.\n",
        r.model,
        r.ood_policy,
        r.goal_policy,
        sources_text(r),
        distributions_table(r),
        share_text(r),
        r.goal_policy_p95,
        report_half_note(r),
        within_support_note(r.goal_policy_p95),
        yardstick_note(r),
        goals_text(r.goals_per_episode[0]),
        goals_text(r.goals_per_episode[1]),
        disagreement_section(r),
        wishlist_table(r),
        command_line(a),
    )
}

#[cfg(test)]
mod tests {
    #[test]
    fn a_yardstick_within_the_support_is_said_to_be() {
        assert!(super::within_support_note(0.743).contains("lies within the support"));
        assert!(super::within_support_note(1.0).contains("lies within the support"));
        assert_eq!(super::within_support_note(1.278), "");
    }

    #[test]
    fn an_interval_across_one_half_is_said_not_to_settle_most_of_the_time() {
        use super::half_note;
        let note = half_note(Some([0.465, 0.565]), Some(6));
        assert!(
            note.contains("holds one half") && note.contains("`--episodes`, here 6"),
            "{note}"
        );
        assert!(half_note(Some([0.4, 0.5]), None).contains("more trials"));
        // Most means more than half, so an interval from one half up does not settle it.
        assert!(half_note(Some([0.5, 0.6]), Some(24)).contains("here 24"));
        // Wholly on one side of one half, or no interval: nothing to say.
        for interval in [Some([0.417, 0.482]), Some([0.51, 0.6]), None] {
            assert_eq!(half_note(interval, Some(6)), "", "{interval:?}");
        }
    }
}
