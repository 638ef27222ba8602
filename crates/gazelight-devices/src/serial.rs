//! Serial-line trackers (USB CDC-ACM `/dev/ttyACM*`, gadget `/dev/ttyGS*`,
//! UARTs), read with `serialport` built without libudev.
//!
//! Three encodings ([`SerialFormat`]):
//!
//! - `gazepoint`: Open Gaze API `<REC … />` lines, decoded exactly as over
//!   TCP ([`super::gazepoint`]); `ACK` and other tags are ignored.
//! - `framed`: binary frames with sync bytes, length and CRC-16
//!   ([`super::framing`]).
//! - `csv`: one sample per line, fields separated by commas, `#` starts a
//!   comment line, blank lines are skipped:
//!
//!   ```text
//!   G,<t_secs>,<u>,<v>,<confidence>               gaze, u/v normalised, top-left origin
//!   P,<t_secs>,<eye>,<diameter>,<unit>,<confidence>
//!                                                 pupil, eye 0 = right / 1 = left,
//!                                                 unit mm | px | au (arbitrary)
//!   ```
//!
//!   `t_secs` is the device's clock in seconds. A line that does not
//!   follow this (wrong field count, a non-number, unknown unit) is an item
//!   error naming the line number and the field.
//!
//! Device times are mapped onto the host clock by a
//! [`gazelight_eye::clock::SourceClock`] (a line with an absurd time is
//! dropped and counted; a device clock that steps is followed after a few
//! lines). A lost line (read error, hang-up) is
//! [`SourceError::Disconnected`]; a source opened from a path reopens it on
//! the next call.

use std::io::Read;
use std::path::{Path, PathBuf};
use std::sync::Arc;
use std::sync::atomic::AtomicBool;
use std::time::Duration;

use tokio::sync::mpsc;

use super::framing::FrameDecoder;
use super::gazepoint::{Line, RecordDecoder, parse_line};
use super::{READ_POLL_MS, ThreadItem, ThreadedSource, now_secs, send_blocking};
use gazelight_eye::clock::{SharedClockStats, SourceClock, SourceClockConfig};
use gazelight_eye::sample::{DetectorMethod, GazeEyes, GazeSample, PupilSample, PupilUnit, Sample};
use gazelight_eye::source::{SampleSource, SourceError};

use crate::target::SerialFormat;

/// Longest accepted text line, bytes.
pub const MAX_LINE_BYTES: usize = 4096;

/// What is wrong with one CSV line.
#[derive(Debug, thiserror::Error, PartialEq, Eq)]
#[error("line {line}: {what}")]
pub struct LineError {
    /// 1-based line number on this connection.
    pub line: u64,
    /// What is wrong (names the field).
    pub what: String,
}

/// Parse one CSV sample line (see the module docs). `Ok(None)` for blank and
/// comment lines. Times are device seconds.
pub fn parse_csv_line(text: &str, line: u64) -> Result<Option<Sample>, LineError> {
    let t = text.trim();
    if t.is_empty() || t.starts_with('#') {
        return Ok(None);
    }
    let err = |what: String| LineError { line, what };
    let mut fields = [""; 7];
    let mut n = 0;
    for f in t.split(',') {
        if n == fields.len() {
            return Err(err(format!("more than {} fields", fields.len() - 1)));
        }
        fields[n] = f.trim();
        n += 1;
    }
    let number = |i: usize, name: &str| -> Result<f64, LineError> {
        fields[i]
            .parse::<f64>()
            .ok()
            .filter(|x| x.is_finite())
            .ok_or_else(|| {
                err(format!(
                    "field {} ({name}): `{}` is not a finite number",
                    i + 1,
                    fields[i]
                ))
            })
    };
    let confidence = |i: usize| -> Result<f32, LineError> {
        let c = number(i, "confidence")?;
        if !(0.0..=1.0).contains(&c) {
            return Err(err(format!(
                "field {} (confidence): {c} is outside 0..=1",
                i + 1
            )));
        }
        Ok(c as f32)
    };
    match fields[0] {
        "G" => {
            if n != 5 {
                return Err(err(format!(
                    "gaze line has {n} fields, expected 5: G,t_secs,u,v,confidence"
                )));
            }
            Ok(Some(Sample::Gaze(GazeSample {
                t_secs: number(1, "t_secs")?,
                gaze_uv: [number(2, "u")? as f32, number(3, "v")? as f32],
                confidence: confidence(4)?,
                eyes: GazeEyes::Binocular,
            })))
        }
        "P" => {
            if n != 6 {
                return Err(err(format!(
                    "pupil line has {n} fields, expected 6: P,t_secs,eye,diameter,unit,confidence"
                )));
            }
            let t_secs = number(1, "t_secs")?;
            let eye = match fields[2] {
                "0" => 0,
                "1" => 1,
                other => {
                    return Err(err(format!(
                        "field 3 (eye): `{other}` is not 0 (right) or 1 (left)"
                    )));
                }
            };
            let diameter = number(3, "diameter")? as f32;
            let unit = match fields[4] {
                "mm" => PupilUnit::Mm,
                "px" => PupilUnit::Px,
                "au" => PupilUnit::Arbitrary,
                other => {
                    return Err(err(format!(
                        "field 5 (unit): `{other}` is not mm, px or au"
                    )));
                }
            };
            Ok(Some(Sample::Pupil(PupilSample {
                t_secs,
                eye,
                diameter_raw: diameter,
                unit,
                diameter_mm: (unit == PupilUnit::Mm && diameter > 0.0).then_some(diameter),
                confidence: confidence(5)?,
                norm_pos: [f32::NAN, f32::NAN],
                method: DetectorMethod::Other,
            })))
        }
        other => Err(err(format!(
            "field 1 (kind): `{other}` is not G (gaze) or P (pupil)"
        ))),
    }
}

/// Decodes a byte stream in one of the [`SerialFormat`]s into samples on the
/// host clock. Buffers are allocated once.
pub struct StreamDecoder {
    format: SerialFormat,
    name: String,
    line: Vec<u8>,
    line_no: u64,
    overlong: bool,
    frames: FrameDecoder,
    records: RecordDecoder,
    /// The device clock → host time (CSV and framed; the Gazepoint format's
    /// records have their own, counting into the same statistics).
    clock: SourceClock,
    errors: u64,
}

impl StreamDecoder {
    /// A decoder for `format`; `name` appears in errors.
    pub fn new(format: SerialFormat, name: impl Into<String>) -> Self {
        Self::with_clock_stats(format, name, Arc::default())
    }

    /// As [`Self::new`], counting the clock mapping into `clock_stats`.
    pub fn with_clock_stats(
        format: SerialFormat,
        name: impl Into<String>,
        clock_stats: Arc<SharedClockStats>,
    ) -> Self {
        let name = name.into();
        let clock =
            |stats| SourceClock::with_stats(name.clone(), SourceClockConfig::default(), stats);
        Self {
            format,
            line: Vec::with_capacity(MAX_LINE_BYTES),
            line_no: 0,
            overlong: false,
            frames: FrameDecoder::new(),
            records: RecordDecoder::with_clock(clock(clock_stats.clone())),
            clock: clock(clock_stats),
            errors: 0,
            name,
        }
    }

    /// Bad items so far.
    pub fn errors(&self) -> u64 {
        self.errors
    }

    fn item_error(
        &mut self,
        index: u64,
        e: impl std::error::Error + Send + Sync + 'static,
    ) -> SourceError {
        self.errors += 1;
        SourceError::Item {
            source_name: self.name.clone(),
            index,
            error: Box::new(e),
        }
    }

    /// Feed `bytes` (arrived at `arrival_host_secs`), calling `emit` for each
    /// sample or item error; stops early (returning `false`) when `emit`
    /// returns `false`.
    pub fn feed(
        &mut self,
        mut bytes: &[u8],
        arrival_host_secs: f64,
        emit: &mut dyn FnMut(ThreadItem) -> bool,
    ) -> bool {
        match self.format {
            SerialFormat::Framed => {
                while !bytes.is_empty() {
                    let n = self.frames.push(bytes);
                    bytes = &bytes[n..];
                    while let Some(r) = self.frames.next_frame() {
                        let item = match r {
                            Ok(fs) => {
                                let mut s = fs.sample;
                                match self.clock.to_host(s.t_secs(), arrival_host_secs) {
                                    Some(t) => s.set_t_secs(t),
                                    // Dropped and counted by the mapping.
                                    None => continue,
                                }
                                Ok(s)
                            }
                            Err(e) => {
                                let idx = self.frames.frames() + self.frames.errors() - 1;
                                Err(self.item_error(idx, e))
                            }
                        };
                        if !emit(item) {
                            return false;
                        }
                    }
                }
                true
            }
            SerialFormat::Csv | SerialFormat::Gazepoint => {
                for &b in bytes {
                    if b != b'\n' {
                        if self.line.len() < MAX_LINE_BYTES {
                            self.line.push(b);
                        } else {
                            self.overlong = true;
                        }
                        continue;
                    }
                    self.line_no += 1;
                    let ok = self.finish_line(arrival_host_secs, emit);
                    self.line.clear();
                    self.overlong = false;
                    if !ok {
                        return false;
                    }
                }
                true
            }
        }
    }

    fn finish_line(&mut self, arrival: f64, emit: &mut dyn FnMut(ThreadItem) -> bool) -> bool {
        let line_no = self.line_no;
        if self.overlong {
            let e = LineError {
                line: line_no,
                what: format!("longer than {MAX_LINE_BYTES} bytes"),
            };
            let e = self.item_error(line_no, e);
            return emit(Err(e));
        }
        let text = match std::str::from_utf8(&self.line) {
            Ok(t) => t,
            Err(u) => {
                let e = LineError {
                    line: line_no,
                    what: format!("byte {}: not UTF-8 text", u.valid_up_to()),
                };
                let e = self.item_error(line_no, e);
                return emit(Err(e));
            }
        };
        match self.format {
            SerialFormat::Csv => match parse_csv_line(text, line_no) {
                Ok(None) => true,
                Ok(Some(mut s)) => match self.clock.to_host(s.t_secs(), arrival) {
                    Some(t) => {
                        s.set_t_secs(t);
                        emit(Ok(s))
                    }
                    // Dropped and counted by the mapping.
                    None => true,
                },
                Err(e) => {
                    let e = self.item_error(line_no, e);
                    emit(Err(e))
                }
            },
            _ => match parse_line(text) {
                Ok(Line::Rec(rec)) => {
                    self.records.push(&rec, arrival);
                    while let Some(s) = self.records.pop() {
                        if !emit(Ok(s)) {
                            return false;
                        }
                    }
                    true
                }
                Ok(_) => true,
                Err(e) => {
                    let e = LineError {
                        line: line_no,
                        what: e.to_string(),
                    };
                    let e = self.item_error(line_no, e);
                    emit(Err(e))
                }
            },
        }
    }
}

fn reader_loop<R: Read>(
    mut port: R,
    mut decoder: StreamDecoder,
    name: String,
    tx: mpsc::Sender<ThreadItem>,
    stop: &AtomicBool,
) {
    let mut buf = [0u8; 512];
    loop {
        if stop.load(std::sync::atomic::Ordering::Relaxed) {
            return;
        }
        match port.read(&mut buf) {
            Ok(0) => {
                let _ = send_blocking(
                    &tx,
                    stop,
                    Err(SourceError::Disconnected {
                        source_name: name,
                        reason: "end of file on the serial line".to_owned(),
                    }),
                );
                return;
            }
            Ok(n) => {
                let arrival = now_secs();
                let mut emit = |item: ThreadItem| send_blocking(&tx, stop, item);
                if !decoder.feed(&buf[..n], arrival, &mut emit) {
                    return;
                }
            }
            Err(e)
                if matches!(
                    e.kind(),
                    std::io::ErrorKind::TimedOut
                        | std::io::ErrorKind::WouldBlock
                        | std::io::ErrorKind::Interrupted
                ) => {}
            Err(e) => {
                let _ = send_blocking(
                    &tx,
                    stop,
                    Err(SourceError::Disconnected {
                        source_name: name,
                        reason: format!("read: {e}"),
                    }),
                );
                return;
            }
        }
    }
}

/// A serial-line tracker.
pub struct SerialSource {
    path: Option<PathBuf>,
    baud: u32,
    format: SerialFormat,
    name: String,
    reader: Option<ThreadedSource>,
    /// The counters of the device clock's mapping (across reopens).
    clock: Arc<SharedClockStats>,
}

fn format_name(format: SerialFormat) -> &'static str {
    match format {
        SerialFormat::Gazepoint => "gazepoint",
        SerialFormat::Csv => "csv",
        SerialFormat::Framed => "framed",
    }
}

impl SerialSource {
    /// Open `path` at `baud`. A missing device or a permission problem is a
    /// [`SourceError::Fatal`] naming the path.
    pub fn open(path: &Path, baud: u32, format: SerialFormat) -> Result<Self, SourceError> {
        let name = format!("serial://{}", path.display());
        let mut s = Self {
            path: Some(path.to_owned()),
            baud,
            format,
            name,
            reader: None,
            clock: Arc::default(),
        };
        s.reader = Some(s.start_from_path().map_err(|reason| SourceError::Fatal {
            source_name: s.name.clone(),
            reason,
        })?);
        Ok(s)
    }

    /// Read from an already open port (e.g. one end of
    /// `serialport::TTYPort::pair()`); such a source cannot reopen and ends
    /// after its line is lost.
    pub fn from_port(
        port: serialport::TTYPort,
        name: impl Into<String>,
        format: SerialFormat,
    ) -> Result<Self, SourceError> {
        let name = name.into();
        let clock = Arc::<SharedClockStats>::default();
        let reader = Self::start(port, name.clone(), format, clock.clone()).map_err(|reason| {
            SourceError::Fatal {
                source_name: name.clone(),
                reason,
            }
        })?;
        Ok(Self {
            path: None,
            baud: 0,
            format,
            name,
            reader: Some(reader),
            clock,
        })
    }

    fn start_from_path(&self) -> Result<ThreadedSource, String> {
        let Some(path) = &self.path else {
            return Err("no device path to reopen".to_owned());
        };
        let path_str = path.to_string_lossy();
        let port = serialport::new(path_str.as_ref(), self.baud)
            .timeout(Duration::from_millis(READ_POLL_MS))
            .open_native()
            .map_err(|e| match e.kind() {
                serialport::ErrorKind::NoDevice => format!("no such device {}", path.display()),
                serialport::ErrorKind::Io(std::io::ErrorKind::PermissionDenied) => format!(
                    "permission denied opening {} (is the user in the dialout group?)",
                    path.display()
                ),
                _ => format!("cannot open {}: {e}", path.display()),
            })?;
        Self::start(port, self.name.clone(), self.format, self.clock.clone())
    }

    fn start(
        mut port: serialport::TTYPort,
        name: String,
        format: SerialFormat,
        clock: Arc<SharedClockStats>,
    ) -> Result<ThreadedSource, String> {
        use serialport::SerialPort;
        port.set_timeout(Duration::from_millis(READ_POLL_MS))
            .map_err(|e| format!("setting the read timeout: {e}"))?;
        let decoder = StreamDecoder::with_clock_stats(format, name.clone(), clock);
        let thread_name = format!("serial {name}");
        ThreadedSource::spawn(&thread_name, move |tx, stop| {
            reader_loop(port, decoder, name, tx, &stop)
        })
        .map_err(|e| format!("starting the reader thread: {e}"))
    }

    async fn next_inner(&mut self) -> Result<Option<Sample>, SourceError> {
        if self.reader.is_none() {
            if self.path.is_none() {
                return Ok(None);
            }
            match self.start_from_path() {
                Ok(r) => self.reader = Some(r),
                Err(reason) => {
                    return Err(SourceError::Disconnected {
                        source_name: self.name.clone(),
                        reason,
                    });
                }
            }
        }
        super::recv_reopenable(&mut self.reader, &self.name).await
    }
}

impl SampleSource for SerialSource {
    fn next(&mut self) -> impl Future<Output = Result<Option<Sample>, SourceError>> + Send {
        self.next_inner()
    }

    fn clock_stats(&self) -> Option<Arc<SharedClockStats>> {
        Some(self.clock.clone())
    }

    fn describe(&self) -> String {
        if self.baud > 0 {
            format!(
                "serial tracker at {} ({} baud, {} format)",
                self.name,
                self.baud,
                format_name(self.format)
            )
        } else {
            format!(
                "serial tracker on {} ({} format)",
                self.name,
                format_name(self.format)
            )
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn csv_lines_parse_and_errors_name_the_field() {
        let Some(Sample::Gaze(g)) = parse_csv_line("G,12.5,0.25,0.5,0.9", 1).unwrap() else {
            panic!()
        };
        assert_eq!(
            (g.t_secs, g.gaze_uv, g.confidence),
            (12.5, [0.25, 0.5], 0.9)
        );
        let Some(Sample::Pupil(p)) = parse_csv_line(" P,12.5,1,3.75,mm,1 \r", 2).unwrap() else {
            panic!()
        };
        assert_eq!(
            (p.eye, p.diameter_mm, p.unit),
            (1, Some(3.75), PupilUnit::Mm)
        );
        assert_eq!(parse_csv_line("# header", 3).unwrap(), None);
        assert_eq!(parse_csv_line("", 4).unwrap(), None);
        let cases = [
            ("G,1,0.5,0.5", "expected 5"),
            ("G,1,0.5,zz,1", "field 4 (v)"),
            ("G,1,0.5,0.5,1.5", "field 5 (confidence)"),
            ("P,1,2,3,mm,1", "field 3 (eye)"),
            ("P,1,0,3,cm,1", "field 5 (unit)"),
            ("X,1", "field 1 (kind)"),
            ("P,nan,0,3,mm,1", "field 2 (t_secs)"),
        ];
        for (line, what) in cases {
            let e = parse_csv_line(line, 7).expect_err(line);
            assert!(e.to_string().starts_with("line 7: "), "{e}");
            assert!(e.what.contains(what), "{line}: {e}");
        }
    }
}
