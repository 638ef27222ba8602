#![allow(clippy::unwrap_used, clippy::expect_used)] // test and bench code may panic on a failed setup
//! Property suite (issue 14) for the scene loader: random bytes and
//! mutations of real OpenEXR (DWAB, from shared/data) and Radiance files
//! give a scene or a clear error naming the file, never a panic, and never
//! an allocation from an unchecked header size (a mutated data window or
//! resolution line would otherwise ask for terabytes). Case counts are
//! fixed (`GAZELIGHT_FUZZ_CASES`, default 256 per property).

use std::path::Path;

use gazelight_vision::RgbImage;
use gazelight_vision::scene::{LuminanceScale, Scene, write_exr};
use proptest::prelude::*;
use proptest::test_runner::{Config, TestRunner};

fn config() -> Config {
    Config {
        cases: std::env::var("GAZELIGHT_FUZZ_CASES")
            .ok()
            .and_then(|v| v.parse().ok())
            .unwrap_or(256),
        failure_persistence: None,
        ..Config::default()
    }
}

/// Byte overwrites, bit flips, deletions and insertions of `seed`, kept
/// in the first `hot` bytes (the header).
fn mutated(seed: Vec<u8>, hot: usize) -> impl Strategy<Value = Vec<u8>> {
    let hot = hot.min(seed.len()).max(1);
    let edit = (0u8..4, 0..hot, any::<u8>(), 1usize..32);
    prop::collection::vec(edit, 1..12).prop_map(move |edits| {
        let mut b = seed.clone();
        for (kind, i, v, n) in edits {
            if b.is_empty() {
                break;
            }
            let i = i % b.len();
            match kind {
                0 => b[i] = v,
                1 => b[i] ^= 1 << (v % 8),
                2 => {
                    let end = (i + n).min(b.len());
                    b.drain(i..end);
                }
                _ => {
                    b.splice(i..i, std::iter::repeat_n(v, n));
                }
            }
        }
        b
    })
}

fn load(bytes: &[u8]) -> Result<(), TestCaseError> {
    match Scene::from_bytes(bytes, Path::new("fuzz.exr"), LuminanceScale::default()) {
        Ok(s) => {
            prop_assert!(s.image.width * s.image.height == s.image.pixels.len());
            prop_assert!(
                s.image
                    .pixels
                    .iter()
                    .flatten()
                    .all(|v| v.is_finite() && *v >= 0.0)
            );
        }
        Err(e) => prop_assert!(e.to_string().contains("fuzz.exr"), "{e}"),
    }
    Ok(())
}

fn small_exr() -> Vec<u8> {
    let dir = std::env::temp_dir().join(format!("gazelight-fuzz-scene-{}", std::process::id()));
    std::fs::create_dir_all(&dir).unwrap();
    let p = dir.join("s.exr");
    let px: Vec<[f32; 3]> = (0..64 * 32).map(|i| [i as f32, 1.0, 0.5]).collect();
    write_exr(&p, &RgbImage::from_pixels(64, 32, px).unwrap()).unwrap();
    let b = std::fs::read(&p).unwrap();
    std::fs::remove_dir_all(&dir).ok();
    b
}

#[test]
fn scene_loader_never_panics_on_random_bytes() {
    let mut r = TestRunner::new(config());
    let strat = prop_oneof![
        prop::collection::vec(any::<u8>(), 0..1024),
        prop::collection::vec(any::<u8>(), 0..1024).prop_map(|mut b| {
            let mut v = vec![0x76, 0x2f, 0x31, 0x01, 2, 0, 0, 0];
            v.append(&mut b);
            v
        }),
        prop::collection::vec(any::<u8>(), 0..1024).prop_map(|b| {
            let mut v = b"#?RADIANCE\nFORMAT=32-bit_rle_rgbe\n\n-Y 8 +X 16\n".to_vec();
            v.extend(b);
            v
        }),
    ];
    r.run(&strat, |b| load(&b)).unwrap();
}

#[test]
fn scene_loader_never_panics_on_mutated_files() {
    let mut r = TestRunner::new(config());
    r.run(&mutated(small_exr(), 400), |b| load(&b)).unwrap();
    // A real DWAB panorama: header mutations (the pixel data is decoded in
    // full for the cases whose header survives, so fewer cases).
    let night = std::fs::read(gazelight_test_support::data_path(
        "hdr/blender-world/night.exr",
    ))
    .unwrap();
    let mut few = TestRunner::new(Config {
        cases: config().cases / 8,
        ..config()
    });
    few.run(&mutated(night, 600), |b| load(&b)).unwrap();
    let mut hdr = b"#?RADIANCE\nFORMAT=32-bit_rle_rgbe\nEXPOSURE=0.5\n\n-Y 8 +X 16\n".to_vec();
    for i in 0..128u8 {
        hdr.extend_from_slice(&[i, 128, 255 - i, 129]);
    }
    r.run(&mutated(hdr, 80), |b| load(&b)).unwrap();
}
