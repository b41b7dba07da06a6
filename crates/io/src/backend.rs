//! The HDF5 implementation, behind one module so that it can be swapped.
//!
//! Chosen: [`hdf5_pure`], a pure-Rust reader and writer. Compared with the reference C
//! library built from bundled source (`hdf5-metno` with `static`), it needs no cmake and no
//! C toolchain on a user's machine, builds in seconds, and, being memory-safe Rust, turns
//! damaged files into errors: on 1,600 truncated and byte-flipped copies of the shared real
//! files it never panicked or hung (the same check runs as a test, `damaged_files`). Files it
//! writes are read by h5py (tested in `python_reads_our_files`).
//!
//! Everything else in this crate sees only [`H5Group`], [`H5Dataset`], [`Attr`] and
//! [`GroupSpec`].

use crate::attr::Attr;
use crate::error::IoError;
use crate::limits::{not_regular, ReadLimits};
use hdf5_pure::{AttrValue, DType, FileBuilder};
use std::collections::BTreeMap;
use std::io::Read;
use std::path::Path;

fn format_err(path: &Path, what: impl Into<String>) -> IoError {
    IoError::Format {
        path: path.to_path_buf(),
        what: what.into(),
    }
}

/// Opens an HDF5 file for reading, within the default [`ReadLimits`].
pub fn open(path: &Path) -> Result<H5Group, IoError> {
    open_with(path, ReadLimits::default())
}

/// Opens an HDF5 file for reading within `limits`: only regular files (a FIFO would block, a
/// device or a symbolic link to one would be read without end), at most
/// `limits.max_file_bytes`, read with a bound even if the file grows meanwhile.
pub fn open_with(path: &Path, limits: ReadLimits) -> Result<H5Group, IoError> {
    if let Some(what) = not_regular(path) {
        return Err(IoError::NotRegular {
            path: path.to_path_buf(),
            what,
        });
    }
    let read_err = |reason| IoError::Read {
        path: path.to_path_buf(),
        reason,
    };
    let file = std::fs::File::open(path).map_err(read_err)?;
    let declared = file.metadata().map_err(read_err)?.len();
    let too_large = |bytes: u64| IoError::TooLarge {
        path: path.to_path_buf(),
        bytes,
        limit: limits.max_file_bytes,
    };
    if declared > limits.max_file_bytes {
        return Err(too_large(declared));
    }
    let mut bytes = Vec::with_capacity(declared as usize);
    file.take(limits.max_file_bytes + 1)
        .read_to_end(&mut bytes)
        .map_err(read_err)?;
    if bytes.len() as u64 > limits.max_file_bytes {
        return Err(too_large(bytes.len() as u64));
    }
    if !hdf5_pure::is_hdf5_bytes(&bytes) {
        return Err(IoError::NotHdf5 {
            path: path.to_path_buf(),
        });
    }
    let file_bytes = bytes.len() as u64;
    let file = hdf5_pure::File::from_bytes(bytes)
        .map_err(|e| format_err(path, format!("cannot parse HDF5: {e}")))?;
    Ok(H5Group {
        g: file.root(),
        path: path.to_path_buf(),
        name: "/".into(),
        bound: Bound { limits, file_bytes },
    })
}

/// The limits in force for one open file.
#[derive(Debug, Clone, Copy)]
struct Bound {
    limits: ReadLimits,
    file_bytes: u64,
}

/// A group of an open file.
pub struct H5Group {
    g: hdf5_pure::Group,
    path: std::path::PathBuf,
    name: String,
    bound: Bound,
}

/// A dataset of an open file.
pub struct H5Dataset {
    d: hdf5_pure::Dataset,
    path: std::path::PathBuf,
    name: String,
    bound: Bound,
}

fn child(parent: &str, name: &str) -> String {
    if parent == "/" {
        format!("/{name}")
    } else {
        format!("{parent}/{name}")
    }
}

fn convert_attr(v: AttrValue) -> Option<Attr> {
    use AttrValue as A;
    Some(match v {
        A::F32(x) => Attr::Float(f64::from(x)),
        A::F64(x) => Attr::Float(x),
        A::I8(x) => Attr::Int(x.into()),
        A::I16(x) => Attr::Int(x.into()),
        A::I32(x) => Attr::Int(x.into()),
        A::I64(x) => Attr::Int(x),
        A::U8(x) => Attr::Int(x.into()),
        A::U16(x) => Attr::Int(x.into()),
        A::U32(x) => Attr::Int(x.into()),
        A::U64(x) => Attr::Int(i64::try_from(x).ok()?),
        A::F32Array(v) => Attr::Floats(v.into_iter().map(f64::from).collect()),
        A::F64Array(v) => Attr::Floats(v),
        A::I8Array(v) => Attr::Ints(v.into_iter().map(i64::from).collect()),
        A::I16Array(v) => Attr::Ints(v.into_iter().map(i64::from).collect()),
        A::I32Array(v) => Attr::Ints(v.into_iter().map(i64::from).collect()),
        A::I64Array(v) => Attr::Ints(v),
        A::U8Array(v) => Attr::Ints(v.into_iter().map(i64::from).collect()),
        A::U16Array(v) => Attr::Ints(v.into_iter().map(i64::from).collect()),
        A::U32Array(v) => Attr::Ints(v.into_iter().map(i64::from).collect()),
        A::U64Array(v) => Attr::Ints(
            v.into_iter()
                .map(|x| i64::try_from(x).ok())
                .collect::<Option<_>>()?,
        ),
        A::String(s) | A::AsciiString(s) | A::VarLenString(s) => Attr::Text(s),
        A::StringArray(v)
        | A::AsciiStringArray(v)
        | A::VarLenStringArray(v)
        | A::VarLenAsciiCharArray(v) => Attr::Texts(v),
        other => match format!("{other:?}") {
            // Sized and other string variants are non-exhaustive structs; keep their text.
            s if s.contains("String") => Attr::Text(s),
            _ => return None,
        },
    })
}

/// Keeps the attributes of kinds fishprobe understands (a reader must skip the others).
fn convert_attrs(raw: std::collections::HashMap<String, AttrValue>) -> BTreeMap<String, Attr> {
    raw.into_iter()
        .filter_map(|(k, v)| convert_attr(v).map(|a| (k, a)))
        .collect()
}

impl H5Group {
    /// The file this group belongs to.
    pub fn file(&self) -> &Path {
        &self.path
    }

    /// The group's path inside the file.
    pub fn name(&self) -> &str {
        &self.name
    }

    /// Attributes of kinds fishprobe understands (others are skipped, as a reader must).
    pub fn attrs(&self) -> Result<BTreeMap<String, Attr>, IoError> {
        let raw = self
            .g
            .attrs()
            .map_err(|e| format_err(&self.path, format!("attributes of {}: {e}", self.name)))?;
        Ok(convert_attrs(raw))
    }

    /// Names of the subgroups, sorted.
    pub fn groups(&self) -> Result<Vec<String>, IoError> {
        let mut v = self
            .g
            .groups()
            .map_err(|e| format_err(&self.path, format!("groups of {}: {e}", self.name)))?;
        v.sort();
        Ok(v)
    }

    /// Names of the datasets, sorted.
    pub fn datasets(&self) -> Result<Vec<String>, IoError> {
        let mut v = self
            .g
            .datasets()
            .map_err(|e| format_err(&self.path, format!("datasets of {}: {e}", self.name)))?;
        v.sort();
        Ok(v)
    }

    /// A subgroup, if it exists.
    pub fn group(&self, name: &str) -> Result<Option<H5Group>, IoError> {
        if !self.groups()?.iter().any(|g| g == name) {
            return Ok(None);
        }
        let g = self.g.group(name).map_err(|e| {
            format_err(
                &self.path,
                format!("group {}: {e}", child(&self.name, name)),
            )
        })?;
        Ok(Some(H5Group {
            g,
            path: self.path.clone(),
            name: child(&self.name, name),
            bound: self.bound,
        }))
    }

    /// A dataset, if it exists.
    pub fn dataset(&self, name: &str) -> Result<Option<H5Dataset>, IoError> {
        if !self.datasets()?.iter().any(|d| d == name) {
            return Ok(None);
        }
        let d = self.g.dataset(name).map_err(|e| {
            format_err(
                &self.path,
                format!("dataset {}: {e}", child(&self.name, name)),
            )
        })?;
        Ok(Some(H5Dataset {
            d,
            path: self.path.clone(),
            name: child(&self.name, name),
            bound: self.bound,
        }))
    }
}

impl H5Dataset {
    /// The dataset's path inside the file.
    pub fn name(&self) -> &str {
        &self.name
    }

    fn err(&self, what: impl std::fmt::Display) -> IoError {
        format_err(&self.path, format!("dataset {}: {what}", self.name))
    }

    /// Dimensions.
    pub fn shape(&self) -> Result<Vec<u64>, IoError> {
        self.d.shape().map_err(|e| self.err(e))
    }

    /// Attributes of kinds fishprobe understands.
    pub fn attrs(&self) -> Result<BTreeMap<String, Attr>, IoError> {
        Ok(convert_attrs(self.d.attrs().map_err(|e| self.err(e))?))
    }

    /// Refuses, before anything is allocated, a dataset that declares more rows than
    /// [`ReadLimits::max_frames`] or more data than the file can hold.
    fn check_declared(&self, dtype: &DType) -> Result<(), IoError> {
        let shape = self.shape()?;
        let limits = self.bound.limits;
        if let Some(&rows) = shape.first() {
            limits.check_frames(&self.path, &self.name, rows)?;
        }
        let elements = shape
            .iter()
            .try_fold(1u64, |n, &d| n.checked_mul(d))
            .unwrap_or(u64::MAX);
        let element_bytes = match dtype {
            DType::I8 | DType::U8 => 1,
            DType::I16 | DType::U16 => 2,
            DType::F32 | DType::I32 | DType::U32 => 4,
            DType::F64 | DType::I64 | DType::U64 => 8,
            _ => 1,
        };
        let compressed = !self.d.filter_pipeline().is_empty();
        limits.check_declared(
            &self.path,
            &self.name,
            elements,
            element_bytes,
            compressed,
            self.bound.file_bytes,
        )
    }

    /// Numeric contents as f32 (any float or integer type; other types are an error).
    pub fn read_f32(&self) -> Result<Vec<f32>, IoError> {
        let dtype = self.d.dtype().map_err(|e| self.err(e))?;
        self.check_declared(&dtype)?;
        let r = match dtype {
            DType::F32 => self.d.read_f32(),
            DType::F64 => self
                .d
                .read_f64()
                .map(|v| v.into_iter().map(|x| x as f32).collect()),
            DType::I8
            | DType::I16
            | DType::I32
            | DType::I64
            | DType::U8
            | DType::U16
            | DType::U32 => self
                .d
                .read_i64()
                .map(|v| v.into_iter().map(|x| x as f32).collect()),
            other => return Err(self.err(format!("expected numbers, found {other}"))),
        };
        r.map_err(|e| self.err(e))
    }

    /// Integer contents (integer types only).
    pub fn read_i64(&self) -> Result<Vec<i64>, IoError> {
        let dtype = self.d.dtype().map_err(|e| self.err(e))?;
        self.check_declared(&dtype)?;
        match dtype {
            DType::I8
            | DType::I16
            | DType::I32
            | DType::I64
            | DType::U8
            | DType::U16
            | DType::U32 => self.d.read_i64().map_err(|e| self.err(e)),
            other => Err(self.err(format!("expected integers, found {other}"))),
        }
    }

    /// String contents (fixed or variable length).
    pub fn read_strings(&self) -> Result<Vec<String>, IoError> {
        let dtype = self.d.dtype().map_err(|e| self.err(e))?;
        self.check_declared(&dtype)?;
        match dtype {
            DType::String | DType::VariableLengthString => {
                self.d.read_string().map_err(|e| self.err(e))
            }
            other => Err(self.err(format!("expected strings, found {other}"))),
        }
    }
}

/// Contents of a dataset to write.
#[derive(Debug, Clone, PartialEq)]
pub enum Data {
    /// float32 with a shape.
    F32(Vec<f32>, Vec<u64>),
    /// int64, one-dimensional.
    I64(Vec<i64>),
    /// int32, one-dimensional.
    I32(Vec<i32>),
    /// Variable-length UTF-8 strings, one-dimensional.
    Strings(Vec<String>),
}

/// A group to write: attributes, datasets and subgroups, in order.
#[derive(Debug, Clone, PartialEq, Default)]
pub struct GroupSpec {
    /// Attributes.
    pub attrs: Vec<(String, AttrOut)>,
    /// Datasets.
    pub datasets: Vec<(String, Data)>,
    /// Subgroups.
    pub groups: Vec<(String, GroupSpec)>,
}

/// An attribute to write, with the exact HDF5 type robofish.io uses.
#[derive(Debug, Clone, PartialEq)]
pub enum AttrOut {
    /// Variable-length UTF-8 string scalar.
    Text(String),
    /// float32 scalar.
    F32(f32),
    /// float32 array.
    F32s(Vec<f32>),
    /// int32 array.
    I32s(Vec<i32>),
    /// int64 scalar.
    I64(i64),
    /// int64 array.
    I64s(Vec<i64>),
    /// float64 scalar.
    F64(f64),
    /// float64 array.
    F64s(Vec<f64>),
    /// Variable-length UTF-8 string array.
    Texts(Vec<String>),
}

fn attr_value(a: &AttrOut) -> AttrValue {
    match a {
        AttrOut::Text(s) => AttrValue::VarLenString(s.clone()),
        AttrOut::F32(x) => AttrValue::F32(*x),
        AttrOut::F32s(v) => AttrValue::F32Array(v.clone()),
        AttrOut::I32s(v) => AttrValue::I32Array(v.clone()),
        AttrOut::I64(x) => AttrValue::I64(*x),
        AttrOut::I64s(v) => AttrValue::I64Array(v.clone()),
        AttrOut::F64(x) => AttrValue::F64(*x),
        AttrOut::F64s(v) => AttrValue::F64Array(v.clone()),
        AttrOut::Texts(v) => AttrValue::VarLenStringArray(v.clone()),
    }
}

fn fill_dataset(b: &mut hdf5_pure::DatasetBuilder, data: &Data) {
    match data {
        Data::F32(v, shape) => {
            b.with_f32_data(v).with_shape(shape);
        }
        Data::I64(v) => {
            b.with_data(v);
        }
        Data::I32(v) => {
            b.with_data(v);
        }
        Data::Strings(v) => {
            let refs: Vec<&str> = v.iter().map(String::as_str).collect();
            b.with_vlen_strings(&refs);
        }
    }
}

fn fill_group(g: &mut hdf5_pure::GroupBuilder, spec: &GroupSpec) {
    for (k, a) in &spec.attrs {
        g.set_attr(k, attr_value(a));
    }
    for (k, d) in &spec.datasets {
        fill_dataset(g.create_dataset(k), d);
    }
    for (k, sub) in &spec.groups {
        let mut sg = g.create_group(k);
        fill_group(&mut sg, sub);
        g.add_group(sg.finish());
    }
}

/// Serialises a whole file (the root group `spec`) to bytes.
pub fn to_bytes(spec: &GroupSpec) -> Result<Vec<u8>, IoError> {
    let mut fb = FileBuilder::new();
    for (k, a) in &spec.attrs {
        fb.set_attr(k, attr_value(a));
    }
    for (k, d) in &spec.datasets {
        fill_dataset(fb.create_dataset(k), d);
    }
    for (k, sub) in &spec.groups {
        let mut g = fb.create_group(k);
        fill_group(&mut g, sub);
        fb.add_group(g.finish());
    }
    fb.finish().map_err(|e| IoError::Write {
        path: std::path::PathBuf::new(),
        what: e.to_string(),
    })
}
