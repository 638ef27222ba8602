//! Pairing of the two eyes' unsynchronised samples and binocular fusion.
//!
//! The eye cameras of Pupil Core run free: the two eyes' samples arrive
//! interleaved with independent timestamps, and one eye can stop reporting
//! altogether. The chain keeps one channel per eye; when a sample of one eye
//! arrives and the partner eye's newest sample is older than
//! `pair_window_s` (default 50 ms: 10 frames at 200 Hz, 4 at 120 Hz), the
//! partner is advanced to the same time as a missing measurement, so its
//! hold/model fallback runs on time even if it has gone silent. An eye that
//! has never reported is left alone (monocular sources stay monocular).
//!
//! Fusion into one pupil for the vision pipeline is
//! [`crate::state::EyeState::pupil_mm`] (mean of measured or held eyes);
//! the fused blink flag is "every eye that reports is closed".

use crate::setting::SettingError;
use serde::{Deserialize, Serialize};

/// Pairing configuration.
#[derive(Clone, Copy, Debug, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields, default)]
pub struct BinocularConfig {
    /// Partner samples older than this (s) count as missing. Default 0.05.
    pub pair_window_s: f64,
}

impl Default for BinocularConfig {
    fn default() -> Self {
        Self {
            pair_window_s: 0.05,
        }
    }
}

impl BinocularConfig {
    /// Checks the value; names the field.
    pub fn validate(&self) -> Result<(), SettingError> {
        if !(self.pair_window_s.is_finite() && self.pair_window_s > 0.0) {
            return Err(SettingError::new(
                "binocular.pair_window_s",
                format!("must be > 0, got {}", self.pair_window_s),
            ));
        }
        Ok(())
    }
}

/// Tracks when each eye last reported.
#[derive(Clone, Copy, Debug)]
pub struct BinocularPairing {
    cfg: BinocularConfig,
    last_t: [Option<f64>; 2],
}

impl BinocularPairing {
    pub fn new(cfg: BinocularConfig) -> Self {
        Self {
            cfg,
            last_t: [None; 2],
        }
    }

    /// Records a sample of `eye` at `t_secs`; returns the partner eye if it
    /// has reported before but not within the pair window, i.e. it must be
    /// advanced to `t_secs` as missing.
    pub fn observe(&mut self, eye: usize, t_secs: f64) -> Option<usize> {
        let eye = eye.min(1);
        let prev = self.last_t[eye].unwrap_or(t_secs);
        self.last_t[eye] = Some(prev.max(t_secs));
        let partner = 1 - eye;
        match self.last_t[partner] {
            Some(tp) if t_secs - tp > self.cfg.pair_window_s => Some(partner),
            _ => None,
        }
    }

    /// Whether `eye` has ever reported.
    pub fn has_reported(&self, eye: usize) -> bool {
        self.last_t.get(eye).is_some_and(Option::is_some)
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn silent_partner_is_flagged_only_after_the_window() {
        let mut p = BinocularPairing::new(BinocularConfig::default());
        assert_eq!(p.observe(0, 0.0), None, "partner never reported");
        assert_eq!(p.observe(1, 0.002), None);
        assert_eq!(p.observe(0, 0.040), None, "left eye 38 ms old");
        assert_eq!(p.observe(0, 0.060), Some(1), "left eye 58 ms old");
        assert!(p.has_reported(1));
    }
}
