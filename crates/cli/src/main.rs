//! The `fishprobe` command line: one subcommand per job. `main` only parses, runs and maps
//! errors to an exit code; the work is in `commands/`.

mod commands;

use clap::Parser;
use std::process::ExitCode;

fn main() -> ExitCode {
    let cli = commands::Cli::parse();
    match commands::run(cli) {
        Ok(()) => ExitCode::SUCCESS,
        Err(e) => {
            // Not `eprintln!`: it panics when stderr is closed or full (`2>/dev/full`).
            commands::note(&format!("error: {e:#}"));
            ExitCode::FAILURE
        }
    }
}
