//! The one per-frame CSV writer of every front end: `render`/`replay`'s
//! `timeline.csv` ([`crate::timeline::TimelineWriter`] formats its rows),
//! a live `run`'s `timeline.csv`, `psf.csv`, `xr.csv` and `events.csv`
//! (`gazelight_output::live`), and the OpenXR layer's `frames.csv`.
//!
//! A [`RowFile`] only ever holds whole rows: rows are collected in a
//! buffer and written when it is full and at least every [`FLUSH_EVERY`]
//! (so a process killed by SIGKILL loses no row older than a second), at
//! [`RowFile::flush`] and when it is dropped. On a write error (a full
//! disk, `ulimit -f`) the file is cut back to its last complete row
//! (`set_len`), the error goes to the `on_error` the owner gave (printed
//! at once by a live run, logged by the layer) and is kept
//! ([`RowFile::failure`]); the file takes no more rows, and the caller's
//! other files go on.

use std::io::Write as _;
use std::path::{Path, PathBuf};
use std::time::{Duration, Instant};

/// How often the rows reach the file at the latest.
pub const FLUSH_EVERY: Duration = Duration::from_secs(1);

/// Size of a [`RowFile`]'s buffer before it writes (it also writes at
/// every flush).
const ROW_BUFFER_BYTES: usize = 64 << 10;

/// What a [`RowFile`] does with its failure message when it happens.
pub type OnError = fn(&str);

/// A CSV file that only ever holds whole rows (see the module docs).
pub struct RowFile {
    path: PathBuf,
    file: Option<std::fs::File>,
    buf: Vec<u8>,
    /// Bytes and rows on disk, all of them whole rows (the header is not
    /// a row).
    bytes_on_disk: u64,
    rows_on_disk: u64,
    /// Rows waiting in `buf` (the header is not one).
    rows_pending: u64,
    last_flush: Instant,
    on_error: OnError,
    failure: Option<String>,
}

impl RowFile {
    /// Creates the file with its header line queued (written at the first
    /// flush). A failure is reported to `on_error` and kept (see
    /// [`Self::failure`]), not returned.
    pub fn create(path: &Path, header: &str, on_error: OnError) -> Self {
        let mut f = Self {
            path: path.to_owned(),
            file: None,
            buf: Vec::with_capacity(ROW_BUFFER_BYTES),
            bytes_on_disk: 0,
            rows_on_disk: 0,
            rows_pending: 0,
            last_flush: Instant::now(),
            on_error,
            failure: None,
        };
        match std::fs::File::create(path) {
            Ok(file) => {
                f.file = Some(file);
                f.buf.extend_from_slice(header.as_bytes());
                f.buf.push(b'\n');
            }
            Err(e) => f.fail(&e),
        }
        f
    }

    /// Queues one formatted row (with its newline); writes when the
    /// buffer is full or the last write is [`FLUSH_EVERY`] old.
    pub fn push(&mut self, row: &str) {
        if self.file.is_none() {
            return;
        }
        self.buf.extend_from_slice(row.as_bytes());
        self.rows_pending += 1;
        if self.buf.len() >= ROW_BUFFER_BYTES || self.last_flush.elapsed() >= FLUSH_EVERY {
            self.flush();
        }
    }

    /// Writes the buffered rows. On an error the file is cut back to its
    /// last complete row and closed.
    pub fn flush(&mut self) {
        self.last_flush = Instant::now();
        let Some(file) = &mut self.file else { return };
        if self.buf.is_empty() {
            return;
        }
        let mut written = 0usize;
        while written < self.buf.len() {
            match file.write(&self.buf[written..]) {
                Ok(0) => {
                    let e = std::io::Error::new(std::io::ErrorKind::WriteZero, "wrote 0 bytes");
                    return self.cut_back(written, &e);
                }
                Ok(n) => written += n,
                Err(e) if e.kind() == std::io::ErrorKind::Interrupted => {}
                Err(e) => return self.cut_back(written, &e),
            }
        }
        self.bytes_on_disk += written as u64;
        self.rows_on_disk += self.rows_pending;
        self.rows_pending = 0;
        self.buf.clear();
    }

    /// After `written` bytes of the buffer reached the file and then
    /// `error`: keeps the whole rows among them, truncates the rest.
    fn cut_back(&mut self, written: usize, error: &std::io::Error) {
        let done = &self.buf[..written];
        let keep = done.iter().rposition(|&b| b == b'\n').map_or(0, |i| i + 1);
        let mut rows = done[..keep].iter().filter(|&&b| b == b'\n').count() as u64;
        if self.bytes_on_disk == 0 && keep > 0 {
            rows -= 1; // the header
        }
        self.bytes_on_disk += keep as u64;
        self.rows_on_disk += rows;
        if let Some(file) = &self.file
            && let Err(e) = file.set_len(self.bytes_on_disk)
        {
            tracing::warn!(file = %self.path.display(), error = %e, "cannot cut the file back to its last complete row");
        }
        self.fail(error);
    }

    fn fail(&mut self, error: &std::io::Error) {
        let msg = format!(
            "cannot write {}: {error}; it stops at its last complete row ({} rows)",
            self.path.display(),
            self.rows_on_disk
        );
        (self.on_error)(&msg);
        self.failure = Some(msg);
        self.file = None;
        self.buf = Vec::new();
        self.rows_pending = 0;
    }

    /// The error that stopped the file, if any.
    pub fn failure(&self) -> Option<&str> {
        self.failure.as_deref()
    }

    /// Whole rows on disk (the header is not one).
    pub fn rows_on_disk(&self) -> u64 {
        self.rows_on_disk
    }
}

impl Drop for RowFile {
    /// The rows still buffered reach the file.
    fn drop(&mut self) {
        self.flush();
    }
}

/// An [`OnError`] that does nothing: the owner reads
/// [`RowFile::failure`] itself.
pub fn keep_error(_: &str) {}

#[cfg(test)]
mod tests {
    #![allow(clippy::unwrap_used)]
    use super::*;

    fn tmp(name: &str) -> PathBuf {
        let d = std::env::temp_dir().join(format!("gazelight-rows-{}-{name}", std::process::id()));
        let _ = std::fs::remove_dir_all(&d);
        std::fs::create_dir_all(&d).unwrap();
        d
    }

    /// Rows reach the disk at a flush and at drop, whole, header first.
    #[test]
    fn rows_reach_the_file_whole_at_flush_and_drop() {
        let d = tmp("flush");
        let path = d.join("t.csv");
        let mut f = RowFile::create(&path, "a,b", keep_error);
        f.push("1,2\n");
        // Buffered: under 64 KiB and under a second old.
        assert_eq!(std::fs::read_to_string(&path).unwrap(), "");
        f.flush();
        assert_eq!(std::fs::read_to_string(&path).unwrap(), "a,b\n1,2\n");
        assert_eq!(f.rows_on_disk(), 1);
        f.push("3,4\n");
        drop(f);
        assert_eq!(std::fs::read_to_string(&path).unwrap(), "a,b\n1,2\n3,4\n");
        let _ = std::fs::remove_dir_all(&d);
    }

    /// A row pushed a second after the last write is written at once.
    #[test]
    fn a_row_a_second_after_the_last_write_is_written_at_once() {
        let d = tmp("second");
        let path = d.join("t.csv");
        let mut f = RowFile::create(&path, "a", keep_error);
        f.flush();
        std::thread::sleep(FLUSH_EVERY + Duration::from_millis(20));
        f.push("1\n");
        // No flush or drop: the push itself wrote it.
        assert_eq!(std::fs::read_to_string(&path).unwrap(), "a\n1\n");
        std::mem::forget(f);
        let _ = std::fs::remove_dir_all(&d);
    }

    /// A file that cannot be created reports once, keeps the reason and
    /// takes no rows.
    #[test]
    fn a_file_that_cannot_be_created_is_reported_and_takes_no_rows() {
        let d = tmp("fail");
        let path = d.join("missing").join("t.csv");
        let mut f = RowFile::create(&path, "a", keep_error);
        f.push("1\n");
        f.flush();
        let failure = f.failure().unwrap();
        assert!(failure.starts_with("cannot write "), "{failure}");
        assert!(failure.contains("t.csv"), "{failure}");
        assert!(failure.ends_with("(0 rows)"), "{failure}");
        let _ = std::fs::remove_dir_all(&d);
    }
}
