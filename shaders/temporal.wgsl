// Stage 2: temporal adaptation (gazelight_vision::temporal::TemporalModel::step),
// one thread: reads FrameState.target_cd_m2 (stage 1) and the carried
// adaptation state, writes the new state. f32 (the CPU carries f64).
//
// Models (`model`):
//   0 Krawczyk, 001 eq 2–4: L += (Y − L)(1 − e^(−dt/τ(Y))), τ = σ τ_rod + (1 − σ) τ_cone,
//     σ(Y) = 0.04/(0.04 + Y) (001 eq 4); a = τ_rod, b = τ_cone;
//   1 p^dt smoothing, 000 eq 7, with the light-adaptation overshoot L̄ (000 eq 8);
//     a = p_light, b = p_dark;
//   2 exponential in log10 L, 003 eq 2; a = τ_light, b = τ_dark;
//   3 constant speed in log10 L, 003 eq 3; a, b = seconds per decade.
// `reset` = 1 starts adapted to the target (the CPU's first frame).

struct TemporalParams {
    model: u32,
    reset: u32,
    overshoot: u32,
    _pad0: u32,
    dt_secs: f32,
    a: f32,
    b: f32,
    _pad1: f32,
}

@group(0) @binding(0) var<uniform> params: TemporalParams;
@group(0) @binding(1) var<storage, read_write> state: FrameState;

// 001 §3.3: lowest luminance of the log-domain models, cd/m² (MIN_LUMINANCE_CD_M2).
const MIN_LUMINANCE_CD_M2: f32 = 1e-6;
const LOG10_E: f32 = 0.4342944819032518;
const LOG2_10: f32 = 3.321928094887362;

fn log_lum(l: f32) -> f32 {
    return log(max(l, MIN_LUMINANCE_CD_M2)) * LOG10_E;
}

fn pow10(x: f32) -> f32 {
    return exp2(x * LOG2_10);
}

// 1 − e^(−x) for x ≥ 0, accurate for small x (the CPU uses −expm1(−x)).
fn one_minus_exp_neg(x: f32) -> f32 {
    if x < 1e-3 {
        return x * (1.0 - x * (0.5 - x / 6.0));
    }
    return 1.0 - exp(-x);
}

@compute @workgroup_size(1, 1, 1)
fn adapt() {
    let y = state.target_cd_m2;
    if params.reset != 0u {
        let l0 = select(0.0, max(y, 0.0), finite_f32(y));
        state.adaptation_cd_m2 = l0;
        state.light_target_cd_m2 = l0;
        return;
    }
    let dt = params.dt_secs;
    if !(finite_f32(y) && y >= 0.0 && finite_f32(dt) && dt >= 0.0) {
        return;
    }
    let l = state.adaptation_cd_m2;
    var next = l;
    var light_target = l;
    switch params.model {
        case 0u: {
            // 001 eq 4: half-sensitivity luminance 0.04 cd/m²
            let s = 0.04 / (0.04 + max(y, 0.0));
            // 001 eq 3
            let tau = s * params.a + (1.0 - s) * params.b;
            // 001 eq 2
            next = l + (y - l) * one_minus_exp_neg(dt / tau);
            light_target = next;
        }
        case 1u: {
            // 000 eq 7
            let p = select(params.b, params.a, y > l);
            let keep = pow(p, dt);
            next = (1.0 - keep) * y + keep * l;
            // 000 eq 8
            light_target = select(next, y, params.overshoot != 0u && y > next);
        }
        case 2u: {
            // 003 eq 2, in log10
            let ll = log_lum(l);
            let ly = log_lum(y);
            let tau = select(params.b, params.a, ly > ll);
            next = pow10(ll + (ly - ll) * one_minus_exp_neg(dt / tau));
            light_target = next;
        }
        default: {
            // 003 eq 3, in log10
            let ll = log_lum(l);
            let ly = log_lum(y);
            var lg = max(ll - dt / params.b, ly);
            if ll < ly {
                lg = min(ll + dt / params.a, ly);
            }
            next = pow10(lg);
            light_target = next;
        }
    }
    state.adaptation_cd_m2 = next;
    state.light_target_cd_m2 = light_target;
}
