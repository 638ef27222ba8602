//! The veil map `render --exr` writes beside its frames (`frames/veil.exr`):
//! the CIE 146:2002 veiling luminance, cd/m², that the scene casts on each
//! direction of the view — the `veil_cie146_cd_m2` `gazelight glare`
//! reports for a gaze in that direction, at the observer's age and
//! pigmentation ([`gazelight_vision::scene_glare`]: `Σ L ω (d·g) f(θ)`
//! over the scene's pixels in its field and in front of the eye, θ ≥ 1°).
//!
//! It depends on the scene, the view and the observer only — not on the
//! gaze, the pupil or the time — so a render writes one. It is sampled
//! on a grid over the view: map pixel (i, j) of an `mw × mh` map is the
//! veil along the view's direction through the view point
//! `((i + ½)·W/mw, (j + ½)·H/mh)`; the grid is one sample per `s × s`
//! view pixels, `s` the pooling block (8 by default) or coarser so that
//! the map costs at most [`MAX_TERMS`] terms (one per scene pixel per
//! sample). All three EXR channels hold the veil.

use std::path::Path;

use gazelight_vision::RgbImage;
use gazelight_vision::scene::{PanoramaView, Scene, ViewParams};
use gazelight_vision::scene_glare::{GlareOptions, SceneGlare};

/// The most scene-pixel × sample terms a veil map may cost (about 5 s on
/// two cores).
pub const MAX_TERMS: f64 = 4e8;

/// What was written.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct VeilMap {
    /// Map size, samples.
    pub width: usize,
    pub height: usize,
    /// View pixels per sample (the grid step, rounded up).
    pub step_px: usize,
}

/// The map's size for a `width × height` view at a step of at least
/// `block_px`, for a scene of `scene_pixels` pixels in its field.
pub fn grid(width: usize, height: usize, block_px: usize, scene_pixels: usize) -> VeilMap {
    let mut s = block_px.max(1);
    loop {
        let (mw, mh) = (width.div_ceil(s).max(1), height.div_ceil(s).max(1));
        if (mw * mh) as f64 * scene_pixels as f64 <= MAX_TERMS || (mw == 1 && mh == 1) {
            return VeilMap {
                width: mw,
                height: mh,
                step_px: s,
            };
        }
        s += 1;
    }
}

/// The view point (continuous view pixels) of map pixel `(i, j)`.
pub fn view_point(map: &VeilMap, view: &ViewParams, i: usize, j: usize) -> [f32; 2] {
    [
        ((i as f64 + 0.5) * view.width as f64 / map.width as f64) as f32,
        ((j as f64 + 0.5) * view.height as f64 / map.height as f64) as f32,
    ]
}

/// Computes the veil map of `scene` seen through `view` for an observer of
/// `age_years` and `pigmentation` and writes it to `path` (OpenEXR).
pub fn write(
    path: &Path,
    scene: &Scene,
    view: &ViewParams,
    age_years: f64,
    pigmentation: f64,
    block_px: usize,
) -> Result<VeilMap, crate::RenderError> {
    // A scene above `glare::MAX_GLARE_PIXELS` is binned, as `glare` does.
    let (image, projection, _) =
        gazelight_vision::scene_glare::bin_for_glare(&scene.image, scene.effective_projection());
    let glare = SceneGlare::new(&image, projection);
    drop(image);
    let map = grid(view.width, view.height, block_px, glare.pixels_in_field());
    let projection = PanoramaView::new(*view)
        .map_err(|e| crate::RenderError::Pipeline(format!("veil map view: {e}")))?;
    let gazes: Vec<_> = (0..map.width * map.height)
        .map(|k| {
            let [x, y] = view_point(&map, view, k % map.width, k / map.width);
            projection.direction(x, y).as_dvec3()
        })
        .collect();
    let opts = GlareOptions {
        age_years,
        pigmentation,
        ..GlareOptions::default()
    };
    let veil = glare.veil_map_cie146(&gazes, &opts);
    let image = RgbImage::from_pixels(
        map.width,
        map.height,
        veil.iter().map(|&v| [v as f32; 3]).collect(),
    )?;
    gazelight_vision::scene::write_exr(path, &image)?;
    Ok(map)
}

#[cfg(test)]
mod tests {
    use super::*;

    /// The grid is one sample per block while it is cheap, and coarsens
    /// to stay within the budget.
    #[test]
    fn grid_keeps_to_the_budget() {
        let g = grid(96, 72, 8, 480_000);
        assert_eq!((g.width, g.height, g.step_px), (12, 9, 8));
        let g = grid(720, 800, 8, 524_288);
        assert!(g.step_px > 8, "{g:?}");
        assert!((g.width * g.height) as f64 * 524_288.0 <= MAX_TERMS);
        let g = grid(8, 8, 8, usize::MAX);
        assert_eq!((g.width, g.height), (1, 1));
    }
}
