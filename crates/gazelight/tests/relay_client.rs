#![allow(clippy::unwrap_used, clippy::expect_used)] // test and bench code may panic on a failed setup
//! `gazelight run --relay` end to end: a live session against the pyzmq
//! Pupil peer (crates/gazelight-tracker/tests/pupil_peer.py) re-published
//! as a Pupil Network API, read by
//! - Pupil Labs' official Python client `pupil-core-network-client`
//!   (crates/gazelight-pupil/tests/relay_client.py), and
//! - gazelight's own `PupilClient`, which must decode the relay's stream
//!   as if it were Pupil Capture.
//!
//! The peer publishes fixed pupils (3D: 3.75 mm right, 4.25 mm left; 2D:
//! 31.5 px, 36.25 px; eye-0 `norm_pos` [0.41, 0.52]); with the identity
//! calibration the filtered, calibrated pupil the relay publishes converges
//! to the 3D values.

mod common;

use std::path::Path;
use std::process::{Command, Stdio};
use std::time::Duration;

use common::{Proc, free_port, spawn_peer, wait_listening};

use gazelight_tracker::pupil::PupilClient;
use gazelight_tracker::{PupilUnit, Sample};

/// The peer's published values (pupil_peer.py PUPIL_2D / PUPIL_3D).
const PEER_MM: [f64; 2] = [3.75, 4.25];
const PEER_PX: [f64; 2] = [31.5, 36.25];

#[test]
fn pupil_clients_read_the_relay_of_a_live_session() {
    let peer = spawn_peer(&["--rate", "200", "--timeout", "60"]);
    let peer_port = peer.remote_port;
    let relay_port = free_port();
    let run = Proc(
        Command::new(env!("CARGO_BIN_EXE_gazelight"))
            // --secs 120: a backstop; the run is killed when `run` drops.
            .args(["run", "--headless", "--size", "256x144", "--secs", "120"])
            .args(["--source", &format!("pupil://127.0.0.1:{peer_port}")])
            .args(["--relay", &format!("127.0.0.1:{relay_port}")])
            .env("RUST_LOG", "warn")
            .stdout(Stdio::null())
            .stderr(Stdio::inherit())
            .spawn()
            .expect("gazelight run"),
    );
    wait_listening(relay_port, Duration::from_secs(60));
    let rt = tokio::runtime::Builder::new_multi_thread()
        .worker_threads(2)
        .enable_all()
        .build()
        .unwrap();
    // The filtered pupil settles on the peer's values (slew-limited from
    // the model pupil): wait until the relay publishes both eyes within
    // the 0.02 mm asserted below, instead of sleeping 3 s.
    rt.block_on(async {
        let config =
            gazelight_tracker::uri::pupil_config(&format!("pupil://127.0.0.1:{relay_port}"))
                .unwrap();
        let (client, mut streams) = PupilClient::spawn(config);
        client
            .wait_connected(Duration::from_secs(60))
            .await
            .unwrap();
        let deadline = tokio::time::Instant::now() + Duration::from_secs(60);
        let mut settled = [false; 2];
        while !(settled[0] && settled[1]) {
            assert!(
                tokio::time::Instant::now() < deadline,
                "the relay's pupil did not settle on {PEER_MM:?}"
            );
            if let Ok(Some(Sample::Pupil(p))) =
                tokio::time::timeout(Duration::from_secs(1), streams.samples.recv()).await
                && let Some(mm) = p.diameter_mm
            {
                settled[p.eye as usize] = (f64::from(mm) - PEER_MM[p.eye as usize]).abs() < 0.02;
            }
        }
        client.shutdown().await;
    });

    // 1. The official Python client.
    let out = Command::new("python3")
        .arg(Path::new(env!("CARGO_MANIFEST_DIR")).join("../gazelight-pupil/tests/relay_client.py"))
        .args(["--port", &relay_port.to_string()])
        .args(["--pupil", "400", "--gaze", "100", "--timeout", "20"])
        .output()
        .expect("python3");
    let stdout = String::from_utf8_lossy(&out.stdout);
    let lines: Vec<serde_json::Value> = stdout
        .lines()
        .map(|l| serde_json::from_str(l).unwrap_or_else(|e| panic!("{e}: {l}")))
        .collect();
    if let Some(e) = lines.iter().find(|v| v["kind"] == "error") {
        panic!("relay_client.py: {}", e["error"]);
    }
    assert!(
        out.status.success(),
        "relay_client.py: {}; {}",
        out.status,
        String::from_utf8_lossy(&out.stderr)
    );
    let hello = &lines[0];
    assert_eq!(hello["kind"], "hello");
    assert!(hello["version"].as_str().unwrap().contains("gazelight"));
    let datums: Vec<&serde_json::Value> = lines.iter().filter(|v| v["kind"] == "datum").collect();
    let mut last_ts = [f64::MIN; 3];
    let mut per_eye: [Vec<&serde_json::Value>; 2] = [Vec::new(), Vec::new()];
    let mut gaze = Vec::new();
    for v in &datums {
        let topic = v["topic"].as_str().unwrap();
        let p = &v["payload"];
        let ts = p["timestamp"].as_f64().unwrap();
        let slot = match topic {
            "pupil.0.3d" => 0,
            "pupil.1.3d" => 1,
            "gaze.3d.01." => 2,
            other => panic!("unexpected topic {other}"),
        };
        assert!(
            ts >= last_ts[slot],
            "{topic}: time went back {} → {ts}",
            last_ts[slot]
        );
        last_ts[slot] = ts;
        if slot < 2 {
            assert_eq!(p["id"], slot);
            assert_eq!(p["method"], "gazelight filtered");
            per_eye[slot].push(p);
        } else {
            gaze.push(p);
        }
    }
    for e in 0..2 {
        assert!(
            per_eye[e].len() >= 100,
            "eye {e}: {} datums",
            per_eye[e].len()
        );
        for p in per_eye[e].iter().rev().take(50) {
            let mm = p["diameter_3d"].as_f64().unwrap();
            assert!(
                (mm - PEER_MM[e]).abs() < 0.02,
                "eye {e}: {mm} mm vs {}",
                PEER_MM[e]
            );
            // The raw 2D diameter of the newest sample, as published.
            assert_eq!(p["diameter"].as_f64(), Some(PEER_PX[e]), "eye {e}: {p}");
            let c = p["confidence"].as_f64().unwrap();
            assert!(c > 0.8 && c <= 1.0, "{c}");
        }
    }
    let np0 = &per_eye[0].last().unwrap()["norm_pos"];
    assert!((np0[0].as_f64().unwrap() - 0.41).abs() < 1e-6, "{np0}");
    assert!((np0[1].as_f64().unwrap() - 0.52).abs() < 1e-6, "{np0}");
    assert!(gaze.len() >= 100, "{} gaze datums", gaze.len());
    for g in &gaze {
        let np = &g["norm_pos"];
        let (x, y) = (np[0].as_f64().unwrap(), np[1].as_f64().unwrap());
        assert!((0.0..=1.0).contains(&x) && (0.0..=1.0).contains(&y), "{np}");
        assert_eq!(g["base_data"].as_array().unwrap().len(), 2);
    }
    // `t` answers the datums' clock.
    let end = lines.iter().find(|v| v["kind"] == "end").expect("end line");
    let t = end["t"].as_f64().unwrap();
    let newest = last_ts.iter().copied().fold(f64::MIN, f64::max);
    assert!(
        t >= newest && t - newest < 2.0,
        "t {t}, newest datum {newest}"
    );

    // 1b. The pupil light response on its own topic, through the same
    // official client: per eye the predicted pupil (within W&Y's range),
    // the peer's pupil, and their difference.
    let out = Command::new("python3")
        .arg(Path::new(env!("CARGO_MANIFEST_DIR")).join("../gazelight-pupil/tests/relay_client.py"))
        .args(["--port", &relay_port.to_string()])
        .args([
            "--topics",
            "gazelight.pupil_light",
            "--pupil",
            "0",
            "--gaze",
            "0",
        ])
        .args(["--light", "20", "--timeout", "20"])
        .output()
        .expect("python3");
    assert!(
        out.status.success(),
        "relay_client.py (pupil light): {}; {}",
        out.status,
        String::from_utf8_lossy(&out.stderr)
    );
    let light: Vec<serde_json::Value> = String::from_utf8_lossy(&out.stdout)
        .lines()
        .map(|l| serde_json::from_str::<serde_json::Value>(l).unwrap())
        .filter(|v| v["kind"] == "datum")
        .collect();
    assert!(light.len() >= 20, "{} pupil light datums", light.len());
    for v in &light {
        assert_eq!(v["topic"], "gazelight.pupil_light");
        let p = &v["payload"];
        for e in 0..2 {
            let predicted = p["pupil_light_mm"][e].as_f64().unwrap();
            assert!((1.5..=9.0).contains(&predicted), "{p}");
            let measured = p["pupil_mm"][e].as_f64().unwrap();
            assert!((measured - PEER_MM[e]).abs() < 0.05, "{p}");
            if let Some(r) = p["pupil_residual_mm"][e].as_f64() {
                assert!((r - (measured - predicted)).abs() < 1e-4, "{p}");
            }
        }
    }
    assert!(
        light
            .iter()
            .any(|v| v["payload"]["pupil_residual_mm"][0].as_f64().is_some()),
        "the peer's pupils are measured: residuals present"
    );

    // 2. gazelight's own Pupil client decodes it like Pupil Capture.
    rt.block_on(async {
        let config =
            gazelight_tracker::uri::pupil_config(&format!("pupil://127.0.0.1:{relay_port}"))
                .unwrap();
        let (client, mut streams) = PupilClient::spawn(config);
        client.wait_connected(Duration::from_secs(5)).await.unwrap();
        let mut pupils = [0usize; 2];
        let mut gazes = 0usize;
        let deadline = tokio::time::Instant::now() + Duration::from_secs(10);
        while (pupils[0] < 200 || pupils[1] < 200 || gazes < 100)
            && tokio::time::Instant::now() < deadline
        {
            let Ok(Some(s)) =
                tokio::time::timeout(Duration::from_secs(1), streams.samples.recv()).await
            else {
                continue;
            };
            match s {
                Sample::Pupil(p) => {
                    let e = p.eye as usize;
                    pupils[e] += 1;
                    assert_eq!(p.unit, PupilUnit::Px);
                    assert_eq!(f64::from(p.diameter_raw), PEER_PX[e]);
                    let mm = f64::from(p.diameter_mm.expect("diameter_3d"));
                    assert!((mm - PEER_MM[e]).abs() < 0.02, "eye {e}: {mm}");
                }
                Sample::Gaze(_) => gazes += 1,
                Sample::Blink(_) => {}
            }
        }
        let stats = client.stats();
        assert!(
            pupils[0] >= 200 && pupils[1] >= 200 && gazes >= 100,
            "{pupils:?} {gazes}"
        );
        assert_eq!(stats.malformed, 0);
        assert_eq!(stats.unknown_topic, 0);
        assert_eq!(stats.unknown_fields, 0);
        let offset = stats.clock.expect("clock estimate").offset_secs;
        // The relay's clock is the session's host clock: a fixed offset to
        // this process's, far from the peer's +1234.5 s.
        assert!(offset.abs() < 1000.0, "offset {offset}");
        client.shutdown().await;
    });
    drop(run);
}
