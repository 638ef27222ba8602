//! Each frame's row of `timeline.csv`, per view: the eye state the frame
//! was rendered for and the pipeline's statistics.

use gazelight_vision::pipeline::FrameStats;

use crate::gaze_glare::{GLARE_COLUMNS, GlareNumbers};

/// One view's row of `timeline.csv`.
#[derive(Clone, Copy, Debug)]
pub struct TimelineRow {
    /// The frame's time from the first frame, s.
    pub t_secs: f64,
    pub gaze_u: f32,
    pub gaze_v: f32,
    /// The measured pupil, mm: the newest clean sample of the view's eye
    /// (mono: the mean of the eyes measured now), the tracker's mm or raw ×
    /// a physical scale; NaN (an empty cell) where nothing is measured or
    /// the pupil has no physical scale.
    pub pupil_mm: f32,
    /// The measured pupil in the tracker's raw unit where it has no
    /// physical scale (session.json names the unit); NaN otherwise.
    pub pupil_raw: f32,
    /// That raw pupil through the profile's black/white map (001 §5), mm
    /// of the map (no physical scale): what the residual is taken from
    /// then; NaN otherwise.
    pub pupil_map_mm: f32,
    /// Whether nothing is measured for this view at this frame (a blink and
    /// its margins, lost, before the first measurement); `None` (an empty
    /// cell) for an eye the recording does not have.
    pub pupil_held: Option<bool>,
    /// The model aperture the glare PSF is built for, mm (001 §5's
    /// black/white map or the measured mm, held and eased; not a
    /// measurement).
    pub aperture_mm: f32,
    pub stats: FrameStats,
    /// The pupil the light predicts, mm (`replay`'s pupil light response;
    /// NaN where it is not computed: then the column is not written).
    pub pupil_light_mm: f32,
    /// Measured pupil − `pupil_light_mm`, mm; NaN (an empty cell) where
    /// the pupil is not measured (a blink, held, the model's fill-in).
    pub pupil_residual_mm: f32,
}

/// The per-view columns of `timeline.csv`, after `t_secs`.
pub const TIMELINE_COLUMNS: [&str; 19] = [
    "gaze_u",
    "gaze_v",
    "pupil_mm",
    "pupil_raw",
    "pupil_map_mm",
    "pupil_held",
    "aperture_mm",
    "target_cd_m2",
    "adaptation_cd_m2",
    "psf_pupil_mm",
    "psf_rebuilt",
    "acuity_sigma_px",
    "pooling_ms",
    "temporal_ms",
    "psf_ms",
    "glare_ms",
    "acuity_ms",
    "tone_colour_encode_ms",
    "total_ms",
];

/// The per-view columns of the pupil light response (`replay`), written
/// after every view's [`TIMELINE_COLUMNS`] when any row has a prediction.
pub const PUPIL_LIGHT_COLUMNS: [&str; 2] = ["pupil_light_mm", "pupil_residual_mm"];

impl TimelineRow {
    /// The values of [`TIMELINE_COLUMNS`], in their order (booleans as 0
    /// or 1, NaN for an empty cell), unrounded.
    pub fn values(&self) -> [f64; 19] {
        let s = &self.stats;
        let t = &s.timings;
        [
            f64::from(self.gaze_u),
            f64::from(self.gaze_v),
            f64::from(self.pupil_mm),
            f64::from(self.pupil_raw),
            f64::from(self.pupil_map_mm),
            self.pupil_held.map_or(f64::NAN, |h| f64::from(u8::from(h))),
            f64::from(self.aperture_mm),
            s.target_cd_m2,
            s.adaptation_cd_m2,
            s.psf_pupil_mm,
            f64::from(u8::from(s.psf_rebuilt)),
            f64::from(s.acuity_sigma_px),
            t.pooling_ms,
            t.temporal_ms,
            t.psf_ms,
            t.glare_ms,
            t.acuity_ms,
            t.tone_colour_encode_ms,
            t.total_ms,
        ]
    }
}

/// `timeline.csv` written as the frames are made: a row per frame (every
/// view's [`TIMELINE_COLUMNS`], then, with the pupil light response, every
/// view's [`PUPIL_LIGHT_COLUMNS`], then, with the glare numbers, every
/// view's [`GLARE_COLUMNS`]), through the one per-frame writer
/// ([`RowFile`]: whole rows, at least once a second), so a replay ended by
/// SIGKILL or a crash keeps every row older than a second.
/// The row is formatted into one reused buffer: no allocation per frame.
pub struct TimelineWriter {
    out: RowFile,
    views: usize,
    pupil_light: bool,
    glare_numbers: bool,
    line: String,
}

pub use crate::rows::FLUSH_EVERY;
use crate::rows::RowFile;

impl TimelineWriter {
    /// Creates `path` with its header: `t_secs`, then each column with
    /// each view's suffix (`""` mono, `_right`/`_left` stereo); with
    /// `pupil_light` and `glare_numbers` their columns after. The error
    /// (the file cannot be created) names the file.
    pub fn create(
        path: &std::path::Path,
        suffixes: &[&str],
        pupil_light: bool,
        glare_numbers: bool,
    ) -> std::io::Result<Self> {
        let mut header = String::from("t_secs");
        for suffix in suffixes {
            for c in TIMELINE_COLUMNS {
                header.push_str(&format!(",{c}{suffix}"));
            }
        }
        if pupil_light {
            for suffix in suffixes {
                for c in PUPIL_LIGHT_COLUMNS {
                    header.push_str(&format!(",{c}{suffix}"));
                }
            }
        }
        if glare_numbers {
            for suffix in suffixes {
                for c in GLARE_COLUMNS {
                    header.push_str(&format!(",{c}{suffix}"));
                }
            }
        }
        let mut out = RowFile::create(path, &header, crate::rows::keep_error);
        // The header reaches the file at once (a reader sees the columns).
        out.flush();
        let w = Self {
            out,
            views: suffixes.len(),
            pupil_light,
            glare_numbers,
            line: String::with_capacity(512 * suffixes.len().max(1)),
        };
        w.checked()?;
        Ok(w)
    }

    /// The file's failure as an error (its message names the file and
    /// the rows it kept).
    fn checked(&self) -> std::io::Result<()> {
        match self.out.failure() {
            Some(f) => Err(std::io::Error::other(f.to_owned())),
            None => Ok(()),
        }
    }

    /// Writes one frame's rows (one per view, in the header's order); a
    /// writer with glare numbers leaves their cells empty.
    pub fn push(&mut self, rows: &[TimelineRow]) -> std::io::Result<()> {
        self.push_with_glare(rows, &[])
    }

    /// [`Self::push`] with each view's glare numbers (in the rows' order;
    /// empty cells for a view without), written when the writer has the
    /// glare columns.
    pub fn push_with_glare(
        &mut self,
        rows: &[TimelineRow],
        glare: &[GlareNumbers],
    ) -> std::io::Result<()> {
        use std::fmt::Write as _;
        if rows.len() != self.views || glare.len() > self.views {
            return Err(std::io::Error::new(
                std::io::ErrorKind::InvalidInput,
                format!(
                    "{} rows and {} glare numbers for {} views",
                    rows.len(),
                    glare.len(),
                    self.views
                ),
            ));
        }
        let line = &mut self.line;
        line.clear();
        let fmt = std::io::Error::other;
        if let Some(r) = rows.first() {
            write!(line, "{:.4}", r.t_secs).map_err(fmt)?;
        }
        for r in rows {
            let s = &r.stats;
            let t = &s.timings;
            write!(line, ",{:.5},{:.5}", r.gaze_u, r.gaze_v).map_err(fmt)?;
            for v in [r.pupil_mm, r.pupil_raw, r.pupil_map_mm] {
                cell(line, v, 4).map_err(fmt)?;
            }
            match r.pupil_held {
                Some(h) => write!(line, ",{}", u8::from(h)).map_err(fmt)?,
                None => line.push(','),
            }
            write!(
                line,
                ",{:.4},{:.6e},{:.6e},{:.4},{},{:.3}",
                r.aperture_mm,
                s.target_cd_m2,
                s.adaptation_cd_m2,
                s.psf_pupil_mm,
                u8::from(s.psf_rebuilt),
                s.acuity_sigma_px,
            )
            .map_err(fmt)?;
            // The stage timings: empty cells where no image pipeline ran
            // (`crate::analysis`: NaN).
            for (v, d) in [
                (t.pooling_ms, 3),
                (t.temporal_ms, 4),
                (t.psf_ms, 3),
                (t.glare_ms, 3),
                (t.acuity_ms, 3),
                (t.tone_colour_encode_ms, 3),
                (t.total_ms, 3),
            ] {
                cell64(line, v, Cell::Fixed(d)).map_err(fmt)?;
            }
        }
        if self.pupil_light {
            for r in rows {
                for v in [r.pupil_light_mm, r.pupil_residual_mm] {
                    cell(line, v, 4).map_err(fmt)?;
                }
            }
        }
        if self.glare_numbers {
            for k in 0..self.views {
                let g = glare.get(k).unwrap_or(&GlareNumbers::NONE);
                // The veil and UGR over decades: 6 significant digits; DGP
                // (0.16…1) to 1e-5.
                cell64(line, g.veil_cie146_cd_m2, Cell::Exp).map_err(fmt)?;
                cell64(line, g.dgp, Cell::Fixed(5)).map_err(fmt)?;
                cell64(line, g.ugr, Cell::Fixed(3)).map_err(fmt)?;
            }
        }
        line.push('\n');
        self.out.push(line);
        self.checked()
    }

    /// Writes what is left.
    pub fn finish(mut self) -> std::io::Result<()> {
        self.out.flush();
        self.checked()
    }
}

/// How a glare cell is written.
enum Cell {
    /// `{:.6e}`.
    Exp,
    /// That many decimals.
    Fixed(usize),
}

/// `,value` as `how`, or `,` (an empty cell) where it is not finite.
fn cell64(line: &mut String, v: f64, how: Cell) -> std::fmt::Result {
    use std::fmt::Write as _;
    match how {
        _ if !v.is_finite() => {
            line.push(',');
            Ok(())
        }
        Cell::Exp => write!(line, ",{v:.6e}"),
        Cell::Fixed(d) => write!(line, ",{v:.d$}"),
    }
}

/// `,value` with `decimals`, or `,` (an empty cell) where it is not finite.
fn cell(line: &mut String, v: f32, decimals: usize) -> std::fmt::Result {
    use std::fmt::Write as _;
    if v.is_finite() {
        write!(line, ",{v:.decimals$}")
    } else {
        line.push(',');
        Ok(())
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    fn row() -> TimelineRow {
        TimelineRow {
            t_secs: 0.5,
            gaze_u: 0.5,
            gaze_v: 0.25,
            pupil_mm: 4.0,
            pupil_raw: f32::NAN,
            pupil_map_mm: f32::NAN,
            pupil_held: Some(false),
            aperture_mm: 4.0,
            stats: FrameStats::default(),
            pupil_light_mm: f32::NAN,
            pupil_residual_mm: f32::NAN,
        }
    }

    /// The glare columns come last, suffixed per view, with empty cells
    /// where a number is undefined; without them the header is as before.
    #[test]
    fn glare_columns_are_last_and_per_view() {
        let dir = std::env::temp_dir().join(format!("gazelight-timeline-{}", std::process::id()));
        std::fs::create_dir_all(&dir).unwrap();
        let path = dir.join("timeline.csv");
        let mut w = TimelineWriter::create(&path, &["_left", "_right"], false, true).unwrap();
        let g = GlareNumbers {
            veil_cie146_cd_m2: 1.25,
            dgp: 0.2,
            ugr: f64::NAN,
        };
        w.push_with_glare(&[row(), row()], &[g, GlareNumbers::NONE])
            .unwrap();
        w.finish().unwrap();
        let text = std::fs::read_to_string(&path).unwrap();
        let lines: Vec<&str> = text.lines().collect();
        let header: Vec<&str> = lines[0].split(',').collect();
        let cells: Vec<&str> = lines[1].split(',').collect();
        assert_eq!(header.len(), 1 + 2 * (TIMELINE_COLUMNS.len() + 3));
        assert_eq!(cells.len(), header.len());
        assert_eq!(
            header[header.len() - 6..],
            [
                "glare_veil_cie146_cd_m2_left",
                "glare_dgp_left",
                "glare_ugr_left",
                "glare_veil_cie146_cd_m2_right",
                "glare_dgp_right",
                "glare_ugr_right"
            ]
        );
        assert_eq!(
            cells[cells.len() - 6..],
            ["1.250000e0", "0.20000", "", "", "", ""]
        );
        let plain = TimelineWriter::create(&path, &[""], false, false).unwrap();
        plain.finish().unwrap();
        let text = std::fs::read_to_string(&path).unwrap();
        assert!(!text.contains("glare_veil"), "{text}");
        let _ = std::fs::remove_dir_all(&dir);
    }
}
