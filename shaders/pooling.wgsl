// Stage 1 of the frame (gazelight_vision::pipeline pass A + PoolingModel::pool,
// 001 §4.1, 000 eq 5–6, 003 eq 1, 004 §3.1, 000 §3.2), four entry points
// over one bind group:
//
// 1. `import_scene`: the HDR frame (RGBA f32, cd/m²) into the working
//    buffer, NaN/±∞/negative/subnormal values set to 0 (the CPU's sanitize);
//    a pixel with no data (any channel NaN: outside the scene's field,
//    gazelight_vision::image::is_no_data) gets w = 1 in the working buffer,
//    which glare and acuity keep and tone_map marks in the output;
// 2. `block_luminance`: one thread per block of ds×ds pixels: the block's
//    luminance summed over its pixels with data over all its pixels, and
//    the share of its pixels with data (same summation order as the CPU:
//    rows, then pixels in the row);
// 3. `pool_partial`: the weighted sums Σ w·L and Σ w·valid over the block plane,
//    per workgroup (grid-stride loop, then a tree reduction; core WebGPU has
//    no float atomics);
// 4. `pool_final`: one workgroup adds the partials and writes the pooled
//    target Σ w·L / Σ w·valid (or the block under the gaze, over its valid
//    share, when the weights vanish; when that block has no data either,
//    the last frame's target is kept) into FrameState.target_cd_m2.
//
// The weight w(x, y) of block (x, y) follows the model:
//   0 Gaussian (001 §4.1): pixel-integrated Gaussian, (erf differences) in x
//     times y, inside the host-computed span of ±(6σ + 1); on a rectilinear
//     plane between block edges mapped to angles, times the exact-angle and
//     solid-angle corrections at the block centre;
//   1 centre weight 1 − 4d² (000 eq 5–6), d normalised by the half sizes;
//   2 eccentricity e2/(e2 + d°) (003 eq 1);
//   3 gaze window (004 §3.1): pixel overlap with the window, in x times y;
//   4 panorama mean with sin(πy/h) row weights (000 §3.2).

struct PoolParams {
    // Frame size, pixels.
    width: u32,
    height: u32,
    // Block plane size (ceil(width/ds), ceil(height/ds)).
    small_w: u32,
    small_h: u32,
    // Block size, pixels.
    ds: u32,
    // Pooling model (see the header).
    model: u32,
    // Workgroups of `pool_partial`.
    partial_count: u32,
    _pad0: u32,
    // Span of blocks with non-zero weight: [x0, x1) × [y0, y1).
    x0: u32,
    x1: u32,
    y0: u32,
    y1: u32,
    // Gaze on the block plane, blocks.
    gaze_x: f32,
    gaze_y: f32,
    // Model parameters: 0: p0 = 1/(σ√2); 1: p0, p1 = half width, height,
    // p2, p3 = the centre;
    // 2: p0 = e2°, p1 = ° per block; 3: p0..p3 = window lo_x, hi_x, lo_y,
    // hi_y; 4: unused.
    p0: f32,
    p1: f32,
    p2: f32,
    p3: f32,
    // The block plane's geometry: 0 uniform (the weights in blocks, p1 of
    // model 2 = ° per block), 1 rectilinear (angles through the view, as
    // gazelight_vision::pooling::Axes): the gaze's azimuth and elevation
    // (rad), cos elevation, k = √(1 + s_gx²); the tangent at x = 0, per
    // block in x, at y = 0, per block in y.
    geo: u32,
    _pad1: u32,
    azimuth: f32,
    elevation: f32,
    cos_elevation: f32,
    k: f32,
    tan_x0: f32,
    tan_per_x: f32,
    tan_y0: f32,
    tan_per_y: f32,
}

@group(0) @binding(0) var<uniform> params: PoolParams;
@group(0) @binding(1) var<storage, read> scene: array<vec4<f32>>;
@group(0) @binding(2) var<storage, read_write> work: array<vec4<f32>>;
// Per block: x = luminance over the valid pixels per block pixel, y = the
// share of the block's pixels with data.
@group(0) @binding(3) var<storage, read_write> small_lum: array<vec2<f32>>;
@group(0) @binding(4) var<storage, read_write> partials: array<vec2<f32>>;
@group(0) @binding(5) var<storage, read_write> state: FrameState;

const POOL_THREADS: u32 = 256u;
var<workgroup> tree: array<vec2<f32>, 256>;

// Smallest normal f32: values below it are physically black (the CPU's sanitize).
const MIN_POSITIVE: f32 = 1.17549435e-38;

fn sanitize(v: f32) -> f32 {
    return select(0.0, v, finite_f32(v) && v >= MIN_POSITIVE);
}

fn clean(v: f32) -> f32 {
    return select(0.0, v, finite_f32(v) && v > 0.0);
}

// NaN on the bit pattern (robust against fast-math assumptions).
fn nan_f32(v: f32) -> bool {
    let b = bitcast<u32>(v);
    return (b & 0x7f800000u) == 0x7f800000u && (b & 0x007fffffu) != 0u;
}

// A pixel with no data (gazelight_vision::image::is_no_data): any channel NaN.
fn no_data(s: vec4<f32>) -> bool {
    return nan_f32(s.x) || nan_f32(s.y) || nan_f32(s.z);
}

// erf, Numerical Recipes' erfc fit (|error| < 1.2e-7), as gazelight_vision::pooling.
fn erf_nr(x: f32) -> f32 {
    let z = abs(x);
    let t = 1.0 / (1.0 + 0.5 * z);
    let ans = t * exp(-z * z - 1.26551223 + t * (1.00002368 + t * (0.37409196 + t * (0.09678418
        + t * (-0.18628806 + t * (0.27886807 + t * (-1.13520398 + t * (1.48851587
        + t * (-0.82215223 + t * 0.17087277)))))))));
    return select(ans - 1.0, 1.0 - ans, x >= 0.0);
}

fn overlap(i: u32, lo: f32, hi: f32) -> f32 {
    let a = max(f32(i), lo);
    let b = min(f32(i) + 1.0, hi);
    return max(b - a, 0.0);
}

// Rectilinear plane: the angle of column edge x and row edge y from the
// gaze along the view's azimuth and elevation, degrees.
fn x_deg(x: f32) -> f32 {
    return degrees(params.cos_elevation * (atan(params.tan_x0 + x * params.tan_per_x) - params.azimuth));
}

fn y_deg(y: f32) -> f32 {
    return degrees(params.elevation - atan((params.tan_y0 - y * params.tan_per_y) / params.k));
}

// Rectilinear plane: the great-circle angle from the gaze to point (x, y), degrees.
fn exact_deg(x: f32, y: f32) -> f32 {
    let s = vec2<f32>(params.tan_x0 + x * params.tan_per_x, params.tan_y0 - y * params.tan_per_y);
    let ce = cos(params.elevation);
    let g = vec3<f32>(ce * sin(params.azimuth), sin(params.elevation), -ce * cos(params.azimuth));
    let p = normalize(vec3<f32>(s.x, s.y, -1.0));
    return degrees(atan2(length(cross(g, p)), dot(g, p)));
}

// Rectilinear plane: a block's solid angle over its separable sides.
fn solid_angle_ratio(x: f32, y: f32) -> f32 {
    let sx = params.tan_x0 + x * params.tan_per_x;
    let sy = params.tan_y0 - y * params.tan_per_y;
    let k = params.k;
    let r2 = 1.0 + sx * sx + sy * sy;
    return (1.0 + sx * sx) * (k * k + sy * sy) / (params.cos_elevation * k * r2 * sqrt(r2));
}

fn in_span(x: u32, y: u32) -> bool {
    return x >= params.x0 && x < params.x1 && y >= params.y0 && y < params.y1;
}

fn weight(x: u32, y: u32) -> f32 {
    let gx = params.gaze_x;
    let gy = params.gaze_y;
    switch params.model {
        case 0u: {
            if !in_span(x, y) {
                return 0.0;
            }
            let inv = params.p0;
            if params.geo == 1u {
                let fy = f32(y);
                let wy = 0.5 * (erf_nr(y_deg(fy + 1.0) * inv) - erf_nr(y_deg(fy) * inv));
                if wy <= 0.0 {
                    return 0.0;
                }
                let fx = f32(x);
                let wx = 0.5 * (erf_nr(x_deg(fx + 1.0) * inv) - erf_nr(x_deg(fx) * inv));
                let dx = x_deg(fx + 0.5);
                let dy = y_deg(fy + 0.5);
                let d = exact_deg(fx + 0.5, fy + 0.5);
                let excess = d * d - dx * dx - dy * dy;
                return wx * wy * exp(-excess * inv * inv) * solid_angle_ratio(fx + 0.5, fy + 0.5);
            }
            let wy = 0.5 * (erf_nr((f32(y) + 1.0 - gy) * inv) - erf_nr((f32(y) - gy) * inv));
            if wy <= 0.0 {
                return 0.0;
            }
            let wx = 0.5 * (erf_nr((f32(x) + 1.0 - gx) * inv) - erf_nr((f32(x) - gx) * inv));
            return wx * wy;
        }
        case 1u: {
            let dy = (f32(y) + 0.5 - params.p3) / params.p1;
            if abs(dy) >= 0.5 {
                return 0.0;
            }
            let dx = (f32(x) + 0.5 - params.p2) / params.p0;
            let d2 = dx * dx + dy * dy;
            return select(0.0, 1.0 - 4.0 * d2, d2 < 0.25);
        }
        case 2u: {
            let dx = f32(x) + 0.5 - gx;
            let dy = f32(y) + 0.5 - gy;
            var d_deg = sqrt(dx * dx + dy * dy) * params.p1;
            if params.geo == 1u {
                d_deg = exact_deg(f32(x) + 0.5, f32(y) + 0.5);
            }
            return params.p0 / (params.p0 + d_deg);
        }
        case 3u: {
            if !in_span(x, y) {
                return 0.0;
            }
            let wy = overlap(y, params.p2, params.p3);
            if wy <= 0.0 {
                return 0.0;
            }
            return wy * overlap(x, params.p0, params.p1);
        }
        default: {
            return sin(PI * (f32(y) + 0.5) / f32(params.small_h));
        }
    }
}

// Tree reduction of `value` over the workgroup; the total is in tree[0].
fn reduce(t: u32, value: vec2<f32>) {
    tree[t] = value;
    workgroupBarrier();
    for (var stride = POOL_THREADS / 2u; stride > 0u; stride = stride / 2u) {
        if t < stride {
            tree[t] += tree[t + stride];
        }
        workgroupBarrier();
    }
}

@compute @workgroup_size(8, 8, 1)
fn import_scene(@builtin(global_invocation_id) gid: vec3<u32>) {
    if gid.x >= params.width || gid.y >= params.height {
        return;
    }
    let i = gid.y * params.width + gid.x;
    let s = scene[i];
    work[i] = vec4<f32>(sanitize(s.x), sanitize(s.y), sanitize(s.z), select(0.0, 1.0, no_data(s)));
}

@compute @workgroup_size(8, 8, 1)
fn block_luminance(@builtin(global_invocation_id) gid: vec3<u32>) {
    if gid.x >= params.small_w || gid.y >= params.small_h {
        return;
    }
    let x0 = gid.x * params.ds;
    let y0 = gid.y * params.ds;
    let x1 = min(x0 + params.ds, params.width);
    let y1 = min(y0 + params.ds, params.height);
    var sum = 0.0;
    var valid = 0u;
    for (var y = y0; y < y1; y++) {
        for (var x = x0; x < x1; x++) {
            let s = scene[y * params.width + x];
            let p = vec3<f32>(sanitize(s.x), sanitize(s.y), sanitize(s.z));
            sum += LUMINANCE_WEIGHTS.x * p.x + LUMINANCE_WEIGHTS.y * p.y + LUMINANCE_WEIGHTS.z * p.z;
            valid += select(1u, 0u, no_data(s));
        }
    }
    let n = f32((x1 - x0) * (y1 - y0));
    small_lum[gid.y * params.small_w + gid.x] = vec2<f32>(sum / n, f32(valid) / n);
}

@compute @workgroup_size(256, 1, 1)
fn pool_partial(
    @builtin(workgroup_id) wid: vec3<u32>,
    @builtin(local_invocation_index) t: u32,
) {
    let n = params.small_w * params.small_h;
    let stride = params.partial_count * POOL_THREADS;
    var acc = vec2<f32>(0.0);
    for (var i = wid.x * POOL_THREADS + t; i < n; i += stride) {
        let x = i % params.small_w;
        let y = i / params.small_w;
        let w = weight(x, y);
        let b = small_lum[i];
        acc += vec2<f32>(w * clean(b.x), w * clamp(b.y, 0.0, 1.0));
    }
    reduce(t, acc);
    if t == 0u {
        partials[wid.x] = tree[0];
    }
}

@compute @workgroup_size(256, 1, 1)
fn pool_final(@builtin(local_invocation_index) t: u32) {
    var acc = vec2<f32>(0.0);
    for (var i = t; i < params.partial_count; i += POOL_THREADS) {
        acc += partials[i];
    }
    reduce(t, acc);
    if t == 0u {
        let sum = tree[0].x;
        let w = tree[0].y;
        if w > 0.0 && finite_f32(w) && finite_f32(sum) {
            state.target_cd_m2 = max(sum / w, 0.0);
        } else {
            let x = min(u32(max(floor(params.gaze_x), 0.0)), params.small_w - 1u);
            let y = min(u32(max(floor(params.gaze_y), 0.0)), params.small_h - 1u);
            let b = small_lum[y * params.small_w + x];
            let a = clamp(b.y, 0.0, 1.0);
            // No data under the gaze either: the last target is kept.
            if a > 0.0 {
                state.target_cd_m2 = max(clean(b.x) / a, 0.0);
            }
        }
    }
}
