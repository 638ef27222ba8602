//! Adaptation luminance pooling: the luminance (cd/m²) the eye adapts to,
//! computed from a luminance plane and the gaze.
//!
//! Every model is a normalised weighted **arithmetic** mean of the pixel
//! luminances, `L̄ = Σ w_i·Y_i / Σ w_i`. 001 §4.1 weights the *linear* RGB
//! colours and averages them before taking Y (eq 1), and 000 §3.2 uses the
//! arithmetic mean ("the total luminous intensity hitting the camera"), so
//! no model averages in log. Negative, NaN and infinite pixels count as 0
//! (the shared EXR files hold negative pixels from lossy compression).
//!
//! The models (`d` is the distance from the gaze):
//!
//! * [`PoolingModel::Gaussian`] (default, 001 §4.1): `w = exp(−d²/2σ²)`,
//!   σ in visual degrees. The seed gives no σ; 003 §2.3 states that the
//!   eye adapts mainly to the 2–4° around the gaze, so the default is 2°.
//!   The seed averages the Gaussian-weighted colours without dividing by
//!   the total weight, which would make a uniform scene adapt below its own
//!   luminance; here the mean is normalised. Each pixel's weight is the
//!   Gaussian integrated over the pixel (a product of erf differences), so
//!   the result is right for any pixel size, down to σ smaller than a
//!   pixel of a downsampled plane.
//! * [`PoolingModel::CentreWeight`] (000 eq 5–6): `w(d) = 1 − 4d²` for
//!   `d < 0.5`, else 0, with `d = ‖(2(x − c_x)/W, 2(y − c_y)/H)‖` relative to
//!   the plane's half width and half height. 000 centres it on the screen
//!   centre (no eye tracker); here it follows the gaze unless
//!   `follow_gaze` is false.
//! * [`PoolingModel::Eccentricity`] (003 eq 1): the cone cutoff frequency
//!   `f_c(d) = 43.1·E2/(E2 + d)` (d in degrees) as weight; the constant
//!   43.1 cancels in the normalised mean. 003 does not print E2's value;
//!   the default 3.118° is Peli et al.'s (003 ref. 14) as used in Mantiuk &
//!   Janus (003 ref. 9).
//! * [`PoolingModel::GazeWindow`] (004 §3.1): the plain mean over a square
//!   window around the gaze. 004 uses 40×40 pixels of its image; since the
//!   plane given here may be downsampled, the window is given in degrees:
//!   the default is 40 px at the 13.85 px/deg of the HTC Vive Pro (001
//!   §4.3.2), 2.89°, inside the 2–4° adaptation area of 003 §2.3. Pixels
//!   are weighted by their overlap with the window, so a window smaller
//!   than a pixel still works.
//! * [`PoolingModel::PanoramaMean`] (000 §3.2): whole-image mean with each
//!   row weighted by its solid angle, `sin(π·y/h)`, evaluated at the row
//!   centre `y + ½`. Ignores the gaze; expects the plane to be a full
//!   equirectangular panorama.
//!
//! Coordinates: `gaze_px` is continuous, with pixel `(i, j)` covering
//! `[i, i+1) × [j, j+1)` (its centre at `i + ½`). How far a pixel is from
//! the gaze, in degrees, depends on the plane's [`PlaneAngles`]:
//!
//! * [`PlaneAngles::Uniform`] ([`PoolingModel::pool`]): the planar pixel
//!   distance times `deg_per_px` (no wrap-around, no projection).
//! * [`PlaneAngles::Rectilinear`] ([`PoolingModel::pool_in`]): the plane is
//!   a pinhole view whose edges lie at the given tangents (a display view:
//!   its pixels subtend less angle away from the axis, by cos²θ along the
//!   radius at θ off axis). Each pixel edge is mapped to its angle from the
//!   gaze along the view's azimuth `a = atan(s_x)` and elevation
//!   `b = atan(s_y / √(1 + s_gx²))` (`s` the tangent coordinates, `s_g` the
//!   gaze's): `Δx° = cos b_g · (a − a_g)`, `Δy° = b − b_g`, the local
//!   metric of the sphere (`ds² = cos²b·da² + db²`) at the gaze. The
//!   Gaussian's weights stay separable (erf differences between mapped
//!   edges), so they still integrate over pixels bigger than σ. Measured
//!   on a night panorama seen through a 90° view (the `rectilinear_*`
//!   tests): within 2 % of the exact angular Gaussian over the sphere
//!   where the planar distance is off by up to 2× in the dark next to a
//!   lamp (the Gaussian's far tail weighs a lamp 10⁴× brighter than the
//!   dark around it, and a 4 % error in distance at 7° changes that weight
//!   by 40 %).
//!
//! The centre-weight (000) and panorama-mean models are defined on the
//! plane itself and ignore the geometry. Pooling never allocates.
//!
//! A plane with "no data" in it (pixels outside a scene's field) pools
//! with [`PoolingModel::pool_valid_in`]: each pixel carries the share of
//! its area with data, and every model's mean becomes the weighted
//! luminance over the weighted area with data, `Σ w·L / Σ w·a`.

use std::ops::Range;

use serde::{Deserialize, Serialize};

use crate::VisionError;

/// Luminance pooling model; see the module docs for the formulas.
#[derive(Clone, Copy, Debug, PartialEq, Serialize, Deserialize)]
#[serde(tag = "model", rename_all = "snake_case", deny_unknown_fields)]
pub enum PoolingModel {
    /// Gaussian centred on the gaze (001 §4.1).
    Gaussian {
        /// Standard deviation, visual degrees.
        sigma_deg: f64,
    },
    /// `w(d) = 1 − 4d²` (000 eq 5–6).
    CentreWeight {
        /// Centre the weight on the gaze (true) or on the plane centre as
        /// in 000 (false).
        follow_gaze: bool,
    },
    /// Cone cutoff frequency as weight (003 eq 1).
    Eccentricity {
        /// Eccentricity at which the cutoff frequency halves, degrees.
        e2_deg: f64,
    },
    /// Plain mean over a square window at the gaze (004 §3.1).
    GazeWindow {
        /// Side of the square window, visual degrees.
        size_deg: f64,
    },
    /// Solid-angle weighted mean of a whole equirectangular panorama
    /// (000 §3.2).
    PanoramaMean,
}

/// Default Gaussian σ, degrees: 003 §2.3, the eye adapts mainly to 2–4°
/// around the gaze (001 §4.1 gives no value).
pub const DEFAULT_GAUSSIAN_SIGMA_DEG: f64 = 2.0;

/// Default E2 of the eccentricity mask, degrees (Peli et al. via 003 eq 1).
pub const DEFAULT_E2_DEG: f64 = 3.118;

/// Default gaze window, degrees: 40 px (004 §3.1) at 13.85 px/deg (001
/// §4.3.2, HTC Vive Pro).
pub const DEFAULT_GAZE_WINDOW_DEG: f64 = 40.0 / 13.85;

/// How a plane's pixel coordinates map to visual angles (see the module
/// docs).
#[derive(Clone, Copy, Debug, PartialEq)]
pub enum PlaneAngles {
    /// Every pixel `deg_per_px` wide: the planar approximation.
    Uniform {
        /// Angular size of a pixel, degrees.
        deg_per_px: f64,
    },
    /// A rectilinear (pinhole) view: plane x = 0 and x = `extent_px[0]` lie
    /// at the tangents `tan_lrud[0]` (left) and `tan_lrud[1]` (right),
    /// y = 0 and y = `extent_px[1]` at `tan_lrud[2]` (up) and `tan_lrud[3]`
    /// (down). `extent_px` is the view's size in plane pixels (fractional
    /// for a block plane whose last block is partial).
    Rectilinear {
        /// Tangents of the left, right, up and down edges (left and down
        /// negative for a view around its axis).
        tan_lrud: [f64; 4],
        /// The view's width and height in plane pixels.
        extent_px: [f64; 2],
    },
}

impl PlaneAngles {
    /// A symmetric rectilinear view `hfov_deg` wide over a `width ×
    /// height` plane with square pixels.
    pub fn symmetric(hfov_deg: f64, width: usize, height: usize) -> Self {
        let tx = (hfov_deg.to_radians() * 0.5).tan();
        let ty = tx * height as f64 / width.max(1) as f64;
        Self::Rectilinear {
            tan_lrud: [-tx, tx, ty, -ty],
            extent_px: [width as f64, height as f64],
        }
    }

    /// The same geometry on the plane of `ds × ds` pixel blocks.
    pub fn downsampled(self, ds: usize) -> Self {
        let ds = ds.max(1) as f64;
        match self {
            Self::Uniform { deg_per_px } => Self::Uniform {
                deg_per_px: deg_per_px * ds,
            },
            Self::Rectilinear {
                tan_lrud,
                extent_px,
            } => Self::Rectilinear {
                tan_lrud,
                extent_px: [extent_px[0] / ds, extent_px[1] / ds],
            },
        }
    }

    /// Checks the geometry: a finite positive pixel size, or finite
    /// tangents with left < right and down < up and a positive extent.
    pub fn validate(&self) -> Result<(), VisionError> {
        match *self {
            Self::Uniform { deg_per_px } => {
                if !(deg_per_px.is_finite() && deg_per_px > 0.0) {
                    return Err(VisionError::invalid(
                        "deg_per_px",
                        deg_per_px,
                        "a finite number of degrees > 0",
                    ));
                }
            }
            Self::Rectilinear {
                tan_lrud: [l, r, u, d],
                extent_px,
            } => {
                let finite = [l, r, u, d, extent_px[0], extent_px[1]]
                    .iter()
                    .all(|v| v.is_finite());
                if !(finite && l < r && d < u && extent_px[0] > 0.0 && extent_px[1] > 0.0) {
                    return Err(VisionError::invalid(
                        "view frustum",
                        format!("tangents {:?} over {:?} px", [l, r, u, d], extent_px),
                        "finite tangents, left < right, down < up, a positive size",
                    ));
                }
            }
        }
        Ok(())
    }
}

/// Angles from the gaze along the plane's axes, degrees, for one gaze.
#[derive(Clone, Copy, Debug)]
pub(crate) enum Axes {
    Uniform {
        gaze: [f64; 2],
        deg_per_px: f64,
    },
    Rectilinear {
        /// Tangent at x = 0 and per plane pixel (x), at y = 0 and per
        /// plane pixel downwards (y).
        tan_x0: f64,
        tan_per_px_x: f64,
        tan_y0: f64,
        tan_per_px_y: f64,
        /// The gaze's azimuth and elevation, radians; cos of its
        /// elevation; √(1 + s_gx²).
        azimuth_rad: f64,
        elevation_rad: f64,
        cos_elevation: f64,
        k: f64,
    },
}

/// A tangent's angle, kept inside ±(90° − 1e-6 rad) for the inverses.
const MAX_AXIS_RAD: f64 = std::f64::consts::FRAC_PI_2 - 1e-6;

impl Axes {
    /// The axes around `gaze` (sanitised plane coordinates). An invalid
    /// geometry falls back to 1° pixels (as `pool` always has).
    pub(crate) fn new(angles: PlaneAngles, gaze: [f64; 2]) -> Self {
        if angles.validate().is_err() {
            return Self::Uniform {
                gaze,
                deg_per_px: 1.0,
            };
        }
        match angles {
            PlaneAngles::Uniform { deg_per_px } => Self::Uniform { gaze, deg_per_px },
            PlaneAngles::Rectilinear {
                tan_lrud: [l, r, u, d],
                extent_px,
            } => {
                let tan_per_px_x = (r - l) / extent_px[0];
                let tan_per_px_y = (u - d) / extent_px[1];
                let sgx = l + gaze[0] * tan_per_px_x;
                let sgy = u - gaze[1] * tan_per_px_y;
                let k = (1.0 + sgx * sgx).sqrt();
                let elevation_rad = (sgy / k).atan();
                Self::Rectilinear {
                    tan_x0: l,
                    tan_per_px_x,
                    tan_y0: u,
                    tan_per_px_y,
                    azimuth_rad: sgx.atan(),
                    elevation_rad,
                    cos_elevation: elevation_rad.cos(),
                    k,
                }
            }
        }
    }

    /// Angle of plane column edge `x` from the gaze, degrees (increasing
    /// with `x`).
    #[inline]
    pub(crate) fn x_deg(&self, x: f64) -> f64 {
        match *self {
            Self::Uniform { gaze, deg_per_px } => (x - gaze[0]) * deg_per_px,
            Self::Rectilinear {
                tan_x0,
                tan_per_px_x,
                azimuth_rad,
                cos_elevation,
                ..
            } => (cos_elevation * ((tan_x0 + x * tan_per_px_x).atan() - azimuth_rad)).to_degrees(),
        }
    }

    /// Angle of plane row edge `y` from the gaze, degrees (increasing with
    /// `y`, i.e. downwards).
    #[inline]
    pub(crate) fn y_deg(&self, y: f64) -> f64 {
        match *self {
            Self::Uniform { gaze, deg_per_px } => (y - gaze[1]) * deg_per_px,
            Self::Rectilinear {
                tan_y0,
                tan_per_px_y,
                elevation_rad,
                k,
                ..
            } => (elevation_rad - ((tan_y0 - y * tan_per_px_y) / k).atan()).to_degrees(),
        }
    }

    /// The plane column whose edge is `deg` degrees from the gaze (the
    /// inverse of [`Self::x_deg`], clamped to the view's ±90°).
    pub(crate) fn x_of_deg(&self, deg: f64) -> f64 {
        match *self {
            Self::Uniform { gaze, deg_per_px } => gaze[0] + deg / deg_per_px,
            Self::Rectilinear {
                tan_x0,
                tan_per_px_x,
                azimuth_rad,
                cos_elevation,
                ..
            } => {
                let a = (azimuth_rad + deg.to_radians() / cos_elevation.max(1e-9))
                    .clamp(-MAX_AXIS_RAD, MAX_AXIS_RAD);
                (a.tan() - tan_x0) / tan_per_px_x
            }
        }
    }

    /// The plane row whose edge is `deg` degrees from the gaze (the inverse
    /// of [`Self::y_deg`], clamped to the view's ±90°).
    pub(crate) fn y_of_deg(&self, deg: f64) -> f64 {
        match *self {
            Self::Uniform { gaze, deg_per_px } => gaze[1] + deg / deg_per_px,
            Self::Rectilinear {
                tan_y0,
                tan_per_px_y,
                elevation_rad,
                k,
                ..
            } => {
                let b = (elevation_rad - deg.to_radians()).clamp(-MAX_AXIS_RAD, MAX_AXIS_RAD);
                (tan_y0 - k * b.tan()) / tan_per_px_y
            }
        }
    }

    /// The great-circle angle, degrees, between the gaze and the plane
    /// point `(x, y)` (a pixel centre); for a uniform plane the planar
    /// distance.
    #[inline]
    pub(crate) fn exact_deg(&self, x: f64, y: f64) -> f64 {
        match *self {
            Self::Uniform { gaze, deg_per_px } => {
                ((x - gaze[0]).powi(2) + (y - gaze[1]).powi(2)).sqrt() * deg_per_px
            }
            Self::Rectilinear {
                tan_x0,
                tan_per_px_x,
                tan_y0,
                tan_per_px_y,
                azimuth_rad,
                elevation_rad,
                ..
            } => {
                let (sx, sy) = (tan_x0 + x * tan_per_px_x, tan_y0 - y * tan_per_px_y);
                // The gaze's direction from its azimuth and elevation (view
                // space, −z forward).
                let (se, ce) = elevation_rad.sin_cos();
                let (sa, ca) = azimuth_rad.sin_cos();
                let g = [ce * sa, se, -ce * ca];
                let n = (sx * sx + sy * sy + 1.0).sqrt();
                let p = [sx / n, sy / n, -1.0 / n];
                let cross = [
                    g[1] * p[2] - g[2] * p[1],
                    g[2] * p[0] - g[0] * p[2],
                    g[0] * p[1] - g[1] * p[0],
                ];
                let sin = (cross[0] * cross[0] + cross[1] * cross[1] + cross[2] * cross[2]).sqrt();
                let cos = g[0] * p[0] + g[1] * p[1] + g[2] * p[2];
                sin.atan2(cos).to_degrees()
            }
        }
    }

    /// A pixel's solid angle over the product of its separable angular
    /// sides, at plane point `(x, y)` (1 at the gaze; 1 on a uniform
    /// plane): `(1 + s_x²)(k² + s_y²) / (cos b_g · k · (1 + s_x² + s_y²)^{3/2})`,
    /// the tangent plane's `dΩ = ds_x ds_y / (1 + s_x² + s_y²)^{3/2}` over
    /// `d(Δx) d(Δy)`.
    #[inline]
    pub(crate) fn solid_angle_ratio(&self, x: f64, y: f64) -> f64 {
        match *self {
            Self::Uniform { .. } => 1.0,
            Self::Rectilinear {
                tan_x0,
                tan_per_px_x,
                tan_y0,
                tan_per_px_y,
                cos_elevation,
                k,
                ..
            } => {
                let (sx, sy) = (tan_x0 + x * tan_per_px_x, tan_y0 - y * tan_per_px_y);
                let (sx2, sy2) = (sx * sx, sy * sy);
                (1.0 + sx2) * (k * k + sy2) / (cos_elevation * k * (1.0 + sx2 + sy2).powf(1.5))
            }
        }
    }

    /// The angular size of a plane pixel at the gaze, degrees (the larger
    /// of its two sides).
    pub(crate) fn deg_per_px_at_gaze(&self, gaze: [f64; 2]) -> f64 {
        let dx = (self.x_deg(gaze[0] + 0.5) - self.x_deg(gaze[0] - 0.5)).abs();
        let dy = (self.y_deg(gaze[1] + 0.5) - self.y_deg(gaze[1] - 0.5)).abs();
        let d = dx.max(dy);
        if d.is_finite() && d > 0.0 { d } else { 1.0 }
    }

    /// The plane columns `[lo, hi]` and rows within `deg` of the gaze along
    /// each axis: `[x_lo, x_hi, y_lo, y_hi]`.
    pub(crate) fn bounds(&self, deg: f64) -> [f64; 4] {
        [
            self.x_of_deg(-deg),
            self.x_of_deg(deg),
            self.y_of_deg(-deg),
            self.y_of_deg(deg),
        ]
    }
}

impl Default for PoolingModel {
    fn default() -> Self {
        Self::Gaussian {
            sigma_deg: DEFAULT_GAUSSIAN_SIGMA_DEG,
        }
    }
}

impl PoolingModel {
    /// Checks the parameters.
    pub fn validate(&self) -> Result<(), VisionError> {
        match *self {
            Self::Gaussian { sigma_deg } => {
                if !(sigma_deg.is_finite() && sigma_deg > 0.0 && sigma_deg <= 360.0) {
                    return Err(VisionError::invalid(
                        "pooling.sigma_deg",
                        sigma_deg,
                        "a finite number of degrees in (0, 360]",
                    ));
                }
            }
            Self::Eccentricity { e2_deg } => {
                if !(e2_deg.is_finite() && e2_deg > 0.0) {
                    return Err(VisionError::invalid(
                        "pooling.e2_deg",
                        e2_deg,
                        "a finite number of degrees > 0",
                    ));
                }
            }
            Self::GazeWindow { size_deg } => {
                if !(size_deg.is_finite() && size_deg > 0.0 && size_deg <= 360.0) {
                    return Err(VisionError::invalid(
                        "pooling.size_deg",
                        size_deg,
                        "a finite number of degrees in (0, 360]",
                    ));
                }
            }
            Self::CentreWeight { .. } | Self::PanoramaMean => {}
        }
        Ok(())
    }

    /// Adaptation luminance, cd/m², of the row-major luminance plane
    /// `luminance_cd_m2` (`width × height`), with the gaze at `gaze_px`
    /// (plane pixels, continuous) and pixels `deg_per_px` degrees wide
    /// ([`PlaneAngles::Uniform`]; [`Self::pool_in`] takes any geometry).
    ///
    /// Returns 0 for an empty plane or one whose length is not
    /// `width·height` (a programming error). A
    /// non-finite gaze is taken as the plane centre; a gaze outside the
    /// plane is used as is (the weights are then those of its tail), or the
    /// nearest pixel when no pixel gets any weight. Never allocates.
    pub fn pool(
        &self,
        luminance_cd_m2: &[f32],
        width: usize,
        height: usize,
        gaze_px: [f64; 2],
        deg_per_px: f64,
    ) -> f64 {
        self.pool_in(
            luminance_cd_m2,
            width,
            height,
            gaze_px,
            PlaneAngles::Uniform { deg_per_px },
        )
    }

    /// [`Self::pool`] on a plane whose pixels map to angles by `angles`
    /// (an invalid geometry is taken as 1° pixels). Never allocates.
    pub fn pool_in(
        &self,
        luminance_cd_m2: &[f32],
        width: usize,
        height: usize,
        gaze_px: [f64; 2],
        angles: PlaneAngles,
    ) -> f64 {
        self.pool_plane(luminance_cd_m2, None, width, height, gaze_px, angles)
            .unwrap_or(0.0)
    }

    /// [`Self::pool_in`] on a plane with "no data" in it: `valid[i]` is
    /// the share of pixel `i`'s area that has data (0..1; a block plane's
    /// valid pixel count over its pixels) and `luminance_cd_m2[i]` the
    /// luminance summed over that valid part, per pixel area (no-data
    /// parts add 0). The mean is the weighted luminance over the weighted
    /// valid area, `Σ w·L / Σ w·a`, so pixels without data are ignored, not
    /// read as black. `None` when no weighted pixel has data (and the
    /// nearest pixel has none either); with every `valid` 1 the same bits
    /// as [`Self::pool_in`]. A `valid` of the wrong length is read as all
    /// valid. Never allocates.
    pub fn pool_valid_in(
        &self,
        luminance_cd_m2: &[f32],
        valid: &[f32],
        width: usize,
        height: usize,
        gaze_px: [f64; 2],
        angles: PlaneAngles,
    ) -> Option<f64> {
        let valid = (valid.len() == luminance_cd_m2.len()).then_some(valid);
        self.pool_plane(luminance_cd_m2, valid, width, height, gaze_px, angles)
    }

    fn pool_plane(
        &self,
        luminance_cd_m2: &[f32],
        valid: Option<&[f32]>,
        width: usize,
        height: usize,
        gaze_px: [f64; 2],
        angles: PlaneAngles,
    ) -> Option<f64> {
        if width == 0 || height == 0 || luminance_cd_m2.len() != width * height {
            return Some(0.0);
        }
        let plane = Plane {
            lum: luminance_cd_m2,
            valid,
            width,
            height,
        };
        let gaze = sanitise(width, height, gaze_px);
        let axes = Axes::new(angles, gaze);
        let (sum, weight) = match *self {
            Self::Gaussian { sigma_deg } => plane.gaussian(&axes, gaze, sigma_deg),
            Self::CentreWeight { follow_gaze } => {
                let c = if follow_gaze {
                    gaze
                } else {
                    [width as f64 / 2.0, height as f64 / 2.0]
                };
                plane.centre_weight(c)
            }
            Self::Eccentricity { e2_deg } => plane.eccentricity(&axes, e2_deg),
            Self::GazeWindow { size_deg } => plane.window(axes.bounds(size_deg / 2.0)),
            Self::PanoramaMean => plane.panorama(),
        };
        if weight > 0.0 && weight.is_finite() && sum.is_finite() {
            Some(sum / weight)
        } else {
            plane.nearest(gaze)
        }
    }
}

/// The pixels of a plane that [`PoolingModel::pool`] reads: columns
/// `x`, rows `y` (half-open). A model that weights the whole plane reaches
/// all of it.
#[derive(Clone, Debug, PartialEq, Eq)]
pub struct PlaneRect {
    /// Columns.
    pub x: Range<usize>,
    /// Rows.
    pub y: Range<usize>,
}

impl PoolingModel {
    /// The pixels of a `width × height` plane that [`PoolingModel::pool`]
    /// reads for this gaze and pixel size (the same arguments): the
    /// Gaussian's ±(6σ + 1) and the gaze window's box, each with the
    /// nearest-pixel fallback; the whole plane for the models that weight
    /// every pixel. `pool`'s result depends on these pixels only, so a
    /// caller need not compute the rest of the plane (the CPU pipeline's
    /// pass A block-averages only these blocks). Empty for an empty plane.
    pub fn reach(
        &self,
        width: usize,
        height: usize,
        gaze_px: [f64; 2],
        deg_per_px: f64,
    ) -> PlaneRect {
        self.reach_in(width, height, gaze_px, PlaneAngles::Uniform { deg_per_px })
    }

    /// [`Self::reach`] for [`Self::pool_in`]: the same with any geometry.
    pub fn reach_in(
        &self,
        width: usize,
        height: usize,
        gaze_px: [f64; 2],
        angles: PlaneAngles,
    ) -> PlaneRect {
        if width == 0 || height == 0 {
            return PlaneRect { x: 0..0, y: 0..0 };
        }
        let gaze = sanitise(width, height, gaze_px);
        let axes = Axes::new(angles, gaze);
        let [lo_x, hi_x, lo_y, hi_y] = match *self {
            Self::Gaussian { sigma_deg } => axes.bounds(gaussian_reach_deg(&axes, gaze, sigma_deg)),
            // `Plane::window`'s box.
            Self::GazeWindow { size_deg } => axes.bounds(size_deg / 2.0),
            Self::CentreWeight { .. } | Self::Eccentricity { .. } | Self::PanoramaMean => {
                return PlaneRect {
                    x: 0..width,
                    y: 0..height,
                };
            }
        };
        let (x0, x1) = span(lo_x, hi_x, width);
        let (y0, y1) = span(lo_y, hi_y, height);
        // With the pixel `Plane::nearest` falls back to.
        let (nx, ny) = nearest_pixel(width, height, gaze);
        let join = |a: usize, b: usize, n: usize| {
            if a < b {
                a.min(n)..b.max(n + 1)
            } else {
                n..n + 1
            }
        };
        PlaneRect {
            x: join(x0, x1, nx),
            y: join(y0, y1, ny),
        }
    }

    /// The blocks `[x0, x1) × [y0, y1)` with weight for the Gaussian and
    /// gaze-window models (the GPU pass takes them from here, so both
    /// visit the same blocks), and the window's edges `[lo_x, hi_x, lo_y,
    /// hi_y]` in plane pixels; `None` for the models that weight every
    /// pixel.
    pub fn span_in(
        &self,
        width: usize,
        height: usize,
        gaze_px: [f64; 2],
        angles: PlaneAngles,
    ) -> Option<([usize; 4], [f64; 4])> {
        let gaze = sanitise(width, height, gaze_px);
        let axes = Axes::new(angles, gaze);
        let edges = match *self {
            Self::Gaussian { sigma_deg } => axes.bounds(gaussian_reach_deg(&axes, gaze, sigma_deg)),
            Self::GazeWindow { size_deg } => axes.bounds(size_deg / 2.0),
            _ => return None,
        };
        let (x0, x1) = span(edges[0], edges[1], width);
        let (y0, y1) = span(edges[2], edges[3], height);
        Some(([x0, x1, y0, y1], edges))
    }
}

/// The gaze's angles for a GPU twin: `[azimuth, elevation, cos elevation,
/// √(1 + s_gx²)]` (radians) and the tangent at x = 0, per plane pixel in
/// x, at y = 0 and per plane pixel in y, for a [`PlaneAngles::Rectilinear`]
/// plane; `None` for a uniform one.
pub fn rectilinear_terms(
    width: usize,
    height: usize,
    gaze_px: [f64; 2],
    angles: PlaneAngles,
) -> Option<([f64; 4], [f64; 4])> {
    match Axes::new(angles, sanitise(width, height, gaze_px)) {
        Axes::Uniform { .. } => None,
        Axes::Rectilinear {
            tan_x0,
            tan_per_px_x,
            tan_y0,
            tan_per_px_y,
            azimuth_rad,
            elevation_rad,
            cos_elevation,
            k,
        } => Some((
            [azimuth_rad, elevation_rad, cos_elevation, k],
            [tan_x0, tan_per_px_x, tan_y0, tan_per_px_y],
        )),
    }
}

/// How far from the gaze the Gaussian pool reaches, degrees: 6σ plus one
/// pixel at the gaze (its weights beyond are < 1e-9 of the peak).
fn gaussian_reach_deg(axes: &Axes, gaze: [f64; 2], sigma_deg: f64) -> f64 {
    6.0 * sigma_deg + axes.deg_per_px_at_gaze(gaze)
}

/// `pool`'s gaze (a non-finite coordinate → the plane centre).
fn sanitise(width: usize, height: usize, gaze_px: [f64; 2]) -> [f64; 2] {
    [
        if gaze_px[0].is_finite() {
            gaze_px[0]
        } else {
            width as f64 / 2.0
        },
        if gaze_px[1].is_finite() {
            gaze_px[1]
        } else {
            height as f64 / 2.0
        },
    ]
}

/// The pixel nearest to `gaze` in a non-empty plane.
fn nearest_pixel(width: usize, height: usize, gaze: [f64; 2]) -> (usize, usize) {
    let x = (gaze[0].floor().max(0.0) as usize).min(width - 1);
    let y = (gaze[1].floor().max(0.0) as usize).min(height - 1);
    (x, y)
}

/// A pixel value with negative / non-finite values as 0.
#[inline]
fn clean(v: f32) -> f64 {
    if v.is_finite() && v > 0.0 {
        f64::from(v)
    } else {
        0.0
    }
}

struct Plane<'a> {
    lum: &'a [f32],
    /// Each pixel's valid fraction (the share of its area with data, 0..1);
    /// `None`: every pixel is wholly valid.
    valid: Option<&'a [f32]>,
    width: usize,
    height: usize,
}

impl Plane<'_> {
    #[inline]
    fn row(&self, y: usize) -> &[f32] {
        &self.lum[y * self.width..(y + 1) * self.width]
    }

    /// Pixel `i`'s valid fraction (1 without a validity plane; a
    /// non-finite or negative fraction counts as 0, above 1 as 1).
    #[inline(always)]
    fn valid_at(&self, i: usize) -> f64 {
        match self.valid {
            None => 1.0,
            Some(v) => {
                let a = v[i];
                if a >= 1.0 {
                    1.0
                } else if a > 0.0 {
                    f64::from(a)
                } else {
                    0.0
                }
            }
        }
    }

    /// The nearest pixel's mean over its valid area; `None` when it has
    /// none.
    fn nearest(&self, gaze: [f64; 2]) -> Option<f64> {
        let (x, y) = nearest_pixel(self.width, self.height, gaze);
        let i = y * self.width + x;
        let a = self.valid_at(i);
        (a > 0.0).then(|| clean(self.lum[i]) / a)
    }

    /// Gaussian integrated over each pixel (erf differences between the
    /// pixel's edges mapped to angles by `axes`); only pixels within 6σ
    /// (plus one) are visited, their weights beyond that are < 1e-9 of the
    /// peak.
    fn gaussian(&self, axes: &Axes, gaze: [f64; 2], sigma_deg: f64) -> (f64, f64) {
        let [lo_x, hi_x, lo_y, hi_y] = axes.bounds(gaussian_reach_deg(axes, gaze, sigma_deg));
        let (x0, x1) = span(lo_x, hi_x, self.width);
        let (y0, y1) = span(lo_y, hi_y, self.height);
        let inv = 1.0 / (sigma_deg * std::f64::consts::SQRT_2);
        let curved = matches!(axes, Axes::Rectilinear { .. });
        let (mut sum, mut weight) = (0.0, 0.0);
        for y in y0..y1 {
            let wy =
                0.5 * (erf(axes.y_deg(y as f64 + 1.0) * inv) - erf(axes.y_deg(y as f64) * inv));
            if wy <= 0.0 {
                continue;
            }
            let dy_sep = axes.y_deg(y as f64 + 0.5);
            let row = self.row(y);
            let base = y * self.width;
            let mut row_sum = 0.0;
            let mut row_w = 0.0;
            let mut e_lo = erf(axes.x_deg(x0 as f64) * inv);
            for (x, &v) in row.iter().enumerate().take(x1).skip(x0) {
                let e_hi = erf(axes.x_deg(x as f64 + 1.0) * inv);
                let mut wx = 0.5 * (e_hi - e_lo);
                e_lo = e_hi;
                if curved {
                    // The separable axes are the sphere's metric at the
                    // gaze; away from it the exact angle and the pixel's
                    // solid angle differ, and the Gaussian's tail is steep:
                    // correct each pixel by the ratio of the Gaussian at its
                    // centre's exact angle to the one at its separable
                    // angle, times the ratio of the solid angles.
                    let (xc, yc) = (x as f64 + 0.5, y as f64 + 0.5);
                    let dx_sep = axes.x_deg(xc);
                    let d_exact = axes.exact_deg(xc, yc);
                    let excess = d_exact * d_exact - dx_sep * dx_sep - dy_sep * dy_sep;
                    wx *= (-excess * inv * inv).exp() * axes.solid_angle_ratio(xc, yc);
                }
                row_sum += wx * clean(v);
                row_w += wx * self.valid_at(base + x);
            }
            sum += wy * row_sum;
            weight += wy * row_w;
        }
        (sum, weight)
    }

    fn centre_weight(&self, c: [f64; 2]) -> (f64, f64) {
        let (hw, hh) = (self.width as f64 / 2.0, self.height as f64 / 2.0);
        let (mut sum, mut weight) = (0.0, 0.0);
        for y in 0..self.height {
            // 000 eq 6: distance relative to the half extent of the screen
            let dy = (y as f64 + 0.5 - c[1]) / hh;
            if dy.abs() >= 0.5 {
                continue;
            }
            for (x, &v) in self.row(y).iter().enumerate() {
                let dx = (x as f64 + 0.5 - c[0]) / hw;
                let d2 = dx * dx + dy * dy;
                // 000 eq 5: w(d) = 1 − 4d² for d < 0.5
                if d2 < 0.25 {
                    let w = 1.0 - 4.0 * d2;
                    sum += w * clean(v);
                    weight += w * self.valid_at(y * self.width + x);
                }
            }
        }
        (sum, weight)
    }

    fn eccentricity(&self, axes: &Axes, e2_deg: f64) -> (f64, f64) {
        let (mut sum, mut weight) = (0.0, 0.0);
        for y in 0..self.height {
            for (x, &v) in self.row(y).iter().enumerate() {
                let d_deg = axes.exact_deg(x as f64 + 0.5, y as f64 + 0.5);
                // 003 eq 1: f_c = 43.1·E2/(E2 + d); 43.1 cancels in the mean
                let w = e2_deg / (e2_deg + d_deg);
                sum += w * clean(v);
                weight += w * self.valid_at(y * self.width + x);
            }
        }
        (sum, weight)
    }

    /// The pixels' overlap with the box `[lo_x, hi_x] × [lo_y, hi_y]`
    /// (plane pixels).
    fn window(&self, [lo_x, hi_x, lo_y, hi_y]: [f64; 4]) -> (f64, f64) {
        let (x0, x1) = span(lo_x, hi_x, self.width);
        let (y0, y1) = span(lo_y, hi_y, self.height);
        let (mut sum, mut weight) = (0.0, 0.0);
        for y in y0..y1 {
            let wy = overlap(y, lo_y, hi_y);
            if wy <= 0.0 {
                continue;
            }
            let row = self.row(y);
            for (x, &v) in row.iter().enumerate().take(x1).skip(x0) {
                let w = wy * overlap(x, lo_x, hi_x);
                sum += w * clean(v);
                weight += w * self.valid_at(y * self.width + x);
            }
        }
        (sum, weight)
    }

    fn panorama(&self) -> (f64, f64) {
        let h = self.height as f64;
        let (mut sum, mut weight) = (0.0, 0.0);
        for y in 0..self.height {
            // 000 §3.2: equirectangular row weight sin(π·y/height), at the
            // row centre
            let w = (std::f64::consts::PI * (y as f64 + 0.5) / h).sin();
            let row_sum: f64 = self.row(y).iter().map(|&v| clean(v)).sum();
            let row_valid: f64 = match self.valid {
                None => self.width as f64,
                Some(_) => (0..self.width)
                    .map(|x| self.valid_at(y * self.width + x))
                    .sum(),
            };
            sum += w * row_sum;
            weight += w * row_valid;
        }
        (sum, weight)
    }
}

/// Index range of the pixels that intersect `[lo, hi]`, clipped to `0..n`.
#[inline]
pub fn span(lo: f64, hi: f64, n: usize) -> (usize, usize) {
    let a = lo.floor().max(0.0).min(n as f64) as usize;
    let b = (hi.ceil().max(0.0).min(n as f64)) as usize;
    (a, b.max(a))
}

/// Length of `[i, i+1] ∩ [lo, hi]`.
#[inline]
fn overlap(i: usize, lo: f64, hi: f64) -> f64 {
    let a = (i as f64).max(lo);
    let b = (i as f64 + 1.0).min(hi);
    (b - a).max(0.0)
}

/// The error function, W. J. Cody's rational approximations as in
/// Numerical Recipes' `erfc` (Chebyshev fit, fractional error < 1.2e-7).
/// Odd, saturates at ±1.
#[inline]
fn erf(x: f64) -> f64 {
    let z = x.abs();
    let t = 1.0 / (1.0 + 0.5 * z);
    let ans = t
        * (-z * z - 1.265_512_23
            + t * (1.000_023_68
                + t * (0.374_091_96
                    + t * (0.096_784_18
                        + t * (-0.186_288_06
                            + t * (0.278_868_07
                                + t * (-1.135_203_98
                                    + t * (1.488_515_87
                                        + t * (-0.822_152_23 + t * 0.170_872_77)))))))))
            .exp();
    if x >= 0.0 { 1.0 - ans } else { ans - 1.0 }
}

/// Real-data helpers shared by the tests of this crate's modules.
#[cfg(test)]
pub(crate) mod night {
    use std::path::PathBuf;

    /// A luminance plane loaded from a shared EXR panorama.
    pub struct Panorama {
        pub width: usize,
        pub height: usize,
        pub lum: Vec<f32>,
    }

    pub fn shared_hdr(name: &str) -> PathBuf {
        gazelight_test_support::data_path("hdr/blender-world").join(name)
    }

    /// Loads `name` from the shared panoramas as a luminance plane (001 eq 1).
    pub fn load(name: &str) -> Panorama {
        use exr::prelude::*;
        let path = shared_hdr(name);
        let image = read_first_rgba_layer_from_file(
            &path,
            |res, _| (res.width(), vec![0f32; res.width() * res.height()]),
            |(w, px): &mut (usize, Vec<f32>), pos, (r, g, b, _a): (f32, f32, f32, f32)| {
                px[pos.y() * *w + pos.x()] = crate::image::luminance([r, g, b]);
            },
        )
        .unwrap_or_else(|e| panic!("cannot read {}: {e}", path.display()));
        let size = image.layer_data.size;
        let (width, lum) = image.layer_data.channel_data.pixels;
        assert_eq!(width, size.width());
        Panorama {
            width,
            height: size.height(),
            lum,
        }
    }

    impl Panorama {
        pub fn deg_per_px(&self) -> f64 {
            360.0 / self.width as f64
        }

        /// Centre of the brightest 9×9 box-averaged spot below the horizon
        /// (a street lamp in night.exr), in continuous pixel coordinates.
        pub fn brightest_below_horizon(&self) -> [f64; 2] {
            let (w, h) = (self.width, self.height);
            let mut best = (f64::MIN, 0, 0);
            for y in (h / 2 + 4)..(h - 4) {
                for x in 4..(w - 4) {
                    let mut s = 0.0;
                    for yy in y - 4..=y + 4 {
                        for xx in x - 4..=x + 4 {
                            s += f64::from(self.lum[yy * w + xx].max(0.0));
                        }
                    }
                    if s > best.0 {
                        best = (s, x, y);
                    }
                }
            }
            [best.1 as f64 + 0.5, best.2 as f64 + 0.5]
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    /// The exact angular Gaussian over the sphere, evaluated here on the
    /// panorama itself (independently of the view and of `Axes`): each
    /// panorama pixel weighted by its solid angle (∝ cos latitude) and by
    /// `exp(−θ²/2σ²)` of its great-circle angle θ from `gaze_dir` (unit
    /// vector, the panorama's frame: −z at longitude 0, +y up), out to 12σ.
    fn sphere_gaussian(pano: &crate::RgbImage, gaze_dir: [f64; 3], sigma_deg: f64) -> f64 {
        use std::f64::consts::{PI, TAU};
        let (pw, ph) = (pano.width, pano.height);
        let sigma = sigma_deg.to_radians();
        let reach = 12.0 * sigma;
        let (mut s, mut w) = (0.0, 0.0);
        for y in 0..ph {
            let lat = (0.5 - (y as f64 + 0.5) / ph as f64) * PI;
            for x in 0..pw {
                let lon = ((x as f64 + 0.5) / pw as f64 - 0.5) * TAU;
                let d = [lat.cos() * lon.sin(), lat.sin(), -lat.cos() * lon.cos()];
                let c = d[0] * gaze_dir[0] + d[1] * gaze_dir[1] + d[2] * gaze_dir[2];
                let ang = c.clamp(-1.0, 1.0).acos();
                if ang > reach {
                    continue;
                }
                let wt = (-(ang * ang) / (2.0 * sigma * sigma)).exp() * lat.cos();
                s += wt
                    * f64::from(crate::image::luminance(
                        pano.pixels[y * pw + x].map(clean_f32),
                    ));
                w += wt;
            }
        }
        s / w
    }

    fn clean_f32(v: f32) -> f32 {
        if v.is_finite() && v > 0.0 { v } else { 0.0 }
    }

    /// A 90° view into the night panorama (yaw −78.4°, pitch −6°: street
    /// lamps and dark road and sky), 480×270 px, as a luminance plane, with
    /// its view.
    fn night_view() -> (crate::scene::PanoramaView, crate::RgbImage, Vec<f32>) {
        let scene = crate::scene::Scene::load(
            &night::shared_hdr("night.exr"),
            crate::scene::LuminanceScale::default(),
        )
        .expect("night.exr");
        let params = crate::scene::ViewParams {
            yaw_deg: -78.4,
            pitch_deg: -6.0,
            hfov_deg: 90.0,
            width: 480,
            height: 270,
        };
        let view = crate::scene::PanoramaView::new(params).expect("view");
        let mut img = crate::RgbImage::new(480, 270);
        view.render(&scene.image, &mut img);
        let lum = img
            .pixels
            .iter()
            .map(|p| crate::image::luminance(p.map(clean_f32)))
            .collect();
        (view, scene.image, lum)
    }

    /// Pooling through the view's projection agrees with the exact angular
    /// Gaussian over the sphere (computed from the panorama, not the view)
    /// within 3 % at gazes from the centre to 35° off axis, next to lamps
    /// and in the dark around them, on the full-resolution plane and on 2×2
    /// blocks; the planar distance (`deg_per_px` at the centre) is off by
    /// more than 25 % at some of them (measured up to 2×: in the dark next
    /// to a lamp the Gaussian's far tail carries the lamp).
    #[test]
    fn rectilinear_pooling_agrees_with_the_angular_gaussian_on_the_sphere() {
        let (view, pano, lum) = night_view();
        let (w, h) = (480usize, 270usize);
        let model = PoolingModel::default();
        let PoolingModel::Gaussian { sigma_deg } = model else {
            panic!("the default is the Gaussian")
        };
        let rect = PlaneAngles::Rectilinear {
            tan_lrud: view.frustum_tans(),
            extent_px: [w as f64, h as f64],
        };
        let uniform = PlaneAngles::Uniform {
            deg_per_px: view.params().deg_per_px(),
        };
        let gazes = [
            (0.5, 0.5),
            (0.608, 0.404),
            (0.689, 0.359),
            (0.682, 0.371),
            (0.167, 0.352),
            (0.703, 0.309),
            (0.626, 0.305),
            (0.228, 0.280),
            (0.85, 0.7),
        ];
        let mut worst_planar = 0.0f64;
        for (u, v) in gazes {
            let g = view.direction((u * w as f64) as f32, (v * h as f64) as f32);
            let truth = sphere_gaussian(
                &pano,
                [f64::from(g.x), f64::from(g.y), f64::from(g.z)],
                sigma_deg,
            );
            let gaze = [u * w as f64, v * h as f64];
            let full = model.pool_in(&lum, w, h, gaze, rect);
            // 2×2 blocks, as the pipeline's pass A makes them.
            let (sw, sh) = (w / 2, h / 2);
            let small: Vec<f32> = (0..sw * sh)
                .map(|i| {
                    let (bx, by) = (2 * (i % sw), 2 * (i / sw));
                    (lum[by * w + bx]
                        + lum[by * w + bx + 1]
                        + lum[(by + 1) * w + bx]
                        + lum[(by + 1) * w + bx + 1])
                        / 4.0
                })
                .collect();
            let blocks = model.pool_in(
                &small,
                sw,
                sh,
                [gaze[0] / 2.0, gaze[1] / 2.0],
                rect.downsampled(2),
            );
            let planar = model.pool_in(&lum, w, h, gaze, uniform);
            eprintln!(
                "gaze ({u}, {v}): sphere {truth:.4} cd/m², rectilinear {full:.4} (2×2 blocks {blocks:.4}), planar {planar:.4}"
            );
            for (what, got) in [("full", full), ("2×2 blocks", blocks)] {
                assert!(
                    (got / truth - 1.0).abs() < 0.03,
                    "gaze ({u}, {v}) {what}: {got} vs the sphere's {truth}"
                );
            }
            worst_planar = worst_planar.max((planar / truth - 1.0).abs());
        }
        assert!(
            worst_planar > 0.25,
            "the planar distance was off by only {worst_planar}"
        );
    }

    /// The mapped axes: a pixel edge's angle from the gaze equals the
    /// great-circle angle between their view directions along the axis
    /// through the gaze (checked with the view's own `direction`), and the
    /// inverses return the columns and rows.
    #[test]
    fn rectilinear_axes_measure_angles_through_the_view() {
        let (view, _, _) = night_view();
        let (w, h) = (480f64, 270f64);
        let rect = PlaneAngles::Rectilinear {
            tan_lrud: view.frustum_tans(),
            extent_px: [w, h],
        };
        for (gx, gy) in [(240.0, 135.0), (400.0, 60.0), (30.0, 250.0)] {
            let axes = Axes::new(rect, [gx, gy]);
            let g = view.direction(gx as f32, gy as f32);
            for (dx, dy) in [
                (-40.0, 0.0),
                (-5.0, 7.0),
                (3.0, -2.0),
                (25.0, 30.0),
                (0.5, 0.0),
            ] {
                let d = view.direction((gx + dx) as f32, (gy + dy) as f32);
                let truth = f64::from(g.dot(d).clamp(-1.0, 1.0)).acos().to_degrees();
                let got = axes.exact_deg(gx + dx, gy + dy);
                // The view's f32 directions: acos near 1 is good to ~0.02°.
                assert!((got - truth).abs() < 0.03, "({dx}, {dy}): {got} vs {truth}");
                let x = axes.x_deg(gx + dx);
                assert!((axes.x_of_deg(x) - (gx + dx)).abs() < 1e-6);
                if dy == 0.0 && gx == 240.0 {
                    // Along the horizon of a centred gaze the axis is exact.
                    assert!((x.abs() - truth).abs() < 0.03, "x {dx}: {x} vs {truth}");
                }
            }
            for dy in [-30.0, -4.0, 6.0, 20.0] {
                // Along the vertical through the gaze's azimuth: the great
                // circle of constant azimuth.
                let axes_y = axes.y_deg(gy + dy);
                assert!((axes.y_of_deg(axes_y) - (gy + dy)).abs() < 1e-6);
                assert!(axes_y.signum() == dy.signum(), "y {dy}: {axes_y}");
            }
        }
        // A uniform plane is the planar distance.
        let axes = Axes::new(PlaneAngles::Uniform { deg_per_px: 0.5 }, [10.0, 20.0]);
        assert_eq!(axes.x_deg(14.0), 2.0);
        assert_eq!(axes.y_deg(16.0), -2.0);
    }

    fn all_models() -> [PoolingModel; 6] {
        [
            PoolingModel::default(),
            PoolingModel::CentreWeight { follow_gaze: true },
            PoolingModel::CentreWeight { follow_gaze: false },
            PoolingModel::Eccentricity {
                e2_deg: DEFAULT_E2_DEG,
            },
            PoolingModel::GazeWindow {
                size_deg: DEFAULT_GAZE_WINDOW_DEG,
            },
            PoolingModel::PanoramaMean,
        ]
    }

    /// `pool` depends on the pixels of `reach` only: every pixel outside
    /// it replaced by garbage (NaN, ∞, huge, negative) gives the same bits,
    /// on a real night panorama, for every model, gazes inside, at the
    /// edges of, outside and off the plane (NaN), and pixel sizes down to
    /// σ below a pixel (and a bad one, taken as 1°). A rectangle one pixel
    /// short on any side changes the result (checked on the Gaussian, so
    /// the test can tell a reach that is too small).
    #[test]
    fn pool_reads_only_its_reach() {
        let pano = night::load("night.exr");
        // A 300×200 crop around the brightest lamp, block-averaged 2×.
        let spot = pano.brightest_below_horizon();
        let (w, h) = (150usize, 100usize);
        let (x0, y0) = (spot[0] as usize - 150, spot[1] as usize - 100);
        let mut plane = vec![0.0f32; w * h];
        for (i, v) in plane.iter_mut().enumerate() {
            let (x, y) = (x0 + 2 * (i % w), y0 + 2 * (i / w));
            *v = [(0, 0), (1, 0), (0, 1), (1, 1)]
                .iter()
                .map(|(dx, dy)| pano.lum[(y + dy) * pano.width + x + dx])
                .sum::<f32>()
                / 4.0;
        }
        let garbage = [f32::NAN, f32::INFINITY, 3.0e38, -5.0, 1.0e6];
        let mut checked_small = 0;
        for m in all_models().into_iter().chain([
            PoolingModel::Gaussian { sigma_deg: 0.3 },
            PoolingModel::Gaussian { sigma_deg: 40.0 },
            PoolingModel::GazeWindow { size_deg: 0.01 },
        ]) {
            for deg_per_px in [0.02, 0.16, 0.9, 7.0, f64::NAN, -1.0] {
                for gaze in [
                    [75.3, 50.8],
                    [0.2, 0.7],
                    [149.9, 99.5],
                    [-12.0, 40.0],
                    [400.0, -300.0],
                    [f64::NAN, 20.0],
                    [f64::NAN, f64::INFINITY],
                ] {
                    let want = m.pool(&plane, w, h, gaze, deg_per_px);
                    let r = m.reach(w, h, gaze, deg_per_px);
                    assert!(!r.x.is_empty() && r.x.end <= w && !r.y.is_empty() && r.y.end <= h);
                    let mut poisoned = plane.clone();
                    for (i, v) in poisoned.iter_mut().enumerate() {
                        if !(r.x.contains(&(i % w)) && r.y.contains(&(i / w))) {
                            *v = garbage[i % garbage.len()];
                        }
                    }
                    let got = m.pool(&poisoned, w, h, gaze, deg_per_px);
                    assert_eq!(
                        got.to_bits(),
                        want.to_bits(),
                        "{m:?} at {gaze:?}, {deg_per_px} deg/px, reach {r:?}: {got} vs {want}"
                    );
                    if r.x.len() * r.y.len() < w * h / 4 {
                        checked_small += 1;
                    }
                    // One pixel less on a side of a partial reach changes
                    // the Gaussian's result (its weights are never 0 there).
                    if matches!(m, PoolingModel::Gaussian { sigma_deg } if sigma_deg == 2.0)
                        && deg_per_px == 0.9
                        && gaze == [75.3, 50.8]
                    {
                        assert!(r.x.len() < w && r.y.len() < h, "{r:?}");
                        for side in 0..4 {
                            let mut p = plane.clone();
                            for (i, v) in p.iter_mut().enumerate() {
                                let (x, y) = (i % w, i / w);
                                let edge = match side {
                                    0 => x == r.x.start,
                                    1 => x == r.x.end - 1,
                                    2 => y == r.y.start,
                                    _ => y == r.y.end - 1,
                                };
                                if edge {
                                    *v = 1.0e6;
                                }
                            }
                            assert_ne!(m.pool(&p, w, h, gaze, deg_per_px), want, "side {side}");
                        }
                    }
                }
            }
        }
        assert!(
            checked_small > 50,
            "{checked_small} reaches below a quarter of the plane"
        );
    }

    #[test]
    fn erf_matches_known_values() {
        // Abramowitz & Stegun table 7.1
        for (x, e) in [
            (0.0, 0.0),
            (0.5, 0.520_499_878),
            (1.0, 0.842_700_793),
            (2.0, 0.995_322_265),
        ] {
            assert!((erf(x) - e).abs() < 2e-7, "erf({x}) = {}", erf(x));
            assert!((erf(-x) + e).abs() < 2e-7);
        }
    }

    #[test]
    fn uniform_plane_gives_its_value() {
        let (w, h) = (96, 48);
        let plane = vec![7.25f32; w * h];
        for m in all_models() {
            m.validate().unwrap();
            for deg_per_px in [0.05, 0.5, 3.75, 30.0] {
                for gaze in [[48.0, 24.0], [3.2, 40.9], [95.9, 0.1]] {
                    let v = m.pool(&plane, w, h, gaze, deg_per_px);
                    assert!(
                        (v - 7.25).abs() < 1e-9,
                        "{m:?} dpp {deg_per_px} gaze {gaze:?}: {v}"
                    );
                }
            }
        }
    }

    #[test]
    fn negative_and_nan_pixels_count_as_zero() {
        let (w, h) = (32, 32);
        let mut plane = vec![2.0f32; w * h];
        let mut zeroed = plane.clone();
        for i in (0..w * h).step_by(7) {
            plane[i] = if i % 2 == 0 { -5.0 } else { f32::NAN };
            zeroed[i] = 0.0;
        }
        for m in all_models() {
            let a = m.pool(&plane, w, h, [16.0, 16.0], 0.5);
            let b = m.pool(&zeroed, w, h, [16.0, 16.0], 0.5);
            assert!(a.is_finite() && (a - b).abs() < 1e-12, "{m:?}: {a} vs {b}");
            assert!(a < 2.0 && a > 1.0);
        }
    }

    /// A 2×2 bright spot at (sx, sy) on a dark plane.
    fn spot_plane(w: usize, h: usize, sx: usize, sy: usize) -> Vec<f32> {
        let mut p = vec![0.01f32; w * h];
        for y in sy..sy + 2 {
            for x in sx..sx + 2 {
                p[y * w + x] = 1000.0;
            }
        }
        p
    }

    #[test]
    fn spot_at_gaze_weighs_more_than_far_spot() {
        let (w, h) = (128, 128);
        let gaze = [64.0, 64.0];
        let near = spot_plane(w, h, 63, 63);
        let far = spot_plane(w, h, 100, 100);
        for m in all_models() {
            if m == PoolingModel::PanoramaMean
                || m == (PoolingModel::CentreWeight { follow_gaze: false })
            {
                continue;
            }
            let a = m.pool(&near, w, h, gaze, 0.25);
            let b = m.pool(&far, w, h, gaze, 0.25);
            assert!(a > 2.0 * b, "{m:?}: near {a} far {b}");
        }
        // The screen-centred variant of 000 ignores the gaze.
        let m = PoolingModel::CentreWeight { follow_gaze: false };
        let a = m.pool(&near, w, h, [10.0, 10.0], 0.25);
        let b = m.pool(&near, w, h, [100.0, 20.0], 0.25);
        assert_eq!(a, b);
    }

    #[test]
    fn gaussian_weights_match_closed_form() {
        // Single bright pixel one σ to the right of the gaze: its weight
        // relative to the gazed pixel is the pixel-integrated Gaussian.
        let (w, h) = (201, 201);
        let sigma_deg = 2.0;
        let deg_per_px = 0.1; // σ = 20 px
        let mut p = vec![0.0f32; w * h];
        p[100 * w + 120] = 1.0;
        let m = PoolingModel::Gaussian { sigma_deg };
        let v = m.pool(&p, w, h, [100.5, 100.5], deg_per_px);
        // Point-sampled Gaussian density at 20 px in x, 0 in y, 1 px² area:
        let expected = (-0.5f64).exp() / (2.0 * std::f64::consts::PI * 400.0);
        assert!((v / expected - 1.0).abs() < 2e-3, "{v} vs {expected}");
    }

    #[test]
    fn gaussian_is_resolution_independent() {
        // The same scene at full size and block-averaged 8× gives the same
        // pooled value when σ spans a few coarse pixels.
        let (w, h) = (256, 256);
        let mut p = vec![0.05f32; w * h];
        for y in 100..140 {
            for x in 150..170 {
                p[y * w + x] = 50.0;
            }
        }
        let ds = 8;
        let (sw, sh) = (w / ds, h / ds);
        let mut small = vec![0.0f32; sw * sh];
        for y in 0..h {
            for x in 0..w {
                small[(y / ds) * sw + x / ds] += p[y * w + x] / (ds * ds) as f32;
            }
        }
        let gaze = [140.0, 110.0];
        for m in [
            PoolingModel::Gaussian { sigma_deg: 2.0 },
            PoolingModel::GazeWindow { size_deg: 4.0 },
            PoolingModel::Eccentricity { e2_deg: 3.118 },
        ] {
            let full = m.pool(&p, w, h, gaze, 0.1);
            let coarse = m.pool(&small, sw, sh, [gaze[0] / 8.0, gaze[1] / 8.0], 0.8);
            assert!(
                (coarse / full - 1.0).abs() < 0.03,
                "{m:?}: full {full} coarse {coarse}"
            );
        }
        // σ far below one coarse pixel: the gazed pixel's value.
        let m = PoolingModel::Gaussian { sigma_deg: 0.01 };
        let v = m.pool(&small, sw, sh, [20.5, 15.5], 0.8);
        assert!((v - f64::from(small[15 * sw + 20])).abs() < 1e-6);
    }

    #[test]
    fn centre_weight_follows_000_eq5() {
        // Bright pixel at d = 0.25 (a quarter of the half width right of the
        // centre): weight 1 − 4·0.0625 = 0.75 relative to the centre.
        let (w, h) = (400, 400);
        let m = PoolingModel::CentreWeight { follow_gaze: true };
        let mut p = vec![0.0f32; w * h];
        let gaze = [200.5, 200.5];
        p[200 * w + 250] = 1.0; // 50 px = 0.25 · 200
        let with_off = m.pool(&p, w, h, gaze, 0.1);
        p[200 * w + 250] = 0.0;
        p[200 * w + 200] = 1.0;
        let with_centre = m.pool(&p, w, h, gaze, 0.1);
        assert!((with_off / with_centre - 0.75).abs() < 1e-12);
        // Beyond d = 0.5 the weight is 0.
        p[200 * w + 200] = 0.0;
        p[200 * w + 301] = 1.0;
        assert_eq!(m.pool(&p, w, h, gaze, 0.1), 0.0);
    }

    #[test]
    fn eccentricity_follows_003_eq1() {
        // Relative weight of a pixel at d degrees: E2/(E2 + d).
        let (w, h) = (301, 1);
        let m = PoolingModel::Eccentricity { e2_deg: 3.118 };
        let mut p = vec![0.0f32; w];
        p[0] = 1.0;
        let gaze = [0.5, 0.5];
        let at_gaze = m.pool(&p, w, h, gaze, 0.1);
        p[0] = 0.0;
        p[100] = 1.0; // 10°
        let at_10 = m.pool(&p, w, h, gaze, 0.1);
        assert!((at_10 / at_gaze - 3.118 / 13.118).abs() < 1e-12);
    }

    #[test]
    fn gaze_window_is_a_box_mean() {
        let (w, h) = (100, 100);
        let mut p = vec![0.0f32; w * h];
        for (i, v) in p.iter_mut().enumerate() {
            *v = (i % 13) as f32;
        }
        // 10 px window at 0.1 deg/px, aligned to pixel edges: plain mean.
        let m = PoolingModel::GazeWindow { size_deg: 1.0 };
        let v = m.pool(&p, w, h, [50.0, 30.0], 0.1);
        let mut s = 0.0;
        for y in 25..35 {
            for x in 45..55 {
                s += f64::from(p[y * w + x]);
            }
        }
        assert!((v - s / 100.0).abs() < 1e-9);
    }

    #[test]
    fn panorama_mean_uses_sine_row_weights() {
        // Two-row-band panorama: 1 at the equator rows, 0 elsewhere, vs the
        // closed form of the weights.
        let (w, h) = (8, 90);
        let mut p = vec![0.0f32; w * h];
        for x in 0..w {
            p[w + x] = 10.0; // row 1, near the pole
            p[45 * w + x] = 10.0; // row 45, at the equator
        }
        let m = PoolingModel::PanoramaMean;
        let v = m.pool(&p, w, h, [0.0, 0.0], 4.0);
        let s = |y: f64| (std::f64::consts::PI * (y + 0.5) / h as f64).sin();
        let total: f64 = (0..h).map(|y| s(y as f64)).sum();
        let expected = 10.0 * (s(1.0) + s(45.0)) / total;
        assert!((v - expected).abs() < 1e-12, "{v} vs {expected}");
        // The equator row counts ~19× more than the one next to the pole.
        assert!(s(45.0) / s(1.0) > 15.0);
    }

    #[test]
    fn validate_rejects_bad_parameters() {
        for m in [
            PoolingModel::Gaussian { sigma_deg: -1.0 },
            PoolingModel::Gaussian {
                sigma_deg: f64::NAN,
            },
            PoolingModel::Eccentricity { e2_deg: 0.0 },
            PoolingModel::GazeWindow {
                size_deg: f64::INFINITY,
            },
        ] {
            let e = m.validate().unwrap_err().to_string();
            assert!(e.contains("pooling."), "{e}");
        }
    }

    #[test]
    fn night_lamp_adapts_higher_than_ground() {
        let pano = night::load("night.exr");
        assert_eq!((pano.width, pano.height), (1024, 512));
        let lamp = pano.brightest_below_horizon();
        // Ground: same column, near the bottom of the view (60° below the
        // horizon), well away from the lamp.
        let ground = [lamp[0], pano.height as f64 * (5.0 / 6.0)];
        let dpp = pano.deg_per_px();
        let m = PoolingModel::default();
        let at_lamp = m.pool(&pano.lum, pano.width, pano.height, lamp, dpp);
        let at_ground = m.pool(&pano.lum, pano.width, pano.height, ground, dpp);
        eprintln!("night.exr lamp at {lamp:?}: {at_lamp}, ground at {ground:?}: {at_ground}");
        assert!(
            at_lamp > 10.0 * at_ground,
            "lamp {at_lamp} ground {at_ground}"
        );
        // The whole-panorama mean lies between.
        let mean = PoolingModel::PanoramaMean.pool(&pano.lum, pano.width, pano.height, lamp, dpp);
        assert!(mean > at_ground && mean < at_lamp, "mean {mean}");
    }
}
