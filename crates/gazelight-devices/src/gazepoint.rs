//! The Gazepoint Open Gaze API (Open Gaze API by Gazepoint, version 2.0):
//! XML records over TCP (default port 4242) or, with the same record
//! syntax, over a serial line.
//!
//! Protocol as used here (section numbers of the v2.0 document):
//!
//! - the client enables data fields with
//!   `<SET ID="ENABLE_SEND_…" STATE="1" />` and the server acknowledges each
//!   with `<ACK ID="ENABLE_SEND_…" STATE="1" />` (§3); records flow once
//!   `ENABLE_SEND_DATA` is set (§3.1), one `<REC … />` per line, lines ended
//!   by `\r\n` (§2.4);
//! - `TIME` (§5.2): seconds since the server's initialisation;
//! - `FPOGX`, `FPOGY` (§5.4): fixation point of gaze as a fraction of the
//!   screen size, (0,0) top-left, (1,1) bottom-right; `FPOGV` its valid flag;
//! - `LPCX`, `LPCY`, `LPD`, `LPV` / `RPCX`, `RPCY`, `RPD`, `RPV` (§5.9, §5.10):
//!   pupil centre as a fraction of the camera image, pupil diameter in
//!   camera pixels, valid flag;
//! - `LPMM`, `LPMMV`, `RPMM`, `RPMMV` (§5.16): pupil diameter in mm and its
//!   valid flag (enabled by `ENABLE_SEND_PUPILMM`).
//!
//! Each record becomes up to three [`Sample`]s: a binocular gaze sample
//! (when `FPOGX/FPOGY` are present; confidence 1 when `FPOGV=1`, else 0) and
//! one pupil sample per eye (when that eye's `*PD` or `*PMM` is present:
//! `diameter_raw` in px from `*PD` if present else in mm from `*PMM`,
//! `diameter_mm` from `*PMM` when its valid flag is 1, confidence from the
//! valid flags). The camera-image pupil centre (top-left origin) becomes
//! `norm_pos` with Pupil's bottom-left origin (`y → 1 − y`).
//!
//! A record that is not well-formed (no closing `/>`, a missing quote, a
//! known numeric field that does not parse) is an item error naming the
//! record index and the byte offset in the line; the source goes on with the
//! next line. A dropped connection is [`SourceError::Disconnected`]; the next
//! call reconnects and repeats the handshake.

use std::collections::VecDeque;
use std::sync::Arc;
use std::time::Duration;

use gazelight_input::LineAccumulator;
use tokio::io::{AsyncBufRead, AsyncBufReadExt, AsyncWriteExt, BufReader};
use tokio::net::TcpStream;
use tokio::net::tcp::{OwnedReadHalf, OwnedWriteHalf};

use super::now_secs;
use gazelight_eye::clock::{SharedClockStats, SourceClock, SourceClockConfig};
use gazelight_eye::sample::{DetectorMethod, GazeEyes, GazeSample, PupilSample, PupilUnit, Sample};
use gazelight_eye::source::{SampleSource, SourceError};

/// The data fields the source enables, in order; `ENABLE_SEND_DATA` last.
pub const ENABLE_FIELDS: [&str; 7] = [
    "ENABLE_SEND_TIME",
    "ENABLE_SEND_POG_FIX",
    "ENABLE_SEND_PUPIL_LEFT",
    "ENABLE_SEND_PUPIL_RIGHT",
    "ENABLE_SEND_PUPILMM",
    "ENABLE_SEND_COUNTER",
    "ENABLE_SEND_DATA",
];

/// Longest line accepted, bytes (a full record with every field enabled is
/// well under 1 KiB). Enforced while reading: a server that sends more
/// without a newline is disconnected once this many bytes have arrived.
pub const MAX_LINE_BYTES: usize = 8192;

/// How a bounded line read ended.
enum LineRead {
    /// A complete line (with its newline) is in the accumulator.
    Line,
    /// The server closed the connection (a partial last line is dropped).
    Eof,
    /// [`MAX_LINE_BYTES`] arrived without a newline; reading stopped there.
    TooLong,
}

/// Reads one line into `line`, keeping at most its limit and stopping as
/// soon as the limit is passed: memory and work are bounded whatever the
/// server sends (the caller bounds the time).
async fn read_bounded_line<R: AsyncBufRead + Unpin>(
    reader: &mut R,
    line: &mut LineAccumulator,
) -> std::io::Result<LineRead> {
    line.clear();
    loop {
        let chunk = reader.fill_buf().await?;
        if chunk.is_empty() {
            return Ok(LineRead::Eof);
        }
        let taken = line.feed(chunk);
        reader.consume(taken);
        if line.too_long() {
            return Ok(LineRead::TooLong);
        }
        if line.is_complete() {
            return Ok(LineRead::Line);
        }
    }
}

/// What is wrong with a line.
#[derive(Debug, thiserror::Error, PartialEq, Eq)]
#[error("byte {offset}: {reason}")]
pub struct RecordError {
    /// Byte offset in the line.
    pub offset: usize,
    /// What was expected.
    pub reason: String,
}

/// The fields of a `<REC />` record that gazelight uses. Absent fields are
/// `None`.
#[derive(Clone, Copy, Debug, Default, PartialEq)]
pub struct Record {
    pub cnt: Option<u64>,
    pub time_secs: Option<f64>,
    pub fpog: Option<[f64; 2]>,
    pub fpog_valid: Option<bool>,
    /// Per eye, index 0 = right, 1 = left (Pupil's eye ids).
    pub pupil_centre: [Option<[f64; 2]>; 2],
    pub pupil_px: [Option<f64>; 2],
    pub pupil_px_valid: [Option<bool>; 2],
    pub pupil_mm: [Option<f64>; 2],
    pub pupil_mm_valid: [Option<bool>; 2],
}

/// One parsed line.
#[derive(Clone, Copy, Debug, PartialEq)]
pub enum Line<'a> {
    /// A data record.
    Rec(Record),
    /// An acknowledgement: `ID` and `STATE` (if given).
    Ack { id: &'a str, state: Option<&'a str> },
    /// Any other well-formed tag (`CAL`, `NACK`, `UPDATE`, …): its name.
    Other { tag: &'a str },
    /// An empty line.
    Empty,
}

/// Iterate over `NAME="VALUE"` attributes of a tag body; yields
/// `(name, value, value_offset)`.
fn attributes<'a>(
    line: &'a str,
    mut pos: usize,
    end: usize,
    mut f: impl FnMut(&'a str, &'a str, usize) -> Result<(), RecordError>,
) -> Result<(), RecordError> {
    let b = line.as_bytes();
    loop {
        while pos < end && b[pos].is_ascii_whitespace() {
            pos += 1;
        }
        if pos >= end {
            return Ok(());
        }
        let name_start = pos;
        while pos < end && (b[pos].is_ascii_alphanumeric() || b[pos] == b'_') {
            pos += 1;
        }
        if pos == name_start {
            return Err(RecordError {
                offset: pos,
                reason: format!("expected an attribute name, found `{}`", b[pos] as char),
            });
        }
        let name = &line[name_start..pos];
        if pos >= end || b[pos] != b'=' {
            return Err(RecordError {
                offset: pos,
                reason: format!("expected `=` after attribute {name}"),
            });
        }
        pos += 1;
        if pos >= end || b[pos] != b'"' {
            return Err(RecordError {
                offset: pos,
                reason: format!("expected `\"` to open the value of {name}"),
            });
        }
        pos += 1;
        let value_start = pos;
        while pos < end && b[pos] != b'"' {
            pos += 1;
        }
        if pos >= end {
            return Err(RecordError {
                offset: value_start - 1,
                reason: format!("unterminated value of {name}"),
            });
        }
        f(name, &line[value_start..pos], value_start)?;
        pos += 1;
    }
}

fn num(name: &str, v: &str, at: usize) -> Result<f64, RecordError> {
    match v.trim().parse::<f64>() {
        Ok(x) if x.is_finite() => Ok(x),
        _ => Err(RecordError {
            offset: at,
            reason: format!("field {name}: `{v}` is not a finite number"),
        }),
    }
}

fn flag(name: &str, v: &str, at: usize) -> Result<bool, RecordError> {
    match v.trim() {
        "1" => Ok(true),
        "0" => Ok(false),
        _ => Err(RecordError {
            offset: at,
            reason: format!("field {name}: `{v}` is not 0 or 1"),
        }),
    }
}

/// Parse one line of the Open Gaze API.
pub fn parse_line(line: &str) -> Result<Line<'_>, RecordError> {
    let t = line.trim_end_matches(['\r', '\n']);
    let lead = t.len() - t.trim_start().len();
    let t_end = t.trim_end().len();
    if t_end == lead {
        return Ok(Line::Empty);
    }
    let b = t.as_bytes();
    if b[lead] != b'<' {
        return Err(RecordError {
            offset: lead,
            reason: "expected `<` to open a tag".to_owned(),
        });
    }
    // Some servers end records with `/>>` (seen in the v2.0 document's
    // examples); accept one stray `>` after the close.
    let mut body_end = t_end;
    if t[..body_end].ends_with("/>>") {
        body_end -= 1;
    }
    if !t[..body_end].ends_with("/>") {
        return Err(RecordError {
            offset: t_end,
            reason: "expected the record to end with `/>`".to_owned(),
        });
    }
    body_end -= 2;
    let name_start = lead + 1;
    let mut p = name_start;
    while p < body_end && (b[p].is_ascii_alphanumeric() || b[p] == b'_') {
        p += 1;
    }
    if p == name_start {
        return Err(RecordError {
            offset: name_start,
            reason: "expected a tag name after `<`".to_owned(),
        });
    }
    let tag = &t[name_start..p];
    match tag {
        "REC" => {
            let mut r = Record::default();
            attributes(t, p, body_end, |name, v, at| {
                // Eye index: R* = right (0), L* = left (1).
                match name {
                    "CNT" => {
                        r.cnt = Some(v.trim().parse::<u64>().map_err(|_| RecordError {
                            offset: at,
                            reason: format!("field CNT: `{v}` is not a counter"),
                        })?)
                    }
                    "TIME" => r.time_secs = Some(num(name, v, at)?),
                    "FPOGX" => r.fpog.get_or_insert([f64::NAN; 2])[0] = num(name, v, at)?,
                    "FPOGY" => r.fpog.get_or_insert([f64::NAN; 2])[1] = num(name, v, at)?,
                    "FPOGV" => r.fpog_valid = Some(flag(name, v, at)?),
                    "RPCX" | "LPCX" | "RPCY" | "LPCY" => {
                        let eye = usize::from(name.starts_with('L'));
                        let axis = usize::from(name.ends_with('Y'));
                        r.pupil_centre[eye].get_or_insert([f64::NAN; 2])[axis] = num(name, v, at)?;
                    }
                    "RPD" | "LPD" => {
                        r.pupil_px[usize::from(name.starts_with('L'))] = Some(num(name, v, at)?)
                    }
                    "RPV" | "LPV" => {
                        r.pupil_px_valid[usize::from(name.starts_with('L'))] =
                            Some(flag(name, v, at)?)
                    }
                    "RPMM" | "LPMM" => {
                        r.pupil_mm[usize::from(name.starts_with('L'))] = Some(num(name, v, at)?)
                    }
                    "RPMMV" | "LPMMV" => {
                        r.pupil_mm_valid[usize::from(name.starts_with('L'))] =
                            Some(flag(name, v, at)?)
                    }
                    _ => {}
                }
                Ok(())
            })?;
            if let Some(g) = r.fpog
                && (g[0].is_nan() || g[1].is_nan())
            {
                return Err(RecordError {
                    offset: lead,
                    reason: "FPOGX and FPOGY must come together".to_owned(),
                });
            }
            Ok(Line::Rec(r))
        }
        "ACK" => {
            let mut id = None;
            let mut state = None;
            attributes(t, p, body_end, |name, v, _| {
                match name {
                    "ID" => id = Some(v),
                    "STATE" => state = Some(v),
                    _ => {}
                }
                Ok(())
            })?;
            let Some(id) = id else {
                return Err(RecordError {
                    offset: lead,
                    reason: "ACK without an ID attribute".to_owned(),
                });
            };
            Ok(Line::Ack { id, state })
        }
        _ => {
            attributes(t, p, body_end, |_, _, _| Ok(()))?;
            Ok(Line::Other { tag })
        }
    }
}

/// Turns records into samples (shared by the TCP and serial sources).
/// The tracker's `TIME` goes to host time through a [`SourceClock`]; a
/// record whose time the mapping drops gives no samples.
#[derive(Debug)]
pub struct RecordDecoder {
    clock: SourceClock,
    pending: VecDeque<Sample>,
}

impl Default for RecordDecoder {
    fn default() -> Self {
        Self::new()
    }
}

impl RecordDecoder {
    /// A decoder with room for one record's samples.
    pub fn new() -> Self {
        Self::with_clock(SourceClock::new("gazepoint", SourceClockConfig::default()))
    }

    /// A decoder mapping the tracker's time through `clock`.
    pub fn with_clock(clock: SourceClock) -> Self {
        Self {
            clock,
            pending: VecDeque::with_capacity(4),
        }
    }

    /// The counters of the clock mapping.
    pub fn clock_stats(&self) -> Arc<SharedClockStats> {
        self.clock.shared_stats()
    }

    /// Forget the clock offset (after a reconnect).
    pub fn reset(&mut self) {
        self.clock.reset();
        self.pending.clear();
    }

    /// Queue the samples of `rec`, which arrived at host time
    /// `arrival_host_secs`.
    pub fn push(&mut self, rec: &Record, arrival_host_secs: f64) {
        let t = match rec.time_secs {
            Some(d) => match self.clock.to_host(d, arrival_host_secs) {
                Some(t) => t,
                // Dropped and counted by the mapping.
                None => return,
            },
            None => self.clock.arrival(arrival_host_secs),
        };
        if let Some([x, y]) = rec.fpog {
            self.pending.push_back(Sample::Gaze(GazeSample {
                t_secs: t,
                gaze_uv: [x as f32, y as f32],
                confidence: if rec.fpog_valid.unwrap_or(false) {
                    1.0
                } else {
                    0.0
                },
                eyes: GazeEyes::Binocular,
            }));
        }
        for eye in 0..2 {
            let px = rec.pupil_px[eye];
            let mm = rec.pupil_mm[eye];
            if px.is_none() && mm.is_none() {
                continue;
            }
            let mm_valid = rec.pupil_mm_valid[eye].unwrap_or(true);
            let diameter_mm = mm.filter(|d| mm_valid && *d > 0.0).map(|d| d as f32);
            let (raw, unit, valid) = match px {
                Some(d) => (d, PupilUnit::Px, rec.pupil_px_valid[eye].unwrap_or(true)),
                None => (mm.unwrap_or(0.0), PupilUnit::Mm, mm_valid),
            };
            let norm_pos = match rec.pupil_centre[eye] {
                Some([x, y]) => [x as f32, 1.0 - y as f32],
                None => [f32::NAN, f32::NAN],
            };
            self.pending.push_back(Sample::Pupil(PupilSample {
                t_secs: t,
                eye: eye as u8,
                diameter_raw: raw as f32,
                unit,
                diameter_mm,
                confidence: if valid && raw > 0.0 { 1.0 } else { 0.0 },
                norm_pos,
                method: DetectorMethod::Other,
            }));
        }
    }

    /// The next queued sample.
    pub fn pop(&mut self) -> Option<Sample> {
        self.pending.pop_front()
    }
}

/// Handshake and reconnection timeouts of a [`GazepointSource`].
#[derive(Clone, Copy, Debug)]
pub struct GazepointTimeouts {
    /// TCP connect.
    pub connect: Duration,
    /// Each `ACK` of the handshake.
    pub ack: Duration,
    /// Silence on an open connection before it is declared lost.
    pub idle: Duration,
}

impl Default for GazepointTimeouts {
    fn default() -> Self {
        Self {
            connect: Duration::from_secs(2),
            ack: Duration::from_secs(2),
            idle: Duration::from_secs(5),
        }
    }
}

struct Conn {
    reader: BufReader<OwnedReadHalf>,
    _writer: OwnedWriteHalf,
}

/// A Gazepoint Open Gaze API client.
pub struct GazepointSource {
    host: String,
    port: u16,
    timeouts: GazepointTimeouts,
    conn: Option<Conn>,
    line: LineAccumulator,
    decoder: RecordDecoder,
    records: u64,
    errors: u64,
    connects: u64,
}

impl GazepointSource {
    /// A client for `host:port`; it connects on the first
    /// [`SampleSource::next`].
    pub fn new(host: impl Into<String>, port: u16) -> Self {
        Self::with_timeouts(host, port, GazepointTimeouts::default())
    }

    /// As [`Self::new`] with explicit timeouts.
    pub fn with_timeouts(host: impl Into<String>, port: u16, timeouts: GazepointTimeouts) -> Self {
        let host = host.into();
        let clock = SourceClock::new(
            format!("gazepoint://{host}:{port}"),
            SourceClockConfig::default(),
        );
        Self {
            host,
            port,
            timeouts,
            conn: None,
            line: LineAccumulator::new(MAX_LINE_BYTES),
            decoder: RecordDecoder::with_clock(clock),
            records: 0,
            errors: 0,
            connects: 0,
        }
    }

    /// Records received (good or bad).
    pub fn records(&self) -> u64 {
        self.records
    }

    /// Malformed records so far.
    pub fn errors(&self) -> u64 {
        self.errors
    }

    /// Successful connections (handshakes) so far.
    pub fn connects(&self) -> u64 {
        self.connects
    }

    fn name(&self) -> String {
        format!("gazepoint://{}:{}", self.host, self.port)
    }

    fn lost(&mut self, reason: String) -> SourceError {
        self.conn = None;
        self.decoder.reset();
        SourceError::Disconnected {
            source_name: self.name(),
            reason,
        }
    }

    async fn connect(&mut self) -> Result<(), SourceError> {
        let addr = (self.host.as_str(), self.port);
        let stream =
            match tokio::time::timeout(self.timeouts.connect, TcpStream::connect(addr)).await {
                Ok(Ok(s)) => s,
                Ok(Err(e)) => return Err(self.lost(format!("connect: {e}"))),
                Err(_) => {
                    return Err(self.lost(format!(
                        "connect: no answer within {:?}",
                        self.timeouts.connect
                    )));
                }
            };
        let _ = stream.set_nodelay(true);
        let (r, mut w) = stream.into_split();
        let mut reader = BufReader::new(r);
        for id in ENABLE_FIELDS {
            let cmd = format!("<SET ID=\"{id}\" STATE=\"1\" />\r\n");
            if let Err(e) = w.write_all(cmd.as_bytes()).await {
                return Err(self.lost(format!("sending {id}: {e}")));
            }
            let deadline = tokio::time::Instant::now() + self.timeouts.ack;
            loop {
                let read = tokio::time::timeout_at(
                    deadline,
                    read_bounded_line(&mut reader, &mut self.line),
                )
                .await;
                match read {
                    Err(_) => {
                        return Err(
                            self.lost(format!("no ACK for {id} within {:?}", self.timeouts.ack))
                        );
                    }
                    Ok(Err(e)) => return Err(self.lost(format!("waiting for ACK of {id}: {e}"))),
                    Ok(Ok(LineRead::Eof)) => {
                        return Err(self.lost(format!("connection closed before ACK of {id}")));
                    }
                    Ok(Ok(LineRead::TooLong)) => {
                        return Err(self.lost(too_long_reason()));
                    }
                    Ok(Ok(LineRead::Line)) => {}
                }
                let Ok(text) = std::str::from_utf8(self.line.bytes()) else {
                    // Not an Open Gaze line; the ACK is still awaited.
                    continue;
                };
                match parse_line(text) {
                    Ok(Line::Ack { id: got, state }) if got == id => {
                        if state.is_some_and(|s| s.trim() != "1") {
                            return Err(SourceError::Fatal {
                                source_name: self.name(),
                                reason: format!(
                                    "server refused {id} (ACK STATE=\"{}\")",
                                    state.unwrap_or("")
                                ),
                            });
                        }
                        break;
                    }
                    // Records or other tags before the ACK (a server that was
                    // already sending): ignore them.
                    _ => continue,
                }
            }
        }
        self.conn = Some(Conn { reader, _writer: w });
        self.decoder.reset();
        self.connects += 1;
        Ok(())
    }

    async fn next_inner(&mut self) -> Result<Option<Sample>, SourceError> {
        loop {
            if let Some(s) = self.decoder.pop() {
                return Ok(Some(s));
            }
            if self.conn.is_none() {
                self.connect().await?;
            }
            let idle = self.timeouts.idle;
            let Some(conn) = self.conn.as_mut() else {
                continue;
            };
            let read =
                tokio::time::timeout(idle, read_bounded_line(&mut conn.reader, &mut self.line))
                    .await;
            match read {
                Err(_) => return Err(self.lost(format!("no data for {idle:?}"))),
                Ok(Err(e)) => return Err(self.lost(format!("read: {e}"))),
                Ok(Ok(LineRead::Eof)) => {
                    return Err(self.lost("connection closed by the server".to_owned()));
                }
                Ok(Ok(LineRead::TooLong)) => {
                    self.records += 1;
                    self.errors += 1;
                    return Err(self.lost(too_long_reason()));
                }
                Ok(Ok(LineRead::Line)) => {}
            }
            let arrival = now_secs();
            let text = match std::str::from_utf8(self.line.bytes()) {
                Ok(text) => text,
                Err(e) => {
                    let index = self.records;
                    self.records += 1;
                    self.errors += 1;
                    return Err(SourceError::Item {
                        source_name: self.name(),
                        index,
                        error: Box::new(RecordError {
                            offset: e.valid_up_to(),
                            reason: "not UTF-8 text".to_owned(),
                        }),
                    });
                }
            };
            match parse_line(text) {
                Ok(Line::Rec(rec)) => {
                    self.records += 1;
                    self.decoder.push(&rec, arrival);
                }
                Ok(_) => {}
                Err(e) => {
                    let index = self.records;
                    self.records += 1;
                    self.errors += 1;
                    return Err(SourceError::Item {
                        source_name: self.name(),
                        index,
                        error: Box::new(e),
                    });
                }
            }
        }
    }
}

/// Why a connection is dropped when a line passes [`MAX_LINE_BYTES`].
fn too_long_reason() -> String {
    format!(
        "the server sent {MAX_LINE_BYTES} bytes without a newline (an Open Gaze record is under \
         1 KiB): not an Open Gaze API stream; connection dropped"
    )
}

impl SampleSource for GazepointSource {
    fn next(&mut self) -> impl Future<Output = Result<Option<Sample>, SourceError>> + Send {
        self.next_inner()
    }

    fn describe(&self) -> String {
        format!("Gazepoint Open Gaze API at {}:{}", self.host, self.port)
    }

    fn clock_stats(&self) -> Option<Arc<SharedClockStats>> {
        Some(self.decoder.clock_stats())
    }
}

/// A Gazepoint Open Gaze API server simulator for tests (and for trying the
/// service without a tracker). It acknowledges `SET` commands, and once
/// `ENABLE_SEND_DATA` is set it sends the scripted lines of the current
/// session, then either keeps the connection open or drops it.
#[doc(hidden)]
pub mod sim {
    use std::net::SocketAddr;
    use std::sync::{Arc, Mutex};

    use tokio::io::{AsyncBufReadExt, AsyncWriteExt, BufReader};
    use tokio::net::TcpListener;
    use tokio::task::JoinHandle;

    /// What one accepted connection does after the handshake.
    #[derive(Clone, Debug)]
    pub struct Session {
        /// Lines to send (without `\r\n`), in order.
        pub lines: Vec<String>,
        /// Close the connection after the last line.
        pub drop_after: bool,
        /// Time between lines (a tracker's sample period); `None` sends
        /// them all at once.
        pub line_interval: Option<std::time::Duration>,
    }

    /// A running simulator.
    pub struct Simulator {
        pub addr: SocketAddr,
        /// Every `SET` the server received, `(ID, STATE)`, across sessions.
        pub received: Arc<Mutex<Vec<(String, String)>>>,
        task: JoinHandle<()>,
    }

    impl Drop for Simulator {
        fn drop(&mut self) {
            self.task.abort();
        }
    }

    /// Format a record line as the server sends it.
    pub fn rec(fields: &[(&str, String)]) -> String {
        let mut s = String::from("<REC");
        for (k, v) in fields {
            s.push_str(&format!(" {k}=\"{v}\""));
        }
        s.push_str(" />");
        s
    }

    fn attr<'a>(line: &'a str, name: &str) -> Option<&'a str> {
        let key = format!("{name}=\"");
        let start = line.find(&key)? + key.len();
        let len = line[start..].find('"')?;
        Some(&line[start..start + len])
    }

    /// Start a simulator on 127.0.0.1 (an ephemeral port) serving the
    /// sessions in order, one per accepted connection; after the last
    /// session it accepts no more connections.
    pub async fn start(sessions: Vec<Session>) -> std::io::Result<Simulator> {
        let listener = TcpListener::bind("127.0.0.1:0").await?;
        let addr = listener.local_addr()?;
        let received = Arc::new(Mutex::new(Vec::new()));
        let rec2 = Arc::clone(&received);
        let task = tokio::spawn(async move {
            for session in sessions {
                let Ok((stream, _)) = listener.accept().await else {
                    return;
                };
                let (r, mut w) = stream.into_split();
                let mut lines = BufReader::new(r).lines();
                let mut streaming = false;
                while !streaming {
                    let Ok(Some(line)) = lines.next_line().await else {
                        break;
                    };
                    if let (Some(id), Some(state)) = (attr(&line, "ID"), attr(&line, "STATE")) {
                        if let Ok(mut v) = rec2.lock() {
                            v.push((id.to_owned(), state.to_owned()));
                        }
                        let ack = format!("<ACK ID=\"{id}\" STATE=\"{state}\" />\r\n");
                        if w.write_all(ack.as_bytes()).await.is_err() {
                            break;
                        }
                        streaming = id == "ENABLE_SEND_DATA" && state == "1";
                    }
                }
                if !streaming {
                    continue;
                }
                for l in &session.lines {
                    if let Some(dt) = session.line_interval {
                        tokio::time::sleep(dt).await;
                    }
                    if w.write_all(format!("{l}\r\n").as_bytes()).await.is_err() {
                        break;
                    }
                }
                let _ = w.flush().await;
                if session.drop_after {
                    drop(w);
                    drop(lines);
                } else {
                    // Keep the connection open until the client goes away.
                    while let Ok(Some(_)) = lines.next_line().await {}
                }
            }
        });
        Ok(Simulator {
            addr,
            received,
            task,
        })
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn spec_example_records_parse() {
        // Open Gaze API v2.0 §5.4 and §5.9 examples.
        let Line::Rec(r) = parse_line(
            "<REC FPOGX=\"0.48439\" FPOGY=\"0.50313\" FPOGS=\"1891.86768\" FPOGD=\"0.49280\" FPOGID=\"1599\" FPOGV=\"1\" />\r\n",
        )
        .unwrap() else {
            panic!()
        };
        assert_eq!(r.fpog, Some([0.48439, 0.50313]));
        assert_eq!(r.fpog_valid, Some(true));
        let Line::Rec(r) = parse_line(
            "<REC LPCX=\"0.40525\" LPCY=\"0.32822\" LPD=\"15.23866\" LPS=\"1.04834\" LPV=\"1\" />>",
        )
        .unwrap() else {
            panic!()
        };
        assert_eq!(r.pupil_px[1], Some(15.23866));
        assert_eq!(r.pupil_centre[1], Some([0.40525, 0.32822]));
        assert_eq!(r.pupil_px[0], None);
        assert_eq!(
            parse_line("<ACK ID=\"ENABLE_SEND_COUNTER\" STATE=\"1\" />").unwrap(),
            Line::Ack {
                id: "ENABLE_SEND_COUNTER",
                state: Some("1")
            }
        );
        assert_eq!(parse_line("\r\n").unwrap(), Line::Empty);
    }

    #[test]
    fn malformed_records_name_the_offset() {
        let cases = [
            ("<REC TIME=\"1.0\" FPOGX=\"0.5", 26),
            ("REC TIME=\"1.0\" />", 0),
            ("<REC TIME=\"x1\" />", 11),
            ("<REC TIME=\"1.0\" FPOGV=\"2\" />", 23),
            ("<REC TIME \"1.0\" />", 9),
            ("<REC TIME=\"1.0 />", 10),
            ("<REC FPOGX=\"0.5\" />", 0),
        ];
        for (line, offset) in cases {
            let e = parse_line(line).expect_err(line);
            assert_eq!(e.offset, offset, "{line}: {e}");
        }
    }

    #[test]
    fn records_become_samples_in_host_time() {
        let mut d = RecordDecoder::new();
        let Line::Rec(r) = parse_line(
            "<REC TIME=\"10.000\" FPOGX=\"0.25\" FPOGY=\"0.75\" FPOGV=\"1\" LPCX=\"0.4\" LPCY=\"0.3\" LPD=\"15.2\" LPV=\"1\" RPD=\"0\" RPV=\"0\" LPMM=\"4.10\" LPMMV=\"1\" RPMM=\"0\" RPMMV=\"0\" />",
        )
        .unwrap() else {
            panic!()
        };
        d.push(&r, 100.0);
        let Some(Sample::Gaze(g)) = d.pop() else {
            panic!()
        };
        assert_eq!(
            (g.gaze_uv, g.confidence, g.t_secs),
            ([0.25, 0.75], 1.0, 100.0)
        );
        let Some(Sample::Pupil(right)) = d.pop() else {
            panic!()
        };
        assert_eq!(
            (right.eye, right.confidence, right.diameter_mm),
            (0, 0.0, None)
        );
        let Some(Sample::Pupil(left)) = d.pop() else {
            panic!()
        };
        assert_eq!(left.eye, 1);
        assert_eq!(left.unit, PupilUnit::Px);
        assert!((left.diameter_raw - 15.2).abs() < 1e-6);
        assert_eq!(left.diameter_mm, Some(4.1));
        assert!((left.norm_pos[1] - 0.7).abs() < 1e-6);
        assert!(d.pop().is_none());
        // 1/60 s later by the tracker clock, on time; another 1/60 s later,
        // arriving 5 ms late: host time follows the tracker clock, not the
        // arrival (the offset is the second-smallest arrival − time of the
        // last second, so the first record alone does not set it).
        for (time, arrival, want) in [
            ("10.01667", 100.01667, 100.01667),
            ("10.03333", 100.03833, 100.03333),
        ] {
            let line = format!("<REC TIME=\"{time}\" FPOGX=\"0.3\" FPOGY=\"0.3\" FPOGV=\"0\" />");
            let Line::Rec(r) = parse_line(&line).unwrap() else {
                panic!()
            };
            d.push(&r, arrival);
            let Some(Sample::Gaze(g)) = d.pop() else {
                panic!()
            };
            assert!((g.t_secs - want).abs() < 1e-9, "{} vs {want}", g.t_secs);
            assert_eq!(g.confidence, 0.0);
        }
        // One record with an absurd time gives no samples (counted).
        let Line::Rec(r) =
            parse_line("<REC TIME=\"1e308\" FPOGX=\"0.3\" FPOGY=\"0.3\" />").unwrap()
        else {
            panic!()
        };
        d.push(&r, 100.05);
        assert!(d.pop().is_none());
        assert_eq!(d.clock_stats().snapshot().rejected, 1);
    }
}
