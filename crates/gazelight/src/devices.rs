//! `gazelight devices`: list connected HID devices (marking page-0x12 eye
//! trackers and devices with a vendor profile), USB devices (marking those
//! with a vendor-specific interface, usable as `usb://VID:PID`) and serial
//! ports, and Pupil Labs Neons announcing themselves on the local network
//! (mDNS), each with the source URI to use. With no tracker found it says so
//! and what it searched; it exits 0 either way.

use std::time::Duration;

use gazelight_tracker::neon::discover::{DiscoverError, FoundNeon};
use gazelight_tracker::transport::discover::{self, Discovery, HidKind};

/// Arguments of `gazelight devices`.
#[derive(clap::Args, Debug)]
pub struct DevicesArgs {
    /// How long to listen for Neons on the local network (mDNS), seconds;
    /// 0 skips it.
    #[arg(long, value_name = "S", default_value_t = 2.0)]
    pub mdns_secs: f64,
}

/// Renders the Neons found by mDNS (`None`: not searched).
pub fn render_neons(found: &Option<Result<Vec<FoundNeon>, DiscoverError>>, secs: f64) -> String {
    use std::fmt::Write;
    let mut s = String::new();
    let Some(found) = found else {
        return s;
    };
    let _ = writeln!(
        s,
        "Neon (mDNS {}, instances \"{}…\", {secs} s):",
        gazelight_tracker::neon::discover::SERVICE_TYPE,
        gazelight_tracker::neon::discover::INSTANCE_PREFIX
    );
    match found {
        Err(e) => {
            let _ = writeln!(s, "  cannot search: {e}");
        }
        Ok(v) if v.is_empty() => {
            let _ = writeln!(s, "  none");
        }
        Ok(v) => {
            for n in v {
                let _ = writeln!(s, "  {}  host {}  source: {}", n.name, n.host, n.uri());
            }
        }
    }
    s
}

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
pub fn run(args: DevicesArgs) -> anyhow::Result<()> {
    let wait = crate::bounds::secs_or_zero("--mdns-secs", args.mdns_secs)?;
    if wait > Duration::from_secs(60) {
        anyhow::bail!("--mdns-secs {}: at most 60 s", args.mdns_secs);
    }
    print!("{}", render(&discover::discover()));
    let neons = (!wait.is_zero()).then(|| gazelight_tracker::neon::discover::discover_neons(wait));
    print!("{}", render_neons(&neons, args.mdns_secs));
    Ok(())
}
