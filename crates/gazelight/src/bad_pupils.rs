//! Test-only: one sequence of pupils, good and bad, with the kernel each
//! kernel path must end up with, so the four paths (offline CPU pipeline,
//! GPU frame, stereo plan, live PSF worker) are checked against the same
//! table (issue 32: "which kernel for which pupil" decided in one place).
//!
//! The expected kernels follow from the documented rule, not from the code:
//! a finite pupil is clamped to the physiological 1.5–9 mm range (001 §5's
//! 2–8 mm with margins, docs/perception.md), a non-finite one (no
//! measurement) keeps the kernel the view has, and the first kernel is the
//! 4 mm one.

/// `(pupil_mm fed to the frame, kernel pupil_mm expected after it)`, in
/// order, starting from the initial 4 mm kernel.
pub(crate) const SEQUENCE: &[(f32, f64)] = &[
    (f32::NAN, 4.0),
    (6.0, 6.0),
    (f32::INFINITY, 6.0),
    (f32::NEG_INFINITY, 6.0),
    (f32::NAN, 6.0),
    (0.0, 1.5),
    (-3.0, 1.5),
    (20.0, 9.0),
    (f32::MAX, 9.0),
    (f32::NAN, 9.0),
    (5.0, 5.0),
];
