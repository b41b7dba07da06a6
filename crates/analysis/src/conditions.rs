//! Which trials can stand for one condition of a policy: the same group size in both arms
//! (else the group metrics are not compared), the same weights in every trial (a policy
//! retrained under one name is two policies), and fish untracked in group trials.

use crate::results::Skipped;
use crate::trial::TrialData;
use std::collections::BTreeMap;

/// The fish per trial of each arm (sorted, distinct).
pub(crate) fn fish_counts(trials: &[&TrialData]) -> Vec<usize> {
    let mut n: Vec<usize> = trials.iter().map(|t| t.fish).collect();
    n.sort_unstable();
    n.dedup();
    n
}

/// Why the trials of one condition cannot stand for one policy: they record two or more
/// different weights (a policy retrained under the same name while its trials were being
/// recorded; `None` when they record one or none).
pub(crate) fn mixed_policies(trials: &[&TrialData]) -> Option<String> {
    let mut by: BTreeMap<&str, usize> = BTreeMap::new();
    for t in trials {
        if let Some(s) = t.policy_sha256.as_deref() {
            *by.entry(s).or_default() += 1;
        }
    }
    (by.len() > 1).then(|| {
        let each: Vec<String> = by
            .iter()
            .map(|(s, n)| format!("{}… in {n}", fishprobe_io::short_sha(s)))
            .collect();
        format!(
            "trials of {} different policies under one name (weights sha256 {}): a policy \
             retrained while they were recorded; not counted as one policy's (put each \
             policy's trials in its own directory)",
            by.len(),
            each.join(", ")
        )
    })
}

/// The weights that `trials` record (the first found; [`mixed_policies`] tells whether there are
/// more), or `None` when none does.
pub(crate) fn weights_of<'a>(trials: &[&'a TrialData]) -> Option<&'a str> {
    trials.iter().find_map(|t| t.policy_sha256.as_deref())
}

/// Why the trials of a further condition of a policy (its reality arm, or another model) cannot
/// be compared with its own-model trials, driven by the weights `own`: they record two weights,
/// or weights other than `own` (`None` when they agree, or when either side records none).
pub(crate) fn other_weights(own: Option<&str>, trials: &[&TrialData]) -> Option<String> {
    if let Some(why) = mixed_policies(trials) {
        return Some(why);
    }
    match (own, weights_of(trials)) {
        (Some(a), Some(b)) if a != b => Some(format!(
            "{}: two policies under one name are not compared (a policy retrained since; put \
             each policy's trials in its own directory)",
            driven_by_other(a, b)
        )),
        _ => None,
    }
}

/// Says that trials were driven by the weights `theirs`, not by `own`, those of the policy's
/// own-model trials (both shortened).
pub(crate) fn driven_by_other(own: &str, theirs: &str) -> String {
    format!(
        "driven by weights sha256 {}…, the policy's own-model trials by {}…",
        fishprobe_io::short_sha(theirs),
        fishprobe_io::short_sha(own)
    )
}

/// Groups: notes in `skipped` where the arms of a policy hold different numbers of fish (the
/// group metrics are then not compared: a group of four is not a group of two; the pair
/// metrics, per fish, still are) and where fish were untracked in group trials (those
/// fish-frames are left out of the metrics).
pub(crate) fn groups_check(
    sim: &BTreeMap<String, Vec<&TrialData>>,
    real: &BTreeMap<String, Vec<&TrialData>>,
    skipped: &mut Vec<Skipped>,
) {
    for (p, s) in sim {
        let ns = fish_counts(s);
        if let Some(r) = real.get(p) {
            let nr = fish_counts(r);
            if ns != nr && (ns.iter().chain(&nr).any(|&n| n > 1)) {
                skipped.push(Skipped {
                    what: format!("group metrics of {p}"),
                    reason: format!(
                        "sim trials hold {ns:?} fish, reality trials {nr:?}: group metrics not \
                         compared (pair metrics, per fish, are)"
                    ),
                });
            }
        }
        for (arm, trials) in [("sim", Some(s)), ("reality", real.get(p))] {
            let lost: usize = trials
                .iter()
                .flat_map(|v| v.iter())
                .map(|t| t.untracked_fish_frames)
                .sum();
            if lost > 0 {
                skipped.push(Skipped {
                    what: format!("untracked fish of {p} ({arm})"),
                    reason: format!(
                        "{lost} fish-frames of control with a fish untracked, left out of those \
                         frames' metrics"
                    ),
                });
            }
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    fn trial(fish: usize, untracked: usize) -> TrialData {
        TrialData {
            untracked_fish_frames: untracked,
            ..TrialData::blank("t.hdf5", fish)
        }
    }

    #[test]
    fn groups_of_other_sizes_and_untracked_fish_are_reported() {
        let (pair, four, three) = (trial(1, 0), trial(4, 7), trial(3, 0));
        let arms = |s: Vec<&'static TrialData>, r: Vec<&'static TrialData>| {
            let sim = BTreeMap::from([("Zone".to_string(), s)]);
            let real = BTreeMap::from([("Zone".to_string(), r)]);
            let mut skipped = Vec::new();
            groups_check(&sim, &real, &mut skipped);
            skipped
        };
        let leak = |t: TrialData| -> &'static TrialData { Box::leak(Box::new(t)) };
        let (pair, four, three) = (leak(pair), leak(four), leak(three));
        // Pairs in both arms: nothing to say.
        assert!(arms(vec![pair], vec![pair]).is_empty());
        // Four fish in simulation, three in reality: group metrics not compared; the untracked
        // fish-frames of the sim arm are counted.
        let s = arms(vec![four], vec![three]);
        assert_eq!(s.len(), 2, "{s:?}");
        assert!(
            s[0].reason.contains("[4]") && s[0].reason.contains("[3]"),
            "{s:?}"
        );
        assert!(s[1].reason.contains("7 fish-frames"), "{s:?}");
        // Groups in simulation, pairs in reality: said too.
        assert!(arms(vec![four], vec![pair])[0]
            .what
            .contains("group metrics"));
    }

    #[test]
    fn trials_of_two_weights_under_one_name_are_not_one_condition() {
        let with = |sha: Option<&str>| TrialData {
            policy_sha256: sha.map(str::to_string),
            ..TrialData::blank("t.hdf5", 1)
        };
        let (a, b, none) = (with(Some("aaaa")), with(Some("bbbb")), with(None));
        // One set of weights, with or without trials that record none: one policy.
        assert_eq!(mixed_policies(&[&a, &a, &none]), None);
        assert_eq!(mixed_policies(&[&none]), None);
        let why = mixed_policies(&[&a, &b, &a, &none]).unwrap();
        assert!(
            why.contains("2 different policies")
                && why.contains("aaaa… in 2")
                && why.contains("bbbb… in 1"),
            "{why}"
        );
        // A further condition (reality, another model) against the own-model trials' weights.
        assert_eq!(weights_of(&[&none, &a]), Some("aaaa"));
        assert_eq!(weights_of(&[&none]), None);
        assert_eq!(other_weights(Some("aaaa"), &[&a, &none]), None);
        assert_eq!(other_weights(None, &[&b]), None);
        assert_eq!(other_weights(Some("aaaa"), &[&none]), None);
        let why = other_weights(Some("aaaa"), &[&b, &none]).unwrap();
        assert!(
            why.contains("driven by weights sha256 bbbb…")
                && why.contains("own-model trials by aaaa…"),
            "{why}"
        );
        assert!(other_weights(Some("aaaa"), &[&a, &b])
            .unwrap()
            .contains("2 different policies"));
    }
}
