//! # gazelight-tracker
//!
//! The device side of gazelight: eye-tracker samples, the sources that
//! produce them (the Pupil Core network API, recorded logs, synthetic
//! traces), the filter chain that cleans them, and the black/white pupil
//! calibration (001 §5) that maps raw pupil units onto millimetres.
//!
//! What the rest of the system reads is [`EyeState`]: the latest filtered,
//! calibrated state of both eyes, with its time and validity. Eye indices
//! follow Pupil Core: index 0 is the right eye, index 1 the left eye.

pub mod sample;
pub mod state;
pub mod trace;

pub use sample::{
    BlinkEvent, DetectorMethod, GazeEyes, GazeSample, PupilSample, PupilUnit, Sample,
};
pub use state::{EYE_LEFT, EYE_RIGHT, EyeChannel, EyeState, PupilOrigin};
pub use trace::{GazeTrace, TraceError, TraceSample};
pub mod calibration;
pub mod filter;
pub mod import;
pub mod lsl;
pub mod pupil;
pub mod pupil_model;
pub mod recording;
pub mod source;
pub use pupil::{
    PupilClient, PupilConfig, PupilError, PupilNotifier, PupilSource, PupilStats, RemoteSink,
};
pub use recording::{PldataReader, PldataWriter, RecordingError};
pub use source::{Pacing, ReplaySource, SampleSource, SourceError};
pub mod summary;
pub mod synthetic;
pub mod transport;
