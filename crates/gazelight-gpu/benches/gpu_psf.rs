//! GPU glare PSF rebuild (001 §4.2, eq 5–10) at the default parameters
//! (N = 512, 32 wavelengths, 65 px at 13.85 ppd, 1000 particles): aperture,
//! FFT, intensity, summed-area table, spectral sum, normalisation, one
//! command buffer, for a pupil alternating between 3 and 6 mm.
//!
//! Times come from GPU timestamps at the beginning and end of the rebuild's
//! three compute passes when the adapter supports `TIMESTAMP_QUERY` (the
//! per-pass split is printed once), otherwise from the wall clock around
//! submit + `device.poll(wait)`. On lavapipe the figures only prove the
//! benchmark runs (`cargo bench -p gazelight-gpu --bench gpu_psf -- --test`).

use std::time::{Duration, Instant};

use criterion::{Criterion, criterion_group, criterion_main};
use gazelight_gpu::fft::read_mapped;
use gazelight_gpu::psf::REBUILD_TIMESTAMPS;
use gazelight_gpu::testing::gpu_required;
use gazelight_gpu::{ContextOptions, GpuContext, GpuPsfBuilder};
use gazelight_vision::psf::PsfParams;

const TIMESTAMP_BYTES: u64 = REBUILD_TIMESTAMPS as u64 * 8;

/// Timestamp query set, resolve buffer and readback buffer.
struct Timestamps {
    set: wgpu::QuerySet,
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
        Some(Self {
            set: device.create_query_set(&wgpu::QuerySetDescriptor {
                label: Some("psf timestamps"),
                ty: wgpu::QueryType::Timestamp,
                count: REBUILD_TIMESTAMPS,
            }),
            resolve: device.create_buffer(&wgpu::BufferDescriptor {
                label: Some("psf timestamps resolve"),
                size: TIMESTAMP_BYTES,
                usage: wgpu::BufferUsages::QUERY_RESOLVE | wgpu::BufferUsages::COPY_SRC,
                mapped_at_creation: false,
            }),
            readback: device.create_buffer(&wgpu::BufferDescriptor {
                label: Some("psf timestamps readback"),
                size: TIMESTAMP_BYTES,
                usage: wgpu::BufferUsages::MAP_READ | wgpu::BufferUsages::COPY_DST,
                mapped_at_creation: false,
            }),
            period_ns: f64::from(ctx.queue().get_timestamp_period()),
        })
    }
}

/// One rebuild; returns its duration and, with timestamps, the per-pass
/// times (aperture, FFT, spectral + normalisation) in ns.
fn rebuild_once(
    ctx: &GpuContext,
    psf: &mut GpuPsfBuilder,
    timestamps: Option<&Timestamps>,
    pupil_mm: f64,
) -> (Duration, Option<[f64; 3]>) {
    let mut encoder = ctx.device().create_command_encoder(&Default::default());
    match timestamps {
        Some(ts) => {
            let _ = psf.encode_rebuild_timed(&mut encoder, pupil_mm, Some(&ts.set));
            encoder.resolve_query_set(&ts.set, 0..REBUILD_TIMESTAMPS, &ts.resolve, 0);
            encoder.copy_buffer_to_buffer(&ts.resolve, 0, &ts.readback, 0, TIMESTAMP_BYTES);
            ctx.queue().submit([encoder.finish()]);
            let mut ticks = [0u64; REBUILD_TIMESTAMPS as usize];
            read_mapped(ctx, &ts.readback, "timestamps", |bytes| {
                ticks.copy_from_slice(bytemuck::cast_slice(bytes));
            })
            .expect("timestamp readback");
            let ns = |a: usize, b: usize| ticks[b].saturating_sub(ticks[a]) as f64 * ts.period_ns;
            let total = ns(0, 5);
            (
                Duration::from_nanos(total as u64),
                Some([ns(0, 1), ns(2, 3), ns(4, 5)]),
            )
        }
        None => {
            let _ = psf.encode_rebuild(&mut encoder, pupil_mm);
            let start = Instant::now();
            ctx.queue().submit([encoder.finish()]);
            ctx.wait_idle().expect("device poll");
            (start.elapsed(), None)
        }
    }
}

fn bench_psf(c: &mut Criterion) {
    let options = ContextOptions {
        timestamp_queries: true,
        ..ContextOptions::default()
    };
    let ctx = match GpuContext::new(&options) {
        Ok(ctx) => ctx,
        Err(e) if gpu_required() => panic!("GAZELIGHT_REQUIRE_GPU=1 but no GPU device: {e}"),
        Err(e) => {
            println!("SKIP gpu_psf: no GPU device ({e})");
            return;
        }
    };
    let timestamps = Timestamps::new(&ctx);
    println!(
        "gpu_psf on {} ({})",
        ctx.describe(),
        if timestamps.is_some() {
            "GPU timestamps"
        } else {
            "wall clock + poll(wait)"
        }
    );
    let params = PsfParams::default();
    let mut psf = GpuPsfBuilder::new(&ctx, &params).expect("GPU PSF builder");
    // Warm up, and print the per-pass split once.
    for pupil_mm in [3.0, 6.0, 3.0] {
        let (total, split) = rebuild_once(&ctx, &mut psf, timestamps.as_ref(), pupil_mm);
        if let Some([aperture, fft, rest]) = split {
            println!(
                "psf rebuild {pupil_mm} mm: {:.1} µs (aperture {:.1} µs, FFT {:.1} µs, \
                 intensity + SAT + spectral + normalise {:.1} µs)",
                total.as_secs_f64() * 1e6,
                aperture / 1e3,
                fft / 1e3,
                rest / 1e3
            );
        }
    }
    let mut group = c.benchmark_group("gpu_psf_rebuild");
    group.sample_size(10);
    group.bench_function("N512_32wl_65px", |b| {
        b.iter_custom(|iters| {
            let mut total = Duration::ZERO;
            for i in 0..iters {
                let pupil_mm = if i % 2 == 0 { 3.0 } else { 6.0 };
                total += rebuild_once(&ctx, &mut psf, timestamps.as_ref(), pupil_mm).0;
            }
            total
        });
    });
    group.finish();
}

criterion_group!(benches, bench_psf);
criterion_main!(benches);
