//! gazelight's application core: the rules the three front ends (the
//! `gazelight` CLI, the `gazelight` Python module and the OpenXR layer)
//! share, written once here so that they cannot drift apart. The front ends
//! only translate their inputs (flags, keyword arguments, a layer config)
//! into calls on it.
//!
//! Today it holds [`bounds`], the limits on every number a user gives
//! (rates, durations, frame counts, image sizes, luminance scales), and
//! [`observer`], the observer's age and pigmentation and where they come
//! from. The
//! rest of the application core (configuration, the renderer choice, the
//! render/replay session and its streaming per-frame writer, source
//! opening, the kernel follower) is still in the binary crate and moves
//! here piece by piece (ARCHITECTURE.md, "Where the front ends still
//! differ").

pub mod bounds;
pub mod observer;
