// The app's swapchain image (its texels copied into a buffer, rows padded
// to `row_words` u32 words) into the frame pipeline's scene buffer: linear
// RGB in cd/m², alpha 0. CPU twin: gazelight_openxr_layer::import::import_cpu.
//
// format 0: R8G8B8A8_SRGB, 1: B8G8R8A8_SRGB (8-bit codes decoded through
// `lut`, the 256 linear values of the codes, then × scale = white_cd_m2);
// 2: R16G16B16A16_SFLOAT (two words per texel, × scale = scene_scale_cd_m2).

struct ImportParams {
    width: u32,
    height: u32,
    row_words: u32,
    format: u32,
    scale: f32,
    _pad0: u32,
    _pad1: u32,
    _pad2: u32,
}

@group(0) @binding(0) var<uniform> params: ImportParams;
@group(0) @binding(1) var<storage, read> texels: array<u32>;
@group(0) @binding(2) var<storage, read> lut: array<f32>;
@group(0) @binding(3) var<storage, read_write> scene: array<vec4<f32>>;

// IEEE binary16 (low 16 bits of `h`) to f32, exactly (without the
// float16 capability): normal numbers by their bits, subnormals as
// fraction × 2^-24, infinities and NaNs kept.
fn half_to_f32(h: u32) -> f32 {
    let sign = (h & 0x8000u) << 16u;
    let e = (h >> 10u) & 0x1fu;
    let frac = h & 0x3ffu;
    if e == 0u {
        let v = f32(frac) * 5.9604644775390625e-8;
        return select(v, -v, sign != 0u);
    }
    if e == 31u {
        return bitcast<f32>(sign | 0x7f800000u | (frac << 13u));
    }
    return bitcast<f32>(sign | ((e + 112u) << 23u) | (frac << 13u));
}

@compute @workgroup_size(8, 8, 1)
fn import_image(@builtin(global_invocation_id) gid: vec3<u32>) {
    if gid.x >= params.width || gid.y >= params.height {
        return;
    }
    let row = gid.y * params.row_words;
    var rgb: vec3<f32>;
    if params.format == 2u {
        let rg = texels[row + 2u * gid.x];
        let ba = texels[row + 2u * gid.x + 1u];
        rgb = vec3<f32>(half_to_f32(rg & 0xffffu), half_to_f32(rg >> 16u), half_to_f32(ba & 0xffffu));
    } else {
        let w = texels[row + gid.x];
        let c0 = lut[w & 0xffu];
        let c1 = lut[(w >> 8u) & 0xffu];
        let c2 = lut[(w >> 16u) & 0xffu];
        if params.format == 1u {
            rgb = vec3<f32>(c2, c1, c0);
        } else {
            rgb = vec3<f32>(c0, c1, c2);
        }
    }
    scene[gid.y * params.width + gid.x] = vec4<f32>(rgb * params.scale, 0.0);
}
