//! The paper's tables, each with its figure: sim-to-real, per-metric gaps, sim-to-sim,
//! temporal trend, time to goal, competence, approach assay, every seed, stability.

use super::*;

impl Page<'_> {
    /// The sim-to-real gap in goals reached (table and figure).
    pub(super) fn sim_to_real(&self, o: &mut String) {
        let d = self.data;
        let r = d.results.as_ref();
        // Sim-to-real, goals.
        o.push_str("<h2 id=\"sim-to-real\">Sim-to-real gap in goals reached</h2>\n");
        if let Some(res) = r.filter(|x| !x.sim_to_real.is_empty()) {
            let rows: Vec<Vec<String>> = res
                .sim_to_real
                .iter()
                .map(|(p, g)| {
                    let pair = res.goals.get(p);
                    let goals = |v: &[u32]| v.iter().map(|&x| f64::from(x)).collect::<Vec<f64>>();
                    let sim = pair.map_or_else(Vec::new, |x| goals(&x.sim));
                    let real = pair.map_or_else(Vec::new, |x| goals(&x.real));
                    vec![
                        format!("π_{p}"),
                        f(mean(&sim), 1),
                        f(mean(&real), 1),
                        f(g.w, 2),
                        ci(&g.ci, 2),
                        p_fmt(g.p),
                        format!(
                            "{} ({})",
                            f(g.cliffs_delta, 2),
                            if g.magnitude.is_empty() {
                                "–"
                            } else {
                                &g.magnitude
                            }
                        ),
                        format!("{} / {}", g.n_sim, g.n_real),
                    ]
                })
                .collect();
            let virtual_arm = d.arm.as_deref() == Some(VIRTUAL_LAB);
            let (mean_h, trials_h) = if virtual_arm {
                ("virtual-lab mean", "trials sim / virtual")
            } else {
                ("real mean", "trials sim / real")
            };
            table(
                o,
                &[
                    "policy",
                    "sim mean",
                    mean_h,
                    "W",
                    "95 % CI",
                    "p (one-sided)",
                    "Cliff's δ",
                    trials_h,
                ],
                &rows,
            );
            o.push_str("<p class=\"small\">W: 1-Wasserstein distance between the per-trial goal counts of simulation and reality; CI: percentile bootstrap; p: permutation test of W; Cliff's δ = P(sim &gt; real) − P(sim &lt; real).</p>\n");
        } else {
            o.push_str("<p class=\"missing\">Needs simulation and reality-arm trials and <code>fishprobe analyze</code>.</p>\n");
        }
        self.fig(o, "goals");
    }

    /// The per-metric gaps and ranks (table and heatmap).
    pub(crate) fn metric_gaps(&self, o: &mut String) {
        let d = self.data;
        let r = d.results.as_ref();
        // Per-metric gaps.
        o.push_str("<h2 id=\"metrics\">Per-metric sim-to-real gaps and ranks</h2>\n");
        if let Some(res) = r.filter(|x| !x.metric_gaps.is_empty()) {
            let mg = &res.metric_gaps;
            let mut policies: Vec<String> = mg.values().flat_map(|m| m.keys().cloned()).collect();
            policies.sort();
            policies.dedup();
            let mut header = vec!["metric".to_string()];
            header.extend(policies.iter().map(|p| format!("π_{p}")));
            let rows: Vec<Vec<String>> = ALL_METRICS
                .iter()
                .zip(METRIC_LABELS)
                .filter_map(|(m, label)| {
                    let per = mg.get(*m)?;
                    let mut row = vec![label.to_string()];
                    for p in &policies {
                        row.push(match per.get(p) {
                            Some(c) => format!(
                                "{} {} (rank {})",
                                f(c.median, 2),
                                ci(&c.ci, 2),
                                f(c.rank, 1)
                            ),
                            None => "–".into(),
                        });
                    }
                    Some(row)
                })
                .chain(std::iter::once({
                    let mut row = vec!["mean rank".to_string()];
                    for p in &policies {
                        row.push(f(res.mean_ranks.get(p).copied().unwrap_or(f64::NAN), 2));
                    }
                    row
                }))
                .collect();
            let h: Vec<&str> = header.iter().map(String::as_str).collect();
            table(o, &h, &rows);
        } else {
            o.push_str("<p class=\"missing\">Needs reality-arm trials and <code>fishprobe analyze</code>.</p>\n");
        }
        self.fig(o, "gap_heatmap");
    }

    /// Sim-to-sim: each policy on each model, and Kruskal-Wallis.
    pub(super) fn sim_to_sim(&self, o: &mut String) {
        let d = self.data;
        let r = d.results.as_ref();
        // Sim-to-sim.
        o.push_str(
            "<h2 id=\"sim-to-sim\">Sim-to-sim: do the models teach different strategies?</h2>\n",
        );
        if let Some(res) = r.filter(|x| !x.sim_to_sim.is_empty()) {
            let rows: Vec<Vec<String>> = res
                .sim_to_sim
                .iter()
                .flat_map(|(p, per)| {
                    per.iter().map(move |(m, c)| {
                        vec![
                            format!("π_{p}"),
                            format!("M_{m}"),
                            f(c.median, 2),
                            ci(&c.ci, 2),
                            c.p_holm.map_or("(diagonal)".into(), p_fmt),
                        ]
                    })
                })
                .collect();
            table(
                o,
                &["policy", "rollout model", "median W", "95 % CI", "p (Holm)"],
                &rows,
            );
            if !res.kruskal.is_empty() {
                let rows: Vec<Vec<String>> = res
                    .kruskal
                    .iter()
                    .map(|(p, v)| vec![format!("π_{p}"), f(v.h, 2), p_fmt(v.p)])
                    .collect();
                o.push_str("<p>Kruskal-Wallis across rollout models (goals per episode):</p>");
                table(o, &["policy", "H", "p"], &rows);
            }
        } else {
            o.push_str("<p class=\"missing\">Needs rollouts of each policy on the other models (<code>rollouts/&lt;P&gt;__&lt;M&gt;/</code>) and <code>fishprobe analyze</code>.</p>\n");
        }
        self.fig(o, "sim_to_sim");
    }

    /// Goals per minute over time (negative-binomial trends).
    pub(super) fn temporal(&self, o: &mut String) {
        let d = self.data;
        let r = d.results.as_ref();
        // Temporal.
        o.push_str("<h2 id=\"temporal\">Goals per minute over time</h2>\n");
        let temporal = r.map(|x| &x.temporal).filter(|t| !t.is_empty());
        if let Some(t) = temporal {
            let rows: Vec<Vec<String>> = t
                .iter()
                .flat_map(|(arm, per)| {
                    per.iter().map(move |(p, v)| {
                        vec![
                            arm.clone(),
                            if p == "total" {
                                "all policies".into()
                            } else {
                                format!("π_{p}")
                            },
                            f(v.rate_ratio, 3),
                            ci(&v.ci, 3),
                            p_fmt(v.p),
                            f(v.alpha, 3),
                        ]
                    })
                })
                .collect();
            table(
                o,
                &[
                    "arm",
                    "policy",
                    "rate ratio per minute",
                    "95 % CI",
                    "p",
                    "NB2 α",
                ],
                &rows,
            );
            o.push_str("<p class=\"small\">Negative-binomial (NB2) regression of goals per minute on the minute of control, standard errors clustered by trial. A rate ratio below 1 means goals become rarer as the trial goes on.</p>\n");
        }
        if !self.fig(o, "goals_over_time") && temporal.is_none() {
            o.push_str("<p class=\"missing\">Needs trials with at least one complete minute of control.</p>\n");
        }
    }

    /// Time to goal.
    pub(super) fn time_to_goal(&self, o: &mut String) {
        let d = self.data;
        let r = d.results.as_ref();
        // Time to goal.
        o.push_str("<h2 id=\"time-to-goal\">Time to goal</h2>\n");
        if let Some(t) = r.map(|x| &x.time_to_goal).filter(|t| !t.is_empty()) {
            let cell = |v: &Option<MeanSd>| match v {
                Some(m) => format!("{} ± {} (n = {})", f(m.mean, 1), f(m.sd, 1), m.n),
                None => "–".into(),
            };
            let rows: Vec<Vec<String>> = t
                .iter()
                .map(|(p, v)| vec![format!("π_{p}"), cell(&v.sim), cell(&v.real)])
                .collect();
            table(
                o,
                &["policy", "sim (s, mean ± s.d. of trial means)", "real (s)"],
                &rows,
            );
        } else {
            o.push_str("<p class=\"missing\">Needs <code>fishprobe analyze</code>.</p>\n");
        }
    }

    /// Probe competence: each policy's goals on its own model next to the scripted
    /// controllers' on the same episodes.
    pub(super) fn competence(&self, o: &mut String) {
        let Some(c) = self
            .data
            .results
            .as_ref()
            .map(|r| (&r.competence, r.config.competence_threshold))
            .filter(|(c, _)| !c.is_empty())
        else {
            return;
        };
        let (c, threshold) = c;
        o.push_str("<h2 id=\"competence\">Probe competence</h2>\n<p>Goals per evaluation episode of each policy on its own model, next to fishprobe's scripted controllers on the same episodes (<code>baselines/</code>): <i>GoalSeeker</i> drives to the goal, <i>FetchAndLead</i> fetches the fish and keeps ahead of it on its line to the goal. A policy below ");
        let _ = write!(o, "{:.0} %", 100.0 * threshold);
        o.push_str(" of the best is marked weak: it has not found what its model allows, and its strategy (approach assay, sim-to-sim) reflects the optimiser as much as the model. The ratio's ± is its standard error over the episodes (delta method): a ratio within about two of them of the bar is not clearly on either side. ");
        if let Some(r) = self.data.results.as_ref() {
            let _ = write!(
                o,
                "<i>Reaches its fish</i>: the median time until a fish is first within {} cm of the robot. A probe that takes as long as GoalSeeker waits at the goal for its fish to come by; one near FetchAndLead fetches it. The goal count hides the difference when the probe holds the fish once it has it.",
                r.config.robot_reach_cm
            );
        }
        o.push_str("</p>\n");
        let names: Vec<&String> = c
            .values()
            .flat_map(|x| x.baselines.keys())
            .collect::<std::collections::BTreeSet<_>>()
            .into_iter()
            .collect();
        let rows: Vec<Vec<String>> = c
            .iter()
            .map(|(p, v)| {
                let mut row = vec![format!("π_{p}"), f(v.policy_goals, 1)];
                row.extend(
                    names
                        .iter()
                        .map(|n| v.baselines.get(*n).map_or("–".into(), |g| f(*g, 1))),
                );
                row.push(format!(
                    "{}{}{}",
                    f(v.ratio, 2),
                    fishprobe_analysis::competence::plus_minus(v.ratio_se),
                    if v.weak { " (weak)" } else { "" }
                ));
                row.push(v.reach_s.map_or("–".into(), |t| f(t, 1)));
                row.extend(
                    names
                        .iter()
                        .map(|n| v.baselines_reach_s.get(*n).map_or("–".into(), |t| f(*t, 1))),
                );
                row
            })
            .collect();
        let reach_headers: Vec<String> = names
            .iter()
            .map(|n| format!("{n} reaches it (s)"))
            .collect();
        let mut header = vec!["policy", "goals"];
        header.extend(names.iter().map(|n| n.as_str()));
        header.push("ratio to best");
        header.push("reaches its fish (median s)");
        header.extend(reach_headers.iter().map(String::as_str));
        table(o, &header, &rows);
    }

    /// The approach assay.
    pub(super) fn approach(&self, o: &mut String) {
        let d = self.data;
        let r = d.results.as_ref();
        // Approach.
        o.push_str("<h2 id=\"approach\">Approach assay</h2>\n");
        let approach = r.map(|x| &x.approach).filter(|a| !a.is_empty());
        if let Some(a) = approach {
            let rows: Vec<Vec<String>> = a
                .iter()
                .map(|(p, v)| {
                    vec![
                        format!("π_{p}"),
                        f(v.min_iid, 1),
                        f(v.mean_iid, 1),
                        f(v.frac_closer_to_fish, 3),
                        v.episodes.to_string(),
                    ]
                })
                .collect();
            table(
                o,
                &[
                    "policy",
                    "min distance to fish (cm)",
                    "mean distance (cm)",
                    "fraction closer to fish than goal",
                    "episodes",
                ],
                &rows,
            );
        }
        if !self.fig(o, "approach") && approach.is_none() {
            o.push_str("<p class=\"missing\">No approach-assay episodes (<code>approach_test/&lt;Policy&gt;/</code>).</p>\n");
        }
        self.seeds(o);
    }

    /// Every training seed: competence and the approach assay of each, so that a strategy
    /// seed 0 happens to find (or miss) is told from the model's.
    pub(super) fn seeds(&self, o: &mut String) {
        let Some(r) = self.data.results.as_ref().filter(|r| !r.seeds.is_empty()) else {
            return;
        };
        let cfg = &r.config;
        o.push_str("<h3 id=\"seeds\">Every training seed</h3>\n<p>The table and figure above show each policy, seed 0. The study trains every model's policy with more seeds (retraining stability); here each of them on its own model (goals per stability episode, against the best scripted controller's goals on the model's evaluation episodes) and in the approach assay. ");
        let _ = write!(
            o,
            "A seed goes to the still fish when it comes within {} cm of it and is nearer it than the goal at least {:.0} % of the time.",
            cfg.approach_closest_cm,
            100.0 * cfg.approach_nearer_share
        );
        let counts: Vec<String> = r
            .seeds
            .iter()
            .filter_map(|(p, rows)| {
                let (yes, of) = fishprobe_analysis::seeds::approach_count(rows);
                (of > 0).then(|| format!("π_{p} in {yes} of {of}"))
            })
            .collect();
        if !counts.is_empty() {
            let _ = write!(
                o,
                " Seeds that go to the fish: {}.",
                esc(&counts.join("; "))
            );
        }
        o.push_str("</p>\n");
        let rows: Vec<Vec<String>> = r
            .seeds
            .iter()
            .flat_map(|(p, rows)| {
                rows.iter().map(move |s| {
                    let a = s.approach.as_ref();
                    vec![
                        format!("π_{p}"),
                        s.seed.clone(),
                        f(s.goals, 1),
                        f(s.ratio, 2) + &fishprobe_analysis::competence::plus_minus(s.ratio_se),
                        s.reach_s.map_or("–".into(), |t| f(t, 1)),
                        a.map_or("–".into(), |a| f(a.min_iid, 1)),
                        a.map_or("–".into(), |a| f(a.frac_closer_to_fish, 3)),
                        match (a, s.goes_to_fish) {
                            (None, _) => "–".into(),
                            (Some(_), true) => "yes".into(),
                            (Some(_), false) => "no".into(),
                        },
                    ]
                })
            })
            .collect();
        table(
            o,
            &[
                "policy",
                "seed",
                "goals (stability)",
                "ratio to best scripted",
                "reaches its fish (median s)",
                "min distance to fish (cm)",
                "fraction closer to fish than goal",
                "goes to the fish",
            ],
            &rows,
        );
    }

    /// Retraining stability.
    pub(super) fn stability(&self, o: &mut String) {
        let d = self.data;
        let r = d.results.as_ref();
        // Stability.
        o.push_str("<h2 id=\"stability\">Retraining stability</h2>\n");
        match r.and_then(|x| x.stability.as_ref()) {
            Some(s) => {
                let _ = writeln!(
                    o,
                    "<p>R = σ²<sub>between models</sub> / σ²<sub>within model (seeds)</sub> = <b>{}</b> {}, permutation p = {}. \
                     R well above 1 means that which model a policy was trained on matters more than the training seed.</p>",
                    f(s.r, 2),
                    ci(&s.ci, 2),
                    p_fmt(s.p)
                );
            }
            None => o.push_str("<p class=\"missing\">Needs <code>stability/&lt;Model&gt;/&lt;seed&gt;/</code> episodes and <code>fishprobe analyze</code>.</p>\n"),
        }
    }
}
