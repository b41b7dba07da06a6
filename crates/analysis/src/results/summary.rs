//! The results as a short Markdown summary.

use super::Results;

impl Results {
    /// A short Markdown summary for terminals and lab notebooks.
    pub fn summary_markdown(&self) -> String {
        let mut s = String::from("# fishprobe analysis\n\n");
        match self.reality.as_deref() {
            Some(fishprobe_io::layout::VIRTUAL_LAB) => {
                s += "**Reality arm: VIRTUAL LAB.** These are not live-fish results.\n\n"
            }
            Some(r) => s += &format!("Reality arm: {r}.\n\n"),
            None => s += "No reality arm (no `<P>__Real` or `<P>__VirtualLab` trials).\n\n",
        }
        if !self.weights.is_empty() {
            let each: Vec<String> = self
                .weights
                .iter()
                .map(|(p, w)| format!("{p} `{}…`", fishprobe_io::short_sha(w)))
                .collect();
            s += &format!(
                "Weights that drove the trials (SHA-256): {}.\n\n",
                each.join(", ")
            );
        }
        if !self.sim_to_real.is_empty() {
            s += &self.sim_to_real_markdown();
        }
        if !self.competence.is_empty() {
            s += &self.competence_markdown();
        }
        if !self.seeds.is_empty() {
            s += &super::seeds_table::summary_markdown(&self.seeds, &self.config);
        }
        if !self.mean_ranks.is_empty() {
            let pairs = crate::count_word(crate::METRICS.len());
            let over = if self.metric_gaps.len() > crate::METRICS.len() {
                format!("the {pairs} pair and the group metrics")
            } else {
                format!("the {pairs} metrics")
            };
            s += &format!("## Per-metric gaps: mean rank over {over} (1 = closest to reality)\n\n| policy | mean rank |\n|---|---|\n");
            for (p, r) in &self.mean_ranks {
                s += &format!("| {p} | {r:.2} |\n");
            }
            s.push('\n');
        }
        if !self.spread.is_empty() {
            s += &self.spread_markdown();
        }
        if !self.kruskal.is_empty() {
            s += "## Sim-to-sim: Kruskal-Wallis across rollout models\n\n| policy | H | p |\n|---|---|---|\n";
            for (p, k) in &self.kruskal {
                s += &format!("| {p} | {:.2} | {:.2e} |\n", k.h, k.p);
            }
            s.push('\n');
        }
        if let Some(st) = &self.stability {
            s += &format!(
                "## Retraining stability\n\nR = {:.2} [{:.2}, {:.2}], p = {:.4}\n\n",
                st.r, st.ci[0], st.ci[1], st.p
            );
        }
        if !self.skipped.is_empty() {
            s += &format!("## Skipped ({})\n\n", self.skipped.len());
            for k in &self.skipped {
                s += &format!("- {}: {}\n", k.what, k.reason);
            }
        }
        s
    }

    /// The sim-to-real gap of the goals, a row per policy.
    fn sim_to_real_markdown(&self) -> String {
        let mut s = String::from(
            "## Sim-to-real gap, goals reached\n\n| policy | sim mean | real mean | W | 95 % CI | p | Cliff's δ |\n|---|---|---|---|---|---|---|\n");
        for (p, g) in &self.sim_to_real {
            let mean =
                |v: &[u32]| v.iter().map(|&x| f64::from(x)).sum::<f64>() / v.len().max(1) as f64;
            let pair = &self.goals[p];
            s += &format!(
                "| {p} | {:.1} | {:.1} | {:.2} | [{:.2}, {:.2}] | {:.4} | {:.2} ({}) |\n",
                mean(&pair.sim),
                mean(&pair.real),
                g.w,
                g.ci[0],
                g.ci[1],
                g.p,
                g.cliffs_delta,
                g.magnitude
            );
        }
        s.push('\n');
        s
    }

    /// The between-trial spread: quantities as rows, policies as columns, the s.d. ratio
    /// sim / real with its interval; a headline per policy in words.
    fn spread_markdown(&self) -> String {
        let ratio = |x: f64| match x {
            x if x.is_finite() => format!("{x:.2}"),
            x if x == f64::INFINITY => "∞".into(),
            _ => "–".into(),
        };
        let policies: Vec<&String> = {
            let mut p: Vec<&String> = self.spread.values().flat_map(|m| m.keys()).collect();
            p.sort();
            p.dedup();
            p
        };
        let mut s = String::from(
            "## Between-trial spread: s.d. of the sim trials / s.d. of the real trials\n\n\
             How much the simulated trials differ from one another, as a share of how much the \
             real ones do (1: as varied as reality); [95 % bootstrap CI]; \\* the spreads differ \
             (Brown–Forsythe, Holm-adjusted across policies, p < 0.05).\n\n| per trial |",
        );
        for p in &policies {
            s += &format!(" π_{p} |");
        }
        s += "\n|---|";
        s += &"---|".repeat(policies.len());
        s.push('\n');
        for q in crate::spread::quantities() {
            let Some(per) = self.spread.get(q.id()) else {
                continue;
            };
            s += &format!("| {} |", q.label().replace('|', "\\|"));
            for p in &policies {
                s += &per.get(*p).map_or(" – |".into(), |e| {
                    format!(
                        " {} [{}, {}]{} |",
                        ratio(e.ratio),
                        ratio(e.ci[0]),
                        ratio(e.ci[1]),
                        if e.bf_p_holm < 0.05 { " \\*" } else { "" }
                    )
                });
            }
            s.push('\n');
        }
        if let Some(goals) = self.spread.get("goals") {
            let arm = match self.reality.as_deref() {
                Some(fishprobe_io::layout::VIRTUAL_LAB) => "virtual-lab",
                _ => "live",
            };
            s.push('\n');
            for (p, e) in goals {
                s += &format!(
                    "π_{p}: {}.\n",
                    crate::spread::spread_sentence(e, "in goals", arm)
                );
            }
        }
        s.push('\n');
        s
    }

    /// Probe competence, a row per policy, with what the columns mean and a warning naming
    /// the weak probes (and those within two standard errors of the bar).
    fn competence_markdown(&self) -> String {
        let mut s = String::from(
            "## Probe competence: goals on the own model, next to the best scripted controller\n\n| policy | goals | best scripted | its goals | ratio | reaches its fish (median s) | scripted controllers reach it (median s) |\n|---|---|---|---|---|---|---|\n");
        for (p, c) in &self.competence {
            let scripted: Vec<String> = c
                .baselines_reach_s
                .iter()
                .map(|(b, t)| format!("{b} {t:.1}"))
                .collect();
            s += &format!(
                "| {p} | {:.1} | {} | {:.1} | {:.2}{}{} | {} | {} |\n",
                c.policy_goals,
                c.best,
                c.best_goals,
                c.ratio,
                super::plus_minus(c.ratio_se),
                if c.weak { " **weak**" } else { "" },
                c.reach_s.map_or("–".into(), |t| format!("{t:.1}")),
                if scripted.is_empty() {
                    "–".into()
                } else {
                    scripted.join(", ")
                },
            );
        }
        s += &format!(
            "\nThe ratio's ± is its standard error over the episodes (delta method): a ratio \
             within about two of them of the bar is not clearly on either side. \
             Reaching the fish: the first moment a fish is within {} cm of the robot. A probe \
             that takes as long as GoalSeeker waits at the goal for its fish to come by; one \
             near FetchAndLead fetches it. The goal count hides the difference when the probe \
             holds the fish once it has it.\n",
            self.config.robot_reach_cm
        );
        let weak: Vec<&str> = self
            .competence
            .iter()
            .filter(|(_, c)| c.weak)
            .map(|(p, _)| p.as_str())
            .collect();
        if !weak.is_empty() {
            s += &format!(
                "\n**Warning:** {} reach{} less than {:.0} % of the best scripted controller's goals on \
                 {} own model: {} strateg{} reflect{} the optimiser, not only the model.\n",
                weak.join(", "),
                if weak.len() == 1 { "es" } else { "" },
                100.0 * self.config.competence_threshold,
                if weak.len() == 1 { "its" } else { "their" },
                if weak.len() == 1 { "its" } else { "their" },
                if weak.len() == 1 { "y" } else { "ies" },
                if weak.len() == 1 { "s" } else { "" },
            );
            // Weak by less than two standard errors: the measurement cannot tell.
            let near: Vec<String> = self
                .competence
                .iter()
                .filter(|(_, c)| c.weak)
                .filter_map(|(p, c)| {
                    let se = c.ratio_se?;
                    (c.ratio + 2.0 * se >= self.config.competence_threshold)
                        .then(|| format!("{p} ({:.2} ± {se:.2})", c.ratio))
                })
                .collect();
            if !near.is_empty() {
                s += &format!(
                    "Within two standard errors of the bar, so not clearly below it: {}; more evaluation episodes would tell.\n",
                    near.join(", ")
                );
            }
        }
        s.push('\n');
        s
    }
}
