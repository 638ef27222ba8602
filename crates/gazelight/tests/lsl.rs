#![allow(clippy::unwrap_used, clippy::expect_used)] // test and bench code may panic on a failed setup
//! `run --lsl`, `inspect lsl://…` and `run --source lsl://…` against pylsl,
//! each test in its own network namespace (`unshare -n`, loopback up) with
//! the machine-only LSL configuration, so no discovery packet can leave.
//! Outside CI a missing `unshare`/`ip`/pylsl/pyzmq prints a SKIP line; with
//! `CI` set it fails.

mod common;

use std::io::{BufRead, BufReader, Read};
use std::path::{Path, PathBuf};
use std::process::{Child, Command, Stdio};
use std::time::Duration;

use common::{Proc, spawn_peer_any_port, tmp, wait_bounded};
use gazelight_test_support::netns;
use serde_json::Value;

/// The pyzmq peer's Pupil time minus its wall clock (its default --offset).
const PEER_OFFSET_S: f64 = 1234.5;

fn script() -> PathBuf {
    Path::new(env!("CARGO_MANIFEST_DIR")).join("tests/lsl_peer.py")
}

/// Runs test `name` again inside a fresh network namespace (loopback up);
/// true when the caller is already inside.
fn in_netns(name: &str) -> bool {
    if netns::inside() {
        return true;
    }
    if !netns::ready(&["pylsl", "zmq", "msgpack"]) {
        return false;
    }
    let dir = tmp(&format!("netns-{name}"));
    let cfg = dir.join("lsl_api.cfg");
    // The same text gazelight generates (lsl::LslConfig::generated), for pylsl.
    std::fs::write(
        &cfg,
        "[ports]\nIPv6 = disable\n\n[multicast]\nResolveScope = machine\n",
    )
    .unwrap();
    netns::rerun_test(name, &[("LSLAPICFG", cfg.as_os_str())]);
    false
}

fn reader(names: &str, extra: &[&str]) -> Proc {
    let mut c = Command::new("python3")
        .arg(script())
        .args([
            "read",
            "--names",
            names,
            "--secs",
            "25",
            "--until-quiet",
            "1.5",
        ])
        .args(extra)
        .stdout(Stdio::piped())
        .stderr(Stdio::inherit())
        .spawn()
        .unwrap();
    let _ = &mut c;
    Proc(c)
}

fn reader_result(mut p: Proc) -> Value {
    let mut s = String::new();
    p.0.stdout.take().unwrap().read_to_string(&mut s).unwrap();
    let _ = p.0.wait();
    let v: Value = serde_json::from_str(s.trim()).unwrap_or_else(|e| panic!("{e}: {s}"));
    assert!(v.get("error").is_none(), "the pylsl reader failed: {s}");
    v
}

fn f(v: &Value) -> f64 {
    v.as_f64().unwrap_or(f64::NAN)
}

fn pct(v: &mut [f64], p: f64) -> f64 {
    v.sort_by(f64::total_cmp);
    v[((v.len() - 1) as f64 * p).round() as usize]
}

fn run_secs() -> String {
    std::env::var("GAZELIGHT_LSL_RUN_SECS").unwrap_or_else(|_| "12".into())
}

#[test]
fn run_lsl_outlets_are_read_by_pylsl() {
    if !in_netns("run_lsl_outlets_are_read_by_pylsl") {
        return;
    }
    let secs = run_secs();
    let peer = spawn_peer_any_port("200", "40", &[]);
    let port = peer.remote_port.to_string();
    let r = reader(
        "gazelight-eye,gazelight-frame,gazelight-markers",
        &["--pupil-remote", &port],
    );
    let dir = tmp("run-lsl");
    let out = dir.join("out");
    let child: Child = Command::new(env!("CARGO_BIN_EXE_gazelight"))
        .args(["run", "--source", &format!("pupil://127.0.0.1:{port}")])
        .args([
            "--headless",
            "--lsl",
            "--backend",
            "cpu",
            "--size",
            "96x96",
            "--hfov-deg",
            "20",
            "--fps",
            "30",
        ])
        .args(["--secs", &secs, "--no-frames", "--out"])
        .arg(&out)
        .env("RUST_LOG", "info")
        .stdout(Stdio::piped())
        .stderr(Stdio::piped())
        .spawn()
        .unwrap();
    let o = wait_bounded(child, Duration::from_secs(40));
    let stderr = String::from_utf8_lossy(&o.stderr);
    assert!(o.status.success(), "{stderr}");
    assert!(stderr.contains("LSL outlets closed"), "{stderr}");
    let v = reader_result(r);
    let streams = &v["streams"];

    // gazelight-eye: labels, monotonic timestamps, the peer's pupils.
    let eye = &streams["gazelight-eye"];
    assert_eq!(eye["info"]["type"], "Gaze");
    let labels: Vec<&str> = eye["info"]["channels"]
        .as_array()
        .unwrap()
        .iter()
        .map(|c| c["label"].as_str().unwrap())
        .collect();
    assert_eq!(
        labels,
        [
            "gaze_x",
            "gaze_y",
            "gaze_valid",
            "pupil_right_mm",
            "confidence_right",
            "pupil_valid_right",
            "pupil_left_mm",
            "confidence_left",
            "pupil_valid_left",
            "blink"
        ]
    );
    assert_eq!(eye["info"]["channels"][3]["unit"], "mm");
    assert_eq!(eye["info"]["channels"][3]["eye"], "right");
    assert!(
        eye["info"]["source"]
            .as_str()
            .unwrap()
            .starts_with("pupil://")
    );
    let ts: Vec<f64> = eye["t"].as_array().unwrap().iter().map(f).collect();
    let vals = eye["values"].as_array().unwrap();
    let secs_f: f64 = secs.parse().unwrap();
    // One sample per tracker cycle at 200 Hz from when pylsl connected.
    // liblsl starts in 3–10 s in a fresh namespace on a loaded 2-core
    // machine, so the rate is checked over what arrived, not the count
    // over the whole run.
    assert!(ts.len() >= 200, "{} eye samples", ts.len());
    let span_secs = ts[ts.len() - 1] - ts[0];
    let rate_hz = (ts.len() - 1) as f64 / span_secs;
    assert!(
        (120.0..=260.0).contains(&rate_hz) && span_secs <= secs_f,
        "{} eye samples over {span_secs:.2} s: {rate_hz:.1} Hz",
        ts.len()
    );
    assert!(
        ts.windows(2).all(|w| w[1] > w[0]),
        "eye timestamps strictly increase"
    );
    let measured: Vec<&Value> = vals
        .iter()
        .filter(|s| f(&s[5]) == 1.0 && f(&s[8]) == 1.0)
        .collect();
    assert!(
        measured.len() * 10 > vals.len() * 8,
        "most samples measured"
    );
    for s in &measured {
        // The peer publishes diameter_3d 3.75 mm (eye 0, right) and 4.25 mm
        // (eye 1, left), constant; identity calibration.
        assert!((f(&s[3]) - 3.75).abs() < 1e-3, "{s}");
        assert!((f(&s[6]) - 4.25).abs() < 1e-3, "{s}");
    }
    // Each LSL timestamp is a tracker time: matched to the nearest peer
    // datum (Pupil time → wall → LSL clock) the offset is constant.
    let wall_minus_lsl = f(&v["wall_minus_lsl"]);
    let mut datum_lsl: Vec<f64> = v["pupil_datums"]["pupil_time"]
        .as_array()
        .unwrap()
        .iter()
        .map(|t| f(t) - PEER_OFFSET_S - wall_minus_lsl)
        .collect();
    datum_lsl.sort_by(f64::total_cmp);
    assert!(datum_lsl.len() > 100);
    let rx: Vec<f64> = eye["rx"].as_array().unwrap().iter().map(f).collect();
    let (mut offsets, mut latency) = (Vec::new(), Vec::new());
    let (first_datum, last_datum) = (datum_lsl[0], datum_lsl[datum_lsl.len() - 1]);
    for (&l, &r) in ts.iter().zip(&rx) {
        // Only while pylsl's own subscriber saw the peer's datums.
        if l < first_datum || l > last_datum {
            continue;
        }
        let i = datum_lsl.partition_point(|&d| d < l);
        let near = [i.checked_sub(1), Some(i)]
            .into_iter()
            .flatten()
            .filter_map(|j| datum_lsl.get(j))
            .min_by(|a, b| (*a - l).abs().total_cmp(&(*b - l).abs()));
        if let Some(&d) = near {
            offsets.push(l - d);
            latency.push(r - d);
        }
    }
    let median = pct(&mut offsets, 0.5);
    let mut dev: Vec<f64> = offsets.iter().map(|o| (o - median).abs()).collect();
    let dev_p99 = pct(&mut dev, 0.99);
    let lat_median = pct(&mut latency, 0.5);
    let lat_p99 = pct(&mut latency, 0.99);
    println!(
        "LSL eye: {} samples in {secs} s; LSL ts - tracker time: median {:.3} ms, |dev| p99 {:.3} ms; \
         latency tracker datum -> pylsl receipt: median {:.2} ms, p99 {:.2} ms",
        ts.len(),
        median * 1e3,
        dev_p99 * 1e3,
        lat_median * 1e3,
        lat_p99 * 1e3
    );
    assert!(
        dev_p99 < 1e-3,
        "offset not constant within 1 ms: p99 {dev_p99}"
    );
    // The service's Pupil clock estimate is good to its round trip.
    assert!(median.abs() < 5e-3, "offset median {median}");

    // gazelight-frame: every frame of timeline.csv, the same values.
    let frame = &streams["gazelight-frame"];
    let fvals = frame["values"].as_array().unwrap();
    let ft: Vec<f64> = frame["t"].as_array().unwrap().iter().map(f).collect();
    assert!(ft.windows(2).all(|w| w[1] > w[0]));
    let timeline = std::fs::read_to_string(out.join("timeline.csv")).unwrap();
    let mut lines = timeline.lines();
    let header: Vec<&str> = lines.next().unwrap().split(',').collect();
    let col = |n: &str| header.iter().position(|h| *h == n).unwrap();
    let (c_frame, c_adapt, c_psf, c_age) = (
        col("frame"),
        col("adaptation_cd_m2"),
        col("psf_pupil_mm"),
        col("eye_state_age_ms"),
    );
    let (c_light, c_residual) = (col("pupil_light_mm"), col("pupil_residual_mm"));
    // The frame stream's channels name the pupil light response.
    let flabels: Vec<&str> = frame["info"]["channels"]
        .as_array()
        .unwrap()
        .iter()
        .map(|c| c["label"].as_str().unwrap())
        .collect();
    assert_eq!(
        &flabels[10..],
        [
            "pupil_light_right_mm",
            "pupil_light_left_mm",
            "pupil_residual_right_mm",
            "pupil_residual_left_mm"
        ]
    );
    let rows: Vec<Vec<f64>> = lines
        .map(|l| {
            l.split(',')
                .map(|x| x.parse().unwrap_or(f64::NAN))
                .collect()
        })
        .collect();
    assert!(!rows.is_empty());
    let mut matched = 0;
    for row in &rows {
        let Some(s) = fvals.iter().find(|s| f(&s[0]) == row[c_frame]) else {
            continue;
        };
        matched += 1;
        let close = |a: f64, b: f64| (a - b).abs() <= 1e-3 * b.abs().max(1e-3);
        assert!(close(f(&s[2]), row[c_adapt]), "adaptation {s} vs {row:?}");
        assert!(close(f(&s[4]), row[c_psf]), "psf pupil {s} vs {row:?}");
        // One view stands for both eyes: both channels are the timeline's.
        assert!(
            (f(&s[10]) - row[c_light]).abs() <= 1e-4 && (f(&s[11]) - row[c_light]).abs() <= 1e-4,
            "pupil light {s} vs {row:?}"
        );
        assert!((1.5..=9.0).contains(&row[c_light]), "pupil light {row:?}");
        // Each eye's residual: its own pupil minus the prediction, where
        // the view's pupil is measured.
        if row[c_residual].is_finite() {
            let right = row[col("pupil_right_mm")] - row[c_light];
            assert!((f(&s[12]) - right).abs() <= 2e-4, "residual {s} vs {row:?}");
        }
        // timeline.csv writes the age with 3 decimals (ms): half a unit of that.
        assert!(
            (f(&s[7]) - row[c_age]).abs() <= 5e-4 + 1e-6,
            "age {s} vs {row:?}"
        );
    }
    // Every frame pylsl got is a timeline row with the same values; it
    // gets every frame from when it connected (consecutive indices, none
    // dropped), up to the end of the session. When it connected depends on
    // how fast liblsl starts in the namespace, so the count is bounded
    // below by one second of frames, not by a share of the run.
    assert_eq!(matched, fvals.len());
    let idx: Vec<f64> = fvals.iter().map(|s| f(&s[0])).collect();
    assert!(
        idx.windows(2).all(|w| w[1] == w[0] + 1.0),
        "frames pylsl got are not consecutive: {idx:?}"
    );
    assert!(
        matched >= 30,
        "{matched} of {} frames reached pylsl",
        rows.len()
    );
    let last_row = rows.iter().map(|r| r[c_frame]).fold(f64::NAN, f64::max);
    assert!(
        idx.last().is_some_and(|&l| l + 30.0 >= last_row),
        "pylsl's last frame {:?}, the session's {last_row}",
        idx.last()
    );

    // gazelight-markers.
    let m: Vec<String> = streams["gazelight-markers"]["values"]
        .as_array()
        .unwrap()
        .iter()
        .map(|x| x[0].as_str().unwrap().to_owned())
        .collect();
    assert_eq!(m.last().map(String::as_str), Some("session_stop"), "{m:?}");
    // Rebuilds seen while pylsl was connected each have their marker.
    let first = fvals.first().map(|s| f(&s[9])).unwrap_or(0.0) as usize;
    let rebuilds = fvals.last().map(|s| f(&s[9])).unwrap_or(0.0) as usize;
    let marked = m.iter().filter(|x| x.starts_with("psf_rebuild")).count();
    assert!(marked >= rebuilds - first && marked <= rebuilds, "{m:?}");
    drop(peer);
}

fn relay(name: &str, layout: &str, secs: &str) -> Proc {
    let mut c = Command::new("python3")
        .arg(script())
        .args([
            "relay", "--name", name, "--layout", layout, "--rate", "100", "--secs", secs,
        ])
        .stdout(Stdio::piped())
        .stderr(Stdio::inherit())
        .spawn()
        .unwrap();
    let mut line = String::new();
    BufReader::new(c.stdout.as_mut().unwrap())
        .read_line(&mut line)
        .unwrap();
    assert!(line.starts_with("READY"), "{line}");
    Proc(c)
}

#[test]
fn inspect_reads_a_pupil_capture_relay_stream() {
    if !in_netns("inspect_reads_a_pupil_capture_relay_stream") {
        return;
    }
    let _relay = relay("pupil_capture", "relay", "12");
    let o = common::gazelight(&[
        "inspect",
        "lsl://?name=pupil_capture",
        "--secs",
        "3",
        "--json",
    ]);
    assert!(o.status.success(), "{}", String::from_utf8_lossy(&o.stderr));
    let v: Value = serde_json::from_slice(&o.stdout).unwrap();
    assert_eq!(v["format"], "lsl");
    assert_eq!(v["lsl_stream"]["layout"], "pupil-capture-relay");
    assert_eq!(v["lsl_stream"]["channels"], 22);
    for (e, mm) in [(0, 3.75), (1, 4.25)] {
        let n = v["samples"]["pupil"][e].as_u64().unwrap();
        // 100 Hz for 3 s.
        // 100 Hz for 3 s from the first sample, plus what liblsl queued
        // while the inlet was set up (time correction).
        assert!((270..=450).contains(&n), "eye {e}: {n} samples");
        assert!((f(&v["rate_hz"]["pupil"][e]) - 100.0).abs() < 5.0, "{v}");
        assert_eq!(v["pupil"][e]["unit"], "mm");
        assert!(
            (f(&v["pupil"][e]["raw"]["median"]) - mm).abs() < 1e-6,
            "{v}"
        );
        assert!(
            (f(&v["pupil"][e]["filtered_mm"]["median"]) - mm).abs() < 1e-3,
            "{v}"
        );
    }
    assert!((270..=450).contains(&v["samples"]["gaze"].as_u64().unwrap()));
    // A stream that does not exist is an error after the wait, not a hang.
    let o = common::gazelight(&["inspect", "lsl://?name=nobody", "--secs", "1"]);
    assert!(!o.status.success());
    assert!(String::from_utf8_lossy(&o.stderr).contains("no LSL stream"));
}

#[test]
fn run_reads_neon_layout_stream_through_the_chain() {
    if !in_netns("run_reads_neon_layout_stream_through_the_chain") {
        return;
    }
    let _relay = relay("neon-gaze", "neon", "12");
    let out = tmp("run-neon").join("out");
    let child = Command::new(env!("CARGO_BIN_EXE_gazelight"))
        .args([
            "run",
            "--source",
            "lsl://?name=neon-gaze",
            "--headless",
            "--backend",
            "cpu",
        ])
        .args([
            "--size",
            "96x96",
            "--hfov-deg",
            "20",
            "--fps",
            "30",
            "--secs",
            "3",
            "--no-frames",
            "--out",
        ])
        .arg(&out)
        .env("RUST_LOG", "warn")
        .stdout(Stdio::piped())
        .stderr(Stdio::piped())
        .spawn()
        .unwrap();
    let o = wait_bounded(child, Duration::from_secs(30));
    let stdout = String::from_utf8_lossy(&o.stdout);
    assert!(o.status.success(), "{}", String::from_utf8_lossy(&o.stderr));
    assert!(stdout.contains("lsl://?name=neon-gaze (Live"), "{stdout}");
    let timeline = std::fs::read_to_string(out.join("timeline.csv")).unwrap();
    let mut lines = timeline.lines();
    let header: Vec<&str> = lines.next().unwrap().split(',').collect();
    let col = |n: &str| header.iter().position(|h| *h == n).unwrap();
    let last: Vec<&str> = timeline.lines().last().unwrap().split(',').collect();
    let num = |c: usize| last[c].parse::<f64>().unwrap();
    // Published: pupil_diameter_right 3.5 mm, left 4.5 mm; gaze (800, 300)
    // px on Neon's 1600 × 1200 scene camera → (0.5, 0.25).
    assert!((num(col("pupil_right_mm")) - 3.5).abs() < 1e-3, "{last:?}");
    assert!((num(col("pupil_left_mm")) - 4.5).abs() < 1e-3, "{last:?}");
    assert!((num(col("gaze_u")) - 0.5).abs() < 1e-3, "{last:?}");
    assert!((num(col("gaze_v")) - 0.25).abs() < 1e-3, "{last:?}");
    // The age is measured from the stream's own (corrected) timestamps.
    assert!(num(col("eye_state_age_ms")) < 100.0, "{last:?}");
}

#[test]
fn run_writes_an_lsl_marker_stream_to_events_csv_at_its_stamps() {
    use std::io::Write;
    if !in_netns("run_writes_an_lsl_marker_stream_to_events_csv_at_its_stamps") {
        return;
    }
    let labels = ["onset 1", "onset 2", "say \"hi\"", "past", "onset 4"];
    // "past" is stamped 0.5 s before its push (a sender that stamps the
    // stimulus's moment): the event is at the stamp, not the arrival.
    let back = [0.0, 0.0, 0.0, 0.5, 0.0];
    let back_arg: Vec<String> = back.iter().map(f64::to_string).collect();
    let mut pusher = Proc(
        Command::new("python3")
            .arg(script())
            .args(["markers", "--name", "stim-markers", "--labels"])
            .arg(labels.join(","))
            .arg("--back")
            .arg(back_arg.join(","))
            .stdin(Stdio::piped())
            .stdout(Stdio::piped())
            .stderr(Stdio::inherit())
            .spawn()
            .unwrap(),
    );
    let mut pusher_out = BufReader::new(pusher.0.stdout.take().unwrap());
    let mut line = String::new();
    pusher_out.read_line(&mut line).unwrap();
    assert_eq!(line.trim(), "READY", "{line}");
    let out = tmp("run-markers").join("out");
    let child = Command::new(env!("CARGO_BIN_EXE_gazelight"))
        .args([
            "run",
            "--source",
            "synthetic://demo",
            "--events",
            "lsl://?name=stim-markers",
            "--headless",
            "--backend",
            "cpu",
            "--size",
            "64x48",
            "--fps",
            "60",
            "--secs",
            "60",
            "--no-frames",
            "--out",
        ])
        .arg(&out)
        .env("RUST_LOG", "warn")
        .stdout(Stdio::piped())
        .stderr(Stdio::piped())
        .spawn()
        .unwrap();
    let run = child;
    // Pushed once the run has written frames: the newest run time then.
    let timeline_path = out.join("timeline.csv");
    let t_seen = {
        let start = std::time::Instant::now();
        loop {
            let rows = std::fs::read_to_string(&timeline_path).unwrap_or_default();
            let whole = rows.rfind('\n').map_or("", |i| &rows[..i]);
            if let Some(last) = whole.lines().skip(1).last() {
                break last.split(',').nth(1).unwrap().parse::<f64>().unwrap();
            }
            assert!(start.elapsed() < Duration::from_secs(60), "no frames");
            std::thread::sleep(Duration::from_millis(20));
        }
    };
    pusher.0.stdin.take().unwrap().write_all(b"go\n").unwrap();
    line.clear();
    pusher_out.read_line(&mut line).unwrap();
    let pushed: Vec<(String, f64, f64)> =
        serde_json::from_str(line.trim()).unwrap_or_else(|e| panic!("{e}: {line}"));
    assert_eq!(pushed.len(), labels.len());
    let events_path = out.join("events.csv");
    let start = std::time::Instant::now();
    while std::fs::read_to_string(&events_path)
        .unwrap_or_default()
        .lines()
        .count()
        <= labels.len()
    {
        assert!(
            start.elapsed() < Duration::from_secs(60),
            "no events.csv rows"
        );
        std::thread::sleep(Duration::from_millis(20));
    }
    let _ = Command::new("kill")
        .args(["-INT", &run.id().to_string()])
        .status();
    let o = wait_bounded(run, Duration::from_secs(30));
    let stdout = String::from_utf8_lossy(&o.stdout);
    assert!(o.status.success(), "{}", String::from_utf8_lossy(&o.stderr));
    assert!(
        stdout.contains("events.csv (5 events, 0 dropped"),
        "{stdout}"
    );

    let text = std::fs::read_to_string(&events_path).unwrap();
    let mut lines = text.lines();
    assert_eq!(
        lines.next(),
        Some("t_secs,recording_t_secs,t_clock,duration_secs,source,text,trial,frame")
    );
    let rows: Vec<Vec<String>> = lines
        .map(|l| gazelight_input::split_csv_line(l, ','))
        .collect();
    assert_eq!(rows.len(), labels.len(), "{text}");
    let num = |s: &str| s.parse::<f64>().unwrap_or(f64::NAN);
    for (r, (label, _, stamp)) in rows.iter().zip(&pushed) {
        assert_eq!(&r[4], "stim-markers");
        assert_eq!(&r[5], label);
        // The sender's own stamp, as pushed.
        assert!((num(&r[2]) - stamp).abs() < 1e-5, "{r:?} vs {stamp}");
    }
    // On the run's clock, each marker lies where the sender's clock put
    // its stamp relative to the first (the pushes the pusher timed, less
    // the back-dating): within a millisecond (the LSL clock and the run's
    // are both the machine's monotonic clock).
    let t: Vec<f64> = rows.iter().map(|r| num(&r[0])).collect();
    for i in 1..t.len() {
        let sender_dt = (pushed[i].1 - back[i]) - pushed[0].1;
        assert!(
            ((t[i] - t[0]) - sender_dt).abs() < 1e-3,
            "marker {i}: {} s after the first on the run's clock, {sender_dt} s on the sender's",
            t[i] - t[0]
        );
    }
    assert!(t[0] > t_seen - 1e-3, "{} vs {t_seen}", t[0]);
    // Each marker on the newest frame at or before it: (frame, t_secs).
    let timeline = std::fs::read_to_string(&timeline_path).unwrap();
    let frames: Vec<(u64, f64)> = timeline
        .lines()
        .skip(1)
        .map(|l| {
            let mut c = l.split(',');
            let f = c.next().unwrap().parse().unwrap();
            (f, num(c.next().unwrap()))
        })
        .collect();
    for (r, &te) in rows.iter().zip(&t) {
        let f: u64 = r[7].parse().unwrap_or_else(|e| panic!("{e}: {r:?}"));
        let k = frames.iter().position(|&(x, _)| x == f).unwrap();
        assert!(
            frames[k].1 <= te + 1e-3,
            "marker at {te} on {:?}",
            frames[k]
        );
        assert!(
            k + 1 == frames.len() || frames[k + 1].1 > te - 1e-3,
            "marker at {te}: the next frame {:?}",
            frames[k + 1]
        );
    }
    let _ = pusher.0.wait();
}
