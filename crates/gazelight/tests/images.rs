#![allow(clippy::unwrap_used, clippy::expect_used)] // test and bench code may panic on a failed setup
//! What a researcher sees (issue 49, items 1–2), read from the files
//! `gazelight render` writes:
//!
//! - a fisheye scene viewed past its field: the PNG frames are opaque and
//!   draw exactly the pixels without data (NaN in the EXR frames) as the
//!   dark hatch that docs/lighting-research.md and the contact sheet's
//!   legend describe — stripe RGB [120, 0, 120] where (x + y) mod 8 < 2,
//!   else [28, 28, 28] — and the contact sheet draws them the same way;
//! - the EXR frames' headers carry the unit, eye, time, gaze and view,
//!   read back with the `exr` crate and checked against the run's own
//!   `timeline.csv` and the flags;
//! - the contact sheet at the smallest size `--size` accepts (8×8, mono
//!   and stereo): every caption line is drawn inside its tile (the largest
//!   size is checked on synthetic frames in `output.rs`'s tests), and on a
//!   bright sky the gaze is marked and the captions stay readable.
//!
//! With `GAZELIGHT_UPDATE_DOCS=1` the fisheye render's contact sheet
//! becomes docs/no_data_sheet.png.

mod common;

use std::path::Path;

use common::{gazelight, shared, tmp};

/// The hatch, as docs/lighting-research.md states it.
fn hatch(x: usize, y: usize) -> [u8; 3] {
    if (x + y) % 8 < 2 {
        [120, 0, 120]
    } else {
        [28, 28, 28]
    }
}

/// The contact sheet's layout, as docs/perception.md states it: a caption
/// band of 55 px under each tile image, a legend strip of 28 px at the
/// bottom, 4 columns of cells at least 200 px wide, 3 rows for 12 tiles.
const CAPTION_H: u32 = 55;
const LEGEND_H: u32 = 28;

fn run_ok(args: &[&str]) -> String {
    let out = gazelight(args);
    let stderr = String::from_utf8_lossy(&out.stderr);
    assert!(out.status.success(), "{args:?}: {stderr}");
    format!("{}{stderr}", String::from_utf8_lossy(&out.stdout))
}

/// An EXR frame's pixels (RGB, row-major) and its header's attributes.
struct Exr {
    width: usize,
    pixels: Vec<[f32; 3]>,
    white_luminance: Option<f32>,
    attributes: std::collections::HashMap<String, exr::meta::attribute::AttributeValue>,
}

fn read_exr(path: &Path) -> Exr {
    let image = exr::prelude::read_first_rgba_layer_from_file(
        path,
        |size, _| (size.width(), vec![[0f32; 3]; size.width() * size.height()]),
        |(w, px): &mut (usize, Vec<[f32; 3]>), pos, (r, g, b, _a): (f32, f32, f32, f32)| {
            px[pos.y() * *w + pos.x()] = [r, g, b];
        },
    )
    .expect("EXR pixels");
    let (width, pixels) = image.layer_data.channel_data.pixels;
    let meta = exr::meta::MetaData::read_from_file(path, false).expect("EXR header");
    let header = &meta.headers[0];
    Exr {
        width,
        pixels,
        white_luminance: header.own_attributes.white_luminance,
        attributes: header
            .own_attributes
            .other
            .iter()
            .map(|(k, v)| (k.to_string(), v.clone()))
            .collect(),
    }
}

fn text(exr: &Exr, name: &str) -> String {
    match exr.attributes.get(name) {
        Some(exr::meta::attribute::AttributeValue::Text(t)) => t.to_string(),
        other => panic!("{name}: {other:?}"),
    }
}

fn f64_attr(exr: &Exr, name: &str) -> f64 {
    match exr.attributes.get(name) {
        Some(exr::meta::attribute::AttributeValue::F64(v)) => *v,
        other => panic!("{name}: {other:?}"),
    }
}

fn vec2_attr(exr: &Exr, name: &str) -> [f32; 2] {
    match exr.attributes.get(name) {
        Some(exr::meta::attribute::AttributeValue::FloatVec2(v)) => [v.x(), v.y()],
        other => panic!("{name}: {other:?}"),
    }
}

/// A column of `timeline.csv` by name.
fn column(csv: &str, name: &str) -> Vec<f64> {
    let mut lines = csv.lines();
    let header: Vec<&str> = lines.next().expect("header").split(',').collect();
    let k = header
        .iter()
        .position(|c| *c == name)
        .unwrap_or_else(|| panic!("no column {name}"));
    lines
        .map(|l| l.split(',').nth(k).expect("cell").parse().expect("number"))
        .collect()
}

/// evalglare's 182° fisheye turned 60° right with a 90° field (a wedge of
/// the view lies outside the scene's field): PNG frames opaque with the
/// hatch exactly on the EXR's NaN pixels; the contact sheet's first tile
/// (the frame enlarged ×3) hatched on the same pixels, and its legend
/// swatch hatched; the EXR header's attributes.
#[test]
fn fisheye_render_draws_no_data_as_the_legend_says_and_exr_headers_carry_the_frame() {
    let dir = tmp("fisheye");
    let scene = Path::new(env!("CARGO_MANIFEST_DIR"))
        .join("../../tests/data/radiance/evalglare_testimage.hdr");
    let out = dir.join("out");
    let log = run_ok(&[
        "render",
        "--scene",
        scene.to_str().expect("utf-8"),
        "--size",
        "96x72",
        "--hfov-deg",
        "90",
        "--yaw-deg",
        "60",
        "--pitch-deg",
        "0",
        "--frames",
        "3",
        "--exr",
        "--backend",
        "cpu",
        "--out",
        out.to_str().expect("utf-8"),
    ]);
    assert!(log.contains("dark hatch"), "{log}");
    let timeline = std::fs::read_to_string(out.join("timeline.csv")).expect("timeline");
    let (t, gu, gv) = (
        column(&timeline, "t_secs"),
        column(&timeline, "gaze_u"),
        column(&timeline, "gaze_v"),
    );
    let mut exr0 = None;
    for i in 0..3 {
        let png = image::open(out.join(format!("frames/frame_{i:05}.png"))).expect("PNG");
        assert!(!png.color().has_alpha(), "frame {i}: {:?}", png.color());
        let png = png.to_rgb8();
        assert_eq!(png.dimensions(), (96, 72));
        let exr = read_exr(&out.join(format!("frames/frame_{i:05}.exr")));
        assert_eq!(exr.width, 96);
        let mut no_data = 0;
        for (k, p) in exr.pixels.iter().enumerate() {
            let (x, y) = (k % 96, k / 96);
            let got = png.get_pixel(x as u32, y as u32).0;
            if p.iter().any(|v| v.is_nan()) {
                no_data += 1;
                assert_eq!(got, hatch(x, y), "frame {i} pixel ({x}, {y})");
            }
        }
        assert!(
            no_data > 96 * 72 / 20 && no_data < 96 * 72 / 2,
            "frame {i}: {no_data} no-data pixels"
        );
        // The header: unit, eye, time, gaze, view.
        assert_eq!(exr.white_luminance, Some(1.0), "frame {i}");
        assert!(text(&exr, "gazelight.unit").starts_with("cd/m^2"));
        assert!(text(&exr, "gazelight.eye").starts_with("mono"));
        assert!(
            (f64_attr(&exr, "gazelight.t_secs") - t[i]).abs() < 1e-4,
            "frame {i}: t {} vs timeline {}",
            f64_attr(&exr, "gazelight.t_secs"),
            t[i]
        );
        assert!((f64_attr(&exr, "gazelight.t_secs") - i as f64 / 30.0).abs() < 1e-9);
        assert_eq!(f64_attr(&exr, "gazelight.frame"), i as f64);
        let gaze = vec2_attr(&exr, "gazelight.gaze_uv");
        assert!(
            (f64::from(gaze[0]) - gu[i]).abs() < 1e-4 && (f64::from(gaze[1]) - gv[i]).abs() < 1e-4,
            "frame {i}: gaze {gaze:?} vs timeline ({}, {})",
            gu[i],
            gv[i]
        );
        assert_eq!(f64_attr(&exr, "gazelight.view.yaw_deg"), 60.0);
        assert_eq!(f64_attr(&exr, "gazelight.view.pitch_deg"), 0.0);
        assert_eq!(f64_attr(&exr, "gazelight.view.hfov_deg"), 90.0);
        assert_eq!(vec2_attr(&exr, "gazelight.view.size_px"), [96.0, 72.0]);
        if i == 0 {
            exr0 = Some(exr);
        }
    }
    // The contact sheet: a 96×72 frame is enlarged ×3 (320 // 96) to a
    // 288×216 tile image at the sheet's top left; its no-data pixels are
    // the hatch at sheet coordinates (the gaze marker's green aside).
    let exr0 = exr0.expect("frame 0");
    let sheet = image::open(out.join("contact_sheet.png"))
        .expect("sheet")
        .to_rgb8();
    assert_eq!(sheet.dimensions(), (4 * 288, 216 + CAPTION_H + LEGEND_H));
    let mut hatched = 0;
    for y in 0..216usize {
        for x in 0..288usize {
            let got = sheet.get_pixel(x as u32, y as u32).0;
            let p = exr0.pixels[(y / 3) * 96 + x / 3];
            if got != [0, 255, 0] && p.iter().any(|v| v.is_nan()) {
                assert_eq!(got, hatch(x, y), "sheet pixel ({x}, {y})");
                hatched += 1;
            }
        }
    }
    assert!(hatched > 288 * 216 / 20, "{hatched}");
    // The legend: a hatched swatch at its left.
    let legend_y = sheet.height() - LEGEND_H;
    let swatch: Vec<(u32, u32)> = (legend_y..sheet.height())
        .flat_map(|y| (0..48).map(move |x| (x, y)))
        .filter(|&(x, y)| {
            let p = sheet.get_pixel(x, y).0;
            p == [120, 0, 120] || p == [28, 28, 28]
        })
        .collect();
    assert!(swatch.len() >= 300, "legend swatch: {} px", swatch.len());
    for &(x, y) in &swatch {
        assert_eq!(sheet.get_pixel(x, y).0, hatch(x as usize, y as usize));
    }
    if std::env::var_os("GAZELIGHT_UPDATE_DOCS").is_some() {
        std::fs::copy(
            out.join("contact_sheet.png"),
            Path::new(env!("CARGO_MANIFEST_DIR")).join("../../docs/no_data_sheet.png"),
        )
        .expect("docs/no_data_sheet.png");
    }
    let _ = std::fs::remove_dir_all(&dir);
}

/// Text pixels (bright: the caption band is black) in rows `ys` of the
/// sheet, between columns `x0..x1`: their leftmost and rightmost column.
fn text_extent(
    sheet: &image::RgbImage,
    ys: std::ops::Range<u32>,
    x0: u32,
    x1: u32,
) -> Option<(u32, u32)> {
    let xs: Vec<u32> = ys
        .flat_map(|y| (x0..x1).map(move |x| (x, y)))
        .filter(|&(x, y)| {
            let p = sheet.get_pixel(x, y).0;
            p.iter().all(|&c| c >= 100)
        })
        .map(|(x, _)| x)
        .collect();
    Some((*xs.iter().min()?, *xs.iter().max()?))
}

/// The smallest frames `--size` accepts (8×8; with a 1° field, so the
/// glare kernel's 8 px per degree stay what the PSF needs), mono and
/// stereo: 12 tiles, each
/// with its three caption lines (time, pupil, adaptation) drawn inside
/// its cell — text on every line, none in the cell's outer 2 px columns
/// (a caption cut off at the cell's edge or spilling into the next cell
/// would have some). The run says its backend once, and prints its
/// settings one per line.
#[test]
fn contact_sheet_captions_fit_at_the_smallest_size() {
    for stereo in [false, true] {
        let dir = tmp(&format!("small-{stereo}"));
        let out = dir.join("out");
        let out_s = out.to_str().expect("utf-8").to_owned();
        let mut args = vec![
            "render",
            "--size",
            "8x8",
            "--hfov-deg",
            "1",
            "--frames",
            "24",
            "--no-frames",
            "--out",
            &out_s,
        ];
        if stereo {
            args.push("--stereo");
        }
        let log = run_ok(&args);
        // Each message once (a stereo run builds two renderers), and the
        // settings one line per setting: the pipeline's table is split
        // into its leaves, no line is a long JSON object.
        assert_eq!(log.matches("backend: ").count(), 1, "{log}");
        assert!(
            log.contains("  pipeline.tone.model = \"ward_ferwerda\" [default]\n"),
            "{log}"
        );
        assert!(!log.contains("pipeline = {"), "{log}");
        let sheet = image::open(out.join("contact_sheet.png"))
            .expect("sheet")
            .to_rgb8();
        let (w, h) = sheet.dimensions();
        // 8×8 enlarged ×40 to 320×320; stereo 16×8 ×20 to 320×160.
        let (cell_w, image_h) = (320, if stereo { 160 } else { 320 });
        assert_eq!((w, h), (4 * cell_w, 3 * (image_h + CAPTION_H) + LEGEND_H));
        for tile in 0..12u32 {
            let (cx, cy) = (
                (tile % 4) * cell_w,
                (tile / 4) * (image_h + CAPTION_H) + image_h,
            );
            for line in 0..3u32 {
                let ys = cy + 2 + line * 17..cy + 2 + (line + 1) * 17;
                let extent = text_extent(&sheet, ys, cx, cx + cell_w);
                let Some((lo, hi)) = extent else {
                    panic!("stereo {stereo} tile {tile} line {line}: no text");
                };
                assert!(
                    lo >= cx + 2 && hi + 2 < cx + cell_w,
                    "stereo {stereo} tile {tile} line {line}: text {lo}..={hi} in cell {cx}..{}",
                    cx + cell_w
                );
            }
        }
        let _ = std::fs::remove_dir_all(&dir);
    }
}

/// The contact sheet explains itself on a bright scene: every tile's gaze
/// is marked (the sheet's marker green) inside its image, and its time,
/// pupil and adaptation are written white on the black caption band
/// under the image (band median ≤ 40 of 255 with text pixels ≥ 200),
/// while the images themselves are bright.
#[test]
fn contact_sheet_marks_gaze_and_captions_readably_on_a_bright_sky() {
    let dir = tmp("sheet");
    let scene = shared("hdr/blender-world/city.exr");
    let out = dir.join("out");
    run_ok(&[
        "render",
        "--scene",
        scene.to_str().expect("utf-8"),
        "--scene-key-cd-m2",
        "2000",
        "--pitch-deg",
        "25",
        "--size",
        "160x120",
        "--frames",
        "24",
        "--no-frames",
        "--out",
        out.to_str().expect("utf-8"),
    ]);
    let sheet = image::open(out.join("contact_sheet.png"))
        .expect("sheet")
        .to_rgb8();
    // 160×120 enlarged ×2 (320 // 160) to 320×240.
    let (cell_w, image_h) = (320u32, 240u32);
    assert_eq!(
        sheet.dimensions(),
        (4 * cell_w, 3 * (image_h + CAPTION_H) + LEGEND_H)
    );
    let luma = |p: &image::Rgb<u8>| {
        (0.2126 * f64::from(p.0[0]) + 0.7152 * f64::from(p.0[1]) + 0.0722 * f64::from(p.0[2])) as u8
    };
    let mut image_sum = 0.0;
    for tile in 0..12u32 {
        let (cx, cy) = ((tile % 4) * cell_w, (tile / 4) * (image_h + CAPTION_H));
        let mut band: Vec<u8> = (cy + image_h..cy + image_h + CAPTION_H)
            .flat_map(|y| (cx..cx + cell_w).map(move |x| (x, y)))
            .map(|(x, y)| luma(sheet.get_pixel(x, y)))
            .collect();
        band.sort_unstable();
        let (median, max) = (band[band.len() / 2], band[band.len() - 1]);
        assert!(
            median <= 40 && max >= 200,
            "tile {tile}: band median {median}, max {max}"
        );
        let green = (cy..cy + image_h)
            .flat_map(|y| (cx..cx + cell_w).map(move |x| (x, y)))
            .filter(|&(x, y)| sheet.get_pixel(x, y).0 == [0, 255, 0])
            .count();
        assert!(green >= 8, "tile {tile}: gaze marker {green} px");
        image_sum += (cy..cy + image_h)
            .flat_map(|y| (cx..cx + cell_w).map(move |x| (x, y)))
            .map(|(x, y)| f64::from(luma(sheet.get_pixel(x, y))))
            .sum::<f64>();
    }
    let mean = image_sum / (12.0 * f64::from(cell_w * image_h));
    assert!(mean >= 100.0, "not a bright scene: {mean:.0}");
    let _ = std::fs::remove_dir_all(&dir);
}

/// No first frame from an unset state: a gaze that starts where the view
/// has no data (evalglare's fisheye, the view turned 100° right with a
/// 120° field: the right edge of the view lies outside the scene's field)
/// pools no light, and the eye starts adapted to the light of the rest of
/// the view — the solid-angle mean of the first EXR frame's luminance over
/// its pixels with data (each pixel weighted by (1 + sx² + sy²)^-3/2, sx,
/// sy its tangent coordinates), within 25 % (the EXR frame is after glare
/// and blur) — and holds it while the gaze stays there; not 0 cd/m², which
/// drew a blown-out first frame. The CPU and GPU pipelines agree.
#[test]
fn first_frame_with_the_gaze_outside_the_field_starts_adapted_to_the_view() {
    let dir = tmp("first-frame");
    let trace = dir.join("trace.csv");
    std::fs::write(
        &trace,
        "t_secs,gaze_u,gaze_v,pupil_mm\n0,0.99,0.5,4\n0.5,0.99,0.5,4\n0.6,0.3,0.5,4\n1.0,0.3,0.5,4\n",
    )
    .expect("trace");
    let scene = Path::new(env!("CARGO_MANIFEST_DIR"))
        .join("../../tests/data/radiance/evalglare_testimage.hdr");
    let mut first = Vec::new();
    for backend in ["cpu", "gpu"] {
        let out = dir.join(backend);
        run_ok(&[
            "render",
            "--scene",
            scene.to_str().expect("utf-8"),
            "--size",
            "96x72",
            "--hfov-deg",
            "120",
            "--yaw-deg",
            "100",
            "--pitch-deg",
            "0",
            "--trace",
            trace.to_str().expect("utf-8"),
            "--frames",
            "20",
            "--exr",
            "--backend",
            backend,
            "--out",
            out.to_str().expect("utf-8"),
        ]);
        let timeline = std::fs::read_to_string(out.join("timeline.csv")).expect("timeline");
        let adaptation = column(&timeline, "adaptation_cd_m2");
        let gaze_u = column(&timeline, "gaze_u");
        // The field mean of frame 0's EXR over its pixels with data.
        let exr = read_exr(&out.join("frames/frame_00000.exr"));
        let (w, h) = (96.0f64, 72.0f64);
        let tan_h = (60f64).to_radians().tan();
        let tan_v = tan_h * h / w;
        let (mut sum, mut weight) = (0.0, 0.0);
        for (k, p) in exr.pixels.iter().enumerate() {
            if p.iter().any(|v| v.is_nan()) {
                continue;
            }
            let sx = -tan_h + ((k % 96) as f64 + 0.5) / w * 2.0 * tan_h;
            let sy = tan_v - ((k / 96) as f64 + 0.5) / h * 2.0 * tan_v;
            let omega = (1.0 + sx * sx + sy * sy).powf(-1.5);
            let y = 0.2126 * f64::from(p[0]) + 0.7152 * f64::from(p[1]) + 0.0722 * f64::from(p[2]);
            sum += omega * y;
            weight += omega;
        }
        let field = sum / weight;
        assert!(
            adaptation[0] > 0.75 * field && adaptation[0] < 1.25 * field,
            "{backend}: first frame adapted to {} cd/m², the view's field mean {field} cd/m²",
            adaptation[0]
        );
        for i in 0..20 {
            if gaze_u[i] > 0.98 {
                assert!(
                    (adaptation[i] / adaptation[0] - 1.0).abs() < 1e-4,
                    "{backend} frame {i}: {} vs {}",
                    adaptation[i],
                    adaptation[0]
                );
            }
        }
        first.push(adaptation[0]);
    }
    assert!(
        (first[1] / first[0] - 1.0).abs() < 1e-3,
        "cpu {} vs gpu {}",
        first[0],
        first[1]
    );
    let _ = std::fs::remove_dir_all(&dir);
}

/// A replay whose pupil has no physical scale (the shipped EyeLink file,
/// in area units, without --calibration) says why it has no pupil light
/// residual, instead of "residual SD NaN mm vs raw pupil SD NaN mm",
/// prints no NaN anywhere in its summary, and warns of the raw unit once.
#[test]
fn replay_summary_says_why_there_is_no_residual_instead_of_nan() {
    let dir = tmp("no-residual");
    let out = dir.join("out");
    let recording = shared("eye/eyelink-psa/both_eyes.asc");
    let result = gazelight(&[
        "replay",
        recording.to_str().expect("utf-8"),
        "--secs",
        "1",
        "--no-frames",
        "--size",
        "120x120",
        "--out",
        out.to_str().expect("utf-8"),
    ]);
    let stdout = String::from_utf8_lossy(&result.stdout);
    assert!(
        result.status.success(),
        "{}",
        String::from_utf8_lossy(&result.stderr)
    );
    assert!(
        stdout.contains("pupil light response: no residual"),
        "{stdout}"
    );
    assert!(!stdout.contains("NaN"), "{stdout}");
    // Its warning that the pupil has no physical scale is said once (a
    // log line repeated it).
    let stderr = String::from_utf8_lossy(&result.stderr);
    assert_eq!(
        stderr
            .matches("the pupil is measured in raw tracker units")
            .count(),
        1,
        "{stderr}"
    );
    let _ = std::fs::remove_dir_all(&dir);
}
