//! The research commands (`fidelity`, `collective`, `support`, `ood-report`, `ood-loop`):
//! their work is [`fishprobe_research`]; here are their flags, each mapped once onto the
//! library's plain settings, and the calls and prints.

use super::{emit, note, BUILD};
use anyhow::Result;
use clap::{Args, ValueEnum};
use fishprobe_models::support::Estimator;
use fishprobe_research::collective::{CollectiveSettings, GroupModel};
use fishprobe_research::fidelity::FidelitySettings;
use fishprobe_research::ood_report::OodReportSettings;
use fishprobe_research::support::SupportSettings;
use fishprobe_research::{self as research, ood_loop::OodLoopConfig, Runner};
use std::path::PathBuf;

/// Which readings and models the sweep runs, with what budget, and where.
#[derive(Debug, Clone, Args)]
pub struct FidelityFlags {
    /// Readings to run, comma-separated (default: all; `--list` names them); `a+b` combines
    /// readings (their overrides merged, on the models both apply to).
    #[arg(long, value_delimiter = ',')]
    pub readings: Vec<String>,
    /// Models, comma-separated (a reading that changes one model runs only on it).
    #[arg(long, value_delimiter = ',', default_value = "Follow,Zone,Force")]
    pub models: Vec<String>,
    /// PPO preset every reading starts from.
    #[arg(long, default_value = "paper")]
    pub preset: String,
    /// Evaluation episodes of 15 minutes per cell (paper: 18).
    #[arg(long, default_value_t = 18)]
    pub episodes: usize,
    /// Approach-assay episodes of 2 minutes per cell (SPEC choice: 10).
    #[arg(long, default_value_t = 10)]
    pub approach_episodes: usize,
    /// Master seed.
    #[arg(long, default_value_t = 0)]
    pub seed: u64,
    /// Where the runs and `scoreboard.md` / `scoreboard.json` go.
    #[arg(long, default_value = "fidelity")]
    pub out: PathBuf,
    /// List the readings and exit.
    #[arg(long)]
    pub list: bool,
    /// Threads (default: all cores).
    #[arg(long)]
    pub jobs: Option<usize>,
}

impl From<FidelityFlags> for FidelitySettings {
    fn from(f: FidelityFlags) -> Self {
        Self {
            readings: f.readings,
            models: f.models,
            preset: f.preset,
            episodes: f.episodes,
            approach_episodes: f.approach_episodes,
            seed: f.seed,
            out: f.out,
            list: f.list,
        }
    }
}

/// What `fishprobe collective` sweeps, and where its output goes.
#[derive(Debug, Clone, Args)]
pub struct CollectiveFlags {
    /// The model.
    #[arg(long, value_enum, default_value_t = GroupModelFlag::Zone)]
    pub model: GroupModelFlag,
    /// Fish per group.
    #[arg(long, default_value_t = 50)]
    pub fish: u32,
    /// Seeds per cell.
    #[arg(long, default_value_t = 3)]
    pub seeds: u64,
    /// Simulated seconds per run (the first half is left out as burn-in).
    #[arg(long, default_value_t = 150.0)]
    pub seconds: f32,
    // The sweeps' flags have no clap default, so that a flag of the other model's sweep is
    // refused instead of ignored; their defaults are the constants below, shown in the help.
    /// M_Zone: orientation widths Δr_o (cm), comma-separated [default: 0,1,2,4,8,12,16,20,30]
    #[arg(long, value_delimiter = ',')]
    pub orientation: Option<Vec<f32>>,
    /// M_Zone: attraction widths Δr_a (cm), comma-separated [default: 4,8,14,20,28,40]
    #[arg(long, value_delimiter = ',')]
    pub attraction: Option<Vec<f32>>,
    /// M_Zone: maximum turning rate in rad/s, or `couzin` (40°/s) or `paper` (10 rad/s)
    /// [default: couzin]
    #[arg(long)]
    pub turn_rate: Option<String>,
    /// M_Force: alignment strengths μ_alg, comma-separated [default: 0,0.05,0.1,0.2,0.3,0.6]
    #[arg(long, value_delimiter = ',')]
    pub alignment: Option<Vec<f32>>,
    /// Master seed.
    #[arg(long, default_value_t = 0)]
    pub seed: u64,
    /// Write the picture (collective-phase.svg/.png) and the numbers (collective.json) here.
    #[arg(long)]
    pub out: Option<PathBuf>,
    /// Print JSON instead of a table.
    #[arg(long)]
    pub json: bool,
}

impl From<CollectiveFlags> for CollectiveSettings {
    fn from(f: CollectiveFlags) -> Self {
        Self {
            model: f.model.into(),
            fish: f.fish,
            seeds: f.seeds,
            seconds: f.seconds,
            orientation: f.orientation,
            attraction: f.attraction,
            turn_rate: f.turn_rate,
            alignment: f.alignment,
            seed: f.seed,
            out: f.out,
            json: f.json,
        }
    }
}

/// Which model's support `fishprobe support` builds, from which recordings, and how it is checked.
#[derive(Debug, Clone, Args)]
pub struct SupportFlags {
    /// The model: `ConvNet` (shipped weights), a ConvNet weights file (`--model
    /// convnet:FILE`) or `onnx:FILE` (a model of the view contract).
    #[arg(long, default_value = "ConvNet")]
    pub model: String,
    /// The model's training recordings (pair files; with --robot-as-partner also files of
    /// one fish with the robot). Default: guppy-pairs/legacy/train of the shared data.
    #[arg(long, num_args = 1..)]
    pub data: Vec<PathBuf>,
    /// Held-out recordings for the check. Default: guppy-pairs/legacy/validation.
    #[arg(long, num_args = 1..)]
    pub validation: Vec<PathBuf>,
    /// Estimator written to the file (`knn` or `gmm`); both are compared.
    #[arg(long, default_value = "knn")]
    pub estimator: Estimator,
    /// Learn from files of one fish with the robot too (the fish's frames, the robot as
    /// its neighbour).
    #[arg(long)]
    pub robot_as_partner: bool,
    /// The support file to write. Default: beside the weights (`FILE.support.json`); the
    /// shipped ConvNet needs an explicit path.
    #[arg(long)]
    pub out: Option<PathBuf>,
    /// Partners farther than this (cm) are embedded as not seen (0: every partner the view
    /// shows; see `support.partner_range_cm` in docs/settings.md).
    #[arg(long, default_value_t = fishprobe_models::support::SupportConfig::default().partner_range_cm)]
    pub partner_range_cm: f32,
    /// Seed of the reference and calibration draws.
    #[arg(long, default_value_t = 0)]
    pub seed: u64,
    /// Synthetic views per kind of unseen situation in the check.
    #[arg(long, default_value_t = 2000)]
    pub synthetic: usize,
    /// Print the check as JSON.
    #[arg(long)]
    pub json: bool,
}

impl From<SupportFlags> for SupportSettings {
    fn from(f: SupportFlags) -> Self {
        Self {
            model: f.model,
            data: f.data,
            validation: f.validation,
            estimator: f.estimator,
            robot_as_partner: f.robot_as_partner,
            out: f.out,
            partner_range_cm: f.partner_range_cm,
            seed: f.seed,
            synthetic: f.synthetic,
            json: f.json,
        }
    }
}

/// Which policies `fishprobe ood-report` runs or scores, against what, and where the report goes.
#[derive(Debug, Clone, Args)]
pub struct OodReportFlags {
    /// The OOD policy: a directory from `fishprobe train --task ood` (or `onnx:FILE`). With
    /// `--trials`, only names the policy the trials were recorded with (and, as a training
    /// directory, the fish model and its yardstick).
    #[arg(long, required_unless_present = "trials")]
    pub policy: Option<String>,
    /// Recorded trials of the OOD policy to score instead of simulating its episodes: trial
    /// files or directories of them (`*.hdf5`, `*.h5`), e.g. live trials (`fishprobe live`)
    /// or the virtual lab's (`fishprobe lab`): how far the fish in those recordings went
    /// outside the model's training support. At most 1000 files.
    #[arg(long, num_args = 1..)]
    pub trials: Vec<PathBuf>,
    /// Recorded trials of the lead-to-goal policy, scored instead of simulating `--compare`'s
    /// episodes (as `--trials`).
    #[arg(long, num_args = 1..)]
    pub compare_trials: Vec<PathBuf>,
    /// The lead-to-goal policy to compare with (a training directory, `onnx:FILE` or
    /// `scripted:NAME`). Default: `scripted:fetch-and-lead`.
    #[arg(long, default_value = "scripted:fetch-and-lead")]
    pub compare: String,
    /// The fish model (default: the one the OOD policy was trained against).
    #[arg(long)]
    pub model: Option<String>,
    /// The model's training recordings, for their score distribution (default: the shared
    /// guppy pairs when the model is the shipped ConvNet and they are found; else none).
    #[arg(long, num_args = 1..)]
    pub data: Vec<PathBuf>,
    /// Episodes per policy.
    #[arg(long, default_value_t = 6)]
    pub episodes: usize,
    /// Minutes per episode (the evaluation task: random starts, corner goals).
    #[arg(long, default_value_t = 5.0)]
    pub minutes: f32,
    /// Master seed of the episodes (both policies get the same ones).
    #[arg(long, default_value_t = 0)]
    pub seed: u64,
    /// Report directory (report.md, ood.json, figures, the episodes' trial files).
    #[arg(long)]
    pub out: PathBuf,
    /// Print ood.json instead of the summary.
    #[arg(long)]
    pub json: bool,
}

impl From<OodReportFlags> for OodReportSettings {
    fn from(f: OodReportFlags) -> Self {
        Self {
            policy: f.policy,
            trials: f.trials,
            compare_trials: f.compare_trials,
            compare: f.compare,
            model: f.model,
            data: f.data,
            episodes: f.episodes,
            minutes: f.minutes,
            seed: f.seed,
            out: f.out,
            json: f.json,
        }
    }
}

/// The group model of `fishprobe collective`.
#[derive(Debug, Clone, Copy, PartialEq, Eq, ValueEnum)]
pub enum GroupModelFlag {
    /// M_Zone over Couzin's orientation and attraction widths.
    Zone,
    /// M_Force over its alignment strength.
    Force,
}

impl From<GroupModelFlag> for GroupModel {
    fn from(m: GroupModelFlag) -> Self {
        match m {
            GroupModelFlag::Zone => GroupModel::Zone,
            GroupModelFlag::Force => GroupModel::Force,
        }
    }
}

/// The command line as typed, recorded with what a command writes.
fn command_line() -> String {
    std::iter::once("fishprobe".to_string())
        .chain(std::env::args().skip(1))
        .collect::<Vec<_>>()
        .join(" ")
}

/// Runs `work` with this build, this command line and stderr for its progress lines.
fn with_runner<T>(work: impl FnOnce(Runner) -> T) -> T {
    let command = command_line();
    let notes = |line: &str| note(line);
    work(Runner {
        build: BUILD,
        command: &command,
        notes: &notes,
    })
}

/// `fishprobe fidelity`.
pub fn fidelity(f: FidelityFlags) -> Result<()> {
    super::no_repeats("--models", &f.models)?;
    super::no_repeats("--readings", &f.readings)?;
    // The sweep's training and evaluations run on `--jobs` threads.
    let jobs = f.jobs;
    let a = FidelitySettings::from(f);
    emit(&super::with_jobs(jobs, || {
        with_runner(|by| research::fidelity::run(&a, by))
    })??)
}

/// `fishprobe collective`, with a progress bar over its runs.
pub fn collective(f: CollectiveFlags) -> Result<()> {
    let a = CollectiveSettings::from(f);
    use indicatif::{ProgressBar, ProgressStyle};
    let bar = ProgressBar::new(0);
    bar.set_style(
        ProgressStyle::with_template("{spinner} [{elapsed_precise}] {bar:30} run {pos}/{len}")
            .unwrap_or_else(|_| ProgressStyle::default_bar()),
    );
    let progress = |done: u64, total: u64| {
        bar.set_length(total);
        bar.set_position(done);
    };
    let text = research::collective::run(&a, &progress);
    bar.finish_and_clear();
    emit(&text?)
}

/// `fishprobe support`.
pub fn support(f: SupportFlags) -> Result<()> {
    let a = SupportSettings::from(f);
    emit(&with_runner(|by| research::support::run(&a, by))?)
}

/// `fishprobe ood-report`.
pub fn ood_report(f: OodReportFlags) -> Result<()> {
    let a = OodReportSettings::from(f);
    emit(&with_runner(|by| research::ood_report::run(&a, by))?)
}

/// The flags of `fishprobe ood-loop`.
#[derive(Debug, Args)]
pub struct OodLoopArgs {
    /// Output directory (one subdirectory per seed; loop.json and loop.md at the end).
    #[arg(long)]
    out: PathBuf,
    /// Seeds (each a whole loop).
    #[arg(long, num_args = 1.., default_values_t = [0u64, 1, 2])]
    seeds: Vec<u64>,
    /// Settings (TOML, the fields of OodLoopConfig).
    #[arg(long)]
    config: Option<PathBuf>,
}

/// `fishprobe ood-loop`.
pub fn ood_loop(a: OodLoopArgs) -> Result<()> {
    super::no_repeats("--seeds", &a.seeds)?;
    let cfg: OodLoopConfig = match &a.config {
        Some(p) => super::read_toml(p, "settings")?,
        None => OodLoopConfig::default(),
    };
    emit(&with_runner(|by| {
        research::ood_loop::run(&a.out, &a.seeds, &cfg, by)
    })?)
}

#[cfg(test)]
mod tests {
    use super::*;
    use clap::Parser;

    #[derive(Parser)]
    struct One<T: Args> {
        #[command(flatten)]
        flags: T,
    }

    /// The flags' defaults are the library's: a command without flags runs the settings a
    /// library caller gets from `Default`.
    #[test]
    fn no_flags_are_the_librarys_default_settings() {
        let parse = |name: &str| vec![name.to_string()];
        let f = One::<FidelityFlags>::parse_from(parse("fidelity")).flags;
        assert_eq!(FidelitySettings::from(f), FidelitySettings::default());
        let c = One::<CollectiveFlags>::parse_from(parse("collective")).flags;
        assert_eq!(CollectiveSettings::from(c), CollectiveSettings::default());
        let s = One::<SupportFlags>::parse_from(parse("support")).flags;
        assert_eq!(SupportSettings::from(s), SupportSettings::default());
    }

    /// The sweeps' flags have no clap default (a flag of the other model's sweep is refused),
    /// so their help states the library's defaults in words; they must be the same.
    #[test]
    fn the_collective_help_shows_the_librarys_default_sweeps() {
        use clap::CommandFactory as _;
        use fishprobe_research::collective::{ALIGNMENT, ATTRACTION_CM, ORIENTATION_CM};
        let help = One::<CollectiveFlags>::command()
            .render_long_help()
            .to_string();
        for d in [ORIENTATION_CM, ATTRACTION_CM, ALIGNMENT] {
            let shown: Vec<String> = d.iter().map(f32::to_string).collect();
            let shown = format!("[default: {}]", shown.join(","));
            assert!(help.contains(&shown), "{shown} not in\n{help}");
        }
    }
}
