//! Outputs of a live run (`--out DIR`), written on their own thread so the
//! frame loop never touches a file:
//!
//! - `timeline.csv`: one row per frame (streamed, so memory stays bounded);
//! - `frames/frame_NNNNNN.png`: the display frames, through a fixed pool of
//!   frame buffers, encoded (fdeflate) on a second thread at idle priority
//!   (`SCHED_IDLE`) so it only takes cores the frame loop leaves free —
//!   when the encoder falls behind, a frame's image is skipped (counted),
//!   never queued without bound;
//! - `psf.csv`: one row per glare kernel installed (the initial one and
//!   every rebuild): the pupil it was built for and the radius of the first
//!   dark ring of its monochromatic PSF at the reference wavelength (001
//!   eq 8), which for a clear circular pupil is 1.22 λ / D — it follows the
//!   live pupil. For rebuilds the ring is the one the PSF worker measured
//!   on the 575 nm field its builder made that kernel from
//!   (`PsfBuilder::first_ring_rad`); for the initial kernel (built by the
//!   pipeline) it is computed from the kernel's parameters
//!   ([`MonoPsf::first_minimum_rad`]).
//!
//! - `events.csv`: the events the live source carries (Pupil Capture's
//!   annotations) and the `--events` marker streams, one row each with
//!   replay's `events.csv` columns ([`crate::EVENTS_COLUMNS`]):
//!   `t_secs` on the run's clock (timeline.csv's), `recording_t_secs` the
//!   host clock the live samples are on, `t_clock` the source's own stamp,
//!   and `frame`, the newest frame whose `t_secs` is at or before the
//!   event's. The sources put them in a bounded [`EventQueue`] (a flood is
//!   dropped and counted there) that this thread drains at every message
//!   and at least every second; an event waits (bounded) for the frame
//!   after it, so its frame is known when it is written.
//!
//! The frame loop hands rows, frames and kernel events over bounded
//! `sync_channel`s (preallocated ring buffers: sending does not allocate).
//!
//! The CSV files only ever hold whole rows (`RowFile`): rows are buffered
//! whole and written at each flush (at least every second); a write error
//! (a full disk) cuts the file back to its last complete row, stops that
//! file only, and is printed at once. A frame image that cannot be written
//! is removed and the images stop. The errors are in [`WriterReport::errors`]
//! for the summary.

use std::collections::VecDeque;
use std::fmt::Write as _;
use std::path::{Path, PathBuf};
use std::sync::Arc;
use std::sync::mpsc::{
    Receiver, RecvTimeoutError, SyncSender, TryRecvError, TrySendError, sync_channel,
};
use std::thread::JoinHandle;

use gazelight_render::frame::View;
use gazelight_render::rows::RowFile;
use gazelight_vision::pipeline::DisplayFrame;
use gazelight_vision::psf::{MonoPsf, PsfParams, REFERENCE_WAVELENGTH_NM, monochromatic_psf};

use crate::sheet::{self, PngCompression};
use gazelight_tracker::EYE_LEFT;
use gazelight_tracker::live::SourceHealth;
use gazelight_tracker::live_events::{EventQueue, LiveEvent};

/// Why the live writer did not start, or did not finish.
#[derive(Debug, thiserror::Error)]
pub enum LiveError {
    /// `--out` or its `frames/` could not be created.
    #[error("cannot create {}", path.display())]
    CreateDir {
        path: PathBuf,
        #[source]
        source: std::io::Error,
    },
    /// A CSV file could not be created: its [`RowFile`] failure message.
    #[error("{0}")]
    CreateFile(String),
    /// A thread could not be started (`what`: "writer", "frame encoder").
    #[error("cannot start the {what} thread")]
    Spawn {
        what: &'static str,
        #[source]
        source: std::io::Error,
    },
    /// A thread panicked (`what`: "output writer", "frame encoder").
    #[error("the {what} thread panicked")]
    Panicked { what: &'static str },
}

use crate::error_chain as chain;

/// Frame buffers in flight between the loop and the PNG encoder.
const FRAME_POOL: usize = 4;
/// Rows/events queued before the loop starts dropping them (counted).
const QUEUE: usize = 4096;
/// The files are flushed at least this often (whole rows only).
const FLUSH_EVERY: std::time::Duration = std::time::Duration::from_secs(1);

/// One row of the live `timeline.csv`.
#[derive(Clone, Copy, Debug, Default)]
pub struct Row {
    pub frame: u64,
    pub t_secs: f64,
    /// The measured pupil per eye, [right, left], mm; NaN (an empty cell)
    /// where the eye is not measured now or has no physical scale.
    pub pupil_mm: [f32; 2],
    /// Nothing measured for any eye the source has.
    pub pupil_held: bool,
    pub eye_state_age_ms: f64,
    pub health: SourceHealth,
    /// Per view: the one view, or left and right (stereo).
    pub views: [ViewRow; 2],
    pub frame_ms: f64,
}

/// What one view of a frame used and did.
#[derive(Clone, Copy, Debug, Default)]
pub struct ViewRow {
    pub gaze_u: f32,
    pub gaze_v: f32,
    /// Aperture the view used (the glare PSF's pupil), mm.
    pub frame_pupil_mm: f32,
    pub target_cd_m2: f64,
    pub adaptation_cd_m2: f64,
    pub psf_pupil_mm: f64,
    pub psf_rebuilt: bool,
    /// The pupil the light predicts, mm (docs/pupil-light-response.md).
    pub pupil_light_mm: f32,
    /// Measured − predicted pupil, mm; NaN (a blank cell) where the pupil
    /// is not measured.
    pub pupil_residual_mm: f32,
}

const HEADER: &str = "frame,t_secs,gaze_u,gaze_v,pupil_right_mm,pupil_left_mm,aperture_mm,pupil_held,eye_state_age_ms,source_health,target_cd_m2,adaptation_cd_m2,psf_pupil_mm,psf_rebuilt,frame_ms,pupil_light_mm,pupil_residual_mm";
/// A stereo run's header: per-view columns suffixed `_left`, `_right`.
const STEREO_HEADER: &str = "frame,t_secs,pupil_right_mm,pupil_left_mm,pupil_held,eye_state_age_ms,source_health,\
gaze_u_left,gaze_v_left,aperture_mm_left,target_cd_m2_left,adaptation_cd_m2_left,psf_pupil_mm_left,psf_rebuilt_left,\
gaze_u_right,gaze_v_right,aperture_mm_right,target_cd_m2_right,adaptation_cd_m2_right,psf_pupil_mm_right,psf_rebuilt_right,frame_ms,\
pupil_light_mm_left,pupil_residual_mm_left,pupil_light_mm_right,pupil_residual_mm_right";

fn health_name(h: SourceHealth) -> &'static str {
    match h {
        SourceHealth::Connecting => "connecting",
        SourceHealth::Live => "live",
        SourceHealth::Degraded => "degraded",
        SourceHealth::Lost => "lost",
        SourceHealth::Ended => "ended",
    }
}

/// A kernel installed: generation (1 = the initial kernel), time, pupil,
/// and the first dark ring measured on the field it was built from (`None`:
/// compute it from the parameters; NaN: no minimum found).
#[derive(Clone, Copy, Debug)]
pub struct PsfEvent {
    pub generation: u64,
    pub t_secs: f64,
    pub pupil_mm: f64,
    pub first_ring_rad: Option<f64>,
    /// The view the kernel is for (`psf.csv`'s `view`: both, left, right).
    pub view: View,
}

enum Msg {
    Row(Row),
    Psf(PsfEvent),
    Xr(XrRow),
    /// The host time (s) of the run clock's zero (`t_secs` = 0).
    ClockOrigin(f64),
}

/// One row of `xr.csv` (an OpenXR session's frame, `run --display xr`).
#[derive(Clone, Copy, Debug, Default)]
pub struct XrRow {
    pub frame: u64,
    /// The runtime's predicted display time (XrTime), ns.
    pub predicted_display_time_ns: i64,
    /// The same on the host clock, s.
    pub display_host_secs: f64,
    /// The `EyeState`'s age at that time, ms.
    pub eye_state_age_ms: f64,
    /// Per eye (left, right): position (m) then orientation (x, y, z, w).
    pub poses: [[f32; 7]; 2],
    /// The left view's gaze.
    pub gaze_uv_left: [f32; 2],
    /// The left view's pooled luminance, cd/m².
    pub target_cd_m2_left: f64,
    /// Each view's mean luminance (what the head's pose shows), cd/m².
    pub view_mean_cd_m2: [f64; 2],
}

const PSF_HEADER: &str =
    "generation,t_secs,pupil_mm,wavelength_nm,first_ring_rad,first_ring_arcmin,view";

const XR_HEADER: &str = "frame,predicted_display_time_ns,display_host_secs,eye_state_age_ms,\
left_x_m,left_y_m,left_z_m,left_qx,left_qy,left_qz,left_qw,\
right_x_m,right_y_m,right_z_m,right_qx,right_qy,right_qz,right_qw,\
gaze_u_left,gaze_v_left,target_cd_m2_left,view_mean_cd_m2_left,view_mean_cd_m2_right";

/// Formats one `xr.csv` row (with its newline) into `w`.
fn format_xr(w: &mut String, r: &XrRow) {
    let _ = write!(
        w,
        "{},{},{:.6},{:.3}",
        r.frame, r.predicted_display_time_ns, r.display_host_secs, r.eye_state_age_ms
    );
    for pose in &r.poses {
        for (i, v) in pose.iter().enumerate() {
            let _ = if i < 3 {
                write!(w, ",{v:.5}")
            } else {
                write!(w, ",{v:.6}")
            };
        }
    }
    let _ = writeln!(
        w,
        ",{:.5},{:.5},{:.6e},{:.6e},{:.6e}",
        r.gaze_uv_left[0],
        r.gaze_uv_left[1],
        r.target_cd_m2_left,
        r.view_mean_cd_m2[0],
        r.view_mean_cd_m2[1]
    );
}

/// What the writer did.
#[derive(Clone, Debug, Default)]
pub struct WriterReport {
    /// `timeline.csv` rows on disk (whole rows).
    pub rows: u64,
    pub frames_written: u64,
    /// `psf.csv` rows on disk.
    pub psf_rows: u64,
    /// `events.csv` rows on disk (`None`: no events were read).
    pub events: Option<u64>,
    /// Events dropped: the sources' queue full, or waiting for the run's
    /// clock too long.
    pub events_dropped: u64,
    /// Write errors (a full disk): each names the file, the error and where
    /// the file stops; each was printed when it happened.
    pub errors: Vec<String>,
}

/// What the PNG encoder thread did.
#[derive(Debug, Default)]
struct FramesReport {
    written: u64,
    error: Option<String>,
}

/// Prints a write error when it happens (stderr and the log): the run
/// goes on, so the user learns of it now, not at the end.
fn report_write_error(msg: &str) {
    tracing::error!("{msg}; the run goes on");
    eprintln!("error: --out: {msg}; the run goes on");
}

/// The writer thread's handle (owned by the frame loop).
pub struct OutputWriter {
    tx: Option<SyncSender<Msg>>,
    /// To the PNG encoder thread: at most [`FRAME_POOL`] frames, as many
    /// as there are buffers, so a send finds room whenever a buffer was free.
    frame_tx: Option<SyncSender<(u64, DisplayFrame)>>,
    pool: Receiver<DisplayFrame>,
    thread: Option<JoinHandle<WriterReport>>,
    encoder: Option<JoinHandle<FramesReport>>,
    write_frames: bool,
    /// Rows or events dropped because the queue was full.
    pub dropped: u64,
    /// Frames whose image was not written because no buffer was free.
    pub frames_skipped: u64,
}

impl OutputWriter {
    /// Creates `dir` (and `frames/`), opens the files and starts the
    /// thread. `psf` are the kernel parameters (ppd set) for `psf.csv`.
    pub fn start(
        dir: &Path,
        width: usize,
        height: usize,
        psf: PsfParams,
        write_frames: bool,
        stereo: bool,
        events: Option<Arc<EventQueue>>,
    ) -> Result<Self, LiveError> {
        let create_dir = |path: &Path| {
            std::fs::create_dir_all(path).map_err(|source| LiveError::CreateDir {
                path: path.to_owned(),
                source,
            })
        };
        create_dir(dir)?;
        let frames_dir = dir.join("frames");
        if write_frames {
            create_dir(&frames_dir)?;
        }
        // The headers are on disk before the session starts; a file that
        // cannot be created is an error now, before anything runs.
        let timeline_path = dir.join("timeline.csv");
        let mut timeline = RowFile::create(
            &timeline_path,
            if stereo { STEREO_HEADER } else { HEADER },
            report_write_error,
        );
        timeline.flush();
        let psf_path = dir.join("psf.csv");
        let mut psf_csv = RowFile::create(&psf_path, PSF_HEADER, report_write_error);
        psf_csv.flush();
        let mut events = events.map(|queue| {
            let mut file = RowFile::create(
                &dir.join("events.csv"),
                &crate::EVENTS_COLUMNS.join(","),
                report_write_error,
            );
            file.flush();
            LiveEvents::new(queue, file)
        });
        for f in [
            Some(&timeline),
            Some(&psf_csv),
            events.as_ref().map(|e| &e.file),
        ]
        .into_iter()
        .flatten()
        {
            if let Some(e) = f.failure() {
                return Err(LiveError::CreateFile(e.to_owned()));
            }
        }
        let xr_path = dir.join("xr.csv");
        let (tx, rx) = sync_channel::<Msg>(QUEUE);
        let (pool_tx, pool) = sync_channel::<DisplayFrame>(FRAME_POOL);
        for _ in 0..FRAME_POOL {
            let _ = pool_tx.try_send(DisplayFrame::new(width, height));
        }
        // The PNG encoder has its own thread at idle priority (see
        // `lower_this_threads_priority`); rows and kernels stay on the
        // writer thread, so their one-second flush never waits on an image.
        let (frame_tx, frame_rx) = sync_channel::<(u64, DisplayFrame)>(FRAME_POOL);
        let encoder = if write_frames {
            Some(
                std::thread::Builder::new()
                    .name("gazelight-png".into())
                    .spawn(move || -> FramesReport {
                        lower_this_threads_priority();
                        let mut report = FramesReport::default();
                        for (i, frame) in frame_rx {
                            let p = frames_dir.join(format!("frame_{i:06}.png"));
                            let r = sheet::write_png(&p, &frame, PngCompression::Fast);
                            let _ = pool_tx.try_send(frame);
                            if let Err(e) = r {
                                // No torn image stays behind; the frames
                                // stop here, the rest of the run goes on.
                                let _ = std::fs::remove_file(&p);
                                let msg = format!(
                                    "{}; frames/ stops after {} images (the partial {} removed)",
                                    chain(&e),
                                    report.written,
                                    p.display()
                                );
                                report_write_error(&msg);
                                report.error = Some(msg);
                                break;
                            }
                            report.written += 1;
                        }
                        report
                    })
                    .map_err(|source| LiveError::Spawn {
                        what: "frame encoder",
                        source,
                    })?,
            )
        } else {
            None
        };
        let thread = std::thread::Builder::new()
            .name("gazelight-writer".into())
            .spawn(move || -> WriterReport {
                let mut report = WriterReport::default();
                // Opened with the first OpenXR row.
                let mut xr_csv: Option<RowFile> = None;
                // Rows are formatted here and handed to the file whole, and
                // the files are flushed at least every `FLUSH_EVERY`: the
                // files only ever hold complete rows, up to a second old,
                // whatever ends the process (a full disk included).
                let mut line = String::with_capacity(256);
                let mut last_flush = std::time::Instant::now();
                loop {
                    let msg = match rx.recv_timeout(FLUSH_EVERY) {
                        Ok(m) => Some(m),
                        Err(RecvTimeoutError::Timeout) => None,
                        Err(RecvTimeoutError::Disconnected) => break,
                    };
                    if let Some(ev) = &mut events {
                        if let Some(Msg::Row(r)) = &msg {
                            ev.frame(r.frame, r.t_secs);
                        }
                        if let Some(Msg::ClockOrigin(host)) = &msg {
                            ev.origin_host_secs = Some(*host);
                        }
                        ev.take(&mut line, false);
                    }
                    if last_flush.elapsed() >= FLUSH_EVERY {
                        last_flush = std::time::Instant::now();
                        timeline.flush();
                        psf_csv.flush();
                        if let Some(x) = &mut xr_csv {
                            x.flush();
                        }
                        if let Some(ev) = &mut events {
                            ev.file.flush();
                        }
                    }
                    let Some(msg) = msg else { continue };
                    match msg {
                        Msg::ClockOrigin(_) => {}
                        Msg::Row(r) => {
                            line.clear();
                            format_row(&mut line, &r, stereo);
                            timeline.push(&line);
                        }
                        Msg::Psf(ev) => {
                            let ring = ev.first_ring_rad.unwrap_or_else(|| {
                                let mut params = psf.clone();
                                params.pupil_mm = ev.pupil_mm;
                                monochromatic_psf(&params, REFERENCE_WAVELENGTH_NM)
                                    .ok()
                                    .as_ref()
                                    .and_then(MonoPsf::first_minimum_rad)
                                    .unwrap_or(f64::NAN)
                            });
                            line.clear();
                            let _ = writeln!(
                                line,
                                "{},{:.4},{:.4},{},{:.6e},{:.4},{}",
                                ev.generation,
                                ev.t_secs,
                                ev.pupil_mm,
                                REFERENCE_WAVELENGTH_NM,
                                ring,
                                ring.to_degrees() * 60.0,
                                match ev.view {
                                    View::Both => "both",
                                    View::Eye(EYE_LEFT) => "left",
                                    View::Eye(_) => "right",
                                }
                            );
                            psf_csv.push(&line);
                        }
                        Msg::Xr(r) => {
                            let x = match &mut xr_csv {
                                Some(x) => x,
                                slot => slot.insert(RowFile::create(
                                    &xr_path,
                                    XR_HEADER,
                                    report_write_error,
                                )),
                            };
                            line.clear();
                            format_xr(&mut line, &r);
                            x.push(&line);
                        }
                    }
                }
                if let Some(ev) = &mut events {
                    ev.take(&mut line, true);
                    report.events_dropped = ev.dropped + ev.queue.dropped();
                }
                let events_file = events.as_mut().map(|e| &mut e.file);
                for f in [
                    Some(&mut timeline),
                    Some(&mut psf_csv),
                    xr_csv.as_mut(),
                    events_file,
                ]
                .into_iter()
                .flatten()
                {
                    f.flush();
                }
                report.rows = timeline.rows_on_disk();
                report.psf_rows = psf_csv.rows_on_disk();
                if let Some(ev) = &events {
                    report.events = Some(ev.file.rows_on_disk());
                }
                report.errors.extend(
                    [
                        Some(&timeline),
                        Some(&psf_csv),
                        xr_csv.as_ref(),
                        events.as_ref().map(|e| &e.file),
                    ]
                    .into_iter()
                    .flatten()
                    .filter_map(|f| f.failure().map(str::to_owned)),
                );
                report
            })
            .map_err(|source| LiveError::Spawn {
                what: "writer",
                source,
            })?;
        Ok(Self {
            tx: Some(tx),
            frame_tx: Some(frame_tx),
            pool,
            thread: Some(thread),
            encoder,
            write_frames,
            dropped: 0,
            frames_skipped: 0,
        })
    }

    fn send(&mut self, msg: Msg) -> Option<Msg> {
        let tx = self.tx.as_ref()?;
        match tx.try_send(msg) {
            Ok(()) => None,
            Err(TrySendError::Full(m)) | Err(TrySendError::Disconnected(m)) => {
                self.dropped += 1;
                Some(m)
            }
        }
    }

    /// Queues a timeline row (never blocks).
    pub fn row(&mut self, row: Row) {
        let _ = self.send(Msg::Row(row));
    }

    /// Sets the run clock's zero (`t_secs` = 0) at host time `host_secs`:
    /// the frame loop's start, which `events.csv` counts from.
    pub fn clock_origin(&mut self, host_secs: f64) {
        let _ = self.send(Msg::ClockOrigin(host_secs));
    }

    /// Queues an `xr.csv` row (never blocks).
    pub fn xr(&mut self, row: XrRow) {
        let _ = self.send(Msg::Xr(row));
    }

    /// Queues a kernel event (never blocks).
    pub fn psf(&mut self, ev: PsfEvent) {
        let _ = self.send(Msg::Psf(ev));
    }

    /// Whether the writer takes frame images (`--out` without `--no-frames`).
    pub fn wants_frames(&self) -> bool {
        self.write_frames
    }

    /// Copies the frame into a free pool buffer and queues it; skips it
    /// when none is free (never blocks, never allocates).
    pub fn frame(&mut self, index: u64, frame: &DisplayFrame) {
        if !self.write_frames {
            return;
        }
        match self.pool.try_recv() {
            Ok(mut buf) if buf.rgba8.len() == frame.rgba8.len() => {
                buf.rgba8.copy_from_slice(&frame.rgba8);
                match self.frame_tx.as_ref().map(|tx| tx.try_send((index, buf))) {
                    Some(Ok(())) => {}
                    // The encoder stopped (a write error, printed there):
                    // no more images are taken, or read back.
                    Some(Err(TrySendError::Disconnected(_))) | None => self.write_frames = false,
                    // No room: the image is skipped.
                    Some(Err(TrySendError::Full(_))) => self.frames_skipped += 1,
                }
            }
            Err(TryRecvError::Disconnected) => self.write_frames = false,
            Ok(_) | Err(TryRecvError::Empty) => self.frames_skipped += 1,
        }
    }

    /// Flushes everything and joins the thread.
    pub fn finish(mut self) -> Result<WriterReport, LiveError> {
        self.tx = None;
        self.frame_tx = None;
        // Both threads are joined before either's error is returned: the
        // images already queued are written whatever the rows' fate.
        let rows = self.thread.take().map(|t| {
            t.join().map_err(|_| LiveError::Panicked {
                what: "output writer",
            })
        });
        let images = self.encoder.take().map(|e| {
            e.join().map_err(|_| LiveError::Panicked {
                what: "frame encoder",
            })
        });
        let mut report = rows.transpose()?.unwrap_or_default();
        if let Some(frames) = images.transpose()? {
            report.frames_written = frames.written;
            report.errors.extend(frames.error);
        }
        Ok(report)
    }
}

/// Frames remembered for placing late events (about 45 s at 90 Hz).
const FRAMES_KEPT: usize = 4096;

/// The live `events.csv` on the writer thread: the events drained from the
/// sources' queue wait here for the run clock's zero and for a frame after
/// them, then are written in arrival order.
struct LiveEvents {
    queue: Arc<EventQueue>,
    file: RowFile,
    /// Host time of `t_secs` = 0, once the frame loop started.
    origin_host_secs: Option<f64>,
    /// Drained, not yet written (at most [`QUEUE`]; more are dropped).
    pending: VecDeque<LiveEvent>,
    drained: Vec<LiveEvent>,
    /// The newest frames: (frame, t_secs), oldest first.
    frames: VecDeque<(u64, f64)>,
    dropped: u64,
}

impl LiveEvents {
    fn new(queue: Arc<EventQueue>, file: RowFile) -> Self {
        Self {
            queue,
            file,
            origin_host_secs: None,
            pending: VecDeque::with_capacity(256),
            drained: Vec::with_capacity(256),
            frames: VecDeque::with_capacity(FRAMES_KEPT),
            dropped: 0,
        }
    }

    /// A frame was rendered at run time `t_secs`.
    fn frame(&mut self, frame: u64, t_secs: f64) {
        if self.frames.len() == FRAMES_KEPT {
            self.frames.pop_front();
        }
        self.frames.push_back((frame, t_secs));
    }

    /// The newest frame at or before run time `t` (`None`: before the
    /// first frame, or older than the frames kept). At the end
    /// (`finishing`) an event after the last frame is on it when it lies
    /// within one frame interval of it.
    fn frame_at(&self, t: f64, finishing: bool) -> Option<u64> {
        let k = self.frames.partition_point(|&(_, ft)| ft <= t);
        if k == 0 {
            return None;
        }
        let (frame, ft) = self.frames[k - 1];
        if k == self.frames.len() && finishing {
            let interval = self
                .frames
                .len()
                .checked_sub(2)
                .map_or(0.0, |i| ft - self.frames[i].1);
            return (t - ft < interval).then_some(frame);
        }
        Some(frame)
    }

    /// Drains the queue and writes every pending event whose frame is
    /// known (a frame after it exists), or all of them when `finishing`.
    fn take(&mut self, line: &mut String, finishing: bool) {
        self.queue.drain_into(&mut self.drained);
        for e in self.drained.drain(..) {
            if self.pending.len() >= QUEUE {
                self.dropped += 1;
            } else {
                self.pending.push_back(e);
            }
        }
        let Some(origin) = self.origin_host_secs else {
            // No frame ever ran: the events on the host clock alone.
            if finishing {
                while let Some(e) = self.pending.pop_front() {
                    write_event(line, &e, f64::NAN, None);
                    self.file.push(line);
                }
            }
            return;
        };
        let newest = self.frames.back().map(|&(_, t)| t);
        while let Some(e) = self.pending.front() {
            let t = e.host_secs - origin;
            if !finishing && newest.is_none_or(|n| n <= t) {
                break;
            }
            let frame = self.frame_at(t, finishing);
            write_event(line, e, t, frame);
            self.file.push(line);
            self.pending.pop_front();
        }
    }
}

/// Formats one `events.csv` row (with its newline) into `w`; a NaN run
/// time (no frame ever ran) is a blank cell.
fn write_event(w: &mut String, e: &LiveEvent, t_secs: f64, frame: Option<u64>) {
    use gazelight_input::csv_field;
    w.clear();
    if t_secs.is_finite() {
        let _ = write!(w, "{t_secs:.6}");
    }
    let _ = write!(w, ",{:.6},{:.6},", e.host_secs, e.source_secs);
    if let Some(d) = e.duration_secs {
        let _ = write!(w, "{d:.6}");
    }
    let _ = write!(w, ",{},{},", csv_field(&e.source), csv_field(&e.text));
    if let Some(f) = frame {
        let _ = write!(w, ",{f}");
    } else {
        w.push(',');
    }
    w.push('\n');
}

/// Formats one timeline row (with its newline) into `w`: the one view's
/// columns, or (stereo) the left then the right view's.
fn format_row(w: &mut String, r: &Row, stereo: bool) {
    let [v, right] = &r.views;
    if !stereo {
        let _ = writeln!(
            w,
            "{},{:.4},{:.5},{:.5},{},{},{:.4},{},{:.3},{},{:.6e},{:.6e},{:.4},{},{:.3},{},{}",
            r.frame,
            r.t_secs,
            v.gaze_u,
            v.gaze_v,
            Mm(r.pupil_mm[0]),
            Mm(r.pupil_mm[1]),
            v.frame_pupil_mm,
            u8::from(r.pupil_held),
            r.eye_state_age_ms,
            health_name(r.health),
            v.target_cd_m2,
            v.adaptation_cd_m2,
            v.psf_pupil_mm,
            u8::from(v.psf_rebuilt),
            r.frame_ms,
            Mm(v.pupil_light_mm),
            Mm(v.pupil_residual_mm),
        );
        return;
    }
    let _ = write!(
        w,
        "{},{:.4},{},{},{},{:.3},{}",
        r.frame,
        r.t_secs,
        Mm(r.pupil_mm[0]),
        Mm(r.pupil_mm[1]),
        u8::from(r.pupil_held),
        r.eye_state_age_ms,
        health_name(r.health),
    );
    for v in [v, right] {
        let _ = write!(
            w,
            ",{:.5},{:.5},{:.4},{:.6e},{:.6e},{:.4},{}",
            v.gaze_u,
            v.gaze_v,
            v.frame_pupil_mm,
            v.target_cd_m2,
            v.adaptation_cd_m2,
            v.psf_pupil_mm,
            u8::from(v.psf_rebuilt),
        );
    }
    let _ = write!(w, ",{:.3}", r.frame_ms);
    for v in [v, right] {
        let _ = write!(w, ",{},{}", Mm(v.pupil_light_mm), Mm(v.pupil_residual_mm));
    }
    let _ = writeln!(w);
}

/// A pupil cell: 4 decimals, blank when not finite (no allocation).
struct Mm(f32);

impl std::fmt::Display for Mm {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        if self.0.is_finite() {
            write!(f, "{:.4}", self.0)
        } else {
            Ok(())
        }
    }
}

/// Puts the calling thread (the PNG encoder) in Linux's `SCHED_IDLE`
/// class: it runs when the frame loop leaves a core free, so on a busy
/// machine the frames it cannot take are skipped and counted
/// (`frames_skipped`) instead of the encoder taking the frame loop's
/// cores. Measured (BENCHMARKS.md): a nice of 10 still cost the stereo run
/// ~5 ms a frame. Moving one's own thread to `SCHED_IDLE` needs no
/// privilege. A failure only costs frame time, so it is logged and ignored.
fn lower_this_threads_priority() {
    #[cfg(target_os = "linux")]
    {
        // SAFETY: a plain system call on the calling thread (pid 0).
        let rc = unsafe {
            let param = libc::sched_param { sched_priority: 0 };
            libc::sched_setscheduler(0, libc::SCHED_IDLE, &param)
        };
        if rc != 0 {
            tracing::debug!(
                "frame encoder: cannot lower the thread's priority: {}",
                std::io::Error::last_os_error()
            );
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn live_events_land_on_the_frame_at_or_before_them_and_a_flood_is_counted() {
        let dir =
            std::env::temp_dir().join(format!("gazelight-writer-events-{}", std::process::id()));
        let _ = std::fs::remove_dir_all(&dir);
        let queue = Arc::new(EventQueue::new(4));
        let mut w = OutputWriter::start(
            &dir,
            8,
            8,
            PsfParams::default(),
            false,
            false,
            Some(queue.clone()),
        )
        .expect("writer");
        let origin = 100.0;
        let ev = |t: f64, text: &str| LiveEvent::new(origin + t, 5000.0 + t, None, "m", text);
        // Before the clock starts: waits for it.
        assert!(queue.push(ev(-0.05, "early")));
        w.clock_origin(origin);
        for (i, t) in [0.0, 0.1, 0.2].into_iter().enumerate() {
            w.row(Row {
                frame: i as u64,
                t_secs: t,
                ..Row::default()
            });
        }
        assert!(queue.push(ev(0.15, "mid, quoted")));
        assert!(queue.push(ev(0.2, "on frame 2")));
        // After the last frame: within one frame interval → the last
        // frame; beyond → none.
        assert!(queue.push(ev(0.25, "late")));
        // The queue holds 4: a fifth is dropped and counted.
        assert!(!queue.push(ev(0.26, "flood")));
        let report = w.finish().expect("finish");
        assert_eq!(report.events, Some(4));
        assert_eq!(report.events_dropped, 1);
        let text = std::fs::read_to_string(dir.join("events.csv")).expect("events.csv");
        let rows: Vec<Vec<String>> = text
            .lines()
            .skip(1)
            .map(|l| gazelight_input::split_csv_line(l, ','))
            .collect();
        let got: Vec<(&str, &str, &str)> = rows
            .iter()
            .map(|r| (r[0].as_str(), r[5].as_str(), r[7].as_str()))
            .collect();
        assert_eq!(
            got,
            [
                ("-0.050000", "early", ""),
                ("0.150000", "mid, quoted", "1"),
                ("0.200000", "on frame 2", "2"),
                ("0.250000", "late", "2"),
            ]
        );
        // The host clock and the source's own stamp.
        assert_eq!(rows[1][1], "100.150000");
        assert_eq!(rows[1][2], "5000.150000");
        let _ = std::fs::remove_dir_all(&dir);
    }
}
