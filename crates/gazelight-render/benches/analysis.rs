#![allow(clippy::unwrap_used, clippy::expect_used)] // bench code may panic on a failed setup
//! Analysis at study speed (issue 47): a replay's numbers without the
//! image pipeline ([`gazelight_render::analysis::AnalysisStep`]) against
//! today's path that renders every frame
//! ([`gazelight_render::frame::FrameStep`] over the CPU `FramePipeline`),
//! on the same input: the shipped Neon recording (`eye/neon-demo` of the
//! shared data), stereo, 720×800 per eye, the embedded night panorama in
//! the default view, 90 frames per second of recording, the default
//! models, each view's pupil light response and the timeline rows
//! formatted (into a sink), all on **one core** (a one-thread rayon pool).
//!
//! Three loops, interleaved round by round:
//!
//! * **feed** (the floor both paths pay): the recording read and filtered
//!   at each frame's time, nothing else;
//! * **numbers**: the whole recording through `AnalysisStep`;
//! * **full**: the first `GAZELIGHT_BENCH_FULL_FRAMES` frames (default 90,
//!   one second; the whole recording takes minutes) through `FrameStep`,
//!   and the numbers path over the same frames for the ratio.
//!
//! Prints the medians, frames per second, the ratio, and what one hour
//! of 90 Hz binocular recording costs on one core at that rate.
//!
//! Run: `cargo bench -p gazelight-render --bench analysis`
//! (`GAZELIGHT_BENCH_ROUNDS`, default 7).

use std::hint::black_box;
use std::path::Path;
use std::time::Instant;

use gazelight_render::analysis::AnalysisStep;
use gazelight_render::demo;
use gazelight_render::feed::{ImporterSamples, SampleFeed, scan};
use gazelight_render::frame::{FrameStep, cpu_pipelines};
use gazelight_render::pupil_light::{PupilLight, PupilLightOptions, PupilLightPlan};
use gazelight_render::timeline::TimelineWriter;
use gazelight_tracker::filter::{FilterChain, FilterConfig};
use gazelight_tracker::profile::PupilCalibration;
use gazelight_vision::RgbImage;
use gazelight_vision::pipeline::PipelineConfig;
use gazelight_vision::scene::{LuminanceScale, PanoramaView, Scene, ViewParams};

const FPS: f64 = 90.0;

struct Input {
    rec: std::path::PathBuf,
    view: ViewParams,
    view_img: RgbImage,
    config: PipelineConfig,
    t_first: f64,
    t_last: f64,
}

fn feed(rec: &Path) -> SampleFeed<ImporterSamples> {
    let chain = FilterChain::new(FilterConfig::default(), PupilCalibration::identity()).unwrap();
    SampleFeed::new(ImporterSamples::open(rec).unwrap(), chain)
}

fn pupil_light(input: &Input) -> PupilLight {
    let views = gazelight_render::frame::views(true);
    PupilLightPlan::new(
        views,
        &input.view_img,
        &input.view,
        &input.config,
        &PupilLightOptions {
            age_years: input.config.glare.psf.age_years,
            calibration: None,
            black_cd_m2: None,
            white_cd_m2: None,
            pupil_fit: None,
        },
        input.t_last - input.t_first,
    )
    .unwrap()
    .start()
    .unwrap()
}

fn writer() -> TimelineWriter {
    let path = std::env::temp_dir().join(format!(
        "gazelight-bench-timeline-{}.csv",
        std::process::id()
    ));
    TimelineWriter::create(&path, &["_left", "_right"], true, false).unwrap()
}

/// The floor: the samples read and filtered at each frame's time.
fn run_feed(input: &Input, frames: usize) -> f64 {
    let started = Instant::now();
    let mut f = feed(&input.rec);
    for i in 0..frames {
        black_box(f.state(input.t_first + i as f64 / FPS, Some(1.0)));
    }
    started.elapsed().as_secs_f64()
}

/// The numbers path: (set-up: the feed opened, the block plane, the
/// light plan; the whole run, set-up included), s.
fn run_numbers(input: &Input, frames: usize) -> (f64, f64) {
    let started = Instant::now();
    let mut f = feed(&input.rec);
    let mut plr = pupil_light(input);
    let mut out = writer();
    let mut step = AnalysisStep::new(
        true,
        &input.config,
        &input.view,
        &input.view_img,
        input.t_first,
        FPS,
    )
    .unwrap();
    let setup = started.elapsed().as_secs_f64();
    for _ in 0..frames {
        let mut s = step.step(&mut f).unwrap();
        plr.apply(s.t_secs - input.t_first, &s.state, &s.inputs, &mut s.rows);
        out.push(&s.rows).unwrap();
    }
    (setup, started.elapsed().as_secs_f64())
}

/// Today's path: every frame rendered (pipelines built outside the
/// timing, as a long replay amortises them).
fn run_full(input: &Input, frames: usize) -> f64 {
    let pipelines = cpu_pipelines(&input.config, &input.view, true).unwrap();
    let mut step = FrameStep::new(
        pipelines,
        true,
        &input.config,
        &input.view,
        input.t_first,
        FPS,
        false,
    )
    .unwrap();
    let mut f = feed(&input.rec);
    let mut plr = pupil_light(input);
    let mut out = writer();
    let started = Instant::now();
    for _ in 0..frames {
        let mut s = step.step(&mut f, &input.view_img).unwrap();
        plr.apply(s.t_secs - input.t_first, &s.state, &s.inputs, &mut s.rows);
        out.push(&s.rows).unwrap();
        black_box(step.display());
    }
    started.elapsed().as_secs_f64()
}

fn median(v: &mut [f64]) -> f64 {
    v.sort_by(f64::total_cmp);
    v[v.len() / 2]
}

fn env_usize(name: &str, default: usize) -> usize {
    std::env::var(name)
        .ok()
        .and_then(|v| v.parse().ok())
        .unwrap_or(default)
}

fn main() {
    let rec = gazelight_test_support::data_path("eye/neon-demo");
    let scene = Scene::from_bytes(
        demo::NIGHT_EXR,
        demo::name_path(),
        LuminanceScale::default(),
    )
    .unwrap();
    let view = demo::default_view(720, 800);
    let mut view_img = RgbImage::new(view.width, view.height);
    PanoramaView::new(view)
        .unwrap()
        .render_scene(&scene, &mut view_img);
    let found = scan(&rec, false).unwrap();
    let input = Input {
        rec,
        view,
        view_img,
        config: PipelineConfig::default(),
        t_first: found.t_first,
        t_last: found.t_last,
    };
    let all = ((input.t_last - input.t_first) * FPS).floor() as usize + 1;
    let full_frames = env_usize("GAZELIGHT_BENCH_FULL_FRAMES", 90).min(all);
    let rounds = env_usize("GAZELIGHT_BENCH_ROUNDS", 7).max(1);
    let pool = rayon::ThreadPoolBuilder::new()
        .num_threads(1)
        .build()
        .unwrap();
    println!(
        "neon-demo, stereo 720x800, {FPS} fps: {all} frames ({:.2} s of recording); \
         full path over the first {full_frames}; {rounds} rounds, one rayon thread",
        input.t_last - input.t_first
    );
    let (mut floor, mut setup, mut numbers, mut numbers_part, mut full) =
        (Vec::new(), Vec::new(), Vec::new(), Vec::new(), Vec::new());
    pool.install(|| {
        // One warm-up of each (page cache, first-touch allocations).
        run_numbers(&input, all);
        run_full(&input, full_frames.min(5));
        for r in 0..rounds {
            floor.push(run_feed(&input, all));
            let (s, n) = run_numbers(&input, all);
            setup.push(s);
            numbers.push(n);
            let (s, n) = run_numbers(&input, full_frames);
            // The loops alone: the full path's pipelines are built outside
            // its timing too.
            numbers_part.push(n - s);
            full.push(run_full(&input, full_frames));
            println!(
                "round {r}: feed {:.1} ms, numbers {:.1} ms of which set-up {:.1} ms ({all} \
                 frames); numbers {:.2} ms, full {:.1} ms ({full_frames} frames, loops only)",
                floor[r] * 1e3,
                numbers[r] * 1e3,
                setup[r] * 1e3,
                numbers_part[r] * 1e3,
                full[r] * 1e3
            );
        }
    });
    let (floor, setup, numbers, numbers_part, full) = (
        median(&mut floor),
        median(&mut setup),
        median(&mut numbers),
        median(&mut numbers_part),
        median(&mut full),
    );
    let per = |secs: f64, n: usize| secs / n as f64;
    let numbers_fps = 1.0 / per(numbers, all);
    let full_fps = 1.0 / per(full, full_frames);
    println!(
        "medians: feed floor {:.1} µs/frame; numbers {:.1} µs/frame with its set-up \
         ({:.1} ms) spread over the {all} frames = {numbers_fps:.0} frames/s ({:.1}x the feed \
         floor), {:.1} µs/frame without it; full {:.2} ms/frame = {full_fps:.1} frames/s",
        per(floor, all) * 1e6,
        per(numbers, all) * 1e6,
        setup * 1e3,
        numbers / floor,
        per(numbers - setup, all) * 1e6,
        per(full, full_frames) * 1e3
    );
    println!(
        "same {full_frames} frames, loops only: numbers {:.1} µs/frame vs full {:.2} ms/frame: \
         {:.0}x",
        per(numbers_part, full_frames) * 1e6,
        per(full, full_frames) * 1e3,
        full / numbers_part
    );
    let hour_frames = 3600.0 * FPS;
    // The hour at the rate measured with the set-up spread over this
    // recording's 9 s (an hour spreads it 400 times thinner).
    println!(
        "one hour of 90 Hz binocular recording ({hour_frames:.0} stereo frames) on one core: \
         numbers {:.2} min, full {:.0} min",
        hour_frames / numbers_fps / 60.0,
        hour_frames / full_fps / 60.0
    );
}
