#![allow(clippy::unwrap_used, clippy::expect_used)] // test and bench code may panic on a failed setup
//! Stereo frames (`--stereo`): each eye rendered on its own pupil, kernel
//! and gaze, frames left | right, per-eye `timeline.csv` columns, and a
//! stereo live run.

mod common;

use std::path::Path;
use std::time::Duration;

use common::{
    Csv, complete_rows, gazelight, python_ready, shared_str, spawn_peer_any_port, tmp, wait_bounded,
};
use gazelight_vision::RgbImage;

fn median(mut v: Vec<f64>) -> f64 {
    v.sort_by(f64::total_cmp);
    v[v.len() / 2]
}

/// Width and height from a PNG's IHDR chunk.
fn png_size(path: &Path) -> (u32, u32) {
    let bytes = std::fs::read(path).expect("png");
    assert_eq!(&bytes[1..4], b"PNG", "{}", path.display());
    let be = |o: usize| u32::from_be_bytes(bytes[o..o + 4].try_into().expect("4 bytes"));
    (be(16), be(20))
}

fn success(out: &std::process::Output) -> String {
    let stderr = String::from_utf8_lossy(&out.stderr);
    assert!(out.status.success(), "exit {:?}: {stderr}", out.status);
    assert!(!stderr.contains("panicked"), "{stderr}");
    String::from_utf8_lossy(&out.stdout).into_owned()
}

/// The filtered pupil medians `inspect` reports per eye: [right, left].
fn inspect_medians(rec: &str) -> [f64; 2] {
    let text = success(&gazelight(&["inspect", rec]));
    let medians: Vec<f64> = text
        .lines()
        .filter(|l| l.trim_start().starts_with("pupil filt."))
        .map(|l| {
            let values = l.split(':').nth(1).expect("values");
            values
                .split('/')
                .nth(1)
                .expect("median")
                .trim()
                .trim_end_matches(" mm")
                .parse()
                .expect("mm")
        })
        .collect();
    assert_eq!(medians.len(), 2, "{text}");
    [medians[0], medians[1]]
}

/// Neon measured different pupils for the two eyes (left ≈ 0.35 mm wider
/// than right in the shared recording): a stereo replay renders each eye
/// with its own pupil and, once they part, its own kernel; the frames are
/// left | right.
#[test]
fn neon_replay_renders_each_eye_with_its_own_pupil_and_kernel() {
    let rec = shared_str("eye/neon-demo");
    let [right_mm, left_mm] = inspect_medians(&rec);
    assert!(
        left_mm - right_mm > 0.2,
        "the recording's eyes: {left_mm} vs {right_mm}"
    );
    let dir = tmp("stereo-neon");
    let out = gazelight(&[
        "replay",
        &rec,
        "--stereo",
        "--backend",
        "cpu",
        "--size",
        "96x80",
        "--fps",
        "30",
        "--secs",
        "6",
        "--out",
        dir.to_str().expect("utf-8"),
    ]);
    let stdout = success(&out);
    assert!(stdout.contains("stereo frames (96x80 per eye"), "{stdout}");
    // Each eye's own gaze (Neon's eye states), said in the summary and in
    // session.json.
    assert!(
        stdout.contains("each eye's own gaze from the source in"),
        "{stdout}"
    );
    let session: serde_json::Value =
        serde_json::from_slice(&std::fs::read(dir.join("session.json")).expect("session.json"))
            .expect("JSON");
    let per_eye = &session["settings"]["gaze.per_eye"];
    assert_eq!(per_eye["source"], "source", "{session}");
    let own = &per_eye["value"]["own_gaze_frames"];
    let frames = per_eye["value"]["frames"].as_u64().unwrap();
    assert!(
        own[0].as_u64().unwrap() * 10 >= frames * 9 && own[1].as_u64().unwrap() * 10 >= frames * 9,
        "{per_eye}"
    );
    assert_eq!(png_size(&dir.join("frames/frame_00010.png")), (192, 80));
    // plot.png: one colour per eye (left in blues, right in oranges; the
    // adaptation lines' exact colours, output.rs `eye_colours`).
    let plot = image::open(dir.join("plot.png")).expect("plot").to_rgb8();
    let count = |c: [u8; 3]| plot.pixels().filter(|p| p.0 == c).count();
    let (left, right) = (count([20, 60, 200]), count([220, 90, 0]));
    assert!(
        left > 200 && right > 200,
        "eye colours in plot.png: left {left}, right {right} px"
    );

    let csv = Csv::read(&dir.join("timeline.csv"));
    for column in [
        "gaze_u",
        "gaze_v",
        "pupil_mm",
        "adaptation_cd_m2",
        "psf_pupil_mm",
    ] {
        for eye in ["left", "right"] {
            csv.col(&format!("{column}_{eye}"));
        }
    }
    // The two views' gazes differ where the recording's eyes differ: the
    // per-eye gaze from each eye state (kappa-corrected optical axes, about
    // 1° apart at the median) against the binocular gaze that stood in for
    // both before (identical in all frames).
    let (gl, gr) = (csv.f64s("gaze_u_left"), csv.f64s("gaze_u_right"));
    let (vl, vr) = (csv.f64s("gaze_v_left"), csv.f64s("gaze_v_right"));
    let apart = (0..gl.len())
        .filter(|&i| (gl[i] - gr[i]).abs() > 1e-3 || (vl[i] - vr[i]).abs() > 1e-3)
        .count();
    assert!(
        apart * 10 >= gl.len() * 8,
        "left and right gaze differ in {apart} of {} frames",
        gl.len()
    );
    let pl = csv.f64s("pupil_mm_left");
    let pr = csv.f64s("pupil_mm_right");
    // Each eye's column follows that eye (its measured frames; an empty
    // cell is a blink and its margins).
    let finite = |v: &[f64]| {
        v.iter()
            .copied()
            .filter(|x| x.is_finite())
            .collect::<Vec<_>>()
    };
    let (ml, mr) = (median(finite(&pl)), median(finite(&pr)));
    eprintln!(
        "median pupils: left {ml:.3} (inspect {left_mm}), right {mr:.3} (inspect {right_mm})"
    );
    assert!((ml - left_mm).abs() < 0.15, "left {ml} vs {left_mm}");
    assert!((mr - right_mm).abs() < 0.15, "right {mr} vs {right_mm}");

    // Kernels: shared while the pupils agree, each eye's own once they part.
    let kl = csv.f64s("psf_pupil_mm_left");
    let kr = csv.f64s("psf_pupil_mm_right");
    // The first frame's kernels are each eye's first measurement (not a
    // made-up default the pupils ease out of).
    assert!(
        (kl[0] - pl[0]).abs() <= 0.1 + 1e-3 && (kr[0] - pr[0]).abs() <= 0.1 + 1e-3,
        "first frame: kernels {} / {} for pupils {} / {}",
        kl[0],
        kr[0],
        pl[0],
        pr[0]
    );
    // The kernels follow each view's aperture (the measured mm, held
    // through blinks, rate-limited): the pupil the view was rendered with.
    let (al, ar) = (csv.f64s("aperture_mm_left"), csv.f64s("aperture_mm_right"));
    let (pl, pr) = (al, ar);
    let parted: Vec<usize> = (0..pl.len())
        .filter(|&i| (pl[i] - pr[i]).abs() > 0.3)
        .collect();
    assert!(
        parted.len() > pl.len() / 3,
        "{} of {} frames parted",
        parted.len(),
        pl.len()
    );
    let own = parted.iter().filter(|&&i| kl[i] != kr[i]).count();
    assert!(
        own * 10 >= parted.len() * 9,
        "only {own} of {} parted frames have two kernels",
        parted.len()
    );
    for &i in &parted {
        assert!(
            (kl[i] - pl[i]).abs() <= 0.1 + 1e-3,
            "frame {i}: left kernel {} for pupil {}",
            kl[i],
            pl[i]
        );
        assert!(
            (kr[i] - pr[i]).abs() <= 0.1 + 1e-3,
            "frame {i}: right kernel {} for pupil {}",
            kr[i],
            pr[i]
        );
    }
    let _ = std::fs::remove_dir_all(&dir);
}

/// A panorama bright on one side of the view and dark on the other, and
/// an EyeLink recording whose left eye looks at the bright side while the
/// right eye looks at the dark side: each eye pools and adapts at its own
/// gaze.
#[test]
fn per_eye_gaze_lands_in_its_own_view() {
    let dir = tmp("stereo-gaze");
    std::fs::create_dir_all(&dir).expect("dir");
    // Equirectangular, 256×128: the view looks at its centre (yaw 0), so
    // with a 60° field the left of the view is bright, the right dark.
    let (w, h) = (256, 128);
    let pixels = (0..w * h)
        .map(|i| {
            if i % w < w / 2 {
                [100.0f32; 3]
            } else {
                [0.5f32; 3]
            }
        })
        .collect();
    let pano = RgbImage::from_pixels(w, h, pixels).expect("image");
    let scene = dir.join("split.exr");
    gazelight_vision::scene::write_exr(&scene, &pano).expect("exr");
    // 2 s at 500 Hz, 1920×1080 display: left eye at x = 20 %, right eye at
    // x = 80 %, both at mid height; pupils in EyeLink area units.
    let mut asc = String::from(
        "MSG\t1 DISPLAY_COORDS 0 0 1919 1079\nSTART\t1000 \tLEFT\tRIGHT\tSAMPLES\tEVENTS\nPUPIL\tAREA\n",
    );
    for i in 0..1000 {
        let t = 1000 + 2 * i;
        asc.push_str(&format!(
            "{t}\t 384.0\t 540.0\t 1400.0\t 1536.0\t 540.0\t 1400.0\t.....\n"
        ));
    }
    let rec = dir.join("split.asc");
    std::fs::write(&rec, asc).expect("asc");
    let out_dir = dir.join("out");
    let out = gazelight(&[
        "replay",
        rec.to_str().unwrap(),
        "--stereo",
        "--scene",
        scene.to_str().unwrap(),
        "--luminance-scale",
        "1",
        "--yaw-deg",
        "0",
        "--pitch-deg",
        "0",
        "--hfov-deg",
        "60",
        "--size",
        "120x80",
        "--backend",
        "cpu",
        "--no-frames",
        "--out",
        out_dir.to_str().unwrap(),
    ]);
    success(&out);
    let csv = Csv::read(&out_dir.join("timeline.csv"));
    let last = csv.rows.len() - 1;
    let at = |name: &str| csv.f64s(name)[last];
    assert!(
        (at("gaze_u_left") - 0.2).abs() < 0.01,
        "left gaze {}",
        at("gaze_u_left")
    );
    assert!(
        (at("gaze_u_right") - 0.8).abs() < 0.01,
        "right gaze {}",
        at("gaze_u_right")
    );
    let (tl, tr) = (at("target_cd_m2_left"), at("target_cd_m2_right"));
    eprintln!("pooled: left {tl:.3} cd/m², right {tr:.3} cd/m²");
    // The left eye looks at 100 cd/m², the right at 0.5 cd/m²; pooling
    // weights the neighbourhood, so ask for a clear separation only.
    assert!(tl > 30.0 && tr < 5.0, "left {tl}, right {tr}");
    let (al, ar) = (at("adaptation_cd_m2_left"), at("adaptation_cd_m2_right"));
    assert!(al > 5.0 * ar, "adaptation left {al}, right {ar}");
    let _ = std::fs::remove_dir_all(&dir);
}

/// `run --stereo` against the pyzmq Pupil peer (whose eyes differ: 3.75
/// and 4.25 mm): per-eye columns follow each eye's pupil, psf.csv names the
/// view of each kernel, and the frames are left | right.
#[test]
fn stereo_run_follows_each_eye() {
    if !python_ready() {
        eprintln!("SKIP: python3 with pyzmq + msgpack is not available");
        return;
    }
    let peer = spawn_peer_any_port("200", "30", &[]);
    let port = peer.remote_port;
    let dir = tmp("stereo-run");
    let child = std::process::Command::new(env!("CARGO_BIN_EXE_gazelight"))
        .args([
            "run",
            "--source",
            &format!("pupil://127.0.0.1:{port}"),
            "--stereo",
            "--headless",
            "--backend",
            "cpu",
            "--size",
            "96x80",
            "--fps",
            "30",
            // A cap for a hung run only: the run is ended (SIGINT) once
            // the events the checks need are on disk.
            "--secs",
            "120",
            "--out",
            dir.to_str().unwrap(),
        ])
        .env("RUST_LOG", "warn")
        .stdout(std::process::Stdio::piped())
        .stderr(std::process::Stdio::piped())
        .spawn()
        .expect("spawn");
    // The events, not a duration: each eye's kernel for its pupil
    // installed (psf.csv; the PSF worker runs at idle priority, so on a
    // loaded machine that takes as long as the machine makes it take),
    // then 30 frames on the timeline after both. Both files are flushed
    // at least every second.
    let started = std::time::Instant::now();
    let kernels_at = loop {
        let kernels_at = [("left", 4.25), ("right", 3.75)].map(|(view, want)| {
            complete_rows(&dir.join("psf.csv"))
                .iter()
                .find(|r| {
                    (r["view"] == view || r["view"] == "both")
                        && r["pupil_mm"]
                            .parse::<f64>()
                            .is_ok_and(|p| (p - want).abs() <= 0.1 + 1e-3)
                })
                .and_then(|r| r["t_secs"].parse().ok())
                .unwrap_or(f64::NAN)
        });
        let after = kernels_at[0].max(kernels_at[1]);
        let frames_after = complete_rows(&dir.join("timeline.csv"))
            .iter()
            .filter(|r| r["t_secs"].parse::<f64>().is_ok_and(|t| t >= after))
            .count();
        if after.is_finite() && frames_after >= 30 {
            break kernels_at;
        }
        assert!(
            started.elapsed() < Duration::from_secs(110),
            "kernels for the pupils at t = {kernels_at:?} s, {frames_after} frames after"
        );
        std::thread::sleep(Duration::from_millis(100));
    };
    // SAFETY: a plain signal to the child this test spawned.
    unsafe { libc::kill(child.id() as i32, libc::SIGINT) };
    let out = wait_bounded(child, Duration::from_secs(60));
    drop(peer);
    let stdout = success(&out);
    eprintln!("{stdout}");
    let csv = Csv::read(&dir.join("timeline.csv"));
    let n = csv.rows.len();
    assert!(n > 30, "{n} frames");
    let t = csv.f64s("t_secs");
    // The frames after both kernels were installed.
    let settled = |name: &str| -> Vec<f64> {
        let after = kernels_at[0].max(kernels_at[1]);
        csv.f64s(name)
            .into_iter()
            .zip(&t)
            .filter(|(_, t)| **t >= after)
            .map(|(v, _)| v)
            .collect()
    };
    let tail = |name: &str| median(settled(name));
    // Pupil's eye 1 is the left eye (3D diameters 4.25 mm), eye 0 the right
    // (3.75 mm).
    // (The live timeline's measured pupils per eye; each view's aperture.)
    assert!(
        (tail("pupil_left_mm") - 4.25).abs() < 0.05,
        "{}",
        tail("pupil_left_mm")
    );
    assert!(
        (tail("pupil_right_mm") - 3.75).abs() < 0.05,
        "{}",
        tail("pupil_right_mm")
    );
    assert!((tail("aperture_mm_left") - 4.25).abs() < 0.05);
    assert!((tail("aperture_mm_right") - 3.75).abs() < 0.05);
    assert!((tail("psf_pupil_mm_left") - 4.25).abs() <= 0.1 + 1e-3);
    assert!((tail("psf_pupil_mm_right") - 3.75).abs() <= 0.1 + 1e-3);
    let psf = Csv::read(&dir.join("psf.csv"));
    let views = psf.strs("view");
    assert!(
        views.iter().any(|v| v == "left") && views.iter().any(|v| v == "right"),
        "{views:?}"
    );
    let frames: Vec<_> = std::fs::read_dir(dir.join("frames"))
        .expect("frames")
        .flatten()
        .collect();
    assert!(!frames.is_empty());
    assert_eq!(png_size(&frames[0].path()), (192, 80));
    let _ = std::fs::remove_dir_all(&dir);
}

/// A source with only a binocular gaze (the demo's synthetic trace) in
/// stereo: said once in the summary and in session.json.
#[test]
fn a_binocular_only_source_is_reported_in_stereo() {
    let dir = tmp("stereo-binocular");
    let out = gazelight(&[
        "render",
        "--stereo",
        "--size",
        "64x48",
        "--frames",
        "6",
        "--backend",
        "cpu",
        "--no-frames",
        "--out",
        dir.to_str().expect("utf-8"),
    ]);
    let stdout = success(&out);
    let said = stdout
        .lines()
        .filter(|l| l.contains("the binocular gaze stood in for both eyes"))
        .count();
    assert_eq!(said, 1, "{stdout}");
    let session: serde_json::Value =
        serde_json::from_slice(&std::fs::read(dir.join("session.json")).expect("session.json"))
            .expect("JSON");
    let per_eye = &session["settings"]["gaze.per_eye"];
    assert_eq!(
        per_eye["value"]["own_gaze_frames"],
        serde_json::json!([0, 0]),
        "{per_eye}"
    );
    assert!(
        per_eye["note"]
            .as_str()
            .is_some_and(|n| n.contains("no per-eye gaze")),
        "{per_eye}"
    );
    let _ = std::fs::remove_dir_all(&dir);
}
