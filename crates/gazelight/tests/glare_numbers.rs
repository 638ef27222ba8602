#![allow(clippy::unwrap_used, clippy::expect_used)] // test code may panic on a failed setup
//! Glare along a gaze trace (issue 46 item 5): `render --glare-numbers`
//! writes each frame's CIE 146 veil at the gaze and the DGP and UGR of the
//! eye's line of sight into `timeline.csv`.
//!
//! The scene is a Radiance picture written here byte by byte: a
//! perspective view (VIEW= -vtv, 120° square, 601 px) of a uniform
//! background with one square lamp 45° to the right, both grey RGBE
//! pixels whose luminance the test takes from Radiance's own rule,
//! 179 × (c + ½)·2^(e−136). `render` looks at it through the same
//! perspective, so its view is the picture. A gaze trace holds four gazes:
//! 10°, 20° and ~7° from the lamp, and one 95° away (the lamp behind the
//! line of sight). For each frame, at the gaze the timeline reports:
//!
//! * the veil column equals the CIE 146:2002 veil summed by this test over
//!   the picture's pixels (each pixel's solid angle and direction from the
//!   pinhole geometry), and the lamp's part of it equals E_lamp × f(θ) at
//!   the lamp's centre within 3 % (the glare equation with the lamp's
//!   illuminance L·Ω·cos θ);
//! * veil, DGP and UGR equal `gazelight glare`'s at the same gaze on the
//!   same picture;
//! * with the lamp behind the gaze the numbers are the background's: the
//!   veil of the background alone, DGP = 5.87·10⁻⁵ E_v + 0.159 with the
//!   test's own E_v and no source, UGR 0 (evalglare's value without a
//!   glare source);
//! * `--stereo` writes the same numbers per eye, suffixed `_left` and
//!   `_right`.

mod common;

use std::path::Path;

use common::{gazelight, tmp};

/// The picture: pixels per side and field (square, both directions).
const SIDE_PX: usize = 601;
const FOV_DEG: f64 = 120.0;
/// Background RGBE: (128.5)·2^(124−136) W/sr/m² per channel.
const BACKGROUND_RGBE: [u8; 4] = [128, 128, 128, 124];
/// Lamp RGBE: (128.5)·2^(138−136) W/sr/m² per channel.
const LAMP_RGBE: [u8; 4] = [128, 128, 128, 138];
/// The lamp's pixel columns and rows (5 × 5, centred 45° right, on the
/// horizon).
const LAMP_COLUMNS: std::ops::Range<usize> = 472..477;
const LAMP_ROWS: std::ops::Range<usize> = 298..303;
/// The observer (non-default, so that the flags are seen to reach the
/// numbers).
const AGE_YEARS: f64 = 60.0;
const PIGMENTATION: f64 = 1.0;

/// Radiance's luminance of a grey RGBE pixel, cd/m²: 179 lm/W (Radiance's
/// white efficacy) × (c + ½)·2^(e−136) (Radiance's `colr_color`), the
/// weights 0.265 + 0.670 + 0.065 summing to 1.
fn radiance_grey_cd_m2(rgbe: [u8; 4]) -> f64 {
    179.0 * (f64::from(rgbe[0]) + 0.5) * 2f64.powi(i32::from(rgbe[3]) - 136)
}

/// CIE 146:2002 General Disability Glare equation, L_veil / E_glare, sr⁻¹
/// (θ in degrees, A age in years, p pigmentation).
fn cie146(theta_deg: f64, age_years: f64, p: f64) -> f64 {
    10.0 / theta_deg.powi(3)
        + (5.0 / theta_deg.powi(2) + 0.1 * p / theta_deg) * (1.0 + (age_years / 62.5).powi(4))
        + 0.0025 * p
}

/// Half the image plane's width, tan(FOV/2).
fn half_tan() -> f64 {
    (FOV_DEG.to_radians() / 2.0).tan()
}

/// The unit direction (−z forward, +x right, +y up) through a continuous
/// pixel position of the pinhole picture, and the image-plane coordinates.
fn pixel_dir(px: f64, py: f64) -> [f64; 3] {
    let x = (px / SIDE_PX as f64 - 0.5) * 2.0 * half_tan();
    let y = (0.5 - py / SIDE_PX as f64) * 2.0 * half_tan();
    let n = (x * x + y * y + 1.0).sqrt();
    [x / n, y / n, -1.0 / n]
}

/// A pixel's solid angle, sr: its image-plane area over (1 + x² + y²)^{3/2}.
fn pixel_sr(x: usize, y: usize) -> f64 {
    let step = 2.0 * half_tan() / SIDE_PX as f64;
    let d = pixel_dir(x as f64 + 0.5, y as f64 + 0.5);
    // 1 / (1 + x² + y²)^{3/2} = (−d_z)³.
    step * step * (-d[2]).powi(3)
}

fn is_lamp(x: usize, y: usize) -> bool {
    LAMP_COLUMNS.contains(&x) && LAMP_ROWS.contains(&y)
}

fn write_picture(path: &Path, with_lamp: bool) {
    let mut b = format!(
        "#?RADIANCE\nFORMAT=32-bit_rle_rgbe\nVIEW= -vtv -vh {FOV_DEG} -vv {FOV_DEG}\n\n\
         -Y {SIDE_PX} +X {SIDE_PX}\n"
    )
    .into_bytes();
    for y in 0..SIDE_PX {
        for x in 0..SIDE_PX {
            let p = if with_lamp && is_lamp(x, y) {
                LAMP_RGBE
            } else {
                BACKGROUND_RGBE
            };
            b.extend_from_slice(&p);
        }
    }
    std::fs::write(path, b).unwrap();
}

/// The test's own sums at a gaze: E_v (the plane facing the gaze), the
/// CIE 146 veil of every pixel in front at least 1° away (`glare`'s inner
/// limit), and the lamp's illuminance, its veil and its centre's angle.
struct HandSums {
    e_v: f64,
    veil: f64,
    lamp_e: f64,
    lamp_veil: f64,
    lamp_theta_deg: f64,
}

fn hand_sums(gaze: [f64; 3], with_lamp: bool) -> HandSums {
    let (l_b, l_lamp) = (
        radiance_grey_cd_m2(BACKGROUND_RGBE),
        radiance_grey_cd_m2(LAMP_RGBE),
    );
    let inner_cos = 1f64.to_radians().cos();
    let mut s = HandSums {
        e_v: 0.0,
        veil: 0.0,
        lamp_e: 0.0,
        lamp_veil: 0.0,
        lamp_theta_deg: 0.0,
    };
    for y in 0..SIDE_PX {
        for x in 0..SIDE_PX {
            let d = pixel_dir(x as f64 + 0.5, y as f64 + 0.5);
            let c = d[0] * gaze[0] + d[1] * gaze[1] + d[2] * gaze[2];
            if c < 0.0 {
                continue;
            }
            let lamp = with_lamp && is_lamp(x, y);
            let l = if lamp { l_lamp } else { l_b };
            let e = l * pixel_sr(x, y) * c;
            s.e_v += e;
            if c <= inner_cos {
                let v = e * cie146(c.acos().to_degrees(), AGE_YEARS, PIGMENTATION);
                s.veil += v;
                if lamp {
                    s.lamp_veil += v;
                }
            }
            if lamp {
                s.lamp_e += e;
            }
        }
    }
    let cx = (LAMP_COLUMNS.start + LAMP_COLUMNS.end) as f64 / 2.0;
    let cy = (LAMP_ROWS.start + LAMP_ROWS.end) as f64 / 2.0;
    let d = pixel_dir(cx, cy);
    let c = d[0] * gaze[0] + d[1] * gaze[1] + d[2] * gaze[2];
    s.lamp_theta_deg = c.clamp(-1.0, 1.0).acos().to_degrees();
    s
}

/// The gaze (azimuth right, elevation up, degrees) of a normalised gaze
/// position on the picture.
fn gaze_angles(u: f64, v: f64) -> ([f64; 2], [f64; 3]) {
    let d = pixel_dir(u * SIDE_PX as f64, v * SIDE_PX as f64);
    (
        [
            d[0].atan2(-d[2]).to_degrees(),
            d[1].clamp(-1.0, 1.0).asin().to_degrees(),
        ],
        d,
    )
}

/// The position (u, v) on the picture of a gaze at (azimuth, elevation).
fn gaze_uv(az_deg: f64, el_deg: f64) -> [f64; 2] {
    let (a, e) = (az_deg.to_radians(), el_deg.to_radians());
    let x = a.tan();
    // Elevation of the direction (cos e sin a, sin e, −cos e cos a).
    let y = e.tan() / a.cos();
    [0.5 + x / (2.0 * half_tan()), 0.5 - y / (2.0 * half_tan())]
}

fn glare_at(picture: &Path, gaze_deg: [f64; 2], out: &Path) -> serde_json::Value {
    let g = format!("{},{}", gaze_deg[0], gaze_deg[1]);
    let o = gazelight(&[
        "glare",
        picture.to_str().unwrap(),
        "--gaze-deg",
        &g,
        "--age-years",
        &AGE_YEARS.to_string(),
        "--pigmentation",
        &PIGMENTATION.to_string(),
        "--json",
        out.to_str().unwrap(),
    ]);
    assert!(
        o.status.success(),
        "glare: {}",
        String::from_utf8_lossy(&o.stderr)
    );
    let v: serde_json::Value =
        serde_json::from_str(&std::fs::read_to_string(out).unwrap()).unwrap();
    v["gazes"]
        .as_array()
        .and_then(|a| a.first().cloned())
        .or_else(|| v.as_array().and_then(|a| a.first().cloned()))
        .unwrap_or(v)
}

fn num(v: &serde_json::Value, key: &str) -> f64 {
    v[key].as_f64().unwrap_or_else(|| panic!("{key} in {v}"))
}

#[test]
fn render_writes_the_glare_along_the_gaze() {
    let dir = tmp("glare_numbers");
    let picture = dir.join("lamp.hdr");
    let background = dir.join("background.hdr");
    write_picture(&picture, true);
    write_picture(&background, false);
    // Four gazes, each held around its frame's time (frames at 0, 1, 2, 3 s).
    let targets = [[35.0, 0.0], [25.0, 0.0], [40.0, 4.0], [-50.0, 0.0]];
    let mut trace = String::from("t_secs,gaze_u,gaze_v,pupil_mm\n");
    for step in 0..175 {
        let t = step as f64 * 0.02;
        let k = ((t + 0.5).floor() as usize).min(3);
        let [u, v] = gaze_uv(targets[k][0], targets[k][1]);
        trace.push_str(&format!("{t:.2},{u:.6},{v:.6},4\n"));
    }
    let trace_path = dir.join("trace.csv");
    std::fs::write(&trace_path, trace).unwrap();
    let out = dir.join("out");
    let text = render(&picture, &trace_path, &out, &[]);
    let mut lines = text.lines();
    let header: Vec<&str> = lines.next().unwrap().split(',').collect();
    let col = |name: &str| {
        header
            .iter()
            .position(|h| *h == name)
            .unwrap_or_else(|| panic!("{name} in {header:?}"))
    };
    let (cu, cv) = (col("gaze_u"), col("gaze_v"));
    let (cveil, cdgp, cugr) = (
        col("glare_veil_cie146_cd_m2"),
        col("glare_dgp"),
        col("glare_ugr"),
    );
    assert_eq!(
        header.last(),
        Some(&"glare_ugr"),
        "the glare columns are last"
    );
    let rows: Vec<Vec<f64>> = lines
        .map(|l| {
            l.split(',')
                .map(|c| c.parse().unwrap_or(f64::NAN))
                .collect()
        })
        .collect();
    assert_eq!(rows.len(), 4);
    for (k, row) in rows.iter().enumerate() {
        let lamp_behind = k == 3;
        let (angles, gaze) = gaze_angles(row[cu], row[cv]);
        let hand = hand_sums(gaze, true);
        let (veil, dgp, ugr) = (row[cveil], row[cdgp], row[cugr]);
        let g = glare_at(
            if lamp_behind { &background } else { &picture },
            angles,
            &dir.join(format!("glare_{k}.json")),
        );
        let (g_veil, g_dgp, g_ugr) = (num(&g, "veil_cie146_cd_m2"), num(&g, "dgp"), num(&g, "ugr"));
        println!(
            "frame {k}: gaze ({:.2}°, {:.2}°), lamp {:.2}° away: veil {veil:.5} cd/m² (hand sum {:.5}, {:+.2} %; \
             lamp E {:.3} lx × CIE 146 = {:.5} vs lamp's share of the sum {:.5}, {:+.2} %; glare {g_veil:.5}, {:+.2} %), \
             DGP {dgp:.5} (glare {g_dgp:.5}), UGR {ugr:.3} (glare {g_ugr:.3})",
            angles[0],
            angles[1],
            hand.lamp_theta_deg,
            hand.veil,
            100.0 * (veil / hand.veil - 1.0),
            hand.lamp_e,
            hand.lamp_e * cie146(hand.lamp_theta_deg, AGE_YEARS, PIGMENTATION),
            hand.lamp_veil,
            if hand.lamp_veil > 0.0 {
                100.0
                    * (hand.lamp_e * cie146(hand.lamp_theta_deg, AGE_YEARS, PIGMENTATION)
                        / hand.lamp_veil
                        - 1.0)
            } else {
                0.0
            },
            100.0 * (veil / g_veil - 1.0),
        );
        // The gaze is where the trace put it (the filter has settled).
        let want = targets[k];
        assert!(
            (angles[0] - want[0]).abs() < 0.2 && (angles[1] - want[1]).abs() < 0.2,
            "frame {k}: gaze {angles:?} vs {want:?}"
        );
        // The veil column is the CIE 146 sum over the picture.
        assert!(
            (veil / hand.veil - 1.0).abs() < 0.02,
            "frame {k}: veil {veil} vs the hand sum {}",
            hand.veil
        );
        // …and `glare`'s at the same gaze on the same picture.
        assert!(
            (veil / g_veil - 1.0).abs() < 0.005,
            "frame {k}: {veil} vs glare {g_veil}"
        );
        assert!(
            (dgp - g_dgp).abs() < 1e-3,
            "frame {k}: DGP {dgp} vs glare {g_dgp}"
        );
        assert!(
            (ugr - g_ugr).abs() < 0.05,
            "frame {k}: UGR {ugr} vs glare {g_ugr}"
        );
        if lamp_behind {
            // Lamp behind the line of sight: the background's numbers.
            assert!(hand.lamp_theta_deg > 90.0, "{}", hand.lamp_theta_deg);
            let bg = hand_sums(gaze, false);
            assert!((veil / bg.veil - 1.0).abs() < 0.02, "{veil} vs {}", bg.veil);
            // Wienold & Christoffersen 2006 without a source term.
            let dgp_bg = 5.87e-5 * bg.e_v + 0.159;
            assert!((dgp - dgp_bg).abs() < 1e-4, "DGP {dgp} vs {dgp_bg}");
            assert_eq!(ugr, 0.0, "no glare source: UGR 0");
        } else {
            // The lamp's part is the glare equation at its centre.
            let formula = hand.lamp_e * cie146(hand.lamp_theta_deg, AGE_YEARS, PIGMENTATION);
            assert!(
                (formula / hand.lamp_veil - 1.0).abs() < 0.03,
                "frame {k}: E × CIE 146 {formula} vs the lamp's sum {}",
                hand.lamp_veil
            );
            // A glare source in view: DGP above the background's.
            // Wienold & Christoffersen 2006 without a source term.
            let dgp_bg = 5.87e-5 * hand.e_v + 0.159;
            assert!(dgp > dgp_bg + 0.01, "frame {k}: DGP {dgp} vs {dgp_bg}");
            assert!(ugr > 0.0, "frame {k}: UGR {ugr}");
        }
    }
    // Stereo: the same numbers per eye (a binocular trace gives both eyes
    // its gaze), in columns suffixed _left and _right, last.
    let stereo = render(&picture, &trace_path, &dir.join("stereo"), &["--stereo"]);
    let mut lines = stereo.lines();
    let header: Vec<&str> = lines.next().unwrap().split(',').collect();
    assert_eq!(
        header[header.len() - 6..],
        [
            "glare_veil_cie146_cd_m2_left",
            "glare_dgp_left",
            "glare_ugr_left",
            "glare_veil_cie146_cd_m2_right",
            "glare_dgp_right",
            "glare_ugr_right"
        ]
    );
    for (row, mono) in lines.zip(&rows) {
        let cells: Vec<f64> = row
            .split(',')
            .map(|c| c.parse().unwrap_or(f64::NAN))
            .collect();
        let n = cells.len();
        for eye in [&cells[n - 6..n - 3], &cells[n - 3..]] {
            assert_eq!(eye, [mono[cveil], mono[cdgp], mono[cugr]], "{row}");
        }
    }
}

/// Renders the picture along the trace with `--glare-numbers` (and
/// `extra`) into `out`; returns its `timeline.csv`.
fn render(picture: &Path, trace: &Path, out: &Path, extra: &[&str]) -> String {
    let size = format!("{SIDE_PX}x{SIDE_PX}");
    let (fov, age, pigmentation) = (
        FOV_DEG.to_string(),
        AGE_YEARS.to_string(),
        PIGMENTATION.to_string(),
    );
    let mut args = vec![
        "render",
        "--scene",
        picture.to_str().unwrap(),
        "--trace",
        trace.to_str().unwrap(),
        "--size",
        &size,
        "--hfov-deg",
        &fov,
        "--yaw-deg",
        "0",
        "--pitch-deg",
        "0",
        "--fps",
        "1",
        "--frames",
        "4",
        "--backend",
        "cpu",
        "--no-frames",
        "--age-years",
        &age,
        "--pigmentation",
        &pigmentation,
        "--glare-numbers",
        "--out",
        out.to_str().unwrap(),
    ];
    args.extend_from_slice(extra);
    let run = gazelight(&args);
    assert!(
        run.status.success(),
        "render: {}",
        String::from_utf8_lossy(&run.stderr)
    );
    std::fs::read_to_string(out.join("timeline.csv")).unwrap()
}
