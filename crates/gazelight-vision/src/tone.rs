//! Tone reproduction: scene linear RGB in cd/m² → display-relative linear
//! RGB (1.0 = the display's peak; values above 1 are clamped later by the
//! pipeline).
//!
//! Per frame, [`ToneModel::prepare`] computes the operator's scalars in
//! `f64` from the adaptation luminance; per pixel, [`ToneFrame::apply`]
//! applies them in `f32`.
//!
//! * [`ToneModel::WardFerwerda`] (default; 000 eq 9–10, after Ward 1994 and
//!   Ferwerda et al. 1996). Display luminance `L_d` from world luminance
//!   `L_w` (cd/m²):
//!   - adapted or dark-adapting (000 eq 9):
//!     `L_d = t_p(L_da)/t_m(L_wa) · L_w`;
//!   - light-adapting towards `L̄ > L_wa` (000 eq 10):
//!     `L_d = t_p(L_da)/t*(L_wa, L̄) · (L_w − L̄) + t_p(L_da)/t_m(L̄) · L̄`,
//!     which keeps the display luminance of `L̄` constant while the
//!     overshoot threshold `t*` (000 eq 8) dims contrast, and adds a
//!     constant (grey) offset to the image.
//!
//!   The display observer's adaptation is half the display peak,
//!   `L_da = peak/2`, with the photopic `t_p` (000 §3.3: half the headset's
//!   luminance, set at 100 cd/m²). RGB is scaled by the same factor as
//!   luminance; eq 10's offset is added equally to R, G and B (a grey of
//!   that luminance, since the luminance weights sum to 1). Output is
//!   `L_d / peak`.
//! * [`ToneModel::NakaRushton`] (003 eq 4–5, after Mantiuk & Markowski and
//!   Schlick): `L_LDR = L/(L + s)` with `s` the adaptation luminance and
//!   `L` the pixel luminance with 003 §3.5's weights (0.212656, 0.715158,
//!   0.072186); colour `c_new = (c/L)^sat · L_LDR` per channel with
//!   `sat = 1.2` (003 §3.5). A grey pixel at `L = s` maps to 0.5.
//! * [`ToneModel::GazeExposure`] (004 §3.1–3.2): a window from 5 stops below
//!   to 3 stops above the adaptation luminance `T`; per channel
//!   `x = clamp((c − T·2^−5)/(T·2^3 − T·2^−5), 0, 1)` and `v = x^γ`, with γ
//!   chosen so that a grey pixel at `T` displays at `target_display`
//!   (0.5, i.e. 128/255 in 004): `γ = ln(target_display)/ln(x_T)`. 004
//!   prints `γ = log_0.5(target)`, which would put the target at
//!   `x_T^(log_0.5 x_T)`, not at 0.5; the intent stated beside it is
//!   followed. `v` is 004's display value (gamma-encoded, 0–255 scaled to
//!   0–1); it is decoded with the sRGB transfer function so that the
//!   pipeline's sRGB display encoding reproduces it. 004 §3.3's
//!   luminance-dependent target brightness needs a three-point fit whose
//!   values the seed does not give, so it is not implemented: the target
//!   brightness is the fixed `target_display`.

use serde::{Deserialize, Serialize};

use crate::VisionError;
use crate::tvi;

/// Lowest adaptation luminance the operators use, cd/m²
/// ([`crate::temporal::MIN_LUMINANCE_CD_M2`]).
const MIN_ADAPTATION_CD_M2: f64 = crate::temporal::MIN_LUMINANCE_CD_M2;

/// Luminance weights of the Naka–Rushton operator (003 §3.5).
// 003 §3.5: L = 0.212656 R + 0.715158 G + 0.072186 B
pub const NAKA_RUSHTON_WEIGHTS: [f32; 3] = [0.212_656, 0.715_158, 0.072_186];

/// Tone reproduction operator; see the module docs for the formulas.
#[derive(Clone, Copy, Debug, PartialEq, Serialize, Deserialize)]
#[serde(tag = "model", rename_all = "snake_case", deny_unknown_fields)]
pub enum ToneModel {
    /// Ward/Ferwerda threshold-ratio operator (000 eq 9–10).
    WardFerwerda {
        /// The display's peak luminance, cd/m².
        display_peak_cd_m2: f64,
    },
    /// Naka–Rushton compression with colour (003 eq 4–5).
    NakaRushton {
        /// Colour exponent of 003 eq 5.
        saturation: f64,
    },
    /// Gaze exposure window with gamma (004 §3.1–3.2).
    GazeExposure {
        /// Stops below the adaptation luminance mapped to black.
        stops_below: f64,
        /// Stops above the adaptation luminance mapped to white.
        stops_above: f64,
        /// Display value (gamma-encoded, 0–1) of the adaptation luminance.
        target_display: f64,
    },
}

impl Default for ToneModel {
    fn default() -> Self {
        Self::WardFerwerda {
            display_peak_cd_m2: 100.0, // 000 §3.3: headset luminance 100 cd/m²
        }
    }
}

impl ToneModel {
    /// Naka–Rushton with 003's saturation.
    pub fn naka_rushton() -> Self {
        Self::NakaRushton {
            saturation: 1.2, // 003 §3.5: colour desaturation factor
        }
    }

    /// Gaze exposure window with 004's parameters.
    pub fn gaze_exposure() -> Self {
        Self::GazeExposure {
            stops_below: 5.0,    // 004 §3.1: 5 f-stops below the target
            stops_above: 3.0,    // 004 §3.1: 3 f-stops above
            target_display: 0.5, // 004 §3.2: target at 128 of 255
        }
    }

    /// Checks the parameters.
    pub fn validate(&self) -> Result<(), VisionError> {
        match *self {
            Self::WardFerwerda { display_peak_cd_m2 } => {
                if !(display_peak_cd_m2.is_finite() && display_peak_cd_m2 > 0.0) {
                    return Err(VisionError::invalid(
                        "tone.display_peak_cd_m2",
                        display_peak_cd_m2,
                        "a finite luminance > 0 cd/m²",
                    ));
                }
            }
            Self::NakaRushton { saturation } => {
                if !(saturation.is_finite() && saturation > 0.0 && saturation <= 4.0) {
                    return Err(VisionError::invalid(
                        "tone.saturation",
                        saturation,
                        "0 < saturation ≤ 4",
                    ));
                }
            }
            Self::GazeExposure {
                stops_below,
                stops_above,
                target_display,
            } => {
                if !(stops_below.is_finite() && stops_below > 0.0 && stops_below <= 30.0) {
                    return Err(VisionError::invalid(
                        "tone.stops_below",
                        stops_below,
                        "0 < stops_below ≤ 30",
                    ));
                }
                if !(stops_above.is_finite() && stops_above > 0.0 && stops_above <= 30.0) {
                    return Err(VisionError::invalid(
                        "tone.stops_above",
                        stops_above,
                        "0 < stops_above ≤ 30",
                    ));
                }
                if !(target_display > 0.0 && target_display < 1.0) {
                    return Err(VisionError::invalid(
                        "tone.target_display",
                        target_display,
                        "0 < target_display < 1",
                    ));
                }
            }
        }
        Ok(())
    }

    /// Per-frame scalars for an eye adapted to `adaptation_cd_m2` (no
    /// light-adaptation overshoot; 000 eq 9 for Ward/Ferwerda).
    pub fn prepare(&self, adaptation_cd_m2: f64) -> ToneFrame {
        self.prepare_adapting(adaptation_cd_m2, adaptation_cd_m2)
    }

    /// Per-frame scalars for an eye at `adaptation_cd_m2` (`L_wa`) that is
    /// light-adapting towards `light_target_cd_m2` (`L̄`, see
    /// [`crate::temporal::AdaptationState::light_target_cd_m2`]). When
    /// `L̄ > L_wa`, Ward/Ferwerda uses 000 eq 10 with `t*` (eq 8); the other
    /// operators ignore `L̄`.
    pub fn prepare_adapting(&self, adaptation_cd_m2: f64, light_target_cd_m2: f64) -> ToneFrame {
        let la = if adaptation_cd_m2.is_finite() {
            adaptation_cd_m2.max(MIN_ADAPTATION_CD_M2)
        } else {
            MIN_ADAPTATION_CD_M2
        };
        let op = match *self {
            Self::WardFerwerda { display_peak_cd_m2 } => {
                let (scale, offset) = ward_ferwerda(la, light_target_cd_m2, display_peak_cd_m2);
                Op::Linear {
                    scale: scale as f32,
                    offset: offset as f32,
                }
            }
            Self::NakaRushton { saturation } => Op::NakaRushton {
                s: la as f32,
                saturation: saturation as f32,
            },
            Self::GazeExposure {
                stops_below,
                stops_above,
                target_display,
            } => {
                let lo = la * 2f64.powf(-stops_below);
                let hi = la * 2f64.powf(stops_above);
                // The target's position in the window, independent of la.
                let x_t = (la - lo) / (hi - lo);
                let gamma = target_display.ln() / x_t.ln();
                Op::Window {
                    lo: lo as f32,
                    inv_range: (1.0 / (hi - lo)) as f32,
                    gamma: gamma as f32,
                }
            }
        };
        ToneFrame { op }
    }
}

/// `(scale, offset)` in display-relative units such that
/// `L_d/peak = scale·L_w + offset` (000 eq 9 / 10).
fn ward_ferwerda(l_wa: f64, l_bar: f64, peak_cd_m2: f64) -> (f64, f64) {
    // 000 §3.3: display observer adapted to half the display luminance
    let l_da = 0.5 * peak_cd_m2;
    let tp_da = tvi::t_p(l_da);
    if l_bar.is_finite() && l_bar > l_wa {
        // 000 eq 10
        let a = tp_da / tvi::t_star(l_wa, l_bar);
        let c = tp_da / tvi::t_m(l_bar);
        (a / peak_cd_m2, (c - a) * l_bar / peak_cd_m2)
    } else {
        // 000 eq 9 with t(L_wa) = t_m(L_wa)
        (tp_da / tvi::t_m(l_wa) / peak_cd_m2, 0.0)
    }
}

/// The per-pixel operator of a prepared [`ToneFrame`], for callers that
/// specialise their pixel loop on it (the frame pipeline matches once per
/// frame, not once per pixel).
#[derive(Clone, Copy, Debug, PartialEq)]
pub(crate) enum Op {
    /// `scale·c + offset` per channel (Ward/Ferwerda, 000 eq 9–10).
    Linear { scale: f32, offset: f32 },
    /// 003 eq 4–5.
    NakaRushton { s: f32, saturation: f32 },
    /// 004 §3.1–3.2, decoded from sRGB.
    Window { lo: f32, inv_range: f32, gamma: f32 },
}

/// The per-frame scalars of a tone operator; see [`ToneModel::prepare`].
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct ToneFrame {
    op: Op,
}

impl ToneFrame {
    /// Maps scene linear RGB (cd/m²) to display-relative linear RGB.
    /// Negative and NaN components are treated as 0.
    #[inline]
    pub fn apply(&self, rgb_cd_m2: [f32; 3]) -> [f32; 3] {
        let c = [
            clean(rgb_cd_m2[0]),
            clean(rgb_cd_m2[1]),
            clean(rgb_cd_m2[2]),
        ];
        match self.op {
            Op::Linear { scale, offset } => [
                c[0] * scale + offset,
                c[1] * scale + offset,
                c[2] * scale + offset,
            ],
            Op::NakaRushton { s, saturation } => naka_rushton(c, s, saturation),
            Op::Window {
                lo,
                inv_range,
                gamma,
            } => window(c, lo, inv_range, gamma),
        }
    }

    /// If the operator is linear per channel (`scale·c + offset`, the
    /// Ward/Ferwerda operator), its `(scale, offset)`.
    pub fn linear(&self) -> Option<(f32, f32)> {
        match self.op {
            Op::Linear { scale, offset } => Some((scale, offset)),
            _ => None,
        }
    }

    /// The operator, for specialised pixel loops.
    pub(crate) fn op(&self) -> Op {
        self.op
    }
}

/// 003 eq 4–5 on a cleaned pixel (no negative or NaN components).
#[inline(always)]
pub(crate) fn naka_rushton(c: [f32; 3], s: f32, saturation: f32) -> [f32; 3] {
    let w = NAKA_RUSHTON_WEIGHTS;
    let l = w[0] * c[0] + w[1] * c[1] + w[2] * c[2];
    if l <= 0.0 {
        return [0.0; 3];
    }
    // 003 eq 4
    let l_ldr = l / (l + s);
    // 003 eq 5
    let inv = 1.0 / l;
    [
        (c[0] * inv).powf(saturation) * l_ldr,
        (c[1] * inv).powf(saturation) * l_ldr,
        (c[2] * inv).powf(saturation) * l_ldr,
    ]
}

/// 004 §3.1–3.2 on a cleaned pixel, decoded from sRGB.
#[inline(always)]
pub(crate) fn window(c: [f32; 3], lo: f32, inv_range: f32, gamma: f32) -> [f32; 3] {
    let f = |v: f32| srgb_to_linear(((v - lo) * inv_range).clamp(0.0, 1.0).powf(gamma));
    [f(c[0]), f(c[1]), f(c[2])]
}

/// Negative, NaN and infinite components become 0 (branch-free: both
/// comparisons are false for NaN).
#[inline(always)]
pub(crate) fn clean(v: f32) -> f32 {
    if v > 0.0 && v < f32::INFINITY { v } else { 0.0 }
}

/// The sRGB electro-optical transfer function (IEC 61966-2-1): encoded
/// value in [0, 1] → linear light.
#[inline]
pub fn srgb_to_linear(v: f32) -> f32 {
    if v <= 0.04045 {
        v / 12.92
    } else {
        ((v + 0.055) / 1.055).powf(2.4)
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    fn grey(l: f32) -> [f32; 3] {
        [l, l, l]
    }

    fn all() -> [ToneModel; 3] {
        [
            ToneModel::default(),
            ToneModel::naka_rushton(),
            ToneModel::gaze_exposure(),
        ]
    }

    #[test]
    fn naka_rushton_half_at_adaptation() {
        let m = ToneModel::naka_rushton();
        for s in [0.001, 0.04, 1.0, 250.0, 1e4] {
            let f = m.prepare(s);
            let out = f.apply(grey(s as f32));
            for c in out {
                assert!((c - 0.5).abs() < 1e-5, "s {s}: {out:?}");
            }
            // 003 eq 4 at L = 3s: 0.75
            let out = f.apply(grey(3.0 * s as f32));
            assert!((out[1] - 0.75).abs() < 1e-5);
        }
    }

    #[test]
    fn naka_rushton_colour_follows_003_eq5() {
        let f = ToneModel::naka_rushton().prepare(2.0);
        let c = [3.0f32, 1.0, 0.5];
        let w = NAKA_RUSHTON_WEIGHTS;
        let l = w[0] * c[0] + w[1] * c[1] + w[2] * c[2];
        let ldr = l / (l + 2.0);
        let out = f.apply(c);
        for i in 0..3 {
            let e = (c[i] / l).powf(1.2) * ldr;
            assert!((out[i] - e).abs() < 1e-6, "{out:?}");
        }
        // Saturation 1.2 > 1: the ratio of channels grows.
        assert!(out[0] / out[2] > c[0] / c[2]);
    }

    #[test]
    fn ward_ferwerda_matches_hand_computation() {
        let peak = 100.0;
        let m = ToneModel::WardFerwerda {
            display_peak_cd_m2: peak,
        };
        // t_p(50): log 50 = 1.69897 < 1.9 → (0.249·1.69897 + 0.65)^2.7 − 0.72.
        let log_tp_da = (0.249 * 50f64.log10() + 0.65).powf(2.7) - 0.72;
        // Night: L_wa = 0.01 → rods only (k = 0), log t_s(−2) = 0.79^2.18 − 2.86.
        let log_ts = (0.405f64 * -2.0 + 1.6).powf(2.18) - 2.86;
        let scale = 10f64.powf(log_tp_da - log_ts) / peak;
        let out = m.prepare(0.01).apply(grey(0.01));
        assert!(
            (f64::from(out[0]) / (scale * 0.01) - 1.0).abs() < 1e-5,
            "{out:?} vs {}",
            scale * 0.01
        );
        // 0.01 cd/m² at night → 5.7 % of the display peak.
        assert!((scale * 0.01 - 0.0565).abs() < 5e-4, "{}", scale * 0.01);
        // Day: L_wa = 1000 → photopic Weber branch, t_m = 10^(3 − 1.255).
        let scale = 10f64.powf(log_tp_da - (3.0 - 1.255)) / peak;
        let out = m.prepare(1000.0).apply(grey(1000.0));
        assert!((f64::from(out[1]) / (scale * 1000.0) - 1.0).abs() < 1e-5);
        // Mesopic: against the tvi functions.
        let scale = tvi::t_p(50.0) / tvi::t_m(0.3) / peak;
        let out = m.prepare(0.3).apply([0.3, 0.1, 0.7]);
        for (o, c) in out.iter().zip([0.3, 0.1, 0.7]) {
            assert!((f64::from(*o) / (scale * c) - 1.0).abs() < 1e-5);
        }
    }

    #[test]
    fn ward_ferwerda_light_adaptation_offset() {
        // 000 eq 10: the display luminance of L̄ stays that of the adapted
        // state, whatever L_wa; contrast is scaled by t_p(L_da)/t*.
        let m = ToneModel::default();
        let (l_wa, l_bar) = (0.05, 80.0);
        let adapting = m.prepare_adapting(l_wa, l_bar);
        let adapted = m.prepare(l_bar);
        let a = adapting.apply(grey(l_bar as f32))[0];
        let b = adapted.apply(grey(l_bar as f32))[0];
        assert!((a / b - 1.0).abs() < 1e-5, "{a} vs {b}");
        let slope = (adapting.apply(grey(100.0))[0] - adapting.apply(grey(60.0))[0]) / 40.0;
        let expected = tvi::t_p(50.0) / tvi::t_star(l_wa, l_bar) / 100.0;
        assert!(
            (f64::from(slope) / expected - 1.0).abs() < 1e-3,
            "{slope} vs {expected}"
        );
        // Black maps to the positive grey offset.
        let black = adapting.apply([0.0; 3]);
        assert!(black[0] > 0.0 && black[0] == black[2]);
        // Dark adaptation (L̄ below L_wa) is plain eq 9.
        assert_eq!(m.prepare_adapting(10.0, 1.0), m.prepare(10.0));
    }

    #[test]
    fn gaze_exposure_window_and_gamma() {
        let m = ToneModel::gaze_exposure();
        for t in [0.01f32, 1.0, 8000.0] {
            let f = m.prepare(f64::from(t));
            // The target displays at code value 0.5.
            let out = f.apply(grey(t));
            assert!((out[0] - srgb_to_linear(0.5)).abs() < 1e-5, "{out:?}");
            // 5 stops below is black, 3 stops above is white.
            assert_eq!(f.apply(grey(t / 40.0)), [0.0; 3]);
            assert!((f.apply(grey(t * 8.0))[0] - 1.0).abs() < 1e-6);
            assert!((f.apply(grey(t * 100.0))[0] - 1.0).abs() < 1e-6);
        }
        // γ = ln 0.5 / ln((1 − 2^−5)/(2^3 − 2^−5)) = 0.3289.
        let x_t = (1.0f64 - 1.0 / 32.0) / (8.0 - 1.0 / 32.0);
        let gamma = 0.5f64.ln() / x_t.ln();
        assert!((gamma - 0.3289).abs() < 1e-4, "{gamma}");
        let f = m.prepare(1.0);
        let c = 2.0f32;
        let x = (f64::from(c) - 1.0 / 32.0) / (8.0 - 1.0 / 32.0);
        let expected = srgb_to_linear(x.powf(gamma) as f32);
        assert!((f.apply(grey(c))[0] - expected).abs() < 1e-5);
    }

    #[test]
    fn monotonic_in_luminance() {
        for m in all() {
            m.validate().unwrap();
            for la in [0.001, 0.1, 10.0, 1000.0] {
                let f = m.prepare(la);
                let mut prev = -1.0f32;
                for i in 0..=400 {
                    let l = (la * 10f64.powf(-4.0 + 8.0 * f64::from(i) / 400.0)) as f32;
                    let y = crate::image::luminance(f.apply(grey(l)));
                    assert!(y >= prev, "{m:?} la {la}: not monotonic at {l}");
                    prev = y;
                }
                assert!(prev > 0.0);
            }
        }
    }

    #[test]
    fn bad_pixels_and_parameters() {
        for m in all() {
            let f = m.prepare(1.0);
            let out = f.apply([f32::NAN, -3.0, f32::INFINITY]);
            assert_eq!(out, f.apply([0.0; 3]));
            assert!(out.iter().all(|v| v.is_finite()));
            // Non-finite adaptation does not poison the frame.
            let out = m.prepare(f64::NAN).apply(grey(1.0));
            assert!(out.iter().all(|v| v.is_finite()));
        }
        let e = ToneModel::WardFerwerda {
            display_peak_cd_m2: -1.0,
        }
        .validate()
        .unwrap_err();
        assert!(e.to_string().contains("tone.display_peak_cd_m2"));
        assert!(
            ToneModel::NakaRushton {
                saturation: f64::NAN
            }
            .validate()
            .is_err()
        );
        assert!(
            ToneModel::GazeExposure {
                stops_below: 5.0,
                stops_above: 3.0,
                target_display: 1.0
            }
            .validate()
            .is_err()
        );
    }
}
