#![allow(clippy::unwrap_used, clippy::expect_used)] // test and bench code may panic on a failed setup
//! Replays of the three real recordings in `shared/data/eye` through the
//! importers and the filter chain.

use std::path::PathBuf;

use gazelight_eye::filter::{FilterChain, FilterConfig};
use gazelight_eye::profile::{EyeCalibration, EyeCalibrations, PupilCalibration, SCHEMA};
use gazelight_eye::{GazeEyes, PupilOrigin, PupilUnit, Sample};
use gazelight_import::{self as import, Importer};

fn data(rel: &str) -> PathBuf {
    gazelight_test_support::data_path("eye").join(rel)
}

/// What a replay saw.
#[derive(Default)]
struct Replay {
    samples: Vec<Sample>,
    /// Per update: (chain time, [aperture right, aperture left], whether
    /// each eye has had its first measurement).
    outputs: Vec<(f64, [f32; 2], [bool; 2])>,
    /// (eye, t, filtered pupil) right after each pupil sample of that eye.
    per_eye: Vec<(u8, f64, f32)>,
}

fn replay(mut imp: Box<dyn Importer + Send>, chain: &mut FilterChain) -> Replay {
    let mut r = Replay::default();
    for s in imp.by_ref() {
        let s = s.expect("no structure error in the real recordings");
        let up = chain.push(&s);
        let started = |e: usize| up.state.eyes[e].pupil_origin != PupilOrigin::Default;
        r.outputs.push((
            up.state.t_secs,
            [up.state.eyes[0].pupil_mm, up.state.eyes[1].pupil_mm],
            [started(0), started(1)],
        ));
        if let Some(e) = up.pupil_eye {
            r.per_eye
                .push((e, up.state.t_secs, up.state.eyes[e as usize].pupil_mm));
        }
        r.samples.push(s);
    }
    let t_end = r.outputs.last().map_or(0.0, |o| o.0);
    chain.finish(t_end);
    assert_eq!(imp.warnings().skipped_records, 0, "{:?}", imp.warnings());
    r
}

/// No output aperture is 0/NaN and none changes faster than the bound
/// (after its first measurement, where it starts rather than easing in
/// from a made-up default).
fn assert_physiological(r: &Replay, chain: &FilterChain) {
    let max_rate = chain.config().physio.max_rate_mm_per_s;
    assert_eq!(chain.stats().invalid_output, 0);
    for w in r.outputs.windows(2) {
        let ((t0, p0, s0), (t1, p1, _)) = (w[0], w[1]);
        for e in 0..2 {
            assert!(
                p1[e].is_finite() && p1[e] > 0.0,
                "eye {e} at {t1}: {}",
                p1[e]
            );
            if !s0[e] {
                continue;
            }
            let dt = (t1 - t0) as f32;
            assert!(
                (p1[e] - p0[e]).abs() <= max_rate * dt + 1e-4,
                "eye {e}: {} → {} in {dt} s at t = {t1}",
                p0[e],
                p1[e]
            );
        }
    }
}

#[test]
fn neon_blinks_match_the_recordings_blinks_file() {
    let imp = import::open(&data("neon-demo")).unwrap();
    assert_eq!(imp.format(), "neon");
    let mut chain = FilterChain::with_defaults();
    let r = replay(imp, &mut chain);
    let pupils = r
        .samples
        .iter()
        .filter(|s| matches!(s, Sample::Pupil(_)))
        .count();
    let gaze = r
        .samples
        .iter()
        .filter(|s| matches!(s, Sample::Gaze(g) if g.eyes == GazeEyes::Binocular))
        .count();
    let per_eye_gaze = r
        .samples
        .iter()
        .filter(|s| matches!(s, Sample::Gaze(g) if g.eyes != GazeEyes::Binocular))
        .count();
    assert_eq!(
        pupils,
        2 * 1788,
        "eye_state: 143040 B / 80 B per record, 2 eyes"
    );
    assert_eq!(gaze, 1788);
    // One gaze per eye and eye_state row (from the optical axes).
    assert_eq!(per_eye_gaze, 2 * 1788);
    // The recording's own blinks: 2, both eyes.
    let stats = *chain.stats();
    eprintln!("neon: {stats:?}");
    assert_eq!(stats.source_blinks, [0, 0, 2]);
    for e in 0..2 {
        assert!(
            stats.blinks[e].abs_diff(2) <= 1,
            "eye {e}: {} blinks detected, the recording has 2 ({stats:?})",
            stats.blinks[e]
        );
    }
    // Neon pupils are ~3–4 mm: every sample outside the blinks is measured
    // (nothing else rejected as implausible).
    assert!(
        stats.measured[0] > 1600 && stats.measured[1] > 1600,
        "{stats:?}"
    );
    assert_physiological(&r, &chain);
}

#[test]
fn eyelink_blinks_match_sblink_eblink_per_eye() {
    // Pass 1 (test only): the equivalent diameters √area of the recording,
    // to build a calibration. The session ("psa_dark_vs_bright") alternates
    // dark and bright screens, so the 2nd/98th percentiles of √area stand in
    // for the white/black phases of 001 §5, mapped onto 3/7 mm — a plausible
    // range for a dark-vs-bright screen. The blink detector itself is
    // units-agnostic and does not depend on this.
    let path = data("eyelink-psa/both_eyes.asc");
    let mut eq_diam: [Vec<f64>; 2] = [Vec::new(), Vec::new()];
    for s in import::open(&path).unwrap() {
        if let Sample::Pupil(p) = s.unwrap()
            && p.diameter_raw > 0.0
        {
            assert_eq!(p.unit, PupilUnit::ArbitraryArea);
            eq_diam[p.eye as usize].push(PupilCalibration::raw_value(&p));
        }
    }
    let mut maps = [None; 2];
    for e in 0..2 {
        let v = &mut eq_diam[e];
        v.sort_by(f64::total_cmp);
        let q = |f: f64| v[((v.len() - 1) as f64 * f) as usize];
        maps[e] = Some(EyeCalibration {
            kind: gazelight_eye::profile::MapKind::Aperture,
            raw_unit: PupilUnit::ArbitraryArea,
            raw_black: q(0.98),
            raw_white: q(0.02),
            mm_min: 3.0,
            mm_max: 7.0,
        });
    }
    let cal = PupilCalibration {
        schema: SCHEMA.into(),
        description: Some("percentile calibration of the PSA recording".into()),
        observer: Default::default(),
        eyes: EyeCalibrations {
            right: maps[0],
            left: maps[1],
        },
    };
    cal.validate().unwrap();
    let mut chain = FilterChain::new(FilterConfig::default(), cal).unwrap();
    let r = replay(import::open(&path).unwrap(), &mut chain);
    let stats = *chain.stats();
    eprintln!("eyelink: {stats:?}");
    // EBLINK lines: 10 per eye (R = eye 0, L = eye 1).
    assert_eq!(stats.source_blinks, [10, 10, 0]);
    for e in 0..2 {
        assert!(
            stats.blinks[e].abs_diff(stats.source_blinks[e]) <= 1,
            "eye {e}: detected {} vs EyeLink {} ({stats:?})",
            stats.blinks[e],
            stats.source_blinks[e]
        );
    }
    assert_physiological(&r, &chain);
    assert!(
        stats.measured[0] > 60_000 && stats.measured[1] > 60_000,
        "{stats:?}"
    );
}

#[test]
fn piprkit_flash_constrictions_are_preserved() {
    let imp = import::open(&data("piprkit-plr/pupil_trace.csv")).unwrap();
    let flashes = import::csv::load_stimuli(&data("piprkit-plr/stimuli.csv")).unwrap();
    assert_eq!(flashes.len(), 6);
    let mut chain = FilterChain::with_defaults();
    let r = replay(imp, &mut chain);
    assert_physiological(&r, &chain);
    let raw: Vec<(u8, f64, f32)> = r
        .samples
        .iter()
        .filter_map(|s| match s {
            Sample::Pupil(p) => Some((p.eye, p.t_secs, p.diameter_raw)),
            _ => None,
        })
        .collect();
    let window_min = |series: &[(u8, f64, f32)], eye: u8, t0: f64, t1: f64| {
        series
            .iter()
            .filter(|(e, t, _)| *e == eye && *t >= t0 && *t <= t1)
            .map(|s| s.2)
            .fold(f32::INFINITY, f32::min)
    };
    for f in &flashes {
        // The constriction peaks within ~3 s of the flash; recovery takes
        // tens of seconds, so 10 s after its start holds the minimum.
        let (t0, t1) = (f.start_t_secs, f.start_t_secs + 10.0);
        for eye in 0..2u8 {
            let raw_min = window_min(&raw, eye, t0, t1);
            let filt_min = window_min(&r.per_eye, eye, t0, t1);
            eprintln!(
                "flash at {:.1} s, eye {eye}: raw min {raw_min:.3} mm, filtered min {filt_min:.3} mm",
                f.start_t_secs
            );
            assert!(raw_min < 4.0, "the raw trace constricts: {raw_min}");
            assert!(
                (filt_min - raw_min).abs() <= 0.2,
                "flash at {} s, eye {eye}: filtered min {filt_min} vs raw {raw_min}",
                f.start_t_secs
            );
        }
    }
}

#[test]
fn inspect_summaries_of_the_three_recordings() {
    use gazelight_import::summary::summarize_importer;
    for (rel, rate_hz) in [
        ("neon-demo", 200.0),
        ("eyelink-psa/both_eyes.asc", 500.0),
        ("piprkit-plr/pupil_trace.csv", 200.0),
    ] {
        let mut imp = import::open(&data(rel)).unwrap();
        let s = summarize_importer(imp.as_mut(), FilterChain::with_defaults()).unwrap();
        eprintln!("{rel}:\n{s}\n");
        assert_eq!(s.invalid_after_filter, 0);
        assert_eq!(s.skipped_records, 0);
        for e in 0..2 {
            assert!(
                (s.rate_hz.pupil[e] - rate_hz).abs() < 0.05 * rate_hz,
                "{rel} eye {e}: {} Hz",
                s.rate_hz.pupil[e]
            );
        }
    }
}
