//! The host clock, and the one mapping from a live source's clock onto it.
//!
//! Host time is [`host_now_secs`]: seconds since a process-wide
//! [`Instant`] epoch, so every part of gazelight shares one clock.
//!
//! # From a source's clock to the host's: [`SourceClock`]
//!
//! Every live source stamps its samples with its own clock (Pupil time, a
//! Neon's Unix time, a sender's LSL clock, a device's counter). Each one maps
//! those stamps onto host time through a [`SourceClock`], which holds an
//! offset `host − source` and checks every stamp against the host time at
//! which it arrived:
//!
//! - a stamp is *consistent* when its apparent age on arrival,
//!   `arrival − (stamp + offset)`, lies within ±`D`
//!   ([`SourceClockConfig::max_age_secs`], 0.25 s by default: the age at
//!   which the live eye task calls a state stale); it is delivered at
//!   `stamp + offset`, clamped into `[max(arrival − D, previous output),
//!   arrival]`. So every host time the mapping gives is **monotonic**,
//!   **never later than the arrival** and **never older than `D` on
//!   arrival** — whatever the stamps were — and the state a delivered
//!   sample makes is fresh;
//! - a stamp that is not consistent (a clock step, one absurd stamp such as
//!   1e308, a lying clock measurement) is *suspect*: it is dropped and
//!   counted ([`ClockStats::rejected`]), the mapping unchanged. When
//!   [`SourceClockConfig::jump_confirm`] (`K`, 3) suspects in a row agree
//!   with each other (their implied offsets within `D`), the source's clock
//!   has **jumped**: the mapping is re-anchored on the least-delayed of them
//!   (that stamp's age on arrival taken as 0), the jump is logged and counted
//!   ([`ClockStats::jumps`], [`ClockStats::last_jump_secs`]) and the `K`-th
//!   stamp is delivered. A single bad stamp (up to `K − 1` in a row) is thus
//!   dropped and decides nothing; a real step costs `K − 1` stamps;
//! - NaN or infinite stamps are dropped and counted
//!   ([`ClockStats::non_finite`]).
//!
//! Where the offset comes from: a source that can *measure* it (Pupil's `t`
//! round trips below, Neon's Time Echo, LSL's `time_correction`) passes each
//! measurement to [`SourceClock::anchor`], and the mapping holds that
//! offset, so a sample's age includes its real transport and processing
//! delay. A measurement that contradicts the stamps of the last one to two
//! windows ([`SourceClockConfig::window_secs`], 1 s) by more than `D` is
//! refused and counted ([`ClockStats::anchors_rejected`]); one taken with
//! no recent stamps is accepted, and if it lies, the stamps that follow are
//! a jump from it. A held measurement that the least-delayed stamp of a
//! whole window contradicts by more than `D/2` (a step smaller than `D`,
//! or a measurement off by less) is a jump too, found when that window
//! ends. A source that cannot measure (and any source after a jump, until
//! its next accepted measurement) follows the lower envelope of the
//! arrivals: the second-smallest `arrival − stamp` of the last one to two
//! windows (the smallest while they hold fewer than four stamps), so one
//! early stamp cannot move it and clock drift is followed.
//!
//! Recovery, for stamps whose transport delays vary by less than `D/2`:
//! after a step larger than `D` plus that jitter, every stamp from the
//! `K`-th on is delivered; after a smaller one, all are again within two
//! windows (2 s), and most meanwhile.
//!
//! The counters are shared ([`SharedClockStats`]) so the live eye task can
//! publish them with the source's health.
//!
//! # Pupil's clock: round trips
//!
//! Pupil stamps every datum with its own clock. gazelight never changes
//! that clock (the `T` command would move it for every client); instead it
//! estimates `offset = pupil_time − host_time` from `t` requests, the way
//! NTP/Cristian's algorithm does: a probe sent at host time `t0` and
//! answered at `t1` with Pupil time `p` gives
//! `offset = p − (t0 + t1) / 2`, with an error bounded by half the round
//! trip `t1 − t0`. Of several probes the one with the smallest round trip
//! is kept. Estimates are repeated periodically; the slope of the offset
//! over host time is the drift between the two clocks. Each estimate is a
//! measurement for the client's [`SourceClock`].

use std::collections::VecDeque;
use std::sync::atomic::{AtomicBool, AtomicU64, Ordering};
use std::sync::{Arc, OnceLock};
use std::time::Instant;

static EPOCH: OnceLock<Instant> = OnceLock::new();

/// The process-wide epoch of host time (set on first use).
pub fn host_epoch() -> Instant {
    *EPOCH.get_or_init(Instant::now)
}

/// Host monotonic time in seconds since [`host_epoch`].
pub fn host_now_secs() -> f64 {
    host_epoch().elapsed().as_secs_f64()
}

/// Host time of an [`Instant`], seconds since [`host_epoch`] (negative for
/// instants before the epoch).
pub fn host_secs_of(instant: Instant) -> f64 {
    let epoch = host_epoch();
    if instant >= epoch {
        (instant - epoch).as_secs_f64()
    } else {
        -(epoch - instant).as_secs_f64()
    }
}

/// One `t` round trip.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct ClockProbe {
    /// Host time when the request was sent, seconds.
    pub sent_host_secs: f64,
    /// Pupil time in the reply, seconds.
    pub pupil_secs: f64,
    /// Host time when the reply arrived, seconds.
    pub received_host_secs: f64,
}

impl ClockProbe {
    /// Round-trip time, seconds.
    pub fn rtt_secs(&self) -> f64 {
        self.received_host_secs - self.sent_host_secs
    }

    /// `pupil − host` at the midpoint of the round trip, seconds.
    pub fn offset_secs(&self) -> f64 {
        self.pupil_secs - 0.5 * (self.sent_host_secs + self.received_host_secs)
    }
}

/// The result of one round of probes.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct ClockEstimate {
    /// `pupil_time − host_time`, seconds, from the fastest probe.
    pub offset_secs: f64,
    /// Round trip of that probe, seconds; the offset's error is at most
    /// half of it.
    pub rtt_secs: f64,
    /// Range (max − min) of the offsets of all probes of the round,
    /// seconds.
    pub spread_secs: f64,
    /// Host time at the middle of the best probe, seconds.
    pub at_host_secs: f64,
    /// Number of probes in the round.
    pub probes: usize,
}

impl ClockEstimate {
    /// Best-of estimate from a round of probes; `None` when empty or when a
    /// probe has a negative round trip or non-finite values.
    pub fn from_probes(probes: &[ClockProbe]) -> Option<Self> {
        let mut best: Option<&ClockProbe> = None;
        let mut lo = f64::INFINITY;
        let mut hi = f64::NEG_INFINITY;
        for p in probes {
            let (rtt, off) = (p.rtt_secs(), p.offset_secs());
            if !(rtt.is_finite() && off.is_finite()) || rtt < 0.0 {
                return None;
            }
            lo = lo.min(off);
            hi = hi.max(off);
            if best.is_none_or(|b| rtt < b.rtt_secs()) {
                best = Some(p);
            }
        }
        let b = best?;
        Some(Self {
            offset_secs: b.offset_secs(),
            rtt_secs: b.rtt_secs(),
            spread_secs: hi - lo,
            at_host_secs: 0.5 * (b.sent_host_secs + b.received_host_secs),
            probes: probes.len(),
        })
    }
}

/// Keeps the recent estimates and reports drift.
#[derive(Clone, Debug)]
pub struct ClockTracker {
    history: VecDeque<ClockEstimate>,
    capacity: usize,
}

impl ClockTracker {
    /// Keeps at most `capacity` (≥ 2) estimates for the drift fit.
    pub fn new(capacity: usize) -> Self {
        let capacity = capacity.max(2);
        Self {
            history: VecDeque::with_capacity(capacity),
            capacity,
        }
    }

    /// Adds an estimate.
    pub fn push(&mut self, e: ClockEstimate) {
        if self.history.len() == self.capacity {
            self.history.pop_front();
        }
        self.history.push_back(e);
    }

    /// The newest estimate.
    pub fn latest(&self) -> Option<&ClockEstimate> {
        self.history.back()
    }

    /// Number of estimates held.
    pub fn len(&self) -> usize {
        self.history.len()
    }

    /// True when no estimate has been made.
    pub fn is_empty(&self) -> bool {
        self.history.is_empty()
    }

    /// Drift of Pupil's clock against the host's, seconds per second
    /// (least-squares slope of offset over host time); `None` with fewer
    /// than two estimates or no time between them.
    pub fn drift_secs_per_sec(&self) -> Option<f64> {
        let n = self.history.len();
        if n < 2 {
            return None;
        }
        let nf = n as f64;
        let mx = self.history.iter().map(|e| e.at_host_secs).sum::<f64>() / nf;
        let my = self.history.iter().map(|e| e.offset_secs).sum::<f64>() / nf;
        let (mut sxy, mut sxx) = (0.0, 0.0);
        for e in &self.history {
            let dx = e.at_host_secs - mx;
            sxy += dx * (e.offset_secs - my);
            sxx += dx * dx;
        }
        (sxx > 0.0).then(|| sxy / sxx)
    }

    /// Forgets all estimates (the peer's clock may have been reset).
    pub fn clear(&mut self) {
        self.history.clear();
    }
}

/// Why a reply to `t` is not a Pupil time.
#[derive(Clone, Debug, PartialEq, thiserror::Error)]
pub enum TimeReplyError {
    #[error("reply to `t` is not UTF-8")]
    NotUtf8,
    /// The reply's first 40 characters.
    #[error("reply to `t` is not a number: {0:?}")]
    NotANumber(String),
    #[error("reply to `t` is not finite: {0}")]
    NotFinite(f64),
}

/// Parses the reply to `t`: Pupil time as decimal text.
pub fn parse_time_reply(reply: &[u8]) -> Result<f64, TimeReplyError> {
    let text = std::str::from_utf8(reply).map_err(|_| TimeReplyError::NotUtf8)?;
    let t: f64 = text
        .trim()
        .parse()
        .map_err(|_| TimeReplyError::NotANumber(truncate(text).to_owned()))?;
    if t.is_finite() {
        Ok(t)
    } else {
        Err(TimeReplyError::NotFinite(t))
    }
}

fn truncate(s: &str) -> &str {
    match s.char_indices().nth(40) {
        Some((i, _)) => &s[..i],
        None => s,
    }
}

/// The oldest a mapped time stamp may be on arrival by default, s: the
/// stated bound of a [`SourceClock`] (a sample's age when it arrives is in
/// `[0, D]`). It equals the age after which the live eye task calls an
/// `EyeState` stale, so a sample the mapping delivers is fresh when it
/// arrives.
pub const DEFAULT_MAX_AGE_SECS: f64 = 0.25;
/// Suspect stamps in a row, agreeing with each other, that make a jump.
pub const DEFAULT_JUMP_CONFIRM: u32 = 3;
/// Length of one window of the arrival envelope, s.
pub const DEFAULT_WINDOW_SECS: f64 = 1.0;

/// Settings of a [`SourceClock`].
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct SourceClockConfig {
    /// `D`: the oldest a delivered stamp may be on arrival, and the largest
    /// disagreement with the mapping a stamp may have before it is suspect,
    /// s (> 0).
    pub max_age_secs: f64,
    /// `K`: suspect stamps in a row whose implied offsets agree within `D`
    /// that confirm a clock jump (≥ 2, so that one stamp never moves the
    /// mapping).
    pub jump_confirm: u32,
    /// Length of one window of the arrival envelope, s (> 0): the offset
    /// of an unanchored mapping, and the check of a measurement, use the
    /// stamps of the last one to two windows.
    pub window_secs: f64,
}

impl Default for SourceClockConfig {
    fn default() -> Self {
        Self {
            max_age_secs: DEFAULT_MAX_AGE_SECS,
            jump_confirm: DEFAULT_JUMP_CONFIRM,
            window_secs: DEFAULT_WINDOW_SECS,
        }
    }
}

impl SourceClockConfig {
    /// The settings with every out-of-range value replaced by its default.
    fn sane(self) -> Self {
        let d = Self::default();
        let positive = |v: f64, default: f64| {
            if v.is_finite() && v > 0.0 { v } else { default }
        };
        Self {
            max_age_secs: positive(self.max_age_secs, d.max_age_secs),
            jump_confirm: self.jump_confirm.max(2),
            window_secs: positive(self.window_secs, d.window_secs),
        }
    }
}

/// What a [`SourceClock`] has done, for the source's health.
#[derive(Clone, Copy, Debug, Default, PartialEq, serde::Serialize)]
pub struct ClockStats {
    /// Stamps mapped onto host time (their samples delivered).
    pub mapped: u64,
    /// Finite stamps dropped because they disagreed with the mapping by
    /// more than `D`: single outliers, and the first `K − 1` stamps of each
    /// jump.
    pub rejected: u64,
    /// NaN or infinite stamps dropped.
    pub non_finite: u64,
    /// Clock jumps detected (each re-anchored the mapping).
    pub jumps: u64,
    /// The newest jump: how far the source's clock moved against the
    /// host's, s (positive: forward); `None` before the first.
    pub last_jump_secs: Option<f64>,
    /// Offset measurements accepted.
    pub anchors: u64,
    /// Offset measurements refused because they contradicted the recent
    /// stamps by more than `D`.
    pub anchors_rejected: u64,
    /// Whether the offset is a measurement now (else the envelope of the
    /// arrivals).
    pub anchored: bool,
}

/// [`ClockStats`] shared between a [`SourceClock`] (which may live on a
/// reader thread or task) and whoever publishes the source's health.
/// Lock-free; one per source, kept across reconnects.
#[derive(Debug)]
pub struct SharedClockStats {
    mapped: AtomicU64,
    rejected: AtomicU64,
    non_finite: AtomicU64,
    jumps: AtomicU64,
    /// f64 bits; NaN = none yet.
    last_jump_bits: AtomicU64,
    anchors: AtomicU64,
    anchors_rejected: AtomicU64,
    anchored: AtomicBool,
}

impl Default for SharedClockStats {
    fn default() -> Self {
        Self {
            mapped: AtomicU64::new(0),
            rejected: AtomicU64::new(0),
            non_finite: AtomicU64::new(0),
            jumps: AtomicU64::new(0),
            last_jump_bits: AtomicU64::new(f64::NAN.to_bits()),
            anchors: AtomicU64::new(0),
            anchors_rejected: AtomicU64::new(0),
            anchored: AtomicBool::new(false),
        }
    }
}

impl SharedClockStats {
    /// A copy of the counters (each read atomically; together
    /// consistent enough for a status page).
    pub fn snapshot(&self) -> ClockStats {
        let l = |a: &AtomicU64| a.load(Ordering::Relaxed);
        let jump = f64::from_bits(l(&self.last_jump_bits));
        ClockStats {
            mapped: l(&self.mapped),
            rejected: l(&self.rejected),
            non_finite: l(&self.non_finite),
            jumps: l(&self.jumps),
            last_jump_secs: (!jump.is_nan()).then_some(jump),
            anchors: l(&self.anchors),
            anchors_rejected: l(&self.anchors_rejected),
            anchored: self.anchored.load(Ordering::Relaxed),
        }
    }
}

/// The two smallest `arrival − stamp` values of the current and the
/// previous window, and how many values each saw (fixed size: no
/// allocation per stamp).
#[derive(Clone, Copy, Debug)]
struct Envelope {
    start: f64,
    cur: [f64; 2],
    prev: [f64; 2],
    cur_n: u32,
    prev_n: u32,
    /// The second-smallest value of the window that just ended, until
    /// taken.
    completed: Option<f64>,
}

const EMPTY: [f64; 2] = [f64::INFINITY; 2];
/// Values the envelope needs before it leaves out its smallest.
const ENVELOPE_ROBUST_FROM: u32 = 4;

impl Envelope {
    fn new() -> Self {
        Self {
            start: f64::NEG_INFINITY,
            cur: EMPTY,
            prev: EMPTY,
            cur_n: 0,
            prev_n: 0,
            completed: None,
        }
    }

    fn roll(&mut self, now: f64, window: f64) {
        let since = now - self.start;
        if since >= window || since.is_nan() {
            self.completed =
                (since < 2.0 * window && self.cur[1].is_finite()).then_some(self.cur[1]);
            (self.prev, self.prev_n) = if since < 2.0 * window {
                (self.cur, self.cur_n)
            } else {
                (EMPTY, 0)
            };
            self.cur = EMPTY;
            self.cur_n = 0;
            self.start = now;
        }
    }

    fn add(&mut self, now: f64, window: f64, c: f64) {
        self.roll(now, window);
        self.cur_n = self.cur_n.saturating_add(1);
        if c < self.cur[0] {
            self.cur[1] = self.cur[0];
            self.cur[0] = c;
        } else if c < self.cur[1] {
            self.cur[1] = c;
        }
    }

    /// The second-smallest value of the last one to two windows, so one
    /// low outlier cannot set it; the smallest while they hold fewer than
    /// [`ENVELOPE_ROBUST_FROM`] values (a young stream).
    fn estimate(&mut self, now: f64, window: f64) -> Option<f64> {
        self.roll(now, window);
        let mut v = [self.cur[0], self.cur[1], self.prev[0], self.prev[1]];
        v.sort_by(f64::total_cmp);
        let robust = self.cur_n.saturating_add(self.prev_n) >= ENVELOPE_ROBUST_FROM;
        if robust && v[1].is_finite() {
            Some(v[1])
        } else {
            v[0].is_finite().then_some(v[0])
        }
    }
}

/// Suspect stamps in a row that agree with each other.
#[derive(Clone, Copy, Debug, Default)]
struct SuspectRun {
    n: u32,
    lo: f64,
    hi: f64,
}

impl SuspectRun {
    fn push(&mut self, c: f64, agree_secs: f64) {
        if self.n > 0 && c.max(self.hi) - c.min(self.lo) <= agree_secs {
            self.n += 1;
            self.lo = self.lo.min(c);
            self.hi = self.hi.max(c);
        } else {
            *self = Self { n: 1, lo: c, hi: c };
        }
    }
}

/// Logs the first ten occurrences, then every thousandth.
fn should_log(count: u64) -> bool {
    count <= 10 || count.is_multiple_of(1000)
}

/// The one mapping from a live source's clock onto host time: tolerates
/// clock jumps, drops single outliers, bounds every sample's age (see the
/// [module documentation](self)). No allocation per stamp.
#[derive(Debug)]
pub struct SourceClock {
    name: String,
    cfg: SourceClockConfig,
    /// `host − source`, s.
    offset: Option<f64>,
    anchored: bool,
    envelope: Envelope,
    run: SuspectRun,
    last_out: f64,
    last_arrival: f64,
    stats: ClockStats,
    shared: Arc<SharedClockStats>,
}

impl SourceClock {
    /// A mapping for the source `name` (used in the log) with its own
    /// counters.
    pub fn new(name: impl Into<String>, cfg: SourceClockConfig) -> Self {
        Self::with_stats(name, cfg, Arc::default())
    }

    /// A mapping that counts into `shared` (which the source's owner
    /// reads). The counters start from what `shared` holds.
    pub fn with_stats(
        name: impl Into<String>,
        cfg: SourceClockConfig,
        shared: Arc<SharedClockStats>,
    ) -> Self {
        Self {
            name: name.into(),
            cfg: cfg.sane(),
            offset: None,
            anchored: false,
            envelope: Envelope::new(),
            run: SuspectRun::default(),
            last_out: f64::NEG_INFINITY,
            last_arrival: f64::NEG_INFINITY,
            stats: shared.snapshot(),
            shared,
        }
    }

    /// The shared counters.
    pub fn shared_stats(&self) -> Arc<SharedClockStats> {
        self.shared.clone()
    }

    /// The counters.
    pub fn stats(&self) -> ClockStats {
        self.stats
    }

    /// The settings in use (out-of-range values replaced by defaults).
    pub fn config(&self) -> &SourceClockConfig {
        &self.cfg
    }

    /// The offset `host − source` in use, s; `None` before the first stamp
    /// or measurement.
    pub fn offset_secs(&self) -> Option<f64> {
        self.offset
    }

    /// Forgets the offset and the recent stamps (a reconnected source may
    /// have restarted its clock). The outputs stay monotonic and the
    /// counters keep counting.
    pub fn reset(&mut self) {
        self.offset = None;
        self.anchored = false;
        self.envelope = Envelope::new();
        self.run = SuspectRun::default();
        self.set_anchored(false);
    }

    /// A measurement of the offset `host − source` (s), taken at host time
    /// `now_host_secs`. Accepted (and held: `true`) unless it contradicts
    /// the stamps of the last one to two windows by more than `D`, which
    /// is logged and counted.
    pub fn anchor(&mut self, offset_secs: f64, now_host_secs: f64) -> bool {
        let now = self.sanitize_arrival(now_host_secs);
        let refused = if offset_secs.is_finite() {
            self.envelope
                .estimate(now, self.cfg.window_secs)
                .map(|m| m - offset_secs)
                .filter(|age| age.abs() > self.cfg.max_age_secs)
                .map(|age| {
                    format!(
                        "it would make the time stamps that just arrived {age:.3} s old \
                         (allowed: ±{} s)",
                        self.cfg.max_age_secs
                    )
                })
        } else {
            Some("it is not finite".to_owned())
        };
        if let Some(why) = refused {
            self.stats.anchors_rejected += 1;
            self.shared.anchors_rejected.fetch_add(1, Ordering::Relaxed);
            if should_log(self.stats.anchors_rejected) {
                tracing::warn!(
                    source = %self.name,
                    offset_s = offset_secs,
                    refused = self.stats.anchors_rejected,
                    "clock measurement refused: {why}; the mapping is unchanged"
                );
            }
            return false;
        }
        self.offset = Some(offset_secs);
        self.run = SuspectRun::default();
        self.envelope.completed = None;
        self.stats.anchors += 1;
        self.shared.anchors.fetch_add(1, Ordering::Relaxed);
        self.set_anchored(true);
        true
    }

    /// Host time of a sample stamped `source_secs` (the source's clock)
    /// that arrived at host time `arrival_host_secs`; `None` when the stamp
    /// is dropped (not finite, or suspect: see the module documentation).
    /// Every `Some` is within `[arrival − D, arrival]` and not earlier than
    /// the previous one.
    pub fn to_host(&mut self, source_secs: f64, arrival_host_secs: f64) -> Option<f64> {
        let arrival = self.sanitize_arrival(arrival_host_secs);
        let c = arrival - source_secs;
        if !c.is_finite() {
            self.stats.non_finite += 1;
            self.shared.non_finite.fetch_add(1, Ordering::Relaxed);
            if should_log(self.stats.non_finite) {
                tracing::warn!(source = %self.name, stamp = source_secs, count = self.stats.non_finite, "time stamp not finite: sample dropped");
            }
            return None;
        }
        let (d, w) = (self.cfg.max_age_secs, self.cfg.window_secs);
        let Some(offset) = self.offset else {
            // The first stamp: its age on arrival is taken as 0.
            self.offset = Some(c);
            self.envelope.add(arrival, w, c);
            return Some(self.deliver(arrival, arrival));
        };
        let age = c - offset;
        if age.abs() <= d {
            self.run.n = 0;
            self.envelope.add(arrival, w, c);
            if self.anchored {
                // A measured offset that the least-delayed stamp of a whole
                // window contradicts by more than D/2 (a clock step smaller
                // than D, or a measurement off by less than D): the
                // arrivals take over.
                if let Some(m) = self.envelope.completed.take()
                    && (m - offset).abs() > 0.5 * d
                {
                    self.jump(
                        offset,
                        m,
                        "the least-delayed time stamp of the last window disagrees with the \
                         measured offset",
                    );
                }
            } else if let Some(e) = self.envelope.estimate(arrival, w) {
                self.offset = Some(e);
            }
            let o = self.offset.unwrap_or(c);
            return Some(self.deliver(source_secs + o, arrival));
        }
        self.run.push(c, d);
        if self.run.n >= self.cfg.jump_confirm {
            let new = self.run.lo;
            self.run = SuspectRun::default();
            self.envelope = Envelope::new();
            self.envelope.add(arrival, w, new);
            self.jump(
                offset,
                new,
                "time stamps in a row agree with each other, not with the mapping",
            );
            return Some(self.deliver(source_secs + new, arrival));
        }
        self.stats.rejected += 1;
        self.shared.rejected.fetch_add(1, Ordering::Relaxed);
        if should_log(self.stats.rejected) {
            tracing::warn!(
                source = %self.name,
                stamp = source_secs,
                rejected = self.stats.rejected,
                "time stamp disagrees with the clock mapping by {:.3} s (more than ±{d} s): \
                 sample dropped (a single outlier, or the start of a clock jump)",
                -age
            );
        }
        None
    }

    /// Host time of a sample the source does not stamp, which arrived at
    /// `arrival_host_secs`: the arrival, kept monotonic with the stamped
    /// samples.
    pub fn arrival(&mut self, arrival_host_secs: f64) -> f64 {
        let arrival = self.sanitize_arrival(arrival_host_secs);
        self.deliver(arrival, arrival)
    }

    /// The arrival time made finite and monotonic.
    fn sanitize_arrival(&mut self, arrival_host_secs: f64) -> f64 {
        let a = if arrival_host_secs.is_finite() {
            arrival_host_secs
        } else {
            host_now_secs()
        };
        let a = if self.last_arrival.is_finite() {
            a.max(self.last_arrival)
        } else {
            a
        };
        self.last_arrival = a;
        a
    }

    /// `mapped` clamped into `[max(arrival − D, previous output), arrival]`.
    fn deliver(&mut self, mapped: f64, arrival: f64) -> f64 {
        let floor = (arrival - self.cfg.max_age_secs).max(self.last_out);
        let t = if mapped.is_nan() {
            arrival
        } else {
            mapped.max(floor).min(arrival)
        };
        self.last_out = t;
        self.stats.mapped += 1;
        self.shared.mapped.fetch_add(1, Ordering::Relaxed);
        t
    }

    /// Re-anchors from offset `old` to `new` on the arrivals; logs and
    /// counts the jump.
    fn jump(&mut self, old: f64, new: f64, why: &str) {
        // source = host − offset: the source's clock moved by old − new.
        let step = old - new;
        self.offset = Some(new);
        self.stats.jumps += 1;
        self.stats.last_jump_secs = Some(step);
        self.shared.jumps.fetch_add(1, Ordering::Relaxed);
        self.shared
            .last_jump_bits
            .store(step.to_bits(), Ordering::Relaxed);
        self.set_anchored(false);
        tracing::warn!(
            source = %self.name,
            step_s = step,
            jumps = self.stats.jumps,
            "clock jump: the source's time stamps moved by {step:+.3} s against the host clock \
             ({why}); re-anchored on their arrival times"
        );
    }

    fn set_anchored(&mut self, anchored: bool) {
        self.anchored = anchored;
        self.stats.anchored = anchored;
        self.shared.anchored.store(anchored, Ordering::Relaxed);
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    fn probe(sent: f64, rtt: f64, true_offset: f64, asym: f64) -> ClockProbe {
        // Reply stamped at `sent + asym * rtt` (asymmetric paths bias the
        // midpoint estimate by (asym − 0.5) · rtt).
        ClockProbe {
            sent_host_secs: sent,
            pupil_secs: sent + asym * rtt + true_offset,
            received_host_secs: sent + rtt,
        }
    }

    #[test]
    fn best_probe_wins_and_error_is_bounded_by_half_rtt() {
        let off = 1234.5;
        let probes = [
            probe(10.0, 0.004, off, 0.9),
            probe(10.01, 0.0002, off, 0.7),
            probe(10.02, 0.002, off, 0.1),
        ];
        let e = ClockEstimate::from_probes(&probes).unwrap();
        assert_eq!(e.rtt_secs, probes[1].rtt_secs());
        assert!((e.offset_secs - off).abs() <= 0.5 * e.rtt_secs + 1e-12);
        assert!((e.offset_secs - off).abs() > 0.0);
        // Spread covers the worst probes: (0.9−0.5)·4 ms and (0.1−0.5)·2 ms.
        assert!(
            (e.spread_secs - (0.0016 + 0.0008)).abs() < 1e-9,
            "{}",
            e.spread_secs
        );
        assert_eq!(e.probes, 3);
        assert!(ClockEstimate::from_probes(&[]).is_none());
        assert!(ClockEstimate::from_probes(&[probe(1.0, -0.1, 0.0, 0.5)]).is_none());
    }

    #[test]
    fn drift_is_the_slope_of_the_offset() {
        let mut t = ClockTracker::new(8);
        assert!(t.drift_secs_per_sec().is_none());
        // 50 ppm drift over 100 s.
        for i in 0..12 {
            let host = 10.0 * i as f64;
            t.push(ClockEstimate {
                offset_secs: 7.0 + 50e-6 * host,
                rtt_secs: 1e-4,
                spread_secs: 0.0,
                at_host_secs: host,
                probes: 5,
            });
        }
        assert_eq!(t.len(), 8);
        let d = t.drift_secs_per_sec().unwrap();
        assert!((d - 50e-6).abs() < 1e-12, "{d}");
    }

    #[test]
    fn time_reply_parsing() {
        assert_eq!(parse_time_reply(b"1234.56789").unwrap(), 1234.56789);
        assert_eq!(parse_time_reply(b" 5.5\n").unwrap(), 5.5);
        assert!(
            parse_time_reply(b"Unknown command.")
                .unwrap_err()
                .to_string()
                .contains("not a number")
        );
        assert!(parse_time_reply(b"nan").is_err());
        assert!(parse_time_reply(&[0xff]).is_err());
    }

    /// A source clock 1234.5 s ahead of the host's, measured exactly.
    const AHEAD: f64 = 1234.5;

    fn anchored() -> SourceClock {
        let mut c = SourceClock::new("test", SourceClockConfig::default());
        assert!(c.anchor(-AHEAD, 0.0));
        c
    }

    /// Feeds stamps taken every 5 ms from `t0` (host time), each arriving
    /// 20 ms after it was taken, on a source clock `ahead` s ahead of the
    /// host's; returns the host times delivered (None = dropped).
    fn stream(c: &mut SourceClock, t0: f64, n: usize, ahead: f64) -> Vec<Option<f64>> {
        (0..n)
            .map(|k| {
                let taken = t0 + 0.005 * k as f64;
                c.to_host(taken + ahead, taken + 0.02)
            })
            .collect()
    }

    #[test]
    fn an_anchored_mapping_gives_each_sample_its_measured_age() {
        let mut c = anchored();
        for (k, t) in stream(&mut c, 1.0, 200, AHEAD).into_iter().enumerate() {
            let taken = 1.0 + 0.005 * k as f64;
            let t = t.unwrap_or_else(|| panic!("stamp {k} dropped"));
            assert!((t - taken).abs() < 1e-9, "{t} vs {taken}");
        }
        let s = c.stats();
        assert_eq!((s.mapped, s.rejected, s.jumps), (200, 0, 0));
        assert!(s.anchored);
    }

    #[test]
    fn one_absurd_stamp_is_dropped_and_decides_nothing() {
        let mut c = anchored();
        stream(&mut c, 1.0, 100, AHEAD);
        let offset = c.offset_secs();
        // 1e308, its negative, 0 (1970 on a Unix clock) and a stamp 1e5 s
        // ahead, each alone between good stamps.
        for (i, bad) in [1e308, -1e308, 0.0, 1.6 + AHEAD + 1e5]
            .into_iter()
            .enumerate()
        {
            let at = 1.6 + i as f64 * 0.1;
            assert_eq!(c.to_host(bad, at), None, "{bad}");
            let good = stream(&mut c, at, 10, AHEAD);
            for (k, t) in good.into_iter().enumerate() {
                let taken = at + 0.005 * k as f64;
                assert!((t.unwrap_or(f64::NAN) - taken).abs() < 1e-9);
            }
        }
        assert_eq!(c.offset_secs(), offset);
        let s = c.stats();
        assert_eq!((s.rejected, s.jumps, s.non_finite), (4, 0, 0));
        assert!(s.anchored);
        assert_eq!(c.to_host(f64::NAN, 3.0), None);
        assert_eq!(c.to_host(f64::INFINITY, 3.0), None);
        assert_eq!(c.stats().non_finite, 2);
    }

    #[test]
    fn a_clock_step_is_a_jump_after_k_stamps_and_the_mapping_follows_it() {
        let mut c = anchored();
        stream(&mut c, 1.0, 100, AHEAD);
        // `T 1.7e9`: the source's clock is set to a Unix time.
        let unix = 1.7e9;
        let after = stream(&mut c, 2.0, 100, unix);
        assert_eq!(after[..2], [None, None]);
        // From the third stamp on, every stamp is delivered at its arrival
        // (the re-anchored mapping takes the first delivered one's age as 0).
        for (k, t) in after.iter().enumerate().skip(2) {
            let arrival = 2.0 + 0.005 * k as f64 + 0.02;
            let t = t.unwrap_or_else(|| panic!("stamp {k} dropped after the jump"));
            assert!((t - arrival).abs() < 1e-6, "{t} vs {arrival}");
        }
        let s = c.stats();
        assert_eq!((s.jumps, s.rejected), (1, 2));
        // The step, less the 20 ms transport delay the re-anchoring takes
        // as 0.
        let step = s.last_jump_secs.unwrap_or(0.0);
        assert!((step - (unix - AHEAD - 0.02)).abs() < 1e-6, "{step}");
        assert!(!s.anchored);
        // A new measurement (the `t` probe that follows) is accepted and the
        // ages are the real 20 ms again.
        assert!(c.anchor(-unix, 2.5));
        let t = c.to_host(2.6 + unix, 2.62).unwrap_or(f64::NAN);
        assert!((t - 2.6).abs() < 1e-6, "{t}");
    }

    #[test]
    fn a_measurement_that_contradicts_the_stamps_is_refused() {
        let mut c = anchored();
        stream(&mut c, 1.0, 100, AHEAD);
        // A Time Echo reply 1e6 s off, then one that says 1970.
        assert!(!c.anchor(-AHEAD - 1e6, 1.5));
        assert!(!c.anchor(1.7e9, 1.5));
        assert!(!c.anchor(f64::NAN, 1.5));
        assert_eq!(c.offset_secs(), Some(-AHEAD));
        assert_eq!(c.stats().anchors_rejected, 3);
        let t = c.to_host(1.6 + AHEAD, 1.62).unwrap_or(f64::NAN);
        assert!((t - 1.6).abs() < 1e-9);
    }

    #[test]
    fn a_lying_measurement_before_any_stamp_is_undone_by_the_stamps() {
        // Phone 1e6 s ahead by the measurement, 1970 by the other: both are
        // taken (nothing contradicts them yet) and the stamps then jump.
        for lie in [1e6, -AHEAD - 1.7e9] {
            let mut c = SourceClock::new("test", SourceClockConfig::default());
            assert!(c.anchor(-AHEAD - lie, 0.0));
            let out = stream(&mut c, 1.0, 50, AHEAD);
            assert_eq!(out[..2], [None, None]);
            assert!(out[2..].iter().all(Option::is_some));
            assert_eq!(c.stats().jumps, 1);
            for (k, t) in out.iter().enumerate().skip(2) {
                let arrival = 1.0 + 0.005 * k as f64 + 0.02;
                assert!((t.unwrap_or(f64::NAN) - arrival).abs() < 1e-6);
            }
        }
    }

    #[test]
    fn a_small_step_is_found_when_its_window_ends() {
        let mut c = anchored();
        stream(&mut c, 1.0, 200, AHEAD);
        // The source's clock steps back 0.2 s: the stamps look 0.22 s old
        // (within D, so delivered), until the first whole window after the
        // step ends and the arrivals take over.
        let after = stream(&mut c, 2.0, 600, AHEAD - 0.2);
        assert!(after.iter().all(Option::is_some));
        assert_eq!(c.stats().jumps, 1);
        let last = after.last().copied().flatten().unwrap_or(f64::NAN);
        let arrival = 2.0 + 0.005 * 599.0 + 0.02;
        assert!((arrival - last).abs() < 1e-6, "age {}", arrival - last);
    }

    #[test]
    fn without_measurements_the_envelope_follows_drift_and_ignores_one_early_stamp() {
        let mut c = SourceClock::new("test", SourceClockConfig::default());
        // A device clock 0.1 % slow, 5 s ahead, stamps 1–4 ms late, for
        // 10 minutes at 100 Hz: the drift (0.6 s) is followed.
        let mut worst = 0.0f64;
        for k in 0..60_000 {
            let taken = k as f64 * 0.01;
            let late = 0.001 + 0.003 * ((k * 7919 % 97) as f64 / 96.0);
            let arrival = taken + late;
            if k == 30_000 {
                // One stamp 0.2 s in the future (within D): dropped from
                // nothing, it cannot move the envelope alone.
                let t = c.to_host(0.999 * (taken + 0.2) + 5.0, arrival);
                assert_eq!(t, Some(arrival));
                continue;
            }
            let t = c.to_host(0.999 * taken + 5.0, arrival).unwrap_or(f64::NAN);
            if k > 300 {
                worst = worst.max((arrival - t).abs());
            }
        }
        assert!(worst < 0.005, "worst age error {worst} s");
        assert_eq!(c.stats().jumps, 0);
    }

    #[test]
    fn outputs_are_monotonic_across_a_reset() {
        let mut c = anchored();
        let before = stream(&mut c, 1.0, 10, AHEAD);
        c.reset();
        // A reconnected source whose clock restarted at 0.
        let t = c.to_host(0.0, 1.1).unwrap_or(f64::NAN);
        assert!(t >= before[9].unwrap_or(f64::INFINITY));
        assert_eq!(c.arrival(0.5), 1.1, "an earlier arrival cannot go back");
        assert!(!c.stats().anchored);
    }

    #[test]
    fn host_clock_is_monotonic_and_shared() {
        let a = host_now_secs();
        let b = host_secs_of(Instant::now());
        assert!(b >= a);
        assert!(host_secs_of(host_epoch()) == 0.0);
    }
}
