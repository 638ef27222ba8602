#![allow(clippy::unwrap_used, clippy::expect_used)] // test code may panic on a failed setup
//! The CSV/TSV importer reads what docs/replay.md says it reads (issue 45
//! item 8): gazelight's trace (`t_secs,gaze_u,gaze_v,pupil_mm[,confidence]`,
//! checked row by row against `render --trace`'s own parser, `GazeTrace`),
//! the old per-eye layout (`time,left,right`: the real piprkit recording,
//! its rows counted from the file's own lines), and a TSV export with
//! per-eye gaze, pupils in px and per-eye confidence. Every row is counted:
//! a lost pupil or gaze is a sample with confidence 0. Files are written by
//! the tests.

use std::path::{Path, PathBuf};

use gazelight_eye::sample::{GazeEyes, PupilUnit, Sample};
use gazelight_eye::trace::GazeTrace;

fn temp(name: &str, text: &str) -> PathBuf {
    let dir = std::env::temp_dir().join(format!("gazelight-csv-{}", std::process::id()));
    std::fs::create_dir_all(&dir).unwrap();
    let p = dir.join(name);
    std::fs::write(&p, text).unwrap();
    p
}

fn read(path: &Path) -> (Vec<Sample>, u64, Vec<String>) {
    let mut imp = gazelight_import::open(path).unwrap_or_else(|e| panic!("{e}"));
    let s: Vec<Sample> = imp
        .by_ref()
        .map(|s| s.unwrap_or_else(|e| panic!("{e}")))
        .collect();
    let w = imp.warnings().clone();
    (s, w.skipped_records, w.messages)
}

/// Pupil samples per eye, gaze samples per kind (binocular, right, left).
fn counts(s: &[Sample]) -> ([usize; 2], [usize; 3]) {
    let mut p = [0; 2];
    let mut g = [0; 3];
    for x in s {
        match x {
            Sample::Pupil(q) => p[usize::from(q.eye)] += 1,
            Sample::Gaze(q) => {
                g[match q.eyes {
                    GazeEyes::Binocular => 0,
                    GazeEyes::Right => 1,
                    GazeEyes::Left => 2,
                }] += 1
            }
            Sample::Blink(_) => {}
        }
    }
    (p, g)
}

/// The documented trace layout, with a blink (empty pupil, confidence 0)
/// and a lost gaze: every row gives a pupil of each eye and a gaze, the
/// same values `render --trace` reads from the file.
#[test]
fn the_documented_trace_layout_is_read_as_render_reads_it() {
    let mut text = String::from("# a trace\nt_secs,gaze_u,gaze_v,pupil_mm,confidence\n");
    for k in 0..400 {
        let t = f64::from(k) * 0.005;
        let blink = (100..130).contains(&k); // 150 ms
        let pupil = if blink {
            String::new()
        } else {
            format!("{:.3}", 4.0 + 0.5 * (t * 3.0).sin())
        };
        let gaze = format!("{:.4},{:.4}", 0.3 + 0.001 * f64::from(k), 0.6);
        let conf = if blink { "0.0" } else { "0.97" };
        text.push_str(&format!("{t:.3},{gaze},{pupil},{conf}\n"));
    }
    let path = temp("trace.csv", &text);
    let (s, skipped, _) = read(&path);
    assert_eq!(skipped, 0);
    assert_eq!(counts(&s), ([400, 400], [400, 0, 0]));
    // render --trace's parser of the same file: the reference.
    let trace = GazeTrace::load(&path).unwrap();
    assert_eq!(trace.samples.len(), 400);
    let mut lost_pupils = 0;
    for (row, chunk) in trace.samples.iter().zip(s.chunks(3)) {
        let [Sample::Pupil(r), Sample::Pupil(l), Sample::Gaze(g)] = chunk else {
            panic!("{chunk:?}")
        };
        for p in [r, l] {
            assert_eq!(p.t_secs, row.t_secs);
            assert_eq!(p.unit, PupilUnit::Mm);
            assert_eq!(p.diameter_mm, row.pupil_mm.filter(|d| *d > 0.0));
            if p.diameter_mm.is_none() {
                assert_eq!(p.confidence, 0.0);
                lost_pupils += 1;
            } else {
                assert_eq!(p.confidence, row.confidence);
            }
        }
        assert_eq!(g.t_secs, row.t_secs);
        assert_eq!(g.gaze_uv, row.gaze_uv);
        assert_eq!(g.confidence, row.confidence);
    }
    assert_eq!(lost_pupils, 60, "the 30 blink rows, both eyes");
    // A lost gaze (render's parser refuses one; a recording has them) is
    // a gaze sample with confidence 0, beside the row's pupils.
    let path = temp(
        "lost-gaze.csv",
        "t_secs,gaze_u,gaze_v,pupil_mm
0,nan,,4
",
    );
    let (s, skipped, _) = read(&path);
    assert_eq!((skipped, counts(&s)), (0, ([1, 1], [1, 0, 0])));
    let Sample::Gaze(g) = s[2] else { panic!() };
    assert!(g.gaze_uv[0].is_nan() && g.confidence == 0.0, "{g:?}");
}

/// The old layout still works: the real piprkit recording gives one
/// sample per eye for every data line of the file (counted here from the
/// file's lines, not by the importer).
#[test]
fn the_piprkit_layout_gives_two_samples_per_line() {
    let path = gazelight_test_support::data_path("eye").join("piprkit-plr/pupil_trace.csv");
    let text = std::fs::read_to_string(&path).unwrap();
    let lines = text
        .lines()
        .skip(1)
        .filter(|l| !l.trim().is_empty())
        .count();
    let (s, skipped, _) = read(&path);
    assert_eq!(skipped, 0);
    assert_eq!(counts(&s), ([lines, lines], [0, 0, 0]));
    eprintln!("piprkit: {lines} lines → {} samples", s.len());
}

/// A TSV export: time in ms, per-eye gaze and confidence, pupils in
/// eye-camera pixels, column names with spaces and brackets, an unknown
/// column (named in the notes), a row starting with an empty field.
#[test]
fn a_tsv_export_with_per_eye_columns() {
    let text = "Timestamp [ms]\tGaze U Left\tGaze V Left\tGaze U Right\tGaze V Right\t\
                Pupil Left [px]\tPupil Right [px]\tConfidence Left\tConfidence Right\tTrial\n\
                1000\t0.40\t0.50\t0.42\t0.51\t31.5\t30.0\t0.9\t0.8\t1\n\
                1002\t\t\t0.43\t0.52\t0\t30.5\t0.0\t0.85\t1\n\
                \t0.40\t0.50\t0.42\t0.51\t31.5\t30.0\t0.9\t0.8\t1\n\
                1004\t0.41\tx\t0.43\t0.52\t31.0\t30.5\t0.9\t0.85\t1\n";
    let path = temp("export.tsv", text);
    let (s, skipped, notes) = read(&path);
    // Row 3 has no time, row 4 a gaze that is not a number: skipped and
    // counted, with file, line and column.
    assert_eq!(skipped, 2, "{notes:?}");
    assert!(
        notes
            .iter()
            .any(|m| m.contains("export.tsv (line 5)") && m.contains("column 3")),
        "{notes:?}"
    );
    assert!(
        notes.iter().any(|m| m.contains("columns not read: Trial")),
        "{notes:?}"
    );
    assert_eq!(counts(&s), ([2, 2], [0, 2, 2]));
    let Sample::Pupil(r) = s[0] else { panic!() };
    assert_eq!(
        (
            r.eye,
            r.t_secs,
            r.diameter_raw,
            r.unit,
            r.confidence,
            r.diameter_mm
        ),
        (0, 1.0, 30.0, PupilUnit::Px, 0.8, None)
    );
    let Sample::Pupil(l) = s[1] else { panic!() };
    assert_eq!((l.eye, l.diameter_raw, l.confidence), (1, 31.5, 0.9));
    let Sample::Gaze(gr) = s[2] else { panic!() };
    assert_eq!(
        (gr.eyes, gr.gaze_uv, gr.confidence),
        (GazeEyes::Right, [0.42, 0.51], 0.8)
    );
    // Row 2: the left eye lost (pupil 0, empty gaze): kept, confidence 0.
    let Sample::Pupil(l2) = s[5] else { panic!() };
    assert_eq!((l2.eye, l2.diameter_raw, l2.confidence), (1, 0.0, 0.0));
    let Sample::Gaze(gl2) = s[7] else { panic!() };
    assert_eq!(gl2.eyes, GazeEyes::Left);
    assert!(gl2.gaze_uv[0].is_nan() && gl2.confidence == 0.0);
}

/// Headers that cannot be mapped are structure errors naming the file,
/// the line and the columns.
#[test]
fn unusable_headers_name_the_columns() {
    for (header, want) in [
        (
            "time,left,pupil_left_mm",
            "columns 2 (`left`) and 3 (`pupil_left_mm`)",
        ),
        (
            "time,pupil_mm,right",
            "a pupil column for both eyes beside per-eye",
        ),
        (
            "t_secs,gaze_u,pupil_mm",
            "one gaze coordinate without the other",
        ),
        ("gaze_u,gaze_v,pupil_mm", "no time column"),
        ("time,trial,label", "no pupil and no gaze column"),
    ] {
        let path = temp("bad.csv", &format!("# c\n{header}\n1,2,3\n"));
        let err = match gazelight_import::open(&path).unwrap().next() {
            Some(Err(e)) => e.to_string(),
            other => panic!("{header}: {other:?}"),
        };
        assert!(err.contains("bad.csv (line 2)"), "{err}");
        assert!(err.contains(want), "{header}: {err}");
        assert!(err.contains("t_secs|time"), "the mapping is named: {err}");
    }
}
