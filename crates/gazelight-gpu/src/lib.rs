//! The gazelight frame pipeline on wgpu compute passes.
//!
//! Every stage of the CPU reference pipeline in `gazelight-vision` gets a
//! WGSL twin here (see DESIGN.md, "Data flow"), matched against it by parity
//! tests. This crate currently provides the foundation:
//!
//! - [`context`]: the device — a caller's `wgpu::Device` + `Queue` (library
//!   use inside a host renderer) or an own one, hardware adapter first,
//!   software (lavapipe) second, a clear [`GpuError::NoAdapter`] otherwise so
//!   the caller can use the CPU pipeline;
//! - [`shaders`]: the WGSL sources under `shaders/`, embedded at build time,
//!   each checked against the device limits (workgroup storage, which wgpu 30
//!   does not check, and workgroup size) before a pipeline is built;
//! - [`fft`]: a batched 2D Stockham FFT (radix 4/2, complex f32, powers of two
//!   up to 2048 per side), the transform behind the glare PSF (001 eq 8) and
//!   the FFT convolution of the frame with it;
//! - [`psf`]: the glare PSF (001 §4.2, eq 5–10) rebuilt on the GPU from the
//!   live pupil — aperture, FFT, intensity, spectral sum into display pixels,
//!   normalisation — matched against `gazelight_vision::psf`;
//! - [`cpu`]: the f64 reference of the kernels, mirroring their index schemes;
//! - [`testing`]: the shared test device and the `GAZELIGHT_REQUIRE_GPU` rule.
//!
//! The other per-frame stages (pooling, adaptation, glare convolution, acuity,
//! tone reproduction, scotopic colour, display encode) are not built yet:
//! until they are, the frame pipeline runs on the CPU reference.

pub mod acuity;
pub mod context;
pub mod cpu;
pub mod error;
pub mod fft;
pub mod frame;
pub mod glare;
pub mod pooling;
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
