// Stage 5: acuity loss as a per-pixel-σ separable Gaussian blur of CIE Lab
// lightness on the HDR frame in cd/m², after glare and before tone
// reproduction (001 §4.3.1, eq 11–13; the twin of
// gazelight_vision::acuity::AcuityBlur::apply, step by step). Entry points:
//
// 1. `prepare_acuity` (one thread): σ at the adaptation luminance, for the
//    frame statistics only (every pixel gets its own σ below);
// 2. `lightness` (per pixel): L* = 116·f(Y/Yn) − 16 of the work frame, Y the
//    RGB → XYZ row of IEC 61966-2-1, Yn = `white_cd_m2`;
// 3. `blur_h` (per pixel): h(x) = Σ g(k)·L(x+k) / Σ g(k), k = −r..=r,
//    g(k) = exp(−k²/2σ²), σ = σ(L(x)) of the pixel itself, r = min(⌈3σ⌉,
//    max_radius), edge pixels repeated; σ ≤ 0.3 px keeps h = L;
// 4. `blur_v` (per pixel): the same over h along the column with σ = σ(h),
//    giving L'; a pixel whose L' differs from L is moved to L' keeping its
//    a*, b*: Δ = (L' + 16)/116 − f(Y/Yn), X' = Xn·f⁻¹(f(X/Xn) + Δ), the same
//    for Y and Z, then XYZ → linear sRGB; others are left bit-identical.
// σ rules (`model`): 0 σ = clamp(1 − L, 0, 1)·ppd/13.85 (001 eq 12);
// 1 σ = ppd/(1.86·√2·R(Y)), Y = f⁻¹((L + 16)/116)·Yn ≥ 1e-6 cd/m², R the
// Larson acuity (001 eq 11, 13); 2 none (the host skips the passes).
// Gaussian weights as the CPU's `gather`: one exp per pixel and the
// recurrence g(k+1) = g(k)·q(k), q(k+1) = q(k)·e², e = exp(−1/2σ²).

struct AcuityParams {
    width: u32,
    height: u32,
    // 0 linear in lightness (001 eq 12), 1 Larson/Krawczyk, 2 none.
    model: u32,
    // Largest tap radius (AcuityBlur::max_radius); 0 = never blurs.
    max_radius: u32,
    // Lab white Yn, cd/m² (AcuityModel::lab_white_cd_m2).
    white_cd_m2: f32,
    // ppd/13.85 (model 0) or ppd/(1.86·√2) (model 1).
    sigma_scale: f32,
    _pad0: f32,
    _pad1: f32,
}

@group(0) @binding(0) var<uniform> params: AcuityParams;
@group(0) @binding(1) var<storage, read_write> state: FrameState;
@group(0) @binding(2) var<storage, read_write> work: array<vec4<f32>>;
@group(0) @binding(3) var<storage, read_write> lightness_buf: array<f32>;
@group(0) @binding(4) var<storage, read_write> horizontal: array<f32>;

// Pixels at or below this σ are not blurred (AcuityBlur::MIN_SIGMA_PX).
const MIN_SIGMA_PX: f32 = 0.3;
// 001 §3.3: lowest luminance of the Larson fit, cd/m².
const MIN_ACUITY_LUMINANCE_CD_M2: f32 = 1e-6;
// D65 white of RGB (1, 1, 1) under the IEC 61966-2-1 matrix.
const WHITE_XYZ: vec3<f32> = vec3<f32>(0.95047, 1.0, 1.08883);

fn lab_f(t: f32) -> f32 {
    // CIE 1976: ε = 216/24389, κ = 24389/27
    if t > 216.0 / 24389.0 {
        return pow(t, 1.0 / 3.0);
    }
    return (24389.0 / 27.0 * t + 16.0) / 116.0;
}

fn lab_f_inv(f: f32) -> f32 {
    if f > 6.0 / 29.0 {
        return f * f * f;
    }
    return (116.0 * f - 16.0) * (27.0 / 24389.0);
}

fn rgb_to_xyz(rgb: vec3<f32>) -> vec3<f32> {
    return vec3<f32>(
        0.4124564 * rgb.x + 0.3575761 * rgb.y + 0.1804375 * rgb.z,
        0.2126729 * rgb.x + 0.7151522 * rgb.y + 0.072175 * rgb.z,
        0.0193339 * rgb.x + 0.119192 * rgb.y + 0.9503041 * rgb.z,
    );
}

fn xyz_to_rgb(xyz: vec3<f32>) -> vec3<f32> {
    return vec3<f32>(
        3.2404542 * xyz.x - 1.5371385 * xyz.y - 0.4985314 * xyz.z,
        -0.969266 * xyz.x + 1.8760108 * xyz.y + 0.041556 * xyz.z,
        0.0556434 * xyz.x - 0.2040259 * xyz.y + 1.0572252 * xyz.z,
    );
}

// σ of a pixel of lightness `l`, pixels; a negative value stands for an
// unbounded σ (a box over max_radius taps; unreachable for Y ≥ 1e-6).
fn sigma_of(l: f32) -> f32 {
    switch params.model {
        case 0u: {
            // 001 eq 12
            return clamp(1.0 - l, 0.0, 1.0) * params.sigma_scale;
        }
        case 1u: {
            let y = max(lab_f_inv((l + 16.0) / 116.0) * params.white_cd_m2, MIN_ACUITY_LUMINANCE_CD_M2);
            // 001 eq 13 solved for R; eq 11
            let r = (1.49 + atan((log(y) + 0.575646) / 1.64)) / 0.06;
            if r > 0.0 {
                return params.sigma_scale / r;
            }
            return -1.0;
        }
        default: {
            return 0.0;
        }
    }
}

fn blurs(sigma: f32) -> bool {
    return sigma < 0.0 || sigma > MIN_SIGMA_PX;
}

// Tap radius and e = exp(−1/2σ²) of σ.
fn taps_of(sigma: f32) -> vec2<f32> {
    if sigma < 0.0 {
        return vec2<f32>(f32(params.max_radius), 1.0);
    }
    let r = min(u32(ceil(3.0 * sigma)), params.max_radius);
    return vec2<f32>(f32(r), exp(-0.5 / (sigma * sigma)));
}

@compute @workgroup_size(1, 1, 1)
fn prepare_acuity() {
    let a = state.adaptation_cd_m2;
    let y = select(0.0, max(a, 0.0), finite_f32(a));
    let t = y / params.white_cd_m2;
    var l = t * (24389.0 / 27.0);
    if t > 216.0 / 24389.0 {
        l = 116.0 * pow(t, 1.0 / 3.0) - 16.0;
    }
    var sigma = 0.0;
    switch params.model {
        case 0u: {
            // 001 eq 12
            sigma = clamp(1.0 - l, 0.0, 1.0) * params.sigma_scale;
        }
        case 1u: {
            // 001 eq 11, 13 at the adaptation luminance itself
            let r = (1.49 + atan((log(max(y, MIN_ACUITY_LUMINANCE_CD_M2)) + 0.575646) / 1.64)) / 0.06;
            sigma = params.sigma_scale / r;
        }
        default: {
            sigma = 0.0;
        }
    }
    state.acuity_sigma_px = sigma;
    state.blur_radius = params.max_radius;
}

@compute @workgroup_size(8, 8, 1)
fn lightness(@builtin(global_invocation_id) gid: vec3<u32>) {
    if gid.x >= params.width || gid.y >= params.height {
        return;
    }
    let i = gid.y * params.width + gid.x;
    let y = rgb_to_xyz(work[i].xyz).y;
    lightness_buf[i] = 116.0 * lab_f(y / params.white_cd_m2) - 16.0;
}

@compute @workgroup_size(8, 8, 1)
fn blur_h(@builtin(global_invocation_id) gid: vec3<u32>) {
    if gid.x >= params.width || gid.y >= params.height {
        return;
    }
    let row = gid.y * params.width;
    let centre = lightness_buf[row + gid.x];
    let sigma = sigma_of(centre);
    if !blurs(sigma) {
        horizontal[row + gid.x] = centre;
        return;
    }
    let t = taps_of(sigma);
    let r = u32(t.x);
    let e = t.y;
    let e2 = e * e;
    var g = 1.0;
    var q = e;
    var acc = centre;
    var norm = 1.0;
    let last = params.width - 1u;
    for (var k = 1u; k <= r; k++) {
        g *= q;
        q *= e2;
        let a = lightness_buf[row + select(0u, gid.x - k, gid.x >= k)];
        let b = lightness_buf[row + min(gid.x + k, last)];
        acc += g * (a + b);
        norm += 2.0 * g;
    }
    horizontal[row + gid.x] = acc / norm;
}

@compute @workgroup_size(8, 8, 1)
fn blur_v(@builtin(global_invocation_id) gid: vec3<u32>) {
    if gid.x >= params.width || gid.y >= params.height {
        return;
    }
    let w = params.width;
    let i = gid.y * w + gid.x;
    let hv = horizontal[i];
    let sigma = sigma_of(hv);
    var l_new = hv;
    if blurs(sigma) {
        let t = taps_of(sigma);
        let r = u32(t.x);
        let e = t.y;
        let e2 = e * e;
        var g = 1.0;
        var q = e;
        var acc = hv;
        var norm = 1.0;
        let last = params.height - 1u;
        for (var k = 1u; k <= r; k++) {
            g *= q;
            q *= e2;
            let a = horizontal[select(0u, gid.y - k, gid.y >= k) * w + gid.x];
            let b = horizontal[min(gid.y + k, last) * w + gid.x];
            acc += g * (a + b);
            norm += 2.0 * g;
        }
        l_new = acc / norm;
    }
    if l_new == lightness_buf[i] {
        return;
    }
    let wx = WHITE_XYZ * params.white_cd_m2;
    let old = work[i];
    let xyz = rgb_to_xyz(old.xyz);
    let f = vec3<f32>(lab_f(xyz.x / wx.x), lab_f(xyz.y / wx.y), lab_f(xyz.z / wx.z));
    let d = (l_new + 16.0) / 116.0 - f.y;
    let moved = vec3<f32>(
        lab_f_inv(f.x + d) * wx.x,
        lab_f_inv(f.y + d) * wx.y,
        lab_f_inv(f.z + d) * wx.z,
    );
    // w: the no-data flag of pooling.wgsl's import_scene, kept.
    work[i] = vec4<f32>(xyz_to_rgb(moved), old.w);
}
