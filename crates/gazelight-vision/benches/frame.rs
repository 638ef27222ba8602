//! Criterion benchmarks of the CPU frame pipeline at the Vive Pro's
//! 1440×1600 per eye: per stage (from the pipeline's own stage timers) and
//! the whole frame, with the PSF cached and with a PSF rebuild.
//!
//! Run: `cargo bench -p gazelight-vision --bench frame`.

use std::hint::black_box;
use std::path::Path;

use criterion::{Criterion, criterion_group, criterion_main};
use gazelight_vision::RgbImage;
use gazelight_vision::pipeline::{
    DisplayFrame, FrameInput, FramePipeline, PipelineConfig, StageTimings,
};
use gazelight_vision::scene::{LuminanceScale, PanoramaView, Scene, ViewParams};

const W: usize = 1440;
const H: usize = 1600;

fn view_of(name: &str, yaw_deg: f64) -> (RgbImage, ViewParams) {
    let path = Path::new(env!("CARGO_MANIFEST_DIR"))
        .join("../../../shared/data/hdr/blender-world")
        .join(name);
    let scene = Scene::load(&path, LuminanceScale::default()).expect("shared panorama");
    let view = ViewParams {
        yaw_deg,
        pitch_deg: -6.0,
        hfov_deg: 104.0,
        width: W,
        height: H,
    };
    let mut img = RgbImage::new(W, H);
    PanoramaView::new(view)
        .expect("view")
        .render(&scene.image, &mut img);
    (img, view)
}

fn frame(c: &mut Criterion) {
    let (img, view) = view_of("night.exr", -78.4);
    let mut pipeline =
        FramePipeline::new(PipelineConfig::default(), W, H, view.deg_per_px()).expect("pipeline");
    let mut out = DisplayFrame::new(W, H);
    let mut input = FrameInput {
        gaze_uv: [0.5, 0.45],
        pupil_mm: 4.0,
        dt_secs: 1.0 / 90.0,
    };
    pipeline.process(&img, &input, &mut out).expect("frame");

    let mut group = c.benchmark_group("cpu_frame_1440x1600");
    group.sample_size(20);
    // Night: scotopic, so the acuity blur runs.
    group.bench_function("one_eye_psf_cached", |b| {
        b.iter(|| {
            let s = pipeline
                .process(black_box(&img), &input, &mut out)
                .expect("frame");
            black_box(s)
        })
    });
    let mut flip = false;
    group.bench_function("one_eye_psf_rebuild", |b| {
        b.iter(|| {
            flip = !flip;
            input.pupil_mm = if flip { 3.0 } else { 6.0 };
            let s = pipeline
                .process(black_box(&img), &input, &mut out)
                .expect("frame");
            black_box(s)
        })
    });
    group.finish();

    // Per-stage medians from the pipeline's own timers, PSF cached.
    input.pupil_mm = 6.0;
    let mut runs: Vec<StageTimings> = (0..30)
        .map(|_| {
            pipeline
                .process(&img, &input, &mut out)
                .expect("frame")
                .timings
        })
        .collect();
    let median = |f: fn(&StageTimings) -> f64, runs: &mut Vec<StageTimings>| {
        runs.sort_by(|a, b| f(a).total_cmp(&f(b)));
        f(&runs[runs.len() / 2])
    };
    eprintln!("per-stage medians, night view 1440x1600, PSF cached (ms):");
    eprintln!(
        "  pooling (copy + luminance + pool) {:.2}",
        median(|t| t.pooling_ms, &mut runs)
    );
    eprintln!(
        "  temporal                          {:.4}",
        median(|t| t.temporal_ms, &mut runs)
    );
    eprintln!(
        "  glare (FFT window)                {:.2}",
        median(|t| t.glare_ms, &mut runs)
    );
    eprintln!(
        "  acuity blur                       {:.2}",
        median(|t| t.acuity_ms, &mut runs)
    );
    eprintln!(
        "  tone + colour + encode            {:.2}",
        median(|t| t.tone_colour_encode_ms, &mut runs)
    );
    eprintln!(
        "  total                             {:.2}",
        median(|t| t.total_ms, &mut runs)
    );
}

criterion_group!(benches, frame);
criterion_main!(benches);
