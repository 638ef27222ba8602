#![allow(clippy::unwrap_used, clippy::expect_used)] // test and bench code may panic on a failed setup
//! The CLI end to end: the default render, `psf`, `inspect`, and bad input
//! (clear error naming the file and the problem, non-zero exit, no panic).

mod common;

use std::process::Output;
use std::time::Instant;

use common::{gazelight, python_ready, shared, spawn_peer_any_port, tmp};

fn assert_clean_failure(out: &Output, needles: &[&str]) {
    let stderr = String::from_utf8_lossy(&out.stderr);
    assert!(!out.status.success(), "expected failure, stderr: {stderr}");
    assert!(!stderr.contains("panicked"), "panic: {stderr}");
    for n in needles {
        assert!(stderr.contains(n), "stderr lacks `{n}`: {stderr}");
    }
}

#[test]
fn default_render_writes_everything() {
    let out_dir = tmp("render");
    let started = Instant::now();
    let out = gazelight(&["render", "--out", out_dir.to_str().expect("utf-8")]);
    let secs = started.elapsed().as_secs_f64();
    assert!(
        out.status.success(),
        "{}",
        String::from_utf8_lossy(&out.stderr)
    );
    // Its speed is a benchmark's figure (BENCHMARKS.md), not a bound
    // here: under load (issue 50's check, other builds beside it) a wall
    // clock says more about the machine than about the render.
    eprintln!("default render took {secs:.1} s");
    for f in [
        "contact_sheet.png",
        "timeline.csv",
        "plot.png",
        "frames/frame_00000.png",
    ] {
        let p = out_dir.join(f);
        assert!(
            p.is_file() && std::fs::metadata(&p).expect("meta").len() > 100,
            "{f}"
        );
    }
    let timeline = std::fs::read_to_string(out_dir.join("timeline.csv")).expect("timeline");
    let head: Vec<&str> = timeline
        .lines()
        .next()
        .expect("header")
        .split(',')
        .collect();
    let col = |n: &str| head.iter().position(|c| *c == n).expect("column");
    // An empty cell (nothing measured, no raw unit) reads NaN.
    let rows: Vec<Vec<f64>> = timeline
        .lines()
        .skip(1)
        .map(|l| {
            l.split(',')
                .map(|v| {
                    if v.is_empty() {
                        f64::NAN
                    } else {
                        v.parse::<f64>().expect("number")
                    }
                })
                .collect()
        })
        .collect();
    let (pupil, aperture, target, adaptation) = (
        col("pupil_mm"),
        col("aperture_mm"),
        col("target_cd_m2"),
        col("adaptation_cd_m2"),
    );
    assert_eq!(rows.len(), 360, "12 s of 200 Hz samples at 30 fps");
    assert_eq!(
        std::fs::read_dir(out_dir.join("frames"))
            .expect("frames")
            .count(),
        360
    );
    // The aperture is never 0 and the trace's pupil is measured from the
    // first frame (a trace is what the user asks for); adaptation rises
    // when the gaze lands on the lamp (3 s) and falls after 7.5 s.
    let at = |t: f64| rows.iter().find(|r| r[0] >= t).expect("row");
    assert!(rows.iter().all(|r| r[aperture] > 1.0 && r[aperture] < 9.0));
    assert!(rows[0][pupil].is_finite(), "{:?}", rows[0]);
    assert!(
        rows.iter()
            .all(|r| r[pupil].is_nan() || (r[pupil] > 1.0 && r[pupil] < 9.0))
    );
    assert!(
        at(6.0)[adaptation] > 100.0 * at(2.0)[adaptation],
        "lamp {} vs ground {}",
        at(6.0)[adaptation],
        at(2.0)[adaptation]
    );
    assert!(at(11.5)[adaptation] < at(6.0)[adaptation] / 100.0);
    // docs/perception.md: the pooled luminance jumps by three and a half
    // decades, 0.013 → 52 cd/m².
    let decades = (at(6.0)[target] / at(2.0)[target]).log10();
    assert!((3.3..3.9).contains(&decades), "{decades} decades");
    assert!((0.010..0.016).contains(&at(2.0)[target]) && (45.0..60.0).contains(&at(6.0)[target]));
    assert!(
        at(6.0)[aperture] < at(2.0)[aperture] - 1.0,
        "the pupil constricts at the lamp"
    );
    let _ = std::fs::remove_dir_all(&out_dir);
}

#[test]
fn psf_writes_kernel_files() {
    let out_dir = tmp("psf");
    let out = gazelight(&[
        "psf",
        "--pupil-mm",
        "4",
        "--field-deg",
        "10",
        "--out",
        out_dir.to_str().expect("utf-8"),
    ]);
    assert!(
        out.status.success(),
        "{}",
        String::from_utf8_lossy(&out.stderr)
    );
    let text = std::fs::read_to_string(out_dir.join("psf.json")).expect("json");
    let json: serde_json::Value = serde_json::from_str(&text).expect("valid json");
    assert_eq!(json["pupil_mm"], 4.0);
    assert_eq!(json["field_deg"], 10.0);
    assert_eq!(json["age_years"], 25.0);
    assert_eq!(json["pigmentation"], 0.5);
    assert!(json["deg_per_px"].as_f64().expect("deg") > 0.0);
    assert!(json["wavelengths_nm"].as_array().expect("wl").len() >= 2);
    for e in json["energy"].as_array().expect("energy") {
        assert!((e.as_f64().expect("e") - 1.0).abs() < 1e-4);
    }
    let img = image::open(out_dir.join("kernel.png")).expect("png");
    assert_eq!(u64::from(img.width()), json["size"].as_u64().expect("size"));
    assert!(out_dir.join("kernel.exr").is_file());
    let _ = std::fs::remove_dir_all(&out_dir);
}

#[test]
fn inspect_summarises_the_real_recordings() {
    for rec in [
        "eye/neon-demo",
        "eye/eyelink-psa/both_eyes.asc",
        "eye/piprkit-plr/pupil_trace.csv",
    ] {
        let out = gazelight(&["inspect", shared(rec).to_str().expect("utf-8"), "--json"]);
        assert!(
            out.status.success(),
            "{rec}: {}",
            String::from_utf8_lossy(&out.stderr)
        );
        let json: serde_json::Value = serde_json::from_slice(&out.stdout).expect("json summary");
        assert!(
            json["duration_s"].as_f64().expect("duration") > 5.0,
            "{rec}: {json}"
        );
        let text = gazelight(&["inspect", shared(rec).to_str().expect("utf-8")]);
        assert!(text.status.success() && !text.stdout.is_empty());
    }
}

#[test]
fn bad_input_gives_clear_errors() {
    let dir = tmp("bad");
    let d = |f: &str| dir.join(f).to_str().expect("utf-8").to_owned();
    let out_dir = d("out");

    // Missing scene.
    let out = gazelight(&[
        "render",
        "--scene",
        "/nonexistent/scene.exr",
        "--out",
        &out_dir,
    ]);
    assert_clean_failure(&out, &["/nonexistent/scene.exr"]);

    // Corrupt scene: a truncated EXR.
    let bytes = std::fs::read(shared("hdr/blender-world/night.exr")).expect("night");
    std::fs::write(d("cut.exr"), &bytes[..bytes.len() / 4]).expect("write");
    let out = gazelight(&["render", "--scene", &d("cut.exr"), "--out", &out_dir]);
    assert_clean_failure(&out, &["cut.exr", "OpenEXR"]);

    // A text file posing as a scene.
    std::fs::write(d("text.hdr"), "hello").expect("write");
    let out = gazelight(&["render", "--scene", &d("text.hdr"), "--out", &out_dir]);
    assert_clean_failure(&out, &["text.hdr"]);

    // A trace with time going backwards names the file and line.
    std::fs::write(
        d("back.csv"),
        "t_secs,gaze_u,gaze_v,pupil_mm\n0,0.5,0.5,4\n1,0.5,0.5,4\n0.5,0.5,0.5,4\n",
    )
    .expect("write");
    let out = gazelight(&[
        "render",
        "--trace",
        &d("back.csv"),
        "--out",
        &out_dir,
        "--frames",
        "2",
    ]);
    assert_clean_failure(&out, &["back.csv:4", "backwards"]);

    // Unknown option.
    let out = gazelight(&["render", "--frobnicate"]);
    assert_clean_failure(&out, &["--frobnicate"]);

    // Malformed config: a bad value and an unknown field are named.
    std::fs::write(d("bad.toml"), "[pipeline]\nglare = { window_px = 100 }\n").expect("write");
    let out = gazelight(&["render", "--config", &d("bad.toml"), "--out", &out_dir]);
    assert_clean_failure(&out, &["bad.toml", "window_px"]);
    std::fs::write(d("typo.toml"), "[pipeline]\npoolng = 3\n").expect("write");
    let out = gazelight(&["render", "--config", &d("typo.toml"), "--out", &out_dir]);
    assert_clean_failure(&out, &["typo.toml", "poolng"]);

    // Bad PSF parameters.
    let out = gazelight(&["psf", "--pupil-mm=-3", "--out", &out_dir]);
    assert_clean_failure(&out, &["pupil_mm"]);

    // A recording in an unknown format.
    let out = gazelight(&["inspect", &d("bad.toml")]);
    assert_clean_failure(&out, &["bad.toml"]);
    let _ = std::fs::remove_dir_all(&dir);
}

#[test]
fn nan_scene_is_rejected() {
    let dir = tmp("nan");
    let img = gazelight_vision::RgbImage::from_pixels(8, 8, vec![[f32::NAN; 3]; 64]).expect("img");
    let exr = dir.join("nan.exr");
    gazelight_vision::scene::write_exr(&exr, &img).expect("exr");
    let out = gazelight(&[
        "render",
        "--scene",
        exr.to_str().expect("utf-8"),
        "--out",
        dir.join("o").to_str().expect("utf-8"),
    ]);
    assert_clean_failure(&out, &["nan.exr", "NaN"]);
    let _ = std::fs::remove_dir_all(&dir);
}

#[test]
fn inspect_summarises_a_live_peer() {
    if !python_ready() {
        return;
    }
    let peer = spawn_peer_any_port("200", "20", &[]);
    let port = peer.remote_port;
    let out = gazelight(&[
        "inspect",
        &format!("pupil://127.0.0.1:{port}"),
        "--secs",
        "1.5",
        "--json",
    ]);
    drop(peer);
    assert!(
        out.status.success(),
        "{}",
        String::from_utf8_lossy(&out.stderr)
    );
    let json: serde_json::Value = serde_json::from_slice(&out.stdout).expect("json summary");
    assert!(json["clock_offset_s"].is_object(), "{json}");
    let text = json.to_string();
    assert!(text.contains("rate_hz"), "{text}");

    // Nothing listening: a clear error, not a hang or a panic.
    let out = gazelight(&["inspect", "pupil://127.0.0.1:9", "--secs", "0.5"]);
    assert_clean_failure(&out, &["127.0.0.1:9"]);
}

/// One configuration file with `[observer]`, `[scene]`, `[pipeline]`,
/// `[filter]` (and keys only `run` uses) is accepted by `render`,
/// `replay`, `run` and `calibrate`; a real `render` with it runs and names
/// the keys it ignores (and only those).
#[test]
fn one_config_file_serves_every_command() {
    let dir = tmp("one-config");
    let config = dir.join("study.toml");
    std::fs::write(
        &config,
        "[source]\nuri = \"pupil://127.0.0.1:50020\"\n\
         [display]\nsize = \"64x48\"\nfps = 60.0\n\
         [scene]\nyaw_deg = -78.4\npitch_deg = -6.0\n\
         [pipeline]\nglare = { full_weight_deg = 10.0 }\n\
         [filter]\ndropout = { hold_s = 0.3 }\n\
         [observer]\nage_years = 70.0\npigmentation = 1.0\n\
         [http]\naddr = \"127.0.0.1:8080\"\n",
    )
    .expect("write");
    let c = config.to_str().expect("utf-8");
    let recording = shared("eye/neon-demo");
    let r = recording.to_str().expect("utf-8");
    let o = dir.join("o");
    let o = o.to_str().expect("utf-8");
    for args in [
        vec!["render", "--config", c, "--out", o],
        vec!["replay", r, "--config", c, "--out", o],
        vec!["run", "--config", c],
        vec!["calibrate", "--config", c, "--out", o],
    ] {
        let out = common::gazelight_env(&args, &[("GAZELIGHT_PARSE_ONLY", "1")]);
        assert!(
            out.status.success(),
            "{args:?}: {}",
            String::from_utf8_lossy(&out.stderr)
        );
    }
    // A real render: the keys it does not use are named.
    let out_dir = dir.join("render");
    let out = gazelight(&[
        "render",
        "--config",
        c,
        "--out",
        out_dir.to_str().expect("utf-8"),
        "--frames",
        "2",
    ]);
    let stderr = String::from_utf8_lossy(&out.stderr);
    assert!(out.status.success(), "{stderr}");
    for key in ["source", "display.fps", "http"] {
        assert!(
            stderr.contains(&format!("`{key}` does not apply to `gazelight render`")),
            "{key} not reported as ignored: {stderr}"
        );
    }
    assert!(!stderr.contains("observer"), "observer reported: {stderr}");
    let timeline = std::fs::read_to_string(out_dir.join("timeline.csv")).expect("timeline");
    assert_eq!(timeline.lines().count(), 3, "{timeline}");
    let _ = std::fs::remove_dir_all(&dir);
}
