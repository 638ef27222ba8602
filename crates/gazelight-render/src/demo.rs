//! The embedded default: a CC0 night panorama (`assets/night.exr`, licence
//! beside it) and a built-in synthetic trace in which the gaze goes from the
//! dark ground up to a street lamp and back, with blinks; the pupil follows
//! the scene's luminance at the gaze. Also the default trace for a scene
//! of one's own (a slow horizontal sweep, [`sweep_trace`]).

use std::path::Path;

use gazelight_tracker::synthetic::KeyframedTrace;
use gazelight_tracker::{GazeTrace, TraceSample};
use gazelight_vision::RgbImage;
use gazelight_vision::pooling::PoolingModel;
use gazelight_vision::scene::{PanoramaView, ViewParams, equirect_direction};

use crate::RenderError;

/// The bundled panorama (HDRI Haven "night", CC0, via Blender).
pub const NIGHT_EXR: &[u8] = include_bytes!("../../../assets/night.exr");
/// Name used for the embedded scene in outputs and errors.
pub const NIGHT_NAME: &str = "embedded:night.exr";

/// Panorama pixel of the brightest street lamp in `night.exr` (4 220 in
/// file units, longitude −78°, latitude +6.7°), 1024×512.
const LAMP_PX: [f32; 2] = [289.5, 237.5];
/// A patch of dark grass below the lamp (latitude −22°).
const GROUND_PX: [f32; 2] = [289.5, 318.5];

/// The default view: looking towards the lamp, slightly down.
pub fn default_view(width: usize, height: usize) -> ViewParams {
    ViewParams {
        yaw_deg: -78.4,
        pitch_deg: -6.0,
        hfov_deg: 90.0,
        width,
        height,
    }
}

/// The demo trace for a view of the bundled panorama, built by the tracker
/// crate's keyframed generator: fixate the dark ground, saccade up to the
/// lamp at 3 s, back down at 7.5 s, blinks at 1.8, 5.6 and 9.6 s. The pupil
/// follows the Watson–Yellott model of the luminance pooled around the gaze
/// in `view_img` (cd/m²), with the tracker crate's pupil dynamics
/// (constriction faster than dilation).
pub fn demo_trace(view: &ViewParams, view_img: &RgbImage) -> Result<GazeTrace, RenderError> {
    let proj = PanoramaView::new(*view)?;
    let uv = |px: [f32; 2]| -> Result<[f32; 2], RenderError> {
        let d = equirect_direction(1024, 512, px);
        let p = proj
            .project(d)
            .ok_or_else(|| RenderError::Demo("demo target is behind the default view".into()))?;
        Ok([p[0] / view.width as f32, p[1] / view.height as f32])
    };
    let ground = uv(GROUND_PX)?;
    let lamp = uv(LAMP_PX)?;
    let mut keys = KeyframedTrace::street_lamp_demo();
    keys.keyframes = vec![
        (0.0, ground),
        (3.0, lamp),
        (7.5, ground),
        (DEMO_SECS, ground),
    ];
    keys.blinks = vec![(1.8, 0.15), (5.6, 0.15), (9.6, 0.15)];
    keys.duration_s = DEMO_SECS;
    keys.field_width_deg = view.hfov_deg;
    let luminance = view_img.luminance_plane();
    let pooling = PoolingModel::default();
    let (w, h) = (view_img.width, view_img.height);
    let deg_per_px = view.deg_per_px();
    Ok(keys.build(|_t, g| {
        let gaze_px = [f64::from(g[0]) * w as f64, f64::from(g[1]) * h as f64];
        pooling.pool(&luminance, w, h, gaze_px, deg_per_px)
    }))
}

/// Duration of the demo trace, seconds.
pub const DEMO_SECS: f64 = 12.0;

/// Path used in messages for the embedded scene.
pub fn name_path() -> &'static Path {
    Path::new(NIGHT_NAME)
}

/// A slow horizontal gaze sweep at a 4 mm pupil over 12 s: the default
/// trace for a scene of one's own.
pub fn sweep_trace() -> GazeTrace {
    let n = 1200;
    GazeTrace {
        samples: (0..n)
            .map(|i| {
                let t = i as f64 / 100.0;
                TraceSample {
                    t_secs: t,
                    gaze_uv: [0.1 + 0.8 * (i as f32 / (n - 1) as f32), 0.5],
                    pupil_mm: Some(4.0),
                    confidence: 1.0,
                }
            })
            .collect(),
    }
}
