#![allow(clippy::unwrap_used, clippy::expect_used)] // test code may panic on a failed setup
//! The static end point against Watson & Yellott (2012) computed outside
//! the code under test: `tests/data/wy2012.csv` is written by
//! `tests/data/gen_wy2012.py`, an independent Python transcription of the
//! paper's equations (Stanley–Davies with M(e), eq. 21 for age), which also
//! checks itself against the paper's appendix closed form (eq. 27).
//!
//! Printed values from the paper (figures/tables) could not be found in the
//! sources available to this session, so there is no spot check against
//! them; the appendix cross-check in the script is the paper-side check.

use gazelight_eye::pupil_model::unified_mm;
use gazelight_eye::pupil_response::{
    Adaptation, EyeInput, EyeLight, LEFT, RIGHT, combined_flux, static_target_mm,
};

const CSV: &str = include_str!("data/wy2012.csv");

struct Row {
    lum: f64,
    area: f64,
    age: f64,
    eyes: u8,
    pupil_mm: f64,
}

fn rows() -> Vec<Row> {
    let mut lines = CSV.lines();
    assert_eq!(
        lines.next().unwrap(),
        "luminance_cd_m2,field_area_deg2,age_years,eyes,pupil_mm"
    );
    lines
        .map(|l| {
            let f: Vec<&str> = l.split(',').collect();
            Row {
                lum: f[0].parse().unwrap(),
                area: f[1].parse().unwrap(),
                age: f[2].parse().unwrap(),
                eyes: f[3].parse().unwrap(),
                pupil_mm: f[4].parse().unwrap(),
            }
        })
        .collect()
}

#[test]
fn the_csv_covers_the_ranges_asked_for() {
    let r = rows();
    assert_eq!(r.len(), 540);
    let min = |f: fn(&Row) -> f64| r.iter().map(f).fold(f64::INFINITY, f64::min);
    let max = |f: fn(&Row) -> f64| r.iter().map(f).fold(f64::NEG_INFINITY, f64::max);
    assert_eq!((min(|r| r.lum), max(|r| r.lum)), (1e-3, 1e4));
    assert_eq!((min(|r| r.area), max(|r| r.area)), (1.0, 3000.0));
    assert_eq!((min(|r| r.age), max(|r| r.age)), (20.0, 80.0));
    assert!(r.iter().any(|r| r.eyes == 1) && r.iter().any(|r| r.eyes == 2));
}

#[test]
fn unified_formula_matches_the_independent_script() {
    for r in rows() {
        let ours = unified_mm(r.lum, r.area, r.age, r.eyes == 2);
        assert!(
            (ours - r.pupil_mm).abs() < 1e-6,
            "L={} a={} y={} e={}: {ours} vs {}",
            r.lum,
            r.area,
            r.age,
            r.eyes,
            r.pupil_mm
        );
    }
}

#[test]
fn per_eye_static_target_matches_the_script_for_uniform_fields() {
    // A uniform field: gaze-pooled = field mean, so any gaze weight gives
    // W&Y's luminance. e = 2: both eyes lit; e = 1: one eye (either) lit.
    for r in rows() {
        for gaze_weight in [0.0, 0.5, 1.0] {
            let adaptation = Adaptation {
                gaze_weight,
                age_years: r.age,
            };
            let input = EyeInput::uniform(r.lum, r.area);
            let lights: Vec<EyeLight> = if r.eyes == 2 {
                vec![EyeLight::both(input)]
            } else {
                vec![EyeLight::one(RIGHT, input), EyeLight::one(LEFT, input)]
            };
            for light in lights {
                let ours = static_target_mm(&light, &adaptation);
                assert!(
                    (ours - r.pupil_mm).abs() < 1e-6,
                    "L={} a={} y={} e={} w={gaze_weight}: {ours} vs {}",
                    r.lum,
                    r.area,
                    r.age,
                    r.eyes,
                    r.pupil_mm
                );
            }
        }
    }
}

#[test]
fn an_eye_that_is_not_lit_adds_no_flux_and_the_drive_is_consensual() {
    let lit = EyeInput::uniform(100.0, 1000.0);
    let occluded = EyeInput { lit: false, ..lit };
    // Right eye occluded, left eye lit → W&Y monocular: F = 0.1 · L · a.
    let light = EyeLight {
        eyes: [occluded, lit],
    };
    assert!((combined_flux(&light, 0.5) - 0.1 * 100.0 * 1000.0).abs() < 1e-9);
    // Unequal eyes: between the monocular flux of the brighter eye and the
    // binocular flux of the brighter eye.
    let dim = EyeInput::uniform(10.0, 1000.0);
    let f = combined_flux(&EyeLight { eyes: [dim, lit] }, 0.5);
    assert!(f > 0.1 * 100.0 * 1000.0 && f < 100.0 * 1000.0, "{f}");
    // f = 0.1·(1e4 + 1e5) + 0.8·1e4 (the formula in combined_flux's doc).
    assert!((f - 19_000.0).abs() < 1e-6, "{f}");
}

#[test]
fn gaze_weight_mixes_gaze_and_field_luminance() {
    let input = EyeInput {
        gaze_luminance_cd_m2: 1000.0,
        field_mean_luminance_cd_m2: 10.0,
        field_area_deg2: 100.0,
        lit: true,
    };
    let a = |w: f64| Adaptation {
        gaze_weight: w,
        age_years: 28.58,
    };
    let both = EyeLight::both(input);
    // w = 0.25: L = 0.25·1000 + 0.75·10 = 257.5 cd/m² (binocular).
    let expected = unified_mm(257.5, 100.0, 28.58, true);
    assert!((static_target_mm(&both, &a(0.25)) - expected).abs() < 1e-12);
    assert!(static_target_mm(&both, &a(1.0)) < static_target_mm(&both, &a(0.0)));
}
