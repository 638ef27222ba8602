//! Vendor profile: Cambridge Research Systems LiveTrack (HID, 64-byte
//! reports, pupil width/height).
//!
//! Sources:
//!
//! - **CRS MATLAB driver** `crsLiveTrackHIDcomm.m` (the 2016 update package,
//!   as redistributed in gkaguirrelab/LiveTrackfMRIToolbox,
//!   `code/crsCode/UpdatePackage_041316/crsLiveTrackHIDcomm.m`): the command
//!   bytes and the report layout below. MATLAB indices there are 1-based;
//!   the offsets here are 0-based (`r(k)` = byte `k − 1`).
//! - **hibiscus** (a C++ LiveTrack client built on hidapi):
//!   `hid_open(2145, 13367, …)`, i.e. VID 0x0861, PID 0x3437.
//!
//! Commands (output report, report ID 0, 64 bytes, first byte the command,
//! the rest 0 — `SetReport([104 zeros(1,63)])` etc. in the driver):
//!
//! | byte | meaning |
//! | --- | --- |
//! | 104 | start sending raw data packets |
//! | 105 | start sending calibrated data packets |
//! | 102 | stop sending data packets |
//!
//! Input report (64 bytes, no report ID):
//!
//! | bytes | content |
//! | --- | --- |
//! | 0 | 200 = raw packet, 201 = calibrated packet |
//! | 8..16 | timestamp, unsigned 64-bit little-endian (`r(9) + r(10)·256 + … + r(16)·256^7`) |
//! | 16..18 | sample 1 flags, u16 LE |
//! | 22..24 | raw: sample 1 scaling factor, u16 LE |
//! | 24..40 | raw: sample 1 pupil W, H, X, Y, glint 1 X, Y, glint 2 X, Y — i16 LE each, divided by the scaling factor |
//! | 22..40 | calibrated: sample 1 pupil W, H, gaze X, Y, Z, azimuth, elevation, longitude, latitude — i16 LE each, divided by 32 |
//! | 40..42 | sample 2 flags |
//! | 46..48 | raw: sample 2 scaling factor |
//! | 48..64 | raw: sample 2 values as sample 1 |
//! | 46..64 | calibrated: sample 2 values as sample 1 |
//!
//! The driver calls the two halves "S1 is the first sample and S2 is the
//! second" — two consecutive samples of one camera per report; which eye the
//! camera watches is set by the caller ([`LiveTrackOptions::eye`]).
//!
//! Flags (bits of the u16; the driver reads them MSB-first with
//! `dec2bin(…,16)`, so its string positions 11-12 are bits 5-4 and 13-16
//! bits 3-0): bits 5-4 = `01` one glint (LiveTrack AV), `10` two glints
//! (LiveTrack FM); the sample is tracked when bits 3-0 are `0111` (one
//! glint) or `1111` (two glints). Bit 0 set with an undefined glint setting
//! is an error in the driver; here it is an invalid sample.
//!
//! The driver does not state the timestamp's unit nor the unit of the
//! calibrated pupil size, so gazelight keeps the device timestamp as
//! `device_timestamp` and stamps samples with the host arrival time; raw
//! pupil sizes are camera pixels (`PupilUnit::Px`), calibrated ones are
//! reported as `PupilUnit::Arbitrary`. The pupil diameter is the larger of
//! width and height (the major axis, which foreshortening does not shrink).

use gazelight_eye::sample::{DetectorMethod, PupilSample, PupilUnit};

/// USB vendor ID of Cambridge Research Systems (hibiscus: `hid_open(2145, …)`).
pub const VENDOR_ID: u16 = 0x0861;
/// LiveTrack product ID (hibiscus: `hid_open(…, 13367, …)`).
pub const PRODUCT_ID: u16 = 0x3437;
/// Report length, bytes.
pub const REPORT_LEN: usize = 64;
/// Command: start raw packets (driver `begin`).
pub const CMD_START_RAW: u8 = 104;
/// Command: start calibrated packets (driver `begin-cal`).
pub const CMD_START_CALIBRATED: u8 = 105;
/// Command: stop packets (driver `end`).
pub const CMD_STOP: u8 = 102;
/// First byte of a raw packet.
pub const PACKET_RAW: u8 = 200;
/// First byte of a calibrated packet.
pub const PACKET_CALIBRATED: u8 = 201;
/// Fixed divisor of calibrated values (driver: `S1Scaling = 32`).
pub const CALIBRATED_SCALE: f64 = 32.0;

/// Which packets to ask for.
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq)]
pub enum LiveTrackMode {
    /// Raw packets: pupil/glint positions in camera pixels.
    #[default]
    Raw,
    /// Calibrated packets: pupil size and gaze from the device calibration.
    Calibrated,
}

/// Options of the LiveTrack profile.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub struct LiveTrackOptions {
    pub mode: LiveTrackMode,
    /// Eye the camera watches: 0 = right, 1 = left.
    pub eye: u8,
}

impl Default for LiveTrackOptions {
    fn default() -> Self {
        Self {
            mode: LiveTrackMode::Raw,
            eye: 0,
        }
    }
}

/// The 64-byte output report for a command (hidapi `write` form: report
/// ID 0 first, then the 64 report bytes).
pub fn command(cmd: u8) -> [u8; REPORT_LEN + 1] {
    let mut b = [0u8; REPORT_LEN + 1];
    b[1] = cmd;
    b
}

/// One half of a packet.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct LiveTrackSample {
    pub tracked: bool,
    /// Pupil width and height (px in raw mode, device units calibrated).
    pub pupil_w: f64,
    pub pupil_h: f64,
    /// Raw: pupil centre X/Y (px). Calibrated: gaze X/Y.
    pub a: [f64; 2],
    /// Raw: glint 1 X/Y, glint 2 X/Y. Calibrated: gaze Z, azimuth,
    /// elevation, longitude (latitude in `b2`).
    pub b: [f64; 4],
    /// Calibrated: latitude; raw: unused (0).
    pub b2: f64,
}

/// A decoded packet.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct LiveTrackPacket {
    pub mode: LiveTrackMode,
    pub device_timestamp: u64,
    pub samples: [LiveTrackSample; 2],
}

/// Why a report is not a LiveTrack data packet.
#[derive(Debug, thiserror::Error, PartialEq, Eq)]
pub enum LiveTrackError {
    #[error("report is {0} bytes, expected 64")]
    Length(usize),
    #[error("byte 0 is {0}: neither a raw (200) nor a calibrated (201) packet")]
    Kind(u8),
    #[error("sample {sample}: scaling factor at byte {offset} is 0")]
    ZeroScale { sample: u8, offset: usize },
}

fn u16_at(r: &[u8], i: usize) -> u16 {
    u16::from_le_bytes([r[i], r[i + 1]])
}

fn i16_at(r: &[u8], i: usize) -> f64 {
    i16::from_le_bytes([r[i], r[i + 1]]) as f64
}

/// Whether the flags say "tracked" (see the module docs).
pub fn tracked(flags: u16) -> bool {
    match (flags >> 4) & 0b11 {
        0b01 => flags & 0xF == 0b0111,
        0b10 => flags & 0xF == 0b1111,
        _ => false,
    }
}

/// Decode a 64-byte input report.
pub fn decode(r: &[u8]) -> Result<LiveTrackPacket, LiveTrackError> {
    if r.len() != REPORT_LEN {
        return Err(LiveTrackError::Length(r.len()));
    }
    let mut ts = [0u8; 8];
    ts.copy_from_slice(&r[8..16]);
    let device_timestamp = u64::from_le_bytes(ts);
    // Per sample: flags offset, scaling offset (raw), values start raw,
    // values start calibrated.
    const LAYOUT: [(usize, usize, usize, usize); 2] = [(16, 22, 24, 22), (40, 46, 48, 46)];
    let mode = match r[0] {
        PACKET_RAW => LiveTrackMode::Raw,
        PACKET_CALIBRATED => LiveTrackMode::Calibrated,
        k => return Err(LiveTrackError::Kind(k)),
    };
    let mut samples = [LiveTrackSample {
        tracked: false,
        pupil_w: 0.0,
        pupil_h: 0.0,
        a: [0.0; 2],
        b: [0.0; 4],
        b2: 0.0,
    }; 2];
    for (k, (flags_at, scale_at, raw_at, cal_at)) in LAYOUT.into_iter().enumerate() {
        let flags = u16_at(r, flags_at);
        let (scale, start, n) = match mode {
            LiveTrackMode::Raw => {
                let s = u16_at(r, scale_at);
                if s == 0 {
                    return Err(LiveTrackError::ZeroScale {
                        sample: k as u8 + 1,
                        offset: scale_at,
                    });
                }
                (s as f64, raw_at, 8)
            }
            LiveTrackMode::Calibrated => (CALIBRATED_SCALE, cal_at, 9),
        };
        let v = |i: usize| i16_at(r, start + 2 * i) / scale;
        samples[k] = LiveTrackSample {
            tracked: tracked(flags),
            pupil_w: v(0),
            pupil_h: v(1),
            a: [v(2), v(3)],
            b: [v(4), v(5), v(6), v(7)],
            b2: if n == 9 { v(8) } else { 0.0 },
        };
    }
    Ok(LiveTrackPacket {
        mode,
        device_timestamp,
        samples,
    })
}

/// The two pupil samples of a packet at host time `t_secs`.
pub fn pupil_samples(p: &LiveTrackPacket, t_secs: f64, eye: u8) -> [PupilSample; 2] {
    p.samples.map(|s| {
        let d = s.pupil_w.max(s.pupil_h);
        let valid = s.tracked && d.is_finite() && d > 0.0;
        PupilSample {
            t_secs,
            eye,
            diameter_raw: if valid { d as f32 } else { 0.0 },
            unit: match p.mode {
                LiveTrackMode::Raw => PupilUnit::Px,
                LiveTrackMode::Calibrated => PupilUnit::Arbitrary,
            },
            diameter_mm: None,
            confidence: if valid { 1.0 } else { 0.0 },
            norm_pos: [f32::NAN, f32::NAN],
            method: DetectorMethod::Other,
        }
    })
}
