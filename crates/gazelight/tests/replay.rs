#![allow(clippy::unwrap_used, clippy::expect_used)] // test and bench code may panic on a failed setup
//! `gazelight replay` end to end on the real recordings: the whole stack
//! (importer → filter chain → frame pipeline → outputs), deterministic, and
//! bad input refused with a clear error.

mod common;

use std::path::Path;

use common::{gazelight, shared_str, tmp};

/// The model columns of timeline.csv (t, gaze, pupil, held, target,
/// adaptation, psf pupil, rebuilt, sigma), without the timing columns.
fn model_rows(dir: &Path) -> Vec<Vec<String>> {
    let text = std::fs::read_to_string(dir.join("timeline.csv")).expect("timeline.csv");
    let mut lines = text.lines();
    let header: Vec<&str> = lines.next().expect("header").split(',').collect();
    assert_eq!(header[0], "t_secs");
    assert_eq!(header[3], "pupil_mm");
    lines
        .map(|l| l.split(',').take(10).map(str::to_owned).collect())
        .collect()
}

fn col(rows: &[Vec<String>], i: usize) -> Vec<f64> {
    rows.iter()
        .map(|r| r[i].parse::<f64>().expect("number"))
        .collect()
}

#[test]
fn neon_recording_replays_deterministically() {
    let rec = shared_str("eye/neon-demo");
    let a = tmp("neon-a");
    let b = tmp("neon-b");
    for dir in [&a, &b] {
        let out = gazelight(&[
            "replay",
            &rec,
            "--size",
            "96x80",
            "--fps",
            "30",
            "--no-frames",
            "--out",
            dir.to_str().expect("utf-8"),
        ]);
        let stderr = String::from_utf8_lossy(&out.stderr);
        assert!(out.status.success(), "replay failed: {stderr}");
        assert!(!stderr.contains("panicked"), "{stderr}");
    }
    for f in ["timeline.csv", "contact_sheet.png", "plot.png"] {
        assert!(a.join(f).is_file(), "{f} missing");
    }
    let rows = model_rows(&a);
    // ~9 s at 30 fps (info.json: the recording's duration).
    assert!(
        (250..=300).contains(&rows.len()),
        "{} frames for a ~9 s recording at 30 fps",
        rows.len()
    );
    // Same recording, same outputs: the replay is deterministic.
    assert_eq!(rows, model_rows(&b), "two replays differ");

    // The Neon pupil is measured in mm: the frames use it (physiological
    // range, and it moves), not a constant.
    let pupil = col(&rows, 3);
    let held = col(&rows, 4);
    let measured: Vec<f64> = pupil
        .iter()
        .zip(&held)
        .filter(|(_, h)| **h == 0.0)
        .map(|(p, _)| *p)
        .collect();
    assert!(
        measured.len() > rows.len() / 2,
        "most frames should use a measured pupil, {} of {}",
        measured.len(),
        rows.len()
    );
    let (lo, hi) = measured
        .iter()
        .fold((f64::MAX, f64::MIN), |(a, b), p| (a.min(*p), b.max(*p)));
    assert!(lo > 1.5 && hi < 9.0, "pupil out of range: {lo}..{hi} mm");
    assert!(hi - lo > 0.05, "pupil never moves: {lo}..{hi} mm");
    // Gaze moves too.
    let u = col(&rows, 1);
    let spread =
        u.iter().cloned().fold(f64::MIN, f64::max) - u.iter().cloned().fold(f64::MAX, f64::min);
    assert!(spread > 0.01, "gaze never moves");
}

#[test]
fn eyelink_replay_with_window_and_frames() {
    let rec = shared_str("eye/eyelink-psa/both_eyes.asc");
    let out_dir = tmp("eyelink");
    let out = gazelight(&[
        "replay",
        &rec,
        "--size",
        "64x48",
        "--fps",
        "20",
        "--from-secs",
        "2",
        "--secs",
        "3",
        "--out",
        out_dir.to_str().expect("utf-8"),
    ]);
    let stderr = String::from_utf8_lossy(&out.stderr);
    assert!(out.status.success(), "replay failed: {stderr}");
    // 3 s at 20 fps, frames on.
    let rows = model_rows(&out_dir);
    assert_eq!(rows.len(), 61);
    let pngs = std::fs::read_dir(out_dir.join("frames"))
        .expect("frames dir")
        .count();
    assert_eq!(pngs, 61);
    // EyeLink pupil is in arbitrary area units and no calibration was given:
    // the service says so and the pupil comes from the adaptation model.
    assert!(
        stderr.contains("not in millimetres"),
        "missing the calibration warning: {stderr}"
    );
    let held = col(&rows, 4);
    assert!(held.iter().all(|h| *h == 1.0));
}

#[test]
fn replay_refuses_bad_input() {
    let out_dir = tmp("bad");
    let o = out_dir.to_str().expect("utf-8");
    let missing = gazelight(&["replay", "/nonexistent/rec.asc", "--out", o]);
    let stderr = String::from_utf8_lossy(&missing.stderr);
    assert!(!missing.status.success());
    assert!(stderr.contains("/nonexistent/rec.asc"), "{stderr}");
    assert!(!stderr.contains("panicked"), "{stderr}");

    let txt = out_dir.join("notes.txt");
    std::fs::write(&txt, "hello").expect("write");
    let unknown = gazelight(&["replay", txt.to_str().expect("utf-8"), "--out", o]);
    let stderr = String::from_utf8_lossy(&unknown.stderr);
    assert!(!unknown.status.success());
    assert!(stderr.contains("unknown recording format"), "{stderr}");

    let late = gazelight(&[
        "replay",
        &shared_str("eye/neon-demo"),
        "--from-secs",
        "500",
        "--out",
        o,
    ]);
    let stderr = String::from_utf8_lossy(&late.stderr);
    assert!(!late.status.success());
    assert!(stderr.contains("--from-secs 500"), "{stderr}");
}
