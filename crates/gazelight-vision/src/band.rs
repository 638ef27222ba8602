//! The CPU band engine of the acuity blur: the separable Gaussian blur of
//! CIE L\*a\*b\* lightness with each pixel's own σ ([`crate::acuity`]'s
//! model, 001 eq 11–13), streamed in bands of rows.
//!
//! ## The blur (001 §4.3.1 steps 1–4, §4.3.3) — the GPU twin mirrors this
//!
//! 1. Every pixel's L\* (from the RGB → XYZ Y row, white `lab_white_cd_m2`).
//! 2. Horizontal pass: pixel x gets `h(x) = Σₖ g(k)·L(x+k) / Σₖ g(k)`,
//!    k = −r..=r, with `g(k) = exp(−k²/(2σ²))`, σ = σ(L(x)) of the pixel
//!    itself and r = min(⌈3σ⌉, [`AcuityBlur::MAX_RADIUS_PX`]) (001 §4.3.2:
//!    size 2⌈3σ⌉ + 1); taps beyond the frame repeat the edge pixel.
//!    Pixels with σ ≤ 0.3 keep h = L.
//! 3. Vertical pass over h the same way, with σ = σ(h(y)) from the *new*
//!    lightness of the pixel (001 §4.3.1 step 3); result L'.
//! 4. Back to RGB with the pixel's own a\*, b\*: keeping a\* = 500(fx − fy)
//!    and b\* = 200(fy − fz) means shifting all three of `g = 116·f − 16`
//!    by the same `Δ = L' − L`: `X' = Xn·g⁻¹(g(X/Xn) + Δ)`, `Y' =
//!    Yn·g⁻¹(L')`, `Z' = Zn·g⁻¹(g(Z/Zn) + Δ)`, with `g(t) = κt` (t ≤ ε) or
//!    `116∛t − 16`, `g⁻¹(v) = v/κ` (v ≤ 8) or `((v + 16)/116)³`; then XYZ →
//!    linear sRGB. (This form keeps dark pixels exact in f32: no
//!    difference of two numbers near 16.) A pixel whose L' equals its L is
//!    left bit-identical.
//!
//! The kernel is the exact sampled Gaussian of each pixel's own σ,
//! normalised over its own taps — the brute-force evaluation of 001 eq 12
//! with no σ quantisation and no blend between blur levels. Its weights
//! come from one `exp` per pixel and the recurrence `g(k+1) = g(k)·q(k)`,
//! `q(k+1) = q(k)·e²`, `g(0) = 1`, `q(0) = e = exp(−1/(2σ²))` (two
//! multiplies per tap, exact up to f32 rounding: < 1e-5 relative over 64
//! taps). Cost follows σ: a pixel costs 2r + 1 taps, i.e. nothing for bright
//! pixels, 3 taps at σ ≤ 1/3 px, and at most 2·64 + 1.
//!
//! ## How it runs: streaming, banded, vectorised
//!
//! The frame is split into bands of rows (at most 8, each at least 8r
//! rows for the frame's largest radius r), which run in parallel on the
//! rayon pool. A band reads its rows from a row source, never from rows
//! another band has already blurred: the r rows on either side of its
//! edges are made again from the source. Within a band, rows stream through two
//! rings of 2r + 1 rows: row t + 2r's Y/Yn (no cube root) and whether it
//! holds a pixel darker than the blur threshold (the models' σ falls
//! monotonically with Y, so one threshold luminance per frame decides,
//! with a 1 % margin); row t + r's L\* and horizontal pass, computed only
//! when a dark row lies within r of it; then output row t: its vertical
//! pass and the conversion back to RGB only if it is dark (a row without a
//! dark pixel has σ ≤ 0.3 everywhere, its h equals L, so step 3 leaves it
//! too), and the row goes straight to the caller's sink (the pipeline's
//! tone + colour + encode, [`crate::encode`]) while it is in cache. The
//! frame is read from memory once for stages 5–8.
//!
//! The source makes each row just before the band first reads it: for
//! [`AcuityBlur::apply`], a copy of the original frame; for the pipeline,
//! the sanitised scene row with the glare blended in. Unless the caller
//! keeps the blurred frame, a band's rows live only in a ring of 2r + 1
//! rows of its own.
//!
//! Pixels are processed 8 at a time as channel planes with fixed trip
//! counts. On a CPU with AVX2 + FMA (detected at run time, [`Simd`]) the
//! row loops run their explicit-intrinsics twins (`kernels::avx2`), and
//! with AVX-512 too, twins on blocks of 16 (`kernels::avx512`, a row's
//! last 8 in AVX2), which compute the same bits (the tests compare all
//! three builds on the shared night panorama); elsewhere, or with
//! `GAZELIGHT_SIMD=portable`, the portable loops, written for the
//! auto-vectoriser, run. The cube root and `exp` are vector polynomials (within
//! 3e-7 of the standard library's) and are skipped for a block whose eight
//! values all lie in L\*'s linear part (Y/Yn ≤ ε, most of a night frame).
//! There step 4 needs no cube root either: with `g(t) = κt` and `g⁻¹(v) =
//! v/κ` for all three of X, Y, Z before and after the shift (checked per
//! block: `κ·max(X/Xn, Z/Zn) + max(Δ, 0) ≤ 8` and `L + max(Δ, 0) ≤ 8`),
//! `X' = X + Xn·Δ/κ` and the same for Y and Z, so RGB' = RGB + (white·Δ/κ)
//! on every channel (the sRGB matrix maps RGB (1, 1, 1) to the D65 white);
//! the same value up to f32 rounding. A block of 8 runs its tap loop to the
//! largest radius of its 8 pixels, and each pixel's taps beyond its own
//! radius get weight exactly 0, so its sum is the one of its own taps. A
//! bright frame costs one Y per pixel; a dark pixel of small σ costs a few
//! taps. Nothing is allocated once the scratch has the image's size.
//!
//! ## Modules
//!
//! The band loop, its scratch and the portable row loops are here; the
//! row loops' AVX2 and AVX-512 twins are generated from one definition in
//! `kernels` (module `band::kernels`), which uses the vector primitives of
//! [`crate::simd`]; [`crate::simd::Simd`] says which of them run.

use rayon::prelude::*;

use crate::RgbImage;
use crate::acuity::{AcuityModel, MIN_ACUITY_LUMINANCE_CD_M2, VIVE_PRO_PPD};
use crate::colour::{LAB_KAPPA, LAB_KAPPA_F32, RGB_TO_XYZ, WHITE_XYZ, XYZ_TO_RGB};
use crate::simd::{LANES, Simd, Tier};

mod kernels;

/// The per-pixel σ rule of one frame size, in f32.
#[derive(Clone, Copy, Debug, PartialEq)]
enum SigmaRule {
    /// σ = clamp(1 − L, 0, 1)·scale (001 eq 12), scale = ppd/13.85.
    Linear { scale: f32 },
    /// σ = scale / R(max(Y, 10⁻⁶)) (001 eq 11, 13), scale = ppd/(1.86·√2).
    Larson { scale: f32 },
    /// No blur.
    None,
}

impl SigmaRule {
    /// σ of a pixel of lightness `l` (white `white_cd_m2`), pixels.
    #[inline]
    fn sigma(self, l: f32, white_cd_m2: f32) -> f32 {
        match self {
            // 001 eq 12
            Self::Linear { scale } => (1.0 - l).clamp(0.0, 1.0) * scale,
            Self::Larson { scale } => {
                let y = (lab_g_inv(l) * white_cd_m2).max(MIN_ACUITY_LUMINANCE_CD_M2 as f32);
                // 001 eq 13 solved for R; eq 11
                let r = (1.49 + ((y.ln() + 0.575_646) / 1.64).atan()) / 0.06;
                if r > 0.0 { scale / r } else { f32::INFINITY }
            }
            Self::None => 0.0,
        }
    }
}

/// CIE lightness scale of a relative tristimulus `t`: `116·f(t) − 16`
/// (L\* for t = Y/Yn): κ·t up to ε, then `116·∛t − 16`. The blur uses
/// its vectorised twin [`lab_g_v`]; the tests compare the two.
#[cfg(test)]
fn lab_g(t: f32) -> f32 {
    if t > 216.0 / 24389.0 {
        116.0 * t.cbrt() - 16.0
    } else {
        24389.0 / 27.0 * t
    }
}

/// Inverse of [`lab_g`]: `v/κ` up to 8, then `((v + 16)/116)³`. In this
/// form a dark pixel's value is never the difference of two numbers
/// near 16 (f32 would lose it).
#[inline(always)]
fn lab_g_inv(v: f32) -> f32 {
    if v > 8.0 {
        let f = (v + 16.0) / 116.0;
        f * f * f
    } else {
        v * (27.0 / 24389.0)
    }
}

/// Per-pixel-σ separable Gaussian blur of Lab lightness (see the module
/// docs) with preallocated scratch.
#[derive(Clone, Debug)]
pub struct AcuityBlur {
    width: usize,
    height: usize,
    rule: SigmaRule,
    white_cd_m2: f32,
    /// Rows holding a pixel below this luminance (cd/m²) are blurred.
    blur_below_cd_m2: f32,
    /// Largest tap radius any pixel gets.
    max_radius: usize,
    /// Rows per band (the last band may be shorter).
    band_rows: usize,
    /// Per band: its ring buffers.
    bands: Vec<Band>,
    /// A copy of the frame [`AcuityBlur::apply`] blurs in place, which it
    /// reads its rows from (allocated by the first `apply` of a size).
    original: Vec<[f32; 3]>,
    /// The tier the row loops run on ([`Simd::host`]; the tests set others
    /// to compare them).
    simd: Simd,
}

/// The scratch of one band of rows.
#[derive(Clone, Debug, Default)]
struct Band {
    /// Ring of 2r + 1 rows: Y/Yn of the newest rows, L\* of the older ones,
    /// each padded by r + lane-rounding values either side (edge repeated).
    lum: Vec<f32>,
    /// Ring of 2r + 1 rows of L\* after the horizontal pass.
    hor: Vec<f32>,
    /// Ring of 2r + 1 rows (as `hor`): each pixel's max(R, G, B)/white, a
    /// bound on all three of X/Xn, Y/Yn, Z/Zn (each row of the sRGB → XYZ
    /// matrix sums to its white component) for step 4's linear-part test.
    head: Vec<f32>,
    /// Per frame row: holds a pixel below the blur threshold.
    dark: Vec<bool>,
    /// One frame row: where a band filled from a [`RowSource`] puts the
    /// rows of its neighbours that it reads (their Y only).
    scratch: Vec<[f32; 3]>,
    /// Ring of 2r + 1 frame rows: the band's own rows when they are not
    /// kept in a frame ([`AcuityBlur::apply_from`] without one).
    rgb: Vec<[f32; 3]>,
}

/// A portable block of lanes.
type V = [f32; LANES];

/// Where the rows of the blurred frame go, one row at a time, while they
/// are still in cache (the pipeline fuses tone reproduction, colour and
/// encoding here).
pub(crate) trait RowSink: Sync {
    /// What the sink writes.
    type Out: Send;
    /// Items of `Out` per image row.
    fn per_row(&self) -> usize;
    /// Consumes finished row `y` (linear RGB, cd/m²).
    fn row(&self, y: usize, px: &[[f32; 3]], out: &mut [Self::Out]);
}

/// A sink that keeps nothing ([`AcuityBlur::apply`]).
struct NoSink;

impl RowSink for NoSink {
    type Out = ();
    fn per_row(&self) -> usize {
        1
    }
    #[inline(always)]
    fn row(&self, _: usize, _: &[[f32; 3]], _: &mut [()]) {}
}

/// Where a band pass filled from a source gets the frame's rows
/// ([`AcuityBlur::apply_from`]): each row is made just before the band
/// first reads it, so it is read while in cache (the pipeline makes a row
/// as the sanitised scene row with the glare blended in).
pub(crate) trait RowSource: Sync {
    /// Writes row `y` of the frame (linear RGB, cd/m², `row.len()` pixels)
    /// into `row`.
    fn fill(&self, y: usize, row: &mut [[f32; 3]]);
}

/// The per-frame constants of the blur.
#[derive(Clone, Copy)]
struct Ctx {
    w: usize,
    h: usize,
    r: usize,
    rule: SigmaRule,
    white: f32,
    /// Y/Yn below which a pixel may blur (with the 1 % margin).
    dark_below: f32,
    /// Lightness-ring row stride: r + w rounded up to lanes + r.
    stride_l: usize,
    /// Horizontal-ring row stride: w rounded up to lanes.
    stride_h: usize,
    /// The tier the band runs on.
    simd: Simd,
    /// `simd` has AVX2 + FMA: the row loops run their `kernels::avx2`
    /// twins.
    avx2: bool,
    /// `simd` has AVX-512 too: the row loops run their `kernels::avx512`
    /// twins on blocks of 16 first.
    avx512: bool,
}

impl AcuityBlur {
    /// Pixels whose σ is at or below this many pixels are not blurred.
    pub const MIN_SIGMA_PX: f32 = 0.3;

    /// The most taps either side of a pixel (σ above `MAX_RADIUS_PX / 3`
    /// is truncated at this radius: only Larson/Krawczyk in the deepest
    /// dark above ~39 px/deg, or eq 12 above ~295 px/deg).
    pub const MAX_RADIUS_PX: usize = 64;

    /// At most this many bands of rows run in parallel.
    const MAX_BANDS: usize = 8;

    /// Scratch buffers for `width × height` frames of pixels `deg_per_px`
    /// degrees wide, blurred with `model`.
    pub fn new(model: &AcuityModel, width: usize, height: usize, deg_per_px: f64) -> Self {
        let ppd = if deg_per_px.is_finite() && deg_per_px > 0.0 {
            1.0 / deg_per_px
        } else {
            0.0
        };
        let white = model.lab_white_cd_m2();
        let (rule, blur_below) = match *model {
            AcuityModel::Linear { .. } => {
                let scale = ppd / VIVE_PRO_PPD;
                // σ > 0.3 ⇔ L* < 1 − 0.3/scale, in the linear part of L*
                let l_t = 1.0 - f64::from(Self::MIN_SIGMA_PX) / scale;
                let y_t = if l_t > 0.0 {
                    l_t / LAB_KAPPA * white
                } else {
                    0.0
                };
                (
                    SigmaRule::Linear {
                        scale: scale as f32,
                    },
                    y_t,
                )
            }
            AcuityModel::LarsonKrawczyk => {
                let scale = ppd / (1.86 * std::f64::consts::SQRT_2);
                // σ > 0.3 ⇔ R < scale/0.3; R(Y) rises to (1.49 + π/2)/0.06
                let r_t = scale / f64::from(Self::MIN_SIGMA_PX);
                let y_t = if 0.06 * r_t - 1.49 >= std::f64::consts::FRAC_PI_2 {
                    f64::INFINITY
                } else {
                    // 001 eq 13
                    (-1.64 * (1.49 - 0.06 * r_t).tan() - 0.575_646).exp()
                };
                (
                    SigmaRule::Larson {
                        scale: scale as f32,
                    },
                    y_t,
                )
            }
            AcuityModel::None => (SigmaRule::None, 0.0),
        };
        let max_sigma = f64::from(model.max_sigma_px(deg_per_px));
        let max_radius = if max_sigma > f64::from(Self::MIN_SIGMA_PX) {
            ((3.0 * max_sigma).ceil() as usize).min(Self::MAX_RADIUS_PX)
        } else {
            0
        };
        let mut blur = Self {
            width: 0,
            height: 0,
            rule,
            white_cd_m2: white as f32,
            // a 1 % margin: rows are marked conservatively, the per-pixel
            // σ decides exactly
            blur_below_cd_m2: (blur_below * 1.01) as f32,
            max_radius,
            band_rows: 1,
            bands: Vec::new(),
            original: Vec::new(),
            simd: Simd::host(),
        };
        blur.resize(width, height);
        blur
    }

    /// The largest tap radius of this blur, pixels (0: never blurs).
    pub fn max_radius(&self) -> usize {
        self.max_radius
    }

    /// Runs the row loops on `simd`'s tier (the tests compare the tiers).
    #[cfg(test)]
    pub(crate) fn set_simd(&mut self, simd: Simd) {
        self.simd = simd;
    }

    /// Sizes the bands and their scratch for `w × h` frames.
    fn resize(&mut self, w: usize, h: usize) {
        self.width = w;
        self.height = h;
        let r = self.max_radius;
        // Bands at least 8r (and 16) rows tall: their halo of 2r rows is
        // small against the rows they output.
        let wanted = (h / (8 * r).max(16)).clamp(1, Self::MAX_BANDS);
        self.band_rows = h.div_ceil(wanted).max(1);
        let n = h.div_ceil(self.band_rows);
        if r == 0 {
            // A row each, for bands whose rows are not kept.
            self.bands = (0..n)
                .map(|_| Band {
                    scratch: vec![[0.0; 3]; w],
                    ..Band::default()
                })
                .collect();
            return;
        }
        let stride_l = 2 * r + w.next_multiple_of(LANES);
        let stride_h = w.next_multiple_of(LANES);
        self.bands = (0..n)
            .map(|_| Band {
                lum: vec![0.0; (2 * r + 1) * stride_l],
                hor: vec![0.0; (2 * r + 1) * stride_h],
                head: vec![0.0; (2 * r + 1) * stride_h],
                dark: vec![false; h],
                scratch: vec![[0.0; 3]; w],
                rgb: vec![[0.0; 3]; (2 * r + 1) * w],
            })
            .collect();
    }

    /// Blurs the lightness of `img` (linear RGB, cd/m²) in place, each
    /// pixel with its own σ, keeping a\* and b\* of every pixel. Returns the
    /// number of pixels whose lightness changed. Reads the rows from a copy
    /// of `img` (no band reads a row another has already blurred); the copy
    /// and the scratch buffers are allocated only when the size changed.
    pub fn apply(&mut self, img: &mut RgbImage) -> usize {
        let mut original = std::mem::take(&mut self.original);
        original.clear();
        original.extend_from_slice(&img.pixels);
        let src = ImageRows {
            pixels: &original,
            width: img.width,
        };
        let mut none = vec![(); img.height];
        let size = (img.width, img.height);
        let changed = self.apply_from(&src, size, Some(img), &NoSink, &mut none);
        self.original = original;
        changed
    }

    /// Blurs the `width × height` frame that `src` makes, each row made
    /// just before the band pass first reads it, then gives `sink` every
    /// row of the result right after the row is final (while it is in
    /// cache); `out` holds `sink.per_row()` items per row. Rows run in
    /// bands, in parallel. With `keep`, the rows are made in it (whatever
    /// it held is overwritten) and it ends as the blurred frame; without,
    /// each band keeps only the 2r + 1 rows it is working on, in its own
    /// ring (no frame-sized buffer is written). Returns the number of
    /// pixels whose lightness changed; does nothing (returns 0) when `keep`
    /// is not `width × height`.
    pub(crate) fn apply_from<S: RowSink, R: RowSource>(
        &mut self,
        src: &R,
        size: (usize, usize),
        keep: Option<&mut RgbImage>,
        sink: &S,
        out: &mut [S::Out],
    ) -> usize {
        let (w, h) = size;
        let mut img = keep;
        let per_row = sink.per_row();
        if w == 0
            || h == 0
            || out.len() != h * per_row
            || img
                .as_ref()
                .is_some_and(|i| (i.width, i.height) != (w, h) || i.pixels.len() != w * h)
        {
            return 0;
        }
        if (w, h) != (self.width, self.height) {
            self.resize(w, h);
        }
        let band_rows = self.band_rows;
        let r = self.max_radius;
        let ctx = Ctx {
            w,
            h,
            r,
            rule: self.rule,
            white: self.white_cd_m2,
            dark_below: self.blur_below_cd_m2 / self.white_cd_m2,
            stride_l: 2 * r + w.next_multiple_of(LANES),
            stride_h: w.next_multiple_of(LANES),
            simd: self.simd,
            avx2: self.simd.has(Tier::Avx2),
            avx512: self.simd.has(Tier::Avx512),
        };
        let no_blur = r == 0 || matches!(self.rule, SigmaRule::None);
        // One job per band: its rows in the frame, or `None` (its ring).
        let frame_rows = img.as_mut().map(|i| i.pixels.par_chunks_mut(band_rows * w));
        let jobs = self
            .bands
            .par_iter_mut()
            .zip(out.par_chunks_mut(band_rows * per_row))
            .enumerate();
        let band =
            |b: usize, band: &mut Band, mut px: Option<&mut [[f32; 3]]>, out: &mut [S::Out]| {
                let y0 = b * band_rows;
                let y1 = (y0 + band_rows).min(h);
                if no_blur {
                    for (k, o) in out.chunks_exact_mut(per_row).enumerate() {
                        let row = match px.as_deref_mut() {
                            Some(px) => &mut px[k * w..(k + 1) * w],
                            None => &mut band.scratch[..],
                        };
                        src.fill(y0 + k, row);
                        sink.row(y0 + k, row, o);
                    }
                    return 0;
                }
                match px {
                    Some(px) => {
                        let rows = BandRows {
                            px,
                            y0,
                            y1,
                            ring: false,
                        };
                        run_band_dispatch(&ctx, band, rows, src, sink, out)
                    }
                    None => {
                        // The ring moves out of the band for the pass (no copy).
                        let mut ring = std::mem::take(&mut band.rgb);
                        let rows = BandRows {
                            px: &mut ring,
                            y0,
                            y1,
                            ring: true,
                        };
                        let changed = run_band_dispatch(&ctx, band, rows, src, sink, out);
                        band.rgb = ring;
                        changed
                    }
                }
            };
        match frame_rows {
            Some(rows) => jobs
                .zip(rows)
                .map(|((b, (bd, out)), px)| band(b, bd, Some(px), out))
                .sum(),
            None => jobs.map(|(b, (bd, out))| band(b, bd, None, out)).sum(),
        }
    }
}

/// Where a band's rows `y0..y1` live: `px` holds them in order, or with
/// `ring` in a ring of 2r + 1 rows.
struct BandRows<'a> {
    px: &'a mut [[f32; 3]],
    y0: usize,
    y1: usize,
    ring: bool,
}

/// The rows of an image, as they are ([`AcuityBlur::apply`]).
struct ImageRows<'a> {
    pixels: &'a [[f32; 3]],
    width: usize,
}

impl RowSource for ImageRows<'_> {
    #[inline]
    fn fill(&self, y: usize, row: &mut [[f32; 3]]) {
        row.copy_from_slice(&self.pixels[y * self.width..(y + 1) * self.width]);
    }
}

/// [`run_band`] compiled for the tier of `ctx` ([`Simd::compiled`]): the
/// same code and so the same results as the portable build; only the
/// instruction set differs.
fn run_band_dispatch<S: RowSink, R: RowSource>(
    ctx: &Ctx,
    band: &mut Band,
    rows: BandRows<'_>,
    src: &R,
    sink: &S,
    out: &mut [S::Out],
) -> usize {
    ctx.simd.compiled(
        #[inline(always)]
        || run_band(ctx, band, rows, src, sink, out),
    )
}

/// One band of rows `y0..y1` (`rows`), streaming: each row's Y/Yn and
/// darkness is read r rows ahead of its L\*, whose horizontal pass is r rows
/// ahead of the output row's vertical pass, back-conversion and sink. The
/// band's rows live in `px` (in order, or with `ring` in a ring of 2r + 1
/// rows); `input` readies each one and gives the neighbours' rows. Returns
/// the number of pixels whose lightness changed.
#[inline(always)]
fn run_band<S: RowSink, R: RowSource>(
    ctx: &Ctx,
    band: &mut Band,
    rows: BandRows<'_>,
    src: &R,
    sink: &S,
    out: &mut [S::Out],
) -> usize {
    let Ctx { w, h, r, .. } = *ctx;
    let per_row = sink.per_row();
    let BandRows { px, y0, y1, ring } = rows;
    // Where row t of the band lives in `px`: the band's rows in order, or
    // a ring of 2r + 1 (row t is made at most 2r rows before it is output,
    // and its slot is reused 2r + 1 rows later).
    let slot = |t: usize| if ring { t % (2 * r + 1) } else { t - y0 };
    let t0 = y0.saturating_sub(r);
    let t_end = (y1 + r).min(h);
    let ring = 2 * r + 1;
    let (mut next_y, mut next_l) = (t0, t0);
    let mut changed = 0;
    for y in y0..y1 {
        // L* and the horizontal pass of every row up to y + r.
        let l_to = (y + r + 1).min(t_end);
        while next_l < l_to {
            let j = next_l;
            // Whether an output row of this band within r of row j is dark
            // needs those rows' flags: read Y up to there (and row j).
            let last = (j + r).min(y1 - 1).max(j);
            while next_y <= last {
                let t = next_y;
                // Rows of the neighbouring bands are made again, into the
                // scratch row (their Y only is read).
                let row = if t < y0 || t >= y1 {
                    &mut band.scratch[..]
                } else {
                    &mut px[slot(t) * w..(slot(t) + 1) * w]
                };
                src.fill(t, row);
                let slot = t % ring;
                band.dark[t] = load_y(
                    ctx,
                    row,
                    &mut band.lum[slot * ctx.stride_l..(slot + 1) * ctx.stride_l],
                    &mut band.head[slot * ctx.stride_h..(slot + 1) * ctx.stride_h],
                );
                next_y += 1;
            }
            let lo = j.saturating_sub(r).max(y0);
            let hi = (j + r).min(y1 - 1);
            if lo <= hi && band.dark[lo..=hi].contains(&true) {
                let slot = j % ring;
                let lrow = &mut band.lum[slot * ctx.stride_l..(slot + 1) * ctx.stride_l];
                to_lightness(ctx, lrow);
                let hrow = &mut band.hor[slot * ctx.stride_h..(slot + 1) * ctx.stride_h];
                if band.dark[j] {
                    horizontal(ctx, lrow, hrow);
                } else {
                    hrow.copy_from_slice(&lrow[r..r + ctx.stride_h]);
                }
            }
            next_l += 1;
        }
        let row = &mut px[slot(y) * w..(slot(y) + 1) * w];
        if band.dark[y] {
            changed += vertical(ctx, band, y, row);
        }
        sink.row(y, row, &mut out[(y - y0) * per_row..(y - y0 + 1) * per_row]);
    }
    changed
}

#[inline(always)]
fn load_v(s: &[f32], at: usize) -> V {
    let mut v = [0.0; LANES];
    v.copy_from_slice(&s[at..at + LANES]);
    v
}

/// Channel planes of `n ≤ LANES` pixels (the rest black).
#[inline(always)]
fn planes(px: &[[f32; 3]]) -> [V; 3] {
    if let Ok(full) = <&[[f32; 3]; LANES]>::try_from(px) {
        return crate::simd::planes_full(full);
    }
    let mut p = [[0.0; LANES]; 3];
    for (i, q) in px.iter().enumerate().take(LANES) {
        p[0][i] = q[0];
        p[1][i] = q[1];
        p[2][i] = q[2];
    }
    p
}

#[inline(always)]
fn mat3_v(m: &[[f32; 3]; 3], p: &[V; 3]) -> [V; 3] {
    let mut o = [[0.0; LANES]; 3];
    for c in 0..3 {
        for i in 0..LANES {
            o[c][i] = m[c][0] * p[0][i] + m[c][1] * p[1][i] + m[c][2] * p[2][i];
        }
    }
    o
}

/// Y/Yn of every pixel of `src` into the ring row `lrow` (at offset r) and
/// max(R, G, B)/white into `head`; whether any is below the blur threshold.
#[inline(always)]
fn load_y(ctx: &Ctx, src: &[[f32; 3]], lrow: &mut [f32], head: &mut [f32]) -> bool {
    #[cfg(target_arch = "x86_64")]
    if ctx.avx2 {
        let (dark16, from) = if ctx.avx512 {
            // SAFETY: `ctx.avx512` is set only where the CPU has AVX-512F
            // (and BW), AVX2 and FMA (from a `Simd` of that tier).
            unsafe { kernels::avx512::load_y(ctx, src, lrow, head, 0) }
        } else {
            (false, 0)
        };
        // SAFETY: `ctx.avx2` is set only where the CPU has AVX2 and FMA
        // (from a `Simd` of that tier).
        let (dark, done) = unsafe { kernels::avx2::load_y(ctx, src, lrow, head, from) };
        return load_y_from(ctx, src, lrow, head, done) | dark | dark16;
    }
    load_y_from(ctx, src, lrow, head, 0)
}

/// [`load_y`] of the pixels from `from` (a multiple of [`LANES`]) on.
#[inline(always)]
fn load_y_from(
    ctx: &Ctx,
    src: &[[f32; 3]],
    lrow: &mut [f32],
    head: &mut [f32],
    from: usize,
) -> bool {
    let y_row = RGB_TO_XYZ[1];
    let inv_white = 1.0 / ctx.white;
    let mut dark = false;
    let dst = &mut lrow[ctx.r + from..ctx.r + ctx.stride_h];
    for ((s, d), hd) in src[from..]
        .chunks(LANES)
        .zip(dst.chunks_exact_mut(LANES))
        .zip(head[from..].chunks_exact_mut(LANES))
    {
        let p = planes(s);
        let mut any = false;
        for i in 0..LANES {
            let y = y_row[0] * p[0][i] + y_row[1] * p[1][i] + y_row[2] * p[2][i];
            let t = y * inv_white;
            d[i] = t;
            hd[i] = p[0][i].max(p[1][i]).max(p[2][i]) * inv_white;
            any |= (i < s.len()) & (t < ctx.dark_below);
        }
        dark |= any;
    }
    dark
}

/// The ring row from Y/Yn to L\* in place, and its padding: the edge
/// pixels repeated r + lane-rounding places out.
#[inline(always)]
fn to_lightness(ctx: &Ctx, lrow: &mut [f32]) {
    let (r, w) = (ctx.r, ctx.w);
    #[cfg(target_arch = "x86_64")]
    let portable = if ctx.avx2 {
        let from = if ctx.avx512 {
            // SAFETY: `ctx.avx512` is set only where the CPU has AVX-512F
            // (and BW), AVX2 and FMA (from a `Simd` of that tier).
            unsafe { kernels::avx512::to_lightness(ctx, lrow, 0) }
        } else {
            0
        };
        // SAFETY: `ctx.avx2` is set only where the CPU has AVX2 and FMA
        // (from a `Simd` of that tier).
        // It does the whole row (a multiple of 8).
        unsafe { kernels::avx2::to_lightness(ctx, lrow, from) };
        false
    } else {
        true
    };
    #[cfg(not(target_arch = "x86_64"))]
    let portable = true;
    if portable {
        for d in lrow[r..r + ctx.stride_h].chunks_exact_mut(LANES) {
            let mut t = [0.0; LANES];
            t.copy_from_slice(d);
            d.copy_from_slice(&lab_g_v(t));
        }
    }
    let (first, last) = (lrow[r], lrow[r + w - 1]);
    lrow[..r].fill(first);
    lrow[r + w..].fill(last);
}

/// Horizontal pass of a dark row: `hrow[x]` = the blur of `lrow` around x
/// with x's own σ.
#[inline(always)]
fn horizontal(ctx: &Ctx, lrow: &[f32], hrow: &mut [f32]) {
    #[cfg(target_arch = "x86_64")]
    if ctx.avx2 {
        let from = if ctx.avx512 {
            // SAFETY: `ctx.avx512` is set only where the CPU has AVX-512F
            // (and BW), AVX2 and FMA (from a `Simd` of that tier).
            unsafe { kernels::avx512::horizontal(ctx, lrow, hrow, 0) }
        } else {
            0
        };
        // SAFETY: `ctx.avx2` is set only where the CPU has AVX2 and FMA
        // (from a `Simd` of that tier).
        // It does the whole row (a multiple of 8).
        unsafe { kernels::avx2::horizontal(ctx, lrow, hrow, from) };
        return;
    }
    let r = ctx.r;
    for (bx, hv) in hrow.chunks_exact_mut(LANES).enumerate() {
        let x = r + bx * LANES;
        let centre = load_v(lrow, x);
        let v = gather_v(
            ctx,
            centre,
            #[inline(always)]
            |k| (load_v(lrow, x - k), load_v(lrow, x + k)),
        );
        hv.copy_from_slice(&v);
    }
}

/// Vertical pass of dark row `y` (σ from its horizontally blurred
/// lightness) and back to RGB with each pixel's a\*, b\*; a pixel whose L\*
/// did not change keeps its bits. Returns how many changed.
#[inline(always)]
fn vertical(ctx: &Ctx, band: &Band, y: usize, row: &mut [[f32; 3]]) -> usize {
    let Ctx { r, h, .. } = *ctx;
    let ring = 2 * r + 1;
    let sh = ctx.stride_h;
    let hor = &band.hor[..];
    // Ring offsets of rows y − k and y + k (edge rows repeated), once per row.
    let mut up = [0usize; AcuityBlur::MAX_RADIUS_PX + 1];
    let mut down = [0usize; AcuityBlur::MAX_RADIUS_PX + 1];
    for k in 0..=r {
        up[k] = (y.saturating_sub(k) % ring) * sh;
        down[k] = ((y + k).min(h - 1) % ring) * sh;
    }
    #[cfg(target_arch = "x86_64")]
    let (mut changed, from) = if ctx.avx2 {
        let (changed16, from) = if ctx.avx512 {
            // SAFETY: `ctx.avx512` is set only where the CPU has AVX-512F
            // (and BW), AVX2 and FMA (from a `Simd` of that tier).
            unsafe { kernels::avx512::vertical(ctx, band, &up[..=r], &down[..=r], y, row, 0) }
        } else {
            (0, 0)
        };
        // SAFETY: `ctx.avx2` is set only where the CPU has AVX2 and FMA
        // (from a `Simd` of that tier).
        let (changed, done) =
            unsafe { kernels::avx2::vertical(ctx, band, &up[..=r], &down[..=r], y, row, from) };
        (changed16 + changed, done)
    } else {
        (0, 0)
    };
    #[cfg(not(target_arch = "x86_64"))]
    let (mut changed, from) = (0, 0);
    let lrow = &band.lum[(y % ring) * ctx.stride_l + r..];
    let head_row = &band.head[(y % ring) * sh..];
    let wx = WHITE_XYZ.map(|c| c * ctx.white);
    for (bx, out) in row[from..].chunks_mut(LANES).enumerate() {
        let x = from + bx * LANES;
        let hv = load_v(hor, up[0] + x);
        let l_new = gather_v(
            ctx,
            hv,
            #[inline(always)]
            |k| (load_v(hor, up[k] + x), load_v(hor, down[k] + x)),
        );
        let l_old = load_v(lrow, x);
        let mut moved = [false; LANES];
        let mut any = false;
        for i in 0..out.len() {
            moved[i] = l_new[i] != l_old[i];
            any |= moved[i];
        }
        if !any {
            continue;
        }
        // g and g⁻¹ both in their linear parts for X, Y and Z, before and
        // after the shift: κ·max(X/Xn, Y/Yn, Z/Zn) + max(Δ, 0) ≤ 8, with
        // `head` bounding all three.
        let head = load_v(head_row, x);
        let mut linear = true;
        for i in 0..LANES {
            let d = l_new[i] - l_old[i];
            linear &= head[i] * LAB_KAPPA_F32 + d.max(0.0) <= 8.0;
        }
        if linear {
            // g(t) = κt and g⁻¹(v) = v/κ: X' = X + Xn·Δ/κ, the same for Y
            // and Z, so RGB' = RGB + (white·Δ/κ)·(1, 1, 1) (M⁻¹·M = I).
            for (i, o) in out.iter_mut().enumerate() {
                if moved[i] {
                    let shift = (l_new[i] - l_old[i]) * (ctx.white / LAB_KAPPA_F32);
                    *o = [o[0] + shift, o[1] + shift, o[2] + shift];
                    changed += 1;
                }
            }
            continue;
        }
        let p = planes(out);
        let xyz = mat3_v(&RGB_TO_XYZ, &p);
        let mut tx = [0.0; LANES];
        let mut tz = [0.0; LANES];
        for i in 0..LANES {
            tx[i] = xyz[0][i] / wx[0];
            tz[i] = xyz[2][i] / wx[2];
        }
        let (gx, gz) = (lab_g_v(tx), lab_g_v(tz));
        let mut new = [[0.0; LANES]; 3];
        for i in 0..LANES {
            let d = l_new[i] - l_old[i];
            new[0][i] = lab_g_inv(gx[i] + d) * wx[0];
            new[1][i] = lab_g_inv(l_old[i] + d) * wx[1];
            new[2][i] = lab_g_inv(gz[i] + d) * wx[2];
        }
        let rgb = mat3_v(&XYZ_TO_RGB, &new);
        for (i, o) in out.iter_mut().enumerate() {
            if moved[i] {
                *o = [rgb[0][i], rgb[1][i], rgb[2][i]];
                changed += 1;
            }
        }
    }
    changed
}

/// σ of `LANES` pixels of lightness `l`, pixels.
#[inline(always)]
fn sigma_v(rule: SigmaRule, l: V, white: f32) -> V {
    let mut s = [0.0; LANES];
    match rule {
        SigmaRule::Linear { scale } => {
            for i in 0..LANES {
                // 001 eq 12
                s[i] = (1.0 - l[i]).clamp(0.0, 1.0) * scale;
            }
        }
        SigmaRule::Larson { .. } => {
            for i in 0..LANES {
                s[i] = rule.sigma(l[i], white);
            }
        }
        SigmaRule::None => {}
    }
    s
}

/// `Σₖ g(k)·v(k) / Σₖ g(k)` over k = −r..=r for `LANES` pixels at once,
/// `g(k) = exp(−k²/(2σ²))` with each lane's own σ (from `centre`, its
/// v(0)) and r = min(⌈3σ⌉, r_max); `pair(k)` = (v(−k), v(k)). Lanes with
/// σ ≤ 0.3 keep `centre`. The tap loop runs to the largest r of the block
/// and masks each lane's taps beyond its own r (they add exact zeros, so
/// each lane's sum is the one of its own taps).
#[inline(always)]
fn gather_v(ctx: &Ctx, centre: V, pair: impl Fn(usize) -> (V, V)) -> V {
    let sigma = sigma_v(ctx.rule, centre, ctx.white);
    let mut sigma_max = 0.0f32;
    for &s in &sigma {
        sigma_max = sigma_max.max(s);
    }
    if sigma_max <= AcuityBlur::MIN_SIGMA_PX {
        return centre;
    }
    let block_r = (3.0 * sigma_max).ceil().min(ctx.r as f32) as usize;
    // Tap k of a lane is in its radius ⌈3σ⌉ iff k − 1 < 3σ; inactive lanes
    // (σ ≤ 0.3) get no taps: their sum is `centre / 1`, bit-identical.
    let mut e = [0.0; LANES];
    let mut three_sigma = [0.0; LANES];
    for i in 0..LANES {
        let active = sigma[i] > AcuityBlur::MIN_SIGMA_PX;
        let s = if active { sigma[i] } else { 1.0 };
        e[i] = -0.5 / (s * s);
        three_sigma[i] = if active { 3.0 * s } else { 0.0 };
    }
    let e = exp_v(e);
    let mut e2 = [0.0; LANES];
    for i in 0..LANES {
        e2[i] = e[i] * e[i];
    }
    let (mut g, mut q) = ([1.0f32; LANES], e);
    let (mut acc, mut norm) = (centre, [1.0f32; LANES]);
    for k in 1..=block_r {
        let (a, b) = pair(k);
        let below = (k - 1) as f32;
        for i in 0..LANES {
            g[i] *= q[i];
            q[i] *= e2[i];
            let gk = if below < three_sigma[i] { g[i] } else { 0.0 };
            acc[i] += gk * (a[i] + b[i]);
            norm[i] += 2.0 * gk;
        }
    }
    let mut out = [0.0; LANES];
    for i in 0..LANES {
        out[i] = acc[i] / norm[i];
    }
    out
}

/// [`lab_g`] of `LANES` values with [`cbrt_v`].
#[inline(always)]
fn lab_g_v(t: V) -> V {
    let mut any_cubic = false;
    for &ti in &t {
        any_cubic |= ti > 216.0 / 24389.0;
    }
    if !any_cubic {
        // All eight in the linear part (most of a night frame): no cube root.
        let mut o = [0.0; LANES];
        for i in 0..LANES {
            o[i] = 24389.0 / 27.0 * t[i];
        }
        return o;
    }
    let mut c = [0.0; LANES];
    for i in 0..LANES {
        c[i] = t[i].max(216.0 / 24389.0);
    }
    let c = cbrt_v(c);
    let mut o = [0.0; LANES];
    for i in 0..LANES {
        o[i] = if t[i] > 216.0 / 24389.0 {
            116.0 * c[i] - 16.0
        } else {
            24389.0 / 27.0 * t[i]
        };
    }
    o
}

/// Cube root of finite `t ≥ 2⁻¹²⁶`, within 2 ulp of `f32::cbrt`: a first
/// guess from the exponent bits (one third of the bit pattern, FreeBSD
/// `s_cbrtf`'s bias), then three Newton steps `y ← (2y + t/y²)/3`
/// (quadratic: 3 % → 1e-3 → 1e-6 → rounding).
#[inline(always)]
fn cbrt_v(t: V) -> V {
    // (127 − 127/3 − 0.0331)·2²³, FreeBSD s_cbrtf.c B1
    const B1: u32 = 709_958_130;
    let mut y = [0.0; LANES];
    for i in 0..LANES {
        // FreeBSD s_cbrtf.c's guess, in integers: bits/3 + B1
        y[i] = f32::from_bits(t[i].to_bits() / 3 + B1);
    }
    for _ in 0..3 {
        for i in 0..LANES {
            y[i] = (2.0 / 3.0) * y[i] + (t[i] * (1.0 / 3.0)) / (y[i] * y[i]);
        }
    }
    y
}

/// `exp(x)` of `LANES` values in [−87, 0] (relative error < 3e-7):
/// `2ⁿ·p(x − n·ln 2)`, `n = round(x/ln 2)`, p the degree-6 Taylor
/// polynomial on |x − n ln 2| ≤ ln 2 / 2.
#[inline(always)]
fn exp_v(x: V) -> V {
    const LN2_HI: f32 = 0.693_145_75;
    const LN2_LO: f32 = 1.428_606_8e-6;
    // 1.5·2²³: adding and subtracting it rounds to the nearest integer
    const ROUND: f32 = 12_582_912.0;
    let mut o = [0.0; LANES];
    for i in 0..LANES {
        let x = x[i].max(-87.0);
        // ROUND + n exactly (|n| ≤ 126): its bits are ROUND's plus n, so 2ⁿ
        // comes from integer arithmetic (no saturating float → int cast).
        let shifted = x * std::f32::consts::LOG2_E + ROUND;
        let n = shifted - ROUND;
        let n_int = shifted.to_bits().wrapping_sub(ROUND.to_bits());
        let r = (x - n * LN2_HI) - n * LN2_LO;
        let p = 1.0
            + r * (1.0
                + r * (0.5
                    + r * (1.0 / 6.0 + r * (1.0 / 24.0 + r * (1.0 / 120.0 + r * (1.0 / 720.0))))));
        let scale = f32::from_bits(n_int.wrapping_add(127) << 23);
        o[i] = p * scale;
    }
    o
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::colour::{lightness, lightness_to_y, rgb_to_lab};

    fn image(w: usize, h: usize, f: impl Fn(usize, usize) -> [f32; 3]) -> RgbImage {
        let mut px = Vec::with_capacity(w * h);
        for y in 0..h {
            for x in 0..w {
                px.push(f(x, y));
            }
        }
        RgbImage::from_pixels(w, h, px).unwrap()
    }

    /// Grey of CIE lightness `l` at a Lab white of 100 cd/m², cd/m².
    fn grey_of_lightness(l: f64) -> [f32; 3] {
        [(lightness_to_y(l) * 100.0) as f32; 3]
    }

    /// 001 §4.3.1 steps 1–4 with eq 12, evaluated directly in f64: every
    /// pixel's σ from its own L* (horizontal) and from its horizontally
    /// blurred L* (vertical), Gaussian weights from `exp`, radius ⌈3σ⌉,
    /// edge pixels repeated, a*, b* kept.
    fn brute_force_eq12(img: &RgbImage, ppd: f64, white: f64) -> Vec<[f64; 3]> {
        let (w, h) = (img.width, img.height);
        // IEC 61966-2-1 matrices and D65 white.
        let m = [
            [0.412_456_4, 0.357_576_1, 0.180_437_5],
            [0.212_672_9, 0.715_152_2, 0.072_175],
            [0.019_333_9, 0.119_192, 0.950_304_1],
        ];
        let mi = [
            [3.240_454_2, -1.537_138_5, -0.498_531_4],
            [-0.969_266, 1.876_010_8, 0.041_556],
            [0.055_643_4, -0.204_025_9, 1.057_225_2],
        ];
        let wn = [0.950_47 * white, white, 1.088_83 * white];
        let f = |t: f64| {
            if t > 216.0 / 24389.0 {
                t.cbrt()
            } else {
                (24389.0 / 27.0 * t + 16.0) / 116.0
            }
        };
        let finv = |v: f64| {
            if v > 6.0 / 29.0 {
                v * v * v
            } else {
                (116.0 * v - 16.0) * 27.0 / 24389.0
            }
        };
        let lab: Vec<[f64; 3]> = img
            .pixels
            .iter()
            .map(|p| {
                let p = p.map(f64::from);
                let xyz: Vec<f64> = (0..3)
                    .map(|i| m[i][0] * p[0] + m[i][1] * p[1] + m[i][2] * p[2])
                    .collect();
                let (fx, fy, fz) = (f(xyz[0] / wn[0]), f(xyz[1] / wn[1]), f(xyz[2] / wn[2]));
                [116.0 * fy - 16.0, 500.0 * (fx - fy), 200.0 * (fy - fz)]
            })
            .collect();
        // 001 eq 12 in Vive Pro pixels, rescaled to this display
        let sigma = |l: f64| (1.0 - l).clamp(0.0, 1.0) * ppd / (1440.0 / 104.0);
        let blur = |v: &dyn Fn(i64) -> f64, s: f64| -> f64 {
            if s <= 0.3 {
                return v(0);
            }
            let r = (3.0 * s).ceil() as i64;
            let (mut acc, mut norm) = (0.0, 0.0);
            for k in -r..=r {
                let g = (-(k * k) as f64 / (2.0 * s * s)).exp();
                acc += g * v(k);
                norm += g;
            }
            acc / norm
        };
        let mut hz = vec![0.0; w * h];
        for y in 0..h {
            for x in 0..w {
                let l = lab[y * w + x][0];
                hz[y * w + x] = blur(
                    &|k| lab[y * w + (x as i64 + k).clamp(0, w as i64 - 1) as usize][0],
                    sigma(l),
                );
            }
        }
        let mut out = vec![[0.0; 3]; w * h];
        for y in 0..h {
            for x in 0..w {
                let hv = hz[y * w + x];
                let l = blur(
                    &|k| hz[(y as i64 + k).clamp(0, h as i64 - 1) as usize * w + x],
                    sigma(hv),
                );
                let [_, a, b] = lab[y * w + x];
                let fy = (l + 16.0) / 116.0;
                let xyz = [
                    finv(fy + a / 500.0) * wn[0],
                    finv(fy) * wn[1],
                    finv(fy - b / 200.0) * wn[2],
                ];
                out[y * w + x] =
                    [0, 1, 2].map(|i| mi[i][0] * xyz[0] + mi[i][1] * xyz[1] + mi[i][2] * xyz[2]);
            }
        }
        out
    }

    #[test]
    fn matches_a_direct_evaluation_of_eq12() {
        // Dark and bright patches, edges, colour, single hot pixels: every
        // pixel gets its own σ.
        // The second size is tall enough for several bands of rows (each
        // with a halo from its neighbours).
        for (w, h) in [(97, 61), (41, 230)] {
            let img = image(w, h, |x, y| {
                let base = 0.002 + 0.1 * ((x / 9 + y / 7) % 5) as f32 / 4.0;
                let tint = [
                    1.0 + 0.3 * ((x * 3 + y) % 4) as f32 / 3.0,
                    1.0,
                    1.0 + 0.5 * ((x + 2 * y) % 3) as f32 / 2.0,
                ];
                let mut p = tint.map(|t| t * base);
                if x > 70 {
                    p = [0.3, 0.25, 0.2]; // L* ≈ 2.5: σ = 0 by eq 12
                }
                if (x * 7 + y * 13) % 97 == 0 {
                    p = [50.0, 40.0, 30.0];
                }
                p
            });
            for ppd in [13.85 * 3.0, 13.85 * 0.4, 50.0] {
                let mut blur = AcuityBlur::new(&AcuityModel::default(), w, h, 1.0 / ppd);
                let mut got = img.clone();
                let changed = blur.apply(&mut got);
                let want = brute_force_eq12(&img, ppd, 100.0);
                let mut worst_l = 0.0f64;
                let mut worst_rel = 0.0f64;
                let mut moved = 0;
                for (i, (g, e)) in got.pixels.iter().zip(&want).enumerate() {
                    let gl = f64::from(rgb_to_lab(g.map(|v| v / 100.0))[0]);
                    let el = f64::from(rgb_to_lab(e.map(|v| (v / 100.0) as f32))[0]);
                    worst_l = worst_l.max((gl - el).abs());
                    let orig_l = f64::from(rgb_to_lab(img.pixels[i].map(|v| v / 100.0))[0]);
                    moved += usize::from((el - orig_l).abs() > 1e-3);
                    for c in 0..3 {
                        let d = (f64::from(g[c]) - e[c]).abs();
                        worst_rel = worst_rel.max(d / e[c].abs().max(1e-3));
                    }
                }
                eprintln!(
                    "acuity vs direct eq 12 at {ppd:.2} ppd: {changed} px changed, {moved} expected to move, \
                 worst |ΔL*| {worst_l:.2e}, worst relative RGB {worst_rel:.2e}"
                );
                assert!(worst_l < 2e-3, "{ppd}: ΔL* {worst_l}");
                assert!(worst_rel < 1e-3, "{ppd}: relative {worst_rel}");
                if ppd > 13.85 {
                    assert!(moved > w * h / 3, "{ppd}: only {moved} pixels blurred");
                } else {
                    // σ ≤ 0.4·1 = 0.4 px: only the darkest pixels blur.
                    assert!(moved < w * h / 2, "{ppd}: {moved}");
                }
            }
        }
    }

    #[test]
    fn simd_rows_match_the_portable_rows_bit_for_bit() {
        // Every build this CPU runs against the portable one: AVX2 alone,
        // and AVX-512 (blocks of 16, a row's last 8 in AVX2).
        let tiers = crate::simd::testing::tiers(
            "simd_rows_match_the_portable_rows_bit_for_bit",
            &[Tier::Avx2, Tier::Avx512],
        );
        if tiers.is_empty() {
            return;
        }
        // The default demo's night view (dark ground, lamps, sky) at three
        // scales, so that blocks fall in L*'s linear part, its cubic part
        // and across both, at two pixel sizes (tap radius 1–3 and more).
        let path = gazelight_test_support::data_path("hdr/blender-world/night.exr");
        let scene = crate::scene::Scene::load(&path, crate::scene::LuminanceScale::default())
            .expect("shared night.exr");
        let mut cases = Vec::new();
        for (hfov_deg, w, h) in [(12.0, 203, 157), (4.0, 181, 90)] {
            let params = crate::scene::ViewParams {
                yaw_deg: -78.4,
                pitch_deg: -6.0,
                hfov_deg,
                width: w,
                height: h,
            };
            let mut view = RgbImage::new(w, h);
            crate::scene::PanoramaView::new(params)
                .expect("view")
                .render(&scene.image, &mut view);
            for gain in [1.0f32, 1e-2, 0.1] {
                let px = view.pixels.iter().map(|p| p.map(|v| v * gain)).collect();
                let img = RgbImage::from_pixels(w, h, px).expect("image");
                cases.push((format!("{hfov_deg}° ×{gain}"), img, params.deg_per_px()));
            }
        }
        // Hot pixels beside dark ones: blocks that take the cube-root path
        // of step 4.
        let hot = image(97, 61, |x, y| {
            if (x * 7 + y * 13) % 31 == 0 {
                [50.0, 40.0, 30.0]
            } else {
                [
                    0.002 * (1 + x % 5) as f32,
                    0.003,
                    0.001 * (1 + y % 3) as f32,
                ]
            }
        });
        cases.push(("hot pixels".into(), hot, 1.0 / 41.55));
        eprintln!("builds compared with the portable one: {tiers:?}");
        for (what, img, dpp) in cases {
            let (w, h) = (img.width, img.height);
            let mut slow = AcuityBlur::new(&AcuityModel::default(), w, h, dpp);
            slow.simd = Simd::PORTABLE;
            let mut b = img.clone();
            let nb = slow.apply(&mut b);
            assert!(nb > 0, "{what}: nothing blurred");
            for &simd in &tiers {
                let mut fast = slow.clone();
                fast.simd = simd;
                let mut a = img.clone();
                let na = fast.apply(&mut a);
                let tier = simd.tier();
                assert_eq!(na, nb, "{what} {tier}: pixels changed");
                let differ = a
                    .pixels
                    .iter()
                    .zip(&b.pixels)
                    .filter(|(p, q)| p.map(f32::to_bits) != q.map(f32::to_bits))
                    .count();
                eprintln!("{what} {tier}: {na} px blurred, {differ} differ");
                assert_eq!(differ, 0, "{what} {tier}");
            }
        }
    }

    #[test]
    fn vector_cbrt_and_exp_match_std() {
        // Against the standard library over the ranges the blur uses:
        // cbrt above Lab's ε (up to 10⁶·ε), exp of −1/(2σ²) for σ > 0.3.
        let mut worst_cbrt = 0.0f64;
        let mut worst_lab = 0.0f32;
        let mut worst_exp = 0.0f64;
        for i in 0..200_000u32 {
            let t = (216.0f32 / 24389.0) * (1.0 + i as f32 * 5.0);
            let got = cbrt_v([t; LANES])[0];
            worst_cbrt = worst_cbrt.max((f64::from(got) / f64::from(t).cbrt() - 1.0).abs());
            let l = lab_g_v([t; LANES])[0];
            worst_lab = worst_lab.max((l - lab_g(t)).abs() / lab_g(t).max(1.0));
            let x = -(i as f32) * (87.0 / 200_000.0);
            let e = exp_v([x; LANES])[0];
            worst_exp = worst_exp.max((f64::from(e) / f64::from(x).exp() - 1.0).abs());
        }
        eprintln!("cbrt_v {worst_cbrt:.2e}, lab_g_v {worst_lab:.2e}, exp_v {worst_exp:.2e}");
        assert!(worst_cbrt < 3e-7, "{worst_cbrt}");
        assert!(worst_lab < 3e-7, "{worst_lab}");
        assert!(worst_exp < 5e-7, "{worst_exp}");
        // Lab's linear part below ε.
        assert_eq!(lab_g_v([1e-3; LANES])[0], lab_g(1e-3));
    }

    /// Standard deviation of the derivative of `l` over `range` (the edge
    /// spread), and its centre.
    fn spread(l: &[f32], range: std::ops::Range<usize>) -> (f64, f64) {
        let (mut m0, mut m1, mut m2) = (0.0f64, 0.0f64, 0.0f64);
        for x in range {
            let d = f64::from(l[x] - l[x - 1]);
            let pos = x as f64 - 0.5;
            m0 += d;
            m1 += d * pos;
            m2 += d * pos * pos;
        }
        let mean = m1 / m0;
        ((m2 / m0 - mean * mean).sqrt(), mean)
    }

    #[test]
    fn sigma_follows_each_pixels_own_lightness() {
        // Two regions of one frame: a small lightness step at L* ≈ 0.1 on
        // the left and at L* ≈ 0.5 on the right. Each step spreads by eq
        // 12's σ of its own region, not by one σ for the frame.
        let (w, h) = (240, 24);
        let img = image(w, h, |x, _| {
            let l = match x {
                0..60 => 0.09,
                60..120 => 0.11,
                120..180 => 0.49,
                _ => 0.51,
            };
            grey_of_lightness(l)
        });
        let ppd = 13.85 * 8.0;
        let mut blur = AcuityBlur::new(&AcuityModel::default(), w, h, 1.0 / ppd);
        let mut im = img.clone();
        blur.apply(&mut im);
        let l: Vec<f32> = (0..w)
            .map(|x| rgb_to_lab(im.get(x, 12).map(|v| v / 100.0))[0])
            .collect();
        for (centre, l_region) in [(60usize, 0.1f64), (180, 0.5)] {
            let (sd, mean) = spread(&l, centre - 35..centre + 35);
            // 001 eq 12, written out: σ = (1 − L)·ppd/13.85
            let expected = (1.0 - l_region) * ppd / 13.85;
            eprintln!(
                "acuity step at L* {l_region}: spread {sd:.3} px, eq 12 σ {expected:.3} px, centre {mean:.3}"
            );
            // Each side blurs with its own σ, so the centroid shifts a little.
            assert!(
                (mean - (centre as f64 - 0.5)).abs() < 0.5,
                "edge moved: {mean}"
            );
            assert!(
                (sd / expected - 1.0).abs() < 0.03,
                "L* {l_region}: {sd} vs {expected}"
            );
        }
        // Rows are alike: the vertical pass keeps them so.
        let top = rgb_to_lab(im.get(58, 0).map(|v| v / 100.0))[0];
        assert!((top - l[58]).abs() < 1e-4);
    }

    #[test]
    fn larson_krawczyk_sigma_per_pixel() {
        // A small step at Y = 0.01 cd/m²: spread = eq 11's σ at that Y.
        let (w, h) = (160, 8);
        let y0 = 0.01f32;
        let img = image(w, h, |x, _| [if x < 80 { y0 * 0.97 } else { y0 * 1.03 }; 3]);
        let dpp = 1.0 / 20.0;
        let mut blur = AcuityBlur::new(&AcuityModel::LarsonKrawczyk, w, h, dpp);
        let mut im = img.clone();
        blur.apply(&mut im);
        let l: Vec<f32> = (0..w)
            .map(|x| rgb_to_lab(im.get(x, 4).map(|v| v / 100.0))[0])
            .collect();
        let (sd, _) = spread(&l, 50..110);
        // 001 eq 13 solved for R, eq 11: σ = ppd / (1.86·√2·R)
        let r = (1.49 + ((0.01f64.ln() + 0.575_646) / 1.64).atan()) / 0.06;
        let expected = 20.0 / (1.86 * 2f64.sqrt() * r);
        eprintln!(
            "Larson/Krawczyk step at 0.01 cd/m²: spread {sd:.3} px, eq 11 σ {expected:.3} px"
        );
        assert!((sd / expected - 1.0).abs() < 0.03, "{sd} vs {expected}");
    }

    #[test]
    fn bright_frames_are_left_alone() {
        // Above L* = 1 eq 12 gives σ = 0: not a bit changes.
        let (w, h) = (64, 48);
        let mut img = image(w, h, |x, y| {
            [0.2 + (x % 7) as f32, 0.15 + (y % 5) as f32, 3.0]
        });
        let orig = img.clone();
        let mut blur = AcuityBlur::new(&AcuityModel::default(), w, h, 1.0 / 40.0);
        assert_eq!(blur.apply(&mut img), 0);
        assert_eq!(img, orig);
        // A display too coarse for σ > 0.3 px never blurs.
        let mut dark = image(w, h, |x, _| [0.001 * (x % 2) as f32; 3]);
        let orig = dark.clone();
        let mut coarse = AcuityBlur::new(&AcuityModel::default(), w, h, 1.0 / 4.0);
        assert_eq!(coarse.max_radius(), 0);
        assert_eq!(coarse.apply(&mut dark), 0);
        assert_eq!(dark, orig);
        let mut none = AcuityBlur::new(&AcuityModel::None, w, h, 1.0 / 40.0);
        assert_eq!(none.apply(&mut dark), 0);
    }

    #[test]
    fn chroma_preserved_and_flat_unchanged() {
        let (w, h) = (48, 32);
        let mut img = image(w, h, |x, y| {
            [
                0.001 + 0.008 * ((x * 7 + y * 3) % 11) as f32 / 10.0,
                0.001 + 0.006 * ((x * 5 + y) % 7) as f32 / 6.0,
                0.0005 + 0.004 * ((x + y * 2) % 5) as f32 / 4.0,
            ]
        });
        let before: Vec<[f32; 3]> = img
            .pixels
            .iter()
            .map(|&p| rgb_to_lab(p.map(|v| v / 100.0)))
            .collect();
        let mut blur = AcuityBlur::new(&AcuityModel::default(), w, h, 1.0 / 40.0);
        let changed = blur.apply(&mut img);
        assert!(changed > w * h / 2, "lightness barely blurred: {changed}");
        for (p, b) in img.pixels.iter().zip(&before) {
            let a = rgb_to_lab(p.map(|v| v / 100.0));
            assert!(
                (a[1] - b[1]).abs() < 2e-3 && (a[2] - b[2]).abs() < 2e-3,
                "{a:?} vs {b:?}"
            );
        }
        let mut flat = image(40, 30, |_, _| [0.003, 0.005, 0.002]);
        let orig = flat.clone();
        blur.apply(&mut flat);
        for (a, b) in flat.pixels.iter().zip(&orig.pixels) {
            for i in 0..3 {
                assert!((a[i] - b[i]).abs() < 1e-5 * b[i], "{a:?} vs {b:?}");
            }
        }
    }

    #[test]
    fn the_f32_sigma_rule_matches_the_model() {
        let lin = AcuityModel::default();
        let lk = AcuityModel::LarsonKrawczyk;
        // The f32 per-pixel rule agrees with the f64 one.
        for (model, dpp) in [(lin, 1.0 / 60.0), (lk, 1.0 / 30.0)] {
            let blur = AcuityBlur::new(&model, 8, 8, dpp);
            for y in [1e-7, 1e-4, 0.01, 0.05, 0.1, 1.0] {
                let l = lightness(y / 100.0) as f32;
                let a = blur.rule.sigma(l, 100.0);
                let b = model.sigma_px(y, dpp);
                assert!(
                    (a - b).abs() <= 1e-4 * b.max(1.0),
                    "{model:?} {y}: {a} vs {b}"
                );
                // Rows are marked wherever a pixel's σ exceeds 0.3 px.
                if a > AcuityBlur::MIN_SIGMA_PX {
                    assert!((y as f32) < blur.blur_below_cd_m2, "{model:?} {y}");
                }
            }
        }
    }
}
