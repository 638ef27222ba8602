#![allow(clippy::unwrap_used, clippy::expect_used)] // test and bench code may panic on a failed setup
//! GPU FFT throughput: 512² and 1024² × 3 channels (RGB), forward transform.
//!
//! Times come from GPU timestamp queries written at the beginning and end of
//! the FFT's compute pass when the adapter supports `TIMESTAMP_QUERY`;
//! otherwise from the wall clock around submit + `device.poll(wait)`. On
//! lavapipe these figures only prove the benchmark runs
//! (`cargo bench -p gazelight-gpu -- --test`); hardware figures go to
//! BENCHMARKS.md.

use std::time::{Duration, Instant};

use criterion::{Criterion, criterion_group, criterion_main};
use gazelight_gpu::fft::read_mapped;
use gazelight_gpu::testing::gpu_required;
use gazelight_gpu::{ContextOptions, FftDirection, GpuContext, GpuFft2d};

/// Timestamp query set, resolve buffer and readback buffer for one pass.
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
        let set = device.create_query_set(&wgpu::QuerySetDescriptor {
            label: Some("fft timestamps"),
            ty: wgpu::QueryType::Timestamp,
            count: 2,
        });
        let resolve = device.create_buffer(&wgpu::BufferDescriptor {
            label: Some("fft timestamps resolve"),
            size: 16,
            usage: wgpu::BufferUsages::QUERY_RESOLVE | wgpu::BufferUsages::COPY_SRC,
            mapped_at_creation: false,
        });
        let readback = device.create_buffer(&wgpu::BufferDescriptor {
            label: Some("fft timestamps readback"),
            size: 16,
            usage: wgpu::BufferUsages::MAP_READ | wgpu::BufferUsages::COPY_DST,
            mapped_at_creation: false,
        });
        Some(Self {
            set,
            resolve,
            readback,
            period_ns: f64::from(ctx.queue().get_timestamp_period()),
        })
    }
}

/// Runs `iters` forward transforms and returns their summed duration.
fn time_fft(
    ctx: &GpuContext,
    fft: &GpuFft2d,
    timestamps: Option<&Timestamps>,
    iters: u64,
) -> Duration {
    let mut total = Duration::ZERO;
    for _ in 0..iters {
        let mut encoder = ctx.device().create_command_encoder(&Default::default());
        match timestamps {
            Some(ts) => {
                fft.encode(
                    &mut encoder,
                    FftDirection::Forward,
                    Some(wgpu::ComputePassTimestampWrites {
                        query_set: &ts.set,
                        beginning_of_pass_write_index: Some(0),
                        end_of_pass_write_index: Some(1),
                    }),
                );
                encoder.resolve_query_set(&ts.set, 0..2, &ts.resolve, 0);
                encoder.copy_buffer_to_buffer(&ts.resolve, 0, &ts.readback, 0, 16);
                ctx.queue().submit([encoder.finish()]);
                let mut ticks = [0u64; 2];
                read_mapped(ctx, &ts.readback, "timestamps", |bytes| {
                    ticks.copy_from_slice(bytemuck::cast_slice(bytes));
                })
                .expect("timestamp readback");
                let ns = ticks[1].saturating_sub(ticks[0]) as f64 * ts.period_ns;
                total += Duration::from_nanos(ns as u64);
            }
            None => {
                fft.encode(&mut encoder, FftDirection::Forward, None);
                let start = Instant::now();
                ctx.queue().submit([encoder.finish()]);
                ctx.wait_idle().expect("device poll");
                total += start.elapsed();
            }
        }
    }
    total
}

fn bench_fft(c: &mut Criterion) {
    let options = ContextOptions {
        timestamp_queries: true,
        ..ContextOptions::default()
    };
    let ctx = match GpuContext::new(&options) {
        Ok(ctx) => ctx,
        Err(e) if gpu_required() => panic!("GAZELIGHT_REQUIRE_GPU=1 but no GPU device: {e}"),
        Err(e) => {
            println!("SKIP gpu_fft: no GPU device ({e})");
            return;
        }
    };
    let timestamps = Timestamps::new(&ctx);
    println!(
        "gpu_fft on {} ({})",
        ctx.describe(),
        if timestamps.is_some() {
            "GPU timestamps"
        } else {
            "wall clock + poll(wait)"
        }
    );
    let mut group = c.benchmark_group("gpu_fft_forward_rgb");
    group.sample_size(10);
    for n in [512u32, 1024] {
        let fft = GpuFft2d::new(&ctx, n, n, 3).expect("FFT plan");
        let input: Vec<[f32; 2]> = (0..fft.len())
            .map(|i| [((i * 7919) % 1000) as f32 / 1000.0, 0.0])
            .collect();
        fft.upload(&ctx, &input).expect("upload");
        group.bench_function(format!("{n}x{n}x3"), |b| {
            b.iter_custom(|iters| time_fft(&ctx, &fft, timestamps.as_ref(), iters));
        });
    }
    group.finish();
}

criterion_group!(benches, bench_fft);
criterion_main!(benches);
