#![allow(clippy::unwrap_used, clippy::expect_used)] // test and bench code may panic on a failed setup
//! `gazelight run` on a hardware transport: the Gazepoint Open Gaze API
//! over TCP, served by the tracker crate's simulator on 127.0.0.1. The
//! records reach the frame loop through the same filter chain and hub as a
//! Pupil source (the HID, serial and USB transports are exercised through
//! real kernel paths by the QEMU stage, `.ci/qemu/run`).

mod common;

use std::process::Command;
use std::time::Duration;

use common::tmp_path;

use gazelight_tracker::transport::gazepoint::sim::{self, Session};

/// A GP3 record (the fields the client enables), gaze (0.3, 0.7), pupils
/// 5.2 mm left and 5.0 mm right.
fn record(cnt: u32, time: f64) -> String {
    sim::rec(&[
        ("CNT", cnt.to_string()),
        ("TIME", format!("{time:.5}")),
        ("FPOGX", "0.30000".into()),
        ("FPOGY", "0.70000".into()),
        ("FPOGS", "0.0".into()),
        ("FPOGD", "0.5".into()),
        ("FPOGID", "7".into()),
        ("FPOGV", "1".into()),
        ("LPCX", "0.4".into()),
        ("LPCY", "0.3".into()),
        ("LPD", "15.2".into()),
        ("LPS", "1.0".into()),
        ("LPV", "1".into()),
        ("RPCX", "0.8".into()),
        ("RPCY", "0.5".into()),
        ("RPD", "14.6".into()),
        ("RPS", "1.0".into()),
        ("RPV", "1".into()),
        ("LPMM", "5.20000".into()),
        ("LPMMV", "1".into()),
        ("RPMM", "5.00000".into()),
        ("RPMMV", "1".into()),
    ])
}

#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn run_reads_a_gazepoint_tracker() {
    let lines: Vec<String> = (0..240)
        .map(|i| record(i + 1, f64::from(i) / 60.0))
        .collect();
    let server = sim::start(vec![Session {
        lines,
        drop_after: false,
        // A 60 Hz GP3.
        line_interval: Some(Duration::from_secs_f64(1.0 / 60.0)),
    }])
    .await
    .expect("simulator");
    let port = server.addr.port();
    let dir = tmp_path("gp");
    let dir_arg = dir.to_str().expect("utf-8").to_owned();
    let out = tokio::task::spawn_blocking(move || {
        Command::new(env!("CARGO_BIN_EXE_gazelight"))
            .args([
                "run",
                "--headless",
                "--source",
                &format!("gazepoint://127.0.0.1:{port}"),
                "--size",
                "64x48",
                "--fps",
                "30",
                "--secs",
                "3",
                "--no-frames",
                "--out",
                &dir_arg,
            ])
            .env("RUST_LOG", "warn")
            .output()
            .expect("run gazelight")
    });
    let out = tokio::time::timeout(Duration::from_secs(60), out)
        .await
        .expect("run ends in time")
        .expect("join");
    let stdout = String::from_utf8_lossy(&out.stdout);
    let stderr = String::from_utf8_lossy(&out.stderr);
    assert!(out.status.success(), "run failed: {stdout}\n{stderr}");
    // The handshake enabled the pupil-in-mm fields.
    let set = server.received.lock().expect("lock").clone();
    assert!(
        set.iter()
            .any(|(id, on)| id == "ENABLE_SEND_PUPILMM" && on == "1"),
        "{set:?}"
    );
    // Frames used the tracker's measured pupils and gaze.
    let text = std::fs::read_to_string(dir.join("timeline.csv")).expect("timeline");
    let mut lines = text.lines();
    let header: Vec<&str> = lines.next().expect("header").split(',').collect();
    let col = |name: &str| header.iter().position(|h| *h == name).expect(name);
    let (gu, gv, pr, pl, health) = (
        col("gaze_u"),
        col("gaze_v"),
        col("pupil_right_mm"),
        col("pupil_left_mm"),
        col("source_health"),
    );
    let measured = lines
        .map(|l| l.split(',').map(str::to_owned).collect::<Vec<_>>())
        .filter(|f| {
            let n = |i: usize| f[i].parse::<f64>().unwrap_or(f64::NAN);
            (n(pr) - 5.0).abs() < 0.01
                && (n(pl) - 5.2).abs() < 0.01
                && (n(gu) - 0.3).abs() < 1e-3
                && (n(gv) - 0.7).abs() < 1e-3
                && f[health] == "live"
        })
        .count();
    assert!(
        measured > 0,
        "no frame used the Gazepoint values:\n{text}\n{stderr}"
    );
}
