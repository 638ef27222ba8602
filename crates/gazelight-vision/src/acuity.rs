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
//! ## The blur
//!
//! The blur this σ drives (001 §4.3.1 steps 1–4: Lab lightness, a
//! horizontal and a vertical Gaussian pass with each pixel's own σ, back to
//! RGB with the pixel's own a\*, b\*) runs in the CPU band engine,
//! [`crate::band::AcuityBlur`], which documents the steps and how they are
//! streamed and vectorised; the CIE Lab conversions are in [`crate::colour`].

use serde::{Deserialize, Serialize};

use crate::VisionError;
use crate::colour::lightness;

/// Pixels per degree of the HTC Vive Pro, 1440 px over 104° (001 §4.3.2),
/// the display 001 eq 12 was fitted for.
// 001 §4.3.2: 1440 / 104 ≈ 13.85 PPD
pub const VIVE_PRO_PPD: f64 = 1440.0 / 104.0;

/// Lowest luminance used for Larson's acuity fit, cd/m² (001 §3.3).
pub(crate) const MIN_ACUITY_LUMINANCE_CD_M2: f64 = 1e-6;

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

#[cfg(test)]
mod tests {
    use super::*;

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
