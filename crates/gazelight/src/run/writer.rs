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
    /// Calibrated pupil per eye, [right, left], mm.
    pub pupil_mm: [f32; 2],
    /// Either pupil held or modelled rather than measured.
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
    /// Pupil the view used, mm.
    pub frame_pupil_mm: f32,
    pub target_cd_m2: f64,
    pub adaptation_cd_m2: f64,
    pub psf_pupil_mm: f64,
    pub psf_rebuilt: bool,
}

const HEADER: &str = "frame,t_secs,gaze_u,gaze_v,pupil_right_mm,pupil_left_mm,pupil_mm,pupil_held,eye_state_age_ms,source_health,target_cd_m2,adaptation_cd_m2,psf_pupil_mm,psf_rebuilt,frame_ms";
/// A stereo run's header: per-view columns suffixed `_left`, `_right`.
const STEREO_HEADER: &str = "frame,t_secs,pupil_right_mm,pupil_left_mm,pupil_held,eye_state_age_ms,source_health,\
gaze_u_left,gaze_v_left,pupil_mm_left,target_cd_m2_left,adaptation_cd_m2_left,psf_pupil_mm_left,psf_rebuilt_left,\
gaze_u_right,gaze_v_right,pupil_mm_right,target_cd_m2_right,adaptation_cd_m2_right,psf_pupil_mm_right,psf_rebuilt_right,frame_ms";

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
#[derive(Clone, Copy, Debug, Default)]
pub struct WriterReport {
    pub rows: u64,
    pub frames_written: u64,
    pub psf_rows: u64,
}

/// The writer thread's handle (owned by the frame loop).
pub struct OutputWriter {
    tx: Option<SyncSender<Msg>>,
    /// To the PNG encoder thread: at most [`FRAME_POOL`] frames, as many
    /// as there are buffers, so a send finds room whenever a buffer was free.
    frame_tx: Option<SyncSender<(u64, DisplayFrame)>>,
    pool: Receiver<DisplayFrame>,
    thread: Option<JoinHandle<anyhow::Result<WriterReport>>>,
    encoder: Option<JoinHandle<anyhow::Result<u64>>>,
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
        let open = |name: &str| -> anyhow::Result<std::io::BufWriter<std::fs::File>> {
            let p = dir.join(name);
            let f = std::fs::File::create(&p)
                .with_context(|| format!("cannot write {}", p.display()))?;
            Ok(std::io::BufWriter::new(f))
        };
        let mut timeline = open("timeline.csv")?;
        let mut psf_csv = open("psf.csv")?;
        writeln!(timeline, "{}", if stereo { STEREO_HEADER } else { HEADER })?;
        writeln!(
            psf_csv,
            "generation,t_secs,pupil_mm,wavelength_nm,first_ring_rad,first_ring_arcmin,view"
        )?;
        // The headers are on disk before the session starts.
        timeline.flush()?;
        psf_csv.flush()?;
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
                    .spawn(move || -> anyhow::Result<u64> {
                        lower_this_threads_priority();
                        let mut written = 0;
                        for (i, frame) in frame_rx {
                            let p = frames_dir.join(format!("frame_{i:06}.png"));
                            let r = output::write_png(&p, &frame, output::PngCompression::Fast);
                            let _ = pool_tx.try_send(frame);
                            r?;
                            written += 1;
                        }
                        Ok(written)
                    })
                    .context("cannot start the frame encoder thread")?,
            )
        } else {
            None
        };
        let dir_owned = dir.to_path_buf();
        let thread = std::thread::Builder::new()
            .name("gazelight-writer".into())
            .spawn(move || -> anyhow::Result<WriterReport> {
                let mut report = WriterReport::default();
                let timeline_path = dir_owned.join("timeline.csv");
                let psf_path = dir_owned.join("psf.csv");
                let xr_path = dir_owned.join("xr.csv");
                // Opened with the first OpenXR row.
                let mut xr_csv: Option<std::io::BufWriter<std::fs::File>> = None;
                // Rows are formatted here and handed to the file whole, and
                // the files are flushed at least every `FLUSH_EVERY`: the
                // files only ever hold complete rows, up to a second old,
                // whatever ends the process.
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
                        timeline
                            .flush()
                            .with_context(|| format!("cannot write {}", timeline_path.display()))?;
                        psf_csv
                            .flush()
                            .with_context(|| format!("cannot write {}", psf_path.display()))?;
                        if let Some(x) = &mut xr_csv {
                            x.flush()
                                .with_context(|| format!("cannot write {}", xr_path.display()))?;
                        }
                    }
                    let Some(msg) = msg else { continue };
                    match msg {
                        Msg::Row(r) => {
                            line.clear();
                            format_row(&mut line, &r, stereo);
                            timeline.write_all(line.as_bytes()).with_context(|| {
                                format!("cannot write {}", timeline_path.display())
                            })?;
                            report.rows += 1;
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
                            psf_csv
                                .write_all(line.as_bytes())
                                .with_context(|| format!("cannot write {}", psf_path.display()))?;
                            report.psf_rows += 1;
                        }
                        Msg::Xr(r) => {
                            let x = match &mut xr_csv {
                                Some(x) => x,
                                slot => {
                                    let f = std::fs::File::create(&xr_path).with_context(|| {
                                        format!("cannot write {}", xr_path.display())
                                    })?;
                                    let mut x = std::io::BufWriter::new(f);
                                    writeln!(x, "{XR_HEADER}")?;
                                    slot.insert(x)
                                }
                            };
                            line.clear();
                            format_xr(&mut line, &r);
                            x.write_all(line.as_bytes())
                                .with_context(|| format!("cannot write {}", xr_path.display()))?;
                        }
                    }
                }
                if let Some(x) = &mut xr_csv {
                    x.flush()
                        .with_context(|| format!("cannot write {}", xr_path.display()))?;
                }
                timeline
                    .flush()
                    .with_context(|| format!("cannot write {}", timeline_path.display()))?;
                psf_csv
                    .flush()
                    .with_context(|| format!("cannot write {}", psf_path.display()))?;
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
                let sent = self
                    .frame_tx
                    .as_ref()
                    .is_some_and(|tx| tx.try_send((index, buf)).is_ok());
                if !sent {
                    // No room or no encoder: the image is skipped.
                    self.frames_skipped += 1;
                }
            }
            Ok(_) | Err(TryRecvError::Empty) | Err(TryRecvError::Disconnected) => {
                self.frames_skipped += 1
            }
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
                .map_err(|_| anyhow::anyhow!("the frame encoder thread panicked"))?
        });
        let mut report = rows.transpose()?.unwrap_or_default();
        if let Some(written) = images.transpose()? {
            report.frames_written = written;
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
            "{},{:.4},{:.5},{:.5},{:.4},{:.4},{:.4},{},{:.3},{},{:.6e},{:.6e},{:.4},{},{:.3}",
            r.frame,
            r.t_secs,
            v.gaze_u,
            v.gaze_v,
            r.pupil_mm[0],
            r.pupil_mm[1],
            v.frame_pupil_mm,
            u8::from(r.pupil_held),
            r.eye_state_age_ms,
            health_name(r.health),
            v.target_cd_m2,
            v.adaptation_cd_m2,
            v.psf_pupil_mm,
            u8::from(v.psf_rebuilt),
            r.frame_ms
        );
        return;
    }
    let _ = write!(
        w,
        "{},{:.4},{:.4},{:.4},{},{:.3},{}",
        r.frame,
        r.t_secs,
        r.pupil_mm[0],
        r.pupil_mm[1],
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
    let _ = writeln!(w, ",{:.3}", r.frame_ms);
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
