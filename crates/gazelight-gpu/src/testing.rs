//! Helpers for GPU tests and benchmarks (this crate's and downstream ones).
//!
//! Tests get one shared device per test binary from [`test_context`]
//! (WebGPU default limits, `WGPU_BACKEND` honoured). When no adapter exists
//! the test prints a skip line and returns, unless `GAZELIGHT_REQUIRE_GPU=1`
//! (CI), in which case it fails. Every GPU test prints the adapter it ran on.

use std::sync::OnceLock;

use crate::context::{ContextOptions, GpuContext};

/// Environment variable that turns a missing adapter into a test failure.
pub const REQUIRE_GPU_ENV: &str = "GAZELIGHT_REQUIRE_GPU";

/// Whether `GAZELIGHT_REQUIRE_GPU=1` is set.
pub fn gpu_required() -> bool {
    std::env::var(REQUIRE_GPU_ENV).is_ok_and(|v| v.trim() == "1")
}

/// The shared test device, created on first use with the WebGPU default
/// limits; `None` (after printing `SKIP <test>: …`) when there is no adapter.
///
/// # Panics
/// When there is no adapter and `GAZELIGHT_REQUIRE_GPU=1`: that is the test
/// failure CI asks for.
pub fn test_context(test: &str) -> Option<&'static GpuContext> {
    static CONTEXT: OnceLock<Result<GpuContext, String>> = OnceLock::new();
    let context = CONTEXT
        .get_or_init(|| GpuContext::new(&ContextOptions::default()).map_err(|e| e.to_string()));
    match context {
        Ok(ctx) => {
            println!("{test}: running on {}", ctx.describe());
            Some(ctx)
        }
        Err(e) if gpu_required() => panic!("{test}: {REQUIRE_GPU_ENV}=1 but no GPU device: {e}"),
        Err(e) => {
            println!(
                "SKIP {test}: no GPU device ({e}); set {REQUIRE_GPU_ENV}=1 to make this a failure"
            );
            None
        }
    }
}

/// Pass-level test helpers: buffers with contents, one-pass dispatch,
/// read-back. Each pass file's own parity test drives its pass with these
/// on small frames, against the CPU reference in `gazelight-vision`.
#[cfg(test)]
pub(crate) mod pass_harness {
    use bytemuck::Pod;

    use crate::context::GpuContext;
    use crate::fft::read_mapped;

    /// A storage buffer (`STORAGE | COPY_DST | COPY_SRC`) holding `data`.
    pub(crate) fn storage<T: Pod>(ctx: &GpuContext, data: &[T]) -> wgpu::Buffer {
        let bytes: &[u8] = bytemuck::cast_slice(data);
        let buffer = ctx.device().create_buffer(&wgpu::BufferDescriptor {
            label: Some("pass test storage"),
            size: (bytes.len() as u64).max(16),
            usage: wgpu::BufferUsages::STORAGE
                | wgpu::BufferUsages::COPY_DST
                | wgpu::BufferUsages::COPY_SRC,
            mapped_at_creation: false,
        });
        ctx.queue().write_buffer(&buffer, 0, bytes);
        buffer
    }

    /// A uniform buffer holding `value`.
    pub(crate) fn uniform<T: Pod>(ctx: &GpuContext, value: &T) -> wgpu::Buffer {
        let buffer = ctx.device().create_buffer(&wgpu::BufferDescriptor {
            label: Some("pass test uniform"),
            size: size_of::<T>() as u64,
            usage: wgpu::BufferUsages::UNIFORM | wgpu::BufferUsages::COPY_DST,
            mapped_at_creation: false,
        });
        ctx.queue()
            .write_buffer(&buffer, 0, bytemuck::bytes_of(value));
        buffer
    }

    /// Runs `dispatches` (pipeline, workgroups) in one compute pass with
    /// `group` bound, and submits.
    pub(crate) fn run(
        ctx: &GpuContext,
        group: &wgpu::BindGroup,
        dispatches: &[(&wgpu::ComputePipeline, [u32; 3])],
    ) {
        let mut encoder = ctx.device().create_command_encoder(&Default::default());
        {
            let mut pass = encoder.begin_compute_pass(&Default::default());
            pass.set_bind_group(0, group, &[]);
            for (pipeline, [x, y, z]) in dispatches {
                pass.set_pipeline(pipeline);
                pass.dispatch_workgroups(*x, *y, *z);
            }
        }
        ctx.queue().submit([encoder.finish()]);
    }

    /// The contents of `buffer` as `T`s (blocking).
    pub(crate) fn read<T: Pod>(ctx: &GpuContext, buffer: &wgpu::Buffer) -> Vec<T> {
        let staging = ctx.device().create_buffer(&wgpu::BufferDescriptor {
            label: Some("pass test staging"),
            size: buffer.size(),
            usage: wgpu::BufferUsages::MAP_READ | wgpu::BufferUsages::COPY_DST,
            mapped_at_creation: false,
        });
        let mut encoder = ctx.device().create_command_encoder(&Default::default());
        encoder.copy_buffer_to_buffer(buffer, 0, &staging, 0, buffer.size());
        ctx.queue().submit([encoder.finish()]);
        let mut out = Vec::new();
        read_mapped(ctx, &staging, "pass test read-back", |bytes| {
            let whole = bytes.len() / size_of::<T>() * size_of::<T>();
            out = bytemuck::pod_collect_to_vec(&bytes[..whole]);
        })
        .unwrap();
        out
    }

    /// A perspective view `hfov_deg` wide into one of the shared
    /// panoramas (file units taken as cd/m²) and its degrees per pixel.
    pub(crate) fn panorama_view(
        name: &str,
        yaw_deg: f64,
        pitch_deg: f64,
        hfov_deg: f64,
        size: [usize; 2],
    ) -> (gazelight_vision::RgbImage, f64) {
        use gazelight_vision::scene::{LuminanceScale, PanoramaView, Scene, ViewParams};
        let path = gazelight_test_support::data_path("hdr/blender-world").join(name);
        let scene = Scene::load(&path, LuminanceScale::default()).unwrap();
        let params = ViewParams {
            yaw_deg,
            pitch_deg,
            hfov_deg,
            width: size[0],
            height: size[1],
        };
        let mut img = gazelight_vision::RgbImage::new(size[0], size[1]);
        PanoramaView::new(params)
            .unwrap()
            .render(&scene.image, &mut img);
        (img, params.deg_per_px())
    }

    /// Binds `buffers` to `layout`'s pass and runs `dispatches`.
    pub(crate) fn run_pass(
        ctx: &GpuContext,
        layout: &crate::pass::PassLayout,
        buffers: &[&wgpu::Buffer],
        dispatches: &[(&wgpu::ComputePipeline, [u32; 3])],
    ) {
        let group = layout.bind_buffers(ctx, buffers).unwrap();
        run(ctx, &group, dispatches);
    }

    /// 8×8 workgroups over `w × h`.
    pub(crate) fn tiles(w: usize, h: usize) -> [u32; 3] {
        [(w as u32).div_ceil(8), (h as u32).div_ceil(8), 1]
    }

    /// Every pooling model, with the defaults' parameters.
    pub(crate) fn every_pooling_model() -> [gazelight_vision::pooling::PoolingModel; 6] {
        use gazelight_vision::pooling::{DEFAULT_E2_DEG, DEFAULT_GAZE_WINDOW_DEG, PoolingModel};
        [
            PoolingModel::default(),
            PoolingModel::CentreWeight { follow_gaze: true },
            PoolingModel::CentreWeight { follow_gaze: false },
            PoolingModel::Eccentricity {
                e2_deg: DEFAULT_E2_DEG,
            },
            PoolingModel::GazeWindow {
                size_deg: DEFAULT_GAZE_WINDOW_DEG,
            },
            PoolingModel::PanoramaMean,
        ]
    }

    /// RGBA texels (alpha 0) of an image.
    pub(crate) fn texels(img: &gazelight_vision::RgbImage) -> Vec<[f32; 4]> {
        img.pixels.iter().map(|p| [p[0], p[1], p[2], 0.0]).collect()
    }
}
