// Glare kernel build, pass 3: the spectral sum onto display pixels (001
// eq 9–10) inside the wave-optics region, the particle lobes beyond it. The
// twin of the `near` loop of gazelight_vision::psf::PsfBuilder::build.
//
// `near_field`: one workgroup per display pixel of the (2 r_near + 1)²
// square, pixels within r_near of the centre. For each wavelength φ the
// pixel's footprint in the 575 nm field is `to_m = px_in_samples · 575/φ`
// samples wide (the Fraunhofer rescaling with its Jacobian (λ/φ)²: the
// integral over the footprint); M is piecewise constant per FFT sample, so
// the integral is the overlap-weighted sum of the samples the footprint
// covers (the CPU reads the same integral from a summed-area table). Each
// thread takes every 64th (wavelength, sample row) pair; the partial
// linear-sRGB sums (the per-wavelength weights are XYZ → sRGB times the
// colour matching functions / (k + 1)) are reduced in workgroup memory and
// clamped at 0, as the CPU clamps XYZ → sRGB.
//
// `lobes`: every kernel pixel beyond r_near: σ_p Ω_px times the unit-power
// particle lobe, linearly interpolated in the radial table; 0 without lobes.

@group(0) @binding(0) var<uniform> params: PsfBuild;
@group(0) @binding(1) var<storage, read> mono: array<f32>;
// Per wavelength: (to_m, linear sRGB weights).
@group(0) @binding(2) var<storage, read> wavelengths: array<vec4<f32>>;
@group(0) @binding(3) var<storage, read> lobe_table: array<vec4<f32>>;
@group(0) @binding(4) var<storage, read_write> near: array<vec4<f32>>;

const NEAR_THREADS: u32 = 64u;

var<workgroup> partial: array<vec4<f32>, 64>;

@compute @workgroup_size(64)
fn near_field(
    @builtin(workgroup_id) wg: vec3<u32>,
    @builtin(local_invocation_index) t: u32,
) {
    let nr = i32(params.near_radius_px);
    let px = i32(wg.x) - nr;
    let py = i32(wg.y) - nr;
    let inside = px * px + py * py <= nr * nr;
    let h = i32(params.n / 2u);
    let half = params.half;
    var acc = vec3<f32>(0.0);
    var offset = 0u;
    for (var l = 0u; l < params.wavelength_count; l++) {
        if (!inside) {
            break;
        }
        let w = wavelengths[l];
        let tm = w.x;
        // The footprint relative to the centre sample's corner (sample s
        // covers [s − N/2, s − N/2 + 1)), clamped to the FFT field.
        let x0 = clamp((f32(px) - 0.5) * tm + 0.5, -half, half);
        let x1 = clamp((f32(px) + 0.5) * tm + 0.5, -half, half);
        let y0 = clamp((f32(py) - 0.5) * tm + 0.5, -half, half);
        let y1 = clamp((f32(py) + 0.5) * tm + 0.5, -half, half);
        let i0 = i32(floor(x0));
        let i1 = i32(ceil(x1));
        let j0 = i32(floor(y0));
        let rows = u32(max(i32(ceil(y1)) - j0, 0));
        // This thread's rows: pair index (offset + k) ≡ t (mod 64).
        var e = 0.0;
        for (var k = (t + NEAR_THREADS - offset % NEAR_THREADS) % NEAR_THREADS; k < rows; k += NEAR_THREADS) {
            let j = j0 + i32(k);
            let wy = min(y1, f32(j + 1)) - max(y0, f32(j));
            let base = u32(j + h) * params.n;
            var s = 0.0;
            for (var i = i0; i < i1; i++) {
                let wx = min(x1, f32(i + 1)) - max(x0, f32(i));
                s += wx * mono[base + u32(i + h)];
            }
            e += wy * s;
        }
        acc += w.yzw * e;
        offset += rows;
    }
    partial[t] = vec4<f32>(acc, 0.0);
    workgroupBarrier();
    for (var stride = NEAR_THREADS / 2u; stride > 0u; stride = stride / 2u) {
        if (t < stride) {
            partial[t] += partial[t + stride];
        }
        workgroupBarrier();
    }
    if (t == 0u && inside) {
        let r = i32(params.kernel_radius);
        let idx = u32(r + py) * params.kernel_size + u32(r + px);
        near[idx] = vec4<f32>(max(partial[0].xyz, vec3<f32>(0.0)), 0.0);
    }
}

@compute @workgroup_size(8, 8)
fn lobes(@builtin(global_invocation_id) gid: vec3<u32>) {
    let size = params.kernel_size;
    if (gid.x >= size || gid.y >= size) {
        return;
    }
    let r = i32(params.kernel_radius);
    let x = i32(gid.x) - r;
    let y = i32(gid.y) - r;
    let nr = i32(params.near_radius_px);
    let d2 = x * x + y * y;
    if (d2 <= nr * nr) {
        return;
    }
    var out = vec3<f32>(0.0);
    if (params.lobe_scale > 0.0) {
        let t = sqrt(f32(d2)) * params.lobe_per_px;
        let i = min(u32(floor(t)), params.lobe_count - 2u);
        let f = t - f32(i);
        out = (lobe_table[i].xyz * (1.0 - f) + lobe_table[i + 1u].xyz * f) * params.lobe_scale;
    }
    near[gid.y * size + gid.x] = vec4<f32>(out, 0.0);
}
