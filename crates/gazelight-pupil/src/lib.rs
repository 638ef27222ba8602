//! # gazelight-pupil
//!
//! Pupil Labs' protocols: the Pupil Core network client ([`PupilClient`],
//! [`PupilSource`]), the msgpack datums on its bus ([`msg`]), `.pldata`
//! recordings ([`recording`]), the calibration stimulus sent to a host
//! application as a notification ([`stimulus`]), and the Pupil-compatible
//! relay server ([`relay`]) that re-publishes a session's filtered stream
//! to existing Pupil clients.
//!
//! Every sample leaves as a [`gazelight_eye::Sample`] on the host clock
//! ([`gazelight_eye::clock`]).

pub mod client;
pub mod msg;
pub mod recording;
pub mod relay;
pub mod stimulus;

pub use client::*;
pub use recording::{PldataReader, PldataWriter, RecordingError};
