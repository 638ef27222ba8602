//! Stage 5 (+ 8) on the GPU, the twin of `shaders/acuity.wgsl`: the acuity
//! σ from the adaptation luminance with the σ rules of
//! [`gazelight_vision::acuity::AcuityModel`] (001 eq 11–13), the normalised
//! Gaussian taps (one thread), then the separable blur of CIE Lab lightness
//! (horizontal, vertical with the pixel's own a*, b*) and the encoding — the
//! CPU's `AcuityBlur::apply` followed by its encode. The blur is skipped on
//! the GPU (no read-back) when σ ≤ [`AcuityBlur::MIN_SIGMA_PX`].
//!
//! [`AcuityBlur::MIN_SIGMA_PX`]: gazelight_vision::acuity::AcuityBlur::MIN_SIGMA_PX

use bytemuck::{Pod, Zeroable};
use gazelight_vision::acuity::{AcuityModel, VIVE_PRO_PPD};

use crate::context::GpuContext;
use crate::error::GpuError;
use crate::psf::{layout, storage_entry, uniform_entry};
use crate::shaders;

/// Uniforms of `acuity.wgsl` (`struct AcuityParams`), field by field.
#[repr(C)]
#[derive(Debug, Clone, Copy, PartialEq, Pod, Zeroable)]
pub struct AcuityParams {
    /// Frame width.
    pub width: u32,
    /// Frame height.
    pub height: u32,
    /// 0 linear in lightness, 1 Larson/Krawczyk, 2 none.
    pub model: u32,
    /// Largest blur radius the tap buffer holds.
    pub max_radius: u32,
    /// Also write the display-linear frame.
    pub keep_linear: u32,
    /// Padding.
    pub _pad0: u32,
    /// Padding.
    pub _pad1: u32,
    /// Padding.
    pub _pad2: u32,
    /// Lab white of model 0, cd/m².
    pub white_cd_m2: f32,
    /// `ppd/13.85` (model 0) or `ppd/(1.86·√2)` (model 1).
    pub sigma_scale: f32,
    /// Padding.
    pub _pad3: f32,
    /// Padding.
    pub _pad4: f32,
}

impl AcuityParams {
    /// The uniforms for `model` on a display of `deg_per_px`.
    pub fn new(
        model: &AcuityModel,
        deg_per_px: f64,
        width: u32,
        height: u32,
        keep_linear: bool,
    ) -> Self {
        let ppd = 1.0 / deg_per_px;
        let (m, white, scale) = match *model {
            // 001 eq 12: σ in pixels at the Vive Pro's 13.85 ppd, scaled to the display
            AcuityModel::Linear { lab_white_cd_m2 } => (0, lab_white_cd_m2, ppd / VIVE_PRO_PPD),
            // 001 eq 13: σ = ppd / (1.86·√2·R)
            AcuityModel::LarsonKrawczyk => (1, 1.0, ppd / (1.86 * std::f64::consts::SQRT_2)),
            AcuityModel::None => (2, 1.0, 0.0),
        };
        Self {
            width,
            height,
            model: m,
            max_radius: max_radius(model, deg_per_px),
            keep_linear: u32::from(keep_linear),
            _pad0: 0,
            _pad1: 0,
            _pad2: 0,
            white_cd_m2: white as f32,
            sigma_scale: scale as f32,
            _pad3: 0.0,
            _pad4: 0.0,
        }
    }
}

/// The largest blur radius `model` can ask for: σ grows as the luminance
/// falls, so σ at 0 cd/m² bounds it (plus one pixel for f32 rounding).
pub fn max_radius(model: &AcuityModel, deg_per_px: f64) -> u32 {
    let sigma = model.sigma_px(0.0, deg_per_px);
    if sigma.is_finite() && sigma > 0.0 {
        (3.0 * f64::from(sigma)).ceil() as u32 + 1
    } else {
        0
    }
}

/// The twin of `shaders/acuity.wgsl`. Bindings: 0 [`AcuityParams`],
/// 1 [`crate::frame::FrameState`], 2 taps (f32), 3 Lab frame (read-only),
/// 4 horizontal pass (f32), 5 display-linear frame, 6 sRGB table
/// (read-only), 7 RGBA8 output.
#[derive(Debug, Clone)]
pub struct AcuityPass {
    layout: wgpu::BindGroupLayout,
    pub(crate) prepare: wgpu::ComputePipeline,
    pub(crate) blur_h: wgpu::ComputePipeline,
    pub(crate) blur_v: wgpu::ComputePipeline,
}

impl AcuityPass {
    /// Checks the shader against the device limits and builds the pipelines.
    pub fn new(ctx: &GpuContext) -> Result<Self, GpuError> {
        let layout = layout(
            ctx,
            "acuity.wgsl",
            &[
                uniform_entry::<AcuityParams>(0),
                storage_entry(1, false),
                storage_entry(2, false),
                storage_entry(3, true),
                storage_entry(4, false),
                storage_entry(5, false),
                storage_entry(6, true),
                storage_entry(7, false),
            ],
        )?;
        let s = &shaders::ACUITY;
        Ok(Self {
            prepare: ctx.create_compute_pipeline(s, "prepare_acuity", &[&layout])?,
            blur_h: ctx.create_compute_pipeline(s, "blur_h", &[&layout])?,
            blur_v: ctx.create_compute_pipeline(s, "blur_v", &[&layout])?,
            layout,
        })
    }

    /// The bind group layout (group 0).
    pub fn bind_group_layout(&self) -> &wgpu::BindGroupLayout {
        &self.layout
    }
}
