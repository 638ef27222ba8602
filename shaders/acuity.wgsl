// Stage 5 (+ 8): acuity loss as a separable Gaussian blur of CIE Lab
// lightness (001 eq 11–13; gazelight_vision::acuity), on the display-linear
// frame, then sRGB encoding. Three entry points:
//
// 1. `prepare_acuity` (one thread): σ from the adaptation luminance —
//    model 0: σ = max(1 − L*, 0)·ppd/13.85 (001 eq 12), L* the CIE Lab
//    lightness of Y/Y_white, model 1: σ = ppd/(1.86·√2·R(Y)) (001 eq 13),
//    R = the Larson acuity in cycles/degree (001 eq 11), model 2: none —
//    the host passes ppd/13.85 or ppd/(1.86√2) as `sigma_scale`; blur when
//    σ > 0.3 px: radius r = ceil(3σ) (capped at `max_radius`) and the
//    normalised taps e^(−d²/2σ²), d = −r..r, into `taps`;
// 2. `blur_h`: horizontal pass over L* (edge pixels repeated);
// 3. `blur_v`: vertical pass, Lab → linear sRGB with the pixel's own a*, b*,
//    then the encoding (and the display-linear value with `keep_linear`).
// All three do nothing when the frame needs no blur (blur_radius = 0).

struct AcuityParams {
    width: u32,
    height: u32,
    // 0 linear in lightness, 1 Larson/Krawczyk, 2 none.
    model: u32,
    // Capacity of `taps`: radius ≤ max_radius.
    max_radius: u32,
    keep_linear: u32,
    _pad0: u32,
    _pad1: u32,
    _pad2: u32,
    // Model 0: Lab white, cd/m².
    white_cd_m2: f32,
    // ppd/13.85 (model 0) or ppd/(1.86·√2) (model 1).
    sigma_scale: f32,
    _pad3: f32,
    _pad4: f32,
}

@group(0) @binding(0) var<uniform> params: AcuityParams;
@group(0) @binding(1) var<storage, read_write> state: FrameState;
@group(0) @binding(2) var<storage, read_write> taps: array<f32>;
@group(0) @binding(3) var<storage, read> lab: array<vec4<f32>>;
@group(0) @binding(4) var<storage, read_write> horizontal: array<f32>;
@group(0) @binding(5) var<storage, read_write> linear_out: array<vec4<f32>>;
@group(0) @binding(6) var<storage, read> lut: array<u32>;
@group(0) @binding(7) var<storage, read_write> output: array<u32>;

// Below this σ no blur is applied (AcuityBlur::MIN_SIGMA_PX).
const MIN_SIGMA_PX: f32 = 0.3;
// 001 eq 11: lowest luminance of the Larson fit, cd/m².
const MIN_ACUITY_LUMINANCE_CD_M2: f32 = 1e-6;

@compute @workgroup_size(1, 1, 1)
fn prepare_acuity() {
    let a = state.adaptation_cd_m2;
    let y = select(0.0, max(a, 0.0), finite_f32(a));
    var sigma = 0.0;
    switch params.model {
        case 0u: {
            let t = y / params.white_cd_m2;
            var l = t * (24389.0 / 27.0);
            if t > 216.0 / 24389.0 {
                l = 116.0 * pow(t, 1.0 / 3.0) - 16.0;
            }
            // 001 eq 12: σ = max(1 − L, 0) at 13.85 ppd, scaled to the display
            sigma = max(1.0 - l, 0.0) * params.sigma_scale;
        }
        case 1u: {
            // 001 eq 11 (Larson et al.): acuity in cycles per degree
            let r = (1.49 + atan((log(max(y, MIN_ACUITY_LUMINANCE_CD_M2)) + 0.575646) / 1.64)) / 0.06;
            // 001 eq 13
            sigma = params.sigma_scale / r;
        }
        default: {
            sigma = 0.0;
        }
    }
    state.acuity_sigma_px = sigma;
    if !(finite_f32(sigma) && sigma > MIN_SIGMA_PX) {
        state.blur_radius = 0u;
        return;
    }
    let r = min(u32(ceil(3.0 * sigma)), params.max_radius);
    state.blur_radius = r;
    let inv2s2 = 1.0 / (2.0 * sigma * sigma);
    var norm = 0.0;
    for (var i = 0u; i <= 2u * r; i++) {
        let d = f32(i) - f32(r);
        let k = exp(-d * d * inv2s2);
        taps[i] = k;
        norm += k;
    }
    for (var i = 0u; i <= 2u * r; i++) {
        taps[i] = taps[i] / norm;
    }
}

@compute @workgroup_size(8, 8, 1)
fn blur_h(@builtin(global_invocation_id) gid: vec3<u32>) {
    let r = state.blur_radius;
    if r == 0u || gid.x >= params.width || gid.y >= params.height {
        return;
    }
    let row = gid.y * params.width;
    var acc = 0.0;
    for (var i = 0u; i <= 2u * r; i++) {
        let xx = min(u32(max(i32(gid.x + i) - i32(r), 0)), params.width - 1u);
        acc += taps[i] * lab[row + xx].x;
    }
    horizontal[row + gid.x] = acc;
}

fn lab_f_inv(f: f32) -> f32 {
    if f > 6.0 / 29.0 {
        return f * f * f;
    }
    return (116.0 * f - 16.0) * (27.0 / 24389.0);
}

fn lab_to_rgb(l: vec3<f32>) -> vec3<f32> {
    let fy = (l.x + 16.0) / 116.0;
    let fx = fy + l.y / 500.0;
    let fz = fy - l.z / 200.0;
    let x = lab_f_inv(fx) * 0.95047;
    let y = lab_f_inv(fy) * 1.0;
    let z = lab_f_inv(fz) * 1.08883;
    return vec3<f32>(
        3.2404542 * x - 1.5371385 * y - 0.4985314 * z,
        -0.969266 * x + 1.8760108 * y + 0.041556 * z,
        0.0556434 * x - 0.2040259 * y + 1.0572252 * z,
    );
}

@compute @workgroup_size(8, 8, 1)
fn blur_v(@builtin(global_invocation_id) gid: vec3<u32>) {
    let r = state.blur_radius;
    if r == 0u || gid.x >= params.width || gid.y >= params.height {
        return;
    }
    var acc = 0.0;
    for (var i = 0u; i <= 2u * r; i++) {
        let yy = min(u32(max(i32(gid.y + i) - i32(r), 0)), params.height - 1u);
        acc += taps[i] * horizontal[yy * params.width + gid.x];
    }
    let index = gid.y * params.width + gid.x;
    let own = lab[index];
    let display = lab_to_rgb(vec3<f32>(acc, own.y, own.z));
    if params.keep_linear != 0u {
        linear_out[index] = vec4<f32>(display, 1.0);
    }
    output[index] = lut[lut_index(display.x)] | (lut[lut_index(display.y)] << 8u)
        | (lut[lut_index(display.z)] << 16u) | 0xff000000u;
}
