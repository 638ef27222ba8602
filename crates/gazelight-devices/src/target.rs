//! What to open: the device addresses and line formats the transports take.
//! The source URI parser (`gazelight-tracker`) produces these.

use std::path::PathBuf;

/// Default TCP port of the Gazepoint Open Gaze API server (Open Gaze API
/// v2.0 §2: "The server default port value is 4242").
pub const GAZEPOINT_DEFAULT_PORT: u16 = 4242;

/// Default serial line rate, baud.
pub const DEFAULT_BAUD: u32 = 115_200;

/// How samples are encoded on a serial line (see [`crate::serial`]).
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum SerialFormat {
    /// Gazepoint Open Gaze API records, one per line.
    Gazepoint,
    /// Comma-separated sample lines.
    Csv,
    /// Binary frames with sync bytes, length and CRC-16 ([`crate::framing`]).
    Framed,
}

impl SerialFormat {
    /// The name used in `serial://…?format=NAME` URIs.
    pub fn as_str(self) -> &'static str {
        match self {
            SerialFormat::Gazepoint => "gazepoint",
            SerialFormat::Csv => "csv",
            SerialFormat::Framed => "framed",
        }
    }
}

/// Which HID device to open.
#[derive(Clone, Debug, PartialEq, Eq)]
pub enum HidTarget {
    /// The first device with this vendor and product id.
    VidPid { vendor_id: u16, product_id: u16 },
    /// A device node such as `/dev/hidraw0`.
    Path(PathBuf),
}
