#![allow(clippy::unwrap_used, clippy::expect_used)] // test code may panic on a failed setup
//! Any input sequence — NaN, ±∞, negative luminances and areas, eyes lit
//! or not, time going back, NaN times, huge gaps — gives a finite
//! prediction within [PUPIL_MIN_MM, PUPIL_MAX_MM] and never panics; the fit
//! on garbage returns `Ok` or `Err`, never panics.

use gazelight_eye::pupil_response::{
    Adaptation, Dynamics, EyeInput, EyeLight, FitOptions, ObserverRange, PUPIL_MAX_MM,
    PUPIL_MIN_MM, PupilLightResponse, PupilRow, ResponseParams, fit_observer,
};
use proptest::prelude::*;

fn any_f64() -> impl Strategy<Value = f64> {
    prop_oneof![
        Just(f64::NAN),
        Just(f64::INFINITY),
        Just(f64::NEG_INFINITY),
        Just(0.0),
        Just(-1.0),
        Just(f64::MAX),
        Just(f64::MIN_POSITIVE),
        -1e3..1e6f64,
        (0.0..12.0f64).prop_map(|e| 10f64.powf(e - 4.0)),
    ]
}

fn eye() -> impl Strategy<Value = EyeInput> {
    (any_f64(), any_f64(), any_f64(), any::<bool>()).prop_map(|(g, f, a, lit)| EyeInput {
        gaze_luminance_cd_m2: g,
        field_mean_luminance_cd_m2: f,
        field_area_deg2: a,
        lit,
    })
}

fn dt() -> impl Strategy<Value = f64> {
    prop_oneof![
        4 => 0.0..0.05f64,
        1 => Just(0.0),
        1 => -100.0..0.0f64,
        1 => Just(1e12),
        1 => Just(f64::NAN),
        1 => Just(f64::INFINITY),
        1 => 1.0..1e6f64,
    ]
}

fn params() -> impl Strategy<Value = ResponseParams> {
    (
        0.01..2.0f64,
        0.01..10.0f64,
        0.01..60.0f64,
        0.0..1.0f64,
        0.0..120.0f64,
        0.01..10.0f64,
        -20.0..20.0f64,
    )
        .prop_map(|(l, tc, td, w, age, s, o)| ResponseParams {
            adaptation: Adaptation {
                gaze_weight: w,
                age_years: age,
            },
            dynamics: Dynamics {
                latency_secs: l,
                constriction_tau_secs: tc,
                redilation_tau_secs: td,
            },
            range: ObserverRange {
                scale: s,
                offset_mm: o,
            },
        })
}

proptest! {
    #![proptest_config(ProptestConfig::with_cases(256))]

    #[test]
    fn any_sequence_gives_a_bounded_finite_pupil(
        p in params(),
        steps in proptest::collection::vec((dt(), eye(), eye()), 1..300),
        t0 in prop_oneof![Just(0.0), -1e9..1e9f64, Just(f64::NAN)],
    ) {
        let mut m = PupilLightResponse::new(p).unwrap();
        let mut t = t0;
        for (d, r, l) in steps {
            t += d;
            if !t.is_finite() {
                t = 0.0;
            }
            let out = m.step(if d.is_nan() { f64::NAN } else { t }, &EyeLight { eyes: [r, l] });
            prop_assert!(out.is_finite(), "{out}");
            prop_assert!((PUPIL_MIN_MM..=PUPIL_MAX_MM).contains(&out), "{out}");
        }
    }

    #[test]
    fn the_fit_never_panics(
        rows in proptest::collection::vec((dt(), any_f64(), eye()), 0..60),
    ) {
        let mut t = 0.0;
        let rows: Vec<PupilRow> = rows
            .into_iter()
            .map(|(d, p, e)| {
                t += d;
                PupilRow { t_secs: t, pupil_mm: p, light: EyeLight::both(e) }
            })
            .collect();
        let opts = FitOptions { max_iterations: 30, min_samples: 3, ..FitOptions::default() };
        match fit_observer(&rows, &ResponseParams::default(), &opts) {
            Ok(fit) => {
                prop_assert!(fit.params.range.scale > 0.0);
                prop_assert!(fit.samples_used >= 3);
            }
            Err(e) => prop_assert!(!e.to_string().is_empty()),
        }
    }
}
