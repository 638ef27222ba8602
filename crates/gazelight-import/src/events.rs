//! A recording's events: the messages, markers and annotations it holds
//! beside its samples, on the samples' own clock.
//!
//! [`read`] picks the reader from the path as [`crate::open`] does:
//!
//! | recording | events | `source` | `t_clock` |
//! | --- | --- | --- | --- |
//! | EyeLink `.asc` | every `MSG` line; `TRIALID`, `TRIAL_RESULT` and `!V TRIAL_VAR name value` also make [`Trial`]s | `MSG` | tracker clock, ms |
//! | XDF | every string stream (and every stream of type `Markers`), each sample one event | the stream's name | LabRecorder's clock, s |
//! | Pupil Core directory | `annotation.pldata` (`label`, `timestamp`, `duration`), else the newest Pupil Player export's `exports/*/annotations.csv` | `annotation` | Pupil time, s |
//! | Neon native directory | `event.time` (Unix ns) + `event.txt` (one name a line) | `event` | Unix time, ns |
//! | `.csv`/`.tsv` | a Neon / Pupil Cloud `events.csv` beside it (`timestamp [ns]`, `name`) | `event` | Unix time, ns |
//! | BIDS `*_physio.tsv.gz` | its `*_physioevents.tsv.gz` rows with a `message` (or a `trial_type` other than blink, fixation, saccade), and the recording's `*_events.tsv` | `physioevents`, `events` | the physio file's `timestamp` clock, s |
//!
//! `t_secs` is on the clock the recording's samples use (the importer's:
//! EyeLink's ms / 1000, Neon's seconds since `info.json`'s `start_time`,
//! XDF's synchronised LSL clock, Pupil time, the CSV's time column), so an
//! event can be laid on the samples and on `replay`'s frames directly.
//!
//! An EyeLink message may begin with an integer: SR Research's time offset
//! (`MSG 1250 750 imageOnset` is an event at 1250 − 750 = 500 ms); the
//! offset is applied and left out of the text. A BIDS `_events.tsv` onset
//! is seconds from the first physio sample (`StartTime` subtracted).
//!
//! Bounds (a hostile file cannot make the list grow without end): at most
//! [`MAX_EVENTS`] events are kept (the rest are counted in
//! [`RecordingEvents::dropped`] with a warning), each text at most
//! [`MAX_TEXT_BYTES`] (longer ones are cut at a character boundary and
//! counted in [`RecordingEvents::truncated`]), at most [`MAX_TRIALS`]
//! trials of [`MAX_TRIAL_VARS`] variables. Lines are read through
//! [`gazelight_input`]'s bounded line reader; an unreadable line or record
//! is skipped and counted in the warnings, naming file and line.

use std::collections::BTreeMap;
use std::fmt;
use std::io::{BufRead, BufReader, Read};
use std::path::{Path, PathBuf};

use serde::Serialize;

use crate::lines::{LineRead, open_text, read_text_line};
use crate::{ImportError, ImportWarnings, Position};

/// Most events kept of one recording; the rest are counted.
pub const MAX_EVENTS: usize = 200_000;
/// Longest event text kept, bytes (longer ones are cut and counted).
pub const MAX_TEXT_BYTES: usize = 1024;
/// Longest source name, trial id or trial variable (name or value), bytes.
pub const MAX_NAME_BYTES: usize = 128;
/// Most trials kept of one recording.
pub const MAX_TRIALS: usize = 20_000;
/// Most variables kept per trial.
pub const MAX_TRIAL_VARS: usize = 64;
/// Most distinct kinds counted by [`EventSummary`] (the rest are `other`).
pub const MAX_KINDS: usize = 256;
/// Events shown by [`EventSummary::first`].
pub const FIRST_SHOWN: usize = 5;

/// One event of a recording.
#[derive(Clone, Debug, PartialEq, Serialize)]
pub struct Event {
    /// When, on the clock the recording's samples use, s.
    pub t_secs: f64,
    /// When, on the recording's own clock, in its own unit
    /// ([`RecordingEvents::clock`]: EyeLink ms, Neon ns, …).
    pub t_clock: f64,
    /// How long, s, where the recording says.
    pub duration_secs: Option<f64>,
    /// The message, marker or annotation label (at most [`MAX_TEXT_BYTES`]).
    pub text: String,
    /// Where it came from: `MSG`, an XDF stream's name, `annotation`,
    /// `event`, `physioevents`, `events`.
    pub source: String,
    /// The trial it belongs to: an index into [`RecordingEvents::trials`].
    pub trial: Option<u32>,
}

/// A trial of an EyeLink recording: from its `TRIALID` to its
/// `TRIAL_RESULT` (or the next `TRIALID`), with its `!V TRIAL_VAR`s.
#[derive(Clone, Debug, Default, PartialEq, Serialize)]
pub struct Trial {
    /// The `TRIALID` message's text after the keyword.
    pub id: String,
    /// The `TRIALID` message's time, samples' clock, s.
    pub start_t_secs: f64,
    /// The `TRIAL_RESULT` (or next `TRIALID`) time, s.
    pub end_t_secs: Option<f64>,
    /// The `TRIAL_RESULT` message's text after the keyword.
    pub result: Option<String>,
    /// `!V TRIAL_VAR name value`, in order (a name given twice keeps its
    /// last value).
    pub vars: Vec<(String, String)>,
}

/// The events of a recording, sorted by time.
#[derive(Clone, Debug, Default, PartialEq, Serialize)]
pub struct RecordingEvents {
    /// The recording's format (`eyelink-asc`, `xdf`, `pupil-core`, `neon`,
    /// `csv`, `bids-eyetrack`).
    pub format: &'static str,
    /// What [`Event::t_clock`] counts ("EyeLink tracker clock, ms", …).
    pub clock: String,
    pub events: Vec<Event>,
    pub trials: Vec<Trial>,
    /// Events past [`MAX_EVENTS`], counted and not kept.
    pub dropped: u64,
    /// Texts cut to [`MAX_TEXT_BYTES`].
    pub truncated: u64,
    /// The files the events were read from (beside the recording's own,
    /// e.g. a Cloud export's `events.csv`), so a writer never overwrites
    /// one.
    pub files: Vec<PathBuf>,
    /// Skipped records and notes (file and line named).
    #[serde(skip)]
    pub warnings: ImportWarnings,
}

/// The first `max` bytes of `s`, cut at a character boundary.
fn cut(s: &str, max: usize) -> &str {
    if s.len() <= max {
        return s;
    }
    let mut k = max;
    while !s.is_char_boundary(k) {
        k -= 1;
    }
    &s[..k]
}

impl RecordingEvents {
    fn new(format: &'static str, clock: &str) -> Self {
        Self {
            format,
            clock: clock.to_owned(),
            ..Self::default()
        }
    }

    /// Keeps an event (bounded): a time that is not finite and within the
    /// import's bounds is a skipped record; past [`MAX_EVENTS`] it is
    /// counted; a long text is cut.
    #[allow(clippy::too_many_arguments)]
    fn push(
        &mut self,
        path: &Path,
        position: Position,
        t_secs: f64,
        t_clock: f64,
        duration_secs: Option<f64>,
        text: &str,
        source: &str,
        trial: Option<u32>,
    ) {
        if !(t_secs.is_finite() && t_secs.abs() <= crate::time_guard::MAX_ABS_T_SECS) {
            self.warnings.skip(
                path,
                position,
                format_args!(
                    "event `{}`: its time {t_secs} is not a usable time",
                    cut(text, 64)
                ),
            );
            return;
        }
        if self.events.len() >= MAX_EVENTS {
            if self.dropped == 0 {
                self.warnings.note(
                    path,
                    position,
                    format_args!("more than {MAX_EVENTS} events: the rest are counted, not kept"),
                );
            }
            self.dropped += 1;
            return;
        }
        let kept = cut(text, MAX_TEXT_BYTES);
        if kept.len() < text.len() {
            if self.truncated == 0 {
                self.warnings.note(
                    path,
                    position,
                    format_args!(
                        "an event text of {} bytes cut to {MAX_TEXT_BYTES} (and any later ones)",
                        text.len()
                    ),
                );
            }
            self.truncated += 1;
        }
        self.events.push(Event {
            t_secs,
            t_clock,
            duration_secs: duration_secs.filter(|d| d.is_finite() && *d >= 0.0),
            text: kept.to_owned(),
            source: cut(source, MAX_NAME_BYTES).to_owned(),
            trial,
        });
    }

    /// Sorts by time (stable: a recording's order among equal times).
    fn finish(mut self) -> Self {
        self.events.sort_by(|a, b| a.t_secs.total_cmp(&b.t_secs));
        self
    }

    /// Counts per source and kind, the trials and the first few events.
    pub fn summary(&self) -> EventSummary {
        let mut sources: BTreeMap<&str, u64> = BTreeMap::new();
        let mut kinds: BTreeMap<String, u64> = BTreeMap::new();
        for e in &self.events {
            *sources.entry(e.source.as_str()).or_default() += 1;
            let k = kind_of(&e.text);
            if kinds.len() < MAX_KINDS || kinds.contains_key(k) {
                *kinds.entry(k.to_owned()).or_default() += 1;
            } else {
                *kinds.entry("other".to_owned()).or_default() += 1;
            }
        }
        let mut kinds: Vec<Count> = kinds
            .into_iter()
            .map(|(name, count)| Count { name, count })
            .collect();
        kinds.sort_by(|a, b| b.count.cmp(&a.count).then(a.name.cmp(&b.name)));
        EventSummary {
            total: self.events.len() as u64 + self.dropped,
            kept: self.events.len() as u64,
            dropped: self.dropped,
            truncated: self.truncated,
            clock: self.clock.clone(),
            sources: sources
                .into_iter()
                .map(|(n, c)| Count {
                    name: n.to_owned(),
                    count: c,
                })
                .collect(),
            kinds,
            trials: self.trials.len() as u64,
            first: self.events.iter().take(FIRST_SHOWN).cloned().collect(),
        }
    }
}

/// The kind of an event for counting: its text's first word (`!V` and
/// `!CAL`-style words with the next one: `!V TRIAL_VAR`), at most 32 bytes.
pub fn kind_of(text: &str) -> &str {
    let t = text.trim_start();
    let first_end = t.find(char::is_whitespace).unwrap_or(t.len());
    let end = if &t[..first_end] == "!V" {
        let rest = &t[first_end..];
        let skip = rest.len() - rest.trim_start().len();
        let second = rest
            .trim_start()
            .find(char::is_whitespace)
            .unwrap_or(rest.trim_start().len());
        first_end + skip + second
    } else {
        first_end
    };
    let k = cut(&t[..end], 32);
    if k.is_empty() { "(empty)" } else { k }
}

/// A name and how often it occurs.
#[derive(Clone, Debug, Default, PartialEq, Serialize)]
pub struct Count {
    pub name: String,
    pub count: u64,
}

/// What `inspect` says of a recording's events.
#[derive(Clone, Debug, Default, PartialEq, Serialize)]
pub struct EventSummary {
    /// Events in the recording (kept + dropped).
    pub total: u64,
    pub kept: u64,
    pub dropped: u64,
    pub truncated: u64,
    /// What `t_clock` counts.
    pub clock: String,
    /// Events per source.
    pub sources: Vec<Count>,
    /// Events per kind ([`kind_of`]), most frequent first.
    pub kinds: Vec<Count>,
    pub trials: u64,
    /// The first [`FIRST_SHOWN`] events.
    pub first: Vec<Event>,
}

impl fmt::Display for EventSummary {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        if self.total == 0 {
            return writeln!(f, "  events: none");
        }
        let list = |v: &[Count], n: usize| {
            let mut s: Vec<String> = v
                .iter()
                .take(n)
                .map(|c| format!("{} {}", c.name, c.count))
                .collect();
            if v.len() > n {
                s.push(format!("… ({} more kinds)", v.len() - n));
            }
            s.join(", ")
        };
        write!(
            f,
            "  events: {} ({})",
            self.total,
            list(&self.sources, usize::MAX)
        )?;
        if self.trials > 0 {
            write!(f, ", {} trials", self.trials)?;
        }
        if self.dropped > 0 {
            write!(f, ", {} past the first {MAX_EVENTS} not kept", self.dropped)?;
        }
        writeln!(f)?;
        writeln!(f, "    kinds: {}", list(&self.kinds, 12))?;
        for e in &self.first {
            writeln!(
                f,
                "    {:>12.3} s  {}  {}",
                e.t_secs,
                e.source,
                cut(&e.text, 100)
            )?;
        }
        if self.total > self.first.len() as u64 {
            writeln!(f, "    … (t_clock: {})", self.clock)?;
        }
        Ok(())
    }
}

/// Reads the events of the recording at `path` (any path [`crate::open`]
/// takes). A recording whose format has no events gives an empty list;
/// an unreadable events file is an error naming it.
pub fn read(path: &Path) -> Result<RecordingEvents, ImportError> {
    if path.is_dir() {
        if path.join("info.json").is_file() && path.join("eye_state.dtype").is_file() {
            return neon_native(path);
        }
        if crate::pupil_core::PupilCoreImporter::detect(path) {
            return pupil_core(path);
        }
        return Err(ImportError::UnknownFormat {
            path: path.to_owned(),
            reason: "a directory that is neither a Neon nor a Pupil Core recording".into(),
        });
    }
    if crate::bids::is_physio(path) {
        return bids(path);
    }
    if let Some((file, _)) = crate::xdf::split_query(path) {
        return xdf(&file);
    }
    let ext = path
        .extension()
        .and_then(|e| e.to_str())
        .map(str::to_ascii_lowercase);
    match ext.as_deref() {
        Some("asc") => eyelink(open_text(path)?, path),
        Some("csv" | "tsv") => csv_sidecar(path),
        _ => Err(ImportError::UnknownFormat {
            path: path.to_owned(),
            reason: "no events reader for this file".into(),
        }),
    }
}

// ------------------------------------------------------------------ EyeLink

/// `MSG <time> [offset] text` → (event time ms, text).
fn msg_line(line: &str) -> Option<(f64, &str)> {
    let rest = line.strip_prefix("MSG")?;
    if !rest.starts_with(char::is_whitespace) {
        return None;
    }
    let rest = rest.trim_start();
    let end = rest.find(char::is_whitespace).unwrap_or(rest.len());
    let t_ms: f64 = rest[..end].parse().ok().filter(|t: &f64| t.is_finite())?;
    let text = rest[end..].trim();
    // A leading integer followed by more text is SR Research's offset.
    let first_end = text.find(char::is_whitespace).unwrap_or(text.len());
    if first_end < text.len()
        && let Ok(offset) = text[..first_end].parse::<i64>()
    {
        return Some((t_ms - offset as f64, text[first_end..].trim_start()));
    }
    Some((t_ms, text))
}

/// `s` after its first `n` whitespace-separated words, trimmed.
fn after_words(s: &str, n: usize) -> &str {
    let mut rest = s.trim_start();
    for _ in 0..n {
        let end = rest.find(char::is_whitespace).unwrap_or(rest.len());
        rest = rest[end..].trim_start();
    }
    rest.trim_end()
}

/// The MSG events of an EyeLink ASC text.
pub fn eyelink<R: BufRead>(mut reader: R, path: &Path) -> Result<RecordingEvents, ImportError> {
    let mut out = RecordingEvents::new("eyelink-asc", "EyeLink tracker clock, ms");
    let mut line = String::with_capacity(256);
    let mut line_no = 0u64;
    let mut current: Option<u32> = None;
    loop {
        match read_text_line(&mut reader, &mut line, &mut line_no, path)? {
            LineRead::Eof => break,
            LineRead::TooLong(n) => {
                out.warnings.skip_long_line(path, line_no, n, "a line");
                continue;
            }
            LineRead::NotUtf8 => {
                out.warnings.skip_not_utf8(path, line_no);
                continue;
            }
            LineRead::Text => {}
        }
        if !line.starts_with("MSG") {
            continue;
        }
        let pos = Position::Line(line_no);
        let Some((t_ms, text)) = msg_line(line.trim_end_matches(['\n', '\r'])) else {
            out.warnings.skip(
                path,
                pos,
                format_args!(
                    "MSG line: expected `MSG time text`, found `{}`",
                    cut(line.trim_end(), 120)
                ),
            );
            continue;
        };
        let t_secs = t_ms * 1e-3;
        let mut words = text.split_whitespace();
        match words.next() {
            Some("TRIALID") => {
                if let Some(k) = current
                    && let Some(t) = out.trials.get_mut(k as usize)
                {
                    t.end_t_secs.get_or_insert(t_secs);
                }
                current = None;
                if out.trials.len() < MAX_TRIALS {
                    let id = text["TRIALID".len()..].trim();
                    out.trials.push(Trial {
                        id: cut(id, MAX_NAME_BYTES).to_owned(),
                        start_t_secs: t_secs,
                        ..Trial::default()
                    });
                    current = u32::try_from(out.trials.len() - 1).ok();
                } else {
                    out.warnings.skip(
                        path,
                        pos,
                        format_args!("more than {MAX_TRIALS} trials: this TRIALID is not a trial"),
                    );
                }
            }
            Some("!V") if words.next() == Some("TRIAL_VAR") => {
                let name = words.next().unwrap_or("");
                let value = after_words(text, 3).to_owned();
                let target = current.or_else(|| out.trials.len().checked_sub(1).map(|k| k as u32));
                if let Some(trial) = target.and_then(|k| out.trials.get_mut(k as usize))
                    && !name.is_empty()
                {
                    let name = cut(name, MAX_NAME_BYTES);
                    let value = cut(&value, MAX_NAME_BYTES).to_owned();
                    if let Some(v) = trial.vars.iter_mut().find(|(n, _)| n == name) {
                        v.1 = value;
                    } else if trial.vars.len() < MAX_TRIAL_VARS {
                        trial.vars.push((name.to_owned(), value));
                    } else {
                        out.warnings.skip(
                            path,
                            pos,
                            format_args!(
                                "trial `{}`: more than {MAX_TRIAL_VARS} TRIAL_VARs, `{name}` not kept",
                                trial.id
                            ),
                        );
                    }
                }
            }
            _ => {}
        }
        out.push(path, pos, t_secs, t_ms, None, text, "MSG", current);
        if let Some(result) = text.strip_prefix("TRIAL_RESULT") {
            if let Some(t) = current.and_then(|k| out.trials.get_mut(k as usize)) {
                t.end_t_secs = Some(t_secs);
                t.result = Some(cut(result.trim(), MAX_NAME_BYTES).to_owned());
            }
            current = None;
        }
    }
    Ok(out.finish())
}

// --------------------------------------------------------------------- XDF

/// The marker streams of an XDF file: every string stream and every
/// stream of type `Markers`, each sample one event at its synchronised
/// time stamp (the samples' clock).
pub fn xdf(file: &Path) -> Result<RecordingEvents, ImportError> {
    use crate::xdf::{ChannelFormat, XdfFile};
    let x = XdfFile::scan(file)?;
    let mut out = RecordingEvents::new(
        "xdf",
        "LabRecorder's LSL clock with the clock offsets applied (as pyxdf), s",
    );
    let mut text = String::new();
    for (k, info) in x.streams.iter().enumerate() {
        let string = info.format == ChannelFormat::String;
        if !(string || info.kind.eq_ignore_ascii_case("markers")) {
            continue;
        }
        let mut s = x.samples(k)?;
        let name = if info.name.is_empty() {
            format!("stream {}", info.id)
        } else {
            info.name.clone()
        };
        while let Some(t) = s.next_sample()? {
            text.clear();
            if string {
                for (c, v) in s.text().iter().enumerate() {
                    if c > 0 {
                        text.push('\t');
                    }
                    text.push_str(cut(v, MAX_TEXT_BYTES + 1));
                }
            } else {
                for (c, v) in s.numeric().iter().enumerate() {
                    if c > 0 {
                        text.push('\t');
                    }
                    text.push_str(&v.to_string());
                    if text.len() > MAX_TEXT_BYTES {
                        break;
                    }
                }
            }
            let pos = s.position();
            out.push(file, pos, t, t, None, &text, &name, None);
        }
    }
    Ok(out.finish())
}

// --------------------------------------------------------------- Pupil Core

/// A Pupil Core recording's annotations: `annotation.pldata`, else the
/// newest Pupil Player export's `annotations.csv`.
pub fn pupil_core(dir: &Path) -> Result<RecordingEvents, ImportError> {
    let mut out = RecordingEvents::new("pupil-core", "Pupil time, s");
    let (pldata, _) = gazelight_pupil::recording::stream_paths(dir, "annotation");
    if crate::data_file(&pldata)? {
        out.files.push(pldata.clone());
        let reader =
            gazelight_pupil::PldataReader::open(&pldata).map_err(|e| recording_err(&pldata, e))?;
        for record in reader {
            // A file that breaks (a megabyte of garbage, an I/O error)
            // keeps the annotations before the break, with a warning.
            let record = match record {
                Ok(r) => r,
                Err(e) => {
                    out.warnings.note(
                        &pldata,
                        Position::File,
                        format_args!("the rest of the annotations not read: {e}"),
                    );
                    break;
                }
            };
            if !record.topic.starts_with("annotation") {
                continue;
            }
            let pos = Position::Byte(record.offset);
            match gazelight_pupil::msg::decode_annotation(&record.payload) {
                Ok(a) => {
                    let t = a.timestamp;
                    out.push(
                        &pldata,
                        pos,
                        t,
                        t,
                        a.duration_secs,
                        &a.label,
                        "annotation",
                        None,
                    );
                }
                Err(why) => out.warnings.skip(&pldata, pos, why),
            }
        }
        return Ok(out.finish());
    }
    if let Some(csv) = newest_export(dir) {
        table_events(
            &csv,
            &mut out,
            TableSpec {
                time: &["timestamp"],
                text: &["label"],
                duration: Some("duration"),
                scale: 1.0,
                source: "annotation",
            },
        )?;
    }
    Ok(out.finish())
}

fn recording_err(path: &Path, e: gazelight_pupil::RecordingError) -> ImportError {
    ImportError::Structure {
        path: path.to_owned(),
        position: Position::File,
        reason: e.to_string(),
    }
}

/// `exports/NNN/annotations.csv` with the largest NNN.
fn newest_export(dir: &Path) -> Option<PathBuf> {
    let entries = std::fs::read_dir(dir.join("exports")).ok()?;
    entries
        .flatten()
        .filter_map(|e| {
            let n: u64 = e.file_name().to_str()?.parse().ok()?;
            let p = e.path().join("annotations.csv");
            p.is_file().then_some((n, p))
        })
        .max_by_key(|(n, _)| *n)
        .map(|(_, p)| p)
}

// --------------------------------------------------------------------- Neon

/// A Neon native recording's events: `event.time` (u64 Unix ns each,
/// little-endian; or `event ps1.time`) with `event.txt`, one name a line.
/// Times as the Neon importer's: seconds since `info.json`'s
/// `start_time`, else since the first eye-state record.
pub fn neon_native(dir: &Path) -> Result<RecordingEvents, ImportError> {
    let mut out = RecordingEvents::new("neon", "Unix time, ns");
    let time_path = ["event.time", "event ps1.time"]
        .iter()
        .map(|n| dir.join(n))
        .find(|p| p.is_file());
    let txt_path = dir.join("event.txt");
    let Some(time_path) = time_path else {
        return Ok(out);
    };
    out.files.push(time_path.clone());
    out.files.push(txt_path.clone());
    let info_path = dir.join("info.json");
    let mut start_ns =
        gazelight_input::read_config(&info_path, gazelight_input::ConfigSyntax::Json)
            .ok()
            .and_then(|t| serde_json::from_str::<serde_json::Value>(&t).ok())
            .and_then(|v| v.get("start_time").and_then(serde_json::Value::as_u64))
            .or_else(|| first_u64(&dir.join("eye_state ps1.time")));
    let mut times =
        BufReader::new(
            gazelight_input::open(&time_path).map_err(|source| ImportError::Io {
                path: time_path.clone(),
                source,
            })?,
        );
    let mut names = if txt_path.is_file() {
        Some(open_text(&txt_path)?)
    } else {
        out.warnings.note(
            &time_path,
            Position::File,
            "no event.txt beside it: the events have no names",
        );
        None
    };
    let mut line = String::new();
    let mut line_no = 0u64;
    let mut k = 0u64;
    loop {
        let mut b = [0u8; 8];
        match times.read_exact(&mut b) {
            Ok(()) => {}
            Err(e) if e.kind() == std::io::ErrorKind::UnexpectedEof => {
                let len = std::fs::metadata(&time_path).map_or(0, |m| m.len());
                if len % 8 != 0 {
                    out.warnings.skip(
                        &time_path,
                        Position::Byte(len - len % 8),
                        format_args!("{} trailing bytes, not a whole u64 time", len % 8),
                    );
                }
                break;
            }
            Err(source) => {
                return Err(ImportError::Io {
                    path: time_path,
                    source,
                });
            }
        }
        let ns = u64::from_le_bytes(b);
        let mut name = String::new();
        if let Some(r) = names.as_mut() {
            match read_text_line(r, &mut line, &mut line_no, &txt_path)? {
                LineRead::Text => name = line.trim_end_matches(['\n', '\r']).to_owned(),
                LineRead::Eof => {}
                LineRead::TooLong(n) => {
                    out.warnings.skip_long_line(&txt_path, line_no, n, "a name")
                }
                LineRead::NotUtf8 => out.warnings.skip_not_utf8(&txt_path, line_no),
            }
        }
        let start = *start_ns.get_or_insert(ns);
        let t = (i128::from(ns) - i128::from(start)) as f64 * 1e-9;
        out.push(
            &time_path,
            Position::Byte(k * 8),
            t,
            ns as f64,
            None,
            &name,
            "event",
            None,
        );
        k += 1;
    }
    Ok(out.finish())
}

/// The first little-endian u64 of a file.
fn first_u64(path: &Path) -> Option<u64> {
    let mut f = gazelight_input::open(path).ok()?;
    let mut b = [0u8; 8];
    f.read_exact(&mut b).ok()?;
    Some(u64::from_le_bytes(b))
}

/// A CSV recording's events: a Neon / Pupil Cloud `events.csv` in the
/// same folder (`timestamp [ns]`, `name`), on the CSV importer's clock
/// for a `timestamp [ns]` column (ns × 1e-9).
pub fn csv_sidecar(path: &Path) -> Result<RecordingEvents, ImportError> {
    let mut out = RecordingEvents::new("csv", "Unix time, ns");
    let dir = path.parent().unwrap_or(Path::new("."));
    let events = dir.join("events.csv");
    if events.is_file() && events != path {
        table_events(
            &events,
            &mut out,
            TableSpec {
                time: &["timestamp_ns"],
                text: &["name"],
                duration: None,
                scale: 1e-9,
                source: "event",
            },
        )?;
    }
    Ok(out.finish())
}

// --------------------------------------------------------------------- CSV

/// Which columns of an events table to read.
struct TableSpec<'a> {
    /// Accepted names of the time column (normalised: lower case, runs of
    /// other characters than letters and digits as one `_`).
    time: &'a [&'a str],
    text: &'a [&'a str],
    duration: Option<&'a str>,
    /// Time column → seconds.
    scale: f64,
    source: &'a str,
}

/// A column name as the CSV importer matches it: lower case, every run
/// of characters other than letters and digits one `_`, trimmed.
fn normalise(name: &str) -> String {
    let mut s = String::with_capacity(name.len());
    for c in name.trim().chars() {
        if c.is_ascii_alphanumeric() {
            s.push(c.to_ascii_lowercase());
        } else if !s.ends_with('_') {
            s.push('_');
        }
    }
    s.trim_matches('_').to_owned()
}

/// Reads an events table (a header line, then one event a line) into
/// `out`; `t_clock` is the time column's own value.
fn table_events(
    path: &Path,
    out: &mut RecordingEvents,
    spec: TableSpec<'_>,
) -> Result<(), ImportError> {
    out.files.push(path.to_owned());
    let mut reader = open_text(path)?;
    let mut line = String::new();
    let mut line_no = 0u64;
    let mut header: Option<(usize, usize, Option<usize>)> = None;
    let sep = if path
        .extension()
        .is_some_and(|e| e.eq_ignore_ascii_case("tsv"))
    {
        '\t'
    } else {
        ','
    };
    loop {
        match read_text_line(&mut reader, &mut line, &mut line_no, path)? {
            LineRead::Eof => break,
            LineRead::TooLong(n) => {
                out.warnings.skip_long_line(path, line_no, n, "a row");
                continue;
            }
            LineRead::NotUtf8 => {
                out.warnings.skip_not_utf8(path, line_no);
                continue;
            }
            LineRead::Text => {}
        }
        let l = line.trim_end_matches(['\n', '\r']);
        if l.trim().is_empty() {
            continue;
        }
        let fields = gazelight_input::split_csv_line(l, sep);
        let Some((ti, xi, di)) = header else {
            let names: Vec<String> = fields.iter().map(|f| normalise(f)).collect();
            // The first of `want` (in its order of preference) the header has.
            let find = |want: &[&str]| {
                want.iter()
                    .find_map(|w| names.iter().position(|n| n.as_str() == *w))
            };
            match (find(spec.time), find(spec.text)) {
                (Some(t), Some(x)) => {
                    header = Some((t, x, spec.duration.and_then(|d| find(&[d]))));
                    continue;
                }
                _ => {
                    return Err(ImportError::Structure {
                        path: path.to_owned(),
                        position: Position::Line(line_no),
                        reason: format!(
                            "an events table needs a time column ({}) and a text column ({}); \
                             the header is `{}`",
                            spec.time.join(" | "),
                            spec.text.join(" | "),
                            cut(l, 200)
                        ),
                    });
                }
            }
        };
        let pos = Position::Line(line_no);
        let Some(t) = fields.get(ti).and_then(|f| f.trim().parse::<f64>().ok()) else {
            out.warnings.skip(
                path,
                pos,
                format_args!("column {}: no numeric time in `{}`", ti + 1, cut(l, 120)),
            );
            continue;
        };
        let text = fields.get(xi).map_or("", |s| s.as_str());
        let duration = di
            .and_then(|i| fields.get(i))
            .and_then(|f| f.trim().parse::<f64>().ok());
        out.push(
            path,
            pos,
            t * spec.scale,
            t,
            duration,
            text,
            spec.source,
            None,
        );
    }
    Ok(())
}

// -------------------------------------------------------------------- BIDS

/// A gzipped TSV, decompressed within [`gazelight_input::MAX_EXPANSION_RATIO`].
fn open_gz(path: &Path) -> Result<impl BufRead, ImportError> {
    let io = |source| ImportError::Io {
        path: path.to_owned(),
        source,
    };
    let f = gazelight_input::open(path).map_err(io)?;
    let compressed = f.metadata().map_err(io)?.len();
    Ok(BufReader::new(gazelight_input::ExpansionLimit::new(
        flate2::read::MultiGzDecoder::new(BufReader::new(f)),
        compressed,
    )))
}

/// Events of a BIDS eye-tracking recording (`path` a `*_physio.tsv.gz` or
/// `*_physio.json`): its physioevents' messages and the `_events.tsv`.
pub fn bids(path: &Path) -> Result<RecordingEvents, ImportError> {
    let mut out = RecordingEvents::new("bids-eyetrack", "the physio file's timestamp clock, s");
    let name = path.file_name().and_then(|n| n.to_str()).unwrap_or("");
    let Some(stem) = name
        .strip_suffix("_physio.tsv.gz")
        .or_else(|| name.strip_suffix("_physio.json"))
    else {
        return Ok(out);
    };
    let dir = path
        .parent()
        .map_or_else(|| PathBuf::from("."), Path::to_path_buf);
    let sidecar_path = dir.join(format!("{stem}_physio.json"));
    let sidecar = crate::bids::read_json(&sidecar_path)?;
    let t_scale = sidecar
        .get("timestamp")
        .and_then(|t| t.get("Units"))
        .and_then(serde_json::Value::as_str)
        .and_then(crate::bids::time_scale)
        .unwrap_or(1.0);
    // physioevents: the tracker's messages.
    let ev_json = dir.join(format!("{stem}_physioevents.json"));
    let ev_tsv = dir.join(format!("{stem}_physioevents.tsv.gz"));
    if ev_json.is_file() && ev_tsv.is_file() {
        out.files.push(ev_tsv.clone());
        let cols: Vec<String> = crate::bids::read_json(&ev_json)?
            .get("Columns")
            .and_then(serde_json::Value::as_array)
            .map(|a| {
                a.iter()
                    .filter_map(|v| v.as_str().map(str::to_owned))
                    .collect()
            })
            .unwrap_or_default();
        let idx = |n: &str| cols.iter().position(|c| c == n);
        if let Some(onset) = idx("onset") {
            let (duration, trial_type, message) =
                (idx("duration"), idx("trial_type"), idx("message"));
            let mut r = open_gz(&ev_tsv)?;
            let mut line = String::new();
            let mut line_no = 0u64;
            loop {
                match read_text_line(&mut r, &mut line, &mut line_no, &ev_tsv)? {
                    LineRead::Eof => break,
                    LineRead::TooLong(n) => {
                        out.warnings.skip_long_line(&ev_tsv, line_no, n, "a row");
                        continue;
                    }
                    LineRead::NotUtf8 => {
                        out.warnings.skip_not_utf8(&ev_tsv, line_no);
                        continue;
                    }
                    LineRead::Text => {}
                }
                let l = line.trim_end_matches(['\n', '\r']);
                if l.is_empty() {
                    continue;
                }
                let f: Vec<&str> = l.split('\t').collect();
                let get = |i: Option<usize>| {
                    i.and_then(|i| f.get(i))
                        .map(|s| s.trim())
                        .filter(|s| !s.is_empty() && *s != "n/a")
                };
                let text = match (get(message), get(trial_type)) {
                    (Some(m), _) => m,
                    (None, Some(t)) if !matches!(t, "blink" | "fixation" | "saccade") => t,
                    _ => continue,
                };
                let pos = Position::Line(line_no);
                let Some(t) = get(Some(onset)).and_then(|s| s.parse::<f64>().ok()) else {
                    out.warnings.skip(&ev_tsv, pos, "no numeric onset");
                    continue;
                };
                let d = get(duration)
                    .and_then(|s| s.parse::<f64>().ok())
                    .map(|d| d * t_scale);
                out.push(&ev_tsv, pos, t * t_scale, t, d, text, "physioevents", None);
            }
        }
    }
    // The task events: `<stem without recording->_events.tsv`, onsets in
    // seconds from the first physio sample (at `StartTime`).
    let base = match stem.find("_recording-") {
        Some(k) => {
            let rest = &stem[k + "_recording-".len()..];
            let after = rest.find('_').map_or("", |e| &rest[e..]);
            format!("{}{after}", &stem[..k])
        }
        None => stem.to_owned(),
    };
    let events_tsv = dir.join(format!("{base}_events.tsv"));
    if events_tsv.is_file() {
        let start_time = sidecar
            .get("StartTime")
            .and_then(serde_json::Value::as_f64)
            .unwrap_or(0.0);
        let tsv = dir.join(format!("{stem}_physio.tsv.gz"));
        let first = first_timestamp(&tsv)?.map(|t| t * t_scale);
        let Some(first) = first else {
            out.warnings.note(
                &events_tsv,
                Position::File,
                "the physio file has no row: its events cannot be placed",
            );
            return Ok(out.finish());
        };
        let mut table = RecordingEvents::new("bids-eyetrack", "");
        table_events(
            &events_tsv,
            &mut table,
            TableSpec {
                time: &["onset"],
                text: &["message", "trial_type", "value"],
                duration: Some("duration"),
                scale: 1.0,
                source: "events",
            },
        )?;
        out.files.extend(table.files);
        for e in table.events {
            let t = first + (e.t_secs - start_time);
            out.push(
                &events_tsv,
                Position::File,
                t,
                e.t_clock,
                e.duration_secs,
                &e.text,
                "events",
                None,
            );
        }
        out.dropped += table.dropped;
        out.truncated += table.truncated;
        out.warnings.skipped_records += table.warnings.skipped_records;
        for m in table.warnings.messages {
            if out.warnings.messages.len() < crate::KEPT_WARNING_MESSAGES {
                out.warnings.messages.push(m);
            }
        }
    }
    Ok(out.finish())
}

/// The first row's `timestamp` (first column) of a physio file.
fn first_timestamp(path: &Path) -> Result<Option<f64>, ImportError> {
    let mut r = open_gz(path)?;
    let mut line = String::new();
    let mut line_no = 0u64;
    for _ in 0..16 {
        match read_text_line(&mut r, &mut line, &mut line_no, path)? {
            LineRead::Eof => return Ok(None),
            LineRead::Text => {
                let first = line.split('\t').next().unwrap_or("").trim();
                if let Ok(t) = first.parse::<f64>() {
                    return Ok(Some(t));
                }
            }
            _ => {}
        }
    }
    Ok(None)
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn msg_lines_with_and_without_offsets() {
        assert_eq!(
            msg_line("MSG\t1250 750 imageOnset"),
            Some((500.0, "imageOnset"))
        );
        assert_eq!(
            msg_line("MSG\t229837 -7 Instruction_screen"),
            Some((229844.0, "Instruction_screen"))
        );
        assert_eq!(
            msg_line("MSG\t221660 !CMD 0 select_parser_configuration 0"),
            Some((221660.0, "!CMD 0 select_parser_configuration 0"))
        );
        // A lone number is the text, not an offset.
        assert_eq!(msg_line("MSG\t1000 5"), Some((1000.0, "5")));
        assert_eq!(msg_line("MSG\t319073 !CAL "), Some((319073.0, "!CAL")));
        assert_eq!(msg_line("MSGX 1 a"), None);
        assert_eq!(msg_line("MSG\tabc a"), None);
    }

    #[test]
    fn trials_and_their_variables() {
        let asc = "MSG\t100 start\nMSG\t200 TRIALID 7\n250\t1\t2\t3\t.....\nMSG\t300 0 !V TRIAL_VAR cond bright screen\n\
                   MSG\t310 TRIAL_RESULT 0\nMSG\t400 TRIALID 8\nMSG\t500 !V TRIAL_VAR cond dark\nMSG\t600 TRIALID 9\n";
        let ev = eyelink(asc.as_bytes(), Path::new("t.asc")).unwrap();
        assert_eq!(ev.events.len(), 7);
        assert_eq!(ev.trials.len(), 3);
        assert_eq!(ev.trials[0].id, "7");
        assert_eq!(
            ev.trials[0].vars,
            vec![("cond".to_owned(), "bright screen".to_owned())]
        );
        assert!((ev.trials[0].end_t_secs.unwrap() - 0.31).abs() < 1e-12);
        assert_eq!(ev.trials[0].result.as_deref(), Some("0"));
        assert!(
            (ev.trials[1].end_t_secs.unwrap() - 0.6).abs() < 1e-12,
            "closed by the next TRIALID"
        );
        assert_eq!(ev.events[0].trial, None);
        assert_eq!(ev.events[1].trial, Some(0));
        assert_eq!(
            ev.events[3].trial,
            Some(0),
            "TRIAL_RESULT belongs to its trial"
        );
        assert_eq!(ev.events[6].trial, Some(2));
        assert_eq!(ev.events[2].text, "!V TRIAL_VAR cond bright screen");
        assert_eq!(kind_of(&ev.events[2].text), "!V TRIAL_VAR");
        assert!((ev.events[1].t_secs - 0.2).abs() < 1e-12 && ev.events[1].t_clock == 200.0);
    }

    #[test]
    fn counts_and_lengths_are_bounded() {
        let mut asc = String::new();
        for i in 0..(MAX_EVENTS + 10) {
            asc.push_str(&format!("MSG\t{i} m\n"));
        }
        asc.push_str(&format!("MSG\t1 {}\n", "x".repeat(5000)));
        let ev = eyelink(asc.as_bytes(), Path::new("big.asc")).unwrap();
        assert_eq!(ev.events.len(), MAX_EVENTS);
        assert_eq!(ev.dropped, 11);
        assert!(
            ev.warnings
                .messages
                .iter()
                .any(|m| m.contains("the rest are counted"))
        );
        let s = ev.summary();
        assert_eq!(s.total, MAX_EVENTS as u64 + 11);

        let ev = eyelink(
            format!("MSG\t1 {}é\n", "x".repeat(MAX_TEXT_BYTES - 1)).as_bytes(),
            Path::new("t.asc"),
        )
        .unwrap();
        assert_eq!(ev.truncated, 1);
        assert_eq!(ev.events[0].text.len(), MAX_TEXT_BYTES - 1);
    }

    #[test]
    fn csv_fields_and_names() {
        assert_eq!(
            gazelight_input::split_csv_line("1,\"a, \"\"b\"\"\",c", ','),
            vec!["1", "a, \"b\"", "c"]
        );
        assert_eq!(normalise("timestamp [ns]"), "timestamp_ns");
        assert_eq!(normalise("Recording ID"), "recording_id");
    }
}
