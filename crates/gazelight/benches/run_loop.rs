#![allow(clippy::unwrap_used, clippy::expect_used)] // test and bench code may panic on a failed setup
//! Live-session benchmarks of `gazelight run` (a bench binary, not
//! criterion: each figure is one whole run of the real binary).
//!
//! 1. `EyeState` age at frame time (median, p99, max) in a live run against
//!    the pyzmq Pupil peer (crates/gazelight-tracker/tests/pupil_peer.py) at
//!    200 Hz and at 1 kHz, default size 720×800, 90 Hz display.
//! 2. Both eyes (`--stereo`, two 720×800 views) against the 200 Hz peer:
//!    frames, late frames, dropped deadlines (issue 13).
//! 3. A sustained 90 Hz frame loop on the CPU path at the default size
//!    (synthetic source, whose glance at the lamp rebuilds the PSF): frames,
//!    late frames, dropped deadlines, and from `timeline.csv` the frames
//!    that installed a new kernel against the others (issue 10: a rebuild
//!    must not cost a frame).
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
        for (rate, stereo) in [(200.0, false), (1000.0, false), (200.0, true)] {
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
            let source = format!("pupil://127.0.0.1:{port}");
            let mut args = vec!["--source", &source, "--headless", "--secs", &secs_s];
            if stereo {
                args.push("--stereo");
            }
            let summary = run(&args);
            let _ = peer.kill();
            let _ = peer.wait();
            let eyes = if stereo { "both eyes" } else { "one eye" };
            println!("peer at {rate} Hz, {eyes} 720x800 @ 90 Hz: {summary}");
        }
    } else {
        println!("SKIP the live runs: python3 with pyzmq + msgpack not available");
    }

    let out = std::env::temp_dir().join(format!("gazelight-run-loop-{}", std::process::id()));
    let out_s = out.to_string_lossy().into_owned();
    let summary = run(&[
        "--source",
        "synthetic://demo",
        "--headless",
        "--secs",
        &secs_s,
        "--out",
        &out_s,
        "--no-frames",
    ]);
    println!("CPU path, 720x800 @ 90 Hz, synthetic source: {summary}");
    rebuild_frames(&out.join("timeline.csv"));
    let _ = std::fs::remove_dir_all(&out);
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

/// The frames of a run that installed a new PSF kernel against the others:
/// their `frame_ms` medians and how many of each took longer than a 90 Hz
/// period.
fn rebuild_frames(timeline: &Path) {
    let text = std::fs::read_to_string(timeline).expect("timeline.csv");
    let mut lines = text.lines();
    let header: Vec<&str> = lines.next().expect("header").split(',').collect();
    let col = |name: &str| header.iter().position(|h| *h == name).expect(name);
    let (rebuilt, ms) = (col("psf_rebuilt"), col("frame_ms"));
    let (mut with, mut without) = (Vec::new(), Vec::new());
    for line in lines {
        let f: Vec<&str> = line.split(',').collect();
        let t: f64 = f[ms].parse().expect("frame_ms");
        if f[rebuilt] == "1" {
            with.push(t);
        } else {
            without.push(t);
        }
    }
    let period_ms = 1e3 / 90.0;
    let stats = |v: &mut Vec<f64>| {
        v.sort_by(f64::total_cmp);
        let over = v.iter().filter(|&&t| t > period_ms).count();
        (
            v.get(v.len() / 2).copied().unwrap_or(f64::NAN),
            over,
            v.len(),
        )
    };
    let (m1, o1, n1) = stats(&mut with);
    let (m0, o0, n0) = stats(&mut without);
    println!(
        "  frames that installed a kernel: {n1}, frame_ms median {m1:.2}, {o1} over {period_ms:.1} ms; \
         other frames: {n0}, median {m0:.2}, {o0} over"
    );
}
