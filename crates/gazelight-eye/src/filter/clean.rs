//! Pupil preprocessing as the published guidelines do it: which samples of
//! one eye's pupil stream are clean measurements.
//!
//! - A sample that is not a pupil (confidence below the gate, a diameter
//!   ≤ 0 or NaN, a millimetre value outside the physiological range) is
//!   **lost**.
//! - Samples within `margin_before_s` before and `margin_after_s` after
//!   every blink or lost stretch (lost samples spanning at least
//!   `min_lost_s`, 30 ms: the chain's shortest blink; a single lost frame
//!   is not one) are discarded: the eyelid covers part of the pupil as it
//!   closes and reopens, so the tracker's first and last values around a
//!   blink are too small (Mathôt, Fabius, Van Heusden & Van der Stigchel
//!   2018, *Safe and sensible preprocessing and baseline correction of
//!   pupil-size data*, Behav Res Methods 50:94–106; Kret & Sjak-Shie 2019,
//!   *Preprocessing pupil size data: Guidelines and code*, Behav Res
//!   Methods 51:1336–1342: "gap padding" of 50 ms on both sides; MNE's
//!   `interpolate_blinks` default `buffer=0.05`).
//! - Dilation-speed outliers are discarded (Kret & Sjak-Shie 2019): the
//!   speed of sample *i* is the larger of its speeds from the previous and
//!   to the next sample, and a sample whose speed exceeds
//!   `median + n · MAD` of the recent speeds (n = 16, their default) is
//!   an outlier — where it also stands more than `speed_min_deviation`
//!   (5 %) off the median of its ±40 ms neighbours. That second condition
//!   is ours: on real trackers the threshold alone is crossed by
//!   quantisation noise and fast but smooth changes (0.4 % of the PLR
//!   trace's samples with the whole trace's threshold), and a sample
//!   consistent with its neighbours is not an artefact.
//! - Every other sample is **clean** and passes unchanged: nothing here
//!   smooths, rate-limits or holds a value.
//!
//! The margin before a blink needs the future: a sample is decided once
//! the stream has moved `margin_before_s + min_lost_s` past it (and its
//! next sample, for its speed, has arrived). So decisions come out in order, a
//! little after the samples went in ([`CleanTrack::pop_ready`]); an offline
//! replay pushes that far ahead of its frame clock, a live run publishes
//! its measurements that much later.
//!
//! Fixed-size state: the pending samples and the speed history live in
//! buffers allocated once; nothing allocates per sample.

use std::collections::VecDeque;

use serde::{Deserialize, Serialize};

use crate::sample::{DetectorMethod, PupilUnit};
use crate::setting::SettingError;

/// Default margin discarded before a lost sample, s (Kret & Sjak-Shie 2019
/// gap padding, backward 50 ms; MNE `interpolate_blinks` `buffer=0.05`).
pub const DEFAULT_MARGIN_BEFORE_S: f64 = 0.05;
/// Default margin discarded after a lost sample, s (Kret & Sjak-Shie 2019
/// gap padding, forward 50 ms; MNE `interpolate_blinks` `buffer=0.05`).
pub const DEFAULT_MARGIN_AFTER_S: f64 = 0.05;
/// Default shortest lost stretch that gets margins, s: the chain's shortest
/// blink ([`crate::filter::BlinkConfig`]'s `min_duration_s`); a single lost
/// frame is a dropout, not an occluding eyelid.
pub const DEFAULT_MIN_LOST_S: f64 = 0.03;
/// Default MAD multiplier of the dilation-speed filter (Kret & Sjak-Shie
/// 2019, `n = 16`).
pub const DEFAULT_SPEED_MAD_N: f64 = 16.0;

/// Default: a speed outlier is discarded only more than this fraction off
/// the median of its ±[`SPEED_NEIGHBOURHOOD_S`] neighbours.
pub const DEFAULT_SPEED_MIN_DEVIATION: f64 = 0.05;
/// Half-width of the neighbourhood a speed outlier is compared with, s.
pub const SPEED_NEIGHBOURHOOD_S: f64 = 0.04;
/// Recent decided values kept for that neighbourhood.
const RECENT_CAPACITY: usize = 256;

/// Most samples one eye may have pending (undecided): 2 s at 2 kHz. A
/// stream faster than that within the margin is decided early (counted).
pub const PENDING_CAPACITY: usize = 4096;
/// Speeds kept for the median and MAD (≈ 10 s at 200 Hz, 4 s at 500 Hz).
pub const SPEED_HISTORY: usize = 2048;
/// Speeds needed before the speed filter rejects anything.
pub const SPEED_MIN_HISTORY: usize = 64;
/// Time stamps closer than this count as equal, s (sample clocks are
/// integer ms or ns; their sums in f64 are not exact).
const TIME_EPS_S: f64 = 1e-9;
/// The speed threshold is recomputed after this many new speeds.
const SPEED_REFRESH: usize = 128;

/// Configuration of the guideline cleaning.
#[derive(Clone, Copy, Debug, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields, default)]
pub struct CleanConfig {
    /// Samples this long before a lost sample are discarded, s. Default
    /// 0.05.
    pub margin_before_s: f64,
    /// Samples this long after a lost sample are discarded, s. Default
    /// 0.05.
    pub margin_after_s: f64,
    /// Shortest lost stretch (first to last lost sample) that gets the
    /// margins, s. Default 0.03.
    pub min_lost_s: f64,
    /// Dilation-speed outliers: speed > median + n · MAD. Default 16; 0
    /// turns the speed filter off.
    pub speed_mad_n: f64,
    /// …and more than this fraction off the median of the ±40 ms
    /// neighbours. Default 0.05.
    pub speed_min_deviation: f64,
}

impl Default for CleanConfig {
    fn default() -> Self {
        Self {
            margin_before_s: DEFAULT_MARGIN_BEFORE_S,
            margin_after_s: DEFAULT_MARGIN_AFTER_S,
            min_lost_s: DEFAULT_MIN_LOST_S,
            speed_mad_n: DEFAULT_SPEED_MAD_N,
            speed_min_deviation: DEFAULT_SPEED_MIN_DEVIATION,
        }
    }
}

impl CleanConfig {
    /// Checks the margins (0..=1 s) and the multiplier (≥ 0); names the
    /// field.
    pub fn validate(&self) -> Result<(), SettingError> {
        for (name, v) in [
            ("clean.margin_before_s", self.margin_before_s),
            ("clean.margin_after_s", self.margin_after_s),
            ("clean.min_lost_s", self.min_lost_s),
        ] {
            if !(v.is_finite() && (0.0..=1.0).contains(&v)) {
                return Err(SettingError::new(
                    name,
                    format!("must be a number of seconds in 0..=1, got {v}"),
                ));
            }
        }
        if !(self.speed_min_deviation.is_finite() && self.speed_min_deviation >= 0.0) {
            return Err(SettingError::new(
                "clean.speed_min_deviation",
                format!("must be ≥ 0, got {}", self.speed_min_deviation),
            ));
        }
        if !(self.speed_mad_n.is_finite() && self.speed_mad_n >= 0.0) {
            return Err(SettingError::new(
                "clean.speed_mad_n",
                format!("must be ≥ 0 (0: off), got {}", self.speed_mad_n),
            ));
        }
        Ok(())
    }
}

/// What became of one pupil sample.
#[derive(Clone, Copy, Debug, PartialEq, Eq, Serialize, Deserialize)]
#[serde(rename_all = "snake_case")]
pub enum SampleFate {
    /// A clean measurement, passed unchanged.
    Clean,
    /// No pupil: below the confidence gate, ≤ 0 or NaN.
    Lost,
    /// A millimetre value outside the physiological range.
    OutOfRange,
    /// Within the margin before or after a lost sample.
    Margin,
    /// A dilation-speed outlier.
    Speed,
    /// Another stream of the same eye than the one measured (Pupil Core's
    /// 2D pixels beside its 3D millimetres): not part of this eye's
    /// measurement.
    OtherStream,
}

impl SampleFate {
    /// Whether the sample is a measurement.
    pub fn is_clean(self) -> bool {
        self == Self::Clean
    }
}

/// One pupil sample as the track sees it (and gives it back, decided).
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct TrackSample {
    /// The chain's running number of pupil samples (to match a decision
    /// with the sample it belongs to).
    pub seq: u64,
    pub t_secs: f64,
    pub eye: u8,
    pub method: DetectorMethod,
    /// The measured pupil in `unit`: millimetres where the tracker gives
    /// them or a physical scale is known, else the tracker's raw value
    /// (diameter, or area for area units). NaN when there is none.
    pub value: f32,
    /// The unit of `value` ([`PupilUnit::Mm`] for millimetres).
    pub unit: PupilUnit,
    /// The model aperture, mm (001 §5's black/white map, or the measured
    /// mm); NaN where neither is known.
    pub aperture_mm: f32,
    /// What became of it (before the decision: `Lost`, `OutOfRange` or
    /// `OtherStream` as pushed, `Clean` for a candidate).
    pub fate: SampleFate,
}

#[derive(Clone, Copy, Debug)]
struct Pending {
    s: TrackSample,
    /// Speed from the previous candidate, units/s (NaN: none).
    speed_back: f32,
    /// Speed to the next candidate (NaN: none yet).
    speed_fwd: f32,
    /// Whether a later sample has arrived (the forward speed is known).
    followed: bool,
}

/// One eye's cleaning: pending samples in, decided samples out, in order.
#[derive(Clone, Debug)]
pub struct CleanTrack {
    cfg: CleanConfig,
    pending: VecDeque<Pending>,
    /// The newest time pushed.
    newest_t: f64,
    /// The current lost stretch: its first and last sample times, and
    /// whether it is long enough for margins (already applied before it).
    run: Option<(f64, f64, bool)>,
    /// The end of the newest lost stretch that gets margins.
    blink_end_t: Option<f64>,
    /// The previous candidate sample (time, value), for the speed.
    prev: Option<(f64, f32)>,
    speeds: Vec<f32>,
    speeds_next: usize,
    speeds_since_refresh: usize,
    scratch: Vec<f32>,
    /// Recently decided valid samples (time, value), for the neighbourhood.
    recent: VecDeque<(f64, f32)>,
    threshold: f32,
    /// Decide everything pending (the stream ended).
    flushing: bool,
    /// Samples decided early because the pending buffer was full.
    pub forced: u64,
}

impl CleanTrack {
    pub fn new(cfg: CleanConfig) -> Self {
        Self {
            cfg,
            pending: VecDeque::with_capacity(PENDING_CAPACITY + 1),
            newest_t: f64::NEG_INFINITY,
            run: None,
            blink_end_t: None,
            prev: None,
            speeds: Vec::with_capacity(SPEED_HISTORY),
            speeds_next: 0,
            speeds_since_refresh: 0,
            scratch: Vec::with_capacity(SPEED_HISTORY),
            recent: VecDeque::with_capacity(RECENT_CAPACITY),
            threshold: f32::INFINITY,
            flushing: false,
            forced: 0,
        }
    }

    /// Forgets everything (a new stream of this eye).
    pub fn reset(&mut self) {
        self.pending.clear();
        self.newest_t = f64::NEG_INFINITY;
        self.run = None;
        self.blink_end_t = None;
        self.prev = None;
        self.speeds.clear();
        self.speeds_next = 0;
        self.speeds_since_refresh = 0;
        self.recent.clear();
        self.threshold = f32::INFINITY;
        self.flushing = false;
    }

    /// Whether nothing is pending.
    pub fn is_empty(&self) -> bool {
        self.pending.is_empty()
    }

    /// The speed threshold now in use, units/s (∞ until enough speeds).
    pub fn speed_threshold(&self) -> f32 {
        self.threshold
    }

    /// Feeds one sample (`fate` `Clean` for a candidate, `Lost`,
    /// `OutOfRange` or `OtherStream` otherwise). Call [`Self::pop_ready`]
    /// until it gives nothing after each push (the buffer then never grows
    /// past its capacity).
    pub fn push(&mut self, s: TrackSample) {
        self.flushing = false;
        let t = s.t_secs;
        if t > self.newest_t {
            self.newest_t = t;
        }
        match s.fate {
            SampleFate::OtherStream => self.pending.push_back(Pending {
                s,
                speed_back: f32::NAN,
                speed_fwd: f32::NAN,
                followed: true,
            }),
            SampleFate::Clean => {
                // A lost stretch ends here.
                if let Some((_, last, long)) = self.run.take()
                    && long
                {
                    self.blink_end_t = Some(last);
                }
                let speed_back = match self.prev {
                    Some((t0, v0)) if t > t0 => (s.value - v0).abs() / (t - t0) as f32,
                    _ => f32::NAN,
                };
                // The previous candidate's forward speed is this one's
                // backward speed.
                if let Some(p) = self.last_of_stream() {
                    p.followed = true;
                    if p.s.fate == SampleFate::Clean {
                        p.speed_fwd = speed_back;
                    }
                }
                let mut fate = SampleFate::Clean;
                if self
                    .blink_end_t
                    .is_some_and(|tl| t - tl <= self.cfg.margin_after_s + TIME_EPS_S)
                {
                    fate = SampleFate::Margin;
                }
                self.pending.push_back(Pending {
                    s: TrackSample { fate, ..s },
                    speed_back,
                    speed_fwd: f32::NAN,
                    followed: false,
                });
                self.prev = Some((t, s.value));
            }
            SampleFate::Lost | SampleFate::OutOfRange | SampleFate::Margin | SampleFate::Speed => {
                self.prev = None;
                let (first, _, long) = match self.run {
                    Some((first, last, long)) => (first, last.max(t), long),
                    None => (t, t, false),
                };
                let reaches = t - first >= self.cfg.min_lost_s - TIME_EPS_S;
                self.run = Some((first, t.max(first), long || reaches));
                if let Some(p) = self.last_of_stream() {
                    p.followed = true;
                }
                if reaches && !long {
                    // Now a blink: the samples before it lose their margin.
                    let margin = self.cfg.margin_before_s;
                    for p in self.pending.iter_mut().rev() {
                        if p.s.fate == SampleFate::OtherStream || p.s.t_secs >= first {
                            continue;
                        }
                        if first - p.s.t_secs > margin + TIME_EPS_S {
                            break;
                        }
                        if p.s.fate == SampleFate::Clean {
                            p.s.fate = SampleFate::Margin;
                        }
                    }
                }
                self.pending.push_back(Pending {
                    s,
                    speed_back: f32::NAN,
                    speed_fwd: f32::NAN,
                    followed: false,
                });
            }
        }
    }

    /// The newest pending sample of the measured stream.
    fn last_of_stream(&mut self) -> Option<&mut Pending> {
        self.pending
            .iter_mut()
            .rev()
            .find(|p| p.s.fate != SampleFate::OtherStream)
    }

    /// Gives up the pending samples as another stream's (the eye's
    /// measured stream changed): they come out as
    /// [`SampleFate::OtherStream`].
    pub fn abandon(&mut self) {
        for p in &mut self.pending {
            p.s.fate = SampleFate::OtherStream;
            p.followed = true;
        }
        self.flushing = true;
        // A new stream starts: nothing of the old one carries over (what is
        // still pending comes out in order).
        self.run = None;
        self.blink_end_t = None;
        self.prev = None;
        self.speeds.clear();
        self.speeds_next = 0;
        self.speeds_since_refresh = 0;
        self.recent.clear();
        self.threshold = f32::INFINITY;
    }

    /// Decides everything pending from now on (the stream ended or went
    /// silent); the next [`Self::push`] ends it.
    pub fn flush(&mut self) {
        self.flushing = true;
    }

    /// The time of the oldest pending sample if it is decided.
    pub fn ready_t(&self) -> Option<f64> {
        let p = self.pending.front()?;
        let ready = self.flushing
            || (p.followed
                && self.newest_t - p.s.t_secs
                    > self.cfg.margin_before_s + self.cfg.min_lost_s + TIME_EPS_S)
            || self.pending.len() >= PENDING_CAPACITY;
        ready.then_some(p.s.t_secs)
    }

    /// The oldest pending sample, decided, if it can be decided now.
    pub fn pop_ready(&mut self) -> Option<TrackSample> {
        self.ready_t()?;
        let full = self.pending.len() >= PENDING_CAPACITY;
        let p = self.pending.pop_front()?;
        if full && !self.flushing {
            // Unreachable at real rates: decided before its margin passed.
            self.forced += 1;
        }
        let mut s = p.s;
        if s.fate == SampleFate::Clean {
            let speed = p.speed_back.max(p.speed_fwd);
            if speed.is_finite() {
                if self.cfg.speed_mad_n > 0.0
                    && speed > self.threshold
                    && self.off_neighbours(s.t_secs, s.value)
                {
                    s.fate = SampleFate::Speed;
                }
                self.record_speed(speed);
            }
        }
        if matches!(
            s.fate,
            SampleFate::Clean | SampleFate::Margin | SampleFate::Speed
        ) {
            if self.recent.len() >= RECENT_CAPACITY {
                self.recent.pop_front();
            }
            self.recent.push_back((s.t_secs, s.value));
        }
        Some(s)
    }

    /// Whether `value` at `t` stands more than `speed_min_deviation` off
    /// the median of the valid samples within ±40 ms (the decided ones
    /// before it, the pending ones after it).
    fn off_neighbours(&mut self, t: f64, value: f32) -> bool {
        let h = SPEED_NEIGHBOURHOOD_S;
        self.scratch.clear();
        self.scratch.extend(
            self.recent
                .iter()
                .rev()
                .take_while(|(tr, _)| t - tr <= h + TIME_EPS_S)
                .map(|&(_, v)| v),
        );
        self.scratch.extend(
            self.pending
                .iter()
                .take_while(|p| p.s.t_secs - t <= h + TIME_EPS_S)
                .filter(|p| {
                    matches!(
                        p.s.fate,
                        SampleFate::Clean | SampleFate::Margin | SampleFate::Speed
                    )
                })
                .map(|p| p.s.value),
        );
        self.scratch.push(value);
        // Off the whole median interval (both middle values of an even
        // count): a sample between them is not off its neighbours.
        let n = self.scratch.len();
        let (_, hi, _) = self.scratch.select_nth_unstable_by(n / 2, f32::total_cmp);
        let hi = *hi;
        let lo = if n.is_multiple_of(2) {
            self.scratch[..n / 2]
                .iter()
                .copied()
                .fold(f32::NEG_INFINITY, f32::max)
        } else {
            hi
        };
        let tol = self.cfg.speed_min_deviation as f32;
        (value - lo).abs() > tol * lo.abs() && (value - hi).abs() > tol * hi.abs()
    }

    fn record_speed(&mut self, speed: f32) {
        if self.speeds.len() < SPEED_HISTORY {
            self.speeds.push(speed);
        } else {
            self.speeds[self.speeds_next] = speed;
            self.speeds_next = (self.speeds_next + 1) % SPEED_HISTORY;
        }
        self.speeds_since_refresh += 1;
        let n = self.speeds.len();
        if n >= SPEED_MIN_HISTORY
            && (self.speeds_since_refresh >= SPEED_REFRESH || !self.threshold.is_finite())
        {
            self.speeds_since_refresh = 0;
            self.threshold = median_plus_mad(&self.speeds, &mut self.scratch, self.cfg.speed_mad_n);
        }
    }
}

/// Default longest stretch bridged by [`interpolate_gaps`], s: longer than
/// any blink (the PSA recording's slowest is 0.7 s) and its margins.
pub const DEFAULT_MAX_INTERPOLATED_GAP_S: f64 = 1.0;

/// The guidelines' interpolated series (Kret & Sjak-Shie 2019; MNE's
/// `interpolate_blinks`): each stretch of not-clean samples (`values`
/// NaN) between two clean ones at most `max_gap_s` apart is filled by the
/// straight line between them, in place, and marked in `interpolated`.
/// Clean samples are not touched; stretches at the ends or longer than
/// `max_gap_s` stay NaN. `t_secs`, `values` and `interpolated` have one
/// entry per sample, in time order.
pub fn interpolate_gaps(
    t_secs: &[f64],
    values: &mut [f32],
    interpolated: &mut [bool],
    max_gap_s: f64,
) {
    let n = values.len().min(t_secs.len()).min(interpolated.len());
    let mut last_clean: Option<usize> = None;
    for i in 0..n {
        interpolated[i] = false;
        if !values[i].is_finite() {
            continue;
        }
        if let Some(a) = last_clean
            && i > a + 1
        {
            let (ta, tb) = (t_secs[a], t_secs[i]);
            let (va, vb) = (values[a], values[i]);
            if tb - ta <= max_gap_s && tb > ta {
                for k in a + 1..i {
                    let f = ((t_secs[k] - ta) / (tb - ta)).clamp(0.0, 1.0) as f32;
                    values[k] = va + (vb - va) * f;
                    interpolated[k] = true;
                }
            }
        }
        last_clean = Some(i);
    }
}

/// `median + n · MAD` of `values` (MAD: the median absolute deviation from
/// the median, unscaled, as Kret & Sjak-Shie 2019). `scratch` is reused.
///
/// One departure, for quantised trackers: where most speeds are equal
/// (EyeLink's integer area units, a pupil that rests) the MAD is 0 and the
/// threshold would fall to the median, rejecting every change of one unit;
/// the spread used is never below half the mean absolute deviation.
pub fn median_plus_mad(values: &[f32], scratch: &mut Vec<f32>, n: f64) -> f32 {
    scratch.clear();
    scratch.extend_from_slice(values);
    let median = median_in_place(scratch);
    let mut sum = 0.0f64;
    for v in scratch.iter_mut() {
        *v = (*v - median).abs();
        sum += f64::from(*v);
    }
    let mean_abs_dev = (sum / scratch.len().max(1) as f64) as f32;
    let mad = median_in_place(scratch);
    median + (n as f32) * mad.max(0.5 * mean_abs_dev)
}

fn median_in_place(v: &mut [f32]) -> f32 {
    if v.is_empty() {
        return f32::NAN;
    }
    let mid = v.len() / 2;
    let (_, m, _) = v.select_nth_unstable_by(mid, f32::total_cmp);
    let m = *m;
    if v.len() % 2 == 1 {
        m
    } else {
        let below = v[..mid].iter().copied().fold(f32::NEG_INFINITY, f32::max);
        0.5 * (m + below)
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    fn sample(seq: u64, t: f64, v: f32, fate: SampleFate) -> TrackSample {
        TrackSample {
            seq,
            t_secs: t,
            eye: 0,
            method: DetectorMethod::Other,
            value: v,
            unit: PupilUnit::Mm,
            aperture_mm: v,
            fate,
        }
    }

    fn run(track: &mut CleanTrack, input: &[TrackSample]) -> Vec<TrackSample> {
        let mut out = Vec::new();
        for s in input {
            track.push(*s);
            while let Some(d) = track.pop_ready() {
                out.push(d);
            }
        }
        track.flush();
        while let Some(d) = track.pop_ready() {
            out.push(d);
        }
        out
    }

    /// A 200 Hz stream with a 100 ms blink: exactly the samples within
    /// 50 ms before and after the lost ones are discarded, the others pass
    /// unchanged, and the order and count are kept.
    #[test]
    fn margins_around_a_blink_and_clean_samples_unchanged() {
        let mut input = Vec::new();
        for i in 0..200u64 {
            let t = i as f64 * 0.005;
            let lost = (100..120).contains(&i); // 0.500 ..= 0.595 s
            let v = 4.0 + 0.001 * (i % 7) as f32;
            input.push(sample(
                i,
                t,
                if lost { 0.0 } else { v },
                if lost {
                    SampleFate::Lost
                } else {
                    SampleFate::Clean
                },
            ));
        }
        let out = run(&mut CleanTrack::new(CleanConfig::default()), &input);
        assert_eq!(out.len(), input.len());
        for (o, i) in out.iter().zip(&input) {
            assert_eq!(o.seq, i.seq);
            let t = i.t_secs;
            let expected = if i.fate == SampleFate::Lost {
                SampleFate::Lost
            } else if (0.5 - t) <= 0.05 + 1e-9 && t < 0.5 || (t - 0.595) <= 0.05 + 1e-9 && t > 0.595
            {
                SampleFate::Margin
            } else {
                SampleFate::Clean
            };
            assert_eq!(o.fate, expected, "t = {t}");
            assert_eq!(o.value, i.value, "values pass unchanged");
        }
    }

    /// One spike in a smooth, noisy series is a speed outlier; its
    /// neighbours (whose speed to it is high too) are the only others
    /// caught, as in Kret & Sjak-Shie's definition.
    #[test]
    fn a_spike_is_a_speed_outlier() {
        let mut input = Vec::new();
        for i in 0..400u64 {
            let t = i as f64 * 0.002;
            let noise = ((i * 7919) % 13) as f32 * 0.002;
            let mut v = 5.0 + 0.5 * (t as f32).sin() + noise;
            if i == 300 {
                v += 1.5;
            }
            input.push(sample(i, t, v, SampleFate::Clean));
        }
        let out = run(&mut CleanTrack::new(CleanConfig::default()), &input);
        let speed: Vec<u64> = out
            .iter()
            .filter(|s| s.fate == SampleFate::Speed)
            .map(|s| s.seq)
            .collect();
        assert!(speed.contains(&300), "{speed:?}");
        assert!(speed.iter().all(|&i| (299..=301).contains(&i)), "{speed:?}");
    }

    /// Decisions wait for the margin: nothing comes out before the stream
    /// has moved `margin_before_s + min_lost_s` past a sample.
    #[test]
    fn decisions_wait_for_the_margin() {
        let mut t = CleanTrack::new(CleanConfig::default());
        t.push(sample(0, 0.0, 4.0, SampleFate::Clean));
        t.push(sample(1, 0.07, 4.0, SampleFate::Clean));
        assert!(t.pop_ready().is_none());
        t.push(sample(2, 0.09, 4.0, SampleFate::Clean));
        assert_eq!(t.pop_ready().map(|s| s.seq), Some(0));
        assert!(t.pop_ready().is_none());
    }

    /// A single lost frame (shorter than `min_lost_s`) is a dropout, not a
    /// blink: its neighbours stay clean.
    #[test]
    fn a_lost_frame_gets_no_margins() {
        let input: Vec<TrackSample> = (0..100u64)
            .map(|i| {
                let t = i as f64 * 0.005;
                if i == 50 {
                    sample(i, t, 0.0, SampleFate::Lost)
                } else {
                    sample(i, t, 4.0, SampleFate::Clean)
                }
            })
            .collect();
        let out = run(&mut CleanTrack::new(CleanConfig::default()), &input);
        let not_clean: Vec<u64> = out
            .iter()
            .filter(|s| !s.fate.is_clean())
            .map(|s| s.seq)
            .collect();
        assert_eq!(not_clean, [50]);
    }

    #[test]
    fn gaps_are_bridged_by_straight_lines_and_clean_samples_kept() {
        let t: Vec<f64> = (0..10).map(|i| i as f64 * 0.1).collect();
        let nan = f32::NAN;
        let mut v = vec![1.0, 2.0, nan, nan, 5.0, nan, 7.0, nan, nan, nan];
        let mut m = vec![false; 10];
        interpolate_gaps(&t, &mut v, &mut m, 1.0);
        assert_eq!(&v[..7], &[1.0, 2.0, 3.0, 4.0, 5.0, 6.0, 7.0]);
        assert!(v[7..].iter().all(|x| x.is_nan()), "no clean sample after");
        assert_eq!(
            m,
            [
                false, false, true, true, false, true, false, false, false, false
            ]
        );
        // A gap longer than the bound stays empty.
        let mut v = vec![1.0, nan, nan, nan, 5.0];
        let mut m = vec![false; 5];
        interpolate_gaps(&t[..5], &mut v, &mut m, 0.3);
        assert!(v[1..4].iter().all(|x| x.is_nan()) && !m.iter().any(|&b| b));
    }

    #[test]
    fn median_and_mad() {
        let mut scratch = Vec::new();
        // median 3, deviations 2 1 0 1 7 → MAD 1 (mean 2.2: half is 1.1).
        let t = median_plus_mad(&[1.0, 2.0, 3.0, 4.0, 10.0], &mut scratch, 16.0);
        assert!((t - (3.0 + 16.0 * 1.1)).abs() < 1e-5, "{t}");
        // median 3, deviations 2 1 0 1 1 → MAD 1 (mean 1: half is 0.5).
        assert_eq!(
            median_plus_mad(&[1.0, 2.0, 3.0, 4.0, 4.0], &mut scratch, 16.0),
            19.0
        );
        assert_eq!(median_plus_mad(&[1.0, 3.0], &mut scratch, 0.0), 2.0);
        // Quantised: nine equal speeds and one step → MAD 0; the spread is
        // half the mean absolute deviation (0.1).
        let mut q = vec![0.0f32; 9];
        q.push(1.0);
        assert!((median_plus_mad(&q, &mut scratch, 16.0) - 0.8).abs() < 1e-6);
    }

    #[test]
    fn config_is_checked() {
        assert!(CleanConfig::default().validate().is_ok());
        let bad = CleanConfig {
            margin_before_s: -1.0,
            ..CleanConfig::default()
        };
        assert!(
            bad.validate()
                .unwrap_err()
                .to_string()
                .contains("margin_before_s")
        );
    }
}
