//! Which frame pipeline renders: the wgpu one of `gazelight-gpu` or the CPU
//! reference of `gazelight-vision` (ARCHITECTURE.md, "Every stage exists twice").
//!
//! [`Renderer`] hides the choice behind one per-frame call with the CPU
//! pipeline's signature, so `render`, `replay` and `run` drive either.
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
//!   against 25–85 ms on the CPU pipeline. `--backend gpu` still picks it on
//!   purpose (parity checks on CI, `tests/backend.rs`).
//! * No adapter, or the GPU pipeline cannot be built on the hardware one →
//!   the CPU pipeline.
//!
//! The choice and its reason are logged (`tracing::info!`) and printed as one
//! line on stderr.
//!
//! # Frames stay where they are rendered
//!
//! [`Renderer::render`] renders a frame and reads nothing back: on the GPU
//! the display frame stays in the pipeline's output buffer, which the window
//! draws directly ([`Renderer::show`] hands it over once as a
//! [`FrameSource`]). Only a consumer on the host — the file writer of
//! `--out`, every frame; the status page, at its own rate — calls
//! [`Renderer::read_frame`], and each GPU read-back is counted
//! ([`Renderer::frames_read_back`], in the status JSON and the run summary).
//! On the CPU the frame is on the host already (0 read-backs); the window
//! uploads it.

use anyhow::{Context, bail};
use gazelight_gpu::context::{is_software_adapter, probe_adapters, searched_backends};
use gazelight_gpu::present::FrameSource;
use gazelight_gpu::{AdapterChoice, ContextOptions, GpuContext, GpuFramePipeline};
use gazelight_render::RenderError;
use gazelight_vision::RgbImage;
use gazelight_vision::pipeline::{
    DisplayFrame, FrameInput, FramePipeline, FrameStats, PipelineConfig,
};
use gazelight_vision::psf::PsfKernel;

use crate::window::DisplaySlot;

/// The `--backend` flag.
#[derive(clap::ValueEnum, Clone, Copy, Debug, Default, PartialEq, Eq)]
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

impl std::fmt::Display for BackendChoice {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        f.write_str(match self {
            BackendChoice::Auto => "auto",
            BackendChoice::Gpu => "gpu",
            BackendChoice::Cpu => "cpu",
        })
    }
}

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

/// The frame pipeline that renders: GPU or CPU.
pub enum Renderer {
    /// The CPU reference pipeline; the string says why it was chosen.
    Cpu(Box<FramePipeline>, String),
    /// The GPU pipeline; the string says why it was chosen.
    Gpu(Box<GpuRenderer>, String),
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
    /// Picks and builds the pipeline for `width × height` frames whose
    /// pixels subtend `deg_per_px` degrees (see the module docs for `auto`).
    /// Logs the choice with the adapter and the reason.
    pub fn new(
        choice: BackendChoice,
        config: &PipelineConfig,
        width: usize,
        height: usize,
        deg_per_px: f64,
    ) -> anyhow::Result<Renderer> {
        let renderer = match choice {
            BackendChoice::Cpu => {
                Self::cpu(config, width, height, deg_per_px, "--backend cpu".into())?
            }
            BackendChoice::Gpu => {
                let ctx = GpuContext::new(&ContextOptions::default()).map_err(|e| {
                    anyhow::anyhow!(
                        "--backend gpu: {e}. Use --backend cpu to render on the CPU \
                         (or --backend auto to fall back to it when there is no hardware GPU)"
                    )
                })?;
                Self::on_device(&ctx, config, width, height, deg_per_px, "--backend gpu")
                    .context("--backend gpu: cannot build the GPU pipeline (try --backend cpu)")?
            }
            BackendChoice::Auto => Self::auto(config, width, height, deg_per_px)?,
        };
        let (backend, adapter, reason) = match &renderer {
            Renderer::Cpu(_, why) => ("cpu", "-", why.as_str()),
            Renderer::Gpu(g, why) => ("gpu", g.adapter.as_str(), why.as_str()),
        };
        if first_time(format!("backend: {} ({reason})", renderer.describe())) {
            tracing::info!(backend, adapter, reason, requested = %choice, "frame pipeline backend");
        }
        Ok(renderer)
    }

    fn cpu(
        config: &PipelineConfig,
        width: usize,
        height: usize,
        deg_per_px: f64,
        why: String,
    ) -> anyhow::Result<Renderer> {
        let pipeline = FramePipeline::new(config.clone(), width, height, deg_per_px)?;
        Ok(Renderer::Cpu(Box::new(pipeline), why))
    }

    /// The GPU pipeline's output (`None` on the CPU), for a presenter that
    /// draws it into the caller's textures.
    pub fn frame_source(&self) -> Option<FrameSource> {
        match self {
            Renderer::Cpu(..) => None,
            Renderer::Gpu(g, _) => Some(FrameSource::of(&g.pipeline)),
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
    ) -> anyhow::Result<Renderer> {
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
        config: &PipelineConfig,
        width: usize,
        height: usize,
        deg_per_px: f64,
    ) -> anyhow::Result<Renderer> {
        let adapters = probe_adapters();
        if adapters.iter().any(|a| !is_software_adapter(a)) {
            let options = ContextOptions {
                adapter: AdapterChoice::Hardware,
                ..ContextOptions::default()
            };
            let attempt = GpuContext::new(&options)
                .map_err(anyhow::Error::from)
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
                    tracing::warn!("auto: the hardware GPU failed ({e:#}); using the CPU pipeline");
                    Self::cpu(
                        config,
                        width,
                        height,
                        deg_per_px,
                        format!("auto: the hardware GPU failed: {e:#}"),
                    )
                }
            };
        }
        let why = match adapters.iter().find(|a| is_software_adapter(a)) {
            Some(soft) => format!(
                "auto: no hardware GPU; the software adapter {} is slower than the CPU pipeline \
                 (--backend gpu uses it anyway)",
                adapter_label(soft)
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
    pub fn set_view_frustum(&mut self, tan_lrud: [f64; 4]) -> anyhow::Result<()> {
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
    ) -> anyhow::Result<FrameStats> {
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
    ) -> anyhow::Result<()> {
        if let ([(Renderer::Cpu(a, _), out_a), (Renderer::Cpu(b, _), out_b)], [in_a, in_b]) =
            (&mut *eyes, inputs)
        {
            let (ra, rb) = rayon::join(
                || a.process(view, in_a, out_a),
                || b.process(view, in_b, out_b),
            );
            stats[0] = ra?;
            stats[1] = rb?;
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
    pub fn read_frame(&mut self, out: &mut DisplayFrame) -> anyhow::Result<()> {
        let Renderer::Gpu(g, _) = self else {
            return Ok(());
        };
        let frame = g.pipeline.display()?;
        g.read_backs += 1;
        if out.width != frame.width || out.height != frame.height {
            *out = DisplayFrame::new(frame.width, frame.height);
        }
        if out.rgba8.len() != frame.rgba8.len() {
            bail!(
                "GPU display frame: {} bytes for {}x{}, expected {}",
                frame.rgba8.len(),
                frame.width,
                frame.height,
                out.rgba8.len()
            );
        }
        out.rgba8.copy_from_slice(&frame.rgba8);
        Ok(())
    }

    /// [`Self::render`] then [`Self::read_frame`] (the tests' one-call frame).
    #[cfg(test)]
    pub fn process(
        &mut self,
        view: &RgbImage,
        input: &FrameInput,
        out: &mut DisplayFrame,
    ) -> anyhow::Result<FrameStats> {
        let stats = self.render(view, input, out)?;
        self.read_frame(out)?;
        Ok(stats)
    }

    /// Offers the last rendered frame to the window: on the CPU a copy of
    /// `out` into the slot (the window uploads it); on the GPU only a note
    /// that a new frame is in the output buffer, which the window draws on
    /// the pipeline's own device (the buffer is handed over once, as a
    /// [`FrameSource`]). Never blocks; allocates only the first time.
    pub fn show(&self, slot: &DisplaySlot, out: &DisplayFrame) {
        match self {
            Renderer::Cpu(..) => slot.put(&out.rgba8),
            Renderer::Gpu(g, _) => slot.put_gpu(|| FrameSource::of(&g.pipeline)),
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
    pub fn retinal(&mut self, out: &mut RgbImage) -> anyhow::Result<()> {
        match self {
            Renderer::Cpu(p, _) => {
                let img = p.retinal();
                anyhow::ensure!(
                    !img.pixels.is_empty(),
                    "the CPU pipeline was built without keep_retinal: no retinal image to read"
                );
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
    pub fn psf_kernel(&mut self) -> anyhow::Result<Option<&PsfKernel>> {
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
    pub fn set_kernel(&mut self, kernel: &PsfKernel) -> anyhow::Result<()> {
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
    ) -> anyhow::Result<()> {
        if let Renderer::Cpu(p, _) = self {
            return Ok(p.install_prepared(prepared)?);
        }
        self.set_kernel(&prepared.kernel)
    }

    /// Sets the adaptation state (the backend test starts both backends
    /// adapted; no command does).
    #[cfg(test)]
    pub fn set_adaptation(&mut self, state: gazelight_vision::temporal::AdaptationState) {
        match self {
            Renderer::Cpu(p, _) => p.set_adaptation(state),
            Renderer::Gpu(g, _) => g.pipeline.set_adaptation(state),
        }
    }
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

fn pipeline_error(e: anyhow::Error) -> RenderError {
    RenderError::Pipeline(format!("{e:#}"))
}

#[cfg(test)]
mod tests {
    use super::*;
    use gazelight_gpu::testing::test_context;
    use gazelight_vision::scene::{LuminanceScale, PanoramaView, Scene};
    use gazelight_vision::temporal::AdaptationState;

    /// The embedded night panorama seen towards the street lamp, at `w × h`.
    fn demo_view(w: usize, h: usize) -> (RgbImage, f64) {
        let scene = Scene::from_bytes(
            crate::demo::NIGHT_EXR,
            crate::demo::name_path(),
            LuminanceScale::default(),
        )
        .unwrap();
        let view = crate::demo::default_view(w, h);
        let mut img = RgbImage::new(w, h);
        PanoramaView::new(view)
            .unwrap()
            .render(&scene.image, &mut img);
        (img, view.deg_per_px())
    }

    /// Max |GPU − CPU| over pixels and channels, relative to the CPU peak.
    fn kernel_error(gpu: &PsfKernel, cpu: &PsfKernel) -> f64 {
        assert_eq!(gpu.size, cpu.size);
        let peak = cpu.rgb.iter().flatten().fold(0.0f32, |a, &b| a.max(b));
        let diff = gpu
            .rgb
            .iter()
            .zip(&cpu.rgb)
            .flat_map(|(g, c)| (0..3).map(move |k| (g[k] - c[k]).abs()))
            .fold(0.0f32, f32::max);
        f64::from(diff / peak)
    }

    /// With the in-frame rebuild off, a kernel built elsewhere and installed
    /// with `set_kernel` is the one both backends convolve with: the frames
    /// match each other within 1/255 and each backend's kernel reads back as
    /// the installed one, not the initial 4 mm one (at 96×80 the two differ
    /// by under 1e-4 of the peak: the Airy core is inside one pixel).
    #[test]
    fn an_installed_kernel_is_used_on_both_backends() {
        let Some(_ctx) = test_context("an_installed_kernel_is_used_on_both_backends") else {
            return;
        };
        let (w, h) = (96, 80);
        let (view, deg_per_px) = demo_view(w, h);
        let config = PipelineConfig::default();
        let mut params = config.glare.psf.clone();
        params.ppd = 1.0 / deg_per_px;
        let mut builder = gazelight_vision::psf::PsfBuilder::new(params).unwrap();
        let kernel = builder.rebuild(7.0).clone();
        let input = FrameInput {
            gaze_uv: [0.5, 0.4],
            pupil_mm: 7.0,
            dt_secs: 0.0,
        };
        let mut frames = Vec::new();
        for choice in [BackendChoice::Cpu, BackendChoice::Gpu] {
            let mut r = Renderer::new(choice, &config, w, h, deg_per_px).unwrap();
            r.set_psf_auto_rebuild(false);
            let mut before = DisplayFrame::new(w, h);
            let s0 = r.process(&view, &input, &mut before).unwrap();
            assert!(!s0.psf_rebuilt, "{choice}: rebuilt in the frame");
            assert_eq!(s0.psf_pupil_mm, 4.0, "{choice}");
            let initial = r.psf_kernel().unwrap().unwrap().clone();
            assert!(
                initial.rgb != kernel.rgb && initial.pupil_mm == 4.0,
                "{choice}: 4 mm = 7 mm kernel"
            );
            r.set_kernel(&kernel).unwrap();
            let mut after = DisplayFrame::new(w, h);
            let s1 = r.process(&view, &input, &mut after).unwrap();
            assert_eq!(s1.psf_pupil_mm, 7.0, "{choice}");
            let back = r.psf_kernel().unwrap().unwrap().clone();
            assert!(
                kernel_error(&back, &kernel) <= 1e-6,
                "{choice}: kernel read back"
            );
            frames.push(after);
        }
        let max_diff = frames[0]
            .rgba8
            .iter()
            .zip(&frames[1].rgba8)
            .map(|(a, b)| a.abs_diff(*b))
            .max()
            .unwrap();
        assert!(
            max_diff <= 1,
            "CPU vs GPU with the installed kernel: {max_diff}/255"
        );
    }

    /// The pupils of [`crate::bad_pupils::SEQUENCE`] (NaN, ±∞, 0, −3, 20 mm,
    /// f32::MAX among good ones) give the same kernels on the offline CPU
    /// pipeline and the GPU frame: the table's, read back from each
    /// backend's kernel as well as its frame statistics.
    #[test]
    fn bad_pupils_give_the_same_kernels_on_both_backends() {
        let (w, h) = (64, 48);
        let (view, deg_per_px) = demo_view(w, h);
        let mut config = PipelineConfig::default();
        // A small field keeps the eleven kernel builds quick.
        config.glare.psf.field_deg = 8.0;
        let gpu = test_context("bad_pupils_give_the_same_kernels_on_both_backends").is_some();
        let choices: &[BackendChoice] = if gpu {
            &[BackendChoice::Cpu, BackendChoice::Gpu]
        } else {
            &[BackendChoice::Cpu]
        };
        for &choice in choices {
            let mut r = Renderer::new(choice, &config, w, h, deg_per_px).unwrap();
            let mut out = DisplayFrame::new(w, h);
            for (i, &(pupil_mm, want_mm)) in crate::bad_pupils::SEQUENCE.iter().enumerate() {
                let input = FrameInput {
                    gaze_uv: [0.5, 0.4],
                    pupil_mm,
                    dt_secs: 1.0 / 90.0,
                };
                let stats = r.process(&view, &input, &mut out).unwrap();
                let kernel_mm = r.psf_kernel().unwrap().unwrap().pupil_mm;
                assert!(
                    (stats.psf_pupil_mm - want_mm).abs() < 1e-9
                        && (kernel_mm - want_mm).abs() < 1e-9,
                    "{choice}, step {i}: pupil {pupil_mm} mm gave kernel {kernel_mm} mm \
                     (stats {}), want {want_mm} mm",
                    stats.psf_pupil_mm
                );
                assert!(
                    out.rgba8.iter().any(|&v| v > 0),
                    "{choice}, step {i}: black frame"
                );
            }
        }
    }

    /// The GPU renderer's kernel is read back again after a rebuild (not the
    /// stale cached copy), matches the CPU's, and a set adaptation state
    /// carries over on both backends.
    #[test]
    fn psf_kernel_and_adaptation_follow_on_both_backends() {
        let Some(ctx) = test_context("psf_kernel_and_adaptation_follow_on_both_backends") else {
            return;
        };
        let (w, h) = (96, 80);
        let (view, deg_per_px) = demo_view(w, h);
        let config = PipelineConfig::default();
        let mut cpu = Renderer::new(BackendChoice::Cpu, &config, w, h, deg_per_px).unwrap();
        let mut gpu = Renderer::new(BackendChoice::Gpu, &config, w, h, deg_per_px).unwrap();
        assert!(!cpu.is_gpu() && gpu.is_gpu());
        assert_eq!(cpu.describe(), "cpu");
        assert!(
            gpu.describe().contains(&ctx.adapter_info().name),
            "{}",
            gpu.describe()
        );
        println!("{} / {} ({})", cpu.describe(), gpu.describe(), gpu.reason());

        // Start both adapted to 50 cd/m² (photopic), far from the night
        // scene's ~0.01–1 cd/m², so the first frame's adaptation shows it.
        let start = AdaptationState::new(50.0);
        cpu.set_adaptation(start);
        gpu.set_adaptation(start);
        let (mut out_cpu, mut out_gpu) = (DisplayFrame::new(w, h), DisplayFrame::new(w, h));
        for (i, pupil_mm) in [4.0f32, 4.0, 6.5, 6.5, 2.5].into_iter().enumerate() {
            let input = FrameInput {
                gaze_uv: [0.5, 0.4],
                pupil_mm,
                dt_secs: 1.0 / 30.0,
            };
            let sc = cpu.process(&view, &input, &mut out_cpu).unwrap();
            let sg = gpu.process(&view, &input, &mut out_gpu).unwrap();
            assert_eq!(sc.psf_rebuilt, sg.psf_rebuilt, "frame {i}");
            let rel = (sc.adaptation_cd_m2 - sg.adaptation_cd_m2).abs() / sc.adaptation_cd_m2;
            assert!(rel <= 1e-4, "frame {i}: {sc:?} vs {sg:?}");
            if i == 0 {
                // One 33 ms step from 50 cd/m² stays far above the scene.
                assert!(sc.adaptation_cd_m2 > 5.0 * sc.target_cd_m2, "{sc:?}");
            }
            let kc = cpu.psf_kernel().unwrap().unwrap().clone();
            let kg = gpu.psf_kernel().unwrap().unwrap().clone();
            assert_eq!(
                kg.pupil_mm,
                f64::from(pupil_mm),
                "frame {i}: stale GPU kernel"
            );
            assert_eq!(kc.pupil_mm, kg.pupil_mm);
            let err = kernel_error(&kg, &kc);
            println!("frame {i}: pupil {pupil_mm} mm, kernel max error {err:e} of the peak");
            assert!(err <= 1e-4, "frame {i}: kernel error {err:e}");
            let max_diff = out_cpu
                .rgba8
                .iter()
                .zip(&out_gpu.rgba8)
                .map(|(a, b)| a.abs_diff(*b))
                .max()
                .unwrap();
            assert!(
                max_diff <= 1,
                "frame {i}: display differs by {max_diff}/255"
            );
        }
    }
}
