//! Light-adapted pupil diameter from luminance: the unified formula of
//! Watson & Yellott (2012), "A unified formula for light-adapted pupil
//! size", J. Vis. 12(10):12.
//!
//! The model combines Stanley & Davies' (1995) dependence on the corneal
//! flux density (luminance × field area) with an age term and a monocular
//! attenuation:
//!
//! ```text
//! F     = L · a · M(e)                       L cd/m², a field area deg², M(1)=0.1, M(2)=1
//! D_SD  = 7.75 − 5.75 · (F/846)^0.41 / ((F/846)^0.41 + 2)
//! D_U   = D_SD + (y − y0) · (0.02132 − 0.009562 · D_SD),  y0 = 28.58 years
//! ```
//!
//! The filter chain uses it as the dropout fallback: when the tracker has
//! no valid pupil for longer than the hold time, the pupil eases towards
//! [`PupilModel::pupil_mm`] at the current adaptation luminance, which the
//! service feeds back from the vision pipeline.

use crate::setting::SettingError;
use serde::{Deserialize, Serialize};

/// Stanley & Davies' flux normalisation constant, cd·deg²/m² (Stanley & Davies 1995, as W&Y 2012 restate it).
const SD_FLUX_NORM: f64 = 846.0;
/// Exponent of the flux term (Stanley & Davies 1995, as W&Y 2012 restate it).
const SD_EXPONENT: f64 = 0.41;
/// Largest (dark) diameter of the Stanley–Davies formula, mm (Stanley & Davies 1995, as W&Y 2012 restate it).
const SD_D_MAX_MM: f64 = 7.75;
/// Span of the Stanley–Davies formula, mm (Stanley & Davies 1995, as W&Y 2012 restate it).
const SD_SPAN_MM: f64 = 5.75;
/// Reference age of the unified formula, years (W&Y 2012 eq. 21).
pub const REFERENCE_AGE_YEARS: f64 = 28.58;
/// Age slope intercept, mm/year (W&Y 2012 eq. 21).
const AGE_SLOPE_A: f64 = 0.02132;
/// Age slope dependence on D_SD, 1/year (W&Y 2012 eq. 21).
const AGE_SLOPE_B: f64 = 0.009562;
/// Monocular attenuation of the effective flux M(1) (W&Y 2012, effective corneal flux density).
pub const MONOCULAR_FACTOR: f64 = 0.1;

/// Parameters of the unified formula.
#[derive(Clone, Copy, Debug, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields, default)]
pub struct PupilModel {
    /// Adapting field area in deg² (W&Y's `a`). Default: a 60° diameter
    /// field (π·30² ≈ 2827 deg²), about what an HMD fills.
    pub field_area_deg2: f64,
    /// Observer age in years (W&Y's `y`; the formula is fitted for 20–83).
    /// Default: the reference age 28.58, where the age term vanishes.
    pub age_years: f64,
    /// Whether both eyes see the field (W&Y's `e` = 2) or one (`e` = 1).
    /// Default: binocular.
    pub binocular: bool,
}

impl Default for PupilModel {
    fn default() -> Self {
        Self {
            field_area_deg2: std::f64::consts::PI * 30.0 * 30.0,
            age_years: REFERENCE_AGE_YEARS,
            binocular: true,
        }
    }
}

/// Stanley & Davies (1995) diameter in mm for a corneal flux density
/// `flux` = L·a·M(e) (Stanley & Davies 1995, as W&Y 2012 restate it).
pub fn stanley_davies_mm(flux: f64) -> f64 {
    let f = (flux.max(0.0) / SD_FLUX_NORM).powf(SD_EXPONENT);
    SD_D_MAX_MM - SD_SPAN_MM * f / (f + 2.0)
}

/// The unified formula (W&Y 2012 eq. 21): pupil diameter in mm.
pub fn unified_mm(
    luminance_cd_m2: f64,
    field_area_deg2: f64,
    age_years: f64,
    binocular: bool,
) -> f64 {
    let m = if binocular { 1.0 } else { MONOCULAR_FACTOR };
    unified_from_flux_mm(
        luminance_cd_m2.max(0.0) * field_area_deg2.max(0.0) * m,
        age_years,
    )
}

/// The unified formula (W&Y 2012 eq. 21) from an effective corneal flux
/// density `flux` = L·a·M(e) in cd·deg²/m² that the caller has already
/// formed (e.g. from two eyes seeing different luminances).
pub fn unified_from_flux_mm(flux: f64, age_years: f64) -> f64 {
    let d_sd = stanley_davies_mm(flux);
    d_sd + (age_years - REFERENCE_AGE_YEARS) * (AGE_SLOPE_A - AGE_SLOPE_B * d_sd)
}

impl PupilModel {
    /// Predicted pupil diameter in mm at adaptation luminance
    /// `luminance_cd_m2` (negative or NaN luminance counts as 0). Always
    /// finite and positive.
    pub fn pupil_mm(&self, luminance_cd_m2: f64) -> f32 {
        let l = if luminance_cd_m2.is_finite() {
            luminance_cd_m2.max(0.0)
        } else {
            0.0
        };
        let d = unified_mm(l, self.field_area_deg2, self.age_years, self.binocular);
        // Ages far outside the fitted range could push it out of anatomy.
        d.clamp(
            crate::pupil_response::PUPIL_MIN_MM,
            crate::pupil_response::PUPIL_MAX_MM,
        ) as f32
    }

    /// Checks the parameters; names the offending field.
    pub fn validate(&self) -> Result<(), SettingError> {
        if !(self.field_area_deg2.is_finite() && self.field_area_deg2 > 0.0) {
            return Err(SettingError::new(
                "field_area_deg2",
                format!("must be > 0, got {}", self.field_area_deg2),
            ));
        }
        if !(1.0..=100.0).contains(&self.age_years) {
            return Err(SettingError::new(
                "age_years",
                format!("must be within 1..=100, got {}", self.age_years),
            ));
        }
        Ok(())
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    /// Watson & Yellott's closed form for ages 20–83 (their appendix, eq.
    /// 27), an independent algebraic rearrangement of eq. 21 with the
    /// constants multiplied out; f = F^0.41.
    fn appendix_closed_form(flux: f64, age: f64) -> f64 {
        let f = flux.powf(0.41);
        (18.5172 + 0.122165 * f - 0.105569 * age + 0.000138645 * f * age) / (2.0 + 0.0630635 * f)
    }

    #[test]
    fn matches_the_papers_closed_form() {
        for &l in &[1e-4, 1e-2, 1.0, 10.0, 100.0, 1e4] {
            for &age in &[20.0, 28.58, 45.0, 83.0] {
                let a = 900.0 * std::f64::consts::PI;
                let ours = unified_mm(l, a, age, true);
                let theirs = appendix_closed_form(l * a, age);
                assert!(
                    (ours - theirs).abs() < 2e-3,
                    "L={l} age={age}: {ours} vs {theirs}"
                );
            }
        }
    }

    #[test]
    fn limits_and_half_point_of_stanley_davies() {
        assert!((stanley_davies_mm(0.0) - 7.75).abs() < 1e-12);
        // (F/846)^0.41 = 2 → D = 7.75 − 5.75/2.
        let flux = 846.0 * 2f64.powf(1.0 / 0.41);
        assert!((stanley_davies_mm(flux) - (7.75 - 2.875)).abs() < 1e-9);
        assert!(stanley_davies_mm(1e12) > 2.0 - 1e-6);
    }

    #[test]
    fn monocular_viewing_gives_a_larger_pupil_and_older_eyes_smaller_dark_pupils() {
        let a = 2827.0;
        assert!(unified_mm(10.0, a, 30.0, false) > unified_mm(10.0, a, 30.0, true));
        assert!(unified_mm(0.001, a, 70.0, true) < unified_mm(0.001, a, 25.0, true));
        // Monocular = binocular at a tenth of the luminance (M(1) = 0.1).
        let d1 = unified_mm(50.0, a, 40.0, false);
        let d2 = unified_mm(5.0, a, 40.0, true);
        assert!((d1 - d2).abs() < 1e-12);
    }

    #[test]
    fn garbage_luminance_still_gives_a_pupil() {
        let m = PupilModel::default();
        for l in [f64::NAN, -1.0, f64::INFINITY, 0.0] {
            let d = m.pupil_mm(l);
            assert!(d.is_finite() && d > 0.0);
        }
        assert!(m.validate().is_ok());
        let bad = PupilModel {
            field_area_deg2: 0.0,
            ..m
        };
        assert!(
            bad.validate()
                .unwrap_err()
                .to_string()
                .contains("field_area_deg2")
        );
    }
}
