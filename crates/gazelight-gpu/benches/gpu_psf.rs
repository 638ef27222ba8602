#![allow(clippy::unwrap_used, clippy::expect_used)] // test and bench code may panic on a failed setup
//! Glare kernel rebuild of [`GpuPsfBuilder`] at the default parameters for
//! a pupil alternating between 3 and 6 mm, built on the GPU (see
//! `gazelight_gpu::psf`): the figure is the wall time of recording the
//! build, submit and `device.poll(wait)`.
//! (`cargo bench -p gazelight-gpu --bench gpu_psf -- --test`).

use std::time::{Duration, Instant};

use criterion::{Criterion, criterion_group, criterion_main};
use gazelight_gpu::testing::gpu_required;
use gazelight_gpu::{ContextOptions, GpuContext, GpuPsfBuilder};
use gazelight_vision::psf::PsfParams;

/// One rebuild + upload, waited for; its wall time.
fn rebuild_once(ctx: &GpuContext, psf: &mut GpuPsfBuilder, pupil_mm: f64) -> Duration {
    let start = Instant::now();
    let mut encoder = ctx.device().create_command_encoder(&Default::default());
    let _ = psf.encode_rebuild(&mut encoder, pupil_mm);
    ctx.queue().submit([encoder.finish()]);
    ctx.wait_idle().expect("device poll");
    start.elapsed()
}

fn bench_psf(c: &mut Criterion) {
    let ctx = match GpuContext::new(&ContextOptions::default()) {
        Ok(ctx) => ctx,
        Err(e) if gpu_required() => panic!("GAZELIGHT_REQUIRE_GPU=1 but no GPU device: {e}"),
        Err(e) => {
            println!("SKIP gpu_psf: no GPU device ({e})");
            return;
        }
    };
    println!(
        "gpu_psf on {} (wall clock, GPU build: record + submit + wait)",
        ctx.describe()
    );
    let params = PsfParams::default();
    let mut psf = GpuPsfBuilder::new(&ctx, &params).expect("GPU PSF builder");
    let mut group = c.benchmark_group("gpu_psf_rebuild");
    group.sample_size(10);
    group.bench_function("default_gpu_built", |b| {
        b.iter_custom(|iters| {
            let mut total = Duration::ZERO;
            for i in 0..iters {
                let pupil_mm = if i % 2 == 0 { 3.0 } else { 6.0 };
                total += rebuild_once(&ctx, &mut psf, pupil_mm);
            }
            total
        });
    });
    group.finish();
}

criterion_group!(benches, bench_psf);
criterion_main!(benches);
