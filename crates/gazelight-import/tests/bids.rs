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
use gazelight_import::bids::{BidsNames, Transaction, export_derivative, export_raw};

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
    let mut tx = Transaction::new(root, &names).unwrap();
    let report = export_raw(imp.as_mut(), &mut tx, recording).unwrap();
    assert_eq!(report.unit_mismatch, 0);
    let mut chain = FilterChain::with_defaults();
    let mut again = gazelight_import::open(recording).unwrap();
    export_derivative(again.as_mut(), &mut chain, &mut tx, None).unwrap();
    tx.commit().unwrap();

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
    let mut tx = Transaction::new(&root.join("ds"), &names).unwrap();
    export_raw(imp.as_mut(), &mut tx, &csv).unwrap();
    let mut again = gazelight_import::open(&csv).unwrap();
    let mut chain = FilterChain::with_defaults();
    let report = export_derivative(again.as_mut(), &mut chain, &mut tx, Some(&timeline)).unwrap();
    tx.commit().unwrap();
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

/// The sidecars (`*.json`) under `dir`, recursively: (name, JSON).
fn sidecars(dir: &Path) -> Vec<(String, serde_json::Value)> {
    let mut out = Vec::new();
    for e in std::fs::read_dir(dir).unwrap().flatten() {
        let p = e.path();
        if p.is_dir() {
            out.extend(sidecars(&p));
        } else if p.extension().is_some_and(|x| x == "json") {
            let text = std::fs::read_to_string(&p).unwrap();
            let name = p.file_name().unwrap().to_string_lossy().into_owned();
            out.push((name, serde_json::from_str(&text).unwrap()));
        }
    }
    out.sort_by(|a, b| a.0.cmp(&b.0));
    out
}

/// Issue 45 item 9: every shipped recording, and a left-eye-only EyeLink
/// file, exported raw and derivative, passes the official validator with
/// 0 errors; the eye sidecars carry the rate the recording states (the
/// EyeLink file's own `SAMPLES … RATE 500.00` line, Neon's `info.json`
/// `gaze_frequency`; read here from the files), the tracker's maker and
/// model from the recording (the ASC header's `(EyeLink 1000 Plus)`), and
/// no path of the exporting machine; one eye stays one eye.
#[test]
fn every_shipped_recording_and_one_eye_exports_a_valid_dataset() {
    let root = temp("all");
    let mono = gazelight_test_support::data::left_eye_eyelink(&temp("mono-src"));
    let asc = std::fs::read_to_string(data("eyelink-psa/both_eyes.asc")).unwrap();
    let stated_rate: f64 = asc
        .lines()
        .find(|l| l.starts_with("SAMPLES"))
        .and_then(|l| {
            let f: Vec<&str> = l.split_whitespace().collect();
            let k = f.iter().position(|w| *w == "RATE")?;
            f.get(k + 1)?.parse().ok()
        })
        .expect("the ASC's SAMPLES … RATE line");
    let model = asc
        .lines()
        .find(|l| l.starts_with("** EYELINK"))
        .and_then(|l| Some(l[l.rfind('(')? + 1..l.rfind(')')?].to_owned()))
        .expect("the ASC header's model");
    let info: serde_json::Value =
        serde_json::from_str(&std::fs::read_to_string(data("neon-demo/info.json")).unwrap())
            .unwrap();
    let neon_rate = info["gaze_frequency"].as_f64().unwrap();
    // (subject, recording, stated rate, (maker, model), eye files).
    type Case<'a> = (
        &'a str,
        PathBuf,
        f64,
        Option<(&'a str, &'a str)>,
        &'a [&'a str],
    );
    let cases: [Case; 4] = [
        (
            "eyelink",
            data("eyelink-psa/both_eyes.asc"),
            stated_rate,
            Some(("SR Research", model.as_str())),
            &["eye1", "eye2", "eye3"],
        ),
        (
            "eyelinkleft",
            mono.clone(),
            stated_rate,
            Some(("SR Research", model.as_str())),
            &["eye2"],
        ),
        (
            "neon",
            data("neon-demo"),
            neon_rate,
            Some(("Pupil Labs", "Neon")),
            &["eye1", "eye2", "eye3"],
        ),
        // No stated rate: the rows' rate without pauses (≈ 197 Hz).
        (
            "piprkit",
            data("piprkit-plr/pupil_trace.csv"),
            f64::NAN,
            None,
            &["eye1", "eye2"],
        ),
    ];
    for (subject, recording, rate, device, eyes) in &cases {
        let names = BidsNames {
            subject: (*subject).into(),
            session: None,
            task: "replay".into(),
            run: None,
        };
        let mut imp = gazelight_import::open(recording).unwrap();
        let mut tx = Transaction::new(&root, &names).unwrap();
        let report = export_raw(imp.as_mut(), &mut tx, recording).unwrap();
        let mut chain = FilterChain::with_defaults();
        let mut again = gazelight_import::open(recording).unwrap();
        let der = export_derivative(again.as_mut(), &mut chain, &mut tx, None).unwrap();
        tx.commit().unwrap();
        let raw_dir = root.join(names.dir());
        let der_dir = root.join("derivatives/gazelight").join(names.dir());
        let found = |dir: &Path, tail: &str| -> Vec<String> {
            let mut v: Vec<String> = std::fs::read_dir(dir)
                .unwrap()
                .flatten()
                .map(|e| e.file_name().to_string_lossy().into_owned())
                .filter(|n| n.ends_with(tail))
                .map(|n| n[n.find("_recording-").unwrap() + 11..n.len() - tail.len()].to_owned())
                .collect();
            v.sort();
            v
        };
        assert_eq!(found(&raw_dir, "_physio.tsv.gz"), *eyes, "{subject} raw");
        let filtered: Vec<String> = eyes
            .iter()
            .filter(|e| **e != "eye3")
            .map(|e| format!("{e}filtered"))
            .collect();
        assert_eq!(found(&der_dir, "_physio.tsv.gz"), filtered, "{subject}");
        // Each events file beside its own eye's data (the crash: events
        // eye1filtered beside data eye2filtered).
        for ev in found(&der_dir, "_physioevents.tsv.gz") {
            assert!(
                filtered.contains(&ev),
                "{subject}: events {ev} without its data"
            );
        }
        for (name, json) in sidecars(&raw_dir)
            .into_iter()
            .filter(|(n, _)| n.ends_with("_physio.json"))
        {
            let f = json["SamplingFrequency"].as_f64().unwrap();
            if rate.is_nan() {
                assert!((150.0..250.0).contains(&f), "{name}: {f}");
            } else {
                assert_eq!(f, *rate, "{name}");
            }
            match device {
                Some((maker, model)) => {
                    assert_eq!(json["Manufacturer"], *maker, "{name}");
                    assert_eq!(json["ManufacturersModelName"], *model, "{name}");
                }
                None => assert!(json.get("Manufacturer").is_none(), "{name}"),
            }
            let source = json["RecordingSource"].as_str().unwrap();
            let file = recording.file_name().unwrap().to_string_lossy();
            assert!(source.starts_with(file.as_ref()), "{name}: {source}");
            eprintln!("{name}: {f} Hz, {}, {source}", json["Manufacturer"]);
        }
        eprintln!(
            "{subject}: raw {:?}, derivative {} files",
            report
                .files
                .iter()
                .map(|(p, n, r)| (p.file_name().unwrap().to_owned(), *n, *r))
                .collect::<Vec<_>>(),
            der.files.len()
        );
    }
    // No sidecar holds a path of this machine: not the data's, not the
    // dataset's, not the temporary folder's.
    let data_dir = gazelight_test_support::data_path("eye");
    for (name, json) in sidecars(&root) {
        let text = json.to_string();
        for p in [&data_dir, &root, &std::env::temp_dir()] {
            let p = p.display().to_string();
            assert!(!text.contains(&p), "{name} holds {p}: {text}");
        }
        assert!(
            !text.contains("/tmp/") && !text.contains("/work/"),
            "{name}: {text}"
        );
    }
    gazelight_test_support::bids::validate(&root);
    gazelight_test_support::bids::validate(&root.join("derivatives/gazelight"));
    let _ = std::fs::remove_dir_all(&root);
    let _ = std::fs::remove_dir_all(mono.parent().unwrap());
}
