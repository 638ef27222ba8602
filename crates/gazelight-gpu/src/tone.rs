//! Stages 6–8 on the GPU, the twin of `shaders/tone.wgsl`: the per-frame
//! tone and colour scalars (one thread, from the adaptation state on the
//! GPU), then per pixel tone reproduction ([`gazelight_vision::tone`],
//! 000 eq 1–4, 8–10, 003 eq 4–5, 004 §3.2–3.3), colour
//! ([`gazelight_vision::colour`], 001 eq 14, 000 eq 11–12), clamping to the
//! display, and the sRGB encoding (8-bit, through the CPU's own
//! 16384-entry table, so equal inputs give equal bytes). The acuity blur
//! (stage 5) has already run on the HDR frame. The threshold functions run in f32 on the GPU; `t_p` of the
//! display adaptation and the gaze-exposure gamma, which do not depend on
//! the frame, come from the host in f64.

use bytemuck::{Pod, Zeroable};
use gazelight_vision::colour::ColourModel;
use gazelight_vision::tone::ToneModel;
use gazelight_vision::tvi;

use crate::context::GpuContext;
use crate::error::GpuError;
use crate::frame::FrameState;
use crate::pass::{Binding, PassDescriptor, PassLayout};
use crate::shaders;

/// Uniforms of `tone.wgsl` (`struct ToneParams`), field by field.
#[repr(C)]
#[derive(Debug, Clone, Copy, PartialEq, Pod, Zeroable)]
pub struct ToneParams {
    /// Frame width.
    pub width: u32,
    /// Frame height.
    pub height: u32,
    /// 0 Ward/Ferwerda, 1 Naka–Rushton, 2 gaze exposure.
    pub model: u32,
    /// Scotopic shift on.
    pub colour_shift: u32,
    /// Colour discrimination on.
    pub colour_discrimination: u32,
    /// Also write the display-linear frame.
    pub keep_linear: u32,
    /// Padding.
    pub _pad0: u32,
    /// Padding.
    pub _pad1: u32,
    /// Display peak, cd/m².
    pub peak_cd_m2: f32,
    /// `t_p(peak/2)` (000 eq 1), cd/m².
    pub tp_da_cd_m2: f32,
    /// Naka–Rushton saturation exponent.
    pub saturation: f32,
    /// Gaze-exposure gamma (004 §3.2).
    pub gamma: f32,
    /// `2^−stops_below`.
    pub window_lo: f32,
    /// `2^stops_above`.
    pub window_hi: f32,
    /// Padding.
    pub _pad2: f32,
    /// Padding.
    pub _pad3: f32,
}

impl ToneParams {
    /// The uniforms for the models of a pipeline.
    pub fn new(
        tone: &ToneModel,
        colour: &ColourModel,
        width: u32,
        height: u32,
        keep_linear: bool,
    ) -> Self {
        let (shift, discrimination) = match colour {
            ColourModel::ScotopicShift => (true, false),
            ColourModel::Discrimination => (false, true),
            ColourModel::Both => (true, true),
            ColourModel::None => (false, false),
        };
        let mut p = Self {
            width,
            height,
            model: 0,
            colour_shift: u32::from(shift),
            colour_discrimination: u32::from(discrimination),
            keep_linear: u32::from(keep_linear),
            _pad0: 0,
            _pad1: 0,
            peak_cd_m2: 1.0,
            tp_da_cd_m2: 1.0,
            saturation: 1.0,
            gamma: 1.0,
            window_lo: 1.0,
            window_hi: 1.0,
            _pad2: 0.0,
            _pad3: 0.0,
        };
        match *tone {
            ToneModel::WardFerwerda { display_peak_cd_m2 } => {
                p.peak_cd_m2 = display_peak_cd_m2 as f32;
                // 000 eq 9: display adaptation L_da = half the display peak
                p.tp_da_cd_m2 = tvi::t_p(0.5 * display_peak_cd_m2) as f32;
            }
            ToneModel::NakaRushton { saturation } => {
                p.model = 1;
                p.saturation = saturation as f32;
            }
            ToneModel::GazeExposure {
                stops_below,
                stops_above,
                target_display,
            } => {
                p.model = 2;
                let lo = 2f64.powf(-stops_below);
                let hi = 2f64.powf(stops_above);
                // 004 §3.2: the target maps to target_display; independent of L_wa
                let x_t = (1.0 - lo) / (hi - lo);
                p.gamma = (target_display.ln() / x_t.ln()) as f32;
                p.window_lo = lo as f32;
                p.window_hi = hi as f32;
            }
        }
        p
    }
}

/// `shaders/tone.wgsl`: the frame's tone and colour scalars (one thread),
/// then tone, colour and encoding per pixel.
pub const TONE_PASS: PassDescriptor = PassDescriptor {
    shader: shaders::TONE,
    entry_points: &["prepare_tone", "tone_map"],
    bindings: &[
        Binding::uniform::<ToneParams>("params"),
        Binding::read_write::<FrameState>("state"),
        Binding::read::<[f32; 4]>("work"),
        Binding::read_write::<[f32; 4]>("linear_out"),
        Binding::read::<u32>("lut"),
        Binding::read_write::<u32>("output"),
    ],
};

/// The twin of `shaders/tone.wgsl` ([`TONE_PASS`]). Bindings:
/// 0 [`ToneParams`], 1 [`crate::frame::FrameState`], 2 working frame
/// (read-only), 3 display-linear frame, 4 sRGB table (read-only), 5 RGBA8
/// output.
#[derive(Debug, Clone)]
pub struct TonePass {
    pub(crate) layout: PassLayout,
    pub(crate) prepare: wgpu::ComputePipeline,
    pub(crate) tone_map: wgpu::ComputePipeline,
}

impl TonePass {
    /// Checks the shader against the device limits and builds the pipelines.
    pub fn new(ctx: &GpuContext) -> Result<Self, GpuError> {
        let (layout, [prepare, tone_map]) = TONE_PASS.build(ctx)?;
        Ok(Self {
            layout,
            prepare,
            tone_map,
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
    use crate::frame::{SRGB_LUT_SIZE, srgb_table};
    use crate::testing::pass_harness::{
        panorama_view, read, run_pass, storage, texels, tiles, uniform,
    };
    use crate::testing::test_context;

    /// The tone pass alone, against `colour.apply(tone.apply(p))` clamped
    /// to the display (the CPU's stages 6–7) and its sRGB codes, for every
    /// tone model, with and without the overshoot of 000 eq 8.
    #[test]
    fn tone_and_colour_match_the_cpu_operators() {
        let Some(ctx) = test_context("tone_and_colour_match_the_cpu_operators") else {
            return;
        };
        let (w, h) = (48usize, 32usize);
        let (img, _) = panorama_view("night.exr", -78.4, -6.0, 30.0, [w, h]);
        let pass = TonePass::new(ctx).unwrap();
        let table = srgb_table();
        let lut = storage(ctx, &table);
        let code = |v: f32| {
            let i = ((v.clamp(0.0, 1.0) * (SRGB_LUT_SIZE - 1) as f32 + 0.5) as usize)
                .min(SRGB_LUT_SIZE - 1);
            table[i] as u8
        };
        let mut worst = 0.0f32;
        for (tone, colour) in [
            (ToneModel::default(), ColourModel::ScotopicShift),
            (ToneModel::naka_rushton(), ColourModel::Discrimination),
            (ToneModel::gaze_exposure(), ColourModel::Both),
        ] {
            for (adaptation, light_target) in [(0.05f32, 0.05f32), (0.05, 2.0)] {
                let params = ToneParams::new(&tone, &colour, w as u32, h as u32, true);
                let params_buf = uniform(ctx, &params);
                let state = storage(
                    ctx,
                    &[FrameState {
                        adaptation_cd_m2: adaptation,
                        light_target_cd_m2: light_target,
                        ..FrameState::default()
                    }],
                );
                let work = storage(ctx, &texels(&img));
                let linear = storage(ctx, &vec![[0.0f32; 4]; w * h]);
                let output = storage(ctx, &vec![0u32; w * h]);
                run_pass(
                    ctx,
                    &pass.layout,
                    &[&params_buf, &state, &work, &linear, &lut, &output],
                    &[(&pass.prepare, [1, 1, 1]), (&pass.tone_map, tiles(w, h))],
                );
                let tone_frame =
                    tone.prepare_adapting(f64::from(adaptation), f64::from(light_target));
                let colour_frame = colour.prepare(f64::from(adaptation));
                let gpu_linear: Vec<[f32; 4]> = read(ctx, &linear);
                let gpu_codes: Vec<u32> = read(ctx, &output);
                let (mut max_err, mut max_code) = (0.0f32, 0u8);
                for ((s, g), packed) in img.pixels.iter().zip(&gpu_linear).zip(&gpu_codes) {
                    let c = colour_frame.apply(tone_frame.apply(*s));
                    let bytes = packed.to_le_bytes();
                    for k in 0..3 {
                        max_err = max_err.max((g[k] - c[k].clamp(0.0, 1.0)).abs());
                        max_code = max_code.max(bytes[k].abs_diff(code(c[k])));
                    }
                }
                println!(
                    "{tone:?} {colour:?} L {adaptation} L̄ {light_target}: display-linear max \
                     |GPU − CPU| {max_err:.2e}, codes ≤ {max_code}"
                );
                assert!(max_err < 2e-4, "{tone:?} {colour:?}: {max_err}");
                assert!(max_code <= 1, "{tone:?} {colour:?}: {max_code}/255");
                worst = worst.max(max_err);
            }
        }
        println!("worst display-linear difference {worst:.2e}");
    }
}
