//! `gazelight devices`: list connected HID devices (marking page-0x12 eye
//! trackers and devices with a vendor profile), USB devices (marking those
//! with a vendor-specific interface, usable as `usb://VID:PID`) and serial
//! ports, each with the source URI to use. With no tracker found it says so
//! and what it searched; it exits 0 either way.

use gazelight_tracker::transport::discover::{self, Discovery, HidKind};

/// Arguments of `gazelight devices` (none yet).
#[derive(clap::Args, Debug)]
pub struct DevicesArgs {}

/// Render the listing as text.
pub fn render(d: &Discovery) -> String {
    use std::fmt::Write;
    let mut s = String::new();
    let opt = |o: &Option<String>| o.clone().unwrap_or_default();
    let _ = writeln!(s, "HID devices (hidapi, /sys/class/hidraw):");
    match &d.hid {
        Err(e) => {
            let _ = writeln!(s, "  cannot list: {e}");
        }
        Ok(v) if v.is_empty() => {
            let _ = writeln!(s, "  none");
        }
        Ok(v) => {
            for h in v {
                let mark = match h.kind {
                    HidKind::Page12 => "  [eye tracker, HID page 0x12]",
                    HidKind::LiveTrack => "  [CRS LiveTrack profile]",
                    HidKind::Other => "",
                };
                let _ = writeln!(
                    s,
                    "  {}  {:04x}:{:04x}  {} {}{mark}",
                    h.path,
                    h.vendor_id,
                    h.product_id,
                    opt(&h.manufacturer),
                    opt(&h.product)
                );
                if h.kind != HidKind::Other {
                    let _ = writeln!(s, "      source: hid://{}", h.path);
                }
                if let Some(n) = &h.note {
                    let _ = writeln!(s, "      note: {n}");
                }
            }
        }
    }
    let _ = writeln!(s, "USB devices (nusb, /sys/bus/usb):");
    match &d.usb {
        Err(e) => {
            let _ = writeln!(s, "  cannot list: {e}");
        }
        Ok(v) if v.is_empty() => {
            let _ = writeln!(s, "  none");
        }
        Ok(v) => {
            for u in v {
                let mark = if u.vendor_interfaces.is_empty() {
                    String::new()
                } else {
                    format!(
                        "  [vendor interface {:?}: usb://{:04x}:{:04x}]",
                        u.vendor_interfaces, u.vendor_id, u.product_id
                    )
                };
                let _ = writeln!(
                    s,
                    "  bus {:03} addr {:03}  {:04x}:{:04x}  {} {}{mark}",
                    u.bus,
                    u.address,
                    u.vendor_id,
                    u.product_id,
                    opt(&u.manufacturer),
                    opt(&u.product)
                );
            }
        }
    }
    let _ = writeln!(s, "Serial ports (serialport, /sys/class/tty):");
    match &d.serial {
        Err(e) => {
            let _ = writeln!(s, "  cannot list: {e}");
        }
        Ok(v) if v.is_empty() => {
            let _ = writeln!(s, "  none");
        }
        Ok(v) => {
            for p in v {
                let _ = writeln!(
                    s,
                    "  {}  {}  source: serial://{}?baud=115200&format=gazepoint|csv|framed",
                    p.path, p.kind, p.path
                );
            }
        }
    }
    if !d.has_candidates() {
        let _ = writeln!(
            s,
            "no trackers found (searched HID devices for page 0x12 and known vendor profiles, \
             USB devices for vendor-specific interfaces, serial ports for USB serial lines)"
        );
    }
    s
}

/// Run `gazelight devices`.
pub fn run(_args: DevicesArgs) -> anyhow::Result<()> {
    print!("{}", render(&discover::discover()));
    Ok(())
}
