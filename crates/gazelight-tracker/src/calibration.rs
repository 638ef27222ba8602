//! Black/white pupil calibration (001 §5): map the tracker's raw pupil
//! units linearly onto millimetres, per eye.
//!
//! 001 §5 calibrates the tracker's pupil reading by showing the observer a
//! black and then a white screen: the pupil is largest in the black phase
//! and smallest in the white one, and those two raw readings are mapped
//! onto the physiological range, 8 mm and 2 mm by default:
//!
//! ```text
//! mm(raw) = mm_max + (raw − raw_black) · (mm_min − mm_max) / (raw_white − raw_black)
//! ```
//!
//! For area units (EyeLink `PUPIL AREA`) the raw value is first turned into
//! an equivalent diameter, √area, so the map stays linear in diameter.
//!
//! Profiles are JSON files (schema `gazelight.pupil-calibration/1`,
//! documented in `calibration/schema.json` and `calibration/README.md` at
//! the repository root). [`PupilCalibration::load`] validates every field
//! and names the one that is wrong.
//!
//! The routine that produces a profile is [`CalibrationSession`]: a state
//! machine fed timed raw pupil samples from any source, driving a
//! [`StimulusSink`].

use std::path::{Path, PathBuf};

use serde::{Deserialize, Serialize};

use crate::sample::{PupilSample, PupilUnit};

/// The schema identifier profiles carry.
pub const SCHEMA: &str = "gazelight.pupil-calibration/1";
/// Default pupil diameter mapped to the white phase, mm (001 §5).
pub const DEFAULT_MM_MIN: f64 = 2.0;
/// Default pupil diameter mapped to the black phase, mm (001 §5).
pub const DEFAULT_MM_MAX: f64 = 8.0;

/// One eye's linear map.
#[derive(Clone, Copy, Debug, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct EyeCalibration {
    /// Unit of the raw values this map applies to.
    pub raw_unit: PupilUnit,
    /// Robust raw pupil during the black phase (√area for area units).
    pub raw_black: f64,
    /// Robust raw pupil during the white phase (√area for area units).
    pub raw_white: f64,
    /// Diameter assigned to `raw_white`, mm.
    pub mm_min: f64,
    /// Diameter assigned to `raw_black`, mm.
    pub mm_max: f64,
}

impl EyeCalibration {
    /// Maps a raw diameter-like value (already √area for area units).
    #[inline]
    pub fn map(&self, raw: f64) -> f64 {
        self.mm_max
            + (raw - self.raw_black) * (self.mm_min - self.mm_max)
                / (self.raw_white - self.raw_black)
    }

    fn validate(&self, field: &str) -> Result<(), (String, String)> {
        let f = |name: &str| format!("{field}.{name}");
        for (name, v) in [
            ("raw_black", self.raw_black),
            ("raw_white", self.raw_white),
            ("mm_min", self.mm_min),
            ("mm_max", self.mm_max),
        ] {
            if !(v.is_finite() && v > 0.0) {
                return Err((f(name), format!("must be a finite number > 0, got {v}")));
            }
        }
        if self.raw_white >= self.raw_black {
            return Err((
                f("raw_white"),
                format!(
                    "must be smaller than raw_black ({}): the pupil constricts in white, got {}",
                    self.raw_black, self.raw_white
                ),
            ));
        }
        if self.mm_min >= self.mm_max {
            return Err((
                f("mm_min"),
                format!(
                    "must be smaller than mm_max ({}), got {}",
                    self.mm_max, self.mm_min
                ),
            ));
        }
        Ok(())
    }
}

/// Per-eye calibrations of a profile.
#[derive(Clone, Copy, Debug, Default, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct EyeCalibrations {
    /// Eye 0.
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub right: Option<EyeCalibration>,
    /// Eye 1.
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub left: Option<EyeCalibration>,
}

/// A pupil calibration profile.
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct PupilCalibration {
    /// Always [`SCHEMA`].
    pub schema: String,
    /// Free text: tracker, session, operator.
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub description: Option<String>,
    /// Per-eye maps; an eye without one passes mm sources through and has
    /// no mm value for raw-unit sources.
    pub eyes: EyeCalibrations,
}

/// Errors of loading, saving and running a calibration.
#[derive(Debug, thiserror::Error)]
pub enum CalibrationError {
    #[error("cannot access {path}: {source}")]
    Io {
        path: PathBuf,
        #[source]
        source: std::io::Error,
    },
    #[error("{path}: not a valid calibration profile: {reason}")]
    Json { path: PathBuf, reason: String },
    #[error("{path}: field `{field}` {reason}")]
    Invalid {
        path: PathBuf,
        field: String,
        reason: String,
    },
    #[error(
        "eye {eye}, {phase:?} phase: only {:.0} % of the samples were valid, {:.0} % required",
        valid_fraction * 100.0,
        required * 100.0
    )]
    TooFewValidSamples {
        eye: u8,
        phase: Phase,
        valid_fraction: f64,
        required: f64,
    },
    #[error(
        "eye {eye}: the white-phase pupil ({white:.3}) is not smaller than the black-phase \
         pupil ({black:.3}); the pupil must constrict in white — check the stimulus reached the eye"
    )]
    WhiteNotSmaller { eye: u8, black: f64, white: f64 },
    #[error("calibration settings: {0}")]
    Config(String),
    #[error("stimulus display failed: {0}")]
    Sink(String),
    #[error("the calibration session is not finished (phase {0:?})")]
    NotFinished(Phase),
}

impl PupilCalibration {
    /// No maps: only sources already in mm give pupils.
    pub fn identity() -> Self {
        Self {
            schema: SCHEMA.to_owned(),
            description: None,
            eyes: EyeCalibrations::default(),
        }
    }

    /// The map of eye `eye` (0 right, 1 left).
    pub fn eye(&self, eye: u8) -> Option<&EyeCalibration> {
        match eye {
            0 => self.eyes.right.as_ref(),
            1 => self.eyes.left.as_ref(),
            _ => None,
        }
    }

    /// The raw value a map applies to: the diameter, or √area for area
    /// units. NaN/negative raw values stay invalid.
    #[inline]
    pub fn raw_value(p: &PupilSample) -> f64 {
        let r = p.diameter_raw as f64;
        match p.unit {
            PupilUnit::ArbitraryArea => {
                if r >= 0.0 {
                    r.sqrt()
                } else {
                    f64::NAN
                }
            }
            _ => r,
        }
    }

    /// The sample's diameter in mm: through this eye's map if it has one for
    /// the sample's unit; else the tracker's own mm (`diameter_mm`, or a raw
    /// value in mm); else `None` (uncalibrated raw units). The value is not
    /// range-checked here.
    #[inline]
    pub fn to_mm(&self, p: &PupilSample) -> Option<f32> {
        if let Some(c) = self.eye(p.eye)
            && c.raw_unit == p.unit
        {
            return Some(c.map(Self::raw_value(p)) as f32);
        }
        if let Some(mm) = p.diameter_mm {
            return Some(mm);
        }
        (p.unit == PupilUnit::Mm).then_some(p.diameter_raw)
    }

    /// Checks the schema and every map; `Err((field, reason))`.
    pub fn validate(&self) -> Result<(), (String, String)> {
        if self.schema != SCHEMA {
            return Err((
                "schema".into(),
                format!("must be \"{SCHEMA}\", got \"{}\"", self.schema),
            ));
        }
        if let Some(c) = &self.eyes.right {
            c.validate("eyes.right")?;
        }
        if let Some(c) = &self.eyes.left {
            c.validate("eyes.left")?;
        }
        Ok(())
    }

    /// Reads and validates a profile; errors name the file and field.
    pub fn load(path: &Path) -> Result<Self, CalibrationError> {
        let text = std::fs::read_to_string(path).map_err(|source| CalibrationError::Io {
            path: path.to_owned(),
            source,
        })?;
        Self::parse(&text, path)
    }

    /// Parses and validates profile text; `path` names it in errors.
    pub fn parse(text: &str, path: &Path) -> Result<Self, CalibrationError> {
        let cal: Self = serde_json::from_str(text).map_err(|e| CalibrationError::Json {
            path: path.to_owned(),
            reason: e.to_string(),
        })?;
        cal.validate()
            .map_err(|(field, reason)| CalibrationError::Invalid {
                path: path.to_owned(),
                field,
                reason,
            })?;
        Ok(cal)
    }

    /// Writes the profile (validated first) atomically: to a temporary file
    /// beside `path`, then renamed over it.
    pub fn save(&self, path: &Path) -> Result<(), CalibrationError> {
        self.validate()
            .map_err(|(field, reason)| CalibrationError::Invalid {
                path: path.to_owned(),
                field,
                reason,
            })?;
        let json = serde_json::to_string_pretty(self).map_err(|e| CalibrationError::Json {
            path: path.to_owned(),
            reason: e.to_string(),
        })?;
        let tmp = path.with_extension("json.tmp");
        let io = |source| CalibrationError::Io {
            path: path.to_owned(),
            source,
        };
        std::fs::write(&tmp, json + "\n").map_err(io)?;
        std::fs::rename(&tmp, path).map_err(io)
    }
}

/// A calibration phase.
#[derive(Clone, Copy, Debug, PartialEq, Eq, Serialize, Deserialize)]
#[serde(rename_all = "snake_case")]
pub enum Phase {
    Black,
    White,
}
