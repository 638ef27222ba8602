//! Criterion benchmarks of the CPU frame pipeline at the default display
//! size (720×800 per eye, half the Vive Pro) and at the Vive Pro's
//! 1440×1600 per eye: the whole frame on a night view (scotopic, so the
//! acuity blur runs) and a day view (the fused tone + colour + encode
//! pass), with the PSF cached and with a PSF rebuild, and per-stage medians
//! from the pipeline's own stage timers.
//!
//! Run: `cargo bench -p gazelight-vision --bench frame` (filter with e.g.
//! `-- 720x800`).

use std::hint::black_box;
use std::path::Path;

use criterion::{Criterion, criterion_group, criterion_main};
use gazelight_vision::RgbImage;
use gazelight_vision::glare::{GlareConvolver, GlareWindow};
use gazelight_vision::pipeline::{
    DisplayFrame, FrameInput, FramePipeline, PipelineConfig, StageTimings,
};
use gazelight_vision::psf::{PsfParams, build_kernel};
use gazelight_vision::scene::{LuminanceScale, PanoramaView, Scene, ViewParams};

fn view_of(name: &str, yaw_deg: f64, width: usize, height: usize) -> (RgbImage, ViewParams) {
    let path = Path::new(env!("CARGO_MANIFEST_DIR"))
        .join("../../../shared/data/hdr/blender-world")
        .join(name);
    let scene = Scene::load(&path, LuminanceScale::default()).expect("shared panorama");
    let view = ViewParams {
        yaw_deg,
        pitch_deg: -6.0,
        hfov_deg: 104.0,
        width,
        height,
    };
    let mut img = RgbImage::new(width, height);
    PanoramaView::new(view)
        .expect("view")
        .render(&scene.image, &mut img);
    (img, view)
}

fn bench_size(c: &mut Criterion, scene: &str, yaw_deg: f64, w: usize, h: usize) {
    let (img, view) = view_of(scene, yaw_deg, w, h);
    let mut pipeline =
        FramePipeline::new(PipelineConfig::default(), w, h, view.deg_per_px()).expect("pipeline");
    let mut out = DisplayFrame::new(w, h);
    let mut input = FrameInput {
        gaze_uv: [0.5, 0.45],
        pupil_mm: 4.0,
        dt_secs: 1.0 / 90.0,
    };
    pipeline.process(&img, &input, &mut out).expect("frame");
    let label = scene.trim_end_matches(".exr");

    let mut group = c.benchmark_group(format!("cpu_frame_{w}x{h}"));
    group.sample_size(20);
    group.bench_function(format!("{label}_psf_cached"), |b| {
        b.iter(|| {
            let s = pipeline
                .process(black_box(&img), &input, &mut out)
                .expect("frame");
            black_box(s)
        })
    });
    let mut flip = false;
    group.bench_function(format!("{label}_psf_rebuild"), |b| {
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
    // "median (min)": the minimum is the steadiest figure on a shared,
    // loaded machine.
    let median = |f: fn(&StageTimings) -> f64, runs: &mut Vec<StageTimings>| {
        runs.sort_by(|a, b| f(a).total_cmp(&f(b)));
        format!("{:.2} ({:.2})", f(&runs[runs.len() / 2]), f(&runs[0]))
    };
    eprintln!("per-stage medians, {label} view {w}x{h}, PSF cached, ms, median (min):");
    eprintln!(
        "  pooling (copy + luminance + pool) {}",
        median(|t| t.pooling_ms, &mut runs)
    );
    eprintln!(
        "  temporal                          {}",
        median(|t| t.temporal_ms, &mut runs)
    );
    eprintln!(
        "  glare (FFT window)                {}",
        median(|t| t.glare_ms, &mut runs)
    );
    eprintln!(
        "  acuity blur                       {}",
        median(|t| t.acuity_ms, &mut runs)
    );
    eprintln!(
        "  tone + colour + encode            {}",
        median(|t| t.tone_colour_encode_ms, &mut runs)
    );
    eprintln!(
        "  total                             {}",
        median(|t| t.total_ms, &mut runs)
    );
}

/// The glare stage alone at 720×800 (default kernel: ±20° field with the
/// CIE 146 wide field, full weight 12° around the gaze), against an f32
/// RGBA copy of the same frame measured in the same run (the floor).
fn glare_stage(c: &mut Criterion) {
    let (w, h) = (720, 800);
    let (img, view) = view_of("night.exr", -78.4, w, h);
    let params = PsfParams {
        ppd: 1.0 / view.deg_per_px(),
        ..PsfParams::default()
    };
    let kernel = build_kernel(&params).expect("kernel");
    let mut conv = GlareConvolver::new(&kernel, GlareWindow::default()).expect("convolver");
    eprintln!(
        "glare stage {w}x{h} at {:.2} ppd: kernel {} px, fine window {} px (radius {} px), coarse window {} blocks of {} px",
        params.ppd,
        kernel.size,
        conv.fine_window_px(),
        conv.fine_radius_px(),
        conv.coarse_window_blocks(),
        conv.block_px()
    );
    let mut work = img.clone();
    let src: Vec<[f32; 4]> = img.pixels.iter().map(|p| [p[0], p[1], p[2], 1.0]).collect();
    let mut dst = vec![[0.0f32; 4]; w * h];
    let mut group = c.benchmark_group(format!("glare_{w}x{h}"));
    group.sample_size(30);
    group.bench_function("glare_stage", |b| {
        b.iter(|| {
            // Energy conserving: applying it again and again keeps the
            // frame finite, and the FFT work does not depend on the values.
            conv.apply(black_box(&mut work), [0.5 * w as f64, 0.45 * h as f64]);
            black_box(&work);
        })
    });
    group.bench_function("f32_rgba_copy_floor", |b| {
        b.iter(|| {
            dst.copy_from_slice(black_box(&src));
            black_box(&dst);
        })
    });
    group.finish();
}

fn frame(c: &mut Criterion) {
    // GAZELIGHT_BENCH_SIZES=720x800 restricts the sizes (the per-stage
    // figures are not covered by criterion's filter).
    let only = std::env::var("GAZELIGHT_BENCH_SIZES").ok();
    for (w, h) in [(720, 800), (1440, 1600)] {
        if let Some(only) = &only
            && !only.split(',').any(|s| s == format!("{w}x{h}"))
        {
            continue;
        }
        // Night: scotopic, so the acuity blur runs.
        bench_size(c, "night.exr", -78.4, w, h);
        // Day: no blur, the fused tone + colour + encode pass.
        bench_size(c, "city.exr", 40.0, w, h);
    }
}

criterion_group!(benches, glare_stage, frame);
criterion_main!(benches);
