//! Files written by `render`: PNG frames, the contact sheet and the plot
//! (the timeline CSV is `gazelight_render::timeline::TimelineWriter`).

use std::path::Path;

use anyhow::Context;
use gazelight_vision::pipeline::DisplayFrame;
use plotters::prelude::*;

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

/// The font for plots and labels (DejaVu Sans, licence in `assets/`).
const FONT: &[u8] = include_bytes!("../../../assets/DejaVuSans.ttf");

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
) -> anyhow::Result<()> {
    Ok(gazelight_render::png::write(path, frame, compression)?)
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
    pub fn write(&self, path: &Path) -> anyhow::Result<()> {
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
            let err = |e| anyhow::anyhow!("drawing the contact sheet: {e}");
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
        image::save_buffer(path, &buf, w as u32, h as u32, image::ColorType::Rgb8)
            .with_context(|| format!("cannot write {}", path.display()))
    }
}

/// The caption style for `text`: white, [`SHEET_FONT_PX`], or smaller
/// (down to [`SHEET_FONT_MIN_PX`]) until it is at most `room_px` wide.
fn fitting_font<'a>(
    root: &DrawingArea<BitMapBackend<'_>, plotters::coord::Shift>,
    text: &str,
    room_px: u32,
) -> anyhow::Result<TextStyle<'a>> {
    let mut px = SHEET_FONT_PX;
    loop {
        let style = ("sans-serif", px).into_font().color(&WHITE);
        let (w, _) = root
            .estimate_text_size(text, &style)
            .map_err(|e| anyhow::anyhow!("measuring a caption: {e}"))?;
        if w <= room_px || px <= SHEET_FONT_MIN_PX {
            return Ok(style);
        }
        px -= 1;
    }
}

pub(crate) fn register_font() -> anyhow::Result<()> {
    plotters::style::register_font("sans-serif", FontStyle::Normal, FONT)
        .map_err(|_| anyhow::anyhow!("the embedded font is invalid"))
}

/// The pupil axis of `plot.png`, mm: the range of the measured pupils and
/// the PSF pupils, padded by a tenth of it on each side (at least 0.25
/// mm), never below 0; 0–9 mm when nothing was measured.
pub fn pupil_axis_mm(views: &[(&str, &[TimelineRow])]) -> (f64, f64) {
    let (lo, hi) = views
        .iter()
        .flat_map(|(_, rows)| rows.iter())
        .flat_map(|r| [f64::from(r.pupil_mm), r.stats.psf_pupil_mm])
        .filter(|v| v.is_finite())
        .fold((f64::INFINITY, f64::NEG_INFINITY), |(a, b), v| {
            (a.min(v), b.max(v))
        });
    if !lo.is_finite() {
        return (0.0, 9.0);
    }
    let pad = ((hi - lo) * 0.1).max(0.25);
    ((lo - pad).max(0.0), hi + pad)
}

/// Writes the plot of adaptation luminance (log) and pupil over time, one
/// set of lines per view (labelled by its suffix in stereo; the right eye
/// dashed), each chart with a legend. The pupil axis fits the data
/// ([`pupil_axis_mm`]); the model's pupil range (`model_range_mm`, the
/// glare PSF's clamp) is drawn as dotted lines where it falls on the axis
/// and named in the legend. Wide lines under narrow ones: the adaptation
/// under the pooled target, the PSF pupil under the measured pupil, so
/// each stays visible where they agree.
pub fn write_plot(
    path: &Path,
    views: &[(&str, &[TimelineRow])],
    model_range_mm: [f64; 2],
) -> anyhow::Result<()> {
    register_font()?;
    let draw = |buf: &mut [u8], size: (u32, u32)| -> Result<(), Box<dyn std::error::Error>> {
        let root = BitMapBackend::with_buffer(buf, size).into_drawing_area();
        root.fill(&WHITE)?;
        let (top, bottom) = root.split_vertically(340);
        let all = || views.iter().flat_map(|(_, rows)| rows.iter());
        let t_max = all().map(|r| r.t_secs).fold(1e-3, f64::max);
        let log = |v: f64| v.max(1e-6).log10();
        let lums = all().flat_map(|r| [log(r.stats.target_cd_m2), log(r.stats.adaptation_cd_m2)]);
        let (lo, hi) = lums.fold((f64::INFINITY, f64::NEG_INFINITY), |(a, b), v| {
            (a.min(v), b.max(v))
        });
        let (lo, hi) = if lo.is_finite() {
            (lo.floor() - 0.25, hi.ceil() + 0.25)
        } else {
            (-3.0, 3.0)
        };
        let mut chart = ChartBuilder::on(&top)
            .caption("adaptation luminance", ("sans-serif", 20))
            .margin(10)
            .x_label_area_size(30)
            .y_label_area_size(70)
            .build_cartesian_2d(0.0..t_max, lo..hi)?;
        chart
            .configure_mesh()
            .x_desc("t (s)")
            .y_desc("log10 cd/m²")
            .draw()?;
        for (k, (suffix, rows)) in views.iter().enumerate() {
            let eye = suffix.replace('_', " ");
            let dashed = k > 0;
            let [target, adaptation, _, _] = eye_colours(k, views.len());
            chart
                .draw_series(line(
                    rows.iter()
                        .map(|r| (r.t_secs, log(r.stats.adaptation_cd_m2))),
                    adaptation.stroke_width(4),
                    dashed,
                ))?
                .label(format!("adaptation{eye}"))
                .legend(move |(x, y)| {
                    PathElement::new(vec![(x, y), (x + 20, y)], adaptation.stroke_width(4))
                });
            chart
                .draw_series(line(
                    rows.iter().map(|r| (r.t_secs, log(r.stats.target_cd_m2))),
                    target.stroke_width(1),
                    dashed,
                ))?
                .label(format!("pooled target{eye}"))
                .legend(move |(x, y)| PathElement::new(vec![(x, y), (x + 20, y)], target));
        }
        chart
            .configure_series_labels()
            .background_style(WHITE.mix(0.8))
            .border_style(BLACK)
            .draw()?;
        let (p_lo, p_hi) = pupil_axis_mm(views);
        let mut chart = ChartBuilder::on(&bottom)
            .caption("pupil", ("sans-serif", 20))
            .margin(10)
            .x_label_area_size(30)
            .y_label_area_size(70)
            .build_cartesian_2d(0.0..t_max, p_lo..p_hi)?;
        chart.configure_mesh().x_desc("t (s)").y_desc("mm").draw()?;
        // The model's pupil range: dotted where it is on the axis.
        let [m_lo, m_hi] = model_range_mm;
        let on_axis: Vec<f64> = [m_lo, m_hi]
            .into_iter()
            .filter(|v| (p_lo..=p_hi).contains(v))
            .collect();
        let range_colour = RGBColor(150, 0, 150);
        let range_label = format!(
            "model's pupil range {m_lo} – {m_hi} mm{}",
            match on_axis.len() {
                2 => "",
                1 => " (one end beyond the axis)",
                _ => " (beyond the axis)",
            }
        );
        chart
            .draw_series(on_axis.iter().flat_map(|&v| {
                let steps = 120;
                (0..steps).step_by(2).map(move |j| {
                    let (a, b) = (
                        t_max * j as f64 / steps as f64,
                        t_max * (j + 1) as f64 / steps as f64,
                    );
                    PathElement::new(vec![(a, v), (b, v)], range_colour.stroke_width(2))
                })
            }))?
            .label(range_label)
            .legend(move |(x, y)| {
                PathElement::new(vec![(x, y), (x + 20, y)], range_colour.stroke_width(2))
            });
        // Held pupils (blinks, dropouts) of the first view as grey bands.
        if let Some((_, rows)) = views.first() {
            let mut bands = Vec::new();
            let mut start = None;
            for w in rows.windows(2) {
                match (start, w[0].pupil_held.unwrap_or(false)) {
                    (None, true) => start = Some(w[0].t_secs),
                    (Some(t), false) => {
                        bands.push((t, w[0].t_secs));
                        start = None;
                    }
                    _ => {}
                }
            }
            if let (Some(t), Some(last)) = (start, rows.last()) {
                bands.push((t, last.t_secs));
            }
            let grey = RGBColor(200, 200, 200);
            chart
                .draw_series(bands.iter().map(|&(a, b)| {
                    Rectangle::new([(a, p_lo), (b.max(a + 1e-3), p_hi)], grey.mix(0.6).filled())
                }))?
                .label("pupil held (blink, dropout)")
                .legend(move |(x, y)| Rectangle::new([(x, y - 4), (x + 20, y + 4)], grey.filled()));
        }
        for (k, (suffix, rows)) in views.iter().enumerate() {
            let eye = suffix.replace('_', " ");
            let dashed = k > 0;
            let [_, _, pupil, psf] = eye_colours(k, views.len());
            chart
                .draw_series(line(
                    rows.iter().map(|r| (r.t_secs, r.stats.psf_pupil_mm)),
                    psf.stroke_width(5),
                    dashed,
                ))?
                .label(format!("pupil the PSF{eye} was built for"))
                .legend(move |(x, y)| {
                    PathElement::new(vec![(x, y), (x + 20, y)], psf.stroke_width(5))
                });
            chart
                .draw_series(line(
                    rows.iter().map(|r| (r.t_secs, f64::from(r.pupil_mm))),
                    pupil.stroke_width(1),
                    dashed,
                ))?
                .label(format!("pupil{eye} measured (gaps: not measured)"))
                .legend(move |(x, y)| PathElement::new(vec![(x, y), (x + 20, y)], pupil));
        }
        chart
            .configure_series_labels()
            .background_style(WHITE.mix(0.8))
            .border_style(BLACK)
            .draw()?;
        root.present()?;
        Ok(())
    };
    write_chart_png(path, (1000, 640), draw)
        .map_err(|e| anyhow::anyhow!("cannot draw {}: {e}", path.display()))
}

/// The colours of view `k` of `n`: pooled target, adaptation, pupil, PSF
/// pupil. One view keeps the classic red/blue/black/green; in stereo the
/// left eye (view 0) is drawn in blues and the right eye (view 1) in
/// oranges, so the eyes differ by colour as well as by dash.
fn eye_colours(k: usize, n: usize) -> [RGBColor; 4] {
    match (n, k) {
        (1, _) => [RED, BLUE, BLACK, GREEN],
        (_, 0) => [
            RGBColor(120, 160, 230),
            RGBColor(20, 60, 200),
            RGBColor(10, 30, 110),
            RGBColor(0, 150, 200),
        ],
        _ => [
            RGBColor(250, 170, 90),
            RGBColor(220, 90, 0),
            RGBColor(130, 50, 0),
            RGBColor(200, 130, 0),
        ],
    }
}

/// A line through `points`, dashed (every other segment drawn) when
/// `dashed`.
fn line(
    points: impl Iterator<Item = (f64, f64)>,
    style: ShapeStyle,
    dashed: bool,
) -> Vec<PathElement<(f64, f64)>> {
    let points: Vec<(f64, f64)> = points.collect();
    // A point that is not finite (an empty cell: nothing measured) breaks
    // the line.
    let runs = points
        .split(|p| !(p.0.is_finite() && p.1.is_finite()))
        .filter(|r| !r.is_empty());
    if !dashed {
        return runs.map(|r| PathElement::new(r.to_vec(), style)).collect();
    }
    runs.flat_map(|r| {
        r.windows(2)
            .step_by(2)
            .map(|w| PathElement::new(w.to_vec(), style))
            .collect::<Vec<_>>()
    })
    .collect()
}

/// Draws a `size` RGB chart into memory with `draw` and writes it as PNG
/// through `image` 0.25 (plotters' own file encoder would compile a second,
/// older `image` into the build).
pub(crate) fn write_chart_png(
    path: &Path,
    size: (u32, u32),
    draw: impl FnOnce(&mut [u8], (u32, u32)) -> Result<(), Box<dyn std::error::Error>>,
) -> Result<(), Box<dyn std::error::Error>> {
    let (w, h) = size;
    let mut buf = vec![0u8; w as usize * h as usize * 3];
    draw(&mut buf, size)?;
    image::save_buffer(path, &buf, w, h, image::ColorType::Rgb8)?;
    Ok(())
}

#[cfg(test)]
mod tests {
    use gazelight_vision::pipeline::FrameStats;

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

    fn row(t_secs: f64, pupil_mm: f32, psf_pupil_mm: f64, cd_m2: f64) -> TimelineRow {
        TimelineRow {
            t_secs,
            gaze_u: 0.5,
            gaze_v: 0.5,
            pupil_mm,
            pupil_raw: f32::NAN,
            pupil_map_mm: f32::NAN,
            pupil_held: Some(false),
            aperture_mm: pupil_mm,
            stats: FrameStats {
                target_cd_m2: cd_m2,
                adaptation_cd_m2: cd_m2,
                psf_pupil_mm,
                ..FrameStats::default()
            },
            pupil_light_mm: f32::NAN,
            pupil_residual_mm: f32::NAN,
        }
    }

    /// The pupil axis fits pupils of 3–4 mm (padded by 0.1 mm), not a
    /// fixed 0–8 mm.
    #[test]
    fn pupil_axis_fits_the_data() {
        let rows: Vec<TimelineRow> = (0..11)
            .map(|i| row(i as f64 * 0.1, 3.0 + i as f32 * 0.1, 3.5, 1.0))
            .collect();
        let (lo, hi) = pupil_axis_mm(&[("", &rows)]);
        assert!(
            (lo - 2.75).abs() < 1e-6 && (hi - 4.25).abs() < 1e-6,
            "{lo} {hi}"
        );
    }

    /// Pixels of exactly `rgb` in the plot of `rows`.
    fn plot_pixels(rows: &[TimelineRow], rgb: impl Fn([u8; 3]) -> bool, name: &str) -> usize {
        let path =
            std::env::temp_dir().join(format!("gazelight-plot-{}-{name}.png", std::process::id()));
        write_plot(&path, &[("", rows)], [1.5, 9.0]).unwrap();
        let img = image::open(&path).unwrap().to_rgb8();
        let _ = std::fs::remove_file(&path);
        img.pixels().filter(|p| rgb(p.0)).count()
    }

    /// Where the PSF pupil equals the measured pupil and the adaptation
    /// equals the pooled target, both lines of each pair stay visible:
    /// the measured pupil (black) adds about a line's length of black
    /// pixels over the same plot without it, and the target (red) and the
    /// adaptation (blue) both show.
    #[test]
    fn plot_lines_that_agree_stay_visible() {
        let with: Vec<TimelineRow> = (0..60)
            .map(|i| row(i as f64 / 30.0, 4.0 + (i as f32 * 0.2).sin(), 4.0, 0.05))
            .collect();
        let with: Vec<TimelineRow> = with
            .into_iter()
            .map(|mut r| {
                r.stats.psf_pupil_mm = f64::from(r.pupil_mm);
                r
            })
            .collect();
        let without: Vec<TimelineRow> = with
            .iter()
            .map(|r| TimelineRow {
                pupil_mm: f32::NAN,
                ..*r
            })
            .collect();
        // Dark pixels: the black line, anti-aliased over the green.
        let dark = |p: [u8; 3]| p.iter().all(|&c| c < 90);
        let black = plot_pixels(&with, dark, "with");
        let black_without = plot_pixels(&without, dark, "without");
        assert!(
            black >= black_without + 400,
            "measured pupil line: {black} vs {black_without} black pixels"
        );
        let red = plot_pixels(&with, |p| p == [255, 0, 0], "red");
        let blue = plot_pixels(&with, |p| p == [0, 0, 255], "blue");
        assert!(
            red >= 400 && blue >= 1000,
            "target {red}, adaptation {blue} px"
        );
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
