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
//! `Σ K_f + Σ K_c = Σ K` exactly. The fine part convolves the weighted frame
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
//! inverts to `R ∗ K_R + i G ∗ K_G`. B runs on its own FFT. Rows without
//! sources are skipped in the first forward pass and rows outside the image
//! in the last inverse pass. The four transforms (fine RG, fine B, coarse RG,
//! coarse B) run on two rayon tasks. Spectra are f32; `apply` allocates
//! nothing.

use std::sync::Arc;

use rayon::prelude::*;
use rustfft::num_complex::Complex;
use rustfft::{Fft, FftPlanner};
use serde::{Deserialize, Serialize};

use crate::psf::PsfKernel;
use crate::{RgbImage, VisionError};

/// Radius of the full-resolution part of the kernel, degrees.
pub const FINE_RADIUS_DEG: f64 = 2.0;
/// Smallest size of one coarse block of the wide field, degrees (the block
/// is the smallest odd number of pixels at least this wide).
pub const COARSE_PX_DEG: f64 = 0.4;
/// Largest FFT window, samples per side.
const MAX_WINDOW: usize = 4096;

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

/// One FFT size: plans, the packed RG and B work buffers and the kernel
/// spectra (transposed 2-D layout, 1/W² folded in).
struct Plane {
    w: usize,
    fwd: Arc<dyn Fft<f32>>,
    inv: Arc<dyn Fft<f32>>,
    rg: Vec<Complex<f32>>,
    b: Vec<Complex<f32>>,
    scratch_rg: Vec<Complex<f32>>,
    scratch_b: Vec<Complex<f32>>,
    spec_a: Vec<Complex<f32>>,
    spec_b: Vec<Complex<f32>>,
    spec_blue: Vec<Complex<f32>>,
}

impl Plane {
    fn new(w: usize) -> Self {
        let mut planner = FftPlanner::<f32>::new();
        let fwd = planner.plan_fft_forward(w);
        let inv = planner.plan_fft_inverse(w);
        let s = fwd
            .get_inplace_scratch_len()
            .max(inv.get_inplace_scratch_len());
        let z = Complex::new(0.0f32, 0.0);
        Self {
            w,
            fwd,
            inv,
            rg: vec![z; w * w],
            b: vec![z; w * w],
            scratch_rg: vec![z; s],
            scratch_b: vec![z; s],
            spec_a: vec![z; w * w],
            spec_b: vec![z; w * w],
            spec_blue: vec![z; w * w],
        }
    }

    /// Spectra of a kernel already written into `rg` (R + iG) and `b` (B),
    /// wrapped so that offset 0 is index 0.
    fn kernel_spectra(&mut self) {
        let w = self.w;
        let (fwd, rg, b) = (&self.fwd, &mut self.rg, &mut self.b);
        fft2(fwd, rg, &mut self.scratch_rg, w, 0..w);
        fft2(fwd, b, &mut self.scratch_b, w, 0..w);
        let inv_area = 1.0 / (w * w) as f32;
        for kx in 0..w {
            for ky in 0..w {
                let i = kx * w + ky;
                let j = ((w - kx) % w) * w + (w - ky) % w;
                let z = rg[i];
                let zc = rg[j].conj();
                // K̂_R = (Z + Z*₋)/2, K̂_G = (Z − Z*₋)/(2i)
                let kr = (z + zc) * 0.5;
                let kg = (z - zc) * Complex::new(0.0, -0.5);
                self.spec_a[i] = (kr + kg) * (0.5 * inv_area);
                self.spec_b[i] = (kr - kg) * (0.5 * inv_area);
                self.spec_blue[i] = b[i] * inv_area;
            }
        }
    }
}

/// Forward 2-D FFT into the transposed layout; rows outside `rows` must be 0.
fn fft2(
    fft: &Arc<dyn Fft<f32>>,
    buf: &mut [Complex<f32>],
    scratch: &mut [Complex<f32>],
    w: usize,
    rows: std::ops::Range<usize>,
) {
    if !rows.is_empty() {
        fft.process_with_scratch(&mut buf[rows.start * w..rows.end * w], scratch);
    }
    transpose_square_blocked(buf, w);
    fft.process_with_scratch(buf, scratch);
}

/// Inverse of [`fft2`]; only `rows` of the result are computed.
fn ifft2(
    fft: &Arc<dyn Fft<f32>>,
    buf: &mut [Complex<f32>],
    scratch: &mut [Complex<f32>],
    w: usize,
    rows: std::ops::Range<usize>,
) {
    fft.process_with_scratch(buf, scratch);
    transpose_square_blocked(buf, w);
    if !rows.is_empty() {
        fft.process_with_scratch(&mut buf[rows.start * w..rows.end * w], scratch);
    }
}

/// FFT convolution of a frame with the glare kernel in a window at the gaze.
pub struct GlareConvolver {
    window: GlareWindow,
    deg_per_px: f64,
    kernel_size: usize,
    /// Fine kernel radius, display pixels.
    r_fine: usize,
    /// Coarse block, display pixels (odd).
    block: usize,
    /// Weight reaches 0 here, display pixels.
    r_src: f64,
    d_full: f64,
    sigma: f64,
    fine: Plane,
    coarse: Plane,
    /// Source weight over the fine window, W_f².
    weight: Vec<f32>,
    /// The coarse result interpolated along x to display columns, `/ b²`:
    /// `(W_c + 2) × (W_c · b)`, a zero row above and below.
    hrows: Vec<[f32; 3]>,
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
        let ppd = 1.0 / dpp;
        let r_kernel = kernel.size / 2;
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
        let wf = good_fft_size(2 * (src_px + r_fine) + 2);
        let wc = good_fft_size(2 * (src_px.div_ceil(block) + 1 + r_coarse) + 2);
        if wf > MAX_WINDOW || wc > MAX_WINDOW {
            return Err(VisionError::invalid(
                "glare.full_weight_deg",
                window.full_weight_deg,
                "a weight region (full_weight_deg + 3 fade_sigma_deg) whose FFT window at this ppd is ≤ 4096 px",
            ));
        }
        let mut conv = Self {
            window,
            deg_per_px: dpp,
            kernel_size: kernel.size,
            r_fine,
            block,
            r_src,
            d_full,
            sigma,
            fine: Plane::new(wf),
            coarse: Plane::new(wc),
            weight: vec![0.0; wf * wf],
            hrows: vec![[0.0; 3]; (wc + 2) * wc * block],
        };
        conv.set_kernel(kernel)?;
        Ok(conv)
    }

    /// The weight settings.
    pub fn window(&self) -> GlareWindow {
        self.window
    }

    /// Fine (full-resolution) FFT window, pixels per side.
    pub fn fine_window_px(&self) -> usize {
        self.fine.w
    }

    /// Coarse FFT window, blocks per side.
    pub fn coarse_window_blocks(&self) -> usize {
        self.coarse.w
    }

    /// Coarse block size, display pixels (odd).
    pub fn block_px(&self) -> usize {
        self.block
    }

    /// Radius of the full-resolution part of the kernel, pixels.
    pub fn fine_radius_px(&self) -> usize {
        self.r_fine
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
        split_weight(d_px, self.r_fine as f64)
    }

    /// Caches the spectra of `kernel` (same size and pixel size as the one
    /// given to [`GlareConvolver::new`]; a PSF rebuild for a new pupil).
    /// Allocates nothing.
    pub fn set_kernel(&mut self, kernel: &PsfKernel) -> Result<(), VisionError> {
        if kernel.size != self.kernel_size
            || kernel.deg_per_px != self.deg_per_px
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
        let z = Complex::new(0.0f32, 0.0);
        let rk = (kernel.size / 2) as isize;
        let rf = self.r_fine as isize;
        // Fine part: (1 − g) K.
        let wf = self.fine.w as isize;
        self.fine.rg.fill(z);
        self.fine.b.fill(z);
        for dy in -rf..=rf {
            for dx in -rf..=rf {
                let keep = 1.0 - split_weight((dx as f64).hypot(dy as f64), rf as f64);
                if keep <= 0.0 {
                    continue;
                }
                let k = kernel.at(dx, dy);
                let i = (dy.rem_euclid(wf) * wf + dx.rem_euclid(wf)) as usize;
                let keep = keep as f32;
                self.fine.rg[i] = Complex::new(k[0] * keep, k[1] * keep);
                self.fine.b[i] = Complex::new(k[2] * keep, 0.0);
            }
        }
        self.fine.kernel_spectra();
        // Coarse part: g K summed over b × b blocks.
        let wc = self.coarse.w as isize;
        let b = self.block as isize;
        let hb = b / 2;
        self.coarse.rg.fill(z);
        self.coarse.b.fill(z);
        for dy in -rk..=rk {
            let by = (dy + hb).div_euclid(b);
            for dx in -rk..=rk {
                let g = split_weight((dx as f64).hypot(dy as f64), rf as f64) as f32;
                if g <= 0.0 {
                    continue;
                }
                let bx = (dx + hb).div_euclid(b);
                let k = kernel.at(dx, dy);
                let i = (by.rem_euclid(wc) * wc + bx.rem_euclid(wc)) as usize;
                self.coarse.rg[i] += Complex::new(k[0] * g, k[1] * g);
                self.coarse.b[i].re += k[2] * g;
            }
        }
        self.coarse.kernel_spectra();
        Ok(())
    }

    /// Convolves `img` with the kernel around `gaze_px` (pixel coordinates,
    /// x right, y down) and blends it in place (see the module docs). Does
    /// nothing for a non-finite gaze or an empty image.
    pub fn apply(&mut self, img: &mut RgbImage, gaze_px: [f64; 2]) {
        if !gaze_px[0].is_finite()
            || !gaze_px[1].is_finite()
            || img.width == 0
            || img.height == 0
            || img.pixels.len() != img.width * img.height
        {
            return;
        }
        let (iw, ih) = (img.width as i64, img.height as i64);
        let wf = self.fine.w;
        let wc = self.coarse.w;
        let b = self.block as i64;
        let hb = b / 2;
        // Far outside the image: clamp so the i64 arithmetic stays exact.
        let limit = (img.width.max(img.height) + 2 * wf * self.block) as f64;
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
        let z = Complex::new(0.0f32, 0.0);
        self.fine.rg.fill(z);
        self.fine.b.fill(z);
        self.coarse.rg.fill(z);
        self.coarse.b.fill(z);
        self.weight.fill(0.0);
        let (d_full, sigma) = (self.d_full, self.sigma);
        for y in sy0..sy1 {
            let fj = (y - ofy) as usize;
            let cj = ((y - ocy) / b) as usize;
            let dy = y as f64 + 0.5 - gy;
            let row = &img.pixels[y as usize * img.width..(y as usize + 1) * img.width];
            for x in sx0..sx1 {
                let dx = x as f64 + 0.5 - gx;
                let wgt = source_weight(dx.hypot(dy), d_full, sigma) as f32;
                if wgt <= 0.0 {
                    continue;
                }
                let p = row[x as usize];
                let fi = (x - ofx) as usize;
                let ci = ((x - ocx) / b) as usize;
                self.weight[fj * wf + fi] = wgt;
                let (r, g, bl) = (p[0] * wgt, p[1] * wgt, p[2] * wgt);
                self.fine.rg[fj * wf + fi] = Complex::new(r, g);
                self.fine.b[fj * wf + fi].re = bl;
                let c = cj * wc + ci;
                self.coarse.rg[c] += Complex::new(r, g);
                self.coarse.b[c].re += bl;
            }
        }
        // Rows with sources, rows inside the image (window coordinates).
        let f_src = (sy0 - ofy) as usize..(sy1 - ofy) as usize;
        let f_out = ((-ofy).max(0) as usize)..((ih - ofy).min(wf as i64).max(0) as usize);
        let c_src = ((sy0 - ocy) / b) as usize..((sy1 - 1 - ocy) / b + 1) as usize;
        let c_out = 0..wc;
        let (fine, coarse) = (&mut self.fine, &mut self.coarse);
        // Two tasks: (fine RG, coarse B) and (fine B, coarse RG).
        let (fine_rg, fine_b) = split_plane(fine);
        let (coarse_rg, coarse_b) = split_plane(coarse);
        rayon::join(
            || {
                fine_rg.run_rg(f_src.clone(), f_out.clone());
                coarse_b.run_b(c_src.clone(), c_out.clone());
            },
            || {
                fine_b.run_b(f_src.clone(), f_out.clone());
                coarse_rg.run_rg(c_src.clone(), c_out.clone());
            },
        );

        // Blend: out = (1 − w) img + fine + bilinear(coarse / b²).
        let inv_b2 = 1.0 / (b * b) as f32;
        let bf = b as f32;
        let cw = wc as i64;
        // Output region: the coarse window ∩ image (it contains the fine one).
        let x0 = ocx.max(0);
        let x1 = (ocx + cw * b).min(iw);
        let y0 = ocy.max(0);
        let y1 = (ocy + cw * b).min(ih);
        if x0 >= x1 || y0 >= y1 {
            return;
        }
        let width = img.width;
        // Bilinear, separable: the coarse rows interpolated along x once.
        let span = wc * self.block;
        let (cx0, cx1) = ((x0 - ocx) as usize, (x1 - ocx) as usize);
        let coarse = &self.coarse;
        self.hrows[..span].fill([0.0; 3]);
        self.hrows[(wc + 1) * span..].fill([0.0; 3]);
        self.hrows[span..(wc + 1) * span]
            .par_chunks_mut(span)
            .enumerate()
            .for_each(|(j, hrow)| {
                let at = |i: i64| -> [f32; 3] {
                    if i < 0 || i >= cw {
                        return [0.0; 3];
                    }
                    let idx = j * wc + i as usize;
                    let rg = coarse.rg[idx];
                    [rg.re, rg.im, coarse.b[idx].re]
                };
                for (xl, h) in hrow.iter_mut().enumerate().take(cx1).skip(cx0) {
                    let u = (xl as f32 + 0.5) / bf - 0.5;
                    let i0f = u.floor();
                    let fx = u - i0f;
                    let i0 = i0f as i64;
                    let (a, c) = (at(i0), at(i0 + 1));
                    for ch in 0..3 {
                        h[ch] = (a[ch] * (1.0 - fx) + c[ch] * fx) * inv_b2;
                    }
                }
            });
        let fine = &self.fine;
        let weight = &self.weight;
        let hrows = &self.hrows;
        img.pixels[y0 as usize * width..y1 as usize * width]
            .par_chunks_mut(width)
            .enumerate()
            .for_each(|(k, row)| {
                let y = y0 + k as i64;
                let v = ((y - ocy) as f32 + 0.5) / bf - 0.5;
                let j0f = v.floor();
                let fy = v - j0f;
                // hrows row j + 1 holds coarse row j; j0 ≥ −1.
                let j0 = (j0f as i64 + 1).clamp(0, cw) as usize;
                let lo = &hrows[j0 * span..(j0 + 1) * span];
                let hi = &hrows[(j0 + 1) * span..(j0 + 2) * span];
                let fj = y - ofy;
                let row = &mut row[x0 as usize..x1 as usize];
                if fj >= 0 && fj < wf as i64 {
                    // The fine window's columns inside the image:
                    // (1 − w)·img + fine.
                    let fx0 = (x0 - ofx).max(0);
                    let fx1 = (x1 - ofx).min(wf as i64);
                    let base = fj as usize * wf;
                    for fi in fx0..fx1 {
                        let idx = base + fi as usize;
                        let keep = 1.0 - weight[idx];
                        let rg = fine.rg[idx];
                        let p = &mut row[(ofx + fi - x0) as usize];
                        p[0] = p[0] * keep + rg.re;
                        p[1] = p[1] * keep + rg.im;
                        p[2] = p[2] * keep + fine.b[idx].re;
                    }
                }
                // + the coarse wide field.
                let (lo, hi) = (&lo[cx0..cx1], &hi[cx0..cx1]);
                for ((p, a), c) in row.iter_mut().zip(lo).zip(hi) {
                    for ch in 0..3 {
                        p[ch] += a[ch] * (1.0 - fy) + c[ch] * fy;
                    }
                }
            });
    }
}

/// The RG or B half of a [`Plane`], borrowed separately so the two run on
/// different rayon tasks.
struct Half<'a> {
    w: usize,
    fwd: &'a Arc<dyn Fft<f32>>,
    inv: &'a Arc<dyn Fft<f32>>,
    buf: &'a mut Vec<Complex<f32>>,
    scratch: &'a mut Vec<Complex<f32>>,
    spec: [&'a Vec<Complex<f32>>; 2],
}

fn split_plane(p: &mut Plane) -> (Half<'_>, Half<'_>) {
    (
        Half {
            w: p.w,
            fwd: &p.fwd,
            inv: &p.inv,
            buf: &mut p.rg,
            scratch: &mut p.scratch_rg,
            spec: [&p.spec_a, &p.spec_b],
        },
        Half {
            w: p.w,
            fwd: &p.fwd,
            inv: &p.inv,
            buf: &mut p.b,
            scratch: &mut p.scratch_b,
            spec: [&p.spec_blue, &p.spec_blue],
        },
    )
}

impl Half<'_> {
    fn run_rg(self, src: std::ops::Range<usize>, out: std::ops::Range<usize>) {
        let w = self.w;
        fft2(self.fwd, self.buf, self.scratch, w, src);
        let (a, bs) = (self.spec[0], self.spec[1]);
        let buf = &mut *self.buf;
        for kx in 0..w {
            let nkx = (w - kx) % w;
            for ky in 0..w {
                let i = kx * w + ky;
                let j = nkx * w + (w - ky) % w;
                if j < i {
                    continue;
                }
                let (zi, zj) = (buf[i], buf[j]);
                buf[i] = zi * a[i] + zj.conj() * bs[i];
                buf[j] = zj * a[j] + zi.conj() * bs[j];
            }
        }
        ifft2(self.inv, buf, self.scratch, w, out);
    }

    fn run_b(self, src: std::ops::Range<usize>, out: std::ops::Range<usize>) {
        let w = self.w;
        fft2(self.fwd, self.buf, self.scratch, w, src);
        for (v, k) in self.buf.iter_mut().zip(self.spec[0].iter()) {
            *v *= *k;
        }
        ifft2(self.inv, self.buf, self.scratch, w, out);
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

/// In-place transpose of a square row-major matrix, in cache-sized blocks.
fn transpose_square_blocked<T: Copy>(m: &mut [T], n: usize) {
    const B: usize = 16;
    for bj in (0..n).step_by(B) {
        for bi in (bj..n).step_by(B) {
            for j in bj..(bj + B).min(n) {
                let start = if bi == bj { j + 1 } else { bi };
                for i in start..(bi + B).min(n) {
                    m.swap(j * n + i, i * n + j);
                }
            }
        }
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
        // The wide field follows the kernel ring by ring within 10 %.
        let r = k.centre();
        let mut worst = 0.0f64;
        for d in conv.fine_radius_px()..r - 2 {
            let want = {
                let mut kimg = RgbImage::new(2 * r + 1, 2 * r + 1);
                for (i, p) in kimg.pixels.iter_mut().enumerate() {
                    *p = k.rgb[i];
                }
                ring_luminance(&kimg, r, r, d)
            };
            let got = ring_luminance(&img, cx, cy, d);
            worst = worst.max((got / want - 1.0).abs());
        }
        eprintln!(
            "wide field vs kernel, worst ring error {:.2} %",
            worst * 100.0
        );
        assert!(worst < 0.1, "{worst}");
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
        let mut pipeline = FramePipeline::new(PipelineConfig::default(), w, h, 1.0 / ppd).unwrap();
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
        let mut config = PipelineConfig::default();
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
