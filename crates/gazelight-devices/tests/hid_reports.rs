#![allow(clippy::unwrap_used, clippy::expect_used)] // test and bench code may panic on a failed setup
//! HID decoding from report-descriptor bytes and report bytes: a page-0x12
//! eye tracker written per HUTRR74 (usage IDs in
//! `transport::hid::page12`), a 12-bit tracker whose units come from
//! physical extents, and CRS LiveTrack packets laid out as CRS's MATLAB
//! driver reads them.

use gazelight_devices::hid::descriptor::{Descriptor, ReportKind};
use gazelight_devices::hid::livetrack::{self, LiveTrackError, LiveTrackMode};
use gazelight_devices::hid::page12::{self, Page12Error, Page12Layout};
use gazelight_devices::hid::{HidOptions, HidProfile, source::choose_profile, testdata};
use gazelight_eye::PupilUnit;

const EYE_TRACKER: &[u8] = testdata::PAGE12_EYE_TRACKER;
const SCREEN_W_UM: i32 = testdata::SCREEN_UM[0];
const SCREEN_H_UM: i32 = testdata::SCREEN_UM[1];

fn tracking_report(t_us: u64, gaze: [i32; 2], left: [i32; 3], right: [i32; 3]) -> Vec<u8> {
    let mut r = vec![0x10];
    r.extend_from_slice(&t_us.to_le_bytes());
    for v in gaze.iter().chain(&left).chain(&right) {
        r.extend_from_slice(&v.to_le_bytes());
    }
    r
}

fn layout() -> Page12Layout {
    let d = Descriptor::parse(EYE_TRACKER).expect("descriptor parses");
    Page12Layout::from_descriptor(&d).expect("page-0x12 layout")
}

#[test]
fn descriptor_fields_have_the_spec_layout() {
    let d = Descriptor::parse(EYE_TRACKER).unwrap();
    assert!(d.uses_report_ids);
    // Tracking Data: 8 + 2·4 + 3·4 + 3·4 = 40 bytes after the ID.
    assert_eq!(d.report_len(ReportKind::Input, 0x10), 40);
    let ts = d
        .find(
            ReportKind::Input,
            page12::PAGE,
            page12::SENSOR_TIMESTAMP,
            None,
        )
        .unwrap();
    assert_eq!((ts.bit_offset, ts.bit_size, ts.unit_exponent), (0, 64, -6));
    assert_eq!(ts.unit.seconds_per_unit(), Some(1.0));
    let ry = d
        .find(
            ReportKind::Input,
            page12::PAGE,
            page12::POSITION_Y,
            Some((page12::PAGE, page12::RIGHT_EYE_POSITION)),
        )
        .unwrap();
    assert_eq!(ry.bit_offset, (8 + 8 + 12 + 4) * 8);
    assert_eq!(ry.logical_min, -2_147_483_647);
    assert_eq!(ry.unit.metres_per_unit(), Some(0.01));
    let h = d
        .find(
            ReportKind::Feature,
            page12::PAGE,
            page12::CALIBRATED_SCREEN_HEIGHT,
            None,
        )
        .unwrap();
    assert_eq!((h.report_id, h.bit_offset), (0x12, 32));
    let l = layout();
    assert_eq!(l.tracking_report_id(), 0x10);
    assert_eq!(l.tracking_report_len(), 41);
}

#[test]
fn tracking_reports_decode_to_micrometres_and_normalised_gaze() {
    let l = layout();
    let mut cfg = vec![0x12];
    cfg.extend_from_slice(&SCREEN_W_UM.to_le_bytes());
    cfg.extend_from_slice(&SCREEN_H_UM.to_le_bytes());
    let screen = l.decode_screen(&cfg).unwrap();
    assert_eq!((screen.width_um, screen.height_um), (531_300.0, 298_900.0));

    // Eyes 32 mm either side of the centre line, 650 mm from the screen.
    let left = [-32_000, 10_000, 650_000];
    let right = [32_000, 10_000, 650_000];
    let r = tracking_report(1_016_667, [132_825, 224_175], left, right);
    let td = l.decode_tracking(&r).unwrap();
    assert_eq!(td.timestamp_us, Some(1_016_667));
    let g = td.gaze_um.unwrap();
    assert!((g[0] - 132_825.0).abs() < 1e-6 && (g[1] - 224_175.0).abs() < 1e-6);
    assert_eq!(Page12Layout::normalise(g, &screen), [0.25, 0.75]);
    let le = td.left_eye_um.unwrap();
    assert!((le[0] + 32_000.0).abs() < 1e-6 && (le[2] - 650_000.0).abs() < 1e-6);
    assert!(td.right_eye_um.is_some());
    assert_eq!(td.head_position_um, None);
    assert_eq!(td.invalid_fields, 0);
}

#[test]
fn out_of_range_values_are_invalid_and_counted() {
    let l = layout();
    // i32::MIN lies below the logical minimum −2^31 + 1: the conventional
    // "no value" of a signed field.
    let r = tracking_report(
        2_000_000,
        [i32::MIN, 149_450],
        [i32::MIN, 0, 650_000],
        [32_000, 10_000, 650_000],
    );
    let td = l.decode_tracking(&r).unwrap();
    assert_eq!(td.gaze_um, None);
    assert_eq!(td.left_eye_um, None);
    assert!(td.right_eye_um.is_some());
    assert_eq!(td.invalid_fields, 2);
    assert_eq!(td.timestamp_us, Some(2_000_000));

    // A Configuration report with a negative width is outside 0..2^31−1.
    let mut cfg = vec![0x12];
    cfg.extend_from_slice(&(-5i32).to_le_bytes());
    cfg.extend_from_slice(&SCREEN_H_UM.to_le_bytes());
    assert!(matches!(
        l.decode_screen(&cfg),
        Err(Page12Error::NoFeature(_))
    ));
}

#[test]
fn wrong_and_short_reports_are_errors() {
    let l = layout();
    let mut r = tracking_report(1, [0, 0], [0; 3], [0; 3]);
    r[0] = 0x11;
    assert_eq!(
        l.decode_tracking(&r),
        Err(Page12Error::WrongReport {
            got: 0x11,
            expected: 0x10
        })
    );
    let r = tracking_report(1, [0, 0], [0; 3], [0; 3]);
    assert!(matches!(
        l.decode_tracking(&r[..20]),
        Err(Page12Error::Short {
            got: 20,
            expected: 41,
            ..
        })
    ));
    assert!(matches!(
        l.decode_tracking(&[]),
        Err(Page12Error::Short { .. })
    ));
}

#[test]
fn feature_reports_status_and_control() {
    let l = layout();
    assert_eq!(l.configuration_report(), Some((0x12, 9)));
    assert_eq!(l.status_report(), Some((0x13, 4)));
    // Configuration status 1 (ready), 60 Hz.
    let (hz, status) = l.decode_status(&[0x13, 1, 60, 0]).unwrap();
    assert_eq!((hz, status), (Some(60.0), Some(1)));
    // Status 9 is outside 0..=4.
    assert_eq!(l.decode_status(&[0x13, 9, 60, 0]).unwrap().1, None);
    assert_eq!(
        l.control_report(page12::MODE_ENABLE_GAZE_POINT | page12::MODE_ENABLE_EYE_POSITION),
        Some(vec![0x14, 0x03])
    );
}

/// A tracker without report IDs whose 12-bit gaze fields map logical
/// 0..4095 onto physical 0..5313 × 10^−2 cm (0..531.3 mm).
#[rustfmt::skip]
const SCALED_TRACKER: &[u8] = &[
    0x05, 0x12, 0x09, 0x01, 0xA1, 0x01, // Usage Page 0x12, Eye Tracker, Application
    0x09, 0x10, 0xA1, 0x02,             // Tracking Data, Logical
    0x09, 0x24, 0xA1, 0x00,             // Gaze Point, Physical
    0x09, 0x21, 0x09, 0x22,             // Position X, Y
    0x15, 0x00, 0x26, 0xFF, 0x0F,       // Logical 0..4095
    0x35, 0x00, 0x46, 0xC1, 0x14,       // Physical 0..5313
    0x65, 0x11, 0x55, 0x0E,             // Unit cm, Unit Exponent −2
    0x75, 0x0C, 0x95, 0x02,             // Report Size 12, Count 2
    0x81, 0x02,                         // Input (Data, Var, Abs)
    0xC0, 0xC0, 0xC0,
];

#[test]
fn physical_extents_units_and_exponents_come_from_the_descriptor() {
    let d = Descriptor::parse(SCALED_TRACKER).unwrap();
    assert!(!d.uses_report_ids);
    let l = Page12Layout::from_descriptor(&d).unwrap();
    assert_eq!(l.tracking_report_len(), 3);
    // X = 2048, Y = 4095 packed as two 12-bit little-endian fields.
    let (x, y) = (2048u32, 4095u32);
    let packed = x | (y << 12);
    let r = [packed as u8, (packed >> 8) as u8, (packed >> 16) as u8];
    let g = l.decode_tracking(&r).unwrap().gaze_um.unwrap();
    // HID 1.11 §6.2.2.7: physical = logical · 5313/4095, in 10^−2 cm.
    let expect_x_um = 2048.0 * 5313.0 / 4095.0 * 1e-2 * 1e4;
    assert!(
        (g[0] - expect_x_um).abs() < 1e-6,
        "{} vs {expect_x_um}",
        g[0]
    );
    assert!((g[1] - 531_300.0).abs() < 1e-6);
    // No Configuration report: the screen size is unavailable.
    assert_eq!(l.configuration_report(), None);
}

#[test]
fn profiles_are_chosen_from_the_descriptor_and_ids() {
    let d = Descriptor::parse(EYE_TRACKER).unwrap();
    assert!(matches!(
        choose_profile(&d, 0x1234, 0x5678, HidOptions::default()),
        Some(HidProfile::Page12 { .. })
    ));
    // A vendor-defined descriptor (usage page 0xFF00, 64-byte reports).
    let vendor = testdata::LIVETRACK_STYLE;
    let v = Descriptor::parse(vendor).unwrap();
    assert_eq!(v.report_len(ReportKind::Input, 0), 64);
    assert!(matches!(
        choose_profile(
            &v,
            livetrack::VENDOR_ID,
            livetrack::PRODUCT_ID,
            HidOptions::default()
        ),
        Some(HidProfile::LiveTrack(_))
    ));
    assert!(choose_profile(&v, 0x1234, 0x5678, HidOptions::default()).is_none());
}

/// A LiveTrack packet per the CRS driver's byte offsets.
fn livetrack_packet(
    kind: u8,
    ts: u64,
    s1: (u16, u16, [i16; 9]),
    s2: (u16, u16, [i16; 9]),
) -> [u8; 64] {
    let mut r = [0u8; 64];
    r[0] = kind;
    r[8..16].copy_from_slice(&ts.to_le_bytes());
    for (flags_at, scale_at, (flags, scale, vals)) in [(16, 22, s1), (40, 46, s2)] {
        r[flags_at..flags_at + 2].copy_from_slice(&flags.to_le_bytes());
        let start = if kind == livetrack::PACKET_RAW {
            r[scale_at..scale_at + 2].copy_from_slice(&scale.to_le_bytes());
            scale_at + 2
        } else {
            scale_at
        };
        let n = if kind == livetrack::PACKET_RAW { 8 } else { 9 };
        for (i, v) in vals.iter().take(n).enumerate() {
            r[start + 2 * i..start + 2 * i + 2].copy_from_slice(&v.to_le_bytes());
        }
    }
    r
}

#[test]
fn livetrack_flags_follow_the_driver() {
    // Bits 5-4 = 01 (one glint): tracked iff bits 3-0 = 0111.
    assert!(livetrack::tracked(0b01_0111));
    assert!(!livetrack::tracked(0b01_1111));
    assert!(!livetrack::tracked(0b01_0011));
    // Bits 5-4 = 10 (two glints): tracked iff bits 3-0 = 1111.
    assert!(livetrack::tracked(0b10_1111));
    assert!(!livetrack::tracked(0b10_0111));
    // Undefined glint setting.
    assert!(!livetrack::tracked(0b00_1111));
    assert!(!livetrack::tracked(0b11_1111));
}

#[test]
fn livetrack_raw_and_calibrated_packets_decode() {
    // Raw: scale 16; pupil 56.25 × 54 px at (320, 240); second half
    // untracked (tracking enabled, pupil missing).
    let p = livetrack_packet(
        livetrack::PACKET_RAW,
        123_456_789,
        (0b01_0111, 16, [900, 864, 5120, 3840, 5200, 3900, 0, 0, 0]),
        (0b01_0001, 16, [0, 0, 0, 0, 0, 0, 0, 0, 0]),
    );
    let d = livetrack::decode(&p).unwrap();
    assert_eq!(d.mode, LiveTrackMode::Raw);
    assert_eq!(d.device_timestamp, 123_456_789);
    let s = d.samples[0];
    assert!(s.tracked);
    assert_eq!((s.pupil_w, s.pupil_h, s.a), (56.25, 54.0, [320.0, 240.0]));
    assert_eq!(s.b[..2], [325.0, 243.75]);
    assert!(!d.samples[1].tracked);
    let [a, b] = livetrack::pupil_samples(&d, 10.0, 1);
    assert_eq!(
        (a.eye, a.unit, a.diameter_raw, a.confidence),
        (1, PupilUnit::Px, 56.25, 1.0)
    );
    assert_eq!((b.diameter_raw, b.confidence), (0.0, 0.0));

    // Calibrated: values / 32, two-glint flags; negative gaze.
    let p = livetrack_packet(
        livetrack::PACKET_CALIBRATED,
        7,
        (0b10_1111, 0, [160, 144, -320, 96, 16_000, 32, -64, 0, 0]),
        (0b10_1111, 0, [161, 145, -316, 98, 16_000, 32, -64, 0, 0]),
    );
    let d = livetrack::decode(&p).unwrap();
    assert_eq!(d.mode, LiveTrackMode::Calibrated);
    let s = d.samples[0];
    assert_eq!((s.pupil_w, s.pupil_h, s.a), (5.0, 4.5, [-10.0, 3.0]));
    assert_eq!(s.b, [500.0, 1.0, -2.0, 0.0]);
    assert_eq!(d.samples[1].pupil_w, 161.0 / 32.0);
    let [a, _] = livetrack::pupil_samples(&d, 0.0, 0);
    assert_eq!((a.unit, a.diameter_raw), (PupilUnit::Arbitrary, 5.0));
}

#[test]
fn bad_livetrack_reports_are_errors() {
    assert_eq!(
        livetrack::decode(&[200; 10]),
        Err(LiveTrackError::Length(10))
    );
    let mut p = livetrack_packet(
        livetrack::PACKET_RAW,
        0,
        (0b01_0111, 16, [0; 9]),
        (0b01_0111, 16, [0; 9]),
    );
    p[0] = 7;
    assert_eq!(livetrack::decode(&p), Err(LiveTrackError::Kind(7)));
    p[0] = livetrack::PACKET_RAW;
    p[46] = 0;
    p[47] = 0;
    assert_eq!(
        livetrack::decode(&p),
        Err(LiveTrackError::ZeroScale {
            sample: 2,
            offset: 46
        })
    );
    assert_eq!(
        livetrack::command(livetrack::CMD_START_CALIBRATED)[..3],
        [0, 105, 0]
    );
}
