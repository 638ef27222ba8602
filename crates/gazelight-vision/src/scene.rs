//! HDR scenes: loading OpenEXR and Radiance `.hdr` files, putting them in
//! physical units, and looking into an equirectangular panorama.
//!
//! The shared panoramas hold relative values, not cd/m², so every scene has
//! a luminance scale (cd/m² per file unit). Seed 004 §3.3 calibrates an HDR
//! image by measuring one known element; [`LuminanceScale::MedianKey`] does
//! the simpler thing of mapping the image's median luminance onto a chosen
//! "scene key", and [`LuminanceScale::CdM2PerUnit`] takes the factor as is.
//!
//! ## Panorama convention
//!
//! Equirectangular, x = longitude from −180° (left edge) to +180° (right
//! edge), y = latitude from +90° (top row) to −90° (bottom row). A view with
//! yaw 0 and pitch 0 looks at the centre of the panorama; positive yaw turns
//! right, positive pitch looks up. World axes: +y up, −z forward at yaw 0,
//! +x right.
//!
//! ```
//! use gazelight_vision::scene::{PanoramaView, ViewParams};
//! use gazelight_vision::RgbImage;
//!
//! let pano = RgbImage::from_pixels(8, 4, vec![[1.0, 1.0, 1.0]; 32]).unwrap();
//! let view = ViewParams { yaw_deg: 30.0, pitch_deg: 0.0, hfov_deg: 90.0, width: 16, height: 16 };
//! let mut out = RgbImage::new(16, 16);
//! PanoramaView::new(view).unwrap().render(&pano, &mut out);
//! assert!((out.get(8, 8)[0] - 1.0).abs() < 1e-6);
//! ```

use std::io::{Cursor, Read, Seek};
use std::path::{Path, PathBuf};

use glam::{Mat3, Vec3};
use serde::{Deserialize, Serialize};

use crate::image::luminance;
use crate::{RgbImage, VisionError};

/// File formats the loader understands.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum HdrFormat {
    /// OpenEXR (any compression the `exr` crate reads, incl. DWAB).
    Exr,
    /// Radiance RGBE (`.hdr`, `.pic`).
    Radiance,
}

impl HdrFormat {
    /// Guesses the format from the file's magic bytes.
    pub fn sniff(bytes: &[u8]) -> Option<Self> {
        if bytes.starts_with(&[0x76, 0x2f, 0x31, 0x01]) {
            Some(Self::Exr)
        } else if bytes.starts_with(b"#?RADIANCE") || bytes.starts_with(b"#?RGBE") {
            Some(Self::Radiance)
        } else {
            None
        }
    }
}

/// How file values are turned into cd/m².
#[derive(Clone, Copy, Debug, PartialEq, Serialize, Deserialize)]
#[serde(tag = "kind", rename_all = "snake_case", deny_unknown_fields)]
pub enum LuminanceScale {
    /// Multiply every file value by this factor (cd/m² per unit).
    CdM2PerUnit { factor: f64 },
    /// Scale so that the median luminance of the image equals `key_cd_m2`.
    MedianKey { key_cd_m2: f64 },
}

impl Default for LuminanceScale {
    fn default() -> Self {
        Self::CdM2PerUnit { factor: 1.0 }
    }
}

impl LuminanceScale {
    /// Checks the parameters.
    pub fn validate(&self) -> Result<(), VisionError> {
        let (name, v) = match *self {
            Self::CdM2PerUnit { factor } => ("luminance_scale.factor", factor),
            Self::MedianKey { key_cd_m2 } => ("luminance_scale.key_cd_m2", key_cd_m2),
        };
        if !(v.is_finite() && v > 0.0) {
            return Err(VisionError::invalid(name, v, "a finite number > 0"));
        }
        Ok(())
    }
}

/// An HDR scene in cd/m².
#[derive(Clone, Debug)]
pub struct Scene {
    /// Where it came from (a path, or `embedded:<name>`).
    pub name: String,
    /// Linear RGB in cd/m², sanitised (no NaN, Inf or negative values).
    pub image: RgbImage,
    /// The factor that was applied to the file's values.
    pub cd_m2_per_unit: f64,
    /// How many components were NaN, infinite or negative in the file.
    pub repaired_components: usize,
}

impl Scene {
    /// Loads a scene file and applies the luminance scale.
    pub fn load(path: &Path, scale: LuminanceScale) -> Result<Self, VisionError> {
        let bytes = std::fs::read(path).map_err(|e| VisionError::SceneRead {
            path: path.to_owned(),
            reason: e.to_string(),
        })?;
        Self::from_bytes(&bytes, path, scale)
    }

    /// Decodes a scene from memory; `name` is used in errors and as
    /// [`Scene::name`].
    pub fn from_bytes(
        bytes: &[u8],
        name: &Path,
        scale: LuminanceScale,
    ) -> Result<Self, VisionError> {
        scale.validate()?;
        let mut image = decode_hdr(bytes, name)?;
        let total = image.pixels.len() * 3;
        let bad = image.sanitize();
        if total == 0 || bad * 2 > total {
            return Err(VisionError::SceneInvalid {
                path: name.to_owned(),
                reason: format!(
                    "{bad} of {total} values are NaN, infinite or negative; expected mostly finite values ≥ 0"
                ),
            });
        }
        let factor = match scale {
            LuminanceScale::CdM2PerUnit { factor } => factor,
            LuminanceScale::MedianKey { key_cd_m2 } => {
                let median = median_luminance(&image);
                if median <= 0.0 {
                    return Err(VisionError::SceneInvalid {
                        path: name.to_owned(),
                        reason: "median luminance is 0: cannot scale to a median key; use a factor"
                            .into(),
                    });
                }
                key_cd_m2 / median
            }
        };
        image.scale(factor as f32);
        Ok(Self {
            name: name.display().to_string(),
            image,
            cd_m2_per_unit: factor,
            repaired_components: bad,
        })
    }
}

/// Median luminance of an image (file units).
pub fn median_luminance(image: &RgbImage) -> f64 {
    let mut y: Vec<f32> = image.pixels.iter().map(|&p| luminance(p)).collect();
    if y.is_empty() {
        return 0.0;
    }
    let mid = y.len() / 2;
    let (_, m, _) = y.select_nth_unstable_by(mid, f32::total_cmp);
    f64::from(*m)
}

/// Decodes EXR or Radiance bytes into linear RGB (file units, not sanitised).
pub fn decode_hdr(bytes: &[u8], name: &Path) -> Result<RgbImage, VisionError> {
    let read_err = |reason: String| VisionError::SceneRead {
        path: name.to_owned(),
        reason,
    };
    match HdrFormat::sniff(bytes) {
        Some(HdrFormat::Exr) => {
            decode_exr(Cursor::new(bytes)).map_err(|e| read_err(format!("corrupt OpenEXR: {e}")))
        }
        Some(HdrFormat::Radiance) => {
            decode_radiance(bytes).map_err(|e| read_err(format!("corrupt Radiance HDR: {e}")))
        }
        None => Err(read_err(
            "not an OpenEXR or Radiance .hdr file (unknown magic bytes)".to_string(),
        )),
    }
}

fn decode_exr(reader: impl Read + Seek + Send) -> Result<RgbImage, exr::error::Error> {
    use exr::prelude::*;
    let image = read()
        .no_deep_data()
        .largest_resolution_level()
        .rgba_channels(
            |resolution, _channels| RgbImage::new(resolution.width(), resolution.height()),
            |img: &mut RgbImage, pos, (r, g, b, _a): (f32, f32, f32, f32)| {
                *img.get_mut(pos.x(), pos.y()) = [r, g, b];
            },
        )
        .first_valid_layer()
        .all_attributes()
        .non_parallel()
        .from_buffered(reader)?;
    Ok(image.layer_data.channel_data.pixels)
}

fn decode_radiance(bytes: &[u8]) -> Result<RgbImage, image::ImageError> {
    let img = image::load_from_memory_with_format(bytes, image::ImageFormat::Hdr)?.into_rgb32f();
    let (w, h) = (img.width() as usize, img.height() as usize);
    let pixels = img.pixels().map(|p| [p.0[0], p.0[1], p.0[2]]).collect();
    Ok(RgbImage {
        width: w,
        height: h,
        pixels,
    })
}

/// Writes a linear RGB float32 OpenEXR file.
pub fn write_exr(path: &Path, image: &RgbImage) -> Result<(), VisionError> {
    exr::prelude::write_rgb_file(path, image.width, image.height, |x, y| {
        let p = image.get(x, y);
        (p[0], p[1], p[2])
    })
    .map_err(|e| VisionError::SceneRead {
        path: PathBuf::from(path),
        reason: format!("cannot write OpenEXR: {e}"),
    })
}

/// A perspective view into a panorama.
#[derive(Clone, Copy, Debug, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct ViewParams {
    /// Head yaw, degrees, positive to the right.
    pub yaw_deg: f64,
    /// Head pitch, degrees, positive up.
    pub pitch_deg: f64,
    /// Horizontal field of view, degrees (0 < fov < 180).
    pub hfov_deg: f64,
    /// Output width, pixels.
    pub width: usize,
    /// Output height, pixels.
    pub height: usize,
}

impl ViewParams {
    /// Angular size of a pixel at the centre of the view, degrees.
    pub fn deg_per_px(&self) -> f64 {
        let half = (self.hfov_deg.to_radians() * 0.5).tan();
        (2.0 * half / self.width as f64).atan().to_degrees()
    }

    /// Pixels per degree at the centre of the view.
    pub fn ppd(&self) -> f64 {
        1.0 / self.deg_per_px()
    }

    /// Checks the parameters.
    pub fn validate(&self) -> Result<(), VisionError> {
        if !(self.hfov_deg > 0.0 && self.hfov_deg < 179.0) {
            return Err(VisionError::invalid(
                "view.hfov_deg",
                self.hfov_deg,
                "0 < hfov_deg < 179",
            ));
        }
        if !self.yaw_deg.is_finite() {
            return Err(VisionError::invalid(
                "view.yaw_deg",
                self.yaw_deg,
                "a finite angle",
            ));
        }
        if self.pitch_deg.is_nan() || self.pitch_deg.abs() > 90.0 {
            return Err(VisionError::invalid(
                "view.pitch_deg",
                self.pitch_deg,
                "−90 ≤ pitch_deg ≤ 90",
            ));
        }
        if self.width < 8 || self.height < 8 || self.width > 8192 || self.height > 8192 {
            return Err(VisionError::invalid(
                "view.size",
                format!("{}x{}", self.width, self.height),
                "8..=8192 pixels per side",
            ));
        }
        Ok(())
    }
}

/// A validated perspective projection into an equirectangular panorama.
#[derive(Clone, Copy, Debug)]
pub struct PanoramaView {
    params: ViewParams,
    rotation: Mat3,
    tan_half_h: f32,
    tan_half_v: f32,
}

impl PanoramaView {
    /// Builds the projection; fails on invalid parameters.
    pub fn new(params: ViewParams) -> Result<Self, VisionError> {
        params.validate()?;
        let tan_half_h = (params.hfov_deg.to_radians() * 0.5).tan() as f32;
        let tan_half_v = tan_half_h * params.height as f32 / params.width as f32;
        // Yaw turns right about +y (a negative rotation in a right-handed frame).
        let rotation = Mat3::from_rotation_y(-(params.yaw_deg.to_radians() as f32))
            * Mat3::from_rotation_x(params.pitch_deg.to_radians() as f32);
        Ok(Self {
            params,
            rotation,
            tan_half_h,
            tan_half_v,
        })
    }

    /// The parameters.
    pub fn params(&self) -> &ViewParams {
        &self.params
    }

    /// World direction through the centre of view pixel (x, y) (pixel units,
    /// may be fractional).
    pub fn direction(&self, x_px: f32, y_px: f32) -> Vec3 {
        let sx = (2.0 * x_px / self.params.width as f32 - 1.0) * self.tan_half_h;
        let sy = (1.0 - 2.0 * y_px / self.params.height as f32) * self.tan_half_v;
        (self.rotation * Vec3::new(sx, sy, -1.0)).normalize()
    }

    /// View pixel of a world direction, or `None` if it is behind the viewer.
    pub fn project(&self, dir: Vec3) -> Option<[f32; 2]> {
        let cam = self.rotation.transpose() * dir;
        if cam.z >= -1e-6 {
            return None;
        }
        let sx = cam.x / -cam.z;
        let sy = cam.y / -cam.z;
        Some([
            (sx / self.tan_half_h + 1.0) * 0.5 * self.params.width as f32,
            (1.0 - sy / self.tan_half_v) * 0.5 * self.params.height as f32,
        ])
    }

    /// Renders the view from `pano` into `out` (bilinear, longitude wraps).
    /// `out` must be `width × height`; it is resized if not (one allocation).
    pub fn render(&self, pano: &RgbImage, out: &mut RgbImage) {
        use rayon::prelude::*;
        let (w, h) = (self.params.width, self.params.height);
        if out.width != w || out.height != h {
            *out = RgbImage::new(w, h);
        }
        out.pixels
            .par_chunks_mut(w)
            .enumerate()
            .for_each(|(y, row)| {
                for (x, px) in row.iter_mut().enumerate() {
                    let d = self.direction(x as f32 + 0.5, y as f32 + 0.5);
                    *px = sample_equirect(pano, d);
                }
            });
    }
}

/// Equirectangular panorama pixel coordinates (continuous, pixel centres at
/// +0.5) of a world direction.
pub fn equirect_px(pano_width: usize, pano_height: usize, dir: Vec3) -> [f32; 2] {
    let lon = dir.x.atan2(-dir.z); // −π..π, 0 = forward
    let lat = dir.y.clamp(-1.0, 1.0).asin(); // −π/2..π/2
    let u = lon / std::f32::consts::TAU + 0.5;
    let v = 0.5 - lat / std::f32::consts::PI;
    [u * pano_width as f32, v * pano_height as f32]
}

/// World direction of a continuous equirectangular pixel position.
pub fn equirect_direction(pano_width: usize, pano_height: usize, px: [f32; 2]) -> Vec3 {
    let lon = (px[0] / pano_width as f32 - 0.5) * std::f32::consts::TAU;
    let lat = (0.5 - px[1] / pano_height as f32) * std::f32::consts::PI;
    Vec3::new(lat.cos() * lon.sin(), lat.sin(), -lat.cos() * lon.cos())
}

/// Bilinear sample of an equirectangular panorama in a direction.
pub fn sample_equirect(pano: &RgbImage, dir: Vec3) -> [f32; 3] {
    let (w, h) = (pano.width, pano.height);
    if w == 0 || h == 0 {
        return [0.0; 3];
    }
    let [fx, fy] = equirect_px(w, h, dir);
    let x = fx - 0.5;
    let y = (fy - 0.5).clamp(0.0, (h - 1) as f32);
    let x0f = x.floor();
    let y0f = y.floor();
    let tx = x - x0f;
    let ty = y - y0f;
    let x0 = (x0f as i64).rem_euclid(w as i64) as usize;
    let x1 = (x0 + 1) % w;
    let y0 = y0f as usize;
    let y1 = (y0 + 1).min(h - 1);
    let a = pano.get(x0, y0);
    let b = pano.get(x1, y0);
    let c = pano.get(x0, y1);
    let d = pano.get(x1, y1);
    let mut out = [0.0; 3];
    for i in 0..3 {
        let top = a[i] + (b[i] - a[i]) * tx;
        let bot = c[i] + (d[i] - c[i]) * tx;
        out[i] = top + (bot - top) * ty;
    }
    out
}

#[cfg(test)]
mod tests {
    use super::*;

    fn shared(name: &str) -> PathBuf {
        Path::new(env!("CARGO_MANIFEST_DIR"))
            .join("../../../shared/data/hdr/blender-world")
            .join(name)
    }

    #[test]
    fn loads_all_shared_panoramas() {
        for name in [
            "city.exr",
            "courtyard.exr",
            "forest.exr",
            "night.exr",
            "studio.exr",
            "sunset.exr",
        ] {
            let s = Scene::load(&shared(name), LuminanceScale::default()).unwrap();
            assert_eq!((s.image.width, s.image.height), (1024, 512), "{name}");
            assert!(
                s.repaired_components > 0,
                "{name}: the README says every file has negative pixels"
            );
            assert!(
                s.image
                    .pixels
                    .iter()
                    .flatten()
                    .all(|v| v.is_finite() && *v >= 0.0)
            );
        }
    }

    #[test]
    fn median_key_matches_readme() {
        // shared/data/README.md: night.exr median Y 0.015, city.exr 0.50.
        let night = decode_hdr(
            &std::fs::read(shared("night.exr")).unwrap(),
            Path::new("night"),
        )
        .unwrap();
        let m = median_luminance(&night);
        assert!((m - 0.015).abs() < 0.003, "{m}");
        let s = Scene::load(
            &shared("city.exr"),
            LuminanceScale::MedianKey { key_cd_m2: 100.0 },
        )
        .unwrap();
        assert!((median_luminance(&s.image) - 100.0).abs() < 1.0);
    }

    #[test]
    fn corrupt_and_missing_files_name_the_file() {
        let e =
            Scene::load(Path::new("/nonexistent/x.exr"), LuminanceScale::default()).unwrap_err();
        assert!(e.to_string().contains("/nonexistent/x.exr"), "{e}");
        let mut bytes = std::fs::read(shared("night.exr")).unwrap();
        bytes.truncate(bytes.len() / 3);
        let e =
            Scene::from_bytes(&bytes, Path::new("cut.exr"), LuminanceScale::default()).unwrap_err();
        assert!(
            e.to_string().contains("cut.exr") && e.to_string().contains("OpenEXR"),
            "{e}"
        );
        let e = Scene::from_bytes(b"hello", Path::new("text.exr"), LuminanceScale::default())
            .unwrap_err();
        assert!(e.to_string().contains("magic"), "{e}");
    }

    #[test]
    fn nan_scene_is_rejected() {
        let dir = std::env::temp_dir().join(format!("gazelight-nan-{}", std::process::id()));
        std::fs::create_dir_all(&dir).unwrap();
        let path = dir.join("nan.exr");
        let img = RgbImage::from_pixels(4, 4, vec![[f32::NAN; 3]; 16]).unwrap();
        write_exr(&path, &img).unwrap();
        let e = Scene::load(&path, LuminanceScale::default()).unwrap_err();
        assert!(
            e.to_string().contains("NaN") && e.to_string().contains("nan.exr"),
            "{e}"
        );
        std::fs::remove_dir_all(&dir).ok();
    }

    #[test]
    fn radiance_round_trip() {
        let mut buf = Vec::new();
        let img = image::Rgb32FImage::from_fn(4, 2, |x, y| {
            image::Rgb([x as f32 + 1.0, y as f32 + 0.5, 2.0])
        });
        image::DynamicImage::ImageRgb32F(img)
            .write_to(&mut Cursor::new(&mut buf), image::ImageFormat::Hdr)
            .unwrap();
        let s = Scene::from_bytes(
            &buf,
            Path::new("t.hdr"),
            LuminanceScale::CdM2PerUnit { factor: 10.0 },
        )
        .unwrap();
        assert_eq!((s.image.width, s.image.height), (4, 2));
        let p = s.image.get(3, 1);
        assert!(
            (p[0] - 40.0).abs() < 0.5 && (p[1] - 15.0).abs() < 0.2,
            "{p:?}"
        );
    }

    #[test]
    fn projection_round_trips_and_orients() {
        let view = PanoramaView::new(ViewParams {
            yaw_deg: 40.0,
            pitch_deg: -10.0,
            hfov_deg: 100.0,
            width: 200,
            height: 160,
        })
        .unwrap();
        let centre = view.direction(100.0, 80.0);
        let [u, v] = equirect_px(360, 180, centre);
        // yaw 40° right of the panorama centre (180 px), pitch 10° down (90 px).
        assert!(
            (u - 220.0).abs() < 1e-3 && (v - 100.0).abs() < 1e-3,
            "{u} {v}"
        );
        for &(x, y) in &[(0.0f32, 0.0f32), (37.5, 120.25), (199.0, 159.0)] {
            let p = view.project(view.direction(x, y)).unwrap();
            assert!(
                (p[0] - x).abs() < 1e-2 && (p[1] - y).abs() < 1e-2,
                "{p:?} vs {x},{y}"
            );
        }
        // Positive pitch looks up: the top of the view is higher than the bottom.
        assert!(view.direction(100.0, 0.0).y > view.direction(100.0, 159.0).y);
        let d = equirect_direction(360, 180, [220.0, 100.0]);
        assert!((d - centre).length() < 1e-5);
    }

    #[test]
    fn deg_per_px_of_vive_pro() {
        // 001 uses the HTC Vive Pro: 1440 px over about 104° → 13.85 ppd.
        let p = ViewParams {
            yaw_deg: 0.0,
            pitch_deg: 0.0,
            hfov_deg: 104.0,
            width: 1440,
            height: 1600,
        };
        // A rectilinear view is sparsest at its centre: 2·tan(52°)/1440 rad per px.
        let expected_ppd = 1.0
            / (2.0 * 52f64.to_radians().tan() / 1440.0)
                .atan()
                .to_degrees();
        assert!((p.ppd() - expected_ppd).abs() < 1e-9);
        assert!(p.ppd() < 1440.0 / 104.0, "centre ppd is below the average");
        assert!(p.validate().is_ok());
        assert!(
            ViewParams {
                hfov_deg: 200.0,
                ..p
            }
            .validate()
            .is_err()
        );
    }
}
