// The spectral glare kernel at display resolution (001 eq 9–10), in three
// entry points over one bind group:
//
// 1. `sat_rows`, 2. `sat_columns`: the summed-area table (SAT) of the
//    monochromatic PSF M (psf_intensity.wgsl), prefix sums by rows, then by
//    columns, sat[j][i] = Σ M[y < j][x < i], (N+1)² entries with a zero
//    first row and column.
// 3. `spectral_sum`: for every display pixel and wavelength φ_i the integral
//    of M over the pixel's footprint rescaled by λ/φ_i (Fraunhofer scaling,
//    with the (λ/φ_i)² Jacobian, as gazelight_vision::psf), read from the SAT,
//    weighted by the colour matching functions, summed to XYZ, converted to
//    linear sRGB with negatives clamped to 0. Normalisation is
//    psf_normalize.wgsl.
//
// Precision. A SAT holds running totals up to Σ M while a display pixel far
// from the centre holds ~1e-6 of it: in f32 (24-bit mantissa) the corner
// differences would cancel to noise. The SAT is therefore exact integer
// arithmetic: M is quantised to fixed point, q = round(M / unit) with
// `unit` = (an upper bound of max M) / 2³¹, so every sample is a u32 and its
// error at most 2⁻³² of the peak; the sums are 64-bit integers (vec2<u32>,
// lo/hi with carry: core WGSL has no 64-bit types), exact whatever the order
// of summation, so the parallel workgroup scans and compiler
// reassociation cannot change them. The pixel integral is taken from exact
// integer block sums of the SAT (below), each converted to f32 only after
// the subtraction. The common scale `unit` cancels in the per-channel
// normalisation, so the XYZ values here are in units of `unit`.
//
// Pixel integral. The CPU reference reads the SAT bilinearly at the
// footprint's corners, which is the exact integral of the piecewise-constant
// M. Along one axis the footprint [y0, y1] is given by (lo, flo), (hi, fhi):
// y0 = lo + flo, y1 = hi + fhi (clamped to 0..=N, lo, hi ≤ N−1, computed in
// f64 on the CPU once). The rows of the footprint split into three
// segments with weights
//   [lo, lo+1) × (1 − flo),   [lo+1, hi) × 1,   [hi, hi+1) × fhi
// (the middle one has height −1 when lo = hi, which makes the total weight
// fhi − flo of that single row). The integral is Σ over the 3 × 3 products
// of row and column segments of weight × (exact integer sum of M over the
// block), i.e. the CPU's F(y1,x1) − F(y0,x1) − F(y1,x0) + F(y0,x0) without
// the cancellation.

struct SpectralParams {
    // Grid size N of M.
    n: u32,
    // Kernel size in display pixels.
    size: u32,
    // Number of wavelengths k + 1.
    count: u32,
    // 1 / unit: the fixed-point scale of the SAT (M per integer step).
    inv_unit: f32,
    // XYZ → linear sRGB matrix, one row per vec4 (w unused).
    rgb_from_xyz: array<vec4<f32>, 3>,
}

// Footprint of one display pixel along one axis at one wavelength.
struct Edge {
    lo: u32,
    lo_frac: f32,
    hi: u32,
    hi_frac: f32,
}

@group(0) @binding(0) var<uniform> params: SpectralParams;
@group(0) @binding(1) var<storage, read> intensity: array<f32>;
// (N+1)² signed 64-bit integers, (lo, hi) words.
@group(0) @binding(2) var<storage, read_write> sat: array<vec2<u32>>;
// count × size footprints: entry i·size + v for wavelength i, pixel index v.
@group(0) @binding(3) var<storage, read> edges: array<Edge>;
// count colour-matching triples x̄ ȳ z̄ (φ_i) / (k + 1) (001 eq 9).
@group(0) @binding(4) var<storage, read> cmf: array<vec4<f32>>;
// size² linear sRGB values (w unused), before normalisation.
@group(0) @binding(5) var<storage, read_write> rgb: array<vec4<f32>>;

const SCAN_THREADS: u32 = 256u;
var<workgroup> scan: array<vec2<u32>, 256>;

fn add64(a: vec2<u32>, b: vec2<u32>) -> vec2<u32> {
    let lo = a.x + b.x;
    return vec2<u32>(lo, a.y + b.y + select(0u, 1u, lo < a.x));
}

fn sub64(a: vec2<u32>, b: vec2<u32>) -> vec2<u32> {
    return vec2<u32>(a.x - b.x, a.y - b.y - select(0u, 1u, a.x < b.x));
}

// Two's complement 64-bit integer to f32 (within 1 ulp).
fn i64_to_f32(v: vec2<u32>) -> f32 {
    if (v.y & 0x80000000u) != 0u {
        let m = sub64(vec2<u32>(0u, 0u), v);
        return -(f32(m.y) * 4294967296.0 + f32(m.x));
    }
    return f32(v.y) * 4294967296.0 + f32(v.x);
}

// M in fixed point (see the header); 4294967040 is the largest f32 < 2³².
fn quantise(m: f32) -> vec2<u32> {
    return vec2<u32>(u32(clamp(round(m * params.inv_unit), 0.0, 4294967040.0)), 0u);
}

// Exclusive prefix of `total` over the workgroup's threads (Hillis–Steele
// in workgroup memory; exact in integers).
fn exclusive_prefix(t: u32, total: vec2<u32>) -> vec2<u32> {
    scan[t] = total;
    workgroupBarrier();
    for (var offset = 1u; offset < SCAN_THREADS; offset = offset * 2u) {
        var v = scan[t];
        if t >= offset {
            v = add64(v, scan[t - offset]);
        }
        workgroupBarrier();
        scan[t] = v;
        workgroupBarrier();
    }
    return sub64(scan[t], total);
}

// One workgroup per row j of M: sat[j+1][i+1] = Σ_{x ≤ i} q(M[j][x]).
@compute @workgroup_size(256, 1, 1)
fn sat_rows(
    @builtin(workgroup_id) wid: vec3<u32>,
    @builtin(local_invocation_index) t: u32,
) {
    let n = params.n;
    let w = n + 1u;
    let row = wid.x;
    let chunk = (n + SCAN_THREADS - 1u) / SCAN_THREADS;
    let start = min(t * chunk, n);
    let end = min(start + chunk, n);
    var total = vec2<u32>(0u, 0u);
    for (var i = start; i < end; i++) {
        total = add64(total, quantise(intensity[row * n + i]));
    }
    var running = exclusive_prefix(t, total);
    for (var i = start; i < end; i++) {
        running = add64(running, quantise(intensity[row * n + i]));
        sat[(row + 1u) * w + i + 1u] = running;
    }
}

// One workgroup per column i+1 of the SAT, in place over rows 1..=N.
@compute @workgroup_size(256, 1, 1)
fn sat_columns(
    @builtin(workgroup_id) wid: vec3<u32>,
    @builtin(local_invocation_index) t: u32,
) {
    let n = params.n;
    let w = n + 1u;
    let column = wid.x + 1u;
    let chunk = (n + SCAN_THREADS - 1u) / SCAN_THREADS;
    let start = min(t * chunk, n);
    let end = min(start + chunk, n);
    var total = vec2<u32>(0u, 0u);
    for (var k = start; k < end; k++) {
        total = add64(total, sat[(k + 1u) * w + column]);
    }
    var running = exclusive_prefix(t, total);
    for (var k = start; k < end; k++) {
        let index = (k + 1u) * w + column;
        running = add64(running, sat[index]);
        sat[index] = running;
    }
}

// The 4 SAT line indices and 3 segment weights of a footprint.
fn segment_lines(e: Edge) -> vec4<u32> {
    return vec4<u32>(e.lo, e.lo + 1u, e.hi, e.hi + 1u);
}

fn segment_weights(e: Edge) -> vec3<f32> {
    return vec3<f32>(1.0 - e.lo_frac, 1.0, e.hi_frac);
}

@compute @workgroup_size(8, 8, 1)
fn spectral_sum(@builtin(global_invocation_id) gid: vec3<u32>) {
    let size = params.size;
    if gid.x >= size || gid.y >= size {
        return;
    }
    let w = params.n + 1u;
    var xyz = vec3<f32>(0.0, 0.0, 0.0);
    for (var i = 0u; i < params.count; i++) {
        let ey = edges[i * size + gid.y];
        let ex = edges[i * size + gid.x];
        let rows = segment_lines(ey);
        let cols = segment_lines(ex);
        let wy = segment_weights(ey);
        let wx = segment_weights(ex);
        // d[p][l]: exact sum of rows [rows[p], rows[p+1]) left of cols[l].
        var d: array<array<vec2<u32>, 4>, 3>;
        for (var l = 0u; l < 4u; l++) {
            let s0 = sat[rows[0] * w + cols[l]];
            let s1 = sat[rows[1] * w + cols[l]];
            let s2 = sat[rows[2] * w + cols[l]];
            let s3 = sat[rows[3] * w + cols[l]];
            d[0][l] = sub64(s1, s0);
            d[1][l] = sub64(s2, s1);
            d[2][l] = sub64(s3, s2);
        }
        var energy = 0.0;
        for (var p = 0u; p < 3u; p++) {
            var row_energy = 0.0;
            for (var q = 0u; q < 3u; q++) {
                row_energy += wx[q] * i64_to_f32(sub64(d[p][q + 1u], d[p][q]));
            }
            energy += wy[p] * row_energy;
        }
        // 001 eq 9: S_XYZ = 1/(k+1) Σ xyz(φ_i) M_i
        xyz += cmf[i].xyz * energy;
    }
    let m = params.rgb_from_xyz;
    let linear = max(
        vec3<f32>(dot(m[0].xyz, xyz), dot(m[1].xyz, xyz), dot(m[2].xyz, xyz)),
        vec3<f32>(0.0, 0.0, 0.0),
    );
    rgb[gid.y * size + gid.x] = vec4<f32>(linear, 0.0);
}
