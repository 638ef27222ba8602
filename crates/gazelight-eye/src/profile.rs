//! Pupil calibration profiles: the per-eye linear map from the tracker's
//! raw pupil units to millimetres (001 §5), and the observer it was made
//! for.
//!
//! Two kinds of map ([`MapKind`]), never confused:
//!
//! - **aperture** (the default, what `calibrate` and `profile phases`
//!   write): 001 §5's black/white map onto the model's range (2–8 mm by
//!   default). It sizes the glare kernel's pupil aperture; it is not a
//!   measurement, so the measured pupil stays in the tracker's own unit
//!   (or its mm). The line runs through the two phases' estimates and is
//!   *not* clamped at them: a pupil larger than in the black phase maps
//!   above `mm_max`; the filter chain bounds the aperture only by the
//!   physiological range and counts what falls outside.
//! - **scale** (`profile scale`, an artificial pupil): a physical scale,
//!   millimetres per raw unit; the measured pupil is then in mm.
//!
//! A raw value that is not finite or ≤ 0 (a blink, a lost pupil) is
//! rejected before mapping ([`BadRawPupil`]).
//!
//! Profiles are JSON files (schema `gazelight.pupil-calibration/2`,
//! documented in `calibration/schema.json` and `calibration/README.md` at
//! the repository root). Version 1 profiles (no `observer`) still load,
//! with the default observer. [`PupilCalibration::load`] validates every
//! field and names the one that is wrong.
//!
//! This module depends on nothing else in the crate: the filter chain
//! applies a profile ([`crate::filter`]), and the calibration routine
//! ([`crate::calibration`]) produces one.

use std::path::{Path, PathBuf};

use serde::{Deserialize, Serialize};

use crate::sample::{PupilSample, PupilUnit};

/// The schema identifier profiles carry (and [`PupilCalibration::save`]
/// writes).
pub const SCHEMA: &str = "gazelight.pupil-calibration/2";
/// The previous schema: no `observer`; still loaded, with the default
/// observer.
pub const SCHEMA_V1: &str = "gazelight.pupil-calibration/1";
/// Default observer age, years (CIE 146:2002's young reference observer).
pub const DEFAULT_AGE_YEARS: f64 = 25.0;
/// Default ocular pigmentation (CIE 146:2002: 0.5 = brown eyes).
pub const DEFAULT_PIGMENTATION: f64 = 0.5;
/// Accepted observer ages, years.
pub const AGE_YEARS_RANGE: (f64, f64) = (0.0, 120.0);
/// Accepted pigmentation (CIE 146:2002: 0 very dark … 1.2 very light eyes).
pub const PIGMENTATION_RANGE: (f64, f64) = (0.0, 1.2);

/// The observer a profile was made for: the CIE 146:2002 stray-light
/// parameters of the glare kernel.
#[derive(Clone, Copy, Debug, PartialEq, Serialize, Deserialize)]
#[serde(default, deny_unknown_fields)]
pub struct Observer {
    /// Age, years (CIE 146 `A`).
    pub age_years: f64,
    /// Ocular pigmentation (CIE 146 `p`).
    pub pigmentation: f64,
}

impl Default for Observer {
    fn default() -> Self {
        Self {
            age_years: DEFAULT_AGE_YEARS,
            pigmentation: DEFAULT_PIGMENTATION,
        }
    }
}

impl Observer {
    /// Checks both fields; `Err((field, reason))` with `prefix.` before
    /// the field name.
    pub fn validate(&self, prefix: &str) -> Result<(), (String, String)> {
        for (name, v, (lo, hi)) in [
            ("age_years", self.age_years, AGE_YEARS_RANGE),
            ("pigmentation", self.pigmentation, PIGMENTATION_RANGE),
        ] {
            if !(v.is_finite() && (lo..=hi).contains(&v)) {
                return Err((
                    format!("{prefix}{name}"),
                    format!("must be a finite number in {lo}..={hi}, got {v}"),
                ));
            }
        }
        Ok(())
    }
}

/// Why a raw pupil value was not mapped.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum BadRawPupil {
    /// NaN or ±∞.
    NotFinite,
    /// Zero or negative (a blink or a lost pupil).
    NonPositive,
}
/// Default pupil diameter mapped to the white phase, mm (001 §5).
pub const DEFAULT_MM_MIN: f64 = 2.0;
/// Default pupil diameter mapped to the black phase, mm (001 §5).
pub const DEFAULT_MM_MAX: f64 = 8.0;

/// What a map means: the model aperture (001 §5) or a physical scale.
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq, Serialize, Deserialize)]
#[serde(rename_all = "snake_case")]
pub enum MapKind {
    /// 001 §5's black/white map onto the model's range: sizes the PSF, not
    /// a measurement.
    #[default]
    Aperture,
    /// A physical scale (mm per raw unit): the measured pupil in mm.
    Scale,
}

/// One eye's linear map.
#[derive(Clone, Copy, Debug, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct EyeCalibration {
    /// Whether this map is the model aperture (default; profiles without
    /// the field) or a physical scale.
    #[serde(default)]
    pub kind: MapKind,
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
    /// Maps a raw diameter-like value (already √area for area units) onto
    /// mm along the line through the two phases: rejects a raw value that
    /// is not finite or ≤ 0 before mapping; never clamps (a value past a
    /// phase's estimate is extrapolated; bounds are the caller's, counted).
    #[inline]
    pub fn map(&self, raw: f64) -> Result<f64, BadRawPupil> {
        if !raw.is_finite() {
            return Err(BadRawPupil::NotFinite);
        }
        if raw <= 0.0 {
            return Err(BadRawPupil::NonPositive);
        }
        Ok(self.mm_max
            + (raw - self.raw_black) * (self.mm_min - self.mm_max)
                / (self.raw_white - self.raw_black))
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
    /// The observer (absent in version 1 profiles: the default).
    #[serde(default)]
    pub observer: Observer,
}

/// Why a profile could not be loaded or saved.
#[derive(Debug, thiserror::Error)]
pub enum ProfileError {
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
}

impl PupilCalibration {
    /// No maps: only sources already in mm give pupils.
    pub fn identity() -> Self {
        Self {
            schema: SCHEMA.to_owned(),
            description: None,
            eyes: EyeCalibrations::default(),
            observer: Observer::default(),
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

    /// The measured pupil of a sample, in its unit: the tracker's own mm
    /// (`diameter_mm`, or a raw value in mm); else raw × this eye's
    /// physical scale ([`MapKind::Scale`]) in mm; else the raw value in
    /// the tracker's unit (diameter, or area for area units). NaN when the
    /// raw value is not finite or ≤ 0.
    #[inline]
    pub fn measured(&self, p: &PupilSample) -> (f32, PupilUnit) {
        if let Some(mm) = p.diameter_mm {
            return (mm, PupilUnit::Mm);
        }
        if p.unit == PupilUnit::Mm {
            return (p.diameter_raw, PupilUnit::Mm);
        }
        if let Some(c) = self.eye(p.eye)
            && c.kind == MapKind::Scale
            && c.raw_unit == p.unit
        {
            return match c.map(Self::raw_value(p)) {
                Ok(mm) => (mm as f32, PupilUnit::Mm),
                Err(_) => (f32::NAN, PupilUnit::Mm),
            };
        }
        (p.diameter_raw, p.unit)
    }

    /// The model aperture of a sample, mm: through this eye's map when it
    /// has one for the sample's unit (001 §5's line, not clamped); else the
    /// tracker's own mm; else `Ok(None)` (raw units with no map). A raw
    /// value that is not finite or ≤ 0 is an error.
    #[inline]
    pub fn aperture_mm(&self, p: &PupilSample) -> Result<Option<f32>, BadRawPupil> {
        if let Some(c) = self.eye(p.eye)
            && c.raw_unit == p.unit
        {
            if !p.diameter_raw.is_finite() {
                return Err(BadRawPupil::NotFinite);
            }
            return c.map(Self::raw_value(p)).map(|mm| Some(mm as f32));
        }
        let (v, unit) = self.measured(p);
        if unit != PupilUnit::Mm {
            return Ok(None);
        }
        if !v.is_finite() {
            return Err(BadRawPupil::NotFinite);
        }
        if v <= 0.0 {
            return Err(BadRawPupil::NonPositive);
        }
        Ok(Some(v))
    }

    /// Whether this eye's map is 001 §5's aperture map for `unit` (then
    /// the measured pupil in `unit` is not in mm).
    pub fn maps_aperture(&self, eye: u8, unit: PupilUnit) -> bool {
        self.eye(eye)
            .is_some_and(|c| c.raw_unit == unit && c.kind == MapKind::Aperture)
    }

    /// Checks the schema and every map; `Err((field, reason))`.
    pub fn validate(&self) -> Result<(), (String, String)> {
        if self.schema != SCHEMA && self.schema != SCHEMA_V1 {
            return Err((
                "schema".into(),
                format!("must be \"{SCHEMA}\", got \"{}\"", self.schema),
            ));
        }
        self.observer.validate("observer.")?;
        if let Some(c) = &self.eyes.right {
            c.validate("eyes.right")?;
        }
        if let Some(c) = &self.eyes.left {
            c.validate("eyes.left")?;
        }
        Ok(())
    }

    /// Reads and validates a profile; errors name the file and field.
    pub fn load(path: &Path) -> Result<Self, ProfileError> {
        let text = gazelight_input::read_config(path, gazelight_input::ConfigSyntax::Json)
            .map_err(|source| ProfileError::Io {
                path: path.to_owned(),
                source,
            })?;
        Self::parse(&text, path)
    }

    /// Parses and validates profile text; `path` names it in errors.
    pub fn parse(text: &str, path: &Path) -> Result<Self, ProfileError> {
        let invalid = |field: String, reason: String| ProfileError::Invalid {
            path: path.to_owned(),
            field,
            reason,
        };
        // Bounded by construction: a text with more values or deeper
        // nesting than any profile is refused before a tree is built.
        gazelight_input::check_config_structure(text, gazelight_input::ConfigSyntax::Json)
            .map_err(|e| ProfileError::Json {
                path: path.to_owned(),
                reason: e.to_string(),
            })?;
        let value: serde_json::Value =
            serde_json::from_str(text).map_err(|e| ProfileError::Json {
                path: path.to_owned(),
                reason: e.to_string(),
            })?;
        // Field-by-field checks first, so that every error names its field
        // (serde's own messages do not say which eye).
        let Some(root) = value.as_object() else {
            return Err(invalid("(root)".into(), "must be a JSON object".into()));
        };
        match root.get("schema").and_then(|v| v.as_str()) {
            Some(SCHEMA) => {}
            Some(SCHEMA_V1) => {
                if root.contains_key("observer") {
                    return Err(invalid(
                        "observer".into(),
                        format!("is not part of \"{SCHEMA_V1}\"; use \"{SCHEMA}\""),
                    ));
                }
            }
            Some(other) => {
                return Err(invalid(
                    "schema".into(),
                    format!("must be \"{SCHEMA}\", got \"{other}\""),
                ));
            }
            None => {
                return Err(invalid(
                    "schema".into(),
                    format!("missing; must be \"{SCHEMA}\""),
                ));
            }
        }
        let Some(eyes) = root.get("eyes").and_then(|v| v.as_object()) else {
            return Err(invalid("eyes".into(), "missing or not an object".into()));
        };
        for (name, eye) in eyes {
            if name != "right" && name != "left" {
                return Err(invalid(
                    format!("eyes.{name}"),
                    "unknown eye (right|left)".into(),
                ));
            }
            let Some(eye) = eye.as_object() else {
                return Err(invalid(format!("eyes.{name}"), "must be an object".into()));
            };
            for key in ["raw_black", "raw_white", "mm_min", "mm_max"] {
                if !eye.get(key).is_some_and(|v| v.is_number()) {
                    return Err(invalid(
                        format!("eyes.{name}.{key}"),
                        "missing or not a number".into(),
                    ));
                }
            }
            let units = ["px", "mm", "arbitrary_area", "arbitrary"];
            match eye.get("raw_unit").and_then(|v| v.as_str()) {
                Some(u) if units.contains(&u) => {}
                other => {
                    return Err(invalid(
                        format!("eyes.{name}.raw_unit"),
                        format!("must be one of {units:?}, got {other:?}"),
                    ));
                }
            }
        }
        if let Some(obs) = root.get("observer") {
            let Some(obs) = obs.as_object() else {
                return Err(invalid("observer".into(), "must be an object".into()));
            };
            for (key, v) in obs {
                if key != "age_years" && key != "pigmentation" {
                    return Err(invalid(
                        format!("observer.{key}"),
                        "unknown field (age_years|pigmentation)".into(),
                    ));
                }
                if !v.is_number() {
                    return Err(invalid(
                        format!("observer.{key}"),
                        "must be a number".into(),
                    ));
                }
            }
        }
        let mut cal: Self = serde_json::from_value(value).map_err(|e| ProfileError::Json {
            path: path.to_owned(),
            reason: e.to_string(),
        })?;
        cal.validate()
            .map_err(|(field, reason)| invalid(field, reason))?;
        // A version 1 profile is read as version 2 with the default observer.
        cal.schema = SCHEMA.to_owned();
        Ok(cal)
    }

    /// Writes the profile (validated first) atomically: to a temporary file
    /// beside `path`, then renamed over it.
    pub fn save(&self, path: &Path) -> Result<(), ProfileError> {
        self.validate()
            .map_err(|(field, reason)| ProfileError::Invalid {
                path: path.to_owned(),
                field,
                reason,
            })?;
        let json = serde_json::to_string_pretty(self).map_err(|e| ProfileError::Json {
            path: path.to_owned(),
            reason: e.to_string(),
        })?;
        let tmp = path.with_extension("json.tmp");
        let io = |source| ProfileError::Io {
            path: path.to_owned(),
            source,
        };
        std::fs::write(&tmp, json + "\n").map_err(io)?;
        std::fs::rename(&tmp, path).map_err(io)
    }
}
