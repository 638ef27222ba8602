//! # gazelight-py
//!
//! The native half of the `gazelight` Python package (`python/gazelight/`
//! is the other half: the public names, pandas, warnings, stubs). It is
//! thin on purpose: every function opens, filters and fits with the same
//! library code the CLI runs (`gazelight-tracker`: the importers, the one
//! filter chain, calibration profiles, the pupil light response;
//! `gazelight-render`: the frame step of `render` and `replay`) and only
//! converts the results to numpy arrays and Python objects.
//!
//! Errors become `gazelight.GazelightError` with the message the CLI prints
//! for the same input; a bad argument type is a `TypeError` (PyO3's
//! conversion). Nothing here panics on outside data: the workspace lints
//! deny `unwrap`/`expect`, and the long loops run with the GIL released.

use std::path::{Path, PathBuf};

use pyo3::create_exception;
use pyo3::exceptions::PyException;
use pyo3::prelude::*;

mod config;
mod filter;
mod paths;
mod pupil;
mod read;
mod render;
mod source;
mod trials;

create_exception!(
    _gazelight,
    GazelightError,
    PyException,
    "An error gazelight reports: the message is the one the CLI prints for the same input."
);

/// Converts any displayable library error into `GazelightError`.
pub(crate) fn err(e: impl std::fmt::Display) -> PyErr {
    GazelightError::new_err(e.to_string())
}

/// An error and its sources, `outer: inner: …`, as the CLI prints it
/// (anyhow's alternate format, `error: {err:#}`).
pub(crate) fn chain_msg(e: &(dyn std::error::Error + 'static)) -> String {
    gazelight_output::error_chain(e)
}

/// A calibration profile (`gazelight profile schema`), loaded once.
pub(crate) fn load_calibration(
    path: &Path,
) -> PyResult<gazelight_tracker::profile::PupilCalibration> {
    gazelight_tracker::profile::PupilCalibration::load(path)
        .map_err(|e| err(format!("--calibration: {e}")))
}

/// A calibration profile mapping a tracker's raw pupil units onto mm.
#[pyclass(module = "gazelight", name = "Calibration", frozen, from_py_object)]
#[derive(Clone)]
pub(crate) struct Calibration {
    pub(crate) inner: gazelight_tracker::profile::PupilCalibration,
    path: PathBuf,
}

#[pymethods]
impl Calibration {
    /// Loads a calibration profile (JSON, `gazelight profile schema`), with
    /// the checks the CLI's `--calibration` makes.
    #[staticmethod]
    fn load(path: PathBuf) -> PyResult<Self> {
        let inner = load_calibration(&path)?;
        Ok(Self { inner, path })
    }

    /// The file it was loaded from.
    #[getter]
    fn path(&self) -> PathBuf {
        self.path.clone()
    }

    /// The profile as JSON text (the file's schema, normalised).
    fn to_json(&self) -> PyResult<String> {
        serde_json::to_string(&self.inner).map_err(err)
    }

    fn __repr__(&self) -> String {
        format!("Calibration.load({:?})", self.path.display().to_string())
    }
}

#[pymodule]
fn _gazelight(m: &Bound<'_, PyModule>) -> PyResult<()> {
    m.add("GazelightError", m.py().get_type::<GazelightError>())?;
    m.add_class::<Calibration>()?;
    m.add_class::<filter::FilterChain>()?;
    m.add_class::<filter::EyeState>()?;
    m.add_class::<pupil::PyPupilLightResponse>()?;
    m.add_class::<source::Source>()?;
    m.add_class::<render::Render>()?;
    m.add_function(wrap_pyfunction!(render::render_open, m)?)?;
    m.add_function(wrap_pyfunction!(render::write_png, m)?)?;
    m.add_function(wrap_pyfunction!(paths::input_kind, m)?)?;
    m.add_function(wrap_pyfunction!(paths::read_config_text, m)?)?;
    m.add_function(wrap_pyfunction!(pupil::psf, m)?)?;
    m.add_function(wrap_pyfunction!(read::read_recording, m)?)?;
    m.add_function(wrap_pyfunction!(read::inspect_json, m)?)?;
    m.add_function(wrap_pyfunction!(trials::trials_csv, m)?)?;
    Ok(())
}
