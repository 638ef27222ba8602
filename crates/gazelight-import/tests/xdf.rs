#![allow(clippy::unwrap_used, clippy::expect_used)] // test code may panic on a failed setup
//! XDF reader against pyxdf (PyPI), on the XDF project's example files
//! (github.com/xdf-modules/example-files, MIT; the files pyxdf's own tests
//! read), in `tests/data/xdf/` at the workspace root: the same streams,
//! sample counts, values and time stamps (clock offsets, clock resets and
//! dejitter as pyxdf's `load_xdf` defaults). Then truncated and damaged
//! copies of a real file: an error naming the chunk, never a panic, a
//! hang or a large allocation.
//!
//! Needs `python3` with `pyxdf` (`.ci/test` installs it): outside CI a
//! missing one skips the pyxdf comparison; with `CI` set it fails.

use std::path::{Path, PathBuf};
use std::process::Command;

use gazelight_import::xdf::{ChannelFormat, XdfFile};
use gazelight_test_support::skip_or_fail;

/// Largest time-stamp difference to pyxdf accepted, s (0.1 µs, four
/// orders below a 1 kHz tracker's sample interval). The same algorithms
/// in a different order of floating-point operations: pyxdf's robust
/// clock fit runs 1000 ADMM iterations on times scaled by 1e4 and solves
/// its 2 × 2 systems with LAPACK; its dejitter line comes from numpy's SVD
/// least squares on raw indices, ours from centred running sums. Measured:
/// up to 1.9e-8 s (clock_resets.xdf, two clock ranges).
const MAX_STAMP_DIFF_SECS: f64 = 1e-7;

fn data(name: &str) -> PathBuf {
    Path::new(env!("CARGO_MANIFEST_DIR"))
        .join("../../tests/data/xdf")
        .join(name)
}

fn pyxdf_dump(file: &Path) -> Option<serde_json::Value> {
    let script = Path::new(env!("CARGO_MANIFEST_DIR")).join("tests/xdf/pyxdf_dump.py");
    let out = match Command::new("python3").arg(&script).arg(file).output() {
        Ok(o) => o,
        Err(e) => {
            skip_or_fail(&format!("python3 not runnable: {e}"));
            return None;
        }
    };
    if !out.status.success() {
        let err = String::from_utf8_lossy(&out.stderr);
        if err.contains("No module named 'pyxdf'") {
            skip_or_fail("python3 has no pyxdf (pip install pyxdf)");
            return None;
        }
        panic!("pyxdf failed on {}: {err}", file.display());
    }
    Some(serde_json::from_slice(&out.stdout).expect("pyxdf's JSON"))
}

/// What our reader reads of one stream: stamps and values.
struct Read {
    stamps: Vec<f64>,
    numeric: Vec<Vec<f64>>,
    text: Vec<Vec<String>>,
}

fn read_stream(file: &XdfFile, index: usize) -> Result<Read, String> {
    let mut s = file.samples(index).map_err(|e| e.to_string())?;
    let mut r = Read {
        stamps: Vec::new(),
        numeric: Vec::new(),
        text: Vec::new(),
    };
    while let Some(t) = s.next_sample().map_err(|e| e.to_string())? {
        r.stamps.push(t);
        if s.info().format == ChannelFormat::String {
            r.text.push(s.text().to_vec());
        } else {
            r.numeric.push(s.numeric().to_vec());
        }
    }
    Ok(r)
}

#[test]
fn reads_what_pyxdf_reads_on_the_xdf_example_files() {
    let mut figures = Vec::new();
    for name in ["minimal.xdf", "clock_resets.xdf", "empty_streams.xdf"] {
        let path = data(name);
        let Some(py) = pyxdf_dump(&path) else { return };
        let file = XdfFile::scan(&path).unwrap_or_else(|e| panic!("{name}: {e}"));
        let py_streams = py["streams"].as_array().expect("streams");
        assert_eq!(file.streams.len(), py_streams.len(), "{name}: stream count");
        for ps in py_streams {
            let id = ps["id"].as_u64().expect("id") as u32;
            let index = file
                .streams
                .iter()
                .position(|s| s.id == id)
                .unwrap_or_else(|| panic!("{name}: no stream {id}"));
            let info = &file.streams[index];
            assert_eq!(info.name, ps["name"].as_str().unwrap_or(""), "{name} {id}");
            assert_eq!(info.kind, ps["type"].as_str().unwrap_or(""), "{name} {id}");
            assert_eq!(info.format.name(), ps["format"].as_str().unwrap_or(""));
            assert_eq!(
                info.clock_offsets.len() as u64,
                ps["clock_offsets"].as_u64().unwrap_or(u64::MAX),
                "{name} {id}: clock offsets"
            );
            let read = read_stream(&file, index).unwrap_or_else(|e| panic!("{name} {id}: {e}"));
            let py_t: Vec<f64> = ps["time_stamps"]
                .as_array()
                .expect("stamps")
                .iter()
                .map(|v| v.as_f64().expect("a stamp"))
                .collect();
            assert_eq!(
                read.stamps.len(),
                py_t.len(),
                "{name} stream {id}: sample count"
            );
            let max_diff = read
                .stamps
                .iter()
                .zip(&py_t)
                .map(|(a, b)| (a - b).abs())
                .fold(0.0f64, f64::max);
            assert!(
                max_diff <= MAX_STAMP_DIFF_SECS,
                "{name} stream {id}: stamps differ from pyxdf by up to {max_diff:e} s"
            );
            let py_v = ps["values"].as_array().expect("values");
            for (k, row) in py_v.iter().enumerate() {
                let row = row.as_array().expect("a row");
                if info.format == ChannelFormat::String {
                    let ours = &read.text[k];
                    let theirs: Vec<&str> = row.iter().map(|v| v.as_str().unwrap_or("")).collect();
                    assert_eq!(ours, &theirs, "{name} stream {id} sample {k}");
                } else {
                    let ours = &read.numeric[k];
                    for (c, v) in row.iter().enumerate() {
                        match v.as_f64() {
                            Some(v) => assert_eq!(ours[c], v, "{name} {id} sample {k} ch {c}"),
                            None => assert!(ours[c].is_nan(), "{name} {id} sample {k} ch {c}"),
                        }
                    }
                }
            }
            figures.push(format!(
                "{name} stream {id} `{}` ({}): {} samples, {} clock offsets, {} clock range(s), \
                 max |Δt| vs pyxdf {max_diff:.3e} s",
                info.name,
                info.format.name(),
                read.stamps.len(),
                info.clock_offsets.len(),
                info.clock_ranges
            ));
        }
    }
    for f in &figures {
        eprintln!("{f}");
    }
    // The example files' own documentation (README of example-files):
    // minimal.xdf has 9 samples in each of its two streams, the first
    // starting at 5.1 s with offset −0.1 s applied.
    assert!(
        figures
            .iter()
            .any(|f| f.contains("minimal.xdf stream 0 `SendDataC` (int16): 9 samples"))
    );
}

/// The byte offsets where the chunks of a well-formed XDF file start,
/// walked independently of the reader (magic, then length-prefixed
/// chunks).
fn chunk_offsets(bytes: &[u8]) -> Vec<usize> {
    let mut at = 4;
    let mut out = Vec::new();
    while at < bytes.len() {
        out.push(at);
        let n = bytes[at] as usize;
        let mut len = 0u64;
        for k in 0..n {
            len |= u64::from(bytes[at + 1 + k]) << (8 * k);
        }
        at += 1 + n + len as usize;
    }
    assert_eq!(at, bytes.len(), "the example file is well formed");
    out
}

/// Reads every stream of `path` whole; the first error.
fn read_all(path: &Path) -> Result<u64, String> {
    let file = XdfFile::scan(path).map_err(|e| e.to_string())?;
    let mut n = 0;
    for k in 0..file.streams.len() {
        n += read_stream(&file, k)?.stamps.len() as u64;
    }
    Ok(n)
}

/// Peak resident memory of this process so far, bytes (Linux).
fn peak_rss_bytes() -> u64 {
    let status = std::fs::read_to_string("/proc/self/status").unwrap_or_default();
    status
        .lines()
        .find_map(|l| l.strip_prefix("VmHWM:"))
        .and_then(|v| v.trim().trim_end_matches("kB").trim().parse::<u64>().ok())
        .map_or(0, |kb| kb * 1024)
}

#[test]
fn truncated_and_damaged_copies_name_the_chunk() {
    let original = std::fs::read(data("minimal.xdf")).expect("minimal.xdf");
    let starts = chunk_offsets(&original);
    let dir = std::env::temp_dir().join(format!("gazelight-xdf-damage-{}", std::process::id()));
    std::fs::create_dir_all(&dir).expect("temp dir");
    let path = dir.join("cut.xdf");

    // Every truncation: cut at a chunk boundary, a shorter valid file; cut
    // anywhere else, an error naming the chunk that was cut.
    for cut in 4..original.len() {
        std::fs::write(&path, &original[..cut]).expect("write");
        let result = read_all(&path);
        if starts.contains(&cut) {
            // A file cut between chunks is well formed, but a stream whose
            // samples were cut off says so.
            continue;
        }
        let chunk = starts.iter().rposition(|&s| s < cut).expect("a chunk");
        let err = result.expect_err(&format!("a file cut at byte {cut} must be an error"));
        let want = format!("(byte offset {}): chunk {chunk}", starts[chunk]);
        assert!(
            err.contains(&want),
            "cut at {cut}: `{err}` should contain `{want}`"
        );
    }
    // A cut short of the magic is not an XDF file.
    std::fs::write(&path, &original[..3]).expect("write");
    assert!(read_all(&path).unwrap_err().contains("not an XDF file"));

    // Damaged lengths and counts that claim huge sizes: an error naming
    // the chunk, before anything of that size is allocated.
    let big = std::fs::read(data("clock_resets.xdf")).expect("clock_resets.xdf");
    let big_starts = chunk_offsets(&big);
    let samples_chunk = big_starts
        .iter()
        .copied()
        .enumerate()
        .find(|&(_, s)| {
            let n = big[s] as usize;
            u16::from_le_bytes([big[s + 1 + n], big[s + 2 + n]]) == 3
        })
        .expect("a Samples chunk");
    let (k, s) = samples_chunk;
    let n = big[s] as usize;
    let body = s + 1 + n + 2; // stream id, then the sample count
    let cases: Vec<(&str, Vec<u8>, String)> = vec![
        (
            "a length-size byte of 3",
            {
                let mut b = big.clone();
                b[s] = 3;
                b
            },
            format!("(byte offset {s}): chunk {k}"),
        ),
        (
            "a chunk length of 2^63",
            {
                let mut b = big.clone();
                let mut head = vec![8u8];
                head.extend_from_slice(&(1u64 << 63).to_le_bytes());
                b.splice(s..s + 1 + n, head);
                b
            },
            "runs past the end of the file".into(),
        ),
        (
            "a sample count of 2^62",
            {
                let mut b = big.clone();
                let old_count_len = 1 + b[body + 4] as usize;
                let mut count = vec![8u8];
                count.extend_from_slice(&(1u64 << 62).to_le_bytes());
                let grow = count.len() as i64 - old_count_len as i64;
                b.splice(body + 4..body + 4 + old_count_len, count);
                // Keep the chunk's length right so only the count lies.
                let mut len = 0u64;
                for j in 0..n {
                    len |= u64::from(b[s + 1 + j]) << (8 * j);
                }
                let len = (len as i64 + grow) as u64;
                for j in 0..n {
                    b[s + 1 + j] = (len >> (8 * j)) as u8;
                }
                b
            },
            "the count is damaged".into(),
        ),
        (
            "a stamp flag of 7",
            {
                let mut b = big.clone();
                let count_len = 1 + b[body + 4] as usize;
                b[body + 4 + count_len] = 7;
                b
            },
            "neither 0 nor 8".into(),
        ),
    ];
    for (what, bytes, want) in cases {
        std::fs::write(&path, &bytes).expect("write");
        let err = read_all(&path).expect_err(what);
        assert!(
            err.contains(&want),
            "{what}: `{err}` should contain `{want}`"
        );
        assert!(err.contains("chunk "), "{what}: `{err}` names no chunk");
    }
    let _ = std::fs::remove_dir_all(&dir);
    // Nothing above may have allocated anywhere near the sizes the damaged
    // files claim (2^62 samples, 2^63 bytes): the whole test binary stays
    // small.
    let peak = peak_rss_bytes();
    assert!(peak < 512 << 20, "peak resident memory {peak} bytes");
}

/// The stand-in eye XDF of `layout` (tests/xdf/write_eye_xdf.py: the real
/// piprkit pupil recording's first `rows` rows, LabRecorder's layout),
/// written into `dir`; `None` when python3 or the shared data is missing.
fn stand_in(layout: &str, rows: usize, dir: &Path) -> Option<PathBuf> {
    stand_in_with(layout, rows, dir, layout, &[])
}

/// [`stand_in`] with the script's KEY=VALUE options (a blink, a gaze, a
/// damaged stamp or clock offset), written as `dir/NAME.xdf`.
fn stand_in_with(
    layout: &str,
    rows: usize,
    dir: &Path,
    name: &str,
    options: &[&str],
) -> Option<PathBuf> {
    let plr = gazelight_test_support::data_path("eye").join("piprkit-plr");
    let out = dir.join(format!("{name}.xdf"));
    let script = Path::new(env!("CARGO_MANIFEST_DIR")).join("tests/xdf/write_eye_xdf.py");
    let status = match Command::new("python3")
        .arg(&script)
        .arg(layout)
        .arg(plr.join("pupil_trace.csv"))
        .arg(plr.join("stimuli.csv"))
        .arg(rows.to_string())
        .arg(&out)
        .args(options)
        .status()
    {
        Ok(s) => s,
        Err(e) => {
            skip_or_fail(&format!("python3 not runnable: {e}"));
            return None;
        }
    };
    assert!(status.success(), "write_eye_xdf.py {layout} failed");
    Some(out)
}

/// The piprkit rows as (right, left) mm, NaN where empty.
fn piprkit_rows(rows: usize) -> Vec<[f32; 2]> {
    let path = gazelight_test_support::data_path("eye").join("piprkit-plr/pupil_trace.csv");
    let text = std::fs::read_to_string(path).expect("pupil_trace.csv");
    text.lines()
        .skip(1)
        .take(rows)
        .map(|l| {
            let f: Vec<&str> = l.split(',').collect();
            let v = |s: &str| s.parse::<f32>().unwrap_or(f32::NAN);
            [v(f[2]), v(f[1])]
        })
        .collect()
}

#[test]
fn eye_streams_in_each_layout_replay_the_recording_with_pyxdf_stamps() {
    use gazelight_eye::sample::{PupilUnit, Sample};
    const ROWS: usize = 3000;
    let dir = std::env::temp_dir().join(format!("gazelight-xdf-eye-{}", std::process::id()));
    std::fs::create_dir_all(&dir).expect("temp dir");
    let rows = piprkit_rows(ROWS);
    for layout in ["pupil-capture-relay", "gazelight-eye", "neon"] {
        let Some(path) = stand_in(layout, ROWS, &dir) else {
            return;
        };
        let Some(py) = pyxdf_dump(&path) else { return };
        let eye = &py["streams"][0];
        assert_eq!(eye["type"], "Gaze");
        let py_t: Vec<f64> = eye["time_stamps"]
            .as_array()
            .expect("stamps")
            .iter()
            .map(|v| v.as_f64().expect("a stamp"))
            .collect();
        assert_eq!(py_t.len(), ROWS);
        let mut imp = gazelight_import::open(&path).unwrap_or_else(|e| panic!("{layout}: {e}"));
        assert_eq!(imp.format(), "xdf");
        // Every row's pupils, in order, at pyxdf's stamps.
        let mut next = [0usize; 2];
        let mut pupils = [0usize; 2];
        let mut gaze = 0;
        for s in imp.by_ref() {
            match s.unwrap_or_else(|e| panic!("{layout}: {e}")) {
                Sample::Pupil(p) => {
                    let e = p.eye as usize;
                    pupils[e] += 1;
                    // Every row gives each eye a sample; a lost pupil is a
                    // lost sample (confidence 0), never left out.
                    let k = next[e];
                    assert!(k < ROWS, "{layout}: more eye {e} pupils than rows");
                    next[e] = k + 1;
                    let v = rows[k][e];
                    assert!(
                        (p.t_secs - py_t[k]).abs() <= MAX_STAMP_DIFF_SECS,
                        "{layout} {k}"
                    );
                    assert_eq!(p.unit, PupilUnit::Mm);
                    if v.is_finite() && v > 0.0 {
                        assert_eq!(p.diameter_mm, Some(v), "{layout} row {k} eye {e}");
                        assert!(p.confidence > 0.0);
                    } else {
                        assert_eq!((p.diameter_mm, p.confidence), (None, 0.0));
                    }
                }
                Sample::Gaze(g) => {
                    gaze += 1;
                    if layout == "pupil-capture-relay" {
                        // The relay's gaze is NaN (the recording has none):
                        // a lost gaze on every row.
                        assert!(g.gaze_uv[0].is_nan() && g.confidence == 0.0, "{g:?}");
                    } else {
                        assert_eq!(g.gaze_uv, [0.5, 0.5], "{layout}");
                    }
                }
                Sample::Blink(_) => panic!("{layout}: the recording has no blink channel set"),
            }
        }
        // Every row counted: pyxdf's row count per eye and for the gaze.
        assert_eq!(pupils, [py_t.len(); 2], "{layout}");
        assert_eq!(gaze, py_t.len(), "{layout}");
        let note = imp.warnings().messages[0].clone();
        assert!(note.contains(&format!("layout {layout}")), "{note}");
        assert!(note.contains("`stimuli` (type Markers"), "{note}");
        eprintln!("{layout}: {ROWS} rows → pupils {pupils:?}, gaze {gaze}; {note}");
    }

    // A stream by name; a marker stream refused; an unknown layout named.
    let Some(path) = stand_in("unknown", 200, &dir) else {
        return;
    };
    let err = gazelight_import::open(&path)
        .err()
        .expect("an unknown layout")
        .to_string();
    assert!(err.contains("channels [a, b]"), "{err}");
    let markers = PathBuf::from(format!("{}?stream=stimuli", path.display()));
    let err = gazelight_import::open(&markers)
        .err()
        .expect("markers")
        .to_string();
    assert!(
        err.contains("markers") && err.contains("events.csv"),
        "{err}"
    );
    let nope = PathBuf::from(format!("{}?stream=nope", path.display()));
    let err = gazelight_import::open(&nope)
        .err()
        .expect("no such stream")
        .to_string();
    assert!(
        err.contains("no stream named `nope`") && err.contains("`mystery`"),
        "{err}"
    );
    let _ = std::fs::remove_dir_all(&dir);
}

/// Issue 45 item 6: a Pupil-Capture-relay XDF (gaze on every row) with a
/// 150 ms blink as Pupil Capture relays one (confidence 0, every diameter
/// 0). `inspect`'s summary (`summarize_importer`, what the command prints)
/// counts as many samples per eye and of gaze as pyxdf reads rows, and
/// the filter chain counts the blink in each eye. Before: the 30 blink
/// rows were left out (3970 of pyxdf's 4000) and no blink was counted.
#[test]
fn a_relay_blink_is_counted_and_the_counts_equal_pyxdfs() {
    use gazelight_eye::filter::FilterChain;
    const ROWS: usize = 4000;
    const BLINK_ROW: usize = 1000;
    const BLINK_ROWS: usize = 30; // 150 ms at 200 Hz
    let dir = std::env::temp_dir().join(format!("gazelight-xdf-blink-{}", std::process::id()));
    std::fs::create_dir_all(&dir).expect("temp dir");
    let Some(path) = stand_in_with(
        "pupil-capture-relay",
        ROWS,
        &dir,
        "relay-blink",
        &["gaze=0.4,0.6", &format!("blink={BLINK_ROW},{BLINK_ROWS}")],
    ) else {
        return;
    };
    let Some(py) = pyxdf_dump(&path) else { return };
    let eye = &py["streams"][0];
    let values = eye["values"].as_array().expect("values");
    let stamps: Vec<f64> = eye["time_stamps"]
        .as_array()
        .expect("stamps")
        .iter()
        .map(|v| v.as_f64().expect("a stamp"))
        .collect();
    // pyxdf's own view of the file: its rows, and the blink (confidence
    // channel 0 is 0) with its duration on pyxdf's clock.
    let closed: Vec<usize> = values
        .iter()
        .enumerate()
        .filter(|(_, row)| row[0].as_f64() == Some(0.0))
        .map(|(k, _)| k)
        .collect();
    assert_eq!(closed.len(), BLINK_ROWS, "pyxdf's zero-confidence rows");
    // 30 rows of the piprkit recording's ~5 ms: 150 ms give or take its
    // jitter.
    let blink_s = stamps[closed[BLINK_ROWS - 1] + 1] - stamps[closed[0]];
    assert!((blink_s - 0.150).abs() < 0.005, "{blink_s}");

    let mut imp = gazelight_import::open(&path).expect("open");
    let summary =
        gazelight_import::summary::summarize_importer(imp.as_mut(), FilterChain::with_defaults())
            .expect("summary");
    let n = stamps.len() as u64;
    assert_eq!(n, ROWS as u64);
    assert_eq!(
        summary.samples.pupil,
        [n, n],
        "pupil samples per eye vs pyxdf"
    );
    assert_eq!(summary.samples.gaze, n, "gaze samples vs pyxdf");
    assert_eq!(summary.skipped_records, 0);
    assert_eq!(summary.blinks.detected, [1, 1], "{:?}", summary.blinks);
    eprintln!(
        "relay XDF with a {:.0} ms blink: pyxdf {n} rows; inspect pupils {:?}, gaze {}, \
         blinks detected {:?}, dropouts {:?}",
        blink_s * 1e3,
        summary.samples.pupil,
        summary.samples.gaze,
        summary.blinks.detected,
        summary.dropouts
    );
    let _ = std::fs::remove_dir_all(&dir);
}

/// What `gazelight_import::open` gives of a file: pupil samples per eye,
/// the right eye's times, the notes.
type Counts = ([u64; 2], Vec<f64>, Vec<String>);

/// The [`Counts`] of `path`.
fn read_counts(path: &Path) -> Result<Counts, String> {
    use gazelight_eye::sample::Sample;
    let mut imp = gazelight_import::open(path).map_err(|e| e.to_string())?;
    let mut pupils = [0u64; 2];
    let mut times = Vec::new();
    for s in imp.by_ref() {
        if let Sample::Pupil(p) = s.map_err(|e| e.to_string())? {
            pupils[usize::from(p.eye)] += 1;
            if p.eye == 0 {
                times.push(p.t_secs);
            }
        }
    }
    Ok((pupils, times, imp.warnings().messages.clone()))
}

/// Issue 48 class 1: one non-finite time stamp among 3000 samples, and
/// one NaN, inf or 1e308 clock offset among 30, no longer poison the
/// stream. The stamp is left out of the dejitter fit and takes its line's
/// time (every sample keeps, within 1 % of the 5 ms sample interval, the
/// time it has in the file without the bad value: the line through 2999
/// of the recording's jittery stamps instead of 3000);
/// the offset is left out of the clock fit. Both are counted in the
/// import's notes (`inspect` prints them). The times of the clean file
/// are the reference (pyxdf's, checked above); pyxdf itself gives NaN
/// for every stamp of such a stream.
#[test]
fn one_non_finite_stamp_or_clock_offset_is_skipped_and_counted() {
    let dir = std::env::temp_dir().join(format!("gazelight-xdf-nonfinite-{}", std::process::id()));
    std::fs::create_dir_all(&dir).expect("temp dir");
    // 3000 rows: the stamps.
    let Some(clean) = stand_in_with("gazelight-eye", 3000, &dir, "clean3000", &[]) else {
        return;
    };
    let (n, want, _) = read_counts(&clean).expect("the clean file");
    assert_eq!(n, [3000, 3000]);
    for value in ["nan", "inf", "-inf", "1e308"] {
        let Some(path) = stand_in_with(
            "gazelight-eye",
            3000,
            &dir,
            &format!("stamp-{value}"),
            &[&format!("stamp=1234,{value}")],
        ) else {
            return;
        };
        let (n, got, notes) = read_counts(&path).unwrap_or_else(|e| panic!("stamp {value}: {e}"));
        assert_eq!(n, [3000, 3000], "stamp {value}: every sample read");
        let worst = want
            .iter()
            .zip(&got)
            .map(|(a, b)| (a - b).abs())
            .fold(0.0, f64::max);
        assert!(worst < 50e-6, "stamp {value}: times moved by {worst} s");
        assert!(
            got[1233] < got[1234] && got[1234] < got[1235],
            "stamp {value}"
        );
        let note = notes
            .iter()
            .find(|m| m.contains("1 of its 3000 samples have a time stamp"))
            .unwrap_or_else(|| panic!("stamp {value}: no note in {notes:?}"));
        eprintln!("stamp {value}: {note}");
    }
    // 30 clock offsets: one every 5 s over 150 s.
    let Some(clean) = stand_in_with("gazelight-eye", 29_200, &dir, "clean29200", &[]) else {
        return;
    };
    let (n, want, notes) = read_counts(&clean).expect("the clean file");
    assert_eq!(n, [29_200, 29_200]);
    assert!(notes[0].contains("30 clock offsets"), "{notes:?}");
    for value in ["nan", "inf", "1e308", "-1e308"] {
        let Some(path) = stand_in_with(
            "gazelight-eye",
            29_200,
            &dir,
            &format!("offset-{value}"),
            &[&format!("offset=17,{value}")],
        ) else {
            return;
        };
        let (n, got, notes) = read_counts(&path).unwrap_or_else(|e| panic!("offset {value}: {e}"));
        assert_eq!(n, [29_200, 29_200], "offset {value}: every sample read");
        let worst = want
            .iter()
            .zip(&got)
            .map(|(a, b)| (a - b).abs())
            .fold(0.0, f64::max);
        // The fit through 29 of the 30 points of one line: the same line.
        assert!(worst < 1e-6, "offset {value}: times moved by {worst} s");
        let note = notes
            .iter()
            .find(|m| m.contains("1 of its 30 clock offsets skipped"))
            .unwrap_or_else(|| panic!("offset {value}: no note in {notes:?}"));
        eprintln!("offset {value}: {note}");
    }
    let _ = std::fs::remove_dir_all(&dir);
}
