#![allow(clippy::unwrap_used, clippy::expect_used)] // test and bench code may panic on a failed setup
//! `gazelight record` against the pyzmq Pupil peer: Ctrl-C and a lost
//! tracker lose no received datum, and the result is a recording in Pupil's
//! layout that the reader, the importer and `replay` accept.

mod common;

use std::path::Path;
use std::process::{Command, Stdio};
use std::time::Duration;

use common::{
    datums_on_disk, python_ready, spawn_peer_any_port, tmp_path, wait_bounded, wait_exit, wait_for,
};

use gazelight_tracker::PldataReader;
use gazelight_tracker::recording::{read_npy_f64, stream_paths};

/// Reads one stream back: (records in the .pldata, timestamps in the .npy,
/// the datum count `record` reported for it).
fn check_stream(dir: &Path, stream: &str) -> usize {
    let (pldata, npy) = stream_paths(dir, stream);
    let reader = PldataReader::open(&pldata).expect("open pldata");
    let mut n = 0usize;
    for r in reader {
        let r = r.expect("record");
        assert!(r.topic.starts_with(stream), "{} in {stream}", r.topic);
        n += 1;
    }
    let ts = read_npy_f64(&npy).expect("npy");
    assert_eq!(ts.len(), n, "{stream}: .npy and .pldata disagree");
    assert!(
        ts.windows(2).all(|w| w[1] >= w[0] - 1e-3),
        "{stream}: time goes back"
    );
    n
}

fn reported(stdout: &str, stream: &str) -> usize {
    let key = format!("{stream}: ");
    let i = stdout
        .find(&key)
        .unwrap_or_else(|| panic!("no `{key}` in {stdout}"));
    stdout[i + key.len()..]
        .split(|c: char| !c.is_ascii_digit())
        .next()
        .and_then(|d| d.parse().ok())
        .expect("count")
}

#[test]
fn ctrl_c_keeps_every_received_datum() {
    if !python_ready() {
        return;
    }
    let peer = spawn_peer_any_port("200", "20", &[]);
    let dir = tmp_path("ctrlc");
    let mut child = Command::new(env!("CARGO_BIN_EXE_gazelight"))
        .args([
            "record",
            "--source",
            &format!("pupil://127.0.0.1:{}", peer.remote_port),
            "--out",
            dir.to_str().expect("utf-8"),
        ])
        .env("RUST_LOG", "warn")
        .stdout(Stdio::piped())
        .stderr(Stdio::piped())
        .spawn()
        .expect("spawn record");
    // Recorded until the counts asserted below are on disk (flushed every
    // second), however long the connection took; not a fixed 2.5 s.
    wait_for(
        Duration::from_secs(60),
        "801 pupil and 101 gaze datums on disk",
        || {
            (datums_on_disk(&dir, "pupil") > 800 && datums_on_disk(&dir, "gaze") > 100)
                .then_some(())
        },
    );
    let sent = Command::new("kill")
        .args(["-INT", &child.id().to_string()])
        .status()
        .expect("kill -INT");
    assert!(sent.success());
    let status = wait_exit(&mut child, Duration::from_secs(10));
    let mut stdout = String::new();
    let mut stderr = String::new();
    use std::io::Read;
    child
        .stdout
        .take()
        .expect("stdout")
        .read_to_string(&mut stdout)
        .expect("read");
    child
        .stderr
        .take()
        .expect("stderr")
        .read_to_string(&mut stderr)
        .expect("read");
    drop(peer);
    assert!(status.success(), "record failed: {stdout}\n{stderr}");
    assert!(stdout.contains("stopped (Ctrl-C)"), "{stdout}");
    assert!(stdout.contains("0 dropped by the queue"), "{stdout}");
    // Every datum it reports is on disk, in both files of its stream.
    let pupil = check_stream(&dir, "pupil");
    let gaze = check_stream(&dir, "gaze");
    assert_eq!(pupil, reported(&stdout, "pupil"));
    assert_eq!(gaze, reported(&stdout, "gaze"));
    // 200 Hz × (2D + 3D) × 2 eyes for well over a second.
    assert!(pupil > 800, "only {pupil} pupil datums");
    assert!(gaze > 100, "only {gaze} gaze datums");
    // Pupil Player's metadata.
    let info: serde_json::Value =
        serde_json::from_str(&std::fs::read_to_string(dir.join("info.player.json")).expect("info"))
            .expect("json");
    assert_eq!(info["recording_software_name"], "gazelight");
    assert!(
        info["duration_s"].as_f64().expect("duration") > 1.0,
        "{info}"
    );
    assert_eq!(info["recording_uuid"].as_str().map(str::len), Some(36));

    // And the recording replays through the whole stack.
    let out = Command::new(env!("CARGO_BIN_EXE_gazelight"))
        .args([
            "replay",
            dir.to_str().expect("utf-8"),
            "--size",
            "48x40",
            "--no-frames",
            "--out",
            dir.join("replayed").to_str().expect("utf-8"),
        ])
        .env("RUST_LOG", "warn")
        .output()
        .expect("replay");
    assert!(
        out.status.success(),
        "replay of the recording failed: {}",
        String::from_utf8_lossy(&out.stderr)
    );
    assert!(dir.join("replayed/timeline.csv").is_file());
}

#[test]
fn lost_tracker_keeps_what_was_received() {
    if !python_ready() {
        return;
    }
    let peer = spawn_peer_any_port("200", "20", &[]);
    let dir = tmp_path("lost");
    let child = Command::new(env!("CARGO_BIN_EXE_gazelight"))
        .args([
            "record",
            "--source",
            &format!("pupil://127.0.0.1:{}", peer.remote_port),
            "--out",
            dir.to_str().expect("utf-8"),
            "--secs",
            "15",
        ])
        .env("RUST_LOG", "warn")
        .stdout(Stdio::piped())
        .stderr(Stdio::piped())
        .spawn()
        .expect("spawn record");
    // The peer killed once 101 pupil datums are on disk (flushed every
    // second), not after a fixed 1.5 s; the recording then ends on its
    // --secs (15 s: room for the wait and the loss's report on a loaded
    // machine; were it too short, "tracker lost" would be missing below).
    wait_for(Duration::from_secs(14), "101 pupil datums on disk", || {
        (datums_on_disk(&dir, "pupil") > 100).then_some(())
    });
    drop(peer);
    let out = wait_bounded(child, Duration::from_secs(60));
    let stdout = String::from_utf8_lossy(&out.stdout);
    let stderr = String::from_utf8_lossy(&out.stderr);
    assert!(out.status.success(), "record failed: {stdout}\n{stderr}");
    assert!(stdout.contains("duration reached"), "{stdout}");
    assert!(
        stderr.contains("tracker lost"),
        "the loss is reported: {stderr}"
    );
    let pupil = check_stream(&dir, "pupil");
    assert_eq!(pupil, reported(&stdout, "pupil"));
    assert!(pupil > 100, "only {pupil} pupil datums before the loss");
}

#[test]
fn bad_arguments_are_refused() {
    let dir = tmp_path("bad");
    let out = Command::new(env!("CARGO_BIN_EXE_gazelight"))
        .args([
            "record",
            "--source",
            "pupil://127.0.0.1:9",
            "--connect-secs",
            "0.5",
            "--out",
            dir.to_str().expect("utf-8"),
        ])
        .output()
        .expect("run");
    let stderr = String::from_utf8_lossy(&out.stderr);
    assert!(!out.status.success());
    assert!(
        stderr.contains("no tracker at pupil://127.0.0.1:9"),
        "{stderr}"
    );
    let out = Command::new(env!("CARGO_BIN_EXE_gazelight"))
        .args([
            "record",
            "--source",
            "http://x",
            "--out",
            dir.to_str().expect("utf-8"),
        ])
        .output()
        .expect("run");
    let stderr = String::from_utf8_lossy(&out.stderr);
    assert!(!out.status.success());
    assert!(stderr.contains("--source http://x"), "{stderr}");
    assert!(!stderr.contains("panicked"), "{stderr}");
}
