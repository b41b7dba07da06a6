//! A trial file in either layout the lab holds: robofish.io 1.0, or its pre-2020 layout. The
//! one place that tells them apart (training data, `inspect`, `compare-offline`, Python).

use crate::{read_legacy, read_trial, IoError, TrialFile};
use std::path::Path;

/// The layout a trial file was read in.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum TrialLayout {
    /// robofish.io 1.0 (fishprobe's own files, RoboTracker's since 2020).
    Robofish,
    /// The lab's pre-2020 layout (the shared `guppy-pairs/legacy/` recordings).
    Legacy,
}

impl TrialLayout {
    /// How `inspect` names it.
    pub fn label(self) -> &'static str {
        match self {
            TrialLayout::Robofish => "robofish.io 1.0",
            TrialLayout::Legacy => "legacy (pre-2020)",
        }
    }
}

/// Reads `path` as robofish.io 1.0 or, when it is HDF5 of another layout, as the lab's
/// pre-2020 layout. A file that is no HDF5 (or too large, or unreadable) is refused with
/// that reason; an HDF5 file of neither layout with both readers' reasons.
pub fn read_any_trial_layout(path: &Path) -> Result<(TrialFile, TrialLayout), IoError> {
    match read_trial(path) {
        Ok(t) => Ok((t, TrialLayout::Robofish)),
        Err(robofish @ IoError::Format { .. }) => match read_legacy(path) {
            Ok(t) => Ok((t, TrialLayout::Legacy)),
            Err(legacy) => Err(IoError::NeitherLayout {
                robofish: Box::new(robofish),
                legacy: Box::new(legacy),
            }),
        },
        Err(e) => Err(e),
    }
}

/// [`read_any_trial_layout`] without the layout.
pub fn read_any_trial(path: &Path) -> Result<TrialFile, IoError> {
    read_any_trial_layout(path).map(|(t, _)| t)
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn a_file_that_is_no_hdf5_is_refused_once_with_its_reason() {
        let d = crate::ScratchDir::for_test("any-trial");
        let f = d.join("x.hdf5");
        std::fs::write(&f, b"not hdf5 at all").unwrap();
        let e = read_any_trial(&f).unwrap_err();
        assert!(matches!(e, IoError::NotHdf5 { .. }), "{e}");
        assert!(!e.to_string().contains("legacy"), "{e}");
    }
}
