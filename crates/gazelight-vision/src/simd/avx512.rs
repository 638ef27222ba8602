//! AVX-512 (F, and BW for the encoding): the vector primitives of 16
//! lanes and the kernels that use them.
//!
//! The primitives carry the same names as in [`super::avx2`] (see there),
//! so that the band engine's row loops are written once for both widths
//! (`band::kernels`). A mask here is a `__mmask16`, one bit per lane.
//! Blocks of 16 instead of 8 change nothing a pixel sees (see
//! `band::kernels` for the row loops).
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
//! Each kernel does the row's full blocks of 16 and returns where it
//! stopped; the caller hands the rest to the AVX2 twin. The primitives are
//! `#[target_feature(enable = "avx512f,avx2,fma")]`, the encoding adds BW
//! (and VBMI2); all are called only behind a [`super::Simd`] of at least
//! [`super::Tier::Avx512`] (F + BW), or [`super::Tier::Avx512Vbmi2`] for
//! the VBMI2 build.

use std::arch::x86_64::*;

use super::map3;
use crate::encode::{Affine, SRGB_CODES, SRGB_LUT_SIZE, SrgbLut, SrgbThresholds};

/// Lanes of one register.
pub(crate) const W: usize = 16;

/// The vector of `W` f32 lanes.
pub(crate) type V = __m512;

/// A lane mask, one bit per lane.
pub(crate) type M = __mmask16;

/// The vector of `W` i32 lanes.
pub(crate) type I = __m512i;

/// Sixteen lanes from `s[at..at + 16]` (bounds-checked).
#[inline]
#[target_feature(enable = "avx512f,avx2,fma")]
pub(crate) fn ld(s: &[f32], at: usize) -> V {
    let s = &s[at..at + W];
    // SAFETY: `s` holds exactly 16 f32s (checked by the slice above); the
    // load is unaligned.
    unsafe { _mm512_loadu_ps(s.as_ptr()) }
}

/// Stores sixteen lanes to `d[at..at + 16]` (bounds-checked).
#[inline]
#[target_feature(enable = "avx512f,avx2,fma")]
pub(crate) fn st(d: &mut [f32], at: usize, v: V) {
    let d = &mut d[at..at + W];
    // SAFETY: `d` holds exactly 16 f32s (checked by the slice above).
    unsafe { _mm512_storeu_ps(d.as_mut_ptr(), v) }
}

/// Broadcast.
#[inline]
#[target_feature(enable = "avx512f,avx2,fma")]
pub(crate) fn splat(v: f32) -> V {
    _mm512_set1_ps(v)
}

/// All lanes 0.
#[inline]
#[target_feature(enable = "avx512f,avx2,fma")]
pub(crate) fn zero() -> V {
    _mm512_setzero_ps()
}

/// Defines the lane-wise binary operations `$name(a, b)` as `$op`.
macro_rules! binary {
    ($($(#[$doc:meta])* $name:ident => $op:ident;)*) => {$(
        $(#[$doc])*
        #[inline]
        #[target_feature(enable = "avx512f,avx2,fma")]
        pub(crate) fn $name(a: V, b: V) -> V {
            $op(a, b)
        }
    )*};
}

binary! {
    /// `a + b`.
    add => _mm512_add_ps;
    /// `a − b`.
    sub => _mm512_sub_ps;
    /// `a · b`.
    mul => _mm512_mul_ps;
    /// `a / b`.
    div => _mm512_div_ps;
    /// `minps` (`b` where either is NaN).
    min => _mm512_min_ps;
    /// `maxps` (`b` where either is NaN).
    max => _mm512_max_ps;
}

/// Defines the comparisons `$name(a, b)` into masks with predicate `$p`.
macro_rules! compare {
    ($($(#[$doc:meta])* $name:ident => $p:ident;)*) => {$(
        $(#[$doc])*
        #[inline]
        #[target_feature(enable = "avx512f,avx2,fma")]
        pub(crate) fn $name(a: V, b: V) -> M {
            _mm512_cmp_ps_mask::<$p>(a, b)
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
#[target_feature(enable = "avx512f,avx2,fma")]
pub(crate) fn select(mask: M, a: V, b: V) -> V {
    _mm512_mask_blend_ps(mask, b, a)
}

/// `if mask { v } else { 0 }` per lane.
#[inline]
#[target_feature(enable = "avx512f,avx2,fma")]
pub(crate) fn keep(mask: M, v: V) -> V {
    _mm512_maskz_mov_ps(mask, v)
}

/// The mask of no lane.
#[inline]
#[target_feature(enable = "avx512f,avx2,fma")]
pub(crate) fn no_lanes() -> M {
    0
}

/// The lanes of either mask.
#[inline]
#[target_feature(enable = "avx512f,avx2,fma")]
pub(crate) fn either(a: M, b: M) -> M {
    a | b
}

/// Whether the mask holds no lane.
#[inline]
#[target_feature(enable = "avx512f,avx2,fma")]
pub(crate) fn none(mask: M) -> bool {
    mask == 0
}

/// The lanes the mask holds.
#[inline]
#[target_feature(enable = "avx512f,avx2,fma")]
pub(crate) fn count(mask: M) -> u32 {
    mask.count_ones()
}

/// The bits of each lane as an integer.
#[inline]
#[target_feature(enable = "avx512f,avx2,fma")]
pub(crate) fn bits(v: V) -> I {
    _mm512_castps_si512(v)
}

/// The lanes whose bits are `i`.
#[inline]
#[target_feature(enable = "avx512f,avx2,fma")]
pub(crate) fn from_bits(i: I) -> V {
    _mm512_castsi512_ps(i)
}

/// Integer broadcast.
#[inline]
#[target_feature(enable = "avx512f,avx2,fma")]
pub(crate) fn splat_i(v: i32) -> I {
    _mm512_set1_epi32(v)
}

/// Integer `a + b` (wrapping).
#[inline]
#[target_feature(enable = "avx512f,avx2,fma")]
pub(crate) fn add_i(a: I, b: I) -> I {
    _mm512_add_epi32(a, b)
}

/// Integer `a − b` (wrapping).
#[inline]
#[target_feature(enable = "avx512f,avx2,fma")]
pub(crate) fn sub_i(a: I, b: I) -> I {
    _mm512_sub_epi32(a, b)
}

/// Integer `a << 23` (into the exponent field).
#[inline]
#[target_feature(enable = "avx512f,avx2,fma")]
pub(crate) fn shl_23(a: I) -> I {
    _mm512_slli_epi32::<23>(a)
}

/// `a / 3` of each lane as an unsigned integer: a multiply by ⌈2³³/3⌉
/// and a shift, exact for every u32, on the even and the odd lanes.
#[inline]
#[target_feature(enable = "avx512f,avx2,fma")]
pub(crate) fn div3_u32(a: I) -> I {
    let magic = _mm512_set1_epi64(0xAAAA_AAAB);
    let even = _mm512_srli_epi64::<33>(_mm512_mul_epu32(a, magic));
    let odd = _mm512_slli_epi64::<32>(_mm512_srli_epi64::<33>(_mm512_mul_epu32(
        _mm512_srli_epi64::<32>(a),
        magic,
    )));
    _mm512_mask_blend_epi32(0xAAAA, even, odd)
}

/// The largest of the sixteen lanes (none NaN).
#[inline]
#[target_feature(enable = "avx512f,avx2,fma")]
pub(crate) fn hmax(v: V) -> f32 {
    _mm512_reduce_max_ps(v)
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
pub(crate) struct Shuffles {
    de: [[__m512i; 2]; 3],
    inter: [[__m512i; 2]; 3],
}

impl Shuffles {
    #[inline]
    #[target_feature(enable = "avx512f,avx2,fma")]
    pub(crate) fn new() -> Self {
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
    pub(crate) fn deinterleave(&self, px: &[[f32; 3]]) -> [V; 3] {
        let f = &px.as_flattened()[..3 * W];
        let (a, b, c) = (ld(f, 0), ld(f, W), ld(f, 2 * W));
        map3(self.de, |[i1, i2]| {
            _mm512_permutex2var_ps(_mm512_permutex2var_ps(a, i1, b), i2, c)
        })
    }

    /// Inverse of [`Self::deinterleave`]: writes 16 RGB pixels.
    #[inline]
    #[target_feature(enable = "avx512f,avx2,fma")]
    pub(crate) fn interleave(&self, c: [V; 3], px: &mut [[f32; 3]]) {
        let [x, y, z] = c;
        let f = &mut px.as_flattened_mut()[..3 * W];
        for (reg, [i1, i2]) in self.inter.iter().enumerate() {
            let v = _mm512_permutex2var_ps(_mm512_permutex2var_ps(x, *i1, y), *i2, z);
            st(f, reg * W, v);
        }
    }
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
    use crate::simd::Tier;

    /// Whether the test `test` runs here (see [`crate::simd::testing`]).
    fn avx512(test: &str) -> bool {
        crate::simd::testing::runs(test, Tier::Avx512)
    }

    #[test]
    fn deinterleave_and_interleave_are_the_transposes() {
        if !avx512("deinterleave_and_interleave_are_the_transposes") {
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
        if !avx512("threshold_search_gives_the_table_at_every_index") {
            return;
        }
        let lut = crate::encode::srgb_lut();
        // SAFETY: the CPU has AVX-512F and BW, AVX2 and FMA (checked above).
        let misses = unsafe { search_misses(&lut, lut.thresholds()) };
        assert_eq!(misses, Vec::<usize>::new());
        // Each node matters: one threshold off by one misses an index.
        for k in 1..SRGB_CODES {
            let mut t = *lut.thresholds();
            t.0[k] += 1;
            // SAFETY: as above.
            let misses = unsafe { search_misses(&lut, &t) };
            assert_ne!(misses, Vec::<usize>::new(), "node {k}");
        }
    }

    /// An [`encode_affine`] build.
    type Encode = unsafe fn(&Affine, &SrgbLut, &[[f32; 3]], &mut [u8]) -> usize;

    /// The builds of [`encode_affine`] this CPU runs, by name.
    fn encoders(test: &str) -> Vec<(&'static str, Encode)> {
        let mut builds: Vec<(&'static str, Encode)> = Vec::new();
        if avx512(test) {
            builds.push(("F+BW", encode_affine));
        }
        if crate::simd::testing::runs(test, Tier::Avx512Vbmi2) {
            builds.push(("F+BW+VBMI2", encode_affine_vbmi2));
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
        for (name, encode) in encoders("encode_gives_the_table_at_every_index") {
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
        for (name, encode) in encoders("encode_matches_the_portable_twin_bit_for_bit") {
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
