//! The guest program of the QEMU stage (`.ci/qemu/run`, `.ci/qemu/init`):
//! feeds known samples into real Linux kernel device paths inside a QEMU
//! guest and reads them back through gazelight's hardware transports.
//!
//! One binary, subcommands (each prints `ok: …` and exits 0, or
//! `error: …` and exits 1):
//!
//! | subcommand | role |
//! | --- | --- |
//! | `feed-uhid` | creates a page-0x12 eye tracker with `/dev/uhid` (`UHID_CREATE2`), answers its feature-report requests, sends Tracking Data reports (`UHID_INPUT2`), one with an out-of-range gaze X |
//! | `probe-uhid` | finds its `/dev/hidrawN`, opens `hid:///dev/hidrawN` (the HID source) and checks the decoded gaze |
//! | `setup-gadgets` | configfs: a CRS LiveTrack HID gadget (`usb_f_hid`) on the first dummy UDC, a CDC-ACM gadget on the second, a FunctionFS gadget (left unbound) on the third |
//! | `feed-gadget-hid` | reads the LiveTrack start command from `/dev/hidg0`, writes LiveTrack packets, reads the stop command |
//! | `probe-gadget-hid` | opens the gadget's host-side `/dev/hidrawN` (usbhid) with the HID source and checks the pupil samples |
//! | `feed-acm` | writes framed samples (one with a corrupt CRC) to `/dev/ttyGS0` |
//! | `probe-acm` | reads `serial:///dev/ttyACM0?format=framed` (cdc-acm) |
//! | `feed-ffs` | writes FunctionFS descriptors to `ep0` of a mounted functionfs, binds the gadget, writes framed samples (one with confidence out of range) to the bulk-IN `ep1` |
//! | `probe-usb` | reads `usb://1209:0001` through nusb/usbfs |
//!
//! Probe and feeder meet through files: the probe creates
//! `/tmp/ready.<scenario>` once its source is open (the feeder starts
//! sending only then, so the reports arrive at the reader one by one) and
//! `/tmp/done.<scenario>` after it closed the source.
//!
//! Expected values are computed, not recorded: page-0x12 gaze points lie on
//! quarter fractions of the calibrated screen (so µm → normalised is exact),
//! LiveTrack sizes are `raw / scaling factor` per the CRS driver, framed
//! samples are f32 values that round-trip exactly. Device timestamps are
//! spaced [`DEVICE_STEP_US`] apart while reports are sent [`SEND_GAP`]
//! apart; the source's clock holds its first offset for the first stamps,
//! so a correctly decoded timestamp shows up as a host-time gap equal to
//! the device gap (see `check_times`).

use std::fs::{self, File, OpenOptions};
use std::io::{Read, Write};
use std::path::{Path, PathBuf};
use std::process::ExitCode;
use std::sync::mpsc;
use std::time::{Duration, Instant};

use gazelight_tracker::sample::{GazeEyes, GazeSample, PupilSample, PupilUnit, Sample};
use gazelight_tracker::source::{SampleSource, SourceError};
use gazelight_tracker::transport::framing::{self, FrameError};
use gazelight_tracker::transport::hid::{livetrack, testdata};
use gazelight_tracker::transport::{self, AnySource, SourceUri};

/// How long a probe waits for its device and its samples.
const PROBE_DEADLINE: Duration = Duration::from_secs(25);
/// How long a feeder waits for the probe.
const FEED_DEADLINE: Duration = Duration::from_secs(30);
/// Gap between two reports sent by a feeder.
const SEND_GAP: Duration = Duration::from_millis(40);
/// Gap between the device timestamps of two consecutive reports, µs
/// (well below [`SEND_GAP`]).
const DEVICE_STEP_US: u64 = 2_000;

// ---------------------------------------------------------------- page 0x12

/// The page-0x12 eye tracker of `tests/hid_reports.rs`.
const EYE_TRACKER_DESCRIPTOR: &[u8] = testdata::PAGE12_EYE_TRACKER;
/// Calibrated screen of the uhid tracker, µm.
const SCREEN_UM: [i32; 2] = testdata::SCREEN_UM;
/// HID_NAME of the uhid tracker.
const UHID_NAME: &str = "gazelight uhid page-0x12 tracker";
/// Vendor/product id given to the uhid tracker (pid.codes' 0x1209 space).
const UHID_VID_PID: (u32, u32) = (0x1209, 0x0002);
/// Gaze points as fractions of the screen (quarters: exact in µm); `None`
/// is the report whose gaze X is i32::MIN, below the logical minimum
/// −2^31 + 1 (out of range: no sample, one invalid report).
const UHID_GAZE: [Option<[f64; 2]>; 7] = [
    Some([0.25, 0.75]),
    Some([0.5, 0.5]),
    Some([0.75, 0.25]),
    None,
    Some([0.0, 1.0]),
    Some([1.0, 0.0]),
    Some([0.5, 0.25]),
];
/// Device timestamp of the first report, µs.
const UHID_T0_US: u64 = 1_000_000;

fn page12_tracking_report(t_us: u64, gaze: Option<[f64; 2]>) -> Vec<u8> {
    let (x, y) = match gaze {
        Some([u, v]) => (
            (u * SCREEN_UM[0] as f64) as i32,
            (v * SCREEN_UM[1] as f64) as i32,
        ),
        None => (i32::MIN, 149_450),
    };
    let mut r = vec![0x10];
    r.extend_from_slice(&t_us.to_le_bytes());
    // Gaze X/Y, then eyes 32 mm either side of the centre line, 650 mm out.
    for v in [x, y, -32_000, 10_000, 650_000, 32_000, 10_000, 650_000] {
        r.extend_from_slice(&v.to_le_bytes());
    }
    r
}

// -------------------------------------------------------------------- uhid

/// `enum uhid_event_type` (include/uapi/linux/uhid.h).
const UHID_DESTROY: u32 = 1;
const UHID_START: u32 = 2;
const UHID_OPEN: u32 = 4;
const UHID_CLOSE: u32 = 5;
const UHID_GET_REPORT: u32 = 9;
const UHID_GET_REPORT_REPLY: u32 = 10;
const UHID_CREATE2: u32 = 11;
const UHID_INPUT2: u32 = 12;
const UHID_SET_REPORT: u32 = 13;
const UHID_SET_REPORT_REPLY: u32 = 14;
/// `enum uhid_report_type`: UHID_FEATURE_REPORT.
const UHID_FEATURE_REPORT: u8 = 0;
/// `sizeof(struct uhid_event)`: u32 type + the largest member,
/// `struct uhid_create2_req` (128 + 64 + 64 + 2 + 2 + 4·4 + 4096).
const UHID_EVENT_SIZE: usize = 4 + 128 + 64 + 64 + 2 + 2 + 16 + 4096;
/// `BUS_USB` (include/uapi/linux/input.h).
const BUS_USB: u16 = 0x03;
/// errno EIO, returned for feature reports the tracker does not have.
const EIO: u16 = 5;

fn uhid_create2() -> Vec<u8> {
    let mut ev = vec![0u8; UHID_EVENT_SIZE];
    ev[0..4].copy_from_slice(&UHID_CREATE2.to_ne_bytes());
    let name = UHID_NAME.as_bytes();
    ev[4..4 + name.len()].copy_from_slice(name);
    let o = 4 + 128 + 64 + 64;
    ev[o..o + 2].copy_from_slice(&(EYE_TRACKER_DESCRIPTOR.len() as u16).to_ne_bytes());
    ev[o + 2..o + 4].copy_from_slice(&BUS_USB.to_ne_bytes());
    ev[o + 4..o + 8].copy_from_slice(&UHID_VID_PID.0.to_ne_bytes());
    ev[o + 8..o + 12].copy_from_slice(&UHID_VID_PID.1.to_ne_bytes());
    let d = o + 20;
    ev[d..d + EYE_TRACKER_DESCRIPTOR.len()].copy_from_slice(EYE_TRACKER_DESCRIPTOR);
    ev
}

fn uhid_input2(report: &[u8]) -> Vec<u8> {
    let mut ev = Vec::with_capacity(6 + report.len());
    ev.extend_from_slice(&UHID_INPUT2.to_ne_bytes());
    ev.extend_from_slice(&(report.len() as u16).to_ne_bytes());
    ev.extend_from_slice(report);
    ev
}

/// What the uhid event thread saw.
#[derive(Debug, Default)]
struct UhidLog {
    started: bool,
    opened: bool,
    closed: bool,
    config_reads: u32,
    set_reports: Vec<Vec<u8>>,
}

/// Serve uhid events: answer GET_REPORT for the Configuration feature
/// report (0x12, the calibrated screen size) and SET_REPORT; report each
/// event on `tx`.
fn uhid_events(mut dev: File, tx: mpsc::Sender<Result<(u32, Vec<u8>), String>>) {
    let mut buf = vec![0u8; UHID_EVENT_SIZE];
    loop {
        let n = match dev.read(&mut buf) {
            Ok(n) => n,
            Err(e) => {
                let _ = tx.send(Err(format!("reading /dev/uhid: {e}")));
                return;
            }
        };
        if n < 4 {
            let _ = tx.send(Err(format!("short uhid event ({n} bytes)")));
            return;
        }
        let ty = u32::from_ne_bytes([buf[0], buf[1], buf[2], buf[3]]);
        let reply = match ty {
            UHID_GET_REPORT => {
                let id = &buf[4..8];
                let (rnum, rtype) = (buf[8], buf[9]);
                let mut r = Vec::with_capacity(32);
                r.extend_from_slice(&UHID_GET_REPORT_REPLY.to_ne_bytes());
                r.extend_from_slice(id);
                if rnum == 0x12 && rtype == UHID_FEATURE_REPORT {
                    let mut data = vec![0x12];
                    data.extend_from_slice(&SCREEN_UM[0].to_le_bytes());
                    data.extend_from_slice(&SCREEN_UM[1].to_le_bytes());
                    r.extend_from_slice(&0u16.to_ne_bytes());
                    r.extend_from_slice(&(data.len() as u16).to_ne_bytes());
                    r.extend_from_slice(&data);
                } else {
                    r.extend_from_slice(&EIO.to_ne_bytes());
                    r.extend_from_slice(&0u16.to_ne_bytes());
                }
                Some((r, vec![rnum, rtype]))
            }
            UHID_SET_REPORT => {
                let id = &buf[4..8];
                let size = u16::from_ne_bytes([buf[10], buf[11]]) as usize;
                let data = buf[12..12 + size.min(n.saturating_sub(12))].to_vec();
                let mut r = Vec::with_capacity(10);
                r.extend_from_slice(&UHID_SET_REPORT_REPLY.to_ne_bytes());
                r.extend_from_slice(id);
                r.extend_from_slice(&0u16.to_ne_bytes());
                Some((r, data))
            }
            _ => None,
        };
        let payload = match reply {
            Some((r, payload)) => {
                if let Err(e) = dev.write_all(&r) {
                    let _ = tx.send(Err(format!("replying to uhid event {ty}: {e}")));
                    return;
                }
                payload
            }
            None => Vec::new(),
        };
        if tx.send(Ok((ty, payload))).is_err() {
            return;
        }
    }
}

fn drain_uhid(
    rx: &mpsc::Receiver<Result<(u32, Vec<u8>), String>>,
    log: &mut UhidLog,
    wait: Duration,
) -> Result<(), String> {
    let until = Instant::now() + wait;
    loop {
        let left = until.saturating_duration_since(Instant::now());
        let ev = match rx.recv_timeout(left) {
            Ok(ev) => ev?,
            Err(mpsc::RecvTimeoutError::Timeout) => return Ok(()),
            Err(mpsc::RecvTimeoutError::Disconnected) => {
                return Err("uhid event thread ended".to_owned());
            }
        };
        match ev {
            (UHID_START, _) => log.started = true,
            (UHID_OPEN, _) => log.opened = true,
            (UHID_CLOSE, _) => log.closed = true,
            (UHID_GET_REPORT, p) if p == [0x12, UHID_FEATURE_REPORT] => log.config_reads += 1,
            (UHID_SET_REPORT, data) => log.set_reports.push(data),
            _ => {}
        }
    }
}

fn feed_uhid() -> Result<String, String> {
    let dev = OpenOptions::new()
        .read(true)
        .write(true)
        .open("/dev/uhid")
        .map_err(|e| format!("opening /dev/uhid: {e}"))?;
    let mut writer = dev
        .try_clone()
        .map_err(|e| format!("duplicating the /dev/uhid handle: {e}"))?;
    writer
        .write_all(&uhid_create2())
        .map_err(|e| format!("UHID_CREATE2: {e}"))?;
    let (tx, rx) = mpsc::channel();
    std::thread::spawn(move || uhid_events(dev, tx));
    let mut log = UhidLog::default();
    let deadline = Instant::now() + FEED_DEADLINE;
    wait_for_file(&ready_path("uhid"), deadline, || {
        drain_uhid(&rx, &mut log, Duration::from_millis(20))
    })?;
    for (i, gaze) in UHID_GAZE.iter().enumerate() {
        std::thread::sleep(SEND_GAP);
        let report = page12_tracking_report(UHID_T0_US + i as u64 * DEVICE_STEP_US, *gaze);
        writer
            .write_all(&uhid_input2(&report))
            .map_err(|e| format!("UHID_INPUT2 report {i}: {e}"))?;
    }
    wait_for_file(&done_path("uhid"), deadline, || {
        drain_uhid(&rx, &mut log, Duration::from_millis(20))
    })?;
    drain_uhid(&rx, &mut log, Duration::from_millis(200))?;
    writer
        .write_all(&UHID_DESTROY.to_ne_bytes())
        .map_err(|e| format!("UHID_DESTROY: {e}"))?;
    if !(log.started && log.opened && log.closed) {
        return Err(format!(
            "the kernel did not start/open/close the device as expected: {log:?}"
        ));
    }
    if log.config_reads == 0 {
        return Err("the Configuration feature report (0x12) was never requested".to_owned());
    }
    // Device Mode Request: gaze point (1) | eye position (2).
    if !log.set_reports.iter().any(|r| r == &[0x14, 0x03]) {
        return Err(format!(
            "no Control report [0x14, 0x03] (Device Mode Request) arrived; SET_REPORTs: {:?}",
            log.set_reports
        ));
    }
    Ok(format!(
        "uhid tracker served {} Configuration read(s), Control {:?}, {} reports sent",
        log.config_reads,
        log.set_reports,
        UHID_GAZE.len()
    ))
}

async fn probe_uhid() -> Result<String, String> {
    let deadline = Instant::now() + PROBE_DEADLINE;
    let node = find_hidraw(deadline, &format!("HID_NAME={UHID_NAME}"))?;
    let uri = SourceUri::parse(&format!("hid://{}", node.display())).map_err(|e| e.to_string())?;
    let mut src = open_until(&uri, deadline).await?;
    touch(&ready_path("uhid"))?;
    let want = UHID_GAZE.iter().flatten().count();
    let (items, errors) = collect(&mut src, want, 0, deadline).await;
    let stats = match &src {
        AnySource::Hid(h) => (h.stats().reports(), h.stats().invalid_reports()),
        _ => (0, 0),
    };
    let desc = src.describe();
    drop(src);
    touch(&done_path("uhid"))?;
    if let Some(e) = errors.first() {
        return Err(format!("{uri}: unexpected error: {e}"));
    }
    let got: Vec<GazeSample> = items
        .iter()
        .filter_map(|s| match s {
            Sample::Gaze(g) => Some(*g),
            _ => None,
        })
        .collect();
    if got.len() != want || items.len() != want {
        return Err(format!(
            "{uri}: expected {want} gaze samples, got {} items: {items:?}",
            items.len()
        ));
    }
    let mut device_t = Vec::new();
    for (k, (i, g)) in UHID_GAZE
        .iter()
        .enumerate()
        .filter_map(|(i, g)| g.map(|g| (i, g)))
        .enumerate()
    {
        let s = got[k];
        let want_uv = [g[0] as f32, g[1] as f32];
        if (s.gaze_uv[0] - want_uv[0]).abs() > 1e-6
            || (s.gaze_uv[1] - want_uv[1]).abs() > 1e-6
            || s.confidence != 1.0
            || s.eyes != GazeEyes::Binocular
        {
            return Err(format!(
                "{uri}: sample {k}: expected gaze {want_uv:?} (binocular, confidence 1), got {s:?}"
            ));
        }
        device_t.push((UHID_T0_US + i as u64 * DEVICE_STEP_US) as f64 * 1e-6);
    }
    if stats != (UHID_GAZE.len() as u64, 1) {
        return Err(format!(
            "{uri}: expected {} reports with 1 invalid (gaze X = i32::MIN), stats say {stats:?}",
            UHID_GAZE.len()
        ));
    }
    let host_t: Vec<f64> = got.iter().map(|g| g.t_secs).collect();
    let gaps = check_times(&host_t, &device_t).map_err(|e| format!("{uri}: {e}"))?;
    Ok(format!(
        "{desc}: {want} gaze samples match, the out-of-range report was rejected \
         (reports {}, invalid {}), {gaps}",
        stats.0, stats.1
    ))
}

// ------------------------------------------------------------ USB gadgets

const CONFIGFS_GADGETS: &str = "/sys/kernel/config/usb_gadget";
/// Vendor/product of the CDC-ACM gadget (Linux Foundation "Multifunction
/// Composite Gadget", as in the kernel's configfs examples).
const ACM_VID_PID: (u16, u16) = (0x1d6b, 0x0104);
/// Vendor/product of the FunctionFS gadget (pid.codes' 0x1209 space).
const FFS_VID_PID: (u16, u16) = (0x1209, 0x0001);
/// Name of the functionfs instance (`mount -t functionfs gl …`).
const FFS_INSTANCE: &str = "gl";
/// Where `.ci/qemu/init` mounts it.
const FFS_MOUNT: &str = "/dev/ffs-gl";

/// The LiveTrack-style vendor descriptor of `tests/hid_reports.rs`.
const LIVETRACK_DESCRIPTOR: &[u8] = testdata::LIVETRACK_STYLE;

fn write_attr(path: &Path, value: &[u8]) -> Result<(), String> {
    fs::write(path, value).map_err(|e| format!("writing {}: {e}", path.display()))
}

fn mkdir(path: &Path) -> Result<(), String> {
    fs::create_dir_all(path).map_err(|e| format!("mkdir {}: {e}", path.display()))
}

/// Create gadget `name` with one configuration holding `function`
/// (`hid.usb0` …), with `attrs` written into the function directory.
fn make_gadget(
    name: &str,
    vid_pid: (u16, u16),
    product: &str,
    function: &str,
    attrs: &[(&str, &[u8])],
) -> Result<PathBuf, String> {
    let g = Path::new(CONFIGFS_GADGETS).join(name);
    mkdir(&g)?;
    write_attr(
        &g.join("idVendor"),
        format!("{:#06x}", vid_pid.0).as_bytes(),
    )?;
    write_attr(
        &g.join("idProduct"),
        format!("{:#06x}", vid_pid.1).as_bytes(),
    )?;
    write_attr(&g.join("bcdUSB"), b"0x0200")?;
    let s = g.join("strings/0x409");
    mkdir(&s)?;
    write_attr(&s.join("manufacturer"), b"gazelight CI")?;
    write_attr(&s.join("product"), product.as_bytes())?;
    write_attr(&s.join("serialnumber"), name.as_bytes())?;
    let c = g.join("configs/c.1");
    mkdir(&c.join("strings/0x409"))?;
    write_attr(&c.join("strings/0x409/configuration"), product.as_bytes())?;
    write_attr(&c.join("MaxPower"), b"100")?;
    let f = g.join("functions").join(function);
    mkdir(&f)?;
    for (k, v) in attrs {
        write_attr(&f.join(k), v)?;
    }
    std::os::unix::fs::symlink(&f, c.join(function))
        .map_err(|e| format!("linking {} into {}: {e}", f.display(), c.display()))?;
    Ok(g)
}

fn udcs() -> Result<Vec<String>, String> {
    let mut v: Vec<String> = fs::read_dir("/sys/class/udc")
        .map_err(|e| format!("listing /sys/class/udc (dummy_hcd loaded?): {e}"))?
        .filter_map(|e| e.ok().map(|e| e.file_name().to_string_lossy().into_owned()))
        .collect();
    v.sort();
    Ok(v)
}

fn setup_gadgets() -> Result<String, String> {
    let u = udcs()?;
    if u.len() < 3 {
        return Err(format!(
            "need 3 UDCs (dummy_hcd num=3), found {u:?} in /sys/class/udc"
        ));
    }
    let hid = make_gadget(
        "g_hid",
        (livetrack::VENDOR_ID, livetrack::PRODUCT_ID),
        "LiveTrack-style HID gadget",
        "hid.usb0",
        &[
            ("protocol", b"0"),
            ("subclass", b"0"),
            ("report_length", b"64"),
            ("report_desc", LIVETRACK_DESCRIPTOR),
        ],
    )?;
    write_attr(&hid.join("UDC"), u[0].as_bytes())?;
    let acm = make_gadget(
        "g_acm",
        ACM_VID_PID,
        "gazelight framed serial",
        "acm.usb0",
        &[],
    )?;
    write_attr(&acm.join("UDC"), u[1].as_bytes())?;
    make_gadget(
        "g_ffs",
        FFS_VID_PID,
        "gazelight bulk tracker",
        &format!("ffs.{FFS_INSTANCE}"),
        &[],
    )?;
    Ok(format!(
        "g_hid on {}, g_acm on {}, g_ffs ready for {}",
        u[0], u[1], u[2]
    ))
}

// ---------------------------------------------------- LiveTrack HID gadget

/// Packets sent by the gadget: `(flags, raw width, raw height)` of the two
/// halves, scaling factor 16. Flags 0b01_0111: one glint, tracked;
/// 0b10_1111: two glints, tracked; 0b01_0001: tracking on, no pupil.
const LT_SCALE: u16 = 16;
const LT_PACKETS: [[(u16, i16, i16); 2]; 5] = [
    [(0b01_0111, 900, 864), (0b10_1111, 800, 820)],
    [(0b01_0111, 916, 864), (0b10_1111, 800, 836)],
    [(0b01_0111, 932, 864), (0b01_0001, 0, 0)],
    [(0b01_0111, 948, 864), (0b10_1111, 800, 852)],
    [(0b01_0111, 964, 864), (0b10_1111, 800, 868)],
];

/// A raw LiveTrack packet laid out as the CRS driver reads it.
fn livetrack_packet(k: usize) -> [u8; livetrack::REPORT_LEN] {
    let mut r = [0u8; livetrack::REPORT_LEN];
    r[0] = livetrack::PACKET_RAW;
    r[8..16].copy_from_slice(&(5_000 + k as u64).to_le_bytes());
    for (half, (flags_at, scale_at)) in [(16, 22), (40, 46)].into_iter().enumerate() {
        let (flags, w, h) = LT_PACKETS[k][half];
        r[flags_at..flags_at + 2].copy_from_slice(&flags.to_le_bytes());
        r[scale_at..scale_at + 2].copy_from_slice(&LT_SCALE.to_le_bytes());
        // Pupil W, H, then centre X, Y (320, 240 px).
        for (i, v) in [w, h, 320 * 16, 240 * 16].into_iter().enumerate() {
            let at = scale_at + 2 + 2 * i;
            r[at..at + 2].copy_from_slice(&v.to_le_bytes());
        }
    }
    r
}

/// `(diameter px, confidence)` of each half, per the CRS driver: the larger
/// of width and height over the scaling factor; untracked → (0, 0).
fn livetrack_expected() -> Vec<(f32, f32)> {
    LT_PACKETS
        .iter()
        .flatten()
        .map(|&(flags, w, h)| {
            if livetrack::tracked(flags) {
                ((w.max(h) as f64 / LT_SCALE as f64) as f32, 1.0)
            } else {
                (0.0, 0.0)
            }
        })
        .collect()
}

fn feed_gadget_hid() -> Result<String, String> {
    let deadline = Instant::now() + FEED_DEADLINE;
    let path = "/dev/hidg0";
    let mut dev = wait_open(Path::new(path), deadline)?;
    let mut reader = dev
        .try_clone()
        .map_err(|e| format!("duplicating the {path} handle: {e}"))?;
    let (tx, rx) = mpsc::channel::<Result<Vec<u8>, String>>();
    std::thread::spawn(move || {
        let mut buf = [0u8; livetrack::REPORT_LEN];
        loop {
            let r = reader.read(&mut buf).map(|n| buf[..n].to_vec());
            let stop = r.is_err();
            if tx
                .send(r.map_err(|e| format!("reading {path}: {e}")))
                .is_err()
                || stop
            {
                return;
            }
        }
    });
    let left = deadline.saturating_duration_since(Instant::now());
    let start = rx
        .recv_timeout(left)
        .map_err(|_| "no output report (the LiveTrack start command) arrived".to_owned())??;
    if start.first() != Some(&livetrack::CMD_START_RAW) || start.len() != livetrack::REPORT_LEN {
        return Err(format!(
            "first output report is not the 64-byte raw start command {}: {start:?}",
            livetrack::CMD_START_RAW
        ));
    }
    wait_for_file(&ready_path("gadget_hid"), deadline, || {
        std::thread::sleep(Duration::from_millis(20));
        Ok(())
    })?;
    for k in 0..LT_PACKETS.len() {
        std::thread::sleep(SEND_GAP);
        dev.write_all(&livetrack_packet(k))
            .map_err(|e| format!("writing packet {k} to {path}: {e}"))?;
    }
    let left = deadline.saturating_duration_since(Instant::now());
    let stop = rx.recv_timeout(left).map_err(|_| {
        "no second output report (the LiveTrack stop command) arrived after the source closed"
            .to_owned()
    })??;
    if stop.first() != Some(&livetrack::CMD_STOP) {
        return Err(format!(
            "second output report is not the stop command {}: {stop:?}",
            livetrack::CMD_STOP
        ));
    }
    Ok(format!(
        "start command {} received, {} packets sent, stop command {} received",
        livetrack::CMD_START_RAW,
        LT_PACKETS.len(),
        livetrack::CMD_STOP
    ))
}

async fn probe_gadget_hid() -> Result<String, String> {
    let deadline = Instant::now() + PROBE_DEADLINE;
    let id = format!(
        "HID_ID=0003:{:08X}:{:08X}",
        livetrack::VENDOR_ID,
        livetrack::PRODUCT_ID
    );
    let node = find_hidraw(deadline, &id)?;
    let uri = SourceUri::parse(&format!("hid://{}", node.display())).map_err(|e| e.to_string())?;
    let mut src = open_until(&uri, deadline).await?;
    touch(&ready_path("gadget_hid"))?;
    let want = livetrack_expected();
    let (items, errors) = collect(&mut src, want.len(), 0, deadline).await;
    let stats = match &src {
        AnySource::Hid(h) => (h.stats().reports(), h.stats().invalid_reports()),
        _ => (0, 0),
    };
    let desc = src.describe();
    drop(src);
    touch(&done_path("gadget_hid"))?;
    if let Some(e) = errors.first() {
        return Err(format!("{uri}: unexpected error: {e}"));
    }
    if items.len() != want.len() {
        return Err(format!(
            "{uri}: expected {} pupil samples, got {}: {items:?}",
            want.len(),
            items.len()
        ));
    }
    for (k, (s, &(d, c))) in items.iter().zip(&want).enumerate() {
        let ok = matches!(s, Sample::Pupil(p)
            if p.diameter_raw == d && p.confidence == c && p.unit == PupilUnit::Px && p.eye == 0);
        if !ok {
            return Err(format!(
                "{uri}: sample {k}: expected diameter {d} px, confidence {c}, eye 0; got {s:?}"
            ));
        }
    }
    let invalid = want.iter().filter(|w| w.1 == 0.0).count() as u64;
    if stats != (LT_PACKETS.len() as u64, invalid) {
        return Err(format!(
            "{uri}: expected {} reports, {invalid} invalid half; stats say {stats:?}",
            LT_PACKETS.len()
        ));
    }
    Ok(format!(
        "{desc}: {} pupil samples from {} packets match (diameters {:?} px), untracked half \
         rejected",
        want.len(),
        LT_PACKETS.len(),
        want.iter().map(|w| w.0).collect::<Vec<_>>()
    ))
}

// ------------------------------------------------------ framed byte streams

/// How the bad frame of a framed stream is broken.
#[derive(Clone, Copy, PartialEq)]
enum BadFrame {
    /// CRC bytes inverted.
    Crc,
    /// A gaze frame with confidence 1.5 (outside 0..=1), CRC intact.
    Confidence,
}

/// Index of the bad frame in [`framed_samples`].
const BAD_FRAME: usize = 4;
/// Device timestamp of the first frame, µs.
const FRAMED_T0_US: u64 = 2_000_000;

fn gaze(u: f32, v: f32, confidence: f32) -> Sample {
    Sample::Gaze(GazeSample {
        t_secs: 0.0,
        gaze_uv: [u, v],
        confidence,
        eyes: GazeEyes::Binocular,
    })
}

fn pupil(eye: u8, diameter: f32, unit: PupilUnit, confidence: f32) -> Sample {
    Sample::Pupil(PupilSample {
        t_secs: 0.0,
        eye,
        diameter_raw: diameter,
        unit,
        diameter_mm: None,
        confidence,
        norm_pos: [f32::NAN, f32::NAN],
        method: gazelight_tracker::sample::DetectorMethod::Other,
    })
}

/// The stream's samples (the bad one at [`BAD_FRAME`]).
fn framed_samples(bad: BadFrame) -> Vec<Sample> {
    vec![
        gaze(0.25, 0.75, 0.875),
        pupil(0, 3.5, PupilUnit::Mm, 0.9375),
        pupil(1, 3.75, PupilUnit::Mm, 0.875),
        gaze(0.5, 0.125, 1.0),
        match bad {
            BadFrame::Crc => gaze(0.375, 0.625, 1.0),
            BadFrame::Confidence => gaze(0.375, 0.625, 1.5),
        },
        gaze(0.625, 0.375, 0.75),
        pupil(0, 41.5, PupilUnit::Px, 1.0),
        gaze(0.875, 0.5, 0.5),
    ]
}

/// The frames, one per sample, and the stream offset of the bad one.
fn framed_stream(bad: BadFrame) -> (Vec<Vec<u8>>, u64) {
    let mut offset = 0u64;
    let mut bad_offset = 0;
    let frames = framed_samples(bad)
        .iter()
        .enumerate()
        .map(|(i, s)| {
            let mut f = Vec::with_capacity(framing::MAX_FRAME_LEN);
            framing::encode(s, FRAMED_T0_US + i as u64 * DEVICE_STEP_US, &mut f);
            if i == BAD_FRAME {
                bad_offset = offset;
                if bad == BadFrame::Crc {
                    let n = f.len();
                    f[n - 2] ^= 0xFF;
                    f[n - 1] ^= 0xFF;
                }
            }
            offset += f.len() as u64;
            f
        })
        .collect();
    (frames, bad_offset)
}

/// Check a framed stream read back: the good samples in order with their
/// values, one item error of the expected kind at the bad frame's offset.
fn check_framed(
    uri: &SourceUri,
    bad: BadFrame,
    items: &[Sample],
    errors: &[SourceError],
) -> Result<String, String> {
    let (_, bad_offset) = framed_stream(bad);
    let sent = framed_samples(bad);
    let want: Vec<(usize, &Sample)> = sent
        .iter()
        .enumerate()
        .filter(|(i, _)| *i != BAD_FRAME)
        .collect();
    if items.len() != want.len() || errors.len() != 1 {
        return Err(format!(
            "{uri}: expected {} samples and 1 error, got {} samples {items:?} and errors {:?}",
            want.len(),
            items.len(),
            errors.iter().map(|e| e.to_string()).collect::<Vec<_>>()
        ));
    }
    let mut device_t = Vec::new();
    for (k, (got, (i, sent))) in items.iter().zip(&want).enumerate() {
        let same = match (got, sent) {
            (Sample::Gaze(g), Sample::Gaze(s)) => {
                g.gaze_uv == s.gaze_uv && g.confidence == s.confidence && g.eyes == s.eyes
            }
            (Sample::Pupil(g), Sample::Pupil(s)) => {
                g.eye == s.eye
                    && g.diameter_raw == s.diameter_raw
                    && g.unit == s.unit
                    && g.confidence == s.confidence
                    && g.diameter_mm == (s.unit == PupilUnit::Mm).then_some(s.diameter_raw)
            }
            _ => false,
        };
        if !same {
            return Err(format!(
                "{uri}: sample {k} (frame {i}): sent {sent:?}, got {got:?}"
            ));
        }
        device_t.push((FRAMED_T0_US + *i as u64 * DEVICE_STEP_US) as f64 * 1e-6);
    }
    let e = &errors[0];
    let frame_error = match e {
        SourceError::Item { error, .. } => error.downcast_ref::<FrameError>(),
        _ => None,
    };
    let ok = match (bad, frame_error) {
        (BadFrame::Crc, Some(FrameError::Crc { offset, .. })) => *offset == bad_offset,
        (BadFrame::Confidence, Some(FrameError::Field { offset, field, .. })) => {
            *offset == bad_offset && *field == "confidence"
        }
        _ => false,
    };
    if !ok {
        return Err(format!(
            "{uri}: expected a {} error at stream byte {bad_offset}, got: {e}",
            match bad {
                BadFrame::Crc => "CRC",
                BadFrame::Confidence => "confidence field",
            }
        ));
    }
    let host_t: Vec<f64> = items.iter().map(Sample::t_secs).collect();
    let gaps = check_times(&host_t, &device_t).map_err(|e| format!("{uri}: {e}"))?;
    Ok(format!(
        "{} samples match, bad frame rejected: \"{e}\"; {gaps}",
        want.len()
    ))
}

// ---------------------------------------------------------------- CDC-ACM

fn feed_acm() -> Result<String, String> {
    let deadline = Instant::now() + FEED_DEADLINE;
    let path = "/dev/ttyGS0";
    while !Path::new(path).exists() {
        if Instant::now() > deadline {
            return Err(format!("{path} did not appear"));
        }
        std::thread::sleep(Duration::from_millis(20));
    }
    // serialport puts the line in raw mode (no ONLCR/echo on binary data).
    let mut port = serialport::new(path, 115_200)
        .timeout(Duration::from_secs(5))
        .open_native()
        .map_err(|e| format!("opening {path}: {e}"))?;
    wait_for_file(&ready_path("acm"), deadline, || {
        std::thread::sleep(Duration::from_millis(20));
        Ok(())
    })?;
    let (frames, bad_offset) = framed_stream(BadFrame::Crc);
    for (i, f) in frames.iter().enumerate() {
        std::thread::sleep(SEND_GAP);
        port.write_all(f)
            .map_err(|e| format!("writing frame {i} to {path}: {e}"))?;
    }
    port.flush().map_err(|e| format!("flushing {path}: {e}"))?;
    wait_for_file(&done_path("acm"), deadline, || {
        std::thread::sleep(Duration::from_millis(20));
        Ok(())
    })?;
    Ok(format!(
        "{} frames written to {path} (CRC of the frame at byte {bad_offset} inverted)",
        frames.len()
    ))
}

async fn probe_acm() -> Result<String, String> {
    let deadline = Instant::now() + PROBE_DEADLINE;
    let uri = SourceUri::parse("serial:///dev/ttyACM0?format=framed").map_err(|e| e.to_string())?;
    let mut src = open_until(&uri, deadline).await?;
    touch(&ready_path("acm"))?;
    let want = framed_samples(BadFrame::Crc).len() - 1;
    let (items, errors) = collect(&mut src, want, 1, deadline).await;
    let desc = src.describe();
    drop(src);
    touch(&done_path("acm"))?;
    let msg = check_framed(&uri, BadFrame::Crc, &items, &errors)?;
    Ok(format!("{desc}: {msg}"))
}

// ------------------------------------------------------------- FunctionFS

/// FunctionFS descriptor blob (include/uapi/linux/usb/functionfs.h,
/// FUNCTIONFS_DESCRIPTORS_MAGIC_V2 with full- and high-speed sets): one
/// vendor-specific interface (class 0xFF) with one bulk-IN endpoint
/// (USB 2.0 §9.6.5, §9.6.6; 64-byte packets full speed, 512 high speed).
fn ffs_descriptors() -> Vec<u8> {
    const MAGIC_V2: u32 = 3;
    const HAS_FS_DESC: u32 = 1;
    const HAS_HS_DESC: u32 = 2;
    let interface = [9, 0x04, 0, 0, 1, 0xFF, 0, 0, 1];
    let ep_fs = [7, 0x05, 0x81, 0x02, 64, 0, 0];
    let ep_hs = [7, 0x05, 0x81, 0x02, 0x00, 0x02, 0];
    let mut body = Vec::new();
    body.extend_from_slice(&HAS_FS_DESC.wrapping_add(HAS_HS_DESC).to_le_bytes());
    body.extend_from_slice(&2u32.to_le_bytes()); // fs_count
    body.extend_from_slice(&2u32.to_le_bytes()); // hs_count
    body.extend_from_slice(&interface);
    body.extend_from_slice(&ep_fs);
    body.extend_from_slice(&interface);
    body.extend_from_slice(&ep_hs);
    let mut blob = Vec::new();
    blob.extend_from_slice(&MAGIC_V2.to_le_bytes());
    blob.extend_from_slice(&(8 + body.len() as u32).to_le_bytes());
    blob.extend_from_slice(&body);
    blob
}

/// FunctionFS strings blob (FUNCTIONFS_STRINGS_MAGIC): one string, US
/// English.
fn ffs_strings() -> Vec<u8> {
    const MAGIC: u32 = 2;
    let text = b"gazelight bulk samples\0";
    let mut blob = Vec::new();
    blob.extend_from_slice(&MAGIC.to_le_bytes());
    blob.extend_from_slice(&((16 + 2 + text.len()) as u32).to_le_bytes());
    blob.extend_from_slice(&1u32.to_le_bytes()); // str_count
    blob.extend_from_slice(&1u32.to_le_bytes()); // lang_count
    blob.extend_from_slice(&0x0409u16.to_le_bytes());
    blob.extend_from_slice(text);
    blob
}

fn feed_ffs() -> Result<String, String> {
    let deadline = Instant::now() + FEED_DEADLINE;
    let ep0_path = Path::new(FFS_MOUNT).join("ep0");
    let mut ep0 = OpenOptions::new()
        .read(true)
        .write(true)
        .open(&ep0_path)
        .map_err(|e| format!("opening {} (functionfs mounted?): {e}", ep0_path.display()))?;
    ep0.write_all(&ffs_descriptors())
        .map_err(|e| format!("writing descriptors to {}: {e}", ep0_path.display()))?;
    ep0.write_all(&ffs_strings())
        .map_err(|e| format!("writing strings to {}: {e}", ep0_path.display()))?;
    let u = udcs()?;
    let udc = u
        .get(2)
        .ok_or_else(|| format!("no third UDC in {u:?}"))?
        .clone();
    write_attr(
        &Path::new(CONFIGFS_GADGETS).join("g_ffs/UDC"),
        udc.as_bytes(),
    )?;
    let ep1_path = Path::new(FFS_MOUNT).join("ep1");
    let mut ep1 = OpenOptions::new()
        .write(true)
        .open(&ep1_path)
        .map_err(|e| format!("opening {}: {e}", ep1_path.display()))?;
    wait_for_file(&ready_path("usb"), deadline, || {
        std::thread::sleep(Duration::from_millis(20));
        Ok(())
    })?;
    let (frames, bad_offset) = framed_stream(BadFrame::Confidence);
    for (i, f) in frames.iter().enumerate() {
        std::thread::sleep(SEND_GAP);
        // One write is one bulk transfer (short packet ends it).
        ep1.write_all(f)
            .map_err(|e| format!("writing frame {i} to {}: {e}", ep1_path.display()))?;
    }
    wait_for_file(&done_path("usb"), deadline, || {
        std::thread::sleep(Duration::from_millis(20));
        Ok(())
    })?;
    drop(ep1);
    drop(ep0);
    Ok(format!(
        "FunctionFS interface bound to {udc}, {} bulk transfers written (confidence 1.5 in the \
         frame at byte {bad_offset})",
        frames.len()
    ))
}

async fn probe_usb() -> Result<String, String> {
    let deadline = Instant::now() + PROBE_DEADLINE;
    let uri = SourceUri::parse(&format!(
        "usb://{:04x}:{:04x}",
        FFS_VID_PID.0, FFS_VID_PID.1
    ))
    .map_err(|e| e.to_string())?;
    let mut src = open_until(&uri, deadline).await?;
    touch(&ready_path("usb"))?;
    let want = framed_samples(BadFrame::Confidence).len() - 1;
    let (items, errors) = collect(&mut src, want, 1, deadline).await;
    let desc = src.describe();
    drop(src);
    touch(&done_path("usb"))?;
    let msg = check_framed(&uri, BadFrame::Confidence, &items, &errors)?;
    Ok(format!("{desc}: {msg}"))
}

// ------------------------------------------------------------------ shared

fn ready_path(scenario: &str) -> PathBuf {
    PathBuf::from(format!("/tmp/ready.{scenario}"))
}

fn done_path(scenario: &str) -> PathBuf {
    PathBuf::from(format!("/tmp/done.{scenario}"))
}

fn touch(p: &Path) -> Result<(), String> {
    File::create(p)
        .map(|_| ())
        .map_err(|e| format!("creating {}: {e}", p.display()))
}

/// Wait until `p` exists, calling `idle` (which must block briefly) in
/// between.
fn wait_for_file(
    p: &Path,
    deadline: Instant,
    mut idle: impl FnMut() -> Result<(), String>,
) -> Result<(), String> {
    while !p.exists() {
        if Instant::now() > deadline {
            return Err(format!("timed out waiting for the probe ({})", p.display()));
        }
        idle()?;
    }
    Ok(())
}

fn wait_open(p: &Path, deadline: Instant) -> Result<File, String> {
    loop {
        match OpenOptions::new().read(true).write(true).open(p) {
            Ok(f) => return Ok(f),
            Err(e) if Instant::now() > deadline => {
                return Err(format!("opening {}: {e}", p.display()));
            }
            Err(_) => std::thread::sleep(Duration::from_millis(20)),
        }
    }
}

/// The `/dev/hidrawN` whose HID device's uevent has the line `key_value`.
fn find_hidraw(deadline: Instant, key_value: &str) -> Result<PathBuf, String> {
    loop {
        if let Ok(dir) = fs::read_dir("/sys/class/hidraw") {
            for e in dir.flatten() {
                let uevent = e.path().join("device/uevent");
                if let Ok(text) = fs::read_to_string(&uevent)
                    && text.lines().any(|l| l == key_value)
                {
                    let node = Path::new("/dev").join(e.file_name());
                    if node.exists() {
                        return Ok(node);
                    }
                }
            }
        }
        if Instant::now() > deadline {
            return Err(format!("no /dev/hidraw* with {key_value} appeared"));
        }
        std::thread::sleep(Duration::from_millis(20));
    }
}

/// Open `uri`, retrying while the device is still being enumerated.
async fn open_until(uri: &SourceUri, deadline: Instant) -> Result<AnySource, String> {
    loop {
        match transport::open(uri) {
            Ok(s) => return Ok(s),
            Err(e) if Instant::now() > deadline => {
                return Err(format!("opening {uri}: {e}"));
            }
            Err(_) => tokio::time::sleep(Duration::from_millis(50)).await,
        }
    }
}

/// Read until `samples` samples and `errors` item errors have arrived, a
/// non-item error ends the source, or the deadline passes.
async fn collect(
    src: &mut AnySource,
    samples: usize,
    errors: usize,
    deadline: Instant,
) -> (Vec<Sample>, Vec<SourceError>) {
    let mut items = Vec::new();
    let mut errs = Vec::new();
    while items.len() < samples || errs.len() < errors {
        let left = deadline.saturating_duration_since(Instant::now());
        match tokio::time::timeout(left, src.next()).await {
            Err(_) => {
                errs.push(SourceError::Fatal {
                    source_name: src.describe(),
                    reason: format!(
                        "timed out with {} of {samples} samples and {} of {errors} errors",
                        items.len(),
                        errs.len()
                    ),
                });
                break;
            }
            Ok(Ok(Some(s))) => items.push(s),
            Ok(Ok(None)) => break,
            Ok(Err(e @ SourceError::Item { .. })) => errs.push(e),
            Ok(Err(e)) => {
                errs.push(e);
                break;
            }
        }
    }
    (items, errs)
}

/// Host times against device times: they show that the device's own
/// timestamps were decoded and used. The reports arrive [`SEND_GAP`] apart
/// while their stamps step [`DEVICE_STEP_US`]; gazelight's `SourceClock`
/// holds the offset of the least-delayed stamp while it has seen fewer than
/// four, then follows the lower envelope of `arrival − stamp` (the
/// second-smallest of its window), which this slow device clock moves
/// forward. So the first gaps equal their device gaps to the microsecond
/// (arrival gaps would be ~40 ms with emulator jitter) and later ones are
/// larger. Required: every host time finite and none earlier than the one
/// before (the mapping is monotonic), and at least one gap equal to its
/// device gap (a reader stalled by the emulator may see the first reports
/// at once, which moves the offset). The mapping's other guarantees (never
/// later than arrival, never older than 0.25 s on arrival, jumps) are
/// property-tested in `crates/gazelight-eye/tests/clock_mapping.rs`.
fn check_times(host_t: &[f64], device_t: &[f64]) -> Result<String, String> {
    const TOL_SECS: f64 = 1e-6;
    let mut equal = 0;
    for i in 1..host_t.len() {
        let (dh, dd) = (host_t[i] - host_t[i - 1], device_t[i] - device_t[i - 1]);
        if !dh.is_finite() || dh < -TOL_SECS {
            return Err(format!(
                "sample {i}: host time {:.6} s goes back from {:.6} s (device gap {dd:.6} s)",
                host_t[i],
                host_t[i - 1]
            ));
        }
        if (dh - dd).abs() <= TOL_SECS {
            equal += 1;
        }
    }
    if host_t.len() > 1 && equal == 0 {
        return Err(format!(
            "no host gap equals its device gap: the device timestamps were not used \
             (host {host_t:?}, device {device_t:?})"
        ));
    }
    Ok(format!(
        "{equal} of {} time gaps equal the device timestamp gaps",
        host_t.len().saturating_sub(1)
    ))
}

fn run_async(f: impl Future<Output = Result<String, String>>) -> Result<String, String> {
    tokio::runtime::Builder::new_current_thread()
        .enable_all()
        .build()
        .map_err(|e| format!("starting the tokio runtime: {e}"))?
        .block_on(f)
}

fn main() -> ExitCode {
    let cmd = std::env::args().nth(1).unwrap_or_default();
    let result = match cmd.as_str() {
        "feed-uhid" => feed_uhid(),
        "probe-uhid" => run_async(probe_uhid()),
        "setup-gadgets" => setup_gadgets(),
        "feed-gadget-hid" => feed_gadget_hid(),
        "probe-gadget-hid" => run_async(probe_gadget_hid()),
        "feed-acm" => feed_acm(),
        "probe-acm" => run_async(probe_acm()),
        "feed-ffs" => feed_ffs(),
        "probe-usb" => run_async(probe_usb()),
        _ => Err(format!(
            "unknown subcommand `{cmd}` (feed-uhid, probe-uhid, setup-gadgets, \
             feed-gadget-hid, probe-gadget-hid, feed-acm, probe-acm, feed-ffs, probe-usb)"
        )),
    };
    match result {
        Ok(msg) => {
            println!("ok: {msg}");
            ExitCode::SUCCESS
        }
        Err(e) => {
            println!("error: {e}");
            ExitCode::FAILURE
        }
    }
}
