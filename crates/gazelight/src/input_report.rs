//! What `inspect` and `replay` say about a recording that cannot be used as
//! it is: no readable samples (and why), a time range that is mostly a
//! gap (both `gazelight_render::feed`'s, shared with the Python package),
//! and pupils that the filter chain (nearly) all rejected.

use std::path::{Path, PathBuf};

use gazelight_tracker::filter::ChainStats;
use gazelight_tracker::filter::physio::PUPIL_MM_RANGE;
use gazelight_tracker::import::ImportWarnings;

/// Warn when at most this fraction of an eye's pupil samples were measured.
pub const MEASURED_WARN_FRACTION: f64 = 0.05;
/// …and the eye has at least this many pupil samples.
const MIN_PUPIL_SAMPLES: u64 = 20;

/// Why a recording gave no samples ([`gazelight_render::feed::no_samples`]).
pub fn no_samples(path: &Path, warnings: &ImportWarnings, data_files: &[PathBuf]) -> anyhow::Error {
    gazelight_render::feed::no_samples(path, warnings, data_files).into()
}

/// A loud warning when (nearly) every pupil sample of an eye was rejected
/// by the filter chain, naming the likely cause and the fix.
pub fn pupil_rejection(stats: &ChainStats) -> Option<String> {
    let eyes = ["right (0)", "left (1)"];
    let mut lines = Vec::new();
    for (e, eye) in eyes.iter().enumerate() {
        let n = stats.pupil_samples[e];
        if n < MIN_PUPIL_SAMPLES {
            continue;
        }
        let measured = stats.measured[e];
        if measured as f64 > MEASURED_WARN_FRACTION * n as f64 {
            continue;
        }
        let reasons = [
            (
                stats.uncalibrated[e],
                "are in raw tracker units (px or area) and no calibration maps them to mm: \
                 give --calibration FILE, a profile made by `gazelight profile scale` (a known \
                 mm per unit) or `gazelight profile phases` (the recording's dark and bright \
                 stretches); `gazelight profile schema` prints its format"
                    .to_string(),
            ),
            (
                stats.rejected_range[e],
                format!(
                    "are outside the physiological range {}–{} mm: \
                     the pupil is probably not in millimetres (pixels, area units or µm); \
                     convert it, or give its unit (a CSV column named `left_px`/`right_px`) \
                     and a --calibration FILE mapping it to mm",
                    PUPIL_MM_RANGE.0, PUPIL_MM_RANGE.1
                ),
            ),
            (
                stats.rejected_confidence[e],
                "are below the confidence gate: the tracker lost the pupil, or its \
                 confidence column is on another scale"
                    .to_string(),
            ),
            (
                stats.rejected_non_positive[e] + stats.rejected_not_finite[e],
                "are 0, negative or NaN (lost pupils)".to_string(),
            ),
            (
                stats.rejected_rate[e],
                "change faster than a pupil can (noise, or a wrong time unit)".to_string(),
            ),
        ];
        let (count, why) = reasons
            .iter()
            .max_by_key(|(c, _)| *c)
            .map(|(c, w)| (*c, w.as_str()))
            .unwrap_or((0, ""));
        lines.push(format!(
            "eye {}: only {measured} of {n} pupil samples were accepted; {count} of them {why}",
            eye
        ));
    }
    if lines.is_empty() {
        return None;
    }
    Some(format!(
        "nearly all pupil samples were rejected, so the pupil falls back to the \
         light-adaptation model (dropout fraction ≈ 1): {}",
        lines.join("; ")
    ))
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
    }
}
