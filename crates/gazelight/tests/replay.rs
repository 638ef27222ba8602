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
    // The columns these tests read, by name, in this order: 3 the measured
    // pupil (mm), 4 pupil_held, 5 the model aperture.
    let names = [
        "t_secs",
        "gaze_u",
        "gaze_v",
        "pupil_mm",
        "pupil_held",
        "aperture_mm",
        "target_cd_m2",
        "adaptation_cd_m2",
        "psf_pupil_mm",
        "psf_rebuilt",
    ];
    let at: Vec<usize> = names
        .iter()
        .map(|n| {
            header
                .iter()
                .position(|h| h == n)
                .unwrap_or_else(|| panic!("{n}"))
        })
        .collect();
    lines
        .map(|l| {
            let cells: Vec<&str> = l.split(',').collect();
            at.iter().map(|&i| cells[i].to_owned()).collect()
        })
        .collect()
}

/// A column's numbers; an empty cell (nothing measured) reads NaN.
fn col(rows: &[Vec<String>], i: usize) -> Vec<f64> {
    rows.iter()
        .map(|r| {
            if r[i].is_empty() {
                f64::NAN
            } else {
                r[i].parse::<f64>().expect("number")
            }
        })
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
    // the service says so; the pupil is measured (held 0 on most frames) in
    // the raw unit, so no frame has a pupil in mm, and the glare aperture
    // comes from the adaptation model.
    assert!(
        stderr.contains("not in millimetres"),
        "missing the calibration warning: {stderr}"
    );
    let held = col(&rows, 4);
    assert!(held.iter().filter(|h| **h == 0.0).count() > rows.len() / 2);
    assert!(col(&rows, 3).iter().all(|p| p.is_nan()));
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

/// Every setting in effect is named with its source: in `session.json`
/// beside `timeline.csv` and in the printed summary. The EyeLink file (pupil
/// in arbitrary area units) reaches millimetres through a calibration
/// profile given in the configuration; the observer's age from a flag wins
/// over the file's, its pigmentation comes from the file; a custom OpenEXR
/// scene with no scale is warned about and its factor printed.
#[test]
fn replay_reports_every_setting_and_its_source() {
    let dir = tmp("settings");
    let profile = dir.join("eyelink-profile.json");
    std::fs::write(
        &profile,
        r#"{ "schema": "gazelight.pupil-calibration/2",
             "observer": { "age_years": 40, "pigmentation": 0.8 },
             "eyes": {
               "right": { "raw_unit": "arbitrary_area", "raw_black": 70.0, "raw_white": 25.0, "mm_min": 2.0, "mm_max": 8.0 },
               "left":  { "raw_unit": "arbitrary_area", "raw_black": 70.0, "raw_white": 25.0, "mm_min": 2.0, "mm_max": 8.0 } } }"#,
    )
    .expect("profile");
    let config = dir.join("study.toml");
    std::fs::write(
        &config,
        "[source]\ncalibration = \"eyelink-profile.json\"\n[observer]\nage_years = 50.0\npigmentation = 1.0\n",
    )
    .expect("config");
    let out_dir = dir.join("out");
    let scene = shared_str("hdr/blender-world/city.exr");
    let out = gazelight(&[
        "replay",
        &shared_str("eye/eyelink-psa/both_eyes.asc"),
        "--config",
        config.to_str().expect("utf-8"),
        "--scene",
        &scene,
        "--age-years",
        "70",
        "--size",
        "64x48",
        "--fps",
        "10",
        "--secs",
        "2",
        "--no-frames",
        "--out",
        out_dir.to_str().expect("utf-8"),
    ]);
    let stdout = String::from_utf8_lossy(&out.stdout);
    let stderr = String::from_utf8_lossy(&out.stderr);
    assert!(out.status.success(), "{stderr}");
    let session: serde_json::Value = serde_json::from_str(
        &std::fs::read_to_string(out_dir.join("session.json")).expect("session.json"),
    )
    .expect("JSON");
    let s = &session["settings"];
    assert_eq!(session["command"], "replay");
    assert_eq!(s["observer.age_years"]["value"], 70.0, "{s}");
    assert_eq!(s["observer.age_years"]["source"], "flag");
    assert_eq!(s["observer.pigmentation"]["value"], 1.0);
    assert_eq!(s["observer.pigmentation"]["source"], "config");
    assert_eq!(s["calibration.profile"]["source"], "config");
    let note = s["calibration.profile"]["note"].as_str().expect("note");
    assert!(
        note.contains("arbitrary area units") && note.contains("8 mm"),
        "{note}"
    );
    assert_eq!(s["scene.cd_m2_per_unit"]["source"], "default");
    assert!(
        s["scene.cd_m2_per_unit"]["note"]
            .as_str()
            .is_some_and(|n| n.contains("no absolute luminance scale")),
        "{s}"
    );
    assert!(
        stderr.contains("no absolute luminance scale"),
        "no warning for the unscaled scene: {stderr}"
    );
    for line in [
        "observer.age_years = 70.0 [flag]",
        "observer.pigmentation = 1.0 [config]",
        "calibration.profile = ",
        "scene.cd_m2_per_unit = 1.0 [default]",
    ] {
        assert!(stdout.contains(line), "summary lacks `{line}`: {stdout}");
    }
    // The black/white profile sizes the aperture (no model fallback, within
    // the model's range); it is not a physical scale, so no pupil in mm.
    assert!(!stderr.contains("not in millimetres"), "{stderr}");
    let rows = model_rows(&out_dir);
    let held = col(&rows, 4);
    let aperture = col(&rows, 5);
    assert!(held.contains(&0.0), "every pupil held/modelled");
    assert!(
        aperture.iter().all(|p| (1.5..=9.0).contains(p)),
        "{aperture:?}"
    );
    assert!(col(&rows, 3).iter().all(|p| p.is_nan()));
    let _ = std::fs::remove_dir_all(&dir);
}

/// The EyeLink recording (pupil in arbitrary area units) reaches
/// millimetres by the documented path: `gazelight profile scale` writes a
/// profile (0.1 mm per unit of √area), `replay --calibration` uses it, and
/// every measured (not held) frame's pupil is F·√area of the file's own
/// samples at that time (both eyes' mean), read here straight from the
/// `.asc` text.
#[test]
fn eyelink_reaches_millimetres_through_a_scale_profile() {
    let dir = tmp("eyelink-mm");
    let profile = dir.join("scale.json");
    let out = gazelight(&[
        "profile",
        "scale",
        "--unit",
        "arbitrary-area",
        "--mm-per-unit",
        "0.1",
        "--out",
        profile.to_str().expect("utf-8"),
    ]);
    assert!(
        out.status.success(),
        "{}",
        String::from_utf8_lossy(&out.stderr)
    );
    let asc = shared_str("eye/eyelink-psa/both_eyes.asc");
    let out_dir = dir.join("out");
    let out = gazelight(&[
        "replay",
        &asc,
        "--calibration",
        profile.to_str().expect("utf-8"),
        "--size",
        "64x48",
        "--fps",
        "10",
        "--secs",
        "30",
        "--no-frames",
        "--out",
        out_dir.to_str().expect("utf-8"),
    ]);
    let stderr = String::from_utf8_lossy(&out.stderr);
    assert!(out.status.success(), "{stderr}");
    assert!(!stderr.contains("not in millimetres"), "{stderr}");
    // The file's binocular samples: `time xL yL areaL xR yR areaR …`.
    let text = std::fs::read_to_string(&asc).expect("asc");
    let samples: Vec<(f64, f64, f64)> = text
        .lines()
        .filter(|l| l.as_bytes().first().is_some_and(u8::is_ascii_digit))
        .filter_map(|l| {
            let f: Vec<&str> = l.split_whitespace().collect();
            let num = |i: usize| f.get(i)?.parse::<f64>().ok();
            Some((num(0)? / 1000.0, num(3)?, num(6)?))
        })
        .collect();
    let t0 = samples[0].0;
    let rows = model_rows(&out_dir);
    let (mut compared, mut close) = (0, 0);
    for r in &rows {
        let (t, pupil, held): (f64, f64, f64) = (
            r[0].parse().expect("t"),
            r[3].parse().unwrap_or(f64::NAN),
            r[4].parse().expect("held"),
        );
        let i = samples.partition_point(|s| s.0 < t0 + t);
        let Some(&(_, left, right)) = samples.get(i) else {
            break;
        };
        if held != 0.0 || left <= 0.0 || right <= 0.0 {
            continue;
        }
        let expected = 0.5 * (0.1 * left.sqrt() + 0.1 * right.sqrt());
        compared += 1;
        close += usize::from((pupil - expected).abs() < 0.05);
    }
    assert!(
        compared > 250,
        "only {compared} measured frames of {}",
        rows.len()
    );
    assert!(
        close as f64 >= 0.95 * compared as f64,
        "{close} of {compared} frames within 0.05 mm of F·√area"
    );
    let _ = std::fs::remove_dir_all(&dir);
}
