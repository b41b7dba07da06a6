//! `fishprobe export`: a trained policy as ONNX for the robot PC.

use anyhow::{Context, Result};
use clap::Args;
use fishprobe_learn::GaussianPolicy;
use std::path::PathBuf;

use super::emit;

#[derive(Debug, Args)]
pub struct ExportArgs {
    /// Policy directory from `fishprobe train`.
    #[arg(long)]
    policy: PathBuf,
    /// The ONNX file to write. Input `obs` (batch x 180 float32), output `turn` (batch x 1,
    /// radians): the policy's deterministic action.
    #[arg(long)]
    onnx: PathBuf,
}

pub fn run(a: ExportArgs) -> Result<()> {
    let (policy, _) = GaussianPolicy::load(&a.policy)
        .with_context(|| format!("loading {}", a.policy.display()))?;
    let bytes = fishprobe_learn::onnx::policy_to_onnx(&policy)?;
    fishprobe_io::write_atomically(&a.onnx, &bytes)?;
    emit(&format!(
        "{}: ONNX (IR 8, opset 13), input `obs` [batch, {}], output `turn` [batch, 1] in rad\n",
        a.onnx.display(),
        policy.obs_dim()
    ))
}
