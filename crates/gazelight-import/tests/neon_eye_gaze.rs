#![allow(clippy::unwrap_used, clippy::expect_used)] // test code may panic on a failed setup
//! Per-eye gaze from the Neon demo recording (`shared/data/eye/neon-demo`):
//! checked against an independent Python computation
//! (`tests/neon_eye_gaze/reference.py`, its output committed beside it),
//! against Neon's own binocular gaze, and with a missing or damaged
//! `calibration.bin`.

use std::path::{Path, PathBuf};

use gazelight_eye::{GazeEyes, Sample};
use gazelight_import::neon::scene_camera::angle_deg;
use gazelight_import::neon::{Dtype, NeonImporter, PerEyeGaze, SCENE_CAMERA_PX, SceneCamera};
use gazelight_import::{self as import, Importer};

const ROWS: usize = 1788;

fn demo() -> PathBuf {
    gazelight_test_support::data_path("eye").join("neon-demo")
}

fn reference(name: &str) -> String {
    let p = Path::new(env!("CARGO_MANIFEST_DIR"))
        .join("tests/neon_eye_gaze")
        .join(name);
    std::fs::read_to_string(&p).unwrap_or_else(|e| panic!("{}: {e}", p.display()))
}

/// One eye_state row's samples: (t, binocular px, right px, left px).
#[derive(Clone, Copy, Debug, Default)]
struct Row {
    t: f64,
    bino: Option<[f64; 2]>,
    eye: [Option<[f64; 2]>; 2],
}

/// Imports the demo with `mode`; rows in eye_state order (a right pupil
/// sample starts a row; the binocular gaze of the same time joins it).
fn rows(mode: PerEyeGaze) -> (Vec<Row>, gazelight_import::EyeGazeReport) {
    let mut imp = NeonImporter::open_with(&demo(), mode).unwrap();
    let mut rows: Vec<Row> = Vec::new();
    let px = |uv: [f32; 2]| {
        [
            f64::from(uv[0] * SCENE_CAMERA_PX[0]),
            f64::from(uv[1] * SCENE_CAMERA_PX[1]),
        ]
    };
    for s in imp.by_ref() {
        match s.unwrap() {
            Sample::Pupil(p) if p.eye == 0 => rows.push(Row {
                t: p.t_secs,
                ..Row::default()
            }),
            Sample::Gaze(g) => {
                let row = rows.last_mut().expect("a row before its gaze");
                assert_eq!(g.t_secs, row.t, "gaze at the row's time");
                let slot = match g.eyes {
                    GazeEyes::Binocular => &mut row.bino,
                    GazeEyes::Right => &mut row.eye[0],
                    GazeEyes::Left => &mut row.eye[1],
                };
                assert!(slot.is_none(), "one gaze of each kind per row: {g:?}");
                *slot = Some(px(g.gaze_uv));
            }
            _ => {}
        }
    }
    assert_eq!(imp.warnings().skipped_records, 0, "{:?}", imp.warnings());
    (rows, imp.eye_gaze().unwrap().clone())
}

fn camera() -> SceneCamera {
    SceneCamera::load(&demo().join("calibration.bin")).unwrap()
}

fn percentile(v: &mut [f64], p: f64) -> f64 {
    v.sort_by(f64::total_cmp);
    v[((v.len() - 1) as f64 * p).round() as usize]
}

#[test]
fn calibration_bin_is_read_as_pupil_labs_lays_it_out() {
    let cam = camera();
    assert_eq!(cam.serial, "578846"); // info.json's module_serial_number
    // fx, fy, cx, cy as numpy reads them (reference.py's layout).
    let [fx, fy, cx, cy] = cam.intrinsics;
    assert!((fx - 888.411).abs() < 1e-3 && (fy - 888.359).abs() < 1e-3);
    assert!((cx - 805.098).abs() < 1e-3 && (cy - 618.638).abs() < 1e-3);
    assert!((cam.distortion[0] + 0.130192).abs() < 1e-6);
    // The rational model folds back at tan ≈ 2.29 (66°) for this camera.
    assert!(
        (cam.max_tan_angle - 2.293).abs() < 0.01,
        "{}",
        cam.max_tan_angle
    );
    // Unprojection inverts projection.
    for px in [
        [100.0, 100.0],
        [805.0, 618.0],
        [1500.0, 1100.0],
        [100.0, 1100.0],
    ] {
        let n = cam.unproject(px).unwrap();
        let back = cam.project_normalized(n).unwrap();
        assert!((back[0] - px[0]).hypot(back[1] - px[1]) < 1e-6, "{px:?}");
    }
    // The image's extreme corner lies beyond the largest radius the
    // distortion model reaches (it folds back first): no ray, not a wrong one.
    assert!(cam.unproject([1599.0, 1199.0]).is_none());
}

#[test]
fn per_eye_gaze_matches_the_python_reference() {
    let (optical, report_o) = rows(PerEyeGaze::OpticalAxis);
    let (corrected, report_c) = rows(PerEyeGaze::KappaCorrected);
    assert_eq!(optical.len(), ROWS);
    assert_eq!(corrected.len(), ROWS);
    assert_eq!(report_o.emitted, [ROWS as u64; 2]);
    assert_eq!(report_o.missing, [0, 0]);
    assert_eq!(report_o.correction_deg, [None, None]);
    assert!(report_c.per_eye && report_c.reason.is_none());

    let mut checked = 0;
    for line in reference("reference.csv").lines().skip(1) {
        let f: Vec<&str> = line.split(',').collect();
        let row: usize = f[0].parse().unwrap();
        let eye = match f[2] {
            "right" => 0,
            "left" => 1,
            other => panic!("{other}"),
        };
        let v = |i: usize| f[i].parse::<f64>().unwrap();
        let uv = |p: [f64; 2]| [p[0] / 1600.0, p[1] / 1200.0];
        let o = uv(optical[row].eye[eye].unwrap());
        let c = uv(corrected[row].eye[eye].unwrap());
        // The optical axis: the same arithmetic (f32 inputs), 1e-5 of the
        // image ≈ 0.02 px.
        assert!(
            (o[0] - v(3)).abs() < 1e-5 && (o[1] - v(4)).abs() < 1e-5,
            "row {row} {}: {o:?} vs {} {}",
            f[2],
            v(3),
            v(4)
        );
        // Corrected: the importer's median is a histogram bin's centre
        // (0.0005 normalised ≈ 0.44 px); 5e-4 of the image ≈ 0.8 px.
        assert!(
            (c[0] - v(5)).abs() < 5e-4 && (c[1] - v(6)).abs() < 5e-4,
            "row {row} {}: {c:?} vs {} {}",
            f[2],
            v(5),
            v(6)
        );
        checked += 1;
    }
    assert_eq!(checked, 18);

    // The offsets themselves, in degrees (atan of the normalised offset).
    for line in reference("kappa.csv").lines().skip(1) {
        let f: Vec<&str> = line.split(',').collect();
        let eye = if f[0] == "right" { 0 } else { 1 };
        let want = [f[1], f[2]].map(|s| s.parse::<f64>().unwrap().atan().to_degrees());
        let got = report_c.correction_deg[eye].expect("corrected");
        for a in 0..2 {
            assert!(
                (got[a] - want[a]).abs() < 0.03,
                "{}: {got:?} vs {want:?}",
                f[0]
            );
        }
    }
}

/// The two eyes' gaze against Neon's binocular gaze: prints the figures
/// for both modes and checks them.
#[test]
fn per_eye_gaze_agrees_with_the_binocular_gaze_and_the_eyes_differ() {
    let cam = camera();
    for mode in [PerEyeGaze::OpticalAxis, PerEyeGaze::KappaCorrected] {
        let (rows, report) = rows(mode);
        let mut mean_to_bino = Vec::new();
        let mut eye_to_bino = [Vec::new(), Vec::new()];
        let mut left_right = Vec::new();
        for r in &rows {
            let (Some(b), Some(rt), Some(lt)) = (r.bino, r.eye[0], r.eye[1]) else {
                continue;
            };
            // The mean of the two eyes' directions, as a pixel.
            let (rr, rl) = (cam.ray(rt).unwrap(), cam.ray(lt).unwrap());
            let m = [rr[0] + rl[0], rr[1] + rl[1], rr[2] + rl[2]];
            let mpx = cam.project_normalized([m[0] / m[2], m[1] / m[2]]).unwrap();
            mean_to_bino.push(angle_deg(&cam, mpx, b).unwrap());
            eye_to_bino[0].push(angle_deg(&cam, rt, b).unwrap());
            eye_to_bino[1].push(angle_deg(&cam, lt, b).unwrap());
            left_right.push(angle_deg(&cam, lt, rt).unwrap());
        }
        assert_eq!(mean_to_bino.len(), ROWS);
        let stats = |v: &mut Vec<f64>| (percentile(v, 0.5), percentile(v, 0.95));
        let (m50, m95) = stats(&mut mean_to_bino);
        let (r50, r95) = stats(&mut eye_to_bino[0]);
        let (l50, l95) = stats(&mut eye_to_bino[1]);
        let (d50, d95) = stats(&mut left_right);
        let differ = left_right.iter().filter(|&&d| d > 0.5).count();
        eprintln!(
            "{mode:?}: mean(L,R) to binocular median {m50:.2}° p95 {m95:.2}°; right to \
             binocular {r50:.2}°/{r95:.2}°, left {l50:.2}°/{l95:.2}°; left to right {d50:.2}°/\
             {d95:.2}°, {differ} of {ROWS} rows > 0.5° apart; correction {:?}",
            report.correction_deg
        );
        // Not the same gaze twice: most rows differ by over half a degree.
        assert!(differ > ROWS / 2, "the eyes' gaze differs in {differ} rows");
        match mode {
            PerEyeGaze::OpticalAxis => {
                // Kappa: the raw axes sit a few degrees off (measured 4.2° / 6.2°).
                assert!(m50 < 5.0 && m95 < 7.5, "{m50} {m95}");
            }
            _ => {
                // The offsets align each eye's median with the binocular gaze.
                assert!(m50 < 1.5 && m95 < 4.0, "{m50} {m95}");
                assert!(r50 < 2.0 && l50 < 2.0, "{r50} {l50}");
            }
        }
    }
}

/// The horizontal difference of the two eyes' gaze follows the
/// horizontal angle between the two optical axes as the raw eye_state
/// file holds them (read here with the crate's dtype parser only): the
/// left sample is the left eye's, and vergence moves them apart.
#[test]
fn left_right_difference_follows_the_eyes_vergence() {
    let dir = demo();
    let dtype = Dtype::load(&dir.join("eye_state.dtype")).unwrap();
    let raw = std::fs::read(dir.join("eye_state ps1.raw")).unwrap();
    let f = |rec: &[u8], name: &str| {
        let (_, off) = dtype.field(name).unwrap();
        f64::from(f32::from_le_bytes(rec[off..off + 4].try_into().unwrap()))
    };
    let vergence: Vec<f64> = raw
        .chunks_exact(dtype.record_size)
        .map(|rec| {
            let yaw = |s: &str| {
                f(rec, &format!("optical_axis_{s}_x"))
                    .atan2(f(rec, &format!("optical_axis_{s}_z")))
                    .to_degrees()
            };
            yaw("left") - yaw("right")
        })
        .collect();
    let cam = camera();
    let (rows, _) = rows(PerEyeGaze::KappaCorrected);
    let horiz: Vec<f64> = rows
        .iter()
        .map(|r| {
            let yaw = |p: [f64; 2]| {
                let n = cam.unproject(p).unwrap();
                n[0].atan().to_degrees()
            };
            yaw(r.eye[1].unwrap()) - yaw(r.eye[0].unwrap())
        })
        .collect();
    let n = vergence.len() as f64;
    let mean = |v: &[f64]| v.iter().sum::<f64>() / n;
    let (mv, mh) = (mean(&vergence), mean(&horiz));
    let cov: f64 = vergence
        .iter()
        .zip(&horiz)
        .map(|(a, b)| (a - mv) * (b - mh))
        .sum();
    let sd = |v: &[f64], m: f64| v.iter().map(|a| (a - m) * (a - m)).sum::<f64>().sqrt();
    let r = cov / (sd(&vergence, mv) * sd(&horiz, mh));
    eprintln!(
        "left−right horizontal gaze vs optical-axis vergence: r = {r:.4}, vergence {:.2}° ± {:.2}°",
        mv,
        sd(&vergence, mv) / n.sqrt()
    );
    assert!(r > 0.95, "r = {r}");
}

/// Copies the demo recording to a fresh temporary directory.
fn copy_demo(tag: &str) -> PathBuf {
    let dir =
        std::env::temp_dir().join(format!("gazelight-neon-eyes-{tag}-{}", std::process::id()));
    let _ = std::fs::remove_dir_all(&dir);
    std::fs::create_dir_all(&dir).unwrap();
    for e in std::fs::read_dir(demo()).unwrap() {
        let e = e.unwrap();
        std::fs::copy(e.path(), dir.join(e.file_name())).unwrap();
    }
    dir
}

#[test]
fn missing_calibration_bin_is_a_warning_and_binocular_gaze_only() {
    let dir = copy_demo("missing");
    std::fs::remove_file(dir.join("calibration.bin")).unwrap();
    let mut imp = import::open(&dir).unwrap();
    let mut eyes = [0u64; 3];
    for s in imp.by_ref() {
        if let Sample::Gaze(g) = s.unwrap() {
            eyes[g.eyes as usize] += 1;
        }
    }
    assert_eq!(eyes, [ROWS as u64, 0, 0], "binocular only");
    let report = imp.eye_gaze().expect("Neon reports per-eye gaze");
    assert!(!report.per_eye);
    assert!(
        report
            .reason
            .as_deref()
            .unwrap()
            .contains("calibration.bin")
    );
    let w = imp.warnings();
    assert_eq!(w.skipped_records, 0, "a note, not a skipped record");
    assert!(
        w.messages.iter().any(|m| m.contains("calibration.bin")
            && m.contains("binocular gaze stands in for both eyes")),
        "{w:?}"
    );
    // The summary says so.
    let mut imp = import::open(&dir).unwrap();
    let s = gazelight_import::summary::summarize_importer(
        imp.as_mut(),
        gazelight_eye::filter::FilterChain::with_defaults(),
    )
    .unwrap();
    let text = s.to_string();
    assert!(
        text.contains("per-eye gaze: none") && text.contains("stands in for both eyes"),
        "{text}"
    );
    std::fs::remove_dir_all(&dir).ok();
}

#[test]
fn damaged_calibration_bin_is_an_error_naming_it() {
    let dir = copy_demo("damaged");
    let path = dir.join("calibration.bin");
    let orig = std::fs::read(&path).unwrap();
    let mut flipped = orig.clone();
    flipped[20] ^= 0x40; // inside fx
    let mut bad_version = orig.clone();
    bad_version[0] = 7;
    for (what, bytes, needle) in [
        ("truncated", orig[..400].to_vec(), "400 bytes"),
        ("empty", Vec::new(), "0 bytes"),
        (
            "too long",
            [orig.clone(), vec![0; 10]].concat(),
            "813 bytes",
        ),
        ("a flipped bit", flipped, "CRC-32 mismatch"),
        ("another version", bad_version, "version 7"),
    ] {
        std::fs::write(&path, &bytes).unwrap();
        let err = match import::open(&dir) {
            Ok(_) => panic!("{what}: opened"),
            Err(e) => e.to_string(),
        };
        assert!(
            err.contains("calibration.bin") && err.contains(needle),
            "{what}: {err}"
        );
    }
    // Binocular-only mode does not read it.
    assert!(NeonImporter::open_with(&dir, PerEyeGaze::Off).is_ok());
    std::fs::remove_dir_all(&dir).ok();
}

/// Rows whose eye geometry is NaN or a zero vector give that eye no gaze,
/// counted; the other eye and the pupils are unaffected.
#[test]
fn nan_and_zero_eye_geometry_give_no_gaze_and_are_counted() {
    let dir = copy_demo("nan");
    let raw_path = dir.join("eye_state ps1.raw");
    let mut raw = std::fs::read(&raw_path).unwrap();
    let dtype = Dtype::load(&dir.join("eye_state.dtype")).unwrap();
    let mut set = |row: usize, field: &str, v: f32| {
        let (_, off) = dtype.field(field).unwrap();
        let at = row * dtype.record_size + off;
        raw[at..at + 4].copy_from_slice(&v.to_le_bytes());
    };
    set(10, "optical_axis_left_x", f32::NAN);
    for a in ["x", "y", "z"] {
        set(11, &format!("optical_axis_right_{a}"), 0.0);
        set(12, &format!("eyeball_center_left_{a}"), 0.0);
    }
    set(13, "eyeball_center_right_z", f32::INFINITY);
    std::fs::write(&raw_path, &raw).unwrap();

    let mut imp = NeonImporter::open_with(&dir, PerEyeGaze::KappaCorrected).unwrap();
    let (mut pupils, mut eye_gaze) = (0, [0u64; 2]);
    for s in imp.by_ref() {
        match s.unwrap() {
            Sample::Pupil(_) => pupils += 1,
            Sample::Gaze(g) if g.eyes == GazeEyes::Right => eye_gaze[0] += 1,
            Sample::Gaze(g) if g.eyes == GazeEyes::Left => eye_gaze[1] += 1,
            _ => {}
        }
    }
    assert_eq!(pupils, 2 * ROWS);
    let report = imp.eye_gaze().unwrap();
    assert_eq!(report.missing, [2, 2], "{report:?}");
    assert_eq!(report.emitted, eye_gaze);
    assert_eq!(eye_gaze, [ROWS as u64 - 2, ROWS as u64 - 2]);
    std::fs::remove_dir_all(&dir).ok();
}
