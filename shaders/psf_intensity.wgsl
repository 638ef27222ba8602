// Monochromatic PSF of the glare model (001 eq 8) from the transformed
// pupil-plane field:
//   M = |FFT(L) / N|² / (λ d)²       (λ, d in mm; FFT unnormalised)
// with an fftshift, so that DC lands at (N/2, N/2): output sample (si, sj)
// reads FFT sample ((si + N/2) mod N, (sj + N/2) mod N). `scale` is
// 1 / N² / (λ d)², computed in f64 on the CPU.

struct IntensityParams {
    // Grid size N (samples per side).
    n: u32,
    // 1 / N² / (λ d)².
    scale: f32,
    _pad0: u32,
    _pad1: u32,
}

@group(0) @binding(0) var<uniform> params: IntensityParams;
@group(0) @binding(1) var<storage, read> spectrum: array<vec2<f32>>;
@group(0) @binding(2) var<storage, read_write> intensity: array<f32>;

@compute @workgroup_size(8, 8, 1)
fn intensity_shift(@builtin(global_invocation_id) gid: vec3<u32>) {
    let n = params.n;
    if gid.x >= n || gid.y >= n {
        return;
    }
    let h = n / 2u;
    let src_x = (gid.x + h) % n;
    let src_y = (gid.y + h) % n;
    intensity[gid.y * n + gid.x] = cabs2(spectrum[src_y * n + src_x]) * params.scale;
}
