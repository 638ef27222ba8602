//! The band pass's per-row loops written with AVX2 intrinsics.
//!
//! Each function here is the twin of a portable one in the parent module
//! ([`super::load_y`], [`super::to_lightness`], [`super::horizontal`],
//! [`super::vertical`]) and of [`crate::encode::encode_row`] for the affine
//! map, and computes **the same bits**: the same float operations in the
//! same order (no fused multiply-adds), selects where the portable code has
//! branches. The portable loops are written for the auto-vectoriser, but a
//! profile showed much of them scalar (the RGB deinterleave as 24 inserts,
//! `f32::max`'s NaN handling as compare + blend per lane, constants
//! re-broadcast inside loops); here the deinterleave is three 256-bit
//! shuffles and every lane operation one instruction. The tests at the end
//! compare each function with its portable twin bit for bit.
//!
//! Only frames' full blocks of 8 pixels run here; a row's short tail goes
//! through the portable code. Everything is `#[target_feature(enable =
//! "avx2,fma")]` and is called only after [`super::has_avx2_fma`].

use std::arch::x86_64::*;

use super::{
    AcuityBlur, Band, Ctx, LAB_KAPPA_F32, LANES, RGB_TO_XYZ, SigmaRule, WHITE_XYZ, XYZ_TO_RGB, map3,
};
use crate::encode::{Affine, SRGB_LUT_SIZE, SrgbLut};

/// Eight lanes from `s[at..at + 8]` (bounds-checked).
#[inline]
#[target_feature(enable = "avx2,fma")]
fn ld(s: &[f32], at: usize) -> __m256 {
    let s = &s[at..at + LANES];
    // SAFETY: `s` holds exactly 8 f32s (checked by the slice above); the
    // load is unaligned.
    unsafe { _mm256_loadu_ps(s.as_ptr()) }
}

/// Stores eight lanes to `d[at..at + 8]` (bounds-checked).
#[inline]
#[target_feature(enable = "avx2,fma")]
fn st(d: &mut [f32], at: usize, v: __m256) {
    let d = &mut d[at..at + LANES];
    // SAFETY: `d` holds exactly 8 f32s (checked by the slice above).
    unsafe { _mm256_storeu_ps(d.as_mut_ptr(), v) }
}

/// Broadcast.
#[inline]
#[target_feature(enable = "avx2,fma")]
fn splat(v: f32) -> __m256 {
    _mm256_set1_ps(v)
}

/// `if mask { a } else { b }` per lane (`mask` from a comparison).
#[inline]
#[target_feature(enable = "avx2,fma")]
fn select(mask: __m256, a: __m256, b: __m256) -> __m256 {
    _mm256_blendv_ps(b, a, mask)
}

/// The largest of the eight lanes (none NaN).
#[inline]
#[target_feature(enable = "avx2,fma")]
fn hmax(v: __m256) -> f32 {
    let m = _mm_max_ps(_mm256_castps256_ps128(v), _mm256_extractf128_ps::<1>(v));
    let m = _mm_max_ps(m, _mm_movehl_ps(m, m));
    let m = _mm_max_ss(m, _mm_shuffle_ps::<0b01>(m, m));
    _mm_cvtss_f32(m)
}

/// Channel planes of 8 interleaved RGB pixels (24 floats): two 128-bit
/// loads per register put pixels 0–3 in the low and 4–7 in the high lane,
/// then three shuffles per plane (the 3-channel transpose of Melax, Intel
/// 2012, "3D vector normalization using 256-bit Intel AVX").
#[inline]
#[target_feature(enable = "avx2,fma")]
fn deinterleave(px: &[[f32; 3]]) -> [__m256; 3] {
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
fn interleave(c: [__m256; 3], px: &mut [[f32; 3]]) {
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

/// `m · p` per lane, each row as `(m₀p₀ + m₁p₁) + m₂p₂`.
#[inline]
#[target_feature(enable = "avx2,fma")]
fn mat3(m: &[[f32; 3]; 3], p: &[__m256; 3]) -> [__m256; 3] {
    map3(*m, |row| {
        _mm256_add_ps(
            _mm256_add_ps(
                _mm256_mul_ps(splat(row[0]), p[0]),
                _mm256_mul_ps(splat(row[1]), p[1]),
            ),
            _mm256_mul_ps(splat(row[2]), p[2]),
        )
    })
}

/// [`super::cbrt_v`]: the exponent-bits guess `bits/3 + B1` (the unsigned
/// division as a multiply by ⌈2³³/3⌉ and a shift, exact for every u32),
/// then three Newton steps.
#[inline]
#[target_feature(enable = "avx2,fma")]
fn cbrt(t: __m256) -> __m256 {
    // (127 − 127/3 − 0.0331)·2²³, FreeBSD s_cbrtf.c B1
    const B1: i32 = 709_958_130;
    let bits = _mm256_castps_si256(t);
    let magic = _mm256_set1_epi64x(0xAAAA_AAAB);
    let even = _mm256_srli_epi64::<33>(_mm256_mul_epu32(bits, magic));
    let odd = _mm256_slli_epi64::<32>(_mm256_srli_epi64::<33>(_mm256_mul_epu32(
        _mm256_srli_epi64::<32>(bits),
        magic,
    )));
    let third = _mm256_blend_epi32::<0b1010_1010>(even, odd);
    let mut y = _mm256_castsi256_ps(_mm256_add_epi32(third, _mm256_set1_epi32(B1)));
    let (two_thirds, one_third) = (splat(2.0 / 3.0), splat(1.0 / 3.0));
    let t3 = _mm256_mul_ps(t, one_third);
    for _ in 0..3 {
        y = _mm256_add_ps(
            _mm256_mul_ps(two_thirds, y),
            _mm256_div_ps(t3, _mm256_mul_ps(y, y)),
        );
    }
    y
}

/// [`super::lab_g_v`]: κt up to ε, `116∛t − 16` above.
#[inline]
#[target_feature(enable = "avx2,fma")]
fn lab_g(t: __m256) -> __m256 {
    let eps = splat(216.0 / 24389.0);
    let linear = _mm256_mul_ps(splat(24389.0 / 27.0), t);
    let cubic = _mm256_cmp_ps::<_CMP_GT_OQ>(t, eps);
    if _mm256_movemask_ps(cubic) == 0 {
        return linear;
    }
    let c = cbrt(_mm256_max_ps(t, eps));
    let v = _mm256_sub_ps(_mm256_mul_ps(splat(116.0), c), splat(16.0));
    select(cubic, v, linear)
}

/// [`super::lab_g_inv`]: v/κ up to 8, `((v + 16)/116)³` above.
#[inline]
#[target_feature(enable = "avx2,fma")]
fn lab_g_inv(v: __m256) -> __m256 {
    let f = _mm256_div_ps(_mm256_add_ps(v, splat(16.0)), splat(116.0));
    let cube = _mm256_mul_ps(_mm256_mul_ps(f, f), f);
    let linear = _mm256_mul_ps(v, splat(27.0 / 24389.0));
    select(_mm256_cmp_ps::<_CMP_GT_OQ>(v, splat(8.0)), cube, linear)
}

/// [`super::exp_v`] for x in [−87, 0].
#[inline]
#[target_feature(enable = "avx2,fma")]
fn exp(x: __m256) -> __m256 {
    const LN2_HI: f32 = 0.693_145_75;
    const LN2_LO: f32 = 1.428_606_8e-6;
    // 1.5·2²³: adding and subtracting it rounds to the nearest integer
    const ROUND: f32 = 12_582_912.0;
    let x = _mm256_max_ps(x, splat(-87.0));
    let shifted = _mm256_add_ps(
        _mm256_mul_ps(x, splat(std::f32::consts::LOG2_E)),
        splat(ROUND),
    );
    let n = _mm256_sub_ps(shifted, splat(ROUND));
    let n_int = _mm256_sub_epi32(
        _mm256_castps_si256(shifted),
        _mm256_set1_epi32(ROUND.to_bits() as i32),
    );
    let r = _mm256_sub_ps(
        _mm256_sub_ps(x, _mm256_mul_ps(n, splat(LN2_HI))),
        _mm256_mul_ps(n, splat(LN2_LO)),
    );
    let mut p = splat(1.0 / 720.0);
    for c in [1.0 / 120.0, 1.0 / 24.0, 1.0 / 6.0, 0.5, 1.0, 1.0] {
        p = _mm256_add_ps(splat(c), _mm256_mul_ps(r, p));
    }
    let scale = _mm256_slli_epi32::<23>(_mm256_add_epi32(n_int, _mm256_set1_epi32(127)));
    _mm256_mul_ps(p, _mm256_castsi256_ps(scale))
}

/// [`super::sigma_v`].
#[inline]
#[target_feature(enable = "avx2,fma")]
fn sigma(rule: SigmaRule, l: __m256, white: f32) -> __m256 {
    match rule {
        SigmaRule::Linear { scale } => {
            // 001 eq 12; clamp of a value that is never NaN
            let s = _mm256_min_ps(
                _mm256_max_ps(_mm256_sub_ps(splat(1.0), l), _mm256_setzero_ps()),
                splat(1.0),
            );
            _mm256_mul_ps(s, splat(scale))
        }
        SigmaRule::Larson { .. } => {
            let mut v = [0.0f32; LANES];
            st(&mut v, 0, l);
            ld(&v.map(|li| rule.sigma(li, white)), 0)
        }
        SigmaRule::None => _mm256_setzero_ps(),
    }
}

/// The per-block setup of [`super::gather_v`]: σ of each lane from
/// `centre`; `None` when no lane blurs, else (tap radius of the block,
/// e = exp(−1/(2σ²)), e², 3σ (0 for lanes that keep their value)).
#[inline]
#[target_feature(enable = "avx2,fma")]
fn taps(ctx: &Ctx, centre: __m256) -> Option<(usize, __m256, __m256, __m256)> {
    let s = sigma(ctx.rule, centre, ctx.white);
    let sigma_max = hmax(s).max(0.0);
    if sigma_max <= AcuityBlur::MIN_SIGMA_PX {
        return None;
    }
    let block_r = (3.0 * sigma_max).ceil().min(ctx.r as f32) as usize;
    let active = _mm256_cmp_ps::<_CMP_GT_OQ>(s, splat(AcuityBlur::MIN_SIGMA_PX));
    let s = select(active, s, splat(1.0));
    let e = _mm256_div_ps(splat(-0.5), _mm256_mul_ps(s, s));
    let three_sigma = select(active, _mm256_mul_ps(splat(3.0), s), _mm256_setzero_ps());
    let e = exp(e);
    Some((block_r, e, _mm256_mul_ps(e, e), three_sigma))
}

/// [`super::gather_v`] with the pairs `(v(−k), v(k))` = `pair(k)`: a macro,
/// so that the loads inline into the calling `target_feature` function.
macro_rules! gather {
    ($ctx:expr, $centre:expr, |$k:ident| $pair:expr) => {{
        let centre: __m256 = $centre;
        match taps($ctx, centre) {
            None => centre,
            Some((block_r, e, e2, three_sigma)) => {
                let (mut g, mut q) = (splat(1.0), e);
                let (mut acc, mut norm) = (centre, splat(1.0));
                let two = splat(2.0);
                for $k in 1..=block_r {
                    let (a, b): (__m256, __m256) = $pair;
                    let below = splat(($k - 1) as f32);
                    g = _mm256_mul_ps(g, q);
                    q = _mm256_mul_ps(q, e2);
                    let gk = _mm256_and_ps(_mm256_cmp_ps::<_CMP_LT_OQ>(below, three_sigma), g);
                    acc = _mm256_add_ps(acc, _mm256_mul_ps(gk, _mm256_add_ps(a, b)));
                    norm = _mm256_add_ps(norm, _mm256_mul_ps(two, gk));
                }
                _mm256_div_ps(acc, norm)
            }
        }
    }};
}

/// [`super::load_y`] over the row's full blocks from pixel `from` (a
/// multiple of 8) on; returns (any of those pixels dark, pixels done). The
/// caller finishes the tail.
#[target_feature(enable = "avx2,fma")]
pub(super) fn load_y(
    ctx: &Ctx,
    src: &[[f32; 3]],
    lrow: &mut [f32],
    head: &mut [f32],
    from: usize,
) -> (bool, usize) {
    let y_row = RGB_TO_XYZ[1];
    let inv_white = splat(1.0 / ctx.white);
    let (c0, c1, c2) = (splat(y_row[0]), splat(y_row[1]), splat(y_row[2]));
    let dark_below = splat(ctx.dark_below);
    let mut dark = _mm256_setzero_ps();
    let full = src.len() / LANES * LANES;
    for x in (from.min(full)..full).step_by(LANES) {
        let [r, g, b] = deinterleave(&src[x..x + LANES]);
        let y = _mm256_add_ps(
            _mm256_add_ps(_mm256_mul_ps(c0, r), _mm256_mul_ps(c1, g)),
            _mm256_mul_ps(c2, b),
        );
        let t = _mm256_mul_ps(y, inv_white);
        st(lrow, ctx.r + x, t);
        st(
            head,
            x,
            _mm256_mul_ps(_mm256_max_ps(_mm256_max_ps(r, g), b), inv_white),
        );
        dark = _mm256_or_ps(dark, _mm256_cmp_ps::<_CMP_LT_OQ>(t, dark_below));
    }
    (_mm256_movemask_ps(dark) != 0, full)
}

/// [`super::to_lightness`]'s conversion from pixel `from` (a multiple of
/// 8) on (the caller pads the row).
#[target_feature(enable = "avx2,fma")]
pub(super) fn to_lightness(ctx: &Ctx, lrow: &mut [f32], from: usize) {
    for x in (ctx.r + from.min(ctx.stride_h)..ctx.r + ctx.stride_h).step_by(LANES) {
        let t = ld(lrow, x);
        st(lrow, x, lab_g(t));
    }
}

/// [`super::horizontal`] from pixel `from` (a multiple of 8) on.
#[target_feature(enable = "avx2,fma")]
pub(super) fn horizontal(ctx: &Ctx, lrow: &[f32], hrow: &mut [f32], from: usize) {
    let r = ctx.r;
    for bx in from / LANES..ctx.stride_h / LANES {
        let x = r + bx * LANES;
        let v = gather!(ctx, ld(lrow, x), |k| (ld(lrow, x - k), ld(lrow, x + k)));
        st(hrow, bx * LANES, v);
    }
}

/// [`super::vertical`] over the row's full blocks from pixel `from` (a
/// multiple of 8) on; returns (pixels whose lightness changed, pixels
/// done). The caller finishes the tail.
#[target_feature(enable = "avx2,fma")]
pub(super) fn vertical(
    ctx: &Ctx,
    band: &Band,
    up: &[usize],
    down: &[usize],
    y: usize,
    row: &mut [[f32; 3]],
    from: usize,
) -> (usize, usize) {
    let Ctx { r, .. } = *ctx;
    let ring = 2 * r + 1;
    let sh = ctx.stride_h;
    let hor = &band.hor[..];
    let lrow = &band.lum[(y % ring) * ctx.stride_l + r..];
    let head_row = &band.head[(y % ring) * sh..];
    let wx = map3(WHITE_XYZ, |c| c * ctx.white);
    let kappa = splat(LAB_KAPPA_F32);
    let shift_scale = splat(ctx.white / LAB_KAPPA_F32);
    let mut changed = 0;
    let full = row.len() / LANES * LANES;
    for x in (from.min(full)..full).step_by(LANES) {
        let hv = ld(hor, up[0] + x);
        let l_new = gather!(ctx, hv, |k| (ld(hor, up[k] + x), ld(hor, down[k] + x)));
        let l_old = ld(lrow, x);
        let moved = _mm256_cmp_ps::<_CMP_NEQ_UQ>(l_new, l_old);
        let moved_bits = _mm256_movemask_ps(moved);
        if moved_bits == 0 {
            continue;
        }
        let d = _mm256_sub_ps(l_new, l_old);
        let head = ld(head_row, x);
        let bound = _mm256_add_ps(
            _mm256_mul_ps(head, kappa),
            _mm256_max_ps(d, _mm256_setzero_ps()),
        );
        let linear = _mm256_movemask_ps(_mm256_cmp_ps::<_CMP_LE_OQ>(bound, splat(8.0))) == 0xff;
        let out = &mut row[x..x + LANES];
        let p = deinterleave(out);
        let new = if linear {
            // RGB' = RGB + (white·Δ/κ)·(1, 1, 1), see the parent module.
            let shift = _mm256_mul_ps(d, shift_scale);
            map3(p, |c| _mm256_add_ps(c, shift))
        } else {
            let xyz = mat3(&RGB_TO_XYZ, &p);
            let gx = lab_g(_mm256_div_ps(xyz[0], splat(wx[0])));
            let gz = lab_g(_mm256_div_ps(xyz[2], splat(wx[2])));
            let new = [
                _mm256_mul_ps(lab_g_inv(_mm256_add_ps(gx, d)), splat(wx[0])),
                _mm256_mul_ps(lab_g_inv(_mm256_add_ps(l_old, d)), splat(wx[1])),
                _mm256_mul_ps(lab_g_inv(_mm256_add_ps(gz, d)), splat(wx[2])),
            ];
            mat3(&XYZ_TO_RGB, &new)
        };
        let kept = map3([0, 1, 2], |c| select(moved, new[c], p[c]));
        interleave(kept, out);
        changed += moved_bits.count_ones() as usize;
    }
    (changed, full)
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

    fn avx2() -> bool {
        super::super::has_avx2_fma()
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
        if !avx2() {
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
    fn cbrt_exp_and_lab_match_the_portable_twins_bit_for_bit() {
        if !avx2() {
            return;
        }
        let mut worst = 0;
        for i in 0..100_000u32 {
            let t: [f32; 8] = std::array::from_fn(|j| {
                f32::from_bits(0x0080_0000 + (i * 8 + j as u32).wrapping_mul(21_473) % 0x7e00_0000)
            });
            let x: [f32; 8] = std::array::from_fn(|j| -((i * 8 + j as u32) as f32) * (90.0 / 8e5));
            let v: [f32; 8] = std::array::from_fn(|j| ((i * 8 + j as u32) as f32 - 1e5) * 1e-3);
            let mut got = [[0.0f32; 8]; 4];
            // SAFETY: the CPU has AVX2 and FMA (checked above).
            unsafe {
                st(&mut got[0], 0, cbrt(ld(&t, 0)));
                st(&mut got[1], 0, exp(ld(&x, 0)));
                st(&mut got[2], 0, lab_g(ld(&t, 0)));
                st(&mut got[3], 0, lab_g_inv(ld(&v, 0)));
            }
            let want = [
                super::super::cbrt_v(t),
                super::super::exp_v(x),
                super::super::lab_g_v(t),
                v.map(super::super::lab_g_inv),
            ];
            for (f, (g, w)) in got.iter().zip(&want).enumerate() {
                for (j, (a, b)) in g.iter().zip(w).enumerate() {
                    if a.to_bits() != b.to_bits() {
                        if worst < 10 {
                            eprintln!(
                                "fn {f} lane {j}: {a:e} vs {b:e} (t {:e}, x {:e}, v {:e})",
                                t[j], x[j], v[j]
                            );
                        }
                        worst += 1;
                    }
                }
            }
        }
        assert_eq!(worst, 0, "lanes that differ");
    }

    #[test]
    fn transpose8_transposes() {
        if !avx2() {
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
        if !avx2() {
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
        if !avx2() {
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
