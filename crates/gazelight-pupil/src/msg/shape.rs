//! Datum shapes: the byte layout of one topic's datums, learnt from a
//! datum the msgpack walk decoded, so that the datums after it with the
//! same layout are decoded by a masked comparison and a few 8-byte loads.
//!
//! A Pupil Capture source writes every datum of a topic with the same keys,
//! in the same order, with the same value types: a `pupil.0.3d` datum
//! differs from the one before only in the 8 payload bytes of its float64
//! values (`0xcb` + 8 bytes). A [`ShapeCache`] holds, per topic:
//!
//! - the *template*: the bytes of one datum that decoded;
//! - a *mask* that is 0 on the payload bytes of the template's float64
//!   values whose content does not change how the datum decodes, and
//!   `0xff` on every other byte (markers, lengths, keys, strings, integers);
//! - the *slots*: which of those float64 values the decoder stores, and
//!   where (for a `pupil.N.3d` datum: `timestamp`, `confidence`,
//!   `diameter`, … `phi`).
//!
//! A datum of the template's length whose bytes equal the template's
//! wherever the mask is `0xff` has the template's msgpack structure (its
//! free bytes are float64 payloads, and any 8 bytes are a valid float64),
//! so the walk would see the same markers, keys and strings and store the
//! same values, except those read from the slots. The fast path therefore
//! copies the template's decoded fields, reads the slots from the datum and
//! runs the same checks (`finish`) as the walk; a datum those checks
//! reject, like one that does not match, takes the walk, so errors are
//! always the walk's. Its result equals the walk's for every input (see
//! the tests, which compare both on mutated and real datums).
//!
//! **How the slots are found.** The decoder's code is not instrumented:
//! each float64 payload of the learnt datum is replaced in turn by a
//! sentinel value and the datum is decoded again. If exactly one stored
//! field changes, to the sentinel, that payload is that field's slot; if
//! nothing changes (a skipped field: `sphere`, `base_data` of a gaze whose
//! topic names its eyes, a duplicate key's overwritten value), it is free
//! without a slot; anything else (the walk fails: an eye `id` written as a
//! float; two fields change) keeps the payload under the mask, so it must
//! match byte for byte. The sentinels have a fractional part, so a value
//! the decoder checks to be an integer fails under them.
//!
//! **Cost bounds.** Learning decodes the datum once per float64 value
//! (at most [`MAX_FLOATS`], payloads of at most [`MAX_SHAPE_BYTES`]).
//! It happens for a topic's first datum that decodes, then again only after
//! [`ShapeCache::learn_after`] datums in a row decoded without matching;
//! that count doubles with every learning, up to [`RELEARN_MAX`], so a
//! source whose layout keeps changing costs at most a few percent over the
//! plain walk.

use super::{
    Cur, DecodeError, DetectorMethod, GazeEyes, RawGaze, RawPupil, SCALAR_SIZE, Sample, TopicKind,
    read_gaze, read_pupil_into,
};

/// Largest payload a shape is learnt from, bytes (Pupil's datums are under
/// 2 KiB; a gaze datum with two 3D base datums is about 1.4 KiB).
pub const MAX_SHAPE_BYTES: usize = 16 * 1024;
/// Most float64 values a learnt datum may hold.
pub const MAX_FLOATS: usize = 256;
/// Datums in a row that decode without matching before a shape is
/// learnt again (the first time); doubled at every learning.
const RELEARN_FIRST: u32 = 8;
/// Upper bound of that count.
pub const RELEARN_MAX: u32 = 1024;

/// Float64 fields of a [`RawPupil`], in slot order.
const PUPIL_SLOTS: usize = 21;
/// Float64 fields of a [`RawGaze`]: its own 4, then the two base datums'.
const GAZE_SLOTS: usize = 4 + 2 * PUPIL_SLOTS;

/// The float64 field `i` of a pupil datum, if it is present.
fn pupil_slot(r: &mut RawPupil, i: usize) -> Option<&mut f64> {
    match i {
        0 => r.timestamp.as_mut(),
        1 => r.confidence.as_mut(),
        2 => r.diameter.as_mut(),
        3 => r.diameter_3d.as_mut(),
        4 | 5 => r.norm_pos.as_mut().map(|p| &mut p[i - 4]),
        6 | 7 => r.ellipse.as_mut().map(|e| &mut e.center[i - 6]),
        8 | 9 => r.ellipse.as_mut().map(|e| &mut e.axes[i - 8]),
        10 => r.ellipse.as_mut().map(|e| &mut e.angle),
        11 => r.model_confidence.as_mut(),
        12..=14 => r.circle_3d.as_mut().map(|c| &mut c.center[i - 12]),
        15..=17 => r.circle_3d.as_mut().map(|c| &mut c.normal[i - 15]),
        18 => r.circle_3d.as_mut().map(|c| &mut c.radius),
        19 => r.theta.as_mut(),
        20 => r.phi.as_mut(),
        _ => None,
    }
}

/// The float64 field `i` of a gaze datum, if it is present.
fn gaze_slot(r: &mut RawGaze, i: usize) -> Option<&mut f64> {
    match i {
        0 => r.timestamp.as_mut(),
        1 => r.confidence.as_mut(),
        2 | 3 => r.norm_pos.as_mut().map(|p| &mut p[i - 2]),
        _ => {
            let j = i.checked_sub(4)?;
            let base = r.base.get_mut(j / PUPIL_SLOTS)?.as_mut()?;
            pupil_slot(base, j % PUPIL_SLOTS)
        }
    }
}

/// What a shape decodes to: the topic's classification and the fields of
/// the template datum.
#[derive(Clone, Copy, PartialEq)]
#[expect(
    clippy::large_enum_variant,
    reason = "copied from the shape for every datum: boxing would allocate per datum"
)]
enum Raw {
    Pupil {
        eye: Option<u8>,
        method: Option<DetectorMethod>,
        raw: RawPupil,
    },
    Gaze {
        eyes: Option<GazeEyes>,
        raw: RawGaze,
    },
}

impl Raw {
    /// Walks `payload` as the record path does (see
    /// [`super::decode_record_sample_as`]) and keeps the fields.
    fn decode(kind: TopicKind, payload: &[u8]) -> Option<Raw> {
        let mut c = Cur { b: payload, p: 0 };
        let raw = match kind {
            TopicKind::Unknown => return None,
            TopicKind::Pupil { eye, method } => {
                let mut raw = RawPupil::default();
                read_pupil_into(&mut c, 0, &mut raw).ok()?;
                Raw::Pupil { eye, method, raw }
            }
            TopicKind::Gaze { eyes } => Raw::Gaze {
                eyes,
                raw: read_gaze(&mut c, eyes.is_none()).ok()?,
            },
        };
        c.end().ok()?;
        Some(raw)
    }

    fn slots(&self) -> usize {
        match self {
            Raw::Pupil { .. } => PUPIL_SLOTS,
            Raw::Gaze { .. } => GAZE_SLOTS,
        }
    }

    fn slot(&mut self, i: usize) -> Option<&mut f64> {
        match self {
            Raw::Pupil { raw, .. } => pupil_slot(raw, i),
            Raw::Gaze { raw, .. } => gaze_slot(raw, i),
        }
    }

    /// The bits of every slot (`None` where the field is absent).
    fn slot_bits(mut self) -> [Option<u64>; GAZE_SLOTS] {
        let mut out = [None; GAZE_SLOTS];
        for (i, o) in out.iter_mut().enumerate().take(self.slots()) {
            *o = self.slot(i).map(|v| v.to_bits());
        }
        out
    }

    /// The datum with every present slot set to 0: what is left are the
    /// fields a float64 payload must not change (ids, method, counts, which
    /// fields are present).
    fn without_slots(mut self) -> Raw {
        for i in 0..self.slots() {
            if let Some(v) = self.slot(i) {
                *v = 0.0;
            }
        }
        self
    }

    /// The sample and the checks of the walk's record path.
    #[inline]
    fn finish(self, topic: &str) -> Result<Sample, DecodeError> {
        match self {
            Raw::Pupil { eye, method, raw } => raw
                .finish(topic, eye, method)
                .map(|d| Sample::Pupil(d.sample)),
            Raw::Gaze { eyes, raw } => raw.finish(topic, eyes).map(|g| Sample::Gaze(g.sample)),
        }
    }
}

/// A learnt layout; see the module docs.
struct Shape {
    template: Box<[u8]>,
    mask: Box<[u8]>,
    /// `(slot, offset of the float64's first payload byte)`.
    slots: Box<[(u8, u32)]>,
    raw: Raw,
    kind: TopicKind,
}

/// The offsets of the payload bytes of every float64 value in `b` (one
/// complete msgpack value), or `None` if there are more than
/// [`MAX_FLOATS`] or `b` is not one complete value.
fn float_offsets(b: &[u8]) -> Option<Vec<u32>> {
    let mut out = Vec::new();
    let mut p = 0usize;
    let mut rem = 1usize;
    // Every value takes at least one byte, so this ends within b.len() steps.
    while rem > 0 {
        let m = *b.get(p)?;
        rem -= 1;
        let children = if m == 0xcb {
            if out.len() == MAX_FLOATS {
                return None;
            }
            out.push(u32::try_from(p + 1).ok()?);
            p += 9;
            0
        } else if m & 0xe0 == 0x80 {
            p += 1;
            let n = (m & 0x0f) as usize;
            if m < 0x90 { 2 * n } else { n }
        } else {
            let size = SCALAR_SIZE[m as usize];
            if size != 0 {
                p += size as usize;
                0
            } else {
                let (len, children) = Cur::sized_value(b, p)?;
                p = p.checked_add(len)?;
                children
            }
        };
        rem = rem.checked_add(children)?;
    }
    (p == b.len()).then_some(out)
}

/// The sentinel for the `k`-th float64 of a datum: a value in (1, 2) with
/// a fractional part, different from `orig`.
fn sentinel(k: usize, orig: [u8; 8]) -> [u8; 8] {
    let s = (0x3ff5_a5a5_0000_0000u64 | k as u64).to_be_bytes();
    if s == orig {
        (0x3ff6_9696_0000_0000u64 | k as u64).to_be_bytes()
    } else {
        s
    }
}

impl Shape {
    /// Learns the layout of `payload` (a datum of `kind` that the walk
    /// decoded); `None` when it is too large or holds too many floats.
    fn learn(kind: TopicKind, payload: &[u8]) -> Option<Shape> {
        if payload.len() > MAX_SHAPE_BYTES {
            return None;
        }
        let raw = Raw::decode(kind, payload)?;
        let bits = raw.slot_bits();
        let rest = raw.without_slots();
        let offsets = float_offsets(payload)?;
        let mut mask = vec![0xffu8; payload.len()].into_boxed_slice();
        let mut slots = Vec::new();
        let mut scratch = payload.to_vec();
        for (k, &off) in offsets.iter().enumerate() {
            let o = off as usize;
            let field = scratch.get_mut(o..o + 8)?;
            let mut orig = [0u8; 8];
            orig.copy_from_slice(field);
            let s = sentinel(k, orig);
            field.copy_from_slice(&s);
            let probed = Raw::decode(kind, &scratch);
            scratch.get_mut(o..o + 8)?.copy_from_slice(&orig);
            let Some(probed) = probed else { continue };
            if probed.without_slots() != rest {
                continue;
            }
            let now = probed.slot_bits();
            let mut changed = (0..GAZE_SLOTS).filter(|&i| now[i] != bits[i]);
            match (changed.next(), changed.next()) {
                (None, _) => {}
                (Some(i), None) if now[i] == Some(u64::from_be_bytes(s)) => {
                    slots.push((u8::try_from(i).ok()?, off));
                }
                _ => continue,
            }
            mask.get_mut(o..o + 8)?.fill(0);
        }
        Some(Shape {
            template: payload.into(),
            mask,
            slots: slots.into_boxed_slice(),
            raw,
            kind,
        })
    }

    /// True if `b` has the template's length and bytes wherever the mask
    /// is set.
    #[inline]
    fn matches(&self, b: &[u8]) -> bool {
        if b.len() != self.template.len() {
            return false;
        }
        let word = |s: &[u8]| {
            let mut w = [0u8; 8];
            w.copy_from_slice(s);
            u64::from_ne_bytes(w)
        };
        let mut diff = 0u64;
        let (x, t, m) = (
            b.chunks_exact(8),
            self.template.chunks_exact(8),
            self.mask.chunks_exact(8),
        );
        let tails = (x.remainder(), t.remainder(), m.remainder());
        for ((x, t), m) in x.zip(t).zip(m) {
            diff |= (word(x) ^ word(t)) & word(m);
        }
        for ((x, t), m) in tails.0.iter().zip(tails.1).zip(tails.2) {
            diff |= u64::from((x ^ t) & m);
        }
        diff == 0
    }

    /// The template's fields with the slots read from `b` (which
    /// [`Self::matches`]); `None` only if that invariant were broken.
    #[inline]
    fn raw_of(&self, b: &[u8]) -> Option<Raw> {
        let mut raw = self.raw;
        for &(slot, off) in self.slots.iter() {
            let o = off as usize;
            let mut v = [0u8; 8];
            v.copy_from_slice(b.get(o..o + 8)?);
            *raw.slot(slot as usize)? = f64::from_be_bytes(v);
        }
        Some(raw)
    }
}

/// A topic's learnt datum layout (see the module docs); one per topic,
/// kept by the reader next to the topic's classification.
#[derive(Default)]
pub struct ShapeCache {
    shape: Option<Box<Shape>>,
    /// Datums in a row that decoded without matching.
    misses: u32,
    /// How many such datums make the next learning (0: the next datum).
    learn_after: u32,
    hits: u64,
    learnt: u32,
}

impl ShapeCache {
    /// Datums decoded by the fast path.
    pub fn hits(&self) -> u64 {
        self.hits
    }

    /// Layouts learnt (including attempts that found none).
    pub fn learnt(&self) -> u32 {
        self.learnt
    }

    /// Datums in a row that must decode without matching before the layout
    /// is learnt again.
    pub fn learn_after(&self) -> u32 {
        self.learn_after
    }
}

/// [`super::decode_record_sample_as`] through a topic's [`ShapeCache`]:
/// the same result for every payload; a payload with the learnt layout is
/// decoded without the msgpack walk.
#[inline]
pub fn decode_record_sample_shaped(
    kind: TopicKind,
    topic: &str,
    payload: &[u8],
    cache: &mut ShapeCache,
) -> Result<Result<Option<Sample>, DecodeError>, super::BadRecord> {
    if let Some(shape) = &cache.shape
        && shape.kind == kind
        && shape.matches(payload)
        && let Some(raw) = shape.raw_of(payload)
        // A datum the checks reject (a NaN timestamp, say) takes the walk,
        // which also reports a payload that is not msgpack at all.
        && let Ok(sample) = raw.finish(topic)
    {
        cache.misses = 0;
        cache.hits += 1;
        return Ok(Ok(Some(sample)));
    }
    let decoded = super::decode_record_sample_as(kind, topic, payload)?;
    if matches!(decoded, Ok(Some(_))) {
        if cache.misses >= cache.learn_after {
            learn_into(cache, kind, payload);
        } else {
            cache.misses += 1;
        }
    }
    Ok(decoded)
}

#[inline(never)]
fn learn_into(cache: &mut ShapeCache, kind: TopicKind, payload: &[u8]) {
    cache.shape = Shape::learn(kind, payload).map(Box::new);
    cache.learnt = cache.learnt.saturating_add(1);
    cache.misses = 0;
    cache.learn_after = if cache.learn_after == 0 {
        RELEARN_FIRST
    } else {
        cache.learn_after.saturating_mul(2).min(RELEARN_MAX)
    };
}

#[cfg(test)]
mod tests {
    use super::super::{decode_record_sample_as, parse_topic};
    use super::*;
    use rmpv::Value as V;

    /// xorshift64*: a fixed, dependency-free stream of test inputs.
    struct Rng(u64);
    impl Rng {
        fn next(&mut self) -> u64 {
            self.0 ^= self.0 >> 12;
            self.0 ^= self.0 << 25;
            self.0 ^= self.0 >> 27;
            self.0.wrapping_mul(0x2545_f491_4f6c_dd1d)
        }
        fn below(&mut self, n: usize) -> usize {
            (self.next() % n as u64) as usize
        }
    }

    fn arr(v: &[f64]) -> V {
        V::Array(v.iter().map(|x| V::from(*x)).collect())
    }

    fn map(e: Vec<(&str, V)>) -> V {
        V::Map(e.into_iter().map(|(k, v)| (V::from(k), v)).collect())
    }

    fn enc(v: &V) -> Vec<u8> {
        let mut b = Vec::new();
        rmpv::encode::write_value(&mut b, v).expect("encode");
        b
    }

    /// A Pupil Capture v3 2D datum (the fields and order Capture writes).
    fn pupil_2d(topic: &str, id: V, t: f64, d_px: f64) -> Vec<(&'static str, V)> {
        vec![
            ("topic", V::from(topic)),
            ("id", id),
            ("method", V::from("2d c++")),
            ("timestamp", V::from(t)),
            ("confidence", V::from(0.97)),
            ("diameter", V::from(d_px)),
            ("norm_pos", arr(&[0.45, 0.52])),
            (
                "ellipse",
                map(vec![
                    ("center", arr(&[86.65, 90.67])),
                    ("axes", arr(&[d_px * 0.92, d_px])),
                    ("angle", V::from(-21.7)),
                ]),
            ),
        ]
    }

    /// A pye3d datum with every field Capture v3 sends.
    fn pupil_3d(eye: u8, t: f64, d_mm: f64) -> V {
        let mut m = pupil_2d(&format!("pupil.{eye}.3d"), V::from(eye), t, d_mm * 9.47);
        m[2].1 = V::from("pye3d 0.3.0 real-time");
        m.extend([
            (
                "sphere",
                map(vec![
                    ("center", arr(&[1.2, 0.7, 41.3])),
                    ("radius", V::from(10.39)),
                ]),
            ),
            (
                "circle_3d",
                map(vec![
                    ("center", arr(&[1.52, -0.48, 31.02])),
                    ("normal", arr(&[0.051, -0.102, -0.993])),
                    ("radius", V::from(d_mm / 2.0)),
                ]),
            ),
            ("diameter_3d", V::from(d_mm)),
            ("location", arr(&[86.65, 90.67])),
            ("model_confidence", V::from(1.0)),
            ("model_id", V::from(3)),
            ("theta", V::from(1.673)),
            ("phi", V::from(-1.518)),
        ]);
        map(m)
    }

    fn gaze(topic: &str, base: Vec<V>, t: f64) -> V {
        map(vec![
            ("topic", V::from(topic)),
            ("gaze_point_3d", arr(&[12.3, -40.1, 497.0])),
            ("confidence", V::from(0.95)),
            ("timestamp", V::from(t)),
            ("base_data", V::Array(base)),
            ("norm_pos", arr(&[0.512, 0.433])),
        ])
    }

    /// `(topic, payload)` of every datum layout the tests exercise: Capture
    /// v3's topics, the legacy topics whose eyes come from the payload, an
    /// eye id written as a float, and a duplicate key.
    fn datums() -> Vec<(String, Vec<u8>)> {
        let t = 8_316.25;
        let p3 = |eye| pupil_3d(eye, t, 4.1);
        let mut dup = pupil_2d("pupil.1.2d", V::from(1), t, 38.0);
        dup.push(("diameter", V::from(39.5)));
        vec![
            (
                "pupil.0.2d".into(),
                enc(&map(pupil_2d("pupil.0.2d", V::from(0), t, 38.0))),
            ),
            ("pupil.1.3d".into(), enc(&p3(1))),
            (
                "pupil".into(),
                enc(&map(pupil_2d("pupil", V::from(1.0), t, 38.0))),
            ),
            ("pupil.1.2d".into(), enc(&map(dup))),
            (
                "gaze.3d.01.".into(),
                enc(&gaze("gaze.3d.01.", vec![p3(0), p3(1)], t)),
            ),
            (
                "gaze.3d.1.".into(),
                enc(&gaze("gaze.3d.1.", vec![p3(1)], t)),
            ),
            ("gaze".into(), enc(&gaze("gaze", vec![p3(0), p3(1)], t))),
        ]
    }

    fn shaped(
        topic: &str,
        payload: &[u8],
        cache: &mut ShapeCache,
    ) -> Result<Result<Option<Sample>, DecodeError>, crate::msg::BadRecord> {
        decode_record_sample_shaped(parse_topic(topic), topic, payload, cache)
    }

    /// Debug text compares NaN payloads as equal, where `==` would not.
    fn same<T: std::fmt::Debug>(a: &T, b: &T) -> bool {
        format!("{a:?}") == format!("{b:?}")
    }

    /// The shape path gives the walk's result for real layouts and for
    /// every mutation of them: new float values (NaN and infinities
    /// included), any byte changed, bytes cut or added.
    #[test]
    fn shaped_equals_walk_on_mutated_datums() {
        let mut rng = Rng(0x9e37_79b9_7f4a_7c15);
        for (topic, base) in datums() {
            let kind = parse_topic(&topic);
            let floats = float_offsets(&base).expect("one msgpack value");
            let mut cache = ShapeCache::default();
            let (mut checked, mut ok) = (0u64, 0u64);
            for round in 0..20_000 {
                let mut b = base.clone();
                match round % 5 {
                    // New values in 1 to 4 floats: the common case.
                    0 | 1 => {
                        for _ in 0..=rng.below(4) {
                            let o = floats[rng.below(floats.len())] as usize;
                            let v = match rng.below(8) {
                                0 => f64::NAN.to_bits(),
                                1 => f64::INFINITY.to_bits(),
                                2 => rng.next(),
                                _ => (rng.next() as f64 / u64::MAX as f64 * 200.0).to_bits(),
                            };
                            b[o..o + 8].copy_from_slice(&v.to_be_bytes());
                        }
                    }
                    // One byte anywhere.
                    2 | 3 => {
                        let i = rng.below(b.len());
                        b[i] = rng.next() as u8;
                    }
                    // Cut or grown.
                    _ => {
                        if rng.below(2) == 0 {
                            b.truncate(rng.below(b.len()));
                        } else {
                            b.push(rng.next() as u8);
                        }
                    }
                }
                let walk = decode_record_sample_as(kind, &topic, &b);
                let fast = shaped(&topic, &b, &mut cache);
                assert!(
                    same(&walk, &fast),
                    "{topic} round {round}: walk {walk:?}, shaped {fast:?}, payload {b:02x?}"
                );
                checked += 1;
                ok += u64::from(matches!(walk, Ok(Ok(Some(_)))));
            }
            // The fast path carried most of the datums that decoded, so the
            // comparison above covers it and not only the walk.
            assert!(
                cache.hits() * 2 > ok,
                "{topic}: {} hits of {ok} decoded ({checked} checked)",
                cache.hits()
            );
        }
    }

    /// What the shape path reads is what was written: values from the
    /// generator, not from the decoder.
    #[test]
    fn shaped_reads_the_written_values() {
        let mut cache = ShapeCache::default();
        let mut gcache = ShapeCache::default();
        let mut rng = Rng(7);
        for i in 0..2_000 {
            let t = 8_316.25 + i as f64 / 200.0;
            let d_mm = 2.0 + (rng.next() % 6000) as f64 / 1000.0;
            let d = pupil_3d(1, t, d_mm);
            let Ok(Ok(Some(Sample::Pupil(p)))) = shaped("pupil.1.3d", &enc(&d), &mut cache) else {
                panic!("datum {i} did not decode");
            };
            assert_eq!(p.t_secs, t);
            assert_eq!(p.eye, 1);
            assert_eq!(p.diameter_mm, Some(d_mm as f32));
            assert_eq!(p.diameter_raw, (d_mm * 9.47) as f32);
            let g = gaze("gaze.3d.01.", vec![pupil_3d(0, t, d_mm), d], t + 0.001);
            let Ok(Ok(Some(Sample::Gaze(g)))) = shaped("gaze.3d.01.", &enc(&g), &mut gcache) else {
                panic!("gaze {i} did not decode");
            };
            assert_eq!(g.t_secs, t + 0.001);
            // Pupil's norm_pos is bottom-left, gaze_uv top-left.
            assert_eq!(g.gaze_uv, [0.512f32, (1.0f64 - 0.433) as f32]);
        }
        // Learnt once from the first datum, then every datum matched.
        assert_eq!((cache.learnt(), cache.hits()), (1, 1_999));
        assert_eq!((gcache.learnt(), gcache.hits()), (1, 1_999));
    }

    /// Two layouts in turn on one topic: the first one learnt keeps
    /// matching every other datum, and nothing is learnt again.
    #[test]
    fn alternating_layouts_keep_the_first() {
        let all = datums();
        let (topic, a) = &all[0];
        let b = enc(&pupil_3d(0, 8_316.25, 4.1));
        let mut cache = ShapeCache::default();
        for i in 0..10_000 {
            let p = if i % 2 == 0 { a } else { &b };
            assert!(matches!(shaped(topic, p, &mut cache), Ok(Ok(Some(_)))));
        }
        assert_eq!((cache.learnt(), cache.hits()), (1, 4_999));
    }

    /// A topic whose layout changes with every datum (a string of another
    /// length each time) learns ever more rarely: it costs little more
    /// than the walk alone.
    #[test]
    fn changing_layouts_learn_rarely() {
        let mut cache = ShapeCache::default();
        for i in 0..100_000 {
            let mut m = pupil_2d("pupil.0.2d", V::from(0), 1.0, 38.0);
            m[2].1 = V::from(format!("2d c++{}", " ".repeat(i % 3000)));
            let p = enc(&map(m));
            assert!(matches!(
                shaped("pupil.0.2d", &p, &mut cache),
                Ok(Ok(Some(_)))
            ));
        }
        // A layout comes back only every 3000 datums.
        assert!(cache.hits() < 100, "{} hits", cache.hits());
        // 0, 8, 16, … 1024 misses apart: about 100 learnings, not 100 000.
        assert!(cache.learnt() < 110, "{} learnings", cache.learnt());
        assert_eq!(cache.learn_after(), RELEARN_MAX);
    }

    /// Float payloads the walk stores nowhere are free, ones it must see as
    /// integers stay fixed.
    #[test]
    fn slots_and_free_floats() {
        let all = datums();
        // The legacy `pupil` topic: the eye id is a float 1.0, which must stay.
        let (topic, legacy) = &all[2];
        let shape = Shape::learn(parse_topic(topic), legacy).expect("learns");
        let id_at = legacy
            .windows(3)
            .position(|w| w == [0xa2, b'i', b'd'])
            .expect("id key")
            + 4;
        assert_eq!(shape.template[id_at - 1], 0xcb);
        assert!(shape.mask[id_at..id_at + 8].iter().all(|&m| m == 0xff));
        // 2D: timestamp, confidence, diameter, norm_pos ×2, ellipse ×5.
        assert_eq!(shape.slots.len(), 10);
        // The duplicate `diameter`: its first value is free, the second a slot.
        let (topic, dup) = &all[3];
        let shape = Shape::learn(parse_topic(topic), dup).expect("learns");
        let first = dup
            .windows(9)
            .position(|w| w == b"\xa8diameter")
            .expect("key")
            + 10;
        assert!(shape.mask[first..first + 8].iter().all(|&m| m == 0));
        assert!(shape.slots.iter().all(|&(_, o)| o as usize != first));
        assert_eq!(shape.slots.len(), 10);
        // pye3d: the 21 fields gazelight reads; sphere, location and
        // projected_sphere are free.
        let (topic, p3) = &all[1];
        let shape = Shape::learn(parse_topic(topic), p3).expect("learns");
        assert_eq!(shape.slots.len(), 21);
        let free = float_offsets(p3).unwrap().len() - 21;
        assert_eq!(free, 4 + 2);
    }
}
