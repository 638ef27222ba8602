//! Raw USB trackers: a vendor-specific interface with a bulk-IN endpoint,
//! read with `nusb` (pure Rust, usbfs; no global context, so a machine
//! without usbfs gets an error, never a panic).
//!
//! The endpoint is found from the active configuration's descriptors: the
//! first interface (or the one named by `?interface=N`) of class 0xFF
//! (vendor specific, USB 2.0 §9.6.5 / the USB-IF class code list) whose
//! alternate setting 0 has a bulk endpoint with the IN direction bit (0x80)
//! set in its address (USB 2.0 §9.6.6).
//!
//! Framing: the byte stream of the bulk endpoint is the sample framing of
//! [`super::framing`] (sync 0xA5 0x5A, version 1, length, little-endian
//! payload, CRC-16/CCITT-FALSE). Frames may be split across transfers and
//! several frames may share one; bytes between frames are skipped and a
//! corrupt frame is an item error naming its stream offset. Device
//! timestamps (µs) are mapped onto the host clock.
//!
//! A lost device is [`SourceError::Disconnected`]; the next call looks
//! for the device again.

use std::sync::Arc;

use nusb::MaybeFuture;
use nusb::descriptors::{ConfigurationDescriptor, TransferType};
use nusb::transfer::{Bulk, Direction, In};

use super::framing::FrameDecoder;
use super::now_secs;
use gazelight_eye::clock::{SharedClockStats, SourceClock, SourceClockConfig};
use gazelight_eye::sample::Sample;
use gazelight_eye::source::{SampleSource, SourceError};

/// USB interface class "vendor specific".
pub const CLASS_VENDOR_SPECIFIC: u8 = 0xFF;
/// Transfers kept in flight on the endpoint.
pub const TRANSFERS_IN_FLIGHT: usize = 4;
/// Bytes requested per transfer (a multiple of every bulk max packet size:
/// 64 full speed, 512 high speed, 1024 super speed).
pub const TRANSFER_LEN: usize = 4096;

/// The endpoint chosen on a device.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub struct BulkInEndpoint {
    pub interface: u8,
    pub alt_setting: u8,
    pub address: u8,
    pub max_packet_size: usize,
}

/// Find the vendor bulk-IN endpoint in a configuration.
pub fn find_bulk_in(
    config: &ConfigurationDescriptor<'_>,
    interface: Option<u8>,
) -> Option<BulkInEndpoint> {
    config.interface_alt_settings().find_map(|alt| {
        if alt.alternate_setting() != 0 {
            return None;
        }
        match interface {
            Some(n) if alt.interface_number() != n => return None,
            None if alt.class() != CLASS_VENDOR_SPECIFIC => return None,
            _ => {}
        }
        alt.endpoints()
            .find(|e| e.transfer_type() == TransferType::Bulk && e.direction() == Direction::In)
            .map(|e| BulkInEndpoint {
                interface: alt.interface_number(),
                alt_setting: 0,
                address: e.address(),
                max_packet_size: e.max_packet_size(),
            })
    })
}

struct Open {
    endpoint: nusb::Endpoint<Bulk, In>,
    _interface: nusb::Interface,
}

/// A vendor bulk-endpoint tracker.
pub struct UsbSource {
    vendor_id: u16,
    product_id: u16,
    interface: Option<u8>,
    name: String,
    open: Option<Open>,
    frames: FrameDecoder,
    /// The device clock → host time.
    clock: SourceClock,
    /// Bytes of the last transfer not yet pushed into the decoder.
    carry: Vec<u8>,
    carry_pos: usize,
}

fn explain(e: &nusb::Error, what: &str) -> String {
    match e.kind() {
        nusb::ErrorKind::PermissionDenied => format!(
            "{what}: permission denied (a udev rule granting access to the USB device node is \
             needed): {e}"
        ),
        nusb::ErrorKind::Busy => format!("{what}: interface busy (claimed by a driver?): {e}"),
        _ => format!("{what}: {e}"),
    }
}

impl UsbSource {
    /// Open the first device with this VID:PID and claim its vendor
    /// interface. A missing device, no usbfs, a permission problem or no
    /// bulk-IN endpoint is a [`SourceError::Fatal`].
    pub fn open(
        vendor_id: u16,
        product_id: u16,
        interface: Option<u8>,
    ) -> Result<Self, SourceError> {
        let mut s = Self {
            vendor_id,
            product_id,
            interface,
            name: format!("usb://{vendor_id:04x}:{product_id:04x}"),
            open: None,
            frames: FrameDecoder::new(),
            clock: SourceClock::new(
                format!("usb://{vendor_id:04x}:{product_id:04x}"),
                SourceClockConfig::default(),
            ),
            carry: Vec::with_capacity(TRANSFER_LEN),
            carry_pos: 0,
        };
        let o = s.connect().map_err(|reason| SourceError::Fatal {
            source_name: s.name.clone(),
            reason,
        })?;
        s.open = Some(o);
        Ok(s)
    }

    fn connect(&self) -> Result<Open, String> {
        let (vid, pid) = (self.vendor_id, self.product_id);
        let info = nusb::list_devices()
            .wait()
            .map_err(|e| explain(&e, "listing USB devices (is usbfs available?)"))?
            .find(|d| d.vendor_id() == vid && d.product_id() == pid)
            .ok_or_else(|| format!("no USB device {vid:04x}:{pid:04x} is connected"))?;
        let device = info
            .open()
            .wait()
            .map_err(|e| explain(&e, &format!("opening {vid:04x}:{pid:04x}")))?;
        let ep = {
            let config = device
                .active_configuration()
                .map_err(|e| format!("reading the active configuration: {e}"))?;
            find_bulk_in(&config, self.interface).ok_or_else(|| match self.interface {
                Some(n) => format!("interface {n} has no bulk-IN endpoint"),
                None => {
                    "no vendor-specific (class 0xFF) interface with a bulk-IN endpoint".to_owned()
                }
            })?
        };
        let iface = device
            .claim_interface(ep.interface)
            .wait()
            .map_err(|e| explain(&e, &format!("claiming interface {}", ep.interface)))?;
        let mut endpoint = iface
            .endpoint::<Bulk, In>(ep.address)
            .map_err(|e| format!("opening endpoint {:#04x}: {e}", ep.address))?;
        while endpoint.pending() < TRANSFERS_IN_FLIGHT {
            let len = TRANSFER_LEN.div_ceil(ep.max_packet_size.max(1)) * ep.max_packet_size.max(1);
            let buf = endpoint.allocate(len);
            endpoint.submit(buf);
        }
        Ok(Open {
            endpoint,
            _interface: iface,
        })
    }

    fn lost(&mut self, reason: String) -> SourceError {
        self.open = None;
        self.clock.reset();
        self.carry.clear();
        self.carry_pos = 0;
        SourceError::Disconnected {
            source_name: self.name.clone(),
            reason,
        }
    }

    async fn next_inner(&mut self) -> Result<Option<Sample>, SourceError> {
        loop {
            // Drain frames from what we have.
            loop {
                if let Some(r) = self.frames.next_frame() {
                    return match r {
                        Ok(fs) => {
                            let Some(t) = self.clock.to_host(fs.t_us as f64 * 1e-6, now_secs())
                            else {
                                // Dropped and counted by the mapping.
                                continue;
                            };
                            let mut s = fs.sample;
                            s.set_t_secs(t);
                            Ok(Some(s))
                        }
                        Err(e) => Err(SourceError::Item {
                            source_name: self.name.clone(),
                            index: self.frames.frames() + self.frames.errors() - 1,
                            error: Box::new(e),
                        }),
                    };
                }
                if self.carry_pos >= self.carry.len() {
                    break;
                }
                let n = self.frames.push(&self.carry[self.carry_pos..]);
                self.carry_pos += n;
            }
            if self.open.is_none() {
                match self.connect() {
                    Ok(o) => self.open = Some(o),
                    Err(reason) => return Err(self.lost(reason)),
                }
            }
            let Some(open) = self.open.as_mut() else {
                continue;
            };
            let completion = open.endpoint.next_complete().await;
            if let Err(e) = completion.status {
                return Err(self.lost(format!("bulk transfer: {e}")));
            }
            self.carry.clear();
            self.carry
                .extend_from_slice(&completion.buffer[..completion.actual_len]);
            self.carry_pos = 0;
            let mut buf = completion.buffer;
            buf.clear();
            open.endpoint.submit(buf);
        }
    }
}

impl SampleSource for UsbSource {
    fn next(&mut self) -> impl Future<Output = Result<Option<Sample>, SourceError>> + Send {
        self.next_inner()
    }

    fn clock_stats(&self) -> Option<Arc<SharedClockStats>> {
        Some(self.clock.shared_stats())
    }

    fn describe(&self) -> String {
        format!("USB bulk tracker at {}", self.name)
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    /// A configuration descriptor (USB 2.0 §9.6.3-9.6.6) with a HID
    /// interface 0 (interrupt IN 0x81) and a vendor interface 1 with bulk
    /// OUT 0x02 and bulk IN 0x83, 512-byte packets.
    const CONFIG: [u8; 57] = [
        9, 0x02, 57, 0, 2, 1, 0, 0x80, 50, // configuration
        9, 0x04, 0, 0, 1, 0x03, 0, 0, 0, // interface 0: HID
        9, 0x21, 0x11, 0x01, 0, 1, 0x22, 30, 0, // HID descriptor
        7, 0x05, 0x81, 0x03, 64, 0, 1, // EP 0x81 interrupt IN
        9, 0x04, 1, 0, 2, 0xFF, 0, 0, 0, // interface 1: vendor
        7, 0x05, 0x02, 0x02, 0x00, 0x02, 0, // EP 0x02 bulk OUT
        7, 0x05, 0x83, 0x02, 0x00, 0x02, 0, // EP 0x83 bulk IN
    ];

    #[test]
    fn the_vendor_bulk_in_endpoint_is_found() {
        let c = ConfigurationDescriptor::new(&CONFIG).expect("valid configuration descriptor");
        assert_eq!(
            find_bulk_in(&c, None),
            Some(BulkInEndpoint {
                interface: 1,
                alt_setting: 0,
                address: 0x83,
                max_packet_size: 512
            })
        );
        assert_eq!(find_bulk_in(&c, Some(1)).map(|e| e.address), Some(0x83));
        // Interface 0 has only an interrupt endpoint.
        assert_eq!(find_bulk_in(&c, Some(0)), None);
        assert_eq!(find_bulk_in(&c, Some(7)), None);
    }
}
