// The per-frame state shared by the frame passes of gazelight_gpu::frame,
// written and read on the GPU (never round-tripped through the host in the
// frame path). Prepended, after common.wgsl, to pooling, temporal, tone and
// acuity passes. Rust twin: gazelight_gpu::frame::FrameState.

struct FrameState {
    // Stage 1: pooled luminance the eye adapts towards, cd/m².
    target_cd_m2: f32,
    // Stage 2: adaptation luminance after this frame's step, cd/m².
    adaptation_cd_m2: f32,
    // Stage 2: the luminance being light-adapted to (000 eq 8's L̄), cd/m².
    light_target_cd_m2: f32,
    // Stage 5: acuity blur σ, display pixels.
    acuity_sigma_px: f32,
    // Stage 6: the prepared tone operator (meaning depends on the model:
    // Ward/Ferwerda scale, offset; Naka–Rushton s, saturation; gaze
    // exposure lo, 1/(hi − lo), gamma).
    tone_a: f32,
    tone_b: f32,
    tone_c: f32,
    // Stage 7: rod sensitivity of the scotopic shift (0 = off), 001 eq 4/14.
    shift_sigma: f32,
    // Stage 7: colour discrimination σ_c (000 eq 11).
    discrimination_sigma: f32,
    // Stage 5: blur radius ceil(3σ), pixels; 0 = no blur this frame.
    blur_radius: u32,
    _pad0: u32,
    _pad1: u32,
}

// Rec. 709 luminance weights of gazelight_vision::image::LUMINANCE_WEIGHTS.
const LUMINANCE_WEIGHTS: vec3<f32> = vec3<f32>(0.2125, 0.7154, 0.0721);

// Entries of the sRGB encoding table (gazelight_vision::pipeline, 8-bit).
const SRGB_LUT_SIZE: u32 = 16384u;

// Finite test on the bit pattern (robust against fast-math assumptions).
fn finite_f32(v: f32) -> bool {
    return (bitcast<u32>(v) & 0x7f800000u) != 0x7f800000u;
}

// The encoding table index of a display-linear value, as the CPU's
// `encode_px`: NaN → 0, clamp to [0, 1], round to nearest.
fn lut_index(v: f32) -> u32 {
    var c = 0.0;
    if v == v {
        c = clamp(v, 0.0, 1.0);
    }
    return min(u32(c * f32(SRGB_LUT_SIZE - 1u) + 0.5), SRGB_LUT_SIZE - 1u);
}
