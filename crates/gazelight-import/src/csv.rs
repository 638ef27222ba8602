//! Eye-tracking CSV and TSV files: gazelight's own trace
//! (`t_secs,gaze_u,gaze_v,pupil_mm[,confidence]`, what `render --trace`
//! reads), per-eye pupil traces such as the piprkit pupil-light-reflex
//! recordings (`time,left,right`), and exports with gaze, per-eye pupils
//! and confidences.
//!
//! ```text
//! t_secs,gaze_u,gaze_v,pupil_left_mm,pupil_right_mm,confidence
//! 0.000,0.50,0.80,5.1,5.0,0.98
//! 0.005,0.50,0.80,,,0.0
//! ```
//!
//! The first line that is neither blank nor a `#` comment is the header;
//! the separator is the header's: a comma, a tab (`.tsv`) or a semicolon.
//! Column names are matched case-insensitively after every run of
//! characters other than letters and digits became one `_` (so
//! `Pupil Left [mm]` is `pupil_left_mm`). The mapping ([`COLUMN_MAPPING`],
//! also in `docs/replay.md`):
//!
//! | role | names |
//! | --- | --- |
//! | time, s (required) | `t_secs`, `time`, `t`, `timestamp`, `time_s`, `timestamp_s`; in ms: `time_ms`, `timestamp_ms`, `t_ms`; in ns: `time_ns`, `timestamp_ns` |
//! | right pupil (eye 0) | `right`, `pupil_right`, `right_pupil`, `diameter_right`, `pupil_diameter_right` + unit |
//! | left pupil (eye 1) | `left`, `pupil_left`, `left_pupil`, `diameter_left`, `pupil_diameter_left` + unit |
//! | one pupil for both eyes | `pupil`, `diameter`, `pupil_diameter` + unit |
//! | gaze (both eyes), normalised, origin top-left | `gaze_u` + `gaze_v`, or `gaze_x` + `gaze_y` |
//! | one eye's gaze | `gaze_u_right` + `gaze_v_right`, `gaze_u_left` + `gaze_v_left` (or `_x`/`_y`) |
//! | confidence 0..1 of the row | `confidence` |
//! | one eye's confidence | `confidence_right`, `confidence_left` |
//!
//! A pupil's unit is its name's suffix: `_mm` (or none) millimetres, `_px`
//! eye-camera pixels, `_area` arbitrary area units, `_au` arbitrary
//! diameter units. Other columns are ignored and named in the import's
//! notes; a role named twice, or a one-pupil column beside per-eye ones,
//! is a structure error naming both columns.
//!
//! **Every row is counted.** Each row becomes one [`PupilSample`] per eye
//! with a pupil column (a one-pupil column gives both eyes, as
//! `render --trace` does) and one [`GazeSample`] per gaze pair. An empty
//! field, `nan`, `n/a` or a pupil ≤ 0 is a *lost* sample — kept, with
//! confidence 0 (`diameter_raw` 0, gaze NaN) — so blinks and dropouts are
//! seen downstream, never dropped. A valid sample's confidence is the
//! eye's confidence column, else the row's, else 1. A row whose time is
//! missing, or with a field that is not a number, is skipped with a
//! counted warning naming file, line and column; a missing or unusable
//! header is a structure error.
//!
//! [`load_stimuli`] reads the companion `stimuli.csv` (flash start, end,
//! relative intensity).

use std::fs::File;
use std::io::{BufRead, BufReader};
use std::path::{Path, PathBuf};

use super::lines::{LineRead, open_text, read_text_line};
use super::{ImportError, ImportWarnings, Importer, Pending, Position};
use gazelight_eye::sample::{DetectorMethod, GazeEyes, GazeSample, PupilSample, PupilUnit, Sample};

/// The column mapping, as (role, accepted names), for error messages and
/// the docs; the module documentation has the units.
pub const COLUMN_MAPPING: [(&str, &str); 8] = [
    (
        "time (s)",
        "t_secs|time|t|timestamp|time_s|timestamp_s (ms: time_ms|timestamp_ms|t_ms; ns: time_ns|timestamp_ns)",
    ),
    (
        "right pupil",
        "right|pupil_right|right_pupil|diameter_right|pupil_diameter_right[_mm|_px|_area|_au]",
    ),
    (
        "left pupil",
        "left|pupil_left|left_pupil|diameter_left|pupil_diameter_left[_mm|_px|_area|_au]",
    ),
    (
        "one pupil for both eyes",
        "pupil|diameter|pupil_diameter[_mm|_px|_area|_au]",
    ),
    (
        "gaze",
        "gaze_u + gaze_v | gaze_x + gaze_y (normalised, origin top-left)",
    ),
    (
        "one eye's gaze",
        "gaze_u_right + gaze_v_right, gaze_u_left + gaze_v_left",
    ),
    ("confidence", "confidence"),
    ("one eye's confidence", "confidence_right|confidence_left"),
];

const TIME_S: [&str; 6] = ["t_secs", "time", "t", "timestamp", "time_s", "timestamp_s"];
const TIME_MS: [&str; 3] = ["time_ms", "timestamp_ms", "t_ms"];
const TIME_NS: [&str; 2] = ["time_ns", "timestamp_ns"];
const PUPIL_RIGHT: [&str; 5] = [
    "right",
    "pupil_right",
    "right_pupil",
    "diameter_right",
    "pupil_diameter_right",
];
const PUPIL_LEFT: [&str; 5] = [
    "left",
    "pupil_left",
    "left_pupil",
    "diameter_left",
    "pupil_diameter_left",
];
const PUPIL_BOTH: [&str; 3] = ["pupil", "diameter", "pupil_diameter"];

/// A column name as matched: lower case, every run of other characters
/// than ASCII letters and digits one `_`, none at the ends.
pub fn normalise_name(name: &str) -> String {
    let mut out = String::with_capacity(name.len());
    for c in name.trim().trim_start_matches('\u{feff}').chars() {
        if c.is_ascii_alphanumeric() {
            out.push(c.to_ascii_lowercase());
        } else if !out.is_empty() && !out.ends_with('_') {
            out.push('_');
        }
    }
    while out.ends_with('_') {
        out.pop();
    }
    out
}

/// A pupil column name without its unit suffix, and the unit.
fn pupil_unit_of(name: &str) -> (&str, PupilUnit) {
    for (suffix, unit) in [
        ("_mm", PupilUnit::Mm),
        ("_px", PupilUnit::Px),
        ("_area", PupilUnit::ArbitraryArea),
        ("_au", PupilUnit::Arbitrary),
    ] {
        if let Some(base) = name.strip_suffix(suffix) {
            return (base, unit);
        }
    }
    (name, PupilUnit::Mm)
}

/// Which columns hold what (indices into a row's fields).
#[derive(Clone, Debug, PartialEq)]
pub struct CsvColumns {
    /// The field separator: `,`, `\t` or `;`.
    pub separator: char,
    /// The time column and its scale to seconds.
    pub time: (usize, f64),
    /// `[right, left]`: each eye's pupil column and unit.
    pub pupil: [Option<(usize, PupilUnit)>; 2],
    /// One pupil column for both eyes.
    pub pupil_both: Option<(usize, PupilUnit)>,
    /// The gaze of both eyes: u, v.
    pub gaze: Option<[usize; 2]>,
    /// `[right, left]`: each eye's own gaze.
    pub eye_gaze: [Option<[usize; 2]>; 2],
    /// The row's confidence.
    pub confidence: Option<usize>,
    /// `[right, left]`: each eye's confidence.
    pub eye_confidence: [Option<usize>; 2],
    /// Header names no role claimed.
    pub ignored: Vec<String>,
}

impl CsvColumns {
    /// Maps a header line; `Err` says why it cannot be used.
    pub(crate) fn from_header(line: &str) -> Result<Self, String> {
        let separator = if line.contains('\t') {
            '\t'
        } else if line.contains(';') && !line.contains(',') {
            ';'
        } else {
            ','
        };
        let raw: Vec<&str> = line
            .split(separator)
            .map(|c| c.trim().trim_matches('"'))
            .collect();
        let names: Vec<String> = raw.iter().map(|n| normalise_name(n)).collect();
        // Each role's column; a second claim is an error naming both.
        let mut claims: Vec<(&'static str, usize)> = Vec::new();
        let mut claim = |role: &'static str, i: usize| -> Result<usize, String> {
            if let Some((_, j)) = claims.iter().find(|(r, _)| *r == role) {
                return Err(format!(
                    "columns {} (`{}`) and {} (`{}`) are both the {role}",
                    j + 1,
                    raw[*j],
                    i + 1,
                    raw[i]
                ));
            }
            claims.push((role, i));
            Ok(i)
        };
        let mut c = Self {
            separator,
            time: (usize::MAX, 1.0),
            pupil: [None; 2],
            pupil_both: None,
            gaze: None,
            eye_gaze: [None; 2],
            confidence: None,
            eye_confidence: [None; 2],
            ignored: Vec::new(),
        };
        let mut gaze_uv: [[Option<usize>; 2]; 3] = [[None; 2]; 3];
        for (i, n) in names.iter().enumerate() {
            let n = n.as_str();
            let (base, unit) = pupil_unit_of(n);
            if TIME_S.contains(&n) {
                c.time = (claim("time", i)?, 1.0);
            } else if TIME_MS.contains(&n) {
                c.time = (claim("time", i)?, 1e-3);
            } else if TIME_NS.contains(&n) {
                c.time = (claim("time", i)?, 1e-9);
            } else if PUPIL_RIGHT.contains(&base) {
                c.pupil[0] = Some((claim("right pupil", i)?, unit));
            } else if PUPIL_LEFT.contains(&base) {
                c.pupil[1] = Some((claim("left pupil", i)?, unit));
            } else if PUPIL_BOTH.contains(&base) {
                c.pupil_both = Some((claim("pupil of both eyes", i)?, unit));
            } else if n == "confidence" {
                c.confidence = Some(claim("confidence", i)?);
            } else if n == "confidence_right" || n == "right_confidence" {
                c.eye_confidence[0] = Some(claim("right confidence", i)?);
            } else if n == "confidence_left" || n == "left_confidence" {
                c.eye_confidence[1] = Some(claim("left confidence", i)?);
            } else if let Some((slot, axis, role)) = gaze_role(n) {
                gaze_uv[slot][axis] = Some(claim(role, i)?);
            } else if !n.is_empty() {
                c.ignored.push(raw[i].to_owned());
            }
        }
        if c.time.0 == usize::MAX {
            return Err("no time column".into());
        }
        if c.pupil_both.is_some() && c.pupil.iter().any(Option::is_some) {
            return Err(
                "a pupil column for both eyes beside per-eye pupil columns: keep one kind".into(),
            );
        }
        let pair = |p: [Option<usize>; 2], what: &str| match p {
            [Some(u), Some(v)] => Ok(Some([u, v])),
            [None, None] => Ok(None),
            _ => Err(format!("{what}: one gaze coordinate without the other")),
        };
        c.gaze = pair(gaze_uv[2], "the gaze")?;
        c.eye_gaze = [
            pair(gaze_uv[0], "the right eye's gaze")?,
            pair(gaze_uv[1], "the left eye's gaze")?,
        ];
        let any_pupil = c.pupil_both.is_some() || c.pupil.iter().any(Option::is_some);
        let any_gaze = c.gaze.is_some() || c.eye_gaze.iter().any(Option::is_some);
        if !any_pupil && !any_gaze {
            return Err("no pupil and no gaze column".into());
        }
        Ok(c)
    }
}

/// A gaze column: (0 right, 1 left, 2 both; 0 u, 1 v; its role).
fn gaze_role(n: &str) -> Option<(usize, usize, &'static str)> {
    Some(match n {
        "gaze_u" | "gaze_x" => (2, 0, "gaze u"),
        "gaze_v" | "gaze_y" => (2, 1, "gaze v"),
        "gaze_u_right" | "gaze_x_right" => (0, 0, "right gaze u"),
        "gaze_v_right" | "gaze_y_right" => (0, 1, "right gaze v"),
        "gaze_u_left" | "gaze_x_left" => (1, 0, "left gaze u"),
        "gaze_v_left" | "gaze_y_left" => (1, 1, "left gaze v"),
        _ => return None,
    })
}

/// Streaming importer of an eye-tracking CSV or TSV file.
pub struct CsvPupilImporter<R: BufRead = BufReader<File>> {
    path: PathBuf,
    reader: R,
    line: String,
    line_no: u64,
    cols: Option<CsvColumns>,
    pending: Pending<6>,
    warnings: ImportWarnings,
    done: bool,
}

impl CsvPupilImporter<BufReader<File>> {
    /// Opens a CSV (or TSV) file.
    pub fn open(path: &Path) -> Result<Self, ImportError> {
        Ok(Self::from_reader(open_text(path)?, path))
    }
}

/// One field: `Ok(None)` when empty, `nan`, `n/a` or `na` (a lost value).
fn value(fields: &[&str], i: usize) -> Result<Option<f64>, String> {
    let f = fields
        .get(i)
        .copied()
        .unwrap_or("")
        .trim()
        .trim_matches('"');
    if f.is_empty()
        || f.eq_ignore_ascii_case("nan")
        || f.eq_ignore_ascii_case("n/a")
        || f.eq_ignore_ascii_case("na")
    {
        return Ok(None);
    }
    f.parse::<f64>()
        .map(Some)
        .map_err(|_| format!("column {}: `{f}` is not a number", i + 1))
}

impl<R: BufRead> CsvPupilImporter<R> {
    /// Reads CSV text from any buffered reader; `path` names it in errors.
    pub fn from_reader(reader: R, path: &Path) -> Self {
        Self {
            path: path.to_owned(),
            reader,
            line: String::with_capacity(128),
            line_no: 0,
            cols: None,
            pending: Pending::new(),
            warnings: ImportWarnings::default(),
            done: false,
        }
    }

    /// The column mapping, once the header is read.
    pub fn columns(&self) -> Option<&CsvColumns> {
        self.cols.as_ref()
    }

    fn header(&mut self, line: &str) -> Result<CsvColumns, ImportError> {
        let cols = CsvColumns::from_header(line).map_err(|why| ImportError::Structure {
            path: self.path.clone(),
            position: Position::Line(self.line_no),
            reason: format!(
                "header `{}`: {why}{}; the columns read: {}",
                line.escape_debug(),
                header_hint(line),
                COLUMN_MAPPING
                    .iter()
                    .map(|(role, names)| format!("{role}: {names}"))
                    .collect::<Vec<_>>()
                    .join("; ")
            ),
        })?;
        if !cols.ignored.is_empty() {
            self.warnings.note(
                &self.path,
                Position::Line(self.line_no),
                format!("columns not read: {}", cols.ignored.join(", ")),
            );
        }
        Ok(cols)
    }

    fn row(&mut self, line: &str, c: &CsvColumns) {
        let fields: Vec<&str> = line.split(c.separator).collect();
        let parsed = (|| -> Result<Option<Pending<6>>, String> {
            let Some(t) = value(&fields, c.time.0)?.map(|t| t * c.time.1) else {
                return Ok(None);
            };
            if !t.is_finite() {
                return Ok(None);
            }
            let mut out = Pending::new();
            let conf = |i: Option<usize>| -> Result<Option<f32>, String> {
                Ok(match i {
                    Some(i) => value(&fields, i)?
                        .filter(|v| v.is_finite())
                        .map(|v| v.clamp(0.0, 1.0) as f32),
                    None => None,
                })
            };
            let row_conf = conf(c.confidence)?;
            for eye in 0..2 {
                let Some((i, unit)) = c.pupil[eye].or(c.pupil_both) else {
                    continue;
                };
                let d = value(&fields, i)?.map(|d| d as f32);
                let valid = d.is_some_and(|d| d.is_finite() && d > 0.0);
                let confidence = conf(c.eye_confidence[eye])?.or(row_conf).unwrap_or(1.0);
                out.push(Sample::Pupil(PupilSample {
                    t_secs: t,
                    eye: eye as u8,
                    diameter_raw: if valid { d.unwrap_or(0.0) } else { 0.0 },
                    unit,
                    diameter_mm: if valid && unit == PupilUnit::Mm {
                        d
                    } else {
                        None
                    },
                    confidence: if valid { confidence } else { 0.0 },
                    norm_pos: [f32::NAN, f32::NAN],
                    method: DetectorMethod::Other,
                }));
            }
            let gazes = [
                (c.gaze, GazeEyes::Binocular, row_conf),
                (
                    c.eye_gaze[0],
                    GazeEyes::Right,
                    conf(c.eye_confidence[0])?.or(row_conf),
                ),
                (
                    c.eye_gaze[1],
                    GazeEyes::Left,
                    conf(c.eye_confidence[1])?.or(row_conf),
                ),
            ];
            for (cols, eyes, confidence) in gazes {
                let Some([ui, vi]) = cols else { continue };
                let (u, v) = (value(&fields, ui)?, value(&fields, vi)?);
                let uv = match (u, v) {
                    (Some(u), Some(v)) if u.is_finite() && v.is_finite() => {
                        Some([u as f32, v as f32])
                    }
                    _ => None,
                };
                out.push(Sample::Gaze(GazeSample {
                    t_secs: t,
                    gaze_uv: uv.unwrap_or([f32::NAN; 2]),
                    confidence: if uv.is_some() {
                        confidence.unwrap_or(1.0)
                    } else {
                        0.0
                    },
                    eyes,
                }));
            }
            Ok(Some(out))
        })();
        match parsed {
            Ok(Some(mut out)) => {
                while let Some(s) = out.pop() {
                    self.pending.push(s);
                }
            }
            Ok(None) => self.warnings.skip(
                &self.path,
                Position::Line(self.line_no),
                format!(
                    "column {}: the time is not a finite number in `{line}`",
                    c.time.0 + 1
                ),
            ),
            Err(why) => self
                .warnings
                .skip(&self.path, Position::Line(self.line_no), why),
        }
    }
}

/// Why a header line that does not parse may look the way it does.
fn header_hint(line: &str) -> &'static str {
    if line.contains('\0') {
        " (NUL bytes between the characters: the file is UTF-16; save it as UTF-8)"
    } else if line.contains('\r') {
        " (carriage returns inside the line: CR-only line endings; use LF or CRLF)"
    } else if line
        .bytes()
        .next()
        .is_some_and(|b| b.is_ascii_digit() || b == b'-')
    {
        " (the first line holds numbers: the header line is missing)"
    } else {
        ""
    }
}

impl<R: BufRead> CsvPupilImporter<R> {
    /// Reads one line: the header, a row (its samples go to `pending`) or a
    /// skipped line. An error ends the import.
    fn read_step(&mut self) -> Result<(), ImportError> {
        let read = read_text_line(
            &mut self.reader,
            &mut self.line,
            &mut self.line_no,
            &self.path,
        )?;
        let at = Position::Line(self.line_no);
        match (read, self.cols.is_some()) {
            (LineRead::Eof, false) => Err(self.structure(Position::File, "empty file: no header")),
            (LineRead::Eof, true) => {
                self.done = true;
                Ok(())
            }
            (LineRead::TooLong(n), false) => Err(self.structure(
                at,
                format!(
                    "the header line is {n} bytes long (limit {}): not a CSV with one record \
                     per line (CR-only line endings?)",
                    gazelight_input::MAX_LINE_BYTES
                ),
            )),
            (LineRead::NotUtf8, false) => Err(self.structure(
                at,
                "the header line is not UTF-8 text (a UTF-16 file? save it as UTF-8)",
            )),
            (LineRead::TooLong(n), true) => {
                self.warnings
                    .skip_long_line(&self.path, self.line_no, n, "a record");
                Ok(())
            }
            (LineRead::NotUtf8, true) => {
                self.warnings.skip_not_utf8(&self.path, self.line_no);
                Ok(())
            }
            (LineRead::Text, _) => {
                let line = std::mem::take(&mut self.line);
                let result = self.text_line(&line);
                self.line = line;
                result
            }
        }
    }

    /// The header (the first line that is neither blank nor a `#` comment)
    /// or a row.
    fn text_line(&mut self, line: &str) -> Result<(), ImportError> {
        // Line ends and a byte-order mark only: a TSV row may start with
        // an empty field (a tab).
        let trimmed = line
            .trim_start_matches('\u{feff}')
            .trim_end_matches(['\r', '\n']);
        let blank = trimmed.trim();
        if blank.is_empty() || blank.starts_with('#') {
            return Ok(());
        }
        match self.cols.take() {
            None => self.cols = Some(self.header(trimmed)?),
            Some(c) => {
                self.row(trimmed, &c);
                self.cols = Some(c);
            }
        }
        Ok(())
    }

    fn structure(&self, position: Position, reason: impl Into<String>) -> ImportError {
        ImportError::Structure {
            path: self.path.clone(),
            position,
            reason: reason.into(),
        }
    }
}

impl<R: BufRead> crate::Stepped for CsvPupilImporter<R> {
    fn step(&mut self) -> Result<bool, ImportError> {
        // `read_step` marks the end itself.
        self.read_step().map(|()| !self.done)
    }
    fn pop_pending(&mut self) -> Option<Sample> {
        self.pending.pop()
    }
    fn done_mut(&mut self) -> &mut bool {
        &mut self.done
    }
}

impl<R: BufRead> Iterator for CsvPupilImporter<R> {
    type Item = Result<Sample, ImportError>;

    fn next(&mut self) -> Option<Self::Item> {
        crate::next_stepped(self)
    }
}

impl<R: BufRead> Importer for CsvPupilImporter<R> {
    fn warnings(&self) -> &ImportWarnings {
        &self.warnings
    }
    fn format(&self) -> &'static str {
        "csv"
    }
    fn position(&self) -> Position {
        Position::Line(self.line_no)
    }
}

/// One light flash of a stimulus file.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct Flash {
    pub start_t_secs: f64,
    pub end_t_secs: f64,
    /// Relative intensity 0..=1.
    pub intensity: f64,
}

/// Reads a `stimuli.csv` (`,start_time,end_time,intensity`; the first,
/// unnamed column is an index). Small file: read whole. Any bad row is an
/// error naming file and line.
pub fn load_stimuli(path: &Path) -> Result<Vec<Flash>, ImportError> {
    let text = gazelight_input::read_to_string(path, gazelight_input::MAX_TEXT_BYTES).map_err(
        |source| ImportError::Io {
            path: path.to_owned(),
            source,
        },
    )?;
    let mut lines = text
        .lines()
        .enumerate()
        .filter(|(_, l)| !l.trim().is_empty());
    let Some((_, header)) = lines.next() else {
        return Err(ImportError::Structure {
            path: path.to_owned(),
            position: Position::File,
            reason: "empty stimulus file".into(),
        });
    };
    let names: Vec<&str> = header.split(',').map(str::trim).collect();
    let col = |n: &str| {
        names
            .iter()
            .position(|c| *c == n)
            .ok_or_else(|| ImportError::Structure {
                path: path.to_owned(),
                position: Position::Line(1),
                reason: format!("missing column `{n}` in header `{header}`"),
            })
    };
    let (si, ei, ii) = (col("start_time")?, col("end_time")?, col("intensity")?);
    let mut out = Vec::new();
    for (i, line) in lines {
        let f: Vec<&str> = line.split(',').map(str::trim).collect();
        let num = |idx: usize, name: &str| {
            f.get(idx)
                .and_then(|v| v.parse::<f64>().ok())
                .filter(|v| v.is_finite())
                .ok_or_else(|| ImportError::Structure {
                    path: path.to_owned(),
                    position: Position::Line(i as u64 + 1),
                    reason: format!("column `{name}` is not a finite number in `{line}`"),
                })
        };
        let flash = Flash {
            start_t_secs: num(si, "start_time")?,
            end_t_secs: num(ei, "end_time")?,
            intensity: num(ii, "intensity")?,
        };
        if flash.end_t_secs < flash.start_t_secs {
            return Err(ImportError::Structure {
                path: path.to_owned(),
                position: Position::Line(i as u64 + 1),
                reason: "end_time before start_time".into(),
            });
        }
        out.push(flash);
    }
    Ok(out)
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn rows_become_two_eyes_and_bad_rows_are_counted() {
        let text = "time,left,right\n0.005,6.4,5.6\n0.010,abc,5.6\n0.015,,5.5\n";
        let mut imp = CsvPupilImporter::from_reader(text.as_bytes(), Path::new("p.csv"));
        let s: Vec<Sample> = imp.by_ref().map(|s| s.unwrap()).collect();
        assert_eq!(s.len(), 4);
        assert_eq!(imp.warnings().skipped_records, 1);
        assert!(imp.warnings().messages[0].contains("p.csv (line 3)"));
        let Sample::Pupil(r) = s[0] else { panic!() };
        assert_eq!((r.eye, r.diameter_raw), (0, 5.6));
        let Sample::Pupil(lost) = s[3] else { panic!() };
        assert_eq!(
            (lost.eye, lost.confidence, lost.diameter_mm),
            (1, 0.0, None)
        );
    }

    #[test]
    fn bad_header_is_a_structure_error() {
        let text = "a,b,c\n1,2,3\n";
        let mut imp = CsvPupilImporter::from_reader(text.as_bytes(), Path::new("p.csv"));
        let e = imp.next().unwrap().unwrap_err();
        assert!(e.to_string().contains("p.csv (line 1)"), "{e}");
        assert!(imp.next().is_none());
    }
}
