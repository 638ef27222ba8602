//! The filtered, calibrated eye state that the rest of gazelight reads.

use serde::{Deserialize, Serialize};

use crate::sample::PupilUnit;

/// Index of the right eye in per-eye arrays (Pupil Core's eye id 0).
pub const EYE_RIGHT: usize = 0;
/// Index of the left eye in per-eye arrays (Pupil Core's eye id 1).
pub const EYE_LEFT: usize = 1;

/// Where a pupil diameter in an [`EyeChannel`] came from.
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq, Serialize, Deserialize)]
#[serde(rename_all = "snake_case")]
pub enum PupilOrigin {
    /// A valid, filtered, calibrated measurement.
    Measured,
    /// The tracker lost the pupil; the last good value is held.
    Held,
    /// The tracker lost the pupil for longer than the hold time; the value
    /// eases towards a luminance-based pupil model.
    Model,
    /// Nothing has been measured yet; the value is the model's default.
    #[default]
    Default,
}

/// One eye's state: two quantities, never confused.
///
/// - The **measured pupil** ([`Self::measured`], in [`Self::measured_unit`]):
///   the newest clean sample of this eye, unchanged — the tracker's mm, raw
///   × a physical scale, or the tracker's raw unit — or `None` where this
///   eye is not measured now (lost, a blink and its margins, a speed
///   outlier, before its first measurement, an eye the source does not
///   have). This is what research outputs carry.
/// - The **model aperture** ([`Self::pupil_mm`]): the pupil the glare PSF
///   is built for — 001 §5's black/white map or the measured mm, held
///   through blinks, eased to the pupil model when nothing is measured,
///   rate-limited; always finite and > 0.
#[derive(Clone, Copy, Debug, PartialEq, Serialize, Deserialize)]
pub struct EyeChannel {
    /// The model aperture, mm (sizes the glare PSF; not a measurement);
    /// always finite and > 0.
    pub pupil_mm: f32,
    /// Where `pupil_mm` came from.
    pub pupil_origin: PupilOrigin,
    /// Confidence of the newest raw sample of this eye, 0..=1.
    pub confidence: f32,
    /// Host time (seconds, monotonic clock of the process) of the newest
    /// valid sample of this eye; `None` if there has been none.
    pub last_valid_t_secs: Option<f64>,
    /// This eye's own gaze (monocular gaze samples, e.g. Pupil's
    /// `gaze.3d.0.`, Neon's per-eye gaze, EyeLink's per-eye columns),
    /// normalised image coordinates, top-left origin; meaningful only when
    /// `gaze_valid`. See [`EyeState::eye_gaze_uv`].
    #[serde(default = "centre_uv")]
    pub gaze_uv: [f32; 2],
    /// Whether `gaze_uv` comes from a valid recent monocular sample.
    #[serde(default)]
    pub gaze_valid: bool,
    /// Whether `pupil_mm` is still moving towards its target at the
    /// physiological rate limit (at the start, after a blink or a
    /// dropout): then it is not yet the measurement, whatever
    /// `pupil_origin` says (the pupil light response leaves such frames'
    /// residual out).
    #[serde(default)]
    pub settling: bool,
    /// The measured pupil now, in `measured_unit`; `None` where this eye is
    /// not measured (see the type's docs).
    #[serde(default)]
    pub measured: Option<f32>,
    /// The unit of `measured` (mm where known).
    #[serde(default)]
    pub measured_unit: Option<PupilUnit>,
    /// The time of the sample `measured` comes from (same clock as
    /// `EyeState::t_secs`).
    #[serde(default)]
    pub measured_t_secs: Option<f64>,
    /// The measured pupil through the profile's black/white map (001 §5),
    /// mm of the map, where the pupil is measured in raw units with such a
    /// map: the sample's own value, not held or rate-limited (the
    /// aperture is); `None` elsewhere.
    #[serde(default)]
    pub measured_map_mm: Option<f32>,
    /// Whether the source has given any pupil sample of this eye (a
    /// monocular recording's other eye never has).
    #[serde(default)]
    pub present: bool,
}

impl EyeChannel {
    /// The measured pupil in mm, where it is measured and in mm.
    pub fn measured_mm(&self) -> Option<f32> {
        match (self.measured, self.measured_unit) {
            (Some(v), Some(PupilUnit::Mm)) => Some(v),
            _ => None,
        }
    }
}

fn centre_uv() -> [f32; 2] {
    [0.5, 0.5]
}

impl Default for EyeChannel {
    fn default() -> Self {
        Self {
            // A typical photopic pupil; replaced as soon as anything is known.
            pupil_mm: 4.0,
            pupil_origin: PupilOrigin::Default,
            confidence: 0.0,
            last_valid_t_secs: None,
            gaze_uv: centre_uv(),
            gaze_valid: false,
            settling: false,
            measured: None,
            measured_unit: None,
            measured_t_secs: None,
            measured_map_mm: None,
            present: false,
        }
    }
}

/// The latest filtered, calibrated state of both eyes.
///
/// Gaze is normalised to the display/scene image: `gaze_uv = [0, 0]` is the
/// top-left corner, `[1, 1]` the bottom-right (note: Pupil's `norm_pos` has
/// its origin at the bottom-left; sources convert).
#[derive(Clone, Copy, Debug, PartialEq, Serialize, Deserialize)]
pub struct EyeState {
    /// Host time (seconds, monotonic clock of the process) this state
    /// describes: the time of the newest sample that went into it.
    pub t_secs: f64,
    /// Fused gaze, normalised image coordinates (top-left origin).
    pub gaze_uv: [f32; 2],
    /// Whether `gaze_uv` comes from a valid recent gaze sample.
    pub gaze_valid: bool,
    /// Per eye, indexed by [`EYE_RIGHT`] / [`EYE_LEFT`].
    pub eyes: [EyeChannel; 2],
    /// Whether the eye is currently considered closed (blink).
    pub blink: bool,
}

impl Default for EyeState {
    fn default() -> Self {
        Self {
            t_secs: 0.0,
            gaze_uv: [0.5, 0.5],
            gaze_valid: false,
            eyes: [EyeChannel::default(); 2],
            blink: false,
        }
    }
}

impl EyeState {
    /// Age of this state at host time `now_secs`, in seconds (never negative).
    pub fn age_secs(&self, now_secs: f64) -> f64 {
        (now_secs - self.t_secs).max(0.0)
    }

    /// The pupil diameter the vision pipeline should use: the mean of the
    /// eyes with a measured (or held) pupil, else the mean of both.
    pub fn pupil_mm(&self) -> f32 {
        let (sum, count) = self
            .eyes
            .iter()
            .filter(|e| matches!(e.pupil_origin, PupilOrigin::Measured | PupilOrigin::Held))
            .fold((0.0f32, 0u32), |(s, n), e| (s + e.pupil_mm, n + 1));
        if count == 0 {
            (self.eyes[0].pupil_mm + self.eyes[1].pupil_mm) * 0.5
        } else {
            sum / count as f32
        }
    }

    /// The pupil diameter of eye `eye` ([`EYE_RIGHT`] or [`EYE_LEFT`]) for a
    /// per-eye (stereo) view: its own pupil when it is measured (or held);
    /// else the other eye's when that one is measured, since both pupils
    /// follow the light reaching either eye (the consensual light reflex);
    /// else its own model value. Any other index gives [`Self::pupil_mm`].
    pub fn eye_pupil_mm(&self, eye: usize) -> f32 {
        let measured =
            |e: &EyeChannel| matches!(e.pupil_origin, PupilOrigin::Measured | PupilOrigin::Held);
        match eye {
            EYE_RIGHT | EYE_LEFT => {
                let own = &self.eyes[eye];
                let other = &self.eyes[1 - eye];
                if !measured(own) && measured(other) {
                    other.pupil_mm
                } else {
                    own.pupil_mm
                }
            }
            _ => self.pupil_mm(),
        }
    }

    /// The measured pupil of a view, with its unit: eye `eye`'s own
    /// ([`EYE_RIGHT`], [`EYE_LEFT`]), or for any other index the mean of
    /// the eyes measured now (in one unit). `None` where nothing is
    /// measured — never the other eye's or the model's value.
    pub fn view_measured(&self, eye: usize) -> Option<(f32, PupilUnit)> {
        match self.eyes.get(eye) {
            Some(e) => e.measured.zip(e.measured_unit),
            None => {
                let mut sum = 0.0f32;
                let mut n = 0u32;
                let mut unit = None;
                for e in &self.eyes {
                    if let (Some(v), Some(u)) = (e.measured, e.measured_unit) {
                        if unit.is_some_and(|u0| u0 != u) {
                            continue;
                        }
                        unit = Some(u);
                        sum += v;
                        n += 1;
                    }
                }
                unit.map(|u| (sum / n as f32, u))
            }
        }
    }

    /// The measured pupil through the black/white map of a view
    /// ([`EyeChannel::measured_map_mm`]): the eye's own, or for any other
    /// index the mean of the eyes that have one now.
    pub fn view_measured_map_mm(&self, eye: usize) -> Option<f32> {
        match self.eyes.get(eye) {
            Some(e) => e.measured_map_mm,
            None => {
                // No allocation: it runs per view per frame.
                let (sum, n) = self
                    .eyes
                    .iter()
                    .filter_map(|e| e.measured_map_mm)
                    .fold((0.0f32, 0u32), |(s, n), v| (s + v, n + 1));
                (n > 0).then(|| sum / n as f32)
            }
        }
    }

    /// Whether eye `eye` (any other index: either eye) is present in the
    /// source.
    pub fn view_present(&self, eye: usize) -> bool {
        match self.eyes.get(eye) {
            Some(e) => e.present,
            None => self.eyes.iter().any(|e| e.present),
        }
    }

    /// The gaze of eye `eye` for its own view: its monocular gaze when the
    /// tracker gives one (valid and recent), else the fused gaze. Any other
    /// index gives the fused gaze.
    pub fn eye_gaze_uv(&self, eye: usize) -> [f32; 2] {
        match self.eyes.get(eye) {
            Some(e) if e.gaze_valid => e.gaze_uv,
            _ => self.gaze_uv,
        }
    }
}

/// The newest filtered state as the live eye task publishes it (on a
/// `watch` channel: readers take the latest value and never wait).
#[derive(Clone, Copy, Debug, Default, PartialEq)]
pub struct LiveEyeState {
    /// The state after the newest sample (or the newest stale-fallback
    /// step).
    pub state: EyeState,
    /// Host time (s, [`crate::clock::host_now_secs`]) when the task wrote
    /// this state.
    pub updated_host_secs: f64,
    /// Samples the chain has consumed so far (0: none yet).
    pub updates: u64,
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn age_is_never_negative() {
        let s = EyeState {
            t_secs: 10.0,
            ..Default::default()
        };
        assert_eq!(s.age_secs(9.0), 0.0);
        assert!((s.age_secs(10.25) - 0.25).abs() < 1e-12);
    }

    #[test]
    fn pupil_prefers_measured_eyes() {
        let mut s = EyeState::default();
        s.eyes[EYE_RIGHT].pupil_mm = 3.0;
        s.eyes[EYE_RIGHT].pupil_origin = PupilOrigin::Measured;
        s.eyes[EYE_LEFT].pupil_mm = 7.0;
        s.eyes[EYE_LEFT].pupil_origin = PupilOrigin::Model;
        assert_eq!(s.pupil_mm(), 3.0);
    }

    #[test]
    fn per_eye_pupil_falls_back_to_the_measured_eye() {
        let mut s = EyeState::default();
        s.eyes[EYE_RIGHT].pupil_mm = 3.0;
        s.eyes[EYE_RIGHT].pupil_origin = PupilOrigin::Measured;
        s.eyes[EYE_LEFT].pupil_mm = 7.0;
        s.eyes[EYE_LEFT].pupil_origin = PupilOrigin::Model;
        assert_eq!(s.eye_pupil_mm(EYE_RIGHT), 3.0);
        assert_eq!(s.eye_pupil_mm(EYE_LEFT), 3.0);
        s.eyes[EYE_LEFT].pupil_origin = PupilOrigin::Held;
        assert_eq!(s.eye_pupil_mm(EYE_LEFT), 7.0);
        assert_eq!(s.eye_pupil_mm(2), 5.0);
    }

    #[test]
    fn per_eye_gaze_falls_back_to_the_fused_gaze() {
        let mut s = EyeState {
            gaze_uv: [0.4, 0.6],
            ..Default::default()
        };
        s.eyes[EYE_LEFT].gaze_uv = [0.1, 0.2];
        s.eyes[EYE_LEFT].gaze_valid = true;
        s.eyes[EYE_RIGHT].gaze_uv = [0.9, 0.9];
        assert_eq!(s.eye_gaze_uv(EYE_LEFT), [0.1, 0.2]);
        assert_eq!(s.eye_gaze_uv(EYE_RIGHT), [0.4, 0.6]);
        assert_eq!(s.eye_gaze_uv(7), [0.4, 0.6]);
    }
}
