//! Gaze/pupil traces in gazelight's own CSV format, used by `gazelight
//! render --trace` and written by the synthetic generators.
//!
//! ```text
//! t_secs,gaze_u,gaze_v,pupil_mm,confidence
//! 0.000,0.50,0.80,5.1,0.98
//! 0.005,0.50,0.80,,0.0
//! ```
//!
//! `gaze_u`/`gaze_v` are normalised image coordinates with the origin at the
//! top-left. An empty or `nan` pupil, or a pupil ≤ 0, is a tracker dropout
//! (as during a blink); `confidence` is optional (default 1). Lines starting
//! with `#` are comments. Time must not go backwards.

use std::io::BufRead;
use std::path::{Path, PathBuf};

/// One sample of a trace.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct TraceSample {
    /// Time since the start of the trace, seconds.
    pub t_secs: f64,
    /// Normalised gaze, top-left origin.
    pub gaze_uv: [f32; 2],
    /// Pupil diameter in mm as reported; `None` (or ≤ 0 in the file) is a
    /// dropout.
    pub pupil_mm: Option<f32>,
    /// Tracker confidence 0..=1.
    pub confidence: f32,
}

/// A parsed trace.
#[derive(Clone, Debug, Default, PartialEq)]
pub struct GazeTrace {
    pub samples: Vec<TraceSample>,
}

/// A trace that cannot be read.
#[derive(Debug, thiserror::Error)]
pub enum TraceError {
    #[error("cannot read trace {path}: {source}")]
    Io {
        path: PathBuf,
        #[source]
        source: std::io::Error,
    },
    #[error("{path}:{line}: {reason}")]
    Parse {
        path: PathBuf,
        line: usize,
        reason: String,
    },
    #[error("{path}: the trace holds no samples")]
    Empty { path: PathBuf },
}

const HEADER: &str = "t_secs,gaze_u,gaze_v,pupil_mm,confidence";

impl GazeTrace {
    /// Reads a trace file.
    pub fn load(path: &Path) -> Result<Self, TraceError> {
        let file = gazelight_input::open(path).map_err(|source| TraceError::Io {
            path: path.to_owned(),
            source,
        })?;
        Self::parse(std::io::BufReader::new(file), path)
    }

    /// Parses a trace from a reader; `path` is only used in errors.
    pub fn parse(reader: impl BufRead, path: &Path) -> Result<Self, TraceError> {
        let err = |line: usize, reason: String| TraceError::Parse {
            path: path.to_owned(),
            line,
            reason,
        };
        let mut samples: Vec<TraceSample> = Vec::new();
        let mut saw_header = false;
        let mut reader = reader;
        let mut buf = String::new();
        let mut line_no = 0usize;
        loop {
            line_no += 1;
            let read =
                gazelight_input::read_line(&mut reader, &mut buf, gazelight_input::MAX_LINE_BYTES)
                    .map_err(|source| TraceError::Io {
                        path: path.to_owned(),
                        source,
                    })?;
            match read {
                gazelight_input::Line::Eof => break,
                gazelight_input::Line::Read => {}
                gazelight_input::Line::TooLong(n) => {
                    return Err(err(
                        line_no,
                        format!(
                            "line of {n} bytes, longer than the {} a trace row can be",
                            gazelight_input::MAX_LINE_BYTES
                        ),
                    ));
                }
                gazelight_input::Line::NotUtf8 => {
                    return Err(err(line_no, "not UTF-8 text".into()));
                }
            }
            let line = buf.trim();
            if line.is_empty() || line.starts_with('#') {
                continue;
            }
            if !saw_header {
                saw_header = true;
                if line.starts_with("t_secs") {
                    let cols: Vec<&str> = line.split(',').map(str::trim).collect();
                    let expected: Vec<&str> = HEADER.split(',').collect();
                    if cols.len() < 4 || cols[..4] != expected[..4] {
                        return Err(err(
                            line_no,
                            format!("header must be `{HEADER}`, found `{line}`"),
                        ));
                    }
                    continue;
                }
            }
            let fields: Vec<&str> = line.split(',').map(str::trim).collect();
            if fields.len() < 4 || fields.len() > 5 {
                return Err(err(
                    line_no,
                    format!(
                        "expected 4 or 5 comma-separated fields ({HEADER}), found {}",
                        fields.len()
                    ),
                ));
            }
            let num = |idx: usize, name: &str| -> Result<f64, TraceError> {
                fields[idx].parse::<f64>().map_err(|_| {
                    err(
                        line_no,
                        format!("column `{name}`: `{}` is not a number", fields[idx]),
                    )
                })
            };
            let t_secs = num(0, "t_secs")?;
            if !t_secs.is_finite() {
                return Err(err(
                    line_no,
                    format!("column `t_secs`: {t_secs} is not finite"),
                ));
            }
            if let Some(prev) = samples.last()
                && t_secs < prev.t_secs
            {
                return Err(err(
                    line_no,
                    format!("time goes backwards: t_secs {t_secs} after {}", prev.t_secs),
                ));
            }
            let u = num(1, "gaze_u")?;
            let v = num(2, "gaze_v")?;
            if !u.is_finite() || !v.is_finite() {
                return Err(err(line_no, "gaze_u/gaze_v must be finite".into()));
            }
            let pupil_mm = if fields[3].is_empty() || fields[3].eq_ignore_ascii_case("nan") {
                None
            } else {
                let p = num(3, "pupil_mm")?;
                (p.is_finite() && p > 0.0).then_some(p as f32)
            };
            let confidence = if fields.len() == 5 && !fields[4].is_empty() {
                let c = num(4, "confidence")?;
                if !(0.0..=1.0).contains(&c) {
                    return Err(err(
                        line_no,
                        format!("column `confidence`: {c} is outside 0..=1"),
                    ));
                }
                c as f32
            } else {
                1.0
            };
            samples.push(TraceSample {
                t_secs,
                gaze_uv: [u as f32, v as f32],
                pupil_mm,
                confidence,
            });
        }
        if samples.is_empty() {
            return Err(TraceError::Empty {
                path: path.to_owned(),
            });
        }
        Ok(Self { samples })
    }

    /// Writes the trace in the format [`GazeTrace::parse`] reads.
    pub fn write(&self, mut w: impl std::io::Write) -> std::io::Result<()> {
        writeln!(w, "{HEADER}")?;
        for s in &self.samples {
            match s.pupil_mm {
                Some(p) => writeln!(
                    w,
                    "{:.4},{:.5},{:.5},{:.4},{:.3}",
                    s.t_secs, s.gaze_uv[0], s.gaze_uv[1], p, s.confidence
                )?,
                None => writeln!(
                    w,
                    "{:.4},{:.5},{:.5},,{:.3}",
                    s.t_secs, s.gaze_uv[0], s.gaze_uv[1], s.confidence
                )?,
            }
        }
        Ok(())
    }

    /// Duration from the first to the last sample, seconds.
    pub fn duration_secs(&self) -> f64 {
        match (self.samples.first(), self.samples.last()) {
            (Some(a), Some(b)) => b.t_secs - a.t_secs,
            _ => 0.0,
        }
    }

    /// The sample at or just before `t_secs` (the first sample before the
    /// start). `None` only for an empty trace.
    pub fn sample_at(&self, t_secs: f64) -> Option<&TraceSample> {
        let idx = self.samples.partition_point(|s| s.t_secs <= t_secs);
        self.samples.get(idx.saturating_sub(1))
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    fn parse(text: &str) -> Result<GazeTrace, TraceError> {
        GazeTrace::parse(text.as_bytes(), Path::new("t.csv"))
    }

    #[test]
    fn parses_dropouts_and_comments() {
        let t = parse("# x\nt_secs,gaze_u,gaze_v,pupil_mm,confidence\n0,0.5,0.5,4.0,0.9\n0.1,0.5,0.5,,0\n0.2,0.5,0.5,0,0\n").unwrap();
        assert_eq!(t.samples.len(), 3);
        assert_eq!(t.samples[0].pupil_mm, Some(4.0));
        assert_eq!(t.samples[1].pupil_mm, None);
        assert_eq!(t.samples[2].pupil_mm, None);
    }

    #[test]
    fn time_backwards_names_the_line() {
        let e = parse("t_secs,gaze_u,gaze_v,pupil_mm\n0.2,0.5,0.5,4\n0.1,0.5,0.5,4\n").unwrap_err();
        let msg = e.to_string();
        assert!(
            msg.contains("t.csv:3") && msg.contains("backwards"),
            "{msg}"
        );
    }

    #[test]
    fn bad_number_names_the_column() {
        let e = parse("0,abc,0.5,4\n").unwrap_err().to_string();
        assert!(e.contains("gaze_u") && e.contains(":1"), "{e}");
    }

    #[test]
    fn empty_is_an_error() {
        assert!(matches!(
            parse("# nothing\n"),
            Err(TraceError::Empty { .. })
        ));
    }

    #[test]
    fn roundtrip() {
        let t = parse("0,0.25,0.75,3.5,1\n0.5,0.3,0.7,,0\n").unwrap();
        let mut buf = Vec::new();
        t.write(&mut buf).unwrap();
        let back = parse(std::str::from_utf8(&buf).unwrap()).unwrap();
        assert_eq!(t, back);
        assert_eq!(back.sample_at(0.2).unwrap().t_secs, 0.0);
        assert_eq!(back.sample_at(9.0).unwrap().t_secs, 0.5);
    }
}
