#![allow(clippy::unwrap_used, clippy::expect_used)] // test and bench code may panic on a failed setup
//! The veil of a lamp away from the gaze (issue 46, "Must show"): a dark
//! field (0.02 cd/m²) with one round lamp (2·10⁵ cd/m², 0.6° radius) at
//! 2°–60° from the gaze; the retinal luminance at the gaze in the image
//! `gazelight render --exr` writes is the field plus the CIE 146:2002 veil
//! of the lamp within 10 %. The expected veil is computed here from the
//! published equation, integrated over the lamp's disc with the cosine of
//! each direction to the line of sight (the illuminance at the eye on it),
//! not from the code under test. And the radial profile around a lamp at
//! the gaze falls monotonically out to 60°, no 1° step losing more than a
//! third (no ring where the window's kernel ends).

mod common;

use std::f64::consts::{PI, TAU};
use std::path::Path;

use common::{gazelight, tmp};
use gazelight_vision::RgbImage;
use gazelight_vision::scene::{LuminanceScale, Scene, write_exr};

/// The lamp's luminance, cd/m² (the table).
const LAMP_CD_M2: f64 = 2e5;
/// The lamp's angular radius, degrees.
const LAMP_RADIUS_DEG: f64 = 0.6;
/// The dark field, cd/m².
const FIELD_CD_M2: f64 = 0.02;
/// Rendered view of the lamp table, pixels per side.
const VIEW_PX: usize = 400;
/// Rendered view of the radial profile (130° wide: 3.3 px/deg at its
/// centre, the lamp 4 px across).
const PROFILE_PX: usize = 800;
/// The panorama: 0.1° per pixel.
const PANO_W: usize = 3600;
const PANO_H: usize = 1800;

/// CIE 146:2002 General Disability Glare equation, L_veil / E_glare in
/// sr⁻¹ (θ in degrees, A age in years, p pigmentation).
fn cie146(theta_deg: f64, age_years: f64, p: f64) -> f64 {
    10.0 / theta_deg.powi(3)
        + (5.0 / theta_deg.powi(2) + 0.1 * p / theta_deg) * (1.0 + (age_years / 62.5).powi(4))
        + 0.0025 * p
}

/// Unit vector of longitude/latitude (radians): x right, y up, z ahead.
fn dir(lon: f64, lat: f64) -> [f64; 3] {
    [lat.cos() * lon.sin(), lat.sin(), lat.cos() * lon.cos()]
}

fn dot(a: [f64; 3], b: [f64; 3]) -> f64 {
    a[0] * b[0] + a[1] * b[1] + a[2] * b[2]
}

/// An equirectangular panorama of the dark field with the lamp straight
/// ahead (longitude 0, latitude 0): each pixel near it holds the field plus
/// the lamp times the fraction of the pixel its disc covers (16 × 16
/// samples).
fn lamp_panorama() -> RgbImage {
    let mut pano = RgbImage::new(PANO_W, PANO_H);
    for p in &mut pano.pixels {
        *p = [FIELD_CD_M2 as f32; 3];
    }
    let cos_r = LAMP_RADIUS_DEG.to_radians().cos();
    const SS: usize = 16;
    let (cx, cy) = (PANO_W / 2, PANO_H / 2);
    for y in cy - 8..cy + 8 {
        for x in cx - 8..cx + 8 {
            let mut covered = 0usize;
            for sy in 0..SS {
                for sx in 0..SS {
                    let u = (x as f64 + (sx as f64 + 0.5) / SS as f64) / PANO_W as f64;
                    let v = (y as f64 + (sy as f64 + 0.5) / SS as f64) / PANO_H as f64;
                    if dir((u - 0.5) * TAU, (0.5 - v) * PI)[2] >= cos_r {
                        covered += 1;
                    }
                }
            }
            let f = covered as f64 / (SS * SS) as f64;
            let value = (FIELD_CD_M2 * (1.0 - f) + LAMP_CD_M2 * f) as f32;
            *pano.get_mut(x, y) = [value; 3];
        }
    }
    pano
}

/// The CIE 146 veil at the direction `gaze` (unit vector) of the lamp's
/// disc: Σ L · dΩ · cos θ · CIE146(θ) over 200 × 200 samples of the disc.
fn expected_veil(gaze: [f64; 3]) -> f64 {
    let r = LAMP_RADIUS_DEG.to_radians();
    let n = 200;
    let (mut sum, mut count) = (0.0, 0usize);
    for i in 0..n {
        for j in 0..n {
            let a = (2.0 * (i as f64 + 0.5) / n as f64 - 1.0) * r;
            let b = (2.0 * (j as f64 + 0.5) / n as f64 - 1.0) * r;
            if a.hypot(b) > r {
                continue;
            }
            // The tangent plane at the lamp's centre (0, 0, 1).
            let q = (1.0 + a * a + b * b).sqrt();
            let d = [a / q, b / q, 1.0 / q];
            let c = dot(d, gaze);
            let theta = c.clamp(-1.0, 1.0).acos().to_degrees();
            sum += c.max(0.0) * cie146(theta, 25.0, 0.5);
            count += 1;
        }
    }
    let omega = TAU * (1.0 - r.cos());
    LAMP_CD_M2 * omega * sum / count as f64
}

/// Renders two frames of `scene` looking at `yaw_deg` (the view's axis)
/// with `hfov_deg`, the gaze at `gaze_uv`, and returns the retinal image
/// of the second, read back from its EXR.
fn render_retinal(
    dir: &Path,
    scene: &Path,
    px: usize,
    yaw_deg: f64,
    hfov_deg: f64,
    gaze_uv: [f64; 2],
    extra: &[&str],
) -> RgbImage {
    std::fs::create_dir_all(dir).expect("render dir");
    let trace = dir.join("trace.csv");
    let (u, v) = (gaze_uv[0], gaze_uv[1]);
    std::fs::write(
        &trace,
        format!("t_secs,gaze_u,gaze_v,pupil_mm\n0,{u},{v},4\n1,{u},{v},4\n"),
    )
    .expect("trace");
    let out = dir.join("out");
    let size = format!("{px}x{px}");
    let (hfov, yaw) = (hfov_deg.to_string(), yaw_deg.to_string());
    let mut args = vec![
        "render",
        "--scene",
        scene.to_str().expect("utf-8"),
        "--luminance-scale",
        "1",
        "--trace",
        trace.to_str().expect("utf-8"),
        "--size",
        &size,
        "--hfov-deg",
        &hfov,
        "--yaw-deg",
        &yaw,
        "--pitch-deg",
        "0",
        "--frames",
        "2",
        "--backend",
        "cpu",
        "--exr",
        "--out",
        out.to_str().expect("utf-8"),
    ];
    args.extend_from_slice(extra);
    let run = gazelight(&args);
    assert!(
        run.status.success(),
        "render failed: {}",
        String::from_utf8_lossy(&run.stderr)
    );
    let exr = out.join("frames").join("frame_00001.exr");
    let back = Scene::load(&exr, LuminanceScale::CdM2PerUnit { factor: 1.0 }).expect("retinal EXR");
    assert_eq!((back.image.width, back.image.height), (px, px));
    back.image
}

fn lum(p: [f32; 3]) -> f64 {
    0.2126 * f64::from(p[0]) + 0.7152 * f64::from(p[1]) + 0.0722 * f64::from(p[2])
}

/// The pinhole view: focal length in pixels for `hfov_deg` over
/// [`VIEW_PX`], and the view-space direction of plane point (`x`, `y`)
/// (pixels, y down) for a view turned `yaw_deg` to the right, in the
/// panorama's frame (x right, y up, z at longitude 0).
fn focal_px(hfov_deg: f64) -> f64 {
    focal_px_of(VIEW_PX, hfov_deg)
}

fn focal_px_of(px: usize, hfov_deg: f64) -> f64 {
    (px as f64 / 2.0) / (hfov_deg.to_radians() / 2.0).tan()
}

fn pixel_dir(x: f64, y: f64, yaw_deg: f64, hfov_deg: f64) -> [f64; 3] {
    let f = focal_px(hfov_deg);
    let c = VIEW_PX as f64 / 2.0;
    let (tx, ty) = ((x - c) / f, -(y - c) / f);
    let q = (1.0 + tx * tx + ty * ty).sqrt();
    let v = [tx / q, ty / q, 1.0 / q];
    let (s, co) = (yaw_deg.to_radians().sin(), yaw_deg.to_radians().cos());
    [v[0] * co + v[2] * s, v[1], -v[0] * s + v[2] * co]
}

/// The table: the lamp at 2°, 5°, 15°, 25°, 35° and 60° from the
/// gaze. The view is turned so that the gaze and the lamp lie
/// symmetrically about its axis, the gaze on a pixel's centre.
#[test]
fn veil_at_the_gaze_is_cie_146_from_2_to_60_degrees() {
    let dir = tmp("far-veil");
    let scene = dir.join("lamp.exr");
    write_exr(&scene, &lamp_panorama()).expect("scene");
    let off = dir.join("far-off.toml");
    std::fs::write(&off, "[pipeline.glare]\nfar_field = false\n").expect("config");
    // The far field is on by default; said here so that the table measures
    // it whatever the default.
    let on = dir.join("far-on.toml");
    std::fs::write(&on, "[pipeline.glare]\nfar_field = true\n").expect("config");
    let mut failures = Vec::new();
    for theta in [2.0f64, 5.0, 15.0, 25.0, 35.0, 60.0] {
        let hfov = (theta + 30.0).max(40.0);
        let f = focal_px(hfov);
        // The view looks half-way: the lamp θ/2 right of its axis, the
        // gaze θ/2 left, on the centre of its pixel.
        let yaw = -theta / 2.0;
        let gx = (VIEW_PX as f64 / 2.0 - f * (theta / 2.0).to_radians().tan()).floor() + 0.5;
        let gy = VIEW_PX as f64 / 2.0 + 0.5;
        let gaze_uv = [gx / VIEW_PX as f64, gy / VIEW_PX as f64];
        let img = render_retinal(
            &dir.join(format!("t{theta}")),
            &scene,
            VIEW_PX,
            yaw,
            hfov,
            gaze_uv,
            &["--config", on.to_str().expect("utf-8")],
        );
        // The lamp lies where the geometry puts it (the sign of yaw).
        let (mut sx, mut sw) = (0.0, 0.0);
        for y in 0..VIEW_PX {
            for x in 0..VIEW_PX {
                let l = lum(img.get(x, y));
                if l > 1e4 {
                    sx += l * (x as f64 + 0.5);
                    sw += l;
                }
            }
        }
        let lamp_x = VIEW_PX as f64 / 2.0 + f * (theta / 2.0).to_radians().tan();
        assert!(
            sw > 0.0 && (sx / sw - lamp_x).abs() < 1.5,
            "lamp at x {} not {lamp_x}",
            sx / sw
        );
        let gaze = pixel_dir(gx, gy, yaw, hfov);
        let angle = dot(gaze, [0.0, 0.0, 1.0]).acos().to_degrees();
        let want = FIELD_CD_M2 + expected_veil(gaze);
        let got = lum(img.get(gx as usize, gy as usize));
        let ratio = got / want;
        // Without the far field (the window kernel alone, as before issue
        // 46), for the record.
        let before = render_retinal(
            &dir.join(format!("t{theta}-off")),
            &scene,
            VIEW_PX,
            yaw,
            hfov,
            gaze_uv,
            &["--config", off.to_str().expect("utf-8")],
        );
        let was = lum(before.get(gx as usize, gy as usize));
        eprintln!(
            "lamp {angle:5.2}° from the gaze: render {got:.4} cd/m² (without the far field {was:.4}), \
             field + CIE 146 veil {want:.4} (×{ratio:.3}), hfov {hfov}°"
        );
        if (ratio - 1.0).abs() > 0.10 {
            failures.push(format!("{angle:.2}°: {got:.4} vs {want:.4} (×{ratio:.3})"));
        }
    }
    assert!(
        failures.is_empty(),
        "not within 10 % of CIE 146: {failures:?}"
    );
    let _ = std::fs::remove_dir_all(&dir);
}

/// Mean luminance of the pixels whose direction lies within half a pixel's
/// angle of `theta_deg` from the view's centre, by the pinhole geometry.
fn ring_luminance(img: &RgbImage, hfov_deg: f64, theta_deg: f64) -> f64 {
    let f = focal_px_of(img.width, hfov_deg);
    let c = img.width as f64 / 2.0;
    let (mut sum, mut n) = (0.0f64, 0usize);
    for y in 0..img.height {
        for x in 0..img.width {
            let r = (x as f64 + 0.5 - c).hypot(y as f64 + 0.5 - c);
            let t = (r / f).atan().to_degrees();
            // Half a pixel's angle at that radius (the radial one).
            let half =
                0.5 * (((r + 0.5) / f).atan() - ((r - 0.5).max(0.0) / f).atan()).to_degrees();
            if (t - theta_deg).abs() <= half.max(0.05) {
                sum += lum(img.get(x, y));
                n += 1;
            }
        }
    }
    assert!(n > 0, "no pixel at {theta_deg}°");
    sum / n as f64
}

/// Around a lamp at the gaze the veil falls monotonically from 2° to 60°;
/// from 7° on (where CIE 146 itself loses less than a third per degree) no
/// 1° step loses more than a third, and from 4° on each 1° step is CIE
/// 146's own within ±10 % (the window kernel's taper from 12° to 20° and
/// the far field beyond it join without a ring); and from 4° to 60° its
/// ratio to the field + CIE 146 veil stays within ±15 % of its median
/// (the median itself is the lamp's flux as the 3.3 px/deg view samples
/// it, printed).
#[test]
fn veil_around_a_lamp_falls_without_a_step_to_60_degrees() {
    let dir = tmp("far-profile");
    let on = dir.join("far-on.toml");
    std::fs::write(&on, "[pipeline.glare]\nfar_field = true\n").expect("config");
    let scene = dir.join("lamp.exr");
    write_exr(&scene, &lamp_panorama()).expect("scene");
    let hfov = 130.0;
    let img = render_retinal(
        &dir.join("p"),
        &scene,
        PROFILE_PX,
        0.0,
        hfov,
        [0.5, 0.5],
        &["--config", on.to_str().expect("utf-8")],
    );
    let (mut prev, mut prev_want) = (f64::INFINITY, f64::INFINITY);
    let mut failures = Vec::new();
    let mut ratios = Vec::new();
    for t in 2..=60 {
        let theta = f64::from(t);
        let v = ring_luminance(&img, hfov, theta);
        let want = FIELD_CD_M2 + expected_veil(dir_at(theta));
        eprintln!(
            "{theta:4}°: {v:.5} cd/m² (field + CIE 146 {want:.5}, ×{:.3})",
            v / want
        );
        if v > prev {
            failures.push(format!("rises at {theta}°: {prev:.5} → {v:.5}"));
        }
        if t >= 7 && v < prev * 2.0 / 3.0 {
            failures.push(format!("step at {theta}°: {prev:.5} → {v:.5}"));
        }
        let step = (v / prev) / (want / prev_want);
        if t >= 5 && (step - 1.0).abs() > 0.10 {
            failures.push(format!(
                "step at {theta}°: ×{:.3}, CIE 146 ×{:.3}",
                v / prev,
                want / prev_want
            ));
        }
        if t >= 4 {
            ratios.push((theta, v / want));
        }
        (prev, prev_want) = (v, want);
    }
    let mut sorted: Vec<f64> = ratios.iter().map(|r| r.1).collect();
    sorted.sort_by(f64::total_cmp);
    let median = sorted[sorted.len() / 2];
    eprintln!("median ratio to the field + CIE 146 veil, 4°–60°: {median:.3}");
    for (theta, r) in ratios {
        if (r / median - 1.0).abs() > 0.15 {
            failures.push(format!("{theta}°: ×{r:.3} against the median ×{median:.3}"));
        }
    }
    assert!(failures.is_empty(), "{failures:?}");
    let _ = std::fs::remove_dir_all(&dir);
}

/// A direction `theta_deg` from straight ahead (to the right).
fn dir_at(theta_deg: f64) -> [f64; 3] {
    dir(theta_deg.to_radians(), 0.0)
}
