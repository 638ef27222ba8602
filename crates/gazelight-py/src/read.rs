//! `gazelight.read`: a recording through the importer and the filter chain
//! the CLI's `inspect` and `replay` use, as per-eye columns.
//!
//! One pass, the GIL released: each sample goes through
//! [`FilterChain::push`]; a pupil sample of eye 0 or 1 adds one row to that
//! eye's columns (its raw values and the chain's state right after it), a
//! gaze sample one row to the gaze columns, a recording's blink event one
//! row to the events; the chain's closures (blinks and dropouts) are
//! collected as it reports them, and [`FilterChain::finish`] flushes the
//! last ones at the recording's end, as `inspect` does.

use std::path::{Path, PathBuf};

use numpy::PyArray1;
use pyo3::prelude::*;
use pyo3::types::{PyDict, PyList};

use gazelight_tracker::filter::{
    ChainStats, Closure, ClosureKind, FilterChain, PupilOutcome, SampleFate, TrackSample,
};
use gazelight_tracker::import::{self, Importer};
use gazelight_tracker::profile::PupilCalibration;
use gazelight_tracker::{DetectorMethod, GazeEyes, PupilOrigin, PupilUnit, Sample};

use crate::err;

/// The unit names, indexed by the `unit` column's codes.
pub(crate) const UNITS: [&str; 4] = ["px", "mm", "arbitrary_area", "arbitrary"];
/// The detector names, indexed by the `detector` column's codes (as
/// `inspect --json`'s `streams`).
pub(crate) const DETECTORS: [&str; 3] = ["2d", "3d", "pupil"];
/// The origin names, indexed by the `origin` column's codes.
pub(crate) const ORIGINS: [&str; 4] = ["measured", "held", "model", "default"];
/// The outcome names, indexed by the `outcome` column's codes (255: none).
pub(crate) const OUTCOMES: [&str; 3] = ["measured", "dropout", "uncalibrated"];
/// The fate names (what the guideline cleaning made of each sample),
/// indexed by the `fate` column's codes (255: not decided: a sample with
/// no valid time).
pub(crate) const FATES: [&str; 6] = [
    "clean",
    "lost",
    "out_of_range",
    "margin",
    "speed",
    "other_stream",
];

fn fate_code(f: SampleFate) -> u8 {
    match f {
        SampleFate::Clean => 0,
        SampleFate::Lost => 1,
        SampleFate::OutOfRange => 2,
        SampleFate::Margin => 3,
        SampleFate::Speed => 4,
        SampleFate::OtherStream => 5,
    }
}

pub(crate) fn unit_code(u: PupilUnit) -> u8 {
    match u {
        PupilUnit::Px => 0,
        PupilUnit::Mm => 1,
        PupilUnit::ArbitraryArea => 2,
        PupilUnit::Arbitrary => 3,
    }
}

pub(crate) fn origin_code(o: PupilOrigin) -> u8 {
    match o {
        PupilOrigin::Measured => 0,
        PupilOrigin::Held => 1,
        PupilOrigin::Model => 2,
        PupilOrigin::Default => 3,
    }
}

fn detector_code(m: DetectorMethod) -> u8 {
    match m {
        DetectorMethod::Pupil2d => 0,
        DetectorMethod::Pupil3d => 1,
        DetectorMethod::Other => 2,
    }
}

fn outcome_code(o: PupilOutcome) -> u8 {
    match o {
        PupilOutcome::Measured => 0,
        PupilOutcome::Uncalibrated => 2,
        PupilOutcome::Rejected => 1,
    }
}

/// One eye's pupil columns, a row per pupil sample of that eye.
#[derive(Default)]
struct EyeColumns {
    t_secs: Vec<f64>,
    pupil_raw: Vec<f32>,
    unit: Vec<u8>,
    tracker_mm: Vec<f32>,
    confidence: Vec<f32>,
    detector: Vec<u8>,
    /// The measured pupil in mm (clean samples in mm), else NaN.
    pupil_mm: Vec<f32>,
    /// The measured pupil in `measured_unit` (clean samples), else NaN.
    measured: Vec<f32>,
    measured_unit: Vec<u8>,
    /// The guidelines' interpolated series of `measured` across the
    /// discarded stretches, and where it is interpolated.
    interpolated: Vec<f32>,
    is_interpolated: Vec<bool>,
    /// The model aperture after this sample was decided, mm.
    aperture_mm: Vec<f32>,
    fate: Vec<u8>,
    origin: Vec<u8>,
    outcome: Vec<u8>,
    blink: Vec<bool>,
    settling: Vec<bool>,
    /// Rows waiting for the chain's decision, oldest first.
    pending: std::collections::VecDeque<usize>,
}

impl EyeColumns {
    /// The chain's decision about this eye's oldest pending row.
    fn decide(&mut self, d: &TrackSample, state: &gazelight_tracker::EyeState) {
        let Some(i) = self.pending.pop_front() else {
            return;
        };
        let ch = &state.eyes[usize::from(d.eye & 1)];
        let clean = d.fate.is_clean();
        self.measured[i] = if clean { d.value } else { f32::NAN };
        self.measured_unit[i] = unit_code(d.unit);
        self.pupil_mm[i] = if clean && d.unit == PupilUnit::Mm {
            d.value
        } else {
            f32::NAN
        };
        self.aperture_mm[i] = ch.pupil_mm;
        self.fate[i] = fate_code(d.fate);
        self.origin[i] = origin_code(ch.pupil_origin);
        self.outcome[i] = outcome_code(PupilOutcome::from(d.fate));
        self.settling[i] = ch.settling;
    }
}

/// The gaze columns, a row per gaze sample.
#[derive(Default)]
struct GazeColumns {
    t_secs: Vec<f64>,
    u: Vec<f32>,
    v: Vec<f32>,
    confidence: Vec<f32>,
    /// 0 binocular, 1 right eye, 2 left eye.
    eyes: Vec<u8>,
    filtered_u: Vec<f32>,
    filtered_v: Vec<f32>,
    filtered_valid: Vec<bool>,
}

/// Events: the recording's own blinks, the chain's closures.
#[derive(Default)]
struct Events {
    start_t_secs: Vec<f64>,
    end_t_secs: Vec<f64>,
    /// 0 right, 1 left, -1 both (a recording's binocular event).
    eye: Vec<i8>,
    /// Closures only: true for a blink, false for a dropout.
    blink: Vec<bool>,
}

impl Events {
    fn closure(&mut self, c: &Closure) {
        self.start_t_secs.push(c.start_t_secs);
        self.end_t_secs.push(c.end_t_secs);
        self.eye.push(c.eye as i8);
        self.blink.push(matches!(c.kind, ClosureKind::Blink));
    }
}

/// Everything one pass collects.
struct Columns {
    format: String,
    eyes: [EyeColumns; 2],
    gaze: GazeColumns,
    recording_blinks: Events,
    closures: Events,
    stats: ChainStats,
    warnings: Vec<String>,
    skipped_records: u64,
    eye_gaze: Option<String>,
}

/// The pass itself (no Python in it: it runs with the GIL released).
fn collect(
    importer: &mut dyn Importer,
    mut chain: FilterChain,
    path: &Path,
) -> Result<Columns, String> {
    let mut eyes: [EyeColumns; 2] = Default::default();
    let mut gaze = GazeColumns::default();
    let mut recording_blinks = Events::default();
    let mut closures = Events::default();
    let mut last_t = f64::NEG_INFINITY;
    chain.keep_decided();
    let decide = |chain: &mut FilterChain, eyes: &mut [EyeColumns; 2]| {
        let state = *chain.state();
        for d in chain.take_decided() {
            eyes[usize::from(d.eye & 1)].decide(&d, &state);
        }
    };
    for sample in &mut *importer {
        let sample = sample
            .map_err(|e| format!("while reading {}: {}", path.display(), crate::chain_msg(&e)))?;
        let up = chain.push(&sample);
        let t = sample.t_secs();
        if t.is_finite() {
            last_t = last_t.max(t);
        }
        if let Some(c) = &up.closure {
            closures.closure(c);
        }
        match sample {
            Sample::Pupil(p) if p.eye <= 1 => {
                let e = p.eye as usize;
                let c = &mut eyes[e];
                let ch = &up.state.eyes[e];
                c.t_secs.push(p.t_secs);
                c.pupil_raw.push(p.diameter_raw);
                c.unit.push(unit_code(p.unit));
                c.tracker_mm.push(p.diameter_mm.unwrap_or(f32::NAN));
                c.confidence.push(p.confidence);
                c.detector.push(detector_code(p.method));
                c.pupil_mm.push(f32::NAN);
                c.measured.push(f32::NAN);
                c.measured_unit.push(unit_code(p.unit));
                c.aperture_mm.push(ch.pupil_mm);
                c.fate.push(255);
                c.origin.push(origin_code(ch.pupil_origin));
                c.outcome.push(255);
                c.blink.push(up.state.blink);
                c.settling.push(ch.settling);
                if p.t_secs.is_finite() {
                    c.pending.push_back(c.t_secs.len() - 1);
                }
                decide(&mut chain, &mut eyes);
            }
            Sample::Pupil(_) => {}
            Sample::Gaze(g) => {
                gaze.t_secs.push(g.t_secs);
                gaze.u.push(g.gaze_uv[0]);
                gaze.v.push(g.gaze_uv[1]);
                gaze.confidence.push(g.confidence);
                gaze.eyes.push(match g.eyes {
                    GazeEyes::Binocular => 0,
                    GazeEyes::Right => 1,
                    GazeEyes::Left => 2,
                });
                gaze.filtered_u.push(up.state.gaze_uv[0]);
                gaze.filtered_v.push(up.state.gaze_uv[1]);
                gaze.filtered_valid.push(up.state.gaze_valid);
            }
            Sample::Blink(b) => {
                recording_blinks.start_t_secs.push(b.start_t_secs);
                recording_blinks.end_t_secs.push(b.end_t_secs);
                recording_blinks
                    .eye
                    .push(b.eye.map_or(-1, |e| e.min(127) as i8));
            }
        }
    }
    // No pupil (eye 0 or 1), gaze or blink sample: the CLI's error, naming
    // the file and why (`inspect` and `replay` refuse it alike).
    if eyes.iter().all(|e| e.t_secs.is_empty())
        && gaze.t_secs.is_empty()
        && recording_blinks.start_t_secs.is_empty()
    {
        return Err(gazelight_render::feed::no_samples(
            path,
            importer.warnings(),
            &importer.data_files(),
        )
        .to_string());
    }
    // The closures still open at the end, as `inspect` counts them.
    let end = if last_t.is_finite() { last_t } else { 0.0 };
    for c in chain.finish(end).iter().flatten() {
        closures.closure(c);
    }
    decide(&mut chain, &mut eyes);
    for c in &mut eyes {
        c.interpolated = c.measured.clone();
        c.is_interpolated = vec![false; c.measured.len()];
        gazelight_tracker::filter::clean::interpolate_gaps(
            &c.t_secs,
            &mut c.interpolated,
            &mut c.is_interpolated,
            gazelight_tracker::filter::clean::DEFAULT_MAX_INTERPOLATED_GAP_S,
        );
    }
    let w = importer.warnings();
    Ok(Columns {
        format: importer.format().to_owned(),
        eyes,
        gaze,
        recording_blinks,
        closures,
        stats: *chain.stats(),
        warnings: w
            .messages
            .iter()
            .cloned()
            // The CLI's `inspect`/`replay` warning, from the same function.
            .chain(gazelight_tracker::summary::pupil_rejection(chain.stats()))
            .collect(),
        skipped_records: w.skipped_records,
        eye_gaze: importer
            .eye_gaze()
            .and_then(|g| serde_json::to_string(g).ok()),
    })
}

/// The chain for a recording: `config` (None, TOML or dict) and an
/// optional calibration (a path or a `Calibration`).
pub(crate) fn chain_for(
    config: Option<&Bound<'_, PyAny>>,
    calibration: Option<&Bound<'_, PyAny>>,
) -> PyResult<FilterChain> {
    let cfg = crate::config::filter_config(config)?;
    let mut chain = FilterChain::new(cfg, PupilCalibration::identity())
        .map_err(|e| err(format!("filter.{e}")))?;
    if let Some(c) = calibration.filter(|c| !c.is_none()) {
        let profile = match c.extract::<crate::Calibration>() {
            Ok(cal) => cal.inner,
            Err(_) => crate::load_calibration(&c.extract::<PathBuf>()?)?,
        };
        chain.set_calibration(profile);
    }
    Ok(chain)
}

fn events_dict<'py>(py: Python<'py>, e: Events, closures: bool) -> PyResult<Bound<'py, PyDict>> {
    let d = PyDict::new(py);
    d.set_item("start_t_secs", PyArray1::from_vec(py, e.start_t_secs))?;
    d.set_item("end_t_secs", PyArray1::from_vec(py, e.end_t_secs))?;
    d.set_item("eye", PyArray1::from_vec(py, e.eye))?;
    if closures {
        d.set_item("blink", PyArray1::from_vec(py, e.blink))?;
    }
    Ok(d)
}

/// A recording's events ([`import::events`]) as columns: `t_secs`,
/// `t_clock`, `duration_secs` (NaN: none) and `trial` (-1: none) as
/// arrays, `text` and `source` as lists, the trials as dicts, the clock
/// and the counts of events dropped and texts cut.
fn recording_events<'py>(
    py: Python<'py>,
    ev: import::events::RecordingEvents,
) -> PyResult<Bound<'py, PyDict>> {
    let d = PyDict::new(py);
    let n = ev.events.len();
    let (mut t, mut clock, mut dur, mut trial) = (
        Vec::with_capacity(n),
        Vec::with_capacity(n),
        Vec::with_capacity(n),
        Vec::with_capacity(n),
    );
    let (mut text, mut source) = (Vec::with_capacity(n), Vec::with_capacity(n));
    for e in ev.events {
        t.push(e.t_secs);
        clock.push(e.t_clock);
        dur.push(e.duration_secs.unwrap_or(f64::NAN));
        trial.push(e.trial.map_or(-1, i64::from));
        text.push(e.text);
        source.push(e.source);
    }
    d.set_item("t_secs", PyArray1::from_vec(py, t))?;
    d.set_item("t_clock", PyArray1::from_vec(py, clock))?;
    d.set_item("duration_secs", PyArray1::from_vec(py, dur))?;
    d.set_item("trial", PyArray1::from_vec(py, trial))?;
    d.set_item("text", text)?;
    d.set_item("source", source)?;
    let trials = PyList::empty(py);
    for tr in ev.trials {
        let td = PyDict::new(py);
        td.set_item("id", tr.id)?;
        td.set_item("start_t_secs", tr.start_t_secs)?;
        td.set_item("end_t_secs", tr.end_t_secs)?;
        td.set_item("result", tr.result)?;
        let vars = PyDict::new(py);
        for (k, v) in tr.vars {
            vars.set_item(k, v)?;
        }
        td.set_item("vars", vars)?;
        trials.append(td)?;
    }
    d.set_item("trials", trials)?;
    d.set_item("clock", ev.clock)?;
    d.set_item("dropped", ev.dropped)?;
    d.set_item("truncated", ev.truncated)?;
    Ok(d)
}

/// Reads a recording (any format `gazelight inspect` reads) through the
/// filter chain; returns a dict of numpy columns (the Python `read` wraps
/// it). Raises `GazelightError` with the CLI's message.
#[pyfunction]
#[pyo3(signature = (path, config=None, calibration=None))]
pub(crate) fn read_recording<'py>(
    py: Python<'py>,
    path: PathBuf,
    config: Option<&Bound<'py, PyAny>>,
    calibration: Option<&Bound<'py, PyAny>>,
) -> PyResult<Bound<'py, PyDict>> {
    let chain = chain_for(config, calibration)?;
    let (mut cols, events) = py
        .detach(
            || -> Result<(Columns, import::events::RecordingEvents), String> {
                let mut importer = import::open(&path).map_err(|e| crate::chain_msg(&e))?;
                let cols = collect(importer.as_mut(), chain, &path)?;
                // The recording's events (bounded); one that cannot be read is
                // a warning, as `inspect` says it.
                let events = match import::events::read(&path) {
                    Ok(ev) => ev,
                    Err(e) => {
                        let mut ev = import::events::RecordingEvents::default();
                        ev.warnings.messages.push(format!("events not read: {e}"));
                        ev
                    }
                };
                Ok((cols, events))
            },
        )
        .map_err(err)?;
    cols.warnings.extend(
        events
            .warnings
            .messages
            .iter()
            .map(|m| format!("events: {m}")),
    );
    let d = PyDict::new(py);
    d.set_item("path", &path)?;
    d.set_item("format", cols.format)?;
    let eyes = PyList::empty(py);
    for c in cols.eyes {
        let e = PyDict::new(py);
        e.set_item("t_secs", PyArray1::from_vec(py, c.t_secs))?;
        e.set_item("pupil_raw", PyArray1::from_vec(py, c.pupil_raw))?;
        e.set_item("unit", PyArray1::from_vec(py, c.unit))?;
        e.set_item("tracker_mm", PyArray1::from_vec(py, c.tracker_mm))?;
        e.set_item("confidence", PyArray1::from_vec(py, c.confidence))?;
        e.set_item("detector", PyArray1::from_vec(py, c.detector))?;
        e.set_item("pupil_mm", PyArray1::from_vec(py, c.pupil_mm))?;
        e.set_item("measured", PyArray1::from_vec(py, c.measured))?;
        e.set_item("measured_unit", PyArray1::from_vec(py, c.measured_unit))?;
        e.set_item("interpolated", PyArray1::from_vec(py, c.interpolated))?;
        e.set_item("is_interpolated", PyArray1::from_vec(py, c.is_interpolated))?;
        e.set_item("aperture_mm", PyArray1::from_vec(py, c.aperture_mm))?;
        e.set_item("fate", PyArray1::from_vec(py, c.fate))?;
        e.set_item("origin", PyArray1::from_vec(py, c.origin))?;
        e.set_item("outcome", PyArray1::from_vec(py, c.outcome))?;
        e.set_item("blink", PyArray1::from_vec(py, c.blink))?;
        e.set_item("settling", PyArray1::from_vec(py, c.settling))?;
        eyes.append(e)?;
    }
    d.set_item("eyes", eyes)?;
    let g = cols.gaze;
    let gd = PyDict::new(py);
    gd.set_item("t_secs", PyArray1::from_vec(py, g.t_secs))?;
    gd.set_item("u", PyArray1::from_vec(py, g.u))?;
    gd.set_item("v", PyArray1::from_vec(py, g.v))?;
    gd.set_item("confidence", PyArray1::from_vec(py, g.confidence))?;
    gd.set_item("eyes", PyArray1::from_vec(py, g.eyes))?;
    gd.set_item("filtered_u", PyArray1::from_vec(py, g.filtered_u))?;
    gd.set_item("filtered_v", PyArray1::from_vec(py, g.filtered_v))?;
    gd.set_item("filtered_valid", PyArray1::from_vec(py, g.filtered_valid))?;
    d.set_item("gaze", gd)?;
    d.set_item(
        "recording_blinks",
        events_dict(py, cols.recording_blinks, false)?,
    )?;
    d.set_item("closures", events_dict(py, cols.closures, true)?)?;
    d.set_item("events", recording_events(py, events)?)?;
    d.set_item("stats", serde_json::to_string(&cols.stats).map_err(err)?)?;
    d.set_item("warnings", cols.warnings)?;
    d.set_item("skipped_records", cols.skipped_records)?;
    d.set_item("eye_gaze", cols.eye_gaze)?;
    d.set_item("units", UNITS.to_vec())?;
    d.set_item("detectors", DETECTORS.to_vec())?;
    d.set_item("origins", ORIGINS.to_vec())?;
    d.set_item("outcomes", OUTCOMES.to_vec())?;
    d.set_item("fates", FATES.to_vec())?;
    Ok(d)
}

/// The summary `gazelight inspect --json` prints for a recording, as JSON
/// text (the library's `summarize_importer`, the CLI's code path).
#[pyfunction]
#[pyo3(signature = (path, config=None, calibration=None))]
pub(crate) fn inspect_json(
    py: Python<'_>,
    path: PathBuf,
    config: Option<&Bound<'_, PyAny>>,
    calibration: Option<&Bound<'_, PyAny>>,
) -> PyResult<String> {
    let chain = chain_for(config, calibration)?;
    py.detach(|| -> Result<String, String> {
        let mut importer = import::open(&path).map_err(|e| crate::chain_msg(&e))?;
        let summary = gazelight_tracker::summary::summarize_importer(importer.as_mut(), chain)
            .map_err(|e| format!("while reading {}: {}", path.display(), crate::chain_msg(&e)))?;
        // `gazelight inspect`'s refusal of a recording without samples.
        let c = &summary.samples;
        if c.pupil == [0, 0] && c.gaze == 0 && c.gaze_per_eye == 0 && c.blink_events == 0 {
            return Err(gazelight_render::feed::no_samples(
                &path,
                importer.warnings(),
                &importer.data_files(),
            )
            .to_string());
        }
        let mut summary = summary;
        // The recording's events, as `gazelight inspect` adds them.
        match import::events::read(&path) {
            Ok(ev) => {
                summary
                    .warnings
                    .extend(ev.warnings.messages.iter().map(|m| format!("events: {m}")));
                summary.events = Some(ev.summary());
            }
            Err(e) => summary.warnings.push(format!("events not read: {e}")),
        }
        // The CLI's own warning, from the same function.
        if let Some(w) = gazelight_tracker::summary::pupil_rejection(&summary.chain) {
            summary.warnings.push(w);
        }
        serde_json::to_string(&summary).map_err(|e| e.to_string())
    })
    .map_err(err)
}
