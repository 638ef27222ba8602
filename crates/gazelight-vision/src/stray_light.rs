//! The eye's intraocular stray light (CIE 146:2002) and the diffraction
//! lobe of one small particle, the two analytic parts of the glare kernel
//! ([`crate::psf`]).
//!
//! * [`cie146_veil_per_sr`] — the CIE 146:2002 General Disability Glare
//!   equation: the equivalent veiling luminance `L_veil` at `θ` degrees from
//!   a glare source that produces the illuminance `E_glare` at the eye, as
//!   `L_veil / E_glare` in sr⁻¹. Read as a point spread function, it is the
//!   fraction of the light entering the eye that lands per steradian at `θ`
//!   (valid 0.1°–100°).
//! * [`airy_lobe_per_sr`] — the Fraunhofer diffraction pattern of an opaque
//!   disc (Babinet: the same as a circular hole of its size), normalised to
//!   unit power: what one particle of the lens or cornea scatters.
//! * [`bessel_j1`] — the Bessel function J1 (Abramowitz & Stegun 9.4.4 and
//!   9.4.6 polynomial fits, |error| < 1e-7).

/// CIE 146:2002 General Disability Glare equation, `L_veil / E_glare` in
/// sr⁻¹, at `theta_deg` degrees from the glare source, for an observer of
/// `age_years` with ocular pigmentation `pigmentation` (0 very dark eyes,
/// 0.5 brown, 1.0 blue-green, 1.2 very light). Defined for 0.1°–100°; the
/// caller keeps θ in that range (it is evaluated as written outside).
pub fn cie146_veil_per_sr(theta_deg: f64, age_years: f64, pigmentation: f64) -> f64 {
    let t = theta_deg;
    // CIE 146:2002 General Disability Glare equation
    let age = 1.0 + (age_years / 62.5).powi(4);
    10.0 / (t * t * t) + (5.0 / (t * t) + 0.1 * pigmentation / t) * age + 0.0025 * pigmentation
}

/// Bessel function of the first kind of order one (Abramowitz & Stegun
/// 9.4.4 for |x| ≤ 3, 9.4.6 beyond; absolute error below 1.3e-8 and 4e-8).
pub fn bessel_j1(x: f64) -> f64 {
    let ax = x.abs();
    if ax <= 3.0 {
        // A&S 9.4.4: x⁻¹ J1(x) as a polynomial in (x/3)²
        let y = (x / 3.0) * (x / 3.0);
        x * (0.5
            + y * (-0.562_499_85
                + y * (0.210_935_73
                    + y * (-0.039_542_89
                        + y * (0.004_433_19 + y * (-0.000_317_61 + y * 0.000_011_09))))))
    } else {
        // A&S 9.4.6: J1(x) = x^-1/2 f1 cos θ1, in u = 3/x
        let u = 3.0 / ax;
        let f1 = 0.797_884_56
            + u * (0.000_001_56
                + u * (0.016_596_67
                    + u * (0.000_171_05
                        + u * (-0.002_495_11 + u * (0.001_136_53 + u * (-0.000_200_33))))));
        let t1 = ax - 2.356_194_49
            + u * (0.124_996_12
                + u * (0.000_056_50
                    + u * (-0.006_378_79
                        + u * (0.000_743_48 + u * (0.000_798_24 + u * (-0.000_291_66))))));
        let r = f1 * t1.cos() / ax.sqrt();
        if x < 0.0 { -r } else { r }
    }
}

/// The Airy pattern of a circular aperture (or, by Babinet, an opaque disc)
/// of diameter `diameter_m` at `wavelength_m`, normalised to unit power:
/// `I(θ) = π D² / (4 λ²) · (2 J1(x) / x)²`, `x = π D θ / λ`, per steradian,
/// `theta_rad` from the axis (small angles).
pub fn airy_lobe_per_sr(theta_rad: f64, diameter_m: f64, wavelength_m: f64) -> f64 {
    let peak = std::f64::consts::PI * diameter_m * diameter_m / (4.0 * wavelength_m * wavelength_m);
    let x = std::f64::consts::PI * diameter_m * theta_rad / wavelength_m;
    if x.abs() < 1e-6 {
        return peak;
    }
    let a = 2.0 * bessel_j1(x) / x;
    peak * a * a
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn j1_matches_tabulated_values() {
        // Abramowitz & Stegun table 9.1 (J1 at x = 1, 2, 5, 10) and the
        // first zero j1,1 = 3.831 705 97 (A&S table 9.5).
        for (x, want) in [
            (1.0, 0.440_050_585_7),
            (2.0, 0.576_724_807_8),
            (5.0, -0.327_579_137_6),
            (10.0, 0.043_472_746_2),
        ] {
            assert!((bessel_j1(x) - want).abs() < 1e-7, "J1({x})");
            assert!((bessel_j1(-x) + want).abs() < 1e-7, "J1(-{x})");
        }
        assert!(bessel_j1(3.831_705_97).abs() < 1e-7);
    }

    #[test]
    fn airy_lobe_has_unit_power() {
        // ∫ I dΩ = ∫ I 2π θ dθ over the lobe (numerically, to 1e-3 rad).
        let (d, l) = (5e-6, 575e-9);
        let n = 400_000;
        let h = 1.5 / n as f64;
        let total: f64 = (0..n)
            .map(|i| {
                let t = (i as f64 + 0.5) * h;
                airy_lobe_per_sr(t, d, l) * std::f64::consts::TAU * t * h
            })
            .sum();
        // Encircled energy beyond 1.5 rad of a 5 µm disc: ≈ 2/(π x) ≈ 1.5 %.
        assert!(total > 0.97 && total < 1.0, "{total}");
    }

    #[test]
    fn cie_equation_values() {
        // Written out: θ = 1°, A = 25, p = 0.5:
        // 10 + (5 + 0.05)(1 + 0.4⁴) + 0.00125
        let want = 10.0 + 5.05 * (1.0 + 0.4f64.powi(4)) + 0.00125;
        assert!((cie146_veil_per_sr(1.0, 25.0, 0.5) - want).abs() < 1e-12);
    }
}
