#![allow(clippy::unwrap_used, clippy::expect_used)] // test code may panic on a failed setup
//! A `.tsv.gz` that expands far beyond its size (a gzip bomb of valid
//! rows) is refused once `gazelight_input::MAX_EXPANSION_RATIO` times its
//! compressed size came out, naming the file: it never becomes minutes of
//! parsing and gigabytes of samples.

use std::io::Write;
use std::path::PathBuf;
use std::time::{Duration, Instant};

use flate2::Compression;
use flate2::write::GzEncoder;

fn temp(name: &str) -> PathBuf {
    let d = std::env::temp_dir().join(format!("gazelight-bidsgz-{name}-{}", std::process::id()));
    let _ = std::fs::remove_dir_all(&d);
    std::fs::create_dir_all(&d).unwrap();
    d
}

#[test]
fn a_gzip_bomb_of_rows_is_refused_at_its_expansion_cap() {
    let dir = temp("bomb");
    let stem = "sub-01_task-x_recording-eye1";
    std::fs::write(
        dir.join(format!("{stem}_physio.json")),
        r#"{"PhysioType": "eyetrack", "RecordedEye": "right", "SamplingFrequency": 1000,
            "StartTime": 0, "Columns": ["timestamp", "x_coordinate", "y_coordinate", "pupil_size"],
            "timestamp": {"Units": "s"}, "pupil_size": {"Units": "mm"}}"#,
    )
    .unwrap();
    // One gzip member of 1 MiB of identical valid rows, written 200 times
    // (gzip members concatenate): ~200 MiB of rows from a few hundred KiB.
    let row = b"1.0\t0.5\t0.5\t4.0\n";
    let mut chunk = Vec::new();
    while chunk.len() < 1 << 20 {
        chunk.extend_from_slice(row);
    }
    let mut enc = GzEncoder::new(Vec::new(), Compression::best());
    enc.write_all(&chunk).unwrap();
    let member = enc.finish().unwrap();
    let tsv = dir.join(format!("{stem}_physio.tsv.gz"));
    let mut f = std::fs::File::create(&tsv).unwrap();
    for _ in 0..200 {
        f.write_all(&member).unwrap();
    }
    drop(f);
    let compressed = std::fs::metadata(&tsv).unwrap().len();
    let cap = gazelight_input::ExpansionLimit::<std::io::Empty>::limit_for(compressed);
    assert!(cap < 200 << 20, "the cap {cap} must fall inside the bomb");

    let started = Instant::now();
    let mut samples = 0usize;
    let mut error = None;
    match gazelight_import::open(&tsv) {
        Err(e) => error = Some(e.to_string()),
        Ok(imp) => {
            for s in imp {
                match s {
                    Ok(_) => samples += 1,
                    Err(e) => {
                        error = Some(e.to_string());
                        break;
                    }
                }
            }
        }
    }
    let error = error.expect("the bomb was read to its end");
    assert!(error.contains("expands to more than"), "{error}");
    assert!(error.contains("physio.tsv.gz"), "{error}");
    // At most the cap's worth of rows became samples (two per row).
    assert!(
        samples as u64 <= 2 * cap / row.len() as u64 + 2,
        "{samples}"
    );
    assert!(started.elapsed() < Duration::from_secs(120));
    std::fs::remove_dir_all(&dir).unwrap();
}
