//! Stages 6–8 on one row at a time: tone reproduction and the colour
//! model, specialised once per frame into one map, then sRGB encoding.
//!
//! The frame pipeline runs these as the sink of the acuity pass
//! ([`crate::band::AcuityBlur`]): each row is tone mapped, coloured and
//! encoded right after its blur is final, while it is still in cache, so
//! the frame is read from memory once for stages 5–8.
//!
//! The colour model is linear in the colour
//! ([`crate::colour::ColourFrame::matrix`]); a linear tone operator
//! (Ward/Ferwerda) folds with it into one affine map
//! `M·(scale·c + offset) = (scale·M)·c + M·offset`. The maps work on
//! [`LANES`] pixels at a time as channel planes, with fixed trip counts
//! and selects instead of branches, so that the compiler vectorises them.

use crate::band::RowSink;
use crate::colour::ColourFrame;
use crate::simd::{LANES, Simd};
use crate::tone::{self, Op as ToneOp, ToneFrame};

/// Size of the sRGB encoding table over linear [0, 1] (a power of two:
/// [`lut_index`] masks with `N − 1`). Defined here only: the GPU's table
/// (`gazelight-gpu`'s `frame.rs`) takes it from here, and the WGSL twin in
/// `shaders/frame_state.wgsl` is checked against it
/// (`tests/tests/rules_once.rs`).
pub const SRGB_LUT_SIZE: usize = 16384;
const _: () = assert!(SRGB_LUT_SIZE.is_power_of_two());

/// Bits of the sRGB table's output codes.
pub(crate) const SRGB_CODE_BITS: u32 = 8;

/// Output codes of the sRGB table.
pub(crate) const SRGB_CODES: usize = 1 << SRGB_CODE_BITS;

/// The sRGB encoding table: entry `i < N` is the 8-bit code of linear
/// `i / (N − 1)`; beside it, the same table as thresholds for lookups
/// without gathers ([`SrgbThresholds`]).
pub(crate) struct SrgbLut {
    codes: [u8; SRGB_LUT_SIZE],
    thresholds: SrgbThresholds,
}

/// The sRGB table as thresholds: `first(c)` = the smallest index whose
/// entry is at least `c` (N when none is), so that, the table being
/// non-decreasing, `lut[i] = #{c in 1..=255 : first(c) ≤ i}`, the largest
/// `c` with `first(c) ≤ i` (`first(0)` = 0). Stored in the order of an
/// 8-step binary search for that `c` (Eytzinger's): node `k` in 1..256 at
/// depth `s = ⌊log₂ k⌋`, `k = 2^s + p`, holds `first((2p + 1)·2^(7−s))`;
/// starting at `k = 1`, each step goes to `2k + (node ≤ i)`, and after 8
/// steps `k − 256` is the code. Node 0 is unused. Aligned to 64 bytes:
/// each of the eight registers of 32 u16s the AVX-512 search loads is one
/// cache line.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
#[repr(C, align(64))]
pub(crate) struct SrgbThresholds(pub(crate) [u16; SRGB_CODES]);

const _: () = assert!(SRGB_LUT_SIZE <= u16::MAX as usize);

impl SrgbLut {
    /// The table's thresholds.
    #[inline(always)]
    pub(crate) fn thresholds(&self) -> &SrgbThresholds {
        &self.thresholds
    }
}

impl std::ops::Index<usize> for SrgbLut {
    type Output = u8;
    #[inline(always)]
    fn index(&self, i: usize) -> &u8 {
        &self.codes[i]
    }
}

impl SrgbThresholds {
    /// The thresholds of `codes`, which must be non-decreasing for the
    /// search to give its entries (the tests check every index).
    fn of(codes: &[u8; SRGB_LUT_SIZE]) -> Self {
        // first[c]: the table is sorted, so the entries below c come first.
        let first = |c: usize| codes.partition_point(|&v| usize::from(v) < c) as u16;
        let mut nodes = [0u16; SRGB_CODES];
        for (k, node) in nodes.iter_mut().enumerate().skip(1) {
            let depth = k.ilog2();
            let p = k - (1 << depth);
            *node = first((2 * p + 1) << (SRGB_CODE_BITS - 1 - depth));
        }
        Self(nodes)
    }
}

/// Builds the table from [`crate::pipeline::srgb_encode`], and its
/// thresholds from the table.
pub(crate) fn srgb_lut() -> Box<SrgbLut> {
    let mut codes = [0u8; SRGB_LUT_SIZE];
    for (i, v) in codes.iter_mut().enumerate() {
        *v = (crate::pipeline::srgb_encode(i as f32 / (SRGB_LUT_SIZE - 1) as f32) * 255.0).round()
            as u8;
    }
    let thresholds = SrgbThresholds::of(&codes);
    Box::new(SrgbLut { codes, thresholds })
}

/// Channel planes of `LANES` pixels.
pub(crate) type Planes = [[f32; LANES]; 3];

/// Stages 6 + 7 for `LANES` pixels at once.
pub(crate) trait Map: Copy + Sync {
    /// Display-relative linear colour (unclamped) of each pixel.
    fn block(&self, src: &[[f32; 3]; LANES]) -> Planes;

    /// Encodes a leading part of the row with a twin of
    /// [`encode_row_portable`] for `simd`'s tier (the same bits) where the
    /// map has one; returns how many pixels it did.
    #[inline(always)]
    fn encode_fast(
        &self,
        _simd: Simd,
        _lut: &SrgbLut,
        _src: &[[f32; 3]],
        _rgba8: &mut [u8],
    ) -> usize {
        0
    }
}

/// A linear tone operator folded with the colour matrix.
#[derive(Clone, Copy, Debug)]
pub(crate) struct Affine {
    pub m: [[f32; 3]; 3],
    pub b: [f32; 3],
}

/// Naka–Rushton, then the colour matrix.
#[derive(Clone, Copy, Debug)]
pub(crate) struct NakaRushton {
    s: f32,
    saturation: f32,
    m: [[f32; 3]; 3],
}

/// The gaze exposure window, then the colour matrix.
#[derive(Clone, Copy, Debug)]
pub(crate) struct Window {
    lo: f32,
    inv_range: f32,
    gamma: f32,
    m: [[f32; 3]; 3],
}

/// The frame's map, one variant per operator.
#[derive(Clone, Copy, Debug)]
pub(crate) enum PixelMap {
    Affine(Affine),
    NakaRushton(NakaRushton),
    Window(Window),
}

impl PixelMap {
    pub(crate) fn new(tone: &ToneFrame, colour: &ColourFrame) -> Self {
        let m = colour.matrix();
        match tone.op() {
            ToneOp::Linear { scale, offset } => {
                let mut ms = m;
                let mut b = [0.0f32; 3];
                for (row, bi) in ms.iter_mut().zip(&mut b) {
                    *bi = (row[0] + row[1] + row[2]) * offset;
                    for v in row.iter_mut() {
                        *v *= scale;
                    }
                }
                Self::Affine(Affine { m: ms, b })
            }
            ToneOp::NakaRushton { s, saturation } => {
                Self::NakaRushton(NakaRushton { s, saturation, m })
            }
            ToneOp::Window {
                lo,
                inv_range,
                gamma,
            } => Self::Window(Window {
                lo,
                inv_range,
                gamma,
                m,
            }),
        }
    }
}

/// The identity map (display-linear → encoded, for the kept frame).
pub(crate) const IDENTITY: Affine = Affine {
    m: [[1.0, 0.0, 0.0], [0.0, 1.0, 0.0], [0.0, 0.0, 1.0]],
    b: [0.0; 3],
};

impl Map for Affine {
    #[inline(always)]
    fn encode_fast(&self, simd: Simd, lut: &SrgbLut, src: &[[f32; 3]], rgba8: &mut [u8]) -> usize {
        #[cfg(target_arch = "x86_64")]
        {
            use crate::simd::{Tier, avx2, avx512};
            if simd.has(Tier::Avx2) {
                let from = if simd.has(Tier::Avx512Vbmi2) {
                    // SAFETY: a `Simd` of this tier proves AVX-512F, BW and
                    // VBMI2, AVX2 and FMA.
                    unsafe { avx512::encode_affine_vbmi2(self, lut, src, rgba8) }
                } else if simd.has(Tier::Avx512) {
                    // SAFETY: a `Simd` of this tier proves AVX-512F and BW,
                    // AVX2 and FMA.
                    unsafe { avx512::encode_affine(self, lut, src, rgba8) }
                } else {
                    0
                };
                // SAFETY: a `Simd` of this tier proves AVX2 and FMA.
                return from
                    + unsafe {
                        avx2::encode_affine(self, lut, &src[from..], &mut rgba8[4 * from..])
                    };
            }
        }
        let _ = (simd, lut, src, rgba8);
        0
    }

    /// `m·max(p, 0) + b`.
    #[inline(always)]
    fn block(&self, src: &[[f32; 3]; LANES]) -> Planes {
        let mut planes = crate::simd::planes_full(src);
        for plane in &mut planes {
            for v in plane.iter_mut() {
                // Pass A already replaced NaN, ±∞, negatives and
                // subnormals; what glare adds is finite but may be slightly
                // negative (FFT round-off). Plain selects vectorise; the
                // class tests of `sanitize` would not.
                *v = (if *v > 0.0 { *v } else { 0.0 }).min(f32::MAX);
            }
        }
        let mut out = [[0.0f32; LANES]; 3];
        #[allow(clippy::needless_range_loop)]
        // c indexes the matrix row, the output and the bias together
        for c in 0..3 {
            let row = self.m[c];
            for i in 0..LANES {
                out[c][i] = row[0] * planes[0][i]
                    + row[1] * planes[1][i]
                    + row[2] * planes[2][i]
                    + self.b[c];
            }
        }
        out
    }
}

#[inline(always)]
fn mat_mul(m: &[[f32; 3]; 3], c: [f32; 3]) -> [f32; 3] {
    [
        m[0][0] * c[0] + m[0][1] * c[1] + m[0][2] * c[2],
        m[1][0] * c[0] + m[1][1] * c[1] + m[1][2] * c[2],
        m[2][0] * c[0] + m[2][1] * c[1] + m[2][2] * c[2],
    ]
}

/// Per pixel `f`, gathered into planes.
#[inline(always)]
fn per_pixel(src: &[[f32; 3]; LANES], f: impl Fn([f32; 3]) -> [f32; 3]) -> Planes {
    let mut out = [[0.0f32; LANES]; 3];
    for (i, s) in src.iter().enumerate() {
        let c = f(*s);
        out[0][i] = c[0];
        out[1][i] = c[1];
        out[2][i] = c[2];
    }
    out
}

impl Map for NakaRushton {
    #[inline(always)]
    fn block(&self, src: &[[f32; 3]; LANES]) -> Planes {
        per_pixel(
            src,
            #[inline(always)]
            |c| {
                mat_mul(
                    &self.m,
                    tone::naka_rushton(c.map(tone::clean), self.s, self.saturation),
                )
            },
        )
    }
}

impl Map for Window {
    #[inline(always)]
    fn block(&self, src: &[[f32; 3]; LANES]) -> Planes {
        per_pixel(
            src,
            #[inline(always)]
            |c| {
                mat_mul(
                    &self.m,
                    tone::window(c.map(tone::clean), self.lo, self.inv_range, self.gamma),
                )
            },
        )
    }
}

/// Runs `f` over `LANES` pixels of `src` at a time; a short tail is
/// padded with black and only its own outputs are written.
#[inline(always)]
fn for_blocks<T, const K: usize>(
    src: &[[f32; 3]],
    dst: &mut [T],
    f: impl Fn(&[[f32; 3]; LANES], &mut [T; K]),
) where
    T: Copy + Default,
{
    let mut s_blocks = src.chunks_exact(LANES);
    let mut d_blocks = dst.chunks_exact_mut(K);
    for (s, d) in (&mut s_blocks).zip(&mut d_blocks) {
        if let (Ok(s), Ok(d)) = (
            <&[[f32; 3]; LANES]>::try_from(s),
            <&mut [T; K]>::try_from(d),
        ) {
            f(s, d);
        }
    }
    let tail = s_blocks.remainder();
    if !tail.is_empty() {
        let mut s = [[0.0f32; 3]; LANES];
        s[..tail.len()].copy_from_slice(tail);
        let mut d = [T::default(); K];
        f(&s, &mut d);
        let out = d_blocks.into_remainder();
        let n = out.len();
        out.copy_from_slice(&d[..n]);
    }
}

/// Sink: the sRGB-encoded RGBA8 row of `map`.
pub(crate) struct EncodeRgba8<'a, M> {
    pub map: M,
    pub lut: &'a SrgbLut,
    pub width: usize,
    /// The tier the encoding runs on.
    pub simd: Simd,
}

impl<M: Map> RowSink for EncodeRgba8<'_, M> {
    type Out = u8;
    fn per_row(&self) -> usize {
        4 * self.width
    }
    #[inline(always)]
    fn row(&self, _: usize, px: &[[f32; 3]], out: &mut [u8]) {
        encode_row(self.simd, &self.map, self.lut, px, out);
    }
}

/// `rgba8` = sRGB encoding of `map` of every pixel of `src`, with the
/// kernels of `simd`'s tier where the map has them.
#[inline(always)]
pub(crate) fn encode_row<M: Map>(
    simd: Simd,
    map: &M,
    lut: &SrgbLut,
    src: &[[f32; 3]],
    rgba8: &mut [u8],
) {
    let done = map.encode_fast(simd, lut, src, rgba8);
    encode_row_portable(map, lut, &src[done..], &mut rgba8[4 * done..]);
}

/// [`encode_row`] with the portable loops only.
#[inline(always)]
pub(crate) fn encode_row_portable<M: Map>(
    map: &M,
    lut: &SrgbLut,
    src: &[[f32; 3]],
    rgba8: &mut [u8],
) {
    for_blocks(
        src,
        rgba8,
        #[inline(always)]
        |s, d: &mut [u8; 4 * LANES]| {
            let planes = map.block(s);
            let mut idx = [[0usize; LANES]; 3];
            for c in 0..3 {
                for i in 0..LANES {
                    idx[c][i] = lut_index(planes[c][i]);
                }
            }
            for i in 0..LANES {
                let word = u32::from(lut[idx[0][i]])
                    | u32::from(lut[idx[1][i]]) << 8
                    | u32::from(lut[idx[2][i]]) << 16
                    | 0xff00_0000;
                d[4 * i..4 * i + 4].copy_from_slice(&word.to_le_bytes());
            }
        },
    );
}

/// Sink: the display-linear row of `map`, clamped to [0, 1].
pub(crate) struct DisplayLinear<M> {
    pub map: M,
    pub width: usize,
}

impl<M: Map> RowSink for DisplayLinear<M> {
    type Out = [f32; 3];
    fn per_row(&self) -> usize {
        self.width
    }
    #[inline(always)]
    fn row(&self, _: usize, px: &[[f32; 3]], out: &mut [[f32; 3]]) {
        for_blocks(
            px,
            out,
            #[inline(always)]
            |s, d: &mut [[f32; 3]; LANES]| {
                let planes = self.map.block(s);
                for (i, d) in d.iter_mut().enumerate() {
                    *d = [planes[0][i], planes[1][i], planes[2][i]].map(|v| v.clamp(0.0, 1.0));
                }
            },
        );
    }
}

/// Index of display-linear `v` in the sRGB table: clamped to [0, 1] (NaN
/// → 0), then `⌊v·(N−1) + 0.5⌋`, the nearest entry.
///
/// The floor is taken without a float → int conversion (whose saturating
/// semantics keep the loop scalar): for `0 ≤ x < 2²²`, adding 2²³ leaves
/// `round(x)` (ties to even) in the low mantissa bits, exactly; one
/// comparison turns that into `⌊x⌋`. Bit-identical to `x as usize`.
#[inline(always)]
pub(crate) fn lut_index(v: f32) -> usize {
    const MAGIC: f32 = 8_388_608.0; // 2^23: one unit in the last place is 1
    // Selects: `v > 0` is false for NaN.
    let v = if v > 0.0 { v } else { 0.0 };
    let v = if v < 1.0 { v } else { 1.0 };
    let x = v * (SRGB_LUT_SIZE - 1) as f32 + 0.5;
    let y = x + MAGIC;
    let rounded = y.to_bits() & 0x007f_ffff;
    let floor = rounded - u32::from(y - MAGIC > x);
    // A no-op (floor ≤ N − 1 here) that proves the index in range.
    floor as usize & (SRGB_LUT_SIZE - 1)
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn srgb_table_is_non_decreasing_and_has_every_code() {
        let lut = srgb_lut();
        assert!(lut.codes.windows(2).all(|w| w[0] <= w[1]));
        assert_eq!((lut.codes[0], lut.codes[SRGB_LUT_SIZE - 1]), (0, 255));
        assert!(lut.codes.windows(2).all(|w| w[1] - w[0] <= 1));
    }

    /// The search of [`SrgbThresholds`], one index at a time.
    fn search(t: &SrgbThresholds, idx: usize) -> usize {
        let mut k = 1;
        for _ in 0..SRGB_CODE_BITS {
            k = 2 * k + usize::from(usize::from(t.0[k]) <= idx);
        }
        k - SRGB_CODES
    }

    #[test]
    fn threshold_search_gives_the_table_at_every_index() {
        let lut = srgb_lut();
        let miss = |t: &SrgbThresholds| {
            (0..SRGB_LUT_SIZE)
                .filter(|&i| search(t, i) != usize::from(lut[i]))
                .count()
        };
        assert_eq!(miss(lut.thresholds()), 0);
        // Each node matters: one threshold off by one misses an index.
        for k in 1..SRGB_CODES {
            let mut t = *lut.thresholds();
            t.0[k] += 1;
            assert!(miss(&t) > 0, "node {k}");
        }
    }

    #[test]
    fn lut_index_matches_the_clamped_rounding() {
        for v in [
            f32::NAN,
            -1.0,
            0.0,
            1e-9,
            0.5,
            0.999_99,
            1.0,
            7.0,
            f32::INFINITY,
        ] {
            let want = ((if v.is_nan() { 0.0 } else { v.clamp(0.0, 1.0) })
                * (SRGB_LUT_SIZE - 1) as f32
                + 0.5) as usize;
            assert_eq!(lut_index(v), want, "{v}");
        }
        assert_eq!(lut_index(f32::NEG_INFINITY), 0);
        // Every f32 in [0, 1] step 2^-24 around each table entry's
        // rounding edge, and a dense sweep: identical to the cast.
        let cast = |v: f32| (v.clamp(0.0, 1.0) * (SRGB_LUT_SIZE - 1) as f32 + 0.5) as usize;
        for k in 0..SRGB_LUT_SIZE {
            let edge = (k as f32 + 0.5) / (SRGB_LUT_SIZE - 1) as f32;
            let mut v = edge;
            for _ in 0..8 {
                v = f32::from_bits(v.to_bits().saturating_sub(1));
            }
            for _ in 0..16 {
                assert_eq!(lut_index(v), cast(v), "{v:e}");
                v = f32::from_bits(v.to_bits() + 1);
            }
        }
        for i in 0..=1_000_000u32 {
            let v = i as f32 / 1e6;
            assert_eq!(lut_index(v), cast(v), "{v:e}");
        }
    }
}
