//! One eye's light perception on the app's image: import
//! ([`crate::import`]) → gazelight-gpu's [`GpuFramePipeline`] (pooling at
//! the gaze, temporal adaptation kept across frames, glare with the PSF of
//! the pupil, acuity, scotopic colour, tone) → its
//! [`TexturePresenter`] drawing the display frame back into the same
//! image (a render pass: the image ends in `COLOR_ATTACHMENT_OPTIMAL`).
//!
//! The PSF follows the pupil by `gazelight_vision::kernel_policy`, rebuilt
//! by the pipeline on the GPU when the pupil moved past the threshold (no
//! host work on the app's thread).

use gazelight_gpu::frame::FRAME_TIMESTAMPS;
use gazelight_gpu::present::{FrameSource, TexturePresenter};
use gazelight_gpu::psf::REBUILD_TIMESTAMPS;
use gazelight_gpu::{EncodedFrame, FrameTimestamps, GpuContext, GpuError, GpuFramePipeline};
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
        })
    }

    /// Whether this processor serves images of `format`, `width × height`,
    /// edge tangents `tan_lrud`.
    pub fn fits(
        &self,
        format: wgpu::TextureFormat,
        width: u32,
        height: u32,
        tan_lrud: [f64; 4],
    ) -> bool {
        self.format == format
            && self.width == width
            && self.height == height
            && self.tan_lrud == tan_lrud
    }

    /// Records the processing of `texture`'s array `layer` (the whole
    /// image is the view; the caller checks) into `encoder`.
    pub fn encode(
        &mut self,
        encoder: &mut wgpu::CommandEncoder,
        texture: &wgpu::Texture,
        layer: u32,
        input: &FrameInput,
    ) -> EncodedFrame {
        let q = self.queries.as_ref();
        self.import.encode(
            encoder,
            texture,
            layer,
            [0, 0],
            q.map(|q| (&q.frame, IMPORT_TS)),
        );
        let encoded = self.pipeline.encode_timed(
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
        self.presenter.encode(encoder, &view);
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
        encoded
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
