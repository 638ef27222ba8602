//! The pupil light response: what the pupil does, over time, to the light
//! each eye sees — so that what it does beyond that (a task-evoked
//! dilation) is left over as a residual.
//!
//! Three parts:
//!
//! 1. **Static target.** Per frame and per eye an [`EyeInput`]: the
//!    luminance pooled at that eye's gaze, the field's mean luminance, the
//!    field area and whether the eye sees light at all. The eye's
//!    *effective adapting luminance* is a mix of the two luminances
//!    ([`Adaptation::gaze_weight`], see [`effective_luminance_cd_m2`]); its
//!    flux is that times the field area. The two eyes' fluxes are combined
//!    with Watson & Yellott's monocular attenuation M(e) ([`combined_flux`]):
//!    both eyes lit equally → the binocular flux, one eye lit → M(1) = 0.1
//!    of it. The combined drive is *consensual*: both pupils follow it. The
//!    static end point is W&Y's unified formula of that flux and the
//!    observer's age ([`static_target_mm`]).
//! 2. **Dynamics.** A pure delay (the reflex latency) followed by a
//!    first-order approach to the delayed target, with a short time
//!    constant while constricting and a long one while redilating
//!    ([`Dynamics`]; constants and sources there). [`PupilLightResponse`]
//!    is the state machine: [`PupilLightResponse::step`] takes the time and
//!    the frame's [`EyeLight`] and returns the predicted diameter. The
//!    delay line is a ring buffer allocated once in
//!    [`PupilLightResponse::new`]; a step never allocates.
//! 3. **The observer.** [`ObserverRange`] maps the formula's diameter onto
//!    this observer (`pupil_mm = scale · formula_mm + offset_mm`), from the
//!    black/white calibration profile ([`ObserverRange::from_calibration`])
//!    or fitted on a baseline block with the dynamics ([`fit_observer`],
//!    Nelder–Mead over the dynamics, closed-form least squares for the
//!    range).
//!
//! The residual `measured − predicted` ([`residual_mm`],
//! [`residuals_mm`]) is what the light does not explain.
//!
//! # Robustness
//!
//! * Luminances and areas that are NaN or negative count as 0 (darkness),
//!   +∞ as [`MAX_LUMINANCE_CD_M2`] / [`MAX_FIELD_AREA_DEG2`].
//! * A step whose time is not finite changes nothing and returns the last
//!   prediction.
//! * Time going backwards (a replay seek) re-bases the clock: the pupil
//!   keeps its diameter, the delay line is refilled with the target it was
//!   heading for, and the new light takes effect one latency later.
//! * Gaps of any length are integrated exactly for a light that holds from
//!   one step to the next (the first-order step response is closed form);
//!   after a gap of many time constants the pupil is adapted to the light.
//! * The output is always finite and within [`PUPIL_MIN_MM`, `PUPIL_MAX_MM`].
//!
//! # Example
//!
//! Dark, then a 100 cd/m² field in both eyes at t = 1 s: the pupil holds
//! its dark size through the latency, then constricts.
//!
//! ```
//! use gazelight_eye::pupil_response::{EyeInput, EyeLight, PupilLightResponse, ResponseParams};
//!
//! let mut plr = PupilLightResponse::new(ResponseParams::default()).unwrap();
//! let dark = EyeLight::both(EyeInput::uniform(0.01, 2827.0));
//! let bright = EyeLight::both(EyeInput::uniform(100.0, 2827.0));
//! let mut t = 0.0;
//! let mut d_dark = 0.0;
//! while t < 1.0 {
//!     d_dark = plr.step(t, &dark);
//!     t += 0.01;
//! }
//! let d_latent = plr.step(1.1, &bright); // within the latency
//! assert!((d_latent - d_dark).abs() < 1e-9);
//! let d_late = plr.step(4.0, &bright);
//! assert!(d_late < d_dark - 2.0, "{d_dark} → {d_late}");
//! ```

use crate::profile::EyeCalibration;
use crate::pupil_model::{MONOCULAR_FACTOR, REFERENCE_AGE_YEARS, unified_from_flux_mm};

/// Smallest diameter the model outputs, mm (the anatomical floor gazelight
/// uses, the lower end of `filter::physio::PUPIL_MM_RANGE`; W&Y's formula
/// alone never goes below ≈ 2 mm).
pub const PUPIL_MIN_MM: f64 = crate::filter::physio::PUPIL_MM_RANGE.0 as f64;
/// Largest diameter the model outputs, mm (the upper end of
/// `filter::physio::PUPIL_MM_RANGE`).
pub const PUPIL_MAX_MM: f64 = crate::filter::physio::PUPIL_MM_RANGE.1 as f64;
/// +∞ luminance counts as this, cd/m² (about the sun's disc, 1.6·10⁹).
pub const MAX_LUMINANCE_CD_M2: f64 = 1.6e9;
/// +∞ field area counts as this, deg² (the whole sphere, 4π sr).
pub const MAX_FIELD_AREA_DEG2: f64 = 41_253.0;
/// Binocular flux factor M(2) (W&Y 2012, effective corneal flux density).
const BINOCULAR_FACTOR: f64 = 1.0;

/// The longest latency a model accepts, s (the delay line is sized from
/// it): well above the 0.49 s of the slowest historical report (von Arlt
/// 1869, as Feinberg & Podolak 1965 list it).
pub const MAX_LATENCY_SECS: f64 = 2.0;

/// Reflex latency, s: the middle of the 0.2–0.3 s most investigators
/// agree on (Feinberg & Podolak 1965, "Latency of pupillary reflex to light
/// stimulation and its relationship to aging", review p. 2).
pub const DEFAULT_LATENCY_SECS: f64 = 0.25;
/// Constriction time constant, s: latency + 2.3 τ (90 % of a first-order
/// step) = 0.94 s, the end of the secondary contraction in Gradle &
/// Eisendrath (1923): latent 0.1875 s + primary 0.4365 s + secondary 0.3125 s.
pub const DEFAULT_CONSTRICTION_TAU_SECS: f64 = 0.3;
/// Redilation time constant, s: latency + 3 τ (95 %) ≈ 4.75 s, the ≈ 5 s
/// dilation phase of the PLR (J. Clin. Med. 2024, 13(23):7451, introduction,
/// citing its ref. 4); also what a delay + first-order fit gives on the
/// red flashes of the piprkit recording (tests/pupil_response_plr.rs).
pub const DEFAULT_REDILATION_TAU_SECS: f64 = 1.5;
/// Share of the gaze-pooled luminance in the adapting luminance (gazelight's
/// choice, see [`effective_luminance_cd_m2`]; not fitted to data).
pub const DEFAULT_GAZE_WEIGHT: f64 = 0.5;
/// Time resolution of the delay line: at most this many entries per second
/// of latency are kept (inputs closer together update the newest entry).
pub const DELAY_LINE_RATE_HZ: f64 = 1000.0;

/// Index of the right eye in [`EyeLight::eyes`] (Pupil Core order, as
/// [`crate::EYE_RIGHT`]).
pub const RIGHT: usize = crate::state::EYE_RIGHT;
/// Index of the left eye in [`EyeLight::eyes`].
pub const LEFT: usize = crate::state::EYE_LEFT;

/// What one eye sees in one frame.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct EyeInput {
    /// Luminance pooled around this eye's gaze point, cd/m².
    pub gaze_luminance_cd_m2: f64,
    /// Mean luminance over the field this eye sees, cd/m².
    pub field_mean_luminance_cd_m2: f64,
    /// Area of that field, deg² (W&Y's `a`).
    pub field_area_deg2: f64,
    /// Whether the eye sees the light at all (false: occluded, closed, the
    /// display shows this eye nothing) — its flux is then 0.
    pub lit: bool,
}

impl EyeInput {
    /// An eye that sees nothing.
    pub const DARK: Self = Self {
        gaze_luminance_cd_m2: 0.0,
        field_mean_luminance_cd_m2: 0.0,
        field_area_deg2: 0.0,
        lit: false,
    };

    /// A lit eye looking at a uniform field of `luminance_cd_m2` over
    /// `field_area_deg2`.
    pub fn uniform(luminance_cd_m2: f64, field_area_deg2: f64) -> Self {
        Self {
            gaze_luminance_cd_m2: luminance_cd_m2,
            field_mean_luminance_cd_m2: luminance_cd_m2,
            field_area_deg2,
            lit: true,
        }
    }
}

/// What both eyes see in one frame: `eyes[RIGHT]`, `eyes[LEFT]`.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct EyeLight {
    /// Per eye, indexed by [`RIGHT`] and [`LEFT`].
    pub eyes: [EyeInput; 2],
}

impl EyeLight {
    /// Both eyes see `input`.
    pub fn both(input: EyeInput) -> Self {
        Self {
            eyes: [input, input],
        }
    }

    /// Only eye `eye` ([`RIGHT`] or [`LEFT`]; anything else counts as the
    /// left) sees `input`; the other is dark.
    pub fn one(eye: usize, input: EyeInput) -> Self {
        let mut eyes = [EyeInput::DARK; 2];
        eyes[eye.min(1)] = input;
        Self { eyes }
    }
}

/// How luminance becomes the adapting drive.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct Adaptation {
    /// Share of the gaze-pooled luminance in the effective adapting
    /// luminance, 0..=1 (the rest is the field mean).
    pub gaze_weight: f64,
    /// Observer age, years (W&Y's `y`).
    pub age_years: f64,
}

impl Default for Adaptation {
    fn default() -> Self {
        Self {
            gaze_weight: DEFAULT_GAZE_WEIGHT,
            age_years: REFERENCE_AGE_YEARS,
        }
    }
}

fn clean_luminance(l: f64) -> f64 {
    if l.is_nan() {
        0.0
    } else {
        l.clamp(0.0, MAX_LUMINANCE_CD_M2)
    }
}

fn clean_area(a: f64) -> f64 {
    if a.is_nan() {
        0.0
    } else {
        a.clamp(0.0, MAX_FIELD_AREA_DEG2)
    }
}

/// The eye's effective adapting luminance, cd/m²:
/// `w · L_gaze + (1 − w) · L_mean` with `w` = `gaze_weight` (clamped to
/// 0..=1; NaN counts as the default).
///
/// Why a mix: W&Y's formula is fitted on *uniform* fields, where both
/// terms are the same luminance and the mix reduces to it exactly. In a
/// non-uniform scene the field mean is the corneal flux density the
/// formula is built on (Stanley & Davies 1995: diameter depends on
/// luminance × area), while the pupil weights the centre of the field more
/// than its periphery (Crawford 1936, "The dependence of pupil size upon
/// external light stimulus under static and variable conditions", found
/// patches of light less effective the further they lie from the line of
/// sight); the gaze-pooled luminance stands for that centre. The default
/// weight 0.5 is a choice, not a fit: [`fit_observer`] does not move it.
pub fn effective_luminance_cd_m2(input: &EyeInput, gaze_weight: f64) -> f64 {
    let w = if gaze_weight.is_nan() {
        DEFAULT_GAZE_WEIGHT
    } else {
        gaze_weight.clamp(0.0, 1.0)
    };
    w * clean_luminance(input.gaze_luminance_cd_m2)
        + (1.0 - w) * clean_luminance(input.field_mean_luminance_cd_m2)
}

/// One eye's corneal flux density, cd·deg²/m²: effective luminance × field
/// area, 0 when the eye is not lit.
pub fn eye_flux(input: &EyeInput, gaze_weight: f64) -> f64 {
    if !input.lit {
        return 0.0;
    }
    effective_luminance_cd_m2(input, gaze_weight) * clean_area(input.field_area_deg2)
}

/// The consensual drive of both pupils, cd·deg²/m²: W&Y's effective
/// corneal flux density L·a·M(e) generalised to two eyes that may see
/// different light,
///
/// ```text
/// F = M(1) · (F_R + F_L) + (M(2) − 2·M(1)) · min(F_R, F_L)
/// ```
///
/// — the summed monocular drive plus the binocular facilitation of the flux
/// both eyes share. Both eyes lit equally (F_R = F_L = L·a): F = M(2)·L·a,
/// W&Y's binocular case; one eye lit: F = M(1)·L·a, their monocular case.
pub fn combined_flux(light: &EyeLight, gaze_weight: f64) -> f64 {
    let fr = eye_flux(&light.eyes[RIGHT], gaze_weight);
    let fl = eye_flux(&light.eyes[LEFT], gaze_weight);
    MONOCULAR_FACTOR * (fr + fl) + (BINOCULAR_FACTOR - 2.0 * MONOCULAR_FACTOR) * fr.min(fl)
}

/// The static (light-adapted) diameter for this light, mm: W&Y's unified
/// formula (eq. 21) of [`combined_flux`] and the observer's age. Not
/// clamped and not mapped onto an observer.
pub fn static_target_mm(light: &EyeLight, adaptation: &Adaptation) -> f64 {
    let age = if adaptation.age_years.is_finite() {
        adaptation.age_years
    } else {
        REFERENCE_AGE_YEARS
    };
    unified_from_flux_mm(combined_flux(light, adaptation.gaze_weight), age)
}

/// The reflex dynamics: delay, then a first-order approach to the delayed
/// static target, faster while constricting than while redilating.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct Dynamics {
    /// Pure delay from light to pupil, s (`(0, MAX_LATENCY_SECS]`).
    pub latency_secs: f64,
    /// Time constant while the pupil is larger than its delayed target, s.
    pub constriction_tau_secs: f64,
    /// Time constant while the pupil is smaller than its delayed target, s.
    pub redilation_tau_secs: f64,
}

impl Default for Dynamics {
    fn default() -> Self {
        Self {
            latency_secs: DEFAULT_LATENCY_SECS,
            constriction_tau_secs: DEFAULT_CONSTRICTION_TAU_SECS,
            redilation_tau_secs: DEFAULT_REDILATION_TAU_SECS,
        }
    }
}

/// This observer's pupil as an affine map of the formula's:
/// `pupil_mm = scale · formula_mm + offset_mm`.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct ObserverRange {
    /// Dimensionless, > 0.
    pub scale: f64,
    /// mm.
    pub offset_mm: f64,
}

impl Default for ObserverRange {
    fn default() -> Self {
        Self::IDENTITY
    }
}

impl ObserverRange {
    /// The formula as it is.
    pub const IDENTITY: Self = Self {
        scale: 1.0,
        offset_mm: 0.0,
    };

    /// Maps a formula diameter onto this observer, mm.
    #[inline]
    pub fn apply(&self, formula_mm: f64) -> f64 {
        self.scale * formula_mm + self.offset_mm
    }

    /// The range from a black/white calibration: the formula's diameters
    /// at the black phase's and the white phase's luminance (each a uniform
    /// binocular field of `field_area_deg2`, observer aged `age_years`) are
    /// mapped onto the profile's `mm_max` (black) and `mm_min` (white).
    pub fn from_calibration(
        calibration: &EyeCalibration,
        black_luminance_cd_m2: f64,
        white_luminance_cd_m2: f64,
        field_area_deg2: f64,
        age_years: f64,
    ) -> Result<Self, ResponseError> {
        for (what, v) in [
            ("black_luminance_cd_m2", black_luminance_cd_m2),
            ("white_luminance_cd_m2", white_luminance_cd_m2),
            ("field_area_deg2", field_area_deg2),
            ("age_years", age_years),
        ] {
            if !(v.is_finite() && v >= 0.0) {
                return Err(ResponseError::Parameter {
                    what,
                    reason: format!("must be a finite number ≥ 0, got {v}"),
                });
            }
        }
        let adaptation = Adaptation {
            gaze_weight: DEFAULT_GAZE_WEIGHT,
            age_years,
        };
        let black = static_target_mm(
            &EyeLight::both(EyeInput::uniform(black_luminance_cd_m2, field_area_deg2)),
            &adaptation,
        );
        let white = static_target_mm(
            &EyeLight::both(EyeInput::uniform(white_luminance_cd_m2, field_area_deg2)),
            &adaptation,
        );
        if black - white <= 1e-6 || (black - white).is_nan() {
            return Err(ResponseError::Parameter {
                what: "white_luminance_cd_m2",
                reason: format!(
                    "the formula's pupil at the white luminance ({white_luminance_cd_m2} cd/m², \
                     {white:.4} mm) must be smaller than at the black one \
                     ({black_luminance_cd_m2} cd/m², {black:.4} mm)"
                ),
            });
        }
        let scale = (calibration.mm_max - calibration.mm_min) / (black - white);
        if !(scale.is_finite() && scale > 0.0) {
            return Err(ResponseError::Parameter {
                what: "calibration.mm_max",
                reason: format!(
                    "mm_max ({}) must exceed mm_min ({})",
                    calibration.mm_max, calibration.mm_min
                ),
            });
        }
        Ok(Self {
            scale,
            offset_mm: calibration.mm_max - scale * black,
        })
    }
}

/// Everything the state machine needs.
#[derive(Clone, Copy, Debug, PartialEq, Default)]
pub struct ResponseParams {
    pub adaptation: Adaptation,
    pub dynamics: Dynamics,
    pub range: ObserverRange,
}

impl ResponseParams {
    /// Checks every field; the error names the one that is wrong.
    pub fn validate(&self) -> Result<(), ResponseError> {
        let d = &self.dynamics;
        let checks: [(&'static str, f64, f64, f64); 7] = [
            (
                "dynamics.latency_secs",
                d.latency_secs,
                1e-3,
                MAX_LATENCY_SECS,
            ),
            (
                "dynamics.constriction_tau_secs",
                d.constriction_tau_secs,
                1e-3,
                600.0,
            ),
            (
                "dynamics.redilation_tau_secs",
                d.redilation_tau_secs,
                1e-3,
                600.0,
            ),
            (
                "adaptation.gaze_weight",
                self.adaptation.gaze_weight,
                0.0,
                1.0,
            ),
            (
                "adaptation.age_years",
                self.adaptation.age_years,
                0.0,
                120.0,
            ),
            ("range.scale", self.range.scale, 1e-3, 100.0),
            ("range.offset_mm", self.range.offset_mm, -100.0, 100.0),
        ];
        for (what, v, lo, hi) in checks {
            if !(v.is_finite() && (lo..=hi).contains(&v)) {
                return Err(ResponseError::Parameter {
                    what,
                    reason: format!("must be a finite number in {lo}..={hi}, got {v}"),
                });
            }
        }
        Ok(())
    }
}

/// Why a model could not be built or fitted.
#[derive(Debug, Clone, PartialEq, thiserror::Error)]
pub enum ResponseError {
    /// A parameter is out of range.
    #[error("pupil response parameter `{what}`: {reason}")]
    Parameter { what: &'static str, reason: String },
    /// Too few rows with a valid pupil to fit.
    #[error(
        "pupil response fit: only {used} of {rows} rows have a finite pupil > 0 mm; \
         at least {required} are needed"
    )]
    TooFewSamples {
        used: usize,
        rows: usize,
        required: usize,
    },
    /// A row's time is NaN or ±∞.
    #[error("pupil response fit: row {row} has a non-finite t_secs ({t_secs})")]
    TimeNotFinite { row: usize, t_secs: f64 },
    /// The rows go back in time (`row` ≥ 1; the previous row is `row − 1`).
    #[error(
        "pupil response fit: row {row} has t_secs = {t_secs}, not after the previous row's {previous}"
    )]
    TimeNotIncreasing {
        row: usize,
        t_secs: f64,
        previous: f64,
    },
    /// The light did not change enough over the block to tell the range.
    #[error(
        "pupil response fit: the predicted pupil varies by only {spread_mm:.2e} mm over the \
         block; the light must change to fit the observer's range"
    )]
    NoLightVariation { spread_mm: f64 },
    /// The best fit has the pupil widen with light.
    #[error(
        "pupil response fit: the fitted range scale is {scale} (≤ 0): the pupil does not constrict with light in this block"
    )]
    NonPositiveScale { scale: f64 },
}

/// The pupil light response state machine: see the module doc.
#[derive(Clone, Debug)]
pub struct PupilLightResponse {
    params: ResponseParams,
    /// Delay line: (time the target took effect at the cornea, target mm).
    times: Vec<f64>,
    targets: Vec<f64>,
    head: usize,
    len: usize,
    /// Minimum spacing of delay-line entries, s.
    spacing_secs: f64,
    /// Formula-domain diameter, mm (before the observer range).
    pupil_formula_mm: f64,
    /// Time of the last step, s (None before the first).
    last_t_secs: Option<f64>,
    last_output_mm: f64,
}

impl PupilLightResponse {
    /// A model; allocates its delay line (sized from the latency and
    /// [`DELAY_LINE_RATE_HZ`]) here and never again.
    pub fn new(params: ResponseParams) -> Result<Self, ResponseError> {
        params.validate()?;
        let latency = params.dynamics.latency_secs;
        let capacity = (latency * DELAY_LINE_RATE_HZ).ceil() as usize + 4;
        let dark = static_target_mm(&EyeLight::both(EyeInput::DARK), &params.adaptation);
        Ok(Self {
            params,
            times: vec![0.0; capacity],
            targets: vec![0.0; capacity],
            head: 0,
            len: 0,
            spacing_secs: latency / (capacity - 3) as f64,
            pupil_formula_mm: dark,
            last_t_secs: None,
            last_output_mm: Self::clamp_out(params.range.apply(dark)),
        })
    }

    /// The parameters.
    pub fn params(&self) -> &ResponseParams {
        &self.params
    }

    /// Forgets all history: the next step starts adapted to its light.
    pub fn reset(&mut self) {
        self.len = 0;
        self.head = 0;
        self.last_t_secs = None;
    }

    fn clamp_out(mm: f64) -> f64 {
        if mm.is_nan() {
            return PUPIL_MAX_MM;
        }
        mm.clamp(PUPIL_MIN_MM, PUPIL_MAX_MM)
    }

    fn cap(&self) -> usize {
        self.times.len()
    }

    fn idx(&self, k: usize) -> usize {
        (self.head + k) % self.cap()
    }

    fn push(&mut self, t: f64, target: f64) {
        if self.len > 0 {
            let last = self.idx(self.len - 1);
            if t - self.times[last] < self.spacing_secs {
                self.targets[last] = target;
                return;
            }
        }
        if self.len == self.cap() {
            // Cannot happen while entries older than one latency are
            // dropped each step and entries are `spacing` apart; keep the
            // newest history if it ever does.
            self.head = (self.head + 1) % self.cap();
            self.len -= 1;
        }
        let i = self.idx(self.len);
        self.times[i] = t;
        self.targets[i] = target;
        self.len += 1;
    }

    fn relax(&mut self, target: f64, dt: f64) {
        if dt <= 0.0 {
            return;
        }
        let d = &self.params.dynamics;
        let tau = if target < self.pupil_formula_mm {
            d.constriction_tau_secs
        } else {
            d.redilation_tau_secs
        };
        // Exact first-order step response over dt (exp(−∞) = 0: any gap).
        let k = (-dt / tau).exp();
        self.pupil_formula_mm = target + (self.pupil_formula_mm - target) * k;
    }

    /// Advances the model to `t_secs` with the light `input` (which holds
    /// from now until the next step) and returns the predicted diameter,
    /// mm, in [`PUPIL_MIN_MM`, `PUPIL_MAX_MM`]. See the module doc for
    /// non-finite and backward times.
    pub fn step(&mut self, t_secs: f64, input: &EyeLight) -> f64 {
        if !t_secs.is_finite() {
            return self.last_output_mm;
        }
        let target = static_target_mm(input, &self.params.adaptation);
        let latency = self.params.dynamics.latency_secs;
        match self.last_t_secs {
            None => {
                // Start adapted to the first light.
                self.len = 0;
                self.head = 0;
                self.pupil_formula_mm = target;
                self.push(t_secs - latency, target);
            }
            Some(prev) if t_secs < prev => {
                // Re-base: keep the pupil and what it was heading for.
                let heading = self.delayed_target_at(prev);
                self.len = 0;
                self.head = 0;
                self.push(t_secs - latency, heading);
                self.push(t_secs, target);
            }
            Some(prev) => {
                self.advance(prev, t_secs);
                self.push(t_secs, target);
            }
        }
        self.last_t_secs = Some(t_secs);
        self.last_output_mm = Self::clamp_out(self.params.range.apply(self.pupil_formula_mm));
        self.last_output_mm
    }

    /// The target in effect (delayed) at time `t`: the newest entry that
    /// took effect at or before `t − latency`.
    fn delayed_target_at(&self, t: f64) -> f64 {
        let latency = self.params.dynamics.latency_secs;
        let mut best = self.pupil_formula_mm;
        for k in 0..self.len {
            let i = self.idx(k);
            if self.times[i] + latency <= t {
                best = self.targets[i];
            } else {
                break;
            }
        }
        best
    }

    /// Integrates from `from` to `to` (≥ `from`), switching the delayed
    /// target at each entry's time + latency, dropping spent entries.
    fn advance(&mut self, from: f64, to: f64) {
        let latency = self.params.dynamics.latency_secs;
        let mut cursor = from;
        while self.len > 0 {
            let front = self.idx(0);
            let current = self.targets[front];
            // The front entry took effect at its time + latency (at or
            // before `from`, except just after a start or re-base).
            let start = (self.times[front] + latency).max(cursor);
            let switch = if self.len > 1 {
                self.times[self.idx(1)] + latency
            } else {
                f64::INFINITY
            };
            if switch <= to {
                if switch > start {
                    self.relax(current, switch - start);
                }
                cursor = cursor.max(switch);
                self.head = (self.head + 1) % self.cap();
                self.len -= 1;
            } else {
                if to > start {
                    self.relax(current, to - start);
                }
                break;
            }
        }
    }

    /// The last prediction, mm.
    pub fn last_mm(&self) -> f64 {
        self.last_output_mm
    }
}

/// One row of a recording: time, measured pupil (NaN for a blink or a
/// dropout) and the light of that frame.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct PupilRow {
    pub t_secs: f64,
    pub pupil_mm: f64,
    pub light: EyeLight,
}

/// `measured − predicted`, mm; NaN when the measurement is missing (NaN,
/// ±∞ or ≤ 0).
#[inline]
pub fn residual_mm(measured_mm: f64, predicted_mm: f64) -> f64 {
    if measured_mm.is_finite() && measured_mm > 0.0 {
        measured_mm - predicted_mm
    } else {
        f64::NAN
    }
}

/// Runs `model` over `rows` and returns each row's residual, mm (NaN where
/// the pupil is missing). Every row steps the model, so the light during
/// blinks still counts.
pub fn residuals_mm(model: &mut PupilLightResponse, rows: &[PupilRow]) -> Vec<f64> {
    rows.iter()
        .map(|r| residual_mm(r.pupil_mm, model.step(r.t_secs, &r.light)))
        .collect()
}

/// Runs `model` over `rows` and returns each row's prediction, mm.
pub fn predictions_mm(model: &mut PupilLightResponse, rows: &[PupilRow]) -> Vec<f64> {
    rows.iter()
        .map(|r| model.step(r.t_secs, &r.light))
        .collect()
}

/// What [`fit_observer`] fits.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct FitOptions {
    /// Also fit latency and both time constants (else only the range).
    pub fit_dynamics: bool,
    /// Nelder–Mead iterations at most.
    pub max_iterations: usize,
    /// Fewest valid rows accepted.
    pub min_samples: usize,
}

impl Default for FitOptions {
    fn default() -> Self {
        Self {
            fit_dynamics: true,
            max_iterations: 400,
            min_samples: 20,
        }
    }
}

/// The result of [`fit_observer`].
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct FitResult {
    /// The fitted parameters (adaptation as given).
    pub params: ResponseParams,
    /// Coefficient of determination over the rows used.
    pub r_squared: f64,
    /// Root-mean-square residual, mm.
    pub rms_mm: f64,
    /// Rows with a valid pupil, used in the fit.
    pub samples_used: usize,
}

/// Bounds of the fitted dynamics, s.
const FIT_LATENCY_RANGE: (f64, f64) = (0.05, 1.0);
const FIT_TAU_RANGE: (f64, f64) = (0.02, 60.0);

fn valid_pupil(p: f64) -> bool {
    p.is_finite() && p > 0.0
}

/// Least-squares fit of the observer's range (scale, offset) and, with
/// `options.fit_dynamics`, of the latency and both time constants, on a
/// baseline block `rows` (times increasing; rows whose pupil is NaN, ±∞ or
/// ≤ 0 are skipped in the cost but still drive the model).
///
/// For given dynamics the model's formula-domain output is affine in
/// (scale, offset), so those two come in closed form (linear least
/// squares); the dynamics are searched by Nelder–Mead on their logarithms,
/// started from `initial.dynamics`. The fitted range is not clamped to the
/// output bounds during the fit.
pub fn fit_observer(
    rows: &[PupilRow],
    initial: &ResponseParams,
    options: &FitOptions,
) -> Result<FitResult, ResponseError> {
    initial.validate()?;
    if let Some((row, r)) = rows.iter().enumerate().find(|(_, r)| !r.t_secs.is_finite()) {
        return Err(ResponseError::TimeNotFinite {
            row,
            t_secs: r.t_secs,
        });
    }
    for (row, pair) in rows.windows(2).enumerate() {
        // Times are finite here: NaN ones were refused above.
        if pair[1].t_secs <= pair[0].t_secs {
            return Err(ResponseError::TimeNotIncreasing {
                row: row + 1,
                t_secs: pair[1].t_secs,
                previous: pair[0].t_secs,
            });
        }
    }
    let used = rows.iter().filter(|r| valid_pupil(r.pupil_mm)).count();
    let required = options.min_samples.max(3);
    if used < required {
        return Err(ResponseError::TooFewSamples {
            used,
            rows: rows.len(),
            required,
        });
    }
    let mut formula = Vec::with_capacity(rows.len());
    let mut eval = |dynamics: Dynamics| -> Result<(ObserverRange, f64), ResponseError> {
        let params = ResponseParams {
            adaptation: initial.adaptation,
            dynamics,
            range: ObserverRange::IDENTITY,
        };
        let mut model = PupilLightResponse::new(params)?;
        formula.clear();
        for r in rows {
            model.step(r.t_secs, &r.light);
            formula.push(model.pupil_formula_mm);
        }
        linear_fit(rows, &formula)
    };

    let (mut best_dyn, (mut best_range, mut best_sse)) = {
        let d = initial.dynamics;
        (d, eval(d)?)
    };
    if options.fit_dynamics {
        let to_x = |d: &Dynamics| {
            [
                d.latency_secs.ln(),
                d.constriction_tau_secs.ln(),
                d.redilation_tau_secs.ln(),
            ]
        };
        let from_x = |x: &[f64; 3]| Dynamics {
            latency_secs: x[0].exp().clamp(FIT_LATENCY_RANGE.0, FIT_LATENCY_RANGE.1),
            constriction_tau_secs: x[1].exp().clamp(FIT_TAU_RANGE.0, FIT_TAU_RANGE.1),
            redilation_tau_secs: x[2].exp().clamp(FIT_TAU_RANGE.0, FIT_TAU_RANGE.1),
        };
        let mut cost = |x: &[f64; 3]| -> f64 {
            match eval(from_x(x)) {
                Ok((range, sse)) if range.scale > 0.0 => sse,
                _ => f64::INFINITY,
            }
        };
        let x0 = to_x(&from_x(&to_x(&initial.dynamics)));
        let x = nelder_mead(&mut cost, x0, 0.3, options.max_iterations);
        let d = from_x(&x);
        let (range, sse) = eval(d)?;
        if sse < best_sse {
            best_dyn = d;
            best_range = range;
            best_sse = sse;
        }
    }
    if !best_range.scale.is_finite() || best_range.scale <= 0.0 {
        return Err(ResponseError::NonPositiveScale {
            scale: best_range.scale,
        });
    }
    let mean = rows
        .iter()
        .filter(|r| valid_pupil(r.pupil_mm))
        .map(|r| r.pupil_mm)
        .sum::<f64>()
        / used as f64;
    let sst: f64 = rows
        .iter()
        .filter(|r| valid_pupil(r.pupil_mm))
        .map(|r| (r.pupil_mm - mean).powi(2))
        .sum();
    let r_squared = if sst > 0.0 { 1.0 - best_sse / sst } else { 0.0 };
    Ok(FitResult {
        params: ResponseParams {
            adaptation: initial.adaptation,
            dynamics: best_dyn,
            range: best_range,
        },
        r_squared,
        rms_mm: (best_sse / used as f64).sqrt(),
        samples_used: used,
    })
}

/// Closed-form least squares `pupil ≈ scale · formula + offset` over the
/// rows with a valid pupil; returns the range and the sum of squares.
fn linear_fit(rows: &[PupilRow], formula: &[f64]) -> Result<(ObserverRange, f64), ResponseError> {
    let (mut n, mut sx, mut sy) = (0.0, 0.0, 0.0);
    let (mut lo, mut hi) = (f64::INFINITY, f64::NEG_INFINITY);
    for (r, &x) in rows.iter().zip(formula) {
        if valid_pupil(r.pupil_mm) {
            n += 1.0;
            sx += x;
            sy += r.pupil_mm;
            lo = lo.min(x);
            hi = hi.max(x);
        }
    }
    let (mx, my) = (sx / n, sy / n);
    let (mut sxx, mut sxy) = (0.0, 0.0);
    for (r, &x) in rows.iter().zip(formula) {
        if valid_pupil(r.pupil_mm) {
            sxx += (x - mx) * (x - mx);
            sxy += (x - mx) * (r.pupil_mm - my);
        }
    }
    let spread = hi - lo;
    if spread.is_nan() || spread <= 1e-6 || sxx.is_nan() || sxx <= 0.0 {
        return Err(ResponseError::NoLightVariation {
            spread_mm: spread.max(0.0),
        });
    }
    let scale = sxy / sxx;
    let offset_mm = my - scale * mx;
    let mut sse = 0.0;
    for (r, &x) in rows.iter().zip(formula) {
        if valid_pupil(r.pupil_mm) {
            sse += (r.pupil_mm - (scale * x + offset_mm)).powi(2);
        }
    }
    Ok((ObserverRange { scale, offset_mm }, sse))
}

/// Minimises `f` over ℝ³ by Nelder–Mead (standard coefficients 1, 2, ½, ½)
/// from `x0` with an initial simplex of side `step`; stops after
/// `max_iter` iterations or when the simplex's values agree to 1e-12
/// (relative).
fn nelder_mead<F: FnMut(&[f64; 3]) -> f64>(
    f: &mut F,
    x0: [f64; 3],
    step: f64,
    max_iter: usize,
) -> [f64; 3] {
    const N: usize = 3;
    let mut pts = [x0; N + 1];
    for (i, p) in pts.iter_mut().enumerate().skip(1) {
        p[i - 1] += step;
    }
    let mut vals = [0.0; N + 1];
    for (v, p) in vals.iter_mut().zip(&pts) {
        *v = f(p);
    }
    for _ in 0..max_iter {
        // Order the simplex, best first.
        let mut order = [0, 1, 2, 3];
        order.sort_by(|&a, &b| vals[a].total_cmp(&vals[b]));
        let pts_s = order.map(|i| pts[i]);
        let vals_s = order.map(|i| vals[i]);
        pts = pts_s;
        vals = vals_s;
        let (best, worst) = (vals[0], vals[N]);
        if worst.is_finite() && (worst - best).abs() <= 1e-12 * best.abs().max(1e-30) {
            break;
        }
        let mut centroid = [0.0; N];
        for p in &pts[..N] {
            for k in 0..N {
                centroid[k] += p[k] / N as f64;
            }
        }
        let along = |t: f64| {
            let mut x = [0.0; N];
            for k in 0..N {
                x[k] = centroid[k] + t * (pts[N][k] - centroid[k]);
            }
            x
        };
        let xr = along(-1.0);
        let fr = f(&xr);
        if fr < vals[0] {
            let xe = along(-2.0);
            let fe = f(&xe);
            if fe < fr {
                pts[N] = xe;
                vals[N] = fe;
            } else {
                pts[N] = xr;
                vals[N] = fr;
            }
        } else if fr < vals[N - 1] {
            pts[N] = xr;
            vals[N] = fr;
        } else {
            let (xc, fc) = if fr < vals[N] {
                let x = along(-0.5);
                (x, f(&x))
            } else {
                let x = along(0.5);
                (x, f(&x))
            };
            if fc < vals[N].min(fr) {
                pts[N] = xc;
                vals[N] = fc;
            } else {
                // Shrink towards the best.
                let (best, rest) = pts.split_at_mut(1);
                for (p, v) in rest.iter_mut().zip(vals.iter_mut().skip(1)) {
                    for (pk, bk) in p.iter_mut().zip(best[0].iter()) {
                        *pk = bk + 0.5 * (*pk - bk);
                    }
                    *v = f(p);
                }
            }
        }
    }
    let mut best = 0;
    for i in 1..=N {
        if vals[i] < vals[best] {
            best = i;
        }
    }
    pts[best]
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn nelder_mead_finds_a_quadratic_minimum() {
        let mut f =
            |x: &[f64; 3]| (x[0] - 1.0).powi(2) + 2.0 * (x[1] + 0.5).powi(2) + (x[2] - 3.0).powi(2);
        let x = nelder_mead(&mut f, [0.0, 0.0, 0.0], 0.5, 2000);
        assert!(
            (x[0] - 1.0).abs() < 1e-4 && (x[1] + 0.5).abs() < 1e-4 && (x[2] - 3.0).abs() < 1e-4,
            "{x:?}"
        );
    }

    #[test]
    fn the_delay_line_holds_one_latency_at_any_input_rate() {
        let mut m = PupilLightResponse::new(ResponseParams::default()).unwrap();
        let cap = m.cap();
        let dark = EyeLight::both(EyeInput::uniform(0.01, 2827.0));
        for k in 0..100_000 {
            m.step(f64::from(k) * 1e-5, &dark);
            assert!(m.len <= cap);
        }
        // No reallocation ever: same capacity.
        assert_eq!(m.times.len(), cap);
    }

    #[test]
    fn fit_errors_name_the_row_and_the_count() {
        let light = EyeLight::both(EyeInput::uniform(1.0, 100.0));
        let row = |t_secs: f64, pupil_mm: f64| PupilRow {
            t_secs,
            pupil_mm,
            light,
        };
        let back = [row(0.0, 4.0), row(1.0, 4.0), row(0.5, 4.0)];
        let e =
            fit_observer(&back, &ResponseParams::default(), &FitOptions::default()).unwrap_err();
        assert!(e.to_string().contains("row 2 has t_secs = 0.5"), "{e}");
        let blinks: Vec<PupilRow> = (0..30)
            .map(|k| row(f64::from(k) * 0.01, if k < 25 { f64::NAN } else { 4.0 }))
            .collect();
        let e =
            fit_observer(&blinks, &ResponseParams::default(), &FitOptions::default()).unwrap_err();
        assert!(e.to_string().contains("only 5 of 30 rows"), "{e}");
        let flat: Vec<PupilRow> = (0..30).map(|k| row(f64::from(k) * 0.01, 4.0)).collect();
        let e =
            fit_observer(&flat, &ResponseParams::default(), &FitOptions::default()).unwrap_err();
        assert!(matches!(e, ResponseError::NoLightVariation { .. }), "{e}");
    }

    #[test]
    fn a_calibration_maps_black_and_white_onto_the_profile() {
        let cal = EyeCalibration {
            kind: crate::profile::MapKind::Aperture,
            raw_unit: crate::PupilUnit::Px,
            raw_black: 40.0,
            raw_white: 15.0,
            mm_min: 2.5,
            mm_max: 7.0,
        };
        let r = ObserverRange::from_calibration(&cal, 0.1, 200.0, 2827.0, 35.0).unwrap();
        let a = Adaptation {
            gaze_weight: 0.5,
            age_years: 35.0,
        };
        let black = static_target_mm(&EyeLight::both(EyeInput::uniform(0.1, 2827.0)), &a);
        let white = static_target_mm(&EyeLight::both(EyeInput::uniform(200.0, 2827.0)), &a);
        assert!((r.apply(black) - 7.0).abs() < 1e-9);
        assert!((r.apply(white) - 2.5).abs() < 1e-9);
        let e = ObserverRange::from_calibration(&cal, 100.0, 100.0, 2827.0, 35.0).unwrap_err();
        assert!(e.to_string().contains("white_luminance_cd_m2"), "{e}");
    }
}
