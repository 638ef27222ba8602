//! The band pass's per-row loops and the affine encoding with AVX-512F:
//! sixteen pixels a register.
//!
//! Each function is the twin of one in [`super::avx2`] (and so of the
//! portable loops of the parent module and of
//! [`crate::encode::encode_row`] for the affine map) and computes **the
//! same bits**: the same float operations in the same order, no fused
//! multiply-adds. Blocks of 16 instead of 8 change nothing a pixel sees:
//!
//! * a block's tap loop runs to the largest radius of its pixels and every
//!   tap beyond a pixel's own radius adds an exact zero (as for 8);
//! * L\*'s "all eight linear" shortcut and the select it skips give the same
//!   value per lane;
//! * step 4's shortcut (RGB + white·Δ/κ when all of a block is in L\*'s
//!   linear part) is decided per half of 8 pixels, the block of the AVX2
//!   and portable loops, and both results are computed and selected per
//!   half when the halves differ.
//!
//! The sRGB table lookups are three 16-lane gathers; the table carries
//! [`crate::encode::SRGB_LUT_PAD`] bytes beyond its last entry so that the
//! 4-byte gather at the last index stays inside it.
//!
//! Each function does the row's full blocks of 16 and returns where it
//! stopped; the caller hands the rest to the AVX2 twin. Everything is
//! `#[target_feature(enable = "avx512f,avx2,fma")]` and called only after
//! [`super::has_avx512`].

use std::arch::x86_64::*;

use super::{AcuityBlur, Band, Ctx, LAB_KAPPA_F32, RGB_TO_XYZ, SigmaRule, WHITE_XYZ, XYZ_TO_RGB};
use crate::encode::{Affine, SRGB_LUT_SIZE, SrgbLut};

/// Lanes of one register.
pub(crate) const W: usize = 16;

/// Sixteen lanes from `s[at..at + 16]` (bounds-checked).
#[inline]
#[target_feature(enable = "avx512f,avx2,fma")]
fn ld(s: &[f32], at: usize) -> __m512 {
    let s = &s[at..at + W];
    // SAFETY: `s` holds exactly 16 f32s (checked by the slice above); the
    // load is unaligned.
    unsafe { _mm512_loadu_ps(s.as_ptr()) }
}

/// Stores sixteen lanes to `d[at..at + 16]` (bounds-checked).
#[inline]
#[target_feature(enable = "avx512f,avx2,fma")]
fn st(d: &mut [f32], at: usize, v: __m512) {
    let d = &mut d[at..at + W];
    // SAFETY: `d` holds exactly 16 f32s (checked by the slice above).
    unsafe { _mm512_storeu_ps(d.as_mut_ptr(), v) }
}

/// Broadcast.
#[inline]
#[target_feature(enable = "avx512f,avx2,fma")]
fn splat(v: f32) -> __m512 {
    _mm512_set1_ps(v)
}

/// `if mask { a } else { b }` per lane.
#[inline]
#[target_feature(enable = "avx512f,avx2,fma")]
fn select(mask: __mmask16, a: __m512, b: __m512) -> __m512 {
    _mm512_mask_blend_ps(mask, b, a)
}

/// Index vectors of the 3-channel transposes of 16 pixels (48 floats in
/// three registers `a`, `b`, `c`), as two-source permutes.
const fn deinterleave_idx(ch: usize) -> [[i32; W]; 2] {
    // Plane `ch`, lane i = float 3i + ch = register (3i + ch)/16, offset
    // (3i + ch)%16. First permute: lanes from a (0..16) and b (16..32);
    // second: keep those (lane i) and take c's (16 + offset).
    let mut first = [0i32; W];
    let mut second = [0i32; W];
    let mut i = 0;
    while i < W {
        let f = 3 * i + ch;
        let (reg, off) = (f / W, (f % W) as i32);
        if reg < 2 {
            first[i] = reg as i32 * W as i32 + off;
            second[i] = i as i32;
        } else {
            second[i] = W as i32 + off;
        }
        i += 1;
    }
    [first, second]
}

/// Inverse of [`deinterleave_idx`]: output register `reg`, lane j = float
/// 16·reg + j = pixel (16 reg + j)/3, channel (16 reg + j)%3; first permute
/// over planes (x, y), second over (that, z).
const fn interleave_idx(reg: usize) -> [[i32; W]; 2] {
    let mut first = [0i32; W];
    let mut second = [0i32; W];
    let mut j = 0;
    while j < W {
        let f = W * reg + j;
        let (px, ch) = ((f / 3) as i32, f % 3);
        match ch {
            0 => {
                first[j] = px;
                second[j] = j as i32;
            }
            1 => {
                first[j] = W as i32 + px;
                second[j] = j as i32;
            }
            _ => second[j] = W as i32 + px,
        }
        j += 1;
    }
    [first, second]
}

const DEINTERLEAVE: [[[i32; W]; 2]; 3] = [
    deinterleave_idx(0),
    deinterleave_idx(1),
    deinterleave_idx(2),
];
const INTERLEAVE: [[[i32; W]; 2]; 3] = [interleave_idx(0), interleave_idx(1), interleave_idx(2)];

/// The permute indices, loaded once per row.
#[derive(Clone, Copy)]
struct Shuffles {
    de: [[__m512i; 2]; 3],
    inter: [[__m512i; 2]; 3],
}

impl Shuffles {
    #[inline]
    #[target_feature(enable = "avx512f,avx2,fma")]
    fn new() -> Self {
        let load = |v: &[i32; W]| {
            // SAFETY: `v` holds 16 i32s; the load is unaligned.
            unsafe { _mm512_loadu_si512(v.as_ptr().cast()) }
        };
        Self {
            de: DEINTERLEAVE.map(|p| p.map(|v| load(&v))),
            inter: INTERLEAVE.map(|p| p.map(|v| load(&v))),
        }
    }

    /// Channel planes of 16 interleaved RGB pixels (48 floats).
    #[inline]
    #[target_feature(enable = "avx512f,avx2,fma")]
    fn deinterleave(&self, px: &[[f32; 3]]) -> [__m512; 3] {
        let f = &px.as_flattened()[..3 * W];
        let (a, b, c) = (ld(f, 0), ld(f, W), ld(f, 2 * W));
        self.de
            .map(|[i1, i2]| _mm512_permutex2var_ps(_mm512_permutex2var_ps(a, i1, b), i2, c))
    }

    /// Inverse of [`Self::deinterleave`]: writes 16 RGB pixels.
    #[inline]
    #[target_feature(enable = "avx512f,avx2,fma")]
    fn interleave(&self, c: [__m512; 3], px: &mut [[f32; 3]]) {
        let [x, y, z] = c;
        let f = &mut px.as_flattened_mut()[..3 * W];
        for (reg, [i1, i2]) in self.inter.iter().enumerate() {
            let v = _mm512_permutex2var_ps(_mm512_permutex2var_ps(x, *i1, y), *i2, z);
            st(f, reg * W, v);
        }
    }
}

/// `m · p` per lane, each row as `(m₀p₀ + m₁p₁) + m₂p₂`.
#[inline]
#[target_feature(enable = "avx512f,avx2,fma")]
fn mat3(m: &[[f32; 3]; 3], p: &[__m512; 3]) -> [__m512; 3] {
    m.map(|row| {
        _mm512_add_ps(
            _mm512_add_ps(
                _mm512_mul_ps(splat(row[0]), p[0]),
                _mm512_mul_ps(splat(row[1]), p[1]),
            ),
            _mm512_mul_ps(splat(row[2]), p[2]),
        )
    })
}

/// [`super::cbrt_v`]: `bits/3 + B1` (the unsigned division as a multiply
/// by ⌈2³³/3⌉ and a shift), then three Newton steps.
#[inline]
#[target_feature(enable = "avx512f,avx2,fma")]
fn cbrt(t: __m512) -> __m512 {
    // (127 − 127/3 − 0.0331)·2²³, FreeBSD s_cbrtf.c B1
    const B1: i32 = 709_958_130;
    let bits = _mm512_castps_si512(t);
    let magic = _mm512_set1_epi64(0xAAAA_AAAB);
    let even = _mm512_srli_epi64::<33>(_mm512_mul_epu32(bits, magic));
    let odd = _mm512_slli_epi64::<32>(_mm512_srli_epi64::<33>(_mm512_mul_epu32(
        _mm512_srli_epi64::<32>(bits),
        magic,
    )));
    let third = _mm512_mask_blend_epi32(0xAAAA, even, odd);
    let mut y = _mm512_castsi512_ps(_mm512_add_epi32(third, _mm512_set1_epi32(B1)));
    let (two_thirds, one_third) = (splat(2.0 / 3.0), splat(1.0 / 3.0));
    let t3 = _mm512_mul_ps(t, one_third);
    for _ in 0..3 {
        y = _mm512_add_ps(
            _mm512_mul_ps(two_thirds, y),
            _mm512_div_ps(t3, _mm512_mul_ps(y, y)),
        );
    }
    y
}

/// [`super::lab_g_v`]: κt up to ε, `116∛t − 16` above.
#[inline]
#[target_feature(enable = "avx512f,avx2,fma")]
fn lab_g(t: __m512) -> __m512 {
    let eps = splat(216.0 / 24389.0);
    let linear = _mm512_mul_ps(splat(24389.0 / 27.0), t);
    let cubic = _mm512_cmp_ps_mask::<_CMP_GT_OQ>(t, eps);
    if cubic == 0 {
        return linear;
    }
    let c = cbrt(_mm512_max_ps(t, eps));
    let v = _mm512_sub_ps(_mm512_mul_ps(splat(116.0), c), splat(16.0));
    select(cubic, v, linear)
}

/// [`super::lab_g_inv`]: v/κ up to 8, `((v + 16)/116)³` above.
#[inline]
#[target_feature(enable = "avx512f,avx2,fma")]
fn lab_g_inv(v: __m512) -> __m512 {
    let f = _mm512_div_ps(_mm512_add_ps(v, splat(16.0)), splat(116.0));
    let cube = _mm512_mul_ps(_mm512_mul_ps(f, f), f);
    let linear = _mm512_mul_ps(v, splat(27.0 / 24389.0));
    select(
        _mm512_cmp_ps_mask::<_CMP_GT_OQ>(v, splat(8.0)),
        cube,
        linear,
    )
}

/// [`super::exp_v`] for x in [−87, 0].
#[inline]
#[target_feature(enable = "avx512f,avx2,fma")]
fn exp(x: __m512) -> __m512 {
    const LN2_HI: f32 = 0.693_145_75;
    const LN2_LO: f32 = 1.428_606_8e-6;
    // 1.5·2²³: adding and subtracting it rounds to the nearest integer
    const ROUND: f32 = 12_582_912.0;
    let x = _mm512_max_ps(x, splat(-87.0));
    let shifted = _mm512_add_ps(
        _mm512_mul_ps(x, splat(std::f32::consts::LOG2_E)),
        splat(ROUND),
    );
    let n = _mm512_sub_ps(shifted, splat(ROUND));
    let n_int = _mm512_sub_epi32(
        _mm512_castps_si512(shifted),
        _mm512_set1_epi32(ROUND.to_bits() as i32),
    );
    let r = _mm512_sub_ps(
        _mm512_sub_ps(x, _mm512_mul_ps(n, splat(LN2_HI))),
        _mm512_mul_ps(n, splat(LN2_LO)),
    );
    let mut p = splat(1.0 / 720.0);
    for c in [1.0 / 120.0, 1.0 / 24.0, 1.0 / 6.0, 0.5, 1.0, 1.0] {
        p = _mm512_add_ps(splat(c), _mm512_mul_ps(r, p));
    }
    let scale = _mm512_slli_epi32::<23>(_mm512_add_epi32(n_int, _mm512_set1_epi32(127)));
    _mm512_mul_ps(p, _mm512_castsi512_ps(scale))
}

/// [`super::sigma_v`].
#[inline]
#[target_feature(enable = "avx512f,avx2,fma")]
fn sigma(rule: SigmaRule, l: __m512, white: f32) -> __m512 {
    match rule {
        SigmaRule::Linear { scale } => {
            // 001 eq 12; clamp of a value that is never NaN
            let s = _mm512_min_ps(
                _mm512_max_ps(_mm512_sub_ps(splat(1.0), l), _mm512_setzero_ps()),
                splat(1.0),
            );
            _mm512_mul_ps(s, splat(scale))
        }
        SigmaRule::Larson { .. } => {
            let mut v = [0.0f32; W];
            st(&mut v, 0, l);
            ld(&v.map(|li| rule.sigma(li, white)), 0)
        }
        SigmaRule::None => _mm512_setzero_ps(),
    }
}

/// The per-block setup of [`super::gather_v`]: `None` when no lane blurs,
/// else (tap radius of the block, e = exp(−1/(2σ²)), e², 3σ (0 for lanes
/// that keep their value)).
#[inline]
#[target_feature(enable = "avx512f,avx2,fma")]
fn taps(ctx: &Ctx, centre: __m512) -> Option<(usize, __m512, __m512, __m512)> {
    let s = sigma(ctx.rule, centre, ctx.white);
    // σ is never NaN (lightness of sanitised, finite values).
    let sigma_max = _mm512_reduce_max_ps(s).max(0.0);
    if sigma_max <= AcuityBlur::MIN_SIGMA_PX {
        return None;
    }
    let block_r = (3.0 * sigma_max).ceil().min(ctx.r as f32) as usize;
    let active = _mm512_cmp_ps_mask::<_CMP_GT_OQ>(s, splat(AcuityBlur::MIN_SIGMA_PX));
    let s = select(active, s, splat(1.0));
    let e = _mm512_div_ps(splat(-0.5), _mm512_mul_ps(s, s));
    let three_sigma = _mm512_maskz_mov_ps(active, _mm512_mul_ps(splat(3.0), s));
    let e = exp(e);
    Some((block_r, e, _mm512_mul_ps(e, e), three_sigma))
}

/// [`super::gather_v`] with the pairs `(v(−k), v(k))` = `pair(k)`.
macro_rules! gather {
    ($ctx:expr, $centre:expr, |$k:ident| $pair:expr) => {{
        let centre: __m512 = $centre;
        match taps($ctx, centre) {
            None => centre,
            Some((block_r, e, e2, three_sigma)) => {
                let (mut g, mut q) = (splat(1.0), e);
                let (mut acc, mut norm) = (centre, splat(1.0));
                let two = splat(2.0);
                for $k in 1..=block_r {
                    let (a, b): (__m512, __m512) = $pair;
                    let below = splat(($k - 1) as f32);
                    g = _mm512_mul_ps(g, q);
                    q = _mm512_mul_ps(q, e2);
                    let gk = _mm512_maskz_mov_ps(
                        _mm512_cmp_ps_mask::<_CMP_LT_OQ>(below, three_sigma),
                        g,
                    );
                    acc = _mm512_add_ps(acc, _mm512_mul_ps(gk, _mm512_add_ps(a, b)));
                    norm = _mm512_add_ps(norm, _mm512_mul_ps(two, gk));
                }
                _mm512_div_ps(acc, norm)
            }
        }
    }};
}

/// [`super::avx2::load_y`] over the row's full blocks of 16; returns (any
/// of those pixels dark, pixels done).
#[target_feature(enable = "avx512f,avx2,fma")]
pub(super) fn load_y(
    ctx: &Ctx,
    src: &[[f32; 3]],
    lrow: &mut [f32],
    head: &mut [f32],
) -> (bool, usize) {
    let sh = Shuffles::new();
    let y_row = RGB_TO_XYZ[1];
    let inv_white = splat(1.0 / ctx.white);
    let (c0, c1, c2) = (splat(y_row[0]), splat(y_row[1]), splat(y_row[2]));
    let dark_below = splat(ctx.dark_below);
    let mut dark: __mmask16 = 0;
    let full = src.len() / W * W;
    for x in (0..full).step_by(W) {
        let [r, g, b] = sh.deinterleave(&src[x..x + W]);
        let y = _mm512_add_ps(
            _mm512_add_ps(_mm512_mul_ps(c0, r), _mm512_mul_ps(c1, g)),
            _mm512_mul_ps(c2, b),
        );
        let t = _mm512_mul_ps(y, inv_white);
        st(lrow, ctx.r + x, t);
        st(
            head,
            x,
            _mm512_mul_ps(_mm512_max_ps(_mm512_max_ps(r, g), b), inv_white),
        );
        dark |= _mm512_cmp_ps_mask::<_CMP_LT_OQ>(t, dark_below);
    }
    (dark != 0, full)
}

/// [`super::avx2::to_lightness`] over the row's full blocks of 16; returns
/// the pixels done.
#[target_feature(enable = "avx512f,avx2,fma")]
pub(super) fn to_lightness(ctx: &Ctx, lrow: &mut [f32]) -> usize {
    let full = ctx.stride_h / W * W;
    for x in (ctx.r..ctx.r + full).step_by(W) {
        let t = ld(lrow, x);
        st(lrow, x, lab_g(t));
    }
    full
}

/// [`super::avx2::horizontal`] over the row's full blocks of 16; returns
/// the pixels done.
#[target_feature(enable = "avx512f,avx2,fma")]
pub(super) fn horizontal(ctx: &Ctx, lrow: &[f32], hrow: &mut [f32]) -> usize {
    let r = ctx.r;
    let full = ctx.stride_h / W * W;
    for x0 in (0..full).step_by(W) {
        let x = r + x0;
        let v = gather!(ctx, ld(lrow, x), |k| (ld(lrow, x - k), ld(lrow, x + k)));
        st(hrow, x0, v);
    }
    full
}

/// [`super::avx2::vertical`] over the row's full blocks of 16; returns
/// (pixels whose lightness changed, pixels done).
#[target_feature(enable = "avx512f,avx2,fma")]
pub(super) fn vertical(
    ctx: &Ctx,
    band: &Band,
    up: &[usize],
    down: &[usize],
    y: usize,
    row: &mut [[f32; 3]],
) -> (usize, usize) {
    let sh = Shuffles::new();
    let Ctx { r, .. } = *ctx;
    let ring = 2 * r + 1;
    let stride_h = ctx.stride_h;
    let hor = &band.hor[..];
    let lrow = &band.lum[(y % ring) * ctx.stride_l + r..];
    let head_row = &band.head[(y % ring) * stride_h..];
    let wx = WHITE_XYZ.map(|c| c * ctx.white);
    let kappa = splat(LAB_KAPPA_F32);
    let shift_scale = splat(ctx.white / LAB_KAPPA_F32);
    let mut changed = 0;
    let full = row.len() / W * W;
    for x in (0..full).step_by(W) {
        let hv = ld(hor, up[0] + x);
        let l_new = gather!(ctx, hv, |k| (ld(hor, up[k] + x), ld(hor, down[k] + x)));
        let l_old = ld(lrow, x);
        let moved = _mm512_cmp_ps_mask::<_CMP_NEQ_UQ>(l_new, l_old);
        if moved == 0 {
            continue;
        }
        let d = _mm512_sub_ps(l_new, l_old);
        let head = ld(head_row, x);
        let bound = _mm512_add_ps(
            _mm512_mul_ps(head, kappa),
            _mm512_max_ps(d, _mm512_setzero_ps()),
        );
        let linear = _mm512_cmp_ps_mask::<_CMP_LE_OQ>(bound, splat(8.0));
        // Per half of 8 (the AVX2 and portable block): all linear?
        let (lo, hi) = (linear & 0x00ff == 0x00ff, linear & 0xff00 == 0xff00);
        let out = &mut row[x..x + W];
        let p = sh.deinterleave(out);
        let shifted = || {
            // RGB' = RGB + (white·Δ/κ)·(1, 1, 1), see the parent module.
            let shift = _mm512_mul_ps(d, shift_scale);
            p.map(|c| _mm512_add_ps(c, shift))
        };
        let converted = || {
            let xyz = mat3(&RGB_TO_XYZ, &p);
            let gx = lab_g(_mm512_div_ps(xyz[0], splat(wx[0])));
            let gz = lab_g(_mm512_div_ps(xyz[2], splat(wx[2])));
            let new = [
                _mm512_mul_ps(lab_g_inv(_mm512_add_ps(gx, d)), splat(wx[0])),
                _mm512_mul_ps(lab_g_inv(_mm512_add_ps(l_old, d)), splat(wx[1])),
                _mm512_mul_ps(lab_g_inv(_mm512_add_ps(gz, d)), splat(wx[2])),
            ];
            mat3(&XYZ_TO_RGB, &new)
        };
        let new = match (lo, hi) {
            (true, true) => shifted(),
            (false, false) => converted(),
            _ => {
                let (a, b) = (shifted(), converted());
                let half: __mmask16 = if lo { 0x00ff } else { 0xff00 };
                [0, 1, 2].map(|c| select(half, a[c], b[c]))
            }
        };
        let kept = [0, 1, 2].map(|c| select(moved, new[c], p[c]));
        sh.interleave(kept, out);
        changed += moved.count_ones() as usize;
    }
    (changed, full)
}

/// [`super::avx2::encode_affine`] over the row's full blocks of 16, the
/// table lookups as gathers; returns the pixels done.
#[target_feature(enable = "avx512f,avx2,fma")]
pub(crate) fn encode_affine(
    map: &Affine,
    lut: &SrgbLut,
    src: &[[f32; 3]],
    rgba8: &mut [u8],
) -> usize {
    const _: () = assert!(crate::encode::SRGB_LUT_PAD >= 3);
    let sh = Shuffles::new();
    let full = (src.len() / W * W).min(rgba8.len() / 4 / W * W);
    let m = map.m.map(|row| row.map(|v| splat(v)));
    let b = map.b.map(|v| splat(v));
    let zero = _mm512_setzero_ps();
    let (one, max) = (splat(1.0), splat(f32::MAX));
    let scale = splat((SRGB_LUT_SIZE - 1) as f32);
    let half = splat(0.5);
    let index_mask = _mm512_set1_epi32((SRGB_LUT_SIZE - 1) as i32);
    let byte = _mm512_set1_epi32(0xff);
    let alpha = _mm512_set1_epi32(0xff00_0000_u32 as i32);
    for x in (0..full).step_by(W) {
        // `max(p, 0)` (NaN → 0), then at most f32::MAX.
        let p = sh
            .deinterleave(&src[x..x + W])
            .map(|v| _mm512_min_ps(_mm512_max_ps(v, zero), max));
        let mut word = alpha;
        for (c, shift) in [0u32, 8, 16].into_iter().enumerate() {
            let v = _mm512_add_ps(
                _mm512_add_ps(
                    _mm512_add_ps(_mm512_mul_ps(m[c][0], p[0]), _mm512_mul_ps(m[c][1], p[1])),
                    _mm512_mul_ps(m[c][2], p[2]),
                ),
                b[c],
            );
            // crate::encode::lut_index, as in the AVX2 twin.
            let v = _mm512_min_ps(_mm512_max_ps(v, zero), one);
            let idx = _mm512_and_si512(
                _mm512_cvttps_epi32(_mm512_add_ps(_mm512_mul_ps(v, scale), half)),
                index_mask,
            );
            // SAFETY: every index is at most N − 1 (masked above) and the
            // table holds N + SRGB_LUT_PAD ≥ N + 3 bytes, so each 4-byte
            // read at byte offset `idx` lies inside it.
            let g = unsafe { _mm512_i32gather_epi32::<1>(idx, lut.as_ptr().cast()) };
            let g = _mm512_and_si512(g, byte);
            word = _mm512_or_si512(word, _mm512_sllv_epi32(g, _mm512_set1_epi32(shift as i32)));
        }
        let out = &mut rgba8[4 * x..4 * (x + W)];
        // SAFETY: `out` holds 64 bytes (checked by the slice above); the
        // store is unaligned.
        unsafe { _mm512_storeu_si512(out.as_mut_ptr().cast(), word) };
    }
    full
}

#[cfg(test)]
mod tests {
    use super::*;

    fn avx512() -> bool {
        super::super::has_avx512()
    }

    #[test]
    fn deinterleave_and_interleave_are_the_transposes() {
        if !avx512() {
            eprintln!("no AVX-512F on this CPU: nothing to check");
            return;
        }
        let px: Vec<[f32; 3]> = (0..16)
            .map(|i| [i as f32, 100.0 + i as f32, 200.0 + i as f32])
            .collect();
        // SAFETY: the CPU has AVX-512F, AVX2 and FMA (checked above).
        let sh = unsafe { Shuffles::new() };
        // SAFETY: as above.
        let planes = unsafe { sh.deinterleave(&px) };
        for (c, plane) in planes.iter().enumerate() {
            let mut v = [0.0f32; 16];
            // SAFETY: as above.
            unsafe { st(&mut v, 0, *plane) };
            assert_eq!(
                v,
                std::array::from_fn(|i| (100 * c + i) as f32),
                "plane {c}"
            );
        }
        let mut back = vec![[0.0f32; 3]; 16];
        // SAFETY: as above.
        unsafe { sh.interleave(planes, &mut back) };
        assert_eq!(back, px);
    }

    #[test]
    fn encode_matches_the_portable_twin_bit_for_bit() {
        if !avx512() {
            eprintln!("no AVX-512F on this CPU: nothing to check");
            return;
        }
        let lut = crate::encode::srgb_lut();
        let map = Affine {
            m: [[0.9, 0.05, 0.01], [0.02, 1.1, 0.03], [0.0, 0.07, 0.8]],
            b: [0.01, -0.02, 0.0],
        };
        // Every table index at least once: a ramp over [0, 1] and past it.
        let mut px: Vec<[f32; 3]> = (0..3 * SRGB_LUT_SIZE)
            .map(|i| {
                let v = i as f32 / (2 * SRGB_LUT_SIZE) as f32;
                [v, 1.1 * v, 0.7 * v]
            })
            .collect();
        px[5] = [f32::NAN, f32::INFINITY, f32::NEG_INFINITY];
        px[13] = [f32::MAX, 1e38, -0.0];
        px[21] = [-1.0, 1e-40, 0.5];
        px.truncate(px.len() - 5);
        let mut want = vec![0u8; 4 * px.len()];
        crate::encode::encode_row_portable(&map, &lut, &px, &mut want);
        let mut got = vec![0u8; 4 * px.len()];
        // SAFETY: the CPU has AVX-512F, AVX2 and FMA (checked above).
        let done = unsafe { encode_affine(&map, &lut, &px, &mut got) };
        assert_eq!(done, px.len() / 16 * 16);
        assert_eq!(got[..4 * done], want[..4 * done]);
    }
}
