// Glare kernel build, pass 4: unit energy over the whole kernel. The twin of
// the end of gazelight_vision::psf::PsfBuilder::build:
// K_c = α_c · N_c + CIE146 term, α_c = (1 − Σ CIE146 term) / Σ N_c.
//
// `sum_near`: one workgroup sums each channel of the near field + lobes N
// (strided per thread, then a tree in workgroup memory) into sums[0].
// `compose`: every kernel pixel, α · N + the CIE 146 stray light (uploaded
// once; 0 without stray light), w = 0.

@group(0) @binding(0) var<uniform> params: PsfBuild;
@group(0) @binding(1) var<storage, read> near: array<vec4<f32>>;
@group(0) @binding(2) var<storage, read> cie: array<f32>;
@group(0) @binding(3) var<storage, read_write> sums: array<vec4<f32>>;
@group(0) @binding(4) var<storage, read_write> kernel: array<vec4<f32>>;

const SUM_THREADS: u32 = 256u;

var<workgroup> partial: array<vec4<f32>, 256>;

@compute @workgroup_size(256)
fn sum_near(@builtin(local_invocation_index) t: u32) {
    let count = params.kernel_size * params.kernel_size;
    var s = vec4<f32>(0.0);
    for (var i = t; i < count; i += SUM_THREADS) {
        s += near[i];
    }
    partial[t] = s;
    workgroupBarrier();
    for (var stride = SUM_THREADS / 2u; stride > 0u; stride = stride / 2u) {
        if (t < stride) {
            partial[t] += partial[t + stride];
        }
        workgroupBarrier();
    }
    if (t == 0u) {
        sums[0] = partial[0];
    }
}

@compute @workgroup_size(8, 8)
fn compose(@builtin(global_invocation_id) gid: vec3<u32>) {
    let size = params.kernel_size;
    if (gid.x >= size || gid.y >= size) {
        return;
    }
    let s = sums[0].xyz;
    let alpha = select(vec3<f32>(0.0), vec3<f32>(params.budget) / s, s > vec3<f32>(0.0));
    let idx = gid.y * size + gid.x;
    kernel[idx] = vec4<f32>(alpha * near[idx].xyz + vec3<f32>(cie[idx]), 0.0);
}
