//! `fishprobe import-legacy`: converts the lab's pre-2020 files to robofish.io 1.0.

use anyhow::{bail, Context, Result};
use clap::Args;
use fishprobe_io::{read_legacy, write_trial, Attr};
use std::path::{Path, PathBuf};

use super::emit;

#[derive(Debug, Args)]
pub struct ImportLegacyArgs {
    /// Legacy files, or directories whose *.hdf5 files are converted.
    #[arg(required = true)]
    inputs: Vec<PathBuf>,
    /// Output directory (created if missing); files keep their names.
    #[arg(long)]
    out: PathBuf,
}

fn expand(inputs: &[PathBuf]) -> Result<Vec<PathBuf>> {
    let mut files = Vec::new();
    for i in inputs {
        if i.is_dir() {
            let mut v: Vec<PathBuf> = std::fs::read_dir(i)
                .with_context(|| format!("cannot list {}", i.display()))?
                .filter_map(|e| e.ok().map(|e| e.path()))
                .filter(|p| p.extension().is_some_and(|x| x == "hdf5" || x == "h5"))
                .collect();
            v.sort();
            files.extend(v);
        } else {
            files.push(i.clone());
        }
    }
    Ok(files)
}

fn convert(input: &Path, out_dir: &Path) -> Result<PathBuf> {
    let mut t = read_legacy(input)?;
    t.attributes
        .entry("experiment_setup".into())
        .or_insert_with(|| {
            Attr::Text(format!(
                "converted from the lab's pre-2020 layout by fishprobe import-legacy {}",
                env!("CARGO_PKG_VERSION")
            ))
        });
    let name = input.file_name().context("input has no file name")?;
    let out = out_dir.join(name);
    if out.canonicalize().ok() == input.canonicalize().ok() {
        bail!(
            "{}: refusing to overwrite the input with its conversion",
            input.display()
        );
    }
    write_trial(&out, &t)?;
    Ok(out)
}

pub fn run(a: ImportLegacyArgs) -> Result<()> {
    let files = expand(&a.inputs)?;
    if files.is_empty() {
        bail!("no .hdf5 files in {:?}", a.inputs);
    }
    let _lock = super::lock_out(&a.out, "import-legacy")?;
    let mut done = 0;
    let mut failed = 0;
    for f in &files {
        match convert(f, &a.out) {
            Ok(_) => done += 1,
            Err(e) => {
                failed += 1;
                say!("error: {e:#}");
            }
        }
    }
    emit(&format!(
        "converted {done} of {} files into {}\n",
        files.len(),
        a.out.display()
    ))?;
    if failed > 0 {
        bail!("{failed} files could not be converted");
    }
    Ok(())
}
