//! Analysis at study speed (issue 47): the numbers of a `render` or
//! `replay` that writes no image, without the image pipeline.
//!
//! A replay's head does not move, so its view of the scene is the same
//! image every frame; what changes is the gaze and the pupil. Every number
//! of a timeline row that is not a stage's wall-clock time depends on the
//! image only through the block-mean luminance plane that pooling reads,
//! and that plane is the same every frame. [`AnalysisStep`] computes it
//! once ([`BlockPlane`], the pipeline's pass A over every block, the same
//! f32 arithmetic in the same order) and then steps, per frame and view,
//! exactly what [`gazelight_vision::pipeline::FramePipeline::process`]
//! computes for the row: the pooled target at the gaze (the pooling model
//! on the plane; the last target where it reaches no data), the temporal
//! adaptation, the kernel policy's PSF pupil and rebuild flag (which
//! kernel the pipeline would build, not the kernel), the acuity σ at the
//! adaptation luminance; and, as [`crate::frame::FrameStep`] does, the
//! eyes' mean adaptation fed back to the filter chain's pupil model. The
//! rows are [`crate::frame::Step`]s, so the pupil light response
//! ([`crate::pupil_light::PupilLight::apply`]), the glare numbers and the
//! timeline writer take them unchanged.
//!
//! What it leaves out: the stage timings (`pooling_ms` … `total_ms`) are
//! the image pipeline's wall-clock times; no stage runs, so they are NaN
//! (empty cells in `timeline.csv`). Every other column equals the CPU
//! pipeline's bit for bit (test: `crates/gazelight/tests/analysis_path.rs`,
//! the same replay both ways).
//!
//! A contact sheet needs a dozen frames drawn: [`SheetFrames`] draws a
//! chosen frame with the CPU pipeline put into the state the numbers
//! carried (adaptation, last target, kernel), so its image is the one the
//! full path draws for that frame.

use gazelight_tracker::{EyeState, Sample};
use gazelight_vision::RgbImage;
use gazelight_vision::image::{is_no_data, luminance};
use gazelight_vision::kernel_policy::{INITIAL_PUPIL_MM, KernelFollower, KernelPolicy};
use gazelight_vision::pipeline::{
    DisplayFrame, FrameInput, FramePipeline, FrameStats, PipelineConfig, StageTimings,
};
use gazelight_vision::pooling::{PlaneAngles, PoolingModel};
use gazelight_vision::psf::PsfBuilder;
use gazelight_vision::scene::{PanoramaView, ViewParams};
use gazelight_vision::temporal::AdaptationState;

use crate::RenderError;
use crate::feed::SampleFeed;
use crate::frame::{Step, View, place_side_by_side, view_row, views};

/// The stage timings of a row no image pipeline made: every one NaN (an
/// empty cell).
pub const NO_TIMINGS: StageTimings = StageTimings {
    pooling_ms: f64::NAN,
    temporal_ms: f64::NAN,
    psf_ms: f64::NAN,
    glare_ms: f64::NAN,
    acuity_ms: f64::NAN,
    tone_colour_encode_ms: f64::NAN,
    total_ms: f64::NAN,
};

/// The block-mean luminance plane of a view, as the pipeline's pass A
/// makes it (`gazelight_vision::pipeline`), over every block at once: per
/// block, each pixel row's luminances of the sanitised pixels summed in
/// order from 0 and added to the block's sum, then divided by the block's
/// pixels; the share of pixels with data likewise. The pooling model then
/// reads it at any gaze.
pub struct BlockPlane {
    lum: Vec<f32>,
    valid: Vec<f32>,
    width: usize,
    height: usize,
    small_w: usize,
    small_h: usize,
    ds: usize,
    /// The plane's geometry (the view's projection, downsampled).
    angles: PlaneAngles,
}

/// The pipeline's `sanitize`: NaN, ±∞, negative and subnormal values → 0.
#[inline]
fn sanitize(v: f32) -> f32 {
    if (f32::MIN_POSITIVE..f32::INFINITY).contains(&v) {
        v
    } else {
        0.0
    }
}

impl BlockPlane {
    /// The plane of `view_img` (cd/m²) in blocks of `ds` (the pipeline's
    /// `pooling_downsample`, 8 by default) for a rectilinear view whose
    /// edges lie at the tangents `tan_lrud`.
    pub fn new(view_img: &RgbImage, ds: usize, tan_lrud: [f64; 4]) -> Self {
        let (w, h) = (view_img.width, view_img.height);
        let ds = ds.max(1);
        let (small_w, small_h) = (w.div_ceil(ds), h.div_ceil(ds));
        let mut lum = vec![0.0f32; small_w * small_h];
        let mut valid = vec![0.0f32; small_w * small_h];
        if w > 0 && view_img.pixels.len() == w * h {
            for (by, rows) in view_img.pixels.chunks(w * ds).enumerate() {
                let lum_row = &mut lum[by * small_w..(by + 1) * small_w];
                let valid_row = &mut valid[by * small_w..(by + 1) * small_w];
                let n_rows = rows.len() / w;
                for srow in rows.chunks_exact(w) {
                    for ((blk, acc), n) in srow
                        .chunks(ds)
                        .zip(lum_row.iter_mut())
                        .zip(valid_row.iter_mut())
                    {
                        let mut sum = 0.0f32;
                        for p in blk {
                            sum += luminance(p.map(sanitize));
                        }
                        *acc += sum;
                        *n += blk.iter().filter(|p| !is_no_data(**p)).count() as f32;
                    }
                }
                for (k, (v, a)) in lum_row.iter_mut().zip(valid_row.iter_mut()).enumerate() {
                    let cols = (w - k * ds).min(ds);
                    *v /= (cols * n_rows) as f32;
                    *a /= (cols * n_rows) as f32;
                }
            }
        }
        let angles = PlaneAngles::Rectilinear {
            tan_lrud,
            extent_px: [w as f64, h as f64],
        }
        .downsampled(ds);
        Self {
            lum,
            valid,
            width: w,
            height: h,
            small_w,
            small_h,
            ds,
            angles,
        }
    }

    /// `pooling`'s luminance at `gaze_uv` (clamped onto the view, a
    /// non-finite coordinate at the centre, as the pipeline does), cd/m²;
    /// `None` where it reaches no pixel with data.
    pub fn pool(&self, pooling: &PoolingModel, gaze_uv: [f32; 2]) -> Option<f64> {
        let c = |v: f32| {
            if v.is_finite() {
                v.clamp(0.0, 1.0)
            } else {
                0.5
            }
        };
        let gaze_px = [
            f64::from(c(gaze_uv[0])) * self.width as f64,
            f64::from(c(gaze_uv[1])) * self.height as f64,
        ];
        let small_gaze = [gaze_px[0] / self.ds as f64, gaze_px[1] / self.ds as f64];
        pooling.pool_valid_in(
            &self.lum,
            &self.valid,
            self.small_w,
            self.small_h,
            small_gaze,
            self.angles,
        )
    }
}

/// What a view's pipeline carries from frame to frame, as far as its
/// numbers go.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct ViewCarry {
    /// The adaptation state (`None` before the first frame).
    pub state: Option<AdaptationState>,
    /// The pooled target held where a gaze's pooling reaches no data.
    pub last_target_cd_m2: f64,
    /// The pupil the view's kernel is built for, mm.
    pub psf_pupil_mm: f64,
}

/// The numbers-only twin of [`crate::frame::FrameStep`]: the same rows
/// (stage timings NaN) and the same state fed back to the filter chain,
/// from the view's block plane computed once (see the module docs).
pub struct AnalysisStep {
    views: &'static [View],
    config: PipelineConfig,
    plane: BlockPlane,
    deg_per_px: f64,
    /// Which kernel each view's pipeline would build (`None`: glare off):
    /// the one follower of the kernel rule, as the pipeline (one view) and
    /// [`crate::frame::StereoKernels`] (two) keep it.
    kernels: Option<KernelFollower>,
    carry: [ViewCarry; 2],
    /// The carry before the last step (what a pipeline had before drawing
    /// that frame), and whether each view's pooling reached data then.
    before: [ViewCarry; 2],
    reached: [bool; 2],
    stereo_builds: u64,
    last_adaptation: Option<f64>,
    own_gaze_frames: [usize; 2],
    t0_secs: f64,
    dt_secs: f64,
    next: usize,
}

impl AnalysisStep {
    /// The numbers of [`crate::frame::FrameStep::new`]`(…, stereo,
    /// config, view, t0_secs, fps, …)` on the view's image `view_img`
    /// (cd/m²).
    pub fn new(
        stereo: bool,
        config: &PipelineConfig,
        view: &ViewParams,
        view_img: &RgbImage,
        t0_secs: f64,
        fps: f64,
    ) -> Result<Self, RenderError> {
        config.validate()?;
        if view_img.width != view.width || view_img.height != view.height {
            return Err(RenderError::Pipeline(format!(
                "analysis: a {}x{} view image for a {}x{} view",
                view_img.width, view_img.height, view.width, view.height
            )));
        }
        let views = views(stereo);
        let tans = PanoramaView::new(*view)?.frustum_tans();
        let ds = config.pooling_downsample.unwrap_or(8);
        let plane = BlockPlane::new(view_img, ds, tans);
        // The first frame's fallback light, as FrameStep sets it
        // (`FramePipeline::set_initial_target` ignores a value that is not
        // finite and ≥ 0: the pipeline's 0 stays).
        let field = crate::pupil_light::field_mean_cd_m2(view_img, tans, 1);
        let initial = if field.is_finite() && field >= 0.0 {
            field
        } else {
            0.0
        };
        let kernels = config.glare.enabled.then(|| {
            KernelFollower::new(
                KernelPolicy::new(&config.glare),
                views.len(),
                INITIAL_PUPIL_MM,
            )
        });
        let carry = ViewCarry {
            state: None,
            last_target_cd_m2: initial,
            psf_pupil_mm: INITIAL_PUPIL_MM,
        };
        Ok(Self {
            views,
            config: config.clone(),
            plane,
            deg_per_px: view.deg_per_px(),
            kernels,
            carry: [carry; 2],
            before: [carry; 2],
            reached: [true; 2],
            stereo_builds: 0,
            last_adaptation: None,
            own_gaze_frames: [0; 2],
            t0_secs,
            dt_secs: 1.0 / fps,
            next: 0,
        })
    }

    /// The next frame's numbers: the eye state at its time from `feed`,
    /// each view's row as the pipeline would give it (stage timings NaN).
    pub fn step<I: Iterator<Item = Sample>>(
        &mut self,
        feed: &mut SampleFeed<I>,
    ) -> Result<Step, RenderError> {
        let i = self.next;
        let n_views = self.views.len();
        let t_secs = self.t0_secs + i as f64 * self.dt_secs;
        let state: EyeState = feed.state(t_secs, self.last_adaptation);
        let dt = if i == 0 { 0.0 } else { self.dt_secs as f32 };
        let inputs: Vec<(FrameInput, bool)> =
            self.views.iter().map(|v| v.input(&state, dt)).collect();
        for (k, v) in self.views.iter().enumerate().take(2) {
            if let View::Eye(e) = v
                && state.eyes.get(*e).is_some_and(|c| c.gaze_valid)
            {
                self.own_gaze_frames[k] += 1;
            }
        }
        self.before = self.carry;
        // The kernels (which pupil each view's kernel is for, and whether
        // it changed this frame), decided as the pipelines decide them.
        let mut rebuilt = [false; 2];
        if let Some(follower) = self.kernels.as_mut() {
            let pupil = |k: usize| inputs.get(k).map_or(f32::NAN, |(i, _)| i.pupil_mm);
            let wanted = follower.follow([pupil(0), pupil(1)]);
            // Two eyes sharing one kernel build it once.
            self.stereo_builds += match wanted {
                [Some(p), Some(q)] if p == q => 1,
                w => w.iter().flatten().count() as u64,
            };
            for (k, w) in wanted.into_iter().enumerate().take(n_views) {
                // A builder asked for a pupil in its range builds for it
                // (`PsfBuilder::rebuild` clamps to the range the rule has
                // clamped to).
                if let Some(p) = w {
                    self.carry[k].psf_pupil_mm = p;
                    rebuilt[k] = true;
                }
            }
        }
        let mut log_adaptation = 0.0;
        let mut rows = Vec::with_capacity(n_views);
        for (k, (input, _)) in inputs.iter().enumerate() {
            let c = &mut self.carry[k];
            let pooled = self.plane.pool(&self.config.pooling, input.gaze_uv);
            self.reached[k] = pooled.is_some();
            let target_cd_m2 = pooled.unwrap_or(c.last_target_cd_m2).max(0.0);
            c.last_target_cd_m2 = target_cd_m2;
            let dt_secs = if input.dt_secs.is_finite() {
                f64::from(input.dt_secs.max(0.0))
            } else {
                0.0
            };
            let adaptation = match c.state {
                Some(s) => self.config.temporal.step(s, target_cd_m2, dt_secs),
                None => AdaptationState::new(target_cd_m2),
            };
            c.state = Some(adaptation);
            let stats = FrameStats {
                target_cd_m2,
                adaptation_cd_m2: adaptation.luminance_cd_m2,
                psf_pupil_mm: c.psf_pupil_mm,
                psf_rebuilt: rebuilt[k],
                acuity_sigma_px: self
                    .config
                    .acuity
                    .sigma_px(adaptation.luminance_cd_m2, self.deg_per_px),
                timings: NO_TIMINGS,
            };
            log_adaptation += stats.adaptation_cd_m2.max(1e-9).ln() / n_views as f64;
            let pupil = self.views[k].pupil(&state);
            rows.push(view_row(t_secs - self.t0_secs, input, &pupil, stats));
        }
        self.last_adaptation = Some(log_adaptation.exp());
        self.next += 1;
        Ok(Step {
            index: i,
            t_secs,
            state,
            inputs,
            rows,
        })
    }

    /// Frames stepped so far (the next frame's index).
    pub fn frames_rendered(&self) -> usize {
        self.next
    }

    /// The views, in display order.
    pub fn views(&self) -> &'static [View] {
        self.views
    }

    /// Kernels the stereo plan would have built (`None` in mono or with
    /// glare off), as [`crate::frame::FrameStep::stereo_kernel_builds`].
    pub fn stereo_kernel_builds(&self) -> Option<u64> {
        (self.kernels.is_some() && self.views.len() == 2).then_some(self.stereo_builds)
    }

    /// Stereo: frames in which each view (left, right) had its eye's own
    /// gaze.
    pub fn own_gaze_frames(&self) -> [usize; 2] {
        self.own_gaze_frames
    }

    /// Each view's carry before the last step and after it (its kernel's
    /// pupil for that frame), and whether its pooling reached data: what
    /// [`SheetFrames`] puts a pipeline into to draw that frame.
    fn last_frame(&self, k: usize) -> (ViewCarry, ViewCarry, bool) {
        (self.before[k], self.carry[k], self.reached[k])
    }
}

/// Draws chosen frames of an [`AnalysisStep`] (a contact sheet's) with the
/// CPU pipeline: before each, every view's pipeline is put into the state
/// the numbers carried into that frame (its adaptation, the target it
/// holds, the kernel for that frame's PSF pupil), so the frame is the one
/// the full path draws. A pipeline is made anew where only a new one can
/// take that state (the first frame; a frame whose pooling reaches no
/// data, which holds a target only a fresh pipeline can be given).
pub struct SheetFrames {
    config: PipelineConfig,
    view: ViewParams,
    pipelines: Vec<Option<FramePipeline>>,
    /// The pupil each pipeline's installed kernel is built for, mm.
    installed_mm: [f64; 2],
    builder: Option<PsfBuilder>,
    eye_out: Vec<DisplayFrame>,
    composed: DisplayFrame,
}

impl SheetFrames {
    /// For the views of `analysis`, `config`'s pipeline on `view`.
    pub fn new(
        analysis: &AnalysisStep,
        config: &PipelineConfig,
        view: &ViewParams,
    ) -> Result<Self, RenderError> {
        let n = analysis.views().len();
        let builder = if config.glare.enabled {
            let mut params = config.glare.psf.clone();
            // As the pipelines' own builders: same size and pixel size.
            params.ppd = 1.0 / view.deg_per_px();
            params.pupil_mm = INITIAL_PUPIL_MM;
            Some(PsfBuilder::new(params)?)
        } else {
            None
        };
        Ok(Self {
            config: PipelineConfig {
                keep_retinal: false,
                keep_display_linear: false,
                ..config.clone()
            },
            view: *view,
            pipelines: (0..n).map(|_| None).collect(),
            installed_mm: [INITIAL_PUPIL_MM; 2],
            builder,
            eye_out: (0..n)
                .map(|_| DisplayFrame::new(view.width, view.height))
                .collect(),
            composed: DisplayFrame::new(view.width * n, if n > 1 { view.height } else { 0 }),
        })
    }

    /// Draws the frame `analysis` stepped last (`step`, what its
    /// [`AnalysisStep::step`] returned) on `view_img`; the display frame
    /// (stereo: left | right).
    pub fn draw(
        &mut self,
        analysis: &AnalysisStep,
        step: &Step,
        view_img: &RgbImage,
    ) -> Result<&DisplayFrame, RenderError> {
        let n = self.pipelines.len();
        for k in 0..n {
            let (before, after, reached) = analysis.last_frame(k);
            let Some((input, _)) = step.inputs.get(k) else {
                return Err(RenderError::Pipeline("a frame without its views".into()));
            };
            let fresh = before.state.is_none() || !reached;
            let slot = &mut self.pipelines[k];
            if fresh || slot.is_none() {
                let mut p = FramePipeline::new(
                    self.config.clone(),
                    self.view.width,
                    self.view.height,
                    self.view.deg_per_px(),
                )?;
                p.set_view_frustum(PanoramaView::new(self.view)?.frustum_tans())?;
                p.set_psf_auto_rebuild(false);
                p.set_initial_target(before.last_target_cd_m2);
                self.installed_mm[k] = INITIAL_PUPIL_MM;
                *slot = Some(p);
            }
            let Some(p) = slot.as_mut() else {
                continue;
            };
            if let Some(s) = before.state {
                p.set_adaptation(s);
            }
            if let Some(b) = self.builder.as_mut()
                && self.installed_mm[k] != after.psf_pupil_mm
            {
                p.set_kernel(b.try_rebuild(after.psf_pupil_mm)?)?;
                self.installed_mm[k] = after.psf_pupil_mm;
            }
            p.process(view_img, input, &mut self.eye_out[k])?;
            if n > 1 {
                place_side_by_side(
                    &self.eye_out[k].rgba8,
                    &mut self.composed.rgba8,
                    self.view.width * 4,
                    k,
                    n,
                );
            }
        }
        Ok(if n > 1 {
            &self.composed
        } else {
            &self.eye_out[0]
        })
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    /// The plane is the mean luminance of each block's pixels with data
    /// (summed by hand here), and its share of them; an edge block over
    /// the pixels it has.
    #[test]
    fn block_plane_is_each_blocks_mean() {
        let (w, h) = (10usize, 5usize);
        let mut img = RgbImage::new(w, h);
        for (i, p) in img.pixels.iter_mut().enumerate() {
            let v = (i % 7) as f32 + 0.5;
            *p = [v, 2.0 * v, 0.5 * v];
        }
        img.pixels[3] = gazelight_vision::scene::NO_DATA_RGB;
        let plane = BlockPlane::new(&img, 4, [-1.0, 1.0, 0.5, -0.5]);
        assert_eq!((plane.small_w, plane.small_h), (3, 2));
        for by in 0..2 {
            for bx in 0..3 {
                let (mut sum, mut n, mut with_data) = (0.0f64, 0usize, 0usize);
                for y in by * 4..((by + 1) * 4).min(h) {
                    for x in bx * 4..((bx + 1) * 4).min(w) {
                        let p = img.pixels[y * w + x];
                        n += 1;
                        if p[0].is_nan() {
                            continue;
                        }
                        with_data += 1;
                        // Y of linear RGB, 001 eq 1's weights.
                        sum += 0.2125 * f64::from(p[0])
                            + 0.7154 * f64::from(p[1])
                            + 0.0721 * f64::from(p[2]);
                    }
                }
                let k = by * 3 + bx;
                let got = f64::from(plane.lum[k]);
                assert!((got - sum / n as f64).abs() < 1e-5, "{bx},{by}: {got}");
                let share = with_data as f64 / n as f64;
                assert!((f64::from(plane.valid[k]) - share).abs() < 1e-6);
            }
        }
        assert!(plane.valid[0] < 1.0);
    }
}
