//! Loss of visual acuity in the dark (001 §4.3): a Gaussian blur of CIE
//! L\*a\*b\* lightness L\* only, whose σ is set **per pixel** by that
//! pixel's own lightness (001 eq 11–13), on the linear HDR frame in cd/m²
//! before tone reproduction (001 §4.3.1: "we convert the linear HDR values
//! (i.e., before tone mapping) of the image to the Lab color space").
//!
//! ## Lightness and its white
//!
//! Lab needs a white. 001 applies Lab to the linear HDR values without
//! naming it; its statement that the Vive Pro's 13.85 px/deg matches
//! "L ≈ 1.31" (eq 13 gives Y = 0.158 cd/m² there) fits a white of about
//! 100 cd/m² (L\* = 1.43), not 1 cd/m² (L\* = 46.7). So the white is a fixed
//! luminance, `lab_white_cd_m2` (default 100 cd/m²), **not** the adaptation
//! luminance or the display peak: acuity is a function of the absolute
//! retinal luminance (Larson's fit, eq 11/13, takes Y in cd/m²), and an
//! adaptation white would make a uniformly dark night scene L\* = 100 and
//! never blur it. The same white serves the σ rule and the Lab conversion
//! of the blur: linear sRGB (Rec. 709 primaries, cd/m²) → CIE XYZ (IEC
//! 61966-2-1 matrix) → L\*a\*b\* with the D65 white scaled to
//! `lab_white_cd_m2`. Above the white L\* exceeds 100 (a lamp of
//! 2·10⁴ cd/m² has L\* = 662); the conversion stays monotone and invertible,
//! and such pixels have σ = 0 anyway.
//!
//! Because the blur runs before tone mapping, the retinal image (the
//! frame in cd/m² after glare and acuity, `render --exr`) is taken right
//! after this stage and tone reproduction sees the blurred frame.
//!
//! ## Blur size σ(L) per pixel, display pixels
//!
//! * [`AcuityModel::Linear`] (default; 001 eq 12): `σ = min(max(1 − L, 0), 1)
//!   · ppd / 13.85`. Eq 12 gives σ in pixels of the HTC Vive Pro's
//!   1440 px / 104° = 13.85 px/deg (001 §4.3.2), and eq 11, which it
//!   approximates, is proportional to the display's pixels per degree, so
//!   it is rescaled by `ppd / 13.85`. L < 0 (only from FFT round-off after
//!   glare) is treated as 0: Lab has no negative lightness and 001 bounds σ
//!   by 1 at L = 0. σ > 0 only for L\* < 1, i.e. Y < white/903.3
//!   (0.11 cd/m² at the default white), where L\* = 903.3·Y/white is linear
//!   in Y — so σ needs no cube root.
//! * [`AcuityModel::LarsonKrawczyk`] (001 eq 11, 13):
//!   `σ = ppd / (1.86·√2·R(Y))` px with `R(Y)` Larson et al.'s highest
//!   resolvable spatial frequency (cycles/deg) at the pixel's luminance Y
//!   (= LtoY(L)), eq 13 solved for R: `R = (1.49 + atan((ln Y +
//!   0.575646)/1.64))/0.06`. Y is clamped to at least 10⁻⁶ cd/m² (the lower
//!   end of human vision, 001 §3.3), where R = 0.70 cycles/deg and
//!   σ = 0.54°.
//! * [`AcuityModel::None`]: no blur.
//!
//! A pixel whose σ ≤ [`AcuityBlur::MIN_SIGMA_PX`] (0.3 px) is not blurred
//! (its kernel would put > 99.9 % on itself).
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
//! Cheap when little is dark: a first pass computes only each pixel's Y
//! (no cube root) and marks the rows holding a pixel with σ > 0.3 (the
//! models' σ falls monotonically with Y, so one threshold
//! luminance per frame decides). A frame with no such row is left as it
//! is after that one read. Otherwise L\* is computed for the marked rows
//! and the rows within the largest radius of them (the vertical taps), and
//! only marked rows are blurred and converted back: an unmarked row's
//! pixels all have σ(L) ≤ 0.3, its h equals L, so step 3 leaves it too.
//! Rows run in parallel (rayon) in each pass; nothing is allocated once
//! the scratch buffers have the image's size.

use rayon::prelude::*;
use serde::{Deserialize, Serialize};

use crate::{RgbImage, VisionError};

/// Pixels per degree of the HTC Vive Pro, 1440 px over 104° (001 §4.3.2),
/// the display 001 eq 12 was fitted for.
// 001 §4.3.2: 1440 / 104 ≈ 13.85 PPD
pub const VIVE_PRO_PPD: f64 = 1440.0 / 104.0;

/// Lowest luminance used for Larson's acuity fit, cd/m² (001 §3.3).
const MIN_ACUITY_LUMINANCE_CD_M2: f64 = 1e-6;

/// CIE 1976 κ = 24389/27: L\* = κ·Y/Yn below ε.
const LAB_KAPPA: f64 = 24389.0 / 27.0;

/// CIE 1976 ε = 216/24389.
const LAB_EPSILON: f64 = 216.0 / 24389.0;

/// Acuity model; see the module docs.
#[derive(Clone, Copy, Debug, PartialEq, Serialize, Deserialize)]
#[serde(tag = "model", rename_all = "snake_case", deny_unknown_fields)]
pub enum AcuityModel {
    /// `σ(L) = max(1 − L, 0)` (001 eq 12) per pixel, scaled to the display.
    Linear {
        /// Luminance of Lab white, cd/m² (for σ and for the blur's Lab).
        lab_white_cd_m2: f64,
    },
    /// Krawczyk's σ from Larson's acuity fit (001 eq 11, 13), per pixel.
    LarsonKrawczyk,
    /// No acuity loss.
    None,
}

impl Default for AcuityModel {
    fn default() -> Self {
        Self::Linear {
            lab_white_cd_m2: 100.0, // fits 001 §4.3.2's L ≈ 1.31 at 13.85 PPD
        }
    }
}

/// Larson et al.'s highest resolvable spatial frequency R(Y), cycles/deg,
/// from 001 eq 13 solved for R. Negative below about 10⁻⁹ cd/m².
pub fn larson_acuity_cpd(y_cd_m2: f64) -> f64 {
    // 001 eq 13: Y = exp(−1.64·tan(1.49 − 0.06·R) − 0.575646)
    (1.49 + ((y_cd_m2.ln() + 0.575_646) / 1.64).atan()) / 0.06
}

/// CIE lightness L\* (0–100) of relative luminance `y` (Y/Yn).
pub fn lightness(y: f64) -> f64 {
    if y > LAB_EPSILON {
        116.0 * y.cbrt() - 16.0
    } else {
        y * LAB_KAPPA
    }
}

/// Relative luminance Y/Yn of CIE lightness `l` (inverse of [`lightness`]).
pub fn lightness_to_y(l: f64) -> f64 {
    let f = (l + 16.0) / 116.0;
    if f > 6.0 / 29.0 {
        f * f * f
    } else {
        l / LAB_KAPPA
    }
}

impl AcuityModel {
    /// Checks the parameters.
    pub fn validate(&self) -> Result<(), VisionError> {
        if let Self::Linear { lab_white_cd_m2 } = *self
            && !(lab_white_cd_m2.is_finite() && lab_white_cd_m2 > 0.0)
        {
            return Err(VisionError::invalid(
                "acuity.lab_white_cd_m2",
                lab_white_cd_m2,
                "a finite luminance > 0 cd/m²",
            ));
        }
        Ok(())
    }

    /// Luminance of Lab white, cd/m² (100 for the models without one).
    pub fn lab_white_cd_m2(&self) -> f64 {
        match *self {
            Self::Linear { lab_white_cd_m2 } => lab_white_cd_m2,
            Self::LarsonKrawczyk | Self::None => 100.0,
        }
    }

    /// Blur σ in display pixels of a pixel (or a region) of luminance
    /// `y_cd_m2` on a display whose pixels are `deg_per_px` degrees wide
    /// (`fov / width`): the per-pixel rule of the module docs, in f64.
    /// The frame statistics report it at the adaptation luminance. 0 for
    /// non-finite or non-positive `deg_per_px`.
    pub fn sigma_px(&self, y_cd_m2: f64, deg_per_px: f64) -> f32 {
        if !(deg_per_px.is_finite() && deg_per_px > 0.0) {
            return 0.0;
        }
        let y = if y_cd_m2.is_finite() {
            y_cd_m2.max(0.0)
        } else {
            0.0
        };
        let ppd = 1.0 / deg_per_px;
        let sigma = match *self {
            Self::Linear { lab_white_cd_m2 } => {
                // 001 eq 12, in Vive Pro pixels, rescaled to this display
                let l = lightness(y / lab_white_cd_m2);
                (1.0 - l).clamp(0.0, 1.0) * ppd / VIVE_PRO_PPD
            }
            Self::LarsonKrawczyk => {
                let r = larson_acuity_cpd(y.max(MIN_ACUITY_LUMINANCE_CD_M2));
                // 001 eq 11: σ = width / (fov · 1.86 · √2 · R)
                ppd / (1.86 * std::f64::consts::SQRT_2 * r)
            }
            Self::None => 0.0,
        };
        sigma as f32
    }

    /// The largest σ any pixel can get, display pixels (σ at Y = 0).
    pub fn max_sigma_px(&self, deg_per_px: f64) -> f32 {
        self.sigma_px(0.0, deg_per_px)
    }
}

/// D65 XYZ of RGB (1, 1, 1) under the sRGB matrix (IEC 61966-2-1).
const WHITE_XYZ: [f32; 3] = [0.950_47, 1.0, 1.088_83];

/// Linear sRGB → XYZ (IEC 61966-2-1, D65).
const RGB_TO_XYZ: [[f32; 3]; 3] = [
    [0.412_456_4, 0.357_576_1, 0.180_437_5],
    [0.212_672_9, 0.715_152_2, 0.072_175],
    [0.019_333_9, 0.119_192, 0.950_304_1],
];

/// XYZ → linear sRGB (inverse of [`RGB_TO_XYZ`]).
const XYZ_TO_RGB: [[f32; 3]; 3] = [
    [3.240_454_2, -1.537_138_5, -0.498_531_4],
    [-0.969_266, 1.876_010_8, 0.041_556],
    [0.055_643_4, -0.204_025_9, 1.057_225_2],
];

#[inline]
fn lab_f(t: f32) -> f32 {
    if t > 216.0 / 24389.0 {
        t.cbrt()
    } else {
        (24389.0 / 27.0 * t + 16.0) / 116.0
    }
}

#[inline]
fn lab_f_inv(f: f32) -> f32 {
    if f > 6.0 / 29.0 {
        f * f * f
    } else {
        (116.0 * f - 16.0) * (27.0 / 24389.0)
    }
}

/// CIE lightness scale of a relative tristimulus `t`: `116·f(t) − 16`
/// (L\* for t = Y/Yn): κ·t up to ε, then `116·∛t − 16`.
#[inline]
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
#[inline]
fn lab_g_inv(v: f32) -> f32 {
    if v > 8.0 {
        let f = (v + 16.0) / 116.0;
        f * f * f
    } else {
        v * (27.0 / 24389.0)
    }
}

#[inline]
fn mat3(m: &[[f32; 3]; 3], v: [f32; 3]) -> [f32; 3] {
    [
        m[0][0] * v[0] + m[0][1] * v[1] + m[0][2] * v[2],
        m[1][0] * v[0] + m[1][1] * v[1] + m[1][2] * v[2],
        m[2][0] * v[0] + m[2][1] * v[1] + m[2][2] * v[2],
    ]
}

/// Linear RGB → CIE L\*a\*b\* (D65, white = RGB 1,1,1 in the input's unit).
#[inline]
pub fn rgb_to_lab(rgb: [f32; 3]) -> [f32; 3] {
    let xyz = mat3(&RGB_TO_XYZ, rgb);
    let fx = lab_f(xyz[0] / WHITE_XYZ[0]);
    let fy = lab_f(xyz[1] / WHITE_XYZ[1]);
    let fz = lab_f(xyz[2] / WHITE_XYZ[2]);
    [116.0 * fy - 16.0, 500.0 * (fx - fy), 200.0 * (fy - fz)]
}

/// CIE L\*a\*b\* → linear RGB (inverse of [`rgb_to_lab`]).
#[inline]
pub fn lab_to_rgb(lab: [f32; 3]) -> [f32; 3] {
    let fy = (lab[0] + 16.0) / 116.0;
    let fx = fy + lab[1] / 500.0;
    let fz = fy - lab[2] / 200.0;
    let xyz = [
        lab_f_inv(fx) * WHITE_XYZ[0],
        lab_f_inv(fy) * WHITE_XYZ[1],
        lab_f_inv(fz) * WHITE_XYZ[2],
    ];
    mat3(&XYZ_TO_RGB, xyz)
}

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
    /// L\* of every pixel of the rows that need it.
    lightness: Vec<f32>,
    /// L\* after the horizontal pass.
    horizontal: Vec<f32>,
    /// Per row: 1 = holds a pixel to blur; 2 = needs L\* (within the
    /// largest radius of such a row); 0 = neither.
    rows: Vec<u8>,
}

const ROW_IDLE: u8 = 0;
const ROW_NEEDED: u8 = 1;
const ROW_BLURRED: u8 = 2;

impl AcuityBlur {
    /// Pixels whose σ is at or below this many pixels are not blurred.
    pub const MIN_SIGMA_PX: f32 = 0.3;

    /// The most taps either side of a pixel (σ above `MAX_RADIUS_PX / 3`
    /// is truncated at this radius: only Larson/Krawczyk in the deepest
    /// dark above ~39 px/deg, or eq 12 above ~295 px/deg).
    pub const MAX_RADIUS_PX: usize = 64;

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
        let n = width * height;
        Self {
            width,
            height,
            rule,
            white_cd_m2: white as f32,
            // a 1 % margin: rows are marked conservatively, the per-pixel
            // σ decides exactly
            blur_below_cd_m2: (blur_below * 1.01) as f32,
            max_radius,
            lightness: vec![0.0; n],
            horizontal: vec![0.0; n],
            rows: vec![ROW_IDLE; height],
        }
    }

    /// The largest tap radius of this blur, pixels (0: never blurs).
    pub fn max_radius(&self) -> usize {
        self.max_radius
    }

    /// Blurs the lightness of `img` (linear RGB, cd/m²) in place, each
    /// pixel with its own σ, keeping a\* and b\* of every pixel. Returns the
    /// number of pixels whose lightness changed. Resizes the scratch
    /// buffers (allocating) only when the image size changed.
    pub fn apply(&mut self, img: &mut RgbImage) -> usize {
        let (w, h) = (img.width, img.height);
        if self.max_radius == 0 || w == 0 || h == 0 || img.pixels.len() != w * h {
            return 0;
        }
        if (w, h) != (self.width, self.height) {
            self.width = w;
            self.height = h;
            self.lightness.resize(w * h, 0.0);
            self.horizontal.resize(w * h, 0.0);
            self.rows.resize(h, ROW_IDLE);
        }
        let (rule, white) = (self.rule, self.white_cd_m2);
        let threshold = self.blur_below_cd_m2;
        let y_row = RGB_TO_XYZ[1];

        // Which rows hold a pixel to blur: Y only, no cube root.
        self.rows
            .par_iter_mut()
            .zip(img.pixels.par_chunks(w))
            .for_each(|(flag, row)| {
                let mut dark = false;
                for p in row {
                    let y = y_row[0] * p[0] + y_row[1] * p[1] + y_row[2] * p[2];
                    dark |= y < threshold;
                }
                *flag = if dark { ROW_BLURRED } else { ROW_IDLE };
            });
        if !self.rows.contains(&ROW_BLURRED) {
            return 0;
        }
        // Rows within the largest radius of a blurred row need L*.
        let r_max = self.max_radius;
        let mut last_blurred: Option<usize> = None;
        for y in 0..h {
            if self.rows[y] == ROW_BLURRED {
                last_blurred = Some(y);
            } else if last_blurred.is_some_and(|b| y - b <= r_max) {
                self.rows[y] = ROW_NEEDED;
            }
        }
        let mut next_blurred: Option<usize> = None;
        for y in (0..h).rev() {
            if self.rows[y] == ROW_BLURRED {
                next_blurred = Some(y);
            } else if next_blurred.is_some_and(|b| b - y <= r_max) {
                self.rows[y] = ROW_NEEDED;
            }
        }

        // Steps 1 + 2: L* of the rows that need it; horizontal pass.
        let rows = &self.rows[..];
        let inv_white = 1.0 / white;
        self.lightness
            .par_chunks_mut(w)
            .zip(self.horizontal.par_chunks_mut(w))
            .zip(img.pixels.par_chunks(w))
            .zip(rows.par_iter())
            .for_each(|(((l_row, h_row), px), &flag)| {
                if flag == ROW_IDLE {
                    return;
                }
                for (l, p) in l_row.iter_mut().zip(px) {
                    let y = y_row[0] * p[0] + y_row[1] * p[1] + y_row[2] * p[2];
                    *l = lab_g(y * inv_white);
                }
                if flag == ROW_NEEDED {
                    h_row.copy_from_slice(l_row);
                    return;
                }
                for (x, hv) in h_row.iter_mut().enumerate() {
                    let centre = l_row[x];
                    let sigma = rule.sigma(centre, white);
                    *hv = if sigma > Self::MIN_SIGMA_PX {
                        gather(sigma, r_max, centre, |k| {
                            (l_row[x.saturating_sub(k)], l_row[(x + k).min(w - 1)])
                        })
                    } else {
                        centre
                    };
                }
            });

        // Steps 3 + 4: vertical pass with σ of the new lightness; back to
        // RGB with each pixel's a*, b*.
        let lightness = &self.lightness[..];
        let horizontal = &self.horizontal[..];
        let wx = WHITE_XYZ.map(|c| c * white);
        img.pixels
            .par_chunks_mut(w)
            .enumerate()
            .filter(|(y, _)| rows[*y] == ROW_BLURRED)
            .map(|(y, out)| {
                let mut changed = 0usize;
                for (x, o) in out.iter_mut().enumerate() {
                    let hv = horizontal[y * w + x];
                    let sigma = rule.sigma(hv, white);
                    let l_new = if sigma > Self::MIN_SIGMA_PX {
                        gather(sigma, r_max, hv, |k| {
                            (
                                horizontal[y.saturating_sub(k) * w + x],
                                horizontal[(y + k).min(h - 1) * w + x],
                            )
                        })
                    } else {
                        hv
                    };
                    let l_old = lightness[y * w + x];
                    if l_new == l_old {
                        continue;
                    }
                    changed += 1;
                    let xyz = mat3(&RGB_TO_XYZ, *o);
                    let d = l_new - l_old;
                    let xyz_new = [
                        lab_g_inv(lab_g(xyz[0] / wx[0]) + d) * wx[0],
                        lab_g_inv(l_old + d) * wx[1],
                        lab_g_inv(lab_g(xyz[2] / wx[2]) + d) * wx[2],
                    ];
                    *o = mat3(&XYZ_TO_RGB, xyz_new);
                }
                changed
            })
            .sum()
    }
}

/// `Σₖ g(k)·v(k) / Σₖ g(k)` over k = −r..=r, `g(k) = exp(−k²/(2σ²))`,
/// r = min(⌈3σ⌉, `r_max`), `centre` = v(0), `pair(k)` = (v(−k), v(k)).
/// The weights come from one `exp` and the recurrence of the module docs.
#[inline(always)]
fn gather(sigma: f32, r_max: usize, centre: f32, pair: impl Fn(usize) -> (f32, f32)) -> f32 {
    let r = ((3.0 * sigma).ceil() as usize).min(r_max);
    let e = (-0.5 / (sigma * sigma)).exp();
    let e2 = e * e;
    let (mut g, mut q) = (1.0f32, e);
    let (mut acc, mut norm) = (centre, 1.0f32);
    for k in 1..=r {
        g *= q;
        q *= e2;
        let (a, b) = pair(k);
        acc += g * (a + b);
        norm += 2.0 * g;
    }
    acc / norm
}

#[cfg(test)]
mod tests {
    use super::*;

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

    #[test]
    fn lab_round_trip() {
        let mut worst = 0.0f32;
        for r in 0..=10 {
            for g in 0..=10 {
                for b in 0..=10 {
                    let c = [r as f32 / 10.0, g as f32 / 10.0, b as f32 / 10.0];
                    let back = lab_to_rgb(rgb_to_lab(c));
                    for i in 0..3 {
                        worst = worst.max((back[i] - c[i]).abs());
                    }
                }
            }
        }
        assert!(worst < 2e-5, "worst round-trip error {worst}");
        // White is L* = 100, a* = b* = 0; black is 0.
        let w = rgb_to_lab([1.0; 3]);
        assert!(
            (w[0] - 100.0).abs() < 1e-3 && w[1].abs() < 1e-3 && w[2].abs() < 1e-3,
            "{w:?}"
        );
        assert_eq!(rgb_to_lab([0.0; 3]), [0.0; 3]);
        // CIE: 18 % grey has L* = 49.5.
        let g = rgb_to_lab([0.18; 3]);
        assert!((g[0] - 49.496).abs() < 0.01, "{g:?}");
        for l in [0.0, 0.5, 7.9, 8.1, 50.0, 662.0] {
            assert!((lightness(lightness_to_y(l)) - l).abs() < 1e-9, "{l}");
        }
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
        let (w, h) = (97, 61);
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
    fn sigma_models() {
        let vive_dpp = 1.0 / VIVE_PRO_PPD;
        let lin = AcuityModel::default();
        // Bright: no blur; black: σ = 1 Vive pixel (001 eq 12).
        assert_eq!(lin.sigma_px(10.0, vive_dpp), 0.0);
        assert!((lin.sigma_px(0.0, vive_dpp) - 1.0).abs() < 1e-6);
        // L* = 0.5 at Y/Yn = 0.5 / 903.3: σ = 0.5.
        let y = 100.0 * 0.5 * 27.0 / 24389.0;
        assert!((lin.sigma_px(y, vive_dpp) - 0.5).abs() < 1e-5);
        // Twice the pixels per degree, twice the σ in pixels.
        assert!((lin.sigma_px(y, vive_dpp / 2.0) - 1.0).abs() < 1e-5);

        // 001 §4.3.2: R = 13.85 cpd at Y = exp(−1.64·tan(1.49 − 0.831) − 0.575646).
        let y = (-1.64 * (1.49f64 - 0.06 * 13.85).tan() - 0.575_646).exp();
        assert!((y - 0.158).abs() < 1e-3, "{y}");
        assert!((larson_acuity_cpd(y) - 13.85).abs() < 1e-9);
        // Larson's R rises with luminance.
        assert!(larson_acuity_cpd(100.0) > larson_acuity_cpd(1.0));
        let lk = AcuityModel::LarsonKrawczyk;
        let s = lk.sigma_px(y, vive_dpp);
        let expected = VIVE_PRO_PPD / (1.86 * std::f64::consts::SQRT_2 * 13.85);
        assert!((f64::from(s) - expected).abs() < 1e-6);
        // Bounded in the dark.
        let dark = lk.sigma_px(0.0, vive_dpp);
        assert!(dark.is_finite() && dark > 5.0 && dark < 10.0, "{dark}");
        assert_eq!(AcuityModel::None.sigma_px(0.0, vive_dpp), 0.0);
        assert_eq!(lin.sigma_px(0.0, f64::NAN), 0.0);
        assert!(
            AcuityModel::Linear {
                lab_white_cd_m2: 0.0
            }
            .validate()
            .is_err()
        );
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
