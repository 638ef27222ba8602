#![allow(clippy::unwrap_used, clippy::expect_used)] // test code may panic on a failed setup
//! Issue 38, "Must show": for each projection, a synthetic image of a
//! small bright disc of known luminance and solid angle at known angles on
//! a dim uniform field gives the right pooled (average) luminance,
//! vertical illuminance, glare source geometry and veils; and a fisheye's
//! out-of-field corners filled with garbage give the same numbers as
//! zeroed ones.
//!
//! The images are drawn here from the projections' radial laws written out
//! below (Radiance's `viewray`, `src/common/image.c`, and the equisolid
//! law r ∝ sin θ/2), not with the code under test; the expected values are
//! geometry: a disc of angular radius ρ subtends 2π(1 − cos ρ) sr; a
//! hemisphere of uniform luminance L gives the illuminance πL; a
//! rectilinear field of half-angles a, b subtends 4 asin(sin a sin b) and
//! its projected solid angle is
//! 2[X/√(1+X²) atan(Y/√(1+X²)) + Y/√(1+Y²) atan(X/√(1+Y²))], X = tan a,
//! Y = tan b (the form factor of a rectangle, four quadrants).

use std::f64::consts::{PI, TAU};

use gazelight_vision::RgbImage;
use gazelight_vision::scene::projection::{DVec3, direction_from_angles};
use gazelight_vision::scene::{ProjectionKind, SceneProjection};
use gazelight_vision::scene_glare::{GlareOptions, SceneGlare};

const DISC_CD_M2: f64 = 10_000.0;
const BACKGROUND_CD_M2: f64 = 0.5;
const DISC_RADIUS_DEG: f64 = 3.0;
const DISC_AZ_EL_DEG: [f64; 2] = [20.0, 10.0];

/// The test's own pixel → direction (camera frame: −z forward, +x right,
/// +y up) for a continuous pixel position, or None outside the field.
fn test_direction(
    kind: ProjectionKind,
    fov: [f64; 2],
    w: usize,
    h: usize,
    px: [f64; 2],
) -> Option<DVec3> {
    let (wf, hf) = (w as f64, h as f64);
    if kind == ProjectionKind::Equirectangular {
        let lon = (px[0] / wf - 0.5) * TAU;
        let lat = (0.5 - px[1] / hf) * PI;
        return Some(DVec3::new(
            lat.cos() * lon.sin(),
            lat.sin(),
            -lat.cos() * lon.cos(),
        ));
    }
    let x = px[0] / wf - 0.5;
    let y = 0.5 - px[1] / hf;
    let (hh, vh) = (fov[0].to_radians() / 2.0, fov[1].to_radians() / 2.0);
    match kind {
        ProjectionKind::Perspective => {
            if x.abs() > 0.5 || y.abs() > 0.5 {
                return None;
            }
            // viewray VT_PER: vdir + x hvec + y vvec, |hvec| = 2 tan(h/2)
            Some(DVec3::new(x * 2.0 * hh.tan(), y * 2.0 * vh.tan(), -1.0).normalize())
        }
        _ => {
            // The field of a fisheye is the inscribed ellipse.
            if (2.0 * x).powi(2) + (2.0 * y).powi(2) > 1.0 {
                return None;
            }
            let (sx, sy, theta) = match kind {
                ProjectionKind::Angular => {
                    // viewray VT_ANG: θ = π √((x h/180)² + (y v/180)²)
                    let (sx, sy) = (x * 2.0 * hh, y * 2.0 * vh);
                    (sx, sy, (sx * sx + sy * sy).sqrt())
                }
                ProjectionKind::Hemispherical => {
                    // VT_HEM: lateral components x · 2 sin(h/2)
                    let (sx, sy) = (x * 2.0 * hh.sin(), y * 2.0 * vh.sin());
                    (sx, sy, (sx * sx + sy * sy).sqrt().min(1.0).asin())
                }
                ProjectionKind::Stereographic => {
                    // VT_PLS: tan(θ/2) = √(x'² + y'²), x' = x · 2 tan(h/4)
                    let (sx, sy) = (x * 2.0 * (hh / 2.0).tan(), y * 2.0 * (vh / 2.0).tan());
                    (sx, sy, 2.0 * (sx * sx + sy * sy).sqrt().atan())
                }
                ProjectionKind::Equisolid => {
                    let (sx, sy) = (x * 2.0 * (hh / 2.0).sin(), y * 2.0 * (vh / 2.0).sin());
                    (sx, sy, 2.0 * (sx * sx + sy * sy).sqrt().min(1.0).asin())
                }
                _ => unreachable!(),
            };
            let r = (sx * sx + sy * sy).sqrt();
            if r < 1e-12 {
                return Some(DVec3::NEG_Z);
            }
            Some(DVec3::new(
                theta.sin() * sx / r,
                theta.sin() * sy / r,
                -theta.cos(),
            ))
        }
    }
}

/// The disc on the uniform field, 6 × 6 samples per pixel near the disc's
/// edge; `outside` fills the pixels whose centre is outside the field.
fn draw(
    kind: ProjectionKind,
    fov: [f64; 2],
    w: usize,
    h: usize,
    outside: impl Fn(usize, usize) -> f32,
) -> RgbImage {
    let centre = direction_from_angles(DISC_AZ_EL_DEG[0], DISC_AZ_EL_DEG[1]);
    let cos_r = DISC_RADIUS_DEG.to_radians().cos();
    let near = (DISC_RADIUS_DEG + 2.0).to_radians().cos();
    let mut img = RgbImage::new(w, h);
    for y in 0..h {
        for x in 0..w {
            let Some(d) = test_direction(kind, fov, w, h, [x as f64 + 0.5, y as f64 + 0.5]) else {
                *img.get_mut(x, y) = [outside(x, y); 3];
                continue;
            };
            let frac = if d.dot(centre) < near {
                0.0
            } else {
                const S: usize = 6;
                let mut inside = 0;
                for sy in 0..S {
                    for sx in 0..S {
                        let p = [
                            x as f64 + (sx as f64 + 0.5) / S as f64,
                            y as f64 + (sy as f64 + 0.5) / S as f64,
                        ];
                        if test_direction(kind, fov, w, h, p)
                            .is_some_and(|s| s.dot(centre) >= cos_r)
                        {
                            inside += 1;
                        }
                    }
                }
                inside as f64 / (S * S) as f64
            };
            let l = BACKGROUND_CD_M2 + (DISC_CD_M2 - BACKGROUND_CD_M2) * frac;
            *img.get_mut(x, y) = [l as f32; 3];
        }
    }
    img
}

fn cases() -> Vec<(ProjectionKind, [f64; 2], usize, usize)> {
    vec![
        (ProjectionKind::Equirectangular, [360.0, 180.0], 1440, 720),
        (ProjectionKind::Perspective, [100.0, 80.0], 720, 540),
        (ProjectionKind::Angular, [180.0, 180.0], 720, 720),
        (ProjectionKind::Hemispherical, [180.0, 180.0], 720, 720),
        (ProjectionKind::Equisolid, [180.0, 180.0], 720, 720),
        (ProjectionKind::Stereographic, [180.0, 180.0], 720, 720),
    ]
}

fn projection(kind: ProjectionKind, fov: [f64; 2], w: usize, h: usize) -> SceneProjection {
    if kind == ProjectionKind::Equirectangular {
        SceneProjection::equirectangular(w, h)
    } else {
        SceneProjection::new(kind, fov[0], fov[1], w, h).unwrap()
    }
}

/// The field's solid angle in front of the eye (gaze straight ahead) and
/// its projected solid angle.
fn field(kind: ProjectionKind, fov: [f64; 2]) -> (f64, f64) {
    if kind == ProjectionKind::Perspective {
        let (a, b) = (fov[0].to_radians() / 2.0, fov[1].to_radians() / 2.0);
        let (x, y) = (a.tan(), b.tan());
        let proj = 2.0
            * (x / (1.0 + x * x).sqrt() * (y / (1.0 + x * x).sqrt()).atan()
                + y / (1.0 + y * y).sqrt() * (x / (1.0 + y * y).sqrt()).atan());
        (4.0 * (a.sin() * b.sin()).asin(), proj)
    } else {
        (TAU, PI)
    }
}

#[test]
fn a_bright_disc_gives_its_luminance_illuminance_and_geometry_in_every_projection() {
    let disc_sr = TAU * (1.0 - DISC_RADIUS_DEG.to_radians().cos());
    let centre = direction_from_angles(DISC_AZ_EL_DEG[0], DISC_AZ_EL_DEG[1]);
    let opts = GlareOptions::default();
    for (kind, fov, w, h) in cases() {
        let img = draw(kind, fov, w, h, |_, _| 0.0);
        let glare = SceneGlare::new(&img, projection(kind, fov, w, h));
        let r = glare.at_gaze(DVec3::NEG_Z, &opts);
        let (field_sr, field_proj_sr) = field(kind, fov);
        let cos_c = centre.dot(DVec3::NEG_Z);
        let e_expected =
            BACKGROUND_CD_M2 * field_proj_sr + (DISC_CD_M2 - BACKGROUND_CD_M2) * disc_sr * cos_c;
        let avg_expected =
            (BACKGROUND_CD_M2 * field_sr + (DISC_CD_M2 - BACKGROUND_CD_M2) * disc_sr) / field_sr;
        let name = kind.name();
        assert!(
            (r.vertical_illuminance_lux / e_expected - 1.0).abs() < 0.01,
            "{name}: E_v {} vs {e_expected}",
            r.vertical_illuminance_lux
        );
        assert!(
            (r.average_luminance_cd_m2 / avg_expected - 1.0).abs() < 0.01,
            "{name}: average {} vs {avg_expected}",
            r.average_luminance_cd_m2
        );
        assert_eq!(r.sources.len(), 1, "{name}: {:?}", r.sources);
        let s = &r.sources[0];
        // Edge pixels more than a fifth covered count whole.
        assert!(
            (s.solid_angle_sr / disc_sr - 1.0).abs() < 0.08,
            "{name}: Ω {} vs {disc_sr}",
            s.solid_angle_sr
        );
        let e_disc = DISC_CD_M2 * disc_sr * cos_c;
        assert!(
            (s.illuminance_lux / e_disc - 1.0).abs() < 0.02,
            "{name}: E_source {} vs {e_disc}",
            s.illuminance_lux
        );
        let off_deg = DVec3::from_array(s.direction)
            .dot(centre)
            .clamp(-1.0, 1.0)
            .acos()
            .to_degrees();
        // The mean pixel position of a disc is its centre's only where the
        // projection is locally linear: within a tenth of its radius.
        assert!(
            off_deg < 0.3,
            "{name}: source {off_deg}° from the disc's centre"
        );
        let theta = cos_c.acos().to_degrees();
        let sh = 10.0 * e_disc / (theta * theta);
        assert!(
            (r.veil_stiles_holladay_cd_m2 / sh - 1.0).abs() < 0.04,
            "{name}: S-H {} vs {sh}",
            r.veil_stiles_holladay_cd_m2
        );
        // The gaze on the disc sees its luminance.
        let on = glare.at_gaze(centre, &opts);
        let l = on.luminance_at_gaze_cd_m2.unwrap();
        assert!(
            (l / DISC_CD_M2 - 1.0).abs() < 0.01,
            "{name}: luminance at the disc {l}"
        );
    }
}

#[test]
fn out_of_field_garbage_changes_nothing() {
    let opts = GlareOptions::default();
    for (kind, fov, w, h) in cases()
        .into_iter()
        .filter(|c| c.0 != ProjectionKind::Equirectangular)
    {
        let zero = draw(kind, fov, w / 2, h / 2, |_, _| 0.0);
        let garbage = draw(kind, fov, w / 2, h / 2, |x, y| {
            1e7 * (1.0 + ((x * 31 + y * 17) % 7) as f32)
        });
        let p = projection(kind, fov, w / 2, h / 2);
        for gaze in [
            DVec3::NEG_Z,
            direction_from_angles(30.0, -20.0),
            direction_from_angles(85.0, 0.0),
        ] {
            let a = SceneGlare::new(&zero, p).at_gaze(gaze, &opts);
            let b = SceneGlare::new(&garbage, p).at_gaze(gaze, &opts);
            assert_eq!(a, b, "{}", kind.name());
        }
        if kind == ProjectionKind::Perspective {
            // A perspective frame has no corners outside its field: the
            // test's garbage never lands; a gaze beyond the frame is
            // reported as outside.
            let r = SceneGlare::new(&zero, p).at_gaze(direction_from_angles(80.0, 0.0), &opts);
            assert!(!r.gaze_in_field && r.luminance_at_gaze_cd_m2.is_none());
        }
    }
}
