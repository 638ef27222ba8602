#![allow(clippy::unwrap_used, clippy::expect_used)] // test code may panic on a failed setup
//! A calibration profile within the old 64 MiB text limit holding one
//! 20 M-element array (`"description": [0,0,…]`, 40 MB) took gigabytes as
//! a parsed JSON tree before its error. Profiles are now refused by size
//! (over 1 MiB) and, below that, by a scan of their structure, before any
//! tree is built: the resident set (VmRSS, sampled every 2 ms) grows by
//! less than [`RSS_BOUND_BYTES`] and the error says why.

use std::io::Write;
use std::sync::Arc;
use std::sync::atomic::{AtomicBool, AtomicU64, Ordering};
use std::time::Duration;

use gazelight_eye::profile::{PupilCalibration, SCHEMA};

/// The file itself is read whole (up to the size limit checked first from
/// its metadata): allowed growth is a few MiB of buffers, far below the
/// 20 M-element tree (≥ 640 MB of `serde_json::Value`s).
const RSS_BOUND_BYTES: u64 = 16 << 20;

fn vm_rss_bytes() -> u64 {
    let status = std::fs::read_to_string("/proc/self/status").unwrap();
    let kib: u64 = status
        .lines()
        .find(|l| l.starts_with("VmRSS:"))
        .and_then(|l| l.split_whitespace().nth(1))
        .and_then(|v| v.parse().ok())
        .expect("VmRSS in /proc/self/status");
    kib * 1024
}

/// Runs `f`, returning its result and the peak growth of VmRSS.
fn peak_growth<T>(f: impl FnOnce() -> T) -> (T, u64) {
    let start = vm_rss_bytes();
    let peak = Arc::new(AtomicU64::new(start));
    let stop = Arc::new(AtomicBool::new(false));
    let sampler = {
        let (peak, stop) = (peak.clone(), stop.clone());
        std::thread::spawn(move || {
            while !stop.load(Ordering::Relaxed) {
                peak.fetch_max(vm_rss_bytes(), Ordering::Relaxed);
                std::thread::sleep(Duration::from_millis(2));
            }
        })
    };
    let r = f();
    peak.fetch_max(vm_rss_bytes(), Ordering::Relaxed);
    stop.store(true, Ordering::Relaxed);
    sampler.join().unwrap();
    (r, peak.load(Ordering::Relaxed).saturating_sub(start))
}

/// A profile whose `description` is an array of `n` zeros.
fn write_profile(path: &std::path::Path, n: usize) {
    let mut f = std::io::BufWriter::new(std::fs::File::create(path).unwrap());
    write!(
        f,
        "{{\"schema\": \"{SCHEMA}\", \"eyes\": {{}}, \"description\": [0"
    )
    .unwrap();
    for _ in 1..n {
        f.write_all(b",0").unwrap();
    }
    f.write_all(b"]}\n").unwrap();
}

#[test]
fn a_profile_with_a_huge_array_is_refused_before_it_is_built() {
    let dir = std::env::temp_dir().join(format!("gazelight-profile-bounds-{}", std::process::id()));
    std::fs::create_dir_all(&dir).unwrap();

    // 20 M elements, 40 MB: within the old 64 MiB limit.
    let big = dir.join("big.json");
    write_profile(&big, 20_000_000);
    assert!(std::fs::metadata(&big).unwrap().len() < 64 << 20);
    let (r, grew) = peak_growth(|| PupilCalibration::load(&big));
    let e = r.expect_err("a 40 MB profile is refused").to_string();
    eprintln!("20 M elements: {e}; VmRSS peak +{grew} bytes");
    assert!(e.contains("limit"), "{e}");
    assert!(grew < RSS_BOUND_BYTES, "VmRSS grew {grew} bytes");

    // 400 k elements, 800 kB: under the size limit, refused by the scan.
    let mid = dir.join("mid.json");
    write_profile(&mid, 400_000);
    assert!(std::fs::metadata(&mid).unwrap().len() < 1 << 20);
    let (r, grew) = peak_growth(|| PupilCalibration::load(&mid));
    let e = r.expect_err("400 k values are refused").to_string();
    eprintln!("400 k elements: {e}; VmRSS peak +{grew} bytes");
    assert!(e.contains("values"), "{e}");
    assert!(grew < RSS_BOUND_BYTES, "VmRSS grew {grew} bytes");

    // A valid profile still loads.
    let good = dir.join("good.json");
    std::fs::write(
        &good,
        format!(
            "{{\"schema\": \"{SCHEMA}\", \"description\": \"GP3, room light\", \"eyes\": {{\"right\": \
             {{\"raw_unit\": \"px\", \"raw_black\": 40.0, \"raw_white\": 20.0, \"mm_min\": 2.0, \"mm_max\": 8.0}}}}}}"
        ),
    )
    .unwrap();
    PupilCalibration::load(&good).unwrap();
    let _ = std::fs::remove_dir_all(&dir);
}
