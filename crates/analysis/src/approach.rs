//! The approach assay (SPEC §8): the robot starts in a corner, a stationary fish and the goal
//! sit to its left and right; does the policy go to the fish first? Per policy, over all
//! frames of all its episodes: the minimum and mean robot-fish distance, and the fraction of
//! frames in which the robot is closer to the fish than to the goal.

use crate::config::AnalysisConfig;
use crate::results::{Approach, Results, Skipped};
use crate::study::StudyFiles;
use fishprobe_io::read_trial;
use std::collections::BTreeMap;
use std::path::Path;

/// One approach episode: the policy it names, the weights it records (`policy_sha256`), and
/// per frame (robot-fish, robot-goal) distance.
type Episode = (Option<String>, Option<String>, Vec<(f64, f64)>);

/// Reads one approach episode.
fn episode(path: &Path, cfg: &AnalysisConfig) -> Result<Episode, String> {
    let t = read_trial(path).map_err(|e| e.to_string())?;
    let robot = t.robot().ok_or("trial without a robot entity")?;
    let fish = t.fish().next().ok_or("trial without a fish entity")?;
    let goal = t
        .task
        .as_ref()
        .and_then(|k| k.goals.first().copied())
        .unwrap_or(cfg.approach_goal);
    let start = t.control_start();
    let frames = robot.frames().min(fish.frames());
    let d = (start..frames)
        .map(|i| {
            let (r, f) = (robot.positions[i], fish.positions[i]);
            let iid = f64::from(((r[0] - f[0]).powi(2) + (r[1] - f[1]).powi(2)).sqrt());
            let dg = f64::from(((r[0] - goal[0]).powi(2) + (r[1] - goal[1]).powi(2)).sqrt());
            (iid, dg)
        })
        .filter(|(a, b)| a.is_finite() && b.is_finite())
        .collect::<Vec<_>>();
    if d.is_empty() {
        return Err("no frame with both robot and fish tracked".into());
    }
    let task = t.task.as_ref();
    Ok((
        task.map(|k| k.policy.clone()),
        task.and_then(|k| k.policy_sha256()),
        d,
    ))
}

/// Fills `res.approach` from `STUDY/approach_test`.
pub fn approach(
    res: &mut Results,
    study: &StudyFiles,
    skipped: &mut Vec<Skipped>,
    cfg: &AnalysisConfig,
) {
    let mut per: BTreeMap<String, (Vec<(f64, f64)>, usize)> = BTreeMap::new();
    for (dir_policy, files) in &study.approach {
        for f in files {
            match episode(f, cfg) {
                Ok((file_policy, sha, d)) => {
                    let policy = if dir_policy.is_empty() {
                        file_policy.unwrap_or_default()
                    } else {
                        dir_policy.clone()
                    };
                    if policy.is_empty() {
                        skipped.push(Skipped {
                            what: f.display().to_string(),
                            reason: "approach file names no policy".into(),
                        });
                        continue;
                    }
                    // Another policy's weights under this name (a policy retrained since its
                    // trials were recorded): not this policy's assay.
                    if let (Some(own), Some(sha)) = (res.weights.get(&policy), &sha) {
                        if own != sha {
                            skipped.push(Skipped {
                                what: f.display().to_string(),
                                reason: format!(
                                    "{}: not counted in {policy}'s approach assay",
                                    crate::conditions::driven_by_other(own, sha)
                                ),
                            });
                            continue;
                        }
                    }
                    let e = per.entry(policy).or_default();
                    e.0.extend(d);
                    e.1 += 1;
                }
                Err(reason) => skipped.push(Skipped {
                    what: f.display().to_string(),
                    reason,
                }),
            }
        }
    }
    for (p, (d, episodes)) in per {
        res.approach.insert(p, summary(&d, episodes));
    }
}

/// The assay's measures over all frames of all episodes: (robot-fish, robot-goal) distance
/// per frame.
fn summary(d: &[(f64, f64)], episodes: usize) -> Approach {
    let n = d.len() as f64;
    Approach {
        min_iid: d.iter().map(|x| x.0).fold(f64::INFINITY, f64::min),
        mean_iid: d.iter().map(|x| x.0).sum::<f64>() / n,
        frac_closer_to_fish: d.iter().filter(|x| x.0 < x.1).count() as f64 / n,
        episodes,
    }
}

/// The assay's measures over the approach episodes in `files` (as `fishprobe assay approach`
/// reports them for one policy); an unreadable file is an error naming it.
pub fn assay_files(
    files: &[std::path::PathBuf],
    cfg: &AnalysisConfig,
) -> Result<Approach, crate::AnalysisError> {
    let mut d = Vec::new();
    for f in files {
        let (_, _, e) = episode(f, cfg).map_err(|why| format!("{}: {why}", f.display()))?;
        d.extend(e);
    }
    if d.is_empty() {
        return Err("no approach episodes".into());
    }
    Ok(summary(&d, files.len()))
}
