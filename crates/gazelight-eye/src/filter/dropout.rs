//! Dropout filling: what the pupil is while the tracker has none.
//!
//! - a valid measurement is passed through ([`PupilOrigin::Measured`]);
//! - for `hold_s` after the last valid measurement (default 0.5 s — longer
//!   than ~95 % of blinks, which last 100–400 ms) the last good pupil is
//!   held ([`PupilOrigin::Held`]): a blink must not change the glare;
//! - after that the value eases, rate-limited at `ease_rate_mm_per_s`
//!   (default 0.5 mm/s, slower than real dilation so a long dropout drifts
//!   rather than jumps), towards the pupil the Watson–Yellott model
//!   ([`crate::pupil_model`]) predicts at the adaptation luminance the
//!   service feeds back ([`PupilOrigin::Model`]);
//! - before any measurement the model's pupil is used
//!   ([`PupilOrigin::Default`]).

use crate::setting::SettingError;
use serde::{Deserialize, Serialize};

use crate::state::PupilOrigin;

/// Dropout configuration.
#[derive(Clone, Copy, Debug, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields, default)]
pub struct DropoutConfig {
    /// How long the last good pupil is held (s). Default 0.5.
    pub hold_s: f64,
    /// How fast the value moves towards the model pupil afterwards (mm/s).
    /// Default 0.5.
    pub ease_rate_mm_per_s: f32,
}

impl Default for DropoutConfig {
    fn default() -> Self {
        Self {
            hold_s: 0.5,
            ease_rate_mm_per_s: 0.5,
        }
    }
}

impl DropoutConfig {
    /// Checks the values; names the field.
    pub fn validate(&self) -> Result<(), SettingError> {
        if !(self.hold_s.is_finite() && self.hold_s >= 0.0) {
            return Err(SettingError::new(
                "dropout.hold_s",
                format!("must be ≥ 0, got {}", self.hold_s),
            ));
        }
        if !(self.ease_rate_mm_per_s.is_finite() && self.ease_rate_mm_per_s > 0.0) {
            return Err(SettingError::new(
                "dropout.ease_rate_mm_per_s",
                format!("must be > 0, got {}", self.ease_rate_mm_per_s),
            ));
        }
        Ok(())
    }
}

/// One eye's dropout filler.
#[derive(Clone, Copy, Debug)]
pub struct DropoutFill {
    cfg: DropoutConfig,
    last_good_t: Option<f64>,
    value_mm: f32,
    t_prev: Option<f64>,
    origin: PupilOrigin,
}

impl DropoutFill {
    /// Starts at `initial_mm` (the model's pupil) with origin `Default`.
    pub fn new(cfg: DropoutConfig, initial_mm: f32) -> Self {
        Self {
            cfg,
            last_good_t: None,
            value_mm: initial_mm,
            t_prev: None,
            origin: PupilOrigin::Default,
        }
    }

    /// Feeds one time step: `measured_mm` is a valid, checked measurement or
    /// `None`; `model_mm` the model pupil now. Returns the value and origin.
    pub fn update(
        &mut self,
        t_secs: f64,
        measured_mm: Option<f32>,
        model_mm: f32,
    ) -> (f32, PupilOrigin) {
        let dt = self.t_prev.map_or(0.0, |t0| (t_secs - t0).max(0.0)) as f32;
        self.t_prev = Some(self.t_prev.map_or(t_secs, |t0| t0.max(t_secs)));
        match (measured_mm, self.last_good_t) {
            (Some(m), _) => {
                self.value_mm = m;
                self.last_good_t = Some(t_secs);
                self.origin = PupilOrigin::Measured;
            }
            (None, Some(tg)) if t_secs - tg <= self.cfg.hold_s => {
                self.origin = PupilOrigin::Held;
            }
            (None, last) => {
                let step = self.cfg.ease_rate_mm_per_s * dt;
                if model_mm.is_finite() {
                    self.value_mm += (model_mm - self.value_mm).clamp(-step, step);
                }
                self.origin = if last.is_some() {
                    PupilOrigin::Model
                } else {
                    PupilOrigin::Default
                };
            }
        }
        (self.value_mm, self.origin)
    }

    /// Time of the last valid measurement.
    pub fn last_good_t_secs(&self) -> Option<f64> {
        self.last_good_t
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn holds_then_eases_towards_the_model() {
        let mut d = DropoutFill::new(DropoutConfig::default(), 4.0);
        assert_eq!(d.update(0.0, None, 4.0), (4.0, PupilOrigin::Default));
        assert_eq!(d.update(0.1, Some(6.0), 3.0), (6.0, PupilOrigin::Measured));
        assert_eq!(d.update(0.5, None, 3.0), (6.0, PupilOrigin::Held));
        assert_eq!(d.update(0.6, None, 3.0), (6.0, PupilOrigin::Held));
        // 0.1 s beyond the hold: eased by 0.5 mm/s · 0.1 s.
        let (v, o) = d.update(0.7, None, 3.0);
        assert_eq!(o, PupilOrigin::Model);
        assert!((v - 5.95).abs() < 1e-5, "{v}");
        // Long enough: reaches the model and stays.
        let (v, _) = d.update(20.0, None, 3.0);
        assert!((v - 3.0).abs() < 1e-6);
        assert_eq!(d.update(20.1, Some(3.2), 3.0).1, PupilOrigin::Measured);
    }
}
