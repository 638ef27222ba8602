//! What `inspect` and `replay` say about a recording that cannot be used as
//! it is: no readable samples (and why), a time range that is mostly a
//! gap (both `gazelight_render::feed`'s, shared with the Python package),
//! and pupils that the filter chain (nearly) all rejected.

use std::path::{Path, PathBuf};

use gazelight_tracker::filter::ChainStats;
use gazelight_tracker::import::ImportWarnings;

/// Why a recording gave no samples ([`gazelight_render::feed::no_samples`]).
pub fn no_samples(path: &Path, warnings: &ImportWarnings, data_files: &[PathBuf]) -> anyhow::Error {
    gazelight_render::feed::no_samples(path, warnings, data_files).into()
}

/// What the chain's counters say about an eye's pupils that a user must
/// know (nearly nothing measured, no physical scale):
/// [`gazelight_tracker::import::summary::pupil_rejection`], the one rule the
/// CLI and the Python package share.
pub fn pupil_rejection(stats: &ChainStats) -> Option<String> {
    gazelight_tracker::import::summary::pupil_rejection(stats)
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn rejection_warning_names_units_and_the_fix() {
        let mut s = ChainStats {
            pupil_samples: [1000, 1000],
            measured: [0, 3],
            rejected_range: [1000, 997],
            ..ChainStats::default()
        };
        let w = pupil_rejection(&s).unwrap();
        assert!(
            w.contains("not in millimetres") && w.contains("--calibration"),
            "{w}"
        );
        assert!(w.contains("only 3 of 1000"), "{w}");
        s.measured = [900, 900];
        assert!(pupil_rejection(&s).is_none());
        // Measured, but in raw units with no physical scale: said once.
        s.uncalibrated = [900, 900];
        let w = pupil_rejection(&s).unwrap();
        assert!(
            w.contains("no physical scale") && w.contains("profile scale"),
            "{w}"
        );
    }
}
