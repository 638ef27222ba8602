//! Issue 45's must-show on every shipped recording: the samples a
//! researcher would call clean leave the filter chain unchanged.
//!
//! "Clean" is defined here from the raw samples alone, independently of the
//! chain: confidence 1.0 (the tracker's own verdict; EyeLink and the PLR
//! trace give 1.0 to every sample with a pupil), more than 200 ms from any
//! lost or low-confidence sample of the same eye, and within 3 % of the
//! median of that eye's samples within ±40 ms (no spike). Such a sample's
//! measured pupil must be within 2 % of its raw value for ≥ 99 % of them,
//! and none may be reported as not measured (held).

use std::collections::VecDeque;
use std::path::Path;

use gazelight_test_support::data::data_path;
use gazelight_tracker::filter::{FilterChain, SampleFate, TrackSample};
use gazelight_tracker::import;
use gazelight_tracker::{PupilUnit, Sample};

/// One raw pupil sample of one eye, as the recording has it.
#[derive(Clone, Copy)]
struct Raw {
    t: f64,
    value: f32,
    confidence: f32,
    seq: u64,
}

/// The value the chain's measured pupil is compared with: the tracker's
/// mm where it gives mm, else its raw value (no physical scale).
fn raw_value(p: &gazelight_tracker::PupilSample) -> f32 {
    p.diameter_mm.unwrap_or(p.diameter_raw)
}

fn is_lost(r: &Raw) -> bool {
    !(r.value.is_finite() && r.value > 0.0) || r.confidence < 0.6
}

/// The clean samples of one eye by the definition above (indices into
/// `raw`, in time order).
fn clean_indices(raw: &[Raw]) -> Vec<usize> {
    let lost_t: Vec<f64> = raw.iter().filter(|r| is_lost(r)).map(|r| r.t).collect();
    let mut out = Vec::new();
    let mut lo = 0usize;
    for (i, r) in raw.iter().enumerate() {
        if r.confidence < 1.0 || is_lost(r) {
            continue;
        }
        // > 200 ms from any lost sample.
        let k = lost_t.partition_point(|&t| t < r.t);
        let near_before = k > 0 && r.t - lost_t[k - 1] <= 0.2;
        let near_after = k < lost_t.len() && lost_t[k] - r.t <= 0.2;
        if near_before || near_after {
            continue;
        }
        // Within 3 % of the ±40 ms median.
        while raw[lo].t < r.t - 0.04 {
            lo += 1;
        }
        let mut window: Vec<f32> = raw[lo..]
            .iter()
            .take_while(|x| x.t <= r.t + 0.04)
            .filter(|x| !is_lost(x))
            .map(|x| x.value)
            .collect();
        window.sort_by(f32::total_cmp);
        let median = window[window.len() / 2];
        if (r.value - median).abs() <= 0.03 * median {
            out.push(i);
        }
    }
    out
}

struct EyeReport {
    clean: usize,
    within_2pct: usize,
    held: usize,
}

/// Runs the recording through the default chain; per eye, how its clean
/// samples came out.
fn check(path: &Path) -> [EyeReport; 2] {
    let mut importer = import::open(path).unwrap_or_else(|e| panic!("{}: {e}", path.display()));
    let mut chain = FilterChain::with_defaults();
    chain.keep_decided();
    let mut raw: [Vec<Raw>; 2] = [Vec::new(), Vec::new()];
    let mut decided: Vec<TrackSample> = Vec::new();
    // Which stream the chain measures per eye: mm where the tracker gives
    // mm. Samples of other streams are not compared.
    let mut seq = 0u64;
    let mut pending: VecDeque<u64> = VecDeque::new();
    for item in &mut *importer {
        let s = item.unwrap_or_else(|e| panic!("{}: {e}", path.display()));
        if let Sample::Pupil(p) = &s
            && p.eye <= 1
            && p.t_secs.is_finite()
        {
            raw[usize::from(p.eye)].push(Raw {
                t: p.t_secs,
                value: raw_value(p),
                confidence: p.confidence,
                seq,
            });
            pending.push_back(seq);
            seq += 1;
        }
        chain.push(&s);
        decided.extend(chain.take_decided());
    }
    chain.finish(f64::MAX);
    decided.extend(chain.take_decided());
    assert_eq!(
        decided.len() as u64,
        seq,
        "{}: every pupil sample is decided once",
        path.display()
    );
    let by_seq: std::collections::HashMap<u64, TrackSample> =
        decided.iter().map(|d| (d.seq, *d)).collect();
    [0usize, 1].map(|e| {
        let mut eye_raw = raw[e].clone();
        eye_raw.sort_by(|a, b| a.t.total_cmp(&b.t));
        let clean = clean_indices(&eye_raw);
        let mut within = 0;
        let mut held = 0;
        let mut compared = 0;
        for &i in &clean {
            let r = eye_raw[i];
            let d = by_seq[&r.seq];
            if d.fate == SampleFate::OtherStream {
                continue;
            }
            compared += 1;
            if !d.fate.is_clean() {
                if held < 5 {
                    eprintln!(
                        "  not measured: t {:.4} raw {} fate {:?}",
                        r.t, r.value, d.fate
                    );
                }
                held += 1;
                continue;
            }
            if (d.value - r.value).abs() <= 0.02 * r.value {
                within += 1;
            }
        }
        EyeReport {
            clean: compared,
            within_2pct: within,
            held,
        }
    })
}

fn assert_clean_samples_pass(rel: &str, min_clean: usize) {
    let path = data_path(rel);
    let reports = check(&path);
    for (e, r) in reports.iter().enumerate() {
        if r.clean == 0 && min_clean == 0 {
            continue;
        }
        eprintln!(
            "{rel} eye {e}: {} clean samples, {} within 2 % ({:.3} %), {} not measured",
            r.clean,
            r.within_2pct,
            100.0 * r.within_2pct as f64 / r.clean.max(1) as f64,
            r.held
        );
        assert!(
            r.clean >= min_clean,
            "{rel} eye {e}: only {} clean samples",
            r.clean
        );
        assert!(
            r.within_2pct as f64 >= 0.99 * r.clean as f64,
            "{rel} eye {e}: {} of {} clean samples within 2 % of their raw value",
            r.within_2pct,
            r.clean
        );
        assert_eq!(
            r.held, 0,
            "{rel} eye {e}: clean samples reported as not measured"
        );
    }
}

#[test]
fn neon_demo_clean_samples_pass_unchanged() {
    assert_clean_samples_pass("eye/neon-demo", 500);
}

#[test]
fn eyelink_clean_samples_pass_unchanged() {
    assert_clean_samples_pass("eye/eyelink-psa/both_eyes.asc", 10_000);
}

#[test]
fn piprkit_plr_clean_samples_pass_unchanged() {
    assert_clean_samples_pass("eye/piprkit-plr/pupil_trace.csv", 10_000);
}

/// The unit the chain measures an uncalibrated EyeLink file in is the
/// tracker's own (area units), named — never mm.
#[test]
fn an_uncalibrated_eyelink_pupil_is_measured_in_its_own_unit() {
    let path = data_path("eye/eyelink-psa/both_eyes.asc");
    let mut importer = import::open(&path).expect("open");
    let mut chain = FilterChain::with_defaults();
    chain.keep_decided();
    let mut units = Vec::new();
    for item in importer.by_ref().take(20_000) {
        chain.push(&item.expect("sample"));
        for d in chain.take_decided() {
            if d.fate.is_clean() && !units.contains(&d.unit) {
                units.push(d.unit);
            }
        }
    }
    assert_eq!(units, [PupilUnit::ArbitraryArea]);
    let s = chain.state();
    assert!(
        s.eyes.iter().all(|e| e.measured_mm().is_none()),
        "no mm without a physical scale: {s:?}"
    );
}
