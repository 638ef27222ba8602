//! The XDF container (XDF 1.0, <https://github.com/sccn/xdf/wiki/Specifications>):
//! the magic `XDF:`, then chunks `[NumLengthBytes: 1, 4 or 8][Length:
//! that many bytes, little-endian][Tag: u16][Content: Length − 2 bytes]`.
//!
//! | tag | chunk | content |
//! | --- | --- | --- |
//! | 1 | FileHeader | XML |
//! | 2 | StreamHeader | stream id u32, XML `<info>` |
//! | 3 | Samples | stream id u32, sample count (variable-length), samples |
//! | 4 | ClockOffset | stream id u32, collection time f64, offset f64 |
//! | 5 | Boundary | a 16-byte UUID |
//! | 6 | StreamFooter | stream id u32, XML `<info>` |
//!
//! A sample is `[TimeStampBytes: 0 or 8][TimeStamp: f64]` then the values:
//! `channel_count` little-endian numbers of the stream's format (int8,
//! int16, int32, int64, float32, double64) or, for `string`, one
//! variable-length byte count and that many bytes per channel. A sample
//! without a stamp is stamped with the stream's previous (raw) stamp plus
//! 1 / nominal rate (0 for an irregular stream), as pyxdf does.
//!
//! Every length is checked before it is used: a chunk must fit in the
//! bytes left in the file, an XML chunk in [`MAX_XML_BYTES`], a string in
//! its chunk and [`MAX_STRING_BYTES`], a sample count in its chunk (a
//! sample takes at least one byte per channel plus its stamp flag);
//! nothing is allocated from a size read from the file before that check.
//! An error names the chunk (its index from 0 and the byte offset where
//! it starts), so a truncated or damaged file says where it breaks.

use std::fs::File;
use std::io::{BufRead, BufReader, Read};
use std::path::{Path, PathBuf};

use super::clock::{ClockMap, Segments, truncate_corrupted};
use super::xml;
use crate::{ImportError, Position};

/// Largest XML chunk (file header, stream header or footer), bytes.
pub const MAX_XML_BYTES: u64 = 16 << 20;
/// Largest channel count of a stream.
pub const MAX_CHANNELS: usize = 1 << 16;
/// Largest string value, bytes.
pub const MAX_STRING_BYTES: u64 = 16 << 20;
/// Most streams in one file.
pub const MAX_STREAMS: usize = 4096;
/// Most clock offsets in one file (16 bytes each in memory).
pub const MAX_CLOCK_OFFSETS: usize = 1 << 20;
/// Most dejitter pieces of one stream (a piece starts at a gap > 1 s).
pub const MAX_SEGMENTS: usize = 1 << 20;
/// Largest plausible |time stamp| and |clock offset|, s: the import's
/// own bound on any time ([`crate::time_guard::MAX_ABS_T_SECS`], about 317
/// years). A stamp or offset beyond it (or not finite) is left out of the
/// clock fits and the dejitter lines, and counted.
pub const MAX_CLOCK_SECS: f64 = crate::time_guard::MAX_ABS_T_SECS;

/// Whether `t` is a time the clock fits may use.
pub fn plausible_time(t: f64) -> bool {
    t.is_finite() && t.abs() <= MAX_CLOCK_SECS
}

const MAGIC: &[u8; 4] = b"XDF:";

/// A channel value format.
#[derive(Clone, Copy, Debug, PartialEq, Eq, serde::Serialize)]
#[serde(rename_all = "snake_case")]
pub enum ChannelFormat {
    Int8,
    Int16,
    Int32,
    Int64,
    Float32,
    Double64,
    String,
}

impl ChannelFormat {
    fn parse(s: &str) -> Option<Self> {
        Some(match s {
            "int8" => Self::Int8,
            "int16" => Self::Int16,
            "int32" => Self::Int32,
            "int64" => Self::Int64,
            "float32" => Self::Float32,
            "double64" => Self::Double64,
            "string" => Self::String,
            _ => return None,
        })
    }

    /// Bytes per value (strings: the least a value can take, its length
    /// prefix byte and a 1-byte length).
    fn value_bytes(self) -> usize {
        match self {
            Self::Int8 => 1,
            Self::Int16 => 2,
            Self::Int32 | Self::Float32 => 4,
            Self::Int64 | Self::Double64 => 8,
            Self::String => 2,
        }
    }

    /// The name used in the stream header.
    pub fn name(self) -> &'static str {
        match self {
            Self::Int8 => "int8",
            Self::Int16 => "int16",
            Self::Int32 => "int32",
            Self::Int64 => "int64",
            Self::Float32 => "float32",
            Self::Double64 => "double64",
            Self::String => "string",
        }
    }
}

/// One channel's description from `<desc><channels><channel>`.
#[derive(Clone, Debug, Default, PartialEq, serde::Serialize)]
pub struct ChannelInfo {
    pub label: String,
    pub unit: String,
    /// `<type>` (the Gaze Meta Data's `ScreenX`, `Diameter`, …).
    pub kind: String,
    /// `<eye>` where given (`left`, `right`, `both`).
    pub eye: String,
}

/// What the file says about one stream.
#[derive(Clone, Debug, serde::Serialize)]
pub struct StreamInfo {
    /// The stream id of the chunks.
    pub id: u32,
    pub name: String,
    /// `<type>`: `Gaze`, `EEG`, `Markers`, …
    pub kind: String,
    pub channel_count: usize,
    pub nominal_srate_hz: f64,
    pub format: ChannelFormat,
    /// One per channel where the header describes them (may be empty).
    pub channels: Vec<ChannelInfo>,
    /// `<desc><manufacturer>` where given.
    pub manufacturer: String,
    /// `<desc><synchronization><can_drop_samples>` is `true`: no dejitter.
    pub can_drop_samples: bool,
    /// Samples in the file (the Samples chunks' counts).
    pub sample_count: u64,
    /// The footer's `sample_count`, when there is a footer.
    pub footer_sample_count: Option<u64>,
    /// (collection time, offset) of the ClockOffset chunks, s.
    #[serde(skip)]
    pub clock_offsets: Vec<(f64, f64)>,
    /// Samples read (the rest dropped with a corrupted last clock offset,
    /// as pyxdf does); `sample_count` when nothing is dropped.
    pub samples_kept: u64,
    /// Clock ranges the offsets split into (1 + clock resets; 0: none).
    pub clock_ranges: usize,
    /// ClockOffset chunks left out of the clock fit: a collection time or
    /// an offset that is not a finite number within ±[`MAX_CLOCK_SECS`]
    /// (NaN, ±inf, 1e308). Counted, never fitted: one such value would
    /// make every synced stamp of the stream NaN.
    pub clock_offsets_skipped: u64,
    #[serde(skip)]
    clock: ClockMap,
}

impl StreamInfo {
    /// The channel labels (empty strings where the header names none).
    pub fn labels(&self) -> Vec<String> {
        (0..self.channel_count)
            .map(|k| {
                self.channels
                    .get(k)
                    .map_or_else(String::new, |c| c.label.clone())
            })
            .collect()
    }

    /// Whether the stream's time stamps are dejittered (a nominal rate and
    /// no `can_drop_samples`).
    pub fn dejittered(&self) -> bool {
        self.nominal_srate_hz > 0.0 && !self.can_drop_samples
    }
}

/// An XDF file's streams, read in one pass over its chunk headers (sample
/// chunks are skipped, not read).
#[derive(Clone, Debug)]
pub struct XdfFile {
    pub path: PathBuf,
    pub streams: Vec<StreamInfo>,
    /// Chunks in the file.
    pub chunks: u64,
    pub file_len: u64,
}

/// Chunk tags.
const TAG_FILE_HEADER: u16 = 1;
const TAG_STREAM_HEADER: u16 = 2;
const TAG_SAMPLES: u16 = 3;
const TAG_CLOCK_OFFSET: u16 = 4;
const TAG_BOUNDARY: u16 = 5;
const TAG_STREAM_FOOTER: u16 = 6;

fn tag_name(tag: u16) -> &'static str {
    match tag {
        TAG_FILE_HEADER => "FileHeader",
        TAG_STREAM_HEADER => "StreamHeader",
        TAG_SAMPLES => "Samples",
        TAG_CLOCK_OFFSET => "ClockOffset",
        TAG_BOUNDARY => "Boundary",
        TAG_STREAM_FOOTER => "StreamFooter",
        _ => "unknown",
    }
}

/// A chunk's framing.
#[derive(Clone, Copy, Debug)]
struct Chunk {
    index: u64,
    /// Byte offset of its length prefix.
    offset: u64,
    tag: u16,
    /// Byte offset just past its end.
    end: u64,
}

/// A buffered file with its position, and where each chunk starts.
struct Cursor {
    path: PathBuf,
    r: BufReader<File>,
    pos: u64,
    len: u64,
    chunk: Option<Chunk>,
    chunks: u64,
}

impl Cursor {
    fn open(path: &Path) -> Result<Self, ImportError> {
        let f = gazelight_input::open(path).map_err(|source| ImportError::Io {
            path: path.to_owned(),
            source,
        })?;
        let len = f
            .metadata()
            .map_err(|source| ImportError::Io {
                path: path.to_owned(),
                source,
            })?
            .len();
        let mut c = Self {
            path: path.to_owned(),
            r: BufReader::with_capacity(64 << 10, f),
            pos: 0,
            len,
            chunk: None,
            chunks: 0,
        };
        let mut magic = [0u8; 4];
        if len < 4 || c.read_exact(&mut magic).is_err() || &magic != MAGIC {
            return Err(ImportError::Structure {
                path: path.to_owned(),
                position: Position::Byte(0),
                reason: "not an XDF file: it does not start with the magic `XDF:`".into(),
            });
        }
        Ok(c)
    }

    fn io(&self, source: std::io::Error) -> ImportError {
        ImportError::Io {
            path: self.path.clone(),
            source,
        }
    }

    /// An error about the current chunk: "chunk N (Tag) at byte X: …".
    fn err(&self, reason: impl std::fmt::Display) -> ImportError {
        match self.chunk {
            Some(c) => ImportError::Structure {
                path: self.path.clone(),
                position: Position::Byte(c.offset),
                reason: if c.tag == 0 {
                    format!("chunk {}: {reason}", c.index)
                } else {
                    format!("chunk {} ({}): {reason}", c.index, tag_name(c.tag))
                },
            },
            None => ImportError::Structure {
                path: self.path.clone(),
                position: Position::Byte(self.pos),
                reason: reason.to_string(),
            },
        }
    }

    fn read_exact(&mut self, buf: &mut [u8]) -> std::io::Result<()> {
        self.r.read_exact(buf)?;
        self.pos += buf.len() as u64;
        Ok(())
    }

    /// Reads `buf.len()` bytes of the current chunk.
    fn take(&mut self, buf: &mut [u8], what: &str) -> Result<(), ImportError> {
        let end = self.chunk.map_or(self.len, |c| c.end);
        if self.pos + buf.len() as u64 > end {
            return Err(self.err(format_args!(
                "{what} at byte {} runs past the chunk's end (byte {end})",
                self.pos
            )));
        }
        match self.read_exact(buf) {
            Ok(()) => Ok(()),
            Err(e) if e.kind() == std::io::ErrorKind::UnexpectedEof => Err(self.err(format_args!(
                "the file ends inside {what} (byte {}): truncated",
                self.pos
            ))),
            Err(e) => Err(self.io(e)),
        }
    }

    fn u8(&mut self, what: &str) -> Result<u8, ImportError> {
        let mut b = [0u8; 1];
        self.take(&mut b, what)?;
        Ok(b[0])
    }

    fn u32(&mut self, what: &str) -> Result<u32, ImportError> {
        let mut b = [0u8; 4];
        self.take(&mut b, what)?;
        Ok(u32::from_le_bytes(b))
    }

    fn f64(&mut self, what: &str) -> Result<f64, ImportError> {
        let mut b = [0u8; 8];
        self.take(&mut b, what)?;
        Ok(f64::from_le_bytes(b))
    }

    /// A variable-length integer: a byte 1, 4 or 8, then that many bytes.
    fn varlen(&mut self, what: &str) -> Result<u64, ImportError> {
        let n = self.u8(what)?;
        match n {
            1 => Ok(u64::from(self.u8(what)?)),
            4 => Ok(u64::from(self.u32(what)?)),
            8 => {
                let mut b = [0u8; 8];
                self.take(&mut b, what)?;
                Ok(u64::from_le_bytes(b))
            }
            other => Err(self.err(format_args!(
                "{what}: the length-size byte at byte {} is {other}, not 1, 4 or 8",
                self.pos - 1
            ))),
        }
    }

    /// Skips `n` bytes of the current chunk.
    fn skip(&mut self, n: u64, what: &str) -> Result<(), ImportError> {
        let end = self.chunk.map_or(self.len, |c| c.end);
        if self.pos + n > end {
            return Err(self.err(format_args!(
                "{what} at byte {} runs past the chunk's end (byte {end})",
                self.pos
            )));
        }
        let mut left = n;
        while left > 0 {
            let avail = match self.r.fill_buf() {
                Ok(buf) => buf.len(),
                Err(e) => return Err(self.io(e)),
            };
            if avail == 0 {
                return Err(self.err(format_args!(
                    "the file ends inside {what} (byte {}): truncated",
                    self.pos
                )));
            }
            let step = (avail as u64).min(left) as usize;
            self.r.consume(step);
            self.pos += step as u64;
            left -= step as u64;
        }
        Ok(())
    }

    /// Moves to the end of the current chunk and reads the next chunk's
    /// framing; `None` at the end of the file.
    fn next_chunk(&mut self) -> Result<Option<Chunk>, ImportError> {
        if let Some(c) = self.chunk {
            let left = c.end - self.pos.min(c.end);
            self.skip(left, "the rest of the chunk")?;
        }
        self.chunk = None;
        if self.pos >= self.len {
            return Ok(None);
        }
        let offset = self.pos;
        let index = self.chunks;
        // Name the chunk in errors from its first byte on.
        self.chunk = Some(Chunk {
            index,
            offset,
            tag: 0,
            end: self.len,
        });
        let len = self.varlen("the chunk's length")?;
        let left = self.len - self.pos;
        if len < 2 {
            return Err(self.err(format_args!("length {len} is too short to hold a tag")));
        }
        // The tag names the chunk in the errors that follow, when the file
        // still holds it.
        let mut tag = [0u8; 2];
        self.take(&mut tag, "the chunk's tag")?;
        let tag = u16::from_le_bytes(tag);
        self.chunk = Some(Chunk {
            index,
            offset,
            tag,
            end: self.len,
        });
        if len > left {
            return Err(self.err(format_args!(
                "length {len} runs past the end of the file ({left} bytes left after the \
                 length field): the file is truncated or the length is damaged"
            )));
        }
        let end = self.pos - 2 + len;
        let c = Chunk {
            index,
            offset,
            tag,
            end,
        };
        self.chunk = Some(c);
        self.chunks += 1;
        Ok(Some(c))
    }

    /// The rest of the current chunk as XML text (at most `MAX_XML_BYTES`).
    fn xml(&mut self) -> Result<xml::Element, ImportError> {
        let end = self.chunk.map_or(self.len, |c| c.end);
        let n = end - self.pos;
        if n > MAX_XML_BYTES {
            return Err(self.err(format_args!(
                "{n} bytes of XML, more than the {MAX_XML_BYTES} a header may have"
            )));
        }
        let mut buf = vec![0u8; n as usize];
        self.take(&mut buf, "the XML")?;
        let text = String::from_utf8_lossy(&buf);
        // A header keeps no more channel entries than it declares (a list
        // of 250 000 under `channel_count` 1 was parsed ~8× its text).
        let keep = declared_channels(&text)
            .unwrap_or(MAX_CHANNELS)
            .min(MAX_CHANNELS);
        let cap = xml::ListCap {
            list: "channels",
            keep,
        };
        xml::parse_capped(&text, Some(cap))
            .map_err(|e| self.err(format_args!("its XML is broken: {e}")))
    }
}

/// The `<channel_count>` a header's text declares, read before it is
/// parsed (the parse keeps no more channel entries than this).
fn declared_channels(text: &str) -> Option<usize> {
    const OPEN: &str = "<channel_count>";
    let start = text.find(OPEN)? + OPEN.len();
    let len = text[start..].find('<')?;
    text[start..start + len].trim().parse().ok()
}

fn parse_header(id: u32, x: &xml::Element) -> Result<StreamInfo, String> {
    if x.name != "info" {
        return Err(format!("the root element is <{}>, not <info>", x.name));
    }
    let field = |n: &str| x.text_of(n).unwrap_or("");
    let channel_count: usize = field("channel_count")
        .parse()
        .map_err(|_| format!("channel_count `{}` is not a count", field("channel_count")))?;
    if channel_count > MAX_CHANNELS {
        return Err(format!(
            "{channel_count} channels, more than the {MAX_CHANNELS} accepted"
        ));
    }
    let nominal_srate_hz: f64 = field("nominal_srate")
        .parse()
        .ok()
        .filter(|r: &f64| r.is_finite() && *r >= 0.0)
        .ok_or_else(|| format!("nominal_srate `{}` is not a rate", field("nominal_srate")))?;
    let format = ChannelFormat::parse(field("channel_format")).ok_or_else(|| {
        format!(
            "channel_format `{}` is none of int8, int16, int32, int64, float32, double64, string",
            field("channel_format")
        )
    })?;
    let desc = x.child("desc");
    let channels = desc
        .and_then(|d| d.child("channels"))
        .map(|cs| {
            cs.children_named("channel")
                .map(|c| ChannelInfo {
                    label: c.text_of("label").unwrap_or("").to_owned(),
                    unit: c.text_of("unit").unwrap_or("").to_owned(),
                    kind: c.text_of("type").unwrap_or("").to_owned(),
                    eye: c.text_of("eye").unwrap_or("").to_owned(),
                })
                .collect()
        })
        .unwrap_or_default();
    let can_drop_samples = desc
        .and_then(|d| d.at(&["synchronization", "can_drop_samples"]))
        .is_some_and(|e| e.text.trim().eq_ignore_ascii_case("true"));
    Ok(StreamInfo {
        id,
        name: field("name").to_owned(),
        kind: field("type").to_owned(),
        channel_count,
        nominal_srate_hz,
        format,
        channels,
        manufacturer: desc
            .and_then(|d| d.text_of("manufacturer"))
            .unwrap_or("")
            .to_owned(),
        can_drop_samples,
        sample_count: 0,
        footer_sample_count: None,
        clock_offsets: Vec::new(),
        samples_kept: 0,
        clock_ranges: 0,
        clock_offsets_skipped: 0,
        clock: ClockMap::default(),
    })
}

impl XdfFile {
    /// Reads the file's chunk framing, stream headers, footers and clock
    /// offsets (the sample chunks' counts, not their samples).
    pub fn scan(path: &Path) -> Result<Self, ImportError> {
        let mut c = Cursor::open(path)?;
        let mut streams: Vec<StreamInfo> = Vec::new();
        let mut offsets_total = 0usize;
        while let Some(chunk) = c.next_chunk()? {
            match chunk.tag {
                TAG_FILE_HEADER => {
                    c.xml()?;
                }
                TAG_STREAM_HEADER => {
                    let id = c.u32("the stream id")?;
                    let x = c.xml()?;
                    let info = parse_header(id, &x)
                        .map_err(|e| c.err(format_args!("stream {id}'s header: {e}")))?;
                    if streams.iter().any(|s| s.id == id) {
                        return Err(c.err(format_args!("a second header for stream {id}")));
                    }
                    if streams.len() >= MAX_STREAMS {
                        return Err(c.err(format_args!("more than {MAX_STREAMS} streams")));
                    }
                    streams.push(info);
                }
                TAG_SAMPLES => {
                    let id = c.u32("the stream id")?;
                    let Some(s) = streams.iter_mut().find(|s| s.id == id) else {
                        return Err(c.err(format_args!(
                            "samples of stream {id}, which has no StreamHeader before them"
                        )));
                    };
                    let n = c.varlen("the sample count")?;
                    let left = chunk.end - c.pos;
                    let min_sample = 1 + s.channel_count as u64 * s.format.value_bytes() as u64;
                    if n.saturating_mul(min_sample) > left {
                        return Err(c.err(format_args!(
                            "{n} samples of stream {id} cannot fit in the chunk's {left} bytes \
                             left: the count is damaged"
                        )));
                    }
                    s.sample_count += n;
                }
                TAG_CLOCK_OFFSET => {
                    let id = c.u32("the stream id")?;
                    let t = c.f64("the collection time")?;
                    let v = c.f64("the offset")?;
                    let Some(s) = streams.iter_mut().find(|s| s.id == id) else {
                        return Err(c.err(format_args!(
                            "a clock offset of stream {id}, which has no StreamHeader before it"
                        )));
                    };
                    if offsets_total >= MAX_CLOCK_OFFSETS {
                        return Err(c.err(format_args!(
                            "more than {MAX_CLOCK_OFFSETS} clock offsets in the file"
                        )));
                    }
                    offsets_total += 1;
                    if plausible_time(t) && plausible_time(v) {
                        s.clock_offsets.push((t, v));
                    } else {
                        s.clock_offsets_skipped += 1;
                    }
                }
                TAG_STREAM_FOOTER => {
                    let id = c.u32("the stream id")?;
                    let x = c.xml()?;
                    let count = x
                        .text_of("sample_count")
                        .and_then(|v| v.parse::<u64>().ok());
                    if let Some(s) = streams.iter_mut().find(|s| s.id == id) {
                        s.footer_sample_count = count;
                    }
                }
                // Boundary chunks and tags this reader does not know are
                // skipped (their length is checked like any chunk's).
                _ => {}
            }
        }
        for s in &mut streams {
            s.samples_kept = s.sample_count;
            if s.sample_count > 0 {
                if let Some(n) =
                    truncate_corrupted(&mut s.clock_offsets, s.sample_count, s.footer_sample_count)
                {
                    s.samples_kept = n;
                }
                s.clock = ClockMap::fit(&s.clock_offsets);
                s.clock_ranges = s.clock.ranges();
            }
        }
        Ok(Self {
            path: path.to_owned(),
            streams,
            chunks: c.chunks,
            file_len: c.len,
        })
    }

    /// Streams the samples of `self.streams[index]` with pyxdf's time
    /// stamps (clock offsets applied, dejittered where pyxdf dejitters).
    /// Reads the file twice: once for the stamps (to fit the dejitter
    /// lines, and to find a damaged sample before the first is handed
    /// out), once for the samples.
    pub fn samples(&self, index: usize) -> Result<StreamSamples, ImportError> {
        let info = self
            .streams
            .get(index)
            .ok_or_else(|| ImportError::Structure {
                path: self.path.clone(),
                position: Position::File,
                reason: format!("no stream {index} (the file has {})", self.streams.len()),
            })?;
        let mut segments = info
            .dejittered()
            .then(|| Segments::new(info.nominal_srate_hz));
        // First pass: every stamp (values skipped), checked.
        let mut pass = StreamSamples::new(self, info)?;
        pass.skip_values = true;
        let mut i = 0u64;
        let mut implausible = 0u64;
        while let Some(t) = pass.next_raw()? {
            if !plausible_time(t) {
                // Left out of the dejitter line (one NaN would make the
                // whole piece NaN); the line gives it a time by its index.
                implausible += 1;
                i += 1;
                continue;
            }
            if let Some(s) = segments.as_mut() {
                s.learn(i, t, MAX_SEGMENTS).map_err(|max| {
                    pass.cursor.err(format_args!(
                        "stream {} breaks into more than {max} pieces (gaps > 1 s)",
                        info.id
                    ))
                })?;
            }
            i += 1;
        }
        let mut out = StreamSamples::new(self, info)?;
        out.segments = segments;
        out.implausible_stamps = implausible;
        Ok(out)
    }
}

/// One stream's samples, streamed: [`StreamSamples::next_sample`] gives
/// each sample's time stamp and leaves its values in
/// [`StreamSamples::numeric`] or [`StreamSamples::text`].
pub struct StreamSamples {
    info: StreamInfo,
    cursor: Cursor,
    /// The clock range of the last stamp.
    range: usize,
    segments: Option<Segments>,
    /// Samples left in the current Samples chunk.
    left_in_chunk: u64,
    /// The stream's last plausible raw stamp (0 before the first) and
    /// the samples since it, for samples without a stamp.
    last_raw: f64,
    since_raw: u64,
    /// Samples whose stamp (raw, or synced) is not a plausible time
    /// (found by the first pass of [`XdfFile::samples`]).
    implausible_stamps: u64,
    /// Samples handed out.
    index: u64,
    skip_values: bool,
    raw: Vec<u8>,
    numeric: Vec<f64>,
    text: Vec<String>,
}

impl StreamSamples {
    fn new(file: &XdfFile, info: &StreamInfo) -> Result<Self, ImportError> {
        let cursor = Cursor::open(&file.path)?;
        let n = info.channel_count;
        Ok(Self {
            info: info.clone(),
            cursor,
            range: 0,
            segments: None,
            left_in_chunk: 0,
            last_raw: 0.0,
            since_raw: 0,
            implausible_stamps: 0,
            index: 0,
            skip_values: false,
            raw: vec![0u8; n * info.format.value_bytes()],
            numeric: vec![
                0.0;
                if info.format == ChannelFormat::String {
                    0
                } else {
                    n
                }
            ],
            text: vec![
                String::new();
                if info.format == ChannelFormat::String {
                    n
                } else {
                    0
                }
            ],
        })
    }

    /// The stream.
    pub fn info(&self) -> &StreamInfo {
        &self.info
    }

    /// The numeric values of the last sample (empty for a string stream).
    pub fn numeric(&self) -> &[f64] {
        &self.numeric
    }

    /// The string values of the last sample (empty for a numeric stream).
    pub fn text(&self) -> &[String] {
        &self.text
    }

    /// Samples whose time stamp is not a finite time within
    /// ±[`MAX_CLOCK_SECS`] (NaN, ±inf, 1e308): left out of the dejitter
    /// fit. In a dejittered stream such a sample gets its piece's line
    /// time at its index (as every sample does); in another it keeps its
    /// stamp, and the import's time guard skips and counts it.
    pub fn implausible_stamps(&self) -> u64 {
        self.implausible_stamps
    }

    /// Where the last sample's chunk starts, byte offset.
    pub fn position(&self) -> Position {
        self.cursor
            .chunk
            .map_or(Position::File, |c| Position::Byte(c.offset))
    }

    /// The next sample's synced, dejittered time stamp, s; `None` after
    /// the last.
    pub fn next_sample(&mut self) -> Result<Option<f64>, ImportError> {
        let i = self.index;
        let Some(t) = self.next_raw()? else {
            return Ok(None);
        };
        Ok(Some(match self.segments.as_mut() {
            Some(s) => s.apply(i, t),
            None => t,
        }))
    }

    /// The next sample with its synced (not dejittered) stamp.
    fn next_raw(&mut self) -> Result<Option<f64>, ImportError> {
        if self.index >= self.info.samples_kept {
            return Ok(None);
        }
        while self.left_in_chunk == 0 {
            let Some(chunk) = self.cursor.next_chunk()? else {
                return Err(self.cursor.err(format_args!(
                    "the file ends after {} of stream {}'s {} samples",
                    self.index, self.info.id, self.info.samples_kept
                )));
            };
            if chunk.tag != TAG_SAMPLES {
                continue;
            }
            if self.cursor.u32("the stream id")? != self.info.id {
                continue;
            }
            self.left_in_chunk = self.cursor.varlen("the sample count")?;
        }
        let c = &mut self.cursor;
        let raw_t = match c.u8("a sample's stamp flag")? {
            0 => self.last_raw + self.info.tdiff() * (self.since_raw + 1) as f64,
            8 => c.f64("a sample's time stamp")?,
            other => {
                return Err(c.err(format_args!(
                    "sample {} of stream {}: stamp size byte {other} at byte {} is neither 0 nor 8",
                    self.index,
                    self.info.id,
                    c.pos - 1
                )));
            }
        };
        if plausible_time(raw_t) {
            self.last_raw = raw_t;
            self.since_raw = 0;
        } else {
            self.since_raw += 1;
        }
        self.read_values()?;
        self.left_in_chunk -= 1;
        if self.left_in_chunk == 0 {
            // The chunk's samples must end where the chunk does.
            let c = &self.cursor;
            if let Some(ch) = c.chunk
                && c.pos != ch.end
            {
                return Err(c.err(format_args!(
                    "its samples end at byte {}, the chunk at byte {}",
                    c.pos, ch.end
                )));
            }
        }
        self.index += 1;
        Ok(Some(self.info.clock.correct(&mut self.range, raw_t)))
    }

    fn read_values(&mut self) -> Result<(), ImportError> {
        let n = self.info.channel_count;
        let fmt = self.info.format;
        let c = &mut self.cursor;
        if fmt == ChannelFormat::String {
            for k in 0..n {
                let len = c.varlen("a string's length")?;
                let end = c.chunk.map_or(c.len, |ch| ch.end);
                if len > MAX_STRING_BYTES || c.pos + len > end {
                    return Err(c.err(format_args!(
                        "channel {k}: a string of {len} bytes at byte {} does not fit in the \
                         chunk (ends at byte {end}) or is over {MAX_STRING_BYTES} bytes",
                        c.pos
                    )));
                }
                if self.skip_values {
                    c.skip(len, "a string")?;
                } else {
                    let mut buf = vec![0u8; len as usize];
                    c.take(&mut buf, "a string")?;
                    self.text[k] = String::from_utf8_lossy(&buf).into_owned();
                }
            }
            return Ok(());
        }
        let bytes = n * fmt.value_bytes();
        if self.skip_values {
            return c.skip(bytes as u64, "a sample's values");
        }
        c.take(&mut self.raw[..bytes], "a sample's values")?;
        let w = fmt.value_bytes();
        for (k, v) in self.numeric.iter_mut().enumerate() {
            let b = &self.raw[k * w..(k + 1) * w];
            *v = match fmt {
                ChannelFormat::Int8 => f64::from(b[0] as i8),
                ChannelFormat::Int16 => f64::from(i16::from_le_bytes([b[0], b[1]])),
                ChannelFormat::Int32 => f64::from(i32::from_le_bytes([b[0], b[1], b[2], b[3]])),
                ChannelFormat::Int64 => {
                    i64::from_le_bytes([b[0], b[1], b[2], b[3], b[4], b[5], b[6], b[7]]) as f64
                }
                ChannelFormat::Float32 => f64::from(f32::from_le_bytes([b[0], b[1], b[2], b[3]])),
                ChannelFormat::Double64 => {
                    f64::from_le_bytes([b[0], b[1], b[2], b[3], b[4], b[5], b[6], b[7]])
                }
                ChannelFormat::String => f64::NAN,
            };
        }
        Ok(())
    }
}

impl StreamInfo {
    /// The nominal sample interval, s (0 for an irregular stream).
    fn tdiff(&self) -> f64 {
        if self.nominal_srate_hz > 0.0 {
            1.0 / self.nominal_srate_hz
        } else {
            0.0
        }
    }
}
