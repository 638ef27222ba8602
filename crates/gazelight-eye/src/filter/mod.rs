//! The filter chain: raw samples in, [`EyeState`] out.
//!
//! Two quantities come out per eye, never confused (see
//! [`crate::state::EyeChannel`]):
//!
//! **The measured pupil** — per pupil sample of eye `e`:
//!
//! 1. **stream** : one stream per eye is measured — the one in mm when the
//!    tracker gives mm (Pupil Core's 3D detector beside its 2D pixels),
//!    else the one the profile maps, else the first; the others are
//!    counted ([`SampleFate::OtherStream`]);
//! 2. **lost** : below the confidence gate ([`confidence`], 0.6), a raw
//!    value ≤ 0 / NaN, or a millimetre value outside the physiological
//!    range ([`physio`], 1.5–9 mm);
//! 3. **guideline cleaning** ([`clean`]): samples within 50 ms before and
//!    after a lost sample and dilation-speed outliers (median + 16 MAD) are
//!    discarded (Mathôt et al. 2018; Kret & Sjak-Shie 2019); every other
//!    sample is **clean** and passes unchanged, in the tracker's mm, raw ×
//!    a physical scale, or the raw unit. Decisions come out a margin after
//!    the samples ([`FilterChain::set_horizon`] for offline look-ahead).
//!
//! **The model aperture** (the glare PSF's pupil) — from the clean samples:
//! 001 §5's black/white map (not clamped; outside the physiological range
//! counted, then bounded) or the measured mm; then
//!
//! 4. **dropout** ([`dropout`]): the last aperture is held for 0.5 s, then
//!    eases towards the Watson–Yellott pupil ([`crate::pupil_model`]) at the
//!    adaptation luminance fed back with
//!    [`FilterChain::set_adaptation_luminance`];
//! 5. **slew limit** ([`physio::SlewLimiter`]): the aperture never changes
//!    faster than `physio.max_rate_mm_per_s` — it starts *at* the first
//!    measurement (before it, the model's pupil, origin `Default`);
//! 6. **binocular pairing** ([`binocular`]): a partner eye silent for longer
//!    than the pair window is advanced as missing.
//!
//! Blinks (closures) are found from the raw samples ([`blink`]); blink
//! events from the source are counted, not trusted. Gaze samples go through
//! outlier rejection and One Euro smoothing ([`gaze`]).
//!
//! The failure of 001 §7.1 (a tracker returning 0 made the glare flicker)
//! cannot happen: the aperture comes out of the slew limiter, whose input
//! is either a bounded aperture of a clean sample or the model's pupil. The
//! property tests feed random garbage to prove it.
//!
//! No stage allocates on the heap per sample: all state is fixed-size.

pub mod binocular;
pub mod blink;
pub mod clean;
pub mod confidence;
pub mod dropout;
pub mod gaze;
pub mod physio;

use crate::setting::SettingError;
use serde::{Deserialize, Serialize};

use crate::profile::{BadRawPupil, PupilCalibration};
use crate::pupil_model::PupilModel;
use crate::sample::{DetectorMethod, GazeEyes, GazeSample, PupilSample, PupilUnit, Sample};
use crate::state::{EYE_LEFT, EYE_RIGHT, EyeState, PupilOrigin};

pub use binocular::{BinocularConfig, BinocularPairing};
pub use blink::{BlinkConfig, BlinkDetector, Closure, ClosureKind};
pub use clean::{CleanConfig, CleanTrack, SampleFate, TrackSample};
pub use confidence::ConfidenceGate;
pub use dropout::{DropoutConfig, DropoutFill};
pub use gaze::{GazeConfig, GazeFilter, OneEuro, OneEuroConfig};
pub use physio::{PhysioConfig, SlewLimiter};

use std::collections::VecDeque;

/// Default adaptation luminance before the service feeds one back, cd/m²
/// (a dim interior; the model pupil there is ≈ 4.3 mm).
pub const DEFAULT_ADAPTATION_LUMINANCE_CD_M2: f64 = 10.0;

/// Configuration of the whole chain. Every field has a documented default;
/// unknown keys are rejected (`deny_unknown_fields`), so a typo in a config
/// file is an error, not a silently ignored setting.
#[derive(Clone, Copy, Debug, Default, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields, default)]
pub struct FilterConfig {
    pub confidence: ConfidenceGate,
    pub physio: PhysioConfig,
    pub blink: BlinkConfig,
    pub dropout: DropoutConfig,
    /// The guideline cleaning of the measured pupil (margins, speed).
    pub clean: CleanConfig,
    pub gaze: GazeConfig,
    pub binocular: BinocularConfig,
    /// Pupil model for the dropout fallback.
    pub pupil_model: PupilModel,
}

impl FilterConfig {
    /// Checks every stage; the error names the offending field.
    pub fn validate(&self) -> Result<(), SettingError> {
        self.confidence.validate()?;
        self.physio.validate()?;
        self.blink.validate()?;
        self.dropout.validate()?;
        self.clean.validate()?;
        self.gaze.validate()?;
        self.binocular.validate()?;
        self.pupil_model
            .validate()
            .map_err(|e| e.within("pupil_model"))?;
        if self.dropout.ease_rate_mm_per_s > self.physio.max_rate_mm_per_s {
            return Err(SettingError::new(
                "dropout.ease_rate_mm_per_s",
                format!(
                    "({}) must not exceed physio.max_rate_mm_per_s ({})",
                    self.dropout.ease_rate_mm_per_s, self.physio.max_rate_mm_per_s
                ),
            ));
        }
        Ok(())
    }
}

/// Counters of what the chain saw and did, per eye where it matters
/// (index 0 = right, 1 = left).
#[derive(Clone, Copy, Debug, Default, PartialEq, Serialize, Deserialize)]
pub struct ChainStats {
    pub pupil_samples: [u64; 2],
    /// Samples accepted as measurements.
    pub measured: [u64; 2],
    pub rejected_confidence: [u64; 2],
    pub rejected_not_finite: [u64; 2],
    pub rejected_non_positive: [u64; 2],
    pub rejected_range: [u64; 2],
    /// Dilation-speed outliers (median + n·MAD of the speed).
    pub rejected_rate: [u64; 2],
    /// Samples discarded in the margin before or after a lost sample.
    #[serde(default)]
    pub discarded_margin: [u64; 2],
    /// Samples of another stream of the eye than the one measured.
    #[serde(default)]
    pub other_stream: [u64; 2],
    /// Clean samples in raw units with no map onto the aperture (measured
    /// in their raw unit; the aperture follows the model).
    pub uncalibrated: [u64; 2],
    /// Clean samples whose aperture fell outside the physiological range
    /// (bounded to it for the PSF, counted here).
    #[serde(default)]
    pub aperture_out_of_range: [u64; 2],
    /// Samples with an eye id other than 0/1, or a non-finite time.
    pub rejected_bad_sample: u64,
    /// Blinks found by the chain's detector.
    pub blinks: [u64; 2],
    /// Closures too short or too long to be blinks.
    pub dropouts: [u64; 2],
    /// Blink events reported by the source: right, left, both eyes.
    pub source_blinks: [u64; 3],
    pub gaze_samples: u64,
    pub gaze_rejected: u64,
    /// Output pupils that were 0, negative or not finite (must stay 0).
    pub invalid_output: u64,
}

/// How far the output may be from its target and count as settled, mm:
/// a tenth of a millimetre (the glare kernel's rebuild threshold), above
/// the lag the rate limit gives measurement noise (0.02 mm SD samples at
/// 500 Hz stay within ~0.05 mm) and below a blink's or dropout's gap.
const SETTLED_MM: f32 = 0.1;

/// What the chain made of one pupil sample, as a user counts dropouts: a
/// sample in raw units with no calibration for them is neither a
/// measurement nor a dropout (the tracker measured; the chain has no mm
/// for it), e.g. Pupil Core's 2D pixels beside its 3D millimetres.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum PupilOutcome {
    /// Accepted as a measurement.
    Measured,
    /// Rejected: below the confidence gate, no pupil (0, NaN), out of the
    /// physiological range or too fast a change — a dropout.
    Rejected,
    /// In raw units with no calibration for them.
    Uncalibrated,
}

/// The outcomes of one pupil stream (one eye, one detector): the one rule
/// for sample rates and dropouts "as a user means them", shared by the
/// live status and `inspect`'s summary.
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq)]
pub struct PupilStreamCounts {
    pub samples: u64,
    pub measured: u64,
    pub rejected: u64,
    pub uncalibrated: u64,
}

impl PupilStreamCounts {
    /// Detectors a stream table tells apart: Pupil 2D, Pupil 3D, other.
    pub const DETECTORS: usize = 3;

    /// The index of `method` among [`Self::DETECTORS`].
    pub fn detector_index(method: DetectorMethod) -> usize {
        match method {
            DetectorMethod::Pupil2d => 0,
            DetectorMethod::Pupil3d => 1,
            DetectorMethod::Other => 2,
        }
    }

    /// Counts one sample.
    pub fn add(&mut self, outcome: PupilOutcome) {
        self.samples += 1;
        self.add_outcome(outcome);
    }

    /// Counts the outcome of a sample already counted (one decided a
    /// margin after it arrived).
    pub fn add_outcome(&mut self, outcome: PupilOutcome) {
        match outcome {
            PupilOutcome::Measured => self.measured += 1,
            PupilOutcome::Rejected => self.rejected += 1,
            PupilOutcome::Uncalibrated => self.uncalibrated += 1,
        }
    }

    /// Whether the chain can use this stream: no sample in raw units
    /// without a calibration (a calibration holds per unit, so a stream
    /// is usable whole or not at all) and something measured or rejected.
    pub fn usable(&self) -> bool {
        self.uncalibrated == 0 && self.measured + self.rejected > 0
    }

    /// Adds `other` when it is [usable](Self::usable) (an eye's or a
    /// source's total over its usable streams).
    pub fn add_usable(&mut self, other: &Self) {
        if other.usable() {
            self.samples += other.samples;
            self.measured += other.measured;
            self.rejected += other.rejected;
        }
    }

    /// Fraction rejected among the samples the chain could measure; `None`
    /// for a stream it cannot use.
    pub fn dropout_rate(&self) -> Option<f64> {
        self.usable()
            .then(|| self.rejected as f64 / (self.measured + self.rejected) as f64)
    }
}

impl From<SampleFate> for PupilOutcome {
    fn from(f: SampleFate) -> Self {
        match f {
            SampleFate::Clean => Self::Measured,
            SampleFate::OtherStream => Self::Uncalibrated,
            _ => Self::Rejected,
        }
    }
}

/// What one [`FilterChain::push`] did.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct ChainUpdate {
    /// The state after the sample.
    pub state: EyeState,
    /// The eye whose pupil this sample was, if it was a pupil sample.
    pub pupil_eye: Option<u8>,
    /// A closure of this eye that has just been finalised.
    pub closure: Option<Closure>,
}

/// How many decided samples the chain keeps for [`FilterChain::take_decided`]
/// when nobody takes them (the oldest are dropped and counted).
pub const DECIDED_LOG_CAPACITY: usize = 2 * clean::PENDING_CAPACITY;

/// The configured chain with its per-eye state.
#[derive(Clone, Debug)]
pub struct FilterChain {
    cfg: FilterConfig,
    calibration: PupilCalibration,
    blink: [BlinkDetector; 2],
    /// Per eye: the guideline cleaning of the measured pupil.
    clean: [CleanTrack; 2],
    /// Per eye: the stream measured (detector, unit, whether in mm).
    stream: [Option<(DetectorMethod, PupilUnit, bool)>; 2],
    /// Pupil samples pushed so far (their running number).
    seq: u64,
    /// Decisions up to this time are applied to the state (∞ live; the
    /// frame time offline, see [`Self::set_horizon`]).
    horizon: f64,
    /// Decided samples for [`Self::take_decided`], when asked for.
    decided_log: Option<VecDeque<TrackSample>>,
    dropout: [DropoutFill; 2],
    slew: [SlewLimiter; 2],
    /// Per eye: whether the aperture has had its first measurement (the
    /// slew limiter starts there).
    slew_started: [bool; 2],
    /// Per eye: the dropout stage's latest value (the slew limiter's target)
    /// and its origin.
    target: [(f32, PupilOrigin); 2],
    /// The fused (binocular) gaze.
    gaze: GazeFilter,
    last_gaze_t: Option<f64>,
    /// Per eye: monocular gaze, with the time of its last accepted sample.
    eye_gaze: [GazeFilter; 2],
    last_eye_gaze_t: [Option<f64>; 2],
    /// Time of the last binocular gaze sample (accepted or not): while
    /// binocular samples arrive, monocular ones feed only their eye.
    last_binocular_t: Option<f64>,
    pairing: BinocularPairing,
    luminance_cd_m2: f64,
    /// The pupil model's diameter at `luminance_cd_m2` (a `powf` each:
    /// computed when the luminance changes, not per sample).
    model_mm: f32,
    state: EyeState,
    stats: ChainStats,
}

impl FilterChain {
    /// Builds a chain; the configuration is validated.
    pub fn new(cfg: FilterConfig, calibration: PupilCalibration) -> Result<Self, SettingError> {
        cfg.validate()?;
        let model_mm = cfg.pupil_model.pupil_mm(DEFAULT_ADAPTATION_LUMINANCE_CD_M2);
        let mut state = EyeState::default();
        for e in &mut state.eyes {
            e.pupil_mm = model_mm;
        }
        Ok(Self {
            cfg,
            calibration,
            blink: [
                BlinkDetector::new(cfg.blink, 0),
                BlinkDetector::new(cfg.blink, 1),
            ],
            clean: [CleanTrack::new(cfg.clean), CleanTrack::new(cfg.clean)],
            stream: [None; 2],
            seq: 0,
            horizon: f64::INFINITY,
            decided_log: None,
            dropout: [DropoutFill::new(cfg.dropout, model_mm); 2],
            slew: [SlewLimiter::new(cfg.physio.max_rate_mm_per_s, model_mm); 2],
            slew_started: [false; 2],
            target: [(model_mm, PupilOrigin::Default); 2],
            gaze: GazeFilter::new(cfg.gaze),
            last_gaze_t: None,
            eye_gaze: [GazeFilter::new(cfg.gaze); 2],
            last_eye_gaze_t: [None; 2],
            last_binocular_t: None,
            pairing: BinocularPairing::new(cfg.binocular),
            luminance_cd_m2: DEFAULT_ADAPTATION_LUMINANCE_CD_M2,
            model_mm,
            state,
            stats: ChainStats::default(),
        })
    }

    /// A chain with the default configuration and no calibration (sources
    /// in mm only).
    pub fn with_defaults() -> Self {
        Self {
            ..Self::new(FilterConfig::default(), PupilCalibration::identity())
                .unwrap_or_else(|_| unreachable!("the default configuration is valid"))
        }
    }

    /// The adaptation luminance (cd/m²) the vision pipeline currently uses;
    /// the dropout fallback eases towards the model pupil at it.
    pub fn set_adaptation_luminance(&mut self, luminance_cd_m2: f64) {
        if luminance_cd_m2.is_finite() && luminance_cd_m2 >= 0.0 {
            if luminance_cd_m2 != self.luminance_cd_m2 {
                self.model_mm = self.cfg.pupil_model.pupil_mm(luminance_cd_m2);
            }
            self.luminance_cd_m2 = luminance_cd_m2;
        }
    }

    /// Replaces the calibration (e.g. after a calibration run): the
    /// streams are chosen anew.
    pub fn set_calibration(&mut self, calibration: PupilCalibration) {
        self.calibration = calibration;
        for e in 0..2 {
            self.flush_eye(e);
            self.stream[e] = None;
        }
    }

    /// The calibration in use.
    pub fn calibration(&self) -> &PupilCalibration {
        &self.calibration
    }

    pub fn config(&self) -> &FilterConfig {
        &self.cfg
    }
    pub fn state(&self) -> &EyeState {
        &self.state
    }
    pub fn stats(&self) -> &ChainStats {
        &self.stats
    }

    /// Keeps every decided pupil sample for [`Self::take_decided`] (per
    /// sample outputs: `inspect`, Python, the BIDS derivative). Bounded:
    /// take them after each push.
    pub fn keep_decided(&mut self) {
        if self.decided_log.is_none() {
            self.decided_log = Some(VecDeque::with_capacity(DECIDED_LOG_CAPACITY));
        }
    }

    /// The pupil samples decided since the last call, in order (with
    /// [`Self::keep_decided`]; else nothing).
    pub fn take_decided(&mut self) -> impl Iterator<Item = TrackSample> + '_ {
        self.decided_log.iter_mut().flat_map(|log| log.drain(..))
    }

    /// Offline look-ahead: decisions about pupil samples later than
    /// `t_secs` are kept back from the state until the horizon passes them.
    /// A replay pushes its samples a margin ahead of each frame's time and
    /// sets the horizon to the frame's time, so the state at a frame holds
    /// the samples up to it, each decided with the margin after it known.
    /// Live, the horizon stays ∞.
    pub fn set_horizon(&mut self, t_secs: f64) {
        if !t_secs.is_nan() {
            self.horizon = t_secs;
            self.release();
            self.advance_outputs();
        }
    }

    /// Feeds one sample.
    pub fn push(&mut self, sample: &Sample) -> ChainUpdate {
        let mut up = ChainUpdate {
            state: self.state,
            pupil_eye: None,
            closure: None,
        };
        match sample {
            Sample::Pupil(p) => self.push_pupil(p, &mut up),
            Sample::Gaze(g) => {
                self.stats.gaze_samples += 1;
                if g.t_secs.is_finite() {
                    let eye = match g.eyes {
                        GazeEyes::Binocular => None,
                        GazeEyes::Right => Some(EYE_RIGHT),
                        GazeEyes::Left => Some(EYE_LEFT),
                    };
                    if eye.is_none() {
                        self.last_binocular_t = Some(g.t_secs);
                        // An eye whose monocular gaze stopped falls back to
                        // the fused one.
                        for (e, ch) in self.state.eyes.iter_mut().enumerate() {
                            if self.last_eye_gaze_t[e]
                                .is_none_or(|t0| g.t_secs - t0 > self.cfg.gaze.reset_after_s)
                            {
                                ch.gaze_valid = false;
                            }
                        }
                    }
                    // A monocular sample also drives the fused gaze when no
                    // binocular gaze has come lately (a monocular tracker).
                    let fused = eye.is_none()
                        || self
                            .last_binocular_t
                            .is_none_or(|t0| g.t_secs - t0 > self.cfg.gaze.reset_after_s);
                    let mut accepted = false;
                    if let Some(e) = eye {
                        let ch = &mut self.state.eyes[e];
                        accepted |= step_gaze(
                            &mut self.eye_gaze[e],
                            &mut self.last_eye_gaze_t[e],
                            (&mut ch.gaze_uv, &mut ch.gaze_valid),
                            g,
                            self.cfg.gaze.reset_after_s,
                        );
                    }
                    if fused {
                        accepted |= step_gaze(
                            &mut self.gaze,
                            &mut self.last_gaze_t,
                            (&mut self.state.gaze_uv, &mut self.state.gaze_valid),
                            g,
                            self.cfg.gaze.reset_after_s,
                        );
                    }
                    if !accepted {
                        self.stats.gaze_rejected += 1;
                    }
                    self.state.t_secs = self.state.t_secs.max(g.t_secs);
                } else {
                    self.stats.gaze_rejected += 1;
                }
            }
            Sample::Blink(b) => {
                let idx = match b.eye {
                    Some(0) => 0,
                    Some(1) => 1,
                    _ => 2,
                };
                self.stats.source_blinks[idx] += 1;
            }
        }
        self.advance_outputs();
        up.state = self.state;
        up
    }

    /// Steps every eye that has reported towards its target at the chain
    /// clock (`state.t_secs`, monotone), so each aperture changes by at
    /// most `max_rate · Δt` between any two consecutive states.
    fn advance_outputs(&mut self) {
        let now = self.state.t_secs;
        let model_mm = self.model_mm;
        for e in 0..2 {
            if !self.pairing.has_reported(e) {
                continue;
            }
            let (target, origin) = self.target[e];
            let mut out = if self.slew_started[e] {
                self.slew[e].step(now, target)
            } else {
                target
            };
            if !(out.is_finite() && out > 0.0) {
                // Unreachable by construction; counted and replaced so that
                // nothing downstream can ever see it.
                self.stats.invalid_output += 1;
                out = model_mm;
            }
            self.state.eyes[e].pupil_mm = out;
            self.state.eyes[e].pupil_origin = origin;
            self.state.eyes[e].settling = (out - target).abs() > SETTLED_MM;
        }
    }

    /// Ends the stream: decides every pending sample (applied up to the
    /// horizon) and finalises pending closures at `t_secs`.
    pub fn finish(&mut self, t_secs: f64) -> [Option<Closure>; 2] {
        for e in 0..2 {
            self.clean[e].flush();
        }
        self.release();
        self.advance_outputs();
        let mut out = [None; 2];
        for (e, o) in out.iter_mut().enumerate() {
            if let Some(c) = self.blink[e].flush(t_secs) {
                self.count_closure(&c);
                *o = Some(c);
            }
        }
        out
    }

    /// Decides what is pending for a silent source (live: the tracker
    /// stopped delivering), so its last samples reach the state.
    pub fn flush_pending(&mut self) {
        for e in 0..2 {
            self.clean[e].flush();
        }
        self.release();
        self.advance_outputs();
    }

    fn flush_eye(&mut self, e: usize) {
        self.clean[e].flush();
        self.release();
        self.clean[e].reset();
    }

    fn count_closure(&mut self, c: &Closure) {
        let e = c.eye as usize & 1;
        match c.kind {
            ClosureKind::Blink => self.stats.blinks[e] += 1,
            ClosureKind::Dropout => self.stats.dropouts[e] += 1,
        }
    }

    /// The stream of eye `e` a sample belongs to, choosing (or switching
    /// to) it: the stream in mm when the tracker gives mm; else the one the
    /// profile maps onto the aperture; else the first seen.
    fn in_stream(&mut self, e: usize, p: &PupilSample) -> bool {
        let has_mm = p.diameter_mm.is_some() || p.unit == PupilUnit::Mm;
        let key = (p.method, p.unit, has_mm);
        match self.stream[e] {
            Some(k) if k == key => true,
            Some((_, unit, locked_mm)) => {
                let better = (has_mm && !locked_mm)
                    || (has_mm == locked_mm
                        && !self
                            .calibration
                            .eye(p.eye)
                            .is_some_and(|c| c.raw_unit == unit)
                        && self
                            .calibration
                            .eye(p.eye)
                            .is_some_and(|c| c.raw_unit == p.unit));
                if better {
                    // What is pending of the old stream is not this eye's
                    // measurement.
                    self.clean[e].abandon();
                    self.release();
                    self.stream[e] = Some(key);
                }
                better
            }
            None => {
                self.stream[e] = Some(key);
                true
            }
        }
    }

    fn push_pupil(&mut self, p: &PupilSample, up: &mut ChainUpdate) {
        if p.eye > 1 || !p.t_secs.is_finite() {
            self.stats.rejected_bad_sample += 1;
            return;
        }
        let e = p.eye as usize;
        let t = p.t_secs;
        self.stats.pupil_samples[e] += 1;
        up.pupil_eye = Some(p.eye);
        let seq = self.seq;
        self.seq += 1;
        self.state.eyes[e].present = true;

        let raw_ok = p.diameter_raw.is_finite() && p.diameter_raw > 0.0;
        let conf_ok = self.cfg.confidence.accept(p.confidence);
        if let Some(c) = self.blink[e].update(t, !(raw_ok && conf_ok)) {
            self.count_closure(&c);
            up.closure = Some(c);
        }
        self.state.blink = (0..2)
            .filter(|&i| self.state.eyes[i].present)
            .all(|i| self.blink[i].is_closed());
        self.state.eyes[e].confidence = if p.confidence.is_finite() {
            p.confidence.clamp(0.0, 1.0)
        } else {
            0.0
        };

        let (value, unit) = self.calibration.measured(p);
        let mut s = TrackSample {
            seq,
            t_secs: t,
            eye: p.eye,
            method: p.method,
            value,
            unit,
            aperture_mm: f32::NAN,
            fate: SampleFate::Clean,
        };
        if !self.in_stream(e, p) {
            s.fate = SampleFate::OtherStream;
        } else if !conf_ok {
            self.stats.rejected_confidence[e] += 1;
            s.fate = SampleFate::Lost;
        } else {
            match self.calibration.aperture_mm(p) {
                Err(bad) => {
                    let c = match bad {
                        BadRawPupil::NotFinite => &mut self.stats.rejected_not_finite,
                        BadRawPupil::NonPositive => &mut self.stats.rejected_non_positive,
                    };
                    c[e] += 1;
                    s.fate = SampleFate::Lost;
                }
                Ok(aperture) => {
                    s.aperture_mm = aperture.unwrap_or(f32::NAN);
                    if !(value.is_finite() && value > 0.0) {
                        let c = if value.is_finite() {
                            &mut self.stats.rejected_non_positive
                        } else {
                            &mut self.stats.rejected_not_finite
                        };
                        c[e] += 1;
                        s.fate = SampleFate::Lost;
                    } else if unit == PupilUnit::Mm
                        && !(self.cfg.physio.min_pupil_mm..=self.cfg.physio.max_pupil_mm)
                            .contains(&value)
                    {
                        self.stats.rejected_range[e] += 1;
                        s.fate = SampleFate::OutOfRange;
                    }
                }
            }
        }
        self.clean[e].push(s);
        // The state has seen this sample (its decision comes a margin
        // later); offline, not beyond the frame's time.
        self.state.t_secs = self.state.t_secs.max(t.min(self.horizon));
        self.release();
    }

    /// Applies the decided samples of both eyes up to the horizon, in time
    /// order.
    fn release(&mut self) {
        loop {
            let next = match (self.clean[0].ready_t(), self.clean[1].ready_t()) {
                (Some(a), Some(b)) => Some(if b < a { 1 } else { 0 }),
                (Some(_), None) => Some(0),
                (None, Some(_)) => Some(1),
                (None, None) => None,
            };
            let Some(e) = next else { break };
            let Some(t) = self.clean[e].ready_t() else {
                break;
            };
            if t > self.horizon {
                break;
            }
            let Some(d) = self.clean[e].pop_ready() else {
                break;
            };
            self.apply(&d);
            if let Some(log) = &mut self.decided_log {
                if log.len() >= DECIDED_LOG_CAPACITY {
                    log.pop_front();
                }
                log.push_back(d);
            }
        }
    }

    /// One decided sample of eye `d.eye` into the state.
    fn apply(&mut self, d: &TrackSample) {
        let e = usize::from(d.eye & 1);
        let t = d.t_secs;
        let model_mm = self.model_mm;
        match d.fate {
            SampleFate::OtherStream => {
                self.stats.other_stream[e] += 1;
                return;
            }
            SampleFate::Margin => self.stats.discarded_margin[e] += 1,
            SampleFate::Speed => self.stats.rejected_rate[e] += 1,
            _ => {}
        }
        let aperture = if d.fate.is_clean() {
            self.stats.measured[e] += 1;
            let ch = &mut self.state.eyes[e];
            ch.measured = Some(d.value);
            ch.measured_unit = Some(d.unit);
            ch.measured_t_secs = Some(t);
            ch.measured_map_mm =
                (d.unit != PupilUnit::Mm && d.aperture_mm.is_finite()).then_some(d.aperture_mm);
            if d.aperture_mm.is_finite() {
                let (lo, hi) = (self.cfg.physio.min_pupil_mm, self.cfg.physio.max_pupil_mm);
                if !(lo..=hi).contains(&d.aperture_mm) {
                    self.stats.aperture_out_of_range[e] += 1;
                }
                Some(d.aperture_mm.clamp(lo, hi))
            } else {
                self.stats.uncalibrated[e] += 1;
                None
            }
        } else {
            self.state.eyes[e].measured = None;
            self.state.eyes[e].measured_map_mm = None;
            None
        };
        self.target[e] = self.dropout[e].update(t, aperture, model_mm);
        if let Some(a) = aperture
            && !self.slew_started[e]
        {
            // The aperture starts at the first measurement, not at a made-up
            // default.
            self.slew[e] = SlewLimiter::new(self.cfg.physio.max_rate_mm_per_s, a);
            self.slew_started[e] = true;
        }
        self.state.eyes[e].last_valid_t_secs = self.dropout[e].last_good_t_secs();
        if let Some(partner) = self.pairing.observe(e, t) {
            self.target[partner] = self.dropout[partner].update(t, None, model_mm);
            self.state.eyes[partner].measured = None;
            self.state.eyes[partner].measured_map_mm = None;
        }
        self.state.t_secs = self.state.t_secs.max(t);
    }
}

/// Feeds one gaze sample to `filter`; on acceptance writes the smoothed
/// gaze into `out` (position, validity) and notes its time in `last_t`. A
/// rejection clears the validity once no sample was accepted for
/// `reset_after_s`. Returns whether the sample was accepted.
fn step_gaze(
    filter: &mut GazeFilter,
    last_t: &mut Option<f64>,
    out: (&mut [f32; 2], &mut bool),
    g: &GazeSample,
    reset_after_s: f64,
) -> bool {
    let (uv_out, valid) = out;
    match filter.update(g.t_secs, g.gaze_uv, g.confidence) {
        Some(uv) => {
            *uv_out = uv;
            *valid = true;
            *last_t = Some(g.t_secs);
            true
        }
        None => {
            if last_t.is_none_or(|t0| g.t_secs - t0 > reset_after_s) {
                *valid = false;
            }
            false
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::sample::{DetectorMethod, GazeEyes, GazeSample, PupilUnit};

    /// xorshift64* — deterministic garbage.
    struct Rng(u64);
    impl Rng {
        fn next(&mut self) -> u64 {
            self.0 ^= self.0 >> 12;
            self.0 ^= self.0 << 25;
            self.0 ^= self.0 >> 27;
            self.0.wrapping_mul(0x2545_F491_4F6C_DD1D)
        }
        fn f32(&mut self) -> f32 {
            (self.next() >> 40) as f32 / (1u64 << 24) as f32
        }
        fn garbage_f32(&mut self) -> f32 {
            match self.next() % 8 {
                0 => f32::NAN,
                1 => 0.0,
                2 => -self.f32() * 10.0,
                3 => f32::INFINITY,
                4 => self.f32() * 1000.0,
                5 => f32::from_bits(self.next() as u32),
                _ => 2.0 + self.f32() * 6.0,
            }
        }
    }

    fn pupil(t: f64, eye: u8, d: f32, conf: f32) -> Sample {
        Sample::Pupil(PupilSample {
            t_secs: t,
            eye,
            diameter_raw: d,
            unit: PupilUnit::Mm,
            diameter_mm: None,
            confidence: conf,
            norm_pos: [0.5, 0.5],
            method: DetectorMethod::Other,
        })
    }

    fn gaze(t: f64, uv: [f32; 2], eyes: GazeEyes) -> Sample {
        Sample::Gaze(GazeSample {
            t_secs: t,
            gaze_uv: uv,
            confidence: 1.0,
            eyes,
        })
    }

    /// Monocular gaze lands in its own eye, binocular gaze in the fused
    /// state; an eye whose monocular gaze stops falls back to the fused one;
    /// a monocular-only tracker still drives the fused gaze.
    #[test]
    fn monocular_gaze_goes_to_its_eye() {
        let mut chain = FilterChain::with_defaults();
        for i in 0..50 {
            let t = f64::from(i) * 0.005;
            chain.push(&gaze(t, [0.5, 0.5], GazeEyes::Binocular));
            chain.push(&gaze(t, [0.3, 0.5], GazeEyes::Left));
            chain.push(&gaze(t, [0.7, 0.5], GazeEyes::Right));
        }
        let s = chain.state();
        assert!((s.gaze_uv[0] - 0.5).abs() < 1e-4, "{s:?}");
        assert!((s.eye_gaze_uv(EYE_LEFT)[0] - 0.3).abs() < 1e-4, "{s:?}");
        assert!((s.eye_gaze_uv(EYE_RIGHT)[0] - 0.7).abs() < 1e-4, "{s:?}");
        // The monocular streams stop; binocular goes on past the reset time.
        for i in 50..200 {
            chain.push(&gaze(f64::from(i) * 0.005, [0.5, 0.5], GazeEyes::Binocular));
        }
        let s = chain.state();
        assert!(!s.eyes[EYE_LEFT].gaze_valid && !s.eyes[EYE_RIGHT].gaze_valid);
        assert_eq!(s.eye_gaze_uv(EYE_LEFT), s.gaze_uv);
        // Monocular only: the fused gaze follows it.
        let mut chain = FilterChain::with_defaults();
        for i in 0..50 {
            chain.push(&gaze(f64::from(i) * 0.005, [0.2, 0.4], GazeEyes::Right));
        }
        let s = chain.state();
        assert!(s.gaze_valid && (s.gaze_uv[0] - 0.2).abs() < 1e-4, "{s:?}");
        assert!(!s.eyes[EYE_LEFT].gaze_valid);
    }

    #[test]
    fn random_garbage_never_yields_a_zero_nan_or_fast_pupil() {
        for seed in 1..=20u64 {
            let mut rng = Rng(seed.wrapping_mul(0x9E37_79B9_7F4A_7C15));
            let mut chain = FilterChain::with_defaults();
            let max_rate = chain.config().physio.max_rate_mm_per_s;
            let mut prev: [Option<(f64, f32, PupilOrigin)>; 2] = [None; 2];
            let mut t = 0.0f64;
            for _ in 0..20_000 {
                // Mostly forward time, sometimes jumps back or stalls.
                t += match rng.next() % 10 {
                    0 => -0.01,
                    1 => 0.0,
                    2 => 0.5,
                    _ => 0.004,
                };
                let eye = (rng.next() % 3) as u8; // eye 2 is garbage too
                let s = match rng.next() % 6 {
                    0 => Sample::Gaze(GazeSample {
                        t_secs: t,
                        gaze_uv: [rng.garbage_f32(), rng.garbage_f32()],
                        confidence: rng.garbage_f32(),
                        eyes: GazeEyes::Binocular,
                    }),
                    1 => {
                        if rng.next().is_multiple_of(4) {
                            chain.set_adaptation_luminance(rng.garbage_f32() as f64 * 1e4);
                        }
                        pupil(f64::NAN, eye, rng.garbage_f32(), rng.f32())
                    }
                    _ => pupil(t, eye, rng.garbage_f32(), rng.garbage_f32()),
                };
                let up = chain.push(&s);
                for (e, ch) in up.state.eyes.iter().enumerate() {
                    assert!(ch.pupil_mm.is_finite() && ch.pupil_mm > 0.0, "{ch:?}");
                    assert!(ch.pupil_mm >= 1.0 && ch.pupil_mm <= 9.0, "{ch:?}");
                    // The aperture starts at the first measurement: the one
                    // jump allowed is out of the model's default.
                    if let Some((t0, p0, o0)) = prev[e]
                        && o0 != PupilOrigin::Default
                    {
                        let dt = (up.state.t_secs - t0).max(0.0) as f32;
                        assert!(
                            (ch.pupil_mm - p0).abs() <= max_rate * dt + 1e-4,
                            "seed {seed}: eye {e} moved {p0} → {} in {dt} s",
                            ch.pupil_mm
                        );
                    }
                    prev[e] = Some((up.state.t_secs, ch.pupil_mm, ch.pupil_origin));
                }
                assert!(up.state.gaze_uv.iter().all(|v| v.is_finite()));
            }
            assert_eq!(chain.stats().invalid_output, 0);
        }
    }

    #[test]
    fn a_blink_holds_the_pupil_and_is_counted_once() {
        let mut chain = FilterChain::with_defaults();
        let mut t = 0.0;
        let mut step = |chain: &mut FilterChain, d: f32, c: f32| {
            let up = chain.push(&pupil(t, 0, d, c));
            t += 0.005;
            up
        };
        for _ in 0..400 {
            step(&mut chain, 5.0, 0.95);
        }
        let before = chain.state().eyes[0].pupil_mm;
        assert!(
            (before - 5.0).abs() < 1e-3,
            "converged to the measurement: {before}"
        );
        // Pupil-style blink: zeros with stray confident frames.
        for i in 0..40 {
            let up = if i % 13 == 5 {
                step(&mut chain, 5.0, 0.9)
            } else {
                step(&mut chain, 0.0, 0.0)
            };
            assert!((up.state.eyes[0].pupil_mm - 5.0).abs() < 1e-3);
        }
        for _ in 0..40 {
            step(&mut chain, 5.0, 0.95);
        }
        assert_eq!(chain.stats().blinks[0], 1);
        assert_eq!(chain.stats().dropouts[0], 0);
    }

    #[test]
    fn a_long_dropout_eases_to_the_model_pupil() {
        let mut chain = FilterChain::with_defaults();
        chain.set_adaptation_luminance(1000.0);
        let target = chain.config().pupil_model.pupil_mm(1000.0);
        for i in 0..200 {
            chain.push(&pupil(i as f64 * 0.005, 0, 7.0, 1.0));
        }
        let mut t = 1.0;
        let mut origins = Vec::new();
        while t < 20.0 {
            let up = chain.push(&pupil(t, 0, 0.0, 0.0));
            origins.push(up.state.eyes[0].pupil_origin);
            t += 0.01;
        }
        // Decisions come a margin (50 ms) after the samples: the samples
        // before the dropout are discarded as its margin, then held.
        assert_eq!(origins[0], PupilOrigin::Measured);
        assert_eq!(origins[10], PupilOrigin::Held);
        assert_eq!(*origins.last().unwrap(), PupilOrigin::Model);
        assert!((chain.state().eyes[0].pupil_mm - target).abs() < 1e-3);
        assert_eq!(
            chain.stats().dropouts[0] + chain.stats().blinks[0],
            0,
            "still open"
        );
    }

    #[test]
    fn silent_partner_eye_falls_back_while_the_other_reports() {
        let mut chain = FilterChain::with_defaults();
        for i in 0..100 {
            let t = i as f64 * 0.005;
            chain.push(&pupil(t, 0, 4.0, 1.0));
            chain.push(&pupil(t + 0.001, 1, 4.4, 1.0));
        }
        for i in 100..400 {
            chain.push(&pupil(i as f64 * 0.005, 0, 4.0, 1.0));
        }
        let s = chain.state();
        assert_eq!(s.eyes[1].pupil_origin, PupilOrigin::Model);
        assert_eq!(s.eyes[0].pupil_origin, PupilOrigin::Measured);
        assert!(
            (s.pupil_mm() - 4.0).abs() < 1e-3,
            "fused = measured eye only"
        );
    }

    #[test]
    fn config_roundtrips_and_validation_names_fields() {
        let cfg = FilterConfig::default();
        let json = serde_json::to_string(&cfg).unwrap();
        let back: FilterConfig = serde_json::from_str(&json).unwrap();
        assert_eq!(cfg, back);
        let partial: FilterConfig =
            serde_json::from_str(r#"{"confidence": {"min_confidence": 0.8}}"#).unwrap();
        assert_eq!(partial.confidence.min_confidence, 0.8);
        assert_eq!(partial.physio, PhysioConfig::default());
        assert!(serde_json::from_str::<FilterConfig>(r#"{"confidense": {}}"#).is_err());
        let mut bad = cfg;
        bad.physio.max_pupil_mm = 1.0;
        assert!(
            bad.validate()
                .unwrap_err()
                .to_string()
                .contains("physio.max_pupil_mm")
        );
        let mut bad = cfg;
        bad.dropout.ease_rate_mm_per_s = 10.0;
        assert!(
            bad.validate()
                .unwrap_err()
                .to_string()
                .contains("ease_rate")
        );
    }
}
