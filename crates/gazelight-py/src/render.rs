//! `gazelight.render`: a scene and a gaze/pupil trace or a recording →
//! frames, one at a time, through `gazelight_render`'s frame step — the
//! code `gazelight render` and `replay` run — on the CPU or the GPU
//! pipeline, chosen as the CLI's `--backend` chooses
//! (`gazelight_app::backend`; `backend="auto"|"gpu"|"cpu"`).
//!
//! Nothing is loaded whole: a recording is scanned once for its time range
//! and then streamed just ahead of the frame clock; each `next()` renders
//! one frame with the GIL released. The frame is the display image the CLI
//! writes as PNG (`write_png` writes it with the CLI's encoder) or, on
//! request, the retinal image in cd/m². A recording's rows carry the
//! pupil light response (`pupil_light_mm`, `pupil_residual_mm`) of
//! `gazelight_render::pupil_light`, as `replay`'s `timeline.csv` does.

use std::path::{Path, PathBuf};

use std::sync::Mutex;

use numpy::{PyArray1, PyArrayMethods, PyUntypedArrayMethods};
use pyo3::prelude::*;
use pyo3::types::{PyDict, PyString};

use gazelight_app::backend::{BackendChoice, BackendError, Renderer, Spelling, view_renderers};
use gazelight_app::bounds;
use gazelight_app::config::render::scene_projection;
use gazelight_app::config::{ConfigUser, RenderConfig};
use gazelight_app::observer::ObserverFlags;
use gazelight_render::analysis::AnalysisStep;
use gazelight_render::demo;
use gazelight_render::display_light::{DisplayGeometry, DisplayLight, DisplayLightTable};
use gazelight_render::feed::{ImporterSamples, SampleFeed, scan};
use gazelight_render::frame::FrameStep;
use gazelight_render::png::PngCompression;
use gazelight_render::pupil_light::{
    self, ParamSource, PupilLight, PupilLightOptions, PupilLightPlan,
};
use gazelight_render::timeline::{PUPIL_LIGHT_COLUMNS, TIMELINE_COLUMNS};
use gazelight_tracker::filter::FilterChain;
use gazelight_tracker::profile::PupilCalibration;
use gazelight_tracker::pupil_response::ResponseParams;
use gazelight_tracker::{GazeTrace, PupilUnit, Sample, trace_source};
use gazelight_vision::RgbImage;
use gazelight_vision::pipeline::PipelineConfig;
use gazelight_vision::scene::{LuminanceScale, PanoramaView, Scene, ViewParams};

use crate::err;

type Samples = Box<dyn Iterator<Item = Sample> + Send>;

/// The CLI's configuration from what the Python side passed: `None`, TOML
/// text (a file's, read with the bounded reader, named by `name`) or a
/// dict converted as it is; the application core loads and checks it
/// (`gazelight_app::config::RenderConfig`, `render`'s and `replay`'s
/// loader), so every key, range and message is the CLI's.
fn load_config(
    config: Option<&Bound<'_, PyAny>>,
    name: &str,
    user: ConfigUser,
) -> PyResult<RenderConfig> {
    let origin = Path::new(name);
    let fail = |e: gazelight_app::config::ConfigError| err(crate::chain_msg(&e));
    match config {
        None => Ok(RenderConfig::default()),
        Some(c) if c.is_none() => Ok(RenderConfig::default()),
        Some(c) if c.is_instance_of::<PyString>() => {
            let text: String = c.extract()?;
            RenderConfig::from_str(&text, origin, user).map_err(fail)
        }
        Some(c) => match crate::config::to_toml(c, "")? {
            toml::Value::Table(t) => RenderConfig::from_table(t, origin, user).map_err(fail),
            _ => Err(pyo3::exceptions::PyTypeError::new_err(
                "config: expected a dict, a TOML string or a path",
            )),
        },
    }
}

/// One render in progress: an iterator of `(frame, row)`.
#[pyclass(module = "gazelight", name = "Render")]
pub(crate) struct Render {
    /// `None` once finished or closed. A `next()` holds the lock while it
    /// renders (without the GIL); a second thread's `next()` meanwhile is
    /// refused rather than waited for (it would hold the GIL while waiting).
    state: Mutex<Option<Box<Running>>>,
    /// The frames it renders.
    #[pyo3(get)]
    frames: usize,
    /// Each frame's width and height (stereo: both eyes side by side).
    #[pyo3(get)]
    size: (usize, usize),
    /// Frames per second on the samples' clock.
    #[pyo3(get)]
    fps: f64,
    /// The keys of the configuration that do not apply (as the CLI's
    /// "ignored" warnings).
    #[pyo3(get)]
    ignored: Vec<String>,
    /// Notes for the Python side to raise as warnings.
    #[pyo3(get)]
    warnings: Vec<String>,
    /// The frame pipeline that renders, as the CLI's summary names it
    /// (`cpu`, `gpu: ADAPTER (BACKEND, hardware|software)`); `None` with
    /// `images=False` (no image pipeline).
    #[pyo3(get)]
    backend: Option<String>,
    /// Why that pipeline (`backend="cpu"`, `auto: no GPU adapter found …`).
    #[pyo3(get)]
    backend_reason: Option<String>,
    /// A recording's pupil light response: each view's parameters and
    /// where they came from (empty for a trace).
    pupil_light_params: Vec<(&'static str, ResponseParams, ParamSource)>,
}

/// What makes the frames: the image pipeline, or with `images=False`
/// only the rows (`gazelight_render::analysis`, the CLI's `--no-frames`
/// path: the same values, the stage timings NaN).
enum Steps {
    Images(Box<FrameStep<Renderer>>),
    Numbers(Box<AnalysisStep>),
}

struct Running {
    step: Steps,
    feed: SampleFeed<Samples>,
    view_img: RgbImage,
    retinal: bool,
    suffixes: Vec<&'static str>,
    /// A recording's pupil light response (`replay`'s), and the first
    /// frame's time on the samples' clock.
    pupil_light: Option<PupilLight>,
    t0_secs: f64,
}

#[pymethods]
impl Render {
    fn __iter__(slf: PyRef<'_, Self>) -> PyRef<'_, Self> {
        slf
    }

    /// The next frame and its timeline row; `StopIteration` after the last.
    fn __next__(&self, py: Python<'_>) -> PyResult<Option<(Py<PyAny>, Py<PyDict>)>> {
        let frames = self.frames;
        let mut guard = match self.state.try_lock() {
            Ok(g) => g,
            Err(std::sync::TryLockError::WouldBlock) => {
                return Err(pyo3::exceptions::PyRuntimeError::new_err(
                    "this render is computing a frame in another thread",
                ));
            }
            Err(std::sync::TryLockError::Poisoned(_)) => return Ok(None),
        };
        let Some(r) = guard.as_deref_mut() else {
            return Ok(None);
        };
        if r.step_count() >= frames {
            *guard = None;
            return Ok(None);
        }
        let Running {
            step,
            feed,
            view_img,
            pupil_light,
            t0_secs,
            ..
        } = &mut *r;
        let mut out = py
            .detach(|| match step {
                Steps::Images(s) => s.step(feed, view_img),
                Steps::Numbers(a) => a.step(feed),
            })
            .map_err(err)?;
        if let Some(plr) = pupil_light {
            plr.apply(
                out.t_secs - *t0_secs,
                &out.state,
                &out.inputs,
                &mut out.rows,
            );
        }
        let image: Py<PyAny> = if let Steps::Numbers(_) = &r.step {
            // `images=False`: no image was made.
            py.None()
        } else if let (true, Steps::Images(step)) = (r.retinal, &r.step) {
            let img = step.retinal();
            let flat: Vec<f32> = img.pixels.iter().flatten().copied().collect();
            PyArray1::from_vec(py, flat)
                .reshape([img.height, img.width, 3])?
                .into_any()
                .unbind()
        } else if let Steps::Images(step) = &r.step {
            let d = step.display();
            PyArray1::from_slice(py, &d.rgba8)
                .reshape([d.height, d.width, 4])?
                .into_any()
                .unbind()
        } else {
            py.None()
        };
        let row = PyDict::new(py);
        let t_secs = out.rows.first().map_or(f64::NAN, |r| r.t_secs);
        row.set_item("t_secs", t_secs)?;
        for (suffix, r) in r.suffixes.iter().zip(&out.rows) {
            for (c, v) in TIMELINE_COLUMNS.iter().zip(r.values()) {
                row.set_item(format!("{c}{suffix}"), v)?;
            }
        }
        if r.pupil_light.is_some() {
            for (suffix, r) in r.suffixes.iter().zip(&out.rows) {
                let values = [r.pupil_light_mm, r.pupil_residual_mm];
                for (c, v) in PUPIL_LIGHT_COLUMNS.iter().zip(values) {
                    row.set_item(format!("{c}{suffix}"), f64::from(v))?;
                }
            }
        }
        row.set_item("frame", out.index)?;
        Ok(Some((image, row.unbind())))
    }

    /// A recording's pupil light response: per view (display order), its
    /// parameters as `replay` writes them to `session.json`
    /// (`pupil_light[_left|_right].*`) and `source` (`default`, `profile`
    /// or `fit`); empty for a trace.
    #[getter]
    fn pupil_light_params<'py>(&self, py: Python<'py>) -> PyResult<Vec<Bound<'py, PyDict>>> {
        self.pupil_light_params
            .iter()
            .map(|(suffix, p, source)| {
                let d = PyDict::new(py);
                d.set_item(
                    "view",
                    match suffix.trim_start_matches('_') {
                        "" => "both",
                        eye => eye,
                    },
                )?;
                d.set_item(
                    "source",
                    match source {
                        ParamSource::Default => "default",
                        ParamSource::Profile => "profile",
                        ParamSource::Fit(_) => "fit",
                    },
                )?;
                d.set_item("latency_secs", p.dynamics.latency_secs)?;
                d.set_item("constriction_tau_secs", p.dynamics.constriction_tau_secs)?;
                d.set_item("redilation_tau_secs", p.dynamics.redilation_tau_secs)?;
                d.set_item("range_scale", p.range.scale)?;
                d.set_item("range_offset_mm", p.range.offset_mm)?;
                if let ParamSource::Fit(f) = source {
                    d.set_item("fit_r_squared", f.r_squared)?;
                    d.set_item("fit_rms_mm", f.rms_mm)?;
                    d.set_item("fit_samples_used", f.samples_used)?;
                }
                Ok(d)
            })
            .collect()
    }

    /// Stops the render (frees the pipelines and closes the recording).
    fn close(&self) -> PyResult<()> {
        match self.state.try_lock() {
            Ok(mut g) => {
                *g = None;
                Ok(())
            }
            Err(std::sync::TryLockError::Poisoned(_)) => Ok(()),
            Err(std::sync::TryLockError::WouldBlock) => {
                Err(pyo3::exceptions::PyRuntimeError::new_err(
                    "this render is computing a frame in another thread",
                ))
            }
        }
    }
}

impl Running {
    fn step_count(&self) -> usize {
        match &self.step {
            Steps::Images(s) => s.frames_rendered(),
            Steps::Numbers(a) => a.frames_rendered(),
        }
    }
}

/// Whether `path` holds no samples the tracker can read in time order:
/// the CLI's scan, its errors in its words.
fn scan_recording(path: &Path, part: bool) -> PyResult<gazelight_render::feed::Scan> {
    scan(path, part).map_err(err)
}

/// Largest view side `render` accepts (`--size`), pixels.
const MAX_SIDE: usize = bounds::MAX_SIDE_PX;
/// Widest frame [`write_png`] encodes: a stereo frame is two views side by
/// side.
const MAX_FRAME_WIDTH: usize = 2 * MAX_SIDE;

/// `gazelight.render`'s native half; the Python wrapper picks `trace` or
/// `recording` and turns `warnings` into Python warnings. With
/// `check_only` (`gazelight.check_render`) it makes the checks that need
/// no file but the configuration (the CLI's `GAZELIGHT_PARSE_ONLY` ones:
/// the configuration, `fps`, `size`, `frames`, `from_secs`, `secs`, the
/// pupil light options) and returns `None`.
#[pyfunction]
#[pyo3(signature = (scene=None, trace=None, recording=None, *, size=None, stereo=false,
    config=None, config_name=None, fps=30.0, frames=None, retinal=false, calibration=None,
    from_secs=0.0, secs=None, yaw_deg=None, pitch_deg=None, hfov_deg=None,
    luminance_scale=None, pupil_fit=None, pupil_black_cd_m2=None, pupil_white_cd_m2=None,
    check_only=false, images=true, backend="auto", display_light=None, display_deg=None, display_cm=None,
    viewing_distance_cm=None))]
#[allow(clippy::too_many_arguments)]
pub(crate) fn render_open(
    py: Python<'_>,
    scene: Option<PathBuf>,
    trace: Option<PathBuf>,
    recording: Option<PathBuf>,
    size: Option<(usize, usize)>,
    stereo: bool,
    config: Option<&Bound<'_, PyAny>>,
    config_name: Option<String>,
    fps: f64,
    frames: Option<usize>,
    retinal: bool,
    calibration: Option<PathBuf>,
    from_secs: f64,
    secs: Option<f64>,
    yaw_deg: Option<f64>,
    pitch_deg: Option<f64>,
    hfov_deg: Option<f64>,
    luminance_scale: Option<f64>,
    pupil_fit: Option<String>,
    pupil_black_cd_m2: Option<f64>,
    pupil_white_cd_m2: Option<f64>,
    check_only: bool,
    images: bool,
    backend: &str,
    display_light: Option<PathBuf>,
    display_deg: Option<String>,
    display_cm: Option<String>,
    viewing_distance_cm: Option<f64>,
) -> PyResult<Option<Render>> {
    let name = config_name.unwrap_or_else(|| "<config>".to_owned());
    // A recording is `replay`'s (its keys, `source.calibration` too), a
    // trace `render`'s.
    let user = if recording.is_some() {
        ConfigUser::Replay
    } else {
        ConfigUser::Render
    };
    let mut settings = load_config(config, &name, user)?;
    let ignored = std::mem::take(&mut settings.ignored);
    let scene = scene.or_else(|| settings.scene_file.clone());
    let calibration = calibration.or_else(|| settings.calibration.clone());
    // The CLI's bounds, by construction (the application core's).
    bounds::fps("fps", fps).map_err(err)?;
    if trace.is_some() && recording.is_some() {
        return Err(err("give a trace or a recording, not both"));
    }
    if let Some(n) = frames {
        bounds::frames(&format!("frames={n}"), n).map_err(err)?;
    }
    // `replay`'s pupil light flags (checked before anything is read, as
    // the CLI does).
    if recording.is_none()
        && (pupil_fit.is_some() || pupil_black_cd_m2.is_some() || pupil_white_cd_m2.is_some())
    {
        return Err(err(
            "pupil_fit, pupil_black_cd_m2 and pupil_white_cd_m2 apply to a recording \
             (`gazelight replay`), not a trace",
        ));
    }
    if let Some(r) = &pupil_fit {
        pupil_light::parse_fit_range(r).map_err(err)?;
    }
    pupil_light::check_calibration_luminance("--pupil-black-cd-m2", pupil_black_cd_m2)
        .map_err(err)?;
    pupil_light::check_calibration_luminance("--pupil-white-cd-m2", pupil_white_cd_m2)
        .map_err(err)?;
    let (width, height) = size.or(settings.size).unwrap_or((720, 800));
    bounds::size(&format!("size=({width}, {height})"), width, height).map_err(err)?;
    if recording.is_some() {
        bounds::from_secs("from_secs", from_secs).map_err(err)?;
        if let Some(s) = secs {
            bounds::secs("secs", s).map_err(err)?;
        }
    }
    let display_geometry = display_geometry(
        recording.is_some(),
        display_light.is_some(),
        display_deg.as_deref(),
        display_cm.as_deref(),
        viewing_distance_cm,
    )?;
    if retinal && !images {
        return Err(err(
            "retinal=True asks for the retinal images; images=False makes none",
        ));
    }
    // The CLI's `--backend` values; the choice itself is made when the
    // pipelines are built (`gazelight_app::backend`, the CLI's rule).
    let backend: BackendChoice = backend
        .parse()
        .map_err(|e: BackendError| pyo3::exceptions::PyValueError::new_err(e.to_string()))?;
    // `check_render`: the checks above (the CLI's `GAZELIGHT_PARSE_ONLY`
    // ones), nothing opened.
    if check_only {
        return Ok(None);
    }
    let mut notes = Vec::new();
    py.detach(|| -> PyResult<Render> {
        // The observer: arguments none here; the configuration, else the
        // calibration profile's (replay), else the pipeline's defaults.
        let calibration = match &calibration {
            Some(p) => Some(crate::load_calibration(p)?),
            None => None,
        };
        let profile_observer = calibration.as_ref().map(|c| c.observer);
        gazelight_app::observer::apply(
            &mut settings.pipeline.glare.psf,
            &ObserverFlags::default(),
            Some(&settings.observer),
            profile_observer.as_ref(),
        )
        .map_err(err)?;
        // The scene.
        let scale = match luminance_scale {
            Some(factor) => LuminanceScale::CdM2PerUnit { factor },
            None => settings.luminance_scale.unwrap_or_default(),
        };
        scale
            .validate()
            .map_err(|e| err(format!("--luminance-scale: {e}")))?;
        let mut scene_img = match &scene {
            Some(p) => Scene::load(p, scale),
            None => Scene::from_bytes(demo::NIGHT_EXR, demo::name_path(), scale),
        }
        .map_err(err)?;
        // `scene.projection`/`scene.fov_deg`, the CLI's rule.
        if let Some(p) = settings.projection {
            let (w, h) = (scene_img.image.width, scene_img.image.height);
            scene_img.projection =
                Some(scene_projection(p, w, h).map_err(|e| err(crate::chain_msg(&e)))?);
        }
        // The shared bound on the scaled scene (as `render`'s): an overflow
        // would give all-black frames.
        scene_img.check_luminance().map_err(err)?;
        let base = demo::default_view(width, height);
        let view = ViewParams {
            yaw_deg: yaw_deg.or(settings.view.yaw_deg).unwrap_or(base.yaw_deg),
            pitch_deg: pitch_deg
                .or(settings.view.pitch_deg)
                .unwrap_or(base.pitch_deg),
            hfov_deg: hfov_deg.or(settings.view.hfov_deg).unwrap_or(base.hfov_deg),
            width,
            height,
        };
        let projection = PanoramaView::new(view).map_err(|e| err(format!("view: {e}")))?;
        let mut view_img = RgbImage::new(width, height);
        let no_data = projection.render_scene(&scene_img, &mut view_img);
        if no_data > 0 {
            notes.push(format!(
                "{no_data} of {} view pixels look outside the scene's field: no data \
                 (alpha 0 in frames, NaN in retinal images)",
                width * height
            ));
        }
        // The samples.
        let new_chain = || -> PyResult<FilterChain> {
            let mut chain = FilterChain::new(settings.filter, PupilCalibration::identity())
                .map_err(|e| err(format!("filter configuration: {e}")))?;
            if recording.is_some()
                && let Some(c) = &calibration
            {
                chain.set_calibration(c.clone());
            }
            Ok(chain)
        };
        let chain = new_chain()?;
        let mut span = None;
        let (samples, t0, duration): (Samples, f64, f64) = match &recording {
            Some(path) => {
                let found = scan_recording(path, secs.is_some())?;
                if calibration.is_none() && found.pupil_units.iter().any(|u| *u != PupilUnit::Mm) {
                    notes.push(format!(
                        "{}: pupil samples are not in millimetres and no calibration was given: \
                         the pupil falls back to the light-adaptation model",
                        path.display()
                    ));
                }
                let t0 = found.t_first + from_secs;
                if t0 > found.t_last {
                    return Err(err(format!(
                        "--from-secs {from_secs}: the recording is only {:.3} s long",
                        found.t_last - found.t_first
                    )));
                }
                let mut duration = found.t_last - t0;
                if let Some(s) = secs {
                    duration = duration.min(s);
                }
                span = Some((found.t_first, found.t_last));
                let samples = ImporterSamples::open(path).map_err(err)?;
                (Box::new(samples), t0, duration)
            }
            None => {
                let trace = match &trace {
                    Some(path) => GazeTrace::load(path).map_err(err)?,
                    None if scene.is_none() => demo::demo_trace(&view, &view_img).map_err(err)?,
                    None => demo::sweep_trace(),
                };
                let t0 = trace.samples.first().map_or(0.0, |s| s.t_secs);
                let duration = trace.duration_secs();
                let samples = trace
                    .samples
                    .into_iter()
                    .flat_map(|s| trace_source::expand(&s, s.t_secs));
                (Box::new(samples), t0, duration)
            }
        };
        let frames = match frames {
            Some(n) => n,
            None => bounds::frames(
                &format!("{duration:.1} s at fps={fps}"),
                ((duration * fps).floor() as usize).saturating_add(1),
            )
            .map_err(err)?,
        };
        let views = gazelight_render::frame::views(stereo);
        let step = if images {
            let pipeline_config = PipelineConfig {
                keep_retinal: retinal,
                ..settings.pipeline.clone()
            };
            // The CLI's renderer choice (`--backend`), named in its
            // messages as Python writes it (`backend="gpu"`).
            let pipelines =
                view_renderers(backend, Spelling::Keyword, &pipeline_config, &view, stereo)
                    .map_err(|e| err(crate::chain_msg(&e)))?;
            Steps::Images(Box::new(
                FrameStep::new(
                    pipelines,
                    stereo,
                    &settings.pipeline,
                    &view,
                    t0,
                    fps,
                    retinal,
                )
                .map_err(err)?,
            ))
        } else {
            Steps::Numbers(Box::new(
                AnalysisStep::new(stereo, &settings.pipeline, &view, &view_img, t0, fps)
                    .map_err(err)?,
            ))
        };
        let (backend_name, backend_reason) = match &step {
            Steps::Images(s) => s
                .pipelines()
                .first()
                .map(|r| (r.describe(), r.reason().to_owned()))
                .unzip(),
            Steps::Numbers(_) => (None, None),
        };
        let suffixes = views.iter().map(|v| v.suffix()).collect();
        let n_views = views.len();
        // A recording: `replay`'s pupil light response (its parameters
        // fitted first on a `pupil_fit` block: a pass of its own over it).
        let mut pupil_light_params = Vec::new();
        let pupil_light = match (&recording, span) {
            (Some(path), Some((t_first, t_last))) => {
                let mut plan = PupilLightPlan::new(
                    views,
                    &view_img,
                    &view,
                    &settings.pipeline,
                    &PupilLightOptions {
                        age_years: settings.pipeline.glare.psf.age_years,
                        calibration: calibration.as_ref(),
                        black_cd_m2: pupil_black_cd_m2,
                        white_cd_m2: pupil_white_cd_m2,
                        pupil_fit: pupil_fit.as_deref(),
                    },
                    t_last - t_first,
                )
                .map_err(err)?;
                // `display_light`: replay's --display-light, for the fit
                // block and the models alike.
                let display = match (&display_light, display_geometry) {
                    (Some(table), Some(geometry)) => {
                        Some(load_display(path, table, geometry, t_first, &mut notes)?)
                    }
                    _ => None,
                };
                if let Some(d) = &display {
                    plan.set_fit_display(d.clone());
                }
                if plan.fit_block_secs.is_some() {
                    let samples = ImporterSamples::open(path).map_err(err)?;
                    let mut fit_feed = SampleFeed::new(samples, new_chain()?);
                    plan.fit(&mut fit_feed, t_first, fps).map_err(err)?;
                }
                pupil_light_params = plan
                    .views
                    .iter()
                    .zip(plan.params.iter().zip(&plan.sources))
                    .map(|(v, (p, s))| (v.suffix(), *p, *s))
                    .collect();
                let mut plr = plan.start().map_err(err)?;
                if let Some(d) = display {
                    plr.set_display(d, t0 - t_first);
                }
                Some(plr)
            }
            _ => None,
        };
        Ok(Render {
            state: Mutex::new(Some(Box::new(Running {
                step,
                feed: if recording.is_some() {
                    SampleFeed::new(samples, chain)
                } else {
                    SampleFeed::new(samples, chain).hold_between_samples()
                },
                view_img,
                retinal,
                suffixes,
                pupil_light,
                t0_secs: t0,
            }))),
            frames,
            size: (width * n_views, height),
            fps,
            ignored,
            warnings: std::mem::take(&mut notes),
            backend: backend_name,
            backend_reason,
            pupil_light_params,
        })
    })
    .map(Some)
}

/// Writes an H×W×4 uint8 frame as a PNG with the CLI's encoder (the bytes
/// `gazelight render` writes for the same frame).
#[pyfunction]
pub(crate) fn write_png(
    py: Python<'_>,
    path: PathBuf,
    frame: numpy::PyReadonlyArray3<'_, u8>,
) -> PyResult<()> {
    let shape = frame.shape();
    let (height, width, channels) = (shape[0], shape[1], shape[2]);
    if channels != 4 {
        return Err(pyo3::exceptions::PyValueError::new_err(format!(
            "write_png: expected an H×W×4 uint8 frame (RGBA), got {height}×{width}×{channels}"
        )));
    }
    // The frame may be a view that holds far fewer bytes than its shape
    // says (`np.broadcast_to`, zero strides): check H·W·4 against the
    // largest frame `render` makes before copying it into a buffer.
    if height == 0 || width == 0 || height > MAX_SIDE || width > MAX_FRAME_WIDTH {
        return Err(pyo3::exceptions::PyValueError::new_err(format!(
            "write_png: a {height}×{width} frame: expected a height 1..={MAX_SIDE} and a width \
             1..={MAX_FRAME_WIDTH} (render's largest frame, stereo; at most {} bytes of RGBA)",
            MAX_SIDE * MAX_FRAME_WIDTH * 4
        )));
    }
    let bytes: Vec<u8> = frame.as_array().iter().copied().collect();
    py.detach(|| {
        gazelight_render::png::write_rgba8(&path, &bytes, width, height, PngCompression::Default)
    })
    .map_err(err)
}

/// `display_light=`'s geometry (`display_deg="WxH"`, or `display_cm="WxH"`
/// at `viewing_distance_cm`; default 40x30 degrees, as `replay`'s
/// `--display-deg`/`--display-cm`); `None` without a display light. Only
/// for a recording (the light drives its pupil light response).
fn display_geometry(
    recording: bool,
    display_light: bool,
    display_deg: Option<&str>,
    display_cm: Option<&str>,
    viewing_distance_cm: Option<f64>,
) -> PyResult<Option<DisplayGeometry>> {
    let given = display_deg.is_some() || display_cm.is_some() || viewing_distance_cm.is_some();
    if !display_light {
        if given {
            return Err(err(
                "display_deg, display_cm and viewing_distance_cm describe display_light's display: \
                 give display_light",
            ));
        }
        return Ok(None);
    }
    if !recording {
        return Err(err(
            "display_light drives a recording's pupil light response (`gazelight replay \
             --display-light`), not a trace's",
        ));
    }
    let geometry = match (display_deg, display_cm, viewing_distance_cm) {
        (Some(_), Some(_), _) => {
            return Err(err("give display_deg or display_cm, not both"));
        }
        (Some(d), None, None) => DisplayGeometry::parse_deg(d),
        (None, Some(c), Some(dist)) => DisplayGeometry::from_cm(c, dist),
        (None, Some(_), None) | (_, None, Some(_)) => {
            return Err(err(
                "display_cm and viewing_distance_cm go together (the display's size and the \
                 eye's distance from it)",
            ));
        }
        (None, None, None) => DisplayGeometry::parse_deg(DEFAULT_DISPLAY_DEG),
    };
    geometry.map(Some).map_err(err)
}

/// The display's angular size when none is given, degrees (`replay`'s).
const DEFAULT_DISPLAY_DEG: &str = "40x30";

/// The display light of `recording` from `table` (`t_secs,luminance_cd_m2`
/// or `event,luminance_cd_m2`, matched against the recording's events;
/// times from its first sample `t_first`).
fn load_display(
    recording: &std::path::Path,
    table: &std::path::Path,
    geometry: DisplayGeometry,
    t_first: f64,
    notes: &mut Vec<String>,
) -> PyResult<DisplayLight> {
    let events = gazelight_tracker::import::events::read(recording).unwrap_or_else(|e| {
        notes.push(format!("{}: events not read: {e}", recording.display()));
        gazelight_tracker::import::events::RecordingEvents::default()
    });
    let loaded = DisplayLightTable::load(table).map_err(err)?;
    DisplayLight::new(
        &loaded,
        geometry,
        events
            .events
            .iter()
            .map(|e| (e.t_secs - t_first, e.text.as_str())),
        &table.display().to_string(),
    )
    .map_err(err)
}
