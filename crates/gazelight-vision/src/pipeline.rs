//! The frame pipeline on the CPU: an HDR frame in cd/m², the eye's state
//! (gaze, pupil) and the time step → a display frame.
//!
//! This is the no-GPU backend and the reference the GPU passes are compared
//! against. Stages (DESIGN.md), and how they are fused here:
//!
//! | pass | stages | what |
//! | --- | --- | --- |
//! | A | 1 (input) | copy the frame into the working buffer and average its luminance over `pooling_downsample`² blocks |
//! | – | 1 pooling | [`PoolingModel::pool`] on the small luminance plane, centred on the gaze |
//! | – | 2 temporal | [`TemporalModel::step`] from the carried [`AdaptationState`] |
//! | – | 3 PSF | [`PsfBuilder::rebuild`] only when the pupil moved more than `psf_rebuild_threshold_mm` |
//! | B | 4 glare | [`GlareConvolver::apply`]: FFT convolution in a window at the gaze, Gaussian falloff blend |
//! | C | 6 tone + 7 colour (+ 8 encode) | per pixel, fused: tone reproduction, colour, and — when no acuity blur is needed — sRGB encoding |
//! | D | 5 acuity (+ 8 encode) | separable blur of Lab lightness, then sRGB encoding |
//!
//! Acuity loss (stage 5) runs on display-relative light after tone
//! reproduction rather than before it: CIE Lab lightness needs a bounded
//! white, which the HDR frame does not have, while the display frame does
//! (white = display peak). Glare, being optical, runs on scene luminance.
//!
//! Nothing is allocated per frame once the pipeline is built (the tests
//! prove it with a counting allocator).

use std::time::Instant;

use rayon::prelude::*;
use serde::{Deserialize, Serialize};

use crate::acuity::{AcuityBlur, AcuityModel};
use crate::colour::ColourModel;
use crate::glare::GlareConvolver;
use crate::image::luminance;
use crate::pooling::PoolingModel;
use crate::psf::{PsfBuilder, PsfParams};
use crate::temporal::{AdaptationState, TemporalModel};
use crate::tone::ToneModel;
use crate::{RgbImage, VisionError};

/// Smallest and largest pupil the PSF is ever built for, mm. Real pupils
/// range over about 2–8 mm (001 §5); the margins keep the aperture physical
/// whatever reaches the pipeline.
pub const PUPIL_MM_RANGE: (f32, f32) = (1.5, 9.0);

/// Glare settings.
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
#[serde(default, deny_unknown_fields)]
pub struct GlareConfig {
    /// Whether glare is simulated at all.
    pub enabled: bool,
    /// FFT window centred on the gaze, display pixels (power of two).
    pub window_px: usize,
    /// σ of the Gaussian falloff blend, as a fraction of the window size.
    pub falloff_sigma_frac: f64,
    /// PSF parameters; `ppd` is replaced by the display's.
    pub psf: PsfParams,
    /// The PSF is rebuilt when the pupil moved more than this, mm.
    pub psf_rebuild_threshold_mm: f64,
}

impl Default for GlareConfig {
    fn default() -> Self {
        Self {
            enabled: true,
            window_px: 256,
            falloff_sigma_frac: 0.25,
            psf: PsfParams::default(),
            psf_rebuild_threshold_mm: 0.1,
        }
    }
}

/// Every model choice of the pipeline.
#[derive(Clone, Debug, Default, PartialEq, Serialize, Deserialize)]
#[serde(default, deny_unknown_fields)]
pub struct PipelineConfig {
    pub pooling: PoolingModel,
    pub temporal: TemporalModel,
    pub tone: ToneModel,
    pub colour: ColourModel,
    pub acuity: AcuityModel,
    pub glare: GlareConfig,
    /// Block size of the luminance plane used for pooling (1 = full res).
    pub pooling_downsample: Option<usize>,
    /// Keep the display-linear frame (before encoding) for
    /// [`FramePipeline::display_linear`]; costs one more write per pixel.
    /// For tests and GPU parity checks.
    #[serde(skip)]
    pub keep_display_linear: bool,
}

impl PipelineConfig {
    /// Checks every field; the error names the field.
    pub fn validate(&self) -> Result<(), VisionError> {
        self.pooling.validate()?;
        self.temporal.validate()?;
        self.tone.validate()?;
        self.colour.validate()?;
        self.acuity.validate()?;
        let g = &self.glare;
        if !g.window_px.is_power_of_two() || !(16..=2048).contains(&g.window_px) {
            return Err(VisionError::invalid(
                "glare.window_px",
                g.window_px,
                "a power of two in 16..=2048",
            ));
        }
        if !(g.falloff_sigma_frac > 0.0 && g.falloff_sigma_frac <= 4.0) {
            return Err(VisionError::invalid(
                "glare.falloff_sigma_frac",
                g.falloff_sigma_frac,
                "0 < falloff_sigma_frac ≤ 4",
            ));
        }
        if !(g.psf_rebuild_threshold_mm >= 0.0 && g.psf_rebuild_threshold_mm.is_finite()) {
            return Err(VisionError::invalid(
                "glare.psf_rebuild_threshold_mm",
                g.psf_rebuild_threshold_mm,
                "a finite number ≥ 0",
            ));
        }
        g.psf.validate()?;
        if let Some(ds) = self.pooling_downsample
            && !(1..=64).contains(&ds)
        {
            return Err(VisionError::invalid("pooling_downsample", ds, "1..=64"));
        }
        Ok(())
    }

    fn downsample(&self) -> usize {
        self.pooling_downsample.unwrap_or(8)
    }
}

/// The per-frame input of the pipeline: what the eye does now.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct FrameInput {
    /// Gaze in normalised frame coordinates, top-left origin.
    pub gaze_uv: [f32; 2],
    /// Calibrated pupil diameter, mm (clamped to [`PUPIL_MM_RANGE`]).
    pub pupil_mm: f32,
    /// Time since the previous frame, seconds.
    pub dt_secs: f32,
}

/// Milliseconds spent in each stage of one frame.
#[derive(Clone, Copy, Debug, Default, PartialEq, Serialize)]
pub struct StageTimings {
    /// Pass A and stage 1: copy, luminance plane, pooling.
    pub pooling_ms: f64,
    /// Stage 2.
    pub temporal_ms: f64,
    /// Stage 3 (0 when the cached PSF was used).
    pub psf_ms: f64,
    /// Stage 4.
    pub glare_ms: f64,
    /// Stage 5 (0 when no blur was needed).
    pub acuity_ms: f64,
    /// Stages 6–8 fused.
    pub tone_colour_encode_ms: f64,
    /// Whole frame.
    pub total_ms: f64,
}

/// What the pipeline reports about one frame.
#[derive(Clone, Copy, Debug, Default, PartialEq, Serialize)]
pub struct FrameStats {
    /// Pooled luminance the eye adapts towards, cd/m².
    pub target_cd_m2: f64,
    /// Adaptation luminance after this frame's step, cd/m².
    pub adaptation_cd_m2: f64,
    /// Pupil the PSF was built for, mm.
    pub psf_pupil_mm: f64,
    /// Whether the PSF was rebuilt this frame.
    pub psf_rebuilt: bool,
    /// Acuity blur σ, display pixels.
    pub acuity_sigma_px: f32,
    /// Per-stage timings.
    pub timings: StageTimings,
}

/// An 8-bit sRGB display frame, RGBA, row-major.
#[derive(Clone, Debug, PartialEq)]
pub struct DisplayFrame {
    pub width: usize,
    pub height: usize,
    pub rgba8: Vec<u8>,
}

impl DisplayFrame {
    /// A black frame.
    pub fn new(width: usize, height: usize) -> Self {
        let mut rgba8 = vec![0u8; width * height * 4];
        for px in rgba8.chunks_exact_mut(4) {
            px[3] = 255;
        }
        Self {
            width,
            height,
            rgba8,
        }
    }
}

/// Size of the sRGB encoding table over linear [0, 1].
const SRGB_LUT_SIZE: usize = 16384;

/// sRGB transfer function (IEC 61966-2-1), linear [0, 1] → encoded [0, 1].
pub fn srgb_encode(linear: f32) -> f32 {
    let l = linear.clamp(0.0, 1.0);
    if l <= 0.003_130_8 {
        12.92 * l
    } else {
        1.055 * l.powf(1.0 / 2.4) - 0.055
    }
}

/// The CPU frame pipeline. Build once per display size; call
/// [`FramePipeline::process`] per frame.
pub struct FramePipeline {
    config: PipelineConfig,
    width: usize,
    height: usize,
    deg_per_px: f64,
    state: Option<AdaptationState>,
    work: RgbImage,
    display: RgbImage,
    small_lum: Vec<f32>,
    small_w: usize,
    small_h: usize,
    glare: Option<(PsfBuilder, GlareConvolver)>,
    psf_pupil_mm: f64,
    acuity: AcuityBlur,
    srgb_lut: Box<[u8; SRGB_LUT_SIZE]>,
}

impl FramePipeline {
    /// Builds a pipeline for `width × height` frames whose pixels subtend
    /// `deg_per_px` degrees. Builds the first PSF (for a 4 mm pupil).
    pub fn new(
        config: PipelineConfig,
        width: usize,
        height: usize,
        deg_per_px: f64,
    ) -> Result<Self, VisionError> {
        config.validate()?;
        if width == 0 || height == 0 {
            return Err(VisionError::invalid(
                "frame size",
                format!("{width}x{height}"),
                "non-zero",
            ));
        }
        if !(deg_per_px.is_finite() && deg_per_px > 0.0) {
            return Err(VisionError::invalid(
                "deg_per_px",
                deg_per_px,
                "a finite number > 0",
            ));
        }
        let ds = config.downsample();
        let small_w = width.div_ceil(ds);
        let small_h = height.div_ceil(ds);
        let psf_pupil_mm = 4.0;
        let glare = if config.glare.enabled {
            let mut params = config.glare.psf.clone();
            params.ppd = 1.0 / deg_per_px;
            params.pupil_mm = psf_pupil_mm;
            params.validate()?;
            let mut builder = PsfBuilder::new(params)?;
            let mut conv = GlareConvolver::new(config.glare.window_px);
            conv.set_kernel(builder.rebuild(psf_pupil_mm));
            Some((builder, conv))
        } else {
            None
        };
        let mut srgb_lut = Box::new([0u8; SRGB_LUT_SIZE]);
        for (i, v) in srgb_lut.iter_mut().enumerate() {
            *v = (srgb_encode(i as f32 / (SRGB_LUT_SIZE - 1) as f32) * 255.0).round() as u8;
        }
        Ok(Self {
            config,
            width,
            height,
            deg_per_px,
            state: None,
            work: RgbImage::new(width, height),
            display: RgbImage::new(width, height),
            small_lum: vec![0.0; small_w * small_h],
            small_w,
            small_h,
            glare,
            psf_pupil_mm,
            acuity: AcuityBlur::new(width, height),
            srgb_lut,
        })
    }

    /// The configuration.
    pub fn config(&self) -> &PipelineConfig {
        &self.config
    }

    /// Angular size of a display pixel, degrees.
    pub fn deg_per_px(&self) -> f64 {
        self.deg_per_px
    }

    /// The current adaptation state (`None` before the first frame).
    pub fn adaptation(&self) -> Option<AdaptationState> {
        self.state
    }

    /// Sets the adaptation state (e.g. to start a replay adapted).
    pub fn set_adaptation(&mut self, state: AdaptationState) {
        self.state = Some(state);
    }

    /// The display-linear frame of the last [`FramePipeline::process`]
    /// (display-relative, 1 = peak), kept only when
    /// [`PipelineConfig::keep_display_linear`] is set or acuity blur ran.
    pub fn display_linear(&self) -> &RgbImage {
        &self.display
    }

    /// The current PSF kernel (at display pixels), if glare is enabled.
    pub fn psf_kernel(&self) -> Option<&crate::psf::PsfKernel> {
        self.glare.as_ref().map(|(b, _)| b.kernel())
    }

    /// Processes one frame. `scene` is linear RGB in cd/m², the pipeline's
    /// size; `out` receives the display frame (resized if needed).
    pub fn process(
        &mut self,
        scene: &RgbImage,
        input: &FrameInput,
        out: &mut DisplayFrame,
    ) -> Result<FrameStats, VisionError> {
        if scene.width != self.width || scene.height != self.height {
            return Err(VisionError::SizeMismatch {
                what: "scene frame",
                expected_w: self.width,
                expected_h: self.height,
                got_w: scene.width,
                got_h: scene.height,
            });
        }
        if out.width != self.width || out.height != self.height {
            *out = DisplayFrame::new(self.width, self.height);
        }
        let t_start = Instant::now();
        let mut timings = StageTimings::default();
        let (w, h) = (self.width, self.height);
        let gaze_u = if input.gaze_uv[0].is_finite() {
            input.gaze_uv[0].clamp(0.0, 1.0)
        } else {
            0.5
        };
        let gaze_v = if input.gaze_uv[1].is_finite() {
            input.gaze_uv[1].clamp(0.0, 1.0)
        } else {
            0.5
        };
        let gaze_px = [f64::from(gaze_u) * w as f64, f64::from(gaze_v) * h as f64];
        let dt_secs = if input.dt_secs.is_finite() {
            f64::from(input.dt_secs.max(0.0))
        } else {
            0.0
        };
        let pupil_mm = if input.pupil_mm.is_finite() {
            input.pupil_mm.clamp(PUPIL_MM_RANGE.0, PUPIL_MM_RANGE.1)
        } else {
            self.psf_pupil_mm as f32
        };

        // Pass A: copy + sanitise, and block-average luminance for pooling.
        let ds = self.config.downsample();
        let small_w = self.small_w;
        self.work
            .pixels
            .par_chunks_mut(w * ds)
            .zip(scene.pixels.par_chunks(w * ds))
            .zip(self.small_lum.par_chunks_mut(small_w))
            .for_each(|((dst, src), small_row)| {
                small_row.fill(0.0);
                let rows = src.len() / w;
                for (i, (d, s)) in dst.iter_mut().zip(src).enumerate() {
                    let p = [sanitize(s[0]), sanitize(s[1]), sanitize(s[2])];
                    *d = p;
                    small_row[(i % w) / ds] += luminance(p);
                }
                for (bx, v) in small_row.iter_mut().enumerate() {
                    let cols = (w - bx * ds).min(ds);
                    *v /= (cols * rows) as f32;
                }
            });
        let small_gaze = [gaze_px[0] / ds as f64, gaze_px[1] / ds as f64];
        let target_cd_m2 = self
            .config
            .pooling
            .pool(
                &self.small_lum,
                self.small_w,
                self.small_h,
                small_gaze,
                self.deg_per_px * ds as f64,
            )
            .max(0.0);
        let t_pool = Instant::now();
        timings.pooling_ms = ms(t_start, t_pool);

        // Stage 2: temporal adaptation (the first frame starts adapted).
        let state = match self.state {
            Some(s) => self.config.temporal.step(s, target_cd_m2, dt_secs),
            None => AdaptationState::new(target_cd_m2),
        };
        self.state = Some(state);
        let adaptation_cd_m2 = state.luminance_cd_m2;
        let t_temporal = Instant::now();
        timings.temporal_ms = ms(t_pool, t_temporal);

        // Stages 3 + 4: PSF (cached) and glare at the gaze.
        let mut psf_rebuilt = false;
        if let Some((builder, conv)) = self.glare.as_mut() {
            if (f64::from(pupil_mm) - self.psf_pupil_mm).abs()
                > self.config.glare.psf_rebuild_threshold_mm
            {
                conv.set_kernel(builder.rebuild(f64::from(pupil_mm)));
                self.psf_pupil_mm = f64::from(pupil_mm);
                psf_rebuilt = true;
            }
            let t_psf = Instant::now();
            timings.psf_ms = ms(t_temporal, t_psf);
            let sigma_px =
                self.config.glare.falloff_sigma_frac * self.config.glare.window_px as f64;
            conv.apply(&mut self.work, gaze_px, sigma_px);
            timings.glare_ms = ms(t_psf, Instant::now());
        }
        let t_glare = Instant::now();

        // Stages 6 + 7 (+ 8): tone reproduction and colour, fused.
        let tone = self
            .config
            .tone
            .prepare_adapting(adaptation_cd_m2, state.light_target_cd_m2);
        let colour = self.config.colour.prepare(adaptation_cd_m2);
        let acuity_sigma_px = self
            .config
            .acuity
            .sigma_px(adaptation_cd_m2, self.deg_per_px);
        let blur = acuity_sigma_px > AcuityBlur::MIN_SIGMA_PX;
        let lut: &[u8; SRGB_LUT_SIZE] = &self.srgb_lut;
        if blur || self.config.keep_display_linear {
            self.display
                .pixels
                .par_chunks_mut(w)
                .zip(self.work.pixels.par_chunks(w))
                .for_each(|(dst, src)| {
                    for (d, s) in dst.iter_mut().zip(src) {
                        *d = clamp01(colour.apply(tone.apply(*s)));
                    }
                });
        } else {
            out.rgba8
                .par_chunks_mut(w * 4)
                .zip(self.work.pixels.par_chunks(w))
                .for_each(|(dst, src)| {
                    for (d, s) in dst.chunks_exact_mut(4).zip(src) {
                        encode_px(lut, colour.apply(tone.apply(*s)), d);
                    }
                });
        }
        let t_tone = Instant::now();

        // Stage 5 (+ 8): acuity loss on display light, then encode.
        if blur || self.config.keep_display_linear {
            if blur {
                self.acuity.apply(&mut self.display, acuity_sigma_px);
            }
            let t_blur = Instant::now();
            timings.acuity_ms = ms(t_tone, t_blur);
            out.rgba8
                .par_chunks_mut(w * 4)
                .zip(self.display.pixels.par_chunks(w))
                .for_each(|(dst, src)| {
                    for (d, s) in dst.chunks_exact_mut(4).zip(src) {
                        encode_px(lut, *s, d);
                    }
                });
            timings.tone_colour_encode_ms = ms(t_glare, t_tone) + ms(t_blur, Instant::now());
        } else {
            timings.tone_colour_encode_ms = ms(t_glare, t_tone);
        }
        timings.total_ms = ms(t_start, Instant::now());
        Ok(FrameStats {
            target_cd_m2,
            adaptation_cd_m2,
            psf_pupil_mm: self.psf_pupil_mm,
            psf_rebuilt,
            acuity_sigma_px,
            timings,
        })
    }
}

/// Display light is bounded by the display: values above its peak clip.
/// NaN stays NaN, so the tests can see it.
#[inline]
fn clamp01(rgb: [f32; 3]) -> [f32; 3] {
    rgb.map(|v| v.clamp(0.0, 1.0))
}

/// NaN, ±∞, negative and subnormal values become 0. Subnormals (below
/// 1.2e-38 cd/m², physically black) would otherwise slow every later
/// arithmetic pass by an order of magnitude on x86.
#[inline]
fn sanitize(v: f32) -> f32 {
    if v.is_finite() && v >= f32::MIN_POSITIVE {
        v
    } else {
        0.0
    }
}

#[inline(always)]
fn encode_px(lut: &[u8; SRGB_LUT_SIZE], rgb: [f32; 3], out: &mut [u8]) {
    if let Ok(out) = <&mut [u8; 4]>::try_from(out) {
        // NaN maps to 0; the index is then provably in range.
        let idx = |v: f32| {
            ((if v.is_nan() { 0.0 } else { v.clamp(0.0, 1.0) } * (SRGB_LUT_SIZE - 1) as f32 + 0.5)
                as usize)
                .min(SRGB_LUT_SIZE - 1)
        };
        *out = [lut[idx(rgb[0])], lut[idx(rgb[1])], lut[idx(rgb[2])], 255];
    }
}

fn ms(a: Instant, b: Instant) -> f64 {
    b.duration_since(a).as_secs_f64() * 1e3
}
