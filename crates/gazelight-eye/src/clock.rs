//! Offset between Pupil time and the host's monotonic clock.
//!
//! Pupil stamps every datum with its own clock. gazelight never changes
//! that clock (the `T` command would move it for every client); instead it
//! estimates `offset = pupil_time − host_time` from `t` requests, the way
//! NTP/Cristian's algorithm does: a probe sent at host time `t0` and
//! answered at `t1` with Pupil time `p` gives
//! `offset = p − (t0 + t1) / 2`, with an error bounded by half the round
//! trip `t1 − t0`. Of several probes the one with the smallest round trip
//! is kept. Estimates are repeated periodically; the slope of the offset
//! over host time is the drift between the two clocks.
//!
//! Host time is [`host_now_secs`]: seconds since a process-wide
//! [`Instant`] epoch, so every part of gazelight shares one clock.

use std::collections::VecDeque;
use std::sync::OnceLock;
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

    #[test]
    fn host_clock_is_monotonic_and_shared() {
        let a = host_now_secs();
        let b = host_secs_of(Instant::now());
        assert!(b >= a);
        assert!(host_secs_of(host_epoch()) == 0.0);
    }
}
