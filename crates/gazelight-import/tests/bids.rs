#![allow(clippy::unwrap_used, clippy::expect_used)] // test code may panic on a failed setup
//! BIDS eye-tracking: real recordings (`shared/data/eye`: the EyeLink
//! binocular ASC, the piprkit pupil CSV) written with `bids::export_raw`
//! read back through the BIDS importer give the same samples; the export
//! (raw and derivatives) passes the official BIDS validator
//! (`bids-validator-deno` from PyPI, installed by `.ci/test`) with 0
//! errors — outside CI a missing validator skips that part.

use std::path::{Path, PathBuf};

use gazelight_eye::filter::FilterChain;
use gazelight_eye::sample::Sample;
use gazelight_import::bids::{BidsNames, RecordingMeta, export_derivative, export_raw};

fn data(rel: &str) -> PathBuf {
    gazelight_test_support::data_path("eye").join(rel)
}

fn temp(name: &str) -> PathBuf {
    let d = std::env::temp_dir().join(format!("gazelight-bids-{name}-{}", std::process::id()));
    let _ = std::fs::remove_dir_all(&d);
    d
}

/// A sortable, comparable key of a sample: every field, NaN as a fixed
/// bit pattern.
fn key(s: &Sample) -> (u64, u8, u8, Vec<u64>) {
    let b = |v: f64| if v.is_nan() { u64::MAX } else { v.to_bits() };
    let f = |v: f32| b(f64::from(v));
    match s {
        Sample::Pupil(p) => (
            b(p.t_secs),
            0,
            p.eye,
            vec![
                f(p.diameter_raw),
                p.unit as u64,
                p.diameter_mm.map_or(u64::MAX - 1, f),
                f(p.confidence),
                f(p.norm_pos[0]),
                f(p.norm_pos[1]),
                p.method as u64,
            ],
        ),
        Sample::Gaze(g) => (
            b(g.t_secs),
            1,
            g.eyes as u8,
            vec![f(g.gaze_uv[0]), f(g.gaze_uv[1]), f(g.confidence)],
        ),
        Sample::Blink(k) => (
            b(k.start_t_secs),
            2,
            k.eye.unwrap_or(9),
            vec![b(k.end_t_secs)],
        ),
    }
}

fn all(path: &Path) -> Vec<Sample> {
    gazelight_import::open(path)
        .unwrap_or_else(|e| panic!("{}: {e}", path.display()))
        .map(|s| s.unwrap())
        .collect()
}

/// Exports `recording`, reads the BIDS files back and compares; returns
/// the dataset root and the sample count.
fn round_trip(recording: &Path, subject: &str, root: &Path) -> usize {
    let names = BidsNames {
        subject: subject.into(),
        session: None,
        task: "replay".into(),
        run: None,
    };
    let mut imp = gazelight_import::open(recording).unwrap();
    let meta = RecordingMeta {
        format: imp.format().into(),
        source: recording.display().to_string(),
    };
    let report = export_raw(&mut imp, root, &names, &meta).unwrap();
    assert_eq!(report.unit_mismatch, 0);
    let mut chain = FilterChain::with_defaults();
    let mut again = gazelight_import::open(recording).unwrap();
    export_derivative(&mut again, &mut chain, root, &names, None).unwrap();

    let first = root
        .join(names.dir())
        .join(format!("{}_recording-eye1_physio.tsv.gz", names.prefix()));
    let mut original: Vec<_> = all(recording).iter().map(key).collect();
    let mut back: Vec<_> = all(&first).iter().map(key).collect();
    original.sort();
    back.sort();
    assert_eq!(
        original.len(),
        back.len(),
        "{}: sample count",
        recording.display()
    );
    for (k, (a, b)) in original.iter().zip(&back).enumerate() {
        assert_eq!(a, b, "{}: sample {k} (sorted)", recording.display());
    }
    eprintln!(
        "{}: {} samples back identical from {:?}",
        recording.display(),
        back.len(),
        report.files
    );
    back.len()
}

#[test]
fn real_recordings_come_back_identical_and_the_export_validates() {
    let root = temp("roundtrip");
    let n_eyelink = round_trip(&data("eyelink-psa/both_eyes.asc"), "eyelink", &root);
    let n_plr = round_trip(&data("piprkit-plr/pupil_trace.csv"), "piprkit", &root);
    // The EyeLink file: 72 878 lines, mostly binocular samples (two
    // pupils and three gazes each) — the counts come from the importer,
    // the equality from the files.
    assert!(
        n_eyelink > 100_000 && n_plr > 100_000,
        "{n_eyelink} {n_plr}"
    );
    let participants = std::fs::read_to_string(root.join("participants.tsv")).unwrap();
    assert_eq!(participants, "participant_id\nsub-eyelink\nsub-piprkit\n");
    gazelight_test_support::bids::validate(&root);
    gazelight_test_support::bids::validate(&root.join("derivatives/gazelight"));
    let _ = std::fs::remove_dir_all(&root);
}

/// The rows of a gzipped TSV.
fn tsv_gz(path: &Path) -> Vec<Vec<String>> {
    use std::io::Read;
    let mut text = String::new();
    flate2::read::GzDecoder::new(std::fs::File::open(path).unwrap())
        .read_to_string(&mut text)
        .unwrap();
    text.lines()
        .map(|l| l.split('\t').map(str::to_owned).collect())
        .collect()
}

#[test]
fn a_replay_timeline_becomes_per_eye_derivatives_that_validate() {
    // A stereo replay's timeline.csv as `gazelight replay` writes it
    // (output.rs: t_secs, each view's 16 columns, then each view's
    // pupil_light_mm and pupil_residual_mm; an empty cell where the pupil
    // is not measured). Three frames, values typed in.
    let cols = [
        "gaze_u",
        "gaze_v",
        "pupil_mm",
        "pupil_held",
        "target_cd_m2",
        "adaptation_cd_m2",
        "psf_pupil_mm",
        "psf_rebuilt",
        "acuity_sigma_px",
        "pooling_ms",
        "temporal_ms",
        "psf_ms",
        "glare_ms",
        "acuity_ms",
        "tone_colour_encode_ms",
        "total_ms",
    ];
    let mut header = vec!["t_secs".to_owned()];
    for v in ["_left", "_right"] {
        header.extend(cols.iter().map(|c| format!("{c}{v}")));
    }
    for v in ["_left", "_right"] {
        header.push(format!("pupil_light_mm{v}"));
        header.push(format!("pupil_residual_mm{v}"));
    }
    let view = |u: f32, p: f32, lum: f32| {
        format!("{u},0.5,{p},0,{lum},{},{p},0,1.0,1,1,1,1,1,1,6", lum * 0.9)
    };
    let rows = [
        format!(
            "12.0000,{},{},4.10,0.25,4.20,-0.15",
            view(0.4, 4.35, 120.0),
            view(0.6, 4.45, 80.0)
        ),
        format!(
            "12.0111,{},{},4.11,,4.21,0.01",
            view(0.41, 4.30, 125.0),
            view(0.61, 4.22, 82.0)
        ),
        format!(
            "12.0222,{},{},4.12,0.10,4.22,",
            view(0.42, 4.22, 130.0),
            view(0.62, 4.20, 84.0)
        ),
    ];
    let root = temp("timeline");
    std::fs::create_dir_all(&root).unwrap();
    let timeline = root.join("timeline.csv");
    std::fs::write(
        &timeline,
        format!("{}\n{}\n", header.join(","), rows.join("\n")),
    )
    .unwrap();
    let names = BidsNames {
        subject: "01".into(),
        session: Some("a".into()),
        task: "night".into(),
        run: Some(2),
    };
    // The raw side from the piprkit recording, so the derivative has a
    // source; the timeline's frames are typed in above.
    let csv = data("piprkit-plr/pupil_trace.csv");
    let mut imp = gazelight_import::open(&csv).unwrap();
    let meta = RecordingMeta {
        format: "csv".into(),
        source: csv.display().to_string(),
    };
    export_raw(&mut imp, &root.join("ds"), &names, &meta).unwrap();
    let mut again = gazelight_import::open(&csv).unwrap();
    let mut chain = FilterChain::with_defaults();
    let report = export_derivative(
        &mut again,
        &mut chain,
        &root.join("ds"),
        &names,
        Some(&timeline),
    )
    .unwrap();
    let dir = root.join("ds/derivatives/gazelight/sub-01/ses-a/beh");
    let left =
        tsv_gz(&dir.join("sub-01_ses-a_task-night_run-2_recording-eye2replay_physio.tsv.gz"));
    let right =
        tsv_gz(&dir.join("sub-01_ses-a_task-night_run-2_recording-eye1replay_physio.tsv.gz"));
    // timestamp, x, y, pupil, luminance at gaze, adaptation, light, residual.
    assert_eq!(
        left[0],
        ["12", "0.4", "0.5", "4.35", "120", "108", "4.1", "0.25"]
    );
    assert_eq!(left[1][7], "n/a", "an empty residual is n/a");
    assert_eq!(
        right[2],
        ["12.0222", "0.62", "0.5", "4.2", "84", "75.6", "4.22", "n/a"]
    );
    assert_eq!(right[0][7], "-0.15");
    assert!(
        report.files.iter().any(
            |f| f.ends_with("sub-01_ses-a_task-night_run-2_recording-eye1replay_physio.tsv.gz")
        )
    );
    gazelight_test_support::bids::validate(&root.join("ds"));
    gazelight_test_support::bids::validate(&root.join("ds/derivatives/gazelight"));
    let _ = std::fs::remove_dir_all(&root);
}
