//! The Python wrapper's own looks at a path, done here with
//! `gazelight-input`'s bounded opener instead of Python's `open`: a FIFO
//! is refused without blocking, a device (`/dev/zero`) without being read,
//! and no more than a bounded prefix of a file is read to tell a trace from
//! a recording.

use std::io::{BufReader, Read};
use std::path::{Path, PathBuf};

use pyo3::prelude::*;

use crate::err;

/// Most bytes read from the start of a `.csv` file to find its header (the
/// first line that is neither blank nor a `#` comment).
pub(crate) const MAX_SNIFF_BYTES: u64 = 1 << 20;

/// The header of a gaze/pupil trace (`gazelight render --trace`).
const TRACE_HEADER: &str = "t_secs,gaze_u,gaze_v";

fn open_error(path: &Path, e: std::io::Error) -> PyErr {
    err(format!("cannot read {}: {e}", path.display()))
}

/// Whether `path` is a trace (`"trace"`: a `.csv` file whose header is a
/// trace's) or a recording (`"recording"`: anything else, which the
/// importers then open and check). A path that exists but is not a regular
/// file or directory (a FIFO, a device, a socket) is refused here, before
/// anything blocks on it or reads it.
#[pyfunction]
pub(crate) fn input_kind(py: Python<'_>, path: PathBuf) -> PyResult<&'static str> {
    py.detach(|| {
        match std::fs::metadata(&path) {
            // Missing: the importer's error names it.
            Err(_) => return Ok("recording"),
            Ok(m) if m.is_dir() => return Ok("recording"),
            Ok(_) => {}
        }
        let is_csv = path
            .extension()
            .and_then(|e| e.to_str())
            .is_some_and(|e| e.eq_ignore_ascii_case("csv"));
        // Refuses a FIFO or a device whatever its name.
        let file = gazelight_input::open(&path).map_err(|e| open_error(&path, e))?;
        if !is_csv {
            return Ok("recording");
        }
        let mut reader = BufReader::new(file.take(MAX_SNIFF_BYTES));
        let mut line = String::new();
        loop {
            let read =
                gazelight_input::read_line(&mut reader, &mut line, gazelight_input::MAX_LINE_BYTES)
                    .map_err(|e| open_error(&path, e))?;
            match read {
                gazelight_input::Line::Read => {
                    let t = line.trim();
                    if t.is_empty() || t.starts_with('#') {
                        continue;
                    }
                    let compact: String = t.chars().filter(|c| *c != ' ').collect();
                    return Ok(if compact.starts_with(TRACE_HEADER) {
                        "trace"
                    } else {
                        "recording"
                    });
                }
                // Not a trace's header (the importer reports what it is).
                _ => return Ok("recording"),
            }
        }
    })
}

/// The text of a config file named by a path, read as the CLI reads its
/// configs (`gazelight_input::read_config`: a regular file of at most
/// 1 MiB whose structure is scanned before any parser builds it).
#[pyfunction]
pub(crate) fn read_config_text(py: Python<'_>, path: PathBuf) -> PyResult<String> {
    py.detach(|| {
        gazelight_input::read_config(&path, gazelight_input::ConfigSyntax::Toml)
            .map_err(|e| err(format!("cannot read config {}: {e}", path.display())))
    })
}
