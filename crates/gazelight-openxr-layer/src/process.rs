//! One eye's light perception on the app's image: import
//! ([`crate::import`]) → gazelight-gpu's [`GpuFramePipeline`] (pooling at
//! the gaze, temporal adaptation kept across frames, glare with the PSF of
//! the pupil, acuity, scotopic colour, tone) → its
//! [`TexturePresenter`] drawing the display frame back into the same
//! image (a render pass: the image ends in `COLOR_ATTACHMENT_OPTIMAL`).
//!
//! The PSF follows the pupil by `gazelight_vision::kernel_policy`: when
//! the pupil moved past the threshold the eye asks its own
//! [`PsfWorker`] (a CPU `PsfBuilder` with the pipeline's PSF parameters on
//! a thread of its own at nice +10, [`Priority::Background`]) for a
//! kernel and keeps the one it has until the kernel is ready; installing it
//! uploads it (the next frame makes its spectra on the GPU). Neither the
//! build nor a wait for it runs on the app's thread or its queue: only the
//! upload does. Where the worker cannot start (no thread) the pipeline
//! rebuilds the kernel itself inside the frame that needs it.

use gazelight_gpu::frame::FRAME_TIMESTAMPS;
use gazelight_gpu::present::{FrameSource, TexturePresenter};
use gazelight_gpu::psf::REBUILD_TIMESTAMPS;
use gazelight_gpu::{EncodedFrame, FrameTimestamps, GpuContext, GpuError, GpuFramePipeline};
use gazelight_psf_worker::{Priority, PsfWorker};
use gazelight_vision::kernel_policy::{KernelFollower, KernelPolicy};
use gazelight_vision::pipeline::{FrameInput, PipelineConfig};

use crate::import::{ImageFormat, ImportPass};

/// Timestamp slots of the layer's own passes after the pipeline's.
const IMPORT_TS: u32 = FRAME_TIMESTAMPS;
const FRAME_QUERIES: u32 = FRAME_TIMESTAMPS + 2;

/// The view's geometry: tangents of its left, right, up and down edges
/// (`tan(angle_left)`, … of the `XrFovf`).
pub fn fov_tangents(angle_left: f32, angle_right: f32, angle_up: f32, angle_down: f32) -> [f64; 4] {
    [angle_left, angle_right, angle_up, angle_down].map(|a| f64::from(a).tan())
}

/// Degrees per pixel across a view `width_px` wide with edge tangents
/// `tan_lrud` (the mean over the width).
pub fn deg_per_px(tan_lrud: [f64; 4], width_px: u32) -> f64 {
    (tan_lrud[1].atan() - tan_lrud[0].atan()).to_degrees() / f64::from(width_px.max(1))
}

struct Queries {
    frame: wgpu::QuerySet,
    psf: wgpu::QuerySet,
    resolve: wgpu::Buffer,
    readback: wgpu::Buffer,
}

/// The largest relative change of a view's pixel size (degrees per pixel)
/// an [`EyeProcessor`] follows without being rebuilt: a field of view that
/// moves a little from frame to frame (some runtimes' views do) only
/// re-aims pooling; the kernels (built for the pixel size) stay within
/// 0.5 % of it.
pub const DEG_PER_PX_TOLERANCE: f64 = 0.005;

/// How an [`EyeProcessor`] serves a view ([`EyeProcessor::fit`]).
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum Fit {
    /// Built for this view.
    Same,
    /// Serves it after [`EyeProcessor::set_view`].
    Frustum,
    /// Needs a new processor (another size, format or pixel size).
    Rebuild,
}

/// What an [`EyeProcessor`] is built for.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct EyeSpec {
    /// The swapchain's format (a served one, [`ImageFormat::of`]).
    pub format: wgpu::TextureFormat,
    pub width: u32,
    pub height: u32,
    /// The view's edge tangents ([`fov_tangents`]).
    pub tan_lrud: [f64; 4],
    /// Decoded value → cd/m² (`white_cd_m2` for sRGB, `scene_scale_cd_m2`
    /// for half floats).
    pub scale: f32,
    /// Write GPU timestamps (when the device has them).
    pub timed: bool,
}

/// One eye's processing of images of one size and format.
pub struct EyeProcessor {
    ctx: GpuContext,
    pipeline: GpuFramePipeline,
    presenter: TexturePresenter,
    import: ImportPass,
    format: wgpu::TextureFormat,
    width: u32,
    height: u32,
    tan_lrud: [f64; 4],
    queries: Option<Queries>,
    psf: Option<EyePsf>,
}

/// The eye's kernels built off the app's thread.
struct EyePsf {
    worker: PsfWorker,
    /// The rule and the pupil of the newest kernel asked for, mm.
    follower: KernelFollower,
    /// The pupil of the kernel installed, mm.
    kernel_mm: f64,
}

impl EyePsf {
    /// The worker for `pipeline`'s PSF (same parameters, the kernel it
    /// holds now as the initial one); `None` with glare off or when the
    /// worker cannot start (the pipeline then rebuilds in-frame).
    fn start(
        pipeline: &mut GpuFramePipeline,
        config: &PipelineConfig,
    ) -> Result<Option<Self>, GpuError> {
        let Some(psf) = pipeline.psf() else {
            return Ok(None);
        };
        let initial = psf.read_kernel()?;
        let params = psf.params().clone();
        match PsfWorker::start(params, &initial, None, 1, Priority::Background) {
            Ok(worker) => {
                pipeline.set_psf_auto_rebuild(false);
                Ok(Some(Self {
                    worker,
                    follower: KernelFollower::new(
                        KernelPolicy::new(&config.glare),
                        1,
                        initial.pupil_mm,
                    ),
                    kernel_mm: initial.pupil_mm,
                }))
            }
            Err(e) => {
                crate::log::log(
                    "warn",
                    &format!(
                        "frame effects: no PSF worker thread ({e}); kernels are rebuilt inside the frames"
                    ),
                );
                Ok(None)
            }
        }
    }

    /// Asks for a kernel when `pupil_mm` moved past the threshold and
    /// installs a finished one; whether one was installed. Never waits.
    fn follow(&mut self, pipeline: &mut GpuFramePipeline, pupil_mm: f32) -> Result<bool, GpuError> {
        self.worker.follow(&mut self.follower, [pupil_mm, f32::NAN]);
        let kernel_mm = &mut self.kernel_mm;
        self.worker
            .take(0, |prepared, _ring_rad| {
                pipeline.set_kernel(&prepared.kernel)?;
                *kernel_mm = prepared.kernel.pupil_mm;
                Ok(())
            })
            .transpose()
            .map(|installed| installed.is_some())
    }

    /// Kernels built so far.
    fn builds(&self) -> u64 {
        self.worker.builds()
    }
}

impl EyeProcessor {
    /// For the images and view of `spec`.
    pub fn new(ctx: &GpuContext, config: &PipelineConfig, spec: EyeSpec) -> Result<Self, GpuError> {
        let EyeSpec {
            format,
            width,
            height,
            tan_lrud,
            scale,
            timed,
        } = spec;
        let image = ImageFormat::of(format).ok_or_else(|| GpuError::Wgpu {
            what: "the app's swapchain image".into(),
            message: format!("format {format:?} is not served"),
        })?;
        let mut pipeline = GpuFramePipeline::new(
            ctx,
            config.clone(),
            width as usize,
            height as usize,
            deg_per_px(tan_lrud, width),
        )?;
        pipeline.set_view_frustum(tan_lrud)?;
        let presenter = TexturePresenter::new(&FrameSource::of(&pipeline), format)?;
        let import = ImportPass::new(ctx, image, width, height, scale, pipeline.scene_buffer())?;
        let psf = EyePsf::start(&mut pipeline, config)?;
        let queries = (timed && ctx.has_timestamp_queries()).then(|| {
            let device = ctx.device();
            Queries {
                frame: device.create_query_set(&wgpu::QuerySetDescriptor {
                    label: Some("gazelight-layer frame"),
                    ty: wgpu::QueryType::Timestamp,
                    count: FRAME_QUERIES,
                }),
                psf: device.create_query_set(&wgpu::QuerySetDescriptor {
                    label: Some("gazelight-layer psf"),
                    ty: wgpu::QueryType::Timestamp,
                    count: REBUILD_TIMESTAMPS,
                }),
                resolve: device.create_buffer(&wgpu::BufferDescriptor {
                    label: Some("gazelight-layer timestamps"),
                    size: u64::from(FRAME_QUERIES) * 8,
                    usage: wgpu::BufferUsages::QUERY_RESOLVE | wgpu::BufferUsages::COPY_SRC,
                    mapped_at_creation: false,
                }),
                readback: device.create_buffer(&wgpu::BufferDescriptor {
                    label: Some("gazelight-layer timestamps read-back"),
                    size: u64::from(FRAME_QUERIES) * 8,
                    usage: wgpu::BufferUsages::MAP_READ | wgpu::BufferUsages::COPY_DST,
                    mapped_at_creation: false,
                }),
            }
        });
        Ok(Self {
            ctx: ctx.clone(),
            pipeline,
            presenter,
            import,
            format,
            width,
            height,
            tan_lrud,
            queries,
            psf,
        })
    }

    /// How this processor serves a view of `format`, `width × height`,
    /// edge tangents `tan_lrud`: as it is, after [`Self::set_view`] (the
    /// same image, a field whose pixel size is within
    /// [`DEG_PER_PX_TOLERANCE`]: pooling follows the new frustum, the
    /// kernels and the acuity keep their pixel size), or not at all.
    pub fn fit(
        &self,
        format: wgpu::TextureFormat,
        width: u32,
        height: u32,
        tan_lrud: [f64; 4],
    ) -> Fit {
        if self.format != format || self.width != width || self.height != height {
            return Fit::Rebuild;
        }
        if self.tan_lrud == tan_lrud {
            return Fit::Same;
        }
        let ratio = deg_per_px(tan_lrud, width) / self.pipeline.deg_per_px();
        if (ratio - 1.0).abs() <= DEG_PER_PX_TOLERANCE {
            Fit::Frustum
        } else {
            Fit::Rebuild
        }
    }

    /// Takes a view with edge tangents `tan_lrud` (see [`Self::fit`]):
    /// pooling measures angles through it from the next frame on.
    pub fn set_view(&mut self, tan_lrud: [f64; 4]) -> Result<(), GpuError> {
        self.pipeline.set_view_frustum(tan_lrud)?;
        self.tan_lrud = tan_lrud;
        Ok(())
    }

    /// Records the processing of the view at `origin` (pixels; the view
    /// is the processor's size, inside the image: the caller checks) of
    /// `texture`'s array `layer` into `encoder`: the whole image, or one
    /// view's `imageRect` of an image holding both side by side, whose
    /// other pixels stay as they are. First
    /// installing the newest kernel the eye's PSF worker finished (then
    /// `psf_rebuilt` is true: a new kernel took effect in this frame).
    pub fn encode(
        &mut self,
        encoder: &mut wgpu::CommandEncoder,
        texture: &wgpu::Texture,
        layer: u32,
        origin: [u32; 2],
        input: &FrameInput,
    ) -> Result<EncodedFrame, GpuError> {
        let installed = match self.psf.as_mut() {
            Some(psf) => psf.follow(&mut self.pipeline, input.pupil_mm)?,
            None => false,
        };
        let q = self.queries.as_ref();
        self.import.encode(
            encoder,
            texture,
            layer,
            origin,
            q.map(|q| (&q.frame, IMPORT_TS)),
        );
        let mut encoded = self.pipeline.encode_timed(
            encoder,
            input,
            q.map(|q| FrameTimestamps {
                frame: &q.frame,
                psf: &q.psf,
            }),
        );
        let view = texture.create_view(&wgpu::TextureViewDescriptor {
            label: Some("gazelight-layer target"),
            format: Some(self.format),
            dimension: Some(wgpu::TextureViewDimension::D2),
            usage: Some(wgpu::TextureUsages::RENDER_ATTACHMENT),
            aspect: wgpu::TextureAspect::All,
            base_mip_level: 0,
            mip_level_count: Some(1),
            base_array_layer: layer,
            array_layer_count: Some(1),
        });
        let whole =
            origin == [0, 0] && [texture.width(), texture.height()] == [self.width, self.height];
        if whole {
            self.presenter.encode(encoder, &view);
        } else {
            self.presenter.encode_rect(
                encoder,
                &view,
                [origin[0], origin[1], self.width, self.height],
            );
        }
        if let Some(q) = q {
            encoder.resolve_query_set(&q.frame, 0..FRAME_QUERIES, &q.resolve, 0);
            encoder.copy_buffer_to_buffer(
                &q.resolve,
                0,
                &q.readback,
                0,
                u64::from(FRAME_QUERIES) * 8,
            );
        }
        encoded.psf_rebuilt |= installed;
        Ok(encoded)
    }

    /// Whether the eye's kernels are built off the app's thread (else the
    /// pipeline rebuilds them inside frames).
    pub fn psf_off_thread(&self) -> bool {
        self.psf.is_some()
    }

    /// Asks for the kernel of `pupil_mm` and waits up to `timeout` until
    /// it is installed (tests: a frame that must have it); whether it is.
    #[doc(hidden)]
    pub fn wait_for_kernel(
        &mut self,
        pupil_mm: f32,
        timeout: std::time::Duration,
    ) -> Result<bool, GpuError> {
        let Some(psf) = self.psf.as_mut() else {
            // Rebuilt inside the next frame.
            return Ok(true);
        };
        let t0 = std::time::Instant::now();
        loop {
            psf.follow(&mut self.pipeline, pupil_mm)?;
            if psf
                .follower
                .policy()
                .decide(pupil_mm, psf.kernel_mm)
                .is_none()
            {
                return Ok(true);
            }
            if t0.elapsed() >= timeout {
                return Ok(false);
            }
            std::thread::sleep(std::time::Duration::from_millis(2));
        }
    }

    /// Kernels the eye's PSF worker built so far.
    pub fn psf_builds(&self) -> u64 {
        self.psf.as_ref().map_or(0, EyePsf::builds)
    }

    /// The GPU time of the last submitted frame, ms: the import pass plus
    /// the pipeline's passes from pooling to tone (the PSF rebuild, when
    /// one ran, and the final draw are not in it). Waits for the queue.
    /// `None` without timestamps.
    pub fn read_gpu_ms(&self) -> Option<f64> {
        let q = self.queries.as_ref()?;
        let slice = q.readback.slice(..);
        let (tx, rx) = std::sync::mpsc::channel();
        slice.map_async(wgpu::MapMode::Read, move |r| {
            let _ = tx.send(r);
        });
        self.ctx.wait_idle().ok()?;
        rx.recv().ok()?.ok()?;
        let ticks: Vec<u64> = {
            let data = slice.get_mapped_range().ok()?;
            bytemuck::cast_slice::<u8, u64>(&data).to_vec()
        };
        q.readback.unmap();
        let period_ns = f64::from(self.ctx.queue().get_timestamp_period());
        let span = |a: usize, b: usize| {
            let (s, e) = (*ticks.get(a)?, *ticks.get(b)?);
            (e >= s).then(|| (e - s) as f64 * period_ns * 1e-6)
        };
        let import = span(IMPORT_TS as usize, IMPORT_TS as usize + 1)?;
        let frame = span(0, FRAME_TIMESTAMPS as usize - 1)?;
        Some(import + frame)
    }

    /// The pipeline (tests, the CSV's frame scalars, the dumps).
    pub fn pipeline(&mut self) -> &mut GpuFramePipeline {
        &mut self.pipeline
    }

    /// The import pass (tests).
    pub fn import(&self) -> &ImportPass {
        &self.import
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn a_90_degree_view_320_pixels_wide_has_0_28125_degrees_per_pixel() {
        let a = 45f32.to_radians();
        let t = fov_tangents(-a, a, a, -a);
        assert!(
            (t[0] + 1.0).abs() < 1e-6 && (t[1] - 1.0).abs() < 1e-6,
            "{t:?}"
        );
        assert!((deg_per_px(t, 320) - 90.0 / 320.0).abs() < 1e-6);
    }
}
