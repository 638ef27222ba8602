#![allow(clippy::unwrap_used, clippy::expect_used)] // test and bench code may panic on a failed setup
//! The GPU frame pipeline ([`GpuFramePipeline`]), both eyes, at the Vive
//! Pro's 1440×1600 per eye (override with `GAZELIGHT_BENCH_SIZE=WxH`, e.g.
//! on a software adapter), on a night view of the shared `night.exr`
//! panorama (scotopic colour, acuity blur, glare): one command buffer per
//! frame holding both eyes, with the PSF cached, and with a PSF rebuild in
//! both eyes (pupil alternating 3 ↔ 6 mm).
//!
//! Times come from GPU timestamps per stage (pooling, adaptation, PSF
//! rebuild — the GPU kernel build, [`REBUILD_TIMESTAMPS`] — kernel spectrum, glare, tone + colour + acuity + encode) when the
//! adapter supports `TIMESTAMP_QUERY` — the per-stage split is printed once
//! per case — otherwise from the wall clock around submit +
//! `device.poll(wait)` (stated in the output). On lavapipe the figures only
//! prove the benchmark runs:
//! `GAZELIGHT_BENCH_SIZE=256x256 cargo bench -p gazelight-gpu --bench gpu_frame -- --quick`.
//! Not part of CI.

use std::time::{Duration, Instant};

use criterion::{Criterion, criterion_group, criterion_main};
use gazelight_gpu::fft::read_mapped;
use gazelight_gpu::frame::{FRAME_TIMESTAMPS, FrameTimestamps};
use gazelight_gpu::psf::REBUILD_TIMESTAMPS;
use gazelight_gpu::testing::gpu_required;
use gazelight_gpu::{ContextOptions, GpuContext, GpuFramePipeline};
use gazelight_vision::RgbImage;
use gazelight_vision::pipeline::{FrameInput, PipelineConfig};
use gazelight_vision::scene::{LuminanceScale, PanoramaView, Scene, ViewParams};

/// Resolve-buffer bytes per query set (`QUERY_RESOLVE_BUFFER_ALIGNMENT`):
/// eye 0 frame, eye 0 PSF, eye 1 frame, eye 1 PSF.
const SLOT: u64 = wgpu::QUERY_RESOLVE_BUFFER_ALIGNMENT;

fn size() -> (usize, usize) {
    std::env::var("GAZELIGHT_BENCH_SIZE")
        .ok()
        .and_then(|s| {
            let (w, h) = s.split_once('x')?;
            Some((w.trim().parse().ok()?, h.trim().parse().ok()?))
        })
        .unwrap_or((1440, 1600))
}

fn eye_view(yaw_deg: f64, w: usize, h: usize) -> (RgbImage, f64) {
    let path = gazelight_test_support::data_path("hdr/blender-world/night.exr");
    let scene = Scene::load(&path, LuminanceScale::default()).expect("shared panorama");
    let view = ViewParams {
        yaw_deg,
        pitch_deg: -6.0,
        hfov_deg: 104.0,
        width: w,
        height: h,
    };
    let mut img = RgbImage::new(w, h);
    PanoramaView::new(view)
        .expect("view")
        .render(&scene.image, &mut img);
    (img, view.deg_per_px())
}

struct Timestamps {
    queries: [wgpu::QuerySet; 2],
    psf: [wgpu::QuerySet; 2],
    resolve: wgpu::Buffer,
    readback: wgpu::Buffer,
    period_ns: f64,
}

impl Timestamps {
    fn new(ctx: &GpuContext) -> Option<Self> {
        if !ctx.has_timestamp_queries() {
            return None;
        }
        let device = ctx.device();
        let set = |count| {
            device.create_query_set(&wgpu::QuerySetDescriptor {
                label: Some("frame timestamps"),
                ty: wgpu::QueryType::Timestamp,
                count,
            })
        };
        let bytes = 4 * SLOT;
        Some(Self {
            queries: [set(FRAME_TIMESTAMPS), set(FRAME_TIMESTAMPS)],
            psf: [set(REBUILD_TIMESTAMPS), set(REBUILD_TIMESTAMPS)],
            resolve: device.create_buffer(&wgpu::BufferDescriptor {
                label: Some("frame timestamps resolve"),
                size: bytes,
                usage: wgpu::BufferUsages::QUERY_RESOLVE | wgpu::BufferUsages::COPY_SRC,
                mapped_at_creation: false,
            }),
            readback: device.create_buffer(&wgpu::BufferDescriptor {
                label: Some("frame timestamps readback"),
                size: bytes,
                usage: wgpu::BufferUsages::MAP_READ | wgpu::BufferUsages::COPY_DST,
                mapped_at_creation: false,
            }),
            period_ns: f64::from(ctx.queue().get_timestamp_period()),
        })
    }
}

/// Per-stage GPU times of both eyes, ns: pooling, adaptation, PSF rebuild,
/// kernel spectrum, glare, tone + colour + acuity + encode; and the span
/// from the first to the last timestamp.
struct Split {
    stages: [f64; 6],
    span: f64,
}

/// One frame for both eyes in one command buffer.
fn frame(
    ctx: &GpuContext,
    eyes: &mut [GpuFramePipeline; 2],
    input: &FrameInput,
    timestamps: Option<&Timestamps>,
    rebuild: bool,
) -> (Duration, Option<Split>) {
    let mut encoder = ctx.device().create_command_encoder(&Default::default());
    for (i, eye) in eyes.iter_mut().enumerate() {
        let t = timestamps.map(|t| FrameTimestamps {
            frame: &t.queries[i],
            psf: &t.psf[i],
        });
        eye.encode_timed(&mut encoder, input, t);
    }
    let Some(ts) = timestamps else {
        let start = Instant::now();
        ctx.queue().submit([encoder.finish()]);
        ctx.wait_idle().expect("device poll");
        return (start.elapsed(), None);
    };
    for i in 0..2 {
        let base = 2 * i as u64 * SLOT;
        encoder.resolve_query_set(&ts.queries[i], 0..FRAME_TIMESTAMPS, &ts.resolve, base);
        if rebuild {
            encoder.resolve_query_set(&ts.psf[i], 0..REBUILD_TIMESTAMPS, &ts.resolve, base + SLOT);
        }
    }
    encoder.copy_buffer_to_buffer(&ts.resolve, 0, &ts.readback, 0, ts.resolve.size());
    ctx.queue().submit([encoder.finish()]);
    let mut ticks = [0u64; (4 * SLOT / 8) as usize];
    read_mapped(ctx, &ts.readback, "timestamps", |bytes| {
        ticks.copy_from_slice(bytemuck::cast_slice(bytes));
    })
    .expect("timestamp readback");
    let mut stages = [0.0; 6];
    let (mut first, mut last) = (u64::MAX, 0u64);
    for eye in 0..2usize {
        let slot = (SLOT / 8) as usize;
        let t = &ticks[2 * eye * slot..(2 * eye + 2) * slot];
        let ns = |a: usize, b: usize| t[b].saturating_sub(t[a]) as f64 * ts.period_ns;
        let f = slot;
        stages[0] += ns(0, 1);
        stages[1] += ns(2, 3);
        stages[4] += ns(6, 7);
        stages[5] += ns(8, 9);
        if rebuild {
            // REBUILD_TIMESTAMPS: 0 before the aperture pass, 1 after the
            // normalisation: the whole GPU kernel build.
            stages[2] += ns(f, f + 1);
            stages[3] += ns(4, 5);
        }
        first = first.min(t[0]);
        last = last.max(t[9]);
    }
    let span = last.saturating_sub(first) as f64 * ts.period_ns;
    (
        Duration::from_nanos(span as u64),
        Some(Split { stages, span }),
    )
}

fn bench_frame(c: &mut Criterion) {
    let options = ContextOptions {
        timestamp_queries: true,
        ..ContextOptions::default()
    };
    let ctx = match GpuContext::new(&options) {
        Ok(ctx) => ctx,
        Err(e) if gpu_required() => panic!("GAZELIGHT_REQUIRE_GPU=1 but no GPU device: {e}"),
        Err(e) => {
            println!("SKIP gpu_frame: no GPU device ({e})");
            return;
        }
    };
    let (w, h) = size();
    let timestamps = Timestamps::new(&ctx);
    println!(
        "gpu_frame {w}x{h} per eye, both eyes, on {} ({})",
        ctx.describe(),
        if timestamps.is_some() {
            "GPU timestamps"
        } else {
            "wall clock around submit + poll(wait): no TIMESTAMP_QUERY"
        }
    );
    let mut eyes = [-81.4, -75.4].map(|yaw| {
        let (img, dpp) = eye_view(yaw, w, h);
        let mut eye = GpuFramePipeline::new(&ctx, PipelineConfig::default(), w, h, dpp)
            .expect("GPU frame pipeline");
        // Upload the view once; the frames below re-run every stage on it.
        eye.process(
            &img,
            &FrameInput {
                gaze_uv: [0.5, 0.45],
                pupil_mm: 4.0,
                dt_secs: 1.0 / 90.0,
            },
        )
        .expect("first frame");
        eye
    });
    let names = [
        "pooling",
        "adaptation",
        "PSF rebuild",
        "kernel spectrum",
        "glare",
        "tone+colour+acuity+encode",
    ];
    let mut group = c.benchmark_group(format!("gpu_frame_{w}x{h}_both_eyes"));
    group.sample_size(10);
    for rebuild in [false, true] {
        let mut pupil = 4.0f32;
        let mut next_input = move || {
            if rebuild {
                pupil = if pupil > 4.5 { 3.0 } else { 6.0 };
            }
            FrameInput {
                gaze_uv: [0.5, 0.45],
                pupil_mm: pupil,
                dt_secs: 1.0 / 90.0,
            }
        };
        let input = next_input();
        let (total, split) = frame(&ctx, &mut eyes, &input, timestamps.as_ref(), rebuild);
        match split {
            Some(s) => {
                let parts: Vec<String> = names
                    .iter()
                    .zip(s.stages)
                    .map(|(n, ns)| format!("{n} {:.1} µs", ns / 1e3))
                    .collect();
                println!(
                    "both eyes, {}: {:.1} µs first to last timestamp; per stage (sum of eyes): {}",
                    if rebuild { "PSF rebuild" } else { "PSF cached" },
                    s.span / 1e3,
                    parts.join(", ")
                );
            }
            None => println!(
                "both eyes, {}: {:.1} ms wall",
                if rebuild { "PSF rebuild" } else { "PSF cached" },
                total.as_secs_f64() * 1e3
            ),
        }
        let name = if rebuild { "psf_rebuild" } else { "psf_cached" };
        group.bench_function(name, |b| {
            b.iter_custom(|iters| {
                let mut total = Duration::ZERO;
                for _ in 0..iters {
                    let input = next_input();
                    total += frame(&ctx, &mut eyes, &input, timestamps.as_ref(), rebuild).0;
                }
                total
            });
        });
    }
    group.finish();
}

criterion_group!(benches, bench_frame);
criterion_main!(benches);
