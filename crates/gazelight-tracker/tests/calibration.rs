#![allow(clippy::unwrap_used, clippy::expect_used)] // test and bench code may panic on a failed setup
//! The black/white pupil calibration (001 §5): synthetic sessions with a
//! known answer, each failure case, a replay of a real flash, and the
//! profile format.

use std::path::PathBuf;

use gazelight_tracker::calibration::{
    CalibrationConfig, CalibrationError, LogSink, Phase, Stimulus, StimulusError, StimulusSink,
    run_calibration, run_calibration_source,
};
use gazelight_tracker::import;
use gazelight_tracker::profile::PupilCalibration;
use gazelight_tracker::source::{Pacing, ReplaySource};
use gazelight_tracker::synthetic::black_white_session;
use gazelight_tracker::{PupilUnit, Sample};

fn tmp(name: &str) -> PathBuf {
    let dir = std::env::temp_dir().join(format!("gazelight-cal-{}-{name}", std::process::id()));
    std::fs::create_dir_all(&dir).unwrap();
    dir.join("profile.json")
}

#[test]
fn synthetic_px_session_gives_the_expected_mapping() {
    // 2D-detector pixels: 12 px/mm; dark 7 mm = 84 px, bright 3 mm = 36 px;
    // the left eye is 0.3 mm larger. Noise 0.1 mm, a 200 ms blink per phase.
    let samples = black_white_session(3, 5.0, 7.0, 3.0, PupilUnit::Px, 12.0, 0.1, 0.3);
    let path = tmp("ok");
    let mut sink = LogSink::default();
    let cal = run_calibration(
        CalibrationConfig::default(),
        samples.iter().copied(),
        &mut sink,
        Some(&path),
    )
    .unwrap();
    // Stimulus log: black at the first sample, white 5 s later, then none.
    let kinds: Vec<Stimulus> = sink.shown.iter().map(|s| s.1).collect();
    assert_eq!(kinds, [Stimulus::Black, Stimulus::White, Stimulus::None]);
    assert!((sink.shown[1].0 - sink.shown[0].0 - 5.0).abs() < 1e-9);
    assert!((sink.shown[2].0 - sink.shown[0].0 - 10.0).abs() < 1e-9);
    for (eye, c) in [(0, cal.eyes.right.unwrap()), (1, cal.eyes.left.unwrap())] {
        let aniso = 0.3 * eye as f64;
        // The session starts half-adapted (5 mm). Dilation (τ 1.5 s) is
        // still 2·e^(−t/1.5) mm short of 7 mm at the middle of the analysis
        // window (t = 3.5 s, after the 2 s settle), constriction (τ 0.3 s)
        // is complete: the medians are those first-order values ± noise.
        let black_mm = 7.0 - 2.0 * (-3.5f64 / 1.5).exp();
        assert!(
            (c.raw_black - (black_mm + aniso) * 12.0).abs() < 0.5,
            "{c:?}"
        );
        assert!((c.raw_white - (3.0 + aniso) * 12.0).abs() < 0.5, "{c:?}");
        assert_eq!(c.raw_unit, PupilUnit::Px);
        assert_eq!((c.mm_min, c.mm_max), (2.0, 8.0));
        // The map: black → 8, white → 2, midpoint → 5.
        assert!((c.map(c.raw_black).unwrap() - 8.0).abs() < 1e-9);
        assert!((c.map(0.5 * (c.raw_black + c.raw_white)).unwrap() - 5.0).abs() < 1e-9);
    }
    // Saved, and loads back identical.
    let back = PupilCalibration::load(&path).unwrap();
    assert_eq!(back, cal);
    let text = std::fs::read_to_string(&path).unwrap();
    assert!(text.contains("\"schema\": \"gazelight.pupil-calibration/2\""));
}

#[test]
fn white_first_order_is_supported() {
    // The same synthetic pupil, but the session is configured white first:
    // then the stimulus doesn't match the pupil and it must fail.
    let samples = black_white_session(4, 5.0, 7.0, 3.0, PupilUnit::Px, 12.0, 0.1, 0.0);
    let cfg = CalibrationConfig {
        order: [Phase::White, Phase::Black],
        ..Default::default()
    };
    let mut sink = LogSink::default();
    let err = run_calibration(cfg, samples, &mut sink, None).unwrap_err();
    assert!(
        matches!(err, CalibrationError::WhiteNotSmaller { .. }),
        "{err}"
    );
    assert_eq!(sink.shown[0].1, Stimulus::White);
}

#[test]
fn too_few_valid_samples_fails_and_writes_nothing() {
    // Lose 70 % of the right eye's white-phase samples (confidence 0).
    let mut samples = black_white_session(5, 5.0, 7.0, 3.0, PupilUnit::Px, 12.0, 0.1, 0.0);
    let t0 = samples[0].t_secs();
    for (i, s) in samples.iter_mut().enumerate() {
        if let Sample::Pupil(p) = s
            && p.eye == 0
            && p.t_secs - t0 >= 5.0
            && i % 10 < 7
        {
            p.confidence = 0.0;
        }
    }
    let path = tmp("few");
    let err = run_calibration(
        CalibrationConfig::default(),
        samples,
        &mut LogSink::default(),
        Some(&path),
    )
    .unwrap_err();
    match err {
        CalibrationError::TooFewValidSamples {
            eye,
            phase,
            valid_fraction,
            required,
        } => {
            assert_eq!((eye, phase, required), (0, Phase::White, 0.5));
            assert!(valid_fraction < 0.4, "{valid_fraction}");
        }
        other => panic!("{other}"),
    }
    assert!(!path.exists(), "nothing written on failure");
}

#[test]
fn no_constriction_fails_with_white_not_smaller_and_writes_nothing() {
    // The pupil ignores the stimulus (e.g. the display stayed dark).
    let samples = black_white_session(6, 5.0, 6.0, 6.0, PupilUnit::Px, 12.0, 0.1, 0.0);
    let path = tmp("flat");
    let err = run_calibration(
        CalibrationConfig::default(),
        samples,
        &mut LogSink::default(),
        Some(&path),
    )
    .unwrap_err();
    let CalibrationError::WhiteNotSmaller { eye, black, white } = err else {
        panic!("{err}")
    };
    assert_eq!(eye, 0);
    assert!((black - 72.0).abs() < 1.0 && (white - 72.0).abs() < 1.0);
    assert!(err.to_string().contains("constrict"));
    assert!(!path.exists());
}

#[test]
fn a_failing_sink_aborts() {
    struct Broken;
    impl StimulusSink for Broken {
        fn show(&mut self, _: Stimulus, _: f64) -> Result<(), StimulusError> {
            Err(StimulusError("display gone".into()))
        }
    }
    let samples = black_white_session(7, 5.0, 7.0, 3.0, PupilUnit::Px, 12.0, 0.1, 0.0);
    let sink: &mut dyn StimulusSink = &mut Broken;
    let err = run_calibration(CalibrationConfig::default(), samples, sink, None).unwrap_err();
    assert!(matches!(err, CalibrationError::Sink(ref m) if m == "display gone"));
}

#[test]
fn piprkit_flash_replayed_as_a_black_white_session() {
    // The piprkit subject saw darkness, then a flash at 8.06 s; the pupil
    // constricts to its minimum within ~3 s. Treat the 5 s before the flash
    // as "black" and the 3 s after its onset as "white" (settle 1.5 s).
    let data = gazelight_test_support::data_path("eye/piprkit-plr");
    let flash = import::csv::load_stimuli(&data.join("stimuli.csv")).unwrap()[0];
    let start = flash.start_t_secs - 5.0;
    let samples: Vec<Sample> = import::open(&data.join("pupil_trace.csv"))
        .unwrap()
        .map(|s| s.unwrap())
        .filter(|s| s.t_secs() >= start)
        .collect();
    // Independent expectation straight from the file: medians of the raw
    // right-eye pupil in the analysis windows.
    let window_median = |a: f64, b: f64| {
        let mut v: Vec<f64> = samples
            .iter()
            .filter_map(|s| match s {
                Sample::Pupil(p) if p.eye == 0 && p.t_secs >= a && p.t_secs < b => {
                    Some(p.diameter_raw as f64)
                }
                _ => None,
            })
            .collect();
        v.sort_by(f64::total_cmp);
        v[v.len() / 2]
    };
    let cfg = CalibrationConfig {
        order: [Phase::Black, Phase::White],
        phase_duration_s: 5.0,
        settle_s: 1.5,
        ..Default::default()
    };
    let t0 = samples[0].t_secs();
    let expect_black = window_median(t0 + 1.5, t0 + 5.0);
    let expect_white = window_median(t0 + 6.5, t0 + 10.0);
    let cal = run_calibration(cfg, samples.iter().copied(), &mut LogSink::default(), None).unwrap();
    let right = cal.eyes.right.unwrap();
    assert_eq!(right.raw_unit, PupilUnit::Mm);
    assert!(
        (right.raw_black - expect_black).abs() < 0.02,
        "{right:?} vs {expect_black}"
    );
    assert!(
        (right.raw_white - expect_white).abs() < 0.02,
        "{right:?} vs {expect_white}"
    );
    assert!(
        right.raw_black > 5.5 && right.raw_white < right.raw_black - 0.8,
        "{right:?}"
    );
}

#[test]
fn profile_validation_names_the_field() {
    let dir = tmp("bad");
    let good = r#"{"schema": "gazelight.pupil-calibration/1",
        "eyes": {"right": {"raw_unit": "px", "raw_black": 80.0, "raw_white": 35.0, "mm_min": 2.0, "mm_max": 8.0}}}"#;
    let cal = PupilCalibration::parse(good, &dir).unwrap();
    assert!(cal.eyes.left.is_none());
    let cases = [
        (good.replace("/1", "/9"), "schema"),
        (good.replace("35.0", "90.0"), "eyes.right.raw_white"),
        (
            good.replace("\"mm_min\": 2.0", "\"mm_min\": 9.0"),
            "eyes.right.mm_min",
        ),
        (good.replace("80.0", "-1"), "eyes.right.raw_black"),
        (good.replace("\"raw_white\": 35.0, ", ""), "raw_white"),
        (good.replace("\"px\"", "\"furlongs\""), "raw_unit"),
    ];
    for (text, field) in cases {
        let e = PupilCalibration::parse(&text, &dir)
            .unwrap_err()
            .to_string();
        assert!(e.contains(field), "expected `{field}` in: {e}");
        assert!(e.contains("profile.json"), "names the file: {e}");
    }
}

#[test]
fn the_chain_uses_the_calibration() {
    use gazelight_tracker::filter::{FilterChain, FilterConfig};
    let cal = PupilCalibration::parse(
        r#"{"schema": "gazelight.pupil-calibration/1",
            "eyes": {"right": {"raw_unit": "px", "raw_black": 80.0, "raw_white": 35.0, "mm_min": 2.0, "mm_max": 8.0}}}"#,
        &PathBuf::from("p.json"),
    )
    .unwrap();
    let mut chain = FilterChain::new(FilterConfig::default(), cal).unwrap();
    // 57.5 px is the midpoint → 5 mm.
    for i in 0..400 {
        chain.push(&Sample::Pupil(gazelight_tracker::PupilSample {
            t_secs: i as f64 * 0.005,
            eye: 0,
            diameter_raw: 57.5,
            unit: PupilUnit::Px,
            diameter_mm: None,
            confidence: 0.99,
            norm_pos: [0.5, 0.5],
            method: gazelight_tracker::DetectorMethod::Pupil2d,
        }));
    }
    assert!((chain.state().eyes[0].pupil_mm - 5.0).abs() < 1e-4);
    assert_eq!(chain.stats().uncalibrated, [0, 0]);
}

#[tokio::test]
async fn async_driver_matches_the_sync_one_and_fails_on_a_short_source() {
    let samples = black_white_session(3, 5.0, 7.0, 3.0, PupilUnit::Px, 12.0, 0.1, 0.3);
    let mut sync_sink = LogSink::default();
    let want = run_calibration(
        CalibrationConfig::default(),
        samples.iter().copied(),
        &mut sync_sink,
        None,
    )
    .unwrap();
    let items = samples.iter().copied().map(Ok::<Sample, std::io::Error>);
    let mut source = ReplaySource::new("session", items, Pacing::AsFastAsPossible);
    let mut sink = LogSink::default();
    let path = tmp("async");
    let got = run_calibration_source(
        CalibrationConfig::default(),
        &mut source,
        &mut sink,
        Some(&path),
    )
    .await
    .unwrap();
    assert_eq!(got, want);
    assert_eq!(sink, sync_sink);
    assert_eq!(PupilCalibration::load(&path).unwrap(), want);

    // The stream ends in the white phase: an error naming the source, and
    // no file.
    let end = samples[0].t_secs() + 7.0;
    let short: Vec<_> = samples
        .iter()
        .copied()
        .filter(|s| s.t_secs() < end)
        .map(Ok::<Sample, std::io::Error>)
        .collect();
    let mut source = ReplaySource::new("short", short.into_iter(), Pacing::AsFastAsPossible);
    let path = tmp("async-short");
    let _ = std::fs::remove_file(&path);
    let err = run_calibration_source(
        CalibrationConfig::default(),
        &mut source,
        &mut LogSink::default(),
        Some(&path),
    )
    .await
    .unwrap_err();
    assert!(matches!(err, CalibrationError::Source(_)), "{err}");
    assert!(err.to_string().contains("replay of short"), "{err}");
    assert!(!path.exists());
}

#[test]
fn summary_reports_each_phase_and_eye() {
    use gazelight_tracker::calibration::{CalibrationSession, Progress};
    // Same synthetic session as above: 7 mm dark, 3 mm bright at 12 px/mm.
    let samples = black_white_session(3, 5.0, 7.0, 3.0, PupilUnit::Px, 12.0, 0.1, 0.3);
    let mut session = CalibrationSession::new(CalibrationConfig::default()).unwrap();
    let mut sink = LogSink::default();
    for s in &samples {
        if let Sample::Pupil(p) = s
            && session.feed(p, &mut sink).unwrap() == Progress::Done
        {
            break;
        }
    }
    let summary = session.summary();
    assert_eq!(summary.len(), 4, "{summary:?}");
    let cal = session.finish().unwrap();
    for s in &summary {
        assert!(s.samples > 0 && s.valid <= s.samples);
        // The 200 ms blink per phase is excluded; most samples are valid.
        assert!(
            s.valid_fraction() > 0.8 && s.valid_fraction() < 1.0,
            "{s:?}"
        );
        assert!(s.raw_min <= s.raw_median && s.raw_median <= s.raw_max);
        let c = if s.eye == 0 {
            cal.eyes.right
        } else {
            cal.eyes.left
        }
        .unwrap();
        let expected = match s.phase {
            Phase::Black => c.raw_black,
            Phase::White => c.raw_white,
        };
        assert_eq!(s.raw_median, expected, "summary median = profile value");
    }
}

fn px_map() -> gazelight_tracker::profile::EyeCalibration {
    gazelight_tracker::profile::EyeCalibration {
        kind: gazelight_tracker::profile::MapKind::Aperture,
        raw_unit: PupilUnit::Px,
        raw_black: 60.0,
        raw_white: 20.0,
        mm_min: 2.0,
        mm_max: 8.0,
    }
}

#[test]
fn the_map_is_the_line_through_the_phases_not_clamped_at_them() {
    use gazelight_tracker::profile::EyeCalibration;
    let c = px_map();
    // Inside the phases' pupils the line itself (001 §5):
    // 8 + (40 − 60)·(2 − 8)/(20 − 60) = 5 mm.
    assert!((c.map(40.0).unwrap() - 5.0).abs() < 1e-12);
    // Beyond them the same line (the filter chain bounds the aperture by
    // the physiological range and counts what falls outside): a pupil
    // larger than in the black phase is not pinned at the black phase's
    // 8 mm. Raw 70 px: 8 + 10·6/40 = 9.5 mm; raw 15 px: 2 − 5·6/40 = 1.25.
    assert!((c.map(70.0).unwrap() - 9.5).abs() < 1e-12);
    assert!((c.map(15.0).unwrap() - 1.25).abs() < 1e-12);
    // The profile's own range, not 2–8 mm, when it configures another:
    // raw 60 → 7 mm, raw 20 → 3 mm.
    let narrow = EyeCalibration {
        mm_min: 3.0,
        mm_max: 7.0,
        ..c
    };
    assert!((narrow.map(60.0).unwrap() - 7.0).abs() < 1e-12);
    assert!((narrow.map(20.0).unwrap() - 3.0).abs() < 1e-12);
}

#[test]
fn a_raw_pupil_at_or_below_zero_is_rejected_before_mapping() {
    use gazelight_tracker::DetectorMethod;
    use gazelight_tracker::profile::{BadRawPupil, EyeCalibrations};
    let c = px_map();
    assert_eq!(c.map(0.0), Err(BadRawPupil::NonPositive));
    assert_eq!(c.map(-3.0), Err(BadRawPupil::NonPositive));
    assert_eq!(c.map(f64::NAN), Err(BadRawPupil::NotFinite));
    assert_eq!(c.map(f64::INFINITY), Err(BadRawPupil::NotFinite));
    // Raw 0 would map to 8 + 60·6/40 = 17 mm: a blink must never read as a
    // (wide) pupil, so it is rejected before the map.
    let mut cal = PupilCalibration::identity();
    cal.eyes = EyeCalibrations {
        right: Some(c),
        left: None,
    };
    let sample = |raw: f32| gazelight_tracker::PupilSample {
        t_secs: 1.0,
        eye: 0,
        diameter_raw: raw,
        unit: PupilUnit::Px,
        diameter_mm: None,
        confidence: 1.0,
        norm_pos: [0.5, 0.5],
        method: DetectorMethod::Pupil2d,
    };
    assert_eq!(cal.aperture_mm(&sample(0.0)), Err(BadRawPupil::NonPositive));
    assert_eq!(
        cal.aperture_mm(&sample(-1.0)),
        Err(BadRawPupil::NonPositive)
    );
    assert_eq!(
        cal.aperture_mm(&sample(f32::NAN)),
        Err(BadRawPupil::NotFinite)
    );
    assert_eq!(cal.aperture_mm(&sample(40.0)), Ok(Some(5.0)));
    // An aperture map is not a measurement: the measured pupil stays raw px.
    assert_eq!(cal.measured(&sample(40.0)), (40.0, PupilUnit::Px));
    // Area units: √area of a negative area is not a pupil either.
    let mut area = sample(-4.0);
    area.unit = PupilUnit::ArbitraryArea;
    cal.eyes.right = Some(gazelight_tracker::profile::EyeCalibration {
        kind: gazelight_tracker::profile::MapKind::Aperture,
        raw_unit: PupilUnit::ArbitraryArea,
        ..c
    });
    assert!(cal.aperture_mm(&area).is_err());
}

#[test]
fn profiles_carry_the_observer_and_version_1_still_loads() {
    use gazelight_tracker::profile::{Observer, SCHEMA};
    let eyes = r#""eyes": {"right": {"raw_unit": "px", "raw_black": 60, "raw_white": 20, "mm_min": 2, "mm_max": 8}}"#;
    let path = std::path::Path::new("profile.json");
    // Version 1: no observer → CIE 146 defaults 25 years, 0.5.
    let v1 = format!(r#"{{"schema": "gazelight.pupil-calibration/1", {eyes}}}"#);
    let cal = PupilCalibration::parse(&v1, path).unwrap();
    assert_eq!(cal.observer.age_years, 25.0);
    assert_eq!(cal.observer.pigmentation, 0.5);
    assert_eq!(cal.schema, SCHEMA);
    // Version 2 with an observer.
    let v2 = format!(
        r#"{{"schema": "gazelight.pupil-calibration/2", "observer": {{"age_years": 70, "pigmentation": 1.0}}, {eyes}}}"#
    );
    let cal = PupilCalibration::parse(&v2, path).unwrap();
    assert_eq!(
        cal.observer,
        Observer {
            age_years: 70.0,
            pigmentation: 1.0
        }
    );
    // Round trip through save/load.
    let file = tmp("observer");
    cal.save(&file).unwrap();
    let back = PupilCalibration::load(&file).unwrap();
    assert_eq!(back, cal);
    let text = std::fs::read_to_string(&file).unwrap();
    assert!(text.contains("\"gazelight.pupil-calibration/2\""), "{text}");
    // Partial observer: the other field defaults.
    let partial = format!(
        r#"{{"schema": "gazelight.pupil-calibration/2", "observer": {{"age_years": 40}}, {eyes}}}"#
    );
    let cal = PupilCalibration::parse(&partial, path).unwrap();
    assert_eq!(
        (cal.observer.age_years, cal.observer.pigmentation),
        (40.0, 0.5)
    );
    // Errors name the field.
    for (observer, field) in [
        (r#"{"pigmentation": 1.5}"#, "observer.pigmentation"),
        (r#"{"age_years": -3}"#, "observer.age_years"),
        (r#"{"age_years": "old"}"#, "observer.age_years"),
        (r#"{"iris": 1}"#, "observer.iris"),
        (r#"[]"#, "observer"),
    ] {
        let text = format!(
            r#"{{"schema": "gazelight.pupil-calibration/2", "observer": {observer}, {eyes}}}"#
        );
        let err = PupilCalibration::parse(&text, path)
            .unwrap_err()
            .to_string();
        assert!(err.contains(&format!("`{field}`")), "{observer}: {err}");
    }
    let v1_with_observer = format!(
        r#"{{"schema": "gazelight.pupil-calibration/1", "observer": {{"age_years": 30}}, {eyes}}}"#
    );
    let err = PupilCalibration::parse(&v1_with_observer, path)
        .unwrap_err()
        .to_string();
    assert!(err.contains("`observer`"), "{err}");
}
