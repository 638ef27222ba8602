//! HID eye trackers: report-descriptor parsing, the standard usage page
//! 0x12 "Eye and Head Trackers", vendor profiles, and the hidapi source.
//!
//! [`source::HidSource`] opens a device (by VID:PID or hidraw path), reads
//! its report descriptor, and picks a decoder: page 0x12 when the
//! descriptor has a Tracking Data report with a Gaze Point, else a vendor
//! profile matched by VID:PID ([`livetrack`]), else it refuses the device
//! with an error naming what it found.

pub mod descriptor;
pub mod livetrack;
pub mod page12;
pub mod source;
#[doc(hidden)]
pub mod testdata;

pub use source::{HidOptions, HidProfile, HidSource, HidStats};
