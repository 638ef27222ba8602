//! Summary of a recording (or a stretch of a live stream) after the filter
//! chain: what `gazelight inspect` prints.
//!
//! [`Summarizer`] is fed samples one by one (from an importer, a replay or a
//! live source) and runs them through a [`FilterChain`]; [`summarize`] and
//! [`summarize_importer`] do it for a whole iterator, [`summarize_live`]
//! for a stretch of a live Pupil stream. The result,
//! [`RecordingSummary`], serialises to JSON with the keys `samples`,
//! `rate_hz`, `duration_s`, `blinks`, `dropouts`, `pupil`,
//! `invalid_after_filter`, `clock_offset_s` (plus details), and displays as
//! a readable multi-line report.
//!
//! Medians need the values: the summariser keeps the raw and filtered pupil
//! of every sample (8 bytes per sample — 2.3 MB for an hour at 2 × 200 Hz).

use std::fmt;
use std::time::Duration;

use serde::Serialize;

use crate::{ImportError, ImportWarnings, Importer};
use gazelight_eye::filter::{ChainStats, FilterChain, PupilOutcome, PupilStreamCounts};
use gazelight_eye::sample::{PupilUnit, Sample};
use gazelight_pupil::{PupilClient, PupilConfig};

/// Intervals longer than this (s) are recording pauses, not sampling.
pub const GAP_S: f64 = 0.5;

/// Minimum, median and maximum of a series.
#[derive(Clone, Copy, Debug, Default, PartialEq, Serialize)]
pub struct Range {
    pub min: f64,
    pub median: f64,
    pub max: f64,
}

impl Range {
    /// Of the finite values in `v` (sorted in place); `None` if there are none.
    fn of(v: &mut Vec<f32>) -> Option<Self> {
        v.retain(|x| x.is_finite());
        if v.is_empty() {
            return None;
        }
        v.sort_by(f32::total_cmp);
        let n = v.len();
        let median = if n % 2 == 1 {
            v[n / 2] as f64
        } else {
            0.5 * (v[n / 2 - 1] as f64 + v[n / 2] as f64)
        };
        Some(Self {
            min: v[0] as f64,
            median,
            max: v[n - 1] as f64,
        })
    }
}

/// Sample counts per stream.
#[derive(Clone, Copy, Debug, Default, PartialEq, Serialize)]
pub struct SampleCounts {
    /// Pupil samples per eye (0 right, 1 left).
    pub pupil: [u64; 2],
    /// Binocular gaze samples (or a monocular tracker's gaze).
    pub gaze: u64,
    /// Per-eye gaze samples beside binocular ones (EyeLink binocular, Neon
    /// live, Pupil's monocular topics): each eye's own gaze for stereo.
    pub gaze_per_eye: u64,
    pub blink_events: u64,
}

/// Sample rates, Hz: intervals between consecutive samples of one stream
/// over their summed duration, leaving out gaps longer than [`GAP_S`]
/// (pauses between the trials of a recording).
#[derive(Clone, Copy, Debug, Default, PartialEq, Serialize)]
pub struct Rates {
    /// Per eye: the rate of that eye's fastest pupil stream (a detector:
    /// Pupil Core's 2D and 3D are two streams at the tracker's rate).
    pub pupil: [f64; 2],
    /// Binocular gaze (or a monocular tracker's gaze).
    pub gaze: f64,
}

/// One stream of a recording: one eye's pupils from one detector.
#[derive(Clone, Debug, PartialEq, Serialize)]
pub struct StreamSummary {
    /// `2d`, `3d` (Pupil Core's detectors) or `pupil` (any other).
    pub detector: &'static str,
    pub samples: u64,
    pub rate_hz: f64,
    /// Fraction of the samples rejected by the filter (blink, low
    /// confidence, no pupil, out of range, too fast); `None` for a stream
    /// in raw units without a calibration, which the chain cannot use.
    pub dropout_fraction: Option<f64>,
    /// Samples in raw units with no calibration for them.
    pub uncalibrated: u64,
}

/// One eye's pupil statistics.
#[derive(Clone, Copy, Debug, Default, PartialEq, Serialize)]
pub struct EyePupil {
    /// Unit of the raw values (the first seen).
    pub unit: Option<PupilUnit>,
    /// Raw values > 0 (0 = lost is excluded).
    pub raw: Option<Range>,
    /// The clean measured pupils of this eye (after the guideline
    /// cleaning, unchanged values), mm; `None` where the pupil is in raw
    /// units without a physical scale.
    pub filtered_mm: Option<Range>,
    /// The clean measured pupils in the raw unit (no physical scale).
    pub measured_raw: Option<Range>,
    /// Mean reported confidence.
    pub confidence_mean: f64,
    /// Fraction of samples below the confidence gate.
    pub low_confidence_fraction: f64,
    /// Fraction of the samples the chain could measure that it rejected
    /// (blink, low confidence, no pupil, out of range, too fast); samples
    /// in raw units without a calibration are not counted (Pupil Core's
    /// 2D pixels beside its 3D millimetres), and with nothing measurable
    /// it is 1.
    pub dropout_fraction: f64,
}

/// Blink counts: the recording's own events and the chain's detector.
#[derive(Clone, Copy, Debug, Default, PartialEq, Serialize)]
pub struct Blinks {
    /// Source blink events for eye 0, eye 1, both eyes.
    pub recording: [u64; 3],
    /// Blinks the chain's detector found, per eye.
    pub detected: [u64; 2],
}

/// The summary.
#[derive(Clone, Debug, Default, PartialEq, Serialize)]
pub struct RecordingSummary {
    /// Importer format, when known.
    pub format: Option<String>,
    pub duration_s: f64,
    /// The first sample's time on the recording's clock (the samples'
    /// `t_secs`, Python's `read()` times), s; `None` without samples.
    /// `replay`/`render`'s `timeline.csv` counts from the first frame:
    /// their `t_secs` + this (+ `--from-secs`) is the recording's time.
    pub first_sample_secs: Option<f64>,
    pub samples: SampleCounts,
    pub rate_hz: Rates,
    pub pupil: [EyePupil; 2],
    /// Per eye (0 right, 1 left), its pupil streams by detector.
    pub streams: [Vec<StreamSummary>; 2],
    pub blinks: Blinks,
    /// Closures too short or too long to be blinks, per eye.
    pub dropouts: [u64; 2],
    /// Filtered pupils that were 0 or NaN (must be 0).
    pub invalid_after_filter: u64,
    /// Host–tracker clock offset and its spread (live sources; the caller
    /// fills it in).
    pub clock_offset_s: Option<ClockOffset>,
    /// Records the importer skipped.
    pub skipped_records: u64,
    pub warnings: Vec<String>,
    /// Per-eye gaze as the importer reports it (Neon: from the eye state
    /// and calibration.bin, or binocular only); `None` for formats whose
    /// samples say it themselves, and for live summaries.
    pub eye_gaze: Option<crate::EyeGazeReport>,
    /// The chain's counters.
    pub chain: ChainStats,
    /// The recording's events ([`crate::events`]), where the caller read
    /// them (`inspect` does).
    #[serde(skip_serializing_if = "Option::is_none")]
    pub events: Option<crate::events::EventSummary>,
}

/// A clock offset estimate (live sources).
#[derive(Clone, Copy, Debug, PartialEq, Serialize)]
pub struct ClockOffset {
    /// Tracker time − host time, s (the newest estimate).
    pub offset_s: f64,
    /// Range of the offsets of that estimate's probes, s.
    pub spread_s: f64,
    /// Round trip of the best probe, s; the offset's error is at most half
    /// of it.
    pub rtt_s: f64,
    /// Drift of the tracker's clock against the host's, s/s, when several
    /// estimates were made.
    pub drift_s_per_s: Option<f64>,
}

/// Incremental summariser.
pub struct Summarizer {
    chain: FilterChain,
    first_t: f64,
    last_t: f64,
    /// Per stream (eye × detector: 2D, 3D, other; then binocular and
    /// per-eye gaze): last time, intervals, their sum.
    intervals: [(f64, u64, f64); 8],
    /// Per eye and detector.
    outcomes: [[PupilStreamCounts; PupilStreamCounts::DETECTORS]; 2],
    counts: SampleCounts,
    unit: [Option<PupilUnit>; 2],
    raw: [Vec<f32>; 2],
    filtered: [Vec<f32>; 2],
    measured_raw: [Vec<f32>; 2],
    conf_sum: [f64; 2],
    invalid: u64,
}

impl Summarizer {
    pub fn new(mut chain: FilterChain) -> Self {
        chain.keep_decided();
        Self {
            chain,
            first_t: f64::INFINITY,
            last_t: f64::NEG_INFINITY,
            intervals: [(f64::NAN, 0, 0.0); 8],
            outcomes: Default::default(),
            counts: SampleCounts::default(),
            unit: [None; 2],
            raw: [Vec::new(), Vec::new()],
            filtered: [Vec::new(), Vec::new()],
            measured_raw: [Vec::new(), Vec::new()],
            conf_sum: [0.0; 2],
            invalid: 0,
        }
    }

    /// The chain (e.g. to feed back a luminance).
    pub fn chain_mut(&mut self) -> &mut FilterChain {
        &mut self.chain
    }

    /// Feeds one sample.
    pub fn push(&mut self, s: &Sample) {
        let up = self.chain.push(s);
        self.take_decided();
        let t = s.t_secs();
        if t.is_finite() {
            self.first_t = self.first_t.min(t);
            self.last_t = self.last_t.max(t);
        }
        let mut span = |k: usize| {
            let (last, n, sum) = &mut self.intervals[k];
            if t.is_finite() {
                let dt = t - *last;
                if dt > 0.0 && dt <= GAP_S {
                    *n += 1;
                    *sum += dt;
                }
                if dt >= 0.0 || dt.is_nan() {
                    *last = t;
                }
            }
        };
        match s {
            Sample::Pupil(p) if p.eye <= 1 => {
                let e = p.eye as usize;
                let m = PupilStreamCounts::detector_index(p.method);
                span(PupilStreamCounts::DETECTORS * e + m);
                self.counts.pupil[e] += 1;
                self.unit[e].get_or_insert(p.unit);
                if p.diameter_raw > 0.0 && p.diameter_raw.is_finite() {
                    self.raw[e].push(p.diameter_raw);
                }
                if p.confidence.is_finite() {
                    self.conf_sum[e] += p.confidence.clamp(0.0, 1.0) as f64;
                }
                let f = up.state.eyes[e].pupil_mm;
                if !(f.is_finite() && f > 0.0) {
                    self.invalid += 1;
                }
            }
            Sample::Pupil(_) => {}
            Sample::Gaze(g) => {
                span(if g.eyes == gazelight_eye::GazeEyes::Binocular {
                    6
                } else {
                    7
                });
                if g.eyes == gazelight_eye::GazeEyes::Binocular {
                    self.counts.gaze += 1;
                } else {
                    self.counts.gaze_per_eye += 1;
                }
            }
            Sample::Blink(_) => self.counts.blink_events += 1,
        }
    }

    /// The chain's decided pupil samples into the per-stream outcomes and
    /// the measured ranges (what was measured: clean samples only).
    fn take_decided(&mut self) {
        for d in self.chain.take_decided() {
            let e = usize::from(d.eye & 1);
            let m = PupilStreamCounts::detector_index(d.method);
            self.outcomes[e][m].add(PupilOutcome::from(d.fate));
            if d.fate.is_clean() {
                if d.unit == PupilUnit::Mm {
                    self.filtered[e].push(d.value);
                } else {
                    self.measured_raw[e].push(d.value);
                }
            }
        }
    }

    /// Finishes: flushes pending blinks and computes the summary.
    pub fn finish(mut self, format: Option<&str>, warnings: &ImportWarnings) -> RecordingSummary {
        let end = if self.last_t.is_finite() {
            self.last_t
        } else {
            0.0
        };
        self.chain.finish(end);
        self.take_decided();
        let stats = *self.chain.stats();
        let rate = |(_, n, sum): (f64, u64, f64)| if n > 0 { n as f64 / sum } else { 0.0 };
        let mut pupil = [EyePupil::default(); 2];
        let mut streams: [Vec<StreamSummary>; 2] = [Vec::new(), Vec::new()];
        let mut eye_rate = [0.0f64; 2];
        for (e, ep) in pupil.iter_mut().enumerate() {
            let n = self.counts.pupil[e];
            let nf = n.max(1) as f64;
            // Dropouts among the samples of the streams the chain can use.
            let mut usable = PupilStreamCounts::default();
            for (m, detector) in ["2d", "3d", "pupil"].into_iter().enumerate() {
                let c = self.outcomes[e][m];
                if c.samples == 0 {
                    continue;
                }
                let r = rate(self.intervals[PupilStreamCounts::DETECTORS * e + m]);
                eye_rate[e] = eye_rate[e].max(r);
                usable.add_usable(&c);
                streams[e].push(StreamSummary {
                    detector,
                    samples: c.samples,
                    rate_hz: r,
                    dropout_fraction: c.dropout_rate(),
                    uncalibrated: c.uncalibrated,
                });
            }
            *ep = EyePupil {
                unit: self.unit[e],
                raw: Range::of(&mut self.raw[e]),
                filtered_mm: Range::of(&mut self.filtered[e]),
                measured_raw: Range::of(&mut self.measured_raw[e]),
                confidence_mean: self.conf_sum[e] / nf,
                low_confidence_fraction: stats.rejected_confidence[e] as f64 / nf,
                dropout_fraction: if n == 0 {
                    0.0
                } else {
                    usable.dropout_rate().unwrap_or(1.0)
                },
            };
        }
        RecordingSummary {
            format: format.map(str::to_owned),
            duration_s: if self.last_t >= self.first_t {
                self.last_t - self.first_t
            } else {
                0.0
            },
            first_sample_secs: self.first_t.is_finite().then_some(self.first_t),
            samples: self.counts,
            rate_hz: Rates {
                pupil: eye_rate,
                gaze: if self.counts.gaze > 0 {
                    rate(self.intervals[6])
                } else {
                    rate(self.intervals[7])
                },
            },
            pupil,
            streams,
            blinks: Blinks {
                recording: stats.source_blinks,
                detected: stats.blinks,
            },
            dropouts: stats.dropouts,
            invalid_after_filter: self.invalid + stats.invalid_output,
            clock_offset_s: None,
            skipped_records: warnings.skipped_records,
            warnings: warnings.messages.clone(),
            eye_gaze: None,
            events: None,
            chain: stats,
        }
    }
}

/// Summarises a stream of samples through `chain`; stops at the first
/// structure error.
pub fn summarize<I>(samples: I, chain: FilterChain) -> Result<RecordingSummary, ImportError>
where
    I: IntoIterator<Item = Result<Sample, ImportError>>,
{
    let mut s = Summarizer::new(chain);
    for sample in samples {
        s.push(&sample?);
    }
    Ok(s.finish(None, &ImportWarnings::default()))
}

/// Summarises a whole import, including its format and counted warnings.
pub fn summarize_importer(
    importer: &mut dyn Importer,
    chain: FilterChain,
) -> Result<RecordingSummary, ImportError> {
    let mut s = Summarizer::new(chain);
    for sample in &mut *importer {
        s.push(&sample?);
    }
    let format = importer.format();
    let mut summary = s.finish(Some(format), importer.warnings());
    summary.eye_gaze = importer.eye_gaze().cloned();
    Ok(summary)
}

/// Warn when at most this fraction of an eye's pupil samples were measured.
pub const MEASURED_WARN_FRACTION: f64 = 0.05;
/// …and the eye has at least this many pupil samples.
const MIN_PUPIL_SAMPLES: u64 = 20;

/// What a user must know about a recording's pupils, from the chain's
/// counters, as one warning (`None` when all is well): an eye whose pupil
/// samples were (nearly) all rejected, naming the likely cause and the
/// fix; an eye measured only in raw tracker units, with no physical scale
/// (so no pupil in mm, and the glare aperture follows the light model
/// unless a black/white profile maps it). The one rule for `inspect`,
/// `replay`, `batch` and the Python package.
pub fn pupil_rejection(stats: &ChainStats) -> Option<String> {
    use gazelight_eye::filter::physio::PUPIL_MM_RANGE;
    let eyes = ["right (0)", "left (1)"];
    let mut lines = Vec::new();
    let mut raw_only = Vec::new();
    for (e, eye) in eyes.iter().enumerate() {
        let n = stats.pupil_samples[e];
        if n < MIN_PUPIL_SAMPLES {
            continue;
        }
        let measured = stats.measured[e];
        if measured as f64 > MEASURED_WARN_FRACTION * n as f64 {
            if stats.uncalibrated[e] * 2 > measured {
                raw_only.push(*eye);
            }
            continue;
        }
        let reasons = [
            (
                stats.rejected_range[e],
                format!(
                    "are outside the physiological range {}–{} mm: \
                     the pupil is probably not in millimetres (pixels, area units or µm); \
                     convert it, or give its unit (a CSV column named `left_px`/`right_px`) \
                     and a --calibration FILE mapping it to mm",
                    PUPIL_MM_RANGE.0, PUPIL_MM_RANGE.1
                ),
            ),
            (
                stats.rejected_confidence[e],
                "are below the confidence gate: the tracker lost the pupil, or its \
                 confidence column is on another scale"
                    .to_string(),
            ),
            (
                stats.rejected_non_positive[e] + stats.rejected_not_finite[e],
                "are 0, negative or NaN (lost pupils)".to_string(),
            ),
            (
                stats.rejected_rate[e],
                "are dilation-speed outliers (noise, or a wrong time unit)".to_string(),
            ),
            (
                stats.discarded_margin[e],
                "lie within the margins around lost samples (a tracker that loses the \
                 pupil every few samples)"
                    .to_string(),
            ),
            (
                stats.other_stream[e],
                "belong to another stream of the eye than the one measured".to_string(),
            ),
        ];
        let (count, why) = reasons
            .iter()
            .max_by_key(|(c, _)| *c)
            .map(|(c, w)| (*c, w.as_str()))
            .unwrap_or((0, ""));
        lines.push(format!(
            "eye {}: only {measured} of {n} pupil samples were accepted; {count} of them {why}",
            eye
        ));
    }
    let mut out = Vec::new();
    if !lines.is_empty() {
        out.push(format!(
            "nearly all pupil samples were rejected, so nothing is measured and the glare \
             aperture falls back to the light-adaptation model: {}",
            lines.join("; ")
        ));
    }
    if !raw_only.is_empty() {
        out.push(format!(
            "eye {}: the pupil is measured in raw tracker units (px or area) with no physical \
             scale, so no pupil in mm is written (the measured pupil is given in the raw unit); \
             for mm give --calibration with a profile made by `gazelight profile scale` (a known \
             mm per unit); a black/white profile (`calibrate`, `profile phases`) sizes only the \
             glare aperture",
            raw_only.join(" and ")
        ));
    }
    (!out.is_empty()).then(|| out.join("; "))
}

/// Why a live summary failed.
#[derive(Debug, thiserror::Error)]
pub enum LiveSummaryError {
    /// No session with Pupil Remote could be established in time.
    #[error("no connection to {endpoint} within {after_ms} ms: {reason}")]
    NoConnection {
        endpoint: String,
        after_ms: u128,
        reason: String,
    },
    /// The client stopped while collecting.
    #[error("the Pupil client stopped while collecting from {endpoint}")]
    Stopped { endpoint: String },
}

/// Connects to a Pupil Remote (Capture or Service), collects samples for
/// `duration` (host time, from the moment the session is established),
/// runs them through `chain` and summarises them, with the clock offset
/// fields filled from the client's newest estimate. The client's counters
/// become the warnings: malformed messages are the skipped records,
/// unknown topics, samples dropped by a lagging consumer and reconnections
/// are listed. Waiting for the connection is bounded by one connect
/// timeout plus the requests of a handshake (`SUB_PORT`, `v`, the clock
/// probes) with their timeouts.
pub async fn summarize_live(
    config: PupilConfig,
    duration: Duration,
    chain: FilterChain,
) -> Result<RecordingSummary, LiveSummaryError> {
    let endpoint = format!("pupil://{}:{}", config.host, config.remote_port);
    let connect_limit =
        config.connect_timeout * 2 + config.request_timeout * (config.clock_probes as u32 + 2);
    let (client, streams) = PupilClient::spawn(config);
    let mut samples = streams.samples;
    if let Err(e) = client.wait_connected(connect_limit).await {
        let reason = client.stats().last_error.unwrap_or_else(|| e.to_string());
        client.shutdown().await;
        return Err(LiveSummaryError::NoConnection {
            endpoint,
            after_ms: connect_limit.as_millis(),
            reason,
        });
    }
    let mut summarizer = Summarizer::new(chain);
    let deadline = tokio::time::Instant::now() + duration;
    loop {
        match tokio::time::timeout_at(deadline, samples.recv()).await {
            Ok(Some(s)) => summarizer.push(&s),
            Ok(None) => {
                client.shutdown().await;
                return Err(LiveSummaryError::Stopped { endpoint });
            }
            Err(_) => break,
        }
    }
    let stats = client.stats();
    client.shutdown().await;
    let mut warnings = ImportWarnings {
        skipped_records: stats.malformed,
        messages: Vec::new(),
    };
    for (n, what) in [
        (stats.malformed, "malformed messages skipped"),
        (stats.unknown_topic, "messages with unknown topics ignored"),
        (stats.dropped, "samples dropped (consumer too slow)"),
        (stats.reconnects, "reconnections"),
    ] {
        if n > 0 {
            warnings.messages.push(format!("{endpoint}: {n} {what}"));
        }
    }
    let mut summary = summarizer.finish(Some("pupil-live"), &warnings);
    summary.clock_offset_s = stats.clock.map(|c| ClockOffset {
        offset_s: c.offset_secs,
        spread_s: c.spread_secs,
        rtt_s: c.rtt_secs,
        drift_s_per_s: stats.drift_secs_per_sec,
    });
    Ok(summary)
}

fn unit_name(u: Option<PupilUnit>) -> &'static str {
    match u {
        Some(PupilUnit::Px) => "px",
        Some(PupilUnit::Mm) => "mm",
        Some(PupilUnit::ArbitraryArea) => "area units",
        Some(PupilUnit::Arbitrary) => "arb. units",
        None => "-",
    }
}

impl fmt::Display for RecordingSummary {
    #[allow(clippy::needless_range_loop)] // e indexes several per-eye arrays
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        let eyes = ["right (0)", "left (1)"];
        writeln!(
            f,
            "recording{}: {:.2} s",
            self.format
                .as_deref()
                .map(|x| format!(" [{x}]"))
                .unwrap_or_default(),
            self.duration_s
        )?;
        if let Some(t0) = self.first_sample_secs {
            writeln!(
                f,
                "  times: the recording's clock, s (first sample at {t0:.6} s; replay's \
                 timeline.csv counts from it: t_secs + {t0:.6} s)"
            )?;
        }
        write!(
            f,
            "  gaze: {} samples, {:.1} Hz",
            self.samples.gaze, self.rate_hz.gaze
        )?;
        if self.samples.gaze_per_eye > 0 {
            write!(f, " (+{} per-eye samples)", self.samples.gaze_per_eye)?;
        }
        writeln!(f)?;
        match &self.eye_gaze {
            Some(g) if !g.per_eye => writeln!(
                f,
                "  per-eye gaze: none ({}); the binocular gaze stands in for both eyes",
                g.reason.as_deref().unwrap_or("not in the recording")
            )?,
            Some(g) => {
                write!(
                    f,
                    "  per-eye gaze: right {}, left {} (rows without: right {}, left {})",
                    g.emitted[0], g.emitted[1], g.missing[0], g.missing[1]
                )?;
                for (e, c) in g.correction_deg.iter().enumerate() {
                    if let Some([x, y]) = c {
                        write!(
                            f,
                            "; {} corrected by ({x:+.2}°, {y:+.2}°)",
                            ["right", "left"][e]
                        )?;
                    }
                }
                writeln!(f)?;
            }
            None => {}
        }
        for e in 0..2 {
            let p = &self.pupil[e];
            if self.samples.pupil[e] == 0 {
                writeln!(f, "  eye {}: no samples", eyes[e])?;
                continue;
            }
            writeln!(
                f,
                "  eye {}: {} samples, {:.1} Hz",
                eyes[e], self.samples.pupil[e], self.rate_hz.pupil[e]
            )?;
            let r = |r: &Option<Range>| {
                r.map_or("-".to_owned(), |r| {
                    format!("{:.3} / {:.3} / {:.3}", r.min, r.median, r.max)
                })
            };
            writeln!(
                f,
                "    pupil raw   min/median/max: {} {}",
                r(&p.raw),
                unit_name(p.unit)
            )?;
            writeln!(
                f,
                "    pupil filt. min/median/max: {} mm",
                r(&p.filtered_mm)
            )?;
            writeln!(
                f,
                "    confidence mean {:.3}, below gate {:.1} %, dropouts {:.1} %",
                p.confidence_mean,
                100.0 * p.low_confidence_fraction,
                100.0 * p.dropout_fraction
            )?;
            if self.streams[e].len() > 1 || self.streams[e].iter().any(|s| s.detector != "pupil") {
                let parts: Vec<String> = self.streams[e]
                    .iter()
                    .map(|s| match s.dropout_fraction {
                        Some(d) => format!(
                            "{} {:.1} Hz, dropouts {:.1} %",
                            s.detector,
                            s.rate_hz,
                            100.0 * d
                        ),
                        None => format!(
                            "{} {:.1} Hz, raw units without a calibration (not used)",
                            s.detector, s.rate_hz
                        ),
                    })
                    .collect();
                writeln!(f, "    streams: {}", parts.join("; "))?;
            }
            if self.chain.uncalibrated[e] > 0 {
                writeln!(
                    f,
                    "    {} samples in raw units without a calibration (no mm value)",
                    self.chain.uncalibrated[e]
                )?;
            }
            writeln!(
                f,
                "    blinks: detected {}, recording {} (+{} both eyes); other dropouts {}",
                self.blinks.detected[e],
                self.blinks.recording[e],
                self.blinks.recording[2],
                self.dropouts[e]
            )?;
        }
        writeln!(
            f,
            "  filtered pupils that were 0 or NaN: {}",
            self.invalid_after_filter
        )?;
        if let Some(c) = self.clock_offset_s {
            writeln!(
                f,
                "  clock offset {:.6} s (spread {:.6} s, round trip {:.6} s)",
                c.offset_s, c.spread_s, c.rtt_s
            )?;
            if let Some(d) = c.drift_s_per_s {
                writeln!(f, "  clock drift {:.3e} s/s", d)?;
            }
        }
        if let Some(e) = &self.events {
            write!(f, "{e}")?;
        }
        write!(f, "  skipped records: {}", self.skipped_records)?;
        for w in &self.warnings {
            write!(f, "\n    {w}")?;
        }
        Ok(())
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use gazelight_eye::synthetic::{SyntheticConfig, SyntheticTrace};

    /// A Pupil Core at 200 Hz: per eye a 2D datum in pixels (no
    /// calibration) and a 3D datum in mm, 1 ms apart. Per eye 200 Hz and
    /// 0 % dropouts (before: the 2D half counted as "not measured", 50 %,
    /// and the two detectors' interleaved stamps as one 400 Hz stream).
    #[test]
    fn a_pupil_core_reads_its_rate_per_eye_and_no_dropouts() {
        use gazelight_eye::sample::{DetectorMethod, PupilSample};
        let mut samples = Vec::new();
        for i in 0..2000 {
            let t = f64::from(i) / 200.0;
            for eye in 0..2u8 {
                let two_d = PupilSample {
                    t_secs: t,
                    eye,
                    diameter_raw: 31.5,
                    unit: PupilUnit::Px,
                    diameter_mm: None,
                    confidence: 0.91,
                    norm_pos: [0.4, 0.5],
                    method: DetectorMethod::Pupil2d,
                };
                let three_d = PupilSample {
                    t_secs: t + 0.001,
                    diameter_raw: 3.75,
                    unit: PupilUnit::Mm,
                    diameter_mm: Some(3.75),
                    method: DetectorMethod::Pupil3d,
                    ..two_d
                };
                samples.push(Ok(Sample::Pupil(two_d)));
                samples.push(Ok(Sample::Pupil(three_d)));
            }
        }
        let s = summarize(samples, FilterChain::with_defaults()).unwrap();
        for e in 0..2 {
            assert!((s.rate_hz.pupil[e] - 200.0).abs() < 0.01, "{:?}", s.rate_hz);
            assert_eq!(s.pupil[e].dropout_fraction, 0.0, "{:?}", s.pupil[e]);
            let st = &s.streams[e];
            assert_eq!(st.len(), 2, "{st:?}");
            assert_eq!((st[0].detector, st[0].dropout_fraction), ("2d", None));
            assert_eq!(st[0].uncalibrated, 2000);
            assert_eq!((st[1].detector, st[1].dropout_fraction), ("3d", Some(0.0)));
            assert!((st[1].rate_hz - 200.0).abs() < 0.01);
        }
        let text = s.to_string();
        assert!(text.contains("dropouts 0.0 %"), "{text}");
        assert!(
            text.contains("streams: 2d 200.0 Hz, raw units without a calibration (not used); 3d 200.0 Hz, dropouts 0.0 %"),
            "{text}"
        );
    }

    #[test]
    fn summary_of_a_synthetic_trace() {
        let cfg = SyntheticConfig {
            duration_s: 30.0,
            ..Default::default()
        };
        let samples = SyntheticTrace::new(cfg, |_| 20.0).map(Ok);
        let s = summarize(samples, FilterChain::with_defaults()).unwrap();
        assert_eq!(s.samples.pupil, [6000, 6000]);
        assert!((s.rate_hz.pupil[0] - 200.0).abs() < 0.1, "{:?}", s.rate_hz);
        assert!((s.duration_s - 29.995).abs() < 1e-6);
        assert_eq!(s.invalid_after_filter, 0);
        let true_mm = gazelight_eye::pupil_model::PupilModel::default().pupil_mm(20.0) as f64;
        let f = s.pupil[0].filtered_mm.unwrap();
        assert!((f.median - true_mm).abs() < 0.05, "{f:?} vs {true_mm}");
        // The generator's blinks (both eyes) vs the detector (per eye).
        let truth = s.blinks.recording[2];
        assert!(truth >= 4);
        for e in 0..2 {
            assert!(s.blinks.detected[e].abs_diff(truth) <= 1, "{:?}", s.blinks);
        }
        let text = s.to_string();
        assert!(
            text.contains("eye right (0): 6000 samples, 200.0 Hz"),
            "{text}"
        );
        let json = serde_json::to_value(&s).unwrap();
        for key in [
            "samples",
            "rate_hz",
            "duration_s",
            "blinks",
            "dropouts",
            "pupil",
            "invalid_after_filter",
            "clock_offset_s",
        ] {
            assert!(json.get(key).is_some(), "{key}");
        }
    }
}
