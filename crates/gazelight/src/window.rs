//! The service's display window: winit + a wgpu surface, vsync (FIFO).
//!
//! The window shows either the frame loop's newest display frame
//! ([`Content::Frames`], letterboxed to keep its aspect) or a solid colour
//! filling the whole window ([`Content::Solid`], the black/white stimulus of
//! `calibrate --stimulus window`). It never drives the frame loop: the loop
//! runs at the display rate on its own thread and drops its newest frame
//! into a [`DisplaySlot`]; the window uploads whatever is newest when the
//! surface is ready, so a slow window drops frames (counted) instead of
//! slowing the loop. The cursor position over the frame is published as a
//! normalised gaze for `run --mouse-gaze`.
//!
//! winit needs the main thread on Linux; [`run`] blocks it until the window
//! is closed (Escape or the close button: the session is asked to shut
//! down) or `stop` turns true.
//!
//! The present pass is `shaders/present.wgsl`; its uniform twin is
//! [`PresentParams`].

use std::sync::atomic::{AtomicU32, AtomicU64, Ordering};
use std::sync::{Arc, Mutex};
use std::time::{Duration, Instant};

use anyhow::Context;
use winit::application::ApplicationHandler;
use winit::dpi::PhysicalSize;
use winit::event::{ElementState, KeyEvent, WindowEvent};
use winit::event_loop::{ActiveEventLoop, ControlFlow, EventLoop};
use winit::keyboard::{Key, NamedKey};
use winit::window::{Window, WindowId};

/// The present shader (one pass: a textured, letterboxed quad or a solid).
const PRESENT_WGSL: &str = include_str!("../../../shaders/present.wgsl");

/// The newest display frame, handed from the frame loop to the window.
/// `put` copies into a buffer allocated once, so the frame loop does not
/// allocate; the window takes a frame only when its sequence number moved.
#[derive(Debug)]
pub struct DisplaySlot {
    width: u32,
    height: u32,
    inner: Mutex<SlotInner>,
    /// Frames put but never shown (the window was busy).
    skipped: AtomicU64,
}

#[derive(Debug)]
struct SlotInner {
    seq: u64,
    rgba8: Vec<u8>,
}

impl DisplaySlot {
    /// A slot for RGBA8 frames of `width × height`.
    pub fn new(width: u32, height: u32) -> Arc<Self> {
        Arc::new(Self {
            width,
            height,
            inner: Mutex::new(SlotInner {
                seq: 0,
                rgba8: vec![0; width as usize * height as usize * 4],
            }),
            skipped: AtomicU64::new(0),
        })
    }

    /// Frame size, pixels.
    pub fn size(&self) -> (u32, u32) {
        (self.width, self.height)
    }

    /// Replaces the newest frame (ignored when the size does not match).
    pub fn put(&self, rgba8: &[u8]) {
        let mut g = self.inner.lock().unwrap_or_else(|p| p.into_inner());
        if g.rgba8.len() != rgba8.len() {
            return;
        }
        g.rgba8.copy_from_slice(rgba8);
        g.seq += 1;
    }

    /// Frames the window never showed.
    pub fn skipped(&self) -> u64 {
        self.skipped.load(Ordering::Relaxed)
    }

    /// Runs `f` on the newest frame if it is newer than `last_seq`.
    fn take_newer(&self, last_seq: &mut u64, f: impl FnOnce(&[u8])) -> bool {
        let g = self.inner.lock().unwrap_or_else(|p| p.into_inner());
        if g.seq == *last_seq {
            return false;
        }
        if g.seq > *last_seq + 1 {
            self.skipped
                .fetch_add(g.seq - *last_seq - 1, Ordering::Relaxed);
        }
        *last_seq = g.seq;
        f(&g.rgba8);
        true
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

/// Uniforms of `present.wgsl` (`PresentParams`, field by field).
#[repr(C)]
#[derive(Clone, Copy, Debug, Default, bytemuck::Pod, bytemuck::Zeroable)]
pub struct PresentParams {
    /// Scale of the quad in clip space.
    pub scale: [f32; 2],
    pub _pad: [f32; 2],
    /// Solid colour (linear 0–1 of the encoded value) with w = 1, or w = 0.
    pub solid: [f32; 4],
}

/// What a closed or stopped window reports.
#[derive(Clone, Copy, Debug, Default)]
pub struct WindowStats {
    /// Frames presented.
    pub presented: u64,
    /// Whether the user closed the window (rather than `stop`).
    pub closed_by_user: bool,
    /// The adapter the window ran on.
    pub software_adapter: bool,
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
        gpu: None,
        error: None,
        stats: WindowStats::default(),
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

struct Gpu {
    window: Arc<Window>,
    surface: wgpu::Surface<'static>,
    device: wgpu::Device,
    queue: wgpu::Queue,
    config: wgpu::SurfaceConfiguration,
    pipeline: wgpu::RenderPipeline,
    bind_group: wgpu::BindGroup,
    params: wgpu::Buffer,
    frame_tex: wgpu::Texture,
    frame_size: (u32, u32),
}

struct App {
    options: WindowOptions,
    content: Content,
    mouse: Option<Arc<MouseGaze>>,
    stop: Box<dyn Fn() -> bool>,
    on_close: Box<dyn Fn()>,
    gpu: Option<Gpu>,
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

    fn frame_size(&self) -> (u32, u32) {
        match &self.content {
            Content::Frames(slot) => slot.size(),
            Content::Solid(_) => (1, 1),
        }
    }

    fn init(&mut self, event_loop: &ActiveEventLoop) -> anyhow::Result<Gpu> {
        let mut attrs = Window::default_attributes()
            .with_title(self.options.title.clone())
            .with_inner_size(PhysicalSize::new(self.options.width, self.options.height));
        if self.options.fullscreen {
            attrs = attrs.with_fullscreen(Some(winit::window::Fullscreen::Borderless(None)));
        }
        let window = Arc::new(
            event_loop
                .create_window(attrs)
                .context("cannot create the window")?,
        );
        let instance = wgpu::Instance::new(
            wgpu::InstanceDescriptor::new_with_display_handle_from_env(Box::new(window.clone())),
        );
        let surface = instance
            .create_surface(window.clone())
            .context("cannot create a GPU surface for the window")?;
        let adapter = pollster::block_on(instance.request_adapter(&wgpu::RequestAdapterOptions {
            power_preference: wgpu::PowerPreference::HighPerformance,
            force_fallback_adapter: false,
            compatible_surface: Some(&surface),
            apply_limit_buckets: false,
        }))
        .context("no GPU adapter can present to this window (Vulkan/lavapipe needed)")?;
        let info = adapter.get_info();
        self.stats.software_adapter = info.device_type == wgpu::DeviceType::Cpu;
        tracing::info!(adapter = %info.name, backend = ?info.backend, "window adapter");
        let (device, queue) = pollster::block_on(adapter.request_device(&wgpu::DeviceDescriptor {
            label: Some("gazelight-window"),
            required_features: wgpu::Features::empty(),
            required_limits: wgpu::Limits::default(),
            experimental_features: wgpu::ExperimentalFeatures::disabled(),
            memory_hints: wgpu::MemoryHints::Performance,
            trace: wgpu::Trace::Off,
        }))
        .context("cannot open the GPU device for the window")?;

        let size = window.inner_size();
        let mut config = surface
            .get_default_config(&adapter, size.width.max(1), size.height.max(1))
            .context("the window surface is not supported by the adapter")?;
        // The frames are already sRGB-encoded: present them unchanged.
        let caps = surface.get_capabilities(&adapter);
        if let Some(f) = caps.formats.iter().find(|f| !f.is_srgb()) {
            config.format = *f;
        }
        config.present_mode = wgpu::PresentMode::Fifo;
        surface.configure(&device, &config);

        let (fw, fh) = self.frame_size();
        let frame_tex = device.create_texture(&wgpu::TextureDescriptor {
            label: Some("present-frame"),
            size: wgpu::Extent3d {
                width: fw,
                height: fh,
                depth_or_array_layers: 1,
            },
            mip_level_count: 1,
            sample_count: 1,
            dimension: wgpu::TextureDimension::D2,
            format: wgpu::TextureFormat::Rgba8Unorm,
            usage: wgpu::TextureUsages::TEXTURE_BINDING | wgpu::TextureUsages::COPY_DST,
            view_formats: &[],
        });
        let sampler = device.create_sampler(&wgpu::SamplerDescriptor {
            label: Some("present-sampler"),
            mag_filter: wgpu::FilterMode::Linear,
            min_filter: wgpu::FilterMode::Linear,
            ..Default::default()
        });
        let params = device.create_buffer(&wgpu::BufferDescriptor {
            label: Some("present-params"),
            size: std::mem::size_of::<PresentParams>() as u64,
            usage: wgpu::BufferUsages::UNIFORM | wgpu::BufferUsages::COPY_DST,
            mapped_at_creation: false,
        });
        let layout = device.create_bind_group_layout(&wgpu::BindGroupLayoutDescriptor {
            label: Some("present-layout"),
            entries: &[
                wgpu::BindGroupLayoutEntry {
                    binding: 0,
                    visibility: wgpu::ShaderStages::FRAGMENT,
                    ty: wgpu::BindingType::Texture {
                        sample_type: wgpu::TextureSampleType::Float { filterable: true },
                        view_dimension: wgpu::TextureViewDimension::D2,
                        multisampled: false,
                    },
                    count: None,
                },
                wgpu::BindGroupLayoutEntry {
                    binding: 1,
                    visibility: wgpu::ShaderStages::FRAGMENT,
                    ty: wgpu::BindingType::Sampler(wgpu::SamplerBindingType::Filtering),
                    count: None,
                },
                wgpu::BindGroupLayoutEntry {
                    binding: 2,
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
        let view = frame_tex.create_view(&wgpu::TextureViewDescriptor::default());
        let bind_group = device.create_bind_group(&wgpu::BindGroupDescriptor {
            label: Some("present-bind-group"),
            layout: &layout,
            entries: &[
                wgpu::BindGroupEntry {
                    binding: 0,
                    resource: wgpu::BindingResource::TextureView(&view),
                },
                wgpu::BindGroupEntry {
                    binding: 1,
                    resource: wgpu::BindingResource::Sampler(&sampler),
                },
                wgpu::BindGroupEntry {
                    binding: 2,
                    resource: params.as_entire_binding(),
                },
            ],
        });
        let shader = device.create_shader_module(wgpu::ShaderModuleDescriptor {
            label: Some("present.wgsl"),
            source: wgpu::ShaderSource::Wgsl(PRESENT_WGSL.into()),
        });
        let pipeline_layout = device.create_pipeline_layout(&wgpu::PipelineLayoutDescriptor {
            label: Some("present-pipeline-layout"),
            bind_group_layouts: &[Some(&layout)],
            immediate_size: 0,
        });
        let pipeline = device.create_render_pipeline(&wgpu::RenderPipelineDescriptor {
            label: Some("present"),
            layout: Some(&pipeline_layout),
            vertex: wgpu::VertexState {
                module: &shader,
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
                module: &shader,
                entry_point: Some("fs_main"),
                compilation_options: Default::default(),
                targets: &[Some(wgpu::ColorTargetState {
                    format: config.format,
                    blend: None,
                    write_mask: wgpu::ColorWrites::ALL,
                })],
            }),
            multiview_mask: None,
            cache: None,
        });
        window.request_redraw();
        Ok(Gpu {
            window,
            surface,
            device,
            queue,
            config,
            pipeline,
            bind_group,
            params,
            frame_tex,
            frame_size: (fw, fh),
        })
    }

    /// Quad scale that letterboxes the frame into the window.
    fn letterbox(frame: (u32, u32), window: (u32, u32)) -> [f32; 2] {
        let fa = frame.0 as f32 / frame.1.max(1) as f32;
        let wa = window.0 as f32 / window.1.max(1) as f32;
        if fa > wa {
            [1.0, wa / fa]
        } else {
            [fa / wa, 1.0]
        }
    }

    fn redraw(&mut self) -> anyhow::Result<()> {
        let Some(gpu) = &mut self.gpu else {
            return Ok(());
        };
        let params = match &self.content {
            Content::Frames(slot) => {
                let tex = &gpu.frame_tex;
                let queue = &gpu.queue;
                let (w, h) = gpu.frame_size;
                slot.take_newer(&mut self.last_seq, |rgba| {
                    queue.write_texture(
                        wgpu::TexelCopyTextureInfo {
                            texture: tex,
                            mip_level: 0,
                            origin: wgpu::Origin3d::ZERO,
                            aspect: wgpu::TextureAspect::All,
                        },
                        rgba,
                        wgpu::TexelCopyBufferLayout {
                            offset: 0,
                            bytes_per_row: Some(4 * w),
                            rows_per_image: Some(h),
                        },
                        wgpu::Extent3d {
                            width: w,
                            height: h,
                            depth_or_array_layers: 1,
                        },
                    );
                });
                PresentParams {
                    scale: Self::letterbox(gpu.frame_size, (gpu.config.width, gpu.config.height)),
                    ..PresentParams::default()
                }
            }
            Content::Solid(c) => {
                let [r, g, b] = c.get();
                PresentParams {
                    scale: [1.0, 1.0],
                    _pad: [0.0; 2],
                    solid: [
                        f32::from(r) / 255.0,
                        f32::from(g) / 255.0,
                        f32::from(b) / 255.0,
                        1.0,
                    ],
                }
            }
        };
        gpu.queue
            .write_buffer(&gpu.params, 0, bytemuck::bytes_of(&params));
        let frame = match gpu.surface.get_current_texture() {
            wgpu::CurrentSurfaceTexture::Success(t)
            | wgpu::CurrentSurfaceTexture::Suboptimal(t) => t,
            wgpu::CurrentSurfaceTexture::Outdated | wgpu::CurrentSurfaceTexture::Lost => {
                gpu.surface.configure(&gpu.device, &gpu.config);
                return Ok(());
            }
            wgpu::CurrentSurfaceTexture::Timeout | wgpu::CurrentSurfaceTexture::Occluded => {
                return Ok(());
            }
            wgpu::CurrentSurfaceTexture::Validation => {
                anyhow::bail!("the window surface reported a validation error");
            }
        };
        let view = frame
            .texture
            .create_view(&wgpu::TextureViewDescriptor::default());
        let mut encoder = gpu
            .device
            .create_command_encoder(&wgpu::CommandEncoderDescriptor {
                label: Some("present"),
            });
        {
            let mut pass = encoder.begin_render_pass(&wgpu::RenderPassDescriptor {
                label: Some("present"),
                color_attachments: &[Some(wgpu::RenderPassColorAttachment {
                    view: &view,
                    depth_slice: None,
                    resolve_target: None,
                    ops: wgpu::Operations {
                        load: wgpu::LoadOp::Clear(wgpu::Color::BLACK),
                        store: wgpu::StoreOp::Store,
                    },
                })],
                depth_stencil_attachment: None,
                timestamp_writes: None,
                occlusion_query_set: None,
                multiview_mask: None,
            });
            pass.set_pipeline(&gpu.pipeline);
            pass.set_bind_group(0, &gpu.bind_group, &[]);
            pass.draw(0..4, 0..1);
        }
        gpu.queue.submit([encoder.finish()]);
        gpu.window.pre_present_notify();
        gpu.queue.present(frame);
        self.stats.presented += 1;
        Ok(())
    }
}

impl ApplicationHandler for App {
    fn resumed(&mut self, event_loop: &ActiveEventLoop) {
        if self.gpu.is_some() {
            return;
        }
        match self.init(event_loop) {
            Ok(gpu) => self.gpu = Some(gpu),
            Err(e) => self.fail(event_loop, e),
        }
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
                if let Some(gpu) = &mut self.gpu
                    && size.width > 0
                    && size.height > 0
                {
                    gpu.config.width = size.width;
                    gpu.config.height = size.height;
                    gpu.surface.configure(&gpu.device, &gpu.config);
                }
            }
            WindowEvent::CursorMoved { position, .. } => {
                if let (Some(mouse), Some(gpu)) = (&self.mouse, &self.gpu) {
                    let (ww, wh) = (gpu.config.width as f64, gpu.config.height as f64);
                    let s = Self::letterbox(gpu.frame_size, (gpu.config.width, gpu.config.height));
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
                if let Some(gpu) = &self.gpu {
                    gpu.window.request_redraw();
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
        // FIFO present paces the redraws; without a surface yet, poll gently.
        if self.gpu.is_none() {
            event_loop.set_control_flow(ControlFlow::WaitUntil(
                Instant::now() + Duration::from_millis(5),
            ));
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn present_params_match_the_wgsl_struct() {
        // vec2 scale + vec2 pad + vec4 solid = 32 bytes, 16-byte aligned.
        assert_eq!(std::mem::size_of::<PresentParams>(), 32);
        assert!(PRESENT_WGSL.contains("scale: vec2<f32>"));
        assert!(PRESENT_WGSL.contains("solid: vec4<f32>"));
    }

    #[test]
    fn letterbox_keeps_the_aspect() {
        assert_eq!(App::letterbox((720, 800), (720, 800)), [1.0, 1.0]);
        let s = App::letterbox((100, 100), (200, 100));
        assert_eq!(s, [0.5, 1.0]);
        let s = App::letterbox((200, 100), (100, 100));
        assert_eq!(s, [1.0, 0.5]);
    }

    #[test]
    fn slot_counts_frames_the_window_never_showed() {
        let slot = DisplaySlot::new(2, 1);
        let mut last = 0;
        slot.put(&[1; 8]);
        slot.put(&[2; 8]);
        slot.put(&[3; 8]);
        let mut got = Vec::new();
        assert!(slot.take_newer(&mut last, |px| got.extend_from_slice(px)));
        assert_eq!(got, vec![3; 8]);
        assert_eq!(slot.skipped(), 2);
        assert!(!slot.take_newer(&mut last, |_| {}));
        // A frame of the wrong size is ignored, never a panic.
        slot.put(&[9; 4]);
        assert!(!slot.take_newer(&mut last, |_| {}));
    }

    #[test]
    fn solid_colour_round_trips() {
        let c = SolidColour::new([0, 0, 0]);
        c.set([255, 128, 7]);
        assert_eq!(c.get(), [255, 128, 7]);
    }
}
