//! The renderer choice is the application core's
//! ([`gazelight_app::backend`]: `--backend`'s values, the `auto` rule and
//! its fallback, the GPU/CPU [`Renderer`]); the CLI adds the window's slot
//! as the place a frame is shown ([`Renderer::show`]).

use gazelight_app::backend::FrameSink;
pub use gazelight_app::backend::{BackendChoice, Renderer};
use gazelight_gpu::present::FrameSource;

use crate::window::DisplaySlot;

impl FrameSink for DisplaySlot {
    fn put(&self, rgba8: &[u8]) {
        DisplaySlot::put(self, rgba8);
    }

    fn put_gpu(&self, source: impl FnOnce() -> FrameSource) {
        DisplaySlot::put_gpu(self, source);
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use gazelight_gpu::testing::test_context;
    use gazelight_vision::RgbImage;
    use gazelight_vision::pipeline::{DisplayFrame, FrameInput, PipelineConfig};
    use gazelight_vision::scene::{LuminanceScale, PanoramaView, Scene};

    /// The embedded night panorama seen towards the street lamp, at `w × h`.
    fn demo_view(w: usize, h: usize) -> (RgbImage, f64) {
        let scene = Scene::from_bytes(
            crate::demo::NIGHT_EXR,
            crate::demo::name_path(),
            LuminanceScale::default(),
        )
        .unwrap();
        let view = crate::demo::default_view(w, h);
        let mut img = RgbImage::new(w, h);
        PanoramaView::new(view)
            .unwrap()
            .render(&scene.image, &mut img);
        (img, view.deg_per_px())
    }

    /// The pupils of [`crate::bad_pupils::SEQUENCE`] (NaN, ±∞, 0, −3, 20 mm,
    /// f32::MAX among good ones) give the same kernels on the offline CPU
    /// pipeline and the GPU frame: the table's, read back from each
    /// backend's kernel as well as its frame statistics.
    #[test]
    fn bad_pupils_give_the_same_kernels_on_both_backends() {
        let (w, h) = (64, 48);
        let (view, deg_per_px) = demo_view(w, h);
        let mut config = PipelineConfig::default();
        // A small field keeps the eleven kernel builds quick.
        config.glare.psf.field_deg = 8.0;
        let gpu = test_context("bad_pupils_give_the_same_kernels_on_both_backends").is_some();
        let choices: &[BackendChoice] = if gpu {
            &[BackendChoice::Cpu, BackendChoice::Gpu]
        } else {
            &[BackendChoice::Cpu]
        };
        for &choice in choices {
            let mut r = Renderer::new(choice, &config, w, h, deg_per_px).unwrap();
            let mut out = DisplayFrame::new(w, h);
            for (i, &(pupil_mm, want_mm)) in crate::bad_pupils::SEQUENCE.iter().enumerate() {
                let input = FrameInput {
                    gaze_uv: [0.5, 0.4],
                    pupil_mm,
                    dt_secs: 1.0 / 90.0,
                };
                let stats = r.process(&view, &input, &mut out).unwrap();
                let kernel_mm = r.psf_kernel().unwrap().unwrap().pupil_mm;
                assert!(
                    (stats.psf_pupil_mm - want_mm).abs() < 1e-9
                        && (kernel_mm - want_mm).abs() < 1e-9,
                    "{choice}, step {i}: pupil {pupil_mm} mm gave kernel {kernel_mm} mm \
                     (stats {}), want {want_mm} mm",
                    stats.psf_pupil_mm
                );
                assert!(
                    out.rgba8.iter().any(|&v| v > 0),
                    "{choice}, step {i}: black frame"
                );
            }
        }
    }
}
