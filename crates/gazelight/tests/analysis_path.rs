#![allow(clippy::unwrap_used, clippy::expect_used)] // test code may panic on a failed setup
//! Analysis at study speed (issue 47): a run that writes no frame image
//! (`--no-frames`) computes only its numbers (`gazelight_render::analysis`);
//! the same run with `--full-pipeline` renders every frame. The image
//! pipeline is the reference here: each case runs both ways on the CPU
//! backend and every output is compared — every column of `timeline.csv`
//! but the stage timings, byte for byte (the numbers path does the same
//! f32/f64 arithmetic in the same order, so no tolerance is needed), the
//! timings empty on the numbers path and filled on the full one, and the
//! contact sheet, plot and events byte for byte (the sheet's frames are
//! drawn in the state the numbers carried).

mod common;

use std::path::Path;

use common::{gazelight, shared_str, tmp};

/// The stage timing columns: the image pipeline's wall-clock times.
const TIMINGS: [&str; 7] = [
    "pooling_ms",
    "temporal_ms",
    "psf_ms",
    "glare_ms",
    "acuity_ms",
    "tone_colour_encode_ms",
    "total_ms",
];

fn is_timing(column: &str) -> bool {
    TIMINGS.iter().any(|t| {
        column == *t
            || column
                .strip_prefix(t)
                .is_some_and(|s| s == "_left" || s == "_right")
    })
}

/// Runs `args` with `--out DIR/numbers` and with `--full-pipeline --out
/// DIR/full`; returns both stdouts.
fn both_ways(dir: &Path, args: &[&str]) -> [String; 2] {
    ["numbers", "full"].map(|how| {
        let out = dir.join(how);
        let mut argv: Vec<&str> = args.to_vec();
        if how == "full" {
            argv.push("--full-pipeline");
        }
        argv.extend(["--out", out.to_str().unwrap()]);
        let o = gazelight(&argv);
        let stdout = String::from_utf8_lossy(&o.stdout).into_owned();
        assert!(
            o.status.success(),
            "{how}: {argv:?}\n{stdout}\n{}",
            String::from_utf8_lossy(&o.stderr)
        );
        stdout
    })
}

/// The comparison; returns (rows, columns compared).
fn assert_same_numbers(dir: &Path) -> (usize, usize) {
    let read = |how: &str| std::fs::read_to_string(dir.join(how).join("timeline.csv")).unwrap();
    let (fast, full) = (read("numbers"), read("full"));
    let (mut fast, mut full) = (fast.lines(), full.lines());
    let header = fast.next().unwrap();
    assert_eq!(header, full.next().unwrap(), "the same columns");
    let columns: Vec<&str> = header.split(',').collect();
    assert_eq!(
        columns.iter().filter(|c| is_timing(c)).count() % TIMINGS.len(),
        0
    );
    let mut rows = 0;
    for (a, b) in fast.zip(full.by_ref()) {
        let (a, b): (Vec<&str>, Vec<&str>) = (a.split(',').collect(), b.split(',').collect());
        assert_eq!((a.len(), b.len()), (columns.len(), columns.len()));
        for ((c, x), y) in columns.iter().zip(&a).zip(&b) {
            if is_timing(c) {
                assert!(x.is_empty(), "row {rows}: {c} = {x} on the numbers path");
                assert!(
                    y.parse::<f64>().is_ok(),
                    "row {rows}: {c} = '{y}' on the full path"
                );
            } else {
                assert_eq!(
                    x, y,
                    "row {rows}, column {c}: numbers {x}, full pipeline {y}"
                );
            }
        }
        rows += 1;
    }
    assert!(full.next().is_none(), "the full path wrote more rows");
    for f in ["contact_sheet.png", "plot.png", "events.csv"] {
        let (a, b) = (dir.join("numbers").join(f), dir.join("full").join(f));
        if !b.exists() {
            assert!(!a.exists(), "{f}");
            continue;
        }
        assert!(
            std::fs::read(&a).unwrap() == std::fs::read(&b).unwrap(),
            "{f} differs between the two paths"
        );
    }
    let session = std::fs::read_to_string(dir.join("numbers").join("session.json")).unwrap();
    assert!(session.contains("\"render.path\""), "{session}");
    let full_session = std::fs::read_to_string(dir.join("full").join("session.json")).unwrap();
    assert!(!full_session.contains("\"render.path\""));
    let compared = columns.iter().filter(|c| !is_timing(c)).count();
    (rows, compared)
}

/// Stereo Neon with each eye's pupil light response and the glare
/// numbers: the per-eye kernels, adaptation fed back to the filter chain
/// and the light model must follow the pipeline's frame by frame.
#[test]
fn stereo_neon_replay_numbers_equal_the_full_pipeline() {
    let dir = tmp("neon");
    let rec = shared_str("eye/neon-demo");
    let [fast, full] = both_ways(
        &dir,
        &[
            "replay",
            &rec,
            "--stereo",
            "--no-frames",
            "--glare-numbers",
            "--size",
            "120x136",
            "--fps",
            "90",
            "--secs",
            "4",
            "--backend",
            "cpu",
        ],
    );
    assert!(fast.contains("analysed "), "{fast}");
    assert!(full.contains("rendered "), "{full}");
    let (rows, columns) = assert_same_numbers(&dir);
    println!("neon stereo: {rows} rows × {columns} columns equal");
    assert!(rows >= 360, "{rows}");
    let header = std::fs::read_to_string(dir.join("full").join("timeline.csv")).unwrap();
    for c in [
        "pupil_light_mm_left",
        "pupil_residual_mm_right",
        "adaptation_cd_m2_left",
        "psf_pupil_mm_right",
        "glare_veil_cie146_cd_m2_left",
    ] {
        assert!(header.lines().next().unwrap().contains(c), "{c}");
    }
}

/// EyeLink in raw units without a profile: the aperture comes from the
/// light-adaptation model, which the chain runs on the adaptation the
/// frames feed back — a loop the numbers path must close the same way.
#[test]
fn mono_eyelink_replay_with_the_model_aperture_is_the_same() {
    let dir = tmp("eyelink");
    let rec = shared_str("eye/eyelink-psa/both_eyes.asc");
    both_ways(
        &dir,
        &[
            "replay",
            &rec,
            "--no-frames",
            "--size",
            "96x104",
            "--fps",
            "60",
            "--from-secs",
            "5",
            "--secs",
            "4",
            "--backend",
            "cpu",
        ],
    );
    let (rows, columns) = assert_same_numbers(&dir);
    println!("eyelink mono: {rows} rows × {columns} columns equal");
    assert!(rows >= 240, "{rows}");
}

/// A 182° fisheye scene turned 80° right (its field ends 11° right of
/// the view's centre, the view's 45°): the gaze sweep (render's
/// default trace on a scene of one's own) crosses pixels without data,
/// where the pooled target holds the last one — and the contact sheet's
/// frames there need a pipeline holding that target.
#[test]
fn render_across_a_view_without_data_holds_the_same_targets() {
    let dir = tmp("nodata");
    let scene = Path::new(env!("CARGO_MANIFEST_DIR"))
        .join("../../tests/data/radiance/evalglare_testimage.hdr");
    both_ways(
        &dir,
        &[
            "render",
            "--scene",
            scene.to_str().unwrap(),
            "--no-frames",
            "--size",
            "96x72",
            "--hfov-deg",
            "90",
            "--yaw-deg",
            "80",
            "--pitch-deg",
            "0",
            "--backend",
            "cpu",
        ],
    );
    let (rows, _) = assert_same_numbers(&dir);
    // The sweep did reach pixels without data: some rows hold a target
    // (the same target on consecutive rows while the gaze moves).
    let text = std::fs::read_to_string(dir.join("full").join("timeline.csv")).unwrap();
    let mut lines = text.lines();
    let header: Vec<&str> = lines.next().unwrap().split(',').collect();
    let (u, target) = (
        header.iter().position(|c| *c == "gaze_u").unwrap(),
        header.iter().position(|c| *c == "target_cd_m2").unwrap(),
    );
    let cells: Vec<(String, String)> = lines
        .map(|l| {
            let f: Vec<&str> = l.split(',').collect();
            (f[u].to_owned(), f[target].to_owned())
        })
        .collect();
    let held = cells
        .windows(2)
        .filter(|w| w[0].1 == w[1].1 && w[0].0 != w[1].0)
        .count();
    println!("no-data render: {rows} rows, {held} with the target held");
    assert!(held > 0, "the sweep never left the scene's field");
}
