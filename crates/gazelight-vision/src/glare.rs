//! Windowed FFT glare at the gaze (001 §4.2.3).
//!
//! 001 convolves the frame with the spectral glare kernel by FFT ("convolutional
//! bloom") and, to save time and because glare is strongest when looking at
//! a light source, does so only in a window centred on the gaze, blended with
//! a Gaussian falloff over the original image. [`GlareConvolver`] does that on
//! the CPU:
//!
//! * The window is `window_px × window_px` display pixels; its centre pixel is
//!   the pixel under the gaze (`floor(gaze_px)`; pixel `(x, y)` covers
//!   `[x, x+1) × [y, y+1)`). Parts of the window outside the image are black:
//!   they emit nothing and their output is discarded (light spread past the
//!   image border is lost).
//! * Falloff: a source pixel at distance `d` (from the gaze to the pixel
//!   centre) glares with weight
//!   `w(d) = (G(d) − G(R)) / (1 − G(R))`, `G(d) = exp(−d² / 2σ²)`, for
//!   `d < R` and 0 beyond, where σ = `falloff_sigma_px` and
//!   `R = window/2 − kernel radius − 1` is the largest source distance whose
//!   glare still fits in the window. So `w = 1` at the gaze, it falls off like
//!   the Gaussian, and it reaches 0 at `R`, so a source crossing the window's
//!   edge never pops (for σ → ∞ it tends to `1 − d²/R²`). The pipeline's
//!   default σ is a quarter of the window.
//! * Blend: `out = (1 − w)·img + K ∗ (w·img)`. The weight applies to the
//!   *source* light before the convolution; this conserves energy exactly
//!   (the kernel has unit sum per channel), a point source at the gaze becomes
//!   exactly the kernel, and glare is strongest for sources near the gaze,
//!   as 001 motivates.
//! * Linear, not circular, convolution: sources lie within `R` of the window
//!   centre and the kernel radius `r` satisfies `R + r < window/2`, so
//!   nothing wraps around the FFT's periodic domain. A kernel wider than half
//!   the window (radius > window/4) is cropped to radius window/4 and
//!   renormalised per channel in [`GlareConvolver::set_kernel`].
//!
//! The kernel must be sampled at the image's pixels per degree
//! ([`crate::psf::PsfKernel::deg_per_px`]). Spectra are f32; the three
//! channels run in parallel (rayon). `apply` allocates nothing.

use std::sync::Arc;

use rayon::prelude::*;
use rustfft::num_complex::Complex;
use rustfft::{Fft, FftPlanner};

use crate::RgbImage;
use crate::psf::PsfKernel;

/// Smallest and largest window, pixels.
const WINDOW_RANGE_PX: (usize, usize) = (16, 4096);

struct Channel {
    /// Kernel spectrum (transposed 2-D layout, 1/W² folded in).
    spectrum: Vec<Complex<f32>>,
    /// Work buffer, W².
    buf: Vec<Complex<f32>>,
    /// FFT scratch.
    scratch: Vec<Complex<f32>>,
}

/// FFT convolution of a frame with the glare kernel in a window at the gaze.
pub struct GlareConvolver {
    window_px: usize,
    fwd: Arc<dyn Fft<f32>>,
    inv: Arc<dyn Fft<f32>>,
    channels: [Channel; 3],
    kernel_radius_px: usize,
    has_kernel: bool,
    /// Separable Gaussian factors along x (columns) and y (rows) of the window.
    gauss_x: Vec<f64>,
    gauss_y: Vec<f64>,
    /// Falloff weight of every window pixel, W².
    weight: Vec<f32>,
}

impl GlareConvolver {
    /// A convolver for `window_px × window_px` windows. Powers of two are
    /// fastest (any size works); the size is clamped to 16..=4096. No glare is
    /// applied until [`GlareConvolver::set_kernel`] is called.
    pub fn new(window_px: usize) -> Self {
        let w = window_px.clamp(WINDOW_RANGE_PX.0, WINDOW_RANGE_PX.1);
        let mut planner = FftPlanner::<f32>::new();
        let fwd = planner.plan_fft_forward(w);
        let inv = planner.plan_fft_inverse(w);
        let scratch_len = fwd
            .get_inplace_scratch_len()
            .max(inv.get_inplace_scratch_len());
        let zero = Complex::new(0.0f32, 0.0);
        let channel = || Channel {
            spectrum: vec![zero; w * w],
            buf: vec![zero; w * w],
            scratch: vec![zero; scratch_len],
        };
        Self {
            window_px: w,
            fwd,
            inv,
            channels: [channel(), channel(), channel()],
            kernel_radius_px: 0,
            has_kernel: false,
            gauss_x: vec![0.0; w],
            gauss_y: vec![0.0; w],
            weight: vec![0.0; w * w],
        }
    }

    /// Window size, pixels.
    pub fn window_px(&self) -> usize {
        self.window_px
    }

    /// Radius of the (possibly cropped) kernel in use, pixels.
    pub fn kernel_radius_px(&self) -> usize {
        self.kernel_radius_px
    }

    /// Largest source distance from the gaze that glares, pixels (`R`).
    pub fn source_radius_px(&self) -> f64 {
        (self.window_px / 2) as f64 - self.kernel_radius_px as f64 - 1.0
    }

    /// Caches the spectra of `kernel` (already at the display's pixels per
    /// degree): zero-padded to the window, centred on index (0, 0). A kernel
    /// of radius > window/4 is cropped to window/4; each channel is
    /// renormalised to unit sum (a channel without light becomes the identity).
    pub fn set_kernel(&mut self, kernel: &PsfKernel) {
        let w = self.window_px;
        let c = kernel.size / 2;
        let r = c.min(w / 4);
        self.kernel_radius_px = r;
        let r = r as isize;
        let fwd = &self.fwd;
        self.channels
            .par_iter_mut()
            .enumerate()
            .for_each(|(ch, chan)| {
                chan.spectrum.fill(Complex::new(0.0, 0.0));
                let mut sum = 0.0f64;
                for dy in -r..=r {
                    for dx in -r..=r {
                        sum += f64::from(kernel.at(dx, dy)[ch]);
                    }
                }
                let inv_area = 1.0 / (w * w) as f64;
                if sum > 0.0 && sum.is_finite() {
                    for dy in -r..=r {
                        for dx in -r..=r {
                            let v = f64::from(kernel.at(dx, dy)[ch]) / sum * inv_area;
                            let i = dx.rem_euclid(w as isize) as usize;
                            let j = dy.rem_euclid(w as isize) as usize;
                            chan.spectrum[j * w + i] = Complex::new(v as f32, 0.0);
                        }
                    }
                } else {
                    chan.spectrum[0] = Complex::new(inv_area as f32, 0.0);
                }
                fwd.process_with_scratch(&mut chan.spectrum, &mut chan.scratch);
                transpose_square_blocked(&mut chan.spectrum, w);
                fwd.process_with_scratch(&mut chan.spectrum, &mut chan.scratch);
            });
        self.has_kernel = true;
    }

    /// Convolves `img` with the kernel in the window at `gaze_px` (pixel
    /// coordinates, x right, y down) and blends it in place with the falloff of
    /// σ = `falloff_sigma_px` (see the module docs). Does nothing before
    /// [`GlareConvolver::set_kernel`], for a non-finite gaze, or for σ that is
    /// not > 0 (NaN included); σ = ∞ gives the limit weight `1 − d²/R²`.
    pub fn apply(&mut self, img: &mut RgbImage, gaze_px: [f64; 2], falloff_sigma_px: f64) {
        if !self.has_kernel
            || !gaze_px[0].is_finite()
            || !gaze_px[1].is_finite()
            || falloff_sigma_px.is_nan()
            || falloff_sigma_px <= 0.0
            || img.width == 0
            || img.height == 0
            || img.pixels.len() != img.width * img.height
        {
            return;
        }
        let w = self.window_px;
        let half = (w / 2) as i64;
        // Far outside the image: clamp so the i64 arithmetic stays exact; the
        // window then misses the image entirely.
        let limit = (img.width.max(img.height) + 2 * w) as f64;
        let gx = gaze_px[0].clamp(-limit, limit);
        let gy = gaze_px[1].clamp(-limit, limit);
        let ox = gx.floor() as i64 - half;
        let oy = gy.floor() as i64 - half;
        let (iw, ih) = (img.width as i64, img.height as i64);
        if ox + w as i64 <= 0 || oy + w as i64 <= 0 || ox >= iw || oy >= ih {
            return;
        }
        let r_src = self.source_radius_px();
        if r_src <= 0.0 {
            return;
        }
        // Separable Gaussian factors and the weight at R.
        let inv_2s2 = 1.0 / (2.0 * falloff_sigma_px * falloff_sigma_px);
        for (i, g) in self.gauss_x.iter_mut().enumerate() {
            let d = (ox + i as i64) as f64 + 0.5 - gx;
            *g = (-d * d * inv_2s2).exp();
        }
        for (j, g) in self.gauss_y.iter_mut().enumerate() {
            let d = (oy + j as i64) as f64 + 0.5 - gy;
            *g = (-d * d * inv_2s2).exp();
        }
        let falloff = Weights {
            gauss_x: &self.gauss_x,
            gauss_y: &self.gauss_y,
            gaze: [gx, gy],
            origin: [ox, oy],
            r2: r_src * r_src,
            g_r: (-r_src * r_src * inv_2s2).exp(),
        };

        // Window ∩ image, in window coordinates.
        let i0 = (-ox).max(0) as usize;
        let j0 = (-oy).max(0) as usize;
        let i1 = ((iw - ox).min(w as i64)) as usize;
        let j1 = ((ih - oy).min(w as i64)) as usize;

        self.weight.fill(0.0);
        for j in j0..j1 {
            for i in i0..i1 {
                self.weight[j * w + i] = falloff.at(i, j);
            }
        }

        let (fwd, inv) = (&self.fwd, &self.inv);
        let weights = &self.weight;
        let src: &RgbImage = img;
        self.channels
            .par_iter_mut()
            .enumerate()
            .for_each(|(ch, chan)| {
                let buf = &mut chan.buf;
                buf.fill(Complex::new(0.0, 0.0));
                for j in j0..j1 {
                    let y = (oy + j as i64) as usize;
                    let row = &src.pixels[y * src.width..(y + 1) * src.width];
                    let x0 = (ox + i0 as i64) as usize;
                    let wrow = &weights[j * w + i0..j * w + i1];
                    let brow = &mut buf[j * w + i0..j * w + i1];
                    for ((b, &wgt), p) in brow.iter_mut().zip(wrow).zip(&row[x0..]) {
                        *b = Complex::new(p[ch] * wgt, 0.0);
                    }
                }
                fwd.process_with_scratch(buf, &mut chan.scratch);
                transpose_square_blocked(buf, w);
                fwd.process_with_scratch(buf, &mut chan.scratch);
                for (b, k) in buf.iter_mut().zip(&chan.spectrum) {
                    *b *= *k;
                }
                inv.process_with_scratch(buf, &mut chan.scratch);
                transpose_square_blocked(buf, w);
                inv.process_with_scratch(buf, &mut chan.scratch);
            });

        let [c0, c1, c2] = &self.channels;
        for j in j0..j1 {
            let y = (oy + j as i64) as usize;
            for i in i0..i1 {
                let x = (ox + i as i64) as usize;
                let keep = 1.0 - self.weight[j * w + i];
                let k = j * w + i;
                let p = &mut img.pixels[y * img.width + x];
                p[0] = p[0] * keep + c0.buf[k].re;
                p[1] = p[1] * keep + c1.buf[k].re;
                p[2] = p[2] * keep + c2.buf[k].re;
            }
        }
    }
}

/// The falloff weight over one window placement.
struct Weights<'a> {
    gauss_x: &'a [f64],
    gauss_y: &'a [f64],
    gaze: [f64; 2],
    origin: [i64; 2],
    r2: f64,
    g_r: f64,
}

impl Weights<'_> {
    /// Weight of the source at window pixel (i, j).
    #[inline]
    fn at(&self, i: usize, j: usize) -> f32 {
        let dx = (self.origin[0] + i as i64) as f64 + 0.5 - self.gaze[0];
        let dy = (self.origin[1] + j as i64) as f64 + 0.5 - self.gaze[1];
        let d2 = dx * dx + dy * dy;
        falloff_weight(d2, self.r2, self.gauss_x[i] * self.gauss_y[j], self.g_r) as f32
    }
}

/// `w = (G − G(R)) / (1 − G(R))` for `d² < R²`, else 0; the σ → ∞ limit
/// `1 − d²/R²` where `1 − G(R)` vanishes.
#[inline]
fn falloff_weight(d2: f64, r2: f64, g: f64, g_r: f64) -> f64 {
    if d2 >= r2 {
        return 0.0;
    }
    let denom = 1.0 - g_r;
    if denom > 1e-9 {
        ((g - g_r) / denom).clamp(0.0, 1.0)
    } else {
        1.0 - d2 / r2
    }
}

/// In-place transpose of a square row-major matrix, in cache-sized blocks.
fn transpose_square_blocked<T: Copy>(m: &mut [T], n: usize) {
    const B: usize = 8;
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
    use crate::psf::{PsfParams, build_kernel};

    /// A kernel with real spatial extent: a dusty 4 mm eye at 300 ppd.
    fn wide_kernel(size: usize) -> PsfKernel {
        build_kernel(&PsfParams {
            particles: 3000,
            particle_um: 40.0,
            ppd: 300.0,
            kernel_size: size,
            wavelength_count: 8,
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

    /// Deterministic pseudo-random image in [0, 1).
    fn random_image(w: usize, h: usize, seed: u64) -> RgbImage {
        let mut s = seed;
        let mut next = || {
            s = s
                .wrapping_mul(6364136223846793005)
                .wrapping_add(1442695040888963407);
            ((s >> 40) as f32) / (1u64 << 24) as f32
        };
        let pixels = (0..w * h).map(|_| [next(), next(), next()]).collect();
        RgbImage::from_pixels(w, h, pixels).unwrap()
    }

    #[test]
    fn point_source_at_the_gaze_becomes_the_kernel() {
        let k = wide_kernel(65);
        let mut conv = GlareConvolver::new(256);
        conv.set_kernel(&k);
        let mut img = RgbImage::new(300, 280);
        *img.get_mut(150, 140) = [1.0, 1.0, 1.0];
        conv.apply(&mut img, [150.5, 140.5], 64.0);
        let c = k.centre() as isize;
        let mut max_err = 0.0f32;
        for y in 0..img.height as isize {
            for x in 0..img.width as isize {
                let want = k.at(x - 150, y - 140);
                let got = img.get(x as usize, y as usize);
                for ch in 0..3 {
                    max_err = max_err.max((want[ch] - got[ch]).abs());
                }
            }
        }
        assert!(
            c == 32 && k.at(0, 0)[1] < 0.5,
            "the test kernel must spread light"
        );
        assert!(max_err < 1e-4, "max |out − kernel| = {max_err}");
    }

    #[test]
    fn energy_is_conserved_in_the_window() {
        let k = wide_kernel(65);
        let mut conv = GlareConvolver::new(256);
        conv.set_kernel(&k);
        for (src, sigma) in [
            ((200usize, 200usize), 64.0),
            ((230, 180), 40.0),
            ((200, 200), f64::INFINITY),
        ] {
            let mut img = RgbImage::new(400, 400);
            *img.get_mut(src.0, src.1) = [1000.0, 500.0, 250.0];
            conv.apply(&mut img, [200.5, 200.5], sigma);
            let t = total(&img);
            for (c, want) in [1000.0, 500.0, 250.0].iter().enumerate() {
                assert!(
                    (t[c] - want).abs() / want < 1e-4,
                    "source {src:?} σ {sigma}: channel {c} {} vs {want}",
                    t[c]
                );
            }
            // Light was actually spread (the source pixel lost some).
            assert!(img.get(src.0, src.1)[0] < 999.0);
        }
    }

    #[test]
    fn glare_stays_near_the_gaze() {
        let k = wide_kernel(65);
        let mut conv = GlareConvolver::new(128);
        conv.set_kernel(&k);
        let mut img = RgbImage::new(1440, 400);
        *img.get_mut(1200, 200) = [1e6, 1e6, 1e6];
        *img.get_mut(200, 200) = [10.0, 10.0, 10.0];
        let before = img.clone();
        conv.apply(&mut img, [200.0, 200.0], 32.0);
        // Every pixel outside the window is untouched, the far source included.
        for y in 0..img.height {
            for x in 0..img.width {
                let inside = (136..264).contains(&x) && (136..264).contains(&y);
                if !inside {
                    assert_eq!(img.get(x, y), before.get(x, y), "({x},{y}) changed");
                }
            }
        }
        // The source at the gaze glared.
        assert!(img.get(201, 200)[1] > 0.0 && img.get(200, 200)[1] < 10.0);
    }

    #[test]
    fn fft_matches_direct_convolution() {
        let k = wide_kernel(33);
        let mut conv = GlareConvolver::new(128);
        conv.set_kernel(&k);
        let img0 = random_image(64, 56, 7);
        let gaze = [30.3, 27.8];
        let sigma = 20.0;
        let mut img = img0.clone();
        conv.apply(&mut img, gaze, sigma);

        // Direct spatial evaluation of out = (1 − w)·img + K ∗ (w·img).
        let r_src = conv.source_radius_px();
        assert_eq!(conv.kernel_radius_px(), 16);
        let weight = |x: usize, y: usize| -> f64 {
            let (dx, dy) = (x as f64 + 0.5 - gaze[0], y as f64 + 0.5 - gaze[1]);
            let d2 = dx * dx + dy * dy;
            let g = (-d2 / (2.0 * sigma * sigma)).exp();
            let g_r = (-r_src * r_src / (2.0 * sigma * sigma)).exp();
            if d2 >= r_src * r_src {
                0.0
            } else {
                (g - g_r) / (1.0 - g_r)
            }
        };
        let (w, h) = (img0.width, img0.height);
        let mut max_err = 0.0f64;
        for y in 0..h {
            for x in 0..w {
                for ch in 0..3 {
                    let mut acc = f64::from(img0.get(x, y)[ch]) * (1.0 - weight(x, y));
                    for sy in 0..h {
                        for sx in 0..w {
                            let kv = k.at(x as isize - sx as isize, y as isize - sy as isize)[ch];
                            if kv != 0.0 {
                                acc += weight(sx, sy)
                                    * f64::from(img0.get(sx, sy)[ch])
                                    * f64::from(kv);
                            }
                        }
                    }
                    max_err = max_err.max((acc - f64::from(img.get(x, y)[ch])).abs());
                }
            }
        }
        assert!(max_err < 1e-5, "max |FFT − direct| = {max_err}");
    }

    #[test]
    fn falloff_weight_is_one_at_the_gaze_and_zero_at_r() {
        let (r2, sigma) = (100.0f64 * 100.0, 40.0f64);
        let g = |d2: f64| (-d2 / (2.0 * sigma * sigma)).exp();
        assert_eq!(falloff_weight(0.0, r2, 1.0, g(r2)), 1.0);
        assert_eq!(falloff_weight(r2, r2, g(r2), g(r2)), 0.0);
        let mut last = 1.0;
        for d in 1..100 {
            let d2 = (d * d) as f64;
            let wv = falloff_weight(d2, r2, g(d2), g(r2));
            assert!(wv < last && wv > 0.0);
            last = wv;
        }
        // σ → ∞ limit.
        assert!((falloff_weight(2500.0, r2, 1.0, 1.0) - 0.75).abs() < 1e-12);
    }

    #[test]
    fn oversized_kernel_is_cropped_and_renormalised() {
        let k = wide_kernel(129);
        let mut conv = GlareConvolver::new(128);
        conv.set_kernel(&k);
        assert_eq!(conv.kernel_radius_px(), 32);
        let mut img = RgbImage::new(200, 200);
        *img.get_mut(100, 100) = [1.0; 3];
        conv.apply(&mut img, [100.5, 100.5], 30.0);
        for (c, t) in total(&img).iter().enumerate() {
            assert!((t - 1.0).abs() < 1e-4, "channel {c}: {t}");
        }
    }

    #[test]
    fn gaze_at_or_outside_the_corners_does_not_panic() {
        let k = wide_kernel(65);
        let mut conv = GlareConvolver::new(128);
        conv.set_kernel(&k);
        let base = random_image(90, 70, 3);
        let gazes = [
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
        ];
        for gaze in gazes {
            for sigma in [32.0, 0.0, -1.0, f64::NAN, f64::INFINITY] {
                let mut img = base.clone();
                conv.apply(&mut img, gaze, sigma);
                assert!(img.pixels.iter().all(|p| p.iter().all(|v| v.is_finite())));
            }
        }
        // A window far off the image leaves it unchanged.
        let mut img = base.clone();
        conv.apply(&mut img, [500.0, 500.0], 32.0);
        assert_eq!(img, base);
        // A corner gaze glares the corner but loses only light that left the image.
        let mut img = base.clone();
        conv.apply(&mut img, [0.0, 0.0], 32.0);
        assert_ne!(img, base);
        let (a, b) = (total(&img), total(&base));
        assert!(
            a[1] <= b[1] * 1.000_01 && a[1] > 0.99 * b[1],
            "{a:?} vs {b:?}"
        );
    }

    #[test]
    fn no_kernel_no_change() {
        let mut conv = GlareConvolver::new(64);
        let base = random_image(40, 40, 1);
        let mut img = base.clone();
        conv.apply(&mut img, [20.0, 20.0], 10.0);
        assert_eq!(img, base);
        assert_eq!(GlareConvolver::new(3).window_px(), 16);
    }
}
