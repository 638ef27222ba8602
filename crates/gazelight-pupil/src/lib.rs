//! # gazelight-pupil
//!
//! Pupil Core only: the Pupil Core network client ([`PupilClient`],
//! [`PupilSource`]), the msgpack datums on its bus ([`msg`]), `.pldata`
//! recordings ([`recording`]), the calibration stimulus sent to a host
//! application as a notification ([`stimulus`]), and the Pupil-compatible
//! relay server ([`relay`]) that re-publishes a session's filtered stream
//! to existing Pupil clients.
//!
//! Pupil Labs Neon is elsewhere: the live Real-time API client is the
//! `gazelight-neon` crate, recorded Neon sessions are `gazelight-import`'s.
//!
//! Every sample leaves as a [`gazelight_eye::Sample`] on the host clock
//! ([`gazelight_eye::clock`]).
//!
//! # Example
//!
//! A pupil sample as Pupil Capture publishes it (`pupil.1.3d`, a msgpack
//! map with named keys) and decoded back, without a network:
//!
//! ```
//! use gazelight_eye::{DetectorMethod, PupilSample, PupilUnit, Sample};
//! use gazelight_pupil::msg;
//!
//! let sample = Sample::Pupil(PupilSample {
//!     t_secs: 12.5,
//!     eye: 1,
//!     diameter_raw: 31.0,
//!     unit: PupilUnit::Px,
//!     diameter_mm: Some(3.5),
//!     confidence: 0.9,
//!     norm_pos: [0.25, 0.75],
//!     method: DetectorMethod::Pupil3d,
//! });
//! let (topic, payload) = msg::encode_sample(&sample)?.expect("a pupil datum");
//! assert_eq!(topic, "pupil.1.3d");
//! let back = msg::decode(&topic, &payload)?.to_sample(0.0);
//! assert_eq!(back, sample);
//! # Ok::<(), Box<dyn std::error::Error>>(())
//! ```

pub mod client;
pub mod limits;
pub mod msg;
pub mod recording;
pub mod relay;
pub mod stimulus;

pub use client::*;
pub use recording::{PldataReader, PldataWriter, RecordingError};
