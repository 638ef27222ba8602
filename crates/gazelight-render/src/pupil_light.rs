//! The pupil light response of a replay: per view, the pupil the light
//! predicts (`pupil_light_mm`) and what is left of the measured pupil
//! (`pupil_residual_mm`), with the model of
//! [`gazelight_tracker::pupil_response`] (docs/pupil-light-response.md).
//! `gazelight replay` and the Python package's `gazelight.render` of a
//! recording both run it through [`PupilLightPlan`] and
//! [`PupilLight::apply`], so their columns are the same numbers; the CLI's
//! live frame loop (`gazelight run`) steps a [`PupilLight`] with the field
//! of the view its head turns to.
//!
//! What each eye sees, every frame:
//!
//! * **Luminance at the gaze**: the pipeline's pooled luminance of that
//!   eye's view (`FrameStats::target_cd_m2`, the same value as the
//!   `target_cd_m2` column: the configured pooling model over the
//!   block-mean luminance plane, at the gaze clamped onto the view).
//! * **Field mean luminance and field area**: a replay's head does not
//!   move, so each eye sees the same panorama view for the whole replay
//!   (both eyes of a stereo replay see the same view of a panorama at
//!   infinity, see [`crate::frame`]). Its mean luminance (the view's
//!   luminance, `Y = 0.2126 R + 0.7152 G + 0.0722 B`, in cd/m², each pixel
//!   weighted by its solid angle: [`field_mean_cd_m2`]) and the view's
//!   solid angle (the exact solid angle of the rectilinear view, in deg²)
//!   are computed once, before the first frame, so the per-frame cost is a
//!   few multiplications.
//!
//! Both eyes' light drives both pupils (the consensual response); each
//! view has its own [`PupilLightResponse`] (its own observer range), all
//! fed the same [`EyeLight`]. A mono replay's one view stands for both
//! eyes (`EyeLight::both`); a stereo replay's views are the left and the
//! right eye. Stepping allocates nothing.
//!
//! Each view's parameters ([`PupilLightPlan`]): W&Y with the observer's
//! age; with a calibration profile, its black/white pupils mapped onto the
//! model's range (at the display's black and white luminances of the
//! calibration); with `--pupil-fit FROM..TO` (Python: `pupil_fit=`), the
//! observer fitted on a baseline block first: a pass over the block with
//! the same filter chain and the same light (the pooling model evaluated on
//! the view's block-mean plane, as the pipeline does, without rendering),
//! then [`fit_observer`].
//!
//! The error messages are the CLI's (its flags' names): the CLI prints
//! them after `error: `, the Python package raises them.

use gazelight_tracker::profile::{EyeCalibration, PupilCalibration};
use gazelight_tracker::pupil_response::{
    Adaptation, DEFAULT_GAZE_WEIGHT, Dynamics, EyeInput, EyeLight, FitOptions, FitResult,
    ObserverRange, PupilLightResponse, PupilRow, ResponseError, ResponseParams, fit_observer,
    residual_mm,
};
use gazelight_tracker::{EYE_LEFT, EYE_RIGHT, EyeState, PupilOrigin, PupilUnit, Sample};
use gazelight_vision::RgbImage;
use gazelight_vision::image::luminance;
use gazelight_vision::pipeline::{FrameInput, FrameStats, PipelineConfig};
use gazelight_vision::pooling::{PlaneAngles, PoolingModel};
use gazelight_vision::scene::ViewParams;

use crate::display_light::DisplayLight;
use crate::feed::SampleFeed;
use crate::frame::View;
use crate::timeline::TimelineRow;

/// The display's black during the calibration's black phase, cd/m²,
/// unless `--pupil-black-cd-m2` says otherwise (an assumption: an LCD
/// headset's black; the profile does not record it).
pub const DEFAULT_CALIBRATION_BLACK_CD_M2: f64 = 0.1;
/// The display's white during the calibration's white phase, cd/m², unless
/// `--pupil-white-cd-m2` says otherwise (000 §3.3: headset luminance
/// 100 cd/m², the tone mapper's default display peak).
pub const DEFAULT_CALIBRATION_WHITE_CD_M2: f64 = 100.0;

/// What can go wrong in setting up the pupil light response. The messages
/// are the CLI's; none carries a `source()` (each says its cause itself,
/// so `error: {e:#}` prints it once).
#[derive(Debug, thiserror::Error)]
pub enum PupilLightError {
    /// Not 1 or 2 views, or not one set of parameters per view.
    #[error("pupil light response: 1 or 2 views, one set of parameters each")]
    Views,
    /// A view's parameters are out of the model's range.
    #[error("pupil light response: {0}")]
    Model(ResponseError),
    /// A flag's value (`--pupil-fit`, `--pupil-black-cd-m2`,
    /// `--pupil-white-cd-m2`): the message names the flag, its value and
    /// what was expected.
    #[error("{0}")]
    Flag(String),
    /// The calibration profile's pupils cannot be mapped onto the model.
    #[error(
        "the calibration profile's pupils cannot be mapped onto the pupil light model \
         (--pupil-black-cd-m2 {black_cd_m2}, --pupil-white-cd-m2 {white_cd_m2}): {reason}"
    )]
    Calibration {
        black_cd_m2: f64,
        white_cd_m2: f64,
        reason: ResponseError,
    },
    /// The fit on the `--pupil-fit` block failed for a view.
    #[error(
        "{flag}: cannot fit the observer on this block{which} ({frames} frames at {fps} fps): {reason}"
    )]
    Fit {
        /// `--pupil-fit FROM..TO` as given.
        flag: String,
        /// `" (left eye)"`, `" (right eye)"` or `""` (a mono view).
        which: String,
        frames: usize,
        fps: f64,
        reason: ResponseError,
    },
}

/// The field an eye sees besides its gaze: the view's mean luminance and
/// its solid angle.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct FieldLight {
    /// Mean of the view's luminance, cd/m².
    pub field_mean_cd_m2: f64,
    /// Solid angle of the view, deg².
    pub field_area_deg2: f64,
}

impl FieldLight {
    /// What an eye looking at `gaze_cd_m2` in this field sees.
    pub fn input(&self, gaze_cd_m2: f64) -> EyeInput {
        EyeInput {
            gaze_luminance_cd_m2: gaze_cd_m2,
            field_mean_luminance_cd_m2: self.field_mean_cd_m2,
            field_area_deg2: self.field_area_deg2,
            lit: true,
        }
    }

    /// Both eyes' light from each view's pooled luminance.
    pub fn light(&self, views: &[View], gaze_cd_m2: &[f64]) -> EyeLight {
        let mut light = EyeLight::both(self.input(gaze_cd_m2.first().copied().unwrap_or(0.0)));
        for (v, &l) in views.iter().zip(gaze_cd_m2) {
            match *v {
                View::Both => light = EyeLight::both(self.input(l)),
                View::Eye(e) => light.eyes[e.min(1)] = self.input(l),
            }
        }
        light
    }
}

/// The light a static view offers: its field, and the block-mean
/// luminance plane the pooling model reads.
pub struct SceneLight {
    pub field: FieldLight,
    pooling: PoolingModel,
    small_lum: Vec<f32>,
    /// Each block's share of pixels with data (as the pipeline's pass A).
    small_valid: Vec<f32>,
    small_w: usize,
    small_h: usize,
    ds: usize,
    width: usize,
    height: usize,
    /// The block plane's geometry: the view's projection, as the
    /// pipeline pools through it.
    small_angles: PlaneAngles,
}

impl SceneLight {
    /// From the rendered view (`view_img`, cd/m²) and the pipeline's
    /// pooling settings.
    pub fn new(view_img: &RgbImage, view: &ViewParams, pipeline: &PipelineConfig) -> Self {
        let (w, h) = (view_img.width, view_img.height);
        let ds = pipeline.pooling_downsample.unwrap_or(8).max(1);
        let (small_w, small_h) = (w.div_ceil(ds), h.div_ceil(ds));
        let mut sums = vec![0.0f64; small_w * small_h];
        let mut counts = vec![0u32; small_w * small_h];
        let mut valid = vec![0u32; small_w * small_h];
        for (y, row) in view_img.pixels.chunks_exact(w.max(1)).enumerate() {
            for (x, p) in row.iter().enumerate() {
                let i = (y / ds) * small_w + x / ds;
                counts[i] += 1;
                // No data (outside the scene's field): neither light nor area.
                if gazelight_vision::image::is_no_data(*p) {
                    continue;
                }
                let l = f64::from(luminance(
                    p.map(|c| if c.is_finite() { c.max(0.0) } else { 0.0 }),
                ));
                sums[i] += l;
                valid[i] += 1;
            }
        }
        let small_valid = valid
            .iter()
            .zip(&counts)
            .map(|(&a, &n)| if n > 0 { a as f32 / n as f32 } else { 0.0 })
            .collect();
        let small_lum = sums
            .iter()
            .zip(&counts)
            .map(|(s, &n)| {
                if n > 0 {
                    (s / f64::from(n)) as f32
                } else {
                    0.0
                }
            })
            .collect();
        let tans = match PlaneAngles::symmetric(view.hfov_deg, w, h) {
            PlaneAngles::Rectilinear { tan_lrud, .. } => tan_lrud,
            PlaneAngles::Uniform { .. } => [-1.0, 1.0, 1.0, -1.0],
        };
        Self {
            field: FieldLight {
                field_mean_cd_m2: field_mean_cd_m2(view_img, tans, 1),
                field_area_deg2: view_solid_angle_deg2(view),
            },
            pooling: pipeline.pooling,
            small_lum,
            small_valid,
            small_w,
            small_h,
            ds,
            width: w,
            height: h,
            small_angles: PlaneAngles::symmetric(view.hfov_deg, w, h).downsampled(ds),
        }
    }

    /// The pooled luminance at `gaze_uv` (clamped onto the view, as the
    /// pipeline does), cd/m²; pixels without data are left out (0 where
    /// the pooling reaches none).
    pub fn pooled_at(&self, gaze_uv: [f32; 2]) -> f64 {
        let c = |v: f32| {
            if v.is_finite() {
                v.clamp(0.0, 1.0)
            } else {
                0.5
            }
        };
        let gaze_px = [
            f64::from(c(gaze_uv[0])) * self.width as f64 / self.ds as f64,
            f64::from(c(gaze_uv[1])) * self.height as f64 / self.ds as f64,
        ];
        self.pooling
            .pool_valid_in(
                &self.small_lum,
                &self.small_valid,
                self.small_w,
                self.small_h,
                gaze_px,
                self.small_angles,
            )
            .unwrap_or(0.0)
            .max(0.0)
    }
}

/// The mean luminance of a rectilinear view's image over its solid angle,
/// cd/m²: `Σ L·ω / Σ ω` with each pixel's solid angle `ω ∝ (1 + s_x² +
/// s_y²)^{−3/2}` (`s` its tangent coordinates, the view's edges at
/// `tan_lrud`: left, right, up, down), over every `step`-th pixel of every
/// `step`-th row; negative and infinite pixels count as 0, pixels without
/// data (NaN: outside the scene's field, [`gazelight_vision::image::is_no_data`])
/// are left out of both sums. (A plain mean of the pixels would weigh the
/// corners of a 90° view 4× too much.) NaN for an empty image or one with
/// no data at all.
pub fn field_mean_cd_m2(img: &RgbImage, tan_lrud: [f64; 4], step: usize) -> f64 {
    let (w, h) = (img.width, img.height);
    if w == 0 || h == 0 || img.pixels.len() != w * h {
        return f64::NAN;
    }
    let step = step.max(1);
    let [l, r, u, d] = tan_lrud;
    let (mut sum, mut weight) = (0.0f64, 0.0f64);
    for y in (0..h).step_by(step) {
        let sy = u - (y as f64 + 0.5) / h as f64 * (u - d);
        let row = &img.pixels[y * w..(y + 1) * w];
        for x in (0..w).step_by(step) {
            let sx = l + (x as f64 + 0.5) / w as f64 * (r - l);
            if gazelight_vision::image::is_no_data(row[x]) {
                continue;
            }
            let omega = (1.0 + sx * sx + sy * sy).powf(-1.5);
            let lum = f64::from(luminance(
                row[x].map(|c| if c.is_finite() { c.max(0.0) } else { 0.0 }),
            ));
            sum += omega * lum;
            weight += omega;
        }
    }
    if weight > 0.0 { sum / weight } else { f64::NAN }
}

/// The solid angle of a rectilinear view, deg²: `4·asin(sin α · sin β)` sr
/// with α, β the half-angles of its horizontal and vertical field.
pub fn view_solid_angle_deg2(view: &ViewParams) -> f64 {
    let half_h = (view.hfov_deg.to_radians() * 0.5).clamp(0.0, std::f64::consts::FRAC_PI_2);
    let aspect = view.height as f64 / (view.width.max(1)) as f64;
    let half_v = (half_h.tan() * aspect).atan();
    let sr = 4.0 * (half_h.sin() * half_v.sin()).asin();
    sr * (180.0 / std::f64::consts::PI).powi(2)
}

/// The pupil a view's residual is taken from, mm: its measured pupil where
/// that is in mm (the tracker's mm, or raw × a physical scale); where the
/// pupil is measured only in raw units, that measurement through the
/// profile's black/white map (001 §5; `pupil_map_mm`) — a residual in the
/// map's millimetres, which `session.json` names ([`ResidualBasis`]);
/// `None` where nothing is measured (a blink and its margins, lost, a
/// speed outlier, before the first measurement).
pub fn residual_pupil_mm(view: View, state: &EyeState) -> Option<f32> {
    let p = view.pupil(state);
    match p.measured {
        Some((v, PupilUnit::Mm)) => Some(v),
        Some(_) => p.map_mm,
        None => None,
    }
}

/// What the residual column is taken from, for `session.json`.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum ResidualBasis {
    /// The measured pupil in mm.
    MeasuredMm,
    /// 001 §5's black/white map of a pupil measured in raw units (no
    /// physical scale): the model aperture's millimetres.
    ApertureMap,
}

impl ResidualBasis {
    /// The basis of a recording whose pupils are in `units`: the measured
    /// mm when any is in mm, else the aperture map.
    pub fn of(units: &[PupilUnit]) -> Self {
        if units.is_empty() || units.contains(&PupilUnit::Mm) {
            Self::MeasuredMm
        } else {
            Self::ApertureMap
        }
    }

    /// Its description in `session.json`.
    pub fn describe(self) -> &'static str {
        match self {
            Self::MeasuredMm => {
                "measured pupil in mm (the tracker's mm, or raw × a physical scale)"
            }
            Self::ApertureMap => {
                "no physical scale: the model aperture of 001 §5's black/white map (the profile's \
                 millimetres, not a measurement in mm)"
            }
        }
    }
}

/// Whether the pupil a view uses this frame is a measurement (not held
/// over a blink or dropout, not the model's fill-in, not the default):
/// the eyes whose value the view's pupil is made of must all be measured.
pub fn view_measured(view: View, state: &EyeState) -> bool {
    // A pupil still settling towards its measurement (after a blink or a
    // dropout, at the start) is not the measurement yet.
    let origin = |e: usize| {
        let c = &state.eyes[e];
        if c.settling && c.pupil_origin == PupilOrigin::Measured {
            PupilOrigin::Held
        } else {
            c.pupil_origin
        }
    };
    let used = |o: PupilOrigin| matches!(o, PupilOrigin::Measured | PupilOrigin::Held);
    match view {
        View::Both => {
            let contributing = [EYE_RIGHT, EYE_LEFT]
                .into_iter()
                .filter(|&e| used(origin(e)));
            let mut any = false;
            for e in contributing {
                if origin(e) != PupilOrigin::Measured {
                    return false;
                }
                any = true;
            }
            any
        }
        View::Eye(e) => {
            let e = e.min(1);
            match origin(e) {
                PupilOrigin::Measured => true,
                PupilOrigin::Held => false,
                // The view falls back to the other eye's pupil.
                _ => origin(1 - e) == PupilOrigin::Measured,
            }
        }
    }
}

/// Where a view's parameters came from.
#[derive(Clone, Copy, Debug, PartialEq)]
pub enum ParamSource {
    /// W&Y's formula as it is, with the observer's age.
    Default,
    /// The black/white calibration profile.
    Profile,
    /// `--pupil-fit` on a baseline block.
    Fit(FitResult),
}

/// The per-view models of a replay.
pub struct PupilLight {
    views: [View; 2],
    n_views: usize,
    models: [Option<PupilLightResponse>; 2],
    field: FieldLight,
    /// The display's light instead of the field's (`--display-light`),
    /// and the seconds from the recording's first sample to `t_secs` 0.
    display: Option<(DisplayLight, f64)>,
    /// Per view: sums for the spreads of the raw pupil and the residual
    /// over frames where both are defined.
    spread: [Spread; 2],
}

/// Running sums of two series over the same frames.
#[derive(Clone, Copy, Debug, Default)]
struct Spread {
    n: u64,
    raw: [f64; 2],
    residual: [f64; 2],
}

impl Spread {
    fn add(&mut self, raw: f64, residual: f64) {
        self.n += 1;
        self.raw[0] += raw;
        self.raw[1] += raw * raw;
        self.residual[0] += residual;
        self.residual[1] += residual * residual;
    }

    fn sd(n: u64, s: [f64; 2]) -> f64 {
        if n < 2 {
            return f64::NAN;
        }
        let n = n as f64;
        ((s[1] - s[0] * s[0] / n) / (n - 1.0)).max(0.0).sqrt()
    }
}

/// One view's spreads (for the summary).
pub struct ViewSpread {
    pub suffix: &'static str,
    pub frames: u64,
    pub raw_sd_mm: f64,
    pub residual_sd_mm: f64,
}

impl PupilLight {
    /// Models for `views` (1 or 2) with each view's parameters.
    pub fn new(
        views: &[View],
        params: &[ResponseParams],
        field: FieldLight,
    ) -> Result<Self, PupilLightError> {
        if views.is_empty() || views.len() > 2 || params.len() != views.len() {
            return Err(PupilLightError::Views);
        }
        let mut models = [None, None];
        for (m, p) in models.iter_mut().zip(params) {
            *m = Some(PupilLightResponse::new(*p).map_err(PupilLightError::Model)?);
        }
        Ok(Self {
            views: [views[0], views.get(1).copied().unwrap_or(views[0])],
            n_views: views.len(),
            models,
            field,
            display: None,
            spread: [Spread::default(); 2],
        })
    }

    /// One frame: each view's pooled luminance (`FrameStats::target_cd_m2`)
    /// and its pupil (mm, and whether it is measured) in; each view's
    /// (`pupil_light_mm`, `pupil_residual_mm`) out, the residual NaN where
    /// the pupil is not measured. Allocates nothing.
    pub fn step(
        &mut self,
        t_secs: f64,
        gaze_cd_m2: [f64; 2],
        pupils: [(f32, bool); 2],
    ) -> [(f32, f32); 2] {
        let n = self.n_views;
        let light = match &self.display {
            Some((d, offset_secs)) => {
                let input = d.input_at(t_secs + offset_secs);
                let field = FieldLight {
                    field_mean_cd_m2: input.field_mean_luminance_cd_m2,
                    field_area_deg2: input.field_area_deg2,
                };
                let gaze = [input.gaze_luminance_cd_m2; 2];
                field.light(&self.views[..n], &gaze[..n])
            }
            None => self.field.light(&self.views[..n], &gaze_cd_m2[..n]),
        };
        let mut out = [(f32::NAN, f32::NAN); 2];
        for k in 0..n {
            let Some(model) = self.models[k].as_mut() else {
                continue;
            };
            let predicted = model.step(t_secs, &light);
            let (pupil, measured) = pupils[k];
            let residual = if measured {
                residual_mm(f64::from(pupil), predicted)
            } else {
                f64::NAN
            };
            if residual.is_finite() {
                self.spread[k].add(f64::from(pupil), residual);
            }
            out[k] = (predicted as f32, residual as f32);
        }
        out
    }

    /// One rendered frame of a replay ([`crate::frame::Step`]'s parts):
    /// each view's pupil (`inputs`, measured or not by `state`) and pooled
    /// luminance (its row's `target_cd_m2`) through [`Self::step`] at
    /// `t_secs` (from the replay's first frame); each view's row gets its
    /// `pupil_light_mm` and `pupil_residual_mm`. `inputs` and `rows` are in
    /// the order of the views this was made for. Allocates nothing.
    pub fn apply(
        &mut self,
        t_secs: f64,
        state: &EyeState,
        inputs: &[(FrameInput, bool)],
        rows: &mut [TimelineRow],
    ) {
        let mut pupils = [(f32::NAN, false); 2];
        for (p, (_, v)) in pupils
            .iter_mut()
            .zip(inputs.iter().zip(&self.views[..self.n_views]))
        {
            let pupil = residual_pupil_mm(*v, state);
            *p = (pupil.unwrap_or(f32::NAN), pupil.is_some());
        }
        let default = FrameStats::default();
        let target = |k: usize| {
            rows.get(k)
                .map_or(default.target_cd_m2, |r| r.stats.target_cd_m2)
        };
        let light = self.step(t_secs, [target(0), target(1)], pupils);
        for (row, (predicted, residual)) in rows.iter_mut().zip(light) {
            row.pupil_light_mm = predicted;
            row.pupil_residual_mm = residual;
        }
    }

    /// Drives the models with the display's light (`--display-light`)
    /// instead of the view's: each frame's `t_secs` + `offset_secs` is
    /// the time from the recording's first sample.
    pub fn set_display(&mut self, display: DisplayLight, offset_secs: f64) {
        self.display = Some((display, offset_secs));
    }

    /// A new field (the view moved: a head turn), from the next frame on.
    pub fn set_field(&mut self, field: FieldLight) {
        self.field = field;
    }

    /// The spread (SD) of the raw pupil and of the residual per view, over
    /// the frames with a measured pupil.
    pub fn spreads(&self) -> Vec<ViewSpread> {
        (0..self.n_views)
            .map(|k| {
                let s = &self.spread[k];
                ViewSpread {
                    suffix: self.views[k].suffix(),
                    frames: s.n,
                    raw_sd_mm: Spread::sd(s.n, s.raw),
                    residual_sd_mm: Spread::sd(s.n, s.residual),
                }
            })
            .collect()
    }
}

/// The adaptation (gaze weight, the observer's age) every view uses.
pub fn adaptation(age_years: f64) -> Adaptation {
    Adaptation {
        gaze_weight: DEFAULT_GAZE_WEIGHT,
        age_years,
    }
}

/// Default dynamics and the range given.
pub fn params(age_years: f64, range: ObserverRange) -> ResponseParams {
    ResponseParams {
        adaptation: adaptation(age_years),
        dynamics: Dynamics::default(),
        range,
    }
}

/// Parses `--pupil-fit FROM..TO` (seconds, `0 ≤ FROM < TO`, finite).
pub fn parse_fit_range(s: &str) -> Result<(f64, f64), PupilLightError> {
    let bad = |why: &str| PupilLightError::Flag(format!("--pupil-fit {s}: {why}"));
    let (a, b) = s
        .split_once("..")
        .ok_or_else(|| bad("expected FROM..TO in seconds of the recording, e.g. 10..40"))?;
    let num = |v: &str| -> Result<f64, PupilLightError> {
        v.trim()
            .parse::<f64>()
            .map_err(|_| bad(&format!("`{v}` is not a number of seconds")))
    };
    let (a, b) = (num(a)?, num(b)?);
    if !(a.is_finite() && b.is_finite() && a >= 0.0) {
        return Err(bad("FROM and TO must be finite and FROM ≥ 0"));
    }
    if b <= a {
        return Err(bad("TO must be after FROM"));
    }
    Ok((a, b))
}

/// Checks a calibration display luminance (`flag`: `--pupil-black-cd-m2`
/// or `--pupil-white-cd-m2`): finite and ≥ 0 cd/m².
pub fn check_calibration_luminance(flag: &str, v: Option<f64>) -> Result<(), PupilLightError> {
    match v {
        Some(v) if !(v.is_finite() && v >= 0.0) => Err(PupilLightError::Flag(format!(
            "{flag} {v}: expected a luminance ≥ 0 in cd/m²"
        ))),
        _ => Ok(()),
    }
}

/// `" (left eye)"`, `" (right eye)"` or `""` for a mono view.
pub fn which_eye(v: View) -> String {
    match v.suffix() {
        "" => String::new(),
        s => format!(" ({} eye)", s.trim_start_matches('_')),
    }
}

/// The first pass of `--pupil-fit`: frames at `fps` over the block
/// `t_from..t_to` (recording clock) through `feed`, each view's pupil
/// (NaN unless measured) and the light at its gaze — the scene's, or with
/// `display` (`--display-light` and the recording's first sample on its
/// clock) the display's then, as the replay's models get it; then one fit
/// per view, started from `initial[k]`. `flag` (`--pupil-fit FROM..TO`)
/// names the block in the error.
#[allow(clippy::too_many_arguments)]
pub fn fit_block<I: Iterator<Item = Sample>>(
    feed: &mut SampleFeed<I>,
    views: &[View],
    scene: &SceneLight,
    display: Option<(&DisplayLight, f64)>,
    (t_from, t_to): (f64, f64),
    fps: f64,
    initial: &[ResponseParams],
    flag: &str,
) -> Result<Vec<FitResult>, PupilLightError> {
    let dt = 1.0 / fps;
    let frames = ((t_to - t_from) * fps).floor() as usize + 1;
    let mut rows: Vec<Vec<PupilRow>> = views.iter().map(|_| Vec::with_capacity(frames)).collect();
    let mut gaze_cd_m2 = [0.0f64; 2];
    for i in 0..frames {
        let t = t_from + i as f64 * dt;
        let state = feed.state(t, None);
        for (k, v) in views.iter().enumerate() {
            let (input, _) = v.input(&state, 0.0);
            gaze_cd_m2[k] = scene.pooled_at(input.gaze_uv);
        }
        let light = match display {
            Some((d, t_first)) => {
                let input = d.input_at(t - t_first);
                let field = FieldLight {
                    field_mean_cd_m2: input.field_mean_luminance_cd_m2,
                    field_area_deg2: input.field_area_deg2,
                };
                field.light(views, &[input.gaze_luminance_cd_m2; 2][..views.len()])
            }
            None => scene.field.light(views, &gaze_cd_m2[..views.len()]),
        };
        for (k, v) in views.iter().enumerate() {
            let pupil = residual_pupil_mm(*v, &state).map_or(f64::NAN, f64::from);
            rows[k].push(PupilRow {
                t_secs: t - t_from,
                pupil_mm: pupil,
                light,
            });
        }
    }
    let options = FitOptions::default();
    views
        .iter()
        .zip(&rows)
        .zip(initial)
        .map(|((v, rows), init)| {
            fit_observer(rows, init, &options).map_err(|reason| PupilLightError::Fit {
                flag: flag.to_owned(),
                which: which_eye(*v),
                frames: rows.len(),
                fps,
                reason,
            })
        })
        .collect()
}

/// What decides a replay's pupil light parameters besides the view.
#[derive(Clone, Copy, Debug)]
pub struct PupilLightOptions<'a> {
    /// The observer's age (the PSF's, after the flags, the configuration
    /// and the profile), years.
    pub age_years: f64,
    /// The calibration profile (`--calibration`): each view's range.
    pub calibration: Option<&'a PupilCalibration>,
    /// `--pupil-black-cd-m2` (default [`DEFAULT_CALIBRATION_BLACK_CD_M2`]).
    pub black_cd_m2: Option<f64>,
    /// `--pupil-white-cd-m2` (default [`DEFAULT_CALIBRATION_WHITE_CD_M2`]).
    pub white_cd_m2: Option<f64>,
    /// `--pupil-fit FROM..TO` as given (seconds from the first sample).
    pub pupil_fit: Option<&'a str>,
}

/// A replay's pupil light response before its first frame: the light of
/// its view, and each view's parameters and where they came from. Made by
/// [`Self::new`]; with a fit block, [`Self::fit`] (a first pass over the
/// block) replaces the parameters; [`Self::start`] gives the models.
pub struct PupilLightPlan {
    /// The views (1 or 2), in display order.
    pub views: &'static [View],
    /// The light of the (static) view.
    pub scene: SceneLight,
    /// Each view's parameters.
    pub params: Vec<ResponseParams>,
    /// Where each view's parameters came from.
    pub sources: Vec<ParamSource>,
    /// The calibration's black and white display luminances, cd/m² (the
    /// flags' or the defaults).
    pub black_cd_m2: f64,
    pub white_cd_m2: f64,
    /// The `--pupil-fit` block, seconds from the recording's first sample,
    /// its end clamped to the recording's length; `None` without a fit.
    pub fit_block_secs: Option<[f64; 2]>,
    /// `--pupil-fit FROM..TO` as given (for the fit's error).
    fit_flag: String,
    /// The display's light the fit block sees (`--display-light`), in
    /// place of the scene's.
    fit_display: Option<DisplayLight>,
}

impl PupilLightPlan {
    /// Each view's parameters for the view `view_img` (cd/m², rendered for
    /// `view`) under `pipeline`'s pooling: the calibration profile's range
    /// where there is one (the eye's own map; the mean of both for a mono
    /// view), else W&Y with the observer's age. A fit block is checked
    /// against the recording's length (`recording_secs`, first to last
    /// sample) but not fitted yet.
    pub fn new(
        views: &'static [View],
        view_img: &RgbImage,
        view: &ViewParams,
        pipeline: &PipelineConfig,
        options: &PupilLightOptions<'_>,
        recording_secs: f64,
    ) -> Result<Self, PupilLightError> {
        check_calibration_luminance("--pupil-black-cd-m2", options.black_cd_m2)?;
        check_calibration_luminance("--pupil-white-cd-m2", options.white_cd_m2)?;
        let scene = SceneLight::new(view_img, view, pipeline);
        let age = options.age_years;
        let black = options
            .black_cd_m2
            .unwrap_or(DEFAULT_CALIBRATION_BLACK_CD_M2);
        let white = options
            .white_cd_m2
            .unwrap_or(DEFAULT_CALIBRATION_WHITE_CD_M2);
        let eye_cal = |v: View| -> Option<EyeCalibration> {
            let eyes = &options.calibration?.eyes;
            let (r, l) = (eyes.right, eyes.left);
            match v {
                View::Eye(EYE_RIGHT) => r.or(l),
                View::Eye(_) => l.or(r),
                View::Both => match (r, l) {
                    (Some(a), Some(b)) => Some(EyeCalibration {
                        mm_min: 0.5 * (a.mm_min + b.mm_min),
                        mm_max: 0.5 * (a.mm_max + b.mm_max),
                        ..a
                    }),
                    (a, b) => a.or(b),
                },
            }
        };
        let mut params_out = Vec::with_capacity(views.len());
        let mut sources = Vec::with_capacity(views.len());
        for v in views {
            let (range, source) = match eye_cal(*v) {
                Some(c) => (
                    ObserverRange::from_calibration(
                        &c,
                        black,
                        white,
                        scene.field.field_area_deg2,
                        age,
                    )
                    .map_err(|reason| PupilLightError::Calibration {
                        black_cd_m2: black,
                        white_cd_m2: white,
                        reason,
                    })?,
                    ParamSource::Profile,
                ),
                None => (ObserverRange::IDENTITY, ParamSource::Default),
            };
            params_out.push(params(age, range));
            sources.push(source);
        }
        let mut fit_block_secs = None;
        let mut fit_flag = String::new();
        if let Some(range) = options.pupil_fit {
            let (from, to) = parse_fit_range(range)?;
            let length = recording_secs;
            if from >= length {
                return Err(PupilLightError::Flag(format!(
                    "--pupil-fit {range}: the block starts after the recording's end ({length:.3} s)"
                )));
            }
            fit_block_secs = Some([from, to.min(length)]);
            fit_flag = format!("--pupil-fit {range}");
        }
        Ok(Self {
            views,
            scene,
            params: params_out,
            sources,
            black_cd_m2: black,
            white_cd_m2: white,
            fit_block_secs,
            fit_flag,
            fit_display: None,
        })
    }

    /// The fit block sees the display's light (`--display-light`, times
    /// from the recording's first sample), as the replay's models will.
    pub fn set_fit_display(&mut self, display: DisplayLight) {
        self.fit_display = Some(display);
    }

    /// With a fit block: fits each view's observer on it (frames at `fps`
    /// through `feed`, a fresh feed of the recording whose first sample is
    /// at `t_first_secs`) and takes the fitted parameters; returns the
    /// fits (none without a block).
    pub fn fit<I: Iterator<Item = Sample>>(
        &mut self,
        feed: &mut SampleFeed<I>,
        t_first_secs: f64,
        fps: f64,
    ) -> Result<Vec<FitResult>, PupilLightError> {
        let Some([from, to]) = self.fit_block_secs else {
            return Ok(Vec::new());
        };
        let fits = fit_block(
            feed,
            self.views,
            &self.scene,
            self.fit_display.as_ref().map(|d| (d, t_first_secs)),
            (t_first_secs + from, t_first_secs + to),
            fps,
            &self.params,
            &self.fit_flag,
        )?;
        for (fit, (p, s)) in fits
            .iter()
            .zip(self.params.iter_mut().zip(self.sources.iter_mut()))
        {
            *p = fit.params;
            *s = ParamSource::Fit(*fit);
        }
        Ok(fits)
    }

    /// The models, one per view, for the whole replay.
    pub fn start(&self) -> Result<PupilLight, PupilLightError> {
        PupilLight::new(self.views, &self.params, self.scene.field)
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    /// Pixels without data (NaN: outside the scene's field) are left out
    /// of the field mean and of the pooled light, not read as black: a
    /// 90° view whose right 40 % has no data and whose rest is 50 cd/m²
    /// has the field mean 50 and pools 50 at a gaze beside the edge (read
    /// as black they would give about 50 · 0.62 and 25).
    #[test]
    fn no_data_is_left_out_of_the_field_light() {
        let view = ViewParams {
            yaw_deg: 0.0,
            pitch_deg: 0.0,
            hfov_deg: 90.0,
            width: 100,
            height: 80,
        };
        let mut img = RgbImage::new(100, 80);
        for (i, p) in img.pixels.iter_mut().enumerate() {
            *p = if i % 100 >= 60 {
                gazelight_vision::scene::NO_DATA_RGB
            } else {
                [50.0; 3]
            };
        }
        let tans = [-1.0, 1.0, 0.8, -0.8];
        let mean = field_mean_cd_m2(&img, tans, 1);
        assert!((mean - 50.0).abs() < 1e-9, "field mean {mean}");
        let light = SceneLight::new(&img, &view, &PipelineConfig::default());
        assert!((light.field.field_mean_cd_m2 - 50.0).abs() < 1e-9);
        let pooled = light.pooled_at([0.6, 0.5]);
        assert!((pooled - 50.0).abs() < 1e-4, "pooled {pooled}");
    }
}
