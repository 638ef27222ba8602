//! Loss of visual acuity in the dark (001 §4.3): a Gaussian blur of CIE
//! L\*a\*b\* lightness L\* only, whose σ grows as the adaptation luminance
//! falls.
//!
//! ## Blur size
//!
//! * [`AcuityModel::Linear`] (default; 001 eq 12): `σ(L) = max(1 − L, 0)`,
//!   where `L` is the Lab lightness (0–100 scale) of the adaptation
//!   luminance. 001 applies Lab to the linear HDR values without naming
//!   the white; its statement that the Vive Pro's 13.85 px/deg matches
//!   "L ≈ 1.31" (eq 13 gives Y = 0.158 cd/m² there) fits a white of about
//!   100 cd/m² (L\* = 1.43), not 1 cd/m² (L\* = 46.7), so the white is a
//!   parameter, `lab_white_cd_m2`, default 100. Eq 12 approximates eq 11
//!   for the HTC Vive Pro's 1440 px / 104° = 13.85 px/deg (001 §4.3.2),
//!   and eq 11 is proportional to the display's pixels per degree, so the
//!   σ of eq 12 is scaled by `ppd / 13.85` for other displays. Largest
//!   blur: σ = 1 Vive pixel (0.072°) at L = 0.
//! * [`AcuityModel::LarsonKrawczyk`] (001 eq 11, 13):
//!   `σ = (width/fov) / (1.86·√2·R(Y))` px with `width/fov` the display's
//!   pixels per degree and `R(Y)` Larson et al.'s highest resolvable
//!   spatial frequency (cycles/deg) at luminance Y, i.e. eq 13 solved for
//!   R: `R = (1.49 + atan((ln Y + 0.575646)/1.64))/0.06`. R reaches 0 near
//!   Y = 10⁻⁹ cd/m²; Y is clamped to at least 10⁻⁶ cd/m² (the lower end of
//!   human vision, 001 §3.3), where R = 0.70 cycles/deg and σ = 0.54°.
//! * [`AcuityModel::None`]: no blur.
//!
//! Unlike 001, which varies σ per pixel with the pixel's lightness, the
//! pipeline uses one σ per frame, from the adaptation luminance.
//!
//! ## The blur
//!
//! [`AcuityBlur::apply`] works on display-relative linear RGB in [0, 1]
//! (after tone reproduction, so that Lab has a bounded white): linear sRGB
//! (Rec. 709 primaries) → CIE XYZ → L\*a\*b\* with the **D65 white of the
//! display, RGB (1, 1, 1)** (IEC 61966-2-1 matrices; Yn = 1 = display
//! peak). L\* is blurred with a normalised, sampled 1D Gaussian of
//! radius ⌈3σ⌉ (001 §4.3.2: size 2⌈3σ⌉ + 1), horizontally then vertically
//! (001 §4.3.3), with edge pixels replicated; a\* and b\* of every pixel are
//! kept, and the result goes back to linear RGB. σ ≤ 0.3 px
//! ([`AcuityBlur::MIN_SIGMA_PX`]) is a no-op. Rows run in parallel (rayon)
//! in both passes; nothing is allocated once the scratch buffers have the
//! image's size (and the kernel its radius).

use rayon::prelude::*;
use serde::{Deserialize, Serialize};

use crate::{RgbImage, VisionError};

/// Pixels per degree of the HTC Vive Pro, 1440 px over 104° (001 §4.3.2),
/// the display 001 eq 12 was fitted for.
// 001 §4.3.2: 1440 / 104 ≈ 13.85 PPD
pub const VIVE_PRO_PPD: f64 = 1440.0 / 104.0;

/// Lowest luminance used for Larson's acuity fit, cd/m² (001 §3.3).
const MIN_ACUITY_LUMINANCE_CD_M2: f64 = 1e-6;

/// Acuity model; see the module docs.
#[derive(Clone, Copy, Debug, PartialEq, Serialize, Deserialize)]
#[serde(tag = "model", rename_all = "snake_case", deny_unknown_fields)]
pub enum AcuityModel {
    /// `σ(L) = max(1 − L, 0)` (001 eq 12), scaled to the display.
    Linear {
        /// Luminance of Lab white for L of the adaptation luminance, cd/m².
        lab_white_cd_m2: f64,
    },
    /// Krawczyk's σ from Larson's acuity fit (001 eq 11, 13).
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
    // CIE 1976: ε = 216/24389, κ = 24389/27
    if y > 216.0 / 24389.0 {
        116.0 * y.cbrt() - 16.0
    } else {
        y * (24389.0 / 27.0)
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

    /// Blur σ in display pixels for the adaptation luminance
    /// `adaptation_cd_m2` on a display whose pixels are `deg_per_px`
    /// degrees wide (`fov / width`). 0 for non-finite or non-positive
    /// `deg_per_px`.
    pub fn sigma_px(&self, adaptation_cd_m2: f64, deg_per_px: f64) -> f32 {
        if !(deg_per_px.is_finite() && deg_per_px > 0.0) {
            return 0.0;
        }
        let y = if adaptation_cd_m2.is_finite() {
            adaptation_cd_m2.max(0.0)
        } else {
            0.0
        };
        let ppd = 1.0 / deg_per_px;
        let sigma = match *self {
            Self::Linear { lab_white_cd_m2 } => {
                // 001 eq 12, in Vive Pro pixels, rescaled to this display
                let l = lightness(y / lab_white_cd_m2);
                (1.0 - l).max(0.0) * ppd / VIVE_PRO_PPD
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

/// Display-relative linear RGB → CIE L\*a\*b\* (D65, white = RGB 1,1,1).
#[inline]
pub fn rgb_to_lab(rgb: [f32; 3]) -> [f32; 3] {
    let m = RGB_TO_XYZ;
    let xyz = [
        m[0][0] * rgb[0] + m[0][1] * rgb[1] + m[0][2] * rgb[2],
        m[1][0] * rgb[0] + m[1][1] * rgb[1] + m[1][2] * rgb[2],
        m[2][0] * rgb[0] + m[2][1] * rgb[1] + m[2][2] * rgb[2],
    ];
    let fx = lab_f(xyz[0] / WHITE_XYZ[0]);
    let fy = lab_f(xyz[1] / WHITE_XYZ[1]);
    let fz = lab_f(xyz[2] / WHITE_XYZ[2]);
    [116.0 * fy - 16.0, 500.0 * (fx - fy), 200.0 * (fy - fz)]
}

/// CIE L\*a\*b\* → display-relative linear RGB (inverse of [`rgb_to_lab`]).
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
    let m = XYZ_TO_RGB;
    [
        m[0][0] * xyz[0] + m[0][1] * xyz[1] + m[0][2] * xyz[2],
        m[1][0] * xyz[0] + m[1][1] * xyz[1] + m[1][2] * xyz[2],
        m[2][0] * xyz[0] + m[2][1] * xyz[1] + m[2][2] * xyz[2],
    ]
}

/// Separable Gaussian blur of Lab lightness with preallocated scratch.
#[derive(Clone, Debug)]
pub struct AcuityBlur {
    width: usize,
    height: usize,
    /// L\*a\*b\* of every pixel.
    lab: Vec<[f32; 3]>,
    /// L\* after the horizontal pass.
    horizontal: Vec<f32>,
    /// Normalised kernel, taps −r..=r.
    kernel: Vec<f32>,
}

impl AcuityBlur {
    /// Blurs with σ at or below this many pixels are skipped.
    pub const MIN_SIGMA_PX: f32 = 0.3;

    /// Scratch buffers for `width × height` images.
    pub fn new(width: usize, height: usize) -> Self {
        let n = width * height;
        Self {
            width,
            height,
            lab: vec![[0.0; 3]; n],
            horizontal: vec![0.0; n],
            // room for σ up to 16 px before any reallocation
            kernel: Vec::with_capacity(2 * 48 + 1),
        }
    }

    /// Blurs the L\* of `img` (display-relative linear RGB) with a Gaussian
    /// of `sigma_px` pixels, keeping a\* and b\* of every pixel. A no-op for
    /// σ ≤ [`Self::MIN_SIGMA_PX`] or non-finite σ. Resizes the scratch
    /// buffers (allocating) only when the image size changed.
    pub fn apply(&mut self, img: &mut RgbImage, sigma_px: f32) {
        if !(sigma_px.is_finite() && sigma_px > Self::MIN_SIGMA_PX) {
            return;
        }
        let (w, h) = (img.width, img.height);
        if w == 0 || h == 0 || img.pixels.len() != w * h {
            return;
        }
        if (w, h) != (self.width, self.height) {
            self.width = w;
            self.height = h;
            self.lab.resize(w * h, [0.0; 3]);
            self.horizontal.resize(w * h, 0.0);
        }
        // Kernel: radius ⌈3σ⌉ (001 §4.3.2), normalised.
        let r = (3.0 * sigma_px).ceil() as usize;
        self.kernel.clear();
        let inv2s2 = 1.0 / (2.0 * sigma_px * sigma_px);
        for i in 0..=2 * r {
            let d = i as f32 - r as f32;
            self.kernel.push((-d * d * inv2s2).exp());
        }
        let norm: f32 = self.kernel.iter().sum();
        for k in &mut self.kernel {
            *k /= norm;
        }
        let kernel = &self.kernel[..];

        // To Lab, and the horizontal pass of L*.
        self.lab
            .par_chunks_mut(w)
            .zip(img.pixels.par_chunks(w))
            .for_each(|(lab, src)| {
                for (l, s) in lab.iter_mut().zip(src) {
                    *l = rgb_to_lab(*s);
                }
            });
        let lab = &self.lab[..];
        self.horizontal
            .par_chunks_mut(w)
            .zip(lab.par_chunks(w))
            .for_each(|(out, row)| {
                for (x, o) in out.iter_mut().enumerate() {
                    let mut acc = 0.0;
                    for (i, k) in kernel.iter().enumerate() {
                        let xx = (x + i).saturating_sub(r).min(w - 1);
                        acc += k * row[xx][0];
                    }
                    *o = acc;
                }
            });
        // Vertical pass of L*, with each pixel's own a*, b*, back to RGB.
        let horizontal = &self.horizontal[..];
        img.pixels
            .par_chunks_mut(w)
            .enumerate()
            .for_each(|(y, out)| {
                let lab_row = &lab[y * w..(y + 1) * w];
                for (x, o) in out.iter_mut().enumerate() {
                    let mut acc = 0.0;
                    for (i, k) in kernel.iter().enumerate() {
                        let yy = (y + i).saturating_sub(r).min(h - 1);
                        acc += k * horizontal[yy * w + x];
                    }
                    let [_, a, b] = lab_row[x];
                    *o = lab_to_rgb([acc, a, b]);
                }
            });
    }
}

#[cfg(test)]
mod tests {
    use super::*;

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
    }

    fn image(w: usize, h: usize, f: impl Fn(usize, usize) -> [f32; 3]) -> RgbImage {
        let mut px = Vec::with_capacity(w * h);
        for y in 0..h {
            for x in 0..w {
                px.push(f(x, y));
            }
        }
        RgbImage::from_pixels(w, h, px).unwrap()
    }

    #[test]
    fn flat_image_unchanged() {
        let mut img = image(40, 30, |_, _| [0.3, 0.5, 0.2]);
        let orig = img.clone();
        let mut blur = AcuityBlur::new(40, 30);
        blur.apply(&mut img, 2.5);
        for (a, b) in img.pixels.iter().zip(&orig.pixels) {
            for i in 0..3 {
                assert!((a[i] - b[i]).abs() < 2e-5, "{a:?} vs {b:?}");
            }
        }
    }

    #[test]
    fn small_sigma_is_a_no_op() {
        let mut img = image(16, 16, |x, y| {
            [(x % 3) as f32 * 0.3, (y % 5) as f32 * 0.2, 0.1]
        });
        let orig = img.clone();
        let mut blur = AcuityBlur::new(16, 16);
        blur.apply(&mut img, 0.3);
        blur.apply(&mut img, f32::NAN);
        assert_eq!(img, orig);
    }

    #[test]
    fn edge_spread_matches_sigma() {
        // Vertical edge between grey 0.05 and 0.6: after the blur, the
        // derivative of the L* profile along a row is the kernel, whose
        // standard deviation is σ (up to the 3σ truncation, ~1.6 %).
        let (w, h) = (120, 20);
        let mut img = image(w, h, |x, _| if x < 60 { [0.05; 3] } else { [0.6; 3] });
        let mut blur = AcuityBlur::new(w, h);
        for sigma in [1.0f32, 2.0, 4.0] {
            let mut im = img.clone();
            blur.apply(&mut im, sigma);
            let l: Vec<f32> = (0..w).map(|x| rgb_to_lab(im.get(x, 10))[0]).collect();
            let (mut m0, mut m1, mut m2) = (0.0f64, 0.0f64, 0.0f64);
            for x in 1..w {
                let d = f64::from(l[x] - l[x - 1]);
                let pos = x as f64 - 0.5;
                m0 += d;
                m1 += d * pos;
                m2 += d * pos * pos;
            }
            let mean = m1 / m0;
            let sd = (m2 / m0 - mean * mean).sqrt();
            eprintln!("acuity edge: σ {sigma} px → measured spread {sd:.4} px, centre {mean:.4}");
            assert!((mean - 59.5).abs() < 0.01, "edge moved: {mean}");
            assert!(
                (sd / f64::from(sigma) - 1.0).abs() < 0.03,
                "σ {sigma}: spread {sd}"
            );
            // Far from the edge nothing changes.
            assert!((l[5] - rgb_to_lab([0.05; 3])[0]).abs() < 1e-3);
            // Rows are all alike: the vertical pass of a vertical edge is flat.
            assert!((rgb_to_lab(im.get(58, 0))[0] - l[58]).abs() < 1e-3);
        }
        // The same buffers serve another size.
        img = image(33, 17, |x, _| if x < 16 { [0.0; 3] } else { [1.0; 3] });
        blur.apply(&mut img, 1.5);
        assert!(img.get(15, 8)[0] > 0.0 && img.get(16, 8)[0] < 1.0);
    }

    #[test]
    fn chroma_preserved() {
        // A colourful image: a*, b* of every pixel survive the blur.
        let (w, h) = (48, 32);
        let mut img = image(w, h, |x, y| {
            [
                0.1 + 0.8 * ((x * 7 + y * 3) % 11) as f32 / 10.0,
                0.1 + 0.6 * ((x * 5 + y) % 7) as f32 / 6.0,
                0.05 + 0.4 * ((x + y * 2) % 5) as f32 / 4.0,
            ]
        });
        let before: Vec<[f32; 3]> = img.pixels.iter().map(|&p| rgb_to_lab(p)).collect();
        let mut blur = AcuityBlur::new(w, h);
        blur.apply(&mut img, 1.7);
        let mut changed_l = 0;
        for (p, b) in img.pixels.iter().zip(&before) {
            let a = rgb_to_lab(*p);
            assert!(
                (a[1] - b[1]).abs() < 2e-3 && (a[2] - b[2]).abs() < 2e-3,
                "{a:?} vs {b:?}"
            );
            if (a[0] - b[0]).abs() > 0.5 {
                changed_l += 1;
            }
        }
        assert!(
            changed_l > w * h / 2,
            "lightness barely blurred: {changed_l}"
        );
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
    }
}
