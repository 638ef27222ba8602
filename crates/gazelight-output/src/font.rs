//! The one font of gazelight's charts and contact sheets, registered with
//! plotters (ab_glyph) as `sans-serif`.

use plotters::style::FontStyle;

/// The font for plots and labels (DejaVu Sans, licence in `assets/`).
const FONT: &[u8] = include_bytes!("../../../assets/DejaVuSans.ttf");

/// The embedded font could not be registered.
#[derive(Debug, thiserror::Error)]
#[error("the embedded font is invalid")]
pub struct FontError;

/// Registers the embedded font as plotters' `sans-serif` (normal style);
/// call it before drawing text.
pub fn register_font() -> Result<(), FontError> {
    plotters::style::register_font("sans-serif", FontStyle::Normal, FONT).map_err(|_| FontError)
}
