//! Test data, not used by the library: the HID report descriptors shared
//! by the crate's HID tests (`tests/hid_reports.rs`) and the QEMU stage's
//! guest program (`.ci/qemu/probe`, which hands them to the Linux
//! kernel through `/dev/uhid` and a configfs HID gadget), so both exercise
//! the same bytes.
//!
//! - [`PAGE12_EYE_TRACKER`]: a page-0x12 eye tracker written per the
//!   "Eye and Head Trackers" usage page (HUTRR74; usage IDs in
//!   [`super::page12`]).
//! - [`LIVETRACK_STYLE`]: a vendor-defined descriptor shaped like a CRS
//!   LiveTrack's (usage page 0xFF00, 64-byte input and output reports, no
//!   report IDs), decoded by the [`super::livetrack`] profile.
//! - [`SCREEN_UM`]: the calibrated screen both report for the page-0x12
//!   tracker's Configuration feature report.

/// A page-0x12 eye tracker: Tracking Data (ID 0x10: 64-bit µs timestamp,
/// gaze point X/Y and left/right eye X/Y/Z as signed 32-bit µm),
/// Capabilities (0x11), Configuration (0x12), Status (0x13), Control
/// (0x14).
#[rustfmt::skip]
pub const PAGE12_EYE_TRACKER: &[u8] = &[
    0x05, 0x12,                   // Usage Page (Eye and Head Trackers)
    0x09, 0x01,                   // Usage (Eye Tracker)
    0xA1, 0x01,                   // Collection (Application)
    0x09, 0x10,                   //   Usage (Tracking Data)
    0xA1, 0x02,                   //   Collection (Logical)
    0x85, 0x10,                   //     Report ID (0x10)
    0x09, 0x20,                   //     Usage (Sensor Timestamp)
    0x15, 0x00,                   //     Logical Minimum (0)
    0x27, 0xFF, 0xFF, 0xFF, 0x7F, //     Logical Maximum (2^31 − 1)
    0x66, 0x01, 0x10,             //     Unit (SI Linear: second)
    0x55, 0x0A,                   //     Unit Exponent (−6)
    0x75, 0x40,                   //     Report Size (64)
    0x95, 0x01,                   //     Report Count (1)
    0x81, 0x02,                   //     Input (Data, Var, Abs)
    0x09, 0x24,                   //     Usage (Gaze Point)
    0xA1, 0x00,                   //     Collection (Physical)
    0x09, 0x21,                   //       Usage (Position X)
    0x09, 0x22,                   //       Usage (Position Y)
    0x17, 0x01, 0x00, 0x00, 0x80, //       Logical Minimum (−2^31 + 1)
    0x27, 0xFF, 0xFF, 0xFF, 0x7F, //       Logical Maximum (2^31 − 1)
    0x65, 0x11,                   //       Unit (SI Linear: centimetre)
    0x55, 0x0C,                   //       Unit Exponent (−4): µm
    0x75, 0x20,                   //       Report Size (32)
    0x95, 0x02,                   //       Report Count (2)
    0x81, 0x02,                   //       Input (Data, Var, Abs)
    0xC0,                         //     End Collection
    0x09, 0x25,                   //     Usage (Left Eye Position)
    0xA1, 0x00,                   //     Collection (Physical)
    0x09, 0x21, 0x09, 0x22, 0x09, 0x23, // Usage (X, Y, Z)
    0x95, 0x03,                   //       Report Count (3)
    0x81, 0x02,                   //       Input (Data, Var, Abs)
    0xC0,                         //     End Collection
    0x09, 0x26,                   //     Usage (Right Eye Position)
    0xA1, 0x00,                   //     Collection (Physical)
    0x09, 0x21, 0x09, 0x22, 0x09, 0x23, // Usage (X, Y, Z)
    0x95, 0x03,                   //       Report Count (3)
    0x81, 0x02,                   //       Input (Data, Var, Abs)
    0xC0,                         //     End Collection
    0xC0,                         //   End Collection
    0x09, 0x11,                   //   Usage (Capabilities)
    0xA1, 0x02,                   //   Collection (Logical)
    0x85, 0x11,                   //     Report ID (0x11)
    0x0A, 0x00, 0x01,             //     Usage (Tracker Quality)
    0x15, 0x00, 0x25, 0x01,       //     Logical Minimum (0), Maximum (1)
    0x65, 0x00, 0x55, 0x00,       //     Unit (none), Unit Exponent (0)
    0x75, 0x08, 0x95, 0x01,       //     Report Size (8), Count (1)
    0xB1, 0x02,                   //     Feature (Data, Var, Abs)
    0x0A, 0x04, 0x01,             //     Usage (Maximum Screen Plane Width)
    0x0A, 0x05, 0x01,             //     Usage (Maximum Screen Plane Height)
    0x27, 0xFF, 0xFF, 0xFF, 0x7F, //     Logical Maximum (2^31 − 1)
    0x65, 0x11, 0x55, 0x0C,       //     Unit (cm), Unit Exponent (−4): µm
    0x75, 0x20, 0x95, 0x02,       //     Report Size (32), Count (2)
    0xB1, 0x02,                   //     Feature (Data, Var, Abs)
    0xC0,                         //   End Collection
    0x09, 0x12,                   //   Usage (Configuration)
    0xA1, 0x02,                   //   Collection (Logical)
    0x85, 0x12,                   //     Report ID (0x12)
    0x0A, 0x04, 0x02,             //     Usage (Calibrated Screen Width)
    0x0A, 0x05, 0x02,             //     Usage (Calibrated Screen Height)
    0x15, 0x00,                   //     Logical Minimum (0)
    0x27, 0xFF, 0xFF, 0xFF, 0x7F, //     Logical Maximum (2^31 − 1)
    0x65, 0x11, 0x55, 0x0C,       //     Unit (cm), Unit Exponent (−4): µm
    0x75, 0x20, 0x95, 0x02,       //     Report Size (32), Count (2)
    0xB1, 0x02,                   //     Feature (Data, Var, Abs)
    0xC0,                         //   End Collection
    0x09, 0x13,                   //   Usage (Status)
    0xA1, 0x02,                   //   Collection (Logical)
    0x85, 0x13,                   //     Report ID (0x13)
    0x0A, 0x01, 0x03,             //     Usage (Configuration Status)
    0x15, 0x00, 0x25, 0x04,       //     Logical Minimum (0), Maximum (4)
    0x65, 0x00, 0x55, 0x00,       //     Unit (none), Unit Exponent (0)
    0x75, 0x08, 0x95, 0x01,       //     Report Size (8), Count (1)
    0xB1, 0x02,                   //     Feature (Data, Var, Abs)
    0x0A, 0x00, 0x03,             //     Usage (Sampling Frequency)
    0x26, 0xFF, 0x7F,             //     Logical Maximum (32767)
    0x66, 0x01, 0xF0,             //     Unit (SI Linear: s^−1 = Hz)
    0x75, 0x10,                   //     Report Size (16)
    0xB1, 0x02,                   //     Feature (Data, Var, Abs)
    0xC0,                         //   End Collection
    0x09, 0x14,                   //   Usage (Control)
    0xA1, 0x02,                   //   Collection (Logical)
    0x85, 0x14,                   //     Report ID (0x14)
    0x0A, 0x00, 0x04,             //     Usage (Device Mode Request)
    0x15, 0x00, 0x25, 0x07,       //     Logical Minimum (0), Maximum (7)
    0x65, 0x00,                   //     Unit (none)
    0x75, 0x08, 0x95, 0x01,       //     Report Size (8), Count (1)
    0xB1, 0x02,                   //     Feature (Data, Var, Abs)
    0xC0,                         //   End Collection
    0xC0,                         // End Collection
];

/// A LiveTrack-style vendor descriptor: usage page 0xFF00, one 64-byte
/// input and one 64-byte output report, no report IDs.
#[rustfmt::skip]
pub const LIVETRACK_STYLE: &[u8] = &[
    0x06, 0x00, 0xFF, 0x09, 0x01, 0xA1, 0x01, // Usage Page 0xFF00, Usage 1, Application
    0x15, 0x00, 0x26, 0xFF, 0x00, 0x75, 0x08, 0x95, 0x40, // 0..255, 8 bits × 64
    0x09, 0x01, 0x81, 0x02, 0x09, 0x01, 0x91, 0x02, 0xC0, // Input, Output
];

/// Calibrated screen of the page-0x12 test tracker, µm (width, height): a
/// 24-inch 16:9 panel, diagonal 609.6 mm → 531.3 mm × 298.9 mm.
pub const SCREEN_UM: [i32; 2] = [531_300, 298_900];
