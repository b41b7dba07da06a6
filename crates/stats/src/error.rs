//! Errors of the statistics.

/// Why a statistic cannot be computed.
#[derive(Debug, Clone, PartialEq, thiserror::Error)]
pub enum StatsError {
    /// A sample that must not be empty is.
    #[error("{0}: empty sample")]
    Empty(&'static str),
    /// A sample holds NaN or infinity.
    #[error("{0}: sample holds a non-finite value")]
    NotFinite(&'static str),
    /// The statistic is undefined for this input (e.g. all values tied).
    #[error("{0}")]
    Undefined(String),
    /// An iterative fit did not converge.
    #[error("{0}")]
    NoConvergence(String),
}

/// Checks a sample is non-empty and finite.
pub fn check_sample(what: &'static str, x: &[f64]) -> Result<(), StatsError> {
    if x.is_empty() {
        return Err(StatsError::Empty(what));
    }
    if x.iter().any(|v| !v.is_finite()) {
        return Err(StatsError::NotFinite(what));
    }
    Ok(())
}
