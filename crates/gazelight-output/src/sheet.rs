//! Files written by `render`: PNG frames and the contact sheet (the plot
//! is [`crate::plot`], the timeline CSV
//! `gazelight_render::timeline::TimelineWriter`).

use std::path::{Path, PathBuf};

use gazelight_render::RenderError;
use gazelight_vision::pipeline::DisplayFrame;
use plotters::prelude::*;

use crate::font::{FontError, register_font};

/// Tiles on the contact sheet (4 columns × 3 rows).
pub const SHEET_TILES: usize = 12;
/// Columns of tiles on the contact sheet.
pub const SHEET_COLUMNS: usize = 4;
/// Longest side of a tile's image, pixels: larger frames are box-filtered
/// down by an integer factor to at most this, smaller ones enlarged by an
/// integer factor (nearest) to at most this.
const SHEET_IMAGE_MAX_PX: usize = 320;
/// Narrowest cell (tile image and its caption), pixels: the caption's
/// lines fit in it at [`SHEET_FONT_MIN_PX`].
pub const SHEET_CELL_MIN_W: usize = 200;
/// Lines of a tile's caption (time; pupil; adaptation).
pub const SHEET_CAPTION_LINES: usize = 3;
/// Height of one caption line, pixels.
const SHEET_LINE_H: usize = 17;
/// Height of a tile's caption band under its image, pixels.
pub const SHEET_CAPTION_H: usize = SHEET_CAPTION_LINES * SHEET_LINE_H + 4;
/// Height of the legend strip at the bottom of the sheet, pixels.
pub const SHEET_LEGEND_H: usize = 28;
/// Margin between a caption's text and its cell's sides, pixels.
pub const SHEET_TEXT_MARGIN_PX: usize = 5;
/// The caption font's size, pixels, and the smallest it shrinks to for a
/// line that would not fit.
const SHEET_FONT_PX: u32 = 14;
const SHEET_FONT_MIN_PX: u32 = 8;

pub use gazelight_render::png::PngCompression;
pub use gazelight_render::timeline::TimelineRow;

/// Writes an RGBA display frame as an RGB PNG, or as an RGBA PNG when
/// the frame has pixels without data (alpha 0, outside the scene's field:
/// `gazelight_vision::pipeline::NO_DATA_RGBA8`), so they stay marked
/// (`gazelight_render::png`, the encoder `gazelight.write_png` shares).
pub fn write_png(
    path: &Path,
    frame: &DisplayFrame,
    compression: PngCompression,
) -> Result<(), RenderError> {
    gazelight_render::png::write(path, frame, compression)
}

/// Why a [`ContactSheet`] was not written.
#[derive(Debug, thiserror::Error)]
pub enum SheetError {
    #[error(transparent)]
    Font(#[from] FontError),
    /// Drawing the captions or the legend failed (plotters' message).
    #[error("drawing the contact sheet: {0}")]
    Draw(String),
    /// Measuring a caption's width failed (plotters' message).
    #[error("measuring a caption: {0}")]
    Measure(String),
    /// The PNG could not be written.
    #[error("cannot write {}", path.display())]
    Write {
        path: PathBuf,
        #[source]
        source: image::ImageError,
    },
}

/// One tile of a [`ContactSheet`].
struct Tile {
    /// The tile image, RGB, `image_w × image_h`.
    pixels: Vec<u8>,
    /// Which of its pixels have no data (more than half of the frame
    /// pixels under them).
    no_data: Vec<bool>,
    /// Gaze points, frame-normalised (`[0, 1]²`, one per view).
    gaze_uv: Vec<[f32; 2]>,
    /// The caption's lines (time, pupil, adaptation).
    caption: Vec<String>,
}

/// Colour of the gaze marker on the contact sheet (saturated green: no
/// rendered night or day pixel has it, so a test can find it).
pub const GAZE_MARKER_RGB: [u8; 3] = [0, 255, 0];

/// A number in engineering notation with three significant digits: plain
/// between 0.01 and 1000 (`0.0116`, `4.00`, `385`), else mantissa `e`
/// exponent with the exponent a multiple of 3 (`3.85e6`, `4.80e-3`);
/// `–` where it is not finite (nothing measured). At most 8 characters.
pub fn engineering(v: f64) -> String {
    if !v.is_finite() {
        return "–".to_owned();
    }
    if v == 0.0 {
        return "0".to_owned();
    }
    // Round to three significant digits first, so 999.6 becomes 1.00e3.
    let exp10 = v.abs().log10().floor() as i32;
    let scale = 10f64.powi(2 - exp10);
    let rounded = match (v * scale).round() / scale {
        r if r.is_finite() && r != 0.0 => r,
        // Subnormal: the scale overflowed.
        _ => v,
    };
    let a = rounded.abs();
    if (0.01..1000.0).contains(&a) {
        let digits = (2 - a.log10().floor() as i32).max(0) as usize;
        return format!("{rounded:.digits$}");
    }
    let exp3 = (a.log10().floor() as i32).div_euclid(3) * 3;
    let mantissa = rounded / 10f64.powi(exp3);
    let digits = (2 - mantissa.abs().log10().floor() as i32).max(0) as usize;
    format!("{mantissa:.digits$}e{exp3}")
}

/// Where a tile lies on a [`ContactSheet`], sheet pixels.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub struct CellRect {
    /// The cell's left and top edge.
    pub x: usize,
    pub y: usize,
    /// The cell's width (at least [`SHEET_CELL_MIN_W`]).
    pub w: usize,
    /// The tile image's left edge (centred in the cell) and size.
    pub image_x: usize,
    pub image_w: usize,
    pub image_h: usize,
    /// The caption band's top edge (under the image); it is
    /// [`SHEET_CAPTION_H`] high and the cell's width.
    pub caption_y: usize,
}

/// A grid of frames scaled to at most 320 px a side (box-filtered down, or
/// enlarged by an integer factor), each with its gaze marked and a caption
/// band under it (time, pupil, adaptation in engineering notation, white
/// on black, sized to fit the cell), and a legend strip at the bottom: the
/// no-data hatch (pixels outside the scene's field, drawn as the PNG
/// frames draw them, `gazelight_render::png::no_data_rgb`) and the gaze
/// marker.
pub struct ContactSheet {
    width: usize,
    height: usize,
    image_w: usize,
    image_h: usize,
    cell_w: usize,
    stereo: bool,
    tiles: Vec<Tile>,
}

impl ContactSheet {
    /// A sheet for frames of `width × height` (`stereo`: left | right).
    pub fn new(width: usize, height: usize, stereo: bool) -> Self {
        let (width, height) = (width.max(1), height.max(1));
        let longest = width.max(height);
        let (image_w, image_h) = if longest > SHEET_IMAGE_MAX_PX {
            let f = longest.div_ceil(SHEET_IMAGE_MAX_PX);
            ((width / f).max(1), (height / f).max(1))
        } else {
            let k = (SHEET_IMAGE_MAX_PX / longest).max(1);
            (width * k, height * k)
        };
        Self {
            width,
            height,
            image_w,
            image_h,
            cell_w: image_w.max(SHEET_CELL_MIN_W),
            stereo,
            tiles: Vec::with_capacity(SHEET_TILES),
        }
    }

    /// Adds a frame (box-filtered down or enlarged; a tile pixel has no
    /// data where more than half of the frame pixels under it have none,
    /// else the mean of those with data) if there is room, with its gaze
    /// points (frame-normalised, one per view) and its caption lines.
    /// A frame of another size than the sheet's is left out.
    pub fn add(&mut self, frame: &DisplayFrame, gaze_uv: &[[f32; 2]], caption: Vec<String>) {
        if self.tiles.len() >= SHEET_TILES
            || frame.width != self.width
            || frame.height != self.height
            || frame.rgba8.len() != frame.width * frame.height * 4
        {
            return;
        }
        let (w, h, tw, th) = (self.width, self.height, self.image_w, self.image_h);
        let span = |t: usize, n: usize, tn: usize| {
            let a = t * n / tn;
            (a, ((t + 1) * n / tn).max(a + 1).min(n))
        };
        let mut pixels = vec![0u8; tw * th * 3];
        let mut no_data = vec![false; tw * th];
        for ty in 0..th {
            let (y0, y1) = span(ty, h, th);
            for tx in 0..tw {
                let (x0, x1) = span(tx, w, tw);
                let (mut acc, mut with, mut without) = ([0u64; 3], 0u64, 0u64);
                for y in y0..y1 {
                    for p in frame.rgba8[(y * w + x0) * 4..(y * w + x1) * 4].chunks_exact(4) {
                        if p[3] == 255 {
                            for (a, v) in acc.iter_mut().zip(&p[..3]) {
                                *a += u64::from(*v);
                            }
                            with += 1;
                        } else {
                            without += 1;
                        }
                    }
                }
                let i = ty * tw + tx;
                if without > with {
                    no_data[i] = true;
                } else {
                    for c in 0..3 {
                        pixels[i * 3 + c] = (acc[c] / with.max(1)) as u8;
                    }
                }
            }
        }
        self.tiles.push(Tile {
            pixels,
            no_data,
            gaze_uv: gaze_uv.to_vec(),
            caption,
        });
    }

    /// Where tile `i` lies on the sheet.
    pub fn cell(&self, i: usize) -> CellRect {
        let cell_h = self.image_h + SHEET_CAPTION_H;
        let (x, y) = (
            (i % SHEET_COLUMNS) * self.cell_w,
            (i / SHEET_COLUMNS) * cell_h,
        );
        CellRect {
            x,
            y,
            w: self.cell_w,
            image_x: x + (self.cell_w - self.image_w) / 2,
            image_w: self.image_w,
            image_h: self.image_h,
            caption_y: y + self.image_h,
        }
    }

    /// The sheet's size, pixels: [`SHEET_COLUMNS`] cells across, as many
    /// rows as the tiles need, and the legend strip.
    pub fn size(&self) -> (usize, usize) {
        let rows = self.tiles.len().div_ceil(SHEET_COLUMNS).max(1);
        (
            self.cell_w * SHEET_COLUMNS,
            rows * (self.image_h + SHEET_CAPTION_H) + SHEET_LEGEND_H,
        )
    }

    /// The pixel (sheet coordinates) of tile `i`'s gaze point `uv`, if it
    /// is inside the tile.
    pub fn gaze_pixel(&self, i: usize, uv: [f32; 2]) -> Option<(usize, usize)> {
        let (u, v) = (f64::from(uv[0]), f64::from(uv[1]));
        if !(0.0..1.0).contains(&u) || !(0.0..1.0).contains(&v) {
            return None;
        }
        let c = self.cell(i);
        Some((
            c.image_x + (u * c.image_w as f64) as usize,
            c.y + (v * c.image_h as f64) as usize,
        ))
    }

    /// Writes the sheet.
    pub fn write(&self, path: &Path) -> Result<(), SheetError> {
        use gazelight_render::png::no_data_rgb;
        let (w, h) = self.size();
        let mut buf = vec![0u8; w * h * 3];
        let put = |buf: &mut [u8], x: usize, y: usize, rgb: [u8; 3]| {
            if x < w && y < h {
                buf[(y * w + x) * 3..(y * w + x) * 3 + 3].copy_from_slice(&rgb);
            }
        };
        for (i, tile) in self.tiles.iter().enumerate() {
            let c = self.cell(i);
            for ty in 0..c.image_h {
                for tx in 0..c.image_w {
                    let k = ty * c.image_w + tx;
                    let (x, y) = (c.image_x + tx, c.y + ty);
                    let rgb = if tile.no_data[k] {
                        no_data_rgb(x, y)
                    } else {
                        [
                            tile.pixels[k * 3],
                            tile.pixels[k * 3 + 1],
                            tile.pixels[k * 3 + 2],
                        ]
                    };
                    put(&mut buf, x, y, rgb);
                }
            }
            // The gaze marker: a cross with a gap at its centre, 2 px
            // wide, clipped to the tile image.
            for &uv in &tile.gaze_uv {
                let Some((gx, gy)) = self.gaze_pixel(i, uv) else {
                    continue;
                };
                let inside = |x: i64, y: i64| {
                    x >= c.image_x as i64
                        && x < (c.image_x + c.image_w) as i64
                        && y >= c.y as i64
                        && y < (c.y + c.image_h) as i64
                };
                for d in 2i64..=7 {
                    for t in 0i64..2 {
                        let (gx, gy) = (gx as i64, gy as i64);
                        for (x, y) in [
                            (gx - d, gy + t),
                            (gx + d, gy + t),
                            (gx + t, gy - d),
                            (gx + t, gy + d),
                        ] {
                            if inside(x, y) {
                                put(&mut buf, x as usize, y as usize, GAZE_MARKER_RGB);
                            }
                        }
                    }
                }
            }
        }
        // The legend's no-data swatch, hatched in place.
        let legend_y = h - SHEET_LEGEND_H;
        let swatch = (8usize, legend_y + 6, 28usize, 16usize);
        for y in swatch.1..swatch.1 + swatch.3 {
            for x in swatch.0..swatch.0 + swatch.2 {
                put(&mut buf, x, y, no_data_rgb(x, y));
            }
        }
        register_font()?;
        {
            let root =
                BitMapBackend::with_buffer(&mut buf, (w as u32, h as u32)).into_drawing_area();
            let err = |e| SheetError::Draw(format!("{e}"));
            let room = self.cell_w.saturating_sub(2 * SHEET_TEXT_MARGIN_PX) as u32;
            for (i, tile) in self.tiles.iter().enumerate() {
                let c = self.cell(i);
                for (l, line) in tile.caption.iter().take(SHEET_CAPTION_LINES).enumerate() {
                    let style = fitting_font(&root, line, room)?;
                    root.draw_text(
                        line,
                        &style,
                        (
                            (c.x + SHEET_TEXT_MARGIN_PX) as i32,
                            (c.caption_y + 2 + l * SHEET_LINE_H) as i32,
                        ),
                    )
                    .map_err(err)?;
                }
            }
            let style = ("sans-serif", SHEET_FONT_PX).into_font().color(&WHITE);
            let text_y = (legend_y + 7) as i32;
            let after_swatch = (swatch.0 + swatch.2 + 6) as i32;
            let no_data = "no data (outside the scene's field)";
            root.draw_text(no_data, &style, (after_swatch, text_y))
                .map_err(err)?;
            let (tw, _) = root.estimate_text_size(no_data, &style).map_err(err)?;
            let marker_x = after_swatch + tw as i32 + 24;
            let cy = (legend_y + SHEET_LEGEND_H / 2) as i32;
            let [r, g, b] = GAZE_MARKER_RGB;
            let marker = RGBColor(r, g, b);
            for (a, b) in [
                ((marker_x - 7, cy), (marker_x - 2, cy)),
                ((marker_x + 2, cy), (marker_x + 7, cy)),
                ((marker_x, cy - 7), (marker_x, cy - 2)),
                ((marker_x, cy + 2), (marker_x, cy + 7)),
            ] {
                root.draw(&PathElement::new(vec![a, b], marker.stroke_width(2)))
                    .map_err(err)?;
            }
            let gaze = if self.stereo {
                "gaze; tiles and captions left | right eye"
            } else {
                "gaze"
            };
            root.draw_text(gaze, &style, (marker_x + 14, text_y))
                .map_err(err)?;
            root.present().map_err(err)?;
        }
        image::save_buffer(path, &buf, w as u32, h as u32, image::ColorType::Rgb8).map_err(
            |source| SheetError::Write {
                path: path.to_owned(),
                source,
            },
        )
    }
}

/// The caption style for `text`: white, [`SHEET_FONT_PX`], or smaller
/// (down to [`SHEET_FONT_MIN_PX`]) until it is at most `room_px` wide.
fn fitting_font<'a>(
    root: &DrawingArea<BitMapBackend<'_>, plotters::coord::Shift>,
    text: &str,
    room_px: u32,
) -> Result<TextStyle<'a>, SheetError> {
    let mut px = SHEET_FONT_PX;
    loop {
        let style = ("sans-serif", px).into_font().color(&WHITE);
        let (w, _) = root
            .estimate_text_size(text, &style)
            .map_err(|e| SheetError::Measure(e.to_string()))?;
        if w <= room_px || px <= SHEET_FONT_MIN_PX {
            return Ok(style);
        }
        px -= 1;
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    /// Engineering notation, against values written out by hand.
    #[test]
    fn engineering_notation() {
        for (v, want) in [
            (3_849_734.405, "3.85e6"),
            (0.0048, "4.80e-3"),
            (-0.0048, "-4.80e-3"),
            (0.011_61, "0.0116"),
            (4.0, "4.00"),
            (385.2, "385"),
            (999.6, "1.00e3"),
            (12_345.0, "12.3e3"),
            (1e-9, "1.00e-9"),
            (1e-300, "1.00e-300"),
            (0.0, "0"),
            (f64::NAN, "–"),
        ] {
            assert_eq!(engineering(v), want, "{v}");
        }
    }

    /// The widest captions fit their cells at the smallest and largest
    /// sizes `--size` accepts (8–8192 px a side), mono and stereo, and the
    /// extreme aspect ratios: in the written sheet every caption line has
    /// text pixels, and none lies in the outer 2 px columns of its cell
    /// (text cut off at the cell's edge, or spilling into the next cell,
    /// would).
    #[test]
    fn captions_fit_their_tiles_at_every_accepted_size() {
        let widest = |stereo: bool| {
            let v = engineering(-888e-12);
            let two = if stereo {
                format!("{v} | {v}")
            } else {
                v.clone()
            };
            vec![
                format!("t = {:.2} s", 30.0 * 86_400.0),
                format!("pupil {two} mm"),
                format!("adapt. {two} cd/m²"),
            ]
        };
        for (w, h, stereo, tiles) in [
            (8, 8, false, 12),
            (8, 8, true, 12),
            (8192, 8192, false, 4),
            (8192, 8192, true, 4),
            (8192, 8, true, 12),
            (8, 8192, true, 12),
        ] {
            let fw = if stereo { 2 * w } else { w };
            let frame = DisplayFrame::new(fw, h);
            let mut sheet = ContactSheet::new(fw, h, stereo);
            for _ in 0..tiles {
                sheet.add(&frame, &[[0.5, 0.5]], widest(stereo));
            }
            let path = std::env::temp_dir().join(format!(
                "gazelight-sheet-{}-{w}x{h}-{stereo}.png",
                std::process::id()
            ));
            sheet.write(&path).unwrap();
            let img = image::open(&path).unwrap().to_rgb8();
            let _ = std::fs::remove_file(&path);
            let (sw, sh) = sheet.size();
            assert_eq!(img.dimensions(), (sw as u32, sh as u32));
            let text = |x: usize, y: usize| img.get_pixel(x as u32, y as u32).0[0] >= 100;
            for i in 0..tiles {
                let c = sheet.cell(i);
                for line in 0..SHEET_CAPTION_LINES {
                    let rows = c.caption_y + line * SHEET_LINE_H
                        ..c.caption_y + (line + 1) * SHEET_LINE_H + 4;
                    let xs: Vec<usize> = rows
                        .clone()
                        .flat_map(|y| (c.x..c.x + c.w).filter(move |&x| text(x, y)))
                        .collect();
                    let (lo, hi) = (xs.iter().min(), xs.iter().max());
                    let (Some(&lo), Some(&hi)) = (lo, hi) else {
                        panic!("{w}x{h} stereo {stereo} tile {i} line {line}: no text");
                    };
                    assert!(
                        lo >= c.x + 2 && hi + 2 < c.x + c.w,
                        "{w}x{h} stereo {stereo} tile {i} line {line}: text x {lo}..={hi}, cell {}..{}",
                        c.x,
                        c.x + c.w
                    );
                }
            }
        }
    }

    /// A frame whose right half has no data: those tile pixels are the
    /// hatch at their sheet coordinates (stripe [120, 0, 120] where
    /// (x + y) mod 8 < 2, else [28, 28, 28], as docs/lighting-research.md
    /// says), the left half keeps the frame's colour, and the legend's
    /// swatch shows both hatch colours.
    #[test]
    fn no_data_is_hatched_on_the_sheet_and_in_its_legend() {
        let (w, h) = (64, 32);
        let mut frame = DisplayFrame::new(w, h);
        for y in 0..h {
            for x in 0..w {
                let px = if x < w / 2 {
                    [90, 140, 60, 255]
                } else {
                    [0, 0, 0, 0]
                };
                frame.rgba8[(y * w + x) * 4..(y * w + x + 1) * 4].copy_from_slice(&px);
            }
        }
        let mut sheet = ContactSheet::new(w, h, false);
        sheet.add(&frame, &[], vec!["t = 0.00 s".into()]);
        let path =
            std::env::temp_dir().join(format!("gazelight-sheet-hatch-{}.png", std::process::id()));
        sheet.write(&path).unwrap();
        let img = image::open(&path).unwrap().to_rgb8();
        let _ = std::fs::remove_file(&path);
        let c = sheet.cell(0);
        assert_eq!((c.image_w, c.image_h), (320, 160));
        let (mut stripes, mut grey) = (0, 0);
        for y in c.y..c.y + c.image_h {
            for x in c.image_x..c.image_x + c.image_w {
                let got = img.get_pixel(x as u32, y as u32).0;
                if x < c.image_x + c.image_w / 2 {
                    assert_eq!(got, [90, 140, 60], "({x}, {y})");
                } else if (x + y) % 8 < 2 {
                    assert_eq!(got, [120, 0, 120], "({x}, {y})");
                    stripes += 1;
                } else {
                    assert_eq!(got, [28, 28, 28], "({x}, {y})");
                    grey += 1;
                }
            }
        }
        assert!(stripes > 1000 && grey > 4000);
        let (_, sh) = sheet.size();
        let legend: Vec<[u8; 3]> = (sh - SHEET_LEGEND_H..sh)
            .flat_map(|y| (0..60).map(move |x| (x, y)))
            .map(|(x, y)| img.get_pixel(x as u32, y as u32).0)
            .collect();
        let count = |rgb: [u8; 3]| legend.iter().filter(|p| **p == rgb).count();
        assert!(count([120, 0, 120]) >= 60 && count([28, 28, 28]) >= 200);
    }
}
