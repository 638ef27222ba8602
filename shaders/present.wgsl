// Present pass: draws the display frame into a window's surface,
// letterboxed to keep the frame's aspect ratio, or a solid colour filling
// the whole surface (the calibration stimulus).
//
// The frame is read straight from the frame pipeline's RGBA8 output buffer
// (tone.wgsl's `out_rgba8`: one u32 per pixel, bytes r g b a, already sRGB
// encoded by stage 8), so a GPU frame reaches the screen with no copy and
// no read-back; a CPU frame is uploaded into a buffer of the same layout.
// It is filtered bilinearly with clamp-to-edge, as a linear sampler would:
// at 1:1 scale each fragment lands on its pixel's centre and gets that
// pixel's code exactly. A window surface is a non-sRGB format, so the
// encoded values pass through unchanged; into an sRGB target they are
// decoded to linear (IEC 61966-2-1) and the target encodes them back.
// Twin: crates/gazelight-gpu/src/present.rs.

struct PresentParams {
    // Scale of the frame quad in clip space (≤ 1 on each axis).
    scale: vec2<f32>,
    // Frame size, pixels (width, height).
    frame_size: vec2<u32>,
    // Solid colour mode for calibration stimuli: rgb + 1 in w, else 0.
    solid: vec4<f32>,
    // 1 when the target is an sRGB format (an OpenXR swapchain image): it
    // encodes what is written, so the codes are decoded to linear first.
    decode_srgb: u32,
    _pad0: u32,
    _pad1: u32,
    _pad2: u32,
};

@group(0) @binding(0) var<storage, read> frame_rgba8: array<u32>;
@group(0) @binding(1) var<uniform> params: PresentParams;

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

fn texel(x: i32, y: i32) -> vec4<f32> {
    let size = vec2<i32>(params.frame_size);
    let cx = clamp(x, 0, size.x - 1);
    let cy = clamp(y, 0, size.y - 1);
    return unpack4x8unorm(frame_rgba8[u32(cy * size.x + cx)]);
}

@fragment
fn fs_main(in: VsOut) -> @location(0) vec4<f32> {
    if (params.solid.w > 0.5) {
        if (params.decode_srgb == 1u) {
            return vec4<f32>(srgb_to_linear(params.solid.rgb), 1.0);
        }
        return vec4<f32>(params.solid.rgb, 1.0);
    }
    // Texel space: pixel centres at integer + 0.5, as a sampler's.
    let t = in.uv * vec2<f32>(params.frame_size) - vec2<f32>(0.5);
    let base = floor(t);
    let f = t - base;
    let i = vec2<i32>(base);
    let top = mix(texel(i.x, i.y), texel(i.x + 1, i.y), f.x);
    let bottom = mix(texel(i.x, i.y + 1), texel(i.x + 1, i.y + 1), f.x);
    let code = mix(top, bottom, f.y).rgb;
    if (params.decode_srgb == 1u) {
        return vec4<f32>(srgb_to_linear(code), 1.0);
    }
    return vec4<f32>(code, 1.0);
}

// The sRGB transfer function inverted (IEC 61966-2-1).
fn srgb_to_linear(c: vec3<f32>) -> vec3<f32> {
    let lo = c / 12.92;
    let hi = pow((c + vec3<f32>(0.055)) / 1.055, vec3<f32>(2.4));
    return select(hi, lo, c <= vec3<f32>(0.04045));
}
