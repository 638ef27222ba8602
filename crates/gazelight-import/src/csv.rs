//! Pupil-diameter CSV traces, as the piprkit pupil-light-reflex recordings:
//!
//! ```text
//! time,left,right
//! 0.0041503906,6.4087,5.6278
//! ```
//!
//! The header names the columns: a time column (`time`, `t`, `t_secs` or
//! `timestamp`, seconds) and pupil diameters in mm (`left` and/or `right`;
//! `left_mm`/`right_mm` and `pupil_left`/`pupil_right` also accepted). Each
//! row becomes one [`PupilSample`] per eye present (left → eye 1, right →
//! eye 0), unit mm, confidence 1 for a finite positive diameter, else 0
//! (an empty field, `nan` or ≤ 0 is a lost pupil). A row that does not parse
//! is skipped with a counted warning naming file and line; a missing or
//! unusable header is a structure error.
//!
//! [`load_stimuli`] reads the companion `stimuli.csv` (flash start, end,
//! relative intensity).

use std::fs::File;
use std::io::{BufRead, BufReader};
use std::path::{Path, PathBuf};

use super::lines::{LineRead, open_text, read_text_line};
use super::{ImportError, ImportWarnings, Importer, Pending, Position};
use gazelight_eye::sample::{DetectorMethod, PupilSample, PupilUnit, Sample};

/// Streaming importer of a pupil CSV trace.
pub struct CsvPupilImporter<R: BufRead = BufReader<File>> {
    path: PathBuf,
    reader: R,
    line: String,
    line_no: u64,
    /// Column indices: time, right, left.
    cols: Option<(usize, Option<usize>, Option<usize>)>,
    pending: Pending<2>,
    warnings: ImportWarnings,
    done: bool,
}

impl CsvPupilImporter<BufReader<File>> {
    /// Opens a CSV trace.
    pub fn open(path: &Path) -> Result<Self, ImportError> {
        Ok(Self::from_reader(open_text(path)?, path))
    }
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

    fn header(&self, line: &str) -> Result<(usize, Option<usize>, Option<usize>), ImportError> {
        let names: Vec<String> = line
            .split(',')
            .map(|c| c.trim().trim_matches('"').to_ascii_lowercase())
            .collect();
        let find = |cands: &[&str]| names.iter().position(|n| cands.contains(&n.as_str()));
        let t = find(&["time", "t", "t_secs", "timestamp", "time_s"]);
        let r = find(&["right", "right_mm", "pupil_right", "pupil_right_mm"]);
        let l = find(&["left", "left_mm", "pupil_left", "pupil_left_mm"]);
        match t {
            Some(t) if r.is_some() || l.is_some() => Ok((t, r, l)),
            _ => Err(ImportError::Structure {
                path: self.path.clone(),
                position: Position::Line(self.line_no),
                reason: format!(
                    "header must name a time column (time|t|t_secs) and a left and/or right \
                     pupil column in mm, found `{}`{}",
                    line.escape_debug(),
                    header_hint(line)
                ),
            }),
        }
    }

    fn row(&mut self, line: &str, (ti, ri, li): (usize, Option<usize>, Option<usize>)) {
        let fields: Vec<&str> = line.split(',').map(str::trim).collect();
        let t_secs = match fields.get(ti).map(|f| f.parse::<f64>()) {
            Some(Ok(t)) if t.is_finite() => t,
            _ => {
                self.warnings.skip(
                    &self.path,
                    Position::Line(self.line_no),
                    format!("column {}: time is not a finite number in `{line}`", ti + 1),
                );
                return;
            }
        };
        let mut vals = [None::<f32>; 2];
        for (eye, idx) in [(0usize, ri), (1usize, li)] {
            let Some(idx) = idx else { continue };
            let field = fields.get(idx).copied().unwrap_or("");
            let v = if field.is_empty() || field.eq_ignore_ascii_case("nan") {
                0.0
            } else {
                match field.parse::<f32>() {
                    Ok(v) => v,
                    Err(_) => {
                        self.warnings.skip(
                            &self.path,
                            Position::Line(self.line_no),
                            format!("column {}: `{field}` is not a number", idx + 1),
                        );
                        return;
                    }
                }
            };
            vals[eye] = Some(v);
        }
        for (eye, v) in vals.iter().enumerate() {
            let Some(d) = *v else { continue };
            let valid = d.is_finite() && d > 0.0;
            self.pending.push(Sample::Pupil(PupilSample {
                t_secs,
                eye: eye as u8,
                diameter_raw: if d.is_finite() { d } else { 0.0 },
                unit: PupilUnit::Mm,
                diameter_mm: valid.then_some(d),
                confidence: if valid { 1.0 } else { 0.0 },
                norm_pos: [f32::NAN, f32::NAN],
                method: DetectorMethod::Other,
            }));
        }
    }
}

/// Why a header line that does not parse may look the way it does.
fn header_hint(line: &str) -> &'static str {
    if line.contains('\0') {
        " (NUL bytes between the characters: the file is UTF-16; save it as UTF-8)"
    } else if line.contains('\r') {
        " (carriage returns inside the line: CR-only line endings; use LF or CRLF)"
    } else if line.contains('\t') && !line.contains(',') {
        " (the fields are separated by tabs; expected commas)"
    } else if line.contains(';') && !line.contains(',') {
        " (the fields are separated by semicolons; expected commas)"
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
        match (read, self.cols) {
            (LineRead::Eof, None) => Err(self.structure(Position::File, "empty file: no header")),
            (LineRead::Eof, Some(_)) => {
                self.done = true;
                Ok(())
            }
            (LineRead::TooLong(n), None) => Err(self.structure(
                at,
                format!(
                    "the header line is {n} bytes long (limit {}): not a CSV with one record \
                     per line (CR-only line endings?)",
                    gazelight_input::MAX_LINE_BYTES
                ),
            )),
            (LineRead::NotUtf8, None) => Err(self.structure(
                at,
                "the header line is not UTF-8 text (a UTF-16 file? save it as UTF-8)",
            )),
            (LineRead::TooLong(n), Some(_)) => {
                self.warnings
                    .skip_long_line(&self.path, self.line_no, n, "a record");
                Ok(())
            }
            (LineRead::NotUtf8, Some(_)) => {
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
        let trimmed = line.trim().trim_start_matches('\u{feff}');
        if trimmed.is_empty() || trimmed.starts_with('#') {
            return Ok(());
        }
        match self.cols {
            None => self.cols = Some(self.header(trimmed)?),
            Some(c) => self.row(trimmed, c),
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
