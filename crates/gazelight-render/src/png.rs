//! The PNG encoding of display frames: the bytes `gazelight render` and
//! `replay` write as `frames/frame_NNNNN.png`, and `gazelight.write_png`.

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

/// Encodes an RGBA display frame (`width × height × 4` bytes, row-major)
/// as an RGB PNG, or as an RGBA PNG when the frame has pixels without data
/// (alpha ≠ 255: outside the scene's field,
/// `gazelight_vision::pipeline::NO_DATA_RGBA8`), so they stay marked.
/// Fails when `rgba8` is not `width × height × 4` bytes.
pub fn encode(
    rgba8: &[u8],
    width: usize,
    height: usize,
    compression: PngCompression,
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
    let (rgb, colour): (std::borrow::Cow<'_, [u8]>, _) = if marked {
        (rgba8.into(), image::ExtendedColorType::Rgba8)
    } else {
        (
            rgba8
                .chunks_exact(4)
                .flat_map(|p| [p[0], p[1], p[2]])
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

/// Writes a display frame to `path` ([`encode`]).
pub fn write(
    path: &Path,
    frame: &DisplayFrame,
    compression: PngCompression,
) -> Result<(), RenderError> {
    write_rgba8(path, &frame.rgba8, frame.width, frame.height, compression)
}

/// Writes `width × height` RGBA bytes to `path` as a PNG ([`encode`]).
pub fn write_rgba8(
    path: &Path,
    rgba8: &[u8],
    width: usize,
    height: usize,
    compression: PngCompression,
) -> Result<(), RenderError> {
    let failed = |reason: String| RenderError::Write {
        path: path.display().to_string(),
        reason,
    };
    let file = std::fs::File::create(path).map_err(|e| failed(e.to_string()))?;
    let mut w = std::io::BufWriter::new(file);
    encode(rgba8, width, height, compression, &mut w).map_err(|e| failed(e.to_string()))?;
    w.flush().map_err(|e| failed(e.to_string()))
}
