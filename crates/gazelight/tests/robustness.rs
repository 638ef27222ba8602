#![allow(clippy::unwrap_used, clippy::expect_used)] // test and bench code may panic on a failed setup
//! Hostile values and faults against the runtime (issue 14): extreme
//! durations and rates, negative numbers, absurd luminance scales and
//! scenes, descriptor exhaustion by idle HTTP clients, and SIGTERM/SIGHUP
//! during `run --out`, `record` and `render`. Every case is bounded in time
//! (each test well under 20 s on two cores).

mod common;

use std::io::{BufRead, BufReader, Read};
use std::path::Path;
use std::process::{Child, Command, Output, Stdio};
use std::time::{Duration, Instant};

use common::{
    Csv, LogWatch, datums_on_disk, free_port, gazelight, python_ready, spawn_peer_any_port, tmp,
    tmp_path, wait_bounded, wait_for,
};

use gazelight_tracker::PldataReader;
use gazelight_tracker::recording::{read_npy_f64, stream_paths};

fn bin() -> Command {
    let mut c = Command::new(env!("CARGO_BIN_EXE_gazelight"));
    c.env("RUST_LOG", "warn");
    c
}

fn spawn(args: &[&str]) -> Child {
    bin()
        .args(args)
        .stdout(Stdio::piped())
        .stderr(Stdio::piped())
        .spawn()
        .expect("spawn gazelight")
}

fn text(out: &Output) -> (String, String) {
    (
        String::from_utf8_lossy(&out.stdout).into_owned(),
        String::from_utf8_lossy(&out.stderr).into_owned(),
    )
}

/// The command failed with a normal error exit (not a panic, not a signal)
/// and its message contains every one of `needles`.
fn refused(out: &Output, needles: &[&str]) {
    let (stdout, stderr) = text(out);
    assert_eq!(
        out.status.code(),
        Some(1),
        "expected a clean error exit; stdout {stdout}\nstderr {stderr}"
    );
    assert!(!stderr.contains("panicked"), "{stderr}");
    assert!(!stderr.contains("unexpected argument"), "{stderr}");
    for n in needles {
        assert!(stderr.contains(n), "no `{n}` in: {stderr}");
    }
}

fn kill(child: &Child, signal: &str) {
    let ok = Command::new("kill")
        .args([&format!("-{signal}"), &child.id().to_string()])
        .status()
        .expect("kill");
    assert!(ok.success(), "kill -{signal}");
}

const SYNTH: &[&str] = &[
    "run",
    "--source",
    "synthetic://demo",
    "--headless",
    "--size",
    "160x120",
];

fn run_args<'a>(extra: &[&'a str]) -> Vec<&'a str> {
    let mut v: Vec<&str> = SYNTH.to_vec();
    v.extend_from_slice(extra);
    v
}

#[test]
fn fps_and_secs_extremes_are_refused_or_honoured() {
    // Out of range: refused before anything starts, naming flag and range.
    refused(
        &gazelight(&run_args(&["--fps", "1e-300", "--secs", "1"])),
        &["--fps 1e-300", "0.001"],
    );
    refused(
        &gazelight(&run_args(&["--secs", "1e308"])),
        &["--secs 1e308", "2592000"],
    );
    refused(
        &gazelight(&["record", "--out", "/nonexistent/x", "--secs", "1e308"]),
        &["--secs 1e308"],
    );
    refused(
        &gazelight(&[
            "render",
            "--frames",
            "1000000000",
            "--size",
            "160x120",
            "--no-frames",
            "--out",
            tmp("frames1e9").to_str().unwrap(),
        ]),
        &["1000000000", "1000000"],
    );

    // The slowest rate accepted stops on time: 2 s, not one 1000 s frame.
    // The bound is the run's own record: its session (the summary's
    // `frames in <s> s`, from its frame loop's start) ends at --secs 2 or
    // when its one frame (timeline.csv's frame_ms) ends, whichever is
    // later, plus one shutdown poll (50 ms); 0.5 s covers the summary's
    // rounding (0.1 s) and a late wake-up on a loaded machine. The wait's
    // 60 s is only a backstop: a run that slept its 1000 s frame hits it.
    let slow = tmp_path("fps-slow");
    let t = Instant::now();
    let out = wait_bounded(
        spawn(&run_args(&[
            "--fps",
            "0.001",
            "--secs",
            "2",
            "--no-frames",
            "--out",
            slow.to_str().unwrap(),
        ])),
        Duration::from_secs(60),
    );
    let wall = t.elapsed().as_secs_f64();
    let (stdout, stderr) = text(&out);
    assert!(out.status.success(), "{stdout}\n{stderr}");
    let session = session_secs(&stdout);
    let frame_secs = Csv::read(&slow.join("timeline.csv"))
        .f64s("frame_ms")
        .iter()
        .fold(0.0, |a: f64, b| a.max(b / 1000.0));
    assert!(
        session <= 2.0f64.max(frame_secs) + 0.05 + 0.5,
        "run --fps 0.001 --secs 2: a {session} s session, its frame {frame_secs:.3} s; {stdout}"
    );
    let _ = std::fs::remove_dir_all(&slow);
    eprintln!("run --fps 0.001 --secs 2: exited 0 after {wall:.2} s (its session {session:.1} s)");

    // ... and on Ctrl-C, once the run said it is running (its signal
    // handlers are installed before that line, not after a sleep). The
    // bound is the frame period the run must not sleep through (1000 s):
    // 60 s covers the exit of a loaded machine.
    let mut child = bin()
        .args(run_args(&["--fps", "0.001"]))
        .env("RUST_LOG", "info")
        .stdout(Stdio::piped())
        .stderr(Stdio::piped())
        .spawn()
        .expect("spawn gazelight");
    let log = LogWatch::start(&mut child);
    log.wait_line("running", Duration::from_secs(60));
    let t = Instant::now();
    kill(&child, "INT");
    let out = wait_bounded(child, Duration::from_secs(60));
    let stop = t.elapsed().as_secs_f64();
    let stderr = log.finish();
    assert!(out.status.success(), "{:?} {stderr}", text(&out));
    assert!(stderr.contains("SIGINT: shutting down"), "{stderr}");
    eprintln!("run --fps 0.001 + SIGINT: exited 0 {stop:.2} s after the signal");
}

/// The session length of a run's summary (`run: N frames in <s> s`).
fn session_secs(stdout: &str) -> f64 {
    let i = stdout
        .find(" frames in ")
        .unwrap_or_else(|| panic!("no summary in {stdout}"));
    stdout[i + " frames in ".len()..]
        .split(' ')
        .next()
        .and_then(|s| s.parse().ok())
        .unwrap_or_else(|| panic!("no session length in {stdout}"))
}

#[test]
fn negative_numbers_reach_the_range_checks() {
    // Each reaches the flag's own check (no "unexpected argument").
    refused(&gazelight(&run_args(&["--fps", "-5"])), &["--fps -5"]);
    refused(&gazelight(&run_args(&["--secs", "-1"])), &["--secs -1"]);
    refused(&gazelight(&run_args(&["--luminance-scale", "-2"])), &["-2"]);
    refused(
        &gazelight(&["record", "--out", "/nonexistent/x", "--secs", "-3"]),
        &["--secs -3"],
    );
    refused(
        &gazelight(&["calibrate", "--out", "/tmp/x.json", "--silence-secs", "-1"]),
        &["-1"],
    );
    refused(
        &gazelight(&["psf", "--pupil-mm", "-4", "--out", "/tmp/x"]),
        &["-4"],
    );
    // A negative yaw is a valid angle and still works.
    let out = gazelight(&run_args(&["--yaw-deg", "-78", "--secs", "0.3"]));
    assert!(out.status.success(), "{:?}", text(&out));
}

/// A `w`×`h` Radiance .hdr whose every pixel is the RGBE value
/// (m, m, m, e): m/256 · 2^(e−128) per channel (flat scanlines).
fn uniform_hdr(path: &Path, w: usize, h: usize, m: u8, e: u8) {
    let mut bytes = format!("#?RADIANCE\nFORMAT=32-bit_rle_rgbe\n\n-Y {h} +X {w}\n").into_bytes();
    for _ in 0..w * h {
        bytes.extend_from_slice(&[m, m, m, e]);
    }
    std::fs::write(path, bytes).expect("write hdr");
}

#[test]
fn absurd_luminance_is_refused_or_warned_never_silently_black() {
    let dir = tmp("luminance");
    let out_dir = dir.join("out");
    let out = out_dir.to_str().unwrap();
    let render = |extra: &[&str]| {
        let mut a = vec![
            "render",
            "--size",
            "160x120",
            "--frames",
            "2",
            "--no-frames",
            "--out",
            out,
        ];
        a.extend_from_slice(extra);
        gazelight(&a)
    };
    refused(
        &render(&["--luminance-scale", "1e308"]),
        &["--luminance-scale 1e308"],
    );
    refused(
        &render(&["--scene-key-cd-m2", "1e308"]),
        &["--scene-key-cd-m2 1e308"],
    );
    // The brightest RGBE value, 255/256 · 2^127 ≈ 1.7e38 (f32::MAX is 3.4e38).
    let huge = dir.join("huge.hdr");
    uniform_hdr(&huge, 64, 32, 255, 255);
    refused(
        &render(&["--scene", huge.to_str().unwrap()]),
        &["huge.hdr", "cd/m²"],
    );
    // 0.5 · 2^93 ≈ 5e27 file units (≈ 9e29 cd/m² with Radiance's
    // 179 lm/W): rendered, with a loud warning.
    let bright = dir.join("bright.hdr");
    uniform_hdr(&bright, 64, 32, 128, 221);
    let o = render(&["--scene", bright.to_str().unwrap()]);
    let (stdout, stderr) = text(&o);
    assert!(o.status.success(), "{stdout}\n{stderr}");
    assert!(
        stderr.contains("warning") && stderr.contains("probably wrong"),
        "no warning for a 6e29 cd/m² scene: {stderr}"
    );
    // A factor in range that overflows single precision on this scene
    // (5e27 × 1e20 > 3.4e38): refused, naming the scale.
    refused(
        &render(&[
            "--scene",
            bright.to_str().unwrap(),
            "--luminance-scale",
            "1e20",
        ]),
        &["overflow", "1e20"],
    );
    // The same from `run`.
    refused(
        &gazelight(&run_args(&["--luminance-scale", "1e308", "--secs", "1"])),
        &["--luminance-scale 1e308"],
    );
    refused(
        &gazelight(&run_args(&[
            "--scene",
            huge.to_str().unwrap(),
            "--secs",
            "1",
        ])),
        &["overflow"],
    );
}

/// Checks a live `timeline.csv` / `psf.csv`: header plus complete rows
/// (every line has the header's field count, the file ends with a newline).
/// Returns (timeline rows, psf rows).
fn check_run_outputs(dir: &Path) -> (usize, usize) {
    let mut counts = [0usize; 2];
    for (i, name) in ["timeline.csv", "psf.csv"].iter().enumerate() {
        let t = std::fs::read_to_string(dir.join(name)).expect(name);
        assert!(
            t.ends_with('\n'),
            "{name} is cut mid-row: {:?}",
            &t[t.len().saturating_sub(80)..]
        );
        let mut lines = t.lines();
        let fields = lines.next().expect("header").split(',').count();
        for (n, l) in lines.enumerate() {
            assert_eq!(
                l.split(',').count(),
                fields,
                "{name} row {n} is incomplete: {l:?}"
            );
            counts[i] += 1;
        }
    }
    (counts[0], counts[1])
}

/// Lines in `dir/name` beyond the header (0 when missing).
fn rows_in(dir: &Path, name: &str) -> usize {
    std::fs::read_to_string(dir.join(name)).map_or(0, |t| t.lines().count().saturating_sub(1))
}

/// Waits (bounded) until `timeline.csv` holds `rows` rows and `psf.csv` a
/// kernel row, as the writer's periodic flush puts them on disk.
fn wait_rows(dir: &Path, rows: usize, limit: Duration) -> (usize, usize) {
    let t = Instant::now();
    loop {
        let (r, p) = (rows_in(dir, "timeline.csv"), rows_in(dir, "psf.csv"));
        if (r >= rows && p >= 1) || t.elapsed() > limit {
            return (r, p);
        }
        std::thread::sleep(Duration::from_millis(100));
    }
}

#[test]
fn sigterm_and_sighup_during_run_out_leave_complete_files() {
    for signal in ["TERM", "HUP"] {
        let dir = tmp_path(&format!("run-{signal}"));
        let child = spawn(&run_args(&["--fps", "60", "--out", dir.to_str().unwrap()]));
        // The files fill while the run goes on (flushed every second).
        let (seen, seen_psf) = wait_rows(&dir, 3, Duration::from_secs(15));
        assert!(
            seen >= 3 && seen_psf >= 1,
            "SIG{signal}: {seen} rows, {seen_psf} kernels on disk before the signal"
        );
        let t = Instant::now();
        kill(&child, signal);
        let out = wait_bounded(child, Duration::from_secs(15));
        let stop = t.elapsed().as_secs_f64();
        let (stdout, stderr) = text(&out);
        assert!(out.status.success(), "SIG{signal}: {stdout}\n{stderr}");
        assert!(
            stdout.contains("run: "),
            "no summary after SIG{signal}: {stdout}"
        );
        let (rows, psf_rows) = check_run_outputs(&dir);
        assert!(
            rows >= seen,
            "SIG{signal}: {rows} rows after the signal, {seen} before"
        );
        assert!(psf_rows >= 1, "SIG{signal}: psf.csv has no kernel row");
        // The summary's count is what is on disk.
        assert!(
            stdout.contains(&format!("timeline.csv ({rows} rows)")),
            "SIG{signal}: {rows} rows on disk; {stdout}"
        );
        let frames = std::fs::read_dir(dir.join("frames"))
            .expect("frames")
            .count();
        assert!(frames > 0, "SIG{signal}: no frames");
        eprintln!(
            "run --out + SIG{signal}: exit 0 in {stop:.2} s; {rows} complete rows, {psf_rows} kernels, {frames} frames"
        );
    }
}

#[test]
fn sigterm_during_render_writes_what_was_rendered() {
    let dir = tmp_path("render-TERM");
    // Glare off, so frames come quickly whatever the kernel build costs.
    let config = tmp("render-TERM-config").join("render.toml");
    std::fs::write(&config, "[pipeline]\nglare = { enabled = false }\n").expect("config");
    let child = spawn(&[
        "render",
        "--size",
        "320x240",
        "--frames",
        "1000000",
        "--config",
        config.to_str().unwrap(),
        "--out",
        dir.to_str().unwrap(),
    ]);
    // The most frames one invocation renders: the signal lands mid-render,
    // once the first frame image is on disk (the signal handlers are
    // installed before the first frame), not after a sleep (a 160x120 run
    // of 100 000 frames once finished inside the 4 s this test used to
    // wait; 10⁶ PNG frames take hours).
    let first = dir.join("frames").join("frame_00000.png");
    wait_for(Duration::from_secs(120), "the first frame image", || {
        first.is_file().then_some(())
    });
    kill(&child, "TERM");
    let out = wait_bounded(child, Duration::from_secs(15));
    let (stdout, stderr) = text(&out);
    assert_eq!(out.status.code(), Some(1), "{stdout}\n{stderr}");
    assert!(stderr.contains("SIGTERM: stopped after"), "{stderr}");
    let t = std::fs::read_to_string(dir.join("timeline.csv")).expect("timeline");
    let rows = t.lines().count() - 1;
    assert!(rows > 0 && rows < 1_000_000, "{rows} rows");
    assert!(
        stderr.contains(&format!("stopped after {rows} of 1000000 frames")),
        "timeline holds {rows} rows; {stderr}"
    );
    assert!(dir.join("plot.png").is_file() && dir.join("contact_sheet.png").is_file());
}

fn pldata_records(dir: &Path, stream: &str) -> usize {
    let (pldata, npy) = stream_paths(dir, stream);
    let mut n = 0usize;
    for r in PldataReader::open(&pldata).expect("open pldata") {
        r.expect("a complete record");
        n += 1;
    }
    let ts = read_npy_f64(&npy).expect("npy");
    assert_eq!(ts.len(), n, "{stream}: .npy and .pldata disagree");
    n
}

#[test]
fn sigterm_and_sighup_during_record_leave_a_readable_recording() {
    if !python_ready() {
        return;
    }
    for signal in ["TERM", "HUP"] {
        let peer = spawn_peer_any_port("200", "20", &[]);
        let dir = tmp_path(&format!("record-{signal}"));
        let mut child = spawn(&[
            "record",
            "--source",
            &format!("pupil://127.0.0.1:{}", peer.remote_port),
            "--out",
            dir.to_str().unwrap(),
        ]);
        // Wait for "recording …" on stderr, then until 401 pupil datums
        // are on disk (flushed every second), not for a fixed 2 s.
        let spawned = Instant::now();
        let mut stderr = BufReader::new(child.stderr.take().expect("stderr"));
        let mut line = String::new();
        let t = Instant::now();
        while !line.starts_with("recording") {
            line.clear();
            if stderr.read_line(&mut line).expect("stderr") == 0 || t.elapsed().as_secs() > 60 {
                panic!("record did not start: {line}");
            }
        }
        wait_for(Duration::from_secs(60), "401 pupil datums on disk", || {
            (datums_on_disk(&dir, "pupil") > 400).then_some(())
        });
        let signalled = Instant::now();
        kill(&child, signal);
        let status = common::wait_exit(&mut child, Duration::from_secs(10));
        let mut stdout = String::new();
        child
            .stdout
            .take()
            .expect("stdout")
            .read_to_string(&mut stdout)
            .expect("read");
        let mut rest = String::new();
        stderr.read_to_string(&mut rest).expect("read");
        drop(peer);
        assert!(status.success(), "SIG{signal}: {stdout}\n{rest}");
        assert!(
            stdout.contains(&format!("stopped (SIG{signal})")),
            "{stdout}"
        );
        let pupil = pldata_records(&dir, "pupil");
        assert!(pupil > 400, "SIG{signal}: only {pupil} pupil datums");
        let info: serde_json::Value = serde_json::from_str(
            &std::fs::read_to_string(dir.join("info.player.json")).expect("info"),
        )
        .expect("json");
        let duration = info["duration_s"].as_f64().expect("duration_s");
        // At least the span of the 401 datums seen before the signal (2 D +
        // 3 D × 2 eyes per 200 Hz cycle: 100 cycles, 0.5 s; halved for a
        // peer that caught up in bursts); at most as long as the process
        // ran before the signal, + 0.5 s for the peer's clock (Python's)
        // against ours.
        let lived = signalled.duration_since(spawned).as_secs_f64();
        assert!(
            duration >= 0.25 && duration <= lived + 0.5,
            "SIG{signal}: duration_s {duration} for a recording signalled {lived:.2} s after its start"
        );
        let inspect = gazelight(&["inspect", dir.to_str().unwrap()]);
        assert!(
            inspect.status.success(),
            "inspect after SIG{signal}: {:?}",
            text(&inspect)
        );
        eprintln!(
            "record + SIG{signal}: {pupil} pupil datums, duration_s {duration:.2}, inspect ok"
        );
    }
}

/// Holds `n` idle TCP connections to `port` from a Python helper with its
/// own descriptor limit; prints `HELD k` once they are open.
fn hold_connections(port: u16, n: usize, secs: u32) -> Child {
    let script = format!(
        r#"
import resource, socket, sys, time, errno
soft, hard = resource.getrlimit(resource.RLIMIT_NOFILE)
resource.setrlimit(resource.RLIMIT_NOFILE, (min(hard, 8192), hard))
held = []
for _ in range({n}):
    s = socket.socket()
    s.setblocking(False)
    r = s.connect_ex(("127.0.0.1", {port}))
    if r in (0, errno.EINPROGRESS):
        held.append(s)
    else:
        s.close()
time.sleep(0.5)
print("HELD", len(held), flush=True)
time.sleep({secs})
"#
    );
    Command::new("python3")
        .args(["-c", &script])
        .stdout(Stdio::piped())
        .stderr(Stdio::inherit())
        .spawn()
        .expect("python3")
}

#[test]
fn idle_http_connections_do_not_starve_the_writers() {
    let dir = tmp_path("fds");
    // Glare off: the frame rate then depends on nothing but the writers.
    let config = tmp("fds-config").join("run.toml");
    std::fs::write(&config, "[pipeline]\nglare = { enabled = false }\n").expect("config");
    let port = free_port();
    let fps = 30.0;
    // The run under `ulimit -n 1024`, as in the campaign; it ends by
    // SIGTERM once the test saw what it needs (--secs 120: a backstop).
    let cmd = format!(
        "ulimit -n 1024 && exec {} run --source synthetic://demo --headless --size 160x120 --fps {fps} --secs 120 --http 127.0.0.1:{port} --out {} --config {}",
        env!("CARGO_BIN_EXE_gazelight"),
        dir.display(),
        config.display()
    );
    let child = Command::new("sh")
        .args(["-c", &cmd])
        .env("RUST_LOG", "warn")
        .stdout(Stdio::piped())
        .stderr(Stdio::piped())
        .spawn()
        .expect("sh");
    common::wait_listening(port, Duration::from_secs(60));
    let mut holder = hold_connections(port, 1100, 120);
    let mut line = String::new();
    BufReader::new(holder.stdout.take().expect("stdout"))
        .read_line(&mut line)
        .expect("HELD line");
    let held: usize = line
        .trim()
        .strip_prefix("HELD ")
        .and_then(|n| n.parse().ok())
        .unwrap_or_else(|| panic!("{line:?}"));
    assert!(held >= 1024, "only {held} connections opened");
    // The writers keep going while the connections are held: 90 more rows
    // (3 s at 30 Hz) on disk after the holder said HELD, then the signal.
    let timeline_path = dir.join("timeline.csv");
    let rows_now = || Csv::try_read(&timeline_path).map_or(0, |c| c.rows.len());
    let early = rows_now();
    wait_for(
        Duration::from_secs(120),
        "90 more rows while the connections are held",
        || (rows_now() >= early + 90).then_some(()),
    );
    kill(&child, "TERM");
    let out = wait_bounded(child, Duration::from_secs(30));
    let _ = holder.kill();
    let _ = holder.wait();
    let (stdout, stderr) = text(&out);
    assert!(out.status.success(), "{stdout}\n{stderr}");
    assert!(!stderr.contains("Too many open files"), "{stderr}");
    let (rows, _) = check_run_outputs(&dir);
    let frames = std::fs::read_dir(dir.join("frames"))
        .expect("frames")
        .count();
    // The rate on the run's own clock (t_secs), over the rows written while
    // the connections were held: at least 0.6 of the 30 Hz asked for, and
    // no frame gap over 0.5 s.
    let t = Csv::read(&timeline_path).f64s("t_secs");
    let held_t = &t[early.min(t.len() - 1)..];
    let span = held_t[held_t.len() - 1] - held_t[0];
    let rate = (held_t.len() - 1) as f64 / span;
    let gap = held_t.windows(2).map(|w| w[1] - w[0]).fold(0.0, f64::max);
    eprintln!(
        "{held} idle connections under ulimit -n 1024: {} rows at {rate:.1} Hz over {span:.1} s while held (largest gap {gap:.3} s); {rows} rows and {frames} frames in all at {fps} Hz",
        held_t.len()
    );
    assert!(
        rate > 0.6 * fps && gap < 0.5,
        "timeline stalled while held: {rate:.1} Hz, largest gap {gap:.3} s"
    );
    // Frame images may be skipped under pressure (counted), never all:
    // at least 0.3 of the rows, as before.
    assert!(
        frames as f64 > 0.3 * rows as f64,
        "{frames} frames for {rows} rows"
    );
}
