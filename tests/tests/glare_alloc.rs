#![allow(clippy::unwrap_used, clippy::expect_used)] // test and bench code may panic on a failed setup
//! The glare numbers along a gaze trace (`render`/`replay
//! --glare-numbers`: `SceneGlare::at_gaze` per frame) allocate nothing once
//! the scene's buffers have grown to the trace's largest gaze: a counting
//! global allocator watches `SceneGlare::at_gaze_into` over a second pass
//! of a gaze trace across a real panorama view with a lamp bright enough
//! for evalglare's peak extraction. (A binary of its own: the counter is
//! global, and another test running beside it would be counted.)

use std::alloc::{GlobalAlloc, Layout, System};
use std::cell::Cell;

use gazelight_render::gaze_glare::ViewGlare;
use gazelight_vision::RgbImage;
use gazelight_vision::scene::projection::{DVec3, ProjectionKind, SceneProjection};
use gazelight_vision::scene::{LuminanceScale, PanoramaView, Scene, ViewParams};
use gazelight_vision::scene_glare::{GlareOptions, SceneGlare};

struct Counting;

thread_local! {
    /// Whether this thread's allocations are counted, and how many were
    /// (per thread: the tests of this binary run side by side).
    static COUNTING: Cell<bool> = const { Cell::new(false) };
    static ALLOCS: Cell<usize> = const { Cell::new(0) };
}

fn count_one() {
    // `try_with`: a thread being torn down has no locals left to count in.
    let _ = COUNTING.try_with(|c| {
        if c.get() {
            let _ = ALLOCS.try_with(|n| n.set(n.get() + 1));
        }
    });
}

/// Runs `f` counting this thread's heap allocations; how many there were.
fn allocations_in(f: impl FnOnce()) -> usize {
    ALLOCS.with(|n| n.set(0));
    COUNTING.with(|c| c.set(true));
    f();
    COUNTING.with(|c| c.set(false));
    ALLOCS.with(|n| n.get())
}

// SAFETY: every call goes to the system allocator with the caller's
// arguments; counting allocates nothing.
unsafe impl GlobalAlloc for Counting {
    unsafe fn alloc(&self, layout: Layout) -> *mut u8 {
        count_one();
        // SAFETY: the caller's layout, as `GlobalAlloc::alloc` asks.
        unsafe { System.alloc(layout) }
    }
    unsafe fn dealloc(&self, ptr: *mut u8, layout: Layout) {
        // SAFETY: `ptr` came from `System` (every allocation does).
        unsafe { System.dealloc(ptr, layout) }
    }
    unsafe fn realloc(&self, ptr: *mut u8, layout: Layout, new_size: usize) -> *mut u8 {
        count_one();
        // SAFETY: `ptr` came from `System` with `layout`.
        unsafe { System.realloc(ptr, layout, new_size) }
    }
}

#[global_allocator]
static GLOBAL: Counting = Counting;

/// The default demo's view of the night panorama (towards the street
/// lamp) with two 3 × 3 px lamps of 10⁵ cd/m² (above evalglare's
/// 50 000 cd/m² peak level) on 20 000 cd/m² diffusers: sources split by
/// peak extraction, whatever the panorama's own lamps are.
fn night_view_with_two_lamps() -> (RgbImage, ViewParams) {
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
    (img, view)
}

#[test]
fn glare_numbers_along_a_gaze_trace_do_not_allocate() {
    let (img, view) = night_view_with_two_lamps();
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
    let mut veil = 0.0;
    let n = allocations_in(|| {
        for &g in &trace {
            glare.at_gaze_into(g, &opts, &mut out);
            veil += out.veil_cie146_cd_m2 + out.indices.dgp;
        }
    });
    assert!(veil > 0.0);
    assert_eq!(n, 0, "{n} heap allocations in {} gazes", trace.len());
}

/// `render`/`replay --glare-numbers`' per-frame call,
/// `gazelight_render::gaze_glare::ViewGlare::at`, on the same kind of view:
/// after a first pass, a second pass of the trace allocates nothing, and
/// its numbers are `SceneGlare::at_gaze`'s (the function `glare` uses).
#[test]
fn the_replays_glare_numbers_per_frame_do_not_allocate() {
    let (img, view) = night_view_with_two_lamps();
    let vg = ViewGlare::new(&img, &view, 25.0, 0.5).expect("view glare");
    let trace: Vec<[f32; 2]> = (0..24)
        .map(|i| {
            [
                (i % 8) as f32 / 8.0 * 1.3 - 0.15,
                (i / 8) as f32 / 3.0 + 0.1,
            ]
        })
        .collect();
    let first: Vec<[f64; 3]> = trace.iter().map(|&g| vg.at(g).values()).collect();
    let n = allocations_in(|| {
        for (g, want) in trace.iter().zip(&first) {
            let got = vg.at(*g).values();
            assert!(got == *want, "{got:?} != {want:?}");
        }
    });
    assert_eq!(n, 0, "{n} heap allocations in {} frames", trace.len());
    let projection = SceneProjection::with_square_pixels(
        ProjectionKind::Perspective,
        view.hfov_deg,
        view.width,
        view.height,
    )
    .expect("projection");
    let glare = SceneGlare::new(&img, projection);
    let opts = GlareOptions {
        age_years: 25.0,
        pigmentation: 0.5,
        ..GlareOptions::default()
    };
    for (g, got) in trace.iter().zip(&first) {
        let dir = vg.gaze_direction(*g).expect("a direction");
        let want = glare.at_gaze(dir, &opts);
        assert_eq!(got[0].to_bits(), want.veil_cie146_cd_m2.to_bits());
        assert_eq!(got[1].to_bits(), want.indices.dgp.to_bits());
    }
}
