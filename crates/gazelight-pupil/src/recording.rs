//! Recording and reading the raw Pupil stream in Pupil's own layout.
//!
//! Pupil Capture records each data stream as two files (Pupil Labs'
//! `file_methods.py`, `PLData_Writer`):
//!
//! - `<stream>.pldata`: a plain concatenation of msgpack arrays
//!   `[topic: str, payload: bin]`, where `payload` is the msgpack encoding
//!   of the datum map — exactly the bytes that came off the bus;
//! - `<stream>_timestamps.npy`: a NumPy `.npy` (format 1.0) 1-D array of
//!   little-endian float64 (`<f8`), the datums' `timestamp`s, one per
//!   record, in order.
//!
//! [`PldataWriter`] writes both incrementally. The `.npy` header is written
//! with a fixed size (128 bytes, padded with spaces as the format allows)
//! so that it can be rewritten in place with the current length on every
//! flush: at any moment after a flush both files describe every record
//! written so far, and Pupil Player / `numpy.load` can open them. Flushes
//! happen at least every [`FLUSH_INTERVAL`] while appending, on
//! [`PldataWriter::flush`], on close and on drop.
//!
//! [`PldataReader`] streams records through a bounded buffer without
//! loading the file, and decodes payloads in place with the live client's
//! zero-copy decoder ([`msg::decode_record_sample`]). Each topic keeps a
//! [`msg::ShapeCache`]: once one of its datums has decoded, the datums
//! with the same byte layout (in a Pupil Capture recording, those whose
//! keys, types, strings and integers repeat) are decoded by a masked
//! comparison with that datum and a few 8-byte loads, with the same result
//! as the walk. A record that does
//! not parse (bad marker, impossible length, a payload that is not one
//! complete msgpack map, a topic that is not printable ASCII) is skipped
//! with a counted warning naming the file and the byte offset; the reader then
//! resyncs on the next byte position where a well-formed record starts.
//! More than [`MAX_GARBAGE_BYTES`] of unreadable bytes in a row end the
//! stream with [`RecordingError::Garbage`], so garbage is refused after
//! reading about a megabyte of it, however large the file. A record cut off
//! by the end of the file ends the stream with a warning.

use std::fs::{File, OpenOptions};
use std::io::{BufWriter, Read, Seek, SeekFrom, Write};
use std::path::{Path, PathBuf};
use std::time::{Duration, Instant};

use crate::msg::{self, BadRecord, DecodeError, RecordScan, TopicKind};
use gazelight_eye::sample::Sample;

/// Longest time appended data may stay in memory buffers.
pub const FLUSH_INTERVAL: Duration = Duration::from_secs(1);

/// Size of the `.npy` header the writer reserves (magic to `\n`), a
/// multiple of 64 as the format requires.
pub const NPY_HEADER_LEN: usize = 128;

/// Largest record the reader accepts (Pupil datums are a few hundred
/// bytes; a larger length field means corruption).
pub const MAX_RECORD_BYTES: usize = 16 << 20;

/// Longest topic the reader accepts (Pupil's are a few dozen bytes).
pub const MAX_TOPIC_BYTES: usize = 1024;

/// Most consecutive bytes the reader skips before it gives up on a file
/// ([`RecordingError::Garbage`]): a real record is at most a few kB, so a
/// megabyte without one is not a `.pldata` file (or not one worth reading).
pub const MAX_GARBAGE_BYTES: u64 = 1 << 20;

/// Errors of recording and reading.
#[derive(Debug, thiserror::Error)]
pub enum RecordingError {
    #[error("{path}: {source}")]
    Io {
        path: PathBuf,
        #[source]
        source: std::io::Error,
    },
    /// A `.npy` file that is not a 1-D little-endian float64 array.
    #[error("{path}: not a float64 1-D .npy file: {reason}")]
    Npy { path: PathBuf, reason: String },
    /// A record whose payload does not decode as a Pupil datum.
    #[error("{path}: record at byte {offset}: {error}")]
    Decode {
        path: PathBuf,
        offset: u64,
        #[source]
        error: DecodeError,
    },
    /// More than [`MAX_GARBAGE_BYTES`] in a row hold no readable record.
    #[error(
        "{path}: no readable record in {bytes} bytes from byte {offset} ({first}); \
         not a .pldata file or corrupt beyond repair"
    )]
    Garbage {
        path: PathBuf,
        offset: u64,
        bytes: u64,
        /// Why the first of those bytes did not start a record.
        first: String,
    },
    /// A stream name that cannot be used as a file name.
    #[error("bad stream name `{0}` (use letters, digits, `_`, `-`, `.`)")]
    BadStreamName(String),
}

fn io_err(path: &Path) -> impl FnOnce(std::io::Error) -> RecordingError + '_ {
    move |source| RecordingError::Io {
        path: path.to_owned(),
        source,
    }
}

/// Paths of a stream's two files inside `dir`.
pub fn stream_paths(dir: &Path, stream: &str) -> (PathBuf, PathBuf) {
    (
        dir.join(format!("{stream}.pldata")),
        dir.join(format!("{stream}_timestamps.npy")),
    )
}

/// The `.npy` 1.0 header for a float64 vector of `len` elements, padded to
/// `total` bytes (a multiple of 64, ≥ 64).
pub fn npy_header(len: u64, total: usize) -> Vec<u8> {
    let dict = format!("{{'descr': '<f8', 'fortran_order': False, 'shape': ({len},), }}");
    let mut h = Vec::with_capacity(total);
    h.extend_from_slice(b"\x93NUMPY\x01\x00");
    let header_len = (total - 10) as u16;
    h.extend_from_slice(&header_len.to_le_bytes());
    h.extend_from_slice(dict.as_bytes());
    h.resize(total - 1, b' ');
    h.push(b'\n');
    h
}

/// Writes one stream (`<stream>.pldata` + `<stream>_timestamps.npy`).
pub struct PldataWriter {
    pldata_path: PathBuf,
    npy_path: PathBuf,
    pldata: BufWriter<File>,
    npy: File,
    /// Timestamps appended since the last flush.
    pending: Vec<f64>,
    /// Records on disk in the `.npy` (and flushed in the `.pldata`).
    flushed: u64,
    written: u64,
    last_flush: Instant,
    scratch: Vec<u8>,
    closed: bool,
}

impl PldataWriter {
    /// Creates (truncates) the two files of `stream` in `dir`.
    pub fn create(dir: &Path, stream: &str) -> Result<Self, RecordingError> {
        if stream.is_empty()
            || !stream
                .chars()
                .all(|c| c.is_ascii_alphanumeric() || matches!(c, '_' | '-' | '.'))
        {
            return Err(RecordingError::BadStreamName(stream.to_owned()));
        }
        let (pldata_path, npy_path) = stream_paths(dir, stream);
        let pldata = File::create(&pldata_path).map_err(io_err(&pldata_path))?;
        let mut npy = OpenOptions::new()
            .read(true)
            .write(true)
            .create(true)
            .truncate(true)
            .open(&npy_path)
            .map_err(io_err(&npy_path))?;
        npy.write_all(&npy_header(0, NPY_HEADER_LEN))
            .map_err(io_err(&npy_path))?;
        Ok(Self {
            pldata_path,
            npy_path,
            pldata: BufWriter::with_capacity(64 << 10, pldata),
            npy,
            pending: Vec::with_capacity(1024),
            flushed: 0,
            written: 0,
            last_flush: Instant::now(),
            scratch: Vec::with_capacity(1024),
            closed: false,
        })
    }

    /// Appends one datum: its topic, its msgpack payload (the datum map as
    /// it came off the bus) and its `timestamp`. Flushes when the last
    /// flush is older than [`FLUSH_INTERVAL`].
    pub fn append(
        &mut self,
        topic: &str,
        payload: &[u8],
        t_secs: f64,
    ) -> Result<(), RecordingError> {
        self.scratch.clear();
        self.scratch.push(0x92); // fixarray of 2
        write_str_header(&mut self.scratch, topic.len());
        self.scratch.extend_from_slice(topic.as_bytes());
        write_bin_header(&mut self.scratch, payload.len());
        self.pldata
            .write_all(&self.scratch)
            .and_then(|()| self.pldata.write_all(payload))
            .map_err(io_err(&self.pldata_path))?;
        self.pending.push(t_secs);
        self.written += 1;
        if self.last_flush.elapsed() >= FLUSH_INTERVAL {
            self.flush()?;
        }
        Ok(())
    }

    /// Flushes when the last flush is older than [`FLUSH_INTERVAL`] (call
    /// it from a timer when the stream may pause).
    pub fn flush_if_due(&mut self) -> Result<(), RecordingError> {
        if self.last_flush.elapsed() >= FLUSH_INTERVAL {
            self.flush()?;
        }
        Ok(())
    }

    /// Writes everything appended so far to both files and rewrites the
    /// `.npy` header with the new length.
    pub fn flush(&mut self) -> Result<(), RecordingError> {
        self.pldata.flush().map_err(io_err(&self.pldata_path))?;
        if !self.pending.is_empty() {
            let npy_err = io_err(&self.npy_path);
            let offset = NPY_HEADER_LEN as u64 + 8 * self.flushed;
            self.scratch.clear();
            for t in &self.pending {
                self.scratch.extend_from_slice(&t.to_le_bytes());
            }
            let n = self.pending.len() as u64;
            let header = npy_header(self.flushed + n, NPY_HEADER_LEN);
            let r = (|| {
                self.npy.seek(SeekFrom::Start(offset))?;
                self.npy.write_all(&self.scratch)?;
                self.npy.seek(SeekFrom::Start(0))?;
                self.npy.write_all(&header)?;
                self.npy.flush()
            })();
            r.map_err(npy_err)?;
            self.flushed += n;
            self.pending.clear();
        }
        self.last_flush = Instant::now();
        Ok(())
    }

    /// Records appended so far.
    pub fn len(&self) -> u64 {
        self.written
    }

    /// True when nothing has been appended.
    pub fn is_empty(&self) -> bool {
        self.written == 0
    }

    /// Flushes, syncs both files to disk and closes them; returns the
    /// number of records.
    pub fn close(mut self) -> Result<u64, RecordingError> {
        self.flush()?;
        self.pldata
            .get_ref()
            .sync_all()
            .map_err(io_err(&self.pldata_path))?;
        self.npy.sync_all().map_err(io_err(&self.npy_path))?;
        self.closed = true;
        Ok(self.written)
    }
}

impl Drop for PldataWriter {
    fn drop(&mut self) {
        if !self.closed
            && let Err(e) = self.flush()
        {
            tracing::error!(error = %e, "flushing recording on drop failed");
        }
    }
}

fn write_str_header(out: &mut Vec<u8>, len: usize) {
    if len < 32 {
        out.push(0xa0 | len as u8);
    } else if len < 256 {
        out.extend_from_slice(&[0xd9, len as u8]);
    } else if len < 65536 {
        out.push(0xda);
        out.extend_from_slice(&(len as u16).to_be_bytes());
    } else {
        out.push(0xdb);
        out.extend_from_slice(&(len as u32).to_be_bytes());
    }
}

fn write_bin_header(out: &mut Vec<u8>, len: usize) {
    if len < 256 {
        out.extend_from_slice(&[0xc4, len as u8]);
    } else if len < 65536 {
        out.push(0xc5);
        out.extend_from_slice(&(len as u16).to_be_bytes());
    } else {
        out.push(0xc6);
        out.extend_from_slice(&(len as u32).to_be_bytes());
    }
}

/// One record of a `.pldata` file.
#[derive(Clone, Debug, PartialEq)]
pub struct PldataRecord {
    /// Byte offset of the record in the file.
    pub offset: u64,
    pub topic: String,
    /// The msgpack-encoded datum.
    pub payload: Vec<u8>,
}

/// A record the reader skipped.
#[derive(Clone, Debug, PartialEq)]
pub struct SkippedRecord {
    /// Byte offset where the unreadable bytes start.
    pub offset: u64,
    /// Number of bytes skipped.
    pub bytes: u64,
    pub reason: String,
}

/// Bytes read from the file at a time (also the buffer's initial size):
/// small enough that the decoder reads them while they are still in the
/// core's cache (64 KiB measured ~15 % faster than 256 KiB here).
const READ_CHUNK_BYTES: usize = 64 << 10;

/// Streams the records of a `.pldata` file through a bounded buffer: it
/// holds [`READ_CHUNK_BYTES`], or one record when a record is larger (at
/// most [`MAX_TOPIC_BYTES`] + [`MAX_RECORD_BYTES`] + headers), whatever the
/// file's size.
pub struct PldataReader {
    path: PathBuf,
    file: File,
    /// The window; `buf[pos..end]` is read but not yet consumed.
    buf: Vec<u8>,
    pos: usize,
    end: usize,
    /// File offset of `buf[0]`.
    buf_offset: u64,
    eof: bool,
    skipped: Vec<SkippedRecord>,
    skipped_count: u64,
    finished: bool,
}

/// Keep at most this many skipped-record details (the count is exact).
const MAX_SKIPPED_DETAILS: usize = 1000;

impl PldataReader {
    /// Opens a `.pldata` file.
    pub fn open(path: &Path) -> Result<Self, RecordingError> {
        let file = gazelight_input::open(path).map_err(io_err(path))?;
        Ok(Self {
            path: path.to_owned(),
            file,
            buf: vec![0; READ_CHUNK_BYTES],
            pos: 0,
            end: 0,
            buf_offset: 0,
            eof: false,
            skipped: Vec::new(),
            skipped_count: 0,
            finished: false,
        })
    }

    /// The file being read.
    pub fn path(&self) -> &Path {
        &self.path
    }

    /// Number of bad regions skipped so far.
    pub fn skipped_count(&self) -> u64 {
        self.skipped_count
    }

    /// Details of skipped regions (the first 1000).
    pub fn skipped(&self) -> &[SkippedRecord] {
        &self.skipped
    }

    /// Makes `n` bytes available from `pos`; false at end of file. `n` is
    /// bounded by [`msg::scan_record`]'s limits, so the buffer is too.
    fn fill(&mut self, n: usize) -> Result<bool, RecordingError> {
        if self.end - self.pos >= n {
            return Ok(true);
        }
        if self.eof {
            return Ok(false);
        }
        if self.pos > 0 {
            self.buf.copy_within(self.pos..self.end, 0);
            self.end -= self.pos;
            self.buf_offset += self.pos as u64;
            self.pos = 0;
        }
        if self.buf.len() < n {
            self.buf.resize(n, 0);
        }
        while self.end < n {
            match self.file.read(&mut self.buf[self.end..]) {
                Ok(0) => {
                    self.eof = true;
                    return Ok(false);
                }
                Ok(got) => self.end += got,
                Err(e) if e.kind() == std::io::ErrorKind::Interrupted => {}
                Err(source) => {
                    return Err(RecordingError::Io {
                        path: self.path.clone(),
                        source,
                    });
                }
            }
        }
        Ok(true)
    }

    fn warn_skip(&mut self, offset: u64, bytes: u64, reason: String) {
        self.skipped_count += 1;
        tracing::warn!(
            file = %self.path.display(),
            offset,
            bytes,
            %reason,
            skipped = self.skipped_count,
            "skipping bad .pldata record"
        );
        if self.skipped.len() < MAX_SKIPPED_DETAILS {
            self.skipped.push(SkippedRecord {
                offset,
                bytes,
                reason,
            });
        }
    }

    /// Finds the next record and hands its topic and payload (borrowed
    /// from the buffer) to `accept`, which returns what to yield or why the
    /// record is corrupt after all. Corrupt bytes are skipped one offset at
    /// a time until a record frames and is accepted; more than
    /// [`MAX_GARBAGE_BYTES`] of them in a row end the stream with
    /// [`RecordingError::Garbage`].
    fn next_with<T>(
        &mut self,
        mut accept: impl FnMut(&[u8], &[u8]) -> Result<T, BadRecord>,
    ) -> Result<Option<(u64, T)>, RecordingError> {
        if self.finished {
            return Ok(None);
        }
        // Start of a bad region being skipped, and its first reason.
        let mut bad: Option<(u64, BadRecord)> = None;
        let mut need = 1;
        loop {
            if !self.fill(need)? {
                // End of file.
                let offset = self.buf_offset + self.pos as u64;
                let rest = (self.end - self.pos) as u64;
                self.finished = true;
                match bad.take() {
                    Some((start, first)) if offset + rest - start > MAX_GARBAGE_BYTES => {
                        return Err(RecordingError::Garbage {
                            path: self.path.clone(),
                            offset: start,
                            bytes: offset + rest - start,
                            first: first.to_string(),
                        });
                    }
                    Some((start, reason)) => {
                        self.warn_skip(start, offset + rest - start, reason.to_string());
                    }
                    None if rest > 0 => self.warn_skip(
                        offset,
                        rest,
                        "record cut off by the end of the file".to_owned(),
                    ),
                    None => {}
                }
                return Ok(None);
            }
            let offset = self.buf_offset + self.pos as u64;
            let b = &self.buf[self.pos..self.end];
            let verdict = match msg::scan_record(b, MAX_TOPIC_BYTES, MAX_RECORD_BYTES) {
                RecordScan::Need(n) => {
                    need = n;
                    continue;
                }
                RecordScan::Bad(why) => Err(why),
                // scan_record checked the topic is printable ASCII.
                RecordScan::Complete(s) => accept(
                    &b[s.topic_start..s.topic_end],
                    &b[s.payload_start..s.payload_end],
                )
                .map(|v| (v, s.payload_end)),
            };
            match verdict {
                Ok((value, len)) => {
                    self.pos += len;
                    if let Some((start, reason)) = bad.take() {
                        self.warn_skip(start, offset - start, reason.to_string());
                    }
                    return Ok(Some((offset, value)));
                }
                Err(why) => {
                    let start = bad.get_or_insert((offset, why)).0;
                    let bytes = offset + 1 - start;
                    if bytes > MAX_GARBAGE_BYTES {
                        self.finished = true;
                        let first = bad.map_or(why, |b| b.1);
                        return Err(RecordingError::Garbage {
                            path: self.path.clone(),
                            offset: start,
                            bytes,
                            first: first.to_string(),
                        });
                    }
                    self.pos += 1;
                    need = 1;
                }
            }
        }
    }

    fn next_record(&mut self) -> Result<Option<PldataRecord>, RecordingError> {
        let next = self.next_with(|topic, payload| {
            let topic = std::str::from_utf8(topic).map_err(|_| BadRecord::TopicNotPrintable)?;
            msg::check_payload(payload)?;
            Ok((topic.to_owned(), payload.to_vec()))
        })?;
        Ok(next.map(|(offset, (topic, payload))| PldataRecord {
            offset,
            topic,
            payload,
        }))
    }

    /// The records decoded as samples (Pupil time). Records with topics the
    /// decoder does not know (notifications, …) are skipped; records that
    /// fail to decode are `Err` items naming the file and offset, after
    /// which the iterator continues. Each payload is decoded in place in
    /// the reader's buffer by [`msg::decode_record_sample`] (the live
    /// client's decoder): no per-record allocation. A gaze datum's
    /// `base_data` (pupil datums, which `pupil.pldata` holds) are checked
    /// as msgpack but not decoded when the topic names the eyes.
    pub fn samples(self) -> PldataSamples {
        PldataSamples {
            reader: self,
            unknown_topics: 0,
            topics: Vec::new(),
        }
    }
}

impl Iterator for PldataReader {
    type Item = Result<PldataRecord, RecordingError>;
    fn next(&mut self) -> Option<Self::Item> {
        match self.next_record() {
            Ok(Some(r)) => Some(Ok(r)),
            Ok(None) => None,
            Err(e) => {
                self.finished = true;
                Some(Err(e))
            }
        }
    }
}

/// Iterator of [`Sample`]s from a `.pldata` file; see
/// [`PldataReader::samples`].
pub struct PldataSamples {
    reader: PldataReader,
    unknown_topics: u64,
    /// The topics seen so far with their classification (a file holds a
    /// handful), so that a record's topic is neither UTF-8 checked nor
    /// parsed again; at most [`MAX_CACHED_TOPICS`].
    topics: Vec<CachedTopic>,
}

/// Most distinct topics [`PldataSamples`] remembers; records with other
/// topics are classified one by one.
const MAX_CACHED_TOPICS: usize = 16;

/// A topic seen before and its classification.
struct CachedTopic {
    /// [`topic_fingerprint`] of `topic`.
    fingerprint: Option<(usize, u64, u64)>,
    topic: String,
    kind: TopicKind,
    /// The layout of the topic's datums, learnt from one that decoded.
    shape: msg::ShapeCache,
}

/// The length and the first and last 8 bytes of a topic of 8 to 16 bytes
/// (Pupil's, such as `pupil.0.3d` and `gaze.3d.01.`), which together are
/// the whole topic: two integer comparisons instead of a `memcmp` call.
#[inline]
fn topic_fingerprint(t: &[u8]) -> Option<(usize, u64, u64)> {
    if !(8..=16).contains(&t.len()) {
        return None;
    }
    let head = <[u8; 8]>::try_from(t.get(..8)?).ok()?;
    let tail = <[u8; 8]>::try_from(t.get(t.len() - 8..)?).ok()?;
    Some((t.len(), u64::from_le_bytes(head), u64::from_le_bytes(tail)))
}

/// Decodes one record's payload to a sample, looking its topic up in (or
/// adding it to) `topics`.
#[inline]
fn decode_cached(
    topics: &mut Vec<CachedTopic>,
    topic: &[u8],
    payload: &[u8],
) -> Result<Result<Option<Sample>, DecodeError>, BadRecord> {
    let fingerprint = topic_fingerprint(topic);
    let hit = match fingerprint {
        Some(f) => topics.iter_mut().find(|c| c.fingerprint == Some(f)),
        None => topics.iter_mut().find(|c| c.topic.as_bytes() == topic),
    };
    if let Some(c) = hit {
        return msg::decode_record_sample_shaped(c.kind, &c.topic, payload, &mut c.shape);
    }
    decode_uncached(topics, fingerprint, topic, payload)
}

#[inline(never)]
fn decode_uncached(
    topics: &mut Vec<CachedTopic>,
    fingerprint: Option<(usize, u64, u64)>,
    topic: &[u8],
    payload: &[u8],
) -> Result<Result<Option<Sample>, DecodeError>, BadRecord> {
    let t = std::str::from_utf8(topic).map_err(|_| BadRecord::TopicNotPrintable)?;
    let kind = msg::parse_topic(t);
    if topics.len() >= MAX_CACHED_TOPICS {
        // Not remembered, so no shape either: learning one costs a decode
        // per float, which only pays off over the topic's later datums.
        return msg::decode_record_sample_as(kind, t, payload);
    }
    let mut shape = msg::ShapeCache::default();
    let decoded = msg::decode_record_sample_shaped(kind, t, payload, &mut shape)?;
    // Only topics of well-formed records are remembered: garbage that
    // happens to frame as a record cannot fill the cache.
    topics.push(CachedTopic {
        fingerprint,
        topic: t.to_owned(),
        kind,
        shape,
    });
    Ok(decoded)
}

impl PldataSamples {
    /// The underlying reader (skip counts).
    pub fn reader(&self) -> &PldataReader {
        &self.reader
    }

    /// Records skipped for an unknown topic.
    pub fn unknown_topics(&self) -> u64 {
        self.unknown_topics
    }
}

impl Iterator for PldataSamples {
    type Item = Result<Sample, RecordingError>;
    fn next(&mut self) -> Option<Self::Item> {
        loop {
            let topics = &mut self.topics;
            let decoded = self
                .reader
                .next_with(|topic, payload| decode_cached(topics, topic, payload));
            let (offset, decoded) = match decoded {
                Ok(Some(r)) => r,
                Ok(None) => return None,
                Err(e) => {
                    self.reader.finished = true;
                    return Some(Err(e));
                }
            };
            match decoded {
                Ok(Some(s)) => return Some(Ok(s)),
                Ok(None) => self.unknown_topics += 1,
                Err(error) => {
                    return Some(Err(RecordingError::Decode {
                        path: self.reader.path.clone(),
                        offset,
                        error,
                    }));
                }
            }
        }
    }
}

/// Reads a `.npy` file holding a 1-D float64 array (formats 1.0–3.0,
/// little- or big-endian).
pub fn read_npy_f64(path: &Path) -> Result<Vec<f64>, RecordingError> {
    let bytes =
        gazelight_input::read(path, gazelight_input::MAX_SCENE_BYTES).map_err(io_err(path))?;
    parse_npy_f64(&bytes).map_err(|reason| RecordingError::Npy {
        path: path.to_owned(),
        reason,
    })
}

/// Parses `.npy` bytes; see [`read_npy_f64`].
pub(crate) fn parse_npy_f64(bytes: &[u8]) -> Result<Vec<f64>, String> {
    if bytes.len() < 10 || &bytes[..6] != b"\x93NUMPY" {
        return Err("missing \\x93NUMPY magic".to_owned());
    }
    let (header_len, start) = match bytes[6] {
        1 => (u16::from_le_bytes([bytes[8], bytes[9]]) as usize, 10),
        2 | 3 => {
            let b = bytes.get(8..12).ok_or("truncated header length")?;
            (u32::from_le_bytes([b[0], b[1], b[2], b[3]]) as usize, 12)
        }
        v => return Err(format!("unsupported format version {v}")),
    };
    let header = bytes
        .get(start..start + header_len)
        .ok_or("header longer than the file")?;
    let header = std::str::from_utf8(header).map_err(|_| "header is not text")?;
    if !(start + header_len).is_multiple_of(16) {
        return Err(format!(
            "data offset {} is not 16-aligned",
            start + header_len
        ));
    }
    let value_of = |key: &str| -> Result<&str, String> {
        let k = format!("'{key}':");
        let i = header.find(&k).ok_or(format!("header has no `{key}`"))?;
        Ok(header[i + k.len()..].trim_start())
    };
    let descr = value_of("descr")?;
    let big_endian = if descr.starts_with("'<f8'") {
        false
    } else if descr.starts_with("'>f8'") {
        true
    } else {
        return Err(format!(
            "descr is {}, expected '<f8'",
            descr.split(',').next().unwrap_or("")
        ));
    };
    if !value_of("fortran_order")?.starts_with("False") {
        return Err("fortran_order is not False".to_owned());
    }
    let shape = value_of("shape")?;
    let inner = shape
        .strip_prefix('(')
        .and_then(|s| s.split_once(')'))
        .map(|(s, _)| s)
        .ok_or("shape is not a tuple")?;
    let dims: Vec<&str> = inner
        .split(',')
        .map(str::trim)
        .filter(|s| !s.is_empty())
        .collect();
    let [n] = dims.as_slice() else {
        return Err(format!("shape ({inner}) is not 1-D"));
    };
    let n: usize = n
        .parse()
        .map_err(|_| format!("shape length `{n}` is not a number"))?;
    let data = &bytes[start + header_len..];
    let need = n.checked_mul(8).ok_or("shape too large")?;
    if data.len() < need {
        return Err(format!(
            "shape says {n} values but the file holds {}",
            data.len() / 8
        ));
    }
    Ok(data[..need]
        .chunks_exact(8)
        .map(|c| {
            let a = [c[0], c[1], c[2], c[3], c[4], c[5], c[6], c[7]];
            if big_endian {
                f64::from_be_bytes(a)
            } else {
                f64::from_le_bytes(a)
            }
        })
        .collect())
}

#[cfg(test)]
mod tests {
    use super::*;
    use gazelight_eye::sample::GazeEyes;

    fn tmpdir(name: &str) -> PathBuf {
        let d = std::env::temp_dir().join(format!("gazelight-rec-{name}-{}", std::process::id()));
        let _ = std::fs::remove_dir_all(&d);
        std::fs::create_dir_all(&d).unwrap();
        d
    }

    fn pupil_payload(eye: u8, t: f64, d: f64) -> Vec<u8> {
        use rmpv::Value as V;
        let v = V::Map(vec![
            (V::from("topic"), V::from(format!("pupil.{eye}.2d"))),
            (V::from("id"), V::from(eye)),
            (V::from("timestamp"), V::from(t)),
            (V::from("confidence"), V::from(0.9)),
            (V::from("diameter"), V::from(d)),
            (
                V::from("norm_pos"),
                V::Array(vec![V::from(0.5), V::from(0.4)]),
            ),
            (V::from("method"), V::from("2d c++")),
        ]);
        let mut b = Vec::new();
        rmpv::encode::write_value(&mut b, &v).unwrap();
        b
    }

    fn gaze_payload(t: f64) -> Vec<u8> {
        use rmpv::Value as V;
        let v = V::Map(vec![
            (V::from("timestamp"), V::from(t)),
            (V::from("confidence"), V::from(0.8)),
            (
                V::from("norm_pos"),
                V::Array(vec![V::from(0.2), V::from(0.9)]),
            ),
            (V::from("base_data"), V::Array(vec![])),
        ]);
        let mut b = Vec::new();
        rmpv::encode::write_value(&mut b, &v).unwrap();
        b
    }

    #[test]
    fn npy_header_follows_the_format_spec() {
        let h = npy_header(1234, NPY_HEADER_LEN);
        assert_eq!(h.len(), 128);
        assert_eq!(&h[..6], b"\x93NUMPY");
        assert_eq!((h[6], h[7]), (1, 0));
        // HEADER_LEN little-endian = total − 10; data starts 64-aligned.
        assert_eq!(u16::from_le_bytes([h[8], h[9]]) as usize, 128 - 10);
        assert_eq!(h.len() % 64, 0);
        let text = std::str::from_utf8(&h[10..]).unwrap();
        assert!(text.starts_with("{'descr': '<f8', 'fortran_order': False, 'shape': (1234,), }"));
        assert!(text.ends_with('\n'));
        assert!(text[..text.len() - 1].trim_end().ends_with('}'));
        // Largest possible length still fits.
        let h = npy_header(u64::MAX, NPY_HEADER_LEN);
        assert_eq!(h.len(), 128);
        assert_eq!(h[127], b'\n');
        // The reader accepts it and checks the data length.
        let mut f = npy_header(2, NPY_HEADER_LEN);
        f.extend_from_slice(&1.5f64.to_le_bytes());
        f.extend_from_slice(&(-2.0f64).to_le_bytes());
        assert_eq!(parse_npy_f64(&f).unwrap(), vec![1.5, -2.0]);
        f.truncate(f.len() - 1);
        assert!(parse_npy_f64(&f).unwrap_err().contains("holds 1"));
    }

    #[test]
    fn npy_reader_rejects_other_arrays() {
        let mk = |dict: &str| {
            let mut h = b"\x93NUMPY\x01\x00".to_vec();
            let mut d = dict.to_owned();
            while !(10 + d.len() + 1).is_multiple_of(64) {
                d.push(' ');
            }
            d.push('\n');
            h.extend_from_slice(&(d.len() as u16).to_le_bytes());
            h.extend_from_slice(d.as_bytes());
            h.extend_from_slice(&[0u8; 64]);
            h
        };
        assert!(
            parse_npy_f64(&mk(
                "{'descr': '<i8', 'fortran_order': False, 'shape': (2,), }"
            ))
            .unwrap_err()
            .contains("descr")
        );
        assert!(
            parse_npy_f64(&mk(
                "{'descr': '<f8', 'fortran_order': False, 'shape': (2, 2), }"
            ))
            .unwrap_err()
            .contains("1-D")
        );
        assert_eq!(
            parse_npy_f64(&mk(
                "{'descr': '>f8', 'fortran_order': False, 'shape': (1,), }"
            ))
            .unwrap(),
            vec![0.0]
        );
        assert!(
            parse_npy_f64(b"PK\x03\x04zipfile")
                .unwrap_err()
                .contains("magic")
        );
    }

    #[test]
    fn write_read_round_trip() {
        let dir = tmpdir("roundtrip");
        let mut w = PldataWriter::create(&dir, "pupil").unwrap();
        let mut expect = Vec::new();
        for i in 0..500 {
            let t = 1000.0 + i as f64 / 120.0;
            let eye = (i % 2) as u8;
            let topic = format!("pupil.{eye}.2d");
            let p = pupil_payload(eye, t, 30.0 + i as f64 * 0.01);
            w.append(&topic, &p, t).unwrap();
            expect.push((topic, p, t));
        }
        // A long topic and a long payload exercise the wider markers.
        let long_topic = format!("gaze.3d.01.{}", "x".repeat(40));
        w.append(&long_topic, &gaze_payload(2000.0), 2000.0)
            .unwrap();
        assert_eq!(w.close().unwrap(), 501);
        let (pl, npy) = stream_paths(&dir, "pupil");
        let ts = read_npy_f64(&npy).unwrap();
        assert_eq!(ts.len(), 501);
        let mut r = PldataReader::open(&pl).unwrap();
        for (i, (topic, p, t)) in expect.iter().enumerate() {
            let rec = r.next().unwrap().unwrap();
            assert_eq!(&rec.topic, topic);
            assert_eq!(&rec.payload, p);
            assert_eq!(ts[i], *t);
        }
        assert_eq!(r.next().unwrap().unwrap().topic, long_topic);
        assert!(r.next().is_none());
        assert_eq!(r.skipped_count(), 0);
        // As samples: the unknown long topic is skipped, the rest decoded.
        let mut s = PldataReader::open(&pl).unwrap().samples();
        let mut n = 0;
        for item in s.by_ref() {
            let Sample::Pupil(p) = item.unwrap() else {
                panic!()
            };
            assert_eq!(p.t_secs, expect[n].2);
            n += 1;
        }
        assert_eq!(n, 500);
        assert_eq!(s.unknown_topics(), 1);
        std::fs::remove_dir_all(&dir).unwrap();
    }

    #[test]
    fn flushes_make_data_visible_before_close_and_drop_finishes() {
        let dir = tmpdir("flush");
        let mut w = PldataWriter::create(&dir, "gaze").unwrap();
        w.append("gaze.3d.01.", &gaze_payload(1.0), 1.0).unwrap();
        w.flush().unwrap();
        let (pl, npy) = stream_paths(&dir, "gaze");
        assert_eq!(read_npy_f64(&npy).unwrap(), vec![1.0]);
        assert_eq!(PldataReader::open(&pl).unwrap().count(), 1);
        w.append("gaze.3d.01.", &gaze_payload(2.0), 2.0).unwrap();
        drop(w);
        assert_eq!(read_npy_f64(&npy).unwrap(), vec![1.0, 2.0]);
        let samples: Vec<_> = PldataReader::open(&pl).unwrap().samples().collect();
        assert_eq!(samples.len(), 2);
        let Ok(Sample::Gaze(g)) = &samples[1] else {
            panic!()
        };
        assert_eq!(g.eyes, GazeEyes::Binocular); // from the topic
        assert!(PldataWriter::create(&dir, "../escape").is_err());
        std::fs::remove_dir_all(&dir).unwrap();
    }

    #[test]
    fn corrupt_record_in_the_middle_is_skipped_with_file_and_offset() {
        let dir = tmpdir("corrupt");
        let mut w = PldataWriter::create(&dir, "pupil").unwrap();
        for i in 0..10 {
            let t = i as f64;
            w.append("pupil.0.2d", &pupil_payload(0, t, 20.0 + t), t)
                .unwrap();
        }
        w.close().unwrap();
        let (pl, _) = stream_paths(&dir, "pupil");
        let mut bytes = std::fs::read(&pl).unwrap();
        let offsets: Vec<u64> = PldataReader::open(&pl)
            .unwrap()
            .map(|r| r.unwrap().offset)
            .collect();
        // Record 4: clobber its header; record 7: corrupt its payload
        // (lengths intact, contents not msgpack).
        let o4 = offsets[4] as usize;
        bytes[o4] = 0xff;
        bytes[o4 + 1] = 0x00;
        let o7 = offsets[7] as usize;
        let payload_start = o7 + 1 + 1 + "pupil.0.2d".len() + 2;
        bytes[payload_start] = 0xc1; // never used in msgpack
        // And cut the last record short.
        bytes.truncate(bytes.len() - 5);
        std::fs::write(&pl, &bytes).unwrap();

        let mut r = PldataReader::open(&pl).unwrap();
        let got: Vec<u64> = r.by_ref().map(|x| x.unwrap().offset).collect();
        assert_eq!(
            got,
            vec![
                offsets[0], offsets[1], offsets[2], offsets[3], offsets[5], offsets[6], offsets[8]
            ]
        );
        assert_eq!(r.skipped_count(), 3);
        let sk = r.skipped();
        assert_eq!(sk[0].offset, offsets[4]);
        assert_eq!(sk[0].bytes, offsets[5] - offsets[4]);
        assert!(sk[0].reason.contains("0xff"), "{}", sk[0].reason);
        assert_eq!(sk[1].offset, offsets[7]);
        assert!(sk[1].reason.contains("payload"), "{}", sk[1].reason);
        assert_eq!(sk[2].offset, offsets[9]);
        assert!(sk[2].reason.contains("end of the file"));
        std::fs::remove_dir_all(&dir).unwrap();
    }

    /// Deterministic pseudo-random bytes (SplitMix64).
    fn random_bytes(n: usize, mut seed: u64) -> Vec<u8> {
        let mut out = Vec::with_capacity(n + 8);
        while out.len() < n {
            seed = seed.wrapping_add(0x9e37_79b9_7f4a_7c15);
            let mut z = seed;
            z = (z ^ (z >> 30)).wrapping_mul(0xbf58_476d_1ce4_e5b9);
            z = (z ^ (z >> 27)).wrapping_mul(0x94d0_49bb_1331_11eb);
            out.extend_from_slice(&(z ^ (z >> 31)).to_le_bytes());
        }
        out.truncate(n);
        out
    }

    /// A recording of `n` 2D pupil datums by the real writer; returns its
    /// bytes and the records' offsets.
    fn real_recording(dir: &Path, n: usize) -> (Vec<u8>, Vec<u64>) {
        let mut w = PldataWriter::create(dir, "pupil").unwrap();
        for i in 0..n {
            let t = 100.0 + i as f64 / 200.0;
            let eye = (i % 2) as u8;
            w.append(
                &format!("pupil.{eye}.2d"),
                &pupil_payload(eye, t, 30.0 + (i % 7) as f64),
                t,
            )
            .unwrap();
        }
        w.close().unwrap();
        let (pl, _) = stream_paths(dir, "pupil");
        let offsets = PldataReader::open(&pl)
            .unwrap()
            .map(|r| r.unwrap().offset)
            .collect();
        (std::fs::read(&pl).unwrap(), offsets)
    }

    #[test]
    fn random_bytes_are_refused_after_a_bounded_scan() {
        let dir = tmpdir("random");
        let (pl, _) = stream_paths(&dir, "pupil");
        std::fs::write(&pl, random_bytes(4 << 20, 13)).unwrap();
        let started = Instant::now();
        let mut r = PldataReader::open(&pl).unwrap();
        let e = r.next().unwrap().unwrap_err();
        let elapsed = started.elapsed();
        match &e {
            // Gave up just past the budget, a quarter of the way in.
            RecordingError::Garbage { offset, bytes, .. } => {
                assert_eq!(*offset, 0);
                assert_eq!(*bytes, MAX_GARBAGE_BYTES + 1);
            }
            other => panic!("{other:?}"),
        }
        let text = e.to_string();
        assert!(
            text.contains("pupil.pldata") && text.contains("no readable record"),
            "{text}"
        );
        assert!(r.next().is_none());
        // Generous: the scan is a few ms in a release build.
        assert!(elapsed < Duration::from_secs(10), "{elapsed:?}");
        // The same error through the samples iterator.
        let items: Vec<_> = PldataReader::open(&pl).unwrap().samples().collect();
        assert_eq!(items.len(), 1);
        assert!(matches!(items[0], Err(RecordingError::Garbage { .. })));
        std::fs::remove_dir_all(&dir).unwrap();
    }

    #[test]
    fn garbage_between_records_is_skipped_up_to_the_budget() {
        let dir = tmpdir("garbage-mid");
        let (orig, offsets) = real_recording(&dir, 200);
        let (pl, _) = stream_paths(&dir, "pupil");
        let at = offsets[120] as usize;
        // 256 KiB of garbage: skipped, every real record still read.
        let junk = random_bytes(256 << 10, 7);
        let mut bytes = orig[..at].to_vec();
        bytes.extend_from_slice(&junk);
        bytes.extend_from_slice(&orig[at..]);
        std::fs::write(&pl, &bytes).unwrap();
        let mut s = PldataReader::open(&pl).unwrap().samples();
        let items: Vec<_> = s.by_ref().collect();
        assert_eq!(items.len(), 200);
        assert!(items.iter().all(|x| x.is_ok()));
        let sk = s.reader().skipped();
        assert_eq!(sk.len(), 1);
        assert_eq!(sk[0].offset, at as u64);
        assert_eq!(sk[0].bytes, junk.len() as u64);
        // 2 MiB of garbage: the records before it, then an error naming
        // the file and where the garbage starts.
        let junk = random_bytes(2 << 20, 8);
        let mut bytes = orig[..at].to_vec();
        bytes.extend_from_slice(&junk);
        bytes.extend_from_slice(&orig[at..]);
        std::fs::write(&pl, &bytes).unwrap();
        let items: Vec<_> = PldataReader::open(&pl).unwrap().samples().collect();
        assert_eq!(items.len(), 121);
        assert!(items[..120].iter().all(|x| x.is_ok()));
        let e = items[120].as_ref().unwrap_err();
        assert!(
            matches!(e, RecordingError::Garbage { offset, .. } if *offset == at as u64),
            "{e:?}"
        );
        assert!(e.to_string().contains(&format!("from byte {at}")), "{e}");
        std::fs::remove_dir_all(&dir).unwrap();
    }

    #[test]
    fn huge_claimed_lengths_do_not_grow_the_buffer() {
        let dir = tmpdir("claims");
        let (pl, _) = stream_paths(&dir, "pupil");
        // A record claiming a 4 GiB payload, then a real record.
        let mut bytes = vec![0x92, 0xaa];
        bytes.extend_from_slice(b"pupil.0.2d");
        bytes.extend_from_slice(&[0xc6, 0xff, 0xff, 0xff, 0xff]);
        let (orig, _) = real_recording(&dir, 3);
        bytes.extend_from_slice(&orig);
        std::fs::write(&pl, &bytes).unwrap();
        let mut r = PldataReader::open(&pl).unwrap();
        assert_eq!(r.by_ref().count(), 3);
        assert_eq!(r.skipped_count(), 1);
        assert!(
            r.skipped()[0].reason.contains("exceeds"),
            "{:?}",
            r.skipped()
        );
        assert!(r.buf.len() <= READ_CHUNK_BYTES);
        std::fs::remove_dir_all(&dir).unwrap();
    }

    #[test]
    fn topics_beyond_the_cache_and_of_any_length_are_classified() {
        // More distinct topics than the reader caches, of lengths with and
        // without a fingerprint (v1 `pupil`, 5 bytes; 20+ bytes unknown).
        let dir = tmpdir("many-topics");
        let mut w = PldataWriter::create(&dir, "pupil").unwrap();
        for i in 0..40u32 {
            let t = f64::from(i);
            let eye = (i % 2) as u8;
            w.append(
                &format!("notify.custom_plugin_{i}"),
                &pupil_payload(eye, t, 3.0),
                t,
            )
            .unwrap();
            let topic = match i % 3 {
                0 => format!("pupil.{eye}.2d"),
                1 => "pupil".to_owned(),
                _ => format!("pupil.{eye}"),
            };
            w.append(&topic, &pupil_payload(eye, t, 3.0 + t), t)
                .unwrap();
        }
        w.close().unwrap();
        let mut samples = PldataReader::open(&dir.join("pupil.pldata"))
            .unwrap()
            .samples();
        let got: Vec<Sample> = samples.by_ref().map(|s| s.unwrap()).collect();
        assert_eq!(got.len(), 40);
        assert_eq!(samples.unknown_topics(), 40);
        for (i, s) in got.iter().enumerate() {
            let Sample::Pupil(p) = s else {
                panic!("{s:?}");
            };
            assert_eq!(p.eye as usize, i % 2);
            assert_eq!(p.diameter_raw, 3.0 + i as f32);
        }
    }

    #[test]
    fn decode_errors_in_samples_name_file_and_offset() {
        let dir = tmpdir("decode");
        let mut w = PldataWriter::create(&dir, "pupil").unwrap();
        w.append("pupil.0.2d", &pupil_payload(0, 1.0, 20.0), 1.0)
            .unwrap();
        // Well-formed msgpack, but the datum says eye 1 on an eye-0 topic.
        w.append("pupil.0.2d", &pupil_payload(1, 2.0, 20.0), 2.0)
            .unwrap();
        w.append("pupil.0.2d", &pupil_payload(0, 3.0, 20.0), 3.0)
            .unwrap();
        w.close().unwrap();
        let (pl, _) = stream_paths(&dir, "pupil");
        let items: Vec<_> = PldataReader::open(&pl).unwrap().samples().collect();
        assert_eq!(items.len(), 3);
        let e = items[1].as_ref().unwrap_err().to_string();
        assert!(
            e.contains("pupil.pldata") && e.contains("record at byte") && e.contains("`id`"),
            "{e}"
        );
        assert_eq!(items[2].as_ref().unwrap().t_secs(), 3.0);
        std::fs::remove_dir_all(&dir).unwrap();
    }
}
