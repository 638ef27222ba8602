#![allow(clippy::unwrap_used, clippy::expect_used)] // test and bench code may panic on a failed setup
//! Hostile input files through the binary (issue 14, the input half): a
//! tiny EXR claiming a huge image, recordings with an enormous time gap or
//! absurd timestamps among good ones, FIFOs and endless files given as
//! recording, scene or config, empty and header-only recordings, and a
//! pupil trace in the wrong unit. Every case must end within seconds with
//! a clear error or a counted warning, never a panic, a hang or an abort.

mod common;

use std::path::{Path, PathBuf};
use std::process::{Command, Output, Stdio};
use std::time::{Duration, Instant};

use common::{shared, tmp, wait_bounded};

/// Runs the binary with a hard time limit (a hang fails the test instead
/// of blocking it).
fn run_bounded(args: &[&str], limit: Duration) -> (Output, Duration) {
    let start = Instant::now();
    let child = Command::new(env!("CARGO_BIN_EXE_gazelight"))
        .args(args)
        .env("RUST_LOG", "warn")
        .stdin(Stdio::null())
        .stdout(Stdio::piped())
        .stderr(Stdio::piped())
        .spawn()
        .expect("spawn gazelight");
    let out = wait_bounded(child, limit);
    (out, start.elapsed())
}

fn text(out: &Output) -> (String, String) {
    (
        String::from_utf8_lossy(&out.stdout).into_owned(),
        String::from_utf8_lossy(&out.stderr).into_owned(),
    )
}

/// Exit 1 (an error, not a signal or a panic) with every needle in stderr.
fn refused(out: &Output, needles: &[&str]) {
    let (stdout, stderr) = text(out);
    assert_eq!(out.status.code(), Some(1), "{stdout}\n{stderr}");
    assert!(!stderr.contains("panicked"), "{stderr}");
    for n in needles {
        assert!(stderr.contains(n), "`{n}` missing from: {stderr}");
    }
}

fn s(p: &Path) -> &str {
    p.to_str().expect("utf-8 path")
}

/// A hand-built single-part scan-line OpenEXR header (openexr.com, "The
/// OpenEXR File Layout") with R, G, B float channels, ZIP compression and
/// the given data window, followed by `tail` bytes of zeros: a few hundred
/// bytes in all.
fn tiny_exr(x1: i32, y1: i32, tail: usize) -> Vec<u8> {
    fn attr(b: &mut Vec<u8>, name: &str, ty: &str, value: &[u8]) {
        b.extend_from_slice(name.as_bytes());
        b.push(0);
        b.extend_from_slice(ty.as_bytes());
        b.push(0);
        b.extend_from_slice(&(value.len() as i32).to_le_bytes());
        b.extend_from_slice(value);
    }
    let mut b = vec![0x76, 0x2f, 0x31, 0x01, 2, 0, 0, 0];
    let mut ch = Vec::new();
    for c in ["B", "G", "R"] {
        ch.extend_from_slice(c.as_bytes());
        ch.push(0);
        ch.extend_from_slice(&2i32.to_le_bytes()); // FLOAT
        ch.extend_from_slice(&[0, 0, 0, 0]);
        ch.extend_from_slice(&1i32.to_le_bytes());
        ch.extend_from_slice(&1i32.to_le_bytes());
    }
    ch.push(0);
    attr(&mut b, "channels", "chlist", &ch);
    attr(&mut b, "compression", "compression", &[3]); // ZIP
    let window: Vec<u8> = [0i32, 0, x1, y1]
        .iter()
        .flat_map(|v| v.to_le_bytes())
        .collect();
    attr(&mut b, "dataWindow", "box2i", &window);
    attr(&mut b, "displayWindow", "box2i", &window);
    attr(&mut b, "lineOrder", "lineOrder", &[0]);
    attr(&mut b, "pixelAspectRatio", "float", &1f32.to_le_bytes());
    attr(&mut b, "screenWindowCenter", "v2f", &[0; 8]);
    attr(&mut b, "screenWindowWidth", "float", &1f32.to_le_bytes());
    b.push(0);
    b.extend(std::iter::repeat_n(0u8, tail));
    b
}

fn render_scene(scene: &Path, out: &Path) -> (Output, Duration) {
    run_bounded(
        &[
            "render",
            "--scene",
            s(scene),
            "--size",
            "160x120",
            "--frames",
            "1",
            "--no-frames",
            "--out",
            s(out),
        ],
        Duration::from_secs(60),
    )
}

#[test]
fn tiny_exr_with_a_huge_claimed_size_is_refused_quickly() {
    let dir = tmp("tiny-exr");
    for (x1, y1, needle) in [
        (1_999_999, 999_999, "at most"), // 2e12 px: 24 TB as RGB f32
        (i32::MAX, i32::MAX, "at most"), // 4.6e18 px: overflows usize math
        (16_383, 8_191, "at least"),     // in range, but no room in 350 bytes
    ] {
        let p = dir.join(format!("huge-{x1}.exr"));
        let bytes = tiny_exr(x1, y1, 64);
        assert!(bytes.len() < 500, "{} bytes", bytes.len());
        std::fs::write(&p, &bytes).unwrap();
        let (out, took) = render_scene(&p, &dir.join("out"));
        refused(&out, &[s(&p), needle]);
        assert!(took < Duration::from_secs(30), "{took:?}");
    }
}

/// The PLR trace with rows rewritten by `f(row index, line) -> line`.
fn plr_variant(dir: &Path, name: &str, f: impl Fn(usize, &str) -> String) -> PathBuf {
    let text = std::fs::read_to_string(shared("eye/piprkit-plr/pupil_trace.csv")).unwrap();
    let mut lines = text.lines();
    let mut outp = String::from(lines.next().unwrap());
    outp.push('\n');
    for (i, l) in lines.enumerate() {
        outp.push_str(&f(i, l));
        outp.push('\n');
    }
    let p = dir.join(name);
    std::fs::write(&p, outp).unwrap();
    p
}

fn timeline_rows(dir: &Path) -> usize {
    std::fs::read_to_string(dir.join("timeline.csv"))
        .map(|t| t.lines().count().saturating_sub(1))
        .unwrap_or(0)
}

fn replay(rec: &Path, out: &Path, extra: &[&str]) -> (Output, Duration) {
    let mut a = vec![
        "replay",
        s(rec),
        "--size",
        "160x120",
        "--no-frames",
        "--out",
        s(out),
    ];
    a.extend_from_slice(extra);
    run_bounded(&a, Duration::from_secs(240))
}

#[test]
fn absurd_timestamps_among_good_ones_are_skipped_and_counted() {
    let dir = tmp("absurd");
    // 1e308 and byte-flipped times (digits replaced) in 4 of 72 000 rows.
    let bad = [10usize, 20_000, 50_000, 71_000];
    let csv = plr_variant(&dir, "absurd.csv", |i, l| {
        let rest = l.split_once(',').map_or("", |(_, r)| r);
        match bad.iter().position(|&b| b == i) {
            Some(0) | Some(2) => format!("1e308,{rest}"),
            Some(1) => format!("9{}", l), // 9x the magnitude: a flipped digit
            Some(_) => format!("-{}", l), // a flipped sign bit
            None => l.to_string(),
        }
    });
    let out = dir.join("out");
    let (o, _) = replay(&csv, &out, &["--fps", "2"]);
    let (stdout, stderr) = text(&o);
    assert!(o.status.success(), "{stdout}\n{stderr}");
    // 360 s at 2 fps: ~720 frames, not 1.
    let rows = timeline_rows(&out);
    assert!(
        (715..=725).contains(&rows),
        "{rows} frames\n{stdout}\n{stderr}"
    );
    assert!(
        stdout.contains("skipped") && stdout.contains("timestamp"),
        "the skipped records are not reported: {stdout}"
    );

    // EyeLink: absurd sample times among the 500 Hz lines.
    let asc = std::fs::read_to_string(shared("eye/eyelink-psa/both_eyes.asc")).unwrap();
    let mut n = 0;
    let mut edited = String::new();
    for l in asc.lines() {
        if l.as_bytes().first().is_some_and(u8::is_ascii_digit) {
            n += 1;
            if n % 10_000 == 0 {
                edited.push_str("99999999999999");
                edited.push_str(&l[l.find(char::is_whitespace).unwrap_or(0)..]);
                edited.push('\n');
                continue;
            }
        }
        edited.push_str(l);
        edited.push('\n');
    }
    let p = dir.join("absurd.asc");
    std::fs::write(&p, edited).unwrap();
    let out = dir.join("out-asc");
    let (o, _) = replay(&p, &out, &["--fps", "1"]);
    let (stdout, stderr) = text(&o);
    assert!(o.status.success(), "{stdout}\n{stderr}");
    let rows = timeline_rows(&out);
    // The file spans ~4 trials over a few hundred seconds.
    assert!((100..2000).contains(&rows), "{rows} frames\n{stderr}");
    assert!(stdout.contains("skipped"), "{stdout}");
}

#[test]
fn byte_flipped_neon_time_file_replays_its_own_nine_seconds() {
    let dir = tmp("neon-flip");
    let rec = dir.join("neon");
    std::fs::create_dir_all(&rec).unwrap();
    for e in std::fs::read_dir(shared("eye/neon-demo")).unwrap() {
        let e = e.unwrap();
        std::fs::copy(e.path(), rec.join(e.file_name())).unwrap();
    }
    let tp = rec.join("eye_state ps1.time");
    let mut t = std::fs::read(&tp).unwrap();
    t[100 * 8 + 7] ^= 0x01; // record 100: +2^56 ns (2.3 years)
    t[900 * 8 + 5] ^= 0x10; // record 900: ±2^44 ns (4.9 hours)
    std::fs::write(&tp, t).unwrap();
    let out = dir.join("out");
    let (o, took) = replay(&rec, &out, &["--fps", "10"]);
    let (stdout, stderr) = text(&o);
    assert!(o.status.success(), "{stdout}\n{stderr}");
    let rows = timeline_rows(&out);
    assert!(
        (85..=100).contains(&rows),
        "{rows} frames for ~9 s at 10 fps"
    );
    // One skipped record per flipped timestamp (each eye_state record
    // holds both eyes' pupils), named with the file.
    assert!(
        stdout.contains("skipped 2") && stdout.contains("eye_state ps1.time"),
        "{stdout}"
    );
    assert!(took < Duration::from_secs(120));
}

#[test]
fn a_one_year_gap_is_refused_with_the_gap_named() {
    let dir = tmp("gap");
    let csv = plr_variant(&dir, "gap.csv", |i, l| {
        if i < 36_000 {
            return l.to_string();
        }
        let (t, rest) = l.split_once(',').unwrap();
        let t: f64 = t.parse().unwrap();
        format!("{},{rest}", t + 365.0 * 86_400.0)
    });
    let (o, took) = replay(&csv, &dir.join("out"), &[]);
    refused(&o, &["gap.csv", "365.0 days", "--from-secs"]);
    assert!(took < Duration::from_secs(30), "{took:?}");
    // A part of it still replays.
    let (o, _) = replay(&csv, &dir.join("out2"), &["--secs", "2", "--fps", "5"]);
    assert!(o.status.success(), "{}", text(&o).1);
    assert_eq!(timeline_rows(&dir.join("out2")), 11);
}

fn mkfifo(p: &Path) {
    let ok = Command::new("mkfifo")
        .arg(p)
        .status()
        .map(|s| s.success())
        .unwrap_or(false);
    assert!(ok, "mkfifo {}", p.display());
}

#[test]
fn fifos_and_dev_zero_as_inputs_return_within_seconds() {
    let dir = tmp("fifo");
    let out = dir.join("out");
    let limit = Duration::from_secs(20);
    for (name, kind) in [("fifo", "FIFO"), ("zero", "character device")] {
        let csv = dir.join(format!("{name}.csv"));
        let exr = dir.join(format!("{name}.exr"));
        let toml = dir.join(format!("{name}.toml"));
        let asc = dir.join(format!("{name}.asc"));
        for p in [&csv, &exr, &toml, &asc] {
            if name == "fifo" {
                mkfifo(p);
            } else {
                std::os::unix::fs::symlink("/dev/zero", p).unwrap();
            }
        }
        let cases: Vec<Vec<&str>> = vec![
            vec!["replay", s(&csv), "--out", s(&out)],
            vec!["inspect", s(&csv)],
            vec!["inspect", s(&asc)],
            vec!["render", "--scene", s(&exr), "--out", s(&out)],
            vec!["render", "--config", s(&toml), "--out", s(&out)],
            vec!["render", "--trace", s(&csv), "--out", s(&out)],
        ];
        for args in cases {
            let (o, took) = run_bounded(&args, limit);
            refused(&o, &[kind]);
            assert!(took < Duration::from_secs(10), "{args:?}: {took:?}");
        }
    }
}

#[test]
fn a_long_single_line_csv_is_refused_without_holding_it() {
    let dir = tmp("long-line");
    let p = dir.join("one-line.csv");
    // 20 MB of digits and commas, no newline.
    let chunk = "1.0,".repeat(1 << 18);
    let mut text = String::with_capacity(chunk.len() * 20);
    for _ in 0..20 {
        text.push_str(&chunk);
    }
    std::fs::write(&p, &text).unwrap();
    let (o, took) = run_bounded(&["inspect", s(&p)], Duration::from_secs(60));
    refused(&o, &["one-line.csv", "line 1", "bytes long"]);
    assert!(took < Duration::from_secs(30));
}

#[test]
fn empty_and_header_only_recordings_are_errors_naming_the_cause() {
    let dir = tmp("empty");
    let empty_asc = dir.join("empty.asc");
    std::fs::write(&empty_asc, "").unwrap();
    let header_asc = dir.join("header.asc");
    std::fs::write(
        &header_asc,
        "** CONVERTED FROM D:\\x.edf using edfapi 4.2\n** DATE: Wed Mar  1 10:00:00 2023\n\
         MSG\t1000 DISPLAY_COORDS 0 0 1279 1023\n",
    )
    .unwrap();
    let header_csv = dir.join("header.csv");
    std::fs::write(&header_csv, "time,left,right\n").unwrap();
    let utf16 = dir.join("utf16.csv");
    let mut b = vec![0xff, 0xfe];
    for u in "time,left,right\n0.1,6.0,6.0\n".encode_utf16() {
        b.extend_from_slice(&u.to_le_bytes());
    }
    std::fs::write(&utf16, b).unwrap();
    // (A tab-separated file is a recording now: the CSV importer reads
    // comma, tab and semicolon separators, docs/replay.md.)
    let lim = Duration::from_secs(30);
    for (p, needle) in [
        (&empty_asc, "empty (0 bytes)"),
        (&header_asc, "no sample records"),
        (&header_csv, "no sample records"),
        (&utf16, "UTF-16"),
    ] {
        let (o, _) = run_bounded(&["inspect", s(p)], lim);
        refused(&o, &[s(p), needle]);
        let (o, _) = replay(p, &dir.join("out"), &[]);
        refused(&o, &[s(p), "no readable samples", needle]);
    }
}

#[test]
fn a_pupil_trace_in_the_wrong_unit_is_warned_about_loudly() {
    let dir = tmp("units");
    // The PLR trace in tenths of a millimetre (35–65 instead of 3.5–6.5).
    let csv = plr_variant(&dir, "tenths.csv", |i, l| {
        if i >= 4000 {
            return String::new();
        }
        let f: Vec<&str> = l.split(',').collect();
        let x = |v: &str| {
            v.parse::<f64>()
                .map_or(String::new(), |v| format!("{}", v * 10.0))
        };
        format!("{},{},{}", f[0], x(f[1]), x(f[2]))
    });
    let (o, _) = run_bounded(&["inspect", s(&csv)], Duration::from_secs(60));
    let (stdout, stderr) = text(&o);
    assert!(o.status.success(), "{stdout}\n{stderr}");
    assert!(
        stderr.contains("warning")
            && stderr.contains("not in millimetres")
            && stderr.contains("--calibration"),
        "{stderr}"
    );
    let (o, _) = replay(&csv, &dir.join("out"), &["--fps", "5"]);
    let (stdout, stderr) = text(&o);
    assert!(o.status.success(), "{stdout}\n{stderr}");
    assert!(stderr.contains("not in millimetres"), "{stderr}");
    // The real trace in mm gives no such warning.
    let (o, _) = run_bounded(
        &["inspect", s(&shared("eye/piprkit-plr/pupil_trace.csv"))],
        Duration::from_secs(60),
    );
    assert!(!text(&o).1.contains("not in millimetres"));
}
