// Per-channel unit energy of the spectral glare kernel (gazelight_vision::psf:
// each linear sRGB channel sums to 1), in three entry points over one bind
// group. Core WebGPU has no float atomics, so the sums are tree reductions
// in workgroup memory:
//
// 1. `partial_sums`: one pixel per thread, each workgroup of 256 reduces its
//    pixels to one partial sum per channel;
// 2. `final_sums`: one workgroup; each thread adds a strided set of the
//    partials, then a tree reduction gives the three channel sums;
// 3. `divide`: every pixel divided by its channel's sum (0 when the sum is 0).

struct NormalizeParams {
    // Kernel pixels (size²).
    pixels: u32,
    // Workgroups of `partial_sums` (= number of partial sums).
    partial_count: u32,
    _pad0: u32,
    _pad1: u32,
}

@group(0) @binding(0) var<uniform> params: NormalizeParams;
@group(0) @binding(1) var<storage, read_write> rgb: array<vec4<f32>>;
@group(0) @binding(2) var<storage, read_write> partials: array<vec4<f32>>;
@group(0) @binding(3) var<storage, read_write> sums: array<vec4<f32>>;

const REDUCE_THREADS: u32 = 256u;
var<workgroup> tree: array<vec4<f32>, 256>;

// Tree reduction of `value` over the workgroup; the total is in tree[0].
fn reduce(t: u32, value: vec4<f32>) {
    tree[t] = value;
    workgroupBarrier();
    for (var stride = REDUCE_THREADS / 2u; stride > 0u; stride = stride / 2u) {
        if t < stride {
            tree[t] += tree[t + stride];
        }
        workgroupBarrier();
    }
}

@compute @workgroup_size(256, 1, 1)
fn partial_sums(
    @builtin(workgroup_id) wid: vec3<u32>,
    @builtin(local_invocation_index) t: u32,
) {
    let index = wid.x * REDUCE_THREADS + t;
    var value = vec4<f32>(0.0);
    if index < params.pixels {
        value = rgb[index];
    }
    reduce(t, value);
    if t == 0u {
        partials[wid.x] = tree[0];
    }
}

@compute @workgroup_size(256, 1, 1)
fn final_sums(@builtin(local_invocation_index) t: u32) {
    var value = vec4<f32>(0.0);
    for (var i = t; i < params.partial_count; i += REDUCE_THREADS) {
        value += partials[i];
    }
    reduce(t, value);
    if t == 0u {
        sums[0] = tree[0];
    }
}

@compute @workgroup_size(256, 1, 1)
fn divide(@builtin(global_invocation_id) gid: vec3<u32>) {
    let index = gid.x;
    if index >= params.pixels {
        return;
    }
    let total = sums[0];
    let scale = select(vec4<f32>(0.0), vec4<f32>(1.0) / total, total > vec4<f32>(0.0));
    rgb[index] = rgb[index] * scale;
}
