//! Saving and loading weights: a safetensors file of named float32 tensors plus a JSON sidecar
//! describing the architecture, so a file from another version or architecture is refused
//! with a clear error instead of being misread.

use crate::error::NnError;
use safetensors::tensor::{Dtype, TensorView};
use std::collections::BTreeMap;
use std::path::Path;

/// Named tensors: name → (shape, data).
pub type Tensors = BTreeMap<String, (Vec<usize>, Vec<f32>)>;

/// Serialises tensors to safetensors bytes.
pub fn to_bytes(tensors: &Tensors) -> Result<Vec<u8>, NnError> {
    let bytes: Vec<(String, Vec<usize>, Vec<u8>)> = tensors
        .iter()
        .map(|(k, (shape, data))| {
            (
                k.clone(),
                shape.clone(),
                data.iter().flat_map(|v| v.to_le_bytes()).collect(),
            )
        })
        .collect();
    let views: Vec<(String, TensorView<'_>)> = bytes
        .iter()
        .map(|(k, shape, b)| {
            TensorView::new(Dtype::F32, shape.clone(), b)
                .map(|v| (k.clone(), v))
                .map_err(|e| NnError::Format(format!("tensor {k}: {e}")))
        })
        .collect::<Result<_, _>>()?;
    safetensors::serialize(views, None).map_err(|e| NnError::Format(e.to_string()))
}

/// Parses safetensors bytes (float32 tensors only).
pub fn from_bytes(bytes: &[u8]) -> Result<Tensors, NnError> {
    let st = safetensors::SafeTensors::deserialize(bytes)
        .map_err(|e| NnError::Format(format!("not a safetensors file: {e}")))?;
    let mut out = Tensors::new();
    for (name, view) in st.tensors() {
        if view.dtype() != Dtype::F32 {
            return Err(NnError::Format(format!(
                "tensor {name} is {:?}, expected F32",
                view.dtype()
            )));
        }
        let data = view
            .data()
            .chunks_exact(4)
            .map(|c| f32::from_le_bytes([c[0], c[1], c[2], c[3]]))
            .collect();
        out.insert(name, (view.shape().to_vec(), data));
    }
    Ok(out)
}

/// Writes tensors to `path` (safetensors) and `meta` to `path` with `.json` appended
/// (atomically: temporary file, then rename).
pub fn save(path: &Path, tensors: &Tensors, meta: &serde_json::Value) -> Result<(), NnError> {
    write_atomic(path, &to_bytes(tensors)?)?;
    let sidecar = sidecar_path(path);
    let text = serde_json::to_string_pretty(meta).map_err(|e| NnError::Format(e.to_string()))?;
    write_atomic(&sidecar, text.as_bytes())
}

/// Reads tensors and their sidecar.
pub fn load(path: &Path) -> Result<(Tensors, serde_json::Value), NnError> {
    let io = |p: &Path, e: std::io::Error| NnError::Io(format!("{}: {e}", p.display()));
    let bytes = std::fs::read(path).map_err(|e| io(path, e))?;
    let tensors =
        from_bytes(&bytes).map_err(|e| NnError::Format(format!("{}: {e}", path.display())))?;
    let sidecar = sidecar_path(path);
    let text = std::fs::read_to_string(&sidecar).map_err(|e| io(&sidecar, e))?;
    let meta = serde_json::from_str(&text)
        .map_err(|e| NnError::Format(format!("{}: {e}", sidecar.display())))?;
    Ok((tensors, meta))
}

/// `weights.safetensors` → `weights.safetensors.json`.
pub fn sidecar_path(path: &Path) -> std::path::PathBuf {
    let mut s = path.as_os_str().to_owned();
    s.push(".json");
    s.into()
}

/// Writes via a synced temporary file and a rename.
pub fn write_atomic(path: &Path, bytes: &[u8]) -> Result<(), NnError> {
    use std::io::Write;
    let err = |e: std::io::Error| NnError::Io(format!("{}: {e}", path.display()));
    if let Some(dir) = path.parent().filter(|d| !d.as_os_str().is_empty()) {
        std::fs::create_dir_all(dir).map_err(err)?;
    }
    let mut tmp = path.as_os_str().to_owned();
    tmp.push(format!(".{}.partial", std::process::id()));
    let tmp = std::path::PathBuf::from(tmp);
    let r = (|| {
        let mut f = std::fs::File::create(&tmp)?;
        f.write_all(bytes)?;
        f.sync_all()?;
        std::fs::rename(&tmp, path)
    })();
    if let Err(e) = r {
        let _ = std::fs::remove_file(&tmp);
        return Err(err(e));
    }
    Ok(())
}
