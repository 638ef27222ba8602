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
//! The profile this produces (the per-eye map, the observer, the JSON
//! file) is [`crate::profile`].
//!
//! The routine that produces a profile is [`CalibrationSession`]: a state
//! machine fed timed raw pupil samples from any source, driving a
//! [`StimulusSink`].

use std::path::Path;

use serde::{Deserialize, Serialize};

use crate::profile::{
    DEFAULT_MM_MAX, DEFAULT_MM_MIN, EyeCalibration, EyeCalibrations, Observer, ProfileError,
    PupilCalibration, SCHEMA,
};

use crate::filter::{BlinkConfig, BlinkDetector, ConfidenceGate};
use crate::sample::{PupilSample, PupilUnit, Sample};
use crate::setting::SettingError;
use crate::source::{SampleSource, SourceError};

/// Errors of loading, saving and running a calibration.
#[derive(Debug, thiserror::Error)]
pub enum CalibrationError {
    /// Loading or saving the profile failed.
    #[error(transparent)]
    Profile(#[from] ProfileError),
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
    Config(#[from] SettingError),
    #[error("stimulus display failed: {0}")]
    Sink(String),
    #[error("the calibration session is not finished (phase {0:?})")]
    NotFinished(Phase),
    /// The sample source failed for good (or ended) during the session.
    #[error("sample source: {0}")]
    Source(String),
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
        let bad = |field: &str, reason: String| {
            Err(CalibrationError::Config(SettingError::new(field, reason)))
        };
        if self.order[0] == self.order[1] {
            return bad("order", "must hold black and white once each".into());
        }
        if !(self.phase_duration_s.is_finite() && self.phase_duration_s > 0.0) {
            return bad(
                "phase_duration_s",
                format!("must be > 0, got {}", self.phase_duration_s),
            );
        }
        if !(self.settle_s.is_finite()
            && self.settle_s >= 0.0
            && self.settle_s < self.phase_duration_s)
        {
            return bad(
                "settle_s",
                format!(
                    "must be within 0..phase_duration_s ({}), got {}",
                    self.phase_duration_s, self.settle_s
                ),
            );
        }
        if !(0.0..=1.0).contains(&self.min_valid_fraction) {
            return bad(
                "min_valid_fraction",
                format!("must be within 0..=1, got {}", self.min_valid_fraction),
            );
        }
        if !(0.0..1.0).contains(&self.min_constriction_fraction) {
            return bad(
                "min_constriction_fraction",
                format!(
                    "must be within 0..1, got {}",
                    self.min_constriction_fraction
                ),
            );
        }
        if !(self.mm_min > 0.0 && self.mm_max > self.mm_min && self.mm_max.is_finite()) {
            return bad(
                "mm_min",
                format!(
                    "must be > 0 and < mm_max, got mm_min {} mm_max {}",
                    self.mm_min, self.mm_max
                ),
            );
        }
        self.confidence.validate()?;
        self.blink.validate()?;
        Ok(())
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
    /// Phase windows on the samples' clock `[start, end)`, in the order of
    /// `cfg.order` ([`Self::with_windows`]: a recording's own dark and
    /// bright stretches); `None` for a timed, stimulus-driven session.
    windows: Option<[(f64, f64); 2]>,
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
            windows: None,
        })
    }

    /// A session over a recording's own dark (`black_secs`) and bright
    /// (`white_secs`) stretches, `[start, end)` on the samples' clock: the
    /// phases are these windows (no stimulus, no settling time; choose
    /// windows after the pupil has settled), the rest as in a timed
    /// session. [`Self::finish`] may be called once the samples are
    /// exhausted. Windows that are empty, not finite or overlapping are an
    /// error naming them.
    pub fn with_windows(
        cfg: CalibrationConfig,
        black_secs: (f64, f64),
        white_secs: (f64, f64),
    ) -> Result<Self, CalibrationError> {
        for (name, (a, b)) in [("black", black_secs), ("white", white_secs)] {
            if !(a.is_finite() && b.is_finite() && a < b) {
                return Err(CalibrationError::Config(SettingError::new(
                    format!("{name} window"),
                    format!("{a}..{b}: expected FROM..TO with FROM < TO, seconds"),
                )));
            }
        }
        if black_secs.0 < white_secs.1 && white_secs.0 < black_secs.1 {
            return Err(CalibrationError::Config(SettingError::new(
                "black and white windows",
                format!(
                    "{}..{} and {}..{} overlap",
                    black_secs.0, black_secs.1, white_secs.0, white_secs.1
                ),
            )));
        }
        let mut cfg = cfg;
        cfg.settle_s = 0.0;
        let mut session = Self::new(cfg)?;
        session.started = true;
        session.windows = Some(if cfg.order[0] == Phase::Black {
            [black_secs, white_secs]
        } else {
            [white_secs, black_secs]
        });
        Ok(session)
    }

    /// [`Self::feed`] of a windowed session.
    fn feed_windowed(&mut self, p: &PupilSample, windows: [(f64, f64); 2]) -> Progress {
        let e = p.eye as usize;
        let raw = PupilCalibration::raw_value(p);
        let valid_now = raw.is_finite() && raw > 0.0 && self.cfg.confidence.accept(p.confidence);
        self.blink[e].update(p.t_secs, !valid_now);
        if p.t_secs >= windows[0].1.max(windows[1].1) {
            self.phase_idx = 2;
        }
        let Some(i) = (0..2).find(|&i| p.t_secs >= windows[i].0 && p.t_secs < windows[i].1) else {
            return self.progress();
        };
        let unit = *self.unit[e].get_or_insert(p.unit);
        if unit != p.unit {
            return self.progress();
        }
        self.total[i][e] += 1;
        if valid_now && !self.blink[e].is_closed() {
            self.values[i][e].push(raw);
        }
        self.progress()
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
        if let Some(windows) = self.windows {
            return Ok(self.feed_windowed(p, windows));
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
        if self.windows.is_none() && self.progress() != Progress::Done {
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
                kind: crate::profile::MapKind::Aperture,
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

#[cfg(test)]
mod window_tests {
    use super::*;
    use crate::sample::DetectorMethod;

    fn sample(t_secs: f64, eye: u8, raw: f32) -> PupilSample {
        PupilSample {
            t_secs,
            eye,
            diameter_raw: raw,
            unit: PupilUnit::Px,
            diameter_mm: None,
            confidence: 0.95,
            norm_pos: [0.5, 0.5],
            method: DetectorMethod::Pupil2d,
        }
    }

    /// A recording's dark stretch (raw 60 px) and bright stretch (30 px),
    /// with other values outside both windows: the windows alone give the
    /// medians, mapped to 8 and 2 mm.
    #[test]
    fn windows_take_the_medians_of_their_stretches() {
        let mut s = CalibrationSession::with_windows(
            CalibrationConfig::default(),
            (10.0, 15.0),
            (20.0, 25.0),
        )
        .unwrap();
        let mut sink = LogSink::default();
        for i in 0..3000 {
            let t = i as f64 * 0.01;
            let raw = if (10.0..15.0).contains(&t) {
                60.0
            } else if (20.0..25.0).contains(&t) {
                30.0
            } else {
                45.0
            };
            for eye in 0..2 {
                s.feed(&sample(t, eye, raw), &mut sink).unwrap();
            }
        }
        let p = s.finish().unwrap();
        let right = p.eyes.right.unwrap();
        assert_eq!((right.raw_black, right.raw_white), (60.0, 30.0));
        assert!((right.map(45.0).unwrap() - 5.0).abs() < 1e-9);
        assert!(
            sink.shown.is_empty(),
            "a windowed session shows no stimulus"
        );
    }

    #[test]
    fn bad_windows_are_refused() {
        let cfg = CalibrationConfig::default();
        assert!(CalibrationSession::with_windows(cfg, (15.0, 10.0), (20.0, 25.0)).is_err());
        assert!(CalibrationSession::with_windows(cfg, (10.0, 21.0), (20.0, 25.0)).is_err());
        assert!(CalibrationSession::with_windows(cfg, (f64::NAN, 1.0), (2.0, 3.0)).is_err());
    }
}
