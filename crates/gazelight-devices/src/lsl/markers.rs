//! An LSL marker stream read live (`run --events lsl://?name=…`): a
//! string-valued stream (irregular rate, as PsychoPy, Presentation,
//! OpenSesame or LabRecorder's markers) whose every sample becomes a
//! [`LiveEvent`] on the host clock in a bounded [`EventQueue`].
//!
//! A reader thread resolves the stream, opens an inlet (strings: liblsl's
//! `lsl_pull_sample_buf`, each channel's bytes with their length; the
//! channels of one sample joined by a tab, as the XDF importer's markers),
//! and maps each marker's timestamp onto the host clock: sender stamp +
//! the inlet's `time_correction()` (refreshed every few seconds) gives
//! this machine's LSL clock, and [`LslClock`] the host clock. Unlike the
//! samples of [`super::LslSource`] a marker's stamp is not checked against
//! its arrival: a sender may stamp a marker with the moment of a stimulus
//! it pushes later. A lost stream is resolved again.

use std::ffi::c_char;
use std::sync::Arc;
use std::sync::atomic::{AtomicBool, AtomicU64, Ordering};
use std::thread::JoinHandle;
use std::time::{Duration, Instant};

use gazelight_eye::live_events::{EventQueue, LiveEvent, MAX_LIVE_EVENT_TEXT_BYTES};

use super::ffi::{self, Api, Ptr};
use super::{LslClock, LslConfig, LslError, LslQuery, StreamInfo, resolve};

/// Most channels of a marker stream read (a marker is one string; a few
/// streams send several).
const MAX_MARKER_CHANNELS: usize = 64;
/// How often the time correction is refreshed, s.
const TIME_CORRECTION_PERIOD_SECS: f64 = 5.0;
/// How long one pull or resolve waits before the stop flag is checked, s.
const PULL_TIMEOUT_SECS: f64 = 0.05;
const RESOLVE_STEP_SECS: f64 = 0.5;

/// A string inlet.
struct MarkerInlet {
    api: &'static Api,
    ptr: Ptr,
    channels: usize,
    name: String,
}

// SAFETY: liblsl inlets may be used from any thread (one at a time here).
unsafe impl Send for MarkerInlet {}

/// What one pull gave.
enum Pull {
    Marker { stamp: f64, text: String },
    Nothing,
    Lost,
}

impl MarkerInlet {
    fn new(info: &StreamInfo) -> Result<Self, LslError> {
        let name = info.name();
        if info.numeric() {
            return Err(LslError::Argument {
                reason: format!(
                    "stream `{name}` carries numbers, not markers: give a string stream \
                     (`--source` reads numeric streams)"
                ),
            });
        }
        let channels = info.channel_count();
        if channels == 0 || channels > MAX_MARKER_CHANNELS {
            return Err(LslError::Argument {
                reason: format!(
                    "marker stream `{name}`: {channels} channels (1 to {MAX_MARKER_CHANNELS})"
                ),
            });
        }
        let ptr = info.create_inlet()?;
        Ok(Self {
            api: info.api,
            ptr,
            channels,
            name,
        })
    }

    fn time_correction(&self, timeout_secs: f64) -> Option<f64> {
        let mut ec = 0;
        // SAFETY: live inlet.
        let c = unsafe { (self.api.time_correction)(self.ptr, timeout_secs, &mut ec) };
        (ec == 0 && c.is_finite()).then_some(c)
    }

    fn open(&self, timeout_secs: f64) -> bool {
        let mut ec = 0;
        // SAFETY: live inlet.
        unsafe { (self.api.open_stream)(self.ptr, timeout_secs, &mut ec) };
        ec == 0
    }

    /// The next marker, its channels joined by a tab, each cut to the
    /// event text bound.
    fn pull(&mut self, strs: &mut [*mut c_char], lens: &mut [u32]) -> Pull {
        let n = self.channels;
        let (strs, lens) = (&mut strs[..n], &mut lens[..n]);
        strs.fill(std::ptr::null_mut());
        lens.fill(0);
        let mut ec = 0;
        // SAFETY: both buffers hold exactly the stream's channel count;
        // liblsl allocates each string, freed below.
        let ts = unsafe {
            (self.api.pull_sample_buf)(
                self.ptr,
                strs.as_mut_ptr(),
                lens.as_mut_ptr(),
                n as i32,
                PULL_TIMEOUT_SECS,
                &mut ec,
            )
        };
        let mut text = String::new();
        for (k, (&p, &len)) in strs.iter().zip(lens.iter()).enumerate() {
            if p.is_null() {
                continue;
            }
            if ec == 0 && ts != 0.0 {
                let len = (len as usize).min(MAX_LIVE_EVENT_TEXT_BYTES);
                // SAFETY: liblsl wrote `len` (≥ the bytes read) bytes at `p`.
                let bytes = unsafe { std::slice::from_raw_parts(p.cast::<u8>(), len) };
                if k > 0 {
                    text.push('\t');
                }
                text.push_str(&String::from_utf8_lossy(bytes));
            }
            // SAFETY: allocated by liblsl for this pull, freed once.
            unsafe { (self.api.destroy_string)(p) };
        }
        match ec {
            0 if ts != 0.0 => Pull::Marker { stamp: ts, text },
            0 | ffi::LSL_TIMEOUT_ERROR => Pull::Nothing,
            _ => Pull::Lost,
        }
    }
}

impl Drop for MarkerInlet {
    fn drop(&mut self) {
        // SAFETY: created by lsl_create_inlet, destroyed once.
        unsafe { (self.api.destroy_inlet)(self.ptr) };
    }
}

/// A marker stream being read into an [`EventQueue`]; dropping it stops
/// the reader (within a pull's timeout).
pub struct LslMarkers {
    query: LslQuery,
    stop: Arc<AtomicBool>,
    received: Arc<AtomicU64>,
    thread: Option<JoinHandle<()>>,
}

impl LslMarkers {
    /// Loads liblsl, measures the clock and starts the reader thread (the
    /// stream is resolved there: it may appear later).
    pub fn start(
        query: LslQuery,
        config: &LslConfig,
        events: Arc<EventQueue>,
    ) -> Result<Self, LslError> {
        let clock = LslClock::measure(config)?;
        let stop = Arc::new(AtomicBool::new(false));
        let received = Arc::new(AtomicU64::new(0));
        let thread = {
            let (query, config, stop, received) = (
                query.clone(),
                config.clone(),
                stop.clone(),
                received.clone(),
            );
            std::thread::Builder::new()
                .name("gazelight-lsl-markers".into())
                .spawn(move || read_markers(&query, &config, clock, &events, &stop, &received))
                .map_err(|e| LslError::Create {
                    what: format!("the marker reader thread ({e})"),
                })?
        };
        Ok(Self {
            query,
            stop,
            received,
            thread: Some(thread),
        })
    }

    /// Markers received so far (queued or dropped by a full queue).
    pub fn received(&self) -> u64 {
        self.received.load(Ordering::Relaxed)
    }

    /// The query, for the log.
    pub fn describe(&self) -> String {
        format!("LSL markers {}", self.query)
    }
}

impl Drop for LslMarkers {
    fn drop(&mut self) {
        self.stop.store(true, Ordering::Relaxed);
        if let Some(t) = self.thread.take() {
            let _ = t.join();
        }
    }
}

fn read_markers(
    query: &LslQuery,
    config: &LslConfig,
    clock: LslClock,
    events: &EventQueue,
    stop: &AtomicBool,
    received: &AtomicU64,
) {
    let mut strs = [std::ptr::null_mut::<c_char>(); MAX_MARKER_CHANNELS];
    let mut lens = [0u32; MAX_MARKER_CHANNELS];
    let mut said_wrong = false;
    while !stop.load(Ordering::Relaxed) {
        let info = match resolve(config, query.prop, &query.value, RESOLVE_STEP_SECS) {
            Ok(Some(i)) => i,
            Ok(None) => continue,
            Err(e) => {
                tracing::error!(markers = %query, "{e}; no markers are read");
                return;
            }
        };
        let mut inlet = match MarkerInlet::new(&info) {
            Ok(i) => i,
            Err(e) => {
                if !said_wrong {
                    said_wrong = true;
                    tracing::error!(markers = %query, "{e}; waiting for a string stream of that {}", query.prop);
                }
                std::thread::sleep(Duration::from_secs_f64(RESOLVE_STEP_SECS));
                continue;
            }
        };
        drop(info);
        // Measured before subscribing, as the sample inlet does.
        let mut correction = inlet.time_correction(2.0);
        if !inlet.open(2.0) {
            tracing::warn!(markers = %query, "could not subscribe within 2 s; resolving again");
            continue;
        }
        tracing::info!(stream = %inlet.name, channels = inlet.channels, "LSL marker inlet open");
        let mut last_correction = Instant::now();
        while !stop.load(Ordering::Relaxed) {
            if correction.is_none()
                || last_correction.elapsed().as_secs_f64() >= TIME_CORRECTION_PERIOD_SECS
            {
                last_correction = Instant::now();
                if let Some(c) = inlet.time_correction(0.2) {
                    correction = Some(c);
                }
            }
            match inlet.pull(&mut strs, &mut lens) {
                Pull::Marker { stamp, text } => {
                    received.fetch_add(1, Ordering::Relaxed);
                    // Same machine or not yet measured: 0.
                    let host = clock.to_host(stamp + correction.unwrap_or(0.0));
                    events.push(LiveEvent::new(host, stamp, None, &inlet.name, &text));
                }
                Pull::Nothing => {}
                Pull::Lost => {
                    tracing::warn!(stream = %inlet.name, "LSL marker stream lost; resolving again");
                    break;
                }
            }
        }
    }
}
