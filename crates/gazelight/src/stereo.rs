//! Stereo frames for `render` and `replay` (`--stereo`) and `run`: the
//! views, the shared/own kernels and the side-by-side composition are
//! `gazelight_render::frame`'s (see its docs); this module re-exports them
//! for the CLI and checks them with the CLI's renderer.

pub(crate) use gazelight_render::frame::{MONO, STEREO, View, place_side_by_side};

#[cfg(test)]
mod tests {
    use gazelight_render::frame::StereoKernels;
    use gazelight_vision::pipeline::{FrameInput, PipelineConfig};

    use crate::backend::Renderer;

    /// The stereo plan gives each eye the kernel of
    /// [`crate::bad_pupils::SEQUENCE`] for its pupils: with both eyes fed
    /// the table (one shared kernel), and with the left eye fed the table
    /// while the right stays at 4 mm (the right keeps the initial kernel).
    #[test]
    fn bad_pupils_give_the_table_kernels_per_eye() {
        use crate::backend::BackendChoice;
        let (w, h, deg_per_px) = (48, 32, 0.2);
        let mut config = PipelineConfig::default();
        config.glare.psf.field_deg = 6.0;
        for right_fixed in [false, true] {
            let mut renderers: Vec<Renderer> = (0..2)
                .map(|_| Renderer::new(BackendChoice::Cpu, &config, w, h, deg_per_px).unwrap())
                .collect();
            let mut kernels = StereoKernels::new(&config, deg_per_px, &mut renderers)
                .unwrap()
                .expect("glare is on");
            for (i, &(pupil_mm, want_mm)) in crate::bad_pupils::SEQUENCE.iter().enumerate() {
                let input = |pupil_mm| FrameInput {
                    gaze_uv: [0.5, 0.5],
                    pupil_mm,
                    dt_secs: 0.01,
                };
                let left = input(pupil_mm);
                let right = input(if right_fixed { 4.0 } else { pupil_mm });
                kernels.update([&left, &right], &mut renderers).unwrap();
                let got: Vec<f64> = renderers
                    .iter_mut()
                    .map(|r| r.psf_kernel().unwrap().unwrap().pupil_mm)
                    .collect();
                let want = [want_mm, if right_fixed { 4.0 } else { want_mm }];
                assert!(
                    got.iter().zip(want).all(|(g, w)| (g - w).abs() < 1e-9),
                    "right fixed {right_fixed}, step {i}: pupil {pupil_mm} mm gave {got:?}, want {want:?}"
                );
            }
        }
    }
}
