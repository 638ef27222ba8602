//! What is connected: HID devices (marked when their report descriptor has
//! a page-0x12 Tracking Data report or their VID:PID has a vendor profile),
//! USB devices (marked when they have a vendor-specific interface, the
//! `usb://` source's candidates), and serial ports.
//!
//! Report descriptors are read from sysfs
//! (`/sys/class/hidraw/hidrawN/device/report_descriptor`, readable without
//! access to the device node), so marking needs no permissions; whether the
//! node itself can be opened is checked separately and reported.
//! Nothing here panics: a part that cannot be listed is an `Err` naming
//! what failed.

use std::path::Path;

use super::hid::descriptor::Descriptor;
use super::hid::livetrack;
use super::hid::page12::Page12Layout;
use super::usb::CLASS_VENDOR_SPECIFIC;

/// What a HID device is to gazelight.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum HidKind {
    /// Standard page-0x12 eye tracker.
    Page12,
    /// CRS LiveTrack vendor profile.
    LiveTrack,
    /// Anything else.
    Other,
}

/// One HID device.
#[derive(Clone, Debug)]
pub struct HidEntry {
    /// `/dev/hidrawN`.
    pub path: String,
    pub vendor_id: u16,
    pub product_id: u16,
    pub manufacturer: Option<String>,
    pub product: Option<String>,
    pub kind: HidKind,
    /// A problem worth telling (permission to open, unreadable
    /// descriptor).
    pub note: Option<String>,
}

/// One USB device.
#[derive(Clone, Debug)]
pub struct UsbEntry {
    pub bus: u8,
    pub address: u8,
    pub vendor_id: u16,
    pub product_id: u16,
    pub manufacturer: Option<String>,
    pub product: Option<String>,
    /// Interface numbers of class 0xFF (vendor specific).
    pub vendor_interfaces: Vec<u8>,
}

/// One serial port.
#[derive(Clone, Debug)]
pub struct SerialEntry {
    pub path: String,
    /// `usb VVVV:PPPP product`, `pci`, `bluetooth` or `unknown`.
    pub kind: String,
}

/// A class of devices the system would not list.
#[derive(Clone, Debug, thiserror::Error)]
#[error("listing {what}: {reason}")]
pub struct ListError {
    /// `HID devices`, `USB devices` or `serial ports`.
    pub what: &'static str,
    /// What the system said.
    pub reason: String,
}

impl ListError {
    fn new(what: &'static str, reason: impl std::fmt::Display) -> Self {
        Self {
            what,
            reason: reason.to_string(),
        }
    }
}

/// Everything found.
#[derive(Debug)]
pub struct Discovery {
    pub hid: Result<Vec<HidEntry>, ListError>,
    pub usb: Result<Vec<UsbEntry>, ListError>,
    pub serial: Result<Vec<SerialEntry>, ListError>,
}

impl Discovery {
    /// Whether anything looks like a tracker gazelight can read: a page-0x12
    /// or profiled HID device, a USB device with a vendor interface, or a
    /// USB serial port (CDC-ACM).
    pub fn has_candidates(&self) -> bool {
        let hid = self
            .hid
            .as_ref()
            .is_ok_and(|v| v.iter().any(|h| h.kind != HidKind::Other));
        let usb = self
            .usb
            .as_ref()
            .is_ok_and(|v| v.iter().any(|u| !u.vendor_interfaces.is_empty()));
        let serial = self
            .serial
            .as_ref()
            .is_ok_and(|v| v.iter().any(|s| s.kind.starts_with("usb")));
        hid || usb || serial
    }
}

/// Classify a HID device from its descriptor bytes and ids.
pub fn classify_hid(
    descriptor: &[u8],
    vendor_id: u16,
    product_id: u16,
) -> (HidKind, Option<String>) {
    if (vendor_id, product_id) == (livetrack::VENDOR_ID, livetrack::PRODUCT_ID) {
        return (HidKind::LiveTrack, None);
    }
    match Descriptor::parse(descriptor) {
        Ok(d) if Page12Layout::is_tracker(&d) => (HidKind::Page12, None),
        Ok(_) => (HidKind::Other, None),
        Err(e) => (
            HidKind::Other,
            Some(format!("descriptor does not parse: {e}")),
        ),
    }
}

fn open_note(path: &str) -> Option<String> {
    match std::fs::OpenOptions::new()
        .read(true)
        .write(true)
        .open(path)
    {
        Ok(_) => None,
        Err(e) if e.kind() == std::io::ErrorKind::PermissionDenied => Some(format!(
            "permission denied opening {path} (a udev rule or group membership is needed)"
        )),
        Err(e) => Some(format!("cannot open {path}: {e}")),
    }
}

fn list_hid() -> Result<Vec<HidEntry>, ListError> {
    let api = hidapi::HidApi::new().map_err(|e| ListError::new("HID devices", e))?;
    let mut out: Vec<HidEntry> = Vec::new();
    for info in api.device_list() {
        let path = info.path().to_string_lossy().into_owned();
        if out.iter().any(|e| e.path == path) {
            continue;
        }
        let base = Path::new(&path)
            .file_name()
            .map(|n| n.to_string_lossy().into_owned())
            .unwrap_or_default();
        let sys = format!("/sys/class/hidraw/{base}/device/report_descriptor");
        let (kind, mut note) = match std::fs::read(&sys) {
            Ok(bytes) => classify_hid(&bytes, info.vendor_id(), info.product_id()),
            Err(e) => (
                if (info.vendor_id(), info.product_id())
                    == (livetrack::VENDOR_ID, livetrack::PRODUCT_ID)
                {
                    HidKind::LiveTrack
                } else {
                    HidKind::Other
                },
                Some(format!("cannot read {sys}: {e}")),
            ),
        };
        if note.is_none() && kind != HidKind::Other {
            note = open_note(&path);
        }
        out.push(HidEntry {
            path,
            vendor_id: info.vendor_id(),
            product_id: info.product_id(),
            manufacturer: info.manufacturer_string().map(str::to_owned),
            product: info.product_string().map(str::to_owned),
            kind,
            note,
        });
    }
    out.sort_by(|a, b| a.path.cmp(&b.path));
    Ok(out)
}

fn list_usb() -> Result<Vec<UsbEntry>, ListError> {
    use nusb::MaybeFuture;
    let devices = nusb::list_devices()
        .wait()
        .map_err(|e| ListError::new("USB devices", e))?;
    let mut out: Vec<UsbEntry> = devices
        .map(|d| UsbEntry {
            bus: d.busnum(),
            address: d.device_address(),
            vendor_id: d.vendor_id(),
            product_id: d.product_id(),
            manufacturer: d.manufacturer_string().map(str::to_owned),
            product: d.product_string().map(str::to_owned),
            vendor_interfaces: d
                .interfaces()
                .filter(|i| i.class() == CLASS_VENDOR_SPECIFIC)
                .map(|i| i.interface_number())
                .collect(),
        })
        .collect();
    out.sort_by_key(|u| (u.bus, u.address));
    Ok(out)
}

fn list_serial() -> Result<Vec<SerialEntry>, ListError> {
    let ports = serialport::available_ports().map_err(|e| ListError::new("serial ports", e))?;
    let mut out: Vec<SerialEntry> = ports
        .into_iter()
        .map(|p| SerialEntry {
            path: p.port_name,
            kind: match p.port_type {
                serialport::SerialPortType::UsbPort(u) => format!(
                    "usb {:04x}:{:04x}{}",
                    u.vid,
                    u.pid,
                    u.product.map(|s| format!(" {s}")).unwrap_or_default()
                ),
                serialport::SerialPortType::PciPort => "pci".to_owned(),
                serialport::SerialPortType::BluetoothPort => "bluetooth".to_owned(),
                serialport::SerialPortType::Unknown => "unknown".to_owned(),
            },
        })
        .collect();
    out.sort_by(|a, b| a.path.cmp(&b.path));
    Ok(out)
}

/// List HID devices, USB devices and serial ports.
pub fn discover() -> Discovery {
    Discovery {
        hid: list_hid(),
        usb: list_usb(),
        serial: list_serial(),
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn classification_uses_descriptor_and_ids() {
        // Boot mouse descriptor (HID 1.11 Appendix E.10), abbreviated to
        // X/Y only: not a tracker.
        let mouse = [
            0x05, 0x01, 0x09, 0x02, 0xA1, 0x01, 0x09, 0x30, 0x09, 0x31, 0x15, 0x81, 0x25, 0x7F,
            0x75, 0x08, 0x95, 0x02, 0x81, 0x06, 0xC0,
        ];
        assert_eq!(classify_hid(&mouse, 0x046d, 0xc077), (HidKind::Other, None));
        assert_eq!(
            classify_hid(&mouse, livetrack::VENDOR_ID, livetrack::PRODUCT_ID).0,
            HidKind::LiveTrack
        );
        // Minimal page-0x12 tracker: Gaze Point X/Y in Tracking Data.
        let tracker = [
            0x05, 0x12, 0x09, 0x01, 0xA1, 0x01, 0x09, 0x10, 0xA1, 0x02, 0x09, 0x24, 0xA1, 0x00,
            0x09, 0x21, 0x09, 0x22, 0x15, 0x00, 0x26, 0xFF, 0x7F, 0x75, 0x10, 0x95, 0x02, 0x81,
            0x02, 0xC0, 0xC0, 0xC0,
        ];
        assert_eq!(classify_hid(&tracker, 1, 2), (HidKind::Page12, None));
        let (k, note) = classify_hid(&[0xA1, 0x01], 1, 2);
        assert_eq!(k, HidKind::Other);
        assert!(note.unwrap().contains("does not parse"));
    }
}
