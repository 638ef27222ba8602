//! # gazelight-import
//!
//! Importers for recorded eye-tracking logs, replayed through the filter
//! chain as a stream of [`Sample`]s.
//!
//! Every importer is a streaming iterator: it reads its files through
//! buffered readers record by record and never loads a whole recording into
//! memory. Items are `Result<Sample, ImportError>`:
//!
//! - a malformed record (an unparsable ASC sample line, a CSV row with a
//!   non-numeric field, a truncated trailing binary record) is **skipped** and
//!   counted in [`ImportWarnings`] (with the first few messages kept, naming
//!   file and line or byte offset);
//! - an unrecoverable structure error (a missing `.dtype` field, an I/O
//!   failure) is yielded once as `Err` and the iterator then ends.
//!
//! Formats:
//!
//! - [`neon`]: Pupil Labs Neon native recordings (a directory with
//!   `info.json`, `*.dtype`, `* ps1.raw`, `* ps1.time`);
//! - [`eyelink`]: SR Research EyeLink ASC exports;
//! - [`csv`]: CSV/TSV files with a documented column mapping: gazelight's
//!   trace (`t_secs,gaze_u,gaze_v,pupil_mm[,confidence]`), per-eye pupil
//!   traces (`time,left,right` in mm, as the piprkit PLR recordings), gaze,
//!   per-eye pupils (mm, px, area units) and confidences;
//! - [`pupil_core`]: Pupil Core recording directories (`pupil.pldata`,
//!   `gaze.pldata`), as Pupil Capture and [`gazelight_pupil::recording`] write them;
//! - [`bids`]: BIDS eye-tracking recordings (`*_physio.tsv.gz` + `.json`,
//!   `PhysioType: "eyetrack"`, the per-eye files merged), and the BIDS
//!   export;
//! - [`xdf`]: one eye stream of an XDF file (Lab Streaming Layer's
//!   LabRecorder), `FILE.xdf?stream=NAME` or the first `Gaze`/`Pupil` stream.
//!
//! [`events::read`] reads a recording's events (EyeLink `MSG` lines and
//! trials, XDF marker streams, Pupil annotations, Neon events, BIDS
//! physioevents and `_events.tsv`) on the samples' clock, bounded.
//!
//! [`open`] picks the importer from the path; [`summary`] condenses a
//! recording (or a stretch of a live Pupil stream) into counts, rates,
//! pupil ranges and blinks.
//!
//! # Example
//!
//! A two-row pupil CSV (the piprkit layout): one sample per eye and row;
//! the empty right pupil of the second row is a lost pupil (confidence 0).
//!
//! ```
//! use gazelight_eye::{PupilUnit, Sample};
//!
//! let dir = std::env::temp_dir().join(format!("gazelight-import-doc-{}", std::process::id()));
//! std::fs::create_dir_all(&dir)?;
//! let path = dir.join("trace.csv");
//! std::fs::write(&path, "time,left,right\n0.00,6.40,5.62\n0.01,6.38,\n")?;
//! let samples: Vec<Sample> = gazelight_import::open(&path)?.collect::<Result<_, _>>()?;
//! assert_eq!(samples.len(), 4);
//! let Sample::Pupil(p) = samples[0] else { panic!("a pupil sample") };
//! assert_eq!(p.unit, PupilUnit::Mm);
//! let lost = samples.iter().filter(|s| matches!(s, Sample::Pupil(p) if p.confidence == 0.0));
//! assert_eq!(lost.count(), 1);
//! std::fs::remove_dir_all(&dir)?;
//! # Ok::<(), Box<dyn std::error::Error>>(())
//! ```

pub mod bids;
pub mod csv;
pub mod events;
pub mod eyelink;
mod lines;
pub mod neon;
pub mod pupil_core;
pub mod summary;
pub mod time_guard;
pub mod xdf;

use std::path::{Path, PathBuf};

use gazelight_eye::sample::Sample;

/// How many warning messages an importer keeps verbatim (all are counted).
pub const KEPT_WARNING_MESSAGES: usize = 16;

/// Most bytes of an error's reason shown: a reason quoting a hostile
/// input (a 16 MiB XML tag, a megabyte-long CSV cell) is shown as its
/// first [`QUOTED_HEAD_BYTES`] and last [`QUOTED_TAIL_BYTES`] with the
/// number of bytes left out between them.
pub const MAX_REASON_BYTES: usize = 1024;
/// See [`MAX_REASON_BYTES`].
pub const QUOTED_HEAD_BYTES: usize = 640;
/// See [`MAX_REASON_BYTES`].
pub const QUOTED_TAIL_BYTES: usize = 256;

/// `reason` as an error shows it: whole up to [`MAX_REASON_BYTES`], else
/// its head and tail (cut at character boundaries) around
/// `… [N bytes left out] …`.
pub fn capped(reason: &str) -> std::borrow::Cow<'_, str> {
    if reason.len() <= MAX_REASON_BYTES {
        return std::borrow::Cow::Borrowed(reason);
    }
    let mut head = QUOTED_HEAD_BYTES;
    while !reason.is_char_boundary(head) {
        head -= 1;
    }
    let mut tail = reason.len() - QUOTED_TAIL_BYTES;
    while !reason.is_char_boundary(tail) {
        tail += 1;
    }
    std::borrow::Cow::Owned(format!(
        "{} … [{} bytes left out] … {}",
        &reason[..head],
        tail - head,
        &reason[tail..]
    ))
}

/// A recording that cannot be imported (or a part of it that cannot).
#[derive(Debug, thiserror::Error)]
pub enum ImportError {
    /// The file cannot be opened or read.
    #[error("cannot read {path}: {source}")]
    Io {
        path: PathBuf,
        #[source]
        source: std::io::Error,
    },
    /// The file's structure is unusable (missing field, wrong layout); the
    /// import stops. `position` names the line or byte offset.
    #[error("{path} ({position}): {}", capped(reason))]
    Structure {
        path: PathBuf,
        position: Position,
        reason: String,
    },
    /// The path is not a recording any importer knows.
    #[error("{path}: unknown recording format ({})", capped(reason))]
    UnknownFormat { path: PathBuf, reason: String },
}

/// Where in a file something happened.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum Position {
    /// 1-based line number of a text file.
    Line(u64),
    /// Byte offset into a binary file.
    Byte(u64),
    /// The file as a whole.
    File,
}

impl std::fmt::Display for Position {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        match self {
            Position::Line(l) => write!(f, "line {l}"),
            Position::Byte(b) => write!(f, "byte offset {b}"),
            Position::File => write!(f, "whole file"),
        }
    }
}

/// Counted warnings of an import: skipped malformed records.
#[derive(Clone, Debug, Default, PartialEq, Eq)]
pub struct ImportWarnings {
    /// Number of records skipped.
    pub skipped_records: u64,
    /// The first [`KEPT_WARNING_MESSAGES`] messages, each naming file and
    /// position.
    pub messages: Vec<String>,
}

impl ImportWarnings {
    /// Keeps a warning about the recording as a whole (a missing optional
    /// file, say) without counting a skipped record; logged as a warning.
    pub fn note(&mut self, path: &Path, position: Position, reason: impl std::fmt::Display) {
        if self.messages.len() < KEPT_WARNING_MESSAGES {
            self.messages
                .push(format!("{} ({position}): {reason}", path.display()));
        }
        tracing::warn!(path = %path.display(), %position, %reason, "recording warning");
    }

    /// Counts a skipped record and keeps its message if there is room.
    pub fn skip(&mut self, path: &Path, position: Position, reason: impl std::fmt::Display) {
        self.skipped_records += 1;
        if self.messages.len() < KEPT_WARNING_MESSAGES {
            self.messages
                .push(format!("{} ({position}): {reason}", path.display()));
        }
        tracing::warn!(path = %path.display(), %position, %reason, "skipped malformed record");
    }
}

/// Whether a recording's data file `path` is there: `Ok(true)` for a
/// regular file (symlinks followed), `Ok(false)` when nothing has that
/// name, and an error naming the file when something is there that cannot
/// be read as one — a dangling symlink (and where it points), a directory,
/// a device — so a broken stream is reported, never taken for a missing one.
pub fn data_file(path: &Path) -> Result<bool, ImportError> {
    let entry = match std::fs::symlink_metadata(path) {
        Ok(m) => m,
        Err(e) if e.kind() == std::io::ErrorKind::NotFound => return Ok(false),
        Err(source) => {
            return Err(ImportError::Io {
                path: path.to_owned(),
                source,
            });
        }
    };
    match std::fs::metadata(path) {
        Ok(m) if m.is_file() => Ok(true),
        Ok(_) => Err(ImportError::Structure {
            path: path.to_owned(),
            position: Position::File,
            reason: "not a regular file; the recording's data cannot be read from it".into(),
        }),
        Err(e) if entry.file_type().is_symlink() => {
            let target = std::fs::read_link(path)
                .map_or_else(|_| "?".to_owned(), |t| t.display().to_string());
            Err(ImportError::Structure {
                path: path.to_owned(),
                position: Position::File,
                reason: format!(
                    "a symlink to {target}, which cannot be opened ({e}); the recording's data \
                     is not there"
                ),
            })
        }
        Err(source) => Err(ImportError::Io {
            path: path.to_owned(),
            source,
        }),
    }
}

/// What an importer says about per-eye gaze ([`GazeEyes::Left`] /
/// [`GazeEyes::Right`] samples) beside its binocular gaze.
///
/// [`GazeEyes::Left`]: gazelight_eye::sample::GazeEyes::Left
/// [`GazeEyes::Right`]: gazelight_eye::sample::GazeEyes::Right
#[derive(Clone, Debug, Default, PartialEq, serde::Serialize)]
pub struct EyeGazeReport {
    /// Whether the importer emits per-eye gaze. `false`: all its gaze is
    /// binocular, and whatever needs a gaze per eye (the filter's per-eye
    /// gaze, the stereo renderer) gets the binocular gaze for both eyes.
    pub per_eye: bool,
    /// Why there is no per-eye gaze, when `per_eye` is false.
    pub reason: Option<String>,
    /// Per-eye gaze samples emitted so far, `[right, left]` (gazelight's
    /// eye ids: 0 = right, 1 = left).
    pub emitted: [u64; 2],
    /// Records that gave that eye no gaze (NaN or zero eye geometry, or a
    /// direction the scene camera cannot image), `[right, left]`.
    pub missing: [u64; 2],
    /// The constant correction added to each eye's gaze, `[right, left]`,
    /// each `[horizontal, vertical]` in degrees (positive = right, down in
    /// the scene image), where one was applied.
    pub correction_deg: [Option<[f64; 2]>; 2],
}

/// A streaming importer of a recording.
pub trait Importer: Iterator<Item = Result<Sample, ImportError>> {
    /// Warnings counted so far (complete once the iterator has ended).
    fn warnings(&self) -> &ImportWarnings;
    /// A short name of the format ("neon", "eyelink-asc", "csv").
    fn format(&self) -> &'static str;
    /// Where the most recently returned sample came from (a text
    /// importer's line); [`Position::File`] when the format cannot say.
    fn position(&self) -> Position {
        Position::File
    }
    /// Clock statistics of the accepted samples, when the importer keeps
    /// them (every importer [`open`] returns does: it is wrapped in a
    /// [`time_guard::TimeGuard`]).
    fn time_stats(&self) -> Option<&time_guard::TimeStats> {
        None
    }
    /// The data files a directory recording's samples come from (its
    /// streams), to name them when they hold nothing; empty for a
    /// one-file recording (the path given is the file).
    fn data_files(&self) -> Vec<PathBuf> {
        Vec::new()
    }
    /// Whether (and how) the importer produces per-eye gaze, for formats
    /// where that is decided per recording (Neon); `None` where each gaze
    /// sample's `eyes` says all there is (EyeLink, Pupil Core, CSV).
    /// Counts are complete once the iterator has ended.
    fn eye_gaze(&self) -> Option<&EyeGazeReport> {
        None
    }
    /// The sampling rate the recording itself states, Hz (EyeLink's
    /// `SAMPLES … RATE`, Neon's `gaze_frequency`, an XDF stream's
    /// `nominal_srate`, a BIDS sidecar's `SamplingFrequency`); `None` where
    /// it states none. A text importer knows it once the line is read
    /// (complete once the iterator has ended).
    fn nominal_rate_hz(&self) -> Option<f64> {
        None
    }
    /// The tracker that made the recording, as far as the recording (or
    /// its format: an EyeLink ASC is SR Research's) says.
    fn device(&self) -> Device {
        Device::default()
    }
}

/// The maker and model of the tracker that made a recording.
#[derive(Clone, Debug, Default, PartialEq, Eq, serde::Serialize)]
pub struct Device {
    /// `SR Research`, `Pupil Labs`, …
    pub manufacturer: Option<String>,
    /// `EyeLink 1000 Plus`, `Neon`, `Pupil Core`, …
    pub model: Option<String>,
}

/// A stated sampling rate, if it is one (finite, > 0, ≤ 1 MHz).
pub(crate) fn plausible_rate(hz: f64) -> Option<f64> {
    (hz.is_finite() && hz > 0.0 && hz <= 1e6).then_some(hz)
}

/// Opens a recording, picking the importer from the path: a directory with
/// an `info.json` and `eye_state.dtype` is a Neon recording, a directory
/// with `pupil.pldata` or `gaze.pldata` a Pupil Core recording, `*.asc` an
/// EyeLink ASC export, `*.csv` or `*.tsv` an eye-tracking CSV/TSV file
/// ([`csv`]: gaze, per-eye pupils, confidence), `*.xdf` (optionally
/// `*.xdf?stream=NAME`) an XDF file, `*_physio.tsv.gz` or `*_physio.json`
/// a BIDS eye-tracking recording.
///
/// Every importer comes wrapped in a [`time_guard::TimeGuard`]: samples
/// with absurd or isolated out-of-line timestamps are skipped and counted,
/// and a file of which (nearly) nothing is readable ends in an error.
pub fn open(path: &Path) -> Result<Box<dyn Importer + Send>, ImportError> {
    use time_guard::TimeGuard;
    if path.is_dir() {
        if path.join("info.json").is_file() && path.join("eye_state.dtype").is_file() {
            return Ok(Box::new(TimeGuard::new(
                neon::NeonImporter::open(path)?,
                path,
            )));
        }
        if pupil_core::PupilCoreImporter::detect(path) {
            return Ok(Box::new(TimeGuard::new(
                pupil_core::PupilCoreImporter::open(path)?,
                path,
            )));
        }
        return Err(ImportError::UnknownFormat {
            path: path.to_owned(),
            reason: "a directory with neither info.json + eye_state.dtype (Neon) nor \
                     pupil.pldata / gaze.pldata (Pupil Core)"
                .into(),
        });
    }
    if bids::is_physio(path) {
        return Ok(Box::new(TimeGuard::new(
            bids::BidsImporter::open(path)?,
            path,
        )));
    }
    if let Some((file, _)) = xdf::split_query(path) {
        return Ok(Box::new(TimeGuard::new(
            xdf::XdfImporter::open(path)?,
            &file,
        )));
    }
    let ext = path
        .extension()
        .and_then(|e| e.to_str())
        .map(str::to_ascii_lowercase);
    match ext.as_deref() {
        Some("asc") => Ok(Box::new(TimeGuard::new(
            eyelink::AscImporter::open(path)?,
            path,
        ))),
        Some("csv" | "tsv") => Ok(Box::new(TimeGuard::new(
            csv::CsvPupilImporter::open(path)?,
            path,
        ))),
        _ => Err(ImportError::UnknownFormat {
            path: path.to_owned(),
            reason: "expected a Neon or Pupil Core directory, an .asc, a .csv or .tsv, an .xdf or \
                     a BIDS *_physio.tsv.gz file"
                .into(),
        }),
    }
}

/// An importer that reads its input one record at a time into a [`Pending`]
/// queue; [`next_stepped`] is then its whole `Iterator::next`.
pub(crate) trait Stepped {
    /// Reads the next record (its samples go to the pending queue); `false`
    /// at the end of the input. An error ends the import.
    fn step(&mut self) -> Result<bool, ImportError>;
    /// The oldest pending sample.
    fn pop_pending(&mut self) -> Option<Sample>;
    /// Whether the input has ended (or failed); set by [`next_stepped`].
    fn done_mut(&mut self) -> &mut bool;
}

/// `Iterator::next` of a [`Stepped`] importer: pending samples first, then
/// one step at a time until a sample, the end, or the first error (after
/// which it yields nothing).
pub(crate) fn next_stepped<T: Stepped>(t: &mut T) -> Option<Result<Sample, ImportError>> {
    loop {
        if let Some(s) = t.pop_pending() {
            return Some(Ok(s));
        }
        if *t.done_mut() {
            return None;
        }
        match t.step() {
            Ok(true) => {}
            Ok(false) => *t.done_mut() = true,
            Err(e) => {
                *t.done_mut() = true;
                return Some(Err(e));
            }
        }
    }
}

/// A small fixed-capacity FIFO of pending samples (an importer record can
/// expand to several samples); no heap allocation.
#[derive(Clone, Copy, Debug)]
pub(crate) struct Pending<const N: usize> {
    buf: [Option<Sample>; N],
    head: usize,
    len: usize,
}

impl<const N: usize> Pending<N> {
    pub(crate) fn new() -> Self {
        Self {
            buf: [None; N],
            head: 0,
            len: 0,
        }
    }

    /// Appends; silently ignored when full (callers size N to their maximum
    /// expansion, so it never is).
    pub(crate) fn push(&mut self, s: Sample) {
        if self.len < N {
            self.buf[(self.head + self.len) % N] = Some(s);
            self.len += 1;
        }
    }

    pub(crate) fn pop(&mut self) -> Option<Sample> {
        if self.len == 0 {
            return None;
        }
        let s = self.buf[self.head].take();
        self.head = (self.head + 1) % N;
        self.len -= 1;
        s
    }
}
