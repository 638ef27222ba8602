// Stages 6–8: tone reproduction, colour and display encoding
// (gazelight_vision::tone, ::colour, ::pipeline pass C), two entry points:
//
// 1. `prepare_tone` (one thread): the per-frame scalars from the adaptation
//    state (the CPU's ToneModel::prepare_adapting and ColourModel::prepare),
//    into FrameState;
// 2. `tone_map` (per pixel): display = clamp01(colour(tone(work))), then
//    sRGB-encoded into `output`; `keep_linear` also writes the
//    display-linear value. The acuity blur (stage 5, acuity.wgsl) has
//    already run on the HDR work frame.
//
// Tone models (`model`):
//   0 Ward/Ferwerda threshold ratio (000 eq 9) with the light-adaptation
//     offset (000 eq 10), display adaptation L_da = peak/2: scale = t_p(L_da)
//     / t_m(L_wa) / peak, or, while light-adapting (L̄ > L_wa),
//     a = t_p(L_da)/t*(L_wa, L̄), c = t_p(L_da)/t_m(L̄): scale = a/peak,
//     offset = (c − a) L̄/peak. t_p(L_da) comes from the host (f64).
//   1 Naka–Rushton (003 eq 4–5): L/(L + s), s = L_wa, colour ratios^saturation.
//   2 Gaze exposure window with gamma (004 §3.2–3.3): [L_wa 2^−below,
//     L_wa 2^above] → [0, 1]^gamma, then sRGB-decoded; gamma from the host.
// Thresholds (000 eq 1–4, 8) are evaluated in f32 here.

struct ToneParams {
    width: u32,
    height: u32,
    model: u32,
    // Scotopic shift on (001 eq 14).
    colour_shift: u32,
    // Colour discrimination on (000 eq 11–12).
    colour_discrimination: u32,
    // Write the display-linear frame too.
    keep_linear: u32,
    _pad0: u32,
    _pad1: u32,
    // Model 0: display peak, cd/m², and t_p(peak/2), cd/m².
    peak_cd_m2: f32,
    tp_da_cd_m2: f32,
    // Model 1: colour saturation exponent.
    saturation: f32,
    // Model 2: gamma, and the window factors 2^−below, 2^above.
    gamma: f32,
    window_lo: f32,
    window_hi: f32,
    _pad2: f32,
    _pad3: f32,
}

@group(0) @binding(0) var<uniform> params: ToneParams;
@group(0) @binding(1) var<storage, read_write> state: FrameState;
@group(0) @binding(2) var<storage, read> work: array<vec4<f32>>;
@group(0) @binding(3) var<storage, read_write> linear_out: array<vec4<f32>>;
@group(0) @binding(4) var<storage, read> lut: array<u32>;
@group(0) @binding(5) var<storage, read_write> output: array<u32>;

// 001 §3.3 / gazelight_vision::temporal::MIN_LUMINANCE_CD_M2.
const MIN_ADAPTATION_CD_M2: f32 = 1e-6;
const LOG10_E: f32 = 0.4342944819032518;
const LOG2_10: f32 = 3.321928094887362;
// 003 eq 4: luminance weights of the Naka–Rushton operator.
const NAKA_RUSHTON_WEIGHTS: vec3<f32> = vec3<f32>(0.212656, 0.715158, 0.072186);
// 001 eq 14: the scotopic tint.
const SCOTOPIC_TINT: vec3<f32> = vec3<f32>(1.05, 0.97, 1.27);

fn log10f(x: f32) -> f32 {
    return log(x) * LOG10_E;
}

fn pow10(x: f32) -> f32 {
    return exp2(x * LOG2_10);
}

fn log_t_p(log_la: f32) -> f32 {
    if log_la <= -2.6 {
        // 000 eq 1, lower branch
        return -0.72;
    }
    if log_la >= 1.9 {
        // 000 eq 1, upper branch
        return log_la - 1.255;
    }
    // 000 eq 1, middle branch
    return pow(0.249 * log_la + 0.65, 2.7) - 0.72;
}

fn log_t_s(log_la: f32) -> f32 {
    if log_la <= -3.94 {
        // 000 eq 2, lower branch
        return -2.86;
    }
    if log_la >= -1.44 {
        // 000 eq 2, upper branch
        return log_la - 0.395;
    }
    // 000 eq 2, middle branch
    return pow(0.405 * log_la + 1.6, 2.18) - 2.86;
}

fn k_mesopic(la: f32) -> f32 {
    // 000 eq 3: scotopic limit 0.03 cd/m², photopic limit 3 cd/m²
    if la <= 0.03 {
        return 0.0;
    }
    if la >= 3.0 {
        return 1.0;
    }
    return pow(max(0.5 * log10f(la) + 0.761, 0.0), 1.5);
}

// 000 eq 4
fn t_m(la: f32) -> f32 {
    let k = k_mesopic(la);
    let lg = log10f(la);
    return pow10(log_t_s(lg)) * (1.0 - k) + pow10(log_t_p(lg)) * k;
}

@compute @workgroup_size(1, 1, 1)
fn prepare_tone() {
    let adaptation = state.adaptation_cd_m2;
    let la = select(MIN_ADAPTATION_CD_M2, max(adaptation, MIN_ADAPTATION_CD_M2), finite_f32(adaptation));
    let l_bar = state.light_target_cd_m2;
    switch params.model {
        case 0u: {
            let peak = params.peak_cd_m2;
            let tp_da = params.tp_da_cd_m2;
            if finite_f32(l_bar) && l_bar > la {
                let tm_bar = t_m(l_bar);
                // 000 eq 8: t* = t_m(L̄)² / t_m(L_wa)
                let a = tp_da / (tm_bar * tm_bar / t_m(la));
                let c = tp_da / tm_bar;
                // 000 eq 10
                state.tone_a = a / peak;
                state.tone_b = (c - a) * l_bar / peak;
            } else {
                // 000 eq 9
                state.tone_a = tp_da / t_m(la) / peak;
                state.tone_b = 0.0;
            }
            state.tone_c = 0.0;
        }
        case 1u: {
            state.tone_a = la;
            state.tone_b = params.saturation;
            state.tone_c = 0.0;
        }
        default: {
            let lo = la * params.window_lo;
            let hi = la * params.window_hi;
            state.tone_a = lo;
            state.tone_b = 1.0 / (hi - lo);
            state.tone_c = params.gamma;
        }
    }
    let lc = select(0.0, max(adaptation, 0.0), finite_f32(adaptation));
    // 001 eq 4: rod sensitivity, half at 0.04 cd/m²
    state.shift_sigma = select(0.0, 0.04 / (0.04 + lc), params.colour_shift != 0u);
    // 000 eq 11: full colour above 3 cd/m², 0.069/(0.069 + 1.409 e^(−4.267 L))
    state.discrimination_sigma = select(0.069 / (0.069 + 1.409 * exp(-4.267 * lc)), 1.0, lc > 3.0);
}

fn clean(v: f32) -> f32 {
    return select(0.0, v, finite_f32(v) && v > 0.0);
}

fn srgb_to_linear(v: f32) -> f32 {
    if v <= 0.04045 {
        return v / 12.92;
    }
    return pow((v + 0.055) / 1.055, 2.4);
}

fn tone(rgb: vec3<f32>) -> vec3<f32> {
    let c = vec3<f32>(clean(rgb.x), clean(rgb.y), clean(rgb.z));
    switch params.model {
        case 0u: {
            return c * state.tone_a + vec3<f32>(state.tone_b);
        }
        case 1u: {
            let w = NAKA_RUSHTON_WEIGHTS;
            let l = w.x * c.x + w.y * c.y + w.z * c.z;
            if l <= 0.0 {
                return vec3<f32>(0.0);
            }
            // 003 eq 4
            let l_ldr = l / (l + state.tone_a);
            let inv = 1.0 / l;
            // 003 eq 5
            return pow(c * inv, vec3<f32>(state.tone_b)) * l_ldr;
        }
        default: {
            let x = pow(clamp((c - vec3<f32>(state.tone_a)) * state.tone_b, vec3<f32>(0.0), vec3<f32>(1.0)),
                vec3<f32>(state.tone_c));
            return vec3<f32>(srgb_to_linear(x.x), srgb_to_linear(x.y), srgb_to_linear(x.z));
        }
    }
}

fn luminance(rgb: vec3<f32>) -> f32 {
    return LUMINANCE_WEIGHTS.x * rgb.x + LUMINANCE_WEIGHTS.y * rgb.y + LUMINANCE_WEIGHTS.z * rgb.z;
}

fn colour(rgb_in: vec3<f32>) -> vec3<f32> {
    var rgb = rgb_in;
    if params.colour_discrimination != 0u {
        // 000 eq 12: towards grey by σ_c
        let sigma = state.discrimination_sigma;
        rgb = sigma * rgb + vec3<f32>((1.0 - sigma) * luminance(rgb));
    }
    let s = state.shift_sigma;
    if s <= 0.0 {
        return rgb;
    }
    // 001 eq 14
    let l = luminance(rgb);
    return rgb * (1.0 - s) + SCOTOPIC_TINT * (l * s);
}

@compute @workgroup_size(8, 8, 1)
fn tone_map(@builtin(global_invocation_id) gid: vec3<u32>) {
    if gid.x >= params.width || gid.y >= params.height {
        return;
    }
    let i = gid.y * params.width + gid.x;
    let p = work[i];
    // No data (pooling.wgsl's import_scene set w): the CPU's NO_DATA_RGBA8,
    // transparent black; alpha 0 in the display-linear frame.
    if p.w != 0.0 {
        if params.keep_linear != 0u {
            linear_out[i] = vec4<f32>(0.0);
        }
        output[i] = 0u;
        return;
    }
    let display = clamp(colour(tone(p.xyz)), vec3<f32>(0.0), vec3<f32>(1.0));
    if params.keep_linear != 0u {
        linear_out[i] = vec4<f32>(display, 1.0);
    }
    output[i] = lut[lut_index(display.x)] | (lut[lut_index(display.y)] << 8u)
        | (lut[lut_index(display.z)] << 16u) | 0xff000000u;
}
