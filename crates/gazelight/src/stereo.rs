//! Stereo frames for `render` and `replay` (`--stereo`): one frame
//! pipeline per eye, each on that eye's own gaze and pupil, so pooling,
//! adaptation, glare and acuity all run per eye; the two frames are written
//! side by side, left | right.
//!
//! The two eyes share one glare kernel while their pupils agree (within
//! `psf_rebuild_threshold_mm`, 0.1 mm by default: the kernel is built once,
//! at their mean, and installed in both pipelines) and get one each when
//! the pupils part (`gazelight_vision::kernel_policy`). The pipelines never rebuild kernels
//! themselves in stereo; [`StereoKernels`] does.
//!
//! A panorama lies at infinity, so an eye offset of ±IPD/2 moves nothing in
//! it: both eyes see the same view of the panorama, and what differs per
//! eye is gaze, pupil, kernel and adaptation. (An OpenXR runtime gives each
//! eye its own pose and field of view.)

use gazelight_tracker::{EYE_LEFT, EYE_RIGHT, EyeState, PupilOrigin};
use gazelight_vision::kernel_policy::{KernelPlan, KernelPolicy};
use gazelight_vision::pipeline::{FrameInput, PipelineConfig};
use gazelight_vision::psf::PsfBuilder;

use crate::backend::Renderer;

/// One view of a frame: which eye it is for.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub(crate) enum View {
    /// One view for both eyes (the binocular gaze and pupil).
    Both,
    /// An eye of a stereo frame: [`EYE_RIGHT`] or [`EYE_LEFT`].
    Eye(usize),
}

/// A mono frame's one view.
pub(crate) const MONO: [View; 1] = [View::Both];
/// A stereo frame's views in display order: left | right.
pub(crate) const STEREO: [View; 2] = [View::Eye(EYE_LEFT), View::Eye(EYE_RIGHT)];

impl View {
    /// The suffix of this view's `timeline.csv` columns ("" for one view).
    pub(crate) fn suffix(self) -> &'static str {
        match self {
            View::Both => "",
            View::Eye(EYE_LEFT) => "_left",
            View::Eye(_) => "_right",
        }
    }

    /// The pipeline's input for this view from the filtered state, and
    /// whether its pupil is held or modelled rather than measured.
    pub(crate) fn input(self, state: &EyeState, dt_secs: f32) -> (FrameInput, bool) {
        match self {
            View::Both => (
                FrameInput {
                    gaze_uv: state.gaze_uv,
                    pupil_mm: state.pupil_mm(),
                    dt_secs,
                },
                state
                    .eyes
                    .iter()
                    .any(|e| e.pupil_origin != PupilOrigin::Measured),
            ),
            View::Eye(e) => (
                FrameInput {
                    gaze_uv: state.eye_gaze_uv(e),
                    pupil_mm: state.eye_pupil_mm(e),
                    dt_secs,
                },
                state
                    .eyes
                    .get(e)
                    .is_none_or(|c| c.pupil_origin != PupilOrigin::Measured),
            ),
        }
    }
}

/// Builds the two eyes' kernels (on the calling thread: `render` and
/// `replay` are offline) and installs them.
pub(crate) struct StereoKernels {
    builder: PsfBuilder,
    policy: KernelPolicy,
    /// The pupil each eye's installed kernel was built for, mm.
    installed_mm: [f64; 2],
    /// Kernels built so far.
    pub(crate) builds: u64,
}

impl StereoKernels {
    /// Takes over kernel building from both renderers (`None` with glare
    /// off). Both start with the renderers' initial kernel, which is one
    /// shared kernel.
    pub(crate) fn new(
        config: &PipelineConfig,
        deg_per_px: f64,
        renderers: &mut [Renderer],
    ) -> anyhow::Result<Option<Self>> {
        if renderers.len() != 2 {
            anyhow::bail!("stereo kernels: {} renderers, expected 2", renderers.len());
        }
        let Some(initial_mm) = renderers[0].psf_kernel()?.map(|k| k.pupil_mm) else {
            return Ok(None);
        };
        let mut params = config.glare.psf.clone();
        // As the pipelines' own builders: same size and pixel size.
        params.ppd = 1.0 / deg_per_px;
        params.pupil_mm = initial_mm;
        let builder = PsfBuilder::new(params)?;
        for r in renderers.iter_mut() {
            r.set_psf_auto_rebuild(false);
        }
        Ok(Some(Self {
            builder,
            policy: KernelPolicy::new(&config.glare),
            installed_mm: [initial_mm; 2],
            builds: 0,
        }))
    }

    /// Brings each eye's kernel up to date for `inputs` (the two eyes'
    /// frame inputs, in the order of `renderers`) and says which eye got a
    /// new kernel.
    pub(crate) fn update(
        &mut self,
        inputs: [&FrameInput; 2],
        renderers: &mut [Renderer],
    ) -> anyhow::Result<[bool; 2]> {
        if renderers.len() != 2 {
            anyhow::bail!("stereo kernels: {} renderers, expected 2", renderers.len());
        }
        let mut changed = [false; 2];
        match self
            .policy
            .plan(inputs.map(|i| i.pupil_mm), self.installed_mm)
        {
            KernelPlan::Keep => {}
            KernelPlan::Shared(p) => {
                let kernel = self.builder.try_rebuild(p)?;
                self.builds += 1;
                for (e, r) in renderers.iter_mut().enumerate() {
                    r.set_kernel(kernel)?;
                    self.installed_mm[e] = kernel.pupil_mm;
                    changed[e] = true;
                }
            }
            KernelPlan::Own(own) => {
                for (e, p) in own.into_iter().enumerate() {
                    let Some(p) = p else { continue };
                    let kernel = self.builder.try_rebuild(p)?;
                    self.builds += 1;
                    renderers[e].set_kernel(kernel)?;
                    self.installed_mm[e] = kernel.pupil_mm;
                    changed[e] = true;
                }
            }
        }
        Ok(changed)
    }
}

/// Copies `src` (rows of `row_len` elements) into column `slot` of a
/// side-by-side image of `slots` such columns.
pub(crate) fn place_side_by_side<T: Copy>(
    src: &[T],
    dst: &mut [T],
    row_len: usize,
    slot: usize,
    slots: usize,
) {
    for (y, row) in src.chunks_exact(row_len).enumerate() {
        let o = (y * slots + slot) * row_len;
        dst[o..o + row_len].copy_from_slice(row);
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn views_take_their_eyes_gaze_and_pupil() {
        let mut s = EyeState {
            gaze_uv: [0.5, 0.5],
            ..Default::default()
        };
        s.eyes[EYE_LEFT].pupil_mm = 3.0;
        s.eyes[EYE_LEFT].pupil_origin = PupilOrigin::Measured;
        s.eyes[EYE_RIGHT].pupil_mm = 5.0;
        s.eyes[EYE_RIGHT].pupil_origin = PupilOrigin::Measured;
        s.eyes[EYE_LEFT].gaze_uv = [0.25, 0.5];
        s.eyes[EYE_LEFT].gaze_valid = true;
        let (left, held) = STEREO[0].input(&s, 0.01);
        assert_eq!(
            (left.gaze_uv, left.pupil_mm, held),
            ([0.25, 0.5], 3.0, false)
        );
        let (right, _) = STEREO[1].input(&s, 0.01);
        assert_eq!((right.gaze_uv, right.pupil_mm), ([0.5, 0.5], 5.0));
        let (both, _) = MONO[0].input(&s, 0.01);
        assert_eq!((both.gaze_uv, both.pupil_mm), ([0.5, 0.5], 4.0));
        assert_eq!(STEREO.map(View::suffix), ["_left", "_right"]);
    }

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

    #[test]
    fn side_by_side_places_rows() {
        let left = [1, 2, 3, 4];
        let right = [5, 6, 7, 8];
        let mut out = [0; 8];
        place_side_by_side(&left, &mut out, 2, 0, 2);
        place_side_by_side(&right, &mut out, 2, 1, 2);
        assert_eq!(out, [1, 2, 5, 6, 3, 4, 7, 8]);
    }
}
