//! Attribute values as fishprobe sees them, independent of the HDF5 implementation.

use serde::Serialize;

/// An HDF5 attribute value, widened to a few plain kinds.
#[derive(Debug, Clone, PartialEq, Serialize)]
#[serde(untagged)]
pub enum Attr {
    /// Any integer scalar.
    Int(i64),
    /// Any floating-point scalar.
    Float(f64),
    /// Any string scalar (fixed or variable length).
    Text(String),
    /// An integer array.
    Ints(Vec<i64>),
    /// A floating-point array.
    Floats(Vec<f64>),
    /// A string array.
    Texts(Vec<String>),
}

impl Attr {
    /// The value as text, if it is a string.
    pub fn as_text(&self) -> Option<&str> {
        match self {
            Attr::Text(s) => Some(s),
            Attr::Texts(v) if v.len() == 1 => Some(&v[0]),
            _ => None,
        }
    }

    /// The value as numbers (a scalar gives one), if numeric.
    pub fn as_numbers(&self) -> Option<Vec<f64>> {
        match self {
            Attr::Int(i) => Some(vec![*i as f64]),
            Attr::Float(f) => Some(vec![*f]),
            Attr::Ints(v) => Some(v.iter().map(|i| *i as f64).collect()),
            Attr::Floats(v) => Some(v.clone()),
            _ => None,
        }
    }

    /// The value as one number, if it is a numeric scalar (or a 1-element array).
    pub fn as_number(&self) -> Option<f64> {
        self.as_numbers().filter(|v| v.len() == 1).map(|v| v[0])
    }
}
