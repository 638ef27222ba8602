//! Confidence gate: a pupil or gaze sample below the tracker-reported
//! confidence threshold is not a measurement. The default 0.6 is Pupil
//! Capture's own threshold (below it Pupil switches a binocular gaze mapper
//! to monocular).

use crate::setting::SettingError;
use serde::{Deserialize, Serialize};

/// Pupil Capture's confidence threshold for usable data.
pub const DEFAULT_MIN_CONFIDENCE: f32 = 0.6;

/// The confidence gate.
#[derive(Clone, Copy, Debug, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields, default)]
pub struct ConfidenceGate {
    /// Minimum confidence (inclusive) of a usable sample, 0..=1.
    /// Default [`DEFAULT_MIN_CONFIDENCE`].
    pub min_confidence: f32,
}

impl Default for ConfidenceGate {
    fn default() -> Self {
        Self {
            min_confidence: DEFAULT_MIN_CONFIDENCE,
        }
    }
}

impl ConfidenceGate {
    /// Whether a sample with this confidence passes (NaN never does).
    #[inline]
    pub fn accept(&self, confidence: f32) -> bool {
        confidence >= self.min_confidence
    }

    /// Checks the threshold lies in 0..=1.
    pub fn validate(&self) -> Result<(), SettingError> {
        if !(0.0..=1.0).contains(&self.min_confidence) {
            return Err(SettingError::new(
                "confidence.min_confidence",
                format!("must be within 0..=1, got {}", self.min_confidence),
            ));
        }
        Ok(())
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn gate_is_inclusive_and_rejects_nan() {
        let g = ConfidenceGate::default();
        assert!(g.accept(0.6));
        assert!(g.accept(1.0));
        assert!(!g.accept(0.59));
        assert!(!g.accept(f32::NAN));
        assert!(
            ConfidenceGate {
                min_confidence: 1.5
            }
            .validate()
            .is_err()
        );
    }
}
