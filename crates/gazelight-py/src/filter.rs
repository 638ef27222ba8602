//! `gazelight.FilterChain` and `gazelight.EyeState`: the library's one
//! filter chain, fed sample by sample from Python (or a whole recording
//! through `read`), and the state it keeps.

use std::sync::{Mutex, MutexGuard, PoisonError};

use pyo3::exceptions::PyValueError;
use pyo3::prelude::*;

use gazelight_tracker::filter::FilterChain as Chain;
use gazelight_tracker::{DetectorMethod, GazeEyes, GazeSample, PupilSample, PupilUnit, Sample};

use crate::read::{ORIGINS, UNITS, origin_code, unit_code};

/// The filtered eye state after a sample (or a live source's newest).
#[pyclass(module = "gazelight", name = "EyeState", frozen, get_all)]
#[derive(Clone)]
pub(crate) struct EyeState {
    /// Time of the newest sample in it, s (the source's clock; a live
    /// source's host clock).
    pub(crate) t_secs: f64,
    /// Fused gaze, normalised image coordinates, top-left origin.
    pub(crate) gaze_uv: (f32, f32),
    pub(crate) gaze_valid: bool,
    /// The model aperture per eye (0 right, 1 left), mm: the pupil the
    /// glare PSF is built for (held through blinks; not a measurement).
    pub(crate) pupil_mm: (f32, f32),
    /// The measured pupil per eye (0 right, 1 left) in `measured_unit`, the
    /// newest clean sample's own value; None where the eye is not measured
    /// now (decided a margin after the sample: see `read`).
    pub(crate) measured: (Option<f32>, Option<f32>),
    pub(crate) measured_unit: (Option<&'static str>, Option<&'static str>),
    /// Where each eye's aperture came from: measured, held, model, default.
    pub(crate) pupil_origin: (&'static str, &'static str),
    /// Confidence of each eye's newest raw sample.
    pub(crate) confidence: (f32, f32),
    /// Whether the eyes are considered closed (a blink).
    pub(crate) blink: bool,
}

impl From<&gazelight_tracker::EyeState> for EyeState {
    fn from(s: &gazelight_tracker::EyeState) -> Self {
        let origin = |e: usize| ORIGINS[origin_code(s.eyes[e].pupil_origin) as usize];
        let unit = |e: usize| {
            s.eyes[e]
                .measured_unit
                .map(|u| UNITS[usize::from(unit_code(u))])
        };
        Self {
            t_secs: s.t_secs,
            gaze_uv: (s.gaze_uv[0], s.gaze_uv[1]),
            gaze_valid: s.gaze_valid,
            pupil_mm: (s.eyes[0].pupil_mm, s.eyes[1].pupil_mm),
            measured: (s.eyes[0].measured, s.eyes[1].measured),
            measured_unit: (unit(0), unit(1)),
            pupil_origin: (origin(0), origin(1)),
            confidence: (s.eyes[0].confidence, s.eyes[1].confidence),
            blink: s.blink,
        }
    }
}

#[pymethods]
impl EyeState {
    fn __repr__(&self) -> String {
        format!(
            "EyeState(t_secs={:.4}, pupil_mm=({:.3}, {:.3}), gaze_uv=({:.4}, {:.4}), blink={})",
            self.t_secs,
            self.pupil_mm.0,
            self.pupil_mm.1,
            self.gaze_uv.0,
            self.gaze_uv.1,
            if self.blink { "True" } else { "False" }
        )
    }
}

fn unit_from(name: &str) -> PyResult<PupilUnit> {
    Ok(match name {
        "px" => PupilUnit::Px,
        "mm" => PupilUnit::Mm,
        "arbitrary_area" => PupilUnit::ArbitraryArea,
        "arbitrary" => PupilUnit::Arbitrary,
        _ => {
            return Err(PyValueError::new_err(format!(
                "unit {name:?}: expected px, mm, arbitrary_area or arbitrary"
            )));
        }
    })
}

/// The filter chain (confidence gate, physiological range and rate, blink
/// detector, dropout hold, 1€ gaze filter, calibration), as `gazelight
/// inspect`, `replay` and the live eye task run it.
///
/// Usable from any Python thread (as `Source`): the chain is behind a
/// mutex, so a second thread's use is never a panic across the boundary.
#[pyclass(module = "gazelight", name = "FilterChain")]
pub(crate) struct FilterChain {
    chain: Mutex<Chain>,
}

impl FilterChain {
    /// The chain through `&mut self` (no locking).
    fn chain(&mut self) -> &mut Chain {
        self.chain.get_mut().unwrap_or_else(PoisonError::into_inner)
    }

    /// The chain through `&self`.
    fn locked(&self) -> MutexGuard<'_, Chain> {
        self.chain.lock().unwrap_or_else(PoisonError::into_inner)
    }
}

#[pymethods]
impl FilterChain {
    /// `config`: None (the defaults), a TOML string or a dict with the keys
    /// of the CLI configuration's `[filter]` table; `calibration`: a
    /// profile path or a `Calibration`.
    #[new]
    #[pyo3(signature = (config=None, calibration=None))]
    fn new(
        config: Option<&Bound<'_, PyAny>>,
        calibration: Option<&Bound<'_, PyAny>>,
    ) -> PyResult<Self> {
        Ok(Self {
            chain: Mutex::new(crate::read::chain_for(config, calibration)?),
        })
    }

    /// Feeds one pupil sample; returns the state after it.
    #[pyo3(signature = (t_secs, eye, diameter, unit="mm", confidence=1.0))]
    fn push_pupil(
        &mut self,
        t_secs: f64,
        eye: u8,
        diameter: f32,
        unit: &str,
        confidence: f32,
    ) -> PyResult<EyeState> {
        let unit = unit_from(unit)?;
        let s = Sample::Pupil(PupilSample {
            t_secs,
            eye,
            diameter_raw: diameter,
            unit,
            diameter_mm: (unit == PupilUnit::Mm).then_some(diameter),
            confidence,
            norm_pos: [f32::NAN; 2],
            method: DetectorMethod::Other,
        });
        Ok(EyeState::from(&self.chain().push(&s).state))
    }

    /// Feeds one binocular gaze sample (normalised, top-left origin).
    #[pyo3(signature = (t_secs, u, v, confidence=1.0))]
    fn push_gaze(&mut self, t_secs: f64, u: f32, v: f32, confidence: f32) -> EyeState {
        let s = Sample::Gaze(GazeSample {
            t_secs,
            gaze_uv: [u, v],
            confidence,
            eyes: GazeEyes::Binocular,
        });
        EyeState::from(&self.chain().push(&s).state)
    }

    /// Filters whole pupil series of one or both eyes: `t_secs`, and per
    /// eye the diameters (mm unless `unit` says otherwise; NaN or 0: no
    /// pupil) — each row is one sample of the right eye, then one of the
    /// left, as a recording's importer delivers a binocular row.
    /// Returns `(right, left)`: each sample's measured pupil — its own
    /// value where the guideline cleaning keeps it, NaN where it does not
    /// (lost, within the margins of a blink, a speed outlier) — as `read`'s
    /// `measured_value` (None for an eye not given). The series' end is the
    /// end of the stream: its last samples are decided.
    #[pyo3(signature = (t_secs, right=None, left=None, confidence=None, unit="mm"))]
    #[allow(clippy::type_complexity)]
    fn filter_pupils<'py>(
        &mut self,
        py: Python<'py>,
        t_secs: numpy::PyReadonlyArray1<'py, f64>,
        right: Option<numpy::PyReadonlyArray1<'py, f32>>,
        left: Option<numpy::PyReadonlyArray1<'py, f32>>,
        confidence: Option<numpy::PyReadonlyArray1<'py, f32>>,
        unit: &str,
    ) -> PyResult<(
        Option<Bound<'py, numpy::PyArray1<f32>>>,
        Option<Bound<'py, numpy::PyArray1<f32>>>,
    )> {
        let unit = unit_from(unit)?;
        let t = t_secs.as_slice()?;
        let eyes = [
            right.as_ref().map(|a| a.as_slice()).transpose()?,
            left.as_ref().map(|a| a.as_slice()).transpose()?,
        ];
        let c = confidence.as_ref().map(|a| a.as_slice()).transpose()?;
        let lens: Vec<usize> = eyes
            .iter()
            .flatten()
            .chain(c.iter())
            .map(|a| a.len())
            .collect();
        if lens.is_empty() {
            return Err(PyValueError::new_err("give right, left or both"));
        }
        if lens.iter().any(|&n| n != t.len()) {
            return Err(PyValueError::new_err(format!(
                "t_secs has {} rows; right, left and confidence must have as many (got {lens:?})",
                t.len()
            )));
        }
        let mut out: [Vec<f32>; 2] = [Vec::new(), Vec::new()];
        // Per eye: the rows waiting for the chain's decision.
        let mut pending: [std::collections::VecDeque<usize>; 2] = Default::default();
        let chain = self.chain();
        chain.keep_decided();
        let decide = |chain: &mut Chain,
                      out: &mut [Vec<f32>; 2],
                      pending: &mut [std::collections::VecDeque<usize>; 2]| {
            for d in chain.take_decided() {
                let e = usize::from(d.eye & 1);
                if let Some(i) = pending[e].pop_front() {
                    out[e][i] = if d.fate.is_clean() { d.value } else { f32::NAN };
                }
            }
        };
        for i in 0..t.len() {
            for (e, d) in eyes.iter().enumerate() {
                let Some(d) = d else { continue };
                let s = Sample::Pupil(PupilSample {
                    t_secs: t[i],
                    eye: e as u8,
                    diameter_raw: d[i],
                    unit,
                    diameter_mm: (unit == PupilUnit::Mm).then_some(d[i]),
                    confidence: c.map_or(1.0, |c| c[i]),
                    norm_pos: [f32::NAN; 2],
                    method: DetectorMethod::Other,
                });
                out[e].push(f32::NAN);
                if t[i].is_finite() {
                    pending[e].push_back(out[e].len() - 1);
                }
                chain.push(&s);
                decide(chain, &mut out, &mut pending);
            }
        }
        chain.flush_pending();
        decide(chain, &mut out, &mut pending);
        let [r, l] = out;
        Ok((
            eyes[0].is_some().then(|| numpy::PyArray1::from_vec(py, r)),
            eyes[1].is_some().then(|| numpy::PyArray1::from_vec(py, l)),
        ))
    }

    /// The state after the last sample.
    #[getter]
    fn state(&self) -> EyeState {
        EyeState::from(self.locked().state())
    }

    /// The chain's counters (as `inspect --json`'s `chain`), JSON text.
    fn stats_json(&self) -> PyResult<String> {
        serde_json::to_string(self.locked().stats()).map_err(crate::err)
    }
}
