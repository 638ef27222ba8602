//! The live eye task: the one place an `EyeState` is filtered.
//!
//! [`spawn`] runs any [`SampleSource`] (what [`crate::open::open_with`]
//! returns for every URI, Pupil included) through a [`LiveChain`] — the
//! filter chain of `gazelight-eye` followed by the stale → model fallback —
//! and publishes:
//! - the latest [`LiveEyeState`] on a `watch` channel (readers `borrow()`
//!   it and never wait: the frame loop reads it every frame);
//! - every sample the chain consumed on a bounded `broadcast` (recorders,
//!   the relay, LSL, telemetry): a receiver that lags loses the oldest
//!   samples and learns how many (`RecvError::Lagged`), the sender never
//!   waits;
//! - the source's [`SourceStatus`] (health, rate, confidence, dropout rate
//!   by the chain's own rule, counters, and the counters of the source's
//!   clock mapping, [`gazelight_eye::clock::SourceClock`]: jumps, rejected
//!   time stamps).
//!
//! A source is [`SourceHealth::Degraded`] (with a reason in the status and
//! a warning in the log) while its measured pupils are being discarded:
//! when over the last second most of the pupils the chain measured arrived
//! older than [`STALE_AFTER_SECS`] by their time stamps (so the state was
//! stale and the pupil came from the fallback), or when its clock mapping
//! rejected more time stamps than it delivered. It is `Live` again after a
//! second without either.
//!
//! The stale → model fallback: when no sample has made the state fresh for
//! [`STALE_AFTER_SECS`] (the tracker vanished), the pupil is filled the
//! way the chain fills a dropout — the last pupil is held for
//! `dropout.hold_s`, then eases towards the Watson–Yellott pupil at the
//! adaptation luminance the frame loop feeds back ([`AdaptationCell`]) —
//! and the output's rate is limited at `physio.max_rate_mm_per_s`, so
//! glare neither freezes on a lost tracker nor jumps when it returns. The
//! task steps it every [`LiveConfig::tick`] while no samples arrive.
//!
//! Offline (`render`, `replay`) the same [`LiveChain`] runs on the
//! recording's clock: [`LiveChain::state_at`] with the frame's time, so a
//! replay is deterministic.

use std::sync::atomic::{AtomicU64, Ordering};
use std::sync::{Arc, Mutex, MutexGuard};
use std::time::Duration;

use gazelight_eye::clock::{ClockStats, host_now_secs};
use gazelight_eye::filter::{
    ChainStats, ChainUpdate, DEFAULT_ADAPTATION_LUMINANCE_CD_M2, DropoutFill, FilterChain,
    PupilOutcome, PupilStreamCounts, SlewLimiter, TrackSample,
};
use gazelight_eye::pupil_model::PupilModel;
use gazelight_eye::source::{SampleSource, SourceError};
use gazelight_eye::{EYE_LEFT, EYE_RIGHT, EyeState, GazeEyes, LiveEyeState, PupilOrigin, Sample};
use serde::Serialize;
use tokio::sync::{broadcast, watch};
use tokio::task::JoinHandle;

/// An `EyeState` older than this is stale: the tracker is not delivering.
/// The same bound as the oldest a live source's clock mapping delivers a
/// sample ([`gazelight_eye::clock::DEFAULT_MAX_AGE_SECS`]), so a sample it
/// delivers is fresh on arrival.
pub const STALE_AFTER_SECS: f64 = gazelight_eye::clock::DEFAULT_MAX_AGE_SECS;
/// Capacity of the sample broadcast (≈ 4 s at 1 kHz).
pub const SAMPLE_BROADCAST_CAPACITY: usize = 4096;

/// Which clock the `EyeState`'s age is measured on.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum AgeClock {
    /// `EyeState::t_secs` is host time (live sources that align clocks):
    /// age = now − time of the newest sample, transport included.
    SampleTime,
    /// The state's times are on a recording's or device's clock: age =
    /// now − when the task published the newest sample's state.
    PublishTime,
}

impl AgeClock {
    /// Age of `live` at host time `now_host_secs`, s (never negative).
    pub fn age_secs(self, live: &LiveEyeState, now_host_secs: f64) -> f64 {
        match self {
            AgeClock::SampleTime => now_host_secs - live.state.t_secs,
            AgeClock::PublishTime => now_host_secs - live.updated_host_secs,
        }
        .max(0.0)
    }
}

/// The adaptation luminance the frame loop feeds back to the pupil
/// fallback (cd/m², stored as `f64` bits; NaN = none yet). Lock-free, no
/// allocation.
#[derive(Debug)]
pub struct AdaptationCell(AtomicU64);

impl Default for AdaptationCell {
    fn default() -> Self {
        Self(AtomicU64::new(f64::NAN.to_bits()))
    }
}

impl AdaptationCell {
    /// Stores the newest adaptation luminance.
    pub fn set(&self, luminance_cd_m2: f64) {
        self.0.store(luminance_cd_m2.to_bits(), Ordering::Relaxed);
    }

    /// The newest value, if any.
    pub fn get(&self) -> Option<f64> {
        let v = f64::from_bits(self.0.load(Ordering::Relaxed));
        v.is_finite().then_some(v)
    }
}

/// Health of the tracker source.
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq, Serialize)]
#[serde(rename_all = "snake_case")]
pub enum SourceHealth {
    /// Not connected yet.
    #[default]
    Connecting,
    /// Samples are arriving.
    Live,
    /// Samples are arriving but their measured pupils are being discarded
    /// (too old by their time stamps, or their time stamps rejected):
    /// [`SourceStatus::degraded_reason`] says why.
    Degraded,
    /// The source was connected and is gone (the service keeps running).
    Lost,
    /// A finite source (a replay) has ended.
    Ended,
}

/// Source-side counters, written by the live task.
#[derive(Clone, Debug, Default, PartialEq, Serialize)]
pub struct SourceStatus {
    /// The source URI (`pupil://127.0.0.1:50020`, `replay://…`).
    pub uri: String,
    pub health: SourceHealth,
    /// The tracker's rate over the last second, as a user means it: the
    /// rate of its fastest stream (one eye's pupils from one detector, or
    /// one kind of gaze), so a 200 Hz tracker reads 200 Hz however many
    /// streams it sends. Each stream's own rate is in [`Self::streams`].
    pub sample_rate_hz: f64,
    /// Mean confidence of the samples over the last second.
    pub confidence: f64,
    /// Fraction of the pupil samples over the last second that were
    /// dropouts: rejected by the filter (blink, low confidence, no pupil,
    /// out of range, too fast). Samples in raw units without a
    /// calibration are not dropouts (Pupil Core's 2D pixels beside its 3D
    /// millimetres); 1 when no pupil could be measured at all.
    pub dropout_rate: f64,
    /// Per eye (0 right, 1 left): the rate of that eye's fastest pupil
    /// stream over the last second, Hz.
    pub eye_rate_hz: [f64; 2],
    /// Per eye: [`Self::dropout_rate`] of that eye's pupils; `None` when
    /// it sent none the chain could measure.
    pub eye_dropout_rate: [Option<f64>; 2],
    /// Every stream seen in the last second, pupils by eye and detector,
    /// then gaze.
    pub streams: Vec<StreamStatus>,
    /// Samples received since start.
    pub samples_total: u64,
    /// Samples dropped by bounded queues since start.
    pub samples_dropped: u64,
    /// Re-connections since start.
    pub reconnects: u64,
    /// Why the source was last lost, if it was.
    pub last_error: Option<String>,
    /// Why the source is [`SourceHealth::Degraded`], while it is.
    pub degraded_reason: Option<String>,
    /// The source's clock mapping (jumps, rejected and non-finite time
    /// stamps, measurements); `None` for sources without one (replays, the
    /// synthetic trace).
    pub clock: Option<ClockStats>,
}

/// One stream of a source over the last second.
#[derive(Clone, Debug, PartialEq, Serialize)]
pub struct StreamStatus {
    /// `pupil 3d right (0)`, `pupil 2d left (1)`, `pupil right (0)` (other
    /// detectors), `gaze binocular`, `gaze right (0)`.
    pub name: &'static str,
    /// The eye (0 right, 1 left); `None` for binocular gaze.
    pub eye: Option<u8>,
    /// Samples per second.
    pub rate_hz: f64,
    /// Fraction of the samples rejected by the filter; `None` for gaze and
    /// for a stream in raw units with no calibration.
    pub dropout_rate: Option<f64>,
    /// Samples in raw units with no calibration for them: the tracker
    /// measured, the chain has no millimetres for them.
    pub uncalibrated: u64,
}

/// Pupil streams per eye: detector Pupil 2D, Pupil 3D, other.
const PUPIL_STREAM_NAMES: [[&str; 3]; 2] = [
    [
        "pupil 2d right (0)",
        "pupil 3d right (0)",
        "pupil right (0)",
    ],
    ["pupil 2d left (1)", "pupil 3d left (1)", "pupil left (1)"],
];
/// Gaze streams: binocular, right, left.
const GAZE_STREAM_NAMES: [&str; 3] = ["gaze binocular", "gaze right (0)", "gaze left (1)"];

/// The source status, shared between the live task and its readers.
pub type SharedStatus = Arc<Mutex<SourceStatus>>;

/// Locks a shared status (a poisoned lock only means a panic elsewhere;
/// the data is plain values).
pub fn lock_status(s: &Mutex<SourceStatus>) -> MutexGuard<'_, SourceStatus> {
    s.lock().unwrap_or_else(|p| p.into_inner())
}

/// The filter chain followed by the stale → model fallback: the one chain
/// every `EyeState` goes through, live and offline.
#[derive(Clone, Debug)]
pub struct LiveChain {
    chain: FilterChain,
    model: PupilModel,
    fill: [DropoutFill; 2],
    slew: [SlewLimiter; 2],
    /// Per eye: whether the fallback's limiter has started (at the chain's
    /// first aperture, never from a made-up default).
    slew_started: [bool; 2],
    luminance_cd_m2: Option<f64>,
    stale_after_secs: f64,
    max_rate_mm_per_s: f32,
}

impl LiveChain {
    /// Wraps `chain`; the fallback uses its dropout, physiology and pupil
    /// model settings.
    pub fn new(chain: FilterChain) -> Self {
        let cfg = *chain.config();
        let model_mm = cfg.pupil_model.pupil_mm(DEFAULT_ADAPTATION_LUMINANCE_CD_M2);
        Self {
            model: cfg.pupil_model,
            fill: [DropoutFill::new(cfg.dropout, model_mm); 2],
            slew: [SlewLimiter::new(cfg.physio.max_rate_mm_per_s, model_mm); 2],
            slew_started: [false; 2],
            luminance_cd_m2: None,
            stale_after_secs: STALE_AFTER_SECS,
            max_rate_mm_per_s: cfg.physio.max_rate_mm_per_s,
            chain,
        }
    }

    /// The adaptation luminance (cd/m²) the vision pipeline uses now: the
    /// chain's dropout stage and the fallback ease towards the model pupil
    /// at it.
    pub fn set_adaptation_luminance(&mut self, luminance_cd_m2: f64) {
        if luminance_cd_m2.is_finite()
            && luminance_cd_m2 >= 0.0
            && self.luminance_cd_m2 != Some(luminance_cd_m2)
        {
            self.chain.set_adaptation_luminance(luminance_cd_m2);
            self.luminance_cd_m2 = Some(luminance_cd_m2);
        }
    }

    /// Feeds one sample to the filter chain.
    pub fn push(&mut self, sample: &Sample) -> ChainUpdate {
        self.chain.push(sample)
    }

    /// Keeps the chain's decided pupil samples for [`Self::take_decided`].
    pub fn keep_decided(&mut self) {
        self.chain.keep_decided();
    }

    /// The pupil samples the chain decided since the last call.
    pub fn take_decided(&mut self) -> impl Iterator<Item = TrackSample> + '_ {
        self.chain.take_decided()
    }

    /// Offline look-ahead ([`FilterChain::set_horizon`]).
    pub fn set_horizon(&mut self, t_secs: f64) {
        self.chain.set_horizon(t_secs);
    }

    /// Ends the stream ([`FilterChain::finish`]).
    pub fn finish(&mut self, t_secs: f64) {
        self.chain.finish(t_secs);
    }

    /// Decides the chain's pending samples ([`FilterChain::flush_pending`]).
    pub fn flush_pending(&mut self) {
        self.chain.flush_pending();
    }

    /// How old the state may be before the fallback takes over, s
    /// ([`STALE_AFTER_SECS`] by default; ∞ for a trace, whose pupil holds
    /// between its rows).
    pub fn set_stale_after_secs(&mut self, secs: f64) {
        if secs > 0.0 {
            self.stale_after_secs = secs;
        }
    }

    /// The chain's counters.
    pub fn stats(&self) -> &ChainStats {
        self.chain.stats()
    }

    /// The filter chain.
    pub fn chain(&self) -> &FilterChain {
        &self.chain
    }

    /// The state at `now_secs` (the clock the fallback runs on: host time
    /// live, the recording's offline) when the chain's state is `age_secs`
    /// old after `updates` samples: the chain's state, with each pupil
    /// passed through the fallback (held, then eased to the model while
    /// stale) and rate-limited.
    pub fn state_at(&mut self, now_secs: f64, age_secs: f64, updates: u64) -> EyeState {
        let mut state = *self.chain.state();
        let fresh = updates > 0 && age_secs <= self.stale_after_secs;
        let model_mm = self.model.pupil_mm(
            self.luminance_cd_m2
                .unwrap_or(DEFAULT_ADAPTATION_LUMINANCE_CD_M2),
        );
        for e in [EYE_RIGHT, EYE_LEFT] {
            let ch = &mut state.eyes[e];
            let measured =
                (fresh && ch.pupil_origin != PupilOrigin::Default).then_some(ch.pupil_mm);
            let (filled, origin) = self.fill[e].update(now_secs, measured, model_mm);
            let target = if fresh { ch.pupil_mm } else { filled };
            if !self.slew_started[e] && ch.pupil_origin != PupilOrigin::Default {
                self.slew[e] = SlewLimiter::new(self.max_rate_mm_per_s, ch.pupil_mm);
                self.slew_started[e] = true;
            }
            ch.pupil_mm = if self.slew_started[e] {
                self.slew[e].step(now_secs, target)
            } else {
                target
            };
            if !fresh {
                ch.pupil_origin = origin;
                // Stale: nothing is measured now, whatever was last.
                ch.measured = None;
                ch.measured_map_mm = None;
            }
        }
        state
    }
}

/// Settings of the live task.
#[derive(Clone, Copy, Debug)]
pub struct LiveConfig {
    /// How often the source status is published.
    pub status_period: Duration,
    /// How often the fallback is stepped while no samples arrive.
    pub tick: Duration,
    /// A source silent this long is reported Lost, s.
    pub silent_lost_secs: f64,
    /// Capacity of the sample broadcast.
    pub broadcast_capacity: usize,
}

impl Default for LiveConfig {
    fn default() -> Self {
        Self {
            status_period: Duration::from_millis(250),
            tick: Duration::from_millis(10),
            silent_lost_secs: 1.0,
            broadcast_capacity: SAMPLE_BROADCAST_CAPACITY,
        }
    }
}

/// A running live eye task: what it publishes, and the task.
pub struct LiveEye {
    /// The latest state (`borrow()` it; never waits).
    pub eye: watch::Receiver<LiveEyeState>,
    /// The samples the chain consumed (`subscribe()`).
    pub samples: broadcast::Sender<Sample>,
    /// The source status.
    pub status: SharedStatus,
    /// Where the frame loop stores the adaptation luminance.
    pub adaptation: Arc<AdaptationCell>,
    /// Which clock the state's age is measured on.
    pub age_clock: AgeClock,
    /// The source, in one line.
    pub describe: String,
    /// The task; it ends at the end of the stream, on a fatal error or
    /// when `shutdown` turns true.
    pub task: JoinHandle<()>,
}

/// Starts the live eye task for `source` (named `uri` in the status).
/// Must be called inside a tokio runtime.
pub fn spawn<S: SampleSource + 'static>(
    uri: &str,
    source: S,
    chain: FilterChain,
    age_clock: AgeClock,
    shutdown: watch::Receiver<bool>,
    config: LiveConfig,
) -> LiveEye {
    let initial = LiveEyeState {
        state: *chain.state(),
        updated_host_secs: host_now_secs(),
        updates: 0,
    };
    let (eye_tx, eye) = watch::channel(initial);
    let (samples, _) = broadcast::channel(config.broadcast_capacity.max(1));
    let status = Arc::new(Mutex::new(SourceStatus {
        uri: uri.to_owned(),
        ..SourceStatus::default()
    }));
    let adaptation = Arc::new(AdaptationCell::default());
    let describe = source.describe();
    let task = tokio::spawn(
        Task {
            source,
            chain: {
                let mut live = LiveChain::new(chain);
                live.keep_decided();
                live
            },
            age_clock,
            config,
            eye_tx,
            samples: samples.clone(),
            status: status.clone(),
            adaptation: adaptation.clone(),
            shutdown,
        }
        .run(),
    );
    LiveEye {
        eye,
        samples,
        status,
        adaptation,
        age_clock,
        describe,
        task,
    }
}

/// Rate, confidence, dropout and discarded pupils over a window of about
/// a second.
#[derive(Debug, Default)]
struct RateWindow {
    start_secs: f64,
    samples: u64,
    confidence_sum: f64,
    /// Per eye and detector (Pupil 2D, Pupil 3D, other).
    pupil: [[PupilStreamCounts; PupilStreamCounts::DETECTORS]; 2],
    /// Gaze: binocular, right, left.
    gaze: [u64; 3],
    /// Pupils the chain measured.
    measured: u64,
    /// Of those, the ones after which the state was stale (the pupil came
    /// from the fallback), and the oldest of them, s.
    measured_stale: u64,
    stale_age_max_secs: f64,
    /// The source's clock counters when the window started.
    clock_at_start: Option<ClockStats>,
    last_sample_secs: Option<f64>,
}

impl RateWindow {
    fn new(now: f64, clock: Option<ClockStats>) -> Self {
        Self {
            start_secs: now,
            clock_at_start: clock,
            ..Self::default()
        }
    }

    /// One sample as it arrived.
    fn add(&mut self, now: f64, sample: &Sample) {
        self.samples += 1;
        let confidence = sample_confidence(sample);
        if confidence.is_finite() {
            self.confidence_sum += f64::from(confidence.clamp(0.0, 1.0));
        }
        match sample {
            Sample::Pupil(p) => {
                // Counted as it arrives; its outcome when it is decided.
                if let Some(eye) = self.pupil.get_mut(usize::from(p.eye)) {
                    eye[PupilStreamCounts::detector_index(p.method)].samples += 1;
                }
            }
            Sample::Gaze(g) => {
                let k = match g.eyes {
                    GazeEyes::Binocular => 0,
                    GazeEyes::Right => 1,
                    GazeEyes::Left => 2,
                };
                self.gaze[k] += 1;
            }
            Sample::Blink(_) => {}
        }
        self.last_sample_secs = Some(now);
    }

    /// One pupil sample as the chain decided it (a margin after it
    /// arrived), and the state's age when that was stale.
    fn add_decided(&mut self, d: &TrackSample, stale_age: Option<f64>) {
        let Some(eye) = self.pupil.get_mut(usize::from(d.eye)) else {
            return;
        };
        let outcome = PupilOutcome::from(d.fate);
        eye[PupilStreamCounts::detector_index(d.method)].add_outcome(outcome);
        if outcome == PupilOutcome::Measured {
            self.measured += 1;
            if let Some(age) = stale_age {
                self.measured_stale += 1;
                self.stale_age_max_secs = self.stale_age_max_secs.max(age);
            }
        }
    }

    /// Rates and dropouts per stream, per eye and overall into `s`.
    fn publish_streams(&self, elapsed: f64, s: &mut SourceStatus) {
        let rate = |n: u64| n as f64 / elapsed;
        s.streams.clear();
        let mut all = PupilStreamCounts::default();
        let mut any_pupil = false;
        let mut fastest = 0u64;
        for (e, eye) in self.pupil.iter().enumerate() {
            let mut this_eye = PupilStreamCounts::default();
            let mut eye_fastest = 0u64;
            for (m, c) in eye.iter().enumerate() {
                if c.samples == 0 {
                    continue;
                }
                this_eye.add_usable(c);
                eye_fastest = eye_fastest.max(c.samples);
                s.streams.push(StreamStatus {
                    name: PUPIL_STREAM_NAMES[e][m],
                    eye: Some(e as u8),
                    rate_hz: rate(c.samples),
                    dropout_rate: c.dropout_rate(),
                    uncalibrated: c.uncalibrated,
                });
            }
            all.add_usable(&this_eye);
            any_pupil |= eye.iter().any(|c| c.samples > 0);
            fastest = fastest.max(eye_fastest);
            s.eye_rate_hz[e] = rate(eye_fastest);
            s.eye_dropout_rate[e] = this_eye.dropout_rate();
        }
        for (k, &n) in self.gaze.iter().enumerate() {
            if n == 0 {
                continue;
            }
            fastest = fastest.max(n);
            s.streams.push(StreamStatus {
                name: GAZE_STREAM_NAMES[k],
                eye: [None, Some(EYE_RIGHT as u8), Some(EYE_LEFT as u8)][k],
                rate_hz: rate(n),
                dropout_rate: None,
                uncalibrated: 0,
            });
        }
        s.sample_rate_hz = rate(fastest);
        s.dropout_rate = match all.dropout_rate() {
            Some(d) => d,
            // Pupils, none measurable; or nothing at all.
            None if any_pupil || self.samples == 0 => 1.0,
            None => 0.0,
        };
    }

    /// Publishes the window into `s` when it has run ≥ 1 s (then restarts
    /// it) and returns `Some(why the source is degraded, if it is)`; always
    /// updates the running total.
    fn publish(
        &mut self,
        now: f64,
        s: &mut SourceStatus,
        total: u64,
        clock: Option<ClockStats>,
    ) -> Option<Option<String>> {
        let elapsed = now - self.start_secs;
        s.samples_total = total;
        if elapsed < 1.0 {
            return None;
        }
        let n = self.samples;
        s.confidence = if n > 0 {
            self.confidence_sum / n as f64
        } else {
            0.0
        };
        self.publish_streams(elapsed, s);
        let degraded = self.degraded_reason(clock);
        let last = self.last_sample_secs;
        *self = Self::new(now, clock);
        self.last_sample_secs = last;
        Some(degraded)
    }

    /// Why the measured pupils of this window were discarded, if most were.
    fn degraded_reason(&self, clock: Option<ClockStats>) -> Option<String> {
        if self.measured > 0 && 2 * self.measured_stale > self.measured {
            return Some(format!(
                "{} of {} measured pupils in the last second were up to {:.2} s old by their \
                 time stamps (older than {STALE_AFTER_SECS} s): not used, the pupil is held or \
                 eased to the model",
                self.measured_stale, self.measured, self.stale_age_max_secs
            ));
        }
        if let (Some(a), Some(b)) = (self.clock_at_start, clock) {
            let rejected = (b.rejected + b.non_finite).saturating_sub(a.rejected + a.non_finite);
            let mapped = b.mapped.saturating_sub(a.mapped);
            if rejected > 0 && rejected >= mapped {
                return Some(format!(
                    "{rejected} of {} time stamps in the last second were rejected by the clock \
                     mapping (not finite, or off by more than {STALE_AFTER_SECS} s from their \
                     arrival): their samples are dropped",
                    rejected + mapped
                ));
            }
        }
        None
    }

    fn silent_for(&self, now: f64) -> Option<f64> {
        self.last_sample_secs.map(|t| now - t)
    }
}

fn sample_confidence(s: &Sample) -> f32 {
    match s {
        Sample::Pupil(p) => p.confidence,
        Sample::Gaze(g) => g.confidence,
        Sample::Blink(_) => f32::NAN,
    }
}

struct Task<S> {
    source: S,
    chain: LiveChain,
    age_clock: AgeClock,
    config: LiveConfig,
    eye_tx: watch::Sender<LiveEyeState>,
    samples: broadcast::Sender<Sample>,
    status: SharedStatus,
    adaptation: Arc<AdaptationCell>,
    shutdown: watch::Receiver<bool>,
}

/// Publishes `chain`'s state at host time `now` after `updates` samples;
/// `published_host_secs` is when the newest sample's state was published.
/// Returns the state's age, s.
fn publish(
    chain: &mut LiveChain,
    eye_tx: &watch::Sender<LiveEyeState>,
    age_clock: AgeClock,
    now: f64,
    updates: u64,
    published_host_secs: f64,
) -> f64 {
    let last = LiveEyeState {
        state: *chain.chain().state(),
        updated_host_secs: published_host_secs,
        updates,
    };
    let age = age_clock.age_secs(&last, now);
    let state = chain.state_at(now, age, updates);
    let next = LiveEyeState { state, ..last };
    // A fallback step that changes nothing wakes no reader.
    eye_tx.send_if_modified(|cur| {
        let changed = *cur != next;
        *cur = next;
        changed
    });
    age
}

impl<S: SampleSource> Task<S> {
    async fn run(self) {
        let Task {
            mut source,
            mut chain,
            age_clock,
            config,
            eye_tx,
            samples,
            status,
            adaptation,
            mut shutdown,
        } = self;
        let update = |f: &mut dyn FnMut(&mut SourceStatus)| f(&mut lock_status(&status));
        let mut status_tick = tokio::time::interval(config.status_period);
        status_tick.set_missed_tick_behavior(tokio::time::MissedTickBehavior::Delay);
        let mut fallback_tick = tokio::time::interval(config.tick);
        fallback_tick.set_missed_tick_behavior(tokio::time::MissedTickBehavior::Delay);
        let tick_secs = config.tick.as_secs_f64();
        let clock = source.clock_stats();
        let clock_now = || clock.as_ref().map(|c| c.snapshot());
        let mut window = RateWindow::new(host_now_secs(), clock_now());
        let mut updates = 0u64;
        let mut published_host_secs = host_now_secs();
        let mut last_sample_host_secs = f64::NEG_INFINITY;
        let mut item_errors = 0u64;
        let mut dropped = 0u64;
        let mut live = false;
        let mut was_lost = false;
        let mut ended = false;
        // Why the source is degraded, while it is.
        let mut degraded: Option<String> = None;
        let describe = source.describe();
        tracing::info!(source = %describe, "source started");
        loop {
            if *shutdown.borrow() {
                break;
            }
            // The pending `next` survives the ticks (a replay's pacing
            // sleep or a half-read line is never lost).
            let result = {
                let next = source.next();
                tokio::pin!(next);
                loop {
                    tokio::select! {
                        r = &mut next => break Some(r),
                        _ = shutdown.changed() => break None,
                        _ = fallback_tick.tick() => {
                            let now = host_now_secs();
                            if now - last_sample_host_secs >= tick_secs {
                                if let Some(l) = adaptation.get() {
                                    chain.set_adaptation_luminance(l);
                                }
                                publish(&mut chain, &eye_tx, age_clock, now, updates, published_host_secs);
                            }
                        }
                        _ = status_tick.tick() => {
                            let now = host_now_secs();
                            let clock = clock_now();
                            let mut closed = None;
                            update(&mut |s| {
                                closed = window.publish(now, s, updates, clock);
                                s.samples_dropped = dropped;
                                s.clock = clock;
                            });
                            match closed {
                                Some(Some(reason)) if live => {
                                    if degraded.is_none() {
                                        tracing::warn!(source = %describe, "source degraded: {reason}");
                                    }
                                    update(&mut |s| {
                                        s.health = SourceHealth::Degraded;
                                        s.degraded_reason = Some(reason.clone());
                                    });
                                    degraded = Some(reason);
                                }
                                Some(None) if degraded.is_some() => {
                                    degraded = None;
                                    if live {
                                        tracing::info!(source = %describe, "source healthy again: live");
                                    }
                                    update(&mut |s| {
                                        s.degraded_reason = None;
                                        if live {
                                            s.health = SourceHealth::Live;
                                        }
                                    });
                                }
                                _ => {}
                            }
                            if let Some(silent) = window.silent_for(now)
                                && silent > config.silent_lost_secs
                                && live
                                && degraded.is_none()
                            {
                                live = false;
                                was_lost = true;
                                tracing::warn!(source = %describe, "no samples for {silent:.1} s: source lost; frames continue");
                                update(&mut |s| {
                                    s.health = SourceHealth::Lost;
                                    s.last_error = Some(format!("no samples for {silent:.1} s"));
                                });
                            }
                        }
                    }
                }
            };
            let Some(result) = result else { break };
            dropped = source.dropped();
            match result {
                Ok(Some(sample)) => {
                    if let Some(l) = adaptation.get() {
                        chain.set_adaptation_luminance(l);
                    }
                    chain.push(&sample);
                    updates += 1;
                    let now = host_now_secs();
                    published_host_secs = now;
                    last_sample_host_secs = now;
                    let age = publish(&mut chain, &eye_tx, age_clock, now, updates, now);
                    window.add(now, &sample);
                    let stale_age = (age > STALE_AFTER_SECS).then_some(age);
                    for d in chain.take_decided() {
                        window.add_decided(&d, stale_age);
                    }
                    // No receiver is fine; a full ring drops its oldest.
                    let _ = samples.send(sample);
                    if !live {
                        live = true;
                        if was_lost {
                            tracing::info!(source = %describe, "source is back: live again");
                        } else {
                            tracing::info!(source = %describe, "source live");
                        }
                        let health = if degraded.is_some() {
                            SourceHealth::Degraded
                        } else {
                            SourceHealth::Live
                        };
                        update(&mut |s| s.health = health);
                    }
                }
                Ok(None) => {
                    let now = host_now_secs();
                    let clock = clock_now();
                    update(&mut |s| {
                        window.publish(now, s, updates, clock);
                        s.health = SourceHealth::Ended;
                        s.degraded_reason = None;
                        s.clock = clock;
                    });
                    tracing::info!(source = %describe, samples = updates, "source ended; frames continue with the last state");
                    ended = true;
                    break;
                }
                Err(e @ SourceError::Item { .. }) => {
                    item_errors += 1;
                    if item_errors <= 10 {
                        tracing::warn!(error = %e, "skipped a bad item");
                    }
                }
                Err(SourceError::Disconnected { reason, .. }) => {
                    let was_live = std::mem::replace(&mut live, false);
                    was_lost |= was_live;
                    degraded = None;
                    update(&mut |s| {
                        if was_live {
                            s.reconnects += 1;
                        }
                        s.health = SourceHealth::Lost;
                        s.last_error = Some(reason.clone());
                        s.degraded_reason = None;
                    });
                    tokio::time::sleep(Duration::from_millis(50)).await;
                }
                Err(SourceError::Fatal { reason, .. }) => {
                    tracing::error!(source = %describe, "source failed: {reason}; frames continue");
                    update(&mut |s| {
                        s.health = SourceHealth::Lost;
                        s.last_error = Some(reason.clone());
                        s.degraded_reason = None;
                    });
                    ended = true;
                    break;
                }
            }
        }
        // A source that ended or failed leaves the state to the fallback
        // (held, then the model) until the session ends.
        while ended && !*shutdown.borrow() {
            tokio::select! {
                _ = shutdown.changed() => break,
                _ = fallback_tick.tick() => {
                    if let Some(l) = adaptation.get() {
                        chain.set_adaptation_luminance(l);
                    }
                    publish(&mut chain, &eye_tx, age_clock, host_now_secs(), updates, published_host_secs);
                }
            }
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use gazelight_eye::{DetectorMethod, PupilSample, PupilUnit};

    use crate::source::{Pacing, ReplaySource};

    fn pupil(t: f64, eye: u8, mm: f32) -> Sample {
        Sample::Pupil(PupilSample {
            t_secs: t,
            eye,
            diameter_raw: mm,
            unit: PupilUnit::Mm,
            diameter_mm: Some(mm),
            confidence: 0.95,
            norm_pos: [0.5, 0.5],
            method: DetectorMethod::Other,
        })
    }

    /// A Pupil Core at 200 Hz as a user sees it: per eye a 2D datum in
    /// pixels (no calibration for them) and a 3D datum in mm, binocular
    /// gaze and every fifth cycle a monocular one. It reads 200 Hz per eye
    /// and overall and 0 % dropouts (before: every datum of every stream
    /// was counted, ~1000 Hz, and the uncalibrated 2D half as dropouts);
    /// every tenth datum below the confidence gate reads 10 % on the 3D
    /// stream, per eye and overall (the 2D stream has nothing measurable).
    #[test]
    fn rates_and_dropouts_are_per_stream_as_a_user_means_them() {
        use gazelight_eye::GazeSample;
        let run = |low_confidence_every: Option<u32>| {
            let mut chain = FilterChain::with_defaults();
            chain.keep_decided();
            let mut w = RateWindow::new(0.0, None);
            let hz = 200.0;
            for i in 0..200u32 {
                let t = f64::from(i) / hz;
                for eye in 0..2u8 {
                    let mut two_d = PupilSample {
                        t_secs: t,
                        eye,
                        diameter_raw: 31.5,
                        unit: PupilUnit::Px,
                        diameter_mm: None,
                        confidence: 0.91,
                        norm_pos: [0.4, 0.5],
                        method: DetectorMethod::Pupil2d,
                    };
                    let mut three_d = PupilSample {
                        diameter_raw: 3.75,
                        unit: PupilUnit::Mm,
                        diameter_mm: Some(3.75),
                        method: DetectorMethod::Pupil3d,
                        ..two_d
                    };
                    if low_confidence_every.is_some_and(|k| i % k == 0) {
                        three_d.confidence = 0.1;
                        two_d.confidence = 0.1;
                    }
                    for smp in [Sample::Pupil(two_d), Sample::Pupil(three_d)] {
                        chain.push(&smp);
                        w.add(t, &smp);
                        for d in chain.take_decided() {
                            w.add_decided(&d, None);
                        }
                    }
                }
                let mut gazes = vec![GazeEyes::Binocular];
                if i % 5 == 0 {
                    gazes.push(GazeEyes::Right);
                }
                for eyes in gazes {
                    let g = Sample::Gaze(GazeSample {
                        t_secs: t,
                        gaze_uv: [0.3, 0.8],
                        confidence: 0.89,
                        eyes,
                    });
                    chain.push(&g);
                    w.add(t, &g);
                }
            }
            // The last samples are decided a margin later: at the end of
            // the stream, now.
            chain.flush_pending();
            for d in chain.take_decided() {
                w.add_decided(&d, None);
            }
            let mut s = SourceStatus::default();
            assert!(w.publish(1.0, &mut s, 0, None).is_some());
            s
        };
        let s = run(None);
        assert!((s.sample_rate_hz - 200.0).abs() < 1e-9, "{s:?}");
        assert_eq!(s.eye_rate_hz, [200.0, 200.0]);
        assert_eq!(s.dropout_rate, 0.0, "{s:?}");
        assert_eq!(s.eye_dropout_rate, [Some(0.0), Some(0.0)]);
        let names: Vec<_> = s.streams.iter().map(|x| x.name).collect();
        assert_eq!(
            names,
            [
                "pupil 2d right (0)",
                "pupil 3d right (0)",
                "pupil 2d left (1)",
                "pupil 3d left (1)",
                "gaze binocular",
                "gaze right (0)"
            ]
        );
        let two_d = &s.streams[0];
        assert_eq!((two_d.dropout_rate, two_d.uncalibrated), (None, 200));
        assert_eq!(s.streams[5].rate_hz, 40.0);
        // One datum in ten below the confidence gate, on both detectors.
        let s = run(Some(10));
        assert!((s.dropout_rate - 0.1).abs() < 1e-9, "{s:?}");
        assert_eq!(s.streams[1].dropout_rate, Some(0.1));
        assert_eq!(s.eye_dropout_rate, [Some(0.1), Some(0.1)]);
        assert_eq!(s.sample_rate_hz, 200.0);
    }

    /// Moved from the frame loop (which filtered on top of the chain until
    /// the fallback became this stage of the one chain): the frames' clock
    /// is the fallback's.
    #[test]
    fn a_lost_tracker_holds_then_eases_to_the_model_and_recovers() {
        let mut live = LiveChain::new(FilterChain::with_defaults());
        // A dark scene: the model pupil is wide.
        let luminance = 0.05;
        live.set_adaptation_luminance(luminance);
        let dt = 1.0 / 90.0;
        let mut t = 0.0;
        let mut updates = 0;
        let mut last_t = 0.0;
        let frame = |live: &mut LiveChain, t: f64, last_t: f64, updates: u64| {
            live.state_at(t, t - last_t, updates).pupil_mm()
        };
        // 1 s live at 3 mm.
        let mut last = 0.0;
        while t < 1.0 {
            for eye in [0, 1] {
                live.push(&pupil(t, eye, 3.0));
            }
            updates += 2;
            last_t = t;
            last = frame(&mut live, t, last_t, updates);
            t += dt;
        }
        assert!((last - 3.0).abs() < 1e-3, "live: {last}");
        let lost_at = t;
        // Lost: fresh for 0.25 s, then held for 0.5 s.
        while t < lost_at + 0.65 {
            last = frame(&mut live, t, last_t, updates);
            t += dt;
        }
        assert!((last - 3.0).abs() < 1e-3, "held: {last}");
        while t < lost_at + 4.0 {
            last = frame(&mut live, t, last_t, updates);
            t += dt;
        }
        // Eased towards the model pupil at 0.5 mm/s (dropout default) for
        // the ≈ 3.25 s after the hold.
        let model = PupilModel::default().pupil_mm(luminance);
        assert!(model > 4.0, "the dark scene's model pupil: {model}");
        let expected = (model - 3.0).min(0.5 * (4.0 - STALE_AFTER_SECS - 0.5) as f32);
        let eased = last - 3.0;
        assert!(
            (eased - expected).abs() < 0.15,
            "eased {eased} mm, expected {expected}"
        );
        let state = live.state_at(t, t - last_t, updates);
        assert!(
            state
                .eyes
                .iter()
                .all(|e| e.pupil_origin == PupilOrigin::Model)
        );
        // The tracker comes back at 6 mm: the pupil returns at ≤ 6 mm/s.
        let before = last;
        for eye in [0, 1] {
            live.push(&pupil(t, eye, 6.0));
        }
        updates += 2;
        last_t = t;
        let back = frame(&mut live, t, last_t, updates);
        assert!((back - before).abs() <= 6.0 * dt as f32 + 1e-3);
        for _ in 0..90 {
            t += dt;
            for eye in [0, 1] {
                live.push(&pupil(t, eye, 6.0));
            }
            updates += 2;
            last_t = t;
            last = frame(&mut live, t, last_t, updates);
        }
        assert!((last - 6.0).abs() < 1e-3, "{last}");
    }

    #[test]
    fn before_any_sample_the_pupil_follows_the_model() {
        let mut live = LiveChain::new(FilterChain::with_defaults());
        live.set_adaptation_luminance(1000.0);
        let model = PupilModel::default().pupil_mm(1000.0);
        let start = live.state_at(0.0, 0.0, 0).pupil_mm();
        let mut t = 0.0;
        let mut p = start;
        while t < 20.0 {
            p = live.state_at(t, t, 0).pupil_mm();
            t += 0.1;
        }
        assert!(start > model + 0.5, "{start} vs {model}");
        assert!((p - model).abs() < 1e-3, "{p} vs {model}");
    }

    #[tokio::test]
    async fn the_task_filters_publishes_and_ends() {
        let samples =
            (0..50).map(|i| Ok::<_, std::convert::Infallible>(pupil(i as f64 * 0.01, 0, 5.0)));
        // In real time: the live task rate-limits the pupil on the host
        // clock, so a burst delivered in no host time could not move it.
        let source = ReplaySource::new("t", samples, Pacing::Scaled { speed: 1.0 });
        let (_stop, shutdown) = watch::channel(false);
        let live = spawn(
            "test://",
            source,
            FilterChain::with_defaults(),
            AgeClock::PublishTime,
            shutdown,
            LiveConfig::default(),
        );
        let mut rx = live.samples.subscribe();
        let mut eye = live.eye.clone();
        tokio::time::timeout(Duration::from_secs(5), async {
            while lock_status(&live.status).health != SourceHealth::Ended {
                tokio::time::sleep(Duration::from_millis(5)).await;
            }
        })
        .await
        .expect("the replay ends");
        let state = *eye.borrow_and_update();
        assert_eq!(state.updates, 50);
        assert!(
            (state.state.eyes[0].pupil_mm - 5.0).abs() < 0.5,
            "{state:?}"
        );
        let status = lock_status(&live.status).clone();
        assert_eq!(status.samples_total, 50);
        assert!(rx.try_recv().is_ok());
        // Ended, the task keeps stepping the fallback until shut down.
        assert!(!live.task.is_finished());
        drop(_stop);
        tokio::time::timeout(Duration::from_secs(5), live.task)
            .await
            .expect("stops on shutdown")
            .expect("no panic");
    }

    #[tokio::test]
    async fn a_slow_sample_reader_loses_the_oldest_and_learns_how_many() {
        let samples =
            (0..100).map(|i| Ok::<_, std::convert::Infallible>(pupil(i as f64 * 0.01, 0, 5.0)));
        let source = ReplaySource::new("t", samples, Pacing::AsFastAsPossible);
        let (_stop, shutdown) = watch::channel(false);
        let config = LiveConfig {
            broadcast_capacity: 16,
            ..LiveConfig::default()
        };
        let live = spawn(
            "test://",
            source,
            FilterChain::with_defaults(),
            AgeClock::PublishTime,
            shutdown,
            config,
        );
        let mut rx = live.samples.subscribe();
        tokio::time::timeout(Duration::from_secs(5), async {
            while lock_status(&live.status).health != SourceHealth::Ended {
                tokio::time::sleep(Duration::from_millis(5)).await;
            }
        })
        .await
        .expect("the replay ends");
        match rx.try_recv() {
            Err(broadcast::error::TryRecvError::Lagged(n)) => assert_eq!(n, 100 - 16),
            other => panic!("expected a lag, got {other:?}"),
        }
        assert_eq!(
            live.eye.borrow().updates,
            100,
            "the state never waits for a reader"
        );
    }

    /// A live source at 100 Hz in real time: pupils of 5 mm stamped
    /// `lag_ms` before now, or (with `garbage`) stamps its clock mapping
    /// rejects, so it delivers nothing.
    struct LaggingSource {
        lag_ms: Arc<AtomicU64>,
        garbage: Arc<std::sync::atomic::AtomicBool>,
        clock: gazelight_eye::clock::SourceClock,
        n: u64,
    }

    impl SampleSource for LaggingSource {
        async fn next(&mut self) -> Result<Option<Sample>, SourceError> {
            loop {
                tokio::time::sleep(Duration::from_millis(10)).await;
                self.n += 1;
                let now = host_now_secs();
                let lag = self.lag_ms.load(Ordering::Relaxed) as f64 * 1e-3;
                // The source's clock is 1000 s ahead of the host's.
                let stamp = if self.garbage.load(Ordering::Relaxed) {
                    [1e308, -1e308, 0.0][(self.n % 3) as usize]
                } else {
                    now - lag + 1000.0
                };
                if let Some(t) = self.clock.to_host(stamp, now) {
                    return Ok(Some(pupil(t, (self.n % 2) as u8, 5.0)));
                }
            }
        }

        fn describe(&self) -> String {
            "lagging test source".to_owned()
        }

        fn clock_stats(&self) -> Option<Arc<gazelight_eye::clock::SharedClockStats>> {
            Some(self.clock.shared_stats())
        }
    }

    async fn wait_health(live: &LiveEye, want: SourceHealth, limit: Duration) -> SourceStatus {
        tokio::time::timeout(limit, async {
            loop {
                let s = lock_status(&live.status).clone();
                if s.health == want {
                    return s;
                }
                tokio::time::sleep(Duration::from_millis(20)).await;
            }
        })
        .await
        .unwrap_or_else(|_| {
            panic!(
                "not {want:?} within {limit:?}: {:?}",
                lock_status(&live.status)
            )
        })
    }

    /// A source whose clock mapping rejects every stamp (absurd stamps
    /// that do not agree with each other) delivers nothing: it is degraded,
    /// with the reason and the mapping's counters in the status, not lost;
    /// with good stamps again it is live.
    #[tokio::test(flavor = "multi_thread", worker_threads = 2)]
    async fn a_source_whose_stamps_are_all_rejected_is_degraded_not_lost() {
        let lag_ms = Arc::new(AtomicU64::new(0));
        let garbage = Arc::new(std::sync::atomic::AtomicBool::new(false));
        let source = LaggingSource {
            lag_ms: lag_ms.clone(),
            garbage: garbage.clone(),
            clock: gazelight_eye::clock::SourceClock::new(
                "lagging",
                gazelight_eye::clock::SourceClockConfig::default(),
            ),
            n: 0,
        };
        let (_stop, shutdown) = watch::channel(false);
        let live = spawn(
            "test://lagging",
            source,
            FilterChain::with_defaults(),
            AgeClock::SampleTime,
            shutdown,
            LiveConfig::default(),
        );
        let s = wait_health(&live, SourceHealth::Live, Duration::from_secs(3)).await;
        assert_eq!(s.degraded_reason, None);
        // Every stamp rejected by the clock mapping: degraded, not lost,
        // with the reason; the counters are published.
        garbage.store(true, Ordering::Relaxed);
        let s = wait_health(&live, SourceHealth::Degraded, Duration::from_secs(3)).await;
        let reason = s.degraded_reason.unwrap_or_default();
        assert!(reason.contains("rejected by the clock mapping"), "{reason}");
        let clock = s.clock.unwrap_or_default();
        assert!(clock.rejected >= 50 && clock.jumps == 0, "{clock:?}");
        tokio::time::sleep(Duration::from_millis(1500)).await;
        assert_eq!(lock_status(&live.status).health, SourceHealth::Degraded);
        // Good stamps again: live within about a second.
        garbage.store(false, Ordering::Relaxed);
        let s = wait_health(&live, SourceHealth::Live, Duration::from_secs(3)).await;
        assert_eq!(s.degraded_reason, None);
        drop(_stop);
        let _ = tokio::time::timeout(Duration::from_secs(5), live.task).await;
    }

    /// A source (without a clock mapping) whose measured pupils all arrive
    /// 0.4 s old: the state is stale, the pupils are not used, and the
    /// source says so; when they arrive fresh again it is live.
    #[tokio::test(flavor = "multi_thread", worker_threads = 2)]
    async fn stale_measured_pupils_make_the_source_degraded() {
        struct Stale {
            lag_ms: Arc<AtomicU64>,
            n: u64,
        }
        impl SampleSource for Stale {
            async fn next(&mut self) -> Result<Option<Sample>, SourceError> {
                tokio::time::sleep(Duration::from_millis(10)).await;
                self.n += 1;
                let lag = self.lag_ms.load(Ordering::Relaxed) as f64 * 1e-3;
                Ok(Some(pupil(host_now_secs() - lag, (self.n % 2) as u8, 5.0)))
            }
            fn describe(&self) -> String {
                "stale test source".to_owned()
            }
        }
        let lag_ms = Arc::new(AtomicU64::new(400));
        let (_stop, shutdown) = watch::channel(false);
        let live = spawn(
            "test://stale",
            Stale {
                lag_ms: lag_ms.clone(),
                n: 0,
            },
            FilterChain::with_defaults(),
            AgeClock::SampleTime,
            shutdown,
            LiveConfig::default(),
        );
        let s = wait_health(&live, SourceHealth::Degraded, Duration::from_secs(3)).await;
        let reason = s.degraded_reason.unwrap_or_default();
        assert!(
            reason.contains("0.40 s old") && reason.contains("not used"),
            "{reason}"
        );
        assert_eq!(s.clock, None);
        let eye = *live.eye.borrow();
        assert!(
            eye.state
                .eyes
                .iter()
                .all(|e| e.pupil_origin != PupilOrigin::Measured),
            "{eye:?}"
        );
        lag_ms.store(5, Ordering::Relaxed);
        wait_health(&live, SourceHealth::Live, Duration::from_secs(3)).await;
        let eye = *live.eye.borrow();
        assert!((eye.state.eyes[0].pupil_mm - 5.0).abs() < 0.5, "{eye:?}");
        drop(_stop);
        let _ = tokio::time::timeout(Duration::from_secs(5), live.task).await;
    }
}
