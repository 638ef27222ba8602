//! BIDS eye-tracking (BIDS 1.11, the eye-tracking extension of
//! physiological recordings, BEP020): read a recording's per-eye
//! `*_recording-<label>_physio.tsv.gz` + `.json` pairs as gazelight
//! samples, and write a recording as a BIDS dataset with a
//! `derivatives/gazelight/` folder.
//!
//! A physio file has no header: its columns are the sidecar's `Columns`
//! (`timestamp`, `x_coordinate`, `y_coordinate` first, then `pupil_size`
//! and any other), `n/a` where a value is missing. The sidecar says
//! `PhysioType: "eyetrack"`, `RecordedEye` (`right`, `left`,
//! `cyclopean`), `SampleCoordinateSystem`, `SamplingFrequency`,
//! `StartTime`, and each column's `Units`.
//!
//! What gazelight writes ([`export_raw`]): per eye a file —
//! `recording-eye1` the right eye (gazelight's eye 0), `recording-eye2` the
//! left (eye 1), `recording-eye3` the binocular (`cyclopean`) gaze — with
//! the columns `timestamp` (s, the recording's clock), `x_coordinate`,
//! `y_coordinate` (gaze normalised to the scene/display image, 0..1,
//! origin top-left: `SampleCoordinateSystem: "custom"`, units
//! `arbitrary`), `pupil_size` (in the recording's own pupil unit: `mm`,
//! `pixel`, or `arbitrary` area or diameter) and two extra columns that
//! make the file a lossless copy of the samples: `pupil_confidence` and
//! `gaze_confidence` (`n/a` where the row has no pupil or no gaze sample).
//! Blinks the tracker reported go to `*_physioevents.tsv.gz` (`onset`,
//! `duration`, `trial_type` = `blink`, `eyes`).
//!
//! Reading ([`BidsImporter`]): the file given and its siblings that differ
//! only in the `recording-` label are merged by time. Files written
//! elsewhere are read too: without the confidence columns a row is a
//! pupil sample when it has a `pupil_size` column (a lost pupil when
//! `n/a`) and a gaze sample when x and y are numbers; gaze in `pixel` is
//! normalised by `ScreenResolution` (from the sidecar or the recording's
//! `*_events.json` `StimulusPresentation`), other gaze units are taken as
//! normalised already.

use std::collections::BTreeMap;
use std::fs::File;
use std::io::{BufRead, BufReader, Write};
use std::path::{Path, PathBuf};

use flate2::Compression;
use flate2::read::MultiGzDecoder;
use flate2::write::GzEncoder;
use serde_json::{Value, json};

use super::{ImportError, ImportWarnings, Importer, Pending, Position};
mod transaction;
use gazelight_eye::filter::FilterChain;
use gazelight_eye::sample::{
    BlinkEvent, DetectorMethod, GazeEyes, GazeSample, PupilSample, PupilUnit, Sample,
};
pub use transaction::Transaction;

/// The BIDS version the files follow.
pub const BIDS_VERSION: &str = "1.11.0";
/// Largest sidecar, bytes.
const MAX_SIDECAR_BYTES: u64 = 1 << 20;
/// Most files in one recording group (eyes + events).
const MAX_GROUP_FILES: usize = 16;
/// The columns gazelight writes, in order.
pub const COLUMNS: [&str; 6] = [
    "timestamp",
    "x_coordinate",
    "y_coordinate",
    "pupil_size",
    "pupil_confidence",
    "gaze_confidence",
];

fn structure(path: &Path, position: Position, reason: impl Into<String>) -> ImportError {
    ImportError::Structure {
        path: path.to_owned(),
        position,
        reason: reason.into(),
    }
}

fn io_err(path: &Path, source: std::io::Error) -> ImportError {
    ImportError::Io {
        path: path.to_owned(),
        source,
    }
}

/// Whether `path` names a BIDS physio file or its sidecar.
pub fn is_physio(path: &Path) -> bool {
    path.file_name()
        .and_then(|n| n.to_str())
        .is_some_and(|n| n.ends_with("_physio.tsv.gz") || n.ends_with("_physio.json"))
}

/// The part of a physio file name before `_physio…`, and its
/// `recording-` label if any.
fn stem_of(name: &str) -> Option<&str> {
    name.strip_suffix("_physio.tsv.gz")
        .or_else(|| name.strip_suffix("_physio.json"))
}

/// `stem` around its `recording-<label>` entity: (before, the label's
/// kind — the label without its digits, `eye1` → `eye`, `eye2filtered` →
/// `eyefiltered` — after).
fn split_recording(stem: &str) -> Option<(&str, String, &str)> {
    let k = stem.find("_recording-")?;
    let rest = &stem[k + "_recording-".len()..];
    let end = rest.find('_').unwrap_or(rest.len());
    let kind = rest[..end]
        .chars()
        .filter(|c| !c.is_ascii_digit())
        .collect();
    Some((&stem[..k + "_recording-".len()], kind, &rest[end..]))
}

/// A sidecar's JSON (at most [`MAX_SIDECAR_BYTES`]); also the events reader's.
pub(crate) fn read_json(path: &Path) -> Result<Value, ImportError> {
    let text =
        gazelight_input::read_to_string(path, MAX_SIDECAR_BYTES).map_err(|e| io_err(path, e))?;
    serde_json::from_str(&text).map_err(|e| {
        structure(
            path,
            Position::Line(e.line() as u64),
            format!("not JSON: {e}"),
        )
    })
}

/// How a physio file's columns are read.
#[derive(Clone, Debug)]
struct ColumnMap {
    t: usize,
    t_scale: f64,
    x: Option<usize>,
    y: Option<usize>,
    /// Divide x, y by this to normalise.
    gaze_range: [f64; 2],
    pupil: Option<usize>,
    pupil_unit: PupilUnit,
    pupil_conf: Option<usize>,
    gaze_conf: Option<usize>,
    eye: Recorded,
}

#[derive(Clone, Copy, Debug, PartialEq, Eq)]
enum Recorded {
    Right,
    Left,
    Cyclopean,
}

/// Seconds per unit of a time column's `Units` (`s`, `ms`, `us`, `ns`).
pub(crate) fn time_scale(units: &str) -> Option<f64> {
    Some(match units.trim() {
        "s" | "sec" | "seconds" => 1.0,
        "ms" => 1e-3,
        "us" | "µs" | "μs" => 1e-6,
        "ns" => 1e-9,
        _ => return None,
    })
}

/// The pupil unit of a `pupil_size` column's `Units` and `Description`.
fn pupil_unit(units: &str, description: &str) -> PupilUnit {
    match units.trim().to_ascii_lowercase().as_str() {
        "mm" => PupilUnit::Mm,
        "pixel" | "pixels" | "px" => PupilUnit::Px,
        _ if description.to_ascii_lowercase().contains("area") => PupilUnit::ArbitraryArea,
        _ => PupilUnit::Arbitrary,
    }
}

fn unit_name(unit: PupilUnit) -> (&'static str, &'static str) {
    match unit {
        PupilUnit::Mm => ("mm", "Pupil diameter of the recorded eye, mm."),
        PupilUnit::Px => (
            "pixel",
            "Pupil diameter of the recorded eye in eye-camera pixels.",
        ),
        PupilUnit::ArbitraryArea => (
            "arbitrary",
            "Pupil area of the recorded eye as the eye tracker reports it, arbitrary units.",
        ),
        PupilUnit::Arbitrary => (
            "arbitrary",
            "Pupil diameter of the recorded eye as the eye tracker reports it, arbitrary units.",
        ),
    }
}

/// The screen resolution in pixels a `pixel` gaze is normalised by: the
/// sidecar's own `ScreenResolution`, else `StimulusPresentation` of the
/// recording's events sidecar.
fn screen_resolution(sidecar: &Value, events_json: Option<&Value>) -> Option<[f64; 2]> {
    let read = |v: &Value| {
        let a = v.as_array()?;
        Some([a.first()?.as_f64()?, a.get(1)?.as_f64()?]).filter(|r| r[0] > 0.0 && r[1] > 0.0)
    };
    sidecar.get("ScreenResolution").and_then(read).or_else(|| {
        events_json?
            .get("StimulusPresentation")?
            .get("ScreenResolution")
            .and_then(read)
    })
}

impl ColumnMap {
    fn from_sidecar(
        path: &Path,
        sidecar: &Value,
        events_json: Option<&Value>,
        warnings: &mut ImportWarnings,
    ) -> Result<Self, ImportError> {
        let bad = |reason: String| structure(path, Position::File, reason);
        if sidecar.get("PhysioType").and_then(Value::as_str) != Some("eyetrack") {
            return Err(bad(
                "the sidecar's PhysioType is not \"eyetrack\": not an eye-tracking recording"
                    .into(),
            ));
        }
        let cols: Vec<&str> = sidecar
            .get("Columns")
            .and_then(Value::as_array)
            .map(|a| a.iter().filter_map(Value::as_str).collect())
            .unwrap_or_default();
        let idx = |n: &str| cols.iter().position(|c| *c == n);
        let t = idx("timestamp").ok_or_else(|| {
            bad(format!(
                "the sidecar's Columns [{}] have no `timestamp`",
                cols.join(", ")
            ))
        })?;
        let units = |n: &str| {
            sidecar
                .get(n)
                .and_then(|c| c.get("Units"))
                .and_then(Value::as_str)
                .unwrap_or("")
                .to_owned()
        };
        let t_units = units("timestamp");
        let t_scale = if t_units.is_empty() {
            warnings.note(
                path,
                Position::File,
                "timestamp has no Units: taken as seconds",
            );
            1.0
        } else {
            time_scale(&t_units).ok_or_else(|| {
                bad(format!(
                    "timestamp Units `{t_units}` is not s, ms, us or ns"
                ))
            })?
        };
        let eye = match sidecar.get("RecordedEye").and_then(Value::as_str) {
            Some("right") => Recorded::Right,
            Some("left") => Recorded::Left,
            Some("cyclopean") => Recorded::Cyclopean,
            other => {
                return Err(bad(format!(
                    "RecordedEye {other:?} is not \"right\", \"left\" or \"cyclopean\""
                )));
            }
        };
        let (mut x, mut y) = (idx("x_coordinate"), idx("y_coordinate"));
        let gaze_units = units("x_coordinate").to_ascii_lowercase();
        let gaze_range = if matches!(gaze_units.as_str(), "pixel" | "pixels" | "px") {
            match screen_resolution(sidecar, events_json) {
                Some(r) => r,
                None => {
                    warnings.note(
                        path,
                        Position::File,
                        "gaze is in pixels but no ScreenResolution is given (sidecar or \
                         events.json StimulusPresentation): gaze left out",
                    );
                    x = None;
                    y = None;
                    [1.0, 1.0]
                }
            }
        } else {
            [1.0, 1.0]
        };
        let description = sidecar
            .get("pupil_size")
            .and_then(|c| c.get("Description"))
            .and_then(Value::as_str)
            .unwrap_or("");
        Ok(Self {
            t,
            t_scale,
            x,
            y,
            gaze_range,
            pupil: idx("pupil_size"),
            pupil_unit: pupil_unit(&units("pupil_size"), description),
            pupil_conf: idx("pupil_confidence"),
            gaze_conf: idx("gaze_confidence"),
            eye,
        })
    }
}

/// Parses one TSV field: `None` for `n/a` or empty.
fn field(fields: &[&str], i: Option<usize>) -> Result<Option<f64>, String> {
    let Some(i) = i else { return Ok(None) };
    match fields.get(i).map(|f| f.trim()) {
        None | Some("" | "n/a") => Ok(None),
        Some(f) => f
            .parse::<f64>()
            .map(Some)
            .map_err(|_| format!("column {}: `{f}` is not a number", i + 1)),
    }
}

/// Parses one TSV field as f32 (values gazelight wrote from f32 come back
/// bit for bit): `None` for `n/a` or empty.
fn field32(fields: &[&str], i: Option<usize>) -> Result<Option<f32>, String> {
    let Some(i) = i else { return Ok(None) };
    match fields.get(i).map(|f| f.trim()) {
        None | Some("" | "n/a") => Ok(None),
        Some(f) => f
            .parse::<f32>()
            .map(Some)
            .map_err(|_| format!("column {}: `{f}` is not a number", i + 1)),
    }
}

/// One gzipped TSV of a recording group, read line by line.
struct TsvSource {
    path: PathBuf,
    /// Decompressed bytes capped at `gazelight_input::MAX_EXPANSION_RATIO`
    /// times the file's size.
    reader: BufReader<gazelight_input::ExpansionLimit<MultiGzDecoder<BufReader<File>>>>,
    line: String,
    line_no: u64,
    kind: SourceKind,
    /// The next item: its time and samples.
    peeked: Option<(f64, Pending<2>)>,
    done: bool,
}

enum SourceKind {
    Physio(ColumnMap),
    /// physioevents: onset, duration, trial_type, eyes columns and the eye.
    Events {
        onset: usize,
        duration: Option<usize>,
        trial_type: Option<usize>,
        eyes: Option<usize>,
        t_scale: f64,
        eye: Option<u8>,
    },
}

impl TsvSource {
    fn open(path: &Path, kind: SourceKind) -> Result<Self, ImportError> {
        let f = gazelight_input::open(path).map_err(|e| io_err(path, e))?;
        let compressed = f.metadata().map_err(|e| io_err(path, e))?.len();
        Ok(Self {
            path: path.to_owned(),
            reader: BufReader::new(gazelight_input::ExpansionLimit::new(
                MultiGzDecoder::new(BufReader::new(f)),
                compressed,
            )),
            line: String::new(),
            line_no: 0,
            kind,
            peeked: None,
            done: false,
        })
    }

    /// Fills `peeked` with the next row that gives samples.
    fn fill(&mut self, warnings: &mut ImportWarnings) -> Result<(), ImportError> {
        while self.peeked.is_none() && !self.done {
            let read = gazelight_input::read_line(
                &mut self.reader,
                &mut self.line,
                gazelight_input::MAX_LINE_BYTES,
            )
            .map_err(|e| {
                structure(
                    &self.path,
                    Position::Line(self.line_no + 1),
                    format!("cannot read the gzipped TSV: {e}"),
                )
            })?;
            match read {
                gazelight_input::Line::Eof => {
                    self.done = true;
                    return Ok(());
                }
                gazelight_input::Line::TooLong(n) => {
                    self.line_no += 1;
                    warnings.skip_long_line(&self.path, self.line_no, n, "a row");
                    continue;
                }
                gazelight_input::Line::NotUtf8 => {
                    self.line_no += 1;
                    warnings.skip_not_utf8(&self.path, self.line_no);
                    continue;
                }
                gazelight_input::Line::Read => self.line_no += 1,
            }
            let line = self.line.trim_end_matches(['\n', '\r']);
            if line.is_empty() {
                continue;
            }
            let fields: Vec<&str> = line.split('\t').collect();
            match self.row(&fields) {
                Ok(item) => self.peeked = item,
                Err(reason) => {
                    warnings.skip(&self.path, Position::Line(self.line_no), reason);
                }
            }
        }
        Ok(())
    }

    fn row(&self, f: &[&str]) -> Result<Option<(f64, Pending<2>)>, String> {
        let mut out = Pending::new();
        match &self.kind {
            SourceKind::Physio(m) => {
                let t = field(f, Some(m.t))?.ok_or("no timestamp")? * m.t_scale;
                let pupil = field32(f, m.pupil)?;
                let pconf = field32(f, m.pupil_conf)?;
                let has_pupil = if m.pupil_conf.is_some() {
                    pconf.is_some()
                } else {
                    m.pupil.is_some()
                };
                let eyes: &[u8] = match m.eye {
                    Recorded::Right => &[0],
                    Recorded::Left => &[1],
                    Recorded::Cyclopean => &[],
                };
                if has_pupil {
                    for &eye in eyes {
                        let raw = pupil.filter(|p| p.is_finite()).unwrap_or(0.0);
                        let valid = raw > 0.0;
                        let confidence = pconf.unwrap_or(if valid { 1.0 } else { 0.0 });
                        out.push(Sample::Pupil(PupilSample {
                            t_secs: t,
                            eye,
                            diameter_raw: raw,
                            unit: m.pupil_unit,
                            diameter_mm: (valid && m.pupil_unit == PupilUnit::Mm).then_some(raw),
                            confidence,
                            norm_pos: [f32::NAN; 2],
                            method: DetectorMethod::Other,
                        }));
                    }
                }
                let (x, y) = (field32(f, m.x)?, field32(f, m.y)?);
                let gconf = field32(f, m.gaze_conf)?;
                // Every row of a file with gaze columns is a gaze sample; an
                // n/a gaze is a lost one (confidence 0), never left out.
                let has_gaze = if m.gaze_conf.is_some() {
                    gconf.is_some()
                } else {
                    m.x.is_some() && m.y.is_some()
                };
                if has_gaze {
                    let (u, v) = match (x, y) {
                        (Some(x), Some(y)) if m.gaze_range == [1.0, 1.0] => (x, y),
                        (Some(x), Some(y)) => (
                            (f64::from(x) / m.gaze_range[0]) as f32,
                            (f64::from(y) / m.gaze_range[1]) as f32,
                        ),
                        _ => (f32::NAN, f32::NAN),
                    };
                    out.push(Sample::Gaze(GazeSample {
                        t_secs: t,
                        gaze_uv: [u, v],
                        confidence: gconf.unwrap_or(if x.is_some() && y.is_some() {
                            1.0
                        } else {
                            0.0
                        }),
                        eyes: match m.eye {
                            Recorded::Right => GazeEyes::Right,
                            Recorded::Left => GazeEyes::Left,
                            Recorded::Cyclopean => GazeEyes::Binocular,
                        },
                    }));
                }
                Ok(Some((t, out)))
            }
            SourceKind::Events {
                onset,
                duration,
                trial_type,
                eyes,
                t_scale,
                eye,
            } => {
                let kind = trial_type.and_then(|i| f.get(i)).map_or("", |s| s.trim());
                if kind != "blink" {
                    return Ok(None);
                }
                let t = field(f, Some(*onset))?.ok_or("no onset")? * t_scale;
                let d = field(f, *duration)?.unwrap_or(0.0) * t_scale;
                let both = eyes
                    .and_then(|i| f.get(i))
                    .is_some_and(|s| s.trim() == "both");
                out.push(Sample::Blink(BlinkEvent {
                    start_t_secs: t,
                    end_t_secs: t + d,
                    eye: if both { None } else { *eye },
                }));
                Ok(Some((t, out)))
            }
        }
    }
}

/// Streaming importer of a BIDS eye-tracking recording: its per-eye physio
/// files (and physioevents) merged by time.
pub struct BidsImporter {
    sources: Vec<TsvSource>,
    /// The first eye sidecar's `SamplingFrequency`, Hz.
    rate_hz: Option<f64>,
    /// Its `Manufacturer` and `ManufacturersModelName`.
    device: crate::Device,
    pending: Pending<2>,
    warnings: ImportWarnings,
    position: Position,
    done: bool,
}

impl BidsImporter {
    /// Opens the recording of `path` (a `*_physio.tsv.gz` or `*_physio.json`)
    /// with its sibling eyes.
    pub fn open(path: &Path) -> Result<Self, ImportError> {
        let name = path
            .file_name()
            .and_then(|n| n.to_str())
            .ok_or_else(|| structure(path, Position::File, "not a file name"))?;
        let stem = stem_of(name).ok_or_else(|| {
            structure(
                path,
                Position::File,
                "not a BIDS *_physio.tsv.gz or *_physio.json",
            )
        })?;
        let dir = path
            .parent()
            .map_or_else(|| PathBuf::from("."), Path::to_path_buf);
        let mut stems: Vec<String> = vec![stem.to_owned()];
        if let Some((before, kind, after)) = split_recording(stem) {
            let entries = std::fs::read_dir(&dir).map_err(|e| io_err(&dir, e))?;
            for entry in entries.flatten() {
                let n = entry.file_name();
                let Some(n) = n.to_str() else { continue };
                if let Some(s) = n.strip_suffix("_physio.json")
                    && s != stem
                    && s.starts_with(before)
                    && split_recording(s)
                        .is_some_and(|(b, k, a)| b == before && k == kind && a == after)
                {
                    stems.push(s.to_owned());
                }
            }
        }
        stems.sort();
        stems.truncate(MAX_GROUP_FILES);
        // The recording's events sidecar: the stem without the recording
        // entity, `_events.json`.
        let events_json = {
            let base = split_recording(stem).map_or(stem.to_owned(), |(b, _, a)| {
                format!("{}{a}", b.trim_end_matches("_recording-"))
            });
            let p = dir.join(format!("{base}_events.json"));
            if p.is_file() {
                Some(read_json(&p)?)
            } else {
                None
            }
        };
        let mut warnings = ImportWarnings::default();
        let mut sources = Vec::new();
        let mut rate_hz = None;
        let mut device = crate::Device::default();
        for s in &stems {
            let json_path = dir.join(format!("{s}_physio.json"));
            let tsv_path = dir.join(format!("{s}_physio.tsv.gz"));
            let sidecar = read_json(&json_path)?;
            if sidecar.get("PhysioType").and_then(Value::as_str) != Some("eyetrack") && s != stem {
                continue;
            }
            let map =
                ColumnMap::from_sidecar(&json_path, &sidecar, events_json.as_ref(), &mut warnings)?;
            let eye = match map.eye {
                Recorded::Right => Some(0),
                Recorded::Left => Some(1),
                Recorded::Cyclopean => None,
            };
            let t_scale = map.t_scale;
            if sources.is_empty() {
                rate_hz = sidecar
                    .get("SamplingFrequency")
                    .and_then(Value::as_f64)
                    .and_then(crate::plausible_rate);
                let text = |k: &str| {
                    sidecar
                        .get(k)
                        .and_then(Value::as_str)
                        .map(str::trim)
                        .filter(|v| !v.is_empty() && *v != "n/a")
                        .map(|v| v.chars().take(64).collect::<String>())
                };
                device = crate::Device {
                    manufacturer: text("Manufacturer"),
                    model: text("ManufacturersModelName"),
                };
            }
            sources.push(TsvSource::open(&tsv_path, SourceKind::Physio(map))?);
            let ev_json = dir.join(format!("{s}_physioevents.json"));
            let ev_tsv = dir.join(format!("{s}_physioevents.tsv.gz"));
            if ev_json.is_file() && ev_tsv.is_file() {
                let ev = read_json(&ev_json)?;
                let cols: Vec<&str> = ev
                    .get("Columns")
                    .and_then(Value::as_array)
                    .map(|a| a.iter().filter_map(Value::as_str).collect())
                    .unwrap_or_default();
                let idx = |n: &str| cols.iter().position(|c| *c == n);
                if let Some(onset) = idx("onset") {
                    sources.push(TsvSource::open(
                        &ev_tsv,
                        SourceKind::Events {
                            onset,
                            duration: idx("duration"),
                            trial_type: idx("trial_type"),
                            eyes: idx("eyes"),
                            t_scale,
                            eye,
                        },
                    )?);
                }
            }
        }
        if sources.is_empty() {
            return Err(structure(
                path,
                Position::File,
                "no eye-tracking physio file",
            ));
        }
        let files: Vec<String> = stems.iter().map(|s| format!("{s}_physio.tsv.gz")).collect();
        tracing::info!(path = %path.display(), files = ?files, "BIDS eye-tracking recording");
        Ok(Self {
            sources,
            rate_hz,
            device,
            pending: Pending::new(),
            warnings,
            position: Position::File,
            done: false,
        })
    }

    /// The next row of the earliest source, into `pending`.
    fn read_step(&mut self) -> Result<bool, ImportError> {
        for s in &mut self.sources {
            s.fill(&mut self.warnings)?;
        }
        let next = self
            .sources
            .iter()
            .enumerate()
            .filter_map(|(k, s)| s.peeked.as_ref().map(|(t, _)| (k, *t)))
            .min_by(|a, b| a.1.total_cmp(&b.1).then(a.0.cmp(&b.0)));
        let Some((k, _)) = next else { return Ok(false) };
        let src = &mut self.sources[k];
        if let Some((_, mut samples)) = src.peeked.take() {
            while let Some(s) = samples.pop() {
                self.pending.push(s);
            }
        }
        self.position = Position::Line(src.line_no);
        Ok(true)
    }
}

impl crate::Stepped for BidsImporter {
    fn step(&mut self) -> Result<bool, ImportError> {
        self.read_step()
    }
    fn pop_pending(&mut self) -> Option<Sample> {
        self.pending.pop()
    }
    fn done_mut(&mut self) -> &mut bool {
        &mut self.done
    }
}

impl Iterator for BidsImporter {
    type Item = Result<Sample, ImportError>;

    fn next(&mut self) -> Option<Self::Item> {
        crate::next_stepped(self)
    }
}

impl Importer for BidsImporter {
    fn warnings(&self) -> &ImportWarnings {
        &self.warnings
    }
    fn format(&self) -> &'static str {
        "bids-eyetrack"
    }
    fn nominal_rate_hz(&self) -> Option<f64> {
        self.rate_hz
    }
    fn device(&self) -> crate::Device {
        self.device.clone()
    }
    fn position(&self) -> Position {
        self.position
    }
    fn data_files(&self) -> Vec<PathBuf> {
        self.sources.iter().map(|s| s.path.clone()).collect()
    }
}

// ---------------------------------------------------------------- writing

/// Why an export failed.
#[derive(Debug, thiserror::Error)]
pub enum ExportError {
    #[error("cannot write {path}: {source}")]
    Io {
        path: PathBuf,
        #[source]
        source: std::io::Error,
    },
    #[error("{0}")]
    Import(#[from] ImportError),
    #[error("{0}")]
    Invalid(String),
}

fn wio(path: &Path) -> impl Fn(std::io::Error) -> ExportError + '_ {
    move |source| ExportError::Io {
        path: path.to_owned(),
        source,
    }
}

/// Where a recording goes in a BIDS dataset: `sub-<subject>[/ses-<session>]/beh/`
/// and `sub-<subject>[_ses-<session>]_task-<task>[_run-<run>]_…`.
#[derive(Clone, Debug, PartialEq, Eq)]
pub struct BidsNames {
    pub subject: String,
    pub session: Option<String>,
    pub task: String,
    pub run: Option<u32>,
}

/// Whether `label` is a BIDS label (letters and digits only).
pub fn is_label(label: &str) -> bool {
    !label.is_empty() && label.chars().all(|c| c.is_ascii_alphanumeric())
}

impl BidsNames {
    fn check(&self) -> Result<(), ExportError> {
        for (what, v) in [
            ("subject", Some(self.subject.as_str())),
            ("session", self.session.as_deref()),
            ("task", Some(self.task.as_str())),
        ] {
            if let Some(v) = v
                && !is_label(v)
            {
                return Err(ExportError::Invalid(format!(
                    "{what} label `{v}`: BIDS labels are letters and digits only"
                )));
            }
        }
        Ok(())
    }

    /// The folder of the files, relative to a dataset root.
    pub fn dir(&self) -> PathBuf {
        let mut p = PathBuf::from(format!("sub-{}", self.subject));
        if let Some(s) = &self.session {
            p.push(format!("ses-{s}"));
        }
        p.push("beh");
        p
    }

    /// The files' common name start.
    pub fn prefix(&self) -> String {
        let mut s = format!("sub-{}", self.subject);
        if let Some(ses) = &self.session {
            s.push_str(&format!("_ses-{ses}"));
        }
        s.push_str(&format!("_task-{}", self.task));
        if let Some(r) = self.run {
            s.push_str(&format!("_run-{r}"));
        }
        s
    }
}

/// The eye files: eye1 right (eye 0), eye2 left (eye 1), eye3 binocular.
const EYE_FILES: [(&str, &str); 3] = [("eye1", "right"), ("eye2", "left"), ("eye3", "cyclopean")];

/// One row being assembled (samples of the same time and file share it).
#[derive(Clone, Copy, Debug, Default)]
struct Row {
    t: f64,
    x: f32,
    y: f32,
    pupil: Option<f32>,
    pupil_conf: Option<f32>,
    gaze_conf: Option<f32>,
}

fn num(v: Option<f32>) -> String {
    match v {
        Some(v) if v.is_finite() => format!("{v}"),
        _ => "n/a".into(),
    }
}

/// A gzipped TSV being written with its row statistics.
struct TsvOut {
    path: PathBuf,
    w: GzEncoder<std::io::BufWriter<File>>,
    rows: u64,
    last_t: f64,
    /// Steps of at most [`crate::summary::GAP_S`] between consecutive rows:
    /// their count and sum, s (the pauses between trials left out).
    steps: (u64, f64),
}

impl TsvOut {
    fn create(tx: &mut Transaction, path: &Path) -> Result<Self, ExportError> {
        let f = tx.create(path)?;
        Ok(Self {
            path: path.to_owned(),
            w: GzEncoder::new(std::io::BufWriter::new(f), Compression::default()),
            rows: 0,
            last_t: f64::NAN,
            steps: (0, 0.0),
        })
    }

    fn line(&mut self, t: f64, cells: &[String]) -> Result<(), ExportError> {
        let mut line = format!("{t}");
        for c in cells {
            line.push('\t');
            line.push_str(c);
        }
        line.push('\n');
        self.w.write_all(line.as_bytes()).map_err(wio(&self.path))?;
        let dt = t - self.last_t;
        if dt > 0.0 && dt <= crate::summary::GAP_S {
            self.steps.0 += 1;
            self.steps.1 += dt;
        }
        self.last_t = t;
        self.rows += 1;
        Ok(())
    }

    /// Finishes the file: its rows and their rate, Hz — the mean rate of
    /// the steps between rows, the pauses longer than
    /// [`crate::summary::GAP_S`] left out (rows over the whole span would
    /// count the gaps between an EyeLink file's trials); 0 for fewer than
    /// two rows.
    fn finish(self) -> Result<(u64, f64), ExportError> {
        let path = self.path.clone();
        let mut inner = self.w.finish().map_err(wio(&path))?;
        inner.flush().map_err(wio(&path))?;
        inner.get_ref().sync_all().map_err(wio(&path))?;
        let (n, sum) = self.steps;
        let rate = if n > 0 && sum > 0.0 {
            n as f64 / sum
        } else {
            0.0
        };
        Ok((self.rows, rate))
    }
}

/// What [`export_raw`] wrote.
#[derive(Clone, Debug, Default, serde::Serialize)]
pub struct RawExport {
    /// The recording's events written as physioevents messages (into each
    /// eye's file; [`export_raw_with_events`]).
    pub messages: u64,
    /// Trials written to the task's `_events.tsv`.
    pub trials: u64,
    /// Per written eye file: (path, rows, sampling frequency Hz).
    pub files: Vec<(PathBuf, u64, f64)>,
    /// Blink events written.
    pub blinks: u64,
    /// Pupil samples left out because their unit differs from the first
    /// one of that eye (one unit per column).
    pub unit_mismatch: u64,
}

/// Describes the recording in the eye sidecars.
#[derive(Clone, Debug, Default)]
pub struct RecordingMeta {
    /// The importer's format (`eyelink-asc`, `neon`, …).
    pub format: String,
    /// The recording's own name ([`source_name`]: its file or directory
    /// name), never a path of the exporting machine.
    pub source: String,
    /// The tracker's maker and model, as the recording says.
    pub device: crate::Device,
    /// The sampling rate the recording states, Hz.
    pub nominal_rate_hz: Option<f64>,
}

impl RecordingMeta {
    /// What `importer` says of the recording `path` (ask once it has been
    /// read: a text format states its rate on a line of its own).
    pub fn of(importer: &dyn Importer, path: &Path) -> Self {
        Self {
            format: importer.format().to_owned(),
            source: source_name(path),
            device: importer.device(),
            nominal_rate_hz: importer.nominal_rate_hz(),
        }
    }
}

/// A recording's name for a sidecar: the last component of its path (an
/// XDF file's `?stream=` kept), so no sidecar holds a path of the machine
/// that exported it.
pub fn source_name(path: &Path) -> String {
    let s = path.to_string_lossy();
    let trimmed = s.trim_end_matches(['/', '\\']);
    let name = trimmed
        .rsplit(['/', '\\'])
        .next()
        .filter(|n| !n.is_empty() && *n != "." && *n != "..")
        .unwrap_or("recording");
    name.chars().take(255).collect()
}

/// Writes the samples of `importer` (the recording `recording`) as the raw
/// per-eye physio files (and physioevents with the tracker's blinks) of
/// `tx`'s recording in `tx`'s dataset, and the dataset's top-level files
/// if missing (`dataset_description.json`, `README`,
/// `participants.tsv`/`.json`, the participant added), all staged in `tx`
/// until its commit. The sidecars' `SamplingFrequency` is the rate the
/// recording states (else the rows' rate without the pauses),
/// `Manufacturer`/`ManufacturersModelName` the recording's tracker, and
/// `RecordingSource` the recording's name ([`RecordingMeta::of`]).
pub fn export_raw(
    importer: &mut dyn Importer,
    tx: &mut Transaction,
    recording: &Path,
) -> Result<RawExport, ExportError> {
    export_raw_with_events(importer, tx, recording, None)
}

/// A message's text as one TSV cell: tabs and line breaks as spaces,
/// `n/a` when empty.
fn tsv_text(s: &str) -> String {
    let t: String = s
        .chars()
        .map(|c| {
            if matches!(c, '\t' | '\n' | '\r') {
                ' '
            } else {
                c
            }
        })
        .collect();
    if t.trim().is_empty() { "n/a".into() } else { t }
}

/// Writes the recording's messages `msgs[*next..]` up to time `until`
/// (inclusive) into a physioevents file with the `message` column.
fn write_messages(
    out: &mut TsvOut,
    msgs: &[crate::events::Event],
    next: &mut usize,
    until: f64,
) -> Result<(), ExportError> {
    while let Some(e) = msgs.get(*next).filter(|e| e.t_secs <= until) {
        let duration = e.duration_secs.map_or("n/a".into(), |d| format!("{d}"));
        out.line(
            e.t_secs,
            &[duration, "message".into(), "n/a".into(), tsv_text(&e.text)],
        )?;
        *next += 1;
    }
    Ok(())
}

/// [`export_raw`] with the recording's events ([`crate::events`]): each
/// eye's `*_physioevents.tsv.gz` then also holds every event as a
/// `message` row (`trial_type` `message`, the text in the `message`
/// column) in time order among the blinks, and, where the recording has
/// trials (EyeLink's `TRIALID`), the task's `*_events.tsv` holds one row
/// per trial (onset in seconds from the first sample, its duration to
/// `TRIAL_RESULT`, `trial_type` `trial`, its id, result and `TRIAL_VAR`s).
pub fn export_raw_with_events(
    importer: &mut dyn Importer,
    tx: &mut Transaction,
    recording: &Path,
    recording_events: Option<&crate::events::RecordingEvents>,
) -> Result<RawExport, ExportError> {
    let msgs: &[crate::events::Event] = recording_events.map_or(&[], |e| e.events.as_slice());
    let mut next_msg = [0usize; 3];
    let mut first_t = f64::INFINITY;
    let names = tx.names().clone();
    let dir = tx.root().join(names.dir());
    write_dataset_files(tx)?;
    let prefix = names.prefix();
    let mut outs: [Option<TsvOut>; 3] = [None, None, None];
    let mut rows: [Option<Row>; 3] = [None; 3];
    let mut units: [Option<PupilUnit>; 3] = [None; 3];
    let mut events: [Option<TsvOut>; 3] = [None, None, None];
    let mut report = RawExport::default();
    let flush = |tx: &mut Transaction,
                 outs: &mut [Option<TsvOut>; 3],
                 k: usize,
                 row: Row|
     -> Result<(), ExportError> {
        if outs[k].is_none() {
            let p = dir.join(format!(
                "{prefix}_recording-{}_physio.tsv.gz",
                EYE_FILES[k].0
            ));
            outs[k] = Some(TsvOut::create(tx, &p)?);
        }
        let has_gaze = row.gaze_conf.is_some();
        let cells = [
            if has_gaze {
                num(Some(row.x))
            } else {
                "n/a".into()
            },
            if has_gaze {
                num(Some(row.y))
            } else {
                "n/a".into()
            },
            num(row.pupil.filter(|p| *p != 0.0)),
            num(row.pupil_conf),
            num(row.gaze_conf),
        ];
        match outs[k].as_mut() {
            Some(o) => o.line(row.t, &cells),
            None => Ok(()),
        }
    };
    for item in &mut *importer {
        let s = item?;
        match s {
            Sample::Pupil(p) => {
                let k = match p.eye {
                    0 => 0,
                    1 => 1,
                    _ => continue,
                };
                if *units[k].get_or_insert(p.unit) != p.unit {
                    report.unit_mismatch += 1;
                    continue;
                }
                first_t = first_t.min(p.t_secs);
                let fits = rows[k].is_some_and(|r| r.t == p.t_secs && r.pupil_conf.is_none());
                if !fits {
                    if let Some(r) = rows[k].take() {
                        flush(tx, &mut outs, k, r)?;
                    }
                    rows[k] = Some(Row {
                        t: p.t_secs,
                        ..Row::default()
                    });
                }
                if let Some(r) = rows[k].as_mut() {
                    r.pupil = Some(p.diameter_raw);
                    r.pupil_conf = Some(p.confidence);
                }
            }
            Sample::Gaze(g) => {
                let k = match g.eyes {
                    GazeEyes::Right => 0,
                    GazeEyes::Left => 1,
                    GazeEyes::Binocular => 2,
                };
                first_t = first_t.min(g.t_secs);
                let fits = rows[k].is_some_and(|r| r.t == g.t_secs && r.gaze_conf.is_none());
                if !fits {
                    if let Some(r) = rows[k].take() {
                        flush(tx, &mut outs, k, r)?;
                    }
                    rows[k] = Some(Row {
                        t: g.t_secs,
                        ..Row::default()
                    });
                }
                if let Some(r) = rows[k].as_mut() {
                    r.x = g.gaze_uv[0];
                    r.y = g.gaze_uv[1];
                    r.gaze_conf = Some(g.confidence);
                }
            }
            Sample::Blink(b) => {
                // A blink of both eyes goes with the first eye file there
                // is (a left-eye-only recording has no right file).
                let k = match b.eye {
                    Some(0) => 0,
                    Some(1) => 1,
                    None => (0..3).find(|&k| outs[k].is_some()).unwrap_or(0),
                    Some(_) => continue,
                };
                if events[k].is_none() {
                    let p = dir.join(format!(
                        "{prefix}_recording-{}_physioevents.tsv.gz",
                        EYE_FILES[k].0
                    ));
                    events[k] = Some(TsvOut::create(tx, &p)?);
                }
                if let Some(e) = events[k].as_mut() {
                    write_messages(e, msgs, &mut next_msg[k], b.start_t_secs)?;
                    let mut cells = vec![
                        format!("{}", b.end_t_secs - b.start_t_secs),
                        "blink".into(),
                        if b.eye.is_none() {
                            "both"
                        } else {
                            EYE_FILES[k].1
                        }
                        .into(),
                    ];
                    if !msgs.is_empty() {
                        cells.push("n/a".into());
                    }
                    e.line(b.start_t_secs, &cells)?;
                }
                report.blinks += 1;
            }
        }
    }
    for (k, row) in rows.iter_mut().enumerate() {
        if let Some(r) = row.take() {
            flush(tx, &mut outs, k, r)?;
        }
    }
    // Every eye file's events: the messages after its last blink (or all).
    if !msgs.is_empty() {
        for k in 0..3 {
            if outs[k].is_none() {
                continue;
            }
            if events[k].is_none() {
                let p = dir.join(format!(
                    "{prefix}_recording-{}_physioevents.tsv.gz",
                    EYE_FILES[k].0
                ));
                events[k] = Some(TsvOut::create(tx, &p)?);
            }
            if let Some(e) = events[k].as_mut() {
                write_messages(e, msgs, &mut next_msg[k], f64::INFINITY)?;
            }
        }
        report.messages = msgs.len() as u64;
    }
    if let Some(ev) = recording_events.filter(|e| !e.trials.is_empty() && first_t.is_finite()) {
        write_trials(tx, &dir.join(format!("{prefix}_events.tsv")), ev, first_t)?;
        report.trials = ev.trials.len() as u64;
    }
    // A blink file needs its eye's physio file beside it.
    for (k, ev) in events.iter().enumerate() {
        if ev.is_some() && outs[k].is_none() {
            return Err(ExportError::Invalid(format!(
                "blinks of the {} eye but no samples of it",
                EYE_FILES[k].1
            )));
        }
    }
    let meta = RecordingMeta::of(importer, recording);
    for (k, out) in outs.into_iter().enumerate() {
        let Some(out) = out else { continue };
        let path = out.path.clone();
        let (n, rows_rate) = out.finish()?;
        let rate = meta.nominal_rate_hz.unwrap_or(rows_rate);
        let (label, eye) = EYE_FILES[k];
        let (pupil_units, pupil_desc) = unit_name(units[k].unwrap_or(PupilUnit::Mm));
        let mut sidecar = json!({
            "TaskName": names.task,
            "PhysioType": "eyetrack",
            "RecordedEye": eye,
            "SamplingFrequency": rate,
            "StartTime": 0.0,
            "Columns": COLUMNS,
            "SampleCoordinateSystem": "custom",
            "SampleCoordinateSystemDescription": "gazelight's gaze: normalised to the scene (or display) image the eye looked at, x 0 = left edge, 1 = right edge, y 0 = top edge, 1 = bottom edge",
            "SoftwareVersions": format!("gazelight {}", env!("CARGO_PKG_VERSION")),
            "RecordingSource": format!("{} ({})", meta.source, meta.format),
            "timestamp": {"LongName": "Time stamp", "Description": "Time of the sample on the recording's own clock (the tracker's, as the recording holds it).", "Units": "s"},
            "x_coordinate": {"LongName": "Gaze position (x)", "Description": format!("Gaze x of the {eye} eye{}, normalised to the image width (0 left, 1 right).", if k == 2 { "s together" } else { "" }), "Units": "arbitrary"},
            "y_coordinate": {"LongName": "Gaze position (y)", "Description": "Gaze y, normalised to the image height (0 top, 1 bottom).", "Units": "arbitrary"},
            "pupil_size": {"Description": pupil_desc, "Units": pupil_units},
            "pupil_confidence": {"Description": "The tracker's confidence in the pupil value, 0..1; n/a where the row holds no pupil sample (a lost pupil has pupil_size n/a and confidence 0).", "Units": "arbitrary"},
            "gaze_confidence": {"Description": "The tracker's confidence in the gaze, 0..1; n/a where the row holds no gaze sample.", "Units": "arbitrary"},
        });
        add_device(&mut sidecar, &meta.device);
        let json_path = dir.join(format!("{prefix}_recording-{label}_physio.json"));
        tx.write_json(&json_path, &sidecar)?;
        report.files.push((path, n, rate));
    }
    for (k, ev) in events.into_iter().enumerate() {
        let Some(ev) = ev else { continue };
        ev.finish()?;
        let mut sidecar = json!({
            "Columns": ["onset", "duration", "trial_type", "eyes"],
            "OnsetSource": "timestamp",
            "Description": "Blinks the eye tracker reported.",
            "onset": {"Description": "Blink start on the clock of the physio file's timestamp column.", "Units": "s"},
            "duration": {"Description": "Blink duration.", "Units": "s"},
            "trial_type": {"Description": "Event kind.", "Levels": {"blink": "a blink the tracker reported"}},
            "eyes": {"Description": "Which eyes the event covers.", "Levels": {"right": "right eye", "left": "left eye", "both": "both eyes"}},
        });
        if !msgs.is_empty() {
            sidecar["Columns"] = json!(["onset", "duration", "trial_type", "eyes", "message"]);
            sidecar["Description"] = json!(
                "Blinks the eye tracker reported and the recording's messages (EyeLink MSG lines, XDF markers, Pupil annotations, Neon events)."
            );
            sidecar["onset"] = json!({"Description": "Event time on the clock of the physio file's timestamp column.", "Units": "s"});
            sidecar["duration"] = json!({"Description": "Blink duration; a message's duration where the recording gives one.", "Units": "s"});
            sidecar["trial_type"] = json!({"Description": "Event kind.", "Levels": {"blink": "a blink the tracker reported", "message": "a message the recording holds (its text in the message column)"}});
            sidecar["message"] = json!({"Description": "The message's text as the recording holds it (an EyeLink message after its time offset); tabs and line breaks as spaces."});
        }
        let p = dir.join(format!(
            "{prefix}_recording-{}_physioevents.json",
            EYE_FILES[k].0
        ));
        tx.write_json(&p, &sidecar)?;
    }
    if report.files.is_empty() {
        return Err(ExportError::Invalid(
            "the recording has no samples to write".into(),
        ));
    }
    Ok(report)
}

/// The task events `path` (`*_events.tsv` + `.json`): one row per trial
/// of `ev`, onset in seconds from the first sample (`t0`, the physio
/// files' `StartTime` 0), duration to its end (`n/a` where it has none),
/// `trial_type` `trial`, its id and result, one column per `TRIAL_VAR`
/// name (`n/a` where a trial lacks it).
fn write_trials(
    tx: &mut Transaction,
    path: &Path,
    ev: &crate::events::RecordingEvents,
    t0: f64,
) -> Result<(), ExportError> {
    let mut vars: Vec<&str> = Vec::new();
    for t in &ev.trials {
        for (n, _) in &t.vars {
            if !vars.contains(&n.as_str()) {
                vars.push(n);
            }
        }
    }
    // A variable's column name: letters, digits and `_` (BIDS columns).
    let column = |n: &str| -> String {
        let c: String = n
            .chars()
            .map(|c| if c.is_ascii_alphanumeric() { c } else { '_' })
            .collect();
        format!("var_{c}")
    };
    let mut text = String::from("onset\tduration\ttrial_type\ttrial\tresult");
    for n in &vars {
        text.push('\t');
        text.push_str(&column(n));
    }
    text.push('\n');
    for t in &ev.trials {
        let cell = |s: Option<&str>| s.map_or("n/a".to_owned(), tsv_text);
        text.push_str(&format!(
            "{:.6}\t{}\ttrial\t{}\t{}",
            t.start_t_secs - t0,
            t.end_t_secs
                .map_or("n/a".into(), |e| format!("{:.6}", e - t.start_t_secs)),
            cell(Some(&t.id)),
            cell(t.result.as_deref()),
        ));
        for n in &vars {
            text.push('\t');
            text.push_str(&cell(
                t.vars.iter().find(|(k, _)| k == n).map(|(_, v)| v.as_str()),
            ));
        }
        text.push('\n');
    }
    tx.write(path, &text)?;
    let mut sidecar = json!({
        "TaskName": tx.names().task,
        "onset": {"Description": "The trial's start (its TRIALID message), seconds from the first sample of the recording's physio files (their StartTime 0).", "Units": "s"},
        "duration": {"Description": "To the trial's TRIAL_RESULT (or the next TRIALID).", "Units": "s"},
        "trial_type": {"Description": "Event kind.", "Levels": {"trial": "a trial of the recording (EyeLink TRIALID .. TRIAL_RESULT)"}},
        "trial": {"Description": "The trial's id: its TRIALID message's text."},
        "result": {"Description": "Its TRIAL_RESULT message's text."},
    });
    for n in &vars {
        sidecar[column(n)] =
            json!({"Description": format!("The trial's `!V TRIAL_VAR {n}` value.")});
    }
    tx.write_json(&path.with_extension("json"), &sidecar)
}

/// The recording's `Manufacturer` and `ManufacturersModelName`, where it
/// says them, into a sidecar.
fn add_device(sidecar: &mut Value, device: &crate::Device) {
    if let Some(obj) = sidecar.as_object_mut() {
        if let Some(m) = &device.manufacturer {
            obj.insert("Manufacturer".into(), json!(m));
        }
        if let Some(m) = &device.model {
            obj.insert("ManufacturersModelName".into(), json!(m));
        }
    }
}

/// The dataset's top-level files, staged to be written where missing;
/// the participant is added to `participants.tsv` (written last).
fn write_dataset_files(tx: &mut Transaction) -> Result<(), ExportError> {
    let root = tx.root().to_owned();
    let desc = root.join("dataset_description.json");
    if !desc.exists() {
        tx.write_json(
            &desc,
            &json!({
                "Name": "gazelight eye-tracking export",
                "BIDSVersion": BIDS_VERSION,
                "DatasetType": "raw",
                "Authors": ["gazelight"],
                "GeneratedBy": [{"Name": "gazelight", "Version": env!("CARGO_PKG_VERSION"), "Description": "gazelight export --bids"}],
            }),
        )?;
    }
    tx.write_if_missing(
        &root.join("README"),
        "Eye-tracking recordings written by `gazelight export --bids` (BIDS eye-tracking, \
         PhysioType eyetrack). derivatives/gazelight/ holds gazelight's filtered pupil \
         and blinks.\n",
    )?;
    let pj = root.join("participants.json");
    if !pj.exists() {
        tx.write_json(
            &pj,
            &json!({"participant_id": {"Description": "Participant label, as given to gazelight export."}}),
        )?;
    }
    tx.add_participant()
}

/// What [`export_derivative`] wrote.
#[derive(Clone, Debug, Default, serde::Serialize)]
pub struct DerivativeExport {
    pub files: Vec<PathBuf>,
    /// Blinks and dropouts the filter chain closed.
    pub closures: u64,
}

/// Writes gazelight's derivatives of a recording under
/// `root/derivatives/gazelight/`: per eye the filtered, calibrated pupil
/// (mm) and gaze after every pupil sample of that eye
/// (`*_recording-eyeNfiltered_physio.tsv.gz`), the blinks and dropouts
/// the filter chain found in that eye beside it
/// (`…_recording-eyeNfiltered_physioevents.tsv.gz`: a left-eye-only
/// recording has eye2 files only),
/// and, from a replay's `timeline.csv` when given, the per-frame pupil,
/// light-driven pupil, residual and luminances
/// (`…_recording-eyeNreplay_physio.tsv.gz`). BIDS 1.11 has no derivative
/// rule for physio files (a `desc-` entity is refused by the validator),
/// so the derivative kind is in the `recording-` label.
pub fn export_derivative(
    importer: &mut dyn Importer,
    chain: &mut FilterChain,
    tx: &mut Transaction,
    timeline: Option<&Path>,
) -> Result<DerivativeExport, ExportError> {
    let names = tx.names().clone();
    let droot = tx.root().join("derivatives").join("gazelight");
    let dir = droot.join(names.dir());
    let desc = droot.join("dataset_description.json");
    tx.write_json(
        &desc,
        &json!({
            "Name": "gazelight derivatives",
            "BIDSVersion": BIDS_VERSION,
            "DatasetType": "derivative",
            "GeneratedBy": [{
                "Name": "gazelight",
                "Version": env!("CARGO_PKG_VERSION"),
                "Description": "The filter chain over the raw recording: the measured pupil cleaned as the guidelines do (50 ms margins around blinks, dilation-speed outliers; clean samples unchanged), the model aperture (001 section 5), blinks and dropouts, 1€-smoothed gaze; from a replay, the pupil light response and the luminance at gaze."
            }],
            "SourceDatasets": [{"URL": "../../"}],
        }),
    )?;
    tx.write_if_missing(
        &droot.join("README"),
        "gazelight's derivatives of the raw eye-tracking recordings two folders up: the \
         filtered pupil and gaze (recording-eyeNfiltered), the filter chain's blinks and \
         dropouts, and a replay's per-frame values (recording-eyeNreplay).\n",
    )?;
    let prefix = names.prefix();
    let mut report = DerivativeExport::default();
    let mut outs: [Option<TsvOut>; 2] = [None, None];
    // Each eye's closures beside that eye's filtered file.
    let mut events: [Option<TsvOut>; 2] = [None, None];
    let closure_row = |tx: &mut Transaction,
                       events: &mut [Option<TsvOut>; 2],
                       c: gazelight_eye::filter::blink::Closure|
     -> Result<(), ExportError> {
        let k = usize::from(c.eye != 0);
        let events = &mut events[k];
        if events.is_none() {
            let p = dir.join(format!(
                "{prefix}_recording-{}filtered_physioevents.tsv.gz",
                EYE_FILES[k].0
            ));
            *events = Some(TsvOut::create(tx, &p)?);
        }
        if let Some(e) = events.as_mut() {
            let kind = match c.kind {
                gazelight_eye::filter::blink::ClosureKind::Blink => "blink",
                gazelight_eye::filter::blink::ClosureKind::Dropout => "dropout",
            };
            let eye = if c.eye == 0 { "right" } else { "left" };
            e.line(
                c.start_t_secs,
                &[
                    format!("{}", c.end_t_secs - c.start_t_secs),
                    kind.into(),
                    eye.into(),
                ],
            )?;
        }
        Ok(())
    };
    // Per eye: the gaze and blink state at each pupil sample, kept until the
    // chain decides the sample (a margin later): one row per sample.
    let mut at_sample: [std::collections::VecDeque<(u64, f32, f32, bool)>; 2] =
        [Default::default(), Default::default()];
    let mut seq = 0u64;
    let mut units: [Option<gazelight_eye::sample::PupilUnit>; 2] = [None, None];
    chain.keep_decided();
    let write_decided = |tx: &mut Transaction,
                         chain: &mut FilterChain,
                         outs: &mut [Option<TsvOut>; 2],
                         at_sample: &mut [std::collections::VecDeque<(u64, f32, f32, bool)>; 2],
                         units: &mut [Option<gazelight_eye::sample::PupilUnit>; 2]|
     -> Result<(), ExportError> {
        let aperture = [
            chain.state().eyes[0].pupil_mm,
            chain.state().eyes[1].pupil_mm,
        ];
        for d in chain.take_decided() {
            let e = usize::from(d.eye & 1);
            let mut gaze = None;
            while let Some(&(s, gx, gy, blink)) = at_sample[e].front() {
                if s > d.seq {
                    break;
                }
                at_sample[e].pop_front();
                if s == d.seq {
                    gaze = Some((gx, gy, blink));
                }
            }
            let Some((gx, gy, blink)) = gaze else {
                continue;
            };
            if outs[e].is_none() {
                let p = dir.join(format!(
                    "{prefix}_recording-{}filtered_physio.tsv.gz",
                    EYE_FILES[e].0
                ));
                outs[e] = Some(TsvOut::create(tx, &p)?);
            }
            let clean = d.fate.is_clean();
            if clean {
                units[e].get_or_insert(d.unit);
            }
            let fate = match d.fate {
                gazelight_eye::filter::SampleFate::Clean => "clean",
                gazelight_eye::filter::SampleFate::Lost => "lost",
                gazelight_eye::filter::SampleFate::OutOfRange => "out_of_range",
                gazelight_eye::filter::SampleFate::Margin => "margin",
                gazelight_eye::filter::SampleFate::Speed => "speed",
                gazelight_eye::filter::SampleFate::OtherStream => "other_stream",
            };
            if let Some(o) = outs[e].as_mut() {
                o.line(
                    d.t_secs,
                    &[
                        num(Some(gx)),
                        num(Some(gy)),
                        num(clean.then_some(d.value)),
                        fate.into(),
                        num(Some(aperture[e])),
                        format!("{}", u8::from(blink)),
                    ],
                )?;
            }
        }
        Ok(())
    };
    let mut last_t = f64::NAN;
    for item in &mut *importer {
        let s = item?;
        let up = chain.push(&s);
        last_t = s
            .t_secs()
            .max(if last_t.is_nan() { s.t_secs() } else { last_t });
        if let Some(c) = up.closure {
            report.closures += 1;
            closure_row(tx, &mut events, c)?;
        }
        if let Some(e) = up.pupil_eye.map(usize::from).filter(|e| *e < 2)
            && s.t_secs().is_finite()
        {
            let st = &up.state;
            let [gx, gy] = st.eye_gaze_uv(e);
            at_sample[e].push_back((seq, gx, gy, st.blink));
            seq += 1;
        }
        write_decided(tx, chain, &mut outs, &mut at_sample, &mut units)?;
    }
    if last_t.is_finite() {
        for c in chain.finish(last_t).into_iter().flatten() {
            report.closures += 1;
            closure_row(tx, &mut events, c)?;
        }
    }
    write_decided(tx, chain, &mut outs, &mut at_sample, &mut units)?;
    let nominal = importer.nominal_rate_hz();
    for (k, out) in outs.into_iter().enumerate() {
        let Some(out) = out else { continue };
        let path = out.path.clone();
        let (_, rows_rate) = out.finish()?;
        let rate = nominal.unwrap_or(rows_rate);
        let (label, eye) = EYE_FILES[k];
        tx.write_json(
            &dir.join(format!("{prefix}_recording-{label}filtered_physio.json")),
            &json!({
                "Description": "gazelight's filtered, calibrated eye state after each pupil sample of this eye.",
                "PhysioType": "eyetrack",
                "RecordedEye": eye,
                "SamplingFrequency": rate,
                "StartTime": 0.0,
                "SampleCoordinateSystem": "custom",
                "Columns": ["timestamp", "x_coordinate", "y_coordinate", "pupil_size", "pupil_fate", "aperture_mm", "blink"],
                "timestamp": {"Description": "Time of the raw pupil sample, the recording's clock.", "Units": "s"},
                "x_coordinate": {"Description": "Filtered gaze x of this eye (its own gaze where the tracker gives one, else the fused gaze), normalised (0 left, 1 right).", "Units": "arbitrary"},
                "y_coordinate": {"Description": "Filtered gaze y, normalised (0 top, 1 bottom).", "Units": "arbitrary"},
                "pupil_size": {"Description": if units[k] == Some(gazelight_eye::sample::PupilUnit::Mm) { "The measured pupil diameter: the sample's own value where it is clean (the guideline cleaning: 50 ms margins around blinks, dilation-speed outliers; Mathot et al. 2018, Kret & Sjak-Shie 2019), n/a where it is not." } else { "The measured pupil in the tracker's raw unit (no physical scale): the sample's own value where it is clean, n/a where it is not." }, "Units": if units[k] == Some(gazelight_eye::sample::PupilUnit::Mm) { "mm" } else { "arbitrary" }},
                "pupil_fate": {"Description": "What the cleaning made of the sample.", "Levels": {"clean": "a clean measurement, unchanged", "lost": "no pupil (low confidence, 0 or NaN)", "out_of_range": "a diameter outside 1.5-9 mm", "margin": "within 50 ms of a blink or lost stretch", "speed": "a dilation-speed outlier", "other_stream": "another stream of this eye than the one measured"}},
                "aperture_mm": {"Description": "The model aperture the glare kernel is built for (001 section 5's black/white map or the measured mm, held through blinks): not a measurement.", "Units": "mm"},
                "blink": {"Description": "Whether the eye is closed (a blink).", "Levels": {"0": "open", "1": "closed"}},
            }),
        )?;
        report.files.push(path);
    }
    for (k, ev) in events.into_iter().enumerate() {
        let Some(ev) = ev else { continue };
        let label = EYE_FILES[k].0;
        let path = ev.path.clone();
        ev.finish()?;
        if !report.files.iter().any(|f| {
            f.file_name()
                .and_then(|n| n.to_str())
                .is_some_and(|n| n.ends_with(&format!("_recording-{label}filtered_physio.tsv.gz")))
        }) {
            // Closures of an eye without filtered samples (cannot happen
            // with the chain's closures, which come from that eye's
            // samples): no events file without its physio file.
            tx.discard(&path);
            continue;
        }
        report.files.push(path);
        tx.write_json(
            &dir.join(format!(
                "{prefix}_recording-{label}filtered_physioevents.json"
            )),
            &json!({
                "Columns": ["onset", "duration", "trial_type", "eyes"],
                "OnsetSource": "timestamp",
                "Description": "Closures the filter chain found in this eye (the eyes column names it).",
                "onset": {"Units": "s"}, "duration": {"Units": "s"},
                "trial_type": {"Levels": {"blink": "a blink (a short closure)", "dropout": "the pupil lost for longer than a blink"}},
                "eyes": {"Levels": {"right": "right eye", "left": "left eye"}},
            }),
        )?;
    }
    if let Some(tl) = timeline {
        report
            .files
            .extend(timeline_derivative(tx, tl, &dir, &prefix)?);
    }
    Ok(report)
}

/// The per-frame values of a replay's `timeline.csv` as derivative
/// physio files, one per view (`""` mono → eye3, `_right` → eye1,
/// `_left` → eye2).
fn timeline_derivative(
    tx: &mut Transaction,
    timeline: &Path,
    dir: &Path,
    prefix: &str,
) -> Result<Vec<PathBuf>, ExportError> {
    let f = gazelight_input::open(timeline).map_err(wio(timeline))?;
    let mut r = BufReader::new(f);
    let mut line = String::new();
    let bad = |what: String| ExportError::Invalid(format!("{}: {what}", timeline.display()));
    r.read_line(&mut line).map_err(wio(timeline))?;
    let header: Vec<String> = line.trim_end().split(',').map(str::to_owned).collect();
    let t_col = header
        .iter()
        .position(|h| h == "t_secs")
        .ok_or_else(|| bad("no t_secs column: not a gazelight timeline".into()))?;
    // Per view: the columns wanted, by name.
    const WANT: [(&str, &str, &str, &str); 7] = [
        (
            "gaze_u",
            "x_coordinate",
            "Gaze x the frame was rendered for, normalised (0 left, 1 right).",
            "arbitrary",
        ),
        (
            "gaze_v",
            "y_coordinate",
            "Gaze y the frame was rendered for, normalised (0 top, 1 bottom).",
            "arbitrary",
        ),
        (
            "pupil_mm",
            "pupil_size",
            "Filtered pupil diameter the frame used.",
            "mm",
        ),
        (
            "target_cd_m2",
            "luminance_at_gaze",
            "Gaze-weighted luminance the eye saw (the adaptation target).",
            "cd/m^2",
        ),
        (
            "adaptation_cd_m2",
            "adaptation_luminance",
            "Adaptation luminance after temporal adaptation.",
            "cd/m^2",
        ),
        (
            "pupil_light_mm",
            "pupil_light",
            "Pupil diameter the light predicts (the pupil light response).",
            "mm",
        ),
        (
            "pupil_residual_mm",
            "pupil_residual",
            "Measured minus light-driven pupil; n/a where not measured.",
            "mm",
        ),
    ];
    let mut views: BTreeMap<String, Vec<Option<usize>>> = BTreeMap::new();
    for suffix in ["", "_right", "_left"] {
        let cols: Vec<Option<usize>> = WANT
            .iter()
            .map(|(c, ..)| header.iter().position(|h| *h == format!("{c}{suffix}")))
            .collect();
        if cols[2].is_some() {
            views.insert(suffix.to_owned(), cols);
        }
    }
    if views.is_empty() {
        return Err(bad("no pupil_mm column".into()));
    }
    let mut outs: Vec<(String, Vec<Option<usize>>, TsvOut)> = Vec::new();
    for (suffix, cols) in views {
        let label = match suffix.as_str() {
            "_right" => "eye1",
            "_left" => "eye2",
            _ => "eye3",
        };
        let p = dir.join(format!("{prefix}_recording-{label}replay_physio.tsv.gz"));
        outs.push((label.to_owned(), cols, TsvOut::create(tx, &p)?));
    }
    let mut line_no = 1u64;
    loop {
        let read = gazelight_input::read_line(&mut r, &mut line, gazelight_input::MAX_LINE_BYTES)
            .map_err(wio(timeline))?;
        line_no += 1;
        match read {
            gazelight_input::Line::Eof => break,
            gazelight_input::Line::Read => {}
            _ => return Err(bad(format!("line {line_no} is not a timeline row"))),
        }
        let f: Vec<&str> = line.trim_end().split(',').collect();
        let Some(t) = f.get(t_col).and_then(|v| v.parse::<f64>().ok()) else {
            return Err(bad(format!("line {line_no}: no time")));
        };
        for (_, cols, out) in &mut outs {
            let cells: Vec<String> = cols
                .iter()
                .map(|c| {
                    c.and_then(|i| f.get(i))
                        .and_then(|v| v.parse::<f32>().ok())
                        .map_or_else(|| "n/a".to_owned(), |v| num(Some(v)))
                })
                .collect();
            out.line(t, &cells)?;
        }
    }
    let mut files = Vec::new();
    for (label, _, out) in outs {
        let path = out.path.clone();
        let (_, rate) = out.finish()?;
        let mut sidecar = json!({
            "Description": "Per frame of a gazelight replay (timeline.csv): the gaze and pupil it rendered for, the luminance at gaze, and the pupil light response.",
            "PhysioType": "eyetrack",
            "RecordedEye": match label.as_str() { "eye1" => "right", "eye2" => "left", _ => "cyclopean" },
            "SamplingFrequency": rate,
            "StartTime": 0.0,
            "SampleCoordinateSystem": "custom",
            "Columns": std::iter::once("timestamp").chain(WANT.iter().map(|w| w.1)).collect::<Vec<_>>(),
            "timestamp": {"Description": "Frame time on the recording's clock.", "Units": "s"},
        });
        if let Some(obj) = sidecar.as_object_mut() {
            for (_, name, d, u) in WANT {
                obj.insert(name.into(), json!({"Description": d, "Units": u}));
            }
        }
        tx.write_json(
            &dir.join(format!("{prefix}_recording-{label}replay_physio.json")),
            &sidecar,
        )?;
        files.push(path);
    }
    Ok(files)
}
