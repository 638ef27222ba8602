//! A scene image's projection: which direction each pixel looks in, which
//! pixel a direction lands on, which pixels lie inside the image's field,
//! and each pixel's solid angle.
//!
//! Directions are in the image's own camera frame, gazelight's axes: −z
//! forward (the image's view direction), +x right, +y up. An
//! equirectangular panorama keeps the panorama convention of
//! [`crate::scene`] (its centre is forward).
//!
//! Every other projection follows Radiance's `viewray` (`src/common/image.c`):
//! a pixel centre at column `px`, row `py` (row 0 at the top) has the image
//! coordinates `x = (px + 0.5)/W − 0.5 + vs`, `y = 0.5 − (py + 0.5)/H + vl`
//! (each in −½..½ without shift), scaled to `sx = x · 2 f(h/2)`,
//! `sy = y · 2 f(v/2)` for the horizontal and vertical fields `h`, `v`; the
//! direction makes the angle θ = f⁻¹(ρ), ρ = √(sx² + sy²), with the view
//! direction, towards (sx, sy). The radial laws f(θ):
//!
//! | projection | f(θ) | Radiance |
//! | --- | --- | --- |
//! | perspective (rectilinear) | tan θ | `-vtv` |
//! | angular fisheye (equidistant) | θ (radians) | `-vta` |
//! | hemispherical fisheye (orthographic) | sin θ | `-vth` |
//! | stereographic (planisphere) | tan(θ/2) | `-vts` |
//! | equisolid-angle fisheye | sin(θ/2) | (none; common camera lenses) |
//!
//! The field of a fisheye image is the ellipse inscribed in its frame
//! (where θ ≤ half the field, for a circular fisheye); its corners are "no
//! data". A perspective image's field is its whole frame. A pixel's solid
//! angle is the spherical quadrilateral of the directions through its four
//! corners (as evalglare's `pict_get_sangle`), or, when a corner has no
//! direction, the projection's Jacobian at the pixel centre.

pub use glam::DVec3;
use serde::{Deserialize, Serialize};

use crate::VisionError;

/// The projections a scene image may have.
#[derive(Clone, Copy, Debug, PartialEq, Eq, Serialize, Deserialize)]
#[serde(rename_all = "snake_case")]
pub enum ProjectionKind {
    /// Longitude across the width (−180°..180°), latitude down the height.
    Equirectangular,
    /// Rectilinear (pinhole), Radiance `-vtv`.
    Perspective,
    /// Equidistant fisheye, r ∝ θ (Radiance `-vta`).
    Angular,
    /// Orthographic fisheye, r ∝ sin θ (Radiance `-vth`).
    Hemispherical,
    /// Equisolid-angle fisheye, r ∝ sin(θ/2).
    Equisolid,
    /// Stereographic fisheye, r ∝ tan(θ/2) (Radiance `-vts`, "planisphere").
    Stereographic,
}

impl ProjectionKind {
    /// Every kind, for help texts and tests.
    pub const ALL: [Self; 6] = [
        Self::Equirectangular,
        Self::Perspective,
        Self::Angular,
        Self::Hemispherical,
        Self::Equisolid,
        Self::Stereographic,
    ];

    /// The name used on the command line and in the config.
    pub fn name(self) -> &'static str {
        match self {
            Self::Equirectangular => "equirectangular",
            Self::Perspective => "perspective",
            Self::Angular => "angular",
            Self::Hemispherical => "hemispherical",
            Self::Equisolid => "equisolid",
            Self::Stereographic => "stereographic",
        }
    }

    /// Parses [`Self::name`] (also Radiance's letters `v a h s` and
    /// `fisheye` for the angular one).
    pub fn parse(s: &str) -> Option<Self> {
        Some(match s.trim().to_ascii_lowercase().as_str() {
            "equirectangular" | "equirect" | "panorama" => Self::Equirectangular,
            "perspective" | "rectilinear" | "v" | "vtv" => Self::Perspective,
            "angular" | "fisheye" | "equidistant" | "a" | "vta" => Self::Angular,
            "hemispherical" | "orthographic" | "h" | "vth" => Self::Hemispherical,
            "equisolid" => Self::Equisolid,
            "stereographic" | "planisphere" | "s" | "vts" => Self::Stereographic,
            _ => return None,
        })
    }

    /// The largest full field (degrees) the projection can map.
    fn max_fov_deg(self) -> f64 {
        match self {
            Self::Equirectangular => 360.0,
            Self::Perspective => 179.0,
            Self::Angular | Self::Equisolid => 360.0,
            Self::Hemispherical => 180.0,
            Self::Stereographic => 359.0,
        }
    }

    /// f(θ) of the module table.
    fn radial(self, theta_rad: f64) -> f64 {
        match self {
            Self::Perspective => theta_rad.tan(),
            Self::Angular => theta_rad,
            Self::Hemispherical => theta_rad.sin(),
            Self::Equisolid => (theta_rad * 0.5).sin(),
            Self::Stereographic => (theta_rad * 0.5).tan(),
            Self::Equirectangular => theta_rad,
        }
    }

    /// f⁻¹(ρ), or `None` where ρ is beyond the projection's range.
    fn inverse_radial(self, rho: f64) -> Option<f64> {
        let pi = std::f64::consts::PI;
        match self {
            Self::Perspective => Some(rho.atan()),
            Self::Angular => (rho <= pi).then_some(rho),
            Self::Hemispherical => (rho <= 1.0).then(|| rho.asin()),
            Self::Equisolid => (rho <= 1.0).then(|| 2.0 * rho.asin()),
            Self::Stereographic => Some(2.0 * rho.atan()),
            Self::Equirectangular => Some(rho),
        }
    }

    /// dρ/dθ, for the Jacobian solid angle.
    fn radial_derivative(self, theta_rad: f64) -> f64 {
        match self {
            Self::Perspective => 1.0 / (theta_rad.cos() * theta_rad.cos()),
            Self::Angular | Self::Equirectangular => 1.0,
            Self::Hemispherical => theta_rad.cos(),
            Self::Equisolid => 0.5 * (theta_rad * 0.5).cos(),
            Self::Stereographic => 0.5 / ((theta_rad * 0.5).cos() * (theta_rad * 0.5).cos()),
        }
    }
}

/// A scene image's projection (see the module docs).
#[derive(Clone, Copy, Debug, PartialEq, Serialize, Deserialize)]
pub struct SceneProjection {
    /// The radial law.
    pub kind: ProjectionKind,
    /// Full horizontal field, degrees (Radiance `-vh`).
    pub hfov_deg: f64,
    /// Full vertical field, degrees (Radiance `-vv`).
    pub vfov_deg: f64,
    /// Horizontal and vertical shift of the image, in image widths and
    /// heights (Radiance `-vs`, `-vl`).
    pub shift: [f64; 2],
    /// Image size, pixels.
    pub width_px: usize,
    /// Image size, pixels.
    pub height_px: usize,
}

impl SceneProjection {
    /// The equirectangular panorama of `width × height` pixels.
    pub fn equirectangular(width_px: usize, height_px: usize) -> Self {
        Self {
            kind: ProjectionKind::Equirectangular,
            hfov_deg: 360.0,
            vfov_deg: 180.0,
            shift: [0.0; 2],
            width_px,
            height_px,
        }
    }

    /// A projection of `kind` with the given full fields; fails on a
    /// field the projection cannot map or an empty image.
    pub fn new(
        kind: ProjectionKind,
        hfov_deg: f64,
        vfov_deg: f64,
        width_px: usize,
        height_px: usize,
    ) -> Result<Self, VisionError> {
        let p = Self {
            kind,
            hfov_deg,
            vfov_deg,
            shift: [0.0; 2],
            width_px,
            height_px,
        };
        p.validate()?;
        Ok(p)
    }

    /// A projection of `kind` with the horizontal field `hfov_deg` and
    /// square pixels: the vertical field maps the image's height with the
    /// same image-plane scale, `v = 2 f⁻¹(f(h/2) · H/W)`.
    pub fn with_square_pixels(
        kind: ProjectionKind,
        hfov_deg: f64,
        width_px: usize,
        height_px: usize,
    ) -> Result<Self, VisionError> {
        if kind == ProjectionKind::Equirectangular {
            return Ok(Self::equirectangular(width_px, height_px));
        }
        let f = kind.radial((hfov_deg * 0.5).to_radians());
        let aspect = height_px as f64 / width_px.max(1) as f64;
        let vfov_deg = kind
            .inverse_radial(f * aspect)
            .map_or(f64::NAN, |t| 2.0 * t.to_degrees());
        Self::new(kind, hfov_deg, vfov_deg, width_px, height_px)
    }

    /// Checks the fields and the size.
    pub fn validate(&self) -> Result<(), VisionError> {
        if self.kind == ProjectionKind::Equirectangular {
            if self.hfov_deg != 360.0 || self.vfov_deg != 180.0 {
                return Err(VisionError::invalid(
                    "scene field",
                    format!("{}×{}°", self.hfov_deg, self.vfov_deg),
                    "360×180° for an equirectangular panorama",
                ));
            }
        } else {
            let max = self.kind.max_fov_deg();
            for (name, v) in [
                ("scene horizontal field", self.hfov_deg),
                ("scene vertical field", self.vfov_deg),
            ] {
                if !(v.is_finite() && v > 0.0 && v <= max) {
                    return Err(VisionError::invalid(
                        name,
                        format!("{v}° for a {} image", self.kind.name()),
                        "0 < field ≤ the projection's largest (perspective 179°, \
                         hemispherical 180°, stereographic 359°, angular and equisolid 360°)",
                    ));
                }
            }
        }
        if !self.shift.iter().all(|s| s.is_finite() && s.abs() <= 10.0) {
            return Err(VisionError::invalid(
                "scene view shift",
                format!("{:?}", self.shift),
                "finite shifts within ±10 image sizes",
            ));
        }
        if self.width_px == 0 || self.height_px == 0 {
            return Err(VisionError::invalid(
                "scene size",
                format!("{}×{}", self.width_px, self.height_px),
                "at least one pixel",
            ));
        }
        Ok(())
    }

    /// Whether the image is a fisheye (its field is the inscribed ellipse).
    pub fn is_fisheye(&self) -> bool {
        !matches!(
            self.kind,
            ProjectionKind::Equirectangular | ProjectionKind::Perspective
        )
    }

    /// Half the field's image-plane extents, 2 f(h/2) and 2 f(v/2).
    fn scales(&self) -> [f64; 2] {
        [
            2.0 * self.kind.radial((self.hfov_deg * 0.5).to_radians()),
            2.0 * self.kind.radial((self.vfov_deg * 0.5).to_radians()),
        ]
    }

    /// Image coordinates (−½..½ across the frame, +y up, shift applied) of
    /// a continuous pixel position (pixel centres at +0.5).
    fn image_xy(&self, px: [f64; 2]) -> [f64; 2] {
        [
            px[0] / self.width_px as f64 - 0.5 + self.shift[0],
            0.5 - px[1] / self.height_px as f64 + self.shift[1],
        ]
    }

    /// The direction (unit, camera frame) through a continuous pixel
    /// position, whether or not it lies in the field; `None` where the
    /// projection maps no direction there (beyond a hemispherical image's
    /// circle, say).
    pub fn direction_any(&self, px: [f64; 2]) -> Option<DVec3> {
        if self.kind == ProjectionKind::Equirectangular {
            let tau = std::f64::consts::TAU;
            let pi = std::f64::consts::PI;
            let lon = (px[0] / self.width_px as f64 - 0.5) * tau;
            let lat = ((0.5 - px[1] / self.height_px as f64) * pi).clamp(-pi / 2.0, pi / 2.0);
            return Some(DVec3::new(
                lat.cos() * lon.sin(),
                lat.sin(),
                -lat.cos() * lon.cos(),
            ));
        }
        let [x, y] = self.image_xy(px);
        let [kx, ky] = self.scales();
        let (sx, sy) = (x * kx, y * ky);
        let rho = (sx * sx + sy * sy).sqrt();
        let theta = self.kind.inverse_radial(rho)?;
        if rho <= 1e-15 {
            return Some(DVec3::new(0.0, 0.0, -1.0));
        }
        let s = theta.sin() / rho;
        Some(DVec3::new(sx * s, sy * s, -theta.cos()).normalize())
    }

    /// Whether a continuous pixel position lies in the image's field: in
    /// the frame, and for a fisheye in the inscribed ellipse.
    pub fn in_field(&self, px: [f64; 2]) -> bool {
        let (w, h) = (self.width_px as f64, self.height_px as f64);
        if !(px[0] >= 0.0 && px[0] <= w && px[1] >= 0.0 && px[1] <= h) {
            return false;
        }
        if self.is_fisheye() {
            let u = 2.0 * px[0] / w - 1.0;
            let v = 2.0 * px[1] / h - 1.0;
            return u * u + v * v <= 1.0;
        }
        true
    }

    /// The direction through a continuous pixel position inside the field,
    /// or `None` outside it ("no data").
    pub fn direction(&self, px: [f64; 2]) -> Option<DVec3> {
        if !self.in_field(px) {
            return None;
        }
        self.direction_any(px)
    }

    /// The direction through the centre of pixel (x, y), `None` outside
    /// the field.
    pub fn pixel_direction(&self, x: usize, y: usize) -> Option<DVec3> {
        self.direction([x as f64 + 0.5, y as f64 + 0.5])
    }

    /// The continuous pixel position (centres at +0.5) a direction (any
    /// length, camera frame) lands on, or `None` outside the field.
    pub fn pixel(&self, dir: DVec3) -> Option<[f64; 2]> {
        let d = dir.try_normalize()?;
        if self.kind == ProjectionKind::Equirectangular {
            let lon = d.x.atan2(-d.z);
            let lat = d.y.clamp(-1.0, 1.0).asin();
            let u = lon / std::f64::consts::TAU + 0.5;
            let v = 0.5 - lat / std::f64::consts::PI;
            return Some([u * self.width_px as f64, v * self.height_px as f64]);
        }
        let theta = (-d.z).clamp(-1.0, 1.0).acos();
        if self.kind == ProjectionKind::Perspective && theta >= std::f64::consts::FRAC_PI_2 {
            return None;
        }
        let rho = self.kind.radial(theta);
        let lateral = (d.x * d.x + d.y * d.y).sqrt();
        let (sx, sy) = if lateral <= 1e-15 {
            (0.0, 0.0)
        } else {
            (rho * d.x / lateral, rho * d.y / lateral)
        };
        let [kx, ky] = self.scales();
        let x = sx / kx;
        let y = sy / ky;
        let px = [
            (x + 0.5 - self.shift[0]) * self.width_px as f64,
            (0.5 - (y - self.shift[1])) * self.height_px as f64,
        ];
        self.in_field(px).then_some(px)
    }

    /// Solid angle of pixel (x, y), steradians; 0 outside the field.
    pub fn pixel_solid_angle_sr(&self, x: usize, y: usize) -> f64 {
        let c = [x as f64 + 0.5, y as f64 + 0.5];
        if !self.in_field(c) {
            return 0.0;
        }
        let (x0, y0) = (x as f64, y as f64);
        let corners = [
            [x0, y0],
            [x0 + 1.0, y0],
            [x0 + 1.0, y0 + 1.0],
            [x0, y0 + 1.0],
        ]
        .map(|p| self.direction_any(p));
        if let [Some(a), Some(b), Some(cc), Some(d)] = corners {
            let q = triangle_sr(a, b, cc) + triangle_sr(a, cc, d);
            if q.is_finite() && q > 0.0 {
                return q;
            }
        }
        self.jacobian_sr(c)
    }

    /// The solid angle of a pixel at a continuous position from the
    /// projection's Jacobian.
    fn jacobian_sr(&self, c: [f64; 2]) -> f64 {
        let (w, h) = (self.width_px as f64, self.height_px as f64);
        if self.kind == ProjectionKind::Equirectangular {
            let lat = (0.5 - c[1] / h) * std::f64::consts::PI;
            return (std::f64::consts::TAU / w) * (std::f64::consts::PI / h) * lat.cos();
        }
        let [kx, ky] = self.scales();
        let [x, y] = self.image_xy(c);
        let (sx, sy) = (x * kx, y * ky);
        let rho = (sx * sx + sy * sy).sqrt();
        let Some(theta) = self.kind.inverse_radial(rho) else {
            return 0.0;
        };
        // dΩ = sinθ dθ dφ, ρ dρ dφ = dsx dsy: dΩ = sinθ/(ρ f'(θ)) dsx dsy.
        let area = (kx / w) * (ky / h);
        let ratio = if rho <= 1e-12 {
            1.0 / (self.kind.radial_derivative(0.0).powi(2))
        } else {
            theta.sin() / (rho * self.kind.radial_derivative(theta))
        };
        (area * ratio).max(0.0)
    }

    /// The solid angle of every pixel (row-major); 0 outside the field.
    pub fn solid_angles_sr(&self) -> Vec<f64> {
        use rayon::prelude::*;
        let w = self.width_px;
        (0..w * self.height_px)
            .into_par_iter()
            .map(|i| self.pixel_solid_angle_sr(i % w, i / w))
            .collect()
    }
}

/// Solid angle of the spherical triangle of three unit vectors (Van
/// Oosterom & Strackee 1983: tan(Ω/2) = |a·(b×c)| / (1 + a·b + b·c + c·a)).
fn triangle_sr(a: DVec3, b: DVec3, c: DVec3) -> f64 {
    let num = a.dot(b.cross(c)).abs();
    let den = 1.0 + a.dot(b) + b.dot(c) + c.dot(a);
    2.0 * num.atan2(den)
}

/// Why a Radiance `VIEW=` line, or the view it gives, cannot be used.
#[derive(Debug, thiserror::Error)]
pub enum RadianceViewError {
    /// An option at the end of the line without its value(s).
    #[error("VIEW= option {option} lacks its value")]
    MissingValue {
        /// The option, e.g. `-vp`.
        option: String,
    },
    /// A value that is not a finite number.
    #[error("VIEW= value {value:?} is not a finite number")]
    NotANumber {
        /// The token as written.
        value: String,
    },
    /// A view type gazelight cannot map (cylindrical `-vtc`, parallel
    /// `-vtl`, or an unknown letter).
    #[error(
        "Radiance view type -vt{0} is not supported (perspective -vtv and the fisheyes -vta, \
         -vth, -vts are)"
    )]
    UnsupportedType(char),
    /// `-vd` is the zero vector.
    #[error("zero view direction -vd")]
    ZeroDirection,
    /// `-vu` is the zero vector.
    #[error("zero view up -vu")]
    ZeroUp,
    /// `-vu` is parallel to `-vd`: no image plane orientation.
    #[error("view up -vu parallel to the view direction -vd")]
    UpAlongDirection,
    /// The projection the view gives is out of range (its field of view,
    /// shift or size).
    #[error(transparent)]
    Projection(#[from] VisionError),
}

/// A Radiance view (`VIEW=` options), in Radiance's world (usually +z up).
#[derive(Clone, Copy, Debug, PartialEq, Serialize, Deserialize)]
pub struct RadianceView {
    /// View type letter (`v a h s c l`).
    pub view_type: char,
    /// Viewpoint (`-vp`).
    pub vp: [f64; 3],
    /// View direction (`-vd`).
    pub vd: [f64; 3],
    /// View up (`-vu`).
    pub vu: [f64; 3],
    /// Full horizontal field, degrees (`-vh`).
    pub vh_deg: f64,
    /// Full vertical field, degrees (`-vv`).
    pub vv_deg: f64,
    /// Shift and lift (`-vs`, `-vl`).
    pub vs: f64,
    /// See `vs`.
    pub vl: f64,
}

impl Default for RadianceView {
    /// Radiance's standard view (`STDVIEW`): `-vtv -vp 0 0 0 -vd 0 1 0
    /// -vu 0 0 1 -vh 45 -vv 45 -vs 0 -vl 0`.
    fn default() -> Self {
        Self {
            view_type: 'v',
            vp: [0.0; 3],
            vd: [0.0, 1.0, 0.0],
            vu: [0.0, 0.0, 1.0],
            vh_deg: 45.0,
            vv_deg: 45.0,
            vs: 0.0,
            vl: 0.0,
        }
    }
}

impl RadianceView {
    /// Applies the options of one `VIEW=` line (later lines refine
    /// earlier ones, as in Radiance). Unknown options (`-vo`, `-va`, `-vf`)
    /// are skipped; a malformed number is an error.
    pub fn apply(&mut self, options: &str) -> Result<(), RadianceViewError> {
        let tokens: Vec<&str> = options.split_whitespace().collect();
        let mut i = 0;
        // Value `i` of option `option`.
        let num = |option: &str, i: usize| -> Result<f64, RadianceViewError> {
            let t = tokens
                .get(i)
                .ok_or_else(|| RadianceViewError::MissingValue {
                    option: option.to_owned(),
                })?;
            t.parse::<f64>()
                .ok()
                .filter(|v| v.is_finite())
                .ok_or_else(|| RadianceViewError::NotANumber {
                    value: (*t).to_owned(),
                })
        };
        while i < tokens.len() {
            let t = tokens[i];
            match t {
                "-vp" | "-vd" | "-vu" => {
                    let v = [num(t, i + 1)?, num(t, i + 2)?, num(t, i + 3)?];
                    match t {
                        "-vp" => self.vp = v,
                        "-vd" => self.vd = v,
                        _ => self.vu = v,
                    }
                    i += 4;
                }
                "-vh" | "-vv" | "-vs" | "-vl" | "-vo" | "-va" => {
                    let v = num(t, i + 1)?;
                    match t {
                        "-vh" => self.vh_deg = v,
                        "-vv" => self.vv_deg = v,
                        "-vs" => self.vs = v,
                        "-vl" => self.vl = v,
                        _ => {}
                    }
                    i += 2;
                }
                _ if t.starts_with("-vt") && t.len() == 4 => {
                    self.view_type = t.chars().nth(3).unwrap_or('v');
                    i += 1;
                }
                _ => i += 1,
            }
        }
        Ok(())
    }

    /// The scene projection of an image of `width × height` rendered with
    /// this view; fails on the view types gazelight cannot map
    /// (cylindrical `-vtc`, parallel `-vtl`) and on degenerate vectors.
    pub fn projection(
        &self,
        width_px: usize,
        height_px: usize,
    ) -> Result<SceneProjection, RadianceViewError> {
        let kind = match self.view_type {
            'v' => ProjectionKind::Perspective,
            'a' => ProjectionKind::Angular,
            'h' => ProjectionKind::Hemispherical,
            's' => ProjectionKind::Stereographic,
            other => return Err(RadianceViewError::UnsupportedType(other)),
        };
        self.basis()?;
        let p = SceneProjection {
            kind,
            hfov_deg: self.vh_deg,
            vfov_deg: self.vv_deg,
            shift: [self.vs, self.vl],
            width_px,
            height_px,
        };
        p.validate()?;
        Ok(p)
    }

    /// The view's right, up and forward unit vectors in Radiance's world
    /// (`hvec = vd × vu`, `vvec = hvec × vd`, as Radiance's `setview`).
    pub fn basis(&self) -> Result<[DVec3; 3], RadianceViewError> {
        let vd = DVec3::from_array(self.vd)
            .try_normalize()
            .ok_or(RadianceViewError::ZeroDirection)?;
        let vu = DVec3::from_array(self.vu)
            .try_normalize()
            .ok_or(RadianceViewError::ZeroUp)?;
        let h = vd
            .cross(vu)
            .try_normalize()
            .ok_or(RadianceViewError::UpAlongDirection)?;
        let v = h.cross(vd);
        Ok([h, v, vd])
    }

    /// A camera-frame direction (gazelight axes) in Radiance's world.
    pub fn to_world(&self, camera: DVec3) -> Option<DVec3> {
        let [h, v, d] = self.basis().ok()?;
        Some(h * camera.x + v * camera.y - d * camera.z)
    }

    /// A Radiance-world direction in the camera frame (gazelight axes).
    pub fn to_camera(&self, world: DVec3) -> Option<DVec3> {
        let [h, v, d] = self.basis().ok()?;
        Some(DVec3::new(world.dot(h), world.dot(v), -world.dot(d)))
    }
}

/// The camera-frame direction of a gaze or head angle pair: `azimuth_deg`
/// to the right of the view direction, then `elevation_deg` up (the
/// panorama views' yaw and pitch).
pub fn direction_from_angles(azimuth_deg: f64, elevation_deg: f64) -> DVec3 {
    let (a, e) = (azimuth_deg.to_radians(), elevation_deg.to_radians());
    DVec3::new(e.cos() * a.sin(), e.sin(), -e.cos() * a.cos())
}

/// The inverse of [`direction_from_angles`]: (azimuth, elevation), degrees.
pub fn angles_from_direction(dir: DVec3) -> [f64; 2] {
    let d = dir.normalize_or_zero();
    [
        d.x.atan2(-d.z).to_degrees(),
        d.y.clamp(-1.0, 1.0).asin().to_degrees(),
    ]
}

#[cfg(test)]
mod tests {
    use super::*;

    fn all(w: usize, h: usize) -> Vec<SceneProjection> {
        vec![
            SceneProjection::equirectangular(2 * w, h),
            SceneProjection::new(ProjectionKind::Perspective, 90.0, 60.0, w, h).unwrap(),
            SceneProjection::new(ProjectionKind::Angular, 180.0, 180.0, w, w).unwrap(),
            SceneProjection::new(ProjectionKind::Hemispherical, 180.0, 180.0, w, w).unwrap(),
            SceneProjection::new(ProjectionKind::Equisolid, 180.0, 180.0, w, w).unwrap(),
            SceneProjection::new(ProjectionKind::Stereographic, 180.0, 180.0, w, w).unwrap(),
        ]
    }

    #[test]
    fn pixel_and_direction_are_inverses() {
        for p in all(64, 48) {
            for (x, y) in [(10.3, 20.7), (32.0, 24.0), (50.5, 5.5), (31.9, 40.1)] {
                let Some(d) = p.direction([x, y]) else {
                    continue;
                };
                let back = p.pixel(d).unwrap();
                assert!(
                    (back[0] - x).abs() < 1e-6 && (back[1] - y).abs() < 1e-6,
                    "{:?}: {x},{y} → {d} → {back:?}",
                    p.kind
                );
            }
        }
    }

    /// The solid angles of a projection's field sum to the field's
    /// solid angle: a hemisphere (2π) for the 180° fisheyes, the sphere
    /// (4π) for the panorama, and for a rectilinear w × h field
    /// 4 asin(sin(w/2) sin(h/2)) (the solid angle of a right rectangular pyramid).
    #[test]
    fn solid_angles_sum_to_the_field() {
        use std::f64::consts::PI;
        for p in all(256, 192) {
            let total: f64 = p.solid_angles_sr().iter().sum();
            let expected = match p.kind {
                ProjectionKind::Equirectangular => 4.0 * PI,
                ProjectionKind::Perspective => {
                    let (a, b) = (45f64.to_radians(), 30f64.to_radians());
                    4.0 * (a.sin() * b.sin()).asin()
                }
                _ => 2.0 * PI,
            };
            // The fisheyes' field edge is a staircase of whole pixels.
            let tol = if p.is_fisheye() { 0.01 } else { 1e-6 };
            assert!(
                (total / expected - 1.0).abs() < tol,
                "{:?}: {total} sr vs {expected}",
                p.kind
            );
        }
    }

    #[test]
    fn radiance_views_parse_and_orient() {
        let mut v = RadianceView::default();
        v.apply("-vta -vp 2 1 1.2 -vd 0 1 0 -vu 0 0 1 -vh 180 -vv 180 -vo 0 -va 0 -vs 0 -vl 0")
            .unwrap();
        let p = v.projection(100, 100).unwrap();
        assert_eq!(p.kind, ProjectionKind::Angular);
        // Right of the image is Radiance's +x (vd × vu = y × z = x), up is +z.
        let right = p.direction([99.999, 50.0]).unwrap();
        let w = v.to_world(right).unwrap();
        assert!((w - DVec3::X).length() < 1e-3, "{w}");
        let up = v.to_world(p.direction([50.0, 0.0001]).unwrap()).unwrap();
        assert!((up - DVec3::Z).length() < 1e-3, "{up}");
        assert!(matches!(
            v.apply("-vh nan"),
            Err(RadianceViewError::NotANumber { value }) if value == "nan"
        ));
        let e = v.apply("-vh 30 -vp 1 2").unwrap_err();
        assert_eq!(e.to_string(), "VIEW= option -vp lacks its value");
        let mut c = RadianceView::default();
        c.apply("-vtc").unwrap();
        assert!(matches!(
            c.projection(10, 10),
            Err(RadianceViewError::UnsupportedType('c'))
        ));
        let mut z = RadianceView::default();
        z.apply("-vd 0 0 1").unwrap();
        assert!(matches!(
            z.projection(10, 10),
            Err(RadianceViewError::UpAlongDirection)
        ));
        z.apply("-vd 0 1 0 -vh 0").unwrap();
        assert!(matches!(
            z.projection(10, 10),
            Err(RadianceViewError::Projection(_))
        ));
    }

    #[test]
    fn fisheye_corners_are_outside_the_field() {
        for p in all(64, 64).into_iter().filter(|p| p.is_fisheye()) {
            assert!(p.pixel_direction(0, 0).is_none(), "{:?}", p.kind);
            assert_eq!(p.pixel_solid_angle_sr(63, 63), 0.0);
            assert!(p.pixel_direction(32, 32).is_some());
        }
    }

    #[test]
    fn angles_round_trip() {
        let d = direction_from_angles(30.0, -10.0);
        let [a, e] = angles_from_direction(d);
        assert!((a - 30.0).abs() < 1e-9 && (e + 10.0).abs() < 1e-9);
    }
}
