//! Which glare kernel for which pupil: the one rule every kernel path
//! follows — the offline [`crate::pipeline::FramePipeline`], the GPU frame
//! (`gazelight-gpu`), the stereo plan, the live PSF worker (`gazelight`)
//! and the OpenXR layer — and the one [`KernelFollower`] that applies it
//! frame by frame.
//!
//! * **Range.** A finite pupil is clamped to the physiological range
//!   [`PUPIL_MM_RANGE`] (1.5–9 mm, defined in `gazelight-eye`), then to the
//!   builder's `psf.pupil_range_mm` (the same range by default): 0 mm and
//!   negative pupils get the 1.5 mm kernel, 20 mm the 9 mm one.
//! * **Non-finite pupils** (NaN, ±∞: no measurement) keep the last good
//!   kernel — the one the view has, or the initial 4 mm one.
//! * **Rebuild threshold.** A new kernel is built only when the wanted
//!   pupil is more than `psf_rebuild_threshold_mm` from the kernel's.
//! * **One kernel or one per eye.** Two eyes whose pupils agree within the
//!   threshold share one kernel at their mean; once they part, each eye's
//!   kernel follows its own pupil as a single eye's does
//!   ([`KernelPolicy::plan`]).

use gazelight_eye::filter::physio::PUPIL_MM_RANGE;

use crate::pipeline::GlareConfig;

/// The pupil of the first kernel, mm, before any pupil is known (the
/// middle of the adult range, 001 §5).
pub const INITIAL_PUPIL_MM: f64 = 4.0;

/// The kernels two eyes need, given their pupils and the pupils their
/// current kernels were built for.
#[derive(Clone, Copy, Debug, PartialEq)]
pub enum KernelPlan {
    /// Both kernels stay.
    Keep,
    /// One kernel, built for this pupil (mm), into both eyes.
    Shared(f64),
    /// Per eye (indexed like the inputs): a kernel for this pupil (mm), or
    /// keep.
    Own([Option<f64>; 2]),
}

/// The rule, for one pipeline configuration (see the module docs).
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct KernelPolicy {
    /// The builder's pupils, mm `[min, max]` (`psf.pupil_range_mm`).
    builder_range_mm: [f64; 2],
    /// Rebuild when the wanted pupil is farther than this from the
    /// kernel's, mm.
    threshold_mm: f64,
}

impl KernelPolicy {
    /// The policy of a glare configuration: its builder's pupil range and
    /// its rebuild threshold.
    pub fn new(glare: &GlareConfig) -> Self {
        Self {
            builder_range_mm: glare.psf.pupil_range_mm,
            threshold_mm: glare.psf_rebuild_threshold_mm,
        }
    }

    /// The rebuild threshold, mm.
    pub fn threshold_mm(&self) -> f64 {
        self.threshold_mm
    }

    /// The pupil a kernel is built for when the eye's pupil is `pupil_mm`:
    /// clamped to [`PUPIL_MM_RANGE`], then to the builder's range; `None`
    /// for a non-finite pupil (no measurement).
    pub fn kernel_pupil_mm(&self, pupil_mm: f32) -> Option<f64> {
        if !pupil_mm.is_finite() {
            return None;
        }
        let [lo, hi] = self.builder_range_mm;
        Some(
            f64::from(pupil_mm)
                .clamp(f64::from(PUPIL_MM_RANGE.0), f64::from(PUPIL_MM_RANGE.1))
                .clamp(lo, hi),
        )
    }

    /// The pupil the view's kernel should have: [`Self::kernel_pupil_mm`],
    /// or `kernel_mm` (the kernel it has) for a non-finite pupil.
    pub fn wanted_mm(&self, pupil_mm: f32, kernel_mm: f64) -> f64 {
        self.kernel_pupil_mm(pupil_mm).unwrap_or(kernel_mm)
    }

    /// Whether a kernel built for `kernel_mm` is too far from `wanted_mm`:
    /// more than the threshold, or no kernel yet (NaN).
    fn moved(&self, wanted_mm: f64, kernel_mm: f64) -> bool {
        // NaN (no kernel yet) compares as moved.
        matches!(
            (wanted_mm - kernel_mm)
                .abs()
                .partial_cmp(&self.threshold_mm),
            None | Some(std::cmp::Ordering::Greater)
        )
    }

    /// One view: the pupil to build a new kernel for, or `None` to keep the
    /// kernel built for `kernel_mm` (NaN: none yet).
    pub fn decide(&self, pupil_mm: f32, kernel_mm: f64) -> Option<f64> {
        let wanted = self.wanted_mm(pupil_mm, kernel_mm);
        (wanted.is_finite() && self.moved(wanted, kernel_mm)).then_some(wanted)
    }

    /// Two eyes: their pupils and the pupils their kernels were built for
    /// → keep, one shared kernel (at the mean of the two wanted pupils,
    /// built when the mean leaves the shared kernel by more than the
    /// threshold, or when the eyes had two), or one each. An eye with a
    /// non-finite pupil wants the kernel it has.
    pub fn plan(&self, pupils_mm: [f32; 2], kernels_mm: [f64; 2]) -> KernelPlan {
        let wanted = [0, 1].map(|e| self.wanted_mm(pupils_mm[e], kernels_mm[e]));
        self.plan_mm(wanted, kernels_mm)
    }

    /// [`Self::plan`] on the wanted pupils.
    fn plan_mm(&self, wanted_mm: [f64; 2], kernels_mm: [f64; 2]) -> KernelPlan {
        let [a, b] = wanted_mm;
        if (a - b).abs() <= self.threshold_mm {
            let mean = 0.5 * (a + b);
            let shared = kernels_mm[0] == kernels_mm[1];
            if shared && !self.moved(mean, kernels_mm[0]) {
                KernelPlan::Keep
            } else {
                KernelPlan::Shared(mean)
            }
        } else {
            let own = [0, 1].map(|e| {
                let w = wanted_mm[e];
                (w.is_finite() && self.moved(w, kernels_mm[e])).then_some(w)
            });
            if own == [None, None] {
                KernelPlan::Keep
            } else {
                KernelPlan::Own(own)
            }
        }
    }
}

/// The one follower of the rule: the pupil each view's kernel was built
/// (or asked) for, and which kernels this frame's pupils need. Every
/// kernel path keeps one — the offline [`crate::pipeline::FramePipeline`]
/// and the GPU frame (one view each), `gazelight-render`'s stereo kernels,
/// the live frame loop's PSF worker and the OpenXR layer's — so the
/// decision and its bookkeeping exist once.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct KernelFollower {
    policy: KernelPolicy,
    /// The pupil each view's kernel was built or asked for, mm (NaN: none
    /// yet).
    kernels_mm: [f64; 2],
    /// 1 or 2 views; two are planned together ([`KernelPolicy::plan`]).
    views: usize,
}

impl KernelFollower {
    /// `views` (1 or 2; more are treated as 2) whose kernels start at
    /// `initial_mm` (NaN: no kernel yet).
    pub fn new(policy: KernelPolicy, views: usize, initial_mm: f64) -> Self {
        Self {
            policy,
            kernels_mm: [initial_mm; 2],
            views: views.clamp(1, 2),
        }
    }

    /// The rule it follows.
    pub fn policy(&self) -> &KernelPolicy {
        &self.policy
    }

    /// The pupil view `view`'s kernel was built or asked for, mm.
    pub fn kernel_mm(&self, view: usize) -> f64 {
        self.kernels_mm[view.min(1)]
    }

    /// The kernels to build for this frame's pupils (indexed like the
    /// views; one view reads `pupils_mm[0]`): `Some(mm)` where a view
    /// needs a new one — both the same while two eyes share one — which
    /// is from now that view's kernel.
    pub fn follow(&mut self, pupils_mm: [f32; 2]) -> [Option<f64>; 2] {
        let wanted = if self.views == 1 {
            [self.policy.decide(pupils_mm[0], self.kernels_mm[0]), None]
        } else {
            match self.policy.plan(pupils_mm, self.kernels_mm) {
                KernelPlan::Keep => [None, None],
                KernelPlan::Shared(mm) => [Some(mm), Some(mm)],
                KernelPlan::Own(own) => own,
            }
        };
        for (k, w) in self.kernels_mm.iter_mut().zip(wanted) {
            if let Some(mm) = w {
                *k = mm;
            }
        }
        wanted
    }

    /// One view: [`Self::follow`] for its pupil.
    pub fn follow_one(&mut self, pupil_mm: f32) -> Option<f64> {
        self.follow([pupil_mm, f32::NAN])[0]
    }

    /// View `view` got a kernel built for `mm` (a builder may round the
    /// pupil it was asked for): its kernel from now.
    pub fn built(&mut self, view: usize, mm: f64) {
        self.kernels_mm[view.min(1)] = mm;
    }

    /// Whether view `view`'s kernel is the one `pupil_mm` wants (no
    /// rebuild due).
    pub fn is_current(&self, view: usize, pupil_mm: f32) -> bool {
        self.policy
            .decide(pupil_mm, self.kernels_mm[view.min(1)])
            .is_none()
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::psf::PsfParams;

    fn policy(threshold_mm: f64) -> KernelPolicy {
        KernelPolicy::new(&GlareConfig {
            psf_rebuild_threshold_mm: threshold_mm,
            ..GlareConfig::default()
        })
    }

    /// The pupils the issue names, against a 4 mm kernel: no measurement
    /// keeps it; 0 and 20 mm clamp to the ends of the 1.5–9 mm range
    /// (001 §5 with its margins); pupils within 0.1 mm keep it.
    #[test]
    fn bad_pupils_keep_or_clamp() {
        let p = policy(0.1);
        for bad in [f32::NAN, f32::INFINITY, f32::NEG_INFINITY] {
            assert_eq!(p.decide(bad, 4.0), None, "{bad}");
            assert_eq!(p.wanted_mm(bad, 4.0), 4.0, "{bad}");
            assert_eq!(p.kernel_pupil_mm(bad), None, "{bad}");
        }
        assert_eq!(p.decide(0.0, 4.0), Some(1.5));
        assert_eq!(p.decide(-3.0, 4.0), Some(1.5));
        assert_eq!(p.decide(20.0, 4.0), Some(9.0));
        assert_eq!(p.decide(20.0, 9.0), None);
        assert_eq!(p.decide(0.0, 1.5), None);
        assert_eq!(p.decide(4.0625, 4.0), None);
        assert_eq!(p.decide(4.125, 4.0), Some(4.125));
        // No kernel yet: any measured pupil builds one; none builds nothing.
        assert_eq!(p.decide(3.0, f64::NAN), Some(3.0));
        assert_eq!(p.decide(f32::NAN, f64::NAN), None);
        // The default builder range is the physiological one.
        assert_eq!(
            PsfParams::default().pupil_range_mm,
            [f64::from(PUPIL_MM_RANGE.0), f64::from(PUPIL_MM_RANGE.1)]
        );
    }

    /// A builder with a narrower range: its ends, not the physiological
    /// ones (so a 1.5 mm pupil does not rebuild a 2 mm kernel each frame).
    #[test]
    fn a_narrower_builder_range_clamps_further() {
        let mut glare = GlareConfig::default();
        glare.psf.pupil_range_mm = [2.0, 8.0];
        let p = KernelPolicy::new(&glare);
        assert_eq!(p.decide(0.0, 4.0), Some(2.0));
        assert_eq!(p.decide(1.5, 2.0), None);
        assert_eq!(p.decide(20.0, 4.0), Some(8.0));
    }

    /// The follower on a pupil trace written here: one view rebuilds only
    /// past the threshold and keeps its kernel over a lost sample; two
    /// agreeing eyes get one shared kernel, parted eyes one each.
    #[test]
    fn the_follower_asks_for_what_the_rule_says_once() {
        let mut one = KernelFollower::new(policy(0.1), 1, 4.0);
        let got: Vec<Option<f64>> = [4.05_f32, 4.2, 4.25, f32::NAN, 4.4, 20.0, 20.0]
            .into_iter()
            .map(|p| one.follow_one(p))
            .collect();
        let want: [Option<f64>; 7] = [None, Some(4.2), None, None, Some(4.4), Some(9.0), None];
        for (g, w) in got.iter().zip(want) {
            assert_eq!(g.map(|m| (m * 1e4).round()), w.map(|m| (m * 1e4).round()));
        }
        assert_eq!(one.kernel_mm(0), 9.0);
        assert!(one.is_current(0, 12.0));

        let mut two = KernelFollower::new(policy(0.1), 2, 4.0);
        assert_eq!(two.follow([4.02, 4.05]), [None, None]);
        let [a, b] = two.follow([5.0, 5.04]);
        assert!(a.is_some() && a == b, "{a:?} {b:?}");
        let parted = two.follow([3.0, 6.0]);
        assert_eq!(parted, [Some(3.0), Some(6.0)]);
        assert_eq!([two.kernel_mm(0), two.kernel_mm(1)], [3.0, 6.0]);
        // A builder that rounds: the follower keeps what was built.
        two.built(1, 6.01);
        assert_eq!(two.follow([3.0, 6.05]), [None, None]);
    }

    #[test]
    fn one_kernel_while_the_pupils_agree_two_when_they_part() {
        let p = policy(0.1);
        // Agreeing pupils near the shared kernel: keep it.
        assert_eq!(p.plan_mm([4.02, 4.05], [4.0, 4.0]), KernelPlan::Keep);
        // Agreeing pupils away from it: one kernel at their mean.
        let shared = |plan: KernelPlan| match plan {
            KernelPlan::Shared(mm) => mm,
            other => panic!("{other:?}"),
        };
        assert!((shared(p.plan_mm([3.0, 3.08], [4.0, 4.0])) - 3.04).abs() < 1e-12);
        // The pupils part: each eye its own, only where needed.
        assert_eq!(
            p.plan_mm([3.0, 3.5], [3.04, 3.04]),
            KernelPlan::Own([None, Some(3.5)])
        );
        assert_eq!(
            p.plan_mm([2.5, 3.5], [3.04, 3.04]),
            KernelPlan::Own([Some(2.5), Some(3.5)])
        );
        assert_eq!(p.plan_mm([2.55, 3.45], [2.5, 3.5]), KernelPlan::Keep);
        // They agree again: back to one kernel, even when each own kernel is
        // within the threshold of its pupil.
        assert!((shared(p.plan_mm([3.0, 3.05], [2.95, 3.1])) - 3.025).abs() < 1e-12);
    }

    /// Two eyes, one without a measurement: that eye keeps its kernel
    /// while the other follows its own pupil; both unmeasured keep both.
    #[test]
    fn an_unmeasured_eye_keeps_its_kernel_in_stereo() {
        let p = policy(0.1);
        for bad in [f32::NAN, f32::INFINITY, f32::NEG_INFINITY] {
            assert_eq!(p.plan([bad, bad], [4.0, 4.0]), KernelPlan::Keep);
            assert_eq!(p.plan([bad, 4.0625], [4.0, 4.0]), KernelPlan::Keep);
            assert_eq!(
                p.plan([bad, 6.0], [4.0, 4.0]),
                KernelPlan::Own([None, Some(6.0)])
            );
            assert_eq!(
                p.plan([20.0, bad], [3.0, 5.0]),
                KernelPlan::Own([Some(9.0), None])
            );
        }
        // 0 and 20 mm: both clamped, then planned as any two pupils.
        assert_eq!(
            p.plan([0.0, 20.0], [4.0, 4.0]),
            KernelPlan::Own([Some(1.5), Some(9.0)])
        );
        assert_eq!(p.plan([0.0, 0.0], [4.0, 4.0]), KernelPlan::Shared(1.5));
    }
}
