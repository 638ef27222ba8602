#![allow(clippy::unwrap_used, clippy::expect_used)] // test and bench code may panic on a failed setup
//! `gazelight calibrate --stimulus remote` against the pyzmq Pupil peer
//! (crates/gazelight-tracker/tests/pupil_peer.py), whose simulated pupil
//! follows the `gazelight.stimulus` notifications: a real black/white
//! session over the network, then a refused one (no light response).

mod common;

use std::process::Command;

use common::{gazelight, python_ready, spawn_peer_any_port, tmp};

/// Asks the peer for the stimuli it received (its `peer.stimulus` command),
/// through a tiny pyzmq REQ client.
fn peer_stimuli(port: u16) -> serde_json::Value {
    let code = format!(
        "import zmq,sys\nc=zmq.Context()\ns=c.socket(zmq.REQ)\ns.setsockopt(zmq.RCVTIMEO,3000)\n\
         s.connect('tcp://127.0.0.1:{port}')\ns.send_string('peer.stimulus')\nprint(s.recv_string())\n"
    );
    let out = Command::new("python3")
        .args(["-c", &code])
        .output()
        .expect("python");
    assert!(
        out.status.success(),
        "{}",
        String::from_utf8_lossy(&out.stderr)
    );
    serde_json::from_slice(&out.stdout).expect("json")
}

#[test]
fn remote_stimulus_calibration_against_the_peer() {
    if !python_ready() {
        return;
    }
    let peer = spawn_peer_any_port("200", "30", &["--black-gain", "1.5", "--white-gain", "0.6"]);
    let dir = tmp("ok");
    let profile = dir.join("profile.json");
    let out = gazelight(&[
        "calibrate",
        "--source",
        &format!("pupil://127.0.0.1:{}", peer.remote_port),
        "--stimulus",
        "remote",
        "--phase-secs",
        "1.5",
        "--settle-secs",
        "0.7",
        "--out",
        profile.to_str().expect("utf-8"),
    ]);
    let stimuli = peer_stimuli(peer.remote_port);
    drop(peer);
    let stdout = String::from_utf8_lossy(&out.stdout);
    let stderr = String::from_utf8_lossy(&out.stderr);
    assert!(out.status.success(), "calibrate failed: {stdout}\n{stderr}");
    // The host application (the peer) received black, white, none in order.
    let log: Vec<String> = stimuli["log"]
        .as_array()
        .expect("log")
        .iter()
        .map(|v| v.as_str().unwrap_or_default().to_owned())
        .collect();
    assert_eq!(log, ["black", "white", "none"], "{stimuli}");
    // The per-eye summary was printed for both phases of both eyes.
    for needle in [
        "right  black",
        "right  white",
        "left   black",
        "left   white",
    ] {
        assert!(
            stdout.contains(needle),
            "summary lacks `{needle}`: {stdout}"
        );
    }
    // The profile maps each eye's black pupil above its white one, and the
    // ratio matches the peer's light response (black 1.5×, white 0.6× the
    // resting pupil → 2.5×) up to the first-order settling in 0.8 s.
    let json: serde_json::Value =
        serde_json::from_str(&std::fs::read_to_string(&profile).expect("profile")).expect("json");
    assert_eq!(json["schema"], "gazelight.pupil-calibration/2");
    for eye in ["right", "left"] {
        let e = &json["eyes"][eye];
        let black = e["raw_black"].as_f64().expect("raw_black");
        let white = e["raw_white"].as_f64().expect("raw_white");
        let ratio = black / white;
        assert!(
            (2.2..=2.6).contains(&ratio),
            "{eye}: black/white = {ratio:.3} ({json})"
        );
        assert_eq!(e["mm_min"], 2.0);
        assert_eq!(e["mm_max"], 8.0);
    }
}

#[test]
fn no_light_response_is_refused_and_writes_nothing() {
    if !python_ready() {
        return;
    }
    let peer = spawn_peer_any_port("200", "30", &["--black-gain", "1.0", "--white-gain", "1.0"]);
    let dir = tmp("refused");
    let profile = dir.join("profile.json");
    let out = gazelight(&[
        "calibrate",
        "--source",
        &format!("pupil://127.0.0.1:{}", peer.remote_port),
        "--stimulus",
        "remote",
        "--phase-secs",
        "1.0",
        "--settle-secs",
        "0.3",
        "--out",
        profile.to_str().expect("utf-8"),
    ]);
    let stimuli = peer_stimuli(peer.remote_port);
    drop(peer);
    let stderr = String::from_utf8_lossy(&out.stderr);
    assert!(!out.status.success(), "a flat response must be refused");
    assert!(stderr.contains("no profile written"), "{stderr}");
    assert!(
        stderr.contains("white"),
        "the reason names the white phase: {stderr}"
    );
    assert!(!stderr.contains("panicked"), "{stderr}");
    assert!(!profile.exists(), "nothing may be written on refusal");
    // The stimulus was still turned off at the end.
    let log = stimuli["log"].as_array().expect("log");
    assert_eq!(
        log.last().and_then(|v| v.as_str()),
        Some("none"),
        "{stimuli}"
    );
}

#[test]
fn no_tracker_is_a_clear_error() {
    let dir = tmp("none");
    let profile = dir.join("profile.json");
    let out = gazelight(&[
        "calibrate",
        "--source",
        "pupil://127.0.0.1:9",
        "--silence-secs",
        "1",
        "--out",
        profile.to_str().expect("utf-8"),
    ]);
    let stderr = String::from_utf8_lossy(&out.stderr);
    assert!(!out.status.success());
    assert!(
        stderr.contains("no tracker at pupil://127.0.0.1:9"),
        "{stderr}"
    );
    assert!(!profile.exists());
}
