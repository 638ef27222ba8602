//! # gazelight-eye
//!
//! The eye, without I/O: eye-tracker [`Sample`]s, the [`EyeState`] the
//! rest of gazelight reads, the [`filter`] chain that cleans samples, the
//! black/white pupil [`calibration`] (001 §5) and its [`profile`]s, the
//! luminance-driven [`pupil_model`], gaze [`trace`]s, [`synthetic`] sessions,
//! the process-wide host [`clock`], and the [`SampleSource`] interface every
//! live source and replay implements.
//!
//! This crate depends on no network, USB, serial or async-runtime crate, so
//! anything that only wants an `EyeState` or a filter stays small. Eye
//! indices follow Pupil Core: index 0 is the right eye, index 1 the left.

pub mod calibration;
pub mod clock;
pub mod filter;
pub mod profile;
pub mod pupil_model;
pub mod sample;
pub mod setting;
pub mod source;
pub mod state;
pub mod synthetic;
pub mod trace;

pub use sample::{
    BlinkEvent, DetectorMethod, GazeEyes, GazeSample, PupilSample, PupilUnit, Sample,
};
pub use setting::SettingError;
pub use source::{SampleSource, SourceError};
pub use state::{EYE_LEFT, EYE_RIGHT, EyeChannel, EyeState, PupilOrigin};
pub use trace::{GazeTrace, TraceError, TraceSample};
