//! The tables of every training seed (`seeds.csv` and the summary's section), from the
//! `seeds` section of the results (the `seeds` module fills it).

use super::{f, table, SeedProbe};
use crate::config::AnalysisConfig;
use std::collections::BTreeMap;

/// `seeds.csv`: one row per policy and seed.
pub fn csv(seeds: &BTreeMap<String, Vec<SeedProbe>>) -> String {
    let rows = seeds
        .iter()
        .flat_map(|(p, rows)| {
            rows.iter().map(move |s| {
                let a = s.approach.as_ref();
                vec![
                    p.clone(),
                    s.seed.clone(),
                    f(s.goals),
                    s.episodes.to_string(),
                    f(s.ratio),
                    s.reach_s.map_or(String::new(), f),
                    a.map_or(String::new(), |a| f(a.min_iid)),
                    a.map_or(String::new(), |a| f(a.mean_iid)),
                    a.map_or(String::new(), |a| f(a.frac_closer_to_fish)),
                    s.goes_to_fish.to_string(),
                    s.ratio_se.map_or(String::new(), f),
                ]
            })
        })
        .collect();
    table(
        &[
            "policy",
            "seed",
            "goals",
            "episodes",
            "ratio_to_best_scripted",
            "reach_s",
            "min_iid_cm",
            "mean_iid_cm",
            "frac_closer_to_fish",
            "goes_to_fish",
            "ratio_se",
        ],
        rows,
    )
}

/// How many of a policy's seeds go to the fish, of those with an assay.
pub fn approach_count(rows: &[SeedProbe]) -> (usize, usize) {
    let assayed = rows.iter().filter(|s| s.approach.is_some()).count();
    (rows.iter().filter(|s| s.goes_to_fish).count(), assayed)
}

/// The summary's section: a table of every seed and, per policy, how many go to the fish.
pub fn summary_markdown(seeds: &BTreeMap<String, Vec<SeedProbe>>, cfg: &AnalysisConfig) -> String {
    let mut s = String::from(
        "## Every training seed: competence and the approach assay\n\n| policy | seed | goals (stability) | ratio to best scripted | reaches its fish (median s) | closest (cm) | nearer the fish | goes to the fish |\n|---|---|---|---|---|---|---|---|\n",
    );
    let num = |x: f64, d: usize| {
        if x.is_finite() {
            format!("{x:.d$}")
        } else {
            "–".into()
        }
    };
    for (p, rows) in seeds {
        for r in rows {
            let a = r.approach.as_ref();
            s += &format!(
                "| {p} | {} | {} | {} | {} | {} | {} | {} |\n",
                r.seed,
                num(r.goals, 1),
                num(r.ratio, 2) + &super::plus_minus(r.ratio_se),
                num(r.reach_s.unwrap_or(f64::NAN), 1),
                a.map_or("–".into(), |a| num(a.min_iid, 1)),
                a.map_or("–".into(), |a| format!(
                    "{} %",
                    num(100.0 * a.frac_closer_to_fish, 1)
                )),
                if a.is_none() {
                    "–"
                } else if r.goes_to_fish {
                    "yes"
                } else {
                    "no"
                },
            );
        }
    }
    s.push('\n');
    let counts: Vec<String> = seeds
        .iter()
        .filter_map(|(p, rows)| {
            let (yes, of) = approach_count(rows);
            (of > 0).then(|| format!("{p} in {yes} of {of}"))
        })
        .collect();
    if !counts.is_empty() {
        s += &format!(
            "Seeds that go to the still fish (closest ≤ {} cm and nearer it than the goal ≥ {:.0} % of the time): {}.\n\n",
            cfg.approach_closest_cm,
            100.0 * cfg.approach_nearer_share,
            counts.join("; ")
        );
    }
    s
}
