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

/// The trials of a reality arm that were recorded under one protocol, and the others named in
/// `skipped`: a trial recorded at another frame rate, in another tank, without fishprobe's
/// task record (a foreign recording) or with another `experiment_setup` than most of the
/// arm's, or whose control phase differs from the arm's median by more than
/// `tolerance_s`, is not one more trial of that protocol. The arm is its largest group
/// (ties: the group with fishprobe's task record, then the one whose first file comes
/// first); an arm of foreign recordings alone is one protocol and is kept whole, whatever
/// their lengths: a recording without fishprobe's task record has no control phase whose
/// length the protocol fixes.
pub(crate) fn one_protocol<'a>(
    what: &str,
    trials: Vec<&'a TrialData>,
    tolerance_s: f64,
    skipped: &mut Vec<Skipped>,
) -> Vec<&'a TrialData> {
    use crate::trial::TrialProtocol;
    fn same(a: &TrialProtocol, b: &TrialProtocol) -> bool {
        a.frame_rate_hz == b.frame_rate_hz
            && a.world_size_cm == b.world_size_cm
            && a.has_task == b.has_task
            && a.setup == b.setup
    }
    let mut groups: Vec<Vec<&'a TrialData>> = Vec::new();
    for t in trials {
        match groups
            .iter_mut()
            .find(|g| same(&g[0].protocol, &t.protocol))
        {
            Some(g) => g.push(t),
            None => groups.push(vec![t]),
        }
    }
    let Some(best) = (0..groups.len()).max_by(|&a, &b| {
        let key = |g: &Vec<&TrialData>| (g.len(), g[0].protocol.has_task);
        key(&groups[a])
            .cmp(&key(&groups[b]))
            .then_with(|| groups[b][0].path.cmp(&groups[a][0].path))
    }) else {
        return Vec::new();
    };
    let arm = groups.swap_remove(best);
    let mut lengths: Vec<f64> = arm.iter().map(|t| t.protocol.control_s).collect();
    lengths.sort_by(f64::total_cmp);
    let median = lengths[lengths.len() / 2];
    let norm = arm[0].protocol.clone();
    let describe = |p: &TrialProtocol| {
        format!(
            "{} Hz, a {} x {} cm tank, {}, set-up {}, {:.1} min of control",
            p.frame_rate_hz,
            p.world_size_cm[0],
            p.world_size_cm[1],
            if p.has_task {
                "fishprobe's task record"
            } else {
                "no fishprobe task record (a foreign recording)"
            },
            p.setup
                .as_deref()
                .map_or_else(|| "not given".to_string(), |s| format!("{s:?}")),
            p.control_s / 60.0
        )
    };
    let (kept, long_or_short): (Vec<&TrialData>, Vec<&TrialData>) = arm
        .into_iter()
        .partition(|t| !norm.has_task || (t.protocol.control_s - median).abs() <= tolerance_s);
    let n = kept.len();
    let arm_is = |p: &TrialProtocol| {
        let mut norm = norm.clone();
        norm.control_s = median;
        format!(
            "recorded with {}; the arm's {n} other trials with {}",
            describe(p),
            describe(&norm)
        )
    };
    for t in long_or_short
        .iter()
        .copied()
        .chain(groups.iter().flatten().copied())
    {
        skipped.push(Skipped {
            what: t.path.display().to_string(),
            reason: format!(
                "left out of {what}, which must hold one protocol: {}",
                arm_is(&t.protocol)
            ),
        });
    }
    kept
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
    fn a_mixed_reality_arm_keeps_its_protocol_and_names_the_rest() {
        use crate::trial::TrialProtocol;
        let ours = TrialProtocol {
            frame_rate_hz: 25.0,
            world_size_cm: [100.0, 100.0],
            has_task: true,
            setup: Some("fishprobe live bridge".into()),
            control_s: 900.0,
        };
        let at = |path: &str, p: TrialProtocol| TrialData {
            protocol: p,
            ..TrialData::blank(path, 1)
        };
        let foreign = TrialProtocol {
            frame_rate_hz: 20.0,
            has_task: false,
            setup: None,
            control_s: 668.8,
            ..ours.clone()
        };
        let trials = [
            at("a.hdf5", ours.clone()),
            at("b.hdf5", ours.clone()),
            at(
                "c.hdf5",
                TrialProtocol {
                    control_s: 899.0,
                    ..ours.clone()
                },
            ),
            at(
                "short.hdf5",
                TrialProtocol {
                    control_s: 600.0,
                    ..ours.clone()
                },
            ),
            at("robot.hdf5", foreign.clone()),
        ];
        let mut skipped = Vec::new();
        let kept = one_protocol("Zone__Real", trials.iter().collect(), 2.0, &mut skipped);
        let names: Vec<_> = kept.iter().map(|t| t.path.display().to_string()).collect();
        assert_eq!(names, ["a.hdf5", "b.hdf5", "c.hdf5"]);
        assert_eq!(skipped.len(), 2, "{skipped:?}");
        assert_eq!(skipped[0].what, "short.hdf5");
        assert!(
            skipped[0].reason.contains("10.0 min of control"),
            "{skipped:?}"
        );
        assert_eq!(skipped[1].what, "robot.hdf5");
        for needle in [
            "20 Hz",
            "a foreign recording",
            "11.1 min",
            "25 Hz",
            "15.0 min",
        ] {
            assert!(skipped[1].reason.contains(needle), "{needle}: {skipped:?}");
        }
        // An arm of foreign recordings alone is one protocol, whatever their lengths.
        let longer = TrialProtocol {
            control_s: 720.0,
            ..foreign.clone()
        };
        let only = [at("r1.hdf5", foreign), at("r2.hdf5", longer)];
        let mut none = Vec::new();
        assert_eq!(
            one_protocol("Zone__Real", only.iter().collect(), 2.0, &mut none).len(),
            2
        );
        assert!(none.is_empty());
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
