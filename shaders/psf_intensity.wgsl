// Glare kernel build, pass 2 (after the forward FFT): the monochromatic PSF
// at 575 nm, M = |FFT(L)/N|² / (λd)² (001 eq 8), fftshifted so the DC
// sample lands at (N/2, N/2), and scaled by (λd)² / (π r²) to the fraction
// of the light entering the pupil per FFT sample (Parseval: the samples of
// a clear pupil sum to 1). The twin of the |·|² step of
// gazelight_vision::psf::MonoEngine::compute and PsfBuilder's `to_fraction`.

@group(0) @binding(0) var<uniform> params: PsfBuild;
@group(0) @binding(1) var<storage, read> field: array<vec2<f32>>;
@group(0) @binding(2) var<storage, read_write> mono: array<f32>;

@compute @workgroup_size(8, 8)
fn intensity(@builtin(global_invocation_id) gid: vec3<u32>) {
    let n = params.n;
    if (gid.x >= n || gid.y >= n) {
        return;
    }
    let h = n / 2u;
    let v = field[((gid.y + h) % n) * n + (gid.x + h) % n];
    mono[gid.y * n + gid.x] = dot(v, v) * params.intensity_scale;
}
