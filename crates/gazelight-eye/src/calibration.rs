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
//! The map is bounded: a raw value that is not finite or ≤ 0 (a blink, a
//! lost pupil) is rejected before mapping ([`BadRawPupil`]), and the
//! result is clamped to the profile's `[mm_min, mm_max]` (2–8 mm by
//! default, 001 §5) — the line is never extrapolated past the pupils the
//! observer showed in the black and white phases.
//!
//! A profile also describes its observer ([`Observer`]): age and ocular
//! pigmentation, the CIE 146:2002 parameters of the glare kernel's stray
//! light; defaults 25 years and 0.5.
//!
//! Profiles are JSON files (schema `gazelight.pupil-calibration/2`,
//! documented in `calibration/schema.json` and `calibration/README.md` at
//! the repository root). Version 1 profiles (no `observer`) still load,
//! with the default observer. [`PupilCalibration::load`] validates every
//! field and names the one that is wrong.
//!
//! The routine that produces a profile is [`CalibrationSession`]: a state
//! machine fed timed raw pupil samples from any source, driving a
//! [`StimulusSink`].

use std::path::{Path, PathBuf};

use serde::{Deserialize, Serialize};

use crate::filter::{BlinkConfig, BlinkDetector, ConfidenceGate};
use crate::sample::{PupilSample, PupilUnit, Sample};
use crate::source::{SampleSource, SourceError};

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
    /// Maps a raw diameter-like value (already √area for area units) onto
    /// mm: rejects a raw value that is not finite or ≤ 0 before mapping,
    /// and clamps the line to `[mm_min, mm_max]`.
    #[inline]
    pub fn map(&self, raw: f64) -> Result<f64, BadRawPupil> {
        if !raw.is_finite() {
            return Err(BadRawPupil::NotFinite);
        }
        if raw <= 0.0 {
            return Err(BadRawPupil::NonPositive);
        }
        let mm = self.mm_max
            + (raw - self.raw_black) * (self.mm_min - self.mm_max)
                / (self.raw_white - self.raw_black);
        Ok(mm.clamp(self.mm_min, self.mm_max))
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
    /// The sample source failed for good (or ended) during the session.
    #[error("sample source: {0}")]
    Source(String),
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

    /// The sample's diameter in mm: through this eye's map if it has one for
    /// the sample's unit (a raw value that is not finite or ≤ 0 is an
    /// error, the result is clamped to the map's range); else the tracker's
    /// own mm (`diameter_mm`, or a raw value in mm), not range-checked
    /// here; else `Ok(None)` (uncalibrated raw units).
    #[inline]
    pub fn to_mm(&self, p: &PupilSample) -> Result<Option<f32>, BadRawPupil> {
        if let Some(c) = self.eye(p.eye)
            && c.raw_unit == p.unit
        {
            if !p.diameter_raw.is_finite() {
                return Err(BadRawPupil::NotFinite);
            }
            return c.map(Self::raw_value(p)).map(|mm| Some(mm as f32));
        }
        if let Some(mm) = p.diameter_mm {
            return Ok(Some(mm));
        }
        Ok((p.unit == PupilUnit::Mm).then_some(p.diameter_raw))
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
    pub fn load(path: &Path) -> Result<Self, CalibrationError> {
        let text = gazelight_input::read_to_string(path, gazelight_input::MAX_TEXT_BYTES).map_err(
            |source| CalibrationError::Io {
                path: path.to_owned(),
                source,
            },
        )?;
        Self::parse(&text, path)
    }

    /// Parses and validates profile text; `path` names it in errors.
    pub fn parse(text: &str, path: &Path) -> Result<Self, CalibrationError> {
        let invalid = |field: String, reason: String| CalibrationError::Invalid {
            path: path.to_owned(),
            field,
            reason,
        };
        let value: serde_json::Value =
            serde_json::from_str(text).map_err(|e| CalibrationError::Json {
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
        let mut cal: Self = serde_json::from_value(value).map_err(|e| CalibrationError::Json {
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

/// What the stimulus display shows.
#[derive(Clone, Copy, Debug, PartialEq, Eq, Serialize, Deserialize)]
#[serde(rename_all = "snake_case")]
pub enum Stimulus {
    Black,
    White,
    /// Nothing: calibration over, the host application shows its content.
    None,
}

impl From<Phase> for Stimulus {
    fn from(p: Phase) -> Self {
        match p {
            Phase::Black => Stimulus::Black,
            Phase::White => Stimulus::White,
        }
    }
}

/// A stimulus display failed.
#[derive(Debug, thiserror::Error)]
#[error("{0}")]
pub struct StimulusError(pub String);

/// Where the calibration stimulus goes: a window of the service, a
/// notification to the host application, or a log (tests). Object-safe.
pub trait StimulusSink {
    /// Shows `stimulus` from `at_t_secs` on (the session's clock: the
    /// source's sample time).
    fn show(&mut self, stimulus: Stimulus, at_t_secs: f64) -> Result<(), StimulusError>;
}

/// A sink that records what was shown and when.
#[derive(Clone, Debug, Default, PartialEq)]
pub struct LogSink {
    pub shown: Vec<(f64, Stimulus)>,
}

impl StimulusSink for LogSink {
    fn show(&mut self, stimulus: Stimulus, at_t_secs: f64) -> Result<(), StimulusError> {
        self.shown.push((at_t_secs, stimulus));
        Ok(())
    }
}

/// Calibration routine settings.
#[derive(Clone, Copy, Debug, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields, default)]
pub struct CalibrationConfig {
    /// Phase order. Default black then white (001 §5).
    pub order: [Phase; 2],
    /// Duration of each phase, s. Default 5 (001 §5).
    pub phase_duration_s: f64,
    /// Samples in the first `settle_s` of a phase are ignored while the
    /// pupil adapts. Default 2 s: the light reflex constricts within ~1 s,
    /// redilation in the dark is slower (time constants of ~1 s).
    pub settle_s: f64,
    /// Minimum fraction of valid samples per phase and eye. Default 0.5.
    pub min_valid_fraction: f64,
    /// The white-phase pupil must be at least this fraction smaller than the
    /// black-phase one. Default 0.05 (real black/white constrictions are
    /// 30–60 %; this only rejects "no response").
    pub min_constriction_fraction: f64,
    /// Diameter assigned to the white phase, mm. Default 2.
    pub mm_min: f64,
    /// Diameter assigned to the black phase, mm. Default 8.
    pub mm_max: f64,
    /// Confidence gate for valid samples. Default 0.6.
    pub confidence: ConfidenceGate,
    /// Blink detection: samples inside a closure are not valid.
    pub blink: BlinkConfig,
}

impl Default for CalibrationConfig {
    fn default() -> Self {
        Self {
            order: [Phase::Black, Phase::White],
            phase_duration_s: 5.0,
            settle_s: 2.0,
            min_valid_fraction: 0.5,
            min_constriction_fraction: 0.05,
            mm_min: DEFAULT_MM_MIN,
            mm_max: DEFAULT_MM_MAX,
            confidence: ConfidenceGate::default(),
            blink: BlinkConfig::default(),
        }
    }
}

impl CalibrationConfig {
    /// Checks the settings; names the field.
    pub fn validate(&self) -> Result<(), CalibrationError> {
        let bad = |m: String| Err(CalibrationError::Config(m));
        if self.order[0] == self.order[1] {
            return bad("order must hold black and white once each".into());
        }
        if !(self.phase_duration_s.is_finite() && self.phase_duration_s > 0.0) {
            return bad(format!(
                "phase_duration_s must be > 0, got {}",
                self.phase_duration_s
            ));
        }
        if !(self.settle_s.is_finite()
            && self.settle_s >= 0.0
            && self.settle_s < self.phase_duration_s)
        {
            return bad(format!(
                "settle_s must be within 0..phase_duration_s ({}), got {}",
                self.phase_duration_s, self.settle_s
            ));
        }
        if !(0.0..=1.0).contains(&self.min_valid_fraction) {
            return bad(format!(
                "min_valid_fraction must be within 0..=1, got {}",
                self.min_valid_fraction
            ));
        }
        if !(0.0..1.0).contains(&self.min_constriction_fraction) {
            return bad(format!(
                "min_constriction_fraction must be within 0..1, got {}",
                self.min_constriction_fraction
            ));
        }
        if !(self.mm_min > 0.0 && self.mm_max > self.mm_min && self.mm_max.is_finite()) {
            return bad(format!(
                "need 0 < mm_min < mm_max, got mm_min {} mm_max {}",
                self.mm_min, self.mm_max
            ));
        }
        self.confidence
            .validate()
            .map_err(CalibrationError::Config)?;
        self.blink.validate().map_err(CalibrationError::Config)
    }
}

/// One phase of one eye, as [`CalibrationSession::summary`] reports it.
#[derive(Clone, Copy, Debug, PartialEq, Serialize)]
pub struct PhaseSummary {
    /// Eye index (0 = right, 1 = left).
    pub eye: u8,
    pub phase: Phase,
    /// Unit of the raw values.
    pub unit: PupilUnit,
    /// Samples in the analysis window (after the settle time).
    pub samples: u64,
    /// Of those, valid ones (confident, not in a blink).
    pub valid: u64,
    /// Smallest valid raw value (√area for area units); NaN when none.
    pub raw_min: f64,
    /// Largest valid raw value; NaN when none.
    pub raw_max: f64,
    /// Median of the valid raw values; NaN when none.
    pub raw_median: f64,
}

impl PhaseSummary {
    /// Valid fraction of the phase's samples (0 when there were none).
    pub fn valid_fraction(&self) -> f64 {
        if self.samples == 0 {
            0.0
        } else {
            self.valid as f64 / self.samples as f64
        }
    }
}

/// Where a session is.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum Progress {
    /// Not started yet.
    Idle,
    /// Showing this phase.
    Running(Phase),
    /// Both phases done: call [`CalibrationSession::finish`].
    Done,
}

/// The calibration routine as a state machine over timed raw pupil samples,
/// so it runs on any source (live, replay, synthetic) and on a virtual
/// clock: the session's time is the samples' time.
pub struct CalibrationSession {
    cfg: CalibrationConfig,
    /// Index into `cfg.order` of the running phase; 2 = done.
    phase_idx: usize,
    phase_start_t: f64,
    started: bool,
    unit: [Option<PupilUnit>; 2],
    /// Valid raw values per phase (order index) and eye.
    values: [[Vec<f64>; 2]; 2],
    /// Samples in the analysis window per phase and eye.
    total: [[u64; 2]; 2],
    blink: [BlinkDetector; 2],
}

impl CalibrationSession {
    /// A new session; the settings are validated.
    pub fn new(cfg: CalibrationConfig) -> Result<Self, CalibrationError> {
        cfg.validate()?;
        Ok(Self {
            cfg,
            phase_idx: 0,
            phase_start_t: 0.0,
            started: false,
            unit: [None; 2],
            values: Default::default(),
            total: [[0; 2]; 2],
            blink: [
                BlinkDetector::new(cfg.blink, 0),
                BlinkDetector::new(cfg.blink, 1),
            ],
        })
    }

    /// Where the session is.
    pub fn progress(&self) -> Progress {
        match (self.started, self.phase_idx) {
            (false, _) => Progress::Idle,
            (true, i) if i < 2 => Progress::Running(self.cfg.order[i]),
            _ => Progress::Done,
        }
    }

    /// Starts the first phase at `t_secs`.
    pub fn start(
        &mut self,
        t_secs: f64,
        sink: &mut dyn StimulusSink,
    ) -> Result<(), CalibrationError> {
        self.started = true;
        self.phase_idx = 0;
        self.phase_start_t = t_secs;
        sink.show(self.cfg.order[0].into(), t_secs)
            .map_err(|e| CalibrationError::Sink(e.0))
    }

    /// Advances the clock to `t_secs`, switching phases (and the stimulus)
    /// when their time is up.
    pub fn tick(
        &mut self,
        t_secs: f64,
        sink: &mut dyn StimulusSink,
    ) -> Result<Progress, CalibrationError> {
        while self.started
            && self.phase_idx < 2
            && t_secs >= self.phase_start_t + self.cfg.phase_duration_s
        {
            self.phase_start_t += self.cfg.phase_duration_s;
            self.phase_idx += 1;
            let stim = if self.phase_idx < 2 {
                self.cfg.order[self.phase_idx].into()
            } else {
                Stimulus::None
            };
            sink.show(stim, self.phase_start_t)
                .map_err(|e| CalibrationError::Sink(e.0))?;
        }
        Ok(self.progress())
    }

    /// Feeds one raw pupil sample (any unit; the first unit seen per eye is
    /// the calibrated one, samples in another unit are ignored).
    pub fn feed(
        &mut self,
        p: &PupilSample,
        sink: &mut dyn StimulusSink,
    ) -> Result<Progress, CalibrationError> {
        if !p.t_secs.is_finite() || p.eye > 1 {
            return Ok(self.progress());
        }
        if !self.started {
            self.start(p.t_secs, sink)?;
        }
        let progress = self.tick(p.t_secs, sink)?;
        let e = p.eye as usize;
        let raw = PupilCalibration::raw_value(p);
        let raw_ok = raw.is_finite() && raw > 0.0;
        let valid_now = raw_ok && self.cfg.confidence.accept(p.confidence);
        self.blink[e].update(p.t_secs, !valid_now);
        let Progress::Running(_) = progress else {
            return Ok(progress);
        };
        let unit = *self.unit[e].get_or_insert(p.unit);
        if unit != p.unit {
            return Ok(progress);
        }
        if p.t_secs < self.phase_start_t + self.cfg.settle_s {
            return Ok(progress);
        }
        let i = self.phase_idx;
        self.total[i][e] += 1;
        if valid_now && !self.blink[e].is_closed() {
            self.values[i][e].push(raw);
        }
        Ok(progress)
    }

    /// Per phase and eye: how many samples fell in the analysis window, how
    /// many were valid, and the range and median of the valid raw values —
    /// what a technician checks before trusting (or rejecting) a profile.
    /// Eyes that never reported are left out.
    pub fn summary(&self) -> Vec<PhaseSummary> {
        let mut out = Vec::new();
        for e in 0..2 {
            let Some(unit) = self.unit[e] else { continue };
            for (i, phase) in self.cfg.order.iter().enumerate() {
                let mut vals = self.values[i][e].clone();
                let (raw_min, raw_max, raw_median) = if vals.is_empty() {
                    (f64::NAN, f64::NAN, f64::NAN)
                } else {
                    let m = median(&mut vals);
                    (vals[0], vals[vals.len() - 1], m)
                };
                out.push(PhaseSummary {
                    eye: e as u8,
                    phase: *phase,
                    unit,
                    samples: self.total[i][e],
                    valid: self.values[i][e].len() as u64,
                    raw_min,
                    raw_max,
                    raw_median,
                });
            }
        }
        out
    }

    /// Computes the calibration: the median of each phase's valid samples per
    /// eye, checked for enough valid samples and for constriction in white.
    /// Eyes that never reported are left out; a session without any samples
    /// fails with `TooFewValidSamples` for eye 0.
    #[allow(clippy::needless_range_loop)] // eye/phase index several arrays at once
    pub fn finish(mut self) -> Result<PupilCalibration, CalibrationError> {
        if self.progress() != Progress::Done {
            return Err(CalibrationError::NotFinished(
                self.cfg.order[self.phase_idx.min(1)],
            ));
        }
        let mut maps: [Option<EyeCalibration>; 2] = [None; 2];
        let any_eye = self.unit.iter().any(Option::is_some);
        for e in 0..2 {
            let Some(unit) = self.unit[e] else { continue };
            let mut medians = [0.0f64; 2];
            for i in 0..2 {
                let total = self.total[i][e];
                let vals = &mut self.values[i][e];
                let frac = if total == 0 {
                    0.0
                } else {
                    vals.len() as f64 / total as f64
                };
                if frac < self.cfg.min_valid_fraction || vals.is_empty() {
                    return Err(CalibrationError::TooFewValidSamples {
                        eye: e as u8,
                        phase: self.cfg.order[i],
                        valid_fraction: frac,
                        required: self.cfg.min_valid_fraction,
                    });
                }
                medians[i] = median(vals);
            }
            let black_i = if self.cfg.order[0] == Phase::Black {
                0
            } else {
                1
            };
            let (black, white) = (medians[black_i], medians[1 - black_i]);
            if white >= black * (1.0 - self.cfg.min_constriction_fraction) {
                return Err(CalibrationError::WhiteNotSmaller {
                    eye: e as u8,
                    black,
                    white,
                });
            }
            maps[e] = Some(EyeCalibration {
                raw_unit: unit,
                raw_black: black,
                raw_white: white,
                mm_min: self.cfg.mm_min,
                mm_max: self.cfg.mm_max,
            });
        }
        if !any_eye {
            return Err(CalibrationError::TooFewValidSamples {
                eye: 0,
                phase: self.cfg.order[0],
                valid_fraction: 0.0,
                required: self.cfg.min_valid_fraction,
            });
        }
        Ok(PupilCalibration {
            schema: SCHEMA.to_owned(),
            description: None,
            observer: Observer::default(),
            eyes: EyeCalibrations {
                right: maps[0],
                left: maps[1],
            },
        })
    }
}

/// Median (sorts in place); `vals` must not be empty.
fn median(vals: &mut [f64]) -> f64 {
    vals.sort_by(f64::total_cmp);
    let n = vals.len();
    if n % 2 == 1 {
        vals[n / 2]
    } else {
        0.5 * (vals[n / 2 - 1] + vals[n / 2])
    }
}

/// Runs a whole calibration over a stream of samples (starting at the first
/// pupil sample), shows `Stimulus::None` at the end, and — only on success —
/// saves the profile to `save_to`. On any error nothing is written.
pub fn run_calibration<I>(
    cfg: CalibrationConfig,
    samples: I,
    sink: &mut dyn StimulusSink,
    save_to: Option<&Path>,
) -> Result<PupilCalibration, CalibrationError>
where
    I: IntoIterator<Item = Sample>,
{
    let mut session = CalibrationSession::new(cfg)?;
    for s in samples {
        let Sample::Pupil(p) = s else { continue };
        if session.feed(&p, sink)? == Progress::Done {
            break;
        }
    }
    let cal = session.finish()?;
    if let Some(path) = save_to {
        cal.save(path)?;
    }
    Ok(cal)
}

/// [`run_calibration`] over an asynchronous [`SampleSource`] (a live
/// tracker, a paced replay): reads samples until both phases are done and
/// shows `Stimulus::None`; only on success saves the profile to `save_to`.
///
/// Bad items of a replay ([`SourceError::Item`]) and transient
/// disconnections are skipped (the phases run on the samples' clock, so a
/// long gap simply ends a phase, and too few valid samples then fail it);
/// a fatal source error or the end of the stream before the end of the
/// session is an error, and nothing is written. The caller bounds the
/// whole run in time (e.g. `tokio::time::timeout`) in case a live source
/// goes silent. A `RemoteSink` (gazelight-pupil) delivers the stimuli
/// asynchronously: `flush` it afterwards to know they all arrived.
pub async fn run_calibration_source<S: SampleSource>(
    cfg: CalibrationConfig,
    source: &mut S,
    sink: &mut (dyn StimulusSink + Send),
    save_to: Option<&Path>,
) -> Result<PupilCalibration, CalibrationError> {
    let mut session = CalibrationSession::new(cfg)?;
    let mut skipped = 0u64;
    loop {
        match source.next().await {
            Ok(Some(Sample::Pupil(p))) => {
                if session.feed(&p, sink)? == Progress::Done {
                    break;
                }
            }
            Ok(Some(_)) => {}
            Ok(None) => {
                return Err(CalibrationError::Source(format!(
                    "{} ended before the calibration finished ({:?})",
                    source.describe(),
                    session.progress()
                )));
            }
            Err(e @ (SourceError::Item { .. } | SourceError::Disconnected { .. })) => {
                skipped += 1;
                if skipped <= 10 || skipped.is_multiple_of(1000) {
                    tracing::warn!(error = %e, skipped, "calibration: source item skipped");
                }
            }
            Err(e @ SourceError::Fatal { .. }) => {
                return Err(CalibrationError::Source(e.to_string()));
            }
        }
    }
    let cal = session.finish()?;
    if let Some(path) = save_to {
        cal.save(path)?;
    }
    Ok(cal)
}
