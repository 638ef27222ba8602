// Stage 4: windowed FFT glare at the gaze (001 §4.2.3; the twin of
// gazelight_vision::glare::GlareConvolver). W×W window centred on the pixel
// under the gaze, three colour planes of W² complex values in the FFT's data
// buffer (plane c at c·W²), transformed by gazelight_gpu::fft. Entry points:
//
// On a PSF rebuild (kernel cached otherwise):
// 1. `kernel_sums` (one workgroup): per-channel sums of the kernel cropped to
//    radius r = min(size/2, W/4);
// 2. `kernel_scatter`: the cropped kernel / its sum, centred on index (0, 0)
//    (wrapped), into the data buffer (a channel without light becomes the
//    identity); the host then runs the forward FFT and copies the spectrum.
// Per frame:
// 3. `window_gather`: source light w(d)·img of the window ∩ image (0
//    elsewhere), w(d) = (G(d) − G(R))/(1 − G(R)), G(d) = e^(−d²/2σ²) for
//    d < R = W/2 − r − 1, 0 beyond (σ → ∞ limit 1 − d²/R²);
// 4. `spectrum_multiply`: data ·= kernel spectrum (forward FFT before,
//    inverse FFT — with its 1/W² — after);
// 5. `blend`: img = (1 − w)·img + (K ∗ w·img) over window ∩ image.

struct GlareParams {
    // Window size W (power of two).
    window: u32,
    // PSF kernel size, pixels; its centre is (size/2, size/2).
    kernel_size: u32,
    // Radius r of the cropped kernel.
    radius: u32,
    // 1: use the σ → ∞ limit weight 1 − d²/R².
    linear_limit: u32,
    // Frame size.
    width: u32,
    height: u32,
    // Window origin in the frame (gaze pixel − W/2).
    origin_x: i32,
    origin_y: i32,
    // Window ∩ image in window coordinates: [i0, i1) × [j0, j1).
    i0: u32,
    i1: u32,
    j0: u32,
    j1: u32,
    // Gaze, frame pixels.
    gaze_x: f32,
    gaze_y: f32,
    // 1/(2σ²), R², G(R).
    inv_2s2: f32,
    r2: f32,
    g_r: f32,
    _pad0: f32,
    _pad1: f32,
    _pad2: f32,
}

@group(0) @binding(0) var<uniform> params: GlareParams;
@group(0) @binding(1) var<storage, read> kernel: array<vec4<f32>>;
@group(0) @binding(2) var<storage, read_write> sums: array<vec4<f32>>;
@group(0) @binding(3) var<storage, read_write> data: array<vec2<f32>>;
@group(0) @binding(4) var<storage, read> spectrum: array<vec2<f32>>;
@group(0) @binding(5) var<storage, read_write> work: array<vec4<f32>>;

const SUM_THREADS: u32 = 256u;
var<workgroup> tree: array<vec4<f32>, 256>;

fn kernel_at(dx: i32, dy: i32) -> vec4<f32> {
    let c = i32(params.kernel_size / 2u);
    return kernel[u32(c + dy) * params.kernel_size + u32(c + dx)];
}

@compute @workgroup_size(256, 1, 1)
fn kernel_sums(@builtin(local_invocation_index) t: u32) {
    let side = 2u * params.radius + 1u;
    let r = i32(params.radius);
    var acc = vec4<f32>(0.0);
    for (var k = t; k < side * side; k += SUM_THREADS) {
        acc += kernel_at(i32(k % side) - r, i32(k / side) - r);
    }
    tree[t] = acc;
    workgroupBarrier();
    for (var stride = SUM_THREADS / 2u; stride > 0u; stride = stride / 2u) {
        if t < stride {
            tree[t] += tree[t + stride];
        }
        workgroupBarrier();
    }
    if t == 0u {
        sums[0] = tree[0];
    }
}

@compute @workgroup_size(8, 8, 1)
fn kernel_scatter(@builtin(global_invocation_id) gid: vec3<u32>) {
    let w = params.window;
    if gid.x >= w || gid.y >= w {
        return;
    }
    // Index (i, j) holds offset (dx, dy) = (i, j) wrapped to (−W/2, W/2].
    let dx = select(i32(gid.x), i32(gid.x) - i32(w), gid.x > w / 2u);
    let dy = select(i32(gid.y), i32(gid.y) - i32(w), gid.y > w / 2u);
    let r = i32(params.radius);
    let inside = abs(dx) <= r && abs(dy) <= r;
    var k = vec4<f32>(0.0);
    if inside {
        k = kernel_at(dx, dy);
    }
    let s = sums[0];
    let origin = gid.x == 0u && gid.y == 0u;
    let index = gid.y * w + gid.x;
    let plane = w * w;
    for (var c = 0u; c < 3u; c++) {
        let sum = s[c];
        var v = 0.0;
        if sum > 0.0 && finite_f32(sum) {
            v = k[c] / sum;
        } else if origin {
            v = 1.0;
        }
        data[c * plane + index] = vec2<f32>(v, 0.0);
    }
}

fn finite_f32(v: f32) -> bool {
    return (bitcast<u32>(v) & 0x7f800000u) != 0x7f800000u;
}

// Falloff weight of the source at window pixel (i, j).
fn falloff(i: u32, j: u32) -> f32 {
    let dx = f32(params.origin_x + i32(i)) + 0.5 - params.gaze_x;
    let dy = f32(params.origin_y + i32(j)) + 0.5 - params.gaze_y;
    let d2 = dx * dx + dy * dy;
    if d2 >= params.r2 {
        return 0.0;
    }
    if params.linear_limit != 0u {
        return 1.0 - d2 / params.r2;
    }
    let g = exp(-d2 * params.inv_2s2);
    return clamp((g - params.g_r) / (1.0 - params.g_r), 0.0, 1.0);
}

fn in_window(i: u32, j: u32) -> bool {
    return i >= params.i0 && i < params.i1 && j >= params.j0 && j < params.j1;
}

fn frame_index(i: u32, j: u32) -> u32 {
    let x = u32(params.origin_x + i32(i));
    let y = u32(params.origin_y + i32(j));
    return y * params.width + x;
}

@compute @workgroup_size(8, 8, 1)
fn window_gather(@builtin(global_invocation_id) gid: vec3<u32>) {
    let w = params.window;
    if gid.x >= w || gid.y >= w {
        return;
    }
    var v = vec3<f32>(0.0);
    if in_window(gid.x, gid.y) {
        v = work[frame_index(gid.x, gid.y)].xyz * falloff(gid.x, gid.y);
    }
    let index = gid.y * w + gid.x;
    let plane = w * w;
    data[index] = vec2<f32>(v.x, 0.0);
    data[plane + index] = vec2<f32>(v.y, 0.0);
    data[2u * plane + index] = vec2<f32>(v.z, 0.0);
}

@compute @workgroup_size(64, 1, 1)
fn spectrum_multiply(
    @builtin(global_invocation_id) gid: vec3<u32>,
    @builtin(num_workgroups) groups: vec3<u32>,
) {
    let k = gid.x + gid.y * groups.x * 64u;
    if k >= 3u * params.window * params.window {
        return;
    }
    let a = data[k];
    let b = spectrum[k];
    data[k] = vec2<f32>(a.x * b.x - a.y * b.y, a.x * b.y + a.y * b.x);
}

@compute @workgroup_size(8, 8, 1)
fn blend(@builtin(global_invocation_id) gid: vec3<u32>) {
    let w = params.window;
    if gid.x >= w || gid.y >= w || !in_window(gid.x, gid.y) {
        return;
    }
    let keep = 1.0 - falloff(gid.x, gid.y);
    let f = frame_index(gid.x, gid.y);
    let index = gid.y * w + gid.x;
    let plane = w * w;
    let glare = vec3<f32>(data[index].x, data[plane + index].x, data[2u * plane + index].x);
    work[f] = vec4<f32>(work[f].xyz * keep + glare, 0.0);
}
