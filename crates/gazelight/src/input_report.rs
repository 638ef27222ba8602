//! What `inspect` and `replay` say about a recording that cannot be used as
//! it is: no readable samples (and why), a time range that is mostly a
//! gap, and pupils that the filter chain (nearly) all rejected.

use std::path::{Path, PathBuf};

use gazelight_tracker::filter::ChainStats;
use gazelight_tracker::filter::physio::PUPIL_MM_RANGE;
use gazelight_tracker::import::ImportWarnings;
use gazelight_tracker::import::time_guard::TimeStats;

/// Refuse a replay whose samples cover less than 1 / this of its span…
pub const MIN_COVERAGE_INV: f64 = 10.0;
/// …when the uncovered time is also more than this, s.
pub const MAX_UNCOVERED_SECS: f64 = 600.0;
/// Warn when at most this fraction of an eye's pupil samples were measured.
pub const MEASURED_WARN_FRACTION: f64 = 0.05;
/// …and the eye has at least this many pupil samples.
const MIN_PUPIL_SAMPLES: u64 = 20;

/// Why a recording gave no samples: an error naming the file and the
/// cause (the importer's first skipped records, an empty file, a file of
/// headers only). For a directory recording, `data_files` (the streams the
/// importer read) are named with their sizes.
pub fn no_samples(path: &Path, warnings: &ImportWarnings, data_files: &[PathBuf]) -> anyhow::Error {
    let what = if warnings.skipped_records > 0 {
        format!(
            "{} records were skipped as malformed; the first: {}",
            warnings.skipped_records,
            warnings.messages.first().map_or("-", String::as_str)
        )
    } else {
        match std::fs::metadata(path) {
            Ok(m) if m.is_dir() && !data_files.is_empty() => {
                let files: Vec<String> = data_files
                    .iter()
                    .map(|f| {
                        let name = f.file_name().map_or_else(
                            || f.display().to_string(),
                            |n| n.to_string_lossy().into_owned(),
                        );
                        match std::fs::metadata(f) {
                            Ok(m) => format!("{name} ({} bytes)", m.len()),
                            Err(e) => format!("{name} ({e})"),
                        }
                    })
                    .collect();
                format!(
                    "its data files hold no sample records: {}",
                    files.join(", ")
                )
            }
            Ok(m) if m.is_file() && m.len() == 0 => "the file is empty (0 bytes)".to_string(),
            Ok(m) if m.is_file() => format!(
                "the file ({} bytes) holds no sample records: only a header, comments or \
                 event lines",
                m.len()
            ),
            _ => "no sample records were found".to_string(),
        }
    };
    anyhow::anyhow!(
        "{}: the recording holds no readable samples: {what}",
        path.display()
    )
}

/// A refusal when the samples cover a sliver of the recording's span (a
/// one-year gap between two minutes of data): replaying it would render the
/// gap. `None` when the recording is fine.
pub fn sliver_span(path: &Path, stats: &TimeStats) -> Option<anyhow::Error> {
    let span = stats.span_secs();
    let covered = stats.covered_secs;
    if !(span > covered * MIN_COVERAGE_INV && span - covered > MAX_UNCOVERED_SECS) {
        return None;
    }
    let gap = stats
        .largest_gap_secs
        .map(|(a, b)| {
            format!(
                "; the largest gap is {} from t = {a:.3} s to t = {b:.3} s",
                human_secs(b - a)
            )
        })
        .unwrap_or_default();
    Some(anyhow::anyhow!(
        "{}: the samples cover {} of a {} time range ({:.4} %){gap}: the timestamps are \
         probably wrong (a clock jump, mixed clocks) — replay a part with --from-secs/--secs",
        path.display(),
        human_secs(covered),
        human_secs(span),
        100.0 * covered / span
    ))
}

fn human_secs(s: f64) -> String {
    if s >= 86_400.0 {
        format!("{:.1} days", s / 86_400.0)
    } else if s >= 3_600.0 {
        format!("{:.1} h", s / 3_600.0)
    } else {
        format!("{s:.1} s")
    }
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

    #[test]
    fn sliver_span_is_refused_and_normal_gaps_pass() {
        let year = TimeStats {
            accepted: 144_000,
            time_skipped: 0,
            range_secs: Some((0.0, 31_536_360.0)),
            covered_secs: 360.0,
            largest_gap_secs: Some((180.0, 31_536_180.0)),
        };
        let e = sliver_span(Path::new("r.csv"), &year).unwrap().to_string();
        assert!(e.contains("r.csv") && e.contains("365.0 days"), "{e}");
        // EyeLink: 4 trials of ~35 s with ~90 s pauses.
        let trials = TimeStats {
            range_secs: Some((0.0, 420.0)),
            covered_secs: 140.0,
            largest_gap_secs: Some((100.0, 193.0)),
            ..year
        };
        assert!(sliver_span(Path::new("t.asc"), &trials).is_none());
    }
}
