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
//! Decoding is a streaming serde visit over the msgpack bytes: no
//! intermediate value tree and no heap allocation for a well-formed datum.
//! Fields Pupil is known to send but gazelight does not use (`sphere`,
//! `projected_sphere`, `location`, `model_id`, `gaze_point_3d`, …) are
//! skipped silently; any other key is skipped and counted in
//! [`PupilDatum::unknown_fields`] / [`GazeDatum::unknown_fields`]. A field
//! with the wrong type is an error naming the field
//! (e.g. `base_data[1].confidence`).

use std::cell::RefCell;
use std::fmt;

use serde::Deserialize;
use serde::de::{self, DeserializeSeed, Deserializer, IgnoredAny, MapAccess, SeqAccess, Visitor};

use crate::sample::{DetectorMethod, GazeEyes, GazeSample, PupilSample, PupilUnit, Sample};

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
#[derive(Clone, Copy, Debug, PartialEq, Deserialize)]
pub struct Ellipse {
    pub center: [f64; 2],
    pub axes: [f64; 2],
    pub angle: f64,
}

/// The 3D model's pupil circle in eye-camera coordinates (mm).
#[derive(Clone, Copy, Debug, PartialEq, Deserialize)]
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
    let kind = parse_topic(topic);
    let slot = FieldSlot::default();
    match kind {
        TopicKind::Unknown => Err(DecodeError::UnknownTopic(topic.to_owned())),
        TopicKind::Pupil { eye, method } => {
            let raw = run(topic, payload, &slot, PupilSeed { slot: &slot })?;
            raw.finish(topic, eye, method).map(Datum::Pupil)
        }
        TopicKind::Gaze { eyes } => {
            let raw = run(topic, payload, &slot, GazeSeed { slot: &slot })?;
            raw.finish(topic, eyes).map(Datum::Gaze)
        }
    }
}

fn run<'de, S: DeserializeSeed<'de>>(
    topic: &str,
    payload: &'de [u8],
    slot: &FieldSlot,
    seed: S,
) -> Result<S::Value, DecodeError> {
    let mut de = rmp_serde::Deserializer::from_read_ref(payload);
    let value = seed.deserialize(&mut de);
    match value {
        Ok(v) => Ok(v),
        Err(e) => {
            let reason = e.to_string();
            match slot.0.borrow_mut().take() {
                Some(field) => Err(DecodeError::Field {
                    topic: topic.to_owned(),
                    field,
                    reason,
                }),
                None => Err(DecodeError::Malformed {
                    topic: topic.to_owned(),
                    reason,
                }),
            }
        }
    }
}

/// Remembers the path of the field whose value failed to decode. Only
/// written on error.
#[derive(Default)]
struct FieldSlot(RefCell<Option<String>>);

impl FieldSlot {
    fn set_innermost(&self, name: &str) {
        let mut s = self.0.borrow_mut();
        if s.is_none() {
            *s = Some(name.to_owned());
        }
    }

    fn prefix(&self, prefix: &str) {
        let mut s = self.0.borrow_mut();
        *s = Some(match s.take() {
            Some(inner) => format!("{prefix}.{inner}"),
            None => prefix.to_owned(),
        });
    }
}

fn value<'de, A: MapAccess<'de>, T: Deserialize<'de>>(
    map: &mut A,
    slot: &FieldSlot,
    name: &'static str,
) -> Result<T, A::Error> {
    map.next_value::<T>()
        .inspect_err(|_| slot.set_innermost(name))
}

/// The keys the decoders look at.
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
    /// A field Pupil sends that gazelight does not use.
    Unused,
    Unknown,
}

impl<'de> Deserialize<'de> for Key {
    fn deserialize<D: Deserializer<'de>>(d: D) -> Result<Self, D::Error> {
        struct KeyVisitor;
        impl<'de> Visitor<'de> for KeyVisitor {
            type Value = Key;
            fn expecting(&self, f: &mut fmt::Formatter) -> fmt::Result {
                f.write_str("a map key")
            }
            fn visit_str<E: de::Error>(self, v: &str) -> Result<Key, E> {
                Ok(match v {
                    "id" => Key::Id,
                    "timestamp" => Key::Timestamp,
                    "confidence" => Key::Confidence,
                    "diameter" => Key::Diameter,
                    "diameter_3d" => Key::Diameter3d,
                    "norm_pos" => Key::NormPos,
                    "method" => Key::Method,
                    "ellipse" => Key::Ellipse,
                    "model_confidence" => Key::ModelConfidence,
                    "circle_3d" => Key::Circle3d,
                    "theta" => Key::Theta,
                    "phi" => Key::Phi,
                    "base_data" => Key::BaseData,
                    "topic"
                    | "sphere"
                    | "projected_sphere"
                    | "location"
                    | "model_id"
                    | "model_birth_timestamp"
                    | "gaze_point_3d"
                    | "gaze_normal_3d"
                    | "gaze_normals_3d"
                    | "eye_center_3d"
                    | "eye_centers_3d"
                    | "__raw_data__" => Key::Unused,
                    _ => Key::Unknown,
                })
            }
            fn visit_bytes<E: de::Error>(self, v: &[u8]) -> Result<Key, E> {
                match std::str::from_utf8(v) {
                    Ok(s) => self.visit_str(s),
                    Err(_) => Ok(Key::Unknown),
                }
            }
            fn visit_u64<E: de::Error>(self, _: u64) -> Result<Key, E> {
                Ok(Key::Unknown)
            }
            fn visit_i64<E: de::Error>(self, _: i64) -> Result<Key, E> {
                Ok(Key::Unknown)
            }
            fn visit_f64<E: de::Error>(self, _: f64) -> Result<Key, E> {
                Ok(Key::Unknown)
            }
            fn visit_bool<E: de::Error>(self, _: bool) -> Result<Key, E> {
                Ok(Key::Unknown)
            }
            fn visit_unit<E: de::Error>(self) -> Result<Key, E> {
                Ok(Key::Unknown)
            }
        }
        d.deserialize_any(KeyVisitor)
    }
}

/// The detector method from Pupil's `method` string (`"2d c++"`,
/// `"3d c++"`, `"pye3d 0.3.0 real-time"`, …).
struct MethodStr(Option<DetectorMethod>);

impl<'de> Deserialize<'de> for MethodStr {
    fn deserialize<D: Deserializer<'de>>(d: D) -> Result<Self, D::Error> {
        struct V;
        impl<'de> Visitor<'de> for V {
            type Value = MethodStr;
            fn expecting(&self, f: &mut fmt::Formatter) -> fmt::Result {
                f.write_str("a method string")
            }
            fn visit_str<E: de::Error>(self, v: &str) -> Result<MethodStr, E> {
                Ok(MethodStr(if v.contains("3d") {
                    Some(DetectorMethod::Pupil3d)
                } else if v.contains("2d") {
                    Some(DetectorMethod::Pupil2d)
                } else {
                    None
                }))
            }
        }
        d.deserialize_str(V)
    }
}

#[derive(Default, Clone, Copy)]
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

struct PupilSeed<'s> {
    slot: &'s FieldSlot,
}

impl<'de> DeserializeSeed<'de> for PupilSeed<'_> {
    type Value = RawPupil;
    fn deserialize<D: Deserializer<'de>>(self, d: D) -> Result<RawPupil, D::Error> {
        d.deserialize_map(self)
    }
}

impl<'de> Visitor<'de> for PupilSeed<'_> {
    type Value = RawPupil;
    fn expecting(&self, f: &mut fmt::Formatter) -> fmt::Result {
        f.write_str("a pupil datum (msgpack map)")
    }
    fn visit_map<A: MapAccess<'de>>(self, mut map: A) -> Result<RawPupil, A::Error> {
        let s = self.slot;
        let mut r = RawPupil::default();
        while let Some(key) = map.next_key::<Key>()? {
            match key {
                Key::Id => r.id = Some(value(&mut map, s, "id")?),
                Key::Timestamp => r.timestamp = Some(value(&mut map, s, "timestamp")?),
                Key::Confidence => r.confidence = Some(value(&mut map, s, "confidence")?),
                Key::Diameter => r.diameter = Some(value(&mut map, s, "diameter")?),
                Key::Diameter3d => r.diameter_3d = Some(value(&mut map, s, "diameter_3d")?),
                Key::NormPos => r.norm_pos = Some(value(&mut map, s, "norm_pos")?),
                Key::Method => r.method = value::<_, MethodStr>(&mut map, s, "method")?.0,
                Key::Ellipse => r.ellipse = Some(value(&mut map, s, "ellipse")?),
                Key::ModelConfidence => {
                    r.model_confidence = Some(value(&mut map, s, "model_confidence")?)
                }
                Key::Circle3d => r.circle_3d = Some(value(&mut map, s, "circle_3d")?),
                Key::Theta => r.theta = Some(value(&mut map, s, "theta")?),
                Key::Phi => r.phi = Some(value(&mut map, s, "phi")?),
                Key::BaseData | Key::Unknown => {
                    r.unknown_fields += 1;
                    map.next_value::<IgnoredAny>()?;
                }
                Key::Unused => {
                    map.next_value::<IgnoredAny>()?;
                }
            }
        }
        Ok(r)
    }
}

fn unit_interval(topic: &str, field: &str, v: f64) -> Result<f32, DecodeError> {
    if (0.0..=1.0).contains(&v) {
        Ok(v as f32)
    } else {
        Err(DecodeError::Field {
            topic: topic.to_owned(),
            field: field.to_owned(),
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
            &name("confidence"),
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

#[derive(Default, Clone, Copy)]
struct RawGaze {
    timestamp: Option<f64>,
    confidence: Option<f64>,
    norm_pos: Option<[f64; 2]>,
    base: [Option<RawPupil>; 2],
    n_base: usize,
    unknown_fields: u32,
}

struct GazeSeed<'s> {
    slot: &'s FieldSlot,
}

impl<'de> DeserializeSeed<'de> for GazeSeed<'_> {
    type Value = RawGaze;
    fn deserialize<D: Deserializer<'de>>(self, d: D) -> Result<RawGaze, D::Error> {
        d.deserialize_map(self)
    }
}

impl<'de> Visitor<'de> for GazeSeed<'_> {
    type Value = RawGaze;
    fn expecting(&self, f: &mut fmt::Formatter) -> fmt::Result {
        f.write_str("a gaze datum (msgpack map)")
    }
    fn visit_map<A: MapAccess<'de>>(self, mut map: A) -> Result<RawGaze, A::Error> {
        let s = self.slot;
        let mut r = RawGaze::default();
        while let Some(key) = map.next_key::<Key>()? {
            match key {
                Key::Timestamp => r.timestamp = Some(value(&mut map, s, "timestamp")?),
                Key::Confidence => r.confidence = Some(value(&mut map, s, "confidence")?),
                Key::NormPos => r.norm_pos = Some(value(&mut map, s, "norm_pos")?),
                Key::BaseData => {
                    let (base, n) = map.next_value_seed(BaseDataSeed { slot: s })?;
                    r.base = base;
                    r.n_base = n;
                }
                Key::Unknown => {
                    r.unknown_fields += 1;
                    map.next_value::<IgnoredAny>()?;
                }
                _ => {
                    map.next_value::<IgnoredAny>()?;
                }
            }
        }
        Ok(r)
    }
}

/// `base_data`: a list of up to two pupil datums (more are skipped).
struct BaseDataSeed<'s> {
    slot: &'s FieldSlot,
}

impl<'de> DeserializeSeed<'de> for BaseDataSeed<'_> {
    type Value = ([Option<RawPupil>; 2], usize);
    fn deserialize<D: Deserializer<'de>>(self, d: D) -> Result<Self::Value, D::Error> {
        let slot = self.slot;
        d.deserialize_seq(self).inspect_err(|_| {
            if slot.0.borrow().is_none() {
                slot.prefix("base_data");
            }
        })
    }
}

impl<'de> Visitor<'de> for BaseDataSeed<'_> {
    type Value = ([Option<RawPupil>; 2], usize);
    fn expecting(&self, f: &mut fmt::Formatter) -> fmt::Result {
        f.write_str("a list of pupil datums")
    }
    fn visit_seq<A: SeqAccess<'de>>(self, mut seq: A) -> Result<Self::Value, A::Error> {
        let mut out = [None, None];
        let mut n = 0;
        for (i, entry) in out.iter_mut().enumerate() {
            let had = self.slot.0.borrow().is_some();
            match seq.next_element_seed(PupilSeed { slot: self.slot }) {
                Ok(Some(p)) => {
                    *entry = Some(p);
                    n += 1;
                }
                Ok(None) => return Ok((out, n)),
                Err(e) => {
                    if had {
                        return Err(e);
                    }
                    self.slot.prefix(&format!("base_data[{i}]"));
                    return Err(e);
                }
            }
        }
        while seq.next_element::<IgnoredAny>()?.is_some() {
            n += 1;
        }
        Ok((out, n))
    }
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
            "confidence",
            self.confidence.ok_or_else(|| missing("confidence"))?,
        )?;
        let p = self.norm_pos.ok_or_else(|| missing("norm_pos"))?;
        let mut base: [Option<PupilSample>; 2] = [None, None];
        for (i, raw) in self.base.iter().enumerate() {
            if let Some(raw) = raw {
                let prefix = format!("base_data[{i}]");
                let d = raw.finish_with(topic, &prefix, None, None)?;
                let slot = &mut base[d.sample.eye as usize];
                if slot.is_some() {
                    return Err(DecodeError::Field {
                        topic: topic.to_owned(),
                        field: prefix,
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
}
