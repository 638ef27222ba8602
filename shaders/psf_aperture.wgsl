// Glare kernel build, pass 1: the pupil-plane field L = P · F · A of 001
// eq 7 on the N × N grid (sample (i, j) at ((i − N/2) Δx, (j − N/2) Δx)),
// written as complex f32 into the forward FFT's data buffer. The twin of the
// field fill in gazelight_vision::psf::MonoEngine::compute: P the static
// particle transmission (uploaded once), A the pupil disc with a one-sample
// anti-aliased edge, F the residual defocus phase exp(i π r² ΔD / λ).

@group(0) @binding(0) var<uniform> params: PsfBuild;
@group(0) @binding(1) var<storage, read> particles: array<f32>;
@group(0) @binding(2) var<storage, read_write> field: array<vec2<f32>>;

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
    // 001 eq 7: anti-aliased aperture A times the particle field P
    let a = clamp(params.r_samples - sqrt(r2) + 0.5, 0.0, 1.0);
    let amp = a * particles[idx];
    if (params.defocus_rad_per_sample2 == 0.0) {
        field[idx] = vec2<f32>(amp, 0.0);
    } else {
        let phase = params.defocus_rad_per_sample2 * r2;
        field[idx] = amp * vec2<f32>(cos(phase), sin(phase));
    }
}
