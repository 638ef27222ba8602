//! Which frame pipeline renders: the wgpu one of `gazelight-gpu` or the CPU
//! reference of `gazelight-vision` (ARCHITECTURE.md, "Every stage exists
//! twice"), for every front end: the CLI's `--backend` and Python's
//! `gazelight.render(backend=…)` make the same choice by the same rule.
//!
//! [`Renderer`] hides the choice behind one per-frame call with the CPU
//! pipeline's signature, so `render`, `replay`, `run` and Python's `render`
//! drive either (it is a `gazelight_render::frame::ViewRenderer`).
//!
//! # The `auto` policy
//!
//! * A hardware adapter (discrete, integrated, virtual or other) is present
//!   and gives a device → the GPU pipeline on it.
//! * Only a software adapter (Mesa's lavapipe/llvmpipe, WARP, SwiftShader) →
//!   the CPU pipeline. A software adapter runs the WGSL passes on the same
//!   CPU cores as the CPU pipeline, through a shader JIT and without the CPU
//!   pipeline's fused per-pixel stages, so it is slower, not a speed-up.
//!   Measured on a 2-core machine with Mesa 22.3 lavapipe, the embedded demo
//!   at 96×80 (12 frames, 8 PSF rebuilds): 350–1 250 ms a frame on lavapipe
//!   against 25–85 ms on the CPU pipeline. `gpu` still picks it on purpose
//!   (parity checks on CI, `crates/gazelight/tests/backend.rs`).
//! * No adapter, or the GPU pipeline cannot be built on the hardware one →
//!   the CPU pipeline.
//!
//! `gpu` with no adapter is an error naming the other two choices.
//! The choice and its reason are logged (`tracing::info!`); the CLI's
//! [`Renderer::new`] also prints them as one line on stderr, Python reads
//! them from [`Renderer::describe`] and [`Renderer::reason`]. Messages name
//! the choice as the front end spells it ([`Spelling`]).
//!
//! # Frames stay where they are rendered
//!
//! [`Renderer::render`] renders a frame and reads nothing back: on the GPU
//! the display frame stays in the pipeline's output buffer, which a window
//! draws directly ([`Renderer::show`] hands it over once as a
//! [`FrameSource`]). Only a consumer on the host — the file writer of
//! `--out`, every frame; the status page, at its own rate; Python — calls
//! [`Renderer::read_frame`], and each GPU read-back is counted
//! ([`Renderer::frames_read_back`], in the status JSON and the run summary).
//! On the CPU the frame is on the host already (0 read-backs); the window
//! uploads it.

use gazelight_gpu::context::{is_software_adapter, probe_adapters, searched_backends};
use gazelight_gpu::present::FrameSource;
use gazelight_gpu::{AdapterChoice, ContextOptions, GpuContext, GpuError, GpuFramePipeline};
use gazelight_render::RenderError;
use gazelight_vision::pipeline::{
    DisplayFrame, FrameInput, FramePipeline, FrameStats, PipelineConfig,
};
use gazelight_vision::psf::PsfKernel;
use gazelight_vision::scene::{PanoramaView, ViewParams};
use gazelight_vision::{RgbImage, VisionError};

/// The backend a front end asks for (the CLI's `--backend`, Python's
/// `backend=`): `auto` (the default), `gpu` or `cpu`.
#[cfg_attr(feature = "clap", derive(clap::ValueEnum))]
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq)]
pub enum BackendChoice {
    /// A hardware GPU when present; otherwise the CPU pipeline (a software
    /// adapter such as lavapipe is slower than the CPU pipeline, so `auto`
    /// does not pick it).
    #[default]
    Auto,
    /// The GPU pipeline on the best adapter (hardware first, then a software
    /// one such as lavapipe); an error when there is none.
    Gpu,
    /// The CPU reference pipeline.
    Cpu,
}

impl BackendChoice {
    /// Every choice, in the order the CLI's help lists them.
    pub const ALL: [BackendChoice; 3] =
        [BackendChoice::Auto, BackendChoice::Gpu, BackendChoice::Cpu];

    /// `"auto"`, `"gpu"` or `"cpu"`.
    pub fn name(self) -> &'static str {
        match self {
            BackendChoice::Auto => "auto",
            BackendChoice::Gpu => "gpu",
            BackendChoice::Cpu => "cpu",
        }
    }
}

impl std::fmt::Display for BackendChoice {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        f.write_str(self.name())
    }
}

/// `"auto"`, `"gpu"` or `"cpu"` (exactly; the CLI's `--backend` values).
impl std::str::FromStr for BackendChoice {
    type Err = BackendError;

    fn from_str(s: &str) -> Result<Self, BackendError> {
        BackendChoice::ALL
            .into_iter()
            .find(|c| c.name() == s)
            .ok_or_else(|| BackendError::Unknown(s.to_owned()))
    }
}

/// How a front end names a choice in the messages: the CLI's flag
/// (`--backend gpu`) or Python's keyword (`backend="gpu"`).
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum Spelling {
    /// `--backend gpu`.
    Flag,
    /// `backend="gpu"`.
    Keyword,
}

impl Spelling {
    /// `choice` as this front end's user writes it.
    pub fn of(self, choice: BackendChoice) -> String {
        match self {
            Spelling::Flag => format!("--backend {choice}"),
            Spelling::Keyword => format!("backend=\"{choice}\""),
        }
    }
}

/// What can go wrong choosing, building or driving a frame pipeline.
#[derive(Debug, thiserror::Error)]
pub enum BackendError {
    /// A backend name that is none of `auto`, `gpu`, `cpu`.
    #[error("unknown backend {0:?}: expected \"auto\", \"gpu\" or \"cpu\"")]
    Unknown(String),
    /// `gpu` was asked for and no GPU device can be made (`error` says
    /// why; no adapter, typically).
    #[error(
        "{}: {error}. Use {} to render on the CPU \
         (or {} to fall back to it when there is no hardware GPU)",
        spelling.of(BackendChoice::Gpu),
        spelling.of(BackendChoice::Cpu),
        spelling.of(BackendChoice::Auto)
    )]
    NoGpu {
        /// How the front end names the choices.
        spelling: Spelling,
        /// Why no device: part of the message, not a cause (the CLI prints
        /// causes after the message).
        error: GpuError,
    },
    /// `gpu` was asked for; there is a device, but the pipeline cannot be
    /// built on it.
    #[error(
        "{}: cannot build the GPU pipeline (try {})",
        spelling.of(BackendChoice::Gpu),
        spelling.of(BackendChoice::Cpu)
    )]
    GpuPipeline {
        /// How the front end names the choices.
        spelling: Spelling,
        /// What failed.
        #[source]
        source: GpuError,
    },
    /// The GPU pipeline failed.
    #[error(transparent)]
    Gpu(#[from] GpuError),
    /// The CPU pipeline failed, or a parameter is out of range.
    #[error(transparent)]
    Vision(#[from] VisionError),
    /// The GPU's display frame has another size than the frame asked for.
    #[error("GPU display frame: {bytes} bytes for {width}x{height}, expected {expected}")]
    FrameSize {
        /// Bytes read back.
        bytes: usize,
        /// The frame's width, pixels.
        width: usize,
        /// The frame's height, pixels.
        height: usize,
        /// Bytes the host frame holds.
        expected: usize,
    },
    /// The retinal image was asked of a CPU pipeline that does not keep it.
    #[error("the CPU pipeline was built without keep_retinal: no retinal image to read")]
    NoRetinal,
}

use gazelight_output::error_chain as chain;

/// The GPU side of a [`Renderer`].
pub struct GpuRenderer {
    pipeline: GpuFramePipeline,
    /// "name (backend, hardware|software)".
    adapter: String,
    /// Host copy of the PSF kernel, read back on demand after a rebuild.
    kernel: Option<PsfKernel>,
    kernel_stale: bool,
    /// Display frames copied back to the host.
    read_backs: u64,
}

impl GpuRenderer {
    /// The pipeline's output, for a presenter that draws it into its own
    /// textures.
    pub fn frame_source(&self) -> FrameSource {
        FrameSource::of(&self.pipeline)
    }
}

/// The frame pipeline that renders: GPU or CPU.
pub enum Renderer {
    /// The CPU reference pipeline; the string says why it was chosen.
    Cpu(Box<FramePipeline>, String),
    /// The GPU pipeline; the string says why it was chosen.
    Gpu(Box<GpuRenderer>, String),
}

/// Where a frame is offered for display (the CLI's window slot): a host
/// copy of a CPU frame, or a note that a new GPU frame is in the pipeline's
/// output buffer (`source` hands that buffer over, called once).
pub trait FrameSink {
    /// A new CPU frame, RGBA8.
    fn put(&self, rgba8: &[u8]);
    /// A new GPU frame in the buffer `source` gives.
    fn put_gpu(&self, source: impl FnOnce() -> FrameSource);
}

impl<T: FrameSink + ?Sized> FrameSink for std::sync::Arc<T> {
    fn put(&self, rgba8: &[u8]) {
        (**self).put(rgba8);
    }

    fn put_gpu(&self, source: impl FnOnce() -> FrameSource) {
        (**self).put_gpu(source);
    }
}

/// "llvmpipe (LLVM 19.1.7, 256 bits) (Vulkan, software)".
fn adapter_label(info: &gazelight_gpu::context::AdapterInfo) -> String {
    format!(
        "{} ({}, {})",
        info.name,
        info.backend,
        if is_software_adapter(info) {
            "software"
        } else {
            "hardware"
        }
    )
}

/// Prints `line` on stderr unless this process printed it already, and
/// says whether it did: a stereo run builds one renderer per eye, and
/// says (and logs) which backend once.
fn first_time(line: String) -> bool {
    static SAID: std::sync::Mutex<Vec<String>> = std::sync::Mutex::new(Vec::new());
    let mut said = SAID
        .lock()
        .unwrap_or_else(std::sync::PoisonError::into_inner);
    if said.contains(&line) {
        return false;
    }
    eprintln!("{line}");
    said.push(line);
    true
}

impl Renderer {
    /// The CLI's choice: [`Self::choose`] with the `--backend` spelling,
    /// and the choice with its reason printed once on stderr
    /// (`backend: cpu (auto: no GPU adapter found …)`) and logged.
    pub fn new(
        choice: BackendChoice,
        config: &PipelineConfig,
        width: usize,
        height: usize,
        deg_per_px: f64,
    ) -> Result<Renderer, BackendError> {
        let renderer = Self::build(choice, Spelling::Flag, config, width, height, deg_per_px)?;
        if first_time(format!(
            "backend: {} ({})",
            renderer.describe(),
            renderer.reason()
        )) {
            renderer.log(choice);
        }
        Ok(renderer)
    }

    /// Picks and builds the pipeline for `width × height` frames whose
    /// pixels subtend `deg_per_px` degrees (see the module docs for
    /// `auto`), naming the choice in messages as `spelling` does. Logs the
    /// choice with the adapter and the reason; prints nothing.
    pub fn choose(
        choice: BackendChoice,
        spelling: Spelling,
        config: &PipelineConfig,
        width: usize,
        height: usize,
        deg_per_px: f64,
    ) -> Result<Renderer, BackendError> {
        let renderer = Self::build(choice, spelling, config, width, height, deg_per_px)?;
        renderer.log(choice);
        Ok(renderer)
    }

    fn log(&self, choice: BackendChoice) {
        let (backend, adapter, reason) = match self {
            Renderer::Cpu(_, why) => ("cpu", "-", why.as_str()),
            Renderer::Gpu(g, why) => ("gpu", g.adapter.as_str(), why.as_str()),
        };
        tracing::info!(backend, adapter, reason, requested = %choice, "frame pipeline backend");
    }

    fn build(
        choice: BackendChoice,
        spelling: Spelling,
        config: &PipelineConfig,
        width: usize,
        height: usize,
        deg_per_px: f64,
    ) -> Result<Renderer, BackendError> {
        match choice {
            BackendChoice::Cpu => Self::cpu(config, width, height, deg_per_px, spelling.of(choice)),
            BackendChoice::Gpu => {
                let ctx = GpuContext::new(&ContextOptions::default())
                    .map_err(|error| BackendError::NoGpu { spelling, error })?;
                let why = spelling.of(choice);
                Self::on_device(&ctx, config, width, height, deg_per_px, &why).map_err(
                    |e| match e {
                        BackendError::Gpu(source) => BackendError::GpuPipeline { spelling, source },
                        other => other,
                    },
                )
            }
            BackendChoice::Auto => Self::auto(spelling, config, width, height, deg_per_px),
        }
    }

    fn cpu(
        config: &PipelineConfig,
        width: usize,
        height: usize,
        deg_per_px: f64,
        why: String,
    ) -> Result<Renderer, BackendError> {
        let pipeline = FramePipeline::new(config.clone(), width, height, deg_per_px)?;
        Ok(Renderer::Cpu(Box::new(pipeline), why))
    }

    /// The GPU pipeline's output (`None` on the CPU), for a presenter that
    /// draws it into the caller's textures.
    pub fn frame_source(&self) -> Option<FrameSource> {
        match self {
            Renderer::Cpu(..) => None,
            Renderer::Gpu(g, _) => Some(g.frame_source()),
        }
    }

    /// The GPU pipeline on `ctx`'s device (one this process made, or a
    /// caller's: an OpenXR runtime's); `why` says why it was chosen.
    pub fn on_device(
        ctx: &GpuContext,
        config: &PipelineConfig,
        width: usize,
        height: usize,
        deg_per_px: f64,
        why: &str,
    ) -> Result<Renderer, BackendError> {
        let adapter = adapter_label(ctx.adapter_info());
        let pipeline = GpuFramePipeline::new(ctx, config.clone(), width, height, deg_per_px)?;
        Ok(Renderer::Gpu(
            Box::new(GpuRenderer {
                pipeline,
                adapter,
                kernel: None,
                kernel_stale: true,
                read_backs: 0,
            }),
            why.to_owned(),
        ))
    }

    fn auto(
        spelling: Spelling,
        config: &PipelineConfig,
        width: usize,
        height: usize,
        deg_per_px: f64,
    ) -> Result<Renderer, BackendError> {
        let adapters = probe_adapters();
        if adapters.iter().any(|a| !is_software_adapter(a)) {
            let options = ContextOptions {
                adapter: AdapterChoice::Hardware,
                ..ContextOptions::default()
            };
            let attempt = GpuContext::new(&options)
                .map_err(BackendError::from)
                .and_then(|ctx| {
                    Self::on_device(
                        &ctx,
                        config,
                        width,
                        height,
                        deg_per_px,
                        "auto: hardware GPU present",
                    )
                });
            return match attempt {
                Ok(r) => Ok(r),
                Err(e) => {
                    let e = chain(&e);
                    tracing::warn!("auto: the hardware GPU failed ({e}); using the CPU pipeline");
                    Self::cpu(
                        config,
                        width,
                        height,
                        deg_per_px,
                        format!("auto: the hardware GPU failed: {e}"),
                    )
                }
            };
        }
        let why = match adapters.iter().find(|a| is_software_adapter(a)) {
            Some(soft) => format!(
                "auto: no hardware GPU; the software adapter {} is slower than the CPU pipeline \
                 ({} uses it anyway)",
                adapter_label(soft),
                spelling.of(BackendChoice::Gpu)
            ),
            None => format!(
                "auto: no GPU adapter found on backends {}",
                searched_backends()
            ),
        };
        Self::cpu(config, width, height, deg_per_px, why)
    }

    /// "gpu: llvmpipe (…) (Vulkan, software)" or "cpu".
    pub fn describe(&self) -> String {
        match self {
            Renderer::Cpu(..) => "cpu".to_owned(),
            Renderer::Gpu(g, _) => format!("gpu: {}", g.adapter),
        }
    }

    /// Why this backend was chosen (e.g. "auto: hardware GPU present").
    pub fn reason(&self) -> &str {
        match self {
            Renderer::Cpu(_, why) | Renderer::Gpu(_, why) => why,
        }
    }

    /// The frames are a rectilinear view with these edge tangents (left,
    /// right, up, down): pooling measures angles through the projection
    /// (`FramePipeline::set_view_frustum`). Fails on tangents that are not
    /// finite or ordered, keeping the old geometry.
    pub fn set_view_frustum(&mut self, tan_lrud: [f64; 4]) -> Result<(), BackendError> {
        match self {
            Renderer::Cpu(p, _) => p.set_view_frustum(tan_lrud)?,
            Renderer::Gpu(g, _) => g.pipeline.set_view_frustum(tan_lrud)?,
        }
        Ok(())
    }

    /// Whether the GPU pipeline renders.
    pub fn is_gpu(&self) -> bool {
        matches!(self, Renderer::Gpu(..))
    }

    /// Renders one frame and reads nothing back: `view` is linear RGB in
    /// cd/m² at the renderer's size. On the CPU the display frame is written
    /// into `out` (resized only if its size differs); on the GPU it stays in
    /// the pipeline's output buffer and `out` is left as it is — call
    /// [`Self::read_frame`] when the host needs it. Only the frame's 48-byte
    /// scalars are read back (for the stats). `timings.total_ms` covers the
    /// whole call.
    pub fn render(
        &mut self,
        view: &RgbImage,
        input: &FrameInput,
        out: &mut DisplayFrame,
    ) -> Result<FrameStats, BackendError> {
        match self {
            Renderer::Cpu(p, _) => Ok(p.process(view, input, out)?),
            Renderer::Gpu(g, _) => {
                let start = std::time::Instant::now();
                let mut stats = g.pipeline.process(view, input)?;
                if stats.psf_rebuilt {
                    g.kernel_stale = true;
                }
                stats.timings.total_ms = start.elapsed().as_secs_f64() * 1e3;
                Ok(stats)
            }
        }
    }

    /// Renders the views of one frame, one renderer and output per view
    /// ([`Self::render`] each). A stereo pair of CPU pipelines runs side by
    /// side on the rayon pool (`rayon::join`): each pipeline's own parallel
    /// passes share the same threads, so one eye's serial parts (pooling,
    /// the FFTs' set-up, the row bands' tails) overlap the other eye's work.
    /// GPU pipelines, and a single view, run one after the other. Each
    /// result is written into `stats` at its view's index.
    pub fn render_views(
        eyes: &mut [(&mut Renderer, &mut DisplayFrame)],
        view: &RgbImage,
        inputs: &[FrameInput],
        stats: &mut [FrameStats],
    ) -> Result<(), BackendError> {
        if let (
            [(Renderer::Cpu(a, _), out_a), (Renderer::Cpu(b, _), out_b)],
            [in_a, in_b],
            [s_a, s_b],
        ) = (&mut *eyes, inputs, &mut *stats)
        {
            let (ra, rb) = rayon::join(
                || a.process(view, in_a, out_a),
                || b.process(view, in_b, out_b),
            );
            *s_a = ra?;
            *s_b = rb?;
            return Ok(());
        }
        for (((renderer, out), input), s) in eyes.iter_mut().zip(inputs).zip(stats.iter_mut()) {
            *s = renderer.render(view, input, out)?;
        }
        Ok(())
    }

    /// Brings the last rendered frame to the host in `out` (resized only if
    /// its size differs; no allocation in steady state): on the GPU a
    /// blocking read-back, counted in [`Self::frames_read_back`]; on the CPU
    /// nothing to do (the frame is in `out` since [`Self::render`]).
    pub fn read_frame(&mut self, out: &mut DisplayFrame) -> Result<(), BackendError> {
        let Renderer::Gpu(g, _) = self else {
            return Ok(());
        };
        let frame = g.pipeline.display()?;
        g.read_backs += 1;
        if out.width != frame.width || out.height != frame.height {
            *out = DisplayFrame::new(frame.width, frame.height);
        }
        if out.rgba8.len() != frame.rgba8.len() {
            return Err(BackendError::FrameSize {
                bytes: frame.rgba8.len(),
                width: frame.width,
                height: frame.height,
                expected: out.rgba8.len(),
            });
        }
        out.rgba8.copy_from_slice(&frame.rgba8);
        Ok(())
    }

    /// [`Self::render`] then [`Self::read_frame`]: one frame, on the host.
    pub fn process(
        &mut self,
        view: &RgbImage,
        input: &FrameInput,
        out: &mut DisplayFrame,
    ) -> Result<FrameStats, BackendError> {
        let stats = self.render(view, input, out)?;
        self.read_frame(out)?;
        Ok(stats)
    }

    /// Offers the last rendered frame to a window's `slot`: on the CPU a
    /// copy of `out` (the window uploads it); on the GPU only a note that a
    /// new frame is in the output buffer, which the window draws on the
    /// pipeline's own device (the buffer is handed over once, as a
    /// [`FrameSource`]). Never blocks.
    pub fn show<S: FrameSink + ?Sized>(&self, slot: &S, out: &DisplayFrame) {
        match self {
            Renderer::Cpu(..) => slot.put(&out.rgba8),
            Renderer::Gpu(g, _) => slot.put_gpu(|| g.frame_source()),
        }
    }

    /// Display frames read back to the host so far (always 0 on the CPU).
    pub fn frames_read_back(&self) -> u64 {
        match self {
            Renderer::Cpu(..) => 0,
            Renderer::Gpu(g, _) => g.read_backs,
        }
    }

    /// Copies the last frame's retinal image (linear RGB in cd/m² after
    /// glare and acuity, before tone mapping) into `out`; read back
    /// (blocking) on the GPU.
    pub fn retinal(&mut self, out: &mut RgbImage) -> Result<(), BackendError> {
        match self {
            Renderer::Cpu(p, _) => {
                let img = p.retinal();
                if img.pixels.is_empty() {
                    return Err(BackendError::NoRetinal);
                }
                if out.width != img.width || out.height != img.height {
                    *out = RgbImage::new(img.width, img.height);
                }
                out.pixels.copy_from_slice(&img.pixels);
                Ok(())
            }
            Renderer::Gpu(g, _) => Ok(g.pipeline.read_retinal(out)?),
        }
    }

    /// The current PSF kernel at display pixels (`None` with glare off). On
    /// the GPU it is read back (blocking) the first time after a rebuild and
    /// cached: call it on rebuilds, not every frame.
    pub fn psf_kernel(&mut self) -> Result<Option<&PsfKernel>, BackendError> {
        match self {
            Renderer::Cpu(p, _) => Ok(p.psf_kernel()),
            Renderer::Gpu(g, _) => {
                let Some(psf) = g.pipeline.psf() else {
                    return Ok(None);
                };
                if g.kernel_stale || g.kernel.is_none() {
                    g.kernel = Some(psf.read_kernel()?);
                    g.kernel_stale = false;
                }
                Ok(g.kernel.as_ref())
            }
        }
    }

    /// Whether a frame rebuilds the PSF itself when the pupil moves (the
    /// default; `render` and `replay` rely on it). `run` turns it off and
    /// installs kernels built off the frame thread with
    /// [`Renderer::set_kernel`].
    pub fn set_psf_auto_rebuild(&mut self, on: bool) {
        match self {
            Renderer::Cpu(p, _) => p.set_psf_auto_rebuild(on),
            Renderer::Gpu(g, _) => g.pipeline.set_psf_auto_rebuild(on),
        }
    }

    /// Installs a kernel built elsewhere with the pipeline's PSF parameters
    /// (same size and pixel size): later frames convolve with it. On the
    /// GPU it is uploaded and the next frame computes its spectra.
    pub fn set_kernel(&mut self, kernel: &PsfKernel) -> Result<(), BackendError> {
        match self {
            Renderer::Cpu(p, _) => Ok(p.set_kernel(kernel)?),
            Renderer::Gpu(g, _) => {
                g.pipeline.set_kernel(kernel)?;
                g.kernel_stale = true;
                Ok(())
            }
        }
    }

    /// A preparer of the CPU convolver's spectra, for the thread that
    /// builds kernels (`None` on the GPU, which makes its spectra itself,
    /// and with glare off).
    pub fn kernel_preparer(&self) -> Option<gazelight_vision::glare::GlarePreparer> {
        match self {
            Renderer::Cpu(p, _) => p.kernel_preparer(),
            Renderer::Gpu(..) => None,
        }
    }

    /// Installs a kernel prepared off the frame thread: on the CPU by
    /// swapping buffers (`FramePipeline::install_prepared`: no FFT, no
    /// allocation; `prepared` gets the previous kernel back); on the GPU it
    /// is uploaded as by [`Renderer::set_kernel`].
    pub fn install_prepared(
        &mut self,
        prepared: &mut gazelight_vision::glare::PreparedKernel,
    ) -> Result<(), BackendError> {
        if let Renderer::Cpu(p, _) = self {
            return Ok(p.install_prepared(prepared)?);
        }
        self.set_kernel(&prepared.kernel)
    }

    /// Sets the adaptation state (the backend tests start both backends
    /// adapted; no command does).
    pub fn set_adaptation(&mut self, state: gazelight_vision::temporal::AdaptationState) {
        match self {
            Renderer::Cpu(p, _) => p.set_adaptation(state),
            Renderer::Gpu(g, _) => g.pipeline.set_adaptation(state),
        }
    }
}

/// One renderer per view of `view` (`gazelight_render::frame::views(stereo)`:
/// one, or a stereo pair), chosen by `choice` as [`Renderer::choose`] does
/// (named in messages as `spelling` writes it), for `view`'s frames with
/// `config`; pooling measures angles through the view's projection. The
/// choosable counterpart of `gazelight_render::frame::cpu_pipelines`
/// (Python's `render`).
pub fn view_renderers(
    choice: BackendChoice,
    spelling: Spelling,
    config: &PipelineConfig,
    view: &ViewParams,
    stereo: bool,
) -> Result<Vec<Renderer>, BackendError> {
    let frustum = PanoramaView::new(*view)?.frustum_tans();
    gazelight_render::frame::views(stereo)
        .iter()
        .map(|_| {
            let mut r = Renderer::choose(
                choice,
                spelling,
                config,
                view.width,
                view.height,
                view.deg_per_px(),
            )?;
            r.set_view_frustum(frustum)?;
            Ok(r)
        })
        .collect()
}

/// The frame step of `render` and `replay` (`gazelight_render::frame`)
/// drives either pipeline through this; the errors keep their causes in
/// their message (`outer: inner`, as the CLI prints them).
impl gazelight_render::frame::ViewRenderer for Renderer {
    fn render_views(
        eyes: &mut [(&mut Self, &mut DisplayFrame)],
        view: &RgbImage,
        inputs: &[FrameInput],
        stats: &mut [FrameStats],
    ) -> Result<(), RenderError> {
        Renderer::render_views(eyes, view, inputs, stats).map_err(pipeline_error)
    }

    fn read_frame(&mut self, out: &mut DisplayFrame) -> Result<(), RenderError> {
        Renderer::read_frame(self, out).map_err(pipeline_error)
    }

    fn retinal(&mut self, out: &mut RgbImage) -> Result<(), RenderError> {
        Renderer::retinal(self, out).map_err(pipeline_error)
    }

    fn psf_kernel(&mut self) -> Result<Option<&PsfKernel>, RenderError> {
        Renderer::psf_kernel(self).map_err(pipeline_error)
    }

    fn set_psf_auto_rebuild(&mut self, on: bool) {
        Renderer::set_psf_auto_rebuild(self, on);
    }

    fn set_kernel(&mut self, kernel: &PsfKernel) -> Result<(), RenderError> {
        Renderer::set_kernel(self, kernel).map_err(pipeline_error)
    }

    fn set_initial_target(&mut self, cd_m2: f64) {
        match self {
            Renderer::Cpu(p, _) => p.set_initial_target(cd_m2),
            Renderer::Gpu(g, _) => g.pipeline.set_initial_target(cd_m2),
        }
    }
}

fn pipeline_error(e: BackendError) -> RenderError {
    RenderError::Pipeline(chain(&e))
}

#[cfg(test)]
mod tests;
