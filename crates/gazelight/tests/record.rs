//! `gazelight record` against the pyzmq Pupil peer: Ctrl-C and a lost
//! tracker lose no received datum, and the result is a recording in Pupil's
//! layout that the reader, the importer and `replay` accept.

use std::io::{BufRead, BufReader};
use std::path::{Path, PathBuf};
use std::process::{Child, Command, Stdio};
use std::time::{Duration, Instant};

use gazelight_tracker::PldataReader;
use gazelight_tracker::recording::{read_npy_f64, stream_paths};

fn tmp(name: &str) -> PathBuf {
    let dir = std::env::temp_dir().join(format!("gazelight-record-{}-{name}", std::process::id()));
    let _ = std::fs::remove_dir_all(&dir);
    dir
}

fn python_ready() -> bool {
    let ok = Command::new("python3")
        .args(["-c", "import zmq, msgpack"])
        .output()
        .map(|o| o.status.success())
        .unwrap_or(false);
    if !ok {
        assert!(
            std::env::var_os("CI").is_none(),
            "CI must have python3 + pyzmq + msgpack"
        );
        eprintln!("SKIP: python3 with pyzmq + msgpack not available");
    }
    ok
}

fn peer(timeout_secs: &str) -> (Child, String) {
    let script =
        Path::new(env!("CARGO_MANIFEST_DIR")).join("../gazelight-tracker/tests/pupil_peer.py");
    let mut child = Command::new("python3")
        .arg(script)
        .args([
            "--remote-port",
            "0",
            "--sub-port",
            "0",
            "--pub-port",
            "0",
            "--rate",
            "200",
            "--timeout",
            timeout_secs,
        ])
        .stdout(Stdio::piped())
        .spawn()
        .expect("spawn peer");
    let mut line = String::new();
    BufReader::new(child.stdout.take().expect("stdout"))
        .read_line(&mut line)
        .expect("READY line");
    let port = line
        .split_whitespace()
        .find_map(|w| w.strip_prefix("remote="))
        .expect("remote port")
        .to_owned();
    (child, port)
}

fn wait_with_deadline(child: &mut Child, limit: Duration) -> std::process::ExitStatus {
    let start = Instant::now();
    loop {
        if let Some(status) = child.try_wait().expect("wait") {
            return status;
        }
        if start.elapsed() > limit {
            let _ = child.kill();
            panic!("gazelight record did not stop within {limit:?}");
        }
        std::thread::sleep(Duration::from_millis(50));
    }
}

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
    let (mut peer, port) = peer("20");
    let dir = tmp("ctrlc");
    let mut child = Command::new(env!("CARGO_BIN_EXE_gazelight"))
        .args([
            "record",
            "--source",
            &format!("pupil://127.0.0.1:{port}"),
            "--out",
            dir.to_str().expect("utf-8"),
        ])
        .env("RUST_LOG", "warn")
        .stdout(Stdio::piped())
        .stderr(Stdio::piped())
        .spawn()
        .expect("spawn record");
    // Let it record for a while (the connection takes a moment).
    std::thread::sleep(Duration::from_millis(2500));
    let sent = Command::new("kill")
        .args(["-INT", &child.id().to_string()])
        .status()
        .expect("kill -INT");
    assert!(sent.success());
    let status = wait_with_deadline(&mut child, Duration::from_secs(10));
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
    let _ = peer.kill();
    let _ = peer.wait();
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
    let (mut peer, port) = peer("20");
    let dir = tmp("lost");
    let child = Command::new(env!("CARGO_BIN_EXE_gazelight"))
        .args([
            "record",
            "--source",
            &format!("pupil://127.0.0.1:{port}"),
            "--out",
            dir.to_str().expect("utf-8"),
            "--secs",
            "3.5",
        ])
        .env("RUST_LOG", "warn")
        .stdout(Stdio::piped())
        .stderr(Stdio::piped())
        .spawn()
        .expect("spawn record");
    std::thread::sleep(Duration::from_millis(1500));
    let _ = peer.kill();
    let _ = peer.wait();
    let out = child.wait_with_output().expect("record output");
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
    let dir = tmp("bad");
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
