//! The HTML page and the Markdown summary.

use crate::data::StudyData;
use crate::figures::{Figure, METRIC_LABELS};
use crate::svg::esc;
use base64::Engine as _;
use fishprobe_analysis::results::MeanSd;
use fishprobe_analysis::ALL_METRICS;
use fishprobe_io::layout::{Arm, StudyLayout, VIRTUAL_LAB};
use fishprobe_stats::sample::mean;
use serde_json::Value;
use std::fmt::Write as _;
use std::path::Path;

const STYLE: &str = r#"
body { font-family: "DejaVu Sans", "Helvetica Neue", Arial, sans-serif; max-width: 1100px; margin: 0 auto; padding: 1em 2em 4em; color: #111; line-height: 1.45; }
h1 { margin-bottom: 0.1em; } h2 { border-bottom: 1px solid #ccc; padding-bottom: 0.2em; margin-top: 2em; }
table { border-collapse: collapse; margin: 0.8em 0; font-size: 0.9em; }
th, td { border: 1px solid #ccc; padding: 0.25em 0.6em; text-align: right; }
th { background: #f0f0f0; } td:first-child, th:first-child { text-align: left; }
figure { margin: 1.2em 0; } figure img { max-width: 100%; border: 1px solid #ddd; }
figcaption { font-size: 0.9em; color: #333; margin-top: 0.4em; }
.banner { background: #fff3cd; border: 3px solid #b8860b; padding: 0.8em 1em; font-size: 1.15em; font-weight: bold; }
.missing { background: #f6f6f6; border-left: 4px solid #999; padding: 0.5em 1em; }
code { background: #f3f3f3; padding: 0 0.25em; }
nav ul { columns: 2; } .small { font-size: 0.85em; color: #555; }
"#;

const CHECK_SCRIPT: &str = r#"
window.addEventListener('load', function () {
  var imgs = Array.prototype.slice.call(document.images);
  var broken = imgs.filter(function (i) { return !i.complete || i.naturalWidth === 0; });
  broken.forEach(function (i) { console.error('broken image: ' + i.alt); });
  document.body.setAttribute('data-images', String(imgs.length));
  document.body.setAttribute('data-broken-images', String(broken.length));
  if (broken.length) {
    var p = document.getElementById('broken');
    p.hidden = false;
    p.textContent = broken.length + ' figure(s) failed to display.';
  }
});
"#;

fn f(v: f64, digits: usize) -> String {
    if v.is_finite() {
        format!("{v:.digits$}")
    } else {
        "–".into()
    }
}

fn p_fmt(p: f64) -> String {
    if !p.is_finite() {
        "–".into()
    } else if p < 0.001 {
        format!("{p:.1e}")
    } else {
        format!("{p:.4}")
    }
}

fn ci(v: &[f64; 2], digits: usize) -> String {
    format!("[{}, {}]", f(v[0], digits), f(v[1], digits))
}

fn table(out: &mut String, header: &[&str], rows: &[Vec<String>]) {
    out.push_str("<table><thead><tr>");
    for h in header {
        let _ = write!(out, "<th>{}</th>", esc(h));
    }
    out.push_str("</tr></thead><tbody>");
    for r in rows {
        out.push_str("<tr>");
        for c in r {
            let _ = write!(out, "<td>{}</td>", esc(c));
        }
        out.push_str("</tr>");
    }
    out.push_str("</tbody></table>\n");
}

fn figure(out: &mut String, fig: &Figure, portable_svg: &str) {
    let b64 = base64::engine::general_purpose::STANDARD.encode(portable_svg.as_bytes());
    let _ = writeln!(
        out,
        "<figure id=\"fig-{name}\"><img alt=\"{title}\" src=\"data:image/svg+xml;base64,{b64}\">\
         <figcaption><b>{title}.</b> {caption} <span class=\"small\">Files: \
         <a href=\"figures/{name}.svg\">SVG</a>, <a href=\"figures/{name}.png\">PNG</a>.</span>\
         </figcaption></figure>",
        name = fig.name,
        title = esc(&fig.title),
        caption = esc(&fig.caption),
    );
}

/// A link target for `file` as seen from the report directory.
fn href(report_dir: &Path, file: &Path) -> String {
    let parent = report_dir.parent();
    match parent.and_then(|p| file.strip_prefix(p).ok()) {
        Some(rel) => format!("../{}", rel.display()),
        None => format!("file://{}", file.display()),
    }
}

/// What the sections of the page need beyond the data: the figures, each with its portable
/// SVG, by name.
pub struct Page<'a> {
    /// The inputs.
    pub data: &'a StudyData,
    /// The figures made, with their portable SVG.
    pub figures: Vec<(Figure, String)>,
    /// The report directory.
    pub report_dir: &'a Path,
    /// fishprobe's version.
    pub version: &'a str,
}

impl Page<'_> {
    fn fig(&self, out: &mut String, name: &str) -> bool {
        match self.figures.iter().find(|(f, _)| f.name == name) {
            Some((fig, svg)) => {
                figure(out, fig, svg);
                true
            }
            None => false,
        }
    }

    /// The HTML document, section by section.
    pub fn html(&self) -> String {
        let mut o = String::with_capacity(1 << 20);
        self.head(&mut o);
        self.what_was_run(&mut o);
        self.missing(&mut o);
        self.sim_to_real(&mut o);
        self.metric_gaps(&mut o);
        self.sim_to_sim(&mut o);
        self.temporal(&mut o);
        self.time_to_goal(&mut o);
        self.competence(&mut o);
        self.approach(&mut o);
        self.stability(&mut o);
        self.drawings(&mut o);
        self.data_files(&mut o);
        o
    }

    /// The title, the reality-arm banner and the contents.
    fn head(&self, o: &mut String) {
        let d = self.data;
        let _ = write!(
            o,
            "<!DOCTYPE html>\n<html lang=\"en\"><head><meta charset=\"utf-8\">\
             <meta name=\"viewport\" content=\"width=device-width, initial-scale=1\">\
             <title>fishprobe report: {}</title><style>{STYLE}</style></head><body>\n\
             <h1>fishprobe report</h1><p class=\"small\">Study <code>{}</code> · fishprobe {}</p>\n\
             <p id=\"broken\" class=\"banner\" hidden></p>\n",
            esc(&d.root.display().to_string()),
            esc(&d.root.display().to_string()),
            esc(self.version)
        );
        match d.arm.as_deref() {
            Some(VIRTUAL_LAB) => o.push_str(
                "<p class=\"banner\" id=\"virtual\">VIRTUAL LAB: the reality arm of this study is the \
                 simulated lab (virtual guppies through the live bridge), not live fish. Nothing here \
                 is a result about real fish.</p>\n",
            ),
            Some(a) => {
                let _ = writeln!(
                    o,
                    "<p>Reality arm: <b>{0}</b> (the <code>&lt;Policy&gt;__{0}</code> trial directories).</p>",
                    esc(a)
                );
                let odd: Vec<String> = d
                    .conditions
                    .iter()
                    .filter(|c| c.model == a)
                    .filter(|c| c.recorded.as_deref().is_some_and(|r| !r.starts_with("real")))
                    .map(|c| StudyLayout::arm_dir_name(&c.policy, &Arm::from_label(&c.model)))
                    .collect();
                if !odd.is_empty() {
                    let _ = writeln!(
                        o,
                        "<p class=\"banner\" id=\"not-real\">Check the reality arm: the files of {} do \
                         not record kind \"real\" (see “What was run”). Results labelled real here may \
                         not come from live fish.</p>",
                        esc(&odd.join(", "))
                    );
                }
            }
            None => o.push_str("<p>No reality arm: only simulation results are shown.</p>\n"),
        }
        o.push_str(
            "<nav><b>Contents</b><ul><li><a href=\"#run\">What was run</a></li>\
             <li><a href=\"#missing\">Missing parts</a></li><li><a href=\"#sim-to-real\">Sim-to-real gap</a></li>\
             <li><a href=\"#metrics\">Per-metric gaps</a></li><li><a href=\"#sim-to-sim\">Sim-to-sim</a></li>\
             <li><a href=\"#temporal\">Goals over time</a></li><li><a href=\"#time-to-goal\">Time to goal</a></li>\
             <li><a href=\"#competence\">Probe competence</a></li><li><a href=\"#approach\">Approach assay</a></li><li><a href=\"#stability\">Retraining stability</a></li>\
             <li><a href=\"#iid\">Robot-fish distance</a></li><li><a href=\"#trajectories\">Trajectories</a></li>\
             <li><a href=\"#training\">Training</a></li><li><a href=\"#files\">Data files</a></li></ul></nav>\n",
        );
    }

    /// What was run: policies, trial files per condition, the analysis settings.
    fn what_was_run(&self, o: &mut String) {
        let d = self.data;
        let r = d.results.as_ref();
        // What was run.
        o.push_str("<h2 id=\"run\">What was run</h2>\n");
        if !d.training.is_empty() {
            let rows: Vec<Vec<String>> = d
                .training
                .iter()
                .map(|(m, log)| {
                    let pv = |k: &str| -> String {
                        log.params
                            .as_ref()
                            .and_then(|p| p.get(k))
                            .map(|v| match v {
                                Value::String(s) => s.clone(),
                                other => other.to_string(),
                            })
                            .unwrap_or_else(|| "–".into())
                    };
                    vec![
                        format!("π_{m}"),
                        pv("seed"),
                        pv("preset"),
                        log.rows
                            .last()
                            .map_or("–".into(), |r| format!("{:.0}", r.0)),
                        pv("program_version"),
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
    fn missing(&self, o: &mut String) {
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

    /// The sim-to-real gap in goals reached (table and figure).
    fn sim_to_real(&self, o: &mut String) {
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
    fn metric_gaps(&self, o: &mut String) {
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
    fn sim_to_sim(&self, o: &mut String) {
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
    fn temporal(&self, o: &mut String) {
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
    fn time_to_goal(&self, o: &mut String) {
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
    fn competence(&self, o: &mut String) {
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
    fn approach(&self, o: &mut String) {
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
    fn seeds(&self, o: &mut String) {
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
    fn stability(&self, o: &mut String) {
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

    /// The figures without a table: robot-fish distance, trajectories, training.
    fn drawings(&self, o: &mut String) {
        o.push_str("<h2 id=\"iid\">Robot-fish distance</h2>\n");
        if !self.fig(o, "iid_density") {
            o.push_str("<p class=\"missing\">No sim or reality-arm trials to draw.</p>\n");
        }
        o.push_str("<h2 id=\"trajectories\">Trajectories</h2>\n");
        if !self.fig(o, "trajectories") {
            o.push_str("<p class=\"missing\">No readable trials to draw.</p>\n");
        }
        o.push_str("<h2 id=\"training\">Training</h2>\n");
        if !self.fig(o, "training") {
            o.push_str("<p class=\"missing\">No training logs (<code>policies/&lt;Model&gt;/progress.csv</code>).</p>\n");
        }
    }

    /// The data files of the analysis, and the document's end.
    fn data_files(&self, o: &mut String) {
        let d = self.data;
        // Files.
        o.push_str("<h2 id=\"files\">Data files</h2><ul>\n");
        let mut any = false;
        for name in fishprobe_analysis::results::OUTPUT_FILES {
            let p = d.analysis_dir.join(name);
            if p.is_file() {
                any = true;
                let _ = writeln!(
                    o,
                    "<li><a href=\"{}\">{name}</a></li>",
                    esc(&href(self.report_dir, &p))
                );
            }
        }
        if !any {
            o.push_str("<li>No analysis files yet.</li>\n");
        }
        o.push_str("<li>Figures: <code>figures/*.svg</code> (text as outlines, for papers) and <code>figures/*.png</code> (for slides).</li></ul>\n");
        let _ = write!(o, "<script>{CHECK_SCRIPT}</script>\n</body></html>\n");
    }

    /// What `results.json` says it left out.
    fn skipped(&self) -> Vec<(String, String)> {
        self.data.results.as_ref().map_or_else(Vec::new, |r| {
            r.skipped
                .iter()
                .map(|s| (s.what.clone(), s.reason.clone()))
                .collect()
        })
    }

    /// `report/summary.md`: the analysis summary (when present), the figures and what is
    /// missing.
    pub fn markdown(&self) -> String {
        let d = self.data;
        let mut s = String::from("# fishprobe report\n\n");
        let _ = writeln!(s, "Study: `{}`\n", d.root.display());
        if d.arm.as_deref() == Some(VIRTUAL_LAB) {
            s += "**VIRTUAL LAB: the reality arm is simulated. These are not live-fish results.**\n\n";
        }
        match fishprobe_io::read_small_text(&d.analysis_dir.join("summary.md")) {
            Ok(a) => {
                s += &a.replacen("# fishprobe analysis", "## Analysis", 1);
                s.push('\n');
            }
            Err(_) => s += "No analysis summary (run `fishprobe analyze`).\n\n",
        }
        s += "## Figures\n\n";
        for (fig, _) in &self.figures {
            let _ = writeln!(
                s,
                "- {}: `figures/{}.svg`, `figures/{}.png`",
                fig.title, fig.name, fig.name
            );
        }
        if !d.missing.is_empty() || !d.unreadable.is_empty() {
            s += "\n## Missing\n\n";
            for m in &d.missing {
                let _ = writeln!(
                    s,
                    "- {}: {}. Produce it with: `{}`",
                    m.what, m.why, m.remedy
                );
            }
            for (p, why) in &d.unreadable {
                let _ = writeln!(s, "- unreadable `{}`: {why}", p.display());
            }
        }
        s
    }
}
