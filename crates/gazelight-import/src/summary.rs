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
use gazelight_eye::filter::{ChainStats, FilterChain};
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

/// Sample rates per stream, Hz: intervals between consecutive samples over
/// their summed duration, leaving out gaps longer than [`GAP_S`] (pauses
/// between the trials of a recording).
#[derive(Clone, Copy, Debug, Default, PartialEq, Serialize)]
pub struct Rates {
    pub pupil: [f64; 2],
    pub gaze: f64,
}

/// One eye's pupil statistics.
#[derive(Clone, Copy, Debug, Default, PartialEq, Serialize)]
pub struct EyePupil {
    /// Unit of the raw values (the first seen).
    pub unit: Option<PupilUnit>,
    /// Raw values > 0 (0 = lost is excluded).
    pub raw: Option<Range>,
    /// The chain's output after each sample of this eye, mm.
    pub filtered_mm: Option<Range>,
    /// Mean reported confidence.
    pub confidence_mean: f64,
    /// Fraction of samples below the confidence gate.
    pub low_confidence_fraction: f64,
    /// Fraction of samples not accepted as measurements.
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
    pub samples: SampleCounts,
    pub rate_hz: Rates,
    pub pupil: [EyePupil; 2],
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
    /// Per stream (pupil 0, pupil 1, gaze): last time, intervals, their sum.
    intervals: [(f64, u64, f64); 3],
    counts: SampleCounts,
    unit: [Option<PupilUnit>; 2],
    raw: [Vec<f32>; 2],
    filtered: [Vec<f32>; 2],
    conf_sum: [f64; 2],
    invalid: u64,
}

impl Summarizer {
    pub fn new(chain: FilterChain) -> Self {
        Self {
            chain,
            first_t: f64::INFINITY,
            last_t: f64::NEG_INFINITY,
            intervals: [(f64::NAN, 0, 0.0); 3],
            counts: SampleCounts::default(),
            unit: [None; 2],
            raw: [Vec::new(), Vec::new()],
            filtered: [Vec::new(), Vec::new()],
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
                span(e);
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
                self.filtered[e].push(f);
            }
            Sample::Pupil(_) => {}
            Sample::Gaze(g) => {
                span(2);
                if g.eyes == gazelight_eye::GazeEyes::Binocular {
                    self.counts.gaze += 1;
                } else {
                    self.counts.gaze_per_eye += 1;
                }
            }
            Sample::Blink(_) => self.counts.blink_events += 1,
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
        let stats = *self.chain.stats();
        let rate = |(_, n, sum): (f64, u64, f64)| if n > 0 { n as f64 / sum } else { 0.0 };
        let mut pupil = [EyePupil::default(); 2];
        for (e, ep) in pupil.iter_mut().enumerate() {
            let n = self.counts.pupil[e];
            let nf = n.max(1) as f64;
            *ep = EyePupil {
                unit: self.unit[e],
                raw: Range::of(&mut self.raw[e]),
                filtered_mm: Range::of(&mut self.filtered[e]),
                confidence_mean: self.conf_sum[e] / nf,
                low_confidence_fraction: stats.rejected_confidence[e] as f64 / nf,
                dropout_fraction: if n == 0 {
                    0.0
                } else {
                    1.0 - stats.measured[e] as f64 / nf
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
            samples: self.counts,
            rate_hz: Rates {
                pupil: [rate(self.intervals[0]), rate(self.intervals[1])],
                gaze: rate(self.intervals[2]),
            },
            pupil,
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
                "    confidence mean {:.3}, below gate {:.1} %, not measured {:.1} %",
                p.confidence_mean,
                100.0 * p.low_confidence_fraction,
                100.0 * p.dropout_fraction
            )?;
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
