//! f64 CPU reference for the GPU kernels, in the manner of vello's
//! `vello_shaders/src/cpu/`: each function mirrors the index scheme of its
//! WGSL twin, in double precision, so a GPU result can be compared against
//! it element by element.
//!
//! The FFT here is the same Stockham autosort algorithm as `shaders/fft.wgsl`
//! (radix-4 stages, then one radix-2 stage when log2 N is odd; see
//! [`radix_plan`]), plus a naive O(N²) DFT as an independent definition.
//! Conventions, shared with the GPU: forward X_k = Σ_n x_n·e^(−2πi·kn/N),
//! unnormalised; inverse x_n = (1/N)·Σ_k X_k·e^(+2πi·kn/N), so that
//! inverse(forward(x)) = x. In 2D the forward transform is unnormalised and
//! the inverse carries 1/(W·H).

use crate::error::GpuError;

/// A complex number in f64: `[re, im]`.
pub type Complex64 = [f64; 2];

/// The radices of the Stockham stages for length `n` (a power of two):
/// radix 4 while possible, then one radix 2 when log2 n is odd. Empty for 1.
pub fn radix_plan(n: u32) -> Vec<u32> {
    let log2 = n.trailing_zeros();
    let mut plan = vec![4; (log2 / 2) as usize];
    if log2 % 2 == 1 {
        plan.push(2);
    }
    plan
}

/// Longest transform per axis supported by the GPU plan.
pub const MAX_FFT_LEN: u32 = 2048;

/// A transform length the GPU plan does not support.
#[derive(Clone, Copy, Debug, PartialEq, Eq, thiserror::Error)]
#[error("length {0} is not a power of two in 1..={MAX_FFT_LEN}")]
pub struct FftLenError(pub usize);

/// Checks that `n` is a power of two in 1..=[`MAX_FFT_LEN`].
pub fn check_len(n: usize) -> Result<(), FftLenError> {
    if n == 0 || !n.is_power_of_two() || n > MAX_FFT_LEN as usize {
        return Err(FftLenError(n));
    }
    Ok(())
}

fn cmul(a: Complex64, b: Complex64) -> Complex64 {
    [a[0] * b[0] - a[1] * b[1], a[0] * b[1] + a[1] * b[0]]
}

fn add(a: Complex64, b: Complex64) -> Complex64 {
    [a[0] + b[0], a[1] + b[1]]
}

fn sub(a: Complex64, b: Complex64) -> Complex64 {
    [a[0] - b[0], a[1] - b[1]]
}

/// a·(−i) for the forward transform, a·(+i) for the inverse.
fn mul_i(a: Complex64, inverse: bool) -> Complex64 {
    if inverse {
        [-a[1], a[0]]
    } else {
        [a[1], -a[0]]
    }
}

/// e^(sign·2πi·num/den) with sign −1 forward, +1 inverse.
fn root(num: usize, den: usize, inverse: bool) -> Complex64 {
    let angle = 2.0 * std::f64::consts::PI * num as f64 / den as f64;
    let sign = if inverse { 1.0 } else { -1.0 };
    [angle.cos(), sign * angle.sin()]
}

/// 1D Stockham FFT of `data` in place (the same stages as `fft.wgsl`);
/// `scratch` must have the same length. Lengths: powers of two up to 2048.
pub fn stockham_fft(
    data: &mut [Complex64],
    scratch: &mut [Complex64],
    inverse: bool,
) -> Result<(), GpuError> {
    let n = data.len();
    check_len(n).map_err(|reason| GpuError::FftSize {
        width: n as u32,
        height: 1,
        channels: 1,
        reason: reason.to_string(),
    })?;
    if scratch.len() != n {
        return Err(GpuError::Length {
            what: "stockham_fft scratch",
            expected: n,
            got: scratch.len(),
        });
    }
    let mut src: &mut [Complex64] = data;
    let mut dst: &mut [Complex64] = scratch;
    let mut ns = 1usize;
    let mut in_scratch = false;
    for radix in radix_plan(n as u32) {
        let radix = radix as usize;
        let butterflies = n / radix;
        for j in 0..butterflies {
            let k = j % ns;
            let out = (j - k) * radix + k;
            if radix == 4 {
                let v0 = src[j];
                let v1 = cmul(src[j + butterflies], root(k, ns * 4, inverse));
                let v2 = cmul(src[j + 2 * butterflies], root(2 * k, ns * 4, inverse));
                let v3 = cmul(src[j + 3 * butterflies], root(3 * k, ns * 4, inverse));
                let a0 = add(v0, v2);
                let a1 = sub(v0, v2);
                let a2 = add(v1, v3);
                let a3 = mul_i(sub(v1, v3), inverse);
                dst[out] = add(a0, a2);
                dst[out + ns] = add(a1, a3);
                dst[out + 2 * ns] = sub(a0, a2);
                dst[out + 3 * ns] = sub(a1, a3);
            } else {
                let v0 = src[j];
                let v1 = cmul(src[j + butterflies], root(k, ns * 2, inverse));
                dst[out] = add(v0, v1);
                dst[out + ns] = sub(v0, v1);
            }
        }
        std::mem::swap(&mut src, &mut dst);
        in_scratch = !in_scratch;
        ns *= radix;
    }
    // `src` now holds the result; it is `scratch` after an odd stage count.
    if in_scratch {
        dst.copy_from_slice(src);
        src = dst;
    }
    if inverse {
        let scale = 1.0 / n as f64;
        for v in src.iter_mut() {
            v[0] *= scale;
            v[1] *= scale;
        }
    }
    Ok(())
}

/// Naive O(N²) DFT with the same conventions (the definition itself).
pub fn dft_naive(input: &[Complex64], inverse: bool) -> Vec<Complex64> {
    let n = input.len();
    let roots: Vec<Complex64> = (0..n).map(|m| root(m, n, inverse)).collect();
    let scale = if inverse { 1.0 / n as f64 } else { 1.0 };
    (0..n)
        .map(|k| {
            let mut acc = [0.0, 0.0];
            for (j, x) in input.iter().enumerate() {
                acc = add(acc, cmul(*x, roots[(j * k) % n]));
            }
            [acc[0] * scale, acc[1] * scale]
        })
        .collect()
}

/// 2D FFT of `channels` planes of `width`×`height` (row-major, planes one
/// after another), rows first then columns, with [`stockham_fft`].
pub fn fft2d(
    data: &mut [Complex64],
    width: usize,
    height: usize,
    channels: usize,
    inverse: bool,
) -> Result<(), GpuError> {
    let size_error = |reason: FftLenError| GpuError::FftSize {
        width: width as u32,
        height: height as u32,
        channels: channels as u32,
        reason: reason.to_string(),
    };
    check_len(width).map_err(size_error)?;
    check_len(height).map_err(size_error)?;
    if data.len() != width * height * channels {
        return Err(GpuError::Length {
            what: "fft2d data",
            expected: width * height * channels,
            got: data.len(),
        });
    }
    let mut line = vec![[0.0; 2]; width.max(height)];
    let mut scratch = vec![[0.0; 2]; width.max(height)];
    for plane in data.chunks_exact_mut(width * height) {
        for row in plane.chunks_exact_mut(width) {
            stockham_fft(row, &mut scratch[..width], inverse)?;
        }
        for x in 0..width {
            for y in 0..height {
                line[y] = plane[y * width + x];
            }
            stockham_fft(&mut line[..height], &mut scratch[..height], inverse)?;
            for y in 0..height {
                plane[y * width + x] = line[y];
            }
        }
    }
    Ok(())
}

/// Relative L2 error ‖a − b‖₂ / ‖b‖₂ of `a` against the reference `b`.
pub fn relative_l2_error(a: &[Complex64], reference: &[Complex64]) -> f64 {
    let mut diff = 0.0;
    let mut norm = 0.0;
    for (x, r) in a.iter().zip(reference) {
        diff += (x[0] - r[0]).powi(2) + (x[1] - r[1]).powi(2);
        norm += r[0] * r[0] + r[1] * r[1];
    }
    (diff / norm).sqrt()
}

#[cfg(test)]
mod tests {
    use super::*;
    use rustfft::FftPlanner;
    use rustfft::num_complex::Complex;

    /// Deterministic pseudo-random complex samples in [−1, 1) (splitmix64).
    pub(crate) fn signal(len: usize, seed: u64) -> Vec<Complex64> {
        let mut state = seed;
        let mut next = || {
            state = state.wrapping_add(0x9E37_79B9_7F4A_7C15);
            let mut z = state;
            z = (z ^ (z >> 30)).wrapping_mul(0xBF58_476D_1CE4_E5B9);
            z = (z ^ (z >> 27)).wrapping_mul(0x94D0_49BB_1331_11EB);
            z ^= z >> 31;
            (z >> 11) as f64 / (1u64 << 53) as f64 * 2.0 - 1.0
        };
        (0..len).map(|_| [next(), next()]).collect()
    }

    #[test]
    fn radix_plans() {
        assert!(radix_plan(1).is_empty());
        assert_eq!(radix_plan(2), vec![2]);
        assert_eq!(radix_plan(8), vec![4, 2]);
        assert_eq!(radix_plan(1024), vec![4; 5]);
        assert_eq!(radix_plan(2048), vec![4, 4, 4, 4, 4, 2]);
    }

    #[test]
    fn stockham_matches_the_naive_dft_at_every_length() {
        for log2 in 0..=11 {
            let n = 1usize << log2;
            let x = signal(n, log2 as u64);
            for inverse in [false, true] {
                let mut y = x.clone();
                let mut scratch = vec![[0.0; 2]; n];
                stockham_fft(&mut y, &mut scratch, inverse).unwrap();
                let reference = dft_naive(&x, inverse);
                let err = relative_l2_error(&y, &reference);
                assert!(err < 1e-12, "n={n} inverse={inverse}: {err:e}");
            }
        }
    }

    #[test]
    fn fft2d_matches_rustfft_and_round_trips() {
        for (w, h, c) in [(8, 8, 3), (64, 16, 2), (32, 128, 1)] {
            let x = signal(w * h * c, (w * h) as u64);
            let mut y = x.clone();
            fft2d(&mut y, w, h, c, false).unwrap();
            // rustfft: rows, then columns through a transpose.
            let mut planner = FftPlanner::<f64>::new();
            let mut reference: Vec<Complex<f64>> =
                x.iter().map(|v| Complex::new(v[0], v[1])).collect();
            let row_fft = planner.plan_fft_forward(w);
            let col_fft = planner.plan_fft_forward(h);
            for plane in reference.chunks_exact_mut(w * h) {
                row_fft.process(plane);
                let mut column = vec![Complex::new(0.0, 0.0); h];
                for xi in 0..w {
                    for yi in 0..h {
                        column[yi] = plane[yi * w + xi];
                    }
                    col_fft.process(&mut column);
                    for yi in 0..h {
                        plane[yi * w + xi] = column[yi];
                    }
                }
            }
            let reference: Vec<Complex64> = reference.iter().map(|v| [v.re, v.im]).collect();
            let err = relative_l2_error(&y, &reference);
            assert!(err < 1e-13, "{w}x{h}x{c}: {err:e}");
            fft2d(&mut y, w, h, c, true).unwrap();
            let err = relative_l2_error(&y, &x);
            assert!(err < 1e-13, "round trip {w}x{h}x{c}: {err:e}");
        }
    }

    #[test]
    fn bad_lengths_are_errors() {
        let mut data = vec![[0.0; 2]; 12];
        let mut scratch = vec![[0.0; 2]; 12];
        assert!(matches!(
            stockham_fft(&mut data, &mut scratch, false),
            Err(GpuError::FftSize { width: 12, .. })
        ));
        let mut data = vec![[0.0; 2]; 4096];
        let mut scratch = vec![[0.0; 2]; 4096];
        assert!(stockham_fft(&mut data, &mut scratch, false).is_err());
        let mut data = vec![[0.0; 2]; 8];
        let mut scratch = vec![[0.0; 2]; 4];
        assert!(matches!(
            stockham_fft(&mut data, &mut scratch, false),
            Err(GpuError::Length { .. })
        ));
        let mut data = vec![[0.0; 2]; 63];
        assert!(fft2d(&mut data, 8, 8, 1, false).is_err());
    }
}
