//! The PNG encoding of display frames: the bytes `gazelight render` and
//! `replay` write as `frames/frame_NNNNN.png`, and `gazelight.write_png`.
//!
//! Pixels without data (outside the scene's field: NaN in the view,
//! [`gazelight_vision::image::is_no_data`], alpha 0 in the display frame,
//! `gazelight_vision::pipeline::NO_DATA_RGBA8`) are drawn as an opaque
//! **dark hatch** by default ([`NoDataStyle::Hatch`]): dark grey
//! ([`NO_DATA_HATCH_BACKGROUND_RGB`]) with dark magenta diagonal stripes
//! ([`NO_DATA_HATCH_STRIPE_RGB`]), something no one can take for light —
//! an image viewer shows a transparent pixel as white or a checkerboard,
//! which reads as a blown-out wall. The contact sheet draws them the same
//! way ([`no_data_rgb`]) and says so in its legend. The alpha channel is
//! kept only where asked for ([`NoDataStyle::Transparent`], the CLI's
//! `--no-data-alpha`).

use std::io::Write;
use std::path::Path;

use gazelight_vision::pipeline::DisplayFrame;

use crate::RenderError;

/// How hard [`encode`] compresses.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum PngCompression {
    /// zlib's default level: smaller files, slower (offline `render`,
    /// where time is not pressing).
    Default,
    /// fdeflate (the `png` crate's fast mode): for frames written during a
    /// live session, where the encoder shares the CPU with the frame loop.
    Fast,
}

/// The hatch's dark grey, sRGB codes.
pub const NO_DATA_HATCH_BACKGROUND_RGB: [u8; 3] = [28, 28, 28];
/// The hatch's stripes: dark magenta, a hue no rendered scene pixel near
/// it has (the scotopic shift pulls night pixels towards blue), sRGB codes.
pub const NO_DATA_HATCH_STRIPE_RGB: [u8; 3] = [120, 0, 120];
/// The hatch's period along each image axis, pixels: a stripe runs along
/// every anti-diagonal `x + y ≡ 0, 1 (mod 8)`.
pub const NO_DATA_HATCH_PERIOD_PX: usize = 8;
/// The stripes' width along an image axis, pixels.
pub const NO_DATA_HATCH_STRIPE_PX: usize = 2;

/// The colour of a pixel without data at image pixel `(x, y)`: the stripe
/// colour where `(x + y) mod 8 < 2`, the dark grey elsewhere.
pub fn no_data_rgb(x: usize, y: usize) -> [u8; 3] {
    if (x + y) % NO_DATA_HATCH_PERIOD_PX < NO_DATA_HATCH_STRIPE_PX {
        NO_DATA_HATCH_STRIPE_RGB
    } else {
        NO_DATA_HATCH_BACKGROUND_RGB
    }
}

/// How a PNG frame shows the pixels without data (alpha ≠ 255 in the
/// display frame).
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq)]
pub enum NoDataStyle {
    /// An opaque RGB PNG with the dark hatch ([`no_data_rgb`]) there.
    #[default]
    Hatch,
    /// An RGBA PNG with alpha 0 there (only when the frame has such
    /// pixels; an RGB PNG otherwise), for compositing.
    Transparent,
}

/// Encodes an RGBA display frame (`width × height × 4` bytes, row-major)
/// as an RGB PNG with the pixels without data (alpha ≠ 255) hatched
/// ([`NoDataStyle::Hatch`]). Fails when `rgba8` is not `width × height ×
/// 4` bytes.
pub fn encode(
    rgba8: &[u8],
    width: usize,
    height: usize,
    compression: PngCompression,
    out: &mut impl Write,
) -> Result<(), image::ImageError> {
    encode_styled(rgba8, width, height, compression, NoDataStyle::Hatch, out)
}

/// [`encode`] with the pixels without data drawn as `style` says.
pub fn encode_styled(
    rgba8: &[u8],
    width: usize,
    height: usize,
    compression: PngCompression,
    style: NoDataStyle,
    out: &mut impl Write,
) -> Result<(), image::ImageError> {
    use image::ImageEncoder;
    use image::codecs::png::{CompressionType, FilterType, PngEncoder};
    use image::error::{ParameterError, ParameterErrorKind};
    let (w, h) = match (u32::try_from(width), u32::try_from(height)) {
        (Ok(w), Ok(h))
            if width.checked_mul(height).and_then(|n| n.checked_mul(4)) == Some(rgba8.len()) =>
        {
            (w, h)
        }
        _ => {
            return Err(image::ImageError::Parameter(ParameterError::from_kind(
                ParameterErrorKind::DimensionMismatch,
            )));
        }
    };
    let marked = rgba8.chunks_exact(4).any(|p| p[3] != 255);
    let (rgb, colour): (std::borrow::Cow<'_, [u8]>, _) =
        if marked && style == NoDataStyle::Transparent {
            (rgba8.into(), image::ExtendedColorType::Rgba8)
        } else {
            (
                rgba8
                    .chunks_exact(4)
                    .enumerate()
                    .flat_map(|(i, p)| {
                        if p[3] == 255 {
                            [p[0], p[1], p[2]]
                        } else {
                            no_data_rgb(i % width, i / width)
                        }
                    })
                    .collect::<Vec<u8>>()
                    .into(),
                image::ExtendedColorType::Rgb8,
            )
        };
    let kind = match compression {
        PngCompression::Default => CompressionType::Default,
        PngCompression::Fast => CompressionType::Fast,
    };
    PngEncoder::new_with_quality(out, kind, FilterType::Adaptive).write_image(&rgb, w, h, colour)
}

/// Writes a display frame to `path` ([`encode`]: no data hatched).
pub fn write(
    path: &Path,
    frame: &DisplayFrame,
    compression: PngCompression,
) -> Result<(), RenderError> {
    write_styled(path, frame, compression, NoDataStyle::Hatch)
}

/// Writes a display frame to `path` with the pixels without data drawn as
/// `style` says ([`encode_styled`]).
pub fn write_styled(
    path: &Path,
    frame: &DisplayFrame,
    compression: PngCompression,
    style: NoDataStyle,
) -> Result<(), RenderError> {
    write_rgba8_styled(
        path,
        &frame.rgba8,
        frame.width,
        frame.height,
        compression,
        style,
    )
}

/// Writes `width × height` RGBA bytes to `path` as a PNG ([`encode`]: no
/// data hatched).
pub fn write_rgba8(
    path: &Path,
    rgba8: &[u8],
    width: usize,
    height: usize,
    compression: PngCompression,
) -> Result<(), RenderError> {
    write_rgba8_styled(path, rgba8, width, height, compression, NoDataStyle::Hatch)
}

/// [`write_rgba8`] with the pixels without data drawn as `style` says.
pub fn write_rgba8_styled(
    path: &Path,
    rgba8: &[u8],
    width: usize,
    height: usize,
    compression: PngCompression,
    style: NoDataStyle,
) -> Result<(), RenderError> {
    let failed = |reason: String| RenderError::Write {
        path: path.display().to_string(),
        reason,
    };
    let file = std::fs::File::create(path).map_err(|e| failed(e.to_string()))?;
    let mut w = std::io::BufWriter::new(file);
    encode_styled(rgba8, width, height, compression, style, &mut w)
        .map_err(|e| failed(e.to_string()))?;
    w.flush().map_err(|e| failed(e.to_string()))
}

#[cfg(test)]
mod tests {
    use super::*;

    /// Decodes a PNG into (RGBA bytes, whether it has alpha).
    fn decode(bytes: &[u8]) -> (Vec<u8>, bool) {
        let img = image::load_from_memory(bytes).expect("a PNG");
        let alpha = img.color().has_alpha();
        (img.to_rgba8().into_raw(), alpha)
    }

    /// A 16 × 4 frame whose right half has no data: hatched by default
    /// (opaque RGB; stripes where (x + y) mod 8 < 2, written out here by
    /// hand), alpha 0 there when asked for, and a frame without such
    /// pixels the same either way.
    #[test]
    fn no_data_is_an_opaque_dark_hatch_unless_alpha_is_asked_for() {
        let (w, h) = (16usize, 4usize);
        let mut rgba = vec![0u8; w * h * 4];
        for y in 0..h {
            for x in 0..w / 2 {
                rgba[(y * w + x) * 4..(y * w + x + 1) * 4].copy_from_slice(&[200, 100, 50, 255]);
            }
        }
        let mut png = Vec::new();
        encode(&rgba, w, h, PngCompression::Fast, &mut png).unwrap();
        let (px, alpha) = decode(&png);
        assert!(!alpha, "hatched frames are RGB");
        let stripe = [120, 0, 120, 255];
        let grey = [28, 28, 28, 255];
        for y in 0..h {
            for x in 0..w {
                let got = &px[(y * w + x) * 4..(y * w + x + 1) * 4];
                let want: [u8; 4] = if x < w / 2 {
                    [200, 100, 50, 255]
                } else if [0, 1, 8, 9, 16, 17].contains(&(x + y)) {
                    stripe
                } else {
                    grey
                };
                assert_eq!(got, want, "pixel ({x}, {y})");
            }
        }
        let mut png = Vec::new();
        encode_styled(
            &rgba,
            w,
            h,
            PngCompression::Fast,
            NoDataStyle::Transparent,
            &mut png,
        )
        .unwrap();
        let (px, alpha) = decode(&png);
        assert!(alpha);
        assert_eq!(px, rgba);
        // Without pixels lacking data: RGB either way.
        let opaque: Vec<u8> = (0..w * h).flat_map(|_| [1, 2, 3, 255]).collect();
        let mut png = Vec::new();
        encode_styled(
            &opaque,
            w,
            h,
            PngCompression::Fast,
            NoDataStyle::Transparent,
            &mut png,
        )
        .unwrap();
        let (px, alpha) = decode(&png);
        assert!(!alpha);
        assert_eq!(px, opaque);
    }
}
