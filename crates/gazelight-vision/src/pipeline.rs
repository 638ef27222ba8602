//! The frame pipeline on the CPU: an HDR frame in cd/m², the eye's state
//! (gaze, pupil) and the time step → a display frame.
//!
//! This is the no-GPU backend and the reference the GPU passes are compared
//! against. Stages (ARCHITECTURE.md, "Data flow"), and how they are fused here:
//!
//! | pass | stages | what |
//! | --- | --- | --- |
//! | A | 1 (input) | average the sanitised frame's luminance, and count the pixels with data ([`crate::image::is_no_data`]), over the `pooling_downsample`² blocks the pooling model reads ([`PoolingModel::reach`]: for the default Gaussian, ±(6σ + 1) blocks around the gaze; the scene only is read) |
//! | – | 1 pooling | [`PoolingModel::pool_valid_in`] on the small luminance plane, centred on the gaze (pixels without data left out) |
//! | – | 2 temporal | [`TemporalModel::step`] from the carried [`AdaptationState`] |
//! | – | 3 PSF | [`PsfBuilder::rebuild`] only when the pupil moved more than `psf_rebuild_threshold_mm` |
//! | B | 4 glare | [`GlareConvolver::prepare`]: FFT convolution at the gaze (full-resolution core + coarse wide field), full weight within `full_weight_deg`, Gaussian fade beyond; nothing is written to the frame yet |
//! | C | 1 + 4 (rows) + 5 acuity + 6 tone + 7 colour + 8 encode | one streaming pass in bands of rows on the rayon pool: each row of the working frame is made just before the band first reads it (the scene row sanitised, the glare blended in: [`GlareConvolver::blend_row`]'s values, in one pass with the sanitising where only the far field's veil reaches), so the frame is read from memory once; then separable blur of Lab lightness, σ per pixel from its own lightness (001 eq 11–13, [`AcuityBlur`]); each row, as soon as its blur is final and while it is in cache, goes through tone reproduction and colour (one affine map per frame for the linear operators) and sRGB encoding ([`crate::encode`]) |
//!
//! Acuity loss (stage 5) runs on the HDR frame in cd/m², after glare and
//! before tone reproduction, as in 001 §4.3.1 ("the linear HDR values (i.e.,
//! before tone mapping)"): visual acuity depends on the absolute luminance
//! reaching the retina, so each pixel's σ comes from its lightness against
//! a fixed Lab white in cd/m² (`lab_white_cd_m2`, see [`crate::acuity`]),
//! not against the display or the adaptation. The frame after this stage is
//! the retinal image, linear RGB in cd/m² after glare and acuity
//! ([`FramePipeline::retinal`]); tone reproduction maps it to the display.
//!
//! Memory traffic per frame: pass C reads the scene once and writes the
//! display frame; pass A reads only the blocks the pooling reaches (for
//! the default Gaussian at 1440×1600 and 12.6 px/deg, about 41 × 41
//! blocks of 8 × 8 pixels, 4.7 % of the frame; a model that weights every
//! pixel reads it all); the window's glare touches only its FFT windows,
//! and the full-field stray light ([`crate::far_glare`], on by default)
//! reads the whole frame once for its block sums, while the window's FFTs
//! run on the other workers ([`GlareConvolver::prepare`]). The retinal
//! image is written to a frame-sized buffer only when
//! [`PipelineConfig::keep_retinal`] asks for it; otherwise each band of
//! pass C keeps just the 2r + 1 rows its blur is working on.
//!
//! Pixels without data (NaN in the view: outside the scene's field,
//! [`crate::scene::NO_DATA_RGB`]) are left out of pooling (pass A counts
//! each block's pixels with data; the pool is `Σ w·L / Σ w·valid`, and a
//! gaze whose reach has none keeps the last target), are no light in
//! glare (sanitised to 0), and are marked in the output:
//! [`NO_DATA_RGBA8`] in the display frame, NaN in the display-linear
//! frame and the retinal image. The GPU twin does the same.
//!
//! Nothing is allocated per frame once the pipeline is built (the tests
//! prove it with a counting allocator).

use std::time::Instant;

use rayon::prelude::*;
use serde::{Deserialize, Serialize};

use crate::acuity::AcuityModel;
use crate::band::{AcuityBlur, RowSource};
use crate::colour::ColourModel;
use crate::encode::{self, DisplayLinear, EncodeRgba8, Map, PixelMap, SrgbLut};
use crate::far_glare::{FarField, FarSplit};
use crate::glare::{GlareConvolver, GlareWindow};
use crate::image::luminance;
use crate::kernel_policy::{INITIAL_PUPIL_MM, KernelFollower, KernelPolicy};
use crate::pooling::{PlaneAngles, PoolingModel};
use crate::psf::{PsfBuilder, PsfParams};
use crate::simd::{LANES, Simd, Tier};
use crate::temporal::{AdaptationState, TemporalModel};
use crate::tone::ToneModel;
use crate::{RgbImage, VisionError};

/// Glare settings.
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
#[serde(default, deny_unknown_fields)]
pub struct GlareConfig {
    /// Whether glare is simulated at all.
    pub enabled: bool,
    /// Sources within this angle of the gaze glare with full weight, degrees.
    pub full_weight_deg: f64,
    /// σ of the Gaussian fade beyond `full_weight_deg`, degrees.
    pub fade_sigma_deg: f64,
    /// PSF parameters (`field_deg` is the kernel's field, ±20° by default;
    /// `glare_scale` physical or seed); `ppd` is replaced by the display's.
    pub psf: PsfParams,
    /// The PSF is rebuilt when the pupil moved more than this, mm.
    pub psf_rebuild_threshold_mm: f64,
    /// The CIE 146 veil of every pixel onto every other beyond the
    /// kernel, out to 90° ([`crate::far_glare`], and its GPU twin
    /// `gazelight-gpu/src/far_glare.rs`; needs the physical kernel's stray
    /// light). On by default.
    pub far_field: bool,
}

impl GlareConfig {
    /// The weight settings of the convolver.
    pub fn window(&self) -> GlareWindow {
        GlareWindow {
            full_weight_deg: self.full_weight_deg,
            fade_sigma_deg: self.fade_sigma_deg,
        }
    }
}

impl Default for GlareConfig {
    fn default() -> Self {
        Self {
            enabled: true,
            full_weight_deg: GlareWindow::default().full_weight_deg,
            fade_sigma_deg: GlareWindow::default().fade_sigma_deg,
            psf: PsfParams::default(),
            psf_rebuild_threshold_mm: 0.1,
            far_field: true,
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
    /// Keep the retinal image (after glare and acuity, before tone
    /// reproduction) for [`FramePipeline::retinal`]; costs a frame-sized
    /// buffer and one more write per pixel (without it, the band pass
    /// keeps only the rows it works on). For EXR output, tests and tools.
    #[serde(skip)]
    pub keep_retinal: bool,
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
        g.window().validate()?;
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
    /// Calibrated pupil diameter, mm (the kernel's pupil follows it by
    /// [`crate::kernel_policy`]: clamped to 1.5–9 mm, non-finite → kept).
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
    /// Stage 5 on its own: 0 in the optimised pipeline, where stage 5 runs
    /// fused with stages 6–8 and its time is in `tone_colour_encode_ms`.
    pub acuity_ms: f64,
    /// Stages 6–8, fused (with stage 5 fused into them: stages 5–8).
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
    /// Acuity blur σ of a pixel at the adaptation luminance, display
    /// pixels (for reporting: every pixel's σ follows its own lightness).
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
    /// How the frame's pixels map to angles for pooling (uniform at
    /// `deg_per_px` until [`FramePipeline::set_view_frustum`]).
    angles: PlaneAngles,
    state: Option<AdaptationState>,
    work: RgbImage,
    display: RgbImage,
    small_lum: Vec<f32>,
    /// Each block's share of pixels with data ([`crate::image::is_no_data`]).
    small_valid: Vec<f32>,
    small_w: usize,
    small_h: usize,
    /// The last frame's pooled target, held when a gaze's pooling reaches
    /// no pixel with data (0 before the first).
    last_target_cd_m2: f64,
    /// The PSF builder (dropped while rebuilding is off: a live session
    /// builds kernels elsewhere, and a builder holds tens of MB) and the
    /// convolver.
    glare: Option<(Option<PsfBuilder>, GlareConvolver)>,
    /// The builder's parameters (to make it again) and its kernel's size
    /// and pixel size.
    psf_params: PsfParams,
    kernel_size: usize,
    kernel_deg_per_px: f64,
    /// The pupil of the installed kernel, and the one rule for the next.
    psf_follower: KernelFollower,
    /// Rebuild the PSF in [`FramePipeline::process`] when the pupil moves
    /// (off: the caller installs kernels with [`FramePipeline::set_kernel`]).
    psf_auto_rebuild: bool,
    /// The kernel last installed by [`FramePipeline::set_kernel`] (its
    /// buffer is reused by later installs of the same size).
    installed: Option<crate::psf::PsfKernel>,
    acuity: AcuityBlur,
    srgb_lut: Box<SrgbLut>,
    /// The tier pass A, the row source and the encoder run on.
    simd: Simd,
    /// Run the pre-optimisation per-pixel passes (the tests' reference).
    #[cfg(test)]
    reference: bool,
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
        let keep_display = config.keep_display_linear;
        let keep_retinal = config.keep_retinal;
        let psf_pupil_mm = INITIAL_PUPIL_MM;
        let psf_follower = KernelFollower::new(KernelPolicy::new(&config.glare), 1, psf_pupil_mm);
        let mut psf_params = config.glare.psf.clone();
        psf_params.ppd = 1.0 / deg_per_px;
        psf_params.pupil_mm = psf_pupil_mm;
        let (mut kernel_size, mut kernel_deg_per_px) = (0, deg_per_px);
        let glare = if config.glare.enabled {
            psf_params.validate()?;
            let builder = PsfBuilder::new(psf_params.clone())?;
            let mut conv = GlareConvolver::new(builder.kernel(), config.glare.window())?;
            kernel_size = builder.kernel().size;
            kernel_deg_per_px = builder.kernel().deg_per_px;
            conv.set_far_field(far_field(
                &config.glare,
                &psf_params,
                kernel_size,
                kernel_deg_per_px,
                width,
                height,
                PlaneAngles::Uniform { deg_per_px },
            )?);
            Some((Some(builder), conv))
        } else {
            None
        };
        let acuity = AcuityBlur::new(&config.acuity, width, height, deg_per_px);
        let srgb_lut = encode::srgb_lut();
        Ok(Self {
            config,
            width,
            height,
            deg_per_px,
            angles: PlaneAngles::Uniform { deg_per_px },
            state: None,
            // Only kept on request (the band pass otherwise works in rings
            // of rows).
            work: if keep_retinal {
                RgbImage::new(width, height)
            } else {
                RgbImage::new(0, 0)
            },
            // Only kept on request (a frame-sized buffer otherwise unused).
            display: if keep_display {
                RgbImage::new(width, height)
            } else {
                RgbImage::new(0, 0)
            },
            small_lum: vec![0.0; small_w * small_h],
            small_valid: vec![1.0; small_w * small_h],
            small_w,
            small_h,
            last_target_cd_m2: 0.0,
            glare,
            psf_params,
            kernel_size,
            kernel_deg_per_px,
            psf_follower,
            psf_auto_rebuild: true,
            installed: None,
            acuity,
            srgb_lut,
            simd: Simd::host(),
            #[cfg(test)]
            reference: false,
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

    /// The frame is a rectilinear view whose left, right, up and down edges
    /// lie at the tangents `tan_lrud`: pooling measures the angle from the
    /// gaze through that projection ([`PlaneAngles::Rectilinear`]) instead
    /// of `deg_per_px` per pixel. Fails (and keeps the old geometry) on
    /// tangents that are not finite or ordered.
    pub fn set_view_frustum(&mut self, tan_lrud: [f64; 4]) -> Result<(), VisionError> {
        let angles = PlaneAngles::Rectilinear {
            tan_lrud,
            extent_px: [self.width as f64, self.height as f64],
        };
        angles.validate()?;
        // The far field's grid follows the geometry: rebuilt (allocating)
        // only when it changed, not when a live loop re-sets the same one
        // each frame.
        if angles != self.angles
            && let Some((_, conv)) = self.glare.as_mut()
        {
            conv.set_far_field(far_field(
                &self.config.glare,
                &self.psf_params,
                self.kernel_size,
                self.kernel_deg_per_px,
                self.width,
                self.height,
                angles,
            )?);
        }
        self.angles = angles;
        Ok(())
    }

    /// How the frame's pixels map to angles for pooling.
    pub fn plane_angles(&self) -> PlaneAngles {
        self.angles
    }

    /// The current adaptation state (`None` before the first frame).
    pub fn adaptation(&self) -> Option<AdaptationState> {
        self.state
    }

    /// The light the first frame adapts to when its pooling reaches no
    /// data (a gaze outside the scene's field), cd/m²: the light measured
    /// elsewhere in the view (`gazelight_render` gives the view's field
    /// mean) instead of an unset 0 cd/m², which would draw a blown-out
    /// first frame. Later frames whose pooling reaches no data hold the
    /// last target, starting from this one. Only before the first frame;
    /// a value that is not finite and ≥ 0 is ignored.
    pub fn set_initial_target(&mut self, cd_m2: f64) {
        if self.state.is_none() && cd_m2.is_finite() && cd_m2 >= 0.0 {
            self.last_target_cd_m2 = cd_m2;
        }
    }

    /// Sets the adaptation state (e.g. to start a replay adapted).
    pub fn set_adaptation(&mut self, state: AdaptationState) {
        self.state = Some(state);
    }

    /// Runs pass A, the row source, the band engine and the encoder on
    /// `simd`'s tier (the tests compare the tiers).
    #[cfg(test)]
    pub(crate) fn set_simd(&mut self, simd: Simd) {
        self.simd = simd;
        self.acuity.set_simd(simd);
    }

    /// The display-linear frame of the last [`FramePipeline::process`]
    /// (display-relative, 1 = peak), kept only when
    /// [`PipelineConfig::keep_display_linear`] is set.
    pub fn display_linear(&self) -> &RgbImage {
        &self.display
    }

    /// The retinal image of the last [`FramePipeline::process`]: linear
    /// RGB in cd/m² after glare and acuity, before tone reproduction. Kept
    /// only when [`PipelineConfig::keep_retinal`] is set (else 0 × 0).
    pub fn retinal(&self) -> &RgbImage {
        &self.work
    }

    /// The current PSF kernel (at display pixels), if glare is enabled:
    /// the one last installed by [`FramePipeline::set_kernel`], else the
    /// builder's.
    pub fn psf_kernel(&self) -> Option<&crate::psf::PsfKernel> {
        let (builder, _) = self.glare.as_ref()?;
        self.installed
            .as_ref()
            .or_else(|| builder.as_ref().map(PsfBuilder::kernel))
    }

    /// Whether [`FramePipeline::process`] rebuilds the PSF itself when the
    /// pupil moves more than `psf_rebuild_threshold_mm` (the default). A
    /// live session turns it off and builds kernels on another thread,
    /// installing each with [`FramePipeline::set_kernel`].
    ///
    /// Turning it off drops the builder (keeping its kernel): a live
    /// session's kernels come from its own worker. Turning it back on makes
    /// a builder again at the first rebuild.
    pub fn set_psf_auto_rebuild(&mut self, on: bool) {
        self.psf_auto_rebuild = on;
        if !on
            && let Some((builder, _)) = self.glare.as_mut()
            && let Some(b) = builder.take()
            && self.installed.is_none()
        {
            self.installed = Some(b.kernel().clone());
        }
    }

    /// Installs a kernel built elsewhere (e.g. by a [`PsfBuilder`] with the
    /// same parameters on another thread): later frames convolve with it.
    /// Its size and pixel size must be the ones this pipeline was built
    /// for. Reuses the previous installed kernel's buffers (no allocation
    /// once one kernel of this size has been installed). An error with
    /// glare off.
    pub fn set_kernel(&mut self, kernel: &crate::psf::PsfKernel) -> Result<(), VisionError> {
        let Some((_, conv)) = self.glare.as_mut() else {
            return Err(VisionError::invalid(
                "glare kernel",
                "a kernel",
                "glare enabled in the pipeline",
            ));
        };
        conv.set_kernel(kernel)?;
        match &mut self.installed {
            Some(k) if k.rgb.len() == kernel.rgb.len() => {
                k.rgb.copy_from_slice(&kernel.rgb);
                k.size = kernel.size;
                k.deg_per_px = kernel.deg_per_px;
                k.pupil_mm = kernel.pupil_mm;
                k.wavelengths_nm.clone_from(&kernel.wavelengths_nm);
            }
            slot => *slot = Some(kernel.clone()),
        }
        self.psf_follower.built(0, kernel.pupil_mm);
        Ok(())
    }

    /// A preparer of glare spectra for this pipeline's convolver (`None`
    /// with glare off), for the thread that builds kernels: see
    /// [`FramePipeline::install_prepared`].
    pub fn kernel_preparer(&self) -> Option<crate::glare::GlarePreparer> {
        self.glare.as_ref().map(|(_, conv)| conv.preparer())
    }

    /// Installs a kernel prepared elsewhere (built, and its spectra made by
    /// [`FramePipeline::kernel_preparer`]'s preparer) by swapping buffers:
    /// no FFT, no copy, no allocation; `prepared` gets the previous kernel
    /// and spectra back for reuse. Without spectra the convolver computes
    /// them here (as [`FramePipeline::set_kernel`]). An error (nothing
    /// changed) with glare off or for a kernel of another size.
    pub fn install_prepared(
        &mut self,
        prepared: &mut crate::glare::PreparedKernel,
    ) -> Result<(), VisionError> {
        let Some((_, conv)) = self.glare.as_mut() else {
            return Err(VisionError::invalid(
                "glare kernel",
                "a kernel",
                "glare enabled in the pipeline",
            ));
        };
        let k = &prepared.kernel;
        if k.size != self.kernel_size
            || k.deg_per_px != self.kernel_deg_per_px
            || k.rgb.len() != k.size * k.size
        {
            return Err(VisionError::invalid(
                "glare kernel",
                format!("{}x{} at {} deg/px", k.size, k.size, k.deg_per_px),
                "the size and pixel size the pipeline was built for",
            ));
        }
        match prepared.spectra.as_mut() {
            Some(s) if s.pupil_mm() == k.pupil_mm => conv.install(s)?,
            _ => conv.set_kernel(k)?,
        }
        self.psf_follower.built(0, k.pupil_mm);
        let empty = crate::psf::PsfKernel {
            size: 0,
            deg_per_px: k.deg_per_px,
            pupil_mm: f64::NAN,
            wavelengths_nm: Vec::new(),
            rgb: Vec::new(),
        };
        match &mut self.installed {
            Some(old) => std::mem::swap(old, &mut prepared.kernel),
            slot => *slot = Some(std::mem::replace(&mut prepared.kernel, empty)),
        }
        Ok(())
    }

    /// Processes one frame. `scene` is linear RGB in cd/m², the pipeline's
    /// size; `out` receives the display frame (resized if needed).
    pub fn process(
        &mut self,
        scene: &RgbImage,
        input: &FrameInput,
        out: &mut DisplayFrame,
    ) -> Result<FrameStats, VisionError> {
        // The whole frame runs on one of rayon's worker threads: the
        // frame's parallel passes then split through work stealing, instead
        // of each pass queueing its job from outside the pool and blocking
        // the caller until a worker takes it (two thread switches a pass).
        if rayon::current_thread_index().is_none() {
            return rayon::scope(|_| self.process_on_pool(scene, input, out));
        }
        self.process_on_pool(scene, input, out)
    }

    fn process_on_pool(
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

        // Pass A: block-average luminance for pooling (the optimised pass
        // reads the scene only; the reference copies it into `work` too).
        let ds = self.config.downsample();
        #[cfg(test)]
        let reference = self.reference;
        #[cfg(not(test))]
        let reference = false;
        let small_gaze = [gaze_px[0] / ds as f64, gaze_px[1] / ds as f64];
        if reference {
            #[cfg(test)]
            {
                if self.work.pixels.len() != w * h {
                    self.work = RgbImage::new(w, h);
                }
                reference_pass_a(
                    scene,
                    &mut self.work,
                    &mut self.small_lum,
                    &mut self.small_valid,
                    ds,
                    self.small_w,
                );
            }
        } else {
            // Only the blocks the pooling model reads.
            let blocks = self.config.pooling.reach_in(
                self.small_w,
                self.small_h,
                small_gaze,
                self.angles.downsampled(ds),
            );
            pass_a(
                self.simd,
                scene,
                &mut self.small_lum,
                &mut self.small_valid,
                ds,
                self.small_w,
                &blocks,
            );
        }
        // Pixels without data are left out (Σ w·L / Σ w·valid); a gaze
        // whose pooling reaches none holds the last target.
        let target_cd_m2 = self
            .config
            .pooling
            .pool_valid_in(
                &self.small_lum,
                &self.small_valid,
                self.small_w,
                self.small_h,
                small_gaze,
                self.angles.downsampled(ds),
            )
            .unwrap_or(self.last_target_cd_m2)
            .max(0.0);
        self.last_target_cd_m2 = target_cd_m2;
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
            if self.psf_auto_rebuild
                && let Some(pupil_mm) = self.psf_follower.follow_one(input.pupil_mm)
            {
                if builder.is_none() {
                    *builder = Some(PsfBuilder::new(self.psf_params.clone())?);
                }
                // Same size and pixel size as at construction: cannot fail.
                if let Some(b) = builder.as_mut()
                    && conv.set_kernel(b.rebuild(pupil_mm)).is_ok()
                {
                    self.psf_follower.built(0, b.kernel().pupil_mm);
                    self.installed = None;
                    psf_rebuilt = true;
                }
            }
            let t_psf = Instant::now();
            timings.psf_ms = ms(t_temporal, t_psf);
            if reference {
                conv.apply(&mut self.work, gaze_px);
            } else {
                // The FFTs only: each row is blended as the band pass makes
                // it (`FrameRows`).
                conv.prepare(scene, gaze_px);
            }
            timings.glare_ms = ms(t_psf, Instant::now());
        }
        let t_glare = Instant::now();

        // Stage 5: acuity loss on the HDR frame, σ per pixel, fused with
        // stages 6 + 7 + 8 (tone reproduction, colour, encoding): each row
        // is mapped and encoded as soon as its blur is final.
        let acuity_sigma_px = self
            .config
            .acuity
            .sigma_px(adaptation_cd_m2, self.deg_per_px);
        let tone = self
            .config
            .tone
            .prepare_adapting(adaptation_cd_m2, state.light_target_cd_m2);
        let colour = self.config.colour.prepare(adaptation_cd_m2);
        let lut: &SrgbLut = &self.srgb_lut;
        let to_display = self.config.keep_display_linear;
        if reference {
            #[cfg(test)]
            {
                reference_acuity(&self.config.acuity, self.deg_per_px, &mut self.work);
                timings.acuity_ms = ms(t_glare, Instant::now());
                reference_pass_c(
                    &tone,
                    &colour,
                    &self.work,
                    &mut self.display,
                    out,
                    lut,
                    to_display,
                );
                // The no-data marks, as the optimised pass makes them.
                mark_retinal(scene, &mut self.work);
                if to_display {
                    mark_retinal(scene, &mut self.display);
                }
                for (p, o) in scene.pixels.iter().zip(out.rgba8.chunks_exact_mut(4)) {
                    if crate::image::is_no_data(*p) {
                        o.copy_from_slice(&NO_DATA_RGBA8);
                    }
                }
            }
        } else {
            let stages = Stages5To8 {
                rows: FrameRows {
                    scene,
                    glare: self.glare.as_ref().map(|(_, conv)| conv),
                    simd: self.simd,
                },
                acuity: &mut self.acuity,
                work: self.config.keep_retinal.then_some(&mut self.work),
                display: &mut self.display,
                out,
                lut,
                to_display,
            };
            match PixelMap::new(&tone, &colour) {
                PixelMap::Affine(m) => stages.run(m),
                PixelMap::NakaRushton(m) => stages.run(m),
                PixelMap::Window(m) => stages.run(m),
            }
        }
        if self.config.keep_retinal && !reference {
            mark_retinal(scene, &mut self.work);
        }
        if to_display {
            let display = &self.display.pixels;
            let simd = self.simd;
            out.rgba8
                .par_chunks_mut(4 * w)
                .zip(display.par_chunks(w))
                .for_each(|(o, d)| {
                    encode::encode_row(simd, &encode::IDENTITY, lut, d, o);
                    // The display-linear frame's no-data marks (NaN).
                    for (p, o) in d.iter().zip(o.chunks_exact_mut(4)) {
                        if crate::image::is_no_data(*p) {
                            o.copy_from_slice(&NO_DATA_RGBA8);
                        }
                    }
                });
        }
        timings.tone_colour_encode_ms = ms(t_glare, Instant::now()) - timings.acuity_ms;
        timings.total_ms = ms(t_start, Instant::now());
        Ok(FrameStats {
            target_cd_m2,
            adaptation_cd_m2,
            psf_pupil_mm: self.psf_follower.kernel_mm(0),
            psf_rebuilt,
            acuity_sigma_px,
            timings,
        })
    }
}

/// The far field of a pipeline's glare (`None` when off or without the
/// physical kernel's stray light): the CIE 146 split at the kernel's
/// radius, for the view's geometry. The one decision, for the CPU pipeline
/// and its GPU twin (`gazelight-gpu/src/far_glare.rs`).
pub fn far_field(
    glare: &GlareConfig,
    psf: &PsfParams,
    kernel_size: usize,
    kernel_deg_per_px: f64,
    width: usize,
    height: usize,
    angles: PlaneAngles,
) -> Result<Option<FarField>, VisionError> {
    if !(glare.enabled && glare.far_field && psf.has_stray_light()) {
        return Ok(None);
    }
    let split = FarSplit::new(
        psf.age_years,
        psf.pigmentation,
        (kernel_size / 2) as f64 * kernel_deg_per_px,
    );
    FarField::new(split, width, height, angles).map(Some)
}

/// NaN, ±∞, negative and subnormal values become 0. Subnormals (below
/// 1.2e-38 cd/m², physically black) would otherwise slow every later
/// arithmetic pass by an order of magnitude on x86. Branch-free: both
/// comparisons are false for NaN.
#[inline(always)]
pub(crate) fn sanitize(v: f32) -> f32 {
    if (f32::MIN_POSITIVE..f32::INFINITY).contains(&v) {
        v
    } else {
        0.0
    }
}

/// Pass A: `small_lum` = luminance of the `ds × ds` blocks `blocks`
/// (block columns and rows) of the sanitised `scene`, summed over the
/// block's pixels with data and divided by all its pixels (edge blocks
/// over the pixels they have), and `small_valid` = the share of the
/// block's pixels with data ([`crate::image::is_no_data`]); the other
/// blocks are left as they are. Reads only
/// those blocks of the scene: the band pass makes the working frame's rows
/// itself ([`FrameRows`]), and the pooling model reads only `blocks`
/// ([`crate::pooling::PoolingModel::reach`]: ±(6σ + 1) blocks around the
/// gaze for the default Gaussian). Rows of blocks run in parallel; within
/// a block row, each row adds its pixels to the block sums `ds` at a time
/// (no per-pixel division), with [`crate::simd::avx2::block_sums_row`] for
/// blocks of 8 where `simd` has AVX2.
fn pass_a(
    simd: Simd,
    scene: &RgbImage,
    small_lum: &mut [f32],
    small_valid: &mut [f32],
    ds: usize,
    small_w: usize,
    blocks: &crate::pooling::PlaneRect,
) {
    let (w, h) = (scene.width, scene.height);
    let (bx0, bx1) = (blocks.x.start, blocks.x.end.min(small_w));
    let (px0, px1) = (bx0 * ds, (bx1 * ds).min(w));
    let (py0, py1) = (blocks.y.start * ds, (blocks.y.end * ds).min(h));
    if bx0 >= bx1 || py0 >= py1 {
        return;
    }
    scene.pixels[py0 * w..py1 * w]
        .par_chunks(w * ds)
        .zip(small_lum[blocks.y.start * small_w..].par_chunks_mut(small_w))
        .zip(small_valid[blocks.y.start * small_w..].par_chunks_mut(small_w))
        .for_each(|((src, small_row), valid_row)| {
            let small_row = &mut small_row[bx0..bx1];
            let valid_row = &mut valid_row[bx0..bx1];
            small_row.fill(0.0);
            valid_row.fill(0.0);
            let rows = src.len() / w;
            for srow in src.chunks_exact(w) {
                let srow = &srow[px0..px1];
                block_valid_row(srow, valid_row, ds);
                #[cfg(target_arch = "x86_64")]
                if ds == LANES && simd.has(Tier::Avx2) {
                    // SAFETY: a `Simd` of this tier proves AVX2 and FMA.
                    if unsafe { crate::simd::avx2::block_sums_row(srow, small_row) } {
                        continue;
                    }
                }
                block_sums_row_portable(srow, small_row, ds);
            }
            for (k, (v, a)) in small_row.iter_mut().zip(valid_row.iter_mut()).enumerate() {
                let cols = (w - (bx0 + k) * ds).min(ds);
                *v /= (cols * rows) as f32;
                *a /= (cols * rows) as f32;
            }
        });
}

/// Adds the number of pixels with data in each `ds`-pixel block of the
/// row `srow` to its entry of `counts`.
#[inline]
pub(crate) fn block_valid_row(srow: &[[f32; 3]], counts: &mut [f32], ds: usize) {
    for (blk, acc) in srow.chunks(ds).zip(counts.iter_mut()) {
        let n = blk
            .iter()
            .filter(|p| !crate::image::is_no_data(**p))
            .count();
        *acc += n as f32;
    }
}

/// Adds each `ds`-pixel block's luminance sum (pixels sanitised, in
/// order, the sum started at 0) of the row `srow` to its entry of `sums`.
pub(crate) fn block_sums_row_portable(srow: &[[f32; 3]], sums: &mut [f32], ds: usize) {
    for (blk, acc) in srow.chunks(ds).zip(sums.iter_mut()) {
        let mut sum = 0.0f32;
        for p in blk {
            sum += luminance(p.map(sanitize));
        }
        *acc += sum;
    }
}

/// The rows of the working frame, made as the band pass first reads them
/// (while they are in cache): the scene row sanitised, with the prepared
/// glare blended in (stages 1 and 4 of one row).
struct FrameRows<'a> {
    scene: &'a RgbImage,
    glare: Option<&'a GlareConvolver>,
    /// The tier the rows are made on.
    simd: Simd,
}

impl RowSource for FrameRows<'_> {
    /// [`FrameRows::fill_portable`] compiled for the tier ([`Simd::compiled`]:
    /// the same operations, no FMA contraction, so the same bits; 16 lanes
    /// with AVX-512, 8 with AVX2, SSE's 4 otherwise).
    #[inline]
    fn fill(&self, y: usize, row: &mut [[f32; 3]]) {
        self.simd.compiled(
            #[inline(always)]
            || self.fill_portable(y, row),
        );
    }
}

impl FrameRows<'_> {
    /// The row: the scene's, sanitised, with the glare blended in.
    #[inline(always)]
    fn fill_portable(&self, y: usize, row: &mut [[f32; 3]]) {
        let w = self.scene.width;
        let src = &self.scene.pixels[y * w..(y + 1) * w];
        match self.glare {
            // Sanitised and blended in one pass where the far field veils.
            Some(glare) => glare.fill_row(y, src, row),
            None => {
                for (d, s) in row.as_flattened_mut().iter_mut().zip(src.as_flattened()) {
                    *d = sanitize(*s);
                }
            }
        }
        // The band makes its rows in order: the next scene row arrives
        // while this one goes through the blur, tone and encoding.
        if let Some(next) = self.scene.pixels.get((y + 1) * w..(y + 2) * w) {
            crate::image::prefetch(next);
        }
    }
}

/// Stages 5–8 of one frame: the acuity blur of the rows `rows` makes, into
/// `work`, with the tone + colour map and the encoding as its row sink.
struct Stages5To8<'a> {
    rows: FrameRows<'a>,
    acuity: &'a mut AcuityBlur,
    /// Where the retinal image is kept (`None`: not kept).
    work: Option<&'a mut RgbImage>,
    display: &'a mut RgbImage,
    out: &'a mut DisplayFrame,
    lut: &'a SrgbLut,
    to_display: bool,
}

impl Stages5To8<'_> {
    /// One monomorphic pass per operator.
    fn run<M: Map>(self, map: M) {
        let size = (self.rows.scene.width, self.rows.scene.height);
        let width = size.0;
        let scene = self.rows.scene;
        if self.to_display {
            let sink = MarkNoData {
                sink: DisplayLinear { map, width },
                scene,
            };
            self.acuity
                .apply_from(&self.rows, size, self.work, &sink, &mut self.display.pixels);
        } else {
            let sink = MarkNoData {
                sink: EncodeRgba8 {
                    map,
                    lut: self.lut,
                    width,
                    simd: self.rows.simd,
                },
                scene,
            };
            self.acuity
                .apply_from(&self.rows, size, self.work, &sink, &mut self.out.rgba8);
        }
    }
}

/// The display value of a pixel with no data ([`crate::image::is_no_data`]:
/// outside the scene's field): RGBA `0, 0, 0, 0`, fully transparent, so a
/// PNG shows it as no data and never as black light. (In the
/// display-linear frame: NaN; in the retinal image: NaN, as in the view.)
pub const NO_DATA_RGBA8: [u8; 4] = [0; 4];

/// What a sink writes for a pixel with no data.
trait NoDataMark: Copy + Send {
    /// Items per pixel.
    const PER_PX: usize;
    /// The mark.
    const MARK: Self;
}

impl NoDataMark for u8 {
    const PER_PX: usize = 4;
    const MARK: Self = 0;
}

impl NoDataMark for [f32; 3] {
    const PER_PX: usize = 1;
    const MARK: Self = [f32::NAN; 3];
}

/// A row sink that marks the pixels of the scene row without data
/// (its rows scanned as they are written: a row with data everywhere is
/// only read).
struct MarkNoData<'a, S> {
    sink: S,
    scene: &'a RgbImage,
}

impl<S: crate::band::RowSink> crate::band::RowSink for MarkNoData<'_, S>
where
    S::Out: NoDataMark,
{
    type Out = S::Out;
    fn per_row(&self) -> usize {
        self.sink.per_row()
    }
    #[inline(always)]
    fn row(&self, y: usize, px: &[[f32; 3]], out: &mut [Self::Out]) {
        self.sink.row(y, px, out);
        let w = self.scene.width;
        let Some(src) = self.scene.pixels.get(y * w..(y + 1) * w) else {
            return;
        };
        if !src.iter().any(|p| crate::image::is_no_data(*p)) {
            return;
        }
        let per = S::Out::PER_PX;
        for (p, o) in src.iter().zip(out.chunks_exact_mut(per)) {
            if crate::image::is_no_data(*p) {
                o.fill(S::Out::MARK);
            }
        }
    }
}

/// Marks the pixels of the retinal image `work` where `scene` has no data
/// (NaN, as in the view).
fn mark_retinal(scene: &RgbImage, work: &mut RgbImage) {
    let w = scene.width;
    if work.pixels.len() != scene.pixels.len() || w == 0 {
        return;
    }
    work.pixels
        .par_chunks_mut(w)
        .zip(scene.pixels.par_chunks(w))
        .for_each(|(d, s)| {
            for (d, s) in d.iter_mut().zip(s) {
                if crate::image::is_no_data(*s) {
                    *d = [f32::NAN; 3];
                }
            }
        });
}

fn ms(a: Instant, b: Instant) -> f64 {
    b.duration_since(a).as_secs_f64() * 1e3
}

#[cfg(test)]
mod reference;
#[cfg(test)]
use reference::{reference_acuity, reference_pass_a, reference_pass_c};

#[cfg(test)]
mod tests {

    use super::*;
    use crate::acuity::AcuityModel;
    use crate::scene::{LuminanceScale, PanoramaView, Scene, ViewParams};

    /// A view into a shared panorama scaled by `cd_m2_per_unit`.
    fn view(
        name: &str,
        cd_m2_per_unit: f64,
        yaw_deg: f64,
        hfov_deg: f64,
        width: usize,
        height: usize,
    ) -> (RgbImage, f64) {
        let path = gazelight_test_support::data_path("hdr/blender-world").join(name);
        let scale = LuminanceScale::CdM2PerUnit {
            factor: cd_m2_per_unit,
        };
        let scene = Scene::load(&path, scale).unwrap();
        let params = ViewParams {
            yaw_deg,
            pitch_deg: -6.0,
            hfov_deg,
            width,
            height,
        };
        let mut img = RgbImage::new(width, height);
        PanoramaView::new(params)
            .unwrap()
            .render(&scene.image, &mut img);
        (img, params.deg_per_px())
    }

    /// Runs the optimised and the reference pipeline side by side over a
    /// few frames (gaze moving, pupil changing so the PSF is rebuilt) and
    /// checks every display byte within 1/255, the display-linear frame
    /// and the frame statistics. The optimised pipeline runs twice, keeping
    /// the retinal image and not (rows in rings): both must give the same
    /// bytes.
    fn compare(config: &PipelineConfig, img: &RgbImage, dpp: f64, what: &str) -> (usize, usize) {
        let (w, h) = (img.width, img.height);
        let kept = PipelineConfig {
            keep_retinal: true,
            ..config.clone()
        };
        let rings = PipelineConfig {
            keep_retinal: false,
            ..config.clone()
        };
        let mut fast = FramePipeline::new(kept, w, h, dpp).unwrap();
        let mut ring = FramePipeline::new(rings, w, h, dpp).unwrap();
        let mut slow = FramePipeline::new(config.clone(), w, h, dpp).unwrap();
        slow.reference = true;
        ring.set_adaptation(AdaptationState::new(0.05));
        let mut out_ring = DisplayFrame::new(w, h);
        // Start adapted to a dim 0.05 cd/m²: the day view light-adapts
        // (000 eq 10's offset), the night view dark-adapts.
        fast.set_adaptation(AdaptationState::new(0.05));
        slow.set_adaptation(AdaptationState::new(0.05));
        let (mut out_fast, mut out_slow) = (DisplayFrame::new(w, h), DisplayFrame::new(w, h));
        let frames = [
            ([0.5, 0.45], 4.0, 1.0 / 90.0),
            ([0.3, 0.6], 4.0, 1.0 / 90.0),
            ([0.7, 0.4], 6.5, 0.5),
            ([0.02, 0.98], 2.5, 2.0),
        ];
        let mut differing = 0;
        let mut light_adapting = 0;
        for (n, (gaze_uv, pupil_mm, dt_secs)) in frames.into_iter().enumerate() {
            let input = FrameInput {
                gaze_uv,
                pupil_mm,
                dt_secs,
            };
            let a = fast.process(img, &input, &mut out_fast).unwrap();
            let b = slow.process(img, &input, &mut out_slow).unwrap();
            let c = ring.process(img, &input, &mut out_ring).unwrap();
            assert_eq!(a.adaptation_cd_m2, c.adaptation_cd_m2);
            assert!(
                out_ring.rgba8 == out_fast.rgba8,
                "{what} frame {n}: the frame made in rings differs from the kept one"
            );
            assert_eq!(ring.retinal().pixels.len(), 0);
            assert_eq!(a.psf_rebuilt, b.psf_rebuilt);
            let state = fast.adaptation().unwrap();
            light_adapting += usize::from(state.light_target_cd_m2 > state.luminance_cd_m2);
            assert!(
                (a.target_cd_m2 / b.target_cd_m2 - 1.0).abs() < 1e-5,
                "{what} frame {n}: pooled {} vs {}",
                a.target_cd_m2,
                b.target_cd_m2
            );
            assert!((a.adaptation_cd_m2 / b.adaptation_cd_m2 - 1.0).abs() < 1e-5);
            for (i, (p, q)) in out_fast.rgba8.iter().zip(&out_slow.rgba8).enumerate() {
                assert!(
                    p.abs_diff(*q) <= 1,
                    "{what} frame {n}: byte {i} (pixel {}, {}) {p} vs {q}",
                    (i / 4) % w,
                    i / 4 / w
                );
                differing += usize::from(p != q);
            }
            // The retinal image (after glare and acuity, cd/m²).
            for (p, q) in fast.retinal().pixels.iter().zip(&slow.retinal().pixels) {
                // No data (NaN) in both.
                if crate::image::is_no_data(*p) && crate::image::is_no_data(*q) {
                    continue;
                }
                for c in 0..3 {
                    assert!(
                        (p[c] - q[c]).abs() <= 2e-4 * q[c].abs().max(1e-3),
                        "{what} frame {n}: retinal {p:?} vs {q:?}"
                    );
                }
            }
            if config.keep_display_linear {
                for (p, q) in fast.display.pixels.iter().zip(&slow.display.pixels) {
                    if crate::image::is_no_data(*p) && crate::image::is_no_data(*q) {
                        continue;
                    }
                    for c in 0..3 {
                        assert!(
                            (p[c] - q[c]).abs() < 1e-5,
                            "{what} frame {n}: {p:?} vs {q:?}"
                        );
                    }
                }
            }
        }
        (differing, light_adapting)
    }

    fn config(
        tone: ToneModel,
        colour: ColourModel,
        acuity: AcuityModel,
        keep: bool,
    ) -> PipelineConfig {
        PipelineConfig {
            tone,
            colour,
            acuity,
            keep_display_linear: keep,
            ..PipelineConfig::default()
        }
    }

    /// Pass A block-averages only the blocks the pooling model reads
    /// ([`crate::pooling::PoolingModel::reach`]); the pooled luminance is
    /// bit for bit the one pooled from every block, for every model, on
    /// the real night view at 1440×1600 (default 8× blocks and 3×), gazes
    /// on the frame, at its corners, off it and NaN; blocks outside the
    /// reach keep whatever they held (here: garbage). The default Gaussian
    /// reads under a tenth of the blocks.
    #[test]
    fn pass_a_blocks_only_what_pooling_reads() {
        let (w, h) = (1440, 1600);
        let (img, dpp) = view("night.exr", 1.0, -78.4, 90.0, w, h);
        for ds in [8usize, 3] {
            let (sw, sh) = (w.div_ceil(ds), h.div_ceil(ds));
            let mut all = vec![0.0f32; sw * sh];
            let mut all_valid = vec![0.0f32; sw * sh];
            let every = crate::pooling::PlaneRect { x: 0..sw, y: 0..sh };
            pass_a(Simd::host(), &img, &mut all, &mut all_valid, ds, sw, &every);
            for model in [
                PoolingModel::default(),
                PoolingModel::Gaussian { sigma_deg: 0.2 },
                PoolingModel::Eccentricity { e2_deg: 3.118 },
                PoolingModel::CentreWeight { follow_gaze: true },
                PoolingModel::GazeWindow {
                    size_deg: 40.0 / 13.85,
                },
                PoolingModel::PanoramaMean,
            ] {
                for gaze_px in [
                    [720.0, 1280.0],
                    [3.0, 1598.5],
                    [1439.9, 0.2],
                    [-200.0, 800.0],
                    [f64::NAN, 400.0],
                ] {
                    let small_gaze = [gaze_px[0] / ds as f64, gaze_px[1] / ds as f64];
                    let sdpp = dpp * ds as f64;
                    let blocks = model.reach(sw, sh, small_gaze, sdpp);
                    let mut some = vec![f32::NAN; sw * sh];
                    let mut some_valid = vec![f32::NAN; sw * sh];
                    pass_a(
                        Simd::host(),
                        &img,
                        &mut some,
                        &mut some_valid,
                        ds,
                        sw,
                        &blocks,
                    );
                    let want = model.pool(&all, sw, sh, small_gaze, sdpp);
                    let got = model.pool(&some, sw, sh, small_gaze, sdpp);
                    assert_eq!(
                        got.to_bits(),
                        want.to_bits(),
                        "{model:?}, {ds}x blocks, gaze {gaze_px:?}: {got} vs {want}"
                    );
                    if model == PoolingModel::default() && gaze_px == [720.0, 1280.0] {
                        let n = blocks.x.len() * blocks.y.len();
                        assert!(n * 10 < sw * sh, "{n} of {} blocks", sw * sh);
                    }
                }
            }
        }
    }

    /// Pooling runs on the `pooling_downsample`² block means of pass A
    /// (8 × 8 by default), not on the full-resolution luminance. Against
    /// the full-resolution reference (`pooling_downsample = 1`, the same
    /// [`PoolingModel::pool`] on every pixel) on real views at the default
    /// display size, gaze on dark ground, on a lamp, on the sky, in a
    /// corner: the block mean is a box prefilter one block wide (1° at 8
    /// px/deg), which widens the default Gaussian (σ = 2°) by b²/12 in
    /// variance (≈ 1 %) and moves the gaze window's edges by at most half
    /// a block, so the pooled luminance may differ where it changes within
    /// a degree of the gaze. Asserted for the default Gaussian away from
    /// point sources (gaze on the ground, sky, corners; measured ≤ 3.5e-3,
    /// tolerance 1e-2); printed for the other models. **Known gap**: with
    /// the gaze 2–3σ from the street lamp (a source a few pixels wide) the
    /// 8 × 8 blocks put the lamp at its block's centre, where the Gaussian
    /// weight differs by up to ~50 % (measured 47 %, printed); block means
    /// that keep their light's centroid would fix it, in the GPU twin too.
    #[test]
    fn reduced_resolution_pooling_matches_full_resolution() {
        let (w, h) = (720, 800);
        let night = view("night.exr", 1.0, -78.4, 90.0, w, h);
        let city = view("city.exr", 1.0, 40.0, 90.0, w, h);
        let models = [
            PoolingModel::default(),
            PoolingModel::Eccentricity { e2_deg: 3.118 },
            PoolingModel::CentreWeight { follow_gaze: true },
            PoolingModel::GazeWindow {
                size_deg: 40.0 / 13.85,
            },
        ];
        for model in models {
            let mut worst = 0.0f64;
            for ((img, dpp), name) in [(&night, "night"), (&city, "city")] {
                let pooled = |ds: usize, gaze_uv: [f32; 2]| {
                    let config = PipelineConfig {
                        pooling: model,
                        pooling_downsample: Some(ds),
                        glare: GlareConfig {
                            enabled: false,
                            ..GlareConfig::default()
                        },
                        acuity: AcuityModel::None,
                        ..PipelineConfig::default()
                    };
                    let mut p = FramePipeline::new(config, w, h, *dpp).unwrap();
                    let input = FrameInput {
                        gaze_uv,
                        pupil_mm: 4.0,
                        dt_secs: 0.0,
                    };
                    p.process(img, &input, &mut DisplayFrame::new(w, h))
                        .unwrap()
                        .target_cd_m2
                };
                for gaze_uv in [
                    [0.5, 0.8],
                    [0.5, 0.45],
                    [0.3, 0.2],
                    [0.02, 0.97],
                    [0.71, 0.52],
                ] {
                    let full = pooled(1, gaze_uv);
                    let reduced = pooled(8, gaze_uv);
                    let rel = (reduced / full - 1.0).abs();
                    // The night view's lamp is near the centre of the frame.
                    let near_lamp = name == "night" && gaze_uv == [0.5, 0.45];
                    eprintln!(
                        "{model:?} {name} gaze {gaze_uv:?}: full {full:.4e}, 8x8 blocks {reduced:.4e} cd/m², \
                         {rel:.2e}{}",
                        if near_lamp { " (near the lamp)" } else { "" }
                    );
                    if !near_lamp {
                        worst = worst.max(rel);
                    }
                }
            }
            eprintln!("{model:?}: worst relative difference away from the lamp {worst:.2e}");
            if model == PoolingModel::default() {
                assert!(worst < 1e-2, "{model:?}: {worst}");
            }
        }
    }

    #[test]
    fn optimised_passes_match_the_reference_on_real_views() {
        // A dim night (scotopic: acuity blur, full scotopic shift) seen
        // through a narrow field so the blur is wider than a pixel, and a
        // daylight city at the headset's field (no blur).
        let (night, night_dpp) = view("night.exr", 1e-3, -78.4, 20.0, 180, 200);
        let (mut city, city_dpp) = view("city.exr", 50.0, 40.0, 104.0, 180, 200);
        // Values the pipeline must clean: ±∞, negative, subnormal; and NaN,
        // no data (left out of pooling, marked in the output).
        for (i, v) in [f32::NAN, f32::INFINITY, -5.0, 1e-40, f32::NEG_INFINITY]
            .into_iter()
            .enumerate()
        {
            city.pixels[1000 + 37 * i][i % 3] = v;
        }
        // Both views exercise the paths they are meant to.
        let probe = FramePipeline::new(PipelineConfig::default(), 180, 200, night_dpp)
            .unwrap()
            .process(
                &night,
                &FrameInput {
                    gaze_uv: [0.5, 0.45],
                    pupil_mm: 4.0,
                    dt_secs: 0.0,
                },
                &mut DisplayFrame::new(180, 200),
            )
            .unwrap();
        assert!(
            probe.acuity_sigma_px > AcuityBlur::MIN_SIGMA_PX,
            "{probe:?}"
        );
        // Per pixel: the night view's dark pixels blur.
        let mut blur = AcuityBlur::new(&AcuityModel::default(), 180, 200, night_dpp);
        let mut blurred = night.clone();
        let changed = blur.apply(&mut blurred);
        eprintln!("night view: {changed} of 36000 px blurred");
        assert!(changed > 36000 / 4, "{changed}");

        let mut total = 0;
        let mut light_adapting_frames = 0;
        for (img, dpp, name) in [(&night, night_dpp, "night"), (&city, city_dpp, "city")] {
            for tone in [
                ToneModel::default(),
                ToneModel::naka_rushton(),
                ToneModel::gaze_exposure(),
            ] {
                for colour in [
                    ColourModel::ScotopicShift,
                    ColourModel::Discrimination,
                    ColourModel::Both,
                    ColourModel::None,
                ] {
                    for (acuity, keep) in [
                        (AcuityModel::default(), false),
                        (AcuityModel::LarsonKrawczyk, false),
                        (AcuityModel::None, false),
                        (AcuityModel::None, true),
                    ] {
                        let what = format!("{name} {tone:?} {colour:?} {acuity:?} keep {keep}");
                        let mut cfg = config(tone, colour, acuity, keep);
                        if name == "city" {
                            // p^dt with the light-adaptation overshoot (000 eq 7–8).
                            cfg.temporal = TemporalModel::power_dt();
                        }
                        let (d, l) = compare(&cfg, img, dpp, &what);
                        total += d;
                        light_adapting_frames += l;
                    }
                }
            }
        }
        // Off-by-one bytes come only from rounding at table-entry edges.
        let bytes = 2 * 3 * 4 * 4 * 4 * 180 * 200 * 4;
        eprintln!("bytes differing by 1: {total} of {bytes}");
        assert!(total * 1000 < bytes, "{total} of {bytes} bytes differ");
        assert!(light_adapting_frames > 0, "no frame used 000 eq 10");
    }
}
