//! Threshold-versus-intensity (TVI) functions of Ferwerda et al. (1996), as
//! fitted and combined in seed 000 §3.1.
//!
//! All functions are scalar `f64`. Luminances are in cd/m²; thresholds are
//! the just-noticeable luminance difference in cd/m². "log" is log₁₀.
//!
//! * Photopic (cones), 000 eq 1:
//!   `log t_p(La) = −0.72` if `log La ≤ −2.6`;
//!   `log La − 1.255` if `log La ≥ 1.9`;
//!   `(0.249 log La + 0.65)^2.7 − 0.72` otherwise.
//! * Scotopic (rods), 000 eq 2:
//!   `log t_s(La) = −2.86` if `log La ≤ −3.94`;
//!   `log La − 0.395` if `log La ≥ −1.44`;
//!   `(0.405 log La + 1.6)^2.18 − 2.86` otherwise.
//! * Mesopic weight, 000 eq 3: `k(La) = 0` if `La ≤ 0.03`, `1` if `La ≥ 3`,
//!   `(0.5 log La + 0.761)^1.5` otherwise.
//! * Mesopic threshold, 000 eq 4: `t_m = t_s·(1 − k) + t_p·k` (linear
//!   thresholds, not logs).
//! * Light-adaptation threshold with overshoot, 000 eq 8:
//!   `t*(L_wa, L̄) = t_m(L̄) · t_m(L̄) / t_m(L_wa)`, where `L_wa` is the
//!   current (photochemical) adaptation and `L̄` the luminance being adapted
//!   to.
//!
//! The fits are continuous only to the precision of their published
//! constants: at `log La = 1.9` the two photopic branches differ by 0.003
//! log units, at `log La = −1.44` the scotopic ones by 0.012, and eq 3's
//! middle branch is 0.9993 at 3 cd/m² (jumping to 1). Just above 0.03 cd/m²
//! the base of eq 3 is −0.00044 (a negative number to the power 1.5); it is
//! clamped to 0 so k is continuous there. As a result `t_m` is increasing
//! except for three small downward jumps: −2.8 % at `La = 10^−1.44`
//! (scotopic branches), −0.07 % at 3 cd/m² (k) and −0.7 % at `10^1.9`
//! (photopic branches); `t*` jumps up by the same ratios when `L_wa`
//! crosses them.
//!
//! Non-positive luminances fall into the lowest branch (log → −∞). NaN
//! propagates.

/// Photopic threshold, log₁₀ cd/m², from log₁₀ of the adaptation luminance
/// (000 eq 1).
pub fn log_t_p(log_la: f64) -> f64 {
    if log_la <= -2.6 {
        // 000 eq 1, lower branch
        -0.72
    } else if log_la >= 1.9 {
        // 000 eq 1, upper branch (Weber)
        log_la - 1.255
    } else {
        // 000 eq 1, middle branch
        (0.249 * log_la + 0.65).powf(2.7) - 0.72
    }
}

/// Scotopic threshold, log₁₀ cd/m², from log₁₀ of the adaptation luminance
/// (000 eq 2).
pub fn log_t_s(log_la: f64) -> f64 {
    if log_la <= -3.94 {
        // 000 eq 2, lower branch
        -2.86
    } else if log_la >= -1.44 {
        // 000 eq 2, upper branch (Weber)
        log_la - 0.395
    } else {
        // 000 eq 2, middle branch
        (0.405 * log_la + 1.6).powf(2.18) - 2.86
    }
}

/// Photopic threshold `t_p(La)`, cd/m² (000 eq 1).
pub fn t_p(la_cd_m2: f64) -> f64 {
    10f64.powf(log_t_p(la_cd_m2.log10()))
}

/// Scotopic threshold `t_s(La)`, cd/m² (000 eq 2).
pub fn t_s(la_cd_m2: f64) -> f64 {
    10f64.powf(log_t_s(la_cd_m2.log10()))
}

/// Mesopic interpolation weight `k(La)` in [0, 1]: 0 = rods only,
/// 1 = cones only (000 eq 3).
pub fn k_mesopic(la_cd_m2: f64) -> f64 {
    // 000 eq 3: scotopic limit 0.03 cd/m², photopic limit 3 cd/m²
    if la_cd_m2 <= 0.03 {
        0.0
    } else if la_cd_m2 >= 3.0 {
        1.0
    } else {
        // 000 eq 3, middle branch; base clamped at 0 (see module docs)
        (0.5 * la_cd_m2.log10() + 0.761).max(0.0).powf(1.5)
    }
}

/// Mesopic (combined) threshold `t_m(La)`, cd/m² (000 eq 4).
pub fn t_m(la_cd_m2: f64) -> f64 {
    let k = k_mesopic(la_cd_m2);
    t_s(la_cd_m2) * (1.0 - k) + t_p(la_cd_m2) * k
}

/// Light-adaptation threshold `t*(L_wa, L̄) = t_m(L̄)² / t_m(L_wa)`, cd/m²
/// (000 eq 8). Above `t_m(L̄)` while the eye is still adapted to a darker
/// `L_wa < L̄` (the overshoot), equal to it once `L_wa = L̄`.
pub fn t_star(l_wa_cd_m2: f64, l_bar_cd_m2: f64) -> f64 {
    let tm_bar = t_m(l_bar_cd_m2);
    tm_bar * tm_bar / t_m(l_wa_cd_m2)
}

#[cfg(test)]
mod tests {
    use super::*;

    const EPS: f64 = 1e-9;

    #[test]
    fn photopic_breakpoints_and_middle() {
        // Lower breakpoint: both sides give −0.72 (the middle branch's base
        // is 0.0026 there, 0.0026^2.7 ≈ 1e-7).
        assert_eq!(log_t_p(-2.6), -0.72);
        assert!((log_t_p(-2.6 + 1e-12) - -0.72).abs() < 2e-7);
        // Upper breakpoint: Weber branch 1.9 − 1.255 = 0.645; the middle
        // branch just below gives 1.1231^2.7 − 0.72 = 0.64814.
        assert!((log_t_p(1.9) - 0.645).abs() < EPS);
        let below = log_t_p(1.9 - 1e-12);
        assert!((below - 0.648_137_5).abs() < 1e-6, "{below}");
        assert!((below - log_t_p(1.9)).abs() < 0.004);
        // Middle: log La = 0 → 0.65^2.7 − 0.72 = −0.407488.
        assert!((log_t_p(0.0) - -0.407_488_457).abs() < 1e-8);
        // log La = 1 → 0.899^2.7 − 0.72 = 0.030155.
        assert!((log_t_p(1.0) - 0.030_155_275).abs() < 1e-8);
        // Linear form agrees.
        assert!((t_p(1.0).log10() - log_t_p(0.0)).abs() < 1e-12);
    }

    #[test]
    fn scotopic_breakpoints_and_middle() {
        assert_eq!(log_t_s(-3.94), -2.86);
        // base 0.405·(−3.94) + 1.6 = 0.0043 → 0.0043^2.18 ≈ 7e-6
        assert!((log_t_s(-3.94 + 1e-12) - -2.86).abs() < 1e-5);
        // Upper: Weber −1.44 − 0.395 = −1.835; middle gives 1.0168^2.18 − 2.86.
        assert!((log_t_s(-1.44) - -1.835).abs() < EPS);
        let below = log_t_s(-1.44 - 1e-12);
        assert!((below - -1.823_012_6).abs() < 1e-6, "{below}");
        assert!((below - log_t_s(-1.44)).abs() < 0.013);
        // Middle: log La = −3 → 0.385^2.18 − 2.86 = −2.735174.
        assert!((log_t_s(-3.0) - -2.735_174_19).abs() < 1e-8);
        // log La = −2 → 0.79^2.18 − 2.86 = −2.261827.
        assert!((log_t_s(-2.0) - -2.261_826_65).abs() < 1e-8);
    }

    #[test]
    fn mesopic_weight_limits() {
        assert_eq!(k_mesopic(0.03), 0.0);
        assert_eq!(k_mesopic(0.001), 0.0);
        // Just above 0.03 the base is clamped, k stays ≈ 0 (continuous).
        assert!(k_mesopic(0.030_001) < 1e-4);
        assert_eq!(k_mesopic(3.0), 1.0);
        assert_eq!(k_mesopic(1e4), 1.0);
        // Just below 3: (0.5·log 3 + 0.761)^1.5 = 0.99934.
        assert!((k_mesopic(3.0 - 1e-12) - 0.999_341).abs() < 1e-6);
        // Middle: k(0.3) = (0.5·log 0.3 + 0.761)^1.5 = 0.353087.
        assert!((k_mesopic(0.3) - 0.353_087_468).abs() < 1e-8);
        // Monotonic over the mesopic range.
        let mut prev = 0.0;
        for i in 0..=100 {
            let la = 0.03 * 100f64.powf(i as f64 / 100.0);
            let k = k_mesopic(la);
            assert!(k >= prev, "k not monotonic at {la}");
            prev = k;
        }
    }

    #[test]
    fn mesopic_threshold_interpolates() {
        // Scotopic and photopic limits.
        assert!((t_m(0.01) - t_s(0.01)).abs() < EPS);
        assert!((t_m(100.0) - t_p(100.0)).abs() < EPS);
        let la = 0.3;
        let k = 0.353_087_468;
        let expected = t_s(la) * (1.0 - k) + t_p(la) * k;
        assert!((t_m(la) - expected).abs() < 1e-9);
        assert!(t_m(la) > t_s(la).min(t_p(la)) && t_m(la) < t_s(la).max(t_p(la)));
    }

    #[test]
    fn light_adaptation_overshoot() {
        // Fully adapted: no overshoot.
        assert!((t_star(10.0, 10.0) - t_m(10.0)).abs() < EPS);
        // Adapted to 0.01, looking at 100: t* = t_m(100)² / t_m(0.01).
        let ts = t_star(0.01, 100.0);
        let expected = t_m(100.0) * t_m(100.0) / t_m(0.01);
        assert!((ts - expected).abs() < 1e-9 * expected);
        assert!(ts > t_m(100.0) * 10.0);
        // Decreases monotonically to t_m(L̄) as L_wa rises to L̄.
        let mut prev = f64::INFINITY;
        for i in 0..=40 {
            let l_wa = 0.01 * 10f64.powf(i as f64 / 10.0);
            let t = t_star(l_wa, 100.0);
            assert!(t <= prev);
            prev = t;
        }
        assert!((prev - t_m(100.0)).abs() < 1e-9);
    }
}
