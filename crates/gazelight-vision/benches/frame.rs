#![allow(clippy::unwrap_used, clippy::expect_used)] // test and bench code may panic on a failed setup
//! Criterion benchmarks of the CPU frame pipeline, every stage on (pooling,
//! temporal adaptation, glare with the cached ±20° PSF, per-pixel acuity,
//! tone + colour + encoding), against the memory floor measured in the same
//! run: an f32 RGBA copy of the same frame(s) (`copy_from_slice` of
//! `w·h` `[f32; 4]`, one thread).
//!
//! * Views: the default demo's (`render`: night.exr towards the street
//!   lamp, 90° field, default luminance scale) with the gaze on the dark
//!   ground, adapted there (**night**: most pixels are below L\* = 1, so
//!   the acuity blur runs on them), and city.exr at the same field
//!   (**day**).
//! * Sizes: 720×800 (half the Vive Pro, the default) and 1440×1600 per eye.
//! * One eye (one pipeline) and two eyes (two pipelines, the views 3° apart
//!   in yaw, run side by side with `rayon::join` as the stereo loops of
//!   `render`, `replay` and `run` do); the two-eye floor copies both frames.
//! * `psf_rebuild`: one eye, a PSF rebuild every frame (pupil 3 ↔ 6 mm).
//!
//! After each group the bench prints medians of 31 interleaved samples of
//! the frame(s) and of the copy, their ratio, and the per-stage medians
//! from the pipeline's own timers.
//!
//! Run: `cargo bench -p gazelight-vision --bench frame` (filter with e.g.
//! `-- 720x800`; `GAZELIGHT_BENCH_SIZES=720x800` skips the other size's
//! setup and printed figures too).

use std::hint::black_box;
use std::time::Instant;

use criterion::{Criterion, criterion_group, criterion_main};
use gazelight_vision::RgbImage;
use gazelight_vision::acuity::AcuityModel;
use gazelight_vision::band::AcuityBlur;
use gazelight_vision::glare::{GlareConvolver, GlareWindow};
use gazelight_vision::pipeline::{
    DisplayFrame, FrameInput, FramePipeline, PipelineConfig, StageTimings,
};
use gazelight_vision::psf::{PsfParams, build_kernel};
use gazelight_vision::scene::{LuminanceScale, PanoramaView, Scene, ViewParams};

/// The default demo's view (`gazelight::demo::default_view`): towards the
/// lamp, 6° down, 90° field.
const DEMO_YAW_DEG: f64 = -78.4;
const DEMO_PITCH_DEG: f64 = -6.0;
const DEMO_HFOV_DEG: f64 = 90.0;

fn load(name: &str) -> Scene {
    let path = gazelight_test_support::data_path("hdr/blender-world").join(name);
    Scene::load(&path, LuminanceScale::default()).expect("shared panorama")
}

fn view_of(scene: &Scene, yaw_deg: f64, width: usize, height: usize) -> (RgbImage, ViewParams) {
    let view = ViewParams {
        yaw_deg,
        pitch_deg: DEMO_PITCH_DEG,
        hfov_deg: DEMO_HFOV_DEG,
        width,
        height,
    };
    let mut img = RgbImage::new(width, height);
    PanoramaView::new(view)
        .expect("view")
        .render(&scene.image, &mut img);
    (img, view)
}

/// One eye: its view, pipeline and output.
struct Eye {
    img: RgbImage,
    pipeline: FramePipeline,
    out: DisplayFrame,
}

impl Eye {
    fn frame(&mut self, input: &FrameInput) -> StageTimings {
        self.pipeline
            .process(black_box(&self.img), input, &mut self.out)
            .expect("frame")
            .timings
    }
}

/// Both eyes of a stereo frame, as the stereo loops run them: the two
/// pipelines side by side on the rayon pool (`rayon::join`), each one's own
/// parallel passes sharing the same threads.
fn both(eyes: &mut [Eye], input: &FrameInput) -> [StageTimings; 2] {
    let [left, right] = eyes else {
        panic!("two eyes")
    };
    let (a, b) = rayon::join(|| left.frame(input), || right.frame(input));
    [a, b]
}

fn median(v: &mut [f64]) -> f64 {
    v.sort_by(f64::total_cmp);
    v[v.len() / 2]
}

fn ms_since(t: Instant) -> f64 {
    t.elapsed().as_secs_f64() * 1e3
}

#[allow(clippy::too_many_arguments)]
fn bench_view(
    c: &mut Criterion,
    scene: &Scene,
    label: &str,
    yaw_deg: f64,
    gaze_uv: [f32; 2],
    w: usize,
    h: usize,
) {
    let input = FrameInput {
        gaze_uv,
        pupil_mm: 4.0,
        dt_secs: 1.0 / 90.0,
    };
    // Left and right eye 3° apart.
    let mut eyes: Vec<Eye> = [yaw_deg - 1.5, yaw_deg + 1.5]
        .into_iter()
        .map(|yaw| {
            let (img, view) = view_of(scene, yaw, w, h);
            let pipeline = FramePipeline::new(PipelineConfig::default(), w, h, view.deg_per_px())
                .expect("pipeline");
            Eye {
                img,
                pipeline,
                out: DisplayFrame::new(w, h),
            }
        })
        .collect();
    let dpp = eyes[0].pipeline.deg_per_px();
    // What the night view holds: how many pixels the acuity stage blurs.
    let mut probe = eyes[0].img.clone();
    let blurred = AcuityBlur::new(&AcuityModel::default(), w, h, dpp).apply(&mut probe);
    // Adapt to the view at the gaze (the first frame starts adapted).
    let mut first = None;
    for eye in &mut eyes {
        let s = eye
            .pipeline
            .process(&eye.img, &input, &mut eye.out)
            .expect("frame");
        first.get_or_insert(s);
    }
    let first = first.expect("two eyes");
    eprintln!(
        "{label} {w}x{h}: {:.2} px/deg, adapted to {:.3} cd/m², acuity blurs {blurred} of {} px \
         (σ at the adaptation {:.2} px, largest tap radius {} px)",
        1.0 / dpp,
        first.adaptation_cd_m2,
        w * h,
        first.acuity_sigma_px,
        AcuityBlur::new(&AcuityModel::default(), 1, 1, dpp).max_radius(),
    );
    // The floor: an f32 RGBA copy of one frame (two for two eyes).
    let src: Vec<[f32; 4]> = eyes[0]
        .img
        .pixels
        .iter()
        .map(|p| [p[0], p[1], p[2], 1.0])
        .collect();
    let mut dst = vec![[0.0f32; 4]; w * h];
    let mut copy = |n: usize| {
        for _ in 0..n {
            dst.copy_from_slice(black_box(&src));
            black_box(&dst);
        }
    };

    let mut group = c.benchmark_group(format!("cpu_frame_{w}x{h}"));
    group.sample_size(20);
    group.bench_function(format!("{label}_one_eye"), |b| {
        b.iter(|| black_box(eyes[0].frame(&input)))
    });
    group.bench_function(format!("{label}_copy_floor_one_frame"), |b| {
        b.iter(|| copy(1))
    });
    group.bench_function(format!("{label}_two_eyes"), |b| {
        b.iter(|| black_box(both(&mut eyes, &input)))
    });
    group.bench_function(format!("{label}_copy_floor_two_frames"), |b| {
        b.iter(|| copy(2))
    });
    if label == "night" && w == 720 {
        let mut flip = false;
        let mut rebuild = input;
        group.bench_function(format!("{label}_one_eye_psf_rebuild"), |b| {
            b.iter(|| {
                flip = !flip;
                rebuild.pupil_mm = if flip { 3.0 } else { 6.0 };
                black_box(eyes[0].frame(&rebuild))
            })
        });
        // Back to the cached 4 mm kernel.
        eyes[0].frame(&input);
    }
    group.finish();

    // Interleaved samples: frame(s) and copy alternate, so load on the
    // shared machine hits both alike.
    let (mut one, mut two, mut floor1, mut floor2) = (vec![], vec![], vec![], vec![]);
    let mut stages: Vec<StageTimings> = vec![];
    for _ in 0..31 {
        let t = Instant::now();
        stages.push(eyes[0].frame(&input));
        one.push(ms_since(t));
        let t = Instant::now();
        copy(1);
        floor1.push(ms_since(t));
        let t = Instant::now();
        both(&mut eyes, &input);
        two.push(ms_since(t));
        let t = Instant::now();
        copy(2);
        floor2.push(ms_since(t));
    }
    let (one, two) = (median(&mut one), median(&mut two));
    let (floor1, floor2) = (median(&mut floor1), median(&mut floor2));
    eprintln!(
        "{label} {w}x{h} medians of 31 interleaved: one eye {one:.2} ms = {:.2}× copy floor \
         {floor1:.2} ms; two eyes {two:.2} ms = {:.2}× copy floor {floor2:.2} ms",
        one / floor1,
        two / floor2,
    );
    let stage = |f: fn(&StageTimings) -> f64| -> f64 {
        let mut v: Vec<f64> = stages.iter().map(f).collect();
        median(&mut v)
    };
    eprintln!(
        "  stages (one eye, ms): pass A + pooling {:.2}, temporal {:.2}, glare {:.2}, \
         acuity + tone + colour + encode (fused) {:.2}, total {:.2}",
        stage(|t| t.pooling_ms),
        stage(|t| t.temporal_ms),
        stage(|t| t.glare_ms),
        stage(|t| t.acuity_ms + t.tone_colour_encode_ms),
        stage(|t| t.total_ms),
    );
}

/// The glare stage alone at 720×800 and 1440×1600 (default kernel: ±20°
/// field with the CIE 146 wide field, full weight 12° around the gaze):
/// `apply` (prepare and blend every row) and `prepare` alone (the FFTs, what
/// the pipeline runs before its band pass blends the rows), against an f32
/// RGBA copy of the same frame measured in the same run (the floor).
fn glare_stage(c: &mut Criterion) {
    let only = std::env::var("GAZELIGHT_BENCH_SIZES").ok();
    let scene = load("night.exr");
    for (w, h) in [(720, 800), (1440, 1600)] {
        if only
            .as_ref()
            .is_some_and(|s| !s.contains(&format!("{w}x{h}")))
        {
            continue;
        }
        glare_at(c, &scene, w, h);
    }
}

fn glare_at(c: &mut Criterion, scene: &Scene, w: usize, h: usize) {
    let (img, view) = view_of(scene, DEMO_YAW_DEG, w, h);
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
    let gaze_px = [0.5 * w as f64, 0.45 * h as f64];
    let mut group = c.benchmark_group(format!("glare_{w}x{h}"));
    group.sample_size(30);
    group.bench_function("glare_stage", |b| {
        b.iter(|| {
            // Energy conserving: applying it again and again keeps the
            // frame finite, and the FFT work does not depend on the values.
            conv.apply(black_box(&mut work), gaze_px);
            black_box(&work);
        })
    });
    group.bench_function("glare_prepare", |b| {
        b.iter(|| {
            conv.prepare(black_box(&img), gaze_px);
            black_box(conv.rows_reached());
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
    let only = std::env::var("GAZELIGHT_BENCH_SIZES").ok();
    let night = load("night.exr");
    let city = load("city.exr");
    for (w, h) in [(720, 800), (1440, 1600)] {
        if let Some(only) = &only
            && !only.split(',').any(|s| s == format!("{w}x{h}"))
        {
            continue;
        }
        // Night: the demo's view, the gaze on the dark ground below the lamp.
        bench_view(c, &night, "night", DEMO_YAW_DEG, [0.5, 0.8], w, h);
        // Day: the city at the same field.
        bench_view(c, &city, "day", 40.0, [0.5, 0.45], w, h);
    }
}

/// The full-field stray light's cost (issue 46): the night 1440×1600 view,
/// one eye, every stage on, with the far field (the default) and without
/// (`glare.far_field = false`), measured side by side: criterion, then 41
/// interleaved samples of each and the ratio of their medians.
fn far_field_cost(c: &mut Criterion) {
    let (w, h) = (1440, 1600);
    if let Ok(only) = std::env::var("GAZELIGHT_BENCH_SIZES")
        && !only.split(',').any(|s| s == format!("{w}x{h}"))
    {
        return;
    }
    let night = load("night.exr");
    let (img, view) = view_of(&night, DEMO_YAW_DEG, w, h);
    let input = FrameInput {
        gaze_uv: [0.5, 0.8],
        pupil_mm: 4.0,
        dt_secs: 1.0 / 90.0,
    };
    let mut eyes: Vec<Eye> = [true, false]
        .into_iter()
        .map(|far| {
            let mut config = PipelineConfig::default();
            config.glare.far_field = far;
            let mut pipeline =
                FramePipeline::new(config, w, h, view.deg_per_px()).expect("pipeline");
            let mut out = DisplayFrame::new(w, h);
            pipeline.process(&img, &input, &mut out).expect("frame");
            Eye {
                img: img.clone(),
                pipeline,
                out,
            }
        })
        .collect();
    let mut group = c.benchmark_group(format!("far_field_{w}x{h}"));
    group.sample_size(20);
    group.bench_function("night_one_eye_far_on", |b| {
        b.iter(|| black_box(eyes[0].frame(&input)))
    });
    group.bench_function("night_one_eye_far_off", |b| {
        b.iter(|| black_box(eyes[1].frame(&input)))
    });
    group.finish();
    let (mut on, mut off, mut glare_on, mut glare_off) = (vec![], vec![], vec![], vec![]);
    for _ in 0..41 {
        let t = Instant::now();
        let s = eyes[0].frame(&input);
        on.push(ms_since(t));
        glare_on.push(s.glare_ms);
        let t = Instant::now();
        let s = eyes[1].frame(&input);
        off.push(ms_since(t));
        glare_off.push(s.glare_ms);
    }
    let (m_on, m_off) = (median(&mut on), median(&mut off));
    eprintln!(
        "far field, night {w}x{h} one eye, interleaved medians: on {m_on:.2} ms, off {m_off:.2} ms \
         (×{:.3}); glare stage {:.2} / {:.2} ms",
        m_on / m_off,
        median(&mut glare_on),
        median(&mut glare_off)
    );
}

criterion_group!(benches, frame, glare_stage, far_field_cost);
criterion_main!(benches);
