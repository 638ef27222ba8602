#![allow(clippy::unwrap_used, clippy::expect_used)] // test and bench code may panic on a failed setup
//! The glare numbers along a gaze trace (`render`/`replay
//! --glare-numbers`: `SceneGlare::at_gaze` per frame) allocate nothing once
//! the scene's buffers have grown to the trace's largest gaze: a counting
//! global allocator watches `SceneGlare::at_gaze_into` over a second pass
//! of a gaze trace across a real panorama view with a lamp bright enough
//! for evalglare's peak extraction. (A binary of its own: the counter is
//! global, and another test running beside it would be counted.)

use std::alloc::{GlobalAlloc, Layout, System};
use std::sync::atomic::{AtomicBool, AtomicUsize, Ordering};

use gazelight_vision::RgbImage;
use gazelight_vision::scene::projection::{DVec3, ProjectionKind, SceneProjection};
use gazelight_vision::scene::{LuminanceScale, PanoramaView, Scene, ViewParams};
use gazelight_vision::scene_glare::{GlareOptions, SceneGlare};

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
fn glare_numbers_along_a_gaze_trace_do_not_allocate() {
    let path = gazelight_test_support::data_path("hdr/blender-world/night.exr");
    let scene = Scene::load(&path, LuminanceScale::default()).expect("night.exr");
    // The default demo's view, towards the street lamp.
    let view = ViewParams {
        yaw_deg: -78.4,
        pitch_deg: -6.0,
        hfov_deg: 90.0,
        width: 240,
        height: 200,
    };
    let mut img = RgbImage::new(view.width, view.height);
    PanoramaView::new(view)
        .expect("view")
        .render(&scene.image, &mut img);
    // Two 3 × 3 px lamps of 10⁵ cd/m² (above evalglare's 50 000 cd/m²
    // peak level) on 20 000 cd/m² diffusers: sources split by peak
    // extraction, whatever the panorama's own lamps are.
    for (cx, cy) in [(60usize, 50usize), (180, 120)] {
        for y in cy - 4..=cy + 4 {
            for x in cx - 4..=cx + 4 {
                let l = if x.abs_diff(cx) <= 1 && y.abs_diff(cy) <= 1 {
                    1e5
                } else {
                    2e4
                };
                *img.get_mut(x, y) = [l; 3];
            }
        }
    }
    let projection = SceneProjection::with_square_pixels(
        ProjectionKind::Perspective,
        view.hfov_deg,
        view.width,
        view.height,
    )
    .expect("projection");
    let glare = SceneGlare::new(&img, projection);
    let opts = GlareOptions::default();
    // A trace across the view (with one gaze off it, where only part of
    // the image is in front of the eye).
    let trace: Vec<DVec3> = (0..24)
        .map(|i| {
            let u = (i % 8) as f64 / 8.0 * 1.3 - 0.15;
            let v = (i / 8) as f64 / 3.0 + 0.1;
            let px = [u * view.width as f64, v * view.height as f64];
            glare
                .projection()
                .direction_any(px)
                .expect("a perspective maps every point")
        })
        .collect();
    let mut out = glare.at_gaze(trace[0], &opts);
    // First pass: the buffers grow; every gaze's numbers are at_gaze's.
    let mut peaks = 0;
    for &g in &trace {
        glare.at_gaze_into(g, &opts, &mut out);
        assert_eq!(out, glare.at_gaze(g, &opts));
        peaks += out.sources.iter().filter(|s| s.peak).count();
    }
    assert!(peaks > 0, "no peak-extracted source along the trace");
    ALLOCS.store(0, Ordering::SeqCst);
    COUNTING.store(true, Ordering::SeqCst);
    let mut veil = 0.0;
    for &g in &trace {
        glare.at_gaze_into(g, &opts, &mut out);
        veil += out.veil_cie146_cd_m2 + out.indices.dgp;
    }
    COUNTING.store(false, Ordering::SeqCst);
    let n = ALLOCS.load(Ordering::SeqCst);
    assert!(veil > 0.0);
    assert_eq!(n, 0, "{n} heap allocations in {} gazes", trace.len());
}
