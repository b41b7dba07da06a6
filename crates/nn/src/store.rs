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

/// Largest weights file [`load`] reads (the ConvNet fish is 0.9 MB, a policy of 2 x 256 units
/// about as much; the limit of ONNX files, 512 MiB, leaves room for any network fishprobe runs on a
/// CPU).
pub const MAX_WEIGHTS_BYTES: u64 = 512 << 20;

/// Largest sidecar (`.json` beside the weights) [`load`] reads; fishprobe's are a few kB.
pub const MAX_SIDECAR_BYTES: u64 = 16 << 20;

/// Reads tensors and their sidecar. Neither is read beyond its limit
/// ([`MAX_WEIGHTS_BYTES`], [`MAX_SIDECAR_BYTES`]), so a wrong path (`/dev/zero`, a pipe, a
/// trial file of gigabytes) is refused once that much is read instead of filling memory.
pub fn load(path: &Path) -> Result<(Tensors, serde_json::Value), NnError> {
    let read = |p: &Path, max, name| {
        read_at_most(p, max, name).map_err(|e| NnError::Io(format!("{}: {e}", p.display())))
    };
    let bytes = read(
        path,
        MAX_WEIGHTS_BYTES,
        "fishprobe_nn::store::MAX_WEIGHTS_BYTES",
    )?;
    let tensors =
        from_bytes(&bytes).map_err(|e| NnError::Format(format!("{}: {e}", path.display())))?;
    let sidecar = sidecar_path(path);
    let text = read(
        &sidecar,
        MAX_SIDECAR_BYTES,
        "fishprobe_nn::store::MAX_SIDECAR_BYTES",
    )?;
    let meta = serde_json::from_slice(&text)
        .map_err(|e| NnError::Format(format!("{}: {e}", sidecar.display())))?;
    Ok((tensors, meta))
}

/// The bytes of a file fishprobe reads whole (weights, sidecars, support files), refused with
/// an error naming the limit (`limit_name`, the constant's path) once more than `max` are
/// read. Bounded by reading, not by the file's stated size, so devices and pipes are refused
/// too.
pub fn read_at_most(path: &Path, max: u64, limit_name: &str) -> std::io::Result<Vec<u8>> {
    use std::io::Read;
    let mut bytes = Vec::new();
    std::fs::File::open(path)?
        .take(max + 1)
        .read_to_end(&mut bytes)?;
    if bytes.len() as u64 > max {
        return Err(std::io::Error::new(
            std::io::ErrorKind::InvalidData,
            format!(
                "larger than {:.1} MiB, not a file fishprobe wrote (reading stopped there; \
                 {limit_name})",
                max as f64 / f64::from(1u32 << 20)
            ),
        ));
    }
    Ok(bytes)
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

#[cfg(test)]
mod tests {
    use super::*;

    /// A fresh directory for one test, removed by the test when it passes.
    fn scratch(test: &str) -> std::path::PathBuf {
        let dir =
            std::env::temp_dir().join(format!("fishprobe-nn-store-{test}-{}", std::process::id()));
        let _ = std::fs::remove_dir_all(&dir);
        std::fs::create_dir_all(&dir).unwrap();
        dir
    }

    fn one_tensor() -> Tensors {
        let mut t = Tensors::new();
        t.insert("w".into(), (vec![2], vec![1.0, -2.5]));
        t
    }

    #[test]
    fn saved_weights_load_back() {
        let dir = scratch("roundtrip");
        let path = dir.join("w.safetensors");
        save(&path, &one_tensor(), &serde_json::json!({"format": "x"})).unwrap();
        let (t, meta) = load(&path).unwrap();
        assert_eq!(t, one_tensor());
        assert_eq!(meta["format"], "x");
        std::fs::remove_dir_all(dir).unwrap();
    }

    #[test]
    fn an_endless_file_is_refused_at_the_limit() {
        // /dev/zero never ends: without the bound, load would fill memory.
        let err = read_at_most(Path::new("/dev/zero"), 1 << 20, "LIMIT")
            .unwrap_err()
            .to_string();
        assert!(err.starts_with("larger than 1.0 MiB"), "{err}");
        assert!(err.contains("stopped there; LIMIT"), "{err}");
        assert_eq!(
            read_at_most(Path::new("/dev/null"), 1 << 20, "LIMIT").unwrap(),
            Vec::<u8>::new()
        );
    }

    #[test]
    fn an_endless_sidecar_is_refused_at_its_limit() {
        let dir = scratch("sidecar");
        let path = dir.join("w.safetensors");
        save(&path, &one_tensor(), &serde_json::json!({})).unwrap();
        std::fs::remove_file(sidecar_path(&path)).unwrap();
        std::os::unix::fs::symlink("/dev/zero", sidecar_path(&path)).unwrap();
        let err = load(&path).unwrap_err().to_string();
        assert!(err.contains(".json: larger than 16.0 MiB"), "{err}");
        assert!(err.contains("MAX_SIDECAR_BYTES"), "{err}");
        std::fs::remove_dir_all(dir).unwrap();
    }
}
