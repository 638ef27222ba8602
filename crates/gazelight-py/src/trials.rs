//! `gazelight.trials`: the per-trial table of a replay, through the same
//! library functions as `gazelight trials` (`gazelight_render::trials`),
//! so both give the same numbers.

use std::path::PathBuf;

use gazelight_render::trials::{self, TrialOptions};
use pyo3::prelude::*;

use crate::err;

/// The table of the replay in `dir` as CSV text (`gazelight trials`'s
/// `trials.csv`) and the pupil's unit (`"mm"` or `"raw"`).
#[pyfunction]
#[pyo3(signature = (dir, events, baseline, window, max_invalid = 0.5, eye = None))]
pub fn trials_csv(
    py: Python<'_>,
    dir: PathBuf,
    events: String,
    baseline: String,
    window: String,
    max_invalid: f64,
    eye: Option<String>,
) -> PyResult<(String, String)> {
    if !(0.0..=1.0).contains(&max_invalid) {
        return Err(err(format!(
            "--max-invalid {max_invalid}: expected a fraction from 0 to 1"
        )));
    }
    let suffix = match eye.as_deref() {
        None => "",
        Some("left") => "_left",
        Some("right") => "_right",
        Some(e) => return Err(err(format!("--eye {e}: expected left or right"))),
    };
    let options = TrialOptions {
        pattern: events.clone(),
        baseline_secs: trials::parse_range("--baseline", &baseline).map_err(err)?,
        window_secs: trials::parse_range("--window", &window).map_err(err)?,
        max_invalid_fraction: max_invalid,
    };
    let (rows, unit) = py
        .detach(|| trials::from_replay_dir(&dir, suffix, &options))
        .map_err(err)?;
    if rows.is_empty() {
        return Err(err(format!(
            "{}: no event matches --events {events:?} (see its events.csv's text column)",
            dir.join("events.csv").display()
        )));
    }
    Ok((trials::to_csv(&rows, unit), unit.to_owned()))
}
