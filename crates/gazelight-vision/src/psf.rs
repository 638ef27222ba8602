//! The glare point spread function in physical units: wave optics near the
//! source (001 §4.2, eq 5–10) and the eye's intraocular stray light
//! calibrated to CIE 146:2002, tapered to 0 at the edge of the glare field.
//!
//! # Public API (mirrored by the GPU twin)
//!
//! * [`PsfParams`] — what is asked for: pupil, particles, display ppd, the
//!   kernel field `field_deg` (the kernel covers ±`field_deg`/2), the CIE 146
//!   observer (`age_years`, `pigmentation`), `stray_light` on/off,
//!   `glare_scale` ([`GlareScale::Physical`] or 001's own [`GlareScale::Seed`]),
//!   and `pupil_range_mm`, the pupils a [`PsfBuilder`] will be rebuilt for.
//! * [`PsfParams::sampling`] → [`PsfSampling`]: the pupil-plane grid chosen
//!   for the request (`grid_size` N, a power of two ≤ [`MAX_GRID_SIZE`],
//!   `pupil_plane_mm` W), the radius of the wave-optics region
//!   `near_radius_px` and the kernel radius `kernel_radius_px`, all in display
//!   pixels.
//! * [`PsfSetup`]: the pupil-independent part of a build, made once per
//!   request (sampling, wavelength and colour-matching table, particle
//!   positions and transmission, particle lobe table, CIE 146 term per
//!   kernel pixel); [`PsfBuilder`] and the GPU twin repeat only the
//!   per-pupil work on it.
//! * [`PsfBuilder`] / [`build_kernel`] → [`PsfKernel`]: the full-resolution
//!   kernel, `(2 kernel_radius_px + 1)²` display pixels, each channel summing
//!   to 1. This is the kernel the glare convolver applies to a point source
//!   ([`crate::glare`] splits it into a full-resolution core and a coarse
//!   wide field, exactly: the two parts add up to this kernel).
//! * [`monochromatic_psf`] (001 eq 8 on the chosen grid),
//!   [`particle_transmission`] (the static particle field `P` on that grid).
//!
//! # The kernel
//!
//! For a display pixel at angle θ from the source (pixel centre), with
//! `Ω_px = (deg_per_px in rad)²` its solid angle, each channel `c`:
//!
//! ```text
//! K_c = α_c · N_c + f(θ) · t(d) · CIE146(θ; A, p) · Ω_px
//! N_c = near field (FFT, θ ≤ near radius)  or  t(d) · particle lobes (beyond it)
//! α_c = (1 − Σ f·t·CIE146·Ω_px) / Σ N_c          (whole kernel: unit energy)
//! ```
//!
//! `f` is a smoothstep from 0 at 0.1° (where CIE 146 starts to hold) to 1 at
//! 0.3° ([`STRAY_LIGHT_FADE_DEG`]); below 0.1° the kernel is wave optics
//! alone. With `stray_light = false` the second term is absent and `α_c = 1 /
//! Σ N_c`. CIE 146 is taken as achromatic (the same in R, G and B).
//!
//! ## Far taper
//!
//! `t(d)` ([`field_taper`]) is 1 out to [`FIELD_TAPER_START`] = 0.6 of the
//! kernel radius `r` (`d` the distance in display pixels) and falls by a
//! smoothstep to 0 at `r`. The kernel is a square of `2r + 1` pixels; cut
//! there, a bright source's veil stopped at straight edges `r` pixels away,
//! a step of several code values in a dark-adapted frame (issue 39).
//! Tapered, it falls to 0 with its slope on the circle of radius `r`, and
//! the square's corners are 0. At the default ±20° field the kernel is CIE
//! 146 to 12°, then ×0.84 at 14°, ×0.5 at 16°, ×0.16 at 18°, 0 from 20°.
//! The light the taper takes off, 0.46 % of a source's (3.1 % of the CIE
//! 146 term inside the field: 0.1495 → 0.1449 at 13.85 ppd, age 25,
//! p = 0.5), goes to the near field through `α_c`. The veil beyond the
//! field (CIE 146 holds to 100°; from 20° to 100° it holds 2.9 % of the
//! light) is not in the kernel, with or without the taper: from the taper
//! out to 90° it is [`crate::far_glare`]'s, which adds CIE 146 × (1 − t)
//! for every source pixel and takes that light out of the source's pixel. The taper applies to the analytic terms only: the
//! wave-optics near field (≤ 0.6°) ends inside any field wider than about
//! 1.2°, and in seed scale (below) the FFT field fills the whole kernel.
//!
//! ## Near field: wave optics (001 eq 5–10)
//!
//! A pupil-plane grid of `N × N` complex samples holds the lens equation
//! (001 eq 7) `L = P · F · A`:
//!
//! * `P` — the static particle field of the cornea and lens: `particles`
//!   opaque discs of diameter `particle_um` (default 5 µm), at seeded
//!   pseudo-random positions (SplitMix64) spread uniformly over the disc of
//!   the largest pupil of `pupil_range_mm`, so that a dilating pupil uncovers
//!   more particles of the same static field. Discs at least a sample wide
//!   are drawn anti-aliased; smaller ones lower the transmission of the
//!   nearest four samples by the area they cover (bilinear split). Overlaps
//!   multiply transmissions.
//! * `F` — the Fresnel term (001 eq 6) times the eye's refraction: the
//!   residual defocus `exp(iπ r² ΔD / λ)` ([`PsfParams::defocus_dioptres`],
//!   0 = focused; the bare Fresnel phase cannot be sampled on any practical
//!   grid, and a focused eye sees its in-focus Airy pattern).
//! * `A` — the pupil, a disc of `pupil_mm`: each sample holds the exact
//!   fraction of its cell that the disc covers (analytic circle–square
//!   overlap, [`pupil_cell_coverage`]), so `Σ A Δx²` is the pupil's area.
//!
//! `M = |FFT(L)/N|² / (λd)²` (001 eq 8, λ = 575 nm, d = 24 mm); by Parseval
//! `Σ M (λd)² = Σ |L|²`. One FFT sample subtends `Δθ = λ / W` rad; the FFT
//! field spans `λ / Δx`, `Δx = W / N`.
//!
//! ### Sampling per request
//!
//! [`PsfParams::sampling`] picks `Δx` and `N` so that, at the display's ppd:
//!
//! * the core is never interpolated: one FFT sample is no wider than one
//!   display pixel even at 770 nm, `770 nm / W ≤ deg_per_px` (rad), so every
//!   display pixel integrates whole FFT samples;
//! * the plane is at least twice the largest pupil (`W ≥ 2 D_max`: the
//!   optical transfer function, the aperture's autocorrelation, is twice as
//!   wide as the aperture, so the intensity PSF does not alias);
//! * the smallest pupil is at least [`MIN_PUPIL_SAMPLES`] samples across;
//! * the FFT field holds the near-field region at every wavelength: the
//!   380 nm PSF at the region's edge reads `M` at `575/380` times that angle,
//!   so `λ / (2Δx) ≥ (575/380) · near radius`.
//!
//! `N` is the next power of two of `W/Δx` (the GPU Stockham FFT needs it),
//! at most [`MAX_GRID_SIZE`]; a request that needs more is an error naming
//! the ppd and pupil range. The near region has radius
//! [`NEAR_FIELD_RADIUS_DEG`] (0.5°) in display pixels, at least 2 (fewer, down to the centre pixel alone, where that would reach past [`NEAR_FIELD_MAX_DEG`]) and at
//! most [`NEAR_FIELD_MAX_PX`] pixels. At the defaults (13.85 ppd, pupils
//! 1.5–9 mm) that is N = 1024 over an 18.2 mm plane; at 6000 ppd and a 2 mm
//! pupil, N = 4096 over a 341 mm plane.
//!
//! ### Spectral sum
//!
//! 001 eq 9–10: `φ_i = 380 + i/k (770 − 380)` nm, `k + 1 = wavelength_count`,
//! `S_XYZ = 1/(k+1) Σ_i xyz(φ_i) M(θ λ/φ_i) (λ/φ_i)²` with the CIE 1931
//! colour matching functions in the fit of Wyman, Sloan and Shirley (001
//! [44]). Only the 575 nm field is transformed; the Jacobian `(λ/φ_i)²` keeps
//! every wavelength at the same energy. Each display pixel receives the exact
//! integral of the rescaled `M` over its area (a summed-area table). XYZ →
//! linear sRGB, negatives clamped to 0.
//!
//! ### Particles: scattered power ∝ covered area
//!
//! A particle of diameter `s` scatters, by Babinet's principle, the Airy lobe
//! of a disc of its size: power equal to its area `a`, angular scale `λ/s`
//! (a 5 µm particle: 6.6°, far beyond the FFT field). The two parts:
//!
//! * inside the near region the FFT is exact for particles wider than a
//!   sample; for a sub-sample particle (covered fraction `f = a/Δx²` of one
//!   sample) the lowered amplitude `1 − f` adds a field of amplitude `f Δx²`
//!   that is flat over the FFT field, intensity `a² / λ²` per sr — exactly the
//!   centre of the particle's own lobe, `a · (π s²/4) / λ²`. So the FFT's
//!   near field is right for any particle size;
//! * beyond the near region the kernel is the incoherent sum of the lobes
//!   ([`crate::stray_light::airy_lobe_per_sr`], spectrally summed like
//!   `M`): `σ_p · lobe(θ) · Ω_px` with `σ_p = n_in a / (π D²/4)`, `n_in` the
//!   particles inside the pupil (tapered as the CIE term, below: the table
//!   holds `t · lobe`). The power of the lobes is `σ_p`, linear in
//!   the covered area (the old kernel, which had only the FFT field, gave
//!   the sub-sample particles' scatter ∝ area² and lost the rest).
//!
//! CIE 146 is the measured total stray light; the particle lobes are added
//! to it (at the default 1000 particles of 5 µm over a 9 mm disc, a 4 mm
//! pupil holds ≈ 200 of them and scatters 0.03 % of its light, far below the
//! ≈ 25 % of the CIE veil; more or larger particles make the corona visible).
//!
//! ## Seed scale ([`GlareScale::Seed`])
//!
//! 001 §4.2.2 evaluates its PSF in normalised device coordinates: the FFT's
//! `N` output samples are laid over the glare window. In seed scale the grid
//! is fixed (N = 512 over a 20 mm plane) and one FFT sample at 575 nm is
//! `field_deg / N` degrees, the whole field is the FFT near field, and there
//! are no stray-light or analytic particle terms (001 has neither). It is for
//! side-by-side comparisons with the paper's figures, not physics.

use std::sync::Arc;

use gazelight_eye::filter::physio::PUPIL_MM_RANGE;
use gazelight_eye::profile::{
    AGE_YEARS_RANGE, DEFAULT_AGE_YEARS, DEFAULT_PIGMENTATION, PIGMENTATION_RANGE,
};
use rayon::prelude::*;
use rustfft::num_complex::Complex;
use rustfft::{Fft, FftPlanner};
use serde::{Deserialize, Serialize};

use crate::VisionError;
use crate::stray_light::{airy_lobe_per_sr, cie146_veil_per_sr};

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
/// Valid range of the kernel field, degrees (CIE 146 holds to 100°; the
/// field's half width is at most that).
pub const FIELD_DEG_RANGE: (f64, f64) = (0.01, 200.0);
/// Smallest pupil, in pupil-plane samples across.
pub const MIN_PUPIL_SAMPLES: f64 = 24.0;
/// Largest pupil-plane grid (FFT size).
pub const MAX_GRID_SIZE: usize = 4096;
/// Largest kernel, display pixels per side (`2 · kernel_radius_px + 1`).
pub const MAX_KERNEL_PX: usize = 4097;
/// Target radius of the wave-optics near-field region, degrees.
pub const NEAR_FIELD_RADIUS_DEG: f64 = 0.5;
/// Largest angle the near-field region (radius plus the pixel margin)
/// reaches, degrees: below ~4 ppd the pixel minimum gives way to it, so the
/// FFT stays at N = 1024 for the default pupil range down to 1 ppd.
pub const NEAR_FIELD_MAX_DEG: f64 = 0.6;
/// Fewest and most display pixels of the near-field radius (the fewest
/// yields to [`NEAR_FIELD_MAX_DEG`] at low ppd).
pub const NEAR_FIELD_MIN_PX: usize = 2;
/// See [`NEAR_FIELD_MIN_PX`].
pub const NEAR_FIELD_MAX_PX: usize = 512;
/// The CIE 146 term fades in (smoothstep) between these angles, degrees
/// (CIE 146:2002 holds from 0.1°).
pub const STRAY_LIGHT_FADE_DEG: (f64, f64) = (0.1, 0.3);
/// Where the kernel's far taper begins, as a fraction of the kernel radius:
/// the CIE 146 term and the particle lobes are whole within it and fall by
/// a smoothstep to 0 at the radius ([`field_taper`]).
pub const FIELD_TAPER_START: f64 = 0.6;
/// Seed scale: the pupil-plane grid (001 gives none; these are the tree's
/// earlier defaults, 8 mm pupils at 2.5× in the plane).
const SEED_GRID: (usize, f64) = (512, 20.0);

/// Which angular scale the kernel has.
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq, Serialize, Deserialize)]
#[serde(rename_all = "lowercase")]
pub enum GlareScale {
    /// Physical units: the FFT sample is `λ / W` rad, plus CIE 146 stray light.
    #[default]
    Physical,
    /// 001's own scale: the FFT's N samples span the glare field (§4.2.2, NDC).
    Seed,
}

impl std::str::FromStr for GlareScale {
    type Err = String;
    fn from_str(s: &str) -> Result<Self, Self::Err> {
        match s {
            "physical" => Ok(Self::Physical),
            "seed" => Ok(Self::Seed),
            other => Err(format!(
                "unknown glare scale `{other}`: expected `physical` or `seed`"
            )),
        }
    }
}

impl std::fmt::Display for GlareScale {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        f.write_str(match self {
            Self::Physical => "physical",
            Self::Seed => "seed",
        })
    }
}

/// Parameters of the glare PSF.
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
#[serde(default, deny_unknown_fields)]
pub struct PsfParams {
    /// Pupil diameter, mm (the aperture `A` of 001 eq 7).
    pub pupil_mm: f64,
    /// Pupils a builder is rebuilt for, mm `[min, max]`: the plane is sized
    /// for the largest, the sampling for the smallest. `pupil_mm` must lie in it.
    /// Default: the physiological range, `gazelight_eye`'s `PUPIL_MM_RANGE`.
    pub pupil_range_mm: [f64; 2],
    /// Number of scattering particles in the static field `P` (0 = a clean
    /// aperture, whose PSF is an Airy pattern).
    pub particles: usize,
    /// Diameter of one particle, µm (a few µm: lens and corneal scatterers).
    pub particle_um: f64,
    /// Residual defocus of the eye, dioptres; 0 = focused on the retina.
    pub defocus_dioptres: f64,
    /// Number of wavelengths `k + 1` of the spectral sum (001 eq 9–10), ≥ 2.
    pub wavelength_count: usize,
    /// Display resolution, pixels per degree.
    pub ppd: f64,
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
    /// Angular scale: physical (default) or 001's own.
    pub glare_scale: GlareScale,
    /// Seed of the particle field.
    pub seed: u64,
}

impl Default for PsfParams {
    fn default() -> Self {
        Self {
            pupil_mm: 4.0,
            pupil_range_mm: [f64::from(PUPIL_MM_RANGE.0), f64::from(PUPIL_MM_RANGE.1)],
            // 001 Fig. 4: 1000 particles
            particles: 1000,
            // lens/cornea scatterers of a few µm (001 Fig. 4 uses 6 and 10 µm)
            particle_um: 5.0,
            defocus_dioptres: 0.0,
            wavelength_count: 32,
            ppd: VIVE_PRO_PPD,
            field_deg: DEFAULT_FIELD_DEG,
            age_years: DEFAULT_AGE_YEARS,
            pigmentation: DEFAULT_PIGMENTATION,
            stray_light: true,
            glare_scale: GlareScale::Physical,
            seed: 0x6a7e_11e7,
        }
    }
}

/// The sampling chosen for a request ([`PsfParams::sampling`]).
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct PsfSampling {
    /// Pupil-plane grid `N` (FFT size), a power of two.
    pub grid_size: usize,
    /// Width of the pupil plane `W`, mm.
    pub pupil_plane_mm: f64,
    /// Radius of the wave-optics near-field region, display pixels.
    pub near_radius_px: usize,
    /// Kernel radius, display pixels (the kernel is `2r + 1` wide).
    pub kernel_radius_px: usize,
    /// Display pixel, degrees.
    pub deg_per_px: f64,
    /// Angular size of one FFT sample of the 575 nm field as laid on the
    /// display, radians: `λ / W` (physical) or `field / N` (seed scale).
    pub ref_rad_per_sample: f64,
}

impl PsfSampling {
    /// Pupil-plane sample spacing `Δx`, mm.
    pub fn sample_mm(&self) -> f64 {
        self.pupil_plane_mm / self.grid_size as f64
    }

    /// Angular size of one FFT sample of the PSF at `wavelength_nm`, radians
    /// (the 575 nm sample scaled by `φ / 575`, Fraunhofer).
    pub fn rad_per_sample(&self, wavelength_nm: f64) -> f64 {
        self.ref_rad_per_sample * wavelength_nm / REFERENCE_WAVELENGTH_NM
    }

    /// Kernel size, display pixels per side.
    pub fn kernel_size(&self) -> usize {
        2 * self.kernel_radius_px + 1
    }
}

impl PsfParams {
    /// Largest pupil the builder supports, mm (`pupil_range_mm[1]`).
    pub fn max_pupil_mm(&self) -> f64 {
        self.pupil_range_mm[1]
    }

    /// Smallest pupil the builder supports, mm (`pupil_range_mm[0]`).
    pub fn min_pupil_mm(&self) -> f64 {
        self.pupil_range_mm[0]
    }

    /// Kernel radius, display pixels: `round(field_deg / 2 · ppd)`, ≥ 1.
    pub fn kernel_radius_px(&self) -> usize {
        ((self.field_deg / 2.0 * self.ppd).round() as usize).max(1)
    }

    /// Kernel size, display pixels per side (`2 · radius + 1`).
    pub fn kernel_size(&self) -> usize {
        2 * self.kernel_radius_px() + 1
    }

    /// Whether the CIE 146 term is in the kernel (on, and physical scale).
    pub fn has_stray_light(&self) -> bool {
        self.stray_light && self.glare_scale == GlareScale::Physical
    }

    /// The pupil-plane sampling for this request (see the module docs).
    pub fn sampling(&self) -> Result<PsfSampling, VisionError> {
        self.validate_fields()?;
        let deg_per_px = 1.0 / self.ppd;
        let rad_px = deg_per_px.to_radians();
        let kernel_radius_px = self.kernel_radius_px();
        if let GlareScale::Seed = self.glare_scale {
            let (n, w) = SEED_GRID;
            let s = PsfSampling {
                grid_size: n,
                pupil_plane_mm: w,
                near_radius_px: kernel_radius_px,
                kernel_radius_px,
                deg_per_px,
                ref_rad_per_sample: self.field_deg.to_radians() / n as f64,
            };
            if self.max_pupil_mm() > w / 2.0
                || self.min_pupil_mm() < MIN_PUPIL_SAMPLES * s.sample_mm()
            {
                return Err(VisionError::invalid(
                    "psf.pupil_range_mm",
                    format!("{:?}", self.pupil_range_mm),
                    "within 0.94..=10 mm in seed glare scale (512 samples over 20 mm)",
                ));
            }
            return Ok(s);
        }
        let mut near_radius_px = ((NEAR_FIELD_RADIUS_DEG * self.ppd).round() as usize)
            .clamp(NEAR_FIELD_MIN_PX, NEAR_FIELD_MAX_PX)
            .min(kernel_radius_px);
        // At low ppd the pixel minimum would make the region degrees wide and
        // the FFT needlessly large (1 ppd: > 4096 samples): cap its angle. At
        // 0 px the region is the centre pixel, covered on its axes.
        while near_radius_px > 0 && (near_radius_px as f64 + 0.75) * deg_per_px > NEAR_FIELD_MAX_DEG
        {
            near_radius_px -= 1;
        }
        let margin_px = if near_radius_px == 0 { 0.5 } else { 0.75 };
        let lambda_mm = REFERENCE_WAVELENGTH_NM * 1e-6;
        // The 380 nm PSF at the region's edge (plus the pixel's corner
        // margin) reads M at 575/380 times the angle.
        let near_rad = (near_radius_px as f64 + margin_px) * rad_px;
        let dx_field = lambda_mm / (2.0 * near_rad * REFERENCE_WAVELENGTH_NM / SPECTRUM_MIN_NM);
        let dx_pupil = self.min_pupil_mm() / MIN_PUPIL_SAMPLES;
        let dx = dx_field.min(dx_pupil);
        // One FFT sample ≤ one display pixel at 770 nm; plane ≥ 2 D_max.
        let w_min = (2.0 * self.max_pupil_mm()).max(SPECTRUM_MAX_NM * 1e-6 / rad_px);
        let need = (w_min / dx).ceil();
        if !(need.is_finite() && need <= MAX_GRID_SIZE as f64) {
            return Err(VisionError::invalid(
                "psf.ppd",
                self.ppd,
                "a ppd and pupil_range_mm whose pupil plane fits a 4096-sample FFT (plane ≥ 770 nm / pixel angle and ≥ 2 × the largest pupil, sample ≤ smallest pupil / 24 and ≤ what the near field needs); lower the ppd or raise the smallest pupil",
            ));
        }
        let n = (need as usize).next_power_of_two().max(64);
        Ok(PsfSampling {
            grid_size: n,
            pupil_plane_mm: n as f64 * dx,
            near_radius_px,
            kernel_radius_px,
            deg_per_px,
            ref_rad_per_sample: lambda_mm / (n as f64 * dx),
        })
    }

    /// Checks every field and that a sampling exists; the error names the
    /// field and the valid range.
    pub fn validate(&self) -> Result<(), VisionError> {
        self.sampling().map(|_| ())
    }

    fn validate_fields(&self) -> Result<(), VisionError> {
        let [lo, hi] = self.pupil_range_mm;
        if !(lo.is_finite() && hi.is_finite() && lo > 0.0 && lo <= hi && hi <= 20.0) {
            return Err(VisionError::invalid(
                "psf.pupil_range_mm",
                format!("{:?}", self.pupil_range_mm),
                "[min, max] with 0 < min ≤ max ≤ 20 mm",
            ));
        }
        self.check_pupil(self.pupil_mm)?;
        if self.particles > 0
            && !(self.particle_um.is_finite()
                && self.particle_um > 0.0
                && self.particle_um <= 1000.0)
        {
            return Err(VisionError::invalid(
                "psf.particle_um",
                self.particle_um,
                "a finite diameter in (0, 1000] µm",
            ));
        }
        if self.particles > 10_000_000 {
            return Err(VisionError::invalid(
                "psf.particles",
                self.particles,
                "at most 10 000 000",
            ));
        }
        if !(self.defocus_dioptres.is_finite() && self.defocus_dioptres.abs() <= 20.0) {
            return Err(VisionError::invalid(
                "psf.defocus_dioptres",
                self.defocus_dioptres,
                "a finite number in -20..=20 dioptres",
            ));
        }
        if self.wavelength_count < 2 || self.wavelength_count > 1024 {
            return Err(VisionError::invalid(
                "psf.wavelength_count",
                self.wavelength_count,
                "2..=1024 (k + 1 of 001 eq 10, k ≥ 1)",
            ));
        }
        if !(self.ppd.is_finite() && self.ppd > 0.0 && self.ppd <= 1e5) {
            return Err(VisionError::invalid(
                "psf.ppd",
                self.ppd,
                "a finite number in (0, 100000]",
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
        if self.kernel_size() > MAX_KERNEL_PX {
            return Err(VisionError::invalid(
                "psf.field_deg",
                self.field_deg,
                "field_deg × ppd ≤ 4096 display pixels (use a smaller field at this ppd)",
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
        Ok(())
    }

    /// Checks that `pupil_mm` is finite and in `pupil_range_mm`.
    pub fn check_pupil(&self, pupil_mm: f64) -> Result<(), VisionError> {
        if !(pupil_mm.is_finite() && pupil_mm > 0.0) {
            return Err(VisionError::invalid(
                "psf.pupil_mm",
                pupil_mm,
                "a finite diameter > 0 mm",
            ));
        }
        if pupil_mm < self.min_pupil_mm() || pupil_mm > self.max_pupil_mm() {
            return Err(VisionError::invalid(
                "psf.pupil_mm",
                pupil_mm,
                "within psf.pupil_range_mm (default 1.5..=9 mm)",
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
        first_minimum_of(&self.axis_profile(self.size / 2)).map(|r| r * self.rad_per_px)
    }
}

/// The first local minimum of a radial profile, in samples, refined by a
/// parabola through the three samples around it.
fn first_minimum_of(p: &[f64]) -> Option<f64> {
    let i = (1..p.len().saturating_sub(1)).find(|&i| p[i] <= p[i - 1] && p[i] < p[i + 1])?;
    let (a, b, c) = (p[i - 1], p[i], p[i + 1]);
    let denom = a - 2.0 * b + c;
    let offset = if denom.abs() > 0.0 {
        0.5 * (a - c) / denom
    } else {
        0.0
    };
    Some(i as f64 + offset)
}

/// The glare kernel at display resolution: the full-resolution composite
/// (near field + particle lobes + CIE 146 stray light) over ±`field_deg`/2.
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
    /// Linear sRGB weights (fraction of a point source's light per pixel),
    /// row-major, centre at `(size/2, size/2)`; each channel sums to 1.
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

    /// Luminance fraction per steradian of the pixel at `(dx, dy)` for a
    /// white source (Rec. 709 luminance weights of the channels / `Ω_px`).
    pub fn luminance_per_sr(&self, dx: isize, dy: isize) -> f64 {
        let p = self.at(dx, dy);
        let rad = self.deg_per_px.to_radians();
        (0.2126 * f64::from(p[0]) + 0.7152 * f64::from(p[1]) + 0.0722 * f64::from(p[2]))
            / (rad * rad)
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

/// Particle centres of the static field, mm, uniform over the disc of the
/// largest pupil.
fn particle_positions(params: &PsfParams) -> Vec<[f64; 2]> {
    let mut rng = SplitMix64(params.seed);
    let field_r_mm = params.max_pupil_mm() / 2.0;
    (0..params.particles)
        .map(|_| {
            let r = field_r_mm * rng.next_f64().sqrt();
            let a = std::f64::consts::TAU * rng.next_f64();
            [r * a.cos(), r * a.sin()]
        })
        .collect()
}

/// Transmission of the static particle field `P` on the N × N grid.
fn particle_field(params: &PsfParams, sampling: &PsfSampling, positions: &[[f64; 2]]) -> Vec<f64> {
    let n = sampling.grid_size;
    let dx = sampling.sample_mm();
    let mut t = vec![1.0f64; n * n];
    let rad_samples = params.particle_um * 1e-3 / 2.0 / dx;
    let half = (n / 2) as f64;
    for &[px, py] in positions {
        // Continuous grid coordinate: sample j sits at (j - N/2) Δx.
        let cx = px / dx + half;
        let cy = py / dx + half;
        if rad_samples >= 0.5 {
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

/// `θ − sin θ` without the cancellation of the direct form at small `θ`
/// (Taylor series below 0.5 rad: the next term, θ¹¹/11!, is < 2e-11 of it).
fn theta_minus_sin(t: f64) -> f64 {
    if t < 0.5 {
        let t2 = t * t;
        t * t2 / 6.0 * (1.0 - t2 / 20.0 * (1.0 - t2 / 42.0 * (1.0 - t2 / 72.0)))
    } else {
        t - t.sin()
    }
}

/// Area of the disc of radius `r` (centred at the origin) inside the
/// rectangle `[x0, x1] × [y0, y1]`, `0 ≤ x0 ≤ x1`, `0 ≤ y0 ≤ y1`, all in
/// samples: `∫ clamp(√(r² − v²) − x0, 0, x1 − x0) dv` over `[y0, y1]`,
/// in closed form. `v1` and `v0` are where the arc leaves the rectangle's
/// right and left edges; between them the integral is the trapezoid under
/// the chord plus the circular segment between chord and arc,
/// `r²/2 (θ − sin θ)`. Every term is local to the rectangle (no
/// difference of quantities of size `r²`), so the f32 twin in
/// `shaders/psf_aperture.wgsl` keeps its error near `r · 2⁻²⁴` where the arc
/// is no steeper than 45° (`pupil_cell_coverage` folds cells into that octant).
fn disc_rect_area(x0: f64, x1: f64, y0: f64, y1: f64, r: f64) -> f64 {
    let h = |v: f64| ((r - v) * (r + v)).max(0.0).sqrt();
    let v1 = ((r - x1) * (r + x1)).max(0.0).sqrt();
    let v0 = ((r - x0) * (r + x0)).max(0.0).sqrt();
    let a = v1.clamp(y0, y1);
    let b = v0.clamp(y0, y1);
    let full = (a - y0) * (x1 - x0);
    if b <= a {
        return full;
    }
    let (ha, hb) = (h(a), h(b));
    let trapezoid = (b - a) * ((ha - x0) + (hb - x0)) * 0.5;
    let chord = (b - a).hypot(ha - hb);
    let theta = 2.0 * (chord / (2.0 * r)).min(1.0).asin();
    full + trapezoid + 0.5 * r * r * theta_minus_sin(theta)
}

/// The pieces `[lo, hi]` (both ≥ 0) of the interval `[c − ½, c + ½]`,
/// `c ≥ 0`, folded about 0: one piece, or two when it straddles 0.
fn folded_half_unit(c: f64) -> [(f64, f64); 2] {
    if c >= 0.5 {
        [(c - 0.5, c + 0.5), (0.0, 0.0)]
    } else {
        [(0.0, c + 0.5), (0.0, 0.5 - c)]
    }
}

/// 001 eq 7, the aperture `A`: the exact fraction of the unit pupil-plane
/// cell centred at `(x, y)` samples from the pupil's centre that the pupil
/// disc of radius `r` samples covers (analytic circle–square overlap). The
/// cell is folded into the octant `|x| ≥ |y| ≥ 0` (the disc is symmetric),
/// where the arc through it is no steeper than 45°.
pub fn pupil_cell_coverage(x: f64, y: f64, r: f64) -> f64 {
    let (ax, ay) = (x.abs(), y.abs());
    let (ax, ay) = if ay > ax { (ay, ax) } else { (ax, ay) };
    let (nx, ny) = ((ax - 0.5).max(0.0), (ay - 0.5).max(0.0));
    if nx * nx + ny * ny >= r * r {
        return 0.0;
    }
    let (fx, fy) = (ax + 0.5, ay + 0.5);
    if fx * fx + fy * fy <= r * r {
        return 1.0;
    }
    let mut area = 0.0;
    for (x0, x1) in folded_half_unit(ax) {
        for (y0, y1) in folded_half_unit(ay) {
            if x1 > x0 && y1 > y0 {
                area += disc_rect_area(x0, x1, y0, y1, r);
            }
        }
    }
    area.clamp(0.0, 1.0)
}

/// Pupil-plane field, FFT plan and scratch: computes monochromatic PSFs.
struct MonoEngine {
    n: usize,
    dx: f64,
    fft: Arc<dyn Fft<f64>>,
    field: Vec<Complex<f64>>,
    scratch: Vec<Complex<f64>>,
    particles: Vec<f64>,
}

impl MonoEngine {
    fn new(params: &PsfParams, sampling: &PsfSampling, positions: &[[f64; 2]]) -> Self {
        let n = sampling.grid_size;
        let fft = FftPlanner::<f64>::new().plan_fft_forward(n);
        let scratch = vec![Complex::new(0.0, 0.0); fft.get_inplace_scratch_len()];
        Self {
            n,
            dx: sampling.sample_mm(),
            fft,
            field: vec![Complex::new(0.0, 0.0); n * n],
            scratch,
            particles: particle_field(params, sampling, positions),
        }
    }

    /// Fills `out` (N², centred) with M (001 eq 8) for `pupil_mm` at
    /// `wavelength_nm`. Allocates nothing. Calls `pace` between steps of
    /// about [`PACE_STEP_ELEMENTS`] grid samples each (see
    /// [`PsfBuilder::rebuild_paced`]).
    fn compute(
        &mut self,
        defocus_dioptres: f64,
        pupil_mm: f64,
        wavelength_nm: f64,
        out: &mut [f64],
        pace: &mut dyn FnMut(),
    ) {
        let n = self.n;
        let dx = self.dx;
        let half = (n / 2) as f64;
        let r_samples = pupil_mm / 2.0 / dx;
        let lambda_m = wavelength_nm * 1e-9;
        // Residual of Fresnel term (001 eq 6) × the eye's refraction: π r² ΔD / λ.
        let defocus_per_mm2 = std::f64::consts::PI * defocus_dioptres * 1e-6 / lambda_m;
        let edge = r_samples + 1.0;
        let particles = &self.particles;
        let step = pace_rows(n);
        for (b, block) in self.field.chunks_mut(step * n).enumerate() {
            block.par_chunks_mut(n).enumerate().for_each(|(jj, row)| {
                let j = b * step + jj;
                let y = j as f64 - half;
                let prow = &particles[j * n..(j + 1) * n];
                for (i, v) in row.iter_mut().enumerate() {
                    let x = i as f64 - half;
                    let r2 = x * x + y * y;
                    if r2 > edge * edge {
                        *v = Complex::new(0.0, 0.0);
                        continue;
                    }
                    // 001 eq 7: aperture A, the area of the cell inside the pupil
                    let a = pupil_cell_coverage(x, y, r_samples);
                    let amp = a * prow[i];
                    *v = if defocus_per_mm2 == 0.0 {
                        Complex::new(amp, 0.0)
                    } else {
                        Complex::from_polar(amp, defocus_per_mm2 * r2 * dx * dx)
                    };
                }
            });
            pace();
        }
        // 2-D FFT: rows, transpose, rows, transpose back. Rows outside the
        // pupil are zero and stay zero in the first pass.
        let lo = ((half - edge).floor().max(0.0)) as usize;
        let hi = (((half + edge).ceil() as usize) + 1).min(n);
        for rows in self.field[lo * n..hi * n].chunks_mut(step * n) {
            self.fft.process_with_scratch(rows, &mut self.scratch);
            pace();
        }
        transpose_square_paced(&mut self.field, n, pace);
        for rows in self.field.chunks_mut(step * n) {
            self.fft.process_with_scratch(rows, &mut self.scratch);
            pace();
        }
        transpose_square_paced(&mut self.field, n, pace);
        // 001 eq 8, λ and d in mm; fftshift so DC lands at (N/2, N/2).
        let lambda_d = wavelength_nm * 1e-6 * PUPIL_RETINA_MM;
        // |FFT/N|² with N the samples per side: Σ|FFT/N|² = Σ|L|² (Parseval).
        let scale = 1.0 / (n * n) as f64 / (lambda_d * lambda_d);
        let h = n / 2;
        let field = &self.field;
        for (b, block) in out.chunks_mut(step * n).enumerate() {
            block.par_chunks_mut(n).enumerate().for_each(|(jj, orow)| {
                let sj = b * step + jj;
                let j = (sj + n - h) % n;
                for (si, o) in orow.iter_mut().enumerate() {
                    let i = (si + n - h) % n;
                    *o = field[j * n + i].norm_sqr() * scale;
                }
            });
            pace();
        }
    }
}

/// Grid samples a PSF build handles between two calls of its pace
/// callback ([`PsfBuilder::rebuild_paced`]): 2¹⁶ complex f64 samples,
/// 1 MiB, a few hundred microseconds of FFT on one core.
pub const PACE_STEP_ELEMENTS: usize = 1 << 16;

/// Rows of an `n`-wide grid per pace step (at least one).
fn pace_rows(n: usize) -> usize {
    (PACE_STEP_ELEMENTS / n.max(1)).max(1)
}

/// In-place transpose of a square row-major matrix, in cache-sized blocks,
/// calling `pace` after each band of rows that touches about
/// [`PACE_STEP_ELEMENTS`] elements.
fn transpose_square_paced<T: Copy>(m: &mut [T], n: usize, pace: &mut dyn FnMut()) {
    const B: usize = 16;
    let mut touched = 0usize;
    for bj in (0..n).step_by(B) {
        // Band `bj` swaps its B rows right of the diagonal with as many
        // columns: 2·B·(n − bj) elements.
        touched += 2 * B * (n - bj);
        if touched >= PACE_STEP_ELEMENTS {
            touched = 0;
            pace();
        }
        for bi in (bj..n).step_by(B) {
            for j in bj..(bj + B).min(n) {
                let start = if bi == bj { j + 1 } else { bi };
                for i in start..(bi + B).min(n) {
                    m.swap(j * n + i, i * n + j);
                }
            }
        }
    }
}

/// The monochromatic PSF `M` (001 eq 8) of `params.pupil_mm` at
/// `wavelength_nm`, on the grid [`PsfParams::sampling`] chooses
/// (`rad_per_px = λ / W`, physical).
pub fn monochromatic_psf(params: &PsfParams, wavelength_nm: f64) -> Result<MonoPsf, VisionError> {
    let sampling = params.sampling()?;
    if !(wavelength_nm.is_finite() && (200.0..=2000.0).contains(&wavelength_nm)) {
        return Err(VisionError::invalid(
            "wavelength_nm",
            wavelength_nm,
            "200..=2000 nm",
        ));
    }
    let positions = particle_positions(params);
    let mut engine = MonoEngine::new(params, &sampling, &positions);
    let n = sampling.grid_size;
    let mut values = vec![0.0; n * n];
    engine.compute(
        params.defocus_dioptres,
        params.pupil_mm,
        wavelength_nm,
        &mut values,
        &mut || {},
    );
    Ok(MonoPsf {
        size: n,
        wavelength_nm,
        rad_per_px: wavelength_nm * 1e-6 / sampling.pupil_plane_mm,
        values,
    })
}

/// Builds the glare kernel for `params` (see the module docs).
pub fn build_kernel(params: &PsfParams) -> Result<PsfKernel, VisionError> {
    let builder = PsfBuilder::new(params.clone())?;
    Ok(builder.kernel)
}

/// Radial table step, display pixels.
const TABLE_STEP_PX: f64 = 0.25;

/// The far taper of the kernel's analytic terms (CIE 146 stray light,
/// particle lobes) at `d_px` display pixels from the source, for a kernel
/// of radius `radius_px`: 1 within [`FIELD_TAPER_START`] × the radius, then
/// a smoothstep to 0 at the radius and 0 beyond it. The kernel is a square
/// of `2r + 1` pixels; cut there, a source's veil would stop at straight
/// edges `r` pixels away (issue 39: a step of several code values in a
/// dark-adapted frame). Tapered, it falls to 0 continuously (with its
/// slope) on the circle of radius `r`, and the square's corners are 0.
pub fn field_taper(d_px: f64, radius_px: f64) -> f64 {
    let start = FIELD_TAPER_START * radius_px;
    if d_px <= start {
        return 1.0;
    }
    let s = ((d_px - start) / (radius_px - start)).clamp(0.0, 1.0);
    1.0 - s * s * (3.0 - 2.0 * s)
}

/// The pupil-independent part of a kernel build, made once per
/// [`PsfParams`]: the sampling, the wavelength table with its colour
/// matching weights, the particle positions, the spectrally summed particle
/// lobe table and the CIE 146 stray-light term per kernel pixel. A
/// [`PsfBuilder`] holds one and repeats only the per-pupil work (aperture ×
/// particles × defocus → FFT → spectral sum → lobes → normalisation); the
/// GPU twin (`gazelight_gpu::psf`) uploads the same tables once.
#[derive(Clone, Debug)]
pub struct PsfSetup {
    params: PsfParams,
    sampling: PsfSampling,
    wavelengths_nm: Vec<f64>,
    /// Colour matching function values per wavelength, / (k + 1).
    cmf: Vec<[f64; 3]>,
    /// Linear sRGB of the unit-power particle lobe per steradian, sampled
    /// every [`TABLE_STEP_PX`] display pixels of radius.
    lobe_table: Vec<[f64; 3]>,
    /// `f · CIE146 · Ω_px` per kernel pixel (0 without stray light).
    cie: Vec<f64>,
    /// Σ `cie`.
    cie_energy: f64,
    positions: Vec<[f64; 2]>,
}

impl PsfSetup {
    /// Validates `params` and computes every pupil-independent table.
    pub fn new(params: PsfParams) -> Result<Self, VisionError> {
        let sampling = params.sampling()?;
        let r = sampling.kernel_radius_px;
        let size = sampling.kernel_size();
        let wavelengths_nm = params.wavelengths_nm();
        let inv = 1.0 / wavelengths_nm.len() as f64;
        let cmf: Vec<[f64; 3]> = wavelengths_nm
            .iter()
            .map(|&l| cie_xyz_wyman(l).map(|v| v * inv))
            .collect();
        let rad_px = sampling.deg_per_px.to_radians();
        let omega_px = rad_px * rad_px;
        // Particle lobes (physical scale only): Σ_i cmf_i · lobe_φi per sr → sRGB.
        let lobe_table = if params.glare_scale == GlareScale::Physical && params.particles > 0 {
            let r_max = (r as f64 + 1.0) * std::f64::consts::SQRT_2 + 2.0;
            let count = (r_max / TABLE_STEP_PX).ceil() as usize + 2;
            let s_m = params.particle_um * 1e-6;
            (0..count)
                .into_par_iter()
                .map(|i| {
                    let theta = i as f64 * TABLE_STEP_PX * rad_px;
                    let mut xyz = [0.0f64; 3];
                    for (&phi, c) in wavelengths_nm.iter().zip(&cmf) {
                        let l = airy_lobe_per_sr(theta, s_m, phi * 1e-9);
                        for k in 0..3 {
                            xyz[k] += c[k] * l;
                        }
                    }
                    xyz_to_rgb(xyz).map(|v| v * field_taper(i as f64 * TABLE_STEP_PX, r as f64))
                })
                .collect()
        } else {
            Vec::new()
        };

        // CIE 146 veil, faded in over STRAY_LIGHT_FADE_DEG and tapered to 0
        // at the kernel's radius (`field_taper`); pixels near the source are
        // averaged over 5 × 5 sub-samples.
        let mut cie = vec![0.0f64; size * size];
        if params.has_stray_light() {
            let dpp = sampling.deg_per_px;
            let (a, p) = (params.age_years, params.pigmentation);
            let veil = |t_deg: f64| -> f64 {
                let (f0, f1) = STRAY_LIGHT_FADE_DEG;
                if t_deg <= f0 {
                    return 0.0;
                }
                let s = ((t_deg - f0) / (f1 - f0)).clamp(0.0, 1.0);
                s * s * (3.0 - 2.0 * s) * cie146_veil_per_sr(t_deg, a, p)
            };
            cie.par_chunks_mut(size).enumerate().for_each(|(v, row)| {
                let y = v as f64 - r as f64;
                for (u, out) in row.iter_mut().enumerate() {
                    let x = u as f64 - r as f64;
                    let d = x.hypot(y);
                    let per_sr = if d * dpp < 2.0 * STRAY_LIGHT_FADE_DEG.1 || d < 6.0 {
                        let mut acc = 0.0;
                        for sy in 0..5 {
                            for sx in 0..5 {
                                let ox = x + (sx as f64 - 2.0) / 5.0;
                                let oy = y + (sy as f64 - 2.0) / 5.0;
                                acc += veil(ox.hypot(oy) * dpp);
                            }
                        }
                        acc / 25.0
                    } else {
                        veil(d * dpp)
                    };
                    *out = per_sr * omega_px * field_taper(d, r as f64);
                }
            });
        }
        let cie_energy: f64 = cie.iter().sum();
        if cie_energy >= 0.95 {
            return Err(VisionError::invalid(
                "psf.field_deg",
                params.field_deg,
                "a field whose CIE 146 stray light holds < 95 % of the light (narrower field, younger age or lower pigmentation)",
            ));
        }
        let positions = particle_positions(&params);
        Ok(Self {
            params,
            sampling,
            wavelengths_nm,
            cmf,
            lobe_table,
            cie,
            cie_energy,
            positions,
        })
    }

    /// The parameters (with `pupil_mm` as given to `new`).
    pub fn params(&self) -> &PsfParams {
        &self.params
    }

    /// The sampling chosen for the parameters.
    pub fn sampling(&self) -> &PsfSampling {
        &self.sampling
    }

    /// The wavelengths of the spectral sum, nm (001 eq 10).
    pub fn wavelengths_nm(&self) -> &[f64] {
        &self.wavelengths_nm
    }

    /// CIE 1931 `[x̄, ȳ, z̄]` (Wyman fit) per wavelength, each divided by
    /// the wavelength count `k + 1` (001 eq 9).
    pub fn cmf_weights(&self) -> &[[f64; 3]] {
        &self.cmf
    }

    /// The spectrally summed unit-power particle lobe per steradian, linear
    /// sRGB, at radii `i ·` [`PsfSetup::LOBE_TABLE_STEP_PX`] display pixels
    /// (linearly interpolated between entries); empty when the kernel has
    /// no particle lobes (no particles, or seed scale).
    pub fn lobe_table(&self) -> &[[f64; 3]] {
        &self.lobe_table
    }

    /// Radial step of [`PsfSetup::lobe_table`], display pixels.
    pub const LOBE_TABLE_STEP_PX: f64 = TABLE_STEP_PX;

    /// `f · CIE146 · Ω_px` per kernel pixel, row-major (all 0 without stray
    /// light).
    pub fn stray_light(&self) -> &[f64] {
        &self.cie
    }

    /// Energy of the CIE 146 term over the kernel field (0 without stray
    /// light); the near field holds the rest.
    pub fn stray_light_energy(&self) -> f64 {
        self.cie_energy
    }

    /// The transmission of the static particle field `P` on the grid of the
    /// sampling, as [`particle_transmission`].
    pub fn particle_transmission(&self) -> Vec<f64> {
        particle_field(&self.params, &self.sampling, &self.positions)
    }

    /// Fraction of the light through a `pupil_mm` pupil that the particle
    /// field scatters by the lobe sum: `n_in · a / (π D² / 4)`.
    pub fn particle_scatter_fraction(&self, pupil_mm: f64) -> f64 {
        let r = pupil_mm / 2.0;
        let n_in = self
            .positions
            .iter()
            .filter(|p| p[0] * p[0] + p[1] * p[1] <= r * r)
            .count();
        let s_mm = self.params.particle_um * 1e-3;
        (n_in as f64 * s_mm * s_mm / (pupil_mm * pupil_mm)).min(1.0)
    }
}

/// Builds kernels repeatedly for a changing pupil: the FFT plan, the particle
/// field, the analytic radial terms ([`PsfSetup`]) and every buffer are made
/// once, so [`PsfBuilder::rebuild`] allocates nothing.
pub struct PsfBuilder {
    setup: PsfSetup,
    engine: MonoEngine,
    /// M at 575 nm, centred, N².
    mono: Vec<f64>,
    /// Summed-area table of `mono`, (N+1)².
    sat: Vec<f64>,
    /// Near field + lobes, per kernel pixel, linear sRGB (before α).
    near: Vec<[f64; 3]>,
    kernel: PsfKernel,
}

impl PsfBuilder {
    /// Validates `params`, prepares every buffer and builds the first kernel
    /// (for `params.pupil_mm`).
    pub fn new(params: PsfParams) -> Result<Self, VisionError> {
        Self::from_setup(PsfSetup::new(params)?)
    }

    /// A builder on a prepared [`PsfSetup`]; builds the first kernel (for
    /// the setup's `params.pupil_mm`).
    pub fn from_setup(setup: PsfSetup) -> Result<Self, VisionError> {
        let sampling = setup.sampling;
        let n = sampling.grid_size;
        let size = sampling.kernel_size();
        let engine = MonoEngine::new(&setup.params, &sampling, &setup.positions);
        let mut builder = Self {
            engine,
            mono: vec![0.0; n * n],
            sat: vec![0.0; (n + 1) * (n + 1)],
            near: vec![[0.0; 3]; size * size],
            kernel: PsfKernel {
                size,
                deg_per_px: sampling.deg_per_px,
                pupil_mm: setup.params.pupil_mm,
                wavelengths_nm: setup.wavelengths_nm.clone(),
                rgb: vec![[0.0; 3]; size * size],
            },
            setup,
        };
        let pupil = builder.setup.params.pupil_mm;
        builder.build(pupil, &mut || {});
        Ok(builder)
    }

    /// The pupil-independent tables the builder was made with.
    pub fn setup(&self) -> &PsfSetup {
        &self.setup
    }

    /// The parameters (with `pupil_mm` as given to `new`).
    pub fn params(&self) -> &PsfParams {
        &self.setup.params
    }

    /// The sampling chosen for the parameters.
    pub fn sampling(&self) -> &PsfSampling {
        &self.setup.sampling
    }

    /// The most recently built kernel.
    pub fn kernel(&self) -> &PsfKernel {
        &self.kernel
    }

    /// Radius of the first dark ring, radians, measured on the 575 nm
    /// monochromatic field of the last build (the field the kernel was made
    /// from), as [`MonoPsf::first_minimum_rad`]. Allocates the axis profile
    /// (`grid_size / 2` values). `None` when the profile has no minimum.
    pub fn first_ring_rad(&self) -> Option<f64> {
        let n = self.setup.sampling.grid_size;
        let c = n / 2;
        let v = &self.mono;
        let profile: Vec<f64> = (0..c)
            .map(|r| {
                (v[c * n + c + r] + v[c * n + c - r] + v[(c + r) * n + c] + v[(c - r) * n + c])
                    / 4.0
            })
            .collect();
        let rad_per_sample = REFERENCE_WAVELENGTH_NM * 1e-6 / self.setup.sampling.pupil_plane_mm;
        first_minimum_of(&profile).map(|r| r * rad_per_sample)
    }

    /// Energy of the CIE 146 term over the kernel field (0 without stray
    /// light); the near field holds the rest.
    pub fn stray_light_energy(&self) -> f64 {
        self.setup.cie_energy
    }

    /// Fraction of the light through a `pupil_mm` pupil that the particle
    /// field scatters by the lobe sum: `n_in · a / (π D² / 4)`.
    pub fn particle_scatter_fraction(&self, pupil_mm: f64) -> f64 {
        self.setup.particle_scatter_fraction(pupil_mm)
    }

    /// Rebuilds the kernel for a new pupil diameter. A diameter outside
    /// `pupil_range_mm` is clamped into it; a non-finite one keeps the
    /// current kernel. Use [`PsfBuilder::try_rebuild`] to get an error instead.
    pub fn rebuild(&mut self, pupil_mm: f64) -> &PsfKernel {
        self.rebuild_paced(pupil_mm, &mut || {})
    }

    /// [`PsfBuilder::rebuild`] in steps: `pace` is called between steps of
    /// about [`PACE_STEP_ELEMENTS`] grid samples (a few hundred µs each on
    /// one core), so a caller can hold the build while something more
    /// urgent runs (the `run` PSF worker waits there while a frame renders).
    /// The kernel is the same as [`PsfBuilder::rebuild`]'s, bit for bit.
    pub fn rebuild_paced(&mut self, pupil_mm: f64, pace: &mut dyn FnMut()) -> &PsfKernel {
        if pupil_mm.is_finite() {
            let p = pupil_mm.clamp(
                self.setup.params.min_pupil_mm(),
                self.setup.params.max_pupil_mm(),
            );
            self.build(p, pace);
        }
        &self.kernel
    }

    /// Like [`PsfBuilder::rebuild`], but an unsupported pupil is an error.
    pub fn try_rebuild(&mut self, pupil_mm: f64) -> Result<&PsfKernel, VisionError> {
        self.setup.params.check_pupil(pupil_mm)?;
        self.build(pupil_mm, &mut || {});
        Ok(&self.kernel)
    }

    fn build(&mut self, pupil_mm: f64, pace: &mut dyn FnMut()) {
        let n = self.setup.sampling.grid_size;
        self.engine.compute(
            self.setup.params.defocus_dioptres,
            pupil_mm,
            REFERENCE_WAVELENGTH_NM,
            &mut self.mono,
            pace,
        );
        // Summed-area table: sat[j][i] = Σ mono[y < j][x < i].
        let w = n + 1;
        self.sat[..w].fill(0.0);
        let step = pace_rows(n);
        for j in 0..n {
            if j % step == step - 1 {
                pace();
            }
            let mut row_sum = 0.0;
            self.sat[(j + 1) * w] = 0.0;
            for i in 0..n {
                row_sum += self.mono[j * n + i];
                self.sat[(j + 1) * w + i + 1] = self.sat[j * w + i + 1] + row_sum;
            }
        }
        // M → fraction of the light entering the pupil: Σ M (λd)² = Σ|L|²,
        // the pupil admits π r² samples.
        let lambda_d = REFERENCE_WAVELENGTH_NM * 1e-6 * PUPIL_RETINA_MM;
        let r_samples = pupil_mm / 2.0 / self.setup.sampling.sample_mm();
        let to_fraction = lambda_d * lambda_d / (std::f64::consts::PI * r_samples * r_samples);
        let sigma_p = if self.setup.lobe_table.is_empty() {
            0.0
        } else {
            self.particle_scatter_fraction(pupil_mm)
        };

        let r = self.setup.sampling.kernel_radius_px;
        let size = 2 * r + 1;
        let near_r = self.setup.sampling.near_radius_px as f64;
        let rad_px = self.setup.sampling.deg_per_px.to_radians();
        let omega_px = rad_px * rad_px;
        // FFT samples per display pixel at 575 nm.
        let px_in_samples = rad_px / self.setup.sampling.ref_rad_per_sample;
        let sat = &self.sat;
        let cmf = &self.setup.cmf;
        let wavelengths = &self.kernel.wavelengths_nm;
        let lobe = &self.setup.lobe_table;
        let half = n as f64 / 2.0;
        // Rows per pace step: a wave-optics pixel costs an SAT lookup per
        // wavelength, about as much as an FFT sample.
        let near_rows = (PACE_STEP_ELEMENTS / (size * wavelengths.len().max(1))).max(1);
        for (b, block) in self.near.chunks_mut(near_rows * size).enumerate() {
            block
                .par_chunks_mut(size)
                .enumerate()
                .for_each(|(vv, row)| {
                    let v = b * near_rows + vv;
                    let y = v as f64 - r as f64;
                    for (u, out) in row.iter_mut().enumerate() {
                        let x = u as f64 - r as f64;
                        let d = x.hypot(y);
                        if d <= near_r {
                            // M_φ(θ)(λ/φ)² integrated over the pixel = ∫ M over the
                            // pixel scaled by λ/φ (001 eq 9 with the Jacobian).
                            let mut xyz = [0.0f64; 3];
                            for (&phi, c) in wavelengths.iter().zip(cmf) {
                                let to_m = px_in_samples * REFERENCE_WAVELENGTH_NM / phi;
                                let y0 = (y - 0.5) * to_m + half + 0.5;
                                let y1 = y0 + to_m;
                                let x0 = (x - 0.5) * to_m + half + 0.5;
                                let x1 = x0 + to_m;
                                let e = (sat_lerp(sat, n, y1, x1)
                                    - sat_lerp(sat, n, y0, x1)
                                    - sat_lerp(sat, n, y1, x0)
                                    + sat_lerp(sat, n, y0, x0))
                                    * to_fraction;
                                for k in 0..3 {
                                    xyz[k] += c[k] * e;
                                }
                            }
                            *out = xyz_to_rgb(xyz);
                        } else if sigma_p > 0.0 {
                            let t = d / TABLE_STEP_PX;
                            let i = (t.floor() as usize).min(lobe.len() - 2);
                            let f = t - i as f64;
                            let scale = sigma_p * omega_px;
                            for k in 0..3 {
                                out[k] = (lobe[i][k] * (1.0 - f) + lobe[i + 1][k] * f) * scale;
                            }
                        } else {
                            *out = [0.0; 3];
                        }
                    }
                });
            pace();
        }
        // α_c: the near field holds what the stray light leaves.
        let mut sums = [0.0f64; 3];
        for p in &self.near {
            for k in 0..3 {
                sums[k] += p[k];
            }
        }
        let budget = 1.0 - self.setup.cie_energy;
        let alpha = sums.map(|s| if s > 0.0 { budget / s } else { 0.0 });
        for ((out, nr), cie) in self
            .kernel
            .rgb
            .iter_mut()
            .zip(&self.near)
            .zip(&self.setup.cie)
        {
            for k in 0..3 {
                out[k] = (alpha[k] * nr[k] + cie) as f32;
            }
        }
        self.kernel.pupil_mm = pupil_mm;
    }
}

/// CIE XYZ → linear sRGB, negatives (monochromatic light is outside the
/// gamut) clamped to 0.
fn xyz_to_rgb(xyz: [f64; 3]) -> [f64; 3] {
    let m = &XYZ_TO_LINEAR_SRGB;
    let mut out = [0.0f64; 3];
    for (ch, o) in out.iter_mut().enumerate() {
        *o = (m[ch][0] * xyz[0] + m[ch][1] * xyz[1] + m[ch][2] * xyz[2]).max(0.0);
    }
    out
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
/// [`build_kernel`] and [`PsfBuilder`] use for `params`: `N²` values in
/// 0..=1 on the grid of [`PsfParams::sampling`], row-major, sample `(i, j)`
/// at `((i − N/2) Δx, (j − N/2) Δx)`. For the GPU twin, which uploads it
/// once so both see the same field.
pub fn particle_transmission(params: &PsfParams) -> Result<Vec<f64>, VisionError> {
    let sampling = params.sampling()?;
    Ok(particle_field(
        params,
        &sampling,
        &particle_positions(params),
    ))
}

#[cfg(test)]
mod tests {
    use super::*;

    /// CIE 146:2002 General Disability Glare equation, written out here
    /// independently of the code under test: L_veil / E_glare in sr⁻¹.
    fn cie146(theta_deg: f64, age: f64, p: f64) -> f64 {
        10.0 / theta_deg.powi(3)
            + (5.0 / theta_deg.powi(2) + 0.1 * p / theta_deg) * (1.0 + (age / 62.5).powi(4))
            + 0.0025 * p
    }

    /// Mean luminance per sr of the kernel's pixels whose centre distance
    /// rounds to `d` pixels.
    fn ring_mean(k: &PsfKernel, d: usize) -> f64 {
        let r = d as isize + 1;
        let (mut sum, mut n) = (0.0, 0usize);
        for dy in -r..=r {
            for dx in -r..=r {
                if ((dx * dx + dy * dy) as f64).sqrt().round() as usize == d {
                    sum += k.luminance_per_sr(dx, dy);
                    n += 1;
                }
            }
        }
        sum / n as f64
    }

    #[test]
    fn kernel_follows_cie_146_per_steradian() {
        let mut checked = 0;
        for ppd in [14.0, 30.0] {
            for pupil_mm in [2.0, 4.0, 8.0] {
                for pigmentation in [0.5, 1.0] {
                    let mut veil_10 = [0.0; 2];
                    for (ai, age) in [25.0, 70.0].into_iter().enumerate() {
                        let k = build_kernel(&PsfParams {
                            pupil_mm,
                            ppd,
                            age_years: age,
                            pigmentation,
                            ..PsfParams::default()
                        })
                        .unwrap();
                        for ch in k.energy() {
                            assert!((ch - 1.0).abs() < 1e-4, "energy {ch}");
                        }
                        let r = k.centre();
                        let mut worst: f64 = 1.0;
                        // Whole CIE 146 within 0.6 r; beyond it the
                        // kernel's far taper (module docs): ×1 at 0.6 r,
                        // a smoothstep to 0 at r.
                        for d in 1..r {
                            let theta = d as f64 * k.deg_per_px;
                            if theta < 0.3 {
                                continue;
                            }
                            let s = ((d as f64 / r as f64 - 0.6) / 0.4).clamp(0.0, 1.0);
                            let taper = 1.0 - s * s * (3.0 - 2.0 * s);
                            if taper < 0.05 {
                                continue;
                            }
                            let got = ring_mean(&k, d);
                            let want = cie146(theta, age, pigmentation) * taper;
                            let ratio = got / want;
                            let tol = if theta < 1.0 { 3.0 } else { 2.0 };
                            assert!(
                                ratio < tol && ratio > 1.0 / tol,
                                "ppd {ppd} D {pupil_mm} age {age} p {pigmentation}: θ {theta:.2}° kernel {got:.4e} /sr, CIE {want:.4e} (×{ratio:.3})"
                            );
                            worst = worst.max(ratio.max(1.0 / ratio));
                            checked += 1;
                        }
                        let d10 = (10.0 * ppd).round() as usize;
                        veil_10[ai] = ring_mean(&k, d10);
                        eprintln!(
                            "ppd {ppd} D {pupil_mm} age {age} p {pigmentation}: worst ratio to CIE 146 from 0.3° to {:.1}°: {worst:.3}",
                            r as f64 * k.deg_per_px
                        );
                    }
                    let t10 = (10.0 * ppd).round() / ppd;
                    let want = cie146(t10, 70.0, pigmentation) / cie146(t10, 25.0, pigmentation);
                    let got = veil_10[1] / veil_10[0];
                    assert!(
                        (got / want - 1.0).abs() < 0.25,
                        "age 70 / age 25 veil at 10°: {got:.3}, CIE {want:.3}"
                    );
                }
            }
        }
        assert!(checked > 1000);
    }

    /// J1 by its integral representation (DLMF 10.9.1), independent of
    /// `stray_light::bessel_j1`: J1(x) = (1/π) ∫₀^π cos(τ − x sin τ) dτ.
    fn j1_integral(x: f64) -> f64 {
        let n = 600;
        let h = std::f64::consts::PI / n as f64;
        // Simpson's rule.
        let f = |t: f64| (t - x * t.sin()).cos();
        let mut acc = f(0.0) + f(std::f64::consts::PI);
        for i in 1..n {
            let w = if i % 2 == 1 { 4.0 } else { 2.0 };
            acc += w * f(i as f64 * h);
        }
        acc * h / 3.0 / std::f64::consts::PI
    }

    /// The spectral Airy pattern per display pixel, linear sRGB, normalised
    /// per channel over the pixels within `radius_px`: 001 eq 9–10 with the
    /// same colour matching functions, 4 × 4 sub-samples per pixel.
    fn spectral_airy(
        d_mm: f64,
        ppd: f64,
        size: usize,
        radius_px: f64,
        count: usize,
    ) -> Vec<[f64; 3]> {
        let rad_px = (1.0 / ppd).to_radians();
        let c = (size / 2) as f64;
        let k = count - 1;
        let phis: Vec<f64> = (0..=k)
            .map(|i| 380.0 + i as f64 / k as f64 * 390.0)
            .collect();
        // Radial table of Σ cmf(φ) Airy_φ(θ) at 1/32 px steps.
        let step = 1.0 / 32.0;
        let n_tab = ((radius_px + 2.0) * std::f64::consts::SQRT_2 / step) as usize + 2;
        let table: Vec<[f64; 3]> = (0..n_tab)
            .into_par_iter()
            .map(|i| {
                let theta = i as f64 * step * rad_px;
                let mut xyz = [0.0; 3];
                for &phi in &phis {
                    let lam = phi * 1e-9;
                    let x = std::f64::consts::PI * d_mm * 1e-3 * theta / lam;
                    let a = if x < 1e-9 {
                        1.0
                    } else {
                        2.0 * j1_integral(x) / x
                    };
                    // Per sr: π D² / (4 λ²) (2 J1(x)/x)², unit power per wavelength.
                    let i_sr =
                        std::f64::consts::PI * (d_mm * 1e-3).powi(2) / (4.0 * lam * lam) * a * a;
                    let cmf = cie_xyz_wyman(phi);
                    for j in 0..3 {
                        xyz[j] += cmf[j] * i_sr;
                    }
                }
                let m = &XYZ_TO_LINEAR_SRGB;
                let mut rgb = [0.0; 3];
                for ch in 0..3 {
                    rgb[ch] = (m[ch][0] * xyz[0] + m[ch][1] * xyz[1] + m[ch][2] * xyz[2]).max(0.0);
                }
                rgb
            })
            .collect();
        let mut out = vec![[0.0f64; 3]; size * size];
        out.par_chunks_mut(size).enumerate().for_each(|(v, row)| {
            for (u, o) in row.iter_mut().enumerate() {
                let (x, y) = (u as f64 - c, v as f64 - c);
                if x.hypot(y) > radius_px {
                    continue;
                }
                for sy in 0..4 {
                    for sx in 0..4 {
                        let ox = x + (sx as f64 - 1.5) / 4.0;
                        let oy = y + (sy as f64 - 1.5) / 4.0;
                        let t = ox.hypot(oy) / step;
                        let i = t.floor() as usize;
                        let f = t - i as f64;
                        for ch in 0..3 {
                            o[ch] += (table[i][ch] * (1.0 - f) + table[i + 1][ch] * f) / 16.0;
                        }
                    }
                }
            }
        });
        let mut sums = [0.0; 3];
        for p in &out {
            for ch in 0..3 {
                sums[ch] += p[ch];
            }
        }
        for p in &mut out {
            for ch in 0..3 {
                p[ch] /= sums[ch];
            }
        }
        out
    }

    #[test]
    fn clean_kernel_is_the_spectral_airy_pattern_at_any_ppd() {
        // (ppd, pupil, field): the near field spans the first rings.
        for (ppd, d_mm, field_deg) in [
            (300.0, 2.0, 3.0),
            (1000.0, 4.0, 1.0),
            (6000.0, 2.0, 0.17),
            (6000.0, 8.0, 0.17),
        ] {
            let params = PsfParams {
                pupil_mm: d_mm,
                pupil_range_mm: [d_mm, d_mm],
                particles: 0,
                stray_light: false,
                ppd,
                field_deg,
                ..PsfParams::default()
            };
            let builder = PsfBuilder::new(params.clone()).unwrap();
            let s = *builder.sampling();
            let k = builder.kernel();
            // One FFT sample ≤ one display pixel at 770 nm.
            assert!(s.rad_per_sample(770.0) <= (1.0 / ppd).to_radians() * (1.0 + 1e-12));
            let near = s.near_radius_px as f64;
            let reference = spectral_airy(d_mm, ppd, k.size, near, params.wavelength_count);
            let lum = |p: [f64; 3]| 0.2126 * p[0] + 0.7152 * p[1] + 0.0722 * p[2];
            let peak = reference.iter().map(|p| lum(*p)).fold(0.0, f64::max);
            let mut worst = 0.0f64;
            for (kp, rp) in k.rgb.iter().zip(&reference) {
                let kl = lum([f64::from(kp[0]), f64::from(kp[1]), f64::from(kp[2])]);
                worst = worst.max((kl - lum(*rp)).abs() / peak);
            }
            eprintln!(
                "ppd {ppd}, D {d_mm} mm: grid {} over {:.1} mm, near radius {} px; max |kernel − spectral Airy| = {:.2} % of the peak",
                s.grid_size,
                s.pupil_plane_mm,
                s.near_radius_px,
                worst * 100.0
            );
            assert!(worst < 0.05, "ppd {ppd} D {d_mm}: {worst}");
            // The Airy core spans pixels at these ppd (not a single one).
            assert!(k.at(0, 0)[1] < 0.5);
        }
    }

    /// The pupil cell coverage against an independent numerical area (the
    /// chord length of the disc across the cell's x range, integrated over
    /// its y range by the midpoint rule) and, summed over the grid, the
    /// disc's area π r².
    #[test]
    fn pupil_cell_coverage_is_the_area_of_the_cell_inside_the_disc() {
        let numeric = |x: f64, y: f64, r: f64| -> f64 {
            let steps = 20_000;
            let mut acc = 0.0;
            for i in 0..steps {
                let v = y - 0.5 + (i as f64 + 0.5) / steps as f64;
                let half = (r * r - v * v).max(0.0).sqrt();
                acc += ((x + 0.5).min(half) - (x - 0.5).max(-half)).max(0.0);
            }
            acc / steps as f64
        };
        for r in [0.3f64, 0.8, 5.3, 12.0, 15.654_351_9, 31.3, 511.7] {
            let m = r.ceil() as i64 + 1;
            let (mut total, mut worst, mut partial) = (0.0, 0.0f64, 0usize);
            for j in -m..=m {
                for i in -m..=m {
                    let (x, y) = (i as f64, j as f64);
                    let c = pupil_cell_coverage(x, y, r);
                    assert!((0.0..=1.0).contains(&c));
                    total += c;
                    // Every cell of the small discs, a sample of the large one.
                    if c > 0.0 && c < 1.0 && (r < 100.0 || (i * 7 + j) % 41 == 0) {
                        let want = numeric(x, y, r);
                        worst = worst.max((c - want).abs());
                        partial += 1;
                    }
                }
            }
            let disc = std::f64::consts::PI * r * r;
            eprintln!(
                "r = {r} samples: Σ coverage / π r² − 1 = {:.1e}; {partial} edge cells checked, worst |analytic − numeric| {worst:.1e}",
                total / disc - 1.0
            );
            assert!(
                (total / disc - 1.0).abs() < 1e-12,
                "r {r}: {total} vs {disc}"
            );
            // The midpoint rule's own error is below 2e-6 at 20 000 steps.
            assert!(worst < 3e-6, "r {r}: {worst:e}");
            assert!(partial > 0);
        }
        // Cells wholly inside and outside, and the symmetry of the disc.
        assert_eq!(pupil_cell_coverage(0.0, 0.0, 12.0), 1.0);
        assert_eq!(pupil_cell_coverage(13.0, 0.0, 12.0), 0.0);
        for (x, y) in [(11.0, 3.0), (8.0, 8.0), (0.0, 12.0)] {
            let c = pupil_cell_coverage(x, y, 12.0);
            assert_eq!(c, pupil_cell_coverage(-y, x, 12.0));
            assert_eq!(c, pupil_cell_coverage(-x, -y, 12.0));
        }
    }

    /// CIE 1931 2° colour matching functions `[x̄, ȳ, z̄]`: the multi-lobe
    /// fit of Wyman, Sloan and Shirley, "Simple Analytic Approximations to
    /// the CIE XYZ Color Matching Functions", JCGT 2(2) 2013, eq 2–4, typed
    /// here from the paper (not `cie_xyz_wyman`).
    fn test_cmf_multi_lobe(l: f64) -> [f64; 3] {
        let g = |mu: f64, s_lo: f64, s_hi: f64| {
            let t = (l - mu) / if l < mu { s_lo } else { s_hi };
            (-0.5 * t * t).exp()
        };
        [
            1.056 * g(599.8, 37.9, 31.0) + 0.362 * g(442.0, 16.0, 26.7)
                - 0.065 * g(501.1, 20.4, 26.2),
            0.821 * g(568.8, 46.9, 40.5) + 0.286 * g(530.9, 16.3, 31.1),
            1.217 * g(437.0, 11.8, 36.0) + 0.681 * g(459.0, 26.0, 13.8),
        ]
    }

    /// The single-lobe fit of the same paper (Wyman 2013 eq 5–7): a second,
    /// coarser approximation of the CIE 1931 table, to size what the choice
    /// of fit does to the comparison.
    fn test_cmf_single_lobe(l: f64) -> [f64; 3] {
        let gauss = |t: f64| (-0.5 * t * t).exp();
        [
            1.065 * gauss((l - 595.8) / 33.33) + 0.366 * gauss((l - 446.8) / 19.44),
            1.014 * gauss((l.ln() - 556.3f64.ln()) / 0.075),
            1.839 * gauss((l.ln() - 449.8f64.ln()) / 0.051),
        ]
    }

    /// Each channel's spectral Airy sum per display pixel of a `size`² grid
    /// centred on the source, for the pixels whose centre lies within
    /// `radius_px`, as the fraction of that channel's light over all angles.
    /// Written independently of the code under test: the energy-normalised
    /// Airy pattern `π D²/(4λ²) [2 J1(x)/x]²` per sr, `x = π D sin θ / λ`
    /// (J1 by its integral, [`j1_integral`]), at the wavelengths of 001 eq
    /// 10 (`count` of them over 380–770 nm), each weighted by its colour
    /// matching functions `cmf` turned into linear sRGB by the IEC
    /// 61966-2-1 matrix (as printed in the standard, 4 decimals), the
    /// weighted sum averaged over 4 × 4 points of each pixel, then negatives
    /// clamped to 0 (the channel definition of [`PsfBuilder`]); the channel's
    /// light over all angles is `Σ_φ w_c(φ)`, each Airy pattern holding unit
    /// energy.
    fn independent_spectral_airy(
        d_mm: f64,
        ppd: f64,
        size: usize,
        radius_px: f64,
        count: usize,
        cmf: fn(f64) -> [f64; 3],
    ) -> Vec<[f64; 3]> {
        // IEC 61966-2-1:1999 eq (F.7): XYZ → linear sRGB.
        const SRGB: [[f64; 3]; 3] = [
            [3.2406, -1.5372, -0.4986],
            [-0.9689, 1.8758, 0.0415],
            [0.0557, -0.2040, 1.0570],
        ];
        let d_m = d_mm * 1e-3;
        let rad_px = (1.0 / ppd).to_radians();
        let k = count - 1;
        // (φ, w_R, w_G, w_B): the channel weights per wavelength.
        let weights: Vec<(f64, [f64; 3])> = (0..=k)
            .map(|i| {
                let phi = 380.0 + i as f64 / k as f64 * 390.0;
                let xyz = cmf(phi);
                let mut w = [0.0; 3];
                for (ch, wc) in w.iter_mut().enumerate() {
                    *wc = (0..3).map(|j| SRGB[ch][j] * xyz[j]).sum();
                }
                (phi, w)
            })
            .collect();
        let mut channel_light = [0.0; 3];
        for (_, w) in &weights {
            for ch in 0..3 {
                channel_light[ch] += w[ch];
            }
        }
        // Radial table of Σ_φ w_c(φ) I_φ(θ) Ω_px, 1/8 px steps.
        let step = 1.0 / 8.0;
        let n_tab = ((radius_px + 2.0) * std::f64::consts::SQRT_2 / step) as usize + 2;
        let table: Vec<[f64; 3]> = (0..n_tab)
            .into_par_iter()
            .map(|i| {
                let theta = i as f64 * step * rad_px;
                let mut acc = [0.0; 3];
                for &(phi, w) in &weights {
                    let lam = phi * 1e-9;
                    let x = std::f64::consts::PI * d_m * theta.sin() / lam;
                    let a = if x < 1e-9 {
                        1.0
                    } else {
                        2.0 * j1_integral(x) / x
                    };
                    let per_sr = std::f64::consts::PI * d_m * d_m / (4.0 * lam * lam) * a * a;
                    for ch in 0..3 {
                        acc[ch] += w[ch] * per_sr * rad_px * rad_px;
                    }
                }
                acc
            })
            .collect();
        let c = (size / 2) as f64;
        let mut out = vec![[0.0f64; 3]; size * size];
        out.par_chunks_mut(size).enumerate().for_each(|(v, row)| {
            for (u, o) in row.iter_mut().enumerate() {
                let (x, y) = (u as f64 - c, v as f64 - c);
                if x.hypot(y) > radius_px {
                    continue;
                }
                for sy in 0..4 {
                    for sx in 0..4 {
                        let ox = x + (sx as f64 - 1.5) / 4.0;
                        let oy = y + (sy as f64 - 1.5) / 4.0;
                        let t = ox.hypot(oy) / step;
                        let i = t.floor() as usize;
                        let f = t - i as f64;
                        for ch in 0..3 {
                            o[ch] += (table[i][ch] * (1.0 - f) + table[i + 1][ch] * f) / 16.0;
                        }
                    }
                }
                for ch in 0..3 {
                    o[ch] = o[ch].max(0.0) / channel_light[ch];
                }
            }
        });
        out
    }

    /// Mean per pixel in 1 px annuli (pixel centre distance rounded),
    /// radii `0..=r_max`, per channel.
    fn annulus_profile(px: &[[f64; 3]], size: usize, r_max: usize) -> Vec<[f64; 3]> {
        let c = (size / 2) as f64;
        let mut sum = vec![[0.0; 3]; r_max + 1];
        let mut n = vec![0usize; r_max + 1];
        for (i, p) in px.iter().enumerate() {
            let (x, y) = ((i % size) as f64 - c, (i / size) as f64 - c);
            let b = x.hypot(y).round() as usize;
            if b <= r_max {
                n[b] += 1;
                for ch in 0..3 {
                    sum[b][ch] += p[ch];
                }
            }
        }
        sum.iter()
            .zip(&n)
            .map(|(s, &k)| s.map(|v| v / k.max(1) as f64))
            .collect()
    }

    /// Issue 32 item 7: each channel of the clean-aperture kernel (no
    /// particles, no stray light) at 6000 ppd against that channel's
    /// spectral Airy sum, evaluated independently
    /// ([`independent_spectral_airy`]), for 2, 4 and 8 mm pupils.
    ///
    /// Like with like: the kernel holds unit energy within its wave-optics
    /// region (radius 510 px, 0.085° here: the kernel's field), so the
    /// reference is normalised to unit energy over the same pixels. The
    /// test asserts the peak (centre pixel) and the 1 px annulus mean at the
    /// first bright ring (the reference's maximum, per channel) within 3 %
    /// and prints the second and third rings;
    /// it also prints the profile's largest deviation out to the fourth dark
    /// ring (as a fraction of the peak), the peak against the Airy sum
    /// normalised over all angles (the kernel has no light beyond its
    /// field, the Airy pattern has 1–4 % there), and the peak and rings with
    /// the paper's single-lobe fit in place of the multi-lobe one.
    #[test]
    fn clean_aperture_channels_match_an_independent_spectral_airy_at_6000_ppd() {
        let ppd = 6000.0;
        for d_mm in [2.0, 4.0, 8.0] {
            let params = PsfParams {
                pupil_mm: d_mm,
                pupil_range_mm: [d_mm, d_mm],
                particles: 0,
                stray_light: false,
                ppd,
                field_deg: 0.17,
                ..PsfParams::default()
            };
            let (size, near, grid, plane_mm, kernel): (usize, usize, usize, f64, Vec<[f64; 3]>) = {
                let builder = PsfBuilder::new(params.clone()).unwrap();
                let s = *builder.sampling();
                let k = builder.kernel();
                (
                    k.size,
                    s.near_radius_px,
                    s.grid_size,
                    s.pupil_plane_mm,
                    k.rgb.iter().map(|p| p.map(f64::from)).collect(),
                )
            };
            let r_pupil_samples = d_mm / 2.0 / (plane_mm / grid as f64);
            let r_max = near;
            let kprof = annulus_profile(&kernel, size, r_max);
            let c = size / 2;
            for (fit, cmf) in [
                ("multi-lobe", test_cmf_multi_lobe as fn(f64) -> [f64; 3]),
                ("single-lobe", test_cmf_single_lobe as fn(f64) -> [f64; 3]),
            ] {
                let all_sky = independent_spectral_airy(
                    d_mm,
                    ppd,
                    size,
                    near as f64,
                    params.wavelength_count,
                    cmf,
                );
                let mut in_field = [0.0; 3];
                for p in &all_sky {
                    for ch in 0..3 {
                        in_field[ch] += p[ch];
                    }
                }
                let reference: Vec<[f64; 3]> = all_sky
                    .iter()
                    .map(|p| [0, 1, 2].map(|ch| p[ch] / in_field[ch]))
                    .collect();
                let rprof = annulus_profile(&reference, size, r_max);
                for (ch, name) in ["R", "G", "B"].into_iter().enumerate() {
                    let k0 = kernel[c * size + c][ch];
                    let peak = k0 / reference[c * size + c][ch] - 1.0;
                    let peak_all_sky = k0 / all_sky[c * size + c][ch] - 1.0;
                    // Bright rings: the reference profile's local maxima;
                    // dark rings: its local minima.
                    let mut rings = Vec::new();
                    let mut darks = Vec::new();
                    for b in 2..r_max {
                        let (p, v, n) = (rprof[b - 1][ch], rprof[b][ch], rprof[b + 1][ch]);
                        if v > p && v >= n {
                            rings.push(b);
                        }
                        if v < p && v <= n {
                            darks.push(b);
                        }
                    }
                    assert!(rings.len() >= 3 && darks.len() >= 4, "{d_mm} mm {name}");
                    let ring_err: Vec<f64> = rings[..3]
                        .iter()
                        .map(|&b| kprof[b][ch] / rprof[b][ch] - 1.0)
                        .collect();
                    let profile_dev = (0..=darks[3])
                        .map(|b| (kprof[b][ch] - rprof[b][ch]).abs())
                        .fold(0.0f64, f64::max)
                        / rprof[0][ch];
                    eprintln!(
                        "D {d_mm} mm ({r_pupil_samples:.2} samples radius, N {grid}), {fit} fit, {name}: \
                         peak {:+.2} % (all-sky normalised {:+.2} %, in-field light {:.2} %); \
                         bright rings at {:?} px: {:+.2?} %; profile to {} px: max |Δ| {:.3} % of the peak",
                        peak * 100.0,
                        peak_all_sky * 100.0,
                        in_field[ch] * 100.0,
                        &rings[..3],
                        ring_err.iter().map(|e| e * 100.0).collect::<Vec<_>>(),
                        darks[3],
                        profile_dev * 100.0
                    );
                    if fit == "multi-lobe" {
                        assert!(peak.abs() < 0.03, "{d_mm} mm {name}: peak {peak}");
                        // The first bright ring is asserted; the second and
                        // third are printed: the cell-averaged aperture's
                        // spectrum is the disc's times sinc(fΔx) per axis,
                        // which lowers them (2 mm, 12 samples radius: ≈ −4 %
                        // and −8 %).
                        assert!(
                            ring_err[0].abs() < 0.03,
                            "{d_mm} mm {name}: ring 1 {}",
                            ring_err[0]
                        );
                    }
                }
            }
        }
    }

    #[test]
    fn clean_aperture_first_dark_ring_at_1_22_lambda_over_d_scales_as_1_over_d() {
        let lambda_m = REFERENCE_WAVELENGTH_NM * 1e-9;
        let mut radii = Vec::new();
        for d_mm in [2.0, 4.0, 8.0] {
            // A fine far-field grid: at 1500 ppd one sample is ≤ 1.16e-5 rad.
            let params = PsfParams {
                pupil_mm: d_mm,
                pupil_range_mm: [d_mm, d_mm],
                particles: 0,
                ppd: 1500.0,
                field_deg: 0.2,
                ..PsfParams::default()
            };
            let m = monochromatic_psf(&params, REFERENCE_WAVELENGTH_NM).unwrap();
            let r = m.first_minimum_rad().expect("a dark ring");
            let expected = 1.22 * lambda_m / (d_mm * 1e-3);
            let err = (r - expected).abs() / expected;
            eprintln!(
                "D = {d_mm} mm: first minimum {r:.5e} rad, 1.22 λ/D = {expected:.5e} rad, error {:.2} %",
                err * 100.0
            );
            assert!(err < 0.03, "D = {d_mm} mm: {r:.4e} vs {expected:.4e}");
            radii.push(r);
        }
        // A smaller pupil widens the rings: the radius scales as 1/D.
        for w in radii.windows(2) {
            let ratio = w[0] / w[1];
            assert!((ratio - 2.0).abs() < 0.06, "ratio {ratio}");
        }
    }

    #[test]
    fn smaller_pupil_gives_wider_rings_in_the_kernel() {
        // Radius holding half the near-field light, display pixels.
        let half_radius = |d_mm: f64| -> f64 {
            let k = build_kernel(&PsfParams {
                pupil_mm: d_mm,
                particles: 0,
                stray_light: false,
                ppd: 2000.0,
                field_deg: 0.2,
                ..PsfParams::default()
            })
            .unwrap();
            let c = k.centre() as f64;
            let mut rings: Vec<(f64, f64)> = k
                .rgb
                .iter()
                .enumerate()
                .map(|(i, p)| {
                    let (x, y) = ((i % k.size) as f64 - c, (i / k.size) as f64 - c);
                    (x.hypot(y), f64::from(p[1]))
                })
                .collect();
            rings.sort_by(|a, b| a.0.total_cmp(&b.0));
            let mut acc = 0.0;
            for (r, v) in rings {
                acc += v;
                if acc >= 0.5 {
                    return r;
                }
            }
            f64::INFINITY
        };
        let (r2, r4, r8) = (half_radius(2.0), half_radius(4.0), half_radius(8.0));
        eprintln!("half-energy radius: D 2 mm {r2} px, 4 mm {r4} px, 8 mm {r8} px");
        assert!(r2 > 1.6 * r4 && r4 > 1.6 * r8, "{r2} {r4} {r8}");
    }

    #[test]
    fn particle_scatter_scales_with_covered_area() {
        // Same covered area (5 % of a 4 mm pupil) from 5 µm particles (below
        // one pupil-plane sample) and from 40 µm ones (above); the light
        // scattered beyond 0.14° must match, and be the covered fraction.
        let base = PsfParams {
            pupil_mm: 4.0,
            pupil_range_mm: [4.0, 4.0],
            stray_light: false,
            ppd: 14.0,
            field_deg: 80.0,
            ..PsfParams::default()
        };
        let beyond = |k: &PsfKernel, r_px: f64| -> f64 {
            let c = k.centre() as f64;
            k.rgb
                .iter()
                .enumerate()
                .filter(|(i, _)| ((i % k.size) as f64 - c).hypot((i / k.size) as f64 - c) > r_px)
                .map(|(_, p)| {
                    0.2126 * f64::from(p[0]) + 0.7152 * f64::from(p[1]) + 0.0722 * f64::from(p[2])
                })
                .sum()
        };
        let clean = build_kernel(&PsfParams {
            particles: 0,
            ..base.clone()
        })
        .unwrap();
        let e_clean = beyond(&clean, 2.0);
        let mut scatter = Vec::new();
        for (um, count) in [(5.0, 32_000usize), (40.0, 500)] {
            let params = PsfParams {
                particles: count,
                particle_um: um,
                ..base.clone()
            };
            let builder = PsfBuilder::new(params.clone()).unwrap();
            let dx_um = builder.sampling().sample_mm() * 1e3;
            let sigma = builder.particle_scatter_fraction(4.0);
            let s = beyond(builder.kernel(), 2.0) - e_clean;
            eprintln!(
                "{count} particles of {um} µm (sample {dx_um:.1} µm): covered {:.4}, scattered beyond 0.14°: {s:.4}",
                sigma
            );
            assert!((sigma - 0.05).abs() < 0.01, "covered fraction {sigma}");
            assert!(
                s > 0.75 * sigma && s < 1.15 * sigma,
                "{um} µm: {s} vs {sigma}"
            );
            scatter.push((um, dx_um, s));
        }
        assert!(scatter[0].0 < scatter[0].1 && scatter[1].0 > scatter[1].1);
        let ratio = scatter[0].2 / scatter[1].2;
        assert!(
            (0.8..1.25).contains(&ratio),
            "5 µm vs 40 µm scatter ratio {ratio}"
        );
    }

    #[test]
    fn sampling_follows_the_request() {
        let default = PsfParams::default().sampling().unwrap();
        assert_eq!(default.grid_size, 1024);
        assert!(default.pupil_plane_mm >= 18.0);
        for (ppd, d) in [(14.0, 2.0), (60.0, 4.0), (1000.0, 2.0), (6000.0, 8.0)] {
            let p = PsfParams {
                pupil_mm: d,
                pupil_range_mm: [d, d],
                ppd,
                field_deg: 2000.0 / ppd,
                ..PsfParams::default()
            };
            let s = p.sampling().unwrap();
            let rad_px = (1.0 / ppd).to_radians();
            assert!(s.grid_size.is_power_of_two() && s.grid_size <= MAX_GRID_SIZE);
            assert!(s.rad_per_sample(770.0) <= rad_px * (1.0 + 1e-12));
            assert!(s.pupil_plane_mm >= 2.0 * d);
            assert!(d / s.sample_mm() >= MIN_PUPIL_SAMPLES - 1e-9);
            // The FFT half field holds the near region at 380 nm.
            let half_field = REFERENCE_WAVELENGTH_NM * 1e-6 / (2.0 * s.sample_mm());
            assert!(half_field >= s.near_radius_px as f64 * rad_px * 575.0 / 380.0);
        }
        // A request no 4096 grid can meet is an error naming the ppd.
        let bad = PsfParams {
            pupil_range_mm: [0.5, 9.0],
            pupil_mm: 1.0,
            ppd: 20000.0,
            field_deg: 0.05,
            ..PsfParams::default()
        };
        assert!(bad.sampling().unwrap_err().to_string().contains("psf.ppd"));
    }

    #[test]
    fn parseval_psf_holds_the_light_through_the_pupil() {
        let params = PsfParams {
            particles: 0,
            ..PsfParams::default()
        };
        let s = params.sampling().unwrap();
        let m = monochromatic_psf(&params, REFERENCE_WAVELENGTH_NM).unwrap();
        let lambda_d = REFERENCE_WAVELENGTH_NM * 1e-6 * PUPIL_RETINA_MM;
        let total: f64 = m.values.iter().sum::<f64>() * lambda_d * lambda_d;
        let r = params.pupil_mm / 2.0 / s.sample_mm();
        let area = std::f64::consts::PI * r * r;
        assert!((total - area).abs() / area < 0.01, "{total} vs {area}");
    }

    #[test]
    fn kernel_has_unit_energy_and_covers_the_field() {
        let k = build_kernel(&PsfParams::default()).unwrap();
        assert_eq!(k.size, 2 * (20.0f64 * 13.85).round() as usize + 1);
        for (ch, e) in k.energy().iter().enumerate() {
            assert!((e - 1.0).abs() < 1e-4, "channel {ch} sums to {e}");
        }
        assert!(
            k.rgb
                .iter()
                .all(|p| p.iter().all(|v| v.is_finite() && *v >= 0.0))
        );
        let c = k.at(0, 0);
        assert!(k.rgb.iter().all(|p| p[1] <= c[1]));
        // Light reaches the field's edge (one pixel inside the radius).
        assert!(k.at(k.centre() as isize - 1, 0)[1] > 0.0);
    }

    /// Issue 39: the kernel is a square of 2r + 1 pixels; its veil used to
    /// stop at the square's edges, r pixels from a source, a step in every
    /// frame with a bright source. It must fall to 0 on the circle of
    /// radius r, with no step on the way: 0 at and beyond r (the square's
    /// corners included), and from 0.6 r on, where the taper starts, no
    /// ring below the one inside it by more than 4 × what a 1/θ² veil
    /// loses over one pixel at 0.6 r (2 / (0.6 r) of itself), as a
    /// fraction of the ring at 0.6 r.
    #[test]
    fn kernel_falls_to_zero_at_its_radius_without_a_step() {
        for (ppd, field_deg) in [(13.85, 40.0), (6.3, 40.0), (14.0, 10.0)] {
            let k = build_kernel(&PsfParams {
                ppd,
                field_deg,
                ..PsfParams::default()
            })
            .unwrap();
            let r = k.centre() as isize;
            let mut beyond = 0.0f64;
            for dy in -r..=r {
                for dx in -r..=r {
                    if dx * dx + dy * dy >= r * r {
                        beyond = beyond.max(f64::from(k.at(dx, dy)[1]));
                    }
                }
            }
            assert_eq!(
                beyond,
                0.0,
                "{ppd} ppd ±{}°: light at or past r",
                field_deg / 2.0
            );
            let start = (0.6 * r as f64).floor() as usize;
            let at_start = ring_mean(&k, start);
            assert!(at_start > 0.0);
            let mut worst = 0.0f64;
            for d in start..r as usize {
                let drop = ring_mean(&k, d) - ring_mean(&k, d + 1);
                worst = worst.max(drop / at_start);
            }
            // 1/θ²: the veil falls by 2/d of itself per pixel at d.
            let bound = 4.0 * 2.0 / start as f64;
            eprintln!(
                "{ppd} ppd ±{}°: largest fall between neighbouring rings from 0.6 r to r: {worst:.4} of the veil at 0.6 r (bound {bound:.4})",
                field_deg / 2.0
            );
            assert!(worst < bound, "{ppd} ppd: a step of {worst:.4} of the veil");
        }
    }

    #[test]
    fn clean_kernel_is_radially_symmetric() {
        let params = PsfParams {
            particles: 0,
            ppd: 2000.0,
            field_deg: 64.0 / 2000.0,
            wavelength_count: 16,
            ..PsfParams::default()
        };
        let k = build_kernel(&params).unwrap();
        let peak = k.at(0, 0)[1];
        let r = k.centre() as isize;
        let mut checked = 0;
        for a in 0..=r {
            for b in 0..=a {
                let v = k.at(a, b);
                for (x, y) in [(-b, a), (-a, -b), (b, -a), (b, a), (-a, b)] {
                    let w = k.at(x, y);
                    for ch in 0..3 {
                        let tol = 1e-4 * v[ch].max(w[ch]) + 1e-7 * peak;
                        assert!((v[ch] - w[ch]).abs() <= tol, "({a},{b}) vs ({x},{y})");
                    }
                    checked += 1;
                }
            }
        }
        assert!(checked > 1000);
    }

    #[test]
    fn long_wavelengths_spread_further() {
        let params = PsfParams {
            particles: 0,
            stray_light: false,
            ppd: 2000.0,
            field_deg: 128.0 / 2000.0,
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
            field_deg: 10.0,
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
            field_deg: 6.0,
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
        assert_eq!(builder.rebuild(50.0).pupil_mm, p.max_pupil_mm());
        assert_eq!(builder.rebuild(f64::NAN).pupil_mm, p.max_pupil_mm());
        assert!(builder.try_rebuild(-1.0).is_err());
        assert!(builder.try_rebuild(3.0).is_ok());
    }

    /// A paced rebuild gives the same kernel bit for bit, and hands control
    /// back often: at least once per 2¹⁶ grid samples of each pass over the
    /// N² grid (fill, two FFT passes of which the first skips rows outside
    /// the pupil, two transposes, the |·|² output and the summed-area
    /// table: more than 5 N² / 2¹⁶ calls in all).
    #[test]
    fn paced_rebuild_matches_and_yields_between_steps() {
        let p = PsfParams {
            field_deg: 6.0,
            ..PsfParams::default()
        };
        let mut plain = PsfBuilder::new(p.clone()).unwrap();
        let mut paced = PsfBuilder::new(p).unwrap();
        let n = paced.sampling().grid_size;
        let mut calls = 0usize;
        let got = paced.rebuild_paced(5.5, &mut || calls += 1).clone();
        assert_eq!(got, *plain.rebuild(5.5));
        let floor = 5 * n * n / PACE_STEP_ELEMENTS;
        assert!(
            calls > floor,
            "{calls} pace calls for a {n}² grid (more than {floor} expected)"
        );
    }

    #[test]
    fn seed_scale_lays_the_fft_field_over_the_glare_window() {
        let physical = build_kernel(&PsfParams {
            field_deg: 10.0,
            ..PsfParams::default()
        })
        .unwrap();
        let seed = build_kernel(&PsfParams {
            field_deg: 10.0,
            glare_scale: GlareScale::Seed,
            ..PsfParams::default()
        })
        .unwrap();
        assert_eq!(seed.size, physical.size);
        for e in seed.energy() {
            assert!((e - 1.0).abs() < 1e-4);
        }
        // 001's NDC scale magnifies the Airy core by (field/N)/(λ/W): at
        // 13.85 ppd the core spreads over several pixels instead of one.
        let (p0, s0) = (physical.at(0, 0)[1], seed.at(0, 0)[1]);
        assert!(
            p0 > 0.5 && s0 < 0.6 * p0,
            "centre pixel: physical {p0}, seed {s0}"
        );
        assert_eq!("seed".parse::<GlareScale>(), Ok(GlareScale::Seed));
        assert!("bogus".parse::<GlareScale>().is_err());
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
            },
            PsfParams {
                pupil_range_mm: [3.0, 2.0],
                ..ok.clone()
            },
            PsfParams {
                pupil_range_mm: [0.0, 2.0],
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
                ppd: f64::INFINITY,
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
                field_deg: 40.0,
                ppd: 200.0,
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
        let core_peak = |dd: f64| -> f32 {
            build_kernel(&PsfParams {
                particles: 0,
                stray_light: false,
                pupil_mm: 6.0,
                defocus_dioptres: dd,
                ppd: 1000.0,
                field_deg: 0.2,
                ..PsfParams::default()
            })
            .unwrap()
            .at(0, 0)[1]
        };
        let (f0, f1) = (core_peak(0.0), core_peak(0.5));
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
                assert!((got[k] - want[k]).abs() < 0.04, "{l} nm component {k}");
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
