//! Stage 4 on the GPU, the twin of `shaders/glare.wgsl`: the windowed FFT
//! glare of [`gazelight_vision::glare::GlareConvolver`] (001 §4.2.3) — the
//! frame's light within `R` of the gaze, weighted by the Gaussian falloff,
//! convolved with the glare kernel by FFT ([`crate::fft::GpuFft2d`], three
//! planes) in a `W×W` window at the gaze, and blended back as
//! `(1 − w)·img + K ∗ (w·img)`. The kernel's spectrum is made on the GPU
//! from [`crate::GpuPsfBuilder`]'s kernel buffer after each PSF rebuild
//! (crop to radius `min(size/2, W/4)`, per-channel renormalisation, forward
//! FFT) and cached between rebuilds.
//!
//! The window placement, `R`, `G(R)` and `1/2σ²` are computed on the host in
//! f64 as the CPU does ([`GlareParams::place`]); the falloff weights and the
//! convolution run in f32 (the CPU's spectra are f32 too).

use bytemuck::{Pod, Zeroable};

use crate::context::GpuContext;
use crate::error::GpuError;
use crate::psf::{layout, storage_entry, uniform_entry};
use crate::shaders;

/// Uniforms of `glare.wgsl` (`struct GlareParams`), field by field.
#[repr(C)]
#[derive(Debug, Clone, Copy, PartialEq, Pod, Zeroable)]
pub struct GlareParams {
    /// Window size W.
    pub window: u32,
    /// PSF kernel size, pixels.
    pub kernel_size: u32,
    /// Radius of the cropped kernel, `min(size/2, W/4)`.
    pub radius: u32,
    /// 1: the σ → ∞ limit weight `1 − d²/R²`.
    pub linear_limit: u32,
    /// Frame width.
    pub width: u32,
    /// Frame height.
    pub height: u32,
    /// Window origin x in the frame.
    pub origin_x: i32,
    /// Window origin y in the frame.
    pub origin_y: i32,
    /// Window ∩ image, window coordinates `[i0, i1) × [j0, j1)`.
    pub i0: u32,
    /// See `i0`.
    pub i1: u32,
    /// See `i0`.
    pub j0: u32,
    /// See `i0`.
    pub j1: u32,
    /// Gaze x, frame pixels.
    pub gaze_x: f32,
    /// Gaze y, frame pixels.
    pub gaze_y: f32,
    /// `1/(2σ²)`, σ the falloff, pixels.
    pub inv_2s2: f32,
    /// `R²`, R the largest source distance that glares.
    pub r2: f32,
    /// `G(R) = e^(−R²/2σ²)`.
    pub g_r: f32,
    /// Padding.
    pub _pad0: f32,
    /// Padding.
    pub _pad1: f32,
    /// Padding.
    pub _pad2: f32,
}

impl GlareParams {
    /// The static part: window, kernel size and cropped radius, frame size.
    pub fn new(window: u32, kernel_size: u32, width: u32, height: u32) -> Self {
        Self {
            window,
            kernel_size,
            radius: (kernel_size / 2).min(window / 4),
            linear_limit: 0,
            width,
            height,
            origin_x: 0,
            origin_y: 0,
            i0: 0,
            i1: 0,
            j0: 0,
            j1: 0,
            gaze_x: 0.0,
            gaze_y: 0.0,
            inv_2s2: 0.0,
            r2: 0.0,
            g_r: 0.0,
            _pad0: 0.0,
            _pad1: 0.0,
            _pad2: 0.0,
        }
    }

    /// `R = W/2 − r − 1`, pixels.
    pub fn source_radius_px(&self) -> f64 {
        f64::from(self.window / 2) - f64::from(self.radius) - 1.0
    }

    /// Places the window at `gaze_px` with falloff σ `falloff_sigma_px`, as
    /// `GlareConvolver::apply`; `false` when that applies no glare (window
    /// off the image, `R ≤ 0`, bad gaze or σ).
    pub fn place(&mut self, gaze_px: [f64; 2], falloff_sigma_px: f64) -> bool {
        if !gaze_px[0].is_finite()
            || !gaze_px[1].is_finite()
            || falloff_sigma_px.is_nan()
            || falloff_sigma_px <= 0.0
        {
            return false;
        }
        let w = i64::from(self.window);
        let half = w / 2;
        let (iw, ih) = (i64::from(self.width), i64::from(self.height));
        let limit = (iw.max(ih) + 2 * w) as f64;
        let gx = gaze_px[0].clamp(-limit, limit);
        let gy = gaze_px[1].clamp(-limit, limit);
        let ox = gx.floor() as i64 - half;
        let oy = gy.floor() as i64 - half;
        if ox + w <= 0 || oy + w <= 0 || ox >= iw || oy >= ih {
            return false;
        }
        let r_src = self.source_radius_px();
        if r_src <= 0.0 {
            return false;
        }
        let inv_2s2 = 1.0 / (2.0 * falloff_sigma_px * falloff_sigma_px);
        let g_r = (-r_src * r_src * inv_2s2).exp();
        self.origin_x = ox as i32;
        self.origin_y = oy as i32;
        self.i0 = (-ox).max(0) as u32;
        self.j0 = (-oy).max(0) as u32;
        self.i1 = (iw - ox).min(w) as u32;
        self.j1 = (ih - oy).min(w) as u32;
        self.gaze_x = gx as f32;
        self.gaze_y = gy as f32;
        self.inv_2s2 = inv_2s2 as f32;
        self.r2 = (r_src * r_src) as f32;
        self.g_r = g_r as f32;
        // GlareConvolver's falloff_weight: the limit where 1 − G(R) vanishes.
        self.linear_limit = u32::from(1.0 - g_r <= 1e-9);
        true
    }
}

/// The twin of `shaders/glare.wgsl`. Bindings: 0 [`GlareParams`], 1 PSF
/// kernel (`vec4<f32>`, read-only), 2 kernel sums (`vec4<f32>`), 3 the FFT's
/// data buffer (3 planes of W² `vec2<f32>`), 4 the cached kernel spectrum
/// (read-only), 5 the working frame (RGBA f32).
#[derive(Debug, Clone)]
pub struct GlarePass {
    layout: wgpu::BindGroupLayout,
    pub(crate) kernel_sums: wgpu::ComputePipeline,
    pub(crate) kernel_scatter: wgpu::ComputePipeline,
    pub(crate) window_gather: wgpu::ComputePipeline,
    pub(crate) spectrum_multiply: wgpu::ComputePipeline,
    pub(crate) blend: wgpu::ComputePipeline,
}

impl GlarePass {
    /// Checks the shader against the device limits and builds the pipelines.
    pub fn new(ctx: &GpuContext) -> Result<Self, GpuError> {
        let layout = layout(
            ctx,
            "glare.wgsl",
            &[
                uniform_entry::<GlareParams>(0),
                storage_entry(1, true),
                storage_entry(2, false),
                storage_entry(3, false),
                storage_entry(4, true),
                storage_entry(5, false),
            ],
        )?;
        let s = &shaders::GLARE;
        Ok(Self {
            kernel_sums: ctx.create_compute_pipeline(s, "kernel_sums", &[&layout])?,
            kernel_scatter: ctx.create_compute_pipeline(s, "kernel_scatter", &[&layout])?,
            window_gather: ctx.create_compute_pipeline(s, "window_gather", &[&layout])?,
            spectrum_multiply: ctx.create_compute_pipeline(s, "spectrum_multiply", &[&layout])?,
            blend: ctx.create_compute_pipeline(s, "blend", &[&layout])?,
            layout,
        })
    }

    /// The bind group layout (group 0).
    pub fn bind_group_layout(&self) -> &wgpu::BindGroupLayout {
        &self.layout
    }
}
