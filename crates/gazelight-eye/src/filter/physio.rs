//! Physiological plausibility of pupil diameters (in mm, after calibration)
//! and the final slew-rate limiter that makes a too-fast change impossible.
//!
//! Bounds, documented:
//!
//! - **Range 1.5–9 mm.** The light-adapted pupil of adults spans about
//!   2 mm (bright) to 8 mm (dark) (Watson & Yellott 2012, Fig. 1 data sets);
//!   we allow a margin on both sides for pharmacological miosis/mydriasis
//!   and calibration error. Anything outside is a detector error.
//! - **Rate 6 mm/s.** The fastest pupil movement is the primary constriction
//!   of the light reflex: Reeves' cinematographic measurements ("The
//!   reaction time of the normal pupil") found 5.48 mm/s; Ellis (1981, Br. J.
//!   Ophthalmol. 65:754) shows the maximum constriction rate rising with
//!   stimulus intensity into that range. Dilation is slower. We use
//!   6 mm/s for both directions. The real piprkit flash responses (≈ 6.2 →
//!   3.5 mm) stay below 4 mm/s over any 50 ms window; the blink artefacts in
//!   the same recording exceed 30 mm/s.
//!
//! The range bounds which millimetre samples count as pupils (the
//! measured pupil's lost samples, [`super::clean`]) and the model aperture.
//! The rate bounds only the aperture: [`SlewLimiter`] is its last stage, so
//! whatever the stages before it do (hold, model easing, a new eye after a
//! dropout) it never changes faster than `max_rate`. The measured pupil is
//! never rate-limited: a rate gate that rejected samples changing faster
//! than `jump_tolerance_mm + max_rate · Δt` locked onto an eyelid-occluded
//! sample after a blink and rejected the tracker's real pupils as jumps
//! (issue 45); outliers are the dilation-speed filter's now.

use crate::setting::SettingError;
use serde::{Deserialize, Serialize};

/// The physiological pupil range, mm `(min, max)` (the bounds in the
/// module docs: 2–8 mm, 001 §5, with margins): the filter's default
/// plausibility bounds, and the pupils every glare kernel is built for
/// (`gazelight_vision::kernel_policy`). Defined here only.
pub const PUPIL_MM_RANGE: (f32, f32) = (1.5, 9.0);
/// Fastest plausible pupil change, mm/s (above Reeves' 5.48 mm/s primary
/// constriction of the light reflex).
pub const DEFAULT_MAX_RATE_MM_PER_S: f32 = 6.0;
/// The old rate gate's noise tolerance, mm (accepted, unused).
pub const DEFAULT_JUMP_TOLERANCE_MM: f32 = 0.5;

/// Configuration of the physiological checks.
#[derive(Clone, Copy, Debug, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields, default)]
pub struct PhysioConfig {
    /// Smallest plausible pupil (mm), default 1.5.
    pub min_pupil_mm: f32,
    /// Largest plausible pupil (mm), default 9.
    pub max_pupil_mm: f32,
    /// Fastest plausible change (mm/s), default 6: the model aperture's
    /// slew limit.
    pub max_rate_mm_per_s: f32,
    /// Accepted for old configurations (the rate gate it tuned is gone:
    /// outliers are the dilation-speed filter's); default 0.5.
    pub jump_tolerance_mm: f32,
}

impl Default for PhysioConfig {
    fn default() -> Self {
        Self {
            min_pupil_mm: PUPIL_MM_RANGE.0,
            max_pupil_mm: PUPIL_MM_RANGE.1,
            max_rate_mm_per_s: DEFAULT_MAX_RATE_MM_PER_S,
            jump_tolerance_mm: DEFAULT_JUMP_TOLERANCE_MM,
        }
    }
}

impl PhysioConfig {
    /// Checks the bounds are ordered and positive; names the field.
    pub fn validate(&self) -> Result<(), SettingError> {
        if !(self.min_pupil_mm.is_finite() && self.min_pupil_mm > 0.0) {
            return Err(SettingError::new(
                "physio.min_pupil_mm",
                format!("must be > 0, got {}", self.min_pupil_mm),
            ));
        }
        if !(self.max_pupil_mm.is_finite() && self.max_pupil_mm > self.min_pupil_mm) {
            return Err(SettingError::new(
                "physio.max_pupil_mm",
                format!(
                    "must be > min_pupil_mm ({}), got {}",
                    self.min_pupil_mm, self.max_pupil_mm
                ),
            ));
        }
        if !(self.max_rate_mm_per_s.is_finite() && self.max_rate_mm_per_s > 0.0) {
            return Err(SettingError::new(
                "physio.max_rate_mm_per_s",
                format!("must be > 0, got {}", self.max_rate_mm_per_s),
            ));
        }
        if !(self.jump_tolerance_mm.is_finite() && self.jump_tolerance_mm >= 0.0) {
            return Err(SettingError::new(
                "physio.jump_tolerance_mm",
                format!("must be ≥ 0, got {}", self.jump_tolerance_mm),
            ));
        }
        Ok(())
    }
}

/// Limits how fast a value may change: at most `max_rate` per second of
/// (monotone) time. It starts at an initial value; the first step only
/// sets its clock, so even the first target cannot make it jump.
#[derive(Clone, Copy, Debug)]
pub struct SlewLimiter {
    max_rate: f32,
    value: f32,
    t: Option<f64>,
}

impl SlewLimiter {
    /// Starts at `initial` (must be finite) with no clock yet.
    pub fn new(max_rate: f32, initial: f32) -> Self {
        Self {
            max_rate,
            value: initial,
            t: None,
        }
    }

    /// Moves towards `target` at time `t_secs`; returns the limited value.
    /// A non-finite target holds the current value; time going backwards
    /// (or NaN) counts as no time passing.
    pub fn step(&mut self, t_secs: f64, target: f32) -> f32 {
        let t0 = match self.t {
            Some(t0) => t0,
            None if t_secs.is_finite() => {
                self.t = Some(t_secs);
                t_secs
            }
            None => return self.value,
        };
        let t = if t_secs.is_finite() {
            t_secs.max(t0)
        } else {
            t0
        };
        let max_step = self.max_rate * (t - t0) as f32;
        if target.is_finite() {
            self.value += (target - self.value).clamp(-max_step, max_step);
        }
        self.t = Some(t);
        self.value
    }

    /// The current value.
    pub fn value(&self) -> f32 {
        self.value
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn slew_never_exceeds_its_rate_even_backwards_in_time() {
        let mut s = SlewLimiter::new(6.0, 4.0);
        assert_eq!(s.step(0.0, 8.0), 4.0, "the first step only sets the clock");
        assert!((s.step(0.1, 8.0) - 4.6).abs() < 1e-6);
        assert!(
            (s.step(0.05, 0.0) - 4.6).abs() < 1e-6,
            "time went backwards"
        );
        assert!((s.step(0.2, 0.0) - 4.0).abs() < 1e-5);
        assert!((s.step(0.3, f32::NAN) - 4.0).abs() < 1e-5);
        assert!((s.step(f64::NAN, 9.0) - 4.0).abs() < 1e-5);
    }
}
