// Shared WGSL helpers for the gazelight compute passes.
//
// Prepended to every pass that needs them by `gazelight_gpu::shaders`
// (compile-time concatenation of this file and the pass file).

const PI: f32 = 3.14159265358979323846;

// Complex numbers are vec2<f32>: x = real part, y = imaginary part.

// Complex product a·b.
fn cmul(a: vec2<f32>, b: vec2<f32>) -> vec2<f32> {
    return vec2<f32>(a.x * b.x - a.y * b.y, a.x * b.y + a.y * b.x);
}

// Complex conjugate of a.
fn cconj(a: vec2<f32>) -> vec2<f32> {
    return vec2<f32>(a.x, -a.y);
}

// a multiplied by -i (forward quarter turn) or +i (inverse quarter turn).
fn cmul_i(a: vec2<f32>, inverse: bool) -> vec2<f32> {
    return select(vec2<f32>(a.y, -a.x), vec2<f32>(-a.y, a.x), inverse);
}

// Squared magnitude |a|².
fn cabs2(a: vec2<f32>) -> f32 {
    return a.x * a.x + a.y * a.y;
}
