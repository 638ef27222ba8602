// Pupil-plane field of the glare PSF (001 eq 7): L = P·F·A on the N×N grid.
//
// P (the static particle transmission) and F (the Fresnel term times the
// eye's refraction: the residual defocus phasor) do not depend on the pupil,
// so their product P·F is computed once on the CPU in f64 (the same particle
// field as gazelight_vision::psf) and uploaded as `static_field`. This pass
// multiplies it by the aperture A of the live pupil: a disc of radius
// `radius_samples` with a one-sample anti-aliased edge,
//   A = clamp(radius − |x| + 0.5, 0, 1),   0 beyond radius + 1,
// exactly as the CPU reference, and writes L into the FFT's data buffer.
// Sample (i, j) sits at ((i − N/2)·Δx, (j − N/2)·Δx).

struct ApertureParams {
    // Grid size N (samples per side).
    n: u32,
    // Pupil radius in pupil-plane samples: pupil_mm / 2 / Δx.
    radius_samples: f32,
    _pad0: u32,
    _pad1: u32,
}

@group(0) @binding(0) var<uniform> params: ApertureParams;
@group(0) @binding(1) var<storage, read> static_field: array<vec2<f32>>;
@group(0) @binding(2) var<storage, read_write> field: array<vec2<f32>>;

@compute @workgroup_size(8, 8, 1)
fn build_field(@builtin(global_invocation_id) gid: vec3<u32>) {
    let n = params.n;
    if gid.x >= n || gid.y >= n {
        return;
    }
    let index = gid.y * n + gid.x;
    let half = f32(n / 2u);
    let x = f32(gid.x) - half;
    let y = f32(gid.y) - half;
    // Exact in f32: |x|, |y| ≤ 1024.
    let r2 = x * x + y * y;
    let edge = params.radius_samples + 1.0;
    if r2 > edge * edge {
        field[index] = vec2<f32>(0.0, 0.0);
        return;
    }
    // 001 eq 7: anti-aliased aperture A
    let a = clamp(params.radius_samples - sqrt(r2) + 0.5, 0.0, 1.0);
    field[index] = static_field[index] * a;
}
