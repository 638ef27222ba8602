#![allow(clippy::unwrap_used, clippy::expect_used)] // test and bench code may panic on a failed setup
//! Live-session benchmarks of `gazelight run` (a bench binary, not
//! criterion: each figure is one whole run of the real binary).
//!
//! 1. `EyeState` age at frame time (median, p99, max) in a live run against
//!    the pyzmq Pupil peer (crates/gazelight-tracker/tests/pupil_peer.py) at
//!    200 Hz and at 1 kHz, default size 720×800, 90 Hz display.
//! 2. A sustained 90 Hz frame loop on the CPU path at the default size
//!    (synthetic source): frames, late frames, dropped deadlines.
//!
//! `cargo bench -p gazelight --bench run_loop` (`RUN_LOOP_SECS` sets the
//! length of each run, default 10 s).

use std::io::{BufRead, BufReader};
use std::path::Path;
use std::process::{Command, Stdio};

fn run(args: &[&str]) -> String {
    let out = Command::new(env!("CARGO_BIN_EXE_gazelight"))
        .arg("run")
        .args(args)
        .env("RUST_LOG", "warn")
        .output()
        .expect("run gazelight");
    let stdout = String::from_utf8_lossy(&out.stdout).into_owned();
    assert!(
        out.status.success(),
        "gazelight run failed: {}",
        String::from_utf8_lossy(&out.stderr)
    );
    stdout
        .lines()
        .find(|l| l.starts_with("run: "))
        .unwrap_or_else(|| panic!("no summary in {stdout}"))
        .to_owned()
}

fn main() {
    // `cargo test --benches` runs bench binaries with `--bench` absent:
    // keep that quick.
    let quick = !std::env::args().any(|a| a == "--bench");
    let secs: f64 = std::env::var("RUN_LOOP_SECS")
        .ok()
        .and_then(|s| s.parse().ok())
        .unwrap_or(if quick { 2.0 } else { 10.0 });
    let secs_s = secs.to_string();
    let cores = std::thread::available_parallelism().map_or(0, |n| n.get());
    println!("machine: {cores} cores; {secs} s per run");

    let python = Command::new("python3")
        .args(["-c", "import zmq, msgpack"])
        .output()
        .map(|o| o.status.success())
        .unwrap_or(false);
    if python {
        let script =
            Path::new(env!("CARGO_MANIFEST_DIR")).join("../gazelight-tracker/tests/pupil_peer.py");
        for rate in [200.0, 1000.0] {
            let mut peer = Command::new("python3")
                .arg(&script)
                .args([
                    "--remote-port",
                    "0",
                    "--rate",
                    &rate.to_string(),
                    "--timeout",
                    &(secs + 30.0).to_string(),
                ])
                .stdout(Stdio::piped())
                .spawn()
                .expect("spawn peer");
            let mut line = String::new();
            BufReader::new(peer.stdout.take().expect("stdout"))
                .read_line(&mut line)
                .expect("READY");
            let port = line
                .split_whitespace()
                .find_map(|w| w.strip_prefix("remote="))
                .expect("remote port")
                .to_owned();
            let summary = run(&[
                "--source",
                &format!("pupil://127.0.0.1:{port}"),
                "--headless",
                "--secs",
                &secs_s,
            ]);
            let _ = peer.kill();
            let _ = peer.wait();
            println!("peer at {rate} Hz, 720x800 @ 90 Hz: {summary}");
        }
    } else {
        println!("SKIP the live runs: python3 with pyzmq + msgpack not available");
    }

    let summary = run(&[
        "--source",
        "synthetic://demo",
        "--headless",
        "--secs",
        &secs_s,
    ]);
    println!("CPU path, 720x800 @ 90 Hz, synthetic source: {summary}");
    let summary = run(&[
        "--source",
        "synthetic://demo",
        "--headless",
        "--secs",
        &secs_s,
        "--size",
        "360x400",
    ]);
    println!("CPU path, 360x400 @ 90 Hz, synthetic source: {summary}");
}
