//! One ONNX network checked against a contract and planned for a fixed batch size.

use crate::guard::{mib, MemoryBound, Stopped};
use crate::{OnnxError, ENGINE};
use std::path::{Path, PathBuf};
use std::sync::Arc;
use tract_onnx::prelude::*;
use tract_onnx::tract_hir::infer::Factoid;
use tract_onnx::tract_hir::internal::DimLike;

/// What a file must look like: one float32 input and one float32 output, each `[batch, ...]`.
#[derive(Debug, Clone, PartialEq, Eq)]
pub struct Contract {
    /// What the file is, for messages ("a policy", "a fish model").
    pub what: &'static str,
    /// The input's name.
    pub input: &'static str,
    /// The input's shape after the batch dimension.
    pub input_dims: Vec<usize>,
    /// The output's name (`None`: any).
    pub output: Option<&'static str>,
    /// The output's shape after the batch dimension.
    pub output_dims: Vec<usize>,
}

impl Contract {
    /// fishprobe's policy contract: `obs` float32 `[batch, 180]` (SPEC §5) in, the turn angle
    /// in radians float32 `[batch, 1]` out.
    pub fn policy() -> Self {
        Self {
            what: "a policy",
            input: "obs",
            input_dims: vec![180],
            output: None,
            output_dims: vec![1],
        }
    }

    /// fishprobe's fish-model contract: `view` float32 `[batch, 3, bins]` (M_ConvNet's view)
    /// in, `logits` float32 `[batch, cells]` over the (v, ω) grid out.
    pub fn fish(bins: usize, cells: usize) -> Self {
        Self {
            what: "a fish model",
            input: "view",
            input_dims: vec![3, bins],
            output: Some("logits"),
            output_dims: vec![cells],
        }
    }

    fn describe(&self) -> String {
        let dims = |d: &[usize]| {
            std::iter::once("batch".to_string())
                .chain(d.iter().map(usize::to_string))
                .collect::<Vec<_>>()
                .join(", ")
        };
        format!(
            "{} with input `{}` float32 [{}] and {} float32 [{}]",
            self.what,
            self.input,
            dims(&self.input_dims),
            self.output
                .map_or_else(|| "one output".to_string(), |o| format!("output `{o}`")),
            dims(&self.output_dims)
        )
    }
}

type Plan = TypedRunnableModel;

/// A network that passed its contract, planned for `batch` rows at a time.
#[derive(Clone)]
pub struct OnnxNet {
    path: PathBuf,
    sha256: String,
    /// The file as read (re-planning for another batch never reads it again).
    bytes: Arc<Vec<u8>>,
    contract: Contract,
    metadata: std::collections::BTreeMap<String, String>,
    plan: Arc<Plan>,
    /// The memory the engine may hold for it (planning and every run).
    bound: MemoryBound,
    batch: usize,
    input_len: usize,
    output_len: usize,
    input_dims: Vec<usize>,
}

impl std::fmt::Debug for OnnxNet {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        f.debug_struct("OnnxNet")
            .field("path", &self.path)
            .field("sha256", &self.sha256)
            .field("batch", &self.batch)
            .finish()
    }
}

/// Largest ONNX file accepted (a policy of 2 x 256 units is 0.3 MB, the ConvNet fish 1 MB).
pub const MAX_FILE_BYTES: u64 = 512 << 20;

/// Most nodes an ONNX file may hold, those of its subgraphs included, unless
/// [`NODES_ENV`] sets another number: the engine's planning time grows faster than the
/// node count (a chain of 20,000 nodes took 6 s, one of 100,000 did not finish in 90 s),
/// while the networks of fishprobe's contracts have tens of nodes and a large exported policy
/// a few hundred. Just under this limit the engine plans a chain in 0.6 s.
pub const MAX_NODES: usize = 10_000;

/// The environment variable that sets the node limit of every ONNX file (a whole number in
/// [1, 1,000,000]) for a user with a big honest network.
pub const NODES_ENV: &str = "FISHPROBE_ONNX_MAX_NODES";

/// The node limit: [`NODES_ENV`] if set (`setting`), else [`MAX_NODES`].
pub fn node_limit(setting: Option<&str>) -> Result<usize, crate::OnnxError> {
    let Some(v) = setting else {
        return Ok(MAX_NODES);
    };
    match v.trim().parse::<usize>() {
        Ok(n) if (1..=1_000_000).contains(&n) => Ok(n),
        _ => Err(crate::OnnxError::Setting(format!(
            "{NODES_ENV} = `{v}`: must be a whole number in [1, 1000000]"
        ))),
    }
}

/// Nodes of a graph and of every subgraph its nodes' attributes hold (`If`, `Loop`, `Scan`).
fn count_nodes(g: &tract_onnx::pb::GraphProto) -> usize {
    g.node
        .iter()
        .map(|n| {
            1 + n
                .attribute
                .iter()
                .map(|a| {
                    a.g.as_ref().map_or(0, count_nodes)
                        + a.graphs.iter().map(count_nodes).sum::<usize>()
                })
                .sum::<usize>()
        })
        .sum()
}

/// The bytes of an ONNX file, as the loader reads them: a regular file of at most
/// [`MAX_FILE_BYTES`] (bounded by reading too, so a file that grows meanwhile is refused
/// all the same). Also what a model's SHA-256 is taken of.
pub fn read_model_file(path: &Path) -> Result<Vec<u8>, OnnxError> {
    use std::io::Read;
    let read_err = |reason| OnnxError::Read {
        path: path.to_path_buf(),
        reason,
    };
    let meta = std::fs::metadata(path).map_err(read_err)?;
    if !meta.is_file() {
        return Err(OnnxError::NotOnnx {
            path: path.to_path_buf(),
            what: "not a regular file".into(),
        });
    }
    if meta.len() > MAX_FILE_BYTES {
        return Err(OnnxError::NotOnnx {
            path: path.to_path_buf(),
            what: format!(
                "{} bytes, more than the {MAX_FILE_BYTES} accepted",
                meta.len()
            ),
        });
    }
    let mut bytes = Vec::new();
    std::fs::File::open(path)
        .and_then(|f| f.take(MAX_FILE_BYTES + 1).read_to_end(&mut bytes))
        .map_err(read_err)?;
    if bytes.len() as u64 > MAX_FILE_BYTES {
        // It grew since its size was read.
        return Err(OnnxError::NotOnnx {
            path: path.to_path_buf(),
            what: format!("more than the {MAX_FILE_BYTES} bytes accepted (reading stopped there)"),
        });
    }
    Ok(bytes)
}

/// The SHA-256 of `bytes`, lower-case hex (what trial files record for a model file).
pub fn sha256_hex(bytes: &[u8]) -> String {
    use sha2::Digest;
    hex(&sha2::Sha256::digest(bytes))
}

/// `bytes` as lower-case hex, two digits a byte (a digest computed elsewhere, e.g. streamed).
pub fn hex(bytes: &[u8]) -> String {
    bytes.iter().map(|b| format!("{b:02x}")).collect()
}

impl OnnxNet {
    /// Loads `path`, checks it against `contract` and plans it for `batch` rows per run.
    pub fn load(path: &Path, contract: &Contract, batch: usize) -> Result<Self, OnnxError> {
        Self::load_with(path, batch, |_| Ok::<_, OnnxError>(contract.clone()))
    }

    /// Like [`OnnxNet::load`], with the contract decided from the file's `metadata_props`
    /// (a fish model's grid may be set there).
    pub fn load_with<E: std::fmt::Display>(
        path: &Path,
        batch: usize,
        contract_of: impl FnOnce(&std::collections::BTreeMap<String, String>) -> Result<Contract, E>,
    ) -> Result<Self, OnnxError> {
        let bytes = Arc::new(read_model_file(path)?);
        let bound = Self::bound(path, bytes.len())?;
        let metadata = Self::inspect(path, &bytes, bound)?;
        let contract = contract_of(&metadata).map_err(|what| OnnxError::Contract {
            path: path.to_path_buf(),
            expected: "metadata_props fishprobe can use".into(),
            found: what.to_string(),
        })?;
        Self::plan(path, bytes, contract, metadata, batch, bound)
    }

    /// The same network planned for another batch size.
    pub fn with_batch(&self, batch: usize) -> Result<Self, OnnxError> {
        Self::plan(
            &self.path,
            self.bytes.clone(),
            self.contract.clone(),
            self.metadata.clone(),
            batch,
            self.bound,
        )
    }

    /// The file's `metadata_props`.
    pub fn metadata(&self) -> &std::collections::BTreeMap<String, String> {
        &self.metadata
    }

    fn bound(path: &Path, file_bytes: usize) -> Result<MemoryBound, OnnxError> {
        MemoryBound::for_file(file_bytes).map_err(|what| OnnxError::Limit {
            path: path.to_path_buf(),
            what: what.to_string(),
        })
    }

    /// Parses the file (with bounded memory: a file's nodes and tensors become structures
    /// larger than their bytes), refuses it above the node limit, and returns its
    /// `metadata_props`.
    fn inspect(
        path: &Path,
        bytes: &[u8],
        bound: MemoryBound,
    ) -> Result<std::collections::BTreeMap<String, String>, OnnxError> {
        let limit = node_limit(std::env::var(NODES_ENV).ok().as_deref()).map_err(|what| {
            OnnxError::Limit {
                path: path.to_path_buf(),
                what: what.to_string(),
            }
        })?;
        let parsed = crate::guard::capped(bound.bytes, || {
            tract_onnx::onnx()
                .proto_model_for_read(&mut &bytes[..])
                .map(|proto| {
                    let nodes = proto.graph.as_ref().map_or(0, count_nodes);
                    let meta = proto
                        .metadata_props
                        .iter()
                        .map(|p| (p.key.clone(), p.value.clone()))
                        .collect();
                    (nodes, meta)
                })
        })
        .map_err(|stop| engine_stopped(path, 1, bytes.len(), bound, stop))?;
        let (nodes, meta) = parsed.map_err(|e| OnnxError::NotOnnx {
            path: path.to_path_buf(),
            what: first_line(&e),
        })?;
        if nodes > limit {
            return Err(OnnxError::Limit {
                path: path.to_path_buf(),
                what: format!(
                    "{nodes} nodes, more than the {limit} fishprobe plans (the engine's planning \
                     time grows faster than the node count; set {NODES_ENV} to raise it)"
                ),
            });
        }
        Ok(meta)
    }

    /// [`Self::plan_unguarded`] with bounded memory: the engine folds constants while it
    /// plans, so a tiny file can make it allocate gigabytes (`crate::guard`).
    fn plan(
        path: &Path,
        bytes: Arc<Vec<u8>>,
        contract: Contract,
        metadata: std::collections::BTreeMap<String, String>,
        batch: usize,
        bound: MemoryBound,
    ) -> Result<Self, OnnxError> {
        let file_bytes = bytes.len();
        crate::guard::capped(bound.bytes, || {
            Self::plan_unguarded(path, bytes, contract, metadata, batch, bound)
        })
        .map_err(|stop| engine_stopped(path, batch, file_bytes, bound, stop))?
    }

    fn plan_unguarded(
        path: &Path,
        bytes: Arc<Vec<u8>>,
        contract: Contract,
        metadata: std::collections::BTreeMap<String, String>,
        batch: usize,
        bound: MemoryBound,
    ) -> Result<Self, OnnxError> {
        let sha256 = sha256_hex(&bytes);
        let expected = contract.describe();
        let contract_err = |found: String| OnnxError::Contract {
            path: path.to_path_buf(),
            expected: expected.clone(),
            found,
        };
        let mut model = tract_onnx::onnx()
            .model_for_read(&mut bytes.as_slice())
            .map_err(|e| OnnxError::NotOnnx {
                path: path.to_path_buf(),
                what: first_line(&e),
            })?;
        // Names, counts and types, as declared.
        let inputs: Vec<String> = model
            .input_outlets()
            .map_err(|e| contract_err(first_line(&e)))?
            .iter()
            .map(|o| model.node(o.node).name.clone())
            .collect();
        let outputs: Vec<String> = model
            .output_outlets()
            .map_err(|e| contract_err(first_line(&e)))?
            .iter()
            .map(|o| {
                model
                    .outlet_label(*o)
                    .map_or_else(|| model.node(o.node).name.clone(), str::to_string)
            })
            .collect();
        if inputs != [contract.input] {
            return Err(contract_err(format!("inputs {inputs:?}")));
        }
        if outputs.len() != 1 || contract.output.is_some_and(|o| outputs[0] != o) {
            return Err(contract_err(format!("outputs {outputs:?}")));
        }
        let declared = model
            .input_fact(0)
            .map_err(|e| contract_err(first_line(&e)))?
            .clone();
        if let Some(dt) = declared.datum_type.concretize() {
            if dt != f32::datum_type() {
                return Err(contract_err(format!(
                    "input `{}` of type {dt:?}",
                    inputs[0]
                )));
            }
        }
        let shape: Vec<usize> = std::iter::once(batch)
            .chain(contract.input_dims.iter().copied())
            .collect();
        model
            .set_input_fact(0, InferenceFact::dt_shape(f32::datum_type(), &shape))
            .map_err(|e| contract_err(first_line(&e)))?;
        let typed = model.into_optimized().map_err(|e| {
            let msg = first_line(&e);
            if msg.contains("nimplemented") || msg.contains("not supported") {
                OnnxError::Unsupported {
                    path: path.to_path_buf(),
                    what: msg,
                }
            } else {
                contract_err(format!(
                    "input `{}` declared as {declared:?} ({msg})",
                    inputs[0]
                ))
            }
        })?;
        let out_fact = typed
            .output_fact(0)
            .map_err(|e| contract_err(first_line(&e)))?
            .clone();
        if out_fact.datum_type != f32::datum_type() {
            return Err(contract_err(format!(
                "output `{}` of type {:?}",
                outputs[0], out_fact.datum_type
            )));
        }
        let out_shape: Option<Vec<usize>> =
            out_fact.shape.iter().map(|d| d.to_usize().ok()).collect();
        let want_out: Vec<usize> = std::iter::once(batch)
            .chain(contract.output_dims.iter().copied())
            .collect();
        if out_shape.as_deref() != Some(&want_out[..]) {
            return Err(contract_err(format!(
                "output `{}` of shape {:?} for a batch of {batch}",
                outputs[0], out_fact.shape
            )));
        }
        let plan = typed.into_runnable().map_err(|e| OnnxError::Unsupported {
            path: path.to_path_buf(),
            what: first_line(&e),
        })?;
        Ok(Self {
            path: path.to_path_buf(),
            sha256,
            bytes: bytes.clone(),
            input_len: contract.input_dims.iter().product(),
            output_len: contract.output_dims.iter().product(),
            contract,
            metadata,
            plan,
            bound,
            batch,
            input_dims: shape,
        })
    }

    /// The file.
    pub fn path(&self) -> &Path {
        &self.path
    }

    /// The file's SHA-256 (hex).
    pub fn sha256(&self) -> &str {
        &self.sha256
    }

    /// Rows per run.
    pub fn batch(&self) -> usize {
        self.batch
    }

    /// Runs `input` (`batch` rows of the contract's input) and writes `batch` rows of output.
    pub fn run(&self, input: &[f32], output: &mut [f32]) -> Result<(), OnnxError> {
        let run_err = |what: String| OnnxError::Run {
            path: self.path.clone(),
            what,
        };
        if input.len() != self.batch * self.input_len
            || output.len() != self.batch * self.output_len
        {
            return Err(run_err(format!(
                "{} input and {} output values for {} rows",
                input.len(),
                output.len(),
                self.batch
            )));
        }
        let t = Tensor::from_shape(&self.input_dims, input).map_err(|e| run_err(first_line(&e)))?;
        // Bounded like planning: a shape the network computes at run time can be huge too.
        let out = crate::guard::capped(self.bound.bytes, || self.plan.run(tvec!(t.into())))
            .map_err(|stop| {
                engine_stopped(&self.path, self.batch, self.bytes.len(), self.bound, stop)
            })?
            .map_err(|e| run_err(first_line(&e)))?;
        let view = out[0]
            .to_plain_array_view::<f32>()
            .map_err(|e| run_err(first_line(&e)))?;
        if view.len() != output.len() {
            return Err(run_err(format!("{} output values", view.len())));
        }
        for (o, v) in output.iter_mut().zip(view.iter()) {
            *o = *v;
        }
        Ok(())
    }
}

/// The engine stopped (panicked) inside [`crate::guard::capped`]: an allocation the guard
/// refused (over the file's memory bound, or a single tensor over
/// [`crate::MAX_ALLOCATION_BYTES`]), named with its sizes, or any other panic of the engine's
/// with its own message.
fn engine_stopped(
    path: &Path,
    batch: usize,
    file_bytes: usize,
    bound: MemoryBound,
    stop: Stopped,
) -> OnnxError {
    let what = match stop {
        Stopped::Memory(r) if r.asked > crate::MAX_ALLOCATION_BYTES => format!(
            "it needs more memory than fishprobe gives an ONNX network: one tensor of {} at a \
             batch of {batch}, over the cap of {} on any single tensor \
             (fishprobe_onnx::MAX_ALLOCATION_BYTES)",
            mib(r.asked),
            mib(crate::MAX_ALLOCATION_BYTES)
        ),
        Stopped::Memory(r) => format!(
            "it needs more memory than fishprobe gives an ONNX network: {} asked for with {} \
             already held at a batch of {batch}, over this file's bound of {}",
            mib(r.asked),
            mib(usize::try_from(r.held).unwrap_or(0)),
            bound.describe(file_bytes)
        ),
        Stopped::Panic(what) => format!("the engine stopped: {what}"),
    };
    OnnxError::Unsupported {
        path: path.to_path_buf(),
        what,
    }
}

/// An error's first line, with the engine's context chain flattened.
fn first_line(e: &impl std::fmt::Display) -> String {
    let s = format!("{e:#}");
    let line = s.lines().next().unwrap_or("").trim().to_string();
    if line.is_empty() {
        format!("({ENGINE} gave no reason)")
    } else {
        line
    }
}

#[cfg(test)]
mod tests {
    use super::{hex, sha256_hex};

    #[test]
    fn hex_and_sha256_known_answers() {
        assert_eq!(hex(&[0x00, 0xab, 0x0f, 0xff]), "00ab0fff");
        assert_eq!(hex(&[]), "");
        // FIPS 180-2, appendix B.1.
        assert_eq!(
            sha256_hex(b"abc"),
            "ba7816bf8f01cfea414140de5dae2223b00361a396177a9cb410ff61f20015ad"
        );
    }
}
