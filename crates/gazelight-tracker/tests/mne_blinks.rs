//! Issue 45's must-show: the interpolated pupil series (the guidelines'
//! blink interpolation, `filter::clean::interpolate_gaps` over the chain's
//! clean samples) against MNE-Python's `interpolate_blinks` with the same
//! 50 ms margins, on the shipped EyeLink recording: within 2 % of the
//! pupil's range for ≥ 99 % of the samples MNE has.
//!
//! MNE is the reference implementation outside this code: it takes the
//! blinks from EyeLink's own SBLINK/EBLINK events, we find them from the
//! samples. MNE is installed by `.ci/test`; without it the test prints
//! SKIP (fails with CI set).

use std::io::Write as _;
use std::process::Command;

use gazelight_test_support::data::data_path;
use gazelight_tracker::filter::FilterChain;
use gazelight_tracker::filter::clean::{DEFAULT_MAX_INTERPOLATED_GAP_S, interpolate_gaps};
use gazelight_tracker::import;

fn mne_available() -> bool {
    Command::new("python3")
        .args(["-c", "import mne, pandas"])
        .output()
        .is_ok_and(|o| o.status.success())
}

#[test]
fn interpolated_pupil_agrees_with_mne_interpolate_blinks() {
    if !mne_available() {
        gazelight_test_support::skip_or_fail("MNE-Python (pip install mne pandas)");
        return;
    }
    let asc = data_path("eye/eyelink-psa/both_eyes.asc");
    let mut importer = import::open(&asc).expect("open the EyeLink recording");
    let mut chain = FilterChain::with_defaults();
    let margin_s = chain.config().clean.margin_before_s;
    assert_eq!(margin_s, chain.config().clean.margin_after_s);
    chain.keep_decided();
    // Per eye: each pupil sample's time and its measured pupil (NaN where
    // it is not clean), in order.
    let mut t: [Vec<f64>; 2] = [Vec::new(), Vec::new()];
    let mut v: [Vec<f32>; 2] = [Vec::new(), Vec::new()];
    let mut take = |chain: &mut FilterChain| {
        for d in chain.take_decided() {
            let e = usize::from(d.eye & 1);
            t[e].push(d.t_secs);
            v[e].push(if d.fate.is_clean() { d.value } else { f32::NAN });
        }
    };
    for item in importer.by_ref() {
        chain.push(&item.expect("sample"));
        take(&mut chain);
    }
    chain.finish(f64::MAX);
    take(&mut chain);

    let dir = std::env::temp_dir().join(format!("gazelight-mne-{}", std::process::id()));
    std::fs::create_dir_all(&dir).expect("temp dir");
    let ours = dir.join("ours.csv");
    let mut f = std::io::BufWriter::new(std::fs::File::create(&ours).expect("csv"));
    writeln!(f, "eye,t_ms,interpolated").expect("write");
    for e in 0..2 {
        let mut interpolated = vec![false; v[e].len()];
        interpolate_gaps(
            &t[e],
            &mut v[e],
            &mut interpolated,
            DEFAULT_MAX_INTERPOLATED_GAP_S,
        );
        eprintln!(
            "eye {e}: {} samples, {} interpolated",
            v[e].len(),
            interpolated.iter().filter(|&&b| b).count()
        );
        for (ti, vi) in t[e].iter().zip(&v[e]) {
            writeln!(f, "{e},{:.1},{vi}", ti * 1e3).expect("write");
        }
    }
    drop(f);
    let script = concat!(env!("CARGO_MANIFEST_DIR"), "/tests/mne/compare_blinks.py");
    let out = Command::new("python3")
        .arg(script)
        .arg(&asc)
        .arg(&ours)
        .arg(format!("{margin_s}"))
        .output()
        .expect("run python3");
    let stdout = String::from_utf8_lossy(&out.stdout);
    assert!(
        out.status.success(),
        "compare_blinks.py failed: {}\n{stdout}",
        String::from_utf8_lossy(&out.stderr)
    );
    let _ = std::fs::remove_dir_all(&dir);
    let mut eyes = 0;
    for line in stdout.lines().filter(|l| l.starts_with('{')) {
        let r: serde_json::Value = serde_json::from_str(line).expect("json");
        let compared = r["compared"].as_f64().unwrap_or(0.0);
        let agree = r["agree"].as_f64().unwrap_or(0.0);
        eprintln!(
            "eye {}: {agree} of {compared} samples within 2 % of the range {} ({:.3} %), \
             {} left empty by gazelight, largest difference {}",
            r["eye"],
            r["range"],
            100.0 * agree / compared.max(1.0),
            r["ours_empty"],
            r["max_diff"]
        );
        assert!(compared > 60_000.0, "{line}");
        assert!(agree >= 0.99 * compared, "eye {}: {line}", r["eye"]);
        eyes += 1;
    }
    assert_eq!(eyes, 2, "{stdout}");
}
