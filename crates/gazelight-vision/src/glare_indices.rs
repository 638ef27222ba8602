//! The glare indices lighting research reports — DGP, DGI, UGR, VCP and
//! CGI — the Stiles–Holladay veil, and the position index that weights a
//! source by where it sits in the field, computed from a list of glare
//! sources as evalglare 3.06 computes them (J. Wienold, Fraunhofer ISE /
//! EPFL; Radiance's `src/util/evalglare.c`, functions `get_dgp`,
//! `get_dgi`, `get_ugr`, `get_dgr`, `get_vcp`, `get_cgi`, `get_posindex`
//! and the detailed output's `Lveil_cie`). [`crate::scene_glare`] finds
//! the sources; the formulas live here and only here.
//!
//! Every sum runs over the sources i with luminance L_i (cd/m²), solid
//! angle ω_i (sr) and position index P_i:
//!
//! * DGP = 5.87·10⁻⁵ E_v + 0.159 +
//!   0.092 log₁₀(1 + Σ L_i² ω_i / (P_i² E_v^1.87)), at most 1 (Wienold &
//!   Christoffersen 2006; evalglare's default has no low-light correction
//!   since 2.14);
//! * DGI = 10 log₁₀ Σ 0.478 L_i^1.6 Ω_i^0.8 / (L_b + 0.07 ω_i^0.5 L_i),
//!   Ω_i = ω_i / P_i² (evalglare's modified solid angle);
//! * UGR = 8 log₁₀(0.25 / L_b · Σ L_i² ω_i / P_i²) (CIE 117);
//! * VCP = 50 erf((6.374 − 1.3227 ln DGR) / √2) + 50, 100 below DGR 20
//!   and 0 above 750, with DGR = (Σ 0.5 L_i (20.4 ω_i + 1.52 ω_i^0.2 −
//!   0.075) / (P_i L_avg^0.44))^(n^−0.0914) over n sources and the image's
//!   average luminance L_avg (IES, Guth);
//! * CGI = 8 log₁₀(2 (1 + E_d / 500) / E_v · Σ L_i² ω_i / P_i²)
//!   (Einhorn 1979), E_d the sources' direct illuminance;
//! * without sources DGI, UGR and CGI are 0 and VCP is 100, as evalglare
//!   prints them; UGR is `None` where evalglare prints −99 (no background
//!   luminance).

use glam::DVec3;
use serde::Serialize;

/// One glare source as the indices see it.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct IndexSource {
    /// Mean luminance, cd/m².
    pub luminance_cd_m2: f64,
    /// Solid angle, sr.
    pub solid_angle_sr: f64,
    /// Guth position index ([`position_index`]).
    pub position_index: f64,
}

/// The scene quantities the indices take besides the sources.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct IndexScene {
    /// Vertical illuminance at the eye, lux.
    pub vertical_illuminance_lux: f64,
    /// The sources' direct illuminance at the eye, lux.
    pub direct_illuminance_lux: f64,
    /// Background luminance (evalglare's default: (E_v − E_d)/π), cd/m².
    pub background_luminance_cd_m2: f64,
    /// The image's average luminance Σ L ω / Σ ω, cd/m² (DGR/VCP).
    pub average_luminance_cd_m2: f64,
}

/// DGP, DGI, UGR, VCP and CGI of one view.
#[derive(Clone, Copy, Debug, PartialEq, Serialize)]
pub struct GlareIndices {
    /// Daylight glare probability, 0…1.
    pub dgp: f64,
    /// Daylight glare index.
    pub dgi: f64,
    /// Unified glare rating; `None` without background luminance
    /// (evalglare prints −99).
    pub ugr: Option<f64>,
    /// Visual comfort probability, percent.
    pub vcp: f64,
    /// CIE glare index.
    pub cgi: f64,
}

/// The indices of `sources` seen in `scene`.
pub fn glare_indices(sources: &[IndexSource], scene: &IndexScene) -> GlareIndices {
    let e_v = scene.vertical_illuminance_lux;
    let l_b = scene.background_luminance_cd_m2;
    // Σ L² ω / P²: DGP, UGR and CGI share it.
    let sum_l2_om_p2: f64 = sources
        .iter()
        .map(|s| (s.luminance_cd_m2 / s.position_index).powi(2) * s.solid_angle_sr)
        .sum();
    // Wienold & Christoffersen 2006 (evalglare c1 = 5.87e-5, c3 = 0.159)
    let mut dgp = 5.87e-5 * e_v + 0.159;
    if !sources.is_empty() && e_v > 0.0 {
        // Wienold & Christoffersen 2006 (evalglare c2 = 0.092, a3 = 1.87)
        dgp += 0.092 * (1.0 + sum_l2_om_p2 / e_v.powf(1.87)).log10();
    }
    let dgp = dgp.min(1.0);
    if sources.is_empty() {
        // evalglare 3.06: no glare source → DGI, UGR, CGI 0, VCP 100.
        return GlareIndices {
            dgp,
            dgi: 0.0,
            ugr: Some(0.0),
            vcp: 100.0,
            cgi: 0.0,
        };
    }
    let dgi_sum: f64 = sources
        .iter()
        .map(|s| {
            let omega_mod = s.solid_angle_sr / (s.position_index * s.position_index);
            // Hopkinson's DGI as evalglare's get_dgi: 0.478 L^1.6 Ω^0.8 / (L_b + 0.07 ω^0.5 L)
            0.478 * s.luminance_cd_m2.powf(1.6) * omega_mod.powf(0.8)
                / (l_b + 0.07 * s.solid_angle_sr.sqrt() * s.luminance_cd_m2)
        })
        .sum();
    let dgi = 10.0 * dgi_sum.log10();
    let ugr = if l_b <= 0.0 {
        None
    } else if sum_l2_om_p2 == 0.0 {
        Some(0.0)
    } else {
        // CIE 117-1995: UGR = 8 log10(0.25 / L_b Σ L² ω / P²)
        Some(8.0 * (0.25 / l_b * sum_l2_om_p2).log10())
    };
    // CIE glare index (Einhorn 1979) as evalglare's get_cgi.
    let cgi =
        8.0 * (2.0 * (1.0 + scene.direct_illuminance_lux / 500.0) / e_v * sum_l2_om_p2).log10();
    let vcp = vcp_from_dgr(discomfort_glare_rating(
        sources,
        scene.average_luminance_cd_m2,
    ));
    GlareIndices {
        dgp,
        dgi,
        ugr,
        vcp,
        cgi,
    }
}

/// Discomfort glare rating (IES, Guth), evalglare's `get_dgr`.
fn discomfort_glare_rating(sources: &[IndexSource], average_cd_m2: f64) -> f64 {
    let sum: f64 = sources
        .iter()
        .map(|s| {
            let om = s.solid_angle_sr;
            // IES DGR (evalglare get_dgr): 0.5 L (20.4 ω + 1.52 ω^0.2 − 0.075) / (P L_a^0.44)
            0.5 * s.luminance_cd_m2 * (20.4 * om + 1.52 * om.powf(0.2) - 0.075)
                / (s.position_index * average_cd_m2.powf(0.44))
        })
        .sum();
    // IES DGR: the sum to the power n^−0.0914 (evalglare get_dgr)
    sum.powf((sources.len() as f64).powf(-0.0914))
}

/// VCP from DGR, evalglare's `get_vcp` (its 2.07 constant 6.374).
fn vcp_from_dgr(dgr: f64) -> f64 {
    // evalglare get_vcp: 0 above DGR 750, 100 below DGR 20.
    if dgr > 750.0 {
        return 0.0;
    }
    if dgr < 20.0 {
        return 100.0;
    }
    // IES VCP (evalglare get_vcp): 50 erf((6.374 − 1.3227 ln DGR)/√2) + 50
    50.0 * erf((6.374 - 1.3227 * dgr.ln()) / std::f64::consts::SQRT_2) + 50.0
}

/// The error function, Abramowitz & Stegun 7.1.26 (|error| ≤ 1.5·10⁻⁷).
fn erf(x: f64) -> f64 {
    // Abramowitz & Stegun 7.1.26: p and a1…a5.
    const P: f64 = 0.327_591_1;
    const A: [f64; 5] = [
        0.254_829_592,
        -0.284_496_736,
        1.421_413_741,
        -1.453_152_027,
        1.061_405_429,
    ];
    let t = 1.0 / (1.0 + P * x.abs());
    let poly = t * (A[0] + t * (A[1] + t * (A[2] + t * (A[3] + t * A[4]))));
    let y = 1.0 - poly * (-x * x).exp();
    if x < 0.0 { -y } else { y }
}

/// Guth's position index of a source in direction `dir` for an eye
/// looking along `gaze` with `up` the view's up vector (evalglare takes
/// its image's `-vu` as it is, not made orthogonal to the view
/// direction), as evalglare's `get_posindex`: σ the angle from the line
/// of sight, τ the angle of the source's meridian from up, both degrees;
/// above the line of sight the IES handbook's fit of Guth's table, below
/// it Iwata & Osterhaus (CIE 2010) in Kikuchi's coordinates (evalglare
/// 3.02); at most 16.
pub fn position_index(gaze: DVec3, up: DVec3, dir: DVec3) -> f64 {
    let g = gaze.normalize_or(DVec3::NEG_Z);
    let u = up.normalize_or(DVec3::Y);
    let d = dir.normalize_or(g);
    let cos_s = g.dot(d).clamp(-1.0, 1.0);
    let sigma_deg = cos_s.acos().to_degrees();
    // evalglare pict_get_tau: the direction scaled onto the plane at unit
    // distance along the gaze, minus the gaze, against up.
    let h = d / cos_s - g;
    let tau_deg = if cos_s > 0.0 && h.length() > 1e-12 {
        u.dot(h.normalize()).clamp(-1.0, 1.0).acos().to_degrees()
    } else {
        90.0
    };
    // evalglare pict_get_vangle: acos(vv·d) − π/2, vv = g × (g × up).
    let vv = g.cross(g.cross(u));
    let phi = vv.dot(d).clamp(-1.0, 1.0).acos() - std::f64::consts::FRAC_PI_2;
    position_index_guth(sigma_deg, tau_deg, phi < 0.0)
}

/// Guth's position index from σ and τ in degrees (see [`position_index`]).
pub fn position_index_guth(sigma_deg: f64, tau_deg: f64, below_line_of_sight: bool) -> f64 {
    let (s, t) = (sigma_deg.abs(), tau_deg);
    let p = if below_line_of_sight {
        // Iwata & Osterhaus 2010 (CIE), evalglare 3.02: β = atan(tan σ √(1 + 0.3225 cos² τ))
        let beta = (s.to_radians().tan() * (1.0 + 0.3225 * t.to_radians().cos().powi(2)).sqrt())
            .atan()
            .to_degrees();
        // Iwata & Osterhaus 2010: P = exp(6.49e-3 β + 21e-5 β²)
        (6.49e-3 * beta + 21.0e-5 * beta * beta).exp()
    } else {
        // Guth, IES Lighting Handbook fit (evalglare get_posindex)
        ((35.2 - 0.31889 * t - 1.22 * (-2.0 * t / 9.0).exp()) / 1000.0 * s
            + (21.0 + 0.26667 * t - 0.002963 * t * t) / 100_000.0 * s * s)
            .exp()
    };
    // evalglare get_posindex: capped at 16.
    p.min(16.0)
}

/// The Stiles–Holladay veil of one source, cd/m²: 10 E / θ², θ in
/// degrees (evalglare's `Lveil_cie` term; the caller keeps θ > 0).
pub fn veil_stiles_holladay_cd_m2(illuminance_lux: f64, theta_deg: f64) -> f64 {
    // Stiles–Holladay (CIE), evalglare 1.12: Lveil = 10 E / θ²
    10.0 * illuminance_lux / (theta_deg * theta_deg)
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn erf_matches_known_values() {
        // erf(0.5), erf(1), erf(2) to 10 digits (tables).
        assert!((erf(0.5) - 0.520_499_877_8).abs() < 3e-7);
        assert!((erf(1.0) - 0.842_700_792_9).abs() < 3e-7);
        assert!((erf(-2.0) + 0.995_322_265_0).abs() < 3e-7);
    }

    #[test]
    fn position_index_is_one_on_the_line_of_sight_and_grows_off_it() {
        let g = DVec3::NEG_Z;
        assert!((position_index(g, DVec3::Y, g) - 1.0).abs() < 1e-12);
        let at = |az: f64, el: f64| {
            let (a, e) = (az.to_radians(), el.to_radians());
            DVec3::new(e.cos() * a.sin(), e.sin(), -e.cos() * a.cos())
        };
        let side = position_index(g, DVec3::Y, at(30.0, 0.0));
        let far = position_index(g, DVec3::Y, at(60.0, 0.0));
        assert!(side > 1.0 && far > side, "{side} {far}");
        // Above: τ = 0 (straight up) at σ = 20°: Guth's fit by hand.
        let up20 = position_index(g, DVec3::Y, at(0.0, 20.0));
        let t = 0.0f64;
        let hand = ((35.2 - 0.31889 * t - 1.22 * (-2.0 * t / 9.0).exp()) / 1000.0 * 20.0
            + (21.0 + 0.26667 * t - 0.002963 * t * t) / 100_000.0 * 400.0)
            .exp();
        assert!((up20 - hand).abs() < 1e-9, "{up20} vs {hand}");
        // Below: τ = 180° at σ = 20°: β = σ √… (Iwata).
        let down20 = position_index(g, DVec3::Y, at(0.0, -20.0));
        let beta = (20f64.to_radians().tan() * 1.3225f64.sqrt())
            .atan()
            .to_degrees();
        let hand = (6.49e-3 * beta + 21.0e-5 * beta * beta).exp();
        assert!((down20 - hand).abs() < 1e-9, "{down20} vs {hand}");
        assert!(position_index(g, DVec3::Y, at(89.0, 0.0)) <= 16.0);
    }

    #[test]
    fn no_sources_give_evalglares_empty_values() {
        let scene = IndexScene {
            vertical_illuminance_lux: 1000.0,
            direct_illuminance_lux: 0.0,
            background_luminance_cd_m2: 1000.0 / std::f64::consts::PI,
            average_luminance_cd_m2: 300.0,
        };
        let r = glare_indices(&[], &scene);
        assert!((r.dgp - (5.87e-5 * 1000.0 + 0.159)).abs() < 1e-12);
        assert_eq!((r.dgi, r.ugr, r.vcp, r.cgi), (0.0, Some(0.0), 100.0, 0.0));
    }
}
