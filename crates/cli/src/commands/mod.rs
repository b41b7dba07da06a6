//! Subcommands.

/// `eprintln!` that cannot panic: a line on stderr through [`note`], ignoring a closed or
/// full stderr.
macro_rules! say {
    ($($t:tt)*) => {
        $crate::commands::note(&format!($($t)*))
    };
}

mod analyze;
mod assay;
mod bench;
mod compare_offline;
mod config;
mod evaluate;
mod export;
mod fit_convnet;
mod fit_population;
mod import_legacy;
mod inspect;
mod live;
mod models;
mod observer;
mod report;
mod research;
mod run;
mod simulate;
mod train;

use anyhow::Context as _;
use clap::{Parser, Subcommand};

/// This build of fishprobe: its version and the git commit it was built from (`--version`;
/// recorded where a result must name the code that made it, e.g. each fitted network).
pub(crate) const BUILD: &str = concat!(
    env!("CARGO_PKG_VERSION"),
    " (",
    env!("FISHPROBE_COMMIT"),
    ")"
);

/// fishprobe: test models of fish behaviour by the robots they teach (Hocke et al. 2026).
///
/// Simulates the 1 x 1 m RoboFish tank with a robot fish and a fish driven by a candidate
/// behaviour model.
#[derive(Debug, Parser)]
#[command(
    name = "fishprobe",
    version = BUILD,
    about,
    long_about = None
)]
pub struct Cli {
    #[command(subcommand)]
    command: Command,
}

#[derive(Debug, Subcommand)]
enum Command {
    /// The whole study in one command: train, evaluate, reality arm, analyse, report (resumable).
    Run(run::RunArgs),
    /// List the fish models with their parameters, units and defaults.
    Models(models::ModelsArgs),
    /// Measure how fast fishprobe runs on this machine.
    Bench(bench::BenchArgs),
    /// Show the default simulation settings, or check a settings file.
    Config(config::ConfigArgs),
    /// Simulate one evaluation trial with a scripted robot and write it as a trial file.
    Simulate(simulate::SimulateArgs),
    /// Show what trial files hold (any robofish.io file, or the legacy layout).
    Inspect(inspect::InspectArgs),
    /// Convert the lab's pre-2020 files to robofish.io 1.0.
    ImportLegacy(import_legacy::ImportLegacyArgs),
    /// Train a robot policy (PPO) against a fish model.
    Train(train::TrainArgs),
    /// Run a trained policy (or the scripted baseline) on the 15-minute evaluation task.
    Evaluate(evaluate::EvaluateArgs),
    /// Assays of one policy's strategy: `assay approach` (does it go to the fish first?).
    Assay(assay::AssayArgs),
    /// The fidelity sweep: probes trained under each reading of what the paper leaves open,
    /// scored against the paper's simulation results.
    Fidelity(research::FidelityFlags),
    /// Groups in open water: Couzin's collective states of M_Zone (its phase picture) and
    /// M_Force's order over alignment.
    Collective(research::CollectiveFlags),
    /// What an OOD policy (`train --task ood`) drives the fish into: support scores next to
    /// the training data's and a lead-to-goal policy's, example episodes, a data wishlist.
    OodReport(research::OodReportFlags),
    /// The OOD idea tested in silico: fit M_ConvNet on narrow virtual-guppy data, add data
    /// recorded under an OOD or a lead-to-goal policy, and compare the refitted models' gaps.
    OodLoop(research::OodLoopArgs),
    /// The support model of a data-driven fish model's training recordings (what the OOD
    /// objective scores against), with its check on held-out and unseen situations.
    Support(research::SupportFlags),
    /// Export a trained policy as ONNX (observation in, turn angle out).
    Export(export::ExportArgs),
    /// Analyse a study directory: every measure and test of the paper (SPEC §8).
    Analyze(analyze::AnalyzeArgs),
    /// Fit M_ConvNet to recordings of live guppy pairs (behavioural cloning).
    FitConvnet(fit_convnet::FitConvnetArgs),
    /// Fit a population of a model's individuals to how much real recordings differ.
    FitPopulation(fit_population::FitPopulationArgs),
    /// Live trials: the bridge between a trained policy and the lab (`serve`), and a replay client.
    Live(live::LiveArgs),
    /// The virtual lab: tank, tracker, robot and a virtual guppy through the live bridge.
    Lab(live::LabArgs),
    /// Compare pairs of model fish with recorded pairs of live guppies (the classic offline test).
    CompareOffline(compare_offline::CompareOfflineArgs),
    /// Figures (SVG, PNG) and the self-contained HTML report of an analysed study.
    Report(report::ReportArgs),
}

/// The commands that check the method itself or explore the paper's outlook, rather than run
/// it: listed apart in `--help`, under their own heading, and run like every other command.
const RESEARCH_COMMANDS: &[&str] = &[
    "fidelity",
    "collective",
    "support",
    "ood-report",
    "ood-loop",
];

/// The heading `--help` lists [`RESEARCH_COMMANDS`] under.
pub const RESEARCH_HEADING: &str =
    "Research commands (checks of the method and the paper's outlook)";

/// The command line as parsed: [`Cli`] with the research commands listed under their own
/// heading in `--help` (clap lists all subcommands under one heading; these are hidden from it
/// and listed again below it, with their one-line help).
pub fn command() -> clap::Command {
    use clap::CommandFactory;
    let mut cmd = Cli::command();
    let width = cmd
        .get_subcommands()
        .map(|s| s.get_name().len())
        .max()
        .unwrap_or(0);
    let mut research = String::new();
    for name in RESEARCH_COMMANDS {
        let about = cmd
            .find_subcommand(name)
            .and_then(|s| s.get_about())
            .map(ToString::to_string)
            .unwrap_or_default();
        research.push_str(&format!("  {name:<width$}  {about}\n"));
        cmd = cmd.mut_subcommand(name, |s| s.hide(true));
    }
    cmd.help_template(format!(
        "{{before-help}}{{about-with-newline}}\n{{usage-heading}} {{usage}}\n\n\
         Commands:\n{{subcommands}}\n\n{RESEARCH_HEADING}:\n{research}\n\
         Options:\n{{options}}{{after-help}}"
    ))
}

/// Parses the process's arguments with [`command`] (exits with clap's message on bad ones).
pub fn parse() -> Cli {
    use clap::FromArgMatches;
    let matches = command().get_matches();
    Cli::from_arg_matches(&matches).unwrap_or_else(|e| e.exit())
}

/// Writes a command's output to stdout. A closed pipe (`fishprobe models | head`) ends the
/// output quietly instead of failing.
pub fn emit(text: &str) -> anyhow::Result<()> {
    use std::io::Write;
    let mut out = std::io::stdout().lock();
    match out.write_all(text.as_bytes()).and_then(|()| out.flush()) {
        Err(e) if e.kind() == std::io::ErrorKind::BrokenPipe => Ok(()),
        other => Ok(other?),
    }
}

/// Parameters as JSON numbers as written (f32 through `to_value` would print 6.3 as
/// 6.300000190734863).
pub fn params_json<T: serde::Serialize>(p: &T) -> anyhow::Result<serde_json::Value> {
    Ok(serde_json::from_str(&serde_json::to_string(p)?)?)
}

/// Most threads or concurrent steps a command starts, as a multiple of the cores: beyond it
/// they only contend (`train --jobs 100000` ran for minutes where 16 took 0.05 s).
pub const MAX_JOBS_PER_CORE: usize = 4;

/// Checks `--jobs`: 0 is an error; more than [`MAX_JOBS_PER_CORE`] x the cores is capped
/// there, with a note.
pub fn resolve_jobs(jobs: Option<usize>) -> anyhow::Result<Option<usize>> {
    let cores = std::thread::available_parallelism().map_or(1, |n| n.get());
    let cap = MAX_JOBS_PER_CORE * cores;
    match jobs {
        None => Ok(None),
        Some(0) => anyhow::bail!("--jobs must be at least 1"),
        Some(n) if n > cap => {
            note(&format!(
                "note: --jobs {n} capped to {cap} ({MAX_JOBS_PER_CORE} x the {cores} cores)"
            ));
            Ok(Some(cap))
        }
        Some(n) => Ok(Some(n)),
    }
}

/// Runs `f` on a thread pool of `jobs` threads (default: rayon's global pool, all cores).
pub fn with_jobs<T: Send>(jobs: Option<usize>, f: impl FnOnce() -> T + Send) -> anyhow::Result<T> {
    match resolve_jobs(jobs)? {
        None => Ok(f()),
        Some(n) => Ok(rayon::ThreadPoolBuilder::new()
            .num_threads(n)
            .build()?
            .install(f)),
    }
}

/// Takes the one-writer lock of an output directory for the whole command (see
/// [`fishprobe_io::DirLock`]); a second writer is refused with the holder's PID.
pub fn lock_out(dir: &std::path::Path, what: &str) -> anyhow::Result<fishprobe_io::DirLock> {
    Ok(fishprobe_io::DirLock::acquire(dir, what)?)
}

/// The one-writer lock of an output *file* ([`fishprobe_io::DirLock::for_file`]).
pub fn lock_out_file(file: &std::path::Path, what: &str) -> anyhow::Result<fishprobe_io::DirLock> {
    Ok(fishprobe_io::DirLock::for_file(file, what)?)
}

/// A line on stderr (a note, a warning, progress). A closed or full stderr is ignored: losing
/// a note must not abort (or, as `eprintln!` does, panic) a command.
pub fn note(line: &str) {
    use std::io::Write;
    let mut err = std::io::stderr().lock();
    let _ = err.write_all(line.as_bytes());
    if !line.ends_with('\n') {
        let _ = err.write_all(b"\n");
    }
}

/// Checks a `--minutes` value: one second to 24 hours
/// ([`fishprobe_learn::evaluate::minutes_in_range`]), shown as it was typed.
pub fn check_minutes<T>(flag: &str, m: T) -> anyhow::Result<()>
where
    T: Copy + Into<f64> + std::fmt::Display + std::fmt::LowerExp,
{
    use fishprobe_learn::evaluate::{minutes_in_range, MINUTES_RANGE};
    if !minutes_in_range(m.into()) {
        anyhow::bail!(
            "{flag} must lie in {MINUTES_RANGE}, got {}",
            fishprobe_sim::params::check::shown(m)
        );
    }
    Ok(())
}

/// Refuses a study path that is not a directory, saying whether it is missing or a file.
pub fn check_study_dir(study: &std::path::Path) -> anyhow::Result<()> {
    if study.is_dir() {
        return Ok(());
    }
    match fishprobe_io::limits::not_regular(study) {
        // A regular file (or a link to one).
        None => anyhow::bail!(
            "{}: a file, not a study directory (name the directory `fishprobe run --out` wrote)",
            study.display()
        ),
        Some(_) if !study.exists() => anyhow::bail!("{}: no such study directory", study.display()),
        Some(_) => anyhow::bail!("{}: not a directory, so not a study", study.display()),
    }
}

/// Refuses a list option that names one value twice (`--model Zone Zone`): each value is one
/// replicate, cell or row, and a repeat would count the same one twice.
pub fn no_repeats<T: PartialEq + std::fmt::Display>(
    flag: &str,
    values: &[T],
) -> anyhow::Result<()> {
    for (i, v) in values.iter().enumerate() {
        if values[..i].contains(v) {
            anyhow::bail!("{flag} names {v} twice: name each once");
        }
    }
    Ok(())
}

/// The controller of a `--policy` argument, sampling its actions with `stochastic`
/// (`--stochastic`; only a policy directory has a Gaussian to sample).
pub fn policy_controller(
    policy: &str,
    stochastic: bool,
) -> anyhow::Result<Box<dyn fishprobe_sim::Controller>> {
    use anyhow::Context;
    let flag = if stochastic { " --stochastic" } else { "" };
    fishprobe_learn::controller(policy, stochastic)
        .with_context(|| format!("loading --policy {policy}{flag}"))
}

/// Runs the parsed command.
pub fn run(cli: Cli) -> anyhow::Result<()> {
    match cli.command {
        Command::Models(a) => models::run(a),
        Command::Bench(a) => bench::run(a),
        Command::Config(a) => config::run(a),
        Command::Simulate(a) => simulate::run(a),
        Command::Inspect(a) => inspect::run(a),
        Command::ImportLegacy(a) => import_legacy::run(a),
        Command::Analyze(a) => analyze::run(a),
        Command::Report(a) => report::run(a),
        Command::FitConvnet(a) => fit_convnet::run(a),
        Command::FitPopulation(a) => fit_population::run(a),
        Command::CompareOffline(a) => compare_offline::run(a),
        Command::Run(a) => run::run(a),
        Command::Live(a) => live::run_live(a),
        Command::Lab(a) => live::run_lab(a),
        Command::Train(a) => train::run(a),
        Command::Evaluate(a) => evaluate::run(a),
        Command::Export(a) => export::run(a),
        Command::Assay(a) => assay::run(a),
        Command::Fidelity(a) => research::fidelity(a),
        Command::Collective(a) => research::collective(a),
        Command::Support(a) => research::support(a),
        Command::OodReport(a) => research::ood_report(a),
        Command::OodLoop(a) => research::ood_loop(a),
    }
}

/// The longest line of a settings file that a TOML error quotes (characters).
const TOML_LINE_SHOWN: usize = 200;

/// The live settings of the three live commands (`live serve`, `live biotracker`, `lab`):
/// a TOML file of [`LiveConfig`](fishprobe_live::session::LiveConfig) fields, or the paper's protocol; checked.
pub(crate) fn live_settings(
    path: Option<&std::path::Path>,
) -> anyhow::Result<fishprobe_live::session::LiveConfig> {
    let cfg: fishprobe_live::session::LiveConfig = match path {
        Some(p) => read_toml(p, "settings")?,
        None => fishprobe_live::session::LiveConfig::default(),
    };
    cfg.validate()?;
    Ok(cfg)
}

/// The pilot of the live commands: the policy loaded and checked against the live settings
/// once ([`fishprobe_learn::pilot`]), a copy for each trial.
pub(crate) fn pilot(
    policy: &str,
    live: &fishprobe_live::session::LiveConfig,
) -> anyhow::Result<
    impl FnMut() -> Result<Box<dyn fishprobe_sim::Controller>, fishprobe_live::LiveError>,
> {
    let c = fishprobe_learn::pilot(policy, &live.observation(), live.command_hz)
        .with_context(|| format!("loading policy {policy}"))?;
    Ok(move || Ok(c.boxed_clone()))
}

/// `text` parsed as TOML into `T`. The parser's error quotes the offending line whole, with a
/// caret under the column; for a line longer than [`TOML_LINE_SHOWN`] characters (a minified
/// or binary file given as settings) only its line, column and the parser's message are
/// shown, so that a mistaken file does not print a megabyte of itself.
pub(crate) fn parse_toml<T: serde::de::DeserializeOwned>(text: &str) -> anyhow::Result<T> {
    toml::from_str(text).map_err(|e| anyhow::Error::msg(short_toml_error(text, &e)))
}

/// The TOML file `path` (a `what`: "settings", "study file", ...) read, at most
/// [`fishprobe_io::limits::MAX_TEXT_BYTES`], and parsed into `T`; errors name the file.
pub(crate) fn read_toml<T: serde::de::DeserializeOwned>(
    path: &std::path::Path,
    what: &str,
) -> anyhow::Result<T> {
    let text = fishprobe_io::read_small_text(path)
        .with_context(|| format!("reading {what} {}", path.display()))?;
    parse_toml(&text).with_context(|| format!("{what} {}", path.display()))
}

fn short_toml_error(text: &str, e: &toml::de::Error) -> String {
    let full = e.to_string();
    if full.lines().all(|l| l.chars().count() <= TOML_LINE_SHOWN) {
        return full;
    }
    let message = e.message().trim_end();
    let Some(span) = e.span() else {
        return message.to_string();
    };
    let before = text.get(..span.start).unwrap_or(text);
    let line = before.matches('\n').count() + 1;
    let column = before.rsplit('\n').next().map_or(0, |l| l.chars().count()) + 1;
    format!(
        "TOML parse error at line {line}, column {column} (the line is too long to show): \
         {message}"
    )
}

/// `cfg` with the `[analysis]` table of the TOML file `path` applied.
pub(crate) fn analysis_settings(
    cfg: &fishprobe_analysis::AnalysisConfig,
    path: &std::path::Path,
) -> anyhow::Result<fishprobe_analysis::AnalysisConfig> {
    let table: toml::Table = read_toml(path, "analysis settings")?;
    let Some(analysis) = table.get("analysis") else {
        anyhow::bail!(
            "analysis settings {}: no [analysis] table (write e.g. `[analysis]` then `competence_threshold = 0.9`)",
            path.display()
        );
    };
    let overrides: serde_json::Map<String, serde_json::Value> = serde_json::to_value(analysis)
        .ok()
        .and_then(|v| v.as_object().cloned())
        .with_context(|| {
            format!(
                "analysis settings {}: `analysis` is not a table",
                path.display()
            )
        })?;
    cfg.with_overrides(&overrides)
        .with_context(|| format!("analysis settings {}", path.display()))
}
