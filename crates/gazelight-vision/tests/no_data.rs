#![allow(clippy::unwrap_used, clippy::expect_used)] // test code may panic on a failed setup
//! Issue 38, "Must show": view pixels outside a scene's field are "no
//! data", not black light. On a real luminance-camera fisheye (evalglare's
//! test image, 182° angular, `tests/data/radiance`) seen through a 90°
//! perspective view that reaches past the fisheye's edge:
//!
//! * the fisheye's out-of-field corners filled with garbage give the same
//!   pooled luminance, adaptation and display bytes as zeroed ones;
//! * a gaze near the field's edge pools only in-field light: the pipeline's
//!   pooled target agrees with the test's own Gaussian-weighted mean over
//!   the in-field view pixels (great-circle angle from the gaze, each
//!   pixel's solid angle), where reading the no-data pixels as black would
//!   be far lower; a uniform in-field scene pools exactly its luminance;
//! * glare sees no light in them (the retinal image is the same as with
//!   the no-data pixels zeroed), and the output marks them (alpha 0 in the
//!   display frame, NaN in the retinal image).

use std::path::PathBuf;

use gazelight_vision::RgbImage;
use gazelight_vision::image::{is_no_data, luminance};
use gazelight_vision::pipeline::{DisplayFrame, FrameInput, FramePipeline, PipelineConfig};
use gazelight_vision::scene::{LuminanceScale, PanoramaView, Scene, ViewParams};

fn fisheye() -> Scene {
    let path = PathBuf::from(env!("CARGO_MANIFEST_DIR"))
        .join("../../tests/data/radiance/evalglare_testimage.hdr");
    let scene = Scene::load(&path, LuminanceScale::default()).unwrap();
    let p = scene
        .projection
        .expect("the header's VIEW= gives the projection");
    assert!(p.is_fisheye());
    scene
}

/// A scene whose out-of-field pixels are set by `f(x, y)`.
fn with_corners(scene: &Scene, f: impl Fn(usize, usize) -> [f32; 3]) -> Scene {
    let mut s = scene.clone();
    let p = s.projection.unwrap();
    let mut n = 0;
    for y in 0..s.image.height {
        for x in 0..s.image.width {
            if p.pixel_direction(x, y).is_none() {
                s.image.pixels[y * s.image.width + x] = f(x, y);
                n += 1;
            }
        }
    }
    assert!(n > s.image.pixels.len() / 10, "{n} corner pixels");
    s
}

const W: usize = 320;
const H: usize = 240;
const SIGMA_DEG: f64 = 2.0;

/// A 90° view turned 60° right: its right part (beyond 91° off the
/// fisheye's axis) has no data.
fn view() -> PanoramaView {
    PanoramaView::new(ViewParams {
        yaw_deg: 60.0,
        pitch_deg: 0.0,
        hfov_deg: 90.0,
        width: W,
        height: H,
    })
    .unwrap()
}

fn pipeline(keep_retinal: bool) -> FramePipeline {
    let config = PipelineConfig {
        keep_retinal,
        ..PipelineConfig::default()
    };
    let v = view();
    let mut p = FramePipeline::new(config, W, H, v.params().deg_per_px()).unwrap();
    p.set_view_frustum(v.frustum_tans()).unwrap();
    p
}

/// The gaze (view uv) at azimuth `az_deg` on the horizon.
fn gaze_uv(az_deg: f64) -> [f32; 2] {
    let a = az_deg.to_radians();
    let dir = glam::Vec3::new(a.sin() as f32, 0.0, -(a.cos() as f32));
    let px = view().project(dir).unwrap();
    [px[0] / W as f32, px[1] / H as f32]
}

/// The test's own pooled luminance: `Σ L·w·ω / Σ w·ω` over the view
/// pixels with data, `w` the Gaussian of the great-circle angle from the
/// gaze, `ω ∝ (1 + s_x² + s_y²)^{−3/2}` the pixel's solid angle. Also the
/// same sum with the no-data pixels read as black (what the old pipeline
/// pooled), and the no-data share of the weight.
fn independent_pool(img: &RgbImage, gaze: [f32; 2]) -> (f64, f64, f64) {
    let v = view();
    let g = v
        .direction(gaze[0] * W as f32, gaze[1] * H as f32)
        .as_dvec3();
    let t = v.frustum_tans();
    let (mut sum, mut weight, mut lost) = (0.0, 0.0, 0.0);
    for y in 0..H {
        for x in 0..W {
            let d = v.direction(x as f32 + 0.5, y as f32 + 0.5).as_dvec3();
            let ang = g.angle_between(d).to_degrees();
            let sx = t[0] + (x as f64 + 0.5) / W as f64 * (t[1] - t[0]);
            let sy = t[2] - (y as f64 + 0.5) / H as f64 * (t[2] - t[3]);
            let omega = (1.0 + sx * sx + sy * sy).powf(-1.5);
            let w = (-0.5 * (ang / SIGMA_DEG).powi(2)).exp() * omega;
            let p = img.pixels[y * W + x];
            if is_no_data(p) {
                lost += w;
                continue;
            }
            sum += w * f64::from(luminance(p));
            weight += w;
        }
    }
    (sum / weight, sum / (weight + lost), lost / (weight + lost))
}

#[test]
fn out_of_field_pixels_are_no_data_in_the_view_pipeline() {
    let scene = fisheye();
    let zeroed = with_corners(&scene, |_, _| [0.0; 3]);
    let garbage = with_corners(&scene, |x, y| {
        let v = 1e7 * (1.0 + ((x * 31 + y * 17) % 7) as f32);
        [v, v * 0.5, v * 2.0]
    });
    let v = view();
    let (mut img_z, mut img_g) = (RgbImage::new(W, H), RgbImage::new(W, H));
    let missing = v.render_scene(&zeroed, &mut img_z);
    assert_eq!(v.render_scene(&garbage, &mut img_g), missing);
    assert!(
        missing > W * H / 20 && missing < W * H / 2,
        "{missing} no-data view pixels"
    );
    assert_eq!(
        img_z.pixels.iter().filter(|p| is_no_data(**p)).count(),
        missing
    );

    // Gazes: well inside, 1.5° inside and 0.5° outside the field's edge
    // (91° off axis).
    let gazes = [gaze_uv(40.0), gaze_uv(89.5), gaze_uv(91.5)];
    let (mut pz, mut pg) = (pipeline(true), pipeline(false));
    let (mut oz, mut og) = (DisplayFrame::new(W, H), DisplayFrame::new(W, H));
    for (n, &g) in gazes.iter().enumerate() {
        let input = FrameInput {
            gaze_uv: g,
            pupil_mm: 4.0,
            dt_secs: 0.1,
        };
        let a = pz.process(&img_z, &input, &mut oz).unwrap();
        let b = pg.process(&img_g, &input, &mut og).unwrap();
        // Garbage in the corners changes nothing.
        assert_eq!(a.target_cd_m2.to_bits(), b.target_cd_m2.to_bits());
        assert_eq!(a.adaptation_cd_m2.to_bits(), b.adaptation_cd_m2.to_bits());
        assert!(oz.rgba8 == og.rgba8, "gaze {n}: display bytes differ");

        // Only in-field light is pooled. The pipeline pools 8×8 block
        // means with pixel-integrated weights through the view's
        // projection: its block prefilter (1.5° at 3.6 px/deg, under σ)
        // and the separable-axes approximation keep it within a few
        // per cent of the exact angular Gaussian (pooling.rs' rectilinear
        // tests: 2-3 %); 4 % here. Black no-data pixels would take away
        // the no-data share of the weight (checked to be > 20 % at the
        // edge gazes, so the old pooling fails by far more than 4 %).
        let (want, black, lost) = independent_pool(&img_z, g);
        eprintln!(
            "gaze {n} {g:?}: pooled {} cd/m², in-field {want}, as black {black}, no-data weight {:.1} %",
            a.target_cd_m2,
            100.0 * lost
        );
        assert!(
            (a.target_cd_m2 / want - 1.0).abs() < 0.04,
            "gaze {n}: pooled {} vs in-field {want} (black: {black})",
            a.target_cd_m2
        );
        if n > 0 {
            assert!(lost > 0.2, "gaze {n}: no-data weight {lost}");
        }

        // The output marks the no-data pixels: alpha 0 (display),
        // NaN (retinal); every other pixel is opaque and finite.
        for (i, p) in img_z.pixels.iter().enumerate() {
            let alpha = oz.rgba8[4 * i + 3];
            let r = pz.retinal().pixels[i];
            if is_no_data(*p) {
                assert_eq!(&oz.rgba8[4 * i..4 * i + 4], &[0, 0, 0, 0]);
                assert!(is_no_data(r));
            } else {
                assert_eq!(alpha, 255);
                assert!(r.iter().all(|c| c.is_finite()));
            }
        }
    }
}

/// A scene of one luminance inside its field pools exactly that luminance
/// at every gaze, also where most of the pooling's reach has no data (the
/// old pooling read it as black and adapted far lower).
#[test]
fn uniform_field_pools_its_luminance_at_the_edge() {
    let scene = fisheye();
    let uniform = {
        let mut s = with_corners(&scene, |_, _| [0.0; 3]);
        let p = s.projection.unwrap();
        for y in 0..s.image.height {
            for x in 0..s.image.width {
                if p.pixel_direction(x, y).is_some() {
                    s.image.pixels[y * s.image.width + x] = [100.0; 3];
                }
            }
        }
        s
    };
    let mut img = RgbImage::new(W, H);
    view().render_scene(&uniform, &mut img);
    let mut p = pipeline(false);
    let mut out = DisplayFrame::new(W, H);
    for az in [40.0, 85.0, 89.0, 92.0] {
        let s = p
            .process(
                &img,
                &FrameInput {
                    gaze_uv: gaze_uv(az),
                    pupil_mm: 4.0,
                    dt_secs: 0.1,
                },
                &mut out,
            )
            .unwrap();
        assert!(
            (s.target_cd_m2 / 100.0 - 1.0).abs() < 1e-5,
            "gaze at {az}°: pooled {}",
            s.target_cd_m2
        );
    }
}

/// Glare sees no light in the no-data pixels: the retinal image at every
/// pixel with data is the same as with the no-data pixels zeroed (with the
/// pooling held equal: both pipelines start adapted alike and the gaze is
/// where no block lacks data).
#[test]
fn glare_sees_no_light_where_there_is_no_data() {
    let scene = fisheye();
    let v = view();
    let mut nan = RgbImage::new(W, H);
    v.render_scene(&scene, &mut nan);
    let mut zero = nan.clone();
    for p in &mut zero.pixels {
        if is_no_data(*p) {
            *p = [0.0; 3];
        }
    }
    let (mut a, mut b) = (pipeline(true), pipeline(true));
    let (mut oa, mut ob) = (DisplayFrame::new(W, H), DisplayFrame::new(W, H));
    let input = FrameInput {
        gaze_uv: gaze_uv(30.0),
        pupil_mm: 4.0,
        dt_secs: 0.1,
    };
    let sa = a.process(&nan, &input, &mut oa).unwrap();
    let sb = b.process(&zero, &input, &mut ob).unwrap();
    assert_eq!(sa.target_cd_m2, sb.target_cd_m2);
    let mut compared = 0;
    for (i, p) in nan.pixels.iter().enumerate() {
        if !is_no_data(*p) {
            assert_eq!(a.retinal().pixels[i], b.retinal().pixels[i], "pixel {i}");
            compared += 1;
        }
    }
    assert!(compared > W * H / 2);
}
