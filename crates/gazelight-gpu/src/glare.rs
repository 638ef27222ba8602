//! Stage 4 on the GPU, the twin of `shaders/glare.wgsl`: the glare of
//! [`gazelight_vision::glare::GlareConvolver`] (001 §4.2.3) — every source
//! within `full_weight_deg` of the gaze at full weight, a Gaussian fade
//! beyond — with the kernel split exactly into a full-resolution core
//! (radius [`FINE_RADIUS_DEG`]) convolved in a fine FFT window and a smooth
//! wide field summed over `b × b` blocks ([`COARSE_PX_DEG`]) convolved in a
//! coarse FFT window of blocks and spread back bilinearly. The kernel's
//! split parts are made on the GPU from [`crate::GpuPsfBuilder`]'s kernel
//! buffer after each PSF rebuild, transformed ([`crate::fft::GpuFft2d`],
//! three planes each) and cached between rebuilds.
//!
//! [`GlareGeometry`] takes the CPU convolver's sizes (fine radius, block,
//! source radius and the windows it needs) from
//! [`gazelight_vision::glare::GlareSizes`], the one definition,
//! and [`GlareParams::place`] its per-frame placement (origins, source box,
//! output region). The GPU's FFT windows are the next powers of two of the
//! sizes the CPU needs (the CPU also takes `3·2^k`, `5·2^k`): a larger
//! window only adds zeros, as the convolution is linear, not circular, in
//! both. The weights and the convolutions run in f32 (the CPU's spectra are
//! f32 too).
//!
//! [`FINE_RADIUS_DEG`]: gazelight_vision::glare::FINE_RADIUS_DEG
//! [`COARSE_PX_DEG`]: gazelight_vision::glare::COARSE_PX_DEG

use bytemuck::{Pod, Zeroable};
use gazelight_vision::VisionError;
use gazelight_vision::glare::{GlareSizes, GlareWindow};

use crate::context::GpuContext;
use crate::error::GpuError;
use crate::far_glare::FarStage;
use crate::fft::{FftDirection, GpuFft2d};
use crate::frame::{
    FrameSizes, STORAGE, TILE, UNIFORM, create_buffer, invalid, tiles, timestamp_writes,
};
use crate::pass::{Binding, PassDescriptor, PassLayout};
use crate::psf::GpuPsfBuilder;
use crate::shaders;
use gazelight_vision::kernel_policy::{INITIAL_PUPIL_MM, KernelFollower, KernelPolicy};
use gazelight_vision::pipeline::PipelineConfig;
use gazelight_vision::pooling::PlaneAngles;

/// Largest GPU FFT window, samples per side ([`crate::fft`]).
const MAX_GPU_WINDOW: usize = 2048;

/// The sizes of the split convolution for one kernel and weight window, as
/// `GlareConvolver::new` computes them.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct GlareGeometry {
    /// Fine kernel radius, display pixels.
    pub r_fine: usize,
    /// Coarse block, display pixels (odd).
    pub block: usize,
    /// Full-weight radius, pixels.
    pub d_full: f64,
    /// Fade σ, pixels.
    pub sigma: f64,
    /// Source radius where the weight reaches 0, pixels.
    pub r_src: f64,
    /// Fine window the CPU needs, pixels per side (before its FFT rounding).
    pub fine_needed: usize,
    /// Coarse window the CPU needs, blocks per side.
    pub coarse_needed: usize,
    /// GPU fine window (power of two ≥ `fine_needed`).
    pub wf: usize,
    /// GPU coarse window (power of two ≥ `coarse_needed`).
    pub wc: usize,
}

impl GlareGeometry {
    /// The geometry for a `kernel_size` kernel of `deg_per_px` pixels and the
    /// weight `window`; an error names the setting when a GPU window would
    /// exceed 2048 samples.
    pub fn new(kernel_size: usize, deg_per_px: f64, window: GlareWindow) -> Result<Self, GpuError> {
        let invalid = |source| GpuError::InvalidParams {
            what: "GPU glare",
            source,
        };
        window.validate().map_err(invalid)?;
        if !(deg_per_px.is_finite() && deg_per_px > 0.0) || kernel_size == 0 {
            return Err(invalid(VisionError::invalid(
                "glare kernel",
                format!("{kernel_size}x{kernel_size} at {deg_per_px} deg/px"),
                "a square kernel with a finite pixel size",
            )));
        }
        let GlareSizes {
            r_fine,
            block,
            d_full,
            sigma,
            r_src,
            fine_needed,
            coarse_needed,
            ..
        } = GlareSizes::new(kernel_size, deg_per_px, window);
        let (wf, wc) = (
            fine_needed.next_power_of_two(),
            coarse_needed.next_power_of_two(),
        );
        if wf > MAX_GPU_WINDOW || wc > MAX_GPU_WINDOW {
            return Err(invalid(VisionError::invalid(
                "glare.full_weight_deg",
                window.full_weight_deg,
                "a weight region (full_weight_deg + 3 fade_sigma_deg) whose GPU FFT windows at \
                 this ppd are ≤ 2048 samples",
            )));
        }
        Ok(Self {
            r_fine,
            block,
            d_full,
            sigma,
            r_src,
            fine_needed,
            coarse_needed,
            wf,
            wc,
        })
    }
}

/// Uniforms of `glare.wgsl` (`struct GlareParams`), field by field.
#[repr(C)]
#[derive(Debug, Clone, Copy, PartialEq, Pod, Zeroable)]
pub struct GlareParams {
    /// Fine window W_f, pixels.
    pub wf: u32,
    /// Coarse window W_c, blocks.
    pub wc: u32,
    /// Block b, pixels (odd).
    pub block: u32,
    /// Fine kernel radius, pixels.
    pub r_fine: u32,
    /// PSF kernel size, pixels.
    pub kernel_size: u32,
    /// Frame width.
    pub width: u32,
    /// Frame height.
    pub height: u32,
    /// Padding.
    pub _pad0: u32,
    /// Fine window origin x.
    pub ofx: i32,
    /// Fine window origin y.
    pub ofy: i32,
    /// Coarse window origin x.
    pub ocx: i32,
    /// Coarse window origin y.
    pub ocy: i32,
    /// Source box ∩ image, `[sx0, sx1) × [sy0, sy1)`.
    pub sx0: i32,
    /// See `sx0`.
    pub sx1: i32,
    /// See `sx0`.
    pub sy0: i32,
    /// See `sx0`.
    pub sy1: i32,
    /// Output region (coarse window ∩ image), `[x0, x1) × [y0, y1)`.
    pub x0: i32,
    /// See `x0`.
    pub x1: i32,
    /// See `x0`.
    pub y0: i32,
    /// See `x0`.
    pub y1: i32,
    /// Gaze x, frame pixels.
    pub gaze_x: f32,
    /// Gaze y, frame pixels.
    pub gaze_y: f32,
    /// Full-weight radius, pixels.
    pub d_full: f32,
    /// Fade σ, pixels.
    pub sigma: f32,
    /// What a source pixel keeps of its own light, `keep0 − keep_slope·w`:
    /// 1 and 1 without the far field, `1 − E_near − E_tail` and
    /// `1 − E_near` with it ([`crate::far_glare`]).
    pub keep0: f32,
    /// See `keep0`.
    pub keep_slope: f32,
    /// Padding.
    pub _pad1: u32,
    /// Padding.
    pub _pad2: u32,
}

impl GlareParams {
    /// The static part for `geometry`, a `kernel_size` kernel and the frame.
    pub fn new(geometry: &GlareGeometry, kernel_size: u32, width: u32, height: u32) -> Self {
        Self {
            wf: geometry.wf as u32,
            wc: geometry.wc as u32,
            block: geometry.block as u32,
            r_fine: geometry.r_fine as u32,
            kernel_size,
            width,
            height,
            d_full: geometry.d_full as f32,
            sigma: geometry.sigma as f32,
            keep0: 1.0,
            keep_slope: 1.0,
            ..Self::zeroed()
        }
    }

    /// Places the windows at `gaze_px` as `GlareConvolver::apply` does;
    /// `false` when that applies no glare (bad gaze, no source pixel in the
    /// image, empty output region).
    pub fn place(&mut self, geometry: &GlareGeometry, gaze_px: [f64; 2]) -> bool {
        if !gaze_px[0].is_finite() || !gaze_px[1].is_finite() {
            return false;
        }
        let (iw, ih) = (i64::from(self.width), i64::from(self.height));
        let (wf, wc) = (i64::from(self.wf), i64::from(self.wc));
        let b = i64::from(self.block);
        let hb = b / 2;
        let limit = (iw.max(ih) + 2 * wf * b) as f64;
        let gx = gaze_px[0].clamp(-limit, limit);
        let gy = gaze_px[1].clamp(-limit, limit);
        let (gxi, gyi) = (gx.floor() as i64, gy.floor() as i64);
        let (ofx, ofy) = (gxi - wf / 2, gyi - wf / 2);
        let (ocx, ocy) = (gxi - hb - (wc / 2) * b, gyi - hb - (wc / 2) * b);
        let rs = geometry.r_src.ceil() as i64 + 1;
        let (sx0, sx1) = ((gxi - rs).max(0), (gxi + rs + 1).min(iw));
        let (sy0, sy1) = ((gyi - rs).max(0), (gyi + rs + 1).min(ih));
        if sx0 >= sx1 || sy0 >= sy1 {
            return false;
        }
        let (x0, x1) = (ocx.max(0), (ocx + wc * b).min(iw));
        let (y0, y1) = (ocy.max(0), (ocy + wc * b).min(ih));
        if x0 >= x1 || y0 >= y1 {
            return false;
        }
        let to = |v: i64| v as i32;
        (self.ofx, self.ofy, self.ocx, self.ocy) = (to(ofx), to(ofy), to(ocx), to(ocy));
        (self.sx0, self.sx1, self.sy0, self.sy1) = (to(sx0), to(sx1), to(sy0), to(sy1));
        (self.x0, self.x1, self.y0, self.y1) = (to(x0), to(x1), to(y0), to(y1));
        self.gaze_x = gx as f32;
        self.gaze_y = gy as f32;
        true
    }

    /// Output region size, pixels (`x1 − x0`, `y1 − y0`).
    pub fn output_size(&self) -> (u32, u32) {
        ((self.x1 - self.x0) as u32, (self.y1 - self.y0) as u32)
    }
}

/// `shaders/glare.wgsl`: the kernel split (fine core, coarse wide field),
/// the weighted sources, the spectrum products and the blend.
pub const GLARE_PASS: PassDescriptor = PassDescriptor {
    shader: shaders::GLARE,
    entry_points: &[
        "kernel_fine",
        "kernel_coarse",
        "gather_fine",
        "gather_coarse",
        "multiply_fine",
        "multiply_coarse",
        "blend",
    ],
    bindings: &[
        Binding::uniform::<GlareParams>("params"),
        Binding::read::<[f32; 4]>("kernel"),
        Binding::read_write::<[f32; 2]>("fine"),
        Binding::read::<[f32; 2]>("fine_spectrum"),
        Binding::read_write::<[f32; 2]>("coarse"),
        Binding::read::<[f32; 2]>("coarse_spectrum"),
        Binding::read_write::<[f32; 4]>("work"),
    ],
};

/// The twin of `shaders/glare.wgsl` ([`GLARE_PASS`]). Bindings:
/// 0 [`GlareParams`], 1 PSF kernel (`vec4<f32>`, read-only), 2 the fine
/// FFT's data buffer, 3 the cached fine kernel spectrum (read-only), 4 the
/// coarse FFT's data buffer, 5 the cached coarse kernel spectrum
/// (read-only), 6 the working frame (RGBA f32).
#[derive(Debug, Clone)]
pub struct GlarePass {
    pub(crate) layout: PassLayout,
    pub(crate) kernel_fine: wgpu::ComputePipeline,
    pub(crate) kernel_coarse: wgpu::ComputePipeline,
    pub(crate) gather_fine: wgpu::ComputePipeline,
    pub(crate) gather_coarse: wgpu::ComputePipeline,
    pub(crate) multiply_fine: wgpu::ComputePipeline,
    pub(crate) multiply_coarse: wgpu::ComputePipeline,
    pub(crate) blend: wgpu::ComputePipeline,
}

impl GlarePass {
    /// Checks the shader against the device limits and builds the pipelines.
    pub fn new(ctx: &GpuContext) -> Result<Self, GpuError> {
        let (layout, [kf, kc, gf, gc, mf, mc, blend]) = GLARE_PASS.build(ctx)?;
        Ok(Self {
            layout,
            kernel_fine: kf,
            kernel_coarse: kc,
            gather_fine: gf,
            gather_coarse: gc,
            multiply_fine: mf,
            multiply_coarse: mc,
            blend,
        })
    }

    /// The bind group layout (group 0).
    pub fn bind_group_layout(&self) -> &wgpu::BindGroupLayout {
        self.layout.layout()
    }
}

/// Stage 4 of [`crate::frame::GpuFramePipeline`]: the PSF builder, the
/// split geometry, both FFT plans and the glare pass with their buffers.
pub(crate) struct GlareStage {
    pub(crate) psf: GpuPsfBuilder,
    geometry: GlareGeometry,
    fine: GpuFft2d,
    coarse: GpuFft2d,
    pass: GlarePass,
    params: GlareParams,
    uniform: wgpu::Buffer,
    fine_spectrum: wgpu::Buffer,
    coarse_spectrum: wgpu::Buffer,
    group: wgpu::BindGroup,
    /// The pupil of the kernel on the GPU, and the one rule for the next.
    pub(crate) follower: KernelFollower,
    /// The full-field stray light ([`crate::far_glare`]), when on.
    far: Option<FarStage>,
    /// The kernel's radius and pixel size, the far field's split.
    kernel_deg_per_px: f64,
    frame_size: (usize, usize),
}

impl GlareStage {
    /// The glare stage of `config` for the frame: the first PSF (4 mm),
    /// the split geometry, both FFT plans, the kernel spectra buffers and
    /// the bind group on the working frame `work`.
    pub(crate) fn new(
        ctx: &GpuContext,
        config: &PipelineConfig,
        deg_per_px: f64,
        sizes: &FrameSizes,
        work: &wgpu::Buffer,
        angles: PlaneAngles,
    ) -> Result<Self, GpuError> {
        let mut params = config.glare.psf.clone();
        params.ppd = 1.0 / deg_per_px;
        params.pupil_mm = INITIAL_PUPIL_MM;
        params.validate().map_err(invalid)?;
        let psf = GpuPsfBuilder::new(ctx, &params)?;
        let geometry = GlareGeometry::new(psf.kernel_size(), deg_per_px, config.glare.window())?;
        let (wf, wc) = (geometry.wf as u32, geometry.wc as u32);
        let fine = GpuFft2d::new(ctx, wf, wf, 3)?;
        let coarse = GpuFft2d::new(ctx, wc, wc, 3)?;
        let pass = GlarePass::new(ctx)?;
        let glare_params = GlareParams::new(
            &geometry,
            psf.kernel_size() as u32,
            sizes.width,
            sizes.height,
        );
        let uniform = create_buffer(
            ctx,
            "glare params",
            size_of::<GlareParams>() as u64,
            UNIFORM,
        )?;
        let spectrum = |label, n: u32| create_buffer(ctx, label, u64::from(n * n) * 3 * 8, STORAGE);
        let fine_spectrum = spectrum("glare fine kernel spectrum", wf)?;
        let coarse_spectrum = spectrum("glare coarse kernel spectrum", wc)?;
        let group = pass.layout.bind_buffers(
            ctx,
            &[
                &uniform,
                psf.kernel_buffer(),
                fine.data_buffer(),
                &fine_spectrum,
                coarse.data_buffer(),
                &coarse_spectrum,
                work,
            ],
        )?;
        let kernel_deg_per_px = psf.setup().sampling().deg_per_px;
        let mut stage = Self {
            psf,
            geometry,
            fine,
            coarse,
            pass,
            params: glare_params,
            uniform,
            fine_spectrum,
            coarse_spectrum,
            group,
            follower: KernelFollower::new(KernelPolicy::new(&config.glare), 1, INITIAL_PUPIL_MM),
            far: None,
            kernel_deg_per_px,
            frame_size: (sizes.width as usize, sizes.height as usize),
        };
        stage.set_angles(ctx, config, angles, work)?;
        Ok(stage)
    }

    /// Builds the far field for the view's geometry `angles` (its grid
    /// follows the projection; allocating: call it when the geometry
    /// changed), or none when the configuration has none
    /// ([`gazelight_vision::pipeline::far_field`], the CPU's decision).
    pub(crate) fn set_angles(
        &mut self,
        ctx: &GpuContext,
        config: &PipelineConfig,
        angles: PlaneAngles,
        work: &wgpu::Buffer,
    ) -> Result<(), GpuError> {
        let (width, height) = self.frame_size;
        let cpu = gazelight_vision::pipeline::far_field(
            &config.glare,
            self.psf.params(),
            self.psf.kernel_size(),
            self.kernel_deg_per_px,
            width,
            height,
            angles,
        )
        .map_err(invalid)?;
        self.far = match cpu {
            Some(cpu) => Some(FarStage::new(ctx, &cpu, work, &self.uniform)?),
            None => None,
        };
        (self.params.keep0, self.params.keep_slope) =
            self.far.as_ref().map_or((1.0, 1.0), FarStage::keep);
        ctx.queue()
            .write_buffer(&self.uniform, 0, bytemuck::bytes_of(&self.params));
        Ok(())
    }

    /// Whether the full-field stray light is on.
    #[cfg(test)]
    pub(crate) fn has_far_field(&self) -> bool {
        self.far.is_some()
    }

    /// Records the split of the kernel in the PSF buffer into its fine and
    /// coarse parts and their spectra (timestamps 4–5 of `timestamps`).
    pub(crate) fn encode_kernel_spectrum(
        &self,
        encoder: &mut wgpu::CommandEncoder,
        timestamps: Option<&wgpu::QuerySet>,
    ) {
        let (wf, wc) = (self.params.wf, self.params.wc);
        {
            let mut pass = encoder.begin_compute_pass(&wgpu::ComputePassDescriptor {
                label: Some("glare kernel split: fine core, coarse wide field"),
                timestamp_writes: timestamp_writes(timestamps, Some(4), None),
            });
            pass.set_bind_group(0, &self.group, &[]);
            pass.set_pipeline(&self.pass.kernel_fine);
            pass.dispatch_workgroups(wf.div_ceil(TILE), wf.div_ceil(TILE), 1);
            pass.set_pipeline(&self.pass.kernel_coarse);
            pass.dispatch_workgroups(wc.div_ceil(TILE), wc.div_ceil(TILE), 1);
        }
        self.fine.encode(encoder, FftDirection::Forward, None);
        self.coarse.encode(
            encoder,
            FftDirection::Forward,
            timestamp_writes(timestamps, None, Some(5)),
        );
        let copy = |encoder: &mut wgpu::CommandEncoder, from: &GpuFft2d, to: &wgpu::Buffer| {
            encoder.copy_buffer_to_buffer(from.data_buffer(), 0, to, 0, to.size());
        };
        copy(encoder, &self.fine, &self.fine_spectrum);
        copy(encoder, &self.coarse, &self.coarse_spectrum);
    }

    /// Records the glare of the windows placed at `gaze_px` (timestamps
    /// 6–7); nothing when that applies no glare.
    pub(crate) fn encode_window(
        &mut self,
        ctx: &GpuContext,
        encoder: &mut wgpu::CommandEncoder,
        gaze_px: [f64; 2],
        timestamps: Option<&wgpu::QuerySet>,
    ) {
        let placed = self.params.place(&self.geometry, gaze_px);
        if placed {
            ctx.queue()
                .write_buffer(&self.uniform, 0, bytemuck::bytes_of(&self.params));
        }
        // The far field's block sums read the frame before the blend.
        if let Some(far) = self.far.as_mut() {
            far.encode_sums(ctx, encoder, placed);
        }
        if placed {
            self.encode_placed(ctx, encoder, timestamps);
        }
        if let Some(far) = self.far.as_ref() {
            far.encode_veil(ctx, encoder, timestamp_writes(timestamps, None, Some(7)));
        }
    }

    /// [`GlareStage::encode_window`] of a placed window.
    fn encode_placed(
        &self,
        ctx: &GpuContext,
        encoder: &mut wgpu::CommandEncoder,
        timestamps: Option<&wgpu::QuerySet>,
    ) {
        let (wf, wc) = (self.params.wf, self.params.wc);
        let max = ctx.limits().max_compute_workgroups_per_dimension;
        let linear = |n: u32| {
            let groups = n.div_ceil(64);
            let gx = groups.min(max);
            (gx, groups.div_ceil(gx))
        };
        let steps: [(&str, Option<u32>, _); 2] = [
            (
                "stage 4: glare sources",
                Some(6),
                [
                    (&self.pass.gather_fine, tiles(wf, wf)),
                    (&self.pass.gather_coarse, tiles(wc, wc)),
                ],
            ),
            (
                "stage 4: glare spectrum products",
                None,
                [
                    (&self.pass.multiply_fine, linear(3 * wf * wf)),
                    (&self.pass.multiply_coarse, linear(3 * wc * wc)),
                ],
            ),
        ];
        for (direction, (label, begin, dispatches)) in
            [FftDirection::Forward, FftDirection::Inverse]
                .into_iter()
                .zip(steps)
        {
            let mut pass = encoder.begin_compute_pass(&wgpu::ComputePassDescriptor {
                label: Some(label),
                timestamp_writes: timestamp_writes(timestamps, begin, None),
            });
            pass.set_bind_group(0, &self.group, &[]);
            for (pipeline, (gx, gy)) in dispatches {
                pass.set_pipeline(pipeline);
                pass.dispatch_workgroups(gx, gy, 1);
            }
            drop(pass);
            self.fine.encode(encoder, direction, None);
            self.coarse.encode(encoder, direction, None);
        }
        // The end timestamp after the far field's blend when it is on.
        let end = if self.far.is_some() { None } else { Some(7) };
        let mut pass = encoder.begin_compute_pass(&wgpu::ComputePassDescriptor {
            label: Some("stage 4: glare blend"),
            timestamp_writes: timestamp_writes(timestamps, None, end),
        });
        pass.set_bind_group(0, &self.group, &[]);
        pass.set_pipeline(&self.pass.blend);
        let (ow, oh) = self.params.output_size();
        let (gx, gy) = tiles(ow, oh);
        pass.dispatch_workgroups(gx, gy, 1);
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use gazelight_vision::glare::GlareConvolver;
    use gazelight_vision::psf::PsfKernel;

    #[test]
    fn geometry_is_the_cpu_convolvers_at_every_ppd() {
        // The ±20° kernel's size at each ppd; values do not matter here.
        for ppd in [1.5f64, 4.0, 4.9, 6.4, 12.0, 20.0] {
            let size = 2 * (20.0 * ppd).round() as usize + 1;
            let kernel = PsfKernel {
                size,
                deg_per_px: 1.0 / ppd,
                pupil_mm: 4.0,
                wavelengths_nm: vec![575.0],
                rgb: vec![[0.0; 3]; size * size],
            };
            let window = GlareWindow::default();
            let cpu = GlareConvolver::new(&kernel, window).unwrap();
            let gpu = GlareGeometry::new(size, 1.0 / ppd, window).unwrap();
            assert_eq!(gpu.r_fine, cpu.fine_radius_px(), "{ppd} ppd");
            assert_eq!(gpu.block, cpu.block_px(), "{ppd} ppd");
            assert_eq!(gpu.r_src, cpu.source_radius_px(), "{ppd} ppd");
            assert!(gpu.wf >= cpu.fine_window_px() && gpu.wf.is_power_of_two());
            assert!(gpu.wc >= cpu.coarse_window_blocks() && gpu.wc.is_power_of_two());
        }
        // A weight region too wide for the GPU's 2048-sample FFT is an error.
        let far = GlareWindow {
            full_weight_deg: 60.0,
            fade_sigma_deg: 10.0,
        };
        let err = GlareGeometry::new(2001, 1.0 / 20.0, far).unwrap_err();
        assert!(err.to_string().contains("glare.full_weight_deg"), "{err}");
    }

    /// The glare pass alone (kernel split, both FFT windows, blend) on a
    /// night view at 14 ppd with a ±2° kernel, against
    /// `GlareConvolver::apply` on the same kernel, gaze on the brightest
    /// lamp and near a corner.
    #[test]
    fn glare_pass_matches_the_cpu_convolver() {
        use crate::frame::FrameSizes;
        use crate::testing::pass_harness::{panorama_view, read, storage, texels};
        use gazelight_vision::pipeline::PipelineConfig;
        use gazelight_vision::psf::PsfBuilder;
        let Some(ctx) = crate::testing::test_context("glare_pass_matches_the_cpu_convolver") else {
            return;
        };
        let (w, h) = (80usize, 64usize);
        let (img, dpp) = panorama_view("night.exr", -78.4, -6.0, 80.0 / 14.0, [w, h]);
        let mut config = PipelineConfig::default();
        config.glare.psf.field_deg = 4.0;
        // The window alone (the far field: crate::far_glare's test).
        config.glare.far_field = false;
        let mut params = config.glare.psf.clone();
        params.ppd = 1.0 / dpp;
        params.pupil_mm = 4.0;
        let builder = PsfBuilder::new(params).unwrap();
        let mut conv = GlareConvolver::new(builder.kernel(), config.glare.window()).unwrap();
        let sizes = FrameSizes::new(&config, w as u32, h as u32);
        let (mut at, mut best) = (0usize, f32::MIN);
        for (i, p) in img.pixels.iter().enumerate() {
            let l = gazelight_vision::image::luminance(*p);
            if l > best {
                (best, at) = (l, i);
            }
        }
        let lamp = [(at % w) as f64 + 0.5, (at / w) as f64 + 0.5];
        for gaze_px in [lamp, [6.0, 58.0]] {
            let work = storage(ctx, &texels(&img));
            let angles = PlaneAngles::Uniform { deg_per_px: dpp };
            let mut stage = GlareStage::new(ctx, &config, dpp, &sizes, &work, angles).unwrap();
            let mut encoder = ctx.device().create_command_encoder(&Default::default());
            stage.encode_kernel_spectrum(&mut encoder, None);
            stage.encode_window(ctx, &mut encoder, gaze_px, None);
            ctx.queue().submit([encoder.finish()]);
            let gpu: Vec<[f32; 4]> = read(ctx, &work);
            let mut cpu = img.clone();
            conv.apply(&mut cpu, gaze_px);
            let peak = cpu.pixels.iter().flatten().fold(0.0f32, |m, &v| m.max(v));
            let (mut max_err, mut changed) = (0.0f32, 0.0f32);
            for ((g, c), s) in gpu.iter().zip(&cpu.pixels).zip(&img.pixels) {
                for k in 0..3 {
                    max_err = max_err.max((g[k] - c[k]).abs());
                    changed = changed.max((c[k] - s[k]).abs());
                }
            }
            let e = max_err / peak;
            println!(
                "gaze {gaze_px:?}: max |GPU − CPU| {max_err:.3e} = {e:.2e} of the peak \
                 {peak:.3e} cd/m²; the glare moved pixels by up to {changed:.3e}"
            );
            if gaze_px == lamp {
                assert!(changed > 1e3 * max_err, "glare too weak to test: {changed}");
            }
            assert!(e < 1e-4, "{e:e}");
        }
    }
}
