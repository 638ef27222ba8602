//! Which frame pipeline renders: the wgpu one of `gazelight-gpu` or the CPU
//! reference of `gazelight-vision` (DESIGN.md, "Every stage exists twice").
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
//!   pipeline's fused per-pixel stages, so it is slower, not a speed-up
//!   (measured figures in the `render --backend` help and the tests of
//!   `tests/backend.rs`). `--backend gpu` still picks it on purpose (parity
//!   checks on CI).
//! * No adapter, or the GPU pipeline cannot be built on the hardware one →
//!   the CPU pipeline.
//!
//! The choice and its reason are logged (`tracing::info!`) and printed as one
//! line on stderr.

use anyhow::{Context, bail};
use gazelight_gpu::{AdapterChoice, ContextOptions, GpuContext, GpuFramePipeline};
use gazelight_vision::RgbImage;
use gazelight_vision::pipeline::{
    DisplayFrame, FrameInput, FramePipeline, FrameStats, PipelineConfig,
};
use gazelight_vision::psf::PsfKernel;
use gazelight_vision::temporal::AdaptationState;

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
}

/// The frame pipeline that renders: GPU or CPU.
pub enum Renderer {
    /// The CPU reference pipeline; the string says why it was chosen.
    Cpu(Box<FramePipeline>, String),
    /// The GPU pipeline; the string says why it was chosen.
    Gpu(Box<GpuRenderer>, String),
}

/// One line per adapter that the (env-filtered) wgpu backends list.
fn probe_adapters() -> Vec<wgpu::AdapterInfo> {
    let instance =
        wgpu::Instance::new(wgpu::InstanceDescriptor::new_without_display_handle_from_env());
    let backends = wgpu::Backends::all().with_env();
    pollster::block_on(instance.enumerate_adapters(backends))
        .iter()
        .map(wgpu::Adapter::get_info)
        .collect()
}

fn is_software(info: &wgpu::AdapterInfo) -> bool {
    info.device_type == wgpu::DeviceType::Cpu
}

/// "llvmpipe (LLVM 19.1.7, 256 bits) (Vulkan, software)".
fn adapter_label(info: &wgpu::AdapterInfo) -> String {
    format!(
        "{} ({}, {})",
        info.name,
        info.backend,
        if is_software(info) {
            "software"
        } else {
            "hardware"
        }
    )
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
                Self::gpu(&ctx, config, width, height, deg_per_px, "--backend gpu")
                    .context("--backend gpu: cannot build the GPU pipeline (try --backend cpu)")?
            }
            BackendChoice::Auto => Self::auto(config, width, height, deg_per_px)?,
        };
        let (backend, adapter, reason) = match &renderer {
            Renderer::Cpu(_, why) => ("cpu", "-", why.as_str()),
            Renderer::Gpu(g, why) => ("gpu", g.adapter.as_str(), why.as_str()),
        };
        tracing::info!(backend, adapter, reason, requested = %choice, "frame pipeline backend");
        eprintln!("backend: {} ({reason})", renderer.describe());
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

    fn gpu(
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
        if adapters.iter().any(|a| !is_software(a)) {
            let options = ContextOptions {
                adapter: AdapterChoice::Hardware,
                ..ContextOptions::default()
            };
            let attempt = GpuContext::new(&options)
                .map_err(anyhow::Error::from)
                .and_then(|ctx| {
                    Self::gpu(
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
        let why = match adapters.iter().find(|a| is_software(a)) {
            Some(soft) => format!(
                "auto: no hardware GPU; the software adapter {} is slower than the CPU pipeline \
                 (--backend gpu uses it anyway)",
                adapter_label(soft)
            ),
            None => format!(
                "auto: no GPU adapter found on backends {:?}",
                wgpu::Backends::all().with_env()
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
    #[allow(dead_code)] // for `run`'s status output, being wired
    pub fn reason(&self) -> &str {
        match self {
            Renderer::Cpu(_, why) | Renderer::Gpu(_, why) => why,
        }
    }

    /// Whether the GPU pipeline renders.
    #[allow(dead_code)] // for `run`, being wired
    pub fn is_gpu(&self) -> bool {
        matches!(self, Renderer::Gpu(..))
    }

    /// Processes one frame: `view` is linear RGB in cd/m² at the renderer's
    /// size; `out` receives the display frame (resized only if its size
    /// differs). On the GPU: submit, read back the frame's scalars and the
    /// RGBA8 frame, copy it into `out` (no allocation in steady state).
    /// `timings.total_ms` covers the whole call, read-back included.
    pub fn process(
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
                let frame = g.pipeline.display()?;
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
                if stats.psf_rebuilt {
                    g.kernel_stale = true;
                }
                stats.timings.total_ms = start.elapsed().as_secs_f64() * 1e3;
                Ok(stats)
            }
        }
    }

    /// The current PSF kernel at display pixels (`None` with glare off). On
    /// the GPU it is read back (blocking) the first time after a rebuild and
    /// cached: call it on rebuilds, not every frame.
    #[allow(dead_code)] // for `run`'s psf.csv and status page, being wired
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

    /// Sets the adaptation state (e.g. to start a replay adapted).
    #[allow(dead_code)] // for `run`, being wired
    pub fn set_adaptation(&mut self, state: AdaptationState) {
        match self {
            Renderer::Cpu(p, _) => p.set_adaptation(state),
            Renderer::Gpu(g, _) => g.pipeline.set_adaptation(state),
        }
    }
}
