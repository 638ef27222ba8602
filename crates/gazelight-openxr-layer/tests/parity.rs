//! Parity of the layer's frame path with gazelight-gpu's pipeline.
//!
//! The test plays the app: it creates a Vulkan instance and device the way
//! an OpenXR app's runtime would (hello_xr's create infos: API 1.0, no
//! extensions, core features), through the layer's patches
//! ([`InstancePatch`], [`DevicePlan::patch`]), opens the layer's wgpu
//! device on that `VkDevice` ([`DevicePlan::open`]), makes an image on it
//! in `COLOR_ATTACHMENT_OPTIMAL` holding a real scene (assets/night.exr,
//! encoded in the swapchain's format), and runs the layer's path on it
//! ([`LayerGpu::wrap_image`], [`EyeProcessor`]): import, pipeline, draw
//! back into the image. The reference is gazelight-gpu's
//! `GpuFramePipeline::process` on the CPU twin's import of the same texels,
//! same gaze, pupil and time step. Two frames (the second with another
//! gaze, pupil and dt: adaptation state and PSF carried over). The layer's
//! image must equal the reference display frame within 1/255 and differ
//! from its input (the effects were applied). Also: the import pass
//! (`shaders/layer_import.wgsl`) equals its CPU twin value for value.

#![allow(clippy::expect_used, clippy::unwrap_used)]

use std::ffi::c_char;

use ash::vk;
use gazelight_gpu::{GpuFramePipeline, testing::gpu_required};
use gazelight_openxr_layer::import::{ImageFormat, import_cpu, row_bytes};
use gazelight_openxr_layer::process::{EyeProcessor, EyeSpec, deg_per_px, fov_tangents};
use gazelight_openxr_layer::vk::{AppInstance, DevicePlan, InstancePatch, LayerGpu, raw_image};
use gazelight_vision::RgbImage;
use gazelight_vision::pipeline::{FrameInput, PipelineConfig, srgb_encode};
use gazelight_vision::scene::{LuminanceScale, Scene};

const W: u32 = 192;
const H: u32 = 160;
const WHITE_CD_M2: f32 = 300.0;

struct App {
    _entry: ash::Entry,
    instance: ash::Instance,
    device: ash::Device,
    gpu: Option<LayerGpu>,
}

impl Drop for App {
    fn drop(&mut self) {
        // The layer's device and instance wrappers first (they do not own
        // the handles), then the app's own.
        self.gpu.take();
        // SAFETY: the app's own device and instance, no longer used (the
        // layer's wrappers are gone), destroyed once, device first.
        unsafe {
            let _ = self.device.device_wait_idle();
            self.device.destroy_device(None);
            self.instance.destroy_instance(None);
        }
    }
}

/// The app's instance and device through the layer's patches, and the
/// layer's wgpu device on them. `None` (with a SKIP line) without Vulkan.
fn app() -> Option<App> {
    // SAFETY: loads the system's Vulkan loader (its initialisation is
    // trusted, as any Vulkan app's).
    let entry = match unsafe { ash::Entry::load() } {
        Ok(e) => e,
        Err(e) if !gpu_required() => {
            println!("SKIP parity: no Vulkan loader ({e})");
            return None;
        }
        Err(e) => panic!("no Vulkan loader: {e}"),
    };
    // hello_xr's VkApplicationInfo: API 1.0.
    let app_info = vk::ApplicationInfo::default()
        .application_name(c"parity")
        .api_version(vk::API_VERSION_1_0);
    let info = vk::InstanceCreateInfo::default().application_info(&app_info);
    // SAFETY: `info` and `app_info` outlive the patch.
    let patch = unsafe { InstancePatch::new(&entry, &info) }.expect("instance patch");
    // SAFETY: the patched info is valid while `patch` lives (the call).
    let instance = unsafe { entry.create_instance(patch.info(), None) }.expect("vkCreateInstance");
    let app_instance = AppInstance {
        entry: entry.clone(),
        raw: instance.handle(),
        api_version: patch.api_version,
        extensions: patch.extensions.clone(),
    };
    // SAFETY: a live instance.
    let phd = unsafe { instance.enumerate_physical_devices() }.expect("physical devices");
    let Some(&phd) = phd.first() else {
        assert!(!gpu_required(), "no Vulkan physical device");
        println!("SKIP parity: no Vulkan physical device");
        return None;
    };
    // SAFETY: a physical device of this live instance.
    let family = unsafe { instance.get_physical_device_queue_family_properties(phd) }
        .iter()
        .position(|f| f.queue_flags.contains(vk::QueueFlags::GRAPHICS))
        .expect("a graphics queue family") as u32;
    let plan = DevicePlan::new(&app_instance, phd).expect("device plan");
    println!("parity: running on {}", plan.adapter_name);
    let priorities = [1.0f32];
    let queues = [vk::DeviceQueueCreateInfo::default()
        .queue_family_index(family)
        .queue_priorities(&priorities)];
    // hello_xr: core features only, no extensions of its own.
    let features = vk::PhysicalDeviceFeatures::default();
    let no_ext: [*const c_char; 0] = [];
    let dinfo = vk::DeviceCreateInfo::default()
        .queue_create_infos(&queues)
        .enabled_extension_names(&no_ext)
        .enabled_features(&features);
    // SAFETY: `dinfo` and what it points to outlive the patch.
    let dpatch = unsafe { plan.patch(&dinfo) }.expect("device patch");
    let device =
        // SAFETY: the patched info is valid while `dpatch` lives (the call).
        unsafe { instance.create_device(phd, dpatch.info(), None) }.expect("vkCreateDevice");
    let gpu = plan
        .open(device.handle(), family, 0)
        .expect("the layer's wgpu device");
    Some(App {
        _entry: entry,
        instance,
        device,
        gpu: Some(gpu),
    })
}

/// A W×H crop of the real night scene, cd/m².
fn scene() -> RgbImage {
    let path = std::path::Path::new(env!("CARGO_MANIFEST_DIR")).join("../../assets/night.exr");
    let s = Scene::load(&path, LuminanceScale::default()).expect("assets/night.exr");
    let img = s.image;
    let (x0, y0) = ((img.width - W as usize) / 2, (img.height - H as usize) / 2);
    let mut out = RgbImage::new(W as usize, H as usize);
    for y in 0..H as usize {
        for x in 0..W as usize {
            out.pixels[y * W as usize + x] = img.pixels[(y0 + y) * img.width + x0 + x];
        }
    }
    out
}

/// IEEE binary16 of `v` (round to nearest even), for the float swapchain.
fn f32_to_f16(v: f32) -> u16 {
    let b = v.to_bits();
    let sign = ((b >> 16) & 0x8000) as u16;
    let exp = ((b >> 23) & 0xff) as i32 - 127 + 15;
    let mant = b & 0x7f_ffff;
    if exp >= 31 {
        return sign | 0x7c00;
    }
    if exp <= 0 {
        return sign;
    }
    let m = mant >> 13;
    let rest = mant & 0x1fff;
    let mut h = (sign as u32) | ((exp as u32) << 10) | m;
    if rest > 0x1000 || (rest == 0x1000 && (m & 1) == 1) {
        h += 1;
    }
    h as u16
}

/// The scene as the app's texels of `format` (tightly packed rows).
fn texels(scene: &RgbImage, format: ImageFormat) -> Vec<u8> {
    let peak = scene
        .pixels
        .iter()
        .map(|p| p[0].max(p[1]).max(p[2]))
        .fold(0.0f32, f32::max)
        .max(1e-6);
    let mut out = Vec::new();
    for p in &scene.pixels {
        match format {
            ImageFormat::Rgba8Srgb | ImageFormat::Bgra8Srgb => {
                // Display-referred: the scene's peak at code 255.
                let c = p.map(|v| (srgb_encode((v / peak).clamp(0.0, 1.0)) * 255.0).round() as u8);
                if format == ImageFormat::Bgra8Srgb {
                    out.extend_from_slice(&[c[2], c[1], c[0], 255]);
                } else {
                    out.extend_from_slice(&[c[0], c[1], c[2], 255]);
                }
            }
            ImageFormat::Rgba16Float => {
                for v in [p[0], p[1], p[2], 1.0] {
                    out.extend_from_slice(&f32_to_f16(v).to_le_bytes());
                }
            }
        }
    }
    out
}

/// Reads `texture` (layer 0) back as bytes, rows unpadded.
fn read_texture(gpu: &LayerGpu, texture: &wgpu::Texture, format: ImageFormat) -> Vec<u8> {
    let ctx = &gpu.ctx;
    let (width, height) = (texture.width(), texture.height());
    let row = row_bytes(format, width);
    let buf = ctx.device().create_buffer(&wgpu::BufferDescriptor {
        label: None,
        size: u64::from(row * height),
        usage: wgpu::BufferUsages::COPY_DST | wgpu::BufferUsages::MAP_READ,
        mapped_at_creation: false,
    });
    let mut enc = ctx.device().create_command_encoder(&Default::default());
    enc.copy_texture_to_buffer(
        texture.as_image_copy(),
        wgpu::TexelCopyBufferInfo {
            buffer: &buf,
            layout: wgpu::TexelCopyBufferLayout {
                offset: 0,
                bytes_per_row: Some(row),
                rows_per_image: Some(height),
            },
        },
        texture.size(),
    );
    ctx.queue().submit([enc.finish()]);
    buf.slice(..).map_async(wgpu::MapMode::Read, |_| ());
    ctx.wait_idle().expect("wait");
    let data = buf.slice(..).get_mapped_range().expect("mapped").to_vec();
    let tb = (format.texel_bytes() * width) as usize;
    data.chunks(row as usize)
        .flat_map(|r| r[..tb].to_vec())
        .collect()
}

/// The display frame's RGBA8 bytes as the app's image of `format` would
/// hold them after the layer drew it (sRGB codes; half floats: decoded).
fn as_codes(bytes: &[u8], format: ImageFormat) -> Vec<[f32; 3]> {
    match format {
        ImageFormat::Rgba8Srgb => bytes
            .chunks(4)
            .map(|c| [c[0], c[1], c[2]].map(f32::from))
            .collect(),
        ImageFormat::Bgra8Srgb => bytes
            .chunks(4)
            .map(|c| [c[2], c[1], c[0]].map(f32::from))
            .collect(),
        ImageFormat::Rgba16Float => bytes
            .chunks(8)
            .map(|c| {
                [0, 2, 4].map(|k| {
                    let lin = gazelight_openxr_layer::import::f16_to_f32(u16::from_le_bytes([
                        c[k],
                        c[k + 1],
                    ]));
                    srgb_encode(lin.clamp(0.0, 1.0)) * 255.0
                })
            })
            .collect(),
    }
}

/// The app's swapchain image, `width` × H, that the app renders into
/// (left in `COLOR_ATTACHMENT_OPTIMAL` after its render pass).
fn app_image(
    ctx: &gazelight_gpu::GpuContext,
    format: wgpu::TextureFormat,
    width: u32,
    label: &str,
) -> wgpu::Texture {
    ctx.device().create_texture(&wgpu::TextureDescriptor {
        label: Some(label),
        size: wgpu::Extent3d {
            width,
            height: H,
            depth_or_array_layers: 1,
        },
        mip_level_count: 1,
        sample_count: 1,
        dimension: wgpu::TextureDimension::D2,
        format,
        usage: wgpu::TextureUsages::COPY_SRC
            | wgpu::TextureUsages::COPY_DST
            | wgpu::TextureUsages::RENDER_ATTACHMENT,
        view_formats: &[],
    })
}

/// The CPU twin's import of a W×H image's `texels`: the reference
/// pipeline's scene, cd/m².
fn imported(texels: &[u8], format: ImageFormat, scale: f32) -> RgbImage {
    let tb = format.texel_bytes() as usize;
    let scene = import_cpu(
        texels,
        W as usize * tb,
        W as usize,
        H as usize,
        format,
        scale,
    )
    .expect("CPU import");
    RgbImage {
        width: W as usize,
        height: H as usize,
        pixels: scene.iter().map(|p| [p[0], p[1], p[2]]).collect(),
    }
}

/// A W×H view of edge tangents `tan_lrud` in `format`, decoded × `scale`.
fn eye_spec(format: wgpu::TextureFormat, tan_lrud: [f64; 4], scale: f32) -> EyeSpec {
    EyeSpec {
        format,
        width: W,
        height: H,
        tan_lrud,
        scale,
        timed: false,
    }
}

/// The two frames' gaze and pupil (the second `second_dt_secs` after the
/// first).
fn two_frames(second_dt_secs: f32) -> [FrameInput; 2] {
    [
        FrameInput {
            gaze_uv: [0.3, 0.6],
            pupil_mm: 5.5,
            dt_secs: 0.0,
        },
        FrameInput {
            gaze_uv: [0.7, 0.4],
            pupil_mm: 3.0,
            dt_secs: second_dt_secs,
        },
    ]
}

/// Two views side by side in one image (one swapchain for both eyes, each
/// view's `imageRect` one half, as some engines submit): each half
/// processed by its own eye's processor equals the pipeline on that half
/// alone, within 1/255, and neither eye's draw touches the other's half.
#[test]
fn two_views_side_by_side_in_one_image_each_match_the_pipeline() {
    let Some(mut app) = app() else {
        return;
    };
    let gpu = app.gpu.as_ref().expect("gpu");
    let ctx = gpu.ctx.clone();
    let format = wgpu::TextureFormat::Rgba8UnormSrgb;
    let image_format = ImageFormat::of(format).expect("served format");
    // The left eye sees the crop, the right eye its mirror image.
    let left = scene();
    let mut right = left.clone();
    for y in 0..H as usize {
        right.pixels[y * W as usize..(y + 1) * W as usize].reverse();
    }
    let halves = [texels(&left, image_format), texels(&right, image_format)];
    let tb = image_format.texel_bytes() as usize;
    let mut both = Vec::with_capacity(halves[0].len() * 2);
    for y in 0..H as usize {
        for half in &halves {
            both.extend_from_slice(&half[y * W as usize * tb..(y + 1) * W as usize * tb]);
        }
    }
    let app_texture = app_image(&ctx, format, 2 * W, "the app's side-by-side image");
    ctx.queue().write_texture(
        app_texture.as_image_copy(),
        &both,
        wgpu::TexelCopyBufferLayout {
            offset: 0,
            bytes_per_row: Some(2 * W * tb as u32),
            rows_per_image: Some(H),
        },
        app_texture.size(),
    );
    ctx.wait_idle().expect("wait");
    let a = 45f32.to_radians();
    let tan = fov_tangents(-a, a, a, -a);
    let config = PipelineConfig::default();
    let spec = eye_spec(format, tan, WHITE_CD_M2);
    // Each eye's first frame.
    let inputs = two_frames(0.0);
    let raw = raw_image(&app_texture).expect("raw image");
    // SAFETY: a live image wgpu made on this device (`app_image`: this size
    // and format, COPY_SRC and RENDER_ATTACHMENT), used by wgpu only as a
    // colour target; `app_texture` outlives `wrapped`.
    let wrapped = unsafe { gpu.wrap_image(raw, format, 2 * W, H, 1) }.expect("wrap");
    let mut processors: Vec<EyeProcessor> = (0..2)
        .map(|_| EyeProcessor::new(&ctx, &config, spec).expect("eye processor"))
        .collect();
    let mut enc = ctx.device().create_command_encoder(&Default::default());
    for (eye, (p, input)) in processors.iter_mut().zip(&inputs).enumerate() {
        assert!(
            p.wait_for_kernel(input.pupil_mm, std::time::Duration::from_secs(120))
                .expect("kernel")
        );
        p.encode(&mut enc, &wrapped, 0, [eye as u32 * W, 0], input)
            .expect("encode");
    }
    ctx.queue().submit([enc.finish()]);
    ctx.wait_idle().expect("wait");
    let out = as_codes(&read_texture(gpu, &app_texture, image_format), image_format);
    for (eye, (half, input)) in [&left, &right].into_iter().zip(&inputs).enumerate() {
        let cpu_scene = imported(&halves[eye], image_format, WHITE_CD_M2);
        let mut reference = GpuFramePipeline::new(
            &ctx,
            config.clone(),
            W as usize,
            H as usize,
            deg_per_px(tan, W),
        )
        .expect("reference pipeline");
        reference.set_view_frustum(tan).expect("frustum");
        reference
            .process(&cpu_scene, input)
            .expect("reference frame");
        let display = reference.display().expect("display").clone();
        let input_codes = as_codes(&halves[eye], image_format);
        let (mut worst, mut changed) = (0.0f32, 0usize);
        for y in 0..H as usize {
            for x in 0..W as usize {
                let l = out[y * 2 * W as usize + eye * W as usize + x];
                let r = &display.rgba8[(y * W as usize + x) * 4..][..4];
                for c in 0..3 {
                    worst = worst.max((l[c] - f32::from(r[c])).abs());
                }
                if (0..3).any(|c| (l[c] - input_codes[y * W as usize + x][c]).abs() > 2.0) {
                    changed += 1;
                }
            }
        }
        let n = (W * H) as usize;
        println!(
            "side by side, eye {eye} ({} px wide half at x = {}): worst difference {worst:.2} codes, {changed} of {n} pixels changed",
            half.width,
            eye as u32 * W
        );
        assert!(worst <= 1.0, "eye {eye}: worst difference {worst} codes");
        assert!(
            changed * 4 > n,
            "eye {eye}: the effects changed only {changed} of {n} pixels"
        );
    }
    drop(wrapped);
    drop(processors);
    drop(app_texture);
    ctx.wait_idle().expect("wait");
    drop(ctx);
    app.gpu.take();
}

fn run_format(format: wgpu::TextureFormat) {
    let Some(mut app) = app() else {
        return;
    };
    let gpu = app.gpu.as_ref().expect("gpu");
    let ctx = gpu.ctx.clone();
    let image_format = ImageFormat::of(format).expect("served format");
    let scene = scene();
    let input_texels = texels(&scene, image_format);
    // The app's swapchain image, rendered into by the app: in
    // COLOR_ATTACHMENT_OPTIMAL after its render pass.
    let app_texture = app_image(&ctx, format, W, "the app's image");
    let scale = if image_format == ImageFormat::Rgba16Float {
        1.0
    } else {
        WHITE_CD_M2
    };
    // 45° half-angles, as a simulated HMD's view.
    let a = 45f32.to_radians();
    let tan = fov_tangents(-a, a, a, -a);
    let config = PipelineConfig::default();
    // The full-field stray light (issue 46) is part of what is compared:
    // on by default, and it changes the frame (against the same pipeline
    // without it, below).
    assert!(config.glare.far_field, "the far field is on by default");
    let spec = eye_spec(format, tan, scale);
    let mut processor = EyeProcessor::new(&ctx, &config, spec).expect("eye processor");
    let reference_of = |config: PipelineConfig| {
        let mut p = GpuFramePipeline::new(&ctx, config, W as usize, H as usize, deg_per_px(tan, W))
            .expect("reference pipeline");
        p.set_view_frustum(tan).expect("frustum");
        p
    };
    let mut reference = reference_of(config.clone());
    let mut without_far = reference_of({
        let mut c = config.clone();
        c.glare.far_field = false;
        c
    });
    let tb = image_format.texel_bytes() as usize;
    let cpu_scene = imported(&input_texels, image_format, scale);
    let inputs = two_frames(1.0 / 60.0);
    let raw = raw_image(&app_texture).expect("raw image");
    // SAFETY: as in the first test: wgpu's image of this size and format on
    // this device, outliving `wrapped`.
    let wrapped = unsafe { gpu.wrap_image(raw, format, W, H, 1) }.expect("wrap");
    for (k, input) in inputs.iter().enumerate() {
        // The app renders its frame.
        ctx.queue().write_texture(
            app_texture.as_image_copy(),
            &input_texels,
            wgpu::TexelCopyBufferLayout {
                offset: 0,
                bytes_per_row: Some(W * tb as u32),
                rows_per_image: Some(H),
            },
            app_texture.size(),
        );
        let view = app_texture.create_view(&Default::default());
        let mut enc = ctx.device().create_command_encoder(&Default::default());
        drop(enc.begin_render_pass(&wgpu::RenderPassDescriptor {
            label: Some("the app's render pass"),
            color_attachments: &[Some(wgpu::RenderPassColorAttachment {
                view: &view,
                depth_slice: None,
                resolve_target: None,
                ops: wgpu::Operations {
                    load: wgpu::LoadOp::Load,
                    store: wgpu::StoreOp::Store,
                },
            })],
            ..Default::default()
        }));
        ctx.queue().submit([enc.finish()]);
        ctx.wait_idle().expect("wait");
        // The layer's path on the app's image.
        // The frame's kernel: the layer's comes from its eye's PSF worker
        // (the CPU builder, off the app's thread), the pipeline's is
        // rebuilt on the GPU inside the frame.
        assert!(
            processor
                .wait_for_kernel(input.pupil_mm, std::time::Duration::from_secs(120))
                .expect("kernel"),
            "the PSF worker's kernel for {} mm",
            input.pupil_mm
        );
        // Built by the eye's worker (one kernel per new pupil), not inside
        // the frame.
        assert!(processor.psf_off_thread());
        assert_eq!(processor.psf_builds(), k as u64 + 1);
        let mut enc = ctx.device().create_command_encoder(&Default::default());
        processor
            .encode(&mut enc, &wrapped, 0, [0, 0], input)
            .expect("encode");
        ctx.queue().submit([enc.finish()]);
        ctx.wait_idle().expect("wait");
        let layer_out = as_codes(&read_texture(gpu, &app_texture, image_format), image_format);
        // The plain pipeline.
        reference
            .process(&cpu_scene, input)
            .expect("reference frame");
        let display = reference.display().expect("display").clone();
        without_far
            .process(&cpu_scene, input)
            .expect("frame without the far field");
        let far_changed = display
            .rgba8
            .iter()
            .zip(&without_far.display().expect("display").rgba8)
            .filter(|(a, b)| a != b)
            .count();
        let mut worst = 0.0f32;
        let mut changed = 0usize;
        let input_codes = as_codes(&input_texels, image_format);
        for (i, (l, r)) in layer_out.iter().zip(display.rgba8.chunks(4)).enumerate() {
            for c in 0..3 {
                worst = worst.max((l[c] - f32::from(r[c])).abs());
            }
            if (0..3).any(|c| (l[c] - input_codes[i][c]).abs() > 2.0) {
                changed += 1;
            }
        }
        let n = (W * H) as usize;
        println!(
            "parity {format:?} frame {k}: worst difference {worst:.2} codes, {changed} of {n} pixels changed by the effects, {far_changed} channel values by the far field"
        );
        assert!(far_changed > 0, "the far field changed nothing");
        // Half floats: the layer's value decoded and re-encoded here.
        let tolerance = 1.0 + 1e-3;
        assert!(
            worst <= tolerance,
            "{format:?} frame {k}: worst {worst} codes > 1/255"
        );
        assert!(
            changed * 4 > n,
            "{format:?} frame {k}: the effects changed only {changed} of {n} pixels"
        );
    }
    drop(wrapped);
    drop(processor);
    drop(reference);
    drop(without_far);
    drop(app_texture);
    ctx.wait_idle().expect("wait");
    drop(ctx);
    app.gpu.take();
}

#[test]
fn the_layer_matches_the_pipeline_on_an_rgba8_srgb_image() {
    run_format(wgpu::TextureFormat::Rgba8UnormSrgb);
}

#[test]
fn the_layer_matches_the_pipeline_on_a_bgra8_srgb_image() {
    run_format(wgpu::TextureFormat::Bgra8UnormSrgb);
}

#[test]
fn the_layer_matches_the_pipeline_on_a_half_float_image() {
    run_format(wgpu::TextureFormat::Rgba16Float);
}

/// The import pass against its CPU twin, value for value, on the scene's
/// texels plus edge values (sRGB codes 0, 1, 254, 255; half-float
/// subnormals, the largest half, infinity).
#[test]
fn the_import_pass_equals_its_cpu_twin() {
    let Some(ctx) = gazelight_gpu::testing::test_context("the_import_pass_equals_its_cpu_twin")
    else {
        return;
    };
    let scene = scene();
    for format in [
        wgpu::TextureFormat::Rgba8UnormSrgb,
        wgpu::TextureFormat::Bgra8UnormSrgb,
        wgpu::TextureFormat::Rgba16Float,
    ] {
        let image_format = ImageFormat::of(format).expect("served");
        let mut input = texels(&scene, image_format);
        let edge: &[u8] = match image_format {
            ImageFormat::Rgba16Float => &[
                0x01, 0x00, 0xff, 0x03, 0xff, 0x7b, 0, 0x3c, 0x00, 0x7c, 0x00, 0x80, 0x00, 0x3c, 0,
                0x3c,
            ],
            _ => &[0, 1, 254, 255, 255, 254, 1, 0],
        };
        input[..edge.len()].copy_from_slice(edge);
        let tb = image_format.texel_bytes();
        let texture = ctx.device().create_texture(&wgpu::TextureDescriptor {
            label: None,
            size: wgpu::Extent3d {
                width: W,
                height: H,
                depth_or_array_layers: 1,
            },
            mip_level_count: 1,
            sample_count: 1,
            dimension: wgpu::TextureDimension::D2,
            format,
            usage: wgpu::TextureUsages::COPY_SRC | wgpu::TextureUsages::COPY_DST,
            view_formats: &[],
        });
        ctx.queue().write_texture(
            texture.as_image_copy(),
            &input,
            wgpu::TexelCopyBufferLayout {
                offset: 0,
                bytes_per_row: Some(W * tb),
                rows_per_image: Some(H),
            },
            texture.size(),
        );
        let bytes = u64::from(W * H) * 16;
        let scene_buf = ctx.device().create_buffer(&wgpu::BufferDescriptor {
            label: None,
            size: bytes,
            usage: wgpu::BufferUsages::STORAGE | wgpu::BufferUsages::COPY_SRC,
            mapped_at_creation: false,
        });
        let read = ctx.device().create_buffer(&wgpu::BufferDescriptor {
            label: None,
            size: bytes,
            usage: wgpu::BufferUsages::MAP_READ | wgpu::BufferUsages::COPY_DST,
            mapped_at_creation: false,
        });
        let pass = gazelight_openxr_layer::import::ImportPass::new(
            ctx,
            image_format,
            W,
            H,
            WHITE_CD_M2,
            &scene_buf,
        )
        .expect("import pass");
        let mut enc = ctx.device().create_command_encoder(&Default::default());
        pass.encode(&mut enc, &texture, 0, [0, 0], None);
        enc.copy_buffer_to_buffer(&scene_buf, 0, &read, 0, bytes);
        ctx.queue().submit([enc.finish()]);
        read.slice(..).map_async(wgpu::MapMode::Read, |_| ());
        ctx.wait_idle().expect("wait");
        let gpu: Vec<f32> =
            bytemuck::cast_slice(&read.slice(..).get_mapped_range().expect("mapped")).to_vec();
        let cpu = import_cpu(
            &input,
            (W * tb) as usize,
            W as usize,
            H as usize,
            image_format,
            WHITE_CD_M2,
        )
        .expect("CPU import");
        let mut mismatches = 0;
        for (g, c) in gpu.chunks(4).zip(&cpu) {
            for k in 0..4 {
                let same = (g[k].is_nan() && c[k].is_nan()) || g[k] == c[k];
                if !same {
                    mismatches += 1;
                }
            }
        }
        println!(
            "import {format:?}: {mismatches} of {} values differ from the CPU twin; first texels GPU {:?} CPU {:?}",
            cpu.len() * 4,
            &gpu[..8],
            &cpu[..2]
        );
        assert_eq!(mismatches, 0, "{format:?}");
    }
}

/// A view whose field of view moves a little (pixel size within 0.5 %)
/// keeps its processor, re-aimed ([`Fit::Frustum`], then the same view);
/// a larger change, another size or format needs a new one.
#[test]
fn a_slightly_changed_field_of_view_re_aims_the_processor() {
    use gazelight_openxr_layer::process::Fit;
    let Some(mut app) = app() else {
        return;
    };
    let ctx = app.gpu.as_ref().expect("gpu").ctx.clone();
    let format = wgpu::TextureFormat::Rgba8UnormSrgb;
    let half = |deg: f32| {
        let a = deg.to_radians();
        fov_tangents(-a, a, a, -a)
    };
    let spec = eye_spec(format, half(45.0), WHITE_CD_M2);
    let mut p = EyeProcessor::new(&ctx, &PipelineConfig::default(), spec).expect("eye processor");
    assert_eq!(p.fit(format, W, H, half(45.0)), Fit::Same);
    // 90.2° over 90°: the pixel size 0.22 % larger.
    assert_eq!(p.fit(format, W, H, half(45.1)), Fit::Frustum);
    p.set_view(half(45.1)).expect("set view");
    assert_eq!(p.fit(format, W, H, half(45.1)), Fit::Same);
    // 94° over 90°: 4.4 % larger; another size; another format.
    assert_eq!(p.fit(format, W, H, half(47.0)), Fit::Rebuild);
    assert_eq!(p.fit(format, W + 2, H, half(45.1)), Fit::Rebuild);
    assert_eq!(
        p.fit(wgpu::TextureFormat::Rgba16Float, W, H, half(45.1)),
        Fit::Rebuild
    );
    // Tangents out of order are refused, and the view is kept.
    let a = 45f32.to_radians();
    assert!(p.set_view(fov_tangents(a, -a, a, -a)).is_err());
    assert_eq!(p.fit(format, W, H, half(45.1)), Fit::Same);
    drop(p);
    ctx.wait_idle().expect("wait");
    drop(ctx);
    app.gpu.take();
}
