//! HDR scenes: loading OpenEXR and Radiance `.hdr` files, putting them in
//! physical units, and looking into an equirectangular panorama.
//!
//! The shared panoramas hold relative values, not cd/m², so every scene has
//! a luminance scale (cd/m² per file unit). Seed 004 §3.3 calibrates an HDR
//! image by measuring one known element; [`LuminanceScale::MedianKey`] does
//! the simpler thing of mapping the image's median luminance onto a chosen
//! "scene key", and [`LuminanceScale::CdM2PerUnit`] takes the factor as is.
//!
//! ## Units of Radiance files
//!
//! A Radiance `.hdr` holds radiance in W·sr⁻¹·m⁻² multiplied by the
//! header's `EXPOSURE=` values (their product; 1 when absent) and
//! per-channel `COLORCORR=` factors. Radiance's luminance is
//! 179 lm/W × (0.265 R + 0.670 G + 0.065 B) / EXPOSURE (the Radiance
//! reference manual, "luminance"; 179 lm/W is its white efficacy). The
//! loader divides the pixels by EXPOSURE and COLORCORR and multiplies them
//! by 179, so a Radiance file's unit is cd/m² and the default
//! [`LuminanceScale`] (1) reads an absolute rendering as it was rendered.
//! Its RGBE pixels are decoded as Radiance decodes them, (c + ½)·2^(e−136)
//! ([`rgbe_to_rgb`]), so a pixel's luminance is rtrace's and evalglare's.
//! OpenEXR files carry no such convention: their unit is the file's own.
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

mod exr_header;
pub mod projection;
mod rgbe;
pub use exr_header::{MAX_PIXELS, MAX_SIDE_PX};
pub use projection::{ProjectionKind, RadianceView, RadianceViewError, SceneProjection};
pub use rgbe::rgbe_to_rgb;

/// Radiance's luminous efficacy of its white, lm/W: luminance =
/// 179 × (0.265 R + 0.670 G + 0.065 B) / EXPOSURE (Radiance reference
/// manual).
pub const RADIANCE_EFFICACY_LM_PER_W: f64 = 179.0;

/// Panorama aspect (width / height) of an equirectangular image, and how
/// far from it a scene may be before the loader warns.
pub const EQUIRECT_ASPECT: f64 = 2.0;
const ASPECT_TOLERANCE: f64 = 0.02;

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

/// Largest luminance factor (cd/m² per file unit) any front end accepts:
/// the CLI's `--luminance-scale`, `glare --luminance-factor`, Python's
/// `luminance_scale` and the OpenXR layer's `white_cd_m2` /
/// `scene_scale_cd_m2` all check against this one bound.
pub const MAX_SCALE_FACTOR: f64 = 1e20;
/// Largest median key accepted, cd/m²: a median of 10⁹ cd/m² is already a
/// scene made of the sun's disc (≈ 1.6·10⁹ cd/m²).
pub const MAX_SCENE_KEY_CD_M2: f64 = 1e9;
/// Brightest scaled scene value accepted, cd/m²: above it the pipeline's
/// single-precision sums (pooling, the glare convolution over up to 2²⁰
/// pixels) come within a factor ~10⁶ of `f32::MAX` and overflow.
pub const MAX_SCENE_CD_M2: f64 = 1e32;

/// A luminance factor (cd/m² per unit): `0 < factor ≤ MAX_SCALE_FACTOR`.
/// `name` is the key or flag it came from, for the error.
pub fn check_factor(name: &'static str, factor: f64) -> Result<f64, VisionError> {
    if factor.is_finite() && factor > 0.0 && factor <= MAX_SCALE_FACTOR {
        Ok(factor)
    } else {
        // 1e308 as `1e308`, not 309 digits.
        let a = factor.abs();
        let shown = if a.is_finite() && a != 0.0 && !(1e-4..1e9).contains(&a) {
            format!("{factor:e}")
        } else {
            format!("{factor}")
        };
        Err(VisionError::invalid(
            name,
            shown,
            "expected 0 < cd/m² per unit ≤ 1e20",
        ))
    }
}

impl LuminanceScale {
    /// Checks the parameters: factor `0 < f ≤ MAX_SCALE_FACTOR`, key
    /// `0 < k ≤ MAX_SCENE_KEY_CD_M2`.
    pub fn validate(&self) -> Result<(), VisionError> {
        match *self {
            Self::CdM2PerUnit { factor } => {
                check_factor("luminance_scale.factor", factor)?;
            }
            Self::MedianKey { key_cd_m2 } => {
                if !(key_cd_m2.is_finite() && key_cd_m2 > 0.0 && key_cd_m2 <= MAX_SCENE_KEY_CD_M2) {
                    return Err(VisionError::invalid(
                        "luminance_scale.key_cd_m2",
                        key_cd_m2,
                        "expected 0 < median cd/m² ≤ 1e9 (the sun's disc is ≈ 1.6e9 cd/m²)",
                    ));
                }
            }
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
    /// The image's projection, where known: from the Radiance header's
    /// `VIEW=` or given ([`Scene::set_projection`]). `None`: unknown, the
    /// image is read as an equirectangular panorama.
    pub projection: Option<SceneProjection>,
    /// The Radiance view of the header (its `VIEW=` lines), where there
    /// was one: gives the scene's directions in Radiance's world.
    pub radiance_view: Option<RadianceView>,
    /// The header's `PIXASPECT=` (pixel height / width), where given.
    pub pixel_aspect: Option<f64>,
}

impl Scene {
    /// The brightest component after scaling, cd/m², and how many
    /// components are not finite (the scale overflowed single precision).
    pub fn luminance_range(&self) -> (f64, usize) {
        let mut max = 0.0f32;
        let mut overflowed = 0usize;
        for &c in self.image.pixels.iter().flatten() {
            if c.is_finite() {
                max = max.max(c);
            } else {
                overflowed += 1;
            }
        }
        (f64::from(max), overflowed)
    }

    /// Refuses a scaled scene with values that overflow single precision
    /// or exceed [`MAX_SCENE_CD_M2`] (its frames would be black), naming
    /// the scale applied; returns the brightest value.
    pub fn check_luminance(&self) -> Result<f64, VisionError> {
        let (max, overflowed) = self.luminance_range();
        if overflowed > 0 || max > MAX_SCENE_CD_M2 {
            return Err(VisionError::SceneInvalid {
                path: PathBuf::from(&self.name),
                reason: format!(
                    "after scaling by {:e} cd/m² per unit, {overflowed} of {} values overflow \
                     single precision and the brightest is {max:e} cd/m² (limit \
                     {MAX_SCENE_CD_M2:e}): the frames would be black; lower the luminance scale \
                     (the sun's disc is ≈ 1.6e9 cd/m²)",
                    self.cd_m2_per_unit,
                    self.image.pixels.len() * 3
                ),
            });
        }
        Ok(max)
    }

    /// Loads a scene file and applies the luminance scale.
    pub fn load(path: &Path, scale: LuminanceScale) -> Result<Self, VisionError> {
        let bytes = gazelight_input::read(path, gazelight_input::MAX_SCENE_BYTES).map_err(|e| {
            VisionError::SceneRead {
                path: path.to_owned(),
                reason: e.to_string(),
            }
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
        let (mut image, header) = decode_hdr_with_header(bytes, name)?;
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
        let projection = match &header.view {
            Some(v) => Some(v.projection(image.width, image.height).map_err(|reason| {
                VisionError::SceneInvalid {
                    path: name.to_owned(),
                    reason: format!("its Radiance VIEW= header: {reason}"),
                }
            })?),
            None => None,
        };
        if projection.is_none()
            && let Some(w) = geometry_warning(&image)
        {
            tracing::warn!(scene = %name.display(), "{w}");
        }
        Ok(Self {
            name: name.display().to_string(),
            image,
            cd_m2_per_unit: factor,
            repaired_components: bad,
            projection,
            radiance_view: header.view,
            pixel_aspect: header.pixel_aspect,
        })
    }

    /// Gives the scene a projection (`--scene-projection`,
    /// `--scene-fov-deg`, or the config's keys), replacing the header's.
    pub fn set_projection(
        &mut self,
        kind: ProjectionKind,
        fov_deg: Option<[f64; 2]>,
    ) -> Result<(), VisionError> {
        let (w, h) = (self.image.width, self.image.height);
        self.projection = Some(match (kind, fov_deg) {
            (ProjectionKind::Equirectangular, _) => SceneProjection::equirectangular(w, h),
            (_, Some([hf, vf])) => SceneProjection::new(kind, hf, vf, w, h)?,
            (_, None) => {
                return Err(VisionError::invalid(
                    "scene field of view",
                    "none",
                    "a field in degrees (--scene-fov-deg H[,V]) for a non-panorama projection",
                ));
            }
        });
        Ok(())
    }

    /// The projection in effect: the known one, or the equirectangular
    /// panorama an unknown image is read as.
    pub fn effective_projection(&self) -> SceneProjection {
        self.projection.unwrap_or_else(|| {
            SceneProjection::equirectangular(self.image.width, self.image.height)
        })
    }
}

/// What a Radiance header says beyond the pixels' scale.
#[derive(Clone, Debug, Default)]
pub struct RadianceHeader {
    /// The view of its `VIEW=` lines (applied in order), if any.
    pub view: Option<RadianceView>,
    /// `PIXASPECT=` (their product), if any.
    pub pixel_aspect: Option<f64>,
}

/// A warning when an image of unknown projection is not shaped like an
/// equirectangular panorama (2:1): a fisheye or a perspective photo would be
/// mapped as if it were one. Images with a known projection (a Radiance
/// `VIEW=`, `--scene-projection`) are not warned about.
pub fn geometry_warning(image: &RgbImage) -> Option<String> {
    if image.height == 0 {
        return None;
    }
    let aspect = image.width as f64 / image.height as f64;
    ((aspect / EQUIRECT_ASPECT - 1.0).abs() > ASPECT_TOLERANCE).then(|| {
        format!(
            "the scene is {}×{} (aspect {aspect:.3}), not a 2:1 equirectangular panorama: it is \
             mapped as one (longitude across the width, latitude down the height), so a \
             fisheye or perspective image will look distorted; give its projection \
             (--scene-projection and --scene-fov-deg, or a Radiance VIEW= header) or \
             convert it to an equirectangular panorama",
            image.width, image.height
        )
    })
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
    decode_hdr_with_header(bytes, name).map(|(image, _)| image)
}

/// [`decode_hdr`], and what a Radiance header says of the view (empty for
/// OpenEXR).
pub fn decode_hdr_with_header(
    bytes: &[u8],
    name: &Path,
) -> Result<(RgbImage, RadianceHeader), VisionError> {
    let read_err = |reason: String| VisionError::SceneRead {
        path: name.to_owned(),
        reason,
    };
    match HdrFormat::sniff(bytes) {
        Some(HdrFormat::Exr) => {
            let header = exr_header::check(bytes).map_err(|p| {
                read_err(if p.unsupported {
                    format!("OpenEXR feature not supported: {}", p.reason)
                } else {
                    format!("corrupt OpenEXR: {}", p.reason)
                })
            })?;
            decode_exr(Cursor::new(bytes), header.has_rgb())
                .map(|image| (image, RadianceHeader::default()))
                .map_err(|e| read_err(format!("corrupt OpenEXR: {e}")))
        }
        Some(HdrFormat::Radiance) => decode_radiance(bytes).map_err(read_err),
        None => Err(read_err(
            "not an OpenEXR or Radiance .hdr file (unknown magic bytes)".to_string(),
        )),
    }
}

fn decode_exr(reader: impl Read + Seek + Send, rgb: bool) -> Result<RgbImage, exr::error::Error> {
    use exr::prelude::*;
    if !rgb {
        // A luminance image (Y, as OpenEXR's luminance/chroma files and
        // grey renders write): grey RGB with R = G = B = Y.
        let image = read()
            .no_deep_data()
            .largest_resolution_level()
            .specific_channels()
            .required("Y")
            .collect_pixels(
                |resolution, _channels| RgbImage::new(resolution.width(), resolution.height()),
                |img: &mut RgbImage, pos, (y,): (f32,)| {
                    *img.get_mut(pos.x(), pos.y()) = [y, y, y];
                },
            )
            .first_valid_layer()
            .all_attributes()
            .non_parallel()
            .from_buffered(reader)?;
        return Ok(image.layer_data.channel_data.pixels);
    }
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

/// Decodes a Radiance file into cd/m² (see the module docs): checks the
/// claimed size against [`MAX_SIDE_PX`], [`MAX_PIXELS`] and the file size
/// before allocating, then applies 179 / (EXPOSURE × COLORCORR).
fn decode_radiance(bytes: &[u8]) -> Result<(RgbImage, RadianceHeader), String> {
    let decoder = image::codecs::hdr::HdrDecoder::new(Cursor::new(bytes))
        .map_err(|e| format!("corrupt Radiance HDR: {e}"))?;
    let meta = decoder.metadata();
    let (w, h) = (u64::from(meta.width), u64::from(meta.height));
    if w == 0 || h == 0 || w > MAX_SIDE_PX || h > MAX_SIDE_PX || w * h > MAX_PIXELS {
        return Err(format!(
            "corrupt Radiance HDR: the header claims {w}×{h} pixels; a scene may have 1 to \
             {MAX_SIDE_PX} per side and at most {MAX_PIXELS} in all"
        ));
    }
    // Run-length encoded scan lines shrink a flat line to ~4 bytes per 127
    // pixels, never further: 2 bytes per 127 pixels and channel at best.
    let min_bytes = w * h / 64;
    if (bytes.len() as u64) < min_bytes {
        return Err(format!(
            "corrupt Radiance HDR: the header claims {w}×{h} pixels but the file holds only {} \
             bytes (at least {min_bytes} needed): it is truncated or its header lies",
            bytes.len()
        ));
    }
    let mut view: Option<RadianceView> = None;
    for (key, value) in &meta.custom_attributes {
        if key == "VIEW" {
            view.get_or_insert_with(RadianceView::default)
                .apply(value)
                .map_err(|e| format!("Radiance HDR header: {e}"))?;
        }
    }
    let header = RadianceHeader {
        view,
        pixel_aspect: meta.pixel_aspect_ratio.map(f64::from),
    };
    let exposure = f64::from(meta.exposure.unwrap_or(1.0));
    let corr = meta.color_correction.unwrap_or((1.0, 1.0, 1.0));
    let corr = [f64::from(corr.0), f64::from(corr.1), f64::from(corr.2)];
    if !(exposure.is_finite() && exposure > 0.0)
        || corr.iter().any(|c| !(c.is_finite() && *c > 0.0))
    {
        return Err(format!(
            "corrupt Radiance HDR: EXPOSURE {exposure} / COLORCORR {corr:?} must be finite and > 0"
        ));
    }
    let k64 = corr.map(|c| RADIANCE_EFFICACY_LM_PER_W / (exposure * c));
    // The pixels as Radiance reads them ((c + ½)·2^(e−136), see `rgbe`),
    // not as the `image` crate does (c·2^(e−136)).
    let offset = rgbe::pixel_data_offset(bytes)
        .ok_or("corrupt Radiance HDR: no resolution line after the header")?;
    let mut lines = rgbe::ScanLines::new(&bytes[offset..]);
    let (w_px, h_px) = (w as usize, h as usize);
    let mut line = vec![[0u8; 4]; w_px];
    let mut pixels = Vec::with_capacity(w_px * h_px);
    let mut brightest = 0.0f64;
    for y in 0..h_px {
        lines
            .read(&mut line)
            .map_err(|e| format!("corrupt Radiance HDR: scan line {y}: {e}"))?;
        pixels.extend(line.iter().map(|&p| {
            let rgb = rgbe::rgbe_to_rgb(p);
            brightest = rgb.iter().copied().fold(brightest, f64::max);
            [0, 1, 2].map(|i| (rgb[i] * k64[i]) as f32)
        }));
    }
    let k_max = k64.iter().copied().fold(0.0, f64::max);
    if brightest * k_max > f64::from(f32::MAX) {
        return Err(format!(
            "Radiance HDR values overflow single precision in cd/m²: the brightest, \
             {brightest:e} W/sr/m², is {:e} cd/m² after Radiance's 179 lm/W / EXPOSURE",
            brightest * k_max
        ));
    }
    Ok((
        RgbImage {
            width: w as usize,
            height: h as usize,
            pixels,
        },
        header,
    ))
}

/// Writes a linear RGB float32 OpenEXR file.
pub fn write_exr(path: &Path, image: &RgbImage) -> Result<(), VisionError> {
    write_exr_with_attributes(path, image, None, &[])
}

/// A header attribute of an OpenEXR file ([`write_exr_with_attributes`]).
#[derive(Clone, Debug, PartialEq)]
pub enum ExrAttribute {
    /// OpenEXR `string` (Latin-1; gazelight writes ASCII).
    Text(String),
    /// OpenEXR `double`.
    F64(f64),
    /// OpenEXR `v2f`.
    Vec2([f32; 2]),
}

/// Writes `image` as an RGB OpenEXR file (as [`write_exr`]) with the
/// standard `whiteLuminance` attribute (the cd/m² of RGB (1, 1, 1):
/// `Some(1.0)` for values in cd/m²) when given, and `attributes` (name,
/// value) in its header. Fails on a name or text that is not Latin-1 or
/// on an empty name.
pub fn write_exr_with_attributes(
    path: &Path,
    image: &RgbImage,
    white_luminance_cd_m2: Option<f32>,
    attributes: &[(String, ExrAttribute)],
) -> Result<(), VisionError> {
    use exr::prelude::{AttributeValue, Image, SpecificChannels, Text, Vec2, WritableImage};
    let failed = |reason: String| VisionError::SceneRead {
        path: PathBuf::from(path),
        reason: format!("cannot write OpenEXR: {reason}"),
    };
    let text = |s: &str| {
        Some(s)
            .filter(|s| !s.is_empty())
            .and_then(Text::new_or_none)
            .ok_or_else(|| failed(format!("header text {s:?} is empty or not Latin-1")))
    };
    let channels = SpecificChannels::rgb(|Vec2(x, y): Vec2<usize>| {
        let p = image.get(x, y);
        (p[0], p[1], p[2])
    });
    let mut exr_image = Image::from_channels((image.width, image.height), channels);
    let layer = &mut exr_image.layer_data.attributes;
    layer.white_luminance = white_luminance_cd_m2;
    for (name, value) in attributes {
        let value = match value {
            ExrAttribute::Text(t) => AttributeValue::Text(text(t)?),
            ExrAttribute::F64(v) => AttributeValue::F64(*v),
            ExrAttribute::Vec2([x, y]) => AttributeValue::FloatVec2(Vec2(*x, *y)),
        };
        layer.other.insert(text(name)?, value);
    }
    exr_image
        .write()
        .to_file(path)
        .map_err(|e| failed(e.to_string()))
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

/// A validated perspective projection into an equirectangular panorama:
/// a symmetric view from yaw, pitch and horizontal field ([`Self::new`]),
/// or any frustum — an HMD eye's asymmetric field of view and full
/// orientation ([`Self::from_frustum`]).
#[derive(Clone, Copy, Debug)]
pub struct PanoramaView {
    params: ViewParams,
    rotation: Mat3,
    /// Tangents of the frustum's edge angles: left and down are negative
    /// for a frustum around the view axis.
    tan_left: f32,
    tan_right: f32,
    tan_up: f32,
    tan_down: f32,
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
            tan_left: -tan_half_h,
            tan_right: tan_half_h,
            tan_up: tan_half_v,
            tan_down: -tan_half_v,
        })
    }

    /// A view through any frustum: `orientation_xyzw` is the unit
    /// quaternion turning view space (−z forward, +y up, +x right, as
    /// OpenXR's) into the panorama's world; `angles_rad` are the edge
    /// angles left, right, up, down (OpenXR's `XrFovf`: left and down
    /// negative for a frustum around the view axis); `width × height`
    /// pixels. [`Self::params`] then gives the view axis's yaw and pitch
    /// and the horizontal field, for the pipeline's pixel size.
    pub fn from_frustum(
        orientation_xyzw: [f32; 4],
        angles_rad: [f32; 4],
        width: usize,
        height: usize,
    ) -> Result<Self, VisionError> {
        let q = glam::Quat::from_array(orientation_xyzw);
        if !q.is_finite() || (q.length() - 1.0).abs() > 1e-3 {
            return Err(VisionError::invalid(
                "view orientation",
                format!("{orientation_xyzw:?}"),
                "a unit quaternion",
            ));
        }
        let [l, r, u, d] = angles_rad;
        let half_pi = std::f32::consts::FRAC_PI_2 - 1e-3;
        if !(angles_rad
            .iter()
            .all(|a| a.is_finite() && a.abs() < half_pi)
            && l < r
            && d < u)
        {
            return Err(VisionError::invalid(
                "view field",
                format!("{angles_rad:?} rad"),
                "left < right and down < up, each within ±90°",
            ));
        }
        let rotation = Mat3::from_quat(q.normalize());
        let forward = rotation * Vec3::new(0.0, 0.0, -1.0);
        let params = ViewParams {
            yaw_deg: f64::from(forward.x.atan2(-forward.z)).to_degrees(),
            pitch_deg: f64::from(forward.y.clamp(-1.0, 1.0).asin()).to_degrees(),
            hfov_deg: f64::from(r - l).to_degrees(),
            width,
            height,
        };
        params.validate()?;
        Ok(Self {
            params,
            rotation,
            tan_left: l.tan(),
            tan_right: r.tan(),
            tan_up: u.tan(),
            tan_down: d.tan(),
        })
    }

    /// The parameters.
    pub fn params(&self) -> &ViewParams {
        &self.params
    }

    /// Tangents of the view's left, right, up and down edges (left and
    /// down negative for a frustum around its axis): the geometry the
    /// pipeline pools through ([`crate::pipeline::FramePipeline::set_view_frustum`]).
    pub fn frustum_tans(&self) -> [f64; 4] {
        [
            f64::from(self.tan_left),
            f64::from(self.tan_right),
            f64::from(self.tan_up),
            f64::from(self.tan_down),
        ]
    }

    /// World direction through the centre of view pixel (x, y) (pixel units,
    /// may be fractional).
    pub fn direction(&self, x_px: f32, y_px: f32) -> Vec3 {
        let fx = x_px / self.params.width as f32;
        let fy = y_px / self.params.height as f32;
        let sx = self.tan_left + fx * (self.tan_right - self.tan_left);
        let sy = self.tan_up - fy * (self.tan_up - self.tan_down);
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
            (sx - self.tan_left) / (self.tan_right - self.tan_left) * self.params.width as f32,
            (self.tan_up - sy) / (self.tan_up - self.tan_down) * self.params.height as f32,
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

impl PanoramaView {
    /// Renders the view from a scene of any projection (bilinear, from the
    /// pixels inside the scene's field only); view pixels whose direction
    /// falls outside the scene's field are "no data": they are set to
    /// [`NO_DATA_RGB`] and counted. An unknown projection is read as an
    /// equirectangular panorama ([`Self::render`]).
    pub fn render_scene(&self, scene: &Scene, out: &mut RgbImage) -> usize {
        let Some(proj) = scene
            .projection
            .filter(|p| p.kind != ProjectionKind::Equirectangular)
        else {
            self.render(&scene.image, out);
            return 0;
        };
        use rayon::prelude::*;
        let (w, h) = (self.params.width, self.params.height);
        if out.width != w || out.height != h {
            *out = RgbImage::new(w, h);
        }
        out.pixels
            .par_chunks_mut(w)
            .enumerate()
            .map(|(y, row)| {
                let mut missing = 0;
                for (x, px) in row.iter_mut().enumerate() {
                    let d = self.direction(x as f32 + 0.5, y as f32 + 0.5);
                    match sample_projected(&scene.image, &proj, d.as_dvec3()) {
                        Some(v) => *px = v,
                        None => {
                            *px = NO_DATA_RGB;
                            missing += 1;
                        }
                    }
                }
                missing
            })
            .sum()
    }
}

/// The value a view pixel gets where the scene has no data (outside a
/// fisheye's circle or a perspective image's frame): NaN in every channel
/// ([`crate::image::is_no_data`]), never light. The frame pipeline leaves
/// these pixels out of pooling and glare and marks them in its output.
pub const NO_DATA_RGB: [f32; 3] = [f32::NAN; 3];

/// Bilinear sample of a scene image through its projection in a direction
/// (camera frame), from the neighbours inside the field (re-weighted);
/// `None` where the direction is outside the field.
pub fn sample_projected(
    image: &RgbImage,
    proj: &SceneProjection,
    dir: glam::DVec3,
) -> Option<[f32; 3]> {
    let [fx, fy] = proj.pixel(dir)?;
    let (w, h) = (image.width, image.height);
    if w == 0 || h == 0 || w != proj.width_px || h != proj.height_px {
        return None;
    }
    let x = fx - 0.5;
    let y = fy - 0.5;
    let (x0, y0) = (x.floor(), y.floor());
    let (tx, ty) = (x - x0, y - y0);
    let mut acc = [0.0f64; 3];
    let mut wsum = 0.0;
    for (dx, dy, wgt) in [
        (0, 0, (1.0 - tx) * (1.0 - ty)),
        (1, 0, tx * (1.0 - ty)),
        (0, 1, (1.0 - tx) * ty),
        (1, 1, tx * ty),
    ] {
        let (xi, yi) = (x0 as i64 + dx, y0 as i64 + dy);
        if wgt <= 0.0 || xi < 0 || yi < 0 || xi >= w as i64 || yi >= h as i64 {
            continue;
        }
        let (xu, yu) = (xi as usize, yi as usize);
        if proj.pixel_direction(xu, yu).is_none() {
            continue;
        }
        let p = image.get(xu, yu);
        for i in 0..3 {
            acc[i] += wgt * f64::from(p[i]);
        }
        wsum += wgt;
    }
    if wsum <= 0.0 {
        // At the field's edge: the nearest pixel.
        let xu = (fx.floor().max(0.0) as usize).min(w - 1);
        let yu = (fy.floor().max(0.0) as usize).min(h - 1);
        return Some(image.get(xu, yu));
    }
    Some(acc.map(|a| (a / wsum) as f32))
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
        gazelight_test_support::data_path("hdr/blender-world").join(name)
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

    /// A one-channel float EXR (`name` = "Y", "A", "R", ...), ZIP-compressed
    /// by the `exr` crate's defaults.
    fn one_channel_exr(name: &str, w: usize, h: usize, v: f32) -> Vec<u8> {
        use exr::prelude::*;
        let channels = SpecificChannels::build()
            .with_channel::<f32>(name)
            .with_pixel_fn(move |_pos: Vec2<usize>| (v,));
        let image = Image::from_channels((w, h), channels);
        let mut buf = Cursor::new(Vec::new());
        image.write().to_buffered(&mut buf).unwrap();
        buf.into_inner()
    }

    /// A small RGB EXR as the project writes them.
    fn small_rgb_exr(w: usize, h: usize) -> Vec<u8> {
        let dir =
            std::env::temp_dir().join(format!("gazelight-exr-{}-{w}x{h}", std::process::id()));
        std::fs::create_dir_all(&dir).unwrap();
        let path = dir.join("small.exr");
        let img = RgbImage::from_pixels(w, h, vec![[0.5, 1.0, 2.0]; w * h]).unwrap();
        write_exr(&path, &img).unwrap();
        let bytes = std::fs::read(&path).unwrap();
        std::fs::remove_dir_all(&dir).ok();
        bytes
    }

    /// Byte offset of an attribute's value in an EXR header.
    fn attribute_value(bytes: &[u8], name: &str, ty: &str) -> usize {
        let key = [name.as_bytes(), b"\0", ty.as_bytes(), b"\0"].concat();
        let at = bytes.windows(key.len()).position(|w| w == key).unwrap();
        at + key.len() + 4
    }

    #[test]
    fn tiny_exr_claiming_a_huge_image_is_refused_before_allocating() {
        let good = small_rgb_exr(8, 4);
        assert!(good.len() < 1000, "{} bytes", good.len());
        let at = attribute_value(&good, "dataWindow", "box2i");
        for (x1, y1, what) in [
            (99_999i32, 99_999i32, "at most"), // 1e10 pixels: over the cap
            (i32::MAX, i32::MAX, "at most"),   // 4.6e18: would overflow usize math
            (16_383, 8_191, "at least"),       // within the cap, not in 500 bytes
        ] {
            let mut bytes = good.clone();
            bytes[at + 8..at + 12].copy_from_slice(&x1.to_le_bytes());
            bytes[at + 12..at + 16].copy_from_slice(&y1.to_le_bytes());
            let t = std::time::Instant::now();
            let e = Scene::from_bytes(&bytes, Path::new("huge.exr"), LuminanceScale::default())
                .unwrap_err()
                .to_string();
            assert!(t.elapsed().as_secs_f64() < 1.0);
            assert!(e.contains("huge.exr") && e.contains(what), "{e}");
        }
        // A negative window is empty, not a wrap-around.
        let mut bytes = good.clone();
        bytes[at..at + 4].copy_from_slice(&5i32.to_le_bytes());
        bytes[at + 8..at + 12].copy_from_slice(&(-5i32).to_le_bytes());
        let e = Scene::from_bytes(&bytes, Path::new("neg.exr"), LuminanceScale::default())
            .unwrap_err()
            .to_string();
        assert!(e.contains("empty"), "{e}");
        // The untouched file still loads.
        let s = Scene::from_bytes(&good, Path::new("ok.exr"), LuminanceScale::default()).unwrap();
        assert_eq!((s.image.width, s.image.height), (8, 4));
    }

    #[test]
    fn exr_compression_newer_than_the_reader_is_unsupported_not_corrupt() {
        let good = small_rgb_exr(8, 4);
        let at = attribute_value(&good, "compression", "compression");
        for code in [10u8, 11, 12, 200] {
            let mut bytes = good.clone();
            bytes[at] = code;
            let e = Scene::from_bytes(&bytes, Path::new("z.exr"), LuminanceScale::default())
                .unwrap_err()
                .to_string();
            assert!(
                e.contains("unsupported compression") && !e.contains("corrupt"),
                "{code}: {e}"
            );
        }
    }

    #[test]
    fn y_only_exr_is_a_luminance_image_and_a_or_r_only_is_named() {
        let y = one_channel_exr("Y", 16, 8, 3.0);
        let s = Scene::from_bytes(&y, Path::new("y.exr"), LuminanceScale::default()).unwrap();
        assert_eq!((s.image.width, s.image.height), (16, 8));
        assert!(s.image.pixels.iter().all(|p| *p == [3.0, 3.0, 3.0]));
        for name in ["A", "R"] {
            let b = one_channel_exr(name, 16, 8, 1.0);
            let e = Scene::from_bytes(&b, Path::new("x.exr"), LuminanceScale::default())
                .unwrap_err()
                .to_string();
            assert!(
                e.contains(&format!("channels [{name}]")) && e.contains("R, G and B"),
                "{e}"
            );
        }
    }

    /// A Radiance file as Radiance writes it: flat RGBE scan lines.
    fn radiance_file(header: &str, w: usize, h: usize, rgbe: [u8; 4]) -> Vec<u8> {
        let mut b =
            format!("#?RADIANCE\nFORMAT=32-bit_rle_rgbe\n{header}\n-Y {h} +X {w}\n").into_bytes();
        for _ in 0..w * h {
            b.extend_from_slice(&rgbe);
        }
        b
    }

    #[test]
    fn radiance_exposure_is_honoured() {
        // RGBE (128, 128, 128, 129), as Radiance's colr_color reads it:
        // (128 + ½)·2^(129−136) = 128.5/128 = 1.00390625 W/sr/m² per
        // channel (the `image` crate's c·2^(e−136) would give 1.0).
        // Radiance: L = 179 × (0.265+0.670+0.065)·1.00390625 / EXPOSURE
        // = 179.69921875 / EXPOSURE cd/m²; the Rec. 709 weights also sum
        // to 1, so grey reads the same.
        for (header, exposure) in [
            ("", 1.0f32),
            ("EXPOSURE=0.5\n", 0.5),
            ("EXPOSURE=2\nEXPOSURE=0.25\n", 0.5),
        ] {
            let b = radiance_file(header, 8, 4, [128, 128, 128, 129]);
            let s = Scene::from_bytes(&b, Path::new("sky.hdr"), LuminanceScale::default()).unwrap();
            let l = luminance(s.image.get(3, 2));
            let want = 179.699_22 / exposure;
            assert!((l - want).abs() < 1e-5 * want, "{header:?}: {l} vs {want}");
        }
        let b = radiance_file("EXPOSURE=0\n", 8, 4, [128, 128, 128, 129]);
        assert!(Scene::from_bytes(&b, Path::new("z.hdr"), LuminanceScale::default()).is_err());
    }

    #[test]
    fn radiance_claiming_a_huge_image_is_refused() {
        let mut b = radiance_file("", 8, 4, [128, 128, 128, 129]);
        let text = String::from_utf8_lossy(&b).replace("-Y 4 +X 8", "-Y 30000 +X 30000");
        b = text.into_bytes();
        let e = Scene::from_bytes(&b, Path::new("big.hdr"), LuminanceScale::default())
            .unwrap_err()
            .to_string();
        assert!(e.contains("big.hdr") && e.contains("30000"), "{e}");
        let mut b = radiance_file("", 8, 4, [128, 128, 128, 129]);
        let text = String::from_utf8_lossy(&b).replace("-Y 4 +X 8", "-Y 8000 +X 16000");
        b = text.into_bytes();
        let e = Scene::from_bytes(&b, Path::new("big.hdr"), LuminanceScale::default())
            .unwrap_err()
            .to_string();
        assert!(e.contains("truncated"), "{e}");
    }

    #[test]
    fn non_panorama_geometry_is_warned_about() {
        let square = RgbImage::new(64, 64);
        let w = geometry_warning(&square).unwrap();
        assert!(w.contains("64×64") && w.contains("not a 2:1"), "{w}");
        assert!(geometry_warning(&RgbImage::new(1024, 512)).is_none());
    }

    /// A Radiance header's VIEW= (two lines, the later refining the
    /// earlier, as rpict then pfilt write them) gives the projection and
    /// PIXASPECT= is kept; a view type gazelight cannot map is refused by
    /// name; no VIEW= leaves the projection unknown (the 2:1 warning's
    /// case).
    #[test]
    fn radiance_view_header_gives_the_projection() {
        let hdr = "VIEW= -vtv -vp 0 0 1.5 -vd 0 1 0 -vu 0 0 1 -vh 60 -vv 60\n\
                   VIEW= -vta -vh 180 -vv 180\nPIXASPECT=1.0\n";
        let bytes = radiance_file(hdr, 32, 32, [128, 128, 128, 129]);
        let s =
            Scene::from_bytes(&bytes, Path::new("fish.hdr"), LuminanceScale::default()).unwrap();
        let p = s.projection.unwrap();
        assert_eq!(
            (p.kind, p.hfov_deg, p.vfov_deg),
            (ProjectionKind::Angular, 180.0, 180.0)
        );
        assert_eq!(s.radiance_view.unwrap().vp, [0.0, 0.0, 1.5]);
        assert_eq!(s.pixel_aspect, Some(1.0));
        let cyl = radiance_file("VIEW= -vtc -vh 360 -vv 90\n", 16, 8, [128, 128, 128, 129]);
        let e =
            Scene::from_bytes(&cyl, Path::new("cyl.hdr"), LuminanceScale::default()).unwrap_err();
        assert!(e.to_string().contains("-vtc"), "{e}");
        let plain = radiance_file("", 16, 16, [128, 128, 128, 129]);
        let s = Scene::from_bytes(&plain, Path::new("p.hdr"), LuminanceScale::default()).unwrap();
        assert!(s.projection.is_none());
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
        // Radiance's unit is W/sr/m²: 179 lm/W turns it into cd/m².
        let p = s.image.get(3, 1);
        let k = RADIANCE_EFFICACY_LM_PER_W as f32;
        assert!(
            (p[0] - 40.0 * k).abs() < 0.5 * k && (p[1] - 15.0 * k).abs() < 0.2 * k,
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

    /// A frustum view: symmetric with no rotation it is the yaw/pitch view;
    /// an asymmetric field puts its edges at the given angles; a quaternion
    /// turning +90° about +y looks left (yaw −90°).
    #[test]
    fn frustum_views_follow_their_angles_and_orientation() {
        let half = 30f32.to_radians();
        let (w, h) = (64, 48);
        let v_half = (half.tan() * h as f32 / w as f32).atan();
        let f =
            PanoramaView::from_frustum([0.0, 0.0, 0.0, 1.0], [-half, half, v_half, -v_half], w, h)
                .unwrap();
        let p = PanoramaView::new(ViewParams {
            yaw_deg: 0.0,
            pitch_deg: 0.0,
            hfov_deg: 60.0,
            width: w,
            height: h,
        })
        .unwrap();
        for (x, y) in [(0.5, 0.5), (31.5, 20.0), (63.5, 47.5)] {
            assert!((f.direction(x, y) - p.direction(x, y)).length() < 1e-5);
        }
        assert!((f.params().hfov_deg - 60.0).abs() < 1e-4);
        // Asymmetric (an HMD eye: more field on the nasal side).
        let (l, r, u, d) = (-0.8f32, 0.6f32, 0.7f32, -0.75f32);
        let a = PanoramaView::from_frustum([0.0, 0.0, 0.0, 1.0], [l, r, u, d], w, h).unwrap();
        let left_edge = a.direction(0.0, 24.0);
        assert!(
            (left_edge.x.atan2(-left_edge.z) - l).abs() < 1e-4,
            "{left_edge}"
        );
        let top_edge = a.direction(32.0, 0.0);
        assert!(
            (top_edge.y.atan2(-top_edge.z) - u).abs() < 1e-4,
            "{top_edge}"
        );
        let px = a.project(a.direction(10.25, 33.5)).unwrap();
        assert!(
            (px[0] - 10.25).abs() < 1e-3 && (px[1] - 33.5).abs() < 1e-3,
            "{px:?}"
        );
        // +90° about +y: −z turns into −x, the view looks left.
        let s = std::f32::consts::FRAC_1_SQRT_2;
        let left = PanoramaView::from_frustum([0.0, s, 0.0, s], [l, r, u, d], w, h).unwrap();
        assert!(
            (left.params().yaw_deg + 90.0).abs() < 1e-3,
            "{:?}",
            left.params()
        );
        // Bad input is an error naming the field.
        let e = PanoramaView::from_frustum([0.0, 0.0, 0.0, 2.0], [l, r, u, d], w, h).unwrap_err();
        assert!(e.to_string().contains("orientation"), "{e}");
        assert!(PanoramaView::from_frustum([0.0, 0.0, 0.0, 1.0], [r, l, u, d], w, h).is_err());
    }
}
