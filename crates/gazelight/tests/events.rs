#![allow(clippy::unwrap_used, clippy::expect_used)] // test code may panic on a failed setup
//! A recording's events reach the user (issue 47, events): `inspect`
//! counts them, `replay` writes `events.csv` with each event's time and
//! the frame it falls on. Checked against what this test knows without
//! gazelight: the shipped EyeLink file's `MSG` lines and first sample read
//! from its text; an XDF whose marker stream the test's writer
//! (crates/gazelight-import/tests/xdf/write_eye_xdf.py) stamps on known
//! clocks; a Pupil Core recording whose annotations this test encodes as
//! msgpack by hand.

mod common;

use std::path::Path;
use std::process::Command;

use common::{gazelight, shared, tmp};

/// A fast replay (no glare, tiny view, no frames) of `rec` into `out`.
fn replay(rec: &str, out: &Path, fps: &str) -> String {
    let config = out.with_extension("toml");
    std::fs::write(&config, "[pipeline]\nglare = { enabled = false }\n").unwrap();
    let o = gazelight(&[
        "replay",
        rec,
        "--size",
        "32x24",
        "--fps",
        fps,
        "--no-frames",
        "--backend",
        "cpu",
        "--config",
        config.to_str().unwrap(),
        "--out",
        out.to_str().unwrap(),
    ]);
    let stdout = String::from_utf8_lossy(&o.stdout).into_owned();
    let stderr = String::from_utf8_lossy(&o.stderr);
    assert!(o.status.success(), "replay {rec}: {stdout}\n{stderr}");
    stdout
}

/// A CSV line split on commas outside quotes ("" inside them).
fn fields(line: &str) -> Vec<String> {
    let mut out = vec![String::new()];
    let mut quoted = false;
    let mut chars = line.chars().peekable();
    while let Some(c) = chars.next() {
        match c {
            '"' if quoted && chars.peek() == Some(&'"') => {
                chars.next();
                out.last_mut().unwrap().push('"');
            }
            '"' => quoted = !quoted,
            ',' if !quoted => out.push(String::new()),
            c => out.last_mut().unwrap().push(c),
        }
    }
    out
}

/// events.csv as rows keyed by its header.
fn events_csv(out: &Path) -> Vec<std::collections::HashMap<String, String>> {
    let text = std::fs::read_to_string(out.join("events.csv")).unwrap();
    let mut lines = text.lines();
    let header = fields(lines.next().unwrap());
    assert_eq!(
        header,
        [
            "t_secs",
            "recording_t_secs",
            "t_clock",
            "duration_secs",
            "source",
            "text",
            "trial",
            "frame"
        ]
    );
    lines
        .map(|l| header.iter().cloned().zip(fields(l)).collect())
        .collect()
}

fn num(row: &std::collections::HashMap<String, String>, k: &str) -> f64 {
    row[k]
        .parse()
        .unwrap_or_else(|_| panic!("{k} = {:?}", row[k]))
}

/// The frame an event at `t_secs` from the first frame falls on at `fps`.
fn frame_of(t_secs: f64, fps: f64) -> Option<u64> {
    let k = (t_secs * fps + 1e-6).floor();
    (k >= 0.0).then_some(k as u64)
}

#[test]
fn the_shipped_eyelink_recordings_msg_lines_in_inspect_and_events_csv() {
    let rec = shared("eye/eyelink-psa/both_eyes.asc");
    let text = std::fs::read_to_string(&rec).unwrap();
    // The truth, from the text: each MSG line's time (minus SR Research's
    // offset, a leading integer before more text) and the first sample's.
    let mut msgs: Vec<(f64, String)> = Vec::new();
    let mut first_sample_ms = None;
    for l in text.lines() {
        if let Some(rest) = l.strip_prefix("MSG") {
            let (t, m) = rest.trim_start().split_once(char::is_whitespace).unwrap();
            let t: f64 = t.parse().unwrap();
            let m = m.trim();
            msgs.push(match m.split_once(char::is_whitespace) {
                Some((o, after)) if o.parse::<i64>().is_ok() => {
                    (t - o.parse::<f64>().unwrap(), after.trim().to_owned())
                }
                _ => (t, m.to_owned()),
            });
        } else if first_sample_ms.is_none() && l.starts_with(|c: char| c.is_ascii_digit()) {
            first_sample_ms = l.split_whitespace().next().unwrap().parse::<f64>().ok();
        }
    }
    msgs.sort_by(|a, b| a.0.total_cmp(&b.0));
    let t0 = first_sample_ms.unwrap() * 1e-3;
    let trialids = msgs.iter().filter(|m| m.1.starts_with("TRIALID")).count();

    // inspect: the count, the trials, the kinds.
    let o = gazelight(&["inspect", rec.to_str().unwrap()]);
    let stdout = String::from_utf8_lossy(&o.stdout);
    assert!(o.status.success(), "{stdout}");
    let line = format!(
        "events: {} (MSG {}), {trialids} trials",
        msgs.len(),
        msgs.len()
    );
    assert!(stdout.contains(&line), "no `{line}` in:\n{stdout}");
    let o = gazelight(&["inspect", "--json", rec.to_str().unwrap()]);
    let v: serde_json::Value = serde_json::from_slice(&o.stdout).unwrap();
    assert_eq!(v["events"]["total"], msgs.len());
    assert_eq!(v["events"]["first"][0]["t_clock"], msgs[0].0);
    let kinds = v["events"]["kinds"].as_array().unwrap();
    assert!(
        kinds
            .iter()
            .any(|k| k["name"] == "TRIALID" && k["count"] == trialids),
        "{kinds:?}"
    );

    // replay: events.csv, every MSG line with its time and frame.
    let out = tmp("eyelink");
    let fps = 10.0;
    let stdout = replay(rec.to_str().unwrap(), &out.join("replay"), "10");
    assert!(stdout.contains("events.csv: 308 events"), "{stdout}");
    let rows = events_csv(&out.join("replay"));
    assert_eq!(rows.len(), msgs.len());
    let timeline = std::fs::read_to_string(out.join("replay/timeline.csv")).unwrap();
    let frames = timeline.lines().count() as u64 - 1;
    let mut on_frames = 0;
    for (r, (t_ms, m)) in rows.iter().zip(&msgs) {
        assert_eq!(&r["text"], m);
        assert_eq!(r["source"], "MSG");
        assert_eq!(num(r, "t_clock"), *t_ms);
        assert!((num(r, "recording_t_secs") - t_ms * 1e-3).abs() < 1e-6);
        let rel = t_ms * 1e-3 - t0;
        assert!((num(r, "t_secs") - rel).abs() < 1e-6, "{m}");
        let want = frame_of(rel, fps).filter(|f| *f < frames);
        let got = (!r["frame"].is_empty()).then(|| num(r, "frame") as u64);
        assert_eq!(got, want, "{m} at {rel} s");
        on_frames += u64::from(got.is_some());
    }
    assert!(on_frames > 100, "{on_frames}");
    // The trial column: the TRIALID's id from it to its TRIAL_RESULT.
    let trial_1: Vec<_> = rows
        .iter()
        .filter(|r| (397_252.0..=432_453.0).contains(&num(r, "t_clock")))
        .collect();
    assert!(trial_1.len() > 5 && trial_1.iter().all(|r| r["trial"] == "1"));
    std::fs::remove_dir_all(&out).ok();
}

#[test]
fn xdf_markers_in_events_csv_at_the_writers_times() {
    let out = tmp("xdf");
    let plr = shared("eye/piprkit-plr");
    let xdf = out.join("markers.xdf");
    let script = Path::new(env!("CARGO_MANIFEST_DIR"))
        .join("../gazelight-import/tests/xdf/write_eye_xdf.py");
    match Command::new("python3")
        .arg(&script)
        .arg("gazelight-eye")
        .arg(plr.join("pupil_trace.csv"))
        .arg(plr.join("stimuli.csv"))
        .arg("14000")
        .arg(&xdf)
        .status()
    {
        Ok(s) => assert!(s.success()),
        Err(e) => {
            gazelight_test_support::skip_or_fail(&format!("python3: {e}"));
            return;
        }
    }
    // The writer's clocks: a marker of trace time s is at
    // LSL_T0 + s + OFFSET0 + DRIFT·s on the recorder's clock.
    let at = |s: f64| 3021.5 + s + -0.2375 + 4e-6 * s;
    let stimuli = std::fs::read_to_string(plr.join("stimuli.csv")).unwrap();
    let mut truth = Vec::new();
    for l in stimuli.lines().skip(1) {
        let f: Vec<f64> = l.split(',').skip(1).map(|v| v.parse().unwrap()).collect();
        if f[1] <= 70.0 {
            truth.push((at(f[0]), format!("flash on {:.3}", f[2])));
            truth.push((at(f[1]), "flash off".to_owned()));
        }
    }
    let fps = 50.0;
    replay(xdf.to_str().unwrap(), &out.join("replay"), "50");
    let rows = events_csv(&out.join("replay"));
    assert_eq!(rows.len(), truth.len());
    for (r, (t, text)) in rows.iter().zip(&truth) {
        assert_eq!(&r["text"], text);
        assert_eq!(r["source"], "stimuli");
        // Within one eye sample (200 Hz), in fact within a microsecond.
        assert!((num(r, "recording_t_secs") - t).abs() < 1e-5, "{text}");
        let rel = num(r, "t_secs");
        assert_eq!(num(r, "frame") as u64, frame_of(rel, fps).unwrap());
    }
    std::fs::remove_dir_all(&out).ok();
}

/// msgpack, by hand: a str, a float64, a map of str keys, a bin.
fn mp_str(b: &mut Vec<u8>, s: &str) {
    assert!(s.len() < 32);
    b.push(0xa0 | s.len() as u8);
    b.extend_from_slice(s.as_bytes());
}
fn mp_f64(b: &mut Vec<u8>, v: f64) {
    b.push(0xcb);
    b.extend_from_slice(&v.to_be_bytes());
}
/// One `.pldata` record: `[topic, bin(payload)]`.
fn record(topic: &str, payload: &[u8]) -> Vec<u8> {
    let mut r = vec![0x92];
    mp_str(&mut r, topic);
    r.push(0xc5);
    r.extend_from_slice(&(payload.len() as u16).to_be_bytes());
    r.extend_from_slice(payload);
    r
}

#[test]
fn pupil_annotations_in_events_csv_at_their_times() {
    let out = tmp("pupil");
    let rec = out.join("rec");
    std::fs::create_dir_all(&rec).unwrap();
    // 10 s of 200 Hz pupil datums of both eyes from Pupil time 5000 s.
    let mut pupil = Vec::new();
    for i in 0..2000 {
        let t = 5000.0 + f64::from(i) * 0.005;
        for eye in 0..2u8 {
            let topic = format!("pupil.{eye}.3d");
            let mut p = vec![0x88]; // a map of 8
            mp_str(&mut p, "topic");
            mp_str(&mut p, &topic);
            mp_str(&mut p, "timestamp");
            mp_f64(&mut p, t);
            mp_str(&mut p, "id");
            p.push(eye);
            mp_str(&mut p, "confidence");
            mp_f64(&mut p, 0.95);
            mp_str(&mut p, "diameter");
            mp_f64(&mut p, 40.0);
            mp_str(&mut p, "diameter_3d");
            mp_f64(&mut p, 4.0 + 0.5 * f64::from(eye));
            mp_str(&mut p, "norm_pos");
            p.push(0x92);
            mp_f64(&mut p, 0.5);
            mp_f64(&mut p, 0.5);
            mp_str(&mut p, "method");
            mp_str(&mut p, "pye3d 0.3.0 real-time");
            pupil.extend(record(&topic, &p));
        }
    }
    std::fs::write(rec.join("pupil.pldata"), pupil).unwrap();
    let notes = [
        (5001.0, "dark"),
        (5003.2525, "bright, \"on\""),
        (5007.5, "end"),
    ];
    let mut ann = Vec::new();
    for (t, label) in notes {
        let mut p = vec![0x84];
        mp_str(&mut p, "topic");
        mp_str(&mut p, "annotation");
        mp_str(&mut p, "label");
        mp_str(&mut p, label);
        mp_str(&mut p, "timestamp");
        mp_f64(&mut p, t);
        mp_str(&mut p, "duration");
        mp_f64(&mut p, 0.5);
        ann.extend(record("annotation", &p));
    }
    std::fs::write(rec.join("annotation.pldata"), ann).unwrap();

    let o = gazelight(&["inspect", rec.to_str().unwrap()]);
    let stdout = String::from_utf8_lossy(&o.stdout);
    assert!(o.status.success(), "{stdout}");
    assert!(stdout.contains("events: 3 (annotation 3)"), "{stdout}");

    let fps = 30.0;
    replay(rec.to_str().unwrap(), &out.join("replay"), "30");
    let rows = events_csv(&out.join("replay"));
    assert_eq!(rows.len(), notes.len());
    for (r, (t, label)) in rows.iter().zip(notes) {
        assert_eq!(r["text"], label);
        assert_eq!(r["source"], "annotation");
        assert_eq!(num(r, "recording_t_secs"), t);
        assert_eq!(num(r, "duration_secs"), 0.5);
        // The first frame is at the first sample, Pupil time 5000 s.
        assert!((num(r, "t_secs") - (t - 5000.0)).abs() < 1e-6);
        assert_eq!(
            num(r, "frame") as u64,
            frame_of(t - 5000.0, fps).unwrap(),
            "{label}"
        );
    }
    std::fs::remove_dir_all(&out).ok();
}

#[test]
fn the_eyelink_recordings_messages_and_trials_in_the_bids_export_validate_and_read_back() {
    let rec = shared("eye/eyelink-psa/both_eyes.asc");
    let text = std::fs::read_to_string(&rec).unwrap();
    // The truth, from the text: the MSG texts in time order, the trials'
    // TRIALID times and Trial_Index_ values.
    let mut msgs: Vec<(f64, String)> = text
        .lines()
        .filter_map(|l| l.strip_prefix("MSG"))
        .map(|rest| {
            let (t, m) = rest.trim_start().split_once(char::is_whitespace).unwrap();
            let t: f64 = t.parse().unwrap();
            let m = m.trim();
            match m.split_once(char::is_whitespace) {
                Some((o, after)) if o.parse::<i64>().is_ok() => {
                    (t - o.parse::<f64>().unwrap(), after.trim().to_owned())
                }
                _ => (t, m.to_owned()),
            }
        })
        .collect();
    msgs.sort_by(|a, b| a.0.total_cmp(&b.0));
    let first_sample_ms: f64 = text
        .lines()
        .find(|l| l.starts_with(|c: char| c.is_ascii_digit()))
        .and_then(|l| l.split_whitespace().next())
        .unwrap()
        .parse()
        .unwrap();
    let trialids: Vec<f64> = msgs
        .iter()
        .filter(|m| m.1.starts_with("TRIALID"))
        .map(|m| m.0)
        .collect();

    let out = tmp("bids");
    let ds = out.join("ds");
    let o = gazelight(&[
        "export",
        "--bids",
        ds.to_str().unwrap(),
        rec.to_str().unwrap(),
    ]);
    let stdout = String::from_utf8_lossy(&o.stdout);
    assert!(
        o.status.success(),
        "{stdout}{}",
        String::from_utf8_lossy(&o.stderr)
    );
    assert!(
        stdout.contains("308 events of the recording as messages (physioevents), 4 trials"),
        "{stdout}"
    );
    gazelight_test_support::bids::validate(&ds);
    let beh = ds.join("sub-01/beh");
    // Each eye's physioevents: its blinks and every message, in time order.
    for eye in ["eye1", "eye2", "eye3"] {
        let gz = beh.join(format!(
            "sub-01_task-replay_recording-{eye}_physioevents.tsv.gz"
        ));
        let out = Command::new("gzip").arg("-dc").arg(&gz).output().unwrap();
        assert!(out.status.success());
        let body = String::from_utf8(out.stdout).unwrap();
        let rows: Vec<Vec<&str>> = body.lines().map(|l| l.split('\t').collect()).collect();
        let onsets: Vec<f64> = rows.iter().map(|r| r[0].parse().unwrap()).collect();
        assert!(
            onsets.windows(2).all(|w| w[0] <= w[1]),
            "{eye}: not in time order"
        );
        let messages: Vec<&Vec<&str>> = rows.iter().filter(|r| r[2] == "message").collect();
        assert_eq!(messages.len(), msgs.len(), "{eye}");
        for (r, (t_ms, m)) in messages.iter().zip(&msgs) {
            assert!((r[0].parse::<f64>().unwrap() - t_ms * 1e-3).abs() < 1e-9);
            assert_eq!(r[4], m.replace('\t', " "));
        }
    }
    // The task events: one row per trial, from the first sample.
    let tsv = std::fs::read_to_string(beh.join("sub-01_task-replay_events.tsv")).unwrap();
    let mut lines = tsv.lines();
    let header: Vec<&str> = lines.next().unwrap().split('\t').collect();
    let col = |n: &str| header.iter().position(|h| *h == n).unwrap();
    let rows: Vec<Vec<&str>> = lines.map(|l| l.split('\t').collect()).collect();
    assert_eq!(rows.len(), trialids.len());
    for (k, (r, t_ms)) in rows.iter().zip(&trialids).enumerate() {
        let onset: f64 = r[col("onset")].parse().unwrap();
        assert!((onset - (t_ms - first_sample_ms) * 1e-3).abs() < 1e-6);
        assert_eq!(r[col("trial")], k.to_string());
        assert_eq!(r[col("var_Trial_Index_")], (k + 1).to_string());
    }
    // Read back: the exported recording's events are the messages at
    // their times, and the trials at their TRIALIDs.
    let eye1 = beh.join("sub-01_task-replay_recording-eye1_physio.tsv.gz");
    let o = gazelight(&["inspect", "--json", eye1.to_str().unwrap()]);
    let v: serde_json::Value = serde_json::from_slice(&o.stdout).unwrap();
    let ev = &v["events"];
    assert_eq!(ev["total"], msgs.len() + trialids.len());
    let sources: Vec<(String, u64)> = ev["sources"]
        .as_array()
        .unwrap()
        .iter()
        .map(|c| {
            (
                c["name"].as_str().unwrap().to_owned(),
                c["count"].as_u64().unwrap(),
            )
        })
        .collect();
    assert_eq!(
        sources,
        [
            ("events".to_owned(), trialids.len() as u64),
            ("physioevents".to_owned(), msgs.len() as u64)
        ]
    );
    assert_eq!(ev["first"][0]["text"], msgs[0].1);
    assert!((ev["first"][0]["t_secs"].as_f64().unwrap() - msgs[0].0 * 1e-3).abs() < 1e-9);
    std::fs::remove_dir_all(&out).ok();
}
