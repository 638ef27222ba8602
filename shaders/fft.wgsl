// One Stockham autosort FFT stage (radix 4, or radix 2 for the final stage of
// an axis whose length is 2·4^k) along one axis of a batch of 2D planes of
// complex f32 values (vec2<f32>), read from `src`, written to `dst`.
//
// Stockham stage with sub-transform length Ns (product of the radices of the
// stages already done) and radix R over a line of length N; butterfly j of
// the N/R in a line, k = j mod Ns:
//   v_r  = src[j + r·N/R] · w^(r·k),  w = exp(∓2πi / (Ns·R))   (r = 0..R-1)
//   V    = R-point DFT of v
//   dst[(j − k)·R + k + r·Ns] = scale · V_r
// Forward uses exp(−2πi·…), inverse exp(+2πi·…). The twiddles come from a
// table exp(−2πi·m / N_max) computed in f64 on the CPU (conjugated for the
// inverse), so their accuracy does not depend on the device's sin/cos.
//
// Addressing of line `l` (one 1D transform): plane = l / lines_per_plane,
// base = plane·plane_size + (l mod lines_per_plane)·line_step, element i at
// base + i·elem_stride. Rows: lines_per_plane = height, line_step = width,
// elem_stride = 1. Columns: lines_per_plane = width, line_step = 1,
// elem_stride = width.

struct FftParams {
    // Transform length along this axis (N).
    n: u32,
    // Sub-transform length already done (Ns).
    ns: u32,
    // Radix of this stage: 4 or 2.
    radix: u32,
    // Distance between consecutive elements of a line.
    elem_stride: u32,
    // Lines in one plane (one channel).
    lines_per_plane: u32,
    // Distance between the first elements of consecutive lines in a plane.
    line_step: u32,
    // Elements in one plane (width·height).
    plane_size: u32,
    // Butterflies in the whole dispatch: lines·N/R.
    total_threads: u32,
    // Twiddle table step: N_max / (Ns·R).
    twiddle_step: u32,
    // 0 forward, 1 inverse.
    inverse: u32,
    // Factor applied to every output (1, or 1/N on the last inverse stage).
    scale: f32,
    _pad: u32,
}

@group(0) @binding(0) var<uniform> params: FftParams;
@group(0) @binding(1) var<storage, read> src: array<vec2<f32>>;
@group(0) @binding(2) var<storage, read_write> dst: array<vec2<f32>>;
@group(0) @binding(3) var<storage, read> twiddles: array<vec2<f32>>;

const FFT_WORKGROUP_SIZE: u32 = 64u;

fn twiddle(index: u32) -> vec2<f32> {
    let w = twiddles[index];
    return select(w, cconj(w), params.inverse != 0u);
}

@compute @workgroup_size(64, 1, 1)
fn fft_stage(
    @builtin(global_invocation_id) gid: vec3<u32>,
    @builtin(num_workgroups) groups: vec3<u32>,
) {
    let t = gid.x + gid.y * groups.x * FFT_WORKGROUP_SIZE;
    if t >= params.total_threads {
        return;
    }
    let butterflies = params.n / params.radix;
    let line = t / butterflies;
    let j = t - line * butterflies;
    let plane = line / params.lines_per_plane;
    let base = plane * params.plane_size + (line - plane * params.lines_per_plane) * params.line_step;
    let stride = params.elem_stride;
    let k = j % params.ns;
    let out_j = (j - k) * params.radix + k;
    let tw = k * params.twiddle_step;
    let inverse = params.inverse != 0u;

    if params.radix == 4u {
        let v0 = src[base + j * stride];
        let v1 = cmul(src[base + (j + butterflies) * stride], twiddle(tw));
        let v2 = cmul(src[base + (j + 2u * butterflies) * stride], twiddle(2u * tw));
        let v3 = cmul(src[base + (j + 3u * butterflies) * stride], twiddle(3u * tw));
        let a0 = v0 + v2;
        let a1 = v0 - v2;
        let a2 = v1 + v3;
        let a3 = cmul_i(v1 - v3, inverse);
        dst[base + out_j * stride] = (a0 + a2) * params.scale;
        dst[base + (out_j + params.ns) * stride] = (a1 + a3) * params.scale;
        dst[base + (out_j + 2u * params.ns) * stride] = (a0 - a2) * params.scale;
        dst[base + (out_j + 3u * params.ns) * stride] = (a1 - a3) * params.scale;
    } else {
        let v0 = src[base + j * stride];
        let v1 = cmul(src[base + (j + butterflies) * stride], twiddle(tw));
        dst[base + out_j * stride] = (v0 + v1) * params.scale;
        dst[base + (out_j + params.ns) * stride] = (v0 - v1) * params.scale;
    }
}
