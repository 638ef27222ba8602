//! Neon's gaze and eye-event RTP payloads.
//!
//! Both are big-endian. The gaze layout is chosen by the payload length
//! (the official client `pupil-labs-realtime-api`,
//! `streaming/gaze.py`, knows 9, 17, 65 and 89 bytes; 25 and 105 are the
//! issue's table, not in that client):
//!
//! | bytes | content |
//! |---|---|
//! | 9 | x, y (f32, scene-camera px), worn (u8, 255 = worn) |
//! | 17 | left-eye x, y, worn, right-eye x, y (dual monocular) |
//! | 25 | the 9 bytes + left-eye x, y + right-eye x, y |
//! | 65 | the 9 bytes + per eye (left, then right): pupil diameter mm, eyeball centre xyz mm, optical axis xyz |
//! | 89 | the 65 bytes + per eye (left, then right): eyelid top angle, bottom angle (rad), aperture (mm) |
//! | 105 | the 89 bytes + left-eye x, y + right-eye x, y |
//!
//! Eye events (`streaming/eye_events.py`) start with an `i32` type:
//! 0/1 fixation or saccade (60 bytes), 2/3 their onsets (12 bytes),
//! 4 a blink (`!iqq`: type, start ns, end ns; 20 bytes), 5 a keepalive.

use crate::NeonError;

/// Accepted gaze payload lengths.
pub const GAZE_LENGTHS: [usize; 6] = [9, 17, 25, 65, 89, 105];

/// One eye's 3D eye state.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct EyeStateDatum {
    pub pupil_diameter_mm: f32,
    pub eyeball_center_mm: [f32; 3],
    pub optical_axis: [f32; 3],
}

/// One eye's eyelids.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct EyelidDatum {
    pub angle_top_rad: f32,
    pub angle_bottom_rad: f32,
    pub aperture_mm: f32,
}

/// One decoded gaze payload. Per-eye arrays are `[left, right]`, the
/// payload's order.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct GazeDatum {
    /// The payload length it was decoded from.
    pub len: usize,
    /// Binocular gaze, scene-camera px (absent in the 17-byte layout).
    pub gaze_px: Option<[f32; 2]>,
    /// The worn byte (255 = worn).
    pub worn_raw: u8,
    /// Per-eye (monocular) gaze, scene-camera px, `[left, right]`.
    pub monocular_px: Option<[[f32; 2]; 2]>,
    /// Per-eye eye state, `[left, right]`.
    pub eye_state: Option<[EyeStateDatum; 2]>,
    /// Per-eye eyelids, `[left, right]`.
    pub eyelid: Option<[EyelidDatum; 2]>,
}

impl GazeDatum {
    /// Neon reports the glasses as worn.
    pub fn worn(&self) -> bool {
        self.worn_raw == 255
    }
}

fn f32_at(b: &[u8], at: usize) -> f32 {
    f32::from_be_bytes([b[at], b[at + 1], b[at + 2], b[at + 3]])
}

fn eye_state_at(b: &[u8], at: usize) -> EyeStateDatum {
    let f = |i: usize| f32_at(b, at + 4 * i);
    EyeStateDatum {
        pupil_diameter_mm: f(0),
        eyeball_center_mm: [f(1), f(2), f(3)],
        optical_axis: [f(4), f(5), f(6)],
    }
}

fn eyelid_at(b: &[u8], at: usize) -> EyelidDatum {
    EyelidDatum {
        angle_top_rad: f32_at(b, at),
        angle_bottom_rad: f32_at(b, at + 4),
        aperture_mm: f32_at(b, at + 8),
    }
}

fn pair_at(b: &[u8], at: usize) -> [[f32; 2]; 2] {
    [
        [f32_at(b, at), f32_at(b, at + 4)],
        [f32_at(b, at + 8), f32_at(b, at + 12)],
    ]
}

/// Decodes a gaze payload (the RTP payload, header excluded).
pub fn decode_gaze(b: &[u8]) -> Result<GazeDatum, NeonError> {
    if !GAZE_LENGTHS.contains(&b.len()) {
        return Err(NeonError::Packet {
            what: "gaze payload",
            reason: format!(
                "{} bytes; the known layouts are 9, 17, 25, 65, 89 and 105 bytes \
                 (RTP header excluded)",
                b.len()
            ),
        });
    }
    if b.len() == 17 {
        return Ok(GazeDatum {
            len: 17,
            gaze_px: None,
            worn_raw: b[8],
            monocular_px: Some([[f32_at(b, 0), f32_at(b, 4)], [f32_at(b, 9), f32_at(b, 13)]]),
            eye_state: None,
            eyelid: None,
        });
    }
    let mut d = GazeDatum {
        len: b.len(),
        gaze_px: Some([f32_at(b, 0), f32_at(b, 4)]),
        worn_raw: b[8],
        monocular_px: None,
        eye_state: None,
        eyelid: None,
    };
    match b.len() {
        25 => d.monocular_px = Some(pair_at(b, 9)),
        65 | 89 | 105 => {
            d.eye_state = Some([eye_state_at(b, 9), eye_state_at(b, 37)]);
            if b.len() >= 89 {
                d.eyelid = Some([eyelid_at(b, 65), eyelid_at(b, 77)]);
            }
            if b.len() == 105 {
                d.monocular_px = Some(pair_at(b, 89));
            }
        }
        _ => {}
    }
    Ok(d)
}

/// One decoded eye event.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum EyeEvent {
    /// A blink, Unix nanoseconds.
    Blink { start_ns: i64, end_ns: i64 },
    /// A fixation/saccade (types 0–3); gazelight does not use them.
    Other { event_type: i32 },
    /// Type 5.
    Keepalive,
}

/// Decodes an eye-event payload.
pub fn decode_eye_event(b: &[u8]) -> Result<EyeEvent, NeonError> {
    let bad = |reason: String| NeonError::Packet {
        what: "eye event payload",
        reason,
    };
    if b.len() < 4 {
        return Err(bad(format!(
            "{} bytes, shorter than the 4-byte type",
            b.len()
        )));
    }
    let event_type = i32::from_be_bytes([b[0], b[1], b[2], b[3]]);
    let need = match event_type {
        0 | 1 => 60,
        2 | 3 => 12,
        4 => 20,
        5 => return Ok(EyeEvent::Keepalive),
        t => return Err(bad(format!("unknown event type {t} ({} bytes)", b.len()))),
    };
    if b.len() != need {
        return Err(bad(format!(
            "type {event_type} is {need} bytes, got {}",
            b.len()
        )));
    }
    if event_type != 4 {
        return Ok(EyeEvent::Other { event_type });
    }
    let i64_at = |at: usize| {
        let mut a = [0u8; 8];
        a.copy_from_slice(&b[at..at + 8]);
        i64::from_be_bytes(a)
    };
    let (start_ns, end_ns) = (i64_at(4), i64_at(12));
    if end_ns < start_ns {
        return Err(bad(format!(
            "blink ends ({end_ns} ns) before it starts ({start_ns} ns)"
        )));
    }
    Ok(EyeEvent::Blink { start_ns, end_ns })
}

#[cfg(test)]
mod tests {
    use super::*;

    fn be(vals: &[f32]) -> Vec<u8> {
        vals.iter().flat_map(|v| v.to_be_bytes()).collect()
    }

    #[test]
    fn every_length_decodes_and_others_are_refused() {
        for n in 0..=120 {
            let b = vec![0u8; n];
            assert_eq!(decode_gaze(&b).is_ok(), GAZE_LENGTHS.contains(&n), "{n}");
        }
    }

    #[test]
    fn seventeen_bytes_is_left_worn_right() {
        let mut b = be(&[1.0, 2.0]);
        b.push(255);
        b.extend(be(&[3.0, 4.0]));
        let d = decode_gaze(&b).unwrap();
        assert_eq!(d.monocular_px, Some([[1.0, 2.0], [3.0, 4.0]]));
        assert!(d.worn() && d.gaze_px.is_none());
    }

    #[test]
    fn eye_events() {
        let mut b = 4i32.to_be_bytes().to_vec();
        b.extend(10i64.to_be_bytes());
        b.extend(20i64.to_be_bytes());
        assert_eq!(
            decode_eye_event(&b).unwrap(),
            EyeEvent::Blink {
                start_ns: 10,
                end_ns: 20
            }
        );
        assert!(decode_eye_event(&b[..19]).is_err());
        assert_eq!(
            decode_eye_event(&5i32.to_be_bytes()).unwrap(),
            EyeEvent::Keepalive
        );
        assert!(decode_eye_event(&9i32.to_be_bytes()).is_err());
        assert!(decode_eye_event(&[0, 0]).is_err());
    }
}
