//! Stage 2 on the GPU, the twin of `shaders/temporal.wgsl`: one thread
//! advances the adaptation state in [`crate::frame::FrameState`] towards
//! the pooled target, with the models of [`gazelight_vision::temporal`]
//! (001 eq 2–4, 000 eq 7–8, 003 eq 2–3), in f32. Running it on the GPU keeps
//! the frame in one command buffer with no read-back between stages.

use bytemuck::{Pod, Zeroable};
use gazelight_vision::temporal::TemporalModel;

use crate::context::GpuContext;
use crate::error::GpuError;
use crate::frame::FrameState;
use crate::pass::{Binding, PassDescriptor, PassLayout};
use crate::shaders;

/// Uniforms of `temporal.wgsl` (`struct TemporalParams`), field by field.
#[repr(C)]
#[derive(Debug, Clone, Copy, PartialEq, Pod, Zeroable)]
pub struct TemporalParams {
    /// 0 Krawczyk, 1 p^dt, 2 log exponential, 3 log linear.
    pub model: u32,
    /// 1: start adapted to the target (first frame).
    pub reset: u32,
    /// Model 1: record the overshoot target (000 eq 8).
    pub overshoot: u32,
    /// Padding.
    pub _pad0: u32,
    /// Time step, seconds.
    pub dt_secs: f32,
    /// τ_rod, p_light or τ_light (see the shader header).
    pub a: f32,
    /// τ_cone, p_dark or τ_dark.
    pub b: f32,
    /// Padding.
    pub _pad1: f32,
}

impl TemporalParams {
    /// The uniforms for `model` (dt and reset are set per frame).
    pub fn new(model: &TemporalModel) -> Self {
        let (m, a, b, overshoot) = match *model {
            TemporalModel::Krawczyk {
                tau_rod_secs,
                tau_cone_secs,
            } => (0, tau_rod_secs, tau_cone_secs, false),
            TemporalModel::PowerDt {
                p_light,
                p_dark,
                overshoot,
            } => (1, p_light, p_dark, overshoot),
            TemporalModel::LogExponential {
                tau_light_secs,
                tau_dark_secs,
            } => (2, tau_light_secs, tau_dark_secs, false),
            TemporalModel::Linear {
                tau_light_secs,
                tau_dark_secs,
            } => (3, tau_light_secs, tau_dark_secs, false),
        };
        Self {
            model: m,
            reset: 1,
            overshoot: u32::from(overshoot),
            _pad0: 0,
            dt_secs: 0.0,
            a: a as f32,
            b: b as f32,
            _pad1: 0.0,
        }
    }
}

/// `shaders/temporal.wgsl`: the one-thread adaptation step.
pub const TEMPORAL_PASS: PassDescriptor = PassDescriptor {
    shader: shaders::TEMPORAL,
    entry_points: &["adapt"],
    bindings: &[
        Binding::uniform::<TemporalParams>("params"),
        Binding::read_write::<FrameState>("state"),
    ],
};

/// The twin of `shaders/temporal.wgsl` ([`TEMPORAL_PASS`]). Bindings:
/// 0 [`TemporalParams`], 1 [`crate::frame::FrameState`].
#[derive(Debug, Clone)]
pub struct TemporalPass {
    pub(crate) layout: PassLayout,
    pub(crate) adapt: wgpu::ComputePipeline,
}

impl TemporalPass {
    /// Checks the shader against the device limits and builds the pipeline.
    pub fn new(ctx: &GpuContext) -> Result<Self, GpuError> {
        let (layout, [adapt]) = TEMPORAL_PASS.build(ctx)?;
        Ok(Self { layout, adapt })
    }

    /// The bind group layout (group 0).
    pub fn bind_group_layout(&self) -> &wgpu::BindGroupLayout {
        self.layout.layout()
    }
}

#[cfg(test)]
mod tests {
    use gazelight_vision::temporal::AdaptationState;

    use super::*;
    use crate::testing::pass_harness::{read, run_pass, storage, uniform};
    use crate::testing::test_context;

    /// The `adapt` pass alone, one frame at a time, against
    /// `TemporalModel::step` for every model: a dark start, a jump up by
    /// four decades, then down, with frame times from 1/90 s to 0.5 s.
    #[test]
    fn adapt_steps_like_the_cpu_model() {
        let Some(ctx) = test_context("adapt_steps_like_the_cpu_model") else {
            return;
        };
        let pass = TemporalPass::new(ctx).unwrap();
        let targets = [(100.0, 1.0 / 90.0), (100.0, 0.05), (0.01, 0.5), (3.0, 0.2)];
        let mut worst = 0.0f64;
        for model in [
            TemporalModel::krawczyk(),
            TemporalModel::power_dt(),
            TemporalModel::log_exponential(),
            TemporalModel::linear(),
        ] {
            let mut params = TemporalParams::new(&model);
            params.reset = 0;
            let mut cpu = AdaptationState::new(0.01);
            let state = storage(
                ctx,
                &[FrameState {
                    adaptation_cd_m2: 0.01,
                    light_target_cd_m2: 0.01,
                    ..FrameState::default()
                }],
            );
            for (target_cd_m2, dt_secs) in targets.into_iter().cycle().take(12) {
                params.dt_secs = dt_secs as f32;
                let params_buf = uniform(ctx, &params);
                // The pooled target of the frame, as pooling leaves it.
                ctx.queue()
                    .write_buffer(&state, 0, bytemuck::bytes_of(&(target_cd_m2 as f32)));
                let dispatch = [(&pass.adapt, [1, 1, 1])];
                run_pass(ctx, &pass.layout, &[&params_buf, &state], &dispatch);
                let gpu: FrameState = read(ctx, &state)[0];
                cpu = model.step(cpu, target_cd_m2, dt_secs);
                let rel = |g: f32, c: f64| (f64::from(g) - c).abs() / c.abs().max(1e-9);
                let e = rel(gpu.adaptation_cd_m2, cpu.luminance_cd_m2)
                    .max(rel(gpu.light_target_cd_m2, cpu.light_target_cd_m2));
                assert!(
                    e < 1e-4,
                    "{model:?} → {target_cd_m2} cd/m² over {dt_secs} s: GPU {} / {}, CPU {} / {}",
                    gpu.adaptation_cd_m2,
                    gpu.light_target_cd_m2,
                    cpu.luminance_cd_m2,
                    cpu.light_target_cd_m2
                );
                worst = worst.max(e);
            }
        }
        println!("worst relative |GPU − CPU| adaptation {worst:.2e}");
    }
}
