//! The commands that check the method itself or explore the paper's outlook, as library
//! calls: the fidelity sweep ([`fidelity`]), groups in open water ([`collective`]), the support
//! of a data-driven model's training views ([`support`]), what an OOD policy drives the fish
//! into ([`ood_report`]) and the OOD idea tested in silico ([`ood_loop`]). Each takes its
//! plain settings (validated here, field by field, naming the setting), does the work (writing
//! its files), and returns what to show; the `fishprobe` command line maps its flags onto the
//! settings once, calls and prints.
//!
//! ```no_run
//! use fishprobe_research::ood_loop::{self, OodLoopConfig};
//!
//! let cfg = OodLoopConfig { rounds: 3, ..OodLoopConfig::default() };
//! let notes = |line: &str| eprintln!("{line}");
//! let by = fishprobe_research::Runner { build: "0.1.0", command: "", notes: &notes };
//! let md = ood_loop::run("loop".as_ref(), &[0, 1, 2], &cfg, by)?;
//! println!("{md}");
//! # Ok::<(), fishprobe_research::ResearchError>(())
//! ```

#![warn(missing_docs)]

pub mod collective;
mod error;
pub mod fidelity;
pub mod ood_loop;
pub mod ood_report;
pub mod reference;
pub mod support;

pub use error::{ResearchError, Result};

/// Who runs a research command: the fishprobe build recorded with what it trains and fits
/// (`fishprobe --version`), and where its progress lines go.
#[derive(Clone, Copy)]
pub struct Runner<'a> {
    /// The build, e.g. "0.1.0 (commit 0123456789ab)".
    pub build: &'a str,
    /// The command line that asked for the work, recorded with the files it writes.
    pub command: &'a str,
    /// Receives each progress line (the command line writes them to stderr).
    pub notes: &'a (dyn Fn(&str) + Sync),
}

impl Runner<'_> {
    /// Passes on one progress line.
    pub fn note(&self, line: &str) {
        (self.notes)(line);
    }
}

/// Refuses a list (the setting `what`) that names one value twice: each value is one
/// replicate, cell or row, and a repeat would count the same one twice.
pub(crate) fn no_repeats<T: PartialEq + std::fmt::Display>(what: &str, values: &[T]) -> Result<()> {
    for (i, v) in values.iter().enumerate() {
        if values[..i].contains(v) {
            return Err(ResearchError::Refused(format!(
                "{what} names {v} twice: name each once"
            )));
        }
    }
    Ok(())
}
