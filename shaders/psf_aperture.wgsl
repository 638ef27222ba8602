// Glare kernel build, pass 1: the pupil-plane field L = P · F · A of 001
// eq 7 on the N × N grid (sample (i, j) at ((i − N/2) Δx, (j − N/2) Δx)),
// written as complex f32 into the forward FFT's data buffer. The twin of the
// field fill in gazelight_vision::psf::MonoEngine::compute: P the static
// particle transmission (uploaded once), A the exact fraction of each
// sample's cell inside the pupil disc (analytic circle–square overlap, the
// twin of gazelight_vision::psf::pupil_cell_coverage), F the residual
// defocus phase exp(i π r² ΔD / λ).

@group(0) @binding(0) var<uniform> params: PsfBuild;
@group(0) @binding(1) var<storage, read> particles: array<f32>;
@group(0) @binding(2) var<storage, read_write> field: array<vec2<f32>>;

// θ − sin θ, by its Taylor series below 0.5 rad (no cancellation).
fn theta_minus_sin(t: f32) -> f32 {
    if (t < 0.5) {
        let t2 = t * t;
        return t * t2 / 6.0 * (1.0 - t2 / 20.0 * (1.0 - t2 / 42.0 * (1.0 - t2 / 72.0)));
    }
    return t - sin(t);
}

// Area of the disc of radius r inside [x0, x1] × [y0, y1] (all ≥ 0):
// ∫ clamp(√(r² − v²) − x0, 0, x1 − x0) dv over [y0, y1] in closed form,
// trapezoid under the chord plus the circular segment r²/2 (θ − sin θ);
// every term local to the rectangle, so f32 holds it to about r · 2⁻²⁴.
fn disc_rect_area(x0: f32, x1: f32, y0: f32, y1: f32, r: f32) -> f32 {
    let v1 = sqrt(max((r - x1) * (r + x1), 0.0));
    let v0 = sqrt(max((r - x0) * (r + x0), 0.0));
    let a = clamp(v1, y0, y1);
    let b = clamp(v0, y0, y1);
    let full = (a - y0) * (x1 - x0);
    if (b <= a) {
        return full;
    }
    let ha = sqrt(max((r - a) * (r + a), 0.0));
    let hb = sqrt(max((r - b) * (r + b), 0.0));
    let trapezoid = (b - a) * ((ha - x0) + (hb - x0)) * 0.5;
    let chord = length(vec2<f32>(b - a, ha - hb));
    let theta = 2.0 * asin(min(chord / (2.0 * r), 1.0));
    return full + trapezoid + 0.5 * r * r * theta_minus_sin(theta);
}

// The interval [c − ½, c + ½] (c ≥ 0) folded about 0: (lo, hi) of its
// piece at or beyond 0 and of its mirrored part below 0 (empty unless c < ½).
fn folded_half_unit(c: f32) -> vec4<f32> {
    if (c >= 0.5) {
        return vec4<f32>(c - 0.5, c + 0.5, 0.0, 0.0);
    }
    return vec4<f32>(0.0, c + 0.5, 0.0, 0.5 - c);
}

// 001 eq 7, the aperture A: the exact fraction of the unit cell centred at
// (x, y) samples inside the disc of radius r, the cell folded into the
// octant |x| ≥ |y| ≥ 0 where the arc is no steeper than 45°.
fn pupil_cell_coverage(x: f32, y: f32, r: f32) -> f32 {
    let ax = max(abs(x), abs(y));
    let ay = min(abs(x), abs(y));
    let nx = max(ax - 0.5, 0.0);
    let ny = max(ay - 0.5, 0.0);
    if (nx * nx + ny * ny >= r * r) {
        return 0.0;
    }
    let fx = ax + 0.5;
    let fy = ay + 0.5;
    if (fx * fx + fy * fy <= r * r) {
        return 1.0;
    }
    let xs = folded_half_unit(ax);
    let ys = folded_half_unit(ay);
    var area = 0.0;
    for (var i = 0u; i < 2u; i++) {
        let x0 = select(xs.x, xs.z, i == 1u);
        let x1 = select(xs.y, xs.w, i == 1u);
        for (var j = 0u; j < 2u; j++) {
            let y0 = select(ys.x, ys.z, j == 1u);
            let y1 = select(ys.y, ys.w, j == 1u);
            if (x1 > x0 && y1 > y0) {
                area += disc_rect_area(x0, x1, y0, y1, r);
            }
        }
    }
    return clamp(area, 0.0, 1.0);
}

@compute @workgroup_size(8, 8)
fn aperture(@builtin(global_invocation_id) gid: vec3<u32>) {
    let n = params.n;
    if (gid.x >= n || gid.y >= n) {
        return;
    }
    let idx = gid.y * n + gid.x;
    let x = f32(gid.x) - params.half;
    let y = f32(gid.y) - params.half;
    // Exact in f32: |x|, |y| ≤ 1024, so r² < 2²⁴.
    let r2 = x * x + y * y;
    if (r2 > params.edge * params.edge) {
        field[idx] = vec2<f32>(0.0, 0.0);
        return;
    }
    // 001 eq 7: aperture A (the cell's area inside the pupil) times the
    // particle field P
    let a = pupil_cell_coverage(x, y, params.r_samples);
    let amp = a * particles[idx];
    if (params.defocus_rad_per_sample2 == 0.0) {
        field[idx] = vec2<f32>(amp, 0.0);
    } else {
        let phase = params.defocus_rad_per_sample2 * r2;
        field[idx] = amp * vec2<f32>(cos(phase), sin(phase));
    }
}
