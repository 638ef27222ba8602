//! Timestamp plausibility for every importer: absurd or byte-flipped times
//! among good ones are skipped and counted, never allowed to stretch a
//! recording's time range.
//!
//! A recording's clock is its backbone: replay places frames on it, and one
//! timestamp of 1e308 (or a Neon `.time` record with a flipped high byte,
//! 2⁵⁶ ns ≈ 2.3 years away) among hours of good ones would otherwise make
//! the recording "span" centuries. [`TimeGuard`] wraps an importer and
//! applies two rules to every sample's time `t`:
//!
//! 1. `t` must be finite with `|t| ≤` [`MAX_ABS_T_SECS`]; otherwise the
//!    sample is skipped with a counted warning naming the position.
//! 2. A sample more than [`MAX_JUMP_SECS`] away from the last accepted one
//!    starts a *candidate segment*. Candidates are held (at most
//!    [`CONFIRM_SAMPLES`], a fixed array: no heap) until either
//!    - a sample comes back near the last accepted time: the candidates
//!      were outliers and are skipped, counted with their reason; or
//!    - [`CONFIRM_SAMPLES`] consecutive candidates agree with each other:
//!      the jump is a genuine gap (EyeLink pauses ~90 s between trials) and
//!      they are released in order.
//!
//!    At the start of a file the first samples are candidates too, so a bad
//!    first timestamp cannot become the anchor. Candidates left at the end
//!    after a jump are skipped (too few to be a segment).
//!
//! The guard also keeps [`TimeStats`] of the accepted samples: first and
//! last time, the time covered by samples (the sum of the steps of at most
//! [`MAX_JUMP_SECS`]) and the largest gap, so that a caller can refuse a
//! recording whose samples cover a sliver of the span it claims. When nine
//! in ten records or more were skipped, the guard ends the import with an
//! error saying so instead of quietly handing on the remainder.

use std::path::{Path, PathBuf};

use super::{ImportError, ImportWarnings, Importer, Position};
use gazelight_eye::sample::Sample;

/// Largest plausible |timestamp|, s (about 317 years: Unix seconds, Pupil
/// time and tracker clocks all sit far below it).
pub const MAX_ABS_T_SECS: f64 = 1e10;
/// A step between consecutive samples above this is a jump that must be
/// confirmed by [`CONFIRM_SAMPLES`] samples before it is believed, s.
pub const MAX_JUMP_SECS: f64 = 10.0;
/// Consecutive agreeing samples that make a jump a genuine gap.
pub const CONFIRM_SAMPLES: usize = 8;
/// Refuse the import when fewer than one record in this many is readable.
pub const MIN_VALID_FRACTION_INV: u64 = 10;

/// What the guard saw of the accepted samples' clock.
#[derive(Clone, Copy, Debug, Default, PartialEq)]
pub struct TimeStats {
    /// Samples accepted.
    pub accepted: u64,
    /// Samples skipped for their timestamp.
    pub time_skipped: u64,
    /// Earliest and latest accepted time, s.
    pub range_secs: Option<(f64, f64)>,
    /// Time covered by samples: the sum of steps ≤ [`MAX_JUMP_SECS`], s.
    pub covered_secs: f64,
    /// The largest confirmed gap: (from, to), s.
    pub largest_gap_secs: Option<(f64, f64)>,
}

impl TimeStats {
    /// Span from the first to the last accepted sample, s.
    pub fn span_secs(&self) -> f64 {
        self.range_secs.map_or(0.0, |(a, b)| b - a)
    }

    fn accept(&mut self, t: f64, prev: Option<f64>) {
        self.accepted += 1;
        self.range_secs = Some(match self.range_secs {
            None => (t, t),
            Some((a, b)) => (a.min(t), b.max(t)),
        });
        if let Some(p) = prev {
            let step = (t - p).abs();
            if step <= MAX_JUMP_SECS {
                self.covered_secs += step;
            } else if self
                .largest_gap_secs
                .is_none_or(|(a, b)| (b - a).abs() < step)
            {
                self.largest_gap_secs = Some((p, t));
            }
        }
    }
}

/// A held candidate sample and where it came from.
type Held = (Sample, Position);

/// Wraps an importer with the timestamp rules above.
pub struct TimeGuard<I: Importer> {
    inner: I,
    path: PathBuf,
    /// Last accepted time.
    anchor: Option<f64>,
    held: [Option<Held>; CONFIRM_SAMPLES],
    held_len: usize,
    /// Time of the newest held candidate.
    held_t: f64,
    /// Confirmed samples waiting to be handed out (front first).
    out: [Option<Sample>; CONFIRM_SAMPLES],
    out_head: usize,
    out_len: usize,
    warnings: ImportWarnings,
    inner_skipped_seen: u64,
    inner_messages_seen: usize,
    stats: TimeStats,
    ended: bool,
    finished: bool,
    refused: bool,
}

impl<I: Importer> TimeGuard<I> {
    /// Wraps `inner`; `path` names the recording in warnings.
    pub fn new(inner: I, path: &Path) -> Self {
        Self {
            inner,
            path: path.to_owned(),
            anchor: None,
            held: [None; CONFIRM_SAMPLES],
            held_len: 0,
            held_t: 0.0,
            out: [None; CONFIRM_SAMPLES],
            out_head: 0,
            out_len: 0,
            warnings: ImportWarnings::default(),
            inner_skipped_seen: 0,
            inner_messages_seen: 0,
            stats: TimeStats::default(),
            ended: false,
            finished: false,
            refused: false,
        }
    }

    /// The wrapped importer.
    pub fn inner(&self) -> &I {
        &self.inner
    }

    /// Copies the inner importer's new warnings into ours.
    fn sync_warnings(&mut self) {
        let iw = self.inner.warnings();
        if iw.skipped_records != self.inner_skipped_seen {
            self.warnings.skipped_records += iw.skipped_records - self.inner_skipped_seen;
            self.inner_skipped_seen = iw.skipped_records;
        }
        while self.inner_messages_seen < iw.messages.len() {
            if self.warnings.messages.len() < super::KEPT_WARNING_MESSAGES {
                self.warnings
                    .messages
                    .push(iw.messages[self.inner_messages_seen].clone());
            }
            self.inner_messages_seen += 1;
        }
    }

    fn skip(&mut self, position: Position, reason: impl std::fmt::Display) {
        self.stats.time_skipped += 1;
        self.warnings.skip(&self.path, position, reason);
    }

    fn emit(&mut self, s: Sample) {
        let t = s.t_secs();
        self.stats.accept(t, self.anchor);
        self.anchor = Some(t);
        if self.out_len < CONFIRM_SAMPLES {
            self.out[(self.out_head + self.out_len) % CONFIRM_SAMPLES] = Some(s);
            self.out_len += 1;
        }
    }

    fn pop_out(&mut self) -> Option<Sample> {
        if self.out_len == 0 {
            return None;
        }
        let s = self.out[self.out_head].take();
        self.out_head = (self.out_head + 1) % CONFIRM_SAMPLES;
        self.out_len -= 1;
        s
    }

    /// Skips every held candidate as an outlier.
    fn drop_held(&mut self, why: &str) {
        for i in 0..self.held_len {
            if let Some((s, pos)) = self.held[i].take() {
                let t = s.t_secs();
                let near = self
                    .anchor
                    .map(|a| format!(" (the samples around it are at {a:.3} s)"))
                    .unwrap_or_default();
                self.skip(pos, format_args!("timestamp {t:.6e} s {why}{near}"));
            }
        }
        self.held_len = 0;
    }

    /// Releases the held candidates in order as accepted samples.
    fn release_held(&mut self) {
        for i in 0..self.held_len {
            if let Some((s, _)) = self.held[i].take() {
                self.emit(s);
            }
        }
        self.held_len = 0;
    }

    fn hold(&mut self, s: Sample, pos: Position) {
        self.held_t = s.t_secs();
        if self.held_len < CONFIRM_SAMPLES {
            self.held[self.held_len] = Some((s, pos));
            self.held_len += 1;
        }
        if self.held_len == CONFIRM_SAMPLES {
            self.release_held();
        }
    }

    fn process(&mut self, s: Sample, pos: Position) {
        let t = s.t_secs();
        if !(t.is_finite() && t.abs() <= MAX_ABS_T_SECS) {
            self.skip(
                pos,
                format_args!("timestamp {t:e} s is not a finite time within ±{MAX_ABS_T_SECS:e} s"),
            );
            return;
        }
        if let Some(a) = self.anchor
            && (t - a).abs() <= MAX_JUMP_SECS
        {
            if self.held_len > 0 {
                self.drop_held(&format!(
                    "jumps more than {MAX_JUMP_SECS} s away from its neighbours"
                ));
            }
            self.emit(s);
            return;
        }
        // No anchor yet, or a jump from it: a candidate.
        if self.held_len > 0 && (t - self.held_t).abs() > MAX_JUMP_SECS {
            self.drop_held(&format!(
                "jumps more than {MAX_JUMP_SECS} s away from its neighbours"
            ));
        }
        self.hold(s, pos);
    }

    fn finish(&mut self) {
        if self.held_len > 0 {
            if self.anchor.is_none() {
                // A short recording: nothing to judge the candidates against.
                self.release_held();
            } else {
                self.drop_held(&format!(
                    "jumps more than {MAX_JUMP_SECS} s away from the samples before it, \
                     and fewer than {CONFIRM_SAMPLES} samples follow it"
                ));
            }
        }
    }

    /// The refusal when (nearly) nothing of the file was readable.
    fn sliver_error(&self) -> Option<ImportError> {
        let skipped = self.warnings.skipped_records;
        let accepted = self.stats.accepted;
        if skipped == 0 || accepted.saturating_mul(MIN_VALID_FRACTION_INV) > accepted + skipped {
            return None;
        }
        let first = self
            .warnings
            .messages
            .first()
            .map(|m| format!("; the first: {m}"))
            .unwrap_or_default();
        Some(ImportError::Structure {
            path: self.path.clone(),
            position: Position::File,
            reason: format!(
                "only {accepted} samples are readable and {skipped} records were skipped \
                 (less than 1 in {MIN_VALID_FRACTION_INV} readable): refusing a recording whose \
                 valid part is a sliver of the file{first}"
            ),
        })
    }
}

impl<I: Importer> Iterator for TimeGuard<I> {
    type Item = Result<Sample, ImportError>;

    fn next(&mut self) -> Option<Self::Item> {
        loop {
            if let Some(s) = self.pop_out() {
                return Some(Ok(s));
            }
            if self.ended {
                if !self.finished {
                    self.finished = true;
                    self.finish();
                    if self.out_len > 0 {
                        continue;
                    }
                }
                if !self.refused {
                    self.refused = true;
                    if let Some(e) = self.sliver_error() {
                        return Some(Err(e));
                    }
                }
                return None;
            }
            let item = self.inner.next();
            self.sync_warnings();
            match item {
                None => self.ended = true,
                Some(Err(e)) => return Some(Err(e)),
                Some(Ok(s)) => {
                    let pos = self.inner.position();
                    self.process(s, pos);
                }
            }
        }
    }
}

impl<I: Importer> Importer for TimeGuard<I> {
    fn warnings(&self) -> &ImportWarnings {
        &self.warnings
    }
    fn format(&self) -> &'static str {
        self.inner.format()
    }
    fn position(&self) -> Position {
        self.inner.position()
    }
    fn time_stats(&self) -> Option<&TimeStats> {
        Some(&self.stats)
    }
    fn data_files(&self) -> Vec<PathBuf> {
        self.inner.data_files()
    }
    fn eye_gaze(&self) -> Option<&super::EyeGazeReport> {
        self.inner.eye_gaze()
    }
    fn nominal_rate_hz(&self) -> Option<f64> {
        self.inner.nominal_rate_hz()
    }
    fn device(&self) -> super::Device {
        self.inner.device()
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::csv::CsvPupilImporter;

    /// Counts the samples, failing on any error.
    fn count_ok(g: &mut impl Iterator<Item = Result<Sample, ImportError>>) -> usize {
        let mut n = 0;
        for s in g {
            s.unwrap();
            n += 1;
        }
        n
    }

    fn guard(text: &str) -> TimeGuard<CsvPupilImporter<&[u8]>> {
        TimeGuard::new(
            CsvPupilImporter::from_reader(text.as_bytes(), Path::new("p.csv")),
            Path::new("p.csv"),
        )
    }

    /// 360 s at 200 Hz, like the piprkit PLR trace, with `bad` rows
    /// replaced by `t_bad`.
    fn plr_like(bad: &[usize], t_bad: &str) -> String {
        let mut s = String::from("time,left,right\n");
        for i in 0..72_000usize {
            if bad.contains(&i) {
                s.push_str(&format!("{t_bad},6.0,5.9\n"));
            } else {
                s.push_str(&format!("{},6.0,5.9\n", i as f64 * 0.005));
            }
        }
        s
    }

    #[test]
    fn absurd_timestamps_among_good_ones_are_skipped_and_counted() {
        for t_bad in ["1e308", "inf", "-3.2e7", "1099.5"] {
            let text = plr_like(&[0, 5, 36_000, 71_999], t_bad);
            let mut g = guard(&text);
            let n = count_ok(&mut g);
            let st = *g.time_stats().unwrap();
            // 4 bad rows skipped, the rest kept. `inf` is not a finite
            // number: the CSV importer skips the row (one record); the
            // finite absurd times reach the guard as two samples a row.
            assert_eq!(n, (72_000 - 4) * 2, "{t_bad}");
            let per_row = if t_bad == "inf" { 0 } else { 2 };
            assert_eq!(st.time_skipped, 4 * per_row, "{t_bad}");
            assert_eq!(g.warnings().skipped_records, 4 * per_row.max(1));
            assert!(
                g.warnings().messages[0].contains("p.csv (line 2)"),
                "{:?}",
                g.warnings().messages
            );
            let (a, b) = st.range_secs.unwrap();
            // The last row (359.995 s) is one of the bad ones.
            assert!(a >= 0.0 && (b - 359.99).abs() < 1e-6, "{t_bad}: {a} {b}");
            assert!(
                (st.covered_secs - 359.99).abs() < 0.1,
                "{}",
                st.covered_secs
            );
            assert!(st.largest_gap_secs.is_none());
        }
    }

    #[test]
    fn a_genuine_gap_is_kept_and_reported() {
        // 10 s of samples, a one-year gap, 10 s more.
        let mut s = String::from("time,left,right\n");
        for i in 0..2000 {
            s.push_str(&format!("{},6.0,5.9\n", i as f64 * 0.01));
        }
        for i in 0..1000 {
            s.push_str(&format!("{},6.0,5.9\n", 31_536_000.0 + i as f64 * 0.01));
        }
        let mut g = guard(&s);
        let n = count_ok(&mut g);
        assert_eq!(n, 6000);
        let st = g.time_stats().unwrap();
        assert_eq!(st.time_skipped, 0);
        let (from, to) = st.largest_gap_secs.unwrap();
        assert!((from - 19.99).abs() < 1e-9 && to == 31_536_000.0);
        assert!(st.covered_secs < 31.0 && st.span_secs() > 3e7);
    }

    #[test]
    fn a_bad_first_timestamp_does_not_become_the_anchor() {
        let text = plr_like(&[0], "5000");
        let mut g = guard(&text);
        let n = count_ok(&mut g);
        assert_eq!(n, 71_999 * 2);
        assert_eq!(g.time_stats().unwrap().range_secs.unwrap().0, 0.005);
    }

    #[test]
    fn a_file_of_mostly_bad_times_is_refused() {
        let mut s = String::from("time,left,right\n0,6,6\n0.005,6,6\n");
        for _ in 0..100 {
            s.push_str("nan,6,6\n");
        }
        let mut g = guard(&s);
        let items: Vec<_> = g.by_ref().collect();
        let e = items.last().unwrap().as_ref().unwrap_err().to_string();
        assert!(e.contains("sliver") && e.contains("p.csv"), "{e}");
    }

    #[test]
    fn short_recordings_pass_whole() {
        let mut g = guard("time,left,right\n0,6,6\n0.01,6,6\n");
        assert_eq!(g.by_ref().filter(|s| s.is_ok()).count(), 4);
        assert_eq!(g.warnings().skipped_records, 0);
    }
}
