//! Stage 1 on the GPU, the twin of `shaders/pooling.wgsl`: scene import
//! (sanitised copy), block luminance (the CPU pipeline's pass A) and the
//! gaze-weighted luminance pooling of [`gazelight_vision::pooling`]
//! (001 §4.1, 000 eq 5–6, 003 eq 1, 004 §3.1, 000 §3.2) as two-level
//! workgroup reductions (core WebGPU has no float atomics). The pooled
//! target lands in [`crate::frame::FrameState::target_cd_m2`].
//!
//! The weights are evaluated per block in f32 on the GPU; the spans and
//! model constants that depend only on the gaze are computed on the host in
//! f64 exactly as the CPU does ([`PoolParams::for_frame`]).

use bytemuck::{Pod, Zeroable};
use gazelight_vision::pooling::{PlaneAngles, PoolingModel};

use crate::context::GpuContext;
use crate::error::GpuError;
use crate::frame::FrameState;
use crate::pass::{Binding, PassDescriptor, PassLayout};
use crate::shaders;

/// Threads per workgroup of the reductions (`POOL_THREADS`).
pub const POOL_THREADS: u32 = 256;

/// Uniforms of `pooling.wgsl` (`struct PoolParams`), field by field.
#[repr(C)]
#[derive(Debug, Clone, Copy, PartialEq, Pod, Zeroable)]
pub struct PoolParams {
    /// Frame width, pixels.
    pub width: u32,
    /// Frame height, pixels.
    pub height: u32,
    /// Block plane width.
    pub small_w: u32,
    /// Block plane height.
    pub small_h: u32,
    /// Block size, pixels.
    pub ds: u32,
    /// 0 Gaussian, 1 centre weight, 2 eccentricity, 3 gaze window, 4 panorama.
    pub model: u32,
    /// Workgroups of `pool_partial`.
    pub partial_count: u32,
    /// Padding.
    pub _pad0: u32,
    /// Span of blocks with weight (models 0 and 3): `[x0, x1) × [y0, y1)`.
    pub x0: u32,
    /// See `x0`.
    pub x1: u32,
    /// See `x0`.
    pub y0: u32,
    /// See `x0`.
    pub y1: u32,
    /// Gaze on the block plane, blocks.
    pub gaze_x: f32,
    /// Gaze on the block plane, blocks.
    pub gaze_y: f32,
    /// Model parameters (see the shader header).
    pub p0: f32,
    /// Model parameters.
    pub p1: f32,
    /// Model parameters.
    pub p2: f32,
    /// Model parameters.
    pub p3: f32,
    /// The block plane's geometry: 0 uniform (`deg_per_block` per block),
    /// 1 rectilinear (`axes`, `tans`: angles measured through the view).
    pub geo: u32,
    /// Padding.
    pub _pad1: u32,
    /// Rectilinear: the gaze's azimuth, rad
    /// ([`gazelight_vision::pooling::rectilinear_terms`]).
    pub azimuth: f32,
    /// Rectilinear: the gaze's elevation, rad.
    pub elevation: f32,
    /// Rectilinear: cos of the gaze's elevation.
    pub cos_elevation: f32,
    /// Rectilinear: √(1 + s_gx²).
    pub k: f32,
    /// Rectilinear: the tangent at x = 0.
    pub tan_x0: f32,
    /// Rectilinear: the tangent per block in x.
    pub tan_per_x: f32,
    /// Rectilinear: the tangent at y = 0.
    pub tan_y0: f32,
    /// Rectilinear: the tangent per block in y (downwards).
    pub tan_per_y: f32,
}

impl PoolParams {
    /// The uniforms of one frame: `gaze_px` on the block plane (finite),
    /// `angles` the block plane's geometry (uniform: the angular size of
    /// one block; rectilinear: the view's tangents).
    #[allow(clippy::too_many_arguments)]
    pub fn for_frame(
        model: &PoolingModel,
        frame: [u32; 2],
        small: [u32; 2],
        ds: u32,
        partial_count: u32,
        gaze_px: [f64; 2],
        angles: PlaneAngles,
    ) -> Self {
        let (w, h) = (small[0] as usize, small[1] as usize);
        let rect = gazelight_vision::pooling::rectilinear_terms(w, h, gaze_px, angles);
        let deg_per_block = match angles {
            PlaneAngles::Uniform { deg_per_px } if deg_per_px.is_finite() && deg_per_px > 0.0 => {
                deg_per_px
            }
            _ => 1.0,
        };
        // The blocks with weight, and the window's edges, as the CPU's.
        let spans = model.span_in(w, h, gaze_px, angles);
        let mut p = Self {
            width: frame[0],
            height: frame[1],
            small_w: small[0],
            small_h: small[1],
            ds,
            model: 0,
            partial_count,
            _pad0: 0,
            x0: 0,
            x1: small[0],
            y0: 0,
            y1: small[1],
            gaze_x: gaze_px[0] as f32,
            gaze_y: gaze_px[1] as f32,
            p0: 0.0,
            p1: 0.0,
            p2: 0.0,
            p3: 0.0,
            geo: 0,
            _pad1: 0,
            azimuth: 0.0,
            elevation: 0.0,
            cos_elevation: 0.0,
            k: 0.0,
            tan_x0: 0.0,
            tan_per_x: 0.0,
            tan_y0: 0.0,
            tan_per_y: 0.0,
        };
        if let Some((axes, tans)) = rect {
            p.geo = 1;
            [p.azimuth, p.elevation, p.cos_elevation, p.k] = axes.map(|v| v as f32);
            [p.tan_x0, p.tan_per_x, p.tan_y0, p.tan_per_y] = tans.map(|v| v as f32);
        }
        if let Some(([x0, x1, y0, y1], _)) = spans {
            // Both ends are at most the block counts, themselves `u32`s.
            (p.x0, p.x1, p.y0, p.y1) = (x0 as u32, x1 as u32, y0 as u32, y1 as u32);
        }
        match *model {
            PoolingModel::Gaussian { sigma_deg } => {
                // 1/(σ√2) in blocks (uniform) or in degrees (rectilinear).
                let sigma = if p.geo == 1 {
                    sigma_deg
                } else {
                    sigma_deg / deg_per_block
                };
                p.p0 = (1.0 / (sigma * std::f64::consts::SQRT_2)) as f32;
            }
            PoolingModel::CentreWeight { follow_gaze } => {
                p.model = 1;
                let c = if follow_gaze {
                    gaze_px
                } else {
                    [w as f64 / 2.0, h as f64 / 2.0]
                };
                p.p0 = (w as f64 / 2.0) as f32;
                p.p1 = (h as f64 / 2.0) as f32;
                p.p2 = c[0] as f32;
                p.p3 = c[1] as f32;
            }
            PoolingModel::Eccentricity { e2_deg } => {
                p.model = 2;
                p.p0 = e2_deg as f32;
                p.p1 = deg_per_block as f32;
            }
            PoolingModel::GazeWindow { .. } => {
                p.model = 3;
                if let Some((_, [lo_x, hi_x, lo_y, hi_y])) = spans {
                    p.p0 = lo_x as f32;
                    p.p1 = hi_x as f32;
                    p.p2 = lo_y as f32;
                    p.p3 = hi_y as f32;
                }
            }
            PoolingModel::PanoramaMean => p.model = 4,
        }
        p
    }
}

/// `shaders/pooling.wgsl`: import, block luminance, the two reductions.
pub const POOLING_PASS: PassDescriptor = PassDescriptor {
    shader: shaders::POOLING,
    entry_points: &[
        "import_scene",
        "block_luminance",
        "pool_partial",
        "pool_final",
    ],
    bindings: &[
        Binding::uniform::<PoolParams>("params"),
        Binding::read::<[f32; 4]>("scene"),
        Binding::read_write::<[f32; 4]>("work"),
        Binding::read_write::<[f32; 2]>("small_lum"),
        Binding::read_write::<[f32; 2]>("partials"),
        Binding::read_write::<FrameState>("state"),
    ],
};

/// The twin of `shaders/pooling.wgsl` ([`POOLING_PASS`]). Bindings:
/// 0 [`PoolParams`], 1 scene (RGBA f32, read-only), 2 working frame (RGBA
/// f32), 3 block luminance and valid share (`vec2<f32>`), 4 partial sums (`vec2<f32>`),
/// 5 [`crate::frame::FrameState`].
#[derive(Debug, Clone)]
pub struct PoolingPass {
    pub(crate) layout: PassLayout,
    pub(crate) import_scene: wgpu::ComputePipeline,
    pub(crate) block_luminance: wgpu::ComputePipeline,
    pub(crate) pool_partial: wgpu::ComputePipeline,
    pub(crate) pool_final: wgpu::ComputePipeline,
}

impl PoolingPass {
    /// Checks the shader against the device limits and builds the pipelines.
    pub fn new(ctx: &GpuContext) -> Result<Self, GpuError> {
        let (layout, [import_scene, block_luminance, pool_partial, pool_final]) =
            POOLING_PASS.build(ctx)?;
        Ok(Self {
            layout,
            import_scene,
            block_luminance,
            pool_partial,
            pool_final,
        })
    }

    /// The bind group layout (group 0).
    pub fn bind_group_layout(&self) -> &wgpu::BindGroupLayout {
        self.layout.layout()
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::testing::pass_harness::{
        every_pooling_model, panorama_view, read, run_pass, storage, texels, tiles, uniform,
    };
    use crate::testing::test_context;

    /// The pooling pass alone at 1-pixel blocks: the block plane is then
    /// each pixel's luminance, and the pooled target must be what
    /// `PoolingModel::pool` gives on that plane, for every model and gaze.
    #[test]
    fn pooled_target_matches_the_cpu_pool_for_every_model() {
        let Some(ctx) = test_context("pooled_target_matches_the_cpu_pool_for_every_model") else {
            return;
        };
        let (w, h) = (96u32, 64u32);
        let (img, dpp) = panorama_view("studio.exr", 30.0, -5.0, 60.0, [96, 64]);
        let lum: Vec<f32> = img
            .pixels
            .iter()
            .map(|p| gazelight_vision::image::luminance(*p))
            .collect();
        let pass = PoolingPass::new(ctx).unwrap();
        let partial_count = (w * h).div_ceil(POOL_THREADS).clamp(1, POOL_THREADS);
        let scene = storage(ctx, &texels(&img));
        let work = storage(ctx, &texels(&img));
        // Per block: luminance and valid share.
        let small = storage(ctx, &vec![[0.0f32; 2]; (w * h) as usize]);
        let partials = storage(ctx, &vec![[0.0f32; 2]; partial_count as usize]);
        let state = storage(ctx, &[FrameState::default()]);
        // The pass's pooled target for `scene` (the texels buffer).
        let gpu_pooled =
            |scene: &wgpu::Buffer, model: &PoolingModel, gaze_px: [f64; 2], angles: PlaneAngles| {
                let params =
                    PoolParams::for_frame(model, [w, h], [w, h], 1, partial_count, gaze_px, angles);
                let params_buf = uniform(ctx, &params);
                run_pass(
                    ctx,
                    &pass.layout,
                    &[&params_buf, scene, &work, &small, &partials, &state],
                    &[
                        (&pass.import_scene, tiles(96, 64)),
                        (&pass.block_luminance, tiles(96, 64)),
                        (&pass.pool_partial, [partial_count, 1, 1]),
                        (&pass.pool_final, [1, 1, 1]),
                    ],
                );
                f64::from(read::<FrameState>(ctx, &state)[0].target_cd_m2)
            };
        let mut worst = 0.0f64;
        // The view's own geometry (60° wide, through its projection) and
        // the planar one.
        let geometries = [
            PlaneAngles::Uniform { deg_per_px: dpp },
            PlaneAngles::symmetric(60.0, w as usize, h as usize),
        ];
        for (model, angles) in every_pooling_model()
            .into_iter()
            .flat_map(|m| geometries.map(|a| (m, a)))
        {
            for gaze_px in [[48.0, 32.0], [10.5, 55.25], [90.0, 3.0]] {
                let gpu = gpu_pooled(&scene, &model, gaze_px, angles);
                let cpu = model.pool_in(&lum, w as usize, h as usize, gaze_px, angles);
                let e = (gpu - cpu).abs() / cpu.abs().max(1e-9);
                println!(
                    "{model:?} {angles:?} at {gaze_px:?}: GPU {gpu:.5} cd/m², CPU {cpu:.5}, rel {e:.1e}"
                );
                assert!(
                    e < 1e-4,
                    "{model:?} {angles:?} at {gaze_px:?}: GPU {gpu}, CPU {cpu}"
                );
                worst = worst.max(e);
            }
        }
        println!("worst relative |GPU − CPU| pooled target {worst:.2e}");

        // No data (NaN) in the right third: block_luminance's valid share
        // and Σ w·L / Σ w·valid against `pool_valid_in` on 0/1 shares.
        let mut holed = img.clone();
        let mut valid = vec![1.0f32; (w * h) as usize];
        for (i, p) in holed.pixels.iter_mut().enumerate() {
            if i % w as usize >= 64 {
                *p = [f32::NAN; 3];
                valid[i] = 0.0;
            }
        }
        let lum: Vec<f32> = holed
            .pixels
            .iter()
            .map(|p| {
                gazelight_vision::image::luminance(p.map(|c| if c.is_nan() { 0.0 } else { c }))
            })
            .collect();
        let scene = storage(ctx, &texels(&holed));
        for model in every_pooling_model() {
            let angles = PlaneAngles::symmetric(60.0, w as usize, h as usize);
            for gaze_px in [[48.0, 32.0], [62.5, 20.0], [66.0, 40.0]] {
                let gpu = gpu_pooled(&scene, &model, gaze_px, angles);
                let cpu = model
                    .pool_valid_in(&lum, &valid, w as usize, h as usize, gaze_px, angles)
                    .unwrap();
                let e = (gpu - cpu).abs() / cpu.abs().max(1e-9);
                assert!(
                    e < 1e-4,
                    "no data: {model:?} at {gaze_px:?}: GPU {gpu}, CPU {cpu}"
                );
            }
        }
    }
}
