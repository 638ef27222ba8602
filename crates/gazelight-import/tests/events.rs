#![allow(clippy::unwrap_used, clippy::expect_used)] // test code may panic on a failed setup
//! Recording events against outside truth: the shipped EyeLink file's
//! `MSG` lines as this test reads them from the text itself, the Neon
//! demo's `event.time`/`event.txt`, an XDF marker stream written by the
//! test's own XDF writer (tests/xdf/write_eye_xdf.py) and read by pyxdf,
//! and a Pupil Core recording whose annotations this test writes with
//! rmpv (msgpack), not gazelight's writer.

use std::path::{Path, PathBuf};
use std::process::Command;

use gazelight_import::events;
use gazelight_test_support::{data_path, skip_or_fail};

fn tmp(name: &str) -> PathBuf {
    let d = std::env::temp_dir().join(format!("gazelight-events-{}-{name}", std::process::id()));
    let _ = std::fs::remove_dir_all(&d);
    std::fs::create_dir_all(&d).unwrap();
    d
}

/// The MSG lines of an ASC text as (time ms after SR Research's offset,
/// text), parsed here without the importer.
fn msg_lines(text: &str) -> Vec<(f64, String)> {
    text.lines()
        .filter_map(|l| l.strip_prefix("MSG"))
        .map(|rest| {
            let rest = rest.trim_start();
            let (t, msg) = rest.split_once(char::is_whitespace).unwrap_or((rest, ""));
            let t: f64 = t.parse().unwrap();
            let msg = msg.trim();
            match msg.split_once(char::is_whitespace) {
                Some((first, after)) if first.parse::<i64>().is_ok() => {
                    (t - first.parse::<f64>().unwrap(), after.trim().to_owned())
                }
                _ => (t, msg.to_owned()),
            }
        })
        .collect()
}

#[test]
fn the_shipped_eyelink_recordings_msg_lines_all_with_their_times_and_trials() {
    let path = data_path("eye/eyelink-psa/both_eyes.asc");
    let text = std::fs::read_to_string(&path).unwrap();
    let mut truth = msg_lines(&text);
    assert_eq!(truth.len(), 308, "the file's MSG lines (grep -c '^MSG')");
    let ev = events::read(&path).unwrap();
    assert_eq!(ev.format, "eyelink-asc");
    assert_eq!(ev.events.len(), truth.len());
    assert_eq!(ev.dropped, 0);
    assert_eq!(ev.warnings.skipped_records, 0);
    // The events are sorted by time (offset messages move); so is truth.
    truth.sort_by(|a, b| a.0.total_cmp(&b.0));
    for (e, (t_ms, msg)) in ev.events.iter().zip(&truth) {
        assert_eq!(e.t_clock, *t_ms, "{msg}");
        assert!((e.t_secs - t_ms * 1e-3).abs() < 1e-9);
        assert_eq!(&e.text, msg);
        assert_eq!(e.source, "MSG");
    }
    // `MSG 229837 -7 Instruction_screen`: 7 ms after it was logged.
    let instr = ev
        .events
        .iter()
        .find(|e| e.text == "Instruction_screen")
        .unwrap();
    assert_eq!(instr.t_clock, 229_844.0);
    // A trial per TRIALID line, each with its TRIAL_VARs and result.
    let trialids = truth
        .iter()
        .filter(|(_, m)| m.starts_with("TRIALID"))
        .count();
    let trial_vars = truth
        .iter()
        .filter(|(_, m)| m.starts_with("!V TRIAL_VAR"))
        .count();
    assert_eq!((trialids, trial_vars), (4, 12));
    assert_eq!(ev.trials.len(), trialids);
    for (k, t) in ev.trials.iter().enumerate() {
        assert_eq!(t.id, k.to_string());
        assert_eq!(t.result.as_deref(), Some("0"));
        let index = t.vars.iter().find(|(n, _)| n == "Trial_Index_").unwrap();
        assert_eq!(index.1, (k + 1).to_string());
        assert!(t.vars.contains(&("Session_Name_".into(), "d35b".into())));
    }
    assert!((ev.trials[0].start_t_secs - 349.505).abs() < 1e-9);
    assert!((ev.trials[0].end_t_secs.unwrap() - 384.907).abs() < 1e-9);
    // The events between a TRIALID and its TRIAL_RESULT carry the trial.
    let in_trial_1 = ev
        .events
        .iter()
        .filter(|e| e.t_clock >= 397_252.0 && e.t_clock <= 432_453.0)
        .all(|e| e.trial == Some(1));
    assert!(in_trial_1);
    let s = ev.summary();
    assert_eq!(s.total, 308);
    assert_eq!(s.trials, trialids as u64);
    assert!(
        s.kinds
            .iter()
            .any(|c| c.name == "TRIALID" && c.count == trialids as u64)
    );
    assert!(
        s.kinds
            .iter()
            .any(|c| c.name == "!V TRIAL_VAR" && c.count == trial_vars as u64)
    );
}

#[test]
fn the_neon_demos_events_on_the_importers_clock() {
    let dir = data_path("eye/neon-demo");
    let ev = events::read(&dir).unwrap();
    let names: Vec<&str> = ev.events.iter().map(|e| e.text.as_str()).collect();
    assert_eq!(names, ["recording.begin", "recording.end"]);
    // event.time: 1760676788219000000 and 1760676799438000000 ns; the
    // importer's clock starts at info.json's start_time 1760676788219000000.
    assert_eq!(ev.events[0].t_secs, 0.0);
    assert!((ev.events[1].t_secs - 11.219).abs() < 1e-9);
    assert_eq!(ev.events[1].source, "event");
}

/// A Pupil Core recording written here: `pupil.pldata` of 200 Hz pupil
/// datums from Pupil time 5000 s and an `annotation.pldata`, both as
/// msgpack `[topic, payload]` records (Pupil's file_methods layout).
pub fn pupil_recording_with_annotations(dir: &Path, annotations: &[(f64, &str)]) {
    use rmpv::Value;
    let record = |topic: &str, payload: Value| {
        let mut p = Vec::new();
        rmpv::encode::write_value(&mut p, &payload).unwrap();
        let mut r = Vec::new();
        rmpv::encode::write_value(
            &mut r,
            &Value::Array(vec![Value::from(topic), Value::Binary(p)]),
        )
        .unwrap();
        r
    };
    let mut pupil = Vec::new();
    for i in 0..2000 {
        let t = 5000.0 + f64::from(i) * 0.005;
        for eye in 0..2 {
            pupil.extend(record(
                &format!("pupil.{eye}.3d"),
                Value::Map(vec![
                    ("topic".into(), format!("pupil.{eye}.3d").into()),
                    ("timestamp".into(), t.into()),
                    ("id".into(), eye.into()),
                    ("confidence".into(), 0.95.into()),
                    ("diameter".into(), 40.0.into()),
                    ("diameter_3d".into(), 4.0.into()),
                    (
                        "norm_pos".into(),
                        Value::Array(vec![0.5.into(), 0.5.into()]),
                    ),
                    ("method".into(), "pye3d 0.3.0 real-time".into()),
                ]),
            ));
        }
    }
    std::fs::write(dir.join("pupil.pldata"), pupil).unwrap();
    let mut notes = Vec::new();
    for (t, label) in annotations {
        notes.extend(record(
            "annotation",
            Value::Map(vec![
                ("topic".into(), "annotation".into()),
                ("label".into(), (*label).into()),
                ("timestamp".into(), (*t).into()),
                ("duration".into(), 0.0.into()),
            ]),
        ));
    }
    std::fs::write(dir.join("annotation.pldata"), notes).unwrap();
}

#[test]
fn pupil_annotations_written_here_are_read_at_their_pupil_times() {
    let dir = tmp("pupil");
    let notes = [(5001.0, "dark"), (5003.25, "bright, on"), (5007.5, "end")];
    pupil_recording_with_annotations(&dir, &notes);
    let ev = events::read(&dir).unwrap();
    assert_eq!(ev.format, "pupil-core");
    assert_eq!(ev.events.len(), 3);
    for (e, (t, label)) in ev.events.iter().zip(notes) {
        assert_eq!((e.t_secs, e.text.as_str()), (t, label));
        assert_eq!(e.source, "annotation");
    }
    // The samples are on the same clock.
    let first = gazelight_import::open(&dir)
        .unwrap()
        .next()
        .unwrap()
        .unwrap()
        .t_secs();
    assert_eq!(first, 5000.0);
    std::fs::remove_dir_all(&dir).ok();
}

/// The stand-in XDF (the eye stream of the piprkit recording's first
/// `rows` rows and its flashes as a string marker stream), or None
/// without python3.
fn stand_in(dir: &Path, rows: usize) -> Option<PathBuf> {
    let plr = data_path("eye/piprkit-plr");
    let out = dir.join("markers.xdf");
    let script = Path::new(env!("CARGO_MANIFEST_DIR")).join("tests/xdf/write_eye_xdf.py");
    match Command::new("python3")
        .arg(&script)
        .arg("gazelight-eye")
        .arg(plr.join("pupil_trace.csv"))
        .arg(plr.join("stimuli.csv"))
        .arg(rows.to_string())
        .arg(&out)
        .status()
    {
        Ok(s) => assert!(s.success(), "write_eye_xdf.py failed"),
        Err(e) => {
            skip_or_fail(&format!("python3 not runnable: {e}"));
            return None;
        }
    }
    Some(out)
}

#[test]
fn an_xdf_marker_stream_is_read_at_pyxdfs_stamps_on_the_eye_streams_clock() {
    let dir = tmp("xdf");
    let Some(xdf) = stand_in(&dir, 14_000) else {
        return;
    };
    let ev = events::read(&xdf).unwrap();
    // stimuli.csv's flashes within the first 14000 rows (70 s): two, each
    // an on and an off marker.
    let stimuli = std::fs::read_to_string(data_path("eye/piprkit-plr/stimuli.csv")).unwrap();
    let flashes: Vec<(f64, f64, f64)> = stimuli
        .lines()
        .skip(1)
        .map(|l| {
            let f: Vec<f64> = l.split(',').skip(1).map(|v| v.parse().unwrap()).collect();
            (f[0], f[1], f[2])
        })
        .filter(|f| f.1 <= 70.0)
        .collect();
    assert_eq!(flashes.len(), 2);
    assert_eq!(ev.events.len(), 4);
    // The writer's clocks (write_eye_xdf.py): a marker of trace time s is
    // stamped LSL_T0 + s on the sender's clock, and every clock offset
    // is OFFSET0 + DRIFT·t: on the recorder's clock it is at
    // LSL_T0 + s + OFFSET0 + DRIFT·s (the eye stream's samples likewise).
    const LSL_T0: f64 = 3021.5;
    const OFFSET0: f64 = -0.2375;
    const DRIFT: f64 = 4e-6;
    let mut k = 0;
    for (s, e, i) in &flashes {
        for (t_trace, text) in [
            (*s, format!("flash on {i:.3}")),
            (*e, "flash off".to_owned()),
        ] {
            let m = &ev.events[k];
            assert_eq!(m.text, text);
            assert_eq!(m.source, "stimuli");
            let expected = LSL_T0 + t_trace + OFFSET0 + DRIFT * t_trace;
            assert!(
                (m.t_secs - expected).abs() < 1e-6,
                "marker `{text}` at {} s, written for {expected} s",
                m.t_secs
            );
            k += 1;
        }
    }
    // pyxdf's stamps of the marker stream, where pyxdf is there.
    let script = Path::new(env!("CARGO_MANIFEST_DIR")).join("tests/xdf/pyxdf_dump.py");
    let out = Command::new("python3")
        .arg(script)
        .arg(&xdf)
        .output()
        .unwrap();
    if !out.status.success() {
        skip_or_fail(&format!("pyxdf: {}", String::from_utf8_lossy(&out.stderr)));
        return;
    }
    let v: serde_json::Value = serde_json::from_slice(&out.stdout).unwrap();
    let markers = v["streams"]
        .as_array()
        .unwrap()
        .iter()
        .find(|s| s["name"] == "stimuli")
        .unwrap();
    let stamps: Vec<f64> = markers["time_stamps"]
        .as_array()
        .unwrap()
        .iter()
        .map(|t| t.as_f64().unwrap())
        .collect();
    assert_eq!(stamps.len(), ev.events.len());
    for (e, t) in ev.events.iter().zip(stamps) {
        assert!((e.t_secs - t).abs() < 1e-7, "{} vs pyxdf {t}", e.t_secs);
    }
    std::fs::remove_dir_all(&dir).ok();
}

#[test]
fn a_neon_cloud_events_csv_beside_an_export() {
    let dir = tmp("cloud");
    std::fs::write(
        dir.join("3d_eye_states.csv"),
        "section id,recording id,timestamp [ns],pupil diameter left [mm],pupil diameter right [mm]\n\
         s,r,1700000000000000000,4.0,4.1\ns,r,1700000000005000000,4.0,4.1\n",
    )
    .unwrap();
    std::fs::write(
        dir.join("events.csv"),
        "recording id,timestamp [ns],name,type\nr,1700000000000000000,recording.begin,recording\n\
         r,1700000000002500000,\"stim, on\",cloud\nr,bad,x,cloud\n",
    )
    .unwrap();
    let ev = events::read(&dir.join("3d_eye_states.csv")).unwrap();
    assert_eq!(ev.events.len(), 2);
    assert_eq!(ev.events[1].text, "stim, on");
    assert_eq!(ev.warnings.skipped_records, 1);
    assert!(ev.warnings.messages[0].contains("events.csv (line 4)"));
    // The CSV importer's clock: ns × 1e-9.
    let first = gazelight_import::open(&dir.join("3d_eye_states.csv"))
        .unwrap()
        .next()
        .unwrap()
        .unwrap()
        .t_secs();
    assert!((ev.events[0].t_secs - first).abs() < 1e-6);
    assert!((ev.events[1].t_secs - first - 0.0025).abs() < 1e-6);
    std::fs::remove_dir_all(&dir).ok();
}

fn gz(path: &Path, text: &str) {
    use std::io::Write;
    let mut e = flate2::write::GzEncoder::new(Vec::new(), flate2::Compression::default());
    e.write_all(text.as_bytes()).unwrap();
    std::fs::write(path, e.finish().unwrap()).unwrap();
}

/// A BIDS recording written here (timestamps in ms, `StartTime` −2 s):
/// its physioevents messages at their onsets, its `_events.tsv` onsets
/// moved onto the physio clock (first sample 1.000 s, at `StartTime`).
#[test]
fn bids_physioevents_messages_and_task_events_on_the_physio_clock() {
    let dir = tmp("bids");
    let stem = "sub-01_task-x_recording-eye1";
    gz(
        &dir.join(format!("{stem}_physio.tsv.gz")),
        "1000\t0.5\t0.5\t4.0\n1002\t0.5\t0.5\t4.1\n1004\t0.5\t0.5\t4.2\n",
    );
    std::fs::write(
        dir.join(format!("{stem}_physio.json")),
        r#"{"PhysioType": "eyetrack", "RecordedEye": "right", "SamplingFrequency": 500,
            "StartTime": -2.0, "Columns": ["timestamp", "x_coordinate", "y_coordinate", "pupil_size"],
            "timestamp": {"Units": "ms"}, "pupil_size": {"Units": "mm"}}"#,
    )
    .unwrap();
    std::fs::write(
        dir.join(format!("{stem}_physioevents.json")),
        r#"{"Columns": ["onset", "duration", "trial_type", "message"]}"#,
    )
    .unwrap();
    gz(
        &dir.join(format!("{stem}_physioevents.tsv.gz")),
        "1001\tn/a\tn/a\tSTIM on\n1002\t100\tblink\tn/a\n1003\tn/a\tfixation\tn/a\n1004\t2\tcue\tn/a\n",
    );
    std::fs::write(
        dir.join("sub-01_task-x_events.tsv"),
        "onset\tduration\ttrial_type\n3.5\t1\tgo\nbad\t1\tx\n",
    )
    .unwrap();
    let ev = events::read(&dir.join(format!("{stem}_physio.tsv.gz"))).unwrap();
    let got: Vec<(f64, &str, &str, Option<f64>)> = ev
        .events
        .iter()
        .map(|e| {
            (
                e.t_secs,
                e.text.as_str(),
                e.source.as_str(),
                e.duration_secs,
            )
        })
        .collect();
    assert_eq!(got.len(), 3, "{got:?}");
    assert!(
        (got[0].0 - 1.001).abs() < 1e-12 && got[0].1 == "STIM on" && got[0].2 == "physioevents"
    );
    assert!((got[1].0 - 1.004).abs() < 1e-12 && got[1].1 == "cue");
    assert!((got[1].3.unwrap() - 0.002).abs() < 1e-12, "ms → s");
    // 1.000 s + (3.5 − (−2.0)) s.
    assert!((got[2].0 - 6.5).abs() < 1e-12 && got[2].1 == "go" && got[2].2 == "events");
    assert_eq!(ev.warnings.skipped_records, 1);
    // The samples are on the same clock.
    let first = gazelight_import::open(&dir.join(format!("{stem}_physio.tsv.gz")))
        .unwrap()
        .next()
        .unwrap()
        .unwrap()
        .t_secs();
    assert!((first - 1.0).abs() < 1e-12);
    std::fs::remove_dir_all(&dir).ok();
}

/// Hostile event files: a Neon `event.time` cut mid-record and a Pupil
/// `annotation.pldata` whose tail is garbage keep what came before, with
/// counted warnings, never an error.
#[test]
fn damaged_event_files_keep_what_is_readable() {
    let dir = tmp("damaged");
    pupil_recording_with_annotations(&dir, &[(5001.0, "a"), (5002.0, "b")]);
    let mut bytes = std::fs::read(dir.join("annotation.pldata")).unwrap();
    bytes.extend(std::iter::repeat_n(0xc1u8, 2 << 20));
    std::fs::write(dir.join("annotation.pldata"), bytes).unwrap();
    let ev = events::read(&dir).unwrap();
    assert_eq!(ev.events.len(), 2);
    assert!(
        ev.warnings
            .messages
            .iter()
            .any(|m| m.contains("annotation.pldata")),
        "{:?}",
        ev.warnings.messages
    );
    std::fs::remove_dir_all(&dir).ok();

    let neon = tmp("neon-cut");
    let demo = data_path("eye/neon-demo");
    for e in std::fs::read_dir(&demo).unwrap().flatten() {
        std::fs::copy(e.path(), neon.join(e.file_name())).unwrap();
    }
    let mut t = std::fs::read(neon.join("event.time")).unwrap();
    t.extend([1, 2, 3]);
    std::fs::set_permissions(
        neon.join("event.time"),
        <std::fs::Permissions as std::os::unix::fs::PermissionsExt>::from_mode(0o644),
    )
    .unwrap();
    std::fs::write(neon.join("event.time"), t).unwrap();
    let ev = events::read(&neon).unwrap();
    assert_eq!(ev.events.len(), 2);
    assert_eq!(ev.warnings.skipped_records, 1);
    assert!(
        ev.warnings.messages[0].contains("3 trailing bytes"),
        "{:?}",
        ev.warnings.messages
    );
    std::fs::remove_dir_all(&neon).ok();
}
