//! Glare along a gaze trace (`render`/`replay --glare-numbers`): each
//! frame's CIE 146 veil at the gaze and the DGP and UGR of the eye's own
//! line of sight, computed by `gazelight glare`'s functions
//! ([`gazelight_vision::scene_glare::SceneGlare::at_gaze`]) on the frame's
//! scene view — the perspective image of the view the pipeline renders, in
//! cd/m² — looking along the frame's gaze.
//!
//! The view's pixels (their directions and solid angles) are prepared once
//! per view image; per frame and view one [`SceneGlare::at_gaze_into`]
//! runs (a pass over the view's pixels), reusing the last gaze's source
//! list: no allocation per frame once the buffers have grown
//! (`tests/tests/glare_alloc.rs`). Pixels
//! without data (outside the scene's field, NaN in the view) are left out
//! as `glare` leaves out pixels outside an image's field. Only what the
//! view shows counts: light outside the display's field of view adds
//! nothing, so the numbers are those of the view, not of the whole scene.

use std::sync::Mutex;

use gazelight_vision::RgbImage;
use gazelight_vision::scene::ViewParams;
use gazelight_vision::scene::projection::{DVec3, ProjectionKind, SceneProjection};
use gazelight_vision::scene_glare::{GazeGlare, GlareOptions, SceneGlare};

use crate::RenderError;

/// The per-view columns of the glare numbers, written after every other
/// column (each view's suffix) when `--glare-numbers` is on.
pub const GLARE_COLUMNS: [&str; 3] = ["glare_veil_cie146_cd_m2", "glare_dgp", "glare_ugr"];

/// One view's glare numbers at one frame's gaze.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct GlareNumbers {
    /// The CIE 146:2002 veil at the gaze, cd/m² (`glare`'s
    /// `veil_cie146_cd_m2`).
    pub veil_cie146_cd_m2: f64,
    /// Daylight glare probability of the line of sight (`glare`'s `dgp`).
    pub dgp: f64,
    /// Unified glare rating of the line of sight; NaN (an empty cell)
    /// where it is undefined (no background luminance: `glare`'s `null`).
    pub ugr: f64,
}

impl GlareNumbers {
    /// No numbers (a gaze outside the view: empty cells).
    pub const NONE: Self = Self {
        veil_cie146_cd_m2: f64::NAN,
        dgp: f64::NAN,
        ugr: f64::NAN,
    };

    /// The values of [`GLARE_COLUMNS`], in their order.
    pub fn values(&self) -> [f64; 3] {
        [self.veil_cie146_cd_m2, self.dgp, self.ugr]
    }
}

/// A frame's scene view prepared for the glare numbers at any gaze.
pub struct ViewGlare {
    glare: SceneGlare,
    options: GlareOptions,
    /// The last gaze's numbers, their source list reused by the next
    /// ([`SceneGlare::at_gaze_into`]): a trace allocates nothing once the
    /// buffers have grown.
    last: Mutex<Option<GazeGlare>>,
}

impl ViewGlare {
    /// Prepares `view_img` (cd/m², NaN without data), the image of
    /// `view`: a perspective of `view.hfov_deg` with square pixels, as
    /// [`gazelight_vision::scene::PanoramaView`] renders it. `age_years`
    /// and `pigmentation` are the observer's (CIE 146); the rest of the
    /// options are `glare`'s defaults (evalglare's).
    pub fn new(
        view_img: &RgbImage,
        view: &ViewParams,
        age_years: f64,
        pigmentation: f64,
    ) -> Result<Self, RenderError> {
        if (view_img.width, view_img.height) != (view.width, view.height) {
            return Err(RenderError::Pipeline(format!(
                "glare numbers: a {}×{} view image for a {}×{} view",
                view_img.width, view_img.height, view.width, view.height
            )));
        }
        let projection = SceneProjection::with_square_pixels(
            ProjectionKind::Perspective,
            view.hfov_deg,
            view.width,
            view.height,
        )?;
        Ok(Self {
            glare: SceneGlare::new(view_img, projection),
            last: Mutex::new(None),
            options: GlareOptions {
                age_years,
                pigmentation,
                ..GlareOptions::default()
            },
        })
    }

    /// The direction (view camera frame: −z forward, +x right, +y up) of
    /// a normalised gaze (origin top-left, the pipeline's `gaze_uv`).
    pub fn gaze_direction(&self, gaze_uv: [f32; 2]) -> Option<DVec3> {
        let p = self.glare.projection();
        let px = [
            f64::from(gaze_uv[0]) * p.width_px as f64,
            f64::from(gaze_uv[1]) * p.height_px as f64,
        ];
        if !(px[0].is_finite() && px[1].is_finite()) {
            return None;
        }
        // A perspective maps every image-plane point, inside the frame
        // or not: a gaze off the display still has a line of sight.
        p.direction_any(px)
    }

    /// The glare numbers along the gaze `gaze_uv`; [`GlareNumbers::NONE`]
    /// for a gaze that is not a number.
    pub fn at(&self, gaze_uv: [f32; 2]) -> GlareNumbers {
        let Some(dir) = self.gaze_direction(gaze_uv) else {
            return GlareNumbers::NONE;
        };
        let numbers = |g: &GazeGlare| GlareNumbers {
            veil_cie146_cd_m2: g.veil_cie146_cd_m2,
            dgp: g.indices.dgp,
            ugr: g.indices.ugr.unwrap_or(f64::NAN),
        };
        match self.last.try_lock() {
            Ok(mut last) => match last.as_mut() {
                Some(g) => {
                    self.glare.at_gaze_into(dir, &self.options, g);
                    numbers(g)
                }
                None => numbers(last.insert(self.glare.at_gaze(dir, &self.options))),
            },
            // Held by another thread's gaze (or poisoned): a list of its own.
            Err(_) => numbers(&self.glare.at_gaze(dir, &self.options)),
        }
    }

    /// The options the numbers are computed with.
    pub fn options(&self) -> &GlareOptions {
        &self.options
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    /// The view's centre looks straight ahead and its right edge at
    /// hfov/2 (a perspective of square pixels, as PanoramaView's).
    #[test]
    fn gaze_directions_follow_the_view() {
        let view = ViewParams {
            yaw_deg: 0.0,
            pitch_deg: 0.0,
            hfov_deg: 90.0,
            width: 64,
            height: 32,
        };
        let img = RgbImage::from_pixels(64, 32, vec![[1.0; 3]; 64 * 32]).unwrap();
        let g = ViewGlare::new(&img, &view, 25.0, 0.5).unwrap();
        let c = g.gaze_direction([0.5, 0.5]).unwrap();
        assert!((c - DVec3::NEG_Z).length() < 1e-12, "{c:?}");
        let r = g.gaze_direction([1.0, 0.5]).unwrap();
        assert!((r.x.atan2(-r.z).to_degrees() - 45.0).abs() < 1e-9, "{r:?}");
        // Up: v = 0 is the top edge, tan = tan 45° · 32/64.
        let u = g.gaze_direction([0.5, 0.0]).unwrap();
        assert!((u.y / -u.z - 0.5).abs() < 1e-9, "{u:?}");
        assert!(g.at([f32::NAN, 0.5]).values().iter().all(|v| v.is_nan()));
    }
}
