//! The HTML page and the Markdown summary.

use crate::data::StudyData;
use crate::figures::{Figure, METRIC_LABELS};
use crate::svg::esc;
use base64::Engine as _;
use fishprobe_analysis::results::MeanSd;
use fishprobe_analysis::ALL_METRICS;
use fishprobe_io::layout::{Arm, StudyLayout, VIRTUAL_LAB};
use fishprobe_stats::sample::mean;
use std::fmt::Write as _;
use std::path::Path;

mod run;
mod spread;
mod tables;

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
        self.spread(&mut o);
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
             <li><a href=\"#metrics\">Per-metric gaps</a></li><li><a href=\"#spread\">How much trials differ</a></li><li><a href=\"#sim-to-sim\">Sim-to-sim</a></li>\
             <li><a href=\"#temporal\">Goals over time</a></li><li><a href=\"#time-to-goal\">Time to goal</a></li>\
             <li><a href=\"#competence\">Probe competence</a></li><li><a href=\"#approach\">Approach assay</a></li><li><a href=\"#stability\">Retraining stability</a></li>\
             <li><a href=\"#iid\">Robot-fish distance</a></li><li><a href=\"#trajectories\">Trajectories</a></li>\
             <li><a href=\"#training\">Training</a></li><li><a href=\"#files\">Data files</a></li></ul></nav>\n",
        );
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
