//! The line reader the text importers (pupil CSV, EyeLink ASC) share:
//! bounded lines through [`gazelight_input::read_line`], counted, with an
//! I/O error turned into an [`ImportError`] that names the file.

use std::io::BufRead;
use std::path::Path;

use super::{ImportError, ImportWarnings, Position};

/// What [`read_text_line`] found.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub(crate) enum LineRead {
    /// A line; its text (with the newline) is in the buffer.
    Text,
    /// A line longer than [`gazelight_input::MAX_LINE_BYTES`] (its length
    /// in bytes), read to its end and dropped.
    TooLong(u64),
    /// A line that is not UTF-8, dropped.
    NotUtf8,
    /// End of the file.
    Eof,
}

/// Reads the next line of `path` into `buf`; every line read (text, too
/// long or not UTF-8) advances `line_no`.
pub(crate) fn read_text_line<R: BufRead>(
    reader: &mut R,
    buf: &mut String,
    line_no: &mut u64,
    path: &Path,
) -> Result<LineRead, ImportError> {
    let read = gazelight_input::read_line(reader, buf, gazelight_input::MAX_LINE_BYTES).map_err(
        |source| ImportError::Io {
            path: path.to_owned(),
            source,
        },
    )?;
    let read = match read {
        gazelight_input::Line::Eof => return Ok(LineRead::Eof),
        gazelight_input::Line::Read => LineRead::Text,
        gazelight_input::Line::TooLong(n) => LineRead::TooLong(n),
        gazelight_input::Line::NotUtf8 => LineRead::NotUtf8,
    };
    *line_no += 1;
    Ok(read)
}

impl ImportWarnings {
    /// Counts a line of `len_bytes` dropped for its length; `what` is what a
    /// line holds ("a record", "a line").
    pub(crate) fn skip_long_line(&mut self, path: &Path, line_no: u64, len_bytes: u64, what: &str) {
        self.skip(
            path,
            Position::Line(line_no),
            format_args!(
                "line of {len_bytes} bytes, longer than the {} bytes {what} can be",
                gazelight_input::MAX_LINE_BYTES
            ),
        );
    }

    /// Counts a line dropped because it is not UTF-8.
    pub(crate) fn skip_not_utf8(&mut self, path: &Path, line_no: u64) {
        self.skip(path, Position::Line(line_no), "line is not valid UTF-8");
    }
}

/// Opens a text recording for [`read_text_line`] (through
/// [`gazelight_input::open`]: regular files only, a FIFO never blocks).
pub(crate) fn open_text(path: &Path) -> Result<std::io::BufReader<std::fs::File>, ImportError> {
    let f = gazelight_input::open(path).map_err(|source| ImportError::Io {
        path: path.to_owned(),
        source,
    })?;
    Ok(std::io::BufReader::new(f))
}
