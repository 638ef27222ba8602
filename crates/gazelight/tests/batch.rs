#![allow(clippy::unwrap_used, clippy::expect_used)] // test and bench code may panic on a failed setup
//! `gazelight batch` end to end on the shipped recordings: each row's
//! outputs are a single `replay`'s, the summary holds one line per row
//! (a failing row reported, the others run), a Slurm-style slice run
//! collects to the same summary, and a batch killed midway resumes
//! without redoing its finished rows.

mod common;

use std::collections::HashMap;
use std::path::{Path, PathBuf};
use std::process::{Command, Stdio};
use std::time::{Duration, Instant, SystemTime};

/// The tests of this file run one at a time (each starts batches of
/// replays; together they overload a 2-core machine).
static SERIAL: std::sync::Mutex<()> = std::sync::Mutex::new(());

fn serial() -> std::sync::MutexGuard<'static, ()> {
    SERIAL.lock().unwrap_or_else(|e| e.into_inner())
}

use common::{gazelight, shared_str, tmp};

/// timeline.csv without its wall-clock timing columns (they differ
/// between any two runs of the same replay).
fn model_timeline(path: &Path) -> String {
    let text = std::fs::read_to_string(path).unwrap();
    let mut lines = text.lines();
    let header: Vec<&str> = lines.next().unwrap().split(',').collect();
    let timing = |h: &str| {
        [
            "pooling_ms",
            "temporal_ms",
            "psf_ms",
            "glare_ms",
            "acuity_ms",
            "tone_colour_encode_ms",
            "total_ms",
        ]
        .iter()
        .any(|t| h.starts_with(t))
    };
    let keep: Vec<bool> = header.iter().map(|h| !timing(h)).collect();
    assert!(keep.iter().filter(|k| !**k).count() >= 7, "{header:?}");
    std::iter::once(header.join(","))
        .chain(lines.map(|l| {
            l.split(',')
                .zip(&keep)
                .filter(|(_, k)| **k)
                .map(|(c, _)| c)
                .collect::<Vec<_>>()
                .join(",")
        }))
        .collect::<Vec<_>>()
        .join("\n")
}

/// Every file under `dir`, relative, sorted.
fn files(dir: &Path) -> Vec<PathBuf> {
    let mut out = Vec::new();
    let mut stack = vec![dir.to_path_buf()];
    while let Some(d) = stack.pop() {
        for e in std::fs::read_dir(&d).unwrap() {
            let p = e.unwrap().path();
            if p.is_dir() {
                stack.push(p);
            } else {
                out.push(p.strip_prefix(dir).unwrap().to_path_buf());
            }
        }
    }
    out.sort();
    out
}

/// `a` and `b` hold the same files with the same bytes (timeline.csv:
/// the same model columns).
fn assert_same_outputs(a: &Path, b: &Path) {
    let fa = files(a);
    assert_eq!(fa, files(b), "{} vs {}", a.display(), b.display());
    assert!(fa.iter().any(|f| f.ends_with("timeline.csv")), "{fa:?}");
    for f in &fa {
        if f.ends_with("timeline.csv") {
            assert_eq!(
                model_timeline(&a.join(f)),
                model_timeline(&b.join(f)),
                "{f:?}"
            );
        } else {
            assert!(
                std::fs::read(a.join(f)).unwrap() == std::fs::read(b.join(f)).unwrap(),
                "{} differs from a single replay's",
                f.display()
            );
        }
    }
}

/// The summary as (header, rows of cells); no cell holds a comma here.
fn summary(out: &Path) -> (Vec<String>, Vec<Vec<String>>) {
    let text = std::fs::read_to_string(out.join("summary.csv")).unwrap();
    let mut lines = text.lines();
    let header = lines.next().unwrap().split(',').map(String::from).collect();
    let rows = lines
        .map(|l| l.split(',').map(String::from).collect())
        .collect();
    (header, rows)
}

fn cell<'a>(header: &[String], row: &'a [String], name: &str) -> &'a str {
    let i = header
        .iter()
        .position(|h| h == name)
        .unwrap_or_else(|| panic!("no {name}"));
    &row[i]
}

/// Rows: (id, recording, replay options).
fn rows() -> Vec<(&'static str, String, Vec<&'static str>)> {
    vec![
        (
            "neon",
            shared_str("eye/neon-demo"),
            vec!["--secs=2", "--size=64x48", "--fps=20", "--backend=cpu"],
        ),
        (
            "eyelink",
            shared_str("eye/eyelink-psa/both_eyes.asc"),
            vec![
                "--from-secs=2",
                "--secs=2",
                "--size=64x48",
                "--fps=20",
                "--backend=cpu",
                "--stereo",
            ],
        ),
        (
            "piprkit",
            shared_str("eye/piprkit-plr/pupil_trace.csv"),
            vec![
                "--secs=20",
                "--from-secs=10",
                "--size=48x32",
                "--fps=4",
                "--backend=cpu",
                "--no-frames",
            ],
        ),
    ]
}

#[test]
fn batch_rows_are_single_replays_and_the_summary_collects() {
    let _serial = serial();
    let dir = tmp("outputs");
    let manifest = dir.join("study.csv");
    // The same rows as CSV, plus a recording that does not exist.
    let mut csv = String::from("id,recording,secs,from_secs,size,fps,backend,stereo,no_frames\n");
    csv.push_str(&format!(
        "neon,{},2,,64x48,20,cpu,,\n",
        shared_str("eye/neon-demo")
    ));
    csv.push_str(&format!(
        "eyelink,{},2,2,64x48,20,cpu,true,no\n",
        shared_str("eye/eyelink-psa/both_eyes.asc")
    ));
    csv.push_str("missing,nowhere/rec.asc,1,,64x48,20,cpu,,\n");
    csv.push_str(&format!(
        "piprkit,{},20,10,48x32,4,cpu,false,yes\n",
        shared_str("eye/piprkit-plr/pupil_trace.csv")
    ));
    std::fs::write(&manifest, csv).unwrap();
    let out = dir.join("out");
    let o = out.to_str().unwrap();
    let run = gazelight(&[
        "batch",
        manifest.to_str().unwrap(),
        "--out",
        o,
        "--jobs",
        "2",
    ]);
    let stderr = String::from_utf8_lossy(&run.stderr);
    // The missing recording fails the batch, after the others ran.
    assert_eq!(run.status.code(), Some(1), "{stderr}");
    assert!(stderr.contains("1 of 4 recordings failed"), "{stderr}");
    assert!(
        stderr.contains("batch: 4/4 recordings done (0 skipped, 1 failed)"),
        "{stderr}"
    );
    assert!(stderr.contains("frames/s · ETA"), "{stderr}");

    // Each row's outputs are a single replay's with the same options.
    let mut warned = Vec::new();
    for (id, rec, opts) in rows() {
        let single = dir.join(format!("single-{id}"));
        let mut argv = vec!["replay", rec.as_str()];
        argv.extend(opts.iter().copied());
        let out_flag = format!("--out={}", single.display());
        argv.push(&out_flag);
        let r = gazelight(&argv);
        let err = String::from_utf8_lossy(&r.stderr);
        assert!(r.status.success(), "{err}");
        assert_same_outputs(&out.join(id), &single);
        warned.push((
            id,
            err.lines().filter(|l| l.starts_with("warning:")).count(),
        ));
    }

    // The summary: one line per row in manifest order.
    let (header, lines) = summary(&out);
    // Its warnings are the ones the row's replay gave: the EyeLink file
    // without a profile warns of its raw pupil unit, the Neon one of
    // nothing; the same count as the single replay's `warning:` lines.
    assert_eq!(cell(&header, &lines[0], "warnings"), "0");
    let eyelink: usize = cell(&header, &lines[1], "warnings").parse().unwrap();
    assert!(eyelink >= 1, "{:?}", lines[1]);
    for (i, id) in [(0, "neon"), (1, "eyelink"), (3, "piprkit")] {
        let single = warned.iter().find(|w| w.0 == id).unwrap().1;
        assert_eq!(
            cell(&header, &lines[i], "warnings"),
            single.to_string(),
            "{id}"
        );
    }
    assert_eq!(&header[..4], ["id", "recording", "status", "message"]);
    let ids: Vec<&str> = lines.iter().map(|r| r[0].as_str()).collect();
    assert_eq!(ids, ["neon", "eyelink", "missing", "piprkit"]);
    let status: Vec<&str> = lines.iter().map(|r| cell(&header, r, "status")).collect();
    assert_eq!(status, ["ok", "ok", "failed", "ok"]);
    assert!(
        cell(&header, &lines[2], "message").contains("nowhere/rec.asc"),
        "{:?}",
        lines[2]
    );
    assert!(out.join("_batch/missing.log").is_file());
    // 2 s at 20 fps: frames at 0, 0.05, …, 2.0 s.
    assert_eq!(cell(&header, &lines[0], "frames"), "41");
    assert_eq!(cell(&header, &lines[0], "duration_secs"), "2.0000");
    assert_eq!(cell(&header, &lines[1], "views"), "2");
    // The pupil figures are the timeline's: measured frames (held = 0).
    let text = std::fs::read_to_string(out.join("neon/timeline.csv")).unwrap();
    let head: Vec<&str> = text.lines().next().unwrap().split(',').collect();
    let col = |name: &str| head.iter().position(|c| *c == name).unwrap();
    let (pupil, held) = (col("pupil_mm"), col("pupil_held"));
    let measured: Vec<f64> = text
        .lines()
        .skip(1)
        .filter(|l| l.split(',').nth(held) == Some("0"))
        .map(|l| l.split(',').nth(pupil).unwrap().parse().unwrap())
        .collect();
    assert!(!measured.is_empty());
    let mean = measured.iter().sum::<f64>() / measured.len() as f64;
    assert_eq!(
        cell(&header, &lines[0], "pupil_measured_frames"),
        measured.len().to_string()
    );
    let got: f64 = cell(&header, &lines[0], "pupil_mean_mm").parse().unwrap();
    assert!((got - mean).abs() < 1e-4, "{got} vs {mean}");
    // piprkit's pupil rate over the replayed window, from the CSV itself:
    // samples 5 ms apart with no pauses, so (n − 1) / (t_last − t_first).
    let text = std::fs::read_to_string(shared_str("eye/piprkit-plr/pupil_trace.csv")).unwrap();
    let times: Vec<f64> = text
        .lines()
        .skip(1)
        .map(|l| l.split(',').next().unwrap().parse().unwrap())
        .collect();
    let t0 = times.iter().cloned().fold(f64::MAX, f64::min) + 10.0;
    let t1 = t0
        + cell(&header, &lines[3], "duration_secs")
            .parse::<f64>()
            .unwrap();
    let window: Vec<f64> = times.into_iter().filter(|t| *t >= t0 && *t <= t1).collect();
    let rate = (window.len() - 1) as f64 / (window[window.len() - 1] - window[0]);
    assert!((190.0..210.0).contains(&rate), "{rate}");
    for col in ["pupil_rate_right_hz", "pupil_rate_left_hz"] {
        assert_eq!(cell(&header, &lines[3], col), format!("{rate:.3}"), "{col}");
    }
    assert_eq!(cell(&header, &lines[3], "frames"), "81");
    // The light-driven pupil and residual are there for a replay.
    assert!(!cell(&header, &lines[0], "pupil_light_mean_mm").is_empty());

    // A Slurm array's slices, then --collect: the same summary.
    let sliced = dir.join("sliced");
    let s = sliced.to_str().unwrap();
    for k in ["0", "1"] {
        let r = gazelight(&[
            "batch",
            manifest.to_str().unwrap(),
            "--out",
            s,
            "--task",
            k,
            "--tasks",
            "2",
        ]);
        let code = r.status.code();
        // Task 0 has rows 0 and 2 (the missing recording): status 1.
        assert_eq!(
            code,
            Some(if k == "0" { 1 } else { 0 }),
            "{}",
            String::from_utf8_lossy(&r.stderr)
        );
        assert!(
            !sliced.join("summary.csv").exists(),
            "a task writes no summary"
        );
    }
    let c = gazelight(&["batch", manifest.to_str().unwrap(), "--out", s, "--collect"]);
    assert_eq!(c.status.code(), Some(1));
    assert!(String::from_utf8_lossy(&c.stderr).contains("failed [missing]"));
    assert_eq!(
        std::fs::read_to_string(sliced.join("summary.csv")).unwrap(),
        std::fs::read_to_string(out.join("summary.csv")).unwrap()
    );

    // A bad row stops the batch before anything runs, naming the place.
    let bad = dir.join("bad.csv");
    std::fs::write(&bad, "recording,fps\nx.asc,20\ny.asc,fast\n").unwrap();
    let r = gazelight(&[
        "batch",
        bad.to_str().unwrap(),
        "--out",
        dir.join("bad-out").to_str().unwrap(),
    ]);
    let e = String::from_utf8_lossy(&r.stderr);
    assert_eq!(r.status.code(), Some(1));
    assert!(
        e.contains("bad.csv: line 3: field fps: invalid value 'fast'"),
        "{e}"
    );
    assert!(!dir.join("bad-out/_batch/001-x.log").exists());
    let _ = std::fs::remove_dir_all(&dir);
}

fn mtime(p: &Path) -> SystemTime {
    std::fs::metadata(p).unwrap().modified().unwrap()
}

/// Starts the batch on `manifest`, waits until `ready` exists (a frame of
/// the row to interrupt), then sends `signal`; returns the batch's exit
/// status and stderr.
/// Whether a `gazelight replay` process writing into `dir` (its `--out`,
/// given as `--out=DIR` or `--out DIR`)
/// is still running (read from /proc; Linux only).
fn replay_running_into(dir: &Path) -> bool {
    let want = dir.to_string_lossy().into_owned();
    let want_flag = format!("--out={want}");
    let Ok(procs) = std::fs::read_dir("/proc") else {
        return false;
    };
    procs.flatten().any(|p| {
        let Ok(cmd) = std::fs::read(p.path().join("cmdline")) else {
            return false;
        };
        let args: Vec<&[u8]> = cmd.split(|&b| b == 0).collect();
        args.iter().any(|a| *a == b"replay")
            && args
                .iter()
                .any(|a| std::str::from_utf8(a).is_ok_and(|s| s == want || s == want_flag))
    })
}

fn interrupt_after(
    manifest: &Path,
    out: &Path,
    ready: &Path,
    signal: i32,
) -> (Option<i32>, String) {
    let err = out.with_extension(format!("err{signal}"));
    let child = Command::new(env!("CARGO_BIN_EXE_gazelight"))
        .args([
            "batch",
            manifest.to_str().unwrap(),
            "--out",
            out.to_str().unwrap(),
        ])
        .env("RUST_LOG", "warn")
        .stdout(Stdio::null())
        .stderr(std::fs::File::create(&err).unwrap())
        .spawn()
        .unwrap();
    let mut child = common::Proc(child);
    let t = Instant::now();
    while !ready.exists() {
        assert!(
            t.elapsed() < Duration::from_secs(300),
            "{} never came",
            ready.display()
        );
        assert!(
            child.0.try_wait().unwrap().is_none(),
            "the batch ended early"
        );
        std::thread::sleep(Duration::from_millis(20));
    }
    // SAFETY: a signal to our own child.
    unsafe { libc::kill(child.0.id() as i32, signal) };
    let t = Instant::now();
    let status = loop {
        if let Some(s) = child.0.try_wait().unwrap() {
            break s;
        }
        assert!(
            t.elapsed() < Duration::from_secs(30),
            "the batch did not stop"
        );
        std::thread::sleep(Duration::from_millis(20));
    };
    (status.code(), std::fs::read_to_string(&err).unwrap())
}

#[test]
fn a_killed_batch_resumes_without_redoing_finished_rows() {
    let _serial = serial();
    let dir = tmp("resume");
    let manifest = dir.join("study.toml");
    // Four rows of a few seconds each, run one at a time.
    let neon = shared_str("eye/neon-demo");
    let eyelink = shared_str("eye/eyelink-psa/both_eyes.asc");
    std::fs::write(
        &manifest,
        format!(
            "[defaults]\nsize = \"96x80\"\nfps = 20\nbackend = \"cpu\"\n\n\
             [[row]]\nid = \"a\"\nrecording = \"{neon}\"\nsecs = 2\n\n\
             [[row]]\nid = \"b\"\nrecording = \"{eyelink}\"\nsecs = 6\n\n\
             [[row]]\nid = \"c\"\nrecording = \"{neon}\"\nfrom_secs = 3\nsecs = 6\n\n\
             [[row]]\nid = \"d\"\nrecording = \"{eyelink}\"\nfrom_secs = 5\nsecs = 1\n"
        ),
    )
    .unwrap();
    let out = dir.join("out");
    let rec = |id: &str| out.join(format!("_batch/{id}.json"));

    let frame = |id: &str| out.join(format!("{id}/frames/frame_00005.png"));
    // SIGKILL while row b renders (a is finished): b is half-written.
    let (code, _) = interrupt_after(&manifest, &out, &frame("b"), 9);
    assert!(rec("a").exists());
    assert_eq!(code, None, "killed by the signal");
    assert!(
        !rec("b").exists(),
        "row b finished before the kill: make it longer"
    );
    let a_timeline = mtime(&out.join("a/timeline.csv"));
    let a_record = mtime(&rec("a"));
    // The replay of b got SIGTERM from the batch's death: wait until it
    // has written what it rendered (session.json is its last file), so
    // nothing else writes into b.
    let t = Instant::now();
    let b_dir = out.join("b");
    while !out.join("b/session.json").exists() && replay_running_into(&b_dir) {
        // Bounded; generous for a loaded 2-core machine.
        assert!(
            t.elapsed() < Duration::from_secs(120),
            "b's replay never stopped; its log:\n{}",
            std::fs::read_to_string(out.join("_batch/b.log")).unwrap_or_default()
        );
        std::thread::sleep(Duration::from_millis(50));
    }
    std::thread::sleep(Duration::from_millis(500));
    // b's replay may have ended without its outputs (seen under load: the
    // cause is not established, see the issue 36 note); when it wrote a
    // timeline, it is a cut-short one.
    match std::fs::read_to_string(out.join("b/timeline.csv")) {
        Ok(b_partial) => assert!(b_partial.lines().count() < 122, "b was cut short"),
        // Printed so that a CI log shows how the replay ended.
        Err(e) => eprintln!(
            "NOTE: b's replay wrote no timeline ({e}); its log:\n{}",
            std::fs::read_to_string(out.join("_batch/b.log")).unwrap_or_default()
        ),
    }

    // SIGTERM while row c renders: a is skipped, b redone, c interrupted.
    let (code, stderr) = interrupt_after(&manifest, &out, &frame("c"), 15);
    assert_eq!(code, Some(1), "{stderr}");
    assert!(
        stderr.contains("batch: skip a: finished earlier"),
        "{stderr}"
    );
    assert!(stderr.contains("SIGTERM: stopped"), "{stderr}");
    assert!(stderr.contains("batch: interrupted c"), "{stderr}");
    assert!(!rec("c").exists());
    let (header, lines) = summary(&out);
    let status: Vec<&str> = lines.iter().map(|r| cell(&header, r, "status")).collect();
    assert_eq!(status, ["ok", "ok", "pending", "pending"]);
    let b_record = mtime(&rec("b"));

    // Run to the end: a and b are not redone.
    let r = gazelight(&[
        "batch",
        manifest.to_str().unwrap(),
        "--out",
        out.to_str().unwrap(),
    ]);
    let stderr = String::from_utf8_lossy(&r.stderr);
    assert!(r.status.success(), "{stderr}");
    assert!(
        stderr.contains("batch: skip a: finished earlier"),
        "{stderr}"
    );
    assert!(
        stderr.contains("batch: skip b: finished earlier"),
        "{stderr}"
    );
    assert!(stderr.contains("batch: done c"), "{stderr}");
    assert!(
        stderr.contains("batch: 4/4 recordings done (2 skipped, 0 failed)"),
        "{stderr}"
    );
    assert_eq!(mtime(&out.join("a/timeline.csv")), a_timeline);
    assert_eq!(mtime(&rec("a")), a_record);
    assert_eq!(mtime(&rec("b")), b_record);
    let (header, lines) = summary(&out);
    assert!(
        lines.iter().all(|r| cell(&header, r, "status") == "ok"),
        "{lines:?}"
    );
    // b, redone after the kill, is whole: 6 s at 20 fps.
    assert_eq!(cell(&header, &lines[1], "frames"), "121");
    // Row c's outputs (interrupted once, then redone) are a single
    // replay's.
    let single = dir.join("single-c");
    let r = gazelight(&[
        "replay",
        &neon,
        "--size=96x80",
        "--fps=20",
        "--backend=cpu",
        "--from-secs=3",
        "--secs=6",
        &format!("--out={}", single.display()),
    ]);
    assert!(r.status.success(), "{}", String::from_utf8_lossy(&r.stderr));
    assert_same_outputs(&out.join("c"), &single);
    let _ = std::fs::remove_dir_all(&dir);
}

/// The replay options both BIDS tests give every recording.
const BIDS_OPTS: [&str; 6] = [
    "--secs=1",
    "--from-secs=2",
    "--size=48x32",
    "--fps=10",
    "--backend=cpu",
    "--no-frames",
];

#[test]
fn a_bids_dataset_root_batches_one_row_per_recording() {
    let _serial = serial();
    let dir = tmp("bids-root");
    // A BIDS dataset of two shipped recordings, written by `export`.
    let ds = dir.join("ds");
    let d = ds.to_str().unwrap();
    for (rec, sub, ses) in [
        ("eye/eyelink-psa/both_eyes.asc", "01", "a"),
        ("eye/piprkit-plr/pupil_trace.csv", "02", "b"),
    ] {
        let r = gazelight(&[
            "export",
            "--bids",
            d,
            &shared_str(rec),
            "--subject",
            sub,
            "--session",
            ses,
            "--task",
            "plr",
            "--run",
            "1",
        ]);
        assert!(r.status.success(), "{}", String::from_utf8_lossy(&r.stderr));
    }
    let defaults = dir.join("defaults.toml");
    std::fs::write(
        &defaults,
        "[defaults]\nsecs = 1\nfrom_secs = 2\nsize = \"48x32\"\nfps = 10\n\
         backend = \"cpu\"\nno_frames = true\n",
    )
    .unwrap();
    let out = dir.join("out");
    let r = gazelight(&[
        "batch",
        d,
        "--defaults",
        defaults.to_str().unwrap(),
        "--out",
        out.to_str().unwrap(),
    ]);
    assert!(r.status.success(), "{}", String::from_utf8_lossy(&r.stderr));
    let (header, lines) = summary(&out);
    let ids: Vec<&str> = lines.iter().map(|r| r[0].as_str()).collect();
    assert_eq!(
        ids,
        ["sub-01_ses-a_task-plr_run-1", "sub-02_ses-b_task-plr_run-1"]
    );
    let ds = ds.canonicalize().unwrap();
    for (line, (id, sub, ses)) in lines.iter().zip([(ids[0], "01", "a"), (ids[1], "02", "b")]) {
        assert_eq!(cell(&header, line, "status"), "ok", "{line:?}");
        // The row replays the recording's eye1 file (its eyes together),
        // as a single replay of that file does.
        let rec = ds.join(format!(
            "sub-{sub}/ses-{ses}/beh/{id}_recording-eye1_physio.tsv.gz"
        ));
        assert_eq!(cell(&header, line, "recording"), rec.to_str().unwrap());
        let single = dir.join(format!("single-{id}"));
        let out_flag = format!("--out={}", single.display());
        let mut argv = vec!["replay", rec.to_str().unwrap()];
        argv.extend(BIDS_OPTS);
        argv.push(&out_flag);
        let s = gazelight(&argv);
        assert!(s.status.success(), "{}", String::from_utf8_lossy(&s.stderr));
        assert_same_outputs(&out.join(id), &single);
    }
    // The EyeLink recording has both eyes: the row read them together.
    assert_ne!(cell(&header, &lines[0], "pupil_rate_left_hz"), "");
    assert_eq!(
        cell(&header, &lines[0], "pupil_rate_left_hz"),
        cell(&header, &lines[0], "pupil_rate_right_hz")
    );
    // A directory that is no dataset is refused, naming it.
    let r = gazelight(&[
        "batch",
        dir.to_str().unwrap(),
        "--out",
        out.to_str().unwrap(),
    ]);
    let e = String::from_utf8_lossy(&r.stderr);
    assert_eq!(r.status.code(), Some(1));
    assert!(e.contains("without dataset_description.json"), "{e}");
    let _ = std::fs::remove_dir_all(&dir);
}

#[test]
fn batch_bids_writes_a_dataset_that_validates() {
    let _serial = serial();
    let dir = tmp("bids-export");
    // Entities as columns (empty: the defaults), options as in BIDS_OPTS.
    let with_opts = dir.join("study.csv");
    let mut text = String::from(
        "id,recording,subject,session,task,run,secs,from_secs,size,fps,backend,no_frames\n",
    );
    text.push_str(&format!(
        "eye-link,{},,,,,1,2,48x32,10,cpu,true\n",
        shared_str("eye/eyelink-psa/both_eyes.asc")
    ));
    text.push_str(&format!(
        "plr,{},p7,s2,light,3,1,2,48x32,10,cpu,true\n",
        shared_str("eye/piprkit-plr/pupil_trace.csv")
    ));
    std::fs::write(&with_opts, text).unwrap();
    let ds = dir.join("ds");
    let out = dir.join("out");
    let batch = |extra: &[&str]| {
        let mut argv = vec![
            "batch",
            with_opts.to_str().unwrap(),
            "--out",
            out.to_str().unwrap(),
            "--bids",
            ds.to_str().unwrap(),
        ];
        argv.extend(extra);
        gazelight(&argv)
    };
    let r = batch(&["--jobs", "2"]);
    assert!(r.status.success(), "{}", String::from_utf8_lossy(&r.stderr));
    // The rows' entities: the id's alphanumerics by default, else columns.
    let a = ds.join("sub-eyelink/beh/sub-eyelink_task-replay_recording-eye1_physio.tsv.gz");
    let b =
        ds.join("sub-p7/ses-s2/beh/sub-p7_ses-s2_task-light_run-3_recording-eye1_physio.tsv.gz");
    assert!(a.is_file() && b.is_file(), "{:?}", files(&ds));
    // The derivative holds the replay's timeline values.
    let der = ds.join("derivatives/gazelight/sub-p7/ses-s2/beh");
    assert!(
        files(&der)
            .iter()
            .any(|f| f.to_str().unwrap().contains("replay_physio.tsv.gz")),
        "{:?}",
        files(&der)
    );
    gazelight_test_support::bids::validate(&ds);
    // Resumed: nothing runs again, the export included.
    let r = batch(&[]);
    let e = String::from_utf8_lossy(&r.stderr);
    assert!(r.status.success(), "{e}");
    assert!(e.contains("batch: skip eye-link: finished earlier"), "{e}");
    assert!(e.contains("batch: skip plr: finished earlier"), "{e}");
    let _ = std::fs::remove_dir_all(&dir);
}

/// The ETA each progress line prints, in seconds (`ETA h:mm:ss`).
fn eta_of(line: &str) -> Option<f64> {
    let hms = line.split("ETA ").nth(1)?.trim();
    let mut parts = hms.split(':').map(|p| p.parse::<f64>().ok());
    let (h, m, s) = (parts.next()??, parts.next()??, parts.next()??);
    Some(h * 3600.0 + m * 60.0 + s)
}

/// Four rows of the same cost (the same replay of the Neon recording),
/// two at a time, so that every row runs beside another (as fast as the
/// others: a row alone on a 2-core machine is quicker): the ETA printed
/// when a row ends is the time the batch then still took, within 40 %, a
/// quarter of a row's time (rows start a little apart and a row's time
/// varies with the machine's load) and the 1 s the line rounds to. The
/// rows ÷ elapsed estimate printed 3× the time left after the first row
/// (two rows run in one row's time): 18 s too much for 8-9 s left.
#[test]
fn the_batch_eta_is_the_time_it_still_takes() {
    let _serial = serial();
    let dir = tmp("eta");
    let manifest = dir.join("same.csv");
    let rec = shared_str("eye/neon-demo");
    let mut csv = String::from("id,recording,secs,size,fps,backend,no_frames\n");
    for id in ["a", "b", "c", "d"] {
        csv.push_str(&format!("{id},{rec},8,64x48,20,cpu,yes\n"));
    }
    std::fs::write(&manifest, csv).unwrap();
    let mut child = Command::new(env!("CARGO_BIN_EXE_gazelight"))
        .args([
            "batch",
            manifest.to_str().unwrap(),
            "--out",
            dir.join("out").to_str().unwrap(),
            "--jobs",
            "2",
        ])
        .stdout(Stdio::null())
        .stderr(Stdio::piped())
        .spawn()
        .unwrap();
    let stderr = child.stderr.take().unwrap();
    // Each stderr line with the time it came.
    let lines: Vec<(Instant, String)> = {
        use std::io::BufRead;
        std::io::BufReader::new(stderr)
            .lines()
            .map(|l| (Instant::now(), l.unwrap()))
            .collect()
    };
    let status = common::wait_exit(&mut child, Duration::from_secs(300));
    let end = Instant::now();
    let text: Vec<&str> = lines.iter().map(|l| l.1.as_str()).collect();
    assert!(status.success(), "{text:#?}");
    // The progress lines after a row ended (after "done …").
    let after_done: Vec<(Instant, f64)> = lines
        .windows(2)
        .filter(|w| w[0].1.starts_with("batch: done "))
        .map(|w| (w[1].0, eta_of(&w[1].1).expect("an ETA")))
        .collect();
    assert_eq!(after_done.len(), 4, "{text:#?}");
    // A row's time as the batch reports it ("done ID: N frames in S s").
    let row_secs: Vec<f64> = text
        .iter()
        .filter(|l| l.starts_with("batch: done "))
        .map(|l| {
            let s = l.rsplit(" in ").next().unwrap();
            s.trim_end_matches(" s").parse::<f64>().unwrap()
        })
        .collect();
    let row_mean = row_secs.iter().sum::<f64>() / row_secs.len() as f64;
    for (k, (at, eta)) in after_done.iter().enumerate() {
        let left = end.duration_since(*at).as_secs_f64();
        let margin = 0.4 * left + 0.25 * row_mean + 1.0;
        eprintln!("after row {}: ETA {eta} s, {left:.2} s left", k + 1);
        assert!(
            (eta - left).abs() <= margin,
            "after row {}: ETA {eta} s, {left:.2} s left (margin {margin:.2} s)\n{text:#?}",
            k + 1
        );
    }
    // The first row's ETA: a row's time left, not 0.
    assert!(after_done[0].1 >= 1.0, "{text:#?}");
    let _ = std::fs::remove_dir_all(&dir);
}

/// A recording written here (CSV with a Cloud-style events.csv beside it):
/// 100 Hz, a 4 mm pupil with ±0.02 mm of deterministic noise, an event
/// `stim K` at each onset, and at the onsets given a task dilation of the
/// amplitude given (Hoeks & Levelt 1993's response, n = 10.1,
/// t_max = 0.93 s, peak 1 at t_max).
fn write_trial_recording(dir: &Path, secs: f64, onsets: &[(f64, f64)]) {
    std::fs::create_dir_all(dir).unwrap();
    let hl = |t: f64| -> f64 {
        if t <= 0.0 {
            return 0.0;
        }
        let h = |t: f64| t.powf(10.1) * (-10.1 * t / 0.93).exp();
        h(t) / h(0.93)
    };
    let t0_ns: i64 = 1_700_000_000_000_000_000;
    let mut csv = String::from("timestamp [ns],gaze_u,gaze_v,pupil_mm\n");
    let mut seed: u64 = 99;
    for i in 0..(secs * 100.0) as usize {
        let t = i as f64 / 100.0;
        let task: f64 = onsets.iter().map(|(o, a)| a * hl(t - o)).sum();
        seed = seed
            .wrapping_mul(6364136223846793005)
            .wrapping_add(1442695040888963407);
        let noise = ((seed >> 33) as f64 / (1u64 << 31) as f64 - 0.5) * 0.04;
        let ns = t0_ns + (t * 1e9).round() as i64;
        csv.push_str(&format!("{ns},0.5,0.5,{:.4}\n", 4.0 + task + noise));
    }
    std::fs::write(dir.join("gaze.csv"), csv).unwrap();
    let mut ev = String::from("timestamp [ns],name\n");
    for (k, (o, _)) in onsets.iter().enumerate() {
        ev.push_str(&format!("{},stim {}\n", t0_ns + (o * 1e9) as i64, k + 1));
    }
    std::fs::write(dir.join("events.csv"), ev).unwrap();
}

#[test]
fn batch_trials_writes_each_recordings_table_and_one_for_the_study() {
    let _serial = serial();
    let dir = tmp("trials");
    // Two participants: onsets (s) and their task dilations (mm; 0 = none).
    let a = [(2.0, 0.0), (6.0, 0.5), (10.0, 0.0), (14.0, 0.4)];
    let b = [(3.0, 0.3), (8.0, 0.0), (13.0, 0.0)];
    write_trial_recording(&dir.join("rec-a"), 18.0, &a);
    write_trial_recording(&dir.join("rec-b"), 17.0, &b);
    std::fs::write(
        dir.join("noglare.toml"),
        "[pipeline]\nglare = { enabled = false }\n",
    )
    .unwrap();
    let manifest = dir.join("study.csv");
    std::fs::write(
        &manifest,
        "id,recording,subject,size,fps,backend,no_frames,config\n\
         pa,rec-a/gaze.csv,01,32x24,20,cpu,true,noglare.toml\n\
         pb,rec-b/gaze.csv,02,32x24,20,cpu,true,noglare.toml\n",
    )
    .unwrap();
    let out = dir.join("out");
    let o = common::gazelight(&[
        "batch",
        manifest.to_str().unwrap(),
        "--out",
        out.to_str().unwrap(),
        "--trials",
        "stim",
        "--baseline",
        "-0.5..0",
        "--window",
        "0..2.5",
    ]);
    let stdout = String::from_utf8_lossy(&o.stdout);
    assert!(
        o.status.success(),
        "{stdout}\n{}",
        String::from_utf8_lossy(&o.stderr)
    );
    assert!(stdout.contains("trials.csv: 7 trials"), "{stdout}");
    let read = |p: &Path| -> Vec<HashMap<String, String>> {
        let text = std::fs::read_to_string(p).unwrap_or_else(|e| panic!("{}: {e}", p.display()));
        let mut lines = text.lines();
        let header = gazelight_input::split_csv_line(lines.next().unwrap(), ',');
        lines
            .map(|l| {
                header
                    .iter()
                    .cloned()
                    .zip(gazelight_input::split_csv_line(l, ','))
                    .collect()
            })
            .collect()
    };
    let all = read(&out.join("trials.csv"));
    assert_eq!(all.len(), a.len() + b.len());
    for (id, participant, truth) in [("pa", "01", &a[..]), ("pb", "02", &b[..])] {
        let own = read(&out.join(id).join("trials.csv"));
        let mine: Vec<&HashMap<String, String>> =
            all.iter().filter(|r| r["recording"] == id).collect();
        assert_eq!(own.len(), truth.len(), "{id}");
        assert_eq!(mine.len(), truth.len(), "{id}");
        for ((row, joined), (onset, amp)) in own.iter().zip(&mine).zip(truth) {
            assert_eq!(joined["participant"], participant);
            // The study's table is the recording's, cell for cell.
            for (k, v) in row {
                assert_eq!(&joined[k], v, "{id} {k}");
            }
            let f = |k: &str| row[k].parse::<f64>().unwrap();
            // Onsets from the first sample (= the first frame here).
            assert!((f("onset_secs") - onset).abs() < 1e-3, "{row:?}");
            // The baseline is the resting 4 mm; the peak dilation the
            // amplitude written (within the noise and 20 Hz sampling).
            assert!((f("baseline_mm") - 4.0).abs() < 0.03, "{row:?}");
            let peak = f("peak_dilation_mm");
            if *amp > 0.0 {
                assert!(
                    (peak - amp).abs() < 0.15 * amp,
                    "{id} {onset}: {peak} vs {amp}"
                );
            } else {
                assert!(peak < 0.06, "{id} {onset}: {peak} without a dilation");
            }
        }
    }
}
