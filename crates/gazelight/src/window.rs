//! The service's display window: winit for the window and its events,
//! [`gazelight_gpu::present::WindowPresenter`] for the surface (vsync, FIFO).
//!
//! The window shows either the frame loop's newest display frame
//! ([`Content::Frames`], letterboxed to keep its aspect) or a solid colour
//! filling the whole window ([`Content::Solid`], the black/white stimulus of
//! `calibrate --stimulus window`). It never drives the frame loop: the loop
//! runs at the display rate on its own thread and offers each frame to a
//! [`DisplaySlot`]; the window draws whatever is newest when the surface is
//! ready, so a slow window drops frames (counted) instead of slowing the
//! loop. The cursor position over the frame is published as a normalised
//! gaze for `run --mouse-gaze`.
//!
//! Where the pixels come from:
//!
//! * **GPU pipeline**: the slot carries the pipeline's output buffer
//!   ([`FrameSource`], handed over once) and a frame counter. The presenter
//!   is built on the pipeline's own device and its fragment shader reads
//!   that buffer: a frame goes from the GPU to the screen with no read-back
//!   and no upload. The window waits (showing nothing) until the first
//!   frame says which device to use.
//! * **CPU pipeline** (and the calibration stimulus): the presenter has a
//!   device of its own; a CPU frame is copied into the slot and uploaded
//!   (the one copy a CPU-rendered frame cannot avoid).
//!
//! Each presented frame's latency — from the moment the frame loop had it
//! rendered ([`DisplaySlot::put`] / [`DisplaySlot::put_gpu`]) to the
//! surface's present call that first showed it — is kept for the run
//! summary ([`WindowStats`]).
//!
//! winit stays in the binary (rather than in `gazelight-gpu`): the event
//! loop, keys and cursor are the application's business, and the GPU crate
//! also serves host renderers that own their windows — it takes any window
//! handle.
//!
//! winit needs the main thread on Linux; [`run`] blocks it until the window
//! is closed (Escape or the close button: the session is asked to shut
//! down) or `stop` turns true.

use std::sync::atomic::{AtomicU32, AtomicU64, Ordering};
use std::sync::{Arc, Mutex, OnceLock};
use std::time::{Duration, Instant};

use anyhow::Context;
use gazelight_gpu::present::{FrameSource, Presented, WindowPresenter, letterbox_scale};
use winit::application::ApplicationHandler;
use winit::dpi::PhysicalSize;
use winit::event::{ElementState, KeyEvent, WindowEvent};
use winit::event_loop::{ActiveEventLoop, ControlFlow, EventLoop};
use winit::keyboard::{Key, NamedKey};
use winit::window::{Window, WindowId};

/// Render→present latencies kept for the summary (≈ 12 min at 90 Hz).
const LATENCY_SAMPLES: usize = 1 << 16;

/// Where the slot's frames live, fixed by the first frame.
#[derive(Debug)]
#[allow(clippy::large_enum_variant)] // one per window, fixed by the first frame; never moved in the frame loop
enum Source {
    /// Copied into the slot by [`DisplaySlot::put`] (CPU frames).
    Host,
    /// In a GPU pipeline's output buffer ([`DisplaySlot::put_gpu`]).
    Gpu(FrameSource),
}

/// The newest display frame, handed from the frame loop to the window.
/// `put` copies into a buffer allocated once, so the frame loop does not
/// allocate; `put_gpu` only counts (the frame stays on the GPU). The window
/// takes a frame only when its sequence number moved.
#[derive(Debug)]
pub struct DisplaySlot {
    width: u32,
    height: u32,
    source: OnceLock<Source>,
    inner: Mutex<SlotInner>,
    /// Frames put but never shown (the window was busy).
    skipped: AtomicU64,
    /// Surface images the window presented.
    presented: AtomicU64,
}

#[derive(Debug)]
struct SlotInner {
    seq: u64,
    /// When the newest frame was handed over (rendered).
    rendered: Option<Instant>,
    rgba8: Vec<u8>,
}

/// What [`DisplaySlot::take_newer`] hands the window.
enum Newer<'a> {
    /// A host frame to upload.
    Host(&'a [u8]),
    /// A new frame is in the GPU source's buffer.
    Gpu,
}

impl DisplaySlot {
    /// A slot for RGBA8 frames of `width × height`.
    pub fn new(width: u32, height: u32) -> Arc<Self> {
        Arc::new(Self {
            width,
            height,
            source: OnceLock::new(),
            inner: Mutex::new(SlotInner {
                seq: 0,
                rendered: None,
                rgba8: Vec::new(),
            }),
            skipped: AtomicU64::new(0),
            presented: AtomicU64::new(0),
        })
    }

    /// Frame size, pixels.
    pub fn size(&self) -> (u32, u32) {
        (self.width, self.height)
    }

    /// Replaces the newest frame with a host copy of `rgba8` (ignored when
    /// the size does not match, or when the slot shows a GPU source).
    pub fn put(&self, rgba8: &[u8]) {
        if !matches!(self.source.get_or_init(|| Source::Host), Source::Host) {
            return;
        }
        let mut g = self.inner.lock().unwrap_or_else(|p| p.into_inner());
        let n = self.width as usize * self.height as usize * 4;
        if rgba8.len() != n {
            return;
        }
        if g.rgba8.len() != n {
            // Once, on the first frame.
            g.rgba8 = vec![0; n];
        }
        g.rgba8.copy_from_slice(rgba8);
        g.seq += 1;
        g.rendered = Some(Instant::now());
    }

    /// Notes that a new frame is in the GPU pipeline's output buffer;
    /// `source` is called once, on the first frame, to hand the buffer over
    /// (ignored when the slot already shows host frames or another size).
    pub fn put_gpu(&self, source: impl FnOnce() -> FrameSource) {
        let s = self.source.get_or_init(|| Source::Gpu(source()));
        let Source::Gpu(src) = s else {
            return;
        };
        if src.size() != [self.width, self.height] {
            return;
        }
        let mut g = self.inner.lock().unwrap_or_else(|p| p.into_inner());
        g.seq += 1;
        g.rendered = Some(Instant::now());
    }

    /// Frames the window never showed.
    pub fn skipped(&self) -> u64 {
        self.skipped.load(Ordering::Relaxed)
    }

    /// Surface images presented so far (the window's redraws).
    pub fn presented(&self) -> u64 {
        self.presented.load(Ordering::Relaxed)
    }

    /// Runs `f` on the newest frame if it is newer than `last_seq`; returns
    /// when that frame was handed over.
    fn take_newer(&self, last_seq: &mut u64, f: impl FnOnce(Newer<'_>)) -> Option<Instant> {
        let g = self.inner.lock().unwrap_or_else(|p| p.into_inner());
        if g.seq == *last_seq {
            return None;
        }
        if g.seq > *last_seq + 1 {
            self.skipped
                .fetch_add(g.seq - *last_seq - 1, Ordering::Relaxed);
        }
        *last_seq = g.seq;
        match self.source.get() {
            Some(Source::Gpu(_)) => f(Newer::Gpu),
            _ => f(Newer::Host(&g.rgba8)),
        }
        g.rendered
    }
}

/// A solid colour (sRGB-encoded 8-bit RGB) shown full screen; settable
/// from any thread.
#[derive(Debug, Default)]
pub struct SolidColour(AtomicU32);

impl SolidColour {
    pub fn new(rgb8: [u8; 3]) -> Arc<Self> {
        let s = Self::default();
        s.set(rgb8);
        Arc::new(s)
    }

    pub fn set(&self, rgb8: [u8; 3]) {
        let v = u32::from(rgb8[0]) | (u32::from(rgb8[1]) << 8) | (u32::from(rgb8[2]) << 16);
        self.0.store(v, Ordering::Relaxed);
    }

    pub fn get(&self) -> [u8; 3] {
        let v = self.0.load(Ordering::Relaxed);
        [
            (v & 0xff) as u8,
            ((v >> 8) & 0xff) as u8,
            ((v >> 16) & 0xff) as u8,
        ]
    }
}

/// The cursor over the frame as a normalised gaze (u right, v down, in
/// [0, 1]), for `--mouse-gaze`; `None` until the cursor enters the frame,
/// then the last position over the frame.
#[derive(Debug, Default)]
pub struct MouseGaze(Mutex<Option<[f32; 2]>>);

impl MouseGaze {
    pub fn get(&self) -> Option<[f32; 2]> {
        *self.0.lock().unwrap_or_else(|p| p.into_inner())
    }
    fn set(&self, uv: Option<[f32; 2]>) {
        *self.0.lock().unwrap_or_else(|p| p.into_inner()) = uv;
    }
}

/// What the window shows.
#[derive(Clone, Debug)]
pub enum Content {
    Frames(Arc<DisplaySlot>),
    Solid(Arc<SolidColour>),
}

/// Window settings.
#[derive(Clone, Debug)]
pub struct WindowOptions {
    pub title: String,
    /// Inner size, physical pixels.
    pub width: u32,
    pub height: u32,
    /// Borderless full screen on the current monitor.
    pub fullscreen: bool,
}

/// What a closed or stopped window reports.
#[derive(Clone, Debug, Default)]
pub struct WindowStats {
    /// Surface images presented (every redraw, new frame or not).
    pub presented: u64,
    /// Distinct frames shown.
    pub frames_shown: u64,
    /// Host frames uploaded to the GPU (CPU pipeline; 0 on the GPU one).
    pub frames_uploaded: u64,
    /// Whether the presenter drew the frame pipeline's own output buffer
    /// (GPU pipeline, no read-back) rather than uploaded host frames.
    pub on_pipeline_device: bool,
    /// Whether the user closed the window (rather than `stop`).
    pub closed_by_user: bool,
    /// The adapter the window ran on.
    pub software_adapter: bool,
    /// Per shown frame: from the frame loop's hand-over (rendered) to the
    /// present call that first showed it, ms.
    pub latency_ms: Vec<f32>,
}

impl WindowStats {
    /// The `p` quantile (0–1) of the render→present latency, ms; NaN when
    /// no frame was shown.
    pub fn latency_quantile_ms(&self, p: f64) -> f64 {
        let mut v = self.latency_ms.clone();
        v.sort_unstable_by(f32::total_cmp);
        if v.is_empty() {
            return f64::NAN;
        }
        f64::from(v[((v.len() - 1) as f64 * p.clamp(0.0, 1.0)).round() as usize])
    }
}

/// Opens the window and runs its event loop on this (the main) thread until
/// the user closes it or `stop()` returns true. `on_close` runs when the
/// user closes it.
pub fn run(
    options: WindowOptions,
    content: Content,
    mouse: Option<Arc<MouseGaze>>,
    stop: impl Fn() -> bool + 'static,
    on_close: impl Fn() + 'static,
) -> anyhow::Result<WindowStats> {
    let event_loop = EventLoop::new().map_err(|e| {
        anyhow::anyhow!(
            "cannot open a window ({e}); is a display available (DISPLAY / WAYLAND_DISPLAY)? \
             Use --headless to run without one"
        )
    })?;
    event_loop.set_control_flow(ControlFlow::Poll);
    let mut app = App {
        options,
        content,
        mouse,
        stop: Box::new(stop),
        on_close: Box::new(on_close),
        window: None,
        presenter: None,
        error: None,
        stats: WindowStats {
            latency_ms: Vec::with_capacity(LATENCY_SAMPLES),
            ..WindowStats::default()
        },
        last_seq: 0,
    };
    event_loop
        .run_app(&mut app)
        .context("the window's event loop failed")?;
    if let Some(e) = app.error {
        return Err(e);
    }
    Ok(app.stats)
}

struct App {
    options: WindowOptions,
    content: Content,
    mouse: Option<Arc<MouseGaze>>,
    stop: Box<dyn Fn() -> bool>,
    on_close: Box<dyn Fn()>,
    window: Option<Arc<Window>>,
    presenter: Option<WindowPresenter>,
    error: Option<anyhow::Error>,
    stats: WindowStats,
    last_seq: u64,
}

impl App {
    fn fail(&mut self, event_loop: &ActiveEventLoop, e: anyhow::Error) {
        tracing::error!(error = %format!("{e:#}"), "window failed");
        self.error.get_or_insert(e);
        event_loop.exit();
    }

    fn create_window(&mut self, event_loop: &ActiveEventLoop) -> anyhow::Result<Arc<Window>> {
        let mut attrs = Window::default_attributes()
            .with_title(self.options.title.clone())
            .with_inner_size(PhysicalSize::new(self.options.width, self.options.height));
        if self.options.fullscreen {
            attrs = attrs.with_fullscreen(Some(winit::window::Fullscreen::Borderless(None)));
        }
        Ok(Arc::new(
            event_loop
                .create_window(attrs)
                .context("cannot create the window")?,
        ))
    }

    /// Builds the presenter once it is known where the frames live: for a
    /// GPU source on the pipeline's device, otherwise on an own one. `None`
    /// while the frame loop has not offered a frame yet.
    fn try_presenter(&self, window: &Arc<Window>) -> anyhow::Result<Option<WindowPresenter>> {
        let size = window.inner_size();
        let size_px = [size.width, size.height];
        let presenter = match &self.content {
            Content::Solid(_) => WindowPresenter::own(window.clone(), size_px, [1, 1])
                .context("cannot present to the window")?,
            Content::Frames(slot) => match slot.source.get() {
                None => return Ok(None),
                Some(Source::Host) => {
                    let (w, h) = slot.size();
                    WindowPresenter::own(window.clone(), size_px, [w, h])
                        .context("cannot present to the window")?
                }
                Some(Source::Gpu(src)) => {
                    WindowPresenter::on_pipeline(src, window.clone(), size_px)
                        .context("cannot present to the window on the frame pipeline's device")?
                }
            },
        };
        let info = presenter.context().adapter_info();
        tracing::info!(
            adapter = %info.name,
            backend = ?info.backend,
            on_pipeline_device = presenter.on_pipeline_device(),
            "window adapter"
        );
        Ok(Some(presenter))
    }

    fn init_presenter(&mut self, event_loop: &ActiveEventLoop) {
        let Some(window) = self.window.clone() else {
            return;
        };
        if self.presenter.is_some() {
            return;
        }
        match self.try_presenter(&window) {
            Ok(Some(p)) => {
                self.stats.software_adapter = p.software_adapter();
                self.stats.on_pipeline_device = p.on_pipeline_device();
                self.presenter = Some(p);
                window.request_redraw();
            }
            Ok(None) => {}
            Err(e) => self.fail(event_loop, e),
        }
    }

    fn redraw(&mut self) -> anyhow::Result<()> {
        let Some(presenter) = &mut self.presenter else {
            return Ok(());
        };
        let (shown, rendered) = match &self.content {
            Content::Frames(slot) => {
                let mut upload = Ok(());
                let mut uploaded = false;
                let rendered = slot.take_newer(&mut self.last_seq, |frame| {
                    if let Newer::Host(rgba) = frame {
                        upload = presenter.upload(rgba);
                        uploaded = true;
                    }
                });
                upload.context("cannot upload the frame to the window")?;
                self.stats.frames_uploaded += u64::from(uploaded);
                (presenter.present_frame()?, rendered)
            }
            Content::Solid(c) => (presenter.present_solid(c.get())?, None),
        };
        if shown == Presented::Shown {
            self.stats.presented += 1;
            if let Content::Frames(slot) = &self.content {
                slot.presented.fetch_add(1, Ordering::Relaxed);
            }
            if let Some(t) = rendered {
                self.stats.frames_shown += 1;
                if self.stats.latency_ms.len() < LATENCY_SAMPLES {
                    self.stats
                        .latency_ms
                        .push((t.elapsed().as_secs_f64() * 1e3) as f32);
                }
            }
        } else if rendered.is_some() {
            // Not shown after all: show it at the next redraw.
            self.last_seq = self.last_seq.saturating_sub(1);
        }
        if let Some(w) = &self.window {
            w.pre_present_notify();
        }
        Ok(())
    }
}

impl ApplicationHandler for App {
    fn resumed(&mut self, event_loop: &ActiveEventLoop) {
        if self.window.is_some() {
            return;
        }
        match self.create_window(event_loop) {
            Ok(w) => self.window = Some(w),
            Err(e) => return self.fail(event_loop, e),
        }
        self.init_presenter(event_loop);
    }

    fn window_event(&mut self, event_loop: &ActiveEventLoop, _id: WindowId, event: WindowEvent) {
        match event {
            WindowEvent::CloseRequested
            | WindowEvent::KeyboardInput {
                event:
                    KeyEvent {
                        logical_key: Key::Named(NamedKey::Escape),
                        state: ElementState::Pressed,
                        ..
                    },
                ..
            } => {
                self.stats.closed_by_user = true;
                (self.on_close)();
                event_loop.exit();
            }
            WindowEvent::Resized(size) => {
                if let Some(p) = &mut self.presenter {
                    p.resize([size.width, size.height]);
                }
            }
            WindowEvent::CursorMoved { position, .. } => {
                if let (Some(mouse), Some(window)) = (&self.mouse, &self.window) {
                    let size = window.inner_size();
                    let (ww, wh) = (f64::from(size.width), f64::from(size.height));
                    let frame = match &self.content {
                        Content::Frames(slot) => [slot.width, slot.height],
                        Content::Solid(_) => [1, 1],
                    };
                    let s = letterbox_scale(frame, [size.width, size.height]);
                    // Window pixel → clip → frame uv.
                    let cx = (position.x / ww * 2.0 - 1.0) / f64::from(s[0]);
                    let cy = (1.0 - position.y / wh * 2.0) / f64::from(s[1]);
                    let (u, v) = ((cx + 1.0) / 2.0, (1.0 - cy) / 2.0);
                    if (0.0..=1.0).contains(&u) && (0.0..=1.0).contains(&v) {
                        mouse.set(Some([u as f32, v as f32]));
                    }
                }
            }
            // Leaving the window keeps the last gaze (it does not snap
            // back to the centre while the user reaches for something).
            WindowEvent::RedrawRequested => {
                if let Err(e) = self.redraw() {
                    self.fail(event_loop, e);
                    return;
                }
                if let Some(w) = &self.window {
                    w.request_redraw();
                }
            }
            _ => {}
        }
    }

    fn about_to_wait(&mut self, event_loop: &ActiveEventLoop) {
        if (self.stop)() {
            event_loop.exit();
            return;
        }
        // FIFO present paces the redraws; until the first frame says which
        // device to present on, poll gently.
        if self.presenter.is_none() {
            self.init_presenter(event_loop);
            event_loop.set_control_flow(ControlFlow::WaitUntil(
                Instant::now() + Duration::from_millis(5),
            ));
        } else {
            event_loop.set_control_flow(ControlFlow::Poll);
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn slot_counts_frames_the_window_never_showed() {
        let slot = DisplaySlot::new(2, 1);
        let mut last = 0;
        slot.put(&[1; 8]);
        slot.put(&[2; 8]);
        slot.put(&[3; 8]);
        let mut got = Vec::new();
        let t = slot.take_newer(&mut last, |f| {
            if let Newer::Host(px) = f {
                got.extend_from_slice(px);
            }
        });
        assert!(t.is_some());
        assert_eq!(got, vec![3; 8]);
        assert_eq!(slot.skipped(), 2);
        assert!(slot.take_newer(&mut last, |_| {}).is_none());
        // A frame of the wrong size is ignored, never a panic.
        slot.put(&[9; 4]);
        assert!(slot.take_newer(&mut last, |_| {}).is_none());
    }

    #[test]
    fn a_host_slot_ignores_gpu_frames() {
        let slot = DisplaySlot::new(2, 1);
        slot.put(&[1; 8]);
        slot.put_gpu(|| unreachable!("a host slot never asks for a GPU source"));
        let mut last = 0;
        assert!(slot.take_newer(&mut last, |_| {}).is_some());
        assert!(slot.take_newer(&mut last, |_| {}).is_none());
    }

    #[test]
    fn latency_quantiles_of_the_shown_frames() {
        let stats = WindowStats {
            latency_ms: vec![5.0, 1.0, 3.0, 2.0, 4.0],
            ..WindowStats::default()
        };
        assert_eq!(stats.latency_quantile_ms(0.5), 3.0);
        assert_eq!(stats.latency_quantile_ms(1.0), 5.0);
        assert!(WindowStats::default().latency_quantile_ms(0.5).is_nan());
    }

    #[test]
    fn solid_colour_round_trips() {
        let c = SolidColour::new([0, 0, 0]);
        c.set([255, 128, 7]);
        assert_eq!(c.get(), [255, 128, 7]);
    }
}
