#![allow(clippy::unwrap_used, clippy::expect_used)] // test and bench code may panic on a failed setup
//! The frame loop allocates nothing in steady state: a counting global
//! allocator watches `FramePipeline::process` over many frames, with the
//! gaze moving and the PSF cached, on a real panorama view.

use std::alloc::{GlobalAlloc, Layout, System};
use std::sync::atomic::{AtomicBool, AtomicUsize, Ordering};

use gazelight_vision::RgbImage;
use gazelight_vision::pipeline::{DisplayFrame, FrameInput, FramePipeline, PipelineConfig};
use gazelight_vision::scene::{LuminanceScale, PanoramaView, Scene, ViewParams};

struct Counting;

static COUNTING: AtomicBool = AtomicBool::new(false);
static ALLOCS: AtomicUsize = AtomicUsize::new(0);

// SAFETY: every call goes to the system allocator with the caller's
// arguments; counting allocates nothing.
unsafe impl GlobalAlloc for Counting {
    unsafe fn alloc(&self, layout: Layout) -> *mut u8 {
        if COUNTING.load(Ordering::Relaxed) {
            ALLOCS.fetch_add(1, Ordering::Relaxed);
        }
        // SAFETY: the caller's layout, as `GlobalAlloc::alloc` asks.
        unsafe { System.alloc(layout) }
    }
    unsafe fn dealloc(&self, ptr: *mut u8, layout: Layout) {
        // SAFETY: `ptr` came from `System` (every allocation does).
        unsafe { System.dealloc(ptr, layout) }
    }
    unsafe fn realloc(&self, ptr: *mut u8, layout: Layout, new_size: usize) -> *mut u8 {
        if COUNTING.load(Ordering::Relaxed) {
            ALLOCS.fetch_add(1, Ordering::Relaxed);
        }
        // SAFETY: `ptr` came from `System` with `layout`.
        unsafe { System.realloc(ptr, layout, new_size) }
    }
}

#[global_allocator]
static GLOBAL: Counting = Counting;

#[test]
fn steady_state_frames_do_not_allocate() {
    // Run everything on this thread: rayon's pool would allocate its own
    // bookkeeping on first use, which is start-up, not steady state.
    let pool = rayon::ThreadPoolBuilder::new()
        .num_threads(2)
        .build()
        .expect("thread pool");
    let path = gazelight_test_support::data_path("hdr/blender-world/night.exr");
    let scene = Scene::load(&path, LuminanceScale::default()).expect("night.exr");
    let view = ViewParams {
        yaw_deg: -78.4,
        pitch_deg: -6.0,
        hfov_deg: 90.0,
        width: 320,
        height: 256,
    };
    let mut frame = RgbImage::new(view.width, view.height);
    PanoramaView::new(view)
        .expect("view")
        .render(&scene.image, &mut frame);
    // The default glare: ±20° kernel, fine core + coarse wide field, and
    // the full-field stray light (issue 46) on the view's rectilinear
    // geometry, set every frame as the live loop does (its grid is rebuilt
    // only when the geometry changes).
    let config = PipelineConfig::default();
    assert!(config.glare.far_field, "the far field is on by default");
    let mut pipeline =
        FramePipeline::new(config, view.width, view.height, view.deg_per_px()).expect("pipeline");
    let tans = PanoramaView::new(view).expect("view").frustum_tans();
    pipeline.set_view_frustum(tans).expect("frustum");
    let mut out = DisplayFrame::new(view.width, view.height);
    pool.install(|| {
        let input = |i: usize| FrameInput {
            gaze_uv: [0.2 + 0.6 * (i % 10) as f32 / 10.0, 0.5],
            pupil_mm: 5.0 + 0.01 * (i % 3) as f32, // below the rebuild threshold
            dt_secs: 1.0 / 90.0,
        };
        // Warm-up: first frame, first PSF rebuild to 5 mm, rayon start-up.
        for i in 0..5 {
            pipeline
                .process(&frame, &input(i), &mut out)
                .expect("frame");
        }
        ALLOCS.store(0, Ordering::SeqCst);
        COUNTING.store(true, Ordering::SeqCst);
        for i in 0..60 {
            pipeline.set_view_frustum(tans).expect("frustum");
            pipeline
                .process(&frame, &input(i), &mut out)
                .expect("frame");
        }
        COUNTING.store(false, Ordering::SeqCst);
    });
    let n = ALLOCS.load(Ordering::SeqCst);
    assert_eq!(n, 0, "{n} heap allocations in 60 steady-state frames");
}
