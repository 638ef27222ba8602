#![allow(clippy::unwrap_used, clippy::expect_used)] // test code may panic on a failed setup
//! BIDS eye-tracking: real recordings (`shared/data/eye`: the EyeLink
//! binocular ASC, the piprkit pupil CSV) written with `bids::export_raw`
//! read back through the BIDS importer give the same samples; the export
//! (raw and derivatives) passes the official BIDS validator
//! (`bids-validator-deno` from PyPI, installed by `.ci/test`) with 0
//! errors — outside CI a missing validator skips that part.

use std::path::{Path, PathBuf};
use std::process::Command;

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
    validate(&root);
    validate(&root.join("derivatives/gazelight"));
    let _ = std::fs::remove_dir_all(&root);
}

/// Runs the official validator on `root`; fails on any error.
fn validate(root: &Path) {
    let out = match Command::new("bids-validator-deno")
        .arg("--format")
        .arg("json")
        .arg(root)
        .output()
    {
        Ok(o) => o,
        Err(e) => {
            gazelight_test_support::skip_or_fail(&format!(
                "bids-validator-deno not runnable ({e}; pip install bids-validator-deno)"
            ));
            return;
        }
    };
    let report: serde_json::Value = serde_json::from_slice(&out.stdout).unwrap_or_else(|e| {
        panic!(
            "validator output is not JSON ({e}): {}",
            String::from_utf8_lossy(&out.stderr)
        )
    });
    let issues = report["issues"]["issues"]
        .as_array()
        .cloned()
        .unwrap_or_default();
    let errors: Vec<String> = issues
        .iter()
        .filter(|i| i["severity"] == "error")
        .map(|i| format!("{} {} {}", i["code"], i["subCode"], i["location"]))
        .collect();
    let warnings: Vec<String> = issues
        .iter()
        .filter(|i| i["severity"] == "warning")
        .map(|i| format!("{} {}", i["code"], i["location"]))
        .collect();
    eprintln!(
        "bids-validator-deno {} (schema {}): {} errors, {} warnings {warnings:?}",
        root.display(),
        report["summary"]["schemaVersion"],
        errors.len(),
        warnings.len()
    );
    assert!(errors.is_empty(), "{}: {errors:#?}", root.display());
}
