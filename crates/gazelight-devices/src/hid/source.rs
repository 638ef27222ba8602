//! The HID source: hidapi (`linux-native-basic-udev` backend, which talks
//! to `/dev/hidraw*` and sysfs directly and needs no system library).
//!
//! Opening reads the report descriptor and picks the decoder
//! ([`HidProfile`]). Page-0x12 trackers: the Configuration feature report
//! is read for the calibrated screen size (without it gaze cannot be
//! normalised, so opening fails naming the report), and a Control feature
//! report requests gaze-point and eye-position data (best effort: a device
//! that rejects it is still read). LiveTrack: the start command for the
//! chosen mode is written, and the stop command when the source is dropped.
//!
//! Samples: page 0x12 yields one gaze sample per Tracking Data report with
//! a valid gaze point (timestamp mapped onto the host clock); a report
//! whose gaze point is out of its logical range yields nothing and is
//! counted ([`HidStats::invalid_reports`]). LiveTrack yields two pupil
//! samples per packet (host arrival time).

use std::ffi::CString;
use std::os::unix::ffi::OsStrExt;
use std::sync::Arc;
use std::sync::atomic::{AtomicBool, AtomicU64, Ordering};

use hidapi::{HidApi, HidDevice, HidError};
use tokio::sync::mpsc;

use super::descriptor::Descriptor;
use super::livetrack::{self, LiveTrackMode, LiveTrackOptions};
use super::page12::{MODE_ENABLE_EYE_POSITION, MODE_ENABLE_GAZE_POINT, Page12Layout, ScreenSize};
use crate::target::HidTarget;
use crate::{READ_POLL_MS, ThreadItem, ThreadedSource, now_secs, send_blocking};
use gazelight_eye::clock::{SharedClockStats, SourceClock, SourceClockConfig};
use gazelight_eye::sample::{GazeEyes, GazeSample, Sample};
use gazelight_eye::source::{SampleSource, SourceError};

/// Largest HID report descriptor (HID_MAX_DESCRIPTOR_SIZE in Linux).
pub const MAX_DESCRIPTOR_LEN: usize = 4096;

/// Options of a [`HidSource`].
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq)]
pub struct HidOptions {
    /// LiveTrack options (ignored for page-0x12 devices).
    pub livetrack: LiveTrackOptions,
}

/// The decoder chosen for a device.
#[derive(Clone, Debug)]
pub enum HidProfile {
    /// Standard page 0x12 with the calibrated screen size.
    Page12 {
        layout: Box<Page12Layout>,
        screen: ScreenSize,
    },
    /// CRS LiveTrack.
    LiveTrack(LiveTrackOptions),
}

/// Counters shared with the reader thread.
#[derive(Debug, Default)]
pub struct HidStats {
    reports: AtomicU64,
    invalid_reports: AtomicU64,
    /// The counters of the device clock's mapping.
    clock: Arc<SharedClockStats>,
}

impl HidStats {
    /// Input reports read.
    pub fn reports(&self) -> u64 {
        self.reports.load(Ordering::Relaxed)
    }
    /// Reports skipped because a value was outside its logical range or
    /// the tracker marked the sample untracked.
    pub fn invalid_reports(&self) -> u64 {
        self.invalid_reports.load(Ordering::Relaxed)
    }
}

/// Explain a hidapi error, naming permission problems.
fn explain(e: &HidError, what: &str) -> String {
    let msg = e.to_string();
    if msg.contains("ermission denied") || msg.contains("EACCES") {
        format!(
            "{what}: permission denied (a udev rule granting access to the hidraw node, or \
             membership of its group, is needed): {msg}"
        )
    } else {
        format!("{what}: {msg}")
    }
}

/// Choose a profile from a descriptor and VID:PID.
pub fn choose_profile(
    descriptor: &Descriptor,
    vendor_id: u16,
    product_id: u16,
    options: HidOptions,
) -> Option<HidProfile> {
    if let Ok(layout) = Page12Layout::from_descriptor(descriptor) {
        // Screen size filled in by the caller.
        return Some(HidProfile::Page12 {
            layout: Box::new(layout),
            screen: ScreenSize {
                width_um: 0.0,
                height_um: 0.0,
            },
        });
    }
    if (vendor_id, product_id) == (livetrack::VENDOR_ID, livetrack::PRODUCT_ID) {
        return Some(HidProfile::LiveTrack(options.livetrack));
    }
    None
}

/// A HID eye tracker.
pub struct HidSource {
    target: HidTarget,
    options: HidOptions,
    name: String,
    profile_name: &'static str,
    stats: Arc<HidStats>,
    reader: Option<ThreadedSource>,
}

fn target_name(t: &HidTarget) -> String {
    match t {
        HidTarget::VidPid {
            vendor_id,
            product_id,
        } => format!("hid://{vendor_id:04x}:{product_id:04x}"),
        HidTarget::Path(p) => format!("hid://{}", p.display()),
    }
}

impl HidSource {
    /// Open a device. A missing device, a permission problem, an unusable
    /// descriptor or an unknown device is a [`SourceError::Fatal`].
    pub fn open(target: HidTarget, options: HidOptions) -> Result<Self, SourceError> {
        let name = target_name(&target);
        let stats = Arc::new(HidStats::default());
        let (reader, profile_name) =
            Self::start(&target, options, &name, &stats).map_err(|reason| SourceError::Fatal {
                source_name: name.clone(),
                reason,
            })?;
        Ok(Self {
            target,
            options,
            name,
            profile_name,
            stats,
            reader: Some(reader),
        })
    }

    /// Counters of this source.
    pub fn stats(&self) -> &HidStats {
        &self.stats
    }

    fn start(
        target: &HidTarget,
        options: HidOptions,
        name: &str,
        stats: &Arc<HidStats>,
    ) -> Result<(ThreadedSource, &'static str), String> {
        let api = HidApi::new().map_err(|e| explain(&e, "initialising hidapi"))?;
        let device = match target {
            HidTarget::VidPid {
                vendor_id,
                product_id,
            } => api.open(*vendor_id, *product_id).map_err(|e| {
                explain(
                    &e,
                    &format!("no HID device {vendor_id:04x}:{product_id:04x} could be opened"),
                )
            })?,
            HidTarget::Path(p) => {
                if !p.exists() {
                    return Err(format!("no such device {}", p.display()));
                }
                let c = CString::new(p.as_os_str().as_bytes())
                    .map_err(|_| format!("path {} contains a NUL byte", p.display()))?;
                api.open_path(&c)
                    .map_err(|e| explain(&e, &format!("opening {}", p.display())))?
            }
        };
        let (vendor_id, product_id) = match device.get_device_info() {
            Ok(info) => (info.vendor_id(), info.product_id()),
            Err(_) => match target {
                HidTarget::VidPid {
                    vendor_id,
                    product_id,
                } => (*vendor_id, *product_id),
                HidTarget::Path(_) => (0, 0),
            },
        };
        let mut desc = vec![0u8; MAX_DESCRIPTOR_LEN];
        let n = device
            .get_report_descriptor(&mut desc)
            .map_err(|e| explain(&e, "reading the report descriptor"))?;
        let descriptor = Descriptor::parse(&desc[..n])
            .map_err(|e| format!("report descriptor of {vendor_id:04x}:{product_id:04x}: {e}"))?;
        let profile =
            choose_profile(&descriptor, vendor_id, product_id, options).ok_or_else(|| {
                format!(
                    "device {vendor_id:04x}:{product_id:04x} has no page-0x12 Tracking Data report \
                 and no known vendor profile (collections: {:?})",
                    descriptor.collections
                )
            })?;
        let profile = match profile {
            HidProfile::Page12 { layout, .. } => {
                let screen = read_screen(&device, &layout)?;
                if let Some(ctrl) =
                    layout.control_report(MODE_ENABLE_GAZE_POINT | MODE_ENABLE_EYE_POSITION)
                    && let Err(e) = device.send_feature_report(&ctrl)
                {
                    tracing::warn!("{name}: Device Mode Request rejected: {e}");
                }
                HidProfile::Page12 { layout, screen }
            }
            HidProfile::LiveTrack(o) => {
                let cmd = match o.mode {
                    LiveTrackMode::Raw => livetrack::CMD_START_RAW,
                    LiveTrackMode::Calibrated => livetrack::CMD_START_CALIBRATED,
                };
                device
                    .write(&livetrack::command(cmd))
                    .map_err(|e| explain(&e, "sending the LiveTrack start command"))?;
                HidProfile::LiveTrack(o)
            }
        };
        let profile_name = match profile {
            HidProfile::Page12 { .. } => "page 0x12 eye tracker",
            HidProfile::LiveTrack(_) => "CRS LiveTrack",
        };
        let name2 = name.to_owned();
        let stats2 = Arc::clone(stats);
        let thread = ThreadedSource::spawn(&format!("hid {name}"), move |tx, stop| {
            reader_loop(device, profile, name2, stats2, tx, &stop)
        })
        .map_err(|e| format!("starting the reader thread: {e}"))?;
        Ok((thread, profile_name))
    }

    async fn next_inner(&mut self) -> Result<Option<Sample>, SourceError> {
        if self.reader.is_none() {
            match Self::start(&self.target, self.options, &self.name, &self.stats) {
                Ok((r, p)) => {
                    self.reader = Some(r);
                    self.profile_name = p;
                }
                Err(reason) => {
                    return Err(SourceError::Disconnected {
                        source_name: self.name.clone(),
                        reason,
                    });
                }
            }
        }
        crate::recv_reopenable(&mut self.reader, &self.name).await
    }
}

fn read_screen(device: &HidDevice, layout: &Page12Layout) -> Result<ScreenSize, String> {
    let Some((id, len)) = layout.configuration_report() else {
        return Err(
            "the descriptor has no Calibrated Screen Width/Height (Configuration feature \
             report); gaze cannot be normalised"
                .to_owned(),
        );
    };
    let mut buf = vec![0u8; len];
    buf[0] = id;
    let n = device.get_feature_report(&mut buf).map_err(|e| {
        explain(
            &e,
            &format!("reading the Configuration feature report {id:#04x}"),
        )
    })?;
    // hidraw returns the report ID first when IDs are used; without IDs
    // hidapi strips nothing, the buffer holds the report body.
    layout
        .decode_screen(&buf[..n])
        .map_err(|e| format!("Configuration feature report {id:#04x}: {e}"))
}

fn reader_loop(
    device: HidDevice,
    profile: HidProfile,
    name: String,
    stats: Arc<HidStats>,
    tx: mpsc::Sender<ThreadItem>,
    stop: &AtomicBool,
) {
    let mut buf = [0u8; 1024];
    let mut clock = SourceClock::with_stats(
        name.clone(),
        SourceClockConfig::default(),
        stats.clock.clone(),
    );
    let mut index: u64 = 0;
    loop {
        if stop.load(Ordering::Relaxed) {
            break;
        }
        let n = match device.read_timeout(&mut buf, READ_POLL_MS as i32) {
            Ok(0) => continue,
            Ok(n) => n,
            Err(e) => {
                let _ = send_blocking(
                    &tx,
                    stop,
                    Err(SourceError::Disconnected {
                        source_name: name.clone(),
                        reason: explain(&e, "read"),
                    }),
                );
                return;
            }
        };
        let arrival = now_secs();
        stats.reports.fetch_add(1, Ordering::Relaxed);
        let report = &buf[..n];
        let this = index;
        index += 1;
        match &profile {
            HidProfile::Page12 { layout, screen } => {
                if layout.tracking_report_id() != 0
                    && report.first() != Some(&layout.tracking_report_id())
                {
                    // Another input report of the device.
                    continue;
                }
                match layout.decode_tracking(report) {
                    Ok(td) => {
                        let Some(g) = td.gaze_um else {
                            stats.invalid_reports.fetch_add(1, Ordering::Relaxed);
                            continue;
                        };
                        let t = match td.timestamp_us {
                            Some(us) => match clock.to_host(us as f64 * 1e-6, arrival) {
                                Some(t) => t,
                                // Dropped and counted by the mapping.
                                None => continue,
                            },
                            None => clock.arrival(arrival),
                        };
                        let s = Sample::Gaze(GazeSample {
                            t_secs: t,
                            gaze_uv: Page12Layout::normalise(g, screen),
                            confidence: 1.0,
                            eyes: GazeEyes::Binocular,
                        });
                        if !send_blocking(&tx, stop, Ok(s)) {
                            break;
                        }
                    }
                    Err(e) => {
                        let item = Err(SourceError::Item {
                            source_name: name.clone(),
                            index: this,
                            error: Box::new(e),
                        });
                        if !send_blocking(&tx, stop, item) {
                            break;
                        }
                    }
                }
            }
            HidProfile::LiveTrack(o) => match livetrack::decode(report) {
                Ok(p) => {
                    let t = clock.arrival(arrival);
                    for s in livetrack::pupil_samples(&p, t, o.eye) {
                        if s.confidence == 0.0 {
                            stats.invalid_reports.fetch_add(1, Ordering::Relaxed);
                        }
                        if !send_blocking(&tx, stop, Ok(Sample::Pupil(s))) {
                            break;
                        }
                    }
                }
                Err(e) => {
                    let item = Err(SourceError::Item {
                        source_name: name.clone(),
                        index: this,
                        error: Box::new(e),
                    });
                    if !send_blocking(&tx, stop, item) {
                        break;
                    }
                }
            },
        }
    }
    if let HidProfile::LiveTrack(_) = profile {
        let _ = device.write(&livetrack::command(livetrack::CMD_STOP));
    }
}

impl SampleSource for HidSource {
    fn next(&mut self) -> impl Future<Output = Result<Option<Sample>, SourceError>> + Send {
        self.next_inner()
    }

    fn describe(&self) -> String {
        format!("{} at {}", self.profile_name, self.name)
    }

    fn clock_stats(&self) -> Option<Arc<SharedClockStats>> {
        Some(self.stats.clock.clone())
    }
}
