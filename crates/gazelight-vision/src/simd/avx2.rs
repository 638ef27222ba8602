//! AVX2 + FMA: the vector primitives of 8 lanes and the kernels that use
//! them.
//!
//! The primitives (`ld`, `st`, `splat`, `add` … `select`, `keep`, the
//! comparisons into masks, the 3-channel transposes of [`Shuffles`]) carry
//! the same names as in [`super::avx512`], so that the band engine's row
//! loops, which do the same maths at both widths, are written once
//! (`band::kernels`) and compiled into each width's `#[target_feature]`
//! functions. A mask here is a vector whose lanes are all ones or all
//! zeros (a comparison's result).
//!
//! The kernels of this width alone: pass A's block sums
//! ([`block_sums_row`]) and the affine encoding ([`encode_affine`]). Each
//! is the twin of a portable function and computes **the same bits**: the
//! same float operations in the same order (no fused multiply-adds),
//! selects where the portable code has branches. The portable loops are
//! written for the auto-vectoriser, but a profile showed much of them
//! scalar (the RGB deinterleave as 24 inserts, `f32::max`'s NaN handling
//! as compare + blend per lane, constants re-broadcast inside loops); here
//! the deinterleave is three 256-bit shuffles and every lane operation one
//! instruction. The tests at the end compare each kernel with its portable
//! twin bit for bit.
//!
//! Only full blocks of 8 pixels run here; a row's short tail goes through
//! the portable code. Everything is `#[target_feature(enable =
//! "avx2,fma")]` and is called only behind a [`super::Simd`] of at least
//! [`super::Tier::Avx2`].

use std::arch::x86_64::*;

use super::{LANES, map3};
use crate::encode::{Affine, SRGB_LUT_SIZE, SrgbLut};

/// Lanes of one register.
pub(crate) const W: usize = 8;

/// The vector of `W` f32 lanes.
pub(crate) type V = __m256;

/// A lane mask: a vector of all-ones or all-zeros lanes.
pub(crate) type M = __m256;

/// The vector of `W` i32 lanes.
pub(crate) type I = __m256i;

/// Eight lanes from `s[at..at + 8]` (bounds-checked).
#[inline]
#[target_feature(enable = "avx2,fma")]
pub(crate) fn ld(s: &[f32], at: usize) -> V {
    let s = &s[at..at + W];
    // SAFETY: `s` holds exactly 8 f32s (checked by the slice above); the
    // load is unaligned.
    unsafe { _mm256_loadu_ps(s.as_ptr()) }
}

/// Stores eight lanes to `d[at..at + 8]` (bounds-checked).
#[inline]
#[target_feature(enable = "avx2,fma")]
pub(crate) fn st(d: &mut [f32], at: usize, v: V) {
    let d = &mut d[at..at + W];
    // SAFETY: `d` holds exactly 8 f32s (checked by the slice above).
    unsafe { _mm256_storeu_ps(d.as_mut_ptr(), v) }
}

/// Broadcast.
#[inline]
#[target_feature(enable = "avx2,fma")]
pub(crate) fn splat(v: f32) -> V {
    _mm256_set1_ps(v)
}

/// All lanes 0.
#[inline]
#[target_feature(enable = "avx2,fma")]
pub(crate) fn zero() -> V {
    _mm256_setzero_ps()
}

/// Defines the lane-wise binary operations `$name(a, b)` as `$op`.
macro_rules! binary {
    ($($(#[$doc:meta])* $name:ident => $op:ident;)*) => {$(
        $(#[$doc])*
        #[inline]
        #[target_feature(enable = "avx2,fma")]
        pub(crate) fn $name(a: V, b: V) -> V {
            $op(a, b)
        }
    )*};
}

binary! {
    /// `a + b`.
    add => _mm256_add_ps;
    /// `a − b`.
    sub => _mm256_sub_ps;
    /// `a · b`.
    mul => _mm256_mul_ps;
    /// `a / b`.
    div => _mm256_div_ps;
    /// `minps` (`b` where either is NaN).
    min => _mm256_min_ps;
    /// `maxps` (`b` where either is NaN).
    max => _mm256_max_ps;
}

/// Defines the comparisons `$name(a, b)` into masks with predicate `$p`.
macro_rules! compare {
    ($($(#[$doc:meta])* $name:ident => $p:ident;)*) => {$(
        $(#[$doc])*
        #[inline]
        #[target_feature(enable = "avx2,fma")]
        pub(crate) fn $name(a: V, b: V) -> M {
            _mm256_cmp_ps::<$p>(a, b)
        }
    )*};
}

compare! {
    /// `a > b` (false for NaN).
    gt => _CMP_GT_OQ;
    /// `a < b` (false for NaN).
    lt => _CMP_LT_OQ;
    /// `a ≤ b` (false for NaN).
    le => _CMP_LE_OQ;
    /// `a ≠ b` (true for NaN).
    neq => _CMP_NEQ_UQ;
}

/// `if mask { a } else { b }` per lane.
#[inline]
#[target_feature(enable = "avx2,fma")]
pub(crate) fn select(mask: M, a: V, b: V) -> V {
    _mm256_blendv_ps(b, a, mask)
}

/// `if mask { v } else { 0 }` per lane.
#[inline]
#[target_feature(enable = "avx2,fma")]
pub(crate) fn keep(mask: M, v: V) -> V {
    _mm256_and_ps(mask, v)
}

/// The mask of no lane.
#[inline]
#[target_feature(enable = "avx2,fma")]
pub(crate) fn no_lanes() -> M {
    _mm256_setzero_ps()
}

/// The lanes of either mask.
#[inline]
#[target_feature(enable = "avx2,fma")]
pub(crate) fn either(a: M, b: M) -> M {
    _mm256_or_ps(a, b)
}

/// Whether the mask holds no lane.
#[inline]
#[target_feature(enable = "avx2,fma")]
pub(crate) fn none(mask: M) -> bool {
    _mm256_movemask_ps(mask) == 0
}

/// Whether the mask holds every lane.
#[inline]
#[target_feature(enable = "avx2,fma")]
pub(crate) fn all(mask: M) -> bool {
    _mm256_movemask_ps(mask) == 0xff
}

/// The lanes the mask holds.
#[inline]
#[target_feature(enable = "avx2,fma")]
pub(crate) fn count(mask: M) -> u32 {
    _mm256_movemask_ps(mask).count_ones()
}

/// The bits of each lane as an integer.
#[inline]
#[target_feature(enable = "avx2,fma")]
pub(crate) fn bits(v: V) -> I {
    _mm256_castps_si256(v)
}

/// The lanes whose bits are `i`.
#[inline]
#[target_feature(enable = "avx2,fma")]
pub(crate) fn from_bits(i: I) -> V {
    _mm256_castsi256_ps(i)
}

/// Integer broadcast.
#[inline]
#[target_feature(enable = "avx2,fma")]
pub(crate) fn splat_i(v: i32) -> I {
    _mm256_set1_epi32(v)
}

/// Integer `a + b` (wrapping).
#[inline]
#[target_feature(enable = "avx2,fma")]
pub(crate) fn add_i(a: I, b: I) -> I {
    _mm256_add_epi32(a, b)
}

/// Integer `a − b` (wrapping).
#[inline]
#[target_feature(enable = "avx2,fma")]
pub(crate) fn sub_i(a: I, b: I) -> I {
    _mm256_sub_epi32(a, b)
}

/// Integer `a << 23` (into the exponent field).
#[inline]
#[target_feature(enable = "avx2,fma")]
pub(crate) fn shl_23(a: I) -> I {
    _mm256_slli_epi32::<23>(a)
}

/// `a / 3` of each lane as an unsigned integer: a multiply by ⌈2³³/3⌉
/// and a shift, exact for every u32, on the even and the odd lanes.
#[inline]
#[target_feature(enable = "avx2,fma")]
pub(crate) fn div3_u32(a: I) -> I {
    let magic = _mm256_set1_epi64x(0xAAAA_AAAB);
    let even = _mm256_srli_epi64::<33>(_mm256_mul_epu32(a, magic));
    let odd = _mm256_slli_epi64::<32>(_mm256_srli_epi64::<33>(_mm256_mul_epu32(
        _mm256_srli_epi64::<32>(a),
        magic,
    )));
    _mm256_blend_epi32::<0b1010_1010>(even, odd)
}

/// The largest of the eight lanes (none NaN).
#[inline]
#[target_feature(enable = "avx2,fma")]
pub(crate) fn hmax(v: V) -> f32 {
    let m = _mm_max_ps(_mm256_castps256_ps128(v), _mm256_extractf128_ps::<1>(v));
    let m = _mm_max_ps(m, _mm_movehl_ps(m, m));
    let m = _mm_max_ss(m, _mm_shuffle_ps::<0b01>(m, m));
    _mm_cvtss_f32(m)
}

/// The 3-channel transposes at this width (they need no constants: the
/// struct is empty, for the same calls as [`super::avx512::Shuffles`]).
#[derive(Clone, Copy)]
pub(crate) struct Shuffles;

impl Shuffles {
    /// The transposes.
    #[inline]
    #[target_feature(enable = "avx2,fma")]
    pub(crate) fn new() -> Self {
        Self
    }

    /// [`deinterleave`].
    #[inline]
    #[target_feature(enable = "avx2,fma")]
    pub(crate) fn deinterleave(&self, px: &[[f32; 3]]) -> [V; 3] {
        deinterleave(px)
    }

    /// [`interleave`].
    #[inline]
    #[target_feature(enable = "avx2,fma")]
    pub(crate) fn interleave(&self, c: [V; 3], px: &mut [[f32; 3]]) {
        interleave(c, px)
    }
}

/// Channel planes of 8 interleaved RGB pixels (24 floats): two 128-bit
/// loads per register put pixels 0–3 in the low and 4–7 in the high lane,
/// then three shuffles per plane (the 3-channel transpose of Melax, Intel
/// 2012, "3D vector normalization using 256-bit Intel AVX").
#[inline]
#[target_feature(enable = "avx2,fma")]
pub(crate) fn deinterleave(px: &[[f32; 3]]) -> [V; 3] {
    let f = &px.as_flattened()[..3 * LANES];
    let p = f.as_ptr();
    // SAFETY: `f` holds 24 f32s (checked by the slice above); every load
    // below reads 4 of them at offsets 0..=20.
    let (m03, m14, m25) = unsafe {
        (
            _mm256_insertf128_ps::<1>(
                _mm256_castps128_ps256(_mm_loadu_ps(p)),
                _mm_loadu_ps(p.add(12)),
            ),
            _mm256_insertf128_ps::<1>(
                _mm256_castps128_ps256(_mm_loadu_ps(p.add(4))),
                _mm_loadu_ps(p.add(16)),
            ),
            _mm256_insertf128_ps::<1>(
                _mm256_castps128_ps256(_mm_loadu_ps(p.add(8))),
                _mm_loadu_ps(p.add(20)),
            ),
        )
    };
    // Per 128-bit lane: m03 = x0 y0 z0 x1, m14 = y1 z1 x2 y2, m25 = z2 x3 y3 z3.
    let xy = _mm256_shuffle_ps::<0b10_01_11_10>(m14, m25); // x2 y2 x3 y3
    let yz = _mm256_shuffle_ps::<0b01_00_10_01>(m03, m14); // y0 z0 y1 z1
    let x = _mm256_shuffle_ps::<0b10_00_11_00>(m03, xy); // x0 x1 x2 x3
    let y = _mm256_shuffle_ps::<0b11_01_10_00>(yz, xy); // y0 y1 y2 y3
    let z = _mm256_shuffle_ps::<0b11_00_11_01>(yz, m25); // z0 z1 z2 z3
    [x, y, z]
}

/// Inverse of [`deinterleave`]: writes 8 RGB pixels.
#[inline]
#[target_feature(enable = "avx2,fma")]
pub(crate) fn interleave(c: [V; 3], px: &mut [[f32; 3]]) {
    let [x, y, z] = c;
    let rxy = _mm256_shuffle_ps::<0b10_00_10_00>(x, y); // x0 x2 y0 y2
    let ryz = _mm256_shuffle_ps::<0b11_01_11_01>(y, z); // y1 y3 z1 z3
    let rzx = _mm256_shuffle_ps::<0b11_01_10_00>(z, x); // z0 z2 x1 x3
    let r03 = _mm256_shuffle_ps::<0b10_00_10_00>(rxy, rzx); // x0 y0 z0 x1
    let r14 = _mm256_shuffle_ps::<0b11_01_10_00>(ryz, rxy); // y1 z1 x2 y2
    let r25 = _mm256_shuffle_ps::<0b11_01_11_01>(rzx, ryz); // z2 x3 y3 z3
    let f = &mut px.as_flattened_mut()[..3 * LANES];
    let p = f.as_mut_ptr();
    // SAFETY: `f` holds 24 f32s (checked by the slice above); every store
    // writes 4 of them at offsets 0..=20.
    unsafe {
        _mm_storeu_ps(p, _mm256_castps256_ps128(r03));
        _mm_storeu_ps(p.add(4), _mm256_castps256_ps128(r14));
        _mm_storeu_ps(p.add(8), _mm256_castps256_ps128(r25));
        _mm_storeu_ps(p.add(12), _mm256_extractf128_ps::<1>(r03));
        _mm_storeu_ps(p.add(16), _mm256_extractf128_ps::<1>(r14));
        _mm_storeu_ps(p.add(20), _mm256_extractf128_ps::<1>(r25));
    }
}

/// [`crate::encode::encode_row`] of the affine map over the row's full
/// blocks; returns the pixels done. The caller finishes the tail.
#[target_feature(enable = "avx2,fma")]
pub(crate) fn encode_affine(
    map: &Affine,
    lut: &SrgbLut,
    src: &[[f32; 3]],
    rgba8: &mut [u8],
) -> usize {
    let full = (src.len() / LANES * LANES).min(rgba8.len() / 4 / LANES * LANES);
    let m = map3(map.m, |row| map3(row, |v| splat(v)));
    let b = map3(map.b, |v| splat(v));
    let zero = _mm256_setzero_ps();
    let (one, max) = (splat(1.0), splat(f32::MAX));
    let scale = splat((SRGB_LUT_SIZE - 1) as f32);
    let half = splat(0.5);
    for x in (0..full).step_by(LANES) {
        // `max(p, 0)` (NaN → 0: `maxps` returns its second operand), then at
        // most f32::MAX.
        let p = map3(deinterleave(&src[x..x + LANES]), |v| {
            _mm256_min_ps(_mm256_max_ps(v, zero), max)
        });
        let mut idx = [[0u32; LANES]; 3];
        for c in 0..3 {
            let v = _mm256_add_ps(
                _mm256_add_ps(
                    _mm256_add_ps(_mm256_mul_ps(m[c][0], p[0]), _mm256_mul_ps(m[c][1], p[1])),
                    _mm256_mul_ps(m[c][2], p[2]),
                ),
                b[c],
            );
            // crate::encode::lut_index: clamp to [0, 1] (NaN → 0), then
            // ⌊v·(N − 1) + 0.5⌋, here by truncation (exact: the value is in
            // [0.5, N − 0.5]).
            let v = _mm256_min_ps(_mm256_max_ps(v, zero), one);
            let floor = _mm256_cvttps_epi32(_mm256_add_ps(_mm256_mul_ps(v, scale), half));
            // SAFETY: `idx[c]` holds 8 u32s; the store is unaligned.
            unsafe { _mm256_storeu_si256(idx[c].as_mut_ptr().cast(), floor) };
        }
        let out = &mut rgba8[4 * x..4 * (x + LANES)];
        for (i, o) in out.chunks_exact_mut(4).enumerate() {
            // Indices are masked to the table's size.
            let word = u32::from(lut[idx[0][i] as usize & (SRGB_LUT_SIZE - 1)])
                | u32::from(lut[idx[1][i] as usize & (SRGB_LUT_SIZE - 1)]) << 8
                | u32::from(lut[idx[2][i] as usize & (SRGB_LUT_SIZE - 1)]) << 16
                | 0xff00_0000;
            o.copy_from_slice(&word.to_le_bytes());
        }
    }
    full
}

/// One row of the pipeline's pass A ([`crate::pipeline`]): each pixel's
/// luminance, sanitised (NaN, ±∞, negatives and subnormals → 0), added in
/// pixel order to its block's sum in `sums` (blocks of 8 pixels, a block's
/// sum started at 0 — the portable pass's order, so the same bits). `src`
/// is only read. Returns false (and does nothing) unless `sums` holds one
/// sum per started block.
#[target_feature(enable = "avx2,fma")]
pub(crate) fn block_sums_row(src: &[[f32; 3]], sums: &mut [f32]) -> bool {
    let w = src.len();
    if sums.len() != w.div_ceil(LANES) {
        return false;
    }
    let (lo, inf, zero) = (
        splat(f32::MIN_POSITIVE),
        splat(f32::INFINITY),
        _mm256_setzero_ps(),
    );
    let sanitize = |v: __m256| {
        let keep = _mm256_and_ps(
            _mm256_cmp_ps::<_CMP_GE_OQ>(v, lo),
            _mm256_cmp_ps::<_CMP_LT_OQ>(v, inf),
        );
        _mm256_and_ps(v, keep)
    };
    // The block sums, eight blocks (64 pixels) at a time: each block's
    // eight luminances, transposed, are added in pixel order.
    let weights = map3(crate::image::LUMINANCE_WEIGHTS, |v| splat(v));
    let full = w / (LANES * LANES) * (LANES * LANES);
    for x in (0..full).step_by(LANES * LANES) {
        let mut y = [zero; LANES];
        for (b, yb) in y.iter_mut().enumerate() {
            let [r, g, bl] = map3(
                deinterleave(&src[x + b * LANES..x + (b + 1) * LANES]),
                sanitize,
            );
            *yb = _mm256_add_ps(
                _mm256_add_ps(_mm256_mul_ps(weights[0], r), _mm256_mul_ps(weights[1], g)),
                _mm256_mul_ps(weights[2], bl),
            );
        }
        let t = transpose8(y);
        let mut sum = zero;
        for tj in t {
            sum = _mm256_add_ps(sum, tj);
        }
        let at = x / LANES;
        st(sums, at, _mm256_add_ps(ld(sums, at), sum));
    }
    // The rest block by block, as the portable pass.
    crate::pipeline::block_sums_row_portable(&src[full..], &mut sums[full / LANES..], LANES);
    true
}

/// Transpose of an 8×8 block of lanes: `out[j][i] = v[i][j]`.
#[inline]
#[target_feature(enable = "avx2,fma")]
fn transpose8(v: [__m256; LANES]) -> [__m256; LANES] {
    let t0 = _mm256_unpacklo_ps(v[0], v[1]);
    let t1 = _mm256_unpackhi_ps(v[0], v[1]);
    let t2 = _mm256_unpacklo_ps(v[2], v[3]);
    let t3 = _mm256_unpackhi_ps(v[2], v[3]);
    let t4 = _mm256_unpacklo_ps(v[4], v[5]);
    let t5 = _mm256_unpackhi_ps(v[4], v[5]);
    let t6 = _mm256_unpacklo_ps(v[6], v[7]);
    let t7 = _mm256_unpackhi_ps(v[6], v[7]);
    let u0 = _mm256_shuffle_ps::<0b01_00_01_00>(t0, t2);
    let u1 = _mm256_shuffle_ps::<0b11_10_11_10>(t0, t2);
    let u2 = _mm256_shuffle_ps::<0b01_00_01_00>(t1, t3);
    let u3 = _mm256_shuffle_ps::<0b11_10_11_10>(t1, t3);
    let u4 = _mm256_shuffle_ps::<0b01_00_01_00>(t4, t6);
    let u5 = _mm256_shuffle_ps::<0b11_10_11_10>(t4, t6);
    let u6 = _mm256_shuffle_ps::<0b01_00_01_00>(t5, t7);
    let u7 = _mm256_shuffle_ps::<0b11_10_11_10>(t5, t7);
    [
        _mm256_permute2f128_ps::<0x20>(u0, u4),
        _mm256_permute2f128_ps::<0x20>(u1, u5),
        _mm256_permute2f128_ps::<0x20>(u2, u6),
        _mm256_permute2f128_ps::<0x20>(u3, u7),
        _mm256_permute2f128_ps::<0x31>(u0, u4),
        _mm256_permute2f128_ps::<0x31>(u1, u5),
        _mm256_permute2f128_ps::<0x31>(u2, u6),
        _mm256_permute2f128_ps::<0x31>(u3, u7),
    ]
}

#[cfg(test)]
mod tests {
    use super::*;

    /// Whether the test `test` runs here (see [`crate::simd::testing`]).
    fn avx2(test: &str) -> bool {
        crate::simd::testing::runs(test, crate::simd::Tier::Avx2)
    }

    /// Pixels that exercise every branch: black, L\*'s linear and cubic
    /// parts, FFT round-off negatives, bright lamps, odd ratios.
    fn pixels(n: usize, seed: u32) -> Vec<[f32; 3]> {
        let mut s = seed.wrapping_mul(2_654_435_761).max(1);
        let mut next = move || {
            s ^= s << 13;
            s ^= s >> 17;
            s ^= s << 5;
            s
        };
        (0..n)
            .map(|_| {
                let scale = match next() % 6 {
                    0 => 0.0,
                    1 => 1e-4,
                    2 => 0.01,
                    3 => 1.0,
                    4 => 100.0,
                    _ => 2e4,
                };
                [0, 1, 2].map(|_| {
                    let u = (next() % 1_000_000) as f32 / 1e6;
                    if next() % 50 == 0 {
                        -1e-6 * u
                    } else {
                        scale * u
                    }
                })
            })
            .collect()
    }

    #[test]
    fn deinterleave_and_interleave_are_the_transposes() {
        if !avx2("deinterleave_and_interleave_are_the_transposes") {
            return;
        }
        let px: Vec<[f32; 3]> = (0..8)
            .map(|i| [i as f32, 10.0 + i as f32, 20.0 + i as f32])
            .collect();
        // SAFETY: the CPU has AVX2 and FMA (checked above).
        let planes = unsafe { deinterleave(&px) };
        for (c, plane) in planes.iter().enumerate() {
            let mut v = [0.0f32; 8];
            // SAFETY: as above.
            unsafe { st(&mut v, 0, *plane) };
            assert_eq!(v, std::array::from_fn(|i| (10 * c + i) as f32), "plane {c}");
        }
        let mut back = vec![[0.0f32; 3]; 8];
        // SAFETY: as above.
        unsafe { interleave(planes, &mut back) };
        assert_eq!(back, px);
    }

    #[test]
    fn transpose8_transposes() {
        if !avx2("transpose8_transposes") {
            return;
        }
        let m: Vec<f32> = (0..64).map(|i| i as f32).collect();
        // SAFETY: the CPU has AVX2 and FMA (checked above).
        let t = unsafe { transpose8(std::array::from_fn(|i| ld(&m, 8 * i))) };
        for (j, tj) in t.iter().enumerate() {
            let mut v = [0.0f32; 8];
            // SAFETY: as above.
            unsafe { st(&mut v, 0, *tj) };
            assert_eq!(v, std::array::from_fn(|i| (8 * i + j) as f32), "row {j}");
        }
    }

    #[test]
    fn block_sums_row_matches_the_portable_pass_bit_for_bit() {
        if !avx2("block_sums_row_matches_the_portable_pass_bit_for_bit") {
            return;
        }
        for w in [1usize, 7, 64, 130, 203, 720] {
            let mut src = pixels(w, w as u32);
            if w > 5 {
                src[3] = [f32::NAN, f32::INFINITY, -1.0];
                src[5] = [1e-40, f32::NEG_INFINITY, f32::MAX];
            }
            let mut sums = vec![0.5f32; w.div_ceil(8)];
            // SAFETY: the CPU has AVX2 and FMA (checked above).
            assert!(unsafe { block_sums_row(&src, &mut sums) });
            let mut want_sums = vec![0.5f32; w.div_ceil(8)];
            crate::pipeline::block_sums_row_portable(&src, &mut want_sums, 8);
            assert_eq!(
                sums.iter().map(|v| v.to_bits()).collect::<Vec<_>>(),
                want_sums.iter().map(|v| v.to_bits()).collect::<Vec<_>>(),
                "w {w}"
            );
            // A sum that is not its block's fails.
            if w >= 64 {
                let mut bad = src.clone();
                bad[9][1] += 1.0;
                let mut bad_sums = vec![0.5f32; w.div_ceil(8)];
                // SAFETY: as above.
                assert!(unsafe { block_sums_row(&bad, &mut bad_sums) });
                assert_ne!(bad_sums[1].to_bits(), want_sums[1].to_bits());
            }
        }
    }

    #[test]
    fn encode_matches_the_portable_twin_bit_for_bit() {
        if !avx2("encode_matches_the_portable_twin_bit_for_bit") {
            return;
        }
        let lut = crate::encode::srgb_lut();
        let map = Affine {
            m: [[0.9, 0.05, 0.01], [0.02, 1.1, 0.03], [0.0, 0.07, 0.8]],
            b: [0.01, -0.02, 0.0],
        };
        for scale in [1.0f32, 0.01, 1e-4] {
            let mut px: Vec<[f32; 3]> = pixels(1003, 7)
                .iter()
                .map(|p| p.map(|v| v * scale))
                .collect();
            // What the sink never gets from the pipeline, handled alike.
            px[5] = [f32::NAN, f32::INFINITY, f32::NEG_INFINITY];
            px[13] = [f32::MAX, 1e38, -0.0];
            let mut want = vec![0u8; 4 * px.len()];
            crate::encode::encode_row_portable(&map, &lut, &px, &mut want);
            let mut got = vec![0u8; 4 * px.len()];
            // SAFETY: the CPU has AVX2 and FMA (checked above).
            let done = unsafe { encode_affine(&map, &lut, &px, &mut got) };
            assert_eq!(done, 1000);
            assert_eq!(got[..4 * done], want[..4 * done], "scale {scale}");
        }
    }
}
