#![allow(clippy::unwrap_used, clippy::expect_used)] // test code may panic on a failed setup
//! Outputs never silently clobber an input or go stale (issue 37, item 6):
//! the one `--out` rule (`src/out_dir.rs`) for every command that writes
//! `--out`; a SIGKILLed `render` re-run; a SIGKILLed `record`'s
//! `info.player.json`; a dangling `pupil.pldata` symlink named; and a full
//! disk (a small tmpfs in a private mount namespace) during `run --out`.

mod common;

use std::io::{BufRead, BufReader};
use std::path::{Path, PathBuf};
use std::process::{Command, Output, Stdio};
use std::time::{Duration, Instant};

use common::{Csv, datums_on_disk, gazelight, shared_str, tmp, tmp_path, wait_bounded, wait_for};
use gazelight_tracker::PldataWriter;
use gazelight_tracker::recording::{read_npy_f64, stream_paths};

fn text(out: &Output) -> (String, String) {
    (
        String::from_utf8_lossy(&out.stdout).into_owned(),
        String::from_utf8_lossy(&out.stderr).into_owned(),
    )
}

fn s(p: &Path) -> &str {
    p.to_str().expect("utf-8")
}

/// The command ended with a clean error (status 1, no panic) whose
/// message holds every needle.
fn refused(out: &Output, needles: &[&str]) {
    let (stdout, stderr) = text(out);
    assert_eq!(out.status.code(), Some(1), "{stdout}\n{stderr}");
    assert!(!stderr.contains("panicked"), "{stderr}");
    for n in needles {
        assert!(stderr.contains(n), "no `{n}` in: {stderr}");
    }
}

fn ok(out: &Output) {
    let (stdout, stderr) = text(out);
    assert!(out.status.success(), "{stdout}\n{stderr}");
}

/// Every file under `dir` with its bytes, sorted by path.
fn snapshot(dir: &Path) -> Vec<(PathBuf, Vec<u8>)> {
    let mut all = Vec::new();
    let mut stack = vec![dir.to_path_buf()];
    while let Some(d) = stack.pop() {
        for e in std::fs::read_dir(&d).unwrap() {
            let p = e.unwrap().path();
            if p.is_dir() {
                stack.push(p);
            } else {
                let bytes = std::fs::read(&p).unwrap_or_default();
                all.push((p, bytes));
            }
        }
    }
    all.sort();
    all
}

/// A config with the glare off: frames come quickly at any size.
fn fast_config(name: &str) -> PathBuf {
    let p = tmp(name).join("fast.toml");
    std::fs::write(&p, "[pipeline]\nglare = { enabled = false }\n").unwrap();
    p
}

fn render_args<'a>(config: &'a Path, out: &'a Path, frames: &'a str) -> Vec<&'a str> {
    vec![
        "render",
        "--size",
        "64x48",
        "--backend",
        "cpu",
        "--frames",
        frames,
        "--config",
        s(config),
        "--out",
        s(out),
    ]
}

fn with<'a>(mut args: Vec<&'a str>, extra: &[&'a str]) -> Vec<&'a str> {
    args.extend_from_slice(extra);
    args
}

/// The real pupil light-reflex trace (200 Hz, mm), as a replayed source.
fn plr_source() -> String {
    format!("replay://{}", shared_str("eye/piprkit-plr/pupil_trace.csv"))
}

#[test]
fn replaying_a_runs_timeline_into_its_own_directory_is_refused() {
    let dir = tmp_path("own-dir");
    let config = fast_config("own-dir-config");
    // A live run's outputs: the timeline is a pupil CSV `replay` reads.
    ok(&gazelight(&[
        "run",
        "--source",
        "synthetic://demo",
        "--headless",
        "--size",
        "160x120",
        "--secs",
        "1.5",
        "--no-frames",
        "--config",
        s(&config),
        "--out",
        s(&dir),
    ]));
    let timeline = dir.join("timeline.csv");
    let before = snapshot(&dir);
    assert!(Csv::read(&timeline).rows.len() > 10);
    for force in [false, true] {
        let mut args = vec![
            "replay",
            s(&timeline),
            "--size",
            "64x48",
            "--config",
            s(&config),
            "--out",
            s(&dir),
        ];
        if force {
            args.push("--force");
        }
        refused(&gazelight(&args), &["holds the input", "timeline.csv"]);
        assert!(snapshot(&dir) == before, "the run's outputs changed");
    }
    // The same recording into another directory is fine.
    ok(&gazelight(&[
        "replay",
        s(&timeline),
        "--size",
        "64x48",
        "--frames",
        "3",
        "--config",
        s(&config),
        "--out",
        s(&tmp_path("own-dir-elsewhere")),
    ]));
}

/// A Pupil Capture 1.x recording: `info.csv` (Capture 1.x's key,value
/// description) and a `pupil.pldata` of 50 records (their payloads do not
/// matter: the test checks that no byte changes).
fn capture_1x_recording(dir: &Path) {
    std::fs::create_dir_all(dir).unwrap();
    std::fs::write(
        dir.join("info.csv"),
        "key,value\nRecording Name,2019_03_12\nStart Date,12.03.2019\nStart Time (System),1552393519.8\n\
         Start Time (Synced),6025.3\nDuration Time,00:00:02\nCapture Software Version,1.11.4\n\
         Data Format Version,1.11\n",
    )
    .unwrap();
    let mut w = PldataWriter::create(dir, "pupil").unwrap();
    for i in 0..50 {
        let t = 6025.3 + f64::from(i) * 0.005;
        let datum = format!("{{\"timestamp\": {t}, \"diameter\": 40.0}}");
        w.append("pupil.0", datum.as_bytes(), t).unwrap();
    }
    w.close().unwrap();
}

#[test]
fn record_into_a_pupil_capture_1x_recording_is_refused_even_with_force() {
    let dir = tmp_path("capture1x");
    capture_1x_recording(&dir);
    let before = snapshot(&dir);
    let source = plr_source();
    for force in [false, true] {
        let mut args = vec![
            "record",
            "--source",
            source.as_str(),
            "--secs",
            "1",
            "--out",
            s(&dir),
        ];
        if force {
            args.push("--force");
        }
        refused(
            &gazelight(&args),
            &["Pupil Capture 1.x recording", "info.csv"],
        );
        assert!(
            snapshot(&dir) == before,
            "the Capture recording changed (pupil.pldata truncated?)"
        );
    }
    // Nor does any other command write into it.
    let config = fast_config("capture1x-config");
    refused(
        &gazelight(&render_args(&config, &dir, "2")),
        &["Pupil Capture 1.x recording"],
    );
    assert!(snapshot(&dir) == before);
}

#[test]
fn previous_outputs_are_refused_unless_force_which_clears_them() {
    let config = fast_config("previous-config");
    // render (and replay: the same outputs).
    let out = tmp_path("previous-render");
    ok(&gazelight(&render_args(&config, &out, "4")));
    let before = snapshot(&out);
    refused(
        &gazelight(&render_args(&config, &out, "2")),
        &["previous run's outputs", "--force", "timeline.csv"],
    );
    assert!(
        snapshot(&out) == before,
        "a refused render changed its --out"
    );
    // A file of the user's beside the outputs is kept through --force.
    std::fs::write(out.join("notes.txt"), "mine").unwrap();
    ok(&gazelight(&with(
        render_args(&config, &out, "2"),
        &["--force"],
    )));
    let frames = std::fs::read_dir(out.join("frames")).unwrap().count();
    assert_eq!(frames, 2, "--force leaves exactly the new frames");
    assert_eq!(Csv::read(&out.join("timeline.csv")).rows.len(), 2);
    assert_eq!(
        std::fs::read_to_string(out.join("notes.txt")).unwrap(),
        "mine"
    );

    // run into a render's outputs: the contact sheet and plot would stay
    // stale beside the run's files.
    refused(
        &gazelight(&[
            "run",
            "--source",
            "synthetic://demo",
            "--headless",
            "--size",
            "160x120",
            "--secs",
            "1",
            "--out",
            s(&out),
        ]),
        &["previous run's outputs"],
    );

    // record.
    let rec = tmp_path("previous-record");
    let source = plr_source();
    let record = [
        "record",
        "--source",
        source.as_str(),
        "--secs",
        "1.5",
        "--out",
        s(&rec),
    ];
    ok(&gazelight(&record));
    let first = snapshot(&rec);
    refused(&gazelight(&record), &["previous run's outputs", "--force"]);
    assert!(
        snapshot(&rec) == first,
        "a refused record changed its --out"
    );
    ok(&gazelight(&with(record.to_vec(), &["--force"])));

    // psf.
    let psf = tmp_path("previous-psf");
    let args = [
        "psf",
        "--pupil-mm",
        "4",
        "--ppd",
        "8",
        "--field-deg",
        "8",
        "--out",
        s(&psf),
    ];
    ok(&gazelight(&args));
    refused(&gazelight(&args), &["previous run's outputs", "kernel.exr"]);
    ok(&gazelight(&with(args.to_vec(), &["--force"])));

    // calibrate: refused before it looks for a tracker.
    let profile = tmp("previous-calibrate").join("profile.json");
    std::fs::write(&profile, "{}").unwrap();
    refused(
        &gazelight(&[
            "calibrate",
            "--source",
            "pupil://127.0.0.1:9",
            "--stimulus",
            "remote",
            "--out",
            s(&profile),
        ]),
        &["the file exists", "--force"],
    );
    assert_eq!(std::fs::read_to_string(&profile).unwrap(), "{}");
}

#[test]
fn a_sigkilled_render_keeps_its_timeline_and_a_rerun_none_of_its_frames() {
    let config = fast_config("sigkill-render-config");
    let out = tmp_path("sigkill-render");
    let mut child = Command::new(env!("CARGO_BIN_EXE_gazelight"))
        .args(render_args(&config, &out, "100000"))
        .env("RUST_LOG", "warn")
        .stdout(Stdio::null())
        .stderr(Stdio::null())
        .spawn()
        .expect("render");
    // Wait until it has written a few dozen frames, note how many, and
    // SIGKILL it 1.1 s later: timeline.csv is flushed every second, so it
    // must hold a row for every frame on disk a second before the kill (a
    // frame's row is written before its image).
    let t = Instant::now();
    let count = || std::fs::read_dir(out.join("frames")).map_or(0, |d| d.count());
    while count() < 30 {
        assert!(
            t.elapsed() < Duration::from_secs(60),
            "render wrote no frames"
        );
        std::thread::sleep(Duration::from_millis(50));
    }
    let older_than_a_second = count();
    std::thread::sleep(Duration::from_millis(1100));
    child.kill().unwrap();
    child.wait().unwrap();
    let killed = count();
    let rows = Csv::read(&out.join("timeline.csv")).rows;
    eprintln!(
        "SIGKILL: {older_than_a_second} frames 1.1 s before it, {killed} at it, {} timeline rows",
        rows.len()
    );
    assert!(
        rows.len() >= older_than_a_second,
        "{} timeline rows for the {older_than_a_second} frames written more than a second \
         before the SIGKILL",
        rows.len()
    );
    let width = Csv::read(&out.join("timeline.csv")).header.len();
    assert!(
        rows.iter().all(|r| r.len() == width),
        "a torn row in the killed run's timeline"
    );

    // Without --force the killed run's frames are refused, not mixed in.
    refused(
        &gazelight(&render_args(&config, &out, "5")),
        &["previous run's outputs", "frames/frame_"],
    );
    assert_eq!(count(), killed);
    // With --force only the new run's frames remain.
    ok(&gazelight(&with(
        render_args(&config, &out, "5"),
        &["--force"],
    )));
    let mut names: Vec<String> = std::fs::read_dir(out.join("frames"))
        .unwrap()
        .map(|e| e.unwrap().file_name().to_string_lossy().into_owned())
        .collect();
    names.sort();
    let want: Vec<String> = (0..5).map(|i| format!("frame_{i:05}.png")).collect();
    eprintln!("killed render left {killed} frames; the --force re-run left {names:?}");
    assert_eq!(names, want);
    assert_eq!(Csv::read(&out.join("timeline.csv")).rows.len(), 5);
}

#[test]
fn a_sigkilled_record_has_a_complete_info_player_json() {
    let rec = tmp_path("sigkill-record");
    let mut child = Command::new(env!("CARGO_BIN_EXE_gazelight"))
        .args(["record", "--source", &plr_source(), "--out", s(&rec)])
        .env("RUST_LOG", "warn")
        .stdout(Stdio::null())
        .stderr(Stdio::null())
        .spawn()
        .expect("record");
    // Recorded until 201 datums and an info.player.json whose duration
    // passed 0.5 s are on disk (the periodic flush; not a fixed 3 s), then
    // SIGKILL: no handler runs, nothing is finished.
    let info_duration = || {
        let text = std::fs::read_to_string(rec.join("info.player.json")).ok()?;
        serde_json::from_str::<serde_json::Value>(&text).ok()?["duration_s"].as_f64()
    };
    wait_for(
        Duration::from_secs(60),
        "201 datums and a 0.5 s duration on disk",
        || {
            (datums_on_disk(&rec, "pupil") > 200 && info_duration().is_some_and(|d| d > 0.5))
                .then_some(())
        },
    );
    child.kill().unwrap();
    child.wait().unwrap();
    let (_, npy) = stream_paths(&rec, "pupil");
    let ts = read_npy_f64(&npy).expect("the pupil timestamps");
    assert!(ts.len() > 200, "only {} datums", ts.len());
    let info: serde_json::Value =
        serde_json::from_str(&std::fs::read_to_string(rec.join("info.player.json")).unwrap())
            .expect("info.player.json is whole JSON");
    let start = info["start_time_synced_s"].as_f64().unwrap();
    let duration = info["duration_s"].as_f64().unwrap();
    let (first, last) = (ts[0], ts[ts.len() - 1]);
    eprintln!(
        "SIGKILLed record: {} datums over {:.3} s; info.player.json start {start} duration {duration:.3} s",
        ts.len(),
        last - first
    );
    assert!(
        (start - first).abs() < 1e-6,
        "start_time_synced_s {start}, first datum at {first}"
    );
    // Rewritten at least every second while recording.
    assert!(
        duration > 0.5 && duration <= last - first + 1e-6 && last - first - duration < 1.5,
        "duration_s {duration} for data spanning {:.3} s",
        last - first
    );
    // And Pupil's readers accept it.
    ok(&gazelight(&["inspect", s(&rec)]));
}

#[test]
fn a_dangling_pupil_pldata_symlink_is_named() {
    let dir = tmp("dangling");
    std::os::unix::fs::symlink(
        "/nonexistent/recording/pupil.pldata",
        dir.join("pupil.pldata"),
    )
    .unwrap();
    // An empty gaze stream beside it: the recording has no samples at all.
    std::fs::write(dir.join("gaze.pldata"), b"").unwrap();
    for args in [
        vec!["inspect", s(&dir)],
        vec!["replay", s(&dir), "--out", s(&tmp_path("dangling-out"))],
    ] {
        refused(
            &gazelight(&args),
            &["pupil.pldata", "/nonexistent/recording/pupil.pldata"],
        );
    }
    // Without the symlink, the empty stream is named with its size.
    std::fs::remove_file(dir.join("pupil.pldata")).unwrap();
    refused(
        &gazelight(&["inspect", s(&dir)]),
        &["no readable samples", "gaze.pldata (0 bytes)"],
    );
}

/// Whether a private mount namespace with a tmpfs can be made here
/// (`unshare -m`, root); outside CI a missing one skips the test.
fn tmpfs_ready() -> bool {
    let ok = Command::new("unshare")
        .args(["-m", "sh", "-c", "mount -t tmpfs -o size=16k tmpfs /mnt"])
        .output()
        .is_ok_and(|o| o.status.success());
    if !ok {
        gazelight_test_support::skip_or_fail(
            "a tmpfs in a private mount namespace (unshare -m and mount: root)",
        );
    }
    ok
}

/// What a `run --out` onto a full tmpfs left.
struct FullRun {
    out: Output,
    /// Each stderr line with the time it arrived, s after the start.
    lines: Vec<(f64, String)>,
    /// When the process ended, s after the start.
    ended: f64,
    /// A copy of what the run wrote (the tmpfs goes with its namespace).
    copy: PathBuf,
}

/// `run --out` for `secs` onto a tmpfs of `size_kib` in a private mount
/// namespace, with `extra` flags.
fn run_on_full_tmpfs(name: &str, size_kib: u32, secs: f64, extra: &str) -> FullRun {
    let config = fast_config(&format!("{name}-config"));
    let mount = tmp(&format!("{name}-mount"));
    let copy = tmp(&format!("{name}-copy"));
    let script = format!(
        "mount -t tmpfs -o size={size_kib}k tmpfs {m} || exit 99; \
         \"$0\" run --source synthetic://demo --headless --size 160x120 --secs {secs} {extra} \
         --config {c} --out {m}; rc=$?; cp -a {m}/. {o}/; exit $rc",
        m = mount.display(),
        c = config.display(),
        o = copy.display()
    );
    let mut child = Command::new("unshare")
        .args(["-m", "sh", "-c", &script, env!("CARGO_BIN_EXE_gazelight")])
        .env("RUST_LOG", "warn")
        .stdout(Stdio::piped())
        .stderr(Stdio::piped())
        .spawn()
        .expect("unshare");
    let stderr = child.stderr.take().unwrap();
    let started = Instant::now();
    let lines = std::thread::spawn(move || {
        BufReader::new(stderr)
            .lines()
            .map_while(Result::ok)
            .map(|l| (started.elapsed().as_secs_f64(), l))
            .collect::<Vec<_>>()
    });
    let out = wait_bounded(child, Duration::from_secs(60));
    let ended = started.elapsed().as_secs_f64();
    let lines = lines.join().unwrap();
    assert_ne!(out.status.code(), Some(99), "mount failed: {lines:?}");
    FullRun {
        out,
        lines,
        ended,
        copy,
    }
}

impl FullRun {
    fn stdout(&self) -> String {
        String::from_utf8_lossy(&self.out.stdout).into_owned()
    }

    /// The summary is printed, with the error, and the run ends in error;
    /// the ENOSPC error for `what` came when it happened (more than 2 s
    /// before the end), not at the end.
    fn check_reported(&self, what: &str) {
        let stdout = self.stdout();
        let all: String = self.lines.iter().map(|(_, l)| format!("{l}\n")).collect();
        assert!(stdout.contains("run: "), "no summary: {stdout}\n{all}");
        assert!(
            stdout.contains("write error: cannot write") && stdout.contains(what),
            "{stdout}"
        );
        assert_eq!(self.out.status.code(), Some(1), "{stdout}\n{all}");
        let (at, line) = self
            .lines
            .iter()
            .find(|(_, l)| l.contains("No space left on device") && l.contains(what))
            .unwrap_or_else(|| panic!("no ENOSPC error for {what}: {all}"));
        eprintln!("at {at:.2} s of {:.2} s: {line}", self.ended);
        assert!(
            self.ended - at > 2.0,
            "the {what} error came {at:.2} s into a {:.2} s run, not when it happened",
            self.ended
        );
    }

    /// `timeline.csv` holds whole rows only, as many as the summary says;
    /// returns them.
    fn whole_rows(&self) -> usize {
        let path = self.copy.join("timeline.csv");
        let t = std::fs::read_to_string(&path).unwrap();
        assert!(
            t.ends_with('\n'),
            "torn last row: {:?}",
            &t[t.len().saturating_sub(80)..]
        );
        let csv = Csv::read(&path);
        for (i, r) in csv.rows.iter().enumerate() {
            assert_eq!(r.len(), csv.header.len(), "row {i} is torn: {r:?}");
        }
        let stdout = self.stdout();
        assert!(
            stdout.contains(&format!("timeline.csv ({} rows)", csv.rows.len())),
            "{} rows on disk; {stdout}",
            csv.rows.len()
        );
        csv.rows.len()
    }
}

#[test]
fn a_full_disk_during_run_out_keeps_whole_rows_reports_at_once_and_summarises() {
    if !tmpfs_ready() {
        return;
    }
    // Rows only: 32 KiB hold ~2.5 s of the timeline at 90 Hz.
    let run = run_on_full_tmpfs("full-rows", 32, 8.0, "--no-frames");
    run.check_reported("timeline.csv");
    let rows = run.whole_rows();
    assert!(rows > 50, "only {rows} rows before the disk was full");
    eprintln!("full tmpfs, rows only: {rows} whole rows kept");

    // With frames: the images fill the disk first, then the timeline.
    let run = run_on_full_tmpfs("full-frames", 96, 6.0, "");
    run.check_reported("frame_");
    let rows = run.whole_rows();
    let mut images = 0;
    for e in std::fs::read_dir(run.copy.join("frames")).unwrap() {
        let p = e.unwrap().path();
        image::open(&p).unwrap_or_else(|e| panic!("a torn image {}: {e}", p.display()));
        images += 1;
    }
    eprintln!("full tmpfs, with frames: {rows} whole rows, {images} whole frame images");
}
