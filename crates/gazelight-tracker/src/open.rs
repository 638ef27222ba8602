//! Opening a source a URI names: the hardware transports of
//! `gazelight-devices` behind one [`AnySource`].

use gazelight_devices::{gazepoint, hid, serial, usb};
use gazelight_eye::Sample;
use gazelight_eye::source::{SampleSource, SourceError};

use crate::uri::SourceUri;

/// Any hardware source, as opened from a [`SourceUri`].
pub enum AnySource {
    /// A HID tracker (`hid://`).
    Hid(hid::HidSource),
    /// A vendor bulk endpoint (`usb://`).
    Usb(usb::UsbSource),
    /// A serial line (`serial://`).
    Serial(serial::SerialSource),
    /// The Gazepoint Open Gaze API (`gazepoint://`).
    Gazepoint(gazepoint::GazepointSource),
}

impl SampleSource for AnySource {
    async fn next(&mut self) -> Result<Option<Sample>, SourceError> {
        match self {
            AnySource::Hid(s) => s.next().await,
            AnySource::Usb(s) => s.next().await,
            AnySource::Serial(s) => s.next().await,
            AnySource::Gazepoint(s) => s.next().await,
        }
    }

    fn describe(&self) -> String {
        match self {
            AnySource::Hid(s) => s.describe(),
            AnySource::Usb(s) => s.describe(),
            AnySource::Serial(s) => s.describe(),
            AnySource::Gazepoint(s) => s.describe(),
        }
    }
}

/// Open the hardware source a URI names.
///
/// `pupil://` and `replay://` are not hardware transports: the service opens
/// them itself ([`crate::PupilSource`], [`crate::import`]), so for those this
/// returns [`SourceError::Fatal`] saying so. Opening does not wait for data:
/// a HID or serial device is opened (so a missing device or a permission
/// problem is reported here), a Gazepoint connection is made on the first
/// [`SampleSource::next`].
pub fn open(uri: &SourceUri) -> Result<AnySource, SourceError> {
    match uri {
        SourceUri::Hid(target) => Ok(AnySource::Hid(hid::HidSource::open(
            target.clone(),
            hid::HidOptions::default(),
        )?)),
        SourceUri::Usb {
            vendor_id,
            product_id,
            interface,
        } => Ok(AnySource::Usb(usb::UsbSource::open(
            *vendor_id,
            *product_id,
            *interface,
        )?)),
        SourceUri::Serial { path, baud, format } => Ok(AnySource::Serial(
            serial::SerialSource::open(path, *baud, *format)?,
        )),
        SourceUri::Gazepoint { host, port } => Ok(AnySource::Gazepoint(
            gazepoint::GazepointSource::new(host.clone(), *port),
        )),
        SourceUri::Pupil { .. } | SourceUri::Replay { .. } => Err(SourceError::Fatal {
            source_name: uri.to_string(),
            reason: "not a hardware transport: open pupil:// with the Pupil client and \
                     replay:// with the recording importers"
                .to_owned(),
        }),
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn pupil_and_replay_uris_are_not_opened_here() {
        for s in ["pupil://127.0.0.1:50020", "replay:///tmp/x.pldata"] {
            let uri: SourceUri = s.parse().unwrap();
            let Err(SourceError::Fatal { reason, .. }) = open(&uri) else {
                panic!("{s} should be refused");
            };
            assert!(reason.contains("not a hardware transport"), "{reason}");
        }
    }
}
