//! Windowed FFT glare at the gaze (001 §4.2.3), with the physical kernel of
//! [`crate::psf`] split into a full-resolution core and a coarse wide field.
//!
//! 001 convolves the frame with the glare kernel by FFT in a window centred
//! on the gaze and blends it with a Gaussian falloff. [`GlareConvolver`] does
//! that on the CPU, for kernels that reach ±20° (and more):
//!
//! # Source weight
//!
//! A source pixel at distance `d` from the gaze (gaze point to pixel centre)
//! glares with weight `w(d) = 1` for `d ≤ d_full` (`full_weight_deg`, default
//! 12°), and beyond it `w = (G(d − d_full) − G(3σ)) / (1 − G(3σ))`,
//! `G(x) = exp(−x² / 2σ²)` (`fade_sigma_deg`, default 2°), which reaches 0 at
//! `R_src = d_full + 3σ` so a source crossing it never pops. Output:
//! `out = (1 − w)·img + K ∗ (w·img)`; the kernel has unit sum per channel, so
//! energy is conserved (up to light spread past the image border, which is
//! lost), and a point source at the gaze becomes exactly the kernel.
//!
//! # Split of the kernel (exact)
//!
//! With `g(d)` a smoothstep from 0 at `r_fine/2` to 1 at `r_fine`
//! (`r_fine` = [`FINE_RADIUS_DEG`] = 2° in display pixels, at most the
//! kernel radius):
//!
//! * **fine** `K_f = (1 − g)·K`, at full resolution, radius `r_fine`: the
//!   Airy core, the steep CIE 10/θ³ part and the near field;
//! * **coarse** `K_c`: `g·K` summed over blocks of `b × b` display pixels
//!   (`b` the smallest odd size ≥ [`COARSE_PX_DEG`] = 0.4°), the smooth wide field out to the
//!   kernel's edge.
//!
//! `Σ K_f + Σ K_c = Σ K` exactly. The kernel itself falls to 0 on the
//! circle of its radius ([`crate::psf::field_taper`]), so the veil of a
//! source ends there without a step instead of at the square's edges
//! (issue 39). The fine part convolves the weighted frame
//! in a window of `W_f ≥ 2 (R_src + r_fine) + 2` pixels. The coarse part
//! box-sums the weighted frame into `b × b` blocks (block centred on the
//! gaze pixel), convolves with `K_c` in a window of `W_c` blocks, and spreads
//! each block's result back by bilinear interpolation of `value / b²` at the
//! block centres (the hat weights of an odd `b` sum to exactly `b` per axis,
//! so each block's light is conserved). The coarse path places a source at
//! its block's centre: the wide field is blurred by at most a block (0.4°),
//! where it changes slowly.
//!
//! # FFTs
//!
//! Window sizes are the smallest `2^k`, `3·2^k` or `5·2^k` that fit (rustfft
//! handles them; a GPU twin pads to a power of two). Linear, not circular,
//! convolution: sources lie within `R_src` of the window centre and the
//! kernel radius fits in the rest. R and G share one complex FFT
//! (`R + iG`): with `Z` its spectrum, `A = (K̂_R + K̂_G)/2`,
//! `B = (K̂_R − K̂_G)/2`, the product `Y(k) = Z(k) A(k) + conj(Z(−k)) B(k)`
//! inverts to `R ∗ K_R + i G ∗ K_G`. B, real, packs two rows into one
//! complex row (`B(2p) + i B(2p+1)`): the row transforms run on half the
//! rows, and the columns are unpacked (`B̂(2p) = (P̂ + P̂*₋)/2`,
//! `B̂(2p+1) = (P̂ − P̂*₋)/(2i)`) for `kx ≤ W/2` only, the rest being their
//! conjugates. Kernels are real, so their spectra are kept for `kx ≤ W/2`.
//!
//! Each 2-D convolution is: row transforms of the rows with sources (in
//! place), then per group of columns `kx` (and their mirrors `W − kx`):
//! gather the columns into a strip (rows without sources as 0), transform,
//! multiply, invert, and write back only the rows with output (inside the
//! image and within reach of a source); then the inverse row transforms of
//! those rows. No transpose, no second buffer, and the multiply runs while
//! the strip is in cache. Each pass splits over the rayon threads (row
//! ranges or column groups). Rows and columns the glare cannot reach
//! (farther from every source than the kernel's radius) are neither
//! inverted nor blended. Spectra are f32; `apply` allocates nothing.
//!
//! # Blending row by row
//!
//! [`GlareConvolver::apply`] is [`GlareConvolver::prepare`] (weight the
//! sources, convolve; the frame is only read) then
//! [`GlareConvolver::blend_row`] on every row the glare reaches. The CPU
//! pipeline calls the two apart: it blends each row inside its band pass,
//! right after reading the row from the scene, so the frame is not read
//! and written once more just for the glare.
//!
//! # Spectra made elsewhere
//!
//! [`GlareConvolver::set_kernel`] computes a kernel's spectra in place
//! (a few milliseconds at 720×800). A live loop instead gives a
//! [`GlarePreparer`] (from [`GlareConvolver::preparer`]) to the thread that
//! builds kernels: it fills a [`GlareSpectra`] there, and the frame thread
//! installs it with [`GlareConvolver::install`], which swaps buffers (no
//! copy, no FFT, no allocation) and hands the old spectra back for reuse.

use std::ops::Range;
use std::sync::Arc;

use rayon::prelude::*;
use rustfft::num_complex::Complex;
use rustfft::{Fft, FftPlanner};
use serde::{Deserialize, Serialize};

use crate::far_glare::{FarField, WeightedSums};
use crate::pipeline::sanitize;
use crate::psf::PsfKernel;
use crate::{RgbImage, VisionError};

/// Radius of the full-resolution part of the kernel, degrees.
pub const FINE_RADIUS_DEG: f64 = 2.0;
/// Smallest size of one coarse block of the wide field, degrees (the block
/// is the smallest odd number of pixels at least this wide).
pub const COARSE_PX_DEG: f64 = 0.4;
/// Largest FFT window, samples per side.
const MAX_WINDOW: usize = 4096;
/// Samples of the source weight's fade (between `d_full` and `r_src`),
/// linearly interpolated: the table's error is < 1e-6 of the weight.
const FADE_TABLE: usize = 2048;
/// Columns per group of the column pass (with as many mirrored ones).
const GROUP: usize = 16;

type C32 = Complex<f32>;
const ZERO: C32 = Complex::new(0.0, 0.0);

/// Where the glare applies around the gaze.
#[derive(Clone, Copy, Debug, PartialEq, Serialize, Deserialize)]
#[serde(default, deny_unknown_fields)]
pub struct GlareWindow {
    /// Sources within this angle of the gaze glare with full weight, degrees.
    pub full_weight_deg: f64,
    /// σ of the Gaussian fade beyond `full_weight_deg`, degrees (the weight
    /// reaches 0 at `full_weight_deg + 3σ`).
    pub fade_sigma_deg: f64,
}

impl Default for GlareWindow {
    fn default() -> Self {
        Self {
            full_weight_deg: 12.0,
            fade_sigma_deg: 2.0,
        }
    }
}

impl GlareWindow {
    /// Checks both fields; the error names the field.
    pub fn validate(&self) -> Result<(), VisionError> {
        if !(self.full_weight_deg.is_finite() && (0.0..=90.0).contains(&self.full_weight_deg)) {
            return Err(VisionError::invalid(
                "glare.full_weight_deg",
                self.full_weight_deg,
                "0..=90 degrees",
            ));
        }
        if !(self.fade_sigma_deg.is_finite()
            && self.fade_sigma_deg > 0.0
            && self.fade_sigma_deg <= 30.0)
        {
            return Err(VisionError::invalid(
                "glare.fade_sigma_deg",
                self.fade_sigma_deg,
                "(0, 30] degrees",
            ));
        }
        Ok(())
    }
}

/// Smallest `2^k`, `3·2^k` or `5·2^k` ≥ `n`.
pub fn good_fft_size(n: usize) -> usize {
    let n = n.max(8);
    [1usize, 3, 5]
        .iter()
        .map(|&f| {
            let mut m = f;
            while m < n {
                m *= 2;
            }
            m
        })
        .min()
        .unwrap_or(n)
}

/// One FFT size: plans, the packed work buffers (spatial, row-major) and
/// one set of column strips and scratch per worker of the parallel passes.
struct Plane {
    w: usize,
    fwd: Arc<dyn Fft<f32>>,
    inv: Arc<dyn Fft<f32>>,
    /// R + iG, `w` rows of `w`.
    rg: Vec<C32>,
    /// B, two rows in one: row `p` holds row `2p` (re) and `2p + 1` (im),
    /// `w/2` rows of `w`.
    b: Vec<C32>,
    /// Groups of the column pass: columns `l` (within `0..=w/2`) and the
    /// columns `m` mirroring them (`w − c` for `0 < c < w/2`).
    groups: Vec<(Range<usize>, Range<usize>)>,
    workers: Vec<Worker>,
}

/// One worker's buffers: gathered columns and FFT scratch.
struct Worker {
    /// Gathered columns `l` then `m` of one group, `2·GROUP` of `w`.
    strip: Vec<C32>,
    /// B's columns `l` unpacked to full length, `GROUP` of `w`.
    cols: Vec<C32>,
    scratch: Vec<C32>,
}

/// The column groups of a window of `w` (even) samples.
fn column_groups(w: usize) -> Vec<(Range<usize>, Range<usize>)> {
    let half = w / 2;
    (0..=half)
        .step_by(GROUP)
        .map(|c0| {
            let c1 = (c0 + GROUP).min(half + 1);
            // Mirrors of the columns max(c0, 1) ..= min(c1 − 1, half − 1).
            let m0 = w + 1 - c1.min(half);
            let m1 = (w + 1 - c0.max(1)).max(m0);
            (c0..c1, m0..m1)
        })
        .collect()
}

/// Row `y` of a buffer of packed row pairs (rows of `w`): the packed row
/// and whether `y` is its imaginary part.
#[inline]
fn packed_row(buf: &mut [C32], w: usize, y: usize) -> (&mut [C32], bool) {
    (&mut buf[y / 2 * w..(y / 2 + 1) * w], y % 2 == 1)
}

/// The real (`odd` false) or imaginary part of `c`.
#[inline]
fn lane(c: &mut C32, odd: bool) -> &mut f32 {
    if odd { &mut c.im } else { &mut c.re }
}

/// Sample (`y`, `x`) of a buffer of packed row pairs (rows of `w`).
#[inline]
fn packed(buf: &mut [C32], w: usize, y: usize, x: usize) -> &mut f32 {
    let (row, odd) = packed_row(buf, w, y);
    lane(&mut row[x], odd)
}

/// Strip index of the column mirroring column `kx` (the `j`-th of `l`):
/// itself for `kx` = 0 and `w/2`, else its place in `m`, after `l`.
#[inline]
fn mirror_in_strip(kx: usize, j: usize, l: &Range<usize>, m: &Range<usize>, w: usize) -> usize {
    if kx == 0 || 2 * kx == w {
        j
    } else {
        l.len() + (w - kx - m.start)
    }
}

impl Plane {
    /// B at row `y`, column `x`.
    #[inline]
    fn b_at(&self, y: usize, x: usize) -> f32 {
        let c = self.b[y / 2 * self.w + x];
        if y % 2 == 1 { c.im } else { c.re }
    }

    fn new(w: usize, workers: usize) -> Self {
        let mut planner = FftPlanner::<f32>::new();
        let fwd = planner.plan_fft_forward(w);
        let inv = planner.plan_fft_inverse(w);
        let s = fwd
            .get_inplace_scratch_len()
            .max(inv.get_inplace_scratch_len());
        Self {
            w,
            fwd,
            inv,
            rg: vec![ZERO; w * w],
            b: vec![ZERO; w / 2 * w],
            groups: column_groups(w),
            workers: (0..workers.max(1))
                .map(|_| Worker {
                    strip: vec![ZERO; 2 * GROUP * w],
                    cols: vec![ZERO; GROUP * w],
                    scratch: vec![ZERO; s],
                })
                .collect(),
        }
    }

    /// Spectra of a kernel already written into `rg` (R + iG) and `b` (B,
    /// packed), wrapped so that offset 0 is index 0.
    fn kernel_spectra(&mut self, out: &mut PlaneSpectra) {
        let w = self.w;
        let h = w / 2;
        let Some(wk) = self.workers.first_mut() else {
            return;
        };
        self.fwd.process_with_scratch(&mut self.rg, &mut wk.scratch);
        self.fwd.process_with_scratch(&mut self.b, &mut wk.scratch);
        let inv_area = 1.0 / (w * w) as f32;
        let rg = Shared::new(&mut self.rg);
        let bb = Shared::new(&mut self.b);
        for (l, m) in &self.groups {
            let n = (l.len() + m.len()) * w;
            // SAFETY: one thread, no other reference to `rg` or `b` lives.
            unsafe { gather(rg, w, w, 0..w, l, m, &mut wk.strip) };
            self.fwd
                .process_with_scratch(&mut wk.strip[..n], &mut wk.scratch);
            for (j, kx) in l.clone().enumerate() {
                let jm = mirror_in_strip(kx, j, l, m, w);
                for ky in 0..w {
                    let z = wk.strip[j * w + ky];
                    let zc = wk.strip[jm * w + (w - ky) % w].conj();
                    // K̂_R = (Z + Z*₋)/2, K̂_G = (Z − Z*₋)/(2i)
                    let kr = (z + zc) * 0.5;
                    let kg = (z - zc) * Complex::new(0.0, -0.5);
                    out.a[kx * w + ky] = (kr + kg) * (0.5 * inv_area);
                    out.b[kx * w + ky] = (kr - kg) * (0.5 * inv_area);
                }
            }
            // SAFETY: as above.
            unsafe { gather(bb, w, h, 0..h, l, m, &mut wk.strip) };
            unpack_b(&wk.strip, l, m, w, &mut wk.cols);
            let n = l.len() * w;
            self.fwd
                .process_with_scratch(&mut wk.cols[..n], &mut wk.scratch);
            for (j, kx) in l.clone().enumerate() {
                for (o, v) in out.blue[kx * w..(kx + 1) * w]
                    .iter_mut()
                    .zip(&wk.cols[j * w..(j + 1) * w])
                {
                    *o = v * inv_area;
                }
            }
        }
    }
}

/// The kernel spectra of one plane over half the frequencies (kernels are
/// real), index `kx·w + ky` for `kx` in `0..=w/2`, 1/W² folded in: `A`,
/// `B` for the packed R + iG, and B's.
struct PlaneSpectra {
    a: Vec<C32>,
    b: Vec<C32>,
    blue: Vec<C32>,
}

impl PlaneSpectra {
    fn new(w: usize) -> Self {
        let n = (w / 2 + 1) * w;
        Self {
            a: vec![ZERO; n],
            b: vec![ZERO; n],
            blue: vec![ZERO; n],
        }
    }
}

/// What a set of spectra was made for: the kernel's size and pixel size
/// and the convolver's windows, radius and block.
#[derive(Clone, Copy, Debug, PartialEq)]
struct SpectraKey {
    kernel_size: usize,
    deg_per_px: f64,
    wf: usize,
    wc: usize,
    r_fine: usize,
    block: usize,
}

/// A kernel's fine and coarse spectra for one [`GlareConvolver`]
/// geometry, made by a [`GlarePreparer`] (on any thread) and installed
/// with [`GlareConvolver::install`].
pub struct GlareSpectra {
    key: SpectraKey,
    fine: PlaneSpectra,
    coarse: PlaneSpectra,
    /// Pupil of the kernel these spectra were made from, mm (NaN: none yet).
    pupil_mm: f64,
}

impl GlareSpectra {
    fn new(key: SpectraKey) -> Self {
        Self {
            key,
            fine: PlaneSpectra::new(key.wf),
            coarse: PlaneSpectra::new(key.wc),
            pupil_mm: f64::NAN,
        }
    }

    /// Pupil diameter of the kernel these spectra were made from, mm (NaN
    /// before the first [`GlarePreparer::prepare`]).
    pub fn pupil_mm(&self) -> f64 {
        self.pupil_mm
    }

    /// Copies `other` into these spectra (a second eye sharing a kernel):
    /// no allocation when both have the same geometry, which is required.
    pub fn copy_from(&mut self, other: &GlareSpectra) -> Result<(), VisionError> {
        if self.key != other.key {
            return Err(VisionError::invalid(
                "glare spectra",
                "spectra of another geometry",
                "spectra of the same convolver geometry",
            ));
        }
        for (d, s) in [
            (&mut self.fine, &other.fine),
            (&mut self.coarse, &other.coarse),
        ] {
            d.a.copy_from_slice(&s.a);
            d.b.copy_from_slice(&s.b);
            d.blue.copy_from_slice(&s.blue);
        }
        self.pupil_mm = other.pupil_mm;
        Ok(())
    }
}

/// Makes [`GlareSpectra`] for the convolver it came from
/// ([`GlareConvolver::preparer`]), with its own FFT plans and buffers, so a
/// kernel's spectra are computed off the frame thread. `Send`.
pub struct GlarePreparer {
    key: SpectraKey,
    fine: Plane,
    coarse: Plane,
}

impl GlarePreparer {
    /// A spectra buffer of this geometry (allocates; make it once).
    pub fn new_spectra(&self) -> GlareSpectra {
        GlareSpectra::new(self.key)
    }

    /// Computes `kernel`'s spectra into `out` (no allocation). The kernel
    /// must have the convolver's size and pixel size, and `out` its
    /// geometry.
    pub fn prepare(
        &mut self,
        kernel: &PsfKernel,
        out: &mut GlareSpectra,
    ) -> Result<(), VisionError> {
        self.prepare_paced(kernel, out, &mut || {})
    }

    /// [`GlarePreparer::prepare`], calling `pace` between its fine and
    /// coarse parts (as [`crate::psf::PsfBuilder::rebuild_paced`] does
    /// between its steps).
    pub fn prepare_paced(
        &mut self,
        kernel: &PsfKernel,
        out: &mut GlareSpectra,
        pace: &mut dyn FnMut(),
    ) -> Result<(), VisionError> {
        compute_spectra(
            &self.key,
            &mut self.fine,
            &mut self.coarse,
            kernel,
            out,
            pace,
        )
    }
}

/// A kernel and, for the CPU convolver, its spectra: what a PSF worker
/// hands the frame thread, installed by swapping buffers
/// (`FramePipeline::install_prepared`).
pub struct PreparedKernel {
    /// The kernel itself (kept by the pipeline, read back by callers).
    pub kernel: PsfKernel,
    /// Its spectra for the CPU convolver (`None`: the installer computes
    /// them itself, or has no CPU convolver).
    pub spectra: Option<GlareSpectra>,
}

fn check_kernel(key: &SpectraKey, kernel: &PsfKernel) -> Result<(), VisionError> {
    if kernel.size != key.kernel_size
        || kernel.deg_per_px != key.deg_per_px
        || kernel.rgb.len() != kernel.size * kernel.size
    {
        return Err(VisionError::invalid(
            "glare kernel",
            format!(
                "{}x{} at {} deg/px",
                kernel.size, kernel.size, kernel.deg_per_px
            ),
            "the size and pixel size the convolver was built for",
        ));
    }
    Ok(())
}

/// Splits `kernel` into its fine and coarse parts (module docs) and
/// computes their spectra into `out`, using `fine` and `coarse` as work.
fn compute_spectra(
    key: &SpectraKey,
    fine: &mut Plane,
    coarse: &mut Plane,
    kernel: &PsfKernel,
    out: &mut GlareSpectra,
    pace: &mut dyn FnMut(),
) -> Result<(), VisionError> {
    check_kernel(key, kernel)?;
    if out.key != *key {
        return Err(VisionError::invalid(
            "glare spectra",
            format!("windows {}/{}", out.key.wf, out.key.wc),
            "spectra made for this convolver",
        ));
    }
    let rk = (kernel.size / 2) as isize;
    let rf = key.r_fine as isize;
    // Fine part: (1 − g) K.
    let wf = fine.w as isize;
    fine.rg.fill(ZERO);
    fine.b.fill(ZERO);
    for dy in -rf..=rf {
        for dx in -rf..=rf {
            let keep = 1.0 - split_weight((dx as f64).hypot(dy as f64), rf as f64);
            if keep <= 0.0 {
                continue;
            }
            let k = kernel.at(dx, dy);
            let (row, col) = (dy.rem_euclid(wf) as usize, dx.rem_euclid(wf) as usize);
            let keep = keep as f32;
            fine.rg[row * fine.w + col] = Complex::new(k[0] * keep, k[1] * keep);
            *packed(&mut fine.b, fine.w, row, col) = k[2] * keep;
        }
    }
    fine.kernel_spectra(&mut out.fine);
    pace();
    // Coarse part: g K summed over b × b blocks.
    let wc = coarse.w as isize;
    let b = key.block as isize;
    let hb = b / 2;
    coarse.rg.fill(ZERO);
    coarse.b.fill(ZERO);
    for dy in -rk..=rk {
        let by = (dy + hb).div_euclid(b);
        for dx in -rk..=rk {
            let g = split_weight((dx as f64).hypot(dy as f64), rf as f64) as f32;
            if g <= 0.0 {
                continue;
            }
            let bx = (dx + hb).div_euclid(b);
            let k = kernel.at(dx, dy);
            let (row, col) = (by.rem_euclid(wc) as usize, bx.rem_euclid(wc) as usize);
            coarse.rg[row * coarse.w + col] += Complex::new(k[0] * g, k[1] * g);
            *packed(&mut coarse.b, coarse.w, row, col) += k[2] * g;
        }
    }
    coarse.kernel_spectra(&mut out.coarse);
    out.pupil_mm = kernel.pupil_mm;
    Ok(())
}

/// A work buffer shared by the workers of one parallel pass, each of which
/// touches only its own rows or its own columns of it.
#[derive(Clone, Copy)]
struct Shared {
    ptr: *mut C32,
    len: usize,
}

// SAFETY: `Shared` only hands out slices through its unsafe `slice`, whose
// callers guarantee that slices used at the same time do not overlap.
unsafe impl Send for Shared {}
// SAFETY: as above.
unsafe impl Sync for Shared {}

impl Shared {
    fn new(v: &mut [C32]) -> Self {
        Self {
            ptr: v.as_mut_ptr(),
            len: v.len(),
        }
    }

    /// `n` samples from `start` (checked against the buffer's length).
    ///
    /// # Safety
    ///
    /// The buffer outlives the slice, and no other slice or reference to
    /// the same samples is used while it lives.
    #[inline]
    unsafe fn slice<'a>(self, start: usize, n: usize) -> &'a mut [C32] {
        assert!(start <= self.len && n <= self.len - start);
        // SAFETY: in bounds (asserted); exclusive by the caller's contract.
        unsafe { std::slice::from_raw_parts_mut(self.ptr.add(start), n) }
    }
}

/// Part `i` of `parts` (nearly) equal parts of `r`.
#[inline]
fn part(r: &Range<usize>, i: usize, parts: usize) -> Range<usize> {
    let n = r.len();
    r.start + n * i / parts..r.start + n * (i + 1) / parts
}

/// Rows per tile of [`gather`] and [`scatter`]: each column of a tile is
/// one run of 8 samples (64 bytes) in the strip. Moving one sample per row
/// and column instead wrote 32 streams 4 KiB apart (the strip's column
/// length), which the L1 cannot hold.
const TILE_ROWS: usize = 8;

/// Copies columns `l` then `m` of `buf` (rows of `w`) into `strip` as
/// columns of length `n`, rows `rows` (< `n`) read, the others zero.
///
/// # Safety
///
/// `buf` holds `n` rows of `w`, and nothing else accesses its columns `l`
/// and `m` meanwhile.
unsafe fn gather(
    buf: Shared,
    w: usize,
    n: usize,
    rows: Range<usize>,
    l: &Range<usize>,
    m: &Range<usize>,
    strip: &mut [C32],
) {
    let nl = l.len();
    let nc = nl + m.len();
    let strip = &mut strip[..nc * n];
    for col in strip.chunks_exact_mut(n) {
        col[..rows.start].fill(ZERO);
        col[rows.end..].fill(ZERO);
    }
    assert!(rows.end <= n);
    for r0 in rows.clone().step_by(TILE_ROWS) {
        let r1 = (r0 + TILE_ROWS).min(rows.end);
        for (c0, cols) in [(0, l), (nl, m)] {
            let mut tile: [&[C32]; TILE_ROWS] = [&[]; TILE_ROWS];
            for (t, r) in tile.iter_mut().zip(r0..r1) {
                // SAFETY: columns l and m are this caller's (contract).
                *t = unsafe { buf.slice(r * w + cols.start, cols.len()) };
            }
            let tile = &tile[..r1 - r0];
            for j in 0..cols.len() {
                let col = &mut strip[(c0 + j) * n + r0..(c0 + j) * n + r1];
                for (d, src) in col.iter_mut().zip(tile) {
                    *d = src[j];
                }
            }
        }
    }
}

/// Writes `strip` (columns `l` then `m`, length `n`) back into rows `rows`
/// of `buf`.
///
/// # Safety
///
/// As [`gather`].
unsafe fn scatter(
    strip: &[C32],
    buf: Shared,
    w: usize,
    n: usize,
    rows: Range<usize>,
    l: &Range<usize>,
    m: &Range<usize>,
) {
    let nl = l.len();
    let strip = &strip[..(nl + m.len()) * n];
    assert!(rows.end <= n);
    for r0 in rows.clone().step_by(TILE_ROWS) {
        let r1 = (r0 + TILE_ROWS).min(rows.end);
        for (c0, cols) in [(0, l), (nl, m)] {
            let mut tile: [&mut [C32]; TILE_ROWS] = Default::default();
            for (t, r) in tile.iter_mut().zip(r0..r1) {
                // SAFETY: columns l and m are this caller's (contract), and
                // the tile's rows are distinct.
                *t = unsafe { buf.slice(r * w + cols.start, cols.len()) };
            }
            let tile = &mut tile[..r1 - r0];
            for j in 0..cols.len() {
                let col = &strip[(c0 + j) * n + r0..(c0 + j) * n + r1];
                for (dst, &v) in tile.iter_mut().zip(col) {
                    dst[j] = v;
                }
            }
        }
    }
}

/// B's columns `l` at full length (`w`) from the row transforms of its
/// packed rows (`strip`: columns `l` then `m`, length `w/2`):
/// `B̂(2p) = (P̂ + P̂*₋)/2`, `B̂(2p + 1) = (P̂ − P̂*₋)/(2i)`.
fn unpack_b(strip: &[C32], l: &Range<usize>, m: &Range<usize>, w: usize, cols: &mut [C32]) {
    let h = w / 2;
    for (j, kx) in l.clone().enumerate() {
        let jm = mirror_in_strip(kx, j, l, m, w);
        let (a, c) = (&strip[j * h..(j + 1) * h], &strip[jm * h..(jm + 1) * h]);
        for ((o, &a), &c) in cols[j * w..(j + 1) * w].chunks_exact_mut(2).zip(a).zip(c) {
            let c = c.conj();
            o[0] = (a + c) * 0.5;
            o[1] = (a - c) * Complex::new(0.0, -0.5);
        }
    }
}

/// The inverse of [`unpack_b`] for a real result: columns `l` of the packed
/// rows from `cols`, and their mirrors `m` as the conjugates.
fn pack_b(cols: &[C32], l: &Range<usize>, m: &Range<usize>, w: usize, strip: &mut [C32]) {
    let h = w / 2;
    let nl = l.len();
    let (sl, sm) = strip.split_at_mut(nl * h);
    for (j, kx) in l.clone().enumerate() {
        let col = &cols[j * w..(j + 1) * w];
        let dst = &mut sl[j * h..(j + 1) * h];
        for (d, e) in dst.iter_mut().zip(col.chunks_exact(2)) {
            // e + i·o
            *d = Complex::new(e[0].re - e[1].im, e[0].im + e[1].re);
        }
        let jm = mirror_in_strip(kx, j, l, m, w);
        if jm != j {
            let jm = jm - nl;
            for (d, e) in sm[jm * h..(jm + 1) * h].iter_mut().zip(col.chunks_exact(2)) {
                // e* + i·o*
                *d = Complex::new(e[0].re + e[1].im, e[1].re - e[0].im);
            }
        }
    }
}

/// `Y(k) = Z(k) A(k) + conj(Z(−k)) B(k)` over the column spectra of one
/// group (`strip`: columns `l` then `m`), each pair `k`, `−k` once: `A`,
/// `B` are stored for `kx ≤ w/2`, and `A(−k) = A(k)*`, `B(−k) = B(k)*`.
fn multiply_rg(
    strip: &mut [C32],
    l: &Range<usize>,
    m: &Range<usize>,
    a: &[C32],
    bs: &[C32],
    w: usize,
) {
    let nl = l.len();
    let (sl, sm) = strip.split_at_mut(nl * w);
    for (j, kx) in l.clone().enumerate() {
        let col = &mut sl[j * w..(j + 1) * w];
        let (ra, rb) = (&a[kx * w..(kx + 1) * w], &bs[kx * w..(kx + 1) * w]);
        let jm = mirror_in_strip(kx, j, l, m, w);
        if jm == j {
            // The column pairs with itself, reversed.
            for ky in 0..=w / 2 {
                let nky = (w - ky) % w;
                let (zi, zj) = (col[ky], col[nky]);
                col[ky] = zi * ra[ky] + zj.conj() * rb[ky];
                if nky != ky {
                    col[nky] = zj * ra[nky] + zi.conj() * rb[nky];
                }
            }
        } else {
            let jm = jm - nl;
            let colm = &mut sm[jm * w..(jm + 1) * w];
            let (zi, zj) = (col[0], colm[0]);
            col[0] = zi * ra[0] + zj.conj() * rb[0];
            colm[0] = (zj.conj() * ra[0] + zi * rb[0]).conj();
            for ky in 1..w {
                let nky = w - ky;
                let (zi, zj) = (col[ky], colm[nky]);
                col[ky] = zi * ra[ky] + zj.conj() * rb[ky];
                colm[nky] = (zj.conj() * ra[ky] + zi * rb[ky]).conj();
            }
        }
    }
}

/// Convolves the plane's R + iG and packed B with `spec`: sources in rows
/// `src`, results wanted in rows `out` (window rows; the other rows of the
/// buffers are left undefined). Row transforms, then per column group:
/// gather, transform, multiply, invert, write back; then row inverses. Each
/// pass is split over the plane's workers.
fn convolve(plane: &mut Plane, spec: &PlaneSpectra, src: Range<usize>, out: Range<usize>) {
    let w = plane.w;
    let h = w / 2;
    let src_p = src.start / 2..src.end.div_ceil(2);
    let out_p = out.start / 2..out.end.div_ceil(2);
    let parts = plane.workers.len();
    let rg = Shared::new(&mut plane.rg);
    let bb = Shared::new(&mut plane.b);
    let (fwd, inv, groups) = (&plane.fwd, &plane.inv, &plane.groups);
    let rows =
        |fft: &Arc<dyn Fft<f32>>, i: usize, wk: &mut Worker, r: &Range<usize>, p: &Range<usize>| {
            let (r, p) = (part(r, i, parts), part(p, i, parts));
            // SAFETY: the workers' parts of the rows are disjoint, and `rg`, `b`
            // are borrowed by nothing else during the pass.
            unsafe {
                if !r.is_empty() {
                    fft.process_with_scratch(rg.slice(r.start * w, r.len() * w), &mut wk.scratch);
                }
                if !p.is_empty() {
                    fft.process_with_scratch(bb.slice(p.start * w, p.len() * w), &mut wk.scratch);
                }
            }
        };
    plane
        .workers
        .par_iter_mut()
        .enumerate()
        .for_each(|(i, wk)| rows(fwd, i, wk, &src, &src_p));
    if out.is_empty() {
        return;
    }
    plane
        .workers
        .par_iter_mut()
        .enumerate()
        .for_each(|(i, wk)| {
            for (l, m) in groups.iter().skip(i).step_by(parts) {
                let n = (l.len() + m.len()) * w;
                // SAFETY: the workers' column groups are disjoint.
                unsafe { gather(rg, w, w, src.clone(), l, m, &mut wk.strip) };
                fwd.process_with_scratch(&mut wk.strip[..n], &mut wk.scratch);
                multiply_rg(&mut wk.strip, l, m, &spec.a, &spec.b, w);
                inv.process_with_scratch(&mut wk.strip[..n], &mut wk.scratch);
                // SAFETY: as above.
                unsafe { scatter(&wk.strip, rg, w, w, out.clone(), l, m) };

                // SAFETY: as above.
                unsafe { gather(bb, w, h, src_p.clone(), l, m, &mut wk.strip) };
                unpack_b(&wk.strip, l, m, w, &mut wk.cols);
                let n = l.len() * w;
                fwd.process_with_scratch(&mut wk.cols[..n], &mut wk.scratch);
                for (j, kx) in l.clone().enumerate() {
                    for (v, k) in wk.cols[j * w..(j + 1) * w]
                        .iter_mut()
                        .zip(&spec.blue[kx * w..(kx + 1) * w])
                    {
                        *v *= *k;
                    }
                }
                inv.process_with_scratch(&mut wk.cols[..n], &mut wk.scratch);
                pack_b(&wk.cols, l, m, w, &mut wk.strip);
                // SAFETY: as above.
                unsafe { scatter(&wk.strip, bb, w, h, out_p.clone(), l, m) };
            }
        });
    plane
        .workers
        .par_iter_mut()
        .enumerate()
        .for_each(|(i, wk)| rows(inv, i, wk, &out, &out_p));
}

/// FFT convolution of a frame with the glare kernel in a window at the gaze.
pub struct GlareConvolver {
    window: GlareWindow,
    key: SpectraKey,
    /// Coarse kernel radius, blocks.
    r_coarse: usize,
    /// Weight reaches 0 here, display pixels.
    r_src: f64,
    d_full: f64,
    sigma: f64,
    fine: Plane,
    coarse: Plane,
    spectra: GlareSpectra,
    /// Source weight over the fine window, W_f².
    weight: Vec<f32>,
    /// The weight's fade at `FADE_TABLE + 1` steps from `d_full` to `r_src`.
    fade: Vec<f32>,
    /// Per pixel offset in the coarse window (`W_c · b`): the coarse block
    /// left of (above) its centre and the bilinear weight of the next one.
    hat: Vec<(i32, f32)>,
    /// The coarse result interpolated along x to display columns, `/ b²`,
    /// 3 floats per column: `(W_c + 2)` rows of `W_c · b` columns (row
    /// `j + 1` holds block row `j`, `j` from −1 to `W_c`).
    hrows: Vec<f32>,
    /// What [`GlareConvolver::blend_row`] adds to each row, set by
    /// [`GlareConvolver::prepare`] (`None`: nothing to add).
    plan: Option<BlendPlan>,
    /// The full-field stray light beyond the kernel ([`crate::far_glare`]),
    /// when set.
    far: Option<FarField>,
}

/// Where the prepared glare lands in the frame (image and window
/// coordinates), from [`GlareConvolver::prepare`].
#[derive(Clone, Debug)]
struct BlendPlan {
    /// Rows with output: the fine rows ∪ the coarse rows.
    rows: Range<i64>,
    /// Fine output rows and columns, image coordinates.
    fine_rows: Range<i64>,
    fine_cols: Range<i64>,
    /// Fine window origin.
    ofx: i64,
    ofy: i64,
    /// Coarse window origin (the y one, for `hat`).
    ocy: i64,
    /// Coarse output rows, image coordinates (empty: no coarse part).
    coarse_rows: Range<i64>,
    /// Coarse output columns: image columns `cx0..cx1` are `hrows`
    /// columns `xs..xe`.
    cx0: usize,
    cx1: usize,
    xs: usize,
    xe: usize,
}

/// The split's geometry for a `kernel_size` kernel at `deg_per_px` and the
/// weight `window`, in display pixels: the one definition the CPU
/// convolver and its GPU twin (`gazelight-gpu/src/glare.rs`) share. Each
/// rounds the needed window sizes to its own FFT sizes (the CPU to
/// `2^k`, `3·2^k`, `5·2^k`, the GPU to `2^k`).
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct GlareSizes {
    /// Radius of the full-resolution core, pixels ([`FINE_RADIUS_DEG`],
    /// at least 1, at most the kernel's radius).
    pub r_fine: usize,
    /// Half the coarse block, pixels.
    pub half_b: usize,
    /// Coarse block `b`: the smallest odd size of at least
    /// [`COARSE_PX_DEG`], pixels.
    pub block: usize,
    /// The kernel's radius in blocks.
    pub r_coarse: usize,
    /// Full-weight radius, pixels.
    pub d_full: f64,
    /// Fade σ, pixels.
    pub sigma: f64,
    /// Source radius `d_full + 3σ`, pixels.
    pub r_src: f64,
    /// Fine window needed for a linear convolution, samples per side.
    pub fine_needed: usize,
    /// Coarse window needed, blocks per side.
    pub coarse_needed: usize,
}

impl GlareSizes {
    /// The geometry (no validation: callers check the window and the
    /// kernel first).
    pub fn new(kernel_size: usize, deg_per_px: f64, window: GlareWindow) -> Self {
        let ppd = 1.0 / deg_per_px;
        let r_kernel = kernel_size / 2;
        let r_fine = ((FINE_RADIUS_DEG * ppd).round() as usize).clamp(1, r_kernel.max(1));
        // The smallest odd block of at least COARSE_PX_DEG (0.4–0.6° above
        // 5 ppd).
        let half_b = (((COARSE_PX_DEG * ppd - 1.0) / 2.0).ceil().max(0.0)) as usize;
        let block = 2 * half_b + 1;
        let r_coarse = (r_kernel + half_b).div_ceil(block);
        let d_full = window.full_weight_deg * ppd;
        let sigma = window.fade_sigma_deg * ppd;
        let r_src = d_full + 3.0 * sigma;
        let src_px = r_src.ceil() as usize + 1;
        Self {
            r_fine,
            half_b,
            block,
            r_coarse,
            d_full,
            sigma,
            r_src,
            fine_needed: 2 * (src_px + r_fine) + 2,
            coarse_needed: 2 * (src_px.div_ceil(block) + 1 + r_coarse) + 2,
        }
    }
}

impl GlareConvolver {
    /// A convolver for `kernel` (at the display's pixels per degree) and the
    /// weight `window`. Errors name the setting when the windows would exceed
    /// 4096 samples.
    pub fn new(kernel: &PsfKernel, window: GlareWindow) -> Result<Self, VisionError> {
        window.validate()?;
        let dpp = kernel.deg_per_px;
        if !(dpp.is_finite() && dpp > 0.0)
            || kernel.size == 0
            || kernel.rgb.len() != kernel.size * kernel.size
        {
            return Err(VisionError::invalid(
                "glare kernel",
                format!("{}x{} at {dpp} deg/px", kernel.size, kernel.size),
                "a square kernel with a finite pixel size",
            ));
        }
        let GlareSizes {
            r_fine,
            half_b,
            block,
            r_coarse,
            d_full,
            sigma,
            r_src,
            fine_needed,
            coarse_needed,
        } = GlareSizes::new(kernel.size, dpp, window);
        let wf = good_fft_size(fine_needed);
        let wc = good_fft_size(coarse_needed);
        if wf > MAX_WINDOW || wc > MAX_WINDOW {
            return Err(VisionError::invalid(
                "glare.full_weight_deg",
                window.full_weight_deg,
                "a weight region (full_weight_deg + 3 fade_sigma_deg) whose FFT window at this ppd is ≤ 4096 px",
            ));
        }
        let key = SpectraKey {
            kernel_size: kernel.size,
            deg_per_px: dpp,
            wf,
            wc,
            r_fine,
            block,
        };
        let fade = (0..=FADE_TABLE)
            .map(|i| {
                let d = d_full + 3.0 * sigma * i as f64 / FADE_TABLE as f64;
                source_weight(d, d_full, sigma) as f32
            })
            .collect();
        let (b, hb) = (block as i64, half_b as i64);
        let hat = (0..(wc * block) as i64)
            .map(|xl| {
                // (xl + ½)/b − ½ = (xl − hb)/b for an odd b.
                let i0 = (xl - hb).div_euclid(b);
                let fx = (xl - hb).rem_euclid(b) as f32 / b as f32;
                (i0 as i32, fx)
            })
            .collect();
        // One set of strips per rayon thread (the passes split over them).
        let workers = rayon::current_num_threads().clamp(1, 8);
        let mut conv = Self {
            window,
            key,
            r_coarse,
            r_src,
            d_full,
            sigma,
            fine: Plane::new(wf, workers),
            coarse: Plane::new(wc, workers),
            spectra: GlareSpectra::new(key),
            weight: vec![0.0; wf * wf],
            fade,
            hat,
            hrows: vec![0.0; (wc + 2) * wc * block * 3],
            plan: None,
            far: None,
        };
        conv.set_kernel(kernel)?;
        Ok(conv)
    }

    /// Adds the full-field stray light beyond the kernel to every frame
    /// ([`crate::far_glare`]; `None` turns it off). Its frame size must be
    /// the frames'; it takes its split from the kernel's radius.
    pub fn set_far_field(&mut self, far: Option<FarField>) {
        self.far = far;
    }

    /// The full-field stray light, when on.
    pub fn far_field(&self) -> Option<&FarField> {
        self.far.as_ref()
    }

    /// The weight settings.
    pub fn window(&self) -> GlareWindow {
        self.window
    }

    /// Fine (full-resolution) FFT window, pixels per side.
    pub fn fine_window_px(&self) -> usize {
        self.key.wf
    }

    /// Coarse FFT window, blocks per side.
    pub fn coarse_window_blocks(&self) -> usize {
        self.key.wc
    }

    /// Coarse block size, display pixels (odd).
    pub fn block_px(&self) -> usize {
        self.key.block
    }

    /// Radius of the full-resolution part of the kernel, pixels.
    pub fn fine_radius_px(&self) -> usize {
        self.key.r_fine
    }

    /// Source distance from the gaze where the weight reaches 0, pixels.
    pub fn source_radius_px(&self) -> f64 {
        self.r_src
    }

    /// Source weight at `d_px` display pixels from the gaze.
    pub fn weight_at(&self, d_px: f64) -> f64 {
        source_weight(d_px, self.d_full, self.sigma)
    }

    /// The fine/coarse split weight `g` at `d_px` pixels from the source.
    pub fn split_at(&self, d_px: f64) -> f64 {
        split_weight(d_px, self.key.r_fine as f64)
    }

    /// Pupil diameter of the kernel whose spectra are installed, mm.
    pub fn kernel_pupil_mm(&self) -> f64 {
        self.spectra.pupil_mm
    }

    /// Caches the spectra of `kernel` (same size and pixel size as the one
    /// given to [`GlareConvolver::new`]; a PSF rebuild for a new pupil).
    /// Computes them here (a few ms at 720×800; see [`GlareConvolver::install`]
    /// for spectra made elsewhere). Allocates nothing.
    pub fn set_kernel(&mut self, kernel: &PsfKernel) -> Result<(), VisionError> {
        compute_spectra(
            &self.key,
            &mut self.fine,
            &mut self.coarse,
            kernel,
            &mut self.spectra,
            &mut || {},
        )
    }

    /// A preparer of spectra for this convolver's geometry, to run on
    /// another thread (allocates its own plans and buffers).
    pub fn preparer(&self) -> GlarePreparer {
        GlarePreparer {
            key: self.key,
            fine: Plane::new(self.key.wf, 1),
            coarse: Plane::new(self.key.wc, 1),
        }
    }

    /// Installs spectra made by a [`GlarePreparer`] of this geometry by
    /// swapping buffers: `spectra` gets the previous ones back (to be
    /// reused). No FFT, no copy, no allocation. An error (nothing changed)
    /// for spectra of another geometry.
    pub fn install(&mut self, spectra: &mut GlareSpectra) -> Result<(), VisionError> {
        if spectra.key != self.key {
            return Err(VisionError::invalid(
                "glare spectra",
                format!(
                    "kernel {} px, windows {}/{}",
                    spectra.key.kernel_size, spectra.key.wf, spectra.key.wc
                ),
                "spectra made for this convolver (its preparer)",
            ));
        }
        if spectra.pupil_mm.is_nan() {
            return Err(VisionError::invalid(
                "glare spectra",
                "empty spectra",
                "spectra filled by GlarePreparer::prepare",
            ));
        }
        std::mem::swap(&mut self.spectra, spectra);
        Ok(())
    }

    /// Convolves `img` with the kernel around `gaze_px` (pixel coordinates,
    /// x right, y down) and blends it in place (see the module docs):
    /// [`GlareConvolver::prepare`], then [`GlareConvolver::blend_row`] on
    /// every row it reaches. Does nothing for a non-finite gaze or an empty
    /// image.
    pub fn apply(&mut self, img: &mut RgbImage, gaze_px: [f64; 2]) {
        self.prepare(img, gaze_px);
        let rows = self.rows_reached();
        let width = img.width;
        let this = &*self;
        img.pixels[rows.start * width..rows.end * width]
            .par_chunks_mut(width)
            .enumerate()
            .for_each(|(k, row)| this.blend_row(rows.start + k, row));
    }

    /// The glare of the frame `src` around `gaze_px` (pixel coordinates,
    /// x right, y down), ready for [`GlareConvolver::blend_row`]: the
    /// weighted sources (NaN, ±∞, negative and subnormal values count as 0)
    /// convolved with the fine and coarse kernels. `src` is only read; the
    /// frame's rows are blended later, each as it is needed (the CPU
    /// pipeline blends them inside its band pass). Prepares nothing for a
    /// non-finite gaze or an empty image.
    ///
    /// With the far field on, its block sums of the whole frame (a read of
    /// the frame, memory-bound) are taken while the window's FFTs
    /// (compute-bound) run on the other workers (`rayon::join`).
    pub fn prepare(&mut self, img: &RgbImage, gaze_px: [f64; 2]) {
        // Out of `self` for the join (a move: no allocation).
        let mut far = self.far.take();
        match far.as_mut().and_then(|f| f.frame_parts(img)) {
            Some((mut sums, mut weighted)) => {
                rayon::join(
                    || sums.take(img),
                    || self.prepare_window(img, gaze_px, Some(&mut weighted)),
                );
            }
            None => self.prepare_window(img, gaze_px, None),
        }
        if let Some(f) = far.as_mut().filter(|f| f.size() == (img.width, img.height)) {
            f.sums_taken();
            f.compute();
        }
        self.far = far;
    }

    /// [`GlareConvolver::prepare`] of the window at the gaze (and the far
    /// field's weighted block sums into `weighted`).
    fn prepare_window(
        &mut self,
        img: &RgbImage,
        gaze_px: [f64; 2],
        weighted: Option<&mut WeightedSums<'_>>,
    ) {
        self.plan = None;
        if !gaze_px[0].is_finite()
            || !gaze_px[1].is_finite()
            || img.width == 0
            || img.height == 0
            || img.pixels.len() != img.width * img.height
        {
            return;
        }
        let (iw, ih) = (img.width as i64, img.height as i64);
        let wf = self.key.wf;
        let wc = self.key.wc;
        let b = self.key.block as i64;
        let hb = b / 2;
        let rf = self.key.r_fine as i64;
        let rcb = self.r_coarse as i64;
        // Far outside the image: clamp so the i64 arithmetic stays exact.
        let limit = (img.width.max(img.height) + 2 * wf * self.key.block) as f64;
        let gx = gaze_px[0].clamp(-limit, limit);
        let gy = gaze_px[1].clamp(-limit, limit);
        let (gxi, gyi) = (gx.floor() as i64, gy.floor() as i64);
        // Fine window origin; coarse block (wc/2) is centred on the gaze pixel.
        let (ofx, ofy) = (gxi - (wf / 2) as i64, gyi - (wf / 2) as i64);
        let (ocx, ocy) = (
            gxi - hb - (wc / 2) as i64 * b,
            gyi - hb - (wc / 2) as i64 * b,
        );
        // Source pixels: within r_src of the gaze, inside the image.
        let rs = self.r_src.ceil() as i64 + 1;
        let sx0 = (gxi - rs).max(0);
        let sx1 = (gxi + rs + 1).min(iw);
        let sy0 = (gyi - rs).max(0);
        let sy1 = (gyi + rs + 1).min(ih);
        if sx0 >= sx1 || sy0 >= sy1 {
            return;
        }
        // Fine output (sources ± r_fine) in the image, image coordinates.
        let (fox0, fox1) = ((sx0 - rf).max(0), (sx1 + rf).min(iw));
        let (foy0, foy1) = ((sy0 - rf).max(0), (sy1 + rf).min(ih));
        // Source blocks and coarse output blocks (sources ± r_coarse).
        let c_src_x = (sx0 - ocx) / b..(sx1 - 1 - ocx) / b + 1;
        let c_src_y = (sy0 - ocy) / b..(sy1 - 1 - ocy) / b + 1;
        let cbx = (c_src_x.start - rcb).max(0)..(c_src_x.end + rcb).min(wc as i64);
        let cby = (c_src_y.start - rcb).max(0)..(c_src_y.end + rcb).min(wc as i64);

        // Weighted sources into the fine window (every column of the source
        // rows written) and their block sums into the coarse one.
        self.weight[(foy0 - ofy) as usize * wf..(foy1 - ofy) as usize * wf].fill(0.0);
        let (cs0, cs1) = (c_src_y.start as usize, c_src_y.end as usize);
        self.coarse.rg[cs0 * wc..cs1 * wc].fill(ZERO);
        self.coarse.b[cs0 / 2 * wc..cs1.div_ceil(2) * wc].fill(ZERO);
        // B's packed rows (with the partner rows outside the sources) are
        // cleared whole, then only the weighted sources written.
        let (fs0, fs1) = ((sy0 - ofy) as usize, (sy1 - ofy) as usize);
        self.fine.b[fs0 / 2 * wf..fs1.div_ceil(2) * wf].fill(ZERO);
        let d_full2 = (self.d_full * self.d_full) as f32;
        let r_src2 = (self.r_src * self.r_src) as f32;
        let fade_d0 = self.d_full as f32;
        let fade_step = (FADE_TABLE as f64 / (3.0 * self.sigma)) as f32;
        let fade = &self.fade;
        let (fx0, fx1) = ((sx0 - ofx) as usize, (sx1 - ofx) as usize);
        let off_x = (0.5 - (gx - gxi as f64)) as f32;
        let off_y = (0.5 - (gy - gyi as f64)) as f32;
        let width = img.width;
        let pixels = &img.pixels;
        // Fine rows in pairs (one packed B row each), in parallel.
        let (p0, p1) = (fs0 / 2, fs1.div_ceil(2));
        self.fine.b[p0 * wf..p1 * wf]
            .par_chunks_mut(wf)
            .zip(self.fine.rg[2 * p0 * wf..2 * p1 * wf].par_chunks_mut(2 * wf))
            .zip(self.weight[2 * p0 * wf..2 * p1 * wf].par_chunks_mut(2 * wf))
            .enumerate()
            .for_each(|(k, ((fb, frg2), fw2))| {
                for (odd, (frg, fw)) in frg2
                    .chunks_exact_mut(wf)
                    .zip(fw2.chunks_exact_mut(wf))
                    .enumerate()
                {
                    let fj = 2 * (p0 + k) + odd;
                    let y = ofy + fj as i64;
                    if !(sy0..sy1).contains(&y) {
                        continue;
                    }
                    let dy = (y - gyi) as f32 + off_y;
                    let dy2 = dy * dy;
                    let src = &pixels[y as usize * width..(y as usize + 1) * width];
                    // The sources of the row after next (this worker's
                    // next pair): a new stream every row, which the
                    // hardware prefetcher starts late.
                    if y + 2 < sy1 {
                        let next = (y + 2) as usize * width;
                        crate::image::prefetch(&pixels[next + sx0 as usize..next + sx1 as usize]);
                    }
                    frg[..fx0].fill(ZERO);
                    frg[fx1..].fill(ZERO);
                    for x in sx0..sx1 {
                        let fi = (x - ofx) as usize;
                        let dx = (x - gxi) as f32 + off_x;
                        let d2 = dx * dx + dy2;
                        let wgt = if d2 <= d_full2 {
                            1.0
                        } else if d2 >= r_src2 {
                            0.0
                        } else {
                            let u = ((d2.sqrt() - fade_d0) * fade_step).max(0.0);
                            let i = (u as usize).min(FADE_TABLE - 1);
                            let t = u - i as f32;
                            fade[i] + (fade[i + 1] - fade[i]) * t
                        };
                        if wgt > 0.0 {
                            let p = src[x as usize].map(sanitize);
                            frg[fi] = Complex::new(p[0] * wgt, p[1] * wgt);
                            *lane(&mut fb[fi], odd == 1) = p[2] * wgt;
                            fw[fi] = wgt;
                        } else {
                            frg[fi] = ZERO;
                        }
                    }
                }
            });
        // Their block sums, block rows in pairs (one packed B row each).
        let (q0, q1) = (cs0 / 2, cs1.div_ceil(2));
        let fine = &self.fine;
        self.coarse.b[q0 * wc..q1 * wc]
            .par_chunks_mut(wc)
            .zip(self.coarse.rg[2 * q0 * wc..2 * q1 * wc].par_chunks_mut(2 * wc))
            .enumerate()
            .for_each(|(k, (cb, crg2))| {
                for (odd, crg) in crg2.chunks_exact_mut(wc).enumerate() {
                    let cj = 2 * (q0 + k) + odd;
                    if !(cs0..cs1).contains(&cj) {
                        continue;
                    }
                    let y0 = (ocy + cj as i64 * b).max(sy0);
                    let y1 = (ocy + (cj as i64 + 1) * b).min(sy1);
                    for y in y0..y1 {
                        let fj = (y - ofy) as usize;
                        let frg = &fine.rg[fj * wf + fx0..fj * wf + fx1];
                        let fb = &fine.b[fj / 2 * wf + fx0..fj / 2 * wf + fx1];
                        let f_odd = fj % 2 == 1;
                        let mut ci = ((sx0 - ocx) / b) as usize;
                        let mut cr = (sx0 - ocx) % b;
                        for (&v, bl) in frg.iter().zip(fb) {
                            crg[ci] += v;
                            *lane(&mut cb[ci], odd == 1) += if f_odd { bl.im } else { bl.re };
                            cr += 1;
                            if cr == b {
                                cr = 0;
                                ci += 1;
                            }
                        }
                    }
                }
            });
        // The far field's weighted sources (w · L), from the fine plane,
        // a block's columns at a time.
        if let Some(weighted) = weighted {
            let fine = &self.fine;
            let (sx, sx_end) = (sx0 as usize, sx1 as usize);
            let bp = weighted.block_px();
            weighted.add_rows(sy0 as usize, sy1 as usize, |y, row| {
                let fj = (y as i64 - ofy) as usize;
                let rg = &fine.rg[fj * wf + fx0..fj * wf + fx1];
                let bl = &fine.b[fj / 2 * wf + fx0..fj / 2 * wf + fx1];
                let odd = fj % 2 == 1;
                let mut x = sx;
                while x < sx_end {
                    let end = ((x / bp + 1) * bp).min(sx_end);
                    let (k0, k1) = (x - sx, end - sx);
                    let mut t = [0.0f32; 3];
                    for (v, b) in rg[k0..k1].iter().zip(&bl[k0..k1]) {
                        t[0] += v.re;
                        t[1] += v.im;
                        t[2] += if odd { b.im } else { b.re };
                    }
                    let acc = &mut row[x / bp];
                    for ch in 0..3 {
                        acc[ch] += t[ch];
                    }
                    x = end;
                }
            });
        }
        // Rows with sources, rows with output (window coordinates).
        let f_src = (sy0 - ofy) as usize..(sy1 - ofy) as usize;
        let f_out = (foy0 - ofy) as usize..(foy1 - ofy) as usize;
        let c_src = c_src_y.start as usize..c_src_y.end as usize;
        let c_out = cby.start as usize..cby.end as usize;
        convolve(&mut self.fine, &self.spectra.fine, f_src, f_out);
        convolve(&mut self.coarse, &self.spectra.coarse, c_src, c_out);

        // Blend: out = (1 − w) img + fine + bilinear(coarse / b²).
        let span = wc * self.key.block;
        // Coarse output pixels (offsets in the coarse window): those whose
        // two bilinear blocks lie in cby − 1 ..= cby.end.
        let pix = |blocks: &Range<i64>, o: i64, n: i64| {
            let lo = ((blocks.start - 1) * b + hb).max(0).max(-o);
            let hi = (blocks.end * b + hb).min(span as i64).min(n - o);
            lo..hi.max(lo)
        };
        let cxl = pix(&cbx, ocx, iw);
        let cyl = pix(&cby, ocy, ih);
        let inv_b2 = 1.0 / (b * b) as f32;
        let row3 = span * 3;
        // hrows rows cby.start .. cby.end + 2 (blocks cby − 1 ..= cby.end),
        // columns cxl.
        let (xs, xe) = (cxl.start as usize, cxl.end as usize);
        if !cxl.is_empty() && !cyl.is_empty() {
            let h0 = cby.start as usize;
            let h1 = cby.end as usize + 2;
            let hat = &self.hat;
            let coarse = &self.coarse;
            let cbx = cbx.clone();
            self.hrows[h0 * row3..h1 * row3]
                .par_chunks_mut(row3)
                .enumerate()
                .for_each(|(k, hrow)| {
                    let hrow = &mut hrow[xs * 3..xe * 3];
                    // hrows row h holds block row h − 1.
                    let j = (h0 + k) as i64 - 1;
                    if !cby.contains(&j) {
                        hrow.fill(0.0);
                        return;
                    }
                    let base = j as usize * wc;
                    let at = |i: i32| -> [f32; 3] {
                        if !cbx.contains(&i64::from(i)) {
                            return [0.0; 3];
                        }
                        let idx = base + i as usize;
                        let rg = coarse.rg[idx];
                        [rg.re, rg.im, coarse.b_at(j as usize, i as usize)]
                    };
                    // Runs of columns between the same two block centres.
                    let mut x = xs;
                    while x < xe {
                        let i0 = hat[x].0;
                        let run = hat[x..xe].iter().take_while(|h| h.0 == i0).count();
                        let (a, c) = (at(i0), at(i0 + 1));
                        let out = &mut hrow[(x - xs) * 3..(x - xs + run) * 3];
                        for (h, &(_, fx)) in out.chunks_exact_mut(3).zip(&hat[x..x + run]) {
                            for ch in 0..3 {
                                h[ch] = (a[ch] * (1.0 - fx) + c[ch] * fx) * inv_b2;
                            }
                        }
                        x += run;
                    }
                });
        }
        // Rows with output: the fine rows ∪ the coarse rows.
        let (cy0, cy1) = (ocy + cyl.start, ocy + cyl.end);
        let (y0, y1) = if cyl.is_empty() {
            (foy0, foy1)
        } else {
            (foy0.min(cy0), foy1.max(cy1))
        };
        if y0 >= y1 {
            return;
        }
        self.plan = Some(BlendPlan {
            rows: y0..y1,
            fine_rows: foy0..foy1,
            fine_cols: fox0..fox1,
            ofx,
            ofy,
            ocy,
            coarse_rows: if cxl.is_empty() { 0..0 } else { cy0..cy1 },
            cx0: (ocx + cxl.start).max(0) as usize,
            cx1: (ocx + cxl.end).max(0) as usize,
            xs,
            xe,
        });
    }

    /// Rows `rows` of the frame get glare from [`GlareConvolver::prepare`]
    /// (empty: none; `0..0` before the first prepare).
    pub fn rows_reached(&self) -> Range<usize> {
        if let Some(far) = self.far.as_ref().filter(|f| f.is_ready()) {
            return 0..far.size().1;
        }
        self.plan
            .as_ref()
            .map_or(0..0, |p| p.rows.start as usize..p.rows.end as usize)
    }

    /// Blends the prepared glare into row `y` of the frame (`row`, its
    /// pixels as given to [`GlareConvolver::prepare`]):
    /// `(1 − w)·row + fine + bilinear(coarse / b²)`. Rows outside
    /// [`GlareConvolver::rows_reached`], or a `row` too short for the
    /// columns the glare reaches (not a row of the prepared frame), are
    /// left as they are.
    ///
    /// Always inlined: the pipeline's row source compiles it inside its
    /// AVX-512 and AVX2 twins.
    #[inline(always)]
    pub fn blend_row(&self, y: usize, row: &mut [[f32; 3]]) {
        self.make_row(y, None, row);
    }

    /// Row `y` of the frame made from its scene row `src` (as long as
    /// `row`): sanitised ([`crate::pipeline::sanitize`]), then
    /// [`GlareConvolver::blend_row`] — the same values, with the far
    /// field's columns sanitised, kept and veiled in one pass. Always
    /// inlined, as `blend_row`.
    #[inline(always)]
    pub(crate) fn fill_row(&self, y: usize, src: &[[f32; 3]], row: &mut [[f32; 3]]) {
        self.make_row(y, Some(src), row);
    }

    /// [`GlareConvolver::blend_row`] of `row`, or of the sanitised `src`
    /// written to `row` ([`GlareConvolver::fill_row`]).
    #[inline(always)]
    fn make_row(&self, y: usize, src: Option<&[[f32; 3]]>, row: &mut [[f32; 3]]) {
        let far = self
            .far
            .as_ref()
            .filter(|f| f.is_ready() && row.len() >= f.size().0);
        let yu = y;
        let y = y as i64;
        let plan = self
            .plan
            .as_ref()
            .filter(|p| p.rows.contains(&y) && row.len() >= p.fine_cols.end as usize);
        // What a pixel keeps of its own light: `k0 − s·w` (1 − w without
        // the far field; with it, `(1 − w)(1 − E_near) − E_tail`).
        let (k0, ks) = match far {
            Some(f) => (f.keep(0.0), f.keep(0.0) - f.keep(1.0)),
            None => (1.0, 1.0),
        };
        // Pixels outside the fine window (w = 0): their light times k0
        // plus the far veil, before the coarse wide field is added.
        let seg = plan.filter(|p| p.fine_rows.contains(&y)).map_or(0..0, |p| {
            p.fine_cols.start as usize..p.fine_cols.end as usize
        });
        match (far, src) {
            (Some(f), Some(src)) if src.len() == row.len() => {
                let width = f.size().0;
                let (s0, s1) = (seg.start.min(width), seg.end.min(width));
                f.fill_cols(yu, src, row, k0, 0..s0);
                sanitize_into(&mut row[s0..s1], &src[s0..s1]);
                f.fill_cols(yu, src, row, k0, s1..width);
                sanitize_into(&mut row[width..], &src[width..]);
            }
            (far, src) => {
                if let Some(src) = src {
                    sanitize_into(row, src);
                }
                if let Some(f) = far {
                    let width = f.size().0;
                    f.blend_cols(yu, row, k0, 0..seg.start.min(width));
                    f.blend_cols(yu, row, k0, seg.end.min(width)..width);
                }
            }
        }
        if let Some(plan) = plan {
            self.blend_window_row(plan, y, row, k0, ks);
        }
        if let Some(f) = far {
            // The fine window's pixels (their own light already kept).
            f.blend_cols(yu, row, 1.0, seg);
        }
    }

    /// The window's part of [`GlareConvolver::blend_row`]: the fine row
    /// with `keep = k0 − ks·w`, and the coarse wide field.
    #[inline]
    fn blend_window_row(&self, plan: &BlendPlan, y: i64, row: &mut [[f32; 3]], k0: f32, ks: f32) {
        let wf = self.key.wf;
        let (fine, weight, hrows, hat) = (&self.fine, &self.weight, &self.hrows, &self.hat);
        let row3 = self.key.wc * self.key.block * 3;
        let (fox0, fox1) = (plan.fine_cols.start, plan.fine_cols.end);
        let (ofx, ofy) = (plan.ofx, plan.ofy);
        if plan.fine_rows.contains(&y) {
            // (1 − w)·img + fine.
            let fj = (y - ofy) as usize;
            let (x0, x1) = ((fox0 - ofx) as usize, (fox1 - ofx) as usize);
            let (f0, f1) = (fj * wf + x0, fj * wf + x1);
            let (p0, p1) = (fj / 2 * wf + x0, fj / 2 * wf + x1);
            let odd = fj % 2 == 1;
            let px = &mut row[fox0 as usize..fox1 as usize];
            for (((p, &w), rg), bl) in px
                .iter_mut()
                .zip(&weight[f0..f1])
                .zip(&fine.rg[f0..f1])
                .zip(&fine.b[p0..p1])
            {
                let keep = k0 - ks * w;
                p[0] = p[0] * keep + rg.re;
                p[1] = p[1] * keep + rg.im;
                p[2] = p[2] * keep + if odd { bl.im } else { bl.re };
            }
        }
        if plan.coarse_rows.contains(&y) && plan.cx1 <= row.len() {
            // + the coarse wide field.
            let (xs, xe) = (plan.xs, plan.xe);
            let (j0, fy) = hat[(y - plan.ocy) as usize];
            let lo = (j0 + 1) as usize * row3;
            let hi = lo + row3;
            let lo = &hrows[lo + xs * 3..lo + xe * 3];
            let hi = &hrows[hi + xs * 3..hi + xe * 3];
            let px = row[plan.cx0..plan.cx1].as_flattened_mut();
            for ((p, &a), &c) in px.iter_mut().zip(lo).zip(hi) {
                *p += a * (1.0 - fy) + c * fy;
            }
        }
    }
}

/// Source weight: 1 within `d_full`, Gaussian fade (σ) to 0 at `d_full + 3σ`.
#[inline]
fn source_weight(d: f64, d_full: f64, sigma: f64) -> f64 {
    if d <= d_full {
        return 1.0;
    }
    let x = d - d_full;
    if x >= 3.0 * sigma {
        return 0.0;
    }
    let g_r = (-4.5f64).exp(); // G(3σ) = exp(−9/2)
    (((-x * x / (2.0 * sigma * sigma)).exp() - g_r) / (1.0 - g_r)).clamp(0.0, 1.0)
}

/// The fine/coarse split `g`: smoothstep from 0 at `r_fine/2` to 1 at `r_fine`.
#[inline]
fn split_weight(d: f64, r_fine: f64) -> f64 {
    let s = ((d - 0.5 * r_fine) / (0.5 * r_fine)).clamp(0.0, 1.0);
    s * s * (3.0 - 2.0 * s)
}

/// `dst = sanitize(src)`, sample by sample.
#[inline(always)]
fn sanitize_into(dst: &mut [[f32; 3]], src: &[[f32; 3]]) {
    for (d, s) in dst.as_flattened_mut().iter_mut().zip(src.as_flattened()) {
        *d = sanitize(*s);
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::pipeline::{DisplayFrame, FrameInput, FramePipeline, PipelineConfig};
    use crate::psf::{PsfParams, build_kernel};

    fn kernel(ppd: f64, field_deg: f64) -> PsfKernel {
        build_kernel(&PsfParams {
            ppd,
            field_deg,
            wavelength_count: 12,
            ..PsfParams::default()
        })
        .unwrap()
    }

    fn total(img: &RgbImage) -> [f64; 3] {
        let mut t = [0.0f64; 3];
        for p in &img.pixels {
            for c in 0..3 {
                t[c] += f64::from(p[c]);
            }
        }
        t
    }

    /// CIE 146:2002 General Disability Glare equation, L_veil / E_glare in
    /// sr⁻¹, written out independently of the code under test.
    fn cie146(theta_deg: f64, age: f64, p: f64) -> f64 {
        10.0 / theta_deg.powi(3)
            + (5.0 / theta_deg.powi(2) + 0.1 * p / theta_deg) * (1.0 + (age / 62.5).powi(4))
            + 0.0025 * p
    }

    use crate::image::ring_mean_luminance as ring_luminance;

    #[test]
    fn point_source_at_the_gaze_becomes_the_kernel() {
        let k = kernel(13.85, 40.0);
        let mut conv = GlareConvolver::new(&k, GlareWindow::default()).unwrap();
        let (w, h) = (640, 600);
        let mut img = RgbImage::new(w, h);
        let (cx, cy) = (320usize, 300usize);
        *img.get_mut(cx, cy) = [1.0, 1.0, 1.0];
        conv.apply(&mut img, [cx as f64 + 0.5, cy as f64 + 0.5]);
        // The fine core (g = 0 inside r_fine/2, away from the coarse spread)
        // is exactly the kernel.
        // Coarse blocks start ≈ r_fine/2 − b/√2 out and spread one block in.
        let exact = conv.fine_radius_px() as f64 / 2.0 - 1.5 * conv.block_px() as f64 - 1.0;
        assert!(exact >= 1.0, "test needs an exact core: {exact}");
        let e = exact.floor() as isize;
        let mut max_err = 0.0f32;
        for dy in -e..=e {
            for dx in -e..=e {
                if ((dx * dx + dy * dy) as f64).sqrt() > exact {
                    continue;
                }
                let want = k.at(dx, dy);
                let got = img.get((cx as isize + dx) as usize, (cy as isize + dy) as usize);
                for ch in 0..3 {
                    max_err = max_err.max((want[ch] - got[ch]).abs());
                }
            }
        }
        assert!(max_err < 1e-5, "core: max |out − kernel| = {max_err}");
        // The wide field follows the kernel ring by ring within 10 % out to
        // 0.9 r. Beyond, the kernel's far taper takes it to 0 at r, and the
        // coarse path's blur by a block (0.4°) is compared with the ring at
        // 0.9 r: within 10 % of it.
        let r = k.centre();
        let mut kimg = RgbImage::new(2 * r + 1, 2 * r + 1);
        for (i, p) in kimg.pixels.iter_mut().enumerate() {
            *p = k.rgb[i];
        }
        let d_tail = (0.9 * r as f64) as usize;
        let tail_ref = ring_luminance(&kimg, r, r, d_tail);
        let (mut worst, mut worst_tail) = (0.0f64, 0.0f64);
        for d in conv.fine_radius_px()..r - 2 {
            let want = ring_luminance(&kimg, r, r, d);
            let got = ring_luminance(&img, cx, cy, d);
            if d <= d_tail {
                worst = worst.max((got / want - 1.0).abs());
            } else {
                worst_tail = worst_tail.max((got - want).abs() / tail_ref);
            }
        }
        eprintln!(
            "wide field vs kernel, worst ring error {:.2} % to 0.9 r, {:.2} % of the ring at 0.9 r beyond",
            worst * 100.0,
            worst_tail * 100.0
        );
        assert!(worst < 0.1, "{worst}");
        assert!(worst_tail < 0.1, "{worst_tail}");
        for (c, t) in total(&img).iter().enumerate() {
            assert!((t - 1.0).abs() < 1e-3, "channel {c}: {t}");
        }
    }

    #[test]
    fn energy_is_conserved() {
        let k = kernel(13.85, 40.0);
        let mut conv = GlareConvolver::new(&k, GlareWindow::default()).unwrap();
        let d_full = 12.0 * 13.85;
        for (dx, dy) in [(0.0, 0.0), (40.0, -30.0), (d_full + 10.0, 0.0)] {
            let mut img = RgbImage::new(1000, 1000);
            let (sx, sy) = ((500.0 + dx) as usize, (500.0 + dy) as usize);
            *img.get_mut(sx, sy) = [1000.0, 500.0, 250.0];
            conv.apply(&mut img, [500.5, 500.5]);
            let t = total(&img);
            for (c, want) in [1000.0, 500.0, 250.0].iter().enumerate() {
                assert!(
                    (t[c] - want).abs() / want < 1e-3,
                    "source ({dx},{dy}): channel {c} {} vs {want}",
                    t[c]
                );
            }
            assert!(img.get(sx, sy)[0] < 999.0, "the source glared");
        }
    }

    #[test]
    fn full_weight_near_the_gaze_fade_beyond() {
        let k = kernel(13.85, 40.0);
        let conv = GlareConvolver::new(&k, GlareWindow::default()).unwrap();
        let ppd = 13.85;
        assert_eq!(conv.weight_at(0.0), 1.0);
        assert_eq!(conv.weight_at(12.0 * ppd), 1.0);
        assert!(conv.weight_at(13.0 * ppd) < 1.0 && conv.weight_at(13.0 * ppd) > 0.8);
        assert_eq!(conv.weight_at(18.0 * ppd + 1.0), 0.0);
        let mut last = 1.0;
        for i in 0..100 {
            let w = conv.weight_at(12.0 * ppd + i as f64 * 0.06 * ppd);
            assert!(w <= last);
            last = w;
        }
        // A source beyond the fade does not glare; the frame outside the
        // coarse window is untouched.
        let mut conv = conv;
        let mut img = RgbImage::new(1400, 400);
        *img.get_mut(1300, 200) = [1e6; 3];
        let before = img.clone();
        conv.apply(&mut img, [200.0, 200.0]);
        assert_eq!(img, before);
    }

    #[test]
    fn gaze_at_or_outside_the_corners_does_not_panic() {
        let k = kernel(8.0, 20.0);
        let mut conv = GlareConvolver::new(&k, GlareWindow::default()).unwrap();
        let mut s = 7u64;
        let pixels = (0..90 * 70)
            .map(|_| {
                s = s
                    .wrapping_mul(6364136223846793005)
                    .wrapping_add(1442695040888963407);
                let v = ((s >> 40) as f32) / (1u64 << 24) as f32;
                [v, v * 0.5, v * 0.25]
            })
            .collect();
        let base = RgbImage::from_pixels(90, 70, pixels).unwrap();
        for gaze in [
            [0.0, 0.0],
            [-0.5, -0.5],
            [89.9, 69.9],
            [90.0, 70.0],
            [-40.0, 30.0],
            [130.0, -60.0],
            [-1e9, 1e9],
            [1e300, -1e300],
            [f64::NAN, 10.0],
            [f64::INFINITY, 10.0],
        ] {
            let mut img = base.clone();
            conv.apply(&mut img, gaze);
            assert!(img.pixels.iter().all(|p| p.iter().all(|v| v.is_finite())));
            let (a, b) = (total(&img), total(&base));
            assert!(a[1] <= b[1] * 1.0001, "{gaze:?}: {a:?} vs {b:?}");
        }
        // A mismatched kernel is refused.
        let other = kernel(8.0, 10.0);
        assert!(conv.set_kernel(&other).is_err());
        assert!(
            GlareWindow {
                full_weight_deg: -1.0,
                ..GlareWindow::default()
            }
            .validate()
            .is_err()
        );
        assert!(
            GlareWindow {
                fade_sigma_deg: 0.0,
                ..GlareWindow::default()
            }
            .validate()
            .is_err()
        );
    }

    /// The model of the module docs evaluated directly (no FFT): the fine
    /// part `(1 − g)K ∗ (w·img)`, the coarse part `g·K` summed over blocks
    /// convolved with the weighted frame's block sums and spread back
    /// bilinearly, blended as `(1 − w)·img + fine + coarse`.
    fn direct(
        conv: &GlareConvolver,
        k: &PsfKernel,
        img: &RgbImage,
        gaze: [f64; 2],
    ) -> Vec<[f64; 3]> {
        let key = conv.key;
        let (wc, b, rf) = (key.wc as i64, key.block as i64, key.r_fine as i64);
        let hb = b / 2;
        let (iw, ih) = (img.width as i64, img.height as i64);
        let (gxi, gyi) = (gaze[0].floor() as i64, gaze[1].floor() as i64);
        let (ocx, ocy) = (gxi - hb - wc / 2 * b, gyi - hb - wc / 2 * b);
        let rk = (k.size / 2) as i64;
        // Fine taps and coarse block kernel.
        let mut fine = vec![];
        for dy in -rf..=rf {
            for dx in -rf..=rf {
                let keep = 1.0 - conv.split_at((dx as f64).hypot(dy as f64));
                if keep > 0.0 {
                    let t = k.at(dx as isize, dy as isize);
                    fine.push((dx, dy, t.map(|v| f64::from(v) * keep)));
                }
            }
        }
        let rcb = conv.r_coarse as i64;
        let n = (2 * rcb + 1) as usize;
        let mut kc = vec![[0.0f64; 3]; n * n];
        for dy in -rk..=rk {
            for dx in -rk..=rk {
                let g = conv.split_at((dx as f64).hypot(dy as f64));
                if g > 0.0 {
                    let (bx, by) = ((dx + hb).div_euclid(b), (dy + hb).div_euclid(b));
                    let t = k.at(dx as isize, dy as isize);
                    let c = &mut kc[((by + rcb) * (2 * rcb + 1) + bx + rcb) as usize];
                    for ch in 0..3 {
                        c[ch] += f64::from(t[ch]) * g;
                    }
                }
            }
        }
        let mut out = vec![[0.0f64; 3]; img.pixels.len()];
        let mut sums = vec![[0.0f64; 3]; (wc * wc) as usize];
        for y in 0..ih {
            for x in 0..iw {
                let p = img.get(x as usize, y as usize).map(f64::from);
                let d = (x as f64 + 0.5 - gaze[0]).hypot(y as f64 + 0.5 - gaze[1]);
                let wgt = conv.weight_at(d);
                let o = &mut out[(y * iw + x) as usize];
                for ch in 0..3 {
                    o[ch] += p[ch] * (1.0 - wgt);
                }
                if wgt == 0.0 {
                    continue;
                }
                let s = p.map(|v| v * wgt);
                for &(dx, dy, t) in &fine {
                    let (tx, ty) = (x + dx, y + dy);
                    if (0..iw).contains(&tx) && (0..ih).contains(&ty) {
                        let o = &mut out[(ty * iw + tx) as usize];
                        for ch in 0..3 {
                            o[ch] += s[ch] * t[ch];
                        }
                    }
                }
                let (bi, bj) = ((x - ocx).div_euclid(b), (y - ocy).div_euclid(b));
                assert!((0..wc).contains(&bi) && (0..wc).contains(&bj));
                let c = &mut sums[(bj * wc + bi) as usize];
                for ch in 0..3 {
                    c[ch] += s[ch];
                }
            }
        }
        // Coarse result per block, blocks −1 ..= wc (zero outside the window).
        let m = wc + 2;
        let mut cres = vec![[0.0f64; 3]; (m * m) as usize];
        for sj in 0..wc {
            for si in 0..wc {
                let s = sums[(sj * wc + si) as usize];
                if s == [0.0; 3] {
                    continue;
                }
                for by in -rcb..=rcb {
                    for bx in -rcb..=rcb {
                        let (j, i) = (sj + by, si + bx);
                        if !(0..wc).contains(&j) || !(0..wc).contains(&i) {
                            continue;
                        }
                        let t = kc[((by + rcb) * (2 * rcb + 1) + bx + rcb) as usize];
                        let c = &mut cres[((j + 1) * m + i + 1) as usize];
                        for ch in 0..3 {
                            c[ch] += s[ch] * t[ch];
                        }
                    }
                }
            }
        }
        let hat = |l: i64| {
            (
                (l - hb).div_euclid(b),
                (l - hb).rem_euclid(b) as f64 / b as f64,
            )
        };
        for y in 0..ih {
            let yl = y - ocy;
            if !(0..wc * b).contains(&yl) {
                continue;
            }
            let (j0, fy) = hat(yl);
            for x in 0..iw {
                let xl = x - ocx;
                if !(0..wc * b).contains(&xl) {
                    continue;
                }
                let (i0, fx) = hat(xl);
                let at = |j: i64, i: i64| cres[((j + 1) * m + i + 1) as usize];
                let o = &mut out[(y * iw + x) as usize];
                let (c00, c01, c10, c11) = (
                    at(j0, i0),
                    at(j0, i0 + 1),
                    at(j0 + 1, i0),
                    at(j0 + 1, i0 + 1),
                );
                for (ch, o) in o.iter_mut().enumerate() {
                    let v = (1.0 - fy) * ((1.0 - fx) * c00[ch] + fx * c01[ch])
                        + fy * ((1.0 - fx) * c10[ch] + fx * c11[ch]);
                    *o += v / (b * b) as f64;
                }
            }
        }
        out
    }

    /// `apply` on the demo's night view (720×800, the street lamp in the
    /// field) agrees with [`direct`] within 1e-5 of the brightest weighted
    /// source everywhere, and within 1e-4 relative where the output is at
    /// least 1e-2 of it.
    #[test]
    fn apply_matches_a_direct_convolution_on_the_night_view() {
        use crate::scene::{LuminanceScale, PanoramaView, Scene, ViewParams};
        let (w, h) = (720, 800);
        let path = gazelight_test_support::data_path("hdr/blender-world/night.exr");
        let scene = Scene::load(&path, LuminanceScale::default()).unwrap();
        let view = ViewParams {
            yaw_deg: -78.4,
            pitch_deg: -6.0,
            hfov_deg: 90.0,
            width: w,
            height: h,
        };
        let mut img = RgbImage::new(w, h);
        PanoramaView::new(view)
            .unwrap()
            .render(&scene.image, &mut img);
        let k = build_kernel(&PsfParams {
            ppd: 1.0 / view.deg_per_px(),
            ..PsfParams::default()
        })
        .unwrap();
        let mut conv = GlareConvolver::new(&k, GlareWindow::default()).unwrap();
        for gaze in [[360.0, 360.0], [361.7, 640.2], [40.5, 30.25]] {
            let mut got = img.clone();
            conv.apply(&mut got, gaze);
            let want = direct(&conv, &k, &img, gaze);
            // The brightest weighted source.
            let mut peak = 0.0f64;
            for y in 0..h {
                for x in 0..w {
                    let d = (x as f64 + 0.5 - gaze[0]).hypot(y as f64 + 0.5 - gaze[1]);
                    let p = img.get(x, y);
                    peak = peak.max(conv.weight_at(d) * f64::from(p[0].max(p[1]).max(p[2])));
                }
            }
            let (mut worst_abs, mut worst_rel) = (0.0f64, 0.0f64);
            for (g, wv) in got.pixels.iter().zip(&want) {
                for ch in 0..3 {
                    let e = (f64::from(g[ch]) - wv[ch]).abs();
                    worst_abs = worst_abs.max(e / peak);
                    if wv[ch] >= 1e-2 * peak {
                        worst_rel = worst_rel.max(e / wv[ch]);
                    }
                }
            }
            eprintln!(
                "gaze {gaze:?}: peak {peak:.3e}, max |err| {worst_abs:.2e} of peak, {worst_rel:.2e} relative"
            );
            assert!(
                worst_abs < 1e-5 && worst_rel < 1e-4,
                "gaze {gaze:?}: {worst_abs:.2e} of peak, {worst_rel:.2e} relative"
            );
        }
    }

    /// A lamp (2·10⁴ cd/m², 0.3° radius) in a dark scene with the gaze on it:
    /// the veil around it follows E_glare × CIE 146(θ) within a factor 2
    /// from 1.5° to 12°, E_glare = L · Ω_lamp.
    fn check_lamp_veil(img: &RgbImage, ppd: f64, lamp: (usize, usize), e_glare: f64, what: &str) {
        let mut worst = 1.0f64;
        for i in 0..=20 {
            let theta = 1.5 * (12.0f64 / 1.5).powf(i as f64 / 20.0);
            let d = (theta * ppd).round() as usize;
            let t = d as f64 / ppd;
            let got = ring_luminance(img, lamp.0, lamp.1, d);
            let want = e_glare * cie146(t, 25.0, 0.5);
            let ratio = got / want;
            assert!(
                ratio > 0.5 && ratio < 2.0,
                "{what}: θ {t:.2}°: veil {got:.4} cd/m², E·CIE {want:.4} (×{ratio:.3})"
            );
            worst = worst.max(ratio.max(1.0 / ratio));
        }
        eprintln!("{what}: veil / (E_glare × CIE 146) within ×{worst:.3} from 1.5° to 12°");
    }

    fn lamp_scene(w: usize, h: usize, ppd: f64, lamp_cd_m2: f32) -> (RgbImage, f64) {
        let mut img = RgbImage::new(w, h);
        let (cx, cy) = (w as f64 / 2.0, h as f64 / 2.0);
        let r_px = 0.3 * ppd;
        let mut n = 0usize;
        for y in 0..h {
            for x in 0..w {
                if (x as f64 + 0.5 - cx).hypot(y as f64 + 0.5 - cy) <= r_px {
                    *img.get_mut(x, y) = [lamp_cd_m2; 3];
                    n += 1;
                }
            }
        }
        // E_glare = L · Ω, Ω from the pixels actually lit.
        let omega = n as f64 * (1.0 / ppd).to_radians().powi(2);
        (img, f64::from(lamp_cd_m2) * omega)
    }

    #[test]
    fn lamp_veil_follows_cie_146_through_the_convolver_and_the_pipeline() {
        let ppd = 13.85;
        let (w, h) = (560, 560);
        let (scene, e_glare) = lamp_scene(w, h, ppd, 2e4);
        // Convolver alone.
        let k = build_kernel(&PsfParams {
            ppd,
            ..PsfParams::default()
        })
        .unwrap();
        let mut conv = GlareConvolver::new(&k, GlareWindow::default()).unwrap();
        let mut img = scene.clone();
        conv.apply(&mut img, [w as f64 / 2.0, h as f64 / 2.0]);
        check_lamp_veil(&img, ppd, (w / 2, h / 2), e_glare, "convolver");
        // Through the frame pipeline: the retinal image (linear cd/m², after
        // glare and acuity, before tone reproduction).
        let kept = PipelineConfig {
            keep_retinal: true,
            ..PipelineConfig::default()
        };
        let mut pipeline = FramePipeline::new(kept.clone(), w, h, 1.0 / ppd).unwrap();
        let mut out = DisplayFrame::new(w, h);
        let input = FrameInput {
            gaze_uv: [0.5, 0.5],
            pupil_mm: 4.0,
            dt_secs: 1.0 / 90.0,
        };
        pipeline.process(&scene, &input, &mut out).unwrap();
        check_lamp_veil(
            pipeline.retinal(),
            ppd,
            (w / 2, h / 2),
            e_glare,
            "pipeline retinal image",
        );
        // Glare off: no veil at 2°.
        let mut config = kept;
        config.glare.enabled = false;
        let mut off = FramePipeline::new(config, w, h, 1.0 / ppd).unwrap();
        off.process(&scene, &input, &mut out).unwrap();
        let d2 = (2.0 * ppd).round() as usize;
        let on_2 = ring_luminance(pipeline.retinal(), w / 2, h / 2, d2);
        let off_2 = ring_luminance(off.retinal(), w / 2, h / 2, d2);
        eprintln!("veil at 2°: glare on {on_2:.3} cd/m², off {off_2:.3} cd/m²");
        assert!(on_2 > 10.0 * off_2.max(1e-6));
    }
}
