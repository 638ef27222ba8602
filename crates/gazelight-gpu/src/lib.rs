//! The gazelight frame pipeline on wgpu compute passes.
//!
//! Every stage of the CPU reference pipeline in `gazelight-vision` has a
//! WGSL twin here (see ARCHITECTURE.md, "Every stage exists twice"), matched against it by parity
//! tests, and [`GpuFramePipeline`] runs them all, per frame, in one command
//! encoder with nothing read back between stages:
//!
//! - [`frame`]: [`GpuFramePipeline`] — `new(ctx, config, width, height,
//!   deg_per_px)`, `process(scene, input) -> FrameStats`, `display()`; and,
//!   for a host renderer on its own device and buffers, `bind_io` +
//!   `encode(encoder, input)`. Whole-frame display values match
//!   `FramePipeline` within 1/255;
//! - [`pooling`] (stage 1): scene import, block luminance and the
//!   gaze-weighted pooling of every `PoolingModel` as workgroup reductions;
//! - [`temporal`] (stage 2): the adaptation step, one GPU thread;
//! - [`psf`] (stage 3): the glare kernel, rebuilt when the pupil moved more
//!   than the threshold, cached otherwise, built on the GPU as the twin of
//!   [`gazelight_vision::psf::PsfBuilder`] (wave-optics near field: aperture
//!   × particles × defocus, FFT, spectral sum; particle lobes; CIE 146 stray
//!   light; unit energy), its pupil-independent tables made once on the CPU;
//! - [`glare`] (stage 4): windowed FFT convolution at the gaze with the
//!   Gaussian falloff blend, kernel spectrum cached between rebuilds;
//! - [`far_glare`] (stage 4): the full-field stray light, the CIE 146 veil
//!   of every pixel on a coarse angular grid, joined to the window glare
//!   (the twin of [`gazelight_vision::far_glare::FarField`]);
//! - [`acuity`] (stage 5): per-pixel σ from each pixel's own lightness
//!   (001 eq 11–13), separable Lab-lightness blur of the HDR frame;
//! - [`tone`] (stages 6–8): tone reproduction, colour, sRGB encoding;
//! - [`present`]: the display frame into a window surface on the
//!   pipeline's own device (the output buffer drawn directly, no read-back),
//!   or a host frame / solid colour on a device of its own;
//! - [`context`]: the device — a caller's `wgpu::Device` + `Queue` (library
//!   use inside a host renderer) or an own one, hardware adapter first,
//!   software (lavapipe) second, a clear [`GpuError::NoAdapter`] otherwise so
//!   the caller can use the CPU pipeline;
//! - [`shaders`]: the WGSL sources under `shaders/`, embedded at build time,
//!   each checked against the device limits (workgroup storage, which wgpu 30
//!   does not check, and workgroup size) before a pipeline is built;
//! - [`fft`]: a batched 2D Stockham FFT (radix 4/2, complex f32, powers of two
//!   up to 2048 per side), behind the glare convolution;
//! - [`cpu`]: the f64 reference of the FFT kernels, mirroring their index
//!   schemes;
//! - [`testing`]: the shared test device and the `GAZELIGHT_REQUIRE_GPU` rule.
//!
//! Benchmarks: `benches/gpu_frame.rs` (per stage, GPU timestamps when the
//! adapter has them), `benches/gpu_psf.rs`, `benches/gpu_fft.rs`.

pub mod acuity;
pub mod context;
pub mod cpu;
pub mod error;
pub mod far_glare;
pub mod fft;
pub mod frame;
pub mod glare;
pub mod pass;
pub mod pooling;
pub mod present;
pub mod psf;
pub mod shaders;
pub mod temporal;
pub mod testing;
pub mod tone;

pub use context::{AdapterChoice, ContextOptions, GpuContext};
pub use error::GpuError;
pub use fft::{FftDirection, FftParams, FftPass, GpuFft2d};
pub use frame::{EncodedFrame, FrameState, FrameTimestamps, GpuFramePipeline};
pub use psf::GpuPsfBuilder;
