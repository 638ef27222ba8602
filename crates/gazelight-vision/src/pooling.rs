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
//! `[i, i+1) × [j, j+1)` (its centre at `i + ½`). Distances in degrees are
//! the planar pixel distance times `deg_per_px` (no wrap-around and no
//! projection correction). Pooling never allocates.

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
    /// (plane pixels, continuous) and pixels `deg_per_px` degrees wide.
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
        if width == 0 || height == 0 || luminance_cd_m2.len() != width * height {
            return 0.0;
        }
        let plane = Plane {
            lum: luminance_cd_m2,
            width,
            height,
        };
        let (gaze, deg_per_px) = sanitise(width, height, gaze_px, deg_per_px);
        let (sum, weight) = match *self {
            Self::Gaussian { sigma_deg } => plane.gaussian(gaze, sigma_deg / deg_per_px),
            Self::CentreWeight { follow_gaze } => {
                let c = if follow_gaze {
                    gaze
                } else {
                    [width as f64 / 2.0, height as f64 / 2.0]
                };
                plane.centre_weight(c)
            }
            Self::Eccentricity { e2_deg } => plane.eccentricity(gaze, e2_deg, deg_per_px),
            Self::GazeWindow { size_deg } => plane.window(gaze, size_deg / deg_per_px),
            Self::PanoramaMean => plane.panorama(),
        };
        if weight > 0.0 && weight.is_finite() && sum.is_finite() {
            sum / weight
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
        if width == 0 || height == 0 {
            return PlaneRect { x: 0..0, y: 0..0 };
        }
        let (gaze, deg_per_px) = sanitise(width, height, gaze_px, deg_per_px);
        let half = match *self {
            Self::Gaussian { sigma_deg } => gaussian_reach_px(sigma_deg / deg_per_px),
            // `Plane::window`'s half side.
            Self::GazeWindow { size_deg } => size_deg / deg_per_px / 2.0,
            Self::CentreWeight { .. } | Self::Eccentricity { .. } | Self::PanoramaMean => {
                return PlaneRect {
                    x: 0..width,
                    y: 0..height,
                };
            }
        };
        let (x0, x1) = span(gaze[0] - half, gaze[0] + half, width);
        let (y0, y1) = span(gaze[1] - half, gaze[1] + half, height);
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
}

/// `pool`'s gaze (a non-finite coordinate → the plane centre) and pixel
/// size (not finite and positive → 1°).
fn sanitise(width: usize, height: usize, gaze_px: [f64; 2], deg_per_px: f64) -> ([f64; 2], f64) {
    let gaze = [
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
    ];
    let deg_per_px = if deg_per_px.is_finite() && deg_per_px > 0.0 {
        deg_per_px
    } else {
        1.0
    };
    (gaze, deg_per_px)
}

/// How far from the gaze the Gaussian pool visits pixels (the GPU pooling
/// pass takes it from here, so both visit the same blocks): 6σ plus one
/// pixel (its weights beyond are < 1e-9 of the peak).
pub fn gaussian_reach_px(sigma_px: f64) -> f64 {
    6.0 * sigma_px + 1.0
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
    width: usize,
    height: usize,
}

impl Plane<'_> {
    #[inline]
    fn row(&self, y: usize) -> &[f32] {
        &self.lum[y * self.width..(y + 1) * self.width]
    }

    fn nearest(&self, gaze: [f64; 2]) -> f64 {
        let (x, y) = nearest_pixel(self.width, self.height, gaze);
        clean(self.lum[y * self.width + x])
    }

    /// Gaussian integrated over each pixel; only pixels within 6σ (plus one)
    /// are visited, their weights beyond that are < 1e-9 of the peak.
    fn gaussian(&self, gaze: [f64; 2], sigma_px: f64) -> (f64, f64) {
        let reach = gaussian_reach_px(sigma_px);
        let (x0, x1) = span(gaze[0] - reach, gaze[0] + reach, self.width);
        let (y0, y1) = span(gaze[1] - reach, gaze[1] + reach, self.height);
        let inv = 1.0 / (sigma_px * std::f64::consts::SQRT_2);
        let (mut sum, mut weight) = (0.0, 0.0);
        for y in y0..y1 {
            let wy =
                0.5 * (erf((y as f64 + 1.0 - gaze[1]) * inv) - erf((y as f64 - gaze[1]) * inv));
            if wy <= 0.0 {
                continue;
            }
            let row = self.row(y);
            let mut row_sum = 0.0;
            let mut row_w = 0.0;
            let mut e_lo = erf((x0 as f64 - gaze[0]) * inv);
            for (x, &v) in row.iter().enumerate().take(x1).skip(x0) {
                let e_hi = erf((x as f64 + 1.0 - gaze[0]) * inv);
                let wx = 0.5 * (e_hi - e_lo);
                e_lo = e_hi;
                row_sum += wx * clean(v);
                row_w += wx;
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
                    weight += w;
                }
            }
        }
        (sum, weight)
    }

    fn eccentricity(&self, gaze: [f64; 2], e2_deg: f64, deg_per_px: f64) -> (f64, f64) {
        let (mut sum, mut weight) = (0.0, 0.0);
        for y in 0..self.height {
            let dy = y as f64 + 0.5 - gaze[1];
            for (x, &v) in self.row(y).iter().enumerate() {
                let dx = x as f64 + 0.5 - gaze[0];
                let d_deg = (dx * dx + dy * dy).sqrt() * deg_per_px;
                // 003 eq 1: f_c = 43.1·E2/(E2 + d); 43.1 cancels in the mean
                let w = e2_deg / (e2_deg + d_deg);
                sum += w * clean(v);
                weight += w;
            }
        }
        (sum, weight)
    }

    fn window(&self, gaze: [f64; 2], size_px: f64) -> (f64, f64) {
        let half = size_px / 2.0;
        let (lo_x, hi_x) = (gaze[0] - half, gaze[0] + half);
        let (lo_y, hi_y) = (gaze[1] - half, gaze[1] + half);
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
                weight += w;
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
            sum += w * row_sum;
            weight += w * self.width as f64;
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
