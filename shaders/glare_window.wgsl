// The glare window's uniforms and its source weight, shared by
// glare.wgsl (stage 4, the window at the gaze) and far_glare.wgsl (the
// full-field stray light, which splits each source's light by the same
// weight): the twin of gazelight_gpu::glare::GlareParams and of
// gazelight_vision::glare's source weight.

struct GlareParams {
    // Fine window W_f, coarse window W_c (blocks), block b, r_fine.
    wf: u32,
    wc: u32,
    block: u32,
    r_fine: u32,
    // Kernel size (centre size/2), frame size.
    kernel_size: u32,
    width: u32,
    height: u32,
    _pad0: u32,
    // Window origins in the frame.
    ofx: i32,
    ofy: i32,
    ocx: i32,
    ocy: i32,
    // Source box ∩ image, frame pixels: [sx0, sx1) × [sy0, sy1).
    sx0: i32,
    sx1: i32,
    sy0: i32,
    sy1: i32,
    // Output region (coarse window ∩ image): [x0, x1) × [y0, y1).
    x0: i32,
    x1: i32,
    y0: i32,
    y1: i32,
    // Gaze, frame pixels; full-weight radius and fade σ, pixels.
    gaze_x: f32,
    gaze_y: f32,
    d_full: f32,
    sigma: f32,
    // What a source pixel keeps of its own light: keep0 − keep_slope·w
    // (1, 1 without the far field).
    keep0: f32,
    keep_slope: f32,
    _pad1: u32,
    _pad2: u32,
}

// Source weight of frame pixel (x, y) for the window `g`: 0 outside the
// source box; 1 within d_full of the gaze, (G(d − d_full) − G(3σ))/(1 −
// G(3σ)) beyond, 0 from d_full + 3σ.
fn window_weight(g: GlareParams, x: i32, y: i32) -> f32 {
    if x < g.sx0 || x >= g.sx1 || y < g.sy0 || y >= g.sy1 {
        return 0.0;
    }
    let dx = f32(x) + 0.5 - g.gaze_x;
    let dy = f32(y) + 0.5 - g.gaze_y;
    let d = sqrt(dx * dx + dy * dy);
    if d <= g.d_full {
        return 1.0;
    }
    let t = d - g.d_full;
    let s = g.sigma;
    if t >= 3.0 * s {
        return 0.0;
    }
    // G(3σ) = exp(−9/2)
    let g_r = exp(-4.5);
    return clamp((exp(-t * t / (2.0 * s * s)) - g_r) / (1.0 - g_r), 0.0, 1.0);
}
