#![allow(clippy::unwrap_used, clippy::expect_used)] // test code may panic on a failed setup
//! A synthetic observer with a known light response and known task-evoked
//! dilations. The "measured" pupil is simulated here, independently of the
//! code under test: W&Y 2012 eq. 21 written out below, a 1 kHz delay line
//! (array shift) and Euler integration of the asymmetric first-order lag,
//! sampled at 120 Hz, plus Hoeks & Levelt (1993) pupil-response bumps,
//! noise, blinks (NaN stretches) and dropouts. Luminance changes by
//! decades (synthesised; a real panorama's luminance is left for later).
//!
//! * The fit on the 90 s baseline block (no bumps) recovers the observer.
//! * With those parameters the residual of the 180 s task block recovers
//!   the bumps (correlation ≥ 0.9, amplitudes within 20 %); the raw pupil's
//!   correlation with the bumps is reported for comparison.

use gazelight_eye::pupil_response::{
    Adaptation, Dynamics, EyeInput, EyeLight, FitOptions, ObserverRange, PupilLightResponse,
    PupilRow, ResponseParams, fit_observer, residuals_mm,
};

const AGE: f64 = 35.0;
const GAZE_WEIGHT: f64 = 0.5;
const AREA: f64 = 2827.0;
const TRUE_LATENCY: f64 = 0.28;
const TRUE_TAU_C: f64 = 0.35;
const TRUE_TAU_D: f64 = 1.8;
const TRUE_SCALE: f64 = 0.85;
const TRUE_OFFSET: f64 = 0.4;
const SIM_DT: f64 = 0.001;
const SAMPLE_EVERY: usize = 8; // 125 Hz
const BASELINE_SECS: f64 = 90.0;
const TOTAL_SECS: f64 = 270.0;

/// Hoeks & Levelt (1993) pupil response function h(t) = tⁿ·e^(−n·t/t_max),
/// n = 10.1, t_max = 0.93 s, scaled to a peak of 1.
fn bump(t: f64) -> f64 {
    const N: f64 = 10.1;
    const T_MAX: f64 = 0.93;
    if t <= 0.0 {
        return 0.0;
    }
    (N * ((t / T_MAX).ln() - t / T_MAX + 1.0)).exp()
}

/// W&Y 2012 eq. 21 for a binocular uniform field (independent of the crate).
fn wy_mm(lum: f64) -> f64 {
    let g = (lum * AREA / 846.0).powf(0.41);
    let d = 7.75 - 5.75 * g / (g + 2.0);
    d + (AGE - 28.58) * (0.02132 - 0.009562 * d)
}

struct Lcg(u64);
impl Lcg {
    fn uniform(&mut self) -> f64 {
        self.0 = self
            .0
            .wrapping_mul(6364136223846793005)
            .wrapping_add(1442695040888963407);
        (self.0 >> 11) as f64 / (1u64 << 53) as f64
    }
    /// Approximately normal (Irwin–Hall, 12 uniforms).
    fn normal(&mut self) -> f64 {
        (0..12).map(|_| self.uniform()).sum::<f64>() - 6.0
    }
}

struct Synthetic {
    rows: Vec<PupilRow>,
    /// Known task-evoked component at each row, mm.
    bumps_mm: Vec<f64>,
    /// (onset s, amplitude mm).
    events: Vec<(f64, f64)>,
}

fn synthesise() -> Synthetic {
    let mut rng = Lcg(0x5eed_1234);
    // Field-mean luminance: a new decade (0.01 … 1000 cd/m²) every 5–9 s;
    // gaze-pooled luminance 0.3–3× the field mean, changing every 1–3 s.
    let n = (TOTAL_SECS / SIM_DT) as usize;
    let mut field = vec![0.0; n];
    let mut gaze = vec![0.0; n];
    let (mut next_field, mut next_gaze) = (0usize, 0usize);
    let (mut f, mut g) = (1.0, 1.0);
    for i in 0..n {
        if i == next_field {
            let decade = (rng.uniform() * 6.0).floor() - 2.0;
            f = 10f64.powf(decade);
            next_field = i + ((5.0 + 4.0 * rng.uniform()) / SIM_DT) as usize;
        }
        if i == next_gaze {
            g = 10f64.powf(rng.uniform() - 0.5);
            next_gaze = i + ((1.0 + 2.0 * rng.uniform()) / SIM_DT) as usize;
        }
        field[i] = f;
        gaze[i] = f * g;
    }
    // Truth: delayed target, Euler-integrated asymmetric lag.
    let lag = (TRUE_LATENCY / SIM_DT).round() as usize;
    let target: Vec<f64> = (0..n)
        .map(|i| wy_mm(GAZE_WEIGHT * gaze[i] + (1.0 - GAZE_WEIGHT) * field[i]))
        .collect();
    let mut d = target[0];
    let mut light_mm = vec![0.0; n];
    for i in 0..n {
        let tg = target[i.saturating_sub(lag)];
        let tau = if tg < d { TRUE_TAU_C } else { TRUE_TAU_D };
        d += (tg - d) * SIM_DT / tau;
        light_mm[i] = TRUE_SCALE * d + TRUE_OFFSET;
    }
    // Task-evoked dilations in the task block, every 8–12 s, 0.2–0.4 mm.
    let mut events = Vec::new();
    let mut t = BASELINE_SECS + 3.0;
    while t < TOTAL_SECS - 6.0 {
        events.push((t, 0.2 + 0.2 * rng.uniform()));
        t += 8.0 + 4.0 * rng.uniform();
    }
    let mut rows = Vec::new();
    let mut bumps_mm = Vec::new();
    let mut blink_until = -1.0;
    let mut next_blink = 3.0;
    for i in (0..n).step_by(SAMPLE_EVERY) {
        let t = i as f64 * SIM_DT;
        let b: f64 = events.iter().map(|&(t0, a)| a * bump(t - t0)).sum();
        let mut p = light_mm[i] + b + 0.02 * rng.normal();
        if t >= next_blink {
            blink_until = t + 0.1 + 0.15 * rng.uniform();
            next_blink = t + 2.0 + 4.0 * rng.uniform();
        }
        let dropout = rng.uniform() < 0.02 || (150.0..151.0).contains(&t);
        if t < blink_until || dropout {
            p = f64::NAN;
        }
        rows.push(PupilRow {
            t_secs: t,
            pupil_mm: p,
            light: EyeLight::both(EyeInput {
                gaze_luminance_cd_m2: gaze[i],
                field_mean_luminance_cd_m2: field[i],
                field_area_deg2: AREA,
                lit: true,
            }),
        });
        bumps_mm.push(b);
    }
    Synthetic {
        rows,
        bumps_mm,
        events,
    }
}

fn initial() -> ResponseParams {
    ResponseParams {
        adaptation: Adaptation {
            gaze_weight: GAZE_WEIGHT,
            age_years: AGE,
        },
        dynamics: Dynamics::default(),
        range: ObserverRange::IDENTITY,
    }
}

fn baseline(s: &Synthetic) -> &[PupilRow] {
    let end = s.rows.partition_point(|r| r.t_secs < BASELINE_SECS);
    &s.rows[..end]
}

fn correlation(a: &[f64], b: &[f64]) -> f64 {
    let pairs: Vec<(f64, f64)> = a
        .iter()
        .zip(b)
        .filter(|(x, y)| x.is_finite() && y.is_finite())
        .map(|(x, y)| (*x, *y))
        .collect();
    let n = pairs.len() as f64;
    let (mx, my) = (
        pairs.iter().map(|p| p.0).sum::<f64>() / n,
        pairs.iter().map(|p| p.1).sum::<f64>() / n,
    );
    let (mut sxy, mut sxx, mut syy) = (0.0, 0.0, 0.0);
    for (x, y) in &pairs {
        sxy += (x - mx) * (y - my);
        sxx += (x - mx).powi(2);
        syy += (y - my).powi(2);
    }
    sxy / (sxx * syy).sqrt()
}

#[test]
fn the_baseline_fit_recovers_the_observer() {
    let s = synthesise();
    let base = baseline(&s);
    let nan = base.iter().filter(|r| r.pupil_mm.is_nan()).count();
    let fit = fit_observer(base, &initial(), &FitOptions::default()).unwrap();
    let d = fit.params.dynamics;
    let r = fit.params.range;
    eprintln!(
        "baseline fit: {} of {} rows used ({nan} NaN), R² {:.4}, rms {:.4} mm; latency {:.3} s \
         (true {TRUE_LATENCY}), τc {:.3} s ({TRUE_TAU_C}), τd {:.3} s ({TRUE_TAU_D}), \
         scale {:.4} ({TRUE_SCALE}), offset {:.4} mm ({TRUE_OFFSET})",
        fit.samples_used,
        base.len(),
        fit.r_squared,
        fit.rms_mm,
        d.latency_secs,
        d.constriction_tau_secs,
        d.redilation_tau_secs,
        r.scale,
        r.offset_mm
    );
    assert_eq!(fit.samples_used, base.len() - nan);
    assert!(nan > 100, "the block has blinks and dropouts: {nan}");
    // Tolerances: latency ±20 ms (between two 125 Hz samples plus the
    // simulator's 1 ms grid), time constants ±10 %, scale ±3 %, offset ±0.1 mm.
    assert!((d.latency_secs - TRUE_LATENCY).abs() < 0.02, "{d:?}");
    assert!(
        (d.constriction_tau_secs / TRUE_TAU_C - 1.0).abs() < 0.10,
        "{d:?}"
    );
    assert!(
        (d.redilation_tau_secs / TRUE_TAU_D - 1.0).abs() < 0.10,
        "{d:?}"
    );
    assert!((r.scale / TRUE_SCALE - 1.0).abs() < 0.03, "{r:?}");
    assert!((r.offset_mm - TRUE_OFFSET).abs() < 0.1, "{r:?}");
    assert!(fit.r_squared > 0.99, "{}", fit.r_squared);
}

#[test]
fn the_residual_recovers_task_evoked_dilations() {
    let s = synthesise();
    let fit = fit_observer(baseline(&s), &initial(), &FitOptions::default()).unwrap();
    let mut model = PupilLightResponse::new(fit.params).unwrap();
    // Run over everything (the model needs the light history), score the
    // task block.
    let residual = residuals_mm(&mut model, &s.rows);
    let start = s.rows.partition_point(|r| r.t_secs < BASELINE_SECS);
    let raw: Vec<f64> = s.rows[start..].iter().map(|r| r.pupil_mm).collect();
    let r_res = correlation(&residual[start..], &s.bumps_mm[start..]);
    let r_raw = correlation(&raw, &s.bumps_mm[start..]);
    eprintln!(
        "{} bumps; correlation with the bumps: residual {r_res:.3}, raw pupil {r_raw:.3}",
        s.events.len()
    );
    assert!(r_res >= 0.9, "residual correlation {r_res}");
    assert!(
        r_raw < 0.5,
        "the raw pupil should not show the bumps: {r_raw}"
    );

    // Amplitude of each bump: least squares of the residual on
    // [template, 1] over 0–3 s after its onset (valid samples only).
    let mut worst: f64 = 0.0;
    for &(t0, amp) in &s.events {
        let (mut n, mut sx, mut sy, mut sxx, mut sxy) = (0.0, 0.0, 0.0, 0.0, 0.0);
        for (row, res) in s.rows.iter().zip(&residual) {
            if (t0..t0 + 3.0).contains(&row.t_secs) && res.is_finite() {
                let x = bump(row.t_secs - t0);
                n += 1.0;
                sx += x;
                sy += res;
                sxx += x * x;
                sxy += x * res;
            }
        }
        let est = (n * sxy - sx * sy) / (n * sxx - sx * sx);
        let err = (est / amp - 1.0).abs();
        worst = worst.max(err);
        assert!(
            err < 0.2,
            "bump at {t0:.1} s: {amp:.3} mm true, {est:.3} mm recovered"
        );
    }
    eprintln!("worst bump amplitude error {:.1} %", worst * 100.0);
}
