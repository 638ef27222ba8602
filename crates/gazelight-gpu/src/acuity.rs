//! Stage 5 on the GPU, the twin of `shaders/acuity.wgsl`: the per-pixel-σ
//! blur of CIE Lab lightness of [`gazelight_vision::band::AcuityBlur`]
//! (001 §4.3.1, eq 11–13) on the HDR frame in cd/m², after glare and before
//! tone reproduction. Every pixel's σ comes from its own lightness against
//! the fixed Lab white `lab_white_cd_m2` (horizontal pass) and from its
//! horizontally blurred lightness (vertical pass), with the CPU's Gaussian
//! weight recurrence; pixels whose lightness did not change are left
//! bit-identical, the others keep their a\*, b\*. The CPU skips rows that
//! hold no pixel to blur; the GPU runs every pixel, which gives the same
//! result (such a pixel's σ ≤ [`AcuityBlur::MIN_SIGMA_PX`] keeps it as it
//! is). When no pixel can ever blur ([`AcuityBlur::max_radius`] = 0) the
//! host skips the per-pixel passes, as the CPU returns at once.
//!
//! [`AcuityBlur::MIN_SIGMA_PX`]: gazelight_vision::band::AcuityBlur::MIN_SIGMA_PX
//! [`AcuityBlur::max_radius`]: gazelight_vision::band::AcuityBlur::max_radius

use bytemuck::{Pod, Zeroable};
use gazelight_vision::acuity::{AcuityModel, VIVE_PRO_PPD};
use gazelight_vision::band::AcuityBlur;

use crate::context::GpuContext;
use crate::error::GpuError;
use crate::frame::FrameState;
use crate::pass::{Binding, PassDescriptor, PassLayout};
use crate::shaders;

/// Uniforms of `acuity.wgsl` (`struct AcuityParams`), field by field.
#[repr(C)]
#[derive(Debug, Clone, Copy, PartialEq, Pod, Zeroable)]
pub struct AcuityParams {
    /// Frame width.
    pub width: u32,
    /// Frame height.
    pub height: u32,
    /// 0 linear in lightness (001 eq 12), 1 Larson/Krawczyk, 2 none.
    pub model: u32,
    /// Largest tap radius any pixel gets; 0 = never blurs.
    pub max_radius: u32,
    /// Lab white, cd/m².
    pub white_cd_m2: f32,
    /// `ppd/13.85` (model 0) or `ppd/(1.86·√2)` (model 1).
    pub sigma_scale: f32,
    /// Padding.
    pub _pad0: f32,
    /// Padding.
    pub _pad1: f32,
}

impl AcuityParams {
    /// The uniforms for `model` on `width × height` frames of `deg_per_px`.
    pub fn new(model: &AcuityModel, deg_per_px: f64, width: u32, height: u32) -> Self {
        let ppd = if deg_per_px.is_finite() && deg_per_px > 0.0 {
            1.0 / deg_per_px
        } else {
            0.0
        };
        let (m, scale) = match *model {
            // 001 eq 12: σ in pixels at the Vive Pro's 13.85 ppd, scaled to the display
            AcuityModel::Linear { .. } => (0, ppd / VIVE_PRO_PPD),
            // 001 eq 13: σ = ppd / (1.86·√2·R)
            AcuityModel::LarsonKrawczyk => (1, ppd / (1.86 * std::f64::consts::SQRT_2)),
            AcuityModel::None => (2, 0.0),
        };
        Self {
            width,
            height,
            model: m,
            max_radius: max_radius(model, deg_per_px),
            white_cd_m2: model.lab_white_cd_m2() as f32,
            sigma_scale: scale as f32,
            _pad0: 0.0,
            _pad1: 0.0,
        }
    }
}

/// The largest tap radius of `model` on a display of `deg_per_px`: the
/// CPU's [`AcuityBlur::max_radius`] (σ at 0 cd/m², capped at
/// [`AcuityBlur::MAX_RADIUS_PX`]; 0 when no pixel can blur).
pub fn max_radius(model: &AcuityModel, deg_per_px: f64) -> u32 {
    AcuityBlur::new(model, 1, 1, deg_per_px).max_radius() as u32
}

/// `shaders/acuity.wgsl`: the frame's σ (one thread), lightness, the
/// horizontal and the vertical pass.
pub const ACUITY_PASS: PassDescriptor = PassDescriptor {
    shader: shaders::ACUITY,
    entry_points: &["prepare_acuity", "lightness", "blur_h", "blur_v"],
    bindings: &[
        Binding::uniform::<AcuityParams>("params"),
        Binding::read_write::<FrameState>("state"),
        Binding::read_write::<[f32; 4]>("work"),
        Binding::read_write::<f32>("lightness_buf"),
        Binding::read_write::<f32>("horizontal"),
    ],
};

/// The twin of `shaders/acuity.wgsl` ([`ACUITY_PASS`]). Bindings:
/// 0 [`AcuityParams`], 1 [`crate::frame::FrameState`], 2 the working frame
/// (RGBA f32, cd/m², blurred in place), 3 lightness (f32 per pixel),
/// 4 horizontal pass (f32 per pixel).
#[derive(Debug, Clone)]
pub struct AcuityPass {
    pub(crate) layout: PassLayout,
    pub(crate) prepare: wgpu::ComputePipeline,
    pub(crate) lightness: wgpu::ComputePipeline,
    pub(crate) blur_h: wgpu::ComputePipeline,
    pub(crate) blur_v: wgpu::ComputePipeline,
}

impl AcuityPass {
    /// Checks the shader against the device limits and builds the pipelines.
    pub fn new(ctx: &GpuContext) -> Result<Self, GpuError> {
        let (layout, [prepare, lightness, blur_h, blur_v]) = ACUITY_PASS.build(ctx)?;
        Ok(Self {
            layout,
            prepare,
            lightness,
            blur_h,
            blur_v,
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
        panorama_view, read, run_pass, storage, texels, tiles, uniform,
    };
    use crate::testing::test_context;

    /// The acuity pass alone on a night view (street lamps, dark facades)
    /// at 30 ppd, against `AcuityBlur::apply`: each pixel blurs with its own
    /// σ; a pixel the CPU leaves as it is must stay bit-identical.
    #[test]
    fn per_pixel_blur_matches_the_cpu_blur() {
        let Some(ctx) = test_context("per_pixel_blur_matches_the_cpu_blur") else {
            return;
        };
        let (w, h) = (64usize, 48usize);
        let (img, dpp) = panorama_view("night.exr", -78.4, -6.0, 64.0 / 30.0, [w, h]);
        let pass = AcuityPass::new(ctx).unwrap();
        for model in [AcuityModel::default(), AcuityModel::LarsonKrawczyk] {
            let params = AcuityParams::new(&model, dpp, w as u32, h as u32);
            let params_buf = uniform(ctx, &params);
            let state = storage(
                ctx,
                &[FrameState {
                    adaptation_cd_m2: 0.05,
                    ..FrameState::default()
                }],
            );
            let work = storage(ctx, &texels(&img));
            let lightness = storage(ctx, &vec![0.0f32; w * h]);
            let horizontal = storage(ctx, &vec![0.0f32; w * h]);
            run_pass(
                ctx,
                &pass.layout,
                &[&params_buf, &state, &work, &lightness, &horizontal],
                &[
                    (&pass.prepare, [1, 1, 1]),
                    (&pass.lightness, tiles(w, h)),
                    (&pass.blur_h, tiles(w, h)),
                    (&pass.blur_v, tiles(w, h)),
                ],
            );
            let gpu: Vec<[f32; 4]> = read(ctx, &work);
            let mut cpu = img.clone();
            let blurred = AcuityBlur::new(&model, w, h, dpp).apply(&mut cpu);
            let (mut max_rel, mut changed, mut same) = (0.0f64, 0usize, 0usize);
            for ((g, c), s) in gpu.iter().zip(&cpu.pixels).zip(&img.pixels) {
                let moved = c != s;
                changed += usize::from(moved);
                same += usize::from(!moved && [g[0], g[1], g[2]] == *c);
                for k in 0..3 {
                    let e = f64::from((g[k] - c[k]).abs()) / f64::from(c[k].abs().max(1e-4));
                    max_rel = max_rel.max(e);
                }
            }
            let state: FrameState = read(ctx, &state)[0];
            let sigma = model.sigma_px(0.05, dpp);
            println!(
                "{model:?}: {changed} of {} px blurred on the CPU ({blurred} rows), {same} \
                 untouched on both, max relative |GPU − CPU| {max_rel:.2e}; frame σ {} (CPU {sigma})",
                w * h,
                state.acuity_sigma_px
            );
            // The blur must run (this dark view blurs every pixel on the CPU).
            assert!(changed > w * h / 10, "{changed}");
            assert_eq!(
                changed + same,
                w * h,
                "a pixel the CPU keeps moved on the GPU"
            );
            assert!(max_rel < 1e-3, "{model:?}: {max_rel:e}");
            assert_eq!(state.blur_radius, params.max_radius);
            assert!((state.acuity_sigma_px - sigma).abs() <= 1e-4 * sigma.max(1.0));
        }
    }
}
