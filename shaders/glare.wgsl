// Stage 4: glare at the gaze with the kernel split into a full-resolution
// core and a coarse wide field (001 §4.2.3; the twin of
// gazelight_vision::glare::GlareConvolver, step by step). Two FFT windows,
// each three colour planes of W² complex values (plane c at c·W²),
// transformed by gazelight_gpu::fft: the fine one (W_f display pixels per
// side, origin (ofx, ofy)) and the coarse one (W_c blocks of b × b display
// pixels, origin (ocx, ocy), block (W_c/2) centred on the gaze pixel).
//
// On a PSF rebuild (spectra cached otherwise):
// 1. `kernel_fine`: (1 − g(d))·K for |dx|, |dy| ≤ r_fine, centred on index
//    (0, 0) (wrapped), g the smoothstep from 0 at r_fine/2 to 1 at r_fine;
// 2. `kernel_coarse`: g(d)·K summed over the b × b pixels of each block
//    (block bx holds dx = bx·b − b/2 … bx·b + b/2), wrapped; the host then
//    runs both forward FFTs and copies the spectra.
// Per frame:
// 3. `gather_fine`: source light w(d)·img in the fine window (sources in the
//    box [sx0, sx1) × [sy0, sy1) around the gaze), w = 1 for d ≤ d_full,
//    (G(d − d_full) − G(3σ))/(1 − G(3σ)) beyond, 0 from d_full + 3σ;
// 4. `gather_coarse`: the same light box-summed into the coarse blocks;
// 5. `multiply_fine`, `multiply_coarse`: data ·= kernel spectrum (forward
//    FFT before, inverse FFT — with its 1/W² — after);
// 6. `blend`: over the coarse window ∩ image, out = keep(w)·img + fine +
//    bilinear(coarse / b²) at the block centres (outside the fine window:
//    keep(0)·img + coarse term), keep(w) = keep0 − keep_slope·w: 1 − w
//    without the far field, (1 − w)(1 − E_near) − E_tail with it
//    (far_glare.wgsl adds its veil after this pass).
//
// GlareParams and the source weight are in glare_window.wgsl (prepended;
// far_glare.wgsl shares them).

@group(0) @binding(0) var<uniform> params: GlareParams;
@group(0) @binding(1) var<storage, read> kernel: array<vec4<f32>>;
@group(0) @binding(2) var<storage, read_write> fine: array<vec2<f32>>;
@group(0) @binding(3) var<storage, read> fine_spectrum: array<vec2<f32>>;
@group(0) @binding(4) var<storage, read_write> coarse: array<vec2<f32>>;
@group(0) @binding(5) var<storage, read> coarse_spectrum: array<vec2<f32>>;
@group(0) @binding(6) var<storage, read_write> work: array<vec4<f32>>;

fn kernel_at(dx: i32, dy: i32) -> vec4<f32> {
    let c = i32(params.kernel_size / 2u);
    return kernel[u32(c + dy) * params.kernel_size + u32(c + dx)];
}

// The fine/coarse split g: smoothstep from 0 at r_fine/2 to 1 at r_fine.
fn split_weight(d: f32) -> f32 {
    let r = f32(params.r_fine);
    let s = clamp((d - 0.5 * r) / (0.5 * r), 0.0, 1.0);
    return s * s * (3.0 - 2.0 * s);
}

// Offset of window index i in a W-periodic window: i wrapped to (−W/2, W/2].
fn wrapped(i: u32, w: u32) -> i32 {
    return select(i32(i), i32(i) - i32(w), i > w / 2u);
}

@compute @workgroup_size(8, 8, 1)
fn kernel_fine(@builtin(global_invocation_id) gid: vec3<u32>) {
    let w = params.wf;
    if gid.x >= w || gid.y >= w {
        return;
    }
    let dx = wrapped(gid.x, w);
    let dy = wrapped(gid.y, w);
    let r = i32(params.r_fine);
    var k = vec3<f32>(0.0);
    if abs(dx) <= r && abs(dy) <= r {
        let keep = 1.0 - split_weight(length(vec2<f32>(f32(dx), f32(dy))));
        if keep > 0.0 {
            k = kernel_at(dx, dy).xyz * keep;
        }
    }
    let index = gid.y * w + gid.x;
    let plane = w * w;
    fine[index] = vec2<f32>(k.x, 0.0);
    fine[plane + index] = vec2<f32>(k.y, 0.0);
    fine[2u * plane + index] = vec2<f32>(k.z, 0.0);
}

@compute @workgroup_size(8, 8, 1)
fn kernel_coarse(@builtin(global_invocation_id) gid: vec3<u32>) {
    let w = params.wc;
    if gid.x >= w || gid.y >= w {
        return;
    }
    let b = i32(params.block);
    let hb = b / 2;
    let rk = i32(params.kernel_size / 2u);
    let bx = wrapped(gid.x, w);
    let by = wrapped(gid.y, w);
    let x_lo = max(bx * b - hb, -rk);
    let x_hi = min(bx * b + hb, rk);
    let y_lo = max(by * b - hb, -rk);
    let y_hi = min(by * b + hb, rk);
    var acc = vec3<f32>(0.0);
    for (var dy = y_lo; dy <= y_hi; dy++) {
        for (var dx = x_lo; dx <= x_hi; dx++) {
            let g = split_weight(length(vec2<f32>(f32(dx), f32(dy))));
            if g > 0.0 {
                acc += kernel_at(dx, dy).xyz * g;
            }
        }
    }
    let index = gid.y * w + gid.x;
    let plane = w * w;
    coarse[index] = vec2<f32>(acc.x, 0.0);
    coarse[plane + index] = vec2<f32>(acc.y, 0.0);
    coarse[2u * plane + index] = vec2<f32>(acc.z, 0.0);
}

// Source weight of frame pixel (x, y) (glare_window.wgsl).
fn source_weight(x: i32, y: i32) -> f32 {
    return window_weight(params, x, y);
}

fn frame_index(x: i32, y: i32) -> u32 {
    return u32(y) * params.width + u32(x);
}

@compute @workgroup_size(8, 8, 1)
fn gather_fine(@builtin(global_invocation_id) gid: vec3<u32>) {
    let w = params.wf;
    if gid.x >= w || gid.y >= w {
        return;
    }
    let x = params.ofx + i32(gid.x);
    let y = params.ofy + i32(gid.y);
    var v = vec3<f32>(0.0);
    let wgt = source_weight(x, y);
    if wgt > 0.0 {
        v = work[frame_index(x, y)].xyz * wgt;
    }
    let index = gid.y * w + gid.x;
    let plane = w * w;
    fine[index] = vec2<f32>(v.x, 0.0);
    fine[plane + index] = vec2<f32>(v.y, 0.0);
    fine[2u * plane + index] = vec2<f32>(v.z, 0.0);
}

@compute @workgroup_size(8, 8, 1)
fn gather_coarse(@builtin(global_invocation_id) gid: vec3<u32>) {
    let w = params.wc;
    if gid.x >= w || gid.y >= w {
        return;
    }
    let b = i32(params.block);
    let bx0 = params.ocx + i32(gid.x) * b;
    let by0 = params.ocy + i32(gid.y) * b;
    let x_lo = max(bx0, params.sx0);
    let x_hi = min(bx0 + b, params.sx1);
    let y_lo = max(by0, params.sy0);
    let y_hi = min(by0 + b, params.sy1);
    var acc = vec3<f32>(0.0);
    for (var y = y_lo; y < y_hi; y++) {
        for (var x = x_lo; x < x_hi; x++) {
            let wgt = source_weight(x, y);
            if wgt > 0.0 {
                acc += work[frame_index(x, y)].xyz * wgt;
            }
        }
    }
    let index = gid.y * w + gid.x;
    let plane = w * w;
    coarse[index] = vec2<f32>(acc.x, 0.0);
    coarse[plane + index] = vec2<f32>(acc.y, 0.0);
    coarse[2u * plane + index] = vec2<f32>(acc.z, 0.0);
}

fn cmul(a: vec2<f32>, b: vec2<f32>) -> vec2<f32> {
    return vec2<f32>(a.x * b.x - a.y * b.y, a.x * b.y + a.y * b.x);
}

@compute @workgroup_size(64, 1, 1)
fn multiply_fine(
    @builtin(global_invocation_id) gid: vec3<u32>,
    @builtin(num_workgroups) groups: vec3<u32>,
) {
    let k = gid.x + gid.y * groups.x * 64u;
    if k >= 3u * params.wf * params.wf {
        return;
    }
    fine[k] = cmul(fine[k], fine_spectrum[k]);
}

@compute @workgroup_size(64, 1, 1)
fn multiply_coarse(
    @builtin(global_invocation_id) gid: vec3<u32>,
    @builtin(num_workgroups) groups: vec3<u32>,
) {
    let k = gid.x + gid.y * groups.x * 64u;
    if k >= 3u * params.wc * params.wc {
        return;
    }
    coarse[k] = cmul(coarse[k], coarse_spectrum[k]);
}

fn coarse_at(j: i32, i: i32) -> vec3<f32> {
    let w = i32(params.wc);
    if j < 0 || i < 0 || j >= w || i >= w {
        return vec3<f32>(0.0);
    }
    let index = u32(j * w + i);
    let plane = params.wc * params.wc;
    return vec3<f32>(coarse[index].x, coarse[plane + index].x, coarse[2u * plane + index].x);
}

@compute @workgroup_size(8, 8, 1)
fn blend(@builtin(global_invocation_id) gid: vec3<u32>) {
    let x = params.x0 + i32(gid.x);
    let y = params.y0 + i32(gid.y);
    if x >= params.x1 || y >= params.y1 {
        return;
    }
    let bf = f32(params.block);
    let v = (f32(y - params.ocy) + 0.5) / bf - 0.5;
    let j0f = floor(v);
    let fy = v - j0f;
    let j0 = i32(j0f);
    let u = (f32(x - params.ocx) + 0.5) / bf - 0.5;
    let i0f = floor(u);
    let fx = u - i0f;
    let i0 = i32(i0f);
    let a = coarse_at(j0, i0);
    let b = coarse_at(j0, i0 + 1);
    let c = coarse_at(j0 + 1, i0);
    let d = coarse_at(j0 + 1, i0 + 1);
    // Separable as on the CPU: along x (with 1/b²), then along y.
    let inv_b2 = 1.0 / (bf * bf);
    let lo = (a * (1.0 - fx) + b * fx) * inv_b2;
    let hi = (c * (1.0 - fx) + d * fx) * inv_b2;
    let add = lo * (1.0 - fy) + hi * fy;
    let f = frame_index(x, y);
    let old = work[f];
    var p = old.xyz;
    let fi = x - params.ofx;
    let fj = y - params.ofy;
    let wf = i32(params.wf);
    if fi >= 0 && fi < wf && fj >= 0 && fj < wf {
        let index = u32(fj * wf + fi);
        let plane = params.wf * params.wf;
        let keep = params.keep0 - params.keep_slope * source_weight(x, y);
        let glare = vec3<f32>(fine[index].x, fine[plane + index].x, fine[2u * plane + index].x);
        p = p * keep + glare + add;
    } else {
        p = p * params.keep0 + add;
    }
    // w: the no-data flag of pooling.wgsl's import_scene, kept.
    work[f] = vec4<f32>(p, old.w);
}
