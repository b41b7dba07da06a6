//! The study directory, laid out like the paper's public archive: written by `fishprobe run`,
//! the live bridge and the virtual lab, read by `analyze` and `report`. The one place its
//! names are spelled.
//!
//! ```text
//! STUDY/study.json                              the resolved configuration
//! STUDY/convnet/                                a refitted M_ConvNet (run --convnet-data)
//! STUDY/policies/<Model>/                       training runs
//! STUDY/policies_stability/<Model>/seed<k>/     the extra seeds
//! STUDY/rollouts/<Policy>__<Model>/             evaluation episodes (an "arm")
//! STUDY/rollouts/<Policy>__Real/                live trials;  <Policy>__VirtualLab/: virtual lab
//! STUDY/approach_test/<Policy>/                 approach-assay episodes
//! STUDY/approach_stability/<Model>/seed<k>/     ... of the extra seeds' policies
//! STUDY/baselines/<Model>/<Controller>/         scripted baselines on the model's own episodes
//! STUDY/stability/<Model>/seed<k>/              stability episodes
//! STUDY/analysis/results.json, STUDY/report/    results and report
//! STUDY/logs/<step>.log                         one log per step
//! STUDY/.fishprobe/done/<step>.json             completion markers (stale/: set-aside outputs)
//! ```
//!
//! ```
//! use fishprobe_io::layout::{Arm, StudyLayout};
//! let s = StudyLayout::new("study");
//! assert_eq!(s.arm("Zone", &Arm::Sim("Force".into())), std::path::Path::new("study/rollouts/Zone__Force"));
//! assert_eq!(StudyLayout::parse_arm("Zone__VirtualLab"), Some(("Zone".into(), Arm::VirtualLab)));
//! ```

use std::path::{Path, PathBuf};

/// Where a policy's trials come from: a simulated fish model, live fish, or the virtual lab.
#[derive(Debug, Clone, PartialEq, Eq, PartialOrd, Ord, Hash)]
pub enum Arm {
    /// Simulation with this fish model (its name in the study).
    Sim(String),
    /// Live trials (`<Policy>__Real`).
    Real,
    /// The virtual lab (`<Policy>__VirtualLab`), never reported as real.
    VirtualLab,
}

impl Arm {
    /// The arm's name in directory names.
    pub fn label(&self) -> &str {
        match self {
            Arm::Sim(m) => m,
            Arm::Real => REAL,
            Arm::VirtualLab => VIRTUAL_LAB,
        }
    }

    /// From a directory name's second half.
    pub fn from_label(s: &str) -> Self {
        match s {
            REAL => Arm::Real,
            VIRTUAL_LAB => Arm::VirtualLab,
            m => Arm::Sim(m.to_string()),
        }
    }

    /// Whether the arm stands for reality (live or virtual lab).
    pub fn is_reality(&self) -> bool {
        !matches!(self, Arm::Sim(_))
    }
}

/// The arm label of live trials.
pub const REAL: &str = "Real";
/// The arm label of virtual-lab trials.
pub const VIRTUAL_LAB: &str = "VirtualLab";
/// The arm labels that mean "not a simulation", in order of preference as the reality arm.
pub const REALITY_ARMS: [&str; 2] = [REAL, VIRTUAL_LAB];
/// Separates policy and arm in a rollout directory's name.
pub const ARM_SEPARATOR: &str = "__";

/// Names the layout gives to directories of its own where a model's name would stand (the
/// reality arms): a model named so would share `rollouts/<Policy>__Real/` with live trials.
pub const RESERVED_NAMES: [&str; 2] = REALITY_ARMS;

/// Why `name` cannot name a model (or its policy) in a study, or `None` when it can: it names
/// directories (`policies/<Model>/`, `rollouts/<Policy>__<Model>/`), so it must be letters,
/// digits, `-` and `_` only, at most 100 characters, neither begin nor end with `_` nor hold
/// the arm separator `__` (which would split `<Policy>__<Model>` in the wrong place), and not
/// be a reserved name ([`RESERVED_NAMES`]) in any spelling of case (a case-insensitive file
/// system, macOS's default, makes `real/` and `Real/` one directory).
pub fn name_problem(name: &str) -> Option<String> {
    if name.is_empty() {
        return Some("an empty name".into());
    }
    if name.chars().count() > 100 {
        return Some("more than 100 characters".into());
    }
    if let Some(c) = name
        .chars()
        .find(|c| !(c.is_ascii_alphanumeric() || matches!(c, '-' | '_')))
    {
        return Some(format!(
            "the character {c:?}: use letters, digits, '-' and '_', it names directories"
        ));
    }
    if name.contains(ARM_SEPARATOR) {
        return Some(format!(
            "\"{ARM_SEPARATOR}\", which separates policy and model in `rollouts/<Policy>{ARM_SEPARATOR}<Model>/`"
        ));
    }
    if name.starts_with('_') || name.ends_with('_') {
        return Some(format!(
            "a leading or trailing '_', which would join the separator \"{ARM_SEPARATOR}\" of `rollouts/<Policy>{ARM_SEPARATOR}<Model>/`"
        ));
    }
    if let Some(r) = RESERVED_NAMES.iter().find(|r| r.eq_ignore_ascii_case(name)) {
        return Some(format!(
            "reserved: `rollouts/<Policy>{ARM_SEPARATOR}{r}/` holds the reality arm (in any case: a case-insensitive file system makes them one directory)"
        ));
    }
    None
}

/// The first two of `names` that would be one directory on a case-insensitive file system
/// (`Zone` and `zone`), if any.
pub fn case_clash<'a>(names: impl IntoIterator<Item = &'a str>) -> Option<(&'a str, &'a str)> {
    let mut seen: std::collections::BTreeMap<String, &'a str> = std::collections::BTreeMap::new();
    for n in names {
        if let Some(first) = seen.insert(n.to_ascii_lowercase(), n) {
            return Some((first, n));
        }
    }
    None
}

/// The top-level directories that hold the outputs of study steps.
pub const STEP_OUTPUT_DIRS: [&str; 7] = [
    "rollouts",
    "approach_test",
    "approach_stability",
    "baselines",
    "policies",
    "policies_stability",
    "stability",
];

/// The analysis's machine-readable results, in the analysis directory.
pub const RESULTS_FILE: &str = "results.json";

/// Of [`STEP_OUTPUT_DIRS`], those with one directory per model and seed (two levels).
pub const SEEDED_DIRS: [&str; 3] = ["policies_stability", "stability", "approach_stability"];

/// Paths of a study directory.
#[derive(Debug, Clone, PartialEq, Eq)]
pub struct StudyLayout {
    root: PathBuf,
}

impl StudyLayout {
    /// The layout under `root`.
    pub fn new(root: impl Into<PathBuf>) -> Self {
        Self { root: root.into() }
    }

    /// The study directory.
    pub fn root(&self) -> &Path {
        &self.root
    }

    /// `rollouts/`.
    pub fn rollouts(&self) -> PathBuf {
        self.root.join("rollouts")
    }

    /// `<policy>__<arm>`: a rollout directory's name.
    pub fn arm_dir_name(policy: &str, arm: &Arm) -> String {
        format!("{policy}{ARM_SEPARATOR}{}", arm.label())
    }

    /// `(policy, arm)` from a rollout directory's name, if it is one.
    pub fn parse_arm(dir_name: &str) -> Option<(String, Arm)> {
        let (p, m) = dir_name.split_once(ARM_SEPARATOR)?;
        (!p.is_empty() && !m.is_empty()).then(|| (p.to_string(), Arm::from_label(m)))
    }

    /// A name from a file (a policy's `about.model`) as one safe path component of this
    /// layout: letters, digits, `-`, `_` and `.` kept, anything else (`/`, `\`, `:`, spaces,
    /// ...) replaced by `_`, no run of `_` long enough to read as the arm separator `__` and
    /// none at the end, no leading dot (so neither `..` nor a hidden name), at most 100
    /// characters, never empty.
    /// A trial path built from it always stays inside its directory.
    pub fn safe_name(name: &str) -> String {
        let mut s: String = name
            .chars()
            .take(100)
            .map(|c| {
                if c.is_ascii_alphanumeric() || matches!(c, '-' | '.') {
                    c
                } else {
                    '_'
                }
            })
            .collect();
        while s.contains(ARM_SEPARATOR) {
            s = s.replace(ARM_SEPARATOR, "_");
        }
        while s.starts_with('.') {
            s.replace_range(0..1, "_");
        }
        // A trailing `_` would join the separator into `___` and split in the wrong place.
        let kept = s.trim_end_matches('_').len();
        s.truncate(kept);
        if s.is_empty() {
            s.push_str("policy");
        }
        s
    }

    /// `rollouts/<policy>__<arm>/`.
    pub fn arm(&self, policy: &str, arm: &Arm) -> PathBuf {
        self.rollouts().join(Self::arm_dir_name(policy, arm))
    }

    /// `approach_test/`.
    pub fn approach_root(&self) -> PathBuf {
        self.root.join("approach_test")
    }

    /// `approach_test/<policy>/`.
    pub fn approach(&self, policy: &str) -> PathBuf {
        self.approach_root().join(policy)
    }

    /// `approach_stability/`.
    pub fn approach_stability_root(&self) -> PathBuf {
        self.root.join("approach_stability")
    }

    /// The approach-assay episodes of `model`'s training run `k`: `approach_test/<model>/` for
    /// seed 0 (the policy), `approach_stability/<model>/seed<k>/` for the others (as
    /// [`StudyLayout::policy`]).
    pub fn approach_seed(&self, model: &str, k: usize) -> PathBuf {
        if k == 0 {
            self.approach(model)
        } else {
            self.approach_stability_root()
                .join(model)
                .join(format!("seed{k}"))
        }
    }

    /// `baselines/`.
    pub fn baselines_root(&self) -> PathBuf {
        self.root.join("baselines")
    }

    /// `baselines/<model>/`: the scripted controllers (one directory each, named by the
    /// controller) on the evaluation episodes of `model`'s own policy.
    pub fn baselines(&self, model: &str) -> PathBuf {
        self.baselines_root().join(model)
    }

    /// `stability/`.
    pub fn stability_root(&self) -> PathBuf {
        self.root.join("stability")
    }

    /// `stability/<model>/seed<k>/`.
    pub fn stability(&self, model: &str, k: usize) -> PathBuf {
        self.stability_root().join(model).join(format!("seed{k}"))
    }

    /// `policies/<model>/` for seed 0, `policies_stability/<model>/seed<k>/` for the others.
    pub fn policy(&self, model: &str, k: usize) -> PathBuf {
        if k == 0 {
            self.policies_root().join(model)
        } else {
            self.root
                .join("policies_stability")
                .join(model)
                .join(format!("seed{k}"))
        }
    }

    /// `policies/`.
    pub fn policies_root(&self) -> PathBuf {
        self.root.join("policies")
    }

    /// `convnet/` (a refitted M_ConvNet).
    pub fn convnet(&self) -> PathBuf {
        self.root.join("convnet")
    }

    /// `analysis/`.
    pub fn analysis(&self) -> PathBuf {
        self.root.join("analysis")
    }

    /// `analysis/results.json` (or in another analysis directory, `results_in`).
    pub fn results(&self) -> PathBuf {
        Self::results_in(&self.analysis())
    }

    /// `results.json` inside an analysis directory.
    pub fn results_in(analysis_dir: &Path) -> PathBuf {
        analysis_dir.join(RESULTS_FILE)
    }

    /// `report/`.
    pub fn report(&self) -> PathBuf {
        self.root.join("report")
    }

    /// `study.json`.
    pub fn config(&self) -> PathBuf {
        self.root.join("study.json")
    }

    /// `logs/`.
    pub fn logs(&self) -> PathBuf {
        self.root.join("logs")
    }

    /// `.fishprobe/done/` (completion markers).
    pub fn markers(&self) -> PathBuf {
        self.root.join(".fishprobe/done")
    }

    /// `.fishprobe/stale/` (outputs of other configurations, set aside).
    pub fn stale(&self) -> PathBuf {
        self.root.join(".fishprobe/stale")
    }

    /// `.fishprobe/slurm/` (job scripts and the state of a SLURM run).
    pub fn slurm(&self) -> PathBuf {
        self.root.join(".fishprobe/slurm")
    }

    /// `.fishprobe/locks/` (per-step locks of SLURM array tasks).
    pub fn step_locks(&self) -> PathBuf {
        self.root.join(".fishprobe/locks")
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn names_that_would_collide_with_the_layout_are_refused() {
        for ok in [
            "Zone",
            "Zone-radii",
            "M_Zone",
            "a-b_c",
            "Real2",
            "VirtualLab-b",
        ] {
            assert_eq!(name_problem(ok), None, "{ok}");
        }
        // Every reserved name, in its own and in other spellings of case.
        for r in RESERVED_NAMES {
            for n in [r.to_string(), r.to_lowercase(), r.to_uppercase()] {
                let why = name_problem(&n).unwrap_or_default();
                assert!(why.contains("reserved") && why.contains(r), "{n}: {why}");
            }
        }
        for (bad, needle) in [
            ("", "empty"),
            ("Zone_", "trailing"),
            ("_Zone", "leading"),
            ("a__b", "separates"),
            ("a/b", "'/'"),
            ("..", "'.'"),
            ("zö", "'ö'"),
        ] {
            let why = name_problem(bad).unwrap_or_default();
            assert!(why.contains(needle), "{bad:?}: {why}");
        }
        assert!(name_problem(&"a".repeat(101)).is_some());
        assert_eq!(
            case_clash(["Zone", "Force", "zone"]),
            Some(("Zone", "zone"))
        );
        assert_eq!(case_clash(["Zone", "Force", "Zone2"]), None);
    }

    #[test]
    fn the_archive_layout() {
        let s = StudyLayout::new("S");
        let p = |x: &str| PathBuf::from(x);
        assert_eq!(
            s.arm("Zone", &Arm::Sim("Force".into())),
            p("S/rollouts/Zone__Force")
        );
        assert_eq!(s.arm("Zone", &Arm::Real), p("S/rollouts/Zone__Real"));
        assert_eq!(
            s.arm("Zone", &Arm::VirtualLab),
            p("S/rollouts/Zone__VirtualLab")
        );
        assert_eq!(s.approach("Zone"), p("S/approach_test/Zone"));
        assert_eq!(s.approach_seed("Zone", 0), p("S/approach_test/Zone"));
        assert_eq!(
            s.approach_seed("Zone", 2),
            p("S/approach_stability/Zone/seed2")
        );
        assert_eq!(s.baselines("Zone"), p("S/baselines/Zone"));
        assert_eq!(s.stability("Force", 2), p("S/stability/Force/seed2"));
        assert_eq!(s.policy("Force", 0), p("S/policies/Force"));
        assert_eq!(s.policy("Force", 3), p("S/policies_stability/Force/seed3"));
        assert_eq!(s.results(), p("S/analysis/results.json"));
        assert_eq!(s.markers(), p("S/.fishprobe/done"));
        assert_eq!(
            StudyLayout::parse_arm("Zone__Real"),
            Some(("Zone".into(), Arm::Real))
        );
        assert_eq!(
            StudyLayout::parse_arm("A__B__C"),
            Some(("A".into(), Arm::Sim("B__C".into())))
        );
        assert_eq!(StudyLayout::parse_arm("Zone"), None);
        assert_eq!(StudyLayout::parse_arm("__Real"), None);
        assert!(Arm::VirtualLab.is_reality() && !Arm::Sim("Real2".into()).is_reality());
    }

    #[test]
    fn names_from_files_stay_one_path_component() {
        let n = StudyLayout::safe_name;
        assert_eq!(n("Zone"), "Zone");
        assert_eq!(n("Zone-radii_2.v1"), "Zone-radii_2.v1");
        assert_eq!(n("../../x"), "_._.._x");
        assert_eq!(n("/etc/passwd"), "_etc_passwd");
        assert_eq!(n(".."), "_.");
        assert_eq!(n("C:\\x y"), "C_x_y");
        assert_eq!(n("A__B"), "A_B");
        assert_eq!(n("A____B"), "A_B");
        assert_eq!(n(""), "policy");
        assert_eq!(n("."), "policy");
        assert_eq!(n("a_"), "a");
        assert_eq!(n(&"a".repeat(500)).len(), 100);
        for hostile in ["../../x", "/abs", "..", ".", "a/../../b", "A__Real"] {
            let dir = StudyLayout::arm_dir_name(&n(hostile), &Arm::Real);
            let p = Path::new("/out").join(&dir);
            assert_eq!(p.parent(), Some(Path::new("/out")), "{hostile}");
            assert_eq!(
                StudyLayout::parse_arm(&dir).map(|(_, a)| a),
                Some(Arm::Real),
                "{hostile}"
            );
        }
    }
}
