#![allow(clippy::unwrap_used, clippy::expect_used)] // test and bench code may panic on a failed setup
//! The service's window under Xvfb (a real X server, lavapipe presenting
//! through Vulkan's X11 WSI): screenshots of the root window taken with
//! `xwd` while the window shows a known thing.

mod common;

use std::io::{BufRead, BufReader};
use std::path::Path;
use std::process::{Child, Command, Stdio};
use std::sync::atomic::{AtomicU32, Ordering};
use std::sync::mpsc;
use std::time::{Duration, Instant};

use common::{python_ready, shared_str, spawn_peer_any_port, tmp};

/// A private X server on a free display number; killed on drop.
struct Xvfb {
    child: Child,
    display: String,
}

impl Drop for Xvfb {
    fn drop(&mut self) {
        let _ = self.child.kill();
        let _ = self.child.wait();
    }
}

fn have(cmd: &str) -> bool {
    Command::new("sh")
        .args(["-c", &format!("command -v {cmd}")])
        .output()
        .map(|o| o.status.success())
        .unwrap_or(false)
}

fn xvfb() -> Option<Xvfb> {
    if !(have("Xvfb") && have("xwd")) {
        assert!(
            std::env::var_os("CI").is_none(),
            "CI must install xvfb and x11-apps"
        );
        eprintln!("SKIP: Xvfb / xwd not installed");
        return None;
    }
    // Tests of this binary run in parallel: each takes its own display
    // number (a lock-file check alone races with a sibling's Xvfb start).
    static NEXT_DISPLAY: AtomicU32 = AtomicU32::new(0);
    for _ in 0..20 {
        let n = NEXT_DISPLAY.fetch_add(1, Ordering::Relaxed);
        let display = format!(":{}", 140 + (std::process::id() % 50) + n * 50);
        let lock = format!("/tmp/.X{}-lock", &display[1..]);
        if Path::new(&lock).exists() {
            continue;
        }
        let child = Command::new("Xvfb")
            .args([&display, "-screen", "0", "800x600x24", "-nolisten", "tcp"])
            .stdout(Stdio::null())
            .stderr(Stdio::null())
            .spawn()
            .expect("spawn Xvfb");
        let mut x = Xvfb { child, display };
        // Wait until it accepts connections.
        let start = Instant::now();
        while start.elapsed() < Duration::from_secs(10) {
            // Exited: the display is someone else's; try the next one.
            if x.child.try_wait().expect("try_wait Xvfb").is_some() {
                break;
            }
            let ok = Command::new("xwd")
                .args([
                    "-root",
                    "-silent",
                    "-display",
                    &x.display,
                    "-out",
                    "/dev/null",
                ])
                .output()
                .map(|o| o.status.success())
                .unwrap_or(false);
            if ok {
                return Some(x);
            }
            std::thread::sleep(Duration::from_millis(100));
        }
    }
    panic!("no Xvfb display came up");
}

/// An X window dump (XWD, version 7, 24/32-bit TrueColor) as RGB rows.
struct Shot {
    width: usize,
    height: usize,
    rgb: Vec<[u8; 3]>,
}

impl Shot {
    /// Screenshots every 50 ms until one satisfies `shows` or `limit`
    /// has passed; the last one taken.
    fn until(display: &str, limit: Duration, shows: impl Fn(&Shot) -> bool) -> Shot {
        let start = Instant::now();
        loop {
            let shot = Shot::take(display);
            if shows(&shot) || start.elapsed() > limit {
                return shot;
            }
            std::thread::sleep(Duration::from_millis(50));
        }
    }

    fn take(display: &str) -> Shot {
        let out = Command::new("xwd")
            .args(["-root", "-silent", "-display", display])
            .output()
            .expect("xwd");
        assert!(out.status.success(), "xwd failed");
        let b = out.stdout;
        let be =
            |i: usize| u32::from_be_bytes([b[4 * i], b[4 * i + 1], b[4 * i + 2], b[4 * i + 3]]);
        let header_size = be(0) as usize;
        assert_eq!(be(1), 7, "XWD version");
        let (width, height) = (be(4) as usize, be(5) as usize);
        let byte_order = be(7);
        let bits_per_pixel = be(11) as usize;
        let bytes_per_line = be(12) as usize;
        let (rmask, gmask, bmask) = (be(14), be(15), be(16));
        let ncolors = be(19) as usize;
        assert_eq!(bits_per_pixel, 32, "expected a 24/32-bit visual");
        let data = &b[header_size + 12 * ncolors..];
        let shift = |m: u32| m.trailing_zeros();
        let mut rgb = Vec::with_capacity(width * height);
        for y in 0..height {
            for x in 0..width {
                let i = y * bytes_per_line + 4 * x;
                let w = [data[i], data[i + 1], data[i + 2], data[i + 3]];
                let v = if byte_order == 0 {
                    u32::from_le_bytes(w)
                } else {
                    u32::from_be_bytes(w)
                };
                rgb.push([
                    ((v & rmask) >> shift(rmask)) as u8,
                    ((v & gmask) >> shift(gmask)) as u8,
                    ((v & bmask) >> shift(bmask)) as u8,
                ]);
            }
        }
        Shot { width, height, rgb }
    }

    fn at(&self, x: usize, y: usize) -> [u8; 3] {
        self.rgb[y * self.width + x]
    }
}

/// Streams a child's stderr lines into a channel.
fn lines_of(child: &mut Child) -> mpsc::Receiver<String> {
    let (tx, rx) = mpsc::channel();
    let stderr = child.stderr.take().expect("stderr");
    std::thread::spawn(move || {
        for line in BufReader::new(stderr).lines().map_while(Result::ok) {
            if tx.send(line).is_err() {
                break;
            }
        }
    });
    rx
}

fn wait_for(rx: &mpsc::Receiver<String>, needle: &str, limit: Duration, log: &mut String) {
    let start = Instant::now();
    while start.elapsed() < limit {
        if let Ok(line) = rx.recv_timeout(Duration::from_millis(100)) {
            log.push_str(&line);
            log.push('\n');
            if line.contains(needle) {
                return;
            }
        }
    }
    panic!("`{needle}` never appeared; output so far:\n{log}");
}

#[test]
fn calibration_window_shows_black_then_white_full_screen() {
    let Some(x) = xvfb() else { return };
    if !python_ready() {
        return;
    }
    let peer = spawn_peer_any_port("100", "40", &[]);
    let dir = tmp("cal");
    let mut child = Command::new(env!("CARGO_BIN_EXE_gazelight"))
        .args([
            "calibrate",
            "--source",
            &format!("pupil://127.0.0.1:{}", peer.remote_port),
            "--stimulus",
            "window",
            "--phase-secs",
            "3",
            "--settle-secs",
            "1",
            "--out",
            dir.join("p.json").to_str().expect("utf-8"),
        ])
        .env("DISPLAY", &x.display)
        .env("RUST_LOG", "warn")
        .stdout(Stdio::piped())
        .stderr(Stdio::piped())
        .spawn()
        .expect("spawn calibrate");
    let rx = lines_of(&mut child);
    let mut log = String::new();
    // Each phase is on screen for its 1 s settle + 3 s: the screen is
    // polled from the phase's own log line until it shows the phase (the
    // window draws it a frame or more after the line), within the phase.
    let points = |s: &Shot| [(5, 5), (s.width - 5, s.height - 5), (400, 300)];
    let phase_secs = Duration::from_secs(4);
    wait_for(&rx, "showing BLACK", Duration::from_secs(20), &mut log);
    let black = Shot::until(&x.display, phase_secs, |s| {
        points(s).iter().all(|&(sx, sy)| s.at(sx, sy) == [0, 0, 0])
    });
    wait_for(&rx, "showing WHITE", Duration::from_secs(10), &mut log);
    let white = Shot::until(&x.display, phase_secs, |s| {
        points(s)
            .iter()
            .all(|&(sx, sy)| s.at(sx, sy) == [255, 255, 255])
    });
    let out = child.wait_with_output().expect("calibrate");
    drop(peer);
    // Full screen: every corner and the centre carry the stimulus.
    for (sx, sy) in points(&black) {
        assert_eq!(black.at(sx, sy), [0, 0, 0], "black phase at ({sx},{sy})");
        assert_eq!(
            white.at(sx, sy),
            [255, 255, 255],
            "white phase at ({sx},{sy})"
        );
    }
    // The peer's simulated pupil reacts only to `gazelight.stimulus`
    // notifications, not to light on a screen it cannot see: the routine
    // must refuse rather than write a profile from a flat response.
    while let Ok(line) = rx.recv_timeout(Duration::from_secs(2)) {
        log.push_str(&line);
        log.push('\n');
    }
    assert!(!out.status.success(), "a flat response must be refused");
    assert!(log.contains("no profile written"), "{log}");
    assert!(!dir.join("p.json").exists());
}

fn png_rgb(path: &Path) -> (usize, usize, Vec<u8>) {
    let img = image::open(path).expect("png").to_rgb8();
    (img.width() as usize, img.height() as usize, img.into_raw())
}

/// The `display:` line of a run's summary: (presented, shown, uploaded,
/// read back, drawn from the GPU pipeline's buffer).
#[derive(Debug)]
struct DisplayLine {
    presented: u64,
    shown: u64,
    uploaded: u64,
    read_back: u64,
    on_gpu_buffer: bool,
    latency_median_ms: f64,
    latency_p99_ms: f64,
}

fn number_before(line: &str, word: &str) -> Option<f64> {
    let i = line.find(word)?;
    line[..i].split_whitespace().last()?.parse().ok()
}

fn display_line(stdout: &str) -> DisplayLine {
    let line = stdout
        .lines()
        .find(|l| l.starts_with("display: window presented"))
        .unwrap_or_else(|| panic!("no window `display:` line in\n{stdout}"));
    let n = |word: &str| {
        number_before(line, word).unwrap_or_else(|| panic!("no `{word}` in {line}")) as u64
    };
    let after = |word: &str| -> f64 {
        let i = line
            .find(word)
            .unwrap_or_else(|| panic!("no `{word}` in {line}"))
            + word.len();
        line[i..]
            .split_whitespace()
            .next()
            .and_then(|v| v.parse().ok())
            .unwrap_or_else(|| panic!("no number after `{word}` in {line}"))
    };
    DisplayLine {
        presented: n(" images"),
        shown: n(" frames shown"),
        uploaded: n(" uploaded"),
        read_back: n(" frames read back"),
        on_gpu_buffer: line.contains("drawn from the GPU pipeline's output buffer"),
        latency_median_ms: after("median"),
        latency_p99_ms: after("p99"),
    }
}

/// The frame count of the run summary (`run: N frames in …`).
fn run_frames(stdout: &str) -> u64 {
    let line = stdout
        .lines()
        .find(|l| l.starts_with("run: "))
        .unwrap_or_else(|| panic!("no run summary in\n{stdout}"));
    number_before(line, " frames in").unwrap_or_else(|| panic!("no frame count: {line}")) as u64
}

/// Whether `--backend gpu` can run here: an adapter exists, or the test is
/// skipped (a failure with GAZELIGHT_REQUIRE_GPU=1, as the GPU tests).
fn gpu_backend_ready(stderr: &str) -> bool {
    if stderr.contains("--backend gpu: no GPU adapter") {
        assert!(
            std::env::var("GAZELIGHT_REQUIRE_GPU").as_deref() != Ok("1"),
            "GAZELIGHT_REQUIRE_GPU=1 but no GPU adapter:\n{stderr}"
        );
        eprintln!("SKIP: no GPU adapter for --backend gpu");
        return false;
    }
    true
}

/// Runs a replayed session in a window on `backend` at 160×120 with
/// `--out`, screenshots the window, and checks its pixels are one of the
/// frames the session wrote. Returns the run's stdout.
fn window_shows_the_written_frames(backend: &str, name: &str) -> Option<String> {
    let x = xvfb()?;
    let dir = tmp(name);
    let (w, h) = (160usize, 120usize);
    let mut child = Command::new(env!("CARGO_BIN_EXE_gazelight"))
        .args([
            "run",
            "--source",
            &format!("replay://{}", shared_str("eye/neon-demo")),
            "--backend",
            backend,
            "--size",
            &format!("{w}x{h}"),
            "--fps",
            "10",
            "--secs",
            "8",
            "--out",
            dir.to_str().expect("utf-8"),
        ])
        .env("DISPLAY", &x.display)
        .env("RUST_LOG", "info")
        .env("NO_COLOR", "1")
        .stdout(Stdio::piped())
        .stderr(Stdio::piped())
        .spawn()
        .expect("spawn run");
    let rx = lines_of(&mut child);
    let mut log = String::new();
    let start = Instant::now();
    // The window appears once the first frame says which device to use.
    while start.elapsed() < Duration::from_secs(60) {
        if let Ok(line) = rx.recv_timeout(Duration::from_millis(100)) {
            log.push_str(&line);
            log.push('\n');
            if line.contains("window adapter") || line.contains("no GPU adapter") {
                break;
            }
        }
    }
    if !gpu_backend_ready(&log) {
        let _ = child.kill();
        return None;
    }
    assert!(log.contains("window adapter"), "no window came up:\n{log}");
    // Several screenshots: the writer skips (and counts) a frame whose
    // image it cannot encode in time, so on a loaded machine the frame on
    // screen at one instant may be one that was never written.
    std::thread::sleep(Duration::from_secs(2));
    let mut shots = Vec::new();
    for _ in 0..6 {
        shots.push(Shot::take(&x.display));
        std::thread::sleep(Duration::from_millis(300));
    }
    let out = child.wait_with_output().expect("run");
    while let Ok(line) = rx.recv_timeout(Duration::from_secs(2)) {
        log.push_str(&line);
        log.push('\n');
    }
    let stdout = String::from_utf8_lossy(&out.stdout).into_owned();
    assert!(out.status.success(), "run failed:\n{log}\n{stdout}");
    assert!(!log.contains("running headless"), "{log}");
    // No window manager: the window sits at the root's origin. Its pixels
    // are one of the frames the session wrote (the window shows the newest
    // frame; adaptation moves slowly, so the nearest written frame is
    // within a few codes) in at least one of the screenshots.
    let written: Vec<(String, Vec<u8>)> = std::fs::read_dir(dir.join("frames"))
        .expect("frames")
        .map(|entry| {
            let path = entry.expect("entry").path();
            let (fw, fh, rgb) = png_rgb(&path);
            assert_eq!((fw, fh), (w, h));
            (path.display().to_string(), rgb)
        })
        .collect();
    assert!(!written.is_empty(), "no frames written:\n{stdout}");
    let mut best = f64::MAX;
    let mut best_name = String::new();
    for (k, shot) in shots.iter().enumerate() {
        let mut region: Vec<u8> = Vec::with_capacity(w * h * 3);
        for y in 0..h {
            for x in 0..w {
                region.extend_from_slice(&shot.at(x, y));
            }
        }
        let max = region.iter().copied().max().unwrap_or(0);
        assert!(
            max > 40,
            "the window region is black in shot {k}: max {max}"
        );
        // Outside the window: the X root (black).
        assert_eq!(shot.at(w + 50, h + 50), [0, 0, 0]);
        for (name, rgb) in &written {
            let mad = rgb
                .iter()
                .zip(&region)
                .map(|(a, b)| (f64::from(*a) - f64::from(*b)).abs())
                .sum::<f64>()
                / rgb.len() as f64;
            if mad < best {
                best = mad;
                best_name = format!("shot {k} vs {name}");
            }
        }
    }
    eprintln!(
        "{backend}: window vs nearest written frame ({best_name}): mean |Δ| = {best:.2} codes"
    );
    assert!(
        best < 3.0,
        "the window does not show the session's frames: {best:.2}\n{stdout}"
    );
    Some(stdout)
}

#[test]
fn run_window_shows_the_replayed_session() {
    let Some(stdout) = window_shows_the_written_frames("cpu", "run") else {
        return;
    };
    // CPU frames are on the host: uploaded to the window, never read back.
    let d = display_line(&stdout);
    eprintln!("{d:?}");
    assert!(!d.on_gpu_buffer, "{d:?}");
    assert!(d.shown > 0 && d.uploaded == d.shown, "{d:?}");
    assert_eq!(d.read_back, 0, "{d:?}");
}

/// On the GPU pipeline the window draws the pipeline's own output buffer
/// (no upload) and shows the frames `--out` wrote; the writer's frames are
/// the only read-backs (one per frame).
#[test]
fn gpu_window_draws_the_pipeline_buffer_and_shows_the_written_frames() {
    let Some(stdout) = window_shows_the_written_frames("gpu", "run-gpu") else {
        return;
    };
    let d = display_line(&stdout);
    eprintln!("{d:?}");
    assert!(d.on_gpu_buffer, "{d:?}");
    assert!(d.shown > 0 && d.presented >= d.shown, "{d:?}");
    assert_eq!(d.uploaded, 0, "{d:?}");
    assert_eq!(
        d.read_back,
        run_frames(&stdout),
        "one read-back per written frame"
    );
}

/// With a window and no host consumer (no `--out`, no `--http`), a GPU
/// frame reaches the surface without a single read-back.
#[test]
fn gpu_window_reads_nothing_back_when_nothing_consumes_the_frames() {
    let Some(x) = xvfb() else { return };
    let out = Command::new(env!("CARGO_BIN_EXE_gazelight"))
        .args([
            "run",
            "--source",
            "synthetic://demo",
            "--backend",
            "gpu",
            "--size",
            "96x80",
            "--fps",
            "10",
            "--secs",
            "6",
        ])
        .env("DISPLAY", &x.display)
        .env("RUST_LOG", "info")
        .env("NO_COLOR", "1")
        .output()
        .expect("run");
    let stdout = String::from_utf8_lossy(&out.stdout);
    let stderr = String::from_utf8_lossy(&out.stderr);
    if !gpu_backend_ready(&stderr) {
        return;
    }
    assert!(out.status.success(), "run failed:\n{stderr}\n{stdout}");
    assert!(!stderr.contains("running headless"), "{stderr}");
    let d = display_line(&stdout);
    eprintln!(
        "{d:?} over {} frames (render to present median {:.2} ms, p99 {:.2} ms)",
        run_frames(&stdout),
        d.latency_median_ms,
        d.latency_p99_ms
    );
    assert!(d.on_gpu_buffer, "{d:?}");
    assert!(d.shown > 0, "no frame reached the window: {d:?}");
    assert_eq!(d.uploaded, 0, "{d:?}");
    assert_eq!(
        d.read_back, 0,
        "a frame was read back with no consumer: {d:?}"
    );
}

#[test]
fn mouse_gaze_follows_the_cursor() {
    let Some(x) = xvfb() else { return };
    if !have("xdotool") {
        assert!(std::env::var_os("CI").is_none(), "CI must install xdotool");
        eprintln!("SKIP: xdotool not installed");
        return;
    }
    let dir = tmp("mouse");
    let mut child = Command::new(env!("CARGO_BIN_EXE_gazelight"))
        .args([
            "run",
            // No tracker: the mouse is the gaze (development mode).
            "--source",
            "pupil://127.0.0.1:9",
            "--mouse-gaze",
            "--size",
            "160x120",
            "--fps",
            "20",
            "--secs",
            "7",
            "--no-frames",
            "--out",
            dir.to_str().expect("utf-8"),
        ])
        .env("DISPLAY", &x.display)
        .env("RUST_LOG", "info")
        .env("NO_COLOR", "1")
        .stdout(Stdio::piped())
        .stderr(Stdio::piped())
        .spawn()
        .expect("spawn run");
    let rx = lines_of(&mut child);
    let mut log = String::new();
    wait_for(&rx, "window adapter", Duration::from_secs(30), &mut log);
    std::thread::sleep(Duration::from_millis(800));
    let mv = |px: &str, py: &str| {
        let ok = Command::new("xdotool")
            .args(["mousemove", px, py])
            .env("DISPLAY", &x.display)
            .status()
            .expect("xdotool");
        assert!(ok.success());
    };
    mv("40", "30");
    std::thread::sleep(Duration::from_millis(1500));
    mv("120", "90");
    std::thread::sleep(Duration::from_millis(1500));
    let out = child.wait_with_output().expect("run");
    while let Ok(line) = rx.recv_timeout(Duration::from_secs(2)) {
        log.push_str(&line);
        log.push('\n');
    }
    assert!(out.status.success(), "run failed:\n{log}");
    let text = std::fs::read_to_string(dir.join("timeline.csv")).expect("timeline");
    let gaze: Vec<(f64, f64)> = text
        .lines()
        .skip(1)
        .map(|l| {
            let f: Vec<&str> = l.split(',').collect();
            (f[2].parse().expect("u"), f[3].parse().expect("v"))
        })
        .collect();
    let near = |u: f64, v: f64| {
        gaze.iter()
            .any(|g| (g.0 - u).abs() < 0.02 && (g.1 - v).abs() < 0.02)
    };
    // Pixel centres (40.5, 30.5) and (120.5, 90.5) of a 160×120 frame.
    assert!(
        near(0.253, 0.254),
        "no frame gazed at (0.25, 0.25): {gaze:?}"
    );
    assert!(
        near(0.753, 0.754),
        "no frame gazed at (0.75, 0.75): {gaze:?}"
    );
}
