//! Raw samples as sources deliver them, before filtering and calibration.

use serde::{Deserialize, Serialize};

/// The unit of a raw pupil diameter.
#[derive(Clone, Copy, Debug, PartialEq, Eq, Serialize, Deserialize)]
#[serde(rename_all = "snake_case")]
pub enum PupilUnit {
    /// Eye-camera pixels (Pupil Core 2D detector `diameter`).
    Px,
    /// Millimetres (Pupil Core 3D `diameter_3d`, Neon, CSV traces in mm).
    Mm,
    /// Arbitrary area units (EyeLink `pupil` column in AREA mode).
    ArbitraryArea,
    /// Arbitrary diameter units (EyeLink DIAMETER mode, vendor trackers).
    Arbitrary,
}

/// Which pupil detector produced a sample.
#[derive(Clone, Copy, Debug, PartialEq, Eq, Serialize, Deserialize)]
#[serde(rename_all = "snake_case")]
pub enum DetectorMethod {
    /// Pupil Core 2D ellipse detector.
    Pupil2d,
    /// Pupil Core 3D eye model (pye3d).
    Pupil3d,
    /// Anything else (Neon, EyeLink, CSV, synthetic).
    Other,
}

/// One eye's pupil measurement.
#[derive(Clone, Copy, Debug, PartialEq, Serialize, Deserialize)]
pub struct PupilSample {
    /// Time of the measurement, seconds, in the source's clock (tracker
    /// time for live sources, recording time for replays). Sources that
    /// align clocks convert to host time before publishing.
    pub t_secs: f64,
    /// 0 = right eye, 1 = left eye (Pupil Core's eye ids).
    pub eye: u8,
    /// Diameter as reported, in `unit`. 0 or NaN means "no pupil".
    pub diameter_raw: f32,
    /// Unit of `diameter_raw`.
    pub unit: PupilUnit,
    /// Diameter in mm when the tracker itself reports one (3D model, Neon).
    pub diameter_mm: Option<f32>,
    /// Detection confidence 0..=1.
    pub confidence: f32,
    /// Pupil centre in the eye image, normalised, origin bottom-left
    /// (Pupil's `norm_pos`); `[NaN, NaN]` when unknown.
    pub norm_pos: [f32; 2],
    /// Which detector produced it.
    pub method: DetectorMethod,
}

/// Pupil Labs Neon's scene camera, pixels (1600 × 1200; Neon's
/// specifications): Neon reports gaze in its pixels, and every Neon path
/// (live `neon://`, recordings, LSL, XDF) divides by it. Defined here only
/// (`tests/tests/rules_once.rs`).
pub const NEON_SCENE_CAMERA_PX: [f32; 2] = [1600.0, 1200.0];

/// Which eyes a gaze sample was computed from.
#[derive(Clone, Copy, Debug, PartialEq, Eq, Serialize, Deserialize)]
#[serde(rename_all = "snake_case")]
pub enum GazeEyes {
    Binocular,
    /// Right eye only (Pupil's `gaze.*.0.`).
    Right,
    /// Left eye only (Pupil's `gaze.*.1.`).
    Left,
}

/// One gaze sample.
#[derive(Clone, Copy, Debug, PartialEq, Serialize, Deserialize)]
pub struct GazeSample {
    /// Time, seconds, same clock convention as [`PupilSample::t_secs`].
    pub t_secs: f64,
    /// Normalised gaze on the display/scene image, origin top-left (Pupil's
    /// bottom-left `norm_pos` is converted by the decoder: v = 1 − y).
    pub gaze_uv: [f32; 2],
    /// Confidence 0..=1.
    pub confidence: f32,
    /// Eyes the gaze was computed from.
    pub eyes: GazeEyes,
}

/// A blink event reported by a tracker or a recording.
#[derive(Clone, Copy, Debug, PartialEq, Serialize, Deserialize)]
pub struct BlinkEvent {
    pub start_t_secs: f64,
    pub end_t_secs: f64,
    /// `None` when the event covers both eyes.
    pub eye: Option<u8>,
}

/// Anything a source can deliver.
#[derive(Clone, Copy, Debug, PartialEq, Serialize, Deserialize)]
#[serde(tag = "kind", rename_all = "snake_case")]
pub enum Sample {
    Pupil(PupilSample),
    Gaze(GazeSample),
    Blink(BlinkEvent),
}

impl Sample {
    /// The sample's time (a blink's start).
    pub fn t_secs(&self) -> f64 {
        match self {
            Sample::Pupil(p) => p.t_secs,
            Sample::Gaze(g) => g.t_secs,
            Sample::Blink(b) => b.start_t_secs,
        }
    }

    /// Sets the sample's time (a blink keeps its duration).
    pub fn set_t_secs(&mut self, t_secs: f64) {
        match self {
            Sample::Pupil(p) => p.t_secs = t_secs,
            Sample::Gaze(g) => g.t_secs = t_secs,
            Sample::Blink(b) => {
                let d = b.end_t_secs - b.start_t_secs;
                b.start_t_secs = t_secs;
                b.end_t_secs = t_secs + d;
            }
        }
    }
}
