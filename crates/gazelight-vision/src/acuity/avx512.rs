//! The band pass's per-row loops and the affine encoding with AVX-512
//! (F, and BW for the encoding): sixteen pixels a register.
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
//! The encoding looks the sRGB table up without gathers (slow on Zen 4):
//! the table is non-decreasing, so its entry at index i is the number of
//! codes c ≥ 1 whose first index is at most i, found by an 8-step
//! branchless binary search over those 255 thresholds
//! ([`crate::encode::SrgbThresholds`], derived from the table) on 32 u16
//! lanes at once, each step's threshold picked with word permutes from
//! eight registers. It needs AVX-512BW, and is built twice: for F + BW and
//! with VBMI2 as well ([`encode_affine_vbmi2`]). The tests check both
//! builds at every table index.
//!
//! Each function does the row's full blocks of 16 and returns where it
//! stopped; the caller hands the rest to the AVX2 twin. The band pass's
//! rows are `#[target_feature(enable = "avx512f,avx2,fma")]` and called
//! only after [`super::has_avx512`]; the encoding only after
//! [`super::has_avx512bw`] (or [`super::has_avx512vbmi2`] for its VBMI2
//! build).

use std::arch::x86_64::*;

use super::{
    AcuityBlur, Band, Ctx, LAB_KAPPA_F32, RGB_TO_XYZ, SigmaRule, WHITE_XYZ, XYZ_TO_RGB, map3,
};
use crate::encode::{Affine, SRGB_CODES, SRGB_LUT_SIZE, SrgbLut, SrgbThresholds};

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
        map3(self.de, |[i1, i2]| {
            _mm512_permutex2var_ps(_mm512_permutex2var_ps(a, i1, b), i2, c)
        })
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
    map3(*m, |row| {
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
    let wx = map3(WHITE_XYZ, |c| c * ctx.white);
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
            map3(p, |c| _mm512_add_ps(c, shift))
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
                map3([0, 1, 2], |c| select(half, a[c], b[c]))
            }
        };
        let kept = map3([0, 1, 2], |c| select(moved, new[c], p[c]));
        sh.interleave(kept, out);
        changed += moved.count_ones() as usize;
    }
    (changed, full)
}

/// Word indices that take the low halves of 32 dwords, those of the first
/// source then those of the second (lane j ← word 2j).
const LOW_WORDS: [u16; 2 * W] = {
    let mut v = [0u16; 2 * W];
    let mut j = 0;
    while j < 2 * W {
        v[j] = 2 * j as u16;
        j += 1;
    }
    v
};

/// Lane 2i ← `first + i`, lane 2i + 1 ← `second + i`: with the words
/// (r | g << 8) of 32 pixels as the first source and (b | α << 8) as the
/// second, `interleave(0, 32)` is the RGBA8 of pixels 0..16 and
/// `interleave(16, 48)` that of 16..32.
const fn interleave_words(first: u16, second: u16) -> [u16; 2 * W] {
    let mut v = [0u16; 2 * W];
    let mut i = 0;
    while i < W {
        v[2 * i] = first + i as u16;
        v[2 * i + 1] = second + i as u16;
        i += 1;
    }
    v
}

const RGBA_LOW: [u16; 2 * W] = interleave_words(0, 2 * W as u16);
const RGBA_HIGH: [u16; 2 * W] = interleave_words(W as u16, 3 * W as u16);

/// 32 u16s from `v` (unaligned).
#[inline]
#[target_feature(enable = "avx512f,avx2,fma")]
fn ld_u16(v: &[u16]) -> __m512i {
    let v = &v[..2 * W];
    // SAFETY: `v` holds exactly 32 u16s (64 bytes, checked by the slice
    // above); the load is unaligned.
    unsafe { _mm512_loadu_si512(v.as_ptr().cast()) }
}

/// The sRGB table as a branchless binary search over its thresholds
/// ([`SrgbThresholds`]), 32 u16 lanes at once, the nodes looked up with
/// word permutes instead of gathers: register r holds nodes 32r..32r + 32.
#[derive(Clone, Copy)]
struct Search {
    nodes: [__m512i; SRGB_CODES / (2 * W)],
    /// Node 1 in every lane.
    root: __m512i,
}

const _: () = assert!(SRGB_CODES == 256);

impl Search {
    #[inline]
    #[target_feature(enable = "avx512f,avx512bw,avx2,fma")]
    fn new(t: &SrgbThresholds) -> Self {
        let mut nodes = [_mm512_setzero_si512(); SRGB_CODES / (2 * W)];
        for (reg, chunk) in nodes.iter_mut().zip(t.0.chunks_exact(2 * W)) {
            *reg = ld_u16(chunk);
        }
        Self {
            nodes,
            // Thresholds are at most N < 2¹⁵.
            root: _mm512_set1_epi16(t.0[1] as i16),
        }
    }

    /// 256 + the table's entry at each of 32 u16 indices (below N). The
    /// steps are written out for 8 (256 codes in 8 registers).
    #[inline]
    #[target_feature(enable = "avx512f,avx512bw,avx2,fma")]
    fn codes(&self, idx: __m512i) -> __m512i {
        let n = &self.nodes;
        // !idx = −idx − 1: threshold + !idx < 0 ⇔ threshold ≤ idx, and the
        // sum of two values in [−2¹⁴ − 1, 2¹⁴] does not wrap.
        let not_idx = _mm512_ternarylogic_epi32::<0x55>(idx, idx, idx);
        // Node k → node 2k + (threshold ≤ idx), the comparison as the sign
        // bit of the sum (compares into masks and masked adds came out
        // slower: LLVM turns the add into three instructions).
        let step = |k: __m512i, threshold: __m512i| {
            let le = _mm512_srli_epi16::<15>(_mm512_add_epi16(threshold, not_idx));
            _mm512_add_epi16(_mm512_add_epi16(k, k), le)
        };
        // Depth 0: node 1.
        let mut k = step(_mm512_set1_epi16(1), self.root);
        // Depths 1–4: nodes 2..32 in register 0 (vpermw reads the low 5
        // bits of each index).
        for _ in 1..5 {
            k = step(k, _mm512_permutexvar_epi16(k, n[0]));
        }
        // Depth 5: nodes 32..64, the low 5 bits in register 1.
        k = step(k, _mm512_permutexvar_epi16(k, n[1]));
        // Depth 6: nodes 64..128, the low 6 bits in registers 2, 3.
        k = step(k, _mm512_permutex2var_epi16(n[2], k, n[3]));
        // Depth 7: nodes 128..256, the low 6 bits in registers 4, 5 (bit 6
        // clear) or 6, 7 (set).
        let below = _mm512_permutex2var_epi16(n[4], k, n[5]);
        let above = _mm512_permutex2var_epi16(n[6], k, n[7]);
        let upper = _mm512_test_epi16_mask(k, _mm512_set1_epi16(64));
        step(k, _mm512_mask_blend_epi16(upper, below, above))
    }
}

/// The per-row constants of the affine encoding and its steps.
#[derive(Clone, Copy)]
struct AffineEncoder {
    sh: Shuffles,
    search: Search,
    m: [[__m512; 3]; 3],
    b: [__m512; 3],
    low_words: __m512i,
    rgba_low: __m512i,
    rgba_high: __m512i,
}

impl AffineEncoder {
    #[inline]
    #[target_feature(enable = "avx512f,avx512bw,avx2,fma")]
    fn new(map: &Affine, lut: &SrgbLut) -> Self {
        Self {
            sh: Shuffles::new(),
            search: Search::new(lut.thresholds()),
            m: map3(map.m, |row| map3(row, |v| splat(v))),
            b: map3(map.b, |v| splat(v)),
            low_words: ld_u16(&LOW_WORDS),
            rgba_low: ld_u16(&RGBA_LOW),
            rgba_high: ld_u16(&RGBA_HIGH),
        }
    }

    /// The table indices of 16 pixels, per channel as i32 lanes. (No
    /// closures here or in [`Self::words`]: LLVM left `[_; 3].map`'s
    /// closures out of line, as calls taking their registers through
    /// memory and compiled without VBMI2, a fifth of the night frame.)
    #[inline]
    #[target_feature(enable = "avx512f,avx512bw,avx2,fma")]
    fn indices(&self, px: &[[f32; 3]]) -> [__m512i; 3] {
        let [r, g, b] = self.sh.deinterleave(px);
        // `max(p, 0)` (NaN → 0), then at most f32::MAX.
        let p = [clamp_finite(r), clamp_finite(g), clamp_finite(b)];
        [self.index(&p, 0), self.index(&p, 1), self.index(&p, 2)]
    }

    /// Channel `c`'s table indices of the clamped pixels `p`.
    #[inline]
    #[target_feature(enable = "avx512f,avx512bw,avx2,fma")]
    fn index(&self, p: &[__m512; 3], c: usize) -> __m512i {
        let (m, b) = (&self.m[c], self.b[c]);
        let zero = _mm512_setzero_ps();
        let v = _mm512_add_ps(
            _mm512_add_ps(
                _mm512_add_ps(_mm512_mul_ps(m[0], p[0]), _mm512_mul_ps(m[1], p[1])),
                _mm512_mul_ps(m[2], p[2]),
            ),
            b,
        );
        // crate::encode::lut_index, as in the AVX2 twin: in 0..N, so the
        // low word of each lane is the index.
        let v = _mm512_min_ps(_mm512_max_ps(v, zero), splat(1.0));
        _mm512_cvttps_epi32(_mm512_add_ps(
            _mm512_mul_ps(v, splat((SRGB_LUT_SIZE - 1) as f32)),
            splat(0.5),
        ))
    }

    /// The RGBA8 words of two blocks of 16 pixels from their table
    /// indices.
    #[inline]
    #[target_feature(enable = "avx512f,avx512bw,avx2,fma")]
    fn words(&self, first: [__m512i; 3], second: [__m512i; 3]) -> [__m512i; 2] {
        let lw = self.low_words;
        let r = self
            .search
            .codes(_mm512_permutex2var_epi16(first[0], lw, second[0]));
        let g = self
            .search
            .codes(_mm512_permutex2var_epi16(first[1], lw, second[1]));
        let b = self
            .search
            .codes(_mm512_permutex2var_epi16(first[2], lw, second[2]));
        // Codes are 256 + entry: (r & 0xff) | g << 8 (the shift drops bit 8)
        // and (b & 0xff) | α << 8, each as `x | (y & z)`.
        let low_byte = _mm512_set1_epi16(0xff);
        let alpha = _mm512_set1_epi16(0xff00_u16 as i16);
        let rg = _mm512_ternarylogic_epi32::<0xf8>(_mm512_slli_epi16::<8>(g), r, low_byte);
        let ba = _mm512_ternarylogic_epi32::<0xf8>(alpha, b, low_byte);
        [
            _mm512_permutex2var_epi16(rg, self.rgba_low, ba),
            _mm512_permutex2var_epi16(rg, self.rgba_high, ba),
        ]
    }
}

/// `min(max(v, 0), f32::MAX)` per lane (NaN → 0).
#[inline]
#[target_feature(enable = "avx512f,avx2,fma")]
fn clamp_finite(v: __m512) -> __m512 {
    _mm512_min_ps(_mm512_max_ps(v, _mm512_setzero_ps()), splat(f32::MAX))
}

/// Stores the RGBA8 words of 16 pixels to `rgba8[4x..4(x + 16)]`
/// (bounds-checked).
#[inline]
#[target_feature(enable = "avx512f,avx2,fma")]
fn st_rgba8(rgba8: &mut [u8], x: usize, words: __m512i) {
    let out = &mut rgba8[4 * x..4 * (x + W)];
    // SAFETY: `out` holds 64 bytes (checked by the slice above); the store
    // is unaligned.
    unsafe { _mm512_storeu_si512(out.as_mut_ptr().cast(), words) };
}

/// Defines [`encode_affine`] and [`encode_affine_vbmi2`]: one body (its
/// steps inlined), compiled for two feature sets.
macro_rules! encode_affine {
    ($(#[$doc:meta])* $name:ident, $features:literal) => {
        $(#[$doc])*
        #[target_feature(enable = $features)]
        pub(crate) fn $name(
            map: &Affine,
            lut: &SrgbLut,
            src: &[[f32; 3]],
            rgba8: &mut [u8],
        ) -> usize {
            let enc = AffineEncoder::new(map, lut);
            let full = (src.len() / W * W).min(rgba8.len() / 4 / W * W);
            let pairs = full / (2 * W) * 2 * W;
            for x in (0..pairs).step_by(2 * W) {
                let first = enc.indices(&src[x..x + W]);
                let second = enc.indices(&src[x + W..x + 2 * W]);
                let [lo, hi] = enc.words(first, second);
                st_rgba8(rgba8, x, lo);
                st_rgba8(rgba8, x + W, hi);
            }
            if pairs < full {
                // The last block alone: searched twice, stored once.
                let last = enc.indices(&src[pairs..full]);
                st_rgba8(rgba8, pairs, enc.words(last, last)[0]);
            }
            full
        }
    };
}

encode_affine!(
    /// [`super::avx2::encode_affine`] over the row's full blocks of 16, two
    /// at a time (the 96 table indices of 32 pixels fill three registers of
    /// u16s), the table lookups as a binary search over its thresholds
    /// ([`Search`]); returns the pixels done.
    encode_affine,
    "avx512f,avx512bw,avx2,fma"
);

encode_affine!(
    /// [`encode_affine`] compiled with AVX-512 VBMI2 as well, the same
    /// operations: LLVM fuses each search step's `2k + (sign bit)` into one
    /// `vpshldw` (a 1440 × 1600 frame's encoding on Zen 4, alone: about 3.9
    /// → 3.2 ms; 4.4 ms with gathers).
    encode_affine_vbmi2,
    "avx512f,avx512bw,avx512vbmi2,avx2,fma"
);

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

    /// Indices in 0..N where the vector search over `t` differs from the
    /// table.
    ///
    /// # Safety
    /// The CPU has AVX-512F and BW, AVX2 and FMA.
    #[target_feature(enable = "avx512f,avx512bw,avx2,fma")]
    fn search_misses(lut: &SrgbLut, t: &SrgbThresholds) -> Vec<usize> {
        let search = Search::new(t);
        let all: Vec<u16> = (0..SRGB_LUT_SIZE as u16).collect();
        let mut miss = Vec::new();
        for (c, chunk) in all.chunks_exact(2 * W).enumerate() {
            // SAFETY: `chunk` holds 32 u16s; the load is unaligned.
            let idx = unsafe { _mm512_loadu_si512(chunk.as_ptr().cast()) };
            let mut codes = [0u16; 2 * W];
            // SAFETY: `codes` holds 32 u16s; the store is unaligned.
            unsafe { _mm512_storeu_si512(codes.as_mut_ptr().cast(), search.codes(idx)) };
            for (j, code) in codes.into_iter().enumerate() {
                let i = 2 * W * c + j;
                if usize::from(code) != SRGB_CODES + usize::from(lut[i]) {
                    miss.push(i);
                }
            }
        }
        miss
    }

    #[test]
    fn threshold_search_gives_the_table_at_every_index() {
        if !super::super::has_avx512bw() {
            eprintln!("no AVX-512BW on this CPU: nothing to check");
            return;
        }
        let lut = crate::encode::srgb_lut();
        // SAFETY: the CPU has AVX-512F and BW, AVX2 and FMA (checked above).
        assert_eq!(unsafe { search_misses(&lut, lut.thresholds()) }, []);
        // Each node matters: one threshold off by one misses an index.
        for k in 1..SRGB_CODES {
            let mut t = *lut.thresholds();
            t.0[k] += 1;
            // SAFETY: as above.
            assert_ne!(unsafe { search_misses(&lut, &t) }, [], "node {k}");
        }
    }

    /// An [`encode_affine`] build.
    type Encode = unsafe fn(&Affine, &SrgbLut, &[[f32; 3]], &mut [u8]) -> usize;

    /// The builds of [`encode_affine`] this CPU runs, by name.
    fn encoders() -> Vec<(&'static str, Encode)> {
        let mut builds: Vec<(&'static str, Encode)> = Vec::new();
        if super::super::has_avx512bw() {
            builds.push(("F+BW", encode_affine));
        } else {
            eprintln!("no AVX-512BW on this CPU: nothing to check");
        }
        if super::super::has_avx512vbmi2() {
            builds.push(("F+BW+VBMI2", encode_affine_vbmi2));
        } else {
            eprintln!("no AVX-512 VBMI2 on this CPU: its build is not checked");
        }
        builds
    }

    #[test]
    fn encode_gives_the_table_at_every_index() {
        let lut = crate::encode::srgb_lut();
        let n = SRGB_LUT_SIZE;
        // Pixel i holds table indices i, i + N/3, i + 2N/3 (mod N), each as
        // the value the table was built from.
        let idx = |i: usize| [i, (i + n / 3) % n, (i + 2 * n / 3) % n];
        let px: Vec<[f32; 3]> = (0..n)
            .map(|i| idx(i).map(|k| k as f32 / (n - 1) as f32))
            .collect();
        for (p, i) in px.iter().zip(0..) {
            assert_eq!(p.map(crate::encode::lut_index), idx(i));
        }
        for (name, encode) in encoders() {
            let mut got = vec![0u8; 4 * n];
            // SAFETY: the CPU has what the build needs (checked by
            // `encoders`).
            let done = unsafe { encode(&crate::encode::IDENTITY, &lut, &px, &mut got) };
            assert_eq!(done, n, "{name}");
            let miss = (0..n).find(|&i| {
                let [r, g, b] = idx(i).map(|k| lut[k]);
                got[4 * i..4 * i + 4] != [r, g, b, 255]
            });
            assert_eq!(miss, None, "{name}: first pixel off the table");
        }
    }

    #[test]
    fn encode_matches_the_portable_twin_bit_for_bit() {
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
        for (name, encode) in encoders() {
            // Odd and even numbers of blocks of 16, and a tail.
            for n in [0, 15, 16, 31, 32, 48, 50, 64, px.len()] {
                let mut got = vec![0u8; 4 * n];
                // SAFETY: the CPU has what the build needs (checked by
                // `encoders`).
                let done = unsafe { encode(&map, &lut, &px[..n], &mut got) };
                assert_eq!(done, n / 16 * 16, "{name}");
                let differ = (0..4 * done).find(|&i| got[i] != want[i]);
                assert_eq!(differ, None, "{name}, {n} pixels: first differing byte");
            }
        }
    }
}
