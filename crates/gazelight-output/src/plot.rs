//! `plot.png` of `render`: adaptation luminance and pupil over time, and
//! the PNG writer every chart of gazelight shares.

use std::path::{Path, PathBuf};

use plotters::prelude::*;

use crate::font::{FontError, register_font};
use gazelight_render::timeline::TimelineRow;

/// Why `plot.png` was not written.
#[derive(Debug, thiserror::Error)]
pub enum PlotError {
    #[error(transparent)]
    Font(#[from] FontError),
    /// Drawing or writing it failed (the message of plotters or `image`).
    #[error("cannot draw {}: {message}", path.display())]
    Draw { path: PathBuf, message: String },
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
) -> Result<(), PlotError> {
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
    write_chart_png(path, (1000, 640), draw).map_err(|e| PlotError::Draw {
        path: path.to_owned(),
        message: e.to_string(),
    })
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
pub fn write_chart_png(
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
}
