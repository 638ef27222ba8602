//! The glare point spread function (001 §4.2, eq 5–10), in physical units.
//!
//! # Model
//!
//! The eye is modelled after 001 §4.2.2 (which follows Ritschel et al. and
//! Kakimoto et al.): a pupil-plane grid of `N × N` complex samples holds the
//! lens equation (001 eq 7)
//!
//! ```text
//! L(x, y) = P(x, y) · F(x, y) · A(x, y)
//! ```
//!
//! * `P` — the static particle field of the cornea and lens: `particles`
//!   opaque discs of diameter `particle_um`, at seeded pseudo-random positions
//!   (a SplitMix64 generator, so a seed always gives the same field) spread
//!   uniformly over the disc of the largest pupil the grid supports
//!   (`pupil_plane_mm / 2`), so that a dilating pupil uncovers more particles
//!   of the same static field. Discs wider than a sample are drawn
//!   anti-aliased; smaller ones remove their geometric area from the nearest
//!   four samples (bilinear splat of the opacity). Overlaps multiply
//!   transmissions.
//! * `F` — the Fresnel term `exp(iπ(x² + y²)/(λd))` with λ = 575 nm and
//!   d = 24 mm (001 eq 6). The refraction of the cornea and lens of an eye
//!   focused on the retina contributes the opposite quadratic phase
//!   `exp(−iπ(x² + y²)/(λ f))` with `f = d`; their product is the residual
//!   defocus `exp(iπ(x² + y²)·ΔD/λ)` with `ΔD = 1/d − 1/f` in dioptres
//!   ([`PsfParams::defocus_dioptres`], default 0 = in focus). The product is
//!   evaluated analytically: the bare Fresnel term cannot be sampled on any
//!   practical grid (at the edge of a 20 mm plane with 512 samples its phase
//!   advances by about 2π·28 per sample), and a physical eye does see its
//!   in-focus Airy pattern. [`PsfParams::validate`] rejects a defocus whose
//!   phase would alias on the grid.
//! * `A` — the pupil aperture, a disc of the live pupil diameter `pupil_mm`
//!   with an anti-aliased (one sample wide) edge.
//!
//! The monochromatic PSF is the Fraunhofer far field (001 eq 5, 8):
//!
//! ```text
//! M = |FFT(L) / N|² / (λ d)²        (λ, d in mm; the FFT is 2-D and unnormalised)
//! ```
//!
//! By Parseval, `Σ M · (λd)² = Σ |L|²`: the PSF holds exactly the light that
//! passes the pupil (the open area in samples).
//!
//! ## Physical sampling
//!
//! With pupil-plane spacing `Δx = pupil_plane_mm / N`, the FFT's frequency
//! spacing is `1/(N Δx)` cycles per mm. A plane-wave component of spatial
//! frequency `ν` leaves the pupil at angle `θ = λ ν` (small angles; the grating
//! equation), so one far-field sample subtends
//!
//! ```text
//! Δθ = λ / (N Δx) = λ / pupil_plane_mm     radians,
//! ```
//!
//! and the whole FFT field spans `N Δθ = λ / Δx`. At the reference 575 nm, with
//! the defaults (N = 512, 20 mm plane) that is Δθ = 2.875e-5 rad
//! (1.65e-3 °/sample) and a field of 0.84°. The first dark ring of a clean
//! aperture of diameter D lies at `1.22 λ / D` rad, i.e. `1.22 · pupil_plane_mm / D`
//! samples; the tests find it there. Finer detail of the particles (the
//! scattering angle of a particle of size s is about λ/s) than `λ/Δx` wraps
//! around the periodic FFT field: glare is simulated up to the field's edge.
//!
//! ## Spectral kernel
//!
//! 001 eq 9–10: `φ_i = 380 + i/k (770 − 380)` nm, `i = 0..=k`, with
//! `k + 1 = wavelength_count`, and `S_XYZ = 1/(k+1) Σ_i xyz(φ_i) M(x λ/φ_i, y λ/φ_i)`
//! with the CIE 1931 colour matching functions in the multi-lobe Gaussian fit
//! of Wyman, Sloan and Shirley (JCGT 2(2), 2013) cited by 001 ([44]). Only the
//! 575 nm field is transformed (as in 001); the PSF at `φ_i` is the Fraunhofer
//! scaling of it. One deviation from the literal eq 9: the rescaled PSF is
//! multiplied by the Jacobian `(λ/φ_i)²`, so that every wavelength carries the
//! same energy and a flat (equal-energy) spectrum is weighted by the colour
//! matching functions alone — without it eq 9 would give 770 nm
//! `(770/380)² ≈ 4×` the weight of 380 nm.
//!
//! The sum is not point-sampled: each display pixel receives the integral of
//! `M(θ λ/φ_i)(λ/φ_i)²` over its area, computed exactly (for the piecewise
//! constant reading of `M`) from a summed-area table. That is the
//! energy-preserving area average when the display pixel is larger than an
//! FFT sample (the usual case: at 13.85 ppd a display pixel is about 44 FFT
//! samples wide) and a box reconstruction when it is smaller. The display
//! kernel is `kernel_size × kernel_size` pixels of `deg_per_px = 1/ppd`,
//! centred at `(size/2, size/2)`; light falling outside it is dropped.
//!
//! `S_XYZ` is converted to linear sRGB (Rec. 709 primaries, D65 white),
//! negative components (monochromatic light is outside the sRGB gamut) are
//! clamped to 0, and **each channel is normalised to sum to 1**, so the kernel
//! redistributes light without changing its amount and a white point source
//! stays white (its centre keeps the source colour; the fringes are coloured).

use std::sync::Arc;

use rayon::prelude::*;
use rustfft::num_complex::Complex;
use rustfft::{Fft, FftPlanner};
use serde::{Deserialize, Serialize};

use crate::VisionError;

/// Reference wavelength of the monochromatic PSF, nm.
// 001 eq 6: λ = 575 nm, the mean of the visible spectrum
pub const REFERENCE_WAVELENGTH_NM: f64 = 575.0;
/// Distance from the pupil to the retina, mm.
// 001 eq 6: d = 24 mm, the human focal length
pub const PUPIL_RETINA_MM: f64 = 24.0;
/// Shortest wavelength of the spectral sum, nm.
// 001 eq 10: φ_0 = 380 nm
pub const SPECTRUM_MIN_NM: f64 = 380.0;
/// Longest wavelength of the spectral sum, nm.
// 001 eq 10: φ_k = 770 nm
pub const SPECTRUM_MAX_NM: f64 = 770.0;
/// Display resolution of the HTC Vive Pro, pixels per degree.
// 001 §4.3: 1440 px / 104° ≈ 13.85 ppd
pub const VIVE_PRO_PPD: f64 = 13.85;
/// Default kernel field, degrees (±20°, the glare window of issue 10).
pub const DEFAULT_FIELD_DEG: f64 = 40.0;
/// Default observer age, years (CIE 146:2002's young reference observer).
pub const DEFAULT_AGE_YEARS: f64 = 25.0;
/// Default ocular pigmentation (CIE 146:2002: 0.5 = brown eyes).
pub const DEFAULT_PIGMENTATION: f64 = 0.5;
/// Valid range of the CIE 146 age, years.
pub const AGE_YEARS_RANGE: (f64, f64) = (0.0, 120.0);
/// Valid range of the CIE 146 pigmentation (0 very dark … 1.2 very light).
pub const PIGMENTATION_RANGE: (f64, f64) = (0.0, 1.2);
/// Valid range of the kernel field, degrees (CIE 146 holds to 100°; the
/// field's half width is at most that).
pub const FIELD_DEG_RANGE: (f64, f64) = (0.01, 200.0);
/// Smallest pupil the PSF is built for, in pupil-plane samples across.
const MIN_PUPIL_SAMPLES: f64 = 4.0;

/// Parameters of the glare PSF.
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
#[serde(default, deny_unknown_fields)]
pub struct PsfParams {
    /// Pupil diameter, mm (the aperture `A` of 001 eq 7).
    pub pupil_mm: f64,
    /// Number of scattering particles in the static field `P` (0 = a clean
    /// aperture, whose PSF is an Airy pattern).
    pub particles: usize,
    /// Diameter of one particle, µm.
    // 001 Fig. 4: particle diameters of 6 µm and 10 µm (1000 particles)
    pub particle_um: f64,
    /// Residual defocus of the eye, dioptres: the Fresnel term (001 eq 6) times
    /// the eye's refraction; 0 = focused on the retina.
    pub defocus_dioptres: f64,
    /// Pupil-plane grid size `N` (FFT size), a power of two in 64..=2048.
    pub grid_size: usize,
    /// Physical width of the pupil-plane grid, mm. The default, 20 mm, is
    /// 2.5 × the largest pupil of 001 §5 (8 mm): pupils up to half the plane
    /// (10 mm) give an alias-free intensity PSF.
    pub pupil_plane_mm: f64,
    /// Number of wavelengths `k + 1` of the spectral sum (001 eq 9–10), ≥ 2.
    pub wavelength_count: usize,
    /// Display resolution, pixels per degree.
    pub ppd: f64,
    /// Output kernel size, display pixels: odd (3..=2049) or a power of two
    /// (4..=2048); the centre is pixel `(size/2, size/2)` (a power-of-two
    /// kernel has one more pixel on the negative side).
    pub kernel_size: usize,
    /// Angular width of the kernel's field, degrees: the kernel covers
    /// ±`field_deg / 2` around the point source (the glare window).
    pub field_deg: f64,
    /// Observer's age, years (CIE 146:2002 General Disability Glare, `A`).
    pub age_years: f64,
    /// Ocular pigmentation (CIE 146:2002, `p`): 0 very dark eyes, 0.5
    /// brown, 1.0 blue-green, 1.2 very light.
    pub pigmentation: f64,
    /// Whether the intraocular stray light (the CIE 146 veil) is part of
    /// the kernel; `false` leaves the wave-optics near field alone.
    pub stray_light: bool,
    /// Seed of the particle field.
    pub seed: u64,
}

impl Default for PsfParams {
    fn default() -> Self {
        Self {
            pupil_mm: 4.0,
            // 001 Fig. 4: 1000 particles
            particles: 1000,
            // 001 Fig. 4 (right): 10 µm particles
            particle_um: 10.0,
            defocus_dioptres: 0.0,
            grid_size: 512,
            pupil_plane_mm: 20.0,
            wavelength_count: 32,
            ppd: VIVE_PRO_PPD,
            kernel_size: 65,
            field_deg: DEFAULT_FIELD_DEG,
            age_years: DEFAULT_AGE_YEARS,
            pigmentation: DEFAULT_PIGMENTATION,
            stray_light: true,
            seed: 0x6a7e_11e7,
        }
    }
}

impl PsfParams {
    /// Pupil-plane sample spacing `Δx`, mm.
    pub fn sample_mm(&self) -> f64 {
        self.pupil_plane_mm / self.grid_size as f64
    }

    /// Largest pupil the grid supports without aliasing the intensity PSF, mm
    /// (half the pupil plane: the optical transfer function is the aperture's
    /// autocorrelation, twice as wide as the aperture).
    pub fn max_pupil_mm(&self) -> f64 {
        self.pupil_plane_mm / 2.0
    }

    /// Smallest pupil the grid resolves (4 samples across), mm.
    pub fn min_pupil_mm(&self) -> f64 {
        MIN_PUPIL_SAMPLES * self.sample_mm()
    }

    /// Angular size of one far-field sample at `wavelength_nm`, radians:
    /// `λ / (N Δx)`.
    pub fn rad_per_sample(&self, wavelength_nm: f64) -> f64 {
        wavelength_nm * 1e-6 / self.pupil_plane_mm
    }

    /// Checks every field; the error names the field and the valid range.
    pub fn validate(&self) -> Result<(), VisionError> {
        if !self.grid_size.is_power_of_two() || !(64..=2048).contains(&self.grid_size) {
            return Err(VisionError::invalid(
                "psf.grid_size",
                self.grid_size,
                "a power of two in 64..=2048",
            ));
        }
        if !(self.pupil_plane_mm.is_finite() && self.pupil_plane_mm > 0.0) {
            return Err(VisionError::invalid(
                "psf.pupil_plane_mm",
                self.pupil_plane_mm,
                "a finite number > 0",
            ));
        }
        self.check_pupil(self.pupil_mm)?;
        if self.particles > 0 && !(self.particle_um.is_finite() && self.particle_um > 0.0) {
            return Err(VisionError::invalid(
                "psf.particle_um",
                self.particle_um,
                "a finite diameter > 0 µm",
            ));
        }
        if self.particles > 10_000_000 {
            return Err(VisionError::invalid(
                "psf.particles",
                self.particles,
                "at most 10 000 000",
            ));
        }
        if !self.defocus_dioptres.is_finite() {
            return Err(VisionError::invalid(
                "psf.defocus_dioptres",
                self.defocus_dioptres,
                "a finite number",
            ));
        }
        // Phase step per sample at the edge of the largest pupil: 2π r ΔD Δx / λ ≤ π.
        let r_m = self.max_pupil_mm() / 2.0 * 1e-3;
        let step = 2.0 * r_m * self.defocus_dioptres.abs() * self.sample_mm() * 1e-3
            / (REFERENCE_WAVELENGTH_NM * 1e-9);
        if step > 1.0 {
            return Err(VisionError::invalid(
                "psf.defocus_dioptres",
                self.defocus_dioptres,
                "small enough that the defocus phase advances < π per pupil-plane sample (|ΔD| ≤ λ / (2 r Δx)); use a larger grid_size",
            ));
        }
        if self.wavelength_count < 2 || self.wavelength_count > 1024 {
            return Err(VisionError::invalid(
                "psf.wavelength_count",
                self.wavelength_count,
                "2..=1024 (k + 1 of 001 eq 10, k ≥ 1)",
            ));
        }
        if !(self.ppd.is_finite() && self.ppd > 0.0) {
            return Err(VisionError::invalid(
                "psf.ppd",
                self.ppd,
                "a finite number > 0",
            ));
        }
        if !(self.field_deg.is_finite()
            && (FIELD_DEG_RANGE.0..=FIELD_DEG_RANGE.1).contains(&self.field_deg))
        {
            return Err(VisionError::invalid(
                "psf.field_deg",
                self.field_deg,
                "0.01..=200 degrees (the kernel covers ±field_deg/2)",
            ));
        }
        if !(self.age_years.is_finite()
            && (AGE_YEARS_RANGE.0..=AGE_YEARS_RANGE.1).contains(&self.age_years))
        {
            return Err(VisionError::invalid(
                "psf.age_years",
                self.age_years,
                "0..=120 years (CIE 146:2002 observer age)",
            ));
        }
        if !(self.pigmentation.is_finite()
            && (PIGMENTATION_RANGE.0..=PIGMENTATION_RANGE.1).contains(&self.pigmentation))
        {
            return Err(VisionError::invalid(
                "psf.pigmentation",
                self.pigmentation,
                "0..=1.2 (CIE 146:2002: 0 very dark, 0.5 brown, 1.0 blue-green, 1.2 very light eyes)",
            ));
        }
        let ks = self.kernel_size;
        let ok = (ks % 2 == 1 && (3..=2049).contains(&ks))
            || (ks.is_power_of_two() && (4..=2048).contains(&ks));
        if !ok {
            return Err(VisionError::invalid(
                "psf.kernel_size",
                ks,
                "odd in 3..=2049 or a power of two in 4..=2048",
            ));
        }
        Ok(())
    }

    fn check_pupil(&self, pupil_mm: f64) -> Result<(), VisionError> {
        if !(pupil_mm.is_finite() && pupil_mm > 0.0) {
            return Err(VisionError::invalid(
                "psf.pupil_mm",
                pupil_mm,
                "a finite diameter > 0 mm",
            ));
        }
        if pupil_mm > self.max_pupil_mm() {
            return Err(VisionError::invalid(
                "psf.pupil_mm",
                pupil_mm,
                "at most pupil_plane_mm / 2 (the aperture must fit twice into the pupil-plane grid)",
            ));
        }
        if pupil_mm < self.min_pupil_mm() {
            return Err(VisionError::invalid(
                "psf.pupil_mm",
                pupil_mm,
                "at least 4 pupil-plane samples across (pupil_plane_mm / grid_size · 4)",
            ));
        }
        Ok(())
    }

    /// The wavelengths of the spectral sum, nm (001 eq 10).
    pub fn wavelengths_nm(&self) -> Vec<f64> {
        let k = self.wavelength_count.max(2) - 1;
        (0..=k)
            .map(|i| SPECTRUM_MIN_NM + i as f64 / k as f64 * (SPECTRUM_MAX_NM - SPECTRUM_MIN_NM))
            .collect()
    }
}

/// A monochromatic PSF at pupil-plane (FFT) sampling, centred at
/// `(size/2, size/2)`.
#[derive(Clone, Debug, PartialEq)]
pub struct MonoPsf {
    /// Samples per side (`grid_size`).
    pub size: usize,
    /// Wavelength, nm.
    pub wavelength_nm: f64,
    /// Angular size of one sample, radians: `λ / (N Δx)`.
    pub rad_per_px: f64,
    /// `M = |FFT(L)/N|² / (λd)²` (001 eq 8, λ and d in mm), row-major.
    pub values: Vec<f64>,
}

impl MonoPsf {
    /// Radial profile along the four axis directions from the centre
    /// (mean of +x, −x, +y, −y), radii `0..=r_max` samples.
    pub fn axis_profile(&self, r_max: usize) -> Vec<f64> {
        let n = self.size;
        let c = n / 2;
        let r_max = r_max.min(c.saturating_sub(1));
        let v = &self.values;
        (0..=r_max)
            .map(|r| {
                (v[c * n + c + r] + v[c * n + c - r] + v[(c + r) * n + c] + v[(c - r) * n + c])
                    / 4.0
            })
            .collect()
    }

    /// Radius of the first dark ring in radians: the first local minimum of
    /// the axis profile, refined by a parabola through the three samples
    /// around it. `None` when the profile has no minimum.
    pub fn first_minimum_rad(&self) -> Option<f64> {
        let p = self.axis_profile(self.size / 2);
        let i = (1..p.len().saturating_sub(1)).find(|&i| p[i] <= p[i - 1] && p[i] < p[i + 1])?;
        let (a, b, c) = (p[i - 1], p[i], p[i + 1]);
        let denom = a - 2.0 * b + c;
        let offset = if denom.abs() > 0.0 {
            0.5 * (a - c) / denom
        } else {
            0.0
        };
        Some((i as f64 + offset) * self.rad_per_px)
    }
}

/// The spectral glare kernel at display resolution.
#[derive(Clone, Debug, PartialEq)]
pub struct PsfKernel {
    /// Pixels per side.
    pub size: usize,
    /// Angular size of one kernel pixel, degrees (`1 / ppd`).
    pub deg_per_px: f64,
    /// Pupil diameter the kernel was built for, mm.
    pub pupil_mm: f64,
    /// Wavelengths of the spectral sum, nm.
    pub wavelengths_nm: Vec<f64>,
    /// Linear sRGB weights, row-major, centre at `(size/2, size/2)`; each
    /// channel sums to 1.
    pub rgb: Vec<[f32; 3]>,
}

impl PsfKernel {
    /// Sum of each channel (1 for a normalised kernel).
    pub fn energy(&self) -> [f64; 3] {
        let mut e = [0.0f64; 3];
        for p in &self.rgb {
            for c in 0..3 {
                e[c] += f64::from(p[c]);
            }
        }
        e
    }

    /// Index of the centre pixel along each axis (`size / 2`).
    pub fn centre(&self) -> usize {
        self.size / 2
    }

    /// Weight at offset `(dx, dy)` from the centre, 0 outside the kernel.
    pub fn at(&self, dx: isize, dy: isize) -> [f32; 3] {
        let c = self.centre() as isize;
        let (x, y) = (c + dx, c + dy);
        if x < 0 || y < 0 || x >= self.size as isize || y >= self.size as isize {
            return [0.0; 3];
        }
        self.rgb[y as usize * self.size + x as usize]
    }
}

/// CIE 1931 2° colour matching functions `[x̄, ȳ, z̄]` at `wavelength_nm`, by
/// the multi-lobe piecewise-Gaussian fit of Wyman, Sloan and Shirley,
/// "Simple Analytic Approximations to the CIE XYZ Color Matching Functions",
/// JCGT 2(2), 2013, eq 2–4 (001 ref. [44]).
pub fn cie_xyz_wyman(wavelength_nm: f64) -> [f64; 3] {
    // g(λ; μ, σ1, σ2): Gaussian with σ1 left of μ and σ2 right of it (Wyman 2013 eq 1)
    fn g(l: f64, mu: f64, s1: f64, s2: f64) -> f64 {
        let t = (l - mu) / if l < mu { s1 } else { s2 };
        (-0.5 * t * t).exp()
    }
    let l = wavelength_nm;
    // Wyman 2013 eq 2
    let x = 1.056 * g(l, 599.8, 37.9, 31.0) + 0.362 * g(l, 442.0, 16.0, 26.7)
        - 0.065 * g(l, 501.1, 20.4, 26.2);
    // Wyman 2013 eq 3
    let y = 0.821 * g(l, 568.8, 46.9, 40.5) + 0.286 * g(l, 530.9, 16.3, 31.1);
    // Wyman 2013 eq 4
    let z = 1.217 * g(l, 437.0, 11.8, 36.0) + 0.681 * g(l, 459.0, 26.0, 13.8);
    [x, y, z]
}

/// CIE XYZ → linear sRGB (IEC 61966-2-1: Rec. 709 primaries, D65 white).
pub const XYZ_TO_LINEAR_SRGB: [[f64; 3]; 3] = [
    [3.240_454_2, -1.537_138_5, -0.498_531_4],
    [-0.969_266_0, 1.876_010_8, 0.041_556_0],
    [0.055_643_4, -0.204_025_9, 1.057_225_2],
];

/// SplitMix64 (Steele, Lea, Flood 2014): a tiny, fast, deterministic PRNG.
struct SplitMix64(u64);

impl SplitMix64 {
    fn next_u64(&mut self) -> u64 {
        self.0 = self.0.wrapping_add(0x9e37_79b9_7f4a_7c15);
        let mut z = self.0;
        z = (z ^ (z >> 30)).wrapping_mul(0xbf58_476d_1ce4_e5b9);
        z = (z ^ (z >> 27)).wrapping_mul(0x94d0_49bb_1331_11eb);
        z ^ (z >> 31)
    }

    /// Uniform in [0, 1).
    fn next_f64(&mut self) -> f64 {
        (self.next_u64() >> 11) as f64 * (1.0 / (1u64 << 53) as f64)
    }
}

/// Transmission of the static particle field `P` on the N × N grid.
fn particle_field(params: &PsfParams) -> Vec<f64> {
    let n = params.grid_size;
    let dx = params.sample_mm();
    let mut t = vec![1.0f64; n * n];
    if params.particles == 0 {
        return t;
    }
    let mut rng = SplitMix64(params.seed);
    let field_r_mm = params.max_pupil_mm() / 2.0;
    let rad_samples = params.particle_um * 1e-3 / 2.0 / dx;
    let half = (n / 2) as f64;
    for _ in 0..params.particles {
        let r = field_r_mm * rng.next_f64().sqrt();
        let a = std::f64::consts::TAU * rng.next_f64();
        // Continuous grid coordinate: sample j sits at (j - N/2) Δx.
        let cx = r * a.cos() / dx + half;
        let cy = r * a.sin() / dx + half;
        if rad_samples >= 1.0 {
            let x0 = (cx - rad_samples - 1.0).floor().max(0.0) as usize;
            let x1 = ((cx + rad_samples + 1.0).ceil() as usize).min(n - 1);
            let y0 = (cy - rad_samples - 1.0).floor().max(0.0) as usize;
            let y1 = ((cy + rad_samples + 1.0).ceil() as usize).min(n - 1);
            for y in y0..=y1 {
                for x in x0..=x1 {
                    let d = ((x as f64 - cx).powi(2) + (y as f64 - cy).powi(2)).sqrt();
                    let cover = (rad_samples - d + 0.5).clamp(0.0, 1.0);
                    t[y * n + x] *= 1.0 - cover;
                }
            }
        } else {
            // Sub-sample particle: its geometric area, split bilinearly.
            let area = std::f64::consts::PI * rad_samples * rad_samples;
            let (fx, fy) = (cx.floor(), cy.floor());
            let (ux, uy) = (cx - fx, cy - fy);
            for (ox, wx) in [(0usize, 1.0 - ux), (1, ux)] {
                for (oy, wy) in [(0usize, 1.0 - uy), (1, uy)] {
                    let x = fx as usize + ox;
                    let y = fy as usize + oy;
                    if x < n && y < n {
                        t[y * n + x] *= (1.0 - area * wx * wy).max(0.0);
                    }
                }
            }
        }
    }
    t
}

/// Pupil-plane field, FFT plan and scratch: computes monochromatic PSFs.
struct MonoEngine {
    n: usize,
    fft: Arc<dyn Fft<f64>>,
    field: Vec<Complex<f64>>,
    scratch: Vec<Complex<f64>>,
    particles: Vec<f64>,
}

impl MonoEngine {
    fn new(params: &PsfParams) -> Self {
        let n = params.grid_size;
        let fft = FftPlanner::<f64>::new().plan_fft_forward(n);
        let scratch = vec![Complex::new(0.0, 0.0); fft.get_inplace_scratch_len()];
        Self {
            n,
            fft,
            field: vec![Complex::new(0.0, 0.0); n * n],
            scratch,
            particles: particle_field(params),
        }
    }

    /// Fills `out` (N², centred) with M (001 eq 8) for `pupil_mm` at
    /// `wavelength_nm`. Allocates nothing.
    fn compute(&mut self, params: &PsfParams, pupil_mm: f64, wavelength_nm: f64, out: &mut [f64]) {
        let n = self.n;
        let dx = params.sample_mm();
        let half = (n / 2) as f64;
        let r_samples = pupil_mm / 2.0 / dx;
        let lambda_m = wavelength_nm * 1e-9;
        // Residual of Fresnel term (001 eq 6) × the eye's refraction: π r² ΔD / λ.
        let defocus_per_mm2 = std::f64::consts::PI * params.defocus_dioptres * 1e-6 / lambda_m;
        let edge = r_samples + 1.0;
        for (j, row) in self.field.chunks_exact_mut(n).enumerate() {
            let y = j as f64 - half;
            let prow = &self.particles[j * n..(j + 1) * n];
            for (i, v) in row.iter_mut().enumerate() {
                let x = i as f64 - half;
                let r2 = x * x + y * y;
                if r2 > edge * edge {
                    *v = Complex::new(0.0, 0.0);
                    continue;
                }
                // 001 eq 7: anti-aliased aperture A
                let a = (r_samples - r2.sqrt() + 0.5).clamp(0.0, 1.0);
                let amp = a * prow[i];
                *v = if defocus_per_mm2 == 0.0 {
                    Complex::new(amp, 0.0)
                } else {
                    Complex::from_polar(amp, defocus_per_mm2 * r2 * dx * dx)
                };
            }
        }
        // 2-D FFT: rows, transpose, rows, transpose back.
        self.fft
            .process_with_scratch(&mut self.field, &mut self.scratch);
        transpose_square(&mut self.field, n);
        self.fft
            .process_with_scratch(&mut self.field, &mut self.scratch);
        transpose_square(&mut self.field, n);
        // 001 eq 8, λ and d in mm; fftshift so DC lands at (N/2, N/2).
        let lambda_d = wavelength_nm * 1e-6 * PUPIL_RETINA_MM;
        // |FFT/N|² with N the samples per side: Σ|FFT/N|² = Σ|L|² (Parseval).
        let scale = 1.0 / (n * n) as f64 / (lambda_d * lambda_d);
        let h = n / 2;
        for j in 0..n {
            let sj = (j + h) % n;
            for i in 0..n {
                let si = (i + h) % n;
                out[sj * n + si] = self.field[j * n + i].norm_sqr() * scale;
            }
        }
    }
}

/// In-place transpose of a square row-major matrix.
pub(crate) fn transpose_square<T: Copy>(m: &mut [T], n: usize) {
    for j in 0..n {
        for i in (j + 1)..n {
            m.swap(j * n + i, i * n + j);
        }
    }
}

/// The monochromatic PSF `M` (001 eq 8) of `params.pupil_mm` at
/// `wavelength_nm`, at pupil-plane sampling (`rad_per_px = λ / (N Δx)`).
pub fn monochromatic_psf(params: &PsfParams, wavelength_nm: f64) -> Result<MonoPsf, VisionError> {
    params.validate()?;
    if !(wavelength_nm.is_finite() && (200.0..=2000.0).contains(&wavelength_nm)) {
        return Err(VisionError::invalid(
            "wavelength_nm",
            wavelength_nm,
            "200..=2000 nm",
        ));
    }
    let mut engine = MonoEngine::new(params);
    let n = params.grid_size;
    let mut values = vec![0.0; n * n];
    engine.compute(params, params.pupil_mm, wavelength_nm, &mut values);
    Ok(MonoPsf {
        size: n,
        wavelength_nm,
        rad_per_px: params.rad_per_sample(wavelength_nm),
        values,
    })
}

/// Builds the spectral RGB glare kernel for `params` (001 eq 5–10).
pub fn build_kernel(params: &PsfParams) -> Result<PsfKernel, VisionError> {
    let builder = PsfBuilder::new(params.clone())?;
    Ok(builder.kernel)
}

/// Builds kernels repeatedly for a changing pupil: the FFT plan, the particle
/// field and every buffer are made once, so [`PsfBuilder::rebuild`] allocates
/// nothing. The resampling of the wavelengths runs in parallel (rayon).
pub struct PsfBuilder {
    params: PsfParams,
    engine: MonoEngine,
    /// M at 575 nm, centred, N².
    mono: Vec<f64>,
    /// Summed-area table of `mono`, (N+1)².
    sat: Vec<f64>,
    /// Colour matching function values per wavelength.
    cmf: Vec<[f64; 3]>,
    /// Energy per display pixel, per wavelength (count × size²).
    per_wavelength: Vec<f64>,
    /// XYZ accumulator, size².
    xyz: Vec<[f64; 3]>,
    kernel: PsfKernel,
}

impl PsfBuilder {
    /// Validates `params`, prepares every buffer and builds the first kernel
    /// (for `params.pupil_mm`).
    pub fn new(params: PsfParams) -> Result<Self, VisionError> {
        params.validate()?;
        let n = params.grid_size;
        let size = params.kernel_size;
        let wavelengths_nm = params.wavelengths_nm();
        let cmf = wavelengths_nm.iter().map(|&l| cie_xyz_wyman(l)).collect();
        let count = wavelengths_nm.len();
        let mut builder = Self {
            engine: MonoEngine::new(&params),
            mono: vec![0.0; n * n],
            sat: vec![0.0; (n + 1) * (n + 1)],
            cmf,
            per_wavelength: vec![0.0; count * size * size],
            xyz: vec![[0.0; 3]; size * size],
            kernel: PsfKernel {
                size,
                deg_per_px: 1.0 / params.ppd,
                pupil_mm: params.pupil_mm,
                wavelengths_nm,
                rgb: vec![[0.0; 3]; size * size],
            },
            params,
        };
        let pupil = builder.params.pupil_mm;
        builder.build(pupil);
        Ok(builder)
    }

    /// The parameters (with `pupil_mm` as given to `new`).
    pub fn params(&self) -> &PsfParams {
        &self.params
    }

    /// The most recently built kernel.
    pub fn kernel(&self) -> &PsfKernel {
        &self.kernel
    }

    /// Rebuilds the kernel for a new pupil diameter. A diameter outside the
    /// supported range ([`PsfParams::min_pupil_mm`] ..= [`PsfParams::max_pupil_mm`])
    /// is clamped into it; a non-finite one keeps the current kernel. Use
    /// [`PsfBuilder::try_rebuild`] to get an error instead.
    pub fn rebuild(&mut self, pupil_mm: f64) -> &PsfKernel {
        if pupil_mm.is_finite() {
            let p = pupil_mm.clamp(self.params.min_pupil_mm(), self.params.max_pupil_mm());
            self.build(p);
        }
        &self.kernel
    }

    /// Like [`PsfBuilder::rebuild`], but an unsupported pupil is an error.
    pub fn try_rebuild(&mut self, pupil_mm: f64) -> Result<&PsfKernel, VisionError> {
        self.params.check_pupil(pupil_mm)?;
        self.build(pupil_mm);
        Ok(&self.kernel)
    }

    fn build(&mut self, pupil_mm: f64) {
        let n = self.params.grid_size;
        self.engine.compute(
            &self.params,
            pupil_mm,
            REFERENCE_WAVELENGTH_NM,
            &mut self.mono,
        );
        // Summed-area table: sat[j][i] = Σ mono[y < j][x < i].
        let w = n + 1;
        self.sat[..w].fill(0.0);
        for j in 0..n {
            let mut row_sum = 0.0;
            self.sat[(j + 1) * w] = 0.0;
            for i in 0..n {
                row_sum += self.mono[j * n + i];
                self.sat[(j + 1) * w + i + 1] = self.sat[j * w + i + 1] + row_sum;
            }
        }

        let size = self.params.kernel_size;
        let c = (size / 2) as f64;
        let rad_per_px = self.params.ppd.recip().to_radians();
        let ref_rad = self.params.rad_per_sample(REFERENCE_WAVELENGTH_NM);
        let sat = &self.sat;
        let wavelengths = &self.kernel.wavelengths_nm;
        self.per_wavelength
            .par_chunks_mut(size * size)
            .zip(wavelengths.par_iter())
            .for_each(|(energy, &phi)| {
                // M_φ(θ)(λ/φ)² = M(θ λ/φ)(λ/φ)²; its integral over a display
                // pixel is the integral of M over the pixel scaled by λ/φ.
                let s = REFERENCE_WAVELENGTH_NM / phi;
                let to_m = s * rad_per_px / ref_rad; // FFT samples per display px
                let half = n as f64 / 2.0;
                for v in 0..size {
                    let y0 = (v as f64 - c - 0.5) * to_m + half + 0.5;
                    let y1 = y0 + to_m;
                    for u in 0..size {
                        let x0 = (u as f64 - c - 0.5) * to_m + half + 0.5;
                        let x1 = x0 + to_m;
                        energy[v * size + u] = sat_lerp(sat, n, y1, x1)
                            - sat_lerp(sat, n, y0, x1)
                            - sat_lerp(sat, n, y1, x0)
                            + sat_lerp(sat, n, y0, x0);
                    }
                }
            });

        // 001 eq 9: S_XYZ = 1/(k+1) Σ xyz(φ_i) M_i
        let count = self.cmf.len();
        let inv = 1.0 / count as f64;
        self.xyz.fill([0.0; 3]);
        for (i, cmf) in self.cmf.iter().enumerate() {
            let e = &self.per_wavelength[i * size * size..(i + 1) * size * size];
            for (acc, &ei) in self.xyz.iter_mut().zip(e) {
                for k in 0..3 {
                    acc[k] += cmf[k] * ei * inv;
                }
            }
        }
        // XYZ → linear sRGB, negatives clamped, per-channel unit energy.
        let mut sums = [0.0f64; 3];
        let m = &XYZ_TO_LINEAR_SRGB;
        for (out, xyz) in self.kernel.rgb.iter_mut().zip(&self.xyz) {
            for ch in 0..3 {
                let v = (m[ch][0] * xyz[0] + m[ch][1] * xyz[1] + m[ch][2] * xyz[2]).max(0.0);
                sums[ch] += v;
                out[ch] = v as f32;
            }
        }
        // Normalise in f64 from the f64 values, then store.
        for (out, xyz) in self.kernel.rgb.iter_mut().zip(&self.xyz) {
            for ch in 0..3 {
                let v = (m[ch][0] * xyz[0] + m[ch][1] * xyz[1] + m[ch][2] * xyz[2]).max(0.0);
                out[ch] = if sums[ch] > 0.0 {
                    (v / sums[ch]) as f32
                } else {
                    0.0
                };
            }
        }
        self.kernel.pupil_mm = pupil_mm;
    }
}

/// Bilinear lookup of the summed-area table at continuous corner coordinates
/// (`y`, `x` in 0..=N); outside the table the integral is clamped (M is 0
/// outside the FFT field).
#[inline]
fn sat_lerp(sat: &[f64], n: usize, y: f64, x: f64) -> f64 {
    let nf = n as f64;
    let y = y.clamp(0.0, nf);
    let x = x.clamp(0.0, nf);
    let (yi, xi) = (
        (y.floor() as usize).min(n - 1),
        (x.floor() as usize).min(n - 1),
    );
    let (fy, fx) = (y - yi as f64, x - xi as f64);
    let w = n + 1;
    let a = sat[yi * w + xi];
    let b = sat[yi * w + xi + 1];
    let c = sat[(yi + 1) * w + xi];
    let d = sat[(yi + 1) * w + xi + 1];
    (a * (1.0 - fx) + b * fx) * (1.0 - fy) + (c * (1.0 - fx) + d * fx) * fy
}

/// The transmission of the static particle field `P` (001 eq 7) that
/// [`build_kernel`] and [`PsfBuilder`] use for `params`: `grid_size²` values
/// in 0..=1, row-major, sample `(i, j)` at `((i − N/2) Δx, (j − N/2) Δx)`.
/// For the GPU twin, which uploads it once so both see the same field.
pub fn particle_transmission(params: &PsfParams) -> Result<Vec<f64>, VisionError> {
    params.validate()?;
    Ok(particle_field(params))
}

#[cfg(test)]
mod tests {
    use super::*;

    /// A fine far-field sampling for ring measurements: 64 mm plane, N = 1024
    /// (Δx = 62.5 µm, 8.98e-6 rad per sample at 575 nm).
    fn airy_params(pupil_mm: f64) -> PsfParams {
        PsfParams {
            pupil_mm,
            particles: 0,
            grid_size: 1024,
            pupil_plane_mm: 64.0,
            ..PsfParams::default()
        }
    }

    #[test]
    fn clean_aperture_is_airy_with_first_minimum_at_1_22_lambda_over_d() {
        let lambda_m = REFERENCE_WAVELENGTH_NM * 1e-9;
        let mut radii = Vec::new();
        for d_mm in [2.0, 4.0, 8.0] {
            let m = monochromatic_psf(&airy_params(d_mm), REFERENCE_WAVELENGTH_NM).unwrap();
            let r = m.first_minimum_rad().expect("a dark ring");
            let expected = 1.22 * lambda_m / (d_mm * 1e-3);
            let err = (r - expected).abs() / expected;
            eprintln!(
                "D = {d_mm} mm: first minimum {r:.5e} rad, 1.22 λ/D = {expected:.5e} rad, error {:.2} %",
                err * 100.0
            );
            assert!(
                err < 0.03,
                "D = {d_mm} mm: first minimum {r:.4e} rad, expected {expected:.4e} (err {err:.4})"
            );
            // The peak is on axis and the first minimum is dark (Airy: exactly 0).
            let p = m.axis_profile(2);
            let c = m.size / 2;
            let peak = m.values[c * m.size + c];
            assert!(p[0] == peak && peak > p[1], "peak not at the centre");
            radii.push(r);
        }
        // The ring radius scales as 1/D.
        for w in radii.windows(2) {
            let ratio = w[0] / w[1];
            assert!(
                (ratio - 2.0).abs() < 0.06,
                "doubling D must halve the ring radius: ratio {ratio}"
            );
        }
    }

    #[test]
    fn airy_minimum_follows_wavelength() {
        // 001 eq 8 at another wavelength: the ring moves with λ.
        let params = airy_params(4.0);
        let m = monochromatic_psf(&params, 450.0).unwrap();
        let expected = 1.22 * 450e-9 / 4e-3;
        let r = m.first_minimum_rad().expect("a dark ring");
        assert!((r - expected).abs() / expected < 0.03, "{r} vs {expected}");
        assert!((m.rad_per_px - 450e-6 / 64.0).abs() < 1e-15);
    }

    #[test]
    fn parseval_psf_holds_the_light_through_the_pupil() {
        // Σ M (λd)² = Σ|L|² = open pupil area in samples (π R² / Δx²).
        let params = PsfParams {
            particles: 0,
            ..PsfParams::default()
        };
        let m = monochromatic_psf(&params, REFERENCE_WAVELENGTH_NM).unwrap();
        let lambda_d = REFERENCE_WAVELENGTH_NM * 1e-6 * PUPIL_RETINA_MM;
        let total: f64 = m.values.iter().sum::<f64>() * lambda_d * lambda_d;
        let r = params.pupil_mm / 2.0 / params.sample_mm();
        let area = std::f64::consts::PI * r * r;
        assert!(
            (total - area).abs() / area < 0.01,
            "Σ M (λd)² = {total}, pupil area {area} samples"
        );
    }

    fn core_fraction(m: &MonoPsf, pupil_mm: f64) -> f64 {
        let n = m.size;
        let c = (n / 2) as f64;
        let core = 1.22 * REFERENCE_WAVELENGTH_NM * 1e-9 / (pupil_mm * 1e-3) / m.rad_per_px;
        let mut inside = 0.0;
        let mut total = 0.0;
        for j in 0..n {
            for i in 0..n {
                let v = m.values[j * n + i];
                total += v;
                if (i as f64 - c).hypot(j as f64 - c) <= core {
                    inside += v;
                }
            }
        }
        inside / total
    }

    #[test]
    fn particles_move_energy_out_of_the_airy_core() {
        let clean = PsfParams {
            particles: 0,
            pupil_mm: 6.0,
            ..PsfParams::default()
        };
        let dusty = PsfParams {
            particles: 4000,
            particle_um: 60.0,
            ..clean.clone()
        };
        let f_clean = core_fraction(&monochromatic_psf(&clean, 575.0).unwrap(), 6.0);
        let f_dusty = core_fraction(&monochromatic_psf(&dusty, 575.0).unwrap(), 6.0);
        eprintln!("energy inside the Airy core: clean {f_clean:.4}, with particles {f_dusty:.4}");
        // An Airy pattern holds 83.8 % of its energy inside the first dark ring.
        assert!(
            (f_clean - 0.838).abs() < 0.02,
            "clean core fraction {f_clean}"
        );
        assert!(
            f_dusty < f_clean - 0.02,
            "particles must scatter light out of the core: {f_dusty} vs {f_clean}"
        );
    }

    #[test]
    fn kernel_has_unit_energy_per_channel() {
        let k = build_kernel(&PsfParams::default()).unwrap();
        assert_eq!(k.rgb.len(), 65 * 65);
        assert!((k.deg_per_px - 1.0 / 13.85).abs() < 1e-12);
        for (ch, e) in k.energy().iter().enumerate() {
            assert!((e - 1.0).abs() < 1e-4, "channel {ch} sums to {e}");
        }
        assert!(
            k.rgb
                .iter()
                .all(|p| p.iter().all(|v| v.is_finite() && *v >= 0.0))
        );
        // The centre pixel holds the most light.
        let c = k.at(0, 0);
        assert!(k.rgb.iter().all(|p| p[1] <= c[1]));
    }

    #[test]
    fn clean_kernel_is_radially_symmetric() {
        // High ppd so the Airy rings span many display pixels.
        let params = PsfParams {
            particles: 0,
            ppd: 2000.0,
            kernel_size: 65,
            wavelength_count: 16,
            ..PsfParams::default()
        };
        let k = build_kernel(&params).unwrap();
        let peak = k.at(0, 0)[1];
        let mut checked = 0;
        for a in 0..=32isize {
            for b in 0..=a {
                let v = k.at(a, b);
                for (x, y) in [(-b, a), (-a, -b), (b, -a), (b, a), (-a, b)] {
                    let w = k.at(x, y);
                    for ch in 0..3 {
                        let tol = 1e-4 * v[ch].max(w[ch]) + 1e-7 * peak;
                        assert!(
                            (v[ch] - w[ch]).abs() <= tol,
                            "({a},{b}) vs ({x},{y}) ch {ch}: {} vs {}",
                            v[ch],
                            w[ch]
                        );
                    }
                    checked += 1;
                }
            }
        }
        assert!(checked > 1000);
    }

    #[test]
    fn long_wavelengths_spread_further() {
        // Fraunhofer scaling (001 eq 9): the red part of the halo is wider.
        let params = PsfParams {
            particles: 0,
            ppd: 2000.0,
            kernel_size: 129,
            ..PsfParams::default()
        };
        let k = build_kernel(&params).unwrap();
        let mean_r2 = |ch: usize| -> f64 {
            let c = k.centre() as f64;
            k.rgb
                .iter()
                .enumerate()
                .map(|(i, p)| {
                    let (x, y) = ((i % k.size) as f64 - c, (i / k.size) as f64 - c);
                    f64::from(p[ch]) * (x * x + y * y).min(100.0)
                })
                .sum()
        };
        let (r, g, b) = (mean_r2(0), mean_r2(1), mean_r2(2));
        assert!(r > g && g > b, "spread R {r} G {g} B {b}");
    }

    #[test]
    fn deterministic_for_a_seed() {
        let p = PsfParams {
            particles: 3000,
            particle_um: 40.0,
            ..PsfParams::default()
        };
        let a = build_kernel(&p).unwrap();
        let b = build_kernel(&p).unwrap();
        assert_eq!(a, b);
        let c = build_kernel(&PsfParams {
            seed: p.seed + 1,
            ..p.clone()
        })
        .unwrap();
        assert_ne!(a.rgb, c.rgb, "another seed gives another particle field");
    }

    #[test]
    fn builder_rebuild_matches_fresh_build() {
        let p = PsfParams {
            particles: 2000,
            particle_um: 30.0,
            kernel_size: 33,
            ..PsfParams::default()
        };
        let mut builder = PsfBuilder::new(p.clone()).unwrap();
        let rebuilt = builder.rebuild(6.5).clone();
        let fresh = build_kernel(&PsfParams {
            pupil_mm: 6.5,
            ..p.clone()
        })
        .unwrap();
        assert_eq!(rebuilt, fresh);
        // Out-of-range pupils are clamped, NaN keeps the kernel; try_rebuild errs.
        assert_eq!(builder.rebuild(50.0).pupil_mm, p.max_pupil_mm());
        assert_eq!(builder.rebuild(f64::NAN).pupil_mm, p.max_pupil_mm());
        assert!(builder.try_rebuild(-1.0).is_err());
        assert!(builder.try_rebuild(3.0).is_ok());
    }

    #[test]
    fn invalid_params_are_errors() {
        let ok = PsfParams::default();
        assert!(ok.validate().is_ok());
        let cases = [
            PsfParams {
                pupil_mm: 0.0,
                ..ok.clone()
            },
            PsfParams {
                pupil_mm: -3.0,
                ..ok.clone()
            },
            PsfParams {
                pupil_mm: f64::NAN,
                ..ok.clone()
            },
            PsfParams {
                pupil_mm: 12.0,
                ..ok.clone()
            }, // > 20 mm / 2
            PsfParams {
                grid_size: 500,
                ..ok.clone()
            },
            PsfParams {
                grid_size: 32,
                ..ok.clone()
            },
            PsfParams {
                grid_size: 4096,
                ..ok.clone()
            },
            PsfParams {
                pupil_plane_mm: 0.0,
                ..ok.clone()
            },
            PsfParams {
                wavelength_count: 1,
                ..ok.clone()
            },
            PsfParams {
                ppd: 0.0,
                ..ok.clone()
            },
            PsfParams {
                kernel_size: 10,
                ..ok.clone()
            },
            PsfParams {
                particle_um: 0.0,
                ..ok.clone()
            },
            PsfParams {
                defocus_dioptres: 50.0,
                ..ok.clone()
            },
            PsfParams {
                field_deg: 0.0,
                ..ok.clone()
            },
            PsfParams {
                field_deg: f64::NAN,
                ..ok.clone()
            },
            PsfParams {
                age_years: -1.0,
                ..ok.clone()
            },
            PsfParams {
                age_years: 500.0,
                ..ok.clone()
            },
            PsfParams {
                pigmentation: 1.5,
                ..ok.clone()
            },
            PsfParams {
                pigmentation: f64::NAN,
                ..ok.clone()
            },
        ];
        for p in &cases {
            let err = p.validate().expect_err(&format!("{p:?} must be rejected"));
            assert!(err.to_string().contains("psf."), "{err}");
            assert!(build_kernel(p).is_err());
            assert!(PsfBuilder::new(p.clone()).is_err());
        }
        assert!(monochromatic_psf(&ok, f64::NAN).is_err());
    }

    #[test]
    fn defocus_blurs_the_core() {
        let focused = PsfParams {
            particles: 0,
            pupil_mm: 6.0,
            ..PsfParams::default()
        };
        let blurred = PsfParams {
            defocus_dioptres: 0.5,
            ..focused.clone()
        };
        assert!(blurred.validate().is_ok());
        let f0 = core_fraction(&monochromatic_psf(&focused, 575.0).unwrap(), 6.0);
        let f1 = core_fraction(&monochromatic_psf(&blurred, 575.0).unwrap(), 6.0);
        assert!(
            f1 < 0.5 * f0,
            "0.5 D of defocus must spread the core: {f1} vs {f0}"
        );
    }

    #[test]
    fn wyman_fit_matches_cie_1931_table() {
        // CIE 1931 2° observer (CIE 15:2004, table T.4): [x̄, ȳ, z̄].
        let table = [
            (450.0, [0.3362, 0.0380, 1.7721]),
            (500.0, [0.0049, 0.3230, 0.2720]),
            (555.0, [0.5121, 1.0000, 0.0057]),
            (600.0, [1.0622, 0.6310, 0.0008]),
            (650.0, [0.2835, 0.1070, 0.0000]),
        ];
        for (l, want) in table {
            let got = cie_xyz_wyman(l);
            for k in 0..3 {
                assert!(
                    (got[k] - want[k]).abs() < 0.04,
                    "{l} nm component {k}: {} vs {}",
                    got[k],
                    want[k]
                );
            }
        }
    }

    #[test]
    fn wavelengths_follow_eq_10() {
        let w = PsfParams {
            wavelength_count: 4,
            ..PsfParams::default()
        }
        .wavelengths_nm();
        assert_eq!(w, vec![380.0, 510.0, 640.0, 770.0]);
    }
}
