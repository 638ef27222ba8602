//! The frame loop of a live session: a dedicated thread at the display
//! rate, paced by a deadline clock (deadline `k` is `start + k · period`,
//! so sleeping never drifts; a frame that ends after its deadline is
//! counted late, and deadlines that passed entirely meanwhile are counted
//! dropped and skipped rather than rendered in a burst).
//!
//! Each frame ([`FrameLoop::step`]):
//! 1. reads the newest `EyeState` from the hub (`watch::borrow`, never
//!    waits) and computes its age. The state is filtered once, by the
//!    live eye task of `gazelight-tracker` (which also holds the pupil and
//!    eases it to the model when the tracker vanishes, fed the adaptation
//!    luminance this loop stores); the loop never filters it again;
//! 2. follows the head orientation (a head trace re-renders the view);
//! 3. asks the PSF worker ([`gazelight_psf_worker`]) for a kernel when the
//!    pupil moved more than `psf_rebuild_threshold_mm` since the last
//!    request, installs a finished kernel if one is ready (frames keep the
//!    previous kernel until then: a rebuild never stalls a frame), runs
//!    [`FramePipeline::process`] and feeds the adaptation luminance back to
//!    the live eye task;
//! 4. offers the frame to the window (on the GPU: a note that the output
//!    buffer holds a new frame, nothing copied), publishes the frame's
//!    figures (and history) to the hub, the display frame at most every
//!    100 ms when the status page serves it, the glare kernel after each
//!    rebuild, and hands a row (and the frame) to the output writer. A GPU
//!    frame is read back only for those two host consumers, at their rates
//!    (`frames_read_back` in the status and the summary).
//!
//! Steady state allocates nothing: every buffer is created in
//! [`FrameLoop::new`] (the test below counts allocations).

use std::sync::Arc;
use std::time::{Duration, Instant};

use gazelight_tracker::pupil::clock::host_now_secs;
use gazelight_tracker::pupil_response::ObserverRange;
use gazelight_tracker::{EYE_LEFT, EYE_RIGHT};
use gazelight_vision::RgbImage;
use gazelight_vision::kernel_policy::{KernelFollower, KernelPolicy};
use gazelight_vision::pipeline::{DisplayFrame, FrameInput, FrameStats, PipelineConfig};
use gazelight_vision::pooling::PlaneAngles;
use gazelight_vision::psf::PsfKernel;
use gazelight_vision::scene::{PanoramaView, Scene, ViewParams};

use super::head::Head;
use super::writer::{OutputWriter, PsfEvent, Row, ViewRow, WriterReport};
use crate::backend::{BackendChoice, Renderer};
use crate::hub::{FrameParts, FrameStatus, Hub};
use crate::stereo::{self, MONO, STEREO, View};
use crate::window::{DisplaySlot, MouseGaze};
use gazelight_psf_worker::{Priority, PsfWorker};
use gazelight_render::pupil_light::{self, FieldLight, PupilLight};
use gazelight_tracker::live::SourceHealth;
use gazelight_tracker::live::{AdaptationCell, AgeClock};

/// Shortest interval between display-frame copies to the hub.
const DISPLAY_PUBLISH_SECS: f64 = 0.1;
/// EyeState ages kept for the summary (≈ 3 h at 90 Hz).
const AGE_SAMPLES: usize = 1 << 20;
/// Largest frame interval fed to the temporal model, s.
const MAX_DT_SECS: f32 = 0.1;

/// Everything the loop needs, assembled by `run`.
pub struct FrameLoopSetup {
    pub hub: Arc<Hub>,
    pub age_clock: AgeClock,
    pub adaptation: Arc<AdaptationCell>,
    pub pipeline: PipelineConfig,
    /// Which frame pipeline renders (CPU reference or GPU).
    pub backend: BackendChoice,
    /// The scene (cd/m²) and its projection.
    pub pano: Scene,
    pub view: ViewParams,
    pub head: Head,
    pub fps: f64,
    pub writer: Option<OutputWriter>,
    /// The window's newest-frame slot (every frame is offered to it).
    pub display: Option<Arc<DisplaySlot>>,
    /// The cursor as gaze (`--mouse-gaze`) or as head orientation
    /// (`--head mouse`), from the window.
    pub mouse: Option<MouseControl>,
    /// Render both eyes (left | right), each on its own gaze and pupil.
    pub stereo: bool,
    /// Render on this device (an OpenXR runtime's) instead of the one
    /// `backend` picks.
    pub device: Option<gazelight_gpu::GpuContext>,
}

/// What the mouse drives in a windowed run.
#[derive(Clone, Debug)]
pub struct MouseControl {
    pub cursor: Arc<MouseGaze>,
    /// The cursor is the gaze (development without a tracker).
    pub gaze: bool,
    /// The cursor turns the head: the view centre follows it across the
    /// field of view, from the configured orientation.
    pub head: bool,
}

/// What a finished run did.
#[derive(Clone, Debug, Default)]
pub struct RunSummary {
    pub frames: u64,
    pub frames_late: u64,
    /// Display deadlines that passed with no frame (skipped).
    pub frames_dropped: u64,
    /// Of those, the ones passed during a frame that rendered while the PSF
    /// worker was building a kernel or that installed one.
    pub frames_dropped_near_rebuilds: u64,
    /// Frames rendered while the PSF worker was building a kernel, or that
    /// installed one.
    pub frames_near_rebuilds: u64,
    pub wall_secs: f64,
    /// Kernels installed after the initial one (per view).
    pub psf_rebuilds: u64,
    /// Kernels the PSF worker built (a kernel two views share counts once).
    pub kernels_built: u64,
    /// Of those, builds that ran partly beside frames: frames left no gap
    /// for the worker's deferral limit.
    pub kernels_unpaced: u64,
    pub eye_state_age_median_ms: f64,
    pub eye_state_age_p99_ms: f64,
    pub eye_state_age_max_ms: f64,
    pub mean_frame_ms: f64,
    pub writer: Option<WriterReport>,
    pub frames_not_written: u64,
    pub rows_dropped: u64,
    /// Display frames read back from the GPU (for `--out` and the status
    /// page only; 0 on the CPU pipeline).
    pub frames_read_back: u64,
}

/// The per-frame state; build with [`FrameLoop::new`], drive with
/// [`FrameLoop::step`] or [`FrameLoop::run`].
pub struct FrameLoop {
    hub: Arc<Hub>,
    age_clock: AgeClock,
    adaptation_cell: Arc<AdaptationCell>,
    /// One pipeline per view: one (both eyes), or left and right.
    eyes: Vec<EyePipe>,
    pano: Scene,
    view: ViewParams,
    view_img: RgbImage,
    head: Head,
    /// The stereo frame, left | right (empty for one view, whose own
    /// frame is the output).
    composed: DisplayFrame,
    frames: u64,
    late: u64,
    dropped: u64,
    dropped_near_rebuilds: u64,
    frames_near_rebuilds: u64,
    /// The last frame rendered beside a kernel build or installed one.
    rebuild_frame: bool,
    psf_rebuilds: u64,
    last_display_secs: f64,
    psf_scratch: Vec<f32>,
    /// Builds every view's kernels off the frame thread (`None` with glare
    /// off).
    psf_worker: Option<PsfWorker>,
    /// Whether the worker's builds wait for the gaps between frames (the
    /// CPU backend only; see [`Self::step_views`]).
    pace_builds: bool,
    /// Which kernel for which pupil, and the pupil each view's kernel was
    /// asked for (NaN with glare off).
    psf_follower: KernelFollower,
    /// Per view: mean luminance of its own image ([`Self::view_means`]).
    view_means: [f64; 2],
    /// The pupil light response per view (W&Y with the observer's age; the
    /// field is the view's, updated when the head turns).
    pupil_light: PupilLight,
    ages_ms: Vec<f32>,
    age_next: usize,
    frame_ms_sum: f64,
    fps: f64,
    writer: Option<OutputWriter>,
    display: Option<Arc<DisplaySlot>>,
    mouse: Option<MouseControl>,
    /// Head orientation the mouse-driven head turns from.
    base_yaw_pitch_deg: (f64, f64),
}

/// One view's pipeline and frame.
struct EyePipe {
    view: View,
    pipeline: Renderer,
    out: DisplayFrame,
    /// The view's own panorama image when each view has its own pose and
    /// field ([`FrameLoop::step_views`]; empty otherwise).
    view_img: RgbImage,
}

impl EyePipe {
    /// Builds the view's pipeline.
    fn new(
        view: View,
        backend: BackendChoice,
        config: &PipelineConfig,
        params: &ViewParams,
        device: Option<&gazelight_gpu::GpuContext>,
    ) -> anyhow::Result<Self> {
        let (w, h, dpp) = (params.width, params.height, params.deg_per_px());
        let mut pipeline = match device {
            Some(ctx) => {
                Renderer::on_device(ctx, config, w, h, dpp, "the OpenXR runtime's device")?
            }
            None => Renderer::new(backend, config, w, h, dpp)?,
        };
        // Pooling measures angles through the view's projection.
        pipeline.set_view_frustum(PanoramaView::new(*params)?.frustum_tans())?;
        Ok(Self {
            view,
            pipeline,
            out: DisplayFrame::new(w, h),
            view_img: RgbImage::new(if device.is_some() { w } else { 0 }, h),
        })
    }
}

/// Starts the one PSF worker that builds every view's kernels off the
/// frame thread (`None` with glare off) and turns the pipelines' own
/// rebuilding off; with the pupil of the initial kernel, mm.
fn start_psf_worker(
    eyes: &mut [EyePipe],
    config: &PipelineConfig,
    view: &ViewParams,
) -> anyhow::Result<Option<(PsfWorker, f64)>> {
    let Some(first) = eyes.first_mut() else {
        return Ok(None);
    };
    // The CPU convolver's spectra are made on the worker too (the views'
    // convolvers have one geometry: the first one's preparer serves all).
    let preparer = first.pipeline.kernel_preparer();
    let Some(initial) = first.pipeline.psf_kernel()?.cloned() else {
        return Ok(None);
    };
    let mut psf = config.glare.psf.clone();
    // As the pipelines' own builders: same size and pixel size.
    psf.ppd = 1.0 / view.deg_per_px();
    psf.pupil_mm = initial.pupil_mm;
    let worker = PsfWorker::start(psf, &initial, preparer, eyes.len(), Priority::Idle)
        .map_err(|e| anyhow::anyhow!("cannot start the PSF worker thread: {e}"))?;
    for eye in eyes.iter_mut() {
        eye.pipeline.set_psf_auto_rebuild(false);
    }
    Ok(Some((worker, initial.pupil_mm)))
}

impl FrameLoop {
    /// Builds the pipelines and every buffer, renders the initial view and
    /// publishes the initial kernel.
    pub fn new(setup: FrameLoopSetup) -> anyhow::Result<Self> {
        let FrameLoopSetup {
            hub,
            age_clock,
            adaptation,
            pipeline,
            backend,
            pano,
            view,
            head,
            fps,
            writer,
            display,
            mouse,
            stereo,
            device,
        } = setup;
        let config = pipeline;
        let views: &[View] = if stereo { &STEREO } else { &MONO };
        let mut eyes = views
            .iter()
            .map(|v| EyePipe::new(*v, backend, &config, &view, device.as_ref()))
            .collect::<anyhow::Result<Vec<_>>>()?;
        if let Some(first) = eyes.first() {
            tracing::info!(backend = %first.pipeline.describe(), reason = first.pipeline.reason(), views = eyes.len(), "frame pipeline");
        }
        let mut view = view;
        if let Some((yaw, pitch)) = head.orientation(0.0) {
            view.yaw_deg = yaw;
            view.pitch_deg = pitch;
        }
        let mut view_img = RgbImage::new(view.width, view.height);
        PanoramaView::new(view)?.render_scene(&pano, &mut view_img);
        // No first frame from an unset state: a first gaze whose pooling
        // reaches no data starts adapted to the view's field mean (every
        // pixel: a few bright lamps can carry a night view's mean).
        let field_cd_m2 = pupil_light::field_mean_cd_m2(&view_img, view_tans(&view), 1);
        for e in &mut eyes {
            gazelight_render::frame::ViewRenderer::set_initial_target(&mut e.pipeline, field_cd_m2);
        }
        let field = field_of(&view, &view_img);
        let kernel_len = match eyes.first_mut() {
            Some(e) => e.pipeline.psf_kernel()?.map_or(0, |k| k.size * k.size),
            None => 0,
        };
        let (psf_worker, initial_kernel_mm) = match start_psf_worker(&mut eyes, &config, &view)? {
            Some((worker, mm)) => (Some(worker), mm),
            None => (None, f64::NAN),
        };
        let psf_follower = KernelFollower::new(
            KernelPolicy::new(&config.glare),
            eyes.len(),
            initial_kernel_mm,
        );
        let age_years = config.glare.psf.age_years;
        let pupil_light = PupilLight::new(
            views,
            &[pupil_light::params(age_years, ObserverRange::IDENTITY); 2][..views.len()],
            field,
        )?;
        let pace_builds = psf_worker.is_some() && eyes.iter().all(|e| !e.pipeline.is_gpu());
        let n = eyes.len();
        let mut this = Self {
            hub,
            age_clock,
            adaptation_cell: adaptation,
            eyes,
            pano,
            view,
            view_img,
            head,
            composed: DisplayFrame::new(
                if n > 1 { view.width * n } else { 0 },
                if n > 1 { view.height } else { 0 },
            ),
            frames: 0,
            late: 0,
            dropped: 0,
            dropped_near_rebuilds: 0,
            frames_near_rebuilds: 0,
            rebuild_frame: false,
            psf_rebuilds: 0,
            last_display_secs: f64::NEG_INFINITY,
            psf_scratch: Vec::with_capacity(kernel_len),
            pace_builds,
            psf_worker,
            view_means: [f64::NAN; 2],
            pupil_light,
            psf_follower,
            ages_ms: Vec::with_capacity(AGE_SAMPLES),
            age_next: 0,
            frame_ms_sum: 0.0,
            fps,
            writer,
            display,
            mouse,
            base_yaw_pitch_deg: (view.yaw_deg, view.pitch_deg),
        };
        this.publish_kernel(0.0);
        Ok(this)
    }

    /// Publishes each view's current kernel (at start, and after a
    /// pipeline rebuilt one itself).
    fn publish_kernel(&mut self, t_secs: f64) {
        let generation = self.psf_rebuilds + 1;
        for (k, eye) in self.eyes.iter_mut().enumerate() {
            let kernel = match eye.pipeline.psf_kernel() {
                Ok(kernel) => kernel,
                Err(e) => {
                    tracing::warn!(error = %format!("{e:#}"), "cannot read the glare kernel back");
                    None
                }
            };
            if let Some(kernel) = kernel {
                // The pipeline built this one: psf.csv computes its ring
                // from its parameters.
                publish_psf(
                    &self.hub,
                    &mut self.writer,
                    &mut self.psf_scratch,
                    PsfPublish {
                        kernel,
                        first_ring_rad: None,
                        generation,
                        t_secs,
                        view: eye.view,
                        to_hub: k == 0,
                    },
                );
            }
        }
    }

    /// Requests kernels for this frame's pupils (one per view) where they
    /// moved more than the threshold since the last request — in stereo one
    /// kernel at the mean while the two pupils agree ([`KernelPolicy::plan`]) —
    /// and installs finished ones that are ready. Returns per view whether
    /// a kernel was installed. Never blocks.
    fn follow_psf(&mut self, pupils_mm: [f32; 2], t_secs: f64) -> anyhow::Result<[bool; 2]> {
        let Some(worker) = &self.psf_worker else {
            return Ok([false; 2]);
        };
        worker.follow(&mut self.psf_follower, pupils_mm);
        let mut installed = [false; 2];
        for (k, eye) in self.eyes.iter_mut().enumerate() {
            // Generation 1 is the initial kernel; this is rebuild
            // `psf_rebuilds + 1`.
            let generation = self.psf_rebuilds + 2;
            let (pipeline, hub, writer, scratch, view) = (
                &mut eye.pipeline,
                &self.hub,
                &mut self.writer,
                &mut self.psf_scratch,
                eye.view,
            );
            let done = worker.take(k, |prepared, ring_rad| -> anyhow::Result<()> {
                // Kernel and spectra were made on the worker: this swaps
                // them in.
                publish_psf(
                    hub,
                    writer,
                    scratch,
                    PsfPublish {
                        kernel: &prepared.kernel,
                        first_ring_rad: Some(ring_rad),
                        generation,
                        t_secs,
                        view,
                        to_hub: k == 0,
                    },
                );
                pipeline.install_prepared(prepared)?;
                Ok(())
            });
            if let Some(r) = done {
                r?;
                self.psf_rebuilds += 1;
                installed[k] = true;
            }
        }
        Ok(installed)
    }

    /// Renders one frame at host time `now_host_secs`, session time
    /// `t_secs`, `dt_secs` after the previous frame.
    pub fn step(
        &mut self,
        now_host_secs: f64,
        t_secs: f64,
        dt_secs: f32,
    ) -> anyhow::Result<FrameStatus> {
        self.step_views(now_host_secs, t_secs, dt_secs, None, [None; 2])
    }

    /// [`Self::step`] with each view's own projection (an HMD's eyes: pose
    /// and field from the OpenXR runtime), rendered from the panorama into
    /// the view's own image, and optionally each view's gaze (the runtime's
    /// eye gaze, in the view's normalised coordinates) in place of the
    /// tracker's. `now_host_secs` is the time the frame will be shown (the
    /// `EyeState` age is taken there).
    pub fn step_views(
        &mut self,
        now_host_secs: f64,
        t_secs: f64,
        dt_secs: f32,
        views: Option<&[PanoramaView; 2]>,
        gaze_uv: [Option<[f32; 2]>; 2],
    ) -> anyhow::Result<FrameStatus> {
        // On the CPU backend the PSF worker holds its build while a frame
        // renders (it builds in the gaps between frames; `psf_worker`), so
        // that the build's FFT grids do not share the caches and memory bus
        // with the frame. On the GPU backend frames are not paced against
        // builds: there the frame's CPU side mostly waits for the device,
        // and holding builds for it was measured to slow the OpenXR loop
        // on lavapipe from 44–47 to 8 frames in 8 s (`.ci/xr/run`).
        if let Some(w) = self.psf_worker.as_ref().filter(|_| self.pace_builds) {
            w.frame_started();
        }
        let status = self.render_step(now_host_secs, t_secs, dt_secs, views, gaze_uv);
        if let Some(w) = self.psf_worker.as_ref().filter(|_| self.pace_builds) {
            w.frame_ended();
        }
        status
    }

    /// The body of [`Self::step_views`].
    fn render_step(
        &mut self,
        now_host_secs: f64,
        t_secs: f64,
        dt_secs: f32,
        views: Option<&[PanoramaView; 2]>,
        gaze_uv: [Option<[f32; 2]>; 2],
    ) -> anyhow::Result<FrameStatus> {
        let started = Instant::now();
        let live = *self.hub.eye.borrow();
        let mut state = live.state;
        let age_secs = self.age_clock.age_secs(&live, now_host_secs);
        // Nothing measured for any eye the source has (one eye of a
        // monocular tracker is not "held").
        let held = state.view_measured(usize::MAX).is_none() && state.view_present(usize::MAX);
        let cursor = self.mouse.as_ref().and_then(|m| m.cursor.get());
        if let (Some(m), Some(uv)) = (&self.mouse, cursor)
            && m.gaze
        {
            state.gaze_uv = uv;
            state.gaze_valid = true;
            for e in &mut state.eyes {
                e.gaze_valid = false;
            }
        }
        let dt_secs = dt_secs.clamp(0.0, MAX_DT_SECS);
        // Per view: its input (one view, or left and right).
        let unused = FrameInput {
            gaze_uv: [0.5, 0.5],
            pupil_mm: f32::NAN,
            dt_secs,
        };
        let mut inputs = [(unused, false); 2];
        for ((slot, eye), gaze) in inputs.iter_mut().zip(&self.eyes).zip(gaze_uv) {
            *slot = eye.view.input(&state, dt_secs);
            if let Some(uv) = gaze {
                slot.0.gaze_uv = uv;
            }
        }
        let at_view = Instant::now();
        if let Some(projections) = views {
            for ((eye, p), mean) in self
                .eyes
                .iter_mut()
                .zip(projections)
                .zip(&mut self.view_means)
            {
                p.render_scene(&self.pano, &mut eye.view_img);
                eye.pipeline.set_view_frustum(p.frustum_tans())?;
                *mean = pupil_light::field_mean_cd_m2(&eye.view_img, p.frustum_tans(), 8);
            }
            let n = self.eyes.len().min(2) as f64;
            self.pupil_light.set_field(FieldLight {
                field_mean_cd_m2: self.view_means.iter().take(self.eyes.len()).sum::<f64>() / n,
                field_area_deg2: pupil_light::view_solid_angle_deg2(&self.view),
            });
        }

        let mouse_head = match (&self.mouse, cursor) {
            (Some(m), Some(uv)) if m.head => {
                let vfov_deg =
                    self.view.hfov_deg * self.view.height as f64 / self.view.width as f64;
                Some((
                    self.base_yaw_pitch_deg.0 + (f64::from(uv[0]) - 0.5) * self.view.hfov_deg,
                    (self.base_yaw_pitch_deg.1 - (f64::from(uv[1]) - 0.5) * vfov_deg)
                        .clamp(-89.0, 89.0),
                ))
            }
            _ => None,
        };
        if let Some((yaw, pitch)) = mouse_head.or_else(|| self.head.orientation(t_secs))
            && ((yaw - self.view.yaw_deg).abs() > 1e-6
                || (pitch - self.view.pitch_deg).abs() > 1e-6)
        {
            self.view.yaw_deg = yaw;
            self.view.pitch_deg = pitch;
            PanoramaView::new(self.view)?.render_scene(&self.pano, &mut self.view_img);
            self.pupil_light
                .set_field(field_of(&self.view, &self.view_img));
        }

        let at_psf = Instant::now();
        let building = self.psf_worker.as_ref().is_some_and(PsfWorker::building);
        let installed = self.follow_psf([inputs[0].0.pupil_mm, inputs[1].0.pupil_mm], t_secs)?;
        self.rebuild_frame = building || installed.contains(&true);
        self.frames_near_rebuilds += u64::from(self.rebuild_frame);
        let at_render = Instant::now();
        let mut all_stats = [FrameStats::default(); 2];
        let mut self_rebuilt = false;
        let mut log_adaptation = 0.0;
        let n = self.eyes.len();
        let frame_inputs = [inputs[0].0, inputs[1].0];
        let view_img = &self.view_img;
        match &mut self.eyes[..] {
            [l, r] => Renderer::render_views(
                &mut [(&mut l.pipeline, &mut l.out), (&mut r.pipeline, &mut r.out)],
                view_img,
                &frame_inputs,
                &mut all_stats,
            )?,
            eyes => {
                for ((eye, input), stats) in eyes.iter_mut().zip(&frame_inputs).zip(&mut all_stats)
                {
                    *stats = eye.pipeline.render(view_img, input, &mut eye.out)?;
                }
            }
        }
        let at_rendered = Instant::now();
        for (k, stats) in all_stats.iter_mut().enumerate().take(n) {
            // Only without a worker (the pipeline rebuilt synchronously).
            self_rebuilt |= stats.psf_rebuilt;
            stats.psf_rebuilt |= installed[k];
            log_adaptation += stats.adaptation_cd_m2.max(1e-9).ln() / n as f64;
        }
        // The pupil model of the live eye task adapts to the eyes' mean
        // adaptation (geometric: luminances compare on a log scale).
        self.adaptation_cell.set(log_adaptation.exp());
        // The pupil the light predicts per view, and the measured pupil's
        // residual.
        let mut pupils = [(f32::NAN, false); 2];
        for (k, eye) in self.eyes.iter().enumerate().take(2) {
            pupils[k] = (
                inputs[k].0.pupil_mm,
                pupil_light::view_measured(eye.view, &state),
            );
        }
        let plr = self.pupil_light.step(
            t_secs,
            [all_stats[0].target_cd_m2, all_stats[1].target_cd_m2],
            pupils,
        );
        if self_rebuilt {
            self.psf_rebuilds += 1;
            self.publish_kernel(t_secs);
        }
        let (input, _) = inputs[0];
        let stats = all_stats[0];
        self.frames += 1;
        let age_ms = age_secs * 1e3;
        if self.ages_ms.len() < self.ages_ms.capacity() {
            self.ages_ms.push(age_ms as f32);
        } else {
            self.ages_ms[self.age_next] = age_ms as f32;
            self.age_next = (self.age_next + 1) % self.ages_ms.len();
        }
        let at_present = Instant::now();
        // The host consumers of the frame: the status page (at most every
        // DISPLAY_PUBLISH_SECS), the file writer (every frame) and, in
        // stereo, the window (one side-by-side frame).
        let publish =
            self.hub.display_wanted() && t_secs - self.last_display_secs >= DISPLAY_PUBLISH_SECS;
        let write = self.writer.as_ref().is_some_and(OutputWriter::wants_frames);
        if n == 1 {
            if let Some(slot) = &self.display {
                self.eyes[0].pipeline.show(slot, &self.eyes[0].out);
            }
            if publish || write {
                let eye = &mut self.eyes[0];
                eye.pipeline.read_frame(&mut eye.out)?;
            }
        } else if publish || write || self.display.is_some() {
            let row_len = self.view.width * 4;
            for (k, eye) in self.eyes.iter_mut().enumerate() {
                eye.pipeline.read_frame(&mut eye.out)?;
                stereo::place_side_by_side(&eye.out.rgba8, &mut self.composed.rgba8, row_len, k, n);
            }
            if let Some(slot) = &self.display {
                slot.put(&self.composed.rgba8);
            }
        }
        let out = if n == 1 {
            &self.eyes[0].out
        } else {
            &self.composed
        };
        let at_end = Instant::now();
        let ms = |a: Instant, b: Instant| b.duration_since(a).as_secs_f64() * 1e3;
        let frame_ms = ms(started, at_end);
        self.frame_ms_sum += frame_ms;
        // CPU stereo renders its two views at once (rayon::join).
        let parallel = n == 2
            && self
                .eyes
                .iter()
                .all(|e| matches!(e.pipeline, Renderer::Cpu(..)));
        // No Vec: the frame loop allocates nothing per frame.
        let view_stages = || all_stats.iter().take(n).map(|s| stages_ms(&s.timings));
        let stages = if parallel {
            view_stages().fold(0.0, f64::max)
        } else {
            view_stages().sum()
        };
        let parts = FrameParts {
            prepare_ms: ms(started, at_view),
            view_ms: ms(at_view, at_psf),
            psf_install_ms: ms(at_psf, at_render),
            stages_ms: stages,
            render_other_ms: ms(at_render, at_rendered) - stages,
            pupil_light_ms: ms(at_rendered, at_present),
            present_ms: ms(at_present, at_end),
        };
        let mut status = FrameStatus {
            frames: self.frames,
            frames_late: self.late,
            t_secs,
            pupil_mm: [
                state.eyes[EYE_RIGHT].measured_mm().unwrap_or(f32::NAN),
                state.eyes[EYE_LEFT].measured_mm().unwrap_or(f32::NAN),
            ],
            aperture_mm: [
                state.eyes[EYE_RIGHT].pupil_mm,
                state.eyes[EYE_LEFT].pupil_mm,
            ],
            frame_pupil_mm: input.pupil_mm,
            gaze_uv: input.gaze_uv,
            adaptation_cd_m2: stats.adaptation_cd_m2,
            target_cd_m2: stats.target_cd_m2,
            eye_state_age_ms: age_ms,
            frame_ms,
            parts,
            timings: stats.timings,
            psf_rebuilds: self.psf_rebuilds,
            ..FrameStatus::default()
        };
        status.views = n as u32;
        status.view_adaptation_cd_m2 = [f64::NAN; 2];
        status.view_target_cd_m2 = [f64::NAN; 2];
        status.view_pupil_light_mm = [f32::NAN; 2];
        status.view_pupil_residual_mm = [f32::NAN; 2];
        for (k, s) in all_stats.iter().enumerate().take(n.min(2)) {
            status.view_adaptation_cd_m2[k] = s.adaptation_cd_m2;
            status.view_target_cd_m2[k] = s.target_cd_m2;
            (
                status.view_pupil_light_mm[k],
                status.view_pupil_residual_mm[k],
            ) = plr[k];
        }
        status.pupil_light_mm = status.eye_pupil_light_mm();
        status.pupil_residual_mm = status.eye_pupil_residual_mm();
        status.frames_read_back = self
            .eyes
            .iter()
            .map(|e| e.pipeline.frames_read_back())
            .sum();
        status.frames_presented = self.display.as_ref().map_or(0, |s| s.presented());
        self.hub.publish_frame(status);
        if publish {
            self.last_display_secs = t_secs;
            self.hub
                .publish_display(self.frames, out.width, out.height, &out.rgba8);
        }
        if let Some(w) = &mut self.writer {
            // Read the health without cloning the status (no allocation).
            let mut health = SourceHealth::Connecting;
            self.hub.update_source(|s| health = s.health);
            let mut views = [ViewRow::default(); 2];
            for (k, v) in views.iter_mut().enumerate().take(n) {
                let (input, _) = inputs[k];
                let s = &all_stats[k];
                *v = ViewRow {
                    gaze_u: input.gaze_uv[0],
                    gaze_v: input.gaze_uv[1],
                    frame_pupil_mm: input.pupil_mm,
                    target_cd_m2: s.target_cd_m2,
                    adaptation_cd_m2: s.adaptation_cd_m2,
                    psf_pupil_mm: s.psf_pupil_mm,
                    psf_rebuilt: s.psf_rebuilt,
                    pupil_light_mm: plr[k].0,
                    pupil_residual_mm: plr[k].1,
                };
            }
            w.row(Row {
                frame: self.frames,
                t_secs,
                pupil_mm: status.pupil_mm,
                pupil_held: held,
                eye_state_age_ms: age_ms,
                health,
                views,
                frame_ms,
            });
            if write {
                w.frame(self.frames, out);
            }
        }
        Ok(status)
    }

    /// Runs at the display rate until the hub's shutdown, then flushes the
    /// outputs and returns the summary.
    pub fn run(mut self) -> anyhow::Result<RunSummary> {
        let period_secs = 1.0 / self.fps;
        let start = Instant::now();
        self.start_clock(start);
        let mut deadline_index: u64 = 0;
        let mut prev: Option<Instant> = None;
        let mut result = Ok(());
        while !self.hub.shutting_down() {
            let now = Instant::now();
            let dt = prev.map_or(0.0, |p| (now - p).as_secs_f32());
            prev = Some(now);
            if let Err(e) = self.step(host_now_secs(), (now - start).as_secs_f64(), dt) {
                result = Err(e);
                break;
            }
            deadline_index += 1;
            let deadline = start + Duration::from_secs_f64(deadline_index as f64 * period_secs);
            let after = Instant::now();
            if after > deadline {
                self.late += 1;
                // Deadlines that passed entirely during this frame get no
                // frame; the next frame aims at the next future deadline.
                let slots = ((after - start).as_secs_f64() / period_secs).floor() as u64;
                if slots > deadline_index {
                    self.dropped += slots - deadline_index;
                    if self.rebuild_frame {
                        self.dropped_near_rebuilds += slots - deadline_index;
                    }
                    deadline_index = slots;
                }
            } else {
                // Sleep in slices so a shutdown (a signal, --secs) is seen
                // within `SHUTDOWN_POLL` even at a very low --fps.
                let mut now = after;
                while now < deadline && !self.hub.shutting_down() {
                    std::thread::sleep((deadline - now).min(crate::bounds::SHUTDOWN_POLL));
                    now = Instant::now();
                }
            }
        }
        self.finish(start.elapsed().as_secs_f64(), result)
    }

    /// The run's clock starts at `start` (`t_secs` = 0 there): the
    /// writer's `events.csv` counts from its host time.
    pub fn start_clock(&mut self, start: Instant) {
        if let Some(w) = &mut self.writer {
            w.clock_origin(gazelight_tracker::pupil::clock::host_secs_of(start));
        }
    }

    /// Counts a frame that missed its display slot (the OpenXR loop's
    /// pacing: the runtime's predicted display times).
    pub fn count_late(&mut self, late: bool, dropped: u64) {
        self.late += u64::from(late);
        self.dropped += dropped;
    }

    /// Each view's mean luminance (cd/m², over a sparse grid) as last
    /// rendered by [`Self::step_views`]: what the head's pose shows.
    pub fn view_means(&self) -> [f64; 2] {
        self.view_means
    }

    /// Hands an `xr.csv` row to the output writer (with `--out`).
    pub fn write_xr(&mut self, row: super::writer::XrRow) {
        if let Some(w) = &mut self.writer {
            w.xr(row);
        }
    }

    /// The GPU output of view `k` (`None` on the CPU), for a presenter.
    pub fn frame_source(&self, k: usize) -> Option<gazelight_gpu::present::FrameSource> {
        self.eyes.get(k).and_then(|e| e.pipeline.frame_source())
    }

    /// Flushes the outputs and returns the summary of a session that ran
    /// `wall_secs` and ended with `result`.
    pub fn finish(
        mut self,
        wall_secs: f64,
        result: anyhow::Result<()>,
    ) -> anyhow::Result<RunSummary> {
        let mut summary = self.summary(wall_secs);
        if let Some(w) = self.writer.take() {
            summary.frames_not_written = w.frames_skipped;
            summary.rows_dropped = w.dropped;
            summary.writer = Some(w.finish()?);
        }
        result.map(|()| summary)
    }

    fn summary(&mut self, wall_secs: f64) -> RunSummary {
        let ages = &mut self.ages_ms;
        ages.sort_unstable_by(f32::total_cmp);
        let pct = |p: f64| -> f64 {
            if ages.is_empty() {
                return f64::NAN;
            }
            let i = ((ages.len() - 1) as f64 * p).round() as usize;
            f64::from(ages[i])
        };
        RunSummary {
            frames: self.frames,
            frames_late: self.late,
            frames_dropped: self.dropped,
            frames_dropped_near_rebuilds: self.dropped_near_rebuilds,
            frames_near_rebuilds: self.frames_near_rebuilds,
            wall_secs,
            psf_rebuilds: self.psf_rebuilds,
            kernels_built: self.psf_worker.as_ref().map_or(0, PsfWorker::builds),
            kernels_unpaced: self
                .psf_worker
                .as_ref()
                .map_or(0, PsfWorker::builds_unpaced),
            eye_state_age_median_ms: pct(0.5),
            eye_state_age_p99_ms: pct(0.99),
            eye_state_age_max_ms: pct(1.0),
            mean_frame_ms: if self.frames > 0 {
                self.frame_ms_sum / self.frames as f64
            } else {
                0.0
            },
            writer: None,
            frames_not_written: 0,
            rows_dropped: 0,
            frames_read_back: self
                .eyes
                .iter()
                .map(|e| e.pipeline.frames_read_back())
                .sum(),
        }
    }
}

/// The field of a view for the pupil light response: its mean luminance
/// over its solid angle (every 8th pixel of every 8th row, each weighted by
/// its solid angle) and its solid angle.
fn field_of(view: &ViewParams, img: &RgbImage) -> FieldLight {
    FieldLight {
        field_mean_cd_m2: pupil_light::field_mean_cd_m2(img, view_tans(view), 8),
        field_area_deg2: pupil_light::view_solid_angle_deg2(view),
    }
}

/// A symmetric view's edge tangents (left, right, up, down).
fn view_tans(view: &ViewParams) -> [f64; 4] {
    match PlaneAngles::symmetric(view.hfov_deg, view.width, view.height) {
        PlaneAngles::Rectilinear { tan_lrud, .. } => tan_lrud,
        PlaneAngles::Uniform { .. } => [-1.0, 1.0, 1.0, -1.0],
    }
}

/// A kernel to publish.
struct PsfPublish<'a> {
    kernel: &'a PsfKernel,
    /// The first dark ring measured where it was built (`None`: psf.csv
    /// computes it from the parameters).
    first_ring_rad: Option<f64>,
    generation: u64,
    t_secs: f64,
    /// The view it is for.
    view: View,
    /// Whether the status page shows it (one view's kernels: the first).
    to_hub: bool,
}

/// Publishes a kernel to the hub (its luminance) and to psf.csv.
fn publish_psf(
    hub: &Hub,
    writer: &mut Option<OutputWriter>,
    scratch: &mut Vec<f32>,
    p: PsfPublish<'_>,
) {
    let k = p.kernel;
    if p.to_hub {
        scratch.clear();
        // Rec. 709 luminance of the linear-sRGB kernel.
        scratch.extend(
            k.rgb
                .iter()
                .map(|p| 0.2126 * p[0] + 0.7152 * p[1] + 0.0722 * p[2]),
        );
        hub.publish_psf(p.generation, k.pupil_mm, k.size, scratch);
    }
    if let Some(w) = writer {
        w.psf(PsfEvent {
            generation: p.generation,
            t_secs: p.t_secs,
            pupil_mm: k.pupil_mm,
            first_ring_rad: p.first_ring_rad,
            view: p.view,
        });
    }
}

/// A view's pipeline stages added, ms (its `total_ms` left out: it is the
/// whole call, not a stage).
fn stages_ms(t: &gazelight_vision::pipeline::StageTimings) -> f64 {
    t.pooling_ms + t.temporal_ms + t.psf_ms + t.glare_ms + t.acuity_ms + t.tone_colour_encode_ms
}

#[cfg(test)]
mod tests {
    use std::alloc::{GlobalAlloc, Layout, System};
    use std::cell::Cell;
    use std::sync::atomic::{AtomicUsize, Ordering};

    use gazelight_tracker::LiveEyeState;
    use gazelight_tracker::{EyeState, PupilOrigin};
    use gazelight_vision::scene::{LuminanceScale, Scene};
    use tokio::sync::watch;

    use super::*;
    use crate::demo;

    /// Counts allocations made on threads that opted in (the test thread
    /// and its rayon pool), so other tests running in parallel do not
    /// disturb the count.
    struct Counting;

    thread_local! {
        static COUNT_HERE: Cell<bool> = const { Cell::new(false) };
    }
    static ALLOCS: AtomicUsize = AtomicUsize::new(0);

    fn note() {
        if COUNT_HERE.with(Cell::get) {
            ALLOCS.fetch_add(1, Ordering::Relaxed);
        }
    }

    // SAFETY: every call goes to the system allocator with the caller's
    // arguments; counting allocates nothing.
    unsafe impl GlobalAlloc for Counting {
        unsafe fn alloc(&self, layout: Layout) -> *mut u8 {
            note();
            // SAFETY: the caller's layout, as `GlobalAlloc::alloc` asks.
            unsafe { System.alloc(layout) }
        }
        unsafe fn dealloc(&self, ptr: *mut u8, layout: Layout) {
            // SAFETY: `ptr` came from `System` (every allocation does).
            unsafe { System.dealloc(ptr, layout) }
        }
        unsafe fn realloc(&self, ptr: *mut u8, layout: Layout, new_size: usize) -> *mut u8 {
            note();
            // SAFETY: `ptr` came from `System` with `layout`.
            unsafe { System.realloc(ptr, layout, new_size) }
        }
    }

    #[global_allocator]
    static GLOBAL: Counting = Counting;

    fn live_state(t: f64, pupil_mm: f32, gaze_u: f32, updates: u64) -> LiveEyeState {
        let mut state = EyeState {
            t_secs: t,
            gaze_uv: [gaze_u, 0.5],
            gaze_valid: true,
            ..EyeState::default()
        };
        for e in &mut state.eyes {
            e.pupil_mm = pupil_mm;
            e.pupil_origin = PupilOrigin::Measured;
            e.confidence = 0.95;
        }
        LiveEyeState {
            state,
            updated_host_secs: t,
            updates,
        }
    }

    fn small_loop(
        tx_state: LiveEyeState,
        out: Option<&std::path::Path>,
        stereo: bool,
    ) -> (FrameLoop, watch::Sender<LiveEyeState>) {
        small_loop_in(tx_state, out, stereo, false)
    }

    /// [`small_loop`]; with `fisheye`, the embedded panorama's pixels read
    /// as a 180° angular fisheye looking forward, so the demo view (turned
    /// 78° left, 90° wide) looks past its field: part of it has no data.
    fn small_loop_in(
        tx_state: LiveEyeState,
        out: Option<&std::path::Path>,
        stereo: bool,
        fisheye: bool,
    ) -> (FrameLoop, watch::Sender<LiveEyeState>) {
        let views = if stereo { 2 } else { 1 };
        let (tx, rx) = watch::channel(tx_state);
        let hub = Hub::new("test://", rx);
        let mut scene = Scene::from_bytes(
            demo::NIGHT_EXR,
            demo::name_path(),
            LuminanceScale::default(),
        )
        .expect("embedded scene");
        if fisheye {
            scene.projection = Some(
                gazelight_vision::scene::SceneProjection::new(
                    gazelight_vision::scene::ProjectionKind::Angular,
                    180.0,
                    180.0,
                    scene.image.width,
                    scene.image.height,
                )
                .expect("fisheye"),
            );
        }
        let view = demo::default_view(320, 256);
        let mut config = PipelineConfig::default();
        // A small glare field keeps the test's PSF builds quick.
        config.glare.psf.field_deg = 10.0;
        let writer = out.map(|dir| {
            let mut psf = config.glare.psf.clone();
            psf.ppd = view.ppd();
            OutputWriter::start(
                dir,
                view.width * views,
                view.height,
                psf,
                true,
                stereo,
                None,
            )
            .expect("writer")
        });
        let fl = FrameLoop::new(FrameLoopSetup {
            hub,
            age_clock: AgeClock::SampleTime,
            adaptation: Arc::new(AdaptationCell::default()),
            pipeline: config,
            backend: BackendChoice::Cpu,
            pano: scene,
            view,
            head: Head::Fixed,
            fps: 90.0,
            writer,
            // The window's slot takes every frame: part of the steady state.
            display: Some(DisplaySlot::new(
                (view.width * views) as u32,
                view.height as u32,
            )),
            mouse: None,
            stereo,
            device: None,
        })
        .expect("frame loop");
        (fl, tx)
    }

    /// One view, then a stereo pair. One test: the count is global, and a
    /// second test counting in parallel would add its own allocations.
    #[test]
    fn steady_state_steps_do_not_allocate() {
        steady_state_does_not_allocate(false, false);
        steady_state_does_not_allocate(true, false);
        // A view with no data in it (outside a fisheye's field).
        steady_state_does_not_allocate(false, true);
    }

    fn steady_state_does_not_allocate(stereo: bool, fisheye: bool) {
        let dir = std::env::temp_dir().join(format!(
            "gazelight-alloc-{}-{stereo}-{fisheye}",
            std::process::id()
        ));
        let (mut fl, tx) = small_loop_in(live_state(0.0, 5.0, 0.3, 1), Some(&dir), stereo, fisheye);
        let pool = rayon::ThreadPoolBuilder::new()
            .num_threads(2)
            .start_handler(|_| COUNT_HERE.with(|c| c.set(true)))
            .build()
            .expect("pool");
        let dt = 1.0 / 90.0;
        let mut t = 0.0;
        let warm_frames = pool.install(|| {
            // Warm-up: first frames, PSF rebuild to 5 mm, first display copy.
            for i in 0..10u64 {
                tx.send_replace(live_state(t, 5.0, 0.3, i + 2));
                fl.step(t, t, dt as f32).expect("frame");
                t += dt;
            }
            // The 5 mm kernel is built off the frame thread: keep stepping
            // (frames keep the 4 mm kernel meanwhile) until it is installed.
            let waited = Instant::now();
            let mut i = 10u64;
            // Done when the pupil has slewed to 5 mm and the kernel for the
            // last request (within the threshold of 5 mm) is installed.
            // Every view's kernel is the one last requested for it.
            let kernels_current = |fl: &mut FrameLoop| {
                let follower = fl.psf_follower;
                fl.eyes.iter_mut().enumerate().all(|(k, e)| {
                    let mm = e
                        .pipeline
                        .psf_kernel()
                        .ok()
                        .flatten()
                        .map_or(f64::NAN, |k| k.pupil_mm);
                    mm == follower.kernel_mm(k)
                })
            };
            let mut last_pupil = 0.0f32;
            while fl.psf_rebuilds == 0 || last_pupil != 5.0 || !kernels_current(&mut fl) {
                assert!(
                    waited.elapsed() < Duration::from_secs(120),
                    "the 5 mm kernel never arrived"
                );
                std::thread::sleep(Duration::from_millis(20));
                tx.send_replace(live_state(t, 5.0, 0.3, i + 2));
                last_pupil = fl.step(t, t, dt as f32).expect("frame").frame_pupil_mm;
                t += dt;
                i += 1;
            }
            let base_mm = fl.psf_follower.kernel_mm(0);
            assert!((base_mm - 5.0).abs() <= 0.1, "kernel at {base_mm} mm");
            // Both eyes' pupils agree: one kernel, the same pupil.
            assert!((0..fl.eyes.len()).all(|k| fl.psf_follower.kernel_mm(k) == base_mm));
            let warm_frames = fl.frames;
            let rebuilds = fl.psf_rebuilds;
            COUNT_HERE.with(|c| c.set(true));
            ALLOCS.store(0, Ordering::SeqCst);
            for i in 0..60u64 {
                // A live-ish state: new samples every frame, gaze moving,
                // pupil jittering below the rebuild threshold.
                let u = 0.2 + 0.6 * (i % 10) as f32 / 10.0;
                tx.send_replace(live_state(
                    t - 0.004,
                    base_mm as f32 + 0.01 * (i % 3) as f32,
                    u,
                    20 + i,
                ));
                fl.step(t, t, dt as f32).expect("frame");
                t += dt;
            }
            COUNT_HERE.with(|c| c.set(false));
            assert_eq!(
                fl.psf_rebuilds, rebuilds,
                "a kernel was installed in steady state"
            );
            warm_frames
        });
        let n = ALLOCS.load(Ordering::SeqCst);
        let no_data = fl
            .view_img
            .pixels
            .iter()
            .filter(|p| gazelight_vision::image::is_no_data(**p))
            .count();
        assert_eq!(no_data > 0, fisheye, "{no_data} view pixels without data");
        let summary = fl.run_summary_for_test();
        let _ = std::fs::remove_dir_all(&dir);
        assert_eq!(n, 0, "steady-state frames allocated {n} times");
        assert_eq!(summary.frames, warm_frames + 60);
        assert!(
            (summary.eye_state_age_median_ms - 4.0).abs() < 0.5,
            "{summary:?}"
        );
    }

    /// No first frame from an unset state: a first gaze far outside the
    /// scene's field (the embedded panorama read as a forward fisheye, the
    /// demo view turned 78° left: its left third has no data) pools no
    /// light; the eye starts adapted to the light of the rest of the view
    /// (within a factor 1.5 of the plain mean luminance of its pixels with
    /// data, and not 0 cd/m², which drew a blown-out frame).
    #[test]
    fn first_frame_with_the_gaze_outside_the_field_starts_adapted_to_the_view() {
        let (mut fl, tx) = small_loop_in(live_state(0.0, 4.0, 0.5, 1), None, false, true);
        let img = &fl.view_img;
        let (w, h) = (img.width, img.height);
        let no_data =
            |x: usize, y: usize| gazelight_vision::image::is_no_data(img.pixels[y * w + x]);
        // The middle row's pixel without data farthest from any with data.
        let y = h / 2;
        let data_x: Vec<usize> = (0..w).filter(|&x| !no_data(x, y)).collect();
        let gaze_x = (0..w)
            .filter(|&x| no_data(x, y))
            .max_by_key(|&x| data_x.iter().map(|&d| d.abs_diff(x)).min().unwrap_or(0))
            .expect("a pixel without data on the middle row");
        let far = data_x
            .iter()
            .map(|&d| d.abs_diff(gaze_x))
            .min()
            .unwrap_or(0);
        assert!(far > w / 5, "no wide region without data: {far} px");
        let with_data: Vec<f64> = img
            .pixels
            .iter()
            .filter(|p| !gazelight_vision::image::is_no_data(**p))
            .map(|p| f64::from(gazelight_vision::image::luminance(*p)))
            .collect();
        let mean = with_data.iter().sum::<f64>() / with_data.len() as f64;
        let u = (gaze_x as f32 + 0.5) / w as f32;
        tx.send_replace(live_state(0.0, 4.0, u, 2));
        fl.step(0.0, 0.0, 0.0).expect("frame");
        let a = fl.hub.frame().adaptation_cd_m2;
        assert!(
            a > mean / 1.5 && a < mean * 1.5,
            "gaze u {u}: first adaptation {a} cd/m², view mean {mean} cd/m²"
        );
    }

    /// The status page's figures per eye: in stereo the frame status and
    /// the history carry each view's adaptation (the page plots both), in
    /// mono one.
    #[test]
    fn frame_status_and_history_carry_each_views_adaptation() {
        for stereo in [false, true] {
            let (mut fl, tx) = small_loop(live_state(0.0, 4.0, 0.3, 1), None, stereo);
            let dt = 1.0 / 90.0;
            for i in 0..5u64 {
                let t = i as f64 * dt;
                tx.send_replace(live_state(t, 4.0, 0.3, i + 2));
                fl.step(t, t, dt as f32).expect("frame");
            }
            let status = fl.hub.frame();
            let history = crate::serve::HistoryJson::collect(&fl.hub);
            if stereo {
                assert_eq!(status.views, 2);
                assert!(
                    status
                        .view_adaptation_cd_m2
                        .iter()
                        .all(|a| a.is_finite() && *a > 0.0),
                    "{status:?}"
                );
                assert!(status.view_target_cd_m2.iter().all(|a| a.is_finite()));
                // Each view's light-driven pupil, within W&Y's range.
                assert!(
                    status
                        .view_pupil_light_mm
                        .iter()
                        .all(|p| (1.5..=9.0).contains(p)),
                    "{status:?}"
                );
                assert_eq!(history.adaptation_left_cd_m2.len(), history.t_secs.len());
                assert_eq!(history.adaptation_right_cd_m2.len(), 5);
            } else {
                assert_eq!(status.views, 1);
                assert_eq!(status.view_adaptation_cd_m2[0], status.adaptation_cd_m2);
                assert!(status.view_adaptation_cd_m2[1].is_nan());
                assert!(history.adaptation_left_cd_m2.is_empty());
            }
        }
    }

    /// The live path (PSF worker, one view and a stereo pair) ends up with
    /// the kernels of [`crate::bad_pupils::SEQUENCE`]: each pupil is held
    /// until the kernel it asks for is installed in every view (or, where
    /// the table keeps the kernel, for ten frames).
    #[test]
    fn bad_pupils_give_the_table_kernels_live() {
        for stereo in [false, true] {
            let (mut fl, tx) = small_loop(live_state(0.0, 4.0, 0.5, 1), None, stereo);
            let dt = 1.0 / 90.0;
            let mut t = 0.0;
            let mut updates = 2u64;
            let mut kernel_mm = 4.0;
            for (i, &(pupil_mm, want_mm)) in crate::bad_pupils::SEQUENCE.iter().enumerate() {
                let installed = |fl: &mut FrameLoop| -> Vec<f64> {
                    fl.eyes
                        .iter_mut()
                        .map(|e| {
                            e.pipeline
                                .psf_kernel()
                                .ok()
                                .flatten()
                                .map_or(f64::NAN, |k| k.pupil_mm)
                        })
                        .collect()
                };
                let waited = Instant::now();
                let mut frames = 0;
                loop {
                    tx.send_replace(live_state(t, pupil_mm, 0.5, updates));
                    fl.step(t, t, dt as f32).expect("frame");
                    t += dt;
                    updates += 1;
                    frames += 1;
                    let got = installed(&mut fl);
                    let targets: Vec<f64> = (0..fl.eyes.len())
                        .map(|k| fl.psf_follower.kernel_mm(k))
                        .collect();
                    let settled = got
                        .iter()
                        .chain(&targets)
                        .all(|&g| (g - want_mm).abs() < 1e-9);
                    if want_mm == kernel_mm {
                        // Kept: never anything else, for ten frames.
                        assert!(
                            settled,
                            "stereo {stereo}, step {i}: pupil {pupil_mm} mm moved the kernel \
                             to {got:?} (targets {targets:?}), want {want_mm} mm"
                        );
                        if frames == 10 {
                            break;
                        }
                    } else if settled {
                        break;
                    } else {
                        assert!(
                            waited.elapsed() < Duration::from_secs(120),
                            "stereo {stereo}, step {i}: pupil {pupil_mm} mm: kernels {got:?} \
                             (targets {targets:?}) never reached {want_mm} mm"
                        );
                        std::thread::sleep(Duration::from_millis(10));
                    }
                }
                kernel_mm = want_mm;
            }
        }
    }

    impl FrameLoop {
        fn run_summary_for_test(mut self) -> RunSummary {
            if let Some(w) = self.writer.take() {
                w.finish().expect("writer");
            }
            self.summary(0.0)
        }
    }
}
