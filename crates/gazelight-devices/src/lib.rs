//! # gazelight-devices
//!
//! Hardware transports: eye trackers on HID, raw USB, serial lines and the
//! Gazepoint Open Gaze API over TCP, all behind [`gazelight_eye::SampleSource`].
//!
//! - [`hid`]: HID trackers. The report descriptor is parsed
//!   ([`hid::descriptor`]); trackers that use the standard usage page 0x12
//!   "Eye and Head Trackers" are decoded from the descriptor alone
//!   ([`hid::page12`]); trackers with a vendor layout that carries pupil size
//!   use a vendor profile ([`hid::livetrack`]: CRS LiveTrack).
//! - [`usb`]: a vendor bulk-IN endpoint carrying [`framing`] frames.
//! - [`serial`]: a serial line carrying CSV-ish lines, [`framing`] frames,
//!   or Gazepoint Open Gaze API records.
//! - [`gazepoint`]: the Open Gaze API over TCP (and its record parser, shared
//!   with the serial transport).
//! - [`discover`]: what is connected (`gazelight devices`).
//! - [`lsl`]: Lab Streaming Layer inlets (liblsl, loaded at run time).
//! - [`target`]: what to open (HID target, serial format); the source URI
//!   parser in `gazelight-tracker` produces these.
//!
//! Times: every sample these sources deliver is on the host clock
//! ([`gazelight_eye::clock::host_now_secs`]). Where the device stamps its
//! samples, the device clock is mapped onto the host clock by the one
//! source-clock mapping, [`gazelight_eye::clock::SourceClock`] (the lower
//! envelope of `arrival − stamp` over the last second or two; a stamp that
//! disagrees with it by more than its bound is dropped and counted, a clock
//! that steps is followed after a few stamps); where it does not, the host
//! time of arrival is used. Each source reports the mapping's counters
//! through [`gazelight_eye::SampleSource::clock_stats`].
//!
//! Blocking device APIs (hidapi, serialport) run on one reader thread per
//! open device that decodes into a bounded channel of ready [`Sample`]s
//! ([`ThreadedSource`]); nothing allocates per sample in steady state.
//! Errors never panic: a missing device, a permission problem or a lost
//! device is a [`SourceError`] naming the device, and a live source reopens
//! its device on the next call after a [`SourceError::Disconnected`].
//!
//! # Example
//!
//! The binary frames a serial line or a USB bulk endpoint carries
//! ([`framing`]): a gaze sample stamped 1 s on the device clock, encoded
//! and found again in the byte stream.
//!
//! ```
//! use gazelight_devices::framing::{self, FrameDecoder};
//! use gazelight_eye::{GazeEyes, GazeSample, Sample};
//!
//! let gaze = Sample::Gaze(GazeSample {
//!     t_secs: 1.0,
//!     gaze_uv: [0.25, 0.75],
//!     confidence: 1.0,
//!     eyes: GazeEyes::Binocular,
//! });
//! let mut bytes = vec![0x00, 0x13]; // line noise before the frame
//! framing::encode(&gaze, 1_000_000, &mut bytes);
//! let mut decoder = FrameDecoder::new();
//! decoder.push(&bytes);
//! let frame = decoder.next_frame().expect("one frame")?;
//! assert_eq!(frame.t_us, 1_000_000);
//! assert_eq!(frame.sample, gaze);
//! # Ok::<(), Box<dyn std::error::Error>>(())
//! ```

pub mod discover;
pub mod framing;
pub mod gazepoint;
pub mod hid;
pub mod lsl;
pub mod serial;
pub mod target;
pub mod usb;

use std::sync::Arc;
use std::sync::atomic::{AtomicBool, Ordering};
use std::thread::JoinHandle;

use tokio::sync::mpsc;

use gazelight_eye::clock::host_now_secs;
use gazelight_eye::sample::Sample;
use gazelight_eye::source::SourceError;

pub use target::{DEFAULT_BAUD, GAZEPOINT_DEFAULT_PORT, HidTarget, SerialFormat};

/// What a reader thread delivers.
pub(crate) type ThreadItem = Result<Sample, SourceError>;

/// Capacity of the channel between a reader thread and its source.
pub(crate) const THREAD_CHANNEL_CAPACITY: usize = 1024;

/// A source fed by a blocking reader thread.
///
/// The thread owns the device; it pushes decoded samples (or per-item
/// errors) into a bounded channel and stops when the source is dropped
/// (the stop flag is set and the channel closes) or when the device is
/// lost (it sends one [`SourceError::Disconnected`] and exits).
pub(crate) struct ThreadedSource {
    rx: mpsc::Receiver<ThreadItem>,
    stop: Arc<AtomicBool>,
    thread: Option<JoinHandle<()>>,
}

impl ThreadedSource {
    /// Start `body` on a named thread. `body` gets the sender and the stop
    /// flag and must return when the flag is set or a send fails.
    pub(crate) fn spawn<F>(name: &str, body: F) -> Result<Self, std::io::Error>
    where
        F: FnOnce(mpsc::Sender<ThreadItem>, Arc<AtomicBool>) + Send + 'static,
    {
        let (tx, rx) = mpsc::channel(THREAD_CHANNEL_CAPACITY);
        let stop = Arc::new(AtomicBool::new(false));
        let stop2 = Arc::clone(&stop);
        let thread = std::thread::Builder::new()
            .name(name.chars().take(15).collect())
            .spawn(move || body(tx, stop2))?;
        Ok(Self {
            rx,
            stop,
            thread: Some(thread),
        })
    }

    /// The next item; `None` once the thread has ended and the channel is
    /// drained.
    pub(crate) async fn recv(&mut self) -> Option<ThreadItem> {
        self.rx.recv().await
    }
}

/// The next sample of a source that reopens its device: reads from the open
/// reader thread; a lost device (or a thread that ended) closes the reader,
/// so the caller's next call reopens it. `Ok(None)` when no reader is open.
pub(crate) async fn recv_reopenable(
    reader: &mut Option<ThreadedSource>,
    source_name: &str,
) -> Result<Option<Sample>, SourceError> {
    let Some(r) = reader.as_mut() else {
        return Ok(None);
    };
    match r.recv().await {
        Some(Ok(s)) => Ok(Some(s)),
        Some(Err(e)) => {
            if matches!(e, SourceError::Disconnected { .. }) {
                *reader = None;
            }
            Err(e)
        }
        None => {
            *reader = None;
            Err(SourceError::Disconnected {
                source_name: source_name.to_owned(),
                reason: "reader stopped".to_owned(),
            })
        }
    }
}

impl Drop for ThreadedSource {
    fn drop(&mut self) {
        self.stop.store(true, Ordering::Relaxed);
        self.rx.close();
        // The reader threads poll the stop flag at least every
        // `READ_POLL_MS`; joining keeps the device closed before a reopen.
        if let Some(t) = self.thread.take() {
            let _ = t.join();
        }
    }
}

/// How long a blocking read waits before a reader thread re-checks its
/// stop flag, milliseconds.
pub(crate) const READ_POLL_MS: u64 = 50;

/// Send from a reader thread; `false` when the source is gone (stop).
pub(crate) fn send_blocking(
    tx: &mpsc::Sender<ThreadItem>,
    stop: &AtomicBool,
    item: ThreadItem,
) -> bool {
    if stop.load(Ordering::Relaxed) {
        return false;
    }
    tx.blocking_send(item).is_ok()
}

/// Host time now, seconds (re-exported for the transports).
pub(crate) fn now_secs() -> f64 {
    host_now_secs()
}
