//! What a live gazelight session (`run`, `replay --serve`) publishes while
//! it runs:
//!
//! - [`hub`]: the newest state every observer reads — the eye state, the
//!   samples, the source status, the frame loop's figures and history, the
//!   latest display frame and glare kernel, and the shutdown flag.
//! - [`serve`]: the status page, its JSON and WebSocket (`--http`).
//! - [`lsl_outlets`]: the eye, frame and marker outlets on the Lab
//!   Streaming Layer (`--lsl`).
//! - [`relay`]: the Pupil-compatible relay fed from the hub (`--relay`).
//!
//! None of them can block the frame loop or the tracker source: they read
//! the hub's copies and bounded queues.

pub mod hub;
pub mod lsl_outlets;
pub mod relay;
pub mod serve;

pub use lsl_outlets::OutletError;
pub use serve::ServeError;
