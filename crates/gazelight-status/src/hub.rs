//! The service hub: what a running session (`run`, `replay --serve`) shares
//! with its observers — the status page (`serve`), the Pupil-compatible
//! relay, recorders and tests.
//!
//! Writers are the live eye task of `gazelight-tracker` (the eye-state
//! `watch` channel, the sample broadcast, the source status) and the frame loop (frame statistics, history,
//! the latest frame and PSF kernel). Readers never block the writers for
//! more than a copy: every shared value sits behind a short `Mutex` whose
//! critical sections copy into preallocated storage, so the frame loop does
//! not allocate in steady state. Queues are bounded: the sample broadcast
//! drops the oldest values for a lagging receiver (the receiver learns how
//! many), and the history is a fixed-size ring.

use std::sync::{Arc, Mutex, MutexGuard};

use gazelight_app::session::SessionSettings;
use gazelight_tracker::LiveEyeState;
use gazelight_tracker::Sample;
use gazelight_tracker::live::{LiveEye, SAMPLE_BROADCAST_CAPACITY, SharedStatus, SourceStatus};
use serde::Serialize;
use tokio::sync::{broadcast, watch};

/// Points kept in the status history ring (≈ 45 s at 90 Hz).
pub const HISTORY_CAPACITY: usize = 4096;

/// Frame-loop figures of the newest frame, written by the frame loop.
#[derive(Clone, Copy, Debug, Default, PartialEq, Serialize)]
pub struct FrameStatus {
    /// Frames produced since start.
    pub frames: u64,
    /// Frames that missed their deadline since start.
    pub frames_late: u64,
    /// Session time of the newest frame, s.
    pub t_secs: f64,
    /// The measured pupil per eye [right, left] (Pupil's eye indices),
    /// mm; NaN (null) where the eye is not measured now or has no physical
    /// scale.
    pub pupil_mm: [f32; 2],
    /// The model aperture per eye [right, left], mm (sizes the glare PSF;
    /// not a measurement).
    pub aperture_mm: [f32; 2],
    /// Aperture the frame used (binocular), mm.
    pub frame_pupil_mm: f32,
    /// Gaze used for the frame, normalised display coordinates.
    pub gaze_uv: [f32; 2],
    /// Adaptation luminance after the frame, cd/m².
    pub adaptation_cd_m2: f64,
    /// Pooled target luminance, cd/m².
    pub target_cd_m2: f64,
    /// Views rendered per frame: 1, or 2 in stereo.
    pub views: u32,
    /// Adaptation luminance after the frame per view, cd/m²: [left, right]
    /// in stereo; the one view's (as [`Self::adaptation_cd_m2`]) and NaN
    /// (JSON null) otherwise.
    pub view_adaptation_cd_m2: [f64; 2],
    /// Pooled target luminance per view, cd/m², as
    /// [`Self::view_adaptation_cd_m2`].
    pub view_target_cd_m2: [f64; 2],
    /// The pupil the light predicts per view, mm (the pupil light
    /// response, docs/pupil-light-response.md), as
    /// [`Self::view_adaptation_cd_m2`].
    pub view_pupil_light_mm: [f32; 2],
    /// The view's measured pupil minus the prediction, mm; NaN (null)
    /// where the pupil is not measured (held, modelled).
    pub view_pupil_residual_mm: [f32; 2],
    /// The same per eye [right, left] ([`Self::eye_pupil_light_mm`]), as
    /// the status page, the relay and LSL show them.
    pub pupil_light_mm: [f32; 2],
    /// Measured − predicted per eye [right, left]
    /// ([`Self::eye_pupil_residual_mm`]).
    pub pupil_residual_mm: [f32; 2],
    /// Age of the `EyeState` the frame used, ms.
    pub eye_state_age_ms: f64,
    /// The frame time, ms: from the frame's start (the `EyeState` read)
    /// to its image handed on (shown in the window's slot, read back for
    /// the status page and files); the sum of [`Self::parts`]. Not in it:
    /// the wait for the next frame's deadline, and the status and file
    /// rows written after it.
    pub frame_ms: f64,
    /// [`Self::frame_ms`] in consecutive parts, ms.
    pub parts: FrameParts,
    /// Per-stage times of the newest frame's first view, ms.
    pub timings: gazelight_vision::pipeline::StageTimings,
    /// PSF rebuilds since start.
    pub psf_rebuilds: u64,
    /// Display frames read back from the GPU since start (only for the
    /// file writer and the status page; 0 on the CPU pipeline).
    pub frames_read_back: u64,
    /// Surface images the window presented since start (0 headless).
    pub frames_presented: u64,
}

/// A frame's time in consecutive parts, ms: each from one checkpoint of
/// the frame loop to the next, so they add up to [`FrameStatus::frame_ms`]
/// (to rounding).
#[derive(Clone, Copy, Debug, Default, PartialEq, Serialize)]
pub struct FrameParts {
    /// Reading the `EyeState`, the mouse and each view's input.
    pub prepare_ms: f64,
    /// The panorama view re-rendered for a new head orientation (0 when
    /// the head did not move).
    pub view_ms: f64,
    /// A glare kernel the PSF worker built, installed into the pipelines
    /// (0 on most frames).
    pub psf_install_ms: f64,
    /// The pipeline stages (pooling, temporal, PSF, glare, acuity,
    /// tone/colour/encode): every view's, added, where the views run one
    /// after another; the slower view's where they run at once (CPU
    /// stereo).
    pub stages_ms: f64,
    /// The pipeline call's wall time less [`Self::stages_ms`]: uploading
    /// the view, submitting to and waiting for the GPU, and the work
    /// between stages.
    pub render_other_ms: f64,
    /// The pupil light response stepped, adaptation handed back to the
    /// eye task.
    pub pupil_light_ms: f64,
    /// The frame handed on: shown in the window's slot, read back from the
    /// GPU (for the status page and files), the stereo views placed side
    /// by side; a wait on the GPU is here.
    pub present_ms: f64,
}

impl FrameStatus {
    /// A per-view pair as per eye [right, left]: stereo views are [left,
    /// right]; one view stands for both eyes.
    fn per_eye<T: Copy>(&self, per_view: [T; 2]) -> [T; 2] {
        if self.views == 2 {
            [per_view[1], per_view[0]]
        } else {
            [per_view[0], per_view[0]]
        }
    }

    /// The pupil the light predicts per eye [right, left], mm.
    pub fn eye_pupil_light_mm(&self) -> [f32; 2] {
        self.per_eye(self.view_pupil_light_mm)
    }

    /// Measured − predicted pupil per eye [right, left], mm: in stereo
    /// each eye's view's; with one view, each eye's own pupil minus the
    /// one prediction where the view's pupil is measured (else NaN).
    pub fn eye_pupil_residual_mm(&self) -> [f32; 2] {
        if self.views == 2 {
            return self.per_eye(self.view_pupil_residual_mm);
        }
        let light = self.view_pupil_light_mm[0];
        if self.view_pupil_residual_mm[0].is_finite() {
            self.pupil_mm.map(|p| p - light)
        } else {
            [f32::NAN; 2]
        }
    }
}

/// One point of the plotted history.
#[derive(Clone, Copy, Debug, Default, PartialEq, Serialize)]
pub struct HistoryPoint {
    pub t_secs: f64,
    /// [right, left], mm.
    pub pupil_mm: [f32; 2],
    pub adaptation_cd_m2: f64,
    /// Per view ([left, right] in stereo; the second NaN in mono).
    pub view_adaptation_cd_m2: [f64; 2],
    /// The pupil the light predicts per eye [right, left], mm.
    pub pupil_light_mm: [f32; 2],
    pub eye_state_age_ms: f64,
    pub frame_ms: f64,
}

/// A fixed-capacity ring of history points (no allocation after creation).
#[derive(Debug)]
pub struct History {
    points: Vec<HistoryPoint>,
    next: usize,
    len: usize,
}

impl History {
    fn new(capacity: usize) -> Self {
        Self {
            points: vec![HistoryPoint::default(); capacity.max(1)],
            next: 0,
            len: 0,
        }
    }

    /// Appends a point, overwriting the oldest when full.
    pub fn push(&mut self, point: HistoryPoint) {
        let cap = self.points.len();
        self.points[self.next] = point;
        self.next = (self.next + 1) % cap;
        self.len = (self.len + 1).min(cap);
    }

    /// Points in time order, oldest first.
    pub fn iter(&self) -> impl Iterator<Item = &HistoryPoint> {
        let cap = self.points.len();
        let start = (self.next + cap - self.len) % cap;
        (0..self.len).map(move |i| &self.points[(start + i) % cap])
    }

    pub fn len(&self) -> usize {
        self.len
    }

    /// Whether the ring holds no point yet.
    pub fn is_empty(&self) -> bool {
        self.len == 0
    }
}

/// The newest display frame (RGBA8), copied at a limited rate.
#[derive(Debug, Default)]
pub struct FrameSnapshot {
    pub width: usize,
    pub height: usize,
    /// Frame counter of the copy (0 = none yet).
    pub frame: u64,
    pub rgba8: Vec<u8>,
}

/// The glare kernel in use.
#[derive(Debug, Default)]
pub struct PsfSnapshot {
    /// Rebuild counter of the copy (0 = none yet).
    pub rebuild: u64,
    pub pupil_mm: f64,
    /// Side of the square kernel, pixels.
    pub size_px: usize,
    /// Kernel values (luminance channel, sums to ≈ 1), row-major.
    pub values: Vec<f32>,
}

/// Everything a session shares. Cheap to clone through `Arc`.
#[derive(Debug)]
pub struct Hub {
    /// Latest filtered, calibrated eye state (the live eye task writes it).
    pub eye: watch::Receiver<LiveEyeState>,
    /// The samples the live eye task consumed, for recorders and the relay.
    pub samples: broadcast::Sender<Sample>,
    source: SharedStatus,
    frame: Mutex<FrameStatus>,
    history: Mutex<History>,
    latest_frame: Mutex<FrameSnapshot>,
    psf: Mutex<PsfSnapshot>,
    shutdown: watch::Sender<bool>,
    /// Per-frame figures for the LSL frame outlet (set once when
    /// `--lsl` is on): a bounded queue, filled without blocking.
    frame_tap: std::sync::OnceLock<FrameTap>,
    /// Whether a reader of the display frame (the status page) exists:
    /// without one the frame loop publishes no frame (and reads none back).
    display_wanted: std::sync::atomic::AtomicBool,
    /// Every setting of the session and its source (set once at start;
    /// served in the status JSON).
    settings: std::sync::OnceLock<SessionSettings>,
}

/// A frame's figures with the host time it was published at.
pub type TappedFrame = (f64, FrameStatus);

/// The sending end of the frame tap: `try_send` only (a full queue drops
/// the frame and counts it).
#[derive(Debug)]
pub struct FrameTap {
    tx: std::sync::mpsc::SyncSender<TappedFrame>,
    dropped: std::sync::atomic::AtomicU64,
}

impl FrameTap {
    /// Frames dropped because the queue was full.
    pub fn dropped(&self) -> u64 {
        self.dropped.load(std::sync::atomic::Ordering::Relaxed)
    }
}

fn lock<T>(m: &Mutex<T>) -> MutexGuard<'_, T> {
    // A poisoned lock only means a panic elsewhere; the data is plain values.
    m.lock().unwrap_or_else(|p| p.into_inner())
}

impl Hub {
    /// A hub around an eye-state channel (tests, observers without a
    /// live task).
    pub fn new(uri: &str, eye: watch::Receiver<LiveEyeState>) -> Arc<Self> {
        let (samples, _) = broadcast::channel(SAMPLE_BROADCAST_CAPACITY);
        let (shutdown, _) = watch::channel(false);
        let source = Arc::new(Mutex::new(SourceStatus {
            uri: uri.to_owned(),
            ..SourceStatus::default()
        }));
        Self::with_parts(eye, samples, source, shutdown)
    }

    /// The hub of a live eye task; `shutdown` is the sender whose receiver
    /// the task was started with.
    pub fn for_live(live: &LiveEye, shutdown: watch::Sender<bool>) -> Arc<Self> {
        Self::with_parts(
            live.eye.clone(),
            live.samples.clone(),
            live.status.clone(),
            shutdown,
        )
    }

    fn with_parts(
        eye: watch::Receiver<LiveEyeState>,
        samples: broadcast::Sender<Sample>,
        source: SharedStatus,
        shutdown: watch::Sender<bool>,
    ) -> Arc<Self> {
        Arc::new(Self {
            eye,
            samples,
            source,
            frame: Mutex::new(FrameStatus::default()),
            history: Mutex::new(History::new(HISTORY_CAPACITY)),
            latest_frame: Mutex::new(FrameSnapshot::default()),
            psf: Mutex::new(PsfSnapshot::default()),
            shutdown,
            frame_tap: std::sync::OnceLock::new(),
            display_wanted: std::sync::atomic::AtomicBool::new(false),
            settings: std::sync::OnceLock::new(),
        })
    }

    /// Publishes the session's settings (the first call wins).
    pub fn set_settings(&self, settings: SessionSettings) {
        let _ = self.settings.set(settings);
    }

    /// The session's settings, once published.
    pub fn settings(&self) -> Option<&SessionSettings> {
        self.settings.get()
    }

    /// Registers a reader of the display frame (the status page).
    pub fn want_display(&self) {
        self.display_wanted
            .store(true, std::sync::atomic::Ordering::Relaxed);
    }

    /// Whether anyone reads the display frame ([`Self::want_display`]).
    pub fn display_wanted(&self) -> bool {
        self.display_wanted
            .load(std::sync::atomic::Ordering::Relaxed)
    }

    /// Updates the source status in place.
    pub fn update_source(&self, f: impl FnOnce(&mut SourceStatus)) {
        f(&mut lock(&self.source));
    }

    /// A copy of the source status.
    pub fn source(&self) -> SourceStatus {
        lock(&self.source).clone()
    }

    /// Publishes the newest frame's figures and appends a history point.
    pub fn publish_frame(&self, status: FrameStatus) {
        if let Some(tap) = self.frame_tap.get()
            && tap
                .tx
                .try_send((gazelight_tracker::pupil::clock::host_now_secs(), status))
                .is_err()
        {
            tap.dropped
                .fetch_add(1, std::sync::atomic::Ordering::Relaxed);
        }
        *lock(&self.frame) = status;
        lock(&self.history).push(HistoryPoint {
            t_secs: status.t_secs,
            pupil_mm: status.pupil_mm,
            adaptation_cd_m2: status.adaptation_cd_m2,
            view_adaptation_cd_m2: status.view_adaptation_cd_m2,
            pupil_light_mm: status.pupil_light_mm,
            eye_state_age_ms: status.eye_state_age_ms,
            frame_ms: status.frame_ms,
        });
    }

    /// Opens the frame tap (once): every published frame is also queued
    /// (bounded by `capacity`; a full queue drops and counts). `None` when
    /// a tap is already open.
    pub fn open_frame_tap(
        &self,
        capacity: usize,
    ) -> Option<std::sync::mpsc::Receiver<TappedFrame>> {
        let (tx, rx) = std::sync::mpsc::sync_channel(capacity.max(1));
        self.frame_tap
            .set(FrameTap {
                tx,
                dropped: std::sync::atomic::AtomicU64::new(0),
            })
            .ok()?;
        Some(rx)
    }

    /// The frame tap, when open.
    pub fn frame_tap(&self) -> Option<&FrameTap> {
        self.frame_tap.get()
    }

    /// The newest frame's figures.
    pub fn frame(&self) -> FrameStatus {
        *lock(&self.frame)
    }

    /// Read access to the history ring.
    pub fn with_history<R>(&self, f: impl FnOnce(&History) -> R) -> R {
        f(&lock(&self.history))
    }

    /// Copies a display frame into the snapshot (reuses its buffer).
    pub fn publish_display(&self, frame: u64, width: usize, height: usize, rgba8: &[u8]) {
        let mut snap = lock(&self.latest_frame);
        snap.width = width;
        snap.height = height;
        snap.frame = frame;
        snap.rgba8.clear();
        snap.rgba8.extend_from_slice(rgba8);
    }

    /// Read access to the newest display frame.
    pub fn with_display<R>(&self, f: impl FnOnce(&FrameSnapshot) -> R) -> R {
        f(&lock(&self.latest_frame))
    }

    /// Copies the glare kernel in use (after a rebuild).
    pub fn publish_psf(&self, rebuild: u64, pupil_mm: f64, size_px: usize, values: &[f32]) {
        let mut snap = lock(&self.psf);
        snap.rebuild = rebuild;
        snap.pupil_mm = pupil_mm;
        snap.size_px = size_px;
        snap.values.clear();
        snap.values.extend_from_slice(values);
    }

    /// Read access to the kernel in use.
    pub fn with_psf<R>(&self, f: impl FnOnce(&PsfSnapshot) -> R) -> R {
        f(&lock(&self.psf))
    }

    /// Asks every task of the session to stop (Ctrl-C, end of replay).
    pub fn request_shutdown(&self) {
        self.shutdown.send_replace(true);
    }

    /// Whether shutdown was requested.
    pub fn shutting_down(&self) -> bool {
        *self.shutdown.borrow()
    }

    /// A receiver that changes to `true` on shutdown.
    pub fn shutdown_signal(&self) -> watch::Receiver<bool> {
        self.shutdown.subscribe()
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn history_ring_keeps_newest_in_order() {
        let mut h = History::new(3);
        for i in 0..5 {
            h.push(HistoryPoint {
                t_secs: i as f64,
                ..HistoryPoint::default()
            });
        }
        let ts: Vec<f64> = h.iter().map(|p| p.t_secs).collect();
        assert_eq!(ts, vec![2.0, 3.0, 4.0]);
        assert_eq!(h.len(), 3);
    }

    #[test]
    fn snapshots_reuse_their_buffers() {
        let (_tx, rx) = watch::channel(LiveEyeState::default());
        let hub = Hub::new("test://", rx);
        let px = vec![7u8; 16];
        hub.publish_display(1, 2, 2, &px);
        let cap = hub.with_display(|s| s.rgba8.capacity());
        hub.publish_display(2, 2, 2, &px);
        hub.with_display(|s| {
            assert_eq!(s.frame, 2);
            assert_eq!(s.rgba8, px);
            assert_eq!(s.rgba8.capacity(), cap);
        });
    }
}
