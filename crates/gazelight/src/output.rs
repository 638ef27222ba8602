//! Files written by `render`: PNG frames, the contact sheet, the timeline
//! CSV and the plot.

use std::io::Write;
use std::path::Path;

use anyhow::Context;
use gazelight_vision::pipeline::DisplayFrame;
use plotters::prelude::*;

/// Tiles on the contact sheet (4 columns × 3 rows).
pub const SHEET_TILES: usize = 12;
const SHEET_COLUMNS: usize = 4;
/// Largest tile width on the contact sheet, pixels.
const SHEET_TILE_MAX_W: usize = 320;

/// The font for plots and labels (DejaVu Sans, licence in `assets/`).
const FONT: &[u8] = include_bytes!("../../../assets/DejaVuSans.ttf");

pub use gazelight_render::png::PngCompression;
pub use gazelight_render::timeline::TimelineRow;
use gazelight_render::timeline::{PUPIL_LIGHT_COLUMNS, TIMELINE_COLUMNS};

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
    t_secs: f64,
    pixels: Vec<u8>,
    /// Gaze points, frame-normalised (`[0, 1]²`, one per view).
    gaze_uv: Vec<[f32; 2]>,
    /// What the tile says under its time (pupil, adaptation).
    label: String,
}

/// Colour of the gaze marker on the contact sheet (saturated green: no
/// rendered night or day pixel has it, so a test can find it).
pub const GAZE_MARKER_RGB: [u8; 3] = [0, 255, 0];

/// A grid of downscaled frames, each with its gaze marked and its time,
/// pupil and adaptation written on a dark band (readable on bright sky).
pub struct ContactSheet {
    factor: usize,
    tile_w: usize,
    tile_h: usize,
    tiles: Vec<Tile>,
}

impl ContactSheet {
    /// A sheet for frames of `width × height`.
    pub fn new(width: usize, height: usize) -> Self {
        let factor = width.div_ceil(SHEET_TILE_MAX_W).max(1);
        Self {
            factor,
            tile_w: width / factor,
            tile_h: height / factor,
            tiles: Vec::with_capacity(SHEET_TILES),
        }
    }

    /// Adds a frame (box-filtered down) if there is room, with its gaze
    /// points (frame-normalised, one per view) and a label.
    pub fn add(&mut self, frame: &DisplayFrame, t_secs: f64, gaze_uv: &[[f32; 2]], label: String) {
        if self.tiles.len() >= SHEET_TILES {
            return;
        }
        let f = self.factor;
        let mut tile = vec![0u8; self.tile_w * self.tile_h * 3];
        for ty in 0..self.tile_h {
            for tx in 0..self.tile_w {
                let mut acc = [0u32; 3];
                for y in ty * f..(ty + 1) * f {
                    for x in tx * f..(tx + 1) * f {
                        let i = (y * frame.width + x) * 4;
                        for (a, v) in acc.iter_mut().zip(&frame.rgba8[i..i + 3]) {
                            *a += u32::from(*v);
                        }
                    }
                }
                let o = (ty * self.tile_w + tx) * 3;
                for c in 0..3 {
                    tile[o + c] = (acc[c] / (f * f) as u32) as u8;
                }
            }
        }
        self.tiles.push(Tile {
            t_secs,
            pixels: tile,
            gaze_uv: gaze_uv.to_vec(),
            label,
        });
    }

    /// The pixel (sheet coordinates) of tile `i`'s gaze point `uv`, if it
    /// is inside the tile.
    pub fn gaze_pixel(&self, i: usize, uv: [f32; 2]) -> Option<(usize, usize)> {
        let (u, v) = (f64::from(uv[0]), f64::from(uv[1]));
        if !(0.0..1.0).contains(&u) || !(0.0..1.0).contains(&v) {
            return None;
        }
        let (cx, cy) = (
            (i % SHEET_COLUMNS) * self.tile_w,
            (i / SHEET_COLUMNS) * self.tile_h,
        );
        Some((
            cx + (u * self.tile_w as f64) as usize,
            cy + (v * self.tile_h as f64) as usize,
        ))
    }

    /// Writes the sheet with a time label on every tile.
    pub fn write(&self, path: &Path) -> anyhow::Result<()> {
        let rows = self.tiles.len().div_ceil(SHEET_COLUMNS).max(1);
        let (w, h) = (self.tile_w * SHEET_COLUMNS, self.tile_h * rows);
        let mut buf = vec![0u8; w * h * 3];
        for (i, tile) in self.tiles.iter().enumerate() {
            let (cx, cy) = (
                (i % SHEET_COLUMNS) * self.tile_w,
                (i / SHEET_COLUMNS) * self.tile_h,
            );
            for y in 0..self.tile_h {
                let src = &tile.pixels[y * self.tile_w * 3..(y + 1) * self.tile_w * 3];
                let o = ((cy + y) * w + cx) * 3;
                buf[o..o + src.len()].copy_from_slice(src);
            }
        }
        register_font()?;
        {
            let root =
                BitMapBackend::with_buffer(&mut buf, (w as u32, h as u32)).into_drawing_area();
            let err = |e| anyhow::anyhow!("drawing the contact sheet: {e}");
            let style = ("sans-serif", 14).into_font().color(&WHITE);
            let [r, g, b] = GAZE_MARKER_RGB;
            let marker = RGBColor(r, g, b);
            for (i, tile) in self.tiles.iter().enumerate() {
                let (cx, cy) = (
                    (i % SHEET_COLUMNS) * self.tile_w,
                    (i / SHEET_COLUMNS) * self.tile_h,
                );
                // A dark band under the text: white on bright sky stays
                // readable.
                let band_h = 38.min(self.tile_h as i32);
                root.draw(&Rectangle::new(
                    [
                        (cx as i32, cy as i32),
                        (cx as i32 + self.tile_w as i32 - 1, cy as i32 + band_h),
                    ],
                    BLACK.mix(0.65).filled(),
                ))
                .map_err(err)?;
                root.draw_text(
                    &format!("t = {:.2} s", tile.t_secs),
                    &style,
                    (cx as i32 + 6, cy as i32 + 3),
                )
                .map_err(err)?;
                root.draw_text(&tile.label, &style, (cx as i32 + 6, cy as i32 + 20))
                    .map_err(err)?;
                for &uv in &tile.gaze_uv {
                    let Some((x, y)) = self.gaze_pixel(i, uv) else {
                        continue;
                    };
                    let (x, y) = (x as i32, y as i32);
                    for (a, b) in [
                        ((x - 7, y), (x - 2, y)),
                        ((x + 2, y), (x + 7, y)),
                        ((x, y - 7), (x, y - 2)),
                        ((x, y + 2), (x, y + 7)),
                    ] {
                        root.draw(&PathElement::new(vec![a, b], marker.stroke_width(2)))
                            .map_err(err)?;
                    }
                }
            }
            root.present()
                .map_err(|e| anyhow::anyhow!("drawing the contact sheet: {e}"))?;
        }
        image::save_buffer(path, &buf, w as u32, h as u32, image::ColorType::Rgb8)
            .with_context(|| format!("cannot write {}", path.display()))
    }
}

/// Writes `timeline.csv`: `t_secs`, then each view's columns with its
/// suffix (`""` for a mono frame; `_left`, `_right` for stereo); then, when
/// the pupil light response was computed (`replay`), each view's
/// `pupil_light_mm` and `pupil_residual_mm` (empty where not defined). The
/// views' rows are frame by frame, so row `i` of every view is frame `i`.
pub fn write_timeline(path: &Path, views: &[(&str, &[TimelineRow])]) -> anyhow::Result<()> {
    let file =
        std::fs::File::create(path).with_context(|| format!("cannot write {}", path.display()))?;
    let mut w = std::io::BufWriter::new(file);
    write!(w, "t_secs")?;
    for (suffix, _) in views {
        for c in TIMELINE_COLUMNS {
            write!(w, ",{c}{suffix}")?;
        }
    }
    let pupil_light = views
        .iter()
        .any(|(_, rows)| rows.iter().any(|r| r.pupil_light_mm.is_finite()));
    if pupil_light {
        for (suffix, _) in views {
            for c in PUPIL_LIGHT_COLUMNS {
                write!(w, ",{c}{suffix}")?;
            }
        }
    }
    writeln!(w)?;
    let frames = views.iter().map(|(_, r)| r.len()).min().unwrap_or(0);
    for i in 0..frames {
        if let Some(r) = views.first().and_then(|(_, rows)| rows.get(i)) {
            write!(w, "{:.4}", r.t_secs)?;
        }
        for (_, rows) in views {
            let r = &rows[i];
            let s = &r.stats;
            let t = &s.timings;
            write!(w, ",{:.5},{:.5}", r.gaze_u, r.gaze_v)?;
            write_opt(&mut w, r.pupil_mm, 4)?;
            write_opt(&mut w, r.pupil_raw, 4)?;
            write_opt(&mut w, r.pupil_map_mm, 4)?;
            match r.pupil_held {
                Some(h) => write!(w, ",{}", u8::from(h))?,
                None => write!(w, ",")?,
            }
            write!(
                w,
                ",{:.4},{:.6e},{:.6e},{:.4},{},{:.3},{:.3},{:.4},{:.3},{:.3},{:.3},{:.3},{:.3}",
                r.aperture_mm,
                s.target_cd_m2,
                s.adaptation_cd_m2,
                s.psf_pupil_mm,
                u8::from(s.psf_rebuilt),
                s.acuity_sigma_px,
                t.pooling_ms,
                t.temporal_ms,
                t.psf_ms,
                t.glare_ms,
                t.acuity_ms,
                t.tone_colour_encode_ms,
                t.total_ms
            )?;
        }
        if pupil_light {
            for (_, rows) in views {
                let r = &rows[i];
                for v in [r.pupil_light_mm, r.pupil_residual_mm] {
                    if v.is_finite() {
                        write!(w, ",{v:.4}")?;
                    } else {
                        write!(w, ",")?;
                    }
                }
            }
        }
        writeln!(w)?;
    }
    w.flush()
        .with_context(|| format!("cannot write {}", path.display()))
}

/// `,value` with `decimals`, or `,` (an empty cell) where it is not finite.
fn write_opt(w: &mut impl Write, v: f32, decimals: usize) -> std::io::Result<()> {
    if v.is_finite() {
        write!(w, ",{v:.decimals$}")
    } else {
        write!(w, ",")
    }
}

pub(crate) fn register_font() -> anyhow::Result<()> {
    plotters::style::register_font("sans-serif", FontStyle::Normal, FONT)
        .map_err(|_| anyhow::anyhow!("the embedded font is invalid"))
}

/// Writes the plot of adaptation luminance (log) and pupil over time, one
/// set of lines per view (labelled by its suffix in stereo; the right eye
/// dashed).
pub fn write_plot(path: &Path, views: &[(&str, &[TimelineRow])]) -> anyhow::Result<()> {
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
                    rows.iter().map(|r| (r.t_secs, log(r.stats.target_cd_m2))),
                    target.stroke_width(1),
                    dashed,
                ))?
                .label(format!("pooled target{eye}"))
                .legend(move |(x, y)| PathElement::new(vec![(x, y), (x + 20, y)], target));
            chart
                .draw_series(line(
                    rows.iter()
                        .map(|r| (r.t_secs, log(r.stats.adaptation_cd_m2))),
                    adaptation.stroke_width(2),
                    dashed,
                ))?
                .label(format!("adaptation{eye}"))
                .legend(move |(x, y)| PathElement::new(vec![(x, y), (x + 20, y)], adaptation));
        }
        chart
            .configure_series_labels()
            .background_style(WHITE.mix(0.8))
            .border_style(BLACK)
            .draw()?;
        let p_hi = all()
            .flat_map(|r| [r.pupil_mm, r.aperture_mm])
            .filter(|v| v.is_finite())
            .fold(8.0f32, f32::max) as f64;
        let mut chart = ChartBuilder::on(&bottom)
            .caption("pupil", ("sans-serif", 20))
            .margin(10)
            .x_label_area_size(30)
            .y_label_area_size(70)
            .build_cartesian_2d(0.0..t_max, 0.0..p_hi + 0.5)?;
        chart.configure_mesh().x_desc("t (s)").y_desc("mm").draw()?;
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
                    Rectangle::new(
                        [(a, 0.0), (b.max(a + 1e-3), p_hi + 0.5)],
                        grey.mix(0.6).filled(),
                    )
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
                    rows.iter().map(|r| (r.t_secs, f64::from(r.pupil_mm))),
                    pupil.stroke_width(1),
                    dashed,
                ))?
                .label(format!("pupil{eye} measured (empty: not measured)"))
                .legend(move |(x, y)| PathElement::new(vec![(x, y), (x + 20, y)], pupil));
            chart
                .draw_series(line(
                    rows.iter().map(|r| (r.t_secs, r.stats.psf_pupil_mm)),
                    psf.stroke_width(2),
                    dashed,
                ))?
                .label(format!("PSF{eye} built for"))
                .legend(move |(x, y)| PathElement::new(vec![(x, y), (x + 20, y)], psf));
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
