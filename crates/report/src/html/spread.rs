//! The between-trial spread: how much simulated trials differ from one another against how
//! much the reality arm's do (table and figure).

use super::*;
use fishprobe_analysis::spread::{quantities, spread_sentence};

impl Page<'_> {
    /// The spread section: the per-trial values figure, then the table of every quantity.
    pub(super) fn spread(&self, o: &mut String) {
        let d = self.data;
        o.push_str("<h2 id=\"spread\">How much trials differ (between-trial spread)</h2>\n");
        let Some(res) = d.results.as_ref().filter(|r| !r.spread.is_empty()) else {
            o.push_str("<p class=\"missing\">Needs simulation and reality-arm trials (two or more a side) and <code>fishprobe analyze</code>.</p>\n");
            return;
        };
        let real = if d.arm.as_deref() == Some(VIRTUAL_LAB) {
            "virtual-lab"
        } else {
            "live"
        };
        if let Some(goals) = res.spread.get("goals") {
            o.push_str("<p>");
            for (p, e) in goals {
                let _ = write!(
                    o,
                    "π_{}: {}. ",
                    esc(p),
                    esc(&spread_sentence(e, "in goals reached", real))
                );
            }
            o.push_str("</p>\n");
        }
        self.fig(o, "spread");
        let mut policies: Vec<&String> = res.spread.values().flat_map(|m| m.keys()).collect();
        policies.sort();
        policies.dedup();
        let mut header = vec!["per trial".to_string()];
        header.extend(policies.iter().map(|p| format!("π_{p}")));
        let rows: Vec<Vec<String>> = quantities()
            .into_iter()
            .filter_map(|q| res.spread.get(q.id()).map(|per| (q, per)))
            .map(|(q, per)| {
                let mut row = vec![q.label()];
                row.extend(policies.iter().map(|p| {
                    per.get(*p).map_or("–".into(), |e| {
                        format!(
                            "{} {}{}",
                            f(e.ratio, 2),
                            ci(&e.ci, 2),
                            if e.bf_p_holm < 0.05 { " *" } else { "" }
                        )
                    })
                }));
                row
            })
            .collect();
        let header: Vec<&str> = header.iter().map(String::as_str).collect();
        table(o, &header, &rows);
        let _ = writeln!(
            o,
            "<p class=\"small\">Each cell: the s.d. across the simulated trials over the s.d. across the {real} \
             trials of the same policy (1: as varied as reality; 0.2: a fifth as varied), with its 95 % \
             bootstrap interval (trials resampled within each side); * the spreads differ (Brown–Forsythe \
             test, <code>scipy.stats.levene(center=\"median\")</code>, Holm-adjusted across policies, p &lt; 0.05). \
             A trial's value of a per-frame metric is its median for distances, its mean of absolute values \
             for signed rates and its mean otherwise. The 1-Wasserstein distances between the per-trial values \
             and the tests' statistics are in <code>analysis/spread.csv</code>.</p>"
        );
    }
}
