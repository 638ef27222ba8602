//! `run --lsl`: the session on the Lab Streaming Layer.
//!
//! - `gazelight-eye` (type `Gaze`): the filtered, calibrated eye state at
//!   the tracker's rate — one sample per tracker time (updates of one
//!   tracker instant are coalesced: a sample goes out when a newer time
//!   arrives or after [`COALESCE`] of quiet), stamped on the LSL clock from
//!   the state's tracker-derived host time, not from its arrival.
//! - `gazelight-frame` (type `Frame`): per frame, the frame's figures,
//!   stamped when the frame loop published them.
//! - `gazelight-markers` (type `Markers`): session start/stop, PSF
//!   rebuilds, blinks, tracker lost/found.
//!
//! Nothing here can block the frame loop or the source: the eye outlet
//! reads the hub's `watch` channel (the source never waits for it), the
//! frame loop's figures come through the hub's bounded frame tap (a full
//! queue drops and counts), and markers go through a bounded queue to the
//! thread that owns the frame and marker outlets.

use std::sync::Arc;
use std::sync::atomic::{AtomicU64, Ordering};
use std::sync::mpsc::{Receiver, RecvTimeoutError, SyncSender, TrySendError};
use std::time::Duration;

use gazelight_tracker::lsl::{
    ChannelDesc, ChannelFormat, LslClock, LslConfig, LslError, Outlet, StreamDesc,
};
use gazelight_tracker::pupil::clock::host_now_secs;
use gazelight_tracker::{EYE_LEFT, EYE_RIGHT, EyeState};
use tokio::task::JoinHandle;

use crate::hub::{Hub, TappedFrame};
use gazelight_tracker::live::{AgeClock, SourceHealth};

/// Quiet time after which a held eye state is published, even if no newer
/// tracker time has arrived.
pub const COALESCE: Duration = Duration::from_millis(1);
/// Capacity of the frame tap (≈ 3 s at 90 Hz).
const FRAME_QUEUE: usize = 256;
/// Capacity of the marker queue.
const MARKER_QUEUE: usize = 256;
/// How often the source's health is polled for lost/found markers.
const HEALTH_POLL: Duration = Duration::from_millis(50);
/// Seconds of samples liblsl keeps for a slow consumer.
const LSL_BUFFER_SECS: i32 = 60;

/// Channels of `gazelight-eye`, in order.
pub const EYE_CHANNELS: [(&str, &str, &str, Option<&str>); 10] = [
    ("gaze_x", "normalized", "ScreenX", Some("both")),
    ("gaze_y", "normalized", "ScreenY", Some("both")),
    ("gaze_valid", "boolean", "Validity", Some("both")),
    ("pupil_right_mm", "mm", "Diameter", Some("right")),
    (
        "confidence_right",
        "normalized",
        "Confidence",
        Some("right"),
    ),
    ("pupil_valid_right", "boolean", "Validity", Some("right")),
    ("pupil_left_mm", "mm", "Diameter", Some("left")),
    ("confidence_left", "normalized", "Confidence", Some("left")),
    ("pupil_valid_left", "boolean", "Validity", Some("left")),
    ("blink", "boolean", "Blink", Some("both")),
];

/// Channels of `gazelight-frame`, in order.
pub const FRAME_CHANNELS: [(&str, &str, &str); 14] = [
    ("frame", "count", "FrameIndex"),
    ("display_t_secs", "s", "SessionTime"),
    ("adaptation_cd_m2", "cd/m^2", "Luminance"),
    ("target_cd_m2", "cd/m^2", "Luminance"),
    ("psf_pupil_mm", "mm", "Diameter"),
    ("pupil_right_mm", "mm", "Diameter"),
    ("pupil_left_mm", "mm", "Diameter"),
    ("eye_state_age_ms", "ms", "Latency"),
    ("frame_ms", "ms", "Duration"),
    ("psf_rebuilds", "count", "Counter"),
    // The pupil light response (docs/pupil-light-response.md): the pupil
    // the light predicts, and measured − predicted (NaN: not measured).
    ("pupil_light_right_mm", "mm", "Diameter"),
    ("pupil_light_left_mm", "mm", "Diameter"),
    ("pupil_residual_right_mm", "mm", "Diameter"),
    ("pupil_residual_left_mm", "mm", "Diameter"),
];

/// Why the outlets did not start.
#[derive(Debug, thiserror::Error)]
pub enum OutletError {
    /// liblsl could not be loaded, or the clock offset not measured.
    #[error("--lsl")]
    Lsl(#[source] LslError),
    /// The `gazelight-eye` outlet could not be created.
    #[error("--lsl: eye outlet")]
    EyeOutlet(#[source] LslError),
    /// The `gazelight-frame` outlet could not be created.
    #[error("--lsl: frame outlet")]
    FrameOutlet(#[source] LslError),
    /// The `gazelight-markers` outlet could not be created.
    #[error("--lsl: marker outlet")]
    MarkerOutlet(#[source] LslError),
    /// The hub's frame tap was opened before (it opens once).
    #[error("--lsl: the frame tap is already open")]
    FrameTapOpen,
    /// The thread that owns the frame and marker outlets did not start.
    #[error("cannot start the LSL thread")]
    Thread(#[source] std::io::Error),
}

/// What the outlets did, for the log at the end.
#[derive(Debug, Default)]
pub struct OutletCounters {
    pub eye_samples: AtomicU64,
    pub frames: AtomicU64,
    pub markers: AtomicU64,
    pub markers_dropped: AtomicU64,
}

/// The running outlets.
pub struct LslOutlets {
    pub counters: Arc<OutletCounters>,
    eye_task: JoinHandle<()>,
    health_task: JoinHandle<()>,
    thread: Option<std::thread::JoinHandle<()>>,
    markers: SyncSender<Marker>,
    stop: Arc<std::sync::atomic::AtomicBool>,
    hub: Arc<Hub>,
}

fn eye_desc(prefix: &str, source: &str, rate_hz: f64) -> StreamDesc {
    StreamDesc {
        name: format!("{prefix}-eye"),
        kind: "Gaze".into(),
        nominal_srate_hz: rate_hz,
        format: ChannelFormat::Double64,
        source_id: format!("{prefix}-eye@{}", std::process::id()),
        channels: EYE_CHANNELS
            .iter()
            .map(|(l, u, k, e)| ChannelDesc::new(l, u, k, *e))
            .collect(),
        meta: vec![
            ("manufacturer".into(), "gazelight".into()),
            ("source".into(), source.into()),
            (
                "coordinate_system".into(),
                "gaze normalized to the display image, origin top-left".into(),
            ),
            (
                "filter".into(),
                "gazelight filter chain (confidence, blink, dropout hold, outlier, 1-euro), calibrated".into(),
            ),
        ],
    }
}

fn frame_desc(prefix: &str, source: &str, fps: f64) -> StreamDesc {
    StreamDesc {
        name: format!("{prefix}-frame"),
        kind: "Frame".into(),
        nominal_srate_hz: fps,
        format: ChannelFormat::Double64,
        source_id: format!("{prefix}-frame@{}", std::process::id()),
        channels: FRAME_CHANNELS
            .iter()
            .map(|(l, u, k)| ChannelDesc::new(l, u, k, None))
            .collect(),
        meta: vec![
            ("manufacturer".into(), "gazelight".into()),
            ("source".into(), source.into()),
        ],
    }
}

fn marker_desc(prefix: &str, source: &str) -> StreamDesc {
    StreamDesc {
        name: format!("{prefix}-markers"),
        kind: "Markers".into(),
        nominal_srate_hz: 0.0,
        format: ChannelFormat::String,
        source_id: format!("{prefix}-markers@{}", std::process::id()),
        channels: Vec::new(),
        meta: vec![
            ("manufacturer".into(), "gazelight".into()),
            ("source".into(), source.into()),
        ],
    }
}

/// The eye sample of a state, in [`EYE_CHANNELS`] order.
pub fn eye_values(s: &EyeState) -> [f64; 10] {
    // The measured pupil (NaN where the eye is not measured now or has no
    // physical scale), never the model aperture.
    let valid = |e: usize| f64::from(u8::from(s.eyes[e].measured_mm().is_some()));
    let mm = |e: usize| s.eyes[e].measured_mm().map_or(f64::NAN, f64::from);
    [
        f64::from(s.gaze_uv[0]),
        f64::from(s.gaze_uv[1]),
        f64::from(u8::from(s.gaze_valid)),
        mm(EYE_RIGHT),
        f64::from(s.eyes[EYE_RIGHT].confidence),
        valid(EYE_RIGHT),
        mm(EYE_LEFT),
        f64::from(s.eyes[EYE_LEFT].confidence),
        valid(EYE_LEFT),
        f64::from(u8::from(s.blink)),
    ]
}

/// A marker and the host time it happened at.
type Marker = (f64, String);

fn send_marker(tx: &SyncSender<Marker>, counters: &OutletCounters, text: String) {
    match tx.try_send((host_now_secs(), text)) {
        Ok(()) => {}
        Err(TrySendError::Full(_)) | Err(TrySendError::Disconnected(_)) => {
            counters.markers_dropped.fetch_add(1, Ordering::Relaxed);
        }
    }
}

impl LslOutlets {
    /// Creates the three outlets and starts publishing. Must be called
    /// inside the session's tokio runtime. `eye_rate_hz` is the nominal
    /// rate of the eye stream (0 = irregular).
    pub fn start(
        config: &LslConfig,
        hub: Arc<Hub>,
        age_clock: AgeClock,
        fps: f64,
        eye_rate_hz: f64,
    ) -> Result<Self, OutletError> {
        let info = gazelight_tracker::lsl::load(config).map_err(OutletError::Lsl)?;
        let clock = LslClock::measure(config).map_err(OutletError::Lsl)?;
        let prefix = config.name_prefix.as_deref().unwrap_or("gazelight");
        let source = hub.source().uri;
        let mut eye = Outlet::new(
            config,
            &eye_desc(prefix, &source, eye_rate_hz),
            LSL_BUFFER_SECS,
        )
        .map_err(OutletError::EyeOutlet)?;
        let mut frame = Outlet::new(config, &frame_desc(prefix, &source, fps), LSL_BUFFER_SECS)
            .map_err(OutletError::FrameOutlet)?;
        let mut markers = Outlet::new(config, &marker_desc(prefix, &source), LSL_BUFFER_SECS)
            .map_err(OutletError::MarkerOutlet)?;
        tracing::info!(
            library = %info.path,
            version = info.version,
            config = %info.config,
            clock_uncertainty_us = clock.uncertainty_secs * 1e6,
            "LSL outlets {prefix}-eye, {prefix}-frame, {prefix}-markers"
        );
        let counters = Arc::new(OutletCounters::default());
        let frames_rx = hub
            .open_frame_tap(FRAME_QUEUE)
            .ok_or(OutletError::FrameTapOpen)?;
        let (marker_tx, marker_rx) = std::sync::mpsc::sync_channel::<Marker>(MARKER_QUEUE);
        // Session start goes out before anything else.
        let _ = markers.push_marker("session_start", clock.to_lsl(host_now_secs()));
        counters.markers.fetch_add(1, Ordering::Relaxed);

        let stop = Arc::new(std::sync::atomic::AtomicBool::new(false));
        let thread = {
            let counters = counters.clone();
            let marker_tx = marker_tx.clone();
            let stop = stop.clone();
            std::thread::Builder::new()
                .name("gazelight-lsl".into())
                .spawn(move || {
                    frame_and_marker_loop(
                        frames_rx,
                        marker_rx,
                        &mut frame,
                        &mut markers,
                        clock,
                        &counters,
                        &marker_tx,
                        &stop,
                    )
                })
                .map_err(OutletError::Thread)?
        };

        let eye_task = {
            let hub = hub.clone();
            let counters = counters.clone();
            let marker_tx = marker_tx.clone();
            tokio::spawn(async move {
                eye_loop(&hub, &mut eye, clock, age_clock, &counters, &marker_tx).await;
            })
        };
        let health_task = {
            let hub = hub.clone();
            let counters = counters.clone();
            let marker_tx = marker_tx.clone();
            tokio::spawn(async move {
                let mut shutdown = hub.shutdown_signal();
                let mut tick = tokio::time::interval(HEALTH_POLL);
                let mut last = hub.source().health;
                loop {
                    tokio::select! {
                        _ = shutdown.changed() => break,
                        _ = tick.tick() => {}
                    }
                    let h = hub.source().health;
                    if h != last {
                        let text = match h {
                            SourceHealth::Live => "tracker_found",
                            SourceHealth::Degraded => "tracker_degraded",
                            SourceHealth::Lost => "tracker_lost",
                            SourceHealth::Ended => "tracker_ended",
                            SourceHealth::Connecting => "tracker_connecting",
                        };
                        send_marker(&marker_tx, &counters, text.to_owned());
                        last = h;
                    }
                    if *shutdown.borrow() {
                        break;
                    }
                }
            })
        };
        Ok(Self {
            counters,
            eye_task,
            health_task,
            thread: Some(thread),
            markers: marker_tx,
            stop,
            hub,
        })
    }

    /// Sends `session_stop`, stops the tasks and the thread (after the
    /// hub's shutdown) and logs the counts.
    pub async fn finish(mut self) {
        send_marker(&self.markers, &self.counters, "session_stop".to_owned());
        let _ = tokio::time::timeout(Duration::from_secs(2), &mut self.eye_task).await;
        let _ = tokio::time::timeout(Duration::from_secs(2), &mut self.health_task).await;
        self.stop.store(true, Ordering::Relaxed);
        if let Some(t) = self.thread.take() {
            // The thread drains the marker queue (session_stop last), then ends.
            let _ = tokio::task::spawn_blocking(move || t.join()).await;
        }
        let c = &self.counters;
        tracing::info!(
            eye_samples = c.eye_samples.load(Ordering::Relaxed),
            frames = c.frames.load(Ordering::Relaxed),
            frames_dropped = self.hub.frame_tap().map_or(0, |t| t.dropped()),
            markers = c.markers.load(Ordering::Relaxed),
            markers_dropped = c.markers_dropped.load(Ordering::Relaxed),
            "LSL outlets closed"
        );
    }
}

/// The eye outlet: one sample per tracker time, coalescing updates of the
/// same instant.
async fn eye_loop(
    hub: &Hub,
    outlet: &mut Outlet,
    clock: LslClock,
    age_clock: AgeClock,
    counters: &OutletCounters,
    markers: &SyncSender<Marker>,
) {
    let mut rx = hub.eye.clone();
    let mut shutdown = hub.shutdown_signal();
    // (state, host time to stamp it with)
    let mut held: Option<(EyeState, f64)> = None;
    let mut last_stamp = f64::NEG_INFINITY;
    let mut last_updates = rx.borrow().updates;
    let mut blink = false;
    let mut publish = |s: &EyeState, host_t: f64, last_stamp: &mut f64| {
        let ts = clock.to_lsl(host_t);
        // LSL timestamps of one stream stay monotonic.
        if ts <= *last_stamp {
            return;
        }
        *last_stamp = ts;
        if outlet.push(&eye_values(s), ts).is_ok() {
            counters.eye_samples.fetch_add(1, Ordering::Relaxed);
        }
    };
    loop {
        let quiet = tokio::time::sleep(COALESCE);
        tokio::select! {
            _ = shutdown.changed() => break,
            r = rx.changed() => {
                if r.is_err() { break; }
                let live = *rx.borrow_and_update();
                if live.updates == last_updates { continue; }
                last_updates = live.updates;
                let host_t = match age_clock {
                    AgeClock::SampleTime => live.state.t_secs,
                    AgeClock::PublishTime => live.updated_host_secs,
                };
                if live.state.blink != blink {
                    blink = live.state.blink;
                    send_marker(markers, counters, if blink { "blink_start" } else { "blink_end" }.to_owned());
                }
                if let Some((s, t)) = held
                    && t != host_t
                {
                    publish(&s, t, &mut last_stamp);
                }
                held = Some((live.state, host_t));
            }
            _ = quiet, if held.is_some() => {
                if let Some((s, t)) = held.take() {
                    publish(&s, t, &mut last_stamp);
                }
            }
        }
    }
    if let Some((s, t)) = held.take() {
        publish(&s, t, &mut last_stamp);
    }
}

/// The thread that owns the frame and marker outlets.
#[allow(clippy::too_many_arguments)]
fn frame_and_marker_loop(
    frames: Receiver<TappedFrame>,
    markers_rx: Receiver<Marker>,
    frame: &mut Outlet,
    markers: &mut Outlet,
    clock: LslClock,
    counters: &OutletCounters,
    marker_tx: &SyncSender<Marker>,
    stop: &std::sync::atomic::AtomicBool,
) {
    let mut rebuilds = 0u64;
    let mut frames_open = true;
    loop {
        // Markers first (they are rare), then up to one frame.
        let stopping = stop.load(Ordering::Relaxed);
        while let Ok((host_t, text)) = markers_rx.try_recv() {
            if markers.push_marker(&text, clock.to_lsl(host_t)).is_ok() {
                counters.markers.fetch_add(1, Ordering::Relaxed);
            }
        }
        if stopping {
            return;
        }
        if !frames_open {
            std::thread::sleep(Duration::from_millis(2));
            continue;
        }
        match frames.recv_timeout(Duration::from_millis(2)) {
            Ok((host_t, f)) => {
                let (light, residual) = (f.pupil_light_mm, f.pupil_residual_mm);
                let values = [
                    f.frames as f64,
                    f.t_secs,
                    f.adaptation_cd_m2,
                    f.target_cd_m2,
                    f64::from(f.frame_pupil_mm),
                    f64::from(f.pupil_mm[EYE_RIGHT]),
                    f64::from(f.pupil_mm[EYE_LEFT]),
                    f.eye_state_age_ms,
                    f.frame_ms,
                    f.psf_rebuilds as f64,
                    f64::from(light[EYE_RIGHT]),
                    f64::from(light[EYE_LEFT]),
                    f64::from(residual[EYE_RIGHT]),
                    f64::from(residual[EYE_LEFT]),
                ];
                if frame.push(&values, clock.to_lsl(host_t)).is_ok() {
                    counters.frames.fetch_add(1, Ordering::Relaxed);
                }
                if f.psf_rebuilds > rebuilds {
                    rebuilds = f.psf_rebuilds;
                    send_marker(
                        marker_tx,
                        counters,
                        format!("psf_rebuild {rebuilds} pupil_mm={:.3}", f.frame_pupil_mm),
                    );
                }
            }
            Err(RecvTimeoutError::Timeout) => {}
            Err(RecvTimeoutError::Disconnected) => frames_open = false,
        }
    }
}
