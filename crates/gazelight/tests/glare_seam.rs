#![allow(clippy::unwrap_used, clippy::expect_used)] // test and bench code may panic on a failed setup
//! Issue 39: the glare veil has no straight seam. Real replays rendered
//! twice, with glare and without (`[pipeline] glare = { enabled = false }`),
//! and their difference searched for a step of ≥ 1.5 code values along
//! ≥ 40 pixels of one column or row boundary
//! ([`gazelight_test_support::seam`], the one detector). The kernel used to
//! be cut at its square field (±20° around every source): in these
//! dark-adapted night frames the veil then stopped at straight edges 20°
//! from the street lamps, in both eyes at the same columns.
//!
//! The GPU test needs an adapter (on CI: lavapipe, `WGPU_BACKEND=vulkan`);
//! without one it prints a skip line, unless `GAZELIGHT_REQUIRE_GPU=1`.

mod common;

use std::path::{Path, PathBuf};

use common::{gazelight, shared_str, tmp};
use gazelight_gpu::testing::test_context;
use gazelight_test_support::seam::{Frame, Seam, SeamRule, find_seams};

/// Replays `recording` into `dir/glare` and `dir/no-glare` with `args`
/// (size, time range, backend) and returns both output directories.
fn replay_twice(dir: &Path, recording: &str, args: &[&str]) -> (PathBuf, PathBuf) {
    let config = dir.join("no-glare.toml");
    std::fs::write(&config, "[pipeline]\nglare = { enabled = false }\n").expect("config");
    let (on, off) = (dir.join("glare"), dir.join("no-glare"));
    for (out, extra) in [
        (&on, vec![]),
        (&off, vec!["--config", config.to_str().expect("utf-8")]),
    ] {
        let mut all = vec!["replay", recording, "--out", out.to_str().expect("utf-8")];
        all.extend_from_slice(args);
        all.extend_from_slice(&extra);
        let run = gazelight(&all);
        let stderr = String::from_utf8_lossy(&run.stderr);
        assert!(run.status.success(), "replay {all:?} failed: {stderr}");
        assert!(!stderr.contains("panicked"), "{stderr}");
    }
    (on, off)
}

/// What the glare changed in one replay, and its seams.
struct Veil {
    frames: usize,
    /// Largest |with − without| of any channel, code values.
    max_diff: u8,
    /// Pixels (of all frames) that differ in any channel.
    changed_px: usize,
    seams: Vec<(String, Seam)>,
}

/// Every frame of `on` against the same frame of `off`.
fn veil(on: &Path, off: &Path) -> Veil {
    let mut names: Vec<String> = std::fs::read_dir(on.join("frames"))
        .expect("frames dir")
        .map(|e| e.expect("entry").file_name().to_string_lossy().into_owned())
        .filter(|n| n.ends_with(".png"))
        .collect();
    names.sort();
    let mut v = Veil {
        frames: names.len(),
        max_diff: 0,
        changed_px: 0,
        seams: Vec::new(),
    };
    for name in &names {
        let a = image::open(on.join("frames").join(name))
            .expect("frame with glare")
            .to_rgb8();
        let b = image::open(off.join("frames").join(name))
            .expect("frame without glare")
            .to_rgb8();
        assert_eq!(a.dimensions(), b.dimensions(), "{name}");
        let (w, h) = (a.width() as usize, a.height() as usize);
        for (p, q) in a.as_raw().chunks_exact(3).zip(b.as_raw().chunks_exact(3)) {
            let d = p
                .iter()
                .zip(q)
                .map(|(x, y)| x.abs_diff(*y))
                .max()
                .unwrap_or(0);
            v.max_diff = v.max_diff.max(d);
            v.changed_px += usize::from(d > 0);
        }
        let frame = |px| Frame {
            pixels: px,
            width: w,
            height: h,
            channels: 3,
        };
        let seams = find_seams(frame(a.as_raw()), frame(b.as_raw()), SeamRule::default());
        v.seams.extend(seams.into_iter().map(|s| (name.clone(), s)));
    }
    v
}

/// Asserts that the replay saw real glare and that its veil has no seam.
fn assert_no_seam(what: &str, v: &Veil, min_frames: usize) {
    println!(
        "{what}: {} frames, glare changed {} pixels by up to {} code values, {} seams",
        v.frames,
        v.changed_px,
        v.max_diff,
        v.seams.len()
    );
    for (name, s) in v.seams.iter().take(12) {
        println!("  {name}: {s}");
    }
    assert!(v.frames >= min_frames, "{what}: {} frames", v.frames);
    // The street lamps are in the glare window: a strong veil (else the
    // test would pass for want of glare).
    assert!(
        v.max_diff >= 50,
        "{what}: glare too weak to test: {}",
        v.max_diff
    );
    assert!(
        v.seams.is_empty(),
        "{what}: {} straight seams in the glare veil, e.g. {}: {}",
        v.seams.len(),
        v.seams[0].0,
        v.seams[0].1
    );
}

/// The Neon recording in stereo on the night demo, 3.5 s to 4 s (the gaze
/// on the street lamps, dark-adapted), CPU pipeline.
#[test]
fn neon_stereo_replay_veil_has_no_seam() {
    let dir = tmp("neon-stereo");
    let (on, off) = replay_twice(
        &dir,
        &shared_str("eye/neon-demo"),
        &[
            "--stereo",
            "--size",
            "360x400",
            "--from-secs",
            "3.5",
            "--secs",
            "0.5",
            "--fps",
            "10",
            "--backend",
            "cpu",
        ],
    );
    assert_no_seam("Neon stereo, CPU", &veil(&on, &off), 6);
}

/// The EyeLink recording (its own gaze; pupil from the light-adaptation
/// model, the file's pupil being in raw units) on the night demo, 80 s to
/// 81 s, where the gaze rests near the street lamps. CPU pipeline.
#[test]
fn eyelink_replay_veil_has_no_seam() {
    let dir = tmp("eyelink");
    let (on, off) = replay_twice(
        &dir,
        &shared_str("eye/eyelink-psa/both_eyes.asc"),
        &[
            "--size",
            "360x400",
            "--from-secs",
            "80",
            "--secs",
            "1",
            "--fps",
            "4",
            "--backend",
            "cpu",
        ],
    );
    assert_no_seam("EyeLink, CPU", &veil(&on, &off), 5);
}

/// The Neon recording, one eye, 3.7 s to 3.9 s, on the GPU pipeline.
#[test]
fn neon_replay_veil_has_no_seam_on_the_gpu() {
    let Some(ctx) = test_context("neon_replay_veil_has_no_seam_on_the_gpu") else {
        return;
    };
    println!("adapter: {}", ctx.describe());
    let dir = tmp("neon-gpu");
    let (on, off) = replay_twice(
        &dir,
        &shared_str("eye/neon-demo"),
        &[
            "--size",
            "360x400",
            "--from-secs",
            "3.7",
            "--secs",
            "0.2",
            "--fps",
            "10",
            "--backend",
            "gpu",
        ],
    );
    assert_no_seam("Neon, GPU", &veil(&on, &off), 3);
}
