//! Night colour: the scotopic colour shift (001 eq 14) and the loss of
//! colour discrimination (000 eq 11–12). Both act on **display-relative
//! linear RGB after tone reproduction**, as in the seeds.
//!
//! * Scotopic shift (001 eq 14, after Krawczyk et al.):
//!   `SV = RGB·(1 − σ(L_i)) + [1.05, 0.97, 1.27]·L'_i·σ(L_i)`, where
//!   `σ(Y) = 0.04/(0.04 + Y)` is the rod sensitivity (001 eq 4) evaluated
//!   at `L_i`, the temporally filtered **adaptation** luminance in scene
//!   cd/m² (001 §4.4: "the original scene luminance (i.e. not tone
//!   mapped)"), and `L'_i` is the luminance (001 eq 1) of the tone-mapped
//!   pixel `RGB`. σ is one number per frame. In daylight σ → 0 (identity);
//!   at night σ → 1 and every pixel becomes the lavender tint times its
//!   luminance. The tint's own luminance is 1.0086, so the shift raises
//!   luminance by at most 0.86 %.
//! * Colour discrimination (000 eq 11–12, after Wernikowski et al.):
//!   `σ_c(L_w) = 1` if `L_w > 3` cd/m², else
//!   `0.069/(0.069 + 1.409·e^(−4.267·L_w))`, and
//!   `RGB_display = L_d(L_w)·(σ_c·RGB_image/L_w + (1 − σ_c))`. 000 uses the
//!   pixel's own **scene** luminance `L_w` (cd/m²). For a tone operator
//!   that scales RGB like luminance (000 eq 9), `L_d·RGB_image/L_w` is the
//!   tone-mapped colour, so eq 12 is, in the display domain,
//!   `out = σ_c·RGB + (1 − σ_c)·Y(RGB)·[1, 1, 1]`: a desaturation towards
//!   the grey of the same luminance, which preserves luminance exactly
//!   (001 eq 1 weights sum to 1). [`ColourFrame::apply_with_scene_luminance`]
//!   follows 000 per pixel; [`ColourFrame::apply`], which sees only the
//!   display colour, evaluates `σ_c` once per frame at the adaptation
//!   luminance given to [`ColourModel::prepare`].
//!
//! [`ColourModel::Both`] applies the discrimination first, then the shift.
//!
//! The CIE 1976 L\*a\*b\* conversions of linear sRGB (IEC 61966-2-1
//! matrices, D65 white scaled to the input's unit) live here too:
//! [`lightness`] / [`lightness_to_y`] (L\* of Y/Yn and back, the acuity
//! model's σ rule, [`crate::acuity`]) and [`rgb_to_lab`] / [`lab_to_rgb`];
//! the band engine ([`crate::band`]) uses their constants.

use serde::{Deserialize, Serialize};

use crate::VisionError;
use crate::image::luminance;
use crate::temporal::rod_sensitivity;

/// The scotopic tint of 001 eq 14 (lavender, after Krawczyk et al.).
// 001 eq 14: [1.05, 0.97, 1.27]
pub const SCOTOPIC_TINT: [f32; 3] = [1.05, 0.97, 1.27];

/// Colour model; see the module docs.
#[derive(Clone, Copy, Debug, Default, PartialEq, Serialize, Deserialize)]
#[serde(tag = "model", rename_all = "snake_case", deny_unknown_fields)]
pub enum ColourModel {
    /// Scotopic shift towards the tint (001 eq 14).
    #[default]
    ScotopicShift,
    /// Desaturation by colour discrimination (000 eq 11–12).
    Discrimination,
    /// Discrimination, then the scotopic shift.
    Both,
    /// Colour unchanged.
    None,
}

/// Colour-discrimination σ (000 eq 11): 1 = full colour, → 0.047 at 0 cd/m².
pub fn discrimination_sigma(l_w_cd_m2: f64) -> f64 {
    // 000 eq 11: full colour above 3 cd/m²
    if l_w_cd_m2 > 3.0 {
        1.0
    } else {
        let l = l_w_cd_m2.max(0.0);
        // 000 eq 11: 0.069 / (0.069 + 1.409·exp(−4.267·L_w))
        0.069 / (0.069 + 1.409 * (-4.267 * l).exp())
    }
}

impl ColourModel {
    /// Checks the parameters (the variants have none).
    pub fn validate(&self) -> Result<(), VisionError> {
        Ok(())
    }

    /// Per-frame scalars for the adaptation luminance `adaptation_cd_m2`
    /// (scene cd/m²; non-finite or negative counts as 0).
    pub fn prepare(&self, adaptation_cd_m2: f64) -> ColourFrame {
        let la = if adaptation_cd_m2.is_finite() {
            adaptation_cd_m2.max(0.0)
        } else {
            0.0
        };
        let (shift, discrimination) = match self {
            Self::ScotopicShift => (true, false),
            Self::Discrimination => (false, true),
            Self::Both => (true, true),
            Self::None => (false, false),
        };
        ColourFrame {
            shift_sigma: if shift {
                rod_sensitivity(la) as f32
            } else {
                0.0
            },
            discrimination,
            discrimination_sigma: discrimination_sigma(la) as f32,
        }
    }
}

/// The per-frame scalars of a [`ColourModel`].
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct ColourFrame {
    /// Rod sensitivity σ(L_i) of 001 eq 4 (0 when the shift is off).
    pub shift_sigma: f32,
    /// Whether colour discrimination is applied.
    pub discrimination: bool,
    /// σ_c of 000 eq 11 at the adaptation luminance.
    pub discrimination_sigma: f32,
}

impl ColourFrame {
    /// Applies the model to a tone-mapped display-relative linear colour,
    /// with the discrimination σ_c of the frame's adaptation luminance.
    #[inline]
    pub fn apply(&self, rgb: [f32; 3]) -> [f32; 3] {
        let rgb = if self.discrimination {
            desaturate(rgb, self.discrimination_sigma)
        } else {
            rgb
        };
        self.shift(rgb)
    }

    /// As [`apply`](Self::apply), with σ_c of 000 eq 11 evaluated at the
    /// pixel's own scene luminance (cd/m², before tone mapping), as 000
    /// does.
    #[inline]
    pub fn apply_with_scene_luminance(
        &self,
        rgb: [f32; 3],
        scene_luminance_cd_m2: f32,
    ) -> [f32; 3] {
        let rgb = if self.discrimination {
            desaturate(rgb, discrimination_sigma_f32(scene_luminance_cd_m2))
        } else {
            rgb
        };
        self.shift(rgb)
    }

    /// [`apply`](Self::apply) as a matrix: `apply(rgb) = M·rgb` (both
    /// models are linear in the colour), `M[i][j] = apply(e_j)[i]`. The
    /// frame pipeline folds it with a linear tone operator into one affine
    /// map per frame.
    pub fn matrix(&self) -> [[f32; 3]; 3] {
        let cols = [
            self.apply([1.0, 0.0, 0.0]),
            self.apply([0.0, 1.0, 0.0]),
            self.apply([0.0, 0.0, 1.0]),
        ];
        [
            [cols[0][0], cols[1][0], cols[2][0]],
            [cols[0][1], cols[1][1], cols[2][1]],
            [cols[0][2], cols[1][2], cols[2][2]],
        ]
    }

    #[inline]
    fn shift(&self, rgb: [f32; 3]) -> [f32; 3] {
        let s = self.shift_sigma;
        if s <= 0.0 {
            return rgb;
        }
        // 001 eq 14, L'_i = luminance of the tone-mapped pixel
        let l = luminance(rgb);
        [
            rgb[0] * (1.0 - s) + SCOTOPIC_TINT[0] * l * s,
            rgb[1] * (1.0 - s) + SCOTOPIC_TINT[1] * l * s,
            rgb[2] * (1.0 - s) + SCOTOPIC_TINT[2] * l * s,
        ]
    }
}

/// 000 eq 11 in f32 for the per-pixel path.
#[inline]
fn discrimination_sigma_f32(l_w: f32) -> f32 {
    if l_w > 3.0 {
        1.0
    } else {
        let l = if l_w > 0.0 { l_w } else { 0.0 };
        0.069 / (0.069 + 1.409 * (-4.267 * l).exp())
    }
}

/// 000 eq 12 in the display domain: `σ·RGB + (1 − σ)·Y(RGB)`.
#[inline]
fn desaturate(rgb: [f32; 3], sigma: f32) -> [f32; 3] {
    let grey = (1.0 - sigma) * luminance(rgb);
    [
        sigma * rgb[0] + grey,
        sigma * rgb[1] + grey,
        sigma * rgb[2] + grey,
    ]
}

// CIE 1976 L*a*b* of linear sRGB (IEC 61966-2-1 primaries, D65 white).

/// CIE 1976 κ = 24389/27: L\* = κ·Y/Yn below ε.
pub(crate) const LAB_KAPPA: f64 = 24389.0 / 27.0;

/// [`LAB_KAPPA`] in f32.
pub(crate) const LAB_KAPPA_F32: f32 = 24389.0 / 27.0;

/// CIE 1976 ε = 216/24389.
const LAB_EPSILON: f64 = 216.0 / 24389.0;

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

/// D65 XYZ of RGB (1, 1, 1) under the sRGB matrix (IEC 61966-2-1).
pub(crate) const WHITE_XYZ: [f32; 3] = [0.950_47, 1.0, 1.088_83];

/// Linear sRGB → XYZ (IEC 61966-2-1, D65).
pub(crate) const RGB_TO_XYZ: [[f32; 3]; 3] = [
    [0.412_456_4, 0.357_576_1, 0.180_437_5],
    [0.212_672_9, 0.715_152_2, 0.072_175],
    [0.019_333_9, 0.119_192, 0.950_304_1],
];

/// XYZ → linear sRGB (inverse of [`RGB_TO_XYZ`]).
pub(crate) const XYZ_TO_RGB: [[f32; 3]; 3] = [
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

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn discrimination_sigma_follows_000_eq11() {
        for l in [3.0001, 10.0, 1e5] {
            assert_eq!(discrimination_sigma(l), 1.0);
        }
        // Hand-computed: 0.069/(0.069 + 1.409) at 0, and just below 3.
        assert!((discrimination_sigma(0.0) - 0.046_684_709).abs() < 1e-8);
        assert!((discrimination_sigma(3.0) - 0.999_943_684).abs() < 1e-8);
        // At 0.5 cd/m²: 0.069/(0.069 + 1.409·e^−2.1335).
        let e = 0.069 / (0.069 + 1.409 * (-2.1335f64).exp());
        assert!((discrimination_sigma(0.5) - e).abs() < 1e-12);
        assert!((f64::from(discrimination_sigma_f32(0.5)) - e).abs() < 1e-6);
        // Monotonic.
        let mut prev = 0.0;
        for i in 0..=300 {
            let s = discrimination_sigma(f64::from(i) * 0.01);
            assert!(s >= prev);
            prev = s;
        }
    }

    #[test]
    fn scotopic_shift_identity_in_daylight_tint_at_night() {
        let c = [0.6f32, 0.3, 0.1];
        let day = ColourModel::ScotopicShift.prepare(1e4);
        let out = day.apply(c);
        for i in 0..3 {
            assert!((out[i] - c[i]).abs() < 1e-5, "{out:?}");
        }
        let night = ColourModel::ScotopicShift.prepare(1e-5);
        assert!(night.shift_sigma > 0.999);
        let out = night.apply(c);
        let l = luminance(c);
        for i in 0..3 {
            assert!((out[i] - SCOTOPIC_TINT[i] * l).abs() < 1e-3, "{out:?}");
        }
        // Blue-ish: B > R > G whatever the input colour.
        assert!(out[2] > out[0] && out[0] > out[1]);
        // At L_i = 0.04 cd/m² the rods are half sensitive: half way.
        let mid = ColourModel::ScotopicShift.prepare(0.04).apply(c);
        for i in 0..3 {
            let e = 0.5 * c[i] + 0.5 * SCOTOPIC_TINT[i] * l;
            assert!((mid[i] - e).abs() < 1e-6);
        }
    }

    #[test]
    fn scotopic_shift_luminance_within_tint_luminance() {
        // Luminance grows by σ·(Y(tint) − 1) = at most 0.86 %.
        let tint_y = luminance(SCOTOPIC_TINT);
        assert!((tint_y - 1.008_63).abs() < 1e-5);
        let f = ColourModel::ScotopicShift.prepare(0.001);
        for c in [[0.2f32, 0.5, 0.9], [1.0, 0.0, 0.0], [0.0, 0.0, 1.0]] {
            let y0 = luminance(c);
            let y1 = luminance(f.apply(c));
            let s = f.shift_sigma;
            assert!((y1 - y0 * (1.0 - s + s * tint_y)).abs() < 1e-6);
        }
    }

    #[test]
    fn discrimination_preserves_luminance_and_desaturates() {
        let f = ColourModel::Discrimination.prepare(0.01);
        let c = [0.8f32, 0.2, 0.05];
        let out = f.apply(c);
        assert!((luminance(out) - luminance(c)).abs() < 1e-6);
        // Spread of the channels shrinks by σ_c.
        let s = f.discrimination_sigma;
        assert!(((out[0] - out[2]) - s * (c[0] - c[2])).abs() < 1e-6);
        // Per pixel: a bright pixel keeps its colour even at night.
        let out = f.apply_with_scene_luminance(c, 50.0);
        assert_eq!(out, c);
        let out = f.apply_with_scene_luminance(c, 0.0);
        let s0 = discrimination_sigma(0.0) as f32;
        assert!(((out[0] - out[2]) - s0 * (c[0] - c[2])).abs() < 1e-6);
        assert!((luminance(out) - luminance(c)).abs() < 1e-6);
        // Daylight adaptation: unchanged.
        assert_eq!(ColourModel::Discrimination.prepare(100.0).apply(c), c);
    }

    #[test]
    fn none_and_both() {
        let c = [0.7f32, 0.1, 0.3];
        assert_eq!(ColourModel::None.prepare(1e-4).apply(c), c);
        let both = ColourModel::Both.prepare(0.01);
        let d = ColourModel::Discrimination.prepare(0.01);
        let s = ColourModel::ScotopicShift.prepare(0.01);
        let a = both.apply(c);
        let b = s.apply(d.apply(c));
        assert_eq!(a, b);
        assert_eq!(ColourModel::default(), ColourModel::ScotopicShift);
        assert!(ColourModel::Both.validate().is_ok());
    }

    #[test]
    fn matrix_reproduces_apply() {
        let colours = [
            [0.6f32, 0.3, 0.1],
            [0.0, 0.0, 1.0],
            [0.9, 0.9, 0.05],
            [0.02, 0.5, 0.7],
        ];
        for model in [
            ColourModel::ScotopicShift,
            ColourModel::Discrimination,
            ColourModel::Both,
            ColourModel::None,
        ] {
            for la in [1e-5, 0.01, 0.04, 0.5, 2.9, 100.0] {
                let f = model.prepare(la);
                let m = f.matrix();
                for c in colours {
                    let want = f.apply(c);
                    for i in 0..3 {
                        let got = m[i][0] * c[0] + m[i][1] * c[1] + m[i][2] * c[2];
                        assert!(
                            (got - want[i]).abs() < 1e-6,
                            "{model:?} {la}: {got} vs {want:?}"
                        );
                    }
                }
            }
        }
        // Night: every column is the tint times a luminance weight.
        let m = ColourModel::ScotopicShift.prepare(1e-6).matrix();
        assert!((m[2][1] / m[0][1] - SCOTOPIC_TINT[2] / SCOTOPIC_TINT[0]).abs() < 1e-3);
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
}
