//! # gazelight-pupil
//!
//! Pupil Labs' protocols: the Pupil Core network client ([`PupilClient`],
//! [`PupilSource`]), the msgpack datums on its bus ([`msg`]), `.pldata`
//! recordings ([`recording`]), and the calibration stimulus sent to a host
//! application as a notification ([`stimulus`]).
//!
//! Every sample leaves as a [`gazelight_eye::Sample`] on the host clock
//! ([`gazelight_eye::clock`]).

pub mod client;
pub mod msg;
pub mod recording;
pub mod stimulus;

pub use client::*;
pub use recording::{PldataReader, PldataWriter, RecordingError};
