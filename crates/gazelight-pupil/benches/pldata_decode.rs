#![allow(clippy::unwrap_used, clippy::expect_used)] // bench code may panic on a failed setup
//! `.pldata` recording decode throughput (issue 13), one core.
//!
//! A Pupil Core recording is written with the real writer
//! ([`PldataWriter`], the one `gazelight record` uses) into a temporary
//! directory: per eye-camera frame and eye, one `pupil.N.2d` and one
//! `pupil.N.3d` (pye3d, every field Pupil Capture v3 sends) datum, and one
//! binocular `gaze.3d.01.` datum carrying both 3D datums as `base_data`,
//! as Pupil Capture records them. The pupil diameters, timestamps and rate
//! (200 Hz) come from the real pupil light reflex trace in
//! `eye/piprkit-plr/pupil_trace.csv` of the shared test data (both eyes, mm).
//!
//! `pldata_decode/pupil` reads `pupil.pldata` with [`PldataReader::samples`]
//! (file → bounded buffer → framing → zero-copy decode → [`Sample`]) and
//! reports pupil datums per second; `pldata_decode/gaze` does the same for
//! `gaze.pldata` (gaze datums per second). The files stay in the page
//! cache, so this is the decode speed, not the disk's.
//!
//! Set `GAZELIGHT_PLDATA_DIR` to a recording directory (e.g. one made by
//! `gazelight record`) to measure that instead (an empty or missing one
//! gets the generated recording, kept), and `GAZELIGHT_BENCH_REPS=N`
//! to decode each file N times without criterion (for `perf stat`, whose
//! CPU time per datum holds on a loaded machine where wall time does not).

use std::hint::black_box;
use std::path::{Path, PathBuf};
use std::time::Duration;

use criterion::{Criterion, Throughput};
use gazelight_eye::sample::Sample;
use gazelight_pupil::recording::{PldataReader, PldataWriter, stream_paths};
use rmpv::Value as V;

/// Eye-camera frames written (× 4 pupil datums: 2D + 3D, two eyes).
const FRAMES: usize = 12_500;

fn arr(v: &[f64]) -> V {
    V::Array(v.iter().map(|x| V::from(*x)).collect())
}

fn map(e: Vec<(&str, V)>) -> V {
    V::Map(e.into_iter().map(|(k, v)| (V::from(k), v)).collect())
}

/// A 2D datum; `d_mm` is the real trace's diameter, drawn at ~9.5 px/mm
/// as on a 192×192 Pupil Core eye camera.
fn pupil_2d(eye: u8, t: f64, d_mm: f64, k: f64) -> V {
    let px = d_mm * 9.47;
    map(vec![
        ("topic", V::from(format!("pupil.{eye}.2d"))),
        ("id", V::from(eye)),
        ("method", V::from("2d c++")),
        ("timestamp", V::from(t)),
        ("confidence", V::from(0.90 + 0.09 * k)),
        ("diameter", V::from(px)),
        ("norm_pos", arr(&[0.45 + 0.01 * k, 0.52 - 0.01 * k])),
        (
            "ellipse",
            map(vec![
                ("center", arr(&[86.65 + k, 90.67 - k])),
                ("axes", arr(&[px * 0.92, px])),
                ("angle", V::from(-21.7 + 3.0 * k)),
            ]),
        ),
    ])
}

/// A pye3d datum with every field Pupil Capture v3 sends.
fn pupil_3d(eye: u8, t: f64, d_mm: f64, k: f64) -> V {
    let V::Map(mut m) = pupil_2d(eye, t, d_mm, k) else {
        unreachable!()
    };
    m[0].1 = V::from(format!("pupil.{eye}.3d"));
    m[2].1 = V::from("pye3d 0.3.0 real-time");
    let V::Map(extra) = map(vec![
        (
            "sphere",
            map(vec![
                ("center", arr(&[1.2, 0.7, 41.3])),
                ("radius", V::from(10.39)),
            ]),
        ),
        (
            "projected_sphere",
            map(vec![
                ("center", arr(&[99.1, 94.2])),
                ("axes", arr(&[121.3, 121.3])),
                ("angle", V::from(0.0)),
            ]),
        ),
        (
            "circle_3d",
            map(vec![
                ("center", arr(&[1.52 + k, -0.48, 31.02])),
                ("normal", arr(&[0.051, -0.102 + 0.01 * k, -0.993])),
                ("radius", V::from(d_mm / 2.0)),
            ]),
        ),
        ("diameter_3d", V::from(d_mm)),
        ("location", arr(&[86.65 + k, 90.67 - k])),
        ("model_confidence", V::from(1.0)),
        ("model_id", V::from(3)),
        ("theta", V::from(1.673 + 0.01 * k)),
        ("phi", V::from(-1.518 - 0.01 * k)),
    ]) else {
        unreachable!()
    };
    m.extend(extra);
    V::Map(m)
}

fn gaze_3d(t: f64, base: [V; 2], k: f64) -> V {
    map(vec![
        ("topic", V::from("gaze.3d.01.")),
        (
            "eye_centers_3d",
            V::Map(vec![
                (V::from(0), arr(&[20.1, 15.2, -20.3])),
                (V::from(1), arr(&[-40.2, 15.1, -20.5])),
            ]),
        ),
        (
            "gaze_normals_3d",
            V::Map(vec![
                (V::from(0), arr(&[-0.1, 0.05, 0.99])),
                (V::from(1), arr(&[0.02, 0.05, 0.99])),
            ]),
        ),
        ("gaze_point_3d", arr(&[12.3 + k, -40.1, 497.0])),
        ("confidence", V::from(0.95)),
        ("timestamp", V::from(t)),
        ("base_data", V::Array(base.to_vec())),
        ("norm_pos", arr(&[0.512 + 0.01 * k, 0.433])),
    ])
}

fn enc(v: &V) -> Vec<u8> {
    let mut b = Vec::new();
    rmpv::encode::write_value(&mut b, v).expect("encode");
    b
}

/// The real PLR trace: (t s, left mm, right mm) at 200 Hz.
fn trace() -> Vec<(f64, f64, f64)> {
    let path = gazelight_test_support::data_path("eye/piprkit-plr/pupil_trace.csv");
    let text = std::fs::read_to_string(&path).unwrap_or_else(|e| panic!("{path:?}: {e}"));
    text.lines()
        .skip(1)
        .filter_map(|l| {
            let mut f = l.split(',').map(|x| x.trim().parse::<f64>());
            Some((f.next()?.ok()?, f.next()?.ok()?, f.next()?.ok()?))
        })
        .collect()
}

/// Writes the recording; returns (pupil datums, gaze datums).
fn write_recording(dir: &Path) -> (u64, u64) {
    let rows = trace();
    assert!(rows.len() >= FRAMES, "trace too short");
    let mut pupil = PldataWriter::create(dir, "pupil").unwrap();
    let mut gaze = PldataWriter::create(dir, "gaze").unwrap();
    // Pupil time of a typical session (seconds since the machine booted).
    let t0 = 8_316.25;
    for (i, (t, left, right)) in rows.iter().take(FRAMES).enumerate() {
        let k = ((i * 7919) % 101) as f64 / 100.0;
        let t = t0 + t;
        let mut base = Vec::with_capacity(2);
        // Pupil's eye 0 is the right eye, eye 1 the left.
        for (eye, d) in [(0u8, *right), (1u8, *left)] {
            let d2 = pupil_2d(eye, t, d, k);
            pupil
                .append(&format!("pupil.{eye}.2d"), &enc(&d2), t)
                .unwrap();
            let d3 = pupil_3d(eye, t, d, k);
            pupil
                .append(&format!("pupil.{eye}.3d"), &enc(&d3), t)
                .unwrap();
            base.push(d3);
        }
        let [b0, b1]: [V; 2] = base.try_into().unwrap();
        gaze.append("gaze.3d.01.", &enc(&gaze_3d(t, [b0, b1], k)), t)
            .unwrap();
    }
    (pupil.close().unwrap(), gaze.close().unwrap())
}

/// Decodes a whole `.pldata`; returns the samples seen.
fn read_all(path: &Path) -> u64 {
    let mut n = 0u64;
    let mut pupil_sum = 0.0f32;
    for s in PldataReader::open(path).unwrap().samples() {
        match s.unwrap() {
            Sample::Pupil(p) => pupil_sum += p.diameter_raw,
            Sample::Gaze(g) => pupil_sum += g.confidence,
            Sample::Blink(_) => {}
        }
        n += 1;
    }
    black_box(pupil_sum);
    n
}

fn main() {
    let (dir, cleanup) = match std::env::var_os("GAZELIGHT_PLDATA_DIR") {
        Some(d) => {
            let d = PathBuf::from(d);
            if !stream_paths(&d, "pupil").0.is_file() {
                std::fs::create_dir_all(&d).unwrap();
                write_recording(&d);
            }
            (d, false)
        }
        None => {
            let d =
                std::env::temp_dir().join(format!("gazelight-pldata-bench-{}", std::process::id()));
            std::fs::create_dir_all(&d).unwrap();
            let (p, g) = write_recording(&d);
            eprintln!("wrote {p} pupil datums, {g} gaze datums to {}", d.display());
            (d, true)
        }
    };
    // `GAZELIGHT_BENCH_REPS=N`: decode each stream N times and exit, for
    // `perf stat` (CPU time per datum on a loaded machine).
    if let Some(reps) = std::env::var("GAZELIGHT_BENCH_REPS")
        .ok()
        .and_then(|r| r.parse::<u32>().ok())
    {
        for stream in ["pupil", "gaze"] {
            let (path, _) = stream_paths(&dir, stream);
            if path.is_file() {
                let n: u64 = (0..reps).map(|_| read_all(&path)).sum();
                eprintln!("{stream}.pldata: decoded {n} datums");
            }
        }
        if cleanup {
            std::fs::remove_dir_all(&dir).ok();
        }
        return;
    }
    let mut c = Criterion::default()
        .sample_size(20)
        .warm_up_time(Duration::from_secs(1))
        .measurement_time(Duration::from_secs(5))
        .configure_from_args();
    let mut g = c.benchmark_group("pldata_decode");
    for stream in ["pupil", "gaze"] {
        let (path, _) = stream_paths(&dir, stream);
        if !path.is_file() {
            continue;
        }
        let n = read_all(&path);
        let bytes = std::fs::metadata(&path).map(|m| m.len()).unwrap_or(0);
        eprintln!("{stream}.pldata: {n} datums, {bytes} bytes");
        g.throughput(Throughput::Elements(n));
        g.bench_function(stream, |b| b.iter(|| read_all(black_box(&path))));
    }
    g.finish();
    c.final_summary();
    if cleanup {
        std::fs::remove_dir_all(&dir).ok();
    }
}
