//! The OpenXR output of gazelight: an OpenXR session on the Vulkan device
//! wgpu renders with, so the frame pipeline writes straight into the
//! runtime's swapchain images (no host round trip).
//!
//! - [`XrSession::open`] loads the OpenXR loader (`libopenxr_loader.so.1`,
//!   at run time), creates the instance with `XR_KHR_vulkan_enable2` (plus
//!   `XR_KHR_convert_timespec_time` and `XR_EXT_eye_gaze_interaction` when
//!   the runtime offers them), lets the runtime create the Vulkan instance
//!   and device from wgpu-hal's extension and feature lists, wraps them as a
//!   `wgpu::Adapter` / `Device` / `Queue` ([`vulkan`] module docs), and
//!   creates a PRIMARY_STEREO session with one sRGB swapchain per eye at the
//!   recommended size, its images wrapped once as `wgpu::Texture`s. No
//!   runtime is a clear [`XrError::NoRuntime`] naming `XR_RUNTIME_JSON`.
//! - [`XrSession::poll_events`] runs the session state machine (begin on
//!   `Ready`, end on `Stopping`, exit on `Exiting` / loss);
//!   [`XrSession::request_exit`] asks the runtime to stop.
//! - [`XrSession::begin_frame`] / [`XrSession::end_frame`]: `xrWaitFrame`
//!   pacing, per-eye pose, field of view and the texture view to render
//!   into, the gaze pose, one projection layer.
//! - [`geometry`]: pure functions — per-pixel view rays of a field of view
//!   ([`TangentProjection::pixel_ray`]) and the gaze in normalised view
//!   coordinates ([`gaze_to_view_uv`]).
//!
//! # Example
//!
//! ```no_run
//! use gazelight_xr::{XrOptions, XrSession};
//!
//! # fn main() -> Result<(), gazelight_xr::XrError> {
//! let (mut xr, _adapter, device, queue) = XrSession::open(&XrOptions::default())?;
//! loop {
//!     let status = xr.poll_events()?;
//!     if status.should_exit {
//!         break;
//!     }
//!     let Some(frame) = xr.begin_frame()? else {
//!         std::thread::sleep(std::time::Duration::from_millis(10));
//!         continue;
//!     };
//!     let mut encoder = device.create_command_encoder(&Default::default());
//!     for eye in &frame.views {
//!         // Cast one ray per pixel with eye.fov.projection().pixel_ray(..),
//!         // centre the foveation at frame.gaze_uv(i); here: clear.
//!         encoder.begin_render_pass(&wgpu::RenderPassDescriptor {
//!             label: None,
//!             color_attachments: &[Some(wgpu::RenderPassColorAttachment {
//!                 view: &eye.view,
//!                 depth_slice: None,
//!                 resolve_target: None,
//!                 ops: wgpu::Operations {
//!                     load: wgpu::LoadOp::Clear(wgpu::Color::BLACK),
//!                     store: wgpu::StoreOp::Store,
//!                 },
//!             })],
//!             ..Default::default()
//!         });
//!     }
//!     queue.submit([encoder.finish()]);
//!     xr.end_frame(frame)?;
//! }
//! # Ok(())
//! # }
//! ```

pub mod error;
pub mod geometry;
pub mod session;
pub mod vulkan;

pub use error::XrError;

/// CLOCK_MONOTONIC now, seconds: the clock
/// [`XrFrame::predicted_display_monotonic_secs`] is on (and the one Rust's
/// `Instant` reads on Linux), for mapping a display time onto a host clock.
pub fn monotonic_now_secs() -> f64 {
    let mut ts = libc::timespec {
        tv_sec: 0,
        tv_nsec: 0,
    };
    // SAFETY: an out-pointer to a timespec; CLOCK_MONOTONIC always exists
    // on Linux.
    let r = unsafe { libc::clock_gettime(libc::CLOCK_MONOTONIC, &mut ts) };
    if r != 0 {
        return f64::NAN;
    }
    ts.tv_sec as f64 + ts.tv_nsec as f64 * 1e-9
}
pub use geometry::{Fov, Pose, TangentProjection, gaze_to_view_uv};
pub use session::{
    Eye, EyeView, ReferenceSpace, SessionState, SessionStatus, XrFrame, XrOptions, XrSession,
    XrSessionInfo,
};
