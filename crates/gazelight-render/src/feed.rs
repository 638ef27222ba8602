//! Samples → the filtered eye state at each frame's time.
//!
//! A recording is streamed, never loaded whole: [`scan`] reads only its
//! time range (for the frame count), then [`ImporterSamples`] feeds its
//! samples through [`SampleFeed`] just ahead of the frame clock. A trace
//! (`t_secs,gaze_u,gaze_v,pupil_mm`) is fed the same way.

use std::collections::VecDeque;
use std::path::{Path, PathBuf};

use gazelight_tracker::filter::{ChainStats, FilterChain};
use gazelight_tracker::import::time_guard::TimeStats;
use gazelight_tracker::import::{self, ImportWarnings, Importer};
use gazelight_tracker::live::LiveChain;
use gazelight_tracker::{EyeState, PupilUnit, Sample};

use crate::RenderError;

/// Feeds samples (in time order) through the tracker's one chain
/// ([`LiveChain`]: the filter chain, then the stale → model fallback) on
/// the recording's clock and maps the resulting `EyeState` onto the
/// pipeline's per-frame input, so the PSF never sees a pupil of 0 (the
/// failure of 001 §7.1). Deterministic: no wall clock.
///
/// Look-ahead: the guideline cleaning decides a pupil sample once it knows
/// the margin after it (a blink 50 ms later discards it), so pupil samples
/// are pushed until every eye has one past the frame's time plus that
/// margin, and the chain's horizon is the frame's time
/// ([`gazelight_tracker::filter::FilterChain::set_horizon`]): the state at
/// a frame holds exactly the samples up to it, each decided. Gaze and
/// blink events read ahead wait in a bounded queue until their time.
pub struct SampleFeed<I> {
    samples: I,
    live: LiveChain,
    updates: u64,
    /// Look-ahead beyond the frame's time, s (the cleaning's margin).
    lookahead_s: f64,
    /// Non-pupil samples read ahead, oldest first (bounded).
    backlog: VecDeque<Sample>,
    /// Per eye: the newest pupil sample time read.
    newest_pupil_t: [Option<f64>; 2],
    /// The newest time read.
    lead_t: f64,
    ended: bool,
}

/// Most gaze/blink samples kept back while reading pupil samples ahead
/// (at 2 kHz, 2 s); beyond it they are applied early.
const BACKLOG_CAPACITY: usize = 4096;
/// The farthest the feed reads ahead of a frame for an eye whose samples
/// stopped, s.
const MAX_LOOKAHEAD_S: f64 = 1.0;

impl<I: Iterator<Item = Sample>> SampleFeed<I> {
    pub fn new(samples: I, chain: FilterChain) -> Self {
        // A sample is decided once the stream is this far past it (the
        // margin before a blink, the blink's shortest length), plus 1 ms
        // against rounding.
        let clean = chain.config().clean;
        let lookahead_s = clean.margin_before_s + clean.min_lost_s + 1e-3;
        Self {
            samples,
            live: LiveChain::new(chain),
            updates: 0,
            lookahead_s,
            backlog: VecDeque::with_capacity(BACKLOG_CAPACITY),
            newest_pupil_t: [None; 2],
            lead_t: f64::NEG_INFINITY,
            ended: false,
        }
    }

    /// A gaze/pupil trace rather than a recording: its rows are what the
    /// user asks for, so its pupil holds from one row to the next (no
    /// stale → model fallback between sparse rows).
    pub fn hold_between_samples(mut self) -> Self {
        self.live.set_stale_after_secs(f64::INFINITY);
        self
    }

    /// The filtered state at `t_secs` (feeding the adaptation luminance of
    /// the previous frame back to the pupil model first).
    pub fn state(&mut self, t_secs: f64, adaptation_cd_m2: Option<f64>) -> EyeState {
        if let Some(l) = adaptation_cd_m2 {
            self.live.set_adaptation_luminance(l);
        }
        // Nothing past the frame reaches the state while reading ahead.
        self.live.set_horizon(t_secs);
        while self.backlog.front().is_some_and(|s| s.t_secs() <= t_secs) {
            if let Some(s) = self.backlog.pop_front() {
                self.live.push(&s);
                self.updates += 1;
            }
        }
        let ahead = t_secs + self.lookahead_s;
        while !self.ended && self.needs_more(ahead) {
            let Some(s) = self.samples.next() else {
                self.ended = true;
                // The last samples have nothing after them: decide them.
                self.live.flush_pending();
                break;
            };
            let t = s.t_secs();
            if t.is_finite() {
                self.lead_t = self.lead_t.max(t);
            }
            match &s {
                Sample::Pupil(p) => {
                    if let Some(n) = self.newest_pupil_t.get_mut(usize::from(p.eye))
                        && t.is_finite()
                    {
                        *n = Some(n.map_or(t, |n0| n0.max(t)));
                    }
                    self.live.push(&s);
                    self.updates += 1;
                }
                _ if t <= t_secs || self.backlog.len() >= BACKLOG_CAPACITY => {
                    self.live.push(&s);
                    self.updates += 1;
                }
                _ => self.backlog.push_back(s),
            }
        }
        self.live.set_horizon(t_secs);
        let age_secs = (t_secs - self.live.chain().state().t_secs).max(0.0);
        self.live.state_at(t_secs, age_secs, self.updates)
    }

    /// Whether to read on: an eye seen so far has no pupil sample past
    /// `ahead` yet (within [`MAX_LOOKAHEAD_S`]), or nothing was read past
    /// it.
    fn needs_more(&self, ahead: f64) -> bool {
        if self.lead_t <= ahead {
            return true;
        }
        if self.lead_t > ahead + MAX_LOOKAHEAD_S || self.backlog.len() >= BACKLOG_CAPACITY {
            return false;
        }
        self.newest_pupil_t.iter().flatten().any(|&t| t <= ahead)
    }

    /// The chain's counters.
    pub fn stats(&self) -> &ChainStats {
        self.live.stats()
    }

    /// The sample iterator (for what it counted).
    pub fn samples(&self) -> &I {
        &self.samples
    }
}

/// What the first pass over a recording found.
#[derive(Clone, Debug)]
pub struct Scan {
    /// The first and last finite sample times, s (the recording's clock).
    pub t_first: f64,
    pub t_last: f64,
    /// The pupil units its samples are in.
    pub pupil_units: Vec<PupilUnit>,
}

/// Reads the recording once for its time range and pupil units. Fails
/// naming the cause when nothing is readable, when the importer refuses
/// the file, and (unless `part` — the user chose a part of it) when the
/// samples cover a sliver of the time range they claim.
pub fn scan(path: &Path, part: bool) -> Result<Scan, RenderError> {
    let mut importer = import::open(path)?;
    let mut range: Option<(f64, f64)> = None;
    let mut units: Vec<PupilUnit> = Vec::new();
    for item in importer.by_ref() {
        let sample = match item {
            Ok(s) => s,
            Err(e) if range.is_none() => {
                return Err(RenderError::Recording(format!(
                    "{}: the recording holds no readable samples: {e}",
                    path.display()
                )));
            }
            Err(e) => return Err(e.into()),
        };
        let t = sample.t_secs();
        if !t.is_finite() {
            continue;
        }
        range = Some(match range {
            None => (t, t),
            Some((a, b)) => (a.min(t), b.max(t)),
        });
        if let Sample::Pupil(p) = &sample
            && !units.contains(&p.unit)
        {
            units.push(p.unit);
        }
    }
    let Some((t_first, t_last)) = range else {
        return Err(no_samples(
            path,
            importer.warnings(),
            &importer.data_files(),
        ));
    };
    if !part
        && let Some(stats) = importer.time_stats()
        && let Some(e) = sliver_span(path, stats)
    {
        return Err(e);
    }
    Ok(Scan {
        t_first,
        t_last,
        pupil_units: units,
    })
}

/// An importer's samples; a read error ends them (logged).
pub struct ImporterSamples {
    importer: Box<dyn Importer + Send>,
    ended: bool,
}

impl ImporterSamples {
    /// Opens the recording at `path` for its samples.
    pub fn open(path: &Path) -> Result<Self, RenderError> {
        Ok(Self::new(import::open(path)?))
    }

    pub fn new(importer: Box<dyn Importer + Send>) -> Self {
        Self {
            importer,
            ended: false,
        }
    }

    /// What the importer noted so far (skipped records, missing files).
    pub fn warnings(&self) -> &ImportWarnings {
        self.importer.warnings()
    }
}

impl Iterator for ImporterSamples {
    type Item = Sample;

    fn next(&mut self) -> Option<Sample> {
        if self.ended {
            return None;
        }
        match self.importer.next() {
            Some(Ok(s)) => Some(s),
            Some(Err(e)) => {
                tracing::warn!(error = %e, "recording ended early");
                self.ended = true;
                None
            }
            None => {
                self.ended = true;
                None
            }
        }
    }
}

/// Refuse a replay whose samples cover less than 1 / this of its span…
pub const MIN_COVERAGE_INV: f64 = 10.0;
/// …when the uncovered time is also more than this, s.
pub const MAX_UNCOVERED_SECS: f64 = 600.0;

/// Why a recording gave no samples: an error naming the file and the
/// cause (the importer's first skipped records, an empty file, a file of
/// headers only). For a directory recording, `data_files` (the streams the
/// importer read) are named with their sizes.
pub fn no_samples(path: &Path, warnings: &ImportWarnings, data_files: &[PathBuf]) -> RenderError {
    let what = if warnings.skipped_records > 0 {
        format!(
            "{} records were skipped as malformed; the first: {}",
            warnings.skipped_records,
            warnings.messages.first().map_or("-", String::as_str)
        )
    } else {
        match std::fs::metadata(path) {
            Ok(m) if m.is_dir() && !data_files.is_empty() => {
                let files: Vec<String> = data_files
                    .iter()
                    .map(|f| {
                        let name = f.file_name().map_or_else(
                            || f.display().to_string(),
                            |n| n.to_string_lossy().into_owned(),
                        );
                        match std::fs::metadata(f) {
                            Ok(m) => format!("{name} ({} bytes)", m.len()),
                            Err(e) => format!("{name} ({e})"),
                        }
                    })
                    .collect();
                format!(
                    "its data files hold no sample records: {}",
                    files.join(", ")
                )
            }
            Ok(m) if m.is_file() && m.len() == 0 => "the file is empty (0 bytes)".to_string(),
            Ok(m) if m.is_file() => format!(
                "the file ({} bytes) holds no sample records: only a header, comments or \
                 event lines",
                m.len()
            ),
            _ => "no sample records were found".to_string(),
        }
    };
    RenderError::Recording(format!(
        "{}: the recording holds no readable samples: {what}",
        path.display()
    ))
}

/// A refusal when the samples cover a sliver of the recording's span (a
/// one-year gap between two minutes of data): replaying it would render the
/// gap. `None` when the recording is fine.
pub fn sliver_span(path: &Path, stats: &TimeStats) -> Option<RenderError> {
    let span = stats.span_secs();
    let covered = stats.covered_secs;
    if !(span > covered * MIN_COVERAGE_INV && span - covered > MAX_UNCOVERED_SECS) {
        return None;
    }
    let gap = stats
        .largest_gap_secs
        .map(|(a, b)| {
            format!(
                "; the largest gap is {} from t = {a:.3} s to t = {b:.3} s",
                human_secs(b - a)
            )
        })
        .unwrap_or_default();
    Some(RenderError::Recording(format!(
        "{}: the samples cover {} of a {} time range ({:.4} %){gap}: the timestamps are \
         probably wrong (a clock jump, mixed clocks) — replay a part with --from-secs/--secs",
        path.display(),
        human_secs(covered),
        human_secs(span),
        100.0 * covered / span
    )))
}

fn human_secs(s: f64) -> String {
    if s >= 86_400.0 {
        format!("{:.1} days", s / 86_400.0)
    } else if s >= 3_600.0 {
        format!("{:.1} h", s / 3_600.0)
    } else {
        format!("{s:.1} s")
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn sliver_span_is_refused_and_normal_gaps_pass() {
        let year = TimeStats {
            accepted: 144_000,
            time_skipped: 0,
            range_secs: Some((0.0, 31_536_360.0)),
            covered_secs: 360.0,
            largest_gap_secs: Some((180.0, 31_536_180.0)),
        };
        let e = sliver_span(Path::new("r.csv"), &year).unwrap().to_string();
        assert!(e.contains("r.csv") && e.contains("365.0 days"), "{e}");
        // EyeLink: 4 trials of ~35 s with ~90 s pauses.
        let trials = TimeStats {
            range_secs: Some((0.0, 420.0)),
            covered_secs: 140.0,
            largest_gap_secs: Some((100.0, 193.0)),
            ..year
        };
        assert!(sliver_span(Path::new("t.asc"), &trials).is_none());
    }
}
