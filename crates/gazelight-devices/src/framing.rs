//! The binary sample framing gazelight accepts on serial lines
//! (`format=framed`) and on vendor USB bulk endpoints.
//!
//! A stream is a sequence of frames; bytes between frames are skipped:
//!
//! ```text
//! offset size  field
//! 0      2     sync: 0xA5 0x5A
//! 2      1     version: 1
//! 3      1     payload length N (bytes)
//! 4      N     payload (little-endian, below)
//! 4+N    2     CRC-16/CCITT-FALSE over bytes 2 .. 4+N (version, length,
//!              payload), little-endian
//! ```
//!
//! CRC-16/CCITT-FALSE: polynomial 0x1021, initial value 0xFFFF, no
//! reflection, no final XOR; its check value for the ASCII bytes
//! `123456789` is 0x29B1 (the catalogue value of this CRC).
//!
//! Payloads (all little-endian):
//!
//! | kind | layout | N |
//! | --- | --- | --- |
//! | 1 gaze | `kind u8, t_us u64, u f32, v f32, confidence f32` | 21 |
//! | 2 pupil | `kind u8, t_us u64, eye u8, unit u8, diameter f32, confidence f32` | 19 |
//!
//! `t_us` is the device's timestamp in microseconds (mapped onto the host
//! clock by [`gazelight_eye::clock::SourceClock`]); `u, v` are normalised display
//! coordinates with the origin at the top-left; `eye` is 0 = right,
//! 1 = left; `unit` is 0 = mm, 1 = camera pixels, 2 = arbitrary units.
//!
//! A frame whose CRC does not match, whose version is unknown, or whose
//! payload does not match its kind is reported as an error naming its byte
//! offset in the stream; the decoder then resynchronises on the next sync
//! pattern after the bad frame's first byte.

use gazelight_eye::sample::{DetectorMethod, GazeEyes, GazeSample, PupilSample, PupilUnit, Sample};

/// First sync byte.
pub const SYNC0: u8 = 0xA5;
/// Second sync byte.
pub const SYNC1: u8 = 0x5A;
/// The only framing version defined.
pub const VERSION: u8 = 1;
/// Payload kind of a gaze sample.
pub const KIND_GAZE: u8 = 1;
/// Payload kind of a pupil sample.
pub const KIND_PUPIL: u8 = 2;
/// Payload length of a gaze sample.
pub const GAZE_PAYLOAD_LEN: usize = 21;
/// Payload length of a pupil sample.
pub const PUPIL_PAYLOAD_LEN: usize = 19;
/// Header bytes before the payload.
pub const HEADER_LEN: usize = 4;
/// Longest frame (header + 255-byte payload + CRC).
pub const MAX_FRAME_LEN: usize = HEADER_LEN + 255 + 2;

/// CRC-16/CCITT-FALSE (poly 0x1021, init 0xFFFF, no reflection, no xorout).
pub fn crc16_ccitt_false(data: &[u8]) -> u16 {
    let mut crc: u16 = 0xFFFF;
    for &b in data {
        crc ^= (b as u16) << 8;
        for _ in 0..8 {
            crc = if crc & 0x8000 != 0 {
                (crc << 1) ^ 0x1021
            } else {
                crc << 1
            };
        }
    }
    crc
}

/// A sample as carried in a frame, device time still in microseconds.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct FramedSample {
    /// Device timestamp, µs.
    pub t_us: u64,
    /// The sample; its `t_secs` is `t_us · 1e-6` (device clock).
    pub sample: Sample,
}

/// Why a frame was rejected.
#[derive(Debug, thiserror::Error, PartialEq, Eq)]
pub enum FrameError {
    #[error(
        "frame at byte {offset}: CRC mismatch (frame says {stated:#06x}, computed {computed:#06x})"
    )]
    Crc {
        offset: u64,
        stated: u16,
        computed: u16,
    },
    #[error("frame at byte {offset}: unknown framing version {version} (expected 1)")]
    Version { offset: u64, version: u8 },
    #[error(
        "frame at byte {offset}: payload kind {kind} with length {len} (expected kind 1 with 21 bytes or kind 2 with 19)"
    )]
    Payload { offset: u64, kind: u8, len: usize },
    #[error("frame at byte {offset}: field `{field}`: {reason}")]
    Field {
        offset: u64,
        field: &'static str,
        reason: &'static str,
    },
}

/// Encode one sample as a frame into `out` (appends). Used by tests, the
/// simulators and as the reference for firmware.
pub fn encode(sample: &Sample, t_us: u64, out: &mut Vec<u8>) {
    let mut payload = [0u8; 32];
    let len = match sample {
        Sample::Gaze(g) => {
            payload[0] = KIND_GAZE;
            payload[1..9].copy_from_slice(&t_us.to_le_bytes());
            payload[9..13].copy_from_slice(&g.gaze_uv[0].to_le_bytes());
            payload[13..17].copy_from_slice(&g.gaze_uv[1].to_le_bytes());
            payload[17..21].copy_from_slice(&g.confidence.to_le_bytes());
            GAZE_PAYLOAD_LEN
        }
        Sample::Pupil(p) => {
            payload[0] = KIND_PUPIL;
            payload[1..9].copy_from_slice(&t_us.to_le_bytes());
            payload[9] = p.eye;
            payload[10] = match p.unit {
                PupilUnit::Mm => 0,
                PupilUnit::Px => 1,
                PupilUnit::Arbitrary | PupilUnit::ArbitraryArea => 2,
            };
            payload[11..15].copy_from_slice(&p.diameter_raw.to_le_bytes());
            payload[15..19].copy_from_slice(&p.confidence.to_le_bytes());
            PUPIL_PAYLOAD_LEN
        }
        Sample::Blink(_) => return,
    };
    let start = out.len();
    out.extend_from_slice(&[SYNC0, SYNC1, VERSION, len as u8]);
    out.extend_from_slice(&payload[..len]);
    let crc = crc16_ccitt_false(&out[start + 2..]);
    out.extend_from_slice(&crc.to_le_bytes());
}

/// Streaming frame decoder: push bytes in, pull samples out. Its buffer is
/// allocated once ([`MAX_FRAME_LEN`] · 2) and reused.
#[derive(Debug)]
pub struct FrameDecoder {
    buf: Vec<u8>,
    /// Stream offset of `buf[0]`.
    base_offset: u64,
    frames: u64,
    errors: u64,
    skipped_bytes: u64,
}

impl Default for FrameDecoder {
    fn default() -> Self {
        Self::new()
    }
}

impl FrameDecoder {
    /// A decoder at stream offset 0.
    pub fn new() -> Self {
        Self {
            buf: Vec::with_capacity(MAX_FRAME_LEN * 2),
            base_offset: 0,
            frames: 0,
            errors: 0,
            skipped_bytes: 0,
        }
    }

    /// Good frames decoded so far.
    pub fn frames(&self) -> u64 {
        self.frames
    }

    /// Bad frames so far.
    pub fn errors(&self) -> u64 {
        self.errors
    }

    /// Bytes skipped outside frames (noise, resynchronisation).
    pub fn skipped_bytes(&self) -> u64 {
        self.skipped_bytes
    }

    /// How many bytes [`Self::push`] can take now.
    pub fn room(&self) -> usize {
        self.buf.capacity() - self.buf.len()
    }

    /// Append bytes; returns how many were taken (at most [`Self::room`]).
    /// Call [`Self::next_frame`] until it returns `None` before pushing more.
    pub fn push(&mut self, bytes: &[u8]) -> usize {
        let n = bytes.len().min(self.room());
        self.buf.extend_from_slice(&bytes[..n]);
        n
    }

    fn consume(&mut self, n: usize) {
        self.buf.drain(..n);
        self.base_offset += n as u64;
    }

    /// The next complete frame in the buffer: `None` when more bytes are
    /// needed.
    pub fn next_frame(&mut self) -> Option<Result<FramedSample, FrameError>> {
        {
            // Find the sync pattern.
            let sync = self
                .buf
                .windows(2)
                .position(|w| w[0] == SYNC0 && w[1] == SYNC1);
            match sync {
                None => {
                    // Keep a trailing SYNC0: it may start a frame.
                    let keep = usize::from(self.buf.last() == Some(&SYNC0));
                    let drop = self.buf.len() - keep;
                    self.skipped_bytes += drop as u64;
                    self.consume(drop);
                    return None;
                }
                Some(p) if p > 0 => {
                    self.skipped_bytes += p as u64;
                    self.consume(p);
                }
                Some(_) => {}
            }
            if self.buf.len() < HEADER_LEN {
                return None;
            }
            let offset = self.base_offset;
            let version = self.buf[2];
            let len = self.buf[3] as usize;
            if version != VERSION {
                self.errors += 1;
                self.consume(1);
                return Some(Err(FrameError::Version { offset, version }));
            }
            let total = HEADER_LEN + len + 2;
            if self.buf.len() < total {
                return None;
            }
            let stated = u16::from_le_bytes([self.buf[total - 2], self.buf[total - 1]]);
            let computed = crc16_ccitt_false(&self.buf[2..HEADER_LEN + len]);
            if stated != computed {
                self.errors += 1;
                self.consume(1);
                return Some(Err(FrameError::Crc {
                    offset,
                    stated,
                    computed,
                }));
            }
            let result = decode_payload(&self.buf[HEADER_LEN..HEADER_LEN + len], offset);
            self.consume(total);
            match &result {
                Ok(_) => self.frames += 1,
                Err(_) => self.errors += 1,
            }
            Some(result)
        }
    }
}

fn f32_at(p: &[u8], i: usize) -> f32 {
    f32::from_le_bytes([p[i], p[i + 1], p[i + 2], p[i + 3]])
}

fn decode_payload(p: &[u8], offset: u64) -> Result<FramedSample, FrameError> {
    let kind = p.first().copied().unwrap_or(0);
    let bad_len = || FrameError::Payload {
        offset,
        kind,
        len: p.len(),
    };
    let t_of = |p: &[u8]| {
        let mut b = [0u8; 8];
        b.copy_from_slice(&p[1..9]);
        u64::from_le_bytes(b)
    };
    match kind {
        KIND_GAZE if p.len() == GAZE_PAYLOAD_LEN => {
            let t_us = t_of(p);
            let confidence = f32_at(p, 17);
            if !(0.0..=1.0).contains(&confidence) {
                return Err(FrameError::Field {
                    offset,
                    field: "confidence",
                    reason: "outside 0..=1",
                });
            }
            Ok(FramedSample {
                t_us,
                sample: Sample::Gaze(GazeSample {
                    t_secs: t_us as f64 * 1e-6,
                    gaze_uv: [f32_at(p, 9), f32_at(p, 13)],
                    confidence,
                    eyes: GazeEyes::Binocular,
                }),
            })
        }
        KIND_PUPIL if p.len() == PUPIL_PAYLOAD_LEN => {
            let t_us = t_of(p);
            let eye = p[9];
            if eye > 1 {
                return Err(FrameError::Field {
                    offset,
                    field: "eye",
                    reason: "not 0 (right) or 1 (left)",
                });
            }
            let unit = match p[10] {
                0 => PupilUnit::Mm,
                1 => PupilUnit::Px,
                2 => PupilUnit::Arbitrary,
                _ => {
                    return Err(FrameError::Field {
                        offset,
                        field: "unit",
                        reason: "not 0 (mm), 1 (px) or 2 (arbitrary)",
                    });
                }
            };
            let diameter = f32_at(p, 11);
            let confidence = f32_at(p, 15);
            if !(0.0..=1.0).contains(&confidence) {
                return Err(FrameError::Field {
                    offset,
                    field: "confidence",
                    reason: "outside 0..=1",
                });
            }
            Ok(FramedSample {
                t_us,
                sample: Sample::Pupil(PupilSample {
                    t_secs: t_us as f64 * 1e-6,
                    eye,
                    diameter_raw: diameter,
                    unit,
                    diameter_mm: (unit == PupilUnit::Mm && diameter.is_finite() && diameter > 0.0)
                        .then_some(diameter),
                    confidence,
                    norm_pos: [f32::NAN, f32::NAN],
                    method: DetectorMethod::Other,
                }),
            })
        }
        _ => Err(bad_len()),
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn crc_matches_the_catalogue_check_value() {
        // CRC-16/CCITT-FALSE check value for "123456789".
        assert_eq!(crc16_ccitt_false(b"123456789"), 0x29B1);
        assert_eq!(crc16_ccitt_false(b""), 0xFFFF);
    }

    fn gaze(u: f32, v: f32) -> Sample {
        Sample::Gaze(GazeSample {
            t_secs: 0.0,
            gaze_uv: [u, v],
            confidence: 0.75,
            eyes: GazeEyes::Binocular,
        })
    }

    fn pupil(d: f32) -> Sample {
        Sample::Pupil(PupilSample {
            t_secs: 0.0,
            eye: 1,
            diameter_raw: d,
            unit: PupilUnit::Mm,
            diameter_mm: Some(d),
            confidence: 1.0,
            norm_pos: [f32::NAN, f32::NAN],
            method: DetectorMethod::Other,
        })
    }

    #[test]
    fn frames_survive_noise_split_reads_and_corruption() {
        let mut stream = vec![0x00, 0xA5, 0x13];
        encode(&gaze(0.25, 0.75), 1_000_000, &mut stream);
        let second = stream.len();
        encode(&pupil(4.5), 1_004_000, &mut stream);
        // Corrupt one payload byte of the second frame.
        stream[second + 12] ^= 0x40;
        encode(&pupil(3.25), 1_008_000, &mut stream);

        let mut dec = FrameDecoder::new();
        let mut out = Vec::new();
        for chunk in stream.chunks(5) {
            let mut rest = chunk;
            while !rest.is_empty() {
                let n = dec.push(rest);
                rest = &rest[n..];
                while let Some(r) = dec.next_frame() {
                    out.push(r);
                }
            }
        }
        assert_eq!(out.len(), 3);
        let FramedSample { t_us, sample } = out[0].as_ref().unwrap();
        assert_eq!(*t_us, 1_000_000);
        let Sample::Gaze(g) = sample else { panic!() };
        assert_eq!(g.gaze_uv, [0.25, 0.75]);
        assert_eq!(g.confidence, 0.75);
        assert!((g.t_secs - 1.0).abs() < 1e-12);
        match &out[1] {
            Err(FrameError::Crc { offset, .. }) => assert_eq!(*offset, second as u64),
            other => panic!("expected a CRC error, got {other:?}"),
        }
        let Sample::Pupil(p) = out[2].as_ref().unwrap().sample else {
            panic!()
        };
        assert_eq!(
            (p.eye, p.diameter_raw, p.diameter_mm),
            (1, 3.25, Some(3.25))
        );
        assert_eq!((dec.frames(), dec.errors()), (2, 1));
    }

    #[test]
    fn bad_fields_and_lengths_are_errors_not_panics() {
        // Pupil frame with eye = 7.
        let mut s = Vec::new();
        encode(&pupil(4.0), 5, &mut s);
        s[4 + 9] = 7;
        let crc = crc16_ccitt_false(&s[2..s.len() - 2]);
        let n = s.len();
        s[n - 2..].copy_from_slice(&crc.to_le_bytes());
        let mut dec = FrameDecoder::new();
        dec.push(&s);
        assert!(matches!(
            dec.next_frame(),
            Some(Err(FrameError::Field { field: "eye", .. }))
        ));
        // A well-formed frame with an unknown kind.
        let mut s = vec![SYNC0, SYNC1, VERSION, 2, 9, 9];
        let crc = crc16_ccitt_false(&s[2..]);
        s.extend_from_slice(&crc.to_le_bytes());
        dec.push(&s);
        assert!(matches!(
            dec.next_frame(),
            Some(Err(FrameError::Payload {
                kind: 9,
                len: 2,
                ..
            }))
        ));
        // Unknown version.
        dec.push(&[SYNC0, SYNC1, 7, 0]);
        assert!(matches!(
            dec.next_frame(),
            Some(Err(FrameError::Version { version: 7, .. }))
        ));
        assert!(dec.next_frame().is_none());
    }
}
