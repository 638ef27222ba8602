//! Temporal adaptation: how the adaptation luminance follows the pooled
//! target luminance over time. Pure state updates, `f64`, cd/m².
//!
//! With `L` the adaptation luminance carried from the previous frame, `Y` the
//! pooled target of this frame and `dt` the frame time in seconds:
//!
//! * [`TemporalModel::Krawczyk`] (default; 001 eq 2–4, after Krawczyk et
//!   al.): `L ← L + (Y − L)·(1 − e^(−dt/τ(Y)))`,
//!   `τ(Y) = σ(Y)·τ_rod + (1 − σ(Y))·τ_cone`, `σ(Y) = 0.04/(0.04 + Y)`,
//!   τ_rod = 0.4 s, τ_cone = 0.1 s. For a constant target this is an
//!   exponential with time constant τ(Y), so the update is exact for any
//!   `dt` (frame-rate independent).
//! * [`TemporalModel::PowerDt`] (000 eq 7): `L ← (1 − p^dt)·Y + p^dt·L`
//!   with `p = p_light` (0.1, 000 §4) when `Y > L` and `p = p_dark` (0.5)
//!   otherwise; `p^a·p^b = p^(a+b)`, so exact for any `dt`. With
//!   `overshoot` on, the state also records the luminance being
//!   light-adapted to, `L̄ = Y`, so the tone operator can use the
//!   light-adaptation threshold `t*(L, L̄) = t_m(L̄)²/t_m(L)` (000 eq 8,
//!   [`crate::tvi::t_star`]) and the offset of 000 eq 10; see
//!   [`AdaptationState::light_target_cd_m2`].
//! * [`TemporalModel::LogExponential`] (003 eq 2, after Krawczyk et al.):
//!   the same exponential in log₁₀ luminance,
//!   `log L ← log L + (log Y − log L)(1 − e^(−dt/τ))`, with separate τ for
//!   light (0.1 s, 003's τ_cone) and dark adaptation (2 s, the preferred
//!   dark adaptation time of 003 §4.2). Exact for any `dt`.
//! * [`TemporalModel::Linear`] (003 eq 3): a constant-speed step in log₁₀
//!   luminance, `log L ← min(log L + dt/τ_light, log Y)` when brightening,
//!   `max(log L − dt/τ_dark, log Y)` when darkening, i.e. τ is the time per
//!   decade. 003 eq 3 is printed without the logs of eq 2, which would make
//!   `dt/τ` a luminance in cd/m²; in log units its experiment (a target one
//!   decade darker, adaptation times of 2–33 s) reads directly as τ. The
//!   printed equation also pairs τ_rod (9 s) with brightening, contrary to
//!   its own text (rods adapt slowly to the dark); here the slow time
//!   belongs to darkening. Defaults: 0.1 s light (003 τ_cone), 2 s dark
//!   (003 §4.2, preferred together with 8 s). Exact for any `dt`.
//!
//! The log models clamp luminances to at least [`MIN_LUMINANCE_CD_M2`].
//! A non-finite or negative target, or a non-finite or negative `dt`,
//! leaves the state unchanged.

use serde::{Deserialize, Serialize};

use crate::VisionError;

/// Lowest luminance the log-domain models use, cd/m² (faint starlight,
/// the lower end of human vision, 001 §3.3).
pub const MIN_LUMINANCE_CD_M2: f64 = 1e-6;

/// Rod sensitivity `σ(Y) = 0.04/(0.04 + Y)` (001 eq 4), Y in cd/m²; 1 in
/// the dark, 0 in daylight. Also used by the scotopic colour shift
/// (001 eq 14).
pub fn rod_sensitivity(y_cd_m2: f64) -> f64 {
    // 001 eq 4: half-sensitivity luminance 0.04 cd/m²
    0.04 / (0.04 + y_cd_m2.max(0.0))
}

/// Krawczyk adaptation time constant `τ(Y)`, seconds (001 eq 3).
pub fn krawczyk_tau_secs(y_cd_m2: f64, tau_rod_secs: f64, tau_cone_secs: f64) -> f64 {
    let s = rod_sensitivity(y_cd_m2);
    s * tau_rod_secs + (1.0 - s) * tau_cone_secs
}

/// The adaptation state carried from frame to frame.
#[derive(Clone, Copy, Debug, PartialEq, Serialize, Deserialize)]
pub struct AdaptationState {
    /// Adaptation luminance, cd/m² (001's `L_i`, 000's `L_wa`).
    pub luminance_cd_m2: f64,
    /// The luminance being light-adapted to, cd/m² (000 eq 8's `L̄`), set
    /// by [`TemporalModel::PowerDt`] with `overshoot`. Equal to
    /// `luminance_cd_m2` when no overshoot is active (always, for the other
    /// models and during dark adaptation). The tone operator uses eq 10
    /// when it is above `luminance_cd_m2`.
    pub light_target_cd_m2: f64,
}

impl AdaptationState {
    /// Fully adapted to `luminance_cd_m2` (clamped to ≥ 0; non-finite → 0).
    pub fn new(luminance_cd_m2: f64) -> Self {
        let l = if luminance_cd_m2.is_finite() {
            luminance_cd_m2.max(0.0)
        } else {
            0.0
        };
        Self {
            luminance_cd_m2: l,
            light_target_cd_m2: l,
        }
    }

    /// Whether the light-adaptation overshoot of 000 eq 8 is active.
    pub fn is_light_adapting(&self) -> bool {
        self.light_target_cd_m2 > self.luminance_cd_m2
    }

    /// The visibility threshold of this state, cd/m²: `t*(L, L̄)` (000 eq 8)
    /// while light-adapting with overshoot, `t_m(L)` (000 eq 4) otherwise.
    pub fn threshold_cd_m2(&self) -> f64 {
        if self.is_light_adapting() {
            crate::tvi::t_star(self.luminance_cd_m2, self.light_target_cd_m2)
        } else {
            crate::tvi::t_m(self.luminance_cd_m2)
        }
    }
}

/// Temporal adaptation model; see the module docs for the formulas.
#[derive(Clone, Copy, Debug, PartialEq, Serialize, Deserialize)]
#[serde(tag = "model", rename_all = "snake_case", deny_unknown_fields)]
pub enum TemporalModel {
    /// Exponential with rod/cone time constants (001 eq 2–4).
    Krawczyk {
        /// Rod adaptation time, seconds.
        tau_rod_secs: f64,
        /// Cone adaptation time, seconds.
        tau_cone_secs: f64,
    },
    /// `p^dt` exponential smoothing (000 eq 7) with the light-adaptation
    /// overshoot (000 eq 8).
    PowerDt {
        /// Fraction of the old state kept after 1 s when brightening.
        p_light: f64,
        /// Fraction of the old state kept after 1 s when darkening.
        p_dark: f64,
        /// Record `L̄` for the light-adaptation threshold `t*` (000 eq 8).
        overshoot: bool,
    },
    /// Exponential in log₁₀ luminance (003 eq 2).
    LogExponential {
        /// Time constant when brightening, seconds.
        tau_light_secs: f64,
        /// Time constant when darkening, seconds.
        tau_dark_secs: f64,
    },
    /// Constant speed in log₁₀ luminance (003 eq 3).
    Linear {
        /// Seconds per decade when brightening.
        tau_light_secs: f64,
        /// Seconds per decade when darkening.
        tau_dark_secs: f64,
    },
}

impl Default for TemporalModel {
    fn default() -> Self {
        Self::krawczyk()
    }
}

impl TemporalModel {
    /// Krawczyk with the seed's time constants.
    pub fn krawczyk() -> Self {
        Self::Krawczyk {
            tau_rod_secs: 0.4,  // 001 eq 3: τ_rod
            tau_cone_secs: 0.1, // 001 eq 3: τ_cone
        }
    }

    /// `p^dt` with the seed's parameters and the overshoot on.
    pub fn power_dt() -> Self {
        Self::PowerDt {
            p_light: 0.1, // 000 §4: light adaptation p
            p_dark: 0.5,  // 000 §4: dark adaptation p
            overshoot: true,
        }
    }

    /// Log-domain exponential with the seed's parameters.
    pub fn log_exponential() -> Self {
        Self::LogExponential {
            tau_light_secs: 0.1, // 003 eq 3: τ_cone
            tau_dark_secs: 2.0,  // 003 §4.2: preferred dark adaptation time
        }
    }

    /// Log-domain linear step with the seed's parameters.
    pub fn linear() -> Self {
        Self::Linear {
            tau_light_secs: 0.1, // 003 eq 3: τ_cone
            tau_dark_secs: 2.0,  // 003 §4.2: preferred dark adaptation time
        }
    }

    /// Checks the parameters.
    pub fn validate(&self) -> Result<(), VisionError> {
        fn tau(name: &'static str, v: f64) -> Result<(), VisionError> {
            if v.is_finite() && v > 0.0 {
                Ok(())
            } else {
                Err(VisionError::invalid(
                    name,
                    v,
                    "a finite time in seconds > 0",
                ))
            }
        }
        fn p(name: &'static str, v: f64) -> Result<(), VisionError> {
            if v > 0.0 && v < 1.0 {
                Ok(())
            } else {
                Err(VisionError::invalid(name, v, "0 < p < 1"))
            }
        }
        match *self {
            Self::Krawczyk {
                tau_rod_secs,
                tau_cone_secs,
            } => {
                tau("temporal.tau_rod_secs", tau_rod_secs)?;
                tau("temporal.tau_cone_secs", tau_cone_secs)
            }
            Self::PowerDt {
                p_light, p_dark, ..
            } => {
                p("temporal.p_light", p_light)?;
                p("temporal.p_dark", p_dark)
            }
            Self::LogExponential {
                tau_light_secs,
                tau_dark_secs,
            }
            | Self::Linear {
                tau_light_secs,
                tau_dark_secs,
            } => {
                tau("temporal.tau_light_secs", tau_light_secs)?;
                tau("temporal.tau_dark_secs", tau_dark_secs)
            }
        }
    }

    /// Advances `state` by `dt_secs` towards `target_cd_m2`.
    pub fn step(&self, state: AdaptationState, target_cd_m2: f64, dt_secs: f64) -> AdaptationState {
        if !(target_cd_m2.is_finite()
            && target_cd_m2 >= 0.0
            && dt_secs.is_finite()
            && dt_secs >= 0.0)
        {
            return state;
        }
        let l = state.luminance_cd_m2;
        let y = target_cd_m2;
        let next = match *self {
            Self::Krawczyk {
                tau_rod_secs,
                tau_cone_secs,
            } => {
                // 001 eq 2
                let tau = krawczyk_tau_secs(y, tau_rod_secs, tau_cone_secs);
                l + (y - l) * -(-dt_secs / tau).exp_m1()
            }
            Self::PowerDt {
                p_light,
                p_dark,
                overshoot,
            } => {
                // 000 eq 7
                let p = if y > l { p_light } else { p_dark };
                let keep = p.powf(dt_secs);
                let next = (1.0 - keep) * y + keep * l;
                let light_target = if overshoot && y > next { y } else { next };
                return AdaptationState {
                    luminance_cd_m2: next,
                    light_target_cd_m2: light_target,
                };
            }
            Self::LogExponential {
                tau_light_secs,
                tau_dark_secs,
            } => {
                // 003 eq 2, in log10
                let (ll, ly) = (log_lum(l), log_lum(y));
                let tau = if ly > ll {
                    tau_light_secs
                } else {
                    tau_dark_secs
                };
                10f64.powf(ll + (ly - ll) * -(-dt_secs / tau).exp_m1())
            }
            Self::Linear {
                tau_light_secs,
                tau_dark_secs,
            } => {
                // 003 eq 3, in log10 (see module docs)
                let (ll, ly) = (log_lum(l), log_lum(y));
                let next = if ll < ly {
                    (ll + dt_secs / tau_light_secs).min(ly)
                } else {
                    (ll - dt_secs / tau_dark_secs).max(ly)
                };
                10f64.powf(next)
            }
        };
        AdaptationState {
            luminance_cd_m2: next,
            light_target_cd_m2: next,
        }
    }
}

#[inline]
fn log_lum(l: f64) -> f64 {
    l.max(MIN_LUMINANCE_CD_M2).log10()
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::pooling::{PoolingModel, night};
    use crate::tvi;

    fn run(m: &TemporalModel, from: f64, to: f64, secs: f64, steps: usize) -> AdaptationState {
        let mut s = AdaptationState::new(from);
        let dt = secs / steps as f64;
        for _ in 0..steps {
            s = m.step(s, to, dt);
        }
        s
    }

    /// Fraction of the way from `from` to `to` (linear, or log when `log`).
    fn fraction(s: &AdaptationState, from: f64, to: f64, log: bool) -> f64 {
        if log {
            (s.luminance_cd_m2.log10() - from.log10()) / (to.log10() - from.log10())
        } else {
            (s.luminance_cd_m2 - from) / (to - from)
        }
    }

    #[test]
    fn krawczyk_tau_limits() {
        let (r, c) = (0.4, 0.1);
        assert!((krawczyk_tau_secs(0.0, r, c) - 0.4).abs() < 1e-15);
        assert!((krawczyk_tau_secs(1e-9, r, c) - 0.4).abs() < 1e-7);
        assert!((krawczyk_tau_secs(1e9, r, c) - 0.1).abs() < 1e-10);
        // At Y = 0.04 the rods are at half sensitivity: τ = 0.25 s.
        assert!((krawczyk_tau_secs(0.04, r, c) - 0.25).abs() < 1e-15);
        assert!((rod_sensitivity(0.04) - 0.5).abs() < 1e-15);
    }

    #[test]
    fn exponential_models_reach_1_minus_1_over_e_after_tau() {
        let target = 1.0 - (-1f64).exp();
        // Krawczyk: τ(Y) of the target, in linear luminance.
        let m = TemporalModel::krawczyk();
        for (from, to) in [(0.001, 100.0), (100.0, 0.001), (0.5, 0.02)] {
            let tau = krawczyk_tau_secs(to, 0.4, 0.1);
            for steps in [1, 7, 1000] {
                let s = run(&m, from, to, tau, steps);
                let f = fraction(&s, from, to, false);
                assert!(
                    (f - target).abs() < 1e-12,
                    "{from}→{to} in {steps} steps: {f}"
                );
            }
        }
        // Log exponential: in log luminance, τ by direction.
        let m = TemporalModel::log_exponential();
        for (from, to, tau) in [(0.01, 100.0, 0.1), (100.0, 0.01, 2.0)] {
            for steps in [1, 13, 1000] {
                let s = run(&m, from, to, tau, steps);
                let f = fraction(&s, from, to, true);
                assert!(
                    (f - target).abs() < 1e-12,
                    "{from}→{to} in {steps} steps: {f}"
                );
            }
        }
    }

    #[test]
    fn power_dt_is_frame_rate_independent() {
        // 000 eq 7: after t seconds, a fraction 1 − p^t of the way.
        let m = TemporalModel::power_dt();
        for (from, to, p) in [(0.01, 100.0, 0.1f64), (100.0, 0.01, 0.5)] {
            for secs in [0.5, 1.0, 3.0] {
                for steps in [1, (90.0 * secs) as usize] {
                    let s = run(&m, from, to, secs, steps);
                    let f = fraction(&s, from, to, false);
                    let expected = 1.0 - p.powf(secs);
                    assert!(
                        (f - expected).abs() < 1e-12,
                        "{from}→{to} {secs}s/{steps}: {f}"
                    );
                }
            }
        }
        // 000 §4: with p = 0.5, dark adaptation is essentially complete
        // after 20 s.
        let s = run(&m, 100.0, 0.01, 20.0, 1800);
        assert!(fraction(&s, 100.0, 0.01, false) > 1.0 - 1e-6);
    }

    #[test]
    fn linear_moves_one_decade_per_tau() {
        let m = TemporalModel::linear();
        // Darkening by 2 decades takes 2 × 2 s; after 2 s one decade is done.
        for steps in [1, 3, 500] {
            let s = run(&m, 100.0, 1.0, 2.0, steps);
            assert!((s.luminance_cd_m2 - 10.0).abs() < 1e-9, "{s:?}");
        }
        let s = run(&m, 100.0, 1.0, 4.0 + 1e-9, 400);
        assert!((s.luminance_cd_m2 - 1.0).abs() < 1e-9);
        // Never overshoots the target.
        let s = run(&m, 100.0, 1.0, 60.0, 7);
        assert_eq!(s.luminance_cd_m2, 1.0);
        // Brightening by 3 decades takes 0.3 s.
        let s = run(&m, 0.01, 10.0, 0.2, 20);
        assert!((s.luminance_cd_m2 - 1.0).abs() < 1e-9, "{s:?}");
        let s = run(&m, 0.01, 10.0, 0.31, 31);
        assert!((s.luminance_cd_m2 - 10.0).abs() < 1e-9, "{s:?}");
    }

    #[test]
    fn dark_adaptation_is_slower_than_light_adaptation() {
        for m in [
            TemporalModel::krawczyk(),
            TemporalModel::power_dt(),
            TemporalModel::log_exponential(),
            TemporalModel::linear(),
        ] {
            m.validate().unwrap();
            let up = run(&m, 0.01, 10.0, 0.2, 20);
            let down = run(&m, 10.0, 0.01, 0.2, 20);
            let log = matches!(
                m,
                TemporalModel::LogExponential { .. } | TemporalModel::Linear { .. }
            );
            let fu = fraction(&up, 0.01, 10.0, log);
            let fd = fraction(&down, 10.0, 0.01, log);
            assert!(fu > fd, "{m:?}: up {fu} down {fd}");
        }
    }

    #[test]
    fn power_dt_light_adaptation_overshoot() {
        // 000 eq 8: after switching from 0.01 to 100 cd/m², the threshold
        // t* = t_m(L̄)²/t_m(L_wa) starts far above t_m(100) and decays to it.
        let m = TemporalModel::power_dt();
        let mut s = AdaptationState::new(0.01);
        let steady = tvi::t_m(100.0);
        let mut prev = f64::INFINITY;
        let mut first = None;
        for _ in 0..(90 * 5) {
            s = m.step(s, 100.0, 1.0 / 90.0);
            assert!(s.is_light_adapting());
            let t = s.threshold_cd_m2();
            let expected = tvi::t_m(100.0).powi(2) / tvi::t_m(s.luminance_cd_m2);
            assert!((t / expected - 1.0).abs() < 1e-12);
            // Non-increasing, up to the small downward jumps of t_m where
            // the published fits are discontinuous (at most 2.8 %, at
            // 10^−1.44 cd/m²; see crate::tvi).
            assert!(t >= steady && t <= prev * 1.03, "t* {t} not decaying");
            first.get_or_insert(t);
            prev = t;
        }
        // One 90 Hz frame in, the eye is at 2.5 cd/m²: t* ≈ 10 t_m(100).
        assert!(first.unwrap() > 5.0 * steady);
        // At the switch itself (dt = 0), t* = t_m(100)²/t_m(0.01) ≈ 1000 t_m(100).
        let s0 = m.step(AdaptationState::new(0.01), 100.0, 0.0);
        assert_eq!(s0.luminance_cd_m2, 0.01);
        assert!(s0.threshold_cd_m2() > 500.0 * steady);
        assert!((prev / steady - 1.0).abs() < 1e-3, "{prev} vs {steady}");
        // Dark adaptation: no overshoot, the threshold is t_m(L_wa).
        let s = m.step(AdaptationState::new(100.0), 0.01, 0.1);
        assert!(!s.is_light_adapting());
        assert_eq!(s.threshold_cd_m2(), tvi::t_m(s.luminance_cd_m2));
        // Without the overshoot flag the state never records L̄.
        let m = TemporalModel::PowerDt {
            p_light: 0.1,
            p_dark: 0.5,
            overshoot: false,
        };
        let s = m.step(AdaptationState::new(0.01), 100.0, 0.1);
        assert!(!s.is_light_adapting());
    }

    #[test]
    fn bad_input_leaves_state_unchanged() {
        let s = AdaptationState::new(3.0);
        for m in [TemporalModel::krawczyk(), TemporalModel::linear()] {
            assert_eq!(m.step(s, f64::NAN, 0.1), s);
            assert_eq!(m.step(s, -1.0, 0.1), s);
            assert_eq!(m.step(s, 10.0, -0.1), s);
            assert_eq!(m.step(s, 10.0, f64::INFINITY), s);
            assert_eq!(m.step(s, 10.0, 0.0).luminance_cd_m2, 3.0);
        }
        assert!(
            TemporalModel::Krawczyk {
                tau_rod_secs: -0.4,
                tau_cone_secs: 0.1
            }
            .validate()
            .is_err()
        );
        let e = TemporalModel::PowerDt {
            p_light: 1.0,
            p_dark: 0.5,
            overshoot: true,
        }
        .validate()
        .unwrap_err();
        assert!(e.to_string().contains("temporal.p_light"), "{e}");
    }

    #[test]
    fn night_lamp_to_ground_time_course() {
        // Pool night.exr at a street lamp and at the dark ground, then
        // follow the adaptation from one to the other.
        let pano = night::load("night.exr");
        let lamp = pano.brightest_below_horizon();
        let ground = [lamp[0], pano.height as f64 * (5.0 / 6.0)];
        let pool = PoolingModel::default();
        let dpp = pano.deg_per_px();
        let y_lamp = pool.pool(&pano.lum, pano.width, pano.height, lamp, dpp);
        let y_ground = pool.pool(&pano.lum, pano.width, pano.height, ground, dpp);
        assert!(y_lamp > y_ground);

        // Krawczyk, lamp → ground (dark adaptation): τ(Y_ground) is close to
        // the rod time since Y_ground ≪ 0.04.
        let m = TemporalModel::krawczyk();
        let tau = krawczyk_tau_secs(y_ground, 0.4, 0.1);
        assert!(tau > 0.3 && tau <= 0.4, "τ = {tau} for Y = {y_ground}");
        let mut s = AdaptationState::new(y_lamp);
        let dt = 1.0 / 90.0;
        for i in 1..=270 {
            s = m.step(s, y_ground, dt);
            let t = i as f64 * dt;
            let expected = y_ground + (y_lamp - y_ground) * (-t / tau).exp();
            assert!((s.luminance_cd_m2 / expected - 1.0).abs() < 1e-9, "t {t}");
        }
        // After 3 s (≥ 7.5 τ) the lamp's luminance is all but gone.
        assert!(s.luminance_cd_m2 < y_ground + 1e-3 * (y_lamp - y_ground));
        // ground → lamp (light adaptation) is faster: τ(Y_lamp) ≈ τ_cone.
        let tau_up = krawczyk_tau_secs(y_lamp, 0.4, 0.1);
        assert!(tau_up < 0.11 && tau_up < tau);
        let s = run(&m, y_ground, y_lamp, tau_up, 45);
        assert!((fraction(&s, y_ground, y_lamp, false) - (1.0 - (-1f64).exp())).abs() < 1e-12);

        // p^dt, ground → lamp with overshoot: half-way (1 − 0.1^t = 0.5) at
        // t = log(0.5)/log(0.1) s, t* above t_m(Y_lamp) throughout.
        let m = TemporalModel::power_dt();
        let t_half = 0.5f64.ln() / 0.1f64.ln();
        let s = run(&m, y_ground, y_lamp, t_half, 27);
        assert!((fraction(&s, y_ground, y_lamp, false) - 0.5).abs() < 1e-12);
        assert!(s.threshold_cd_m2() > tvi::t_m(y_lamp));
    }
}
