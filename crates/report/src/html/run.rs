//! "What was run" and "Missing parts": the page's account of the study's inputs.

use super::*;

impl Page<'_> {
    /// What was run: policies, trial files per condition, the analysis settings.
    pub(super) fn what_was_run(&self, o: &mut String) {
        let d = self.data;
        let r = d.results.as_ref();
        // What was run.
        o.push_str("<h2 id=\"run\">What was run</h2>\n");
        if !d.training.is_empty() {
            let rows: Vec<Vec<String>> = d
                .training
                .iter()
                .map(|(m, log)| {
                    let p = log.params.as_ref();
                    let or_dash = |v: Option<String>| {
                        v.filter(|v| !v.is_empty()).unwrap_or_else(|| "–".into())
                    };
                    vec![
                        format!("π_{m}"),
                        or_dash(p.and_then(|p| p.seed).map(|s| s.to_string())),
                        or_dash(p.map(|p| p.preset.clone())),
                        log.rows
                            .last()
                            .map_or("–".into(), |r| format!("{:.0}", r.0)),
                        or_dash(p.map(|p| p.program_version.clone())),
                        r.and_then(|r| r.weights.get(m))
                            .map_or("–".into(), |w| format!("{}…", fishprobe_io::short_sha(w))),
                    ]
                })
                .collect();
            o.push_str(
                "<p>Policies (from <code>policies/&lt;Model&gt;/params.json</code>; the weights \
                 as the trials record them, <code>policy_sha256</code>):</p>",
            );
            table(
                o,
                &[
                    "policy",
                    "training seed",
                    "preset",
                    "environment steps",
                    "fishprobe",
                    "weights (SHA-256)",
                ],
                &rows,
            );
        }
        if !d.candidates.is_empty() {
            let rows: Vec<Vec<String>> = d
                .candidates
                .iter()
                .map(|(n, m, o)| vec![n.clone(), format!("M_{m}"), o.clone()])
                .collect();
            o.push_str("<p>Candidate models (from <code>study.json</code>), each with where it comes from:</p>");
            table(o, &["candidate", "model", "origin"], &rows);
        }
        if !d.conditions.is_empty() {
            let mut models: Vec<&str> = d.conditions.iter().map(|c| c.model.as_str()).collect();
            models.sort_by_key(|m| (Arm::from_label(m).is_reality(), *m));
            models.dedup();
            let mut policies: Vec<&str> = d.conditions.iter().map(|c| c.policy.as_str()).collect();
            policies.dedup();
            let mut header = vec!["policy".to_string()];
            header.extend(models.iter().map(|m| match Arm::from_label(m) {
                Arm::Real => "live fish".to_string(),
                Arm::VirtualLab => "VIRTUAL LAB".to_string(),
                Arm::Sim(m) => format!("M_{m}"),
            }));
            let rows: Vec<Vec<String>> = policies
                .iter()
                .map(|p| {
                    let mut row = vec![format!("π_{p}")];
                    row.extend(models.iter().map(|m| {
                        d.conditions
                            .iter()
                            .find(|c| c.policy == *p && c.model == *m)
                            .map_or("–".into(), |c| c.files.to_string())
                    }));
                    row
                })
                .collect();
            o.push_str(
                "<p>Trial files per condition (<code>rollouts/&lt;Policy&gt;__&lt;Model&gt;/</code>; \
                 rows: the policy, columns: the fish it was run with):</p>",
            );
            let h: Vec<&str> = header.iter().map(String::as_str).collect();
            table(o, &h, &rows);
            let mut notes: Vec<String> = d
                .conditions
                .iter()
                .filter(|c| Arm::from_label(&c.model).is_reality())
                .filter_map(|c| {
                    c.recorded.as_ref().map(|r| {
                        let dir = StudyLayout::arm_dir_name(&c.policy, &Arm::from_label(&c.model));
                        format!("{dir}: {r}")
                    })
                })
                .collect();
            notes.dedup();
            if !notes.is_empty() {
                o.push_str("<p class=\"small\">What the reality-arm files record (kind; set-up): ");
                o.push_str(&esc(&notes.join(" · ")));
                o.push_str("</p>\n");
            }
        }
        if let Some(res) = r {
            let c = &res.config;
            let _ = writeln!(
                o,
                "<p>Analysis: master seed {}, {} sim trials per policy, {} bootstrap replicates, {} \
                 permutations, {} % intervals.</p>",
                res.seed,
                c.sim_trials,
                c.bootstrap_reps,
                c.permutations,
                c.ci_level * 100.0
            );
        }
    }

    /// What is missing, unreadable or left out, and how to produce it.
    pub(super) fn missing(&self, o: &mut String) {
        let d = self.data;
        // Missing.
        o.push_str("<h2 id=\"missing\">Missing parts</h2>\n");
        if d.missing.is_empty() && d.unreadable.is_empty() && self.skipped().is_empty() {
            o.push_str("<p>Nothing: every part of the report has its inputs.</p>\n");
        } else {
            o.push_str("<div class=\"missing\"><ul>");
            for m in &d.missing {
                let _ = write!(
                    o,
                    "<li><b>{}</b>: {}. To produce it: <code>{}</code></li>",
                    esc(&m.what),
                    esc(&m.why),
                    esc(&m.remedy)
                );
            }
            for (p, why) in &d.unreadable {
                let _ = write!(
                    o,
                    "<li>unreadable: <code>{}</code>: {}</li>",
                    esc(&p.display().to_string()),
                    esc(why)
                );
            }
            for (what, why) in self.skipped() {
                let _ = write!(
                    o,
                    "<li>left out by the analysis: <code>{}</code>: {}</li>",
                    esc(&what),
                    esc(&why)
                );
            }
            o.push_str("</ul></div>\n");
        }
    }
}
