//! Decoding of Pupil Core Network API messages (msgpack datums) and
//! encoding of notifications.
//!
//! Pupil Capture / Service publish every datum as a multipart ZeroMQ
//! message `[topic, msgpack map, (extra binary frames)…]`. The topics this
//! module understands, current (v2/v3) and legacy (v1.x) names:
//!
//! | topic | datum |
//! | --- | --- |
//! | `pupil.0.2d`, `pupil.1.2d` | 2D detector: `diameter` (eye-camera px), `confidence`, `norm_pos`, `timestamp`, `ellipse`, `id`, `method` |
//! | `pupil.0.3d`, `pupil.1.3d` | 3D model (pye3d): the 2D fields plus `diameter_3d` (mm), `model_confidence`, `circle_3d`, `theta`, `phi` |
//! | `pupil.0`, `pupil.1`, `pupil` | v1.x names; the method then comes from the datum's `method` string |
//! | `gaze.3d.01.`, `gaze.2d.01.` | binocular gaze with two `base_data` pupil datums |
//! | `gaze.3d.0.`, `gaze.3d.1.`, `gaze.2d.0.`, `gaze.2d.1.` | monocular gaze (Pupil falls back to one eye when the other's confidence is below 0.6) |
//! | `gaze` | v1.x name; the eyes come from `base_data` |
//!
//! Pupil's `norm_pos` has its origin at the bottom-left; gaze samples are
//! converted to gazelight's top-left `gaze_uv` (u = x, v = 1 − y). Pupil
//! samples keep the eye-image `norm_pos` as reported (see
//! [`PupilSample::norm_pos`]).
//!
//! Decoding walks the msgpack bytes with a zero-copy cursor (no
//! intermediate value tree, no heap allocation for a well-formed datum;
//! nesting of skipped values is bounded at 32 levels).
//! Fields Pupil is known to send but gazelight does not use (`sphere`,
//! `projected_sphere`, `location`, `model_id`, `gaze_point_3d`, …) are
//! skipped silently; any other key is skipped and counted in
//! [`PupilDatum::unknown_fields`] / [`GazeDatum::unknown_fields`]. A field
//! with the wrong type is an error naming the field
//! (e.g. `base_data[1].confidence`).
//!
//! Recordings hold long runs of datums with one layout per topic;
//! [`decode_record_sample_shaped`] decodes those through a learnt
//! [`ShapeCache`] (see the `shape` module) with the walk's result.

use gazelight_eye::sample::{DetectorMethod, GazeEyes, GazeSample, PupilSample, PupilUnit, Sample};

mod shape;
pub use shape::{ShapeCache, decode_record_sample_shaped};

/// Why a message could not be decoded.
#[derive(Debug, Clone, PartialEq, thiserror::Error)]
pub enum DecodeError {
    /// The topic frame is not one of the topics listed in the module docs.
    #[error("unknown topic `{0}`")]
    UnknownTopic(String),
    /// The topic frame is not UTF-8.
    #[error("topic frame is not UTF-8 ({len} bytes)")]
    TopicNotUtf8 { len: usize },
    /// The message has no payload frame.
    #[error("message with topic `{topic}` has no payload frame")]
    MissingPayload { topic: String },
    /// A field has the wrong type or an impossible value.
    #[error("topic `{topic}`: field `{field}`: {reason}")]
    Field {
        topic: String,
        field: String,
        reason: String,
    },
    /// A required field is absent.
    #[error("topic `{topic}`: missing field `{field}`")]
    MissingField { topic: String, field: &'static str },
    /// The payload is not a well-formed msgpack map (truncated, corrupt,
    /// or another type).
    #[error("topic `{topic}`: malformed msgpack payload: {reason}")]
    Malformed { topic: String, reason: String },
}

impl DecodeError {
    /// True for [`DecodeError::UnknownTopic`] (counted separately from
    /// malformed messages by the client).
    pub fn is_unknown_topic(&self) -> bool {
        matches!(self, DecodeError::UnknownTopic(_))
    }
}

/// What a topic string announces.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum TopicKind {
    /// A pupil datum; `eye` and `method` when the topic names them.
    Pupil {
        eye: Option<u8>,
        method: Option<DetectorMethod>,
    },
    /// A gaze datum; `eyes` when the topic names them.
    Gaze { eyes: Option<GazeEyes> },
    /// Anything else.
    Unknown,
}

/// Classifies a topic (current and v1.x names, trailing dot optional).
pub fn parse_topic(topic: &str) -> TopicKind {
    // The topics Pupil Capture v2/v3 publishes, without splitting.
    let pupil = |eye, m| TopicKind::Pupil {
        eye: Some(eye),
        method: Some(m),
    };
    match topic {
        "pupil.0.2d" => return pupil(0, DetectorMethod::Pupil2d),
        "pupil.1.2d" => return pupil(1, DetectorMethod::Pupil2d),
        "pupil.0.3d" => return pupil(0, DetectorMethod::Pupil3d),
        "pupil.1.3d" => return pupil(1, DetectorMethod::Pupil3d),
        "gaze.3d.01." | "gaze.2d.01." => {
            return TopicKind::Gaze {
                eyes: Some(GazeEyes::Binocular),
            };
        }
        _ => {}
    }
    let mut parts = topic.split('.');
    let head = parts.next().unwrap_or("");
    let rest: [Option<&str>; 3] = [parts.next(), parts.next(), parts.next()];
    // A trailing dot yields one empty part; more parts than that are unknown.
    let extra = parts.next();
    fn norm(p: Option<&str>) -> Option<&str> {
        p.filter(|s| !s.is_empty())
    }
    match head {
        "pupil" => {
            if extra.is_some() || norm(rest[2]).is_some() {
                return TopicKind::Unknown;
            }
            let eye = match norm(rest[0]) {
                None => None,
                Some("0") => Some(0),
                Some("1") => Some(1),
                Some(_) => return TopicKind::Unknown,
            };
            let method = match norm(rest[1]) {
                None => None,
                Some("2d") => Some(DetectorMethod::Pupil2d),
                Some("3d") => Some(DetectorMethod::Pupil3d),
                Some(_) => return TopicKind::Unknown,
            };
            if eye.is_none() && method.is_some() {
                return TopicKind::Unknown;
            }
            TopicKind::Pupil { eye, method }
        }
        "gaze" => {
            if extra.is_some() || norm(rest[2]).is_some() {
                return TopicKind::Unknown;
            }
            match (norm(rest[0]), norm(rest[1])) {
                (None, None) => TopicKind::Gaze { eyes: None },
                (Some("2d" | "3d"), eyes) => {
                    let eyes = match eyes {
                        None => None,
                        Some("01") => Some(GazeEyes::Binocular),
                        Some("0") => Some(GazeEyes::Right),
                        Some("1") => Some(GazeEyes::Left),
                        Some(_) => return TopicKind::Unknown,
                    };
                    TopicKind::Gaze { eyes }
                }
                _ => TopicKind::Unknown,
            }
        }
        _ => TopicKind::Unknown,
    }
}

/// Pupil's 2D ellipse fit in eye-image pixels.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct Ellipse {
    pub center: [f64; 2],
    pub axes: [f64; 2],
    pub angle: f64,
}

/// The 3D model's pupil circle in eye-camera coordinates (mm).
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct Circle3d {
    pub center: [f64; 3],
    pub normal: [f64; 3],
    pub radius: f64,
}

/// A decoded pupil datum: the [`PupilSample`] (in Pupil time) plus the
/// detector details gazelight keeps.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct PupilDatum {
    pub sample: PupilSample,
    pub ellipse: Option<Ellipse>,
    /// 3D only: confidence of the eye model, 0..=1.
    pub model_confidence: Option<f32>,
    /// 3D only: the pupil circle.
    pub circle_3d: Option<Circle3d>,
    /// 3D only: polar angles of the pupil normal, radians.
    pub theta: Option<f32>,
    pub phi: Option<f32>,
    /// Keys in the map that are neither used nor known Pupil fields.
    pub unknown_fields: u32,
}

/// A decoded gaze datum: the [`GazeSample`] (in Pupil time) plus the
/// pupil datums it was computed from (`base_data`), indexed by eye id.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct GazeDatum {
    pub sample: GazeSample,
    pub base: [Option<PupilSample>; 2],
    /// Keys in the map that are neither used nor known Pupil fields.
    pub unknown_fields: u32,
}

/// A decoded datum.
#[derive(Clone, Copy, Debug, PartialEq)]
pub enum Datum {
    Pupil(PupilDatum),
    Gaze(GazeDatum),
}

impl Datum {
    /// The datum's `timestamp`, in Pupil time (seconds).
    pub fn timestamp(&self) -> f64 {
        match self {
            Datum::Pupil(p) => p.sample.t_secs,
            Datum::Gaze(g) => g.sample.t_secs,
        }
    }

    /// The sample, with its time shifted by `-offset_secs` (Pupil time →
    /// host time when `offset_secs = pupil − host`).
    pub fn to_sample(&self, offset_secs: f64) -> Sample {
        match self {
            Datum::Pupil(p) => {
                let mut s = p.sample;
                s.t_secs -= offset_secs;
                Sample::Pupil(s)
            }
            Datum::Gaze(g) => {
                let mut s = g.sample;
                s.t_secs -= offset_secs;
                Sample::Gaze(s)
            }
        }
    }

    /// The sample at time `t_secs` (its host time, from the source's
    /// clock mapping).
    pub fn sample_at(&self, t_secs: f64) -> Sample {
        let mut s = match self {
            Datum::Pupil(p) => Sample::Pupil(p.sample),
            Datum::Gaze(g) => Sample::Gaze(g.sample),
        };
        s.set_t_secs(t_secs);
        s
    }

    /// Unknown keys skipped while decoding.
    pub fn unknown_fields(&self) -> u32 {
        match self {
            Datum::Pupil(p) => p.unknown_fields,
            Datum::Gaze(g) => g.unknown_fields,
        }
    }
}

/// Decodes one message given its topic frame and first payload frame.
/// Extra frames (Pupil attaches raw images to some topics) are the
/// caller's to ignore.
pub fn decode_message(topic: &[u8], payload: &[u8]) -> Result<Datum, DecodeError> {
    let topic =
        std::str::from_utf8(topic).map_err(|_| DecodeError::TopicNotUtf8 { len: topic.len() })?;
    decode(topic, payload)
}

/// Decodes a datum with a UTF-8 topic.
pub fn decode(topic: &str, payload: &[u8]) -> Result<Datum, DecodeError> {
    decode_as(parse_topic(topic), topic, payload)
}

/// Decodes a datum whose topic has already been classified
/// (`kind == parse_topic(topic)`).
pub fn decode_as(kind: TopicKind, topic: &str, payload: &[u8]) -> Result<Datum, DecodeError> {
    let wrap = |f: Fail| f.into_error(topic);
    match kind {
        TopicKind::Unknown => Err(DecodeError::UnknownTopic(topic.to_owned())),
        TopicKind::Pupil { eye, method } => {
            let mut c = Cur { b: payload, p: 0 };
            let raw = read_pupil(&mut c, 0).map_err(wrap)?;
            c.end().map_err(wrap)?;
            raw.finish(topic, eye, method).map(Datum::Pupil)
        }
        TopicKind::Gaze { eyes } => decode_gaze(topic, payload, eyes, true).map(Datum::Gaze),
    }
}

/// Decodes a gaze datum; with `decode_base` false (only when the topic
/// names the eyes) its `base_data` are walked as msgpack but not decoded
/// and the datum's `base` is empty.
fn decode_gaze(
    topic: &str,
    payload: &[u8],
    eyes: Option<GazeEyes>,
    decode_base: bool,
) -> Result<GazeDatum, DecodeError> {
    let wrap = |f: Fail| f.into_error(topic);
    let mut c = Cur { b: payload, p: 0 };
    let raw = read_gaze(&mut c, decode_base || eyes.is_none()).map_err(wrap)?;
    c.end().map_err(wrap)?;
    raw.finish(topic, eyes)
}

/// Deepest nesting a skipped value may have.
const MAX_DEPTH: usize = 32;

/// Total size in bytes of a value whose marker alone gives it (nil,
/// booleans, integers, floats, fixstr, fixext), or 0 for the other markers
/// (maps, arrays, sized str / bin / ext, and the invalid `0xc1`).
static SCALAR_SIZE: [u8; 256] = {
    let mut t = [0u8; 256];
    let mut m = 0;
    while m < 256 {
        t[m] = match m as u8 {
            0x00..=0x7f | 0xe0..=0xff | 0xc0 | 0xc2 | 0xc3 => 1,
            0xa0..=0xbf => 1 + (m as u8 & 0x1f),
            0xcc | 0xd0 => 2,
            0xcd | 0xd1 => 3,
            0xce | 0xd2 | 0xca => 5,
            0xcf | 0xd3 | 0xcb => 9,
            0xd4 => 3,
            0xd5 => 4,
            0xd6 => 6,
            0xd7 => 10,
            0xd8 => 18,
            _ => 0,
        };
        m += 1;
    }
    t
};

/// Why the msgpack walk stopped.
enum Fail {
    Truncated {
        at: usize,
    },
    Invalid {
        at: usize,
        marker: u8,
    },
    TooDeep {
        at: usize,
    },
    Trailing {
        at: usize,
    },
    /// A value of the wrong type (or shape) in a named field (boxed, so
    /// that `Fail`, and the `Result`s of the hot path, stay two words).
    Type(Box<TypeFail>),
}

/// See [`Fail::Type`]; `path` is the enclosing field (e.g. `base_data[1]`),
/// empty at the top level.
struct TypeFail {
    path: String,
    field: &'static str,
    expected: &'static str,
    found: &'static str,
}

#[cold]
fn type_err(field: &'static str, expected: &'static str, found: &'static str) -> Fail {
    Fail::Type(Box::new(TypeFail {
        path: String::new(),
        field,
        expected,
        found,
    }))
}

impl Fail {
    fn in_path(self, prefix: &str) -> Fail {
        match self {
            Fail::Type(mut t) => {
                t.path = if t.path.is_empty() {
                    prefix.to_owned()
                } else {
                    format!("{prefix}.{}", t.path)
                };
                Fail::Type(t)
            }
            other => other,
        }
    }

    fn into_error(self, topic: &str) -> DecodeError {
        let malformed = |reason: String| DecodeError::Malformed {
            topic: topic.to_owned(),
            reason,
        };
        match self {
            Fail::Truncated { at } => malformed(format!("truncated at byte {at}")),
            Fail::Invalid { at, marker } => {
                malformed(format!("invalid marker 0x{marker:02x} at byte {at}"))
            }
            Fail::TooDeep { at } => {
                malformed(format!("nesting deeper than {MAX_DEPTH} at byte {at}"))
            }
            Fail::Trailing { at } => {
                malformed(format!("trailing bytes after the datum at byte {at}"))
            }
            Fail::Type(t) => t.into_error(topic),
        }
    }
}

impl TypeFail {
    fn into_error(self, topic: &str) -> DecodeError {
        let TypeFail {
            path,
            field,
            expected,
            found,
        } = self;
        match field {
            "" => {
                if path.is_empty() {
                    DecodeError::Malformed {
                        topic: topic.to_owned(),
                        reason: format!("payload is {found}, expected {expected}"),
                    }
                } else {
                    DecodeError::Field {
                        topic: topic.to_owned(),
                        field: path,
                        reason: format!("expected {expected}, found {found}"),
                    }
                }
            }
            field => DecodeError::Field {
                topic: topic.to_owned(),
                field: if path.is_empty() {
                    field.to_owned()
                } else {
                    format!("{path}.{field}")
                },
                reason: format!("expected {expected}, found {found}"),
            },
        }
    }
}

fn type_fail(field: &'static str, expected: &'static str, marker: u8) -> Fail {
    type_err(field, expected, marker_name(marker))
}

fn marker_name(m: u8) -> &'static str {
    match m {
        0x00..=0x7f | 0xe0..=0xff | 0xcc..=0xd3 => "an integer",
        0x80..=0x8f | 0xde | 0xdf => "a map",
        0x90..=0x9f | 0xdc | 0xdd => "an array",
        0xa0..=0xbf | 0xd9..=0xdb => "a string",
        0xc0 => "nil",
        0xc2 | 0xc3 => "a boolean",
        0xc4..=0xc6 => "binary data",
        0xca | 0xcb => "a float",
        0xc7..=0xc9 | 0xd4..=0xd8 => "an extension value",
        _ => "an invalid marker",
    }
}

/// A zero-copy msgpack cursor.
struct Cur<'a> {
    b: &'a [u8],
    p: usize,
}

impl<'a> Cur<'a> {
    #[inline]
    fn byte(&mut self) -> Result<u8, Fail> {
        let v = *self.b.get(self.p).ok_or(Fail::Truncated { at: self.p })?;
        self.p += 1;
        Ok(v)
    }

    #[inline]
    fn take(&mut self, n: usize) -> Result<&'a [u8], Fail> {
        let end = self.p.checked_add(n).filter(|e| *e <= self.b.len());
        let end = end.ok_or(Fail::Truncated { at: self.b.len() })?;
        let s = &self.b[self.p..end];
        self.p = end;
        Ok(s)
    }

    #[inline]
    fn uint(&mut self, width: usize) -> Result<u64, Fail> {
        Ok(self
            .take(width)?
            .iter()
            .fold(0u64, |a, x| (a << 8) | u64::from(*x)))
    }

    fn end(&self) -> Result<(), Fail> {
        if self.p == self.b.len() {
            Ok(())
        } else {
            Err(Fail::Trailing { at: self.p })
        }
    }

    /// Length of a map whose marker is `m`, or `None` if it is not a map.
    #[inline]
    fn map_len(&mut self, m: u8) -> Result<Option<usize>, Fail> {
        Ok(match m {
            0x80..=0x8f => Some((m & 0x0f) as usize),
            0xde => Some(self.uint(2)? as usize),
            0xdf => Some(self.uint(4)? as usize),
            _ => None,
        })
    }

    #[inline]
    fn array_len(&mut self, m: u8) -> Result<Option<usize>, Fail> {
        Ok(match m {
            0x90..=0x9f => Some((m & 0x0f) as usize),
            0xdc => Some(self.uint(2)? as usize),
            0xdd => Some(self.uint(4)? as usize),
            _ => None,
        })
    }

    #[inline]
    fn str_len(&mut self, m: u8) -> Result<Option<usize>, Fail> {
        Ok(match m {
            0xa0..=0xbf => Some((m & 0x1f) as usize),
            0xd9 => Some(self.uint(1)? as usize),
            0xda => Some(self.uint(2)? as usize),
            0xdb => Some(self.uint(4)? as usize),
            _ => None,
        })
    }

    /// The length of a `.pldata` record's topic or payload (a str or bin
    /// value), at most `max`; the cursor is left on its first byte.
    #[inline]
    fn str_or_bin(&mut self, field: RecordField, max: usize) -> Result<usize, RecordScan> {
        let start = self.p;
        let m = self.byte().map_err(|_| RecordScan::Need(start + 1))?;
        let width = match m {
            0xa0..=0xbf => 0,
            0xd9 | 0xc4 => 1,
            0xda | 0xc5 => 2,
            0xdb | 0xc6 => 4,
            marker => {
                return Err(RecordScan::Bad(BadRecord::NotStrOrBin { field, marker }));
            }
        };
        let len = if width == 0 {
            (m & 0x1f) as usize
        } else {
            self.uint(width)
                .map_err(|_| RecordScan::Need(start + 1 + width))? as usize
        };
        if len > max {
            return Err(RecordScan::Bad(BadRecord::TooLong { field, len, max }));
        }
        Ok(len)
    }

    /// A map key: `Some(bytes)` for a string key (compared as bytes, so
    /// no UTF-8 validation on the hot path), `None` (key skipped) for any
    /// other key.
    #[inline(always)]
    fn key(&mut self) -> Result<Option<&'a [u8]>, Fail> {
        // Pupil's keys are short strings (fixstr): inline that case.
        if let Some(&m) = self.b.get(self.p)
            && m & 0xe0 == 0xa0
        {
            let start = self.p + 1;
            if let Some(k) = self.b.get(start..start + (m & 0x1f) as usize) {
                self.p = start + k.len();
                return Ok(Some(k));
            }
        }
        self.key_slow()
    }

    #[inline(never)]
    fn key_slow(&mut self) -> Result<Option<&'a [u8]>, Fail> {
        let at = self.p;
        let m = self.byte()?;
        match self.str_len(m)? {
            Some(n) => Ok(Some(self.take(n)?)),
            None => {
                self.p = at;
                self.skip(0)?;
                Ok(None)
            }
        }
    }

    /// A number (any msgpack int or float) as f64.
    #[inline(always)]
    fn f64(&mut self, field: &'static str) -> Result<f64, Fail> {
        // Pupil's numbers are float64 (0xcb) nearly always: inline that
        // case, before the jump table of the other markers.
        if let Some(&[0xcb, a, b, c, d, e, f, g, h]) = self.b.get(self.p..self.p + 9) {
            self.p += 9;
            return Ok(f64::from_be_bytes([a, b, c, d, e, f, g, h]));
        }
        self.f64_slow(field)
    }

    #[inline(never)]
    fn f64_slow(&mut self, field: &'static str) -> Result<f64, Fail> {
        let m = self.byte()?;
        Ok(match m {
            0xcb => f64::from_bits(self.uint(8)?),
            0xca => f64::from(f32::from_bits(self.uint(4)? as u32)),
            0x00..=0x7f => f64::from(m),
            0xe0..=0xff => f64::from(m as i8),
            0xcc => self.uint(1)? as f64,
            0xcd => self.uint(2)? as f64,
            0xce => self.uint(4)? as f64,
            0xcf => self.uint(8)? as f64,
            0xd0 => f64::from(self.uint(1)? as u8 as i8),
            0xd1 => f64::from(self.uint(2)? as u16 as i16),
            0xd2 => f64::from(self.uint(4)? as u32 as i32),
            0xd3 => self.uint(8)? as i64 as f64,
            0xc1 => {
                return Err(Fail::Invalid {
                    at: self.p - 1,
                    marker: m,
                });
            }
            _ => return Err(type_fail(field, "a number", m)),
        })
    }

    /// A fixed-length array of numbers.
    #[inline]
    fn f64s<const N: usize>(&mut self, field: &'static str) -> Result<[f64; N], Fail> {
        let m = self.byte()?;
        match self.array_len(m)? {
            Some(n) if n == N => {
                let mut out = [0.0; N];
                for v in &mut out {
                    *v = self.f64(field)?;
                }
                Ok(out)
            }
            Some(_) => Err(type_err(
                field,
                if N == 2 {
                    "an array of 2 numbers"
                } else {
                    "an array of 3 numbers"
                },
                "an array of another length",
            )),
            None => Err(type_fail(field, "an array of numbers", m)),
        }
    }

    /// A small unsigned integer (eye id).
    fn u8_value(&mut self, field: &'static str) -> Result<u8, Fail> {
        let v = self.f64(field)?;
        if v.fract() == 0.0 && (0.0..=255.0).contains(&v) {
            Ok(v as u8)
        } else {
            Err(type_err(field, "an integer 0..=255", "another number"))
        }
    }

    /// A string's bytes, checked to be UTF-8 (ASCII, the usual case, is
    /// recognised without the full validation).
    #[inline]
    fn str_value(&mut self, field: &'static str) -> Result<&'a [u8], Fail> {
        let m = self.byte()?;
        match self.str_len(m)? {
            Some(n) => {
                let s = self.take(n)?;
                if s.is_ascii() || std::str::from_utf8(s).is_ok() {
                    Ok(s)
                } else {
                    Err(type_err(field, "a UTF-8 string", "invalid UTF-8"))
                }
            }
            None => Err(type_fail(field, "a string", m)),
        }
    }

    /// Skips one value of any type at nesting `depth` (values deeper than
    /// [`MAX_DEPTH`] are refused).
    ///
    /// Most values are skipped by [`Self::skip_fast`]; whatever it does not
    /// settle (an error, or nesting that might exceed the limit) is walked
    /// again from the same byte by [`Self::skip_values`], which gives the
    /// exact error.
    #[inline]
    fn skip(&mut self, depth: usize) -> Result<(), Fail> {
        if depth <= MAX_DEPTH && self.skip_fast(MAX_DEPTH - depth) {
            return Ok(());
        }
        self.skip_values(1, depth)
    }

    /// Skips one value with a single counter of values still to skip (each
    /// value read takes one off, a map or array adds its entries), which
    /// msgpack's prefix encoding allows, and a table of the values whose
    /// size their marker alone gives. Returns false, with the cursor
    /// unmoved, when the value is truncated or invalid, or when it holds
    /// more than `budget` non-empty maps and arrays (so that its nesting
    /// cannot exceed the budget when this returns true).
    #[inline]
    fn skip_fast(&mut self, mut budget: usize) -> bool {
        let b = self.b;
        let mut p = self.p;
        let mut rem: usize = 1;
        while rem > 0 {
            let Some(&m) = b.get(p) else {
                return false;
            };
            rem -= 1;
            // Branches for the markers nearly all of Pupil's bytes are
            // (float64, short strings, small maps and arrays): a predicted
            // branch lets the next value's position be computed ahead, a
            // table lookup would chain two loads per value.
            if m == 0xcb {
                p += 9;
                continue;
            }
            if m & 0xe0 == 0xa0 {
                p += 1 + (m & 0x1f) as usize;
                continue;
            }
            let children = if m & 0xe0 == 0x80 {
                // fixmap (0x80..=0x8f): 2 values per entry; fixarray
                // (0x90..=0x9f): 1.
                p += 1;
                let n = (m & 0x0f) as usize;
                if m < 0x90 { 2 * n } else { n }
            } else {
                let size = SCALAR_SIZE[m as usize];
                if size != 0 {
                    // At most 18 bytes: `p` cannot overflow; a value
                    // running past the end is caught by the next `get` or
                    // the final check.
                    p += size as usize;
                    continue;
                }
                let Some((len, children)) = Self::sized_value(b, p) else {
                    return false;
                };
                p = match p.checked_add(len) {
                    Some(end) if end <= b.len() => end,
                    _ => return false,
                };
                children
            };
            if children > 0 {
                if budget == 0 {
                    return false;
                }
                budget -= 1;
                rem = rem.saturating_add(children);
            }
        }
        if p > b.len() {
            return false;
        }
        self.p = p;
        true
    }

    /// The header and data length and the number of contained values of
    /// the value at `b[p]` whose marker is not in [`SCALAR_SIZE`] and not a
    /// fixmap or fixarray: `(bytes from the marker to the first child or
    /// the next value, children)`; `None` for a truncated header or an
    /// invalid marker (`0xc1`).
    #[inline(never)]
    fn sized_value(b: &[u8], p: usize) -> Option<(usize, usize)> {
        let m = *b.get(p)?;
        let be = |w: usize| -> Option<usize> {
            let s = b.get(p + 1..p + 1 + w)?;
            Some(s.iter().fold(0usize, |a, x| (a << 8) | usize::from(*x)))
        };
        Some(match m {
            0xc4 | 0xd9 => (2 + be(1)?, 0),
            0xc5 | 0xda => (3 + be(2)?, 0),
            0xc6 | 0xdb => (5 + be(4)?, 0),
            0xc7 => (3 + be(1)?, 0),
            0xc8 => (4 + be(2)?, 0),
            0xc9 => (6 + be(4)?, 0),
            0xdc => (3, be(2)?),
            0xdd => (5, be(4)?),
            0xde => (3, 2 * be(2)?),
            0xdf => (5, be(4)?.saturating_mul(2)),
            _ => return None,
        })
    }

    /// Skips `n` values at nesting `depth` and everything inside them,
    /// with a counter per nesting level instead of recursion.
    fn skip_values(&mut self, n: usize, depth: usize) -> Result<(), Fail> {
        if depth > MAX_DEPTH {
            return Err(Fail::TooDeep { at: self.p });
        }
        // `rem`: values still to skip at nesting depth + k; `outer[i]`:
        // the same for the enclosing levels depth + i, i < k.
        let mut outer = [0usize; MAX_DEPTH + 1];
        let mut k = 0;
        let mut rem = n;
        loop {
            while rem == 0 {
                if k == 0 {
                    return Ok(());
                }
                k -= 1;
                rem = outer[k];
            }
            rem -= 1;
            // Inline the markers nearly all of Pupil's bytes are (float64,
            // short strings, small ints, small arrays and maps); the rest
            // go through the jump table.
            let p = self.p;
            let children = match self.b.get(p) {
                Some(0xcb) if p + 9 <= self.b.len() => {
                    self.p = p + 9;
                    continue;
                }
                Some(&m) if m & 0xe0 == 0xa0 && p + 1 + (m & 0x1f) as usize <= self.b.len() => {
                    self.p = p + 1 + (m & 0x1f) as usize;
                    continue;
                }
                Some(&m) if m < 0x80 => {
                    self.p = p + 1;
                    continue;
                }
                Some(&m) if m & 0xf0 == 0x90 => {
                    self.p = p + 1;
                    (m & 0x0f) as usize
                }
                Some(&m) if m & 0xf0 == 0x80 => {
                    self.p = p + 1;
                    2 * (m & 0x0f) as usize
                }
                _ => self.skip_one()?,
            };
            if children > 0 {
                // The children sit at depth + k + 1; the first of them
                // starts here.
                if depth + k + 1 > MAX_DEPTH {
                    return Err(Fail::TooDeep { at: self.p });
                }
                // depth + k + 1 ≤ MAX_DEPTH, so k < MAX_DEPTH.
                outer[k] = rem;
                k += 1;
                rem = children;
            }
        }
    }

    /// Reads one marker and skips the value's bytes; for a map or array,
    /// returns how many values it holds (keys and values for a map), which
    /// are not skipped yet.
    #[inline(never)]
    fn skip_one(&mut self) -> Result<usize, Fail> {
        let at = self.p;
        let m = self.byte()?;
        // The common case first.
        if m == 0xcb {
            self.take(8)?;
            return Ok(0);
        }
        let n = match m {
            0x00..=0x7f | 0xe0..=0xff | 0xc0 | 0xc2 | 0xc3 => return Ok(0),
            0x80..=0x8f => return Ok(2 * (m & 0x0f) as usize),
            0x90..=0x9f => return Ok((m & 0x0f) as usize),
            0xde => return Ok(2 * self.uint(2)? as usize),
            0xdf => return Ok((self.uint(4)? as usize).saturating_mul(2)),
            0xdc => return Ok(self.uint(2)? as usize),
            0xdd => return Ok(self.uint(4)? as usize),
            0xa0..=0xbf => (m & 0x1f) as usize,
            0xcc | 0xd0 => 1,
            0xcd | 0xd1 => 2,
            0xce | 0xd2 | 0xca => 4,
            0xcf | 0xd3 => 8,
            0xc4 | 0xd9 => self.uint(1)? as usize,
            0xc5 | 0xda => self.uint(2)? as usize,
            0xc6 | 0xdb => self.uint(4)? as usize,
            0xd4 => 2,
            0xd5 => 3,
            0xd6 => 5,
            0xd7 => 9,
            0xd8 => 17,
            0xc7 => self.uint(1)? as usize + 1,
            0xc8 => self.uint(2)? as usize + 1,
            0xc9 => self.uint(4)? as usize + 1,
            _ => return Err(Fail::Invalid { at, marker: m }),
        };
        self.take(n)?;
        Ok(0)
    }

    /// Starts a map; a non-map is a type error of `field` ("" = payload).
    #[inline]
    fn map_start(&mut self, field: &'static str) -> Result<usize, Fail> {
        let m = self.byte()?;
        match self.map_len(m)? {
            Some(n) => Ok(n),
            None if m == 0xc1 => Err(Fail::Invalid {
                at: self.p - 1,
                marker: m,
            }),
            None => Err(type_fail(field, "a map", m)),
        }
    }

    fn ellipse(&mut self) -> Result<Ellipse, Fail> {
        const F: &str = "ellipse";
        let n = self.map_start(F)?;
        let (mut center, mut axes, mut angle) = (None, None, None);
        for _ in 0..n {
            match self.key()? {
                Some(b"center") => center = Some(self.f64s::<2>(F)?),
                Some(b"axes") => axes = Some(self.f64s::<2>(F)?),
                Some(b"angle") => angle = Some(self.f64(F)?),
                _ => self.skip(0)?,
            }
        }
        match (center, axes, angle) {
            (Some(center), Some(axes), Some(angle)) => Ok(Ellipse {
                center,
                axes,
                angle,
            }),
            _ => Err(type_err(
                F,
                "a map with center, axes and angle",
                "a map without them",
            )),
        }
    }

    fn circle_3d(&mut self) -> Result<Circle3d, Fail> {
        const F: &str = "circle_3d";
        let n = self.map_start(F)?;
        let (mut center, mut normal, mut radius) = (None, None, None);
        for _ in 0..n {
            match self.key()? {
                Some(b"center") => center = Some(self.f64s::<3>(F)?),
                Some(b"normal") => normal = Some(self.f64s::<3>(F)?),
                Some(b"radius") => radius = Some(self.f64(F)?),
                _ => self.skip(0)?,
            }
        }
        match (center, normal, radius) {
            (Some(center), Some(normal), Some(radius)) => Ok(Circle3d {
                center,
                normal,
                radius,
            }),
            _ => Err(type_err(
                F,
                "a map with center, normal and radius",
                "a map without them",
            )),
        }
    }
}

/// The keys of pupil and gaze datums the decoder knows.
#[derive(Clone, Copy, PartialEq, Eq, Debug)]
enum Key {
    Id,
    Timestamp,
    Confidence,
    Diameter,
    Diameter3d,
    NormPos,
    Method,
    Ellipse,
    ModelConfidence,
    Circle3d,
    Theta,
    Phi,
    BaseData,
    /// A field Pupil is known to send that gazelight does not use
    /// (skipped without counting).
    Unused,
    Unknown,
}

/// Classifies a datum key: one jump on its length, then at most two
/// comparisons of that fixed length.
#[inline(always)]
fn key_of(k: &[u8]) -> Key {
    let is = |name: &[u8]| k == name;
    match k.len() {
        2 if is(b"id") => Key::Id,
        3 if is(b"phi") => Key::Phi,
        5 if is(b"theta") => Key::Theta,
        5 if is(b"topic") => Key::Unused,
        6 if is(b"method") => Key::Method,
        6 if is(b"sphere") => Key::Unused,
        7 if is(b"ellipse") => Key::Ellipse,
        8 if is(b"diameter") => Key::Diameter,
        8 if is(b"norm_pos") => Key::NormPos,
        8 if is(b"location") || is(b"model_id") => Key::Unused,
        9 if is(b"timestamp") => Key::Timestamp,
        9 if is(b"circle_3d") => Key::Circle3d,
        9 if is(b"base_data") => Key::BaseData,
        10 if is(b"confidence") => Key::Confidence,
        11 if is(b"diameter_3d") => Key::Diameter3d,
        12 if is(b"__raw_data__") => Key::Unused,
        13 if is(b"gaze_point_3d") || is(b"eye_center_3d") => Key::Unused,
        14 if is(b"gaze_normal_3d") || is(b"eye_centers_3d") => Key::Unused,
        15 if is(b"gaze_normals_3d") => Key::Unused,
        16 if is(b"model_confidence") => Key::ModelConfidence,
        16 if is(b"projected_sphere") => Key::Unused,
        21 if is(b"model_birth_timestamp") => Key::Unused,
        _ => Key::Unknown,
    }
}

/// The detector method from Pupil's `method` string (`"2d c++"`,
/// `"3d c++"`, `"pye3d 0.3.0 real-time"`, …).
fn method_of(s: &[u8]) -> Option<DetectorMethod> {
    // A plain byte scan: the strings are a few dozen bytes, and setting up
    // a substring searcher cost more than the search.
    let has = |pat: &[u8; 2]| s.windows(2).any(|w| w == pat);
    if has(b"3d") {
        Some(DetectorMethod::Pupil3d)
    } else if has(b"2d") {
        Some(DetectorMethod::Pupil2d)
    } else {
        None
    }
}

fn read_pupil(c: &mut Cur<'_>, depth: usize) -> Result<RawPupil, Fail> {
    let mut r = RawPupil::default();
    read_pupil_into(c, depth, &mut r)?;
    Ok(r)
}

/// [`read_pupil`] into a caller's `RawPupil` (a few hundred bytes not
/// moved through a `Result`); `r` must be `RawPupil::default()`.
fn read_pupil_into(c: &mut Cur<'_>, depth: usize, r: &mut RawPupil) -> Result<(), Fail> {
    if depth > MAX_DEPTH {
        return Err(Fail::TooDeep { at: c.p });
    }
    let n = c.map_start("")?;
    for _ in 0..n {
        let Some(key) = c.key()? else {
            r.unknown_fields += 1;
            c.skip(depth + 1)?;
            continue;
        };
        match key_of(key) {
            Key::Id => r.id = Some(c.u8_value("id")?),
            Key::Timestamp => r.timestamp = Some(c.f64("timestamp")?),
            Key::Confidence => r.confidence = Some(c.f64("confidence")?),
            Key::Diameter => r.diameter = Some(c.f64("diameter")?),
            Key::Diameter3d => r.diameter_3d = Some(c.f64("diameter_3d")?),
            Key::NormPos => r.norm_pos = Some(c.f64s::<2>("norm_pos")?),
            Key::Method => r.method = method_of(c.str_value("method")?),
            Key::Ellipse => r.ellipse = Some(c.ellipse()?),
            Key::ModelConfidence => r.model_confidence = Some(c.f64("model_confidence")?),
            Key::Circle3d => r.circle_3d = Some(c.circle_3d()?),
            Key::Theta => r.theta = Some(c.f64("theta")?),
            Key::Phi => r.phi = Some(c.f64("phi")?),
            Key::Unused => c.skip(depth + 1)?,
            Key::BaseData | Key::Unknown => {
                r.unknown_fields += 1;
                c.skip(depth + 1)?;
            }
        }
    }
    Ok(())
}

fn read_gaze(c: &mut Cur<'_>, decode_base: bool) -> Result<RawGaze, Fail> {
    let n = c.map_start("")?;
    let mut r = RawGaze::default();
    for _ in 0..n {
        let Some(key) = c.key()? else {
            r.unknown_fields += 1;
            c.skip(1)?;
            continue;
        };
        match key_of(key) {
            Key::Timestamp => r.timestamp = Some(c.f64("timestamp")?),
            Key::Confidence => r.confidence = Some(c.f64("confidence")?),
            Key::NormPos => r.norm_pos = Some(c.f64s::<2>("norm_pos")?),
            Key::BaseData => {
                let m = c.byte()?;
                let len = c
                    .array_len(m)?
                    .ok_or_else(|| type_fail("base_data", "an array of pupil datums", m))?;
                for i in 0..len {
                    if i < 2 && decode_base {
                        let p = read_pupil(c, 2).map_err(|f| {
                            f.in_path(if i == 0 {
                                "base_data[0]"
                            } else {
                                "base_data[1]"
                            })
                        })?;
                        r.base[i] = Some(p);
                    } else {
                        c.skip(2)?;
                    }
                }
                r.n_base = len;
            }
            Key::Unused => c.skip(1)?,
            _ => {
                r.unknown_fields += 1;
                c.skip(1)?;
            }
        }
    }
    Ok(r)
}

#[derive(Default, Clone, Copy, PartialEq)]
struct RawPupil {
    id: Option<u8>,
    timestamp: Option<f64>,
    confidence: Option<f64>,
    diameter: Option<f64>,
    diameter_3d: Option<f64>,
    norm_pos: Option<[f64; 2]>,
    method: Option<DetectorMethod>,
    ellipse: Option<Ellipse>,
    model_confidence: Option<f64>,
    circle_3d: Option<Circle3d>,
    theta: Option<f64>,
    phi: Option<f64>,
    unknown_fields: u32,
}

fn unit_interval(topic: &str, field: impl FnOnce() -> String, v: f64) -> Result<f32, DecodeError> {
    if (0.0..=1.0).contains(&v) {
        Ok(v as f32)
    } else {
        Err(DecodeError::Field {
            topic: topic.to_owned(),
            field: field(),
            reason: format!("{v} is outside 0..=1"),
        })
    }
}

impl RawPupil {
    /// Builds the datum; `prefix` names the enclosing field for errors in
    /// base data (`base_data[0]`).
    fn finish_with(
        self,
        topic: &str,
        prefix: &str,
        topic_eye: Option<u8>,
        topic_method: Option<DetectorMethod>,
    ) -> Result<PupilDatum, DecodeError> {
        let name = |f: &'static str| {
            if prefix.is_empty() {
                f.to_owned()
            } else {
                format!("{prefix}.{f}")
            }
        };
        let missing = |f: &'static str| {
            if prefix.is_empty() {
                DecodeError::MissingField {
                    topic: topic.to_owned(),
                    field: f,
                }
            } else {
                DecodeError::Field {
                    topic: topic.to_owned(),
                    field: name(f),
                    reason: "missing".to_owned(),
                }
            }
        };
        let eye = match (self.id, topic_eye) {
            (Some(id), Some(t)) if id != t => {
                return Err(DecodeError::Field {
                    topic: topic.to_owned(),
                    field: name("id"),
                    reason: format!("eye id {id} contradicts the topic (eye {t})"),
                });
            }
            (Some(id), _) if id > 1 => {
                return Err(DecodeError::Field {
                    topic: topic.to_owned(),
                    field: name("id"),
                    reason: format!("eye id {id} is not 0 or 1"),
                });
            }
            (Some(id), _) => id,
            (None, Some(t)) => t,
            (None, None) => return Err(missing("id")),
        };
        let t_secs = self.timestamp.ok_or_else(|| missing("timestamp"))?;
        if !t_secs.is_finite() {
            return Err(DecodeError::Field {
                topic: topic.to_owned(),
                field: name("timestamp"),
                reason: format!("{t_secs} is not finite"),
            });
        }
        let confidence = unit_interval(
            topic,
            || name("confidence"),
            self.confidence.ok_or_else(|| missing("confidence"))?,
        )?;
        let method = topic_method
            .or(self.method)
            .unwrap_or(if self.diameter_3d.is_some() {
                DetectorMethod::Pupil3d
            } else {
                DetectorMethod::Pupil2d
            });
        let (diameter_raw, unit) = match (self.diameter, self.diameter_3d) {
            (Some(px), _) => (px as f32, PupilUnit::Px),
            (None, Some(mm)) => (mm as f32, PupilUnit::Mm),
            (None, None) => return Err(missing("diameter")),
        };
        let norm_pos = self
            .norm_pos
            .map_or([f32::NAN; 2], |p| [p[0] as f32, p[1] as f32]);
        Ok(PupilDatum {
            sample: PupilSample {
                t_secs,
                eye,
                diameter_raw,
                unit,
                diameter_mm: self.diameter_3d.map(|d| d as f32),
                confidence,
                norm_pos,
                method,
            },
            ellipse: self.ellipse,
            model_confidence: self.model_confidence.map(|c| c as f32),
            circle_3d: self.circle_3d,
            theta: self.theta.map(|v| v as f32),
            phi: self.phi.map(|v| v as f32),
            unknown_fields: self.unknown_fields,
        })
    }

    fn finish(
        self,
        topic: &str,
        eye: Option<u8>,
        method: Option<DetectorMethod>,
    ) -> Result<PupilDatum, DecodeError> {
        self.finish_with(topic, "", eye, method)
    }
}

#[derive(Default, Clone, Copy, PartialEq)]
struct RawGaze {
    timestamp: Option<f64>,
    confidence: Option<f64>,
    norm_pos: Option<[f64; 2]>,
    base: [Option<RawPupil>; 2],
    n_base: usize,
    unknown_fields: u32,
}

impl RawGaze {
    fn finish(self, topic: &str, topic_eyes: Option<GazeEyes>) -> Result<GazeDatum, DecodeError> {
        let missing = |f: &'static str| DecodeError::MissingField {
            topic: topic.to_owned(),
            field: f,
        };
        let t_secs = self.timestamp.ok_or_else(|| missing("timestamp"))?;
        if !t_secs.is_finite() {
            return Err(DecodeError::Field {
                topic: topic.to_owned(),
                field: "timestamp".to_owned(),
                reason: format!("{t_secs} is not finite"),
            });
        }
        let confidence = unit_interval(
            topic,
            || "confidence".to_owned(),
            self.confidence.ok_or_else(|| missing("confidence"))?,
        )?;
        let p = self.norm_pos.ok_or_else(|| missing("norm_pos"))?;
        let mut base: [Option<PupilSample>; 2] = [None, None];
        for (i, raw) in self.base.iter().enumerate() {
            if let Some(raw) = raw {
                let prefix = if i == 0 {
                    "base_data[0]"
                } else {
                    "base_data[1]"
                };
                let d = raw.finish_with(topic, prefix, None, None)?;
                let slot = &mut base[d.sample.eye as usize];
                if slot.is_some() {
                    return Err(DecodeError::Field {
                        topic: topic.to_owned(),
                        field: prefix.to_owned(),
                        reason: format!("second datum for eye {}", d.sample.eye),
                    });
                }
                *slot = Some(d.sample);
            }
        }
        let eyes = match topic_eyes {
            Some(e) => e,
            None => match (base[0].is_some(), base[1].is_some()) {
                (true, true) => GazeEyes::Binocular,
                (true, false) => GazeEyes::Right,
                (false, true) => GazeEyes::Left,
                (false, false) => {
                    return Err(DecodeError::Field {
                        topic: topic.to_owned(),
                        field: "base_data".to_owned(),
                        reason: "no pupil datum to tell which eyes the gaze is from".to_owned(),
                    });
                }
            },
        };
        Ok(GazeDatum {
            sample: GazeSample {
                t_secs,
                gaze_uv: [p[0] as f32, (1.0 - p[1]) as f32],
                confidence,
                eyes,
            },
            base,
            unknown_fields: self.unknown_fields,
        })
    }
}

/// Why bytes of a `.pldata` file are not a record (see [`scan_record`]).
/// Cheap to build and copy: a reader trying every byte offset of a
/// corrupt region makes one per offset and formats only the first.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum BadRecord {
    /// The first byte is not an array of 2.
    NotAPair { marker: u8 },
    /// An array of another length.
    ArrayLen { len: usize },
    /// The topic or payload is not a str or bin.
    NotStrOrBin { field: RecordField, marker: u8 },
    /// The topic or payload claims more bytes than a record may hold.
    TooLong {
        field: RecordField,
        len: usize,
        max: usize,
    },
    /// The topic is empty or not printable ASCII.
    TopicNotPrintable,
    /// The payload is not a msgpack map.
    PayloadNotMap,
    /// The payload is a map, but not one complete msgpack value: the walk
    /// stopped at byte `at` of the payload.
    PayloadInvalid { at: usize, why: PayloadFault },
}

/// The two parts of a `.pldata` record.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum RecordField {
    Topic,
    Payload,
}

/// How a payload's msgpack walk failed.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum PayloadFault {
    Truncated,
    InvalidMarker(u8),
    TooDeep,
    TrailingBytes,
}

impl std::fmt::Display for RecordField {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        f.write_str(match self {
            RecordField::Topic => "topic",
            RecordField::Payload => "payload",
        })
    }
}

impl std::fmt::Display for BadRecord {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        match self {
            BadRecord::NotAPair { marker } => write!(
                f,
                "byte 0x{marker:02x} does not start a [topic, payload] pair"
            ),
            BadRecord::ArrayLen { len } => write!(f, "record is an array of {len}, not 2"),
            BadRecord::NotStrOrBin { field, marker } => {
                write!(f, "{field}: byte 0x{marker:02x} is not a str or bin marker")
            }
            BadRecord::TooLong { field, len, max } => {
                write!(f, "{field}: length {len} exceeds {max}")
            }
            BadRecord::TopicNotPrintable => f.write_str("topic is not printable ASCII"),
            BadRecord::PayloadNotMap => f.write_str("payload is not a msgpack map"),
            BadRecord::PayloadInvalid { at, why } => match why {
                PayloadFault::Truncated => {
                    write!(f, "payload is not valid msgpack: truncated at byte {at}")
                }
                PayloadFault::InvalidMarker(m) => write!(
                    f,
                    "payload is not valid msgpack: invalid marker 0x{m:02x} at byte {at}"
                ),
                PayloadFault::TooDeep => write!(
                    f,
                    "payload is not valid msgpack: nesting deeper than {MAX_DEPTH} at byte {at}"
                ),
                PayloadFault::TrailingBytes => {
                    write!(f, "payload has trailing bytes at byte {at}")
                }
            },
        }
    }
}

/// Where the parts of one `.pldata` record lie, relative to its start.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub struct RecordSpan {
    pub topic_start: usize,
    pub topic_end: usize,
    pub payload_start: usize,
    /// Also the record's length.
    pub payload_end: usize,
}

/// What [`scan_record`] found at the start of a buffer.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum RecordScan {
    /// A complete record: a printable topic and a payload that starts
    /// like a map (its body is not walked; see [`check_payload`]).
    Complete(RecordSpan),
    /// More bytes are needed: at least this many from the record start.
    /// Never more than `max_topic_bytes + max_payload_bytes + 13`.
    Need(usize),
    Bad(BadRecord),
}

/// Frames one `.pldata` record (`[topic: str|bin, payload: str|bin]`, as
/// Pupil's `PLData_Writer` and older writers wrote it) at the start of `b`.
///
/// Checks are ordered so that garbage is refused after a few bytes: the
/// array marker, the topic's marker and length (≤ `max_topic_bytes`), the
/// topic's bytes (printable ASCII), the payload's marker and length
/// (≤ `max_payload_bytes`) and the payload's first byte (a map marker),
/// before asking for the whole payload.
pub fn scan_record(b: &[u8], max_topic_bytes: usize, max_payload_bytes: usize) -> RecordScan {
    let mut c = Cur { b, p: 0 };
    let need = |c: &Cur<'_>, n: usize| RecordScan::Need(c.p + n);
    let Ok(m) = c.byte() else {
        return need(&c, 1);
    };
    match m {
        0x92 => {}
        0xdc => match c.uint(2) {
            Ok(2) => {}
            Ok(len) => {
                return RecordScan::Bad(BadRecord::ArrayLen { len: len as usize });
            }
            Err(_) => return RecordScan::Need(3),
        },
        marker => return RecordScan::Bad(BadRecord::NotAPair { marker }),
    }
    let topic = match c.str_or_bin(RecordField::Topic, max_topic_bytes) {
        Ok(n) => n,
        Err(s) => return s,
    };
    if c.b.len() < c.p + topic {
        return need(&c, topic);
    }
    let topic_start = c.p;
    c.p += topic;
    let t = &b[topic_start..c.p];
    if t.is_empty() || !t.iter().all(u8::is_ascii_graphic) {
        return RecordScan::Bad(BadRecord::TopicNotPrintable);
    }
    let topic_end = c.p;
    let payload = match c.str_or_bin(RecordField::Payload, max_payload_bytes) {
        Ok(n) => n,
        Err(s) => return s,
    };
    let payload_start = c.p;
    match b.get(payload_start) {
        _ if payload == 0 => return RecordScan::Bad(BadRecord::PayloadNotMap),
        None => return need(&c, 1),
        Some(&m) if !matches!(m, 0x80..=0x8f | 0xde | 0xdf) => {
            return RecordScan::Bad(BadRecord::PayloadNotMap);
        }
        Some(_) => {}
    }
    if b.len() < payload_start + payload {
        return need(&c, payload);
    }
    RecordScan::Complete(RecordSpan {
        topic_start,
        topic_end,
        payload_start,
        payload_end: payload_start + payload,
    })
}

/// Checks that `payload` is exactly one complete msgpack map (any keys and
/// values, nesting up to 32 levels), without decoding it.
pub fn check_payload(payload: &[u8]) -> Result<(), BadRecord> {
    let mut c = Cur { b: payload, p: 0 };
    let fault = |f: Fail| match f {
        Fail::Truncated { at } => BadRecord::PayloadInvalid {
            at,
            why: PayloadFault::Truncated,
        },
        Fail::Invalid { at, marker } => BadRecord::PayloadInvalid {
            at,
            why: PayloadFault::InvalidMarker(marker),
        },
        Fail::TooDeep { at } => BadRecord::PayloadInvalid {
            at,
            why: PayloadFault::TooDeep,
        },
        Fail::Trailing { at } => BadRecord::PayloadInvalid {
            at,
            why: PayloadFault::TrailingBytes,
        },
        Fail::Type(_) => BadRecord::PayloadNotMap,
    };
    let m = c.byte().map_err(fault)?;
    let n = c
        .map_len(m)
        .map_err(fault)?
        .ok_or(BadRecord::PayloadNotMap)?;
    for _ in 0..n {
        c.skip(1).map_err(fault)?;
        c.skip(1).map_err(fault)?;
    }
    c.end().map_err(fault)
}

/// Decodes one `.pldata` record's payload straight into the [`Sample`] it
/// holds (Pupil time): `Ok(Some(sample))`, `Ok(None)` for a well-formed
/// payload under a topic the decoder does not know, `Ok(Err(e))` for a
/// well-formed map that is not a valid datum, and `Err` when the payload is
/// not one complete msgpack map (the record is corrupt). A payload that
/// decodes is walked once; only a failing one is walked again
/// ([`check_payload`]) to tell the two kinds of failure apart. What a
/// sample does not carry is not decoded: a gaze datum whose topic names
/// its eyes has its `base_data` checked as msgpack only (the pupil datums
/// in it are recorded, and decoded, in their own stream).
pub fn decode_record_sample(
    topic: &str,
    payload: &[u8],
) -> Result<Result<Option<Sample>, DecodeError>, BadRecord> {
    decode_record_sample_as(parse_topic(topic), topic, payload)
}

/// [`decode_record_sample`] for a topic already classified
/// (`kind == parse_topic(topic)`), e.g. by a reader that caches the
/// classification of the few topics a file holds.
pub fn decode_record_sample_as(
    kind: TopicKind,
    topic: &str,
    payload: &[u8],
) -> Result<Result<Option<Sample>, DecodeError>, BadRecord> {
    let decoded = match kind {
        TopicKind::Unknown => {
            check_payload(payload)?;
            return Ok(Ok(None));
        }
        TopicKind::Gaze { eyes } => {
            decode_gaze(topic, payload, eyes, false).map(|g| Sample::Gaze(g.sample))
        }
        TopicKind::Pupil { eye, method } => {
            // decode_as without building the whole Datum.
            let wrap = |f: Fail| f.into_error(topic);
            let mut c = Cur { b: payload, p: 0 };
            let mut raw = RawPupil::default();
            read_pupil_into(&mut c, 0, &mut raw)
                .and_then(|()| c.end())
                .map_err(wrap)
                .and_then(|()| raw.finish(topic, eye, method))
                .map(|d| Sample::Pupil(d.sample))
        }
    };
    match decoded {
        Ok(s) => Ok(Ok(Some(s))),
        Err(e) => {
            check_payload(payload)?;
            Ok(Err(e))
        }
    }
}

/// The topic prefix of Pupil Capture's annotations (its Annotation
/// plugin and the Network API publish `annotation` datums on the bus; a
/// `.pldata` recording stores them in `annotation.pldata`).
pub const ANNOTATION_TOPIC: &str = "annotation";

/// One Pupil Capture annotation: a label at a Pupil time.
#[derive(Clone, Debug, PartialEq)]
pub struct Annotation {
    /// `timestamp`, Pupil time, s (the moment it marks, which may be
    /// before the datum was sent).
    pub timestamp: f64,
    pub label: String,
    /// `duration`, s, where given.
    pub duration_secs: Option<f64>,
}

/// Decodes an annotation datum (a msgpack map with a numeric `timestamp`,
/// a text `label` and an optional numeric `duration`; other keys, such as
/// `topic` and custom fields, are ignored): the one reader of live and
/// recorded annotations.
pub fn decode_annotation(payload: &[u8]) -> Result<Annotation, String> {
    let v = rmpv::decode::read_value(&mut &payload[..])
        .map_err(|e| format!("annotation: not msgpack ({e})"))?;
    let map = v.as_map().ok_or("annotation: not a msgpack map")?;
    let get = |k: &str| {
        map.iter()
            .find(|(key, _)| key.as_str() == Some(k))
            .map(|(_, v)| v)
    };
    let num = |v: &rmpv::Value| v.as_f64().or_else(|| v.as_i64().map(|i| i as f64));
    let timestamp = get("timestamp")
        .and_then(num)
        .ok_or("annotation: no numeric `timestamp`")?;
    let label = get("label")
        .and_then(|l| l.as_str().map(str::to_owned))
        .ok_or("annotation: no text `label`")?;
    Ok(Annotation {
        timestamp,
        label,
        duration_secs: get("duration").and_then(num),
    })
}

/// Builds a notification message: topic `notify.<subject>` and a msgpack
/// map with `subject` and the given fields, as Pupil Remote expects it.
pub fn encode_notification(
    subject: &str,
    fields: &[(&str, rmpv::Value)],
) -> Result<(String, Vec<u8>), rmpv::encode::Error> {
    let mut entries = Vec::with_capacity(fields.len() + 1);
    entries.push((rmpv::Value::from("subject"), rmpv::Value::from(subject)));
    for (k, v) in fields {
        if *k != "subject" {
            entries.push((rmpv::Value::from(*k), v.clone()));
        }
    }
    let mut buf = Vec::new();
    rmpv::encode::write_value(&mut buf, &rmpv::Value::Map(entries))?;
    Ok((format!("notify.{subject}"), buf))
}

/// Encodes a sample as the Pupil datum it would have come from, for
/// recording synthetic or imported traces in Pupil's layout (see
/// [`crate::recording::PldataWriter`]): `(topic, msgpack map)`, or `None`
/// for a blink event (Pupil publishes blinks as a separate plugin's datum
/// with other fields).
///
/// Pupil samples become `pupil.<eye>.2d`, or `pupil.<eye>.3d` for
/// [`DetectorMethod::Pupil3d`], with `id`, `method`, `timestamp`,
/// `confidence`, `norm_pos` (left out when NaN) and the diameter: a raw
/// value in mm as `diameter_3d` alone, any other raw value as `diameter`
/// (plus `diameter_3d` when `diameter_mm` is known). Decoding gives the
/// sample back, except that [`DetectorMethod::Other`] comes back as 2D and
/// a raw unit other than px or mm comes back as px. Gaze samples become
/// `gaze.3d.01.` / `gaze.3d.0.` / `gaze.3d.1.` with `norm_pos` converted
/// back to Pupil's bottom-left origin and no `base_data`.
pub fn encode_sample(sample: &Sample) -> Result<Option<(String, Vec<u8>)>, rmpv::encode::Error> {
    use rmpv::Value as V;
    let pair = |a: f32, b: f32| V::Array(vec![V::from(a as f64), V::from(b as f64)]);
    let (topic, entries) = match sample {
        Sample::Pupil(p) => {
            let three_d = p.method == DetectorMethod::Pupil3d;
            let topic = format!("pupil.{}.{}", p.eye, if three_d { "3d" } else { "2d" });
            let method = if three_d {
                "pye3d 0.3.0 real-time"
            } else {
                "2d c++"
            };
            let mut e = vec![
                ("topic", V::from(topic.as_str())),
                ("id", V::from(p.eye)),
                ("method", V::from(method)),
                ("timestamp", V::from(p.t_secs)),
                ("confidence", V::from(p.confidence as f64)),
            ];
            if !(p.norm_pos[0].is_nan() || p.norm_pos[1].is_nan()) {
                e.push(("norm_pos", pair(p.norm_pos[0], p.norm_pos[1])));
            }
            if p.unit == PupilUnit::Mm {
                e.push(("diameter_3d", V::from(p.diameter_raw as f64)));
            } else {
                e.push(("diameter", V::from(p.diameter_raw as f64)));
                if let Some(mm) = p.diameter_mm {
                    e.push(("diameter_3d", V::from(mm as f64)));
                }
            }
            (topic, e)
        }
        Sample::Gaze(g) => {
            let topic = match g.eyes {
                GazeEyes::Binocular => "gaze.3d.01.",
                GazeEyes::Right => "gaze.3d.0.",
                GazeEyes::Left => "gaze.3d.1.",
            };
            // In f64, 1 − (1 − v) gives v back exactly for an f32 v.
            let y = 1.0 - g.gaze_uv[1] as f64;
            let norm_pos = V::Array(vec![V::from(g.gaze_uv[0] as f64), V::from(y)]);
            let e = vec![
                ("topic", V::from(topic)),
                ("norm_pos", norm_pos),
                ("confidence", V::from(g.confidence as f64)),
                ("timestamp", V::from(g.t_secs)),
            ];
            (topic.to_owned(), e)
        }
        Sample::Blink(_) => return Ok(None),
    };
    let map = V::Map(entries.into_iter().map(|(k, v)| (V::from(k), v)).collect());
    let mut buf = Vec::with_capacity(160);
    rmpv::encode::write_value(&mut buf, &map)?;
    Ok(Some((topic, buf)))
}

#[cfg(test)]
mod tests {
    use super::*;
    use serde::Serialize;
    use std::collections::BTreeMap;

    #[derive(Serialize, Clone)]
    struct EllipseOut {
        center: [f64; 2],
        axes: [f64; 2],
        angle: f64,
    }

    #[derive(Serialize, Clone)]
    struct Pupil2dOut {
        topic: String,
        id: u8,
        method: String,
        timestamp: f64,
        confidence: f64,
        diameter: f64,
        norm_pos: [f64; 2],
        ellipse: EllipseOut,
    }

    fn pupil2d(eye: u8, t: f64, conf: f64, d: f64) -> Pupil2dOut {
        Pupil2dOut {
            topic: format!("pupil.{eye}.2d"),
            id: eye,
            method: "2d c++".into(),
            timestamp: t,
            confidence: conf,
            diameter: d,
            norm_pos: [0.41, 0.62],
            ellipse: EllipseOut {
                center: [78.7, 73.0],
                axes: [d * 0.9, d],
                angle: 12.5,
            },
        }
    }

    /// A pye3d datum with the fields Pupil v3 sends, including the unused
    /// ones (sphere, projected_sphere, location, model_id).
    fn pupil3d_value(eye: u8, t: f64) -> rmpv::Value {
        use rmpv::Value as V;
        let arr = |v: &[f64]| V::Array(v.iter().map(|x| V::from(*x)).collect());
        let map = |e: Vec<(&str, V)>| V::Map(e.into_iter().map(|(k, v)| (V::from(k), v)).collect());
        map(vec![
            ("topic", V::from(format!("pupil.{eye}.3d"))),
            ("id", V::from(eye)),
            ("method", V::from("pye3d 0.3.0 real-time")),
            ("timestamp", V::from(t)),
            ("confidence", V::from(0.97)),
            ("diameter", V::from(41.2)),
            ("norm_pos", arr(&[0.45, 0.55])),
            (
                "ellipse",
                map(vec![
                    ("center", arr(&[86.0, 85.5])),
                    ("axes", arr(&[38.0, 41.2])),
                    ("angle", V::from(-33.0)),
                ]),
            ),
            (
                "sphere",
                map(vec![
                    ("center", arr(&[1.0, 2.0, 40.0])),
                    ("radius", V::from(10.39)),
                ]),
            ),
            (
                "projected_sphere",
                map(vec![
                    ("center", arr(&[96.0, 96.0])),
                    ("axes", arr(&[120.0, 120.0])),
                    ("angle", V::from(0.0)),
                ]),
            ),
            (
                "circle_3d",
                map(vec![
                    ("center", arr(&[0.5, -1.0, 30.2])),
                    ("normal", arr(&[0.1, -0.2, -0.97])),
                    ("radius", V::from(1.95)),
                ]),
            ),
            ("diameter_3d", V::from(3.9)),
            ("location", arr(&[86.0, 85.5])),
            ("model_confidence", V::from(1.0)),
            ("model_id", V::from(4)),
            ("theta", V::from(1.78)),
            ("phi", V::from(-1.47)),
        ])
    }

    fn enc_value(v: &rmpv::Value) -> Vec<u8> {
        let mut b = Vec::new();
        rmpv::encode::write_value(&mut b, v).unwrap();
        b
    }

    #[test]
    fn topics() {
        use TopicKind::*;
        assert_eq!(
            parse_topic("pupil.0.2d"),
            Pupil {
                eye: Some(0),
                method: Some(DetectorMethod::Pupil2d)
            }
        );
        assert_eq!(
            parse_topic("pupil.1.3d"),
            Pupil {
                eye: Some(1),
                method: Some(DetectorMethod::Pupil3d)
            }
        );
        assert_eq!(
            parse_topic("pupil.1"),
            Pupil {
                eye: Some(1),
                method: None
            }
        );
        assert_eq!(
            parse_topic("pupil"),
            Pupil {
                eye: None,
                method: None
            }
        );
        assert_eq!(
            parse_topic("gaze.3d.01."),
            Gaze {
                eyes: Some(GazeEyes::Binocular)
            }
        );
        assert_eq!(
            parse_topic("gaze.3d.0."),
            Gaze {
                eyes: Some(GazeEyes::Right)
            }
        );
        assert_eq!(
            parse_topic("gaze.2d.1."),
            Gaze {
                eyes: Some(GazeEyes::Left)
            }
        );
        assert_eq!(
            parse_topic("gaze.2d.01"),
            Gaze {
                eyes: Some(GazeEyes::Binocular)
            }
        );
        assert_eq!(parse_topic("gaze"), Gaze { eyes: None });
        for bad in [
            "pupil.2.2d",
            "pupil.0.4d",
            "gaze.3d.2.",
            "gaze.x",
            "notify.recording",
            "frame.world",
            "pupil.0.2d.x",
            "pupils",
            "",
        ] {
            assert_eq!(parse_topic(bad), Unknown, "{bad}");
        }
    }

    #[test]
    fn decodes_2d_pupil() {
        let bytes = rmp_serde::to_vec_named(&pupil2d(1, 5123.25, 0.88, 33.5)).unwrap();
        let Datum::Pupil(p) = decode("pupil.1.2d", &bytes).unwrap() else {
            panic!("not pupil")
        };
        let s = p.sample;
        assert_eq!(s.eye, 1);
        assert_eq!(s.t_secs, 5123.25);
        assert_eq!(s.diameter_raw, 33.5);
        assert_eq!(s.unit, PupilUnit::Px);
        assert_eq!(s.diameter_mm, None);
        assert!((s.confidence - 0.88).abs() < 1e-6);
        assert_eq!(s.norm_pos, [0.41, 0.62]);
        assert_eq!(s.method, DetectorMethod::Pupil2d);
        let e = p.ellipse.unwrap();
        assert_eq!(e.center, [78.7, 73.0]);
        assert_eq!(e.angle, 12.5);
        assert_eq!(p.unknown_fields, 0);
        assert_eq!(p.model_confidence, None);
    }

    #[test]
    fn decodes_3d_pupil_and_skips_unused_fields() {
        let bytes = enc_value(&pupil3d_value(0, 812.5));
        let Datum::Pupil(p) = decode("pupil.0.3d", &bytes).unwrap() else {
            panic!()
        };
        assert_eq!(p.sample.method, DetectorMethod::Pupil3d);
        assert_eq!(p.sample.diameter_mm, Some(3.9));
        assert_eq!(p.sample.diameter_raw, 41.2);
        assert_eq!(p.model_confidence, Some(1.0));
        assert_eq!(p.theta, Some(1.78));
        assert_eq!(p.phi, Some(-1.47));
        let c = p.circle_3d.unwrap();
        assert_eq!(c.radius, 1.95);
        assert_eq!(c.normal, [0.1, -0.2, -0.97]);
        assert_eq!(p.unknown_fields, 0);
    }

    #[test]
    fn v1_names_and_unknown_fields() {
        // v1.x: topic `pupil.0`, method from the datum, an extra key.
        let mut v = pupil3d_value(0, 10.0);
        if let rmpv::Value::Map(m) = &mut v {
            m.push((rmpv::Value::from("vendor_extra"), rmpv::Value::from("x")));
            m.push((rmpv::Value::from(7), rmpv::Value::from(1)));
        }
        let Datum::Pupil(p) = decode("pupil.0", &enc_value(&v)).unwrap() else {
            panic!()
        };
        assert_eq!(p.sample.method, DetectorMethod::Pupil3d);
        assert_eq!(p.unknown_fields, 2);
        // v1 `gaze` with base data from both eyes → binocular.
        let g = gaze_value(&[0, 1], 10.5, [0.25, 0.8]);
        let Datum::Gaze(g) = decode("gaze", &enc_value(&g)).unwrap() else {
            panic!()
        };
        assert_eq!(g.sample.eyes, GazeEyes::Binocular);
        let g = gaze_value(&[1], 10.5, [0.25, 0.8]);
        let Datum::Gaze(g) = decode("gaze", &enc_value(&g)).unwrap() else {
            panic!()
        };
        assert_eq!(g.sample.eyes, GazeEyes::Left);
    }

    fn gaze_value(eyes: &[u8], t: f64, norm: [f64; 2]) -> rmpv::Value {
        use rmpv::Value as V;
        let base: Vec<V> = eyes.iter().map(|e| pupil3d_value(*e, t - 0.002)).collect();
        let mut centers = Vec::new();
        for e in eyes {
            centers.push((
                V::from(*e),
                V::Array(vec![V::from(20.0), V::from(15.0), V::from(-20.0)]),
            ));
        }
        V::Map(vec![
            (V::from("topic"), V::from("gaze.3d.01.")),
            (V::from("eye_centers_3d"), V::Map(centers)),
            (
                V::from("gaze_point_3d"),
                V::Array(vec![V::from(1.0), V::from(2.0), V::from(500.0)]),
            ),
            (V::from("confidence"), V::from(0.93)),
            (V::from("timestamp"), V::from(t)),
            (V::from("base_data"), V::Array(base)),
            (
                V::from("norm_pos"),
                V::Array(vec![V::from(norm[0]), V::from(norm[1])]),
            ),
        ])
    }

    #[test]
    fn decodes_binocular_and_monocular_gaze() {
        let bytes = enc_value(&gaze_value(&[0, 1], 99.0, [0.3, 0.75]));
        let Datum::Gaze(g) = decode("gaze.3d.01.", &bytes).unwrap() else {
            panic!()
        };
        assert_eq!(g.sample.eyes, GazeEyes::Binocular);
        assert_eq!(g.sample.t_secs, 99.0);
        // Bottom-left origin → top-left: v = 1 − y.
        assert_eq!(g.sample.gaze_uv, [0.3, 0.25]);
        assert!((g.sample.confidence - 0.93).abs() < 1e-6);
        assert_eq!(g.base[0].unwrap().eye, 0);
        assert_eq!(g.base[1].unwrap().diameter_mm, Some(3.9));
        assert_eq!(g.unknown_fields, 0);
        let bytes = enc_value(&gaze_value(&[1], 99.0, [0.3, 0.75]));
        let Datum::Gaze(g) = decode("gaze.3d.1.", &bytes).unwrap() else {
            panic!()
        };
        assert_eq!(g.sample.eyes, GazeEyes::Left);
        assert!(g.base[0].is_none());
        // Host-time conversion.
        let s = Datum::Gaze(g).to_sample(1234.5);
        assert_eq!(s.t_secs(), 99.0 - 1234.5);
    }

    #[test]
    fn unknown_topic_is_an_error_of_its_own_kind() {
        let e = decode("frame.world", b"\x80").unwrap_err();
        assert!(e.is_unknown_topic());
        let e = decode_message(b"\xff\xfe", b"\x80").unwrap_err();
        assert_eq!(e, DecodeError::TopicNotUtf8 { len: 2 });
    }

    #[test]
    fn truncated_frames_are_malformed_not_panics() {
        let bytes = enc_value(&gaze_value(&[0, 1], 99.0, [0.3, 0.75]));
        for cut in 0..bytes.len() {
            let e = decode("gaze.3d.01.", &bytes[..cut]).unwrap_err();
            assert!(
                matches!(
                    e,
                    DecodeError::Malformed { .. }
                        | DecodeError::Field { .. }
                        | DecodeError::MissingField { .. }
                ),
                "cut {cut}: {e:?}"
            );
        }
        // Not a map at all.
        let e = decode("pupil.0.2d", &[0x93, 1, 2, 3]).unwrap_err();
        assert!(matches!(e, DecodeError::Malformed { .. }), "{e:?}");
        // Garbage.
        let e = decode("pupil.0.2d", &[0xc1, 0xff, 0x00]).unwrap_err();
        assert!(matches!(e, DecodeError::Malformed { .. }), "{e:?}");
    }

    /// What a skip did: where the cursor ended, or the error and where.
    fn skip_outcome(r: Result<(), Fail>, c: &Cur<'_>) -> String {
        match r {
            Ok(()) => format!("ok at {}", c.p),
            Err(Fail::Truncated { at }) => format!("truncated at {at}"),
            Err(Fail::Invalid { at, marker }) => format!("invalid {marker:#x} at {at}"),
            Err(Fail::TooDeep { at }) => format!("too deep at {at}"),
            Err(Fail::Trailing { at }) => format!("trailing at {at}"),
            Err(Fail::Type(_)) => "type".to_owned(),
        }
    }

    #[test]
    fn fast_skip_agrees_with_the_exact_walk() {
        // Real datums, cut and mutated, random bytes and deep nesting: the
        // fast skip (with its fallback) must end where the exact walk ends
        // and fail where and how it fails, at every nesting depth.
        let mut inputs: Vec<Vec<u8>> = vec![
            enc_value(&pupil3d_value(1, 3.0)),
            enc_value(&gaze_value(&[0, 1], 4.0, [0.5, 0.5])),
            std::iter::repeat_n(0x91u8, 40).chain([0x01]).collect(),
            std::iter::repeat_n(0x81u8, 40).chain([0x01]).collect(),
            vec![0xdc, 0x00, 0x02, 0xcb, 0, 0, 0, 0, 0, 0, 0, 0, 0xc0],
            vec![
                0xde, 0x00, 0x01, 0xd9, 0x03, b'a', b'b', b'c', 0xc7, 0x01, 0x05, 0xaa,
            ],
            vec![0xdf, 0xff, 0xff, 0xff, 0xff],
            vec![0x92, 0xc1, 0x00],
            vec![0xc8, 0x00, 0x02, 0x01, 0xaa, 0xbb, 0xd8, 0x01],
        ];
        let mut seed = 0x9e37_79b9_7f4a_7c15u64;
        let mut rnd = || {
            seed ^= seed << 13;
            seed ^= seed >> 7;
            seed ^= seed << 17;
            seed
        };
        for base in inputs.clone() {
            for cut in 0..base.len() {
                inputs.push(base[..cut].to_vec());
            }
            for _ in 0..300 {
                let mut m = base.clone();
                let i = rnd() as usize % m.len();
                m[i] = rnd() as u8;
                inputs.push(m);
            }
        }
        for _ in 0..2000 {
            let n = rnd() as usize % 24;
            inputs.push((0..n).map(|_| rnd() as u8).collect());
        }
        for b in &inputs {
            for depth in [0, 1, 2, 20, 31, 32, 33] {
                let mut fast = Cur { b, p: 0 };
                let r = fast.skip(depth);
                let got = skip_outcome(r, &fast);
                let mut exact = Cur { b, p: 0 };
                let r = exact.skip_values(1, depth);
                let want = skip_outcome(r, &exact);
                assert_eq!(got, want, "depth {depth}, bytes {b:02x?}");
            }
        }
    }

    #[test]
    fn hostile_payloads_are_bounded() {
        // An unknown field nested 10 000 levels deep: refused, no stack
        // overflow.
        let mut b = vec![0x81, 0xa5];
        b.extend_from_slice(b"extra");
        b.extend(std::iter::repeat_n(0x91u8, 10_000));
        b.push(0x01);
        let e = decode("pupil.0.2d", &b).unwrap_err();
        assert!(e.to_string().contains("nesting"), "{e}");
        // A huge declared length with nothing behind it.
        let e = decode("pupil.0.2d", &[0xdf, 0xff, 0xff, 0xff, 0xff]).unwrap_err();
        assert!(e.to_string().contains("truncated"), "{e}");
        // Trailing bytes after a complete datum.
        let mut ok = rmp_serde::to_vec_named(&pupil2d(0, 1.0, 0.5, 20.0)).unwrap();
        assert!(decode("pupil.0.2d", &ok).is_ok());
        ok.push(0x00);
        let e = decode("pupil.0.2d", &ok).unwrap_err();
        assert!(e.to_string().contains("trailing"), "{e}");
    }

    #[test]
    fn wrong_types_name_the_field() {
        let mut m: BTreeMap<&str, rmpv::Value> = BTreeMap::new();
        m.insert("id", 0.into());
        m.insert("timestamp", 1.0.into());
        m.insert("confidence", "high".into());
        m.insert("diameter", 30.0.into());
        let bytes = rmp_serde::to_vec_named(&m).unwrap();
        let e = decode("pupil.0.2d", &bytes).unwrap_err();
        match &e {
            DecodeError::Field { field, .. } => assert_eq!(field, "confidence"),
            other => panic!("{other:?}"),
        }
        assert!(e.to_string().contains("confidence"), "{e}");
        // Nested: a base datum with a bad confidence.
        let mut g = gaze_value(&[0, 1], 5.0, [0.5, 0.5]);
        if let rmpv::Value::Map(entries) = &mut g {
            for (k, v) in entries.iter_mut() {
                if k.as_str() == Some("base_data")
                    && let rmpv::Value::Array(a) = v
                    && let rmpv::Value::Map(inner) = &mut a[1]
                {
                    for (ik, iv) in inner.iter_mut() {
                        if ik.as_str() == Some("confidence") {
                            *iv = rmpv::Value::from("x");
                        }
                    }
                }
            }
        }
        let e = decode("gaze.3d.01.", &enc_value(&g)).unwrap_err();
        match &e {
            DecodeError::Field { field, .. } => assert_eq!(field, "base_data[1].confidence"),
            other => panic!("{other:?}"),
        }
        // Out-of-range confidence and a missing field.
        m.insert("confidence", 1.5.into());
        let e = decode("pupil.0.2d", &rmp_serde::to_vec_named(&m).unwrap()).unwrap_err();
        assert!(
            matches!(&e, DecodeError::Field { field, .. } if field == "confidence"),
            "{e:?}"
        );
        m.remove("timestamp");
        m.insert("confidence", 0.5.into());
        let e = decode("pupil.0.2d", &rmp_serde::to_vec_named(&m).unwrap()).unwrap_err();
        assert_eq!(
            e,
            DecodeError::MissingField {
                topic: "pupil.0.2d".into(),
                field: "timestamp"
            }
        );
        // Eye id contradicting the topic.
        m.insert("timestamp", 1.0.into());
        let e = decode("pupil.1.2d", &rmp_serde::to_vec_named(&m).unwrap()).unwrap_err();
        assert!(
            matches!(&e, DecodeError::Field { field, .. } if field == "id"),
            "{e:?}"
        );
    }

    #[test]
    fn notification_encoding() {
        let (topic, bytes) = encode_notification(
            "gazelight.stimulus",
            &[("color", rmpv::Value::from("black"))],
        )
        .unwrap();
        assert_eq!(topic, "notify.gazelight.stimulus");
        let v = rmpv::decode::read_value(&mut &bytes[..]).unwrap();
        let m = v.as_map().unwrap();
        assert_eq!(m[0].0.as_str(), Some("subject"));
        assert_eq!(m[0].1.as_str(), Some("gazelight.stimulus"));
        assert_eq!(m[1].1.as_str(), Some("black"));
    }

    #[test]
    fn annotation_payloads() {
        let v = rmpv::Value::Map(vec![
            ("topic".into(), "annotation".into()),
            ("label".into(), "flash".into()),
            ("timestamp".into(), 12.5.into()),
            ("duration".into(), 0.25.into()),
            ("custom".into(), 3.into()),
        ]);
        let mut b = Vec::new();
        rmpv::encode::write_value(&mut b, &v).unwrap();
        assert_eq!(
            decode_annotation(&b).unwrap(),
            Annotation {
                timestamp: 12.5,
                label: "flash".to_owned(),
                duration_secs: Some(0.25)
            }
        );
        let v = rmpv::Value::Map(vec![("label".into(), "x".into())]);
        let mut b = Vec::new();
        rmpv::encode::write_value(&mut b, &v).unwrap();
        assert!(decode_annotation(&b).unwrap_err().contains("timestamp"));
        assert!(decode_annotation(&[0xc1]).is_err());
    }
}
