//! The pupil's light response (`gazelight_tracker::pupil_response`, what
//! `replay` predicts and `--pupil-fit` fits) and the glare kernel
//! (`gazelight_vision::psf`, what `gazelight psf` builds), over numpy
//! arrays. Light here is a uniform field seen by both eyes (W&Y's
//! binocular case): per row, a luminance and the field's area.

use numpy::{PyArray1, PyArray3, PyArrayMethods, PyReadonlyArray1};
use pyo3::exceptions::PyValueError;
use pyo3::prelude::*;
use pyo3::types::PyDict;

use gazelight_tracker::pupil_response::{
    Adaptation, Dynamics, EyeInput, EyeLight, FitOptions, ObserverRange, PupilLightResponse,
    PupilRow, ResponseParams, fit_observer, static_target_mm,
};
use gazelight_vision::psf::{GlareScale, PsfBuilder, PsfParams};

use crate::err;

fn params(
    age_years: f64,
    gaze_weight: f64,
    latency_secs: f64,
    constriction_tau_secs: f64,
    redilation_tau_secs: f64,
    scale: f64,
    offset_mm: f64,
) -> PyResult<ResponseParams> {
    let p = ResponseParams {
        adaptation: Adaptation {
            gaze_weight,
            age_years,
        },
        dynamics: Dynamics {
            latency_secs,
            constriction_tau_secs,
            redilation_tau_secs,
        },
        range: ObserverRange { scale, offset_mm },
    };
    p.validate().map_err(err)?;
    Ok(p)
}

fn params_dict<'py>(py: Python<'py>, p: &ResponseParams) -> PyResult<Bound<'py, PyDict>> {
    let d = PyDict::new(py);
    d.set_item("age_years", p.adaptation.age_years)?;
    d.set_item("gaze_weight", p.adaptation.gaze_weight)?;
    d.set_item("latency_secs", p.dynamics.latency_secs)?;
    d.set_item("constriction_tau_secs", p.dynamics.constriction_tau_secs)?;
    d.set_item("redilation_tau_secs", p.dynamics.redilation_tau_secs)?;
    d.set_item("scale", p.range.scale)?;
    d.set_item("offset_mm", p.range.offset_mm)?;
    Ok(d)
}

/// Rows of a uniform binocular field: `t_secs`, the pupil (NaN where not
/// measured), the luminance and the field's area per row.
fn rows(
    t_secs: &[f64],
    pupil_mm: Option<&[f64]>,
    luminance_cd_m2: &[f64],
    field_area_deg2: f64,
) -> PyResult<Vec<PupilRow>> {
    if luminance_cd_m2.len() != t_secs.len() || pupil_mm.is_some_and(|p| p.len() != t_secs.len()) {
        return Err(PyValueError::new_err(format!(
            "t_secs, pupil_mm and luminance_cd_m2 must have one length (got {}, {}, {})",
            t_secs.len(),
            pupil_mm.map_or(t_secs.len(), <[f64]>::len),
            luminance_cd_m2.len()
        )));
    }
    Ok((0..t_secs.len())
        .map(|i| PupilRow {
            t_secs: t_secs[i],
            pupil_mm: pupil_mm.map_or(f64::NAN, |p| p[i]),
            light: EyeLight::both(EyeInput::uniform(luminance_cd_m2[i], field_area_deg2)),
        })
        .collect())
}

/// The pupil light response: W&Y's unified formula (the static target of
/// the flux and the observer's age), a latency and first-order
/// constriction / redilation, mapped onto an observer's range.
#[pyclass(module = "gazelight", name = "PupilLightResponse", frozen)]
pub(crate) struct PyPupilLightResponse {
    params: ResponseParams,
}

#[pymethods]
impl PyPupilLightResponse {
    #[new]
    #[pyo3(signature = (age_years=None, gaze_weight=None, latency_secs=None,
        constriction_tau_secs=None, redilation_tau_secs=None, scale=1.0, offset_mm=0.0))]
    fn new(
        age_years: Option<f64>,
        gaze_weight: Option<f64>,
        latency_secs: Option<f64>,
        constriction_tau_secs: Option<f64>,
        redilation_tau_secs: Option<f64>,
        scale: f64,
        offset_mm: f64,
    ) -> PyResult<Self> {
        let a = Adaptation::default();
        let d = Dynamics::default();
        Ok(Self {
            params: params(
                age_years.unwrap_or(a.age_years),
                gaze_weight.unwrap_or(a.gaze_weight),
                latency_secs.unwrap_or(d.latency_secs),
                constriction_tau_secs.unwrap_or(d.constriction_tau_secs),
                redilation_tau_secs.unwrap_or(d.redilation_tau_secs),
                scale,
                offset_mm,
            )?,
        })
    }

    /// The parameters, as a dict.
    #[getter]
    fn params<'py>(&self, py: Python<'py>) -> PyResult<Bound<'py, PyDict>> {
        params_dict(py, &self.params)
    }

    /// The predicted pupil (mm) at each row, the model run from rest over
    /// the rows (times increasing): both eyes see a uniform field of
    /// `luminance_cd_m2[i]` over `field_area_deg2`.
    fn predict<'py>(
        &self,
        py: Python<'py>,
        t_secs: PyReadonlyArray1<'py, f64>,
        luminance_cd_m2: PyReadonlyArray1<'py, f64>,
        field_area_deg2: f64,
    ) -> PyResult<Bound<'py, PyArray1<f64>>> {
        let rows = rows(
            t_secs.as_slice()?,
            None,
            luminance_cd_m2.as_slice()?,
            field_area_deg2,
        )?;
        let mut model = PupilLightResponse::new(self.params).map_err(err)?;
        let out =
            py.detach(|| gazelight_tracker::pupil_response::predictions_mm(&mut model, &rows));
        Ok(PyArray1::from_vec(py, out))
    }

    /// The static (light-adapted) diameter, mm: W&Y's unified formula for a
    /// uniform field of `luminance_cd_m2` over `field_area_deg2` seen by
    /// `eyes` (1 or 2) eyes, at this observer's age (not mapped onto the
    /// observer's range).
    #[pyo3(signature = (luminance_cd_m2, field_area_deg2, eyes=2))]
    fn static_mm(&self, luminance_cd_m2: f64, field_area_deg2: f64, eyes: u8) -> PyResult<f64> {
        let input = EyeInput::uniform(luminance_cd_m2, field_area_deg2);
        let light = match eyes {
            2 => EyeLight::both(input),
            1 => EyeLight::one(0, input),
            _ => {
                return Err(PyValueError::new_err(format!(
                    "eyes {eyes}: expected 1 or 2"
                )));
            }
        };
        Ok(static_target_mm(&light, &self.params.adaptation))
    }

    /// Fits an observer (range, and with `fit_dynamics` the latency and
    /// both time constants) on a block of a recording, as `replay
    /// --pupil-fit` does: `pupil_mm` NaN where not measured. Returns
    /// `(PupilLightResponse, {"r_squared", "rms_mm", "samples_used"})`.
    #[staticmethod]
    #[pyo3(signature = (t_secs, pupil_mm, luminance_cd_m2, field_area_deg2, age_years=None,
        fit_dynamics=true, min_samples=20))]
    #[allow(clippy::too_many_arguments)]
    fn fit<'py>(
        py: Python<'py>,
        t_secs: PyReadonlyArray1<'py, f64>,
        pupil_mm: PyReadonlyArray1<'py, f64>,
        luminance_cd_m2: PyReadonlyArray1<'py, f64>,
        field_area_deg2: f64,
        age_years: Option<f64>,
        fit_dynamics: bool,
        min_samples: usize,
    ) -> PyResult<(Self, Bound<'py, PyDict>)> {
        let rows = rows(
            t_secs.as_slice()?,
            Some(pupil_mm.as_slice()?),
            luminance_cd_m2.as_slice()?,
            field_area_deg2,
        )?;
        let mut initial = ResponseParams::default();
        if let Some(a) = age_years {
            initial.adaptation.age_years = a;
        }
        let options = FitOptions {
            fit_dynamics,
            min_samples,
            ..FitOptions::default()
        };
        let fit = py
            .detach(|| fit_observer(&rows, &initial, &options))
            .map_err(|e| err(format!("cannot fit the observer: {e}")))?;
        let d = PyDict::new(py);
        d.set_item("r_squared", fit.r_squared)?;
        d.set_item("rms_mm", fit.rms_mm)?;
        d.set_item("samples_used", fit.samples_used)?;
        Ok((Self { params: fit.params }, d))
    }

    fn __repr__(&self) -> String {
        let p = &self.params;
        format!(
            "PupilLightResponse(age_years={}, latency_secs={:.4}, constriction_tau_secs={:.4}, \
             redilation_tau_secs={:.4}, scale={:.4}, offset_mm={:.4})",
            p.adaptation.age_years,
            p.dynamics.latency_secs,
            p.dynamics.constriction_tau_secs,
            p.dynamics.redilation_tau_secs,
            p.range.scale,
            p.range.offset_mm
        )
    }
}

/// The glare kernel `gazelight psf` builds: (size, size, 3) float32 linear
/// sRGB weights, each channel summing to 1, centre at (size//2, size//2);
/// with its facts (deg_per_px, energy, ...). Options as the CLI's flags;
/// None keeps the CLI's default.
#[pyfunction]
#[pyo3(signature = (pupil_mm, ppd=None, field_deg=None, age_years=None, pigmentation=None,
    particles=None, particle_um=None, stray_light=true, glare_scale="physical"))]
#[allow(clippy::too_many_arguments)]
pub(crate) fn psf<'py>(
    py: Python<'py>,
    pupil_mm: f64,
    ppd: Option<f64>,
    field_deg: Option<f64>,
    age_years: Option<f64>,
    pigmentation: Option<f64>,
    particles: Option<usize>,
    particle_um: Option<f64>,
    stray_light: bool,
    glare_scale: &str,
) -> PyResult<(Bound<'py, PyArray3<f32>>, Bound<'py, PyDict>)> {
    let glare_scale: GlareScale = glare_scale
        .parse()
        .map_err(|e| PyValueError::new_err(format!("glare_scale: {e}")))?;
    // The same mapping of flags onto parameters as `gazelight psf`.
    let mut params = PsfParams {
        pupil_mm,
        stray_light,
        glare_scale,
        ..PsfParams::default()
    };
    if pupil_mm.is_finite() && pupil_mm > 0.0 {
        params.pupil_range_mm = [pupil_mm, pupil_mm];
    }
    if let Some(n) = particles {
        params.particles = n;
    }
    if let Some(s) = particle_um {
        params.particle_um = s;
    }
    if let Some(p) = ppd {
        params.ppd = p;
    }
    if let Some(f) = field_deg {
        params.field_deg = f;
    }
    if let Some(a) = age_years {
        params.age_years = a;
    }
    if let Some(p) = pigmentation {
        params.pigmentation = p;
    }
    let (size, rgb, facts) = py
        .detach(|| -> Result<_, String> {
            let builder = PsfBuilder::new(params.clone()).map_err(|e| e.to_string())?;
            let k = builder.kernel();
            let facts = (
                k.pupil_mm,
                k.deg_per_px,
                k.energy(),
                builder.stray_light_energy(),
                k.wavelengths_nm.clone(),
            );
            Ok((k.size, k.rgb.clone(), facts))
        })
        .map_err(err)?;
    let flat: Vec<f32> = rgb.into_iter().flatten().collect();
    let arr = PyArray1::from_vec(py, flat).reshape([size, size, 3])?;
    let d = PyDict::new(py);
    d.set_item("pupil_mm", facts.0)?;
    d.set_item("deg_per_px", facts.1)?;
    d.set_item("size", size)?;
    d.set_item("energy", facts.2.to_vec())?;
    d.set_item("stray_light_energy", facts.3)?;
    d.set_item("wavelengths_nm", facts.4)?;
    Ok((arr, d))
}
