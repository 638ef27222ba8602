// Present pass: draws the display-encoded frame (RGBA8, already sRGB
// encoded by stage 8) into the window's surface, letterboxed to keep the
// frame's aspect ratio. The surface is a non-sRGB format, so the encoded
// values pass through unchanged. Twin: crates/gazelight/src/window.rs.

struct PresentParams {
    // Scale of the frame quad in clip space (≤ 1 on each axis).
    scale: vec2<f32>,
    // Solid colour mode for calibration stimuli: rgb + 1 in w, else 0.
    _pad: vec2<f32>,
    solid: vec4<f32>,
};

@group(0) @binding(0) var frame_tex: texture_2d<f32>;
@group(0) @binding(1) var frame_sampler: sampler;
@group(0) @binding(2) var<uniform> params: PresentParams;

struct VsOut {
    @builtin(position) pos: vec4<f32>,
    @location(0) uv: vec2<f32>,
};

// One triangle strip quad from the vertex index (no vertex buffer).
@vertex
fn vs_main(@builtin(vertex_index) i: u32) -> VsOut {
    let x = f32(i & 1u);
    let y = f32((i >> 1u) & 1u);
    var out: VsOut;
    out.pos = vec4<f32>((x * 2.0 - 1.0) * params.scale.x, (1.0 - y * 2.0) * params.scale.y, 0.0, 1.0);
    out.uv = vec2<f32>(x, y);
    return out;
}

@fragment
fn fs_main(in: VsOut) -> @location(0) vec4<f32> {
    if (params.solid.w > 0.5) {
        return vec4<f32>(params.solid.rgb, 1.0);
    }
    return vec4<f32>(textureSample(frame_tex, frame_sampler, in.uv).rgb, 1.0);
}
