//! `fishprobe export`: a trained policy as ONNX for the robot PC, or M_ConvNet in fishprobe's
//! fish-model contract (docs/onnx-models.md).

use anyhow::{bail, Context, Result};
use clap::Args;
use fishprobe_learn::GaussianPolicy;
use fishprobe_models::ConvNet;
use std::path::{Path, PathBuf};

use super::emit;

#[derive(Debug, Args)]
pub struct ExportArgs {
    /// Policy directory from `fishprobe train`: writes input `obs` (batch x 180 float32),
    /// output `turn` (batch x 1, radians), the policy's deterministic action.
    #[arg(long, conflicts_with = "convnet")]
    policy: Option<PathBuf>,
    /// M_ConvNet instead: the shipped weights, or a weights file of `fishprobe fit-convnet`
    /// (`--convnet FILE`). Writes input `view` (batch x 3 x 72), output `logits` (batch x
    /// 1025), loadable as `--model onnx:FILE`.
    #[arg(long, num_args = 0..=1, default_missing_value = "")]
    convnet: Option<String>,
    /// The ONNX file to write.
    #[arg(long)]
    onnx: PathBuf,
}

pub fn run(a: ExportArgs) -> Result<()> {
    match (&a.policy, &a.convnet) {
        (Some(dir), None) => {
            let (policy, _) =
                GaussianPolicy::load(dir).with_context(|| format!("loading {}", dir.display()))?;
            let bytes = fishprobe_learn::onnx::policy_to_onnx(&policy)?;
            fishprobe_io::write_atomically(&a.onnx, &bytes)?;
            emit(&format!(
                "{}: ONNX (IR 8, opset 13), input `obs` [batch, {}], output `turn` [batch, 1] in rad\n",
                a.onnx.display(),
                policy.obs_dim()
            ))
        }
        (None, Some(weights)) => {
            let net = if weights.is_empty() {
                ConvNet::shipped()?
            } else {
                ConvNet::load(Path::new(weights))?
            };
            let bytes = fishprobe_learn::onnx::convnet_to_onnx(&net)?;
            fishprobe_io::write_atomically(&a.onnx, &bytes)?;
            emit(&format!(
                "{}: ONNX (IR 8, opset 13), input `view` [batch, 3, {}], output `logits` [batch, {}]: M_ConvNet ({}); use it as --model onnx:{}\n",
                a.onnx.display(),
                net.arch.bins,
                net.arch.cells(),
                if weights.is_empty() { "shipped weights" } else { weights.as_str() },
                a.onnx.display()
            ))
        }
        _ => bail!("say what to export: --policy DIR or --convnet [WEIGHTS]"),
    }
}
