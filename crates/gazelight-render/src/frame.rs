//! The per-frame step of `render` and `replay`: the filtered eye state at
//! the frame's time → each view's pipeline input → the frame pipelines →
//! the display frame and each view's timeline row.
//!
//! Stereo (`--stereo`): one frame pipeline per eye, each on that eye's own
//! gaze and pupil, so pooling, adaptation, glare and acuity all run per
//! eye; the two frames are composed side by side, left | right. The two
//! eyes share one glare kernel while their pupils agree (within
//! `psf_rebuild_threshold_mm`, 0.1 mm by default: the kernel is built once,
//! at their mean, and installed in both pipelines) and get one each when
//! the pupils part (`gazelight_vision::kernel_policy`). The pipelines never
//! rebuild kernels themselves in stereo; [`StereoKernels`] does.
//!
//! A panorama lies at infinity, so an eye offset of ±IPD/2 moves nothing in
//! it: both eyes see the same view of the panorama, and what differs per
//! eye is gaze, pupil, kernel and adaptation. (An OpenXR runtime gives each
//! eye its own pose and field of view.)
//!
//! The pipelines are anything that renders a view ([`ViewRenderer`]): the
//! CPU reference pipeline here, and the CLI's renderer, which picks the GPU
//! or the CPU (`--backend`).

use gazelight_tracker::{EYE_LEFT, EYE_RIGHT, EyeState, PupilUnit, Sample};
use gazelight_vision::RgbImage;
use gazelight_vision::kernel_policy::{KernelFollower, KernelPolicy};
use gazelight_vision::pipeline::{
    DisplayFrame, FrameInput, FramePipeline, FrameStats, PipelineConfig,
};
use gazelight_vision::psf::{PsfBuilder, PsfKernel};
use gazelight_vision::scene::{PanoramaView, ViewParams};

use crate::RenderError;
use crate::feed::SampleFeed;
use crate::timeline::TimelineRow;

/// One view of a frame: which eye it is for.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum View {
    /// One view for both eyes (the binocular gaze and pupil).
    Both,
    /// An eye of a stereo frame: [`EYE_RIGHT`] or [`EYE_LEFT`].
    Eye(usize),
}

/// A mono frame's one view.
pub const MONO: [View; 1] = [View::Both];
/// A stereo frame's views in display order: left | right.
pub const STEREO: [View; 2] = [View::Eye(EYE_LEFT), View::Eye(EYE_RIGHT)];

impl View {
    /// The suffix of this view's `timeline.csv` columns ("" for one view).
    pub fn suffix(self) -> &'static str {
        match self {
            View::Both => "",
            View::Eye(EYE_LEFT) => "_left",
            View::Eye(_) => "_right",
        }
    }

    /// The pipeline's input for this view from the filtered state (its
    /// pupil is the model aperture), and whether nothing is measured for
    /// the view now ([`Self::pupil`]).
    pub fn input(self, state: &EyeState, dt_secs: f32) -> (FrameInput, bool) {
        let held = self.pupil(state).measured.is_none();
        match self {
            View::Both => (
                FrameInput {
                    gaze_uv: state.gaze_uv,
                    pupil_mm: state.pupil_mm(),
                    dt_secs,
                },
                held,
            ),
            View::Eye(e) => (
                FrameInput {
                    gaze_uv: state.eye_gaze_uv(e),
                    pupil_mm: state.eye_pupil_mm(e),
                    dt_secs,
                },
                held,
            ),
        }
    }

    /// The index [`EyeState::view_measured`] takes for this view.
    fn eye_index(self) -> usize {
        match self {
            View::Both => usize::MAX,
            View::Eye(e) => e,
        }
    }

    /// What this view's pupil columns carry: its measured pupil now (the
    /// view's own eye, or mono the mean of the eyes measured now) and
    /// whether the recording has its eye at all.
    pub fn pupil(self, state: &EyeState) -> ViewPupil {
        let i = self.eye_index();
        ViewPupil {
            measured: state.view_measured(i),
            map_mm: state.view_measured_map_mm(i),
            present: state.view_present(i),
        }
    }
}

/// A view's measured pupil at a frame ([`View::pupil`]).
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct ViewPupil {
    /// The measured pupil and its unit; `None` where nothing is measured.
    pub measured: Option<(f32, PupilUnit)>,
    /// A raw measured pupil through the black/white map, mm of the map.
    pub map_mm: Option<f32>,
    /// Whether the source has the view's eye (mono: either eye).
    pub present: bool,
}

impl ViewPupil {
    /// The measured pupil in mm (NaN where none or not in mm).
    pub fn mm(&self) -> f32 {
        match self.measured {
            Some((v, PupilUnit::Mm)) => v,
            _ => f32::NAN,
        }
    }

    /// The measured pupil in a raw unit (NaN where none or in mm).
    pub fn raw(&self) -> f32 {
        match self.measured {
            Some((v, u)) if u != PupilUnit::Mm => v,
            _ => f32::NAN,
        }
    }

    /// `pupil_held`: true where nothing is measured, `None` for an eye the
    /// source does not have.
    pub fn held(&self) -> Option<bool> {
        self.present.then_some(self.measured.is_none())
    }
}

/// The views of a mono or a stereo frame.
pub fn views(stereo: bool) -> &'static [View] {
    if stereo { &STEREO } else { &MONO }
}

/// A frame pipeline that renders one view: what the frame step needs of it.
pub trait ViewRenderer {
    /// Renders the views of one frame, one renderer and output per view;
    /// each result is written into `stats` at its view's index. A renderer
    /// may leave its frame on its device until [`Self::read_frame`].
    fn render_views(
        eyes: &mut [(&mut Self, &mut DisplayFrame)],
        view: &RgbImage,
        inputs: &[FrameInput],
        stats: &mut [FrameStats],
    ) -> Result<(), RenderError>
    where
        Self: Sized;
    /// Brings the last rendered frame to the host in `out`.
    fn read_frame(&mut self, out: &mut DisplayFrame) -> Result<(), RenderError>;
    /// Copies the last frame's retinal image (linear RGB in cd/m² after
    /// glare and acuity, before tone mapping) into `out`.
    fn retinal(&mut self, out: &mut RgbImage) -> Result<(), RenderError>;
    /// The current PSF kernel (`None` with glare off).
    fn psf_kernel(&mut self) -> Result<Option<&PsfKernel>, RenderError>;
    /// Whether a frame rebuilds the PSF itself when the pupil moves.
    fn set_psf_auto_rebuild(&mut self, on: bool);
    /// Installs a kernel built elsewhere with the pipeline's PSF parameters.
    fn set_kernel(&mut self, kernel: &PsfKernel) -> Result<(), RenderError>;
    /// The light (cd/m²) the first frame adapts to when its pooling
    /// reaches no data (`FramePipeline::set_initial_target`).
    fn set_initial_target(&mut self, cd_m2: f64);
}

/// The CPU reference pipeline. A stereo pair runs side by side on the
/// rayon pool (`rayon::join`): each pipeline's own parallel passes share
/// the same threads, so one eye's serial parts overlap the other eye's
/// work.
impl ViewRenderer for FramePipeline {
    fn render_views(
        eyes: &mut [(&mut Self, &mut DisplayFrame)],
        view: &RgbImage,
        inputs: &[FrameInput],
        stats: &mut [FrameStats],
    ) -> Result<(), RenderError> {
        if let ([(a, out_a), (b, out_b)], [in_a, in_b]) = (&mut *eyes, inputs) {
            let (ra, rb) = rayon::join(
                || a.process(view, in_a, out_a),
                || b.process(view, in_b, out_b),
            );
            if let Some(s) = stats.get_mut(0) {
                *s = ra?;
            }
            if let Some(s) = stats.get_mut(1) {
                *s = rb?;
            }
            return Ok(());
        }
        for (((p, out), input), s) in eyes.iter_mut().zip(inputs).zip(stats.iter_mut()) {
            *s = p.process(view, input, out)?;
        }
        Ok(())
    }

    fn read_frame(&mut self, _out: &mut DisplayFrame) -> Result<(), RenderError> {
        Ok(())
    }

    fn retinal(&mut self, out: &mut RgbImage) -> Result<(), RenderError> {
        let img = FramePipeline::retinal(self);
        if img.pixels.is_empty() {
            return Err(RenderError::Pipeline(
                "the CPU pipeline was built without keep_retinal: no retinal image to read".into(),
            ));
        }
        if out.width != img.width || out.height != img.height {
            *out = RgbImage::new(img.width, img.height);
        }
        out.pixels.copy_from_slice(&img.pixels);
        Ok(())
    }

    fn psf_kernel(&mut self) -> Result<Option<&PsfKernel>, RenderError> {
        Ok(FramePipeline::psf_kernel(self))
    }

    fn set_psf_auto_rebuild(&mut self, on: bool) {
        FramePipeline::set_psf_auto_rebuild(self, on);
    }

    fn set_kernel(&mut self, kernel: &PsfKernel) -> Result<(), RenderError> {
        Ok(FramePipeline::set_kernel(self, kernel)?)
    }

    fn set_initial_target(&mut self, cd_m2: f64) {
        FramePipeline::set_initial_target(self, cd_m2);
    }
}

/// One CPU pipeline per view of `view` (pooling measures angles through
/// the view's projection), with `config`.
pub fn cpu_pipelines(
    config: &PipelineConfig,
    view: &ViewParams,
    stereo: bool,
) -> Result<Vec<FramePipeline>, RenderError> {
    views(stereo)
        .iter()
        .map(|_| {
            let mut p =
                FramePipeline::new(config.clone(), view.width, view.height, view.deg_per_px())?;
            p.set_view_frustum(PanoramaView::new(*view)?.frustum_tans())?;
            Ok(p)
        })
        .collect()
}

/// Builds the two eyes' kernels (on the calling thread: `render` and
/// `replay` are offline) and installs them.
pub struct StereoKernels {
    builder: PsfBuilder,
    /// The pupil each eye's installed kernel was built for, and the rule.
    follower: KernelFollower,
    /// Kernels built so far.
    pub builds: u64,
}

impl StereoKernels {
    /// Takes over kernel building from both renderers (`None` with glare
    /// off). Both start with the renderers' initial kernel, which is one
    /// shared kernel.
    pub fn new<R: ViewRenderer>(
        config: &PipelineConfig,
        deg_per_px: f64,
        renderers: &mut [R],
    ) -> Result<Option<Self>, RenderError> {
        let [first, _] = renderers else {
            return Err(RenderError::Pipeline(format!(
                "stereo kernels: {} renderers, expected 2",
                renderers.len()
            )));
        };
        let Some(initial_mm) = first.psf_kernel()?.map(|k| k.pupil_mm) else {
            return Ok(None);
        };
        let mut params = config.glare.psf.clone();
        // As the pipelines' own builders: same size and pixel size.
        params.ppd = 1.0 / deg_per_px;
        params.pupil_mm = initial_mm;
        let builder = PsfBuilder::new(params)?;
        for r in renderers.iter_mut() {
            r.set_psf_auto_rebuild(false);
        }
        Ok(Some(Self {
            builder,
            follower: KernelFollower::new(KernelPolicy::new(&config.glare), 2, initial_mm),
            builds: 0,
        }))
    }

    /// Brings each eye's kernel up to date for `inputs` (the two eyes'
    /// frame inputs, in the order of `renderers`) and says which eye got a
    /// new kernel.
    pub fn update<R: ViewRenderer>(
        &mut self,
        inputs: [&FrameInput; 2],
        renderers: &mut [R],
    ) -> Result<[bool; 2], RenderError> {
        if renderers.len() != 2 {
            return Err(RenderError::Pipeline(format!(
                "stereo kernels: {} renderers, expected 2",
                renderers.len()
            )));
        }
        let mut changed = [false; 2];
        let wanted = self.follower.follow(inputs.map(|i| i.pupil_mm));
        if let [Some(p), Some(q)] = wanted
            && p == q
        {
            // Two eyes sharing one kernel: built once, installed in both.
            let kernel = self.builder.try_rebuild(p)?;
            self.builds += 1;
            for (e, r) in renderers.iter_mut().enumerate() {
                r.set_kernel(kernel)?;
                self.follower.built(e, kernel.pupil_mm);
                changed[e] = true;
            }
        } else {
            for (e, p) in wanted.into_iter().enumerate() {
                let Some(p) = p else { continue };
                let kernel = self.builder.try_rebuild(p)?;
                self.builds += 1;
                renderers[e].set_kernel(kernel)?;
                self.follower.built(e, kernel.pupil_mm);
                changed[e] = true;
            }
        }
        Ok(changed)
    }
}

/// A view's timeline row for its frame input, pupil and pipeline stats
/// (`t_rel_secs` from the first frame; no pupil light response yet: NaN,
/// which the caller may fill in). The full and the analysis path both
/// write their rows through it.
pub fn view_row(
    t_rel_secs: f64,
    input: &FrameInput,
    pupil: &ViewPupil,
    stats: FrameStats,
) -> TimelineRow {
    TimelineRow {
        t_secs: t_rel_secs,
        gaze_u: input.gaze_uv[0],
        gaze_v: input.gaze_uv[1],
        pupil_mm: pupil.mm(),
        pupil_raw: pupil.raw(),
        pupil_map_mm: pupil.map_mm.unwrap_or(f32::NAN),
        pupil_held: pupil.held(),
        aperture_mm: input.pupil_mm,
        stats,
        pupil_light_mm: f32::NAN,
        pupil_residual_mm: f32::NAN,
    }
}

/// Copies `src` (rows of `row_len` elements) into column `slot` of a
/// side-by-side image of `slots` such columns.
pub fn place_side_by_side<T: Copy>(
    src: &[T],
    dst: &mut [T],
    row_len: usize,
    slot: usize,
    slots: usize,
) {
    for (y, row) in src.chunks_exact(row_len).enumerate() {
        let o = (y * slots + slot) * row_len;
        dst[o..o + row_len].copy_from_slice(row);
    }
}

/// What one [`FrameStep::step`] rendered besides the frame itself.
#[derive(Clone, Debug)]
pub struct Step {
    /// The frame's index (0, 1, …).
    pub index: usize,
    /// The frame's time on the samples' clock, s.
    pub t_secs: f64,
    /// The filtered eye state it was rendered for.
    pub state: EyeState,
    /// Each view's pipeline input and whether its pupil was held or
    /// modelled.
    pub inputs: Vec<(FrameInput, bool)>,
    /// Each view's timeline row (its `t_secs` from the first frame; no
    /// pupil light response: NaN, which the caller may fill in).
    pub rows: Vec<TimelineRow>,
}

/// The frame loop's state: the views' pipelines and output buffers, the
/// stereo kernels, the adaptation fed back to the pupil model, the frame
/// clock. Frames are placed on the samples' clock at `fps` from `t0_secs`:
/// a render is deterministic and runs as fast as the pipeline allows.
pub struct FrameStep<R> {
    views: &'static [View],
    pipelines: Vec<R>,
    kernels: Option<StereoKernels>,
    eye_out: Vec<DisplayFrame>,
    composed: DisplayFrame,
    keep_retinal: bool,
    eye_retinal: RgbImage,
    retinal: RgbImage,
    last_adaptation: Option<f64>,
    /// The view's frustum (tangents left, right, up, down): the first
    /// frame's fallback light is the view's field mean over it.
    frustum_tans: [f64; 4],
    own_gaze_frames: [usize; 2],
    width: usize,
    t0_secs: f64,
    dt_secs: f64,
    next: usize,
}

impl<R: ViewRenderer> FrameStep<R> {
    /// A frame loop over `pipelines` (one per view of [`views`]`(stereo)`,
    /// built for `view`'s frames with `config`; with `keep_retinal` their
    /// retinal images are kept and composed too).
    pub fn new(
        mut pipelines: Vec<R>,
        stereo: bool,
        config: &PipelineConfig,
        view: &ViewParams,
        t0_secs: f64,
        fps: f64,
        keep_retinal: bool,
    ) -> Result<Self, RenderError> {
        let views = views(stereo);
        let n_views = views.len();
        let (width, height, deg_per_px) = (view.width, view.height, view.deg_per_px());
        if pipelines.len() != n_views {
            return Err(RenderError::Pipeline(format!(
                "{} frame pipelines for {n_views} views",
                pipelines.len()
            )));
        }
        let kernels = if n_views == 2 {
            StereoKernels::new(config, deg_per_px, &mut pipelines)?
        } else {
            None
        };
        let exr_w = if keep_retinal { width } else { 0 };
        let frustum_tans = PanoramaView::new(*view)?.frustum_tans();
        Ok(Self {
            views,
            pipelines,
            kernels,
            eye_out: views
                .iter()
                .map(|_| DisplayFrame::new(width, height))
                .collect(),
            composed: DisplayFrame::new(width * n_views, if n_views > 1 { height } else { 0 }),
            keep_retinal,
            eye_retinal: RgbImage::new(exr_w, height),
            retinal: RgbImage::new(exr_w * n_views, height),
            last_adaptation: None,
            frustum_tans,
            own_gaze_frames: [0; 2],
            width,
            t0_secs,
            dt_secs: 1.0 / fps,
            next: 0,
        })
    }

    /// Renders the next frame: the eye state at its time from `feed`, each
    /// view through its pipeline (the display frame is then
    /// [`Self::display`], the retinal image [`Self::retinal`]).
    pub fn step<I: Iterator<Item = Sample>>(
        &mut self,
        feed: &mut SampleFeed<I>,
        view_img: &RgbImage,
    ) -> Result<Step, RenderError> {
        let i = self.next;
        let n_views = self.views.len();
        let t_secs = self.t0_secs + i as f64 * self.dt_secs;
        let state = feed.state(t_secs, self.last_adaptation);
        let dt = if i == 0 { 0.0 } else { self.dt_secs as f32 };
        if i == 0 {
            // No first frame from an unset state: where the first gaze's
            // pooling reaches no data (outside the scene's field), the eye
            // starts adapted to the light measured in the rest of the view
            // (its solid-angle mean over every pixel with data: a few bright
            // lamps can carry a night view's mean), not 0 cd/m².
            let field_cd_m2 = crate::pupil_light::field_mean_cd_m2(view_img, self.frustum_tans, 1);
            for p in &mut self.pipelines {
                p.set_initial_target(field_cd_m2);
            }
        }
        let inputs: Vec<(FrameInput, bool)> =
            self.views.iter().map(|v| v.input(&state, dt)).collect();
        for (k, v) in self.views.iter().enumerate().take(2) {
            if let View::Eye(e) = v
                && state.eyes.get(*e).is_some_and(|c| c.gaze_valid)
            {
                self.own_gaze_frames[k] += 1;
            }
        }
        let new_kernel = match (&mut self.kernels, inputs.as_slice()) {
            (Some(k), [(left, _), (right, _)]) => k.update([left, right], &mut self.pipelines)?,
            _ => [false; 2],
        };
        // The pupil model of the chain adapts to the eyes' mean adaptation
        // (geometric: luminances are compared on a log scale).
        let mut log_adaptation = 0.0;
        let Some(first) = inputs.first().map(|i| i.0) else {
            return Err(RenderError::Pipeline("a frame without views".into()));
        };
        let frame_inputs: [FrameInput; 2] = [first, inputs.get(1).map_or(first, |i| i.0)];
        let mut all_stats = [FrameStats::default(); 2];
        {
            let mut eyes: Vec<(&mut R, &mut DisplayFrame)> = self
                .pipelines
                .iter_mut()
                .zip(self.eye_out.iter_mut())
                .collect();
            R::render_views(
                &mut eyes,
                view_img,
                &frame_inputs[..n_views],
                &mut all_stats,
            )?;
            // The caller takes every frame (a GPU frame comes back).
            for (pipeline, out) in &mut eyes {
                pipeline.read_frame(out)?;
            }
        }
        let mut rows = Vec::with_capacity(n_views);
        for (k, ((input, _), pipeline)) in inputs.iter().zip(&mut self.pipelines).enumerate() {
            let pupil = self.views[k].pupil(&state);
            let mut stats = all_stats[k];
            stats.psf_rebuilt |= new_kernel.get(k).copied().unwrap_or(false) && n_views > 1;
            log_adaptation += stats.adaptation_cd_m2.max(1e-9).ln() / n_views as f64;
            if n_views > 1 {
                place_side_by_side(
                    &self.eye_out[k].rgba8,
                    &mut self.composed.rgba8,
                    self.width * 4,
                    k,
                    n_views,
                );
            }
            if self.keep_retinal {
                pipeline.retinal(&mut self.eye_retinal)?;
                place_side_by_side(
                    &self.eye_retinal.pixels,
                    &mut self.retinal.pixels,
                    self.width,
                    k,
                    n_views,
                );
            }
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

    /// The last frame's display image (stereo: left | right), RGBA.
    pub fn display(&self) -> &DisplayFrame {
        if self.views.len() > 1 {
            &self.composed
        } else {
            &self.eye_out[0]
        }
    }

    /// The last frame's retinal image (stereo: left | right), linear RGB in
    /// cd/m², NaN where the view has no data; empty unless built with
    /// `keep_retinal`.
    pub fn retinal(&self) -> &RgbImage {
        &self.retinal
    }

    /// Frames rendered so far (the next frame's index).
    pub fn frames_rendered(&self) -> usize {
        self.next
    }

    /// The views, in display order.
    pub fn views(&self) -> &'static [View] {
        self.views
    }

    /// The pipelines, one per view.
    pub fn pipelines(&self) -> &[R] {
        &self.pipelines
    }

    /// Kernels built by the stereo kernel builder (`None` in mono or with
    /// glare off: the pipelines then rebuild their own).
    pub fn stereo_kernel_builds(&self) -> Option<u64> {
        self.kernels.as_ref().map(|k| k.builds)
    }

    /// Stereo: frames in which each view (left, right) had its eye's own
    /// gaze.
    pub fn own_gaze_frames(&self) -> [usize; 2] {
        self.own_gaze_frames
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use gazelight_tracker::PupilOrigin;

    #[test]
    fn views_take_their_eyes_gaze_and_pupil() {
        let mut s = EyeState {
            gaze_uv: [0.5, 0.5],
            ..Default::default()
        };
        s.eyes[EYE_LEFT].pupil_mm = 3.0;
        s.eyes[EYE_LEFT].pupil_origin = PupilOrigin::Measured;
        s.eyes[EYE_RIGHT].pupil_mm = 5.0;
        s.eyes[EYE_RIGHT].pupil_origin = PupilOrigin::Measured;
        s.eyes[EYE_LEFT].gaze_uv = [0.25, 0.5];
        s.eyes[EYE_LEFT].gaze_valid = true;
        s.eyes[EYE_LEFT].measured = Some(3.1);
        s.eyes[EYE_LEFT].measured_unit = Some(PupilUnit::Mm);
        s.eyes[EYE_LEFT].present = true;
        let (left, held) = STEREO[0].input(&s, 0.01);
        assert_eq!(
            (left.gaze_uv, left.pupil_mm, held),
            ([0.25, 0.5], 3.0, false)
        );
        let (right, _) = STEREO[1].input(&s, 0.01);
        assert_eq!((right.gaze_uv, right.pupil_mm), ([0.5, 0.5], 5.0));
        let (both, _) = MONO[0].input(&s, 0.01);
        assert_eq!((both.gaze_uv, both.pupil_mm), ([0.5, 0.5], 4.0));
        assert_eq!(STEREO.map(View::suffix), ["_left", "_right"]);
        // The measured pupil is the eye's own, never the other eye's or the
        // aperture; an eye the source does not have has empty columns.
        let left = STEREO[0].pupil(&s);
        assert_eq!((left.mm(), left.held()), (3.1, Some(false)));
        let right = STEREO[1].pupil(&s);
        assert!(right.mm().is_nan() && right.held().is_none(), "{right:?}");
        let both = MONO[0].pupil(&s);
        assert_eq!((both.mm(), both.held()), (3.1, Some(false)));
    }

    #[test]
    fn side_by_side_places_rows() {
        let left = [1, 2, 3, 4];
        let right = [5, 6, 7, 8];
        let mut out = [0; 8];
        place_side_by_side(&left, &mut out, 2, 0, 2);
        place_side_by_side(&right, &mut out, 2, 1, 2);
        assert_eq!(out, [1, 2, 5, 6, 3, 4, 7, 8]);
    }
}
