//! # gazelight-vision
//!
//! The perception model of gazelight on the CPU: the formulas of the seed
//! papers as plain scalar functions (f64, tested against the seeds), the
//! adaptation state carried between frames, the physics of the glare point
//! spread function, HDR scene loading and a complete f32 reference frame
//! pipeline that is both the no-GPU backend and the reference the GPU passes
//! are compared against.
//!
//! Equation references such as `001 eq 14` name a seed paper by its prefix
//! and an equation number in it (the prefixes and full references are in
//! `docs/references.md`).
//!
//! | module | what | seeds |
//! | --- | --- | --- |
//! | [`image`] | linear RGB float images, luminance | 001 eq 1 |
//! | [`tvi`] | threshold-vs-intensity functions | 000 eq 1–4, 8 |
//! | [`pooling`] | adaptation luminance pooling around the gaze | 001 §4.1, 000 eq 5–6, 003 eq 1, 004 §3.1, 000 §3.2 |
//! | [`temporal`] | temporal adaptation state updates | 001 eq 2–4, 000 eq 7–8, 003 eq 2–3 |
//! | [`tone`] | tone reproduction operators | 000 eq 9–10, 003 eq 4–5, 004 §3.2–3.3 |
//! | [`colour`] | scotopic colour shift, colour discrimination, CIE L\*a\*b\* | 001 eq 14, 000 eq 11–12 |
//! | [`acuity`] | acuity loss: the blur σ per pixel | 001 eq 11–13 |
//! | [`band`] | the CPU band engine of the acuity blur (streamed bands of rows) | 001 §4.3.1 |
//! | [`psf`] | the glare point spread function | 001 §4.2, eq 5–10 |
//! | [`stray_light`] | CIE 146:2002 stray light, particle Airy lobes, J1 | CIE 146:2002 |
//! | [`glare`] | windowed FFT glare convolution at the gaze | 001 §4.2.3 |
//! | [`kernel_policy`] | which glare kernel for which pupil (range, missing pupils, rebuild threshold, one kernel or one per eye) | 001 §5 |
//! | [`scene`] | OpenEXR / Radiance loading, panorama views | 004 §3.3 |
//! | [`scene_glare`], [`glare_indices`] | glare numbers of a scene image at a gaze: sources as evalglare finds them, veils, DGP/DGI/UGR/VCP/CGI | evalglare 3.06, CIE 146:2002 |
//! | [`pipeline`] | the full frame pipeline, stages 1–8 | all |
//! | `simd` | CPU feature tiers (`GAZELIGHT_SIMD`, `GAZELIGHT_REQUIRE_SIMD`), the AVX2 / AVX-512 kernels | – |
//!
//! ## CPU SIMD tiers
//!
//! The CPU pipeline's row kernels run on the widest instruction-set tier
//! the CPU has: `portable` (plain Rust, any CPU), `avx2` (AVX2 + FMA),
//! `avx512` (AVX-512F + BW) or `avx512vbmi2`; every tier computes the same
//! bits (the tests compare each with the portable path, down to whole
//! frames). Two environment variables:
//!
//! * `GAZELIGHT_SIMD=portable|avx2|avx512|avx512vbmi2` caps the tier the
//!   process uses (read once): `GAZELIGHT_SIMD=portable gazelight render …`
//!   renders with the portable loops on any CPU.
//! * `GAZELIGHT_REQUIRE_SIMD=avx2,avx512,…` (for the tests, like
//!   `GAZELIGHT_REQUIRE_GPU`): a SIMD parity test whose tier is listed but
//!   missing on the machine fails instead of printing `SKIP` and passing.
//!   Unset, a missing tier is skipped with a `SKIP` line; the portable path
//!   is tested on every host. `.ci/run` lists the CI machine's tiers.

pub mod acuity;
pub mod band;
pub mod colour;
mod encode;
pub mod error;
pub mod far_glare;
pub mod glare;
pub mod glare_indices;
pub mod image;
pub mod kernel_policy;
pub mod pipeline;
pub mod pooling;
pub mod psf;
pub mod scene;
pub mod scene_glare;
mod simd;
pub mod stray_light;
pub mod temporal;
pub mod tone;
pub mod tvi;

pub use encode::SRGB_LUT_SIZE;
pub use error::VisionError;
pub use image::RgbImage;
