//! Presentation: the display frame into a window's surface, on the frame
//! pipeline's own device (ARCHITECTURE.md, "Threads": GPU frames go to the display
//! without a round trip through host memory).
//!
//! A [`WindowPresenter`] owns the surface of one window and one render pass
//! (`shaders/present.wgsl`, loaded through [`crate::shaders`] and checked
//! like every other shader of the crate). It draws one of three things:
//!
//! * a **GPU frame**: the RGBA8 output buffer of a [`GpuFramePipeline`]
//!   ([`FrameSource`]), read directly by the fragment shader — on the
//!   pipeline's device and queue, so the frame never leaves the GPU. The
//!   queue orders the present pass after the frame that was submitted
//!   before it, and the next frame's passes after the present pass;
//! * a **host frame** (the CPU pipeline's): uploaded into the presenter's own
//!   buffer of the same layout ([`WindowPresenter::upload`]) — the one copy a
//!   CPU-rendered frame cannot avoid;
//! * a **solid colour** filling the surface (calibration stimuli).
//!
//! The frame is letterboxed to keep its aspect ([`letterbox_scale`]) and
//! filtered bilinearly; at 1:1 scale each window pixel is its frame pixel's
//! code exactly (the window tests compare screenshots with written frames).
//! The surface is configured FIFO (vsync) in a non-sRGB format, since the
//! frame is already display-encoded.
//!
//! The window itself (event loop, input) belongs to the caller: the
//! presenter takes anything with a window and display handle (a
//! `winit::window::Window` in an `Arc`), so this crate needs no windowing
//! library and host renderers keep their own.
//!
//! ```no_run
//! # fn demo(pipeline: &gazelight_gpu::GpuFramePipeline,
//! #         window: impl Into<wgpu::SurfaceTarget<'static>>)
//! #     -> Result<(), gazelight_gpu::GpuError> {
//! use gazelight_gpu::present::{FrameSource, WindowPresenter};
//! // On the frame thread: what to draw (the pipeline's output buffer).
//! let source = FrameSource::of(pipeline);
//! // On the window's thread (e.g. an `Arc<winit::window::Window>`):
//! let mut presenter = WindowPresenter::on_pipeline(&source, window, [720, 800])?;
//! presenter.present_frame()?; // each redraw: the newest frame, no read-back
//! # Ok(()) }
//! ```

use bytemuck::{Pod, Zeroable};

use crate::context::{ContextOptions, GpuContext};
use crate::error::GpuError;
use crate::frame::GpuFramePipeline;
use crate::shaders::{PRESENT, check_shader};

/// Uniforms of `present.wgsl` (`struct PresentParams`; the naga test below
/// checks sizes and offsets).
#[repr(C)]
#[derive(Clone, Copy, Debug, Default, PartialEq, Pod, Zeroable)]
pub struct PresentParams {
    /// Scale of the frame quad in clip space (≤ 1 on each axis).
    pub scale: [f32; 2],
    /// Frame size, pixels (width, height).
    pub frame_size: [u32; 2],
    /// Solid colour (the encoded value / 255) with w = 1, or w = 0 to draw
    /// the frame.
    pub solid: [f32; 4],
    /// 1: the target is an sRGB format (an OpenXR swapchain image), which
    /// encodes what the shader writes, so the shader writes the frame's
    /// codes decoded to linear; 0: a UNORM target takes the codes as they
    /// are.
    pub decode_srgb: u32,
    /// Padding to the uniform's 16-byte size.
    pub _pad: [u32; 3],
}

/// A GPU frame to present: a pipeline's device and its RGBA8 output buffer
/// (`width·height` packed `u32`, bytes r g b a). Cheap to clone and `Send`,
/// so the frame thread can hand it to the window's thread.
#[derive(Clone, Debug)]
pub struct FrameSource {
    ctx: GpuContext,
    buffer: wgpu::Buffer,
    width: u32,
    height: u32,
}

impl FrameSource {
    /// The output of `pipeline` (whatever buffer is bound as its output).
    pub fn of(pipeline: &GpuFramePipeline) -> Self {
        Self {
            ctx: pipeline.context().clone(),
            buffer: pipeline.output_buffer().clone(),
            width: pipeline.width() as u32,
            height: pipeline.height() as u32,
        }
    }

    /// Frame size, pixels.
    pub fn size(&self) -> [u32; 2] {
        [self.width, self.height]
    }

    /// The device the frame lives on.
    pub fn context(&self) -> &GpuContext {
        &self.ctx
    }
}

/// What one [`WindowPresenter::present_frame`] or
/// [`WindowPresenter::present_solid`] call did.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum Presented {
    /// A surface image was drawn and queued for display.
    Shown,
    /// The surface was outdated or lost (reconfigured), timed out or
    /// occluded: nothing was drawn; try again at the next redraw.
    Skipped,
}

/// Quad scale in clip space that letterboxes a `frame` into a `window`
/// (both width, height in pixels) keeping the frame's aspect.
pub fn letterbox_scale(frame: [u32; 2], window: [u32; 2]) -> [f32; 2] {
    let fa = frame[0] as f32 / frame[1].max(1) as f32;
    let wa = window[0] as f32 / window[1].max(1) as f32;
    if fa > wa {
        [1.0, wa / fa]
    } else {
        [fa / wa, 1.0]
    }
}

/// Tries at configuring a window surface (see [`WindowPresenter::on_pipeline`]).
const CONFIGURE_ATTEMPTS: u32 = 4;

/// Which buffer the present pass reads.
enum Frames {
    /// A pipeline's output buffer (no copy).
    Pipeline,
    /// The presenter's own buffer, filled by [`WindowPresenter::upload`].
    Uploaded,
}

/// The present render pass: `present.wgsl` reading one RGBA8 frame buffer,
/// drawing into a colour target of one format.
struct PresentPass {
    pipeline: wgpu::RenderPipeline,
    bind_group: wgpu::BindGroup,
    params: wgpu::Buffer,
}

/// A window surface and the present pass, on one device. See the module docs.
pub struct WindowPresenter {
    ctx: GpuContext,
    surface: wgpu::Surface<'static>,
    config: wgpu::SurfaceConfiguration,
    pass: PresentPass,
    frame_buffer: wgpu::Buffer,
    frame_size: [u32; 2],
    frames: Frames,
}

fn wgpu_error(what: &str, message: impl std::fmt::Display) -> GpuError {
    GpuError::Wgpu {
        what: what.to_owned(),
        message: message.to_string(),
    }
}

impl PresentPass {
    /// Checks the shader against the device's limits and builds the pass
    /// for `frame_buffer` into targets of `format`.
    fn new(
        ctx: &GpuContext,
        frame_buffer: &wgpu::Buffer,
        format: wgpu::TextureFormat,
    ) -> Result<Self, GpuError> {
        // Parses and validates the WGSL against this device's limits.
        check_shader(&PRESENT, ctx.limits())?;
        let params = ctx.scoped("present params", |device| {
            device.create_buffer(&wgpu::BufferDescriptor {
                label: Some("present params"),
                size: size_of::<PresentParams>() as u64,
                usage: wgpu::BufferUsages::UNIFORM | wgpu::BufferUsages::COPY_DST,
                mapped_at_creation: false,
            })
        })?;
        let (pipeline, bind_group) = ctx.scoped("present pipeline 'present.wgsl'", |device| {
            let layout = device.create_bind_group_layout(&wgpu::BindGroupLayoutDescriptor {
                label: Some("present.wgsl"),
                entries: &[
                    wgpu::BindGroupLayoutEntry {
                        binding: 0,
                        visibility: wgpu::ShaderStages::FRAGMENT,
                        ty: wgpu::BindingType::Buffer {
                            ty: wgpu::BufferBindingType::Storage { read_only: true },
                            has_dynamic_offset: false,
                            min_binding_size: None,
                        },
                        count: None,
                    },
                    wgpu::BindGroupLayoutEntry {
                        binding: 1,
                        visibility: wgpu::ShaderStages::VERTEX_FRAGMENT,
                        ty: wgpu::BindingType::Buffer {
                            ty: wgpu::BufferBindingType::Uniform,
                            has_dynamic_offset: false,
                            min_binding_size: None,
                        },
                        count: None,
                    },
                ],
            });
            let bind_group = device.create_bind_group(&wgpu::BindGroupDescriptor {
                label: Some("present.wgsl"),
                layout: &layout,
                entries: &[
                    wgpu::BindGroupEntry {
                        binding: 0,
                        resource: frame_buffer.as_entire_binding(),
                    },
                    wgpu::BindGroupEntry {
                        binding: 1,
                        resource: params.as_entire_binding(),
                    },
                ],
            });
            let module = device.create_shader_module(wgpu::ShaderModuleDescriptor {
                label: Some(PRESENT.name),
                source: wgpu::ShaderSource::Wgsl(PRESENT.source.into()),
            });
            let pipeline_layout = device.create_pipeline_layout(&wgpu::PipelineLayoutDescriptor {
                label: Some(PRESENT.name),
                bind_group_layouts: &[Some(&layout)],
                immediate_size: 0,
            });
            let pipeline = device.create_render_pipeline(&wgpu::RenderPipelineDescriptor {
                label: Some(PRESENT.name),
                layout: Some(&pipeline_layout),
                vertex: wgpu::VertexState {
                    module: &module,
                    entry_point: Some("vs_main"),
                    compilation_options: Default::default(),
                    buffers: &[],
                },
                primitive: wgpu::PrimitiveState {
                    topology: wgpu::PrimitiveTopology::TriangleStrip,
                    ..Default::default()
                },
                depth_stencil: None,
                multisample: wgpu::MultisampleState::default(),
                fragment: Some(wgpu::FragmentState {
                    module: &module,
                    entry_point: Some("fs_main"),
                    compilation_options: Default::default(),
                    targets: &[Some(wgpu::ColorTargetState {
                        format,
                        blend: None,
                        write_mask: wgpu::ColorWrites::ALL,
                    })],
                }),
                multiview_mask: None,
                cache: None,
            });
            (pipeline, bind_group)
        })?;
        Ok(Self {
            pipeline,
            bind_group,
            params,
        })
    }

    /// Records the pass drawing into `target` with `params`: the whole
    /// target (cleared first), or only its rectangle `rect` = `[x, y,
    /// width, height]` pixels (viewport and scissor; the rest of the target
    /// is kept).
    fn encode(
        &self,
        ctx: &GpuContext,
        encoder: &mut wgpu::CommandEncoder,
        target: &wgpu::TextureView,
        params: &PresentParams,
        rect: Option<[u32; 4]>,
    ) {
        ctx.queue()
            .write_buffer(&self.params, 0, bytemuck::bytes_of(params));
        let mut pass = encoder.begin_render_pass(&wgpu::RenderPassDescriptor {
            label: Some("present"),
            color_attachments: &[Some(wgpu::RenderPassColorAttachment {
                view: target,
                depth_slice: None,
                resolve_target: None,
                ops: wgpu::Operations {
                    load: if rect.is_some() {
                        wgpu::LoadOp::Load
                    } else {
                        wgpu::LoadOp::Clear(wgpu::Color::BLACK)
                    },
                    store: wgpu::StoreOp::Store,
                },
            })],
            depth_stencil_attachment: None,
            timestamp_writes: None,
            occlusion_query_set: None,
            multiview_mask: None,
        });
        pass.set_pipeline(&self.pipeline);
        pass.set_bind_group(0, &self.bind_group, &[]);
        if let Some([x, y, w, h]) = rect {
            pass.set_viewport(x as f32, y as f32, w as f32, h as f32, 0.0, 1.0);
            pass.set_scissor_rect(x, y, w, h);
        }
        pass.draw(0..4, 0..1);
    }
}

/// Draws a GPU frame into textures the caller owns — an OpenXR swapchain
/// image, say — on the frame's own device: the pipeline's output buffer is
/// read in place (no copy, no read-back), scaled to fill the target (1:1
/// when the pipeline renders at the target's size). An sRGB target gets the
/// codes decoded to linear, so it stores the frame's own codes; an
/// `Rgba16Float` target gets the decoded linear values.
pub struct TexturePresenter {
    ctx: GpuContext,
    pass: PresentPass,
    params: PresentParams,
}

impl TexturePresenter {
    /// A presenter of `source` into targets of `format` (created with
    /// `RENDER_ATTACHMENT` usage).
    pub fn new(source: &FrameSource, format: wgpu::TextureFormat) -> Result<Self, GpuError> {
        let pass = PresentPass::new(&source.ctx, &source.buffer, format)?;
        Ok(Self {
            ctx: source.ctx.clone(),
            pass,
            params: PresentParams {
                scale: [1.0, 1.0],
                frame_size: [source.width, source.height],
                // A float target (an `R16G16B16A16_SFLOAT` swapchain)
                // holds linear values too.
                decode_srgb: u32::from(
                    format.is_srgb() || format == wgpu::TextureFormat::Rgba16Float,
                ),
                ..PresentParams::default()
            },
        })
    }

    /// Records drawing the frame into `target` (a view of a texture of the
    /// presenter's format). The frame is whatever the pipeline last wrote
    /// when the encoder is submitted.
    pub fn encode(&self, encoder: &mut wgpu::CommandEncoder, target: &wgpu::TextureView) {
        self.pass
            .encode(&self.ctx, encoder, target, &self.params, None);
    }

    /// Records drawing the frame into the rectangle `rect` = `[x, y,
    /// width, height]` pixels of `target` only, keeping the rest of it (an
    /// image holding several views side by side, as an OpenXR
    /// `imageRect`). The rectangle must lie inside the target.
    pub fn encode_rect(
        &self,
        encoder: &mut wgpu::CommandEncoder,
        target: &wgpu::TextureView,
        rect: [u32; 4],
    ) {
        self.pass
            .encode(&self.ctx, encoder, target, &self.params, Some(rect));
    }

    /// Draws the frame into `target` now: records and submits one command
    /// buffer (for callers that keep no encoder of their own).
    pub fn present(&self, target: &wgpu::TextureView) {
        let mut encoder =
            self.ctx
                .device()
                .create_command_encoder(&wgpu::CommandEncoderDescriptor {
                    label: Some("present to texture"),
                });
        self.encode(&mut encoder, target);
        self.ctx.queue().submit([encoder.finish()]);
    }
}

impl WindowPresenter {
    /// A presenter for `window` on the device of a GPU frame pipeline,
    /// drawing the pipeline's output buffer itself. `size_px` is the window's
    /// inner size. An error when the context is a caller's device (no
    /// instance to make a surface from) or its adapter cannot present to the
    /// window.
    pub fn on_pipeline(
        source: &FrameSource,
        window: impl Into<wgpu::SurfaceTarget<'static>>,
        size_px: [u32; 2],
    ) -> Result<Self, GpuError> {
        Self::build(
            &source.ctx,
            window.into(),
            size_px,
            source.buffer.clone(),
            [source.width, source.height],
            Frames::Pipeline,
        )
    }

    /// A presenter for `window` on a device of its own (hardware first, as
    /// [`GpuContext::new`]), for frames rendered on the host
    /// ([`Self::upload`]) of `frame_size` pixels, or solid colours
    /// (`frame_size` = `[1, 1]`).
    pub fn own(
        window: impl Into<wgpu::SurfaceTarget<'static>>,
        size_px: [u32; 2],
        frame_size: [u32; 2],
    ) -> Result<Self, GpuError> {
        let ctx = GpuContext::new(&ContextOptions::default())?;
        let [w, h] = frame_size;
        if w == 0 || h == 0 {
            return Err(GpuError::Length {
                what: "host frame",
                expected: 1,
                got: 0,
            });
        }
        let bytes = u64::from(w) * u64::from(h) * 4;
        let buffer = ctx.scoped("present upload buffer", |device| {
            device.create_buffer(&wgpu::BufferDescriptor {
                label: Some("present upload"),
                size: bytes,
                usage: wgpu::BufferUsages::STORAGE | wgpu::BufferUsages::COPY_DST,
                mapped_at_creation: false,
            })
        })?;
        Self::build(
            &ctx,
            window.into(),
            size_px,
            buffer,
            frame_size,
            Frames::Uploaded,
        )
    }

    fn build(
        ctx: &GpuContext,
        target: wgpu::SurfaceTarget<'static>,
        size_px: [u32; 2],
        frame_buffer: wgpu::Buffer,
        frame_size: [u32; 2],
        frames: Frames,
    ) -> Result<Self, GpuError> {
        let Some((instance, adapter)) = ctx.surface_source() else {
            return Err(wgpu_error(
                "a window surface",
                "the device was handed in by the caller (GpuContext::from_device): \
                 no instance to create a surface from",
            ));
        };
        let surface = instance
            .create_surface(target)
            .map_err(|e| wgpu_error("a window surface", e))?;
        if !adapter.is_surface_supported(&surface) {
            return Err(wgpu_error(
                "a window surface",
                format!(
                    "the adapter {} cannot present to this window",
                    ctx.describe()
                ),
            ));
        }
        let mut config = surface
            .get_default_config(adapter, size_px[0].max(1), size_px[1].max(1))
            .ok_or_else(|| {
                wgpu_error(
                    "a window surface",
                    format!("the adapter {} does not support it", ctx.describe()),
                )
            })?;
        // The frames are already sRGB-encoded: present them unchanged.
        let caps = surface.get_capabilities(adapter);
        if let Some(f) = caps.formats.iter().find(|f| !f.is_srgb()) {
            config.format = *f;
        }
        config.present_mode = wgpu::PresentMode::Fifo;
        // Configuring waits (with a deadline) for the device to go idle; on
        // the pipeline's own device the frame thread may be submitting work
        // meanwhile, and a software adapter on a loaded machine can miss the
        // deadline ("Failed to wait for GPU to come idle"). Wait for what is
        // queued, then try again, a few times.
        let mut attempt = 0;
        loop {
            attempt += 1;
            match ctx.scoped("window surface configuration", |device| {
                surface.configure(device, &config)
            }) {
                Ok(()) => break,
                Err(e) if attempt < CONFIGURE_ATTEMPTS => {
                    tracing::warn!(attempt, error = %e, "window surface configuration failed; waiting for the device and retrying");
                    ctx.wait_idle()?;
                }
                Err(e) => return Err(e),
            }
        }

        let pass = PresentPass::new(ctx, &frame_buffer, config.format)?;
        tracing::info!(
            adapter = %ctx.describe(),
            format = ?config.format,
            frames = match frames {
                Frames::Pipeline => "the frame pipeline's output buffer (no copy)",
                Frames::Uploaded => "host frames, uploaded",
            },
            "window presenter"
        );
        Ok(Self {
            ctx: ctx.clone(),
            surface,
            config,
            pass,
            frame_buffer,
            frame_size,
            frames,
        })
    }

    /// The device the presenter draws on.
    pub fn context(&self) -> &GpuContext {
        &self.ctx
    }

    /// Whether the device is a software (CPU) adapter such as lavapipe.
    pub fn software_adapter(&self) -> bool {
        self.ctx.adapter_info().device_type == wgpu::DeviceType::Cpu
    }

    /// Whether the presenter reads a pipeline's output buffer (no upload).
    pub fn on_pipeline_device(&self) -> bool {
        matches!(self.frames, Frames::Pipeline)
    }

    /// Frame size, pixels.
    pub fn frame_size(&self) -> [u32; 2] {
        self.frame_size
    }

    /// Surface size, pixels.
    pub fn surface_size(&self) -> [u32; 2] {
        [self.config.width, self.config.height]
    }

    /// The quad scale the frame is drawn with now.
    pub fn letterbox(&self) -> [f32; 2] {
        letterbox_scale(self.frame_size, self.surface_size())
    }

    /// Follows a window resize (ignored at zero size, e.g. minimised).
    pub fn resize(&mut self, size_px: [u32; 2]) {
        if size_px[0] == 0 || size_px[1] == 0 {
            return;
        }
        self.config.width = size_px[0];
        self.config.height = size_px[1];
        self.surface.configure(self.ctx.device(), &self.config);
    }

    /// Uploads a host frame (RGBA8, `frame_size`, rows top to bottom) for
    /// the next [`Self::present_frame`]. An error on a presenter that reads
    /// a pipeline's buffer, or for a frame of the wrong length.
    pub fn upload(&mut self, rgba8: &[u8]) -> Result<(), GpuError> {
        if !matches!(self.frames, Frames::Uploaded) {
            return Err(wgpu_error(
                "a host frame upload",
                "this presenter draws the frame pipeline's output buffer",
            ));
        }
        let expected = self.frame_size[0] as usize * self.frame_size[1] as usize * 4;
        if rgba8.len() != expected {
            return Err(GpuError::Length {
                what: "host frame (RGBA8 bytes)",
                expected,
                got: rgba8.len(),
            });
        }
        self.ctx.queue().write_buffer(&self.frame_buffer, 0, rgba8);
        Ok(())
    }

    /// Draws the frame (the pipeline's newest output, or the last upload)
    /// letterboxed, and queues the surface image for display.
    pub fn present_frame(&mut self) -> Result<Presented, GpuError> {
        let params = PresentParams {
            scale: self.letterbox(),
            frame_size: self.frame_size,
            ..PresentParams::default()
        };
        self.draw(&params)
    }

    /// Fills the surface with a solid colour (sRGB-encoded 8-bit RGB).
    pub fn present_solid(&mut self, rgb8: [u8; 3]) -> Result<Presented, GpuError> {
        let [r, g, b] = rgb8.map(|c| f32::from(c) / 255.0);
        let params = PresentParams {
            scale: [1.0, 1.0],
            frame_size: self.frame_size,
            solid: [r, g, b, 1.0],
            ..PresentParams::default()
        };
        self.draw(&params)
    }

    fn draw(&mut self, params: &PresentParams) -> Result<Presented, GpuError> {
        let frame = match self.surface.get_current_texture() {
            wgpu::CurrentSurfaceTexture::Success(t)
            | wgpu::CurrentSurfaceTexture::Suboptimal(t) => t,
            wgpu::CurrentSurfaceTexture::Outdated | wgpu::CurrentSurfaceTexture::Lost => {
                self.surface.configure(self.ctx.device(), &self.config);
                return Ok(Presented::Skipped);
            }
            wgpu::CurrentSurfaceTexture::Timeout | wgpu::CurrentSurfaceTexture::Occluded => {
                return Ok(Presented::Skipped);
            }
            wgpu::CurrentSurfaceTexture::Validation => {
                return Err(wgpu_error(
                    "the window surface",
                    "a validation error acquiring the next image",
                ));
            }
        };
        let view = frame
            .texture
            .create_view(&wgpu::TextureViewDescriptor::default());
        let mut encoder =
            self.ctx
                .device()
                .create_command_encoder(&wgpu::CommandEncoderDescriptor {
                    label: Some("present"),
                });
        self.pass
            .encode(&self.ctx, &mut encoder, &view, params, None);
        self.ctx.queue().submit([encoder.finish()]);
        self.ctx.queue().present(frame);
        Ok(Presented::Shown)
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    /// The Rust twin has the size and field offsets naga lays out for the
    /// WGSL struct (read from the shader, not restated by hand).
    #[test]
    fn present_params_match_the_wgsl_struct_layout() {
        let module = naga::front::wgsl::parse_str(PRESENT.source).expect("present.wgsl parses");
        let mut layouter = naga::proc::Layouter::default();
        layouter.update(module.to_ctx()).expect("layout");
        let (handle, ty) = module
            .types
            .iter()
            .find(|(_, t)| t.name.as_deref() == Some("PresentParams"))
            .expect("struct PresentParams in present.wgsl");
        let naga::TypeInner::Struct { members, span } = &ty.inner else {
            panic!("PresentParams is not a struct");
        };
        assert_eq!(*span as usize, size_of::<PresentParams>());
        assert_eq!(layouter[handle].size as usize, size_of::<PresentParams>());
        let offsets: Vec<(String, u32)> = members
            .iter()
            .map(|m| (m.name.clone().unwrap_or_default(), m.offset))
            .collect();
        assert_eq!(
            offsets,
            vec![
                (
                    "scale".to_owned(),
                    std::mem::offset_of!(PresentParams, scale) as u32
                ),
                (
                    "frame_size".to_owned(),
                    std::mem::offset_of!(PresentParams, frame_size) as u32
                ),
                (
                    "solid".to_owned(),
                    std::mem::offset_of!(PresentParams, solid) as u32
                ),
                (
                    "decode_srgb".to_owned(),
                    std::mem::offset_of!(PresentParams, decode_srgb) as u32
                ),
                ("_pad0".to_owned(), 36),
                ("_pad1".to_owned(), 40),
                ("_pad2".to_owned(), 44),
            ]
        );
    }

    #[test]
    fn the_present_shader_passes_the_crate_check_with_both_stages() {
        let report = check_shader(&PRESENT, &wgpu::Limits::default()).expect("check");
        // No compute entry points: nothing for the workgroup limits.
        assert!(report.entry_points.is_empty());
        let module = naga::front::wgsl::parse_str(PRESENT.source).expect("parses");
        let stages: Vec<(&str, naga::ShaderStage)> = module
            .entry_points
            .iter()
            .map(|e| (e.name.as_str(), e.stage))
            .collect();
        assert_eq!(
            stages,
            vec![
                ("vs_main", naga::ShaderStage::Vertex),
                ("fs_main", naga::ShaderStage::Fragment)
            ]
        );
    }

    /// Draws `frame` (RGBA8 bytes, `fw × fh`) with the present pass into
    /// an offscreen `Rgba8Unorm` target of `tw × th` and reads the target
    /// back (RGBA8 rows). `tw · 4` must be a multiple of 256.
    fn draw_offscreen(
        ctx: &GpuContext,
        frame: &[u8],
        [fw, fh]: [u32; 2],
        [tw, th]: [u32; 2],
    ) -> Vec<u8> {
        draw_offscreen_as(
            ctx,
            frame,
            [fw, fh],
            [tw, th],
            wgpu::TextureFormat::Rgba8Unorm,
        )
    }

    /// A `w × h` 2-D texture of `format` with `usage`.
    fn texture_2d(
        ctx: &GpuContext,
        [w, h]: [u32; 2],
        format: wgpu::TextureFormat,
        usage: wgpu::TextureUsages,
    ) -> wgpu::Texture {
        ctx.device().create_texture(&wgpu::TextureDescriptor {
            label: Some("test texture"),
            size: wgpu::Extent3d {
                width: w,
                height: h,
                depth_or_array_layers: 1,
            },
            mip_level_count: 1,
            sample_count: 1,
            dimension: wgpu::TextureDimension::D2,
            format,
            usage,
            view_formats: &[],
        })
    }

    /// Reads a 4-byte-per-texel `w × h` texture back (rows of `w · 4`
    /// bytes; `w · 4` must be a multiple of 256), after what `encoder`
    /// already holds.
    fn read_rgba8(
        ctx: &GpuContext,
        mut encoder: wgpu::CommandEncoder,
        texture: &wgpu::Texture,
        [w, h]: [u32; 2],
    ) -> Vec<u8> {
        let staging = ctx.device().create_buffer(&wgpu::BufferDescriptor {
            label: Some("test texture read-back"),
            size: u64::from(w * h * 4),
            usage: wgpu::BufferUsages::COPY_DST | wgpu::BufferUsages::MAP_READ,
            mapped_at_creation: false,
        });
        encoder.copy_texture_to_buffer(
            texture.as_image_copy(),
            wgpu::TexelCopyBufferInfo {
                buffer: &staging,
                layout: wgpu::TexelCopyBufferLayout {
                    offset: 0,
                    bytes_per_row: Some(w * 4),
                    rows_per_image: Some(h),
                },
            },
            texture.size(),
        );
        ctx.queue().submit([encoder.finish()]);
        let mut out = Vec::new();
        crate::fft::read_mapped(ctx, &staging, "test texture", |b| out.extend_from_slice(b))
            .expect("read back");
        out
    }

    /// [`draw_offscreen`] into a target of `format` (with the matching
    /// `decode_srgb`).
    fn draw_offscreen_as(
        ctx: &GpuContext,
        frame: &[u8],
        [fw, fh]: [u32; 2],
        [tw, th]: [u32; 2],
        format: wgpu::TextureFormat,
    ) -> Vec<u8> {
        let device = ctx.device();
        let frame_buffer = device.create_buffer(&wgpu::BufferDescriptor {
            label: Some("test frame"),
            size: frame.len() as u64,
            usage: wgpu::BufferUsages::STORAGE | wgpu::BufferUsages::COPY_DST,
            mapped_at_creation: false,
        });
        ctx.queue().write_buffer(&frame_buffer, 0, frame);
        let pass = PresentPass::new(ctx, &frame_buffer, format).expect("present pass");
        let target = texture_2d(
            ctx,
            [tw, th],
            format,
            wgpu::TextureUsages::RENDER_ATTACHMENT | wgpu::TextureUsages::COPY_SRC,
        );
        let view = target.create_view(&wgpu::TextureViewDescriptor::default());
        let mut encoder = device.create_command_encoder(&wgpu::CommandEncoderDescriptor::default());
        let params = PresentParams {
            scale: letterbox_scale([fw, fh], [tw, th]),
            frame_size: [fw, fh],
            decode_srgb: u32::from(format.is_srgb()),
            ..PresentParams::default()
        };
        pass.encode(ctx, &mut encoder, &view, &params, None);
        read_rgba8(ctx, encoder, &target, [tw, th])
    }

    /// A frame of distinct codes (a hash of the pixel index per channel).
    fn test_frame(w: u32, h: u32) -> Vec<u8> {
        (0..w * h)
            .flat_map(|i| {
                let v = i.wrapping_mul(2_654_435_761);
                [v as u8, (v >> 8) as u8, (v >> 16) as u8, 255]
            })
            .collect()
    }

    /// At 1:1 every target pixel is its frame pixel's code, exactly (what
    /// the window screenshots rely on); letterboxed into a taller target
    /// the bars are black and the frame rows sit centred, unchanged.
    #[test]
    fn present_pass_draws_the_frame_buffer_unchanged_at_one_to_one() {
        let Some(ctx) =
            crate::testing::test_context("present_pass_draws_the_frame_buffer_unchanged")
        else {
            return;
        };
        let (w, h) = (64u32, 32u32);
        let frame = test_frame(w, h);
        let same = draw_offscreen(ctx, &frame, [w, h], [w, h]);
        let diff = same.iter().zip(&frame).filter(|(a, b)| a != b).count();
        assert_eq!(diff, 0, "{diff} bytes differ at 1:1");

        let boxed = draw_offscreen(ctx, &frame, [w, h], [w, 2 * h]);
        let row = (w * 4) as usize;
        let bar = (h / 2) as usize;
        for y in 0..(2 * h) as usize {
            let got = &boxed[y * row..(y + 1) * row];
            if y < bar || y >= bar + h as usize {
                assert!(
                    got.chunks_exact(4).all(|p| p[..3] == [0, 0, 0]),
                    "bar row {y} is not black"
                );
            } else {
                let want = &frame[(y - bar) * row..(y - bar + 1) * row];
                assert_eq!(got, want, "frame row {} letterboxed at row {y}", y - bar);
            }
        }
    }

    /// Into an sRGB target (an OpenXR swapchain's format) the shader writes
    /// linear values that the target encodes back: the stored bytes are
    /// the frame's codes (within one code of rounding).
    #[test]
    fn an_srgb_target_stores_the_frames_codes() {
        let Some(ctx) = crate::testing::test_context("an_srgb_target_stores_the_frames_codes")
        else {
            return;
        };
        let (w, h) = (64u32, 32u32);
        let frame = test_frame(w, h);
        let got = draw_offscreen_as(
            ctx,
            &frame,
            [w, h],
            [w, h],
            wgpu::TextureFormat::Rgba8UnormSrgb,
        );
        let worst = got
            .iter()
            .zip(&frame)
            .map(|(a, b)| a.abs_diff(*b))
            .max()
            .unwrap_or(0);
        assert!(worst <= 1, "an sRGB target is off by up to {worst} codes");
        // Without the decode the mid-greys would be encoded twice.
        let mid = [128u8, 128, 128, 255].repeat((w * h) as usize);
        let twice = draw_offscreen_as(
            ctx,
            &mid,
            [w, h],
            [w, h],
            wgpu::TextureFormat::Rgba8UnormSrgb,
        );
        assert!(
            twice.chunks_exact(4).all(|p| p[0].abs_diff(128) <= 1),
            "{:?}",
            &twice[..4]
        );
    }

    /// The host-renderer API: the frame pipeline on a device the caller
    /// made (`GpuContext::from_device`, as an OpenXR runtime's), one
    /// pipeline per eye with its own input, each drawn by a
    /// [`TexturePresenter`] into the caller's sRGB texture (an XR swapchain
    /// image's format): the texture holds the CPU reference pipeline's
    /// frame within 2 codes (1 for GPU vs CPU, 1 for the sRGB round trip).
    #[test]
    fn host_renderer_on_the_callers_device_matches_the_cpu() {
        use gazelight_vision::RgbImage;
        use gazelight_vision::pipeline::{DisplayFrame, FrameInput, FramePipeline, PipelineConfig};

        let Some(own) = crate::testing::test_context("host_renderer_on_the_callers_device") else {
            return;
        };
        let caller = GpuContext::from_device(own.device().clone(), own.queue().clone());
        // A dim night scene with a bright lamp (glare, scotopic colour,
        // per-pixel acuity) at 6.4 ppd.
        let (w, h) = (128usize, 96usize);
        let deg_per_px = 1.0 / 6.4;
        let pixels = (0..w * h)
            .map(|i| {
                let (x, y) = ((i % w) as f32, (i / w) as f32);
                let d2 = (x - 40.0).powi(2) + (y - 30.0).powi(2);
                if d2 < 4.0 {
                    [3.0e3, 2.5e3, 1.5e3]
                } else {
                    let g = 0.02 + 0.03 * x / w as f32;
                    [g, 1.2 * g, 0.8 * g]
                }
            })
            .collect();
        let scene = RgbImage::from_pixels(w, h, pixels).unwrap();
        let format = wgpu::TextureFormat::Rgba8UnormSrgb;
        let eyes = [
            FrameInput {
                gaze_uv: [0.3, 0.3],
                pupil_mm: 3.0,
                dt_secs: 0.0,
            },
            FrameInput {
                gaze_uv: [0.7, 0.6],
                pupil_mm: 6.0,
                dt_secs: 0.0,
            },
        ];
        let size = [w as u32, h as u32];
        for (k, input) in eyes.iter().enumerate() {
            let mut config = PipelineConfig::default();
            config.glare.far_field = true;
            let mut cpu = FramePipeline::new(config.clone(), w, h, deg_per_px).unwrap();
            let mut gpu = crate::GpuFramePipeline::new(&caller, config, w, h, deg_per_px).unwrap();
            let mut reference = DisplayFrame::new(w, h);
            cpu.process(&scene, input, &mut reference).unwrap();
            if k == 0 {
                // Eye 0: the scene from host memory.
                gpu.process(&scene, input).unwrap();
            } else {
                // Eye 1: the scene as the caller's HDR texture, copied on
                // the device and rendered in the caller's encoder.
                let texture = texture_2d(
                    &caller,
                    size,
                    wgpu::TextureFormat::Rgba32Float,
                    wgpu::TextureUsages::COPY_DST | wgpu::TextureUsages::COPY_SRC,
                );
                let texels: Vec<[f32; 4]> = scene
                    .pixels
                    .iter()
                    .map(|p| [p[0], p[1], p[2], 1.0])
                    .collect();
                caller.queue().write_texture(
                    texture.as_image_copy(),
                    bytemuck::cast_slice(&texels),
                    wgpu::TexelCopyBufferLayout {
                        offset: 0,
                        bytes_per_row: Some(w as u32 * 16),
                        rows_per_image: Some(h as u32),
                    },
                    texture.size(),
                );
                let mut encoder = caller
                    .device()
                    .create_command_encoder(&wgpu::CommandEncoderDescriptor::default());
                gpu.encode_scene_texture(&mut encoder, &texture).unwrap();
                gpu.encode(&mut encoder, input);
                caller.queue().submit([encoder.finish()]);
                // A texture of another format is refused, naming it.
                let wrong = texture_2d(
                    &caller,
                    size,
                    wgpu::TextureFormat::Rgba8Unorm,
                    wgpu::TextureUsages::COPY_SRC,
                );
                let mut encoder = caller
                    .device()
                    .create_command_encoder(&wgpu::CommandEncoderDescriptor::default());
                let e = gpu.encode_scene_texture(&mut encoder, &wrong).unwrap_err();
                assert!(e.to_string().contains("Rgba32Float"), "{e}");
            }
            let presenter = TexturePresenter::new(&FrameSource::of(&gpu), format).unwrap();
            let target = texture_2d(
                &caller,
                size,
                format,
                wgpu::TextureUsages::RENDER_ATTACHMENT | wgpu::TextureUsages::COPY_SRC,
            );
            presenter.present(&target.create_view(&wgpu::TextureViewDescriptor::default()));
            let encoder = caller
                .device()
                .create_command_encoder(&wgpu::CommandEncoderDescriptor::default());
            let got = read_rgba8(&caller, encoder, &target, size);
            let worst = got
                .iter()
                .zip(&reference.rgba8)
                .map(|(a, b)| a.abs_diff(*b))
                .max()
                .unwrap_or(0);
            println!("eye {k}: worst difference from the CPU reference {worst}/255");
            assert!(
                worst <= 2,
                "eye {k}: the caller's texture is {worst} codes from the CPU"
            );
            // The eyes differ (gaze and pupil), so each texture is its own.
            assert!(got.iter().any(|&c| c > 0), "eye {k}: a black texture");
        }
    }

    #[test]
    fn letterbox_keeps_the_aspect() {
        assert_eq!(letterbox_scale([720, 800], [720, 800]), [1.0, 1.0]);
        assert_eq!(letterbox_scale([100, 100], [200, 100]), [0.5, 1.0]);
        assert_eq!(letterbox_scale([200, 100], [100, 100]), [1.0, 0.5]);
        // A zero-height window (minimised) gives finite scales, no panic.
        assert!(
            letterbox_scale([4, 3], [0, 0])
                .iter()
                .all(|s| s.is_finite())
        );
    }
}
