//! Each frame's row of `timeline.csv`, per view: the eye state the frame
//! was rendered for and the pipeline's statistics.

use gazelight_vision::pipeline::FrameStats;

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
