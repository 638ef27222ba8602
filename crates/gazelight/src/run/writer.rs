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
//! The frame loop hands rows, frames and kernel events over bounded
//! `sync_channel`s (preallocated ring buffers: sending does not allocate).
//!
//! The CSV files only ever hold whole rows (`RowFile`): rows are buffered
//! whole and written at each flush (at least every second); a write error
//! (a full disk) cuts the file back to its last complete row, stops that
//! file only, and is printed at once. A frame image that cannot be written
//! is removed and the images stop. The errors are in [`WriterReport::errors`]
//! for the summary.

use std::fmt::Write as _;
use std::io::Write;
use std::path::Path;
use std::sync::mpsc::{
    Receiver, RecvTimeoutError, SyncSender, TryRecvError, TrySendError, sync_channel,
};
use std::thread::JoinHandle;

use anyhow::Context;
use gazelight_vision::pipeline::DisplayFrame;
use gazelight_vision::psf::{MonoPsf, PsfParams, REFERENCE_WAVELENGTH_NM, monochromatic_psf};

use crate::output;
use crate::stereo::View;
use gazelight_tracker::EYE_LEFT;
use gazelight_tracker::live::SourceHealth;

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

/// Size of a [`RowFile`]'s buffer before it writes (it also writes at
/// every flush).
const ROW_BUFFER_BYTES: usize = 64 << 10;

/// A CSV file that only ever holds whole rows. Rows are collected in a
/// buffer and written at each flush; on a write error (a full disk) the
/// file is cut back to its last complete row (`set_len`), the error is
/// printed at once, and the file takes no more rows — the run and the other
/// files go on.
struct RowFile {
    path: std::path::PathBuf,
    file: Option<std::fs::File>,
    buf: Vec<u8>,
    /// Bytes and rows on disk, all of them whole rows (the header is not
    /// a row).
    bytes_on_disk: u64,
    rows_on_disk: u64,
    /// Rows waiting in `buf` (the header is not one).
    rows_pending: u64,
    failure: Option<String>,
}

impl RowFile {
    /// Creates the file with its header line queued (written at the first
    /// flush). A failure is kept (see [`Self::failure`]), not returned.
    fn create(path: &Path, header: &str) -> Self {
        let mut f = Self {
            path: path.to_owned(),
            file: None,
            buf: Vec::with_capacity(ROW_BUFFER_BYTES),
            bytes_on_disk: 0,
            rows_on_disk: 0,
            rows_pending: 0,
            failure: None,
        };
        match std::fs::File::create(path) {
            Ok(file) => {
                f.file = Some(file);
                f.buf.extend_from_slice(header.as_bytes());
                f.buf.push(b'\n');
            }
            Err(e) => f.fail(&e),
        }
        f
    }

    /// Queues one formatted row (with its newline); writes when the
    /// buffer is full.
    fn push(&mut self, row: &str) {
        if self.file.is_none() {
            return;
        }
        self.buf.extend_from_slice(row.as_bytes());
        self.rows_pending += 1;
        if self.buf.len() >= ROW_BUFFER_BYTES {
            self.flush();
        }
    }

    /// Writes the buffered rows. On an error the file is cut back to its
    /// last complete row and closed.
    fn flush(&mut self) {
        let Some(file) = &mut self.file else { return };
        if self.buf.is_empty() {
            return;
        }
        let mut written = 0usize;
        while written < self.buf.len() {
            match file.write(&self.buf[written..]) {
                Ok(0) => {
                    let e = std::io::Error::new(std::io::ErrorKind::WriteZero, "wrote 0 bytes");
                    return self.cut_back(written, &e);
                }
                Ok(n) => written += n,
                Err(e) if e.kind() == std::io::ErrorKind::Interrupted => {}
                Err(e) => return self.cut_back(written, &e),
            }
        }
        self.bytes_on_disk += written as u64;
        self.rows_on_disk += self.rows_pending;
        self.rows_pending = 0;
        self.buf.clear();
    }

    /// After `written` bytes of the buffer reached the file and then
    /// `error`: keeps the whole rows among them, truncates the rest.
    fn cut_back(&mut self, written: usize, error: &std::io::Error) {
        let done = &self.buf[..written];
        let keep = done.iter().rposition(|&b| b == b'\n').map_or(0, |i| i + 1);
        let mut rows = done[..keep].iter().filter(|&&b| b == b'\n').count() as u64;
        if self.bytes_on_disk == 0 && keep > 0 {
            rows -= 1; // the header
        }
        self.bytes_on_disk += keep as u64;
        self.rows_on_disk += rows;
        if let Some(file) = &self.file
            && let Err(e) = file.set_len(self.bytes_on_disk)
        {
            tracing::warn!(file = %self.path.display(), error = %e, "cannot cut the file back to its last complete row");
        }
        self.fail(error);
    }

    fn fail(&mut self, error: &std::io::Error) {
        let msg = format!(
            "cannot write {}: {error}; it stops at its last complete row ({} rows)",
            self.path.display(),
            self.rows_on_disk
        );
        report_write_error(&msg);
        self.failure = Some(msg);
        self.file = None;
        self.buf = Vec::new();
        self.rows_pending = 0;
    }

    /// The error that stopped the file, if any.
    fn failure(&self) -> Option<String> {
        self.failure.clone()
    }
}

/// The writer thread's handle (owned by the frame loop).
pub struct OutputWriter {
    tx: Option<SyncSender<Msg>>,
    /// To the PNG encoder thread: at most [`FRAME_POOL`] frames, as many
    /// as there are buffers, so a send finds room whenever a buffer was free.
    frame_tx: Option<SyncSender<(u64, DisplayFrame)>>,
    pool: Receiver<DisplayFrame>,
    thread: Option<JoinHandle<anyhow::Result<WriterReport>>>,
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
    ) -> anyhow::Result<Self> {
        std::fs::create_dir_all(dir).with_context(|| format!("cannot create {}", dir.display()))?;
        let frames_dir = dir.join("frames");
        if write_frames {
            std::fs::create_dir_all(&frames_dir)
                .with_context(|| format!("cannot create {}", frames_dir.display()))?;
        }
        // The headers are on disk before the session starts; a file that
        // cannot be created is an error now, before anything runs.
        let timeline_path = dir.join("timeline.csv");
        let mut timeline =
            RowFile::create(&timeline_path, if stereo { STEREO_HEADER } else { HEADER });
        timeline.flush();
        let psf_path = dir.join("psf.csv");
        let mut psf_csv = RowFile::create(&psf_path, PSF_HEADER);
        psf_csv.flush();
        for f in [&timeline, &psf_csv] {
            if let Some(e) = f.failure() {
                anyhow::bail!("{e}");
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
                            let r = output::write_png(&p, &frame, output::PngCompression::Fast);
                            let _ = pool_tx.try_send(frame);
                            if let Err(e) = r {
                                // No torn image stays behind; the frames
                                // stop here, the rest of the run goes on.
                                let _ = std::fs::remove_file(&p);
                                let msg = format!(
                                    "{e:#}; frames/ stops after {} images (the partial {} removed)",
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
                    .context("cannot start the frame encoder thread")?,
            )
        } else {
            None
        };
        let thread = std::thread::Builder::new()
            .name("gazelight-writer".into())
            .spawn(move || -> anyhow::Result<WriterReport> {
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
                    if last_flush.elapsed() >= FLUSH_EVERY {
                        last_flush = std::time::Instant::now();
                        timeline.flush();
                        psf_csv.flush();
                        if let Some(x) = &mut xr_csv {
                            x.flush();
                        }
                    }
                    let Some(msg) = msg else { continue };
                    match msg {
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
                                slot => slot.insert(RowFile::create(&xr_path, XR_HEADER)),
                            };
                            line.clear();
                            format_xr(&mut line, &r);
                            x.push(&line);
                        }
                    }
                }
                for f in [Some(&mut timeline), Some(&mut psf_csv), xr_csv.as_mut()]
                    .into_iter()
                    .flatten()
                {
                    f.flush();
                }
                report.rows = timeline.rows_on_disk;
                report.psf_rows = psf_csv.rows_on_disk;
                report.errors.extend(
                    [Some(&timeline), Some(&psf_csv), xr_csv.as_ref()]
                        .into_iter()
                        .flatten()
                        .filter_map(|f| f.failure()),
                );
                Ok(report)
            })
            .context("cannot start the writer thread")?;
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
    pub fn finish(mut self) -> anyhow::Result<WriterReport> {
        self.tx = None;
        self.frame_tx = None;
        // Both threads are joined before either's error is returned: the
        // images already queued are written whatever the rows' fate.
        let rows = self.thread.take().map(|t| {
            t.join()
                .map_err(|_| anyhow::anyhow!("the output writer thread panicked"))?
        });
        let images = self.encoder.take().map(|e| {
            e.join()
                .map_err(|_| anyhow::anyhow!("the frame encoder thread panicked"))
        });
        let mut report = rows.transpose()?.unwrap_or_default();
        if let Some(frames) = images.transpose()? {
            report.frames_written = frames.written;
            report.errors.extend(frames.error);
        }
        Ok(report)
    }
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
